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


def test_a_compile_logs_one_note_line_and_a_cached_load_none(tmp_path):
    """Two fresh processes share one empty cache: the first compiles the kernel (and the
    kernel it calls, within the same line), the second loads it and says nothing."""
    import os
    import subprocess
    import sys

    (tmp_path / "probe.py").write_text(
        "from rigcal.jit import njit\n"
        "def _inner(x):\n    return x + 1.0\n"
        "inner = njit(_inner)\n"
        "def _outer(x):\n    return 2.0 * inner(x)\n"
        "outer = njit(_outer)\n"
    )
    script = (
        "from rigcal.cli.progress import configure; configure(0, False)\n"
        "import probe; assert probe.outer(1.0) == 4.0\n"
        "import numba; numba.njit(lambda x: x)(1.0)\n"  # not made by rigcal.jit.njit: not reported
        "from rigcal.jit import COMPILED; print(len(COMPILED))\n"
    )
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"), PYTHONPATH=str(tmp_path))

    def run() -> subprocess.CompletedProcess[str]:
        out = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True)
        assert out.returncode == 0, out.stderr
        return out

    first = run()
    lines = [x for x in first.stderr.splitlines() if x.startswith("NOTE: rigcal.jit: ")]
    assert len(lines) == 1, first.stderr
    assert "compiled probe._outer on first use in " in lines[0]
    assert f"cached in {tmp_path / 'cache'}" in lines[0]
    assert first.stdout.strip() == "1"
    second = run()
    assert "rigcal.jit" not in second.stderr
    assert second.stdout.strip() == "0"
    # -q (the error level) keeps a compile quiet
    quiet = subprocess.run(
        [sys.executable, "-c", script.replace("configure(0, False)", "configure(0, True)")],
        env=dict(env, NUMBA_CACHE_DIR=str(tmp_path / "cache2")),
        capture_output=True,
        text=True,
        check=True,
    )
    assert "rigcal.jit" not in quiet.stderr
    assert quiet.stdout.strip() == "1"
