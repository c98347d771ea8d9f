"""The scans of a small room, for command-line tests on sequence folders."""

from __future__ import annotations

import numpy as np

from rigcal.scan import Scan


def room_scan(x_m: float, t_s: float) -> Scan:
    """A 6 m x 4 m room seen from (x_m, 0), 181 beams over 180 deg."""
    a = np.radians(np.arange(181) - 90.0)
    c, s = np.cos(a), np.sin(a)
    with np.errstate(divide="ignore"):
        to_x = np.where(c > 1e-9, (3.0 - x_m) / c, np.inf)
        to_y = np.where(np.abs(s) > 1e-9, 2.0 / np.abs(s), np.inf)
    return Scan.from_uniform(-np.pi / 2, np.radians(1.0), np.minimum(to_x, to_y), 0.05, 30.0, stamp_s=t_s)
