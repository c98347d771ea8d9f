"""Contact sheet of a session's picks: one thumbnail per capture, to verify picks by eye.

Each tile shows the whole image scaled down with the two box ends, and below it both ends
magnified (4x) with a cross at the pick (sub-pixel) and a circle at the prediction. The
label gives the capture's name, the pick's source and confidence and, for a pick to
review, why; picks to review are red, automatic picks green, manual picks blue.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from rigcal.arrays import FloatArray
from rigcal.io.files import atomic_write_bytes

TILE_W = 320
ZOOM = 4
ZOOM_HALF_PX = 20  # each magnified crop shows 40 x 40 px of the image
COLUMNS = 4
REVIEW_BGR = (0, 0, 255)
AUTO_BGR = (0, 200, 0)
MANUAL_BGR = (255, 140, 0)
PREDICTED_BGR = (0, 220, 255)
LABEL_CHARS = 52  # characters of a reason's line across a tile (Hershey simplex at 0.34)


@dataclass(frozen=True)
class SheetEntry:
    """One capture on the sheet.

    Attributes:
        name: the capture's name.
        image_path: its image.
        ends_px: (2, 2) the picks, or None.
        predicted_px: (2, 2) the predictions, or None.
        label: text under the name (source, confidence).
        review: draw in red.
        manual: draw in blue.
        reasons: why the pick is marked for review, one line or more each.
    """

    name: str
    image_path: Path
    ends_px: FloatArray | None
    predicted_px: FloatArray | None
    label: str
    review: bool
    manual: bool
    reasons: tuple[str, ...] = ()


def contact_sheet(entries: Sequence[SheetEntry]) -> NDArray[np.uint8]:
    """The sheet as a BGR image."""
    tiles = [_tile(e) for e in entries]
    h = max(t.shape[0] for t in tiles)
    rows = []
    for i in range(0, len(tiles), COLUMNS):
        row = tiles[i : i + COLUMNS]
        row += [np.full((h, TILE_W, 3), 255, np.uint8)] * (COLUMNS - len(row))
        rows.append(
            np.hstack([np.pad(t, ((0, h - t.shape[0]), (0, 0), (0, 0)), constant_values=255) for t in row])
        )
    return np.vstack(rows)


def write_contact_sheet(path: str | Path, entries: Sequence[SheetEntry], force: bool = False) -> Path:
    """Write the sheet as PNG atomically."""
    import cv2

    ok, buf = cv2.imencode(".png", contact_sheet(entries))
    if not ok:  # pragma: no cover - cv2 encodes any 8-bit image
        raise RuntimeError("PNG encoding failed")
    return atomic_write_bytes(path, buf.tobytes(), force=force)


def _tile(e: SheetEntry) -> NDArray[np.uint8]:
    import cv2

    from rigcal.io.images import read_image

    img = read_image(e.image_path)
    H, W = img.shape[:2]
    s = TILE_W / W
    thumb = cv2.resize(img, (TILE_W, round(H * s)), interpolation=cv2.INTER_AREA)
    colour = REVIEW_BGR if e.review else MANUAL_BGR if e.manual else AUTO_BGR
    if e.ends_px is not None:
        for u, v in e.ends_px:
            cv2.drawMarker(thumb, (round(u * s), round(v * s)), colour, cv2.MARKER_CROSS, 10, 1, cv2.LINE_AA)
    zooms = []
    for j in range(2):
        centre = (
            e.ends_px[j]
            if e.ends_px is not None
            else (e.predicted_px[j] if e.predicted_px is not None else np.array([W / 2, H / 2]))
        )
        zooms.append(
            _zoom(
                img,
                centre,
                e.ends_px[j] if e.ends_px is not None else None,
                e.predicted_px[j] if e.predicted_px is not None else None,
                colour,
            )
        )
    size = TILE_W // 2
    zoom_row = np.hstack([cv2.resize(z, (size, size), interpolation=cv2.INTER_NEAREST) for z in zooms])
    why = [line for r in e.reasons for line in _wrapped(f"- {r}")] if e.review else []
    label = np.full((34 + 14 * len(why), TILE_W, 3), 255, np.uint8)
    cv2.putText(label, e.name, (4, 13), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(label, e.label, (4, 29), cv2.FONT_HERSHEY_SIMPLEX, 0.38, colour, 1, cv2.LINE_AA)
    for k, line in enumerate(why):
        cv2.putText(label, line, (4, 43 + 14 * k), cv2.FONT_HERSHEY_SIMPLEX, 0.34, colour, 1, cv2.LINE_AA)
    tile = np.vstack([thumb, zoom_row, label])
    cv2.rectangle(tile, (0, 0), (TILE_W - 1, tile.shape[0] - 1), (255, 255, 255), 2)
    return tile


def _wrapped(text: str) -> list[str]:
    """``text`` in lines that fit a tile's width at the reasons' font size."""
    import textwrap

    return textwrap.wrap(text, width=LABEL_CHARS, subsequent_indent="  ")


def _zoom(
    img: NDArray[np.uint8],
    centre: FloatArray,
    pick: FloatArray | None,
    predicted: FloatArray | None,
    colour: tuple[int, int, int],
) -> NDArray[np.uint8]:
    """A ZOOM x magnified crop around ``centre`` with the pick and the prediction drawn
    (pixel-centre convention: pixel (0, 0)'s centre is at (0, 0))."""
    import cv2

    c = np.round(centre).astype(int)
    n = 2 * ZOOM_HALF_PX + 1
    pad = np.pad(img, ((n, n), (n, n), (0, 0)), mode="edge")
    crop = pad[
        c[1] - ZOOM_HALF_PX + n : c[1] + ZOOM_HALF_PX + 1 + n,
        c[0] - ZOOM_HALF_PX + n : c[0] + ZOOM_HALF_PX + 1 + n,
    ]
    big = cv2.resize(crop, (n * ZOOM, n * ZOOM), interpolation=cv2.INTER_NEAREST)

    def at(p: FloatArray) -> tuple[int, int]:
        q = (np.asarray(p) - c + ZOOM_HALF_PX + 0.5) * ZOOM
        return round(float(q[0])), round(float(q[1]))

    if predicted is not None:
        cv2.circle(big, at(predicted), 6, PREDICTED_BGR, 1, cv2.LINE_AA)
    if pick is not None:
        cv2.drawMarker(big, at(pick), colour, cv2.MARKER_CROSS, 16, 1, cv2.LINE_AA)
    return np.asarray(big, dtype=np.uint8)
