"""A file of another kind given where rigcal expects one: the error names both kinds."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from rigcal.calib.box.picks import read_picks
from rigcal.camera import read_camera
from rigcal.cli.main import main
from rigcal.errors import InputError
from rigcal.io.kinds import kind_of_bytes, kind_of_mapping
from rigcal.rigfile import read_rig
from rigcal.scan import read_scan

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "box-session"


@pytest.fixture
def session(tmp_path) -> Path:
    folder = tmp_path / "session"
    shutil.copytree(EXAMPLE, folder)
    return folder


def test_npz_given_as_a_scan(tmp_path, capsys):
    npz = tmp_path / "scans.npz"
    np.savez_compressed(npz, stamps_s=np.zeros(3))
    with pytest.raises(InputError, match=re.escape(f"{npz}: got a zip archive such as NumPy's .npz")):
        read_scan(npz)
    assert main(["lines", str(npz)]) == 3
    err = capsys.readouterr().err
    assert "expected a scan file (docs/formats/scan.md), which is text" in err
    assert "codec" not in err


@pytest.mark.parametrize(
    ("head", "kind"),
    [(b"\x89PNG\r\n", "PNG image"), (b"#ROSBAG V2.0", "ROS 1 bag"), (b"SQLite format 3\x00", "ROS 2 bag")],
)
def test_binary_kinds(tmp_path, head, kind):
    assert kind in (kind_of_bytes(head) or "")
    f = tmp_path / "x.yaml"
    f.write_bytes(head + bytes(range(128, 256)))
    with pytest.raises(InputError, match=kind):
        read_rig(f)


def test_picking_file_given_as_a_rig(session):
    picks = session / "picks.yaml"
    with pytest.raises(
        InputError,
        match=re.escape(f"{picks}: got a picking file (docs/formats/session.md); expected a rig file"),
    ):
        read_rig(picks)


def test_scan_given_as_a_picking_file_and_camera(session):
    scan = session / "scans" / "cap00.yaml"
    with pytest.raises(InputError, match=r"got a scan file .*; expected a picking file"):
        read_picks(scan)
    with pytest.raises(InputError, match=r"got a scan file .*; expected a camera file"):
        read_camera(scan)


def test_folder_given_as_a_file(tmp_path):
    (tmp_path / "seq").mkdir()
    (tmp_path / "seq" / "sequence.yaml").write_text("x: 1\n")
    with pytest.raises(InputError, match=r"seq: got a folder \(a sequence folder\); expected a scan file"):
        read_scan(tmp_path / "seq")


def test_signatures():
    assert kind_of_mapping({"schema_version": 1, "captures": [], "camera": "c"}) == "picking file"
    assert kind_of_mapping({"method": "board", "captures": [], "camera": "c"}) == "board session file"
    assert kind_of_mapping({"T_cam_laser": {}, "camera": {}}) == "rig file"
    assert kind_of_mapping({"T_cam_laser": {}}) == "truth file"
    assert kind_of_mapping({"scans": {}, "images": {}}) == "sequence file"
    assert kind_of_mapping({"anything": 1}) is None
    assert kind_of_mapping([1, 2]) is None


def test_a_broken_file_of_the_expected_kind_is_not_called_another(session, tmp_path):
    import yaml

    from rigcal.io.kinds import wrong_kind

    # A rig file without its camera looks like a truth file, but is a broken rig file.
    doc = {"schema_version": 1, "T_cam_laser": {}, "uncertainty": {}}
    assert wrong_kind(tmp_path / "r.yaml", doc, "rig file") is None
    assert "got a rig file" in wrong_kind(tmp_path / "r.yaml", {**doc, "camera": {}}, "picking file")
    picks = yaml.safe_load((session / "picks.yaml").read_text())
    assert wrong_kind(tmp_path / "p.yaml", picks, "picking file") is None
