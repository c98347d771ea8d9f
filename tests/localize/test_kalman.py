"""The Kalman filter of Section VI: constant velocity, increments as relative-pose measurements."""

from __future__ import annotations

import numpy as np
import pytest

from rigcal.localize import kalman


def _plain(**changes):
    """The weighted filter without the remedies (each step's own covariance as it is),
    with ``changes``."""
    base = {"icp_own": 1.0, "icp_shared": 0.0, "vo_own": 1.0, "vo_shared": 0.0}
    base |= {"gate": 0.0, "gate_window": 1, "vo_weak_only": 0.0}
    base |= {"vo_memory_s": 0.0, "vo_forward_adapt": False, "vo_forward_window": 0}
    base |= {"vo_guard": 0, "vo_forward_reference": False}
    return kalman.KfParams(**{**base, **changes})


def _arc(n=200, dt=0.1, v=1.0, w=0.2):
    t = np.arange(n) * dt
    yaw = w * t
    x = v / w * np.sin(yaw)
    y = v / w * (1 - np.cos(yaw))
    return t, np.column_stack([x, y, yaw])


def test_exact_increments_reproduce_the_path():
    t, poses = _arc()
    st, est = kalman.fuse(kalman.increments(t, poses, kalman.ICP_SIGMAS))
    assert np.allclose(st, t)
    assert np.max(np.linalg.norm(est[:, :2] - poses[:, :2], axis=1)) < 0.1
    assert np.max(np.abs(est[:, 2] - poses[:, 2])) < 0.01


def _scaled(poses, forward, cross):
    """Odometry whose every step is stretched forward and sideways in the rig's frame."""
    out = [poses[0]]
    for k in range(1, len(poses)):
        c, s = np.cos(poses[k - 1, 2]), np.sin(poses[k - 1, 2])
        d = poses[k, :2] - poses[k - 1, :2]
        lx, ly = c * d[0] + s * d[1], -s * d[0] + c * d[1]
        lx, ly = lx * forward, lx * cross + ly
        p = out[-1]
        cc, ss = np.cos(p[2]), np.sin(p[2])
        out.append(
            np.array(
                [p[0] + cc * lx - ss * ly, p[1] + ss * lx + cc * ly, p[2] + poses[k, 2] - poses[k - 1, 2]]
            )
        )
    return np.array(out)


def test_forward_speed_follows_vo_and_cross_track_follows_icp():
    t, poses = _arc(w=1e-6)
    icp = _scaled(poses, 1.2, 0.0)  # ICP overestimates forward motion by 20 %
    vo = _scaled(poses, 1.0, 0.1)  # VO drifts sideways by 10 % of the distance
    ms = kalman.increments(t, icp, kalman.ICP_SIGMAS) + kalman.increments(t, vo, kalman.VO_SIGMAS)
    _, est = kalman.fuse(ms)
    travelled = est[-1, 0]
    assert travelled == pytest.approx(poses[-1, 0], rel=0.05)  # nearer VO's 1.0 than ICP's 1.2
    assert abs(est[-1, 1]) < 0.3 * abs(vo[-1, 1])  # most of VO's sideways drift rejected


def test_no_measurements_give_an_empty_path():
    st, est = kalman.fuse([])
    assert st.shape == (0,)
    assert est.shape == (0, 3)


def test_repeated_stamps_are_skipped():
    t = np.array([0.0, 0.1, 0.1, 0.2])
    p = np.array([[0, 0, 0], [0.1, 0, 0], [0.1, 0, 0], [0.2, 0, 0]], dtype=float)
    assert len(kalman.increments(t, p, kalman.ICP_SIGMAS)) == 2


