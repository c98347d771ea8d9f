"""How good are the image correspondences of IASM and H-IASM, and what do they do to Table 1?

Part 1, the correspondences. On every ``--every``-th image step of one lap of each
simulated loop (seed 1, as ``bench_localize.py``), each return of image t is matched in
image t+1 three ways:

- ``IASM``: among scan t+1's returns in IASM's search area around its own pixel, with
  the sub-beam parabola (:func:`rigcal.localize.iasm.match_returns`);
- ``window``: the same among the returns within H-IASM's window around where the *true*
  motion puts it (so that the figures measure the matching, not visual odometry);
- ``dense``: H-IASM's dense search along the wall in that window
  (:func:`rigcal.localize.hiasm.window_search`);

each on the scans as measured (``raw``) and with the returns moved onto their lines
(``snapped``, :func:`rigcal.localize.iasm.snap_to_lines`). A match's error is its point
in scan t+1 minus where the true motion puts the return of scan t; the table gives its
median along the motion (a bias) and its robust scatter (1.4826 MAD), over matches within
4 cm of the truth. Then the motion from the correspondences alone (RANSAC and the Eq. (4)
fit on the inliers, no laser): its mean forward error as a fraction of the step, and its
yaw error's RMS.

Part 2, Table 1's figures of IASM and H-IASM (real visual odometry) with each setting:
returns snapped or not, H-IASM's window searched among the returns or densely; for each
seed of ``--seeds`` (the sequences as ``bench_localize.py --seed N`` makes them), and
their means. Each step's laser term is scan t's (``keyframe_m`` 0), as these settings
were measured before keyframes.

Part 3, keyframes: the same figures (and RPE over 1 m) of IASM with the joint polish's
laser term against a keyframe ``keyframe_m`` back (0: scan t, every step), with and
without leaving out returns more than ``laser_reject_m`` off their paired line, and of
H-IASM without both and with the defaults, per seed and their means.

Part 4, IASM against H-IASM over many seeds: point-to-line ICP (the laser odometry, as
``rigcal localize --method icp`` runs it), IASM and H-IASM with the defaults, per seed;
then each method's mean with its standard error, and H-IASM minus IASM paired by seed
(one lap's loop closure is one draw of how the heading wanders, so a difference means
something only against its standard error): its mean, standard error and the number of
seeds where H-IASM is ahead.

Part 5, the camera's rate: the same laps (the same scans) with the camera at 10, 5 and
2.5 Hz, so that the rig moves 0.1, 0.2 and 0.4 m between images (IASM's search area is
fixed around each return's own pixel; H-IASM's window follows the homography's
prediction): IASM's and H-IASM's figures and fallbacks per seed, and their means.

Part 6, a laser that cannot see the corridors' ends: the laps simulated with each laser
range of ``--ranges`` (metres; at 8 m the corridor lap's long sides are corridors whose
ends are out of range, the case the paper's image methods are for), per seed: ICP (the
laser odometry), the laser alone through the same chain as the image methods (every
image step refused, ``min_correspondences`` out of reach: each step is the laser
odometry's motion aligned with the keyframe's walls, so that what the images add shows),
IASM and H-IASM, with H-IASM's steps by method; then the means with their standard
errors and H-IASM minus IASM paired by seed.

Parts 3 to 6 take ``--iasm KEY=VALUE`` (repeatable) as ``rigcal localize`` does: e.g.
``--iasm joint_polish=false --iasm keyframe_m=0`` ends each step as the paper does
(Eq. (4) on the RANSAC winner's inliers alone, every step from scan t).

    .venv/bin/python benchmarks/bench_matching.py [--keep DIR] [--every 10] [--parts 1,2,3,4,5,6]
        [--seeds 1,2,3] [--worlds corridor-loop,cubicle-loop] [--rates 10,5,2.5] [--ranges 30,8]
        [--iasm KEY=VALUE ...]
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from rigcal.arrays import MAD_TO_SIGMA
from rigcal.errors import InputError
from rigcal.geometry import pose_of, se2, transform_points
from rigcal.io.trajectory import Trajectory, read_tum
from rigcal.localize import image_matching
from rigcal.localize.hiasm import window_search
from rigcal.localize.iasm import IasmParams, Matches, match_returns, robust_motion
from rigcal.localize.metrics import anchored, evaluate
from rigcal.localize.pipeline import parse_iasm_settings, planar_at
from rigcal.localize.streams import Streams, open_streams
from rigcal.sim.drive import DriveSpec, write_drive
from rigcal.sim.world import BUILTIN

SNAP_M = 0.03  # snap_max_m when snapping


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--keep", type=Path, help="Keep (or reuse) the sequences in this folder.")
    ap.add_argument("--every", type=int, default=10, help="Use every n-th image step.")
    ap.add_argument("--parts", default="1,2", help="Which parts to run.")
    ap.add_argument("--worlds", default=",".join(WORLDS))
    ap.add_argument("--seeds", default="1", help="Parts 2-5: the seeds (part 1 uses seed 1).")
    ap.add_argument("--rates", default="10,5,2.5", help="Part 5: the camera rates (Hz).")
    ap.add_argument("--ranges", default="30,8", help="Part 6: the laser's ranges (m).")
    ap.add_argument(
        "--iasm",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="Parts 3-6: change one of IASM's and H-IASM's settings, as rigcal localize --iasm.",
    )
    args = ap.parse_args()
    try:
        params = parse_iasm_settings(args.iasm)
    except InputError as e:
        ap.error(str(e))
    parts = args.parts.split(",")
    worlds = args.worlds.split(",")
    seeds = [int(x) for x in args.seeds.split(",")]
    with tempfile.TemporaryDirectory() as tmp:
        root = args.keep or Path(tmp)
        root.mkdir(parents=True, exist_ok=True)
        if "1" in parts:
            _header(
                "world",
                "returns",
                "matching",
                "matches per step",
                "median error along the motion (mm)",
                "scatter (mm)",
                "correspondences alone: forward bias (% of step)",
                "yaw RMS (mdeg)",
            )
            for name in worlds:
                correspondences(sequence(root, name, 1), args.every)
        if "2" in parts:
            _header(
                "world",
                "seed",
                "returns",
                "H-IASM window",
                "IASM loop / avg / RPE 10 m (m)",
                "H-IASM loop / avg / RPE 10 m (m)",
            )
            for name in worlds:
                table(root, name, seeds)
        if "3" in parts:
            _header(
                "world",
                "seed",
                "method",
                "keyframe_m",
                "laser_reject_m",
                "loop closure (m)",
                "avg position error (m)",
                "RPE 1 m (m)",
                "RPE 10 m (m)",
            )
            for name in worlds:
                keyframes(root, name, seeds, params)
        if "4" in parts:
            _header("world", "seed", *(f"{m} loop / avg (m)" for m in PAIRED))
            diffs = [row for name in worlds for row in paired(root, name, seeds, params)]
            _differences(diffs)
        if "5" in parts:
            _header("world", "camera (Hz)", "seed", *(f"{m} loop / avg (m), fallbacks" for m in PAIRED[1:]))
            diffs = [
                row
                for name in worlds
                for row in rates(root, name, seeds, [float(x) for x in args.rates.split(",")], params)
            ]
            _differences(diffs)
        if "6" in parts:
            _header(
                "world",
                "laser range (m)",
                "seed",
                *(f"{LABELS6[m]} loop / avg (m)" for m in RANGE_METHODS),
                "H-IASM steps by",
            )
            diffs = [
                row
                for name in worlds
                for row in ranges(root, name, seeds, [float(x) for x in args.ranges.split(",")], params)
            ]
            _differences(diffs, "laser range (m)")


def _header(*columns: str) -> None:
    """A Markdown table's header, after a blank line."""
    print("\n| " + " | ".join(columns) + " |")
    print("|" + "---|" * len(columns))


