"""A chart of a rig's drift history (its drift log) over successive checks.

Three panels share the check axis: the rotation and the translation between each fresh
solve and the stored calibration, with a grey bar of 2 combined sigmas (what noise alone
would give), and the RMS reprojection error of the new picks under the stored calibration.
Targetless checks (drives) put their correction of T_cam_laser on the observed directions
in the first two panels, as diamonds, with 2 sigmas of their own. Checks are green when ok,
red when drifted, grey when the drive could not tell; checks without a fresh solve have
no point in the first two panels. Ticks, labels and a legend are matplotlib's
(rigcal.viz.charts).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from rigcal.viz.charts import DRIFTED, OK, figure, save_figure, style

BAND = "#d9d9d9"
CANNOT_TELL = "#7f7f7f"

PANELS = (
    ("rotation change", "deg", "rotation_deg", "sigma_rotation_deg"),
    ("translation change", "mm", "translation_mm", "sigma_translation_mm"),
    ("RMS reprojection under the stored rig", "px", None, None),
)


def panel_values(records: list[dict[str, Any]], key: str | None, sig_key: str | None) -> tuple[Any, Any]:
    """(values, 2-sigma bands) of one panel, NaN where a check has none."""
    values, bands = [], []
    for r in records:
        pose = r.get("pose") or r.get("targetless")
        if pose and "rotation_deg" not in pose:
            pose = None  # a targetless check that could not tell
        if key is None:
            rms = (r.get("residual") or {}).get("rms_px")  # null when no end was within the gate
            values.append(np.nan if rms is None else float(rms))
            bands.append(np.nan)
        elif pose:
            values.append(float(pose[key]))
            bands.append(2.0 * float(np.linalg.norm(pose[sig_key])))
        else:
            values.append(np.nan)
            bands.append(np.nan)
    return np.array(values, dtype=float), np.array(bands, dtype=float)


def drift_figure(records: list[dict[str, Any]]) -> Any:
    """The chart as a matplotlib Figure (three axes, top to bottom as :data:`PANELS`)."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    fig = figure(9.0, 7.5)
    axes = fig.subplots(3, 1, sharex=True)
    x = np.arange(1, len(records) + 1)
    verdict = np.array([r["verdict"] for r in records])
    drive = np.array([r.get("kind") == "targetless" for r in records], dtype=bool)
    for ax, (title, unit, key, sig_key) in zip(axes, PANELS, strict=True):
        v, b = panel_values(records, key, sig_key)
        ok_band = np.isfinite(b)
        if ok_band.any():
            ax.bar(x[ok_band], b[ok_band], width=0.6, color=BAND, label="2 sigma (noise alone)")
        for name, colour in (("ok", OK), ("drifted", DRIFTED)):
            for kind, marker in ((~drive, "o"), (drive, "D")):
                m = (verdict == name) & kind & np.isfinite(v)
                if m.any():
                    ax.plot(x[m], v[m], marker, color=colour, markersize=7, label=name)
        m = (verdict == "cannot_tell") & drive
        if key is not None and m.any():
            ax.plot(x[m], np.zeros(int(m.sum())), "x", color=CANNOT_TELL, markersize=8, clip_on=False)
        style(ax, title, "", unit)
        ax.margins(y=0.15)
        ax.set_ylim(bottom=0)
    axes[-1].set_xlabel("check")
    if len(records):
        ticks = x if len(x) <= 12 else x[:: max(1, len(x) // 12)]
        axes[-1].set_xticks(ticks, [f"#{i} {str(records[i - 1].get('checked_utc', ''))[:10]}" for i in ticks])
        axes[-1].tick_params(axis="x", labelrotation=30)
    handles = [
        Line2D([], [], marker="o", linestyle="", color=OK, label="ok"),
        Line2D([], [], marker="o", linestyle="", color=DRIFTED, label="drifted"),
        Line2D([], [], marker="D", linestyle="", color="black", label="targetless (a drive)"),
        Line2D([], [], marker="x", linestyle="", color=CANNOT_TELL, label="cannot tell"),
        Patch(color=BAND, label="2 sigma (noise alone)"),
    ]
    axes[0].legend(handles=handles, loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=8)
    return fig


def write_drift_plot(path: str | Path, records: list[dict[str, Any]], force: bool = False) -> Path:
    """Draw and write the chart atomically (PNG, SVG or PDF by the file's suffix)."""
    return save_figure(path, drift_figure(records), force=force)
