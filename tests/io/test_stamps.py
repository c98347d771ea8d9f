"""The stamp repair of real logs (rigcal.io.stamps) and the importers' --stamps."""

from __future__ import annotations

import numpy as np
import pytest

from rigcal.errors import InputError
from rigcal.io.stamps import repair_stamps
from rigcal.recordings.laser_text import read_csv_laser, read_radlocc_laser


def test_increasing_stamps_are_left_alone():
    r = repair_stamps([0.0, 0.1, 0.2, 0.3], "log")
    np.testing.assert_array_equal(r.stamps_s, [0.0, 0.1, 0.2, 0.3])
    assert r.repaired == 0
    assert r.gaps == 0
    assert r.message("scan stamps") is None


def test_equal_stamps_of_low_precision_printing_are_spread_over_the_period():
    # 40 Hz scans printed to 0.1 s: runs of 4 equal stamps.
    true = 100.0 + 0.025 * np.arange(40)
    printed = np.floor(true * 10 + 1e-9) / 10
    r = repair_stamps(printed, "log")
    assert r.equal == 30
    assert r.backward == 0
    assert (np.diff(r.stamps_s) > 0).all()
    np.testing.assert_allclose(r.stamps_s, true, atol=1e-9)
    assert "repaired 30 scan stamps (30 equal to the previous one)" in r.message("scan stamps")


def test_a_step_back_and_a_stamp_that_jumped_ahead_are_placed_between_neighbours():
    back = repair_stamps([0.0, 0.1, 0.2, 0.09, 0.4, 0.5], "log")
    np.testing.assert_allclose(back.stamps_s, [0.0, 0.1, 0.2, 0.3, 0.4, 0.5])
    assert back.backward == 1
    assert back.equal == 0
    ahead = repair_stamps([0.0, 0.1, 0.2, 0.9, 0.4, 0.5], "log")
    np.testing.assert_allclose(ahead.stamps_s, [0.0, 0.1, 0.2, 0.3, 0.4, 0.5])
    # A clock stepping back 0.11 s and going on from there: the fewest stamps move.
    clock = repair_stamps([0.0, 0.1, 0.2, 0.09, 0.19, 0.29, 0.39], "log")
    assert (np.diff(clock.stamps_s) > 0).all()
    assert clock.backward == 2
    assert clock.max_shift_s <= 0.11 + 0.1  # the step and a period
    # Trailing equal stamps continue at the log's rate.
    tail = repair_stamps([0.0, 0.1, 0.2, 0.2, 0.2], "log")
    np.testing.assert_allclose(tail.stamps_s, [0.0, 0.1, 0.2, 0.3, 0.4])


def test_gaps_are_reported_not_filled():
    r = repair_stamps([0.0, 0.1, 0.2, 3.0, 3.1], "log")
    np.testing.assert_array_equal(r.stamps_s, [0.0, 0.1, 0.2, 3.0, 3.1])
    assert r.gaps == 1
    assert r.longest_gap_s == pytest.approx(2.8)
    assert "1 gap(s) longer than 5 scan periods" in r.message("scan stamps")


@pytest.mark.parametrize(
    ("stamps", "mode", "match"),
    [
        ([0.0, 0.1, 0.1], "strict", r"log: line 3: got stamp 0.1; expected a stamp after the previous one"),
        ([0.0, 0.1, 0.05], "strict", r"line 3: got stamp 0.05"),
        ([0.0, 50.0, 51.0, 52.0, 0.1, 0.2], "repair", r"broken clock"),
        ([0.0, float("nan"), 0.2], "repair", r"log: line 2: got stamp nan; expected a finite stamp"),
        ([0.0, 0.1], "lenient", r"--stamps: got 'lenient'; expected one of repair, strict"),
    ],
)
def test_refused_stamps(stamps, mode, match):
    with pytest.raises(InputError, match=match):
        repair_stamps(stamps, "log", mode, lines=list(range(1, len(stamps) + 1)))


