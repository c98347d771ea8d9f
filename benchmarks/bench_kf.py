"""The Kalman filter against its inputs, lap by lap: ICP, VO, the KF with the paper's fixed
covariances and the KF with each step's own covariance (docs/localization.md).

For each built-in loop and seed a drive of ``--duration-s`` seconds (40 by default; the
whole lap with 0) is simulated (``rigcal simulate world``: 30 m laser at 40 Hz, 10 Hz
camera; ``--wheel-odometry`` adds the base's wheel odometry, which then is ICP's initial
guess and a KF input) and localized once: the laser odometry and the visual odometry
are computed once, then three filters are run on them (:data:`VARIANTS`: the paper's
fixed covariances, each step's own, and each step's own matched to its input's
innovations, which ``rigcal localize --method kf`` runs). Each is scored against the
truth (ATE RMSE after anchoring the first pose, as ``rigcal localize`` scores).

Consistency (NEES, normalized estimation error squared; 3 for a consistent 3-dof
estimate): each input's steps against the truth's motion over the same interval
(x, y, yaw in the step's start frame) with the step's covariance, and the KF's poses
against the truth with the filter's covariance. The mean over a lap is printed.

    .venv/bin/python benchmarks/bench_kf.py [--worlds cubicle-loop,corridor-loop]
        [--seeds 1-10] [--duration-s 40] [--wheel-odometry] [--keep DIR] [--reuse]
    .venv/bin/python benchmarks/bench_kf.py --seeds 1-2 --keep DIR --reuse --consistency
    .venv/bin/python benchmarks/bench_kf.py ... --reuse [--without vo] [--vo-axes yaw]

Round 9 (``--variants``, see :data:`ROUND9`): the filter's path is scored at the scans'
stamps (kalman.path_at, as ``rigcal localize``); laps with wheel odometry are the kept
laps copied by benchmarks/kf_wheel_laps.py (``--keep DIR2 --wheel-odometry --reuse``),
where ``--wheel-windows`` measures the wheel witness's window model (laps 1-2).

``--start-still S --gyro``: laps that begin standing still for S seconds with the simulated
gyroscope (``DriveSpec(start_still_s=S, gyro=True)``, kept as ``...-stillS-gyro``), each
filter run without the gyro and with it ("KEY-gyro"), the bias each ends with printed
beside the simulated one; every input scored over the whole drive, standstill included.

``--consistency`` prints, per lap and input, the figures the filter's error model is made
of (kalman.ICP_VARIANCE_RATIO, ICP_LAG1, VO_VARIANCE_RATIO, VO_LAG1: laps 1-2 of each loop).
"""

from __future__ import annotations

import argparse
import dataclasses
import pickle
import tempfile
import time
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
from scipy.stats import chi2

from bench_tracks import seeds_of
from rigcal.arrays import FloatArray
from rigcal.geometry import pose_of, se2
from rigcal.io.trajectory import read_tum
from rigcal.localize import kalman
from rigcal.localize.metrics import anchored, evaluate
from rigcal.localize.pipeline import kf_inputs, kf_measurements, planar_at
from rigcal.localize.streams import open_streams
from rigcal.sim.drive import DriveSpec, Motion, gyro_bias, write_drive
from rigcal.sim.world import BUILTIN

# The filters compared: the paper's fixed covariances (``rigcal localize --kf fixed``),
# round 2's weighted filter (each step's own covariance matched to its input's
# innovations, ICP's steps taken as independent, every VO run in every direction), round
# 4's (ICP's shared scan error, VO's shared frame error, its innovation gates, VO only
# where the filter is weaker) and the default (``--kf weighted``: round 4's with VO's
# forward error's Gauss-Markov memory, its forward variance ratio matched on line and the
# whiteness test on its forward innovations); and the odometry-driven filter (``--kf
# driven``: ICP's steps drive the prediction, VO and the wheels are its measurements).
# and the default with VO's bias states (kalman.VO_BIASED) or with the process noise of the
# drive (kalman.DRIVE_PROCESS), round 7's measured options; "kf-round7", the default without
# round 8's rule (kalman.KfParams.vo_pays 0: the same as the default while that stays 0);
# with --pays Q, the rule at q* = Q on the default ("kf-pays"), on the drive's process noise
# ("kf-pays-process") and on the driven filter ("kf-pays-driven"; Q -> 0 is --kf icp-first).
NO_MEMORY = {"vo_memory_s": 0.0, "vo_forward_adapt": False, "vo_forward_window": 0}
NO_GUARD = {"vo_guard": 0, "vo_forward_reference": False, "vo_pays": 0.0}
VARIANTS = {
    "kf-fixed": kalman.KF_MODES["fixed"],
    # The paper's error model (no shared parts, gates or memory) with each step's own
    # covariance, matched to its input's innovations.
    "kf-own": dataclasses.replace(
        kalman.KF_MODES["fixed"], weights=kalman.KfParams.weights, adapt=kalman.KfParams.adapt
    ),
    "kf-round4": dataclasses.replace(kalman.KF_MODES["weighted"], **NO_MEMORY, **NO_GUARD),  # type: ignore[arg-type]
    "kf-round5": dataclasses.replace(kalman.KF_MODES["weighted"], **NO_GUARD),  # type: ignore[arg-type]
    "kf-guard": dataclasses.replace(kalman.KF_MODES["weighted"], vo_forward_reference=False, vo_pays=0.0),
    "kf-round7": dataclasses.replace(kalman.KF_MODES["weighted"], vo_pays=0.0),
    "kf": kalman.KF_MODES["weighted"],
    "kf-driven": kalman.KF_MODES["driven"],
    "kf-bias": kalman.VO_BIASED,
    "kf-process": kalman.DRIVE_PROCESS,
    # Round 9 (run with --variants; laps with wheel odometry: --wheel-odometry): --kf
    # icp-first; the wheels as the guard's witness and not fused ("-witness"), as both.
    "kf-icp-first": kalman.KF_MODES["icp-first"],
    "kf-witness": dataclasses.replace(kalman.KF_MODES["weighted"], wheel_witness=True, wheel_input=False),
    # (the wheels fused as they come, with the witness; kalman.KfParams.wheel_calibrated off)
    "kf-witness-fused": dataclasses.replace(kalman.KF_MODES["weighted"], wheel_calibrated=False),
    "kf-icp-first-witness": dataclasses.replace(
        kalman.KF_MODES["icp-first"], wheel_witness=True, wheel_input=False
    ),
    "kf-icp-first-witness-fused": dataclasses.replace(kalman.KF_MODES["icp-first"], wheel_calibrated=False),
}
# The gyro's bias learned at the stops against ICP's turn there, not against none
# (kalman.KfParams.gyro_zero_turn off; with --gyro, "-gyro").
VARIANTS["kf-icp-turn"] = dataclasses.replace(VARIANTS["kf"], gyro_zero_turn=False)
VARIANTS["kf-icp-first-icp-turn"] = dataclasses.replace(VARIANTS["kf-icp-first"], gyro_zero_turn=False)
# The gyro fused in icp-first (its mode takes it as the guard's witness alone), "-fused".
VARIANTS["kf-icp-first-fused"] = dataclasses.replace(
    VARIANTS["kf-icp-first"], gyro_witness=False, gyro_fused=True
)
# The gyro as the guard's heading witness (kalman.KfParams.gyro_witness; with --gyro, "-gyro"):
# its witness alone, its steps not fused but at the standstill (the bias); the witness alone
# with its turn fused over the runs where it finds ICP's yaw erring ("-turn",
# kalman.KfParams.gyro_where_icp_errs); the witness with the gyro fused as before ("-fused").
for _key in ("kf", "kf-icp-first"):
    VARIANTS[f"{_key}-heading"] = dataclasses.replace(VARIANTS[_key], gyro_witness=True, gyro_fused=False)
    VARIANTS[f"{_key}-heading-turn"] = dataclasses.replace(
        VARIANTS[f"{_key}-heading"], gyro_where_icp_errs=True
    )
    VARIANTS[f"{_key}-heading-fused"] = dataclasses.replace(
        VARIANTS[_key], gyro_witness=True, gyro_fused=True
    )
