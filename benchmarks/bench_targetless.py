"""Targetless drift check (``rigcal check RIG --sequence SEQ``) on simulated drives.

Drives of both worlds with the realistic camera (exposure walk, blur, noise) are simulated
once (``rigcal simulate world``; kept in ``--cache``). Each drive is cut into windows of
30 s, 60 s and the full lap; each window is checked against the true rig and against
rigs perturbed by known amounts, one axis at a time (laser frame: rotations about x, y,
z; translations along x, y, z). Printed: per window length, the false alarms on the true
rig, the detection rate per axis and size on the axes the window observes, the error of
the estimated correction there, and the check's speed (the window's duration over the
first check's wall time, which includes the laser odometry and decoding the images).

    .venv/bin/python benchmarks/bench_targetless.py                  # ~40 min on 2 loaded cores
    .venv/bin/python benchmarks/bench_targetless.py --sizes 0.3:20 --json out.json
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from rigcal.drift.targetless import AXES, TargetlessSettings, check_targetless
from rigcal.geometry import make_T, rotvec_to_R
from rigcal.localize.streams import Streams, open_streams

WORLDS = ("corridor-loop", "cubicle-loop")
REALISTIC = ["--exposure-walk", "0.02", "--image-blur-px", "0.7", "--image-noise", "3"]


def drive(cache: Path, world: str, seed: int) -> Path:
    """The simulated lap, made once."""
    out = cache / f"{world}-s{seed}"
    if not (out / "sequence.yaml").exists():
        rigcal = str(Path(sys.executable).parent / "rigcal")
        command = [rigcal, "simulate", "world", "--world", world, "-o", str(out), "--seed", str(seed)]
        subprocess.run(
            [*command, *REALISTIC, "--force"],
            check=True,
        )
    return out


def window(streams: Streams, t0: float, length_s: float | None) -> Streams:
    """The part of a drive from t0 for length_s seconds (None: to the end)."""
    seq = streams.sequence
    t1 = math.inf if length_s is None else t0 + length_s
    keep_s = [i for i, s in enumerate(seq.scans) if s.stamp_s is not None and t0 <= s.stamp_s < t1]
    keep_i = [i for i, t in enumerate(seq.image_stamps_s) if t0 <= t < t1]
    sub = dataclasses.replace(
        seq,
        scans=tuple(seq.scans[i] for i in keep_s),
        image_stamps_s=seq.image_stamps_s[keep_i],
        image_files=tuple(seq.image_files[i] for i in keep_i),
    )
    return Streams(sub, streams.rig)


def perturbed(rig, axis: int, size: float):  # type: ignore[no-untyped-def]
    """The rig with T_cam_laser moved by ``size`` along one laser-frame axis (rad or m):
    T_stored = T_true Exp(p); the right correction is -p."""
    p = np.zeros(6)
    p[axis] = size
    return dataclasses.replace(rig, T_cam_laser=rig.T_cam_laser @ make_T(rotvec_to_R(p[:3]), p[3:]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cache", type=Path, default=Path("/tmp/rigcal-bench-targetless"))
    ap.add_argument("--seeds", type=int, nargs="+", default=[2])
    ap.add_argument(
        "--sizes", default="0.3:20", help="perturbation sizes, rotation deg:translation mm, comma-separated"
    )
    ap.add_argument("--lengths", default="30,full")
    ap.add_argument("--axes", default="rx,ry,rz,tx,ty,tz", help="axes perturbed, comma-separated")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    sizes = [tuple(float(x) for x in s.split(":")) for s in args.sizes.split(",")]
    lengths = [None if x == "full" else float(x) for x in args.lengths.split(",")]
    axes = args.axes.split(",")
    settings = TargetlessSettings()
    rows = []
    for world in WORLDS:
        for seed in args.seeds:
            full = open_streams(drive(args.cache, world, seed))
            lap = float(full.scan_stamps_s[-1])
            for length in lengths:
                if length is not None and length > lap:
                    continue
                starts = [0.0] if length is None else list(np.arange(0.0, lap - length + 1e-9, length))
                for t0 in starts:
                    w = window(full, float(t0), length)
                    dur = float(w.scan_stamps_s[-1] - w.scan_stamps_s[0])
                    label = "full" if length is None else f"{length:g}"
                    rig = full.rig
                    assert rig is not None
                    trials = [(None, 0.0, 0.0)] + [
                        (a, s_deg, s_mm) for s_deg, s_mm in sizes for a in range(6) if AXES[a] in axes
                    ]
                    for axis, s_deg, s_mm in trials:
                        size = 0.0 if axis is None else (math.radians(s_deg) if axis < 3 else s_mm / 1000.0)
                        stored = rig if axis is None else perturbed(rig, axis, size)
                        t = time.perf_counter()
                        res = check_targetless(stored, w, settings)
                        wall = time.perf_counter() - t
                        rec = res.record
                        row = {
                            "world": world,
                            "seed": seed,
                            "length": label,
                            "start_s": float(t0),
                            "duration_s": round(dur, 1),
                            "axis": None if axis is None else AXES[axis],
                            "size": None if axis is None else (s_deg if axis < 3 else s_mm),
                            "verdict": res.verdict,
                            "observed": rec.get("observed_axes", []),
                            "p_value": rec.get("p_value"),
                            "t2": rec.get("t2"),
                            "correction_deg": rec.get("correction_rotation_deg"),
                            "correction_mm": rec.get("correction_translation_mm"),
                            "sigma_deg": rec.get("sigma_rotation_deg"),
                            "sigma_mm": rec.get("sigma_translation_mm"),
                            "wall_s": round(wall, 2),
                            # The laser odometry's share (the first check of a window runs it;
                            # the others reuse it): a reference measured in the same process.
                            "icp_s": round(w.timings_s.get("icp_s", 0.0), 2),
                        }
                        if axis is not None and res.verdict != "cannot_tell":
                            est = res.correction[axis]
                            row["error"] = (
                                math.degrees(est + size) if axis < 3 else 1000.0 * (est + size)
                            )  # deg or mm
                        rows.append(row)
                        print(json.dumps(row), flush=True)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    report(rows, sizes)


def report(rows: list[dict], sizes: list[tuple[float, ...]]) -> None:  # type: ignore[type-arg]
    print("\n| drive | unperturbed: false alarms / cannot tell / checks | x real time | check / odometry |")
    print("|---|---|---|---|")
    for length in ("30", "60", "full"):
        r0 = [r for r in rows if r["length"] == length and r["axis"] is None]
        if not r0:
            continue
        fa = sum(r["verdict"] == "drifted" for r in r0)
        ct = sum(r["verdict"] == "cannot_tell" for r in r0)
        speed = [r["duration_s"] / r["wall_s"] for r in r0]
        ratio = [r["wall_s"] / r["icp_s"] for r in r0 if r["icp_s"] > 0]
        rel = f"{min(ratio):.1f}-{max(ratio):.1f}" if ratio else "-"
        print(f"| {length} s | {fa} / {ct} / {len(r0)} | {min(speed):.2f}-{max(speed):.2f} | {rel} |")
    print("\n| drive | axis | size | observed in | detected | correction error (median, max) |")
    print("|---|---|---|---|---|---|")
    for length in ("30", "60", "full"):
        for axis in AXES:
            for s_deg, s_mm in sizes:
                size = s_deg if axis.startswith("r") else s_mm
                rs = [r for r in rows if r["length"] == length and r["axis"] == axis and r["size"] == size]
                if not rs:
                    continue
                obs = [r for r in rs if axis in r["observed"]]
                det = sum(r["verdict"] == "drifted" for r in obs)
                err = [abs(r["error"]) for r in obs if "error" in r]
                unit = "deg" if axis.startswith("r") else "mm"
                e = f"{np.median(err):.3f}, {max(err):.3f} {unit}" if err else "-"
                cells = [
                    f"{length} s",
                    axis,
                    f"{size:g} {unit}",
                    f"{len(obs)}/{len(rs)}",
                    f"{det}/{len(obs)}",
                    e,
                ]
                print("| " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
