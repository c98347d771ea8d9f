"""Loop closure: proposals, the verification, the pose graph and its robust kernel, the CLI."""

from __future__ import annotations

import itertools
import json
from dataclasses import replace

import numpy as np
import pytest

from rigcal.cli.main import main
from rigcal.errors import InputError
from rigcal.geometry import pose_of, se2
from rigcal.localize import branch_and_bound as bnb
from rigcal.localize import pose_graph
from rigcal.localize.loop_closure import (
    Closure,
    LoopParams,
    build_graph,
    chained_covariances,
    close_loops,
    closure_covariance,
    compose,
    correlative_match,
    graph_path,
    keyframes,
    path_along,
    relative,
    scans_at,
    search_window,
    step_covariances,
    verify_global,
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


@pytest.mark.parametrize("with_false", [False, True])
def test_the_block_assembled_solve_matches_the_generic_sparse_one(rng, with_false, monkeypatch):
    # The normal equations built block by block and solved as symmetric positive definite
    # take the same Gauss-Newton steps as the generic sparse least squares: held to a
    # tighter stop, the two agree to far below the stop.
    g, _ = _noisy_square_graph(rng, with_false)
    g = replace(
        g,
        poses=g.poses
        + rng.normal(0, [0.05, 0.05, 0.01], g.poses.shape) * (np.arange(len(g.poses)) > 0)[:, None],
    )
    monkeypatch.setattr(pose_graph, "STEP_TOLERANCE", 1e-10)
    a = pose_graph._scipy_optimum(g)
    b = pose_graph._scipy_optimum_reference(g)
    np.testing.assert_allclose(a, b, atol=1e-9)
    assert np.array_equal(a[0], g.poses[0])  # the first pose held
    # At the default stop the optimum moves by well under a millimetre.
    monkeypatch.setattr(pose_graph, "STEP_TOLERANCE", 1e-6)
    np.testing.assert_allclose(pose_graph._scipy_optimum(g), b, atol=1e-4)


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
    assert (
        rows[0]
        == "i,j,stamp_i_s,stamp_j_s,status,source,inliers,rms_m,sigma_x_m,sigma_y_m,sigma_yaw_rad,why_not"
    )
    assert len(rows) == counts["proposed"] + 1
    # An accepted closure's 1-sigma: its fit's on the floor's (2 mm, 0.5 mrad), not the
    # fixed 5 cm and 0.02 rad.
    fields = next(r for r in rows[1:] if ",accepted," in r).split(",")
    sx, sy, syaw = (float(v) for v in fields[8:11])
    assert min(sx, sy) >= 0.002
    assert max(sx, sy) < 0.02
    assert 0.0005 <= syaw < 0.01
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


def _correlated(rng, n):
    """n random positive definite covariances (n, 3, 3), millimetres and milliradians."""
    A = rng.normal(0, 1, (n, 3, 3)) * np.array([0.003, 0.003, 0.001])[None, :, None]
    return np.einsum("nij,nkj->nik", A, A) + np.diag([1e-6, 1e-6, 1e-7])


def test_full_covariances_whiten_each_edge_and_both_back_ends_agree(rng):
    g, _ = _noisy_square_graph(rng, False)
    # Diagonal covariances are the sigmas themselves.
    diag = np.einsum("mi,ij->mij", g.sigmas**2, np.eye(3))
    same = PoseGraph(g.poses, g.a, g.b, g.z, g.sigmas, g.robust, diag)
    np.testing.assert_allclose(optimise(same)[0], optimise(g)[0], atol=1e-9)
    # Correlated covariances, the measurements drawn from them; U^T U is the information,
    # and a non-finite covariance falls back to the sigmas.
    truth = _square()
    cov = _correlated(rng, len(g.a))
    z = relative(truth[g.a], truth[g.b])
    z += np.array([rng.multivariate_normal(np.zeros(3), c) for c in cov])
    cov[3] = np.nan
    full = PoseGraph(g.poses, g.a, g.b, z, g.sigmas, g.robust, cov)
    U = full.whiteners()
    np.testing.assert_allclose(np.einsum("mji,mjk->mik", U[:3], U[:3]), np.linalg.inv(cov[:3]), rtol=1e-8)
    np.testing.assert_allclose(U[3], np.diag(1.0 / g.sigmas[3]))
    a, _ = optimise(full, "scipy")

    def cost(p):
        e = np.einsum("mij,mj->mi", U, edge_errors_of(p, full))
        r2 = np.sum(e**2, axis=1)
        return float(np.sum(np.where(full.robust, 4.5 * np.log1p(r2 / 9.0), r2 / 2)))

    # The optimum: no small move of a pose lowers the cost.
    base = cost(a)
    for k in (5, 80, 150):
        for d in range(3):
            for h in (1e-5, -1e-5):
                moved = a.copy()
                moved[k, d] += h
                assert cost(moved) >= base - 1e-12
    if gtsam_available():
        b, _ = optimise(full, "gtsam")
        assert np.abs(a[:, :2] - b[:, :2]).max() < 1e-3


def edge_errors_of(p, g):
    from rigcal.localize.pose_graph import edge_errors

    return edge_errors(p[g.a], p[g.b], g.z)


def test_chained_covariances_compound_the_steps_as_a_monte_carlo_does(rng):
    # A laser odometry of 9 steps, each with its own covariance; stamps at every scan,
    # then at every third scan, then two stamps sharing their nearest scan.
    steps = np.column_stack([rng.uniform(0.2, 0.5, 9), rng.normal(0, 0.05, 9), rng.normal(0, 0.2, 9)])
    poses = [np.zeros(3)]
    for st in steps:
        poses.append(compose(poses[-1][None], st[None])[0])
    poses = np.array(poses)
    cov = np.concatenate([np.full((1, 3, 3), np.nan), _correlated(rng, 9)])
    t = np.arange(10) * 0.1
    np.testing.assert_allclose(chained_covariances(t, poses, cov, t)[1:], cov[1:], atol=1e-15)
    out = chained_covariances(t, poses, cov, t[[0, 3, 6, 9]])
    assert np.isnan(out[0]).all()
    # Monte Carlo of the steps 4..6 chained (stamps 3 -> 6).
    draws = np.array([rng.multivariate_normal(steps[q - 1], cov[q], 40000) for q in (4, 5, 6)])
    p = compose(compose(draws[0], draws[1]), draws[2])
    mc = np.cov(p.T)
    scale = np.sqrt(np.outer(np.diag(mc), np.diag(mc)))
    # Within the Monte Carlo's own spread (1/sqrt(40000) of a correlation: 0.005).
    assert np.abs((out[2] - mc) / scale).max() < 0.03
    # A tenth of a step (an image's stamp and its scan's): a tenth of its covariance, and
    # the two pieces of a step split at an image add up to the step.
    np.testing.assert_allclose(chained_covariances(t, poses, cov, np.array([0.3, 0.31]))[1], 0.1 * cov[4])
    halves = chained_covariances(t, poses, cov, np.array([0.3, 0.35, 0.4]))
    np.testing.assert_allclose(halves[1] + halves[2], cov[4], rtol=1e-2)
    assert np.isnan(chained_covariances(t, poses, cov, np.array([0.3, 0.3]))[1]).all()


def test_scans_at_moves_each_scan_to_its_stamp():
    # A laser on an arc, scanned at 40 Hz; three fixed world points seen from each pose.
    t = np.arange(0, 1.0, 0.025)
    poses = np.column_stack([np.sin(0.5 * t) / 0.5, (1 - np.cos(0.5 * t)) / 0.5, 0.5 * t])
    world = np.array([[3.0, 1.0], [2.0, -2.0], [4.0, 0.5]])

    class _Returns:
        def __init__(self, points):
            self.points = points
            self.valid = np.ones(len(points), dtype=bool)

    stamps = np.array([0.0123, 0.5, 0.61, 0.9874])
    out = scans_at([_Returns(_moved(world, p)) for p in poses], t, poses, stamps)
    for s, o in zip(stamps, out, strict=True):
        # Each stamp's returns, placed by the odometry interpolated there, are the world's.
        at = np.array([np.interp(s, t, poses[:, k]) for k in range(3)])
        c, sn = np.cos(at[2]), np.sin(at[2])
        np.testing.assert_allclose(o @ np.array([[c, sn], [-sn, c]]) + at[:2], world, atol=1e-9)


def test_a_closure_covariance_covers_its_fits_spread(rng):
    model = _room(rng, 300)
    T = np.array([0.4, -0.3, np.radians(4.0)])
    params = LoopParams()
    from rigcal.localize.icp import IcpParams, icp

    errs, covs = [], []
    for _ in range(30):
        submap = model + rng.normal(0, 0.01, model.shape)
        data = _moved(model[::2], T) + rng.normal(0, 0.01, (len(model[::2]), 2))
        start = T + np.array([0.05, -0.05, 0.01])
        res = icp(submap, data, initial=start, params=IcpParams(method="point-to-line"))
        errs.append(res.pose - T)
        covs.append(closure_covariance(submap, data, res.pose, params))
    nees = np.mean([e @ np.linalg.solve(c, e) for e, c in zip(errs, covs, strict=True)])
    # Consistent or conservative (3 for a consistent 3-dof estimate), and not vacuous:
    # the fit's own part is sub-millimetre, the floor's 2 mm and 0.5 mrad on top.
    assert 0.3 < nees < 6.0
    assert np.sqrt(covs[0][0, 0]) < 0.005


def test_a_precise_odometry_is_not_made_worse_by_a_coarser_closure(rng):
    # An odometry 10 times more precise than the closure: its covariance keeps the closure
    # from bending it, where the fixed sigmas let the closure's error spread over the lap.
    truth = _square()
    n = len(truth) - 1
    steps = relative(truth[:-1], truth[1:])
    step_cov = np.diag([1e-4, 1e-4, 2e-5]) ** 2
    noisy = steps + rng.normal(0, 1, steps.shape) * np.array([1e-4, 1e-4, 2e-5])
    odo = [truth[0]]
    for st in noisy:
        odo.append(compose(odo[-1][None], st[None])[0])
    odo = np.array(odo)
    closure_cov = np.diag([0.01, 0.01, 0.003]) ** 2
    z = relative(truth[[0]], truth[[n]])[0] + np.array([0.01, -0.01, 0.003])  # 1 sigma off
    c = Closure(n, 0, z, covariance=closure_cov)
    covs = np.concatenate([np.full((1, 3, 3), np.nan), np.tile(step_cov, (n, 1, 1))])
    # The steps' own covariances alone: the drift model (on by default) says the odometry
    # drifts as much as step 1's window assumes, which this one does not.
    params = LoopParams(step_drift=False)
    own, _ = optimise(build_graph(odo, odo, [c], n, params, covs))
    fixed, _ = optimise(build_graph(odo, odo, [Closure(n, 0, z)], n, params))

    def ate(p):
        return float(np.sqrt(np.mean(np.sum((p[:, :2] - truth[:, :2]) ** 2, axis=1))))

    assert ate(own) <= 1.05 * ate(odo)
    assert ate(fixed) > 2 * ate(odo)


def test_a_methods_step_covariance_opens_where_it_left_the_laser_odometry(rng):
    t = np.arange(20) * 0.025
    laser = np.column_stack([t, np.zeros(20), np.zeros(20)])
    cov = np.concatenate([np.full((1, 3, 3), np.nan), _correlated(rng, 19)])
    # ICP's own poses: its step covariances as they are.
    np.testing.assert_allclose(step_covariances(t, laser, cov, t, laser)[1:], cov[1:])
    # A method that jumped 0.3 m forward between scans 9 and 10 (visual odometry at a
    # stop): that step, and only that one, is opened by the jump.
    method = laser.copy()
    method[10:, 0] += 0.3
    out = step_covariances(t, laser, cov, t, method)
    np.testing.assert_allclose(out[10], cov[10] + np.diag([0.09, 0.0, 0.0]), atol=1e-12)
    np.testing.assert_allclose(np.delete(out, 10, axis=0)[1:], np.delete(cov, 10, axis=0)[1:], atol=1e-12)


def _square_world(rng):
    """A 10 m square corridor loop (walls 1.5 m either side of the path, with gaps for
    doors at random) and pillars at random along it (M, 2): places that look alike only
    where they are the same."""

    def outline(lo, hi):
        t = np.linspace(lo, hi, int((hi - lo) / 0.03))
        return np.vstack(
            [np.column_stack(p) for p in ((t, t * 0 + lo), (t, t * 0 + hi), (t * 0 + lo, t), (t * 0 + hi, t))]
        )

    walls = np.vstack([outline(1.5, 8.5), outline(-1.5, 11.5)])
    doors = rng.uniform(-1.5, 11.5, (12, 2))
    keep = np.all(np.max(np.abs(walls[:, None, :] - doors[None]), axis=2) > 0.4, axis=1)
    parts = [walls[keep]]
    a = np.linspace(0, 2 * np.pi, 40)
    for _ in range(40):
        side, s = rng.integers(4), rng.uniform(0, 10)
        centre = np.array([[s, 0], [10, s], [s, 10], [0, s]][side], dtype=float)
        centre[(side + 1) % 2] += rng.choice([-1.0, 1.0]) * rng.uniform(0.6, 1.1)
        parts.append(centre + rng.uniform(0.05, 0.25) * np.column_stack([np.cos(a), np.sin(a)]))
    return np.vstack(parts)


def _scans_of(world, truth, range_m=8.0):
    """Each pose's returns (P, 2) in its frame: the world's points within range (no
    occlusion; the matching sees the same structure either way)."""
    out = []
    for p in truth:
        local = _moved(world, p)
        out.append(local[np.hypot(*local.T) < range_m])
    return out


def test_branch_and_bound_finds_the_exhaustive_searchs_best(rng):
    model = _room(rng)
    T = np.array([0.63, -0.41, 2.2])  # a yaw only the full circle reaches
    data = _moved(model[::5], T) + rng.normal(0, 0.01, (len(model[::5]), 2))
    pyr = bnb.pyramid(model, 0.1, 4)
    step = 0.03
    found = bnb.match(pyr, data, np.zeros(3), 1.0, np.pi, step_rad=step)
    pose, score = bnb.exhaustive_match(pyr, data, np.zeros(3), 1.0, np.pi, step)
    np.testing.assert_allclose(found.pose, pose, atol=1e-12)
    assert found.score == pytest.approx(score, abs=1e-12)
    assert np.hypot(*(pose[:2] - T[:2])) < 0.15
    assert abs(np.angle(np.exp(1j * (pose[2] - T[2])))) < 2 * step
    poses = len(bnb.search_yaws(0.0, np.pi, step)) * 21**2
    assert found.nodes < poses / 3  # the bound cut most of the search
    # Each level bounds the level below over its block: the bound is exact.
    for h in range(1, pyr.levels):
        half = 1 << (h - 1)
        lower = pyr.grids[h - 1]
        assert np.all(pyr.grids[h][:-half, :-half] >= lower[half:, half:])
        assert np.all(pyr.grids[h] >= lower)


def test_branch_and_bound_reports_the_best_elsewhere_only_above_the_ratio(rng):
    # A corridor of doors every 3 m: 3 m along, the scan fits as well.
    x = rng.uniform(0, 30, 3000)
    x = x[(x % 3.0) > 1.0]
    model = np.vstack([np.column_stack([x, np.zeros_like(x)]), np.column_stack([x, np.full_like(x, 2.0)])])
    data = model[np.abs(model[:, 0] - 15) < 5][::4] - np.array([15.0, 0.0])
    pyr = bnb.pyramid(model, 0.1, 5)
    found = bnb.match(pyr, data, np.array([15.0, 0.0, 0.0]), 4.0, 0.1, away_m=1.0, away_ratio=0.9)
    assert found.elsewhere > 0.9 * found.score
    room = _room(rng)
    one = bnb.match(
        bnb.pyramid(room, 0.1, 5), _moved(room[::3], np.zeros(3)), np.zeros(3), 2.0, 0.2, away_m=1.0
    )
    assert one.score > 0.9
    assert 0 < one.elsewhere < 0.9 * one.score  # one room: nothing else fits as well
    cut = bnb.match(
        bnb.pyramid(room, 0.1, 5),
        _moved(room[::3], np.zeros(3)),
        np.zeros(3),
        2.0,
        0.2,
        away_m=1.0,
        away_ratio=0.9,
    )
    assert cut.elsewhere == 0.0
    assert cut.nodes < one.nodes


def _precise_steps(n):
    """(n, 3, 3) steps' covariances of a precise odometry (the first NaN)."""
    return np.concatenate([np.full((1, 3, 3), np.nan), np.tile(np.diag([1e-6, 1e-6, 1e-8]), (n - 1, 1, 1))])


def _jumped_lap(rng):
    """A lap and a half of the square (the lap, the truth, the odometry, the scans); the
    odometry drifts 0.002 rad a step and its heading jumps by 0.7 rad once."""
    lap = _square()
    truth = np.vstack([lap, lap[1:61] + np.array([0.0, 0.0, 2 * np.pi])])
    odo = _drifted(truth, yaw_per_step=0.002)
    after = relative(np.repeat(odo[99][None], len(odo) - 100, 0), odo[100:])
    odo[100:] = compose(np.repeat((odo[99] + np.array([0.0, 0.0, 0.7]))[None], len(after), 0), after)
    return lap, truth, odo, _scans_of(_square_world(rng), truth)


def test_the_global_search_closes_a_far_return_rotated_by_a_large_angle(rng):
    # A lap and a half of the square; the odometry drifts 0.002 rad a step and its heading
    # jumps by 0.7 rad once (a step it got wrong): the return comes back 9 m away and
    # rotated by about 60 degrees, beyond a local window capped at 1 m and 0.35 rad. A
    # drift model that allows for it (a heading random walk of 0.06 rad/sqrt(m), on the
    # steps too) opens the global search's yaw window past it and lets the graph bend.
    _, truth, odo, scans = _jumped_lap(rng)
    params = LoopParams(
        max_search_m=1.0, drift_rad_per_sqrt_m=0.06, step_drift=True, global_every=5, backend="scipy"
    )
    own = _precise_steps(len(odo))
    yaw_error = relative(odo[[0]], odo[[160]])[0, 2]
    assert abs(yaw_error) > max(params.global_rad, params.max_search_rad)
    assert np.hypot(*(odo[160, :2] - odo[0, :2])) > 8 * params.max_search_m
    local = close_loops(scans, odo, replace(params, global_every=0), own)
    assert local.counts["accepted"] == 0
    found = close_loops(scans, odo, params, own)
    accepted = [c for c in found.closures if c.T_j_i is not None and not c.kernel_rejected]
    assert any(c.wide for c in accepted)  # the global search's
    for c in accepted:  # each closure is the truth's relative pose
        true = relative(truth[[c.j]], truth[[c.i]])[0]
        assert np.hypot(*(c.T_j_i[:2] - true[:2])) < 0.05
        assert abs(np.angle(np.exp(1j * (c.T_j_i[2] - true[2])))) < 0.03
    end = float(np.hypot(*(found.poses[-1, :2] - truth[-1, :2])))
    assert end < 0.15 * float(np.hypot(*(odo[-1, :2] - truth[-1, :2])))


def test_the_global_search_rejects_a_false_candidate(rng):
    # The poses put keyframe i (the square's third corner) next to j (its first): no
    # match over j's submap passes the test.
    truth = _square()
    scans = _scans_of(_square_world(rng), truth)
    est = truth.copy()
    i, j = 80, 5
    est[i - 40 : i + 1] = compose(
        np.repeat(truth[j][None], 41, 0), relative(np.repeat(truth[i][None], 41, 0), truth[i - 40 : i + 1])
    )
    params = LoopParams(backend="scipy")
    c = verify_global(scans, est, path_along(truth), i, j, np.pi, params)
    assert c.T_j_i is None
    assert c.wide
    assert c.why_not


def test_the_global_search_rejects_a_false_candidate_in_a_repetitive_corridor(rng):
    # A 60 m corridor with a door every 3 m on both walls: keyframe i 40 m along is
    # searched for on the submap of j 15 m along, a place that looks the same; every 3 m
    # along fits as well, so the match is ambiguous and no closure is made.
    x = rng.uniform(-10, 70, 16000)
    x = x[(x % 3.0) > 1.0]
    world = np.vstack([np.column_stack([x, np.zeros_like(x)]), np.column_stack([x, np.full_like(x, 2.0)])])
    truth = np.column_stack([np.arange(0, 60, 0.25), np.full(240, 1.0), np.zeros(240)])
    scans = _scans_of(world, truth)
    i, j = 160, 60
    params = LoopParams(backend="scipy")
    c = verify_global(scans, truth, path_along(truth), i, j, params.global_rad, params)
    assert c.T_j_i is None
    assert "ambiguous" in c.why_not or "degenerate" in c.why_not


def test_step_drift_adds_the_search_windows_drift_model_to_the_steps_own_covariances():
    # Compounded over the steps, the added variance is the window's: (a L)^2-ish on x, b^2 L
    # on yaw; the fit's own covariance (capped by the step prior, here all but unchanged)
    # is kept under it.
    truth = _square()
    n = len(truth) - 1
    own = np.concatenate([np.full((1, 3, 3), np.nan), np.tile(np.diag([1e-6, 1e-6, 1e-8]), (n, 1, 1))])
    params = LoopParams(step_drift=True)
    plain = build_graph(truth, truth, [], n, replace(params, step_drift=False), own).covariances
    drift = build_graph(truth, truth, [], n, params, own).covariances
    assert plain is not None
    assert drift is not None
    step_m = 10.0 / 40
    kept = drift.copy()
    kept[:, 2, 2] -= params.drift_rad_per_sqrt_m**2 * step_m
    kept[:, 0, 0] -= (params.drift_per_m * step_m) ** 2
    kept[:, 1, 1] -= (params.drift_per_m * step_m) ** 2
    np.testing.assert_allclose(kept, plain, rtol=0.05)  # the prior (7 mm, 1 mrad) barely caps 1 mm
    assert np.all(kept[:, [0, 1, 2], [0, 1, 2]] <= plain[:, [0, 1, 2], [0, 1, 2]])


def test_step_drift_caps_a_degenerate_steps_covariance_by_the_step_prior():
    # ICP along a corridor: its covariance along the corridor is metres (unconstrained);
    # the step is then as certain as its guess, the fixed step sigmas' prior, and a loop's
    # correction is not put into that one step.
    truth = _square()
    n = len(truth) - 1
    own = np.concatenate([np.full((1, 3, 3), np.nan), np.tile(np.diag([1e-6, 1e-6, 1e-8]), (n, 1, 1))])
    own[10] = np.diag([100.0, 1e-6, 1e-8])
    params = LoopParams(step_drift=True)
    cov = build_graph(truth, truth, [], n, params, own).covariances
    assert cov is not None
    prior_m = params.step_sigmas[0] + params.step_sigma_per_m * 10.0 / 40
    drift = (params.drift_per_m * 10.0 / 40) ** 2
    assert cov[9, 0, 0] == pytest.approx(prior_m**2 + drift, rel=1e-3)  # capped: millimetres, not 10 m
    assert cov[9, 1, 1] == pytest.approx(cov[8, 1, 1], rel=1e-9)  # the constrained ones as before
    unfused = build_graph(truth, truth, [], n, replace(params, step_drift=False), own).covariances
    assert unfused is not None
    assert unfused[9, 0, 0] == pytest.approx(100.0)


@pytest.mark.parametrize(
    "bad",
    [
        {"global_every": -1},
        {"global_candidates": 0},
        {"global_grid_m": 0.0},
        {"global_context_m": -1.0},
        {"global_window_m": 0.0},
        {"global_levels": 0},
    ],
)
def test_the_global_search_settings_are_checked(bad):
    with pytest.raises(ValueError, match="global"):
        LoopParams(**bad)


def _same_closures(a, b):
    assert len(a.closures) == len(b.closures)
    for x, y in zip(a.closures, b.closures, strict=True):
        assert (x.i, x.j, x.why_not, x.kernel_rejected, x.wide) == (
            y.i,
            y.j,
            y.why_not,
            y.kernel_rejected,
            y.wide,
        )
        assert x.score == y.score or (np.isnan(x.score) and np.isnan(y.score))
        if x.T_j_i is None:
            assert y.T_j_i is None
        else:
            np.testing.assert_array_equal(x.T_j_i, y.T_j_i)
            np.testing.assert_array_equal(x.covariance, y.covariance)
    np.testing.assert_array_equal(a.poses, b.poses)


def test_the_searches_on_threads_give_exactly_the_serial_result(rng):
    # A lap and a half with a drift the local search closes and a heading jump only the
    # global search reaches: closures found, poses corrected mid-run (each correction a new
    # version of the poses, whose searches started ahead are dropped), global candidates
    # matched at once. Every closure, score and pose is the serial run's, bit for bit.
    lap, _, odo, scans = _jumped_lap(rng)
    params = LoopParams(max_search_m=1.0, drift_rad_per_sqrt_m=0.06, global_every=5, backend="scipy")
    own = _precise_steps(len(odo))
    serial = close_loops(scans, odo, replace(params, workers=1), own)
    assert serial.counts["accepted"] >= 2
    assert any(c.wide for c in serial.closures)
    for workers in (2, 3):
        _same_closures(serial, close_loops(scans, odo, replace(params, workers=workers), own))
    # The local search alone, on a drift it closes within its window.
    small = _drifted(lap, yaw_per_step=0.001)
    scans = _scans_of(_square_world(rng), lap)
    local = replace(params, global_every=0, max_search_m=8.0)
    serial = close_loops(scans, small, replace(local, workers=1))
    assert serial.counts["accepted"] >= 1
    _same_closures(serial, close_loops(scans, small, replace(local, workers=2)))


def test_the_number_of_threads_is_checked():
    with pytest.raises(ValueError, match="workers must be at least 1, not 0"):
        LoopParams(workers=0)
