"""CARMEN logs as real loggers and editors leave them: line endings mixed (CRLF, LF, a
lone CR), a byte-order mark, comments with form feeds, message types rigcal does not read
between the laser lines. The scans read as from the clean log, the line numbers in an
error are those an editor shows, and the summary names what was skipped."""

from __future__ import annotations

import numpy as np
import pytest
from test_carmen_logs_as_shipped import LINES

from rigcal.cli.main import main
from rigcal.errors import InputError
from rigcal.io.files import text_lines
from rigcal.recordings.carmen import read_carmen

CLEAN = LINES  # a FLASER and an ODOM line for each of 6 scans, a comment and a PARAM


def messy() -> list[str]:
    """The clean log's lines with others between them: comments holding a form feed, a
    vertical tab, a Unicode line separator; messages of other types."""
    out = []
    for k, line in enumerate(CLEAN):
        out.append(line)
        if k % 5 == 2:
            out.append("# page \x0c break \x0b and \u2028 separator")
        if k % 7 == 3:
            out.append("TRUEPOS 1 2 3 4 5 6 100.0 host 100.0")
        if k % 4 == 1:
            out.append("NMEAGGA 1 2 garbage")
    return out


def joined(lines: list[str]) -> bytes:
    ends = ["\r\n", "\n", "\r"]  # mixed, as after an edit on another system
    return b"\xef\xbb\xbf" + "".join(line + ends[k % 3] for k, line in enumerate(lines)).encode()


def test_text_lines_split_only_at_line_ends():
    assert text_lines("a\r\nb\nc\rd\x0ce\u2028f\x1cg\n") == ["a", "b", "c", "d\x0ce\u2028f\x1cg"]
    assert text_lines("") == []
    assert text_lines("a\n\n") == ["a", ""]


def test_a_messy_log_reads_as_the_clean_one(tmp_path):
    (tmp_path / "clean.log").write_text("\n".join(CLEAN) + "\n")
    (tmp_path / "messy.log").write_bytes(joined(messy()))
    clean, mess = read_carmen(tmp_path / "clean.log"), read_carmen(tmp_path / "messy.log")
    assert len(mess.scans) == len(clean.scans) == 6
    np.testing.assert_array_equal([s.stamp_s for s in mess.scans], [s.stamp_s for s in clean.scans])
    np.testing.assert_array_equal(mess.odom, clean.odom)
    assert mess.params == clean.params
    lines = messy()
    assert mess.skipped_kinds == {
        "comment": sum(x.startswith("#") for x in lines),
        "NMEAGGA": sum(x.startswith("NMEA") for x in lines),
        "TRUEPOS": sum(x.startswith("TRUEPOS") for x in lines),
    }
    # Each scan's line number is the one an editor shows.
    assert [lines[n - 1].split()[0] for n in mess.line_numbers] == ["FLASER"] * 6


def test_an_error_after_form_feeds_names_the_line_an_editor_shows(tmp_path):
    lines = messy()
    k = max(i for i, x in enumerate(lines) if x.startswith("FLASER"))
    lines[k] = lines[k].replace("FLASER 180 2.0", "FLASER 180 x2.0")
    (tmp_path / "bad.log").write_bytes(joined(lines))
    with pytest.raises(InputError, match=rf"bad.log:{k + 1}: FLASER field 2 .*got 'x2.000'"):
        read_carmen(tmp_path / "bad.log")


def test_import_carmen_names_what_it_skipped(tmp_path, capsys):
    (tmp_path / "messy.log").write_bytes(joined(messy()))
    assert main(["import-carmen", str(tmp_path / "messy.log"), "-o", str(tmp_path / "seq")]) == 0
    out = capsys.readouterr().out
    # Most first; a tie in the order first met (the log's comment before its first NMEAGGA).
    assert out.rstrip().endswith("10 other lines skipped (comment 4, NMEAGGA 4, TRUEPOS 2)")
