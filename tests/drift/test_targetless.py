"""The targetless drift check (`rigcal check RIG --sequence SEQ`) on small simulated drives.

The drives use a 320x240 camera (the simulated camera at half size) so that rendering
stays quick; the check's statistics are the same at any image size."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest

from rigcal.camera import Camera
from rigcal.cli.main import main
from rigcal.drift.log import read_log
from rigcal.drift.targetless import TargetlessSettings, check_targetless
from rigcal.geometry import make_T, rotvec_to_R
from rigcal.localize.streams import open_streams
from rigcal.rig import Rig
from rigcal.rigfile import read_rig, write_rig
from rigcal.sim.box_session import default_T_cam_laser

REALISTIC = ["--exposure-walk", "0.02", "--image-blur-px", "0.7", "--image-noise", "3"]


def small_camera() -> Camera:
    K = np.array([[260.0, 0.0, 159.5], [0.0, 260.0, 119.5], [0.0, 0.0, 1.0]])
    return Camera.from_opencv(K, [-0.15, 0.05, 0.0005, -0.0003, 0.0], 320, 240, source="simulated")


def run(capsys, *args: object) -> tuple[int, str, str]:
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def drives(tmp_path_factory) -> dict[str, Path]:
    base = tmp_path_factory.mktemp("targetless")
    rig = Rig(default_T_cam_laser(), small_camera(), laser={"name": "simulated 2D scanner"})
    write_rig(base / "rig.yaml", rig)
    out = {"rig": base / "rig.yaml"}
    for name, extra in (
        ("drive", ["--world", "cubicle-loop", "--duration-s", "24", "--camera-rate-hz", "5"]),
        ("longer", ["--world", "cubicle-loop", "--duration-s", "34", "--camera-rate-hz", "5"]),
        ("short", ["--world", "cubicle-loop", "--duration-s", "6", "--camera-rate-hz", "5"]),
        ("blind", ["--world", "cubicle-loop", "--duration-s", "4", "--no-images"]),
    ):
        folder = base / name
        code = main(
            [
                "simulate",
                "world",
                "-o",
                str(folder),
                "--seed",
                "3",
                "--rig",
                str(out["rig"]),
                *REALISTIC,
                *extra,
            ]
        )
        assert code == 0
        out[name] = folder
    return out


def moved(rig_path: Path, out: Path, axis: int, size: float) -> Path:
    """The rig file with T_cam_laser moved along one laser-frame axis: T Exp(p)."""
    rig = read_rig(rig_path)
    p = np.zeros(6)
    p[axis] = size
    write_rig(out, dataclasses.replace(rig, T_cam_laser=rig.T_cam_laser @ make_T(rotvec_to_R(p[:3]), p[3:])))
    return out


def test_true_rig_is_ok_and_laser_z_is_never_observed(drives):
    rig = read_rig(drives["rig"])
    res = check_targetless(rig, open_streams(drives["drive"], rig_file=drives["rig"]))
    assert res.verdict == "ok", res.reasons
    rec = res.record
    assert "tz" not in rec["observed_axes"]
    assert {"rx", "ry"} <= set(rec["observed_axes"])
    z = [u for u in rec["unobserved"] if u["components"] == {"tz": 1.0}]
    assert len(z) == 1
    assert "scan plane" in z[0]["why"]
    # The scans' corners and the partitions' ends against the images' edges observe the
    # yaw and the translations across the laser plane, as far as the physical corners'
    # spread can judge them (G corners fixing m directions test at most G - m - 1: this
    # drive's 3 corners whose bands agree fix all three and judge none); the ones left
    # are said to need more corners.
    assert rec["corners"] >= 3
    assert rec["corner_directions"] == 3
    edge_axes = {"rz", "tx", "ty"} & set(rec["observed_axes"])
    assert len(edge_axes) == max(0, min(3, rec["corners"] - rec["corner_directions"] - 1))
    left = [u for u in rec["unobserved"] if set(u["components"]) & ({"rz", "tx", "ty"} - edge_axes)]
    assert left
    assert all("corners" in u["why"] for u in left)
    assert rec["edges"] > 50
    assert rec["edge_bands"] > 100
    assert rec["edge_rms_px"] < 1.0
    # The correction is within its own (honest) uncertainty of zero on every observed axis.
    for x, s in zip(rec["correction_rotation_deg"], rec["sigma_rotation_deg"], strict=True):
        assert abs(x) <= 4 * s + 1e-9
    for x, s in zip(rec["correction_translation_mm"], rec["sigma_translation_mm"], strict=True):
        assert abs(x) <= 4 * s + 1e-9


def test_without_edges_no_translation_is_observed_and_the_record_says_why(drives):
    """The photometric term alone: the odometry's errors take up a shifted camera, so the
    translations' floor (1 cm) keeps them from counting as observed to 2 cm."""
    rig = read_rig(drives["rig"])
    res = check_targetless(
        rig, open_streams(drives["drive"], rig_file=drives["rig"]), TargetlessSettings(edges=False)
    )
    rec = res.record
    assert res.verdict == "ok", res.reasons
    assert not {"tx", "ty"} & set(rec["observed_axes"])
    assert any("systematic floor" in u["why"] for u in rec["unobserved"])
    assert rec["edges"] == 0
    assert "edge_bands" not in rec


