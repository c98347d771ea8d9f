"""The board method's weak-geometry warning: normals that span 3D, but thinly."""

from __future__ import annotations

import numpy as np
import pytest

from rigcal.calib.board.plane import (
    MIN_NORMAL_SPREAD,
    WEAK_NORMAL_SPREAD,
    PlaneObservation,
    weak_normals_warning,
)


def _obs(normals: np.ndarray) -> list[PlaneObservation]:
    return [
        PlaneObservation(i, f"c{i}", n / np.linalg.norm(n), 2.0, np.zeros((3, 2)))
        for i, n in enumerate(normals)
    ]


def _turned(up_down_deg: float) -> np.ndarray:
    """Boards turned left and right by up to 40 deg, tilted forward and back by up to ``up_down_deg``."""
    yaw = np.radians(np.linspace(-40, 40, 6))
    pitch = np.radians(up_down_deg) * np.array([1, -1, 0.5, -0.5, 1, -1])
    return np.column_stack([np.sin(yaw), np.sin(pitch), -np.cos(yaw)])


@pytest.mark.parametrize("up_down_deg", [4.0, 6.0])
def test_boards_turned_one_way_are_weak_and_the_warning_says_how_to_tilt(up_down_deg):
    normals = _turned(up_down_deg)
    s = np.linalg.svd(normals / np.linalg.norm(normals, axis=1, keepdims=True), compute_uv=False)
    assert MIN_NORMAL_SPREAD <= s[2] / s[0] < WEAK_NORMAL_SPREAD
    w = weak_normals_warning(_obs(normals))
    assert w is not None
    assert w.startswith("weak geometry: the board normals' spread is")
    assert "tilted forward and back (about its horizontal axis)" in w
    direction = [float(x) for x in w.split("camera direction (")[1].split(")")[0].split(",")]
    assert abs(direction[1]) > 0.99


def test_well_spread_boards_give_no_warning():
    assert weak_normals_warning(_obs(_turned(30.0))) is None
    # Swapping the axes: boards tilted but never turned want turning.
    n = _turned(5.0)[:, [1, 0, 2]]
    w = weak_normals_warning(_obs(n))
    assert w is not None
    assert "turned left and right (about its vertical axis)" in w
