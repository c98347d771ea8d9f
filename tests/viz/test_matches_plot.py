"""The matches picture (Fig. 5): both images with axes in pixels, a line per match."""

from __future__ import annotations

import numpy as np

from rigcal.viz.charts import figure_bytes
from rigcal.viz.matches_plot import INLIER, OUTLIER, matches_figure


def test_images_have_pixel_axes_and_each_match_is_a_line_between_them():
    rng = np.random.default_rng(3)
    g1 = rng.integers(0, 255, (480, 640), dtype=np.uint8)
    g2 = np.roll(g1, 12, axis=1)
    returns1 = np.column_stack([np.linspace(20, 600, 50), np.full(50, 250.0)])
    returns2 = returns1 + np.array([12.0, 0.0])
    inlier = np.arange(50) % 5 != 0
    fig = matches_figure(g1, g2, returns1, returns2, returns1, returns2, inlier, "IASM images 3->4")
    top, bottom = fig.axes
    assert top.get_ylabel() == "v (px)"
    assert bottom.get_xlabel() == "u (px)"
    # The image fills its axes pixel for pixel: u from -0.5 to 639.5, v downwards.
    assert top.get_xlim() == (-0.5, 639.5)
    assert top.get_ylim() == (479.5, -0.5)
    lines = [a for a in fig.artists if type(a).__name__ == "ConnectionPatch"]
    assert len(lines) == 50
    colours = [a.get_edgecolor() for a in lines]
    from matplotlib.colors import to_rgba

    assert sum(np.allclose(c[:3], to_rgba(INLIER)[:3]) for c in colours) == 40
    assert sum(np.allclose(c[:3], to_rgba(OUTLIER)[:3]) for c in colours) == 10
    # Each line runs from its return in the first image to its match in the second.
    first = lines[-1]
    assert first.xy1 in [tuple(p) for p in returns1]
    assert np.allclose(np.array(first.xy2) - np.array(first.xy1), [12.0, 0.0])
    assert fig._suptitle.get_text() == "IASM images 3->4"
    assert figure_bytes(fig, ".png")[:4] == b"\x89PNG"
