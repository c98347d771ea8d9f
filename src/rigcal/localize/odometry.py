"""Laser odometry: ICP between successive scans of a sequence, chained into a trajectory.

Point-to-line ICP takes the model scan's normals from its lines (:mod:`rigcal.localize.line_normals`).
The lines are extracted (``rigcal.lines``) on every ``LINES_EVERY``-th scan only (in
Python, a return at a time, the extraction cost about as much as the ICP step itself;
compiled it costs about a tenth of one); the scans between carry them: a return of the
new scan, moved by the step just estimated into the previous scan's frame, takes the line
of its nearest previous return when it lies within ``CARRY_M`` of that line (the nearest
returns are ICP's own, from the step). Returns of walls that come into view are left off
until the next extraction (at most ``LINES_EVERY`` - 1 scans).

The extraction, the carrying and the lines' fits run in compiled kernels
(:mod:`rigcal.jit`); ``icp_odometry(..., kernel=False)`` runs their Python / numpy
references (and ICP's numpy iterations), which the tests hold them to.
"""

from __future__ import annotations

import dataclasses
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from rigcal.arrays import FloatArray, IntArray
from rigcal.geometry import pose_of, se2
from rigcal.jit import njit
from rigcal.lines import Segment, extract_lines, line_labels, return_labels
from rigcal.localize.icp import IcpParams, IcpResult, icp
from rigcal.localize.icp_covariance import icp_covariance
from rigcal.localize.line_normals import MIN_LINE_FRACTION, label_runs, line_normals, pairing_normals
from rigcal.scan import Scan

LINES_EVERY = 4
# A carried return lies within this of its line (3 sigma of a Hokuyo-class scanner's
# range noise, as the line extraction's own distance test).
CARRY_M = 0.03
# An ICP step whose degeneracy indicator is below this constrains too little.
DEGENERATE_BELOW = 0.01
# The wheel odometry's error over one step, bounding how far ICP may move its guess:
# (m, fraction of the step's length) and (rad, fraction of the step's turn).
WHEEL_GATE_M = (0.10, 0.10)
WHEEL_GATE_RAD = (np.radians(3.0), 0.10)
# Scans in the model each step is matched against (scan-to-submap): 1 the previous scan.
SUBMAP_SCANS = 1


def agrees_with_wheels(step: FloatArray, wheel: FloatArray) -> bool:
    """Whether ICP's step (x, y, yaw) lies within the wheel odometry's error bound of its
    guess (:data:`WHEEL_GATE_M`, :data:`WHEEL_GATE_RAD`): a fit beyond it slid into
    another minimum (a repeated corridor, clutter) more likely than the wheels erred."""
    d = np.asarray(step, dtype=float) - np.asarray(wheel, dtype=float)
    turn = abs(float(np.angle(np.exp(1j * d[2]))))
    far = float(np.hypot(d[0], d[1]))
    return bool(
        far <= WHEEL_GATE_M[0] + WHEEL_GATE_M[1] * float(np.hypot(wheel[0], wheel[1]))
        and turn <= WHEEL_GATE_RAD[0] + WHEEL_GATE_RAD[1] * abs(float(wheel[2]))
    )


# The laser odometry methods of ``rigcal localize`` (and ``rigcal.LaserOdometry``) and
# their ICP settings.
LASER_ODOMETRY = {
    "icp": IcpParams(method="point-to-line"),
    "icp-p2p": IcpParams(method="point-to-point"),
}


@dataclass(frozen=True)
class Odometry:
    """Poses (N, 3) of the laser in the first scan's frame, per-step degeneracy and ICP
    fit RMS, how many steps were skipped (too few points) and kept the last motion, and
    how many were tried again from zero motion (a poor fit from the previous motion), and
    how many ICP steps the wheel odometry overruled (a fit beyond its error bound), and
    how many steps across a gap in the wheel odometry kept its motion as their guess
    (``gap_kept``; the others there: the scans contradicted it, ICP's own fit kept).
    ``covariance`` (N, 3, 3): each step's T_prev_cur covariance (x, y, yaw; the one ending
    at scan k at index k, :func:`rigcal.localize.icp_covariance.icp_covariance`), NaN where ICP did
    not measure the step (index 0, skipped and overruled steps: a guess)."""

    poses: FloatArray
    degeneracy: FloatArray
    rms_m: FloatArray
    skipped: int
    restarts: int = 0
    overruled: int = 0
    covariance: FloatArray | None = None
    gap_kept: int = 0


