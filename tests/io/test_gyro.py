"""The gyroscope's stream: gyro.csv, its checks and the sequence's ``gyro`` mapping (schema 4)."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from rigcal.errors import InputError
from rigcal.io.gyro import checked, gyro_csv, read_gyro_csv
from rigcal.recordings.sequence import read_sequence, write_sequence
from rigcal.scan import Scan


def _scans(n=20, dt=0.1):
    return [Scan.from_uniform(-1.0, 0.5, np.full(5, 2.0), 0.1, 30.0, k * dt) for k in range(n)]


def test_yaw_between_integrates_each_sample_over_the_period_before_it():
    t = np.arange(0.0, 2.0001, 0.01)
    rate = np.where(t < 1.0 + 1e-6, 0.5, -0.2)  # each over the period ending at its stamp
    g = checked(t, rate, "gyro")
    got = g.yaw_between(np.array([0.0, 0.5, 1.0, 2.0]))
    np.testing.assert_allclose(got, [0.25, 0.25, -0.2], atol=1e-9)
    # Outside the samples' span: not measured.
    assert np.isnan(g.yaw_between(np.array([1.5, 2.5]))).all()


def test_a_gap_in_the_samples_measures_nothing_across_it():
    t = np.r_[np.arange(0.0, 1.0, 0.01), np.arange(3.0, 4.0, 0.01)]
    g = checked(t, np.full(len(t), 0.1), "gyro")
    got = g.yaw_between(np.array([0.0, 0.5, 3.5, 3.9]))
    assert np.isfinite(got[0])
    assert np.isnan(got[1])
    assert np.isfinite(got[2])


def test_gyro_csv_round_trips_to_the_bit(tmp_path):
    rng = np.random.default_rng(3)
    t = np.cumsum(rng.uniform(0.004, 0.006, 50))
    g = checked(t, rng.normal(0.0, 0.3, 50), "gyro")
    path = tmp_path / "gyro.csv"
    path.write_text(gyro_csv(g))
    back = read_gyro_csv(path, None)
    assert np.array_equal(back.stamps_s, g.stamps_s)
    assert np.array_equal(back.rates_rad_s, g.rates_rad_s)


@pytest.mark.parametrize(
    ("stamps", "rates", "scans", "match"),
    [
        ([0.0, 0.1, 0.1], [0, 0, 0], None, r"where: gyro stamp 2: got 0.1; expected a stamp after"),
        ([0.0, 0.1, 0.2], [0, np.nan, 0], None, r"where: gyro sample 1: got \[0.1, nan\]; expected a finite"),
        ([0.0, 0.1, 0.2], [0, 100.0, 0], None, r"gyro sample 1: .*within \+-40 rad/s"),
        ([0.0], [0], None, r"where: gyro: got '1 stamps, 1 rates'; expected at least 2"),
        ([100.0, 100.1, 100.2], [0, 0, 0], [0.0, 1.0], r"gyro stamps: got '100.0 to 100.2'; expected a span"),
        ([0.0, 100.0, 200.0], [0, 0, 0], None, r"gyro stamps: got 'a sample every 100 \(median\)'"),
    ],
)
def test_bad_samples_are_one_line_errors(stamps, rates, scans, match):
    with pytest.raises(InputError, match=match) as e:
        checked(np.array(stamps), np.array(rates), "where", None if scans is None else np.array(scans))
    assert "\n" not in str(e.value)


def test_a_bad_gyro_csv_names_the_file_and_line(tmp_path):
    path = tmp_path / "gyro.csv"
    path.write_text("stamp,rate\n0,0\n")
    with pytest.raises(InputError, match=r"gyro.csv: line 1: got 'stamp,rate'; expected the header"):
        read_gyro_csv(path, None)
    path.write_text("stamp_s,yaw_rate_rad_s\n0.0,0.1\n0.01,abc\n")
    with pytest.raises(
        InputError, match=r"gyro.csv: line 3: got '0.01,abc'; expected stamp_s,yaw_rate_rad_s"
    ):
        read_gyro_csv(path, None)


def test_a_sequence_keeps_its_gyro_at_schema_4(tmp_path):
    t = np.arange(0.0, 2.0, 0.005)
    g = checked(t, 0.1 * np.sin(t), "gyro")
    folder = write_sequence(tmp_path / "seq", "s", _scans(), [], None, {}, gyro=g)
    doc = yaml.safe_load((folder / "sequence.yaml").read_text())
    assert doc["schema_version"] == 4
    assert doc["gyro"] == {"file": "gyro.csv"}
    seq = read_sequence(folder)
    assert seq.has_gyro
    assert seq.gyro is not None
    assert np.array_equal(seq.gyro.rates_rad_s, g.rates_rad_s)
    # Without a gyro: schema 1 as before, nothing read.
    plain = write_sequence(tmp_path / "plain", "s", _scans(), [], None, {})
    assert yaml.safe_load((plain / "sequence.yaml").read_text())["schema_version"] == 1
    assert not read_sequence(plain).has_gyro
    assert read_sequence(plain).gyro is None


def test_a_gyro_key_before_schema_4_and_a_broken_gyro_file_are_refused(tmp_path):
    t = np.arange(0.0, 2.0, 0.005)
    folder = write_sequence(tmp_path / "seq", "s", _scans(), [], None, {}, gyro=checked(t, 0 * t, "g"))
    doc = yaml.safe_load((folder / "sequence.yaml").read_text())
    (folder / "sequence.yaml").write_text(yaml.safe_dump({**doc, "schema_version": 3}))
    with pytest.raises(InputError, match=r"sequence.yaml: schema_version: got 3; expected 4 for key 'gyro'"):
        read_sequence(folder)
    (folder / "sequence.yaml").write_text(yaml.safe_dump(doc))
    (folder / "gyro.csv").write_text("stamp_s,yaw_rate_rad_s\n0.0,0.1\n0.0,0.1\n")
    seq = read_sequence(folder)  # read when used
    with pytest.raises(InputError, match=r"gyro.csv: gyro stamp 1: .*\(--gyro ignore runs without it\)$"):
        _ = seq.gyro
