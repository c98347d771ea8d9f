"""Text files saved on Windows: UTF-16 with its byte-order mark (an editor's "Unicode",
Windows PowerShell's ``>``) is read as the same text in UTF-8 would be, by every reader
(they all go through read_text or read_log_text); UTF-16 without its mark and bytes of
another 8-bit encoding (Windows-1252) are one line naming the file (and the line)."""

from __future__ import annotations

import gzip
import shutil
from pathlib import Path

import numpy as np
import pytest

from rigcal.camera import read_camera
from rigcal.cli.main import main
from rigcal.errors import InputError
from rigcal.io.files import load_yaml, read_log_text, read_text
from rigcal.recordings.sequence import ImageFrame, read_sequence, write_sequence
from rigcal.rig import Rig
from rigcal.rigfile import write_rig
from rigcal.scan import Scan

TEXT = "# a comment\r\nkey: [1, 2]\r\nname: caf\u00e9\r\n"


@pytest.mark.parametrize("codec", ["utf-16", "utf-16-be-bom", "utf-8-sig", "utf-8"])
def test_utf16_with_its_mark_and_utf8_read_alike(tmp_path, codec):
    p = tmp_path / "f.yaml"
    data = b"\xfe\xff" + TEXT.encode("utf-16-be") if codec == "utf-16-be-bom" else TEXT.encode(codec)
    p.write_bytes(data)
    assert read_text(p) == TEXT.replace("\r\n", "\n")
    assert load_yaml(p) == {"key": [1, 2], "name": "caf\u00e9"}
    assert read_log_text(p) == TEXT  # logs keep their line ends (their lines are split alike)
    p.write_bytes(gzip.compress(data))
    assert read_log_text(p) == TEXT


def test_utf16_without_its_mark_is_named(tmp_path):
    p = tmp_path / "f.yaml"
    for codec in ("utf-16-le", "utf-16-be"):
        p.write_bytes(TEXT.encode(codec))
        with pytest.raises(
            InputError, match=r"f.yaml: got UTF-16 text without its byte-order mark; expected UTF-8"
        ):
            read_text(p, "rig file")
        with pytest.raises(InputError, match=r"got UTF-16 text without its byte-order mark"):
            read_log_text(p)


def test_bytes_of_another_encoding_name_the_line(tmp_path):
    p = tmp_path / "f.yaml"
    p.write_bytes(TEXT.encode("cp1252"))
    with pytest.raises(
        InputError, match=r"f.yaml: line 3: got byte 0xE9, not UTF-8; expected UTF-8 text for this rig"
    ):
        read_text(p, "rig file")
    assert "caf\ufffd" in read_log_text(p)  # a log's comments: replaced, as before
    p.write_bytes(b"\xff\xfe" + "ab\n".encode("utf-16-le") + b"\x00\xd8")  # a lone surrogate
    with pytest.raises(InputError, match=r"line 2: got bytes that are not UTF-16 after its byte-order mark"):
        read_text(p)


def _sequence(folder: Path) -> None:
    scans = [Scan.from_uniform(-1.0, 0.04, np.full(50, 2.0 + 0.01 * k), 0.1, 30.0, 0.1 * k) for k in range(6)]
    images = [ImageFrame(0.05 + 0.1 * k, f"f{k}.png", b"") for k in range(3)]
    write_sequence(folder, "s", scans, images, None, {})


def test_an_image_list_and_sequence_file_in_utf16_read_as_in_utf8(tmp_path):
    _sequence(tmp_path / "a")
    shutil.copytree(tmp_path / "a", tmp_path / "b")
    for name in ("images.csv", "sequence.yaml"):
        p = tmp_path / "b" / name
        p.write_bytes(p.read_text(encoding="utf-8").replace("\n", "\r\n").encode("utf-16"))
    a, b = read_sequence(tmp_path / "a"), read_sequence(tmp_path / "b")
    assert b.image_files == a.image_files
    np.testing.assert_array_equal(b.image_stamps_s, a.image_stamps_s)


def test_a_rig_file_in_utf16_exports_as_in_utf8(tmp_path, capsys):
    camera = read_camera(Path(__file__).parents[2] / "examples" / "box-session" / "camera.yaml")
    rig = write_rig(tmp_path / "rig.yaml", Rig(np.eye(4), camera))
    wide = tmp_path / "rig16.yaml"
    wide.write_bytes(rig.read_text(encoding="utf-8").encode("utf-16"))
    capsys.readouterr()
    assert main(["export", str(rig), "--format", "ros"]) == 0
    want = capsys.readouterr().out
    assert main(["export", str(wide), "--format", "ros"]) == 0
    assert capsys.readouterr().out == want.replace(str(rig), str(wide))
    wide.write_bytes(rig.read_text(encoding="utf-8").encode("utf-16-le"))
    assert main(["export", str(wide), "--format", "ros"]) == 3
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert "rig16.yaml: got UTF-16 text without its byte-order mark" in err[0]
