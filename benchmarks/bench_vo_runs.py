"""Which stage of visual odometry gives way on a harsher camera: each run against the truth.

Visual odometry (``rigcal.localize.vo``) measures the rig's motion run by run: the
feature tracks give the rotation and the translation's direction (five-point, Eq. (5)),
the laser points the translation's length (Eq. (6)), or the tracks carry it from a
neighbouring run. A lap's loop closure mixes all of these; this script splits them. For
each built-in loop, seed and camera (``--cameras``: sets of ``DriveSpec`` fields,
separated by ``;``, the empty set being the simulator's own camera), one lap is simulated
and localized by VO as ``rigcal localize --method vo`` runs it, and each run's planar
motion is compared with the ground truth over the same two images:

- the turn's error (degrees): the tracks and the five-point pose;
- the translation's direction error (degrees; runs that moved at least 5 cm);
- the length's error ``|length / true length - 1|`` (runs that moved at least 5 cm): the
  scale, by the run's status (``ok``: the laser's Eq. (6); ``carried``: the tracks;
  ``no-scale``: the last speed, a guess).

The table gives, per loop, camera and status, the runs, the median and 90th percentile
of each error and the share of runs with a length off by more than 10 %. ``--tracks``
sets the feature tracks' settings, as ``rigcal localize --tracks`` takes them
(``"equalize=clahe"``).

    .venv/bin/python benchmarks/bench_vo_runs.py [--worlds corridor-loop,cubicle-loop] [--seeds 1,2]
        [--cameras ";exposure_walk=0.03;image_noise_sigma=4;image_blur_sigma_px=1"]
        [--tracks KEY=VALUE,...] [--keep DIR]
"""

from __future__ import annotations

import argparse
import tempfile
from collections import defaultdict
from pathlib import Path

import numpy as np

from bench_localize import sequence_name
from bench_tracks import drive_of, folder_of, seeds_of, variants_of
from rigcal.geometry import pose_of, se2
from rigcal.io.trajectory import read_tum
from rigcal.localize.pipeline import _vo_result, planar_at
from rigcal.localize.streams import open_streams
from rigcal.localize.tracks import TrackParams
from rigcal.sim.drive import DriveSpec, write_drive
from rigcal.sim.world import BUILTIN

MOVED_M = 0.05  # runs shorter than this give no direction or length error


def run_errors(seq: Path, tracks: TrackParams) -> list[tuple[str, float, float, float]]:
    """(status, turn error deg, direction error deg, length error) of each VO run of a lap."""
    streams = open_streams(seq)
    streams.track_params = tracks
    try:
        res = _vo_result(streams)
    finally:
        streams.stop_background()
    truth = read_tum(seq / "groundtruth.tum")
    stamps = streams.image_stamps_s[res.frames]
    gt = planar_at(truth, stamps)
    out = []
    for k, step in enumerate(res.steps):
        est = pose_of(np.linalg.inv(se2(res.poses[k])) @ se2(res.poses[k + 1]))
        true = pose_of(np.linalg.inv(se2(gt[k])) @ se2(gt[k + 1]))
        turn = abs(np.degrees(np.angle(np.exp(1j * (est[2] - true[2])))))
        moved = float(np.linalg.norm(true[:2]))
        direction = length = float("nan")
        if moved >= MOVED_M:
            length = abs(float(np.linalg.norm(est[:2])) / moved - 1.0)
            if np.linalg.norm(est[:2]) > 1e-9:
                c = complex(*est[:2]) / complex(*true[:2])
                direction = abs(float(np.degrees(np.angle(c))))
        out.append((step.status, float(turn), direction, length))
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--worlds", default="corridor-loop,cubicle-loop")
    ap.add_argument("--seeds", default="1,2", help='The simulation seeds: "1", "1,2,3" or "1-10".')
    ap.add_argument(
        "--cameras",
        default=";exposure_walk=0.03;image_noise_sigma=4;image_blur_sigma_px=1;"
        "image_noise_sigma=4,image_blur_sigma_px=1,exposure_walk=0.03",
        help='Cameras compared: DriveSpec fields "KEY=VALUE,...;..." (empty: the simulator\'s).',
    )
    ap.add_argument("--tracks", default="", help='The feature tracks\' settings: "KEY=VALUE,...".')
    ap.add_argument("--keep", type=Path, help="Keep the sequences in this folder.")
    args = ap.parse_args()
    tracks = next(iter(variants_of(args.tracks).values()))
    cameras = [c.strip() for c in args.cameras.split(";")]
    rows: dict[tuple[str, str, str], list[tuple[float, float, float]]] = defaultdict(list)
    with tempfile.TemporaryDirectory() as tmp:
        root = args.keep or Path(tmp)
        root.mkdir(parents=True, exist_ok=True)
        for name in args.worlds.split(","):
            for camera in cameras:
                for seed in seeds_of(args.seeds):
                    seq = root / (sequence_name(name, seed, 30.0) + folder_of(camera, "-"))
                    if not (seq / "sequence.yaml").exists():
                        write_drive(BUILTIN[name](), DriveSpec(seed=seed, **drive_of(camera)), str(seq))
                    for status, *err in run_errors(seq, tracks):
                        rows[name, camera or "simulator's", status].append((err[0], err[1], err[2]))
                        rows[name, camera or "simulator's", "all"].append((err[0], err[1], err[2]))
    print(f"\n### VO runs against the truth, seeds {args.seeds}, tracks: {args.tracks or 'defaults'}\n")
    print(
        "| world | camera | status | runs | turn error median / p90 (deg) "
        "| direction error median / p90 (deg) | length error median / p90 | length off > 10 % |"
    )
    print("|---|---|---|---|---|---|---|---|")
    order = {"all": 0, "ok": 1, "carried": 2, "no-scale": 3, "still": 4, "failed": 5}
    for (name, camera, status), v in sorted(rows.items(), key=lambda kv: (*kv[0][:2], order[kv[0][2]])):
        a = np.array(v)
        lengths = a[:, 2][np.isfinite(a[:, 2])]
        off = f"{np.mean(lengths > 0.1):.0%}" if len(lengths) else "-"
        cells = [_spread(a[:, 0]), _spread(a[:, 1]), _spread(a[:, 2], "{:.3f}")]
        print(f"| {name} | {camera} | {status} | {len(a)} | " + " | ".join(cells) + f" | {off} |")


def _spread(x: np.ndarray, fmt: str = "{:.2f}") -> str:
    """ "median / 90th percentile" of the finite values, or "-"."""
    x = x[np.isfinite(x)]
    if not len(x):
        return "-"
    return f"{fmt.format(np.median(x))} / {fmt.format(np.percentile(x, 90))}"


if __name__ == "__main__":
    main()
