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
    caps = [{"image": f"i{k}.png", "scan": f"s{k}.yaml", "laser_side": "auto"} for k in range(3)]
    caps[1]["image"] = str(tmp_path / "i0.png")  # absolute: the same file
    path = _plane_session(tmp_path, "board", caps)
    with pytest.raises(InputError, match=r"captures\[1\].image: got .*\(captures\[0\].image names it too"):
        read_board_session(path)


# Each capture's own entry is checked before the files named once across the captures:
# a capture's error wins over the duplicate it also makes, whichever capture comes first.
MARKER_CAPTURE_ERRORS = [
    (
        lambda c: c.update(scan="s1x.yaml"),
        r"captures\[1\]: got \['image', 'scan', 'scans'\]; expected one of scan",
    ),
    (lambda c: c.pop("scans"), r"captures\[1\]: got \['image'\]; expected one of scan"),
    (lambda c: c.update(scans=[]), r"captures\[1\]\.scans: got \[\]; expected a non-empty list"),
    (
        lambda c: c.update(scans="s1a.yaml"),
        r"captures\[1\]\.scans: got 's1a.yaml'; expected a non-empty list",
    ),
    (lambda c: c["scans"].append(3), r"captures\[1\]\.scans\[2\]: got 3; expected a file path"),
    (lambda c: c.update(image=""), r"captures\[1\]\.image: got ''; expected a file path"),
    (lambda c: c.update(colour=1), r"captures\[1\]\.colour: got 1; expected no such key"),
    (lambda c: c.update(name="a/b"), r"captures\[1\]\.name: got 'a/b'"),
]


@pytest.mark.parametrize("at", [0, 2])
@pytest.mark.parametrize(("edit", "match"), MARKER_CAPTURE_ERRORS)
def test_a_marker_capture_error_before_a_file_named_twice(tmp_path, edit, match, at):
    # Capture 1 is broken; capture `at`, before or after it, names capture 1's first scan.
    caps = [{"image": f"i{k}.png", "scans": [f"s{k}a.yaml", f"s{k}b.yaml"]} for k in range(3)]
    caps[at]["scans"][0] = "s1a.yaml"
    edit(caps[1])
    path = _plane_session(tmp_path, "marker", caps)
    with pytest.raises(InputError, match=match):
        read_marker_session(path)


@pytest.mark.parametrize("at", [0, 2])
@pytest.mark.parametrize(
    ("edit", "match"),
    [
        (lambda c: c.pop("laser_side"), r"captures\[1\]\.laser_side: missing"),
        (lambda c: c.update(corners_px=[]), r"captures\[1\]: got .*; expected exactly one of corners_px"),
        (lambda c: c.update(scans=["s1.yaml"]), r"captures\[1\]: got .*; expected one of scan"),
        (lambda c: c.update(scan=None), r"captures\[1\]\.scan: got None; expected a file path"),
    ],
)
def test_a_board_capture_error_before_a_file_named_twice(tmp_path, edit, match, at):
    caps = [{"image": f"i{k}.png", "scan": f"s{k}.yaml", "laser_side": "auto"} for k in range(3)]
    caps[at]["image"] = "i1.png"
    edit(caps[1])
    path = _plane_session(tmp_path, "board", caps)
    doc = yaml.safe_load(path.read_text())
    doc["schema_version"] = 4
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    with pytest.raises(InputError, match=match):
        read_board_session(path)


@pytest.mark.parametrize("at", [0, 5])
@pytest.mark.parametrize(
    ("key", "value", "match"),
    [
        ("image_endpoints_px", [[1, 1], [1, 1]], r"\.image_endpoints_px: .*expected two distinct box ends"),
        ("laser_side", {"line": 3}, r"\.laser_side: got \{'line': 3\}; expected \{segment: ID\}"),
        ("name", "a/b", r"\.name: got 'a/b'"),
        ("scans", ["scans/cap03.yaml"], r"\.scans: got .*; expected no such key"),
    ],
)
def test_a_box_capture_error_before_a_file_named_twice(box, key, value, match, at):
    # Capture 3 is broken; capture `at`, before or after it, names capture 3's image.
    def change(doc):
        doc["captures"][at]["image"] = doc["captures"][3]["image"]
        doc["captures"][3][key] = value

    _edit(box, change)
    with pytest.raises(InputError, match=r"captures\[3\]" + match):
        read_picks(box)


def _csv_names(index: Path) -> list[str]:
    return _read_index(index)[1]


def _list_names(listing: Path) -> list[str]:
    return [p.name for p in read_image_list(listing)[1]]


@pytest.mark.parametrize(
    ("name", "head", "row", "read", "shown", "lines"),
    [  # a sequence's images.csv; import-laser's image list (its files must exist)
        ("images.csv", "stamp_s,file\n", "{t},{f}\n", _csv_names, "./a.png", (4, 2)),
        ("images.txt", "", "{t} {f}\n", _list_names, "a.png", (3, 1)),
    ],
)
def test_an_image_list_naming_a_frame_twice(tmp_path, name, head, row, read, shown, lines):
    for f in ("a.png", "b.png"):
        (tmp_path / f).write_bytes(b"not decoded here")
    path = tmp_path / name
    path.write_text(
        head + "".join(row.format(t=t, f=f) for t, f in [(0.1, "a.png"), (0.2, "b.png"), (0.3, "./a.png")])
    )
    with pytest.raises(InputError) as err:
        read(path)
    assert str(err.value) == (
        f"{path}: line {lines[0]}: file: got {shown!r}; "
        f"expected an image no other line names (line {lines[1]} does)"
    )
    path.write_text(head + "".join(row.format(t=t, f=f) for t, f in [(0.1, "a.png"), (0.2, "b.png")]))
    assert read(path) == ["a.png", "b.png"]
