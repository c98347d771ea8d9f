"""Estimated paths against ground truth, seen from above (the paper's Fig. 8).

Ground truth in blue, one colour per method, equal scale on both axes, a 1 m / 5 m / 10 m
scale bar and a legend; each path's start is a circle and its end a cross, so a loop's
closure error is visible as the gap between them.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

TRUTH_BGR = (200, 90, 20)
METHOD_BGR = ((40, 40, 220), (40, 160, 40), (0, 140, 255), (160, 40, 160), (120, 120, 0), (60, 60, 60))


def draw_paths(truth: FloatArray, paths: dict[str, FloatArray], size_px: int = 900) -> NDArray[np.uint8]:
    """The picture as an 8-bit BGR image.

    Args:
        truth: (N, 2+) true positions.
        paths: method name -> (M, 2+) estimated positions, same frame as the truth.
    """
    import cv2

    allp = np.vstack([truth[:, :2], *[p[:, :2] for p in paths.values()]])
    lo, hi = allp.min(axis=0), allp.max(axis=0)
    span = float(max(hi[0] - lo[0], hi[1] - lo[1], 1e-3))
    margin, legend_h = 50, 24 * (len(paths) + 1) + 10
    scale = (size_px - 2 * margin) / span
    width = int((hi[0] - lo[0]) * scale) + 2 * margin
    height = int((hi[1] - lo[1]) * scale) + 2 * margin + legend_h
    img = np.full((height, width, 3), 255, dtype=np.uint8)

    def px(p: FloatArray) -> NDArray[np.int32]:
        u = margin + (p[:, 0] - lo[0]) * scale
        v = height - legend_h - margin - (p[:, 1] - lo[1]) * scale
        return np.column_stack([u, v]).round().astype(np.int32)

    items = [("ground truth", truth, TRUTH_BGR)] + [
        (name, p, METHOD_BGR[k % len(METHOD_BGR)]) for k, (name, p) in enumerate(paths.items())
    ]
    for name, p, colour in items:
        q = px(p[:, :2])
        cv2.polylines(
            img, [q.reshape(-1, 1, 2)], False, colour, 2 if name == "ground truth" else 1, cv2.LINE_AA
        )
        cv2.circle(img, (int(q[0, 0]), int(q[0, 1])), 5, colour, 1, cv2.LINE_AA)
        cv2.drawMarker(img, (int(q[-1, 0]), int(q[-1, 1])), colour, cv2.MARKER_CROSS, 10, 1, cv2.LINE_AA)
    # Scale bar: the largest of 1, 5, 10, 20 m under a third of the width.
    bar = max(b for b in (1.0, 5.0, 10.0, 20.0, 50.0) if b * scale < width / 3 or b == 1.0)
    y0 = height - legend_h - 15
    cv2.line(img, (margin, y0), (margin + int(bar * scale), y0), (0, 0, 0), 2)
    cv2.putText(
        img, f"{bar:g} m", (margin, y0 - 6), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA
    )
    for k, (name, _, colour) in enumerate(items):
        y = height - legend_h + 20 + 24 * k
        cv2.line(img, (margin, y - 4), (margin + 30, y - 4), colour, 2)
        cv2.putText(img, name, (margin + 40, y), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    return img