def test_icp_steps_the_walls_do_not_constrain_leave_the_forward_speed_to_vo():
    """Along a corridor whose ends the laser cannot see, ICP's forward step is only the
    motion it started from (here 50 % too long): flagged, it does not pull the path."""
    t, poses = _arc(w=1e-6)
    icp = _scaled(poses, 1.5, 0.0)
    vo = _scaled(poses, 1.0, 0.0)
    open_forward = np.ones(len(t), dtype=bool)
    for flag, near_vo in ((None, False), (open_forward, True)):
        ms = kalman.increments(t, icp, kalman.ICP_SIGMAS, flag) + kalman.increments(t, vo, kalman.VO_SIGMAS)
        _, est = kalman.fuse(ms)
        assert bool(est[-1, 0] == pytest.approx(poses[-1, 0], rel=0.01)) is near_vo


def test_vo_runs_without_a_scale_leave_the_forward_speed_to_icp():
    """A VO run whose length is a guess (no scale: the last measured speed, here a tenth
    of the true one) measures no forward speed, and a failed run (a constant-velocity
    guess, here a standstill) nothing: flagged, neither pulls the path off ICP's."""
    t, poses = _arc(w=1e-6)
    icp = _scaled(poses, 1.0, 0.0)
    vo = _scaled(poses, 0.1, 0.0)
    icp_ms = kalman.increments(t, icp, kalman.ICP_SIGMAS)
    unflagged = kalman.fuse(icp_ms + kalman.increments(t, vo, kalman.VO_SIGMAS))[1]
    assert unflagged[-1, 0] < 0.5 * poses[-1, 0]  # VO's weight on forward speed: pulled back
    guessed = np.ones(len(t), dtype=bool)
    flagged = kalman.fuse(icp_ms + kalman.increments(t, vo, kalman.VO_SIGMAS, open_forward=guessed))[1]
    assert flagged[-1, 0] == pytest.approx(poses[-1, 0], rel=0.01)
    still = _scaled(poses, 0.0, 0.0)
    failed = np.zeros(len(t), dtype=bool)
    assert kalman.increments(t, still, kalman.VO_SIGMAS, measured=failed) == []
    alone = kalman.fuse(icp_ms + kalman.increments(t, still, kalman.VO_SIGMAS, measured=failed))[1]
    assert np.allclose(alone, kalman.fuse(icp_ms)[1])


def test_vo_runs_become_measurements_by_their_status():
    t, poses = _arc(n=5)
    ms = kalman.vo_increments(t, poses, ["ok", "no-scale", "failed", "carried"])
    assert [(m.t0, m.t1) for m in ms] == [(t[0], t[1]), (t[1], t[2]), (t[3], t[4])]
    dt = t[1] - t[0]
    forward = [np.sqrt(m.covariance[0, 0]) for m in ms]
    assert forward == pytest.approx([kalman.VO_SIGMAS[0] * dt, kalman.OPEN_SIGMA_M, kalman.VO_SIGMAS[0] * dt])
    assert all(
        np.sqrt(np.diag(m.covariance)[1:]) == pytest.approx(np.array(kalman.VO_SIGMAS[1:]) * dt) for m in ms
    )
    assert all(m.source == "vo" for m in ms)
    with pytest.raises(ValueError, match="3 run statuses for 5 poses"):
        kalman.vo_increments(t, poses, ["ok", "ok", "ok"])


def test_vo_runs_with_their_own_covariances():
    t, poses = _arc(n=4)
    own = np.stack([np.diag([1e-4, 4e-4, 1e-6])] * 3)
    own[2] = np.nan  # a run whose covariance is unknown is left out
    ms = kalman.vo_increments(t, poses, ["ok", "no-scale", "ok"], own)
    assert len(ms) == 2
    assert np.allclose(ms[0].covariance, own[0])
    assert ms[1].covariance[0, 0] == kalman.OPEN_SIGMA_M**2  # no scale: open forward
    assert ms[1].covariance[1, 1] == own[1][1, 1]
    with pytest.raises(ValueError, match=r"VO covariances of shape \(2, 3, 3\), expected \(3, 3, 3\)"):
        kalman.vo_increments(t, poses, ["ok", "ok", "ok"], own[:2])


def _own(t, sigmas_m_rad):
    """Per-step covariances (N, 3, 3) of constant 1-sigma (forward m, cross m, yaw rad)."""
    return np.stack([np.diag(np.square(sigmas_m_rad))] * len(t))


