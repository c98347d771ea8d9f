"""First-call cost of rigcal's compiled kernels, measured apart from their steady state.

A kernel compiles on its first call in a process unless numba's cache has it. Each
figure runs a fresh interpreter with an empty ``NUMBA_CACHE_DIR`` (cold: import +
compile + first call), then another with the cache that run filled (warm: import + load
+ first call), and subtracts the same interpreter's import of the module alone.

    .venv/bin/python benchmarks/jit_cost.py [LABEL-PART]
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile

KERNELS = {
    "P3P (rigcal.calib.p3p)": (
        "import numpy as np; from rigcal.calib.p3p import p3p",
        "p3p(np.eye(3)[None] + 0.1, np.eye(3)[None] * 2.0)",
    ),
    "P3P + Horn poses (rigcal.calib.p3p.p3p_poses, rigcal.calib.horn)": (
        "import numpy as np; from rigcal.calib.p3p import p3p_poses",
        "p3p_poses(np.eye(3)[None] + 0.1, np.eye(3)[None] * 2.0)",
    ),
    "ICP iterations and grid neighbours (rigcal.localize.icp, nearest)": (
        "import numpy as np; from rigcal.localize.icp import icp; "
        "t = np.linspace(0, 6, 200); m = np.vstack([np.c_[t, 0 * t + 1], np.c_[0 * t + 2, t - 3]])",
        "icp(m, m + 0.01, model_normals=np.tile([0.0, 1.0], (len(m), 1)))",
    ),
    "Line extraction, carrying lines, line fits (rigcal.calib.lines, localize.odometry)": (
        "import numpy as np; import rigcal.calib.lines_kernel; from rigcal.calib.lines import extract_lines; "
        "from rigcal.scan import Scan; "
        "from rigcal.localize.odometry import carry_labels; a = np.linspace(-1, 1, 400); "
        "s = Scan(a, 2 / np.cos(a), 0.1, 30.0); p = s.points; k = np.arange(400)",
        "extract_lines(s); carry_labels(p, 0 * k, None, np.zeros(3), p, k)",
    ),
    "Colour to grey as OpenCV reads PNGs (rigcal.io.images)": (
        "import numpy as np; from rigcal.io.images import rgb_to_grey; c = np.zeros((480, 640, 3), np.uint8)",
        "rgb_to_grey(c)",
    ),
}

_TIMED = """
import time
t0 = time.perf_counter()
{setup}
t1 = time.perf_counter()
{call}
t2 = time.perf_counter()
print(t1 - t0, t2 - t1)
"""


def first_call_seconds(setup: str, call: str, cache_dir: str) -> tuple[float, float]:
    """(import seconds, first-call seconds) in a fresh interpreter using ``cache_dir``."""
    env = dict(os.environ, NUMBA_CACHE_DIR=cache_dir)
    out = subprocess.run(
        [sys.executable, "-c", _TIMED.format(setup=setup, call=call)],
        env=env,
        check=True,
        capture_output=True,
        text=True,
    ).stdout.split()
    return float(out[0]), float(out[1])


def compile_table(kernels: dict[str, tuple[str, str]]) -> str:
    """Markdown rows: kernel, first call with an empty cache, with a filled cache."""
    lines = ["| kernel | first call, empty cache (s) | first call, cached (s) |", "|---|---|---|"]
    for label, (setup, call) in kernels.items():
        with tempfile.TemporaryDirectory() as cache:
            _, cold = first_call_seconds(setup, call, cache)
            _, warm = first_call_seconds(setup, call, cache)
        lines.append(f"| {label} | {cold:.2f} | {warm:.3f} |")
    return "\n".join(lines)


if __name__ == "__main__":
    # An argument keeps only the kernels whose label contains it.
    wanted = sys.argv[1] if len(sys.argv) > 1 else ""
    print(compile_table({k: v for k, v in KERNELS.items() if wanted in k}))
