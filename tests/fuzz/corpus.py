"""A corpus of bad inputs over every command, and the one check each case must pass.

Each :class:`Case` starts from small valid inputs (built once, copied into the case's own
folder), spoils one thing (a number in a file, a name, an option, the output path), runs
the command in-process and records the outcome. A case passes when the command exits with
the documented code, prints one ``Error: ...`` line naming what was wrong, raises no
exception (no traceback), writes nothing anywhere, and leaves every input as it was.

Run as a script to count the outcomes (``python tests/fuzz/corpus.py``).
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import math
import os
import shutil
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

NAN, INF = math.nan, math.inf
HUGE = 10**400
# Values no number field accepts.
NOT_A_NUMBER: list[Any] = [NAN, INF, -INF, HUGE, "x", True, None, [1.0]]
NOT_POSITIVE: list[Any] = [*NOT_A_NUMBER, 0, -1.5]
NOT_NONNEG: list[Any] = [*NOT_A_NUMBER, -1.5]
NOT_AN_INDEX: list[Any] = [-1, HUGE, 1.5, "1", True, None, NAN]
BAD_NAMES: list[Any] = ["../escaped", "a/b", "..", "", "a\0b", None, 7, "/abs"]


@dataclass
class Case:
    """One bad input.

    Attributes:
        id: unique, readable test id.
        args: the command line; ``{in}`` and ``{out}`` stand for the input and output folders.
        mutate: spoils the copied inputs (gets the input folder).
        code: the exit code expected.
        message: text the one ``Error:`` line must contain (``{in}`` expanded).
    """

    id: str
    args: list[str]
    mutate: Callable[[Path], None] = lambda _: None
    code: int = 3
    message: str = ""
    setup_out: Callable[[Path, Path], None] | None = None


@dataclass
class Outcome:
    code: int | None
    err: str
    traceback: str = ""
    problems: list[str] = field(default_factory=list)


# --- the valid inputs ------------------------------------------------------------------------
def build_template(root: Path) -> Path:
    """Small valid inputs for every command, in ``root`` (a few seconds, once)."""
    from rigcal.cli.main import main
    from rigcal.recordings.sequence import ImageFrame, write_sequence
    from rigcal.scan import Scan, write_scan
    from rigcal.sim.box_session import SessionSpec, generate_session, write_session

    root.mkdir(parents=True, exist_ok=True)
    angles = np.linspace(-np.pi / 2, np.pi / 2, 181)
    write_scan(
        root / "scan.yaml",
        Scan.from_uniform(-np.pi / 2, np.pi / 180, 2.0 / np.maximum(np.cos(angles), 0.3), 0.05, 30.0, 1.0),
    )
    write_session(generate_session(SessionSpec(n_captures=5, seed=3)), root / "sess", render_images=False)
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        assert main(["solve", str(root / "sess" / "picks.yaml"), "-o", str(root / "rig.yaml")]) == 0
    # A sequence: a robot moving 5 cm per scan along a 4 m x 3 m room; three small images.
    scans = []
    for k in range(8):
        x = -1.0 + 0.05 * k
        a = np.linspace(-np.pi / 2, np.pi / 2, 91)
        c, s = np.cos(a), np.sin(a)
        with np.errstate(divide="ignore"):
            tx = np.where(c > 1e-9, (2.0 - x) / np.where(c > 1e-9, c, 1), np.inf)
            ty = np.where(np.abs(s) > 1e-9, 1.5 / np.where(np.abs(s) > 1e-9, np.abs(s), 1), np.inf)
        scans.append(Scan.from_uniform(a[0], a[1] - a[0], np.minimum(tx, ty), 0.05, 30.0, 10.0 + 0.1 * k))
    import cv2

    png = cv2.imencode(".png", np.full((24, 32), 128, np.uint8))[1].tobytes()
    frames = [ImageFrame(10.05 + 0.2 * i, f"f{i:03d}.png", png) for i in range(3)]
    tum = "".join(f"{10.0 + 0.1 * k!r} {-1.0 + 0.05 * k!r} 0 0 0 0 0 1\n" for k in range(8))
    write_sequence(root / "seq", "room", scans, frames, None, {"made": "corpus"}, groundtruth_tum=tum)
    (root / "a.tum").write_text(tum, encoding="utf-8")
    (root / "gt.tum").write_text(tum, encoding="utf-8")
    flaser = [
        "FLASER 5 2.0 2.1 2.2 2.1 2.0 {x} 0.0 0.0 {x} 0.0 0.0 {t} host {t}".format(x=0.1 * k, t=100.0 + k)
        for k in range(4)
    ]
    robot = (
        "ROBOTLASER1 0 -1.5708 3.1416 0.7854 30.0 0.01 0 5 2.0 2.1 2.2 2.1 2.0 0 "
        "0.5 0.0 0.0 0.5 0.0 0.0 0 0 0 0 0 110.0 host 110.0"
    )
    (root / "log.carmen").write_text("# a log\n" + "\n".join([*flaser, robot]) + "\n", encoding="utf-8")
    (root / "world.yaml").write_text(
        "schema_version: 1\nname: box room\nwalls:\n"
        "  - {from: [0, 0], to: [8, 0]}\n  - {from: [8, 0], to: [8, 6]}\n"
        "  - {from: [8, 6], to: [0, 6]}\n  - {from: [0, 6], to: [0, 0]}\n"
        "path: [[2, 2], [6, 2], [6, 4], [2, 4]]\n",
        encoding="utf-8",
    )
    (root / "cv.yaml").write_text(
        "%YAML:1.0\n---\nimage_width: 640\nimage_height: 480\ncamera_matrix: !!opencv-matrix\n"
        "   rows: 3\n   cols: 3\n   dt: d\n   data: [ 520., 0., 319.5, 0., 520., 239.5, 0., 0., 1. ]\n"
        "distortion_coefficients: !!opencv-matrix\n   rows: 1\n   cols: 5\n   dt: d\n"
        "   data: [ -0.15, 0.05, 0.0005, -0.0003, 0. ]\n",
        encoding="utf-8",
    )
    corners = "".join(
        f"img{i}.png {x:.1f} {y:.1f}\n" for i in range(3) for y in (100, 200) for x in (100, 200, 300)
    )
    (root / "corners.vnl").write_text(corners, encoding="utf-8")
    write_bag(root / "run.bag")
    (root / "cam6x4.yaml").write_text(  # the camera of run.bag's 6 x 4 images
        "schema_version: 1\nimage_width_px: 6\nimage_height_px: 4\n"
        "K: [[50.0, 0, 3], [0, 50.0, 2], [0, 0, 1]]\ndistortion: [0, 0, 0, 0, 0]\n",
        encoding="utf-8",
    )
    build_new_inputs(root, png)
    return root


def build_new_inputs(root: Path, png: bytes) -> None:
    """Inputs of import-laser, batch and a board session whose first board is a returns file."""
    from rigcal.calib.board.session import read_board_session
    from rigcal.sim.board_session import BoardSpec, generate_board_session, write_board_session

    (root / "laser.txt").write_text(
        "".join(f"{1.0 + 0.1 * k:.1f} -0.5 0.25 0.5 3 5 2.0 2.0 2.0 2.0 2.0\n" for k in range(4)),
        encoding="utf-8",
    )
    (root / "laser.csv").write_text(
        "stamp_s,angle_rad,range_m\n"
        + "".join(f"{1.0 + 0.1 * k:.1f},{a},2.0\n" for k in range(3) for a in ("-0.2", "0.0", "0.2")),
        encoding="utf-8",
    )
    for i in range(3):
        (root / f"im{i}.png").write_bytes(png)
    (root / "images.txt").write_text("".join(f"{1.0 + 0.1 * i:.1f} im{i}.png\n" for i in range(3)))
    (root / "batch.yaml").write_text(
        "schema_version: 1\ncommand: evaluate\nitems:\n  - name: one\n    trajectory: a.tum\n"
        "    gt: gt.tum\n",
        encoding="utf-8",
    )
    bs = write_board_session(generate_board_session(BoardSpec(n_captures=6, seed=4)), root / "board")
    bs = bs / "board_session.yaml"
    pts = read_board_session(bs).observations[0].points_laser
    (root / "board" / "ret00.txt").write_text(
        "% laser points on the board\n" + "".join(f"{x:.6f} {y:.6f} 0\n" for x, y in pts), encoding="utf-8"
    )
    doc = yaml.safe_load(bs.read_text(encoding="utf-8"))
    doc["schema_version"] = 2
    doc["captures"][0]["laser_side"] = {"returns_file": "ret00.txt"}
    del doc["captures"][0]["scan"]
    bs.write_text(yaml.safe_dump(doc, sort_keys=False), encoding="utf-8")


# --- spoiling --------------------------------------------------------------------------------
def _set(doc: Any, keys: list[str], value: Any) -> None:
    for k in keys[:-1]:
        doc = doc[int(k)] if isinstance(doc, list) else doc[k]
    last = keys[-1]
    if isinstance(doc, list):
        doc[int(last)] = value
    else:
        doc[last] = value


def set_yaml(rel: str, key: str, value: Any) -> Callable[[Path], None]:
    """Set ``key`` (dotted, list indices as numbers) of the YAML file ``rel`` to ``value``."""

    def mutate(inp: Path) -> None:
        p = inp / rel
        doc = yaml.safe_load(p.read_text(encoding="utf-8"))
        _set(doc, key.split("."), value)
        p.write_text(yaml.safe_dump(doc, sort_keys=False), encoding="utf-8")

    return mutate


def drop_yaml(rel: str, key: str) -> Callable[[Path], None]:
    def mutate(inp: Path) -> None:
        p = inp / rel
        doc = yaml.safe_load(p.read_text(encoding="utf-8"))
        keys = key.split(".")
        d = doc
        for k in keys[:-1]:
            d = d[int(k)] if isinstance(d, list) else d[k]
        del d[keys[-1]]
        p.write_text(yaml.safe_dump(doc, sort_keys=False), encoding="utf-8")

    return mutate


def write(rel: str, text: str | bytes) -> Callable[[Path], None]:
    def mutate(inp: Path) -> None:
        p = inp / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        if isinstance(text, bytes):
            p.write_bytes(text)
        else:
            p.write_text(text, encoding="utf-8")

    return mutate


def edit_text(rel: str, old: str, new: str) -> Callable[[Path], None]:
    def mutate(inp: Path) -> None:
        p = inp / rel
        s = p.read_text(encoding="utf-8")
        assert old in s, (rel, old)
        p.write_text(s.replace(old, new, 1), encoding="utf-8")

    return mutate


def recode(rel: str, codec: str, old: str = "", new: str = "") -> Callable[[Path], None]:
    """The text file saved in another encoding than UTF-8 (after one edit)."""

    def mutate(inp: Path) -> None:
        p = inp / rel
        s = p.read_text(encoding="utf-8")
        assert old in s, (rel, old)
        p.write_bytes(s.replace(old, new, 1).encode(codec))

    return mutate


def npz_edit(change: Callable[[dict[str, Any]], None]) -> Callable[[Path], None]:
    def mutate(inp: Path) -> None:
        p = inp / "seq" / "scans.npz"
        with np.load(p) as z:
            arrays = {k: np.array(z[k]) for k in z.files}
        change(arrays)
        with open(p, "wb") as f:
            np.savez(f, **arrays)

    return mutate


def _show(value: Any) -> str:
    text = repr(value)
    return text if len(text) < 20 else text[:12] + "~"


# --- the cases -------------------------------------------------------------------------------
def number_cases(
    cmd: str, args: list[str], rel: str, key: str, values: list[Any], message: str | None = None
) -> list[Case]:
    leaf = message if message is not None else key.split(".")[-1]
    return [Case(f"{cmd}-{rel}-{key}={_show(v)}", args, set_yaml(rel, key, v), 3, leaf) for v in values]


LINES = ["lines", "{in}/scan.yaml", "--png", "{out}/l.png"]
SOLVE = ["solve", "{in}/sess/picks.yaml", "-o", "{out}/rig.yaml", "--report", "{out}/report"]
EXPORT = ["export", "{in}/rig.yaml", "--format", "kalibr", "-o", "{out}/k.yaml"]
CHECK = ["check", "{in}/rig.yaml", "--picks", "{in}/sess/picks.yaml", "--log", "{out}/log.jsonl"]
PROJECT = ["project", "{in}/rig.yaml", "{in}/scan.yaml", "{in}/sess/images/cap00.png", "-o", "{out}/o.png"]
CARMEN = ["import-carmen", "{in}/log.carmen", "-o", "{out}/seq"]
LOCALIZE = ["localize", "{in}/seq", "--method", "icp", "-o", "{out}/loc"]
EVALUATE = ["evaluate", "{in}/a.tum", "--gt", "{in}/gt.tum"]
WORLD = [
    "simulate",
    "world",
    "--world",
    "{in}/world.yaml",
    "--no-images",
    "--duration-s",
    "1",
    "-o",
    "{out}/w",
]
CALIB = ["simulate", "calib-session", "--captures", "3", "--no-images", "-o", "{out}/s"]


def scan_cases(cmd: str, args: list[str], rel: str) -> list[Case]:
    out = []
    out += number_cases(cmd, args, rel, "range_min_m", NOT_NONNEG)
    out += number_cases(cmd, args, rel, "range_max_m", NOT_POSITIVE)
    out += number_cases(cmd, args, rel, "angle_min_rad", NOT_A_NUMBER)
    out += number_cases(cmd, args, rel, "angle_increment_rad", NOT_POSITIVE)
    out += number_cases(cmd, args, rel, "stamp_s", NOT_A_NUMBER)
    out += number_cases(cmd, args, rel, "ranges_m.3", [-1.0, HUGE, "x", True, None, [1]], "ranges_m[3]")
    out += number_cases(cmd, args, rel, "schema_version", [3, "1", 1.0, True, None], "schema_version")
    out.append(
        Case(
            f"{cmd}-{rel}-step-overflows",
            args,
            set_yaml(rel, "angle_increment_rad", 1e306),
            3,
            "angle_increment_rad",
        )
    )
    return out


def picks_cases() -> list[Case]:
    rel = "sess/picks.yaml"
    out = []
    out += number_cases(
        "solve", SOLVE, rel, "captures.0.image_endpoints_px.0.0", NOT_A_NUMBER, "image_endpoints_px"
    )
    out += number_cases("solve", SOLVE, rel, "captures.0.laser_side.segment", NOT_AN_INDEX, "segment")
    out += number_cases("solve", SOLVE, rel, "captures.0.name", BAD_NAMES, "name")
    out += number_cases("solve", SOLVE, rel, "laser.range_sigma_m", [*NOT_NONNEG, 1.0], "range_sigma_m")
    out += number_cases(
        "solve", SOLVE, rel, "captures.0.scan", ["../../../../../nope.yaml", "a\0b.yaml", None, 3], "scan"
    )
    out += number_cases("solve", SOLVE, rel, "camera", ["nope.yaml", None, "a\0b"], "camera")
    out += number_cases("solve", SOLVE, rel, "schema_version", [0, "1", None], "schema_version")
    out += number_cases("solve", SOLVE, rel, "captures", [None, [], "x", {}], "captures")
    # A capture listed twice (however its paths are spelled) would be weighed twice.
    out += number_cases(
        "solve",
        SOLVE,
        rel,
        "captures.1.image",
        ["images/cap00.png", "./images//cap00.png"],
        "captures[1].image",
    )
    out += number_cases(
        "solve", SOLVE, rel, "captures.1.scan", ["scans/../scans/cap00.yaml"], "captures[1].scan"
    )
    cam = "sess/camera.yaml"
    out += number_cases("solve", SOLVE, cam, "K.0.0", NOT_POSITIVE, "K")
    out += number_cases("solve", SOLVE, cam, "K.1.2", NOT_A_NUMBER, "K")
    out += number_cases("solve", SOLVE, cam, "distortion.0", NOT_A_NUMBER, "distortion")
    out += number_cases(
        "solve", SOLVE, cam, "image_width_px", [0, -640, HUGE, 640.5, NAN, "640", True], "image_width_px"
    )
    out += number_cases("solve", SOLVE, cam, "distortion", [{"rows": 1}, "x", [1, 2, 3]], "distortion")
    out += scan_cases("solve", SOLVE, "sess/scans/cap00.yaml")[::3]
    return out


def rig_cases(cmd: str, args: list[str]) -> list[Case]:
    rel = "rig.yaml"
    out = []
    out += number_cases(
        cmd, args, rel, "T_cam_laser.rotation_vector_rad.0", NOT_A_NUMBER, "rotation_vector_rad"
    )
    out += number_cases(
        cmd, args, rel, "T_cam_laser.translation_m.1", [*NOT_A_NUMBER, 1e308, -1e9], "translation_m"
    )
    out += number_cases(cmd, args, rel, "camera.intrinsics.0", NOT_POSITIVE, "intrinsics")
    out += number_cases(cmd, args, rel, "camera.intrinsics.2", NOT_A_NUMBER, "intrinsics")
    out += number_cases(cmd, args, rel, "camera.imagersize.0", [0, -1, HUGE, 1.5, NAN, "640"], "imagersize")
    out += number_cases(
        cmd, args, rel, "uncertainty.covariance.0.0", [NAN, INF, -1.0, "x", None], "covariance"
    )
    out += number_cases(
        cmd, args, rel, "uncertainty.sigma_rotation_deg.0", [NAN, -1.0, 99.0], "sigma_rotation_deg"
    )
    out += number_cases(
        cmd, args, rel, "uncertainty.sigma_translation_mm.2", [INF, 0.0, 1e6], "sigma_translation_mm"
    )
    return out


def carmen_cases() -> list[Case]:
    rel = "log.carmen"
    first = "FLASER 5 2.0 2.1 2.2 2.1 2.0 0.0 0.0 0.0 0.0 0.0 0.0 100.0 host 100.0"
    assert first.startswith("FLASER 5 ")

    def line(new: str) -> Callable[[Path], None]:
        return edit_text(rel, first, new)

    out = []
    for n in ["²", "0", "-1", "5.0", "9" * 400, "99999", "x"]:
        out.append(
            Case(f"carmen-n={n[:8]}", CARMEN, line(first.replace("FLASER 5 ", f"FLASER {n} ")), 3, "FLASER")
        )
    for v in ["nan", "inf", "-inf", "1e400", "x"]:
        if v in ("-inf", "x"):  # nan, inf (and 1e400, inf) are a range's no return
            out.append(Case(f"carmen-range={v}", CARMEN, line(first.replace(" 2.2 ", f" {v} ")), 3, "FLASER"))
        out.append(
            Case(
                f"carmen-x={v}",
                CARMEN,
                line(first.replace(" 2.0 0.0 0.0 0.0 ", f" 2.0 {v} 0.0 0.0 ")),
                3,
                "FLASER",
            )
        )
        out.append(
            Case(f"carmen-stamp={v}", CARMEN, line(first.replace(" 100.0 host", f" {v} host")), 3, "FLASER")
        )
    out.append(
        Case(
            "carmen-stamp-zero-then-back",
            CARMEN,
            lambda p: (
                line(first.replace(" 100.0 host", " 0.0 host"))(p),
                edit_text(rel, " 101.0 host", " -5.0 host")(p),
            ),
            3,
            "ipc_timestamp",
        )
    )
    strict = [*CARMEN, "--stamps", "strict"]  # the default repairs small glitches
    out.append(
        Case(
            "carmen-stamp-repeated", strict, edit_text(rel, " 101.0 host", " 100.0 host"), 3, "ipc_timestamp"
        )
    )
    out.append(
        Case(
            "carmen-stamp-broken-clock",
            CARMEN,
            edit_text(rel, " 101.0 host", " 50.0 host"),
            3,
            "broken clock",
        )
    )
    robot = "ROBOTLASER1 0 -1.5708 3.1416 0.7854 30.0 0.01"
    for name, new in [
        ("start-nan", "ROBOTLASER1 0 nan 3.1416 0.7854 30.0 0.01"),
        ("step-zero", "ROBOTLASER1 0 -1.5708 3.1416 0 30.0 0.01"),
        ("step-neg", "ROBOTLASER1 0 -1.5708 3.1416 -0.1 30.0 0.01"),
        ("step-nan", "ROBOTLASER1 0 -1.5708 3.1416 nan 30.0 0.01"),
        ("step-inf", "ROBOTLASER1 0 -1.5708 3.1416 inf 30.0 0.01"),
        ("max-inf", "ROBOTLASER1 0 -1.5708 3.1416 0.7854 inf 0.01"),
        ("max-zero", "ROBOTLASER1 0 -1.5708 3.1416 0.7854 0 0.01"),
        ("max-nan", "ROBOTLASER1 0 -1.5708 3.1416 0.7854 nan 0.01"),
        ("start-huge", "ROBOTLASER1 0 1e300 3.1416 0.7854 30.0 0.01"),
    ]:
        out.append(Case(f"carmen-robotlaser-{name}", CARMEN, edit_text(rel, robot, new), 3, "ROBOTLASER1"))
    out.append(
        Case(
            "carmen-robotlaser-n-huge",
            CARMEN,
            edit_text(rel, "0.01 0 5 2.0", "0.01 0 " + "9" * 400 + " 2.0"),
            3,
            "ROBOTLASER1",
        )
    )
    out.append(Case("carmen-empty", CARMEN, write(rel, ""), 3, "no FLASER"))
    out.append(Case("carmen-binary", CARMEN, write(rel, b"\xff\xfe\x00FLASER\x00"), 3, "log.carmen"))
    out.append(
        Case(
            "carmen-missing",
            ["import-carmen", "{in}/nope.carmen", "-o", "{out}/seq"],
            code=3,
            message="nope.carmen",
        )
    )
    for v in ["nan", "inf", "-1", "0"]:
        out.append(
            Case(
                f"carmen-option-range-max={v}",
                [*CARMEN, "--flaser-range-max-m", v],
                code=2,
                message="--flaser-range-max-m",
            )
        )
    return out


def sequence_cases() -> list[Case]:
    out = []

    def seq(name: str, mutate: Callable[[Path], None], message: str, code: int = 3) -> None:
        out.append(Case(f"localize-{name}", LOCALIZE, mutate, code, message))

    seq("npz-garbage", write("seq/scans.npz", b"PK\x03\x04garbage"), "scans.npz")
    seq("npz-empty", write("seq/scans.npz", b""), "scans.npz")
    seq("npz-text", write("seq/scans.npz", "hello"), "scans.npz")
    seq("npz-missing", lambda p: (p / "seq" / "scans.npz").unlink(), "scans.npz")

    def arr(key: str, value: Any) -> Callable[[dict[str, Any]], None]:
        def change(a: dict[str, Any]) -> None:
            if callable(value):
                a[key] = value(a[key])
            else:
                a[key] = value

        return change

    def at0(v: float) -> Callable[[Any], Any]:
        def f(x: Any) -> Any:
            x = np.array(x, dtype=float)
            x.flat[0] = v
            return x

        return f

    seq("npz-no-key", npz_edit(lambda a: a.pop("n_beams")), "n_beams")
    # Stamps in another unit than seconds (Unix milliseconds; milliseconds from the start);
    # a sequence.yaml of a newer rigcal, whose new key is not a typo.
    seq("npz-stamps-unix-ms", npz_edit(arr("stamps_s", lambda t: t * 1e3 + 1.7e12)), "like milliseconds")
    seq("npz-stamps-ms", npz_edit(arr("stamps_s", lambda t: t * 1e3)), "a scan every 100 (median)")
    seq(
        "yaml-newer-version",
        lambda p: (
            set_yaml("seq/sequence.yaml", "schema_version", 9)(p),
            set_yaml("seq/sequence.yaml", "lidar", 1)(p),
        ),
        "schema_version: got 9; expected 1, 2, 3 or 4 (the versions this rigcal reads; a file of a newer",
    )
    seq("npz-ranges-1d", npz_edit(arr("ranges_m", np.zeros(8))), "ranges_m")
    seq("npz-ranges-3d", npz_edit(arr("ranges_m", np.zeros((8, 2, 2)))), "ranges_m")
    seq("npz-ranges-strings", npz_edit(arr("ranges_m", np.array([["a"] * 91] * 8))), "ranges_m")
    seq("npz-short-column", npz_edit(arr("angle_min_rad", np.zeros(3))), "angle_min_rad")
    seq("npz-n-beams-big", npz_edit(arr("n_beams", np.full(8, 500))), "n_beams")
    seq("npz-n-beams-neg", npz_edit(arr("n_beams", np.full(8, -3))), "n_beams")
    seq("npz-n-beams-float", npz_edit(arr("n_beams", np.full(8, 2.5))), "n_beams")
    seq("npz-stamps-nanoseconds", npz_edit(arr("stamps_s", np.arange(8) * 10**8)), "integers: nanoseconds?")
    seq("npz-ranges-objects", npz_edit(arr("ranges_m", np.array([[None] * 91] * 8))), "ranges_m")
    for v in (-1.0, -INF, -1e-9):
        seq(f"npz-range={v}", npz_edit(arr("ranges_m", at0(v))), "ranges_m")
    for key, vals in [
        ("stamps_s", [NAN, INF]),
        ("angle_min_rad", [NAN, INF, 1e300]),
        ("angle_increment_rad", [NAN, 0.0, -0.01, INF]),
        ("range_min_m", [NAN, -1.0]),
        ("range_max_m", [NAN, 0.0, -5.0]),
    ]:
        for v in vals:
            seq(f"npz-{key}={v}", npz_edit(arr(key, at0(v))), key)
    rel = "seq/images.csv"
    seq("csv-dotdot", edit_text(rel, "f001.png", "../../../x.png"), "images.csv")
    seq("csv-abs", edit_text(rel, "f001.png", "/etc/passwd"), "images.csv")
    seq("csv-nul", edit_text(rel, "f001.png", "f\0.png"), "images.csv")
    seq("csv-nan", edit_text(rel, "10.25,", "nan,"), "images.csv")
    seq("csv-inf", edit_text(rel, "10.25,", "inf,"), "images.csv")
    seq("csv-order", edit_text(rel, "10.25,", "1.0,"), "images.csv")
    seq("csv-header", edit_text(rel, "stamp_s,file", "time,name"), "images.csv")
    seq("csv-short", edit_text(rel, "10.25,f001.png", "10.25"), "images.csv")
    seq("csv-missing-image", lambda p: (p / "seq/images/f001.png").unlink(), "f001.png")
    seq(
        "csv-image-twice",
        edit_text(rel, "f001.png", "./f000.png"),
        "images.csv: line 3: file: got './f000.png'",
    )
    # Text saved in another encoding than UTF-8 (UTF-16 with its byte-order mark is read).
    seq(
        "csv-utf16-no-bom",
        recode(rel, "utf-16-le"),
        "images.csv: got UTF-16 text without its byte-order mark",
    )
    seq(
        "csv-cp1252",
        recode(rel, "cp1252", "f001.png", "f\u00e9.png"),
        "images.csv: line 3: got byte 0xE9, not UTF-8",
    )
    seq(
        "yaml-utf16-no-bom",
        recode("seq/sequence.yaml", "utf-16-be"),
        "sequence.yaml: got UTF-16 text without",
    )
    y = "seq/sequence.yaml"
    for key, vals in [
        ("scans.file", ["../../x.npz", "/etc/passwd", None, "a\0b"]),
        ("scans.count", [-1, HUGE, 9, "8", NAN]),
        ("images.count", [-1, 99, None]),
        ("images.index", ["../../../etc/passwd", None]),
        ("images.folder", ["../..", "/", None]),
        ("groundtruth", ["../../../nope", "/etc/passwd", 5]),
        ("schema_version", [5, None, "1"]),  # 3 (odometry) and 4 (gyro) are read
    ]:
        for v in vals:
            seq(f"yaml-{key}={_show(v)}", set_yaml(y, key, v), key.split(".")[0])
    seq("yaml-alias-bomb", write(y, _alias_bomb()), "sequence.yaml")
    seq("gt-nan", edit_text("seq/groundtruth.tum", "10.2 ", "nan "), "groundtruth.tum")
    seq("gt-inf-pose", edit_text("seq/groundtruth.tum", " -0.9 0 0", " inf 0 0"), "groundtruth.tum")
    return out


def bomb_under(key: str) -> str:
    """A billion laughs as the value of ``key``: 10 lines, 9^10 values once expanded."""
    lines = [f"{key}:", '  - &a ["x","x","x","x","x","x","x","x","x"]']
    for i, k in enumerate("bcdefghij"):
        p = "abcdefghij"[i]
        lines.append(f"  - &{k} [*{p},*{p},*{p},*{p},*{p},*{p},*{p},*{p},*{p}]")
    return "\n".join(lines) + "\n"


def with_bomb(rel: str, key: str) -> Callable[[Path], None]:
    """Replace ``key`` of the YAML file ``rel`` by a billion laughs."""

    def mutate(p: Path) -> None:
        doc = yaml.safe_load((p / rel).read_text())
        doc.pop(key, None)
        (p / rel).write_text(yaml.safe_dump(doc, sort_keys=False) + bomb_under(key))

    return mutate


def _alias_bomb() -> str:
    lines = ['a: &a ["x","x","x","x","x","x","x","x","x"]']
    for i, k in enumerate("bcdefghij"):
        prev = "abcdefghij"[i]
        lines.append(f"{k}: &{k} [*{prev},*{prev},*{prev},*{prev},*{prev},*{prev},*{prev},*{prev},*{prev}]")
    return "\n".join(lines) + "\n"


def tum_cases() -> list[Case]:
    out = []
    for v in ["nan", "inf", "1e300", "-1e400", "x"]:
        out.append(
            Case(f"evaluate-x={v}", EVALUATE, edit_text("a.tum", "10.2 -0.9 0", f"10.2 {v} 0"), 3, "a.tum")
        )
        out.append(
            Case(
                f"evaluate-stamp={v}",
                EVALUATE,
                edit_text("gt.tum", "10.2 -0.9 0", f"{v} -0.9 0"),
                3,
                "gt.tum",
            )
        )
    out.append(
        Case(
            "evaluate-no-overlap",
            EVALUATE,
            lambda p: (p / "gt.tum").write_text("".join(f"{500.0 + k} {k} 0 0 0 0 0 1\n" for k in range(8))),
            3,
            "overlap",
        )
    )
    out.append(
        Case(
            "evaluate-zero-quaternion",
            EVALUATE,
            edit_text("a.tum", "0 0 0 0 1\n", "0 0 0 0 0\n"),
            3,
            "quaternion",
        )
    )
    out.append(
        Case(
            "evaluate-short-line",
            EVALUATE,
            edit_text("a.tum", "10.2 -0.9 0 0 0 0 0 1", "10.2 -0.9"),
            3,
            "a.tum",
        )
    )
    out.append(Case("evaluate-empty", EVALUATE, write("a.tum", ""), 3, "a.tum"))

    # A trajectory copied while written: read to its last whole line, refused under --stamps strict.
    def cut(p: Path) -> None:
        (p / "a.tum").write_bytes((p / "a.tum").read_bytes()[:-8])  # the last line's quaternion cut

    strict = [*EVALUATE, "--stamps", "strict"]
    out.append(Case("evaluate-cut-short-strict", strict, cut, 3, "a log cut short"))
    out.append(Case("check-wheel-odometry-without-a-drive", [*CHECK, "--wheel-odometry", "ignore"], code=2))
    out.append(Case("evaluate-one-pose", EVALUATE, write("a.tum", "10.0 0 0 0 0 0 0 1\n"), 3, "a.tum"))
    return out


def world_cases() -> list[Case]:
    rel = "world.yaml"
    out = []
    out += number_cases("world", WORLD, rel, "walls.0.from.0", NOT_A_NUMBER, "walls[0].from")
    out += number_cases("world", WORLD, rel, "path.1.0", [*NOT_A_NUMBER, 1e300], "path")
    out += number_cases("world", WORLD, rel, "laser_height_m", NOT_POSITIVE, "laser_height_m")
    out.append(
        Case(
            "world-path-through-wall",
            WORLD,
            set_yaml(rel, "path", [[2, 2], [9, 2], [6, 4], [2, 4]]),
            3,
            "path",
        )
    )
    out.append(
        Case(
            "world-path-through-obstacle",
            WORLD,
            set_yaml(rel, "obstacles", [{"polygon": [[3, 1.5], [4, 1.5], [4, 2.5]]}]),
            3,
            "path",
        )
    )
    out.append(Case("world-alias-bomb", WORLD, write(rel, _alias_bomb()), 3, "world.yaml"))
    out.append(
        Case("world-huge-yaml", WORLD, write(rel, "name: [" + "1," * 3_000_000 + "1]\n"), 3, "world.yaml")
    )
    out.append(
        Case(
            "world-unknown",
            ["simulate", "world", "--world", "moon", "-o", "{out}/w"],
            code=2,
            message="--world",
        )
    )
    return out


OPTIONS: list[tuple[list[str], str, list[str]]] = [
    (CALIB, "--pick-sigma-px", ["nan", "inf", "-1"]),
    (CALIB, "--range-sigma-m", ["nan", "-inf", "1e400"]),
    (CALIB, "--wrong-picks", ["nan"]),
    (CALIB, "--move-deg", ["nan", "inf"]),
    (CALIB, "--move-mm", ["nan"]),
    (CALIB, "--captures", ["0", "9" * 400, "1.5", "nan"]),
    (CALIB, "--seed", ["-1", "x"]),
    (WORLD, "--range-sigma-m", ["nan"]),
    (WORLD, "--laser-rate-hz", ["nan", "inf", "0"]),
    (WORLD, "--camera-rate-hz", ["nan"]),
    (WORLD, "--clock-offset-s", ["nan", "inf"]),
    (WORLD, "--duration-s", ["nan", "inf", "0", "-1"]),
    (WORLD, "--range-max-m", ["nan"]),
    (WORLD, "--image-noise", ["nan"]),
    (SOLVE, "--threshold-px", ["nan", "inf", "0"]),
    (SOLVE, "--pick-sigma-px", ["nan", "-1"]),
    (SOLVE, "--range-sigma-m", ["nan", "inf"]),
    (SOLVE, "--loss", ["foo"]),
    (SOLVE, "--seed", ["x", "1.5"]),
    (CHECK, "--level", ["nan", "inf", "0", "1"]),
    (CHECK, "--min-captures", ["2", "x"]),
    (LINES, "--range-sigma-m", ["nan", "inf", "-1", "0"]),
    (LOCALIZE, "--method", ["foo", "icp,icp", ","]),
    (
        LOCALIZE,
        "--iasm",
        [
            "x=1",
            "snap_max_m=nan",
            "snap_max_m=inf",
            "hypotheses=" + "9" * 400,
            "window_px=-1",
            "dense_window=maybe",
        ],
    ),
    (EXPORT, "--format", ["foo"]),
    (
        ["intrinsics", "{in}/sess/images/cap00.png", "--board", "9x6", "-o", "{out}/c.cameramodel"],
        "--square-m",
        ["nan", "inf", "0", "-1"],
    ),
    (
        ["intrinsics", "{in}/sess/images/cap00.png", "--square-m", "0.02", "-o", "{out}/c.cameramodel"],
        "--board",
        ["0x0", "1x6", "9" * 400 + "x6", "²x6", "9x"],
    ),
    (["matches", "{in}/seq", "--image", "0", "-o", "{out}/m.png"], "--method", ["sift"]),
    (WORLD, "--image-format", ["gif", "PNG", ""]),
    (EVALUATE, "--precision", ["-1", "13", "1.5", "nan"]),
    (["simulate", "board-session", "-o", "{out}/b"], "--session", ["fine", ""]),
    (["simulate", "board-session", "-o", "{out}/b"], "--captures", ["0", "nan"]),
]


def option_cases() -> list[Case]:
    out = []
    for base, opt, values in OPTIONS:
        for v in values:
            args = list(base)
            if opt in args:  # replace the base's own value
                args[args.index(opt) + 1] = v
            else:
                args += [opt, v]
            out.append(
                Case(
                    f"{base[0]}-{base[1] if base[0] == 'simulate' else ''}-{opt}={v[:16]}",
                    args,
                    code=2,
                    message=opt,
                )
            )
    return out


def output_cases() -> list[Case]:
    """Outputs that would destroy, or write into, what is being read."""
    out = []

    def case(
        name: str,
        args: list[str],
        message: str,
        code: int = 5,
        mutate: Callable[[Path], None] = lambda _: None,
    ) -> None:
        out.append(Case(f"output-{name}", args, mutate, code, message))

    loc = ["localize", "{in}/seq", "--method", "icp"]
    case("localize-into-seq", [*loc, "-o", "{in}/seq", "--force"], "is the input")
    case("localize-into-parent", [*loc, "-o", "{in}", "--force"], "contains the input")
    case("localize-into-parent-noforce", [*loc, "-o", "{in}"], "contains the input")
    case("localize-inside-seq", [*loc, "-o", "{in}/seq/out", "--force"], "inside the input")
    case("localize-onto-file", [*loc, "-o", "{in}/a.tum"], "exists")
    case("localize-onto-file-force", [*loc, "-o", "{in}/a.tum", "--force"], "not a folder")
    case("localize-foreign-folder", [*loc, "-o", "{in}/sess/scans", "--force"], "not written by rigcal")
    case("localize-dotdot", [*loc, "-o", "{in}/seq/../seq", "--force"], "is the input")
    case(
        "carmen-onto-log",
        ["import-carmen", "{in}/log.carmen", "-o", "{in}/log.carmen", "--force"],
        "is the input",
    )
    case(
        "carmen-into-parent",
        ["import-carmen", "{in}/log.carmen", "-o", "{in}", "--force"],
        "contains the input",
    )
    case(
        "carmen-foreign",
        ["import-carmen", "{in}/log.carmen", "-o", "{in}/sess/scans", "--force"],
        "not written by rigcal",
    )
    case(
        "solve-onto-picks",
        ["solve", "{in}/sess/picks.yaml", "-o", "{in}/sess/picks.yaml", "--force"],
        "is the input",
    )
    case("solve-report-over-session", [*SOLVE[:4], "--report", "{in}/sess", "--force"], "contains the input")
    case(
        "solve-report-foreign",
        [*SOLVE[:4], "--report", "{in}/sess/scans", "--force"],
        "not written by rigcal",
    )
    case(
        "export-onto-rig",
        ["export", "{in}/rig.yaml", "--format", "ros", "-o", "{in}/rig.yaml", "--force"],
        "is the input",
    )
    case("export-exists", ["export", "{in}/rig.yaml", "--format", "ros", "-o", "{in}/a.tum"], "exists")
    case(
        "export-onto-folder",
        ["export", "{in}/rig.yaml", "--format", "ros", "-o", "{in}/seq", "--force"],
        "is a folder",
    )
    case("lines-onto-scan", ["lines", "{in}/scan.yaml", "--png", "{in}/scan.yaml", "--force"], "is the input")
    case("project-onto-image", [*PROJECT[:4], "-o", "{in}/sess/images/cap00.png", "--force"], "is the input")
    case(
        "check-log-onto-rig",
        ["check", "{in}/rig.yaml", "--picks", "{in}/sess/picks.yaml", "--log", "{in}/rig.yaml"],
        "is the input",
    )
    case("check-plot-onto-picks", [*CHECK, "--plot", "{in}/sess/picks.yaml", "--force"], "is the input")
    case("simulate-foreign", [*CALIB[:-1], "{in}/sess/scans", "--force"], "not written by rigcal")
    case("simulate-onto-file", [*CALIB[:-1], "{in}/a.tum"], "exists")
    case("world-onto-world-file", [*WORLD[:-1], "{in}/world.yaml", "--force"], "is the input")
    case("evaluate-plot-onto-truth", [*EVALUATE, "--plot", "{in}/gt.tum", "--force"], "a name ending in", 3)
    image = "{in}/sess/images/cap00.png"
    case("evaluate-plot-onto-file", [*EVALUATE, "--plot", image], "exists")
    case("matches-onto-file", ["matches", "{in}/seq", "--image", "0", "-o", image], "exists")

    def dangling(rel: str) -> Callable[[Path], None]:
        def mutate(inp: Path) -> None:
            (inp / rel).symlink_to(inp / "nowhere")

        return mutate

    case(
        "export-dangling-symlink",
        ["export", "{in}/rig.yaml", "--format", "ros", "-o", "{in}/link"],
        "exists",
        mutate=dangling("link"),
    )
    case("localize-dangling-symlink", [*loc, "-o", "{in}/link"], "not a folder", mutate=dangling("link"))
    case(
        "solve-escaping-name",
        SOLVE,
        "name",
        3,
        mutate=set_yaml("sess/picks.yaml", "captures.1.name", "../../../escaped"),
    )
    return out


def write_bag(
    path: Path,
    image: dict[str, Any] | None = None,
    info: dict[str, Any] | None = None,
    ros: int = 1,
    **scan: Any,
) -> None:
    """A ROS 1 (or 2: ``path`` a folder) bag with three scans, two images and, when
    ``info`` is given, a CameraInfo (/info, with ``info``'s fields); ``scan`` overrides
    LaserScan fields, ``image`` the second image's (with ``format``: CompressedImages)."""
    from rosbags.rosbag1 import Writer
    from rosbags.rosbag2 import Writer as Writer2
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC if ros == 1 else Stores.ROS2_HUMBLE)
    T = ts.types
    ser = ts.serialize_ros1 if ros == 1 else ts.serialize_cdr

    def header(t: float) -> Any:
        stamp = T["builtin_interfaces/msg/Time"](sec=int(t), nanosec=round((t % 1) * 1e9))
        extra = {"seq": 0} if ros == 1 else {}
        return T["std_msgs/msg/Header"](stamp=stamp, frame_id="f", **extra)

    fields = {
        "angle_min": -0.5, "angle_max": 0.5, "angle_increment": 0.1, "time_increment": 0.0,
        "scan_time": 0.025, "range_min": 0.1, "range_max": 30.0,
        "ranges": np.full(11, 2.0, np.float32), "intensities": np.zeros(0, np.float32),
    }  # fmt: skip
    fields.update(scan)
    compressed = image is not None and "format" in image
    img_type = "sensor_msgs/msg/CompressedImage" if compressed else "sensor_msgs/msg/Image"
    with Writer(path) if ros == 1 else Writer2(path, version=8) as w:
        cs = w.add_connection("/scan", "sensor_msgs/msg/LaserScan", typestore=ts)
        ci = w.add_connection("/image", img_type, typestore=ts)
        for k in range(3):
            msg = T["sensor_msgs/msg/LaserScan"](header=header(1.0 + 0.1 * k), **fields)
            w.write(cs, int(1e9 * (1 + k)), ser(msg, "sensor_msgs/msg/LaserScan"))
        for k in range(2):
            if compressed:
                png = np.frombuffer(cv2_png(np.full((4, 6), 50, np.uint8)), np.uint8)
                img = T[img_type](header=header(1.0 + 0.2 * k), format="png", data=png)
            else:
                img = T[img_type](
                    header=header(1.0 + 0.2 * k), height=4, width=6, encoding="mono8", is_bigendian=0,
                    step=6, data=np.full(24, 50, np.uint8),
                )  # fmt: skip
            for key, v in (image or {}).items() if k == 1 else ():
                setattr(img, key, _png_body(v) if key == "data" and compressed else v)
            w.write(ci, int(1e9 * (1 + k)) + 1, ser(img, img_type))
        if info is not None:
            cc = w.add_connection("/info", "sensor_msgs/msg/CameraInfo", typestore=ts)
            upper = ros == 1  # ROS 1 names the matrices K, D, R, P
            mats = {
                "d": np.zeros(5), "k": np.array([50.0, 0, 3, 0, 50, 2, 0, 0, 1]), "r": np.eye(3).ravel(),
                "p": np.array([50.0, 0, 3, 0, 0, 50, 2, 0, 0, 0, 1, 0]), **info,
            }  # fmt: skip
            roi = T["sensor_msgs/msg/RegionOfInterest"](
                x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
            )
            plain = {k: v for k, v in mats.items() if len(k) > 1}
            msg = T["sensor_msgs/msg/CameraInfo"](
                header=header(1.0), height=plain.pop("height", 4), width=plain.pop("width", 6),
                distortion_model=plain.pop("distortion_model", "plumb_bob"), binning_x=0, binning_y=0,
                roi=roi,
                **{(k.upper() if upper else k): v for k, v in mats.items() if len(k) == 1},
            )  # fmt: skip
            w.write(cc, int(1e9) + 2, ser(msg, "sensor_msgs/msg/CameraInfo"))


