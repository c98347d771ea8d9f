"""The simulated person holding a board: stretches 50-100 mm off the board's line touching
its ends."""

from __future__ import annotations

import numpy as np

from rigcal.sim.board_session import _holder


def test_holder_stretches_touch_the_ends_off_the_line():
    rng = np.random.default_rng(0)
    cut = np.array([[2.0, -0.4], [2.2, 0.4]])
    u = (cut[1] - cut[0]) / np.linalg.norm(cut[1] - cut[0])
    n = np.array([-u[1], u[0]])
    for _ in range(20):
        segs = _holder(rng, cut)
        assert segs.shape == (2, 2, 2)
        for seg, end in zip(segs, cut, strict=True):
            off = (seg - end) @ n
            assert np.allclose(off[0], off[1])
            assert 0.05 <= abs(off[0]) <= 0.1
            # Its near end touches the board's end; it runs 0.1-0.3 m on, outwards.
            assert np.linalg.norm(seg[0] - end - off[0] * n) <= 0.011
            assert 0.09 <= np.linalg.norm(seg[1] - seg[0]) <= 0.3
