"""rigcal batch on real Ray processes, started as docs/batch.md tells a user: a local
instance (``--ray local``) that listens on loopback only, and a cluster of a head and a
second node (``ray start --head``, ``ray start --address``, token authentication) joined
with ``--ray auto`` and with the Ray Client address; items land on both nodes with the
local pool's results to the last digit; a node killed mid-batch.

Slow (each Ray node takes tens of seconds to start on a loaded machine):
``pytest -m slow tests/batch/test_ray_cluster.py``.
"""

from __future__ import annotations

import json
import subprocess
import time
from pathlib import Path

import pytest
import yaml
from ray_nodes import (
    HEAD_IP,
    NODE_IPS,
    RIGCAL,
    TEST_NICE,
    LoopbackCluster,
    batch,
    descendants,
    item_nodes,
    listening_sockets,
    running_items,
    solve_manifest,
)

pytest.importorskip("ray")
pytestmark = pytest.mark.slow

N_ITEMS = 6


@pytest.fixture(scope="module")
def manifest(tmp_path_factory) -> Path:
    return solve_manifest(tmp_path_factory.mktemp("sessions"), N_ITEMS, 40)


def results(out: Path) -> dict[str, dict]:
    """Per item: the summary's figures and the solved transform, exactly as written."""
    doc = json.loads((out / "summary.json").read_text())
    keep = {}
    for row in doc["items"]:
        rig = yaml.safe_load((out / row["name"] / "rig.yaml").read_text())
        figures = {k: v for k, v in row.items() if k not in ("resumed", "seconds", "host", "node")}
        keep[row["name"]] = figures | {"T_cam_laser": rig["T_cam_laser"]}
    return keep


@pytest.fixture(scope="module")
def reference(manifest, tmp_path_factory) -> dict[str, dict]:
    out = tmp_path_factory.mktemp("pool") / "out"
    done = batch(manifest, out, "-j", "2")
    assert done.returncode == 0, done.stderr
    assert set(item_nodes(out).values()) == {None}
    return results(out)