def cv2_png(img: np.ndarray) -> bytes:
    import cv2

    return bytes(cv2.imencode(".png", img)[1].tobytes())


INTR = [
    "intrinsics",
    "--corners",
    "{in}/corners.vnl",
    "--board",
    "3x2",
    "--square-m",
    "0.02",
    "--imagersize",
    "640x480",
    "-o",
    "{out}/c.cameramodel",
]
CAPTURE = [
    "capture",
    "{in}/run.bag",
    "--scan-topic",
    "/scan",
    "--image-topic",
    "/image",
    "--camera",
    "{in}/cam6x4.yaml",
    "--still-frames",
    "2",
    "-o",
    "{out}/cap",
]
PICK = ["pick", "{in}/sess/picks.yaml", "-o", "{out}/p.yaml"]
LASER = ["import-laser", "{in}/laser.txt", "--images", "{in}/images.txt", "-o", "{out}/seq"]
LASER_CSV = ["import-laser", "{in}/laser.csv", "-o", "{out}/seq"]
BATCH = ["batch", "{in}/batch.yaml", "-o", "{out}/b", "-j", "1"]
BOARD = ["solve", "{in}/board/board_session.yaml", "-o", "{out}/rig.yaml"]
BAG = ["import-bag", "{in}/run.bag", "--scan-topic", "/scan", "--image-topic", "/image", "-o", "{out}/seq"]


