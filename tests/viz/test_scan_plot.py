"""The top-down scan picture with numbered line segments."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from rigcal.calib.lines import extract_lines
from rigcal.errors import OutputError
from rigcal.scan import Scan
from rigcal.sim.raycast import cast_scan
from rigcal.viz.scan_plot import _PALETTE, draw_scan_segments, render_scan_segments

STEP = np.radians(0.25)


def room_scan() -> Scan:
    walls = [[[3.0, -3.0], [3.0, 3.0]], [[3.0, 3.0], [-3.0, 3.0]], [[1.5, -0.4], [1.5, 0.4]]]
    angles = np.radians(-135.0) + STEP * np.arange(1081)
    return Scan.from_uniform(angles[0], STEP, cast_scan(walls, angles, 30.0), 0.05, 30.0)


def count_colour(img: np.ndarray, bgr) -> int:
    return int(np.all(img == np.array(bgr, dtype=np.uint8), axis=2).sum())


def test_render_writes_a_png_of_the_expected_size(tmp_path):
    scan = room_scan()
    path = render_scan_segments(scan, extract_lines(scan), tmp_path / "lines.png")
    assert path == tmp_path / "lines.png"
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert img is not None
    assert img.shape == (900, 900, 3)
    assert img.dtype == np.uint8
    np.testing.assert_array_equal(img, draw_scan_segments(scan, extract_lines(scan)))


def test_render_refuses_to_overwrite_without_force(tmp_path):
    scan = room_scan()
    path = tmp_path / "lines.png"
    path.write_bytes(b"keep me")
    with pytest.raises(OutputError, match="exists"):
        render_scan_segments(scan, extract_lines(scan), path)
    assert path.read_bytes() == b"keep me"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["lines.png"]
    render_scan_segments(scan, extract_lines(scan), path, force=True)
    assert cv2.imread(str(path)).shape == (900, 900, 3)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["lines.png"]


def test_draw_paints_each_segment_in_its_palette_colour():
    scan = room_scan()
    segs = extract_lines(scan)
    assert len(segs) >= 3
    img = draw_scan_segments(scan, segs, size_px=600)
    assert img.shape == (600, 600, 3)
    for g in segs:
        assert count_colour(img, _PALETTE[g.id % len(_PALETTE)]) > 50
    # Without segments only the white background, grey returns and grid, and the axes remain.
    bare = draw_scan_segments(scan, [], size_px=600)
    assert all(count_colour(bare, c) == 0 for c in _PALETTE)
    assert count_colour(bare, (150, 150, 150)) > 0


def test_draw_an_all_invalid_scan():
    scan = Scan.from_uniform(-1.0, STEP, [0.0, np.nan, np.inf] * 10, 0.05, 30.0)
    img = draw_scan_segments(scan, [], size_px=300)
    assert img.shape == (300, 300, 3)
    assert count_colour(img, (255, 255, 255)) > 0.5 * 300 * 300