@pytest.mark.parametrize("axis", [4])
def test_two_centimetres_across_the_laser_plane_are_detected_and_corrected(drives, tmp_path, axis):
    """Sideways (laser y), which the 34 s drive's 5 corners observe (they fix the yaw and
    both shifts and judge the best determined of them); forward (x) needs more corners
    (benchmarks: the laps)."""
    rig = read_rig(drives["rig"])
    p = np.zeros(6)
    p[axis] = 0.02
    stored = dataclasses.replace(rig, T_cam_laser=rig.T_cam_laser @ make_T(np.eye(3), p[3:]))
    res = check_targetless(stored, open_streams(drives["longer"], rig_file=drives["rig"]))
    assert res.verdict == "drifted", res.reasons
    # The right correction is -2 cm along that axis; what is reported is its part along
    # the observed directions (the one edge direction judged mixes the yaw in): within
    # 3 mm (0.15 resolutions) of the truth's part along each.
    want = -p / TargetlessSettings().scale
    for g in res.details["groups"]:
        assert np.abs(g["z"] - g["V"].T @ want).max() < 0.15
    edge = res.details["groups"][-1]["V"]
    assert abs(edge[axis, 0]) > 0.5  # the judged edge direction is mostly this shift


def test_a_shift_the_corners_cannot_judge_is_named_not_observed(drives):
    """The 24 s drive's 3 corners fix the yaw and both shifts exactly, so their spread
    cannot tell a shifted camera from the corners' own errors: a 2 cm sideways shift is
    not judged, and the record says so (the roll and pitch still are)."""
    rig = read_rig(drives["rig"])
    stored = dataclasses.replace(rig, T_cam_laser=rig.T_cam_laser @ make_T(np.eye(3), [0.0, 0.02, 0.0]))
    res = check_targetless(stored, open_streams(drives["drive"], rig_file=drives["rig"]))
    rec = res.record
    assert res.verdict == "ok", res.reasons
    assert not {"rz", "tx", "ty"} & set(rec["observed_axes"])
    ty = [u for u in rec["unobserved"] if "ty" in u["components"]]
    assert ty
    assert all("leaves too few" in u["why"] for u in ty)
    assert any("not observed by this drive" in r and "ty" not in r for r in res.reasons)


def test_a_sideways_shift_of_2_cm_is_detected_and_corrected(drives, tmp_path, capsys):
    """The 34 s drive's edges observe the sideways shift (its 5 corners fix three
    directions and judge one: the yaw is left to a drive with more corners)."""
    stored = moved(drives["rig"], tmp_path / "moved.yaml", 4, 0.02)
    code, out, err = run(capsys, "check", stored, "--sequence", drives["longer"], "--json")
    assert code == 1, err
    rec = json.loads(out)
    assert rec["kind"] == "targetless"
    assert rec["verdict"] == "drifted"
    t = rec["targetless"]
    # The right correction is -2 cm along laser y, reported along the observed direction
    # (the yaw mixed in): a good part of it, the right sign.
    assert t["correction_translation_mm"][1] < -10.0
    assert "ty" in t["observed_axes"]
    assert read_log(tmp_path / "moved.checks.jsonl")[-1]["targetless"]["dof"] == t["dof"]


