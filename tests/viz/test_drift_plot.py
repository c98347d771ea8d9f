"""The drift history picture: three panels, ok checks green and drifted ones red."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from rigcal.errors import OutputError
from rigcal.viz.drift_plot import BAND_BGR, DRIFT_BGR, OK_BGR, draw_drift, write_drift_png

PANEL_PX = 220
WIDTH_PX = 900


def record(
    verdict: str, rms_px: float | None, rotation_deg: float | None = None, translation_mm: float = 0.0
):
    pose = None
    if rotation_deg is not None:
        pose = {
            "rotation_deg": rotation_deg,
            "translation_mm": translation_mm,
            "sigma_rotation_deg": [0.05, 0.07, 0.05],
            "sigma_translation_mm": [3.0, 2.0, 3.0],
            "p_value": 0.5,
        }
    return {
        "checked_utc": "2026-11-23T08:12:40Z",
        "verdict": verdict,
        "residual": {"rms_px": rms_px},
        "pose": pose,
    }


# ok with a pose, drifted with a pose, ok without a pose, drifted without a pose.
RECORDS = [
    record("ok", 1.8, rotation_deg=0.1, translation_mm=4.0),
    record("drifted", 4.2, rotation_deg=0.6, translation_mm=15.0),
    record("ok", 2.1),
    record("drifted", 3.5),
]
XS = np.linspace(90, WIDTH_PX - 40, len(RECORDS))  # the checks' columns (left 70, right 880, 20 in)


def count(img: np.ndarray, bgr: tuple[int, int, int]) -> int:
    return int(np.all(img == np.array(bgr, dtype=np.uint8), axis=2).sum())


def cell(img: np.ndarray, panel: int, check: int) -> np.ndarray:
    """The part of the picture where a check's point in a panel can be."""
    top = 20 + panel * PANEL_PX
    x = round(XS[check])
    return img[top - 6 : top + PANEL_PX - 34, x - 8 : x + 9]


@pytest.fixture(scope="module")
def img() -> np.ndarray:
    return draw_drift(RECORDS)


def test_picture_has_the_expected_size(img):
    assert img.shape == (3 * PANEL_PX + 40, WIDTH_PX, 3)
    assert img.dtype == np.uint8
    assert draw_drift(RECORDS, width_px=600, panel_px=150).shape == (3 * 150 + 40, 600, 3)


def test_ok_checks_are_green_and_drifted_ones_red(img):
    assert count(img, OK_BGR) > 0
    assert count(img, DRIFT_BGR) > 0
    for panel in range(3):
        assert count(cell(img, panel, 0), OK_BGR) > 0
        assert count(cell(img, panel, 0), DRIFT_BGR) == 0
        assert count(cell(img, panel, 1), DRIFT_BGR) > 0
        assert count(cell(img, panel, 1), OK_BGR) == 0


def test_checks_without_a_pose_have_only_their_residual_point(img):
    for check, colour in ((2, OK_BGR), (3, DRIFT_BGR)):
        assert count(cell(img, 0, check), colour) == 0
        assert count(cell(img, 1, check), colour) == 0
        assert count(cell(img, 2, check), colour) > 0
        # Nor a noise band in the pose panels.
        assert count(cell(img, 0, check), BAND_BGR) == 0


def test_checks_with_a_pose_have_a_noise_band(img):
    for check in (0, 1):
        assert count(cell(img, 0, check), BAND_BGR) > 0
        assert count(cell(img, 1, check), BAND_BGR) > 0


def test_larger_change_is_drawn_higher(img):
    def point_row(panel: int, check: int, colour) -> float:
        rows, _ = np.nonzero(np.all(cell(img, panel, check) == np.array(colour, dtype=np.uint8), axis=2))
        return float(rows.mean())

    for panel in range(3):
        assert point_row(panel, 1, DRIFT_BGR) < point_row(panel, 0, OK_BGR)


def test_check_without_rms_has_no_residual_point():
    img = draw_drift([record("ok", 1.5, rotation_deg=0.1), record("drifted", None, rotation_deg=1.2)])
    x = round(WIDTH_PX - 40)
    third = img[20 + 2 * PANEL_PX - 6 : 20 + 3 * PANEL_PX - 34, x - 8 : x + 9]
    assert count(third, DRIFT_BGR) == 0
    assert count(img, DRIFT_BGR) > 0  # its pose points are drawn


def test_one_check_and_no_checks_draw(img):
    one = draw_drift(RECORDS[:1])
    assert one.shape == img.shape
    assert count(one, OK_BGR) > 0
    assert count(one, DRIFT_BGR) == 0
    none = draw_drift([])
    assert none.shape == img.shape
    assert count(none, OK_BGR) == count(none, DRIFT_BGR) == 0


def test_png_is_the_drawn_picture(tmp_path, img):
    path = write_drift_png(tmp_path / "drift.png", RECORDS)
    assert path == tmp_path / "drift.png"
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    np.testing.assert_array_equal(cv2.imread(str(path)), img)


def test_png_refuses_to_overwrite_without_force(tmp_path, img):
    path = tmp_path / "drift.png"
    path.write_bytes(b"keep me")
    with pytest.raises(OutputError, match="exists"):
        write_drift_png(path, RECORDS)
    assert path.read_bytes() == b"keep me"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["drift.png"]
    write_drift_png(path, RECORDS, force=True)
    np.testing.assert_array_equal(cv2.imread(str(path)), img)
