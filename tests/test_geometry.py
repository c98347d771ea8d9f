"""Rigid-transform helpers: Rodrigues' formula against scipy, and round trips of every
helper (inverse, point transforms, rt vectors, tangent deltas, angles up to pi)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from rigcal.geometry import (
    R_to_rotvec,
    inv_T,
    line_intersection,
    make_T,
    pose_error,
    pose_of,
    random_rotation,
    rotation_angle_rad,
    rotvec_to_R,
    rt_from_T,
    se2,
    tangent_delta,
    transform_points,
)

finite = st.floats(-10.0, 10.0, allow_nan=False, allow_infinity=False)
vec3 = st.tuples(finite, finite, finite).map(np.array)
# Rotation vectors of any angle in [0, pi): the axis from three floats, the angle apart.
angle = st.floats(0.0, math.pi - 1e-6)


@st.composite
def rotations(draw):
    axis = draw(vec3)
    n = np.linalg.norm(axis)
    if n < 1e-3:
        axis, n = np.array([0.0, 0.0, 1.0]), 1.0
    return axis / n * draw(angle)


@st.composite
def transforms(draw):
    return make_T(rotvec_to_R(draw(rotations())), draw(vec3))


@pytest.mark.parametrize("size", [0.0, 1e-9, 1e-6, 1e-3, 0.3, 1.0, 3.0])
def test_rotvec_to_R_matches_scipy_from_tiny_to_large_angles(size):
    rng = np.random.default_rng(1)
    for _ in range(50):
        w = rng.normal(0.0, 1.0, 3)
        w *= size / max(np.linalg.norm(w), 1e-300)
        R = rotvec_to_R(w)
        assert np.abs(R - Rotation.from_rotvec(w).as_matrix()).max() < 1e-14
        assert np.abs(R @ R.T - np.eye(3)).max() < 1e-14
        if 1e-6 <= size < np.pi:
            assert np.allclose(R_to_rotvec(R), w, atol=1e-12)


def test_rotvec_to_R_takes_a_batch():
    w = np.array([[0.0, 0.0, 0.5], [0.1, -0.2, 0.3]])
    R = rotvec_to_R(w)
    assert R.shape == (2, 3, 3)
    assert np.allclose(R[1], rotvec_to_R(w[1]))


@settings(max_examples=200, deadline=None)
@given(transforms())
def test_inverse_is_a_two_sided_inverse(T):
    assert np.abs(T @ inv_T(T) - np.eye(4)).max() < 1e-12
    assert np.abs(inv_T(T) @ T - np.eye(4)).max() < 1e-12
    assert np.abs(inv_T(inv_T(T)) - T).max() < 1e-12


@settings(max_examples=200, deadline=None)
@given(transforms(), transforms(), st.lists(vec3, min_size=1, max_size=5))
def test_points_round_trip_and_compose(T_a_b, T_b_c, pts):
    p_c = np.array(pts)
    p_b = transform_points(T_b_c, p_c)
    # Composition: T_a_c = T_a_b T_b_c maps the same points as the two in turn.
    assert np.abs(transform_points(T_a_b @ T_b_c, p_c) - transform_points(T_a_b, p_b)).max() < 1e-9
    # And back again with the inverse.
    assert np.abs(transform_points(inv_T(T_b_c), p_b) - p_c).max() < 1e-9
    # Rigid: distances are kept.
    if len(p_c) > 1:
        assert np.linalg.norm(p_b[0] - p_b[1]) == pytest.approx(np.linalg.norm(p_c[0] - p_c[1]), abs=1e-9)


def test_planar_points_are_taken_at_z_zero():
    T = make_T(rotvec_to_R([0.1, -0.2, 0.3]), [1.0, 2.0, 3.0])
    xy = np.array([[1.0, 2.0], [-3.0, 0.5]])
    xyz = np.column_stack([xy, np.zeros(2)])
    assert np.array_equal(transform_points(T, xy), transform_points(T, xyz))


@settings(max_examples=200, deadline=None)
@given(transforms())
def test_rt_round_trip(T):
    rt = rt_from_T(T)
    T2 = make_T(rotvec_to_R(rt[:3]), rt[3:])
    assert np.abs(T2 - T).max() < 1e-9
    assert np.linalg.norm(rt[:3]) <= math.pi + 1e-12


@settings(max_examples=200, deadline=None)
@given(transforms(), rotations(), vec3)
def test_tangent_delta_inverts_its_own_perturbation(T_ref, d, e):
    # R = Exp(d) R_ref, t = t_ref + e (docs/conventions.md), for angles below pi.
    T = make_T(rotvec_to_R(d) @ T_ref[:3, :3], T_ref[:3, 3] + e)
    x = tangent_delta(T, T_ref)
    assert np.abs(x[:3] - d).max() < 1e-7
    assert np.abs(x[3:] - e).max() < 1e-9
    assert np.abs(tangent_delta(T_ref, T_ref)).max() < 1e-12


@settings(max_examples=200, deadline=None)
@given(rotations())
def test_rotation_angle_is_the_rotvec_norm_up_to_pi(w):
    assert rotation_angle_rad(rotvec_to_R(w)) == pytest.approx(np.linalg.norm(w), abs=1e-9)


@pytest.mark.parametrize(
    "theta", [0.0, 1e-10, 1e-8, 1e-4, math.pi / 2, math.pi - 1e-4, math.pi - 1e-8, math.pi]
)
def test_rotation_angle_is_accurate_near_zero_and_pi(theta):
    axis = np.array([0.3, -0.4, 0.5]) / np.linalg.norm([0.3, -0.4, 0.5])
    R = Rotation.from_rotvec(axis * theta).as_matrix()
    assert rotation_angle_rad(R) == pytest.approx(theta, abs=1e-12 if theta < 1 else 1e-7)


@settings(max_examples=100, deadline=None)
@given(transforms(), transforms())
def test_pose_error_is_symmetric_and_zero_on_itself(A, B):
    assert pose_error(A, A) == pytest.approx((0.0, 0.0), abs=1e-6)
    r_ab, t_ab = pose_error(A, B)
    r_ba, t_ba = pose_error(B, A)
    assert r_ab == pytest.approx(r_ba, abs=1e-6)
    assert t_ab == pytest.approx(t_ba, abs=1e-12)
    assert 0.0 <= r_ab <= 180.0 + 1e-9


def test_random_rotation_is_a_rotation_within_its_bound():
    rng = np.random.default_rng(3)
    for bound in (None, 0.01, 1.0):
        for _ in range(50):
            R = random_rotation(rng, bound)
            assert np.abs(R @ R.T - np.eye(3)).max() < 1e-12
            assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-12)
            if bound is not None:
                assert rotation_angle_rad(R) <= bound + 1e-12


@settings(max_examples=100, deadline=None)
@given(finite, finite, st.floats(-math.pi + 1e-9, math.pi))
def test_se2_and_pose_of_round_trip(x, y, yaw):
    T = se2(np.array([x, y, yaw]))
    c, s = math.cos(yaw), math.sin(yaw)
    assert np.allclose(T[:2, :2], [[c, -s], [s, c]], atol=1e-15)
    assert np.allclose(T[:2, 2], [x, y])
    p = pose_of(T)
    assert np.allclose(p[:2], [x, y])
    assert abs(math.remainder(p[2] - yaw, 2 * math.pi)) < 1e-12


def test_line_intersection_meets_both_lines_and_refuses_parallel_ones():
    rng = np.random.default_rng(7)
    for _ in range(50):
        p, q = rng.normal(size=2), rng.normal(size=2)
        a, b = rng.uniform(0, np.pi, 2)
        u, v = np.array([np.cos(a), np.sin(a)]), np.array([np.cos(b), np.sin(b)])
        x = line_intersection(p, u, q, v)
        if abs(np.sin(a - b)) < 1e-6:
            assert x is None
            continue
        assert x is not None
        for c, d in ((p, u), (q, v)):  # on each line: no part across it
            assert abs((x - c)[0] * d[1] - (x - c)[1] * d[0]) < 1e-9 * max(1.0, float(np.abs(x).max()))
    u = np.array([1.0, 0.0])
    assert line_intersection(np.zeros(2), u, np.ones(2), u) is None
    assert line_intersection(np.zeros(2), u, np.ones(2), np.array([1.0, 1e-7]), parallel_below=1e-6) is None
