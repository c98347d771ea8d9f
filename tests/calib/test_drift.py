"""The drift check: residual and pose tests of a new session against a stored rig."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from rigcal.calib.box.picks import PickSession
from rigcal.calib.box.refine import NoiseModel
from rigcal.calib.box.solve import CalibProblem, SolveSettings, solve
from rigcal.camera import Camera
from rigcal.drift.target import DriftResult, DriftSettings, check_drift, rig_noise_model
from rigcal.errors import InputError
from rigcal.geometry import R_to_rotvec
from rigcal.rig import Rig
from rigcal.rigfile import read_rig, write_rig
from rigcal.sim.box_session import (
    SessionSpec,
    default_camera,
    default_T_cam_laser,
    generate_session,
    moved_T_cam_laser,
    session_observations,
)

T_TRUE = default_T_cam_laser()
NOISE = NoiseModel()
LEVEL = DriftSettings().level


def new_session(
    n_captures: int,
    seed: int,
    T_cam_laser: np.ndarray = T_TRUE,
    camera: Camera | None = None,
    wrong_pick_fraction: float = 0.0,
) -> PickSession:
    """A simulated session, resolved in memory exactly as read_picks would resolve it."""
    spec = SessionSpec(n_captures=n_captures, seed=seed, wrong_pick_fraction=wrong_pick_fraction)
    sim = generate_session(spec, camera=camera, T_cam_laser=T_cam_laser)
    where = Path("simulated")
    return PickSession(where, sim.camera, where, {}, tuple(session_observations(sim)))


@pytest.fixture(scope="module")
def rig() -> Rig:
    """The stored rig: solved from a 20-capture session of the true rig."""
    sim = generate_session(SessionSpec(n_captures=20, seed=1))
    res = solve(CalibProblem(sim.camera, tuple(session_observations(sim)), SolveSettings(noise=NOISE)))
    return Rig(res.T_cam_laser, sim.camera, res.covariance, provenance={"noise": vars(NOISE)})


@pytest.fixture(scope="module")
def unmoved() -> PickSession:
    return new_session(6, seed=11)


@pytest.fixture(scope="module")
def unmoved_result(rig, unmoved) -> DriftResult:
    return check_drift(rig, unmoved)


@pytest.fixture(scope="module")
def short_unmoved() -> PickSession:
    return new_session(3, seed=21)


def expected_difference(T_moved: np.ndarray) -> np.ndarray:
    """[rotation deg (3), translation mm (3)] of a move, as the pose test reports it."""
    d_rot = np.degrees(R_to_rotvec(T_moved[:3, :3] @ T_TRUE[:3, :3].T))
    return np.concatenate([d_rot, 1000.0 * (T_moved[:3, 3] - T_TRUE[:3, 3])])


def reported_difference(pose: dict) -> tuple[np.ndarray, np.ndarray]:
    diff = np.array(pose["rotation_diff_deg"] + pose["translation_diff_mm"])
    sigma = np.array(pose["sigma_rotation_deg"] + pose["sigma_translation_mm"])
    return diff, sigma


def test_unmoved_rig_is_ok_with_high_p_values(unmoved_result):
    r = unmoved_result
    assert not r.drifted
    assert r.verdict == "ok"
    assert r.level == LEVEL
    assert r.residual["p_value"] > 0.05
    assert r.pose is not None
    assert r.pose["p_value"] > 0.05
    assert r.residual["ends"] == 12
    assert r.residual["used_ends"] == 12
    assert r.residual["rejected_ends"] == 0
    assert r.residual["dof"] == 24
    assert r.fresh is not None
    assert r.reasons == []


def test_unmoved_pose_difference_is_within_the_combined_sigmas(unmoved_result):
    diff, sigma = reported_difference(unmoved_result.pose)
    assert np.all(np.abs(diff) < 3.0 * sigma)
    assert unmoved_result.pose["rotation_deg"] < 0.3
    assert unmoved_result.pose["translation_mm"] < 10.0


def test_camera_turned_half_a_degree_is_detected_by_the_pose_test(rig):
    T = moved_T_cam_laser(T_TRUE, 0.5, 0.0, seed=3)
    r = check_drift(rig, new_session(6, seed=12, T_cam_laser=T))
    assert r.drifted
    assert r.verdict == "drifted"
    assert r.pose is not None
    assert r.pose["p_value"] < LEVEL
    assert any("fresh solve differs" in reason for reason in r.reasons)
    assert 0.3 < r.pose["rotation_deg"] < 0.7
    # The per-axis difference is the move itself, within the combined uncertainty.
    diff, sigma = reported_difference(r.pose)
    assert np.all(np.abs(diff - expected_difference(T)) < 3.0 * sigma)


def test_camera_shifted_20_mm_is_detected_by_the_pose_test(rig):
    T = moved_T_cam_laser(T_TRUE, 0.0, 20.0, seed=4)
    r = check_drift(rig, new_session(6, seed=13, T_cam_laser=T))
    assert r.drifted
    assert r.pose is not None
    assert r.pose["p_value"] < LEVEL
    assert 12.0 < r.pose["translation_mm"] < 28.0
    diff, sigma = reported_difference(r.pose)
    assert np.all(np.abs(diff - expected_difference(T)) < 3.0 * sigma)


def test_three_captures_run_only_the_residual_test(rig, short_unmoved):
    r = check_drift(rig, short_unmoved)
    assert not r.drifted
    assert r.pose is None
    assert r.fresh is None
    assert r.residual["dof"] == 12
    assert any("only the residual test" in reason for reason in r.reasons)
    assert any("3 captures" in reason for reason in r.reasons)


def test_three_captures_detect_a_one_degree_turn(rig):
    T = moved_T_cam_laser(T_TRUE, 1.0, 0.0, seed=5)
    r = check_drift(rig, new_session(3, seed=21, T_cam_laser=T))
    assert r.drifted
    assert r.pose is None
    assert any("only the residual test" in reason for reason in r.reasons)
    # Same picks noise as short_unmoved (same seed): only the turn differs.
    assert r.residual["rejected_ends"] > 0 or r.residual["p_value"] < LEVEL


def test_min_captures_setting_decides_whether_the_pose_test_runs(rig, short_unmoved, unmoved):
    r = check_drift(rig, short_unmoved, DriftSettings(min_captures_for_solve=3))
    assert r.pose is not None
    assert r.fresh is not None
    r = check_drift(rig, unmoved, DriftSettings(min_captures_for_solve=7))
    assert r.pose is None


def test_wrong_picks_are_left_out_and_raise_no_false_alarm(rig):
    session = new_session(8, seed=15, wrong_pick_fraction=0.25)
    r = check_drift(rig, session)
    assert r.residual["rejected_ends"] > 0
    assert r.residual["used_ends"] == r.residual["ends"] - r.residual["rejected_ends"]
    assert r.residual["dof"] == 2 * r.residual["used_ends"]
    # The wrong picks are far off, yet the ends used fit the noise.
    assert r.residual["max_px"] > 10.0
    assert r.residual["rms_px"] < 4.0
    assert r.residual["p_value"] > LEVEL
    assert not r.drifted
    # ... and the report names them.
    assert len(r.reasons) == 1
    assert r.reasons[0].startswith("left out of the residual test as wrong picks")
    assert len(r.residual["rejected"]) == r.residual["rejected_ends"]
    assert all(x["capture"].startswith("cap") and x["sigma"] > 3.7 for x in r.residual["rejected"])


def test_rig_without_covariance_is_refused(rig, short_unmoved):
    bare = replace(rig, covariance=None)
    with pytest.raises(InputError, match="uncertainty"):
        check_drift(bare, short_unmoved)


def test_session_with_another_camera_is_named_in_the_reasons(rig):
    cam = default_camera()
    K = np.array([[530.0, 0.0, 321.5], [0.0, 530.0, 239.5], [0.0, 0.0, 1.0]])
    other = Camera.from_opencv(K, [-0.15, 0.05, 0.0005, -0.0003, 0.0], cam.width_px, cam.height_px)
    r = check_drift(rig, new_session(3, seed=22, camera=other))
    assert any("camera" in reason for reason in r.reasons)
    r_same = check_drift(rig, new_session(3, seed=22))
    assert not any("camera" in reason for reason in r_same.reasons)


def test_two_tests_each_run_at_half_the_level(rig, unmoved, unmoved_result):
    p_min = min(unmoved_result.residual["p_value"], unmoved_result.pose["p_value"])
    assert p_min < 0.38  # so that 2.6 * p_min is a valid level
    # level/2 < p_min < level: a single test at the full level would fire; Bonferroni does not.
    between = check_drift(rig, unmoved, DriftSettings(level=1.5 * p_min))
    assert not between.drifted
    # p_min < level/2: fires.
    below = check_drift(rig, unmoved, DriftSettings(level=2.6 * p_min))
    assert below.drifted
    # The level does not change the statistics, only the verdict.
    assert between.residual == below.residual == unmoved_result.residual
    assert between.pose == below.pose == unmoved_result.pose


def test_a_single_test_runs_at_the_full_level(rig, short_unmoved):
    p = check_drift(rig, short_unmoved).residual["p_value"]
    assert 0.0 < p < 0.6
    assert check_drift(rig, short_unmoved, DriftSettings(level=1.5 * p)).drifted
    assert not check_drift(rig, short_unmoved, DriftSettings(level=0.7 * p)).drifted


def test_rig_noise_model_reads_the_provenance(rig):
    noisy = replace(rig, provenance={"noise": {"pick_sigma_px": 2.5, "range_sigma_m": 0.02}})
    assert rig_noise_model(noisy) == NoiseModel(pick_sigma_px=2.5, range_sigma_m=0.02)


def test_rig_noise_model_prefers_the_noise_the_rig_used(rig, tmp_path):
    """A rig solved with --noise auto records the assumed noise in its provenance and the
    estimated one it used in uncertainty.noise: the check uses the latter."""
    used = {
        "pick_sigma_px": {"assumed": 1.0, "estimated": 1.7, "used": 1.7},
        "range_sigma_m": {"assumed": 0.01, "estimated": 0.018, "used": 0.018},
    }
    stored = replace(
        rig,
        provenance={"noise": {"mode": "auto", "pick_sigma_px": 1.0, "range_sigma_m": 0.01}},
        uncertainty={"noise": used},
    )
    back = read_rig(write_rig(tmp_path / "rig.yaml", stored))
    assert rig_noise_model(back) == NoiseModel(pick_sigma_px=1.7, range_sigma_m=0.018)


@pytest.mark.parametrize(
    "provenance",
    [
        {},
        {"noise": "loud"},
        {"noise": {"pick_sigma_px": 2.0}},
        {"noise": {"pick_sigma_px": "two", "range_sigma_m": 0.02}},
    ],
)
def test_rig_noise_model_falls_back_to_the_default(rig, provenance):
    assert rig_noise_model(replace(rig, provenance=provenance)) == NoiseModel()


def test_rig_noise_model_survives_the_rig_file(rig, tmp_path):
    settings = SolveSettings(noise=NoiseModel(pick_sigma_px=1.5, range_sigma_m=0.015))
    stored = replace(rig, provenance={"command": "test", **settings.to_dict()})
    path = write_rig(tmp_path / "rig.yaml", stored)
    assert rig_noise_model(read_rig(path)) == NoiseModel(pick_sigma_px=1.5, range_sigma_m=0.015)


def test_the_check_uses_the_rigs_noise_model(rig, short_unmoved):
    # A rig solved under a claim of 0.2 px pick noise cannot explain 1 px picks.
    tight = replace(rig, provenance={"noise": {"pick_sigma_px": 0.2, "range_sigma_m": 0.01}})
    assert check_drift(tight, short_unmoved).drifted
    # An explicit noise model overrides the rig's.
    assert not check_drift(tight, short_unmoved, DriftSettings(noise=NOISE)).drifted


@pytest.mark.parametrize("level", [0.0, 1.0, -0.01, 1.5])
def test_settings_reject_a_level_outside_0_1(level):
    with pytest.raises(ValueError, match="level"):
        DriftSettings(level=level)


def test_residual_test_false_alarms_are_rare_on_an_unmoved_rig(rig):
    """15 unmoved 3-capture sessions (residual test only) at level 0.05.

    If the test is calibrated its p-values are uniform: about 0.75 false alarms are
    expected, and 4 or more would have a probability of about 0.5 % for independent
    sessions. The sessions share the stored rig (its own error shifts every session's
    residuals alike), which spreads the count more than a binomial would, hence the loose
    bound of 3. The spread of the p-values catches a test that is far off either way: all
    tiny (noise underestimated) or all near 1 (noise overestimated, no power).
    """
    settings = DriftSettings(level=0.05)
    results = [check_drift(rig, new_session(3, seed=300 + k), settings) for k in range(15)]
    assert all(r.pose is None for r in results)
    p = np.array([r.residual["p_value"] for r in results])
    assert sum(r.drifted for r in results) <= 3
    assert (p < 0.05).sum() <= 3
    assert p.max() > 0.5
    assert p.min() < 0.5
    assert 0.15 < np.median(p) < 0.85
