"""CARMEN logs as archives ship them: compressed, cut short, with Windows line ends,
Latin-1 comments, other message types, and rangefinders' nan / inf for no return."""

from __future__ import annotations

import bz2
import gzip

import numpy as np
import pytest
import yaml

from rigcal.cli.main import main
from rigcal.errors import InputError
from rigcal.recordings.carmen import read_carmen


def flaser(i: int, n: int = 180) -> str:
    r = " ".join(f"{2.0 + 0.01 * (k % 7):.3f}" for k in range(n))
    x = 0.05 * i
    return f"FLASER {n} {r} {x + 0.2:.3f} 0 0 {x:.3f} 0 0 {100 + 0.1 * i:.6f} host {100 + 0.1 * i:.6f}"


def odom(i: int) -> str:
    return f"ODOM {0.05 * i:.3f} 0 0 0.5 0 0 {100.05 + 0.1 * i:.6f} host 1"


LINES = ["# CARMEN Logfile", "PARAM robot_frontlaser_offset 0.2"] + [
    line for i in range(6) for line in (flaser(i), odom(i))
]
TEXT = "\n".join(LINES) + "\n"


@pytest.mark.parametrize(
    ("name", "data"),
    [
        ("run.log.gz", gzip.compress(TEXT.encode())),
        ("run.log.bz2", bz2.compress(TEXT.encode())),
        ("run.log", gzip.compress(TEXT.encode())),  # told by its bytes, not its name
        ("crlf.log", TEXT.replace("\n", "\r\n").encode()),
        ("bom.log", b"\xef\xbb\xbf" + TEXT.encode()),
        ("latin1.log", ("# caf\xe9 \xb0C\n" + TEXT).encode("latin-1")),
    ],
)
def test_compressed_and_foreign_logs_read_as_the_plain_one(tmp_path, name, data):
    plain = tmp_path / "plain.log"
    plain.write_text(TEXT)
    p = tmp_path / name
    p.write_bytes(data)
    got, want = read_carmen(p), read_carmen(plain)
    assert len(got.scans) == len(want.scans) == 6
    np.testing.assert_array_equal([s.stamp_s for s in got.scans], [s.stamp_s for s in want.scans])
    np.testing.assert_array_equal(got.odom, want.odom)
    assert got.cut is None


@pytest.mark.parametrize("kind", ["gzip", "bzip2"])
def test_a_cut_short_compressed_log_is_one_line_naming_it(tmp_path, kind):
    packed = gzip.compress(TEXT.encode()) if kind == "gzip" else bz2.compress(TEXT.encode())
    p = tmp_path / "run.log.gz"
    p.write_bytes(packed[: len(packed) // 2])
    with pytest.raises(InputError, match=rf"run.log.gz: CARMEN log: got a broken or cut-short {kind} stream"):
        read_carmen(p)


@pytest.mark.parametrize("newline", ["", "\n"])
def test_an_incomplete_last_line_is_left_out_and_said(tmp_path, newline):
    p = tmp_path / "cut.log"
    p.write_text(TEXT + flaser(6)[:300] + newline)
    log = read_carmen(p)
    assert len(log.scans) == 6
    assert log.cut is not None
    assert log.cut.line == len(LINES) + 1
    assert log.cut.message == "FLASER"
    assert "expected at least 188" in log.cut.problem


def test_a_number_cut_in_two_on_the_last_line_without_newline_is_left_out(tmp_path):
    p = tmp_path / "cut.log"
    whole = odom(6).split()
    p.write_text(TEXT + " ".join([*whole[:7], "1e"]))  # the stamp cut mid-number
    log = read_carmen(p)
    assert log.cut is not None
    assert log.cut.message == "ODOM"
    assert len(log.odom) == 6


@pytest.mark.parametrize(
    ("last", "match"),
    [
        (flaser(6)[:300] + "\n" + "# a comment after it", "expected at least 188"),  # not the last line
        (odom(6).replace("ODOM 0.300", "ODOM nan") + "\n", r"ODOM field 1 .*got nan; expected a finite"),
    ],
)
def test_a_broken_line_that_is_not_a_cut_is_still_refused(tmp_path, last, match):
    p = tmp_path / "bad.log"
    p.write_text(TEXT + last)
    with pytest.raises(InputError, match=match):
        read_carmen(p)


def test_nan_and_inf_ranges_are_no_return_and_negative_ones_refused(tmp_path):
    fields = flaser(0).split()
    fields[3], fields[4] = "nan", "inf"
    p = tmp_path / "nan.log"
    p.write_text("\n".join([" ".join(fields), *LINES[3:]]) + "\n")
    scan = read_carmen(p).scans[0]
    assert not scan.valid[1]
    assert not scan.valid[2]
    assert scan.valid[0]
    fields[3] = "-1"
    p.write_text("\n".join([" ".join(fields), *LINES[3:]]) + "\n")
    with pytest.raises(InputError, match=r"nan.log:1: FLASER range 2: got -1.0; expected a range >= 0"):
        read_carmen(p)


def test_import_carmen_of_a_cut_gzip_log_warns_once_and_records_it(tmp_path, capsys):
    p = tmp_path / "run.log.gz"
    p.write_bytes(gzip.compress((TEXT + flaser(6)[:250]).encode()))
    out = tmp_path / "seq"
    assert main(["import-carmen", str(p), "-o", str(out)]) == 0
    err = capsys.readouterr().err
    warnings = [line for line in err.splitlines() if "left out as incomplete" in line]
    assert len(warnings) == 1
    assert f"{p}:{len(LINES) + 1}: FLASER" in warnings[0]
    doc = yaml.safe_load((out / "sequence.yaml").read_text())
    assert doc["source"]["incomplete_last_line"] == len(LINES) + 1
    assert doc["scans"]["count"] == 6
