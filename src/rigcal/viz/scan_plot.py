"""A top-down picture of a scan with its numbered line segments (to help picking).

The laser sits at the centre-left of the picture looking right (+x right, +y up). Every
valid return is a grey dot; each segment is drawn in its own colour with its id at its
middle, the id that picking files use (``laser_side: {segment: ID}``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from rigcal.calib.lines import Segment
from rigcal.io.files import atomic_write_bytes
from rigcal.scan import Scan

# Distinct BGR colours for neighbouring segments.
_PALETTE = [
    (180, 119, 31),
    (14, 127, 255),
    (44, 160, 44),
    (40, 39, 214),
    (189, 103, 148),
    (75, 86, 140),
    (194, 119, 227),
    (34, 189, 188),
    (207, 190, 23),
]


def draw_scan_segments(scan: Scan, segments: list[Segment], size_px: int = 900) -> NDArray[np.uint8]:
    """The picture as an 8-bit BGR image of ``size_px`` x ``size_px``."""
    import cv2

    img = np.full((size_px, size_px, 3), 255, dtype=np.uint8)
    pts = scan.points[scan.valid]
    extent = float(np.abs(pts).max()) if len(pts) else 1.0
    extent = max(extent, 0.5) * 1.05
    margin = 30
    scale = (size_px - 2 * margin) / (2.0 * extent)

    def px(p: NDArray[np.float64]) -> tuple[int, int]:
        return round(size_px / 2 + scale * float(p[0])), round(size_px / 2 - scale * float(p[1]))

    # Grid every metre, and the scanner's axes.
    for m in range(-int(extent), int(extent) + 1):
        u, v = px(np.array([m, m], dtype=float))
        cv2.line(img, (u, 0), (u, size_px - 1), (235, 235, 235), 1)
        cv2.line(img, (0, v), (size_px - 1, v), (235, 235, 235), 1)
    o = px(np.zeros(2))
    cv2.arrowedLine(img, o, px(np.array([0.5, 0.0])), (0, 0, 200), 2, tipLength=0.2)
    cv2.arrowedLine(img, o, px(np.array([0.0, 0.5])), (0, 160, 0), 2, tipLength=0.2)
    for p in pts:
        cv2.circle(img, px(p), 1, (150, 150, 150), -1)
    for g in segments:
        colour = _PALETTE[g.id % len(_PALETTE)]
        for p in g.points:
            cv2.circle(img, px(p), 2, colour, -1)
        cv2.line(img, px(g.start), px(g.end), colour, 2, cv2.LINE_AA)
        mid = 0.5 * (g.start + g.end)
        label_at = mid + 0.12 * extent / 5.0 * g.normal * -1.0
        cv2.putText(img, str(g.id), px(label_at), cv2.FONT_HERSHEY_SIMPLEX, 0.55, colour, 2, cv2.LINE_AA)
    cv2.putText(
        img,
        "1 m grid; laser +x right, +y up",
        (10, size_px - 10),
        cv2.FONT_HERSHEY_SIMPLEX,
        0.5,
        (90, 90, 90),
        1,
        cv2.LINE_AA,
    )
    return img


def render_scan_segments(scan: Scan, segments: list[Segment], path: str | Path, force: bool = False) -> Path:
    """Draw the picture and write it as a PNG, atomically."""
    import cv2

    ok, buf = cv2.imencode(".png", draw_scan_segments(scan, segments))
    if not ok:  # pragma: no cover - cv2 encodes any 8-bit image
        raise RuntimeError("PNG encoding failed")
    return atomic_write_bytes(path, buf.tobytes(), force=force)
