"""ICP from the wheel odometry against ICP from the previous motion, on a real log and on
sparse simulated loops.

Killian Court (the rtb-data package's g2o file, 3873 ROBOTLASER1 scans, ~0.5 m apart):
imported as ``rigcal import-carmen`` does (the g2o's sequential edges as the odometry,
rigcal.recordings.carmen.carmen_odometry); each method is scored against the g2o's vertices (the
SLAM-optimised poses) by ATE (evo's, SE(2)-aligned) and the relation error of Kuemmerle
et al. 2009 over consecutive scans (mean +- std, m and deg; rigcal.localize.metrics.
relation_error; the relations are the optimised poses' own, not the hand-verified
relation files of the Freiburg site). Across the odometry's 15 gaps (its logger paused)
its motion starts ICP unless the scans contradict it, as ``rigcal localize`` does;
``--gaps none`` takes no motion from it there. Speed: the log's duration over the run's wall time
(ICP, and ICP with loop closure).

Simulated loops (``--sim``): each of the cubicle and corridor loops driven once and
scanned at 1 Hz (``--rate-hz``; scans ~1 m and up to ~60 deg apart, as the subsampled
logs of SLAM papers), with simulated wheel odometry (rigcal.sim.drive.wheel_odometry);
ATE and loop closure error of ICP from the previous motion, ICP from the odometry, each
with and without loop closure (rigcal.localize.loop_closure), and the odometry.

    uv sync --group bench        # rtb-data
    .venv/bin/python benchmarks/bench_wheel_odometry.py [--sim [--rate-hz R]] [--scans N] [--gaps none]
"""

from __future__ import annotations

import argparse
import tempfile
import time
import zipfile
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from rigcal.geometry import pose_of, se2
from rigcal.io.wheel_odometry import icp_starts, laser_motions
from rigcal.localize.icp import IcpParams
from rigcal.localize.loop_closure import close_loops
from rigcal.localize.metrics import anchored, evaluate, relation_error
from rigcal.localize.odometry import icp_odometry
from rigcal.recordings.carmen import carmen_odometry, read_carmen

FloatArray = np.ndarray


def chained(steps: FloatArray) -> FloatArray:
    T = np.eye(3)
    out = [pose_of(T)]
    for s in steps:
        T = T @ se2(s)
        out.append(pose_of(T))
    return np.array(out)


def killian_log() -> tuple[Any, Any, str]:
    """The Killian Court log (rtb-data's killian.g2o), its odometry, and how it was read."""
    archive = resources.files("rtbdata") / "data" / "killian.g2o.zip"
    with tempfile.TemporaryDirectory() as tmp, zipfile.ZipFile(str(archive)) as z:
        z.extract("killian.g2o", tmp)
        log = read_carmen(Path(tmp) / "killian.g2o")
        odom, how = carmen_odometry(log, "killian.g2o")
    assert odom is not None
    return log, odom, how


def killian_row(name: str, est: FloatArray, gt: FloatArray) -> str:
    """A table row's first cells: ``name``, the ATE and end error of ``est`` (N, 3) against
    ``gt`` and the relation error over consecutive scans (mean ± std, m and deg)."""
    m = evaluate(anchored(est, gt), gt)
    r = relation_error(est, gt)
    return (
        f"| {name} | {m['ate_rmse_m']:.3f} | {m['end_position_error_m']:.2f} "
        f"| {r['trans_mean_m']:.4f} ± {r['trans_std_m']:.4f} "
        f"| {r['rot_mean_deg']:.3f} ± {r['rot_std_deg']:.3f} |"
    )


