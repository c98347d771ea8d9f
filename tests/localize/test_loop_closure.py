"""Loop closure: proposals, the verification, the pose graph and its robust kernel, the CLI."""

from __future__ import annotations

import itertools
import json

import numpy as np
import pytest

from rigcal.cli.main import main
from rigcal.errors import InputError
from rigcal.geometry import pose_of, se2
from rigcal.localize.loop_closure import (
    Closure,
    LoopParams,
    build_graph,
    correlative_match,
    graph_path,
    keyframes,
    path_along,
    relative,
    search_window,
)
from rigcal.localize.pose_graph import PoseGraph, gtsam_available, optimise


@pytest.fixture
def rng():
    return np.random.default_rng(7)


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


def test_the_search_window_grows_with_the_path_and_a_closure_is_a_short_cut():
    params = LoopParams()
    w_m, w_rad = search_window(np.array([0.0, 10.0, 50.0, 200.0, 1e5]), params)
    assert np.all(np.diff(w_m) >= 0)
    assert np.all(np.diff(w_rad) >= 0)
    assert w_m[0] == params.search_m
    assert w_rad[0] == params.min_search_rad
    assert w_m[-1] == params.max_search_m
    assert w_rad[-1] == params.max_search_rad
    truth = _square()
    along = path_along(truth)
    keys = keyframes(along, params.keyframe_m)
    last = len(keys) - 1
    # Without closures the path back to the first keyframe is the whole square (40 m) ...
    assert graph_path(along, keys, [], last, [0])[0] == pytest.approx(along[keys[last]])
    # ... and a closure joining keyframe 5 to the last but one makes it a few metres.
    assert graph_path(along, keys, [(last - 1, 5)], last, [0])[0] < 7.0


def _room(rng, n=400):
    """Returns on the walls of a 12 x 8 m room with a pillar and a shelf (M, 2)."""
    t = rng.uniform(0, 1, n)
    walls = [
        np.column_stack([12 * t, np.zeros(n)]),
        np.column_stack([12 * t, np.full(n, 8.0)]),
        np.column_stack([np.zeros(n), 8 * t]),
        np.column_stack([np.full(n, 12.0), 8 * t]),
        np.column_stack([3 + 0.5 * np.cos(2 * np.pi * t), 5 + 0.5 * np.sin(2 * np.pi * t)]),
        np.column_stack([7 + 2 * t, np.full(n, 2.5)]),
    ]
    return np.vstack(walls) - np.array([6.0, 4.0])


def _moved(points, T):
    """points (M, 2) of frame b in frame a, for T = T_a_b (x, y, yaw): b's points given a's."""
    c, s = np.cos(T[2]), np.sin(T[2])
    return (points - T[:2]) @ np.array([[c, -s], [s, c]])


def test_the_correlative_search_finds_a_match_metres_from_the_guess(rng):
    model = _room(rng)
    T = np.array([2.7, -1.9, np.radians(9.0)])
    data = _moved(model[::3], T) + rng.normal(0, 0.01, (len(model[::3]), 2))
    pose, score, elsewhere = correlative_match(model, data, np.zeros(3), 4.0, np.radians(15), LoopParams())
    assert np.hypot(*(pose[:2] - T[:2])) < 0.15  # within ICP's reach of the truth
    assert abs(pose[2] - T[2]) < np.radians(1.5)
    assert score > 0.8
    assert elsewhere < 0.9 * score  # one room: no other pose fits as well


def test_a_corridor_of_repeated_doors_is_ambiguous(rng):
    # Two walls with a door every 3 m: shifted by a door's period the scan fits as well.
    x = rng.uniform(0, 30, 3000)
    x = x[(x % 3.0) > 1.0]
    model = np.vstack([np.column_stack([x, np.zeros_like(x)]), np.column_stack([x, np.full_like(x, 2.0)])])
    data = model[np.abs(model[:, 0] - 15) < 6] - np.array([15.0, 0.0])
    params = LoopParams()
    _, score, elsewhere = correlative_match(model, data, np.array([15.0, 0.0, 0.0]), 4.0, 0.05, params)
    assert elsewhere > params.max_ambiguity * score


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
    out, _ = optimise(build_graph(odo, odo, [good], len(odo) - 1, params))
    assert np.hypot(*(out[n, :2] - truth[n, :2])) < 0.05 * before
    out2, whitened = optimise(build_graph(odo, odo, [good, false], len(odo) - 1, params))
    whitened2 = whitened[len(odo) - 1 :]  # the closures' (after the odometry's steps)
    assert whitened2[1] > params.reject_whitened  # the false one contradicts the rest
    assert whitened2[0] < params.reject_whitened
    # The false closure barely moves the map: the corners stay where the good graph put them.
    assert np.abs(out2[:, :2] - out[:, :2]).max() < 0.5


