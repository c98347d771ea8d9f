"""The batch's summary: one row per item as CSV and JSON (docs/formats/batch-summary.md).

Each row has the item's status and the figures a reader compares across a fleet or a
sweep: the drift check's verdict, rotation and translation change; a solve's residuals;
each localization method's Table 1 errors; an evaluation's errors.
"""

from __future__ import annotations

import csv
import datetime
import io
import json
from pathlib import Path
from typing import Any

from rigcal import __version__
from rigcal.batch.runner import Outcome, warning_lines
from rigcal.io.files import atomic_write_text

SUMMARY_SCHEMA_VERSION = 3  # 2: host, node; 3: warnings
BASE_COLUMNS = (
    "name", "command", "status", "resumed", "exit_code", "seconds", "host", "node", "error", "warnings",
)  # fmt: skip
METRICS = ("ate_rmse_m", "average_position_error_m", "loop_closure_error_percent", "rpe_1m_rmse_m")


def figures(command: str, result: Any) -> dict[str, Any]:
    """The comparable figures of one item's result (the command's JSON), flat."""
    if not isinstance(result, dict):
        return {}
    if command == "check":
        r = result.get("residual") or {}
        # A drive's targetless correction stands where a fresh solve's change would.
        pose = result.get("pose") or result.get("targetless") or {}
        return {
            "kind": result.get("kind", "box"),
            "verdict": result.get("verdict"),
            "residual_rms_px": r.get("rms_px"),
            "residual_p_value": r.get("p_value"),
            "rotation_deg": pose.get("rotation_deg"),
            "translation_mm": pose.get("translation_mm"),
            "pose_p_value": pose.get("p_value"),
        }
    if command == "solve":
        s = result.get("summary") or {}
        row = {k: s.get(k) for k in ("captures_used", "inlier_ends", "rms_px", "median_px")}
        truth = result.get("truth")
        if isinstance(truth, dict):
            row |= {f"truth_{k}": v for k, v in truth.items() if isinstance(v, (int, float))}
        return row
    if command == "localize":
        row = {"x_real_time": result.get("x_real_time")}
        for method, m in (result.get("methods") or {}).items():
            metrics = m.get("metrics") or {}
            row |= {f"{method}.{k}": metrics.get(k) for k in METRICS if k in metrics}
        return row
    return {k: result.get(k) for k in METRICS}  # evaluate


def rows(outcomes: list[Outcome]) -> list[dict[str, Any]]:
    """One flat row per item."""
    out = []
    for o in outcomes:
        r = o.record
        base = {
            "name": o.item.name,
            "command": o.item.command,
            "status": r["status"],
            "resumed": o.resumed,
            "exit_code": r["exit_code"],
            "seconds": r["seconds"],
            "host": r.get("host"),
            "node": r.get("node"),
            "error": r["error"],
            "warnings": " | ".join(warning_lines(str(r.get("stderr") or ""))) or None,
        }
        out.append(base | figures(o.item.command, r.get("result")))
    return out


def write_summary(output: str | Path, outcomes: list[Outcome]) -> tuple[Path, Path]:
    """Write ``summary.json`` and ``summary.csv`` into the batch folder (replacing the last
    run's: they always describe every item)."""
    out = Path(output)
    table = rows(outcomes)
    columns = list(BASE_COLUMNS)
    for row in table:
        columns += [k for k in row if k not in columns]
    counts = {s: sum(r["status"] == s for r in table) for s in ("ok", "drifted", "cannot_tell", "failed")}
    doc = {
        "schema_version": SUMMARY_SCHEMA_VERSION,
        "rigcal_version": __version__,
        "written_utc": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "command": outcomes[0].item.command if outcomes else None,
        "counts": counts,
        "columns": columns,
        "items": table,
    }
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=columns, lineterminator="\n")
    writer.writeheader()
    for row in table:
        writer.writerow({k: _cell(row.get(k)) for k in columns})
    j = atomic_write_text(out / "summary.json", json.dumps(doc, indent=1) + "\n", force=True)
    c = atomic_write_text(out / "summary.csv", buf.getvalue(), force=True)
    return j, c


def _cell(v: Any) -> Any:
    if v is None:
        return ""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return v.replace("\n", " ")
    return v
