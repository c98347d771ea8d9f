"""The Scan record and its YAML file: validity mask, points, round trip and read errors."""

from __future__ import annotations

import re

import numpy as np
import pytest

from rigcal.errors import InputError, OutputError
from rigcal.scan import Scan, read_scan, scan_to_text, write_scan

STEP = np.radians(0.25)


def assert_same_bits(a: np.ndarray, b: np.ndarray) -> None:
    """NaN at the same places, every other value bit for bit (the sign of zero included).

    A NaN's sign and payload carry nothing (PyYAML's .nan has the sign bit set)."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    assert a.shape == b.shape
    np.testing.assert_array_equal(np.isnan(a), np.isnan(b))
    keep = ~np.isnan(a)
    np.testing.assert_array_equal(a[keep].view(np.uint64), b[keep].view(np.uint64))


def assert_same_scan(a: Scan, b: Scan) -> None:
    assert_same_bits(a.angles_rad, b.angles_rad)
    assert_same_bits(a.ranges_m, b.ranges_m)
    assert (a.range_min_m, a.range_max_m) == (b.range_min_m, b.range_max_m)
    assert a.stamp_s == b.stamp_s
    assert a.angle_increment_rad == b.angle_increment_rad


# --- the record ------------------------------------------------------------------------------
def test_invalid_returns_are_masked_and_their_points_nan():
    ranges = [1.0, 0.0, np.nan, np.inf, 0.05, 31.0, 0.1, 30.0, -np.inf]
    scan = Scan.from_uniform(-1.0, 0.1, ranges, 0.1, 30.0)
    # range_min itself is valid; 0, NaN, +-inf, below, above and range_max itself (a
    # driver's no return) are not.
    np.testing.assert_array_equal(scan.valid, [True, False, False, False, False, False, True, False, False])
    assert np.isnan(scan.points[~scan.valid]).all()
    assert np.isfinite(scan.points[scan.valid]).all()
    # The record keeps the invalid returns as they were recorded.
    assert_same_bits(scan.ranges_m, ranges)


def test_zero_range_is_invalid_even_when_range_min_is_zero():
    scan = Scan([0.0, 0.1, 0.2, 0.3], [0.0, -0.0, 1e-9, 29.0], 0.0, 30.0)
    np.testing.assert_array_equal(scan.valid, [False, False, True, True])


def test_points_are_range_times_cos_sin_of_the_beam_angle():
    angles = np.array([-np.pi / 2, -0.3, 0.0, 0.7, np.pi / 2, 3.0])
    ranges = np.array([2.0, 1.5, 3.0, 4.0, 0.5, 6.0])
    scan = Scan(angles, ranges, 0.1, 30.0)
    expected = ranges[:, None] * np.column_stack([np.cos(angles), np.sin(angles)])
    np.testing.assert_allclose(scan.points, expected, rtol=0, atol=1e-15)
    np.testing.assert_allclose(scan.points[2], [3.0, 0.0])
    np.testing.assert_allclose(scan.points[4], [0.0, 0.5], atol=1e-15)


def test_from_uniform_angles_and_increment():
    scan = Scan.from_uniform(-0.5, 0.125, [1.0] * 9, 0.1, 10.0, stamp_s=12.5)
    np.testing.assert_array_equal(scan.angles_rad, -0.5 + 0.125 * np.arange(9))
    assert scan.angle_increment_rad == 0.125
    assert scan.step_rad == pytest.approx(0.125)
    assert scan.stamp_s == 12.5
    assert Scan([0.0, 0.1, 0.3], [1.0, 1.0, 1.0], 0.1, 10.0).angle_increment_rad is None


def test_record_arrays_are_read_only_copies():
    ranges = np.array([1.0, 2.0, 3.0])
    scan = Scan([0.0, 0.1, 0.2], ranges, 0.1, 10.0)
    ranges[0] = 9.0
    assert scan.ranges_m[0] == 1.0
    with pytest.raises(ValueError, match="read-only"):
        scan.ranges_m[0] = 5.0


@pytest.mark.parametrize(
    ("angles", "ranges", "rmin", "rmax", "match"),
    [
        ([0.0, 0.1, 0.2], [1.0, 2.0], 0.1, 10.0, "3 angles but 2 ranges"),
        ([0.0, 0.2, 0.1], [1.0, 2.0, 3.0], 0.1, 10.0, "strictly increasing"),
        ([0.0, 0.1, 0.1], [1.0, 2.0, 3.0], 0.1, 10.0, "strictly increasing"),
        ([0.0, 0.1], [1.0, 2.0], 5.0, 5.0, "range_min_m < range_max_m"),
        ([0.0, 0.1], [1.0, 2.0], -0.1, 5.0, "0 <= range_min_m"),
    ],
)
def test_record_rejects_inconsistent_input(angles, ranges, rmin, rmax, match):
    with pytest.raises(ValueError, match=match):
        Scan(angles, ranges, rmin, rmax)


def test_from_uniform_rejects_a_non_positive_increment():
    with pytest.raises(ValueError, match="strictly increasing"):
        Scan.from_uniform(0.0, 0.0, [1.0, 2.0], 0.1, 10.0)
    with pytest.raises(ValueError, match="strictly increasing"):
        Scan.from_uniform(0.0, -0.1, [1.0, 2.0], 0.1, 10.0)


# --- round trip ------------------------------------------------------------------------------
def awkward_ranges(rng: np.random.Generator, n: int) -> np.ndarray:
    """Random ranges with every kind of invalid return and a few hard-to-print floats."""
    r = rng.uniform(0.02, 35.0, n)
    r[[3, 10, 11, 20]] = [0.0, np.nan, np.inf, -0.0]
    r[30:34] = [1e-05, 5e-324, 0.1 + 0.2, 2.0 / 3.0]  # '1e-05' without a '.' is a string in YAML 1.1
    return r


@pytest.mark.parametrize("stamp", [None, 1712345678.123456, 0.0])
def test_round_trip_uniform_is_bit_exact(tmp_path, stamp):
    rng = np.random.default_rng(7)
    scan = Scan.from_uniform(-2.356194490192345, STEP, awkward_ranges(rng, 200), 0.02, 30.0, stamp_s=stamp)
    back = read_scan(write_scan(tmp_path / "scan.yaml", scan))
    assert_same_scan(back, scan)
    np.testing.assert_array_equal(back.valid, scan.valid)


@pytest.mark.parametrize("stamp", [None, 3.25])
def test_round_trip_non_uniform_is_bit_exact(tmp_path, stamp):
    rng = np.random.default_rng(8)
    angles = np.sort(rng.uniform(-np.pi, np.pi, 150))
    angles[75] = 5e-05  # between its neighbours; repr gives '5e-05'
    angles.sort()
    scan = Scan(angles, awkward_ranges(rng, 150), 0.02, 30.0, stamp_s=stamp)
    back = read_scan(write_scan(tmp_path / "scan.yaml", scan))
    assert_same_scan(back, scan)
    assert back.angle_increment_rad is None


def test_written_text_uses_the_documented_keys():
    text = scan_to_text(Scan.from_uniform(-0.5, 0.25, [1.0, np.nan, np.inf, 0.0], 0.1, 10.0, stamp_s=2.0))
    lines = [ln for ln in text.splitlines() if not ln.startswith("#")]
    assert lines == [
        "schema_version: 1",
        "frame: laser",
        "stamp_s: 2.0",
        "angle_min_rad: -0.5",
        "angle_increment_rad: 0.25",
        "range_min_m: 0.1",
        "range_max_m: 10.0",
        "ranges_m: [1.0, .nan, .inf, 0.0]",
    ]
    assert "stamp_s" not in scan_to_text(Scan([0.0, 1.0], [1.0, 2.0], 0.1, 10.0))


def test_golden_file_written_by_hand(tmp_path):
    path = tmp_path / "golden.yaml"
    path.write_text(
        "# a scan written by hand\n"
        "schema_version: 1\n"
        "frame: laser\n"
        "stamp_s: 1700000000.5\n"
        "angle_min_rad: -0.1\n"
        "angle_increment_rad: 0.05\n"
        "range_min_m: 0.1\n"
        "range_max_m: 20\n"
        "ranges_m: [2, 2.5, .nan, 0, .inf, 0.05, 25.0]\n"
    )
    scan = read_scan(path)
    assert scan.stamp_s == 1700000000.5
    assert (scan.range_min_m, scan.range_max_m) == (0.1, 20.0)
    assert scan.angle_increment_rad == 0.05
    np.testing.assert_allclose(scan.angles_rad, [-0.1, -0.05, 0.0, 0.05, 0.1, 0.15, 0.2], atol=1e-15)
    np.testing.assert_array_equal(scan.ranges_m, [2.0, 2.5, np.nan, 0.0, np.inf, 0.05, 25.0])
    np.testing.assert_array_equal(scan.valid, [True, True, False, False, False, False, False])
    np.testing.assert_allclose(scan.points[0], [2.0 * np.cos(0.1), -2.0 * np.sin(0.1)])


def test_golden_file_with_explicit_angles_and_no_frame_or_stamp(tmp_path):
    path = tmp_path / "golden.yaml"
    path.write_text(
        "schema_version: 1\nrange_min_m: 0\nrange_max_m: 5\nangles_rad: [-1, 0, 0.5]\nranges_m: [1, 2, 3]\n"
    )
    scan = read_scan(path)
    np.testing.assert_array_equal(scan.angles_rad, [-1.0, 0.0, 0.5])
    assert scan.stamp_s is None
    assert scan.angle_increment_rad is None
    assert scan.valid.all()


def test_write_refuses_to_overwrite_without_force_and_leaves_no_temp_files(tmp_path):
    path = tmp_path / "scan.yaml"
    first = Scan.from_uniform(0.0, 0.1, [1.0, 2.0, 3.0], 0.1, 10.0)
    second = Scan.from_uniform(0.0, 0.1, [4.0, 5.0, 6.0], 0.1, 10.0)
    write_scan(path, first)
    with pytest.raises(OutputError, match=re.escape(f"{path}: exists")):
        write_scan(path, second)
    assert_same_scan(read_scan(path), first)
    write_scan(path, second, force=True)
    assert_same_scan(read_scan(path), second)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scan.yaml"]


def test_write_creates_missing_folders(tmp_path):
    path = write_scan(tmp_path / "a" / "b" / "scan.yaml", Scan([0.0, 1.0], [1.0, 2.0], 0.1, 10.0))
    assert path.is_file()
    assert sorted(p.name for p in path.parent.iterdir()) == ["scan.yaml"]


# --- read errors -----------------------------------------------------------------------------
VALID = {
    "schema_version": "1",
    "frame": "laser",
    "stamp_s": "10.0",
    "angle_min_rad": "-0.5",
    "angle_increment_rad": "0.25",
    "range_min_m": "0.1",
    "range_max_m": "10.0",
    "ranges_m": "[1.0, 2.0, 3.0]",
}


def scan_file(tmp_path, drop=(), **values: str):
    """A scan file: VALID with keys dropped and values (YAML text) replaced or added."""
    fields = {k: v for k, v in VALID.items() if k not in drop} | values
    path = tmp_path / "scan.yaml"
    path.write_text("".join(f"{k}: {v}\n" for k, v in fields.items()))
    return path


def read_error(path) -> str:
    with pytest.raises(InputError) as info:
        read_scan(path)
    return str(info.value)


def test_the_valid_base_file_reads(tmp_path):
    scan = read_scan(scan_file(tmp_path))
    np.testing.assert_array_equal(scan.angles_rad, [-0.5, -0.25, 0.0])


def test_missing_file(tmp_path):
    path = tmp_path / "nope.yaml"
    with pytest.raises(InputError, match=re.escape(f"{path}: scan file not found")):
        read_scan(path)


def test_not_yaml(tmp_path):
    path = tmp_path / "scan.yaml"
    path.write_text("schema_version: 1\nranges_m: [1.0, 2.0\n")
    with pytest.raises(InputError, match=re.escape(f"{path}: not valid YAML at line")):
        read_scan(path)


@pytest.mark.parametrize(("text", "shown"), [("- 1\n- 2\n", "[1, 2]"), ("", "None"), ("3.5\n", "3.5")])
def test_not_a_mapping(tmp_path, text, shown):
    path = tmp_path / "scan.yaml"
    path.write_text(text)
    with pytest.raises(InputError, match=re.escape(f"{path}: (top level): got {shown}; expected a mapping")):
        read_scan(path)


def test_unknown_key(tmp_path):
    path = scan_file(tmp_path, range_m="[1.0]")
    with pytest.raises(InputError, match=re.escape(f"{path}: range_m: got [1.0]; expected no such key")):
        read_scan(path)


@pytest.mark.parametrize("key", ["schema_version", "range_min_m", "range_max_m", "ranges_m"])
def test_missing_required_key(tmp_path, key):
    path = scan_file(tmp_path, drop=[key])
    with pytest.raises(InputError, match=re.escape(f"{path}: {key}: missing; this key is required")):
        read_scan(path)


@pytest.mark.parametrize(("text", "shown"), [("'1'", "'1'"), ("true", "True"), ("0", "0")])
def test_wrong_schema_version(tmp_path, text, shown):
    path = scan_file(tmp_path, schema_version=text)
    with pytest.raises(
        InputError, match=re.escape(f"{path}: schema_version: got {shown}; expected one of 1, 2")
    ):
        read_scan(path)


def test_newer_schema_version(tmp_path):
    """A version above those this rigcal reads is named as a newer rigcal's file."""
    path = scan_file(tmp_path, schema_version="3")
    with pytest.raises(
        InputError,
        match=re.escape(
            f"{path}: schema_version: got 3; expected 1 or 2 (the versions this rigcal reads; "
            "a file of a newer rigcal: upgrade rigcal to read it)"
        ),
    ):
        read_scan(path)