def test_short_drive_cannot_tell(drives, tmp_path, capsys):
    code, out, _ = run(
        capsys, "check", drives["rig"], "--sequence", drives["short"], "--log", tmp_path / "l.jsonl"
    )
    assert code == 6
    assert "verdict: cannot_tell" in out
    assert "too short" in out
    assert read_log(tmp_path / "l.jsonl")[-1]["verdict"] == "cannot_tell"


def test_camera_looking_away_from_the_returns_cannot_tell(drives, tmp_path, capsys):
    # The camera turned to look backwards: no return of the laser's 270 deg... but the back.
    stored = moved(drives["rig"], tmp_path / "back.yaml", 2, math.pi)
    code, out, _ = run(capsys, "check", stored, "--sequence", drives["drive"], "--no-log")
    assert code == 6
    assert "no overlap" in out


def test_sequence_without_images_is_bad_input(drives, capsys):
    code, _, err = run(capsys, "check", drives["rig"], "--sequence", drives["blind"], "--no-log")
    assert code == 3
    assert "images.count: got 0" in err
    assert err.count("\n") == 1


def test_sequence_of_another_camera_is_bad_input(drives, tmp_path, capsys):
    from rigcal.sim.box_session import default_camera

    other = tmp_path / "other.yaml"
    write_rig(other, Rig(default_T_cam_laser(), default_camera()))
    code, _, err = run(capsys, "check", other, "--sequence", drives["drive"], "--no-log")
    assert code == 3
    assert "image size: got '320x240'; expected 640x480" in err


def test_one_source_only(drives, capsys):
    code, _, err = run(capsys, "check", drives["rig"], "--no-log")
    assert code == 2
    assert "one of --picks, --session or --sequence" in err
    code, _, err = run(
        capsys, "check", drives["rig"], "--sequence", drives["drive"], "--picks", drives["rig"]
    )
    assert code == 2


def test_settings_reject_a_bad_level():
    with pytest.raises(ValueError, match="level"):
        TargetlessSettings(level=1.5)


def test_an_estimate_that_does_not_settle_or_runs_off_its_pairing_cannot_tell():
    """The estimate's region of trust: a last step still large, or a correction that
    moves the edges' projections beyond the window their image edges were paired in,
    is "cannot tell" with the reason, never a verdict."""
    from rigcal.drift.edges import Edges, band_points
    from rigcal.drift.targetless import RUNAWAY_UNITS, _CannotTellError, _runaway

    rig = Rig(default_T_cam_laser(), small_camera())
    feet = np.array([[2.5, 0.3], [3.0, -0.4], [4.0, 0.8]])
    n = len(feet)
    edges = Edges(band_points(feet), np.arange(n), np.zeros(n, np.int64), np.arange(n), np.hypot(*feet.T))
    s = TargetlessSettings()
    T0 = rig.T_cam_laser
    near = T0 @ make_T(rotvec_to_R([0.0, 0.0, math.radians(0.5)]), [0.0, 0.0, 0.0])
    _runaway(rig, T0, near, edges, 0.005, s)  # settled, within the window: no objection
    with pytest.raises(_CannotTellError, match="did not settle"):
        _runaway(rig, T0, near, edges, 2 * RUNAWAY_UNITS, s)
    # 3 deg of yaw: the edges' projections move about 14 px at 260 px focal length.
    far = T0 @ make_T(rotvec_to_R([0.0, 0.0, math.radians(3.0)]), [0.0, 0.0, 0.0])
    with pytest.raises(_CannotTellError, match=r"ran away: the correction \(3.00 deg"):
        _runaway(rig, T0, far, edges, 0.005, s)
    _runaway(rig, T0, far, None, 0.005, s)  # an estimate that used no edges: nothing to run off


