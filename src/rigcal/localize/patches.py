"""Sub-pixel patches of a grey image: what every patch comparison of the image side reads
(visual odometry's scale search, IASM's and H-IASM's SAD, the exposure gain between two
frames)."""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

Gray = NDArray[np.uint8]


def sample_patches(gray: Gray, centres: NDArray[np.floating], radius: int) -> NDArray[np.float32]:
    """(N, (2r+1)^2) bilinear samples of square patches around sub-pixel centres (pixel
    centres at whole numbers; NaN outside the image); radius 0 samples the centres alone."""
    off = np.arange(-radius, radius + 1, dtype=np.float32)
    dx, dy = np.meshgrid(off, off)
    c = centres.astype(np.float32)
    mx = (c[:, 0:1] + dx.ravel()[None, :]).astype(np.float32)
    my = (c[:, 1:2] + dy.ravel()[None, :]).astype(np.float32)
    return np.asarray(
        cv2.remap(
            gray.astype(np.float32),
            mx,
            my,
            cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=np.nan,
        ),
        dtype=np.float32,
    )
