"""Monte-Carlo accuracy of the box-target calibration, and honesty of its covariance.

For each setting, synthetic sessions are generated with a known T_cam_laser
(rigcal.sim.box_session), solved, and compared with the truth. Printed as markdown tables
for docs/benchmarks.md.

    .venv/bin/python benchmarks/bench_calib_accuracy.py            # full run (~25 min on 2 cores)
    .venv/bin/python benchmarks/bench_calib_accuracy.py --quick    # a smoke run

Tables:
1. noise sweep at 20 captures: pick noise 0.5 / 1 / 2 px with range noise 5 / 10 / 20 mm;
2. captures sweep at 1 px / 10 mm: 5, 10, 20, 40 captures;
3. the paper's end points versus rigcal's whole-side model, same sessions;
4. covariance honesty: mean NEES against the chi-square 95% band for 6 dof.
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import time
from dataclasses import dataclass, replace

import numpy as np
from scipy.stats import chi2

from rigcal.calib.box.refine import NoiseModel, RefineParams
from rigcal.calib.box.solve import CalibProblem, SolveSettings, solve
from rigcal.calib.report import truth_comparison
from rigcal.errors import CalibrationError
from rigcal.sim.box_session import SessionSpec, generate_session, session_observations

PROCESSES = os.cpu_count() or 1


@dataclass
class Outcome:
    rot_deg: list[float]
    trans_mm: list[float]
    nees: list[float]
    failures: int
    seconds: float


def one_session(job: tuple[SessionSpec, bool]) -> tuple[float, float, float, float] | None:
    """(rotation error deg, translation error mm, NEES, solve seconds) of one simulated
    session, or None when the solve fails."""
    spec, use_side_points = job
    settings = SolveSettings(
        refine=RefineParams(use_side_points=use_side_points),
        noise=NoiseModel(pick_sigma_px=spec.pick_sigma_px, range_sigma_m=spec.range_sigma_m),
    )
    sess = generate_session(spec)
    obs = tuple(session_observations(sess))
    t0 = time.perf_counter()
    try:
        res = solve(CalibProblem(sess.camera, obs, settings))
    except CalibrationError:
        return None
    seconds = time.perf_counter() - t0
    cmp = truth_comparison(res.T_cam_laser, res.covariance, sess.T_cam_laser)
    return cmp["rotation_error_deg"], cmp["translation_error_mm"], cmp["nees"], seconds


def run(spec: SessionSpec, sessions: int, use_side_points: bool, seed0: int) -> Outcome:
    """Sessions seed0, seed0 + 1, ... of ``spec``, over all cores (each session is seeded,
    so the result does not depend on the number of processes)."""
    out = Outcome([], [], [], 0, 0.0)
    jobs = [(replace(spec, seed=seed0 + k), use_side_points) for k in range(sessions)]
    with multiprocessing.Pool(PROCESSES) as pool:
        results = pool.map(one_session, jobs, chunksize=1)
    for r in results:
        if r is None:
            out.failures += 1
            continue
        out.rot_deg.append(r[0])
        out.trans_mm.append(r[1])
        out.nees.append(r[2])
        out.seconds += r[3]
    return out


def row(label: str, o: Outcome) -> str:
    r = np.array(o.rot_deg)
    t = np.array(o.trans_mm)
    n = len(r)
    return (
        f"| {label} | {n} | {np.median(r):.3f} | {np.percentile(r, 90):.3f} | {np.median(t):.2f} | "
        f"{np.percentile(t, 90):.2f} | {np.mean(o.nees):.2f} | {o.failures} | "
        f"{1000 * o.seconds / max(n, 1):.0f} |"
    )


HEADER = (
    "| setting | sessions | median rot err (deg) | p90 rot (deg) | median trans err (mm) | p90 trans (mm) "
    "| mean NEES | failed | solve ms |\n|---|---|---|---|---|---|---|---|---|"
)


def nees_band(sessions: int, dof: int = 6) -> tuple[float, float]:
    """95% band of the mean of `sessions` chi-square(dof) variables."""
    return chi2.ppf(0.025, dof * sessions) / sessions, chi2.ppf(0.975, dof * sessions) / sessions


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument(
        "--sessions", type=int, default=200, help="sessions at the main setting (1 px, 10 mm, 20)"
    )
    ap.add_argument("--sweep-sessions", type=int, default=60, help="sessions at each other setting")
    ap.add_argument("--quick", action="store_true", help="10 sessions per setting")
    ap.add_argument("--seed", type=int, default=1000)
    args = ap.parse_args()
    main_n = 10 if args.quick else args.sessions
    sweep_n = 10 if args.quick else args.sweep_sessions
    base = SessionSpec(n_captures=20, pick_sigma_px=1.0, range_sigma_m=0.01)

    print("## Noise sweep (20 captures, whole-side model)\n")
    print(HEADER)
    main_outcome = None
    for px, m in ((0.5, 0.005), (1.0, 0.01), (2.0, 0.02)):
        n = main_n if px == 1.0 else sweep_n
        o = run(replace(base, pick_sigma_px=px, range_sigma_m=m), n, True, args.seed)
        if px == 1.0:
            main_outcome = o
        print(row(f"{px:g} px / {1000 * m:g} mm", o))

    print("\n## Captures sweep (1 px / 10 mm, whole-side model)\n")
    print(HEADER)
    for nc in (5, 10, 20, 40):
        o = (
            main_outcome
            if nc == 20 and main_outcome is not None
            else run(replace(base, n_captures=nc), sweep_n, True, args.seed)
        )
        print(row(f"{nc} captures", o))

    print("\n## Paper's end points vs whole-side model (1 px / 10 mm, 20 captures, same sessions)\n")
    print(HEADER)
    paper = run(base, main_n, False, args.seed)
    print(row("paper: first/last returns, isotropic", paper))
    assert main_outcome is not None
    print(row("rigcal: fitted side, per-end covariance", main_outcome))

    print("\n## Covariance honesty (1 px / 10 mm, 20 captures)\n")
    lo, hi = nees_band(len(main_outcome.nees))
    mean = float(np.mean(main_outcome.nees))
    verdict = "inside" if lo <= mean <= hi else "OUTSIDE"
    print(
        f"mean NEES {mean:.3f} over {len(main_outcome.nees)} sessions; "
        f"95% band for 6 dof [{lo:.3f}, {hi:.3f}]: {verdict}"
    )


if __name__ == "__main__":
    main()
