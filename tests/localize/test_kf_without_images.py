"""The Kalman filter on a log without images (rigcal localize --method kf on a CARMEN
import): ICP's steps and the wheel odometry's fused, the path anchored
(KfParams.anchored); the wheels' step across a gap measured only where ICP measured
nothing there."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from rigcal.cli.main import main
from rigcal.io.wheel_odometry import checked
from rigcal.localize import kalman
from rigcal.localize.pipeline import wheel_measurements
from room_scans import carmen_drive


@pytest.fixture(scope="module")
def paused_log(tmp_path_factory):
    """Two drives 30 s apart; the base's odometry carried on over the pause (no reboot),
    then the rebooted case: its odometry starts again at -5 m, 1 rad."""
    base = tmp_path_factory.mktemp("paused")
    out = {}
    for name, (x0, yaw) in {"kept": (1.0, 0.0), "rebooted": (-5.0, 1.0)}.items():
        lines = carmen_drive(100.0, 0.0, 0.0, 0.0) + carmen_drive(132.0, 1.0, x0, yaw)
        log = base / f"{name}.log"
        log.write_text("\n".join(line for _, line in sorted(lines)) + "\n")
        assert main(["import-carmen", str(log), "-o", str(base / name)]) == 0
        out[name] = base / name
    return out


@pytest.mark.parametrize("name", ["kept", "rebooted"])
def test_kf_runs_on_icp_and_the_wheels_without_images(paused_log, tmp_path, name):
    out = tmp_path / "out"
    assert main(["localize", str(paused_log[name]), "--method", "icp,kf", "-o", str(out)]) == 0
    doc = yaml.safe_load((out / "summary.yaml").read_text())
    kf = doc["methods"]["kf"]
    assert kf["inputs"].startswith("ICP and the wheel odometry")
    assert kf["vo_measurements"] == 0
    assert kf["icp_measurements"] > 0
    assert kf["wheel_measurements"] > 0
    # The scans agree with the truth across the pause; a rebooted base's 5 m is not taken.
    assert kf["metrics"]["end_position_error_m"] < 0.05
    path = np.loadtxt(out / "kf" / "trajectory.tum")
    assert np.abs(path[:, 1:3]).max() < 2.5


def test_the_wheels_step_across_a_gap_is_measured_only_where_icp_measured_nothing():
    t = np.r_[np.arange(0.0, 2.0, 0.05), 30.0 + np.arange(0.0, 2.0, 0.05)]
    x = np.r_[np.arange(40) * 0.025, 1.0 + np.arange(40) * 0.025]
    od = checked(t, np.column_stack([x, np.zeros(80), np.zeros(80)]), (0.0, 0.0, 0.0), "odom")
    scans = np.array([0.5, 1.0, 1.9, 30.5, 31.0])
    icp_cov = np.stack([np.eye(3) * 1e-6] * 5)
    measured = wheel_measurements(od, scans, icp_cov)
    assert [(m.t0, m.t1) for m in measured] == [(0.5, 1.0), (1.0, 1.9), (30.5, 31.0)]
    icp_cov[3] = np.nan  # ICP measured nothing across the gap: the odometry's motion kept
    measured = wheel_measurements(od, scans, icp_cov)
    assert [(m.t0, m.t1) for m in measured] == [(0.5, 1.0), (1.0, 1.9), (1.9, 30.5), (30.5, 31.0)]
    np.testing.assert_allclose(measured[2].motion, [1.0 + 0.5 * 0.025 * 20 - 0.95, 0.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(measured[2].covariance, kalman.rate_covariance(kalman.WHEEL_SIGMAS, 28.6))
