"""Fixtures of the API tests: apps on temp caches, a real uvicorn process (and the store's
real Redis)."""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import httpx
import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient

from neural_shdf.api.app import create_app
from tests.api.api_helpers import TEST_METHOD, capsule, free_port, make_settings
from tests.store.conftest import redis_server, redis_url, wait_for_port  # noqa: F401 - fixtures


@pytest.fixture
def app_factory(tmp_path: Path) -> Callable[..., FastAPI]:
    """Build apps on a per-test temp cache: ``app_factory(sync_face_threshold=10)``."""

    def build(**overrides) -> FastAPI:
        overrides.setdefault("cache_dir", tmp_path / "cache")
        return create_app(make_settings(**overrides))

    return build


@pytest.fixture
def client(app_factory) -> Iterator[TestClient]:
    with TestClient(app_factory()) as test_client:
        yield test_client


@pytest.fixture(scope="session")
def capsule_obj() -> bytes:
    """A 288-face capsule as OBJ."""
    return capsule().export(file_type="obj").encode()


@contextlib.contextmanager
def running_server(
    cache_dir: Path,
    workers: int = 1,
    port: int | None = None,
    log_file: Path | None = None,
    **settings: object,
) -> Iterator[str]:
    """`python -m neural_shdf.api.serve` on a free (or the given) loopback port; yields its
    base URL.

    ``log_file``: where the server's stderr (its log) goes; ``settings``: further service
    settings by name (``request_timeout_s=0.05``)."""
    port = port or free_port()
    env = dict(os.environ)
    env.update(
        NEURAL_SHDF_HOST="127.0.0.1",
        NEURAL_SHDF_PORT=str(port),
        NEURAL_SHDF_WORKERS=str(workers),
        NEURAL_SHDF_CACHE_DIR=str(cache_dir),
        NEURAL_SHDF_DEFAULT_METHOD=TEST_METHOD,
        NEURAL_SHDF_MAX_UPLOAD_BYTES=str(2_000_000),
        NEURAL_SHDF_LOG_LEVEL="warning",
    )
    env.update({f"NEURAL_SHDF_{name.upper()}": str(value) for name, value in settings.items()})
    env.pop("NEURAL_SHDF_REDIS_URL", None)
    env.pop("PROMETHEUS_MULTIPROC_DIR", None)
    log = open(log_file, "wb") if log_file else None  # noqa: SIM115 - closed below
    command = [sys.executable, "-m", "neural_shdf.api.serve"]
    process = subprocess.Popen(command, env=env, stderr=log)
    base = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 180  # start-up under a loaded CI machine
        while True:
            if process.poll() is not None:
                raise RuntimeError(f"server exited with {process.returncode}")
            try:
                if httpx.get(f"{base}/healthz", timeout=1).status_code == 200:
                    break
            except httpx.HTTPError:
                pass
            if time.monotonic() > deadline:
                raise RuntimeError("server did not become healthy")
            time.sleep(0.1)
        yield base
    finally:
        if process.poll() is None:
            process.terminate()
            try:  # uvicorn lets requests in flight finish for up to 10 s
                process.wait(timeout=30)
            except subprocess.TimeoutExpired:  # report it, without leaving the server running
                process.kill()
                process.wait()
                raise
        if log is not None:
            log.close()


@pytest.fixture(scope="module")
def uvicorn_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """One uvicorn worker on loopback."""
    with running_server(tmp_path_factory.mktemp("server-cache")) as base:
        yield base


@pytest.fixture(scope="module")
def two_worker_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """Two uvicorn worker processes sharing one disk cache."""
    with running_server(tmp_path_factory.mktemp("server-cache"), workers=2) as base:
        yield base
