"""Residual report of a solve: per-end and per-capture residuals, summary, warnings.

The report is a plain dictionary (written as ``report.yaml``) plus a readable table
(``report.txt`` and the terminal). Warnings name what is weak about the data: few
captures, little spread in distance or angle, large uncertainty, strongly correlated
(nearly unobservable) parameter combinations, and picks that look swapped or wrong.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from rigcal.arrays import FloatArray
from rigcal.calib.box.ransac import reprojection_errors
from rigcal.calib.box.solve import CalibResult
from rigcal.calib.spread import Sensitivity, Spread, uncertainty_warnings
from rigcal.geometry import tangent_delta

if TYPE_CHECKING:
    from rigcal.calib.intrinsics import Detections, IntrinsicsResult


# Thresholds of the weak-geometry warnings (docs/calibration.md explains each).
RECOMMENDED_CAPTURES = 8
MIN_DISTANCE_SPREAD_M = 1.0
MIN_BEARING_SPREAD_DEG = 15.0
MAX_SIGMA_ROTATION_DEG = 0.3
MAX_SIGMA_TRANSLATION_MM = 10.0
MAX_CORRELATION = 0.98

PARAMETER_NAMES = ("rot_x", "rot_y", "rot_z", "t_x", "t_y", "t_z")


def box_noise_section(result: CalibResult) -> dict[str, Any]:
    """The box solve's noise model: assumed, estimated from the data, used."""
    assumed = result.problem.settings.noise
    est_range = result.range_noise.sigma_m if result.range_noise is not None else None
    return noise_section(
        {
            "range_sigma_m": (assumed.range_sigma_m, est_range, result.noise.range_sigma_m),
            "pick_sigma_px": (assumed.pick_sigma_px, result.pick_sigma_estimated, result.noise.pick_sigma_px),
        }
    )


def build_report(result: CalibResult, T_truth: FloatArray | None = None) -> dict[str, Any]:
    """Everything a user needs to judge a solve, as plain types.

    Args:
        result: the solve.
        T_truth: (4, 4) known T_cam_laser (simulated sessions), to report the true error.
    """
    obs = result.problem.observations
    meas = result.measurements
    names = {o.capture: o.name for o in obs}
    ends = []
    for k in range(len(meas.points_laser)):
        ends.append(
            {
                "capture": names[int(meas.capture[k])],
                "end": int(meas.end[k]),
                "picked_px": [round(float(x), 2) for x in meas.pixels[k]],
                "error_px": _r(result.errors_px[k], 3),
                "error_sigma": _r(result.errors_sigma[k], 2),
                "inlier": bool(result.inliers[k]),
            }
        )
    per_capture = []
    for o in obs:
        m = meas.capture == o.capture
        e = result.errors_px[m]
        per_capture.append(
            {
                "capture": o.name,
                "rms_px": _r(np.sqrt(np.mean(e**2)), 3),
                "max_px": _r(e.max(), 3),
                "inlier_ends": int(result.inliers[m].sum()),
                "distance_m": _r(float(np.linalg.norm(o.laser_endpoints.mean(axis=0))), 3),
            }
        )
    e_in = result.errors_px[result.inliers]
    sig_rot = np.degrees(np.sqrt(np.diag(result.covariance)[:3]))
    sig_t = 1000.0 * np.sqrt(np.diag(result.covariance)[3:])
    summary = {
        "captures": len(obs),
        "captures_used": len(np.unique(meas.capture[result.inliers])),
        "box_ends": len(meas.points_laser),
        "inlier_ends": int(result.inliers.sum()),
        "rms_px": _r(np.sqrt(np.mean(e_in**2)), 4),
        "median_px": _r(np.median(e_in), 4),
        "max_px": _r(e_in.max(), 4),
        "residual_scale": _r(result.refine.residual_scale, 4),
        "sigma_rotation_deg": [_r(x, 5) for x in sig_rot],
        "sigma_translation_mm": [_r(x, 3) for x in sig_t],
        "ransac_triples": result.ransac.triples_drawn,
        "ransac_hypotheses": result.ransac.hypotheses,
    }
    noise = box_noise_section(result)
    uncertainty = uncertainty_section(
        result.covariance_model, result.covariance, result.spread, result.sensitivity
    )
    report: dict[str, Any] = {
        "summary": summary,
        "noise": noise,
        "uncertainty": uncertainty,
        "rejected": [
            {
                "capture": e["capture"],
                "end": e["end"],
                "error_px": e["error_px"],
                "error_sigma": e["error_sigma"],
            }
            for e in ends
            if not e["inlier"]
        ],
        "warnings": noise_warnings(noise)
        + _warnings(result, sig_rot, sig_t)
        + uncertainty_warnings(
            result.spread, result.sensitivity, result.covariance_model, "range and pick noise"
        ),
        "per_capture": per_capture,
        "ends": ends,
    }
    if T_truth is not None:
        report["truth"] = truth_comparison(result.T_cam_laser, result.covariance, T_truth)
    return report