def test_frame_not_laser(tmp_path):
    path = scan_file(tmp_path, frame="camera")
    with pytest.raises(InputError, match=re.escape(f"{path}: frame: got 'camera'; expected 'laser'")):
        read_scan(path)


@pytest.mark.parametrize(("rmin", "rmax"), [("10.0", "10.0"), ("12.0", "10.0"), ("-0.5", "10.0")])
def test_range_min_not_below_range_max(tmp_path, rmin, rmax):
    path = scan_file(tmp_path, range_min_m=rmin, range_max_m=rmax)
    msg = f"{path}: range_min_m: got {float(rmin)!r}; expected a number in [0, range_max_m = 10)"
    with pytest.raises(InputError, match=re.escape(msg)):
        read_scan(path)


@pytest.mark.parametrize(
    ("key", "text", "shown", "expected"),
    [
        ("range_max_m", "0", "0", "a finite number > 0"),
        ("range_max_m", "far", "'far'", "a finite number > 0"),
        ("range_min_m", ".nan", "nan", "a finite number"),
        ("stamp_s", "yes", "True", "a finite number"),
        ("stamp_s", ".inf", "inf", "a finite number"),
    ],
)
def test_bad_scalar_values(tmp_path, key, text, shown, expected):
    path = scan_file(tmp_path, **{key: text})
    with pytest.raises(InputError, match=re.escape(f"{path}: {key}: got {shown}; expected {expected}")):
        read_scan(path)