def test_edges_at_one_depth_are_said_to_leave_yaw_and_a_sideways_shift_apart():
    from rigcal.drift.targetless import _unobserved_words

    # Observed: roll, pitch, and yaw + sideways shift together; not: their difference
    # (and laser z, x).
    u = np.array([0.0, 0.0, 0.6, 0.0, 0.8, 0.0])
    w = np.array([0.0, 0.0, 0.8, 0.0, -0.6, 0.0])
    V = np.column_stack([np.eye(6)[:, 0], np.eye(6)[:, 1], u])
    info = {"edge_corners": 6, "edge_depth_m": [2.4, 2.7], "heading_range_deg": 90.0}
    words = _unobserved_words(V, info)
    mixed = [x for x in words if set(x["components"]) == {"rz", "ty"}]
    assert len(mixed) == 1
    assert "one depth (2.4-2.7 m)" in mixed[0]["why"]
    assert "not told apart" in mixed[0]["why"]
    assert abs(abs(mixed[0]["components"]["rz"]) - abs(w[2])) < 1e-3
    shift = [x for x in words if set(x["components"]) == {"tx"}]
    assert "6 corners" in shift[0]["why"]
    # Fewer corners than the edges' three directions need: said so.
    few = _unobserved_words(V, info | {"edge_corners": 4, "edge_fixed": 3})
    edge_words = [x["why"] for x in few if set(x["components"]) & {"rz", "tx", "ty"}]
    assert edge_words
    assert all("fitting 3 directions" in w and "too few (at least 5 corners)" in w for w in edge_words)


@pytest.mark.parametrize(
    ("corners", "determined", "edge_axes"),
    [
        (2, 5, 0),
        (3, 5, 0),
        (4, 5, 0),
        (5, 5, 1),
        (6, 5, 2),
        (7, 5, 3),
        (9, 5, 3),
        (3, 4, 0),
        (4, 4, 1),
        (5, 4, 2),
    ],
)
def test_the_edges_directions_need_more_corners_than_they_estimate(corners, determined, edge_axes):
    """With the edge term used, the yaw and the translations across the plane are tested
    as far as the physical corners' spread has degrees of freedom left: G corners fixing
    m directions leave G - m, and an F test of k directions on them needs G - m - k + 1
    >= 2; so 7 corners for all three when all three are fixed, none with 4. With one of
    them held (the yaw against a sideways shift at one depth: m = 2), 4 corners test one."""
    from rigcal.drift.targetless import AXES, _axis_observed, _Estimate, _observed_basis

    est = _Estimate(
        xi=np.zeros(6),
        cov_z=np.diag([1e-3] * 5 + [0.0]),
        odometry=np.zeros(6),
        odometry_sigma=np.zeros(6),
        blocks=12,
        corners=corners,
        moves=np.zeros((12 + corners, 6)),
        determined=np.eye(6)[:, :determined],
        edge_stats={"edge_bands": 100},
    )
    V = _observed_basis(est, TargetlessSettings())
    got = {AXES[a] for a in range(6) if _axis_observed(V, a)}
    assert {"rx", "ry"} <= got
    assert len(got & {"rz", "tx", "ty"}) == edge_axes


def test_edges_found_but_unusable_leave_the_photometric_term_on_every_scans_odometry(drives, monkeypatch):
    """A drive shows edges (so its odometry starts on the scans thinned to 10 Hz, which serve
    where the edges estimate the yaw and the translations), but too few of them are clear
    in the images to be used: the photometric term alone then judges, and it needs every
    scan's odometry (on the thinned one a corridor drive's yaw came out 0.18 deg off,
    against 0.07 deg on every scan's). The estimate is made again on every scan."""
    import rigcal.drift.targetless as targetless

    def unusable(*args, **kwargs):  # type: ignore[no-untyped-def]
        er, J6, eusable, found = found_edges(*args, **kwargs)
        return er, J6, np.zeros_like(eusable), found

    found_edges = targetless.edge_residuals
    monkeypatch.setattr(targetless, "edge_residuals", unusable)
    scans_seen = []
    estimate = targetless._estimate

    def spy(rig, streams, *args, **kwargs):  # type: ignore[no-untyped-def]
        scans_seen.append(len(streams.scan_stamps_s))
        return estimate(rig, streams, *args, **kwargs)

    monkeypatch.setattr(targetless, "_estimate", spy)
    streams = open_streams(drives["drive"], rig_file=drives["rig"])
    res = check_targetless(read_rig(drives["rig"]), streams)
    assert res.verdict != "cannot_tell", res.reasons
    assert "edge_bands" not in res.record  # the photometric term alone
    assert res.record["edges"] >= targetless.MIN_EDGE_BANDS  # edges were found
    n = len(streams.scan_stamps_s)  # 40 Hz: the thinned odometry has every 4th scan
    # Then on every scan's, and again there on the patches chosen under the estimate.
    assert scans_seen[:2] == [len(range(0, n, 4)), n]
    assert set(scans_seen[2:]) == {n}
    assert 1 <= res.record["reselected"] <= targetless.MAX_RESELECTIONS


