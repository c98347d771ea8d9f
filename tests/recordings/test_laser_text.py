"""RADLOCC laser.txt, generic CSV laser logs and image lists, made here, into sequence
folders and on to rigcal capture."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from rigcal.cli.main import main
from rigcal.errors import InputError
from rigcal.recordings.laser_text import read_csv_laser, read_image_list, read_radlocc_laser
from rigcal.recordings.sequence import read_sequence

CAMERA = """schema_version: 1
image_width_px: 64
image_height_px: 48
K: [[50.0, 0.0, 31.5], [0.0, 50.0, 23.5], [0.0, 0.0, 1.0]]
"""


def radlocc_line(t: float, ranges) -> str:
    a0, step = -math.pi / 4, math.pi / 40
    a1 = a0 + step * (len(ranges) - 1)
    return " ".join(repr(float(x)) for x in (t, a0, step, a1, *ranges))


@pytest.fixture
def radlocc(tmp_path) -> Path:
    """A RADLOCC folder: laser.txt (11 beams, a NaN and an inf), images and their list.
    The rig holds still twice (scans and images unchanged), moving in between."""
    rng = np.random.default_rng(0)
    lines, listing = ["# RADLOCC laser log"], []
    t = 10.0
    k = 0
    for placement in range(2):
        base = 2.0 + placement * rng.uniform(0.3, 0.6, 21)
        img = rng.integers(0, 255, (48, 64, 3), dtype=np.uint8)
        for phase in ("still", "move"):
            for _ in range(8):
                r = base if phase == "still" else base + rng.uniform(0.2, 1.0, 21)
                r = r.copy()
                r[3], r[7] = np.nan, np.inf
                lines.append(radlocc_line(t, r))
                im = img if phase == "still" else np.roll(img, rng.integers(5, 30), axis=1)
                name = f"image_{k:04d}.png"
                cv2.imwrite(str(tmp_path / name), im)
                listing.append(f"{t + 0.02:.3f} {name}")
                t += 0.1
                k += 1
    (tmp_path / "laser.txt").write_text("\n".join(lines) + "\n")
    (tmp_path / "images.txt").write_text("# stamp file\n" + "\n".join(listing) + "\n")
    (tmp_path / "camera.yaml").write_text(CAMERA)
    return tmp_path


def test_radlocc_laser(radlocc):
    scans = read_radlocc_laser(radlocc / "laser.txt")
    assert len(scans) == 32
    s = scans[0]
    assert s.stamp_s == 10.0
    assert len(s.ranges_m) == 21
    np.testing.assert_allclose(s.angles_rad[[0, -1]], [-math.pi / 4, -math.pi / 4 + 20 * math.pi / 40])
    assert not s.valid[3]
    assert not s.valid[7]
    assert s.valid[0]


@pytest.mark.parametrize("pack", ["gzip", "bz2"])
def test_a_compressed_laser_log_reads_as_the_plain_one(radlocc, pack):
    import bz2
    import gzip

    plain = (radlocc / "laser.txt").read_bytes()
    packed = radlocc / f"laser.txt.{pack}"
    packed.write_bytes(gzip.compress(plain) if pack == "gzip" else bz2.compress(plain))
    got, want = read_radlocc_laser(packed), read_radlocc_laser(radlocc / "laser.txt")
    assert [s.stamp_s for s in got] == [s.stamp_s for s in want]
    np.testing.assert_array_equal(got[5].ranges_m, want[5].ranges_m)
    packed.write_bytes(packed.read_bytes()[:40])
    with pytest.raises(InputError, match=rf"laser.txt.{pack}: RADLOCC laser log: got a broken or cut-short"):
        read_radlocc_laser(packed)


def test_radlocc_to_sequence_to_session(radlocc, tmp_path, capsys):
    seq_dir, session = tmp_path / "seq", tmp_path / "session"
    assert main(["import-laser", str(radlocc / "laser.txt"), "--images", str(radlocc / "images.txt"),
                 "--camera", str(radlocc / "camera.yaml"), "-o", str(seq_dir)]) == 0  # fmt: skip
    assert "32 scans (radlocc), 32 images, camera.yaml" in capsys.readouterr().out
    seq = read_sequence(seq_dir)
    assert len(seq.scans) == 32
    assert seq.image_stamps_s[0] == pytest.approx(10.02)
    assert main(["capture", str(seq_dir), "-o", str(session)]) == 0
    out = capsys.readouterr().out
    assert "2 captures; largest stamp offset 20.0 ms" in out
    assert (session / "images" / "cap01.png").is_file()


def test_radlocc_collect_form_and_stamps_only_image_list(tmp_path):
    """laser.txt with range unit type 3 and the beam count, image_stamps.txt with stamps
    only and image_001.png, ... beside it, as radlocc_collect writes them."""
    a0, step = -0.5, 0.25
    rows = [f"{t} {a0} {step} 0.5 3 5 2.0 2.1 nan 2.3 inf" for t in (1.0, 1.1)]
    (tmp_path / "laser.txt").write_text("\n".join(rows) + "\n")
    scans = read_radlocc_laser(tmp_path / "laser.txt")
    assert [len(s.ranges_m) for s in scans] == [5, 5]
    assert scans[0].ranges_m[1] == 2.1
    assert not scans[0].valid[2]
    (tmp_path / "laser.txt").write_text(f"1.0 {a0} {step} 0.5 1 5 2000 2100 2200 2300 2400\n")
    with pytest.raises(InputError, match=r"line 1: range unit type 1\.0; expected 3 \(metres\)"):
        read_radlocc_laser(tmp_path / "laser.txt")
    for k in (1, 2):
        cv2.imwrite(str(tmp_path / f"image_{k:03d}.png"), np.zeros((4, 4), np.uint8))
    (tmp_path / "image_stamps.txt").write_text("1.02 1.02\n1.12 1.12\n")
    stamps, files = read_image_list(tmp_path / "image_stamps.txt")
    assert stamps.tolist() == [1.02, 1.12]
    assert files == [tmp_path / "image_001.png", tmp_path / "image_002.png"]
    (tmp_path / "image_stamps.txt").write_text("1.02 1.02\n1.12 1.12\n1.22 1.22\n")
    with pytest.raises(InputError, match=r"line 3: image_003\.png \(or \.jpg, \.\.\.\) not found"):
        read_image_list(tmp_path / "image_stamps.txt")


def test_csv_laser(tmp_path):
    rows = ["stamp_s,angle_deg,range_m,intensity"]
    for t in (1.0, 1.1):
        rows += [f"{t},{a},{2.0 + a / 100},0" for a in (-10, 0, 10)]
    rows.append("1.1,20,nan,0")
    (tmp_path / "l.csv").write_text("\n".join(rows) + "\n")
    scans = read_csv_laser(tmp_path / "l.csv")
    assert [len(s.ranges_m) for s in scans] == [3, 4]
    np.testing.assert_allclose(scans[1].angles_rad, np.radians([-10, 0, 10, 20]))
    assert not scans[1].valid[3]
    assert main(["import-laser", str(tmp_path / "l.csv"), "-o", str(tmp_path / "seq")]) == 0


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("1.0 -0.5 0.1 0.5 2 2 2", r"line 1: got 3 ranges; expected 11"),
        ("1.0 -0.5 x 0.5 2 2", r"line 1: got '1.0 -0.5 x 0.5 2 2'; expected numbers"),
        ("1.0 -0.5 0.0 0.5 2 2", r"increment 0.0; expected finite, increment > 0"),
        ("1.0 -50 1 -48 2 2 2", r"expected radians"),
        ("3.0 -0.1 0.1 0.1 2 2 2\n1.0 -0.1 0.1 0.1 2 2 2", r"line 2: got stamp 1.0; expected stamps that"),
        ("1.0 -0.1", r"line 1: got 2 fields"),
        ("# nothing\n", r"got an empty file"),
    ],
)
def test_radlocc_errors(tmp_path, text, match):
    (tmp_path / "laser.txt").write_text(text + "\n")
    with pytest.raises(InputError, match=match):
        read_radlocc_laser(tmp_path / "laser.txt")


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("stamp_s,range_m\n1,2\n", r"expected columns stamp_s, angle_rad, range_m"),
        ("stamp_s,angle_rad,range_m\n1,0.1,2\n1,0.0,2\n", r"line 3: angle 0.0 not after"),
        ("stamp_s,angle_rad,range_m\n1,a,2\n", r"line 2: got '1,a,2'"),
        ("stamp_s,angle_rad,range_m\n", r"header only"),
    ],
)
def test_csv_errors(tmp_path, text, match):
    (tmp_path / "l.csv").write_text(text)
    with pytest.raises(InputError, match=match):
        read_csv_laser(tmp_path / "l.csv")


def test_image_list(tmp_path):
    for name in ("a.png", "c.png"):
        cv2.imwrite(str(tmp_path / name), np.zeros((4, 4), np.uint8))
    (tmp_path / "l.txt").write_text("a.png 3.5\n")  # either order
    stamps, files = read_image_list(tmp_path / "l.txt")
    assert stamps.tolist() == [3.5]
    assert files == [tmp_path / "a.png"]
    for text, match in (("1.0 b.png\n", "image b.png not found"), ("1.0 a.png b.png\n", "expected a stamp"),
                        ("1.0 a.png\n0.5 c.png\n", "line 2: got stamp 0.5; expected a stamp")):  # fmt: skip
        (tmp_path / "l.txt").write_text(text)
        with pytest.raises(InputError, match=match):
            read_image_list(tmp_path / "l.txt")


def test_cli_refuses_an_existing_folder_and_bad_files(radlocc, tmp_path, capsys):
    (tmp_path / "seq").mkdir()
    assert main(["import-laser", str(radlocc / "laser.txt"), "-o", str(tmp_path / "seq")]) == 5
    (tmp_path / "bad.txt").write_text("1 2 3\n")
    assert main(["import-laser", str(tmp_path / "bad.txt"), "-o", str(tmp_path / "s2")]) == 3
    assert "line 1" in capsys.readouterr().err
    assert not (tmp_path / "s2").exists()


def test_radlocc_header_count_is_trusted_when_angle_max_is_one_step_off(tmp_path):
    """A Hokuyo log from radlocc_collect: N = 511 and 511 ranges, while angle_max says 512
    beams (written one step past the last). The header's N is the scanner's."""
    a0, step = -2.0943951, 0.00613592315
    a1 = a0 + 511 * step  # 512 beams by the angles
    ranges = " ".join(["1.5"] * 509 + ["5.0", "nan"])
    rows = [f"{t} {a0} {step} {a1} 3 511 {ranges}" for t in (1.0, 1.1)]
    (tmp_path / "laser.txt").write_text("\n".join(rows) + "\n")
    scans = read_radlocc_laser(tmp_path / "laser.txt", range_max_m=5.6)
    assert [len(s.ranges_m) for s in scans] == [511, 511]
    assert scans[0].angles_rad[-1] == pytest.approx(a0 + 510 * step)
    assert scans[0].valid[509]  # 5.0 is a return unless the scanner's no-return value is given
    scans = read_radlocc_laser(tmp_path / "laser.txt", range_max_m=5.6, no_return_m=5.0)
    assert not scans[0].valid[509]
    assert scans[0].valid[:509].all()
    # Without the header, one step either way is accepted too.
    (tmp_path / "plain.txt").write_text(f"1.0 {a0} {step} {a1} {ranges}\n")
    assert len(read_radlocc_laser(tmp_path / "plain.txt")[0].ranges_m) == 511


@pytest.mark.parametrize(
    ("text", "match"),
    [
        (
            "1.0 -0.5 0.25 0.5 3 5 2 2 2 2 2\n1.1 -0.5 0.25 0.5 2 2 2 2 2",
            r"line 2: got 5 values after the angles; expected stamp angle_min increment angle_max 3 N "
            r"r_1 \.\.\. r_N \(unit type 3: metres, N ranges\), as line 1 has",
        ),
        (
            "1.0 -0.5 0.25 0.5 2 2 2 2 2\n1.1 -0.5 0.25 0.5 3 5 2 2 2 2 2",
            r"line 2: .*without unit type and count, as the first line",
        ),
        (
            "1.0 -0.5 0.1 0.5 3 8 2 2 2 2 2 2 2 2",
            r"line 1: got the header's N = 8; expected 11 \(within one step\)",
        ),
    ],
)
def test_radlocc_form_and_count_errors_name_the_line(tmp_path, text, match):
    (tmp_path / "laser.txt").write_text(text + "\n")
    with pytest.raises(InputError, match=match):
        read_radlocc_laser(tmp_path / "laser.txt")


def test_import_laser_no_return_option(tmp_path, capsys):
    (tmp_path / "laser.txt").write_text("1.0 -0.5 0.25 0.5 3 5 2.0 5.0 2.0 2.0 2.0\n")
    out = tmp_path / "seq"
    assert main(["import-laser", str(tmp_path / "laser.txt"), "-o", str(out), "--no-return-m", "5.0"]) == 0
    (tmp_path / "l.csv").write_text("stamp_s,angle_rad,range_m\n1,0.1,2\n")
    code = main(["import-laser", str(tmp_path / "l.csv"), "-o", str(tmp_path / "s2"), "--no-return-m", "5.0"])
    assert code == 3
    assert "--no-return-m" in capsys.readouterr().err


def test_csv_scans_are_put_on_their_beam_grid(tmp_path):
    """Sequence folders store angle_min and increment: a row left out (no return) is a
    missing beam; angles off one grid are refused, naming the scan."""
    rows = ["stamp_s,angle_deg,range_m"] + [f"1.0,{a},2.0" for a in (-10, -5, 10)]
    (tmp_path / "l.csv").write_text("\n".join(rows) + "\n")
    (s,) = read_csv_laser(tmp_path / "l.csv")
    assert s.angle_increment_rad == pytest.approx(math.radians(5))
    np.testing.assert_allclose(s.angles_rad, np.radians([-10, -5, 0, 5, 10]))
    assert s.valid.tolist() == [True, True, False, False, True]
    assert main(["import-laser", str(tmp_path / "l.csv"), "-o", str(tmp_path / "seq")]) == 0
    assert read_sequence(tmp_path / "seq").scans[0].valid.tolist() == s.valid.tolist()
    (tmp_path / "l.csv").write_text("\n".join([*rows[:3], "1.0,2.5,2.0"]) + "\n")
    with pytest.raises(
        InputError, match=r"scan at stamp 1\.0: angles: got .gaps from .*; expected angles on one grid"
    ):
        read_csv_laser(tmp_path / "l.csv")
