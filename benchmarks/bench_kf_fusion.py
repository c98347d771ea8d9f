"""What "never worse than its best input" asks of a filter: two odometries of a known
trajectory with errors drawn from known models, fused with those true models.

Both inputs measure the same increments, the motion (forward, cross-track, yaw) over each
of ``--runs`` VO runs of a simulated lap (0.49 s each, 82 for a 40 s drive). Each input's
error along each axis is a stationary Gaussian sequence: a white part and a correlated
part, a first-order Gauss-Markov process where consecutive errors correlate positively
(VO: the frame and scale a run shares with the next, its errors over seconds) or a
shared-step part of opposite sign where they correlate negatively (ICP: the scan two
steps share). Their levels are the laps' (``--levels DIR``: the per-run errors of VO and
of ICP's own steps chained over the same run against the truth on laps 1-2 of both loops,
``bench_kf.py --keep DIR``; their RMS and lag-1/2/3 correlations, kalman.gauss_markov_fit),
VO's scaled by ``c`` to sweep the two inputs' ratio.

Fused with the TRUE models and no motion prior, the best linear estimate of the
increments is generalised least squares on both inputs (the Kalman filter's and the
Rauch-Tung-Striebel smoother's answer for this model): the smoother uses the whole lap,
the causal filter at each run only the runs so far (its pose there is the prefix's
estimate, composed). The ATE (RMS position error over the run ends after the best rigid
alignment, as rigcal scores a path) of each input and of the fused path is computed per realization, and
"worse" counts the realizations where the fused ATE is above the better input's: the
rate at which an optimal filter misses the target on a lap, by the inputs' ratio.

The rule (``kalman.VO_PAYS``, docs/localization.md): along an axis, VO enters only where
its error over a window of ``--window`` runs (the guard's longest) has at most q* times
the variance of ICP's over the same window, both under their models; otherwise the filter
follows ICP there. ``--rule`` sweeps q*: "worse" and the mean fused ATE over ICP's.

    .venv/bin/python benchmarks/bench_kf_fusion.py --levels DIR [--realizations 2000]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from scipy.stats import chi2

from bench_kf import kept_measurements, planar_at_stamps, step_nees
from bench_tracks import seeds_of
from rigcal.arrays import FloatArray
from rigcal.geometry import pose_of, se2
from rigcal.localize import kalman

AXES = ("forward", "cross-track", "yaw")
RUN_S = kalman.VO_RUN_S
SPEED_M_S = 0.8  # the cubicle loop's 33.8 m in 43 s


WINDOWS = (1, 2, 4, 8, 16, 32)
PHIS = np.linspace(0.05, 0.99, 95)


def measured_levels(root: Path, seeds: str) -> dict[str, FloatArray]:
    """Per input ("icp", "vo"): each axis's error summed over windows of 1, 2, 4 ... 32
    chained VO runs, its mean square (len(WINDOWS), 3), on the kept laps: VO's runs and
    ICP's own steps chained over each run (kalman._IcpReference) against the truth, in the
    run's frame. VO's runs beyond the chi-square 0.999 point at the lap's median NEES (a
    wrong scale) end no window, as ``bench_kf.py --windows`` does."""
    args = argparse.Namespace(keep=root, duration_s=40.0)
    params = kalman.KF_MODES["weighted"]
    sums: dict[str, list[list[FloatArray]]] = {"icp": [[] for _ in WINDOWS], "vo": [[] for _ in WINDOWS]}
    for seed in seeds_of(seeds):
        for name in ("cubicle-loop", "corridor-loop"):
            ms, gt, truth_s = kept_measurements(args, name, seed, params)
            reference = kalman._IcpReference([m for m in ms if m.source == "icp"], params)
            vo = sorted((m for m in ms if m.source == "vo" and m.covariance[0, 0] < 1.0), key=lambda m: m.t1)
            nees = step_nees(vo, gt, truth_s)
            good = nees < chi2.ppf(0.999, 3) * np.median(nees) / chi2.ppf(0.5, 3)
            ends = planar_at_stamps(gt, truth_s, np.array([[m.t0, m.t1] for m in vo]).ravel()).reshape(
                -1, 2, 3
            )
            errors = {"icp": np.full((len(vo), 3), np.nan), "vo": np.full((len(vo), 3), np.nan)}
            for k, m in enumerate(vo):
                truth = pose_of(np.linalg.inv(se2(ends[k, 0])) @ se2(ends[k, 1]))
                ref = reference.between(m.t0, m.t1, m.t1)
                if not good[k] or ref is None:
                    continue
                for src, motion in (("vo", m.motion), ("icp", ref[0])):
                    e = motion - truth
                    e[2] = np.angle(np.exp(1j * e[2]))
                    errors[src][k] = e
            chained = np.array([k > 0 and vo[k].t0 == vo[k - 1].t1 for k in range(len(vo))])
            for src, e in errors.items():
                for i, w in enumerate(WINDOWS):
                    for k in range(w - 1, len(vo)):
                        part = e[k - w + 1 : k + 1]
                        if chained[k - w + 2 : k + 1].all() and np.isfinite(part).all():
                            sums[src][i].append(part.sum(axis=0))
    return {src: np.array([np.mean(np.square(v), axis=0) for v in rows]) for src, rows in sums.items()}


def window_design(phi: float, windows: tuple[int, ...] = WINDOWS) -> FloatArray:
    """The variance of an error summed over w runs (rows: ``windows``) per unit variance of
    its three parts (columns): white, a part two consecutive runs share with opposite
    signs (s_k - s_(k-1): chained it cancels, 2 for any window) and a first-order
    Gauss-Markov part correlating by phi per run."""
    w = np.asarray(windows, dtype=float)
    gm = np.array([n + 2.0 * sum((n - j) * phi**j for j in range(1, int(n))) for n in w])
    return np.column_stack([w, np.full_like(w, 2.0), gm])


def fit_model(chain_var: FloatArray) -> tuple[FloatArray, float]:
    """One axis's error model fitted to its windows' mean squares (len(WINDOWS),): the
    three parts' variances (white, shared, Gauss-Markov) >= 0 and the Gauss-Markov phi,
    least squares on the relative misfit over a grid of phi."""
    from scipy.optimize import nnls

    best: tuple[float, FloatArray, float] = (np.inf, np.zeros(3), 0.0)
    for phi in PHIS:
        A = window_design(float(phi)) / chain_var[:, None]
        coef, res = nnls(A, np.ones(len(chain_var)))
        if res < best[0]:
            best = (res, coef, float(phi))
    return best[1], best[2]


def error_covariance(parts: FloatArray, phi: float, n: int) -> FloatArray:
    """The (n, n) covariance of one axis's errors over n runs under the fitted model."""
    i = np.arange(n)
    lag = np.abs(i[:, None] - i[None, :])
    white, shared, gm = parts
    out: FloatArray = (
        np.where(lag == 0, white + 2.0 * shared, 0.0)
        + np.where(lag == 1, -shared, 0.0)
        + gm * phi ** lag.astype(float)
    )
    return out