def _never_settles(*args, **kwargs):  # type: ignore[no-untyped-def]
    from rigcal.drift.targetless import _CannotTellError

    raise _CannotTellError("the estimate did not settle (as the test makes it)")


@pytest.mark.parametrize("edges_usable", [True, False])
def test_the_photometric_term_alone_is_made_again_only_where_the_estimate_was_not_already_it(
    drives, monkeypatch, edges_usable
):
    """An estimate that does not settle is made again with the edge term off
    (_photometric_alone) where it used the edges; where it was already the photometric
    term alone on every scan's odometry with its errors held (the drive's edges found but
    unusable), it is "cannot tell" at once, with its reason, not made a second time."""
    import rigcal.drift.targetless as targetless

    if not edges_usable:

        def unusable(*args, **kwargs):  # type: ignore[no-untyped-def]
            er, J6, eusable, found = found_edges(*args, **kwargs)
            return er, J6, np.zeros_like(eusable), found

        found_edges = targetless.edge_residuals
        monkeypatch.setattr(targetless, "edge_residuals", unusable)
    monkeypatch.setattr(targetless, "_runaway", _never_settles)
    again = []
    alone = targetless._photometric_alone

    def spy(*args, **kwargs):  # type: ignore[no-untyped-def]
        again.append(True)
        return alone(*args, **kwargs)

    monkeypatch.setattr(targetless, "_photometric_alone", spy)
    res = check_targetless(read_rig(drives["rig"]), open_streams(drives["drive"], rig_file=drives["rig"]))
    assert res.verdict == "cannot_tell"
    assert res.reasons == ["the estimate did not settle (as the test makes it)"]
    assert len(again) == (1 if edges_usable else 0)


def _photometric_alone(seed: int, yaw_deg: float, held: bool = True):  # type: ignore[no-untyped-def]
    """A synthetic estimate of the photometric term alone (no edges) on 10 blocks of an
    unmoved rig, whose yaw carries an error common to every block (``yaw_deg``: the laser
    odometry's, the image model's), which the blocks' spread cannot show: their leave-one-
    out moves scatter by about 0.01 deg on the rotations and 3 mm on the translations.
    ``held``: made with the odometry's errors held (else estimated)."""
    from rigcal.drift.targetless import _Estimate

    s = TargetlessSettings()
    rng = np.random.default_rng(seed)
    G = 10
    sd = np.array([math.radians(0.01)] * 3 + [3e-3, 3e-3, 0.0]) / s.scale  # resolution units
    moves = rng.normal(size=(G, 6)) * sd / math.sqrt(G)
    dc = moves - moves.mean(axis=0)
    cov_z = (G - 1) / G * dc.T @ dc
    xi = np.r_[rng.normal(size=3) * math.radians(0.01), rng.normal(size=3) * 3e-3]
    xi[2] = math.radians(yaw_deg)
    xi[5] = 0.0
    return _Estimate(
        xi=xi,
        cov_z=cov_z,
        odometry=np.zeros(6),
        odometry_sigma=np.zeros(6),
        blocks=G,
        corners=0,
        moves=moves,
        determined=np.eye(6)[:, :5],
        solve={"odometry_errors_held": held},
        information=np.diag([1e4, 1e4, 1e4, 1e3, 1e3, 0.0]),
    )


