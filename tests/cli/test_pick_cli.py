"""`rigcal pick --json`: every capture's picks, confidence and reasons for a script."""

from __future__ import annotations

import json

import numpy as np
import yaml

from rigcal.cli.main import main
from rigcal.sim.box_session import SessionSpec, generate_session, write_session


def test_json_lists_each_capture_with_its_review_reasons(tmp_path, capsys):
    sim = generate_session(SessionSpec(n_captures=6, seed=3))
    folder = write_session(sim, tmp_path / "session")
    doc = yaml.safe_load((folder / "picks.yaml").read_text())
    doc["schema_version"] = 2
    for c in doc["captures"][3:]:
        del c["image_endpoints_px"]
    draft = folder / "draft.yaml"
    draft.write_text(yaml.safe_dump(doc, sort_keys=False))
    out = tmp_path / "auto.yaml"
    assert main(["pick", str(draft), "-o", str(out), "--json"]) == 0
    got = json.loads(capsys.readouterr().out)
    assert got["output"] == str(out)
    assert got["sheet"] is None
    assert got["seeded_from"] == "3 manual picks"
    assert [c["name"] for c in got["captures"]] == [c.name for c in sim.captures]
    assert [c["source"] for c in got["captures"]] == ["manual"] * 3 + ["auto"] * 3
    assert got["solve"]["ends"] == 12
    for c, truth in zip(got["captures"][3:], sim.captures[3:], strict=True):
        assert np.abs(np.array(c["image_endpoints_px"]) - truth.true_pixels).max() < 3.0
        assert c["review"] == bool(c["reasons"])
    # No box side of 2 m in the scans without laser_side: those captures are for review.
    for c in doc["captures"][3:]:
        del c["laser_side"]
    draft.write_text(yaml.safe_dump(doc, sort_keys=False))
    argv = ["pick", str(draft), "-o", str(tmp_path / "a2.yaml"), "--box-width-m", "2", "--json"]
    assert main(argv) == 0
    cap = capsys.readouterr()
    got = json.loads(cap.out)
    for c in got["captures"][3:]:
        assert c["review"]
        assert c["image_endpoints_px"] is None
        assert any("no segment of the box's width 2 m" in r for r in c["reasons"])
        assert f"review {c['name']}: " in cap.err  # stderr still says it
    assert not got["captures"][0]["reasons"]
