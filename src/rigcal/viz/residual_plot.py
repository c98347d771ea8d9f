"""The residual summary of a box-target solve (the report folder's residuals.png/.svg).

Left: each capture's RMS reprojection error of its box ends, as bars (captures whose ends
were all rejected in red). Right: every box end in the image, an arrow from the picked
pixel to where the calibration projects the laser's end, lengthened ``scale`` times so
that pixel errors are visible; inliers green, rejected ends red.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from rigcal.viz.charts import DRIFTED, OK, figure, style

FloatArray = NDArray[np.float64]


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
    names = [r["capture"] for r in rows]
    rms = np.array([np.nan if r["rms_px"] is None else r["rms_px"] for r in rows], dtype=float)
    used = np.array([r.get("inlier_ends", 1) > 0 for r in rows], dtype=bool)
    x = np.arange(len(rows))
    bars.bar(x[used], rms[used], color=OK, label="used")
    if (~used).any():
        bars.bar(x[~used], rms[~used], color=DRIFTED, label="all ends rejected")
    overall = report["summary"]["rms_px"]
    bars.axhline(overall, color="#555555", linestyle="--", linewidth=1, label=f"overall RMS {overall:.2f} px")
    bars.set_xticks(x, names, rotation=60, fontsize=7)
    style(bars, "RMS reprojection error per capture", "capture", "RMS error (px)")
    bars.legend(loc="upper left", fontsize=8)
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
