"""Loop closure: proposals, the verification, the pose graph and its robust kernel, the CLI."""

from __future__ import annotations

import itertools
import json

import numpy as np
import pytest

from rigcal.cli.main import main
from rigcal.geometry import pose_of, se2
from rigcal.localize.loop_closure import Closure, LoopParams, optimise, propose


def _square(n_side=40, side_m=10.0):
    """Poses around a square, counter-clockwise, ending where they start."""
    out = []
    for k in range(4):
        yaw = k * np.pi / 2
        start = np.array([[0, 0], [side_m, 0], [side_m, side_m], [0, side_m]][k], dtype=float)
        for s in range(n_side):
            p = start + s * side_m / n_side * np.array([np.cos(yaw), np.sin(yaw)])
            out.append([p[0], p[1], yaw])
    out.append([0.0, 0.0, 2 * np.pi])
    return np.array(out)


def _drifted(truth, yaw_per_step=0.002):
    """The truth's steps chained with a heading bias: an odometry that does not close."""
    T = se2(truth[0])
    out = [truth[0]]
    for a, b in itertools.pairwise(truth):
        step = pose_of(np.linalg.inv(se2(a)) @ se2(b)) + np.array([0.0, 0.0, yaw_per_step])
        T = T @ se2(step)
        out.append(pose_of(T))
    return np.array(out)


def test_proposals_need_a_long_path_and_nearness():
    truth = _square()
    pairs = propose(truth, LoopParams())
    assert pairs  # the end comes back to the start
    assert all(j < i for i, j in pairs)
    # Nothing is proposed along a straight path that never returns.
    line = np.column_stack([np.linspace(0, 50, 100), np.zeros(100), np.zeros(100)])
    assert propose(line, LoopParams()) == []


def test_the_pose_graph_closes_the_loop_and_the_kernel_rejects_a_false_closure():
    truth = _square()
    odo = _drifted(truth)
    n = len(truth) - 1
    true_closure = pose_of(np.linalg.inv(se2(truth[0])) @ se2(truth[n]))
    # A false closure: poses 40 and 120 (opposite corners, 14 m apart) said to coincide.
    false = Closure(120, 40, np.zeros(3))
    good = Closure(n, 0, true_closure)
    params = LoopParams()
    before = np.hypot(*(odo[n, :2] - truth[n, :2]))
    out, _ = optimise(odo, [good], params)
    assert np.hypot(*(out[n, :2] - truth[n, :2])) < 0.05 * before
    out2, whitened2 = optimise(odo, [good, false], params)
    assert whitened2[1] > params.reject_whitened  # the false one contradicts the rest
    assert whitened2[0] < params.reject_whitened
    # The false closure barely moves the map: the corners stay where the good graph put them.
    assert np.abs(out2[:, :2] - out[:, :2]).max() < 0.5


@pytest.fixture(scope="module")
def corridor(tmp_path_factory):
    out = tmp_path_factory.mktemp("lc") / "corridor"
    args = ["simulate", "world", "--world", "corridor-loop", "-o", str(out), "--no-images"]
    assert main([*args, "--laser-rate-hz", "10"]) == 0
    return out


def test_localize_with_loop_closure_reports_closures_and_draws_the_graph(corridor, tmp_path, capsys):
    out = tmp_path / "out"
    assert (
        main(["localize", str(corridor), "--method", "icp", "--loop-closure", "-o", str(out), "--json"]) == 0
    )
    captured = capsys.readouterr()
    s = json.loads(captured.out)
    lc = s["methods"]["icp+lc"]
    counts = lc["closures"]
    assert counts["proposed"] >= 1
    assert counts["accepted"] >= 1
    assert counts["proposed"] == (
        counts["accepted"] + counts["rejected_by_verification"] + counts["rejected_by_kernel"]
    )
    assert "closures proposed" in captured.err
    # Closing the loop takes the open ICP's end error away.
    assert (
        lc["metrics"]["loop_closure_error_m"] < 0.5 * s["methods"]["icp"]["metrics"]["loop_closure_error_m"]
    )
    rows = (out / "icp+lc" / "closures.csv").read_text().splitlines()
    assert rows[0] == "i,j,stamp_i_s,stamp_j_s,status,inliers,rms_m,why_not"
    assert len(rows) == counts["proposed"] + 1
    assert (out / "icp+lc" / "graph.png").stat().st_size > 1000
