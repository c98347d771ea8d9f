"""Loop closure's image place recognition on the simulated loops driven twice.

Each loop of the paper (``cubicle-loop``, ``corridor-loop``) is driven two laps in a row
(``DriveSpec(laps=2)``, images and scans, seed 0): every keyframe of the second lap
revisits a place of the first. Point-to-line ICP (the pipeline's laser odometry) gives the
poses; loop closure (rigcal.localize.loop_closure.close_loops) runs on them with the scan
search alone and with the image proposals too (rigcal.localize.place_recognition, through
rigcal.localize.pipeline.image_proposals), on

- ``icp``: ICP's poses as they are, and
- ``icp, heading bias``: ICP's poses with a heading bias of ``--bias-deg-per-m`` added to
  every step (a miscalibrated or slipping odometry): the second lap is metres and tens of
  degrees off the first, beyond the scan search's window.

The truth tells which keyframe pairs are revisits: two keyframes at least ``min_loop_m``
of path apart whose true positions are within ``--revisit-m``. For each source, the
proposals' precision (the share that are revisits) and recall (the share of keyframes
with an earlier revisit that got one) before the scan verification, and after it (an
accepted closure is right when its T_j_i is within 0.2 m and 2 deg of the truth's). ATE
(SE(2)-aligned, m) and the end position error of the poses with closure off, with the
scan search, and with the scan search and images. CPU time (this process, all threads)
of place recognition per keyframe, with and without reading the images, as a ratio to
ICP's over the same drive, and of loop closure with and without the image proposals; the
load average is printed beside them.

    uv sync --group bench
    .venv/bin/python benchmarks/bench_place_recognition.py [--drives DIR] [--bias-deg-per-m 0.5]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from rigcal.localize.icp import IcpParams
from rigcal.localize.loop_closure import (
    Closure,
    LoopParams,
    close_loops,
    compose,
    keyframes,
    path_along,
    relative,
    scans_at,
)
from rigcal.localize.metrics import anchored, evaluate
from rigcal.localize.odometry import icp_odometry
from rigcal.localize.pipeline import Estimate, _ground_truth, image_proposals, planar_at
from rigcal.localize.place_recognition import PlaceParams
from rigcal.localize.streams import open_streams


def biased(poses: np.ndarray, deg_per_m: float) -> np.ndarray:
    """The poses re-chained with each step's yaw biased by ``deg_per_m`` per metre of step."""
    steps = relative(poses[:-1], poses[1:])
    steps[:, 2] += np.radians(deg_per_m) * np.hypot(steps[:, 0], steps[:, 1])
    out = [poses[0]]
    for s in steps:
        out.append(compose(out[-1][None], s[None])[0])
    return np.array(out)


def revisits(
    along: np.ndarray, keys: np.ndarray, gt: np.ndarray, params: LoopParams, near_m: float
) -> set[int]:
    """The keyframes (pose indices) with an earlier keyframe ``min_loop_m`` of path back
    whose true position is within ``near_m``."""
    out = set()
    for a, i in enumerate(keys):
        earlier = keys[:a][along[i] - along[keys[:a]] >= params.min_loop_m]
        if len(earlier) and np.min(np.hypot(*(gt[earlier, :2] - gt[i, :2]).T)) <= near_m:
            out.add(int(i))
    return out


def right_pair(gt: np.ndarray, i: int, j: int, near_m: float) -> bool:
    return bool(np.hypot(*(gt[i, :2] - gt[j, :2])) <= near_m)


def right_closure(gt: np.ndarray, c: Closure) -> bool:
    assert c.T_j_i is not None
    true = relative(gt[c.j][None], gt[c.i][None])[0]
    d = c.T_j_i - true
    return bool(np.hypot(d[0], d[1]) <= 0.2 and abs(np.angle(np.exp(1j * d[2]))) <= np.radians(2.0))


def scores(closures: list[Closure], gt: np.ndarray, truth: set[int], near_m: float) -> str:
    """Precision and recall before and after the verification (module docstring)."""
    proposed = [(c.i, c.j) for c in closures]
    good = [p for p in proposed if right_pair(gt, *p, near_m)]
    accepted = [c for c in closures if c.T_j_i is not None and not c.kernel_rejected]
    right = [c for c in accepted if right_closure(gt, c)]

    def share(a: int, b: int) -> str:
        return f"{a}/{b} ({100 * a / b:.0f} %)" if b else "-"

    return (
        f"{share(len(good), len(proposed))} | {share(len({i for i, _ in good} & truth), len(truth))} "
        f"| {share(len(right), len(accepted))} | {share(len({c.i for c in right} & truth), len(truth))}"
    )


