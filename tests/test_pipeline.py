"""The library's front door: warm-up of the compiled paths."""

import numpy as np
import pytest

from neural_shdf import geometry, pipeline
from neural_shdf.mesh import TriangleMesh
from neural_shdf.mesh_io import load_mesh
from neural_shdf.segment import SegmentParams, graphcut, mixture, parts
from neural_shdf.shdf import exact
from neural_shdf.shdf.neural import inference


def test_warm_up_compiles_every_kernel_it_reaches():
    seconds = pipeline.warm_up()
    assert seconds > 0
    assert exact._shdf_of_faces.signatures
    compiled = [
        getattr(module, name)
        for module in (geometry, graphcut, mixture, parts)
        for name in dir(module)
        if hasattr(getattr(module, name), "signatures")
    ]
    called = [k for k in compiled if k.targetoptions.get("inline") != "always"]  # not inlined
    assert called and all(kernel.signatures for kernel in called)


def test_warm_up_skips_a_missing_model(monkeypatch, tmp_path):
    monkeypatch.setenv(inference.MODEL_ENV_VAR, str(tmp_path / "absent.onnx"))
    assert pipeline.warm_up() > 0
    with pytest.raises(Exception, match="not found"):
        inference.load_model()


@pytest.mark.parametrize(
    "params",
    [
        SegmentParams(),
        SegmentParams(partitioner="metis", parts=4),
        SegmentParams(refine=True, boundary_smoothing=True, clusters=0),
    ],
    ids=["graphcut", "metis", "refined"],
)
def test_a_tetrahedron_repeated_in_place_segments_like_one(params):
    """Every edge shared by 12k faces: the face graph, the neural ShDF's samples, its
    smoothing and the partitioners stay linear (all pairs would be 108M edges)."""
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    tetrahedron = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]])
    stack = TriangleMesh(vertices, np.tile(tetrahedron, (6000, 1)))
    assert len(stack.face_graph.pairs) <= 3 * stack.face_count
    shdf = pipeline.compute_shdf(stack, method="neural").values
    assert shdf.shape == (stack.face_count,) and np.isfinite(shdf).all()
    labels = pipeline.segment(stack, shdf, params).labels
    assert labels.shape == (stack.face_count,) and labels.min() >= 0
    if params.partitioner == "metis":
        assert len(np.unique(labels)) == 4
    again = pipeline.segment(stack, shdf, params).labels
    np.testing.assert_array_equal(labels, again)


def test_library_examples_run_as_written(tmp_path, monkeypatch, capsys):
    """The README's library example, then docs/library.md's, on a capsule saved as model.obj."""
    import trimesh

    from tests.doc_examples import python_blocks

    blocks = python_blocks("README.md", "Library") + python_blocks(
        "docs/library.md", "Several segmentations of one mesh"
    )
    assert len(blocks) == 2
    capsule = trimesh.creation.capsule(height=2.0, radius=0.4, count=[16, 16])
    (tmp_path / "model.obj").write_text(capsule.export(file_type="obj"))
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    for block in blocks:
        exec(block, namespace)  # noqa: S102
    assert len(namespace["per_input_face"]) == len(capsule.faces)
    assert len(capsys.readouterr().out.splitlines()) == 3


@pytest.mark.parametrize("seed", [0, 1])
def test_a_file_with_its_faces_and_vertices_in_another_order_gets_the_same_parts(psb_off, seed):
    """psb 21 (a cup) with its faces and vertices listed in another order: the same parts.
    Up to version 17 the graph cut summed costs in face order and placed coarse nodes at
    their first face by index, so the ties of its even walls fell apart another way (seed
    0: 2 parts against 3)."""
    mesh = load_mesh(psb_off(21))
    rng = np.random.default_rng(seed)
    face_order, vertex_order = rng.permutation(mesh.face_count), rng.permutation(len(mesh.vertices))
    new_vertex = np.argsort(vertex_order)
    reordered = TriangleMesh(mesh.vertices[vertex_order], new_vertex[mesh.faces[face_order]])
    given = pipeline.segment(mesh, pipeline.compute_shdf(mesh), SegmentParams()).labels
    other = pipeline.segment(reordered, pipeline.compute_shdf(reordered), SegmentParams()).labels
    pairs = set(zip(given[face_order].tolist(), other.tolist(), strict=True))
    assert len(pairs) == given.max() + 1 == other.max() + 1  # one part for one part
