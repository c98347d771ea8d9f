"""Trajectory errors as the paper's Table 1 reports them, and as evo computes them.

All trajectories are planar poses (x, y, yaw) of the same frame at the same stamps.

- Loop-closure error (Table 1): for a drive that ends where it started, how far the
  estimate's end is from its start, also as a percentage of the path length. The truth's
  own gap is taken out: the error is the difference between the estimate's end-to-start
  offset and the truth's, so a perfect estimate scores 0 even when the poses stop a few
  centimetres short of the start (a method estimated at the image stamps ends at the last
  image, up to 0.1 s before the last scan). Where the truth closes exactly this is the
  paper's figure. Undefined (None) when the truth does not close a loop: its end is more
  than ``LOOP_GAP_FRACTION`` of the path length (and more than 0.5 m) from its start.
- End position error: the distance between the estimate's and the truth's last
  positions (the estimate started at the true first pose), loop or not.
- Average position error (Table 1): the mean distance between estimated and true
  positions over all stamps, with the estimate started at the true first pose.
- ATE RMSE: root mean square position error after the rigid alignment that minimises
  it (Umeyama without scale), exactly evo's ``evo_ape REF EST --align`` (for planar
  poses at one height evo's SE(3) alignment is this SE(2) one).
- RPE over a distance d: exactly evo's ``evo_rpe REF EST --delta d --delta_unit m`` with
  its defaults (translation part, consecutive pairs, pairs chosen along the estimate's
  path): pose 0, then each pose where the estimate's path since the previous chosen pose
  reaches d; for each consecutive pair (i, j) the translation of
  E = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j) (Q the truth, P the estimate); RMSE over the pairs.

:func:`associate` pairs two trajectories' stamps as evo does (nearest stamp within
0.01 s). The tests check every figure against evo's own functions.
"""

from __future__ import annotations

import itertools
from typing import Any

import numpy as np
from numpy.typing import NDArray

from rigcal.arrays import FloatArray
from rigcal.geometry import pose_of, se2

LOOP_GAP_FRACTION = 0.05


def steps(poses: FloatArray) -> FloatArray:
    """(N-1, 3) the motion from each pose to the next, in the first one's frame."""
    return np.array([pose_of(np.linalg.inv(se2(a)) @ se2(b)) for a, b in itertools.pairwise(poses)])


def path_length_m(poses: FloatArray) -> float:
    return float(np.linalg.norm(np.diff(poses[:, :2], axis=0), axis=1).sum())


def anchored(est: FloatArray, gt: FloatArray) -> FloatArray:
    """The estimate moved rigidly so that its first pose is the truth's first pose."""
    A = se2(gt[0]) @ np.linalg.inv(se2(est[0]))
    return np.array([pose_of(A @ se2(p)) for p in est])


def align_se2(est: FloatArray, gt: FloatArray) -> FloatArray:
    """The estimate moved by the SE(2) transform minimising its position error."""
    a, b = est[:, :2], gt[:, :2]
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    H = (a - ca).T @ (b - cb)
    yaw = float(np.arctan2(H[0, 1] - H[1, 0], H[0, 0] + H[1, 1]))
    c, s = np.cos(yaw), np.sin(yaw)
    R = np.array([[c, -s], [s, c]])
    t = cb - R @ ca
    return np.column_stack([a @ R.T + t, est[:, 2] + yaw])


def ate_rmse(est: FloatArray, gt: FloatArray) -> float:
    """Position RMSE after the best rigid alignment (evo's ``evo_ape --align``)."""
    ali = align_se2(est, gt)
    return float(np.sqrt(np.mean(np.sum((ali[:, :2] - gt[:, :2]) ** 2, axis=1))))


def rpe_pairs(poses: FloatArray, delta_m: float) -> list[tuple[int, int]]:
    """evo's consecutive pairs by path length (``filters.filter_pairs_by_path`` with
    ``all_pairs=False``): pose 0, then every pose at which the path travelled since the
    last chosen one reaches ``delta_m``; each chosen pose paired with the next."""
    ids = [0]
    travelled = 0.0
    step = np.linalg.norm(np.diff(poses[:, :2], axis=0), axis=1)
    for i in range(1, len(poses)):
        travelled += float(step[i - 1])
        if travelled >= delta_m:
            ids.append(i)
            travelled = 0.0
    return list(itertools.pairwise(ids))


def rpe_rmse(est: FloatArray, gt: FloatArray, delta_m: float) -> float:
    """RMSE of the relative translation error over evo's pairs ``delta_m`` apart along
    the estimate's path (evo's default); NaN when the path is shorter than ``delta_m``."""
    errs = []
    for i, j in rpe_pairs(est, delta_m):
        rel_gt = np.linalg.inv(se2(gt[i])) @ se2(gt[j])
        rel_est = np.linalg.inv(se2(est[i])) @ se2(est[j])
        e = np.linalg.inv(rel_gt) @ rel_est
        errs.append(np.hypot(e[0, 2], e[1, 2]))
    return float(np.sqrt(np.mean(np.square(errs)))) if errs else float("nan")