def test_the_photometric_yaw_is_judged_where_its_floor_allows():
    """Without edges the photometric term estimates the yaw too. With the laser odometry's
    errors estimated beside T its yaw erred by 0.14 deg on every drive
    (``photo_floor_free_deg``), above the resolution over the detection factor: not
    observed, and said why. With them held on every scan's odometry its floor is the
    odometry's and the image model's (``photo_floor_deg``), under that limit: the yaw is
    observed, and a 0.3 deg yaw on 10 agreeing blocks is detected."""
    from types import SimpleNamespace

    from rigcal.drift.targetless import _test

    rig = Rig(default_T_cam_laser(), small_camera())
    patches = SimpleNamespace(info={"heading_range_deg": 174.0, "edges": 0})
    s = TargetlessSettings()
    assert s.photo_floor_deg[2] < s.resolution_deg / s.detection_factor()
    assert s.photo_floor_free_deg[2] > s.resolution_deg / s.detection_factor()
    est = _photometric_alone(seed=1220, yaw_deg=0.3)
    old = _test(rig, _photometric_alone(seed=1220, yaw_deg=0.3, held=False), patches, s, [])
    assert old["record"]["observed_axes"] == ["rx", "ry"]
    yaw = [u for u in old["record"]["unobserved"] if "rz" in u["components"]]
    assert yaw
    assert all("systematic floor" in u["why"] and "no corner" in u["why"] for u in yaw)
    new = _test(rig, est, patches, s, [])
    assert new["record"]["observed_axes"] == ["rx", "ry", "rz"]
    assert new["verdict"] == "drifted"
    # An error of the floor's size common to the blocks is not an alarm.
    unmoved = _photometric_alone(seed=1220, yaw_deg=s.photo_floor_deg[2])
    assert _test(rig, unmoved, patches, s, [])["verdict"] == "ok"


def test_without_edges_the_odometrys_errors_are_held_and_the_yaw_is_judged(drives):
    """The photometric term alone, on every scan's odometry: the odometry's errors are held
    at zero (estimated beside T they took up the image model's errors and dragged the
    yaw), the estimate iterates until it settles, the yaw is observed, and a 0.3 deg yaw
    is detected and corrected to within 0.1 deg. With edges, on the thinned scans'
    odometry, the odometry's errors are still estimated."""
    from rigcal.drift.targetless import SETTLED_UNITS

    rig = read_rig(drives["rig"])
    streams = open_streams(drives["drive"], rig_file=drives["rig"])
    s = TargetlessSettings(edges=False)
    res = check_targetless(rig, streams, s)
    rec = res.record
    assert res.verdict == "ok", res.reasons
    assert "rz" in rec["observed_axes"]
    assert rec["last_step_units"] < SETTLED_UNITS
    assert rec["odometry_errors_held"] is True
    held = rec["odometry_errors"]
    assert held["crab_deg"] == [0.0, 0.0]
    assert held["pivot_mm"] == [[0.0, 0.0], [0.0, 0.0]]
    stored = dataclasses.replace(
        rig, T_cam_laser=rig.T_cam_laser @ make_T(rotvec_to_R([0, 0, 0.3 * math.pi / 180]), np.zeros(3))
    )
    moved_res = check_targetless(stored, streams, s)
    assert moved_res.verdict == "drifted", moved_res.reasons
    assert abs(math.degrees(moved_res.correction[2]) + 0.3) < 0.1
    # The patches chosen again under the estimate: the turned rig's correction less the
    # unmoved one's is the turn (-0.295 deg on this drive; chosen under the stored T it
    # was -0.324: a gain of 1.08).
    assert rec["reselected"] >= 1
    assert moved_res.record["reselected"] >= 1
    assert abs(math.degrees(moved_res.correction[2] - res.correction[2]) + 0.3) < 0.015
    with_edges = check_targetless(rig, streams).record
    assert "edge_bands" in with_edges
    assert with_edges["odometry_errors_held"] is False
    assert with_edges["odometry_errors"]["crab_deg"][1] > 0.0


class _Inline:
    """A stand-in for ThreadPoolExecutor that runs each task at once on the calling thread."""

    def __init__(self, *args: object, **kwargs: object) -> None:
        pass

    def submit(self, fn, *args, **kwargs):  # type: ignore[no-untyped-def]
        from concurrent.futures import Future

        done: Future = Future()  # type: ignore[type-arg]
        done.set_result(fn(*args, **kwargs))
        return done

    def map(self, fn, *iterables):  # type: ignore[no-untyped-def]
        return list(map(fn, *iterables))

    def shutdown(self, wait: bool = True, cancel_futures: bool = False) -> None:
        pass

    def __enter__(self) -> _Inline:
        return self

    def __exit__(self, *exc: object) -> None:
        pass


