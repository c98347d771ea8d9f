"""A picture of a rig's drift history (its drift log) over successive checks.

Three panels share the check axis: the rotation and the translation between each fresh
solve and the stored calibration, with a grey band of 2 combined sigmas (what noise alone
would give), and the RMS reprojection error of the new picks under the stored calibration.
Checks are green when ok and red when drifted; checks without a fresh solve have no point
in the first two panels.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from rigcal.io.files import atomic_write_bytes

OK_BGR = (60, 160, 40)
DRIFT_BGR = (40, 40, 220)
BAND_BGR = (225, 225, 225)
AXIS_BGR = (90, 90, 90)


def draw_drift(records: list[dict[str, Any]], width_px: int = 900, panel_px: int = 220) -> NDArray[np.uint8]:
    """The picture as an 8-bit BGR image."""
    import cv2

    n = len(records)
    img = np.full((3 * panel_px + 40, width_px, 3), 255, dtype=np.uint8)
    panels = [
        ("rotation change (deg)", "rotation_deg", "sigma_rotation_deg"),
        ("translation change (mm)", "translation_mm", "sigma_translation_mm"),
        ("RMS reprojection under stored rig (px)", None, None),
    ]
    left, right = 70, width_px - 20
    xs = np.linspace(left + 20, right - 20, n) if n > 1 else np.array([(left + right) / 2.0])
    for p, (title, key, sig_key) in enumerate(panels):
        top = 20 + p * panel_px
        bottom = top + panel_px - 40
        values = []
        bands = []
        for r in records:
            pose = r.get("pose")
            if key is None:
                rms = r["residual"]["rms_px"]  # null when no end was within the gate
                values.append(float("nan") if rms is None else float(rms))
                bands.append(0.0)
            elif pose:
                values.append(float(pose[key]))
                bands.append(2.0 * float(np.linalg.norm(pose[sig_key])))
            else:
                values.append(float("nan"))
                bands.append(float("nan"))
        v = np.array(values, dtype=float)
        b = np.array(bands, dtype=float)
        finite = np.isfinite(v)
        vmax = float(np.nanmax(np.concatenate([v[finite], b[np.isfinite(b)], [1e-9]]))) * 1.15
        vmax = vmax if vmax > 0 else 1.0

        def y(value: float, top: int = top, bottom: int = bottom, vmax: float = vmax) -> int:
            return round(bottom - (bottom - top) * value / vmax)

        half = min(14.0, 0.4 * (xs[1] - xs[0])) if n > 1 else 14.0
        for i in range(n):
            if np.isfinite(b[i]) and b[i] > 0:
                cv2.rectangle(
                    img, (round(xs[i] - half), y(b[i])), (round(xs[i] + half), bottom), BAND_BGR, -1
                )
        cv2.line(img, (left, bottom), (right, bottom), AXIS_BGR, 1)
        cv2.line(img, (left, top), (left, bottom), AXIS_BGR, 1)
        cv2.putText(img, title, (left + 5, top - 4), cv2.FONT_HERSHEY_SIMPLEX, 0.5, AXIS_BGR, 1, cv2.LINE_AA)
        cv2.putText(
            img, f"{vmax:.3g}", (5, top + 10), cv2.FONT_HERSHEY_SIMPLEX, 0.4, AXIS_BGR, 1, cv2.LINE_AA
        )
        cv2.putText(img, "0", (55, bottom), cv2.FONT_HERSHEY_SIMPLEX, 0.4, AXIS_BGR, 1, cv2.LINE_AA)
        for i, r in enumerate(records):
            if not finite[i]:
                continue
            colour = DRIFT_BGR if r["verdict"] == "drifted" else OK_BGR
            cv2.circle(img, (round(xs[i]), y(v[i])), 5, colour, -1, cv2.LINE_AA)
    for i, r in enumerate(records):
        label = f"#{i + 1} {str(r.get('checked_utc', ''))[:10]}"
        if n <= 12 or i % max(1, n // 12) == 0:
            cv2.putText(
                img,
                label,
                (round(xs[i]) - 35, 3 * panel_px + 30),
                cv2.FONT_HERSHEY_SIMPLEX,
                0.35,
                AXIS_BGR,
                1,
            )
    return img


def write_drift_png(path: str | Path, records: list[dict[str, Any]], force: bool = False) -> Path:
    """Draw and write the picture atomically as a PNG."""
    import cv2

    ok, buf = cv2.imencode(".png", draw_drift(records))
    if not ok:  # pragma: no cover - cv2 encodes any 8-bit image
        raise RuntimeError("PNG encoding failed")
    return atomic_write_bytes(path, buf.tobytes(), force=force)
