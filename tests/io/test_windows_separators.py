"""Paths written on Windows (``images\\cap00.png``) in the files rigcal reads name the file
they would there: a backslash is a folder separator in an image list, a sequence file and
a session's captures (it was looked for as part of one file name, "image sub\\f0.png not
found"). A backslash never lets a path out of its folder."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
import yaml

from rigcal.calib.box.picks import read_picks
from rigcal.errors import InputError
from rigcal.io.validate import relative_inside
from rigcal.recordings.sequence import _read_index

EXAMPLE = Path(__file__).parents[2] / "examples" / "box-session"


@pytest.mark.parametrize(
    ("rel", "read"),
    [("sub\\f0.png", "sub/f0.png"), ("a\\b\\c.png", "a/b/c.png"), ("f0.png", "f0.png")],
)
def test_backslashes_are_separators(rel, read):
    assert relative_inside(rel, "images.csv", "file") == read


@pytest.mark.parametrize("rel", ["\\etc\\passwd", "..\\x.png", "sub\\..\\..\\x.png", "C:\\x.png"])
def test_a_backslash_never_leads_out(rel):
    with pytest.raises(InputError, match="a relative path inside the folder"):
        relative_inside(rel, "images.csv", "file")


def test_an_image_list_written_on_windows(tmp_path):
    index = tmp_path / "images.csv"
    index.write_text("stamp_s,file\r\n0.1,cam0\\f0.png\r\n0.2,cam0\\f1.png\r\n0.3,cam0/f0.png\r\n")
    with pytest.raises(
        InputError, match=r"line 4: file: got 'cam0/f0.png'; expected an image no other line names"
    ):
        _read_index(index)  # the same file, however separated
    index.write_text("stamp_s,file\r\n0.1,cam0\\f0.png\r\n0.2,cam0\\f1.png\r\n")
    assert _read_index(index)[1] == ["cam0/f0.png", "cam0/f1.png"]


def test_a_session_written_on_windows(tmp_path):
    shutil.copytree(EXAMPLE, tmp_path / "box")
    picks = tmp_path / "box" / "picks.yaml"
    want = read_picks(picks)
    doc = yaml.safe_load(picks.read_text())
    for c in doc["captures"]:
        c["scan"], c["image"] = c["scan"].replace("/", "\\"), c["image"].replace("/", "\\")
    picks.write_text(yaml.safe_dump(doc, sort_keys=False))
    got = read_picks(picks)
    assert [o.image_path for o in got.observations] == [o.image_path for o in want.observations]
    assert [o.scan_path for o in got.observations] == [o.scan_path for o in want.observations]