def drive(world: str, folder: Path) -> Path:
    from rigcal.sim.drive import DriveSpec, write_drive
    from rigcal.sim.world import world_named

    seq = folder / f"{world}-2laps"
    if not (seq / "sequence.yaml").exists():
        write_drive(world_named(world), DriveSpec(laps=2), str(seq))
    return seq


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--drives", default=None, help="keep the drives in (and reuse them from) DIR")
    ap.add_argument("--bias-deg-per-m", type=float, default=0.5, help="the heading bias of the second case")
    ap.add_argument("--revisit-m", type=float, default=2.0, help="true positions this close are a revisit")
    ap.add_argument("--worlds", default="cubicle-loop,corridor-loop")
    a = ap.parse_args()
    params, place = LoopParams(), PlaceParams()
    pr_rows, ate_rows, cost_rows = [], [], []
    loads = [os.getloadavg()[0]]
    with tempfile.TemporaryDirectory() as tmp:
        for world in a.worlds.split(","):
            seq = drive(world, Path(a.drives or tmp))
            streams = open_streams(seq)
            truth = _ground_truth(seq, streams.sequence.groundtruth_file)
            assert truth is not None
            t = streams.scan_stamps_s
            icp_odometry(streams.scans[:50], IcpParams(method="point-to-line"))  # compile / load kernels
            c0 = time.process_time()
            od = streams.laser_odometry()
            icp_cpu = time.process_time() - c0
            gt = planar_at(truth, t)
            points = scans_at(streams.scans, t, od.poses, t)
            for case, poses in (
                ("icp", od.poses),
                (f"icp, heading bias {a.bias_deg_per_m:g} deg/m", biased(od.poses, a.bias_deg_per_m)),
            ):
                along = path_along(poses)
                keys = keyframes(along, params.keyframe_m)
                truth_keys = revisits(along, keys, gt, params, a.revisit_m)
                est = Estimate(t, poses)
                streams.results.pop("place_features", None)  # each case pays for its features
                c0 = time.process_time()
                read0 = streams.timings_s.get("read_images_s", 0.0)
                proposals, stats = image_proposals(streams, est, params, place)
                place_cpu = time.process_time() - c0
                read_s = streams.timings_s.get("read_images_s", 0.0) - read0
                c0 = time.process_time()
                scan_only = close_loops(points, poses, params, od.covariance)
                scan_cpu = time.process_time() - c0
                c0 = time.process_time()
                both = close_loops(points, poses, params, od.covariance, proposals)
                both_cpu = time.process_time() - c0
                loads.append(os.getloadavg()[0])
                by_images = [c for c in both.closures if c.source == "images"]
                by_scan = [c for c in both.closures if c.source == "scan"]
                label = f"{world} | {case}"
                for source, tried in (
                    ("scan search (alone)", scan_only.closures),
                    ("scan search (with images)", by_scan),
                    ("images", by_images),
                ):
                    pr_rows.append(f"| {label} | {source} | {scores(tried, gt, truth_keys, a.revisit_m)} |")
                m = [evaluate(anchored(p, gt), gt) for p in (poses, scan_only.poses, both.poses)]
                ate = " | ".join(f"{x['ate_rmse_m']:.3f}" for x in m)
                end = " | ".join(f"{x['end_position_error_m']:.3f}" for x in m)
                by = {s: c["accepted"] for s, c in both.counts_by_source.items()}
                ate_rows.append(
                    f"| {label} | {len(keys)} / {len(truth_keys)} | {ate} | {end} "
                    f"| {scan_only.counts['accepted']} | {by.get('scan', 0)} + {by.get('images', 0)} |"
                )
                n = max(stats.get("keyframes_with_images", 0), 1)
                cost_rows.append(
                    f"| {label} | {len(t)} scans, {len(keys)} keyframes | {icp_cpu:.1f} "
                    f"| {1000 * place_cpu / n:.1f} ({1000 * (place_cpu - read_s) / n:.1f}) "
                    f"| {1000 * icp_cpu / len(keys):.1f} "
                    f"| {place_cpu / icp_cpu:.2f} ({(place_cpu - read_s) / icp_cpu:.2f}) "
                    f"| {scan_cpu / icp_cpu:.2f} | {both_cpu / icp_cpu:.2f} |"
                )
                print(f"{label}: place recognition {stats}", flush=True)
    print(
        "\nPrecision and recall of the proposals (before the scan verification) "
        "and of the accepted closures (after)"
    )
    print("| loop | case | source | precision before | recall before | precision after | recall after |")
    print("|---|---|---|---|---|---|---|")
    print("\n".join(pr_rows))
    print("\nLoop closure off, scan search, scan search + images")
    print(
        "| loop | case | keyframes / with a revisit | ATE off (m) | ATE scan (m) | ATE scan + images (m) "
        "| end error off (m) | scan (m) | scan + images (m) | accepted: scan | scan + images |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    print("\n".join(ate_rows))
    print("\nCPU time (this process, all threads)")
    print(
        "| loop | case | drive | ICP (s) | place recognition per keyframe (ms; without reading images) "
        "| ICP per keyframe (ms) | place recognition / ICP (without reading) | loop closure, scan / ICP "
        "| loop closure, scan + images / ICP |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    print("\n".join(cost_rows))
    print(f"load average (1 min) over the runs: {min(loads):.1f}-{max(loads):.1f} (2 cores)")


if __name__ == "__main__":
    main()
