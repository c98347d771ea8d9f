"""From a picking file to a rig and its report: the library side of ``rigcal solve``.

Data flow: picking file -> :func:`rigcal.calib.picks.read_picks` -> :class:`CalibProblem`
-> :func:`rigcal.calib.solve.solve` -> report + :class:`~rigcal.rig.Rig` -> writers.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from rigcal.calib.picks import BoxObservation, PickSession, read_picks
from rigcal.calib.report import build_report, report_table, rig_uncertainty
from rigcal.calib.solve import CalibProblem, CalibResult, FloatArray, SolveSettings, solve
from rigcal.calib.truth import read_truth
from rigcal.io.files import atomic_folder, check_folder_writable
from rigcal.rig import Rig
from rigcal.rigfile import provenance


@dataclass(frozen=True)
class Calibration:
    """A finished calibration: the session, the solve, its report and the rig to write."""

    session: PickSession
    result: CalibResult
    report: dict[str, Any]
    rig: Rig


def calibrate(
    picks_path: str | Path,
    settings: SolveSettings | None = None,
    truth_path: str | Path | None = None,
    command: str = "",
    range_sigma_m: float | None = None,
) -> Calibration:
    """Read a picking file, solve, and build the report and the rig
    (:func:`calibrate_session` on the file's session).

    Raises:
        InputError: bad picking file or any file it names, or a bad truth file.
        CalibrationError: the data cannot determine a calibration.
    """
    T_truth = read_truth(truth_path) if truth_path is not None else None
    session = read_picks(picks_path)
    return calibrate_session(
        session,
        settings,
        T_truth,
        command,
        range_sigma_m,
        inputs=session.input_files(),
        base=Path(picks_path).resolve().parent,
    )


def calibrate_session(
    session: PickSession,
    settings: SolveSettings | None = None,
    T_truth: FloatArray | None = None,
    command: str = "",
    range_sigma_m: float | None = None,
    *,
    inputs: Sequence[Path] = (),
    base: Path | None = None,
) -> Calibration:
    """Solve a session (read from a picking file, or built in memory by the Python API),
    and build the report and the rig: the one box-target solve path of ``rigcal solve``
    and ``rigcal.solve_box``.

    The laser's range noise is ``range_sigma_m`` when given, else the session's
    ``laser.range_sigma_m`` when it has one, else ``settings.noise.range_sigma_m`` (the
    board method's rule, :func:`rigcal.calib.board_calibrate.calibrate_board`).

    Args:
        inputs, base: the files the session was read from and their folder, for the
            rig's provenance (none for a session built in memory).

    Raises:
        CalibrationError: the data cannot determine a calibration.
    """
    settings = settings or SolveSettings()
    if range_sigma_m is None and "range_sigma_m" in session.laser:
        range_sigma_m = float(session.laser["range_sigma_m"])  # validated by read_picks
    if range_sigma_m is not None:
        settings = replace(settings, noise=replace(settings.noise, range_sigma_m=max(range_sigma_m, 1e-5)))
    result = solve(CalibProblem(session.camera, session.observations, settings))
    report = build_report(result, T_truth)
    source = {"camera_source": str(session.camera_path.resolve())} if inputs else {}
    prov = provenance(
        command,
        list(inputs),
        {"method": "box-target (Algorithm 1)", **source, **settings.to_dict()},
        base=base,
    )
    laser = {**session.laser, **scanner_description(session.observations)}
    rig = box_rig(result, report, laser, prov)
    return Calibration(session, result, report, rig)


def box_rig(result: CalibResult, report: dict[str, Any], laser: dict[str, Any], prov: dict[str, Any]) -> Rig:
    """The rig of a box-target solve: its pose, covariance and residual summary."""
    s = report["summary"]
    return Rig(
        T_cam_laser=result.T_cam_laser,
        camera=result.problem.camera,
        covariance=result.covariance,
        laser=laser,
        residuals={
            k: s[k] for k in ("captures", "captures_used", "box_ends", "inlier_ends", "rms_px", "median_px")
        }
        | {"max_px": s["max_px"], "residual_scale": s["residual_scale"]},
        provenance=prov,
        uncertainty=rig_uncertainty(result.covariance_model, report["noise"], report["uncertainty"]),
    )


def scanner_description(observations: Sequence[BoxObservation]) -> dict[str, Any]:
    steps = [o.beam_step_rad for o in observations if o.beam_step_rad > 0]
    return {"angle_increment_deg": round(float(np.degrees(np.median(steps))), 6)} if steps else {}


def check_report_dir(folder: str | Path, force: bool) -> Path:
    """Refuse an existing report folder unless ``force`` (checked before solving)."""
    return check_folder_writable(folder, force)


def write_report_dir(folder: str | Path, cal: Calibration, force: bool = False) -> Path:
    """Write report.yaml, report.json, report.txt, the residual summary chart
    (residuals.png/.svg) and one overlay PNG per capture.

    Everything goes into a temporary sibling folder first, then replaces ``folder`` in one
    rename, so a failure leaves no half-written report.
    """
    from rigcal.scan import read_scan
    from rigcal.viz.charts import figure_bytes
    from rigcal.viz.overlay import draw_overlay, read_image, write_png
    from rigcal.viz.residual_plot import residuals_figure

    with atomic_folder(check_report_dir(folder, force), force) as tmp:
        (tmp / "report.yaml").write_text(
            "# rigcal solve report (docs/formats/report.md)\n"
            + yaml.safe_dump(cal.report, sort_keys=False, default_flow_style=None, width=110)
        )
        (tmp / "report.json").write_text(json.dumps(cal.report, indent=1) + "\n")
        (tmp / "report.txt").write_text(report_table(cal.report))
        res = cal.result
        T = res.T_cam_laser
        pts = res.measurements.points_laser
        projected_all = cal.session.camera.project(
            np.column_stack([pts, np.zeros(len(pts))]) @ T[:3, :3].T + T[:3, 3]
        )
        cam = cal.session.camera
        fig = residuals_figure(
            cal.report, res.measurements.pixels, projected_all, res.inliers, (cam.width_px, cam.height_px)
        )
        for fmt in (".png", ".svg"):
            (tmp / f"residuals{fmt}").write_bytes(figure_bytes(fig, fmt))
        for obs in cal.session.observations:
            m = res.measurements.capture == obs.capture
            ends3 = np.column_stack([res.measurements.points_laser[m], np.zeros(int(m.sum()))])
            projected = cal.session.camera.project(ends3 @ T[:3, :3].T + T[:3, 3])
            img = draw_overlay(
                read_image(obs.image_path),
                cal.session.camera,
                T,
                read_scan(obs.scan_path),
                picked_px=obs.image_endpoints_px,
                projected_ends_px=projected,
                end_inlier=res.inliers[m],
            )
            write_png(tmp / f"overlay_{obs.name}.png", img)
    return Path(folder)
