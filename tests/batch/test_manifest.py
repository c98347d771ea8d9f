"""The batch manifest: reading, validation of every key, globs and derived names."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from rigcal.batch.manifest import Item, glob_items, read_manifest
from rigcal.errors import InputError


def write(folder: Path, doc: object) -> Path:
    p = folder / "batch.yaml"
    p.write_text(yaml.safe_dump(doc))
    return p


def test_items_take_defaults_and_paths_from_the_manifest_folder(tmp_path):
    p = write(
        tmp_path,
        {
            "schema_version": 1,
            "command": "check",
            "defaults": {"rig": "rigs/rig.yaml", "level": 0.05},
            "items": [
                {"name": "r1", "picks": "a/picks.yaml"},
                {"name": "r2", "picks": "b/picks.yaml", "level": 0.001, "no_log": True},
            ],
        },
    )
    items = read_manifest(p)
    assert [i.name for i in items] == ["r1", "r2"]
    assert items[0].options == {
        "rig": tmp_path / "rigs/rig.yaml",
        "level": 0.05,
        "picks": tmp_path / "a/picks.yaml",
    }
    argv = items[1].argv(tmp_path / "out" / "r2")
    assert argv == [
        "check",
        str(tmp_path / "rigs/rig.yaml"),
        "--picks",
        str(tmp_path / "b/picks.yaml"),
        "--level",
        "0.001",
        "--no-log",
        "--json",
    ]


def test_solve_and_localize_write_into_the_item_folder(tmp_path):
    solve = Item("a", "solve", {"picks": Path("/p.yaml"), "seed": 3})
    assert solve.argv(tmp_path) == [
        "solve", "/p.yaml", "--seed", "3", "-o", str(tmp_path / "rig.yaml"),
        "--report", str(tmp_path / "report"), "--force", "--json",
    ]  # fmt: skip
    loc = Item(
        "b",
        "localize",
        {"sequence": Path("/s"), "method": "icp,kf", "iasm": ["snap_max_m=0"], "tracks": ["detector=sift"]},
    )
    assert loc.argv(tmp_path) == [
        "localize", "/s", "--method", "icp,kf", "--iasm", "snap_max_m=0", "--tracks", "detector=sift",
        "-o", str(tmp_path / "localize"), "--force", "--json",
    ]  # fmt: skip


def test_names_are_derived_from_the_paths_that_differ(tmp_path):
    p = write(
        tmp_path,
        {
            "schema_version": 1,
            "command": "solve",
            "items": [{"picks": "fleet/r01/today/picks.yaml"}, {"picks": "fleet/r02/today/picks.yaml"}],
        },
    )
    assert [i.name for i in read_manifest(p)] == ["r01", "r02"]


@pytest.mark.parametrize(
    ("doc", "match"),
    [
        ({"schema_version": 2, "command": "check", "items": [{}]}, r"schema_version: got 2; expected 1"),
        ({"schema_version": 1, "command": "fly", "items": [{}]}, r"command: got 'fly'; expected one of"),
        (
            {"schema_version": 1, "command": "solve", "items": []},
            r"items: got \[\]; expected a non-empty list",
        ),
        ({"schema_version": 1, "command": "solve"}, r"items: missing"),
        (
            {"schema_version": 1, "command": "solve", "items": ["a"]},
            r"items\[0\]: got 'a'; expected a mapping",
        ),
        (
            {"schema_version": 1, "command": "solve", "items": [{"picks": "a", "sead": 1}]},
            r"items\[0\].sead: got 1; expected no such key",
        ),
        (
            {"schema_version": 1, "command": "solve", "items": [{"picks": "a", "seed": 1.5}]},
            r"items\[0\].seed: got 1.5; expected an integer",
        ),
        (
            {"schema_version": 1, "command": "check", "items": [{"picks": "a"}]},
            r"items\[0\].rig: missing; check needs it",
        ),
        (
            {"schema_version": 1, "command": "check", "items": [{"rig": "r"}]},
            r"items\[0\]: got 'none of them'; expected exactly one of \['picks', 'session', 'sequence'\]",
        ),
        (
            {"schema_version": 1, "command": "check", "items": [{"rig": "r", "picks": "p", "sequence": "s"}]},
            r"items\[0\]: got \['picks', 'sequence'\]; expected exactly one of",
        ),
        (
            {
                "schema_version": 1,
                "command": "check",
                "items": [{"rig": "r", "picks": "p", "trajectory": "t.tum"}],
            },
            r"items\[0\].trajectory: got '.*t.tum'; expected an item with a sequence",
        ),
        (
            {
                "schema_version": 1,
                "command": "check",
                "items": [{"rig": "r", "sequence": "s", "trajectory": 3}],
            },
            r"items\[0\].trajectory: got 3; expected a path",
        ),
        (
            {"schema_version": 1, "command": "check", "defaults": {"level": "high"}, "items": [{}]},
            r"defaults.level: got 'high'; expected a number",
        ),
        (
            {"schema_version": 1, "command": "solve", "items": [{"picks": "a", "name": "x/y"}]},
            r"items\[0\].name: got 'x/y'; expected a name of letters",
        ),
        (
            {
                "schema_version": 1,
                "command": "solve",
                "items": [{"picks": "a", "name": "x"}, {"picks": "b", "name": "x"}],
            },
            r"items\[1\].name: got 'x'; expected a name no other item has",
        ),
        (
            {"schema_version": 1, "command": "localize", "items": [{"sequence": "s", "kitti": "yes"}]},
            r"items\[0\].kitti: got 'yes'; expected true or false",
        ),
        (
            {"schema_version": 1, "command": "localize", "items": [{"sequence": ""}]},
            r"items\[0\].sequence: got ''; expected a path",
        ),
    ],
)
def test_bad_manifests_name_the_key(tmp_path, doc, match):
    with pytest.raises(InputError, match=match):
        read_manifest(write(tmp_path, doc))


def test_missing_and_broken_manifest_files(tmp_path):
    with pytest.raises(InputError, match=r"batch manifest not found"):
        read_manifest(tmp_path / "none.yaml")
    (tmp_path / "bad.yaml").write_text("items: [\n")
    with pytest.raises(InputError, match=r"bad.yaml: not valid YAML"):
        read_manifest(tmp_path / "bad.yaml")


def test_a_glob_fills_the_main_input(tmp_path, monkeypatch):
    for name in ("a", "b"):
        (tmp_path / "runs" / name).mkdir(parents=True)
    monkeypatch.chdir(tmp_path)
    items = glob_items("runs/*", "localize", {"method": "icp", "kitti": "true", "iasm": ["keyframe_m=0"]})
    assert [i.name for i in items] == ["a", "b"]
    assert items[0].options == {
        "method": "icp",
        "kitti": True,
        "iasm": ["keyframe_m=0"],
        "sequence": tmp_path / "runs" / "a",
    }
    with pytest.raises(InputError, match=r"manifest glob: got 'none/\*'; expected a pattern matching"):
        glob_items("none/*", "localize", {})
    with pytest.raises(InputError, match=r"--set.seed: got 'x'; expected an integer"):
        glob_items("runs/*", "solve", {"seed": "x"})
    with pytest.raises(InputError, match=r"--set: got 'sequence'; expected an option other than"):
        glob_items("runs/*", "localize", {"sequence": "x"})
    with pytest.raises(InputError, match=r"evaluate needs it"):
        glob_items("runs/*", "evaluate", {})


def test_check_items_take_drives_and_board_sessions(tmp_path, monkeypatch):
    for name in ("r01", "r02"):
        (tmp_path / "fleet" / name / "drive").mkdir(parents=True)
    monkeypatch.chdir(tmp_path)
    items = glob_items("fleet/*/drive", "check", {"rig": "rig.yaml"})
    assert [i.name for i in items] == ["r01", "r02"]
    assert items[0].options["sequence"] == tmp_path / "fleet" / "r01" / "drive"
    assert items[0].argv(tmp_path / "out")[:4] == [
        "check",
        str(tmp_path / "rig.yaml"),
        "--sequence",
        str(items[0].options["sequence"]),
    ]
    with pytest.raises(InputError, match=r"--set: got 'picks'; expected an option other than"):
        glob_items("fleet/*/drive", "check", {"rig": "rig.yaml", "picks": "p.yaml"})
    manifest = tmp_path / "m.yaml"
    manifest.write_text(
        yaml.safe_dump(
            {
                "schema_version": 1,
                "command": "check",
                "defaults": {"rig": "rig.yaml"},
                "items": [{"sequence": "fleet/r01/drive"}, {"session": "r02/board_session.yaml"}],
            }
        )
    )
    a, b = read_manifest(manifest)
    assert (a.name, b.name) == ("fleet_r01_drive", "r02_board_session")
    assert "--session" in b.argv(tmp_path)


def test_a_drives_check_takes_a_trajectory(tmp_path):
    p = write(
        tmp_path,
        {
            "schema_version": 1,
            "command": "check",
            "items": [{"rig": "rig.yaml", "sequence": "d1", "trajectory": "runs/d1/kf/trajectory.tum"}],
        },
    )
    (item,) = read_manifest(p)
    assert item.options["trajectory"] == tmp_path / "runs/d1/kf/trajectory.tum"
    assert item.argv(tmp_path / "out")[2:6] == [
        "--sequence", str(tmp_path / "d1"), "--trajectory", str(tmp_path / "runs/d1/kf/trajectory.tum"),
    ]  # fmt: skip