def icp_odometry(
    scans: Sequence[Scan],
    params: IcpParams | None = None,
    progress: Callable[[int], None] | None = None,
    lines: Callable[[int], list[Segment]] | None = None,
    *,
    kernel: bool = True,
    guess: FloatArray | None = None,
    gap_guess: FloatArray | None = None,
    covariance: bool = True,
    submap_scans: int = SUBMAP_SCANS,
) -> Odometry:
    """Chain ICP increments T_prev_cur over the scans (:class:`ScanOdometry` fed every
    scan in turn), each started from ``guess[k]`` (N - 1, 3: the wheel odometry's motion
    from scan k to k + 1, NaN where it has none) or else from the previous increment
    (constant velocity); ``gap_guess`` (N - 1, 3): the wheel odometry's motion across its
    gaps, NaN elsewhere, a guess unless the scans contradict it (:meth:`ScanOdometry.add`'s
    ``candidate``);
    ``progress`` is called with the scans done so far. ``lines(k)``:
    scan k's segments, to share them with other stages (by default extracted here).
    ``kernel=False`` runs the line extraction, the carrying of the lines and ICP in their
    Python/numpy references instead of the compiled kernels. ``covariance=False`` leaves
    the steps' covariances out (NaN): most of the cost of a step, for callers that use the
    poses only (the targetless drift check)."""
    if not scans:
        raise ValueError("icp_odometry needs at least one scan")
    for name, g in (("guess", guess), ("gap_guess", gap_guess)):
        if g is not None and np.shape(g) != (len(scans) - 1, 3):
            raise ValueError(f"icp_odometry: {name} of shape {np.shape(g)}, expected ({len(scans) - 1}, 3)")
    od = ScanOdometry(params, lines, kernel=kernel, covariance=covariance, submap_scans=submap_scans)
    for k, scan in enumerate(scans):
        if k and progress is not None:
            progress(k + 1)
        od.add(
            scan,
            None if guess is None or not k else guess[k - 1],
            None if gap_guess is None or not k else gap_guess[k - 1],
        )
    return od.odometry()


# A scan's return agrees with the model at a fit when a model return lies within this
# (m): a few times a Hokuyo-class scanner's range noise and its returns' spacing at 3 m.
AGREE_M = 0.05


def _agreement(model: FloatArray, cur: FloatArray, pose: FloatArray) -> float:
    """The fraction of the scan's returns ``cur`` (K, 2) that agree with the model's
    (:data:`AGREE_M`) at the fit ``pose`` (T_prev_cur). Unlike the fit's inlier fraction,
    whose gate widens with the fit's own median distance, it does not favour a fit that
    slid into a wrong minimum."""
    from scipy.spatial import cKDTree

    T = se2(np.asarray(pose, dtype=float))
    d = cKDTree(model).query(cur @ T[:2, :2].T + T[:2, 2], distance_upper_bound=AGREE_M)[0]
    return float(np.isfinite(d).mean()) if len(d) else 0.0


# Across a gap in the wheel odometry its motion stands unless the scans clearly
# contradict it: ICP's own fit agrees with the model on at least this fraction of the
# scan's returns and on this many times as many as the fit from the odometry's motion
# (on Killian Court's 15 gaps the two fits' agreements differ by at most 0.05 where both
# are right, and where the scans barely overlap, a 172 deg turn, neither reaches 0.11).
CONTRADICT_AGREEMENT = 0.5
CONTRADICT_RATIO = 2.0


def contradicts(model: FloatArray, cur: FloatArray, own: FloatArray, odometry: FloatArray) -> bool:
    """Whether the scans clearly contradict the wheel odometry's motion across a gap in
    it: ICP's own fit ``own`` (T_prev_cur) agrees with the model (:func:`_agreement`) on
    at least :data:`CONTRADICT_AGREEMENT` of the returns and :data:`CONTRADICT_RATIO`
    times as many as the fit from the odometry's motion ``odometry`` (a base rebooted or
    carried while the logger paused)."""
    a_own = _agreement(model, cur, own)
    return a_own >= CONTRADICT_AGREEMENT and a_own >= CONTRADICT_RATIO * _agreement(model, cur, odometry)


