"""First-call cost of rigcal's compiled kernels, measured apart from their steady state.

A kernel compiles on its first call in a process unless numba's cache has it. Each
figure runs a fresh interpreter with an empty ``NUMBA_CACHE_DIR`` (cold: import +
compile + first call), then another with the cache that run filled (warm: import + load
+ first call), and subtracts the same interpreter's import of the module alone.

    .venv/bin/python benchmarks/jit_cost.py [LABEL-PART]
    .venv/bin/python benchmarks/jit_cost.py --localize [DURATION-S]
    .venv/bin/python benchmarks/jit_cost.py --warm-up

``--localize`` times what a user meets: ``rigcal localize --method icp`` on a simulated
corridor drive (40 s by default, scans only), run twice in fresh processes sharing one
cache that starts empty: the first run compiles, the second loads. It prints the ICP
figure localize reports (its ``total_s``: the laser odometry) and the whole command's
wall time of both runs, and the kernels the first run said it compiled.

``--warm-up`` times ``rigcal warm-up`` the same way: with an empty cache (it compiles
every kernel) and again (it loads them and prints nothing), wall and CPU seconds.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile

KERNELS = {
    "P3P (rigcal.calib.box.p3p)": (
        "import numpy as np; from rigcal.calib.box.p3p import p3p",
        "p3p(np.eye(3)[None] + 0.1, np.eye(3)[None] * 2.0)",
    ),
    "P3P + Horn poses (rigcal.calib.box.p3p.p3p_poses, rigcal.calib.box.horn)": (
        "import numpy as np; from rigcal.calib.box.p3p import p3p_poses",
        "p3p_poses(np.eye(3)[None] + 0.1, np.eye(3)[None] * 2.0)",
    ),
    "ICP iterations and grid neighbours (rigcal.localize.icp, nearest)": (
        "import numpy as np; from rigcal.localize.icp import icp; "
        "t = np.linspace(0, 6, 200); m = np.vstack([np.c_[t, 0 * t + 1], np.c_[0 * t + 2, t - 3]])",
        "icp(m, m + 0.01, model_normals=np.tile([0.0, 1.0], (len(m), 1)))",
    ),
    "Line extraction, carrying lines, line fits (rigcal.lines, localize.odometry)": (
        "import numpy as np; import rigcal.lines_kernel; from rigcal.lines import extract_lines; "
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


def localize_first_and_second(duration_s: float = 40.0) -> str:
    """Markdown rows: localize's ICP seconds and wall seconds, first run (empty cache)
    against second run (cache filled by the first), on one simulated drive."""
    import json
    import time
    from pathlib import Path

    rigcal = [sys.executable, "-c", "from rigcal.cli.main import entry; entry()"]
    with tempfile.TemporaryDirectory() as tmp:
        seq = Path(tmp) / "seq"
        drive = ["world", "-o", str(seq), "--duration-s", str(duration_s), "--no-images"]
        subprocess.run([*rigcal, "-q", "simulate", *drive], check=True)
        env = dict(os.environ, NUMBA_CACHE_DIR=str(Path(tmp) / "cache"))
        rows = ["| run | ICP, as localize reports it (s) | localize command, wall (s) | kernels compiled |"]
        rows.append("|---|---|---|---|")
        for label in ("first (empty cache)", "second (cache filled)"):
            out = Path(tmp) / "out"
            t0 = time.perf_counter()
            done = subprocess.run(
                [*rigcal, "localize", str(seq), "--method", "icp", "-o", str(out), "--force", "--json"],
                env=env,
                check=True,
                capture_output=True,
                text=True,
            )
            wall = time.perf_counter() - t0
            icp = json.loads(done.stdout)["methods"]["icp"]["total_s"]
            compiled = sum("rigcal.jit: compiled" in line for line in done.stderr.splitlines())
            rows.append(f"| {label} | {icp:.1f} | {wall:.1f} | {compiled} |")
    return "\n".join(rows)


def warm_up_twice() -> str:
    """Markdown rows: ``rigcal warm-up`` with an empty cache, then with the cache it filled."""
    import resource
    import time
    from pathlib import Path

    rows = ["| run | wall (s) | CPU (s) | what it printed |", "|---|---|---|---|"]
    with tempfile.TemporaryDirectory() as tmp:
        env = dict(os.environ, NUMBA_CACHE_DIR=str(Path(tmp) / "cache"))
        for label in ("first (empty cache)", "second (cache filled)"):
            cpu0 = resource.getrusage(resource.RUSAGE_CHILDREN)
            t0 = time.perf_counter()
            done = subprocess.run(
                [sys.executable, "-c", "from rigcal.cli.main import entry; entry()", "warm-up"],
                env=env,
                check=True,
                capture_output=True,
                text=True,
            )
            wall = time.perf_counter() - t0
            cpu1 = resource.getrusage(resource.RUSAGE_CHILDREN)
            cpu = cpu1.ru_utime - cpu0.ru_utime + cpu1.ru_stime - cpu0.ru_stime
            said = done.stderr.strip().split(";")[0] or "nothing"
            rows.append(f"| {label} | {wall:.0f} | {cpu:.0f} | {said} |")
    return "\n".join(rows)


if __name__ == "__main__":
    if sys.argv[1:2] == ["--warm-up"]:
        print(warm_up_twice())
        sys.exit()
    if sys.argv[1:2] == ["--localize"]:
        print(localize_first_and_second(float(sys.argv[2]) if len(sys.argv) > 2 else 40.0))
        sys.exit()
    # An argument keeps only the kernels whose label contains it.
    wanted = sys.argv[1] if len(sys.argv) > 1 else ""
    print(compile_table({k: v for k, v in KERNELS.items() if wanted in k}))