WORLDS = ("corridor-loop", "cubicle-loop")
SETTINGS = ((False, False), (False, True), (True, False), (True, True))  # (snapped, dense)


def sequence(
    root: Path, name: str, seed: int, camera_rate_hz: float = 10.0, range_max_m: float = 30.0
) -> Path:
    """The lap of world ``name`` with ``seed`` (simulated once, then reused)."""
    folder = name if seed == 1 and camera_rate_hz == 10.0 else f"{name}-seed{seed}"
    if camera_rate_hz != 10.0:
        folder += f"-cam{camera_rate_hz:g}"
    if range_max_m != 30.0:
        folder += f"-range{range_max_m:g}"
    seq = root / folder
    if not (seq / "sequence.yaml").exists():
        spec = DriveSpec(seed=seed, camera_rate_hz=camera_rate_hz, range_max_m=range_max_m)
        write_drive(BUILTIN[name](), spec, str(seq))
    return seq


def correspondences(seq: Path, every: int) -> None:
    streams = open_streams(seq)
    streams.laser_odometry()
    rig = streams.require_rig("iasm")
    cam, T_cl = rig.camera, rig.T_cam_laser
    gt = planar_at(read_tum(seq / "groundtruth.tum"), streams.image_stamps_s)
    rng = np.random.default_rng(0)
    for snap in (False, True):
        params = IasmParams(snap_max_m=SNAP_M if snap else 0.0, joint_polish=False)
        matcher = image_matching.ScanMatcher(streams, "iasm", params)
        errors: dict[str, list[np.ndarray]] = {"IASM": [], "window": [], "dense": []}
        motions: dict[str, list[list[float]]] = {k: [] for k in errors}
        counts: dict[str, list[int]] = {k: [] for k in errors}
        for i in range(0, streams.n_images - 1, every):
            f1, f2 = (matcher.frame(k)[0] for k in (i, i + 1))
            T = np.linalg.inv(se2(gt[i])) @ se2(gt[i + 1])  # T_t_t1, true
            Ti = np.linalg.inv(T)
            true_b = f1.points @ Ti[:2, :2].T + Ti[:2, 2]
            P = transform_points(T_cl, true_b)
            pred = np.full((len(P), 2), np.nan)
            front = f1.visible & (P[:, 2] > 0.1)
            pred[front] = cam.project(P[front])
            found: dict[str, Matches] = {
                "IASM": match_returns(f1, f2, f1.pixels, params.search_u_px, params.search_v_px),
                "window": match_returns(f1, f2, pred, params.window_px, params.window_px),
                "dense": window_search(f1, f2, pred, cam, T_cl, params),
            }
            truth = pose_of(T)
            length = float(np.hypot(truth[0], truth[1]))
            d = truth[:2] / max(length, 1e-9)
            for key, m in found.items():
                counts[key].append(len(m.i1))
                e = m.b - true_b[m.i1]
                near = np.linalg.norm(e, axis=1) < 0.04
                errors[key].append(e[near] @ d)
                res = robust_motion(m, f1, f2, cam, T_cl, params, rng)
                if res is not None and length > 0.01:
                    err = res.motion - truth
                    motions[key].append([float(err[:2] @ d) / length, float(err[2])])
        for key in errors:
            e = np.concatenate(errors[key])
            med = float(np.median(e))
            mad = MAD_TO_SIGMA * float(np.median(np.abs(e - med)))
            mo = np.array(motions[key])
            print(
                f"| {seq.name} | {'snapped' if snap else 'raw'} | {key} | {np.mean(counts[key]):.0f} "
                f"| {1e3 * med:+.2f} | {1e3 * mad:.2f} | {100 * mo[:, 0].mean():+.2f} "
                f"| {1e3 * np.degrees(np.sqrt(np.mean(mo[:, 1] ** 2))):.1f} |",
                flush=True,
            )


