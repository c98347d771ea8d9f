"""Sequence folders: the laser.clockwise key (schema 2); the images known before the scans."""

import re

import numpy as np
import pytest
import yaml

from rigcal.errors import InputError
from rigcal.recordings.sequence import read_sequence, write_sequence
from rigcal.scan import Scan


def _folder(tmp_path, scans, **extra):
    out = write_sequence(tmp_path / "seq", "test", scans, [], None, {})
    path = out / "sequence.yaml"
    d = yaml.safe_load(path.read_text()) | extra
    path.write_text(yaml.safe_dump(d, sort_keys=False))
    return out


def test_clockwise_sequence_reads_as_the_unmirrored_scans(tmp_path):
    rng = np.random.default_rng(0)
    ranges = [rng.uniform(0.5, 5.0, 9) for _ in range(3)]
    truth = [Scan.from_uniform(-1.0, 0.25, r, 0.1, 10.0, stamp_s=float(i)) for i, r in enumerate(ranges)]
    mirrored = [
        Scan.from_uniform(-1.0, 0.25, r[::-1], 0.1, 10.0, stamp_s=float(i)) for i, r in enumerate(ranges)
    ]
    seq = read_sequence(_folder(tmp_path, mirrored, schema_version=2, laser={"clockwise": True}))
    for got, want in zip(seq.scans, truth, strict=True):
        np.testing.assert_allclose(got.points, want.points, atol=1e-12)
        assert got.stamp_s == want.stamp_s


def test_laser_key_needs_schema_2(tmp_path):
    scans = [Scan.from_uniform(-1.0, 0.25, [1.0, 2.0], 0.1, 10.0, stamp_s=0.0)]
    folder = _folder(tmp_path, scans, laser={"clockwise": True})
    with pytest.raises(InputError, match=re.escape(f"{folder / 'sequence.yaml'}: laser: got")):
        read_sequence(folder)


def test_clockwise_must_be_a_boolean(tmp_path):
    scans = [Scan.from_uniform(-1.0, 0.25, [1.0, 2.0], 0.1, 10.0, stamp_s=0.0)]
    folder = _folder(tmp_path, scans, schema_version=2, laser={"clockwise": "cw"})
    with pytest.raises(InputError, match=re.escape("laser.clockwise: got 'cw'; expected true")):
        read_sequence(folder)


def _with_images(tmp_path):
    from rigcal.recordings.sequence import ImageFrame

    scans = [Scan.from_uniform(-1.0, 0.25, np.full(9, 2.0), 0.1, 10.0, stamp_s=0.1 * i) for i in range(5)]
    images = [ImageFrame(0.05 + 0.1 * k, f"{k:06d}.png", b"not read here") for k in range(3)]
    return write_sequence(tmp_path / "seq", "test", scans, images, None, {})


def test_the_images_are_told_before_the_scans_are_read(tmp_path):
    folder = _with_images(tmp_path)
    told = []
    (folder / "scans.npz").rename(folder / "moved.npz")
    with pytest.raises(InputError, match="scans file not found"):
        read_sequence(folder, on_images=lambda *a: told.append(a))
    (folder / "moved.npz").rename(folder / "scans.npz")
    assert len(told) == 1
    images, stamps, files = told[0]
    seq = read_sequence(folder)
    assert images == folder / "images"
    assert list(stamps) == list(seq.image_stamps_s)
    assert tuple(files) == seq.image_files


def test_a_broken_index_is_not_told_and_fails_as_without_the_callback(tmp_path):
    folder = _with_images(tmp_path)
    (folder / "images.csv").write_text("stamp,file\n")
    told = []
    with pytest.raises(InputError) as plain:
        read_sequence(folder)
    with pytest.raises(InputError) as early:
        read_sequence(folder, on_images=lambda *a: told.append(a))
    assert str(early.value) == str(plain.value)
    assert told == []
