"""``rigcal export``: a rig in the formats other tools read."""

from __future__ import annotations

from pathlib import Path

import click


@click.command("export")
@click.argument("rig", type=click.Path(path_type=Path))
@click.option(
    "--format",
    "fmt",
    required=True,
    type=click.Choice(["ros", "urdf", "kalibr", "mrcal"]),
    help="ros: static_transform_publisher commands and launch lines; urdf: a fixed joint; "
    "kalibr: camchain-style YAML; mrcal: a .cameramodel with the laser as reference frame.",
)
@click.option(
    "--parent",
    default="laser",
    show_default=True,
    type=click.Choice(["laser", "camera"]),
    help="Parent frame of the ros and urdf transforms (the child is the other sensor).",
)
@click.option("-o", "--output", type=click.Path(path_type=Path), help="Write to this file instead of stdout.")
@click.option("--force", is_flag=True, help="Overwrite an existing output file.")
def export(rig: Path, fmt: str, parent: str, output: Path | None, force: bool) -> None:
    """Write the calibration in RIG for ROS, URDF, Kalibr or mrcal.

    Every export states its transform's direction in a comment: a ROS or URDF transform from
    a parent to a child is the child's pose in the parent, so the default (parent laser,
    child camera_optical_frame) is T_laser_cam, the inverse of the rig file's T_cam_laser.

    \b
    Examples:
      rigcal export rig.yaml --format ros
      rigcal export rig.yaml --format urdf --parent camera
      rigcal export rig.yaml --format kalibr -o camchain.yaml
      rigcal export rig.yaml --format mrcal -o camera.cameramodel --force
    """
    from rigcal.io.exports import export_rig
    from rigcal.io.files import atomic_write_text, check_writable
    from rigcal.rigfile import read_rig

    if output is not None:
        check_writable(output, force, [rig])
    text = export_rig(read_rig(rig), fmt, parent)
    if output is None:
        click.echo(text, nl=False)
    else:
        atomic_write_text(output, text, force=force)
        click.echo(f"wrote {output}", err=True)
