"""Boundary smoothing and recursive refinement."""

import numpy as np
import trimesh

from neural_shdf.geometry import build_face_graph, face_normals, weld_faces
from neural_shdf.segment.graphcut import dihedral_weights, near_boundary
from neural_shdf.segment.params import SegmentParams
from neural_shdf.segment.parts import FaceData
from neural_shdf.segment.refine import refine_parts, smooth_boundaries
from neural_shdf.segment.synthetic import JUNCTION_Z, dumbbell


def test_smoothing_shortens_a_jagged_boundary_and_stays_in_the_band():
    mesh = trimesh.creation.icosphere(4)
    normals, areas = face_normals(mesh.vertices, mesh.faces)
    graph = build_face_graph(mesh.vertices, mesh.faces, normals)
    centre = mesh.triangles_center
    jagged = (
        centre[:, 2] > 0.15 * np.sign(np.sin(12 * np.arctan2(centre[:, 1], centre[:, 0])))
    ).astype(np.int64)
    weights = dihedral_weights(graph, 0.26)
    smoothed = smooth_boundaries(jagged, graph, weights, areas / areas.mean())

    def cut_length(labels):
        cut = labels[graph.pairs[:, 0]] != labels[graph.pairs[:, 1]]
        return graph.edge_length[cut].sum()

    assert cut_length(smoothed) < 0.8 * cut_length(jagged)
    band = near_boundary(jagged, graph.pairs, graph.face_count, 3)
    np.testing.assert_array_equal(smoothed[~band], jagged[~band])


def test_refinement_splits_a_heterogeneous_part():
    mesh, shdf = dumbbell(4000)
    vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    normals, _ = face_normals(vertices, faces)
    graph = build_face_graph(vertices, weld_faces(vertices, faces), normals)
    geometry = FaceData.of(vertices, faces)
    one_part = np.zeros(len(faces), dtype=np.int64)
    refined = refine_parts(
        one_part, shdf, graph, dihedral_weights(graph, 0.26), geometry, SegmentParams(refine=True)
    )
    z = mesh.triangles_center[:, 2]
    neck = np.abs(z) < JUNCTION_Z - 0.1
    assert refined.max() >= 1
    assert not set(refined[neck]) & set(refined[np.abs(z) > JUNCTION_Z + 0.1])
    # Depth 0 means no refinement at all.
    unchanged = refine_parts(
        one_part,
        shdf,
        graph,
        dihedral_weights(graph, 0.26),
        geometry,
        SegmentParams(refine=True, refine_depth=0),
    )
    np.testing.assert_array_equal(unchanged, one_part)
