"""Property tests over the Python API's arguments: whatever a caller passes, a function
either works or raises one ArgumentError naming the function and the argument; never a
TypeError, AttributeError, IndexError or LinAlgError from deep inside, never a file
written. And each keyword is refused exactly when the command line refuses the same
value for its option."""

from __future__ import annotations

import functools
import math
from dataclasses import replace
from pathlib import Path
from typing import Any

import click
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import rigcal
from rigcal.calib import options
from rigcal.cli.types import option_type
from rigcal.errors import ArgumentError, InputError

# The suite's hypothesis profile (tests/conftest.py), without the function-scoped
# fixture check (tmp_path only names a folder here).
SETTINGS = settings(suppress_health_check=[HealthCheck.function_scoped_fixture])

# Anything a caller might pass where a number, a name or an array is expected.
scalars = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(min_value=-(10**400), max_value=10**400),
    st.text(max_size=8),
    st.booleans(),
    st.none(),
)
values = st.one_of(scalars, st.lists(scalars, max_size=4), st.builds(object), st.just(np.eye(3)))


@functools.cache
def box():
    from rigcal.sim.box_session import SessionSpec, generate_session

    sim = generate_session(SessionSpec(n_captures=4, seed=8))
    caps = [rigcal.BoxCapture(c.scan, c.segment_id, c.picked_pixels, c.name) for c in sim.captures]
    return sim, caps


@functools.cache
def board():
    from rigcal.lines import extract_lines
    from rigcal.sim.board_session import BoardSpec, generate_board_session

    spec = BoardSpec(n_captures=3, seed=1)
    sim = generate_board_session(spec)
    caps = [
        rigcal.BoardCapture(c.corners_px, extract_lines(c.scan)[c.segment_id].points, c.name)
        for c in sim.captures
    ]
    return sim, caps, rigcal.Board(spec.board.width_n, spec.board.height_n, spec.board.spacing_m)


OPTION_RULES = [
    (options.RANGE_SIGMA_M, st.floats(allow_nan=True, allow_infinity=True)),
    (options.PICK_SIGMA_PX, st.floats(allow_nan=True, allow_infinity=True)),
    (options.THRESHOLD_PX, st.floats(allow_nan=True, allow_infinity=True)),
    (options.CORNER_SIGMA_PX, st.floats(allow_nan=True, allow_infinity=True)),
    (options.SEED, st.integers(min_value=-(10**30), max_value=10**30)),
]


@pytest.mark.parametrize("rule", [r for r, _ in OPTION_RULES], ids=lambda r: repr(r))
@SETTINGS
@given(data=st.data())
def test_a_keyword_is_refused_exactly_when_the_option_refuses_its_text(rule, data):
    """The API's check and the command line's option are one rule: for any number, the
    check accepts it iff click accepts its text, and returns the same value."""
    strategy = {id(r): s for r, s in OPTION_RULES}[id(rule)]
    value = data.draw(st.one_of(strategy, st.integers(min_value=-5, max_value=5)))
    try:
        cli: Any = option_type(rule).convert(repr(value), None, None)
    except click.BadParameter:
        cli = None
    message = ""
    try:
        api: Any = rule.check(value, "f", "x")
    except InputError as e:
        message, api = str(e), None
    assert api == cli
    assert api is not None or message.startswith("f: x: got ")
    assert api is None or math.isfinite(api)


@pytest.mark.parametrize("rule", [options.NOISE, options.LOSS], ids=["noise", "loss"])
@SETTINGS
@given(value=scalars)
def test_a_choice_keyword_takes_only_the_options_choices(rule, value):
    if value in rule.choices:
        assert rule.check(value, "f", "x") == value
    else:
        with pytest.raises(InputError, match=r"^f: x: got .*; expected one of "):
            rule.check(value, "f", "x")


SOLVE_BOX_KEYWORDS = {
    "range_sigma_m": (None, options.RANGE_SIGMA_M),
    "pick_sigma_px": (1.0, options.PICK_SIGMA_PX),
    "threshold_px": (6.0, options.THRESHOLD_PX),
    "seed": (0, options.SEED),
    "noise": ("auto", options.NOISE),
    "loss": ("cauchy", options.LOSS),
}


def outcome(call: Any) -> str:
    """ "" when the call works, "calibration" when the data cannot calibrate, else the
    ArgumentError's message (any other exception fails the test)."""
    try:
        call()
    except ArgumentError as e:
        return str(e)
    except rigcal.CalibrationError:
        return "calibration"
    return ""


def refused(rule: Any, value: Any) -> bool:
    try:
        rule.check(value, None, "x")
    except InputError:
        return True
    return False


@SETTINGS
@given(key=st.sampled_from(sorted(SOLVE_BOX_KEYWORDS)), value=values)
def test_solve_box_refuses_any_bad_keyword_with_an_argument_error(key, value):
    default, rule = SOLVE_BOX_KEYWORDS[key]
    if (value is None and default is None) or not refused(rule, value):
        return  # a good value: not this property's business (solving takes seconds)
    sim, caps = box()
    with pytest.raises(ArgumentError, match=rf"^rigcal\.solve_box: {key}: got "):
        rigcal.solve_box(caps, sim.camera, **{key: value})