def trajectory(n: int) -> FloatArray:
    """The true increments (n, 3) of a rectangular loop driven at SPEED_M_S: 10 s straight,
    a 90 degree turn over 2 s, and so on."""
    t = (np.arange(n) + 0.5) * RUN_S
    turning = (t % 12.0) >= 10.0
    yaw = np.where(turning, (np.pi / 2) / 2.0 * RUN_S, 0.0)
    return np.column_stack([np.full(n, SPEED_M_S * RUN_S), np.zeros(n), yaw])


def compose(u: FloatArray) -> FloatArray:
    """Positions (..., n, 2) at the ends of increments u (..., n, 3) chained from the origin."""
    heading = np.cumsum(u[..., 2], axis=-1) - u[..., 2]
    c, s = np.cos(heading), np.sin(heading)
    dx = c * u[..., 0] - s * u[..., 1]
    dy = s * u[..., 0] + c * u[..., 1]
    return np.stack([np.cumsum(dx, axis=-1), np.cumsum(dy, axis=-1)], axis=-1)


def ate(positions: FloatArray, truth: FloatArray) -> FloatArray:
    """Position RMSE (...,) over the run ends after the best rigid alignment, as rigcal
    scores a path (:func:`rigcal.localize.metrics.ate_rmse`)."""
    a = positions - positions.mean(axis=-2, keepdims=True)
    b = truth - truth.mean(axis=-2, keepdims=True)
    H = np.einsum("...ni,...nj->...ij", a, b)
    yaw = np.arctan2(H[..., 0, 1] - H[..., 1, 0], H[..., 0, 0] + H[..., 1, 1])
    c, s = np.cos(yaw)[..., None], np.sin(yaw)[..., None]
    x = c * a[..., 0] - s * a[..., 1] - b[..., 0]
    y = s * a[..., 0] + c * a[..., 1] - b[..., 1]
    out: FloatArray = np.sqrt(np.mean(x**2 + y**2, axis=-1))
    return out


