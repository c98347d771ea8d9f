"""rigcal simulate marker-session: what it writes, and a bad targets file."""

from __future__ import annotations

import json

import yaml

from rigcal.cli.main import main
from rigcal.targets.marker import default_target, targets_text


def test_simulate_marker_session(tmp_path, capsys):
    out = tmp_path / "v"
    assert (
        main(["simulate", "marker-session", "-o", str(out), "--captures", "2", "--seed", "3", "--json"]) == 0
    )
    doc = json.loads(capsys.readouterr().out)
    assert doc["entry"] == str(out / "marker_session.yaml")
    session = yaml.safe_load((out / "marker_session.yaml").read_text())
    assert session["method"] == "marker"
    assert [c["image"] for c in session["captures"]] == ["images/cap00.png", "images/cap01.png"]
    assert (out / "images" / "cap01.png").is_file()
    assert (out / "truth.yaml").is_file()
    assert (out / "targets.yaml").read_text() == targets_text(default_target())
    # Ten scans of each still moment by default, independent noise each.
    assert session["schema_version"] == 2
    scans = session["captures"][0]["scans"]
    assert scans == [f"scans/cap00_{j:02d}.yaml" for j in range(10)]
    r = [yaml.safe_load((out / f).read_text())["ranges_m"] for f in scans[:2]]
    assert r[0] != r[1]
    # Refuses to overwrite without --force.
    assert main(["simulate", "marker-session", "-o", str(out), "--captures", "2"]) == 5


def test_simulate_marker_session_one_scan_a_capture(tmp_path):
    out = tmp_path / "v"
    args = ["simulate", "marker-session", "-o", str(out), "--captures", "1", "--scans-per-capture", "1"]
    assert main(args) == 0
    session = yaml.safe_load((out / "marker_session.yaml").read_text())
    assert session["captures"][0]["scan"] == "scans/cap00.yaml"
    assert main([*args[:-1], "0", "--force"]) == 2


def test_simulate_marker_session_bad_targets(tmp_path, capsys):
    bad = tmp_path / "t.yaml"
    bad.write_text(targets_text(default_target()).replace("angle_deg: 90", "angle_deg: 175"))
    assert main(["simulate", "marker-session", "-o", str(tmp_path / "v"), "--targets", str(bad)]) == 3
    assert "angle_deg: got 175" in capsys.readouterr().err
    assert not (tmp_path / "v").exists()
