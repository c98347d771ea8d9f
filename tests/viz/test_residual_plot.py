"""The solve report's residual summary chart and the overlays' legend."""

from __future__ import annotations

import numpy as np
import pytest

from rigcal.calib.box.session import calibrate
from rigcal.camera import Camera
from rigcal.scan import Scan
from rigcal.viz.overlay import draw_overlay
from rigcal.viz.residual_plot import residuals_figure


@pytest.fixture(scope="module")
def cal():
    return calibrate("examples/box-session/picks.yaml")


def test_bars_are_each_captures_rms_and_arrows_start_at_the_picks(cal):
    res = cal.result
    T = res.T_cam_laser
    pts = np.column_stack([res.measurements.points_laser, np.zeros(len(res.inliers))])
    projected = cal.session.camera.project(pts @ T[:3, :3].T + T[:3, 3])
    fig = residuals_figure(cal.report, res.measurements.pixels, projected, res.inliers, (640, 480))
    bars, vectors = fig.axes
    heights = [p.get_height() for p in bars.patches]
    assert heights == pytest.approx(
        [r["rms_px"] for r in cal.report["per_capture"] if r["inlier_ends"] > 0]
        + [r["rms_px"] for r in cal.report["per_capture"] if r["inlier_ends"] == 0]
    )
    assert [t.get_text() for t in bars.get_legend().get_texts()][:2] == [
        f"overall RMS {cal.report['summary']['rms_px']:.2f} px",
        "used",
    ]
    quivers = {
        q.get_label(): q for q in vectors.collections if q.get_label() in ("inlier end", "rejected end")
    }
    np.testing.assert_allclose(quivers["inlier end"].get_offsets(), res.measurements.pixels[res.inliers])
    assert len(quivers["rejected end"].get_offsets()) == int((~res.inliers).sum()) > 0
    assert vectors.get_ylim() == (480, 0)  # image rows downwards


def test_overlay_has_a_legend_naming_what_is_drawn():
    cam = Camera.from_opencv(np.array([[300.0, 0, 160], [0, 300, 120], [0, 0, 1]]), [], 320, 240)
    T = np.array([[0.0, -1, 0, 0], [0, 0, -1, 0], [1, 0, 0, 0], [0, 0, 0, 1]])
    scan = Scan(np.linspace(-0.3, 0.3, 30), np.full(30, 3.0), 0.1, 10.0)
    white = np.full((240, 320, 3), 255, np.uint8)
    plain = draw_overlay(white, cam, T, scan)
    full = draw_overlay(
        white,
        cam,
        T,
        scan,
        np.array([[100.0, 150], [200, 150]]),
        np.array([[90.0, 120], [210, 120]]),
        np.array([True, False]),
    )

    # A dimmed box in the top-left corner, one row per kind of mark: 1 without picks, 4 with.
    def rows(img):
        box = np.all(img[:, :8] < 120, axis=2)[:, 4]
        return int(np.nonzero(box)[0].max())

    assert rows(full) > rows(plain) + 50
    assert np.all(full[40:44, 5:8] < 120)


def test_board_chart_bars_and_every_returns_distance(tmp_path):
    from rigcal.calib.board.calibrate import calibrate_board
    from rigcal.sim.board_session import BoardSpec, generate_board_session, write_board_session
    from rigcal.viz.residual_plot import board_residuals_figure

    write_board_session(generate_board_session(BoardSpec(n_captures=6, seed=1)), tmp_path / "b")
    c = calibrate_board(tmp_path / "b" / "board_session.yaml")
    bars, spread = board_residuals_figure(c.report, c.result.residuals_m).axes
    assert [p.get_height() for p in bars.patches] == pytest.approx(
        [r["rms_mm"] for r in c.report["per_capture"]]
    )
    ys = np.concatenate([line.get_ydata() for line in spread.get_lines() if line.get_marker() == "."])
    np.testing.assert_allclose(np.sort(ys), np.sort(1000 * np.concatenate(c.result.residuals_m)))