# Each command's unspoiled inputs: they must run clean, so that every case's error comes
# from what the case spoiled.
BASES = {
    "lines": LINES,
    "solve": SOLVE,
    "export": EXPORT,
    "check": CHECK,
    "project": PROJECT,
    "import-carmen": CARMEN,
    "localize": LOCALIZE,
    "evaluate": EVALUATE,
    "simulate-world": WORLD,
    "simulate-calib-session": CALIB,
    "import-bag": BAG,
    "intrinsics": INTR,
    "capture": CAPTURE,
    "pick": PICK,
    "import-laser": LASER,
    "import-laser-csv": LASER_CSV,
    "batch": BATCH,
    "solve-board": BOARD,
}


def bag_cases() -> list[Case]:
    out = []

    def bag(**scan: Any) -> Callable[[Path], None]:
        def mutate(p: Path) -> None:
            (p / "run.bag").unlink()
            write_bag(p / "run.bag", **scan)

        return mutate

    for key, vals in [
        ("angle_increment", [NAN, 0.0, 7.0, INF]),
        ("angle_min", [NAN, -INF, 1e30]),
        ("range_min", [NAN, -1.0, 50.0]),
        ("range_max", [NAN, 0.0, -INF]),  # +inf: no limit (test_bag_unlimited_range.py)
    ]:
        for v in vals:
            out.append(Case(f"bag-{key}={v}", BAG, bag(**{key: v}), 3, key))
    neg = np.full(11, 2.0, np.float32)
    neg[2] = -1.0
    out.append(Case("bag-negative-range", BAG, bag(ranges=neg), 3, "ranges[2]"))
    out.append(Case("bag-no-ranges", BAG, bag(ranges=np.zeros(0, np.float32)), 3, "ranges"))
    out.append(Case("bag-garbage", BAG, write("run.bag", b"#ROSBAG V2.0\ngarbage"), 3, "run.bag"))
    out.append(Case("bag-missing-topic", [*BAG[:3], "/nope", *BAG[4:]], code=3, message="/nope"))
    out.append(Case("bag-wrong-type", [*BAG[:3], "/image", *BAG[4:]], code=3, message="/image"))
    out.append(Case("bag-onto-bag", [*BAG[:-1], "{in}/run.bag", "--force"], code=5, message="is the input"))
    # A folder given as a ROS 2 bag that holds neither a metadata.yaml nor a storage file.
    folder = [BAG[0], "{in}/notes", *BAG[2:]]
    out.append(
        Case("bag-folder-no-bag", folder, write("notes/readme.txt", "x"), 3, "notes: got a folder without")
    )
    return out


