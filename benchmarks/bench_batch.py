"""Throughput of ``rigcal batch``: the same items on the local pool with 1, 2 and 4
workers and on Ray with two local nodes, where the overhead goes, and what a fleet's
nightly checks would cost on a cluster.

Items are drift checks (``rigcal check`` of a fresh 6-capture session against the stored
rig, as a fleet's nightly run does) or solves (``--command solve``: 20 captures, report
with overlay PNGs). Every figure is measured in this run, on this machine:

- **in process**: the items one after the other in this process, after one warm-up item
  (no worker processes, no imports, compiled kernels loaded): the work itself;
- **start-up**: a fresh interpreter importing the command's modules (``python -c
  'import rigcal.cli.main'`` and the command's own modules), and its first item minus a
  warm one (imports of the item's code paths plus numba's cache loads and first calls);
- **serialisation**: pickling an item's command line and its result (what the pool and
  Ray move per item), and a no-op Ray task's round trip on the cluster;
- **throughput**: items per second over the whole run (pool start-up or cluster join
  included) with 1, 2 and 4 workers on the local pool, and on Ray with two local nodes
  (separate ``ray start`` processes on loopback addresses, tests/batch/ray_nodes.py) with
  ``-j`` 1, 2 and 4 (at most that many items at once);
- **fleet cost**: N rigs' checks on M nodes of C cores, from the warm item time, each
  worker's one-off start and the cluster's join time, a core per worker.

    .venv/bin/python benchmarks/bench_batch.py [--items 8] [--command check] [--no-ray]
"""

from __future__ import annotations

import argparse
import os
import pickle
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

from rigcal.batch.manifest import read_manifest
from rigcal.batch.runner import BatchSettings, run_batch, run_item, versions
from rigcal.calib.box.session import calibrate
from rigcal.rigfile import write_rig
from rigcal.sim.box_session import SessionSpec, default_T_cam_laser, generate_session, write_session

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "batch"))

WORKERS = (1, 2, 4)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--items", type=int, default=8)
    ap.add_argument("--command", choices=["check", "solve"], default="check")
    ap.add_argument("--no-ray", action="store_true")
    args = ap.parse_args()
    # a stopped run (kill, Ctrl-C) unwinds the context managers, so the Ray nodes it started
    # are stopped and the temporary folder removed
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        batch = make_items(root, args.items, args.command)
        print(f"## rigcal batch: {args.items} {args.command} items; {os.cpu_count()} CPUs, load {load()}\n")

        # the work itself, in this process
        run_item(batch[0], (root / "warm" / batch[0].name).resolve(), "bench")
        t0 = time.perf_counter()
        results = []
        for item in batch:
            results.append(run_item(item, (root / "inline" / item.name).resolve(), "bench"))
            assert results[-1]["error"] is None, results[-1]["error"]
        t_item = (time.perf_counter() - t0) / len(batch)

        print("### Where the time goes, per worker and per item\n")
        print("| part | seconds |\n|---|---|")
        print(f"| one item, warm (in this process) | {t_item:.3f} |")
        bare = fresh("pass")
        imports = fresh("import rigcal.cli.main, rigcal.batch.runner") - bare
        libs, first = fresh_first_item(root / "batch.yaml", (root / "first" / batch[0].name).resolve())
        print(f"| a fresh interpreter (python -c pass) | {bare:.2f} |")
        print(f"| imports of the CLI and the runner | {imports:.2f} |")
        print(
            f"| imports of the item's libraries (numpy, scipy, OpenCV, mrcal, numba, rigcal) | {libs:.2f} |"
        )
        print(
            f"| first item in a fresh worker after those imports, minus a warm one (numba's cache "
            f"loads and first calls) | {first - t_item:.2f} |"
        )
        first += libs
        argv = batch[0].argv(root / "x")
        t0 = time.perf_counter()
        for _ in range(1000):
            pickle.loads(pickle.dumps((batch[0], argv, versions())))
            pickle.loads(pickle.dumps(results[0]))
        ser = (time.perf_counter() - t0) / 1000
        print(
            f"| pickling an item and its result ({len(pickle.dumps(results[0]))} bytes) "
            f"| {ser * 1e3:.3f} ms |"
        )

        rows = [("in this process, one after the other (no workers)", len(batch) * t_item)]
        for w in WORKERS:
            rows.append((f"local pool, {w} worker{'s' if w > 1 else ''}", timed(batch, root / f"p{w}", w)))
        join = rtt = None
        if not args.no_ray:
            join, rtt, ray_rows = on_ray(batch, root)
            rows += ray_rows
        rows.append(("local pool, 2 workers, resumed (all finished)", timed(batch, root / "p2", 2)))
        if rtt is not None:
            print(f"| a no-op Ray task's round trip on the two-node cluster | {rtt * 1e3:.1f} ms |")
            print(f"| joining the cluster (ray.init, a driver process) | {join:.2f} |")

        print(f"\n### Throughput (load {load()})\n")
        print("| run | seconds | items/s | x one worker |\n|---|---|---|---|")
        one = dict(rows)["local pool, 1 worker"]
        for label, t in rows:
            print(f"| {label} | {t:.1f} | {len(batch) / t:.2f} | {one / t:.2f} |")

        # per worker, once: an interpreter, the imports, numba's cache loads and first calls
        per_worker = bare + imports + (first - t_item)
        start = (join or 0.0) + per_worker
        print(
            f"\n### A fleet's nightly checks on M nodes of C cores\n\n"
            f"Each worker pays {per_worker:.1f} s once (interpreter, imports, numba's cache loads "
            f"and first calls), the driver {join or 0.0:.1f} s to join, then {t_item:.2f} s per "
            f"item (warm, measured here under load {load()}); with a core per worker, time = "
            f"{start:.1f} s + ceil(N / (M C)) x {t_item:.2f} s.\n"
        )
        print("| rigs N | M x C = 1 x 8 | 4 x 8 | 16 x 8 |\n|---|---|---|---|")
        for n in (50, 500, 5000):
            cells = [f"{(start + -(-n // (m * 8)) * t_item) / 60:.1f} min" for m in (1, 4, 16)]
            print(f"| {n} | " + " | ".join(cells) + " |")