# The wheels fused as they come (WHEEL_SIGMAS) with no witness: round 8's default on laps with wheels.
VARIANTS["kf-raw"] = dataclasses.replace(VARIANTS["kf"], wheel_witness=False, wheel_calibrated=False)
# The wheels fused calibrated against ICP (kalman.KfParams.wheel_calibrated), with the witness:
# the default now (the same as "kf" on laps with wheels).
VARIANTS["kf-wheels"] = dataclasses.replace(VARIANTS["kf-witness"], wheel_input=True, wheel_calibrated=True)
VARIANTS["kf-icp-first-wheels"] = dataclasses.replace(
    VARIANTS["kf-icp-first-witness"], wheel_input=True, wheel_calibrated=True
)
# Each of them and the default smoothed (kalman.KfParams.smooth: the RTS backward pass), "-smooth".
VARIANTS.update(
    {
        f"{k}-smooth": dataclasses.replace(VARIANTS[k], smooth=True)
        for k in (
            "kf",
            "kf-icp-first",
            "kf-witness",
            "kf-icp-first-witness",
            "kf-wheels",
            "kf-icp-first-wheels",
        )
    }
)
# The causal path anchored (kalman.KfParams.anchored: the filter's relative estimates
# chained, as method kf runs without images), "-anchored".
VARIANTS.update(
    {
        f"{k}-anchored": dataclasses.replace(VARIANTS[k], anchored=True)
        for k in ("kf", "kf-driven", "kf-icp-first", "kf-wheels", "kf-icp-first-wheels")
    }
)
ROUND9 = (
    "kf-icp-first",
    "kf-witness",
    "kf-witness-fused",
    "kf-icp-first-witness",
    "kf-icp-first-witness-fused",
    "kf-smooth",
    "kf-icp-first-smooth",
    "kf-witness-smooth",
    "kf-icp-first-witness-smooth",
    "kf-wheels",
    "kf-icp-first-wheels",
    "kf-wheels-smooth",
    "kf-icp-first-wheels-smooth",
    "kf-raw",
    "kf-icp-turn",
    "kf-icp-first-icp-turn",
    "kf-heading",
    "kf-heading-turn",
    "kf-heading-fused",
    "kf-icp-first-heading",
    "kf-icp-first-heading-turn",
    "kf-icp-first-heading-fused",
    "kf-icp-first-fused",
    *(k for k in VARIANTS if k.endswith("-anchored")),
)
ALL_VARIANTS = tuple(k for k in VARIANTS if k not in ROUND9)
# The compact table: the default against round 7's and the options, lap by lap (those run).
ROUND7 = (
    *ROUND9,
    "kf-round7",
    "kf",
    "kf-pays",
    "kf-pays-process",
    "kf-pays-driven",
    "kf-bias",
    "kf-process",
    "kf-driven",
)
# With --gyro, each filter with the gyroscope beside it.
ROUND7 = tuple(k for key in ROUND7 for k in (key, f"{key}-gyro"))


AXES = ("forward", "cross", "yaw")


def kept_lap(args: argparse.Namespace, name: str, seed: int) -> tuple[Any, Any, Any, FloatArray, FloatArray]:
    """A lap kept by ``--keep``: its streams (VO's result set), odometries, planar truth and
    the truth's stamps."""
    seq = args.keep / f"{name}-seed{seed}{lap_tag(args)}"
    streams = open_streams(seq)
    od, res = pickle.loads((seq / "odometries.pkl").read_bytes())
    streams.results["vo"] = res
    assert streams.sequence.groundtruth_file is not None
    truth = read_tum(seq / streams.sequence.groundtruth_file)
    assert truth.stamps_s is not None
    return streams, od, res, planar_at(truth, truth.stamps_s), truth.stamps_s


def lap_tag(args: argparse.Namespace) -> str:
    """A kept lap's folder name after its seed: its drive's length, wheels, standstill, gyro."""
    tag = f"-{args.duration_s:g}s" if args.duration_s else ""
    tag += "-wheels" if args.wheel_odometry else ""
    tag += f"-still{args.start_still:g}" if args.start_still else ""
    return tag + ("-gyro" if args.gyro else "")


def kept_measurements(
    args: argparse.Namespace, name: str, seed: int, params: kalman.KfParams
) -> tuple[list[kalman.Increment], FloatArray, FloatArray]:
    """A kept lap's increments as the filter of ``params`` takes them, its planar truth
    and the truth's stamps (the lap's background work stopped)."""
    streams, od, res, gt, truth_s = kept_lap(args, name, seed)
    ms = kf_measurements(streams, od, res, params)
    streams.stop_background()
    return ms, gt, truth_s


def open_axes(m: kalman.Increment, keep: tuple[int, ...]) -> kalman.Increment:
    """The step measuring only along ``keep`` (axes of its frame): the others' covariance
    1-sigma kalman.OPEN_SIGMA_M, uncorrelated."""
    cov = m.covariance.copy()
    for a in set(range(3)) - set(keep):
        cov[a, :] = cov[:, a] = 0.0
        cov[a, a] = kalman.OPEN_SIGMA_M**2
    return dataclasses.replace(m, covariance=cov)


def step_nees(ms: list[kalman.Increment], truth: FloatArray, stamps: FloatArray) -> FloatArray:
    """Each increment's NEES against the truth's motion over its interval."""
    errors = step_errors(ms, truth, stamps)
    return np.array([float(e @ np.linalg.solve(m.covariance, e)) for m, e in zip(ms, errors, strict=True)])