def fuse(
    z1: FloatArray, z2: FloatArray, S1: list[FloatArray], S2: list[FloatArray | None], causal: bool
) -> FloatArray:
    """The fused positions (N, n, 2) of increments measured by both inputs (N, n, 3) under
    their error covariances per axis (n, n): GLS, u = z1 + S1 (S1 + S2)^-1 (z2 - z1) per
    axis; ``causal``: at each run k from runs 1 ... k alone (the filter), otherwise from
    all (the smoother). Along an axis whose S2 is None VO is not fused: z1 kept."""
    n = z1.shape[1]
    if not causal:
        u = z1.copy()
        for a in range(3):
            if S2[a] is None:
                continue
            K = np.linalg.solve((S1[a] + S2[a]).T, S1[a].T).T
            u[..., a] = z1[..., a] + (z2[..., a] - z1[..., a]) @ K.T
        return compose(u)
    out = np.empty((*z1.shape[:2], 2))
    for k in range(1, n + 1):
        u = z1[:, :k].copy()
        for a in range(3):
            if S2[a] is None:
                continue
            A, B = S1[a][:k, :k], S2[a][:k, :k]
            K = np.linalg.solve((A + B).T, A.T).T
            u[..., a] = z1[:, :k, a] + (z2[:, :k, a] - z1[:, :k, a]) @ K.T
        out[:, k - 1] = compose(u)[:, -1]
    return out