def _noisy_square_graph(rng, with_false=True):
    truth = _square()
    odo = _drifted(truth)
    n = len(truth) - 1
    params = LoopParams()
    closures = [Closure(n, 0, relative(truth[[0]], truth[[n]])[0] + rng.normal(0, [0.02, 0.02, 0.005]))]
    closures.append(
        Closure(100, 20, relative(truth[[20]], truth[[100]])[0] + rng.normal(0, [0.02, 0.02, 0.005]))
    )
    if with_false:
        closures.append(Closure(120, 40, np.zeros(3)))
    g = build_graph(odo, odo, closures, n, params)
    noisy = g.z[:n] + rng.normal(0, 1, (n, 3)) * g.sigmas[:n]
    return PoseGraph(g.poses, g.a, g.b, np.vstack([noisy, g.z[n:]]), g.sigmas, g.robust), truth


@pytest.mark.skipif(not gtsam_available(), reason="GTSAM is the optional extra rigcal[gtsam]")
@pytest.mark.parametrize("with_false", [False, True])
def test_scipy_and_gtsam_reach_the_same_optimum(rng, with_false):
    g, truth = _noisy_square_graph(rng, with_false)
    a, wa = optimise(g, "scipy")
    b, wb = optimise(g, "gtsam")
    # GTSAM measures an edge's error on SE(2)'s chart, rigcal by components: the optima
    # differ by the second order of the residuals (larger with a false closure's metres,
    # down-weighted by the kernel).
    assert np.abs(a[:, :2] - b[:, :2]).max() < (3e-3 if with_false else 1e-3)
    assert np.abs(np.angle(np.exp(1j * (a[:, 2] - b[:, 2])))).max() < (1e-3 if with_false else 1e-4)
    np.testing.assert_allclose(wa, wb, atol=0.05)
    # The optimum itself is right: the loop closed near the truth whatever the false edge.
    assert np.hypot(*(a[-1, :2] - truth[-1, :2])) < 0.1


def test_an_unknown_or_missing_back_end_is_an_input_error(rng, monkeypatch):
    g, _ = _noisy_square_graph(rng, False)
    with pytest.raises(InputError, match=r"--pose-graph: got 'ceres'; expected one of scipy, gtsam"):
        optimise(g, "ceres")
    monkeypatch.setattr("rigcal.localize.pose_graph.gtsam_available", lambda: False)
    monkeypatch.setattr("rigcal.localize.loop_closure.gtsam_available", lambda: False)
    with pytest.raises(InputError, match=r"--pose-graph: got 'gtsam'; expected .*rigcal\[gtsam\]"):
        optimise(g, "gtsam")
    assert LoopParams(backend="auto").pose_graph == "scipy"
    with pytest.raises(ValueError, match="backend must be"):
        LoopParams(backend="ceres")


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
    assert lc["pose_graph"] == ("gtsam" if gtsam_available() else "scipy")
    # Closing the loop takes the open ICP's end error away.
    assert (
        lc["metrics"]["loop_closure_error_m"] < 0.5 * s["methods"]["icp"]["metrics"]["loop_closure_error_m"]
    )
    rows = (out / "icp+lc" / "closures.csv").read_text().splitlines()
    assert rows[0] == "i,j,stamp_i_s,stamp_j_s,status,inliers,rms_m,why_not"
    assert len(rows) == counts["proposed"] + 1
    assert (out / "icp+lc" / "graph.png").stat().st_size > 1000


def test_localize_refuses_gtsam_where_it_is_not_installed(corridor, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr("rigcal.localize.pose_graph.gtsam_available", lambda: False)
    args = ["localize", str(corridor), "--method", "icp", "--loop-closure", "-o", str(tmp_path / "out")]
    assert main([*args, "--pose-graph", "gtsam"]) == 2
    err = capsys.readouterr().err
    assert "--pose-graph: got 'gtsam'; expected auto or scipy: GTSAM is not installed" in err
    assert not (tmp_path / "out").exists()  # nothing written


def test_the_compiled_search_matches_its_numpy_reference(rng):
    model = _room(rng)
    T = np.array([-1.3, 0.8, np.radians(-6.0)])
    data = _moved(model[::4], T) + rng.normal(0, 0.01, (len(model[::4]), 2))
    params = LoopParams()
    compiled = correlative_match(model, data, np.zeros(3), 3.0, np.radians(10), params)
    reference = correlative_match(model, data, np.zeros(3), 3.0, np.radians(10), params, kernel=False)
    np.testing.assert_allclose(compiled[0], reference[0], atol=1e-12)
    assert compiled[1] == pytest.approx(reference[1], abs=1e-12)
    assert compiled[2] == pytest.approx(reference[2], abs=1e-12)
