"""The drift log: one JSON record per check, appended and read back with validation."""

from __future__ import annotations

import hashlib
import json
import math
import re
from pathlib import Path

import pytest

from rigcal.drift.log import (
    DRIFT_LOG_SCHEMA_VERSION,
    RECORD_KEYS,
    append_record,
    default_log_path,
    drift_record,
    read_log,
)
from rigcal.drift.target import DriftResult
from rigcal.errors import InputError, OutputError

RESIDUAL = {
    "ends": 12,
    "used_ends": 12,
    "rejected_ends": 0,
    "rms_px": 1.83,
    "max_px": 3.9,
    "chi2": 25.1,
    "dof": 24,
    "p_value": 0.4,
}
POSE = {
    "rotation_deg": 0.12,
    "translation_mm": 4.5,
    "rotation_diff_deg": [0.05, -0.09, 0.04],
    "translation_diff_mm": [3.1, -2.2, 2.4],
    "sigma_rotation_deg": [0.09, 0.13, 0.08],
    "sigma_translation_mm": [5.9, 3.5, 4.8],
    "mahalanobis2": 5.1,
    "p_value": 0.53,
}


def result(drifted: bool = False, pose: dict | None = POSE, **residual: float) -> DriftResult:
    reasons = ["a fresh solve differs by ..."] if drifted else []
    return DriftResult(drifted, 0.01, RESIDUAL | residual, pose, None, reasons)


@pytest.fixture
def picks(tmp_path) -> Path:
    p = tmp_path / "session" / "picks.yaml"
    p.parent.mkdir()
    p.write_text("schema_version: 1\n")
    return p


def test_record_has_every_key_and_names_the_picks(picks):
    rec = drift_record(result(drifted=True), picks)
    assert tuple(rec) == RECORD_KEYS
    assert rec["schema_version"] == DRIFT_LOG_SCHEMA_VERSION
    assert rec["verdict"] == "drifted"
    assert rec["level"] == 0.01
    assert rec["kind"] == "box"
    assert rec["input"] == str(picks.resolve())
    assert rec["input_sha256"] == hashlib.sha256(picks.read_bytes()).hexdigest()
    assert rec["targetless"] is None
    assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ", rec["checked_utc"])
    assert rec["residual"] == RESIDUAL
    assert rec["pose"] == POSE
    assert rec["reasons"] == ["a fresh solve differs by ..."]


def test_record_writes_no_rms_as_null(picks):
    rec = drift_record(result(drifted=True, pose=None, used_ends=0, rms_px=math.nan, max_px=math.inf), picks)
    assert rec["residual"]["rms_px"] is None
    assert rec["residual"]["max_px"] is None
    assert rec["residual"]["ends"] == 12
    assert rec["pose"] is None


def test_records_round_trip_through_the_log(picks, tmp_path):
    log = tmp_path / "rig.checks.jsonl"
    records = [
        drift_record(result(), picks),
        drift_record(result(drifted=True), picks),
        drift_record(result(pose=None, used_ends=0, rms_px=math.nan), picks),
    ]
    for rec in records:
        assert append_record(log, rec) == log
    assert read_log(log) == records
    lines = log.read_text().splitlines()
    assert len(lines) == 3
    assert [json.loads(line)["verdict"] for line in lines] == ["ok", "drifted", "ok"]
    assert "NaN" not in log.read_text()


def test_append_keeps_what_is_there_and_makes_the_folder(picks, tmp_path):
    log = tmp_path / "logs" / "deep" / "rig.checks.jsonl"
    append_record(log, drift_record(result(), picks))
    first = log.read_text()
    append_record(log, drift_record(result(drifted=True), picks))
    assert log.read_text().startswith(first)
    assert len(read_log(log)) == 2


def test_append_where_the_folder_is_a_file_is_an_output_error(picks, tmp_path):
    (tmp_path / "blocker").write_text("")
    with pytest.raises(OutputError, match="drift log"):
        append_record(tmp_path / "blocker" / "rig.checks.jsonl", drift_record(result(), picks))


def test_read_log_skips_blank_lines(picks, tmp_path):
    log = tmp_path / "log.jsonl"
    line = json.dumps(drift_record(result(), picks))
    log.write_text(f"\n{line}\n   \n{line}\n\n")
    assert len(read_log(log)) == 2


def test_read_log_of_a_missing_file(tmp_path):
    with pytest.raises(InputError, match=r"nope\.jsonl: drift log not found"):
        read_log(tmp_path / "nope.jsonl")


def write_lines(path: Path, *records: object) -> Path:
    path.write_text("".join((r if isinstance(r, str) else json.dumps(r)) + "\n" for r in records))
    return path


def good_record(picks: Path) -> dict:
    return drift_record(result(), picks)


