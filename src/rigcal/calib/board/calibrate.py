"""A board session, solved: the plane method from file to rig and report.

The counterpart of :func:`rigcal.calib.box.session.calibrate` for sessions with
``method: board`` (:mod:`rigcal.calib.board.session`, :mod:`rigcal.calib.board.plane`). The
report has the same shape as the box method's where it can (summary, per capture,
warnings, truth) with point-to-plane residuals in millimetres.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from rigcal.arrays import FloatArray
from rigcal.calib.board.level import (
    LevelPriors,
    LevelSolution,
    level_errors,
    level_section,
    reduced_warning,
    refit_level,
    solve_level,
)
from rigcal.calib.board.plane import (
    LOSS,
    LOSS_SCALE,
    PlaneObservation,
    PlaneResult,
    refit_pose,
    solve_plane,
    weak_normals_warning,
)
from rigcal.calib.board.session import BoardSession, board_pose, plane_observation, read_board_session
from rigcal.calib.noise import corner_sigma_from_rms
from rigcal.calib.options import NOISE_MODES
from rigcal.calib.report import (
    MAX_SIGMA_ROTATION_DEG,
    MAX_SIGMA_TRANSLATION_MM,
    checks_lines,
    noise_section,
    noise_warnings,
    rig_uncertainty,
    truth_comparison,
    uncertainty_section,
)
from rigcal.calib.spread import honest_covariance, propagated_covariance, uncertainty_warnings
from rigcal.calib.truth import read_truth
from rigcal.errors import InputError
from rigcal.rig import Rig
from rigcal.rigfile import provenance

DEFAULT_RANGE_SIGMA_M = 0.01
# Fewer board poses than this are too few to trust the noise estimated from them (the
# covariance is widened for it at any size; below this the report says so in words).
MIN_TRUSTED_POSES = 8


@dataclass(frozen=True)
class BoardCalibration:
    """A finished board calibration: the session, the solve, its report and the rig."""

    session: BoardSession
    result: PlaneResult
    report: dict[str, Any]
    rig: Rig


def calibrate_board(
    path: str | Path,
    range_sigma_m: float | None = None,
    truth_path: str | Path | None = None,
    command: str = "",
    seed: int = 0,
    noise: str = "auto",
    range_bias: bool = True,
    loss: str = LOSS,
    intrinsics_sigma: Sequence[float] | None = None,
    skip_unseen_boards: bool = False,
    level: LevelPriors | None = None,
) -> BoardCalibration:
    """Read a board session, solve, build the report and the rig
    (:func:`calibrate_board_session` on the file's session); ``level`` (over the session's
    ``level:``) asks for the reduced solve of :mod:`rigcal.calib.board.level`.

    Raises:
        InputError: a bad session or truth file.
        CalibrationError: too few captures, parallel boards, or no consensus.
    """
    T_truth = read_truth(truth_path) if truth_path is not None else None
    session = read_board_session(path, skip_unseen_boards=skip_unseen_boards, level=level)
    return calibrate_board_session(
        session,
        range_sigma_m,
        T_truth,
        command,
        seed,
        noise,
        range_bias,
        loss=loss,
        intrinsics_sigma=intrinsics_sigma,
        inputs=session.files,
        base=Path(path).resolve().parent,
    )


def calibrate_board_session(
    session: BoardSession,
    range_sigma_m: float | None = None,
    T_truth: Any = None,
    command: str = "",
    seed: int = 0,
    noise: str = "auto",
    range_bias: bool = True,
    *,
    loss: str = LOSS,
    intrinsics_sigma: Sequence[float] | None = None,
    inputs: Sequence[Path] = (),
    base: Path | None = None,
) -> BoardCalibration:
    """Solve a board session (read from a file, or built in memory by the Python API),
    build the report and the rig: the one board solve path of ``rigcal solve`` and
    ``rigcal.solve_board``.

    Args:
        session: the session.
        range_sigma_m: the scanner's range noise to assume (default: the session's
            ``laser.range_sigma_m``, else 1 cm).
        T_truth: (4, 4) a known T_cam_laser to compare with.
        command: the command line, for provenance.
        seed: RANSAC seed.
        noise: "auto" estimates the range noise from the board returns' line fits and the
            corner noise from the corners' reprojection residuals, and uses the estimates
            (the assumed values are reported beside them); "assumed" uses the assumed ones.
        range_bias: estimate the scanner's range bias by incidence with the pose
            (:class:`rigcal.calib.board.plane.PlaneNoise`).
        loss: the refinement's robust loss (``rigcal.calib.board.plane.LOSSES``; "linear" for
            plain least squares).
        intrinsics_sigma: 1-sigma of each of the camera's intrinsics (its lens model's
            order: fx, fy, cx, cy, distortion...), independent; their effect on the board
            planes is propagated into T_cam_laser's covariance and reported as the camera's
            share (:func:`camera_uncertainty`). None: the camera is taken as exact, and the
            report says that its uncertainty is missing.
        inputs, base: the files the session was read from and their folder, for the
            rig's provenance (none for a session built in memory).

    Raises:
        CalibrationError: too few captures, parallel boards, or no consensus.
    """
    if noise not in NOISE_MODES:
        raise ValueError(f"noise must be one of {NOISE_MODES}")
    # A noise-free (simulated) scanner still gets a floor, so the whitening stays finite.
    assumed = max(range_sigma_m or float(session.laser.get("range_sigma_m", DEFAULT_RANGE_SIGMA_M)), 1e-4)
    n_corners = session.board.width_n * session.board.height_n
    corner_est = corner_sigma_from_rms(session.corner_rms_px, n_corners)
    corner_used = session.corner_sigma_px
    observations = list(session.observations)
    if noise == "auto":
        # The board poses' covariances scale with the corner noise squared.
        corner_used = max(corner_est, 0.01)
        k = (corner_used / session.corner_sigma_px) ** 2
        observations = [
            replace(o, board_pose_cov=None if o.board_pose_cov is None else k * o.board_pose_cov)
            for o in observations
        ]
    level: LevelSolution | None = None
    if session.level is not None:
        # Boards that never tilt: yaw and the horizontal translations, the rest from priors.
        result, level = solve_level(
            observations,
            session.level,
            range_sigma_m=assumed if noise == "assumed" else None,
            fit_range_bias=range_bias,
            loss=loss,
        )
    else:
        result = solve_plane(
            observations,
            range_sigma_m=assumed if noise == "assumed" else None,
            seed=seed,
            corner_sigma_px=corner_used,
            fit_range_bias=range_bias,
            loss=loss,
        )
    refit = (lambda r, moved: refit_level(r, level, moved)) if level is not None else refit_pose
    camera_doc, cov_camera = camera_uncertainty(
        session, result, observations, corner_used, intrinsics_sigma, refit=refit
    )
    if cov_camera is not None:
        result = replace(result, covariance=result.covariance + cov_camera)
    estimated = result.range_noise.sigma_m if result.range_noise is not None else None
    noise_doc = noise_section(
        {
            "range_sigma_m": (assumed, estimated, result.noise.range_sigma_m),
            "corner_sigma_px": (session.corner_sigma_px, corner_est, corner_used),
        }
    )
    report = board_report(session, result, T_truth, noise_doc)
    report["uncertainty"]["camera"] = camera_doc
    reduced = None
    if level is not None:
        reduced = level_section(level, result, cov_camera)
        report["reduced"] = reduced
        report["summary"]["method"] = "board, reduced (level scanner)"
        # T's sigma is the priors' along what the data cannot see: the generic "large
        # uncertainty" advice would only repeat the reduced solve's own warning.
        report["warnings"] = [reduced_warning(reduced)] + [
            w for w in report["warnings"] if not w.startswith("large uncertainty")
        ]
        if T_truth is not None:
            report["truth"]["level"] = {k: round(v, 4) for k, v in level_errors(level, T_truth).items()}
    if cov_camera is not None:
        camera_doc["variance_share"] = [
            round(float(a / b), 4) if b > 0 else 0.0
            for a, b in zip(np.diag(cov_camera), np.diag(result.covariance), strict=True)
        ]
    rig = plane_rig(
        session,
        result,
        report,
        noise_doc,
        "board planes (Zhang and Pless)",
        RIG_RESIDUAL_KEYS,
        command=command,
        inputs=inputs,
        base=base,
        noise=noise,
        range_bias=range_bias,
        seed=seed,
        loss=loss,
    )
    return BoardCalibration(session, result, report, rig)


# The report summary's keys a board rig file's ``residuals`` carries.
RIG_RESIDUAL_KEYS = (
    "captures",
    "captures_used",
    "rms_mm",
    "max_mm",
    "residual_scale",
    "range_bias_mm",
    "range_bias_sigma_mm",
)


def plane_rig(
    session: Any,
    result: PlaneResult,
    report: dict[str, Any],
    noise_doc: dict[str, Any],
    method: str,
    residual_keys: Sequence[str],
    *,
    command: str,
    inputs: Sequence[Path],
    base: Path | None,
    noise: str,
    range_bias: bool,
    seed: int,
    loss: str,
) -> Rig:
    """The rig of a plane-method solve (board or marker session): the pose, the camera,
    the covariance, the report summary's ``residual_keys``, provenance (``method``, the
    camera file when read from files, the noise, RANSAC and refinement settings) and the
    uncertainty section."""
    s = report["summary"]
    return Rig(
        T_cam_laser=result.T_cam_laser,
        camera=session.camera,
        covariance=result.covariance,
        laser=dict(session.laser),
        residuals={k: s[k] for k in residual_keys},
        provenance=provenance(
            command,
            list(inputs),
            {
                "method": method,
                **({"camera_source": str(session.camera_path.resolve())} if inputs else {}),
                "noise": {"mode": noise, "fit_range_bias": range_bias}
                | {k: v["used"] for k, v in noise_doc.items()},
                "ransac": {"seed": seed},
                "refine": {"loss": loss, "loss_scale": LOSS_SCALE},
            },
            base=base,
        ),
        uncertainty=rig_uncertainty(result.covariance_model, noise_doc, report["uncertainty"])
        | ({"reduced": report["reduced"]} if "reduced" in report else {}),
    )


def camera_uncertainty(
    session: BoardSession,
    result: PlaneResult,
    observations: Sequence[PlaneObservation],
    corner_sigma_px: float,
    intrinsics_sigma: Sequence[float] | None,
    refit: Callable[[PlaneResult, Sequence[PlaneObservation]], FloatArray] = refit_pose,
) -> tuple[dict[str, Any], FloatArray | None]:
    """The camera intrinsics' share of T_cam_laser's uncertainty.

    Every board plane comes from PnP through the camera's intrinsics, so an error in them
    moves all the planes together, and the answer with them; the solve itself takes the
    intrinsics as exact. The intrinsics' covariance is the one given by their 1-sigmas
    (``intrinsics_sigma``, independent), else the one a mrcal camera model carries from the
    calibration that solved it (:func:`rigcal.camera.read_intrinsics_covariance`). The
    intrinsics are moved by +-1 sigma along each principal axis of that covariance, every
    board's pose re-solved by PnP from its corners and T_cam_laser re-fitted on the same
    returns and verdicts (:func:`rigcal.calib.spread.propagated_covariance`) by ``refit``
    (the full solve's, or the level solve's).

    Returns:
        (the report's ``uncertainty.camera`` section, the (6, 6) covariance to add; None
        when the camera's uncertainty is unknown: the section then says it is missing and
        how to give it).

    Raises:
        InputError: a sigma list whose length is not the lens model's intrinsics count,
            or a sigma that is negative or not finite.
    """
    from rigcal.camera import read_intrinsics_covariance

    camera = session.camera
    n = len(camera.intrinsics)
    if intrinsics_sigma is not None:
        sig = np.asarray(list(intrinsics_sigma), dtype=float)
        if sig.shape != (n,) or not np.all(np.isfinite(sig)) or (sig < 0).any():
            shown = ",".join(f"{x:g}" for x in sig.ravel())
            raise InputError(
                f"--intrinsics-sigma: got {shown!r}; expected {n} non-negative numbers, one per "
                f"intrinsic of {camera.lensmodel} (fx, fy, cx, cy, then its distortion), in "
                f"{session.camera_path}'s order"
            )
        cov_in: FloatArray | None = np.diag(sig**2)
        source = "--intrinsics-sigma (independent 1-sigmas)"
    elif session.camera_path.is_file():
        cov_in, source = read_intrinsics_covariance(session.camera_path)
    else:  # a session built in memory, with no camera file
        cov_in, source = None, "the session's camera carries no uncertainty of its intrinsics"
    if cov_in is None:
        why = f"not included: {source}; give the intrinsics' 1-sigmas with --intrinsics-sigma"
        return {"included": False, "note": why}, None
    if not session.corners_px:
        raise ValueError("the session has no corners to re-solve the board poses from")
    used = [int(i) for i in np.flatnonzero(result.inlier_captures)]

    def changed(intr: FloatArray) -> FloatArray:
        cam = replace(camera, intrinsics=intr)
        moved = list(observations)
        for i in used:
            T_cb, _, _ = board_pose(cam, session.board, session.corners_px[i], corner_sigma_px)
            p = plane_observation(i, "", T_cb, np.eye(6), observations[i].points_laser)
            moved[i] = replace(
                observations[i],
                normal_cam=p.normal_cam,
                distance_m=p.distance_m,
                board_origin_cam=p.board_origin_cam,
            )
        return refit(result, moved)

    cov = propagated_covariance(changed, result.T_cam_laser, np.array(camera.intrinsics), cov_in)
    s = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    doc: dict[str, Any] = {
        "included": True,
        "source": source,
        "intrinsics_sigma": [float(f"{x:.6g}") for x in np.sqrt(np.clip(np.diag(cov_in), 0.0, None))],
        "sigma_rotation_deg": [round(float(x), 5) for x in np.degrees(s[:3])],
        "sigma_translation_mm": [round(float(x), 3) for x in 1000.0 * s[3:]],
    }
    return doc, cov


def board_report(
    session: BoardSession,
    result: PlaneResult,
    T_truth: Any = None,
    noise: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """The report of a board solve (docs/formats/report.md, board variant)."""
    per = []
    used = []
    C = len(session.observations)
    screened = result.screened_out if result.screened_out is not None else np.zeros(C, dtype=bool)
    for k, (o, res, keep, rms_px) in enumerate(
        zip(
            session.observations,
            result.residuals_m,
            result.inlier_captures,
            session.corner_rms_px,
            strict=True,
        )
    ):
        fit = result.lines[k].fit
        own = fit.range_residuals_m
        per.append(
            {
                "capture": o.name,
                "distance_m": round(float(o.distance_m), 3),
                "returns": len(res),
                "returns_trimmed": int((~fit.kept).sum()),
                "range_sigma_mm": round(1000.0 * float(np.sqrt(np.mean(own**2))), 3),
                "rms_mm": round(1000.0 * float(np.sqrt(np.mean(res**2))), 3),
                "max_mm": round(1000.0 * float(np.abs(res).max()), 3),
                "corner_rms_px": round(float(rms_px), 3),
                "chi2": round(float(result.chi2[k]), 3),
                "weight": round(float(result.weights[k]), 3),
                "pose_group": int(result.pose_group[k]),
                "screened_out": bool(screened[k]),
                "inlier": bool(keep),
            }
        )
        if o.name in session.scans_per_capture:
            # A marker session counts scans per capture, not per face: it adds its own.
            per[-1]["scans"] = session.scans_per_capture[o.name]
        if keep:
            used.append(res)
    allr = np.concatenate(used)
    sig = np.sqrt(np.clip(np.diag(result.covariance), 0.0, None))
    summary = {
        "method": "board",
        "captures": len(session.observations),
        "captures_used": int(result.inlier_captures.sum()),
        "captures_screened_out": int(screened.sum()),
        "poses_used": result.poses_used,
        "noise_dof": result.noise_dof,
        "few_poses_factor": round(result.few_poses_factor, 4),
        "returns": len(allr),
        "rms_mm": round(1000.0 * float(np.sqrt(np.mean(allr**2))), 3),
        "max_mm": round(1000.0 * float(np.abs(allr).max()), 3),
        "residual_scale": round(result.residual_scale, 4),
        "capture_sigma_mm": round(1000.0 * result.noise.capture_sigma_m, 3),
        "range_bias_mm": round(1000.0 * result.noise.range_bias_m, 3),
        "range_bias_sigma_mm": None
        if result.range_bias_sigma_m is None
        else round(1000.0 * result.range_bias_sigma_m, 3),
        "sigma_rotation_deg": [round(float(x), 5) for x in np.degrees(sig[:3])],
        "sigma_translation_mm": [round(float(x), 3) for x in 1000.0 * sig[3:]],
    }
    cov_model = result.covariance_model
    # The covariance also carries the few-poses factor and the camera's share; whether it
    # was scaled to the spread is the spread's own verdict.
    uncertainty = uncertainty_section(
        cov_model, honest_covariance(cov_model, result.spread), result.spread, result.sensitivity
    )
    warnings = noise_warnings(noise or {})
    if result.poses_used < MIN_TRUSTED_POSES:
        warnings.append(
            f"the session is too small to trust: {result.poses_used} board poses leave "
            f"{result.noise_dof} degree(s) of freedom to estimate the noise scale, range bias and "
            f"per-capture error from, so the sigmas have been widened "
            f"{np.sqrt(result.few_poses_factor):.2f}x for that; capture at least {MIN_TRUSTED_POSES} "
            "poses, the board turned and tilted differently at each"
        )
    weak = weak_normals_warning(
        [o for o, k in zip(session.observations, result.inlier_captures, strict=True) if k]
    )
    if weak is not None:
        warnings.append(weak)
    if np.degrees(sig[:3]).max() > MAX_SIGMA_ROTATION_DEG or 1000 * sig[3:].max() > MAX_SIGMA_TRANSLATION_MM:
        warnings.append("large uncertainty: add captures with the board turned and tilted more")
    warnings += uncertainty_warnings(result.spread, result.sensitivity, cov_model, "range and corner noise")
    warnings = [f"capture {s} (left out: --skip-unseen-boards)" for s in session.skipped] + warnings
    warnings = _screen_warnings(session, result, screened) + warnings
    for c in per:
        if not c["inlier"] and not c["screened_out"]:
            warnings.append(
                f"capture {c['capture']}: rejected ({c['rms_mm']:.1f} mm RMS off its board plane, "
                f"chi-square {c['chi2']:.1f} on 2 dof); check its segment id and corners"
            )
    report: dict[str, Any] = {"summary": summary, "noise": noise or {}, "uncertainty": uncertainty}
    report |= {"per_capture": per, "warnings": warnings}
    if T_truth is not None:
        report["truth"] = truth_comparison(result.T_cam_laser, result.covariance, T_truth)
    return report


def _screen_warnings(session: BoardSession, result: PlaneResult, screened: Any) -> list[str]:
    """One warning per capture set aside before the solve (:func:`rigcal.calib.board.plane.gross_outliers`),
    saying "millimetres read as metres?" when its returns are 500-2000 times as far as its
    board is from the camera."""
    out = []
    for k in np.flatnonzero(screened):
        o = session.observations[k]
        origin = o.board_origin_cam
        board_m = float(np.linalg.norm(origin)) if origin is not None else o.distance_m
        ratio = float(np.median(np.linalg.norm(o.points_laser, axis=1))) / max(board_m, 1e-12)
        hint = "another scan's returns, or a wrong file?"
        if 500.0 <= ratio <= 2000.0:
            hint = f"its returns are {ratio:.0f} times as far as its board: millimetres read as metres?"
        rms = result.screen_rms_m[k] if result.screen_rms_m is not None else float("nan")
        out.append(
            f"capture {o.name}: set aside before the solve: {rms:.3g} m off its board plane under the "
            f"pose the other captures agree on (limit {result.screen_limit_m:.2g} m, far beyond any "
            f"noise); {hint}"
        )
    return out


def board_report_table(report: dict[str, Any]) -> str:
    """Readable summary of a board solve."""
    s = report["summary"]
    lines = [f"{'capture':<14}{'dist_m':>8}{'returns':>9}{'rms_mm':>9}{'max_mm':>9}{'corners_px':>12}"]
    for c in report["per_capture"]:
        mark = "" if c["inlier"] else "  set aside" if c.get("screened_out") else "  rejected"
        lines.append(
            f"{c['capture']:<14}{c['distance_m']:>8.2f}{c['returns']:>9}{c['rms_mm']:>9.2f}{c['max_mm']:>9.2f}"
            f"{c['corner_rms_px']:>12.2f}{mark}"
        )
    lines += [
        "",
        f"captures {s['captures_used']}/{s['captures']} used; {s['returns']} laser returns",
        f"point-to-plane error: rms {s['rms_mm']:.2f} mm, max {s['max_mm']:.2f} mm; "
        f"residual scale {s['residual_scale']:.2f}; per-capture error {s['capture_sigma_mm']:.2f} mm",
        "1-sigma rotation (deg, about cam x/y/z): " + ", ".join(f"{x:.4f}" for x in s["sigma_rotation_deg"]),
        "1-sigma translation (mm, along cam x/y/z): "
        + ", ".join(f"{x:.2f}" for x in s["sigma_translation_mm"]),
    ]
    if "reduced" in report:
        r = report["reduced"]
        sv, pb = r["solved"], r["prior_bound"]
        lines.append(
            f"reduced solve ({r['model']}): yaw {sv['yaw_deg']['value']:.3f} +- "
            f"{sv['yaw_deg']['sigma']:.3f} deg; camera in the scan plane x "
            f"{sv['camera_x_mm']['value']:.1f} +- {sv['camera_x_mm']['sigma']:.1f} mm, "
            f"y {sv['camera_y_mm']['value']:.1f} +- {sv['camera_y_mm']['sigma']:.1f} mm"
        )
        lines.append(
            "prior-bound (not measured): "
            + "; ".join(
                f"{k} {v['value']:.3f} +- {v['sigma']:.3f} (prior {v['prior']:g} +- {v['prior_sigma']:g})"
                for k, v in pb.items()
            )
        )
    if "truth" in report:
        t = report["truth"]
        lines.append(
            f"error against truth: rotation {t['rotation_error_deg']:.4f} deg, translation "
            f"{t['translation_error_mm']:.2f} mm (NEES {t['nees']:.2f}, expected about 6)"
        )
    if s.get("range_bias_sigma_mm") is not None:
        lines.append(
            f"range bias by incidence (reads long by b (1/cos(i) - 1)): b = {s['range_bias_mm']:.1f} "
            f"+- {s['range_bias_sigma_mm']:.1f} mm"
        )
    cam = report.get("uncertainty", {}).get("camera")
    if cam is not None and cam.get("included"):
        lines.append(
            f"camera intrinsics' uncertainty from {cam['source']}; its 1-sigma share: rotation (deg) "
            + ", ".join(f"{x:.4f}" for x in cam["sigma_rotation_deg"])
            + "; translation (mm) "
            + ", ".join(f"{x:.2f}" for x in cam["sigma_translation_mm"])
            + "; of the variance: "
            + ", ".join(f"{x:.0%}" for x in cam["variance_share"])
        )
    elif cam is not None:
        lines.append(f"camera intrinsics' uncertainty: {cam['note']}")
    lines += checks_lines(report)
    lines += [f"warning: {w}" for w in report["warnings"]]
    return "\n".join(lines) + "\n"
