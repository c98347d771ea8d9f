"""A drive stamped in another unit than seconds (loggers write Unix milliseconds,
microseconds or nanoseconds, or milliseconds from their start): one line naming the file,
the key, the value and the unit it looks like (exit 3), for `rigcal check --sequence`
and `rigcal localize`, never a "cannot tell" for the wrong reason or a run of 3900 s."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from room_scans import room_drive


@pytest.fixture
def drive(tmp_path) -> Path:
    return room_drive(tmp_path, odometry=True)


def _scans(seq: Path, f) -> None:
    with np.load(seq / "scans.npz") as z:
        arrays = dict(z)
    arrays["stamps_s"] = f(arrays["stamps_s"])
    np.savez_compressed(seq / "scans.npz", **arrays)


def _images(seq: Path, f) -> None:
    rows = (seq / "images.csv").read_text().splitlines()
    out = [rows[0]] + [f"{f(float(r.split(',')[0]))!r},{r.split(',')[1]}" for r in rows[1:]]
    (seq / "images.csv").write_text("\n".join(out) + "\n")


def _odometry(seq: Path, f) -> None:
    rows = [r.split() for r in (seq / "odometry.tum").read_text().splitlines() if not r.startswith("#")]
    (seq / "odometry.tum").write_text("".join(" ".join([repr(f(float(r[0]))), *r[1:]]) + "\n" for r in rows))


def _both(f):
    return lambda seq: (_scans(seq, f), _images(seq, f), _odometry(seq, f))


CASES = [
    (
        _both(lambda t: t * 1e3 + 1.7e12),
        "scans.npz: stamps_s: got 1700000003900.0; expected seconds (Unix time is about 1.7e9 s; this looks "
        "like milliseconds: convert to seconds)",
    ),
    (_both(lambda t: t * 1e9 + 1.7e18), "this looks like nanoseconds"),
    (_both(lambda t: t * 1e6 + 1.7e15), "this looks like microseconds"),
    (
        _both(lambda t: t * 1e3),
        "scans.npz: stamps_s: got 'a scan every 100 (median)'; expected seconds: a laser scans several "
        "times a second (stamps in milliseconds?)",
    ),
    (
        lambda seq: _images(seq, lambda t: t * 1e3),
        "images.csv: stamp_s: got '10.000 to 3810.000 s'; expected images within the scans' span, 0.000 to "
        "3.900 s (scans.npz): the same clock (one stream in milliseconds, the other in seconds?)",
    ),
    (lambda seq: _images(seq, lambda t: t * 1e9 + 1.7e18), "images.csv: stamp_s: got 1.70000000381e+18"),
]


@pytest.mark.parametrize(("spoil", "want"), CASES)
def test_a_drive_stamped_in_another_unit_is_one_line(drive, fails, spoil, want):
    spoil(drive)
    rig = drive.parent / "rig.yaml"
    assert want in fails(["check", rig, "--sequence", drive, "--no-log", "--wheel-odometry", "ignore"], 3)
    if "images.csv: stamp_s: got '" not in want:  # (icp reads no images)
        assert want in fails(["localize", drive, "--method", "icp", "-o", drive.parent / "out"], 3)


def test_wheel_odometry_in_milliseconds_says_so(drive, fails):
    _odometry(drive, lambda t: t * 1e3)  # 20 Hz: a pose every 50 ms
    line = fails(["localize", drive, "--method", "icp", "-o", drive.parent / "out"], 3)
    assert (
        "odometry.tum: odometry stamps: got 'a pose every 50 (median)'; expected seconds: wheel "
        "odometry is logged several times a second (stamps in milliseconds?)" in line
    )


def test_fast_wheel_odometry_in_milliseconds_from_its_start_says_so(drive, fails):
    """200 Hz odometry stamped in milliseconds from its start steps by 5, which passes for
    seconds, and overlaps the scans: its span, about 1000x the scans', says milliseconds."""
    rows = [r.split() for r in (drive / "odometry.tum").read_text().splitlines() if not r.startswith("#")]
    t = np.arange(0.0, 4.0, 0.005)
    x = np.interp(t, [float(r[0]) for r in rows], [float(r[1]) for r in rows])
    lines = [f"{k * 5} {float(xi)!r} 0 0 0 0 0 1\n" for k, xi in enumerate(x)]
    (drive / "odometry.tum").write_text("".join(lines))
    line = fails(["localize", drive, "--method", "icp", "-o", drive.parent / "out"], 3)
    assert "odometry.tum: odometry stamps: got 'a pose every 5 (median) over 3995'; expected seconds" in line
    assert "(stamps in milliseconds from the start?)" in line
    rig = drive.parent / "rig.yaml"
    assert "a pose every 5 (median)" in fails(["check", rig, "--sequence", drive, "--no-log"], 3)


def test_wheel_odometry_in_milliseconds_on_another_clock_gets_the_hint(drive, fails):
    _odometry(drive, lambda t: t * 1e3 + 1e4)  # no overlap either: the spans' ratio is a hint
    line = fails(["localize", drive, "--method", "icp", "-o", drive.parent / "out"], 3)
    assert "odometry stamps: got 'a pose every 50 (median)'" in line


def test_wheel_odometry_logged_far_longer_than_the_scans_is_read(drive, capsys):
    """An hour of 5 Hz odometry around the drive's 4 s of scans (spans about 1000x apart,
    which the spans' ratio once took for milliseconds): the stamps' own step (0.2 s) says
    seconds, so the drive localizes from the wheels."""
    from rigcal.cli.main import main

    rows = [r.split() for r in (drive / "odometry.tum").read_text().splitlines() if not r.startswith("#")]
    before = [[repr(-1800.0 + 0.2 * k), "0", "0", "0", "0", "0", "0", "1"] for k in range(9000)]
    after = [[repr(4.0 + 0.2 * k), "2.0", "0", "0", "0", "0", "0", "1"] for k in range(9000)]
    (drive / "odometry.tum").write_text("".join(" ".join(r) + "\n" for r in [*before, *rows, *after]))
    assert main(["-q", "localize", str(drive), "--method", "icp,odom", "-o", str(drive.parent / "out")]) == 0
    assert "Error" not in capsys.readouterr().err
    odom = (drive.parent / "out" / "odom" / "trajectory.tum").read_text().splitlines()
    last = [float(v) for v in odom[-1].split()]
    assert last[1] == pytest.approx(0.5 * 3.9, abs=0.01)  # the wheels' 0.5 m/s over the scans