def table(root: Path, name: str, seeds: list[int]) -> None:
    figures: dict[tuple[bool, bool, str], list[list[float]]] = {}
    for seed in seeds:
        streams, truth = _opened(sequence(root, name, seed))
        for snap, dense in SETTINGS:
            params = dataclasses.replace(
                IasmParams(), snap_max_m=SNAP_M if snap else 0.0, dense_window=dense, keyframe_m=0.0
            )
            cells = []
            for method in ("iasm", "hiasm"):
                if method == "iasm" and dense:  # IASM has no window
                    cells.append("as above")
                    continue
                f = _figures(streams, truth, method, params, ("loop", "avg", "rpe10"))
                figures.setdefault((snap, dense, method), []).append(f)
                cells.append(_cell(f))
            print(f"| {name} | {seed} | {_setting(snap, dense)} | {cells[0]} | {cells[1]} |", flush=True)
    if len(seeds) > 1:
        for snap, dense in SETTINGS:
            cells = [
                _cell(list(np.mean(figures[(snap, dense, m)], axis=0)))
                if (snap, dense, m) in figures
                else "as above"
                for m in ("iasm", "hiasm")
            ]
            print(f"| {name} | mean | {_setting(snap, dense)} | {cells[0]} | {cells[1]} |", flush=True)


# (method, keyframe_m, laser_reject_m): keyframes with and without leaving out the returns
# paired across corners, and the defaults (2 m, 0.03 m) against no keyframes.
KEYFRAMES = (
    ("iasm", 0.0, 0.0),
    ("iasm", 0.0, 0.03),
    ("iasm", 1.0, 0.03),
    ("iasm", 2.0, 0.0),
    ("iasm", 2.0, 0.03),
    ("iasm", 3.0, 0.03),
    ("hiasm", 0.0, 0.0),
    ("hiasm", 2.0, 0.03),
)