def _u8(n: int) -> np.ndarray:
    return np.full(n, 7, np.uint8)


# Message bodies a broken driver writes: (name, fields of the second image, the key named).
BAD_IMAGE_BODIES: list[tuple[str, dict[str, Any], str]] = [
    ("data-short", {"data": _u8(23)}, "data"),
    ("data-long", {"data": _u8(25)}, "data"),
    ("data-empty", {"data": _u8(0)}, "data"),
    ("height-0", {"height": 0, "data": _u8(0)}, "height"),
    ("width-0", {"width": 0, "step": 0, "data": _u8(0)}, "width"),
    ("width-huge", {"width": 2**31, "step": 6}, "width"),
    ("step-short", {"step": 5, "data": _u8(20)}, "step"),
    ("step-0", {"step": 0, "data": _u8(0)}, "step"),
    ("bgr-step", {"encoding": "bgr8", "step": 6}, "step"),
    ("mono16-odd-step", {"encoding": "mono16", "step": 13, "data": _u8(52)}, "step"),
    ("mono16-odd-bytes", {"encoding": "mono16", "step": 12, "data": _u8(47)}, "data"),
    ("mono16-8-bit-step", {"encoding": "mono16"}, "step"),
    ("encoding-float", {"encoding": "32FC1"}, "encoding"),
    ("encoding-empty", {"encoding": ""}, "encoding"),
    ("encoding-bidi", {"encoding": "mono8\u202e\x1b[2J"}, "encoding"),
    ("compressed-broken-png", {"format": "png", "data": b"\x89PNG\r\n\x1a\nbroken"}, "data"),
    ("compressed-truncated-png", {"format": "png", "data": "truncated"}, "data"),
    ("compressed-crc", {"format": "png", "data": "crc"}, "data"),
    ("compressed-garbage", {"format": "jpeg", "data": _u8(40)}, "data"),
    ("compressed-empty", {"format": "png", "data": _u8(0)}, "data"),
]  # fmt: skip
BAD_BEAM_COUNTS: list[tuple[str, dict[str, Any], str]] = [
    ("angle-max-far", {"angle_max": 0.9}, "ranges"),
    ("angle-max-short", {"angle_max": 0.2}, "ranges"),
    ("angle-max-nan", {"angle_max": NAN}, "angle_max"),
    ("angle-max-inf", {"angle_max": INF}, "angle_max"),
    ("angle-max-wrong-side", {"angle_max": -1.5}, "ranges"),
    ("one-beam-of-many", {"ranges": np.full(1, 2.0, np.float32)}, "ranges"),
    ("ranges-doubled", {"ranges": np.full(22, 2.0, np.float32)}, "ranges"),
]
BAD_CAMERA_INFOS: list[tuple[str, dict[str, Any], str]] = [
    ("K-zero", {"k": np.zeros(9)}, "K"),
    ("fx-zero", {"k": np.array([0.0, 0, 3, 0, 50, 2, 0, 0, 1])}, "K"),
    ("fy-negative", {"k": np.array([50.0, 0, 3, 0, -50, 2, 0, 0, 1])}, "K"),
    ("K-nan", {"k": np.array([50.0, 0, NAN, 0, 50, 2, 0, 0, 1])}, "K"),
    ("width-0", {"width": 0}, "width"),
    ("height-0", {"height": 0}, "height"),
    ("size-0", {"width": 0, "height": 0}, "width"),
    ("model-fisheye", {"distortion_model": "equidistant", "d": np.zeros(4)}, "distortion_model"),
    ("d-short", {"d": np.zeros(3)}, "D"),
    ("d-inf", {"d": np.array([0.1, INF, 0, 0, 0])}, "D"),
]


