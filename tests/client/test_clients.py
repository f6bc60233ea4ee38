"""Client and AsyncClient against a real uvicorn process (`python -m neural_shdf.api.serve`)."""

from __future__ import annotations

import asyncio
import hashlib

import httpx
import numpy as np
import pytest
import trimesh

from neural_shdf.client import (
    AsyncClient,
    Client,
    InvalidRequestError,
    NotFoundError,
    PayloadTooLargeError,
    ServiceTimeoutError,
    ServiceUnavailableError,
    UnsupportedMediaError,
)
from neural_shdf.mesh_io import load_mesh, load_source
from neural_shdf.segment.synthetic import dumbbell
from tests.api.api_helpers import TEST_METHOD, capsule, free_port, obj_bytes, quad_box
from tests.exchange.scene_helpers import textured_scene_glb


def two_boxes_obj() -> bytes:
    """Two quad cubes (6 + 6 polygons) as OBJ: labels come back one per polygon."""
    left, left_quads = quad_box((-2.0, 0.0, 0.0), 1.0)
    right, right_quads = quad_box((2.0, 0.0, 0.0), 1.0)
    quads = left_quads + [[i + len(left) for i in quad] for quad in right_quads]
    return obj_bytes(np.concatenate([left, right]), quads)


def requests_with_status(base: str, route: str, status: int, method: str = "POST") -> float:
    line = f'neural_shdf_http_requests_total{{method="{method}",route="{route}",status="{status}"}}'
    for text in httpx.get(f"{base}/metrics").text.splitlines():
        if text.startswith(line):
            return float(text.split()[-1])
    return 0.0


def test_upload_segment_and_shdf_match_the_raw_api(service, tmp_path):
    path = tmp_path / "capsule.obj"
    path.write_bytes(capsule().export(file_type="obj").encode())
    faces = load_mesh(path).input_face_count
    with Client(service) as client:
        assert client.health() and client.ready()["status"] == "ready"
        uploaded = client.upload(path)
        assert uploaded.mesh.faces == faces and uploaded.shdf.method == TEST_METHOD
        result = client.segment(uploaded.mesh_id, clusters=3, smoothing=0.2)
        shdf = client.shdf(uploaded.mesh_id)
        info = client.mesh(uploaded.mesh_id)
    raw = httpx.post(
        f"{service}/v1/segment",
        json={"mesh_id": uploaded.mesh_id, "clusters": 3, "smoothing": 0.2},
        timeout=60,
    ).json()
    assert result.labels.dtype == np.int32 and result.labels.tolist() == raw["labels"]
    assert result.part_count == raw["part_count"] == len(np.unique(result.labels))
    assert [p.faces for p in result.parts] == np.bincount(result.labels).tolist()
    assert result.timings.shdf_cached
    raw_shdf = httpx.get(f"{service}/v1/meshes/{uploaded.mesh_id}/shdf", timeout=60).json()
    assert shdf.dtype == np.float32 and len(shdf) == faces
    np.testing.assert_allclose(shdf, np.array(raw_shdf["values"], dtype=np.float32), rtol=1e-6)
    assert uploaded.mesh.filename == "capsule.obj"
    assert info.mesh_id == uploaded.mesh_id and info.filename is None  # per upload, not kept


