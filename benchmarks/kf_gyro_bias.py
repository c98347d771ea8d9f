"""What the gyroscope's bias costs the Kalman filter, on one kept lap with the gyro
(benchmarks/kf_gyro_laps.py): the default and ``--kf icp-first`` without the gyro, with it
(the bias learned at the stops, and learned from every step), and with a perfect gyro (the
truth's yaw over the same steps) whose bias is known (prior 1-sigma ~0) or not (the
filter's prior); and the simulated gyro less its simulated bias (``rigcal.sim.drive.gyro_bias``,
the drive re-simulated from the sequence's seed, world and standstill), that bias known.
ATE (m) at the scans' stamps, as bench_kf.py scores; the bias estimated at the end and its
1-sigma (deg/s), the seconds of gyro steps the rig stood still over, and the simulated
bias at the end.

    .venv/bin/python benchmarks/kf_gyro_bias.py DIR3/cubicle-loop-seed1-40s
    .venv/bin/python benchmarks/kf_gyro_bias.py DIR/corridor-loop-seed4-40s-still3-gyro  # bench_kf.py --gyro
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
from rigcal.sim.drive import DriveSpec, Motion, gyro_bias
from rigcal.sim.world import BUILTIN


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("lap", type=Path)
    args = ap.parse_args()
    streams = open_streams(args.lap)
    od, res = pickle.loads((args.lap / "odometries.pkl").read_bytes())
    streams.results["vo"] = res
    truth = read_tum(args.lap / "groundtruth.tum")
    source = streams.sequence.source
    spec = DriveSpec(
        seed=int(source["seed"]),
        duration_s=float(streams.scan_stamps_s[-1]) + 1.0,
        start_still_s=float(source.get("start_still_s", 0.0)),
        gyro=True,
    )
    bias_t, bias = gyro_bias(Motion(BUILTIN[str(source["world"])](), spec), spec)
    print(
        f"simulated bias: {np.degrees(bias[0]):.4f} deg/s at the start, "
        f"{np.degrees(np.interp(spec.start_still_s, bias_t, bias)):.4f} after the standstill, "
        f"{np.degrees(np.interp(streams.scan_stamps_s[-1], bias_t, bias)):.4f} at the end",
        flush=True,
    )

    def ate(r: kalman.KfResult) -> tuple[float, float]:
        """ATE (m) and the heading's RMS error (deg), both after anchoring the first pose."""
        r = kalman.path_at(r, streams.scan_stamps_s)
        gt = planar_at(truth, r.stamps_s)
        est = anchored(r.poses, gt)
        yaw = np.angle(np.exp(1j * (est[:, 2] - gt[:, 2])))
        return float(evaluate(est, gt)["ate_rmse_m"]), float(np.degrees(np.sqrt(np.mean(yaw**2))))

    icp_ate, icp_yaw = ate(kalman.KfResult(streams.scan_stamps_s, od.poses, np.zeros((len(od.poses), 3, 3))))
    print(f"ICP | ATE {icp_ate:.4f} m | yaw RMS {icp_yaw:.3f} deg", flush=True)

    for mode in ("weighted", "icp-first"):
        base = kalman.KF_MODES[mode]
        ms = kf_measurements(streams, od, res, base)
        others = [m for m in ms if m.source != "gyro"]
        gyro = [m for m in ms if m.source == "gyro"]
        at = np.array([gyro[0].t0] + [m.t1 for m in gyro])
        perfect = kalman.gyro_increments(at, np.diff(planar_at(truth, at)[:, 2]), base.gyro_noise)
        known = dataclasses.replace(base, gyro_bias_sigma=1e-9, gyro_bias_walk=1e-9)
        # The simulated gyro's steps less its simulated bias over each.
        unbiased = [
            dataclasses.replace(
                m,
                motion=m.motion
                - np.array(
                    [0.0, 0.0, np.mean(np.interp(np.linspace(m.t0, m.t1, 21), bias_t, bias)) * (m.t1 - m.t0)]
                ),
            )
            for m in gyro
        ]
        everywhere = dataclasses.replace(base, gyro_still_only=False)
        for label, meas, params in (
            ("no gyro", others, base),
            ("gyro, bias learned at the stops", ms, base),
            ("gyro, bias learned from every step", ms, everywhere),
            ("perfect gyro, bias known", others + perfect, known),
            ("perfect gyro, bias learned at the stops", others + perfect, base),
            ("gyro less its simulated bias, bias known", others + unbiased, known),
        ):
            r = kalman.run_filter(meas, params)
            err, yaw_err = ate(r)
            print(
                f"{mode} | {label} | ATE {err:.4f} m | yaw RMS {yaw_err:.3f} deg "
                f"| bias {np.degrees(r.gyro_bias):.4f} "
                f"+- {np.degrees(r.gyro_bias_sigma):.4f} deg/s | still {r.gyro_still_s:.1f} s",
                flush=True,
            )
    streams.stop_background()


if __name__ == "__main__":
    main()
