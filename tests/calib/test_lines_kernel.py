"""The compiled line extraction against its Python reference: the same segments (same
beams, fits equal to 1e-12) on simulated, noisy, gappy, 360-degree, clockwise and tiny
scans, and on random rooms (hypothesis, the suite's profile in tests/conftest.py)."""

from __future__ import annotations

import dataclasses
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from rigcal.lines import LineParams, Segment, extract_lines, is_full_circle, line_labels, return_labels
from rigcal.scan import Scan, counter_clockwise
from rigcal.sim.drive import DriveSpec, Motion, laser_stamps, simulate_scans
from rigcal.sim.raycast import cast_scan
from rigcal.sim.world import BUILTIN


def assert_same_segments(got: list[Segment], ref: list[Segment]) -> None:
    assert [len(s.indices) for s in got] == [len(s.indices) for s in ref]
    for s, t in zip(got, ref, strict=True):
        assert s.id == t.id
        np.testing.assert_array_equal(s.indices, t.indices)
        np.testing.assert_array_equal(s.points, t.points)
        for name in ("centroid", "direction", "start", "end"):
            np.testing.assert_allclose(getattr(s, name), getattr(t, name), rtol=0, atol=1e-12, err_msg=name)
        # The residual is the scatter's smaller eigenvalue, a difference of sums of order
        # (length^2 x returns): its mean square is exact to ~1e-16 m^2 x length^2, so an RMS
        # near 0 (a noiseless wall) is only determined to ~1e-8 m, in either version.
        assert s.rms_residual_m**2 == pytest.approx(t.rms_residual_m**2, rel=0, abs=1e-14)


def assert_compiled_matches(scan: Scan, params: LineParams | None = None) -> list[Segment]:
    """The compiled extraction and labels equal the reference's; returns the segments."""
    ref = extract_lines(scan, params, kernel=False)
    assert_same_segments(extract_lines(scan, params), ref)
    np.testing.assert_array_equal(line_labels(scan, params), return_labels(scan, ref))
    return ref


def drive_scans(world: str, spec: DriveSpec, every: int, count: int) -> list[Scan]:
    motion = Motion(BUILTIN[world](), spec)
    stamps = laser_stamps(motion, spec)[::every][:count]
    return simulate_scans(BUILTIN[world](), motion.poses(stamps), stamps, spec)


@pytest.mark.parametrize("world", ["corridor-loop", "cubicle-loop"])
def test_compiled_matches_on_simulated_drives(world):
    """Scans of the built-in worlds round a lap (1 cm noise, 1 % dropouts)."""
    scans = drive_scans(world, DriveSpec(laser_rate_hz=10.0, seed=3), every=7, count=60)
    total = sum(len(assert_compiled_matches(s)) for s in scans)
    assert total > 3 * len(scans)  # the scans do have lines


@pytest.mark.parametrize("sigma", [0.0, 0.005, 0.02, 0.05])
def test_compiled_matches_at_other_noise_levels(sigma):
    spec = DriveSpec(laser_rate_hz=10.0, seed=5, range_sigma_m=sigma, dropout_fraction=0.05)
    for scan in drive_scans("cubicle-loop", spec, every=23, count=15):
        assert_compiled_matches(scan, LineParams.for_range_noise(sigma))
        assert_compiled_matches(scan)


def test_compiled_matches_on_a_full_circle_scanner_and_clockwise():
    """A 360-degree scanner (the ring cut at its widest gap; lines over the seam), and the
    same scans as a clockwise scanner gives them."""
    spec = DriveSpec(laser_rate_hz=10.0, seed=7, fov_deg=359.5, angle_increment_deg=0.5)
    scans = drive_scans("corridor-loop", spec, every=17, count=20)
    assert all(is_full_circle(s) for s in scans)
    for scan in scans:
        assert_compiled_matches(scan)
        assert_compiled_matches(counter_clockwise(scan))


def room(rng: np.random.Generator, n_walls: int) -> np.ndarray:
    """Random walls around the origin: (S, 2, 2) segments, metres."""
    centres = rng.uniform(-6.0, 6.0, (n_walls, 2))
    half = rng.uniform(0.05, 4.0, n_walls)[:, None] * np.stack(
        [np.cos(a := rng.uniform(0, np.pi, n_walls)), np.sin(a)], 1
    )
    return np.stack([centres - half, centres + half], axis=1)