def make_items(root: Path, n: int, command: str) -> list:
    items = []
    defaults: dict = {}
    if command == "check":
        write_rig(root / "rig.yaml", calibrate_session(root / "calib"))
        defaults = {"rig": "rig.yaml", "no_log": True}
    for k in range(n):
        spec = SessionSpec(n_captures=6 if command == "check" else 20, seed=100 + k)
        write_session(generate_session(spec, T_cam_laser=default_T_cam_laser()), root / f"s{k:02d}", False)
        items.append({"name": f"s{k:02d}", "picks": f"s{k:02d}/picks.yaml"})
    doc = {"schema_version": 1, "command": command, "items": items}
    if defaults:
        doc["defaults"] = defaults
    (root / "batch.yaml").write_text(yaml.safe_dump(doc))
    return read_manifest(root / "batch.yaml")


def calibrate_session(folder: Path):
    write_session(generate_session(SessionSpec(n_captures=20, seed=1)), folder, False)
    return calibrate(folder / "picks.yaml").rig


def load() -> str:
    return " ".join(f"{x:.1f}" for x in os.getloadavg())


def fresh(code: str, repeat: int = 3) -> float:
    """The best wall time of a fresh interpreter running ``code``."""
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-c", code], check=True)
        best = min(best, time.perf_counter() - t0)
    return best


def fresh_first_item(manifest: Path, folder: Path) -> tuple[float, float]:
    """In a fresh interpreter, after the CLI's imports: the time to import every module a
    warm item has loaded (this process's ``sys.modules`` of the item's libraries), then
    the first item's time."""
    roots = ("rigcal", "numpy", "scipy", "cv2", "mrcal", "numba", "yaml", "matplotlib", "imagecodecs")
    mods = sorted(m for m in sys.modules if m.split(".")[0] in roots and "._" not in m)
    code = (
        "import importlib, os, sys, time, rigcal.cli.main, rigcal.batch.runner as r\n"
        "t0 = time.perf_counter()\n"
        "for m in os.environ['BENCH_MODULES'].split():\n"
        "    try: importlib.import_module(m)\n"
        "    except Exception: pass\n"
        "from pathlib import Path; from rigcal.batch.manifest import read_manifest\n"
        "item = read_manifest(Path(sys.argv[1]))[0]\n"
        "t1 = time.perf_counter(); out = r.run_item(item, Path(sys.argv[2]), 'bench')\n"
        "assert out['error'] is None, out\n"
        "print(t1 - t0, time.perf_counter() - t1)\n"
    )
    env = os.environ | {"BENCH_MODULES": " ".join(mods)}
    done = subprocess.run(
        [sys.executable, "-c", code, str(manifest), str(folder)],
        check=True,
        capture_output=True,
        text=True,
        env=env,
    )
    libs, first = (float(x) for x in done.stdout.strip().splitlines()[-1].split())
    return libs, first


def timed(batch: list, out: Path, workers: int, address: str | None = None) -> float:
    t0 = time.perf_counter()
    outcomes = run_batch(batch, out, BatchSettings(workers, address))
    errors = [o.record["error"] for o in outcomes if o.record["status"] == "failed"]
    assert not errors, errors
    return time.perf_counter() - t0


def on_ray(batch: list, root: Path) -> tuple[float, float, list[tuple[str, float]]]:
    """The cluster's join time, a no-op task's round trip, and the batch on two local
    nodes of 2 CPUs each with 1, 2 and 4 items at once (each run its own driver
    process, as ``rigcal batch --ray auto`` is)."""
    from ray_nodes import LoopbackCluster

    rows = []
    nice = -10 if os.geteuid() == 0 else 0  # the nodes' start only; see LoopbackCluster
    with LoopbackCluster(root / "cluster", workers=1, cpus=2, start_nice=nice) as cluster:
        env = cluster.env | {"RAY_ADDRESS": cluster.address}
        probe = (
            "import time, ray\nt0 = time.perf_counter(); ray.init(address='auto', log_to_driver=False)\n"
            "join = time.perf_counter() - t0\nf = ray.remote(num_cpus=1)(lambda: 0)\nray.get(f.remote())\n"
            "t0 = time.perf_counter()\nfor _ in range(20): ray.get(f.remote())\n"
            "print(join, (time.perf_counter() - t0) / 20)\n"
        )
        done = subprocess.run(
            [sys.executable, "-c", probe], env=env, capture_output=True, text=True, check=True
        )
        join, rtt = (float(x) for x in done.stdout.split())
        manifest = root / "batch.yaml"
        for w in WORKERS:
            cmd = [str(Path(sys.executable).with_name("rigcal")), "batch", str(manifest)]
            cmd += ["-o", str(root / f"ray{w}"), "--ray", "auto", "-j", str(w)]
            t0 = time.perf_counter()
            run = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False)
            t = time.perf_counter() - t0
            assert run.returncode in (0, 1), run.stderr
            summary = yaml.safe_load((root / f"ray{w}" / "summary.json").read_text())
            nodes = {r["node"] for r in summary["items"]}
            rows.append((f"Ray, two local nodes, -j {w} ({len(nodes)} nodes used; a driver process)", t))
    return join, rtt, rows


if __name__ == "__main__":
    main()
