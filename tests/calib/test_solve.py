"""Algorithm 1 end to end on simulated sessions with a known T_cam_laser."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.stats import chi2

from rigcal.calib.box.refine import NoiseModel, RefineParams
from rigcal.calib.box.solve import CalibProblem, SolveSettings, solve
from rigcal.calib.report import build_report, report_table
from rigcal.errors import CalibrationError
from rigcal.geometry import pose_error, tangent_delta
from rigcal.sim.box_session import SessionSpec, generate_session, session_observations


def problem(spec: SessionSpec, settings: SolveSettings | None = None):
    sess = generate_session(spec)
    obs = tuple(session_observations(sess))
    return sess, CalibProblem(sess.camera, obs, settings or SolveSettings())


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_recovers_truth_within_noise_bound(seed):
    sess, prob = problem(SessionSpec(n_captures=20, seed=seed))
    res = solve(prob)
    rot_deg, trans_m = pose_error(res.T_cam_laser, sess.T_cam_laser)
    sig = np.sqrt(np.diag(res.covariance))
    # Error within 4 sigma of the reported uncertainty, and within the product's bar.
    assert np.degrees(np.linalg.norm(sig[:3])) * 4 > rot_deg
    assert np.linalg.norm(sig[3:]) * 4 > trans_m
    assert rot_deg < 0.5
    assert trans_m < 0.02
    assert res.inliers.all()


def test_noiseless_session_is_nearly_exact():
    sess, prob = problem(
        SessionSpec(n_captures=10, pick_sigma_px=0.0, range_sigma_m=0.0, dropout_fraction=0.0, seed=4)
    )
    prob = replace(prob, settings=SolveSettings(noise=NoiseModel(pick_sigma_px=0.05, range_sigma_m=1e-4)))
    res = solve(prob)
    rot_deg, trans_m = pose_error(res.T_cam_laser, sess.T_cam_laser)
    # Only the beam quantisation of the box ends remains.
    assert rot_deg < 0.1
    assert trans_m < 0.005


def test_wrong_picks_are_rejected_and_named():
    sess, prob = problem(SessionSpec(n_captures=20, wrong_pick_fraction=0.2, seed=5))
    res = solve(prob)
    wrong = {c.name for c in sess.captures if c.is_wrong_pick}
    assert wrong, "the generator should have made wrong picks"
    report = build_report(res, sess.T_cam_laser)
    rejected = {r["capture"] for r in report["rejected"]}
    assert rejected <= wrong
    assert len(rejected) >= len(wrong) - 1
    assert pose_error(res.T_cam_laser, sess.T_cam_laser)[0] < 0.5
    text = report_table(report)
    for name in rejected:
        assert name in text


def test_paper_endpoints_also_solve():
    sess, prob = problem(
        SessionSpec(n_captures=20, seed=6), SolveSettings(refine=RefineParams(use_side_points=False))
    )
    res = solve(prob)
    assert pose_error(res.T_cam_laser, sess.T_cam_laser)[0] < 1.0


def test_report_contents_and_truth():
    sess, prob = problem(SessionSpec(n_captures=12, seed=7))
    res = solve(prob)
    rep = build_report(res, sess.T_cam_laser)
    s = rep["summary"]
    assert s["captures"] == 12
    assert s["box_ends"] == 24
    assert 0.3 < s["rms_px"] < 3.0
    assert len(rep["per_capture"]) == 12
    assert len(rep["ends"]) == 24
    # NEES is the error's Mahalanobis square under the reported covariance, recomputed
    # here independently, and an honest covariance puts it below chi-square(6)'s 99.9 %.
    x = tangent_delta(sess.T_cam_laser, res.T_cam_laser)
    nees = float(x @ np.linalg.solve(res.covariance, x))
    assert rep["truth"]["nees"] == pytest.approx(nees, rel=1e-3, abs=1e-3)
    assert rep["truth"]["nees"] < chi2.ppf(0.999, 6)
    assert rep["truth"]["rotation_error_deg"] == pytest.approx(np.degrees(np.linalg.norm(x[:3])), abs=1e-4)
    assert "error against truth" in report_table(rep)


def test_too_few_captures():
    _, prob = problem(SessionSpec(n_captures=4, seed=8))
    prob = replace(prob, observations=prob.observations[:2])
    with pytest.raises(CalibrationError, match="at least 3"):
        solve(prob)


def test_all_box_ends_on_one_line_is_degenerate():
    _, prob = problem(SessionSpec(n_captures=4, seed=9))
    o = prob.observations[0]
    same = tuple(replace(o, capture=i, name=f"c{i}") for i in range(4))
    with pytest.raises(CalibrationError, match="one line"):
        solve(replace(prob, observations=same))


def test_weak_geometry_warnings():
    _sess, prob = problem(SessionSpec(n_captures=5, distance_m=(2.0, 2.3), seed=10))
    rep = build_report(solve(prob))
    text = " ".join(rep["warnings"])
    assert "only 5 captures" in text
    assert "distance" in text


def test_swapped_picks_are_diagnosed():
    _, prob = problem(SessionSpec(n_captures=15, seed=11))
    o = prob.observations[3]
    swapped = replace(o, image_endpoints_px=o.image_endpoints_px[::-1].copy())
    obs = list(prob.observations)
    obs[3] = swapped
    rep = build_report(solve(replace(prob, observations=tuple(obs))))
    assert any(o.name in w and "swapped" in w for w in rep["warnings"])


def test_correct_picks_stay_inliers_by_their_own_covariance():
    # 40 captures with 20% wrong picks: every correct end must survive the Mahalanobis gate
    # (a fixed pixel threshold would drop far, steep ends whose laser uncertainty projects
    # to several pixels), and every wrong one must be caught.
    from rigcal.calib.box.solve import INLIER_GATE_CHI2

    sess, prob = problem(SessionSpec(n_captures=40, wrong_pick_fraction=0.2, seed=11))
    res = solve(prob)
    wrong = np.repeat([c.is_wrong_pick for c in sess.captures], 2)
    kinds = np.repeat([c.wrong_pick_kind for c in sess.captures], 2)
    ends = res.measurements.end
    # A "moved end 0" capture has a correct end 1, and vice versa.
    truly_wrong = (
        wrong & ~((kinds == "moved end 0") & (ends == 1)) & ~((kinds == "moved end 1") & (ends == 0))
    )
    assert res.inliers[~truly_wrong].all()
    assert not res.inliers[truly_wrong].any()
    assert (
        res.errors_sigma[res.inliers] ** 2 < INLIER_GATE_CHI2 * max(1.0, res.refine.residual_scale**2) * 2
    ).all()