def step_errors(ms: list[kalman.Increment], truth: FloatArray, stamps: FloatArray) -> FloatArray:
    """Each increment's error (M, 3) against the truth's motion over its interval."""
    t0s = planar_at_stamps(truth, stamps, np.array([m.t0 for m in ms]))
    t1s = planar_at_stamps(truth, stamps, np.array([m.t1 for m in ms]))
    out = []
    for m, a, b in zip(ms, t0s, t1s, strict=True):
        e = m.motion - pose_of(np.linalg.inv(se2(a)) @ se2(b))
        e[2] = np.angle(np.exp(1j * e[2]))
        out.append(e)
    return np.array(out)


def lag1_correlation(ms: list[kalman.Increment], truth: FloatArray, stamps: FloatArray) -> float:
    """The correlation of consecutive steps' errors, each over its 1-sigma (x, y and yaw
    pooled); negative where consecutive steps share an error with opposite signs."""
    return float(np.mean(axis_consistency(ms, truth, stamps)[1][0]))


def axis_consistency(
    ms: list[kalman.Increment], truth: FloatArray, stamps: FloatArray, trim: bool = False, lags: int = 1
) -> tuple[FloatArray, FloatArray]:
    """Per axis (x, y, yaw in the step's frame): the steps' squared errors over their
    variance (mean; 1 for an honest covariance) and the error correlation (lags, 3) of
    steps 1 ... ``lags`` apart in an unbroken chain of steps (kalman.shared_error_fractions,
    kalman.gauss_markov_fit). ``trim``: only steps whose NEES is within the chi-square
    0.999 point (3 dof) times the lap's median NEES over the chi-square median (the runs a
    gate passes once their covariance is scaled to the median: VO's runs with a wrong
    carried scale left out)."""
    z = step_errors(ms, truth, stamps) / np.sqrt([np.diag(m.covariance) for m in ms])
    keep = np.ones(len(ms), dtype=bool)
    if trim:
        nees = step_nees(ms, truth, stamps)
        keep = nees < chi2.ppf(0.999, 3) * np.median(nees) / chi2.ppf(0.5, 3)
    chained = np.array([ms[k].t0 == ms[k - 1].t1 for k in range(1, len(ms))])
    ratio = np.mean(z[keep] ** 2, axis=0)
    corr = []
    for lag in range(1, lags + 1):
        # Steps k - lag ... k each starting where the one before ends, both ends kept.
        pairs = keep[lag:] & keep[:-lag]
        for j in range(lag):
            pairs &= chained[j : len(chained) - lag + 1 + j]
        a, b = z[:-lag][pairs], z[lag:][pairs]
        corr.append([np.corrcoef(a[:, i], b[:, i])[0, 1] for i in range(3)])
    return ratio, np.array(corr)


def planar_at_stamps(truth: FloatArray, stamps: FloatArray, at: FloatArray) -> FloatArray:
    """The truth (N, 3) at ``stamps`` (N,) interpolated at ``at``."""
    yaw = np.unwrap(truth[:, 2])
    return np.column_stack(
        [np.interp(at, stamps, truth[:, 0]), np.interp(at, stamps, truth[:, 1]), np.interp(at, stamps, yaw)]
    )


