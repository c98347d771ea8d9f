"""A marker session whose images came from a 12-bit camera as 16-bit PNGs: read by their
top byte they are black, so the markers would be "not seen" in every capture. The solve
names the frame and what to do instead (exit 3)."""

from __future__ import annotations

import cv2
import numpy as np

from rigcal.cli.main import main


def test_twelve_bit_frames_are_named_not_reported_as_unseen_markers(tmp_path, capsys):
    session = tmp_path / "ms"
    assert main(["-q", "simulate", "marker-session", "-o", str(session), "--captures", "4",
                 "--scans-per-capture", "1"]) == 0  # fmt: skip
    first = sorted((session / "images").glob("*.png"))[0]
    cv2.imwrite(str(first), cv2.imread(str(first), cv2.IMREAD_GRAYSCALE).astype(np.uint16) * 16)
    capsys.readouterr()
    assert main(["solve", str(session / "marker_session.yaml"), "-o", str(tmp_path / "rig.yaml")]) == 3
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith(f"Error: {first}: levels: got '16-bit, up to ")
    assert not (tmp_path / "rig.yaml").exists()