def _png_body(kind: Any) -> Any:
    """Damaged PNG data: "truncated" (40 bytes of a PNG), "crc" (its image data fail their
    CRC: libpng prints a line of its own), bytes as they are."""
    if isinstance(kind, np.ndarray):
        return kind
    png = bytearray(cv2_png(np.arange(400, dtype=np.uint8).reshape(20, 20)))
    if kind == "truncated":
        png = png[:40]
    elif kind == "crc":
        png[60] ^= 0xFF
    else:
        png = bytearray(kind)
    return np.frombuffer(bytes(png), np.uint8)


def body_cases() -> list[Case]:
    """Bags whose messages do not hold what their type promises, for import-bag and
    capture, ROS 1 and ROS 2: each error names the bag, the topic and the message."""
    out: list[Case] = []
    capture_info = [
        *CAPTURE[: CAPTURE.index("--camera")],
        "--camera-info-topic",
        "/info",
        *CAPTURE[CAPTURE.index("--still-frames") :],
    ]

    def bag(ros: int, **kw: Any) -> Callable[[Path], None]:
        def mutate(p: Path) -> None:
            if ros == 1:
                (p / "run.bag").unlink()
            write_bag(p / ("run.bag" if ros == 1 else "run2"), ros=ros, **kw)

        return mutate

    def on(args: list[str], ros: int) -> list[str]:
        return [a.replace("{in}/run.bag", "{in}/run2") if ros == 2 else a for a in args]

    for ros in (1, 2):
        bagname = "run.bag" if ros == 1 else "run2"
        for name, fields, text in BAD_IMAGE_BODIES:
            msg = f"{bagname}: /image message 1: {text}: got "
            out.append(Case(f"bag-ros{ros}-image-{name}", on(BAG, ros), bag(ros, image=fields), 3, msg))
        for name, fields, text in BAD_BEAM_COUNTS:
            out.append(
                Case(
                    f"bag-ros{ros}-scan-{name}",
                    on(BAG, ros),
                    bag(ros, **fields),
                    3,
                    f"/scan message 0: {text}",
                )
            )
        for name, fields, text in BAD_CAMERA_INFOS:
            args = [*on(BAG, ros), "--camera-info-topic", "/info"]
            out.append(
                Case(f"bag-ros{ros}-info-{name}", args, bag(ros, info=fields), 3, f"/info message 0: {text}")
            )
        for name, fields, text in BAD_IMAGE_BODIES[::3]:
            out.append(
                Case(
                    f"capture-ros{ros}-image-{name}",
                    on(CAPTURE, ros),
                    bag(ros, image=fields),
                    3,
                    f"{bagname}: /image message 1: {text}: got ",
                )
            )
        for name, fields, text in BAD_CAMERA_INFOS[::3]:
            out.append(
                Case(
                    f"capture-ros{ros}-info-{name}",
                    on(capture_info, ros),
                    bag(ros, info=fields),
                    3,
                    f"{bagname}: /info message 0: {text}",
                )
            )
        out.append(
            Case(
                f"capture-ros{ros}-scan-count",
                on(CAPTURE, ros),
                bag(ros, angle_max=0.9),
                3,
                f"{bagname}: /scan message 0: ranges",
            )
        )
    out.append(
        Case(
            "capture-camera-of-another-size",
            [
                *CAPTURE[: CAPTURE.index("{in}/cam6x4.yaml")],
                "{in}/sess/camera.yaml",
                *CAPTURE[CAPTURE.index("{in}/cam6x4.yaml") + 1 :],
            ],
            code=3,
            message="expected the camera's size 640x480",
        )
    )
    out.append(
        Case(
            "capture-info-of-another-size",
            capture_info,
            bag(1, info={"width": 640, "height": 480}),
            3,
            "width x height: got '640x480'; expected the images' size 6x4",
        )
    )
    return out


# Names that would change the XML or the shell line they are pasted into, or hide what
# they are: none is a ROS name.
BAD_FRAME_NAMES = [
    '"/><joint name="x', "a--b", "-->", "", " ", "$(rm -rf ~)", "`id`", "a;b", "a\nb", "/abs",
    "a__b", "a/", "1a", "a b", "a&b", "\u202eevil", "a\u200bb", "é", "x" * 201,
]  # fmt: skip
HIDDEN = ["\u202e", "\u2066", "\u200b", "\x85", "\u2028", "\x1b[2J", "\x7f"]


def name_cases() -> list[Case]:
    """Names that reach other languages (URDF, xacro, shell lines) or the terminal."""
    out: list[Case] = []
    for fmt in ("ros", "urdf", "xacro"):
        base = ["export", "{in}/rig.yaml", "--format", fmt]
        for i, n in enumerate(BAD_FRAME_NAMES):
            opt = "--parent-frame" if i % 2 else "--child-frame"
            out.append(
                Case(f"export-{fmt}{opt}={_show(n)}", [*base, opt, n, "-o", "{out}/x"], code=2, message=opt)
            )
        out.append(
            Case(
                f"export-{fmt}-same-frames",
                [*base, "--parent-frame", "a", "--child-frame", "a"],
                code=2,
                message="a",
            )
        )
    for t in ["cam", "", "/a b", "/a;rm", "/a\n", "/\u202e"]:
        out.append(
            Case(f"export-rostopic={_show(t)}", [*EXPORT, "--rostopic", t], code=2, message="--rostopic")
        )
    for h in HIDDEN:
        name = f"cap{h}gnp.exe"
        out.append(
            Case(
                f"solve-hidden-name={_show(h)}",
                SOLVE,
                set_yaml("sess/picks.yaml", "captures.0.name", name),
                3,
                "name",
            )
        )
        out.append(
            Case(
                f"batch-hidden-name={_show(h)}",
                BATCH,
                set_yaml("batch.yaml", "items.0.name", name),
                3,
                "name",
            )
        )
        out.append(
            Case(
                f"localize-hidden-image={_show(h)}",
                LOCALIZE,
                edit_text("seq/images.csv", "f001.png", f"f{h}001.png"),
                3,
                "images.csv",
            )
        )
        for args, o in (
            (SOLVE, "{out}/rig.yaml"),
            (LOCALIZE, "{out}/loc"),
            (BATCH, "{out}/b"),
            (CAPTURE, "{out}/cap"),
            (EXPORT, "{out}/k.yaml"),
        ):
            bad = [a.replace(o, o[:-2] + h + o[-2:]) for a in args]
            out.append(Case(f"output-hidden-{args[0]}={_show(h)}", bad, code=5, message=f"U+{ord(h[0]):04X}"))
    long = "n" * 300
    out.append(Case("batch-name-300", BATCH, set_yaml("batch.yaml", "items.0.name", long), 3, "at most 200"))
    out.append(
        Case("solve-name-300", SOLVE, set_yaml("sess/picks.yaml", "captures.0.name", long), 3, "at most 200")
    )
    out.append(
        Case("pick-name-300", PICK, set_yaml("sess/picks.yaml", "captures.0.name", long), 3, "at most 200")
    )
    return out


DEEP = 50_000


def deep_texts() -> dict[str, str]:
    """Documents nested DEEP levels, each way a parser can nest."""
    return {
        "flow-seq": "schema_version: 1\nx: " + "[" * DEEP + "]" * DEEP + "\n",
        "flow-map": "schema_version: 1\nx: " + "{a: " * DEEP + "1" + "}" * DEEP + "\n",
        "block-seq": "- " * DEEP + "x\n",
        "unclosed": "x: " + "[" * DEEP + "\n",
        "after-error": "x: ]\n" + "[" * DEEP,
    }


def deep_cases() -> list[Case]:
    """Every YAML (and FileStorage, JSON) reader given a file nested 50 000 levels deep:
    one error line, not a crash of the parser's recursion."""
    out: list[Case] = []
    readers = [
        ("lines", LINES, "scan.yaml"),
        ("solve", SOLVE, "sess/picks.yaml"),
        ("solve-camera", SOLVE, "sess/camera.yaml"),
        ("export", EXPORT, "rig.yaml"),
        ("localize", LOCALIZE, "seq/sequence.yaml"),
        ("world", WORLD, "world.yaml"),
        ("batch", BATCH, "batch.yaml"),
        ("capture-camera", CAPTURE, "cam6x4.yaml"),
        ("board", BOARD, "board/board_session.yaml"),
        ("pick", PICK, "sess/picks.yaml"),
    ]
    texts = deep_texts()
    for name, args, rel in readers:
        for kind, text in texts.items():
            out.append(Case(f"deep-{name}-{kind}", args, write(rel, text), 3, rel.split("/")[-1]))

    for kind, text in (
        ("opencv-yaml", "%YAML:1.0\n---\nx: " + "[" * DEEP + "]" * DEEP + "\n"),
        (
            "opencv-xml",
            '<?xml version="1.0"?>\n<opencv_storage>' + "<a>" * DEEP + "</a>" * DEEP + "</opencv_storage>\n",
        ),
    ):
        rel = "cv.yaml" if kind == "opencv-yaml" else "cv.xml"

        def mutate(p: Path, rel: str = rel, text: str = text) -> None:
            write(rel, text)(p)
            set_yaml("sess/picks.yaml", "camera", f"../{rel}")(p)

        out.append(Case(f"deep-solve-camera-{kind}", SOLVE, mutate, 3, rel))

    out.append(
        Case(
            "deep-check-log",
            [*CHECK[:-1], "{in}/log.jsonl"],
            write("log.jsonl", "[" * DEEP + "]" * DEEP + "\n"),
            3,
            "log.jsonl",
        )
    )
    return out


