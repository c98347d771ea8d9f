"""The compiled carrying of lines between scans, the per-line fits and the whole laser
odometry against their numpy / Python references (``kernel=False``)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from rigcal.lines import line_labels
from rigcal.localize.icp import IcpParams, icp
from rigcal.localize.line_normals import line_fits, line_normals
from rigcal.localize.odometry import carry_labels, icp_odometry
from rigcal.sim.drive import DriveSpec, Motion, laser_stamps, simulate_scans
from rigcal.sim.world import BUILTIN


def drive(world: str, spec: DriveSpec, count: int, every: int = 1):
    motion = Motion(BUILTIN[world](), spec)
    stamps = laser_stamps(motion, spec)[::every][:count]
    return simulate_scans(BUILTIN[world](), motion.poses(stamps), stamps, spec)


def labels_strategy(n: int):
    return st.lists(st.integers(-1, 6), min_size=n, max_size=n).map(lambda v: np.array(v, dtype=np.int64))


@given(seed=st.integers(0, 2**32 - 1), n=st.integers(0, 60), data=st.data())
def test_line_fits_kernel_matches_numpy(seed, n, data):
    """Random points and labels: lines missing from the numbering, one-point lines,
    points on no line, no points at all."""
    rng = np.random.default_rng(seed)
    pts = rng.normal(size=(n, 2)) * rng.uniform(0.01, 10.0)
    labels = data.draw(labels_strategy(n))
    got, ref = line_fits(pts, labels), line_fits(pts, labels, kernel=False)
    for g, r in zip(got, ref, strict=True):
        np.testing.assert_array_equal(np.isnan(g), np.isnan(r))
        np.testing.assert_allclose(g, r, rtol=0, atol=1e-12)


@given(seed=st.integers(0, 2**32 - 1), n_prev=st.integers(1, 50), n_cur=st.integers(0, 50), data=st.data())
def test_carry_labels_kernel_matches_numpy(seed, n_prev, n_cur, data):
    """Random returns, lines and nearest pairs, returns 1-3 cm off their line's offset."""
    rng = np.random.default_rng(seed)
    prev = rng.uniform(-5.0, 5.0, (n_prev, 2))
    labels = data.draw(labels_strategy(n_prev))
    normals = line_normals(prev, labels) if data.draw(st.booleans()) else None
    step = rng.normal(scale=[0.05, 0.05, 0.02])
    cur = prev[rng.integers(0, n_prev, n_cur)] + rng.normal(scale=0.02, size=(n_cur, 2))
    nearest = rng.integers(0, n_prev, n_cur) if data.draw(st.booleans()) else None
    got = carry_labels(prev, labels, normals, step, cur, nearest)
    np.testing.assert_array_equal(got, carry_labels(prev, labels, normals, step, cur, nearest, kernel=False))


def test_carry_labels_kernel_matches_on_odometry_steps():
    """Scans of the cubicle loop, their lines carried over ICP's steps (with ICP's nearest
    returns, and looked up afresh)."""
    scans = drive("cubicle-loop", DriveSpec(laser_rate_hz=40.0, seed=2), 30, every=3)
    carried = 0
    for a, b in itertools.pairwise(scans):
        prev, cur = a.points[a.valid], b.points[b.valid]
        labels = line_labels(a)
        normals = line_normals(prev, labels)
        res = icp(prev, cur, params=IcpParams(), model_normals=normals)
        for nearest in (res.nearest, None):
            got = carry_labels(prev, labels, normals, res.pose, cur, nearest)
            ref = carry_labels(prev, labels, None, res.pose, cur, nearest, kernel=False)
            np.testing.assert_array_equal(got, ref)
            carried += int((got >= 0).sum())
    assert carried > 0.5 * 2 * 29 * 800  # most returns do carry a line


@pytest.mark.parametrize(
    ("world", "spec"),
    [
        ("cubicle-loop", DriveSpec(laser_rate_hz=40.0, seed=1)),
        ("corridor-loop", DriveSpec(laser_rate_hz=10.0, seed=4, fov_deg=359.5, angle_increment_deg=0.5)),
    ],
    ids=["hokuyo-cubicles", "full-circle-corridor"],
)
def test_odometry_with_kernels_matches_the_references(world, spec):
    """The whole odometry (line extraction every LINES_EVERY scans, lines carried between,
    ICP) compiled against all its references."""
    scans = drive(world, spec, 40)
    got, ref = icp_odometry(scans), icp_odometry(scans, kernel=False)
    np.testing.assert_allclose(got.poses, ref.poses, rtol=0, atol=1e-9)
    np.testing.assert_allclose(got.degeneracy, ref.degeneracy, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(got.rms_m, ref.rms_m, rtol=1e-9, atol=1e-12)
    assert (got.skipped, got.restarts) == (ref.skipped, ref.restarts)
