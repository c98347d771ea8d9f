"""Wheel odometry in localization: ICP's initial guess, its gate, the odom method, the KF."""

from __future__ import annotations

import json

import numpy as np
import pytest

from rigcal.cli.main import main
from rigcal.localize.odometry import agrees_with_wheels
from rigcal.recordings.sequence import read_sequence


@pytest.fixture(scope="module")
def sparse(tmp_path_factory):
    """A lap of the cubicle loop scanned once a second (scans ~1 m and up to ~60 deg
    apart, as the subsampled logs of SLAM papers), with simulated wheel odometry."""
    out = tmp_path_factory.mktemp("wheel") / "sparse"
    args = ["simulate", "world", "--world", "cubicle-loop", "-o", str(out), "--no-images"]
    args += ["--laser-rate-hz", "1", "--wheel-odometry"]
    assert main(args) == 0
    return out


def _summary(seq, out, capsys, *extra):
    assert main(["localize", str(seq), "-o", str(out), "--json", *extra]) == 0
    return json.loads(capsys.readouterr().out)


def test_icp_starts_from_the_wheel_odometry_on_sparse_scans(sparse, tmp_path, capsys):
    seq = read_sequence(sparse)
    assert seq.odometry is not None
    np.testing.assert_allclose(seq.odometry.T_base_laser, [0.2, 0.0, 0.0])
    used = _summary(sparse, tmp_path / "use", capsys, "--method", "icp,odom")
    ignored = _summary(sparse, tmp_path / "ign", capsys, "--method", "icp", "--wheel-odometry", "ignore")
    assert used["config"]["wheel_odometry"] == "used"
    assert ignored["config"]["wheel_odometry"] == "ignored"
    icp_used, icp_ignored = used["methods"]["icp"], ignored["methods"]["icp"]
    assert icp_used["wheel_odometry_steps"] == len(seq.scans) - 1
    assert icp_ignored["wheel_odometry_steps"] == 0
    # From the previous motion ICP loses the way in the turns; from the wheels it does not,
    # and it is better than the wheels alone (their scale error and heading drift).
    ate_used = icp_used["metrics"]["ate_rmse_m"]
    assert ate_used < 0.05
    assert icp_ignored["metrics"]["ate_rmse_m"] > 5 * ate_used
    assert used["methods"]["odom"]["metrics"]["ate_rmse_m"] > 2 * ate_used


def test_odom_needs_wheel_odometry(tmp_path, capsys):
    seq = tmp_path / "seq"
    args = ["simulate", "world", "--world", "cubicle-loop", "-o", str(seq), "--no-images"]
    assert main([*args, "--duration-s", "3", "--laser-rate-hz", "5"]) == 0
    assert main(["localize", str(seq), "--method", "odom", "-o", str(tmp_path / "o")]) == 3
    err = capsys.readouterr().err
    assert "no wheel odometry (key 'odometry' of sequence.yaml); method 'odom' needs it" in err


def test_the_gate_takes_icp_within_the_wheels_error_bound():
    wheel = np.array([1.0, 0.0, np.radians(60.0)])
    assert agrees_with_wheels(wheel + np.array([0.15, -0.05, np.radians(5.0)]), wheel)
    assert not agrees_with_wheels(wheel + np.array([0.5, 0.0, 0.0]), wheel)  # slid along a pattern
    assert not agrees_with_wheels(wheel + np.array([0.0, 0.0, np.radians(20.0)]), wheel)


def test_every_method_names_its_shared_stages():
    from rigcal.localize.pipeline import METHODS, SHARED_STAGES

    assert set(SHARED_STAGES) == set(METHODS)
