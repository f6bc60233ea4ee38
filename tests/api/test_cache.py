"""The cache: checksummed framing, disk LRU cap, Redis shared by two replicas."""

from __future__ import annotations

import numpy as np
import pytest
from fastapi.testclient import TestClient
from hypothesis import given, settings
from hypothesis import strategies as st

from neural_shdf.api.cache import (
    CorruptEntryError,
    DiskBackend,
    RedisBackend,
    ResultCache,
    decode_arrays,
    encode_arrays,
    seal,
    unseal,
)
from tests.api.api_helpers import TEST_METHOD, metric


@given(st.binary(max_size=512))
@settings(max_examples=50, deadline=None)
def test_seal_round_trip_and_any_change_is_detected(payload):
    blob = seal(payload)
    assert unseal(blob) == payload
    for index in {0, len(blob) // 2, len(blob) - 1}:
        damaged = bytearray(blob)
        damaged[index] ^= 0x01
        with pytest.raises(CorruptEntryError):
            unseal(bytes(damaged))
    with pytest.raises(CorruptEntryError):
        unseal(blob[:-1] if payload else blob[:10])


def test_arrays_round_trip_without_pickles():
    arrays = {"a": np.arange(5.0), "b": np.array(3), "c": np.zeros((2, 3), np.int32)}
    decoded = decode_arrays(encode_arrays(arrays))
    for name, value in arrays.items():
        np.testing.assert_array_equal(decoded[name], value)
        assert decoded[name].dtype == value.dtype
    with pytest.raises(CorruptEntryError):
        decode_arrays(b"PK\x03\x04 not really a zip")


def test_disk_cache_is_capped_with_lru_eviction(tmp_path):
    backend = DiskBackend(tmp_path / "c", size_limit=1024**2)
    cache = ResultCache(backend, memory_items=0)
    chunk = np.zeros(40_000, dtype=np.uint8)  # ~40 kB per entry, 100 entries
    cache.put_arrays("k0:x", {"v": chunk}, group="k0")
    for i in range(1, 100):
        cache.get_arrays("k0:x")  # keep the first entry recently used
        cache.put_arrays(f"k{i}:x", {"v": chunk}, group=f"k{i}")
    backend._cache.cull()
    assert backend._cache.volume() <= 1.5 * 1024**2
    assert cache.get_arrays("k0:x") is not None
    assert cache.get_arrays("k1:x") is None


def test_entries_survive_a_restart(tmp_path):
    first = ResultCache(DiskBackend(tmp_path / "c", 10 * 1024**2))
    first.put_json("m:meta", {"a": 1}, group="m")
    first.close()
    second = ResultCache(DiskBackend(tmp_path / "c", 10 * 1024**2))
    assert second.get_json("m:meta") == {"a": 1}
    assert second.delete_group("m") == 1 and second.get_json("m:meta") is None


def test_redis_backend_round_trip_lock_and_groups(redis_url):
    cache = ResultCache(RedisBackend(redis_url, 2.0, ttl_s=100), memory_items=0)
    assert cache.ping()
    cache.put_arrays("m1:shdf", {"shdf": np.linspace(0, 1, 7)}, group="m1")
    cache.put_json("m1:meta", {"faces": 7}, group="m1")
    np.testing.assert_array_equal(cache.get_arrays("m1:shdf")["shdf"], np.linspace(0, 1, 7))
    assert 0 < cache.backend._redis.ttl("neural-shdf:m1:meta") <= 100  # entries expire
    with cache.lock("m1:shdf", timeout=5):
        pass
    cache.backend.set("m1:bad", b"corrupt", group="m1")
    assert cache.get_json("m1:bad") is None and cache.backend.get("m1:bad") is None
    assert cache.delete_group("m1") == 2
    assert cache.get_json("m1:meta") is None


def test_replica_b_segments_what_replica_a_uploaded(app_factory, redis_url, capsule_obj, tmp_path):
    """Two app instances (replicas) share only the Redis URL; B never recomputes the ShDF."""
    replica_a = app_factory(redis_url=redis_url, cache_dir=tmp_path / "a")
    replica_b = app_factory(redis_url=redis_url, cache_dir=tmp_path / "b")
    with TestClient(replica_a) as a, TestClient(replica_b) as b:
        assert b.get("/readyz").json()["checks"]["cache"] == {"ok": True, "detail": "redis"}
        mesh_id = a.post("/v1/meshes", files={"file": ("m.obj", capsule_obj)}).json()["mesh"][
            "mesh_id"
        ]
        assert b.get(f"/v1/meshes/{mesh_id}").status_code == 200
        from_b = b.post("/v1/segment", json={"mesh_id": mesh_id, "clusters": 3})
        assert from_b.status_code == 200, from_b.text
        assert from_b.json()["timings"]["shdf_cached"] is True
        name = "neural_shdf_shdf_computations_total"
        assert metric(replica_a, name, method=TEST_METHOD) == 1
        assert metric(replica_b, name, method=TEST_METHOD) == 0
        # B's segmentation is cached for A as well; a deletion through A reaches B.
        from_a = a.post("/v1/segment", json={"mesh_id": mesh_id, "clusters": 3}).json()
        assert from_a["labels"] == from_b.json()["labels"]
        assert from_a["timings"]["segmentation_cached"] is True
        assert a.delete(f"/v1/meshes/{mesh_id}").status_code == 204
        # B's memory still holds the mesh and the segmentation: it must not serve them.
        assert b.get(f"/v1/meshes/{mesh_id}").status_code == 404
        gone = b.post("/v1/segment", json={"mesh_id": mesh_id, "clusters": 3})
        assert gone.status_code == 404
        other = b.post("/v1/segment", json={"mesh_id": mesh_id, "clusters": 2})
        assert other.status_code == 404
