"""Image place recognition for loop closure: a bag of binary words, as DBoW2.

The paper hopes that image-augmented accuracy makes loop closures easier to detect
(Section VIII); images also recognise a place where the poses have drifted too far for
the scan search to look (:mod:`rigcal.localize.loop_closure`, step 1). Following
Galvez-Lopez and Tardos 2012 ("Bags of binary words for fast place recognition in image
sequences", DBoW2):

1. **Features**: ORB keypoints and their 256-bit descriptors (OpenCV) in each keyframe's
   image (the frame nearest its stamp).
2. **Vocabulary**: a tree of binary words trained on the sequence's own keyframe images
   (no vocabulary file, no download): the descriptors are split by k-majority
   (k-means with Hamming distances and bitwise-majority centres, seeded as k-means++)
   into ``branching`` clusters, each cluster again, ``depth`` levels deep; the leaves
   are the words. A descriptor's word is found by descending to the nearest centre.
3. **Scoring**: each image is a vector of tf-idf weights (a word's share of the image's
   words times ln(N / n_w), n_w of the N images holding it), L1-normalised, and two
   images score s = 1 - |v1 - v2|_1 / 2 (DBoW2's L1 score, 0 to 1). A keyframe's score
   against an earlier one is normalised by its best score against its ``neighbours``
   previous keyframes (DBoW2's eta = s / s(v_t, v_t-1), here best of several so that
   one blurred neighbour does not inflate it); earlier keyframes within ``min_loop_m`` of
   path are not queried.
4. **Candidates**: the ``candidates`` best earlier keyframes whose normalised score is at
   least ``min_normalised`` (at most one per ``island_m`` of path: neighbouring keyframes
   see the same place), best first.
5. **Geometric verification**: each candidate's ORB features are matched to the
   keyframe's (nearest Hamming neighbours passing Lowe's ratio test both ways), the
   matches' bearings through the rig's camera (distortion undone) are fitted by an
   essential matrix with RANSAC (OpenCV's ``findEssentialMat`` on normalised
   coordinates) and the pose recovered; the candidate passes with at least
   ``min_inliers`` inliers in front of both cameras. The best (most inliers) is the
   keyframe's proposal, with the relative yaw the essential matrix gives, moved into the
   laser frame by the rig's T_cam_laser (the translation's scale is unknown to images).

Each proposal then goes through the scan verification as any closure does
(:func:`rigcal.localize.loop_closure.close_loops`, ``proposals``): searched around the
image's yaw when the current poses put the two keyframes beyond the scan search's window.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import NDArray

from rigcal.arrays import FloatArray
from rigcal.camera import Camera
from rigcal.jit import njit

Gray = NDArray[np.uint8]
Descriptors = NDArray[np.uint8]  # (N, 32) ORB descriptors, 256 bits each
_BYTES = 32


@dataclass(frozen=True)
class PlaceParams:
    """Image place recognition's settings (module docstring)."""

    n_features: int = 500
    branching: int = 10
    depth: int = 3
    iterations: int = 10
    neighbours: int = 3
    min_normalised: float = 0.5
    candidates: int = 3
    island_m: float = 3.0
    ratio: float = 0.8
    ransac_px: float = 1.0
    min_inliers: int = 40
    max_image_gap_s: float = 0.2
    window_m: float = 3.0
    window_rad: float = 0.3
    seed: int = 0

    def __post_init__(self) -> None:
        if self.n_features < 8 or self.branching < 2 or self.depth < 1 or self.iterations < 1:
            raise ValueError("n_features at least 8, branching at least 2, depth and iterations at least 1")
        if self.candidates < 1 or self.neighbours < 1 or self.min_inliers < 5:
            raise ValueError("candidates and neighbours at least 1, min_inliers at least 5")
        if not (0 < self.ratio <= 1 and self.ransac_px > 0 and self.window_m > 0 and self.window_rad > 0):
            raise ValueError("ratio in (0, 1], ransac_px, window_m and window_rad positive")


@dataclass(frozen=True)
class Features:
    """One image's ORB keypoints (N, 2) (pixels) and descriptors (N, 32)."""

    pixels: FloatArray
    descriptors: Descriptors


