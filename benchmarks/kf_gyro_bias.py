"""What the gyroscope's bias costs the Kalman filter, on one kept lap with the gyro
(benchmarks/kf_gyro_laps.py): the default and ``--kf icp-first`` without the gyro, with it
(the bias learned at the stops, and learned from every step), and with a perfect gyro (the
truth's yaw over the same steps) whose bias is known (prior 1-sigma ~0) or not (the
filter's prior). ATE (m) at the scans' stamps, as bench_kf.py scores; the bias estimated
at the end (deg/s).

    .venv/bin/python benchmarks/kf_gyro_bias.py DIR3/cubicle-loop-seed1-40s
"""

from __future__ import annotations

import argparse
import dataclasses
import pickle
from pathlib import Path

import numpy as np

from rigcal.io.trajectory import read_tum
from rigcal.localize import kalman
from rigcal.localize.metrics import anchored, evaluate
from rigcal.localize.pipeline import kf_measurements, planar_at
from rigcal.localize.streams import open_streams


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("lap", type=Path)
    args = ap.parse_args()
    streams = open_streams(args.lap)
    od, res = pickle.loads((args.lap / "odometries.pkl").read_bytes())
    streams.results["vo"] = res
    truth = read_tum(args.lap / "groundtruth.tum")

    def ate(r: kalman.KfResult) -> float:
        r = kalman.path_at(r, streams.scan_stamps_s)
        gt = planar_at(truth, r.stamps_s)
        return float(evaluate(anchored(r.poses, gt), gt)["ate_rmse_m"])

    for mode in ("weighted", "icp-first"):
        base = kalman.KF_MODES[mode]
        ms = kf_measurements(streams, od, res, base)
        others = [m for m in ms if m.source != "gyro"]
        gyro = [m for m in ms if m.source == "gyro"]
        at = np.array([gyro[0].t0] + [m.t1 for m in gyro])
        perfect = kalman.gyro_increments(at, np.diff(planar_at(truth, at)[:, 2]), base.gyro_noise)
        known = dataclasses.replace(base, gyro_bias_sigma=1e-9, gyro_bias_walk=1e-9)
        everywhere = dataclasses.replace(base, gyro_still_only=False)
        for label, meas, params in (
            ("no gyro", others, base),
            ("gyro, bias learned at the stops", ms, base),
            ("gyro, bias learned from every step", ms, everywhere),
            ("perfect gyro, bias known", others + perfect, known),
            ("perfect gyro, bias learned at the stops", others + perfect, base),
        ):
            r = kalman.run_filter(meas, params)
            print(
                f"{mode} | {label} | ATE {ate(r):.4f} m | bias {np.degrees(r.gyro_bias):.4f} deg/s",
                flush=True,
            )
    streams.stop_background()


if __name__ == "__main__":
    main()
