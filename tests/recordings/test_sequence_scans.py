"""A sequence's scans read all at once (rigcal.scan.uniform_scans) against the scan-by-scan
construction they replace, bit for bit, on odd values."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from rigcal.errors import InputError
from rigcal.recordings.sequence import read_sequence, write_sequence
from rigcal.scan import Scan, ScanArrayError, counter_clockwise, uniform_scans

Arrays = dict[str, np.ndarray]


def _reference(a0: float, step: float, ranges: np.ndarray, lo: float, hi: float, stamp: float) -> dict:
    """One scan as the reader built it before, scan by scan (angles, validity and points
    written out as Scan.__post_init__ computes them; a range at range_max is no return)."""
    r = np.array(ranges, dtype=float)
    a = a0 + step * np.arange(len(r), dtype=np.float64)
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(r) & (r > 0.0) & (r >= lo) & (r < hi)
    pts = np.full((len(r), 2), np.nan)
    w = np.where(a > np.pi, a - 2.0 * np.pi, np.where(a < -np.pi, a + 2.0 * np.pi, a))[valid]
    pts[valid, 0] = r[valid] * np.cos(w)
    pts[valid, 1] = r[valid] * np.sin(w)
    return {"angles": a, "ranges": r, "valid": valid, "points": pts, "fields": (lo, hi, stamp, step)}


def _same(scan: Scan, ref: dict) -> None:
    assert np.array_equal(scan.angles_rad, ref["angles"])
    assert np.array_equal(scan.ranges_m, ref["ranges"], equal_nan=True)
    assert np.array_equal(scan.valid, ref["valid"])
    assert np.array_equal(scan.points, ref["points"], equal_nan=True)
    assert (scan.range_min_m, scan.range_max_m, scan.stamp_s, scan.angle_increment_rad) == ref["fields"]
    for x in (scan.angles_rad, scan.ranges_m, scan.valid, scan.points):
        assert not x.flags.writeable


def _odd_arrays(seed: int, n: int = 60, width: int = 50) -> Arrays:
    """Scans of several widths (padding beyond each one's beams: NaN or junk), ranges with
    NaN, +inf, 0, below range_min and above range_max, angles beyond +-pi."""
    rng = np.random.default_rng(seed)
    ranges = rng.uniform(0.0, 12.0, (n, width))
    odd = rng.random((n, width))
    ranges[odd < 0.05] = np.nan
    ranges[(odd >= 0.05) & (odd < 0.1)] = np.inf
    ranges[(odd >= 0.1) & (odd < 0.13)] = 0.0
    nb = rng.integers(1, width + 1, n)
    nb[:3] = (1, 2, width)
    for i, k in enumerate(nb):
        ranges[i, k:] = np.nan if i % 2 else rng.uniform(0.0, 5.0, width - k)  # padding
    lo = rng.choice([0.0, 0.1, 0.5], n)
    hi = rng.choice([5.0, 10.0, 30.0], n)
    ranges[4, :3] = (lo[4], hi[4], np.nextafter(hi[4], np.inf))  # at and just past the limits
    a0 = rng.uniform(-2 * np.pi, np.pi, n)
    a0[5] = 0.0  # a 0..2pi scanner
    step = rng.uniform(0.01, 2 * np.pi / width, n)
    return {
        "angle_min_rad": a0,
        "angle_increment_rad": step,
        "ranges_m": ranges,
        "n_beams": nb,
        "range_min_m": lo,
        "range_max_m": hi,
        "stamps_s": np.cumsum(rng.uniform(0.01, 0.05, n)),
    }


def _expected(z: Arrays, clockwise: bool) -> list[dict]:
    out = []
    for i in range(len(z["stamps_s"])):
        k = int(z["n_beams"][i])
        args = (float(z["angle_min_rad"][i]), float(z["angle_increment_rad"][i]), z["ranges_m"][i, :k])
        lims = (float(z["range_min_m"][i]), float(z["range_max_m"][i]), float(z["stamps_s"][i]))
        if clockwise:  # counter_clockwise()'s turn: the first angle is minus the last one
            first = -(args[0] + args[1] * 0.0 + args[1] * (k - 1))
            args = (first, args[1], args[2][::-1])
        out.append(_reference(args[0], args[1], args[2], *lims))
    return out


@pytest.mark.parametrize("clockwise", [False, True])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_uniform_scans_are_the_scan_by_scan_construction_bit_for_bit(seed: int, clockwise: bool) -> None:
    z = _odd_arrays(seed)
    scans = uniform_scans(**z, clockwise=clockwise)
    expected = _expected(z, clockwise)
    assert len(scans) == len(expected)
    for scan, ref in zip(scans, expected, strict=True):
        _same(scan, ref)
    # and Scan itself (from_uniform, counter_clockwise) still builds the same scans
    i = 7
    k = int(z["n_beams"][i])
    one = Scan.from_uniform(
        float(z["angle_min_rad"][i]),
        float(z["angle_increment_rad"][i]),
        z["ranges_m"][i, :k],
        float(z["range_min_m"][i]),
        float(z["range_max_m"][i]),
        stamp_s=float(z["stamps_s"][i]),
    )
    _same(counter_clockwise(one) if clockwise else one, expected[i])


def test_whole_number_ranges_read_as_floats() -> None:
    z = _odd_arrays(3, n=8)
    z["ranges_m"] = np.nan_to_num(z["ranges_m"], nan=0.0, posinf=0.0).astype(np.int64)
    for scan, ref in zip(uniform_scans(**z), _expected(z, False), strict=True):
        _same(scan, ref)


def _write(tmp_path: Path, z: Arrays, clockwise: bool = False) -> Path:
    n = len(z["stamps_s"])
    scans = [Scan.from_uniform(-1.0, 0.5, [1.0, 2.0], 0.1, 10.0, stamp_s=float(t)) for t in z["stamps_s"]]
    folder = write_sequence(tmp_path / "seq", "odd", scans, [], None, {})
    assert n == len(scans)
    np.savez_compressed(folder / "scans.npz", **z)  # type: ignore[arg-type]
    if clockwise:
        text = (folder / "sequence.yaml").read_text().replace("schema_version: 1", "schema_version: 2")
        (folder / "sequence.yaml").write_text(text + "laser: {clockwise: true}\n")
    return folder


@pytest.mark.parametrize("clockwise", [False, True])
def test_read_sequence_reads_odd_scans_as_before(tmp_path: Path, clockwise: bool) -> None:
    z = _odd_arrays(4)
    seq = read_sequence(_write(tmp_path, z, clockwise))
    for scan, ref in zip(seq.scans, _expected(z, clockwise), strict=True):
        _same(scan, ref)


def test_written_scans_read_back_bit_for_bit(tmp_path: Path) -> None:
    """write_sequence pads the narrower scans with NaN; reading gives the same scans."""
    rng = np.random.default_rng(5)
    scans = [
        Scan.from_uniform(rng.uniform(-3, 0), 0.01, rng.uniform(0, 9, k), 0.05, 8.0, stamp_s=0.1 * j)
        for j, k in enumerate((5, 40, 1, 17))
    ]
    seq = read_sequence(write_sequence(tmp_path / "seq", "w", scans, [], None, {}))
    for got, want in zip(seq.scans, scans, strict=True):
        fields = (want.range_min_m, want.range_max_m, want.stamp_s, want.angle_increment_rad)
        ref = {"angles": want.angles_rad, "ranges": want.ranges_m, "valid": want.valid, "points": want.points}
        _same(got, ref | {"fields": fields})


def test_a_step_too_small_for_the_angles_to_rise_is_bad_input(tmp_path: Path) -> None:
    z = _odd_arrays(6, n=8)
    z["angle_min_rad"][2], z["angle_increment_rad"][2], z["n_beams"][2] = 6.0, 1e-17, 5
    folder = _write(tmp_path, z)
    npz = folder / "scans.npz"
    want = f"{npz}: angle_increment_rad[2]: got 1e-17; expected a step that makes the beams' angles increase"
    with pytest.raises(InputError, match=re.escape(want)):
        read_sequence(folder)
    with pytest.raises(ScanArrayError, match=re.escape("scan 2: angle_increment_rad: expected a step")):
        uniform_scans(**z)


def test_range_limits_out_of_order_are_refused() -> None:
    z = _odd_arrays(7, n=8)
    z["range_min_m"][3] = z["range_max_m"][3]
    with pytest.raises(ScanArrayError, match=re.escape("scan 3: range_min_m: expected 0 <= range_min_m")):
        uniform_scans(**z)
