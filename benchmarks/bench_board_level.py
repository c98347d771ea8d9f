"""Boards that never tilt: the reduced solve on upright boards, scans read from PCD files.

A session as a common course procedure records it: the board upright (leaning at most
``--lean-deg``, never rolled), turned in front of a level scanner, ``--captures`` captures,
the realistic simulator's scanner and room (``rigcal.sim.noise``: Student-t range noise of
about 20 mm sd, mixed pixels, grazing bias, clutter). Every scan is written as a binary PCD
file stored clockwise, no-return beams as 0 0 0, and the session reads those.

The priors are what a lab measures: roll and pitch 0 +- 0.5 deg (a spirit level) and the
camera's height above the scan plane +- 5 mm (a tape); each trial draws the measured
values from those sigmas around the truth, so a covariance that carries the priors'
uncertainty should cover the error as often as it says.

Per seed: the full solve's verdict (it must refuse, naming the missing tilt), then
``calibrate_board(..., level=priors)`` (the product's path); scored against the truth by
the yaw error, the error of the camera's position in the scan plane, the squared
Mahalanobis distance of those three observed parameters under their own covariance
(d2, 3 dof, 95 % bound 7.81) and the 6-dof NEES of T_cam_laser under its covariance (95 %
bound 12.59). A PCD check compares each capture's board returns read from PCD and from the
YAML scan.

    .venv/bin/python benchmarks/bench_board_level.py              # 20 seeds
    .venv/bin/python benchmarks/bench_board_level.py --seeds 5
"""

from __future__ import annotations

import argparse
import re
import tempfile
import time
from pathlib import Path

import numpy as np

from rigcal.calib.board.calibrate import calibrate_board
from rigcal.calib.board.level import LevelPriors
from rigcal.calib.board.session import read_board_session
from rigcal.calib.intrinsics import Board
from rigcal.errors import CalibrationError
from rigcal.scan import read_scan
from rigcal.sim.board_session import BoardSpec, generate_board_session, write_board_session
from rigcal.sim.noise import RealisticNoise

CHI2_3_95 = 7.814727903251178
CHI2_6_95 = 12.591587243743977
ROLL_PITCH_SIGMA_DEG = 0.5
HEIGHT_SIGMA_M = 0.005


def write_pcd(path: Path, xyz: np.ndarray) -> None:
    """A binary PCD file of the points in this order (x y z float32)."""
    head = (
        "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\n"
        f"COUNT 1 1 1\nWIDTH {len(xyz)}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {len(xyz)}\nDATA binary\n"
    )
    path.write_bytes(head.encode() + np.asarray(xyz, dtype="<f4").tobytes())


def to_pcd(folder: Path) -> Path:
    """Rewrite a session folder's scans as clockwise binary PCD files (no return: 0 0 0) and
    a session file that names them."""
    session = folder / "board_session.yaml"
    for scan_file in sorted((folder / "scans").glob("*.yaml")):
        scan = read_scan(scan_file)
        xyz = np.zeros((len(scan.ranges_m), 3))
        xyz[scan.valid, :2] = scan.points[scan.valid]
        write_pcd(scan_file.with_suffix(".pcd"), xyz[::-1])  # stored clockwise
    text = re.sub(r"(scan: scans/\S+)\.yaml", r"\1.pcd", session.read_text())
    out = folder / "board_session_pcd.yaml"
    out.write_text(text)
    return out


