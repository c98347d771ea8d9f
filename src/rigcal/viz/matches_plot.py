"""Matched scan returns between two images (the paper's Fig. 5).

Both images in grey, the first above the second (the scan crosses both as a band at
about the same height, so the correspondences run down the picture and stay apart);
every projected return of each scan is a small dot, and every correspondence a line from
its return in the first image to its match in the second: green when the step's final
motion agrees with it (an inlier), red otherwise.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

INLIER_BGR = (40, 170, 40)
OUTLIER_BGR = (40, 40, 230)
RETURN_BGR = (200, 120, 0)


def draw_matches(
    gray1: NDArray[np.uint8],
    gray2: NDArray[np.uint8],
    returns1: FloatArray,
    returns2: FloatArray,
    match1: FloatArray,
    match2: FloatArray,
    inlier: NDArray[np.bool_],
    title: str = "",
) -> NDArray[np.uint8]:
    """The picture as an 8-bit BGR image.

    Args:
        returns1, returns2: (N, 2) pixels of each scan's visible returns.
        match1, match2: (M, 2) pixels of the matched returns in image 1 and image 2.
        inlier: (M,) which matches agree with the final motion.
    """
    import cv2

    gap = 6
    dy = gray1.shape[0] + gap
    img = np.concatenate(
        [
            cv2.cvtColor(gray1, cv2.COLOR_GRAY2BGR),
            np.zeros((gap, gray1.shape[1], 3), np.uint8),
            cv2.cvtColor(gray2, cv2.COLOR_GRAY2BGR),
        ],
        axis=0,
    )
    for (u1, v1), (u2, v2), ok in zip(match1, match2, inlier, strict=True):
        colour = INLIER_BGR if ok else OUTLIER_BGR
        cv2.line(img, (round(u1), round(v1)), (round(u2), round(v2) + dy), colour, 1, cv2.LINE_AA)
    for pts, off in ((returns1, 0), (returns2, dy)):
        for u, v in pts:
            cv2.circle(img, (round(u), round(v) + off), 1, RETURN_BGR, -1)
    if title:
        (tw, th), _ = cv2.getTextSize(title, cv2.FONT_HERSHEY_SIMPLEX, 0.6, 1)
        cv2.rectangle(img, (4, 4), (16 + tw, 14 + th), (0, 0, 0), -1)
        cv2.putText(img, title, (10, 9 + th), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 1, cv2.LINE_AA)
    return img
