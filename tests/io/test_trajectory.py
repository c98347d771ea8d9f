"""TUM and KITTI trajectory files: round trips, golden files, and errors naming file and line."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rigcal.errors import InputError, OutputError
from rigcal.geometry import make_T, random_rotation
from rigcal.io.trajectory import Trajectory, read_kitti, read_tum, write_kitti, write_tum

GOLDEN_TUM = """\
# ground truth trajectory
# timestamp tx ty tz qx qy qz qw
1305031102.1758 1.3405 0.6266 1.6575 0.6574 0.6126 -0.2949 -0.3248

1305031102.2758 1.3303 0.6256 1.6464 0.6579 0.6161 -0.2932 -0.3189  # trailing comment
1305031102.3758 -2.5 0 1e-3 0 0 0 1
"""

# The second pose is turned 90 degrees about z and sits at (1.5, -0.25, 2).
GOLDEN_KITTI = (
    "1.000000e+00 0.000000e+00 0.000000e+00 0.000000e+00 0.000000e+00 1.000000e+00 "
    "0.000000e+00 0.000000e+00 0.000000e+00 0.000000e+00 1.000000e+00 0.000000e+00\n"
    "0 -1 0 1.5 1 0 0 -0.25 0 0 1 2\n"
)


def random_trajectory(seed: int, n: int = 20, stamps: bool = True) -> Trajectory:
    rng = np.random.default_rng(seed)
    poses = np.array([make_T(random_rotation(rng), rng.uniform(-50.0, 50.0, 3)) for _ in range(n)])
    t = 1.7e9 + np.cumsum(rng.uniform(0.01, 0.2, n)) if stamps else None
    return Trajectory(poses, t)


def write(tmp_path: Path, text: str, name: str = "traj.txt") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def tum_error(path: Path) -> str:
    with pytest.raises(InputError) as info:
        read_tum(path)
    return str(info.value)


def kitti_error(path: Path) -> str:
    with pytest.raises(InputError) as info:
        read_kitti(path)
    return str(info.value)


IDENTITY_TUM = "0 0 0 0 0 0 0 1"
IDENTITY_KITTI = "1 0 0 0 0 1 0 0 0 0 1 0"


# --- round trips ---------------------------------------------------------------------------


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_tum_round_trip(seed, tmp_path):
    traj = random_trajectory(seed)
    back = read_tum(write_tum(tmp_path / "traj.tum", traj))
    assert back.stamps_s is not None
    assert traj.stamps_s is not None
    np.testing.assert_array_equal(back.stamps_s, traj.stamps_s)
    np.testing.assert_allclose(back.poses, traj.poses, rtol=0, atol=1e-12)
    assert len(back) == 20


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_kitti_round_trip(seed, tmp_path):
    traj = random_trajectory(seed, stamps=False)
    back = read_kitti(write_kitti(tmp_path / "traj.kitti", traj))
    assert back.stamps_s is None
    np.testing.assert_allclose(back.poses, traj.poses, rtol=0, atol=1e-12)


def test_tum_writer_states_the_field_order(tmp_path):
    text = write_tum(tmp_path / "traj.tum", random_trajectory(3, n=2)).read_text()
    assert text.splitlines()[0] == "# timestamp tx ty tz qx qy qz qw"
    assert len(text.splitlines()) == 3


def test_tum_writer_needs_stamps(tmp_path):
    with pytest.raises(ValueError, match="time stamps"):
        write_tum(tmp_path / "traj.tum", random_trajectory(3, stamps=False))
    assert not (tmp_path / "traj.tum").exists()


# --- golden files --------------------------------------------------------------------------


def test_tum_golden_file(tmp_path):
    traj = read_tum(write(tmp_path, GOLDEN_TUM))
    assert traj.stamps_s is not None
    assert traj.stamps_s.tolist() == [1305031102.1758, 1305031102.2758, 1305031102.3758]
    np.testing.assert_array_equal(traj.poses[0][:3, 3], [1.3405, 0.6266, 1.6575])
    q = np.array([0.6574, 0.6126, -0.2949, -0.3248])  # x, y, z, w; norm 0.99996
    np.testing.assert_allclose(traj.poses[0][:3, :3], Rotation.from_quat(q / np.linalg.norm(q)).as_matrix())
    np.testing.assert_array_equal(traj.poses[2], make_T(np.eye(3), [-2.5, 0.0, 1e-3]))


def test_tum_scalar_last_quaternion_order(tmp_path):
    # qz = qw = sqrt(1/2): 90 degrees about z, so body x points along world y.
    s = float(np.sqrt(0.5))
    traj = read_tum(write(tmp_path, f"0 1 2 3 0 0 {s!r} {s!r}\n"))
    np.testing.assert_allclose(traj.poses[0][:3, 0], [0.0, 1.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(traj.poses[0][:3, 2], [0.0, 0.0, 1.0], atol=1e-15)


def test_kitti_golden_file(tmp_path):
    traj = read_kitti(write(tmp_path, GOLDEN_KITTI))
    assert traj.stamps_s is None
    np.testing.assert_array_equal(traj.poses[0], np.eye(4))
    expected = np.array([[0.0, -1, 0, 1.5], [1, 0, 0, -0.25], [0, 0, 1, 2], [0, 0, 0, 1]])
    np.testing.assert_array_equal(traj.poses[1], expected)


def test_kitti_accepts_commas_and_comments(tmp_path):
    traj = read_kitti(write(tmp_path, "# pose 0\n" + IDENTITY_KITTI.replace(" ", ", ") + "\n"))
    np.testing.assert_array_equal(traj.poses, [np.eye(4)])


# --- errors --------------------------------------------------------------------------------


def test_tum_wrong_field_count(tmp_path):
    path = write(tmp_path, f"{IDENTITY_TUM}\n\n1 0 0 0 0 0 1\n")
    message = tum_error(path)
    assert message.startswith(f"{path}: line 3:")
    assert "got 7 fields; expected 8" in message


def test_kitti_wrong_field_count(tmp_path):
    path = write(tmp_path, f"{IDENTITY_KITTI} 0\n")
    message = kitti_error(path)
    assert message.startswith(f"{path}: line 1:")
    assert "got 13 fields; expected 12" in message


def test_tum_non_number(tmp_path):
    path = write(tmp_path, f"# header\n{IDENTITY_TUM}\n1 0 0 zero 0 0 0 1\n")
    message = tum_error(path)
    assert message.startswith(f"{path}: line 3:")
    assert "zero" in message
    assert "8 numbers" in message


def test_kitti_non_number(tmp_path):
    path = write(tmp_path, IDENTITY_KITTI.replace("1 0 0 0", "1 0 0 x", 1) + "\n")
    message = kitti_error(path)
    assert message.startswith(f"{path}: line 1:")
    assert "12 numbers" in message


@pytest.mark.parametrize("value", ["nan", "inf", "-inf"])
def test_tum_non_finite(value, tmp_path):
    path = write(tmp_path, f"{IDENTITY_TUM}\n1 0 {value} 0 0 0 0 1\n")
    message = tum_error(path)
    assert message.startswith(f"{path}: line 2:")
    assert "non-finite" in message


def test_kitti_non_finite(tmp_path):
    path = write(tmp_path, f"{IDENTITY_KITTI}\n{IDENTITY_KITTI[:-1]}nan\n")
    message = kitti_error(path)
    assert message.startswith(f"{path}: line 2:")
    assert "non-finite" in message


@pytest.mark.parametrize("q", ["0 0 0 2", "0 0 0 0", "0.5 0.5 0.5 0.51"])
def test_tum_non_unit_quaternion(q, tmp_path):
    path = write(tmp_path, f"0 1 2 3 {q}\n")
    message = tum_error(path)
    assert message.startswith(f"{path}: line 1:")
    assert "unit quaternion" in message


def test_tum_nearly_unit_quaternion_is_normalised(tmp_path):
    traj = read_tum(write(tmp_path, "0 1 2 3 0 0 0 1.0005\n"))
    np.testing.assert_allclose(traj.poses[0], make_T(np.eye(3), [1, 2, 3]), atol=1e-15)


@pytest.mark.parametrize("second", ["1.5", "1.0"])
def test_tum_non_increasing_timestamps(second, tmp_path):
    path = write(tmp_path, f"1.0 0 0 0 0 0 0 1\n{second} 0 0 0 0 0 0 1\n0.5 0 0 0 0 0 0 1\n")
    message = tum_error(path)
    line = 3 if second == "1.5" else 2
    assert message.startswith(f"{path}: line {line}:")
    assert "expected increasing" in message
    assert "np.float64" not in message
    assert f"timestamp {0.5 if line == 3 else 1.0} not after" in message


@pytest.mark.parametrize(
    "matrix",
    [
        "2 0 0 0 0 1 0 0 0 0 1 0",  # scaled
        "1 0 0 0 0 1 0 0 0 0 -1 0",  # reflection
        "1 0.01 0 0 0 1 0 0 0 0 1 0",  # sheared
    ],
)
def test_kitti_non_rotation(matrix, tmp_path):
    path = write(tmp_path, f"{IDENTITY_KITTI}\n{matrix}\n")
    message = kitti_error(path)
    assert message.startswith(f"{path}: line 2:")
    assert "not a rotation matrix" in message


@pytest.mark.parametrize("text", ["", "\n\n", "# comments only\n#\n"])
def test_empty_files(text, tmp_path):
    path = write(tmp_path, text)
    assert tum_error(path).startswith(f"{path}: no poses")
    assert kitti_error(path).startswith(f"{path}: no poses")


def test_missing_files(tmp_path):
    path = tmp_path / "nope.txt"
    assert tum_error(path) == f"{path}: trajectory file not found"
    assert kitti_error(path) == f"{path}: trajectory file not found"


def test_non_utf8_file(tmp_path):
    path = tmp_path / "traj.txt"
    path.write_bytes(b"0 0 0 0 0 0 0 1 \xff\n")
    assert tum_error(path).startswith(f"{path}: line 1: got byte 0xFF, not UTF-8; expected UTF-8 text")


# --- overwrite refusal ---------------------------------------------------------------------


@pytest.mark.parametrize("writer", [write_tum, write_kitti])
def test_writers_refuse_to_overwrite_without_force(writer, tmp_path):
    path = write(tmp_path, "keep me")
    traj = random_trajectory(4, n=3)
    with pytest.raises(OutputError, match="--force"):
        writer(path, traj)
    assert path.read_text() == "keep me"
    writer(path, traj, force=True)
    assert path.read_text() != "keep me"
    reader = read_tum if writer is write_tum else read_kitti
    np.testing.assert_allclose(reader(path).poses, traj.poses, atol=1e-12)


@pytest.mark.parametrize(
    ("stamp", "unit"),
    [("1700000000123", "milliseconds"), ("1700000000123456", "microseconds"), ("1.7e18", "nanoseconds")],
)
def test_tum_stamps_in_another_unit_are_named(tmp_path, stamp, unit):
    # A ROS 2 or logger export stamped in ns (us, ms Unix time) is not seconds.
    path = write(tmp_path, f"{stamp} 0 0 0 0 0 0 1\n")
    assert tum_error(path) == (
        f"{path}: line 1: timestamp: got {float(stamp)!r}; expected seconds (Unix time is about 1.7e9 s; "
        f"this looks like {unit}: convert to seconds)"
    )


@pytest.mark.parametrize("header", ["timestamp tx ty tz qx qy qz qw", "t,x,y,z,qx,qy,qz,qw"])
def test_tum_header_line_without_its_hash_is_named(tmp_path, header):
    path = write(tmp_path, f"{header}\n{IDENTITY_TUM}\n")
    message = tum_error(path)
    assert message.startswith(f"{path}: line 1: got ")
    assert message.endswith("expected 8 numbers (a header line? start it with '#' to make it a comment)")
    # A word among numbers is a broken pose, not a header.
    assert "header line" not in tum_error(write(tmp_path, f"{IDENTITY_TUM}\n1 0 0 zero 0 0 0 1\n"))
