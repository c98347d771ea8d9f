"""Box target against checkerboard planes, at equal effort (number of captures).

Both simulated with the same rig, camera, scanner (1 cm range noise, 1 % dropouts) and
room. Box sessions: hand-picked box ends with 1 px noise (``rigcal.sim.box_session``).
Board sessions: an 8x6-corner, 6 cm checkerboard turned up to 45 deg and tilted up to 35
deg, corners detected with 0.3 px noise (``rigcal.sim.board_session``). Each session is
solved the way ``rigcal solve`` solves it, from the resolved observations, and compared
with the truth. Printed as a markdown table for docs/benchmarks.md.

    .venv/bin/python benchmarks/bench_box_vs_board.py            # ~10 min on 2 cores
    .venv/bin/python benchmarks/bench_box_vs_board.py --sessions 10
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
from dataclasses import replace

import numpy as np

from rigcal.calib.board.plane import solve_plane
from rigcal.calib.board.session import board_pose, plane_observation
from rigcal.calib.box.refine import NoiseModel
from rigcal.calib.box.solve import CalibProblem, SolveSettings, solve
from rigcal.calib.report import truth_comparison
from rigcal.errors import CalibrationError
from rigcal.lines import LineParams, extract_lines
from rigcal.sim.board_session import BoardSpec, generate_board_session
from rigcal.sim.box_session import SessionSpec, generate_session, session_observations

PROCESSES = os.cpu_count() or 1
CORNER_SIGMA_PX = 0.3


def box_trial(job: tuple[int, int]) -> tuple[float, float, float] | None:
    captures, seed = job
    sess = generate_session(SessionSpec(n_captures=captures, seed=seed))
    try:
        res = solve(
            CalibProblem(sess.camera, tuple(session_observations(sess)), SolveSettings(noise=NoiseModel()))
        )
    except CalibrationError:
        return None
    c = truth_comparison(res.T_cam_laser, res.covariance, sess.T_cam_laser)
    return c["rotation_error_deg"], c["translation_error_mm"], c["nees"]


def board_trial(job: tuple[int, int]) -> tuple[float, float, float] | None:
    captures, seed = job
    spec = replace(BoardSpec(n_captures=captures, corner_sigma_px=CORNER_SIGMA_PX), seed=seed)
    sess = generate_board_session(spec)
    params = LineParams.for_range_noise(spec.range_sigma_m)
    obs = []
    for i, c in enumerate(sess.captures):
        T, cov, _ = board_pose(sess.camera, spec.board, c.corners_px, CORNER_SIGMA_PX)
        pts = np.array(extract_lines(c.scan, params)[c.segment_id].points)
        obs.append(plane_observation(i, c.name, T, cov, pts))
    try:
        res = solve_plane(obs, spec.range_sigma_m)
    except CalibrationError:
        return None
    c = truth_comparison(res.T_cam_laser, res.covariance, sess.T_cam_laser)
    return c["rotation_error_deg"], c["translation_error_mm"], c["nees"]


def row(label: str, results: list[tuple[float, float, float] | None]) -> str:
    ok = np.array([r for r in results if r is not None])
    failed = sum(r is None for r in results)
    return (
        f"| {label} | {len(ok)} | {np.median(ok[:, 0]):.3f} | {np.percentile(ok[:, 0], 90):.3f} | "
        f"{np.median(ok[:, 1]):.2f} | {np.percentile(ok[:, 1], 90):.2f} | "
        f"{np.mean(ok[:, 2]):.2f} | {failed} |"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sessions", type=int, default=60)
    args = ap.parse_args()
    print(f"## Box target vs checkerboard planes, {args.sessions} sessions per row\n")
    print(
        "| method, captures | sessions | median rot err (deg) | p90 rot (deg) | median trans err (mm) "
        "| p90 trans (mm) | mean NEES | failed |\n|---|---|---|---|---|---|---|---|"
    )
    with multiprocessing.Pool(PROCESSES) as pool:
        for captures in (10, 20):
            jobs = [(captures, 2000 + k) for k in range(args.sessions)]
            print(row(f"box, {captures}", pool.map(box_trial, jobs, chunksize=1)), flush=True)
            print(row(f"board, {captures}", pool.map(board_trial, jobs, chunksize=1)), flush=True)


if __name__ == "__main__":
    main()
