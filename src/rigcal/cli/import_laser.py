"""``rigcal import-laser``: a RADLOCC or CSV laser log (and image list) into a sequence folder."""

from __future__ import annotations

from pathlib import Path

import click

from rigcal.cli.options import force_option, json_option, output_option
from rigcal.cli.stamps import laser_offset_option, stamps_option, warn_cut, warn_stamps
from rigcal.cli.types import Real


@click.command("import-laser")
@click.argument("log", type=click.Path(path_type=Path))
@click.option("--images", type=click.Path(path_type=Path), help="Image list: a stamp and a file per line.")
@click.option(
    "--camera", type=click.Path(path_type=Path), help="Camera file to include (any form rigcal reads)."
)
@click.option(
    "--format", "fmt", type=click.Choice(["radlocc", "csv"]),
    help="The log's format [default: csv when it starts with a header naming stamp_s, else radlocc].",
)  # fmt: skip
@click.option(
    "--range-min-m",
    default=0.0,
    show_default=True,
    type=Real(min=0.0),
    help="Shorter: no return.",
)
@click.option(
    "--range-max-m", default=80.0, show_default=True, type=Real(min=0.0, min_open=True),
    help="Longer: no return.",
)  # fmt: skip
@click.option(
    "--no-return-m",
    type=Real(min=0.0, min_open=True),
    help="RADLOCC: the range the scanner writes for no return (a Hokuyo driver writes its "
    "maximum, e.g. 5.0).",
)
@output_option("Sequence folder.", "DIR", file_okay=False)
@stamps_option
@click.option(
    "--odometry",
    type=click.Path(path_type=Path, dir_okay=False),
    help="Wheel odometry: a TUM file of the robot base's poses (same clock as the scans).",
)
@laser_offset_option
@force_option("Replace an existing folder.")
@json_option("Print what was written as JSON on stdout.")
def import_laser(
    log: Path,
    images: Path | None,
    camera: Path | None,
    fmt: str | None,
    range_min_m: float,
    range_max_m: float,
    no_return_m: float | None,
    output: Path,
    stamps: str,
    odometry: Path | None,
    laser_offset: str | None,
    force: bool,
    as_json: bool,
) -> None:
    """Write the scans of LOG (and the images of --images) as a sequence folder.

    LOG is a RADLOCC laser.txt (stamp, angle_min, increment, angle_max, ranges per line;
    nan/inf: no return) or a CSV with columns stamp_s, angle_rad (or angle_deg), range_m,
    one row per beam (docs/formats/sequence.md). The folder feeds rigcal capture. An
    incomplete last line of the log, the image list or the --odometry TUM file (a file
    copied while it was recorded) is left out with a warning (--stamps strict refuses it).

    \b
    Examples:
      rigcal import-laser data/laser.txt --images data/images.txt --camera cam.xml -o seq/
      rigcal import-laser scans.csv -o seq/ --force --json
      rigcal import-laser hokuyo/laser.txt --no-return-m 5.0 -o seq/
      rigcal capture seq/ -o session/ --box-width-m 0.6
    """
    from rigcal.errors import InputError
    from rigcal.io.files import check_folder_writable
    from rigcal.io.wheel_odometry import parse_mounting
    from rigcal.recordings.laser_text import import_laser_text

    mounting = parse_mounting(laser_offset) if laser_offset is not None else None
    check_folder_writable(output, force, [p for p in (log, images, camera, odometry) if p is not None])
    if not range_min_m < range_max_m:
        raise InputError.at(
            None, "--range-min-m", range_min_m, f"a range below --range-max-m {range_max_m:g}"
        )
    s = import_laser_text(
        log,
        output,
        images,
        camera,
        fmt,
        range_min_m,
        range_max_m,
        force=force,
        no_return_m=no_return_m,
        stamps=stamps,
        odometry=odometry,
        laser_offset=mounting,
    )
    warn_cut(s.cut, log)
    warn_cut(s.images_cut, images)
    warn_cut(s.odometry_cut, odometry)
    warn_stamps(s.stamps, "scan stamps")
    warn_stamps(s.image_stamps, "image stamps")
    if as_json:
        import json

        doc = {
            "output": str(output),
            "entry": str(output / "sequence.yaml"),
            "format": s.format,
            "scans": s.scans,
            "images": s.images,
            "camera": str(output / "camera.yaml") if s.camera else None,
        }
        click.echo(json.dumps(doc, indent=1))
        return
    click.echo(
        f"wrote {output}/: {s.scans} scans ({s.format}), {s.images} images"
        + (", camera.yaml" if s.camera else "")
        + (", odometry.tum" if s.odometry else "")
    )
