"""A marker session whose JPEGs carry EXIF orientation tags (a camera with an orientation
sensor tags a frame "rotate 180" or "rotate 90" for display) solves as the same JPEGs
untagged, to the last digit: the pixels are read as stored. Read turned, a "rotate 180"
session solved with exit 0 to T_cam_laser turned 180 degrees about the optical axis, and a
"rotate 90" one failed (exit 4) blaming the V in every scan."""

from __future__ import annotations

import shutil

import numpy as np
from PIL import Image

from rigcal.cli.main import main
from rigcal.rigfile import read_rig


def _as_jpegs(folder, orientations):
    for k, p in enumerate(sorted((folder / "images").glob("*.png"))):
        exif = Image.Exif()
        exif[0x0112] = orientations[k % len(orientations)]
        Image.open(p).convert("RGB").save(p.with_suffix(".jpg"), "JPEG", quality=95, exif=exif.tobytes())
        p.unlink()
    session = folder / "marker_session.yaml"
    session.write_text(session.read_text().replace(".png", ".jpg"))


def test_orientation_tags_do_not_change_the_solve(tmp_path, capsys):
    session = tmp_path / "ms"
    assert main(["-q", "simulate", "marker-session", "-o", str(session), "--captures", "6"]) == 0
    tagged = tmp_path / "tagged"
    shutil.copytree(session, tagged)
    _as_jpegs(session, [1])
    _as_jpegs(tagged, [3, 6, 8])
    capsys.readouterr()
    assert main(["-q", "solve", str(session / "marker_session.yaml"), "-o", str(tmp_path / "a.yaml")]) == 0
    assert main(["-q", "solve", str(tagged / "marker_session.yaml"), "-o", str(tmp_path / "b.yaml")]) == 0
    a, b = read_rig(tmp_path / "a.yaml"), read_rig(tmp_path / "b.yaml")
    np.testing.assert_array_equal(b.T_cam_laser, a.T_cam_laser)
