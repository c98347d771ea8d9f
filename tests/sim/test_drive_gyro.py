"""The simulated gyroscope: its error model, and a drive's other streams unchanged by it."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from rigcal.cli.main import main
from rigcal.io.gyro import checked
from rigcal.recordings.sequence import read_sequence
from rigcal.sim.drive import (
    GYRO_BIAS_DEG_S,
    GYRO_NOISE_DEG_S_RT_HZ,
    GYRO_RATE_HZ,
    DriveSpec,
    Motion,
    gyro_rates,
    laser_stamps,
)
from rigcal.sim.world import BUILTIN


def test_the_gyro_turns_with_the_rig_up_to_its_bias_and_noise():
    """Over 25 ms steps the yaw it turned is the truth's plus bias x dt and the angle
    random walk (0.005 deg/s/sqrt(Hz)): the steps' errors less their mean are within 4 sigma
    of that noise (the bias walk is 1e-4 of it over a step); the mean is a bias of the
    model's size."""
    spec = DriveSpec(seed=4, duration_s=30.0, gyro=True)
    motion = Motion(BUILTIN["cubicle-loop"](), spec)
    t, r = gyro_rates(motion, spec)
    assert np.median(np.diff(t)) == pytest.approx(1.0 / GYRO_RATE_HZ)
    gyro = checked(t, r, "simulated gyroscope")
    stamps = laser_stamps(motion, spec)[1:]
    err = gyro.yaw_between(stamps) - np.diff(motion.poses(stamps)[:, 2])
    dt = float(np.median(np.diff(stamps)))
    bias = float(np.mean(err)) / dt
    assert abs(np.degrees(bias)) < 4 * GYRO_BIAS_DEG_S
    sigma = np.radians(GYRO_NOISE_DEG_S_RT_HZ) * np.sqrt(dt)
    assert np.abs(err - bias * dt).max() < 5 * sigma
    assert 0.8 < np.std(err) / sigma < 1.2


def test_a_drive_with_the_gyro_has_the_same_other_files(tmp_path):
    args = [
        "simulate",
        "world",
        "--world",
        "corridor-loop",
        "--duration-s",
        "3",
        "--seed",
        "5",
        "--no-images",
    ]
    assert main([*args, "--wheel-odometry", "-o", str(tmp_path / "plain")]) == 0
    assert main([*args, "--wheel-odometry", "--gyro", "-o", str(tmp_path / "gyro")]) == 0
    for f in ("scans.npz", "groundtruth.tum", "odometry.tum", "images.csv", "rig.yaml"):
        assert (tmp_path / "plain" / f).read_bytes() == (tmp_path / "gyro" / f).read_bytes(), f
    doc = yaml.safe_load((tmp_path / "gyro" / "sequence.yaml").read_text())
    assert doc["schema_version"] == 4
    assert doc["source"]["gyro"]["noise_deg_s_rt_hz"] == GYRO_NOISE_DEG_S_RT_HZ
    seq = read_sequence(tmp_path / "gyro")
    assert seq.gyro is not None
    assert len(seq.gyro.stamps_s) == 3 * GYRO_RATE_HZ
    assert not read_sequence(tmp_path / "plain").has_gyro