def test_compiled_matches_with_gaps_nan_and_inf_ranges():
    rng = np.random.default_rng(11)
    angles = np.radians(np.arange(-135.0, 135.001, 0.25))
    for _ in range(20):
        r = cast_scan(room(rng, 8), angles, 30.0) + rng.normal(0.0, 0.01, len(angles))
        bad = rng.random(len(r))
        r[bad < 0.05] = np.nan
        r[(bad >= 0.05) & (bad < 0.08)] = np.inf
        r[(bad >= 0.08) & (bad < 0.1)] = 0.0
        r[rng.integers(0, len(r)) :][:40] = np.nan  # a block of dropouts
        assert_compiled_matches(Scan(angles, r, 0.05, 30.0))


@pytest.mark.parametrize("n", [0, 1, 2, 3, 4, 5, 6, 9])
def test_compiled_matches_on_tiny_scans(n):
    """Fewer returns than a seed or a segment needs, and just enough."""
    angles = np.radians(np.arange(n) * 0.25) if n else np.zeros(0)
    for r0 in (1.0, 3.0, np.nan):
        scan = Scan(angles, np.full(n, r0) / np.cos(angles - angles.mean()), 0.05, 30.0) if n else None
        if scan is None:
            scan = Scan(np.zeros(0), np.zeros(0), 0.05, 30.0)
        assert_compiled_matches(
            scan, LineParams(seed_points=2, seed_length_m=0.001, min_points=2, min_length_m=0.0)
        )
        assert_compiled_matches(scan)


@given(
    seed=st.integers(0, 2**32 - 1),
    n_walls=st.integers(1, 12),
    sigma=st.sampled_from([0.0, 0.003, 0.01, 0.03]),
    dropout=st.floats(0.0, 0.3),
    fov_deg=st.sampled_from([90.0, 270.0, 359.75]),
    step_deg=st.sampled_from([0.25, 0.5, 1.0]),
    turn_deg=st.floats(1.0, 30.0),
    seed_points=st.integers(2, 8),
    clockwise=st.booleans(),
)
def test_compiled_matches_on_random_rooms(
    seed, n_walls, sigma, dropout, fov_deg, step_deg, turn_deg, seed_points, clockwise
):
    rng = np.random.default_rng(seed)
    step = np.radians(step_deg)
    n = round(fov_deg / step_deg) + 1
    angles = -0.5 * step * (n - 1) + step * np.arange(n)
    r = cast_scan(room(rng, n_walls), angles, 30.0) + rng.normal(0.0, sigma, n)
    r[rng.random(n) < dropout] = np.nan
    scan = Scan.from_uniform(float(angles[0]), float(step), r, 0.05, 30.0)
    params = dataclasses.replace(
        LineParams.for_range_noise(sigma), max_angle_change_deg=turn_deg, seed_points=seed_points
    )
    assert_compiled_matches(counter_clockwise(scan) if clockwise else scan, params)


@pytest.mark.parametrize("n", [360, 721, 1440])
@pytest.mark.parametrize("extra_rad", [-1e-3, -1e-7, -1e-12, 0.0, 1e-12, 1e-7, 1e-3, -1.0])
def test_full_circle_of_a_uniform_scan_is_decided_as_by_the_median_step(n, extra_rad):
    """is_full_circle takes a uniform scan's increment for its median step: the same
    answer as the median of the angles' differences, at the boundary too (the step here
    makes the span plus 1.5 steps 2 pi + extra_rad)."""
    step = (2.0 * np.pi + extra_rad) / (n + 0.5)
    uniform = Scan.from_uniform(-np.pi + 0.1 * step, step, np.ones(n), 0.1, 30.0)
    listed = Scan(uniform.angles_rad, np.ones(n), 0.1, 30.0)  # no increment: the median
    assert listed.angle_increment_rad is None
    assert is_full_circle(uniform) == is_full_circle(listed)
    if abs(extra_rad) > 1e-6:
        assert is_full_circle(uniform) == (extra_rad > 0)


def test_importing_lines_leaves_numba_for_the_first_compiled_call():
    """Calibration and plots import the module without paying for numba."""
    code = (
        "import sys, numpy as np; from rigcal.lines import extract_lines; "
        "from rigcal.scan import Scan; print('numba' in sys.modules); "
        "a = np.linspace(-1, 1, 200); s = Scan(a, 2 / np.cos(a), 0.1, 30.0); "
        "extract_lines(s, kernel=False); print('numba' in sys.modules); "
        "print(len(extract_lines(s))); print('numba' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split() == ["False", "False", "1", "True"]