def window_variance(S: FloatArray, w: int) -> float:
    """The variance of an axis's errors summed over w consecutive runs."""
    return float(S[:w, :w].sum())


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--levels", type=Path, required=True, help="bench_kf.py's --keep folder (laps 1-2 read).")
    ap.add_argument("--seeds", default="1-2", help="The laps the levels are measured on.")
    ap.add_argument("--runs", type=int, default=82, help="VO runs a lap (82: 40 s).")
    ap.add_argument("--realizations", type=int, default=2000)
    ap.add_argument("--scales", default="0.25,0.5,1,1.5,2,3", help="VO's error sigmas times these.")
    ap.add_argument("--rule", default="0.5,1,2,4,8,16,inf", help="The rule's q* values swept.")
    ap.add_argument("--window", type=int, default=kalman.VO_GUARD_RUNS, help="The rule's window (runs).")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    levels = measured_levels(args.levels, args.seeds)
    print(f"Laps {args.seeds} of both loops, VO runs of {RUN_S} s: each input's error summed over windows of")
    print(
        "w runs, RMS against the truth (measured) and under the fitted model (white, shared, Gauss-Markov)\n"
    )
    print("| input | axis | " + " | ".join(f"w={w} measured / model" for w in WINDOWS), end=" ")
    print("| white RMS | shared RMS | Gauss-Markov RMS | phi per run | time constant (s) |")
    print("|---" * (7 + len(WINDOWS)) + "|")
    models: dict[str, list[tuple[FloatArray, float]]] = {}
    for src, chain_var in levels.items():
        models[src] = [fit_model(chain_var[:, a]) for a in range(3)]
        for a, (parts, phi) in enumerate(models[src]):
            unit = (1e3, "mm") if a < 2 else (1e3, "mrad")
            fitted = window_design(phi) @ parts
            cells = " | ".join(
                f"{unit[0] * np.sqrt(m):.2f} / {unit[0] * np.sqrt(f):.2f}"
                for m, f in zip(chain_var[:, a], fitted, strict=True)
            )
            tau = -RUN_S / np.log(phi)
            print(
                f"| {src} | {AXES[a]} ({unit[1]}) | {cells} | "
                + " | ".join(f"{unit[0] * np.sqrt(v):.2f}" for v in parts)
                + f" | {phi:.2f} | {tau:.2f} |"
            )
    n, N = args.runs, args.realizations
    rng = np.random.default_rng(args.seed)
    u = trajectory(n)
    truth = compose(u)
    S_icp = [error_covariance(*models["icp"][a], n) for a in range(3)]
    base_vo = [error_covariance(*models["vo"][a], n) for a in range(3)]
    L_icp = [np.linalg.cholesky(S + 1e-18 * np.eye(n)) for S in S_icp]
    rules = [float(q) for q in args.rule.split(",")]
    print(
        f"\n{N} realizations of a {n * RUN_S:.0f} s lap per row; 'worse': the fused ATE above the better "
        "input's (share of realizations); window variance ratio: VO's over ICP's over "
        f"{args.window} runs, forward / cross-track / yaw\n"
    )
    print(
        "| VO sigmas x | window variance ratio VO / ICP | ICP ATE mean (cm) | VO ATE mean (cm) "
        "| VO / ICP ATE | ICP alone worse | VO alone worse | filter ATE mean (cm) | filter worse "
        "| smoother ATE mean (cm) | smoother worse | "
        + " | ".join(f"rule q*={q:g}: worse, mean over ICP" for q in rules)
        + " |"
    )
    print("|---" * (11 + len(rules)) + "|")
    for c in (float(v) for v in args.scales.split(",")):
        S_vo = [c**2 * S for S in base_vo]
        L_vo = [np.linalg.cholesky(S + 1e-18 * np.eye(n)) for S in S_vo]
        e1 = np.stack([rng.standard_normal((N, n)) @ L.T for L in L_icp], axis=-1)
        e2 = np.stack([rng.standard_normal((N, n)) @ L.T for L in L_vo], axis=-1)
        z1, z2 = u + e1, u + e2
        a_icp, a_vo = ate(compose(z1), truth), ate(compose(z2), truth)
        best = np.minimum(a_icp, a_vo)
        q = [window_variance(S_vo[a], args.window) / window_variance(S_icp[a], args.window) for a in range(3)]
        filt = ate(fuse(z1, z2, S_icp, list[FloatArray | None](S_vo), causal=True), truth)
        smooth = ate(fuse(z1, z2, S_icp, list[FloatArray | None](S_vo), causal=False), truth)
        cells = []
        for qs in rules:
            S2: list[FloatArray | None] = [S_vo[a] if q[a] <= qs else None for a in range(3)]
            ruled = (
                ate(fuse(z1, z2, S_icp, S2, causal=True), truth) if any(s is not None for s in S2) else a_icp
            )
            cells.append(f"{np.mean(ruled > best + 1e-12):.3f}, {np.mean(ruled) / np.mean(a_icp):.3f}")
        print(
            f"| {c:g} | {' / '.join(f'{v:.2f}' for v in q)} "
            f"| {100 * a_icp.mean():.2f} | {100 * a_vo.mean():.2f} "
            f"| {a_vo.mean() / a_icp.mean():.2f} | {np.mean(a_icp > best):.3f} | {np.mean(a_vo > best):.3f} "
            f"| {100 * filt.mean():.2f} | {np.mean(filt > best):.3f} "
            f"| {100 * smooth.mean():.2f} | {np.mean(smooth > best):.3f} | " + " | ".join(cells) + " |",
            flush=True,
        )


if __name__ == "__main__":
    main()
