"""A batch run with ``cache=`` the service's Redis: the service then computes no ShDF."""

from __future__ import annotations

from pathlib import Path

from fastapi.testclient import TestClient

from neural_shdf.api.app import create_app
from neural_shdf.batch import run_batch
from tests.api.api_helpers import TEST_METHOD, make_settings
from tests.test_batch import _library, _outputs


def test_batch_and_service_share_the_shdf_through_redis(redis_url: str, tmp_path: Path):
    _library(tmp_path / "in", 2)
    first = run_batch([tmp_path / "in"], tmp_path / "a", method=TEST_METHOD, cache=redis_url,
                      workers=0)  # fmt: skip
    assert [r["shdf_cached"] for r in first] == [False, False]
    again = run_batch([tmp_path / "in"], tmp_path / "b", method=TEST_METHOD, cache=redis_url,
                      workers=2)  # fmt: skip
    assert [r["shdf_cached"] for r in again] == [True, True]
    assert _outputs(tmp_path / "b") == _outputs(tmp_path / "a")
    # The service finds the batch's ShDF under the mesh's id: it computes nothing.
    app = create_app(make_settings(tmp_path / "cache", redis_url=redis_url, warm_up=False))
    with TestClient(app) as client:
        mesh = Path(first[0]["path"])
        upload = client.post("/v1/meshes", files={"file": (mesh.name, mesh.read_bytes())})
        assert upload.status_code == 200, upload.text
        assert upload.json()["mesh"]["mesh_id"] == first[0]["mesh_id"]
        assert upload.json()["shdf"]["cached"] is True
        segment = client.post("/v1/segment", json={"mesh_id": first[0]["mesh_id"]})
        assert segment.status_code == 200, segment.text
        assert segment.json()["timings"]["shdf_cached"] is True
        labels = [
            int(x) for x in (tmp_path / "a" / f"{first[0]['output']}.seg").read_text().split()
        ]
        assert segment.json()["labels"] == labels