def test_local_listens_on_loopback_only_and_cleans_up(manifest, reference, tmp_path):
    """Every socket the run's Ray processes listen on is on 127.0.0.1, polled while the
    batch runs; stderr says so and names the session folder, which is gone after."""
    proc = subprocess.Popen(
        [RIGCAL, "batch", str(manifest), "-o", str(tmp_path / "out"), "--ray", "local", "-j", "2"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    seen: set[str] = set()
    try:
        while proc.poll() is None:
            seen |= {addr for _, addr, _ in listening_sockets(descendants(proc.pid))}
            time.sleep(0.5)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    line = next(x for x in err.splitlines() if x.startswith("Ray: a local instance"))
    assert "on 127.0.0.1 only" in line
    session = Path(line.split("session files in ")[1].split(" ")[0])
    assert session.name.startswith("rigcal-ray-")
    assert not session.exists()
    assert len(seen) >= 4, seen  # the GCS, the raylet, the driver, a worker at least
    assert {a.rsplit(":", 1)[0] for a in seen} == {"127.0.0.1"}, seen
    assert results(tmp_path / "out") == reference
    assert set(item_nodes(tmp_path / "out").values()) == {"127.0.0.1"}


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    with LoopbackCluster(tmp_path_factory.mktemp("cluster"), workers=1, cpus=1, start_nice=TEST_NICE) as c:
        yield c


def test_auto_joins_the_cluster_named_by_ray_address(cluster, manifest, reference, tmp_path):
    env = cluster.driver_env(RAY_ADDRESS=cluster.address)
    done = batch(manifest, tmp_path / "out", "--ray", "auto", env=env)
    assert done.returncode == 0, done.stderr
    assert f"Ray: joined {cluster.address}: 2 nodes, 2 CPUs" in done.stderr
    assert results(tmp_path / "out") == reference
    assert set(item_nodes(tmp_path / "out").values()) == {HEAD_IP, NODE_IPS[0]}


def test_the_client_address(cluster, manifest, reference, tmp_path):
    done = batch(manifest, tmp_path / "out", "--ray", cluster.client_address, env=cluster.driver_env())
    assert done.returncode == 0, done.stderr
    assert f"Ray: joined {cluster.client_address}: 2 nodes, 2 CPUs" in done.stderr
    assert results(tmp_path / "out") == reference
    assert set(item_nodes(tmp_path / "out").values()) == {HEAD_IP, NODE_IPS[0]}


def test_without_the_token_the_join_fails_in_one_line(cluster, manifest, tmp_path):
    env = cluster.driver_env(HOME=str(tmp_path), RAY_AUTH_MODE="token")
    done = batch(manifest, tmp_path / "out", "--ray", cluster.address, env=env, timeout=300)
    assert done.returncode == 3, done.stderr
    last = done.stderr.strip().splitlines()[-1]
    assert last.startswith(f"Error: --ray: got '{cluster.address}'; expected a Ray cluster to join (")
    assert not list((tmp_path / "out").glob("*/item.json"))


def test_a_node_killed_mid_batch_has_its_items_run_elsewhere(cluster, manifest, reference, tmp_path):
    """With the default retry, the item a killed node was running runs again on another
    node and the batch succeeds, to the pool's results."""
    node = cluster.add_node(NODE_IPS[1])
    out = tmp_path / "out"
    env = cluster.driver_env(RAY_ADDRESS=cluster.address)
    proc = subprocess.Popen(
        [RIGCAL, "batch", str(manifest), "-o", str(out), "--ray", "auto"],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        _kill_when_busy(cluster, node, proc)
        _, err = proc.communicate(timeout=900)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    assert "3 nodes" in err
    assert results(out) == reference
    assert set(item_nodes(out).values()) <= {HEAD_IP, NODE_IPS[0], NODE_IPS[1]}


def _kill_when_busy(cluster: LoopbackCluster, node, proc: subprocess.Popen) -> None:
    """Kill ``node`` as soon as one of its workers runs an item."""
    deadline = time.monotonic() + 600
    while not running_items(cluster.marker, node.ip):
        assert proc.poll() is None, "the batch ended before a task ran on the node"
        assert time.monotonic() < deadline, "no task ran on the node"
        time.sleep(0.2)
    cluster.kill_node(node)


def test_a_node_killed_mid_batch(cluster, manifest, reference, tmp_path):
    """Without retries, the items of a node killed while they run are recorded as failed,
    the batch finishes, every record is whole; the resume runs only those items. (Runs
    last: it takes the second node away.)"""
    out = tmp_path / "out"
    node = next(n for n in cluster.nodes if n.ip == NODE_IPS[0])
    env = cluster.driver_env(RAY_ADDRESS=cluster.address)
    cmd = [RIGCAL, "batch", str(manifest), "-o", str(out), "--ray", "auto", "--ray-retries", "0"]
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        _kill_when_busy(cluster, node, proc)
        _, err = proc.communicate(timeout=900)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 1, err
    recs = {p.parent.name: json.loads(p.read_text()) for p in out.glob("*/item.json")}
    assert len(recs) == N_ITEMS
    failed = sorted(k for k, r in recs.items() if r["status"] == "failed")
    assert failed, err
    assert all(recs[k]["exit_code"] == 70 and recs[k]["error"].startswith("worker failed: ") for k in failed)
    assert all(r["status"] == "ok" for k, r in recs.items() if k not in failed)
    # the resume: only the failed items run, on the head that is left
    again = batch(manifest, out, "--ray", "auto", env=env)
    assert again.returncode == 0, again.stderr
    assert again.stderr.count("skipped, finished before") == N_ITEMS - len(failed)
    assert {k: v for k, v in item_nodes(out).items() if k in failed} == dict.fromkeys(failed, HEAD_IP)
    assert results(out) == reference
