"""The marker target: targets files (round trip, every error path) and the printed pages."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest
import yaml

from rigcal.cli.main import main
from rigcal.errors import InputError
from rigcal.targets.marker import default_target, face_image, parse_targets, read_targets, targets_text
from rigcal.targets.marker_print import sheet_image, write_print


def _doc() -> dict:
    return yaml.safe_load(targets_text(default_target()))


def test_round_trip(tmp_path):
    t = default_target()
    p = tmp_path / "t.yaml"
    p.write_text(targets_text(t))
    back = read_targets(p)
    assert back.faces == t.faces
    assert (back.angle_deg, back.edge_m, back.dictionary, back.corner) == (
        90.0,
        0.6,
        "DICT_4X4_50",
        "concave",
    )


def test_faces_meet_on_the_edge():
    t = default_target()
    for corner in ("concave", "convex"):
        from dataclasses import replace

        tt = replace(t, corner=corner)
        A, B = tt.T_target_face(0), tt.T_target_face(1)
        # The left face's right side and the right face's left side are the common edge.
        a_edge = A[:3, :3] @ np.array([t.faces[0].width_m, 0.3, 0.0]) + A[:3, 3]
        b_edge = B[:3, :3] @ np.array([0.0, 0.3, 0.0]) + B[:3, 3]
        assert np.allclose(a_edge, [0.0, 0.3, 0.0])
        assert np.allclose(b_edge, [0.0, 0.3, 0.0])
        cos = float(A[:3, 2] @ B[:3, 2])
        assert cos == pytest.approx(-np.cos(np.radians(t.angle_deg)))
        # Concave: the faces' outer sides are nearer the viewer (-z) than the edge.
        outer = A[:3, 3][2]
        assert (outer < 0) == (corner == "concave")


@pytest.mark.parametrize(
    ("edit", "match"),
    [
        (lambda d: d.pop("edge_m"), r"edge_m: missing"),
        (lambda d: d.update(edge_m=0), r"edge_m: got 0; expected a finite number > 0"),
        (lambda d: d["faces"][0].update(width_m=-0.5), r"faces\[0\]\.width_m: got -0.5"),
        (lambda d: d["faces"][1].update(square_m=0), r"faces\[1\]\.square_m: got 0"),
        (lambda d: d.update(dictionary="DICT_9X9_50"), r"dictionary: got 'DICT_9X9_50'; expected one of"),
        (
            lambda d: d["faces"][1].update(first_id=5),
            r"faces\[1\]\.ids: got \[5, 6, 7, 8, 9\]; .*duplicate ids",
        ),
        (lambda d: d["faces"][0].pop("first_id") or d["faces"][0].update(ids=[1] * 10), r"duplicate ids"),
        (lambda d: d["faces"][1].update(first_id=45), r"faces\[1\]\.first_id: got 45; expected at most 40"),
        (lambda d: d.update(angle_deg=180), r"angle_deg: got 180; expected the angle between the faces"),
        (lambda d: d.update(angle_deg=5), r"angle_deg: got 5"),
        (lambda d: d["faces"].pop(), r"faces: got '1 faces'; expected a list of two faces"),
        (
            lambda d: d["faces"][0].update(square_m=0.2),
            r"faces\[0\]: got 'pattern 0.8 x 1 m.*inside its face",
        ),
        (
            lambda d: d["faces"][0].update(marker_m=0.12),
            r"faces\[0\]\.marker_m: got 0.12; expected a marker side",
        ),
        (lambda d: d.update(corner="flat"), r"corner: got 'flat'"),
        (lambda d: d.update(schema_version=3), r"schema_version: got 3; expected 1 or 2"),
        (lambda d: d.update(kind="marker"), r"kind: got 'marker'; expected no kind in schema_version 1"),
        (lambda d: d.update(schema_version=2, kind="board"), r"kind: got 'board'; expected marker"),
        (lambda d: d.update(colour="red"), r"colour: got 'red'; expected no such key"),
        (lambda d: d["faces"][1].update(name="left"), r"faces\[1\]\.name: got 'left'"),
        (lambda d: d["faces"][0].update(squares=[4]), r"faces\[0\]\.squares: got \[4\]"),
    ],
)
def test_errors_name_file_key_and_value(tmp_path, edit, match):
    d = _doc()
    edit(d)
    p = tmp_path / "bad.yaml"
    p.write_text(yaml.safe_dump(d))
    with pytest.raises(InputError, match=match) as e:
        read_targets(p)
    assert str(p) in str(e.value)
    assert "\n" not in str(e.value)


def test_version_2_says_its_kind():
    d = _doc()
    d.update(schema_version=2, kind="marker")
    assert parse_targets(d, None) == parse_targets(_doc(), None)


def test_explicit_ids():
    d = _doc()
    d["faces"][0].pop("first_id")
    d["faces"][0]["ids"] = [30, 31, 32, 33, 34, 35, 36, 37, 38, 39]
    t = parse_targets(d, None)
    assert t.faces[0].ids[0] == 30
    assert t.all_ids == set(range(10, 20)) | set(range(30, 40))


def test_face_image_is_the_pattern_at_its_offset():
    t = default_target()
    img = face_image(t, 0, 2000.0)
    assert img.shape == (1200, 1000)
    f = t.faces[0]
    x0, y0 = round(f.offset_m[0] * 2000), round(f.offset_m[1] * 2000)
    assert (img[:y0] == 255).all()
    assert (img[:, :x0] == 255).all()
    # The pattern's first square (top-left) is black in OpenCV's ChArUco layout.
    assert img[y0 + 10, x0 + 10] == 0


def test_sheet_is_true_scale_with_a_100_mm_bar(tmp_path):
    t = default_target()
    dpi = 100.0
    page = sheet_image(t, 1, dpi)
    ppm = dpi / 0.0254
    assert page.shape[1] == round(0.5 * ppm)
    assert page.shape[0] > round(0.6 * ppm)
    strip = page[round(0.6 * ppm) :]
    # The bar: the longest run of dark pixels in a row of the strip is 100 mm.
    runs = []
    for row in strip:
        dark = np.concatenate([[0], (row < 60).astype(int), [0]])
        edges = np.flatnonzero(np.diff(dark))
        runs.append(int(np.max(edges[1::2] - edges[::2])) if len(edges) else 0)
    assert max(runs) == pytest.approx(0.1 * ppm, abs=2)
    files = write_print(t, tmp_path / "print", dpi=dpi)
    names = sorted(f.name for f in files)
    assert names == ["face-left.pdf", "face-left.png", "face-right.pdf", "face-right.png", "targets.yaml"]
    from PIL import Image

    im = Image.open(io.BytesIO((tmp_path / "print" / "face-left.png").read_bytes()))
    assert im.size[0] == round(0.5 * ppm)
    assert im.info["dpi"][0] == pytest.approx(dpi, abs=0.5)
    pdf = (tmp_path / "print" / "face-left.pdf").read_bytes()
    # The PDF page is the sheet's true size in points (1/72 inch).
    box = pdf.split(b"/MediaBox")[1].split(b"]")[0].strip(b" [").split()
    assert float(box[2]) == pytest.approx(0.5 / 0.0254 * 72, abs=1.0)
    assert read_targets(tmp_path / "print" / "targets.yaml").faces == t.faces


def test_cli_new_and_print(tmp_path):
    out = tmp_path / "t.yaml"
    assert main(["targets", "new", "-o", str(out)]) == 0
    assert main(["targets", "new", "-o", str(out)]) == 5  # exists, no --force
    assert main(["targets", "print", str(out), "-o", str(tmp_path / "p"), "--dpi", "60"]) == 0
    assert (tmp_path / "p" / "face-right.pdf").is_file()
    bad = tmp_path / "bad.yaml"
    bad.write_text(out.read_text().replace("DICT_4X4_50", "DICT_NOPE"))
    assert main(["targets", "print", str(bad), "-o", str(tmp_path / "q")]) == 3
    assert not Path(tmp_path / "q").exists()