def relation_error(
    est: FloatArray, gt: FloatArray, pairs: list[tuple[int, int]] | None = None
) -> dict[str, float]:
    """The relation-based error of Kuemmerle et al. 2009 ("On measuring the accuracy of
    SLAM algorithms", Eq. (2)): for each relation (i, j), the error of the estimate's
    relative displacement T_i^-1 T_j against the truth's, as its translation (m) and its
    rotation (deg); their means and standard deviations. ``pairs`` defaults to every
    pose and the next (the relations between consecutive scans)."""
    if pairs is None:
        pairs = [(k, k + 1) for k in range(len(gt) - 1)]
    t, r = [], []
    for i, j in pairs:
        e = pose_of(
            np.linalg.inv(np.linalg.inv(se2(gt[i])) @ se2(gt[j])) @ (np.linalg.inv(se2(est[i])) @ se2(est[j]))
        )
        t.append(np.hypot(e[0], e[1]))
        r.append(np.degrees(abs(e[2])))
    return {
        "relations": len(pairs),
        "trans_mean_m": float(np.mean(t)),
        "trans_std_m": float(np.std(t)),
        "rot_mean_deg": float(np.mean(r)),
        "rot_std_deg": float(np.std(r)),
    }


def associate(
    stamps_1: FloatArray, stamps_2: FloatArray, max_diff_s: float = 0.01
) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Indices of matching stamps of two trajectories, as evo's
    ``sync.associate_trajectories`` (nearest time, ``max_diff`` 0.01 s): each stamp of
    the trajectory with fewer poses is matched to the nearest stamp of the other within
    ``max_diff_s`` (a tie goes to the earlier one), unmatched stamps are dropped. Both
    stamp arrays must be increasing. Returns (indices into stamps_1, into stamps_2)."""
    swap = len(stamps_2) <= len(stamps_1)
    short, long_ = (stamps_2, stamps_1) if swap else (stamps_1, stamps_2)
    i_short, i_long = [], []
    for k, t in enumerate(short):
        if t < long_[0] - max_diff_s or t > long_[-1] + max_diff_s:
            continue
        j = min(int(np.searchsorted(long_, t, side="right")), len(long_) - 1)
        up = long_[j] - t
        down = t - long_[j - 1] if j > 0 else np.inf
        if up <= max_diff_s and up < down:
            best = j
        elif down <= max_diff_s and down <= up:
            best = j - 1
        else:
            continue
        i_short.append(k)
        i_long.append(best)
    a, b = np.array(i_short, dtype=np.intp), np.array(i_long, dtype=np.intp)
    return (b, a) if swap else (a, b)


def evaluate(est: FloatArray, gt: FloatArray, rounded: bool = True) -> dict[str, Any]:
    """Every figure above, for an estimate and the truth at the same stamps; rounded to
    0.1 mm (lengths to 1 mm, percentages to 0.001) unless ``rounded`` is False."""
    if est.shape != gt.shape:
        raise ValueError(f"estimate {est.shape} and truth {gt.shape} differ in shape")

    def r(x: float, digits: int = 4) -> float | None:
        """Rounded (or as is), None when undefined (a path shorter than the RPE distance)."""
        if not np.isfinite(x):
            return None
        return round(float(x), digits) if rounded else float(x)

    a = anchored(est, gt)
    length = path_length_m(gt)
    gt_offset = gt[-1, :2] - gt[0, :2]
    loop = float(np.linalg.norm((a[-1, :2] - a[0, :2]) - gt_offset))
    gt_gap = float(np.linalg.norm(gt_offset))
    is_loop = length > 0 and gt_gap <= max(0.5, LOOP_GAP_FRACTION * length)
    return {
        "path_length_m": r(length, 3),
        "loop_closure_error_m": r(loop) if is_loop else None,
        "loop_closure_error_percent": r(100.0 * loop / length, 3) if is_loop else None,
        "truth_loop_gap_m": r(gt_gap),
        "end_position_error_m": r(float(np.linalg.norm(a[-1, :2] - gt[-1, :2]))),
        "average_position_error_m": r(float(np.mean(np.linalg.norm(a[:, :2] - gt[:, :2], axis=1)))),
        "ate_rmse_m": r(ate_rmse(est, gt)),
        "rpe_1m_rmse_m": r(rpe_rmse(est, gt, 1.0)),
        "rpe_10m_rmse_m": r(rpe_rmse(est, gt, 10.0)),
    }
