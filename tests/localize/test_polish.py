"""The joint polish of image steps and its keyframes."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from rigcal.geometry import pose_of, se2
from rigcal.localize.iasm import Frame, IasmParams
from rigcal.localize.line_normals import line_normals
from rigcal.localize.polish import joint_polish, keyframe_reference, match_weights, new_keyframe


def test_joint_polish_takes_the_walls_where_they_constrain_and_the_matches_where_not():
    # A featureless corridor: the walls fix the cross-corridor offset and the heading, not
    # the motion along it. Correspondences 1 cm off (biased) along and across: the polish
    # keeps the walls' answer across and takes the correspondences' along the corridor.
    u = np.linspace(-8, 8, 800)
    walls = np.vstack(
        [np.column_stack([u, np.full_like(u, -1.0)]), np.column_stack([u, np.full_like(u, 1.0)])]
    )
    truth = np.array([0.08, 0.02, 0.0])
    scan2 = walls - truth[:2]  # the same walls seen after the motion
    b = np.array([[2.0, 1.0], [-3.0, -1.0], [5.0, 1.0], [-6.0, -1.0]])
    a = b + truth[:2] + [0.01, 0.01]  # the correspondences' bias
    x = joint_polish(
        np.zeros(3), a, b, walls, scan2, IasmParams(), line_normals(walls, np.repeat([0, 1], 800))
    )
    assert x[0] == pytest.approx(0.09, abs=1e-3)  # along: the correspondences'
    assert x[1] == pytest.approx(0.02, abs=1e-4)  # across: the walls'
    assert x[2] == pytest.approx(0.0, abs=1e-5)


def _room_walls(n: int = 400) -> tuple[np.ndarray, np.ndarray]:
    """Returns on the four walls of a 10 x 4 m room (beam order per wall) and their labels."""
    u = np.linspace(0.0, 1.0, n)[:, None]
    corners = np.array([[-5.0, -2.0], [5.0, -2.0], [5.0, 2.0], [-5.0, 2.0], [-5.0, -2.0]])
    pts = [a + u * (b - a) for a, b in itertools.pairwise(corners)]
    return np.vstack(pts), np.repeat(np.arange(4), n)


def _moved(points: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """Points seen from ``pose`` (x, y, yaw) in their frame."""
    T = np.linalg.inv(se2(pose))
    out: np.ndarray = points @ T[:2, :2].T + T[:2, 2]
    return out


def test_keyframe_reference_aligns_scan_t1_with_an_older_scan():
    # The keyframe's scan, scan t 1.5 m on, scan t+1 a step further: the keyframe's
    # returns, put in scan t's frame, give the step as scan t's own would.
    walls, labels = _room_walls()
    T_key_t = np.array([1.5, 0.2, 0.1])
    step = np.array([0.1, 0.01, 0.02])
    n = len(walls)
    key = Frame(
        np.zeros((1, 1), np.uint8),
        walls,
        np.zeros((n, 3)),
        np.zeros((n, 2)),
        np.zeros(n, bool),
        np.zeros((n, 1), np.float32),
        [],
        labels,
        line_normals(walls, labels),
        np.zeros((n, 2)),
    )
    ref = keyframe_reference(key, se2(T_key_t))
    np.testing.assert_allclose(ref.points, _moved(walls, T_key_t), atol=1e-12)
    np.testing.assert_allclose(
        np.abs(np.einsum("ij,ij->i", ref.normals, line_normals(ref.points, labels))), 1.0
    )
    scan2 = _moved(walls, pose_of(se2(T_key_t) @ se2(step)))
    none = np.zeros((0, 2))
    x = joint_polish(
        step + np.array([0.02, -0.01, 0.01]), none, none, ref.points, scan2, IasmParams(), ref.normals
    )
    np.testing.assert_allclose(x, step, atol=1e-6)


def test_fallback_keeps_the_odometry_where_the_walls_leave_the_motion_open():
    # Along a featureless corridor the walls fix the offset across and the heading, not
    # the motion along: aligned with the keyframe, the fallback takes the walls' answer
    # across and the odometry's along.
    u = np.linspace(-8, 8, 800)
    walls = np.vstack(
        [np.column_stack([u, np.full_like(u, -1.0)]), np.column_stack([u, np.full_like(u, 1.0)])]
    )
    truth = np.array([0.1, 0.02, 0.0])
    odometry = np.array([0.12, 0.035, 0.002])
    none = np.zeros((0, 2))
    normals = line_normals(walls, np.repeat([0, 1], 800))
    x = joint_polish(odometry, none, none, walls, walls - truth[:2], IasmParams(), normals, odometry)
    assert x[0] == pytest.approx(0.12, abs=1e-3)  # along: the odometry's
    assert x[1] == pytest.approx(0.02, abs=1e-4)  # across: the walls'
    assert x[2] == pytest.approx(0.0, abs=1e-4)
    # Nothing in common with the keyframe: the odometry's motion, wherever it starts.
    far = walls + np.array([50.0, 0.0])
    x = joint_polish(np.zeros(3), none, none, walls, far, IasmParams(), normals, odometry)
    np.testing.assert_allclose(x, odometry, atol=1e-9)


def test_a_new_keyframe_past_its_distance_or_turn():
    p = IasmParams(keyframe_m=2.0, keyframe_deg=20.0)
    assert not new_keyframe(se2([1.9, 0.5, np.radians(19.0)]), p)
    assert new_keyframe(se2([1.9, 0.7, 0.0]), p)
    assert new_keyframe(se2([0.0, 0.0, np.radians(-21.0)]), p)
    assert new_keyframe(se2([0.0, 0.0, 0.0]), IasmParams(keyframe_m=0.0))


def test_joint_polish_leaves_out_returns_paired_across_a_corner():
    # Returns of scan t+1 on a surface scan t did not see, 8 cm behind one of its walls
    # near a corner: paired with that wall's line they pull the scan off and round; left
    # out (laser_reject_m) they do not.
    walls, labels = _room_walls()
    step = np.array([0.1, 0.0, 0.0])
    scan2 = _moved(walls, step)
    stray = _moved(np.column_stack([np.full(15, 5.08), np.linspace(-1.9, -1.5, 15)]), step)
    none = np.zeros((0, 2))
    normals = line_normals(walls, labels)
    data = np.vstack([scan2, stray])
    kept = joint_polish(step, none, none, walls, data, IasmParams(laser_reject_m=0.0), normals)
    left_out = joint_polish(step, none, none, walls, data, IasmParams(), normals)
    assert np.abs(kept[0] - step[0]) > 5e-4
    assert np.abs(np.degrees(kept[2] - step[2])) > 5e-3
    np.testing.assert_allclose(left_out, step, atol=1e-9)


def test_a_lopsided_tail_of_correspondences_does_not_shift_the_motion_along_a_corridor():
    """Along a corridor only the correspondences place the motion; 15 % of them 25 mm
    ahead (far returns on walls seen at a slant) would shift it 4 mm with equal weights."""
    rng = np.random.default_rng(5)
    u = np.linspace(-8, 8, 800)
    walls = np.vstack(
        [np.column_stack([u, np.full_like(u, -1.0)]), np.column_stack([u, np.full_like(u, 1.0)])]
    )
    normals = line_normals(walls, np.repeat([0, 1], 800))
    truth = np.array([0.1, 0.0, 0.0])
    b = np.column_stack([rng.uniform(-6, 6, 100), np.where(rng.random(100) < 0.5, -1.0, 1.0)])
    a = b + truth[:2]
    a[:, 0] += rng.normal(0.0, 0.005, 100)
    a[:15, 0] += 0.025
    scan2 = walls - truth[:2]
    along = {}
    for c in (0.0, IasmParams().match_cauchy):
        params = IasmParams(match_cauchy=c)
        along[c] = joint_polish(np.zeros(3), a, b, walls, scan2, params, normals)[0] - truth[0]
    assert along[0.0] > 0.003
    assert abs(along[IasmParams().match_cauchy]) < 0.0015


def test_match_weights():
    e = np.column_stack([np.linspace(0.0, 0.05, 20), np.zeros(20)])
    w = match_weights(e, 2.385)
    assert np.all(np.diff(w) < 0)
    assert w[0] == 1.0
    assert np.array_equal(match_weights(e, 0.0), np.ones(20))
    assert np.array_equal(match_weights(e[:7], 2.385), np.ones(7))
