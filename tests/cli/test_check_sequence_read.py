"""``rigcal check --sequence`` reads the drive on a second thread while its modules
import: a bad sequence is still one error line, exit code 3, and nothing logged."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rigcal.camera import Camera
from rigcal.cli.main import main
from rigcal.recordings.sequence import write_sequence
from rigcal.rig import Rig
from rigcal.rigfile import write_rig
from rigcal.scan import Scan
from rigcal.sim.box_session import default_T_cam_laser


@pytest.fixture
def rig_and_drive(tmp_path: Path) -> tuple[Path, Path]:
    K = np.array([[260.0, 0.0, 159.5], [0.0, 260.0, 119.5], [0.0, 0.0, 1.0]])
    camera = Camera.from_opencv(K, [0.0] * 5, 320, 240, source="test")
    write_rig(tmp_path / "rig.yaml", Rig(default_T_cam_laser(), camera, laser={"name": "test"}))
    scans = [Scan.from_uniform(-1.0, 0.5, [1.0, 2.0, 3.0], 0.1, 10.0, stamp_s=0.1 * i) for i in range(3)]
    return tmp_path / "rig.yaml", write_sequence(tmp_path / "drive", "d", scans, [], None, {})


def test_a_broken_scans_file_is_one_error_line(rig_and_drive, capsys):
    rig, drive = rig_and_drive
    (drive / "scans.npz").write_bytes(b"not a zip archive")
    code = main(["check", str(rig), "--sequence", str(drive)])
    err = capsys.readouterr().err
    assert code == 3
    npz = drive / "scans.npz"
    assert err.startswith(f"Error: {npz}: got a file starting b'not a zi'; expected a NumPy .npz")
    assert len(err.strip().splitlines()) == 1
    assert not (rig.parent / "rig.checks.jsonl").exists()


def test_a_step_that_stalls_the_angles_is_named(rig_and_drive, capsys):
    rig, drive = rig_and_drive
    with np.load(drive / "scans.npz") as z:
        arrays = {k: np.array(z[k]) for k in z.files}
    arrays["angle_min_rad"][1], arrays["angle_increment_rad"][1] = 6.0, 1e-17
    np.savez_compressed(drive / "scans.npz", **arrays)
    code = main(["check", str(rig), "--sequence", str(drive)])
    err = capsys.readouterr().err
    assert code == 3
    assert f"{drive / 'scans.npz'}: angle_increment_rad[1]: got 1e-17; expected a step" in err
