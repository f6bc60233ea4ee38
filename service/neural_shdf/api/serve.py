"""``neural-shdf serve``: run the service with uvicorn."""

from __future__ import annotations

import copy
import os
import shutil
import tempfile
from typing import Any

import uvicorn
from uvicorn.config import LOGGING_CONFIG

from neural_shdf.api.settings import Settings


def log_config(level: str) -> dict[str, Any]:
    """uvicorn's logging set-up plus the package's loggers (``neural_shdf.*``): start-up and
    warm-up, job failures and cache faults reach the console in uvicorn's format."""
    config = copy.deepcopy(LOGGING_CONFIG)
    config["loggers"]["neural_shdf"] = {
        "handlers": ["default"],
        "level": level.upper(),
        "propagate": False,
    }
    return config


def run(host: str | None = None, port: int | None = None, workers: int | None = None) -> None:
    """Serve on settings from the environment (``NEURAL_SHDF_*``), overridden by the arguments."""
    settings = Settings()
    host = host or settings.host
    port = settings.port if port is None else port
    workers = workers or settings.workers
    # Workers re-read the settings from the environment; keep overrides consistent there.
    os.environ["NEURAL_SHDF_HOST"] = host
    os.environ["NEURAL_SHDF_PORT"] = str(port)
    metrics_dir = None
    if workers > 1 and not os.environ.get("PROMETHEUS_MULTIPROC_DIR"):
        # One /metrics for all workers (prometheus-client multiprocess mode); a fresh
        # directory per start, as that mode requires.
        metrics_dir = tempfile.mkdtemp(prefix="neural-shdf-metrics-")
        os.environ["PROMETHEUS_MULTIPROC_DIR"] = metrics_dir
    try:
        uvicorn.run(
            "neural_shdf.api.app:create_app_from_env",
            factory=True,
            host=host,
            port=port,
            workers=workers,
            log_level=settings.log_level,
            log_config=log_config(settings.log_level),
            timeout_graceful_shutdown=10,
        )
    finally:
        if metrics_dir is not None:
            shutil.rmtree(metrics_dir, ignore_errors=True)


if __name__ == "__main__":
    run()
