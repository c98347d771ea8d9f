"""An image list of a 12-bit camera's 16-bit PNGs: `import-laser` stores them as 8 bits
by the rule `import-bag` applies (every frame shifted by the same bits), so that the
sequence's image methods read them; the shift is recorded in sequence.yaml."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from test_laser_text import radlocc  # noqa: F401  (the fixture)

from rigcal.cli.main import main
from rigcal.recordings.sequence import read_sequence


def test_sixteen_bit_frames_of_an_image_list_are_stored_as_8_bits(radlocc, tmp_path):  # noqa: F811
    names = sorted(radlocc.glob("image_*.png"))
    originals = []
    for k, p in enumerate(names):
        g = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE).astype(np.uint16)
        wide = g * 16 if k % 2 else g * 4  # 12-bit levels, every other frame darker
        originals.append(wide)
        cv2.imwrite(str(p), wide)
    argv = ["-q", "import-laser", str(radlocc / "laser.txt"), "--images", str(radlocc / "images.txt"),
            "--camera", str(radlocc / "camera.yaml"), "-o", str(tmp_path / "seq")]  # fmt: skip
    assert main(argv) == 0
    seq = read_sequence(tmp_path / "seq")
    top = max(int(w.max()) for w in originals)
    shift = top.bit_length() - 8
    assert seq.source["images_16_bit"] == {"frames": len(names), "max_level": top, "shift_bits": shift}
    for f, wide in zip(seq.image_files, originals, strict=True):
        got = cv2.imread(str(tmp_path / "seq" / "images" / f), cv2.IMREAD_UNCHANGED)
        np.testing.assert_array_equal(got, (wide >> shift).astype(np.uint8))


@pytest.mark.parametrize("ext", [".tif", ".pgm"])
def test_sixteen_bit_tiffs_and_pgms_of_an_image_list_are_stored_as_8_bit_pngs(radlocc, tmp_path, ext):  # noqa: F811
    """Other tools' 16-bit frames (TIFF, PGM) by the same rule as 16-bit PNGs, stored as
    8-bit PNGs; their 8-bit siblings as they are."""
    names = sorted(radlocc.glob("image_*.png"))
    originals = []
    for p in names:
        wide = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE).astype(np.uint16) * 16  # 12-bit levels
        originals.append(wide)
        assert cv2.imwrite(str(p.with_suffix(ext)), wide)
        p.unlink()
    listed = radlocc / "images.txt"
    listed.write_text(listed.read_text().replace(".png", ext))
    argv = ["-q", "import-laser", str(radlocc / "laser.txt"), "--images", str(radlocc / "images.txt"),
            "--camera", str(radlocc / "camera.yaml"), "-o", str(tmp_path / "seq")]  # fmt: skip
    assert main(argv) == 0
    seq = read_sequence(tmp_path / "seq")
    top = max(int(w.max()) for w in originals)
    assert seq.source["images_16_bit"] == {"frames": len(names), "max_level": top, "shift_bits": 4}
    assert all(f.endswith(".png") for f in seq.image_files)
    for f, wide in zip(seq.image_files, originals, strict=True):
        got = cv2.imread(str(tmp_path / "seq" / "images" / f), cv2.IMREAD_UNCHANGED)
        np.testing.assert_array_equal(got, (wide >> 4).astype(np.uint8))
