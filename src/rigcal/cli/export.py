"""``rigcal export``: a rig in the formats other tools read."""

from __future__ import annotations

import json
from pathlib import Path

import click

from rigcal.cli.options import force_option, output_option


def _ros_name(ctx: click.Context, param: click.Parameter, value: str | None) -> str | None:
    """A frame (or, for --rostopic, topic) name checked against the ROS name rules: a bad
    one is a usage error (exit 2) before any file is read."""
    from rigcal.errors import InputError
    from rigcal.io.exports import ros_name

    if value is None:
        return None
    try:
        return ros_name(value, f"--{param.name}".replace("_", "-"), topic=param.name == "rostopic")
    except InputError as exc:
        raise click.BadParameter(str(exc).split(": ", 1)[1]) from None


@click.command("export")
@click.argument("rig", type=click.Path(path_type=Path))
@click.option(
    "--format",
    "fmt",
    required=True,
    type=click.Choice(["ros", "urdf", "xacro", "kalibr", "mrcal"]),
    help="ros: static_transform_publisher commands and launch lines; urdf: a <robot> with both "
    "links and the fixed joint; xacro: a macro adding the child link and joint to your robot; "
    "kalibr: camchain-imucam YAML, the laser in the IMU's place; mrcal: a .cameramodel with "
    "the laser as reference frame.",
)
@click.option(
    "--parent",
    default="laser",
    show_default=True,
    type=click.Choice(["laser", "camera"]),
    help="Parent sensor of the ros, urdf and xacro transforms (the child is the other sensor).",
)
@click.option(
    "--parent-frame",
    callback=_ros_name,
    help="Name of the parent frame (default: laser, camera_optical_frame or camera_link); a ROS "
    "name: letters, digits and '_', tokens joined by '/'.",
)
@click.option(
    "--child-frame", callback=_ros_name, help="Name of the child frame (default as --parent-frame)."
)
@click.option(
    "--camera-link",
    is_flag=True,
    help="Attach to the camera's body frame (camera_link: x forward, y left, z up) instead of "
    "its optical frame, so that the camera driver's camera_link -> camera_optical_frame "
    "transform stays the optical frame's only parent.",
)
@click.option(
    "--rostopic",
    default="/camera/image_raw",
    show_default=True,
    callback=_ros_name,
    help="The camera's image topic, written into the Kalibr camchain.",
)
@output_option("Write to this file instead of stdout.", required=False)
@force_option("Overwrite an existing output file.")
@click.option(
    "--json",
    "as_json",
    is_flag=True,
    help="Print the transform written, the output file (or, without -o, the export's text) as JSON.",
)
def export(
    rig: Path,
    fmt: str,
    parent: str,
    parent_frame: str | None,
    child_frame: str | None,
    camera_link: bool,
    rostopic: str,
    output: Path | None,
    force: bool,
    as_json: bool,
) -> None:
    """Write the calibration in RIG for ROS, URDF, xacro, Kalibr or mrcal.

    Every export states its transform's direction in a comment: a ROS or URDF transform from
    a parent to a child is the child's pose in the parent, so the default (parent laser,
    child camera_optical_frame) is T_laser_cam, the inverse of the rig file's T_cam_laser.

    \b
    Examples:
      rigcal export rig.yaml --format ros
      rigcal export rig.yaml --format ros --camera-link --parent-frame base_laser
      rigcal export rig.yaml --format urdf -o rig.urdf
      rigcal export rig.yaml --format xacro --parent camera -o rig.xacro
      rigcal export rig.yaml --format kalibr --rostopic /cam0/image_raw -o camchain.yaml
      rigcal export rig.yaml --format mrcal -o camera.cameramodel --force
    """
    from rigcal.errors import InputError
    from rigcal.io.exports import Frames, export_rig, transform_between
    from rigcal.io.files import atomic_write_text, check_writable
    from rigcal.rigfile import read_rig

    if output is not None:
        check_writable(output, force, [rig])
    try:
        frames = Frames(parent, camera_link, parent_frame, child_frame)
    except InputError as exc:  # the same name for both frames
        raise click.UsageError(f"--child-frame: {str(exc).split(': ', 1)[1]}") from None
    the_rig = read_rig(rig)
    text = export_rig(the_rig, fmt, frames, rostopic, source=rig)
    if output is not None:
        atomic_write_text(output, text, force=force)
    if as_json:
        if fmt in ("ros", "urdf", "xacro"):
            T, _, _ = transform_between(the_rig, parent, camera_link)
            pf, cf = frames.names()
        else:  # kalibr and mrcal hold T_cam_laser
            T, pf, cf = the_rig.T_cam_laser, "camera_optical_frame", "laser"
        doc = {
            "output": None if output is None else str(output),
            "format": fmt,
            "parent_frame": pf,
            "child_frame": cf,
            "T_parent_child": [[float(x) for x in row] for row in T],
        }
        if output is None:
            doc["text"] = text
        click.echo(json.dumps(doc, indent=1))
    elif output is None:
        click.echo(text, nl=False)
    else:
        click.echo(f"wrote {output}", err=True)