def test_a_precise_input_is_reproduced_without_lag():
    """Relative-pose measurements (the clone of the pose at each step's start): a precise
    input's path comes back to the micrometre, in turns too (the paper's velocity
    measurements lag half a step there)."""
    t, poses = _arc(n=300, dt=0.025, w=0.6)
    res = kalman.run_filter(kalman.increments(t, poses, _own(t, (1e-5, 1e-5, 1e-6))))
    assert np.allclose(res.stamps_s, t)
    assert np.max(np.linalg.norm(res.poses[:, :2] - poses[:, :2], axis=1)) < 1e-4
    assert np.max(np.abs(res.poses[:, 2] - poses[:, 2])) < 1e-5
    # The filter's pose covariance grows as the steps' errors add up.
    assert np.all(np.diff([np.trace(c[:2, :2]) for c in res.covariances[1:]]) > -1e-15)


def test_a_well_constrained_input_dominates_a_poor_one_at_another_rate():
    """ICP at 40 Hz good to 1 mm per step, VO runs at 10 Hz each 20 % long, good to 5 cm:
    the fused path stays with ICP."""
    t, poses = _arc(n=401, dt=0.025, w=0.3)
    ms = kalman.increments(t, poses, _own(t, (1e-3, 1e-3, 1e-4)), source="icp")
    vo = _scaled(poses[::4], 1.2, 0.0)
    ms += kalman.increments(t[::4], vo, _own(t[::4], (0.05, 0.05, 0.01)), source="vo")
    res = kalman.run_filter(ms)
    end_error = np.linalg.norm(res.poses[-1, :2] - poses[-1, :2])
    assert end_error < 0.02 * np.linalg.norm(vo[-1, :2] - poses[-1, :2])


def test_where_icp_is_open_along_a_corridor_vo_carries_the_forward_motion():
    t, poses = _arc(n=201, dt=0.025, w=1e-6)
    icp_cov = _own(t, (kalman.OPEN_SIGMA_M, 1e-3, 1e-4))
    icp = _scaled(poses, 0.5, 0.0)  # its step along the corridor is only its guess
    ms = kalman.increments(t, icp, icp_cov) + kalman.increments(
        t[::4], poses[::4], _own(t[::4], (0.01, 0.05, 0.01))
    )
    res = kalman.run_filter(ms)
    assert res.poses[-1, 0] == pytest.approx(poses[-1, 0], rel=0.01)


def test_the_filters_settings_are_checked():
    with pytest.raises(ValueError, match="weights 'equal': expected one of covariance, fixed"):
        kalman.KfParams(weights="equal")
    with pytest.raises(ValueError, match="must be > 0"):
        kalman.KfParams(accel_sigma=0.0)
    t, poses = _arc(n=4)
    with pytest.raises(ValueError, match=r"covariances of shape \(2, 3, 3\), expected \(4, 3, 3\)"):
        kalman.increments(t, poses, np.zeros((2, 3, 3)))


def _noisy(poses, rng, sigma_m):
    """Odometry whose every step has white noise of sigma_m (m) in x and y."""
    out = [poses[0]]
    for k in range(1, len(poses)):
        step = kalman.pose_of(np.linalg.inv(kalman.se2(poses[k - 1])) @ kalman.se2(poses[k]))
        step[:2] += rng.normal(0.0, sigma_m, 2)
        out.append(kalman.pose_of(kalman.se2(out[-1]) @ kalman.se2(step)))
    return np.array(out)


