"""`rigcal check --sequence` with a rig whose camera is not the drive's: another lens model
or image size named by the drive's own rig.yaml or camera.yaml is one line naming that file,
the key, both values and "a drive of another rig?" (exit 3), never a verdict."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from room_scans import room_drive


@pytest.fixture
def drive(tmp_path) -> Path:
    return room_drive(tmp_path)


def _rig(path: Path, **camera) -> Path:
    doc = yaml.safe_load(path.read_text())
    doc["camera"].update(camera)
    out = path.parent / "other.yaml"
    out.write_text(yaml.safe_dump(doc))
    return out


def test_a_rig_of_another_lens_model(drive, fails):
    other = _rig(
        drive.parent / "rig.yaml", lensmodel="LENSMODEL_PINHOLE", intrinsics=[50.0, 50.0, 31.5, 23.5]
    )
    line = fails(["check", other, "--sequence", drive, "--no-log"], 3)
    assert line == (
        f"Error: {drive / 'rig.yaml'}: lensmodel: got 'LENSMODEL_OPENCV5'; expected 'LENSMODEL_PINHOLE', "
        f"the rig's camera ({other}): a drive of another rig?"
    )


def test_the_drives_own_camera_file_of_another_size(drive, fails):
    doc = yaml.safe_load((drive / "sequence.yaml").read_text())
    doc["camera"] = "camera.yaml"
    (drive / "sequence.yaml").write_text(yaml.safe_dump(doc))
    K = [[50.0, 0.0, 63.5], [0.0, 50.0, 47.5], [0.0, 0.0, 1.0]]
    cam = {"schema_version": 1, "image_width_px": 128, "image_height_px": 96, "K": K, "distortion": [0.0] * 5}
    (drive / "camera.yaml").write_text(yaml.safe_dump(cam))
    line = fails(["check", drive.parent / "rig.yaml", "--sequence", drive, "--no-log"], 3)
    assert f"{drive / 'camera.yaml'}: image size: got '128x96'; expected 64x48, the rig's camera" in line
