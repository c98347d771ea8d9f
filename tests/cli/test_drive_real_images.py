"""Sequence folders whose images are what real cameras write: 16-bit PNGs (a 12-bit
camera's levels in 16-bit words), PNGs with alpha, frames stamped before the first scan or
after the last. `rigcal localize` and `rigcal check --sequence` read them by a documented
rule, or refuse them in one line naming the frame (docs/formats/sequence.md#imagescsv)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from rigcal.cli.main import main
from room_scans import room_drive


@pytest.fixture
def drive(tmp_path) -> Path:
    return room_drive(tmp_path)


def _frames(seq: Path) -> list[Path]:
    return sorted((seq / "images").glob("*.png"))


@pytest.mark.parametrize("ext", [".png", ".tif"])
def test_twelve_bit_levels_in_sixteen_bit_frames_read_as_the_importers_store_them(tmp_path, capsys, ext):
    """A 12-bit camera's levels in 16-bit frames (PNG, or another tool's TIFF) would read
    black by their top byte: every frame is shifted right by the same bits (those of the
    drive's brightest level beyond 8), the importers' rule, and one warning says so."""
    import json

    from rigcal.localize.streams import open_streams

    plain = room_drive(tmp_path / "plain")
    drive = room_drive(tmp_path / "wide")
    rows = (drive / "images.csv").read_text().replace(".png", ext)
    for p in _frames(drive):  # a 12-bit camera's levels: its grey * 16, up to 4080
        cv2.imwrite(str(p.with_suffix(ext)), cv2.imread(str(p), cv2.IMREAD_GRAYSCALE).astype(np.uint16) * 16)
        if ext != ".png":
            p.unlink()
    (drive / "images.csv").write_text(rows)
    a, b = open_streams(plain), open_streams(drive)
    for i in range(a.n_images):
        np.testing.assert_array_equal(b.image(i), a.image(i))
    top = int(b.image_depth()["max_level"])
    assert b.image_depth() == {"frames": 20, "max_level": top, "shift_bits": top.bit_length() - 8}
    assert main(["localize", str(drive), "--method", "vo", "-o", str(tmp_path / "out")]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1] == (
        f"warning: 20 16-bit images read as 8 bits (levels up to {top}: shifted right by 4 bits, "
        "every frame the same)"
    )
    code = main(
        ["-q", "check", str(drive.parent / "rig.yaml"), "--sequence", str(drive), "--no-log", "--json"]
    )
    assert code == 6  # four seconds of a room: too short to tell
    record = json.loads(capsys.readouterr().out)
    assert record["targetless"]["images_16_bit"]["shift_bits"] == 4


def test_full_range_sixteen_bit_and_alpha_frames_read_as_their_grey(tmp_path):
    """A 16-bit frame filling its range reads as its top byte, a PNG's alpha is ignored:
    every method sees the 8-bit drive's grey levels, and the image methods run."""
    from rigcal.localize.streams import open_streams

    plain = room_drive(tmp_path / "plain")
    odd = room_drive(tmp_path / "odd")
    for k, p in enumerate(_frames(odd)):
        g = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
        if k % 2:
            cv2.imwrite(str(p), g.astype(np.uint16) * 257 + 3)  # the top byte is the grey
        else:
            cv2.imwrite(str(p), np.dstack([g, g, g, np.full_like(g, 128)]))  # RGBA, half transparent
    a, b = open_streams(plain), open_streams(odd)
    assert b.n_images == a.n_images == 20
    for i in range(a.n_images):
        np.testing.assert_array_equal(b.image(i), a.image(i))
    assert main(["-q", "localize", str(odd), "--method", "vo,iasm", "-o", str(tmp_path / "out")]) == 0


def _restamp(seq: Path, before: int, after: int) -> None:
    """Move the first ``before`` images 3 s earlier and the last ``after`` 3 s later."""
    rows = (seq / "images.csv").read_text().splitlines()
    n = len(rows) - 1
    out = [rows[0]]
    for k, row in enumerate(rows[1:]):
        t, name = row.split(",")
        shift = -3.0 if k < before else 3.0 if k >= n - after else 0.0
        out.append(f"{float(t) + shift!r},{name}")
    (seq / "images.csv").write_text("\n".join(out) + "\n")


def test_images_outside_the_scans_are_left_out_by_localize_and_named_after_the_run(drive, capsys):
    """Their laser pose is not measured: the image methods leave them out, and so do
    their trajectories; one warning line, the last, counts them."""
    _restamp(drive, 2, 3)
    out = drive.parent / "out"
    assert main(["localize", str(drive), "--method", "icp,vo", "-o", str(out)]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1] == (
        "warning: 2 image(s) before the first scan and 3 after the last (by more than a scan period) "
        "left out of the image methods and their trajectories: no scan measures the laser's motion there"
    )
    assert sum("image(s) before the first scan" in line for line in err) == 1
    with np.load(drive / "scans.npz") as z:
        t_scan = z["stamps_s"]
    vo = np.loadtxt(out / "vo" / "trajectory.tum", ndmin=2)[:, 0]
    assert len(vo) == 20 - 5
    assert vo.min() >= t_scan[0] - 0.5
    assert vo.max() <= t_scan[-1] + 0.5
    assert main(["localize", str(drive), "--method", "icp", "-o", str(drive.parent / "icp")]) == 0
    assert "before the first scan" not in capsys.readouterr().err  # no image method: nothing to say


def test_localize_refuses_a_drive_with_too_few_images_within_the_scans(drive, fails):
    _restamp(drive, 9, 10)  # one frame left within the scans
    line = fails(["localize", drive, "--method", "vo", "-o", drive.parent / "out"], 3)
    want = f"Error: {drive / 'sequence.yaml'}: images.count: got 1; expected at least 2 images"
    assert line.startswith(want)


def test_the_targetless_check_leaves_out_frames_outside_the_scans(drive, monkeypatch):
    """Their laser pose would be held at the drive's ends, projecting the returns at the
    wrong place (a false alarm); the frames the check decodes are those within the scans."""
    from rigcal.drift import targetless
    from rigcal.localize.streams import open_streams

    _restamp(drive, 2, 3)
    streams = open_streams(drive)
    asked: list[list[int]] = []

    class AskedError(Exception):
        pass

    def images_ahead(indices, ahead, workers=1):
        asked.append(list(indices))
        raise AskedError

    monkeypatch.setattr(streams, "images_ahead", images_ahead)
    with pytest.raises(AskedError):
        targetless._build_patches(streams.require_rig("check"), streams, targetless.TargetlessSettings())
    t = streams.image_stamps_s
    assert asked[0]
    assert all(0.0 <= t[i] <= streams.scan_stamps_s[-1] for i in asked[0])
    assert 0 not in asked[0]
    assert 1 not in asked[0]
    assert len(t) - 1 not in asked[0]


def test_the_check_records_the_images_outside_the_scans(drive, capsys):
    import json

    _restamp(drive, 2, 3)
    rig = drive.parent / "rig.yaml"
    code = main(["-q", "check", str(rig), "--sequence", str(drive), "--no-log", "--json"])
    assert code == 6  # four seconds of a room: too short to tell, and said so
    record = json.loads(capsys.readouterr().out)
    assert record["targetless"]["images_outside_scans"] == {"before": 2, "after": 3}
