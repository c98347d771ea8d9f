"""A CARMEN log holding the front laser twice: as FLASER and, with the robot module
running, as ROBOTLASER1 lines (what CARMEN's logger writes). A FLASER line whose ranges
are a ROBOTLASER1 line's within a second is that reading again: skipped and counted, so
that no scan is read twice; FLASER lines of other readings are read."""

from __future__ import annotations

import json

import numpy as np
import pytest

from rigcal.cli.main import main
from rigcal.recordings.carmen import read_carmen

N = 6
FLASER_AGAIN = "FLASER (a ROBOTLASER1 line's reading again)"


def _ranges(k: int, other: bool = False) -> str:
    r = 2.0 + 0.01 * k + 0.3 * np.sin(np.arange(181) * (0.2 + k)) + (0.02 * other) * (np.arange(181) == 90)
    r[7] = 9.0  # beyond ROBOTLASER1's 8 m: no return there, a return to FLASER's 50 m
    return " ".join(f"{v:.2f}" for v in r)


def _flaser(k: int, dt: float = 0.0, other: bool = False) -> str:
    t, x = 100.0 + 0.2 * k + dt, 0.1 * k
    return f"FLASER 181 {_ranges(k, other)} {x} 0 0 {x} 0 0 {t} host {t}"


def _robotlaser(k: int) -> str:
    t, x = 100.0 + 0.2 * k, 0.1 * k
    geometry = f"0 {-np.pi / 2} {np.pi} {np.pi / 180} 8.0 0.01 0"
    return f"ROBOTLASER1 {geometry} 181 {_ranges(k)} 0 {x} 0 0 {x} 0 0 0 0 0.5 0.5 0 {t} host {t}"


@pytest.mark.parametrize("order", ["flaser first", "robotlaser first", "flaser block first"])
def test_flaser_lines_of_the_robotlaser_readings_are_skipped(tmp_path, order):
    if order == "flaser block first":
        lines = [_flaser(k) for k in range(N)] + [_robotlaser(k) for k in range(N)]
    else:
        pairs = [(_flaser(k), _robotlaser(k)) for k in range(N)]
        lines = [line for p in pairs for line in (p if order == "flaser first" else p[::-1])]
    path = tmp_path / "both.log"
    path.write_text("\n".join(lines) + "\n")
    log = read_carmen(path)
    np.testing.assert_allclose([s.stamp_s for s in log.scans], 100.0 + 0.2 * np.arange(N))
    assert log.stamps is not None
    assert log.stamps.equal == 0
    assert {s.range_max_m for s in log.scans} == {8.0}  # ROBOTLASER1's max_range, not FLASER's 50 m
    assert log.skipped_kinds == {FLASER_AGAIN: N}
    np.testing.assert_allclose(log.laser_poses[:, 0], 0.1 * np.arange(N))


def test_import_carmen_names_the_flaser_lines_it_skipped(tmp_path, capsys):
    path = tmp_path / "both.log"
    path.write_text("".join(f"{_flaser(k)}\n{_robotlaser(k)}\n" for k in range(N)))
    assert main(["-q", "import-carmen", str(path), "-o", str(tmp_path / "seq"), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["scans"] == N
    assert doc["other_lines_by_kind"] == {FLASER_AGAIN: N}


@pytest.mark.parametrize(("dt", "other"), [(1.5, False), (0.05, True)])
def test_flaser_lines_of_other_readings_are_read(tmp_path, dt, other):
    # Over a second away, or one beam 2 cm off: another reading, kept.
    path = tmp_path / "both.log"
    lines = [_robotlaser(k) for k in range(N)] + [_flaser(k, dt, other) for k in range(N)]
    path.write_text("\n".join(lines) + "\n")
    log = read_carmen(path)
    assert len(log.scans) == 2 * N
    assert log.skipped_kinds == {}


def test_a_log_of_flaser_lines_alone_is_read_as_before(tmp_path):
    path = tmp_path / "front.log"
    path.write_text("".join(f"{_flaser(k)}\n" for k in range(N)))
    log = read_carmen(path)
    assert len(log.scans) == N
    assert log.skipped_kinds == {}


def test_a_log_of_laser_lines_rigcal_does_not_read_names_them(tmp_path, capsys):
    geometry = f"0 {-np.pi / 2} {np.pi} {np.pi / 180} 8.0 0.01 0 3 1 2 3 0"
    path = tmp_path / "raw.log"
    path.write_text(
        "".join(
            f"RAWLASER1 {geometry} {t} host {t}\nRLASER 1 2.0 0 0 0 0 0 0 {t} host {t}\n" for t in (1.0, 1.2)
        )
    )
    assert main(["import-carmen", str(path), "-o", str(tmp_path / "seq")]) == 3
    assert capsys.readouterr().err.strip().splitlines()[-1] == (
        f"Error: {path}: no FLASER or ROBOTLASER1 lines (it has RAWLASER1 2, RLASER 2, not read: RAWLASER "
        "lines carry no pose, RLASER and ROBOTLASER2 are a rear laser); expected a CARMEN log or a g2o file "
        "with them"
    )
    assert not (tmp_path / "seq").exists()
