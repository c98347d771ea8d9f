"""Speed of the targetless check (``rigcal check RIG --sequence SEQ``) on one window of a
simulated drive, against the laser odometry of the same window in the same process.

The drive is the one ``bench_targetless.py`` simulates (realistic camera; kept in
``--cache``). The laser odometry of the window on every scan runs first (the reference),
then the check with that odometry reused (``scan_rate_hz=None``, as after a pipeline has
computed it; decoding the window's images included), then the check again (images
kept), then the check end to end as ``rigcal check`` runs it on a fresh copy of the
window: its own laser odometry on the scans thinned to 10 Hz, decoding, the check; then
the check on another fresh copy with the laser's motion from a trajectory file (``rigcal
check --trajectory``: the reference odometry written as ``rigcal localize --method icp``
writes it, a TUM file of the laser's poses at the scans' stamps; reading it, decoding,
the check). Each is timed by the wall clock and by the process's CPU time (all
threads), and the end-to-end run also by its main thread's CPU time (the work no other
thread takes off it: about its wall time on an idle machine with two cores or more). On
a machine shared with other jobs the wall clock measures the load, while the CPU time
and the ratio to the odometry do not. Printed as x real time (the window's duration
over the time) and as the check's time over the odometry's.

    .venv/bin/python benchmarks/bench_targetless_speed.py --world corridor-loop --length 60
    .venv/bin/python benchmarks/bench_targetless_speed.py --world cubicle-loop --length 30

With ``--sequence DIR`` (a sequence folder with its rig, e.g. ``rigcal simulate world
--duration-s 60``), the command itself instead: ``rigcal -q check RIG --sequence DIR --no-log
--json`` (RIG a copy of DIR/rig.yaml) in a new process (starting Python, imports, loading the
compiled kernels from their cache, reading the sequence, the check), against the same check
as a library call in this process (``rigcal.jobs.check_rig``, which the command calls: it
reads the sequence anew, so the difference is the process's start-up: Python, the imports,
the kernels loaded from their cache), and against the laser odometry of every scan in this
process. Each is timed by the wall clock and CPU time (the child's, all threads). One more
child runs the command under ``python -X importtime`` and reports its CPU time when the check
proper begins (the start-up: Python, imports, reading the sequence and the rig, as a child
of this benchmark), its main thread's CPU time at the end (the work no other thread takes
off it: about the command's wall time on two idle cores, whatever the load) and the imports
that cost most; it also says how many kernels were
compiled rather than loaded from the cache (0 once warmed). ``--trajectory`` adds the
command with ``--trajectory`` (the reference odometry as a TUM file), ``--no-bytecode`` a
run with no compiled bytecode to load or write (``PYTHONDONTWRITEBYTECODE=1`` and an empty
``PYTHONPYCACHEPREFIX``: what each process costs where bytecode is never written, and what the
first run of an install costs). The children write bytecode as an ordinary install does
(``PYTHONDONTWRITEBYTECODE`` removed from their environment) and the importtime child runs
first, so the timed runs load it. Verdicts and corrections of the command and of the library
call are printed side by side (they are the same check).

    .venv/bin/python benchmarks/bench_targetless_speed.py --sequence /tmp/c60
    .venv/bin/python benchmarks/bench_targetless_speed.py --sequence /tmp/c60 --repeat 3 --no-bytecode

With ``--against SRC`` (another checkout's ``src`` folder, e.g. ``git archive main src``
unpacked), the command alone, A/B: ``--pairs`` pairs of runs, each pair SRC's code
(``PYTHONPATH=SRC``) then this checkout's, in turn; each run's wall and CPU seconds and the
load, the medians and ranges of each side, and whether each run's record equals the first
run's (all but the check's time and date).

    .venv/bin/python benchmarks/bench_targetless_speed.py --sequence /tmp/c60 --against /tmp/b/src --pairs 6
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench_targetless import drive, window
from rigcal.drift.targetless import TargetlessSettings, check_targetless
from rigcal.drift.trajectory import trajectory_odometry
from rigcal.io.trajectory import planar_trajectory, write_tum
from rigcal.localize.streams import open_streams


def timed(fn):  # type: ignore[no-untyped-def]
    """(result, wall s, CPU s) of fn()."""
    c, t = time.process_time(), time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t, time.process_time() - c


def reused(streams, path: Path):  # type: ignore[no-untyped-def]
    """The check with the laser's motion from the TUM file at path, as ``rigcal check
    --trajectory`` runs it."""
    streams.use_laser_odometry(trajectory_odometry(path, streams))
    return check_targetless(streams.rig, streams, TargetlessSettings(scan_rate_hz=None))


def command(
    argv: list[str], env: dict[str, str] | None = None, python: list[str] | None = None
) -> tuple[dict, float, float, str]:  # type: ignore[type-arg]
    """(the JSON printed, wall s, CPU s of the child, its stderr) of ``rigcal -q ARGV``
    (with ``python``: that interpreter command line instead of the console script)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    done = subprocess.run(
        [*(python or [str(Path(sys.executable).parent / "rigcal")]), "-q", *argv],
        capture_output=True,
        text=True,
        check=False,
        env=env if env is not None else _child_env(),
    )
    wall = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    if done.returncode not in (0, 1, 6):
        raise SystemExit(done.stderr)
    return json.loads(done.stdout), wall, cpu, done.stderr


