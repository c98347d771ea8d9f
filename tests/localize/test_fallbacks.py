"""The fallbacks of an IASM or H-IASM step (H-IASM -> IASM -> VO -> ICP) on a simulated drive."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from rigcal.geometry import pose_of, se2
from rigcal.io.trajectory import read_tum
from rigcal.localize import image_matching
from rigcal.localize.iasm import Matches
from rigcal.localize.image_matching import ScanMatcher
from rigcal.localize.pipeline import planar_at
from rigcal.localize.streams import open_streams


@pytest.fixture
def failing(drive, monkeypatch):
    """The drive's streams with every image step failing (no correspondences), and the
    true motion between images 10 and 11."""
    monkeypatch.setattr(image_matching, "iasm_step", lambda *a, **k: (None, Matches.none()))
    monkeypatch.setattr(ScanMatcher, "try_hiasm", lambda *a, **k: (None, None, "no correspondences"))
    streams = open_streams(drive)
    gt = planar_at(read_tum(drive / "groundtruth.tum"), streams.image_stamps_s)
    return streams, pose_of(np.linalg.inv(se2(gt[10])) @ se2(gt[11]))


@pytest.mark.parametrize("degenerate", [False, True])
def test_hiasm_falls_back_to_vo_only_where_the_laser_odometry_is_degenerate(failing, monkeypatch, degenerate):
    streams, true = failing
    monkeypatch.setattr(ScanMatcher, "odometry_constrained", lambda self, i1, i2: not degenerate)
    sm = ScanMatcher(streams, "hiasm")
    f1, tr1 = sm.frame(10)
    f2, tr2 = sm.frame(11)
    scale = sm.scale_of(true)  # carried from the step before
    st = sm.step(f1, f2, tr1, tr2, scale, 10, 11)
    assert st.used == ("vo" if degenerate else "icp")
    assert "no correspondences" in (st.why_fallback or "")
    assert np.linalg.norm(st.motion[:2] - true[:2]) < 0.005
    if degenerate:
        # The paper's scale (carried over), on the first pair: none to scale VO by.
        sm.params = dataclasses.replace(sm.params, odometry_scale=False)
        assert sm.step(f1, f2, tr1, tr2, None, 10, 11).used == "icp"


def test_iasm_never_falls_back_to_vo(failing, monkeypatch):
    streams, true = failing
    monkeypatch.setattr(ScanMatcher, "odometry_constrained", lambda self, i1, i2: False)
    sm = ScanMatcher(streams, "iasm")
    f1, tr1 = sm.frame(10)
    f2, tr2 = sm.frame(11)
    st = sm.step(f1, f2, tr1, tr2, sm.scale_of(true), 10, 11)
    assert st.used == "icp"


def test_after_a_stop_the_vo_fallback_takes_the_last_moving_steps_scale(failing, monkeypatch):
    """The step before stood still (its scale, carried, is 0): visual odometry's fallback
    scales its direction by the last step that moved, or it would stand still too."""
    streams, true = failing
    monkeypatch.setattr(ScanMatcher, "odometry_constrained", lambda self, i1, i2: False)
    sm = ScanMatcher(streams, "hiasm")
    f1, tr1 = sm.frame(10)
    f2, tr2 = sm.frame(11)
    assert sm.carry(true) == pytest.approx(sm.scale_of(true))  # a moving step
    assert sm.carry(np.zeros(3)) == pytest.approx(0.0, abs=1e-12)  # a still one
    assert sm.moving_scale == pytest.approx(sm.scale_of(true))
    st = sm.step(f1, f2, tr1, tr2, 0.0, 10, 11)
    assert st.used == "vo"
    assert np.linalg.norm(st.motion[:2] - true[:2]) < 0.005
