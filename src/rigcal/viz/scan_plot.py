"""A top-down picture of a scan with its numbered line segments (to help picking).

A matplotlib figure (rigcal.viz.charts) with axes in metres in the laser frame (+x ahead,
+y left), equal scale on both, so coordinates can be read off it. Every valid return is a
grey dot; each segment is drawn in its own colour with its id at its middle, the id that
picking files use (``laser_side: {segment: ID}``); the laser sits at the origin with its
x axis (red) and y axis (green) drawn half a metre long.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from rigcal.io.files import atomic_write_bytes
from rigcal.lines import Segment
from rigcal.scan import Scan
from rigcal.viz.charts import figure, figure_bytes, style

# Distinct colours for neighbouring segments (matplotlib's tab10 without its grey).
PALETTE = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#bcbd22", "#17becf")
RETURNS = "#969696"


def scan_figure(scan: Scan, segments: list[Segment], size_in: float = 9.0) -> Any:
    """The picture as a matplotlib figure."""
    fig = figure(size_in, size_in)
    ax = fig.subplots()
    pts = scan.points[scan.valid]
    ax.plot(pts[:, 0], pts[:, 1], ".", color=RETURNS, markersize=2, label="returns", zorder=1)
    extent = float(np.abs(pts).max()) if len(pts) else 1.0
    for g in segments:
        colour = PALETTE[g.id % len(PALETTE)]
        ax.plot(g.points[:, 0], g.points[:, 1], ".", color=colour, markersize=4, zorder=2)
        ax.plot([g.start[0], g.end[0]], [g.start[1], g.end[1]], "-", color=colour, linewidth=2, zorder=3)
        # The id beside the segment's middle, on the side facing the laser.
        at = 0.5 * (g.start + g.end) - 0.025 * max(extent, 0.5) * g.normal
        ax.text(
            at[0], at[1], str(g.id), color=colour, fontsize=11, fontweight="bold", ha="center", va="center"
        )
    ax.annotate("", (0.5, 0.0), (0.0, 0.0), arrowprops={"arrowstyle": "->", "color": "#c80000", "lw": 2})
    ax.annotate("", (0.0, 0.5), (0.0, 0.0), arrowprops={"arrowstyle": "->", "color": "#00a000", "lw": 2})
    ax.plot([0.0], [0.0], "k+", markersize=8)
    ax.set_aspect("equal", adjustable="datalim")
    style(ax, f"{len(segments)} line segments (ids as picking files use them)", "x (m)", "y (m)")
    return fig


def render_scan_segments(scan: Scan, segments: list[Segment], path: str | Path, force: bool = False) -> Path:
    """Draw the picture and write it as a PNG, atomically."""
    return atomic_write_bytes(path, figure_bytes(scan_figure(scan, segments), ".png"), force=force)
