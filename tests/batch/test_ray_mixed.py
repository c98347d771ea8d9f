"""rigcal batch on a Ray cluster whose nodes are not all installed alike, for real: a node
started from a virtual environment of another Python (with the same Ray) and a driver in
that Python, both refused by Ray with its reason; a node whose rigcal is another version,
found when the batch joins and given no items, while the batch finishes on the others.

The other Python is CPython 3.12 or 3.13, whichever this one is not (``RIGCAL_OTHER_PYTHON``,
else ``python3.X`` on ``PATH``, else pyenv); its environment (Ray only, the version this one
runs) is built once with uv into ``.cache/`` and reused.

Slow (each Ray node takes tens of seconds to start on a loaded machine):
``pytest -m slow tests/batch/test_ray_mixed.py``.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest
from ray_nodes import (
    HEAD_IP,
    NODE_IPS,
    RIGCAL,
    TEST_NICE,
    LoopbackCluster,
    batch,
    item_nodes,
    running_items,
    solve_manifest,
)

ray = pytest.importorskip("ray")
pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]
OTHER_MINOR = {12: "3.13", 13: "3.12"}.get(sys.version_info.minor, "3.12")
N_ITEMS = 4


def other_python() -> str | None:
    """An interpreter of the other supported Python minor version that runs, or None (a
    pyenv shim of a version that is installed but not selected is on PATH yet fails)."""
    candidates = [os.environ.get("RIGCAL_OTHER_PYTHON"), shutil.which(f"python{OTHER_MINOR}")]
    if shutil.which("pyenv"):
        done = subprocess.run(["pyenv", "prefix", OTHER_MINOR], capture_output=True, text=True, check=False)
        if done.returncode == 0 and done.stdout.strip():
            candidates.append(str(Path(done.stdout.strip().splitlines()[-1]) / "bin" / "python3"))
    want = tuple(int(x) for x in OTHER_MINOR.split("."))
    for exe in filter(None, candidates):
        done = subprocess.run(
            [exe, "-c", "import sys; print(*sys.version_info[:2])"],
            capture_output=True,
            text=True,
            check=False,
        )
        if done.returncode == 0 and tuple(int(x) for x in done.stdout.split()) == want:
            return exe
    return None


def uv() -> str | None:
    local = ROOT / ".cache" / "uv-bootstrap" / "bin" / "uv"
    return str(local) if local.is_file() else shutil.which("uv")


@pytest.fixture(scope="module")
def other_env() -> Path:
    """A virtual environment of the other Python holding this Ray version (with the
    client), built with uv once into .cache/ and reused."""
    python, tool = other_python(), uv()
    if python is None:
        pytest.skip(f"no Python {OTHER_MINOR} interpreter (RIGCAL_OTHER_PYTHON, python{OTHER_MINOR}, pyenv)")
    if tool is None:
        pytest.skip("uv is not installed (bash scripts/dev.sh installs it into .cache/uv-bootstrap)")
    venv = ROOT / ".cache" / f"ray-py{OTHER_MINOR.replace('.', '')}-{ray.__version__}"
    exe = venv / "bin" / "python"
    check = [str(exe), "-c", "import ray, sys; print(ray.__version__, sys.version_info[:2])"]
    want = f"{ray.__version__} {tuple(int(x) for x in OTHER_MINOR.split('.'))}"
    if not (exe.is_file() and subprocess.run(check, capture_output=True, text=True).stdout.strip() == want):
        env = os.environ | {"UV_PYTHON_DOWNLOADS": "never"}
        for cmd in (
            [tool, "venv", "--clear", "-p", python, str(venv)],
            [tool, "pip", "install", "-p", str(exe), f"ray[client]=={ray.__version__}"],
        ):
            done = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=900)
            if done.returncode != 0:
                pytest.fail(f"{' '.join(cmd)} failed: {done.stderr[-2000:]}")
    assert subprocess.run(check, capture_output=True, text=True).stdout.strip() == want
    return venv


@pytest.fixture(scope="module")
def manifest(tmp_path_factory) -> Path:
    return solve_manifest(tmp_path_factory.mktemp("sessions"), N_ITEMS, 60)


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    with LoopbackCluster(tmp_path_factory.mktemp("cluster"), workers=1, cpus=1, start_nice=TEST_NICE) as c:
        yield c


def test_ray_refuses_a_node_of_another_python_with_its_reason(cluster, other_env, manifest, tmp_path):
    """`ray start --address` from the other Python's environment exits non-zero and says
    why (both versions); the cluster keeps its nodes and the batch runs on them."""
    code, output = cluster.try_node(NODE_IPS[2], str(other_env / "bin" / "ray"))
    assert code not in (0, -1), output[-3000:]
    assert "Version mismatch: The cluster was started with:" in output, output[-3000:]
    other = subprocess.run(
        [str(other_env / "bin" / "python"), "-c", "import platform; print(platform.python_version())"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout.strip()
    assert f"Python: {other}" in output
    assert f"Python: {sys.version.split()[0]}" in output
    done = batch(
        manifest, tmp_path / "out", "--ray", "auto", env=cluster.driver_env(RAY_ADDRESS=cluster.address)
    )
    assert done.returncode == 0, done.stderr
    assert f"Ray: joined {cluster.address}: 2 nodes, 2 CPUs" in done.stderr
    assert set(item_nodes(tmp_path / "out").values()) <= {HEAD_IP, NODE_IPS[0]}


def test_a_driver_of_another_python_is_refused_in_one_line(cluster, other_env):
    """rigcal's own join code, run by the other Python: Ray's version-mismatch reason,
    which spans lines, becomes one line naming both versions."""
    code = (
        "import sys\n"
        "from rigcal.batch.raycluster import connect, parse_address\n"
        "from rigcal.errors import InputError\n"
        "try:\n"
        "    with connect(parse_address(sys.argv[1]), 0, 10.0, print):\n"
        "        print('joined')\n"
        "except InputError as exc:\n"
        "    print('Error:', exc)\n"
        "    sys.exit(exc.exit_code)\n"
    )
    env = cluster.driver_env(PYTHONPATH=str(ROOT / "src"))
    done = subprocess.run(
        [str(other_env / "bin" / "python"), "-c", code, cluster.address],
        capture_output=True,
        text=True,
        env=env,
        timeout=600,
        check=False,
    )
    assert done.returncode == 3, done.stdout + done.stderr
    (line,) = [x for x in done.stdout.splitlines() if x.startswith("Error: ")]
    assert line.startswith(
        f"Error: --ray: got '{cluster.address}'; expected a Ray cluster to join "
        "(RuntimeError: Version mismatch: "
    ), line
    assert f"Python: {sys.version.split()[0]} This process on" in line, line


def test_a_long_manifest_holds_a_window_of_items_in_the_cluster(cluster, manifest, tmp_path):
    """With -j 1 on a cluster of two CPUs, the driver hands Ray one item at a time: never
    two items run at once (were they all submitted, both CPUs would take one)."""
    out = tmp_path / "out"
    cmd = [RIGCAL, "batch", str(manifest), "-o", str(out), "--ray", "auto", "-j", "1"]
    env = cluster.driver_env(RAY_ADDRESS=cluster.address)
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    seen = []
    try:
        while proc.poll() is None:
            seen.append(running_items(cluster.marker))
            time.sleep(0.2)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    assert max(seen) == 1, seen


def test_a_node_with_another_rigcal_gets_no_items(cluster, manifest, tmp_path):
    """A node whose workers import another rigcal version (its own PYTHONPATH) is named
    when the batch joins, once, and gets no items; the batch finishes on the others,
    through the cluster's address and through Ray Client. (Runs last: it adds the node.)"""
    other = tmp_path / "other"
    shutil.copytree(ROOT / "src" / "rigcal", other / "rigcal", ignore=shutil.ignore_patterns("__pycache__"))
    init = other / "rigcal" / "__init__.py"
    init.write_text(init.read_text().replace('__version__ = "', '__version__ = "0.0.0+other-', 1))
    cluster.add_node(NODE_IPS[1], env={"PYTHONPATH": str(other)})
    from rigcal import __version__

    for k, args in enumerate((("--ray", "auto"), ("--ray", cluster.client_address))):
        out = tmp_path / f"out{k}"
        done = batch(manifest, out, *args, env=cluster.driver_env(RAY_ADDRESS=cluster.address))
        assert done.returncode == 0, done.stderr
        assert "3 nodes, 3 CPUs" in done.stderr
        line = (
            f"Ray: node {NODE_IPS[1]} runs rigcal 0.0.0+other-{__version__} (driver: {__version__}); "
            "no items are sent there"
        )
        assert done.stderr.count(line) == 1, done.stderr
        summary = json.loads((out / "summary.json").read_text())
        assert [r["status"] for r in summary["items"]] == ["ok"] * N_ITEMS
        assert set(item_nodes(out).values()) <= {HEAD_IP, NODE_IPS[0]}
