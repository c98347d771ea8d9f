"""CSV files saved by a spreadsheet (RFC 4180: quoted fields, a file name holding a comma,
every field quoted, spaces after the commas) read as the plain file does: images.csv,
gyro.csv and CSV laser logs share one field reader (csv_fields). Before, a quoted image
name was looked for with its quotes ("image "f0.png" not found") and a quoted header was
refused."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rigcal.errors import InputError
from rigcal.io.files import csv_fields
from rigcal.io.gyro import read_gyro_csv
from rigcal.recordings.laser_text import detect_format, read_csv_laser
from rigcal.recordings.sequence import _read_index


@pytest.mark.parametrize(
    ("line", "fields"),
    [
        ("0.1,f0.png", ["0.1", "f0.png"]),
        ("0.1, f0.png ", ["0.1", "f0.png"]),
        ('"0.1","f0.png"', ["0.1", "f0.png"]),
        ('0.1, "cam 1, left.png"', ["0.1", "cam 1, left.png"]),
        ('0.1,"a ""b"".png"', ["0.1", 'a "b".png']),
        ('0.1,"open', ["0.1", "open"]),
        ("", [""]),
    ],
)
def test_fields(line, fields):
    assert csv_fields(line) == fields


def test_an_image_list_as_a_spreadsheet_saves_it(tmp_path):
    index = tmp_path / "images.csv"
    index.write_text('"stamp_s","file"\r\n"0.1","f0.png"\r\n0.2, "cam 1, left.png"\r\n')
    stamps, files = _read_index(index)
    assert files == ["f0.png", "cam 1, left.png"]
    np.testing.assert_array_equal(stamps, [0.1, 0.2])
    index.write_text("stamp_s,file\n0.1,f0.png,\n")  # a third (empty) column
    with pytest.raises(InputError, match=r"images.csv: line 2: got '0.1,f0.png,'; expected 'stamp_s,file'"):
        _read_index(index)


def test_a_gyro_file_with_quoted_fields(tmp_path):
    plain, quoted = tmp_path / "a.csv", tmp_path / "b.csv"
    rows = [(0.005 * k, 0.01 * k) for k in range(400)]
    plain.write_text("stamp_s,yaw_rate_rad_s\n" + "".join(f"{t!r},{r!r}\n" for t, r in rows))
    quoted.write_text('"stamp_s","yaw_rate_rad_s"\n' + "".join(f'"{t!r}", "{r!r}"\n' for t, r in rows))
    a, b = read_gyro_csv(plain, None), read_gyro_csv(quoted, None)
    np.testing.assert_array_equal(b.stamps_s, a.stamps_s)
    np.testing.assert_array_equal(b.rates_rad_s, a.rates_rad_s)


def test_a_csv_laser_log_with_a_quoted_header(tmp_path):
    rows = "".join(
        f"{1.0 + 0.1 * s},{0.0625 * a - 1},{2.0 + 0.01 * s}\n" for s in range(5) for a in range(32)
    )
    plain, quoted = tmp_path / "a.csv", tmp_path / "b.csv"
    plain.write_text("stamp_s,angle_rad,range_m\n" + rows)
    quoted.write_text('"stamp_s","angle_rad","range_m"\n' + rows)
    assert detect_format(Path(quoted)) == "csv"
    a, b = read_csv_laser(plain), read_csv_laser(quoted)
    assert len(a) == len(b) == 5
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(y.ranges_m, x.ranges_m)
        assert y.stamp_s == x.stamp_s
