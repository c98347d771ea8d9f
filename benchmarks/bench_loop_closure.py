"""Loop closure on and off: on the Killian Court log, and on the simulated loops for every
method.

Killian Court (the rtb-data package's g2o file, 3873 ROBOTLASER1 scans ~0.5 m apart,
7673 s of data), imported as ``rigcal import-carmen`` does: ICP started from the log's
odometry (rigcal.localize.odometry.icp_odometry), then loop closure on its poses
(rigcal.localize.loop_closure.close_loops, the pose graph on each back end installed; the
odometry edges carry ICP's step covariances, the closures their fit's).
Scored against the g2o's vertices (the SLAM-optimised poses) by ATE (SE(2)-aligned), the
end position error and the relation error of Kuemmerle et al. 2009 over consecutive
scans and over all pairs of scans 10 m of path apart (mean +- std; rigcal.localize.
metrics.relation_error). Speed, measured in the same process: the loop closure's time as a
ratio to ICP's, and the log's duration over ICP + loop closure's wall and CPU time (x real
time); the load average is printed beside it.

Simulated loops (``--sim``): each loop of the paper driven once (images and scans, seed
0), localized by ``rigcal localize --loop-closure`` (rigcal.localize.pipeline.run) with
every method loop closure takes (icp, kf, iasm, hiasm): ATE and loop closure error of
each with closure off and on, and the closures' counts.

    uv sync --group bench --extra gtsam     # rtb-data, GTSAM
    .venv/bin/python benchmarks/bench_loop_closure.py [--scans N] [--backend scipy|gtsam|both]
        [--steps own|own+drift|fixed] [--global-every N] [--workers 1,2] [--submap-scans N]
    .venv/bin/python benchmarks/bench_loop_closure.py --solver [--scans N]
    .venv/bin/python benchmarks/bench_loop_closure.py --sim [--methods icp,kf,iasm,hiasm] [--drives DIR]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from collections import Counter
from pathlib import Path

import numpy as np

from bench_wheel_odometry import killian_log
from rigcal.io.wheel_odometry import icp_starts, laser_motions
from rigcal.localize.icp import IcpParams
from rigcal.localize.loop_closure import Closure, LoopParams, LoopResult, close_loops, compose, relative
from rigcal.localize.metrics import anchored, evaluate, relation_error, rpe_pairs
from rigcal.localize.odometry import icp_odometry
from rigcal.localize.pose_graph import gtsam_available


def _row(name: str, est: np.ndarray, gt: np.ndarray, speed: str) -> str:
    m = evaluate(anchored(est, gt), gt)
    r1 = relation_error(est, gt)
    r10 = relation_error(est, gt, rpe_pairs(gt, 10.0))
    return (
        f"| {name} | {m['ate_rmse_m']:.3f} | {m['end_position_error_m']:.2f} "
        f"| {r1['trans_mean_m']:.4f} ± {r1['trans_std_m']:.4f} "
        f"| {r1['rot_mean_deg']:.3f} ± {r1['rot_std_deg']:.3f} "
        f"| {r10['trans_mean_m']:.3f} ± {r10['trans_std_m']:.3f} "
        f"| {r10['rot_mean_deg']:.2f} ± {r10['rot_std_deg']:.2f} "
        f"| {speed} |"
    )


# An accepted closure is counted true when its relative pose is within these of the g2o's.
TRUE_M, TRUE_DEG = 0.5, 2.0


def _true(closures: list[Closure], gt: np.ndarray) -> int:
    """How many of the closures' T_j_i are within TRUE_M / TRUE_DEG of the truth's."""
    if not closures:
        return 0
    z = np.array([c.T_j_i for c in closures], dtype=float)
    t = relative(gt[[c.j for c in closures]], gt[[c.i for c in closures]])
    off_deg = np.degrees(np.abs(np.angle(np.exp(1j * (z[:, 2] - t[:, 2])))))
    return int(np.sum((np.hypot(*(z[:, :2] - t[:, :2]).T) < TRUE_M) & (off_deg < TRUE_DEG)))


def _same(a: LoopResult, b: LoopResult) -> bool:
    """Whether two runs gave the same closures (pairs, verdicts, poses) and poses, bit for bit."""

    def key(c: Closure) -> tuple[object, ...]:
        pose = None if c.T_j_i is None else tuple(c.T_j_i)
        return c.i, c.j, c.why_not, c.kernel_rejected, pose

    return [key(c) for c in a.closures] == [key(c) for c in b.closures] and np.array_equal(a.poses, b.poses)


def killian(
    n: int | None,
    backends: list[str],
    steps: str = "own+drift",
    global_every: int = 5,
    workers: tuple[int, ...] = (2,),
    submap_scans: int = 1,
) -> None:
    log, odom, _ = killian_log()
    scans, gt = log.scans[:n], log.laser_poses[:n]
    t = np.array([s.stamp_s for s in scans])
    duration = float(t[-1] - t[0])
    guess, gap_guess = icp_starts(odom, t)
    icp_odometry(scans[:50], IcpParams(method="point-to-line"), guess=guess[:49])  # compile / load kernels
    w0, c0 = time.perf_counter(), time.process_time()
    od = icp_odometry(
        scans, IcpParams(method="point-to-line"), guess=guess, gap_guess=gap_guess, submap_scans=submap_scans
    )
    icp_wall, icp_cpu = time.perf_counter() - w0, time.process_time() - c0
    load = [os.getloadavg()[0]]
    print(
        f"Killian Court: {len(scans)} scans, {duration:.0f} s of data; "
        f"ICP {icp_wall:.1f} s wall, {icp_cpu:.1f} s CPU (the step matched to the last {submap_scans} scans)"
    )
    header = (
        "| method | ATE (m) | end error (m) | relation error, consecutive (m) | (deg) "
        "| relation error, 10 m apart (m) | (deg) | speed |"
    )
    w0 = time.perf_counter()
    prev = icp_odometry(scans, IcpParams(method="point-to-line"))
    prev_speed = f"{duration / (time.perf_counter() - w0):.0f}x real time"
    # The log's odometry chained alone (the g2o's sequential edges, which its vertices
    # are the optimum of): how far the reference itself follows it step by step.
    wheels = np.zeros((len(scans), 3))
    for k, step in enumerate(laser_motions(odom, t, over_gaps=True)):
        wheels[k + 1] = compose(wheels[k][None], step[None])[0]
    rows = [
        _row("the log's odometry alone", wheels, gt, "-"),
        _row("ICP from the previous motion", prev.poses, gt, prev_speed),
        _row("ICP from the odometry", od.poses, gt, f"{duration / icp_wall:.0f}x real time"),
    ]
    for backend in backends:
        first: LoopResult | None = None
        for threads in workers:
            w0, c0 = time.perf_counter(), time.process_time()
            params = LoopParams(
                backend=backend,
                global_every=global_every,
                step_drift=steps == "own+drift",
                workers=threads,
            )
            lc = close_loops(scans, od.poses, params, None if steps == "fixed" else od.covariance)
            wall, cpu = time.perf_counter() - w0, time.process_time() - c0
            load.append(os.getloadavg()[0])
            c = lc.counts
            print(
                f"{backend}, {threads} thread(s): closures proposed {c['proposed']}, "
                f"accepted {c['accepted']}, rejected by the verification {c['rejected_by_verification']}, "
                f"by the kernel {c['rejected_by_kernel']}; "
                f"loop closure {wall:.1f} s wall ({wall / icp_wall:.2f}x ICP's), "
                f"{cpu:.1f} s CPU ({cpu / icp_cpu:.2f}x ICP's); load average {load[-1]:.1f}"
            )
            if first is None:
                first = lc
                _by_search(lc, gt)
            else:
                print(f"  the same closures and poses as with {workers[0]} thread(s): {_same(first, lc)}")
            speed = (
                f"{duration / (icp_wall + wall):.0f}x real time wall, {duration / (icp_cpu + cpu):.0f}x CPU; "
                f"closure {cpu / icp_cpu:.2f}x ICP's CPU"
            )
            name = f"ICP from the odometry + loop closure ({backend}, {threads} thread(s))"
            rows.append(_row(name, lc.poses, gt, speed))
    print(f"load average (1 min) over the runs: {min(load):.1f}-{max(load):.1f}")
    print(header)
    print("|---|---|---|---|---|---|---|---|")
    print("\n".join(rows))
    # Hess et al. 2016, Table I (Killian Court, against the Freiburg site's relations).
    cartographer = "| - | - | 0.0395 ± 0.0488 | 0.352 ± 0.353 | - | - | 40x real time on 6 cores |"
    print(f"| Cartographer (published) {cartographer}")


def solver(n: int | None) -> None:
    """The scipy back end's solve against its reference (the generic sparse least squares
    and its old 1e-7 stop) on every graph a loop closure run over the log's first N scans
    re-optimises, in this process: CPU time of each and the largest difference."""
    from rigcal.localize import loop_closure, pose_graph

    log, odom, _ = killian_log()
    scans = log.scans[:n]
    guess, gap_guess = icp_starts(odom, np.array([s.stamp_s for s in scans]))
    od = icp_odometry(scans, IcpParams(method="point-to-line"), guess=guess, gap_guess=gap_guess)
    graphs: list[pose_graph.PoseGraph] = []
    optimise = loop_closure.optimise

    def kept(g: pose_graph.PoseGraph, backend: str = "scipy") -> tuple[np.ndarray, np.ndarray]:
        graphs.append(g)
        return optimise(g, backend)

    loop_closure.optimise = kept  # type: ignore[assignment]
    close_loops(scans, od.poses, LoopParams(backend="scipy"), od.covariance)
    loop_closure.optimise = optimise
    tolerance = pose_graph.STEP_TOLERANCE
    pose_graph.STEP_TOLERANCE = 1e-7
    c0 = time.process_time()
    ref = [pose_graph._scipy_optimum_reference(g) for g in graphs]
    ref_cpu = time.process_time() - c0
    pose_graph.STEP_TOLERANCE = tolerance
    c0 = time.process_time()
    new = [pose_graph._scipy_optimum(g) for g in graphs]
    new_cpu = time.process_time() - c0
    diff = max(float(np.abs(a - b).max()) for a, b in zip(ref, new, strict=True))
    print(
        f"{len(graphs)} graphs of {len(graphs[0].poses)}-{len(graphs[-1].poses)} poses: reference "
        f"{ref_cpu:.2f} s CPU, block-assembled SPD solve {new_cpu:.2f} s ({ref_cpu / new_cpu:.2f}x); "
        f"largest difference {diff:.2g} (m, rad); load average {os.getloadavg()[0]:.1f}"
    )


def _by_search(lc: LoopResult, gt: np.ndarray) -> None:
    """The local and the global search's closures: accepted (true), rejected and why."""
    for name, wide in (("local", False), ("global", True)):
        tried = [x for x in lc.closures if x.wide == wide]
        why = Counter(x.why_not.split(" ")[0] for x in tried if x.T_j_i is None)
        accepted = [x for x in tried if x.T_j_i is not None and not x.kernel_rejected]
        kernel = [x for x in tried if x.kernel_rejected]
        print(
            f"  {name} search: proposed {len(tried)}, accepted {len(accepted)} "
            f"({_true(accepted, gt)} within {TRUE_M} m / {TRUE_DEG} deg of the g2o's), rejected by the "
            f"kernel {len(kernel)} ({_true(kernel, gt)} of them true); by the verification "
            f"{dict(why.most_common())}"
        )


