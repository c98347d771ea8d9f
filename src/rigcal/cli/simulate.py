"""``rigcal simulate``: synthetic data with a known answer."""

from __future__ import annotations

import copy
from pathlib import Path

import click

from rigcal.cli.options import force_option, json_option, output_option
from rigcal.cli.types import Real


@click.group("simulate")
def simulate() -> None:
    """Make synthetic sessions with a known calibration (for trying rigcal out and testing it).

    \b
    Examples:
      rigcal simulate box-session -o session/ --seed 1
      rigcal simulate marker-session -o v-session/ --seed 1
    """


_noise_option = click.option(
    "--noise",
    "noise_model",
    default="clean",
    show_default=True,
    type=click.Choice(["clean", "realistic"]),
    help="Scanner and room model: clean (Gaussian range noise, empty room) or realistic "
    "(heavy-tailed noise, mixed pixels, grazing bias, dropouts, static clutter; "
    "rigcal.sim.noise.RealisticNoise; --range-sigma-m is then ignored).",
)

# Every subcommand's seed and --json, declared once.
_seed_option = click.option(
    "--seed", default=0, show_default=True, type=click.IntRange(min=0), help="Random seed."
)
_json_option = json_option("Print what was written (and the true T_cam_laser) as JSON on stdout.")


@simulate.command("box-session")
@output_option("Session folder to create.", "DIR")
@click.option(
    "--captures",
    default=20,
    show_default=True,
    type=click.IntRange(min=1, max=999),
    help="Number of captures (scan + image).",
)
@_seed_option
@click.option(
    "--pick-sigma-px",
    default=1.0,
    show_default=True,
    type=Real(min=0.0, max=20.0),
    help="Noise of the picked pixels (1 sigma).",
)
@click.option(
    "--range-sigma-m",
    default=0.01,
    show_default=True,
    type=Real(min=0.0, max=0.05),
    help="Noise of the laser ranges (1 sigma).",
)
@click.option(
    "--wrong-picks",
    default=0.0,
    show_default=True,
    type=Real(min=0.0, max=1.0),
    help="Fraction of captures whose image picks are grossly wrong (moved 15-60 px or swapped).",
)
@click.option(
    "--move-deg",
    default=0.0,
    show_default=True,
    type=Real(min=0.0, max=30.0),
    help="Turn the camera on the rig by this much (random axis) before simulating, to try drift checks.",
)
@click.option(
    "--move-mm",
    default=0.0,
    show_default=True,
    type=Real(min=0.0, max=500.0),
    help="Shift the camera on the rig by this much (random direction) before simulating.",
)
@_noise_option
@click.option("--no-images", is_flag=True, help="Write flat grey placeholder images instead of renders.")
@force_option("Replace an existing session folder.")
@_json_option
def box_session(
    output: Path,
    captures: int,
    seed: int,
    pick_sigma_px: float,
    range_sigma_m: float,
    wrong_picks: float,
    move_deg: float,
    move_mm: float,
    noise_model: str,
    no_images: bool,
    force: bool,
    as_json: bool,
) -> None:
    """Write a synthetic box-target session with its truth file (also known by its first
    name, calib-session).

    The box is placed at random distances (1.2-4 m), bearings and angles in a simulated
    room; scans are ray-cast with range noise and dropouts, images rendered through the
    camera model, and the box ends "picked" with pixel noise. The folder holds camera.yaml,
    scans/, images/, picks.yaml (ready for `rigcal solve`) and truth.yaml (the true
    T_cam_laser). See docs/formats/session.md.

    \b
    Examples:
      rigcal simulate box-session -o examples/box-session --seed 1
      rigcal simulate box-session -o /tmp/s --captures 8 --wrong-picks 0.25 --force
      rigcal simulate box-session -o /tmp/s --pick-sigma-px 2 --range-sigma-m 0.02 --no-images
      rigcal solve /tmp/s/picks.yaml -o rig.yaml --truth /tmp/s/truth.yaml
      rigcal simulate box-session -o /tmp/moved --captures 8 --seed 2 --move-deg 0.5 --no-images
      rigcal check rig.yaml --picks /tmp/moved/picks.yaml
      rigcal simulate box-session -o /tmp/real --noise realistic --no-images
    """
    from rigcal.io.files import check_folder_writable
    from rigcal.sim.box_session import (
        SessionSpec,
        default_T_cam_laser,
        describe_session,
        generate_session,
        moved_T_cam_laser,
        write_session,
    )
    from rigcal.sim.noise import RealisticNoise

    # Refuse before working: generating and rendering take a few seconds.
    check_folder_writable(output, force)
    spec = SessionSpec(
        n_captures=captures,
        pick_sigma_px=pick_sigma_px,
        range_sigma_m=range_sigma_m,
        wrong_pick_fraction=wrong_picks,
        seed=seed,
        noise=RealisticNoise() if noise_model == "realistic" else None,
    )
    T = default_T_cam_laser()
    if move_deg or move_mm:
        T = moved_T_cam_laser(T, move_deg, move_mm, seed=seed)
    session = generate_session(spec, T_cam_laser=T)
    write_session(session, output, force=force, render_images=not no_images)
    if as_json:
        wrong = [c.name for c in session.captures if c.is_wrong_pick]
        _echo_json(output, "picks.yaml", session.T_cam_laser, captures=captures, seed=seed, wrong_picks=wrong)
        return
    click.echo(
        f"wrote {output}/: {describe_session(session)} "
        f"Solve it with: rigcal solve {output}/picks.yaml -o rig.yaml --truth {output}/truth.yaml",
        err=True,
    )