def pose_nees(poses: FloatArray, covs: FloatArray, gt: FloatArray) -> FloatArray:
    """The KF's poses' NEES against the truth (both anchored at the first pose)."""
    e = poses - gt
    e[:, 2] = np.angle(np.exp(1j * e[:, 2]))
    out = [float(v @ np.linalg.solve(c + 1e-12 * np.eye(3), v)) for v, c in zip(e[1:], covs[1:], strict=True)]
    return np.array(out)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--worlds", default="cubicle-loop,corridor-loop")
    ap.add_argument("--seeds", default="1-10", help='"1", "1,2,3" or "1-10".')
    ap.add_argument("--duration-s", type=float, default=40.0, help="Drive length (0: the whole lap).")
    ap.add_argument("--wheel-odometry", action="store_true", help="Simulate and fuse wheel odometry.")
    ap.add_argument(
        "--start-still",
        type=float,
        default=0.0,
        help="Seconds the rig stands still before it moves (DriveSpec.start_still_s); the drive "
        "lasts that and --duration-s of motion, every input scored over all of it.",
    )
    ap.add_argument(
        "--gyro",
        action="store_true",
        help="Simulate the gyroscope too; each filter then runs without it and with it (KEY-gyro).",
    )
    ap.add_argument(
        "--gyro-only",
        action="store_true",
        help="With --gyro, run each filter with the gyroscope alone (KEY-gyro; the filters without it "
        "score as on the same kept laps without this option).",
    )
    ap.add_argument("--keep", type=Path, help="Keep (and reuse) the sequences in this folder.")
    ap.add_argument("--reuse", action="store_true", help="Reuse each lap's odometries of an earlier run.")
    ap.add_argument(
        "--without",
        default="",
        help="Inputs the filters leave out, e.g. vo (the filter on ICP alone).",
    )
    ap.add_argument(
        "--vo-axes",
        default="forward,cross,yaw",
        help="The axes of VO's runs the filters take, e.g. yaw (the others open: 1-sigma 10 m or rad).",
    )
    ap.add_argument(
        "--process",
        help="The filters' process noise ACCEL,YAW_ACCEL (m/s^2, rad/s^2) instead of their own (0.5,1.0).",
    )
    ap.add_argument("--pays", help="Also run the filters kf-pays* with the rule kalman.VO_PAYS at this q*.")
    ap.add_argument(
        "--consistency",
        action="store_true",
        help="Print each input's variance ratio and lag-1 correlation per axis instead "
        "(kalman.ICP_VARIANCE_RATIO ...: laps 1-2); needs --reuse.",
    )
    ap.add_argument(
        "--variants",
        default="",
        help=f"Run only these filters (of {','.join(VARIANTS)}); prints round 7's table alone.",
    )
    ap.add_argument(
        "--windows",
        action="store_true",
        help="Print VO's and ICP's errors over windows of 1-32 VO runs against their error models; "
        "needs --reuse.",
    )
    ap.add_argument(
        "--drive-stats",
        action="store_true",
        help="Print the truth's velocity changes per scan (kalman.DRIVE_ACCEL_SIGMA: laps 1-2); "
        "needs --reuse.",
    )
    ap.add_argument(
        "--bias-fit",
        action="store_true",
        help="Print VO's scale, cross-track and yaw-rate errors' correlation over runs and their "
        "Gauss-Markov fits (kalman.VO_BIAS_RMS, VO_BIAS_LAGS: laps 1-2); needs --reuse.",
    )
    ap.add_argument(
        "--guard-evidence",
        action="store_true",
        help="Print, per lap, the VO runs the guard leaves out per direction and on how many of "
        "them VO's chain is further from the truth than ICP's; needs --reuse.",
    )
    ap.add_argument(
        "--wheel-windows",
        action="store_true",
        help="Print the wheel witness's calibrated chain's error over windows of 1-8 VO runs against "
        "its model (kalman.WHEEL_WINDOW_RATIO: laps 1-2); needs --reuse --wheel-odometry.",
    )
    args = ap.parse_args()
    if args.wheel_windows:
        wheel_windows(args)
        return
    if args.bias_fit:
        bias_fit(args)
        return
    if args.drive_stats:
        drive_stats(args)
        return
    if args.windows:
        windows(args)
        return
    if args.consistency:
        consistency(args)
        return
    if args.guard_evidence:
        guard_evidence(args)
        return
    duration = args.duration_s or None
    if args.process:
        accel, yaw_accel = (float(v) for v in args.process.split(","))
        for key, params in VARIANTS.items():
            VARIANTS[key] = dataclasses.replace(params, accel_sigma=accel, yaw_accel_sigma=yaw_accel)
    if args.pays:
        q = float(args.pays)
        VARIANTS["kf-pays"] = dataclasses.replace(VARIANTS["kf-round7"], vo_pays=q)
        VARIANTS["kf-pays-process"] = dataclasses.replace(VARIANTS["kf-process"], vo_pays=q)
        VARIANTS["kf-pays-driven"] = dataclasses.replace(VARIANTS["kf-driven"], vo_pays=q)
    if args.variants:
        for key in set(VARIANTS) - set(args.variants.split(",")):
            del VARIANTS[key]
    else:  # round 9's run by name alone; the rest as before
        for key in ROUND9:
            VARIANTS.pop(key, None)
    if args.gyro and args.gyro_only:
        shown = [k for k in ROUND7 if k.endswith("-gyro") and k.removesuffix("-gyro") in VARIANTS]
    elif args.gyro:
        shown = [k for k in ROUND7 if k in VARIANTS or k.removesuffix("-gyro") in VARIANTS]
    else:
        shown = [k for k in ROUND7 if k in VARIANTS]
    scores: dict[tuple[str, str], list[float]] = defaultdict(list)
    wins: dict[str, list[bool]] = defaultdict(list)
    round7: list[str] = []
    with tempfile.TemporaryDirectory() as tmp:
        root = args.keep or Path(tmp)
        root.mkdir(parents=True, exist_ok=True)
        if set(VARIANTS) == set(ALL_VARIANTS):
            print(
                "| world | seed | ICP ATE (m) | VO ATE (m) | odom ATE (m) | KF fixed ATE (m) "
                "| KF round 2 ATE (m) | KF round 4 ATE (m) | KF round 5 ATE (m) | KF guard alone ATE (m) "
                "| KF ATE (m) | KF <= best input | KF driven ATE (m) "
                "| KF driven <= best input | NEES ICP steps "
                "| ICP lag-1 corr | NEES VO runs | NEES KF poses | VO forward ratio matched "
                "| VO forward left out | VO runs guarded forward / cross / yaw | KF s | KF s over round 5's |"
            )
            print("|---" * 23 + "|")
        for seed in seeds_of(args.seeds):
            for name in args.worlds.split(","):
                seq = root / f"{name}-seed{seed}{lap_tag(args)}"
                if not (seq / "sequence.yaml").exists():
                    spec = DriveSpec(
                        seed=seed,
                        duration_s=duration,
                        wheel_odometry=args.wheel_odometry,
                        start_still_s=args.start_still,
                        gyro=args.gyro,
                    )
                    write_drive(BUILTIN[name](), spec, str(seq))
                axes = tuple(AXES.index(a) for a in args.vo_axes.split(","))
                row = lap(
                    seq,
                    args.reuse,
                    tuple(filter(None, args.without.split(","))),
                    axes,
                    args.gyro,
                    args.gyro and args.gyro_only,
                )
                for k, v in row.items():
                    if isinstance(v, float):
                        scores[name, k].append(v)
                best = min(row["icp"], row["vo"])  # the wheels' own ATE is printed beside
                cells = []
                for key in ROUND7:
                    if key in row:
                        cells.append(f"{row[key]:.4f} {'yes' if row[key] <= best else 'no'}")
                        wins[f"{name} {key} compact"].append(row[key] <= best)
                        scores[name, f"{key} over best"].append(row[key] - best)
                odom = f"{row['odom']:.4f}" if "odom" in row else "-"
                round7.append(
                    f"| {name} | {seed} | {row['icp']:.4f} | {row['vo']:.4f} | {odom} | "
                    + " | ".join(cells)
                    + " |"
                )
                if set(VARIANTS) != set(ALL_VARIANTS):
                    print(round7[-1], flush=True)
                    if args.gyro:  # the gyro's bias as each filter ends the lap, and the simulated one
                        spec = DriveSpec(
                            seed=seed, duration_s=duration, start_still_s=args.start_still, gyro=True
                        )
                        motion = Motion(BUILTIN[name](), spec)
                        _, bias = gyro_bias(motion, spec)
                        print(
                            f"gyro bias at the end (deg/s): simulated {np.degrees(bias[-1]):+.4f}, "
                            + ", ".join(
                                f"{k} {row[k + '-bias-deg-s']:+.4f}" for k in shown if k.endswith("-gyro")
                            ),
                            flush=True,
                        )
                        print(
                            "the gyro's heading verdicts (VO runs over which it found ICP's yaw / VO's "
                            "erring): "
                            + ", ".join(
                                f"{k} {row[k + '-heading-verdicts']}"
                                for k in shown
                                if k.endswith("-gyro") and "heading" in k
                            ),
                            flush=True,
                        )
                    continue
                win = row["kf"] <= best
                wins[name].append(win)
                wins[name + " round 4"].append(row["kf-round4"] <= best)
                wins[name + " round 5"].append(row["kf-round5"] <= best)
                wins[name + " guard"].append(row["kf-guard"] <= best)
                wins[name + " driven"].append(row["kf-driven"] <= best)
                odom = f"{row['odom']:.4f}" if "odom" in row else "-"
                print(
                    f"| {name} | {seed} | {row['icp']:.4f} | {row['vo']:.4f} | {odom} "
                    f"| {row['kf-fixed']:.4f} | {row['kf-own']:.4f} | {row['kf-round4']:.4f} "
                    f"| {row['kf-round5']:.4f} | {row['kf-guard']:.4f} | {row['kf']:.4f} "
                    f"| {'yes' if win else 'no'} | {row['kf-driven']:.4f} "
                    f"| {'yes' if row['kf-driven'] <= best else 'no'} "
                    f"| {row['nees-icp']:.2f} | {row['icp-lag1']:.2f} "
                    f"| {row.get('nees-vo', float('nan')):.2f} "
                    f"| {row['nees-kf']:.2f} | {row['vo-ratio']:.2f} | {row['vo-left-out']:.0f} "
                    f"| {row['guarded']} "
                    f"| {row['kf-s']:.2f} | {row['kf-s'] / row['kf-round5-s']:.2f} |",
                    flush=True,
                )
    print(
        "\n| world | seed | ICP ATE (m) | VO ATE (m) | wheels ATE (m) | "
        + " | ".join(f"{k} ATE (m), <= best input" for k in shown)
        + " |"
    )
    print("|---" * (5 + len(shown)) + "|")
    print("\n".join(round7))
    print(
        "\n| world | laps | "
        + " | ".join(f"{k}: ATE mean (m), worst over best input (m), laps <= best input" for k in shown)
        + " |"
    )
    print("|---" * (2 + len(shown)) + "|")
    for name in args.worlds.split(","):
        cells = []
        for key in shown:
            won = wins[f"{name} {key} compact"]
            over = np.array(scores[name, f"{key} over best"])
            cells.append(f"{np.mean(scores[name, key]):.4f}, {over.max():+.4f}, {sum(won)} of {len(won)}")
        laps = len(scores[name, "icp"])
        print(f"| {name} | {laps} | " + " | ".join(cells) + " |")
    if set(VARIANTS) != set(ALL_VARIANTS):
        return
    print(
        "\n| world | laps | ICP ATE mean (m) | VO ATE mean (m) | KF fixed ATE mean (m) "
        "| KF round 2 ATE mean (m) | KF round 4 ATE mean (m) | KF round 5 ATE mean (m) "
        "| KF guard alone ATE mean (m) | KF ATE mean (m) | KF ATE worst (m) "
        "| laps KF <= best input: round 4 / round 5 / guard alone / now | now, laps 3-10 "
        "| NEES KF poses, median lap "
        "| KF driven ATE mean (m) | KF driven ATE worst (m) | laps KF driven <= best input |"
    )
    print("|---" * 17 + "|")
    for name in args.worlds.split(","):
        s = {k: np.array(v) for (w, k), v in scores.items() if w == name}
        seeds = seeds_of(args.seeds)
        held_out = sum(w for w, seed in zip(wins[name], seeds, strict=True) if seed > 2)
        print(
            f"| {name} | {len(wins[name])} | {s['icp'].mean():.4f} | {s['vo'].mean():.4f} "
            f"| {s['kf-fixed'].mean():.4f} | {s['kf-own'].mean():.4f} | {s['kf-round4'].mean():.4f} "
            f"| {s['kf-round5'].mean():.4f} | {s['kf-guard'].mean():.4f} "
            f"| {s['kf'].mean():.4f} | {s['kf'].max():.4f} "
            f"| {sum(wins[name + ' round 4'])} / {sum(wins[name + ' round 5'])} "
            f"/ {sum(wins[name + ' guard'])} "
            f"/ {sum(wins[name])} of {len(wins[name])} "
            f"| {held_out} of {sum(seed > 2 for seed in seeds)} | {np.median(s['nees-kf']):.2f} "
            f"| {s['kf-driven'].mean():.4f} | {s['kf-driven'].max():.4f} "
            f"| {sum(wins[name + ' driven'])} of {len(wins[name])} |"
        )


