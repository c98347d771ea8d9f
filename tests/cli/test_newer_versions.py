"""Files of a newer schema_version than this rigcal reads, as a fleet meets them when one
robot's rigcal is upgraded before another's: each reader names the version and says to
upgrade, before it checks the keys (a newer file's new keys are not typos)."""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import yaml

from rigcal.batch.manifest import read_manifest
from rigcal.calib.box.picks import read_pick_draft
from rigcal.calib.truth import read_truth
from rigcal.camera import read_camera
from rigcal.drift.log import read_log
from rigcal.errors import InputError
from rigcal.recordings.sequence import read_sequence, write_sequence
from rigcal.rigfile import read_rig, write_rig
from rigcal.scan import read_scan
from rigcal.sim.box_session import default_T_cam_laser
from rigcal.sim.world import read_world
from rigcal.targets.board import read_target
from rigcal.targets.marker import default_target, targets_text
from room_scans import room_scan

EXAMPLE = Path(__file__).parents[2] / "examples" / "box-session"
NEWER = (
    r"schema_version: got 99; expected [\d, or]+ "
    r"\(the versions? this rigcal reads; a file of a newer rigcal: upgrade"
)


def _rig(folder: Path) -> Path:
    from rigcal.rig import Rig

    return write_rig(folder / "rig.yaml", Rig(default_T_cam_laser(), read_camera(EXAMPLE / "camera.yaml")))


def _sequence(folder: Path) -> Path:
    scans = [room_scan(0.05 * k, 0.1 * k) for k in range(5)]
    return write_sequence(folder / "seq", "room", scans, [], None, {}) / "sequence.yaml"


def _copy(name: str) -> Callable[[Path], Path]:
    def make(folder: Path) -> Path:
        shutil.copytree(EXAMPLE, folder / "ex")
        return folder / "ex" / name

    return make


def _text(name: str, text: str) -> Callable[[Path], Path]:
    def make(folder: Path) -> Path:
        (folder / name).write_text(text)
        return folder / name

    return make


BOARD = "schema_version: 2\nkind: board\nboard: {corners_x: 7, corners_y: 5, spacing_m: 0.05}\n"
WORLD = (
    "schema_version: 1\nname: room\nwalls:\n  - {from: [0, 0], to: [8, 0]}\n  - {from: [8, 0], to: [8, 6]}\n"
    "path: [[2, 2], [6, 2], [6, 4], [2, 4]]\n"
)
MANIFEST = "schema_version: 1\ncommand: check\nitems:\n  - {rig: rig.yaml, sequence: seq}\n"

READERS = [
    ("rig", _rig, read_rig),
    ("sequence", _sequence, lambda p: read_sequence(p.parent)),
    ("camera", _copy("camera.yaml"), read_camera),
    ("picks", _copy("picks.yaml"), read_pick_draft),
    ("scan", _copy("scans/cap00.yaml"), read_scan),
    ("truth", _copy("truth.yaml"), read_truth),
    ("board targets", _text("board.yaml", BOARD), read_target),
    ("marker targets", _text("v.yaml", targets_text(default_target())), read_target),
    ("world", _text("world.yaml", WORLD), read_world),
    ("manifest", _text("fleet.yaml", MANIFEST), read_manifest),
]


@pytest.mark.parametrize(("make", "read"), [r[1:] for r in READERS], ids=[r[0] for r in READERS])
def test_a_newer_file_is_named_as_such_not_its_new_keys_as_typos(tmp_path, make, read):
    path = make(tmp_path)
    read(path)  # the file as this rigcal writes it reads
    doc = yaml.safe_load(path.read_text())
    path.write_text(yaml.safe_dump({**doc, "schema_version": 99, "a_key_of_version_99": {"x": 1}}))
    with pytest.raises(InputError, match=NEWER):
        read(path)
    # An older or unknown version, or a key that is not of a newer version, as before.
    path.write_text(yaml.safe_dump({**doc, "a_key_of_version_99": {"x": 1}}))
    with pytest.raises(InputError, match=r"a_key_of_version_99: got \{'x': 1\}; expected no such key"):
        read(path)


def test_a_drift_log_record_of_a_newer_rigcal(tmp_path):
    log = tmp_path / "rig.checks.jsonl"
    log.write_text(json.dumps({"schema_version": 99, "verdict": "ok"}) + "\n")
    with pytest.raises(InputError, match=r"line 1: schema_version: got 99; expected 1 or \d .*upgrade"):
        read_log(log)


def test_check_and_localize_say_it_in_one_line(tmp_path, fails):
    rig = _rig(tmp_path)
    seq = _sequence(tmp_path).parent
    doc = yaml.safe_load(rig.read_text())
    rig.write_text(yaml.safe_dump({**doc, "schema_version": 4, "imu": {"T_imu_laser": np.zeros(6).tolist()}}))
    line = fails(["check", rig, "--sequence", seq, "--no-log"], 3)
    assert line.startswith(f"Error: {rig}: schema_version: got 4; expected 1, 2 or 3 (the versions this")
    doc = yaml.safe_load((seq / "sequence.yaml").read_text())
    newer = {**doc, "schema_version": 5, "lidar": {"file": "l.npz"}}
    (seq / "sequence.yaml").write_text(yaml.safe_dump(newer))
    line = fails(["localize", seq, "--method", "icp", "-o", tmp_path / "out"], 3)
    assert "sequence.yaml: schema_version: got 5; expected 1, 2, 3 or 4 (the versions this rigcal" in line
