"""The drift history of a rig: one JSON record per check, appended to a file beside the rig
(docs/formats/drift-log.md). ``rigcal check`` appends to ``<rig>.checks.jsonl``; the plot
of drift over time is drawn from it (:mod:`rigcal.viz.drift_plot`).

Schema 2 records say which kind of check ran (``box``, ``board`` or ``targetless``) and
what it read (``input``, ``input_sha256``); schema 1 records (box checks, ``picks``) are
read as they are."""

from __future__ import annotations

import datetime
import json
import math
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rigcal.errors import InputError, OutputError
from rigcal.io.files import read_text, sha256_file, text_lines

if TYPE_CHECKING:  # types only: a drive's check need not load the target checks' solvers
    from rigcal.drift.target import DriftResult
    from rigcal.drift.targetless import TargetlessResult

DRIFT_LOG_SCHEMA_VERSION = 2

RECORD_KEYS_V1 = (
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
RECORD_KEYS = (
    "schema_version",
    "checked_utc",
    "kind",
    "input",
    "input_sha256",
    "verdict",
    "level",
    "residual",
    "pose",
    "targetless",
    "reasons",
)
KINDS = ("box", "board", "targetless")
VERDICTS = ("ok", "drifted", "cannot_tell")
# The verdicts' exit codes (docs/cli.md).
EXIT_CODES = {"ok": 0, "drifted": 1, "cannot_tell": 6}


def default_log_path(rig_path: str | Path) -> Path:
    """``rig.yaml`` -> ``rig.checks.jsonl`` in the same folder."""
    p = Path(rig_path)
    return p.with_name(p.stem + ".checks.jsonl")


def drift_record(result: DriftResult, session_path: str | Path, kind: str = "box") -> dict[str, Any]:
    """The log record of one check with a target (``box`` picks or a ``board`` session)."""
    return {
        "schema_version": DRIFT_LOG_SCHEMA_VERSION,
        "checked_utc": _now(),
        "kind": kind,
        "input": str(Path(session_path).resolve()),
        "input_sha256": sha256_file(session_path),
        "verdict": result.verdict,
        "level": result.level,
        "residual": _json_safe(result.residual),
        "pose": _json_safe(result.pose),
        "targetless": None,
        "reasons": result.reasons,
    }


def targetless_record(
    result: TargetlessResult, sequence: str | Path, trajectory: str | Path | None = None
) -> dict[str, Any]:
    """The log record of one targetless check of a drive (a sequence folder); its hash is
    over the sequence's index files (sequence.yaml, images.csv, scans.npz). ``trajectory``:
    the TUM file the check took the laser's motion from (its path and hash in the
    ``targetless`` block), None when it ran its own laser odometry."""
    import hashlib

    folder = Path(sequence)
    h = hashlib.sha256()
    for name in ("sequence.yaml", "images.csv", "scans.npz"):
        if (folder / name).is_file():
            h.update(sha256_file(folder / name).encode())
    return {
        "schema_version": DRIFT_LOG_SCHEMA_VERSION,
        "checked_utc": _now(),
        "kind": "targetless",
        "input": str(folder.resolve()),
        "input_sha256": h.hexdigest(),
        "verdict": result.verdict,
        "level": result.level,
        "residual": None,
        "pose": None,
        "targetless": _json_safe(result.record)
        | ({"trajectory": _file_entry(Path(trajectory))} if trajectory is not None else {}),
        "reasons": result.reasons,
    }


def _file_entry(path: Path) -> dict[str, str]:
    return {"file": str(path.resolve()), "sha256": sha256_file(path)}


def _now() -> str:
    return datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


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
    for n, line in enumerate(text_lines(text), start=1):
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
        version = rec.get("schema_version")
        if version not in (1, DRIFT_LOG_SCHEMA_VERSION) or type(version) is not int:
            newer = type(version) is int and version > DRIFT_LOG_SCHEMA_VERSION
            upgrade = " (the versions this rigcal reads; a record of a newer rigcal: upgrade rigcal)"
            raise InputError.at(
                path,
                f"line {n}: schema_version",
                version,
                f"1 or {DRIFT_LOG_SCHEMA_VERSION}" + (upgrade if newer else ""),
            )
        missing = [k for k in (RECORD_KEYS_V1 if version == 1 else RECORD_KEYS) if k not in rec]
        if missing:
            raise InputError(f"{path}: line {n}: missing keys {missing}")
        if version == 2 and rec["kind"] not in KINDS:
            raise InputError.at(path, f"line {n}: kind", rec["kind"], f"one of {list(KINDS)}")
        verdicts = VERDICTS if version == 2 else VERDICTS[:2]
        if rec["verdict"] not in verdicts:
            raise InputError.at(path, f"line {n}: verdict", rec["verdict"], f"one of {list(verdicts)}")
        out.append(rec)
    return out
