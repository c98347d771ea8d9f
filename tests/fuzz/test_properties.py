"""Property tests over every reader and the option type: whatever a file or an option
holds, a reader either returns a valid value or raises one InputError; never another
exception, never a value with NaN, infinities or broken invariants inside.

Examples are few per property (CI stays fast); the corpus (test_corpus.py) pins the
cases found so far.
"""

from __future__ import annotations

import itertools
import math
from pathlib import Path
from typing import Any

import click
import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from rigcal.cli.types import Real
from rigcal.errors import InputError
from rigcal.io.validate import path_component, relative_inside, whole

# The suite's hypothesis profile (tests/conftest.py): a fixed 40 examples per test,
# RIGCAL_HYPOTHESIS_EXAMPLES=N explores N random ones.
SETTINGS = settings()

# Anything a YAML file can hold where a reader expects something else.
scalars = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(min_value=-(10**400), max_value=10**400),
    st.text(max_size=8),
    st.booleans(),
    st.none(),
)
values = st.one_of(
    scalars, st.lists(scalars, max_size=4), st.dictionaries(st.text(max_size=4), scalars, max_size=2)
)


def leaves(doc: Any, prefix: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    """Key paths of every value in a parsed YAML document (containers included)."""
    out = [prefix] if prefix else []
    if isinstance(doc, dict):
        for k, v in doc.items():
            out += leaves(v, (*prefix, k))
    elif isinstance(doc, list):
        for i, v in enumerate(doc[:3]):
            out += leaves(v, (*prefix, i))
    return out


def replaced(doc: Any, keys: tuple[Any, ...], value: Any) -> Any:
    import copy

    doc = copy.deepcopy(doc)
    d = doc
    for k in keys[:-1]:
        d = d[k]
    d[keys[-1]] = value
    return doc


def dump(path: Path, doc: Any) -> Path:
    path.write_text(yaml.safe_dump(doc, sort_keys=False), encoding="utf-8")
    return path


@pytest.fixture(scope="module")
def valid(tmp_path_factory):
    """Valid files of every kind (the corpus's template)."""
    from corpus import build_template

    return build_template(tmp_path_factory.mktemp("props") / "t")


def spoil(valid: Path, rel: str, data: st.DataObject, tmp: Path) -> Path:
    doc = yaml.safe_load((valid / rel).read_text())
    paths = leaves(doc)
    keys = data.draw(st.sampled_from(paths))
    out = tmp / Path(rel).name
    return dump(out, replaced(doc, keys, data.draw(values)))


def parsed(read: Any, p: Path) -> Any:
    """What ``read`` makes of ``p``, or None when it raises InputError (the only exception
    a reader may raise)."""
    try:
        return read(p)
    except InputError:
        return None


def finite(*arrays: Any) -> bool:
    return all(np.all(np.isfinite(np.asarray(a, dtype=float))) for a in arrays)


@SETTINGS
@given(data=st.data())
def test_scan_reader(valid, tmp_path_factory, data):
    from rigcal.scan import read_scan

    p = spoil(valid, "scan.yaml", data, tmp_path_factory.mktemp("s"))
    s = parsed(read_scan, p)
    if s is None:
        return
    assert finite(s.angles_rad, s.range_min_m, s.range_max_m)
    assert 0 <= s.range_min_m < s.range_max_m
    assert np.all(np.diff(s.angles_rad) > 0)
    assert not np.any(s.ranges_m < 0)


@SETTINGS
@given(data=st.data())
def test_rig_reader(valid, tmp_path_factory, data):
    from rigcal.rigfile import read_rig

    p = spoil(valid, "rig.yaml", data, tmp_path_factory.mktemp("r"))
    r = parsed(read_rig, p)
    if r is None:
        return
    assert finite(r.T_cam_laser)
    assert np.abs(r.T_cam_laser[:3, 3]).max() <= 1000
    assert r.camera.intrinsics[0] > 0
    assert r.covariance is None or finite(r.covariance)


@SETTINGS
@given(data=st.data())
def test_camera_reader(valid, tmp_path_factory, data):
    from rigcal.camera import read_camera

    p = spoil(valid, "sess/camera.yaml", data, tmp_path_factory.mktemp("c"))
    c = parsed(read_camera, p)
    if c is None:
        return
    assert finite(c.intrinsics)
    assert c.intrinsics[0] > 0
    assert c.intrinsics[1] > 0
    assert 0 < c.width_px <= 10**6


@SETTINGS
@given(data=st.data())
def test_picks_reader(valid, tmp_path_factory, data):
    from rigcal.calib.box.picks import read_picks

    tmp = tmp_path_factory.mktemp("p")
    import shutil

    shutil.copytree(valid / "sess", tmp / "sess")
    doc = yaml.safe_load((valid / "sess/picks.yaml").read_text())
    keys = data.draw(st.sampled_from(leaves(doc)))
    p = dump(tmp / "sess/picks.yaml", replaced(doc, keys, data.draw(values)))
    session = parsed(read_picks, p)
    if session is None:
        return
    for o in session.observations:
        assert finite(o.image_endpoints_px, o.laser_endpoints)
        assert path_component(o.name, None, "name") == o.name
        assert o.scan_path.is_file()


tokens = st.sampled_from(
    [
        "FLASER",
        "ROBOTLASER1",
        "ODOM",
        "0",
        "1",
        "2",
        "5",
        "-1",
        "0.5",
        "2.0",
        "nan",
        "inf",
        "-inf",
        "1e400",
        "x",
        "²",
        "9" * 30,
        "host",
        "100.0",
        "0.0",
        "-0.0",
        "3.1416",
    ]
)


@SETTINGS
@given(lines=st.lists(st.lists(tokens, min_size=1, max_size=30), min_size=1, max_size=6))
def test_carmen_reader(tmp_path_factory, lines):
    from rigcal.recordings.carmen import read_carmen

    p = tmp_path_factory.mktemp("k") / "log"
    p.write_text("\n".join(" ".join(x) for x in lines) + "\n")
    log = parsed(read_carmen, p)
    if log is None:
        return
    stamps = [s.stamp_s for s in log.scans]
    assert all(b > a for a, b in itertools.pairwise(stamps))
    assert finite(log.laser_poses, log.odometry_poses, stamps)
    for s in log.scans:
        assert not np.any(s.ranges_m < 0)
        assert finite(s.angles_rad)


@SETTINGS
@given(data=st.data())
def test_sequence_reader(valid, tmp_path_factory, data):
    import shutil

    from rigcal.recordings.sequence import SCAN_KEYS, read_sequence

    tmp = tmp_path_factory.mktemp("q")
    shutil.copytree(valid / "seq", tmp / "seq")
    with np.load(valid / "seq/scans.npz") as z:
        arrays = {k: np.array(z[k]) for k in z.files}
    key = data.draw(st.sampled_from(SCAN_KEYS))
    shape = data.draw(st.sampled_from([arrays[key].shape, (8,), (8, 3), (0,), (3,)]))
    dtype = data.draw(st.sampled_from([np.float64, np.int64]))
    elements = st.floats(allow_nan=True, allow_infinity=True) if dtype is np.float64 else st.integers(-5, 500)
    from hypothesis.extra.numpy import arrays as np_arrays

    arrays[key] = data.draw(np_arrays(dtype, shape, elements=elements))
    with open(tmp / "seq/scans.npz", "wb") as f:
        np.savez(f, **arrays)
    try:
        seq = read_sequence(tmp / "seq")
    except InputError:
        return
    for s in seq.scans:
        assert finite(s.angles_rad, s.range_min_m, s.range_max_m, s.stamp_s)
        assert not np.any(s.ranges_m < 0)


@SETTINGS
@given(
    text=st.one_of(
        st.text(max_size=12), st.sampled_from(["nan", "inf", "-inf", "1e400", "NaN", " 1", "0x10"])
    )
)
def test_real_option(text):
    t = Real(min=0.0, min_open=True)
    try:
        v = t.convert(text, None, None)
    except click.BadParameter:
        return
    assert math.isfinite(v)
    assert v > 0


@SETTINGS
@given(value=values)
def test_whole(value):
    try:
        n = whole(value, None, "k", lo=0, hi=100)
    except InputError:
        return
    assert type(n) is int
    assert 0 <= n <= 100


@SETTINGS
@given(
    name=st.one_of(
        st.text(max_size=12), st.sampled_from(["..", ".", "../x", "a/../..", "/etc", "C:x", "a\\..\\b"])
    )
)
def test_names_never_leave_their_folder(tmp_path_factory, name):
    base = tmp_path_factory.mktemp("n")
    for check in (path_component, relative_inside):
        try:
            ok = check(name, None, "name")
        except InputError:
            continue
        target = (base / ok).resolve()
        assert target.is_relative_to(base.resolve())
        if check is path_component:  # one component: a file or folder in base, never base
            assert target != base.resolve()


def commands(group: click.Group, prefix: str = "") -> list[tuple[str, click.Command]]:
    out: list[tuple[str, click.Command]] = []
    for name, cmd in group.commands.items():
        if isinstance(cmd, click.Group):
            out += commands(cmd, f"{prefix}{name} ")
        else:
            out.append((prefix + name, cmd))
    return out


def test_every_float_option_is_finite():
    """Every float option of every command refuses nan and inf (the Real type)."""
    from rigcal.cli.main import cli

    floats = []
    for name, cmd in commands(cli):
        for p in cmd.params:
            if isinstance(p.type, (click.types.FloatParamType, click.FloatRange)):
                floats.append(f"{name} {p.name}")
                assert isinstance(p.type, Real), f"rigcal {name} {p.opts}: a float option that is not Real"
                for bad in ("nan", "inf", "-inf"):
                    with pytest.raises(click.BadParameter):
                        p.type.convert(bad, p, None)
    assert len(floats) >= 20


BOARD_TARGET = {
    "schema_version": 2,
    "kind": "board",
    "name": "b",
    "board": {
        "corners_x": 8,
        "corners_y": 6,
        "spacing_m": 0.06,
        "size_m": [0.6, 0.5],
        "corner_sigma_px": 0.4,
    },
}


@SETTINGS
@given(data=st.data())
def test_board_targets_reader(tmp_path_factory, data):
    from rigcal.targets.board import BoardTarget, read_target

    keys = data.draw(st.sampled_from(leaves(BOARD_TARGET)))
    p = dump(tmp_path_factory.mktemp("bt") / "b.yaml", replaced(BOARD_TARGET, keys, data.draw(values)))
    t = parsed(read_target, p)
    if t is None or not isinstance(t, BoardTarget):
        return
    assert t.corners_x >= 2
    assert t.corners_y >= 2
    assert math.isfinite(t.spacing_m)
    assert t.spacing_m > 0
    if t.size_m is not None:
        assert finite(t.size_m)
        assert t.size_m[0] >= (t.corners_x + 1) * t.spacing_m - 1e-9
    assert t.corner_sigma_px is None or (math.isfinite(t.corner_sigma_px) and t.corner_sigma_px > 0)
