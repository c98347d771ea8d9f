"""A drive (sequence folder) broken the ways real recordings and hand edits break it, through
`rigcal check --sequence` and `rigcal localize`: one line naming the file, the key and the
value (exit 3), never a traceback, a false "ok" or a file written into the drive."""

from __future__ import annotations

import shutil
import threading
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from rigcal.cli.main import main
from rigcal.errors import InputError
from rigcal.localize.streams import open_streams
from rigcal.recordings.sequence import read_sequence
from room_scans import room_drive

W, H = 64, 48


@pytest.fixture(scope="module")
def drive(tmp_path_factory) -> Path:
    """Four seconds: scans at 10 Hz, 64x48 textured images at 5 Hz, the rig inside."""
    return room_drive(tmp_path_factory.mktemp("drive"))


@pytest.fixture
def copy(drive, tmp_path):
    """A fresh copy of the drive and the rig beside it (outside the drive)."""
    shutil.copytree(drive, tmp_path / "seq")
    shutil.copy(drive / "rig.yaml", tmp_path / "rig.yaml")
    return tmp_path / "seq"


def edit_yaml(seq: Path, **changes) -> None:
    doc = yaml.safe_load((seq / "sequence.yaml").read_text())
    doc.update(changes)
    (seq / "sequence.yaml").write_text(yaml.safe_dump(doc))


def test_the_drive_reads(copy):
    s = open_streams(copy)
    assert s.n_images == 20
    assert s.image(3).shape == (H, W)