def test_part_tree_gives_the_services_labels_for_any_part_count(service, tmp_path):
    path = tmp_path / "dumbbell.obj"
    path.write_bytes(dumbbell(3000)[0].export(file_type="obj").encode())
    with Client(service) as client:
        mesh_id = client.upload(path).mesh_id
        automatic = client.segment(mesh_id, clusters=8, smoothing=0.0)
        tree = automatic.hierarchy
        assert tree is not None and "hierarchy" not in automatic.extra
        assert tree.leaf_count >= 4 and tree.parts == automatic.part_count
        assert len(tree.leaf_labels) == len(automatic.labels) and tree.leaf_labels.dtype == np.int32
        assert (
            len(tree.parent) == 2 * tree.leaf_count - 1
            and len(tree.merge_cost) == tree.leaf_count - 1
        )
        assert np.all(np.diff(tree.merge_height) >= 0)
        np.testing.assert_array_equal(tree.labels(), automatic.labels)  # None: automatic
        assert tree.parts == tree.automatic_parts
        counts = sorted({1, 2, 3, tree.leaf_count // 2, tree.leaf_count, tree.leaf_count + 5})
        for count in counts:
            asked = client.segment(mesh_id, clusters=8, smoothing=0.0, parts=count)
            assert asked.hierarchy is not None and asked.hierarchy.parts == asked.part_count
            np.testing.assert_array_equal(asked.hierarchy.parent, tree.parent)
            labels = tree.labels(count)
            assert labels.dtype == np.int32
            np.testing.assert_array_equal(labels, asked.labels, err_msg=f"{count} parts")
        assert client.segment(mesh_id, partitioner="metis", parts=3).hierarchy is None


def test_segment_file_bytes_polygons_and_glb_downloads(service):
    data = two_boxes_obj()
    with Client(service) as client:
        result = client.segment_file(data, file_type="obj", partitioner="metis", parts=2)
        assert len(result.labels) == 12  # one label per quad, in file order
        assert result.part_count == 2
        assert set(result.labels[:6].tolist()) != set(result.labels[6:].tolist())
        again = client.segment(result.mesh_id, partitioner="metis", parts=2)
        assert again.labels.tolist() == result.labels.tolist()
        assert again.timings.segmentation_cached
        colored = client.colored_glb(result.mesh_id, partitioner="metis", parts=2)
        parts = client.parts_glb(result.mesh_id, partitioner="metis", parts=2, refine=False)
    assert colored[:4] == b"glTF" and parts[:4] == b"glTF"
    scene = trimesh.load(trimesh.util.wrap_as_stream(parts), file_type="glb")
    assert len(scene.geometry) == 2


def test_segment_file_source_gives_parts_glb_and_parts_usda_of_the_users_file(service, tmp_path):
    """segment_file answers the upload's source_id; parts_glb and parts_usda (sync and
    async) with it give the file's own materials and stage, without it the stored faces."""
    from pxr import Usd, UsdGeom, UsdUtils

    from neural_shdf.exchange.gltf_writer import parts_glb
    from tests.exchange.test_usd import _material_stage

    package = tmp_path / "materials.usdz"
    assert UsdUtils.CreateNewUsdzPackage(str(_material_stage(tmp_path)), str(package))
    data = package.read_bytes()
    options = {"partitioner": "metis", "parts": 3}
    with Client(service) as client:
        result = client.segment_file(package, **options)
        assert result.source_id == hashlib.sha256(b"usdz\0" + data).hexdigest()
        glb = client.parts_glb(result.mesh_id, source=result.source_id, **options)
        usda = client.parts_usda(result.mesh_id, source=result.source_id, **options)
        plain_usda = client.parts_usda(result.mesh_id, **options)
    source = load_source(data, "usdz")
    labels = result.labels[source.mesh.face_origin].astype(np.int64)
    assert glb == parts_glb(source.mesh, labels, attributes=source.attributes)

    async def scenario() -> tuple[bytes, bytes]:
        async with AsyncClient(service) as client:
            glb = await client.parts_glb(result.mesh_id, source=result.source_id, **options)
            usda = await client.parts_usda(result.mesh_id, source=result.source_id, **options)
            return glb, usda

    assert asyncio.run(scenario()) == (glb, usda)
    (tmp_path / "parts.usda").write_bytes(usda)
    (tmp_path / "plain.usda").write_bytes(plain_usda)
    stage = Usd.Stage.Open(str(tmp_path / "parts.usda"))
    assert stage.GetPrimAtPath("/World/Looks/Wood")  # the file's own stage
    offset = 0
    for path in ("/World/Box", "/World/Plain", "/World/Bare"):
        mesh = UsdGeom.Mesh.Get(stage, path)
        count = len(mesh.GetFaceVertexCountsAttr().Get())
        subsets = UsdGeom.Subset.GetGeomSubsets(mesh, UsdGeom.Tokens.face, "part")
        own = result.labels[offset : offset + count]
        found = {s.GetPrim().GetName(): list(s.GetIndicesAttr().Get()) for s in subsets}
        assert found == {f"part_{k:03d}": np.flatnonzero(own == k).tolist() for k in np.unique(own)}
        offset += count
    plain = Usd.Stage.Open(str(tmp_path / "plain.usda"))
    assert [p.GetPath().pathString for p in plain.Traverse() if p.IsA(UsdGeom.Mesh)] == [
        "/World/Mesh"
    ]


def test_errors_carry_the_services_code_and_message(service):
    with Client(service) as client:
        with pytest.raises(UnsupportedMediaError) as unsupported:
            client.upload(b"hello", file_type="xyz")
        assert unsupported.value.status == 415
        assert unsupported.value.code == "unsupported_format"
        assert "unsupported mesh format 'xyz'" in str(unsupported.value)
        with pytest.raises(InvalidRequestError) as invalid:
            client.upload(b"v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n", file_type="obj")
        assert invalid.value.status == 422 and "area" in invalid.value.message
        mesh_id = client.upload(capsule().export(file_type="obj").encode(), file_type="obj")
        with pytest.raises(InvalidRequestError) as bad_parameter:
            client.segment(mesh_id.mesh_id, clusters=-1)
        assert bad_parameter.value.code == "invalid_parameter"
        assert "clusters must be an integer" in str(bad_parameter.value)
        client.delete(mesh_id.mesh_id)
        with pytest.raises(NotFoundError, match="upload it again") as missing:
            client.segment(mesh_id.mesh_id)
        assert missing.value.code == "mesh_not_found"
        with pytest.raises(PayloadTooLargeError, match="exceeds the limit"):
            client.upload(b"v 0 0 0\n" * 300_000, file_type="obj")


def test_large_mesh_waits_for_its_job_with_a_progress_bar(service, capsys):
    sphere = trimesh.creation.icosphere(subdivisions=6)  # 81920 triangles: a job (202)
    data = sphere.export(file_type="ply")
    with Client(service, progress=True) as client:
        result = client.segment_file(data, file_type="ply", clusters=2)
        uploaded = client.upload(data, file_type="ply")  # now cached: answered at once
    assert len(result.labels) == len(sphere.faces)
    assert uploaded.mesh_id == result.mesh_id and uploaded.shdf.cached
    # Answered 202 first: the upload's file is still named (the 202's X-Source-Id).
    assert (
        result.source_id == uploaded.mesh.source_id == hashlib.sha256(b"ply\0" + data).hexdigest()
    )
    assert f"ShDF ({TEST_METHOD})" in capsys.readouterr().err


def test_async_client_runs_concurrent_segmentations(service):
    data = capsule(16).export(file_type="stl")

    async def scenario() -> tuple[list, np.ndarray]:
        async with AsyncClient(service) as client:
            uploaded = await client.upload(data, file_type="stl")
            results = await asyncio.gather(
                *[client.segment(uploaded.mesh_id, clusters=k) for k in (2, 3, 4)]
            )
            return results, await client.shdf(uploaded.mesh_id)

    results, shdf = asyncio.run(scenario())
    with Client(service) as client:
        for clusters, result in zip((2, 3, 4), results, strict=True):
            expected = client.segment(result.mesh_id, clusters=clusters)
            assert result.labels.tolist() == expected.labels.tolist()
        assert np.array_equal(shdf, client.shdf(results[0].mesh_id))


def test_503_is_retried_then_raised_with_the_services_message(failing_service):
    data = capsule().export(file_type="obj").encode()
    before = {s: requests_with_status(failing_service, "/v1/meshes", s) for s in (503, 504)}
    client = Client(failing_service, retries=2, backoff_s=0.01)
    with client, pytest.raises(ServiceUnavailableError) as unavailable:
        client.upload(data, file_type="obj", method="neural")
    assert unavailable.value.code == "model_unavailable"
    assert "emd.onnx" in unavailable.value.message
    # Three attempts; the first may outlive the 0.05 s timeout (504) before the model is tried.
    after = {s: requests_with_status(failing_service, "/v1/meshes", s) for s in (503, 504)}
    assert after[503] > before[503]
    assert sum(after.values()) == sum(before.values()) + 3


def test_504_is_retried_until_the_background_computation_is_cached(failing_service):
    data = trimesh.creation.icosphere(subdivisions=5).export(file_type="ply")  # 20k faces
    before = requests_with_status(failing_service, "/v1/meshes", 504)
    with Client(failing_service, retries=8, backoff_s=0.2) as client:
        uploaded = client.upload(data, file_type="ply", method="exact")
    # The first attempts outlive the 0.05 s request timeout (504); the computation goes on in
    # the background and a later attempt gets its result.
    assert requests_with_status(failing_service, "/v1/meshes", 504) > before
    assert uploaded.mesh.faces == 20480 and uploaded.shdf.method == "exact"


def test_timeouts_and_refused_connections_raise_after_retries(failing_service):
    data = trimesh.creation.icosphere(subdivisions=5, radius=2.0).export(file_type="ply")
    client = Client(failing_service, timeout=0.001, retries=1, backoff_s=0.01)
    with client, pytest.raises(ServiceTimeoutError):
        client.upload(data, file_type="ply")
    nowhere = f"http://127.0.0.1:{free_port()}"
    client = Client(nowhere, retries=1, backoff_s=0.01)
    with client, pytest.raises(ServiceUnavailableError, match="cannot reach") as refused:
        client.health()
    assert refused.value.code == "unreachable" and refused.value.status == 0


def test_client_examples_run_as_written(service, tmp_path, monkeypatch, capsys):
    """docs/client.md's examples, against the live service and a capsule as model.obj."""
    from tests.doc_examples import python_blocks

    blocks = python_blocks("docs/client.md", "Python client")
    assert len(blocks) == 2
    (tmp_path / "model.obj").write_bytes(capsule().export(file_type="obj").encode())
    (tmp_path / "scene.glb").write_bytes(textured_scene_glb())
    monkeypatch.chdir(tmp_path)
    owns = []
    for block in blocks:
        namespace: dict = {}
        exec(block.replace("http://127.0.0.1:8000", service), namespace)  # noqa: S102
        owns.append(namespace.get("own"))
        if "own_usd" in namespace:  # segment_file's source_id: parts_usda of the scene
            assert namespace["shot"].source_id == namespace["scene"].mesh.source_id
            assert namespace["own_usd"].startswith(b"#usda")
    assert "invalid_parameter" in capsys.readouterr().out
    assert (tmp_path / "parts.glb").read_bytes()[:4] == b"glTF"
    own = load_source(owns[0], "glb").attributes  # the scene's parts keep its attributes
    assert own is not None and own.normals is not None and len(own.uvs) == 2
    results = asyncio.run(namespace["sweep"]("model.obj"))
    assert [len(r.labels) for r in results] == [
        load_mesh(tmp_path / "model.obj").input_face_count
    ] * 3


def test_segment_with_edits_matches_the_local_edit_of_the_tree(service):
    from neural_shdf.client import edits

    with Client(service) as client:
        mesh_id = client.upload(capsule().export(file_type="obj").encode(), file_type="obj").mesh_id
        plain = client.segment(mesh_id, smoothing=0.02, parts=3)
        faces = len(plain.labels)
        target = faces // 2
        # Two faces outside the target's part, so that the paint changes the labels
        # whichever three parts the segmentation found.
        outside = np.flatnonzero(plain.labels != plain.labels[target])[-2:].tolist()
        document = [
            edits.shrink(0),
            edits.merge(0, faces - 1),
            edits.paint(outside, to_face=target),
        ]
        edited = client.segment(mesh_id, smoothing=0.02, parts=3, edits=document)
        with pytest.raises(InvalidRequestError, match="out of range"):
            client.segment(mesh_id, edits=[edits.grow(faces)])
    assert plain.hierarchy is not None
    local = plain.hierarchy.edited(document)
    assert edited.labels.tolist() == local.tolist() != plain.labels.tolist()
    assert edited.part_count == int(local.max()) + 1


def test_part_editing_example_runs_as_written(service, tmp_path, monkeypatch):
    """docs/part-editing.md's example, against the live service and a capsule as model.obj."""
    from tests.doc_examples import python_blocks

    (block,) = python_blocks("docs/part-editing.md", "Python")
    (tmp_path / "model.obj").write_bytes(capsule().export(file_type="obj").encode())
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    exec(block.replace("http://127.0.0.1:8000", service), namespace)  # noqa: S102
    assert namespace["edited"].labels.tolist() != namespace["plain"].labels.tolist()


def test_named_parts_upload_train_segment_and_delete_a_labeler(service):
    from neural_shdf.labeling import label_mesh, load_labeler
    from neural_shdf.pipeline import compute_shdf
    from tests.labeling.helpers import BALL, NECK, labelled_dumbbell, obj_of, small_labeler_file

    data = small_labeler_file()
    target, truth = labelled_dumbbell(1500, 0.9, 3)
    with Client(service, progress=False) as client:
        info = client.upload_labeler(data)
        assert (info.label_names, info.label_values) == (["neck", "ball"], [NECK, BALL])
        assert info.labeler_id in [entry.labeler_id for entry in client.labelers()]
        assert client.labeler(info.labeler_id) == info
        assert client.labeler_file(info.labeler_id) == data
        mesh_id = client.upload(obj_of(target), file_type="obj").mesh_id
        named = client.segment(mesh_id, labeler_id=info.labeler_id)
        assert named.labeler_id == info.labeler_id and named.hierarchy is None
        assert named.names == {NECK: "neck", BALL: "ball"}
        mesh = load_mesh(obj_of(target), "obj")
        expected, confidence = label_mesh(
            mesh, load_labeler(data), shdf=compute_shdf(mesh, method=TEST_METHOD).values
        )
        np.testing.assert_array_equal(named.labels, expected)
        assert named.confidence is not None and named.confidence.dtype == np.float32
        np.testing.assert_allclose(named.confidence, confidence, atol=1e-6)
        assert {part.name for part in named.parts} == {"neck", "ball"}
        assert named.face_names()[int(np.argmax(truth == BALL))] == "ball"
        assert b'"name":"neck"' in client.parts_glb(mesh_id, labeler_id=info.labeler_id)
        # Trained on the service from stored meshes, then used the same way.
        examples = [labelled_dumbbell(1500, s, seed) for s, seed in ((1.0, None), (1.2, 5))]
        ids = [client.upload(obj_of(m), file_type="obj").mesh_id for m, _ in examples]
        trained = client.train_labeler(ids, [labels for _, labels in examples], names=["n", "b"])
        assert trained.label_names == ["n", "b"] and trained.training_meshes == 2
        again = client.segment(mesh_id, labeler_id=trained.labeler_id)
        assert np.mean(again.labels == truth) > 0.95
        with pytest.raises(InvalidRequestError, match="labels for meshes of"):
            client.train_labeler(ids[:1], [examples[0][1][:-1]])
        with pytest.raises(ValueError, match="comma"):
            client.train_labeler(ids, [labels for _, labels in examples], names=["a,b", "c"])
        client.delete_labeler(info.labeler_id)
        with pytest.raises(NotFoundError, match="labeler"):
            client.segment(mesh_id, labeler_id=info.labeler_id)

    async def asynchronous() -> None:
        async with AsyncClient(service, progress=False) as client:
            stored = await client.upload_labeler(data)
            assert [e.labeler_id for e in await client.labelers()].count(stored.labeler_id) == 1
            named = await client.segment(mesh_id, labeler_id=stored.labeler_id)
            np.testing.assert_array_equal(named.labels, expected)
            await client.delete_labeler(stored.labeler_id)

    asyncio.run(asynchronous())


def test_named_parts_example_runs_as_written(service, tmp_path, monkeypatch, capsys):
    """docs/client.md's named-parts example, with a dumbbell labeller and dumbbells."""
    from neural_shdf.labeling import load_labeler
    from tests.doc_examples import python_blocks
    from tests.labeling.helpers import labelled_dumbbell, obj_of, small_labeler_file

    (block,) = python_blocks("docs/client.md", "Named parts")
    (tmp_path / "parts.npz").write_bytes(small_labeler_file())
    (tmp_path / "model.obj").write_bytes(obj_of(labelled_dumbbell(1500, 0.9, 3)[0]))
    for name, stretch, seed in (("a", 1.0, None), ("b", 1.2, 5)):
        mesh, labels = labelled_dumbbell(1500, stretch, seed)
        (tmp_path / f"{name}.obj").write_bytes(obj_of(mesh))
        (tmp_path / f"{name}.txt").write_text("\n".join(map(str, labels)) + "\n")
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    exec(block.replace("http://127.0.0.1:8000", service), namespace)  # noqa: S102
    assert "['neck', 'ball']" in capsys.readouterr().out
    assert len(namespace["named"].labels) == len(namespace["named"].confidence)
    assert b'"name":"ball"' in namespace["parts_glb"]
    assert load_labeler(tmp_path / "learnt.npz").label_names == ("neck", "ball")
