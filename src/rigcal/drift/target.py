"""Drift check: has the rig moved since it was calibrated?

A new box-target session (a full one, or just a few captures) is compared with a stored
rig in up to two ways:

1. **Residual test.** The new box ends are projected with the stored T_cam_laser. Their
   reprojection errors e (2P,) should be explained by the measurement noise and by the
   stored calibration's own uncertainty: e ~ N(0, S), S = S_pix + J C_rig J^T, with S_pix
   the ends' pixel covariance (:func:`rigcal.calib.box.refine.pixel_covariance`), J the
   derivative of the pixels with respect to the pose and C_rig the rig's covariance. So
   e^T S^-1 e is chi-square with 2P degrees of freedom when nothing moved.
2. **Pose test** (when the new session has at least ``min_captures_for_solve`` captures):
   a fresh solve T_new with covariance C_new is compared with the stored one in the rig's
   tangent space, d = [log(R_new R_rig^T), t_new - t_rig]; the two sessions are
   independent, so d^T (C_rig + C_new)^-1 d is chi-square with 6 dof when nothing moved.

Each test is run at ``level / (number of tests)`` (Bonferroni), so the chance of a false
alarm on an unmoved rig is at most ``level``. Box ends whose own Mahalanobis distance under
the stored calibration is beyond the solve's inlier gate are wrong picks, not drift: they
are left out of the residual test and reported, unless they are most of the ends (then the
rig has moved too far for any of them to agree).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rigcal.arrays import FloatArray
from rigcal.calib.box.picks import PickSession
from rigcal.calib.box.refine import (
    EndpointSet,
    NoiseModel,
    endpoint_set,
    pixel_covariance,
    whitened_residuals_and_jacobian,
    whitening,
)
from rigcal.calib.box.solve import INLIER_GATE_CHI2, CalibProblem, CalibResult, SolveSettings, solve
from rigcal.errors import CalibrationError, InputError
from rigcal.geometry import tangent_delta
from rigcal.rig import Rig
from rigcal.stats import chi2_sf


@dataclass(frozen=True)
class DriftSettings:
    """Settings of a drift check.

    Attributes:
        level: probability of a false alarm on an unmoved rig (both tests together).
        min_captures_for_solve: a fresh solve (and the pose test) needs this many captures.
        noise: the measurement noise model (default: the one the rig was solved with).
        solve: settings of the fresh solve.
    """

    level: float = 0.01
    min_captures_for_solve: int = 5
    noise: NoiseModel | None = None
    solve: SolveSettings = field(default_factory=SolveSettings)

    def __post_init__(self) -> None:
        if not 0.0 < self.level < 1.0:
            raise ValueError("DriftSettings: level must be in (0, 1)")


@dataclass(frozen=True)
class DriftResult:
    """Outcome of a drift check.

    Attributes:
        drifted: the verdict.
        level: the false-alarm level it was tested at.
        residual: the residual test: ends used and rejected (with their capture names and
            Mahalanobis distances), RMS px, chi2, dof, p_value.
        pose: the pose test (rotation_deg, translation_mm, per-axis differences,
            mahalanobis2, p_value, combined 1-sigma), or None without a fresh solve.
        fresh: the fresh solve, or None.
        reasons: human sentences behind the verdict and any caveats.
    """

    drifted: bool
    level: float
    residual: dict[str, Any]
    pose: dict[str, Any] | None
    fresh: CalibResult | None
    reasons: list[str]

    @property
    def verdict(self) -> str:
        return "drifted" if self.drifted else "ok"


def check_drift(rig: Rig, session: PickSession, settings: DriftSettings | None = None) -> DriftResult:
    """Test a new session against a stored rig (see the module docstring).

    Raises:
        InputError: the rig has no covariance (nothing to test against).
        CalibrationError: the session has fewer than 1 capture usable.
    """
    settings = settings or DriftSettings()
    if rig.covariance is None:
        raise InputError(
            "the rig file has no uncertainty block (covariance); a drift check needs the stored "
            "calibration's covariance: re-solve the rig with `rigcal solve`"
        )
    noise = settings.noise or rig_noise_model(rig)
    meas = endpoint_set(session.observations, noise, use_side_points=True)
    reasons: list[str] = []
    if session.camera.lensmodel != rig.camera.lensmodel or not np.allclose(
        session.camera.intrinsics, rig.camera.intrinsics
    ):
        reasons.append("the session's camera file differs from the rig's camera; the rig's camera is used")
    n_tests = 2 if len(session.observations) >= settings.min_captures_for_solve else 1
    alpha = settings.level / n_tests

    residual, moved_far = _residual_test(rig, meas, noise, alpha)
    names = {o.capture: o.name for o in session.observations}
    for r in residual["rejected"]:
        r["capture"] = names.get(r["capture"], str(r["capture"]))
    if residual["rejected"] and not moved_far:
        listed = ", ".join(
            f"{r['capture']} end {r['end']} ({r['sigma']:.1f} sigma)" for r in residual["rejected"]
        )
        reasons.append(f"left out of the residual test as wrong picks (beyond the inlier gate): {listed}")
    if moved_far:
        reasons.append(
            f"{residual['rejected_ends']} of {residual['ends']} box ends disagree with the stored "
            "calibration beyond the inlier gate"
        )
    elif residual["p_value"] < alpha:
        reasons.append(
            f"the new picks' reprojection errors under the stored calibration are too large for the "
            f"noise (chi2 {residual['chi2']:.1f} over {residual['dof']} dof, p = {residual['p_value']:.2g})"
        )

    pose = None
    fresh = None
    if n_tests == 2:
        try:
            fresh = solve(CalibProblem(rig.camera, session.observations, _with_noise(settings.solve, noise)))
        except CalibrationError as exc:
            reasons.append(f"no fresh solve ({exc}); only the residual test was run")
        else:
            pose = _pose_test(rig, fresh)
            if pose["p_value"] < alpha:
                reasons.append(
                    f"a fresh solve differs by {pose['rotation_deg']:.3f} deg and "
                    f"{pose['translation_mm']:.1f} mm (Mahalanobis^2 {pose['mahalanobis2']:.1f}, "
                    f"p = {pose['p_value']:.2g})"
                )
    else:
        reasons.append(
            f"{len(session.observations)} captures: fewer than {settings.min_captures_for_solve} for a "
            "fresh solve; only the residual test was run"
        )
    drifted = moved_far or residual["p_value"] < alpha or (pose is not None and pose["p_value"] < alpha)
    return DriftResult(drifted, settings.level, residual, pose, fresh, reasons)


def check_drift_board(
    rig: Rig, session_path: str | Path, settings: DriftSettings | None = None
) -> DriftResult:
    """Test a new board session (``method: board``) against a stored rig, whatever
    method the rig was solved with: what is tested is the rig's T_cam_laser.

    1. **Residual test.** The cut ends of each capture's board returns (the solve's
       reduction of a capture to its line, :class:`rigcal.calib.board.plane.CaptureLine`) lie on
       the board's plane (from the corners' PnP) under the stored T: their point-to-plane
       distances e (2C,) ~ N(0, S), S = the capture covariances of the fresh solve's noise
       model (range noise, the board poses' covariances, the per-capture error) + J C_rig
       J^T. Chi-square with 2C dof over the captures the fresh solve kept.
    2. **Pose test** as for box sessions: the fresh board solve against the stored pose.

    Raises:
        InputError: a bad session file; the rig has no covariance.
        CalibrationError: the session cannot be solved (too few captures, parallel boards).
    """
    from rigcal.calib.board.calibrate import calibrate_board

    settings = settings or DriftSettings()
    if rig.covariance is None:
        raise InputError(
            "the rig file has no uncertainty block (covariance); a drift check needs the stored "
            "calibration's covariance: re-solve the rig with `rigcal solve`"
        )
    board = calibrate_board(session_path)
    fresh = board.result
    alpha = settings.level / 2
    reasons: list[str] = []
    if board.session.camera.lensmodel != rig.camera.lensmodel or not np.allclose(
        board.session.camera.intrinsics, rig.camera.intrinsics
    ):
        reasons.append("the session's camera file differs from the rig's camera; the rig's camera is used")
    residual = _board_residual_test(rig, fresh, board.session.observations)
    if residual["p_value"] < alpha:
        reasons.append(
            f"the new board returns lie off their boards' planes under the stored calibration beyond the "
            f"noise (chi2 {residual['chi2']:.1f} over {residual['dof']} dof, p = {residual['p_value']:.2g})"
        )
    pose = _pose_test(rig, fresh)
    if pose["p_value"] < alpha:
        reasons.append(
            f"a fresh solve differs by {pose['rotation_deg']:.3f} deg and {pose['translation_mm']:.1f} mm "
            f"(Mahalanobis^2 {pose['mahalanobis2']:.1f}, p = {pose['p_value']:.2g})"
        )
    drifted = residual["p_value"] < alpha or pose["p_value"] < alpha
    return DriftResult(drifted, settings.level, residual, pose, None, reasons)


def _board_residual_test(rig: Rig, fresh: Any, observations: Any) -> dict[str, Any]:
    """Point-to-plane distances of the kept captures' cut ends under the stored T."""
    from rigcal.calib.board.plane import capture_cov, end_residuals

    T = rig.T_cam_laser
    noise = fresh.noise
    kept = [k for k in range(len(observations)) if fresh.inlier_captures[k]]

    def residuals(T_: FloatArray) -> FloatArray:
        return np.concatenate(
            [end_residuals(T_, observations[k], fresh.lines[k], noise.range_bias_m) for k in kept]
        )

    e = residuals(T)
    # Derivative with respect to the rig's tangent (R = Exp(d) R0, t = t0 + e), by central
    # differences (the residuals are linear in t and smooth in R).
    h = 1e-6
    J = np.zeros((len(e), 6))
    for a in range(6):
        d = np.zeros(6)
        d[a] = h
        J[:, a] = (residuals(_moved(T, d)) - residuals(_moved(T, -d))) / (2 * h)
    S = np.zeros((len(e), len(e)))
    for n, k in enumerate(kept):
        S[2 * n : 2 * n + 2, 2 * n : 2 * n + 2] = capture_cov(T, observations[k], fresh.lines[k], noise)
    assert rig.covariance is not None
    S += J @ rig.covariance @ J.T
    chi2_value = float(e @ np.linalg.solve(S, e)) if len(e) else 0.0
    dof = len(e)
    return {
        "captures": len(observations),
        "used_captures": len(kept),
        "rms_mm": _r(1000.0 * float(np.sqrt(np.mean(e**2))) if len(e) else float("nan"), 3),
        "max_mm": _r(1000.0 * float(np.max(np.abs(e))) if len(e) else float("nan"), 3),
        "chi2": _r(chi2_value, 4),
        "dof": dof,
        "p_value": float(f"{chi2_sf(chi2_value, dof) if dof else 1.0:.4g}"),
    }


def _moved(T: FloatArray, d: FloatArray) -> FloatArray:
    from rigcal.geometry import make_T, rotvec_to_R

    return make_T(rotvec_to_R(d[:3]) @ T[:3, :3], T[:3, 3] + d[3:])


def rig_noise_model(rig: Rig) -> NoiseModel:
    """The noise model the rig was solved with: the noise it used (estimated from its
    session, rig file schema 2's ``uncertainty.noise``), else its provenance's settings,
    else the default."""
    used = rig.uncertainty.get("noise")
    if isinstance(used, dict):
        try:
            return NoiseModel(
                pick_sigma_px=float(used["pick_sigma_px"]["used"]),
                range_sigma_m=float(used["range_sigma_m"]["used"]),
            )
        except (KeyError, TypeError, ValueError):
            pass
    recorded = rig.provenance.get("noise")
    if isinstance(recorded, dict):
        try:
            return NoiseModel(
                pick_sigma_px=float(recorded["pick_sigma_px"]), range_sigma_m=float(recorded["range_sigma_m"])
            )
        except (KeyError, TypeError, ValueError):
            pass
    return NoiseModel()


def _with_noise(settings: SolveSettings, noise: NoiseModel) -> SolveSettings:
    return SolveSettings(ransac=settings.ransac, refine=settings.refine, noise=noise)


def _residual_test(
    rig: Rig, meas: EndpointSet, noise: NoiseModel, alpha: float
) -> tuple[dict[str, Any], bool]:
    """The residual test; also whether most ends are beyond the gate (moved far)."""
    camera = rig.camera
    T = rig.T_cam_laser
    P = len(meas.points_laser)
    # Per-end gate, with the stored calibration's uncertainty included.
    # With W = I these are the plain pixel errors (2P,) and their pose Jacobian.
    e, J = whitened_residuals_and_jacobian(camera, T, meas, np.eye(2 * P))
    assert rig.covariance is not None
    pose_cov = J @ rig.covariance @ J.T
    W_end = whitening(camera, T, meas, noise)
    z2 = np.array(
        [
            _end_chi2(e[2 * k : 2 * k + 2], W_end[k], pose_cov[2 * k : 2 * k + 2, 2 * k : 2 * k + 2])
            for k in range(P)
        ]
    )
    gated = np.isfinite(z2) & (z2 < INLIER_GATE_CHI2)
    moved_far = int(gated.sum()) < max(2, P // 2)
    # When most ends are beyond the gate they are the evidence, not wrong picks: test them all.
    keep = np.isfinite(z2) if moved_far else gated
    idx = np.flatnonzero(keep)
    rows = np.concatenate([[2 * k, 2 * k + 1] for k in idx]) if len(idx) else np.zeros(0, dtype=int)
    sub = meas.subset(keep)
    S = pixel_covariance(camera, T, sub, noise) + pose_cov[np.ix_(rows, rows)]
    e_in = e[rows]
    chi2_value = float(e_in @ np.linalg.solve(S, e_in)) if len(rows) else 0.0
    dof = len(rows)
    p_value = chi2_sf(chi2_value, dof) if dof else 1.0
    err_px = np.linalg.norm(e.reshape(-1, 2), axis=1)
    return (
        {
            "ends": P,
            "used_ends": int(keep.sum()),
            "rejected_ends": int(P - keep.sum()),
            "rejected": [
                {
                    "capture": int(meas.capture[k]),
                    "end": int(meas.end[k]),
                    "sigma": _r(float(np.sqrt(z2[k])), 2),
                }
                for k in np.flatnonzero(~keep)
            ],
            "rms_px": _r(float(np.sqrt(np.mean(err_px[keep] ** 2))) if keep.any() else float("nan"), 4),
            "max_px": _r(
                float(np.max(err_px[np.isfinite(err_px)])) if np.isfinite(err_px).any() else float("inf"), 4
            ),
            "chi2": _r(chi2_value, 4),
            "dof": dof,
            "p_value": float(f"{p_value:.4g}"),
        },
        moved_far,
    )


def _end_chi2(e: FloatArray, W: FloatArray, pose_block: FloatArray) -> float:
    """Squared Mahalanobis distance of one end's error under noise + pose uncertainty."""
    if not np.isfinite(e).all():
        return float("inf")
    S = np.linalg.inv(W.T @ W) + pose_block
    return float(e @ np.linalg.solve(S, e))


def _pose_test(rig: Rig, fresh: CalibResult | Any) -> dict[str, Any]:
    """The fresh solve (box or board: a T_cam_laser and its covariance) against the rig."""
    assert rig.covariance is not None
    T0, T1 = rig.T_cam_laser, fresh.T_cam_laser
    d = tangent_delta(T1, T0)
    d_rot, d_t = d[:3], d[3:]
    C = rig.covariance + fresh.covariance
    m2 = float(d @ np.linalg.solve(C, d))
    sig = np.sqrt(np.diag(C))
    return {
        "rotation_deg": _r(float(np.degrees(np.linalg.norm(d_rot))), 5),
        "translation_mm": _r(float(1000.0 * np.linalg.norm(d_t)), 3),
        "rotation_diff_deg": [_r(float(x), 5) for x in np.degrees(d_rot)],
        "translation_diff_mm": [_r(float(x), 3) for x in 1000.0 * d_t],
        "sigma_rotation_deg": [_r(float(x), 5) for x in np.degrees(sig[:3])],
        "sigma_translation_mm": [_r(float(x), 3) for x in 1000.0 * sig[3:]],
        "mahalanobis2": _r(m2, 4),
        "p_value": float(f"{chi2_sf(m2, 6):.4g}"),
    }


def _r(x: float, digits: int) -> float:
    return round(float(x), digits)
