"""The pick contact sheet says why a capture is marked for review."""

from __future__ import annotations

import cv2
import numpy as np

from rigcal.viz.contact_sheet import LABEL_CHARS, REVIEW_BGR, TILE_W, SheetEntry, contact_sheet


def _entry(image, review: bool, reasons: tuple[str, ...]) -> SheetEntry:
    ends = np.array([[200.0, 240.0], [440.0, 240.0]])
    return SheetEntry("cap01", image, ends, ends + 1.0, "auto, confidence 0.31", review, False, reasons)


def _red_rows(sheet: np.ndarray) -> np.ndarray:
    red = np.all(np.abs(sheet.astype(int) - REVIEW_BGR) < 60, axis=2)
    return np.flatnonzero(red.any(axis=1))


def test_a_pick_to_review_shows_its_reasons_under_the_label(tmp_path):
    image = tmp_path / "cap01.png"
    cv2.imwrite(str(image), np.full((480, 640), 128, np.uint8))
    long_reason = "end 1: no edge found near the prediction; " * 3
    plain = contact_sheet([_entry(image, True, ())])
    told = contact_sheet([_entry(image, True, ("confidence 0.31 below 0.5", long_reason))])
    assert told.shape[1] == plain.shape[1] == 4 * TILE_W
    # One line for the short reason and the long one wrapped to fit the tile's width.
    lines = 1 + -(-len(f"- {long_reason}".strip()) // LABEL_CHARS)
    assert told.shape[0] - plain.shape[0] >= 14 * lines
    assert _red_rows(told).max() > plain.shape[0]  # the reasons are drawn in the review colour
    # A pick not marked for review shows no reasons, even if it has some.
    assert contact_sheet([_entry(image, False, ("confidence 0.31 below 0.5",))]).shape == plain.shape