@dataclass(frozen=True)
class Vocabulary:
    """A tree of binary words (module docstring, step 2).

    Attributes:
        centres: (M, 32) each node's centre, a binary descriptor (node 0 the root, no centre).
        children: (M, branching) each node's children, -1 where it has fewer.
        word: (M,) each leaf's word index, -1 for inner nodes.
    """

    centres: NDArray[np.uint8]
    children: NDArray[np.intp]
    word: NDArray[np.intp]

    @property
    def n_words(self) -> int:
        return int(self.word.max()) + 1

    def words(self, descriptors: Descriptors) -> NDArray[np.intp]:
        """(N,) the word of each descriptor (N, 32): down the tree to the nearest centre."""
        bits = np.asarray(descriptors, dtype=np.uint8)
        node = np.zeros(len(bits), dtype=np.intp)
        while True:
            inner = self.word[node] < 0
            if not inner.any():
                return self.word[node]
            for n in np.unique(node[inner]):
                at = np.flatnonzero(node == n)
                kids = self.children[n][self.children[n] >= 0]
                node[at] = kids[_nearest(bits[at], self.centres[kids])[0]]


@dataclass(frozen=True)
class PlaceProposal:
    """Keyframe position ``a`` proposed as a revisit of earlier keyframe position ``b``:
    the BoW score, normalised score, essential-matrix inliers, and the relative yaw
    T_b_a (rad) of the laser by the images."""

    a: int
    b: int
    score: float
    normalised: float
    inliers: int
    yaw_rad: float


@dataclass(frozen=True)
class PlaceResult:
    """The proposals and what was looked at: ``described`` keyframes with an image,
    ``candidates`` (keyframe, earlier) pairs by the scores, of them ``geometric_rejected``
    by the essential matrix; ``note`` why there were none where there could not be."""

    proposals: list[PlaceProposal] = field(default_factory=list)
    described: int = 0
    candidates: int = 0
    geometric_rejected: int = 0
    note: str = ""

    @property
    def stats(self) -> dict[str, object]:
        out: dict[str, object] = {
            "keyframes_with_images": self.described,
            "candidates": self.candidates,
            "rejected_by_geometry": self.geometric_rejected,
            "proposed": len(self.proposals),
        }
        if self.note:
            out["note"] = self.note
        return out


def orb_features(gray: Gray, params: PlaceParams) -> Features:
    """ORB keypoints and descriptors of a grey image (module docstring, step 1)."""
    orb = cv2.ORB_create(nfeatures=params.n_features)  # type: ignore[attr-defined]
    kps, desc = orb.detectAndCompute(gray, None)
    if desc is None or not kps:
        return Features(np.zeros((0, 2)), np.zeros((0, 32), dtype=np.uint8))
    return Features(np.array([k.pt for k in kps], dtype=float), np.asarray(desc, dtype=np.uint8))


def hamming(a: Descriptors, b: Descriptors) -> NDArray[np.int64]:
    """(N, M) Hamming distances between binary descriptors a (N, 32) and b (M, 32)
    (numpy; the reference of the compiled :func:`_nearest`)."""
    out: NDArray[np.int64] = np.bitwise_count(a[:, None, :] ^ b[None, :, :]).sum(axis=2, dtype=np.int64)
    return out


def _nearest(a: Descriptors, b: Descriptors) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """(N,) the nearest of descriptors b (M, 32) to each of a (N, 32) by Hamming distance
    (the first of equals), and (N,) that distance."""
    return _nearest_kernel(np.ascontiguousarray(a), np.ascontiguousarray(b), _POPCOUNT)


_POPCOUNT = np.array([bin(v).count("1") for v in range(256)], dtype=np.int64)