def test_an_image_of_another_size_mid_drive_is_one_line_naming_it(copy, fails):
    img = np.zeros((H // 2, W // 2), np.uint8)
    cv2.imwrite(str(copy / "images" / "000007.png"), img)
    with pytest.raises(
        InputError, match=rf"000007.png: image size: got '32x24'; expected {W}x{H}, the rig's"
    ):
        open_streams(copy).image(7)
    line = fails(["localize", copy, "--method", "vo", "-o", copy.parent / "out"], 3)
    assert "000007.png: image size: got '32x24'" in line
    # The laser odometry ran beside the tracking on a second thread: the failed command
    # waited for it, so nothing of it goes on writing into what runs next (the next
    # test's captured stderr).
    assert _worker_threads() == []


def _worker_threads() -> list[str]:
    """rigcal's worker threads still alive (laser odometry, images decoded ahead, ...)."""
    names = ("laser-odometry", "ahead", "vo-run", "stages", "sample", "stack", "rigcal-read")
    return [t.name for t in threading.enumerate() if t.name.startswith(names)]


def test_images_on_another_clock_than_the_scans_are_refused(copy, fails):
    rows = (copy / "images.csv").read_text().splitlines()
    shifted = [rows[0]] + [f"{float(r.split(',')[0]) + 1000.0!r},{r.split(',')[1]}" for r in rows[1:]]
    (copy / "images.csv").write_text("\n".join(shifted) + "\n")
    line = fails(["check", copy.parent / "rig.yaml", "--sequence", copy, "--no-log"], 3)
    assert "images.csv: stamp_s: got '1000.010 to 1003.810 s'; expected images within the scans' span" in line
    line = fails(["localize", copy, "--method", "hiasm", "-o", copy.parent / "out"], 3)
    assert "images.csv: stamp_s: got '1000.010 to 1003.810 s'" in line


@pytest.mark.parametrize("value", [np.nan, 0.0, np.inf])
def test_scans_without_a_single_return_are_refused_not_localized(copy, fails, value):
    with np.load(copy / "scans.npz") as z:
        arrays = dict(z)
    arrays["ranges_m"][:] = value
    np.savez_compressed(copy / "scans.npz", **arrays)
    line = fails(["localize", copy, "--method", "icp", "-o", copy.parent / "out"], 3)
    assert "scans: got 'no return in all 40 scans'" in line
    fails(["check", copy.parent / "rig.yaml", "--sequence", copy, "--no-log"], 3)


def test_scans_whose_every_return_is_the_maximum_range_are_refused(copy, fails):
    with np.load(copy / "scans.npz") as z:
        arrays = dict(z)
    arrays["ranges_m"][:] = arrays["range_max_m"][:, None]  # a Hokuyo's 'no return'
    np.savez_compressed(copy / "scans.npz", **arrays)
    line = fails(["localize", copy, "--method", "icp", "-o", copy.parent / "out"], 3)
    assert "scans: got 'every return at range_max_m in all 40 scans'" in line
    assert "--no-return-m" in line


def test_a_spreadsheets_bom_and_blank_lines_in_the_image_index_are_no_data(copy):
    text = (copy / "images.csv").read_text()
    (copy / "images.csv").write_bytes(b"\xef\xbb\xbf" + (text + "\n\n").replace("\n", "\r\n").encode())
    assert len(read_sequence(copy).image_files) == 20


def test_a_wrong_image_index_header_says_what_it_got(copy):
    (copy / "images.csv").write_text("time,name\n0.01,000000.png\n")
    with pytest.raises(
        InputError, match=r"images.csv: line 1: got 'time,name'; expected the header 'stamp_s,file'"
    ):
        read_sequence(copy)


@pytest.mark.parametrize(
    ("key", "value", "match"),
    [
        ("name", [1, 2], r"sequence.yaml: name: got \[1, 2\]; expected a string"),
        ("source", [1, 2], r"sequence.yaml: source: got \[1, 2\]; expected a mapping"),
        ("schema_version", 99, r"schema_version: got 99; expected 1, 2, 3 or 4"),
        ("scans", "scans.npz", r"scans: got 'scans.npz'; expected a mapping"),
    ],
)
def test_sequence_yaml_values_of_the_wrong_type(copy, fails, key, value, match):
    edit_yaml(copy, **{key: value})
    with pytest.raises(InputError, match=match):
        read_sequence(copy)
    fails(["localize", copy, "--method", "icp", "-o", copy.parent / "out"], 3)


def test_the_image_folder_named_in_sequence_yaml_is_the_one_read(copy):
    (copy / "images").rename(copy / "frames")
    doc = yaml.safe_load((copy / "sequence.yaml").read_text())
    doc["images"]["folder"] = "frames"
    (copy / "sequence.yaml").write_text(yaml.safe_dump(doc))
    assert open_streams(copy).image(2).shape == (H, W)


@pytest.mark.parametrize("name", ["sequence.yaml", "scans.npz"])
def test_a_file_given_for_the_drive_names_its_folder(copy, fails, name):
    line = fails(["localize", copy / name, "--method", "icp", "-o", copy.parent / "out"], 3)
    assert (
        line
        == f"Error: {copy / name}: got a file; expected a sequence folder ({copy}?), holding sequence.yaml"
    )


def test_a_check_without_log_takes_the_rig_inside_the_drive(copy, capsys):

    before = sorted(copy.rglob("*"))
    assert main(["check", str(copy / "rig.yaml"), "--sequence", str(copy), "--no-log"]) in (0, 1, 6)
    assert "Error" not in capsys.readouterr().err
    assert sorted(copy.rglob("*")) == before
    # With the log (beside the rig, inside the drive): refused, nothing written.
    assert main(["check", str(copy / "rig.yaml"), "--sequence", str(copy)]) == 5
    assert "rig.checks.jsonl: is inside the input" in capsys.readouterr().err
    assert sorted(copy.rglob("*")) == before


def test_a_drive_under_a_path_with_spaces_and_accents(drive, tmp_path, capsys):

    seq = tmp_path / "nuit d'été" / "drive 1"
    shutil.copytree(drive, seq)
    assert main(["-q", "localize", str(seq), "--method", "icp", "-o", str(tmp_path / "sortie é")]) == 0
    assert (tmp_path / "sortie é" / "icp" / "trajectory.tum").is_file()


def test_a_trajectory_error_names_the_pose_by_its_stamp(copy, fails):
    tum = copy.parent / "tilted.tum"
    # A camera's trajectory (z forward) given for the laser's: tilted 90 deg.
    tum.write_text("".join(f"{0.1 * k!r} {0.05 * k} 0 0 0.7071068 0 0 0.7071068\n" for k in range(40)))
    line = fails(["check", copy.parent / "rig.yaml", "--sequence", copy, "--trajectory", tum, "--no-log"], 3)
    assert "tilted.tum: pose at 0.0 s: got 'z axis tilted 90.0 deg'" in line


def test_the_check_names_an_image_of_another_size_mid_drive_in_one_line(copy, fails):
    """Each frame's own work runs two frames at a time: the frame that does not decode is
    named in the one error line, whichever thread decoded it."""
    cv2.imwrite(str(copy / "images" / "000007.png"), np.zeros((H // 2, W // 2), np.uint8))
    line = fails(["check", copy.parent / "rig.yaml", "--sequence", copy, "--no-log"], 3)
    assert "000007.png: image size: got '32x24'" in line
