"""Sizes of a simulated sequence's images by ``--image-format``, and what rigcal reads.

Writes the same corridor drive (seed 0) once per format and prints, per format, the
images' total size and size per frame, the size a 40 s drive (400 frames at 10 Hz) would
take, the estimate ``simulate world`` printed before writing, and the grey levels rigcal
reads (``read_grey``) against those of the lossless colour PNG: max and RMS difference.

    .venv/bin/python benchmarks/bench_image_formats.py [DURATION-S]
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from rigcal.io.images import read_grey
from rigcal.recordings.sequence import read_sequence

FORMATS = ("png", "png-grey", "jpg")


def main(duration_s: float = 3.0) -> str:
    rows = [
        "| format | frames | kB per frame | 40 s drive (MB) | estimate said | grey levels vs png: max, RMS |",
        "|---|---|---|---|---|---|",
    ]
    with tempfile.TemporaryDirectory() as tmp:
        grey: dict[str, list[np.ndarray]] = {}
        for fmt in FORMATS:
            out = Path(tmp) / fmt
            args = [
                "simulate",
                "world",
                "-o",
                str(out),
                "--duration-s",
                str(duration_s),
                "--image-format",
                fmt,
            ]
            done = subprocess.run(
                [sys.executable, "-c", "from rigcal.cli.main import entry; entry()", *args],
                check=True,
                capture_output=True,
                text=True,
            )
            said = next(x for x in done.stderr.splitlines() if x.startswith("writing ")).split(": ")[1]
            seq = read_sequence(out)
            files = [out / "images" / f for f in seq.image_files]
            grey[fmt] = [read_grey(f) for f in files]  # type: ignore[misc]
            each = sum(f.stat().st_size for f in files) / len(files)
            diff = np.concatenate(
                [(a.astype(float) - b).ravel() for a, b in zip(grey["png"], grey[fmt], strict=True)]
            )
            estimate = said.split(";")[0]
            rows.append(
                f"| {fmt} | {len(files)} | {each / 1e3:.0f} | {400 * each / 1e6:.0f} | {estimate} | "
                f"{np.abs(diff).max():.0f}, {np.sqrt(np.mean(diff**2)):.2f} |"
            )
    return "\n".join(rows)


if __name__ == "__main__":
    print(main(float(sys.argv[1]) if len(sys.argv) > 1 else 3.0))