@SETTINGS
@given(key=st.sampled_from(["paper_endpoints", "T_truth", "captures", "camera"]), value=values)
def test_solve_box_refuses_bad_flags_transforms_captures_and_cameras(key, value):
    sim, caps = box()
    if key in ("paper_endpoints",) and isinstance(value, bool):
        return
    if key == "T_truth" and value is None:
        return
    args: dict[str, Any] = {"captures": caps, "camera": sim.camera} | {key: value}
    if key == "captures" and isinstance(value, str):
        args["camera"] = None  # a text is a file name: then a missing file
        with pytest.raises(InputError, match=r"picking file|rigcal\.solve_box: captures"):
            rigcal.solve_box(**args)
        return
    with pytest.raises(ArgumentError, match=rf"^rigcal\.solve_box: {key}"):
        rigcal.solve_box(**args)


@SETTINGS
@given(
    i=st.integers(0, 3),
    field=st.sampled_from(["side", "image_endpoints_px", "scan", "name"]),
    value=st.one_of(values, st.integers(-(10**6), 10**6), st.lists(st.integers(-5, 10**4), max_size=5)),
)
def test_solve_box_refuses_a_bad_capture_field_naming_it(i, field, value):
    sim, caps = box()
    if field == "name" and value in ("", None):
        return  # the default name
    c = replace(caps[i], **{field: value})
    bad = [*caps[:i], c, *caps[i + 1 :]]
    # A valid but poor capture (another segment, other beams) may fail to calibrate.
    message = outcome(lambda: rigcal.solve_box(bad, sim.camera))
    assert message in ("", "calibration") or message.startswith(f"rigcal.solve_box: captures[{i}].")


@SETTINGS
@given(
    i=st.integers(0, 2),
    field=st.sampled_from(["corners_px", "points_laser", "name"]),
    value=st.one_of(values, st.lists(st.lists(st.floats(), min_size=2, max_size=2), max_size=3)),
)
def test_solve_board_refuses_a_bad_capture_field_naming_it(i, field, value):
    sim, caps, b = board()
    if field == "name" and value in ("", None):
        return
    c = replace(caps[i], **{field: value})
    bad = [*caps[:i], c, *caps[i + 1 :]]
    message = outcome(lambda: rigcal.solve_board(bad, sim.camera, b))
    assert message in ("", "calibration") or message.startswith(f"rigcal.solve_board: captures[{i}].")


@SETTINGS
@given(methods=st.one_of(values, st.lists(st.text(max_size=6), max_size=3), st.text(max_size=12)))
def test_localize_refuses_any_bad_method_list_before_reading_the_sequence(methods, tmp_path):
    from rigcal.localize.pipeline import parse_methods

    good = isinstance(methods, str) or (
        isinstance(methods, list) and methods and all(isinstance(m, str) and "," not in m for m in methods)
    )
    if good:
        text = methods if isinstance(methods, str) else ",".join(methods)
        try:
            parse_methods(text)
            return  # valid methods: then the missing sequence is the error
        except InputError:
            pass
    with pytest.raises(ArgumentError, match=r"^rigcal\.localize: methods: got "):
        rigcal.localize(tmp_path / "no-sequence", methods)


@SETTINGS
@given(
    row=st.integers(0, 3),
    col=st.integers(0, 3),
    value=st.one_of(st.sampled_from([math.nan, math.inf, -math.inf, 1e4, 2.0]), st.floats(-1e6, 1e6)),
)
def test_write_rig_refuses_any_broken_transform_and_writes_nothing(row, col, value, tmp_path):
    sim, _ = box()
    rig = rigcal.Rig(sim.T_cam_laser, sim.camera)
    T = sim.T_cam_laser.copy()
    T[row, col] = value
    out = tmp_path / "rig.yaml"
    out.unlink(missing_ok=True)
    message = outcome(lambda: rigcal.write_rig(out, replace(rig, T_cam_laser=T)))
    if message:
        assert message.startswith("rigcal.write_rig: rig.T_cam_laser")
        assert not out.exists()
        return
    # Written: then it reads back as the same transform (a change within a rotation's
    # tolerance, or a translation within the rig file's range).
    np.testing.assert_allclose(rigcal.read_rig(out).T_cam_laser, T, atol=1e-6)


@SETTINGS
@given(guess=values)
def test_laser_odometry_refuses_any_bad_guess(guess):
    angles = np.radians(np.arange(-90, 90.01, 1.0))
    odom = rigcal.LaserOdometry()
    odom.register_scan(rigcal.Scan(angles, np.full(len(angles), 4.0), 0.1, 30.0))
    if guess is None:
        return
    try:
        g = np.asarray(guess, dtype=float)
        ok = g.shape == (3,) and np.isfinite(g).all()
    except (TypeError, ValueError, OverflowError):
        ok = False
    if ok:
        return
    with pytest.raises(ArgumentError, match=r"^rigcal\.LaserOdometry\.register_scan: guess"):
        odom.register_scan(rigcal.Scan(angles, np.full(len(angles), 4.0), 0.1, 30.0), guess)
    assert len(odom) == 1


@SETTINGS
@given(path=values)
def test_readers_and_writers_refuse_a_path_that_is_no_path(path, tmp_path: Path):
    if isinstance(path, str):
        return
    for call in (
        lambda: rigcal.read_rig(path),
        lambda: rigcal.read_trajectory(path),
        lambda: rigcal.write_trajectory(path, rigcal.Trajectory(np.eye(4)[None], np.zeros(1))),
    ):
        with pytest.raises(ArgumentError, match=r"^rigcal\.\w+: path: got "):
            call()
