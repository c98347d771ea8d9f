"""The solve's report folder (docs/formats/report.md), for every method: report.yaml,
report.json, report.txt, the residual chart (residuals.png/.svg) and, for the box method,
one overlay PNG per capture. The solvers return their report; this output layer writes it.

Everything goes into a temporary sibling folder first, then replaces the folder in one
rename, so a failure leaves no half-written report.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import yaml

from rigcal.io.files import atomic_folder, check_folder_writable

if TYPE_CHECKING:
    from rigcal.calib.board.calibrate import BoardCalibration
    from rigcal.calib.box.session import Calibration
    from rigcal.calib.marker.calibrate import MarkerCalibration


def _write_texts(tmp: Path, report: dict[str, Any], title: str, table: str) -> None:
    """report.yaml (with its title line), report.json and report.txt."""
    (tmp / "report.yaml").write_text(
        f"# {title} (docs/formats/report.md)\n"
        + yaml.safe_dump(report, sort_keys=False, default_flow_style=None, width=110)
    )
    (tmp / "report.json").write_text(json.dumps(report, indent=1) + "\n")
    (tmp / "report.txt").write_text(table)


def _write_figure(tmp: Path, name: str, fig: Any) -> None:
    from rigcal.viz.charts import figure_bytes

    for fmt in (".png", ".svg"):
        (tmp / f"{name}{fmt}").write_bytes(figure_bytes(fig, fmt))


def write_box_report(folder: str | Path, cal: Calibration, force: bool = False) -> Path:
    """The box method's report folder, with one overlay PNG per capture (the picked box
    ends, the laser's projected through the solved T_cam_laser, inliers and outliers).

    Raises:
        OutputError: ``folder`` exists and ``force`` is False, or cannot be written.
    """
    from rigcal.calib.report import report_table
    from rigcal.io.images import read_image
    from rigcal.scan import read_scan
    from rigcal.viz.overlay import draw_overlay, write_png
    from rigcal.viz.residual_plot import residuals_figure

    with atomic_folder(check_folder_writable(folder, force), force) as tmp:
        _write_texts(tmp, cal.report, "rigcal solve report", report_table(cal.report))
        res = cal.result
        T = res.T_cam_laser
        cam = cal.session.camera
        pts = res.measurements.points_laser
        projected_all = cam.project(np.column_stack([pts, np.zeros(len(pts))]) @ T[:3, :3].T + T[:3, 3])
        fig = residuals_figure(
            cal.report, res.measurements.pixels, projected_all, res.inliers, (cam.width_px, cam.height_px)
        )
        _write_figure(tmp, "residuals", fig)
        for obs in cal.session.observations:
            m = res.measurements.capture == obs.capture
            ends3 = np.column_stack([res.measurements.points_laser[m], np.zeros(int(m.sum()))])
            projected = cam.project(ends3 @ T[:3, :3].T + T[:3, 3])
            img = draw_overlay(
                read_image(obs.image_path),
                cam,
                T,
                read_scan(obs.scan_path),
                picked_px=obs.image_endpoints_px,
                projected_ends_px=projected,
                end_inlier=res.inliers[m],
            )
            write_png(tmp / f"overlay_{obs.name}.png", img)
    return Path(folder)


def write_plane_report(
    folder: str | Path, cal: BoardCalibration | MarkerCalibration, force: bool = False
) -> Path:
    """The board or marker method's report folder (the plane method's residuals chart).

    Raises:
        OutputError: ``folder`` exists and ``force`` is False, or cannot be written.
    """
    from rigcal.calib.board.calibrate import board_report_table
    from rigcal.calib.marker.calibrate import MarkerCalibration, marker_report_table
    from rigcal.viz.residual_plot import board_residuals_figure

    marker = isinstance(cal, MarkerCalibration)
    table = marker_report_table if marker else board_report_table
    kind = "marker" if marker else "board"
    with atomic_folder(folder, force) as tmp:
        _write_texts(tmp, cal.report, f"rigcal solve report, {kind} method", table(cal.report))
        _write_figure(tmp, "residuals", board_residuals_figure(cal.report, cal.result.residuals_m))
    return Path(folder)
