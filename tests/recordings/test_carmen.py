"""CARMEN logs (FLASER, ROBOTLASER1; plain and inside g2o) and rigcal import-carmen."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from rigcal.cli.main import cli, main
from rigcal.errors import InputError
from rigcal.io.trajectory import read_tum
from rigcal.recordings.carmen import read_carmen
from rigcal.recordings.sequence import read_sequence


def robotlaser1(ranges, pose=(1.0, 2.0, 0.5), stamp=100.0, remissions=(), start=-1.570796, step=0.017453):
    r = " ".join(str(x) for x in ranges)
    rem = " ".join(str(x) for x in remissions)
    x, y, th = pose
    return (
        f"ROBOTLASER1 0 {start} 3.141593 {step} 50.0 0.1 0 {len(ranges)} {r} {len(remissions)} {rem} "
        f"{x} {y} {th} {x + 0.1} {y} {th} 0 0 0 0 0 {stamp} host 1.5"
    ).replace("  ", " ")


def flaser(ranges, pose=(1.0, 2.0, 0.5), odom=(0.0, 0.0, 0.0), stamp=100.0):
    r = " ".join(str(x) for x in ranges)
    return f"FLASER {len(ranges)} {r} {' '.join(map(str, pose))} {' '.join(map(str, odom))} {stamp} host 2.5"


def write(tmp_path, lines, name="run.log"):
    p = tmp_path / name
    p.write_text("\n".join(lines) + "\n")
    return p


def test_robotlaser1_inside_g2o_with_poses_stamps_and_geometry(tmp_path):
    p = write(
        tmp_path,
        [
            "VERTEX_SE2 0 1.0 2.0 0.5",
            robotlaser1([1.0, 2.0, 3.0], stamp=10.0, remissions=(0.5, 0.7)),
            "VERTEX_SE2 1 1.5 2.0 0.5",
            robotlaser1([4.0, 60.0, 0.0], pose=(1.5, 2.0, 0.5), stamp=10.5),
            "EDGE_SE2 0 1 0.5 0 0 500 0 0 500 0 5000",
        ],
        "log.g2o",
    )
    log = read_carmen(p)
    assert len(log.scans) == 2
    assert log.skipped_lines == 3
    np.testing.assert_array_equal(log.line_numbers, [2, 4])
    s = log.scans[0]
    assert s.stamp_s == 10.0
    np.testing.assert_allclose(s.angles_rad, -1.570796 + 0.017453 * np.arange(3))
    np.testing.assert_allclose(s.ranges_m, [1.0, 2.0, 3.0])
    assert s.range_max_m == 50.0
    # 60 m is beyond the logged maximum range and 0 is no return.
    np.testing.assert_array_equal(log.scans[1].valid, [True, False, False])
    np.testing.assert_allclose(log.laser_poses, [[1.0, 2.0, 0.5], [1.5, 2.0, 0.5]])
    np.testing.assert_allclose(log.odometry_poses[:, 0], [1.1, 1.6])


@pytest.mark.parametrize(("n", "step_deg"), [(180, 1.0), (181, 1.0), (361, 0.5)])
def test_flaser_spans_180_degrees_from_minus_90(tmp_path, n, step_deg):
    p = write(tmp_path, ["PARAM robot_length 0.5", "ODOM 0 0 0 0 0 0 1.0 h 1.0", flaser(np.ones(n))])
    log = read_carmen(p)
    a = log.scans[0].angles_rad
    assert a[0] == pytest.approx(-np.pi / 2)
    assert a[1] - a[0] == pytest.approx(np.radians(step_deg))
    np.testing.assert_allclose(log.laser_poses[0], [1.0, 2.0, 0.5])
    np.testing.assert_allclose(log.odometry_poses[0], [0.0, 0.0, 0.0])
    assert log.scans[0].stamp_s == 100.0


@pytest.mark.parametrize(
    ("line", "match"),
    [
        ("FLASER", r"run.log:2: FLASER: got '0 fields'; expected at least 1"),
        ("FLASER x 1 2", r"run.log:2: FLASER num_readings: got 'x'; expected an integer in \[1, 100000\]"),
        ("FLASER 3 1 2 3 0 0 0", r"run.log:2: FLASER: got '7 fields'; expected at least 11"),
        (
            "FLASER 1 1.0 0 0 zero 0 0 0 5 h 1",
            r"run.log:2: FLASER field 5 \(n, .*\): got 'zero'; expected a finite number",
        ),
        ("ROBOTLASER1 0 -1.5 3.1 0.01 50", r"run.log:2: ROBOTLASER1: got '5 fields'; expected at least 8"),
        (
            "ROBOTLASER1 0 -1.5 3.1 0.01 50 0.1 0 -2",
            r"ROBOTLASER1 num_readings: got '-2'; expected an integer in \[1, 100000\]",
        ),
        ("ROBOTLASER1 0 -1.5 3.1 0.01 50 0.1 0 2 1 1", r"ROBOTLASER1: got '10 fields'; expected at least 11"),
        ("ROBOTLASER1 0 -1.5 3.1 0.01 50 0.1 0 1 1 x", r"ROBOTLASER1 num_remissions: got 'x'"),
        (
            "ROBOTLASER1 0 -1.5 3.1 0.01 50 0.1 0 1 1 0 1 2 3",
            r"ROBOTLASER1: got '13 fields'; expected at least 22",
        ),
        (
            robotlaser1([1.0, 2.0], step=0.0),
            r"ROBOTLASER1 angular_resolution: got '0.0'; expected an angle in \(0, 2 pi\] rad",
        ),
        (
            robotlaser1([1.0]).replace(" 50.0 ", " -1 "),
            r"ROBOTLASER1 max_range: got '-1'; expected a positive",
        ),
        (
            robotlaser1([1.0, 2.0], stamp=50.0),
            r"run.log: laser ipc_timestamp: line 2: got stamp 50.0; expected stamps that increase but for "
            r"glitches of at most 1 s",
        ),
        ("ODOM 1 2 x 0 0 0 61.0 h 1", r"run.log:2: ODOM field 3 \(x y theta tv rv accel ipc_timestamp\)"),
        ("ODOM 1 2 3", r"run.log:2: ODOM: got '3 fields'; expected at least 7"),
    ],
)
def test_bad_lines_name_file_line_and_what_was_expected(tmp_path, line, match):
    # Not the last line: an incomplete last line is a log cut short (test_carmen_logs_as_shipped.py).
    p = write(tmp_path, [robotlaser1([1.0, 2.0], stamp=60.0), line, "# end"])
    with pytest.raises(InputError, match=match):
        read_carmen(p)


def test_a_log_without_laser_lines_and_a_missing_file(tmp_path):
    with pytest.raises(InputError, match="no FLASER or ROBOTLASER1 lines"):
        read_carmen(write(tmp_path, ["ODOM 0 0 0 0 0 0 1.0 h 1.0"]))
    with pytest.raises(InputError, match=r"missing\.log: CARMEN log not found"):
        read_carmen(tmp_path / "missing.log")


def test_import_carmen_writes_a_sequence_with_ground_truth(tmp_path):
    ranges = np.linspace(1.0, 3.0, 20)
    p = write(tmp_path, [robotlaser1(ranges, (0, 0, 0), 1.0), robotlaser1(ranges, (0.5, 0.25, 0.1), 2.0)])
    out = tmp_path / "seq"
    res = CliRunner().invoke(cli, ["import-carmen", str(p), "-o", str(out)])
    assert res.exit_code == 0, res.output
    assert "2 scans" in res.output
    res = CliRunner().invoke(cli, ["import-carmen", str(p), "-o", str(tmp_path / "j"), "--json"])
    assert res.exit_code == 0, res.output
    doc = json.loads(res.output)
    assert (doc["scans"], doc["duration_s"], doc["output"]) == (2, 1.0, str(tmp_path / "j"))
    seq = read_sequence(out)
    assert len(seq.scans) == 2
    np.testing.assert_allclose(seq.scans[1].ranges_m, ranges)
    gt = read_tum(out / "groundtruth.tum")
    np.testing.assert_allclose(gt.stamps_s, [1.0, 2.0])
    np.testing.assert_allclose(gt.poses[1][:2, 3], [0.5, 0.25])
    np.testing.assert_allclose(np.arctan2(gt.poses[1][1, 0], gt.poses[1][0, 0]), 0.1)
    # An existing folder needs --force; a bad log is exit code 3.
    assert main(["import-carmen", str(p), "-o", str(out)]) == 5
    assert main(["import-carmen", str(p), "-o", str(out), "--force"]) == 0
    assert (
        main(["import-carmen", str(write(tmp_path, ["FLASER 2 1"], "bad.log")), "-o", str(tmp_path / "b")])
        == 3
    )


def test_import_carmen_warns_once_and_records_the_repair(tmp_path, capsys):
    ranges = np.linspace(1.0, 3.0, 20)
    lines = [robotlaser1(ranges, (0.1 * k, 0, 0), t) for k, t in enumerate((1.0, 1.1, 1.1, 1.05, 1.4))]
    log = tmp_path / "run.log"
    log.write_text("\n".join(lines) + "\n")
    res = CliRunner().invoke(cli, ["import-carmen", str(log), "-o", str(tmp_path / "seq")])
    assert res.exit_code == 0, res.output
    warnings = [ln for ln in res.stderr.splitlines() if ln.startswith("warning:")]
    assert len(warnings) == 1
    assert "repaired 2 scan stamps (1 equal to the previous one, 1 stepping back)" in warnings[0]
    seq = read_sequence(tmp_path / "seq")
    assert [s.stamp_s for s in seq.scans] == pytest.approx([1.0, 1.1, 1.2, 1.3, 1.4])
    assert seq.source["stamps"]["equal_spread"] == 1
    assert seq.source["stamps"]["backward_placed"] == 1
    assert main(["import-carmen", str(log), "-o", str(tmp_path / "s2"), "--stamps", "strict"]) == 3
    err = capsys.readouterr().err
    assert "run.log: laser ipc_timestamp: line 3: got stamp 1.1; expected a stamp after" in err
    assert not (tmp_path / "s2").exists()
