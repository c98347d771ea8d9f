"""A simulated drive's standstill at the start (``DriveSpec.start_still_s``, ``rigcal simulate
world --start-still``): every sensor covers it, the motion after it is the drive's without
it, and a drive without one is the same as before to the bit."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest
import yaml

from rigcal.cli.main import main
from rigcal.errors import InputError
from rigcal.io.gyro import checked
from rigcal.recordings.sequence import read_sequence
from rigcal.sim.drive import (
    DriveSpec,
    Motion,
    camera_stamps,
    gyro_bias,
    gyro_rates,
    laser_stamps,
    wheel_odometry,
)
from rigcal.sim.world import BUILTIN

# sha256 of the sensors' arrays of 40 s drives (seed 3; the cubicles driven twice) and of a
# written 2 s drive's files, as written before the standstill existed (its default 0
# changes nothing).
MOTION_SHA256 = {
    "corridor-loop": "182169c5750855add0a835040519d30b6dc4f776e86bc1ba084b0baf59d707a0",
    "cubicle-loop": "1dc5f70d54c1cad40d1ef9f42154e07c8da3bd67666ff73c8ccdaa609739e365",
}
FILE_SHA256 = {
    "groundtruth.tum": "98d2144e2f9c318fbd1963df25bf240665aed72a6c8327034db84b209e9e4a56",
    "gyro.csv": "c60f9fb1570490768d9a172f1f06b63e35b381ecd7f8b141b7214aaed91980a0",
    "odometry.tum": "ac5b48c253fb706e8d74a6a2529c39563cbcf92012876b3b20e88103e06eeb09",
    "scans.npz": "ce0a8d928ac6b934c01ae628f2a476bf797b34dd765aa4392a1ee2aebb86c326",
}


@pytest.mark.parametrize("name", sorted(MOTION_SHA256))
def test_a_drive_without_a_standstill_is_as_before_to_the_bit(name):
    spec = DriveSpec(seed=3, duration_s=40.0, laps=2 if name == "cubicle-loop" else 1)
    assert spec.start_still_s == 0.0
    m = Motion(BUILTIN[name](), spec)
    h = hashlib.sha256()
    arrays = (
        m.t,
        m.xy,
        m.yaw,
        laser_stamps(m, spec),
        camera_stamps(m, spec),
        *gyro_rates(m, spec),
        *wheel_odometry(m, spec),
    )
    for a in arrays:
        h.update(np.ascontiguousarray(a).tobytes())
    assert h.hexdigest() == MOTION_SHA256[name]


def test_a_written_drive_without_a_standstill_is_as_before_to_the_bit(tmp_path):
    args = ["simulate", "world", "--world", "corridor-loop", "--duration-s", "2", "--seed", "5"]
    assert main([*args, "--wheel-odometry", "--gyro", "--no-images", "-o", str(tmp_path / "d")]) == 0
    for f, digest in FILE_SHA256.items():
        assert hashlib.sha256((tmp_path / "d" / f).read_bytes()).hexdigest() == digest, f
    doc = yaml.safe_load((tmp_path / "d" / "sequence.yaml").read_text())
    assert "start_still_s" not in doc["source"]


def test_the_rig_stands_at_its_first_pose_then_drives_as_without_the_standstill():
    world = BUILTIN["cubicle-loop"]()
    plain = DriveSpec(seed=4, duration_s=10.0)
    still = DriveSpec(seed=4, duration_s=10.0, start_still_s=3.0)
    a, b = Motion(world, plain), Motion(world, still)
    assert b.duration_s == pytest.approx(a.duration_s + 3.0)
    t = np.linspace(0.0, 3.0, 31)
    np.testing.assert_array_equal(b.poses(t), np.repeat(a.poses(np.zeros(1)), len(t), axis=0))
    t = np.linspace(0.0, 10.0, 101)
    np.testing.assert_allclose(b.poses(t + 3.0), a.poses(t), atol=1e-12)
    # Every sensor covers the standstill and the 10 s of motion after it.
    scans = laser_stamps(b, still)
    assert scans[0] == 0.0
    assert 12.9 < scans[-1] < 13.0
    assert camera_stamps(b, still)[0] < 0.1
    assert camera_stamps(b, still)[-1] > 12.8
    wheel_t, _ = wheel_odometry(b, still)
    assert wheel_t[0] == 0.0
    assert wheel_t[-1] > 12.9
    gyro_t, _rates = gyro_rates(b, still)
    assert gyro_t[0] == 0.0
    assert gyro_t[-1] > 12.9


def test_the_gyro_reads_its_bias_while_the_rig_stands():
    """Over the standstill the true turn is 0: the gyro's mean rate is its bias (constant and
    walk) to within its white noise's mean (0.005 deg/s/sqrt(Hz) over 5 s: 0.0022 deg/s)."""
    spec = DriveSpec(seed=6, duration_s=2.0, start_still_s=5.0, gyro=True)
    motion = Motion(BUILTIN["corridor-loop"](), spec)
    t, rates = gyro_rates(motion, spec)
    bias_t, bias = gyro_bias(motion, spec)
    np.testing.assert_array_equal(bias_t, t)
    standing = t < 5.0
    assert abs(np.degrees(np.mean(rates[standing] - bias[standing]))) < 4 * 0.005 / np.sqrt(5.0)
    assert abs(np.degrees(np.mean(rates[standing]))) > 0.0  # a bias to learn (seed 6: 0.01 deg/s or more)
    checked(t, rates, "simulated gyroscope")


def test_simulate_world_start_still_writes_the_standstill(tmp_path):
    out = tmp_path / "still"
    args = ["simulate", "world", "--world", "corridor-loop", "--duration-s", "1", "--seed", "2"]
    assert main([*args, "--start-still", "2", "--gyro", "--no-images", "-o", str(out)]) == 0
    doc = yaml.safe_load((out / "sequence.yaml").read_text())
    assert doc["source"]["start_still_s"] == 2.0
    seq = read_sequence(out)
    assert seq.gyro is not None
    assert seq.gyro.stamps_s[-1] > 2.9
    assert len(seq.scans) == 120
    truth = np.loadtxt(out / "groundtruth.tum")
    standing = truth[truth[:, 0] <= 2.0]
    assert len(standing) == 81
    assert np.ptp(standing[:, 1:], axis=0).max() == 0.0
    assert np.ptp(truth[:, 1:3], axis=0).max() > 0.3  # then it moves (0.5 m/s into its first turn)


@pytest.mark.parametrize("value", [-1.0, float("nan"), 4000.0])
def test_a_bad_standstill_is_refused_naming_it(value):
    with pytest.raises(InputError, match="start_still_s"):
        DriveSpec(start_still_s=value)


def test_simulate_world_refuses_a_negative_standstill(tmp_path, capsys):
    code = main(["simulate", "world", "--start-still", "-1", "--no-images", "-o", str(tmp_path / "x")])
    assert code == 2
    err = capsys.readouterr().err
    assert "--start-still" in err
    assert "-1" in err
    assert not (tmp_path / "x").exists()
