"""The kernel decorator: compiled, GIL-free, cached where it can be."""

import numpy as np

from neural_shdf import compiled


def total(values):  # noqa: ANN001, ANN201
    out = 0.0
    for value in values:
        out += value
    return out


def test_kernel_compiles_and_computes():
    fast = compiled.kernel(total)
    values = np.arange(10.0)
    assert fast(values) == 45.0
    assert fast.targetoptions["nogil"] is True


def test_kernel_without_a_writable_cache_still_compiles(monkeypatch):
    real_njit = compiled.numba.njit

    def njit(*args, **options):  # noqa: ANN002, ANN003, ANN202
        if options.get("cache"):
            raise RuntimeError("cannot cache function: no locator available")
        return real_njit(*args, **options)

    monkeypatch.setattr(compiled.numba, "njit", njit)
    assert compiled.kernel(total)(np.ones(3)) == 3.0
