"""A marker session whose images came from a 12-bit camera as 16-bit PNGs: read by their
top byte they would be black, so the markers would be "not seen" in every capture. They
are read by the importers' rule (every 16-bit frame shifted right by the same bits, those
of the brightest level beyond 8: docs/formats/sequence.md#imagescsv), as the camera's grey."""

from __future__ import annotations

import shutil

import cv2
import numpy as np

from rigcal.cli.main import main
from rigcal.rigfile import read_rig


def test_twelve_bit_frames_read_as_their_grey_and_solve_as_the_8_bit_session(tmp_path, capsys):
    session = tmp_path / "ms"
    assert main(["-q", "simulate", "marker-session", "-o", str(session), "--captures", "6"]) == 0
    wide = tmp_path / "wide"
    shutil.copytree(session, wide)
    for p in sorted((wide / "images").glob("*.png"))[:2]:  # 12-bit levels: the grey * 16
        cv2.imwrite(str(p), cv2.imread(str(p), cv2.IMREAD_GRAYSCALE).astype(np.uint16) * 16)
    capsys.readouterr()
    assert main(["-q", "solve", str(session / "marker_session.yaml"), "-o", str(tmp_path / "a.yaml")]) == 0
    assert main(["-q", "solve", str(wide / "marker_session.yaml"), "-o", str(tmp_path / "b.yaml")]) == 0
    a, b = read_rig(tmp_path / "a.yaml"), read_rig(tmp_path / "b.yaml")
    np.testing.assert_allclose(b.T_cam_laser, a.T_cam_laser, atol=1e-9)