def simulated(methods: list[str], drives: str | None = None) -> None:
    from rigcal.localize.pipeline import run
    from rigcal.sim.drive import DriveSpec, write_drive
    from rigcal.sim.world import world_named

    print(
        "| loop | method | ATE off (m) | ATE on (m) | loop closure error off (m) | on (m) "
        "| closures (proposed / accepted) |"
    )
    print("|---|---|---|---|---|---|---|")
    for world in ("cubicle-loop", "corridor-loop"):
        with tempfile.TemporaryDirectory() as tmp:
            seq = Path(drives or tmp) / world
            if not (seq / "sequence.yaml").exists():
                write_drive(world_named(world), DriveSpec(), str(seq))
            r = run(seq, methods, loop_closure=LoopParams())
            by = {m.method: m for m in r.methods}
            for name in methods:
                off, on = by[name], by[f"{name}+lc"]
                assert off.metrics is not None
                assert on.metrics is not None
                assert on.closures is not None
                c = on.closures.counts
                print(
                    f"| {world} | {name} | {off.metrics['ate_rmse_m']:.4f} | {on.metrics['ate_rmse_m']:.4f} "
                    f"| {off.metrics['loop_closure_error_m']:.4f} | {on.metrics['loop_closure_error_m']:.4f} "
                    f"| {c['proposed']} / {c['accepted']} |"
                )
    print(f"load average (1 min) at the end: {os.getloadavg()[0]:.1f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sim", action="store_true", help="the simulated loops instead of Killian Court")
    ap.add_argument("--methods", default="icp,kf,iasm,hiasm", help="--sim: the methods")
    ap.add_argument("--drives", default=None, help="--sim: keep the drives in (and reuse them from) DIR")
    ap.add_argument("--scans", type=int, default=None, help="only the log's first N scans")
    ap.add_argument("--backend", default="both", choices=["scipy", "gtsam", "both"])
    ap.add_argument(
        "--steps",
        default="own+drift",
        choices=["own", "own+drift", "fixed"],
        help="the odometry edges' covariance: ICP's own capped by the step prior plus the drift "
        "model's (LoopParams.step_drift, the default), ICP's own alone, or the fixed sigmas",
    )
    ap.add_argument(
        "--global-every",
        type=int,
        default=5,
        help="the global search at most every N keyframes (default 5; 0: off, the local search only)",
    )
    ap.add_argument(
        "--workers",
        default="2",
        help="loop closure's threads (LoopParams.workers), a run for each of a comma-separated list, "
        "e.g. 1,2: the same closures, the speed of each (default 2)",
    )
    ap.add_argument(
        "--submap-scans",
        type=int,
        default=1,
        help="ICP's steps matched to the last N scans (scan-to-submap; default 1: the previous scan)",
    )
    ap.add_argument(
        "--solver",
        action="store_true",
        help="time the scipy back end's solve against its reference on the graphs of a run",
    )
    a = ap.parse_args()
    if a.solver:
        solver(a.scans)
        return
    if a.sim:
        simulated(a.methods.split(","), a.drives)
        return
    backends = ["scipy", "gtsam"] if a.backend == "both" else [a.backend]
    if not gtsam_available() and "gtsam" in backends:
        print("GTSAM is not installed (uv sync --extra gtsam): scipy only")
        backends = ["scipy"]
    workers = tuple(int(w) for w in a.workers.split(","))
    killian(a.scans, backends, a.steps, a.global_every, workers, a.submap_scans)


if __name__ == "__main__":
    main()
