"""`rigcal localize` on sequence folders as real recordings and copies leave them: a corrupt
scans.npz, no images for an image method, a drive too short for a loop. One line naming
the file, the key and the value (exit 3), or a documented warning when the honest
answer is to go on; never a traceback or a half-written output."""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np
import pytest
import yaml

from rigcal.cli.main import main
from rigcal.recordings.sequence import write_sequence
from room_scans import room_scan

KEYS = "stamps_s, ranges_m, n_beams, angle_min_rad, angle_increment_rad, range_min_m, range_max_m"


def _sequence(folder: Path, n: int) -> Path:
    scans = [room_scan(0.05 * k, 0.1 * k) for k in range(n)]
    return write_sequence(folder, "room", scans, [], None, {"test": True})


@pytest.fixture
def seq(tmp_path) -> Path:
    return _sequence(tmp_path / "seq", 20)


def _arrays(seq: Path) -> dict[str, np.ndarray]:
    with np.load(seq / "scans.npz") as z:
        return dict(z)


def _not_a_zip(seq: Path) -> None:
    (seq / "scans.npz").write_bytes(b"hello, not numpy")


def _cut_short(seq: Path) -> None:
    data = (seq / "scans.npz").read_bytes()
    (seq / "scans.npz").write_bytes(data[: len(data) // 2])


def _missing_array(seq: Path) -> None:
    a = _arrays(seq)
    del a["n_beams"]
    np.savez(seq / "scans.npz", **a)


def _object_array(seq: Path) -> None:
    a = _arrays(seq)
    a["ranges_m"] = a["ranges_m"].astype(object)
    np.savez(seq / "scans.npz", **a)


def _text_ranges(seq: Path) -> None:
    a = _arrays(seq)
    a["ranges_m"] = a["ranges_m"].astype(str)
    np.savez(seq / "scans.npz", **a)


def _nanosecond_stamps(seq: Path) -> None:
    a = _arrays(seq)
    a["stamps_s"] = (a["stamps_s"] * 1e9).astype(np.int64)
    np.savez(seq / "scans.npz", **a)


def _garbage_member(seq: Path) -> None:
    with zipfile.ZipFile(seq / "scans.npz", "w") as z:
        z.writestr("stamps_s.npy", b"garbage")


def _a_folder(seq: Path) -> None:
    (seq / "scans.npz").unlink()
    (seq / "scans.npz").mkdir()


CORRUPT = [
    (_not_a_zip, "scans.npz: got a file starting b'hello, n'; expected a NumPy .npz archive of the scans"),
    (_cut_short, "scans.npz: got a zip archive cut short or broken (no table of contents at its end)"),
    (_missing_array, "scans.npz: n_beams: got no such array (it has angle_increment_rad, "),
    (_object_array, "scans.npz: ranges_m: got an unreadable array (Object arrays cannot be loaded"),
    (_text_ranges, "scans.npz: ranges_m: got '<U32 array of shape (20, 181)'; expected numbers"),
    (_nanosecond_stamps, "scans.npz: stamps_s: got 'int64 array'; expected seconds as floating-point"),
    (
        _garbage_member,
        f"scans.npz: ranges_m: got no such array (it has stamps_s); expected the arrays {KEYS}",
    ),
    (_a_folder, "scans.npz: got a folder; expected a NumPy .npz archive"),
]


@pytest.mark.parametrize(("spoil", "want"), CORRUPT, ids=[c[0].__name__.strip("_") for c in CORRUPT])
def test_a_corrupt_scans_file_is_one_line_naming_it(seq, fails, spoil, want):
    spoil(seq)
    line = fails(["localize", seq, "--method", "icp", "-o", seq.parent / "out"], 3)
    assert want in line


@pytest.mark.parametrize(
    ("methods", "named"), [("kf", "kf"), ("icp,iasm", "iasm"), ("vo,icp,hiasm", "vo,hiasm")]
)
def test_image_methods_without_images_name_what_is_missing_and_what_runs(seq, fails, methods, named):
    line = fails(["localize", seq, "--method", methods, "-o", seq.parent / "out"], 3)
    assert line == (
        f"Error: {seq / 'sequence.yaml'}: images.count: got 0; expected at least 2 images for "
        f"--method {named}; without images, --method icp,icp-p2p run"
    )
    fails(["localize", seq, "--method", methods, "--kf", "fixed", "-o", seq.parent / "out"], 3)


def test_loop_closure_on_five_scans_goes_on_and_says_why_nothing_closed(tmp_path, capsys):
    seq = _sequence(tmp_path / "five", 5)
    out = tmp_path / "out"
    assert main(["localize", str(seq), "--method", "icp", "--loop-closure", "-o", str(out)]) == 0
    err = capsys.readouterr().err
    (warning,) = [line for line in err.splitlines() if line.startswith("warning: ")]
    assert warning == (
        "warning: icp+lc: a path of 0.2 m over 5 poses, shorter than the 10 m a loop needs: no closure "
        "could be searched; the trajectory is the method's own"
    )
    doc = yaml.safe_load((out / "summary.yaml").read_text())
    lc = doc["methods"]["icp+lc"]
    assert lc["closures"]["proposed"] == 0
    assert lc["note"].startswith("a path of 0.2 m")
    icp = np.loadtxt(out / "icp" / "trajectory.tum")
    np.testing.assert_allclose(np.loadtxt(out / "icp+lc" / "trajectory.tum"), icp, atol=1e-9)