def test_an_input_whose_covariance_is_too_small_is_matched_to_its_innovations():
    """VO claims 2 mm per run but errs by 2 cm: with covariance matching (the default) its
    innovations against a precise ICP scale its covariance up, and the path stays with
    ICP; without, VO pulls it off by several times as much."""
    rng = np.random.default_rng(0)
    t, poses = _arc(n=801, dt=0.025, w=0.3)
    icp = _noisy(poses, rng, 2e-4)
    ms = kalman.increments(t, icp, _own(t, (2e-4, 2e-4, 1e-5)), source="icp")
    vo = _noisy(poses[::4], rng, 0.02)
    ms += kalman.increments(t[::4], vo, _own(t[::4], (2e-3, 2e-3, 1e-4)), source="vo")
    errors = {}
    for adapt in (False, True):
        params = _plain(adapt=adapt)
        res = kalman.run_filter(ms, params)
        errors[adapt] = np.sqrt(np.mean(np.sum((res.poses[:, :2] - poses[:, :2]) ** 2, axis=1)))
    icp_error = np.sqrt(np.mean(np.sum((icp[:, :2] - poses[:, :2]) ** 2, axis=1)))
    assert errors[True] < 0.5 * errors[False]
    assert errors[True] < 2.0 * icp_error + 1e-3


def _shared_noise_steps(poses, rng, cov, rho, sign=-1.0):
    """Steps (N - 1, 3) whose errors are e_k = s_k + sign s_(k-1) + w_k: s (per step
    boundary) of covariance rho x ``cov`` (3, 3), w (per step) of ``cov``; sign -1 as
    ICP's scans, +1 as VO's frames."""
    s = rng.multivariate_normal(np.zeros(3), rho * cov, len(poses))
    w = rng.multivariate_normal(np.zeros(3), cov, len(poses))
    steps = [
        kalman.pose_of(np.linalg.inv(kalman.se2(poses[k - 1])) @ kalman.se2(poses[k]))
        + s[k]
        + sign * s[k - 1]
        + w[k]
        for k in range(1, len(poses))
    ]
    out = [poses[0]]
    for step in steps:
        out.append(kalman.pose_of(kalman.se2(out[-1]) @ kalman.se2(step)))
    return np.array(out)


def _end_nees(source, sign, dt, cov, rho, seed):
    """The filter's end pose NEES over 60 drives whose steps of ``source`` share errors
    (:func:`_shared_noise_steps`), with the shared error modelled ("shared") and with the
    steps taken as independent under their whole error's covariance ("independent")."""
    rng = np.random.default_rng(seed)
    t, poses = _arc(n=round(2.0 / dt) + 1, dt=dt, v=0.5, w=0.3)
    nees = {"shared": [], "independent": []}
    for _ in range(60):
        steps = _shared_noise_steps(poses, rng, cov, rho, sign)
        for key, params, step_cov in (
            ("shared", _plain(adapt=False, **{f"{source}_shared": rho}), cov),
            ("independent", _plain(adapt=False), (1 + 2 * rho) * cov),
        ):
            ms = kalman.increments(t, steps, np.stack([step_cov] * len(t)), source=source)
            res = kalman.run_filter(ms, params)
            e = res.poses[-1] - poses[-1]
            nees[key].append(float(e @ np.linalg.solve(res.covariances[-1], e)))
    return {k: float(np.mean(v)) for k, v in nees.items()}


def test_icp_steps_sharing_their_scans_errors_keep_the_filter_consistent():
    """Consecutive steps sharing a scan: each step errs by (1 + 2 rho) times its
    covariance, a chain by the sum of its steps' only. With ``icp_shared`` = rho the
    filter's end pose is consistent (NEES near 3) whether its steps are read one by one
    or chained; taking the steps as independent with their whole error's covariance,
    it overstates the chain's (NEES well under 3)."""
    nees = _end_nees("icp", -1.0, 0.025, np.diag([1e-6, 1e-6, 1e-8]), 0.75, seed=3)
    assert 2.0 < nees["shared"] < 4.2
    assert nees["independent"] < 0.6 * nees["shared"]


def test_vo_runs_sharing_their_frames_errors_keep_the_filter_consistent():
    """Consecutive VO runs err together (e_k = w_k + s_k + s_(k-1)): a chain of runs errs
    more than its runs' covariances summed. With ``vo_shared`` = rho the filter's end pose
    is consistent (NEES near 3); taking the runs as independent with each run's whole
    error covariance, it understates the chain's (NEES well over 3)."""
    nees = _end_nees("vo", 1.0, 0.1, np.diag([1e-5, 1e-5, 1e-7]), 1.0, seed=5)
    assert 2.0 < nees["shared"] < 4.2
    assert nees["independent"] > 1.4 * nees["shared"]


