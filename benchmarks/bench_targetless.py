"""Targetless drift check (``rigcal check RIG --sequence SEQ``) on simulated drives.

Drives of both worlds with the realistic camera (exposure walk, blur, noise) are simulated
once (``rigcal simulate world``; kept in ``--cache``). Each drive is cut into windows of
30 s, 60 s and the full lap; each window is checked against the true rig and against
rigs perturbed by known amounts, one axis at a time (laser frame: rotations about x, y,
z; translations along x, y, z). Printed: per window length, the false alarms on the true
rig, the detection rate per axis and size on the axes the window observes (with its
Clopper-Pearson 95 % interval), the error of the estimated correction there, and the
check's speed. The speed is measured in the same process against a reference: the laser
odometry of the same window is run first (timed alone), then the first check of the
window (decoding its images included; the odometry reused, as ``rigcal check`` reuses the
one the pipeline computes) is timed; printed as x real time (the window's duration over
the check's wall time, and over check plus odometry) and as the check's time over the
odometry's.

    .venv/bin/python benchmarks/bench_targetless.py                  # ~40 min on 2 loaded cores
    .venv/bin/python benchmarks/bench_targetless.py --sizes 0.3:20 --json out.json
    .venv/bin/python benchmarks/bench_targetless.py --seeds 2 3 --lengths 30 --step-s 15 --axes rx,ry,rz
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
    ap.add_argument("--step-s", type=float, help="windows start this far apart (default: their length)")
    ap.add_argument("--worlds", default=",".join(WORLDS))
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    sizes = [tuple(float(x) for x in s.split(":")) for s in args.sizes.split(",")]
    lengths = [None if x == "full" else float(x) for x in args.lengths.split(",")]
    axes = args.axes.split(",")
    settings = TargetlessSettings()
    rows = []
    for world in args.worlds.split(","):
        for seed in args.seeds:
            full = open_streams(drive(args.cache, world, seed))
            lap = float(full.scan_stamps_s[-1])
            for length in lengths:
                if length is not None and length > lap:
                    continue
                step = length if args.step_s is None or length is None else args.step_s
                starts = [0.0] if length is None else list(np.arange(0.0, lap - length + 1e-9, step))
                for t0 in starts:
                    w = window(full, float(t0), length)
                    t = time.perf_counter()
                    w.laser_odometry()
                    icp_s = time.perf_counter() - t
                    dur = float(w.scan_stamps_s[-1] - w.scan_stamps_s[0])
                    label = "full" if length is None else f"{length:g}"
                    rig = full.rig
                    assert rig is not None
                    # One trial per axis and size (a translation's size repeats across
                    # the rotations' sizes: tried once).
                    once = {
                        (a, s_deg if a < 3 else s_mm): (a, s_deg, s_mm)
                        for s_deg, s_mm in sizes
                        for a in range(6)
                        if AXES[a] in axes
                    }
                    trials = [(None, 0.0, 0.0), *once.values()]
                    for n_trial, (axis, s_deg, s_mm) in enumerate(trials):
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
                            "wall_s": round(wall, 3),
                            # The first check of a window decodes its images (the others
                            # find them kept); the laser odometry of the window, run just
                            # before in the same process, is the reference.
                            "first": n_trial == 0,
                            "icp_s": round(icp_s, 3),
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


def clopper_pearson(k: int, n: int, level: float = 0.95) -> tuple[float, float]:
    """The exact (Clopper-Pearson) two-sided interval of a rate seen k times in n."""
    from scipy.stats import beta

    a = (1.0 - level) / 2.0
    lo = 0.0 if k == 0 else float(beta.ppf(a, k, n - k + 1))
    hi = 1.0 if k == n else float(beta.ppf(1.0 - a, k + 1, n - k))
    return lo, hi


def rate(k: int, n: int) -> str:
    """``k/n (lo-hi %)``."""
    if n == 0:
        return "-"
    lo, hi = clopper_pearson(k, n)
    return f"{k}/{n} ({100 * lo:.0f}-{100 * hi:.0f} %)"


def label(length: str) -> str:
    return "full lap" if length == "full" else f"{length} s"


def report(rows: list[dict], sizes: list[tuple[float, ...]]) -> None:  # type: ignore[type-arg]
    print(
        "\n| drive | unperturbed: false alarms (95 % interval) / cannot tell | "
        "x real time: check, check + odometry | check / odometry |"
    )
    print("|---|---|---|---|")
    for length in ("30", "60", "full"):
        r0 = [r for r in rows if r["length"] == length and r["axis"] is None]
        if not r0:
            continue
        fa = sum(r["verdict"] == "drifted" for r in r0)
        ct = sum(r["verdict"] == "cannot_tell" for r in r0)
        first = [r for r in rows if r["length"] == length and r.get("first")]
        speed = [r["duration_s"] / r["wall_s"] for r in first]
        both = [r["duration_s"] / (r["wall_s"] + r["icp_s"]) for r in first]
        ratio = [r["wall_s"] / r["icp_s"] for r in first if r["icp_s"] > 0]
        rel = f"{min(ratio):.2f}-{max(ratio):.2f}" if ratio else "-"
        cells = [
            label(length),
            f"{rate(fa, len(r0) - ct)} / {ct}",
            f"{min(speed):.1f}-{max(speed):.1f}, {min(both):.1f}-{max(both):.1f}",
            rel,
        ]
        print("| " + " | ".join(cells) + " |")
    head = ["drive", "axis", "size", "observed in", "detected (95 % interval)"]
    head.append("correction error (median, max)")
    print("\n| " + " | ".join(head) + " |")
    print("|---|---|---|---|---|---|")
    for length in ("30", "60", "full"):
        for axis in AXES:
            for size in dict.fromkeys(s_deg if axis.startswith("r") else s_mm for s_deg, s_mm in sizes):
                rs = [r for r in rows if r["length"] == length and r["axis"] == axis and r["size"] == size]
                if not rs:
                    continue
                obs = [r for r in rs if axis in r["observed"]]
                det = sum(r["verdict"] == "drifted" for r in obs)
                err = [abs(r["error"]) for r in obs if "error" in r]
                unit = "deg" if axis.startswith("r") else "mm"
                e = f"{np.median(err):.3f}, {max(err):.3f} {unit}" if err else "-"
                cells = [
                    label(length),
                    axis,
                    f"{size:g} {unit}",
                    f"{len(obs)}/{len(rs)}",
                    rate(det, len(obs)),
                    e,
                ]
                print("| " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
