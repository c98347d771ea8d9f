"""Image place recognition: the vocabulary and its scores, the essential-matrix check, the
proposals, loop closure's hook (counts by source) and a sequence without images."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from test_loop_closure import _drifted, _scans_of, _square, _square_world

from rigcal.cli.main import main
from rigcal.geometry import make_T, rotvec_to_R
from rigcal.localize.loop_closure import LoopParams, Proposal, close_loops, keyframes, path_along, relative
from rigcal.localize.place_recognition import (
    Features,
    PlaceParams,
    _majorities,
    _nearest,
    bow_vectors,
    essential_check,
    hamming,
    l1_scores,
    laser_yaw,
    orb_features,
    recognise,
    train_vocabulary,
)
from rigcal.sim.drive import default_rig
from rigcal.sim.textures import world_textures
from rigcal.sim.world import cubicle_loop
from rigcal.sim.world_render import render_world

RIG = default_rig()  # the simulator's forward-looking camera
WORLD = cubicle_loop()
PARAMS = PlaceParams()


@pytest.fixture
def rng():
    return np.random.default_rng(3)


def _view(pose, tex):
    """ORB features of the camera's image with the laser at ``pose`` (x, y, yaw)."""
    x, y, yaw = pose
    T_world_laser = make_T(rotvec_to_R([0.0, 0.0, yaw]), [x, y, WORLD.laser_height_m])
    img = render_world(WORLD, RIG.camera, T_world_laser @ np.linalg.inv(RIG.T_cam_laser), tex).image
    return orb_features(cv2.cvtColor(img, cv2.COLOR_BGR2GRAY), PARAMS)


# Along the cubicle loop's south side (y = -3.25) heading east, then other places: the
# same place seen again 0.4 m on and 4 deg turned, and places along the other sides.
A = (-3.0, -3.25, 0.0)
A_AGAIN = (-2.6, -3.2, np.radians(4.0))
ELSEWHERE = [(5.5, 0.5, np.pi / 2), (2.0, 3.25, np.pi), (-5.5, 0.0, -np.pi / 2), (5.5, -2.0, np.pi / 2)]


@pytest.fixture(scope="module")
def views():
    tex = world_textures(WORLD, 0)
    return {"a": _view(A, tex), "again": _view(A_AGAIN, tex), "else": [_view(p, tex) for p in ELSEWHERE]}


def test_the_same_place_from_two_poses_passes_the_essential_matrix_and_gives_the_yaw(views):
    n, R = essential_check(views["again"], views["a"], RIG.camera, PARAMS)
    assert n >= PARAMS.min_inliers
    assert R is not None
    true = relative(np.array([A]), np.array([A_AGAIN]))[0]  # T_a_again
    assert abs(laser_yaw(R, RIG.T_cam_laser) - true[2]) < np.radians(1.0)


def test_the_essential_matrix_rejects_a_pair_of_different_places(views):
    for other in views["else"]:
        n, R = essential_check(other, views["a"], RIG.camera, PARAMS)
        assert R is None or n < PARAMS.min_inliers


def test_a_place_seen_again_scores_above_other_places(views):
    feats = [views["a"], *views["else"], views["again"]]
    vocab = train_vocabulary([f.descriptors for f in feats], PARAMS)
    assert 100 < vocab.n_words <= PARAMS.branching**PARAMS.depth
    v = bow_vectors(vocab, [f.descriptors for f in feats])
    s = l1_scores(v, v)
    np.testing.assert_allclose(np.diag(s), 1.0)
    np.testing.assert_allclose(s, s.T)
    assert s[-1, 0] > 1.5 * max(s[-1, 1:-1])  # again vs a, against again vs elsewhere


def test_the_l1_score_is_1_for_the_same_words_and_0_for_none_shared():
    v = np.array([[0.5, 0.5, 0.0, 0.0], [0.0, 0.0, 0.25, 0.75], [0.5, 0.5, 0.0, 0.0]])
    np.testing.assert_allclose(l1_scores(v, v), [[1, 0, 1], [0, 1, 0], [1, 0, 1]])


