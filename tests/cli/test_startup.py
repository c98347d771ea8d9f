"""What a command imports before it runs: ``rigcal --help`` loads none of the heavy
libraries, and the targetless check loads none it does not use (scipy.stats, tqdm without
a terminal, plotting, the box solver's kernels), nor before it runs what it uses only later
(scipy.spatial, scipy.special, scipy.sparse: imported beside the laser odometry)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

HEAVY = ["numpy", "scipy", "numba", "cv2", "matplotlib", "tqdm", "imagecodecs", "yaml"]


def _child(code: str) -> dict:  # type: ignore[type-arg]
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return json.loads(done.stdout.splitlines()[-1])


@pytest.mark.parametrize("argv", [["--help"], ["check", "--help"]])
def test_help_imports_no_heavy_library(argv: list[str]) -> None:
    out = _child(
        "import contextlib, io, json, sys\n"
        "from rigcal.cli.main import main\n"
        "buf = io.StringIO()\n"
        f"with contextlib.redirect_stdout(buf): rc = main({argv!r})\n"
        f"loaded = [m for m in {HEAVY!r} if m in sys.modules]\n"
        "print(json.dumps({'rc': rc, 'text': buf.getvalue(), 'loaded': loaded}))"
    )
    assert out["rc"] == 0
    assert out["loaded"] == []
    assert ("--sequence" in out["text"]) == (argv[0] == "check")
    assert "check" in out["text"]


def test_targetless_check_modules_leave_out_what_it_does_not_use() -> None:
    """The modules ``rigcal check --sequence`` imports (rigcal.jobs' targetless path)."""
    modules = [
        "rigcal.cli.main",
        "rigcal.cli.progress",
        "rigcal.jobs",
        "rigcal.drift.log",
        "rigcal.rigfile",
        "rigcal.recordings.sequence",
        "rigcal.drift.targetless",
        "rigcal.drift.trajectory",
        "rigcal.localize.streams",
    ]
    unused = [
        "scipy.stats",
        "tqdm",
        "matplotlib",
        "rigcal.calib.box.solve",
        "rigcal.drift.target",
        "rigcal.viz",
    ]
    out = _child(
        "import json, sys\n"
        + "".join(f"import {m}\n" for m in modules)
        + "from rigcal.cli.progress import Progress\n"
        + "with Progress('frame', disable=True) as bars: bars('frame', 3, 3)\n"
        + f"print(json.dumps([m for m in {unused!r} if m in sys.modules]))"
    )
    assert out == []


def test_targetless_check_modules_defer_scipy() -> None:
    """The check's modules (its reading of a drive without --trajectory) import no scipy
    package the check uses only later (:data:`rigcal.drift.targetless.LATER_IMPORTS`:
    imported on a second thread while the laser odometry runs)."""
    modules = [
        "rigcal.cli.main",
        "rigcal.jobs",
        "rigcal.drift.log",
        "rigcal.rigfile",
        "rigcal.recordings.sequence",
        "rigcal.drift.targetless",
        "rigcal.localize.streams",
    ]
    out = _child(
        "import json, sys\n"
        + "".join(f"import {m}\n" for m in modules)
        + "from rigcal.drift.targetless import LATER_IMPORTS\n"
        + "print(json.dumps([m for m in sys.modules if m.startswith(LATER_IMPORTS)]))"
    )
    assert out == []


def test_the_targetless_check_keeps_openblas_to_one_thread() -> None:
    """``rigcal check --sequence`` runs its own threads on both cores: OpenBLAS's are set to
    one before numpy loads it (unless the user set them), and not for the other checks."""
    code = (
        "import contextlib, io, json, os, sys\n"
        "from rigcal.cli.main import main\n"
        "with contextlib.redirect_stderr(io.StringIO()):\n"
        "    rc = main(sys.argv[1:])\n"
        "print(json.dumps({'rc': rc, 'blas': os.environ.get('OPENBLAS_NUM_THREADS')}))"
    )
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}

    def run(*argv: str) -> dict:  # type: ignore[type-arg]
        done = subprocess.run(
            [sys.executable, "-c", code, *argv], capture_output=True, text=True, check=True, env=env
        )
        return json.loads(done.stdout.splitlines()[-1])  # type: ignore[no-any-return]

    drive = run("check", "missing-rig.yaml", "--sequence", "missing-drive", "--no-log")
    assert drive == {"rc": 3, "blas": "1"}
    box = run("check", "missing-rig.yaml", "--picks", "missing-picks.yaml", "--no-log")
    assert box == {"rc": 3, "blas": None}
