"""The paper's Table 1 on the simulated loops: ICP, VO, KF, IASM and H-IASM on one sequence.

For each built-in loop (``corridor-loop``, 60 m; ``cubicle-loop``, 35 m) one lap is
simulated (``rigcal simulate world``: 40 Hz laser with 1 cm noise and 1 % dropouts, 10 Hz
camera with 2 grey levels of noise, seed 1) and localized by every method in the same
process (``rigcal localize --method icp-p2p,icp,vo,kf,iasm,hiasm``), scored against the
ground truth. Speed: each method is then run alone, end to end, as ``rigcal localize``
runs it (reading, laser odometry, feature tracks, the method); its wall time is compared
with the lap's duration (real time = 1) -- for ``kf`` that is ICP + VO + KF. The CPU
seconds of the run (all its threads) are given too: wall time near CPU / 2 means both
cores were kept busy, and CPU / 2 is the least wall time 2 free cores could reach. Each is run
with rigcal's compiled kernels (the laser odometry's ICP iterations and line work, IASM's
laser metric and SAD) and again with
their numpy references in the same run (``--no-reference`` skips those), after a first
run that compiles the kernels (or loads them from numba's cache; ``jit_cost.py``).
``--decoders rigcal,opencv`` runs each also with the images read by OpenCV, in turn (the
same grey levels; rigcal's reader decodes PNG faster, ``bench_decode.py``).

``--range-max-m`` shortens the laser's range (30 m by default): at 8 m the corridor lap's
long sides are corridors whose ends the laser cannot see, the case the paper's image
methods are for.

    .venv/bin/python benchmarks/bench_localize.py [--worlds corridor-loop,cubicle-loop] [--keep DIR]
        [--seed N] [--range-max-m M] [--methods icp,iasm,...] [--no-speed] [--decoders rigcal,opencv]
"""

from __future__ import annotations

import argparse
import contextlib
import os
import tempfile
from collections.abc import Iterator
from itertools import product
from pathlib import Path

from rigcal.localize.pipeline import run, table
from rigcal.localize.tracks import DETECTORS, TrackParams
from rigcal.sim.drive import DriveSpec, write_drive
from rigcal.sim.world import BUILTIN
from rigcal.viz.localize_output import write_run

