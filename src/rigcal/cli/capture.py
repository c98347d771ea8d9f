"""``rigcal capture``: a recording (bag or sequence folder) into a box-target, marker or board session."""

from __future__ import annotations

import json
from pathlib import Path

import click

from rigcal.cli.options import force_option, json_option, output_option
from rigcal.cli.types import Real


@click.command("capture")
@click.argument("source", type=click.Path(path_type=Path))
@output_option("Session folder.", "DIR", file_okay=False)
@click.option("--scan-topic", help="Bags: the sensor_msgs/LaserScan topic.")
@click.option("--image-topic", help="Bags: the sensor_msgs/Image or CompressedImage topic.")
@click.option("--camera-info-topic", help="Bags: a sensor_msgs/CameraInfo topic for the camera.")
@click.option(
    "--camera", "camera_file", type=click.Path(path_type=Path), help="Camera file (else the recording's)."
)
@click.option("--box-width-m", type=Real(min=0.05), help="The box side's length (written for rigcal pick).")
@click.option(
    "--target",
    "target_file",
    type=click.Path(path_type=Path),
    help="A targets file (docs/formats/targets.md). A marker target's: write a marker session "
    "that rigcal solve takes as it is, and list the markers each capture shows. A board's (kind: "
    "board): find the chessboard in each still moment's image and scans and write a board session "
    "of those it is found in (the others listed with the reason). Each capture keeps the scans of "
    "its still moment (see --max-scans; the solve averages them).",
)
@click.option(
    "--max-scans", default=30, show_default=True, type=click.IntRange(min=1),
    help="With --target: most scans of a still moment kept per capture, spread over it "
    "(1: the scan paired with the image).",
)  # fmt: skip
@click.option(
    "--still-frames", default=5, show_default=True, type=click.IntRange(min=2),
    help="Least number of consecutive still frames of each stream.",
)  # fmt: skip
@click.option(
    "--scan-threshold-m", default=0.05, show_default=True, type=Real(min=0.0, min_open=True),
    help="A beam moved when its range changed by more.",
)  # fmt: skip
@click.option(
    "--image-threshold", default=15.0, show_default=True, type=Real(min=0.0, min_open=True),
    help="A pixel moved when its grey level changed by more.",
)  # fmt: skip
@click.option(
    "--changed-fraction", default=0.01, show_default=True,
    type=Real(0.0, 1.0, min_open=True, max_open=True),
    help="Two frames are still when under this fraction of beams / pixels moved (beams: "
    "those that moved with their neighbours, in runs of 3).",
)  # fmt: skip
@click.option(
    "--max-offset-s", default=0.5, show_default=True, type=Real(min=0.0, min_open=True),
    help="Largest stamp difference of a scan + image pair.",
)  # fmt: skip
@force_option("Replace an existing session folder.")
@json_option("Print the captures as JSON on stdout.")
def capture(
    source: Path,
    output: Path,
    scan_topic: str | None,
    image_topic: str | None,
    camera_info_topic: str | None,
    camera_file: Path | None,
    box_width_m: float | None,
    target_file: Path | None,
    max_scans: int,
    still_frames: int,
    scan_threshold_m: float,
    image_threshold: float,
    changed_fraction: float,
    max_offset_s: float,
    force: bool,
    as_json: bool,
) -> None:
    """Find the still moments of SOURCE and write one capture (scan + image) per moment.

    SOURCE is a ROS 1 / ROS 2 bag (give --scan-topic and --image-topic) or a sequence
    folder (rigcal import-bag, import-laser, simulate world). A moment is still when the
    scans and the images both stay unchanged for --still-frames frames; its scan and image
    are the pair nearest in time (the offset is printed). Writes a session folder with a
    picking file skeleton (docs/formats/session.md) for rigcal pick and rigcal solve; with
    --target a marker session (marker_session.yaml) or a board session (board_session.yaml)
    that rigcal solve takes as it is.

    \b
    Examples:
      rigcal capture lab.bag --scan-topic /scan --image-topic /cam/image_raw \\
          --camera-info-topic /cam/camera_info --box-width-m 0.6 -o session/
      rigcal capture run1/ --camera camera.yaml -o session/ --still-frames 10 --force
      rigcal capture run1/ --camera camera.yaml --target targets.yaml -o v-session/
      rigcal capture run1/ --camera camera.yaml --target board.yaml -o board-session/
    """
    import tempfile

    from rigcal.calib.capture import CaptureSettings, find_still_periods, write_capture_session
    from rigcal.camera import read_camera
    from rigcal.errors import InputError
    from rigcal.io.files import check_folder_writable
    from rigcal.recordings.sequence import read_sequence

    inputs = [
        source,
        *([camera_file] if camera_file is not None else []),
        *([target_file] if target_file else []),
    ]
    check_folder_writable(output, force, inputs)
    from rigcal.targets.board import BoardTarget

    target = None
    if target_file is not None:
        from rigcal.targets.board import read_target

        target = read_target(target_file)  # a bad targets file stops here, before anything is read
    settings = CaptureSettings(
        scan_threshold_m, image_threshold, changed_fraction, still_frames, max_offset_s
    )
    with tempfile.TemporaryDirectory(prefix="rigcal-capture-") as tmp:
        if (source / "sequence.yaml").is_file():
            folder = source
        else:
            from rigcal.recordings.bag import import_bag

            if scan_topic is None or image_topic is None:
                raise InputError.at(
                    source, "--scan-topic/--image-topic", None, "both topics for a bag (or a sequence folder)"
                )
            folder = Path(tmp) / "sequence"
            import_bag(source, folder, scan_topic, image_topic, camera_info_topic)
        seq = read_sequence(folder)
        cam = camera_file
        if cam is None and seq.camera_file is not None:
            cam = folder / seq.camera_file
        if cam is None:
            raise InputError.at(
                source, "camera", None, "a camera: give --camera FILE (or --camera-info-topic for a bag)"
            )
        camera = read_camera(cam)  # a bad camera file stops here, before anything is written
        captures = find_still_periods(seq, settings, origin=source)
        boards = None
        if isinstance(target, BoardTarget):
            from rigcal.calib.board.capture import write_board_capture_session

            boards = write_board_capture_session(
                seq, captures, output, cam, target, force=force, origin=source, max_scans=max_scans
            )
        else:
            write_capture_session(
                seq,
                captures,
                output,
                cam,
                box_width_m,
                force=force,
                origin=source,
                targets_file=target_file,
                max_scans=max_scans,
            )
    rows = [
        {
            "name": f"cap{k:02d}",
            "scan_stamp_s": seq.scans[c.scan_index].stamp_s,
            "image_stamp_s": float(seq.image_stamps_s[c.image_index]),
            "offset_ms": round(1000 * c.offset_s, 3),
            "still_s": round(c.end_s - c.start_s, 3),
            "still_scans": c.still_scans,
            "still_images": c.still_images,
        }
        for k, c in enumerate(captures)
    ]
    if boards is not None:
        why = dict(boards.dropped)
        for r, n, sc in zip(rows, boards.corners, boards.scans, strict=True):
            r["scans"] = sc
            r["board"] = f"set aside: {why[str(r['name'])]}" if r["name"] in why else f"board {n} corners"
    elif target is not None:
        from rigcal.calib.marker.session import capture_markers

        assert not isinstance(target, BoardTarget)
        for r in rows:
            r["markers"] = capture_markers(output / "images", str(r["name"]), camera, target)
    if as_json:
        click.echo(json.dumps({"session": str(output), "captures": rows}, indent=1))
    else:
        click.echo("capture  scan stamp (s)  image stamp (s)  offset (ms)  still (s)")
        for r in rows:
            click.echo(
                f"{r['name']:7s}  {r['scan_stamp_s']:14.3f}  {r['image_stamp_s']:15.3f}  "
                f"{r['offset_ms']:+11.1f}  {r['still_s']:9.2f}"
                + (f"  {r['markers']}" if "markers" in r else "")
                + (f"  {r['scans']} scans, {r['board']}" if "board" in r else "")
            )
        worst = max(abs(1000 * c.offset_s) for c in captures)
        click.echo(f"{len(rows)} captures; largest stamp offset {worst:.1f} ms")
    if boards is not None:
        click.echo(
            f"the board found in {len(boards.found)} of {len(rows)} captures; wrote {output}/; "
            f"solve it with: rigcal solve {output}/board_session.yaml -o rig.yaml",
            err=True,
        )
        return
    if target is not None:
        click.echo(
            f"wrote {output}/; solve it with: rigcal solve {output}/marker_session.yaml -o rig.yaml", err=True
        )
        return
    click.echo(f"wrote {output}/ (pick 3+ captures in picks.yaml, then rigcal pick)", err=True)
