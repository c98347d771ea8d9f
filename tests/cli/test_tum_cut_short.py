"""TUM files copied while they were written (a SLAM run's trajectory, a logger's wheel
odometry): `read_tum_cut` applies the importers' rule for logs cut short
(rigcal.io.log_lines), and each caller decides: `import-laser --odometry` and `evaluate`
read such a file to its last whole line with one warning and refuse it under
`--stamps strict`; a file rigcal wrote itself (a sequence's odometry.tum) must be whole."""

from __future__ import annotations

import numpy as np
import pytest

from rigcal.cli.main import main
from rigcal.errors import InputError
from rigcal.io.trajectory import read_tum, read_tum_cut
from rigcal.recordings.sequence import read_sequence

POSES = "".join(f"{1.0 + 0.1 * k:.1f} {0.1 * k:.1f} 0 0 0 0 0 1\n" for k in range(6))
LASER = "".join(f"{1.0 + 0.1 * k:.1f} -0.5 0.25 0.5 3 5 2.0 2.0 2.0 2.0 2.0\n" for k in range(5))

# The ways a copy ends mid-line: fields missing, a number cut in two (a quaternion off unit
# length, a stamp going back).
CUT = [
    ("1.6 0.5 0 0", ":7: got 4 fields; expected 8"),
    ("1.6 0.5 0 0 0 0 0 0.9", ":7: qx qy qz qw: got [0.0, 0.0, 0.0, 0.9]"),
    ("1", ":7: got 1 fields; expected 8"),
    ("1.6 0.5 0 0 0 0 0 1\n1.", ":8: got 1 fields"),
]


@pytest.mark.parametrize(("tail", "problem"), CUT)
def test_a_file_cut_short_is_read_to_its_last_whole_line(tmp_path, tail, problem):
    path = tmp_path / "t.tum"
    path.write_text(POSES + tail)
    traj, cut = read_tum_cut(path, strict=False)
    whole = 6 + tail.count("\n")
    assert len(traj) == whole
    assert cut is not None
    assert cut.line == whole + 1
    assert problem in cut.warning(path)
    with pytest.raises(InputError, match="a log cut short; --stamps repair leaves it out"):
        read_tum_cut(path, strict=True)
    with pytest.raises(InputError, match="expected"):  # a file that must be whole
        read_tum(path)


@pytest.mark.parametrize(
    ("text", "match"),
    [
        # Fields missing on a line with its newline, in the middle: not a cut end.
        (POSES[:40] + "1.05 0 0\n" + POSES[40:], "got 3 fields"),
        # A whole last line (its newline) with every field, but wrong: an error, not a cut.
        (POSES + "1.6 0.5 0 0 0 0 0 7\n", "qx qy qz qw: got"),
        (POSES + "1.2 0.5 0 0 0 0 0 1", "timestamp 1.2 not after 1.5"),  # no newline, but whole
        ("1.0 0 0", "got 3 fields"),  # nothing whole before it
    ],
)
def test_only_the_end_of_a_file_can_be_cut_short(tmp_path, text, match):
    path = tmp_path / "t.tum"
    path.write_text(text)
    if "1.2 0.5" in text:  # a stamp going back on an unterminated last line: cut (a stamp cut in two)
        assert read_tum_cut(path, strict=False)[1] is not None
        return
    with pytest.raises(InputError, match=match):
        read_tum_cut(path, strict=False)


def test_a_whole_file_has_no_cut_line(tmp_path):
    path = tmp_path / "t.tum"
    path.write_text(POSES.replace("\n", "\r\n") + "# the end\n")
    traj, cut = read_tum_cut(path, strict=False)
    assert cut is None
    assert len(traj) == 6
    np.testing.assert_array_equal(traj.stamps_s, read_tum(path).stamps_s)


def test_import_laser_reads_an_odometry_file_cut_short_with_one_warning(tmp_path, capsys):
    (tmp_path / "laser.txt").write_text(LASER)
    (tmp_path / "odom.tum").write_text(POSES + "1.6 0.5 0")
    argv = ["import-laser", str(tmp_path / "laser.txt"), "--odometry", str(tmp_path / "odom.tum")]
    assert main([*argv, "-o", str(tmp_path / "s")]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert [e for e in err if e.startswith("warning:")] == [
        f"warning: {tmp_path / 'odom.tum'}:7: got 3 fields; expected 8 (timestamp tx ty tz qx qy qz qw); "
        "the log's last line (9 bytes), left out as incomplete (a log cut short; --stamps strict refuses it)"
    ]
    seq = read_sequence(tmp_path / "s")
    assert seq.odometry is not None
    assert len(seq.odometry.stamps_s) == 6
    assert seq.source["odometry_incomplete_last_line"] == 7


def test_import_laser_strict_refuses_an_odometry_file_cut_short(tmp_path, fails):
    (tmp_path / "laser.txt").write_text(LASER)
    (tmp_path / "odom.tum").write_text(POSES + "1.6 0.5 0")
    argv = ["import-laser", tmp_path / "laser.txt", "--odometry", tmp_path / "odom.tum", "--stamps", "strict"]
    line = fails([*argv, "-o", tmp_path / "s"], 3)
    assert "odom.tum: line 7: got 3 fields" in line
    assert "a log cut short" in line


def test_a_sequences_own_odometry_file_must_be_whole(tmp_path):
    (tmp_path / "laser.txt").write_text(LASER)
    (tmp_path / "odom.tum").write_text(POSES)
    argv = ["import-laser", str(tmp_path / "laser.txt"), "--odometry", str(tmp_path / "odom.tum")]
    assert main([*argv, "-o", str(tmp_path / "s")]) == 0
    odom = tmp_path / "s" / "odometry.tum"
    odom.write_text(odom.read_text()[:-20])  # rigcal writes it whole: a cut one is damage
    with pytest.raises(InputError, match=r"odometry.tum: line \d+: .*--wheel-odometry ignore runs without"):
        read_sequence(tmp_path / "s").odometry  # noqa: B018


@pytest.mark.parametrize("which", ["estimate", "truth"])
def test_evaluate_reads_a_trajectory_cut_short_with_one_warning(tmp_path, capsys, fails, which):
    est, gt = tmp_path / "est.tum", tmp_path / "gt.tum"
    est.write_text(POSES)
    gt.write_text(POSES)
    (est if which == "estimate" else gt).write_text(POSES + "1.6 0.5 0 0 0 0 0")
    assert main(["evaluate", str(est), "--gt", str(gt), "--json"]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    cut = est if which == "estimate" else gt
    assert len(err) == 1
    assert err[0].startswith(f"warning: {cut}:7: got 7 fields; expected 8")
    line = fails(["evaluate", est, "--gt", gt, "--stamps", "strict"], 3)
    assert f"{cut}: line 7: got 7 fields" in line
    assert "a log cut short" in line
