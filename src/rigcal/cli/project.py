"""``rigcal project``: a scan drawn onto its image with a rig's calibration (Fig. 2a)."""

from __future__ import annotations

import json
from pathlib import Path

import click

from rigcal.cli.options import force_option, json_option, output_option


@click.command("project")
@click.argument("rig", type=click.Path(path_type=Path))
@click.argument("scan", type=click.Path(path_type=Path))
@click.argument("image", type=click.Path(path_type=Path))
@output_option("Overlay PNG to write.")
@force_option("Overwrite an existing PNG.")
@json_option("Print the projected pixels as JSON on stdout.")
def project(rig: Path, scan: Path, image: Path, output: Path, force: bool, as_json: bool) -> None:
    """Project SCAN into IMAGE with RIG's T_cam_laser and camera model; write an overlay PNG.

    A quick visual check of a calibration: the laser points should sit on the surfaces
    they hit (walls at the scanner's height, the box face).

    \b
    Examples:
      rigcal project rig.yaml examples/box-session/scans/cap00.yaml \\
          examples/box-session/images/cap00.png -o overlay.png
      rigcal project rig.yaml scan.yaml image.png -o overlay.png --force --json
    """
    from rigcal.errors import InputError
    from rigcal.io.files import check_writable
    from rigcal.io.images import read_image
    from rigcal.rigfile import read_rig
    from rigcal.scan import read_scan
    from rigcal.viz.overlay import draw_overlay, project_scan, write_png

    check_writable(output, force, [rig, scan, image])
    r = read_rig(rig)
    s = read_scan(scan)
    img = read_image(image)
    h, w = img.shape[:2]
    if (w, h) != (r.camera.width_px, r.camera.height_px):
        raise InputError.at(
            image,
            "size",
            f"{w}x{h}",
            f"{r.camera.width_px}x{r.camera.height_px} as the rig's camera model says",
        )
    write_png(output, draw_overlay(img, r.camera, r.T_cam_laser, s), force=force)
    q, inside = project_scan(r.camera, r.T_cam_laser, s)
    if as_json:
        click.echo(
            json.dumps(
                {
                    "beams_in_image": int(inside.sum()),
                    "beams": len(q),
                    "pixels": [
                        [int(i), round(float(u), 2), round(float(v), 2)]
                        for i, (u, v) in enumerate(q)
                        if inside[i]
                    ],
                }
            )
        )
    click.echo(f"{int(inside.sum())} of {len(q)} beams land in the image; wrote {output}", err=True)