@pytest.mark.parametrize(
    ("ranges", "key", "shown", "expected"),
    [
        ("[1.0, abc, 3.0]", "ranges_m[1]", "'abc'", "a number (0, .nan or .inf for no return)"),
        ("[1.0, 2.0, null]", "ranges_m[2]", "None", "a number (0, .nan or .inf for no return)"),
        ("[1.0, [2.0], 3.0]", "ranges_m[1]", "[2.0]", "a number (0, .nan or .inf for no return)"),
        ("[true, 2.0, 3.0]", "ranges_m[0]", "True", "a number (0, .nan or .inf for no return)"),
        ("[1.0, 2.0, -0.5]", "ranges_m[2]", "-0.5", "a range >= 0"),
        ("[1.0, -.inf, 3.0]", "ranges_m[1]", "-inf", "a range >= 0"),
        ("[]", "ranges_m", "[]", "a non-empty list of ranges in metres"),
        ("2.0", "ranges_m", "2.0", "a non-empty list of ranges in metres"),
    ],
)
def test_bad_ranges(tmp_path, ranges, key, shown, expected):
    path = scan_file(tmp_path, ranges_m=ranges)
    with pytest.raises(InputError, match=re.escape(f"{path}: {key}: got {shown}; expected {expected}")):
        read_scan(path)


