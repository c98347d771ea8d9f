"""The gyroscope's bias learned over a drive's standstill at its start, before the rig moves:
simulated scans (rigcal's ICP on them) and the simulated gyro, as ``rigcal localize --gyro
use`` fuses them."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from rigcal.localize import kalman
from rigcal.localize.pipeline import gyro_measurements
from rigcal.localize.streams import open_streams
from rigcal.sim.drive import DriveSpec, Motion, gyro_bias, write_drive
from rigcal.sim.world import BUILTIN


@pytest.fixture(scope="module")
def standing_start(tmp_path_factory):
    """3 s standing, then 1 s of the corridor loop (seed 11: a simulated bias of -0.083
    deg/s, near 2 sigma of the simulated gyro's 0.05); ICP's steps and the gyro's."""
    folder = tmp_path_factory.mktemp("still") / "seq"
    spec = DriveSpec(seed=11, duration_s=1.0, start_still_s=3.0, gyro=True, images=False)
    world = BUILTIN["corridor-loop"]()
    write_drive(world, spec, str(folder))
    streams = open_streams(folder)
    od = streams.laser_odometry()
    assert od.covariance is not None
    ms = kalman.increments(streams.scan_stamps_s, od.poses, od.covariance, source="icp")
    assert streams.gyro is not None
    t, bias = gyro_bias(Motion(world, spec), spec)
    return (
        ms,
        gyro_measurements(streams.gyro, streams.scan_stamps_s, kalman.KfParams()),
        float(np.interp(3.0, t, bias)),
    )


@pytest.mark.parametrize("mode", ["weighted", "icp-first"])
def test_the_bias_is_learned_over_the_standstill_before_the_rig_moves(standing_start, mode):
    """The standstill's 3 s of gyro steps are found still (:func:`kalman._still`, ICP's steps
    as slow as a standing rig's), and the bias comes out within 3 of its own sigmas of the
    simulated one, that sigma a twentieth of the prior's (0.2 deg/s; measured 0.006 deg/s:
    the gyro's own noise over 3 s)."""
    icp, gyro, simulated = standing_start
    assert np.degrees(abs(simulated)) > 0.05
    r = kalman.run_filter(icp + gyro, kalman.KF_MODES[mode])
    assert 2.8 <= r.gyro_still_s <= 3.1
    assert r.gyro_bias_sigma < kalman.GYRO_BIAS_SIGMA / 20
    assert abs(r.gyro_bias - simulated) < 3 * r.gyro_bias_sigma


def test_against_icps_turn_the_standstill_tells_the_bias_less(standing_start):
    """Learned against the turn ICP measured over the standstill (``gyro_zero_turn`` off)
    rather than against none, the bias's sigma is several times larger: ICP's yaw walks by
    its steps' noise while the rig stands (measured 0.030 against 0.006 deg/s)."""
    icp, gyro, _ = standing_start
    zero = kalman.run_filter(icp + gyro, kalman.KF_MODES["weighted"])
    against_icp = kalman.run_filter(
        icp + gyro, dataclasses.replace(kalman.KF_MODES["weighted"], gyro_zero_turn=False)
    )
    assert against_icp.gyro_bias_sigma > 3 * zero.gyro_bias_sigma


def test_without_the_standstill_the_bias_stays_open(standing_start):
    """The same gyro steps from the moment the rig moves: nothing is still, the bias keeps
    nearly its prior's sigma (the pose's updates narrow it a little through their
    correlation) and its estimate stays far from the simulated one."""
    icp, gyro, simulated = standing_start
    moving = [m for m in icp + gyro if m.t0 >= 3.0]
    r = kalman.run_filter(moving, kalman.KF_MODES["weighted"])
    assert r.gyro_still_s == 0.0
    assert r.gyro_bias_sigma > 0.9 * kalman.GYRO_BIAS_SIGMA
    assert abs(r.gyro_bias - simulated) > 0.5 * abs(simulated)
