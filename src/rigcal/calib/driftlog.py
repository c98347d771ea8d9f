"""The drift history of a rig: one JSON record per check, appended to a file beside the rig
(docs/formats/drift-log.md). ``rigcal check`` appends to ``<rig>.checks.jsonl``; the plot
of drift over time is drawn from it (:mod:`rigcal.viz.drift_plot`)."""

from __future__ import annotations

import datetime
import json
import math
import os
from pathlib import Path
from typing import Any

from rigcal.calib.drift import DRIFT_LOG_SCHEMA_VERSION, DriftResult
from rigcal.errors import InputError, OutputError
from rigcal.io.files import read_text, sha256_file

RECORD_KEYS = (
    "schema_version",
    "checked_utc",
    "picks",
    "picks_sha256",
    "verdict",
    "level",
    "residual",
    "pose",
    "reasons",
)


def default_log_path(rig_path: str | Path) -> Path:
    """``rig.yaml`` -> ``rig.checks.jsonl`` in the same folder."""
    p = Path(rig_path)
    return p.with_name(p.stem + ".checks.jsonl")


def drift_record(result: DriftResult, picks_path: str | Path) -> dict[str, Any]:
    """The log record of one check."""
    return {
        "schema_version": DRIFT_LOG_SCHEMA_VERSION,
        "checked_utc": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "picks": str(Path(picks_path).resolve()),
        "picks_sha256": sha256_file(picks_path),
        "verdict": result.verdict,
        "level": result.level,
        "residual": _json_safe(result.residual),
        "pose": _json_safe(result.pose),
        "reasons": result.reasons,
    }


def _json_safe(x: Any) -> Any:
    """NaN and infinities (e.g. the RMS of no ends) become null: JSON has no such numbers."""
    if isinstance(x, dict):
        return {k: _json_safe(v) for k, v in x.items()}
    if isinstance(x, list):
        return [_json_safe(v) for v in x]
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def append_record(path: str | Path, record: dict[str, Any]) -> Path:
    """Append one record as a single line (one ``write`` of a whole line, flushed and
    synced, so a crash cannot leave half a record)."""
    path = Path(path)
    line = json.dumps(record, separators=(",", ":")) + "\n"
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(path, os.O_RDWR | os.O_APPEND | os.O_CREAT, 0o666)
        try:
            size = os.fstat(fd).st_size
            if size and os.pread(fd, 1, size - 1) != b"\n":
                line = "\n" + line  # a last line without its newline stays a line of its own
            os.write(fd, line.encode("utf-8"))
            os.fsync(fd)
        finally:
            os.close(fd)
    except OSError as exc:
        raise OutputError(f"{path}: cannot append to the drift log: {exc.strerror or exc}") from None
    return path


def read_log(path: str | Path) -> list[dict[str, Any]]:
    """Every record of a drift log, validated.

    Raises:
        InputError: missing or unreadable file, a line that is not a JSON record of this
            schema (named by its line number).
    """
    path = Path(path)
    text = read_text(path, "drift log")
    out = []
    for n, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        try:
            rec = json.loads(line)
        except json.JSONDecodeError as exc:
            raise InputError(f"{path}: line {n}: not JSON ({exc.msg})") from None
        except RecursionError:  # json recurses per level: 50 000 nested brackets
            raise InputError(f"{path}: line {n}: JSON nested too deep; expected one check record") from None
        if not isinstance(rec, dict):
            raise InputError.at(path, f"line {n}", rec, "a JSON object (one check)")
        if (
            rec.get("schema_version") != DRIFT_LOG_SCHEMA_VERSION
            or type(rec.get("schema_version")) is not int
        ):
            raise InputError.at(
                path, f"line {n}: schema_version", rec.get("schema_version"), f"{DRIFT_LOG_SCHEMA_VERSION}"
            )
        missing = [k for k in RECORD_KEYS if k not in rec]
        if missing:
            raise InputError(f"{path}: line {n}: missing keys {missing}")
        if rec["verdict"] not in ("ok", "drifted"):
            raise InputError.at(path, f"line {n}: verdict", rec["verdict"], "'ok' or 'drifted'")
        out.append(rec)
    return out
