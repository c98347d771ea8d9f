"""A board session, solved: the plane method from file to rig and report.

The counterpart of :func:`rigcal.calib.session.calibrate` for sessions with
``method: board`` (:mod:`rigcal.calib.board_session`, :mod:`rigcal.calib.plane`). The
report has the same shape as the box method's where it can (summary, per capture,
warnings, truth) with point-to-plane residuals in millimetres.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from rigcal.calib.board_session import BoardSession, read_board_session
from rigcal.calib.plane import PlaneResult, solve_plane
from rigcal.calib.report import MAX_SIGMA_ROTATION_DEG, MAX_SIGMA_TRANSLATION_MM, truth_comparison
from rigcal.calib.truth import read_truth
from rigcal.rig import Rig
from rigcal.rigfile import provenance

DEFAULT_RANGE_SIGMA_M = 0.01


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
) -> BoardCalibration:
    """Read a board session, solve, build the report and the rig.

    Args:
        path: the board session file.
        range_sigma_m: the scanner's range noise (default: the session's
            ``laser.range_sigma_m``, else 1 cm).
        truth_path: a truth file to compare with.
        command: the command line, for provenance.
        seed: RANSAC seed.

    Raises:
        InputError: a bad session or truth file.
        CalibrationError: too few captures, parallel boards, or no consensus.
    """
    T_truth = read_truth(truth_path) if truth_path is not None else None
    session = read_board_session(path)
    # A noise-free (simulated) scanner still gets a floor, so the whitening stays finite.
    sigma = max(range_sigma_m or float(session.laser.get("range_sigma_m", DEFAULT_RANGE_SIGMA_M)), 1e-4)
    result = solve_plane(session.observations, range_sigma_m=sigma, seed=seed)
    report = board_report(session, result, T_truth)
    s = report["summary"]
    rig = Rig(
        T_cam_laser=result.T_cam_laser,
        camera=session.camera,
        covariance=result.covariance,
        laser=dict(session.laser),
        residuals={k: s[k] for k in ("captures", "captures_used", "rms_mm", "max_mm", "residual_scale")},
        provenance=provenance(
            command,
            list(session.files),
            {
                "method": "board planes (Zhang and Pless)",
                "camera_source": str(session.camera_path.resolve()),
                "noise": {"range_sigma_m": sigma},
                "ransac": {"seed": seed},
            },
            base=Path(path).resolve().parent,
        ),
    )
    return BoardCalibration(session, result, report, rig)


def board_report(session: BoardSession, result: PlaneResult, T_truth: Any = None) -> dict[str, Any]:
    """The report of a board solve (docs/formats/report.md, board variant)."""
    per = []
    used = []
    for o, res, keep, rms_px in zip(
        session.observations, result.residuals_m, result.inlier_captures, session.corner_rms_px, strict=True
    ):
        per.append(
            {
                "capture": o.name,
                "distance_m": round(float(o.distance_m), 3),
                "returns": len(res),
                "rms_mm": round(1000.0 * float(np.sqrt(np.mean(res**2))), 3),
                "max_mm": round(1000.0 * float(np.abs(res).max()), 3),
                "corner_rms_px": round(float(rms_px), 3),
                "inlier": bool(keep),
            }
        )
        if keep:
            used.append(res)
    allr = np.concatenate(used)
    sig = np.sqrt(np.clip(np.diag(result.covariance), 0.0, None))
    summary = {
        "method": "board",
        "captures": len(session.observations),
        "captures_used": int(result.inlier_captures.sum()),
        "returns": len(allr),
        "rms_mm": round(1000.0 * float(np.sqrt(np.mean(allr**2))), 3),
        "max_mm": round(1000.0 * float(np.abs(allr).max()), 3),
        "residual_scale": round(result.residual_scale, 4),
        "sigma_rotation_deg": [round(float(x), 5) for x in np.degrees(sig[:3])],
        "sigma_translation_mm": [round(float(x), 3) for x in 1000.0 * sig[3:]],
    }
    warnings = []
    if np.degrees(sig[:3]).max() > MAX_SIGMA_ROTATION_DEG or 1000 * sig[3:].max() > MAX_SIGMA_TRANSLATION_MM:
        warnings.append("large uncertainty: add captures with the board turned and tilted more")
    for c in per:
        if not c["inlier"]:
            warnings.append(
                f"capture {c['capture']}: rejected ({c['rms_mm']:.1f} mm RMS off its board plane); "
                "check its segment id and corners"
            )
    report: dict[str, Any] = {"summary": summary, "per_capture": per, "warnings": warnings}
    if T_truth is not None:
        report["truth"] = truth_comparison(result.T_cam_laser, result.covariance, T_truth)
    return report


def board_report_table(report: dict[str, Any]) -> str:
    """Readable summary of a board solve."""
    s = report["summary"]
    lines = [f"{'capture':<14}{'dist_m':>8}{'returns':>9}{'rms_mm':>9}{'max_mm':>9}{'corners_px':>12}"]
    for c in report["per_capture"]:
        mark = "" if c["inlier"] else "  rejected"
        lines.append(
            f"{c['capture']:<14}{c['distance_m']:>8.2f}{c['returns']:>9}{c['rms_mm']:>9.2f}{c['max_mm']:>9.2f}"
            f"{c['corner_rms_px']:>12.2f}{mark}"
        )
    lines += [
        "",
        f"captures {s['captures_used']}/{s['captures']} used; {s['returns']} laser returns",
        f"point-to-plane error: rms {s['rms_mm']:.2f} mm, max {s['max_mm']:.2f} mm; "
        f"residual scale {s['residual_scale']:.2f}",
        "1-sigma rotation (deg, about cam x/y/z): " + ", ".join(f"{x:.4f}" for x in s["sigma_rotation_deg"]),
        "1-sigma translation (mm, along cam x/y/z): "
        + ", ".join(f"{x:.2f}" for x in s["sigma_translation_mm"]),
    ]
    if "truth" in report:
        t = report["truth"]
        lines.append(
            f"error against truth: rotation {t['rotation_error_deg']:.4f} deg, translation "
            f"{t['translation_error_mm']:.2f} mm (NEES {t['nees']:.2f}, expected about 6)"
        )
    lines += [f"warning: {w}" for w in report["warnings"]]
    return "\n".join(lines) + "\n"