def smaller_cases() -> list[Case]:
    """Checks made in the wrong order or with the wrong message or exit code before."""
    out: list[Case] = []
    missing_images = [
        "intrinsics",
        "{in}/nope0.png",
        "{in}/nope1.png",
        "--board",
        "3x2",
        "--square-m",
        "0.02",
    ]
    for lm in ["LENSMODEL_NOPE", "", "OPENCV8", "LENSMODEL_OPENCV8\n"]:
        # The lens model is checked before any image is looked at (or corners detected).
        out.append(
            Case(
                f"intrinsics-lensmodel={lm!r}",
                [*missing_images, "--lensmodel", lm, "-o", "{out}/c.cameramodel"],
                code=2,
                message="--lensmodel",
            )
        )
        out.append(
            Case(
                f"intrinsics-corners-lensmodel={lm!r}",
                [*INTR, "--lensmodel", lm],
                code=2,
                message="--lensmodel",
            )
        )

    def no_images(p: Path) -> None:
        from rigcal.recordings.sequence import read_sequence, write_sequence

        seq = read_sequence(p / "seq")
        write_sequence(p / "noimg", "room", list(seq.scans), [], None, {"made": "corpus"})

    def one_image(p: Path) -> None:
        from rigcal.recordings.sequence import ImageFrame, read_sequence, write_sequence

        seq = read_sequence(p / "seq")
        frame = ImageFrame(10.05, "f000.png", (p / "seq" / "images" / "f000.png").read_bytes())
        write_sequence(p / "oneimg", "room", list(seq.scans), [frame], None, {"made": "corpus"})

    for i in ("0", "1", "5"):
        out.append(
            Case(
                f"matches-no-images-{i}",
                ["matches", "{in}/noimg", "--image", i, "-o", "{out}/m.png"],
                no_images,
                3,
                "noimg: images: got '0 images'; expected 2 or more",
            )
        )
        out.append(
            Case(
                f"matches-one-image-{i}",
                ["matches", "{in}/oneimg", "--image", i, "-o", "{out}/m.png"],
                one_image,
                3,
                "got '1 images'",
            )
        )
    out.append(
        Case(
            "matches-last-image",
            ["matches", "{in}/seq", "--image", "2", "-o", "{out}/m.png"],
            code=3,
            message="--image: got 2; expected an index from 0 to 1",
        )
    )
    for log in ("{in}/seq", "{in}", "{out}"):
        out.append(
            Case(
                f"check-log-folder-{log.strip('{}').replace('/', '-')}",
                [*CHECK[:-1], log],
                code=5,
                message="is a folder" if log != "{in}" else "contains the input",
            )
        )
    out.append(
        Case(
            "check-log-folder-with-plot",
            [*CHECK[:-1], "{out}", "--no-log", "--plot", "{out}/p.png"],
            code=5,
            message="is a folder",
        )
    )

    def link(target: str) -> Callable[[Path], None]:
        def mutate(p: Path) -> None:
            (p / "im1.png").unlink()
            (p / "im1.png").symlink_to(target if target.startswith("/") else p / target)

        return mutate

    for name, target in (("outside", "../outside.png"), ("abs", "/etc/hostname"), ("loop", "im1.png")):

        def mutate(p: Path, target: str = target, name: str = name) -> None:
            if name == "outside":
                (p.parent / "outside.png").write_bytes((p / "im0.png").read_bytes())
            link(target)(p)

        out.append(Case(f"import-laser-images-symlink-{name}", LASER, mutate, 3, "images.txt: line 2"))
    return out


def opt_cases(cmd: str, args: list[str], option: str, values: list[str]) -> list[Case]:
    """``option`` given each of ``values`` (exit 2, the option named)."""
    return [Case(f"{cmd}-option{option}={v}", [*args, option, v], code=2, message=option) for v in values]


BAD_FLOATS = ["nan", "inf", "-inf", "x", "1e400"]


def capture_cases() -> list[Case]:
    out: list[Case] = []
    out += opt_cases("capture", CAPTURE, "--still-frames", ["1", "0", "x", "1e400"])
    out += opt_cases("capture", CAPTURE, "--scan-threshold-m", [*BAD_FLOATS, "0", "-1"])
    out += opt_cases("capture", CAPTURE, "--image-threshold", [*BAD_FLOATS, "0"])
    out += opt_cases("capture", CAPTURE, "--changed-fraction", [*BAD_FLOATS, "0", "1"])
    out += opt_cases("capture", CAPTURE, "--max-offset-s", [*BAD_FLOATS, "0"])
    out += opt_cases("capture", CAPTURE, "--box-width-m", [*BAD_FLOATS, "0.01"])
    src = CAPTURE.index("{in}/run.bag")
    cam = CAPTURE.index("{in}/cam6x4.yaml")

    def arg(i: int, value: str) -> list[str]:
        return [*CAPTURE[:i], value, *CAPTURE[i + 1 :]]

    out.append(Case("capture-missing-source", arg(src, "{in}/nope.bag"), code=3, message="nope.bag"))
    out.append(Case("capture-nul-source", arg(src, "{in}/ru\0n.bag"), code=2, message="NUL"))
    out.append(Case("capture-garbage-bag", CAPTURE, write("run.bag", b"#ROSBAG V2.0\ngarbage"), 3, "run.bag"))
    out.append(Case("capture-empty-bag", CAPTURE, write("run.bag", b""), 3, "run.bag"))
    out.append(Case("capture-missing-topic", arg(CAPTURE.index("/scan"), "/nope"), code=3, message="/nope"))
    out.append(Case("capture-wrong-type", arg(CAPTURE.index("/scan"), "/image"), code=3, message="/image"))
    out.append(Case("capture-missing-camera", arg(cam, "{in}/nope.yaml"), code=3, message="nope.yaml"))
    out.append(Case("capture-camera-folder", arg(cam, "{in}/seq"), code=3, message="seq"))
    out += [
        Case(f"capture-camera-K={_show(v)}", CAPTURE, set_yaml("cam6x4.yaml", "K.0.0", v), 3, "K")
        for v in NOT_POSITIVE[::2]
    ]
    out.append(Case("capture-camera-not-utf8", CAPTURE, write("cam6x4.yaml", b"\xff\xfa\xfe"), 3, "camera"))
    out.append(
        Case(
            "capture-sequence-garbage-npz",
            arg(src, "{in}/seq"),
            write("seq/scans.npz", b"PK"),
            3,
            "scans.npz",
        )
    )
    out.append(
        Case(
            "capture-sequence-dotdot-image",
            arg(src, "{in}/seq"),
            edit_text("seq/images.csv", "f001.png", "../../../x.png"),
            3,
            "images.csv",
        )
    )
    o = CAPTURE.index("{out}/cap")
    out.append(Case("capture-onto-input-folder", [*arg(o, "{in}"), "--force"], code=5, message="input"))
    out.append(Case("capture-onto-bag", [*arg(o, "{in}/run.bag"), "--force"], code=2, message="run.bag"))
    out.append(
        Case(
            "capture-onto-camera",
            [*arg(o, "{in}/sess")[:cam], "{in}/sess/camera.yaml", *arg(o, "{in}/sess")[cam + 1 :], "--force"],
            code=5,
            message="sess",
        )
    )
    out.append(Case("capture-into-sequence", [*arg(src, "{in}/seq")[:-1], "{in}/seq/sub", "--force"], code=5))
    out.append(Case("capture-exists", arg(o, "{in}/seq"), code=5, message="exists"))
    out.append(Case("capture-onto-file", arg(o, "{in}/a.tum"), code=2, message="a.tum"))
    out.append(Case("capture-nul-output", arg(o, "{out}/c\0ap"), code=2, message="NUL"))
    return out


def pick_cases() -> list[Case]:
    out: list[Case] = []
    out += opt_cases("pick", PICK, "--search-px", [*BAD_FLOATS, "1", "500"])
    out += opt_cases("pick", PICK, "--edge-span-m", [*BAD_FLOATS, "0"])
    out += opt_cases("pick", PICK, "--review-below", [*BAD_FLOATS, "2"])
    out += opt_cases("pick", PICK, "--box-width-m", [*BAD_FLOATS, "0"])
    rel = "sess/picks.yaml"
    out += number_cases(
        "pick", PICK, rel, "captures.0.image_endpoints_px.0.0", NOT_A_NUMBER, "image_endpoints_px"
    )
    out += number_cases("pick", PICK, rel, "captures.0.name", BAD_NAMES, "name")
    out += number_cases(
        "pick", PICK, rel, "captures.0.scan", ["../../../../../nope.yaml", "a\0b.yaml", None], "scan"
    )
    out += number_cases(
        "pick", PICK, rel, "captures.0.image", ["../../../../../nope.png", "a\0b.png", 3], "image"
    )
    out += number_cases("pick", PICK, rel, "camera", ["nope.yaml", None], "camera")
    out += [
        Case(
            f"pick-box-width={_show(v)}",
            PICK,
            lambda p, v=v: (set_yaml(rel, "schema_version", 2)(p), set_yaml(rel, "box", {"width_m": v})(p)),
            3,
            "width_m",
        )
        for v in NOT_POSITIVE
    ]
    out += number_cases("pick", PICK, rel, "captures", [None, [], "x"], "captures")
    out += number_cases("pick", PICK, "sess/camera.yaml", "K.0.0", NOT_POSITIVE[::2], "K")
    out += rig_cases("pick", [*PICK, "--rig", "{in}/rig.yaml"])[::4]
    out.append(
        Case("pick-missing", ["pick", "{in}/nope.yaml", "-o", "{out}/p.yaml"], code=3, message="nope.yaml")
    )
    out.append(Case("pick-missing-rig", [*PICK, "--rig", "{in}/nope.yaml"], code=3, message="nope.yaml"))
    out.append(Case("pick-alias-bomb", PICK, write(rel, _alias_bomb()), 3, "picks.yaml"))
    out.append(Case("pick-not-utf8", PICK, write(rel, b"\xff\xfe\xfa"), 3, "picks.yaml"))
    out.append(
        Case("pick-corrupt-image", PICK, write("sess/images/cap00.png", b"\x89PNGbroken"), 3, "cap00.png")
    )
    out.append(
        Case(
            "pick-onto-picks",
            ["pick", "{in}/" + rel, "-o", "{in}/" + rel, "--force"],
            code=5,
            message="is the input",
        )
    )
    out.append(Case("pick-exists", ["pick", "{in}/" + rel, "-o", "{in}/a.tum"], code=5, message="exists"))
    out.append(
        Case(
            "pick-onto-folder",
            ["pick", "{in}/" + rel, "-o", "{in}/seq", "--force"],
            code=2,
            message="directory",
        )
    )
    out.append(
        Case(
            "pick-sheet-onto-image",
            [*PICK, "--sheet", "{in}/sess/images/cap00.png", "--force"],
            code=5,
            message="is the input",
        )
    )
    out.append(
        Case(
            "pick-sheet-onto-rig",
            [*PICK, "--rig", "{in}/rig.yaml", "--sheet", "{in}/rig.yaml", "--force"],
            code=5,
            message="is the input",
        )
    )
    out.append(Case("pick-sheet-is-output", [*PICK, "--sheet", "{out}/p.yaml"], code=5, message="p.yaml"))
    out.append(Case("pick-sheet-exists", [*PICK, "--sheet", "{in}/a.tum"], code=5, message="exists"))
    out.append(
        Case("pick-nul-output", ["pick", "{in}/" + rel, "-o", "{out}/p\0.yaml"], code=2, message="NUL")
    )
    return out


