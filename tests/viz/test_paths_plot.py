"""The paths chart (Fig. 8) and the error-over-time chart: what they draw, and their legends."""

from __future__ import annotations

import numpy as np
import pytest

from rigcal.viz.charts import METHODS, TRUTH, figure_bytes
from rigcal.viz.paths_plot import errors_figure, paths_figure

T = np.linspace(0.0, 2 * np.pi, 50)
TRUTH_XY = np.column_stack([5 * np.cos(T), 5 * np.sin(T)])
EST = {"icp": TRUTH_XY + np.array([0.2, 0.0]), "kf": TRUTH_XY * 1.01}


def test_paths_are_drawn_at_their_positions_with_a_legend_and_equal_axes():
    ax = paths_figure(TRUTH_XY, EST).axes[0]
    lines = {line.get_label(): line for line in ax.get_lines() if not line.get_label().startswith("_")}
    assert list(lines) == ["ground truth", "icp", "kf"]
    assert lines["ground truth"].get_color() == TRUTH
    assert lines["icp"].get_color() == METHODS[0]
    np.testing.assert_allclose(lines["icp"].get_xydata(), EST["icp"])
    assert [t.get_text() for t in ax.get_legend().get_texts()] == ["ground truth", "icp", "kf"]
    assert ax.get_aspect() == 1.0
    assert ax.get_xlabel() == "x (m)"


def test_errors_over_time_are_the_distances_to_the_truth():
    stamps = {k: 100.0 + np.arange(50) * 0.1 for k in EST}
    ax = errors_figure(dict.fromkeys(EST, TRUTH_XY), EST, stamps).axes[0]
    lines = {line.get_label(): line for line in ax.get_lines()}
    np.testing.assert_allclose(lines["icp"].get_ydata(), 0.2)
    np.testing.assert_allclose(lines["kf"].get_ydata(), 0.05, atol=1e-12)
    assert lines["icp"].get_xdata()[0] == pytest.approx(0.0)  # time since the first stamp
    assert ax.get_ylabel() == "error (m)"


def test_charts_encode_as_png_and_svg():
    fig = paths_figure(TRUTH_XY, EST)
    assert figure_bytes(fig, ".png")[:4] == b"\x89PNG"
    assert b"<svg" in figure_bytes(fig, ".svg")[:400]


def _pixels_of(png: bytes, hex_colour: str) -> int:
    """How many pixels of a PNG have (nearly) the colour."""
    import cv2

    img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
    bgr = np.array([int(hex_colour[i : i + 2], 16) for i in (5, 3, 1)])
    return int((np.abs(img.astype(int) - bgr).max(axis=2) < 40).sum())


def test_two_methods_that_agree_both_stay_visible():
    same = TRUTH_XY + np.array([0.3, 0.0])
    png = figure_bytes(paths_figure(TRUTH_XY, {"iasm": same, "hiasm": same.copy()}), ".png")
    alone = figure_bytes(paths_figure(TRUTH_XY, {"hiasm": same}), ".png")
    # The first method shows around the second (a wider line below it): a good share of
    # the pixels it would have alone, not just its legend entry.
    first = _pixels_of(png, METHODS[0])
    assert first > 0.3 * _pixels_of(alone, METHODS[0])
    assert _pixels_of(png, METHODS[1]) > 500
    lines = {
        ln.get_label(): ln for ln in paths_figure(TRUTH_XY, {"iasm": same, "hiasm": same}).axes[0].get_lines()
    }
    assert lines["iasm"].get_linestyle() != lines["hiasm"].get_linestyle()
    assert lines["iasm"].get_marker() != lines["hiasm"].get_marker()
    assert lines["iasm"].get_zorder() < lines["hiasm"].get_zorder()
