"""The one place where the labeller calls the rest of the library.

The core (``pipeline``, ``segment``, ``shdf``) may rename things; a merge fixes them here.
"""

from __future__ import annotations

from neural_shdf.exchange.seg import read_labels, write_labels, write_values
from neural_shdf.geometry import FaceGraph, face_centroids
from neural_shdf.mesh import TriangleMesh
from neural_shdf.mesh_io import SUPPORTED_FORMATS, load_mesh
from neural_shdf.pipeline import compute_shdf
from neural_shdf.segment.graphcut import data_costs, dihedral_weights, multilevel_alpha_expansion
from neural_shdf.shdf.sampling import interpolate_samples, sample_surface_points

__all__ = [
    "SUPPORTED_FORMATS",
    "FaceGraph",
    "TriangleMesh",
    "compute_shdf",
    "data_costs",
    "dihedral_weights",
    "face_centroids",
    "interpolate_samples",
    "load_mesh",
    "multilevel_alpha_expansion",
    "read_labels",
    "sample_surface_points",
    "write_labels",
    "write_values",
]