def test_radlocc_and_csv_logs_repair_or_refuse(tmp_path):
    p = tmp_path / "laser.txt"
    p.write_text("".join(f"{t} -0.1 0.1 0.1 2 2 2\n" for t in (1.0, 1.1, 1.1, 1.3)))
    scans = read_radlocc_laser(p)
    assert [s.stamp_s for s in scans] == pytest.approx([1.0, 1.1, 1.2, 1.3])
    with pytest.raises(InputError, match=r"laser.txt: stamp: line 3: got stamp 1.1; expected a stamp after"):
        read_radlocc_laser(p, stamps="strict")
    c = tmp_path / "l.csv"
    rows = [f"{t},{a},2" for t in (1.0, 1.1, 0.95, 1.3) for a in (0.0, 0.1)]
    c.write_text("stamp_s,angle_rad,range_m\n" + "\n".join(rows) + "\n")
    assert [s.stamp_s for s in read_csv_laser(c)] == pytest.approx([1.0, 1.1, 1.2, 1.3])
    with pytest.raises(InputError, match=r"l.csv: stamp: line 6: got stamp 0.95"):
        read_csv_laser(c, stamps="strict")


# --- the unit of a stream's stamps, from its own steps and magnitude --------------------------
@pytest.mark.parametrize(
    ("stamps", "scans"),
    [
        (np.arange(0.0, 3600.0, 0.02), (100.0, 160.0)),  # an hour of 50 Hz odometry, a minute of scans
        (1.7e9 + np.arange(0.0, 3600.0, 0.02), (1.7e9 + 10.0, 1.7e9 + 13.6)),  # 1000x the scans' span
        (np.arange(0.0, 60.0, 5.0), (0.0, 60.0)),  # a slow logger: a pose every 5 s
    ],
)
def test_odometry_far_longer_than_the_scans_is_seconds(stamps, scans):
    from rigcal.io.wheel_odometry import checked

    odom = checked(stamps, np.zeros((len(stamps), 3)), (0.0, 0.0, 0.0), "odom.tum", np.array(scans))
    assert len(odom.stamps_s) == len(stamps)


@pytest.mark.parametrize(
    ("stamps", "match"),
    [
        (np.arange(0.0, 60.0, 0.02) * 1e3, r"got 'a pose every 20 \(median\)'; expected seconds: wheel"),
        ((1.7e9 + np.arange(0.0, 60.0, 0.02)) * 1e3, r"got 1700000059980.0; expected seconds .*milliseconds"),
        ((1.7e9 + np.arange(0.0, 60.0, 0.02)) * 1e9, r"got 1.7.*e\+18; .*this looks like nanoseconds"),
    ],
)
def test_odometry_in_another_unit_is_refused_by_its_own_stamps(stamps, match):
    from rigcal.io.wheel_odometry import checked

    with pytest.raises(InputError, match=rf"^odom.tum: odometry stamps: {match}"):
        checked(stamps, np.zeros((len(stamps), 3)), (0.0, 0.0, 0.0), "odom.tum", np.array([0.0, 60.0]))


@pytest.mark.parametrize("hz", [200, 500])
def test_fast_odometry_in_milliseconds_from_its_start_is_refused_beside_its_scans(hz):
    """Steps under 10 pass for seconds by themselves; a pose every 5 (or 2) "seconds" over
    about 1000x the scans' span is two things real odometry is not at once."""
    from rigcal.io.wheel_odometry import checked

    t = np.round(np.arange(0.0, 60.0, 1.0 / hz) * 1e3)  # a logger's integer milliseconds
    with pytest.raises(
        InputError, match=rf"^odom.tum: odometry stamps: got 'a pose every {1000 // hz:g} \(median\)"
    ):
        checked(t, np.zeros((len(t), 3)), (0.0, 0.0, 0.0), "odom.tum", np.array([0.0, 60.0]))