def test_the_command_and_the_check_on_one_thread_agree_to_the_bit(drives, monkeypatch):
    """`rigcal check --sequence`'s orchestration (frames decoded from the reading on, two at
    a time; each frame's own work two at a time; the edges' frames, blurred on two
    threads, and the later stages made ahead; the edge term beside the photometric one;
    the samples, and the residuals, in two halves) changes no result: its record is the
    record of the check with every step in turn on the calling thread, the residuals in one
    pass."""
    import rigcal.drift.blur_stack as blur_stack
    import rigcal.drift.sampling as sampling
    import rigcal.drift.targetless as targetless
    import rigcal.localize.prefetch as prefetch
    from rigcal.jobs import check_rig

    command = check_rig(drives["rig"], sequence=drives["drive"], no_log=True).record["targetless"]
    assert command["patches"] > targetless.SPLIT_PATCHES_ABOVE  # the command split its residuals
    for module in (targetless, sampling, prefetch, blur_stack):
        monkeypatch.setattr(module, "ThreadPoolExecutor", _Inline)
    monkeypatch.setattr(sampling, "SPLIT_ABOVE", 0)  # the halves, one after the other
    monkeypatch.setattr(targetless, "SPLIT_PATCHES_ABOVE", 10**9)  # the residuals in one pass
    streams = open_streams(drives["drive"], rig_file=drives["rig"])
    streams.odometry_covariance = False
    serial = check_targetless(read_rig(drives["rig"]), streams).record
    command.pop("check_s")
    serial.pop("check_s")
    assert command["correction_rotation_deg"] is not None
    assert command == serial


def test_blurring_only_where_the_check_reads_changes_no_result(drives, monkeypatch):
    """The stacks and the edges' frames made only over the boxes their reads fall in
    (rigcal.drift.blur_stack), widened where a read needs more, give the record of
    blurring the whole band of every frame: with no margin (many reads widen their box)
    and with boxes as large as the band."""
    import rigcal.drift.blur_stack as blur_stack
    import rigcal.drift.targetless as targetless

    def record() -> dict[str, object]:
        streams = open_streams(drives["drive"], rig_file=drives["rig"])
        streams.odometry_covariance = False
        out = check_targetless(read_rig(drives["rig"]), streams).record
        out.pop("check_s")
        return out

    widened = []
    widen = blur_stack.BlurStack.widen

    def counted(self, keys, need, margin_px):  # type: ignore[no-untyped-def]
        widened.append(len(keys))
        widen(self, keys, need, margin_px)

    def boxes(size: int):  # type: ignore[no-untyped-def]
        return lambda camera, T, edges, window_px: np.tile([-size, size, -size, size], (len(edges.X), 1))

    monkeypatch.setattr(blur_stack.BlurStack, "widen", counted)
    monkeypatch.setattr(targetless, "BOX_MARGIN_PX", 0.0)
    monkeypatch.setattr(targetless, "search_boxes", boxes(0))  # the edges' frames: each read widens
    tight = record()
    assert len(widened) > 5
    monkeypatch.setattr(targetless, "BOX_MARGIN_PX", 10.0**4)
    monkeypatch.setattr(targetless, "search_boxes", boxes(10**4))
    whole = record()
    assert whole["correction_rotation_deg"] is not None
    assert tight == whole


def test_frames_inflated_by_libdeflate_change_no_result(drives, monkeypatch):
    """The frames' image data inflated by libdeflate and given to libpng stored
    (rigcal.io.png.stored_png) gives the command's record of libpng inflating the files
    itself."""
    import rigcal.io.png as png
    from rigcal.jobs import check_rig

    stored = png.stored_png
    rewritten = []

    def counted(data: bytes):  # type: ignore[no-untyped-def]
        out = stored(data)
        rewritten.append(out is not None)
        return out

    monkeypatch.setattr(png, "stored_png", counted)
    fast = check_rig(drives["rig"], sequence=drives["drive"], no_log=True).record
    assert rewritten
    assert all(rewritten)
    monkeypatch.setattr(png, "stored_png", lambda data: None)
    as_before = check_rig(drives["rig"], sequence=drives["drive"], no_log=True).record
    for record in (fast, as_before):
        record.pop("checked_utc")
        record["targetless"].pop("check_s")
    assert fast["targetless"]["correction_rotation_deg"] is not None
    assert fast == as_before
