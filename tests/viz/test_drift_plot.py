"""The drift history chart: three panels, ok checks green and drifted ones red, noise
bands, real ticks and a legend; PNG, SVG and PDF."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from rigcal.errors import InputError, OutputError
from rigcal.viz.charts import DRIFTED, OK
from rigcal.viz.drift_plot import drift_figure, write_drift_plot


def record(
    verdict: str, rms_px: float | None, rotation_deg: float | None = None, translation_mm: float = 0.0
):
    pose = None
    if rotation_deg is not None:
        pose = {
            "rotation_deg": rotation_deg,
            "translation_mm": translation_mm,
            "sigma_rotation_deg": [0.05, 0.07, 0.05],
            "sigma_translation_mm": [3.0, 2.0, 3.0],
            "p_value": 0.5,
        }
    return {
        "checked_utc": "2026-11-23T08:12:40Z",
        "verdict": verdict,
        "residual": {"rms_px": rms_px},
        "pose": pose,
    }


# ok with a pose, drifted with a pose, ok without a pose, drifted without a pose.
RECORDS = [
    record("ok", 1.8, rotation_deg=0.1, translation_mm=4.0),
    record("drifted", 4.2, rotation_deg=0.6, translation_mm=15.0),
    record("ok", 2.1),
    record("drifted", 3.5),
]


def points(ax, colour: str) -> dict[float, float]:
    """check number -> value of the markers of one colour in a panel."""
    out = {}
    for line in ax.get_lines():
        if line.get_color() == colour and line.get_marker() == "o" and len(line.get_xdata()):
            out.update(zip(map(float, line.get_xdata()), map(float, line.get_ydata()), strict=True))
    return out


def bands(ax) -> dict[float, float]:
    return {round(p.get_x() + p.get_width() / 2, 6): p.get_height() for p in ax.patches}


@pytest.fixture(scope="module")
def axes():
    return drift_figure(RECORDS).axes


def test_three_labelled_panels_with_real_ticks_and_a_legend(axes):
    assert [ax.get_title() for ax in axes] == [
        "rotation change",
        "translation change",
        "RMS reprojection under the stored rig",
    ]
    assert [ax.get_ylabel() for ax in axes] == ["deg", "mm", "px"]
    for ax in axes:
        assert len(ax.get_yticks()) >= 3  # more than 0 and the maximum
    assert [t.get_text() for t in axes[0].get_legend().get_texts()] == [
        "ok",
        "drifted",
        "targetless (a drive)",
        "cannot tell",
        "2 sigma (noise alone)",
    ]
    assert axes[-1].get_xticklabels()[0].get_text() == "#1 2026-11-23"


def test_ok_checks_are_green_and_drifted_ones_red_at_their_values(axes):
    assert points(axes[0], OK) == {1.0: 0.1}
    assert points(axes[0], DRIFTED) == {2.0: 0.6}
    assert points(axes[1], DRIFTED) == {2.0: 15.0}
    assert points(axes[2], OK) == {1.0: 1.8, 3.0: 2.1}
    assert points(axes[2], DRIFTED) == {2.0: 4.2, 4.0: 3.5}


def test_noise_bands_only_where_there_is_a_pose(axes):
    b = bands(axes[0])
    assert set(b) == {1.0, 2.0}
    assert b[1.0] == pytest.approx(2 * np.linalg.norm([0.05, 0.07, 0.05]))
    assert bands(axes[2]) == {}


def test_check_without_rms_has_no_residual_point():
    ax = drift_figure([record("ok", 1.5, rotation_deg=0.1), record("drifted", None, rotation_deg=1.2)]).axes
    assert points(ax[2], DRIFTED) == {}
    assert points(ax[0], DRIFTED) == {2.0: 1.2}


def test_one_check_and_no_checks_draw():
    assert points(drift_figure(RECORDS[:1]).axes[0], OK) == {1.0: 0.1}
    assert len(drift_figure([]).axes) == 3


@pytest.mark.parametrize(("suffix", "magic"), [(".png", b"\x89PNG"), (".svg", b"<?xml"), (".pdf", b"%PDF")])
def test_written_as_png_svg_or_pdf(suffix, magic, tmp_path):
    path = write_drift_plot(tmp_path / f"drift{suffix}", RECORDS)
    assert path.read_bytes()[:5].startswith(magic)
    if suffix == ".png":
        assert cv2.imread(str(path)).shape == (750, 900, 3)
    # The same records give the same bytes.
    again = write_drift_plot(tmp_path / f"again{suffix}", RECORDS)
    assert again.read_bytes() == path.read_bytes()


def test_refuses_to_overwrite_without_force_and_unknown_formats(tmp_path):
    path = tmp_path / "drift.png"
    path.write_bytes(b"keep me")
    with pytest.raises(OutputError, match="exists"):
        write_drift_plot(path, RECORDS)
    assert path.read_bytes() == b"keep me"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["drift.png"]
    write_drift_plot(path, RECORDS, force=True)
    assert path.read_bytes()[:4] == b"\x89PNG"
    with pytest.raises(InputError, match=r"chart file: got '.*drift\.jpg'; expected a name ending in \.png"):
        write_drift_plot(tmp_path / "drift.jpg", RECORDS)


def test_drives_are_diamonds_and_cannot_tell_a_grey_cross():
    drive = {
        "schema_version": 2,
        "checked_utc": "2026-11-26T08:00:00Z",
        "kind": "targetless",
        "verdict": "drifted",
        "residual": None,
        "pose": None,
        "targetless": {
            "rotation_deg": 0.31,
            "translation_mm": 4.0,
            "sigma_rotation_deg": [0.05, 0.05, 0.05],
            "sigma_translation_mm": [3.0, 3.0, 0.0],
        },
    }
    blind = drive | {"verdict": "cannot_tell", "targetless": {"duration_s": 5.0}}
    ax = drift_figure([*RECORDS, drive, blind]).axes[0]
    diamonds = [ln for ln in ax.get_lines() if ln.get_marker() == "D"]
    assert [list(ln.get_ydata()) for ln in diamonds] == [[0.31]]
    crosses = [ln for ln in ax.get_lines() if ln.get_marker() == "x"]
    assert [list(ln.get_xdata()) for ln in crosses] == [[len(RECORDS) + 2]]
    assert bands(ax)[len(RECORDS) + 1] == pytest.approx(2 * np.linalg.norm([0.05, 0.05, 0.05]))
