"""Every setting of the REST service, read from the environment (prefix ``NEURAL_SHDF_``)."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import Field
from pydantic_settings import BaseSettings, SettingsConfigDict

from neural_shdf.constants import DEFAULT_MAX_FACES, DEFAULT_MAX_VERTICES
from neural_shdf.store.cache import CacheConfig

#: The store's defaults (batch workers share them): one source for both.
STORE = CacheConfig()


class Settings(BaseSettings):
    """Service configuration; each field is the env var ``NEURAL_SHDF_<NAME>``."""

    model_config = SettingsConfigDict(env_prefix="NEURAL_SHDF_", extra="ignore")

    host: str = Field("127.0.0.1", description="Interface `neural-shdf serve` binds to.")
    port: int = Field(8000, ge=0, le=65535, description="TCP port `neural-shdf serve` binds to.")
    workers: int = Field(1, ge=1, description="uvicorn worker processes.")
    log_level: str = Field("info", description="uvicorn log level.")

    cache_dir: Path = Field(STORE.cache_dir, description="Local disk cache directory.")
    cache_size_bytes: int = Field(
        STORE.cache_size_bytes,
        ge=1024**2,
        description="Disk cache size cap; least-recently-used eviction.",
    )
    redis_url: str | None = Field(
        STORE.redis_url,
        description="redis://host:port/db; when set, Redis replaces the disk cache.",
    )
    redis_timeout_s: float = Field(
        STORE.redis_timeout_s,
        gt=0,
        description="Redis socket timeout in seconds; one timeout opens the circuit breaker.",
    )
    redis_retry_s: float = Field(
        STORE.redis_retry_s,
        gt=0,
        description="While Redis is unreachable, how often it is probed again; meanwhile "
        "requests use the local disk cache (`CACHE_DIR`) without waiting on Redis.",
    )
    redis_ttl_s: float | None = Field(
        STORE.redis_ttl_s,
        gt=0,
        description="Expiry of Redis entries (refreshed on write); size Redis with "
        "maxmemory-policy allkeys-lru as well.",
    )
    memory_cache_items: int = Field(
        STORE.memory_cache_items,
        ge=0,
        description="Meshes, graphs and results kept in process memory (LRU).",
    )
    memory_working_set_bytes: int = Field(
        STORE.memory_working_set_bytes,
        ge=0,
        description="Bytes of segmentation working sets (per mesh, ShDF, clusters and seed: "
        "mixture, data costs, the graph cut's coarse graphs; about 45 MB per 100k faces) kept "
        "in process memory (LRU), so that a new smoothing or part count only re-cuts; 0 keeps "
        "none.",
    )

    default_method: Literal["auto", "exact", "sampled", "neural"] = Field(
        "auto",
        description="ShDF method used when a request names none (auto: the fastest "
        "producer that meets the fidelity target, per mesh).",
    )
    model: Path | None = Field(
        None,
        description="ONNX model of the neural ShDF (its card beside it, same stem, .json); "
        "default: the packaged emd.onnx. The library reads the same variable.",
    )

    max_upload_bytes: int = Field(
        128 * 1024**2,
        ge=1,
        description="Largest request body accepted (checked while reading). Text OBJ "
        "parsing peaks at about 13x the file size in memory; size workers accordingly.",
    )
    max_json_bytes: int = Field(
        64 * 1024,
        ge=1,
        description="Largest JSON request body accepted (a segmentation request is a few "
        "hundred bytes); JSON is parsed and validated on the event loop, so this bounds "
        "how long one request can hold it.",
    )
    max_labeler_bytes: int = Field(
        32 * 1024**2,
        ge=1,
        description="Largest part-labeller file accepted (`POST /v1/labelers`); its "
        "members may unpack to at most 256 MB (checked before they are read).",
    )
    max_train_meshes: int = Field(
        64,
        ge=1,
        description="Most meshes one labeller training (`POST /v1/labeler-trainings`) takes.",
    )
    max_train_triangles: int = Field(
        1_000_000,
        ge=1,
        description="Most triangles, all meshes together, one labeller training takes "
        "(about 1 s of features per 1,500-face mesh, plus its ShDF when not cached).",
    )
    max_faces: int = Field(
        DEFAULT_MAX_FACES,
        ge=1,
        description="Largest mesh accepted, in triangles (after triangulating polygons and "
        "expanding glTF instances; checked before they are made).",
    )
    max_vertices: int = Field(
        DEFAULT_MAX_VERTICES,
        ge=1,
        description="Largest mesh accepted, in vertices (glTF instances counted).",
    )
    sync_face_threshold: int = Field(
        50_000,
        ge=0,
        description="Meshes with more triangles than this are computed as a job (202).",
    )
    request_timeout_s: float = Field(
        120.0, gt=0, description="Longest a synchronous request waits for a computation."
    )
    body_read_timeout_s: float = Field(
        60.0, gt=0, description="Longest pause between two chunks of a request body (408)."
    )
    compute_threads: int = Field(2, ge=1, description="Threads running ShDF and segmentation.")
    compute_share: int | None = Field(
        None,
        ge=1,
        description="Computations one client (by address; background jobs count as one "
        "client) runs at once; its further requests wait for one of them to end. Default: "
        "all compute threads but one, so that no client can hold the whole pool. Behind a "
        "proxy, let uvicorn trust its forwarded address (FORWARDED_ALLOW_IPS).",
    )
    warm_up: bool = Field(
        True,
        description="At start-up, run a small mesh through every compiled path (kernels "
        "compiled or loaded from their cache, model session made) before serving.",
    )
    io_threads: int = Field(
        8, ge=1, description="Threads for cache I/O (never blocked by computations)."
    )
    job_ttl_s: int = Field(7 * 24 * 3600, ge=1, description="How long job records are kept.")
    lock_lease_s: float = Field(
        STORE.lock_lease_s,
        gt=0,
        description="Compute locks and running jobs are leases their worker renews every "
        "third of this; a crashed worker's lock lapses, and its job is re-run, after this long.",
    )
    lock_timeout_s: float = Field(
        STORE.lock_timeout_s,
        gt=0,
        description="Longest a computation waits for another live worker computing the same "
        "result before computing it too (seconds).",
    )
    job_max_attempts: int = Field(
        3,
        ge=1,
        description="Runs of a job whose worker keeps dying (crash, out of memory) before it "
        "is marked failed.",
    )

    viewer_three_url: str | None = Field(
        None,
        description="Base URL of the npm package `three` (the folder holding build/ and "
        "examples/) in the web viewer's import map. Default: the local copy at /viewer/three/ "
        "when one is installed (`npm ci` in neural_shdf/viewer, or `viewer_three_dir`), else "
        "the jsDelivr CDN at the version locked in the viewer's package.json.",
    )
    viewer_three_dir: Path | None = Field(
        None,
        description="Local copy of the npm package `three` served at /viewer/three/; default: "
        "node_modules/three in the viewer's folder when `npm ci` ran there.",
    )