def _child_env(**extra: str) -> dict[str, str]:
    """This environment, writing bytecode as an ordinary install does."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    return env | extra


# The command in a child that says its CPU time when the check proper begins and how many
# kernels it compiled (rather than loaded from their cache).
_MARKED = """
import sys, time
import rigcal.drift.targetless as t
check = t.check_targetless
def marked(*a, **k):
    print(f"STARTUP_CPU_S {time.process_time():.3f}", file=sys.stderr)
    return check(*a, **k)
t.check_targetless = marked
from rigcal.cli.main import main
from rigcal.jit import COMPILED
rc = main(sys.argv[1:])
print(f"KERNELS_COMPILED {len(COMPILED)}", file=sys.stderr)
print(f"MAIN_THREAD_CPU_S {time.thread_time():.3f}", file=sys.stderr)
print(f"PROCESS_CPU_S {time.process_time():.3f}", file=sys.stderr)
sys.exit(rc)
"""


def importtime(stderr: str, top: int = 12) -> dict[str, object]:
    """``-X importtime``'s lines: the costliest imports made at top level (not inside
    another import: what the command asked for) by cumulative time, and each package's own
    time summed (ms; the child's wall clock, so under load they measure the load too)."""
    rows = []
    for line in stderr.splitlines():
        if not line.startswith("import time:") or "self [us]" in line:
            continue
        own, cum, name = line[len("import time:") :].split("|")
        rows.append((len(name) - len(name.lstrip()), name.strip(), int(own), int(cum)))
    first = min((r[0] for r in rows), default=0)
    outer = sorted((r for r in rows if r[0] == first), key=lambda r: -r[3])
    packages: dict[str, int] = {}
    for _, name, own, _ in rows:
        packages[name.split(".")[0]] = packages.get(name.split(".")[0], 0) + own
    return {
        "total_ms": round(sum(r[2] for r in rows) / 1000),
        "modules": len(rows),
        "top_level_cumulative_ms": {r[1]: round(r[3] / 1000) for r in outer[:top]},
        "package_self_ms": {
            k: round(v / 1000) for k, v in sorted(packages.items(), key=lambda kv: -kv[1])[:top]
        },
    }


def _marks(stderr: str) -> dict[str, float]:
    out = {}
    for line in stderr.splitlines():
        if line.startswith(("STARTUP_CPU_S ", "KERNELS_COMPILED ", "MAIN_THREAD_CPU_S ", "PROCESS_CPU_S ")):
            key, value = line.split()
            out[key.lower()] = float(value)
    return out


def _corrections(targetless: dict) -> list[object]:  # type: ignore[type-arg]
    return [targetless.get("correction_rotation_deg"), targetless.get("correction_translation_mm")]


def main_command(seq: Path, repeat: int, with_trajectory: bool, no_bytecode: bool) -> None:
    """The --sequence mode (module docstring)."""
    from rigcal.jobs import check_rig

    streams = open_streams(seq)
    dur = float(streams.image_stamps_s[-1] - streams.image_stamps_s[0])
    load0 = os.getloadavg()[0]
    _, icp_wall, icp_cpu = timed(streams.laser_odometry)
    tmp = Path(tempfile.mkdtemp())
    rig = tmp / "rig.yaml"  # outside the sequence (a check's outputs may not go inside an input)
    rig.write_bytes((seq / "rig.yaml").read_bytes())
    _, read_wall, read_cpu = timed(lambda: open_streams(seq, rig_file=rig))
    inproc, in_wall, in_cpu = timed(lambda: check_rig(rig, sequence=seq, no_log=True).record)
    base = ["check", str(rig), "--sequence", str(seq), "--no-log", "--json"]
    python = [sys.executable, "-X", "importtime", "-c", _MARKED]
    marked, m_wall, m_cpu, m_err = command(base, python=python)  # first: writes any bytecode missing
    runs = [command(base)[:3] for _ in range(repeat)]
    wall = min(r[1] for r in runs)
    cpu = min(r[2] for r in runs)
    rec = runs[0][0]
    marks = _marks(m_err)
    row: dict[str, object] = {
        "sequence": str(seq),
        "drive_s": round(dur, 1),
        "load": [round(load0, 1), round(os.getloadavg()[0], 1)],
        "odometry_s": {"wall": round(icp_wall, 2), "cpu": round(icp_cpu, 2)},
        "in_process_s": {
            "check_rig": {"wall": round(in_wall, 2), "cpu": round(in_cpu, 2), "verdict": inproc["verdict"]},
            "reading_the_sequence": {"wall": round(read_wall, 2), "cpu": round(read_cpu, 2)},
        },
        "rigcal_check_s": {
            "runs": [{"wall": round(r[1], 2), "cpu": round(r[2], 2)} for r in runs],
            "verdict": rec["verdict"],
        },
        "command_over_in_process": {"wall": round(wall / in_wall, 3), "cpu": round(cpu / in_cpu, 3)},
        "command_over_odometry": {"wall": round(wall / icp_wall, 3), "cpu": round(cpu / icp_cpu, 3)},
        "x_real_time_wall": {"command": round(dur / wall, 2), "in_process": round(dur / in_wall, 2)},
        "importtime_child": {
            "wall": round(m_wall, 2),
            "cpu": round(m_cpu, 2),
            "startup_cpu_s": marks.get("startup_cpu_s"),
            "main_thread_cpu_s": marks.get("main_thread_cpu_s"),
            "process_cpu_s": marks.get("process_cpu_s"),
            "kernels_compiled": marks.get("kernels_compiled"),
            "verdict": marked["verdict"],
            "imports": importtime(m_err),
        },
        "corrections": {
            "command": _corrections(rec["targetless"]),
            "in_process": _corrections(inproc["targetless"]),
        },
    }
    if no_bytecode:
        empty = tempfile.mkdtemp()
        env = _child_env(PYTHONDONTWRITEBYTECODE="1", PYTHONPYCACHEPREFIX=empty)
        rec3, wall3, cpu3, _ = command(base, env=env)
        row["rigcal_check_no_bytecode_s"] = {
            "wall": round(wall3, 2),
            "cpu": round(cpu3, 2),
            "verdict": rec3["verdict"],
        }
    if with_trajectory:
        tum = tmp / "trajectory.tum"
        write_tum(tum, planar_trajectory(streams.scan_stamps_s, streams.laser_odometry().poses))
        rec2, wall2, cpu2, _ = command([*base, "--trajectory", str(tum)])
        row["rigcal_check_trajectory_s"] = {
            "wall": round(wall2, 2),
            "cpu": round(cpu2, 2),
            "verdict": rec2["verdict"],
            "over_odometry": {"wall": round(wall2 / icp_wall, 3), "cpu": round(cpu2 / icp_cpu, 3)},
            "x_real_time_wall": round(dur / wall2, 2),
            "corrections": _corrections(rec2["targetless"]),
        }
    print(json.dumps(row, indent=1))


def main_against(seq: Path, before_src: Path, pairs: int) -> None:
    """The --against mode (module docstring)."""
    import statistics

    tmp = Path(tempfile.mkdtemp())
    rig = tmp / "rig.yaml"
    rig.write_bytes((seq / "rig.yaml").read_bytes())
    base = ["check", str(rig), "--sequence", str(seq), "--no-log", "--json"]
    here = str(Path(__file__).resolve().parents[1] / "src")
    sides = {"before": _child_env(PYTHONPATH=str(before_src)), "after": _child_env(PYTHONPATH=here)}
    runs: dict[str, list[dict[str, float]]] = {"before": [], "after": []}
    first: dict | None = None  # type: ignore[type-arg]
    identical = True
    for _ in range(pairs):
        for side, env in sides.items():
            load = os.getloadavg()[0]
            rec, wall, cpu, _ = command(base, env=env)
            same = {k: v for k, v in rec.items() if k != "checked_utc"}
            same["targetless"] = {k: v for k, v in rec["targetless"].items() if k != "check_s"}
            first = first or same
            identical = identical and same == first
            runs[side].append({"wall": round(wall, 2), "cpu": round(cpu, 2), "load": round(load, 1)})

    def summary(rows: list[dict[str, float]], key: str) -> dict[str, float]:
        values = [r[key] for r in rows]
        return {"median": round(statistics.median(values), 2), "min": min(values), "max": max(values)}

    pairs_cpu = [a["cpu"] / b["cpu"] for a, b in zip(runs["after"], runs["before"], strict=True)]
    pairs_wall = [a["wall"] / b["wall"] for a, b in zip(runs["after"], runs["before"], strict=True)]
    print(
        json.dumps(
            {
                "sequence": str(seq),
                "before_src": str(before_src),
                "runs": runs,
                "wall_s": {side: summary(rows, "wall") for side, rows in runs.items()},
                "cpu_s": {side: summary(rows, "cpu") for side, rows in runs.items()},
                "after_over_before_by_pair": {
                    "cpu": [round(x, 3) for x in pairs_cpu],
                    "wall": [round(x, 3) for x in pairs_wall],
                    "cpu_median": round(statistics.median(pairs_cpu), 3),
                    "wall_median": round(statistics.median(pairs_wall), 3),
                },
                "records_identical": identical,
                "verdict": first["verdict"] if first else None,
            },
            indent=1,
        )
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cache", type=Path, default=Path("/tmp/rigcal-bench-targetless"))
    ap.add_argument("--world", default="corridor-loop")
    ap.add_argument("--seed", type=int, default=2)
    ap.add_argument("--start-s", type=float, default=0.0)
    ap.add_argument("--length", type=float, default=60.0)
    ap.add_argument("--sequence", type=Path, help="time `rigcal check` on this sequence folder instead")
    ap.add_argument(
        "--repeat", type=int, default=1, help="--sequence: timed command runs (the least is used)"
    )
    ap.add_argument(
        "--trajectory", action="store_true", help="--sequence: also the command with --trajectory"
    )
    ap.add_argument("--no-bytecode", action="store_true", help="--sequence: also a run with no bytecode")
    ap.add_argument("--against", type=Path, help="--sequence: A/B of the command against this src folder")
    ap.add_argument("--pairs", type=int, default=6, help="--against: pairs of runs")
    args = ap.parse_args()
    if args.sequence is not None and args.against is not None:
        main_against(args.sequence, args.against, args.pairs)
        return
    if args.sequence is not None:
        main_command(args.sequence, args.repeat, args.trajectory, args.no_bytecode)
        return
    full = open_streams(drive(args.cache, args.world, args.seed))
    w = window(full, args.start_s, args.length)
    dur = float(w.scan_stamps_s[-1] - w.scan_stamps_s[0])
    assert w.rig is not None
    load0 = os.getloadavg()[0]
    reuse = TargetlessSettings(scan_rate_hz=None)
    _, icp_wall, icp_cpu = timed(w.laser_odometry)
    res, wall1, cpu1 = timed(lambda: check_targetless(w.rig, w, reuse))
    _, wall2, cpu2 = timed(lambda: check_targetless(w.rig, w, reuse))
    fresh = window(full, args.start_s, args.length)
    fresh.odometry_covariance = False  # as `rigcal check` opens a drive
    main0 = time.thread_time()
    res3, wall3, cpu3 = timed(lambda: check_targetless(fresh.rig, fresh))
    main3 = time.thread_time() - main0
    tum = Path(tempfile.mkdtemp()) / "trajectory.tum"
    write_tum(tum, planar_trajectory(w.scan_stamps_s, w.laser_odometry().poses))
    again = window(full, args.start_s, args.length)
    res4, wall4, cpu4 = timed(lambda: reused(again, tum))
    row = {
        "world": args.world,
        "window_s": round(dur, 1),
        "verdict": res.verdict,
        "load": [round(load0, 1), round(os.getloadavg()[0], 1)],
        "odometry_s": {"wall": round(icp_wall, 2), "cpu": round(icp_cpu, 2)},
        "check_s": {"wall": round(wall1, 2), "cpu": round(cpu1, 2)},
        "check_again_s": {"wall": round(wall2, 2), "cpu": round(cpu2, 2)},
        "end_to_end_s": {
            "wall": round(wall3, 2),
            "cpu": round(cpu3, 2),
            "main_thread_cpu": round(main3, 2),
            "verdict": res3.verdict,
        },
        "reused_trajectory_s": {"wall": round(wall4, 2), "cpu": round(cpu4, 2), "verdict": res4.verdict},
        "check_over_odometry": {"wall": round(wall1 / icp_wall, 2), "cpu": round(cpu1 / icp_cpu, 2)},
        "end_to_end_over_odometry": {
            "wall": round(wall3 / icp_wall, 3),
            "cpu": round(cpu3 / icp_cpu, 3),
            "main_thread_cpu": round(main3 / icp_cpu, 3),
        },
        "reused_trajectory_over_odometry": {
            "wall": round(wall4 / icp_wall, 3),
            "cpu": round(cpu4 / icp_cpu, 3),
        },
        "x_real_time_cpu": {
            "odometry": round(dur / icp_cpu, 1),
            "check": round(dur / cpu1, 1),
            "check_again": round(dur / cpu2, 1),
            "odometry_and_check": round(dur / (icp_cpu + cpu1), 1),
            "end_to_end": round(dur / cpu3, 1),
            "end_to_end_main_thread": round(dur / main3, 1),
            "reused_trajectory": round(dur / cpu4, 1),
        },
        "x_real_time_wall": {
            "check": round(dur / wall1, 2),
            "odometry_and_check": round(dur / (icp_wall + wall1), 2),
            "end_to_end": round(dur / wall3, 2),
            "reused_trajectory": round(dur / wall4, 2),
        },
        "corrections": {
            "odometry_every_scan": [
                res.record.get("correction_rotation_deg"),
                res.record.get("correction_translation_mm"),
            ],
            "end_to_end": [
                res3.record.get("correction_rotation_deg"),
                res3.record.get("correction_translation_mm"),
            ],
            "reused_trajectory": [
                res4.record.get("correction_rotation_deg"),
                res4.record.get("correction_translation_mm"),
            ],
        },
    }
    print(json.dumps(row, indent=1))


if __name__ == "__main__":
    main()
