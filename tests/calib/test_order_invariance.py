"""The board method's answer depends on the returns, never on the order they are given in:
permuted returns, a returns_file's lines shuffled, a 360-degree scan written from another
start angle (-pi..pi or 0..2pi)."""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rigcal.calib.board.calibrate import calibrate_board
from rigcal.calib.board.plane import capture_line, solve_plane
from rigcal.calib.board.session import read_board_session
from rigcal.calib.noise import fit_line_robust
from rigcal.scan import Scan, read_scan, write_scan
from rigcal.sim.board_session import BoardSpec, generate_board_session, write_board_session
from rigcal.sim.noise import RealisticNoise

TOL = 1e-9


@pytest.fixture(scope="module")
def observations(tmp_path_factory):
    """A realistic-noise board session's captures (mixed pixels, heavy tails, strays)."""
    sim = generate_board_session(BoardSpec(n_captures=8, seed=11, noise=RealisticNoise()))
    folder = write_board_session(sim, tmp_path_factory.mktemp("order") / "s")
    return read_board_session(folder / "board_session.yaml").observations


def test_line_fit_is_a_function_of_the_set_of_returns(observations):
    p = observations[0].points_laser
    a = fit_line_robust(p)
    perm = np.random.default_rng(0).permutation(len(p))
    b = fit_line_robust(p[perm])
    assert np.array_equal(a.direction, b.direction)
    assert np.array_equal(a.ends, b.ends)
    # Per-return arrays follow the order given.
    assert np.array_equal(a.residuals_m[perm], b.residuals_m)
    assert np.array_equal(a.kept[perm], b.kept)
    # The ends are the extreme kept returns, not the first and last listed.
    s = (p[a.kept] - a.centroid) @ a.direction
    assert np.allclose(a.ends, a.centroid + np.array([s.min(), s.max()])[:, None] * a.direction)
    reversed_line = capture_line(p[::-1])
    assert np.array_equal(reversed_line.ends, capture_line(p).ends)


@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**32 - 1), rotate=st.booleans())
def test_solve_is_invariant_to_the_order_of_each_captures_returns(observations, seed, rotate):
    """Any permutation of every capture's returns (or a rotation of their list, as a scan
    started elsewhere gives) leaves the pose, covariance, verdicts and noise unchanged."""
    rng = np.random.default_rng(seed)

    def reorder(p: np.ndarray) -> np.ndarray:
        if rotate:
            return np.roll(p, int(rng.integers(len(p))), axis=0)
        return p[rng.permutation(len(p))]

    base = solve_plane(observations, uncertainty_checks=False, fit_range_bias=True)
    shuffled = [replace(o, points_laser=reorder(o.points_laser)) for o in observations]
    res = solve_plane(shuffled, uncertainty_checks=False, fit_range_bias=True)
    assert np.abs(res.T_cam_laser - base.T_cam_laser).max() < TOL
    assert np.abs(res.covariance - base.covariance).max() < TOL * np.abs(base.covariance).max()
    assert np.array_equal(res.inlier_captures, base.inlier_captures)
    assert np.allclose(res.chi2, base.chi2, rtol=TOL, atol=TOL)
    assert res.noise.range_sigma_m == pytest.approx(base.noise.range_sigma_m, rel=TOL)
    assert res.noise.range_bias_m == pytest.approx(base.noise.range_bias_m, rel=TOL, abs=TOL)


@settings(max_examples=4, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**32 - 1), rotate=st.booleans(), shuffle_returns=st.booleans())
def test_solve_is_invariant_to_the_order_of_the_captures(observations, seed, rotate, shuffle_returns):
    """Any order of the session's captures (a permutation, or the list rotated), with or
    without every capture's returns shuffled too, gives the same answer to the last bit and
    the same per-capture figures, listed in the order given."""
    rng = np.random.default_rng(seed)
    C = len(observations)
    order = np.roll(np.arange(C), int(rng.integers(C))) if rotate else rng.permutation(C)
    base = solve_plane(observations, fit_range_bias=True)
    given = [observations[i] for i in order]
    if shuffle_returns:
        given = [replace(o, points_laser=o.points_laser[rng.permutation(len(o.points_laser))]) for o in given]
    res = solve_plane(given, fit_range_bias=True)
    assert np.array_equal(res.T_cam_laser, base.T_cam_laser)
    assert np.array_equal(res.covariance, base.covariance)
    assert np.array_equal(res.inlier_captures, base.inlier_captures[order])
    assert np.array_equal(res.chi2, base.chi2[order])
    assert np.array_equal(res.weights, base.weights[order])
    # The same groups, numbered by first appearance in the order given.
    same = res.pose_group[:, None] == res.pose_group[None, :]
    assert np.array_equal(same, (base.pose_group[:, None] == base.pose_group[None, :])[np.ix_(order, order)])
    assert res.pose_group[0] == 0
    assert res.spread is not None
    assert base.spread is not None
    names = [o.name for o in given]
    assert list(res.spread.captures) == [n for n in names if n in set(base.spread.captures)]
    shifts = dict(zip(base.spread.captures, base.spread.shifts, strict=True))
    assert all(
        np.array_equal(shifts[n], v) for n, v in zip(res.spread.captures, res.spread.shifts, strict=True)
    )