def killian(n: int | None, gaps: str = "contradict") -> None:
    """``gaps``: across the odometry's gaps its motion starts ICP unless the scans
    contradict it ("contradict", as rigcal localize), or ICP takes no motion from it
    there ("none")."""
    log, odom, how = killian_log()
    scans, gt = log.scans[:n], log.laser_poses[:n]
    t = np.array([s.stamp_s for s in scans])
    guess, gap_guess = icp_starts(odom, t)
    duration = float(t[-1] - t[0])
    rows = {}
    for name, g in (("ICP from the previous motion", None), ("ICP from the odometry", guess)):
        t0 = time.perf_counter()
        across = gap_guess if g is not None and gaps == "contradict" else None
        od = icp_odometry(scans, IcpParams(method="point-to-line"), guess=g, gap_guess=across)
        if g is not None:
            n_gaps = int(np.isfinite(gap_guess).all(axis=1).sum())
            print(f"{name}: {od.gap_kept} of {n_gaps} steps across the odometry's gaps kept its motion")
        wall = time.perf_counter() - t0
        rows[name] = (od.poses, duration / wall)
        t1 = time.perf_counter()
        lc = close_loops(scans, od.poses)
        rows[f"{name} + loop closure"] = (lc.poses, duration / (wall + time.perf_counter() - t1))
        print(f"{name}: closures {lc.counts}")
    rows["odometry (g2o sequential edges)"] = (chained(laser_motions(odom, t, over_gaps=True)), float("nan"))
    print(f"Killian Court: {len(scans)} scans, {duration:.0f} s of data; odometry: {how}")
    print(
        "| method | ATE (m) | loop/end error (m) | relation error (m) | relation error (deg) | x real time |"
    )
    print("|---|---|---|---|---|---|")
    for name, (est, speed) in rows.items():
        print(f"{killian_row(name, est, gt)} {speed:.0f} |")


def simulated(rate_hz: float) -> None:
    from rigcal.io.trajectory import read_tum
    from rigcal.localize.pipeline import planar_at
    from rigcal.recordings.sequence import read_sequence
    from rigcal.sim.drive import DriveSpec
    from rigcal.sim.world import world_named

    print(f"| loop ({rate_hz:g} Hz scans) | method | ATE (m) | loop closure error (m) |")
    print("|---|---|---|---|")
    for world in ("cubicle-loop", "corridor-loop"):
        with tempfile.TemporaryDirectory() as tmp:
            from rigcal.sim.drive import write_drive

            spec = DriveSpec(laser_rate_hz=rate_hz, images=False, wheel_odometry=True)
            write_drive(world_named(world), spec, f"{tmp}/seq")
            seq = read_sequence(f"{tmp}/seq")
            assert seq.odometry is not None
            t = np.array([s.stamp_s for s in seq.scans])
            gt = planar_at(read_tum(f"{tmp}/seq/groundtruth.tum"), t)
            guess = laser_motions(seq.odometry, t)
            ests = {
                "ICP from the previous motion": icp_odometry(seq.scans).poses,
                "ICP from the odometry": icp_odometry(seq.scans, guess=guess).poses,
                "odometry": chained(guess),
            }
            for name in list(ests)[:2]:
                ests[f"{name} + loop closure"] = close_loops(seq.scans, ests[name]).poses
            for name, est in ests.items():
                m = evaluate(anchored(est, gt), gt)
                print(f"| {world} | {name} | {m['ate_rmse_m']:.3f} | {m['loop_closure_error_m']:.3f} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sim", action="store_true", help="the simulated loops instead of Killian Court")
    ap.add_argument("--scans", type=int, default=None, help="only the log's first N scans")
    ap.add_argument("--rate-hz", type=float, default=1.0, help="the simulated laser's rate")
    ap.add_argument(
        "--gaps",
        choices=("contradict", "none"),
        default="contradict",
        help="Killian: across the odometry's gaps its motion starts ICP unless the scans contradict it "
        "(as rigcal localize), or none is taken there",
    )
    a = ap.parse_args()
    if a.sim:
        simulated(a.rate_hz)
    else:
        killian(a.scans, a.gaps)


if __name__ == "__main__":
    main()
