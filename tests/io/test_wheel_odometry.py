"""Wheel odometry: CARMEN's ODOM lines and laser lines, TUM files, the sequence's odometry.tum."""

from __future__ import annotations

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from rigcal.cli.main import cli, main
from rigcal.errors import InputError
from rigcal.geometry import pose_of, se2
from rigcal.io.wheel_odometry import checked, laser_motions, parse_mounting
from rigcal.recordings.carmen import carmen_odometry, read_carmen
from rigcal.recordings.sequence import read_sequence


def flaser(pose, odom, stamp):
    ranges = " ".join(["2.0"] * 10)
    return f"FLASER 10 {ranges} {' '.join(map(str, pose))} {' '.join(map(str, odom))} {stamp} host {stamp}"


def test_laser_motion_is_the_base_motion_seen_from_the_mounted_laser():
    mount = np.array([0.3, -0.1, 0.4])
    base = np.array([[0.0, 0.0, 0.0], [1.0, 0.5, 0.3], [2.0, 0.8, 1.0]])
    od = checked(np.array([0.0, 1.0, 2.0]), base, mount, "odom")
    got = laser_motions(od, np.array([0.0, 1.0, 2.0]))
    for k in range(2):
        laser0, laser1 = se2(base[k]) @ se2(mount), se2(base[k + 1]) @ se2(mount)
        np.testing.assert_allclose(got[k], pose_of(np.linalg.inv(laser0) @ laser1), atol=1e-12)
    assert od.laser_motion(-1.0, 1.0) is None
    np.testing.assert_allclose(od.laser_motion(0.0, 0.5), laser_motions(od, np.array([0.0, 0.5]))[0])