# The box session's first name, kept so that scripts written for it still run.
calib_session = copy.copy(box_session)
calib_session.hidden = True
simulate.add_command(calib_session, "calib-session")


@simulate.command("board-session")
@output_option("Folder to create.", "DIR")
@click.option(
    "--session",
    "kind",
    default="good",
    show_default=True,
    type=click.Choice(["good", "weak"]),
    help="good: the board's distance, bearing, turn and tilt spread evenly over their ranges, as a "
    "careful lab records them (the solve is certain); weak: each at random, as a hurried one "
    "(the solve often warns of a large uncertainty).",
)
@click.option(
    "--captures",
    type=click.IntRange(min=1, max=999),
    help="Board captures.  [default: 20 for a good session, 12 for a weak one]",
)
@_seed_option
@click.option(
    "--corner-sigma-px",
    default=0.3,
    show_default=True,
    type=Real(min=0.0, max=5.0),
    help="Corner noise.",
)
@click.option(
    "--range-sigma-m",
    default=0.01,
    show_default=True,
    type=Real(min=0.0, max=0.05),
    help="Range noise.",
)
@_noise_option
@force_option("Replace an existing folder.")
@_json_option
def board_session(
    output: Path,
    kind: str,
    captures: int | None,
    seed: int,
    corner_sigma_px: float,
    range_sigma_m: float,
    noise_model: str,
    force: bool,
    as_json: bool,
) -> None:
    """Write a synthetic checkerboard session (board corners listed, scans, truth) for the
    plane method of `rigcal solve`. By default a good session (20 captures, the board's
    poses spread over their ranges); --session weak writes what a hurried lab records,
    to see the solve's warnings. See docs/formats/board-session.md.

    \b
    Examples:
      rigcal simulate board-session -o /tmp/board --seed 1
      rigcal simulate board-session -o /tmp/weak --session weak
      rigcal solve /tmp/board/board_session.yaml -o rig.yaml --truth /tmp/board/truth.yaml
      rigcal simulate board-session -o /tmp/real --captures 28 --noise realistic
    """
    from rigcal.io.files import check_folder_writable
    from rigcal.sim.board_session import BoardSpec, generate_board_session, write_board_session
    from rigcal.sim.noise import RealisticNoise

    check_folder_writable(output, force)
    captures = captures or (GOOD_BOARD_CAPTURES if kind == "good" else WEAK_BOARD_CAPTURES)
    spec = BoardSpec(
        spread=kind == "good",
        n_captures=captures,
        corner_sigma_px=corner_sigma_px,
        range_sigma_m=range_sigma_m,
        seed=seed,
        noise=RealisticNoise() if noise_model == "realistic" else None,
    )
    session = generate_board_session(spec)
    write_board_session(session, output, force=force)
    if as_json:
        _echo_json(output, "board_session.yaml", session.T_cam_laser, captures=captures, seed=seed)
        return
    click.echo(
        f"wrote {output}/: {captures} board captures ({kind} session), seed {seed}. Solve it with: "
        f"rigcal solve {output}/board_session.yaml -o rig.yaml --truth {output}/truth.yaml",
        err=True,
    )


