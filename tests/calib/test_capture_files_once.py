"""A session naming one image or scan in two captures (a capture pasted twice, a file
pasted into the wrong capture), however the path is spelled, is bad input naming both
entries: solved, the capture would be weighed twice and the covariance shrunk with nothing
wrong to see. Box, board and marker sessions share the check; an image list (images.csv)
naming one frame on two lines is refused the same way."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
import yaml

from rigcal.calib.board.session import read_board_session
from rigcal.calib.box.picks import read_picks
from rigcal.calib.marker.session import read_marker_session
from rigcal.errors import InputError
from rigcal.recordings.laser_text import read_image_list
from rigcal.recordings.sequence import _read_index

EXAMPLE = Path(__file__).parents[2] / "examples" / "box-session"


@pytest.fixture
def box(tmp_path) -> Path:
    shutil.copytree(EXAMPLE, tmp_path / "box")
    return tmp_path / "box" / "picks.yaml"


def _edit(path: Path, change) -> None:
    doc = yaml.safe_load(path.read_text())
    change(doc)
    path.write_text(yaml.safe_dump(doc, sort_keys=False))


def test_the_example_reads(box):
    assert len(read_picks(box).observations) == 20


@pytest.mark.parametrize(
    ("key", "value", "first"),
    [
        ("image", "images/cap00.png", "captures[0].image"),
        ("image", "./images//cap00.png", "captures[0].image"),
        ("scan", "scans/../scans/cap00.yaml", "captures[0].scan"),
    ],
)
def test_a_box_capture_naming_another_captures_file(box, key, value, first):
    def change(doc):
        doc["captures"][3][key] = value

    _edit(box, change)
    with pytest.raises(InputError) as err:
        read_picks(box)
    assert str(err.value) == (
        f"{box}: captures[3].{key}: got {value!r}; expected a file no other entry names "
        f"({first} names it too: a capture listed twice?)"
    )


def test_a_box_capture_listed_twice_under_another_name(box):
    def change(doc):
        doc["captures"].append({**doc["captures"][5], "name": "again"})

    _edit(box, change)
    with pytest.raises(
        InputError, match=r"captures\[20\].image: got 'images/cap05.png'; expected a file no other"
    ):
        read_picks(box)


def _plane_session(folder: Path, method: str, captures: list[dict]) -> Path:
    shutil.copy(EXAMPLE / "camera.yaml", folder / "camera.yaml")
    doc = {"schema_version": 2, "method": method, "camera": "camera.yaml", "captures": captures}
    doc.update(
        {"targets": "targets.yaml"}
        if method == "marker"
        else {"board": {"corners": [7, 5], "square_m": 0.05}}
    )
    path = folder / f"{method}.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def test_a_marker_capture_naming_a_scan_twice(tmp_path):
    # Caught before any file is read: the files need not exist.
    caps = [{"image": f"i{k}.png", "scans": [f"s{k}a.yaml", f"s{k}b.yaml"]} for k in range(3)]
    caps[2]["scans"][1] = "s2a.yaml"
    path = _plane_session(tmp_path, "marker", caps)
    with pytest.raises(
        InputError, match=r"captures\[2\].scans\[1\]: got 's2a.yaml'; .*\(captures\[2\].scans\[0\]"
    ):
        read_marker_session(path)


def test_a_board_capture_naming_another_captures_image(tmp_path):
    caps = [{"image": f"i{k}.png", "scan": f"s{k}.yaml"} for k in range(3)]
    caps[1]["image"] = str(tmp_path / "i0.png")  # absolute: the same file
    path = _plane_session(tmp_path, "board", caps)
    with pytest.raises(InputError, match=r"captures\[1\].image: got .*\(captures\[0\].image names it too"):
        read_board_session(path)


def test_an_image_list_naming_a_frame_twice(tmp_path):
    index = tmp_path / "images.csv"
    index.write_text("stamp_s,file\n0.1,a.png\n0.2,b.png\n0.3,./a.png\n")
    with pytest.raises(InputError) as err:
        _read_index(index)
    assert str(err.value) == (
        f"{index}: line 4: file: got './a.png'; expected an image no other line names (line 2 does)"
    )
    index.write_text("stamp_s,file\n0.1,a.png\n0.2,b.png\n0.3,c.png\n")
    assert _read_index(index)[1] == ["a.png", "b.png", "c.png"]


def test_an_import_laser_image_list_naming_a_frame_twice(tmp_path):
    for name in ("a.png", "b.png"):
        (tmp_path / name).write_bytes(b"not decoded here")
    listing = tmp_path / "images.txt"
    listing.write_text("0.1 a.png\n0.2 b.png\n0.3 ./a.png\n")
    with pytest.raises(InputError) as err:
        read_image_list(listing)
    assert str(err.value) == (
        f"{listing}: line 3: file: got 'a.png'; expected an image no other line names (line 1 does)"
    )
    listing.write_text("0.1 a.png\n0.2 b.png\n")
    assert [p.name for p in read_image_list(listing)[1]] == ["a.png", "b.png"]
