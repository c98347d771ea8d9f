"""A ROS 2 bag given by any of its paths imports alike: its folder, its metadata.yaml, one
of its storage files (sqlite3 .db3 or MCAP), or a folder of storage files copied without
their metadata.yaml (the parts of a split bag, read as one); a folder with none of these is
one line naming it (was rosbags' "Expected metadata file ... does not exist")."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag2 import StoragePlugin, Writer
from test_bag import TS2, _msgs

from rigcal.cli.main import main
from rigcal.recordings.sequence import read_sequence


def _bag(path: Path, storage: StoragePlugin, first: int, n: int) -> Path:
    scan, image, _, _ = _msgs(TS2)
    with Writer(path, version=8, storage_plugin=storage) as w:
        cs = w.add_connection("/scan", "sensor_msgs/msg/LaserScan", typestore=TS2)
        ci = w.add_connection("/cam/image", "sensor_msgs/msg/Image", typestore=TS2)
        for k in range(first, first + n):
            t = 1.0 + 0.025 * k
            w.write(cs, int(1e9 * t), TS2.serialize_cdr(scan(t, k), "sensor_msgs/msg/LaserScan"))
            if k % 2:
                w.write(ci, int(1e9 * t) + 1, TS2.serialize_cdr(image(t, k), "sensor_msgs/msg/Image"))
    return path


def _imported(args: list[str], out: Path) -> tuple[list[float], list[float]]:
    assert main(["-q", "import-bag", *args, "-o", str(out)]) == 0
    seq = read_sequence(out)
    return [s.stamp_s for s in seq.scans], seq.image_stamps_s.tolist()


@pytest.mark.parametrize("storage", [StoragePlugin.SQLITE3, StoragePlugin.MCAP])
def test_a_ros2_bag_by_any_of_its_paths(tmp_path, storage):
    bag = _bag(tmp_path / "run", storage, 0, 6)
    (data,) = [f for f in bag.iterdir() if f.suffix in (".db3", ".mcap")]
    want = _imported([str(bag)], tmp_path / "a")
    assert len(want[0]) == 6
    assert _imported([str(bag / "metadata.yaml")], tmp_path / "b") == want
    assert _imported([str(data)], tmp_path / "c") == want
    bare = tmp_path / "copied"
    bare.mkdir()
    shutil.copy(data, bare / data.name)
    assert _imported([str(bare)], tmp_path / "d") == want
    assert read_sequence(tmp_path / "b").name == "run"


def test_split_parts_copied_without_metadata_read_as_one_bag(tmp_path):
    parts = [_bag(tmp_path / f"part{k}", StoragePlugin.SQLITE3, 3 * k, 3) for k in range(2)]
    bare = tmp_path / "copied"
    bare.mkdir()
    files = []
    for k, p in enumerate(parts):
        (data,) = p.glob("*.db3")
        files.append(shutil.copy(data, bare / f"run_{k}.db3"))
    whole = _imported([str(bare)], tmp_path / "a")
    np.testing.assert_allclose(whole[0], 1.0 + 0.025 * np.arange(6))
    assert _imported([str(f) for f in files], tmp_path / "b") == whole


def test_a_folder_that_holds_no_bag(tmp_path, capsys):
    (tmp_path / "notes").mkdir()
    (tmp_path / "notes" / "readme.txt").write_text("x")
    assert main(["-q", "import-bag", str(tmp_path / "notes"), "-o", str(tmp_path / "out")]) == 3
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        f"Error: {tmp_path / 'notes'}: got a folder without metadata.yaml or a .db3 or .mcap file; expected "
        "a ROS 2 bag's folder (its metadata.yaml and storage files) or a ROS 1 .bag file"
    ]
    assert not (tmp_path / "out").exists()