def test_both_angle_forms(tmp_path):
    path = scan_file(tmp_path, angles_rad="[0.0, 0.1, 0.2]")
    with pytest.raises(InputError, match=re.escape(f"{path}: angles: expected either angle_min_rad")):
        read_scan(path)


def test_neither_angle_form(tmp_path):
    path = scan_file(tmp_path, drop=["angle_min_rad", "angle_increment_rad"])
    with pytest.raises(InputError, match=re.escape(f"{path}: angles: expected either angle_min_rad")):
        read_scan(path)


@pytest.mark.parametrize(
    ("drop", "missing"), [("angle_increment_rad", "angle_increment_rad"), ("angle_min_rad", "angle_min_rad")]
)
def test_half_of_the_uniform_angle_form(tmp_path, drop, missing):
    path = scan_file(tmp_path, drop=[drop])
    msg = f"{path}: {missing}: missing; angle_min_rad needs angle_increment_rad"
    with pytest.raises(InputError, match=re.escape(msg)):
        read_scan(path)


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("0", "got 0; expected a finite number in [1e-06, 6.28319]"),
        ("-0.25", "got -0.25; expected a step > 0"),
    ],
)
def test_increment_not_positive(tmp_path, text, expected):
    path = scan_file(tmp_path, angle_increment_rad=text)
    msg = f"{path}: angle_increment_rad: {expected}"
    with pytest.raises(InputError, match=re.escape(msg)):
        read_scan(path)