@simulate.command("marker-session")
@output_option("Folder to create.", "DIR")
@click.option(
    "--captures",
    default=20,
    show_default=True,
    type=click.IntRange(min=1, max=999),
    help="Views of the target.",
)
@_seed_option
@click.option(
    "--range-sigma-m", default=0.01, show_default=True, type=Real(min=0.0, max=0.05), help="Range noise."
)
@click.option(
    "--targets",
    "targets_file",
    type=click.Path(path_type=Path),
    help="Targets file of the V to simulate [default: `rigcal targets new`'s].",
)
@click.option(
    "--upright",
    is_flag=True,
    help="Every view upright (no tilt, no roll): the weak geometry the solve warns about.",
)
@click.option(
    "--scans-per-capture",
    default=10,
    show_default=True,
    type=click.IntRange(min=1, max=200),
    help="Scans of each still moment, independent range noise each (a bag's 40 Hz scanner "
    "held still a quarter of a second gives 10); 1 writes one scan per capture.",
)
@_noise_option
@force_option("Replace an existing folder.")
@_json_option
def marker_session(
    output: Path,
    captures: int,
    seed: int,
    range_sigma_m: float,
    targets_file: Path | None,
    upright: bool,
    scans_per_capture: int,
    noise_model: str,
    force: bool,
    as_json: bool,
) -> None:
    """Write a synthetic marker session (rendered images, scans, the targets file, truth)
    for the marker method of `rigcal solve`. See docs/formats/marker-session.md.

    \b
    Examples:
      rigcal simulate marker-session -o /tmp/v --seed 1
      rigcal solve /tmp/v/marker_session.yaml -o rig.yaml --truth /tmp/v/truth.yaml
      rigcal simulate marker-session -o /tmp/vr --noise realistic --captures 10
    """
    from rigcal.io.files import check_folder_writable
    from rigcal.sim.marker_session import MarkerSpec, generate_marker_session, write_marker_session
    from rigcal.sim.noise import RealisticNoise
    from rigcal.targets.marker import default_target, read_targets

    check_folder_writable(output, force, [targets_file] if targets_file else [])
    target = read_targets(targets_file) if targets_file else default_target()
    spec = MarkerSpec(
        n_captures=captures,
        range_sigma_m=range_sigma_m,
        seed=seed,
        upright=upright,
        noise=RealisticNoise() if noise_model == "realistic" else None,
        target=target,
        scans_per_capture=scans_per_capture,
    )
    session = generate_marker_session(spec)
    write_marker_session(session, output, force=force)
    if as_json:
        _echo_json(output, "marker_session.yaml", session.T_cam_laser, captures=captures, seed=seed)
        return
    click.echo(
        f"wrote {output}/: {captures} views of the marker target, seed {seed}. Solve it with: rigcal solve "
        f"{output}/marker_session.yaml -o rig.yaml --truth {output}/truth.yaml",
        err=True,
    )


GOOD_BOARD_CAPTURES = 20
WEAK_BOARD_CAPTURES = 12


