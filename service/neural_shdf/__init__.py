"""neural-shdf: mesh segmentation from a (neural) Shape Diameter Function."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from neural_shdf.errors import MeshError

if TYPE_CHECKING:
    from neural_shdf.mesh import TriangleMesh

__all__ = ["MeshError", "TriangleMesh", "__version__"]
__version__ = "0.2.0"


def __getattr__(name: str) -> Any:
    """``TriangleMesh`` on first use: importing the package (as ``neural_shdf.client`` does)
    must not load the compiled kernels (numba) and scipy that the mesh module needs."""
    if name == "TriangleMesh":
        from neural_shdf.mesh import TriangleMesh

        return TriangleMesh
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