def truth_comparison(T_est: FloatArray, cov: FloatArray, T_truth: FloatArray) -> dict[str, Any]:
    """Error of an estimate against the truth, and its normalised squared size (NEES).

    The error is expressed in the covariance's tangent space: R_truth = Exp(d) R_est,
    t_truth = t_est + e; NEES = [d, e]^T C^-1 [d, e], chi-square with 6 dof if the
    covariance is honest.
    """
    x = tangent_delta(T_truth, T_est)
    d, e = x[:3], x[3:]
    nees = float(x @ np.linalg.solve(cov, x))
    return {
        "rotation_error_deg": _r(np.degrees(np.linalg.norm(d)), 5),
        "translation_error_mm": _r(1000.0 * np.linalg.norm(e), 3),
        "nees": _r(nees, 3),
    }


# An estimated noise this many times off the assumed one is warned about.
NOISE_MISMATCH_RATIO = 2.0


def noise_section(entries: dict[str, tuple[float, float | None, float]]) -> dict[str, Any]:
    """The noise model, each noise assumed (options, files), estimated from the data and
    used, by name: ``{name: (assumed, estimated or None, used)}``."""
    out: dict[str, Any] = {}
    for name, (assumed, estimated, used) in entries.items():
        out[name] = {
            "assumed": float(f"{assumed:.6g}"),
            "estimated": None if estimated is None else float(f"{estimated:.6g}"),
            "used": float(f"{used:.6g}"),
        }
    return out


def noise_warnings(noise: dict[str, Any]) -> list[str]:
    """Warn where a noise estimated from the data is far from the one assumed and the
    assumed one was used."""
    out = []
    for name, v in noise.items():
        est = v.get("estimated")
        if est is None or not v["assumed"] > 0 or v["used"] != v["assumed"]:
            continue
        ratio = est / v["assumed"]
        if ratio > NOISE_MISMATCH_RATIO or ratio < 1.0 / NOISE_MISMATCH_RATIO:
            out.append(
                f"{name}: the data say {est:.4g}, {ratio:.1f}x the {v['assumed']:.4g} assumed; "
                "solve with --noise auto to use the data's"
            )
    return out


def uncertainty_section(
    cov_model: FloatArray, cov: FloatArray, spread: Spread | None, sens: Sequence[Sensitivity]
) -> dict[str, Any]:
    """The covariance's checks: the model's own 1-sigma, the spread over captures and the
    sensitivity to the noise settings (:mod:`rigcal.calib.spread`)."""
    sig = np.sqrt(np.clip(np.diag(cov_model), 0.0, None))
    out: dict[str, Any] = {
        "model_sigma_rotation_deg": [_r(x, 5) for x in np.degrees(sig[:3])],
        "model_sigma_translation_mm": [_r(x, 3) for x in 1000.0 * sig[3:]],
        "scaled_to_spread": bool(not np.allclose(cov, cov_model)),
    }
    if spread is not None:
        out["spread"] = spread.to_dict(cov_model)
    out["sensitivity"] = [s.to_dict() for s in sens]
    return out


def rig_uncertainty(
    cov_model: FloatArray, noise: dict[str, Any], uncertainty: dict[str, Any]
) -> dict[str, Any]:
    """What a rig file records beside its covariance (docs/formats/rig.md): the noise
    model, the model's own covariance, the spread over captures and the sensitivity."""
    out: dict[str, Any] = {
        "noise": noise,
        "model_covariance": [[float(f"{x:.6e}") for x in row] for row in cov_model],
    }
    if "spread" in uncertainty:
        out["spread"] = uncertainty["spread"]
    out["sensitivity"] = uncertainty["sensitivity"]
    return out


def checks_lines(report: dict[str, Any]) -> list[str]:
    """A report's noise and uncertainty sections as lines of the readable table (both
    methods)."""
    lines = _noise_lines(report.get("noise", {}))
    if "uncertainty" in report:
        lines += _uncertainty_lines(report["uncertainty"])
    return lines