def laser_cases() -> list[Case]:
    out: list[Case] = []
    rel = "laser.txt"
    first = "1.0 -0.5 0.25 0.5 3 5 2.0 2.0 2.0 2.0 2.0"

    def radlocc(name: str, new: str, message: str = "laser.txt") -> None:
        out.append(Case(f"import-laser-radlocc-{name}", LASER, edit_text(rel, first, new), 3, message))

    for v in ["nan", "inf", "-inf", "1e400", "x"]:
        radlocc(f"stamp={v}", first.replace("1.0 ", f"{v} ", 1))
        radlocc(f"angle-min={v}", first.replace(" -0.5 ", f" {v} "))
        radlocc(f"increment={v}", first.replace(" 0.25 ", f" {v} "))
        radlocc(f"angle-max={v}", first.replace(" 0.5 3 ", f" {v} 3 "))
    for v in ["0", "-0.25", "1e-300"]:
        radlocc(f"increment={v}", first.replace(" 0.25 ", f" {v} "))
    radlocc("range=x", first.replace(" 2.0 2.0 ", " x 2.0 ", 1))
    radlocc("unit-type", first.replace(" 3 5 ", " 2 5 "))
    for n in ["4", "6", "0", "-5", "5.5", "9" * 400]:
        radlocc(f"count={n[:8]}", first.replace(" 3 5 ", f" 3 {n} "))
    radlocc("angles-beyond-2pi", "1.0 -50 25 50 3 5 2.0 2.0 2.0 2.0 2.0")
    radlocc("too-few", "1.0 -0.5 0.25")
    radlocc("short-ranges", "1.0 -0.5 0.25 0.5 3 5 2.0 2.0")
    last = "1.3 -0.5 0.25 0.5 3 5 2.0 2.0 2.0 2.0 2.0\n"  # a log cut short: refused when strict
    cut = edit_text(rel, last, last[:24])
    out.append(Case("import-laser-radlocc-cut-strict", [*LASER, "--stamps", "strict"], cut, 3, "cut short"))
    strict = [*LASER, "--stamps", "strict"]  # the default repairs small glitches
    out.append(
        Case(
            "import-laser-radlocc-stamp-repeated",
            strict,
            edit_text(rel, "1.1 -0.5", "1.0 -0.5"),
            3,
            "laser.txt",
        )
    )
    out.append(
        Case(
            "import-laser-radlocc-stamp-back", strict, edit_text(rel, "1.2 -0.5", "0.5 -0.5"), 3, "laser.txt"
        )
    )
    out.append(
        Case(
            "import-laser-radlocc-broken-clock",
            LASER,
            edit_text(rel, "1.2 -0.5", "-9 -0.5"),
            3,
            "broken clock",
        )
    )
    out.append(Case("import-laser-radlocc-empty", LASER, write(rel, ""), 3, "laser.txt"))
    out.append(Case("import-laser-radlocc-comments", LASER, write(rel, "# nothing\n"), 3, "laser.txt"))
    out.append(Case("import-laser-radlocc-binary", LASER, write(rel, b"\xff\xfe\x00\x01"), 3, "laser.txt"))
    out.append(Case("import-laser-radlocc-as-csv", [*LASER, "--format", "csv"], code=3, message="laser.txt"))
    csv = "laser.csv"

    def csvcase(name: str, old: str, new: str) -> None:
        out.append(Case(f"import-laser-csv-{name}", LASER_CSV, edit_text(csv, old, new), 3, "laser.csv"))

    for v in ["nan", "inf", "x", "1e400"]:
        csvcase(f"stamp={v}", "1.1,0.0,2.0", f"{v},0.0,2.0")
        csvcase(f"angle={v}", "1.1,0.0,2.0", f"1.1,{v},2.0")
    csvcase("range=x", "1.1,0.0,2.0", "1.1,0.0,x")
    csvcase("angle-degrees-as-rad", "1.1,0.2,2.0", "1.1,90,2.0")
    csvcase("angles-decrease", "1.1,0.2,2.0", "1.1,-0.1,2.0")
    csvcase("angle-repeated", "1.1,0.2,2.0", "1.1,0.0,2.0")
    back = ("1.2,-0.2,2.0\n1.2,0.0,2.0\n1.2,0.2,2.0", "0.5,-0.2,2.0\n0.5,0.0,2.0\n0.5,0.2,2.0")
    out.append(
        Case(
            "import-laser-csv-stamp-back",
            [*LASER_CSV, "--stamps", "strict"],
            edit_text(csv, *back),
            3,
            "laser.csv",
        )
    )
    csvcase("broken-clock", back[0], back[0].replace("1.2,", "-9,"))
    csvcase("short-row", "1.1,0.0,2.0", "1.1,0.0")
    csvcase("no-range-column", "stamp_s,angle_rad,range_m", "stamp_s,angle_rad,dist")
    csvcase("no-angle-column", "stamp_s,angle_rad,range_m", "stamp_s,bearing,range_m")
    out.append(
        Case(
            "import-laser-csv-header-only",
            LASER_CSV,
            write(csv, "stamp_s,angle_rad,range_m\n"),
            3,
            "laser.csv",
        )
    )
    out.append(
        Case("import-laser-csv-as-radlocc", [*LASER_CSV, "--format", "radlocc"], code=3, message="laser.csv")
    )
    il = "images.txt"

    def images(name: str, old: str, new: str, message: str = "images.txt") -> None:
        out.append(Case(f"import-laser-images-{name}", LASER, edit_text(il, old, new), 3, message))

    images("dotdot", "im1.png", "../../../x.png")
    images("abs", "im1.png", "/etc/passwd")
    images("nul", "im1.png", "i\0m.png")
    images("folder", "im1.png", ".")
    images("missing", "im1.png", "nope.png", "nope.png")
    for v in ["nan", "inf", "-inf", "1e400"]:
        images(f"stamp={v}", "1.1 im1.png", f"{v} im1.png")
    # Steps back and repeated stamps are repaired as the log's (--stamps repair); strict refuses them.
    for name, stamp in (("stamp-back", "0.5"), ("stamp-repeated", "1.0")):
        edit = edit_text(il, "1.1 im1.png", f"{stamp} im1.png")
        out.append(Case(f"import-laser-images-{name}", strict, edit, 3, il))
    images("three-fields", "1.1 im1.png", "1.1 im1.png extra")
    images("no-stamp", "1.1 im1.png", "im1.png im1.png")
    out.append(Case("import-laser-images-empty", LASER, write(il, ""), 3, "images.txt"))
    out.append(Case("import-laser-images-binary", LASER, write(il, b"\xff\xfe\x00"), 3, "images.txt"))
    out.append(
        Case("import-laser-images-stamps-only-missing", LASER, write(il, "1.0\n1.1\n"), 3, "image_001")
    )
    out.append(Case("import-laser-images-stamps-only-nan", LASER, write(il, "nan\n"), 3, "images.txt"))
    out += opt_cases("import-laser", LASER, "--range-min-m", ["nan", "inf", "-1", "x"])
    out += opt_cases("import-laser", LASER, "--range-max-m", ["nan", "inf", "0", "-1"])
    out += opt_cases("import-laser", LASER, "--format", ["carmen", ""])
    out.append(
        Case(
            "import-laser-range-min-over-max",
            [*LASER, "--range-min-m", "50", "--range-max-m", "10"],
            code=3,
            message="--range-min-m",
        )
    )
    out.append(
        Case(
            "import-laser-missing",
            ["import-laser", "{in}/nope.txt", "-o", "{out}/seq"],
            code=3,
            message="nope.txt",
        )
    )
    out.append(
        Case("import-laser-folder", ["import-laser", "{in}/seq", "-o", "{out}/seq"], code=3, message="seq")
    )
    out.append(
        Case(
            "import-laser-nul", ["import-laser", "{in}/la\0ser.txt", "-o", "{out}/seq"], code=2, message="NUL"
        )
    )
    out.append(
        Case(
            "import-laser-missing-images",
            [*LASER[:3], "{in}/nope.txt", *LASER[4:]],
            code=3,
            message="nope.txt",
        )
    )
    out.append(
        Case(
            "import-laser-missing-camera", [*LASER, "--camera", "{in}/nope.yaml"], code=3, message="nope.yaml"
        )
    )
    out.append(
        Case(
            "import-laser-camera-K=nan",
            [*LASER, "--camera", "{in}/sess/camera.yaml"],
            set_yaml("sess/camera.yaml", "K.0.0", NAN),
            3,
            "K",
        )
    )
    out.append(
        Case(
            "import-laser-camera-garbage", [*LASER, "--camera", "{in}/laser.txt"], code=3, message="laser.txt"
        )
    )
    out.append(
        Case("import-laser-onto-input-folder", [*LASER[:-1], "{in}", "--force"], code=5, message="input")
    )
    out.append(
        Case("import-laser-onto-log", [*LASER[:-1], "{in}/laser.txt", "--force"], code=2, message="laser.txt")
    )
    out.append(Case("import-laser-exists", [*LASER[:-1], "{in}/seq"], code=5, message="exists"))
    out.append(
        Case(
            "import-laser-foreign",
            [*LASER[:-1], "{in}/sess/scans", "--force"],
            code=5,
            message="not written by rigcal",
        )
    )
    out.append(Case("import-laser-nul-output", [*LASER[:-1], "{out}/s\0eq"], code=2, message="NUL"))
    return out


def batch_cases() -> list[Case]:
    out: list[Case] = []
    rel = "batch.yaml"
    for key, vals in [
        ("schema_version", [2, None, "1", 1.5]),
        ("command", ["bogus", None, 3, ["check"]]),
        ("items", [None, [], "x", {}, [None], ["a.tum"]]),
        ("items.0.name", ["../x", "a/b", "", "a\0b", 7, ".."]),
        ("items.0.trajectory", [None, 5, "a\0b.tum", ["a.tum"]]),
        ("items.0.gt", [None, 3.5]),
        ("items.0.level", [0.01]),
        ("defaults", ["x", [1]]),
    ]:
        for v in vals:
            out.append(
                Case(
                    f"batch-{key}={_show(v)}",
                    BATCH,
                    set_yaml(rel, key, v),
                    3,
                    key.split(".")[-1].replace("0", ""),
                )
            )
    out.append(Case("batch-no-items-key", BATCH, drop_yaml(rel, "items"), 3, "items"))
    out.append(Case("batch-no-command", BATCH, drop_yaml(rel, "command"), 3, "command"))
    out.append(Case("batch-no-gt", BATCH, drop_yaml(rel, "items.0.gt"), 3, "gt"))
    out.append(Case("batch-unknown-top-key", BATCH, set_yaml(rel, "workers", 4), 3, "workers"))
    out.append(
        Case(
            "batch-duplicate-names",
            BATCH,
            set_yaml(rel, "items", [{"name": "one", "trajectory": "a.tum", "gt": "gt.tum"}] * 2),
            3,
            "one",
        )
    )
    out.append(Case("batch-alias-bomb", BATCH, write(rel, _alias_bomb()), 3, "batch.yaml"))
    out.append(Case("batch-items-bomb", BATCH, with_bomb(rel, "items"), 3, "batch.yaml"))
    out.append(Case("batch-not-utf8", BATCH, write(rel, b"\xff\xfe\xfa"), 3, "batch.yaml"))
    out.append(Case("batch-not-yaml", BATCH, write(rel, "items: [\n"), 3, "batch.yaml"))
    out.append(Case("batch-empty", BATCH, write(rel, ""), 3, "batch.yaml"))
    out.append(
        Case("batch-missing", ["batch", "{in}/nope.yaml", "-o", "{out}/b"], code=3, message="nope.yaml")
    )
    out.append(
        Case("batch-glob-no-command", ["batch", "{in}/*.tum", "-o", "{out}/b"], code=2, message="--command")
    )
    out.append(
        Case(
            "batch-glob-no-match",
            ["batch", "{in}/*.nope", "--command", "evaluate", "--set", "gt=gt.tum", "-o", "{out}/b"],
            code=3,
            message="nope",
        )
    )
    out.append(
        Case(
            "batch-glob-bad-set",
            ["batch", "{in}/*.tum", "--command", "evaluate", "--set", "noequals", "-o", "{out}/b"],
            code=3,
            message="--set",
        )
    )
    out.append(
        Case(
            "batch-glob-unknown-set",
            [
                "batch",
                "{in}/*.tum",
                "--command",
                "evaluate",
                "--set",
                "gt=gt.tum",
                "--set",
                "bogus=1",
                "-o",
                "{out}/b",
            ],
            code=3,
            message="bogus",
        )
    )
    out.append(
        Case(
            "batch-glob-nul",
            ["batch", "{in}/*\0.tum", "--command", "evaluate", "-o", "{out}/b"],
            code=2,
            message="NUL",
        )
    )
    out += opt_cases("batch", BATCH[:-2], "-j", ["-1", "x", "nan"])
    out.append(Case("batch-onto-manifest", [*BATCH[:3], "{in}/batch.yaml"], code=2, message="batch.yaml"))
    out.append(Case("batch-onto-input-folder", [*BATCH[:3], "{in}"], code=5, message="input"))
    out.append(Case("batch-onto-file", [*BATCH[:3], "{in}/a.tum"], code=2, message="a.tum"))
    out.append(
        Case("batch-foreign", [*BATCH[:3], "{in}/sess/scans"], code=5, message="not written by rigcal")
    )
    out.append(Case("batch-nul-output", [*BATCH[:3], "{out}/b\0"], code=2, message="NUL"))
    return out