def test_non_finite_angle_min(tmp_path):
    path = scan_file(tmp_path, angle_min_rad=".nan")
    msg = f"{path}: angle_min_rad: got nan; expected a finite number"
    with pytest.raises(InputError, match=re.escape(msg)):
        read_scan(path)


def test_angles_rad_length_mismatch(tmp_path):
    path = scan_file(tmp_path, drop=["angle_min_rad", "angle_increment_rad"], angles_rad="[0.0, 0.1]")
    msg = f"{path}: angles_rad: got '2 angles'; expected one angle per range (3)"
    with pytest.raises(InputError, match=re.escape(msg)):
        read_scan(path)


@pytest.mark.parametrize(
    ("angles", "index", "shown"), [("[0.0, 0.2, 0.1]", 2, "0.1"), ("[0.0, 0.0, 0.1]", 1, "0.0")]
)
def test_angles_rad_not_increasing_names_the_index(tmp_path, angles, index, shown):
    path = scan_file(tmp_path, drop=["angle_min_rad", "angle_increment_rad"], angles_rad=angles)
    msg = f"{path}: angles_rad[{index}]: got {shown}; expected an angle > angles_rad[{index - 1}]"
    with pytest.raises(InputError, match=re.escape(msg)):
        read_scan(path)


@pytest.mark.parametrize(
    ("angles", "key", "shown"),
    [
        ("[0.0, .nan, 0.2]", "angles_rad[1]", "nan"),
        ("[0.0, 0.1, .inf]", "angles_rad[2]", "inf"),
        ("[x, 0.1, 0.2]", "angles_rad[0]", "'x'"),
        ("[0.0, false, 0.2]", "angles_rad[1]", "False"),
    ],
)
def test_angles_rad_not_finite_numbers(tmp_path, angles, key, shown):
    path = scan_file(tmp_path, drop=["angle_min_rad", "angle_increment_rad"], angles_rad=angles)
    with pytest.raises(InputError, match=re.escape(f"{path}: {key}: got {shown}; expected a finite number")):
        read_scan(path)


