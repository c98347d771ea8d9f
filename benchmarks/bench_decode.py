"""Reading a sequence's images as grey: OpenCV's ``cv2.imread(..., IMREAD_GRAYSCALE)``
against rigcal's ``read_grey`` (imagecodecs' PNG decoder and libpng's grey weights).

The frames of a simulated lap (640x480 colour PNG, as ``rigcal simulate world`` writes
them; or ``--sequence DIR``, any sequence folder) are read both ways, alternately, in
the same process: the time per frame (best of ``--repeats`` passes) and the ratio, and
whether the grey levels are the same on every frame (they must be: the tracks, and so
every trajectory, depend on them).

    .venv/bin/python benchmarks/bench_decode.py [--sequence DIR] [--frames 200] [--repeats 3]

With ``--parts``, also where a frame's decoding goes, in CPU milliseconds of this thread per
frame (the best of the passes, each step alternating with the others): imagecodecs' three
PNG decoders (libpng, its APNG build, libspng: whether any is faster on the same pixels),
the inflating alone (zlib, as libpng does it, zlib-ng and libdeflate), the rewriting of
:func:`rigcal.io.png.stored_png` (libdeflate's inflating included) and libpng's decoding of
the rewritten file (the rows stored), and the colour conversion (numpy's, the compiled
kernel's).

    .venv/bin/python benchmarks/bench_decode.py --sequence /work/tmp/c60 --frames 150 --parts
"""

from __future__ import annotations

import argparse
import struct
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


def idat(data: bytes) -> bytes:
    """A PNG's compressed image data (its IDAT chunks joined)."""
    pos, out = 8, []
    while pos + 8 <= len(data):
        length, kind = struct.unpack(">I4s", data[pos : pos + 8])
        if kind == b"IDAT":
            out.append(data[pos + 8 : pos + 8 + length])
        pos += 12 + length
    return b"".join(out)


def parts(paths: list[Path], repeats: int) -> None:
    """The --parts table (module docstring)."""
    import imagecodecs

    from rigcal.io.images import rgb_to_grey
    from rigcal.io.png import rgb_to_grey_reference, stored_png

    data = [p.read_bytes() for p in paths]
    streams = [idat(d) for d in data]
    rgb = [np.asarray(imagecodecs.png_decode(d)) for d in data]
    rows = bytearray(len(imagecodecs.zlib_decode(streams[0])))

    def into(stream: object) -> object:
        return imagecodecs.deflate_decode(stream, out=rows)

    rewritten = [bytes(stored[0]) for d in data if (stored := stored_png(d)) is not None]
    reference = rgb[0]
    steps: dict[str, tuple[Callable[[object], object], list[object]]] = {
        "imagecodecs.png_decode (libpng)": (imagecodecs.png_decode, list(data)),
        "imagecodecs.apng_decode": (imagecodecs.apng_decode, list(data)),
        "imagecodecs.spng_decode (libspng)": (imagecodecs.spng_decode, list(data)),
        "inflating alone, zlib": (imagecodecs.zlib_decode, list(streams)),
        "inflating alone, zlib-ng": (imagecodecs.zlibng_decode, list(streams)),
        "inflating alone, libdeflate (into a buffer reused)": (into, list(streams)),
        "rows stored by libdeflate (stored_png)": (stored_png, list(data)),  # type: ignore[dict-item]
        "libpng on the rows stored": (imagecodecs.png_decode, list(rewritten)),
        "colour to grey, numpy": (rgb_to_grey_reference, list(rgb)),  # type: ignore[dict-item]
        "colour to grey, compiled": (rgb_to_grey, list(rgb)),  # type: ignore[dict-item]
    }
    same = all(
        np.array_equal(np.asarray(f(data[0])), reference)
        for f in (imagecodecs.png_decode, imagecodecs.apng_decode, imagecodecs.spng_decode)
    )
    stored_same = all(
        np.array_equal(np.asarray(imagecodecs.png_decode(r)), x) for r, x in zip(rewritten, rgb, strict=False)
    ) and len(rewritten) == len(data)
    best = dict.fromkeys(steps, float("inf"))
    for _ in range(repeats):
        for name, (fn, inputs) in steps.items():
            c = time.thread_time()
            for x in inputs:
                fn(x)
            best[name] = min(best[name], 1e3 * (time.thread_time() - c) / len(inputs))
    print("\n| step | CPU ms per frame |\n|---|---|")
    for name, ms in best.items():
        print(f"| {name} | {ms:.2f} |")
    print(f"\nThe three PNG decoders give the same pixels: {same}")
    print(f"Frames rewritten (rows stored) {len(rewritten)} of {len(data)}, the same pixels: {stored_same}")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--sequence", type=Path, help="A sequence folder (default: a simulated corridor lap).")
    ap.add_argument("--frames", type=int, default=200, help="Frames read per pass.")
    ap.add_argument("--repeats", type=int, default=3, help="Passes per reader (the best is kept).")
    ap.add_argument("--parts", action="store_true", help="Also the decoding's parts (module docstring).")
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
        if args.parts:
            parts(paths, args.repeats)


if __name__ == "__main__":
    main()
