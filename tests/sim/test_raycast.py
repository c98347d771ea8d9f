"""2D ray casting of laser beams against segments."""

from __future__ import annotations

import numpy as np
import pytest

from rigcal.sim.raycast import cast_scan, cast_scan_hits


def wall_x(x: float, half: float = 5.0) -> list[list[float]]:
    return [[x, -half], [x, half]]


def test_beam_at_zero_hits_wall_at_its_distance():
    r = cast_scan([wall_x(2.0)], [0.0], 30.0)
    assert r[0] == pytest.approx(2.0, abs=1e-12)


def test_oblique_beams_and_misses():
    angles = np.radians([45.0, -60.0, 90.0, 180.0])
    r = cast_scan([wall_x(2.0)], angles, 30.0)
    np.testing.assert_allclose(r[:2], [2.0 * np.sqrt(2.0), 2.0 / np.cos(np.radians(60.0))], atol=1e-12)
    # Parallel to the wall and pointing away from it: no return.
    assert np.isinf(r[2:]).all()


def test_occlusion_keeps_the_nearest_hit_whatever_the_order():
    segs = [wall_x(3.0), wall_x(2.0, half=0.5), wall_x(5.0)]
    angles = np.radians([0.0, 10.0, 30.0])
    r, hit = cast_scan_hits(segs, angles, 30.0)
    # Beam 30 deg passes beside the short near wall (y = 2 tan 30 = 1.15 > 0.5).
    np.testing.assert_allclose(r, [2.0, 2.0 / np.cos(np.radians(10.0)), 3.0 / np.cos(np.radians(30.0))])
    np.testing.assert_array_equal(hit, [1, 1, 0])
    r2 = cast_scan(segs[::-1], angles, 30.0)
    np.testing.assert_array_equal(r, r2)


def test_range_max_and_segment_ends():
    assert np.isinf(cast_scan([wall_x(31.0)], [0.0], 30.0)[0])
    # The segment spans y in [-1, 1] at x = 2: atan(1/2) = 26.57 deg is its edge.
    r, hit = cast_scan_hits([wall_x(2.0, half=1.0)], np.radians([26.0, 27.0]), 30.0)
    assert np.isfinite(r[0])
    assert np.isinf(r[1])
    np.testing.assert_array_equal(hit, [0, -1])
    assert cast_scan(np.zeros((0, 2, 2)), [0.0, 1.0], 30.0).shape == (2,)


def test_matches_a_per_beam_solve_on_random_segments():
    rng = np.random.default_rng(3)
    segs = rng.uniform(-4, 4, size=(12, 2, 2))
    angles = np.linspace(-np.pi, np.pi, 721)
    r = cast_scan(segs, angles, 30.0)
    expected = np.full(len(angles), np.inf)
    for i, a in enumerate(angles):
        d = np.array([np.cos(a), np.sin(a)])
        for p, q in segs:
            A = np.column_stack([d, p - q])  # t d = p + s (q - p)
            if abs(np.linalg.det(A)) < 1e-12:
                continue
            t, s = np.linalg.solve(A, p)
            if t > 0 and 0 <= s <= 1:
                expected[i] = min(expected[i], t)
    np.testing.assert_allclose(r, expected, rtol=1e-9)
    assert np.isfinite(r).sum() > 100