def test_the_compiled_hamming_and_majority_match_numpy(rng):
    a = rng.integers(0, 256, (300, 32), dtype=np.uint8)
    b = rng.integers(0, 256, (7, 32), dtype=np.uint8)
    d = hamming(a, b)
    assert d[0, 0] == sum(bin(int(x)).count("1") for x in a[0] ^ b[0])
    label, dist = _nearest(a, b)
    np.testing.assert_array_equal(label, np.argmin(d, axis=1))
    np.testing.assert_array_equal(dist, d.min(axis=1))
    maj = _majorities(a, label, b)
    for m in range(len(b)):
        mine = np.unpackbits(a[label == m], axis=1)
        if len(mine):
            want = np.packbits((2 * mine.sum(axis=0) >= len(mine)).astype(np.uint8))
            np.testing.assert_array_equal(maj[m], want)
        else:
            np.testing.assert_array_equal(maj[m], b[m])


def test_each_descriptor_falls_to_the_word_of_its_nearest_leaf(rng):
    # Clusters of descriptors a few bits from their centres: the tree's first level finds
    # them, and each descriptor's word is shared with its cluster, not with others.
    centres = rng.integers(0, 256, (6, 32), dtype=np.uint8)
    label = rng.integers(0, 6, 600)
    flips = np.packbits(rng.random((600, 256)) < 0.03, axis=1)
    desc = centres[label] ^ flips
    vocab = train_vocabulary([desc], PlaceParams(branching=6, depth=1))
    words = vocab.words(desc)
    for m in range(6):
        assert len(set(words[label == m])) == 1
    assert len(set(words)) == 6


def test_recognise_proposes_the_place_seen_again_and_not_elsewhere(views):
    # Keyframes in driving order: the place, four others, then the place again 14 m of
    # path on (and, as a second sequence, a fifth other place instead).
    others = views["else"]
    along = np.array([0.0, 4.0, 8.0, 11.0, 13.0, 14.0])
    found = recognise([views["a"], *others, views["again"]], along, RIG.camera, RIG.T_cam_laser, PARAMS)
    assert [(p.a, p.b) for p in found.proposals] == [(5, 0)]
    p = found.proposals[0]
    assert p.inliers >= PARAMS.min_inliers
    assert p.normalised >= PARAMS.min_normalised
    true = relative(np.array([A]), np.array([A_AGAIN]))[0]
    assert abs(p.yaw_rad - true[2]) < np.radians(1.0)
    assert found.described == 6
    # The place again but fewer than min_loop_m of path on: not queried.
    near = recognise([views["a"], *others, views["again"]], along / 2, RIG.camera, RIG.T_cam_laser, PARAMS)
    assert near.proposals == []
    none = recognise([views["a"], *others, others[0]], along, RIG.camera, RIG.T_cam_laser, PARAMS)
    assert all(p.b != 0 for p in none.proposals)


def test_keyframes_without_images_are_skipped_and_too_few_say_so(views):
    found = recognise(
        [views["a"], None, views["again"]], np.array([0.0, 5.0, 12.0]), RIG.camera, RIG.T_cam_laser
    )
    assert found.described == 2
    empty = Features(np.zeros((0, 2)), np.zeros((0, 32), dtype=np.uint8))
    few = recognise([views["a"], empty, None], np.array([0.0, 5.0, 12.0]), RIG.camera, RIG.T_cam_laser)
    assert few.proposals == []
    assert "fewer than 2 keyframes" in few.stats["note"]


def test_bad_settings_are_refused():
    with pytest.raises(ValueError, match="branching"):
        PlaceParams(branching=1)
    with pytest.raises(ValueError, match="min_inliers"):
        PlaceParams(min_inliers=2)


def _lap_and_a_half(rng):
    lap = _square()
    truth = np.vstack([lap, lap[1:61] + np.array([0.0, 0.0, 2 * np.pi])])
    return truth, _drifted(truth, yaw_per_step=0.002), _scans_of(_square_world(rng), truth)


