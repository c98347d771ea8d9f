"""Estimated paths against ground truth, seen from above (the paper's Fig. 8), and each
method's position error over time.

Paths: ground truth in blue, one colour per method, equal scale on both axes (metres),
each path's start a circle and its end a cross, so a loop's closure error is visible as
the gap between them. Methods that agree (IASM and H-IASM often do) stay visible where
they overlap: each has its own dash pattern and markers, and a method drawn earlier is
drawn wider and below the later ones, so it shows as a rim around them. Errors: the
distance between each estimate and the truth at its stamps, over the time since the
first scan. All are matplotlib figures (rigcal.viz.charts) with ticks and a legend.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from rigcal.arrays import FloatArray
from rigcal.viz.charts import METHODS, TRUTH, figure, style

# (dash pattern, marker) per method, in order; the markers sit along each path.
LINES = (("-", "o"), ("--", "s"), ("-.", "^"), (":", "D"), ((0, (5, 1, 1, 1)), "v"), ((0, (1, 2)), "P"))
MARKERS_PER_PATH = 12


def paths_figure(truth: FloatArray, paths: dict[str, FloatArray]) -> Any:
    """The paths seen from above.

    Args:
        truth: (N, 2+) true positions.
        paths: method name -> (M, 2+) estimated positions, same frame as the truth.
    """
    fig = figure(8.0, 8.0)
    draw_paths(fig.subplots(), truth, paths)
    return fig


def draw_paths(ax: Any, truth: FloatArray, paths: dict[str, FloatArray]) -> None:
    """The paths seen from above, on ``ax`` (see :func:`paths_figure`)."""
    n = len(paths)
    ax.plot(truth[:, 0], truth[:, 1], color=TRUTH, linewidth=2.0, label="ground truth", zorder=1)
    _ends(ax, truth, TRUTH, 1)
    for k, (name, p) in enumerate(paths.items()):
        colour = METHODS[k % len(METHODS)]
        dash, marker = LINES[k % len(LINES)]
        ax.plot(
            p[:, 0],
            p[:, 1],
            color=colour,
            linestyle=dash,
            linewidth=1.2 + 1.3 * (n - 1 - k),  # earlier: wider and below
            marker=marker,
            markevery=max(1, len(p) // MARKERS_PER_PATH),
            markersize=5,
            markerfacecolor="none",
            label=name,
            zorder=2 + k,
        )
        _ends(ax, p, colour, 2 + k)
    ax.set_aspect("equal", adjustable="datalim")
    style(ax, "paths (start o, end x)", "x (m)", "y (m)")
    ax.legend(loc="best", fontsize=9)


def _ends(ax: Any, p: FloatArray, colour: str, zorder: int) -> None:
    ax.plot(p[0, 0], p[0, 1], "o", color=colour, markerfacecolor="none", markersize=8, zorder=zorder)
    ax.plot(p[-1, 0], p[-1, 1], "x", color=colour, markersize=8, zorder=zorder)


def graph_figure(
    poses: FloatArray, accepted: list[tuple[int, int, str]], rejected: list[tuple[int, int, str]]
) -> Any:
    """A loop-closed path and its closures seen from above: the optimised path, each
    accepted closure as a segment between its two poses (green from the scan search,
    purple from another source such as images), each closure rejected (by the verification
    or the robust kernel) as a dashed one (red, orange); the legend counts each.

    Args:
        poses: (N, 2+) the optimised positions.
        accepted, rejected: (i, j, source) pose index pairs and who proposed them.
    """
    fig = figure(8.0, 8.0)
    ax = fig.subplots()
    ax.plot(poses[:, 0], poses[:, 1], color=TRUTH, linewidth=1.0, label="optimised path")
    sources = sorted({s for _, _, s in accepted + rejected}, key=lambda s: (s != "scan", s))
    for n, source in enumerate(sources):
        for pairs, colours, dash, label in (
            (accepted, ("tab:green", "tab:purple", "tab:olive"), "-", "accepted"),
            (rejected, ("tab:red", "tab:orange", "tab:brown"), "--", "rejected"),
        ):
            mine = [(i, j) for i, j, s in pairs if s == source]
            for k, (i, j) in enumerate(mine):
                ax.plot(
                    [poses[i, 0], poses[j, 0]], [poses[i, 1], poses[j, 1]], dash,
                    color=colours[min(n, 2)], linewidth=1.5,
                    label=f"{label} closures, {source} ({len(mine)})" if k == 0 else None,
                )  # fmt: skip
    ax.set_aspect("equal", adjustable="datalim")
    style(ax, "pose graph: loop closures", "x (m)", "y (m)")
    ax.legend(loc="best", fontsize=9)
    return fig


def errors_figure(
    truth: dict[str, FloatArray], paths: dict[str, FloatArray], stamps: dict[str, FloatArray]
) -> Any:
    """Each method's position error against the truth over time.

    Args:
        truth: method name -> (M, 2+) true positions at the method's stamps.
        paths: method name -> (M, 2+) estimated positions.
        stamps: method name -> (M,) stamps, seconds.
    """
    fig = figure(9.0, 4.5)
    draw_errors(fig.subplots(), truth, paths, stamps)
    return fig


def draw_errors(
    ax: Any, truth: dict[str, FloatArray], paths: dict[str, FloatArray], stamps: dict[str, FloatArray]
) -> None:
    """Each method's position error over time, on ``ax`` (see :func:`errors_figure`)."""
    t0 = min(float(s[0]) for s in stamps.values()) if stamps else 0.0
    for k, (name, p) in enumerate(paths.items()):
        err = np.linalg.norm(p[:, :2] - truth[name][:, :2], axis=1)
        ax.plot(
            stamps[name] - t0,
            err,
            color=METHODS[k % len(METHODS)],
            linestyle=LINES[k % len(LINES)][0],
            linewidth=1.2,
            label=name,
        )
    style(ax, "position error against the truth", "time (s)", "error (m)")
    ax.set_ylim(bottom=0)
    if paths:
        ax.legend(loc="upper left", fontsize=9)


def evaluation_figure(
    truth: FloatArray,
    paths: dict[str, FloatArray],
    truth_at: dict[str, FloatArray],
    stamps: dict[str, FloatArray],
) -> Any:
    """``rigcal evaluate --plot``: the paths from above beside the errors over time (as
    evo_ape's --plot shows a trajectory and its error)."""
    fig = figure(15.0, 6.5)
    left, right = fig.subplots(1, 2, width_ratios=[1.0, 1.3])
    draw_paths(left, truth, paths)
    draw_errors(right, truth_at, paths, stamps)
    return fig
