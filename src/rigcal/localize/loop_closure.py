"""Loop closure: scan-to-submap closures searched within the drift's reach, verified, and
a pose graph with a robust kernel.

The paper names automatic loop closure as its future work (Section VIII). Here, on top of
any odometry (ICP, ICP from the wheels, H-IASM), keyframes every
:attr:`LoopParams.keyframe_m` of path are taken in driving order, as an online system
would, and the poses are corrected as closures are found, so that each later search
starts from a map whose earlier loops are already closed:

1. **Proposals.** Keyframe i and an earlier keyframe j at least ``min_loop_m`` of path
   back are proposed as a closure when the current poses put them within the search
   window of each other; each keyframe proposes its nearest such j. The window grows with
   the drift accumulated between them: over L metres of path, position sigma
   sqrt((a L)^2 + b^2 L^3 / 3) and heading sigma b sqrt(L) (a scale error a per metre,
   ``drift_per_m``, and a heading random walk b, ``drift_rad_per_sqrt_m``), times
   ``n_sigma``, plus ``search_m``, at most ``max_search_m`` / ``max_search_rad``. L is
   the shortest path between them in the graph, where an accepted closure is a short cut:
   once a loop is closed, the places it joined are close in the graph again.
1b. **Global search** (with ``global_every`` > 0). A keyframe whose local search proposed
   nothing or failed the verification, at most every ``global_every`` keyframes and not
   within as many of the last closure, searches the earlier keyframes beyond their window
   but within step 1's drift model's reach (its 3-sigma window uncapped, at most
   ``max_global_m``, plus ``global_window_m``), nearest first, at most
   ``global_candidates`` of them 2 ``submap_m`` of path apart (:func:`global_search`).
   Each is matched by :func:`verify_global`: keyframe i's local submap (its scans over the
   last ``global_context_m`` of path, placed by the odometry: short enough not to drift,
   long enough to be distinctive) anywhere within ``global_window_m`` of j on j's submap
   and within the drift model's yaw window (at least ``global_rad``; the full circle from
   pi), by multi-resolution branch and bound (:mod:`rigcal.localize.branch_and_bound`,
   Hess et al. 2016: max-pooled likelihood grids of ``global_levels`` levels on
   ``global_grid_m`` cells, an exact bound) cut below ``global_min_score``; then step 2's
   ambiguity test, fit and test. The robust kernel (step 3) catches what that lets
   through.
2. **Verification.** Keyframe i is matched to the submap of j (the scans within
   ``submap_m`` of path of j, moved into j's frame by the current poses). First i's
   context (its scan and those of the 2 ``submap_m`` of path before it, placed by the
   odometry, which is locally right) is searched for over the whole window by a
   correlative search (Olson 2009, "Real-time correlative scan matching"; one level of
   branch and bound as in Hess et al. 2016: a coarse grid's block maxima bound the fine
   score, and blocks are searched best bound first until no bound beats the best score).
   Matching the context rather than one scan is what tells a corridor's repeated doors
   apart. Then i's scan alone, the part that overlaps j's submap, is fitted by
   point-to-line ICP from the search's match. The closure is accepted when the search's
   score (the mean likelihood of the context's points in the submap, 1 when every point
   lies on a submap return) is at least ``min_score``; no pose farther than
   ``ambiguity_m`` from the best scores above ``max_ambiguity`` of it; ICP moves the
   match by at most ``max_refine_m`` (else the fit slides along a corridor); ICP keeps
   at least ``min_inliers`` of the scan's points as inliers with an RMS below
   ``max_rms_m``; and the scans constrain every direction (degeneracy indicator above
   ``min_degeneracy``: a corridor's length is not a closure).
3. **Pose graph.** The odometry steps between consecutive poses and the accepted closures
   (under the Cauchy kernel) are the edges (:mod:`rigcal.localize.pose_graph`, on scipy or
   GTSAM), each with a full covariance: a closure's from its ICP fit's Hessian
   (:func:`closure_covariance`, ``closure_sigmas`` where the fit has too few pairs), a
   step's the odometry's own where given (``step_covariances``: the laser odometry's over
   the step and the step's departure from it, :func:`step_covariances`; with
   ``step_drift`` (the default) first capped by the fixed sigmas below as a prior, fused
   as information, since where the scans do not constrain a step ICP kept its guess,
   then plus step 1's drift model over the step: (a l)^2 on x and y, b^2 l on yaw), else
   1-sigma ``step_sigmas`` plus ``step_sigma_per_m`` per metre of step. A precise
   odometry (without ``step_drift``) is then not bent by a coarser closure. A closure that disagrees with
   the current poses by more than ``reoptimise_whitened`` (whitened) corrects them at once
   (the graph up to keyframe i; the later poses follow it rigidly); the whole graph is
   optimised at the end, and a closure whose whitened residual stays above
   ``reject_whitened`` there contradicts the others and is reported as rejected by the
   kernel.

Closures proposed by other sources (``proposals``: image place recognition,
:mod:`rigcal.localize.place_recognition`) go through step 2's verification and step 3's
kernel as the scan search's own, each keyframe's after its scan search; each
:class:`Closure` records its ``source``, and :attr:`LoopResult.counts_by_source` counts
them apart. A proposal whose pair the current poses put within the search window (and
whose yaw agrees within it) is searched there; otherwise, as where the drift has carried
the poses beyond the window, around the proposal's own guess (its yaw, no translation)
within its ``window_m`` / ``window_rad``, by the global search's branch and bound. A
proposal of a place that a closure found at the same keyframe already joins (within that
closure's ``submap_m``) is not searched: the same information twice would count twice.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import maximum_filter
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra
from scipy.spatial import cKDTree

from rigcal.arrays import FloatArray
from rigcal.jit import njit
from rigcal.localize import branch_and_bound as bnb
from rigcal.localize.icp import IcpParams, icp
from rigcal.localize.icp_covariance import icp_covariance
from rigcal.localize.line_normals import pairing_normals
from rigcal.localize.pose_graph import PoseGraph, edge_errors, gtsam_available, optimise
from rigcal.scan import Scan

# A closure edge's weight in the graph of path lengths (a short cut; not 0, which the
# sparse graph would read as no edge).
_SHORT_CUT_M = 1e-6
# The correlative search stops after this many coarse blocks (best bound first).
_MAX_BLOCKS = 64


@dataclass(frozen=True)
class LoopParams:
    """Loop closure's settings (module docstring). ``backend``: the pose graph's, "scipy",
    "gtsam" or "auto" (GTSAM where it is installed, scipy otherwise). ``workers``: threads
    the global search's candidates are matched on (step 1b; 1: one by one)."""

    keyframe_m: float = 1.0
    min_loop_m: float = 10.0
    search_m: float = 1.0
    drift_per_m: float = 0.01
    drift_rad_per_sqrt_m: float = 0.005
    n_sigma: float = 3.0
    max_search_m: float = 8.0
    min_search_rad: float = 0.05
    max_search_rad: float = 0.35
    submap_m: float = 5.0
    voxel_m: float = 0.05
    match_points: int = 150
    grid_m: float = 0.1
    coarse: int = 4
    yaw_step_rad: float = 0.015
    min_score: float = 0.3
    ambiguity_m: float = 1.0
    max_ambiguity: float = 0.9
    max_refine_m: float = 0.3
    min_inliers: float = 0.8
    max_rms_m: float = 0.06
    min_degeneracy: float = 0.05
    step_sigmas: tuple[float, float, float] = (0.002, 0.002, 0.001)  # m, m, rad (floor)
    step_sigma_per_m: float = 0.02
    closure_sigmas: tuple[float, float, float] = (0.05, 0.05, 0.02)  # where the fit has none
    closure_floor_sigmas: tuple[float, float, float] = (0.002, 0.002, 0.0005)
    reoptimise_whitened: float = 3.0
    reject_whitened: float = 5.0
    global_every: int = 5
    max_global_m: float = 60.0
    global_rad: float = 0.6
    global_candidates: int = 8
    global_grid_m: float = 0.1
    global_levels: int = 7
    global_context_m: float = 6.0
    global_window_m: float = 6.0
    global_min_score: float = 0.55
    step_drift: bool = True
    backend: str = "auto"
    workers: int = 2

    def __post_init__(self) -> None:
        if self.backend not in ("auto", "scipy", "gtsam"):
            raise ValueError(f"backend must be auto, scipy or gtsam, not {self.backend!r}")
        for name in ("keyframe_m", "grid_m", "voxel_m", "yaw_step_rad", "n_sigma"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive")
        if self.coarse < 1 or self.match_points < 3:
            raise ValueError("coarse must be at least 1 and match_points at least 3")
        if self.global_every < 0 or self.global_candidates < 1:
            raise ValueError("global_every must be at least 0 and global_candidates at least 1")
        if not (self.global_grid_m > 0 and self.global_context_m > 0 and self.global_window_m > 0):
            raise ValueError("global_grid_m, global_context_m and global_window_m must be positive")
        if self.global_levels < 1:
            raise ValueError("global_levels must be at least 1")
        if self.workers < 1:
            raise ValueError(f"workers must be at least 1, not {self.workers}")

    @property
    def pose_graph(self) -> str:
        """The back end this run uses."""
        if self.backend == "auto":
            return "gtsam" if gtsam_available() else "scipy"
        return self.backend


@dataclass(frozen=True)
class Closure:
    """A proposed closure: keyframe scan i matched to scan j; T_j_i (x, y, yaw) when it
    passed the verification, and why not otherwise. ``score``: the correlative search's
    best score; ``window_m``: the translation window it searched; ``covariance`` (3, 3):
    T_j_i's, from the ICP fit's Hessian (:func:`closure_covariance`); ``wide``: proposed
    by the global search (module docstring, step 1b); ``source``: who proposed it,
    "scan" (the scan search, local or global) or a :class:`Proposal`'s source."""

    i: int
    j: int
    T_j_i: FloatArray | None
    inliers: float = 0.0
    rms_m: float = float("nan")
    why_not: str = ""
    kernel_rejected: bool = False
    score: float = float("nan")
    window_m: float = float("nan")
    covariance: FloatArray | None = None
    wide: bool = False
    source: str = "scan"


@dataclass(frozen=True)
class Proposal:
    """A closure proposed from outside the scan search (module docstring): keyframe pose
    i as a revisit of earlier keyframe pose j (indices of the poses; both keyframes of
    :func:`keyframes`, at least ``min_loop_m`` of path apart), with the source's guess of
    T_j_i's yaw (rad) and the window it vouches for around it (m, rad)."""

    i: int
    j: int
    source: str
    yaw_rad: float
    window_m: float
    window_rad: float


@dataclass(frozen=True)
class LoopResult:
    """The optimised poses (N, 3) and the closures proposed (accepted and not)."""

    poses: FloatArray
    closures: list[Closure] = field(default_factory=list)
    backend: str = "scipy"

    @property
    def counts(self) -> dict[str, int]:
        verified = [c for c in self.closures if c.T_j_i is not None]
        return {
            "proposed": len(self.closures),
            "accepted": sum(1 for c in verified if not c.kernel_rejected),
            "rejected_by_verification": len(self.closures) - len(verified),
            "rejected_by_kernel": sum(1 for c in verified if c.kernel_rejected),
        }

    @property
    def counts_by_source(self) -> dict[str, dict[str, int]]:
        """:attr:`counts` of each source's closures ("scan", "images", ...)."""
        sources = sorted({c.source for c in self.closures}, key=lambda s: (s != "scan", s))
        return {
            s: replace(self, closures=[c for c in self.closures if c.source == s]).counts for s in sources
        }


def close_loops(
    scans: Sequence[Scan | FloatArray],
    poses: FloatArray,
    params: LoopParams | None = None,
    step_covariances: FloatArray | None = None,
    proposals: Sequence[Proposal] = (),
) -> LoopResult:
    """Loop closure over an odometry's poses (N, 3) of the scans (module docstring).

    ``scans``: each pose's scan, or its valid returns (P, 2) in the laser frame at the
    pose (a scan moved to the pose's stamp). ``step_covariances`` (N, 3, 3): the
    odometry's own covariance of each step T_k-1_k at index k (x, y, yaw), NaN where it has
    none; those steps, and all without it, take ``step_sigmas`` and ``step_sigma_per_m``.
    ``proposals``: closures proposed by other sources (module docstring).

    Raises:
        ValueError: a proposal that is not a pair of keyframes ``min_loop_m`` apart.
    """
    params = params or LoopParams()
    if step_covariances is not None and np.shape(step_covariances) != (len(poses), 3, 3):
        shape = np.shape(step_covariances)
        raise ValueError(f"step_covariances of shape {shape}, expected ({len(poses)}, 3, 3)")
    backend = params.pose_graph
    points = [s if isinstance(s, np.ndarray) else s.points[s.valid] for s in scans]
    along = path_along(poses)
    keys = keyframes(along, params.keyframe_m)
    est = poses.copy()
    closures: list[Closure] = []
    short_cuts: list[tuple[int, int]] = []  # keyframe positions joined by a closure
    position = {int(k): a for a, k in enumerate(keys)}
    extra = _proposals_by_key(proposals, position, along, params)
    last_found, last_global = 0, 0  # keyframe positions of the last closure and global search
    for a, i in enumerate(keys):
        earlier = keys[:a][along[i] - along[keys[:a]] >= params.min_loop_m]
        if not len(earlier):
            continue
        path = graph_path(along, keys, short_cuts, a, [position[int(k)] for k in earlier])
        window_m, window_rad = search_window(path, params)
        d = np.hypot(*(est[earlier, :2] - est[i, :2]).T)
        near = np.flatnonzero(d <= window_m)
        closure = None
        if len(near):
            c = near[np.argmin(d[near])]
            j = int(earlier[c])
            closure = verify(points, est, along, int(i), j, float(window_m[c]), float(window_rad[c]), params)
            closures.append(closure)
        if (closure is None or closure.T_j_i is None) and _global_due(a, last_found, last_global, params):
            last_global = a
            tried = global_search(points, est, along, int(i), earlier, d, window_m, path, params)
            closures.extend(tried)
            closure = tried[-1] if tried else None
        found = [] if closure is None or closure.T_j_i is None else [closure]
        for p in extra.get(int(i), []):
            if any(abs(along[p.j] - along[x.j]) <= params.submap_m for x in found):
                # The place is already in the graph by this keyframe's closure (within its
                # submap): the same information twice would count it twice.
                closures.append(
                    Closure(p.i, p.j, None, why_not="the place of a closure found here", source=p.source)
                )
                continue
            path_j = graph_path(along, keys, short_cuts, a, [position[p.j]])
            proposed = _verified_proposal(points, est, along, p, *search_window(path_j, params), params)
            closures.append(proposed)
            found += [proposed] if proposed.T_j_i is not None else []
        if not found:
            continue
        last_found = a
        short_cuts += [(a, position[x.j]) for x in found]
        accepted = [x for x in closures if x.T_j_i is not None]
        innovation = np.max(_whitened(est, found, params))
        if innovation > params.reoptimise_whitened:
            est = _corrected(poses, est, accepted, int(i), params, backend, step_covariances)
    accepted = [x for x in closures if x.T_j_i is not None]
    if not accepted:
        return LoopResult(poses.copy(), closures, backend)
    graph = build_graph(poses, est, accepted, len(poses) - 1, params, step_covariances)
    optimised, whitened = optimise(graph, backend)
    flags = iter(whitened[len(poses) - 1 :] > params.reject_whitened)
    out = [
        replace(x, why_not="contradicts the other edges", kernel_rejected=True)
        if x.T_j_i is not None and next(flags)
        else x
        for x in closures
    ]
    return LoopResult(optimised, out, backend)


def _proposals_by_key(
    proposals: Sequence[Proposal], position: dict[int, int], along: FloatArray, params: LoopParams
) -> dict[int, list[Proposal]]:
    """The proposals by their keyframe i, checked to be keyframe pairs ``min_loop_m`` apart."""
    out: dict[int, list[Proposal]] = {}
    for p in proposals:
        if p.i not in position or p.j not in position or along[p.i] - along[p.j] < params.min_loop_m:
            raise ValueError(
                f"proposal ({p.i}, {p.j}) from {p.source}: expected keyframes at least "
                f"{params.min_loop_m:g} m of path apart, the later first"
            )
        out.setdefault(p.i, []).append(p)
    return out


def _verified_proposal(
    scans: Sequence[FloatArray],
    poses: FloatArray,
    along: FloatArray,
    p: Proposal,
    window_m: FloatArray,
    window_rad: FloatArray,
    params: LoopParams,
) -> Closure:
    """A proposal through step 2's verification (module docstring): within the search
    window where the poses put its pair there, else around its own yaw within its own reach,
    by the global search's branch and bound."""
    by_poses = relative(poses[p.j][None], poses[p.i][None])[0]
    yaw_off = abs(np.angle(np.exp(1j * (by_poses[2] - p.yaw_rad))))
    if np.hypot(*by_poses[:2]) <= window_m[0] and yaw_off <= window_rad[0]:
        closure = verify(scans, poses, along, p.i, p.j, float(window_m[0]), float(window_rad[0]), params)
    else:
        closure = verify_global(
            scans, poses, along, p.i, p.j, p.window_rad, params, yaw_rad=p.yaw_rad, window_m=p.window_m
        )
    return replace(closure, source=p.source)


def path_along(poses: FloatArray) -> FloatArray:
    """(N,) the path length (m) from the first pose to each."""
    return np.r_[0.0, np.cumsum(np.hypot(*np.diff(poses[:, :2], axis=0).T))]


def keyframes(along: FloatArray, keyframe_m: float) -> NDArray[np.intp]:
    """The first pose and each pose at least ``keyframe_m`` of path after the previous key."""
    keys = [0]
    for k in range(1, len(along)):
        if along[k] - along[keys[-1]] >= keyframe_m:
            keys.append(k)
    return np.array(keys, dtype=np.intp)


def graph_path(
    along: FloatArray, keys: NDArray[np.intp], short_cuts: list[tuple[int, int]], a: int, targets: list[int]
) -> FloatArray:
    """The shortest path (m) from keyframe position a to each target position, along the
    odometry and through the accepted closures (short cuts)."""
    if not short_cuts:
        return np.asarray(along[keys[a]] - along[keys[targets]], dtype=float)
    n = a + 1
    seg = np.diff(along[keys[:n]])
    rows = [np.arange(n - 1), np.array([s[0] for s in short_cuts])]
    cols = [np.arange(1, n), np.array([s[1] for s in short_cuts])]
    weights = [np.maximum(seg, _SHORT_CUT_M), np.full(len(short_cuts), _SHORT_CUT_M)]
    g = coo_matrix(
        (np.concatenate(weights), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n)
    ).tocsr()
    dist = dijkstra(g, directed=False, indices=a)
    return np.asarray(dist[targets], dtype=float)


def search_window(path_m: FloatArray, params: LoopParams) -> tuple[FloatArray, FloatArray]:
    """The translation (m) and yaw (rad) half-widths of the search after ``path_m`` of
    drift (module docstring, step 1)."""
    L = np.maximum(path_m, 0.0)
    a, b = params.drift_per_m, params.drift_rad_per_sqrt_m
    sigma_xy = np.sqrt((a * L) ** 2 + b**2 * L**3 / 3.0)
    window_m = np.minimum(params.search_m + params.n_sigma * sigma_xy, params.max_search_m)
    window_rad = np.clip(params.n_sigma * b * np.sqrt(L), params.min_search_rad, params.max_search_rad)
    return window_m, window_rad


def verify(
    scans: Sequence[FloatArray],
    poses: FloatArray,
    along: FloatArray,
    i: int,
    j: int,
    window_m: float,
    window_rad: float,
    params: LoopParams,
) -> Closure:
    """Match scan i to scan j's submap within the window; the closure T_j_i when the fit
    passes the test (module docstring, step 2). ``scans``: each pose's valid returns (P, 2)."""
    submap = local_map(scans, poses, j, np.flatnonzero(np.abs(along - along[j]) <= params.submap_m), params)
    # The search matches keyframe i's context: its scan and those of the last 2 x submap_m
    # of path before it (the odometry is locally right), so that a corridor's repeated
    # structure is matched with what surrounds it, not one scan at a time. ICP then fits
    # i's scan alone, the part that overlaps j's submap, and its fit is the test.
    context = _context(scans, poses, along, i, 2 * params.submap_m, params)
    data = voxel_filter(scans[i], params.voxel_m)
    if len(submap) < 20 or len(data) < 20:
        return Closure(i, j, None, why_not="too few returns", window_m=window_m)
    guess = relative(poses[j][None], poses[i][None])[0]
    start, score, elsewhere = correlative_match(submap, context, guess, window_m, window_rad, params)
    return _tested(submap, data, start, score, elsewhere, Closure(i, j, None, window_m=window_m), params)


def verify_global(
    scans: Sequence[FloatArray],
    poses: FloatArray,
    along: FloatArray,
    i: int,
    j: int,
    window_rad: float,
    params: LoopParams,
    *,
    yaw_rad: float | None = None,
    window_m: float | None = None,
) -> Closure:
    """The global search's match of keyframe i anywhere on keyframe j's submap (module
    docstring, step 1b): i's local submap (its scans over the last ``global_context_m`` of
    path, placed by the odometry) is searched for by branch and bound
    (:func:`rigcal.localize.branch_and_bound.match`) over every translation within
    ``global_window_m`` of j and every yaw within ``window_rad`` of the poses' relative
    yaw (the full circle from pi), then tested as :func:`verify`'s match is. ``yaw_rad``
    and ``window_m``: another source's relative yaw and reach (an image proposal's) in
    place of the poses' and ``global_window_m``."""
    submap = local_map(scans, poses, j, np.flatnonzero(np.abs(along - along[j]) <= params.submap_m), params)
    context = _context(scans, poses, along, i, params.global_context_m, params)
    data = voxel_filter(scans[i], params.voxel_m)
    reach_m = params.global_window_m if window_m is None else window_m
    proposal = Closure(i, j, None, window_m=reach_m, wide=True)
    if len(submap) < 20 or len(data) < 20:
        return replace(proposal, why_not="too few returns")
    yaw = relative(poses[j][None], poses[i][None])[0, 2] if yaw_rad is None else yaw_rad
    pyr = bnb.pyramid(submap, params.global_grid_m, params.global_levels)
    found = bnb.match(
        pyr,
        context,
        np.array([0.0, 0.0, yaw]),
        reach_m,
        window_rad,
        away_m=params.ambiguity_m,
        away_ratio=params.max_ambiguity,
        min_score=params.global_min_score,
    )
    return _tested(
        submap, data, found.pose, found.score, found.elsewhere, proposal, params, params.global_min_score
    )


def _context(
    scans: Sequence[FloatArray],
    poses: FloatArray,
    along: FloatArray,
    i: int,
    behind_m: float,
    params: LoopParams,
) -> FloatArray:
    """Keyframe i's context: its scan and those of the last ``behind_m`` of path before it,
    in its frame, at most about ``match_points`` of them."""
    behind = np.flatnonzero((along <= along[i]) & (along >= along[i] - behind_m))
    context = local_map(scans, poses, i, behind[behind <= i], params)
    return context[:: max(1, int(np.ceil(len(context) / params.match_points)))]


def _tested(
    submap: FloatArray,
    data: FloatArray,
    start: FloatArray,
    score: float,
    elsewhere: float,
    proposal: Closure,
    params: LoopParams,
    min_score: float | None = None,
) -> Closure:
    """The search's match ``start`` tested (module docstring, step 2): its score against
    ``min_score`` (``params.min_score`` when None), its ambiguity, then ICP's fit."""
    floor = params.min_score if min_score is None else min_score
    proposal = replace(proposal, score=score)
    if not score >= floor:
        return replace(proposal, why_not=f"score {score:.2f} < {floor:g}")
    if elsewhere > params.max_ambiguity * score:
        why = f"ambiguous (score {elsewhere:.2f} {params.ambiguity_m:g} m away, {score:.2f} at best)"
        return replace(proposal, why_not=why)
    return fitted(submap, data, start, proposal, params)


def fitted(
    submap: FloatArray, data: FloatArray, start: FloatArray, proposal: Closure, params: LoopParams
) -> Closure:
    """The proposal with scan ``data`` (P, 2) fitted to the ``submap`` (M, 2) by
    point-to-line ICP from the search's match ``start`` (x, y, yaw), accepted when the fit
    passes the test (module docstring, step 2), with its covariance."""
    res = icp(submap, data, initial=start, params=IcpParams(method="point-to-line"))
    slid = float(np.hypot(*(res.pose[:2] - start[:2])))
    if slid > params.max_refine_m:
        why = f"ICP slid {slid:.2f} m > {params.max_refine_m:g} m from the search's match"
    elif res.inlier_fraction < params.min_inliers:
        why = f"inliers {res.inlier_fraction:.2f} < {params.min_inliers:g}"
    elif not res.rms_m <= params.max_rms_m:
        why = f"RMS {res.rms_m:.3f} m > {params.max_rms_m:g} m"
    elif res.degeneracy < params.min_degeneracy:
        why = f"degenerate ({res.degeneracy:.3f})"
    else:
        cov = closure_covariance(submap, data, res.pose, params)
        fit = replace(proposal, inliers=res.inlier_fraction, rms_m=res.rms_m)
        return replace(fit, T_j_i=res.pose, covariance=cov)
    return replace(proposal, inliers=res.inlier_fraction, rms_m=res.rms_m, why_not=why)


def _global_due(a: int, last_found: int, last_global: int, params: LoopParams) -> bool:
    """Whether keyframe position ``a``, whose local search found nothing, runs the global
    search: at most every ``global_every`` keyframes, and not within ``global_every`` of
    the last closure found (the local search is then still on track)."""
    every = params.global_every
    return every > 0 and a - last_found >= every and a - last_global >= every


def global_search(
    scans: Sequence[FloatArray],
    poses: FloatArray,
    along: FloatArray,
    i: int,
    earlier: NDArray[np.intp],
    dist_m: FloatArray,
    window_m: FloatArray,
    path_m: FloatArray,
    params: LoopParams,
) -> list[Closure]:
    """The global search for keyframe i when the local one found nothing (module
    docstring, step 1b): of the earlier keyframes ``earlier`` beyond their local window
    (``window_m``, at ``dist_m`` from i by the poses) but within the drift model's reach
    over the graph path ``path_m`` (step 1's window uncapped, at most ``max_global_m``),
    nearest first, at most ``global_candidates`` of them ``2 submap_m`` of path apart are
    each matched by :func:`verify_global`, in a yaw window of the drift model's, at least
    ``global_rad``; the closures tried, the last the accepted one if any; on
    ``workers`` threads at once (the same closures as one by one)."""
    L = np.maximum(path_m, 0.0)
    a, b = params.drift_per_m, params.drift_rad_per_sqrt_m
    sigma_xy = np.sqrt((a * L) ** 2 + b**2 * L**3 / 3.0)
    reach = np.minimum(params.search_m + params.n_sigma * sigma_xy, params.max_global_m)
    yaw_window = np.maximum(params.n_sigma * b * np.sqrt(L), params.global_rad)
    far = np.flatnonzero((dist_m > window_m) & (dist_m <= reach + params.global_window_m))
    picked: list[int] = []
    for c in far[np.argsort(dist_m[far])]:
        if all(abs(along[earlier[c]] - along[earlier[p]]) >= 2 * params.submap_m for p in picked):
            picked.append(int(c))
        if len(picked) == params.global_candidates:
            break

    def match(c: int) -> Closure:
        return verify_global(scans, poses, along, i, int(earlier[c]), float(yaw_window[c]), params)

    if params.workers == 1 or len(picked) < 2:
        return _until_accepted(map(match, picked))
    # The candidates are matched at once on threads (the branch and bound and ICP kernels
    # release the GIL) and taken in order up to the first accepted, as one by one.
    with ThreadPoolExecutor(min(params.workers, len(picked))) as pool:
        futures = [pool.submit(match, c) for c in picked]
        out = _until_accepted(f.result() for f in futures)
        for f in futures[len(out) :]:
            f.cancel()
    return out


def _until_accepted(closures: Iterator[Closure]) -> list[Closure]:
    """The closures up to and with the first accepted one."""
    out = []
    for closure in closures:
        out.append(closure)
        if closure.T_j_i is not None:
            break
    return out


def local_map(
    scans: Sequence[FloatArray],
    poses: FloatArray,
    at: int,
    which: NDArray[np.intp],
    params: LoopParams,
) -> FloatArray:
    """The returns of scans ``which`` moved into scan ``at``'s frame by the poses, one per
    ``voxel_m`` cell (M, 2)."""
    rel = relative(np.repeat(poses[at][None], len(which), 0), poses[which])
    parts = [np.zeros((0, 2))]
    for k, T in zip(which, rel, strict=True):
        pts = scans[k]
        c, s = np.cos(T[2]), np.sin(T[2])
        parts.append(pts @ np.array([[c, s], [-s, c]]) + T[:2])
    return voxel_filter(np.vstack(parts), params.voxel_m)


def correlative_match(
    model: FloatArray,
    data: FloatArray,
    guess: FloatArray,
    window_m: float,
    window_rad: float,
    params: LoopParams,
    *,
    kernel: bool = True,
) -> tuple[FloatArray, float, float]:
    """The pose T_model_data (x, y, yaw) within ``window_m`` / ``window_rad`` of ``guess``
    that puts ``data`` (N, 2) best on ``model`` (M, 2), and its score: the mean over the
    points of exp(-d^2 / 2 r^2), d the distance to the nearest model point on a grid of
    r = ``grid_m`` (Olson 2009), and the best score of the poses farther than
    ``ambiguity_m`` from it. Branch and bound over one coarse level (module docstring).
    ``kernel=False`` scores the shifts with numpy (the compiled kernel's reference)."""
    r, k = params.grid_m, params.coarse
    like, lo, hi = bnb.likelihood_grid(model, r, k + 1)
    # Block (u, v) of the coarse grid holds the best fine cell among u..u+k-1, v..v+k-1:
    # an upper bound of the score of any shift inside the block.
    bound = maximum_filter(like, size=k, origin=-(k // 2), mode="constant")
    n_t = int(np.ceil(window_m / (k * r)))
    shifts = np.arange(-n_t, n_t, dtype=np.int64) * k  # coarse blocks, in fine cells
    n_y = int(np.ceil(window_rad / params.yaw_step_rad))
    yaws = guess[2] + np.arange(-n_y, n_y + 1) * params.yaw_step_rad
    c, s = np.cos(yaws)[:, None], np.sin(yaws)[:, None]
    qx = c * data[:, 0] - s * data[:, 1] + guess[0]  # (Y, P) the points at each yaw
    qy = s * data[:, 0] + c * data[:, 1] + guess[1]
    bases = np.stack([np.floor((qx - lo[0]) / r), np.floor((qy - lo[1]) / r)]).astype(np.int64)  # (2, Y, P)
    scores = _block_scores if kernel else block_scores_numpy
    bounds = scores(bound, bases[0], bases[1], shifts, shifts, int(hi[0]), int(hi[1]))
    args = (bounds, bases, like, shifts, yaws, guess, r, k, hi, scores)
    best, best_pose = _best_in_blocks(*args, None, 0.0)
    # The best elsewhere (beyond ``ambiguity_m`` of the best): a corridor's repeated doors
    # or a long wall fit as well a few metres along, and such a match is no closure.
    second, _ = _best_in_blocks(*args, best_pose, params.ambiguity_m)
    return best_pose, best, max(second, 0.0)


def _best_in_blocks(
    bounds: FloatArray,
    bases: NDArray[np.int64],
    like: FloatArray,
    shifts: NDArray[np.int64],
    yaws: FloatArray,
    guess: FloatArray,
    r: float,
    k: int,
    hi: NDArray[np.int_],
    scores_of: Callable[..., FloatArray],
    away_from: FloatArray | None,
    away_m: float,
) -> tuple[float, FloatArray]:
    """Branch and bound: the best fine score and its pose among the coarse blocks, best
    bound first, skipping blocks within ``away_m`` of ``away_from`` when given."""
    best, best_pose = -1.0, guess.copy()
    fine = np.arange(k, dtype=np.int64)
    block_m = k * r
    searched = 0
    for flat in np.argsort(-bounds, axis=None):
        if bounds.flat[flat] <= best or searched >= _MAX_BLOCKS:
            break
        y, u, v = np.unravel_index(flat, bounds.shape)
        corner = guess[:2] + np.array([shifts[u], shifts[v]]) * r
        if away_from is not None and np.hypot(*(corner + block_m / 2 - away_from[:2])) < away_m + block_m:
            continue
        searched += 1
        bu, bv = bases[0, y : y + 1], bases[1, y : y + 1]
        su, sv = shifts[u] + fine, shifts[v] + fine
        scores = scores_of(like, bu, bv, su, sv, int(hi[0]), int(hi[1]))[0]  # (k, k)
        du, dv = np.unravel_index(np.argmax(scores), scores.shape)
        if scores[du, dv] > best:
            best = float(scores[du, dv])
            best_pose = np.array([corner[0] + du * r, corner[1] + dv * r, yaws[y]])
    return best, best_pose


def block_scores_numpy(
    grid: FloatArray,
    base_u: NDArray[np.int64],
    base_v: NDArray[np.int64],
    shift_u: NDArray[np.int64],
    shift_v: NDArray[np.int64],
    hi_u: int,
    hi_v: int,
) -> FloatArray:
    """(Y, U, V) the mean of ``grid`` over the points' cells (Y, P) shifted by each
    (shift_u, shift_v), cells clipped to the grid (its border is 0)."""
    out = np.empty((len(base_u), len(shift_u), len(shift_v)))
    for y in range(len(base_u)):
        iu = np.clip(base_u[y][None, :] + shift_u[:, None], 0, hi_u)
        iv = np.clip(base_v[y][None, :] + shift_v[:, None], 0, hi_v)
        out[y] = grid[iu[:, None, :], iv[None, :, :]].mean(axis=2)
    return out


@njit
def _block_scores(
    grid: FloatArray,
    base_u: NDArray[np.int64],
    base_v: NDArray[np.int64],
    shift_u: NDArray[np.int64],
    shift_v: NDArray[np.int64],
    hi_u: int,
    hi_v: int,
) -> FloatArray:  # pragma: no cover - compiled; block_scores_numpy is its reference
    n_y, n_p = base_u.shape
    out = np.empty((n_y, len(shift_u), len(shift_v)))
    for y in range(n_y):
        for a in range(len(shift_u)):
            for b in range(len(shift_v)):
                total = 0.0
                for p in range(n_p):
                    u = min(max(base_u[y, p] + shift_u[a], 0), hi_u)
                    v = min(max(base_v[y, p] + shift_v[b], 0), hi_v)
                    total += grid[u, v]
                out[y, a, b] = total / n_p
    return out


def voxel_filter(points: FloatArray, voxel_m: float) -> FloatArray:
    """The first point of each ``voxel_m`` square cell, in the points' order."""
    if not len(points):
        return points
    cells = np.floor(points / voxel_m).astype(np.int64)
    cells -= cells.min(axis=0)
    key = cells[:, 0] * (int(cells[:, 1].max()) + 1) + cells[:, 1]
    _, first = np.unique(key, return_index=True)
    return points[np.sort(first)]


def relative(pa: FloatArray, pb: FloatArray) -> FloatArray:
    """(M, 3) T_a_b of poses a and b (M, 3), vectorised."""
    c, s = np.cos(pa[:, 2]), np.sin(pa[:, 2])
    dx, dy = pb[:, 0] - pa[:, 0], pb[:, 1] - pa[:, 1]
    return np.column_stack([c * dx + s * dy, -s * dx + c * dy, np.angle(np.exp(1j * (pb[:, 2] - pa[:, 2])))])


def compose(pa: FloatArray, rel: FloatArray) -> FloatArray:
    """(M, 3) the poses a (M, 3) composed with T_a_b (M, 3), vectorised."""
    c, s = np.cos(pa[:, 2]), np.sin(pa[:, 2])
    return np.column_stack(
        [
            pa[:, 0] + c * rel[:, 0] - s * rel[:, 1],
            pa[:, 1] + s * rel[:, 0] + c * rel[:, 1],
            pa[:, 2] + rel[:, 2],
        ]
    )


def closure_covariance(
    submap: FloatArray, data: FloatArray, pose: FloatArray, params: LoopParams
) -> FloatArray:
    """T_j_i's covariance (3, 3) from the closure's fit of the scan ``data`` (P, 2) to the
    ``submap`` (M, 2) at ``pose``: the point-to-line Hessian of ICP's cost (Eq. (4)),
    sigma^2 (J^T J)^-1 with sigma the residuals' robust spread
    (:func:`rigcal.localize.icp.icp_covariance`, normals from the submap's nearest
    neighbours), plus ``closure_floor_sigmas`` squared on its diagonal: the submap's own
    placement error, which the fit's residuals see only in part. ``closure_sigmas`` where
    the fit has too few pairs."""
    tree = cKDTree(submap)
    ip = IcpParams(method="point-to-line")
    normals, _ = pairing_normals(submap, tree, ip.normal_neighbours, None)
    c, s = np.cos(pose[2]), np.sin(pose[2])
    _, nearest = tree.query(data @ np.array([[c, s], [-s, c]]) + pose[:2])
    cov = icp_covariance(submap, data, pose, nearest, normals, ip.reject_m, params.min_degeneracy)
    if not np.isfinite(cov).all():
        return np.diag(np.square(params.closure_sigmas))
    return np.asarray(cov + np.diag(np.square(params.closure_floor_sigmas)), dtype=float)


def build_graph(
    odometry: FloatArray,
    start: FloatArray,
    closures: list[Closure],
    last: int,
    params: LoopParams,
    step_covariances: FloatArray | None = None,
) -> PoseGraph:
    """The graph of poses 0..last: the odometry's steps (each with its own covariance where
    ``step_covariances`` has one, else the fixed sigmas) and the closures (each with its
    fit's covariance where it has one, else ``closure_sigmas``), started at ``start``."""
    steps = relative(odometry[:last], odometry[1 : last + 1])
    length = np.hypot(steps[:, 0], steps[:, 1])
    step_sig = np.array(params.step_sigmas)[None, :] + params.step_sigma_per_m * length[:, None]
    measured = np.array([c.T_j_i for c in closures], dtype=float).reshape(-1, 3)
    covariances = None
    if step_covariances is not None or any(c.covariance is not None for c in closures):
        own = np.full((last, 3, 3), np.nan) if step_covariances is None else step_covariances[1 : last + 1]
        if params.step_drift:
            # Where the scans do not constrain a step (a corridor's length), ICP keeps its
            # initial guess, and its Hessian's covariance there is unbounded (metres): the
            # step is then as certain as the guess, the fixed step sigmas' prior. Fused as
            # information, the prior caps those directions and leaves the constrained ones
            # to the fit; without it the graph puts a loop's whole correction into the few
            # degenerate steps.
            own = _capped(own, step_sig)
            # The drift the search window assumes (step 1), per step: a scale error
            # drift_per_m and a heading random walk drift_rad_per_sqrt_m, which the fit's
            # own covariance does not see; compounded over L metres they give the window's
            # position and heading sigmas.
            a, b = params.drift_per_m, params.drift_rad_per_sqrt_m
            drift = np.zeros((last, 3, 3))
            drift[:, 0, 0] = drift[:, 1, 1] = (a * length) ** 2
            drift[:, 2, 2] = b**2 * length
            own = own + drift
        fixed = np.diag(np.square(params.closure_sigmas))
        of_closures = [fixed if c.covariance is None else c.covariance for c in closures]
        covariances = np.concatenate([own, np.array(of_closures).reshape(-1, 3, 3)])
    return PoseGraph(
        poses=start[: last + 1].copy(),
        a=np.r_[np.arange(last), [c.j for c in closures]].astype(np.intp),
        b=np.r_[np.arange(1, last + 1), [c.i for c in closures]].astype(np.intp),
        z=np.vstack([steps, measured]),
        sigmas=np.vstack([step_sig, np.tile(params.closure_sigmas, (len(closures), 1))]),
        robust=np.r_[np.zeros(last, dtype=bool), np.ones(len(closures), dtype=bool)],
        covariances=covariances,
    )


def _capped(own: FloatArray, prior_sigmas: FloatArray) -> FloatArray:
    """(M, 3, 3) each finite, positive definite covariance ``own`` fused with the prior
    diag(``prior_sigmas``^2) (M, 3) as information: (own^-1 + prior^-1)^-1; NaN kept."""
    out = own.copy()
    ok = np.flatnonzero(np.isfinite(own).all(axis=(1, 2)))
    ok = ok[np.linalg.eigvalsh(own[ok])[:, 0] > 0]
    info = np.linalg.inv(own[ok])
    idx = np.arange(3)
    info[:, idx, idx] += 1.0 / np.square(prior_sigmas[ok])
    out[ok] = np.linalg.inv(info)
    return out


def _whitened(est: FloatArray, closures: list[Closure], params: LoopParams) -> FloatArray:
    """Each closure's whitened disagreement with the poses ``est``."""
    z = np.array([c.T_j_i for c in closures], dtype=float)
    fixed = np.diag(np.square(params.closure_sigmas))
    cov = np.array([fixed if c.covariance is None else c.covariance for c in closures])
    e = edge_errors(est[[c.j for c in closures]], est[[c.i for c in closures]], z)
    return np.sqrt(np.einsum("mi,mi->m", e, np.linalg.solve(cov, e[:, :, None])[:, :, 0]))


def _corrected(
    odometry: FloatArray,
    est: FloatArray,
    closures: list[Closure],
    i: int,
    params: LoopParams,
    backend: str,
    step_covariances: FloatArray | None = None,
) -> FloatArray:
    """The poses with the graph of poses 0..i optimised and the later poses moved with
    pose i along the odometry."""
    head, _ = optimise(build_graph(odometry, est, closures, i, params, step_covariances), backend)
    out = est.copy()
    out[: i + 1] = head
    if i + 1 < len(est):
        tail = relative(np.repeat(odometry[i][None], len(est) - i - 1, 0), odometry[i + 1 :])
        out[i + 1 :] = compose(np.repeat(head[i][None], len(tail), 0), tail)
        out[i + 1 :, 2] = head[i, 2] + odometry[i + 1 :, 2] - odometry[i, 2]  # yaw kept continuous
    return out


def nearest_scans(scan_stamps_s: FloatArray, stamps_s: FloatArray) -> NDArray[np.intp]:
    """(M,) the index of the scan stamp nearest each stamp (scan stamps increasing)."""
    if len(scan_stamps_s) == 1:
        return np.zeros(len(stamps_s), dtype=np.intp)
    k = np.clip(np.searchsorted(scan_stamps_s, stamps_s), 1, len(scan_stamps_s) - 1)
    return np.where(stamps_s - scan_stamps_s[k - 1] <= scan_stamps_s[k] - stamps_s, k - 1, k).astype(np.intp)


def laser_at(scan_stamps_s: FloatArray, laser_poses: FloatArray, stamps_s: FloatArray) -> FloatArray:
    """(M, 3) the laser odometry's poses (N, 3) at ``scan_stamps_s`` interpolated at the
    stamps (yaw unwrapped), held at the ends."""
    yaw = np.unwrap(laser_poses[:, 2])
    return np.column_stack([np.interp(stamps_s, scan_stamps_s, v) for v in (*laser_poses[:, :2].T, yaw)])


def step_covariances(
    scan_stamps_s: FloatArray,
    laser_poses: FloatArray,
    laser_covariances: FloatArray,
    stamps_s: FloatArray,
    poses: FloatArray,
) -> FloatArray:
    """(M, 3, 3) a method's step covariances for the pose graph: for each step of its
    poses (M, 3) at ``stamps_s`` (index k: from k - 1 to k; index 0 NaN), the laser
    odometry's covariance over the step (:func:`chained_covariances`) plus d d^T, d the
    step's departure from the laser odometry's motion over the same time (x, y, yaw):
    where a method left the laser's motion (a Kalman filter pulled by visual odometry at
    a stop), the two disagree by d and the step is no more certain than that; for ICP
    itself d = 0."""
    cov = chained_covariances(scan_stamps_s, laser_poses, laser_covariances, stamps_s)
    laser = laser_at(scan_stamps_s, laser_poses, stamps_s)
    d = relative(poses[:-1], poses[1:]) - relative(laser[:-1], laser[1:])
    d[:, 2] = np.angle(np.exp(1j * d[:, 2]))
    cov[1:] += np.einsum("mi,mj->mij", d, d)
    return cov


def scans_at(
    scans: Sequence[Scan], scan_stamps_s: FloatArray, laser_poses: FloatArray, stamps_s: FloatArray
) -> list[FloatArray]:
    """Each stamp's laser returns (P, 2), in the laser frame at that stamp: the valid
    returns of the scan nearest it, moved by the laser odometry (``laser_poses`` (N, 3) at
    ``scan_stamps_s``, interpolated) over the time between (a 10 Hz image's pose and its
    nearest 40 Hz scan are up to 12.5 ms, a centimetre of walking, apart)."""
    k = nearest_scans(scan_stamps_s, stamps_s)
    at = laser_at(scan_stamps_s, laser_poses, stamps_s)
    T = relative(at, laser_at(scan_stamps_s, laser_poses, scan_stamps_s[k]))  # each scan's pose at its stamp
    out = []
    for kk, (x, y, a) in zip(k, T, strict=True):
        pts = scans[kk].points[scans[kk].valid]
        c, s = np.cos(a), np.sin(a)
        out.append(pts @ np.array([[c, s], [-s, c]]) + np.array([x, y]))
    return out


def chained_covariances(
    scan_stamps_s: FloatArray, laser_poses: FloatArray, laser_covariances: FloatArray, stamps_s: FloatArray
) -> FloatArray:
    """(M, 3, 3) the covariance of the laser odometry's motion between consecutive stamps
    (index k: from stamp k - 1 to k; index 0 NaN): its steps' covariances
    (``laser_covariances`` (N, 3, 3), the step ending at scan k at index k) over the time
    between the two stamps, compounded to first order (p = p1 + p2 on SE(2): Sigma = J1
    Sigma1 J1^T + J2 Sigma2 J2^T). A step the interval covers in part counts with that
    fraction of its motion and of its covariance (a random walk within the step), so that
    the pieces of a step between a scan and an image add up to the step. NaN where a step
    it covers has no covariance, or where the interval is empty (the fixed sigmas then)."""
    steps = np.full((len(laser_poses), 3), np.nan)
    steps[1:] = relative(laser_poses[:-1], laser_poses[1:])
    out = np.full((len(stamps_s), 3, 3), np.nan)
    t = np.clip(stamps_s, scan_stamps_s[0], scan_stamps_s[-1])
    first = np.searchsorted(scan_stamps_s, t, side="right")  # the step that covers t (ends after it)
    for m in range(1, len(t)):
        if not t[m] > t[m - 1]:
            continue
        p, cov = np.zeros(3), np.zeros((3, 3))
        for q in range(first[m - 1], min(first[m], len(steps) - 1) + 1):
            span = scan_stamps_s[q] - scan_stamps_s[q - 1]
            covered = min(t[m], scan_stamps_s[q]) - max(t[m - 1], scan_stamps_s[q - 1])
            if covered <= 0:
                continue
            frac = covered / span if span > 0 else 1.0
            step = frac * steps[q]
            c, s = np.cos(p[2]), np.sin(p[2])
            J1 = np.array(
                [[1.0, 0.0, -s * step[0] - c * step[1]], [0.0, 1.0, c * step[0] - s * step[1]], [0, 0, 1]]
            )
            J2 = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
            cov = J1 @ cov @ J1.T + frac * (J2 @ laser_covariances[q] @ J2.T)
            p = compose(p[None], step[None])[0]
        out[m] = cov
    return out
