"""`rigcal import-laser --json`: what was written, as a script reads it."""

from __future__ import annotations

import json

from rigcal.cli.main import main
from rigcal.recordings.sequence import read_sequence


def test_json_names_the_folder_the_format_and_the_counts(tmp_path, capsys):
    rows = ["stamp_s,angle_deg,range_m"]
    for t in (1.0, 1.1, 1.2):
        rows += [f"{t},{a},{2.0 + a / 100}" for a in (-10, 0, 10)]
    (tmp_path / "l.csv").write_text("\n".join(rows) + "\n")
    out = tmp_path / "seq"
    assert main(["import-laser", str(tmp_path / "l.csv"), "-o", str(out), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc == {
        "output": str(out),
        "entry": str(out / "sequence.yaml"),
        "format": "csv",
        "scans": 3,
        "images": 0,
        "camera": None,
    }
    assert len(read_sequence(out).scans) == 3
    # Refused output: one error line, no JSON.
    assert main(["import-laser", str(tmp_path / "l.csv"), "-o", str(out), "--json"]) == 5
    cap = capsys.readouterr()
    assert cap.out == ""
    assert cap.err.startswith("Error: ")