def returns_file_cases() -> list[Case]:
    out: list[Case] = []
    rel = "board/board_session.yaml"
    for v in [
        "../../../../../nope.txt",
        "a\0b.txt",
        None,
        5,
        "",
        "nope.txt",
        ".",
        ["ret00.txt"],
    ]:
        out.append(
            Case(
                f"board-returns-file={_show(v)}",
                BOARD,
                set_yaml(rel, "captures.0.laser_side.returns_file", v),
                3,
                "returns_file",
            )
        )
    out.append(
        Case(
            "board-returns-file-outside",
            BOARD,
            set_yaml(rel, "captures.0.laser_side.returns_file", "/etc/passwd"),
            3,
            "passwd",
        )
    )
    out.append(
        Case(
            "board-returns-file-needs-schema-2",
            BOARD,
            set_yaml(rel, "schema_version", 1),
            3,
            "schema_version",
        )
    )
    ret = "board/ret00.txt"

    def spoil(name: str, text: str | bytes, message: str = "ret00.txt") -> None:
        out.append(Case(f"board-returns-{name}", BOARD, write(ret, text), 3, message))

    for v in ["nan", "inf", "-inf", "1e400", "x"]:
        spoil(f"x={v}", f"{v} 1.0\n1.0 1.0\n")
        spoil(f"z={v}", f"1.0 1.0 {v}\n1.1 1.0 0\n")
    spoil("z-off-plane", "1.0 1.0 0.5\n1.1 1.0 0\n")
    spoil("one-field", "1.0\n1.1 1.0\n")
    spoil("four-fields", "1.0 1.0 0 0\n1.1 1.0 0\n")
    spoil("one-point", "1.0 1.0\n")
    spoil("repeated-point", "1.0 1.0\n1.0 1.0\n")
    spoil("empty", "")
    spoil("comments-only", "% nothing\n# still nothing\n")
    spoil("binary", b"\xff\xfe\x00\x01")
    out.append(Case("board-returns-missing", BOARD, lambda p: (p / ret).unlink(), 3, "ret00.txt"))
    out.append(
        Case("board-returns-folder", BOARD, lambda p: (p / ret).unlink() or (p / ret).mkdir(), 3, "ret00.txt")
    )
    out.append(
        Case(
            "board-rig-onto-returns", [*BOARD[:-1], "{in}/" + ret, "--force"], code=5, message="is the input"
        )
    )
    return out


def camera_format_cases() -> list[Case]:
    """The session's camera as an OpenCV FileStorage file, spoiled; and corner files."""
    out = []
    use = set_yaml("sess/picks.yaml", "camera", "../cv.yaml")
    good = "   data: [ -0.15, 0.05, 0.0005, -0.0003, 0. ]"
    for name, new in [
        ("scalar", "distortion_coefficients: 5"),
        ("string", 'distortion_coefficients: "abc"'),
        ("list", "distortion_coefficients: [1, 2]"),
    ]:

        def mutate(p: Path, new: str = new) -> None:
            use(p)
            text = (p / "cv.yaml").read_text().split("distortion_coefficients:")[0]
            (p / "cv.yaml").write_text(text + new + "\n")

        out.append(Case(f"solve-opencv-distortion-{name}", SOLVE, mutate, 3, "distortion_coefficients"))
    for v in ["nan", "inf", "-inf", "1e400"]:

        def spoil(p: Path, v: str = v) -> None:
            use(p)
            edit_text("cv.yaml", good, good.replace("0.05", v))(p)

        out.append(Case(f"solve-opencv-distortion-value={v}", SOLVE, spoil, 3, "distortion_coefficients"))
    for v in ["nan", "inf", "-inf", "x"]:
        out.append(
            Case(
                f"intrinsics-corner={v}",
                INTR,
                edit_text("corners.vnl", "img1.png 200.0 100.0", f"img1.png {v} 100.0"),
                3,
                "corners.vnl",
            )
        )
        out.append(
            Case(
                f"intrinsics-level={v}",
                INTR,
                edit_text("corners.vnl", "img1.png 200.0 100.0", f"img1.png 200.0 100.0 {v}"),
                3,
                "corners.vnl",
            )
        )
    return out


def all_cases() -> list[Case]:
    cases = [
        *scan_cases("lines", LINES, "scan.yaml"),
        *picks_cases(),
        *rig_cases("export", EXPORT),
        *rig_cases("check", CHECK)[::4],
        *rig_cases("project", PROJECT)[::5],
        *carmen_cases(),
        *sequence_cases(),
        *tum_cases(),
        *world_cases(),
        *option_cases(),
        *camera_format_cases(),
        *bag_cases(),
        *body_cases(),
        *name_cases(),
        *deep_cases(),
        *smaller_cases(),
        *output_cases(),
        *capture_cases(),
        *pick_cases(),
        *laser_cases(),
        *batch_cases(),
        *returns_file_cases(),
        Case("lines-nul-path", ["lines", "{in}/sc\0an.yaml"], code=2, message="NUL"),
        Case("lines-missing", ["lines", "{in}/nope.yaml"], code=3, message="nope.yaml"),
        Case("lines-folder", ["lines", "{in}/seq"], code=3, message="seq"),
        Case("lines-alias-bomb", LINES, write("scan.yaml", _alias_bomb()), 3, "scan.yaml"),
        Case("lines-not-utf8", LINES, write("scan.yaml", b"\xff\xfe\xfa"), 3, "scan.yaml"),
        Case(
            "project-corrupt-image",
            PROJECT,
            write("sess/images/cap00.png", b"\x89PNG\r\n\x1a\nbroken"),
            3,
            "cap00.png",
        ),
        Case("project-empty-image", PROJECT, write("sess/images/cap00.png", b""), 3, "cap00.png"),
        Case(
            "check-corrupt-log",
            [*CHECK[:-1], "{in}/log.jsonl"],
            write("log.jsonl", "{not json\n"),
            3,
            "log.jsonl",
        ),
        Case(
            "check-plot-fails-log-untouched",
            [*CHECK[:-1], "{in}/log.jsonl", "--plot", "{in}/a.tum/p.png"],
            write("log.jsonl", ""),
            5,
            "p.png",
        ),
        Case(
            "solve-rig-onto-report",
            [*SOLVE[:3], "{out}/same", "--report", "{out}/same"],
            code=5,
            message="same",
        ),
        Case("bomb-scan-frame", LINES, with_bomb("scan.yaml", "frame"), 3, "scan.yaml"),
        Case("bomb-sequence-source", LOCALIZE, with_bomb("seq/sequence.yaml", "source"), 3, "sequence.yaml"),
        Case("bomb-rig-provenance", EXPORT, with_bomb("rig.yaml", "provenance"), 3, "rig.yaml"),
        Case("bomb-picks-laser", SOLVE, with_bomb("sess/picks.yaml", "laser"), 3, "picks.yaml"),
        Case("bomb-world-name", WORLD, with_bomb("world.yaml", "name"), 3, "world.yaml"),
        Case(
            "yaml-self-reference",
            LINES,
            lambda p: (p / "scan.yaml").write_text((p / "scan.yaml").read_text() + "frame: &loop [*loop]\n"),
            3,
            "scan.yaml",
        ),
        Case("check-unwritable-plot", [*CHECK, "--plot", "{out}/nodir/\0.png"], code=2, message="NUL"),
        Case(
            "check-board-session-as-picks",
            [
                "check",
                "{in}/rig.yaml",
                "--picks",
                "{in}/board/board_session.yaml",
                "--log",
                "{out}/log.jsonl",
            ],
            code=3,
            message="check a board session with",
        ),
        Case("check-two-sources", [*CHECK, "--sequence", "{in}/seq"], code=2, message="one of --picks"),
        Case(
            "check-sequence-of-another-camera",
            ["check", "{in}/rig.yaml", "--sequence", "{in}/seq", "--log", "{out}/log.jsonl"],
            code=3,
            message="expected 640x480",
        ),
    ]
    ids = [c.id for c in cases]
    dup = {i for i in ids if ids.count(i) > 1}
    assert not dup, dup
    return cases


# --- running ---------------------------------------------------------------------------------
def snapshot(root: Path) -> dict[str, tuple[Any, ...]]:
    """Every entry under ``root``: kind, mode and content hash (or link target)."""
    out: dict[str, tuple[Any, ...]] = {}
    for dirpath, dirnames, filenames in os.walk(root):
        for name in dirnames + filenames:
            p = Path(dirpath) / name
            st = p.lstat()
            rel = p.relative_to(root).as_posix()
            if p.is_symlink():
                out[rel] = ("link", os.readlink(p))
            elif p.is_dir():
                out[rel] = ("dir", st.st_mode)
            else:
                out[rel] = ("file", st.st_mode, hashlib.sha256(p.read_bytes()).hexdigest())
    return out


def prepare(case: Case, template: Path, tmp: Path) -> tuple[Path, Path, list[str]]:
    """Copy the inputs under tmp/a/b/in (escapes land in tmp/a), spoil them; the args."""
    inp = tmp / "a" / "b" / "in"
    out = tmp / "a" / "b" / "out"
    shutil.copytree(template, inp, symlinks=True)
    out.mkdir()
    case.mutate(inp)
    args = [a.replace("{in}", str(inp)).replace("{out}", str(out)) for a in case.args]
    return inp, out, args


def run_case(case: Case, template: Path, tmp: Path) -> Outcome:
    """Run one case and list what is wrong with its outcome (empty: it passed)."""
    from rigcal.cli.main import main

    _, _, args = prepare(case, template, tmp)
    before = snapshot(tmp)
    err = io.StringIO()
    code: int | None = None
    tb = ""
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            code = main(args)
        except BaseException as exc:  # a traceback: the bug this corpus hunts
            import traceback

            tb = "".join(traceback.format_exception(exc))
    after = snapshot(tmp)
    o = Outcome(code, err.getvalue(), tb)
    if tb:
        o.problems.append("traceback: " + tb.strip().splitlines()[-1][:200])
    elif code == 0:
        o.problems.append("exit 0 on bad input")
    elif code != case.code:
        o.problems.append(f"exit {code}, expected {case.code}")
    lost = [k for k in before if after.get(k) != before[k]]
    if lost:
        o.problems.append(f"data loss: {lost[:3]}")
    new = [k for k in after if k not in before]
    if new:
        outside = [k for k in new if not k.startswith("a/b/out/")]
        o.problems.append(("escaped: " if outside else "written on failure: ") + str((outside or new)[:3]))
    if not tb:
        lines = [x for x in o.err.splitlines() if x.strip()]
        errors = [x for x in lines if x.startswith("Error: ")]
        if len(errors) != 1 or lines[-1] != errors[0]:
            o.problems.append(f"not one final Error line: {o.err[-300:]!r}")
        elif case.message and case.message not in errors[0]:
            o.problems.append(f"message lacks {case.message!r}: {errors[0][:300]!r}")
    return o


def classify(o: Outcome) -> str:
    for tag in ("traceback", "exit 0", "data loss", "escaped"):
        if any(p.startswith(tag) for p in o.problems):
            return tag
    return "problem" if o.problems else "clean"


if __name__ == "__main__":  # count the outcomes over the whole corpus
    import tempfile
    from collections import Counter

    with tempfile.TemporaryDirectory() as d:
        template = build_template(Path(d) / "template")
        counts: Counter[str] = Counter()
        for i, c in enumerate(all_cases()):
            o = run_case(c, template, Path(d) / f"c{i}")
            shutil.rmtree(Path(d) / f"c{i}", ignore_errors=True)
            counts[classify(o)] += 1
            if o.problems and "-v" in sys.argv:
                print(c.id, "|", "; ".join(o.problems)[:300])
        print(dict(counts), "of", sum(counts.values()))
