"""The top-down scan picture with numbered line segments, axes in metres."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from rigcal.errors import OutputError
from rigcal.lines import extract_lines
from rigcal.scan import Scan
from rigcal.sim.raycast import cast_scan
from rigcal.viz.scan_plot import PALETTE, render_scan_segments, scan_figure

STEP = np.radians(0.25)


def room_scan() -> Scan:
    walls = [[[3.0, -3.0], [3.0, 3.0]], [[3.0, 3.0], [-3.0, 3.0]], [[1.5, -0.4], [1.5, 0.4]]]
    angles = np.radians(-135.0) + STEP * np.arange(1081)
    return Scan.from_uniform(angles[0], STEP, cast_scan(walls, angles, 30.0), 0.05, 30.0)


def test_render_writes_a_png(tmp_path):
    scan = room_scan()
    path = render_scan_segments(scan, extract_lines(scan), tmp_path / "lines.png")
    assert path == tmp_path / "lines.png"
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert img.shape[:2] == (900, 900)


def test_render_refuses_to_overwrite_without_force(tmp_path):
    scan = room_scan()
    path = tmp_path / "lines.png"
    path.write_bytes(b"keep me")
    with pytest.raises(OutputError, match="exists"):
        render_scan_segments(scan, extract_lines(scan), path)
    assert path.read_bytes() == b"keep me"
    render_scan_segments(scan, extract_lines(scan), path, force=True)
    assert path.read_bytes()[:4] == b"\x89PNG"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["lines.png"]


def test_axes_are_in_metres_and_segments_sit_at_their_coordinates():
    scan = room_scan()
    segs = extract_lines(scan)
    assert len(segs) >= 3
    ax = scan_figure(scan, segs).axes[0]
    assert ax.get_xlabel() == "x (m)"
    assert ax.get_ylabel() == "y (m)"
    assert ax.get_aspect() == 1.0
    # The wall at x = 3 m and the box face at x = 1.5 m are read off the axes where they are.
    x0, x1 = ax.get_xlim()
    assert x0 < 0.0 < 1.5 < 3.0 < x1
    labels = {t.get_text(): t for t in ax.texts}
    for g in segs:
        text = labels[str(g.id)]
        assert text.get_color() == PALETTE[g.id % len(PALETTE)]
        assert np.linalg.norm(np.array(text.get_position()) - 0.5 * (g.start + g.end)) < 0.3
        drawn = [ln for ln in ax.get_lines() if ln.get_color() == PALETTE[g.id % len(PALETTE)]]
        ends = [ln.get_xydata() for ln in drawn if len(ln.get_xydata()) == 2]
        assert any(np.allclose(e, [g.start, g.end]) for e in ends)


def test_draw_an_all_invalid_scan():
    scan = Scan.from_uniform(-1.0, STEP, [0.0, np.nan, np.inf] * 10, 0.05, 30.0)
    ax = scan_figure(scan, []).axes[0]
    assert [t.get_text() for t in ax.texts if t.get_text()] == []  # the arrows have no text