def test_a_vo_run_far_from_a_precise_icp_is_gated_out():
    """One VO run 10 cm off among runs that agree with ICP: the innovation test leaves it
    out, so the path is the one without it; without the gate it pulls the path off."""
    t, poses = _arc(n=201, dt=0.025, w=0.3)
    icp = kalman.increments(t, poses, _own(t, (1e-3, 1e-3, 1e-4)), source="icp")
    vo = kalman.increments(t[::4], poses[::4], _own(t[::4], (1e-3, 1e-3, 1e-4)), source="vo")
    bad = vo[20]
    vo_bad = [
        *vo[:20],
        kalman.Increment(bad.t0, bad.t1, bad.motion + np.array([0.1, 0.0, 0.0]), bad.covariance, "vo"),
        *vo[21:],
    ]
    params = _plain(adapt=False, gate=kalman.VO_GATE)
    without = kalman.run_filter(icp + vo[:20] + vo[21:], params).poses
    gated = kalman.run_filter(icp + vo_bad, params).poses
    ungated = kalman.run_filter(icp + vo_bad, _plain(adapt=False)).poses
    assert np.max(np.abs(gated - without)) < 1e-9
    assert np.max(np.linalg.norm(ungated[:, :2] - poses[:, :2], axis=1)) > 0.02


def test_vo_enters_only_where_the_filter_is_weaker():
    """ICP precise in every direction: VO runs 20 % long change nothing. ICP open along a
    corridor: VO carries the forward motion there."""
    t, poses = _arc(n=201, dt=0.025, w=1e-6)
    vo = kalman.increments(
        t[::4], _scaled(poses[::4], 1.2, 0.0), _own(t[::4], (0.01, 0.05, 0.01)), source="vo"
    )
    params = _plain(adapt=False, vo_weak_only=kalman.VO_WEAK_ONLY)
    precise = kalman.increments(t, poses, _own(t, (1e-4, 1e-4, 1e-5)), source="icp")
    alone = kalman.run_filter(precise, params).poses
    assert np.max(np.abs(kalman.run_filter(precise + vo, params).poses[-1] - alone[-1])) < 1e-9
    every_direction = kalman.run_filter(precise + vo, _plain(adapt=False))
    assert np.max(np.abs(every_direction.poses[-1] - alone[-1])) > 1e-6
    open_icp = kalman.increments(
        t, _scaled(poses, 0.5, 0.0), _own(t, (kalman.OPEN_SIGMA_M, 1e-4, 1e-5)), source="icp"
    )
    res = kalman.run_filter(open_icp + vo, params)
    assert res.poses[-1, 0] == pytest.approx(1.2 * poses[-1, 0], rel=0.02)  # VO's forward, not ICP's guess


def test_the_papers_filter_by_name_has_none_of_the_additions():
    fixed = kalman.KF_MODES["fixed"]
    assert (fixed.weights, fixed.adapt, fixed.icp_shared, fixed.gate, fixed.vo_weak_only) == (
        "fixed",
        False,
        0,
        0,
        0,
    )
    weighted = kalman.KF_MODES["weighted"]
    assert weighted == kalman.KfParams()
    assert weighted.icp_shared == kalman.ICP_SHARED
    assert min(kalman.ICP_SHARED) > 0
    assert min(kalman.VO_SHARED) > 0
    assert weighted.gate > 0
    assert weighted.vo_weak_only > 0