class ScanOdometry:
    """Laser odometry one scan at a time: each scan is matched by ICP to the one before
    it, and the increment T_prev_cur chained onto the pose (:func:`icp_odometry` feeds it
    a whole sequence; a robot's own loop feeds it scans as they come).

    Each step starts from a given guess (wheel odometry), or else from the previous
    increment (constant velocity) and, when that fit is poor
    (``params.restart_below_inliers``), from zero motion too, the better fit kept. From a
    guess, a fit beyond its error bound (:func:`agrees_with_wheels`) is overruled by the
    guess, and a step ICP cannot constrain keeps the guess where the scans say nothing:
    ICP solves only in the directions the scans constrain and keeps its initial guess
    along the others (a corridor's length). A scan with fewer than 10 valid returns (or
    one after such a scan) takes the guess, or else keeps the last motion, and counts as
    skipped. Across a gap in the wheel odometry its motion is a ``candidate``: a guess
    as above unless the scans clearly contradict it (:func:`contradicts`: ICP's own fit
    agrees with them far better, as after a base rebooted or carried while the logger
    paused), where ICP's own fit is kept. Point-to-line
    with ``params.normals == "lines"`` takes the model scan's normals from its lines,
    extracted every ``LINES_EVERY`` scans (``lines(k)``: scan k's segments when given)
    and carried between. Each measured step's covariance is computed unless
    ``covariance=False`` (then NaN).
    """

    def __init__(
        self,
        params: IcpParams | None = None,
        lines: Callable[[int], list[Segment]] | None = None,
        *,
        kernel: bool = True,
        covariance: bool = True,
        submap_scans: int = SUBMAP_SCANS,
    ) -> None:
        if submap_scans < 1:
            raise ValueError(f"submap_scans must be at least 1, not {submap_scans}")
        self.params = params or IcpParams()
        self._submap_scans = submap_scans
        # The last submap_scans scans' returns and normals in their own frames, and their poses.
        self._recent: deque[tuple[FloatArray, FloatArray | None, FloatArray]] = deque(maxlen=submap_scans)
        self._with_covariance = covariance
        self._lines = lines
        self._kernel = kernel
        self._use_lines = self.params.method == "point-to-line" and self.params.normals == "lines"
        self._labels: IntArray | None = None  # the model scan's line of each return
        self._extracted = -LINES_EVERY  # the scan whose lines were last extracted
        self._T = np.eye(3)
        self._poses: list[FloatArray] = []
        self._deg: list[float] = []
        self._rms: list[float] = []
        self._cov: list[FloatArray] = []
        self._last = np.zeros(3)
        self._skipped = self._restarts = self._overruled = self._gap_kept = 0
        self._prev = np.zeros((0, 2))
        self._prev_normals: FloatArray | None = None
        self._nearest: NDArray[np.intp] | None = None  # the last step's nearest model returns

    def __len__(self) -> int:
        """The number of scans added."""
        return len(self._poses)

    def add(
        self, scan: Scan, guess: FloatArray | None = None, candidate: FloatArray | None = None
    ) -> FloatArray:
        """Match ``scan`` to the previous one; returns its pose (x m, y m, yaw rad) in the
        first scan's frame. ``guess``: T_prev_cur (x, y, yaw) to start ICP from instead of
        the previous increment (e.g. from wheel odometry); a guess with a non-finite value
        counts as none. ``candidate``: where there is no guess, the wheel odometry's motion
        across a gap in it, taken as a guess unless the scans clearly contradict it
        (:func:`contradicts`); a non-finite one counts as none."""
        k = len(self._poses)
        cur = scan.points[scan.valid]
        if k == 0:
            self._prev = cur
            self._prev_normals = self._normals_of(0, scan, cur, cur, None, np.zeros(3), None)
            self._recent.append((cur, self._prev_normals, self._T.copy()))
            self._poses.append(pose_of(self._T))
            self._deg.append(1.0)
            self._rms.append(0.0)
            self._cov.append(np.full((3, 3), np.nan))
            return self._poses[-1]
        params, kernel, prev = self.params, self._kernel, self._prev
        wheel = guess is not None and bool(np.isfinite(guess).all())
        across = not wheel and candidate is not None and bool(np.isfinite(candidate).all())
        start = np.asarray(guess if wheel else candidate if across else self._last, dtype=float)
        cov = np.full((3, 3), np.nan)
        if len(cur) < 10 or len(prev) < 10:
            step, d, r = start, 0.0, float("nan")
            self._skipped += 1
        else:
            model, model_normals = self._model()
            measured = True
            if wheel or across:
                res = icp(
                    model, cur, initial=start, params=params, model_normals=model_normals, kernel=kernel
                )
                if not agrees_with_wheels(res.pose, start):
                    res = dataclasses.replace(res, pose=start, degeneracy=0.0)
                    measured = False  # the step is the wheels' own
                if across:
                    own = self._own_fit(model, model_normals, cur)
                    if contradicts(model, cur, own.pose, res.pose):
                        res, measured = own, True
                    else:
                        self._gap_kept += 1
                self._overruled += not measured
            else:
                res = self._own_fit(model, model_normals, cur)
            step, d, r = res.pose, res.degeneracy, res.rms_m
            # The lines are carried from the previous scan's returns: its nearest, where
            # the model is the previous scan alone.
            self._nearest = res.nearest if len(model) == len(prev) else None
            if measured and res.nearest is not None and self._with_covariance:
                cov = self._covariance(model, model_normals, cur, res)
        self._T = self._T @ se2(step)
        self._poses.append(pose_of(self._T))
        self._deg.append(d)
        self._rms.append(r)
        self._cov.append(cov)
        self._last = step
        if len(cur) >= 10:
            self._prev_normals = self._normals_of(k, scan, cur, prev, self._prev_normals, step, self._nearest)
            self._prev = cur
            self._recent.append((cur, self._prev_normals, self._T.copy()))
        return self._poses[-1]

    def _own_fit(self, model: FloatArray, model_normals: FloatArray | None, cur: FloatArray) -> IcpResult:
        """The step matched from the previous increment and, where that fit is poor
        (``params.restart_below_inliers``), from zero motion too, the better fit kept."""
        params, kernel = self.params, self._kernel
        res = icp(model, cur, initial=self._last, params=params, model_normals=model_normals, kernel=kernel)
        if res.inlier_fraction < params.restart_below_inliers:
            zero = np.zeros(3)
            again = icp(model, cur, initial=zero, params=params, model_normals=model_normals, kernel=kernel)
            if (again.inlier_fraction, -again.rms_m) > (res.inlier_fraction, -res.rms_m):
                res = again
            self._restarts += 1
        return res

    def odometry(self) -> Odometry:
        """Everything so far: the poses (N, 3), per-step degeneracy and fit RMS, counts."""
        return Odometry(
            np.array(self._poses),
            np.array(self._deg),
            np.array(self._rms),
            self._skipped,
            self._restarts,
            self._overruled,
            np.array(self._cov),
            self._gap_kept,
        )

    def _model(self) -> tuple[FloatArray, FloatArray | None]:
        """The step's model in the previous scan's frame: the previous scan's returns and
        normals, then those of the ``submap_scans`` - 1 scans before it moved there by the
        poses already estimated (scan-to-submap, as Cartographer's local SLAM matches a scan
        to the submap of the last scans rather than to one: a wall the previous scan saw
        in part or through clutter is whole in the submap, and each scan's range noise
        averages out over the submap's returns). Normals NaN where a scan's return lies on
        no line, or where a scan has no line normals at all."""
        prev_pts, prev_normals, T_w_prev = self._recent[-1]
        if len(self._recent) == 1:
            return prev_pts, prev_normals
        T_prev_w = np.linalg.inv(T_w_prev)
        points, normals = [prev_pts], [prev_normals]
        for pts, nrm, T_w in list(self._recent)[:-1]:
            T = T_prev_w @ T_w
            points.append(pts @ T[:2, :2].T + T[:2, 2])
            normals.append(None if nrm is None else nrm @ T[:2, :2].T)
        model = np.ascontiguousarray(np.vstack(points))
        if all(n is None for n in normals):
            return model, None
        filled = [
            np.full((len(p), 2), np.nan) if n is None else n for p, n in zip(points, normals, strict=True)
        ]
        return model, np.ascontiguousarray(np.vstack(filled))

    def _covariance(
        self, prev: FloatArray, prev_normals: FloatArray | None, cur: FloatArray, res: IcpResult
    ) -> FloatArray:
        """ICP's step covariance (:func:`icp_covariance`) with the normals it paired along."""
        assert res.nearest is not None
        normals = None
        if self.params.method == "point-to-line":
            given = prev_normals
            if given is not None and np.isfinite(given[:, 0]).mean() >= MIN_LINE_FRACTION:
                normals = given
            else:
                from scipy.spatial import cKDTree

                normals = pairing_normals(prev, cKDTree(prev), self.params.normal_neighbours, None)[0]
        reject_m = self.params.reject_m
        return icp_covariance(prev, cur, res.pose, res.nearest, normals, reject_m, DEGENERATE_BELOW)

    def _normals_of(
        self,
        k: int,
        scan: Scan,
        pts: FloatArray,
        model: FloatArray,
        model_normals: FloatArray | None,
        step: FloatArray,
        nearest: NDArray[np.intp] | None,
    ) -> FloatArray | None:
        """Scan k's (``scan``, valid returns ``pts``) line normals: its own lines every LINES_EVERY scans,
        else the model's carried over by the step (T_model_k, ICP's ``nearest`` pairs);
        None (nearest-neighbour normals) until the next extraction when too few returns
        lay on a line (clutter)."""
        if not self._use_lines:
            return None
        kernel = self._kernel
        if k - self._extracted >= LINES_EVERY:
            self._extracted = k
            if self._lines is not None:
                self._labels = return_labels(scan, self._lines(k))
            elif kernel:
                self._labels = line_labels(scan)
            else:
                self._labels = return_labels(scan, extract_lines(scan, kernel=False))
            if not len(self._labels) or (self._labels >= 0).mean() < MIN_LINE_FRACTION:
                self._labels = None
        elif self._labels is not None:
            self._labels = carry_labels(model, self._labels, model_normals, step, pts, nearest, kernel=kernel)
        return None if self._labels is None else line_normals(pts, self._labels, kernel=kernel)


