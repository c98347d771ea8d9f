"""A fleet's nightly targetless checks with the inputs a fleet really has: a drive that is
missing, one without images, one of another rig (its camera's image size), beside a good
one; and fleet files with repeated item names or unknown keys. Each bad item fails alone
with its one-line reason in the summary (exit 1 for the batch), a bad fleet file stops
before any item runs (exit 3), nothing half-written."""

from __future__ import annotations

import csv
import shutil
from pathlib import Path

import pytest
import yaml

from rigcal.batch.manifest import read_manifest
from rigcal.cli.main import main
from rigcal.errors import InputError
from room_scans import room_drive


@pytest.fixture(scope="module")
def fleet(tmp_path_factory) -> Path:
    base = tmp_path_factory.mktemp("fleet")
    good = room_drive(base)
    shutil.copytree(good, base / "noimg")
    (base / "noimg" / "images.csv").write_text("stamp_s,file\n")
    doc = yaml.safe_load((base / "noimg" / "sequence.yaml").read_text())
    doc["images"]["count"] = 0
    (base / "noimg" / "sequence.yaml").write_text(yaml.safe_dump(doc))
    rig = yaml.safe_load((base / "rig.yaml").read_text())
    rig["camera"]["imagersize"] = [640, 480]  # the rig of another robot, whose camera differs
    (base / "rig640.yaml").write_text(yaml.safe_dump(rig))
    return base


def _manifest(folder: Path, items: list[dict], defaults: dict | None = None) -> Path:
    doc = {"schema_version": 1, "command": "check", "items": items}
    if defaults is not None:
        doc["defaults"] = defaults
    (folder / "fleet.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
    return folder / "fleet.yaml"


def test_bad_drives_fail_alone_with_their_reason(fleet, tmp_path, capsys):
    items = [
        {"name": "missing", "rig": str(fleet / "rig.yaml"), "sequence": str(fleet / "nowhere")},
        {"name": "noimg", "rig": str(fleet / "rig.yaml"), "sequence": str(fleet / "noimg")},
        {"name": "other", "rig": str(fleet / "rig640.yaml"), "sequence": str(fleet / "seq")},
        {"name": "good", "rig": str(fleet / "rig.yaml"), "sequence": str(fleet / "seq")},
    ]
    manifest = _manifest(tmp_path, items, {"no_log": True})
    assert main(["batch", str(manifest), "-o", str(tmp_path / "out"), "-j", "1"]) == 1
    with (tmp_path / "out" / "summary.csv").open() as f:
        rows = {r["name"]: r for r in csv.DictReader(f)}
    assert {n: (r["status"], r["exit_code"]) for n, r in rows.items()} == {
        "missing": ("failed", "3"),
        "noimg": ("failed", "3"),
        "other": ("failed", "3"),
        "good": ("cannot_tell", "6"),  # four seconds: too short, said as such
    }
    assert (
        rows["missing"]["error"]
        == f"{fleet / 'nowhere'}: not found; expected a sequence folder holding sequence.yaml"
    )
    assert rows["noimg"]["error"].startswith(
        f"{fleet / 'noimg' / 'sequence.yaml'}: images.count: got 0; expected"
    )
    assert rows["other"]["error"] == (
        f"{fleet / 'seq' / 'rig.yaml'}: image size: got '64x48'; expected 640x480, the rig's camera "
        f"({fleet / 'rig640.yaml'}): a drive of another rig?"
    )
    assert "Traceback" not in capsys.readouterr().err
    assert sorted(p.name for p in fleet.iterdir()) == ["noimg", "rig.yaml", "rig640.yaml", "seq"]


@pytest.mark.parametrize(
    ("items", "defaults", "match"),
    [
        (
            [
                {"name": "r1", "rig": "a.yaml", "sequence": "s1"},
                {"name": "r1", "rig": "b.yaml", "sequence": "s2"},
            ],
            None,
            r"fleet.yaml: items\[1\].name: got 'r1'; expected a name no other item has",
        ),
        (
            [{"rig": "a.yaml", "sequence": "s1", "sequense": "s2"}],
            None,
            r"items\[0\].sequense: got 's2'; expected no such key; allowed keys are",
        ),
        (
            [{"rig": "a.yaml", "sequence": "s1"}],
            {"plot": "x.png"},
            r"defaults.plot: got 'x.png'; expected no",
        ),
        (
            [{"rig": "a.yaml", "sequence": "s1", "picks": "p.yaml"}],
            None,
            r"items\[0\]: got \['picks', 'sequence'\]",
        ),
    ],
)
def test_a_bad_fleet_file_stops_before_any_item(tmp_path, capsys, items, defaults, match):
    manifest = _manifest(tmp_path, items, defaults)
    with pytest.raises(InputError, match=match):
        read_manifest(manifest)
    assert main(["batch", str(manifest), "-o", str(tmp_path / "out")]) == 3
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert err[0].startswith("Error: ")
    assert not (tmp_path / "out").exists()