def test_the_error_models_fractions_come_from_the_measured_ratios_and_correlations():
    own, shared = np.array(kalman.shared_error_fractions((2.0, 1.0, 0.5), (-0.25, 0.1, 0.3)))
    assert own + 2 * shared == pytest.approx([2.0, 1.0, 0.5])  # each axis's variance ratio
    assert shared / (own + 2 * shared) == pytest.approx([0.25, 0.1, 0.3])
    # A correlation beyond a two-step share's reach is taken at MAX_LAG1.
    own, shared = np.array(kalman.shared_error_fractions((1.0, 1.0, 1.0), (0.6, -0.7, 0.0)))
    assert shared == pytest.approx([kalman.MAX_LAG1, kalman.MAX_LAG1, 0.0])
    assert (own > 0).all()
    icp, vo = (kalman.ICP_VARIANCE_RATIO, kalman.ICP_LAG1), (kalman.VO_VARIANCE_RATIO, kalman.VO_LAG1)
    assert kalman.shared_error_fractions(*icp) == (kalman.ICP_OWN, kalman.ICP_SHARED)
    assert kalman.shared_error_fractions(*vo) == (kalman.VO_OWN, kalman.VO_SHARED)
    with pytest.raises(ValueError, match="ratios > 0"):
        kalman.shared_error_fractions((1.0, 0.0, 1.0), (0.1, 0.1, 0.1))


def test_an_axis_fraction_scales_that_axis_only():
    """icp_own per axis: a step's x standard deviation doubled, its y and yaw kept, moves
    the filter as a step given that covariance outright."""
    t, poses = _arc(n=41, dt=0.1)
    cov = np.diag([1e-4, 4e-4, 1e-6])
    vo = kalman.increments(t, _scaled(poses, 1.1, 0.0), np.stack([cov] * len(t)), source="vo")
    icp = kalman.increments(t, poses, np.stack([cov] * len(t)), source="icp")
    wide = kalman.increments(t, poses, np.stack([np.diag([4e-4, 4e-4, 1e-6])] * len(t)), source="icp")
    by_axis = kalman.run_filter(icp + vo, _plain(adapt=False, icp_own=(4.0, 1.0, 1.0))).poses
    outright = kalman.run_filter(wide + vo, _plain(adapt=False)).poses
    assert np.max(np.abs(by_axis - outright)) < 1e-9


@pytest.mark.parametrize(
    ("bad", "match"),
    [
        ({"icp_own": 0.0}, "icp_own"),
        ({"vo_own": (1.0, 0.0, 1.0)}, "vo_own"),
        ({"vo_shared": -0.1}, "vo_shared"),
        ({"gate_window": 0}, "gate_window"),
    ],
)
def test_the_error_models_settings_are_checked(bad, match):
    with pytest.raises(ValueError, match=match):
        kalman.KfParams(**bad)


def test_vo_runs_each_within_the_gate_but_off_together_fail_the_windowed_gate():
    """Eight VO runs in a row each off by 3 sigma (squared distance about 10, under the
    single gate's 16.3) among runs that agree with ICP: once four runs' distances summed
    fail their test (the fourth run on) the rest are left out, and the path ends less
    than half as far off as with the single-run test alone, which lets all eight in."""
    t, poses = _arc(n=201, dt=0.025, w=0.3)
    # 4.3 mm off: about 3 sigma of the innovation (the filter's prediction from ICP's four
    # steps ending with the run, 1 mm, and the run's own, 1 mm), a squared distance of about 9.
    icp = kalman.increments(t, poses, _own(t, (5e-4, 5e-4, 5e-5)), source="icp")
    vo = kalman.increments(t[::4], poses[::4], _own(t[::4], (1e-3, 1e-3, 1e-4)), source="vo")
    step = np.array([4.3e-3, 0.0, 0.0])
    off = [
        kalman.Increment(m.t0, m.t1, m.motion + step, m.covariance, "vo") if 20 <= k < 28 else m
        for k, m in enumerate(vo)
    ]
    clean = kalman.run_filter(icp + vo, _plain(adapt=False)).poses
    single = kalman.run_filter(icp + off, _plain(adapt=False, gate=kalman.VO_GATE)).poses
    window = kalman.run_filter(icp + off, _plain(adapt=False, gate=kalman.VO_GATE, gate_window=4)).poses
    assert np.linalg.norm(single[-1, :2] - clean[-1, :2]) > 2 * np.linalg.norm(window[-1, :2] - clean[-1, :2])
