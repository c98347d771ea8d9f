"""Line extraction by region growing on ray-cast scans of known geometry."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from rigcal.lines import LineParams, Segment, extract_lines, fit_line, segments_table
from rigcal.scan import Scan
from rigcal.sim.raycast import cast_scan_hits

STEP = np.radians(0.25)  # a Hokuyo-class angular step
SIGMA = 0.01  # 1 cm range noise, what the LineParams defaults are tuned for
RANGE_MIN, RANGE_MAX = 0.05, 30.0


def cast(walls, lo_deg=-135.0, hi_deg=135.0, sigma=0.0, seed=0) -> tuple[Scan, np.ndarray]:
    """A scan of the walls ((S, 2, 2) segments) and, per beam, the index of the wall hit (-1: none)."""
    n = round(np.radians(hi_deg - lo_deg) / STEP) + 1
    angles = np.radians(lo_deg) + STEP * np.arange(n)
    ranges, hit = cast_scan_hits(walls, angles, RANGE_MAX)
    if sigma:
        ranges = ranges + np.random.default_rng(seed).normal(0.0, sigma, n)
    return Scan.from_uniform(np.radians(lo_deg), STEP, ranges, RANGE_MIN, RANGE_MAX), hit


def sin_angle_between(u, v) -> float:
    """|sin| of the angle between two lines given by direction vectors (a line has no sense)."""
    u, v = np.asarray(u, float), np.asarray(v, float)
    return abs(float(u[0] * v[1] - u[1] * v[0])) / float(np.linalg.norm(u) * np.linalg.norm(v))


WALL = np.array([[[3.0, -3.0], [3.0, 3.0]]])  # x = 3, 6 m long, in front of the laser


# --- single wall -----------------------------------------------------------------------------
def test_single_wall_without_noise_is_one_exact_segment():
    scan, hit = cast(WALL)
    segs = extract_lines(scan)
    assert len(segs) == 1
    g = segs[0]
    np.testing.assert_array_equal(g.indices, np.flatnonzero(hit == 0))
    assert sin_angle_between(g.direction, [0.0, 1.0]) < 1e-9
    assert g.distance_m == pytest.approx(3.0, abs=1e-9)
    assert g.rms_residual_m < 1e-9
    np.testing.assert_allclose(g.points[:, 0], 3.0, atol=1e-9)
    # The wall's ends are at +-45 deg, where beams fall exactly: the end returns are its ends.
    np.testing.assert_allclose([g.start, g.end], [[3.0, -3.0], [3.0, 3.0]], atol=1e-9)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_single_wall_with_1cm_noise_fits_the_wall_within_the_noise(seed):
    scan, hit = cast(WALL, sigma=SIGMA, seed=seed)
    segs = extract_lines(scan)
    assert len(segs) == 1
    g = segs[0]
    wall_beams = np.flatnonzero(hit == 0)
    assert set(g.indices) <= set(wall_beams)
    # Left out: returns off the line by > 3 sigma (0.27% of 361, about 1) and end returns
    # past 4 robust sigmas (rarer still).
    assert len(wall_beams) - len(g.indices) <= 5
    # Range noise is along the beam: its part across the wall is sigma cos(beam angle) <= sigma.
    assert np.abs(g.points[:, 0] - 3.0).max() < 5 * SIGMA
    s = g.points[:, 1] - g.points[:, 1].mean()
    # Least squares: direction error ~ sigma / sqrt(sum s^2); the fitted line at the far end
    # of the segment ~ sigma sqrt(1/N + max s^2 / sum s^2). Allow 5 of each.
    assert sin_angle_between(g.direction, [0.0, 1.0]) < 5 * SIGMA / np.sqrt(s @ s)
    end_sigma = SIGMA * np.sqrt(1 / len(s) + (s**2).max() / (s @ s))
    assert abs(g.start[0] - 3.0) < 5 * end_sigma
    assert abs(g.end[0] - 3.0) < 5 * end_sigma
    assert abs(g.distance_m - 3.0) < 5 * end_sigma
    cos_a = np.cos(scan.angles_rad[g.indices])
    expected_rms = SIGMA * np.sqrt(np.mean(cos_a**2))
    assert g.rms_residual_m == pytest.approx(expected_rms, rel=0.2)  # rel. std ~ 1/sqrt(2N) = 4%


def test_max_angle_change_bounds_how_far_the_refitted_line_may_turn():
    exact, _ = cast(WALL)
    noisy, _ = cast(WALL, sigma=SIGMA, seed=0)
    stiff = LineParams(max_angle_change_deg=0.05)
    # An exact line never turns; noise turns a short line by more than 0.05 deg per return.
    assert len(extract_lines(exact, stiff)) == 1
    assert len(extract_lines(noisy, stiff)) > 1
    assert len(extract_lines(noisy)) == 1


# --- corner, occlusion -----------------------------------------------------------------------
CORNER = np.array([[[3.0, -3.0], [3.0, 2.0]], [[-3.0, 2.0], [3.0, 2.0]]])  # walls x = 3 and y = 2


def test_corner_without_noise_splits_at_the_corner_with_no_foreign_returns():
    scan, hit = cast(CORNER)
    segs = extract_lines(scan)
    assert len(segs) == 2
    corner_beam = np.flatnonzero(hit == 0)[-1]  # the last beam on wall x = 3
    assert set(hit[segs[0].indices]) == {0}
    assert set(hit[segs[1].indices]) == {1}
    assert segs[0].indices[-1] >= corner_beam - 1
    assert segs[1].indices[0] <= corner_beam + 2
    assert sin_angle_between(segs[0].direction, [0.0, 1.0]) < 1e-9
    assert sin_angle_between(segs[1].direction, [1.0, 0.0]) < 1e-9


@pytest.mark.parametrize("seed", [0, 1])
def test_corner_with_noise_splits_at_the_corner(seed):
    scan, hit = cast(CORNER, sigma=SIGMA, seed=seed)
    segs = extract_lines(scan)
    assert len(segs) == 2
    corner = np.array([3.0, 2.0])
    for g, wall, direction in [(segs[0], 0, [0.0, 1.0]), (segs[1], 1, [1.0, 0.0])]:
        assert (hit[g.indices] == wall).mean() > 0.98
        # A return of the other wall within max_point_distance_m (3 sigma) of the corner is
        # within the noise of both walls: ambiguous. Any farther one must not be taken.
        foreign = g.points[hit[g.indices] != wall]
        assert np.all(np.linalg.norm(foreign - corner, axis=1) < LineParams().max_point_distance_m)
        s = g.points - g.points.mean(axis=0)
        spread = np.sqrt(np.sum((s @ np.asarray(direction)) ** 2))
        assert sin_angle_between(g.direction, direction) < 5 * SIGMA / spread


BOX_BEFORE_WALL = np.array(
    [
        [[4.0, -3.0], [4.0, 3.0]],  # wall
        [[2.5, -0.3], [2.5, 0.3]],  # box face, 0.6 m wide, 1.5 m in front of the wall
        [[2.5, 0.3], [2.9, 0.3]],
        [[2.5, -0.3], [2.9, -0.3]],
    ]
)


def test_box_in_front_of_a_wall_is_its_own_segment():
    scan, hit = cast(BOX_BEFORE_WALL)
    segs = extract_lines(scan)
    # The box hides part of the wall: wall, box face, wall, in beam order.
    assert [g.id for g in segs] == [0, 1, 2]
    assert [set(hit[g.indices]) for g in segs] == [{0}, {1}, {0}]
    face = segs[1]
    face_beams = np.flatnonzero(hit == 1)
    assert set(face.indices) <= set(face_beams)
    assert len(face.indices) >= len(face_beams) - 2
    assert face.distance_m == pytest.approx(2.5, abs=1e-9)
    assert face.length_m == pytest.approx(0.6, abs=2 * 2.6 * STEP)  # within a beam step at each end


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_box_face_with_noise_is_one_segment_of_box_returns(seed):
    scan, hit = cast(BOX_BEFORE_WALL, sigma=SIGMA, seed=seed)
    segs = extract_lines(scan)
    on_face = [g for g in segs if (hit[g.indices] == 1).any()]
    assert len(on_face) == 1
    assert set(hit[on_face[0].indices]) == {1}
    assert len(on_face[0].indices) >= 0.95 * np.count_nonzero(hit == 1)


# --- invalid returns, outliers ---------------------------------------------------------------
def test_invalid_returns_are_skipped_and_indices_are_beam_numbers():
    scan, hit = cast(WALL, lo_deg=-40.0, hi_deg=40.0)
    assert (hit == 0).all()
    ranges = scan.ranges_m.copy()
    bad = {0: 0.0, 1: np.nan, 100: np.inf, 150: 0.0, 151: np.nan, 200: RANGE_MAX + 5.0, 250: 0.02}
    ranges[list(bad)] = list(bad.values())
    scan = Scan.from_uniform(scan.angles_rad[0], STEP, ranges, RANGE_MIN, RANGE_MAX)
    segs = extract_lines(scan)
    assert len(segs) == 1
    expected = [i for i in range(len(ranges)) if i not in bad]
    np.testing.assert_array_equal(segs[0].indices, expected)
    np.testing.assert_array_equal(segs[0].points, scan.points[segs[0].indices])
    assert sin_angle_between(segs[0].direction, [0.0, 1.0]) < 1e-9


@pytest.mark.parametrize("offset_m", [-0.15, 0.15])
@pytest.mark.parametrize("sigma", [0.0, SIGMA])
def test_single_spike_in_a_wall_neither_splits_it_nor_joins_it(offset_m, sigma):
    # 15 cm off is far beyond the 3 cm point distance but within the 25 cm gap limit.
    scan, _ = cast(WALL, lo_deg=-40.0, hi_deg=40.0, sigma=sigma, seed=3)
    ranges = scan.ranges_m.copy()
    spike = len(ranges) // 2
    ranges[spike] += offset_m
    scan = Scan.from_uniform(scan.angles_rad[0], STEP, ranges, RANGE_MIN, RANGE_MAX)
    segs = extract_lines(scan)
    assert len(segs) == 1
    g = segs[0]
    assert spike not in g.indices
    assert g.indices[0] < spike - 50
    assert g.indices[-1] > spike + 50
    assert np.abs(g.points[:, 0] - 3.0).max() < 5 * SIGMA


# --- dropping short segments -----------------------------------------------------------------
def plate_before_wall(plate_x: float, half_width: float) -> np.ndarray:
    wall = [[plate_x + 2.0, -3.0], [plate_x + 2.0, 3.0]]
    return np.array([wall, [[plate_x, -half_width], [plate_x, half_width]]])


def test_segments_shorter_than_min_length_are_dropped_and_ids_stay_consecutive():
    scan, hit = cast(plate_before_wall(2.0, 0.04))  # an 8 cm plate: about 9 returns
    plate_beams = np.flatnonzero(hit == 1)
    # A seed short enough to grow on the plate; only min_length_m differs between the two runs.
    segs = extract_lines(scan, LineParams(min_length_m=0.1, seed_length_m=0.03))
    assert [g.id for g in segs] == [0, 1]
    assert all(set(hit[g.indices]) == {0} for g in segs)
    kept = extract_lines(scan, LineParams(min_length_m=0.05, seed_length_m=0.03))
    assert [g.id for g in kept] == [0, 1, 2]
    assert set(kept[1].indices) <= set(plate_beams)
    assert 0.05 <= kept[1].length_m < 0.1


def test_segments_with_fewer_than_min_points_are_dropped():
    scan, hit = cast(plate_before_wall(3.0, 0.08))  # a 16 cm plate at 3 m: about 12 returns
    n_plate = np.count_nonzero(hit == 1)
    kept = extract_lines(scan, LineParams(min_points=n_plate))
    assert [set(hit[g.indices]) for g in kept] == [{0}, {1}, {0}]
    assert len(kept[1].indices) == n_plate
    dropped = extract_lines(scan, LineParams(min_points=n_plate + 1))
    assert [set(hit[g.indices]) for g in dropped] == [{0}, {0}]
    assert [g.id for g in dropped] == [0, 1]


def test_ids_are_consecutive_in_beam_order():
    room = np.array(
        [
            [[3.0, -3.0], [3.0, 3.0]],
            [[3.0, 3.0], [-3.0, 3.0]],
            [[-3.0, 3.0], [-3.0, -3.0]],
            [[1.5, -0.5], [2.0, -1.0]],
        ]
    )
    scan, _ = cast(room, sigma=SIGMA, seed=4)
    segs = extract_lines(scan)
    assert len(segs) >= 4
    assert [g.id for g in segs] == list(range(len(segs)))
    firsts = [int(g.indices[0]) for g in segs]
    assert firsts == sorted(firsts)
    assert all(np.all(np.diff(g.indices) > 0) for g in segs)
    assert all(a.indices[-1] < b.indices[0] for a, b in itertools.pairwise(segs))


# --- degenerate scans ------------------------------------------------------------------------
def test_all_invalid_scan_gives_no_segments():
    ranges = np.array([0.0, np.nan, np.inf, 0.01, 31.0] * 40)
    assert extract_lines(Scan.from_uniform(-1.0, STEP, ranges, RANGE_MIN, RANGE_MAX)) == []


@pytest.mark.parametrize("n", [0, 1, 2, 4])
def test_scan_shorter_than_a_seed_gives_no_segments(n):
    scan = Scan.from_uniform(-0.01, STEP, np.full(n, 2.0), RANGE_MIN, RANGE_MAX)
    assert extract_lines(scan) == []


def test_scattered_returns_give_no_segments():
    rng = np.random.default_rng(5)
    ranges = rng.uniform(1.0, 10.0, 400)  # neighbours metres apart: every pair is a gap
    assert extract_lines(Scan.from_uniform(-1.0, STEP, ranges, RANGE_MIN, RANGE_MAX)) == []


# --- Segment properties ----------------------------------------------------------------------
@pytest.mark.parametrize("normal_deg", [0.0, 30.0, 89.0, 90.0, 135.0, 180.0, -100.0, -45.0])
def test_segment_geometry_of_a_wall_at_any_bearing(normal_deg):
    phi, dist, half = np.radians(normal_deg), 2.5, 3.0
    n = np.array([np.cos(phi), np.sin(phi)])
    t = np.array([-n[1], n[0]])
    wall = np.array([[dist * n - half * t, dist * n + half * t]])
    scan, _ = cast(wall, lo_deg=normal_deg - 90.0, hi_deg=normal_deg + 90.0)
    segs = extract_lines(scan)
    assert len(segs) == 1
    g = segs[0]
    assert -np.pi / 2 < g.angle_rad <= np.pi / 2
    line_angle = np.arctan2(t[1], t[0])
    assert abs(np.sin(g.angle_rad - line_angle)) < 1e-9
    np.testing.assert_allclose(g.normal, n, atol=1e-9)
    assert g.distance_m == pytest.approx(dist, abs=1e-9)
    # The end returns are the outermost beams on the wall: within one return spacing of its ends.
    spacing = np.linalg.norm(np.diff(g.points, axis=0), axis=1).max()
    assert 2 * half - 2 * spacing <= g.length_m <= 2 * half
    assert g.length_m == pytest.approx(np.linalg.norm(g.points[-1] - g.points[0]), abs=1e-9)
    assert np.dot(g.end - g.start, g.direction) > 0


def hand_segment(direction, centroid) -> Segment:
    d = np.asarray(direction, float) / np.linalg.norm(direction)
    c = np.asarray(centroid, float)
    pts = np.array([c - d, c + d])
    return Segment(0, np.array([0, 1]), pts, c, d, pts[0], pts[1], 0.0)


@pytest.mark.parametrize(
    ("direction", "angle"),
    [
        ([0.0, 1.0], np.pi / 2),
        ([0.0, -1.0], np.pi / 2),
        ([1.0, 0.0], 0.0),
        ([-1.0, 0.0], 0.0),
        ([1.0, 1.0], np.pi / 4),
        ([-1.0, -1.0], np.pi / 4),
        ([1.0, -1.0], -np.pi / 4),
        ([-1.0, 1.0], -np.pi / 4),
    ],
)
def test_angle_is_in_minus_half_pi_to_half_pi_whatever_the_sense(direction, angle):
    assert hand_segment(direction, [2.0, 1.0]).angle_rad == pytest.approx(angle, abs=1e-15)


@pytest.mark.parametrize("sense", [1.0, -1.0])
@pytest.mark.parametrize(
    ("direction", "centroid", "normal", "distance"),
    [
        ([0.0, 1.0], [2.0, 0.5], [1.0, 0.0], 2.0),
        ([0.0, 1.0], [-2.0, 0.5], [-1.0, 0.0], 2.0),
        ([1.0, 0.0], [0.3, -1.5], [0.0, -1.0], 1.5),
        ([1.0, 1.0], [0.0, 2.0], [-np.sqrt(0.5), np.sqrt(0.5)], np.sqrt(2.0)),
    ],
)
def test_normal_points_away_from_the_laser(sense, direction, centroid, normal, distance):
    g = hand_segment(sense * np.asarray(direction), centroid)
    np.testing.assert_allclose(g.normal, normal, atol=1e-15)
    assert g.distance_m == pytest.approx(distance, abs=1e-15)
    assert g.length_m == pytest.approx(2.0)


# --- fit_line --------------------------------------------------------------------------------
def test_fit_line_on_exact_points():
    x = np.linspace(-2.0, 3.0, 11)
    pts = np.column_stack([x, 0.5 * x + 1.0])
    c, u, rms = fit_line(pts)
    np.testing.assert_allclose(c, pts.mean(axis=0), atol=1e-15)
    np.testing.assert_allclose(u, np.array([2.0, 1.0]) / np.sqrt(5.0), atol=1e-14)
    assert rms < 1e-14
    _, u_rev, _ = fit_line(pts[::-1])
    np.testing.assert_allclose(u_rev, -u, atol=1e-14)


def test_fit_line_vertical_and_two_points():
    c, u, rms = fit_line([[1.0, 5.0], [1.0, 2.0], [1.0, -1.0]])
    np.testing.assert_allclose(c, [1.0, 2.0])
    np.testing.assert_allclose(u, [0.0, -1.0], atol=1e-15)
    assert rms == pytest.approx(0.0, abs=1e-15)
    _, u2, rms2 = fit_line([[0.0, 0.0], [3.0, 4.0]])
    np.testing.assert_allclose(u2, [0.6, 0.8], atol=1e-15)
    assert rms2 == pytest.approx(0.0, abs=1e-15)


def test_fit_line_rms_is_the_orthogonal_residual():
    # Pairs at +-1 cm around y = 0: the best line is y = 0 and every residual is 1 cm.
    pts = np.array([[x, y] for x in (0.0, 1.0, 2.0, 3.0) for y in (0.01, -0.01)])
    c, u, rms = fit_line(pts)
    np.testing.assert_allclose(c, [1.5, 0.0], atol=1e-15)
    np.testing.assert_allclose(u, [1.0, 0.0], atol=1e-12)
    assert rms == pytest.approx(0.01, rel=1e-9)
    # Rotating and shifting the points changes neither the residual nor the fit's geometry.
    a = 0.7
    R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    c2, u2, rms2 = fit_line(pts @ R.T + [4.0, -2.0])
    np.testing.assert_allclose(u2, R @ u, atol=1e-12)
    np.testing.assert_allclose(c2, R @ c + [4.0, -2.0], atol=1e-12)
    assert rms2 == pytest.approx(0.01, rel=1e-9)


# --- parameters, table -----------------------------------------------------------------------
@pytest.mark.parametrize(
    ("field", "value", "match"),
    [
        ("max_point_distance_m", 0.0, "must be > 0"),
        ("max_point_distance_m", -0.01, "must be > 0"),
        ("max_gap_m", 0.0, "must be > 0"),
        ("max_angle_change_deg", 0.0, "must be > 0"),
        ("max_angle_change_deg", -5.0, "must be > 0"),
        ("seed_points", 1, ">= 2"),
        ("min_points", 1, ">= 2"),
        ("min_points", 0, ">= 2"),
    ],
)
def test_line_params_reject_bad_values(field, value, match):
    with pytest.raises(ValueError, match=match):
        LineParams(**{field: value})


def test_line_params_accept_the_smallest_valid_counts():
    p = LineParams(seed_points=2, min_points=2)
    assert (p.seed_points, p.min_points) == (2, 2)


def test_segments_table_has_a_header_and_one_row_per_segment():
    scan, _ = cast(BOX_BEFORE_WALL)
    segs = extract_lines(scan)
    lines = segments_table(segs).splitlines()
    header = ["id", "points", "beams", "start_m", "end_m", "length_m", "angle_deg", "rms_mm"]
    assert lines[0].split() == header
    assert len(lines) == 1 + len(segs)
    for g, row in zip(segs, lines[1:], strict=True):
        cells = row.split()
        assert cells[0] == str(g.id)
        assert cells[1] == str(len(g.indices))
        assert cells[2] == f"{g.indices[0]}-{g.indices[-1]}"
        assert float(cells[-3]) == pytest.approx(g.length_m, abs=5e-4)
    assert segments_table([]).splitlines() == lines[:1]


def test_a_wall_cut_by_noise_is_joined_again():
    # Seed 52 of this setting cut a 7 m wall after 6 returns when pieces were not joined.
    from rigcal.sim.raycast import cast_scan as cast

    angles = np.radians(np.arange(-135, 135.001, 0.25))
    rng = np.random.default_rng(52)
    d = rng.uniform(6, 8)
    r = cast([[[d, -6], [d, 6]]], angles, 30.0)
    r = np.where(np.isfinite(r), r + rng.normal(0, 0.01, len(r)), 0)
    segs = extract_lines(Scan.from_uniform(angles[0], np.radians(0.25), r, 0.1, 30.0))
    assert len(segs) == 1
    assert abs(np.degrees(segs[0].angle_rad)) == pytest.approx(90.0, abs=0.5)


@pytest.mark.parametrize("turn_deg", [90.0, 30.0, 15.0])
def test_pieces_meeting_at_a_corner_are_not_joined(turn_deg):
    from rigcal.sim.raycast import cast_scan as cast

    # Two noiseless walls meeting at (3, 1), the second turned by turn_deg towards the scanner.
    t = np.radians(turn_deg)
    walls = [[[3.0, -2.0], [3.0, 1.0]], [[3.0, 1.0], [3.0 - 2.0 * np.sin(t), 1.0 + 2.0 * np.cos(t)]]]
    angles = np.radians(np.arange(-60, 60.001, 0.25))
    r = cast(walls, angles, 30.0)
    segs = extract_lines(
        Scan.from_uniform(angles[0], np.radians(0.25), np.where(np.isfinite(r), r, 0), 0.1, 30.0)
    )
    assert len(segs) == 2


def test_thresholds_scale_with_the_range_noise_never_below_the_defaults():
    d = LineParams()
    assert LineParams.for_range_noise(0.005) == d
    assert LineParams.for_range_noise(0.01) == d
    p = LineParams.for_range_noise(0.03)
    assert p.max_point_distance_m == pytest.approx(3 * d.max_point_distance_m)
    assert p.seed_length_m == pytest.approx(3 * d.seed_length_m)
    assert p.max_gap_m == pytest.approx(0.3)
    assert p.min_points == d.min_points


# --- 360-degree scans: the seam at +-180 deg -------------------------------------------------
def _ring_scan(angle_min_rad: float) -> Scan:
    """A 360-degree scan (0.5 deg steps) in a 4 m x 3 m room, laser at (2.5, 1.5) from
    its corner: the wall 2.5 m behind the laser crosses the seam at +-180 deg."""
    from rigcal.sim.raycast import cast_scan

    walls = np.array(
        [
            [[-2.5, -1.5], [1.5, -1.5]],
            [[1.5, -1.5], [1.5, 1.5]],
            [[1.5, 1.5], [-2.5, 1.5]],
            [[-2.5, 1.5], [-2.5, -1.5]],
        ]
    )
    step = np.radians(0.5)
    angles = angle_min_rad + step * np.arange(720)
    return Scan.from_uniform(angle_min_rad, step, cast_scan(walls, angles, 30.0), 0.1, 30.0)


@pytest.mark.parametrize("angle_min_rad", [-np.pi, -np.pi + np.radians(0.2), 0.0, -3.0])
def test_a_wall_over_the_seam_comes_out_whole(angle_min_rad):
    scan = _ring_scan(angle_min_rad)
    segments = extract_lines(scan)
    assert len(segments) == 4
    back = [g for g in segments if abs(g.centroid[0] + 2.5) < 0.01]
    assert len(back) == 1
    assert back[0].length_m > 2.9
    assert [g.id for g in segments] == list(range(4))
    firsts = [int(g.indices[0]) for g in segments]
    assert firsts == sorted(firsts)


def test_a_scan_short_of_the_full_circle_is_not_a_ring():
    step = np.radians(0.5)
    scan = Scan.from_uniform(-np.pi, step, np.ones(700), 0.1, 30.0)
    from rigcal.lines import is_full_circle

    assert not is_full_circle(scan)
    assert is_full_circle(Scan.from_uniform(-np.pi, step, np.ones(720), 0.1, 30.0))