def test_carmen_odometry_from_odom_lines_params_and_laser_lines(tmp_path):
    # A raw log: the laser pose is the odometry moved by a fixed mounting (0.2 m ahead).
    lines = []
    for k in range(5):
        odom = (0.5 * k, 0.1 * k, 0.05 * k)
        c, s = np.cos(odom[2]), np.sin(odom[2])
        laser = (odom[0] + 0.2 * c, odom[1] + 0.2 * s, odom[2])
        lines.append(flaser(laser, odom, 10.0 + k))
    log = tmp_path / "raw.log"
    log.write_text("\n".join(lines) + "\n")
    od, how = carmen_odometry(read_carmen(log), str(log))
    assert od is not None
    assert "mounting from the laser lines" in how
    np.testing.assert_allclose(od.T_base_laser, [0.2, 0.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(od.stamps_s, 10.0 + np.arange(5))
    # ODOM lines (their own stamps) and the PARAMs win over the laser lines.
    odom_lines = [f"ODOM {0.1 * k} 0 0 0.1 0 0 {9.5 + 0.5 * k} host 1" for k in range(12)]
    log.write_text("\n".join(["PARAM robot_frontlaser_offset 0.25", *odom_lines, *lines]) + "\n")
    od, how = carmen_odometry(read_carmen(log), str(log))
    assert od is not None
    assert how.startswith("12 ODOM lines")
    assert "PARAM" in how
    np.testing.assert_allclose(od.T_base_laser, [0.25, 0.0, 0.0])
    assert len(od.stamps_s) == 12
    # Odometry fields left at 0: no odometry.
    log.write_text("\n".join(flaser((k, 0, 0), (0, 0, 0), k) for k in range(3)) + "\n")
    od, how = carmen_odometry(read_carmen(log), str(log))
    assert od is None
    assert "never change" in how


def test_import_carmen_keeps_odometry_in_a_version_3_sequence(tmp_path):
    lines = [flaser((0.5 * k, 0, 0), (0.5 * k, 1.0, 0.1), 10.0 + k) for k in range(4)]
    log = tmp_path / "run.log"
    log.write_text("\n".join(lines) + "\n")
    out = tmp_path / "seq"
    res = CliRunner().invoke(cli, ["import-carmen", str(log), "-o", str(out), "--laser-offset", "0.1,0,90"])
    assert res.exit_code == 0, res.output
    assert "odometry.tum (the laser lines' odometry poses; mounting given)" in res.output
    doc = yaml.safe_load((out / "sequence.yaml").read_text())
    assert doc["schema_version"] == 3
    assert doc["odometry"]["file"] == "odometry.tum"
    np.testing.assert_allclose(doc["odometry"]["T_base_laser"], [0.1, 0.0, np.pi / 2])
    seq = read_sequence(out)
    assert seq.odometry is not None
    np.testing.assert_allclose(seq.odometry.poses[:, 0], 0.5 * np.arange(4))
    np.testing.assert_allclose(seq.odometry.poses[:, 2], 0.1, atol=1e-12)
    res = CliRunner().invoke(cli, ["import-carmen", str(log), "-o", str(tmp_path / "s2"), "--no-odometry"])
    assert res.exit_code == 0
    assert read_sequence(tmp_path / "s2").odometry is None


def _odometry_sequence(tmp_path):
    log = tmp_path / "run.log"
    log.write_text("\n".join(flaser((0.5 * k, 0, 0), (0.5 * k, 0, 0), 10.0 + k) for k in range(4)) + "\n")
    out = tmp_path / "seq"
    assert main(["import-carmen", str(log), "-o", str(out)]) == 0
    return out


TUM_REST = "0 0 0 0 1\n"  # z, quaternion: the rest of a TUM line
BAD_ODOMETRY = [
    (("odometry.tum", "0.5 0 0 " + TUM_REST + "0.2 0 0 " + TUM_REST), r"line 2: timestamp 0.2 not after"),
    (("odometry.tum", "10 nan 0 " + TUM_REST + "11 0 0 " + TUM_REST), r"line 1: got a non-finite"),
    (
        ("odometry.tum", "100 0 0 " + TUM_REST + "101 0 0 " + TUM_REST),
        r"odometry.tum: odometry stamps: got '100.0 to 101.0'; expected a span overlapping the scans' "
        r"\(10.0 to 13.0\)",
    ),
    (
        ("odometry.tum", "10 0 0 0 0.7071068 0 0 0.7071068\n11 0 0 " + TUM_REST),
        r"pose 0: got 'tilted 90.0 deg'",
    ),
    (
        ("yaml", "schema_version: 3", "schema_version: 1"),
        r"schema_version: got 1; expected 3 for key 'odometry'",
    ),
    (("yaml", "- 0.0\n  - 0.0\n  - 0.0", "- 0.0\n  - 0.0"), r"odometry.T_base_laser: got \[0.0, 0.0\]"),
]


@pytest.mark.parametrize(("change", "match"), BAD_ODOMETRY)
def test_bad_odometry_in_a_sequence_is_one_line_naming_the_file(tmp_path, change, match):
    out = _odometry_sequence(tmp_path)
    if change[0] == "yaml":
        y = out / "sequence.yaml"
        text = y.read_text()
        assert change[1] in text
        y.write_text(text.replace(change[1], change[2]))
    else:
        (out / change[0]).write_text(change[1])
    with pytest.raises(InputError, match=match):
        read_sequence(out).odometry  # noqa: B018 (the file is read when first used)


BROKEN_TUM = [
    ("10 0 0 0 0 0 0 1\n11 0 0 0 0 0\n", r"odometry.tum: line 2: got 6 fields; expected 8"),
    ("10 0 0 0 0 0 0 1\n11 zero 0 0 0 0 0 1\n", r"odometry.tum: line 2: got '11 zero"),
    ("", r"odometry.tum: no poses"),
]


@pytest.mark.parametrize(("text", "match"), BROKEN_TUM)
def test_a_broken_odometry_file_is_read_only_when_used(tmp_path, capsys, text, match):
    """`--wheel-odometry ignore` runs without the file; using it names the file, line and value."""
    out = _odometry_sequence(tmp_path)
    (out / "odometry.tum").write_text(text)
    seq = read_sequence(out)  # the scans and images read; the odometry not yet
    assert seq.has_odometry
    with pytest.raises(InputError, match=match):
        seq.odometry  # noqa: B018
    argv = ["localize", str(out), "--method", "icp", "-o", str(tmp_path / "run")]
    assert main(argv) == 3
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert err[0].startswith("Error: ")
    assert "odometry.tum: " in err[0]
    assert not (tmp_path / "run").exists()
    assert main([*argv, "--wheel-odometry", "ignore", "--json"]) == 0
    doc = yaml.safe_load((tmp_path / "run" / "summary.yaml").read_text())
    assert doc["config"]["wheel_odometry"] == "ignored"


def test_import_laser_with_a_tum_odometry_and_its_errors(tmp_path, capsys):
    laser = tmp_path / "laser.txt"
    laser.write_text("".join(f"{t} -0.1 0.1 0.1 2 2 2\n" for t in (1.0, 1.1, 1.2)))
    odom = tmp_path / "odom.tum"
    odom.write_text("0.9 0 0 0 0 0 0 1\n1.3 0.4 0 0 0 0 0 1\n")
    assert main(["import-laser", str(laser), "--odometry", str(odom), "-o", str(tmp_path / "s")]) == 0
    seq = read_sequence(tmp_path / "s")
    assert seq.odometry is not None
    assert len(seq.odometry.stamps_s) == 2
    odom.write_text("5 0 0 0 0 0 0 1\n6 0.4 0 0 0 0 0 1\n")
    assert main(["import-laser", str(laser), "--odometry", str(odom), "-o", str(tmp_path / "t")]) == 3
    err = capsys.readouterr().err
    assert "odom.tum: odometry stamps: got '5.0 to 6.0'; expected a span overlapping" in err
    assert not (tmp_path / "t").exists()


def test_mounting_option():
    np.testing.assert_allclose(parse_mounting("0.1, -0.2, 180"), [0.1, -0.2, np.pi])
    for bad in ("0.1,0.2", "a,b,c", "0,0,nan", "500,0,0"):
        with pytest.raises(InputError, match=r"--laser-offset: got .*; expected X,Y,YAW_DEG"):
            parse_mounting(bad)