def _uncertainty_lines(u: dict[str, Any]) -> list[str]:
    """The uncertainty section as lines of the readable table."""
    lines = []
    if "spread" in u:
        sp = u["spread"]
        lines.append(
            f"spread over captures (leave one out, {sp['captures']}): "
            f"{sp['scale']:.2f}x the noise model's 1-sigma (worst direction {sp['ratio_max']:.2f}x)"
            + ("; covariance scaled up to it" if u["scaled_to_spread"] else "")
        )
    for s in u["sensitivity"]:
        lines.append(
            f"sensitivity: {s['setting']} x{s['factor']:g} moves the answer {s['rotation_deg']:.4f} deg, "
            f"{s['translation_mm']:.2f} mm ({s['sigmas']:.2f} sigma)"
        )
    return lines


def _noise_lines(noise: dict[str, Any]) -> list[str]:
    """The noise section as lines of the readable table."""
    lines = []
    for name, v in noise.items():
        est = "-" if v["estimated"] is None else f"{v['estimated']:.4g}"
        lines.append(f"noise {name}: assumed {v['assumed']:.4g}, estimated {est}, used {v['used']:.4g}")
    return lines


def _warnings(result: CalibResult, sig_rot: FloatArray, sig_t: FloatArray) -> list[str]:
    out: list[str] = []
    obs = result.problem.observations
    meas = result.measurements
    used = [o for o in obs if result.inliers[meas.capture == o.capture].any()]
    if len(used) < RECOMMENDED_CAPTURES:
        out.append(
            f"only {len(used)} captures used; {RECOMMENDED_CAPTURES} or more at different distances "
            "and angles make a reliable calibration"
        )
    centres = np.array([o.laser_endpoints.mean(axis=0) for o in used])
    dist = np.linalg.norm(centres, axis=1)
    if dist.max() - dist.min() < MIN_DISTANCE_SPREAD_M:
        out.append(
            f"captures span only {dist.min():.2f}-{dist.max():.2f} m of distance; "
            f"spread them over at least {MIN_DISTANCE_SPREAD_M:g} m"
        )
    bearing = np.degrees(np.arctan2(centres[:, 1], centres[:, 0]))
    if bearing.max() - bearing.min() < MIN_BEARING_SPREAD_DEG:
        out.append(
            f"the box was seen within {bearing.max() - bearing.min():.1f} deg of bearing; "
            "place it across the whole image width"
        )
    if sig_rot.max() > MAX_SIGMA_ROTATION_DEG or sig_t.max() > MAX_SIGMA_TRANSLATION_MM:
        out.append(
            f"large uncertainty: 1-sigma rotation up to {sig_rot.max():.3f} deg, translation up to "
            f"{sig_t.max():.1f} mm; add captures"
        )
    s = np.sqrt(np.diag(result.covariance))
    corr = result.covariance / np.outer(s, s)
    np.fill_diagonal(corr, 0.0)
    i, j = np.unravel_index(int(np.argmax(np.abs(corr))), corr.shape)
    if abs(corr[i, j]) > MAX_CORRELATION:
        out.append(
            f"{PARAMETER_NAMES[i]} and {PARAMETER_NAMES[j]} are nearly indistinguishable from these "
            f"captures (correlation {corr[i, j]:+.3f}); vary the box distance and bearing more"
        )
    out += _swapped_or_wrong(result)
    review = [o.name for o in used if o.review]
    if review:
        out.append(
            f"{len(review)} picks marked for review used: {', '.join(review)}; check them on "
            "rigcal pick's contact sheet (--sheet), then set pick.review to false or remove the capture"
        )
    return out


def _swapped_or_wrong(result: CalibResult) -> list[str]:
    """Name captures whose picks look swapped (both ends fit once exchanged) or wrong."""
    out = []
    meas = result.measurements
    T = result.T_cam_laser
    thr = result.problem.settings.ransac.threshold_px
    for o in result.problem.observations:
        m = meas.capture == o.capture
        if result.inliers[m].all():
            continue
        swapped = reprojection_errors(
            result.problem.camera, T[:3, :3], T[:3, 3], meas.points_laser[m], meas.pixels[m][::-1]
        )
        if (swapped < thr).all():
            out.append(f"capture {o.name}: the two image ends look swapped (they fit in the other order)")
        else:
            k = int(np.argmax(np.where(result.inliers[m], -np.inf, result.errors_sigma[m])))
            # Rounded as the report's "rejected" entries are, so both lines agree.
            px, sig = _r(result.errors_px[m][k], 3), _r(result.errors_sigma[m][k], 2)
            out.append(
                f"capture {o.name}: pick rejected ({px:.1f} px, {sig:.1f} sigma off); "
                "check the picks and segment id"
            )
    return out


