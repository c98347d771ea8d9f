"""Weak-geometry warnings of an intrinsics solve: a handful of near-identical views, or
boards turned one way only, must say which direction is weak and what views to add."""

from __future__ import annotations

import numpy as np
import pytest

from rigcal.calib.intrinsics import Board, solve_intrinsics
from rigcal.sim.boards import board_views
from rigcal.sim.box_session import default_camera

BOARD = Board(9, 6, 0.04)


def _solve(n: int, seed: int, **kw):
    det = board_views(default_camera(), BOARD, n, np.random.default_rng(seed), distance_m=(0.5, 0.9), **kw)
    return solve_intrinsics(det, BOARD, "LENSMODEL_OPENCV5", focal_estimate_px=520.0)


@pytest.mark.parametrize("seed", [2, 3])
def test_five_views_turned_one_way_warn_which_direction_and_what_to_add(seed):
    res = _solve(5, seed, max_tilt_deg=(1.0, 20.0))
    text = " | ".join(res.warnings)
    assert "turned one way only" in text
    assert "tilted forward and back (about its horizontal axis)" in text
    assert "weak geometry: the focal length is known to" in text
    assert "only 5 views" in text
    # The warning's sigma is of the size of the focal length's actual error (several %).
    fx = float(res.model.intrinsics()[1][0])
    stated = float(text.split("the focal length is known to ")[1].split(" %")[0])
    assert stated > 0.5
    assert abs(fx / 520.0 - 1.0) * 100 < 4.0 * stated


def test_near_identical_views_warn():
    res = _solve(5, 1, jitter=(2.0, 0.03))
    text = " | ".join(res.warnings)
    assert "weak geometry" in text
    assert "only 5 views" in text


def test_a_good_set_gives_no_weak_geometry_warning():
    res = _solve(20, 0)
    assert not [w for w in res.warnings if "weak geometry" in w or "one way only" in w or "views:" in w]
    assert abs(float(res.model.intrinsics()[1][0]) / 520.0 - 1.0) < 0.005
