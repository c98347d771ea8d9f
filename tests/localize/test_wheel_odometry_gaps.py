"""Wheel odometry with a gap (a logger paused): its motion across the gap is no
measurement, with one warning; it starts ICP there unless the scans contradict it (a
robot parked an hour, its base rebooted meanwhile: ICP's own fit is kept), and method
odom holds its pose."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from rigcal.cli.main import main
from rigcal.io.wheel_odometry import across_gaps, checked, laser_motions
from room_scans import carmen_drive

PARKED_S = 3600.0


def test_steps_across_a_gap_take_no_motion_from_the_odometry():
    t = np.r_[np.arange(0.0, 2.0, 0.05), 3600.0 + np.arange(0.0, 2.0, 0.05)]
    poses = np.column_stack(
        [np.r_[np.arange(40) * 0.025, -5.0 + np.arange(40) * 0.025], np.zeros(80), np.zeros(80)]
    )
    od = checked(t, poses, (0.0, 0.0, 0.0), "odom")
    scans = np.array([0.5, 1.0, 1.9, 3600.5, 3601.0])
    assert across_gaps(od, scans).tolist() == [False, False, True, False]
    steps = laser_motions(od, scans)
    assert np.isnan(steps[2]).all()
    np.testing.assert_allclose(steps[[0, 1, 3], 0], [0.25, 0.45, 0.25], atol=1e-9)


@pytest.fixture(scope="module")
def parked_log(tmp_path_factory):
    base = tmp_path_factory.mktemp("parked")
    # After the hour parked the base was rebooted: its odometry starts again at -5 m, 1 rad.
    lines = carmen_drive(100.0, 0.0, 0.0, 0.0) + carmen_drive(102.0 + PARKED_S, 1.0, -5.0, 1.0)
    log = base / "parked.log"
    log.write_text("\n".join(line for _, line in sorted(lines)) + "\n")
    assert main(["import-carmen", str(log), "-o", str(base / "seq")]) == 0
    return base / "seq"


def test_localize_does_not_integrate_the_odometry_across_an_hour_parked(parked_log, tmp_path, capsys):
    capsys.readouterr()
    out = tmp_path / "out"
    assert main(["localize", str(parked_log), "--method", "icp,odom", "-o", str(out)]) == 0
    err = capsys.readouterr().err
    (warning,) = [line for line in err.splitlines() if "pauses" in line]
    assert warning.startswith("WARNING: rigcal.localize.pipeline: the wheel odometry pauses for over 1 s ")
    assert "between 1 pair(s) of scans (the longest pause 3.6e+03 s)" in warning
    doc = yaml.safe_load((out / "summary.yaml").read_text())
    # ICP is right across the gap (the scans agree), as it is without the odometry.
    assert doc["methods"]["icp"]["metrics"]["end_position_error_m"] < 0.02
    assert doc["methods"]["odom"]["odometry_gaps_held"] == 1
    odom = np.loadtxt(out / "odom" / "trajectory.tum")
    assert np.abs(odom[:, 1]).max() < 2.0  # no 5 m jump from the rebooted base


# An L-shaped room (m): no symmetry a wrong turn could fit.
_ROOM = np.array([[-2.0, -1.5], [4.0, -1.5], [4.0, 1.0], [1.5, 1.0], [1.5, 3.5], [-2.0, 3.5]])


def _scan_at(x: float, y: float, yaw: float, t: float):  # type: ignore[no-untyped-def]
    """The room scanned from (x, y, yaw): 271 beams over 270 deg, no noise."""
    from rigcal.scan import Scan
    from rigcal.sim.raycast import beam_angles, cast_scan

    walls = np.stack([_ROOM, np.roll(_ROOM, -1, axis=0)], axis=1)  # (6, 2, 2) segments
    c, s = np.cos(yaw), np.sin(yaw)
    local = (walls - np.array([x, y])) @ np.array([[c, s], [-s, c]]).T
    angle_min, step, angles = beam_angles(270.0, 1.0)
    return Scan.from_uniform(angle_min, step, cast_scan(local.reshape(-1, 4), angles, 30.0), 0.05, 30.0, t)


def _across_a_gap(candidate: np.ndarray | None):  # type: ignore[no-untyped-def]
    """Five scans 5 cm apart, then the rig 0.6 m on and turned 90 deg left while the
    logger paused, then one more scan: the step across the pause matched from ICP's own
    last motion, and from ``candidate`` as well (the odometry's motion across the gap)."""
    from rigcal.localize.icp import IcpParams
    from rigcal.localize.odometry import icp_odometry

    poses = [(0.05 * k, 0.0, 0.0) for k in range(5)] + [(0.8, 0.2, np.pi / 2)]
    scans = [_scan_at(*p, t=float(k)) for k, p in enumerate(poses)]
    gap = np.full((len(scans) - 1, 3), np.nan)
    if candidate is not None:
        gap[-1] = candidate
    od = icp_odometry(scans, IcpParams(method="point-to-line"), gap_guess=gap)
    return od, np.array(poses)


def test_across_a_gap_the_odometrys_motion_starts_icp_unless_the_scans_contradict_it():
    """A logger paused while the base counted on: the odometry's motion across the gap
    (off by 3 cm and 2 deg, as wheels are) starts the fit that matches the scans, where
    ICP's own last motion (5 cm straight on) slides into a wrong turn. A base rebooted
    meanwhile gives a motion that is nonsense (5 m back, 1 rad): the scans contradict it
    (ICP's own fit agrees with them on far more returns), and ICP's own fit is kept."""
    true_step = np.array([0.8 - 0.2, 0.2, np.pi / 2])  # in the last scan's frame: yaw 0 there
    own, truth = _across_a_gap(None)
    err_own = own.poses[-1] - truth[-1]
    assert np.hypot(*err_own[:2]) > 0.1 or abs(err_own[2]) > np.radians(5.0)  # the own start fails
    right, _ = _across_a_gap(true_step + np.array([0.03, -0.02, np.radians(2.0)]))
    err = right.poses[-1] - truth[-1]
    assert np.hypot(*err[:2]) < 0.01
    assert abs(err[2]) < np.radians(0.2)
    assert right.gap_kept == 1
    # A small true motion across the gap: ICP's own start finds it, the rebooted base's does not.
    from rigcal.localize.icp import IcpParams
    from rigcal.localize.odometry import icp_odometry

    poses = [(0.05 * k, 0.0, 0.0) for k in range(6)]
    scans = [_scan_at(*p, t=float(k)) for k, p in enumerate(poses)]
    gap = np.full((5, 3), np.nan)
    gap[-1] = (-5.0, 0.0, 1.0)
    od = icp_odometry(scans, IcpParams(method="point-to-line"), gap_guess=gap)
    assert od.gap_kept == 0
    np.testing.assert_allclose(od.poses[-1], poses[-1], atol=1e-3)
