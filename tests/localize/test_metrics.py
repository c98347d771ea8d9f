"""Trajectory metrics (Table 1 figures, ATE, RPE) on constructed trajectories."""

from __future__ import annotations

import numpy as np
import pytest

from rigcal.geometry import pose_of, se2
from rigcal.localize.metrics import align_se2, anchored, evaluate, relation_error, rpe_rmse


def square_loop(n: int = 400) -> np.ndarray:
    """A 40 m closed square (10 m sides), poses heading along the path."""
    s = np.linspace(0, 40, n, endpoint=False)
    side = (s // 10).astype(int)
    u = s % 10
    x = np.choose(side, [u, np.full_like(u, 10), 10 - u, np.zeros_like(u)])
    y = np.choose(side, [np.zeros_like(u), u, np.full_like(u, 10), 10 - u])
    yaw = side * np.pi / 2
    return np.column_stack([x, y, yaw])


def test_a_perfect_estimate_scores_zero_even_in_another_frame():
    gt = square_loop()
    moved = np.array([pose_of(se2([3.0, -1.0, 0.4]) @ se2(p)) for p in gt])
    m = evaluate(moved, gt)
    assert m["average_position_error_m"] == pytest.approx(0.0, abs=1e-9)
    assert m["ate_rmse_m"] == pytest.approx(0.0, abs=1e-9)
    assert m["rpe_1m_rmse_m"] == pytest.approx(0.0, abs=1e-9)
    assert m["path_length_m"] == pytest.approx(39.9, abs=0.2)


def test_loop_closure_error_is_the_end_to_start_gap_beyond_the_truths():
    gt = square_loop()
    est = gt.copy()
    est[:, 0] += np.linspace(0.0, 0.4, len(gt))  # drifts 0.4 m along x by the end
    m = evaluate(est, gt)
    assert m["loop_closure_error_m"] == pytest.approx(0.4, abs=1e-9)
    assert m["loop_closure_error_percent"] == pytest.approx(
        100 * m["loop_closure_error_m"] / m["path_length_m"], rel=1e-3
    )
    assert m["average_position_error_m"] == pytest.approx(0.2, abs=0.01)


def test_a_perfect_estimate_of_a_loop_stopping_short_scores_no_loop_closure_error():
    gt = square_loop()[:-1]  # the last pose 0.2 m before the start, as a last image can be
    m = evaluate(gt.copy(), gt)
    assert m["truth_loop_gap_m"] == pytest.approx(0.2, abs=1e-6)
    assert m["loop_closure_error_m"] == pytest.approx(0.0, abs=1e-12)
    closed = gt.copy()
    closed[-1, :2] = gt[0, :2]  # an estimate that closes where the truth does not
    assert evaluate(closed, gt)["loop_closure_error_m"] == pytest.approx(0.2, abs=1e-6)


def test_rpe_of_a_constant_scale_error():
    gt = square_loop(800)
    est = gt.copy()
    est[:, :2] *= 1.01  # 1 % too long everywhere
    # Over 1 m steps the relative translation is 1 % too long: about 1 cm.
    assert rpe_rmse(est, gt, 1.0) == pytest.approx(0.01, rel=0.1)
    assert rpe_rmse(est, gt, 10.0) == pytest.approx(0.1, rel=0.2)


def test_alignment_and_anchoring():
    gt = square_loop()
    T = se2([1.0, 2.0, -0.3])
    est = np.array([pose_of(T @ se2(p)) for p in gt])
    np.testing.assert_allclose(align_se2(est, gt)[:, :2], gt[:, :2], atol=1e-9)
    np.testing.assert_allclose(anchored(est, gt)[:, :2], gt[:, :2], atol=1e-9)
    with pytest.raises(ValueError, match="shape"):
        evaluate(est[:-1], gt)


def test_an_open_path_has_no_loop_closure_but_an_end_position_error():
    gt = square_loop()[:150]  # 15 m of the square: ends far from its start
    est = gt.copy()
    est[:, 1] += np.linspace(0.0, 0.3, len(gt))
    m = evaluate(est, gt)
    assert m["loop_closure_error_m"] is None
    assert m["loop_closure_error_percent"] is None
    assert m["end_position_error_m"] == pytest.approx(0.3, abs=1e-6)
    assert m["truth_loop_gap_m"] > 5.0


def test_a_closed_loop_scores_its_end_position_error_too():
    gt = square_loop()
    est = gt.copy()
    est[:, 0] += np.linspace(0.0, 0.4, len(gt))
    m = evaluate(est, gt)
    assert m["loop_closure_error_m"] is not None
    assert m["end_position_error_m"] == pytest.approx(0.4, abs=1e-6)


def test_relation_error_of_consecutive_and_chosen_relations():
    gt = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, np.pi / 2], [2.0, 1.0, np.pi / 2]])
    est = gt.copy()
    est[2:, 0] += 0.1  # the second step 10 cm too long, the others exact
    r = relation_error(est, gt)
    assert r["relations"] == 3
    assert r["trans_mean_m"] == pytest.approx(0.1 / 3)
    assert r["trans_std_m"] == pytest.approx(np.std([0.0, 0.1, 0.0]))
    assert r["rot_mean_deg"] == pytest.approx(0.0, abs=1e-12)
    est[3, 2] += np.radians(2.0)  # the last pose turned 2 deg: its relation errs 2 deg
    r = relation_error(est, gt, [(0, 3)])
    assert r["rot_mean_deg"] == pytest.approx(2.0)
    assert r["trans_mean_m"] == pytest.approx(0.1)