# Accuracy: every method on the same sequence in one run. The paper's ICP (Eq. 4) is
# point-to-point; point-to-line is listed as the stronger baseline.
METHODS = ["icp-p2p", "icp", "vo", "kf", "iasm", "hiasm"]
LABELS = {
    "icp-p2p": "ICP (Eq. 4, point-to-point)",
    "icp": "ICP point-to-line (baseline)",
    "vo": "VO",
    "kf": "KF",
    "iasm": "IASM",
    "hiasm": "H-IASM",
}
# Speed: each method alone, end to end (every stage it needs), as `rigcal localize` runs it.
ALONE = ["icp", "vo", "kf", "iasm", "hiasm"]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--worlds", default="corridor-loop,cubicle-loop")
    ap.add_argument("--keep", type=Path, help="Keep the sequences and outputs in this folder.")
    ap.add_argument("--no-speed", action="store_true", help="Skip the runs of each method alone.")
    ap.add_argument("--seed", type=int, default=1, help="The simulation's seed.")
    ap.add_argument("--range-max-m", type=float, default=30.0, help="The simulated laser's range.")
    ap.add_argument("--methods", default=",".join(METHODS), help="Methods of the accuracy table.")
    ap.add_argument("--alone", default=",".join(ALONE), help="Methods of the speed table.")
    ap.add_argument("--no-reference", action="store_true", help="Skip the runs with the numpy references.")
    ap.add_argument("--detector", choices=DETECTORS, help="What starts the feature tracks.")
    ap.add_argument(
        "--decoders",
        default="rigcal",
        help="Image readers of the speed runs, each in turn: rigcal (read_grey), opencv (cv2.imread).",
    )
    args = ap.parse_args()
    methods = args.methods.split(",")
    decoders = args.decoders.split(",")
    if not set(decoders) <= {"rigcal", "opencv"}:
        ap.error(f"--decoders: {args.decoders!r}; expected rigcal, opencv or both")
    tracks = TrackParams() if args.detector is None else TrackParams(detector=args.detector)
    with tempfile.TemporaryDirectory() as tmp:
        root = args.keep or Path(tmp)
        root.mkdir(parents=True, exist_ok=True)
        for name in args.worlds.split(","):
            seq = root / sequence_name(name, args.seed, args.range_max_m)
            if not (seq / "sequence.yaml").exists():
                spec = DriveSpec(seed=args.seed, range_max_m=args.range_max_m)
                write_drive(BUILTIN[name](), spec, str(seq))
            r = run(seq, methods, tracks=tracks)
            write_run(r, seq, root / f"{seq.name}-out", force=True)
            laser = f", {args.range_max_m:g} m laser" if args.range_max_m != 30.0 else ""
            length = r.methods[0].metrics["path_length_m"]  # type: ignore[index]
            print(f"\n### {name}: {length} m lap in {r.duration_s:.1f} s{laser}, {tracks.detector} tracks\n")
            print(table([(LABELS[m.method], m.metrics) for m in r.methods if m.metrics is not None]))
            print("\n| method | poses | counts |")
            print("|---|---|---|")
            for m in r.methods:
                counts = {k: v for k, v in m.stats.items() if k in ("run_status", "steps_by", "fallbacks")}
                print(f"| {m.method} | {len(m.stamps_s)} | {counts or ''} |")
            if args.no_speed:
                continue
            n_images = len((seq / "images.csv").read_text().splitlines()) - 1
            print(f"\n(load average before: {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs)")
            print("\n| method alone | kernels | wall (s) | CPU (s) | x real time | stages (s) |")
            print("|---|---|---|---|---|---|")
            per = float("nan")
            alone = args.alone.split(",")
            # Compile / load the kernels.
            run(seq, alone[:1], tracks=tracks)
            for m, compiled, decoder in product(
                alone, (True, False) if not args.no_reference else (True,), decoders
            ):
                with kernels(compiled), images_read_by(decoder):
                    a = run(seq, [m], tracks=tracks)
                cpu = a.cpu_s
                stages = ", ".join(f"{k.removesuffix('_s')} {v:.1f}" for k, v in a.timings_s.items())
                label = "compiled" if compiled else "numpy reference"
                label += ", OpenCV decoding" if decoder == "opencv" else ""
                print(
                    f"| {m} | {label} | {a.wall_s:.1f} | {cpu:.1f} "
                    f"| {a.duration_s / a.wall_s:.2f} | {stages} |",
                    flush=True,
                )
                if m == "vo" and compiled:
                    per = (a.timings_s["tracks_s"] + a.timings_s["vo_s"]) / n_images * 1000
            if per == per:  # measured only when vo runs alone
                print(f"\nVO per frame (tracks + runs, the laser odometry beside it): {per:.1f} ms")


@contextlib.contextmanager
def images_read_by(decoder: str) -> Iterator[None]:
    """Within: the sequence's images are read by rigcal's ``read_grey`` (``"rigcal"``) or
    by OpenCV's ``cv2.imread(..., IMREAD_GRAYSCALE)`` (``"opencv"``; the same grey levels)."""
    import cv2

    from rigcal.localize import streams

    saved = streams.read_grey
    if decoder == "opencv":
        streams.read_grey = lambda path: cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    try:
        yield
    finally:
        streams.read_grey = saved


@contextlib.contextmanager
def kernels(compiled: bool) -> Iterator[None]:
    """Within: the laser odometry (ICP's iterations, line extraction, carrying and fits),
    IASM's laser metric and its SAD matching use their compiled kernels or, when not
    ``compiled``, their numpy / Python references (the ``kernel`` keyword's default)."""
    from rigcal import lines
    from rigcal.localize import iasm, icp, line_normals, odometry

    functions = (
        icp.icp,
        line_normals.line_fits,
        line_normals.line_normals,
        odometry.icp_odometry,
        odometry.carry_labels,
        lines.extract_lines,
        iasm.laser_scores,
        iasm.match_returns,
        iasm.image_scores,
    )
    saved = [dict(f.__kwdefaults__ or {}) for f in functions]
    for f in functions:
        assert "kernel" in (f.__kwdefaults__ or {}), f"{f.__qualname__} has no kernel keyword"
        f.__kwdefaults__ = {**(f.__kwdefaults__ or {}), "kernel": compiled}
    try:
        yield
    finally:
        for f, d in zip(functions, saved, strict=True):
            f.__kwdefaults__ = d


def sequence_name(world: str, seed: int, range_max_m: float) -> str:
    """The folder of a lap (as ``bench_matching.py`` names them too)."""
    name = world if seed == 1 else f"{world}-seed{seed}"
    return name if range_max_m == 30.0 else f"{name}-range{range_max_m:g}"


if __name__ == "__main__":
    main()