def carry_labels(
    prev: FloatArray,
    prev_labels: IntArray,
    prev_normals: FloatArray | None,
    step: FloatArray,
    cur: FloatArray,
    nearest: NDArray[np.intp] | None = None,
    *,
    kernel: bool = True,
) -> IntArray:
    """The line of each return of ``cur`` carried from the previous scan's returns
    (``prev``, ``prev_labels``, their ``prev_normals`` when known; ``step`` =
    T_prev_cur): the line of its nearest previous return (``nearest``, as ICP found them;
    else looked up here) when it lies within CARRY_M of that line (the line refitted to
    the previous returns on it), else -1. ``kernel=False`` runs the numpy version (the
    compiled kernel's reference)."""
    out = np.full(len(cur), -1, dtype=np.int64)
    if not (prev_labels >= 0).any() or len(cur) == 0:
        return out
    T = se2(step)
    if nearest is None or len(nearest) != len(cur):
        from scipy.spatial import cKDTree

        nearest = cKDTree(prev).query(cur @ T[:2, :2].T + T[:2, 2])[1]
    normals = line_normals(prev, prev_labels, kernel=kernel) if prev_normals is None else prev_normals
    if kernel:
        pose = np.array([T[0, 0], T[1, 0], T[0, 2], T[1, 2]])
        labels = np.asarray(prev_labels, dtype=np.int64)
        _carry_kernel(prev, labels, normals, pose, cur, np.asarray(nearest, dtype=np.int64), CARRY_M, out)
        return out
    moved = cur @ T[:2, :2].T + T[:2, 2]
    # Each line's offset n . p (the mean over its returns).
    on = prev_labels >= 0
    lab = prev_labels[on]
    count = np.maximum(np.bincount(lab).astype(float), 1.0)
    offset = np.bincount(lab, weights=np.einsum("ij,ij->i", normals[on], prev[on])) / count
    line = prev_labels[nearest]
    k = np.flatnonzero(line >= 0)
    line = line[k]
    close = np.abs(np.einsum("ij,ij->i", normals[nearest[k]], moved[k]) - offset[line]) < CARRY_M
    out[k[close]] = line[close]
    return out


