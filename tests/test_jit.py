"""rigcal.jit: compiled with numba, cached when possible, compiled per process otherwise."""

from __future__ import annotations

import numba
import numpy as np

from rigcal.jit import njit


def test_compiles_and_follows_numpy_on_division_by_zero():
    @njit
    def ratio(a: float, b: float) -> float:
        return a / b

    assert ratio(1.0, 4.0) == 0.25
    assert np.isinf(ratio(1.0, 0.0))  # numpy's error model, no ZeroDivisionError
    assert isinstance(ratio, numba.core.registry.CPUDispatcher)


def test_without_a_writable_cache_it_compiles_uncached(monkeypatch):
    real = numba.njit
    seen = []

    def njit_without_cache(**kwargs):
        seen.append(kwargs["cache"])
        if kwargs["cache"]:
            raise RuntimeError("cannot cache function: no locator available")
        return real(**kwargs)

    monkeypatch.setattr(numba, "njit", njit_without_cache)

    @njit
    def double(x: float) -> float:
        return 2.0 * x

    assert double(1.5) == 3.0
    assert seen == [True, False]