@simulate.command("world")
@click.option(
    "--world",
    "world_name",
    default="corridor-loop",
    show_default=True,
    help="corridor-loop (60 m), cubicle-loop (35 m), calibration-room, or a world file (.yaml).",
)
@output_option("Sequence folder.", "DIR")
@_seed_option
@click.option(
    "--range-sigma-m",
    default=0.01,
    show_default=True,
    type=Real(min=0.0, max=0.1),
    help="Range noise.",
)
@click.option(
    "--laser-rate-hz",
    default=40.0,
    show_default=True,
    type=Real(min=1.0, max=200.0),
    help="Scan rate.",
)
@click.option(
    "--range-max-m",
    default=30.0,
    show_default=True,
    type=Real(min=0.5, max=100.0),
    help="The laser's range: farther walls give no return (a Hokuyo URG-04LX's is 5.6 m, a UTM-30LX's 30 m).",
)
@click.option(
    "--camera-rate-hz",
    default=10.0,
    show_default=True,
    type=Real(min=0.1, max=100.0),
    help="Camera frame rate (its first frame at a random phase: not synchronised with the laser).",
)
@click.option(
    "--clock-offset-s",
    default=0.0,
    show_default=True,
    type=Real(min=-10.0, max=10.0),
    help="Added to the written image stamps (camera clock = true time + offset).",
)
@click.option(
    "--image-noise",
    default=2.0,
    show_default=True,
    type=Real(min=0.0, max=50.0),
    help="Additive Gaussian image noise, grey levels (1 sigma).",
)
@click.option(
    "--image-blur-px",
    default=0.0,
    show_default=True,
    type=Real(min=0.0, max=20.0),
    help="Gaussian blur of the images, pixels (1 sigma).",
)
@click.option(
    "--exposure-walk",
    default=0.0,
    show_default=True,
    type=Real(min=0.0, max=0.2),
    help="Exposure changes: the log-gain's random-walk step per frame.",
)
@click.option(
    "--duration-s",
    default=None,
    type=Real(min=0.0, min_open=True),
    help="Drive only the lap's first seconds of motion (after --start-still).  [default: the whole lap]",
)
@click.option(
    "--start-still",
    "start_still_s",
    default=0.0,
    show_default=True,
    type=Real(min=0.0, max=3600.0),
    help="Seconds standing still before the rig moves, as real drives begin (every sensor "
    "covers them; a gyroscope's bias can be learned there).",
)
@click.option(
    "--rig",
    "rig_file",
    default=None,
    type=click.Path(path_type=Path, dir_okay=False),
    help="Rig file (T_cam_laser and camera) to simulate, e.g. a side-looking camera.  "
    "[default: the simulated forward-looking rig]",
)
@click.option("--no-images", is_flag=True, help="Write no camera images (laser and ground truth only).")
@click.option(
    "--image-format",
    default="png",
    show_default=True,
    type=click.Choice(["png", "png-grey", "jpg"]),
    help="png: lossless colour; png-grey: lossless grey, the levels rigcal reads (the same "
    "results in a third of the space); jpg: colour JPEG quality 95 (a fifth, lossy).",
)
@click.option(
    "--wheel-odometry",
    is_flag=True,
    help="Also write the base's wheel odometry (odometry.tum: 50 Hz, 2 %% scale error, "
    "0.5 deg/m heading drift; docs/formats/sequence.md).",
)
@click.option(
    "--gyro",
    is_flag=True,
    help="Also write a MEMS gyroscope's yaw rate (gyro.csv: 200 Hz, 0.005 deg/s/sqrt(Hz) noise, "
    "a constant bias and a bias random walk; docs/formats/sequence.md). The drive's other "
    "files are the same with or without it.",
)
@force_option("Replace an existing folder.")
@_json_option
def world(
    world_name: str,
    output: Path,
    seed: int,
    range_sigma_m: float,
    laser_rate_hz: float,
    range_max_m: float,
    camera_rate_hz: float,
    clock_offset_s: float,
    image_noise: float,
    image_blur_px: float,
    exposure_walk: float,
    duration_s: float | None,
    start_still_s: float,
    rig_file: Path | None,
    no_images: bool,
    image_format: str,
    wheel_odometry: bool,
    gyro: bool,
    force: bool,
    as_json: bool,
) -> None:
    """Drive one lap of a simulated indoor world and write it as a sequence folder: laser
    scans, camera images rendered at the true poses, the laser's ground truth at every
    sensor stamp (groundtruth.tum) and the rig file. The same seed writes the same files.
    See docs/formats/sequence.md and docs/formats/world.md.

    \b
    Examples:
      rigcal simulate world --world corridor-loop -o corridor/ --seed 1
      rigcal simulate world --world cubicle-loop -o cubicles/ --clock-offset-s 0.03 --image-noise 3
      rigcal simulate world --world my-office.yaml -o office/ --laser-rate-hz 20 --no-images --force
      rigcal simulate world -o side/ --rig side-looking-rig.yaml --duration-s 20
      rigcal simulate world -o small/ --image-format png-grey
      rigcal simulate world -o imu/ --wheel-odometry --gyro --duration-s 40
      rigcal simulate world -o imu/ --gyro --start-still 3 --duration-s 40
    """
    from rigcal.cli.progress import Progress, quiet
    from rigcal.io.files import check_folder_writable
    from rigcal.rigfile import read_rig
    from rigcal.sim.drive import DriveSpec, Motion, camera_stamps, first_image_bytes, write_drive
    from rigcal.sim.world import BUILTIN, world_named

    world_file = [Path(world_name)] if Path(world_name).suffix in (".yaml", ".yml") else []
    if world_name not in BUILTIN and not world_file:
        raise click.BadParameter(
            f"{world_name!r}: expected one of {sorted(BUILTIN)} or a world file (.yaml)", param_hint="--world"
        )
    check_folder_writable(output, force, [*world_file, *([rig_file] if rig_file else [])])
    w = world_named(world_name)
    rig = read_rig(rig_file) if rig_file is not None else None
    spec = DriveSpec(
        range_sigma_m=range_sigma_m,
        laser_rate_hz=laser_rate_hz,
        range_max_m=range_max_m,
        seed=seed,
        camera_rate_hz=camera_rate_hz,
        camera_clock_offset_s=clock_offset_s,
        image_noise_sigma=image_noise,
        image_blur_sigma_px=image_blur_px,
        exposure_walk=exposure_walk,
        images=not no_images,
        duration_s=duration_s,
        start_still_s=start_still_s,
        image_format=image_format,
        wheel_odometry=wheel_odometry,
        gyro=gyro,
    )
    n_images = len(camera_stamps(Motion(w, spec), spec)) if spec.images else 0
    if n_images and not quiet():
        each = first_image_bytes(w, spec, rig)
        hint = (
            "; --image-format png-grey writes a third of it, the same for rigcal"
            if image_format == "png"
            else ""
        )
        click.echo(
            f"writing {n_images} images of about {each / 1e3:.0f} kB ({image_format}): "
            f"about {n_images * each / 1e6:.0f} MB{hint}",
            err=True,
        )
    done = [0]

    with Progress("image") as bars:

        def rendered(n: int) -> None:
            done[0] += n
            bars("rendering", done[0], n_images)

        figures = write_drive(w, spec, str(output), force=force, rig=rig, progress=rendered)
    ratio = x_real_time(figures["duration_s"], figures["generation_s"])
    if as_json:
        from rigcal.sim.box_session import default_T_cam_laser

        _echo_json(
            output,
            "sequence.yaml",
            rig.T_cam_laser if rig is not None else default_T_cam_laser(),
            world=w.name,
            seed=seed,
            length_m=figures["length_m"],
            duration_s=figures["duration_s"],
            scans=int(figures["scans"]),
            images=int(figures["images"]),
            wall_s=figures["generation_s"],
            x_real_time=ratio,
        )
        return
    click.echo(
        f"wrote {output}/: {w.name}, a {figures['length_m']:.1f} m lap, "
        f"{figures['duration_s']:.1f} s driven, "
        f"{int(figures['scans'])} scans, {int(figures['images'])} images, "
        f"generated in {figures['generation_s']:.1f} s ({ratio:.2f}x real time)",
        err=True,
    )


def x_real_time(duration_s: float, wall_s: float) -> float:
    """Seconds of data per second of wall time (above 1: faster than real time); the one
    meaning of "x real time" in every command's output."""
    return duration_s / wall_s if wall_s > 0 else float("inf")


def _echo_json(output: Path, entry: str, T_cam_laser: object, **figures: object) -> None:
    """What a simulate command wrote, and the true T_cam_laser, as JSON on stdout."""
    import json

    import numpy as np

    T = np.asarray(T_cam_laser, dtype=float)
    doc = {"output": str(output), "entry": str(output / entry), **figures}
    doc["T_cam_laser_true"] = [[float(x) for x in row] for row in T]
    click.echo(json.dumps(doc, indent=1))