@njit
def _carry_kernel(
    prev: FloatArray,
    prev_labels: IntArray,
    normals: FloatArray,
    pose: FloatArray,
    cur: FloatArray,
    nearest: IntArray,
    carry_m: float,
    out: IntArray,
) -> None:
    """:func:`carry_labels`' test in one pass: each line's offset n . p (the mean over its
    previous returns), then each return of ``cur`` moved by ``pose`` = (cos, sin, x, y)
    of T_prev_cur takes its nearest previous return's line when its own n . p is within
    ``carry_m`` of that offset (``out``, left -1 otherwise)."""
    c, s, tx, ty = pose[0], pose[1], pose[2], pose[3]
    n_lines = 0
    for i in range(len(prev_labels)):
        n_lines = max(n_lines, prev_labels[i] + 1)
    count = np.zeros(n_lines)
    offset = np.zeros(n_lines)
    bounds = label_runs(prev_labels)  # a line's returns come in runs: its sums in registers
    for r in range(len(bounds) - 1):
        k = prev_labels[bounds[r]]
        if k < 0:
            continue
        n, o = count[k], offset[k]
        for i in range(bounds[r], bounds[r + 1]):
            n += 1.0
            o += normals[i, 0] * prev[i, 0] + normals[i, 1] * prev[i, 1]
        count[k], offset[k] = n, o
    for k in range(n_lines):
        offset[k] /= max(count[k], 1.0)
    for i in range(len(cur)):
        j = nearest[i]
        k = prev_labels[j]
        if k < 0:
            continue
        mx = c * cur[i, 0] - s * cur[i, 1] + tx
        my = s * cur[i, 0] + c * cur[i, 1] + ty
        if abs(normals[j, 0] * mx + normals[j, 1] * my - offset[k]) < carry_m:
            out[i] = k