def keyframes(root: Path, name: str, seeds: list[int], base: IasmParams) -> None:
    figures: dict[tuple[str, float, float], list[list[float]]] = {}
    for seed in seeds:
        streams, truth = _opened(sequence(root, name, seed))
        for method, kf, reject in KEYFRAMES:
            params = dataclasses.replace(base, keyframe_m=kf, laser_reject_m=reject)
            f = _figures(streams, truth, method, params, ("loop", "avg", "rpe1", "rpe10"))
            figures.setdefault((method, kf, reject), []).append(f)
            print(
                f"| {name} | {seed} | {method} | {kf:g} | {reject:g} | "
                + " | ".join(f"{x:.4f}" for x in f)
                + " |",
                flush=True,
            )
    if len(seeds) > 1:
        for (method, kf, reject), fs in figures.items():
            mean = np.mean(fs, axis=0)
            print(
                f"| {name} | mean | {method} | {kf:g} | {reject:g} | "
                + " | ".join(f"{x:.4f}" for x in mean)
                + " |",
                flush=True,
            )


PAIRED = ("icp", "iasm", "hiasm")


def paired(root: Path, name: str, seeds: list[int], params: IasmParams) -> list[str]:
    """Part 4: ICP, IASM and H-IASM (with ``params``) per seed, the means with their
    standard errors, and H-IASM minus IASM paired by seed."""
    fig: dict[str, list[list[float]]] = {m: [] for m in PAIRED}
    for seed in seeds:
        streams, truth = _opened(sequence(root, name, seed))
        fig["icp"].append(_odometry_figures(streams, truth))
        for method in PAIRED[1:]:
            fig[method].append(_figures(streams, truth, method, params, ("loop", "avg")))
        print(f"| {name} | {seed} | " + " | ".join(_cell(fig[m][-1]) for m in PAIRED) + " |", flush=True)
    if len(seeds) < 2:
        return []
    stats = {m: np.array(fig[m]) for m in PAIRED}
    print(f"| {name} | mean ± s.e. | " + _means(stats) + " |", flush=True)
    return _difference_rows(name, 10.0, stats["iasm"], stats["hiasm"])


def _difference_rows(name: str, rate: float, iasm: np.ndarray, hiasm: np.ndarray) -> list[str]:
    """Rows of H-IASM minus IASM paired by seed (one row per seed in ``iasm``, ``hiasm``:
    loop closure, average position error in metres)."""
    d = 1000.0 * (hiasm[:, :2] - iasm[:, :2])
    mu, se = _mean_se(d)
    return [
        f"| {name} | {rate:g} | {label} | {mu[k]:+.2f} ± {se[k]:.2f} | {(d[:, k] < 0).sum()} of {len(d)} |"
        for k, label in enumerate(("loop closure", "avg position error"))
    ]


def _differences(rows: list[str], setting: str = "camera (Hz)") -> None:
    """The table of H-IASM minus IASM."""
    if rows:
        _header("world", setting, "figure", "H-IASM - IASM, mean ± s.e. (mm)", "seeds where H-IASM is ahead")
        print("\n".join(rows), flush=True)


def rates(
    root: Path, name: str, seeds: list[int], camera_rates: list[float], params: IasmParams
) -> list[str]:
    """Part 5: IASM and H-IASM (with ``params``) at each camera rate, per seed and the
    means; returns the rows of H-IASM minus IASM."""
    diffs: list[str] = []
    for rate in camera_rates:
        fig: dict[str, list[list[float]]] = {m: [] for m in PAIRED[1:]}
        for seed in seeds:
            streams, truth = _opened(sequence(root, name, seed, rate))
            cells = []
            for method in PAIRED[1:]:
                f, stats, steps = _scored(streams, truth, method, params, ("loop", "avg"))
                fig[method].append([*f, stats["fallbacks"]])
                cells.append(f"{_cell(f)}, {stats['fallbacks']} of {steps}")
            print(f"| {name} | {rate:g} | {seed} | " + " | ".join(cells) + " |", flush=True)
        if len(seeds) > 1:
            means = [np.mean(fig[m], axis=0) for m in PAIRED[1:]]
            cells = [f"{_cell(list(v[:2]))}, {v[2]:.1f}" for v in means]
            print(f"| {name} | {rate:g} | mean | " + " | ".join(cells) + " |", flush=True)
            diffs += _difference_rows(name, rate, np.array(fig["iasm"]), np.array(fig["hiasm"]))
    return diffs