def report_table(report: dict[str, Any]) -> str:
    """Readable summary: per-capture table, totals, rejected picks and warnings."""
    s = report["summary"]
    lines = [f"{'capture':<14}{'dist_m':>8}{'rms_px':>9}{'max_px':>9}{'ends':>6}"]
    for c in report["per_capture"]:
        lines.append(
            f"{c['capture']:<14}{c['distance_m']:>8.2f}{c['rms_px']:>9.2f}{c['max_px']:>9.2f}{c['inlier_ends']:>4}/2"
        )
    lines.append("")
    lines.append(
        f"captures {s['captures_used']}/{s['captures']} used; "
        f"box ends {s['inlier_ends']}/{s['box_ends']} inliers"
    )
    lines.append(
        f"reprojection error (inliers): rms {s['rms_px']:.3f} px, median {s['median_px']:.3f} px, "
        f"max {s['max_px']:.3f} px; residual scale {s['residual_scale']:.2f}"
    )
    rot = ", ".join(f"{x:.4f}" for x in s["sigma_rotation_deg"])
    tr = ", ".join(f"{x:.2f}" for x in s["sigma_translation_mm"])
    lines.append(f"1-sigma rotation (deg, about cam x/y/z): {rot}")
    lines.append(f"1-sigma translation (mm, along cam x/y/z): {tr}")
    if "truth" in report:
        t = report["truth"]
        lines.append(
            f"error against truth: rotation {t['rotation_error_deg']:.4f} deg, translation "
            f"{t['translation_error_mm']:.2f} mm (NEES {t['nees']:.2f}, expected about 6)"
        )
    lines += checks_lines(report)
    for r in report["rejected"]:
        lines.append(
            f"rejected: capture {r['capture']} end {r['end']} "
            f"({r['error_px']:.1f} px, {r['error_sigma']:.1f} sigma)"
        )
    for w in report["warnings"]:
        lines.append(f"warning: {w}")
    return "\n".join(lines) + "\n"


def _r(x: float | np.floating[Any], nd: int) -> float:
    return round(float(x), nd)


def intrinsics_report(result: IntrinsicsResult, det: Detections, output: Path) -> tuple[dict[str, Any], str]:
    """``rigcal intrinsics``' summary of a solve written to ``output``: the JSON document
    (``--json``) and the readable lines (fit over the inliers and over all corners, the
    worst images, the projection uncertainty)."""
    lens, intr = result.model.intrinsics()
    doc = {
        "output": str(output),
        "lensmodel": lens,
        "intrinsics": [round(float(x), 8) for x in intr],
        "imagersize": list(det.imagersize),
        "images_used": result.images_used,
        "boards_not_found": list(det.missing),
        "rms_px": result.rms_px,
        "worst_px": result.worst_px,
        "rms_all_corners_px": result.rms_all_px,
        "worst_all_corners_px": result.worst_all_px,
        "warnings": list(result.warnings),
        "outliers": result.outliers,
        "corners": result.corners,
        "per_image_rms_px": result.per_image_rms_px,
        "projection_uncertainty_px": result.uncertainty_px,
    }
    worst = sorted(result.per_image_rms_px.items(), key=lambda kv: -kv[1])[:3]
    text = "\n".join(
        [
            f"{lens}: fx {intr[0]:.3f}, fy {intr[1]:.3f}, cx {intr[2]:.3f}, cy {intr[3]:.3f} px",
            f"images used {result.images_used} (board not found in {len(det.missing)}); "
            f"outliers {result.outliers} of {result.corners} corners",
            f"reprojection over the inliers ({result.corners - result.outliers} corners): "
            f"RMS {result.rms_px:.3f} px, worst {result.worst_px:.3f} px",
            f"reprojection over all detected corners (outliers included): "
            f"RMS {result.rms_all_px:.3f} px, worst {result.worst_all_px:.3f} px",
            "worst images (RMS px): " + ", ".join(f"{k} {v:.3f}" for k, v in worst),
            "projection uncertainty (1-sigma, worst direction, px): "
            + ", ".join(f"{k.replace('_', ' ')} {v:.3f}" for k, v in result.uncertainty_px.items()),
        ]
    )
    return doc, text
