"""Unwrap from the client against a real uvicorn process whose every mesh is a job (the
ShDF's, then the atlas's): the UVs per corner, the GLB, the OBJ and the atlas PNG."""

from __future__ import annotations

import asyncio
import base64
import io
from collections.abc import Iterator

import numpy as np
import pytest
import trimesh

from neural_shdf.client import AsyncClient, Client, InvalidRequestError, UvLayout
from neural_shdf.mesh_io import load_mesh
from neural_shdf.unwrap import UnwrapParams, polygon_corner_uvs, unwrap
from tests.api.api_helpers import quad_dumbbell_obj
from tests.api.conftest import running_server

OPTIONS = {"clusters": 3, "atlas_size": 256}


@pytest.fixture(scope="module")
def job_service(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """Every mesh over 10 triangles answers 202 with a job."""
    with running_server(tmp_path_factory.mktemp("unwrap-cache"), sync_face_threshold=10) as base:
        yield base


def test_uvs_follow_the_files_polygons_and_match_the_library(job_service, tmp_path):
    data = quad_dumbbell_obj(rings=12, sectors=8)
    mesh = load_mesh(data, "obj")
    with Client(job_service, progress=False) as client:
        mesh_id = client.upload(data, file_type="obj").mesh_id  # a ShDF job, waited for
        layout = client.uvs(mesh_id, **OPTIONS)  # an atlas job, waited for
        labels = client.segment(mesh_id, clusters=3).labels
        glb = client.unwrapped_glb(mesh_id, **OPTIONS)
        obj = client.unwrapped_obj(mesh_id, **OPTIONS)
        png = client.atlas_png(mesh_id, **OPTIONS)
    assert layout.faces == mesh.input_face_count and layout.mesh_id == mesh_id
    assert layout.uvs.dtype == np.float32 and layout.uvs.shape == (layout.corners, 2)
    atlas = unwrap(mesh, labels, UnwrapParams(atlas_size=256))
    expected = polygon_corner_uvs(mesh, atlas.corner_uvs)
    assert np.array_equal(layout.corner_counts, expected.corner_counts)
    np.testing.assert_allclose(layout.uvs, expected.uvs, atol=1e-6)
    np.testing.assert_array_equal(np.asarray(layout.chart_part)[layout.chart], labels)
    last = mesh.input_face_count - 1
    np.testing.assert_allclose(layout.face_uvs(last), expected.uvs[-expected.corner_counts[-1] :])

    assert glb[:4] == b"glTF" and png[:8] == b"\x89PNG\r\n\x1a\n"
    loaded = trimesh.load(io.BytesIO(glb), file_type="glb", force="mesh", process=False)
    np.testing.assert_allclose(loaded.visual.uv[loaded.faces], atlas.corner_uvs, atol=1e-6)
    faces = [line for line in obj.decode().splitlines() if line.startswith("f ")]
    assert len(faces) == mesh.input_face_count + layout.split_faces


def test_async_client_and_errors(job_service):
    data = quad_dumbbell_obj(rings=8, sectors=6)

    async def fetch() -> tuple[UvLayout, bytes]:
        async with AsyncClient(job_service, progress=False) as client:
            mesh_id = (await client.upload(data, file_type="obj")).mesh_id
            return await asyncio.gather(
                client.uvs(mesh_id, **OPTIONS), client.atlas_png(mesh_id, **OPTIONS)
            )

    layout, png = asyncio.run(fetch())
    assert layout.corners == int(layout.corner_counts.sum()) and png[:4] == b"\x89PNG"
    with (
        Client(job_service, progress=False) as client,
        pytest.raises(InvalidRequestError, match="atlas_size"),
    ):
        client.uvs(layout.mesh_id, atlas_size=10)


def test_a_layout_that_does_not_add_up_is_refused():
    counts = base64.b64encode(np.array([3, 3], "<i4").tobytes()).decode()
    uvs = base64.b64encode(np.zeros((5, 2), "<f4").tobytes()).decode()
    body = {
        "mesh_id": "0" * 64, "faces": 2, "corners": 6, "corner_counts_base64": counts,
        "uvs_base64": uvs, "chart_base64": counts, "chart_part": [0], "width": 64,
        "height": 64, "utilization": 0.5, "split_faces": 0,
    }  # fmt: skip
    with pytest.raises(ValueError, match="5 UVs for 6 corners"):
        UvLayout.from_json(body)


def test_unwrap_example_runs_as_written(job_service, tmp_path, monkeypatch):
    """docs/client.md's unwrap example, against the live service and a mesh as model.obj."""
    from tests.doc_examples import python_blocks

    (block,) = python_blocks("docs/client.md", "Unwrap")
    (tmp_path / "model.obj").write_bytes(quad_dumbbell_obj(rings=8, sectors=6))
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    exec(block.replace("http://127.0.0.1:8000", job_service), namespace)  # noqa: S102
    layout = namespace["layout"]
    assert len(namespace["part_of_face"]) == layout.faces
    assert (tmp_path / "atlas.png").read_bytes()[:4] == b"\x89PNG"
    assert (tmp_path / "unwrapped.glb").read_bytes()[:4] == b"glTF"
    assert (tmp_path / "unwrapped.obj").read_text().count("\nf ") >= layout.faces
