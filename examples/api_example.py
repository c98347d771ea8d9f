"""rigcal's Python API from arrays in memory: calibrate with a box target and with a
checkerboard, save and read the rig, and localize a drive (docs/api.md).

The data are simulated here (with a known answer); with your own, build the same
``BoxCapture``/``BoardCapture`` records from your scans, picks and board corners
(docs/api.md says how to build a ``rigcal.Scan`` and a ``rigcal.Camera`` from arrays).

    python examples/api_example.py
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

import rigcal


def error_text(T: np.ndarray, T_true: np.ndarray) -> str:
    """The rotation (deg) and translation (mm) error of T_cam_laser against the truth."""
    R = T[:3, :3] @ T_true[:3, :3].T
    deg = float(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1.0, 1.0))))
    return f"error {deg:.3f} deg, {1000 * np.linalg.norm(T[:3, 3] - T_true[:3, 3]):.1f} mm"


def box_target() -> rigcal.Rig:
    """Algorithm 1 from scans and picked box ends."""
    from rigcal.sim.box_session import SessionSpec, generate_session

    sim = generate_session(SessionSpec(n_captures=12, seed=5))
    captures = [
        rigcal.BoxCapture(scan=c.scan, side=c.segment_id, image_endpoints_px=c.picked_pixels, name=c.name)
        for c in sim.captures
    ]
    sol = rigcal.solve_box(captures, sim.camera, range_sigma_m=0.01, T_truth=sim.T_cam_laser)
    s = sol.report["summary"]
    fit = f"{s['captures_used']}/{s['captures']} captures, {s['rms_px']:.2f} px RMS"
    print(f"box target: {fit}; {error_text(sol.rig.T_cam_laser, sim.T_cam_laser)}")
    return sol.rig


def checkerboard() -> rigcal.Rig:
    """The plane method from each board's corners in the image and its returns in the scan."""
    from rigcal.lines import extract_lines
    from rigcal.sim.board_session import BoardSpec, generate_board_session

    spec = BoardSpec(n_captures=10, seed=2)
    sim = generate_board_session(spec)
    board = rigcal.Board(spec.board.width_n, spec.board.height_n, spec.board.spacing_m)
    captures = []
    for c in sim.captures:
        # The board's corners as cv2.findChessboardCorners finds them, and its returns:
        # the scan's line on the board.
        segment = extract_lines(c.scan)[c.segment_id]
        captures.append(rigcal.BoardCapture(c.corners_px, segment.points, c.name))
    sol = rigcal.solve_board(
        captures, sim.camera, board, range_sigma_m=spec.range_sigma_m, corner_sigma_px=spec.corner_sigma_px
    )
    s = sol.report["summary"]
    fit = f"{s['captures_used']}/{s['captures']} captures, {s['rms_mm']:.1f} mm RMS"
    print(f"checkerboard: {fit}; {error_text(sol.rig.T_cam_laser, sim.T_cam_laser)}")
    return sol.rig


def drive(folder: Path) -> None:
    """Laser odometry through 20 s of a simulated office, scored against its truth, then
    the same scans fed one at a time, as a robot's loop would."""
    from rigcal.sim.drive import DriveSpec, write_drive
    from rigcal.sim.world import world_named

    spec = DriveSpec(laser_rate_hz=10.0, images=False, duration_s=20.0)
    write_drive(world_named("cubicle-loop"), spec, str(folder))
    runs = rigcal.localize(folder, ["icp"])
    m = runs["icp"].metrics
    assert m is not None
    print(
        f"localize: icp, {len(runs['icp'].stamps_s)} poses over {m['path_length_m']:.1f} m; "
        f"ATE {m['ate_rmse_m']:.3f} m, RPE 1 m {m['rpe_1m_rmse_m']:.3f} m"
    )
    odom = rigcal.LaserOdometry()
    for scan in rigcal.read_scans(folder):  # here from the folder; in a robot, from its driver
        x, y, yaw = odom.register_scan(scan)
    # The batch run's poses are in the truth's frame; the same step from the first pose:
    batch = runs["icp"].poses
    c, s = np.cos(batch[0, 2]), np.sin(batch[0, 2])
    last = np.array([[c, s], [-s, c]]) @ (batch[-1, :2] - batch[0, :2])
    same = bool(np.allclose([x, y, yaw], [*last, batch[-1, 2] - batch[0, 2]], atol=1e-9))
    print(f"streaming: {len(odom)} scans, last pose equal to the batch run's: {same}")
    rigcal.write_trajectory(folder / "odometry.tum", odom.trajectory())


def main() -> None:
    rig = box_target()
    checkerboard()
    with tempfile.TemporaryDirectory() as tmp:
        path = rigcal.write_rig(Path(tmp) / "rig.yaml", rig)
        again = rigcal.read_rig(path)
        assert np.allclose(again.T_cam_laser, rig.T_cam_laser, atol=1e-9)
        sig = again.sigmas()
        assert sig is not None
        print(
            f"rig file: 1-sigma rotation {np.round(sig.rotation_deg, 3).tolist()} deg, "
            f"translation {np.round(sig.translation_mm, 1).tolist()} mm"
        )
        drive(Path(tmp) / "drive")


if __name__ == "__main__":
    main()