RANGE_METHODS = ("icp", "laser", "iasm", "hiasm")
LABELS6 = {"icp": "ICP", "laser": "laser alone, keyframes", "iasm": "IASM", "hiasm": "H-IASM"}


def ranges(
    root: Path, name: str, seeds: list[int], laser_ranges: list[float], params: IasmParams
) -> list[str]:
    """Part 6: ICP, the laser alone through the image methods' chain, IASM and H-IASM
    (with ``params``) with each laser range, per seed and the means; returns the rows of
    H-IASM minus IASM."""
    alone = dataclasses.replace(params, min_correspondences=10**9)  # every image step refused
    diffs: list[str] = []
    for range_m in laser_ranges:
        fig: dict[str, list[list[float]]] = {m: [] for m in RANGE_METHODS}
        for seed in seeds:
            streams, truth = _opened(sequence(root, name, seed, range_max_m=range_m))
            fig["icp"].append(_odometry_figures(streams, truth))
            fig["laser"].append(_figures(streams, truth, "iasm", alone, ("loop", "avg")))
            fig["iasm"].append(_figures(streams, truth, "iasm", params, ("loop", "avg")))
            f, stats, _ = _scored(streams, truth, "hiasm", params, ("loop", "avg"))
            fig["hiasm"].append(f)
            by = ", ".join(f"{k} {v}" for k, v in stats["steps_by"].items())
            cells = " | ".join(_cell(fig[k][-1]) for k in RANGE_METHODS)
            print(f"| {name} | {range_m:g} | {seed} | {cells} | {by} |", flush=True)
        if len(seeds) > 1:
            stat = {k: np.array(fig[k]) for k in RANGE_METHODS}
            print(f"| {name} | {range_m:g} | mean ± s.e. | {_means(stat)} | |", flush=True)
            diffs += _difference_rows(name, range_m, stat["iasm"], stat["hiasm"])
    return diffs


def _means(stats: dict[str, np.ndarray]) -> str:
    """Table cells: each method's mean loop closure / average error ± standard errors."""
    cells = []
    for v in stats.values():
        cells.append(" / ".join(f"{mu:.4f} ± {se:.4f}" for mu, se in zip(*_mean_se(v), strict=True)))
    return " | ".join(cells)


def _odometry_figures(streams: Streams, truth: Trajectory) -> list[float]:
    """The laser odometry's (ICP's) loop closure and average error at every scan."""
    gt = planar_at(truth, streams.scan_stamps_s)
    m = evaluate(anchored(streams.laser_odometry().poses, gt), gt)
    return [float(m[FIGURES[k]]) for k in ("loop", "avg")]


def _mean_se(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Column means of ``v`` (one row per seed) and their standard errors."""
    return v.mean(0), v.std(0, ddof=1) / np.sqrt(len(v))


FIGURES = {
    "loop": "loop_closure_error_m",
    "avg": "average_position_error_m",
    "rpe1": "rpe_1m_rmse_m",
    "rpe10": "rpe_10m_rmse_m",
}


def _opened(seq: Path) -> tuple[Streams, Trajectory]:
    """A sequence's streams, its laser odometry and feature tracks under way, and its truth."""
    streams = open_streams(seq)
    streams.start_laser_odometry()
    streams.feature_tracks()
    return streams, read_tum(seq / "groundtruth.tum")


def _figures(
    streams: Streams, truth: Trajectory, method: str, params: IasmParams, which: tuple[str, ...]
) -> list[float]:
    """One method's run on the streams, scored against the truth (``which``: FIGURES keys)."""
    return _scored(streams, truth, method, params, which)[0]


def _scored(
    streams: Streams, truth: Trajectory, method: str, params: IasmParams, which: tuple[str, ...]
) -> tuple[list[float], dict[str, Any], int]:
    """One method's run: its figures (``which``: FIGURES keys), its counts and its steps."""
    stamps, poses, stats, _ = image_matching.scan_matching(streams, method, params)
    gt = planar_at(truth, stamps)
    m = evaluate(anchored(poses, gt), gt)
    return [float(m[FIGURES[k]]) for k in which], stats, len(stamps) - 1


def _setting(snap: bool, dense: bool) -> str:
    return f"{'snapped' if snap else 'raw'} | {'dense' if dense else 'returns'}"


def _cell(f: list[float]) -> str:
    return " / ".join(f"{x:.4f}" for x in f)


if __name__ == "__main__":
    main()
