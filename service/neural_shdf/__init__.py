"""neural-shdf: mesh segmentation from a (neural) Shape Diameter Function."""

from neural_shdf.errors import MeshError
from neural_shdf.mesh import TriangleMesh

__all__ = ["MeshError", "TriangleMesh", "__version__"]
__version__ = "0.2.0"
