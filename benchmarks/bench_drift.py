"""Drift check on simulated rigs: false alarms when nothing moved, detection when it did.

For each trial a stored rig is solved from a 20-capture simulated session (one of
``--rigs`` seeded base sessions, reused across trials), then a new session is simulated
with the camera moved on the rig by a known amount (``moved_T_cam_laser``: a turn about a
random axis or a shift in a random direction, seeded), and ``check_drift`` is run at the
default false-alarm level (1 %). New sessions have 10 captures (residual and pose tests)
or 3 captures (residual test only). Printed as a markdown table for docs/benchmarks.md.

    .venv/bin/python benchmarks/bench_drift.py              # ~10 min on 2 cores
    .venv/bin/python benchmarks/bench_drift.py --trials 20  # a smoke run
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
from dataclasses import replace
from pathlib import Path

import numpy as np

from rigcal.calib.box.picks import PickSession
from rigcal.calib.box.refine import NoiseModel
from rigcal.calib.box.solve import CalibProblem, SolveSettings, solve
from rigcal.drift.target import DriftSettings, check_drift
from rigcal.rig import Rig
from rigcal.sim.box_session import (
    SessionSpec,
    default_T_cam_laser,
    generate_session,
    moved_T_cam_laser,
    session_observations,
)

PROCESSES = os.cpu_count() or 1
MOVES = [("nothing moved", 0.0, 0.0), ("1 mm", 0.0, 1.0), ("5 mm", 0.0, 5.0), ("20 mm", 0.0, 20.0),
         ("0.1 deg", 0.1, 0.0), ("0.5 deg", 0.5, 0.0)]  # fmt: skip
NOISE = NoiseModel()


def base_rig(seed: int) -> Rig:
    sess = generate_session(SessionSpec(n_captures=20, seed=seed))
    res = solve(CalibProblem(sess.camera, tuple(session_observations(sess)), SolveSettings(noise=NOISE)))
    return Rig(res.T_cam_laser, sess.camera, res.covariance, provenance={"noise": vars(NOISE)})


def trial(job: tuple[Rig, int, float, float, int]) -> bool:
    """Whether the check says drifted for one new session."""
    rig, captures, deg, mm, seed = job
    T = moved_T_cam_laser(default_T_cam_laser(), deg, mm, seed=seed)
    sess = generate_session(replace(SessionSpec(n_captures=captures), seed=seed), T_cam_laser=T)
    obs = tuple(session_observations(sess))
    where = Path("simulated")
    session = PickSession(path=where, camera=sess.camera, camera_path=where, laser={}, observations=obs)
    return check_drift(rig, session, DriftSettings()).drifted


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--trials", type=int, default=100, help="new sessions per row")
    ap.add_argument("--rigs", type=int, default=10, help="stored rigs (base sessions) to draw from")
    args = ap.parse_args()
    with multiprocessing.Pool(PROCESSES) as pool:
        rigs = pool.map(base_rig, [5000 + k for k in range(args.rigs)], chunksize=1)
        print(f"## Drift check, {args.trials} new sessions per row, level 1 %\n")
        print("| camera moved by | new session | flagged drifted | rate |\n|---|---|---|---|")
        for captures in (10, 3):
            for label, deg, mm in MOVES:
                jobs = [(rigs[k % len(rigs)], captures, deg, mm, 9000 + k) for k in range(args.trials)]
                flags = np.array(pool.map(trial, jobs, chunksize=1))
                kind = "false alarms" if deg == 0 and mm == 0 else "detected"
                count = f"{int(flags.sum())}/{len(flags)} {kind}"
                print(f"| {label} | {captures} captures | {count} | {100 * flags.mean():.0f} % |", flush=True)


if __name__ == "__main__":
    main()
