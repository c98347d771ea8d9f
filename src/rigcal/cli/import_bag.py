"""``rigcal import-bag``: a ROS 1 or ROS 2 bag into a sequence folder."""

from __future__ import annotations

import json
from pathlib import Path

import click

from rigcal.cli.options import force_option, json_option, output_option
from rigcal.cli.stamps import laser_offset_option


@click.command("import-bag")
@click.argument("bags", nargs=-1, required=True, type=click.Path(path_type=Path), metavar="BAG...")
@click.option("--scan-topic", help="sensor_msgs/LaserScan topic [default: the bag's only one].")
@click.option(
    "--image-topic", help="sensor_msgs/Image or CompressedImage topic [default: the bag's only one]."
)
@click.option("--camera-info-topic", help="sensor_msgs/CameraInfo topic: also write camera.yaml.")
@click.option(
    "--odometry-topic",
    help="nav_msgs/Odometry topic, or a tf topic (/tf) with the odom -> base_link transform: keep "
    "it as the wheel odometry (the laser's mounting from --laser-offset or the bag's /tf_static).",
)
@click.option(
    "--odometry-frames",
    default="odom,base_link",
    show_default=True,
    metavar="PARENT,CHILD",
    help="With a tf --odometry-topic: the transform that is the odometry.",
)
@click.option(
    "--imu-topic",
    help="sensor_msgs/Imu topic: keep its angular velocity, rotated into the scans' frame (the same "
    "frame or linked by the bag's /tf_static), as the gyroscope (gyro.csv); none: no IMU.  "
    "[default: the bag's only Imu topic, if it has one]",
)
@laser_offset_option
@click.option(
    "--stamps",
    type=click.Choice(["repair", "strict"]),
    default="repair",
    show_default=True,
    help="repair: sort messages out of time order and drop repeated stamps (counted); strict: refuse them.",
)
@output_option("Sequence folder.", "DIR")
@force_option("Replace an existing folder.")
@json_option("Print what was written as JSON on stdout.")
def import_bag(
    bags: tuple[Path, ...],
    scan_topic: str | None,
    image_topic: str | None,
    camera_info_topic: str | None,
    odometry_topic: str | None,
    odometry_frames: str,
    imu_topic: str | None,
    laser_offset: str | None,
    stamps: str,
    output: Path,
    force: bool,
    as_json: bool,
) -> None:
    """Write the scans, images (and camera) of BAG as a sequence folder (docs/formats/sequence.md).

    Works on ROS 1 (.bag) and ROS 2 (folder with metadata.yaml) bags through the rosbags
    package; no ROS installation is needed. A bag recorded in parts (rosbag record --split)
    is given as all its files, read as one bag. Without --scan-topic (--image-topic) the bag's
    only LaserScan (image) topic is read; a bag with several names them.

    \b
    Examples:
      rigcal import-bag run1.bag --scan-topic /scan --image-topic /camera/image_raw -o run1/
      rigcal import-bag run2/ --scan-topic /scan --image-topic /cam/image/compressed \\
          --camera-info-topic /cam/camera_info -o run2-seq/ --force
      rigcal import-bag run3/ --scan-topic /scan --image-topic /cam/image --odometry-topic /tf -o run3/
      rigcal import-bag run4_0.bag run4_1.bag run4_2.bag -o run4/
      rigcal import-bag run5/ --odometry-topic /odom --imu-topic /imu/data -o run5/
    """
    from rigcal.errors import InputError
    from rigcal.io.files import check_folder_writable
    from rigcal.io.wheel_odometry import parse_mounting
    from rigcal.recordings.bag import import_bag as run

    mounting = parse_mounting(laser_offset) if laser_offset is not None else None
    frames = tuple(f.strip().lstrip("/") for f in odometry_frames.split(","))
    if len(frames) != 2 or not all(frames):
        raise InputError.at(None, "--odometry-frames", odometry_frames, "PARENT,CHILD (e.g. odom,base_link)")
    bag, more = bags[0], bags[1:]
    check_folder_writable(output, force, list(bags))
    from rigcal.cli.progress import Progress

    with Progress("msg") as bars:
        s = run(
            bag,
            output,
            scan_topic,
            image_topic,
            camera_info_topic,
            force=force,
            progress=lambda done, total: bars("reading", done, total),
            stamps=stamps,
            odometry_topic=odometry_topic,
            laser_offset=mounting,
            odometry_frames=(frames[0], frames[1]),
            more=more,
            imu_topic=imu_topic,
        )
    if as_json:
        doc = {
            "output": str(output),
            "scans": s.scans,
            "images": s.images,
            "camera_yaml": s.camera,
            "reordered": dict(s.reordered),
            "duplicates_dropped": dict(s.duplicates),
            "odometry_poses": s.odometry,
            "gyro_samples": s.gyro,
            **s.record(),
        }
        click.echo(json.dumps(doc, indent=1))
        return
    notes = []
    for what in ("scans", "images"):
        if s.reordered.get(what):
            notes.append(f"{s.reordered[what]} {what} out of order (sorted)")
        if s.duplicates.get(what):
            notes.append(f"{s.duplicates[what]} {what} with a repeated stamp (dropped)")
    notes += s.notes()
    click.echo(
        f"wrote {output}/: {s.scans} scans, {s.images} images"
        + (", camera.yaml" if s.camera else "")
        + (f", odometry.tum ({s.odometry} poses)" if s.odometry else "")
        + (f", gyro.csv ({s.gyro} samples)" if s.gyro else "")
        + ("; " + "; ".join(notes) if notes else "")
    )
