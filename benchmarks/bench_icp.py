"""Laser odometry by ICP on the simulated loops, in the form of the paper's Table 1.

One lap of each built-in loop (``rigcal.sim``: 1 cm range noise, 1 % dropouts; and the
cubicle loop without noise or dropouts) at a 10 Hz laser, localized with point-to-line
ICP (line normals, as ``rigcal localize`` runs it, and 5-nearest-neighbour normals) and
point-to-point ICP, scored against the ground truth
(``rigcal.localize.metrics``), with the mean (bias) and RMS of the scan-to-scan yaw
error. Time per scan is also given as a ratio to the laser's period (real time = 1).

Then the time per scan pair of the simulated Hokuyo (1081 beams over 270 deg, 40 Hz) on
the first 400 scans of the cubicle loop, by the laser odometry as ``rigcal localize`` runs
it (each scan's lines extracted for the line normals; each pair started from the previous
motion), and with 5-nearest-neighbour normals as before: the best of three passes
(other processes on the machine only slow a pass down), as a ratio to the laser's 25 ms
period and to the 5 ms target, and, when the ``bench`` dependency group is installed,
KISS-ICP's time per scan on the same scans in the same run (its configuration as in
``bench_killian.py``, range up to 30 m). ICP, the line extraction and the carrying of the
lines run their compiled kernels; the same odometry with their numpy / Python references
(``icp_odometry(..., kernel=False)``) is timed too, with the largest pose difference
between the two, and for each the time spent in the ICP steps alone (the line extraction
and carrying the lines over excluded). The kernels are compiled (or
loaded from numba's cache) before timing; ``jit_cost.py`` measures that first call.

    .venv/bin/python benchmarks/bench_icp.py
"""

from __future__ import annotations

import contextlib
import dataclasses
import time
from collections.abc import Callable, Iterator

import numpy as np

from rigcal.localize.icp import IcpParams
from rigcal.localize.metrics import anchored, evaluate, steps
from rigcal.localize.odometry import icp_odometry
from rigcal.scan import Scan
from rigcal.sim.drive import DriveSpec, Motion, laser_stamps, simulate_scans
from rigcal.sim.world import BUILTIN


def main() -> None:
    spec = DriveSpec(laser_rate_hz=10.0, seed=1)
    print("| world | method | loop closure (m) | loop closure (%) | avg position error (m) | ATE RMSE (m) "
          "| RPE 10 m (m) | step yaw bias (mdeg) | step yaw RMS (mdeg) "
          "| ms per scan | x real time |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    variants = {
        "point-to-line": IcpParams(),
        "point-to-line, 5-nearest normals": IcpParams(normals="neighbours"),
        "point-to-point": IcpParams(method="point-to-point"),
    }
    noiseless = dataclasses.replace(spec, range_sigma_m=0.0, dropout_fraction=0.0)
    for name, spec_w in (
        ("corridor-loop", spec),
        ("cubicle-loop", spec),
        ("cubicle-loop, noiseless", noiseless),
    ):
        world = BUILTIN[name.split(",")[0]]()
        motion = Motion(world, spec_w)
        stamps = laser_stamps(motion, spec_w)
        gt = motion.poses(stamps)
        scans = simulate_scans(world, gt, stamps, spec_w)
        for label, params in variants.items():
            t0 = time.perf_counter()
            od = icp_odometry(scans, params)
            ms = 1000.0 * (time.perf_counter() - t0) / len(scans)
            m = evaluate(anchored(od.poses, gt), gt)
            bias, rms = step_yaw_errors_mdeg(od.poses, gt)
            figures = (
                f"{m['loop_closure_error_m']:.3f} | {m['loop_closure_error_percent']:.2f} | "
                f"{m['average_position_error_m']:.3f} | {m['ate_rmse_m']:.3f} | {m['rpe_10m_rmse_m']:.3f} | "
                f"{bias:.2f} | {rms:.1f}"
            )
            speed = f"{ms:.1f} | {(1000.0 / spec.laser_rate_hz) / ms:.1f}"
            print(f"| {name} | {label} | {figures} | {speed} |", flush=True)

    pair_timing()


