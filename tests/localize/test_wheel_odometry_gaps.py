"""Wheel odometry with a gap (a robot parked an hour with its logger paused, its base
rebooted meanwhile): no motion is taken from the odometry across the gap, with one warning;
ICP starts from its own last motion there, method odom holds its pose."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from rigcal.cli.main import main
from rigcal.io.wheel_odometry import across_gaps, checked, laser_motions
from room_scans import room_scan

PARKED_S = 3600.0


def _drive(t0: float, x0: float, odom_x0: float, odom_yaw: float) -> list[tuple[float, str]]:
    """2 s at 0.5 m/s: ODOM lines at 20 Hz, FLASER lines at 10 Hz (laser pose = truth)."""
    out = []
    for k in range(40):
        t, x = t0 + 0.05 * k, x0 + 0.025 * k
        ox = odom_x0 + 0.025 * k
        xy = f"{ox * np.cos(odom_yaw):.4f} {ox * np.sin(odom_yaw):.4f}"
        out.append((t, f"ODOM {xy} {odom_yaw} 0.5 0 0 {t:.6f} h {t:.6f}"))
        if k % 2 == 0:
            r = " ".join(f"{v:.3f}" for v in room_scan(x, 0.0).ranges_m)
            ts = t + 0.001
            out.append((ts, f"FLASER 181 {r} {x:.4f} 0 0 {x:.4f} 0 0 {ts:.6f} h {ts:.6f}"))
    return out


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
    lines = _drive(100.0, 0.0, 0.0, 0.0) + _drive(102.0 + PARKED_S, 1.0, -5.0, 1.0)
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
