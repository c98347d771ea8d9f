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
--json`` (RIG a copy of DIR/rig.yaml) in a new process (starting Python, imports, loading the compiled
kernels from their cache, reading the sequence, the check), without and with
``--trajectory`` (the reference odometry written as a TUM file), each timed by the wall
clock and the child process's CPU time, against the laser odometry of every scan of the
same sequence in this process:

    .venv/bin/python benchmarks/bench_targetless_speed.py --sequence /tmp/c60
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


def command(argv: list[str]) -> tuple[dict, float, float]:  # type: ignore[type-arg]
    """(the JSON printed, wall s, CPU s of the child) of ``rigcal ARGV``."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    done = subprocess.run(
        [str(Path(sys.executable).parent / "rigcal"), "-q", *argv],
        capture_output=True,
        text=True,
        check=False,
    )
    wall = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    if done.returncode not in (0, 1, 6):
        raise SystemExit(done.stderr)
    return json.loads(done.stdout), wall, cpu


def main_command(seq: Path) -> None:
    """The --sequence mode (module docstring)."""
    streams = open_streams(seq)
    dur = float(streams.image_stamps_s[-1] - streams.image_stamps_s[0])
    load0 = os.getloadavg()[0]
    _, icp_wall, icp_cpu = timed(streams.laser_odometry)
    tmp = Path(tempfile.mkdtemp())
    tum = tmp / "trajectory.tum"
    write_tum(tum, planar_trajectory(streams.scan_stamps_s, streams.laser_odometry().poses))
    rig = tmp / "rig.yaml"  # outside the sequence (a check's outputs may not go inside an input)
    rig.write_bytes((seq / "rig.yaml").read_bytes())
    base = ["check", str(rig), "--sequence", str(seq), "--no-log", "--json"]
    rec, wall, cpu = command(base)
    rec2, wall2, cpu2 = command([*base, "--trajectory", str(tum)])
    row = {
        "sequence": str(seq),
        "drive_s": round(dur, 1),
        "load": [round(load0, 1), round(os.getloadavg()[0], 1)],
        "odometry_s": {"wall": round(icp_wall, 2), "cpu": round(icp_cpu, 2)},
        "rigcal_check_s": {"wall": round(wall, 2), "cpu": round(cpu, 2), "verdict": rec["verdict"]},
        "rigcal_check_trajectory_s": {
            "wall": round(wall2, 2),
            "cpu": round(cpu2, 2),
            "verdict": rec2["verdict"],
        },
        "over_odometry": {
            "check": {"wall": round(wall / icp_wall, 3), "cpu": round(cpu / icp_cpu, 3)},
            "check_trajectory": {"wall": round(wall2 / icp_wall, 3), "cpu": round(cpu2 / icp_cpu, 3)},
        },
        "x_real_time_wall": {"check": round(dur / wall, 2), "check_trajectory": round(dur / wall2, 2)},
        "corrections": {
            "check": [
                rec["targetless"].get("correction_rotation_deg"),
                rec["targetless"].get("correction_translation_mm"),
            ],
            "check_trajectory": [
                rec2["targetless"].get("correction_rotation_deg"),
                rec2["targetless"].get("correction_translation_mm"),
            ],
        },
    }
    print(json.dumps(row, indent=1))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cache", type=Path, default=Path("/tmp/rigcal-bench-targetless"))
    ap.add_argument("--world", default="corridor-loop")
    ap.add_argument("--seed", type=int, default=2)
    ap.add_argument("--start-s", type=float, default=0.0)
    ap.add_argument("--length", type=float, default=60.0)
    ap.add_argument("--sequence", type=Path, help="time `rigcal check` on this sequence folder instead")
    args = ap.parse_args()
    if args.sequence is not None:
        main_command(args.sequence)
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
