"""Simulated drives with camera images: stamps, clock offset, ground truth, rigs, seeds, errors."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import yaml

from rigcal.cli.main import main
from rigcal.errors import InputError
from rigcal.io.trajectory import read_tum
from rigcal.recordings.sequence import read_sequence
from rigcal.rig import Rig
from rigcal.rigfile import read_rig, write_rig
from rigcal.sim.box_session import default_camera
from rigcal.sim.drive import DriveSpec, side_T_cam_laser

ARGS = ["simulate", "world", "--world", "cubicle-loop", "--duration-s", "1.5", "--laser-rate-hz", "20"]


def _files(folder):
    return {
        p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()
    }


def test_images_at_the_camera_rate_with_the_clock_offset_and_truth_at_every_stamp(tmp_path):
    out = tmp_path / "seq"
    assert main([*ARGS, "-o", str(out), "--camera-rate-hz", "8", "--clock-offset-s", "0.25"]) == 0
    seq = read_sequence(out)
    stamps = seq.image_stamps_s
    assert len(stamps) in (11, 12)  # 1.5 s at 8 Hz from a random phase
    np.testing.assert_allclose(np.diff(stamps), 1 / 8, atol=1e-9)
    true_t = stamps - 0.25
    assert 0.0 <= true_t[0] < 1 / 8
    assert true_t[0] > 0  # not synchronised with the laser's first scan
    scan_t = np.array([s.stamp_s for s in seq.scans])
    truth = read_tum(out / "groundtruth.tum")
    np.testing.assert_allclose(truth.stamps_s, np.unique(np.concatenate([scan_t, true_t])), atol=1e-9)
    img = cv2.imread(str(out / "images" / seq.image_files[0]))
    assert img.shape == (480, 640, 3)
    assert img.std() > 10  # a rendered scene, not a blank frame
    source = yaml.safe_load((out / "sequence.yaml").read_text())["source"]
    assert source["camera_clock_offset_s"] == 0.25


def test_one_seed_writes_identical_files_and_another_seed_other_images(tmp_path):
    a, b, c = tmp_path / "a", tmp_path / "b", tmp_path / "c"
    for folder, seed in ((a, "3"), (b, "3"), (c, "4")):
        assert main([*ARGS, "--duration-s", "0.5", "--seed", seed, "-o", str(folder)]) == 0
    fa, fb, fc = _files(a), _files(b), _files(c)
    assert fa == fb
    assert any(k.startswith("images/") for k in fa)
    assert fa["images/000000.png"] != fc["images/000000.png"]


def test_a_side_looking_rig_from_a_rig_file(tmp_path):
    rig_path = write_rig(tmp_path / "side.yaml", Rig(side_T_cam_laser(), default_camera()))
    out = tmp_path / "seq"
    assert main([*ARGS, "--duration-s", "0.3", "--rig", str(rig_path), "-o", str(out)]) == 0
    written = read_rig(out / "rig.yaml")
    np.testing.assert_allclose(written.T_cam_laser, side_T_cam_laser(), atol=1e-9)
    assert len(read_sequence(out).image_files) >= 2


def test_no_images(tmp_path):
    out = tmp_path / "seq"
    assert main([*ARGS, "--no-images", "-o", str(out)]) == 0
    seq = read_sequence(out)
    assert len(seq.image_files) == 0
    assert len(read_tum(out / "groundtruth.tum")) == len(seq.scans)


def test_bad_inputs_name_the_option_or_key(tmp_path, capsys):
    bad_rig = tmp_path / "bad.yaml"
    write_rig(bad_rig, Rig(side_T_cam_laser(), default_camera()))
    doc = yaml.safe_load(bad_rig.read_text())
    doc["camera"]["lensmodel"] = "LENSMODEL_FISHBOWL"
    bad_rig.write_text(yaml.safe_dump(doc))
    assert main([*ARGS, "--rig", str(bad_rig), "-o", str(tmp_path / "x")]) == 3
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert "camera.lensmodel: got 'LENSMODEL_FISHBOWL'" in err[0]
    assert main([*ARGS, "--rig", str(tmp_path / "none.yaml"), "-o", str(tmp_path / "x")]) == 3
    assert main([*ARGS, "--camera-rate-hz", "0", "-o", str(tmp_path / "x")]) == 2
    assert "--camera-rate-hz" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()
    with pytest.raises(InputError, match=r"camera_rate_hz: got -1\.0; expected a rate above 0 Hz"):
        DriveSpec(camera_rate_hz=-1.0)
    with pytest.raises(InputError, match=r"image_noise_sigma: got nan"):
        DriveSpec(image_noise_sigma=float("nan"))


def test_a_short_range_laser_sees_no_wall_beyond_its_range(tmp_path, capsys):
    out = tmp_path / "seq"
    assert main([*ARGS, "--duration-s", "0.5", "--no-images", "--range-max-m", "3", "-o", str(out)]) == 0
    seq = read_sequence(out)
    r = np.concatenate([s.ranges_m[s.valid] for s in seq.scans])
    assert r.max() <= 3.0
    assert (r > 2.5).any()  # the cubicle loop's walls reach past 3 m
    assert all(s.range_max_m == 3.0 for s in seq.scans)
    assert yaml.safe_load((out / "sequence.yaml").read_text())["source"]["range_max_m"] == 3.0
    assert main([*ARGS, "--range-max-m", "0.1", "-o", str(tmp_path / "x")]) == 2
    assert "--range-max-m" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()
    with pytest.raises(InputError, match=r"range_max_m: got 0\.2; expected 0\.5 to 100 m"):
        DriveSpec(range_max_m=0.2)