def trial(seed: int, captures: int, lean_deg: float, folder: Path) -> dict[str, float]:
    spec = BoardSpec(
        n_captures=captures,
        seed=seed,
        noise=RealisticNoise(),
        board=Board(7, 5, 0.12),
        max_tilt_deg=lean_deg,
        max_roll_deg=0.0,
    )
    sim = generate_board_session(spec)
    yaml_session = write_board_session(sim, folder) / "board_session.yaml"
    pcd_session = to_pcd(folder)
    T = sim.T_cam_laser
    rng = np.random.default_rng(10_000 + seed)
    height = float((-T[:3, :3].T @ T[:3, 3])[2])
    priors = LevelPriors(
        (float(rng.normal(0.0, ROLL_PITCH_SIGMA_DEG)), ROLL_PITCH_SIGMA_DEG),
        (float(rng.normal(0.0, ROLL_PITCH_SIGMA_DEG)), ROLL_PITCH_SIGMA_DEG),
        (height + float(rng.normal(0.0, HEIGHT_SIGMA_M)), HEIGHT_SIGMA_M),
    )
    refused = 0.0
    try:
        calibrate_board(pcd_session)
    except CalibrationError as exc:
        refused = float("never tilt" in str(exc))
    a = read_board_session(yaml_session, level=priors)
    b = read_board_session(pcd_session, level=priors)
    pcd_diff = max(
        float(np.abs(np.sort(x.points_laser, axis=0) - np.sort(y.points_laser, axis=0)).max())
        if len(x.points_laser) == len(y.points_laser)
        else np.inf
        for x, y in zip(a.observations, b.observations, strict=True)
    )
    t0 = time.perf_counter()
    cal = calibrate_board(pcd_session, truth_path=folder / "truth.yaml", level=priors)
    seconds = time.perf_counter() - t0
    truth = cal.report["truth"]
    lv = truth["level"]
    return {
        "refused": refused,
        "pcd_diff_m": pcd_diff,
        "yaw_deg": abs(lv["yaw_error_deg"]),
        "horizontal_mm": lv["horizontal_error_mm"],
        "d2": lv["d2_observed"],
        "nees": truth["nees"],
        "rotation_deg": truth["rotation_error_deg"],
        "translation_mm": truth["translation_error_mm"],
        "sigma_yaw_deg": cal.report["reduced"]["solved"]["yaw_deg"]["sigma"],
        "seconds": seconds,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--captures", type=int, default=5)
    ap.add_argument("--lean-deg", type=float, default=2.0)
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(args.seeds):
            r = trial(seed, args.captures, args.lean_deg, Path(tmp) / f"s{seed}")
            rows.append(r)
            print(
                f"seed {seed:3d}: yaw {r['yaw_deg']:.3f} deg (sigma {r['sigma_yaw_deg']:.3f}), "
                f"horizontal {r['horizontal_mm']:.1f} mm, d2 {r['d2']:.2f}, NEES {r['nees']:.2f}, "
                f"T error {r['rotation_deg']:.2f} deg / {r['translation_mm']:.1f} mm, "
                f"{r['seconds']:.1f} s",
                flush=True,
            )
    col = {k: np.array([r[k] for r in rows]) for k in rows[0]}
    n = len(rows)
    print(
        f"\n{n} seeds, {args.captures} captures of upright boards (lean <= {args.lean_deg:g} deg), PCD scans"
    )
    print(f"full solve refused with the tilt message: {int(col['refused'].sum())}/{n}")
    print(f"PCD vs YAML scans: largest difference of a board return {col['pcd_diff_m'].max():.2e} m")
    print(
        f"yaw error: median {np.median(col['yaw_deg']):.3f} deg, 95th pct "
        f"{np.percentile(col['yaw_deg'], 95):.3f} deg (median sigma {np.median(col['sigma_yaw_deg']):.3f})"
    )
    print(
        f"horizontal error: median {np.median(col['horizontal_mm']):.1f} mm, 95th pct "
        f"{np.percentile(col['horizontal_mm'], 95):.1f} mm"
    )
    print(
        f"d2 (3 observed dof): mean {col['d2'].mean():.2f} (expected 3), inside the 95 % bound "
        f"{CHI2_3_95:.2f}: {np.mean(col['d2'] <= CHI2_3_95):.0%}"
    )
    print(
        f"NEES (6 dof): mean {col['nees'].mean():.2f} (expected 6), inside the 95 % bound "
        f"{CHI2_6_95:.2f}: {np.mean(col['nees'] <= CHI2_6_95):.0%}"
    )
    print(f"solve time: median {np.median(col['seconds']):.1f} s (machine loaded)")


if __name__ == "__main__":
    main()
