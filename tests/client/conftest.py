"""Real `neural-shdf serve` processes for the client tests."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from tests.api.conftest import running_server


@pytest.fixture(scope="module")
def service(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """The service with its test settings (jobs above 50k triangles)."""
    with running_server(tmp_path_factory.mktemp("client-cache")) as base:
        yield base


@pytest.fixture(scope="module")
def failing_service(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """A service whose neural model is missing (503) and whose computations outlive its
    request timeout (504, then cached for a retry)."""
    missing = tmp_path_factory.mktemp("no-model") / "emd.onnx"
    with running_server(
        tmp_path_factory.mktemp("failing-cache"),
        default_method="exact",
        model=missing,
        request_timeout_s=0.05,
        warm_up="false",
    ) as base:
        yield base
