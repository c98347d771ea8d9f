"""Property tests over the bodies of ROS messages (import-bag, capture), the names that
reach URDF, xacro and shell command lines, and YAML nesting: whatever a message, a name or
a file holds, rigcal either returns a valid value or raises one InputError naming the
message or the file; never another exception.

Each property uses the suite's hypothesis profile (tests/conftest.py).
"""

from __future__ import annotations

from types import SimpleNamespace

import cv2
import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from rigcal.errors import InputError
from rigcal.recordings.bag import RAW_ENCODINGS, _camera_yaml, _image_bytes, _scan

SETTINGS = settings()
WHERE = "run.bag: /image message 3"


def attempt(fn, *args):
    """(value, None) or (None, the InputError's message); any other exception propagates."""
    try:
        return fn(*args), None
    except InputError as exc:
        return None, str(exc)


@SETTINGS
@given(
    encoding=st.sampled_from([*RAW_ENCODINGS, "MONO8", "", "32FC1", "rgb16"]),
    height=st.integers(-2, 9),
    width=st.integers(-2, 9),
    pad=st.integers(-3, 5),
    extra=st.integers(-3, 3),
    bigendian=st.integers(0, 1),
)
def test_a_raw_image_body_is_stored_exactly_or_refused(encoding, height, width, pad, extra, bigendian):
    size, channels = RAW_ENCODINGS.get(encoding.lower(), (1, 1))
    step = max(width, 0) * size * channels + pad
    n = max(height, 0) * max(step, 0) + extra
    data = np.random.default_rng(n + 100).integers(0, 256, max(n, 0), dtype=np.uint8)
    msg = SimpleNamespace(
        encoding=encoding, height=height, width=width, step=step, is_bigendian=bigendian, data=data
    )
    ok = (
        encoding.lower() in RAW_ENCODINGS
        and height > 0
        and width > 0
        and step >= width * size * channels
        and step % size == 0
        and n == height * step
    )
    if not ok:
        with pytest.raises(InputError, match=rf"^{WHERE}: (encoding|height|width|step|data): got "):
            _image_bytes(msg, "sensor_msgs/msg/Image", WHERE)
        return
    png, ext, wxh = _image_bytes(msg, "sensor_msgs/msg/Image", WHERE)
    assert wxh == (width, height)
    img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_UNCHANGED)
    assert ext == "png"
    assert img.shape[:2] == (height, width)
    # The stored pixels are the message's, row padding dropped.
    dtype = np.dtype(">u2" if bigendian else "<u2") if size == 2 else np.dtype(np.uint8)
    rows = np.frombuffer(data.tobytes(), dtype=dtype).reshape(height, step // size)[:, : width * channels]
    want = rows.reshape(height, width, channels) if channels == 3 else rows
    if encoding.lower() == "rgb8":
        want = want[:, :, ::-1]
    np.testing.assert_array_equal(img.reshape(want.shape), want.astype(want.dtype.newbyteorder("=")))


@SETTINGS
@given(data=st.binary(max_size=64), cut=st.integers(0, 200), flip=st.integers(0, 200))
def test_a_compressed_body_is_kept_only_when_it_decodes(data, cut, flip):
    png = bytearray(cv2.imencode(".png", np.arange(64, dtype=np.uint8).reshape(8, 8))[1].tobytes())
    flip %= len(png)
    for body in (data, bytes(png[:cut]), bytes(png[:flip] + bytes([png[flip] ^ 0x55]) + png[flip + 1 :])):
        msg = SimpleNamespace(format="png", data=np.frombuffer(body, np.uint8))
        got, error = attempt(_image_bytes, msg, "sensor_msgs/msg/CompressedImage", WHERE)
        if error is not None:
            assert error.startswith(f"{WHERE}: data: got ")
            continue
        out = got[0]
        assert out == body
        assert cv2.imdecode(np.frombuffer(out, np.uint8), cv2.IMREAD_UNCHANGED) is not None


finite_or_not = st.one_of(st.floats(-10, 10), st.sampled_from([float("nan"), float("inf"), -float("inf")]))


@SETTINGS
@given(
    angle_min=finite_or_not,
    angle_max=finite_or_not,
    step=st.one_of(finite_or_not, st.floats(-0.5, 0.5)),
    n=st.integers(0, 40),
)
def test_a_laser_scan_keeps_its_beam_count_within_one_of_its_angles(angle_min, angle_max, step, n):
    msg = SimpleNamespace(
        angle_min=angle_min, angle_max=angle_max, angle_increment=step, ranges=np.full(n, 2.0),
        range_min=0.1, range_max=30.0,
    )  # fmt: skip
    scan, error = attempt(_scan, msg, 1.0, WHERE)
    if error is not None:
        assert error.startswith(f"{WHERE}: ")
        return
    assert len(scan.ranges_m) == n >= 1
    assert np.all(np.isfinite(scan.angles_rad))
    if n > 1:
        assert abs(n - (round((angle_max - angle_min) / step) + 1)) <= 1


@SETTINGS
@given(
    k=st.lists(finite_or_not, min_size=9, max_size=9),
    width=st.integers(-1, 3000),
    height=st.integers(-1, 3000),
    model=st.sampled_from(["plumb_bob", "rational_polynomial", "equidistant", ""]),
    nd=st.sampled_from([0, 3, 4, 5, 8, 12]),
)
def test_a_camera_info_is_written_only_as_a_camera_rigcal_reads_back(
    tmp_path_factory, k, width, height, model, nd
):
    from rigcal.camera import read_camera

    info = SimpleNamespace(k=np.array(k), d=np.zeros(nd), width=width, height=height, distortion_model=model)
    text, error = attempt(_camera_yaml, info, "run.bag: /info message 0")
    if error is not None:
        assert error.startswith("run.bag: /info message 0: ")
        return
    p = tmp_path_factory.mktemp("cam") / "camera.yaml"
    p.write_text(text)
    cam = read_camera(p)
    assert (cam.width_px, cam.height_px) == (width, height)


# --- names that reach XML and shell command lines --------------------------------------------
xml_text = st.text(
    st.characters(blacklist_categories=("Cs",), blacklist_characters="\x00\ufffe\uffff").filter(
        lambda c: c in "\t\n\r" or ord(c) >= 32
    ),
    max_size=30,
)


@SETTINGS
@given(name=xml_text)
def test_escaped_names_come_back_from_xml_as_they_were(name):
    import xml.etree.ElementTree as ET

    from rigcal.io.exports import _attr, _comment

    doc = ET.fromstring(f'<robot><!-- {_comment(name)} --><link name="{_attr(name)}"/></robot>')
    assert len(doc) == 1  # one link, whatever the name held: no element added
    # XML normalizes whitespace in attributes; everything else comes back as it was.
    assert doc[0].get("name") == name.replace("\r\n", " ").replace("\t", " ").replace("\n", " ").replace(
        "\r", " "
    )


@SETTINGS
@given(name=st.text(max_size=30))
def test_a_frame_name_is_a_ros_name_or_refused(name):
    from rigcal.io.exports import Frames, ros_name

    got, error = attempt(ros_name, name, "--parent-frame")
    if error is not None:
        assert error.startswith("--parent-frame: got ")
        assert "\n" not in error
        with pytest.raises(InputError):
            Frames(parent_frame=name)
        return
    assert got == name
    assert name.isascii()
    assert name[0].isalpha()
    assert "__" not in name
    assert all(c.isalnum() or c in "_/" for c in name)


@SETTINGS
@given(parent=st.from_regex(r"[a-z][a-z0-9_/]{0,12}", fullmatch=True))
def test_every_export_of_a_valid_name_parses_and_round_trips(parent):
    import shlex
    import xml.etree.ElementTree as ET

    from rigcal.io.exports import Frames, T_from_ros_args, export_rig, ros_name
    from rigcal.rig import Rig

    if attempt(ros_name, parent, "p")[1] is not None:
        return
    sim = _sim()
    rig = Rig(T_cam_laser=sim.T_cam_laser, camera=sim.camera)
    frames = Frames(parent_frame=parent, child_frame="cam")
    urdf = ET.fromstring(export_rig(rig, "urdf", frames).split("\n", 1)[1])
    assert [e.get("name") for e in urdf.iter("link")] == [parent, "cam"]
    ET.fromstring(export_rig(rig, "xacro", frames).split("\n", 1)[1])
    ros = export_rig(rig, "ros", frames)
    line = next(x for x in ros.splitlines() if x.startswith("rosrun"))
    _, p, c = T_from_ros_args(shlex.split(line)[3:])
    assert (p, c) == (parent, "cam")


_SIM: list = []


def _sim():
    from rigcal.sim.box_session import SessionSpec, generate_session

    if not _SIM:
        _SIM.append(generate_session(SessionSpec(n_captures=3, seed=1)))
    return _SIM[0]


@SETTINGS
@given(name=st.text(max_size=12))
def test_names_with_control_or_bidi_characters_are_refused_as_file_names(name):
    import unicodedata

    from rigcal.io.validate import path_component

    got, error = attempt(path_component, name, "picks.yaml", "captures[0].name")
    hidden = any(unicodedata.category(c) in ("Cc", "Cf", "Zl", "Zp", "Cs") for c in name)
    if hidden:
        assert error is not None
    if error is None:
        assert got == name
        assert "/" not in name
        assert name not in ("", ".", "..")


# --- YAML nesting -------------------------------------------------------------------------
@SETTINGS
@given(
    kinds=st.lists(st.sampled_from(["[", "{", "-", "k"]), min_size=1, max_size=140),
    leaf=st.sampled_from(["1", "x", "[]", "'[[['"]),
)
@example(kinds=["["] * 100, leaf="1")
@example(kinds=["["] * 101, leaf="1")
@example(kinds=["-"] * 101, leaf="x")
@example(kinds=["k"] * 100, leaf="[]")
@example(kinds=["k", "{"] * 50, leaf="1")
def test_yaml_nested_up_to_the_limit_is_read_and_deeper_is_one_error(tmp_path_factory, kinds, leaf):
    """Nest ``kinds`` (flow sequence, flow mapping, block sequence, block mapping) around
    ``leaf``: read when the depth is within MAX_YAML_DEPTH, one InputError beyond."""
    from rigcal.io.files import MAX_YAML_DEPTH, load_yaml

    text = leaf
    block = False  # a flow collection cannot hold a block one: then wrap in block style
    for k in reversed(kinds):
        if k == "[" and not block:
            text = f"[{text}]"
        elif k == "{" and not block:
            text = f"{{a: {text}}}"
        elif k in "[-":
            text, block = "- " + text.replace("\n", "\n  "), True
        else:
            text, block = "b:\n  " + text.replace("\n", "\n  "), True
    depth = len(kinds) + (leaf == "[]")
    p = tmp_path_factory.mktemp("deep") / "doc.yaml"
    p.write_text(text + "\n")
    got, error = attempt(load_yaml, p)
    if depth > MAX_YAML_DEPTH:
        assert error is not None
        assert error.startswith(f"{p}: ")
        assert "nested deeper than" in error
    else:
        assert error is None, error
        for _ in range(len(kinds)):
            got = got[0] if isinstance(got, list) else next(iter(got.values()))