def test_angles_rad_empty(tmp_path):
    path = scan_file(tmp_path, drop=["angle_min_rad", "angle_increment_rad"], angles_rad="[]")
    msg = f"{path}: angles_rad: got []; expected a non-empty list of numbers"
    with pytest.raises(InputError, match=re.escape(msg)):
        read_scan(path)


# --- laser.clockwise (schema 2) ----------------------------------------------------------------
def test_clockwise_uniform_scan_gives_the_points_of_the_unmirrored_one(tmp_path):
    ranges = [1.0, 2.0, 0.0, 3.5, 4.0]
    ccw = Scan.from_uniform(-0.5, 0.25, ranges, 0.1, 10.0)
    # The same sweep from a scanner counting clockwise: beam i at +0.5 - ... read clockwise.
    path = scan_file(
        tmp_path,
        schema_version="2",
        angle_min_rad="-0.5",
        ranges_m=str(ranges[::-1]),
        laser="{clockwise: true}",
    )
    scan = read_scan(path)
    np.testing.assert_allclose(scan.angles_rad, ccw.angles_rad, atol=1e-15)
    np.testing.assert_array_equal(scan.valid, ccw.valid)
    np.testing.assert_allclose(scan.points[scan.valid], ccw.points[ccw.valid], atol=1e-15)
    assert scan.angle_increment_rad == 0.25


def test_clockwise_listed_angles(tmp_path):
    ccw = Scan(np.array([-2.0, 0.1, 3.0]), np.array([1.0, 2.0, 3.0]), 0.1, 10.0)
    path = tmp_path / "scan.yaml"
    path.write_text(
        "schema_version: 2\nlaser: {clockwise: true}\nangles_rad: [-3.0, -0.1, 2.0]\n"
        "range_min_m: 0.1\nrange_max_m: 10.0\nranges_m: [3.0, 2.0, 1.0]\n"
    )
    scan = read_scan(path)
    np.testing.assert_allclose(scan.points, ccw.points, atol=1e-15)


def test_clockwise_false_reads_as_before(tmp_path):
    a = read_scan(scan_file(tmp_path, schema_version="2", laser="{clockwise: false}"))
    np.testing.assert_array_equal(a.angles_rad, [-0.5, -0.25, 0.0])


@pytest.mark.parametrize(
    ("values", "message"),
    [
        (
            {"laser": "{clockwise: true}"},
            "laser: got {'clockwise': True}; expected no laser key in schema_version 1",
        ),
        (
            {"schema_version": "2", "laser": "{clockwise: yes please}"},
            "laser.clockwise: got 'yes please'; expected true",
        ),
        (
            {"schema_version": "2", "laser": "{clockwize: true}"},
            "laser.clockwize: got True; expected no such key",
        ),
        ({"schema_version": "2", "laser": "[1]"}, "laser: got [1]; expected a mapping"),
    ],
)
def test_bad_laser_key(tmp_path, values, message):
    path = scan_file(tmp_path, **values)
    assert read_error(path).startswith(f"{path}: {message}")


# --- the mean of a still moment's scans ---------------------------------------------------
def _still(rng, k: int, sigma: float, n: int = 200) -> tuple[np.ndarray, list[Scan]]:
    truth = 2.0 + 0.5 * np.sin(np.linspace(0, 3, n))
    return truth, [
        Scan.from_uniform(-1.0, 0.01, truth + rng.normal(0, sigma, n), 0.1, 30.0) for _ in range(k)
    ]


def test_mean_scan_averages_independent_noise_down():
    from rigcal.scan import mean_scan

    rng = np.random.default_rng(3)
    truth, scans = _still(rng, 16, 0.01)
    m = mean_scan(scans)
    err = m.ranges_m - truth
    # sqrt(16) = 4 times less than one scan's 1 cm (a 5 % band for 200 beams' estimate).
    assert 0.0020 < float(np.std(err)) < 0.0031
    assert m.valid.all()
    assert mean_scan(scans[:1]) is scans[0]