def _rotated(scan: Scan, k: int) -> Scan:
    """The same 360-degree sweep written from beam k on: its angles run past pi (the
    0..2pi form of a scanner that starts at 0)."""
    step = float(np.median(np.diff(scan.angles_rad)))
    assert abs(len(scan.ranges_m) * step - 2.0 * np.pi) < 1e-9
    return Scan.from_uniform(
        float(scan.angles_rad[k]), step, np.roll(scan.ranges_m, -k), scan.range_min_m, scan.range_max_m
    )


def test_auto_returns_and_answer_do_not_depend_on_where_a_full_sweep_starts(tmp_path: Path):
    """A 360-degree scanner's sweeps written -pi..pi and from 0 on (the board, ahead of the
    scanner, then straddles the seam between the last and first beams): the same returns
    are found on every board and the same calibration comes out."""
    sim = generate_board_session(
        BoardSpec(n_captures=8, seed=4, fov_deg=359.5, angle_increment_deg=0.5, noise=RealisticNoise())
    )
    answers = []
    for start in ("minus_pi", "zero"):
        folder = write_board_session(sim, tmp_path / start)
        f = folder / "board_session.yaml"
        f.write_text(re.sub(r"laser_side: \{segments?: [^}]*\}", "laser_side: auto", f.read_text()))
        if start == "zero":
            for scan_file in sorted((folder / "scans").glob("*.yaml")):
                scan = read_scan(scan_file)
                k = int(np.searchsorted(scan.angles_rad, 0.0))
                write_scan(scan_file, _rotated(scan, k), force=True)
                assert read_scan(scan_file).angles_rad[-1] > np.pi
        answers.append(calibrate_board(f))
    a, b = answers
    for oa, ob in zip(a.session.observations, b.session.observations, strict=True):
        pa = oa.points_laser[np.lexsort(oa.points_laser.T[::-1])]
        pb = ob.points_laser[np.lexsort(ob.points_laser.T[::-1])]
        assert pa.shape == pb.shape
        assert np.abs(pa - pb).max() < 1e-12
    # The two forms' returns differ by rounding (an angle a against a + 2 pi, ~1e-15 m);
    # the fits are polished to their minimum, so the pose follows that smoothly.
    assert np.abs(a.result.T_cam_laser - b.result.T_cam_laser).max() < TOL
    cov = np.abs(a.result.covariance).max()
    assert np.abs(a.result.covariance - b.result.covariance).max() < TOL * cov


def test_a_shuffled_returns_file_gives_the_same_answer(tmp_path: Path):
    """Each capture's board returns listed in a returns_file (as MATLAB toolboxes save
    them), once in scan order and once with the lines shuffled."""
    sim = generate_board_session(BoardSpec(n_captures=6, seed=3))
    answers = []
    rng = np.random.default_rng(5)
    for form in ("ordered", "shuffled"):
        folder = write_board_session(sim, tmp_path / form)
        f = folder / "board_session.yaml"
        session = read_board_session(f)
        doc = yaml.safe_load(f.read_text())
        doc["schema_version"] = 2
        for i, (c, o) in enumerate(zip(doc["captures"], session.observations, strict=True)):
            p = o.points_laser if form == "ordered" else o.points_laser[rng.permutation(len(o.points_laser))]
            name = f"returns{i:02d}.txt"
            (folder / name).write_text("".join(f"{float(x)!r} {float(y)!r}\n" for x, y in p))
            c["laser_side"] = {"returns_file": name}
        f.write_text(yaml.safe_dump(doc, sort_keys=False))
        answers.append(calibrate_board(f))
    a, b = answers
    assert np.abs(a.result.T_cam_laser - b.result.T_cam_laser).max() < TOL
    assert a.report["summary"] == b.report["summary"]
