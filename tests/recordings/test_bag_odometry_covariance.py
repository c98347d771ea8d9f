"""nav_msgs/Odometry covariances as drivers fill them: all zeros (none given), -1 (REP 103
/ sensor_msgs' "unknown"), a constant, NaN. rigcal does not read them: the wheel
odometry's poses are imported alike, without a warning, and the Kalman filter weighs the
wheels by its own noise model (kalman.WHEEL_SIGMAS, recorded in the run's summary), so no
covariance in a bag can make the filter trust the wheels blindly or not at all."""

from __future__ import annotations

import numpy as np
import pytest
from test_bag_odometry import _odometry_bag

from rigcal.cli.main import main


def _diag(v: float) -> np.ndarray:
    return np.diag(np.full(6, v)).ravel()


COVARIANCES = {
    "zeros": np.zeros(36),
    "unknown": np.full(36, -1.0),
    "unknown-first": np.r_[-1.0, np.zeros(35)],
    "constant": _diag(1e-3),
    "huge": _diag(1e9),
    "nan": np.full(36, np.nan),
}


@pytest.mark.parametrize("name", sorted(COVARIANCES))
def test_the_odometry_imports_alike_whatever_its_covariance(tmp_path, capsys, name):
    stamps = [0.9, 1.4, 1.9, 2.4]
    imported = {}
    for label, cov in {"zeros": np.zeros(36), name: COVARIANCES[name]}.items():
        bag = _odometry_bag(tmp_path / f"{label}.b2", 2, stamps, covariance=cov)
        out = tmp_path / f"{label}.seq"
        argv = ["import-bag", str(bag), "--scan-topic", "/scan", "--image-topic", "/cam/image"]
        assert main([*argv, "--odometry-topic", "/odom", "-o", str(out)]) == 0
        assert "warning" not in capsys.readouterr().err
        imported[label] = (out / "odometry.tum").read_bytes()
    assert imported[name] == imported["zeros"]
