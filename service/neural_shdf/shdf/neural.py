"""The neural ShDF: predicted diameters, then the exact path's post-processing.

The predictions are interpolated from a few thousand surface samples, so they
are already smooth at the sampling scale; by default the post-processing
therefore skips its bilateral pass (``smooth=False``: filling and the same
linear normalisation), which on dense meshes would cost far more than the
prediction (its window grows with the face count) while changing little.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from neural_shdf.geometry import FaceGraph
from neural_shdf.mesh import TriangleMesh
from neural_shdf.neural.inference import DEFAULT_SAMPLE_SETS, load_model, neural_raw_shdf
from neural_shdf.shdf.postprocess import postprocess_shdf

Progress = Callable[[float], None]


def neural_shdf(
    mesh: TriangleMesh,
    *,
    graph: FaceGraph,
    seed: int = 0,
    sample_sets: int = DEFAULT_SAMPLE_SETS,
    progress: Progress | None = None,
    model_path: str | Path | None = None,
    smooth: bool = False,
) -> NDArray[np.float64]:
    """ShDF in [0, 1] per triangle of ``mesh`` from the ONNX network.

    ``seed`` picks the surface samples, ``sample_sets`` how many sample sets are
    averaged (``neural_raw_shdf``); ``smooth`` adds the bilateral pass of
    ``postprocess_shdf``. Raises ModelUnavailableError when no model is installed.
    """
    model = load_model(model_path)
    normals, areas = mesh.normals_and_areas
    raw = neural_raw_shdf(
        mesh.vertices,
        mesh.faces,
        seed=seed,
        sample_sets=sample_sets,
        model=model,
        normals=normals,
        areas=areas,
    )
    if progress is not None:
        progress(0.5)
    out = postprocess_shdf(raw, graph, smooth=smooth)
    if progress is not None:
        progress(1.0)
    return out