def test_an_image_proposal_closes_a_return_beyond_the_scan_searchs_window(rng):
    # The heading drift puts the return metres and degrees from the start, beyond the
    # local scan search's window (the global search off): an image proposal (with the
    # images' yaw) closes it, verified by the scans, and the counts tell the sources apart.
    truth, odo, scans = _lap_and_a_half(rng)
    params = LoopParams(max_search_m=1.0, backend="scipy", global_every=0)
    keys = keyframes(path_along(odo), params.keyframe_m)
    i, j = int(keys[keys >= 162][0]), 0
    assert np.hypot(*(odo[i, :2] - odo[j, :2])) > 2 * params.max_search_m
    scan_only = close_loops(scans, odo, params)
    assert scan_only.counts["accepted"] == 0
    true = relative(truth[[j]], truth[[i]])[0]
    proposal = Proposal(i, j, "images", true[2] + 0.05, PARAMS.window_m, PARAMS.window_rad)
    found = close_loops(scans, odo, params, proposals=[proposal])
    by = found.counts_by_source
    assert by["images"] == {
        "proposed": 1,
        "accepted": 1,
        "rejected_by_verification": 0,
        "rejected_by_kernel": 0,
    }
    assert sum(c["proposed"] for c in by.values()) == found.counts["proposed"]
    c = next(c for c in found.closures if c.source == "images")
    assert np.hypot(*(c.T_j_i[:2] - true[:2])) < 0.05
    end = float(np.hypot(*(found.poses[-1, :2] - truth[-1, :2])))
    assert end < 0.25 * float(np.hypot(*(odo[-1, :2] - truth[-1, :2])))


def test_a_false_image_proposal_is_rejected_by_the_scans(rng):
    _, odo, scans = _lap_and_a_half(rng)
    params = LoopParams(max_search_m=1.0, backend="scipy")
    keys = keyframes(path_along(odo), params.keyframe_m)
    i = int(keys[keys >= 162][0])
    j = int(keys[keys >= 80][0])  # the square's third corner: not where i is
    found = close_loops(scans, odo, params, proposals=[Proposal(i, j, "images", 0.0, 3.0, 0.3)])
    assert found.counts_by_source["images"]["accepted"] == 0
    assert found.counts_by_source["images"]["rejected_by_verification"] == 1


def test_a_proposal_that_is_not_a_keyframe_pair_is_refused(rng):
    _, odo, scans = _lap_and_a_half(rng)
    with pytest.raises(ValueError, match="from images: expected keyframes"):
        close_loops(scans, odo, LoopParams(), proposals=[Proposal(150, 149, "images", 0.0, 3.0, 0.3)])


def test_a_sequence_without_images_gives_no_image_proposals_and_says_so(tmp_path, capsys):
    seq = tmp_path / "seq"
    args = ["simulate", "world", "--world", "cubicle-loop", "-o", str(seq), "--no-images"]
    assert main([*args, "--laser-rate-hz", "10"]) == 0
    out = tmp_path / "out"
    assert main(["localize", str(seq), "--method", "icp", "--loop-closure", "-o", str(out), "--json"]) == 0
    captured = capsys.readouterr()
    lc = json.loads(captured.out)["methods"]["icp+lc"]
    assert lc["place_recognition"] == {
        "used": "images",
        "note": "the sequence has no images: no image proposals",
    }
    assert set(lc["closures_by_source"]) <= {"scan"}
    assert "the sequence has no images" in captured.err
    rows = (out / "icp+lc" / "closures.csv").read_text().splitlines()
    assert all(r.split(",")[5] == "scan" for r in rows[1:])
    off = tmp_path / "off"
    args = ["localize", str(seq), "--method", "icp", "--loop-closure", "-o", str(off), "--json"]
    assert main([*args, "--place-recognition", "none"]) == 0
    assert json.loads(capsys.readouterr().out)["methods"]["icp+lc"]["place_recognition"] == {"used": "none"}
    assert main([*args[:-1], "--place-recognition", "orb"]) == 2


def test_an_image_proposal_of_the_place_the_scan_search_closed_is_not_counted_twice(rng):
    # Without drift the scan search closes the return itself; the images proposing the
    # same place (within the closure's submap) add no second edge of the same information.
    truth, _, scans = _lap_and_a_half(rng)
    params = LoopParams(backend="scipy")
    scan_only = close_loops(scans, truth, params)
    first = next(c for c in scan_only.closures if c.T_j_i is not None)
    keys = keyframes(path_along(truth), params.keyframe_m)
    j = int(keys[keys > first.j][0])  # the next keyframe: the same place
    found = close_loops(scans, truth, params, proposals=[Proposal(first.i, j, "images", 0.0, 3.0, 0.3)])
    images = next(c for c in found.closures if c.source == "images")
    assert images.T_j_i is None
    assert images.why_not == "the place of a closure found here"
    assert found.counts_by_source["images"]["accepted"] == 0
    assert found.counts["accepted"] == scan_only.counts["accepted"]
