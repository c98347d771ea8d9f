"""`rigcal solve` warns when it uses picks marked for review."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import yaml

from rigcal.cli.main import main

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "box-session"


def test_solve_names_the_picks_marked_for_review(tmp_path, capsys):
    session = tmp_path / "s"
    shutil.copytree(EXAMPLE, session)
    doc = yaml.safe_load((session / "picks.yaml").read_text())
    doc["schema_version"] = 2
    for c in doc["captures"]:
        c["pick"] = {"source": "auto", "confidence": 0.9, "review": c["name"] in ("cap04", "cap11")}
    (session / "picks.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
    assert main(["solve", str(session / "picks.yaml"), "-o", str(tmp_path / "rig.yaml"), "--json"]) == 0
    warnings = json.loads(capsys.readouterr().out)["warnings"]
    assert [w for w in warnings if "marked for review" in w] == [
        "2 picks marked for review used: cap04, cap11; check them on rigcal pick's contact sheet "
        "(--sheet), then set pick.review to false or remove the capture"
    ]
    for c in doc["captures"]:
        c["pick"]["review"] = False
    (session / "picks.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
    assert main(["solve", str(session / "picks.yaml"), "-o", str(tmp_path / "rig2.yaml"), "--json"]) == 0
    assert not [w for w in json.loads(capsys.readouterr().out)["warnings"] if "review" in w]
