"""Timing shared by the benchmark scripts: best wall and CPU time of repeated calls."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TypeVar

Result = TypeVar("Result")


def best_time(function: Callable[[], Result], repeat: int) -> tuple[float, float, Result]:
    """(best wall seconds, best CPU seconds, last result) of ``repeat`` calls (at least one).

    CPU time is printed beside wall time because on a shared, oversubscribed machine wall
    time mostly measures waiting for a core.
    """
    wall, cpu, result = float("inf"), float("inf"), None
    for _ in range(max(1, repeat)):
        start, start_cpu = time.perf_counter(), time.process_time()
        result = function()
        wall = min(wall, time.perf_counter() - start)
        cpu = min(cpu, time.process_time() - start_cpu)
    return wall, cpu, result  # type: ignore[return-value]
