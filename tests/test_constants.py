"""ALGORITHM_VERSION: the golden result of each version, so that a change of results
without a new version (which would serve stale cached results after an upgrade) fails."""

from __future__ import annotations

import hashlib

import numpy as np

from neural_shdf.constants import ALGORITHM_VERSION
from neural_shdf.mesh import TriangleMesh
from neural_shdf.pipeline import compute_shdf, segment
from neural_shdf.segment import SegmentParams
from tests.mesh_helpers import balls_and_bar

#: ALGORITHM_VERSION -> sha256 of the golden mesh's (ShDF rounded to 6 decimals, labels).
#: When results change on purpose: bump ALGORITHM_VERSION and add its pair here.
GOLDEN = {
    1: "5ee33c7d099cd0d92512580967e781745716be427f636ccacadcf67d5ec44fe9",
    # The ray cone turns with each triangle; segmentation grids along the mesh's axes.
    2: "3091e815157e21cac5ad8de2257dee47ee4e677d537cea33a4907df064a30d0c",
    # The graph cut normalised for resolution (reference_faces 40k), tree concavity
    # measured against the mesh's mean bending.
    3: "8734aaa5dd9a1c6cf4fd4d502ff19d318576fd5b9b88d08cb2c4500683cce633",
}


def golden_mesh() -> TriangleMesh:
    """Two balls of different sizes joined by a thin bar: parts a segmentation must find."""
    joined = balls_and_bar(2, 2)
    return TriangleMesh(np.asarray(joined.vertices, float), np.asarray(joined.faces, np.int64))


def golden_digest() -> str:
    mesh = golden_mesh()
    shdf = compute_shdf(mesh, method="exact", seed=0).values
    labels = segment(mesh, shdf, SegmentParams()).labels
    digest = hashlib.sha256(np.round(shdf, 6).astype("<f8").tobytes())
    digest.update(np.asarray(labels, dtype="<i8").tobytes())
    return digest.hexdigest()


def test_results_change_only_with_the_algorithm_version():
    assert ALGORITHM_VERSION in GOLDEN, (
        f"ALGORITHM_VERSION {ALGORITHM_VERSION} has no golden result: add it to GOLDEN"
    )
    assert golden_digest() == GOLDEN[ALGORITHM_VERSION], (
        "the ShDF or the labels of the golden mesh changed: bump ALGORITHM_VERSION in "
        "neural_shdf/constants.py (cached results of the code before must not be served) "
        "and add the new version's digest to GOLDEN"
    )
