"""Sequence folders: the laser.clockwise key (schema 2)."""

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
