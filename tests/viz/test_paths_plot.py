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