def pair_timing(target_ms: float = 5.0) -> None:
    """Time per 1081-point scan pair at 40 Hz (best of three passes)."""
    spec = DriveSpec(laser_rate_hz=40.0, seed=1)
    scans = hokuyo_loop_scans(spec)
    budget_ms = 1000.0 / spec.laser_rate_hz
    print()
    print(f"| method | beams | ms per scan pair | x real time ({budget_ms:.0f} ms) "
          f"| x {target_ms:.0f} ms target | time / KISS-ICP |")  # fmt: skip
    print("|---|---|---|---|---|---|")
    times: dict[str, float] = {}
    variants = {
        "point-to-line": (IcpParams(), True),
        "point-to-line, numpy / Python references": (IcpParams(), False),
        "point-to-line, 5-nearest normals": (IcpParams(normals="neighbours"), True),
        "point-to-point": (IcpParams(method="point-to-point"), True),
    }
    icp_odometry(scans[:3], IcpParams())  # compile the kernels (or load them) first
    poses = {}
    for label, (params, kernel) in variants.items():
        # The odometry as `rigcal localize` runs it: each scan's lines extracted (for the
        # line normals), restarts from zero motion included.
        with icp_timer() as spent:

            def work(params: IcpParams = params, label: str = label, kernel: bool = kernel) -> object:
                spent.append(0.0)  # a new pass
                poses[label] = icp_odometry(scans, params, kernel=kernel).poses
                return None

            times[label] = best_ms(work, len(scans) - 1)
        times[f"{label}: ICP steps alone"] = min(spent) / (len(scans) - 1)
    diff = np.abs(poses["point-to-line"] - poses["point-to-line, numpy / Python references"]).max()
    try:
        from bench_killian import kiss_icp_odometry  # the bench group's kiss-icp
    except ImportError:
        kiss = None
    else:
        kiss = best_ms(lambda: kiss_icp_odometry(scans, max_range_m=30.0), len(scans) - 1)
    beams = len(scans[0].ranges_m)
    for method, ms in [*times.items(), ("KISS-ICP", kiss)]:
        if ms is None:
            continue
        ratio = f"{ms / kiss:.2f}" if kiss else "-"
        print(f"| {method} | {beams} | {ms:.2f} | {budget_ms / ms:.1f} | {target_ms / ms:.2f} | {ratio} |")
    print(f"\nLargest pose difference, compiled kernels against their references, 400 scans: {diff:.1e}")


def hokuyo_loop_scans(spec: DriveSpec, count: int = 400) -> list[Scan]:
    """The first ``count`` scans of the simulated cubicle loop (a Hokuyo: 1081 beams)."""
    world = BUILTIN["cubicle-loop"]()
    motion = Motion(world, spec)
    stamps = laser_stamps(motion, spec)[:count]
    return simulate_scans(world, motion.poses(stamps), stamps, spec)


@contextlib.contextmanager
def icp_timer() -> Iterator[list[float]]:
    """Within: the milliseconds the odometry's ICP calls take add up in the list's last
    entry (append one per pass)."""
    import rigcal.localize.odometry as odometry

    spent: list[float] = []
    original = odometry.icp

    def timed(*args: object, **kwargs: object) -> object:
        t0 = time.perf_counter()
        out = original(*args, **kwargs)  # type: ignore[arg-type]
        spent[-1] += 1000.0 * (time.perf_counter() - t0)
        return out

    odometry.icp = timed  # type: ignore[assignment]
    try:
        yield spent
    finally:
        odometry.icp = original


def step_yaw_errors_mdeg(poses: np.ndarray, gt: np.ndarray) -> tuple[float, float]:
    """Mean (bias) and RMS of the scan-to-scan yaw error against the truth, millidegrees:
    a bias adds up round a loop driven one way."""
    est, true = steps(poses)[:, 2], steps(gt)[:, 2]
    e = np.degrees(np.angle(np.exp(1j * (est - true)))) * 1000.0
    return float(e.mean()), float(np.sqrt(np.mean(e * e)))


def best_ms(work: Callable[[], object], pairs: int, passes: int = 3) -> float:
    """Milliseconds per scan pair of the best of several passes of ``work``."""
    out = []
    for _ in range(passes):
        t0 = time.perf_counter()
        work()
        out.append(1000.0 * (time.perf_counter() - t0) / pairs)
    return min(out)


if __name__ == "__main__":
    main()
