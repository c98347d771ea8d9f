"""Printable sheets of a marker target's faces, at true scale.

Each face becomes one page: the face itself (white, its ChArUco pattern at its offset, a
thin cut line round it) and, below the cut line, a strip with the target's and face's
names, the face's marker ids, and a 100 mm measuring bar with centimetre ticks to check
the printer's scale before gluing (a print at the wrong scale shows later as a scale
disagreement between laser and camera). Pages are written as PNG (with its DPI recorded)
and PDF (page size the sheet's true size), with the targets file beside them.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from rigcal.io.files import atomic_folder
from rigcal.targets.marker import MarkerTarget, face_image, targets_text

DEFAULT_DPI = 300
BAR_M = 0.1
STRIP_M = 0.035
INCH_M = 0.0254


def sheet_image(target: MarkerTarget, k: int, dpi: float = DEFAULT_DPI) -> NDArray[np.uint8]:
    """(H, W) uint8 the printed page of face k at ``dpi``: the face, then the strip."""
    import cv2

    ppm = dpi / INCH_M
    face = face_image(target, k, ppm)
    f = target.faces[k]
    H, W = face.shape
    strip = round(STRIP_M * ppm)
    page = np.full((H + strip, max(W, round((BAR_M + 0.02) * ppm))), 255, dtype=np.uint8)
    page[:H, :W] = face
    line = max(1, round(0.0002 * ppm))
    cv2.rectangle(page, (0, 0), (W - 1, H - 1), 128, line)
    # The measuring bar: 100 mm, with a tick every centimetre.
    x0, y0 = round(0.01 * ppm), H + round(0.008 * ppm)
    bar_h = round(0.004 * ppm)
    x1 = x0 + round(BAR_M * ppm)
    cv2.rectangle(page, (x0, y0), (x1 - 1, y0 + bar_h - 1), 0, -1)
    for cm in range(11):
        x = x0 + round(cm * 0.01 * ppm)
        cv2.line(page, (min(x, x1 - 1), y0 + bar_h), (min(x, x1 - 1), y0 + 2 * bar_h), 0, line)
    scale = 0.0035 * ppm / 22.0
    ids = (
        f"ids {f.ids[0]}-{f.ids[-1]}"
        if list(f.ids) == list(range(f.ids[0], f.ids[-1] + 1))
        else f"ids {list(f.ids)}"
    )
    text = [
        f"{target.name}: face {f.name} ({k + 1}/2), {target.dictionary}, {ids}",
        f"squares {f.squares[0]}x{f.squares[1]} of {1000 * f.square_m:g} mm, "
        f"markers {1000 * f.marker_m:g} mm; bar = {1000 * BAR_M:g} mm: measure it",
    ]
    for j, t in enumerate(text):
        y = y0 + 2 * bar_h + round((0.006 + 0.005 * j) * ppm)
        cv2.putText(
            page, t, (x0, y), cv2.FONT_HERSHEY_SIMPLEX, scale, 0, max(1, round(scale * 1.5)), cv2.LINE_AA
        )
    return page


def sheet_bytes(page: NDArray[np.uint8], dpi: float, fmt: str) -> bytes:
    """A page as PNG (its DPI recorded) or PDF (page size = the sheet's true size)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(page.shape[1] / dpi, page.shape[0] / dpi), dpi=dpi)
    fig.figimage(page, cmap="gray", vmin=0, vmax=255, resize=False)
    buf = io.BytesIO()
    fig.savefig(buf, format=fmt, dpi=dpi)
    return buf.getvalue()


def write_print(
    target: MarkerTarget, folder: str | Path, dpi: float = DEFAULT_DPI, force: bool = False
) -> list[Path]:
    """Write ``face-NAME.png`` and ``face-NAME.pdf`` per face and ``targets.yaml`` into
    ``folder``, atomically (refuses an existing folder unless ``force``). Returns the files."""
    names = []
    with atomic_folder(folder, force) as tmp:
        for k, f in enumerate(target.faces):
            page = sheet_image(target, k, dpi)
            for fmt in ("png", "pdf"):
                name = f"face-{f.name}.{fmt}"
                (tmp / name).write_bytes(sheet_bytes(page, dpi, fmt))
                names.append(name)
        (tmp / "targets.yaml").write_text(targets_text(target), encoding="utf-8")
        names.append("targets.yaml")
    return [Path(folder) / n for n in names]
