"""`rigcal simulate world --image-format`: compact images that read back as rigcal reads
them, and the size said before writing."""

from __future__ import annotations

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from rigcal.cli.main import cli
from rigcal.io.images import read_grey
from rigcal.recordings.sequence import read_sequence

ARGS = [
    "simulate",
    "world",
    "--world",
    "cubicle-loop",
    "--duration-s",
    "1",
    "--camera-rate-hz",
    "3",
    "--seed",
    "4",
]


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    root = tmp_path_factory.mktemp("fmt")
    out = {}
    for fmt in ("png", "png-grey", "jpg"):
        res = CliRunner().invoke(cli, [*ARGS, "-o", str(root / fmt), "--image-format", fmt])
        assert res.exit_code == 0, res.output
        out[fmt] = (root / fmt, res.stderr)
    return out


def _images(folder):
    seq = read_sequence(folder)
    return [folder / "images" / f for f in seq.image_files], seq


def test_png_grey_reads_back_as_the_colour_png_does(written):
    colour, _ = _images(written["png"][0])
    grey, seq = _images(written["png-grey"][0])
    assert len(grey) == len(colour) == 3
    for a, b in zip(colour, grey, strict=True):
        assert b.suffix == ".png"
        np.testing.assert_array_equal(read_grey(a), read_grey(b))  # bit for bit what rigcal uses
        assert b.stat().st_size < 0.5 * a.stat().st_size
    assert seq.source["image_format"] == "png-grey"
    assert "image_format" not in yaml.safe_load((written["png"][0] / "sequence.yaml").read_text())["source"]


def test_jpg_is_small_and_close(written):
    colour, _ = _images(written["png"][0])
    jpg, _ = _images(written["jpg"][0])
    for a, b in zip(colour, jpg, strict=True):
        assert b.suffix == ".jpg"
        assert b.stat().st_size < 0.35 * a.stat().st_size
        diff = read_grey(a).astype(float) - read_grey(b).astype(float)
        assert np.sqrt(np.mean(diff**2)) < 3.0


def test_the_size_is_said_before_writing(written):
    for fmt, (folder, err) in written.items():
        files, _ = _images(folder)
        line = next(x for x in err.splitlines() if x.startswith("writing "))
        assert line.startswith("writing 3 images of about ")
        assert f"({fmt})" in line
        said_mb = float(line.split("about ")[2].split(" MB")[0])
        total_mb = sum(f.stat().st_size for f in files) / 1e6
        assert said_mb == pytest.approx(total_mb, abs=0.5 + 0.2 * total_mb)
        assert ("png-grey writes a third of it" in line) == (fmt == "png")


def test_unknown_format_is_a_usage_error(tmp_path):
    res = CliRunner().invoke(cli, [*ARGS, "-o", str(tmp_path / "x"), "--image-format", "gif"])
    assert res.exit_code == 2
    assert not (tmp_path / "x").exists()