@njit
def _nearest_kernel(
    a: Descriptors, b: Descriptors, popcount: NDArray[np.int64]
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:  # pragma: no cover - compiled; hamming is its reference
    label = np.zeros(a.shape[0], dtype=np.int64)
    dist = np.zeros(a.shape[0], dtype=np.int64)
    for n in range(a.shape[0]):
        best = 1 << 30
        for m in range(b.shape[0]):
            d = 0
            for k in range(a.shape[1]):
                d += popcount[a[n, k] ^ b[m, k]]
            if d < best:
                best = d
                label[n] = m
        dist[n] = best
    return label, dist


def _majorities(bits: Descriptors, label: NDArray[np.int64], old: Descriptors) -> Descriptors:
    """(K, 32) each cluster's bitwise majority of its descriptors (a tie sets the bit);
    ``old``'s row for a cluster left empty."""
    ones, size = _bit_counts(bits, label, len(old))
    out = np.packbits((2 * ones >= size[:, None]).astype(np.uint8), axis=1)
    out[size == 0] = old[size == 0]
    return out


@njit
def _bit_counts(
    bits: Descriptors, label: NDArray[np.int64], k: int
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:  # pragma: no cover - compiled; tested via _majorities
    """(K, 256) each cluster's count of set bits (most significant bit of each byte first,
    as np.unpackbits), and (K,) its size."""
    ones = np.zeros((k, 8 * bits.shape[1]), dtype=np.int64)
    size = np.zeros(k, dtype=np.int64)
    for n in range(bits.shape[0]):
        m = label[n]
        size[m] += 1
        for byte in range(bits.shape[1]):
            v = bits[n, byte]
            for bit in range(8):
                if v & (128 >> bit):
                    ones[m, 8 * byte + bit] += 1
    return ones, size


def _k_majority(bits: Descriptors, k: int, iterations: int, rng: np.random.Generator) -> Descriptors:
    """(k', 32) k-majority centres of the descriptors (k' <= k where they repeat): seeded as
    k-means++ (each next seed drawn with probability by its squared distance to the
    nearest seed), then assignment and bitwise majority in turn."""
    c = bits[rng.integers(len(bits))][None]
    d = _nearest(bits, c)[1]
    while len(c) < k and d.sum() > 0:
        w = d.astype(float) ** 2
        c = np.vstack([c, bits[rng.choice(len(bits), p=w / w.sum())]])
        d = _nearest(bits, c)[1]
    for _ in range(iterations):
        new = _majorities(bits, _nearest(bits, c)[0], c)
        if np.array_equal(new, c):
            break
        c = new
    return c


def train_vocabulary(descriptors: Sequence[Descriptors], params: PlaceParams) -> Vocabulary:
    """A vocabulary tree from the images' descriptors (module docstring, step 2)."""
    rng = np.random.default_rng(params.seed)
    parts = [d for d in descriptors if len(d)]
    bits = np.vstack(parts) if parts else np.zeros((0, _BYTES), dtype=np.uint8)
    centres = [np.zeros(_BYTES, dtype=np.uint8)]
    children: list[list[int]] = [[]]
    stack = [(0, np.arange(len(bits)), 0)]
    while stack:
        node, rows, level = stack.pop()
        if level == params.depth or len(rows) <= params.branching:
            continue
        c = _k_majority(bits[rows], params.branching, params.iterations, rng)
        label = _nearest(bits[rows], c)[0]
        for m in range(len(c)):
            children[node].append(len(centres))
            centres.append(c[m])
            children.append([])
            stack.append((len(centres) - 1, rows[label == m], level + 1))
    kids = np.full((len(centres), params.branching), -1, dtype=np.intp)
    for n, ch in enumerate(children):
        kids[n, : len(ch)] = ch
    leaves = np.array([not ch for ch in children])
    word = np.full(len(centres), -1, dtype=np.intp)
    word[leaves] = np.arange(int(leaves.sum()))
    return Vocabulary(np.array(centres, dtype=np.uint8), kids, word)


def bow_vectors(vocab: Vocabulary, descriptors: Sequence[Descriptors]) -> FloatArray:
    """(N, W) each image's L1-normalised tf-idf vector (module docstring, step 3); idf
    from these N images."""
    counts = np.zeros((len(descriptors), vocab.n_words))
    for n, d in enumerate(descriptors):
        if len(d):
            np.add.at(counts[n], vocab.words(d), 1.0)
    held = np.count_nonzero(counts, axis=0)
    idf = np.where(held > 0, np.log(len(descriptors) / np.maximum(held, 1)), 0.0)
    tf = counts / np.maximum(counts.sum(axis=1, keepdims=True), 1.0)
    v = tf * idf
    out: FloatArray = v / np.maximum(np.abs(v).sum(axis=1, keepdims=True), 1e-12)
    return out


def l1_scores(v: FloatArray, w: FloatArray) -> FloatArray:
    """(N, M) DBoW2's L1 score between L1-normalised vectors v (N, W) and w (M, W):
    1 - |v - w|_1 / 2, 1 for the same words in the same shares, 0 for no word shared."""
    out: FloatArray = 1.0 - 0.5 * np.abs(v[:, None, :] - w[None, :, :]).sum(axis=2)
    return out


def candidates(
    scores: FloatArray, along_m: FloatArray, a: int, params: PlaceParams, min_loop_m: float
) -> list[tuple[int, float, float]]:
    """Keyframe position a's candidates (module docstring, steps 3 and 4): (b, score,
    normalised score) of the earlier keyframes at least ``min_loop_m`` of path back,
    best first. ``scores``: (K, K) the keyframes' L1 scores (NaN for a keyframe without
    an image); ``along_m``: (K,) their path along the odometry."""
    own = [b for b in range(max(0, a - params.neighbours), a) if np.isfinite(scores[a, b])]
    best_neighbour = max((scores[a, b] for b in own), default=np.nan)
    if not best_neighbour > 0:
        return []
    earlier = np.flatnonzero((along_m[a] - along_m[:a] >= min_loop_m) & np.isfinite(scores[a, :a]))
    out: list[tuple[int, float, float]] = []
    for b in earlier[np.argsort(-scores[a, earlier], kind="stable")]:
        eta = float(scores[a, b] / best_neighbour)
        if eta < params.min_normalised or len(out) == params.candidates:
            break
        if all(abs(along_m[b] - along_m[c]) >= params.island_m for c, _, _ in out):
            out.append((int(b), float(scores[a, b]), eta))
    return out


def ratio_matches(da: Descriptors, db: Descriptors, ratio: float) -> NDArray[np.intp]:
    """(M, 2) index pairs (in a, in b) of mutual nearest Hamming neighbours that pass
    Lowe's ratio test both ways."""
    if len(da) < 2 or len(db) < 2:
        return np.zeros((0, 2), dtype=np.intp)
    bf = cv2.BFMatcher(cv2.NORM_HAMMING)

    def best(x: Descriptors, y: Descriptors) -> dict[int, int]:
        out = {}
        for m in bf.knnMatch(x, y, k=2):
            if len(m) == 2 and m[0].distance < ratio * m[1].distance:
                out[m[0].queryIdx] = m[0].trainIdx
        return out

    ab, ba = best(da, db), best(db, da)
    pairs = [(q, t) for q, t in ab.items() if ba.get(t) == q]
    return np.array(pairs, dtype=np.intp).reshape(-1, 2)


def essential_check(
    fa: Features, fb: Features, camera: Camera, params: PlaceParams
) -> tuple[int, FloatArray | None]:
    """Geometric verification of an image pair (module docstring, step 5): the inliers in
    front of both cameras of the essential matrix fitted by RANSAC to the ratio-test
    matches, and R_cb_ca (3, 3) (None with too few matches)."""
    pairs = ratio_matches(fa.descriptors, fb.descriptors, params.ratio)
    if len(pairs) < max(params.min_inliers, 8):
        return len(pairs), None
    ra, rb = camera.bearings(fa.pixels[pairs[:, 0]]), camera.bearings(fb.pixels[pairs[:, 1]])
    ok = (ra[:, 2] > 1e-6) & (rb[:, 2] > 1e-6)
    if ok.sum() < 8:
        return int(ok.sum()), None
    xa, xb = ra[ok, :2] / ra[ok, 2:], rb[ok, :2] / rb[ok, 2:]
    f = float(np.mean(camera.K[[0, 1], [0, 1]]))
    E, mask = cv2.findEssentialMat(
        xa, xb, np.eye(3), method=cv2.RANSAC, prob=0.999, threshold=params.ransac_px / f
    )
    if E is None or E.shape != (3, 3):
        return 0, None
    n, R, _, _ = cv2.recoverPose(E, xa, xb, np.eye(3), mask=mask)
    return int(n), np.asarray(R, dtype=float)


def laser_yaw(R_cb_ca: FloatArray, T_cam_laser: FloatArray) -> float:
    """The yaw (rad) of T_lb_la, laser a in laser b's frame, from the cameras' rotation:
    R_lb_la = R_l_c R_cb_ca R_c_l."""
    R_c_l = T_cam_laser[:3, :3]
    R = R_c_l.T @ R_cb_ca @ R_c_l
    return float(np.arctan2(R[1, 0], R[0, 0]))


def recognise(
    features: Sequence[Features | None],
    along_m: FloatArray,
    camera: Camera,
    T_cam_laser: FloatArray,
    params: PlaceParams | None = None,
    min_loop_m: float = 10.0,
) -> PlaceResult:
    """Place recognition over keyframes in driving order (module docstring): each
    keyframe's features (None without an image) and its path along the odometry
    ``along_m`` (K,) in; each keyframe's proposal (at most one) out."""
    params = params or PlaceParams()
    have = [k for k, f in enumerate(features) if f is not None and len(f.descriptors)]
    if len(have) < 2:
        return PlaceResult(described=len(have), note="fewer than 2 keyframes have an image with features")
    descs = [features[k].descriptors for k in have]  # type: ignore[union-attr]
    vocab = train_vocabulary(descs, params)
    v = bow_vectors(vocab, descs)
    scores = np.full((len(features), len(features)), np.nan)
    scores[np.ix_(have, have)] = l1_scores(v, v)
    out = []
    n_candidates, rejected = 0, 0
    for a in have:
        best: PlaceProposal | None = None
        for b, score, eta in candidates(scores, along_m, a, params, min_loop_m):
            n_candidates += 1
            fa, fb = features[a], features[b]
            assert fa is not None
            assert fb is not None
            n, R = essential_check(fa, fb, camera, params)
            if R is None or n < params.min_inliers:
                rejected += 1
                continue
            if best is None or n > best.inliers:
                best = PlaceProposal(a, b, score, eta, n, laser_yaw(R, T_cam_laser))
        if best is not None:
            out.append(best)
    return PlaceResult(out, len(have), n_candidates, rejected)
