"""Matched scan returns between two images (the paper's Fig. 5).

A matplotlib figure (rigcal.viz.charts): both images in grey, the first above the
second, each with its axes in pixels (u right, v down; pixel (0, 0)'s centre at (0, 0)),
so a correspondence's pixels can be read off it. Every projected return of each scan is a
small dot, and every correspondence a line from its return in the first image to its match
in the second: green when the step's final motion agrees with it (an inlier), red
otherwise.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from rigcal.arrays import FloatArray
from rigcal.viz.charts import figure

if TYPE_CHECKING:
    from rigcal.localize.image_matching import StepMatches


INLIER = "#28aa28"
OUTLIER = "#e62828"
RETURN = "#0078c8"


def matches_figure(
    gray1: NDArray[np.uint8],
    gray2: NDArray[np.uint8],
    returns1: FloatArray,
    returns2: FloatArray,
    match1: FloatArray,
    match2: FloatArray,
    inlier: NDArray[np.bool_],
    title: str = "",
    labels: tuple[str, str] = ("first image", "second image"),
) -> Any:
    """The picture as a matplotlib figure.

    Args:
        returns1, returns2: (N, 2) pixels of each scan's visible returns.
        match1, match2: (M, 2) pixels of the matched returns in image 1 and image 2.
        inlier: (M,) which matches agree with the final motion.
        labels: the two images' titles.
    """
    from matplotlib.patches import ConnectionPatch

    h, w = gray1.shape[:2]
    fig = figure(9.0, 9.0 * 2 * h / w * 0.92 + 0.6)
    top, bottom = fig.subplots(2, 1, sharex=True)
    for ax, img, pts, label in ((top, gray1, returns1, labels[0]), (bottom, gray2, returns2, labels[1])):
        ax.imshow(img, cmap="gray", vmin=0, vmax=255, extent=(-0.5, w - 0.5, h - 0.5, -0.5))
        ax.plot(pts[:, 0], pts[:, 1], ".", color=RETURN, markersize=2)
        ax.set_title(label, fontsize=10)
        ax.set_ylabel("v (px)")
    bottom.set_xlabel("u (px)")
    # Outliers first, so inliers are drawn on top of them.
    order = np.argsort(inlier, kind="stable")
    for k in order:
        ok = bool(inlier[k])
        line = ConnectionPatch(
            xyA=tuple(match1[k]),
            coordsA="data",
            axesA=top,
            xyB=tuple(match2[k]),
            coordsB="data",
            axesB=bottom,
            color=INLIER if ok else OUTLIER,
            linewidth=0.7,
            alpha=0.85,
        )
        fig.add_artist(line)
    if title:
        fig.suptitle(title, fontsize=11)
    return fig


def step_figure(step: StepMatches) -> Any:
    """The picture of one step's correspondences (:func:`rigcal.localize.image_matching.step_matches`)."""
    return matches_figure(
        step.gray1,
        step.gray2,
        step.returns1,
        step.returns2,
        step.match1,
        step.match2,
        step.inlier,
        step.title,
        step.labels,
    )