def test_read_log_names_the_line_that_is_not_json(picks, tmp_path):
    log = write_lines(tmp_path / "log.jsonl", good_record(picks), '{"verdict": "ok",')
    with pytest.raises(InputError, match=r"log\.jsonl: line 2: not JSON"):
        read_log(log)


def test_read_log_refuses_a_line_that_is_not_an_object(picks, tmp_path):
    log = write_lines(tmp_path / "log.jsonl", [1, 2])
    with pytest.raises(InputError, match=r"line 1.*a JSON object"):
        read_log(log)


@pytest.mark.parametrize("version", [3, 0, "1", 1.0, True, None])
def test_read_log_refuses_another_schema_version(picks, tmp_path, version):
    bad = good_record(picks) | {"schema_version": version}
    log = write_lines(tmp_path / "log.jsonl", good_record(picks), good_record(picks), bad)
    with pytest.raises(InputError, match="line 3: schema_version"):
        read_log(log)


def test_read_log_refuses_missing_keys(picks, tmp_path):
    bad = {k: v for k, v in good_record(picks).items() if k not in ("pose", "level")}
    log = write_lines(tmp_path / "log.jsonl", bad)
    with pytest.raises(InputError, match=r"line 1: missing keys \['level', 'pose'\]"):
        read_log(log)


@pytest.mark.parametrize("verdict", ["OK", "maybe", None, True])
def test_read_log_refuses_a_bad_verdict(picks, tmp_path, verdict):
    log = write_lines(tmp_path / "log.jsonl", good_record(picks), good_record(picks) | {"verdict": verdict})
    with pytest.raises(InputError, match=r"line 2: verdict.*\['ok', 'drifted', 'cannot_tell'\]"):
        read_log(log)


@pytest.mark.parametrize(
    ("rig", "log"),
    [
        ("rig.yaml", "rig.checks.jsonl"),
        ("lab/rig.yaml", "lab/rig.checks.jsonl"),
        ("lab/rig.v2.yml", "lab/rig.v2.checks.jsonl"),
        ("rig", "rig.checks.jsonl"),
    ],
)
def test_default_log_path_is_beside_the_rig(rig, log):
    assert default_log_path(rig) == Path(log)
    assert default_log_path(Path(rig)) == Path(log)


def test_append_after_a_last_line_without_newline_keeps_both_records(picks, tmp_path):
    log = tmp_path / "rig.checks.jsonl"
    append_record(log, drift_record(result(), picks))
    log.write_text(log.read_text().rstrip("\n"))  # an editor dropped the final newline
    append_record(log, drift_record(result(drifted=True), picks))
    assert [r["verdict"] for r in read_log(log)] == ["ok", "drifted"]


def test_schema_1_records_are_read_as_they_are(picks, tmp_path):
    old = {
        "schema_version": 1,
        "checked_utc": "2026-11-23T08:12:40Z",
        "picks": str(picks),
        "picks_sha256": "0" * 64,
        "verdict": "ok",
        "level": 0.01,
        "residual": RESIDUAL,
        "pose": None,
        "reasons": [],
    }
    log = tmp_path / "rig.checks.jsonl"
    log.write_text(json.dumps(old) + "\n")
    append_record(log, drift_record(result(drifted=False), picks))
    recs = read_log(log)
    assert [r["schema_version"] for r in recs] == [1, 2]
    assert recs[0]["picks"] == str(picks)


@pytest.mark.parametrize(
    ("change", "match"),
    [
        ({"kind": "lidar"}, r"line 1: kind: got 'lidar'; expected one of \['box', 'board', 'targetless'\]"),
        (
            {"verdict": "maybe"},
            r"line 1: verdict: got 'maybe'; expected one of \['ok', 'drifted', 'cannot_tell'\]",
        ),
        ({"schema_version": 3}, r"line 1: schema_version: got 3; expected 1 or 2"),
    ],
)
def test_bad_schema_2_records_name_the_line_and_key(picks, tmp_path, change, match):
    rec = drift_record(result(drifted=False), picks) | change
    log = tmp_path / "rig.checks.jsonl"
    log.write_text(json.dumps(rec) + "\n")
    with pytest.raises(InputError, match=match):
        read_log(log)


def test_a_schema_1_verdict_cannot_be_cannot_tell(picks, tmp_path):
    log = tmp_path / "rig.checks.jsonl"
    old = dict.fromkeys(("checked_utc", "picks", "picks_sha256", "level", "residual", "pose"))
    log.write_text(json.dumps(old | {"schema_version": 1, "verdict": "cannot_tell", "reasons": []}) + "\n")
    with pytest.raises(InputError, match=r"verdict: got 'cannot_tell'; expected one of \['ok', 'drifted'\]"):
        read_log(log)
