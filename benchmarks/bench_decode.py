"""Reading a sequence's images as grey: OpenCV's ``cv2.imread(..., IMREAD_GRAYSCALE)``
against rigcal's ``read_grey`` (imagecodecs' PNG decoder and libpng's grey weights).

The frames of a simulated lap (640x480 colour PNG, as ``rigcal simulate world`` writes
them; or ``--sequence DIR``, any sequence folder) are read both ways, alternately, in
the same process: the time per frame (best of ``--repeats`` passes) and the ratio, and
whether the grey levels are the same on every frame (they must be: the tracks, and so
every trajectory, depend on them).

    .venv/bin/python benchmarks/bench_decode.py [--sequence DIR] [--frames 200] [--repeats 3]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from rigcal.io.images import read_grey
from rigcal.recordings.sequence import read_sequence
from rigcal.sim.drive import DriveSpec, write_drive
from rigcal.sim.world import BUILTIN


def per_frame_ms(read: Callable[[Path], object], paths: list[Path]) -> float:
    """One pass's time per frame (milliseconds)."""
    t0 = time.perf_counter()
    for p in paths:
        read(p)
    return 1e3 * (time.perf_counter() - t0) / len(paths)


def opencv(path: Path) -> object:
    return cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--sequence", type=Path, help="A sequence folder (default: a simulated corridor lap).")
    ap.add_argument("--frames", type=int, default=200, help="Frames read per pass.")
    ap.add_argument("--repeats", type=int, default=3, help="Passes per reader (the best is kept).")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.sequence
        if folder is None:
            folder = Path(tmp) / "corridor"
            spec = DriveSpec(seed=1, duration_s=args.frames / 10 + 1)
            write_drive(BUILTIN["corridor-loop"](), spec, str(folder))
        seq = read_sequence(folder)
        paths = [folder / "images" / f for f in seq.image_files[: args.frames]]
        same = all(np.array_equal(read_grey(p), opencv(p)) for p in paths)  # (compiles the kernel)
        # The two readers alternate, pass by pass; the best pass of each counts.
        a = b = float("inf")
        for _ in range(args.repeats):
            a = min(a, per_frame_ms(opencv, paths))
            b = min(b, per_frame_ms(read_grey, paths))
        shape = cv2.imread(str(paths[0]), cv2.IMREAD_UNCHANGED).shape
        channels = shape[2] if len(shape) > 2 else 1
        print(f"\n{len(paths)} frames of {folder.name}, {shape[1]}x{shape[0]}, {channels} channels\n")
        print("| reader | ms per frame | ratio |")
        print("|---|---|---|")
        print(f"| cv2.imread(IMREAD_GRAYSCALE) | {a:.2f} | 1.00 |")
        print(f"| rigcal.io.images.read_grey | {b:.2f} | {a / b:.2f} |")
        print(f"\nGrey levels identical on every frame: {same}")


if __name__ == "__main__":
    main()
