"""Auto's returns near the predicted cut: the returns that fit one line within the range
noise over the cut's full extent, and a sheet size that only ever adds returns."""

from __future__ import annotations

import numpy as np
import pytest

from rigcal.calib.board.detect import board_shape, pick_near_cut
from rigcal.calib.intrinsics import Board
from rigcal.scan import Scan

SIGMA = 0.015


def _scene(rng: np.random.Generator, off_m: float):
    """A board 2 m ahead (a line x = 2, y in [-0.45, 0.45]) with 15 mm range noise and, at
    each of its ends, 0.2 m of a holder ``off_m`` behind the board's line, touching it."""
    y_board = np.linspace(-0.45, 0.45, 80)
    board = np.column_stack([np.full_like(y_board, 2.0), y_board])
    y_hold = np.concatenate([np.linspace(-0.66, -0.47, 16), np.linspace(0.47, 0.66, 16)])
    holder = np.column_stack([np.full_like(y_hold, 2.0 + off_m), y_hold])
    p = np.concatenate([board, holder])
    a = np.arctan2(p[:, 1], p[:, 0])
    r = np.linalg.norm(p, axis=1) + rng.normal(0.0, SIGMA, len(p))
    order = np.argsort(a)
    is_board = np.arange(len(p)) < len(board)
    scan = Scan(a[order], r[order], 0.1, 30.0)
    return scan, is_board[order]


@pytest.mark.parametrize("off_m", [0.06, 0.08, 0.1])
def test_the_board_is_taken_whole_and_the_holder_off_its_line_is_left_out(off_m):
    rng = np.random.default_rng(int(off_m * 100))
    scan, is_board = _scene(rng, off_m)
    # The rough pose puts the cut 3 deg askew and 3 cm off.
    turn = np.radians(3.0)
    R = np.array([[np.cos(turn), -np.sin(turn)], [np.sin(turn), np.cos(turn)]])
    cut = np.array([[2.0, -0.5], [2.0, 0.5]]) @ R.T + np.array([0.03, 0.0])
    picked = pick_near_cut(scan, np.ones(len(is_board), dtype=bool), cut, 0.15, 10, SIGMA)
    took = np.zeros(len(is_board), dtype=bool)
    took[picked] = True
    assert (took & is_board).sum() >= 0.97 * is_board.sum()
    # The holder's stretches (4-7 sigma off the line) are left out but for the few returns
    # right at the board's ends that share a run with its own.
    assert (took & ~is_board).sum() <= 5
    # The picks are a function of the set of returns, not of the order of the scan's beams.
    assert len(set(picked.tolist())) == len(picked)


def test_a_sheet_size_never_narrows_what_is_allowed():
    board = Board(7, 5, 0.12)
    bare = board_shape(board)
    sized = board_shape(board, (1.06, 0.82))
    assert bare.pattern_outline is None
    assert sized.pattern_outline is not None
    assert np.allclose(sized.pattern_outline, bare.outline)
    assert sized.min_cut_m <= bare.min_cut_m
    assert sized.max_cut_m >= bare.max_cut_m
    # A sheet smaller than the pattern's one-square border still allows the pattern's cuts.
    small = board_shape(board, (0.9, 0.66))
    assert small.min_cut_m <= bare.min_cut_m
    assert small.max_cut_m >= bare.max_cut_m
