"""The frames of a drive the targetless check uses (:mod:`rigcal.drift.targetless`),
chosen from the images' stamps alone, and how many it decodes ahead of their use: known
before the check's own modules are imported, so that ``rigcal check --sequence`` starts
decoding them while it imports (:class:`rigcal.localize.image_cache.EarlyFrames`)."""

from __future__ import annotations

import numpy as np

from rigcal.arrays import FloatArray

FRAME_RATE_HZ = 5.0
"""The check uses images at most at this rate by default (the rest skipped)."""
FRAMES_AHEAD_BYTES = 256 * 2**20
"""Decoded frames held ahead of the check's use at most (8-bit grey)."""


def used_frames(image_stamps_s: FloatArray, rate_hz: float) -> list[int]:
    """Image indices at most ``rate_hz`` apart in time (each the first at least 0.9 /
    ``rate_hz`` after the one before)."""
    out: list[int] = []
    last = -np.inf
    for i, t in enumerate(image_stamps_s):
        if t - last >= 0.9 / rate_hz:
            out.append(i)
            last = float(t)
    return out


def frames_ahead(width_px: int, height_px: int) -> int:
    """How many frames of this size the check decodes ahead of their use."""
    return max(8, FRAMES_AHEAD_BYTES // (width_px * height_px))
