"""``rigcal pick``: propose the image box ends of a box-target session."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

from rigcal.cli.options import force_option, output_option
from rigcal.cli.types import Real

if TYPE_CHECKING:
    from rigcal.calib.box.autopick import PickRun


@click.command("pick")
@click.argument("picks", type=click.Path(path_type=Path))
@output_option("Picking file to write.", dir_okay=False)
@click.option("--rig", type=click.Path(path_type=Path), help="A rough rig file to predict the ends with.")
@click.option(
    "--sheet",
    type=click.Path(path_type=Path, dir_okay=False),
    help="Contact sheet PNG: every capture's picks.",
)
@click.option(
    "--box-width-m",
    type=Real(min=0.05),
    help="The box side's length, to find it in scans without laser_side [default: the file's box.width_m].",
)
@click.option(
    "--search-px", default=12.0, show_default=True, type=Real(min=2.0, max=200.0),
    help="Half-width of the edge search around each predicted end.",
)  # fmt: skip
@click.option(
    "--edge-span-m", default=0.03, show_default=True, type=Real(min=0.002, max=1.0),
    help="Length of the box's vertical edge averaged, centred on the laser plane (within the box's height).",
)  # fmt: skip
@click.option(
    "--review-below", default=0.5, show_default=True, type=Real(min=0.0, max=1.0),
    help="Mark picks with a lower confidence for review.",
)  # fmt: skip
@force_option("Overwrite the output files.")
@click.option(
    "--json", "as_json", is_flag=True, help="Print the picks, confidences and review reasons as JSON."
)
def pick(
    picks: Path,
    output: Path,
    rig: Path | None,
    sheet: Path | None,
    box_width_m: float | None,
    search_px: float,
    edge_span_m: float,
    review_below: float,
    force: bool,
    as_json: bool,
) -> None:
    """Propose the box ends in every image of the picking file PICKS.

    Captures with image_endpoints_px picked by hand are kept. With at least 3 of them (or a
    rough --rig), every other capture's box ends are predicted through the solve and
    refined to the box's vertical edges; each pick gets a confidence, and doubtful ones
    are marked `review: true` (docs/calibration.md). Check the --sheet by eye, then solve.

    \b
    Examples:
      rigcal pick session/picks.yaml -o session/picks-auto.yaml --sheet sheet.png
      rigcal pick session/picks.yaml --rig rough-rig.yaml --box-width-m 0.6 -o picks2.yaml --force
      rigcal pick session/picks.yaml -o picks-auto.yaml --json | jq '.captures[] | select(.review)'
      rigcal solve session/picks-auto.yaml -o rig.yaml
    """
    from rigcal.calib.box.autopick import PickSettings, auto_pick, pick_file_text
    from rigcal.calib.box.picks import read_pick_draft
    from rigcal.errors import CalibrationError
    from rigcal.io.files import atomic_write_text, check_apart, check_writable
    from rigcal.rigfile import read_rig
    from rigcal.viz.contact_sheet import SheetEntry, write_contact_sheet

    inputs = [picks, *([rig] if rig is not None else [])]
    check_writable(output, force, inputs)
    if sheet is not None:
        check_writable(sheet, force, [*inputs, output])
    draft = read_pick_draft(picks)
    files = [draft.path, draft.camera_path, *(p for c in draft.captures for p in (c.scan_path, c.image_path))]
    check_apart(output, files)
    if sheet is not None:
        check_apart(sheet, files)
    T = read_rig(rig).T_cam_laser if rig is not None else None
    settings = PickSettings(
        search_px=search_px, edge_span_m=edge_span_m, review_below=review_below, box_width_m=box_width_m
    )
    run = auto_pick(draft, settings, T)
    if all(p.image_endpoints_px is None for p in run.picks):
        raise CalibrationError(
            f"{picks}: no capture could be picked ({len(run.picks)} captures): with the pose from "
            f"{run.seeded_from} no box end lands in its image (the box behind the camera or outside "
            "the image); check --rig, or pick 3 or more captures by hand"
        )
    text = pick_file_text(run, output)
    sheet_was_there = sheet is not None and (sheet.exists() or sheet.is_symlink())
    if sheet is not None:
        entries = [
            SheetEntry(
                p.name,
                c.image_path,
                p.image_endpoints_px,
                p.predicted_px,
                "manual" if p.source == "manual" else f"auto, confidence {p.confidence:.2f}",
                p.review,
                p.source == "manual",
                p.reasons,
            )
            for p, c in zip(run.picks, draft.captures, strict=True)
        ]
        write_contact_sheet(sheet, entries, force=force)
    try:
        atomic_write_text(output, text, force=force)
    except BaseException:
        if sheet is not None and not sheet_was_there:  # no sheet of a run that wrote no picks
            sheet.unlink(missing_ok=True)
        raise
    auto = [p for p in run.picks if p.source == "auto" and p.image_endpoints_px is not None]
    review = [p for p in run.picks if p.review]
    for p in review:
        click.echo(f"review {p.name}: {'; '.join(p.reasons)}", err=True)
    unpicked = [p.name for p in run.picks if p.image_endpoints_px is None]
    summary = (
        f"{len(auto)} captures picked automatically (pose from {run.seeded_from}), {len(review)} to review"
    )
    if run.final is not None:
        s = run.final
        summary += f"; solve over all picks: {int(s.inliers.sum())}/{len(s.inliers)} ends inliers"
    if as_json:
        click.echo(json.dumps(pick_doc(run, output, sheet), indent=1))
    else:
        click.echo(summary)
    if run.seeded_from == "rig" and not any(p.source == "manual" for p in run.picks):
        click.echo(
            "note: with no capture picked by hand, the picks' height on the box is the rig's own "
            "(the images cannot show the laser plane); pick 3 or more by hand to measure it",
            err=True,
        )
    if unpicked and not as_json:
        click.echo(f"not picked (pick by hand or remove): {', '.join(unpicked)}")
    click.echo(f"wrote {output}" + (f" and {sheet}" if sheet else ""), err=True)


def pick_doc(run: PickRun, output: Path, sheet: Path | None) -> dict[str, Any]:
    """What ``--json`` prints: the files written, where the pose came from, the solve over
    all picks, and per capture its ends (pixels, unrounded), source, confidence, review
    flag and reasons (null ends: not picked)."""
    final = None
    if run.final is not None:
        final = {"inlier_ends": int(run.final.inliers.sum()), "ends": len(run.final.inliers)}
    return {
        "output": str(output),
        "sheet": None if sheet is None else str(sheet),
        "seeded_from": run.seeded_from,
        "solve": final,
        "captures": [
            {
                "name": p.name,
                "source": p.source,
                "image_endpoints_px": None
                if p.image_endpoints_px is None
                else [[float(x) for x in e] for e in p.image_endpoints_px],
                "confidence": float(p.confidence),
                "review": bool(p.review),
                "reasons": list(p.reasons),
            }
            for p in run.picks
        ],
    }
