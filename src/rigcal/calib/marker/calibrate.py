"""A marker session, solved: the V marker target from file to rig and report.

Each kept capture gives two planes (the target's faces, each posed by the camera from its
own ChArUco corners, so the two poses' errors are independent) and the laser's returns on
each, the two arms of a V. The solve is the board method's
(:func:`rigcal.calib.board.plane.solve_plane`: point-to-plane on each face's cut, whitened by the
range noise, the face pose's covariance and a per-face error estimated from the data,
Cauchy loss, chi-square verdicts, covariance, leave-one-out spread, sensitivity), on the
2 x captures face observations. The apex, where the V's arms meet in the scan, must lie
on the faces' common edge; both cuts lying on their planes already put it there, so it
adds no constraint of its own: it is reported per capture (its distance from the edge the
camera sees) as a check of the pair.

Beyond the board report: the captures the target was found in (and why the others were
not), markers of other targets, a scale check (laser against camera: a pattern printed at
the wrong scale puts every face at the wrong distance by the same factor) and the
geometry of the views (which direction the face normals leave unobserved and what view
to add).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import numpy as np

from rigcal.arrays import FloatArray
from rigcal.calib.board.calibrate import (
    DEFAULT_RANGE_SIGMA_M,
    RIG_RESIDUAL_KEYS,
    board_report,
    board_report_table,
    plane_rig,
)
from rigcal.calib.board.plane import LOSS, PlaneResult, solve_plane
from rigcal.calib.marker.session import MarkerSession, fit_scale, read_marker_session, with_corner_scale
from rigcal.calib.noise import corner_sigma_from_rms
from rigcal.calib.options import NOISE_MODES
from rigcal.calib.report import noise_section
from rigcal.calib.truth import read_truth
from rigcal.rig import Rig

# The views are weak in a direction when the face normals' (laser frame) smallest
# singular value is under this share of the largest.
WEAK_NORMAL_SPREAD = 0.3
# All views at about one distance when the faces' distances spread less than this.
MIN_DISTANCE_SPREAD_M = 0.2
# A scale ratio farther from 1 than this and than 3 sigma is reported.
SCALE_TOLERANCE = 0.005


@dataclass(frozen=True)
class MarkerCalibration:
    """A finished marker calibration: the session, the solve, its report and the rig."""

    session: MarkerSession
    result: PlaneResult
    report: dict[str, Any]
    rig: Rig


def calibrate_marker(
    path: str | Path,
    range_sigma_m: float | None = None,
    truth_path: str | Path | None = None,
    command: str = "",
    seed: int = 0,
    noise: str = "auto",
    range_bias: bool = True,
    loss: str = LOSS,
    joint: bool = True,
) -> MarkerCalibration:
    """Read a marker session, detect, solve, build the report and the rig.

    The arguments are :func:`rigcal.calib.board.calibrate.calibrate_board`'s; with
    ``noise="auto"`` the corner noise is estimated from the faces' corner reprojection
    residuals and the range noise from the cuts' line fits. ``joint``:
    :func:`read_marker_session`'s (False: each face posed on its own).

    Raises:
        InputError: a bad session, targets or truth file.
        CalibrationError: too few captures with the target found, or no consensus.
    """
    if noise not in NOISE_MODES:
        raise ValueError(f"noise must be one of {NOISE_MODES}")
    T_truth = read_truth(truth_path) if truth_path is not None else None
    session = read_marker_session(path, joint)
    assumed = max(range_sigma_m or float(session.laser.get("range_sigma_m", DEFAULT_RANGE_SIGMA_M)), 1e-4)
    # Pooled over the poses the planes came from, with their own corner counts
    # (corner_sigma_from_rms per pose: 2 n - 6 degrees of freedom).
    fits = [(r, n) for r, n in session.pose_fits if n > 3]
    ss = sum(corner_sigma_from_rms(np.array([r]), int(n)) ** 2 * (2 * n - 6) for r, n in fits)
    corner_est = float(np.sqrt(ss / max(sum(2 * n - 6 for _, n in fits), 1)))
    corner_used = session.corner_sigma_px
    observations = session.observations
    if noise == "auto":
        corner_used = max(corner_est, 0.01)
        observations = with_corner_scale(session, (corner_used / session.corner_sigma_px) ** 2)
    result = solve_plane(
        list(observations),
        range_sigma_m=assumed if noise == "assumed" else None,
        seed=seed,
        corner_sigma_px=corner_used,
        fit_range_bias=range_bias,
        loss=loss,
    )
    estimated = result.range_noise.sigma_m if result.range_noise is not None else None
    noise_doc = noise_section(
        {
            "range_sigma_m": (assumed, estimated, result.noise.range_sigma_m),
            "corner_sigma_px": (session.corner_sigma_px, corner_est, corner_used),
        }
    )
    report = marker_report(session, result, T_truth, noise_doc)
    rig = plane_rig(
        session,
        result,
        report,
        noise_doc,
        "marker V target (ChArUco faces, plane method)",
        ("captures", "captures_found", *RIG_RESIDUAL_KEYS[1:]),
        command=command,
        inputs=session.files,
        base=Path(path).resolve().parent,
        noise=noise,
        range_bias=range_bias,
        seed=seed,
        loss=loss,
    )
    return MarkerCalibration(session, result, report, rig)


def marker_report(
    session: MarkerSession, result: PlaneResult, T_truth: Any = None, noise: dict[str, Any] | None = None
) -> dict[str, Any]:
    """The report of a marker solve (docs/formats/report.md, marker variant): the board
    report over the face observations, its summary counting captures, and a ``marker``
    section."""
    report = board_report(cast(Any, session), result, T_truth, noise)
    s = report["summary"]
    used_faces = result.inlier_captures.reshape(-1, 2)
    summary = {
        "method": "marker",
        "captures": len(session.captures),
        "captures_found": len(session.found),
        "found_share": round(len(session.found) / len(session.captures), 4),
        "captures_used": int(used_faces.all(axis=1).sum()),
        "faces_used": s["captures_used"],
    }
    report["summary"] = summary | {
        k: v for k, v in s.items() if k not in ("method", "captures", "captures_used")
    }
    for j, c in enumerate(report["per_capture"]):
        view = session.views[j // 2]
        f = view.faces[j % 2]
        c["corners"] = 0 if f is None else len(f.corner_ids)
        c["scans"] = session.scans_per_capture.get(session.found[j // 2], 1)
    apex = apex_distances(session, result)
    scale, scale_sigma = scale_check(session, result)
    foreign = sorted({i for ids in session.foreign_ids.values() for i in ids})
    report["marker"] = {
        "target": session.target.name,
        "dictionary": session.target.dictionary,
        "dropped": [{"capture": n, "reason": r} for n, r in session.dropped],
        "foreign_markers": {"captures": len(session.foreign_ids), "ids": foreign},
        "apex_mm": {
            n: round(1000.0 * float(a), 2) if np.isfinite(a) else None
            for n, a in zip(session.found, apex, strict=True)
        },
        "scale": {"ratio": round(scale, 5), "sigma": round(scale_sigma, 5)},
    }
    warnings = [w for w in report["warnings"] if not w.startswith("large uncertainty")]
    warnings = [w.replace("check its segment id and corners", "check its markers and scan") for w in warnings]
    for n, r in session.dropped:
        warnings.append(f"capture {n}: target not found ({r}); set aside")
    for n, r in session.disagreements:
        warnings.append(f"capture {n}: {r}")
    if not session.rigid and session.joint:
        warnings.append(
            f"the faces disagree with the targets file's geometry in {len(session.disagreements)} of "
            f"{len(session.found)} captures: each face was posed on its own from its own corners; check the "
            "targets file (angle_deg, offset_m, square_m) against the target and the print's measuring bar"
        )
    if foreign:
        warnings.append(
            f"{sum(len(v) for v in session.foreign_ids.values())} markers of another target "
            f"(ids {foreign[:10]}) seen in {len(session.foreign_ids)} captures; ignored"
        )
    if abs(scale - 1.0) > max(SCALE_TOLERANCE, 3.0 * scale_sigma):
        warnings.append(
            f"scale disagreement: the laser puts the faces {scale:.4f} +- {scale_sigma:.4f} times as far as "
            "the camera does; check the printed measuring bar (a print at the wrong scale) and the "
            "camera's focal length"
        )
    warnings += geometry_warnings(session, result)
    report["warnings"] = warnings
    return report


def apex_distances(session: MarkerSession, result: PlaneResult) -> FloatArray:
    """(K,) per kept capture, the distance of the V's apex in the scan (the two cut lines'
    intersection, mapped by the solved pose) from the faces' common edge seen by the
    camera (the intersection of the two face planes), metres."""
    T = result.T_cam_laser
    out = []
    for j in range(len(session.found)):
        la, lb = result.lines[2 * j].fit, result.lines[2 * j + 1].fit
        # Lines c + s u in the laser plane: their intersection.
        A = np.column_stack([la.direction, -lb.direction])
        if abs(np.linalg.det(A)) < 1e-9:
            out.append(np.nan)
            continue
        s = np.linalg.solve(A, lb.centroid - la.centroid)
        apex = T[:3, :2] @ (la.centroid + s[0] * la.direction) + T[:3, 3]
        oa, ob = session.observations[2 * j], session.observations[2 * j + 1]
        na, nb = np.asarray(oa.normal_cam), np.asarray(ob.normal_cam)
        u = np.cross(na, nb)
        u /= np.linalg.norm(u)
        # A point on both planes: least-norm solution of [na; nb] p = [da, db].
        p0 = np.linalg.lstsq(np.vstack([na, nb]), np.array([oa.distance_m, ob.distance_m]), rcond=None)[0]
        r = apex - p0
        out.append(float(np.linalg.norm(r - (r @ u) * u)))
    return np.array(out)


def scale_check(session: MarkerSession, result: PlaneResult) -> tuple[float, float]:
    """The ratio by which the laser puts the faces farther than the camera does, and its
    1-sigma: the pose refitted with every face's distance multiplied by a free factor s,
    n . (R p + t) = s d, on the cut ends of the used faces (unweighted; the sigma from the
    fit's residual scale). The returns are taken as the scanner gives them, with no range
    bias by incidence taken out: the solve's bias would absorb part of a scale.

    The planes are the faces' own poses (each from its own corners) where a face has one:
    a pattern printed at the wrong scale puts each face at the wrong distance by the print's
    factor, while the one target pose over both faces, fitted to patterns of the wrong
    size at the right offsets, takes up an unknown part of it. Faces without an own pose
    use the target's."""
    used = np.flatnonzero(result.inlier_captures)
    planes = []
    for i in used:
        o = session.observations[i]
        own = session.views[i // 2].faces[i % 2]
        if own is not None and own.T_cam_face is not None:
            n = own.T_cam_face[:3, 2]
            d = float(n @ own.T_cam_face[:3, 3])
            planes.append((n, d) if d > 0 else (-n, -d))
        else:
            planes.append((np.asarray(o.normal_cam), o.distance_m))
    return fit_scale(result.T_cam_laser, planes, [result.lines[i].ends for i in used])


_AXES = ("forward (laser x)", "sideways (laser y)", "up-down (laser z)")


def geometry_warnings(session: MarkerSession, result: PlaneResult) -> list[str]:
    """Which direction the views leave weakly observed, and what view to add.

    The laser frame's face normals must point in every direction: a normal with no
    up-down part (an upright face) says nothing of the laser's height, roll or pitch, so
    upright views leave those to the covariance alone; the faces' distances must vary, or
    translation trades against rotation.
    """
    used = np.flatnonzero(result.inlier_captures)
    R = result.T_cam_laser[:3, :3]
    normals = np.array([R.T @ np.asarray(session.observations[i].normal_cam) for i in used])
    out = weak_views(normals, np.array([session.observations[i].distance_m for i in used]))
    sig = np.sqrt(np.clip(np.diag(result.covariance), 0.0, None))
    if np.degrees(sig[:3]).max() > 0.2 or 1000 * sig[3:].max() > 5.0:
        k = int(np.argmax(1000 * sig[3:]))
        out.append(
            f"large uncertainty (1 sigma up to {np.degrees(sig[:3]).max():.3f} deg, "
            f"{1000 * sig[3:].max():.1f} mm along camera {'xyz'[k]}): add views with the target turned, "
            "tilted and rolled more"
        )
    return out


def weak_views(normals_laser: FloatArray, distances_m: FloatArray) -> list[str]:
    """Warnings on the views' geometry from the used faces' (K, 3) unit normals in the
    laser frame and their (K,) distances from the camera (see :func:`geometry_warnings`)."""
    _, sv, Vt = np.linalg.svd(normals_laser, full_matrices=False)
    out = []
    if sv[-1] < WEAK_NORMAL_SPREAD * sv[0]:
        k = int(np.argmax(np.abs(Vt[-1])))
        what = "the laser's height, roll and pitch" if k == 2 else "the laser's position and turn along it"
        out.append(
            f"weak geometry: the faces' normals hardly point {_AXES[k]} (spread {sv[-1] / sv[0]:.2f} < "
            f"{WEAK_NORMAL_SPREAD}), so {what} rest on few views; add views with the target tilted "
            "20-30 degrees (its top towards and away from the rig) and rolled 20-30 degrees both ways"
        )
    if np.ptp(distances_m) < MIN_DISTANCE_SPREAD_M:
        out.append(
            f"weak geometry: every face within {np.ptp(distances_m):.2f} m of one distance "
            f"({float(np.mean(distances_m)):.2f} m); add views nearer and farther"
        )
    return out


def marker_report_table(report: dict[str, Any]) -> str:
    """Readable summary of a marker solve: the board table over faces, then the captures found."""
    s = report["summary"]
    m = report["marker"]
    head = [
        f"marker target {m['target']!r} ({m['dictionary']}): found in {s['captures_found']}/{s['captures']} "
        f"captures ({100 * s['found_share']:.0f} %), {s['captures_used']} used with both faces; "
        f"scale laser/camera {m['scale']['ratio']:.4f} +- {m['scale']['sigma']:.4f}",
    ]
    apex = [a for a in m["apex_mm"].values() if a is not None]
    if apex:
        head.append(
            f"apex off the faces' edge: median {float(np.median(apex)):.1f} mm, max {max(apex):.1f} mm"
        )
    board_like = dict(report)
    board_like["summary"] = dict(s) | {"captures": 2 * s["captures_found"], "captures_used": s["faces_used"]}
    table = (
        board_report_table(board_like).replace("captures ", "faces ", 1).replace("capture  ", "face     ", 1)
    )
    return "\n".join(head) + "\n" + table