def consistency(args: argparse.Namespace) -> None:
    """Each input's error model's figures per lap (:func:`axis_consistency`; VO trimmed)
    from the kept odometries, and their mean over the laps; for VO also the forward error's
    Gauss-Markov memory fitted to the mean lag-1 ... lag-3 correlations
    (kalman.gauss_markov_fit)."""
    print(
        "| world | seed | input | variance ratio x / y / yaw | lag-1 corr x / y / yaw "
        "| lag-2 corr x / y / yaw | lag-3 corr x / y / yaw | NEES modelled | run s |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    sums: dict[str, list[FloatArray]] = defaultdict(list)
    for seed in seeds_of(args.seeds):
        for name in args.worlds.split(","):
            streams, od, res, gt, truth_s = kept_lap(args, name, seed)
            ms = kf_measurements(streams, od, res, kalman.KF_MODES["weighted"])
            for src in ("icp", "vo"):
                mine = [m for m in ms if m.source == src]
                ratio, corr = axis_consistency(mine, gt, truth_s, trim=src == "vo", lags=3)
                # Each step's NEES under the filter's model of its error (own and twice the
                # shared part, kalman.shared_error_fractions): 3 where the model is honest.
                own, shared = kalman._error_model(src, kalman.KF_MODES["weighted"])
                total = own + 2 * shared
                modelled = [
                    kalman.Increment(m.t0, m.t1, m.motion, kalman._scaled(m.covariance, total), src)
                    for m in mine
                ]
                nees = step_nees(modelled, gt, truth_s)
                if src == "vo":
                    nees = nees[nees < chi2.ppf(0.999, 3) * np.median(nees) / chi2.ppf(0.5, 3)]
                run_s = float(np.mean([m.t1 - m.t0 for m in mine]))
                sums[src].append(np.concatenate([ratio, corr.ravel(), [nees.mean(), run_s]]))
                cells = " | ".join(" / ".join(f"{v:+.2f}" for v in c) for c in corr)
                r = " / ".join(f"{v:.2f}" for v in ratio)
                print(
                    f"| {name} | {seed} | {src} | {r} | {cells} | {nees.mean():.2f} | {run_s:.3f} |",
                    flush=True,
                )
            streams.stop_background()
    for src, rows in sums.items():
        m = np.mean(rows, axis=0)
        cells = " | ".join(" / ".join(f"{v:+.2f}" for v in m[3 + 3 * i : 6 + 3 * i]) for i in range(3))
        r = " / ".join(f"{v:.2f}" for v in m[:3])
        print(f"| mean | {args.seeds} | {src} | {r} | {cells} | {m[12]:.2f} | {m[13]:.3f} |")
        if src == "vo":
            forward = (float(m[3]), float(m[6]), float(m[9]))
            fit = kalman.gauss_markov_fit(forward, float(m[13]))
            print(
                f"\nVO forward lag-1/2/3 {forward[0]:+.3f} / {forward[1]:+.3f} / {forward[2]:+.3f}: "
                f"Gauss-Markov share {fit[0]:.3f} of the forward variance, {fit[1]:.3f} per run "
                f"of {m[13]:.3f} s, time constant {fit[2]:.3f} s"
            )


def windows(args: argparse.Namespace, sizes: tuple[int, ...] = (1, 2, 4, 8, 16, 32)) -> None:
    """Each input's error over windows of 1 ... 32 chained VO runs (0.5-16 s) against its
    error model there: VO's chain under the guard's model (kalman._vo_guard: the runs'
    covariances with their variance ratios, the forward memory's and the lag-1 shares'
    correlations), ICP's own steps chained over the same interval under theirs
    (kalman._IcpReference.between); per direction of the window's last run, the squared
    error against the truth over the modelled variance (1 where the model holds at that
    length), mean and median over every window of the laps. VO's runs whose own error is
    beyond the chi-square 0.999 point at the lap's median (a wrong scale) end no window."""
    params = kalman.KF_MODES["weighted"]
    own, share = kalman._error_model("vo", params)
    total = own + 2.0 * share
    rho = np.divide(share, total, out=np.zeros(3), where=total > 0)
    stats: dict[int, dict[str, list[FloatArray]]] = {n: {"vo": [], "icp": [], "gyro": []} for n in sizes}
    for seed in seeds_of(args.seeds):
        for name in args.worlds.split(","):
            ms, gt, truth_s = kept_measurements(args, name, seed, params)
            reference = kalman._IcpReference([m for m in ms if m.source == "icp"], params)
            # The gyro's heading witness (with --gyro), its bias as the filter learns it at the
            # standstill (the steps before the rig moves alone).
            gyro = [m for m in ms if m.source == "gyro"]
            heading = kalman._GyroWitness(gyro, reference) if gyro else None
            standing = kalman.run_filter(
                [m for m in ms if m.source in ("icp", "gyro") and m.t1 <= args.start_still], params
            )
            vo = sorted((m for m in ms if m.source == "vo" and m.covariance[0, 0] < 1.0), key=lambda m: m.t1)
            nees = step_nees(vo, gt, truth_s)
            bad = nees > chi2.ppf(0.999, 3) * np.median(nees) / chi2.ppf(0.5, 3)
            for k, m in enumerate(vo):
                for n in sizes:
                    j = k - n + 1
                    broken = any(vo[i].t0 != vo[i - 1].t1 for i in range(j + 1, k + 1))
                    if j < 0 or bad[j : k + 1].any() or broken:
                        continue
                    runs = [(r, kalman._scaled(r.covariance, total)) for r in vo[j : k + 1]]
                    corr = np.zeros((max(n - 1, 1), 3))
                    corr[0] = rho
                    lags = np.arange(1, len(corr) + 1)
                    corr[:, 0] = params.vo_memory_share * np.exp(-lags * (m.t1 - m.t0) / params.vo_memory_s)
                    a, b = vo[j].t0, m.t1
                    ends = planar_at_stamps(gt, truth_s, np.array([a, b]))
                    truth = pose_of(np.linalg.inv(se2(ends[0])) @ se2(ends[1]))
                    ref = reference.between(a, b, b + 1.0)
                    if ref is None:
                        continue
                    exact = (truth, np.zeros((3, 3)))
                    stats[n]["vo"].append(kalman._vo_guard(runs, exact, corr[: n - 1], 1e9)[1])
                    # ICP's chain against the truth, in the last run's frame, as the guard turns it.
                    T = np.eye(3)
                    for r, _ in runs:
                        T = T @ se2(r.motion)
                    G = kalman._rotation3(float(np.arctan2(T[1, 0], T[0, 0])) - m.motion[2])
                    d = ref[0] - truth
                    d[2] = np.angle(np.exp(1j * d[2]))
                    stats[n]["icp"].append((G.T @ d) ** 2 / np.diag(G.T @ ref[1] @ G))
                    turn = (
                        heading.between(a, b, b, standing.gyro_bias, standing.gyro_bias_sigma**2)
                        if heading is not None and np.isfinite(standing.gyro_bias)
                        else None
                    )
                    if turn is not None:
                        off = float(np.angle(np.exp(1j * (turn[0][2] - truth[2]))))
                        stats[n]["gyro"].append(np.array([off**2 / turn[1][2, 2]]))
    print(f"laps {args.seeds} of {args.worlds}: squared error over modelled variance")
    print("(forward / cross-track / yaw of the window's last run)\n")
    # The share of windows where an input's yaw is off the truth beyond the guard's gate: where
    # an exact third heading (kalman._witness) could find it erring at most.
    gate = kalman._guard_gate(kalman.VO_GUARD_RUNS)
    # The gyro's yaw (kalman._GyroWitness, with --gyro) likewise: its witness's model at that length.
    print(
        "| VO runs in the window | windows | VO mean | VO median | ICP mean | ICP median "
        "| VO yaw beyond the guard's gate | ICP yaw beyond it | gyro yaw mean / median | gyro yaw beyond it |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    for n in sizes:
        v, i = np.array(stats[n]["vo"]), np.array(stats[n]["icp"])
        cells = [" / ".join(f"{x:.2f}" for x in f(a, axis=0)) for a in (v, i) for f in (np.mean, np.median)]
        cells += [f"{np.mean(a[:, 2] > gate):.4f}" for a in (v, i)]
        g = np.array(stats[n]["gyro"]).reshape(-1)
        cells += (
            [f"{np.mean(g):.2f} / {np.median(g):.2f}", f"{np.mean(g > gate):.4f}"] if len(g) else ["-", "-"]
        )
        print(f"| {n} | {len(v)} | " + " | ".join(cells) + " |")


def wheel_windows(args: argparse.Namespace, sizes: tuple[int, ...] = (1, 2, 4, 8)) -> None:
    """The wheel witness's error model (kalman.WHEEL_WINDOW_RATIO: laps 1-2; needs
    --wheel-odometry): at each VO run's end, the wheels' calibrated chain over the last 1,
    2, 4, 8 runs (kalman._WheelWitness.between, the model's ratio taken as 1) against the
    truth, per direction of the frame at the window's end (forward, cross-track, yaw), the squared error
    over the modelled variance: mean and median over the windows of the laps."""
    params = dataclasses.replace(kalman.KF_MODES["weighted"], wheel_witness=True)
    stats: dict[int, list[FloatArray]] = {n: [] for n in sizes}
    for seed in seeds_of(args.seeds):
        for name in args.worlds.split(","):
            ms, gt, truth_s = kept_measurements(args, name, seed, params)
            reference = kalman._IcpReference([m for m in ms if m.source == "icp"], params)
            witness = kalman._WheelWitness([m for m in ms if m.source == "wheel"], reference, params)
            vo = sorted((m for m in ms if m.source == "vo"), key=lambda m: m.t1)
            for k, m in enumerate(vo):
                for n in sizes:
                    if k - n + 1 < 0:
                        continue
                    a, b = vo[k - n + 1].t0, m.t1
                    w = witness.between(a, b, b, n)
                    if w is None:
                        continue
                    ends = planar_at_stamps(gt, truth_s, np.array([a, b]))
                    truth = pose_of(np.linalg.inv(se2(ends[0])) @ se2(ends[1]))
                    d = w[0] - truth
                    d[2] = np.angle(np.exp(1j * d[2]))
                    G = kalman._rotation3(float(w[0][2]))  # the frame at the window's end, the ratio's
                    ratio = np.asarray(kalman.WHEEL_WINDOW_RATIO[int(np.log2(n))])
                    cov = G.T @ w[1] @ G / np.sqrt(np.outer(ratio, ratio))  # the ratio taken as 1
                    stats[n].append((G.T @ d) ** 2 / np.diag(cov))
    print(f"laps {args.seeds} of {args.worlds}: the wheels' calibrated chain,")
    print("squared error over modelled variance (forward / cross-track / yaw of the frame at")
    print("the window's end; the model's ratio 1)\n")
    print("| VO runs in the window | windows | mean | median |")
    print("|---|---|---|---|")
    for n in sizes:
        v = np.array(stats[n])
        cells = [" / ".join(f"{x:.3f}" for x in f(v, axis=0)) for f in (np.mean, np.median)]
        print(f"| {n} | {len(v)} | " + " | ".join(cells) + " |")


def drive_stats(args: argparse.Namespace) -> None:
    """The drive's velocity changes (kalman.DRIVE_ACCEL_SIGMA, DRIVE_YAW_ACCEL_SIGMA: laps
    1-2): the truth's velocity (world x, y, yaw) over each scan interval, its change from
    one interval to the next over sqrt(dt) (m/s^1.5, rad/s^1.5: a white acceleration's
    1-sigma level that would make the change a 1-sigma event), its percentiles over the
    laps."""
    changes = []
    for seed in seeds_of(args.seeds):
        for name in args.worlds.split(","):
            streams, _, _, gt, truth_s = kept_lap(args, name, seed)
            streams.stop_background()
            t = streams.scan_stamps_s
            dt = float(np.median(np.diff(t)))
            v = np.diff(planar_at_stamps(gt, truth_s, t), axis=0) / np.diff(t)[:, None]
            changes.append(np.abs(np.diff(v, axis=0)) / np.sqrt(dt))
    c = np.vstack(changes)
    print(f"{len(c)} scan intervals of laps {args.seeds} ({args.worlds})\n")
    print("| percentile | x (m/s^1.5) | y (m/s^1.5) | yaw (rad/s^1.5) |")
    print("|---|---|---|---|")
    for q in (50, 90, 99, 99.9, 100):
        print(f"| {q:g} | " + " | ".join(f"{v:.3f}" for v in np.percentile(c, q, axis=0)) + " |")
    print("| RMS | " + " | ".join(f"{v:.3f}" for v in np.sqrt(np.mean(c**2, axis=0))) + " |")


def bias_fit(args: argparse.Namespace, lags: int = 16) -> None:
    """VO's errors over seconds (kalman.VO_BIAS_RMS, VO_BIAS_LAGS: laps 1-2): per VO run
    with a measured forward motion of 5 cm or more, its forward error over that motion (a
    scale error), its cross-track error over it, and its yaw error over the run's duration
    (a yaw-rate error), against the truth; a lap's values beyond 6 x 1.4826 MAD (a wrong
    scale) left out. Printed: each series' RMS over the laps, its correlation at lags 1 ...
    ``lags`` runs in an unbroken chain (about the mean 0, pooled over the laps) and the
    Gauss-Markov fit to those (kalman.gauss_markov_fit): share, per run, time constant, and
    the state's sigma (RMS x sqrt(share))."""
    series: list[tuple[FloatArray, FloatArray]] = []  # per lap: (chained (M,), values (M, 3))
    durations = []
    for seed in seeds_of(args.seeds):
        for name in args.worlds.split(","):
            ms, gt, truth_s = kept_measurements(args, name, seed, kalman.KF_MODES["weighted"])
            vo = sorted((m for m in ms if m.source == "vo" and m.covariance[0, 0] < 1.0), key=lambda m: m.t1)
            e = step_errors(vo, gt, truth_s)
            dist = np.array([m.motion[0] for m in vo])
            dt = np.array([m.t1 - m.t0 for m in vo])
            moving = np.abs(dist) >= 0.05
            v = np.column_stack(
                [
                    np.where(moving, e[:, 0] / np.where(moving, dist, 1.0), np.nan),
                    np.where(moving, e[:, 1] / np.where(moving, dist, 1.0), np.nan),
                    e[:, 2] / dt,
                ]
            )
            mad = 1.4826 * np.nanmedian(np.abs(v), axis=0)
            v[np.abs(v) > 6.0 * mad] = np.nan
            chained = np.array([True] + [vo[k].t0 == vo[k - 1].t1 for k in range(1, len(vo))])
            series.append((chained, v))
            durations.append(dt)
    run_s = float(np.mean(np.concatenate(durations)))
    allv = np.vstack([v for _, v in series])
    rms = np.sqrt(np.nanmean(allv**2, axis=0))
    corr = np.zeros((lags, 3))
    for lag in range(1, lags + 1):
        num, den = np.zeros(3), np.zeros(3)
        for chained, v in series:
            unbroken = np.array([chained[k - lag + 1 : k + 1].all() for k in range(lag, len(v))], dtype=bool)
            if not unbroken.any():
                continue
            a, b = v[:-lag][unbroken], v[lag:][unbroken]
            ok = np.isfinite(a) & np.isfinite(b)
            num += np.where(ok, a * b, 0.0).sum(axis=0)
            den += ok.sum(axis=0)
        corr[lag - 1] = num / np.maximum(den, 1) / rms**2
    print(f"VO runs of {run_s:.3f} s on average; laps {args.seeds} of {args.worlds}\n")
    print("| series | RMS | correlation at lags 1 ... | share | per run | time constant (s) | sigma |")
    print("|---|---|---|---|---|---|---|")
    for k, label in enumerate(("forward scale", "cross-track per metre", "yaw rate (rad/s)")):
        share, phi, tau = kalman.gauss_markov_fit(corr[:, k], run_s)
        cells = " ".join(f"{c:+.2f}" for c in corr[:, k])
        print(
            f"| {label} | {rms[k]:.4g} | {cells} | {share:.3f} | {phi:.3f} | {tau:.3f} "
            f"| {rms[k] * np.sqrt(share):.4g} |"
        )


def guard_evidence(args: argparse.Namespace) -> None:
    """Who is at fault where the guard fires: on the kept odometries, the guard
    (kalman._guard, the default's error model with no covariance matching) at each VO run
    in turn, and for each direction it leaves out, whether VO's chain or ICP's own steps
    over the guard's longest window then are further from the truth along it."""
    params = kalman.KF_MODES["weighted"]
    print("| world | seed | VO runs | left out forward / cross / yaw | of which VO further from the truth |")
    print("|---|---|---|---|---|")
    total = np.zeros((2, 3), dtype=int)
    for seed in seeds_of(args.seeds):
        for name in args.worlds.split(","):
            ms, gt, truth_s = kept_measurements(args, name, seed, params)
            reference = kalman._IcpReference([m for m in ms if m.source == "icp"], params)
            vo = sorted((m for m in ms if m.source == "vo"), key=lambda m: m.t1)
            own, share = kalman._error_model("vo", params)
            own, share = own.copy(), share.copy()
            own[0], share[0] = (own[0] + 2 * share[0]) * (1 - params.vo_memory_share), 0.0
            runs: list[tuple[kalman.Increment, FloatArray]] = []
            counts = np.zeros((2, 3), dtype=int)
            for m in vo:
                out = kalman._guard(reference, runs, m, own, share, (1.0, 1.0), True, m.t1, params)[0]
                if out is None or not out.any():
                    continue
                first = runs[0][0]
                ref = reference.between(first.t0, m.t1, m.t1)
                assert ref is not None
                T = np.eye(3)
                for r, _ in runs:
                    T = T @ se2(r.motion)
                chains = [kalman.Increment(first.t0, m.t1, pose_of(T), np.eye(3), "vo")]
                chains.append(kalman.Increment(first.t0, m.t1, ref[0], np.eye(3), "icp"))
                e_vo, e_icp = step_errors(chains, gt, truth_s)
                # In the last run's frame, as the guard tests.
                yaw = float(np.arctan2(T[1, 0], T[0, 0]) - m.motion[2])
                G = kalman._rotation3(yaw)
                e_vo, e_icp = G.T @ e_vo, G.T @ e_icp
                counts[0] += out
                counts[1] += out & (np.abs(e_vo) > np.abs(e_icp))
            total += counts
            print(
                f"| {name} | {seed} | {len(vo)} | {' / '.join(map(str, counts[0]))} "
                f"| {' / '.join(map(str, counts[1]))} |",
                flush=True,
            )
    print(f"| all | {args.seeds} | | {' / '.join(map(str, total[0]))} | {' / '.join(map(str, total[1]))} |")


def lap(
    seq: Path,
    reuse: bool = False,
    without: tuple[str, ...] = (),
    vo_axes: tuple[int, ...] = (0, 1, 2),
    gyro: bool = False,
    gyro_only: bool = False,
) -> dict[str, float]:
    """One lap's ATEs, NEES means and the filter's time. ``reuse``: take the laser and
    visual odometry from an earlier run's ``odometries.pkl`` in the lap's folder (written
    by every run), to try the filter's settings without computing them again; ``vo_axes``:
    the axes (0 forward, 1 cross-track, 2 yaw) of VO's runs the filters take, the others
    open (:func:`open_axes`); ``without``:
    the inputs ("icp", "vo", "wheel", "gyro") the filters leave out; ``gyro``: each filter
    run without the lap's gyroscope (KEY) and with it (KEY-gyro); ``gyro_only``: with it alone."""
    streams = open_streams(seq)
    cache = seq / "odometries.pkl"
    if reuse and cache.exists():
        od, res = pickle.loads(cache.read_bytes())
        streams.results["vo"] = res
    else:
        streams.start_laser_odometry()
        streams.feature_tracks()
        od, res = kf_inputs(streams)
        cache.write_bytes(pickle.dumps((od, res)))
    assert streams.sequence.groundtruth_file is not None
    truth = read_tum(seq / streams.sequence.groundtruth_file)
    assert truth.stamps_s is not None
    gt_all = planar_at(truth, truth.stamps_s)
    row: dict[str, float] = {}
    guarded = [""]  # the runs the guard left out per direction, as printed

    def ate(stamps: FloatArray, poses: FloatArray) -> float:
        return float(
            evaluate(anchored(poses, planar_at(truth, stamps)), planar_at(truth, stamps))["ate_rmse_m"]
        )

    runs = [(key, params, ()) for key, params in VARIANTS.items()]
    if gyro:
        runs = [] if gyro_only else [(key, params, ("gyro",)) for key, params, _ in runs]
        runs += [(f"{key}-gyro", params, ()) for key, params in VARIANTS.items()]
    for key, params, left in runs:
        ms = [
            open_axes(m, vo_axes) if m.source == "vo" else m
            for m in kf_measurements(streams, od, res, params)
            if m.source not in without + left
        ]
        t0 = time.perf_counter()
        kf = kalman.run_filter(ms, params)
        seconds = time.perf_counter() - t0
        # Scored at the scans' stamps, as ICP (kalman.path_at; rigcal localize does the same).
        kf = kalman.path_at(kf, streams.scan_stamps_s)
        row[key] = ate(kf.stamps_s, kf.poses)
        row[f"{key}-witnessed"] = float(sum(kf.icp_witnessed))
        row[f"{key}-bias-deg-s"] = float(np.degrees(kf.gyro_bias))
        row[f"{key}-heading-verdicts"] = kf.gyro_witnessed  # type: ignore[assignment]
        if key == "kf-round5":
            row["kf-round5-s"] = seconds
        if key == "kf":
            row["kf-s"] = seconds
            row["vo-ratio"], row["vo-left-out"] = kf.vo_forward_ratio, float(kf.vo_forward_left_out)
            guarded[0] = " / ".join(map(str, kf.vo_guarded))
            for src in ("icp", "vo", "wheel"):
                mine = [m for m in ms if m.source == src]
                if mine:
                    row[f"nees-{src}"] = float(np.mean(step_nees(mine, gt_all, truth.stamps_s)))
            row["icp-lag1"] = lag1_correlation([m for m in ms if m.source == "icp"], gt_all, truth.stamps_s)
            gt = planar_at(truth, kf.stamps_s)
            row["nees-kf"] = float(np.mean(pose_nees(anchored(kf.poses, gt), kf.covariances, gt)))
    wheel = [m for m in kf_measurements(streams, od, res, kalman.KfParams()) if m.source == "wheel"]
    if wheel:  # the wheel odometry's own path: its steps chained
        T, path = np.eye(3), [np.zeros(3)]
        for m in wheel:
            T = T @ se2(m.motion)
            path.append(pose_of(T))
        row["odom"] = ate(np.array([wheel[0].t0] + [m.t1 for m in wheel]), np.array(path))
    row["icp"] = ate(streams.scan_stamps_s, od.poses)
    row["vo"] = ate(streams.image_stamps_s[res.frames], res.poses)
    streams.stop_background()
    return {**row, "guarded": guarded[0]}  # type: ignore[dict-item]


if __name__ == "__main__":
    main()