def test_mean_scan_drops_flicker_and_invalidates_beams_seen_in_too_few_scans():
    from rigcal.scan import mean_scan

    rng = np.random.default_rng(4)
    truth, scans = _still(rng, 10, 0.005)
    ranges = np.array([s.ranges_m for s in scans])
    ranges[2, 50] = truth[50] + 3.0  # a mixed pixel flickering to the wall once
    ranges[:6, 80] = np.nan  # beam 80 lost in 6 of 10 scans
    scans = [Scan.from_uniform(-1.0, 0.01, r, 0.1, 30.0) for r in ranges]
    m = mean_scan(scans)
    assert abs(m.ranges_m[50] - truth[50]) < 0.01
    assert not m.valid[80]
    assert m.valid.sum() == len(truth) - 1


def test_mean_scan_refuses_scans_of_other_beams():
    from rigcal.scan import mean_scan

    a = Scan.from_uniform(-1.0, 0.01, np.ones(10), 0.1, 30.0)
    b = Scan.from_uniform(-1.0, 0.02, np.ones(10), 0.1, 30.0)
    with pytest.raises(ValueError, match="beams differ"):
        mean_scan([a, b])
    with pytest.raises(ValueError, match="no scans"):
        mean_scan([])


def test_a_range_at_range_max_is_no_return_in_every_reader(tmp_path):
    """A driver's value for no return, read by the one rule of rigcal.scan: from a scan
    file (`rigcal solve`, `rigcal lines`) as from a sequence's scans.npz (the importers
    store it as inf: the same beams)."""
    from rigcal.recordings.sequence import read_sequence, write_sequence

    path = tmp_path / "scan.yaml"
    path.write_text(
        "schema_version: 1\nrange_min_m: 0.1\nrange_max_m: 30\n"
        "angle_min_rad: -0.1\nangle_increment_rad: 0.1\nranges_m: [2.0, 30.0, 29.999]\n"
    )
    scan = read_scan(path)
    np.testing.assert_array_equal(scan.valid, [True, False, True])
    assert np.isnan(scan.points[1]).all()
    seq = write_sequence(
        tmp_path / "seq",
        "s",
        [Scan.from_uniform(-0.1, 0.1, [2.0, 30.0, 29.999], 0.1, 30.0, 0.0)],
        [],
        None,
        {},
    )
    np.testing.assert_array_equal(read_sequence(seq).scans[0].valid, scan.valid)


def test_a_negative_step_names_the_clockwise_form(tmp_path):
    """A ROS LaserScan sweeping clockwise (angle_increment < 0) copied into a scan file: one
    line saying how the file states it (the clockwise key, angles negated)."""
    path = tmp_path / "cw.yaml"
    path.write_text(
        "schema_version: 1\nrange_min_m: 0.1\nrange_max_m: 30\n"
        "angle_min_rad: -0.5\nangle_increment_rad: -0.1\nranges_m: [1.0, 2.0, 3.0]\n"
    )
    with pytest.raises(InputError, match=r"cw.yaml: angle_increment_rad: got -0.1; expected a step > 0") as e:
        read_scan(path)
    assert "angle_min_rad 0.5 and angle_increment_rad 0.1, negated, with schema_version: 2" in str(e.value)
    cw = tmp_path / "cw2.yaml"
    cw.write_text(
        "schema_version: 2\nlaser: {clockwise: true}\nrange_min_m: 0.1\nrange_max_m: 30\n"
        "angle_min_rad: 0.5\nangle_increment_rad: 0.1\nranges_m: [1.0, 2.0, 3.0]\n"
    )
    scan = read_scan(cw)  # the same beams: -0.5, -0.6, -0.7 rad, in increasing order
    np.testing.assert_allclose(scan.angles_rad, [-0.7, -0.6, -0.5])
    np.testing.assert_allclose(scan.ranges_m, [3.0, 2.0, 1.0])
