"""Calibration on realistic scanner noise: accuracy, NEES, spread against covariance, verdicts.

Both methods on sessions from the realistic simulator (``rigcal.sim.noise``: Student-t range
noise of about 20 mm standard deviation, mixed pixels at depth jumps, grazing beams
reading long, static clutter in a still room, a board larger than its printed pattern),
at 10 and 20 captures, over many seeds:

- median rotation and translation error against the truth;
- NEES under the reported covariance (the model's, scaled to the spread over captures
  where that is clearly larger): its mean, and the share of solves within the chi-square
  6-dof 95 % point (12.59), which should be about 95 %;
- how often the spread over captures and the covariance agree (spread scale <= 2);
- captures (board) or box ends (box) rejected;
- for contrast, the same sessions solved with the noise assumed instead of estimated
  (``--noise assumed``: 1 cm range noise, 1 px picks, 0.5 px corners);
- board sessions with every pose captured twice (``BoardSpec.repeats``): repeats whose
  verdicts differ (should be none).

    .venv/bin/python benchmarks/bench_realistic_calib.py            # 20 seeds
    .venv/bin/python benchmarks/bench_realistic_calib.py --seeds 5  # quicker
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from rigcal.calib.board.calibrate import calibrate_board
from rigcal.calib.box.solve import CalibProblem, SolveSettings, solve
from rigcal.calib.intrinsics import Board
from rigcal.calib.report import truth_comparison
from rigcal.errors import CalibrationError
from rigcal.sim.board_session import BoardSpec, generate_board_session, write_board_session
from rigcal.sim.box_session import SessionSpec, generate_session, session_observations
from rigcal.sim.noise import RealisticNoise

CHI2_6_95 = 12.591587243743977


# A lab's large board (A0-like): 7 x 5 inner corners of 12 cm squares, a 0.96 x 0.72 m
# printed pattern on a sheet 5 cm larger all round (the realistic model's border).
BOARD = Board(7, 5, 0.12)


def board_run(n: int, seed: int, mode: str, repeats: int = 1) -> dict[str, object]:
    spec = BoardSpec(n_captures=n, seed=seed, noise=RealisticNoise(), repeats=repeats, board=BOARD)
    sim = generate_board_session(spec)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "s"
        write_board_session(sim, folder)
        cal = calibrate_board(folder / "board_session.yaml", noise=mode)
    res = cal.result
    out = _scores(res.T_cam_laser, res.covariance, sim.T_cam_laser)
    out["rejected"] = int((~res.inlier_captures).sum())
    out["scale"] = res.spread.scale if res.spread is not None else np.nan
    out["range_est_mm"] = 1000 * res.noise.range_sigma_m
    if repeats > 1:
        v = res.inlier_captures.reshape(-1, repeats)
        out["split_poses"] = int((v != v[:, :1]).any(axis=1).sum())
    return out


def box_run(n: int, seed: int, mode: str) -> dict[str, object]:
    sim = generate_session(SessionSpec(n_captures=n, seed=seed, noise=RealisticNoise()))
    obs = tuple(session_observations(sim))
    res = solve(CalibProblem(sim.camera, obs, SolveSettings(noise_mode=mode)))
    out = _scores(res.T_cam_laser, res.covariance, sim.T_cam_laser)
    out["rejected"] = int((~res.inliers).sum())
    out["scale"] = res.spread.scale if res.spread is not None else np.nan
    out["range_est_mm"] = 1000 * res.noise.range_sigma_m
    return out


def _scores(T, cov, T_truth) -> dict[str, object]:
    t = truth_comparison(T, cov, T_truth)
    return {"rot_deg": t["rotation_error_deg"], "trans_mm": t["translation_error_mm"], "nees": t["nees"]}


def nees_band(runs: int) -> tuple[float, float]:
    """95 % interval of the mean of `runs` chi-square(6) draws (an honest covariance's NEES)."""
    from scipy.stats import chi2

    return chi2.ppf(0.025, 6 * runs) / runs, chi2.ppf(0.975, 6 * runs) / runs


def summarise(rows: list[dict[str, object]]) -> dict[str, float]:
    ok = [r for r in rows if "error" not in r]
    a = {k: np.array([r[k] for r in ok], dtype=float) for k in ("rot_deg", "trans_mm", "nees", "scale")}
    return {
        "runs": len(rows),
        "failed": len(rows) - len(ok),
        "rot_med": float(np.median(a["rot_deg"])),
        "trans_med": float(np.median(a["trans_mm"])),
        "nees_mean": float(np.mean(a["nees"])),
        "nees_med": float(np.median(a["nees"])),
        "in_band": float(np.mean(a["nees"] <= CHI2_6_95)),
        "agree": float(np.mean(a["scale"] <= 2.0)),
        "rejected": float(np.mean([r["rejected"] for r in ok])),
        "range_mm": float(np.median([r["range_est_mm"] for r in ok])),
    }


def run_many(fn, *args) -> list[dict[str, object]]:
    rows = []
    for a in args[0]:
        try:
            rows.append(fn(*a))
        except CalibrationError as exc:
            rows.append({"error": str(exc)})
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--captures", type=int, nargs="+", default=[10, 20])
    args = ap.parse_args()
    seeds = range(args.seeds)
    print(f"realistic noise: {RealisticNoise()}")
    print(
        f"board: {BOARD}; a mean NEES over {args.seeds} honest solves lies in {nees_band(args.seeds)} (95 %)"
    )
    print(
        f"{'method':<7}{'captures':>9}{'noise':>9}{'runs':>6}{'fail':>6}{'rot_med_deg':>13}{'trans_med_mm':>14}"
        f"{'NEES_mean':>11}{'NEES_med':>10}{'in_95%':>8}{'agree':>7}{'rejected':>10}{'range_mm':>10}{'s/run':>7}"
    )
    for method, fn in (("board", board_run), ("box", box_run)):
        for n in args.captures:
            for mode in ("auto", "assumed"):
                t0 = time.perf_counter()
                rows = run_many(fn, [(n, s, mode) for s in seeds])
                dt = (time.perf_counter() - t0) / len(rows)
                s = summarise(rows)
                print(
                    f"{method:<7}{n:>9}{mode:>9}{s['runs']:>6}{s['failed']:>6}{s['rot_med']:>13.3f}"
                    f"{s['trans_med']:>14.2f}{s['nees_mean']:>11.2f}{s['nees_med']:>10.2f}{s['in_band']:>8.0%}"
                    f"{s['agree']:>7.0%}{s['rejected']:>10.2f}{s['range_mm']:>10.1f}{dt:>7.2f}"
                )
    print()
    print("board poses captured twice (repeats=2): poses whose two captures got different verdicts")
    for n in args.captures:
        for mode in ("auto", "assumed"):
            rows = run_many(board_run, [(n // 2, s, mode, 2) for s in seeds])
            ok = [r for r in rows if "error" not in r]
            split = sum(int(r["split_poses"]) for r in ok)
            print(
                f"  {n} captures ({n // 2} poses x 2), noise {mode}: {split} split poses of "
                f"{len(ok) * (n // 2)} over {len(ok)} solves ({len(rows) - len(ok)} failed); "
                f"captures rejected {np.mean([r['rejected'] for r in ok]):.2f} per solve"
            )


if __name__ == "__main__":
    main()
