"""Line-based logs cut short (copied while recording): one rule for CARMEN, RADLOCC and CSV
logs. The incomplete last line is left out with one warning saying how many bytes (and
rows of its scan) were dropped; `--stamps strict` refuses it; a bad line elsewhere is an
error as before (rigcal.io.log_lines)."""

from __future__ import annotations

import pytest
import yaml

from rigcal.cli.main import main
from rigcal.errors import InputError
from rigcal.recordings.laser_text import read_csv_laser, read_radlocc_laser


def radlocc(k: int, header: bool = True) -> str:
    ranges = " ".join(f"{2.0 + 0.01 * b:.3f}" for b in range(11))
    head = "3 11 " if header else ""
    return f"{1.0 + 0.1 * k:.3f} -0.5 0.1 0.5 {head}{ranges}"


def csv(k: int) -> list[str]:
    return [f"{1.0 + 0.1 * k:.3f},{-0.5 + 0.1 * b:.3f},{2.0 + 0.01 * b:.3f}" for b in range(11)]


def _import(tmp_path, capsys, log, *extra):
    out = tmp_path / f"seq{len(list(tmp_path.iterdir()))}"
    code = main(["import-laser", str(log), "-o", str(out), *extra])
    return code, out, capsys.readouterr().err


@pytest.mark.parametrize("header", [True, False])
@pytest.mark.parametrize("newline", ["", "\n"])
def test_a_radlocc_log_cut_mid_line_is_read_to_its_last_whole_line(tmp_path, capsys, header, newline):
    whole = "".join(radlocc(k, header) + "\n" for k in range(5))
    cut = radlocc(5, header)[:60].strip()
    log = tmp_path / "laser.txt"
    log.write_text(whole + cut + newline)
    assert len(read_radlocc_laser(log)) == 5
    code, out, err = _import(tmp_path, capsys, log)
    assert code == 0, err
    warnings = [line for line in err.splitlines() if "left out as incomplete" in line]
    assert len(warnings) == 1
    assert warnings[0].startswith(f"warning: {log}:6: got ")
    assert f"the log's last line ({len(cut)} bytes)" in warnings[0]
    doc = yaml.safe_load((out / "sequence.yaml").read_text())
    assert doc["scans"]["count"] == 5
    assert doc["source"]["incomplete_last_line"] == 6
    with pytest.raises(InputError, match=r"laser.txt: line 6: .*a log cut short; --stamps repair leaves"):
        read_radlocc_laser(log, stamps="strict")
    code, strict_out, err = _import(tmp_path, capsys, log, "--stamps", "strict")
    assert code == 3
    assert err.strip().startswith(f"Error: {log}: line 6: ")
    assert not strict_out.exists()


def test_a_number_cut_in_two_without_a_newline_is_left_out(tmp_path):
    log = tmp_path / "laser.txt"
    log.write_text("".join(radlocc(k) + "\n" for k in range(3)) + radlocc(3)[:-4] + "1e")
    assert len(read_radlocc_laser(log)) == 3


def test_a_bad_line_that_is_not_the_last_still_stops_the_import(tmp_path, capsys):
    log = tmp_path / "laser.txt"
    lines = [radlocc(k) for k in range(4)]
    lines[2] = lines[2][:60]
    log.write_text("\n".join(lines) + "\n")
    code, out, err = _import(tmp_path, capsys, log)
    assert code == 3
    assert err.strip().startswith(f"Error: {log}: line 3: got ")
    assert not out.exists()
    # A last line with its newline and all its fields but a broken value is no cut either.
    lines = [radlocc(k) for k in range(4)]
    lines[3] = lines[3].replace("2.050", "2.0x5")
    log.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match=r"line 4: got .*expected numbers"):
        read_radlocc_laser(log)


def test_a_csv_log_cut_mid_scan_drops_that_scan_and_says_how_many_rows(tmp_path, capsys):
    rows = ["stamp_s,angle_rad,range_m"] + [r for k in range(4) for r in csv(k)]
    log = tmp_path / "scans.csv"
    log.write_text("\n".join(rows[:-3]) + "\n" + rows[-3][:8])  # the last scan's 9th row cut
    scans = read_csv_laser(log)
    assert len(scans) == 3
    code, out, err = _import(tmp_path, capsys, log)
    assert code == 0, err
    (warning,) = [line for line in err.splitlines() if "left out as incomplete" in line]
    assert f"{log}:{len(rows) - 2}: " in warning
    assert "(8 bytes), and the 8 line(s) of the scan it ended" in warning
    assert yaml.safe_load((out / "sequence.yaml").read_text())["scans"]["count"] == 3
    # A cut row that starts a new scan leaves the scan before it whole.
    log.write_text("\n".join(rows[:-11]) + "\n" + "1.3,-0.")
    assert len(read_csv_laser(log)) == 3
    assert _import(tmp_path, capsys, log, "--stamps", "strict")[0] == 3


def test_carmen_logs_follow_the_same_rule_and_strict_refuses(tmp_path, capsys):
    ranges = " ".join(["2.0"] * 10)
    lines = [f"FLASER 10 {ranges} {k} 0 0 {k} 0 0 {10.0 + k} host {10.0 + k}" for k in range(4)]
    log = tmp_path / "run.log"
    log.write_text("\n".join(lines) + "\n" + lines[0][:30] + "\n")
    assert main(["import-carmen", str(log), "-o", str(tmp_path / "a")]) == 0
    err = capsys.readouterr().err
    assert f"warning: {log}:5: FLASER: got '" in err
    assert "the log's last line (30 bytes), left out as incomplete" in err
    assert main(["import-carmen", str(log), "-o", str(tmp_path / "b"), "--stamps", "strict"]) == 3
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert err[0].startswith(f"Error: {log}:5: FLASER: got ")
    assert "a log cut short" in err[0]
    assert not (tmp_path / "b").exists()


def test_an_image_list_cut_short_is_read_to_its_last_whole_line(tmp_path, capsys):
    log = tmp_path / "laser.txt"
    log.write_text("".join(radlocc(k) + "\n" for k in range(5)))
    for i in range(3):
        (tmp_path / f"im{i}.png").write_bytes(b"\x89PNG\r\n\x1a\n")
    images = tmp_path / "images.txt"
    images.write_text("1.0 im0.png\n1.2 im1.png\n1.4 im2.p")  # copied while im2.png was listed
    code, out, err = _import(tmp_path, capsys, log, "--images", images)
    assert code == 0, err
    (warning,) = [line for line in err.splitlines() if "left out as incomplete" in line]
    assert warning.startswith(f"warning: {images}:3: image im2.p not found in {tmp_path}; the log's last")
    doc = yaml.safe_load((out / "sequence.yaml").read_text())
    assert doc["images"]["count"] == 2
    assert doc["source"]["images_incomplete_last_line"] == 3
    code, strict_out, err = _import(tmp_path, capsys, log, "--images", images, "--stamps", "strict")
    assert code == 3
    assert "a log cut short" in err
    assert not strict_out.exists()
    # With its newline, a missing last image is an error as before.
    images.write_text("1.0 im0.png\n1.2 im1.png\n1.4 im2.p\n")
    assert _import(tmp_path, capsys, log, "--images", images)[0] == 3
