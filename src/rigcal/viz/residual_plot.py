"""The residual summary of a solve (the report folder's residuals.png/.svg).

Box target: left, each capture's RMS reprojection error of its box ends as bars (captures
whose ends were all rejected in red); right, every box end in the image, an arrow from the
picked pixel to where the calibration projects the laser's end, lengthened ``scale`` times
so that pixel errors are visible (inliers green, rejected ends red).

Board (plane method): left, each capture's RMS point-to-plane distance as bars (captures
RANSAC left out in red); right, every laser return's signed distance to its board plane,
per capture.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from rigcal.arrays import FloatArray
from rigcal.viz.charts import DRIFTED, OK, figure, style


def residuals_figure(
    report: dict[str, Any],
    picked_px: FloatArray,
    projected_px: FloatArray,
    inlier: NDArray[np.bool_],
    image_size: tuple[int, int],
    scale: float = 10.0,
) -> Any:
    """The figure.

    Args:
        report: the solve's report (its ``per_capture`` rows and ``summary``).
        picked_px, projected_px: (P, 2) every box end's pick and its projection.
        inlier: (P,) whether each end was kept.
        image_size: (width, height) of the images, pixels.
        scale: how many times the arrows are lengthened.
    """
    fig = figure(12.0, 5.0)
    bars, vectors = fig.subplots(1, 2, width_ratios=[1.0, 1.3])
    rows = report["per_capture"]
    rms = np.array([np.nan if r["rms_px"] is None else r["rms_px"] for r in rows], dtype=float)
    used = np.array([r.get("inlier_ends", 1) > 0 for r in rows], dtype=bool)
    _capture_bars(bars, [r["capture"] for r in rows], rms, used, report["summary"]["rms_px"], "px")
    style(bars, "RMS reprojection error per capture", "capture", "RMS error (px)")
    d = (projected_px - picked_px) * scale
    for mask, colour, label in ((inlier, OK, "inlier end"), (~inlier, DRIFTED, "rejected end")):
        if mask.any():
            vectors.quiver(
                picked_px[mask, 0],
                picked_px[mask, 1],
                d[mask, 0],
                d[mask, 1],
                color=colour,
                angles="xy",
                scale_units="xy",
                scale=1.0,
                width=0.004,
                label=label,
            )
            vectors.plot(picked_px[mask, 0], picked_px[mask, 1], ".", color=colour, markersize=3)
    w, h = image_size
    vectors.set_xlim(0, w)
    vectors.set_ylim(h, 0)  # image rows grow downwards
    vectors.set_aspect("equal")
    style(vectors, f"residual vectors, picked -> projected (x{scale:g})", "u (px)", "v (px)")
    vectors.legend(loc="upper right", fontsize=8)
    return fig


def board_residuals_figure(report: dict[str, Any], residuals_m: tuple[FloatArray, ...]) -> Any:
    """The board method's figure.

    Args:
        report: the board solve's report (``per_capture`` rows with ``inlier``, ``summary``).
        residuals_m: per capture, (M,) signed point-to-plane distances, metres.
    """
    fig = figure(12.0, 5.0)
    bars, spread = fig.subplots(1, 2)
    rows = report["per_capture"]
    names = [r["capture"] for r in rows]
    used = np.array([bool(r["inlier"]) for r in rows], dtype=bool)
    rms = np.array([r["rms_mm"] for r in rows], dtype=float)
    _capture_bars(bars, names, rms, used, report["summary"]["rms_mm"], "mm", "left out by RANSAC")
    style(bars, "RMS point-to-plane distance per capture", "capture", "RMS distance (mm)")
    for k, (res, keep) in enumerate(zip(residuals_m, used, strict=True)):
        x = k + np.linspace(-0.3, 0.3, len(res))
        spread.plot(x, 1000.0 * res, ".", markersize=3, color=OK if keep else DRIFTED)
    spread.axhline(0.0, color="#555555", linewidth=1)
    spread.set_xticks(np.arange(len(rows)), names, rotation=60, fontsize=7)
    style(spread, "laser returns' distance to their board plane", "capture (returns in scan order)", "mm")
    return fig


def _capture_bars(
    ax: Any,
    names: list[str],
    values: FloatArray,
    used: NDArray[np.bool_],
    overall: float,
    unit: str,
    unused_label: str = "all ends rejected",
) -> None:
    """One bar per capture (green used, red not), the overall RMS as a dashed line, a legend."""
    x = np.arange(len(names))
    ax.bar(x[used], values[used], color=OK, label="used")
    if (~used).any():
        ax.bar(x[~used], values[~used], color=DRIFTED, label=unused_label)
    ax.axhline(
        overall, color="#555555", linestyle="--", linewidth=1, label=f"overall RMS {overall:.2f} {unit}"
    )
    ax.set_xticks(x, names, rotation=60, fontsize=7)
    ax.legend(loc="upper left", fontsize=8)
