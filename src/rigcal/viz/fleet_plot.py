"""A fleet's drift at a glance: one column per rig of a batch of drift checks.

Three panels share the rig axis: the rotation and the translation between each rig's
fresh solve and its stored calibration, each with a bar of 2 combined sigmas (what noise
alone would give), and the RMS reprojection error of the new picks under the stored
calibration. Rigs are green when ok and red when drifted; an item that failed is marked
with a grey cross on the axis, as is a drive that could not tell. A targetless check (a
drive) shows its correction of T_cam_laser on the observed directions in the first two
panels.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from rigcal.io.files import atomic_write_bytes

OK = "#2ca02c"
DRIFT = "#d62728"
FAILED = "#7f7f7f"


def fleet_png(items: list[tuple[str, str, dict[str, Any] | None]]) -> bytes:
    """The picture as PNG bytes.

    Args:
        items: (name, status, drift-check record or None when the item failed), in order.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(items)
    x = np.arange(n)
    fig, axes = plt.subplots(3, 1, figsize=(max(6.0, 0.45 * n + 2.0), 7.5), sharex=True)
    panels = [
        ("rotation change (deg)", "rotation_deg", "sigma_rotation_deg"),
        ("translation change (mm)", "translation_mm", "sigma_translation_mm"),
        ("RMS reprojection under\nstored rig (px)", None, None),
    ]
    for ax, (label, key, sigma_key) in zip(axes, panels, strict=True):
        for i, (_, status, rec) in enumerate(items):
            if rec is None or status == "cannot_tell":
                ax.plot(i, 0, "x", color=FAILED, ms=8, clip_on=False)
                continue
            colour = DRIFT if status == "drifted" else OK
            if key is None:
                value = (rec.get("residual") or {}).get("rms_px")
            else:
                # A drive's targetless correction stands where a fresh solve's change would.
                pose = rec.get("pose") or rec.get("targetless")
                if not pose or "rotation_deg" not in pose:
                    continue  # no fresh solve, or a drive that could not tell
                value = pose[key]
                band = 2.0 * float(np.linalg.norm(pose[sigma_key]))
                ax.bar(i, band, width=0.6, color="#dddddd", zorder=1)
            if value is not None:
                ax.plot(i, value, "o", color=colour, ms=7, zorder=2)
        ax.set_ylabel(label)
        ax.set_ylim(bottom=0)
        ax.grid(axis="y", alpha=0.3)
    axes[0].set_title(
        f"drift checks of {n} rigs: {sum(s == 'drifted' for _, s, _ in items)} drifted, "
        f"{sum(s == 'failed' for _, s, _ in items)} failed, "
        f"{sum(s == 'cannot_tell' for _, s, _ in items)} cannot tell\n(grey bars: 2 sigma of noise)",
        fontsize=10,
    )
    axes[-1].set_xticks(
        x, [name for name, _, _ in items], rotation=60 if n > 8 else 0, ha="right" if n > 8 else "center"
    )
    fig.tight_layout()
    import io

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    plt.close(fig)
    return buf.getvalue()


def write_fleet_png(path: str | Path, items: list[tuple[str, str, dict[str, Any] | None]]) -> Path:
    """Draw and write the picture atomically (replacing an earlier run's)."""
    return atomic_write_bytes(path, fleet_png(items), force=True)
