"""``rigcal localize`` and ``rigcal evaluate``: trajectories from sequences, and their errors."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING

import click

from rigcal.cli.options import choice_option, force_option, json_option, output_option, wheel_odometry_option
from rigcal.cli.types import option_type
from rigcal.jobs import MAX_DIFF_S

if TYPE_CHECKING:
    import numpy as np
    from numpy.typing import NDArray

    from rigcal.localize.pipeline import MethodRun

    FloatArray = NDArray[np.float64]

rig_option = click.option(
    "--rig",
    "rig_file",
    type=click.Path(path_type=Path, dir_okay=False),
    help="Rig file to use instead of the sequence's own rig.yaml.",
)


@click.command("localize")
@click.argument("sequence", type=click.Path(path_type=Path))
@click.option(
    "--method",
    "methods",
    default="icp",
    show_default=True,
    help="One method or several, comma-separated: icp (point-to-line), icp-p2p (point-to-point, "
    "Eq. 4), vo (visual odometry with laser scale), kf (Kalman filter of icp and vo, and the wheel "
    "odometry when used), iasm (image augmented scan matching), hiasm (homography based IASM), "
    "odom (the wheel odometry alone).",
)
@output_option("Output folder.", "DIR")
@rig_option
@click.option("--kitti", is_flag=True, help="Also write each trajectory in KITTI form.")
@force_option("Replace an existing output folder.")
@json_option("Print the summary as JSON.")
@click.option(
    "--iasm",
    "iasm_items",
    multiple=True,
    metavar="KEY=VALUE",
    help="Change one of IASM's and H-IASM's settings (docs/localization.md), e.g. "
    "snap_max_m=0 or dense_window=true; may be repeated. The summary records them.",
)
@click.option(
    "--tracks",
    "track_items",
    multiple=True,
    metavar="KEY=VALUE",
    help="Change one of the feature tracks' settings (vo, kf, hiasm; docs/localization.md), e.g. "
    "detector=shi-tomasi or n_features=500; may be repeated. The summary records them.",
)
@wheel_odometry_option(
    "use: ICP starts each step from the sequence's wheel odometry (when it has one) and the "
    "Kalman filter fuses it; ignore: start from the previous motion."
)
@choice_option(
    "--gyro",
    ["ignore", "use"],
    "use: the Kalman filter (method kf) fuses the sequence's gyroscope (gyro.csv, when it has "
    "one), its bias learned as a state where the rig stands still (with --kf icp-first: it is the "
    "guard's heading witness, not fused); ignore (the default: on the simulated laps the fused gyro "
    "was not better than the filter without it): runs without it.",
)
@click.option(
    "--loop-closure",
    is_flag=True,
    help="Also run icp, icp-p2p, kf, iasm and hiasm with loop closure (scan-to-submap closures, a pose "
    "graph with a robust kernel), as METHOD+lc: closures.csv and graph.png beside its trajectory.",
)
@click.option(
    "--pose-graph",
    type=click.Choice(["auto", "scipy", "gtsam"]),
    default="auto",
    show_default=True,
    help="The loop closure's pose-graph back end: gtsam (the optional extra rigcal[gtsam]), "
    "scipy, or auto (gtsam where installed, scipy otherwise).",
)
@click.option(
    "--place-recognition",
    type=click.Choice(["images", "none"]),
    default="images",
    show_default=True,
    help="With --loop-closure: images (the keyframes' images also propose closures, by a bag of "
    "ORB words and an essential matrix, verified by the scans as the scan search's; where the "
    "sequence has images) or none (the scan search alone).",
)
@click.option(
    "--kf",
    type=click.Choice(["weighted", "fixed", "driven", "icp-first"]),
    default="weighted",
    show_default=True,
    help="The Kalman filter (method kf): weighted (each step by its own covariance, matched to its "
    "input's innovations), fixed (the paper's filter: fixed covariances per input, Section VI) or "
    "driven (weighted, ICP's steps driving the prediction, VO and the wheels its measurements) or "
    "icp-first (driven, VO only along directions ICP leaves open: ICP's path wherever ICP "
    "constrains the motion).",
)
@click.option(
    "--smooth",
    is_flag=True,
    help="Follow the Kalman filter (method kf) with its backward pass (the Rauch-Tung-Striebel "
    "smoother): each pose from the whole drive's measurements, not only those before it.",
)
def localize(
    sequence: Path,
    methods: str,
    output: Path,
    rig_file: Path | None,
    kitti: bool,
    force: bool,
    as_json: bool,
    iasm_items: tuple[str, ...],
    track_items: tuple[str, ...],
    wheel_odometry: str,
    loop_closure: bool,
    pose_graph: str,
    place_recognition: str,
    kf: str,
    smooth: bool,
    gyro: str,
) -> None:
    """Estimate the laser's trajectory through SEQUENCE (a sequence folder) with one or
    more methods, run on the same data in the same process.

    Writes METHOD/trajectory.tum (and .kitti) per method, summary.yaml/json with the
    configuration, per-stage timings and, when the sequence has ground truth, the paper's
    Table 1 figures, paths.png/.svg (estimated paths against the truth, as Fig. 8)
    and errors.png/.svg (each method's position error over time).

    \b
    Examples:
      rigcal simulate world --world corridor-loop -o corridor/
      rigcal localize corridor/ --method icp,vo,kf -o out/
      rigcal localize corridor/ --method iasm,hiasm --iasm snap_max_m=0 -o out-raw/
      rigcal localize corridor/ --method vo,kf --tracks detector=sift -o out-sift/
      rigcal localize corridor/ --method icp,vo,kf --kf fixed -o out-paper/
      rigcal localize corridor/ --method icp,kf --kf icp-first --smooth -o out-smooth/
    """
    from rigcal.cli.progress import Progress
    from rigcal.errors import ArgumentError
    from rigcal.jobs import localize_sequence
    from rigcal.localize.pipeline import table

    try:
        with Progress("step") as bars:
            done = localize_sequence(
                sequence,
                output,
                methods=methods,
                rig=rig_file,
                kitti=kitti,
                iasm=iasm_items,
                tracks=track_items,
                wheel_odometry=wheel_odometry == "use",
                loop_closure=loop_closure,
                pose_graph=pose_graph,
                place_recognition=place_recognition,
                kf=kf,
                kf_smooth=smooth,
                force=force,
                progress=bars,
                gyro=gyro == "use",
            )
    except ArgumentError as exc:  # bad option values are usage errors (exit code 2)
        raise click.UsageError(str(exc)) from None
    _warn_ignored_options(methods, bool(iasm_items), bool(track_items), smooth, loop_closure)
    r = done.run
    if _given("gyro") and r.gyro == "none" and "kf" in [m.strip() for m in methods.split(",")]:
        click.echo(f"warning: --gyro ignored: {sequence} has no gyroscope (gyro.csv, schema 4)", err=True)
    if as_json:
        click.echo(json.dumps(done.doc, indent=1))
    elif r.truth is not None:
        click.echo(table([(m.method, m.metrics) for m in r.methods if m.metrics is not None]))
    for m in r.methods:
        click.echo(method_line(m), err=True)
        if m.closures is not None:
            c = m.closures.counts
            click.echo(
                f"{m.method}: {c['proposed']} closures proposed, {c['accepted']} accepted, "
                f"{c['rejected_by_verification']} rejected by the verification, "
                f"{c['rejected_by_kernel']} by the robust kernel (pose graph on {m.closures.backend})",
                err=True,
            )
            click.echo(f"{m.method}: {source_line(m)}", err=True)
            if "note" in m.stats:
                click.echo(f"warning: {m.method}: {m.stats['note']}", err=True)
    shared = ", ".join(f"{k.removesuffix('_s')} {v:.1f} s" for k, v in r.timings_s.items())
    click.echo(f"stages: {shared}", err=True)
    ratio = r.duration_s / r.wall_s if r.wall_s > 0 else float("inf")
    click.echo(
        f"{r.duration_s:.1f} s of data in {r.wall_s:.1f} s ({ratio:.2f}x real time); wrote {output}/",
        err=True,
    )
    out = r.images_outside_scans
    if out["before"] or out["after"]:
        click.echo(
            f"warning: {out['before']} image(s) before the first scan and {out['after']} after the last "
            "(by more than a scan period) left out of the image methods and their trajectories: no scan "
            "measures the laser's motion there",
            err=True,
        )
    if d := r.images_16_bit:
        click.echo(
            f"warning: {d['frames']} 16-bit images read as 8 bits (levels up to {d['max_level']}: "
            f"shifted right by {d['shift_bits']} bits, every frame the same)",
            err=True,
        )


def _warn_ignored_options(methods: str, iasm: bool, tracks: bool, smooth: bool, loop_closure: bool) -> None:
    """One warning line per kind of option given that nothing in the run reads: ``--kf``,
    ``--smooth`` and ``--gyro`` without method kf, ``--iasm`` without iasm or hiasm, ``--tracks`` without a
    method that tracks images, ``--pose-graph`` and ``--place-recognition`` without
    ``--loop-closure``. The run goes on; those options change nothing in it."""
    from rigcal.localize.pipeline import TRACKING

    names = [m.strip() for m in methods.split(",") if m.strip()]
    for given, used_by in (
        (
            [o for o, on in (("--kf", _given("kf")), ("--smooth", smooth), ("--gyro", _given("gyro"))) if on],
            ("kf",),
        ),
        (["--iasm"] if iasm else [], ("iasm", "hiasm")),
        (["--tracks"] if tracks else [], TRACKING),
    ):
        if given and not set(used_by) & set(names):
            which = "which is not" if len(used_by) == 1 else "none of which is"
            click.echo(
                f"warning: {_options_ignored(given)} only on method {' or '.join(used_by)}, {which} "
                f"among the methods given ({', '.join(names)})",
                err=True,
            )
    lc_only = [
        o
        for o, p in (("--pose-graph", "pose_graph"), ("--place-recognition", "place_recognition"))
        if _given(p)
    ]
    if lc_only and not loop_closure:
        click.echo(
            f"warning: {_options_ignored(lc_only)} only with --loop-closure, which is not given", err=True
        )


def _options_ignored(given: list[str]) -> str:
    they = "they act" if len(given) > 1 else "it acts"
    return f"{' and '.join(given)} ignored: {they}"


def _given(param: str) -> bool:
    """Whether the option was given on the command line (not its default)."""
    source = click.get_current_context().get_parameter_source(param)
    return source is not None and source.name == "COMMANDLINE"


def source_line(m: MethodRun) -> str:
    """The closures by source (scan search, images) and what place recognition did."""
    assert m.closures is not None
    parts = [
        f"{source} {c['proposed']} proposed, {c['accepted']} accepted"
        for source, c in m.closures.counts_by_source.items()
    ]
    place = m.stats.get("place_recognition", {})
    if place.get("used") == "none":
        note = "place recognition off"
    elif "note" in place:
        note = f"place recognition: {place['note']}"
    else:
        note = (
            f"place recognition: {place['keyframes_with_images']} keyframes with images, "
            f"{place['candidates']} candidates, {place['rejected_by_geometry']} rejected by the "
            f"essential matrix, {place['proposed']} proposed"
        )
    return "by source: " + ("; ".join(parts) or "none") + f" ({note})"


def method_line(m: MethodRun) -> str:
    """One method's poses and time: the shared stages it is built on, then its own work."""
    line = f"{m.method}: {len(m.stamps_s)} poses in {m.total_s:.1f} s"
    if not m.shared_s:
        return line
    shared = ", ".join(f"{k.removesuffix('_s')} {v:.1f} s" for k, v in m.shared_s.items())
    return f"{line} (shared stages {shared}; its own {m.seconds:.1f} s)"


@click.command("evaluate")
@click.argument("trajectories", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option("--gt", required=True, type=click.Path(path_type=Path), help="Ground truth (TUM).")
@click.option(
    "--max-diff-s",
    default=0.01,
    show_default=True,
    type=option_type(MAX_DIFF_S),
    help="Stamps of estimate and truth closer than this are matched (evo's --t_max_diff).",
)
@json_option("Print the figures as JSON, unrounded.")
@click.option(
    "--precision",
    default=4,
    show_default=True,
    type=click.IntRange(0, 12),
    help="Decimals of the table's figures (the JSON is never rounded).",
)
@click.option(
    "--plot",
    type=click.Path(path_type=Path, dir_okay=False),
    metavar="FILE",
    help="Chart the paths against the truth beside their errors over time (.png, .svg or .pdf).",
)
@choice_option(
    "--stamps",
    ["repair", "strict"],
    "repair: a TUM file's incomplete last line (a file copied while it was written) is left "
    "out with one warning; strict: refuse it.",
)
@force_option("Overwrite an existing --plot file.")
def evaluate_cmd(
    trajectories: tuple[Path, ...],
    gt: Path,
    max_diff_s: float,
    as_json: bool,
    precision: int,
    plot: Path | None,
    stamps: str,
    force: bool,
) -> None:
    """Score TUM TRAJECTORIES against ground truth the way the paper's Table 1 does, plus
    ATE and RPE over 1 m and 10 m exactly as evo computes them (evo_ape --align,
    evo_rpe --delta D --delta_unit m). Poses are matched to the truth by stamp as evo does.
    Each row is labelled by its method folder (out/icp/trajectory.tum -> icp; longer
    paths where two would be the same). The table rounds to --precision decimals; with
    --json, unrounded figures: one trajectory gives one object of figures, several give
    one object per label. --plot charts the paths (each started at the truth's first
    matched pose) and their position errors over time, as evo_ape --plot does. A file
    copied while it was written is read to its last whole line with one warning
    (--stamps strict refuses it).

    \b
    Examples:
      rigcal evaluate out/icp/trajectory.tum --gt corridor/groundtruth.tum
      rigcal evaluate out/*/trajectory.tum --gt corridor/groundtruth.tum --json
      rigcal evaluate out/iasm/trajectory.tum out/hiasm/trajectory.tum --gt corridor/groundtruth.tum \\
        --plot compare.png --precision 6
    """
    from rigcal.cli.stamps import warn_cut
    from rigcal.jobs import evaluate_files
    from rigcal.localize.pipeline import table

    done = evaluate_files(
        trajectories, gt, max_diff_s=max_diff_s, plot=plot, force=force, strict=stamps == "strict"
    )
    for path, cut in done.cut:
        warn_cut(cut, path)
    if plot is not None:
        click.echo(f"wrote {plot}", err=True)
    if as_json:
        click.echo(json.dumps(done.doc, indent=1))
    else:
        click.echo(table(done.rows, precision))


@click.command("matches")
@click.argument("sequence", type=click.Path(path_type=Path))
@click.option("--image", "index", required=True, type=click.IntRange(min=0), help="First image of the pair.")
@click.option(
    "--method",
    default="iasm",
    show_default=True,
    type=click.Choice(["iasm", "hiasm"]),
    help="Matching method; as localize's --method, the default is the simplest (the paper's Fig. 5).",
)
@output_option("Picture to write (.png, .svg or .pdf).", dir_okay=False)
@rig_option
@force_option("Replace an existing file.")
@json_option("Print the counts and the step's motion as JSON.")
def matches(
    sequence: Path, index: int, method: str, output: Path, rig_file: Path | None, force: bool, as_json: bool
) -> None:
    """Draw the scan-return correspondences IASM or H-IASM finds between image INDEX and
    the next (as the paper's Fig. 5): both images with axes in pixels, inliers green,
    outliers red. Prints the metric chosen, the counts and the step's motion.

    \b
    Examples:
      rigcal matches corridor/ --image 120 --method iasm -o iasm.png
      rigcal matches corridor/ --image 120 --method hiasm -o hiasm.png
    """
    import numpy as np

    from rigcal.errors import InputError
    from rigcal.io.files import check_writable
    from rigcal.localize.image_matching import step_matches
    from rigcal.localize.streams import open_streams
    from rigcal.viz.charts import check_chart_name, save_figure
    from rigcal.viz.matches_plot import step_figure

    check_chart_name(output)
    check_writable(output, force, [sequence, *([rig_file] if rig_file else [])])
    streams = open_streams(sequence, rig_file)
    if streams.n_images < 2:
        raise InputError.at(
            sequence, "images", f"{streams.n_images} images", "2 or more images (a pair to match)"
        )
    if index + 1 >= streams.n_images:
        raise InputError.at(
            None, "--image", index, f"an index from 0 to {streams.n_images - 2} (the first image of a pair)"
        )
    found = step_matches(streams, index, method)
    save_figure(output, step_figure(found), force=True)
    st = found.step
    n = 0 if st.matches is None else len(st.matches.i1)
    inl = 0 if st.result is None else st.result.inliers
    metric = "-" if st.result is None else st.result.metric
    x, y, yaw = st.motion
    if as_json:
        doc = {
            "output": str(output),
            "image": index,
            "method": st.used,
            "correspondences": n,
            "inliers": int(inl),
            "metric": None if st.result is None else st.result.metric,
            "motion": {"x_m": float(x), "y_m": float(y), "yaw_rad": float(yaw)},
            "fallback": st.why_fallback or None,
        }
        click.echo(json.dumps(doc, indent=1))
        return
    click.echo(
        f"{st.used}: {n} correspondences, {inl} inliers, {metric} metric; "
        f"motion x {x:.3f} m, y {y:.3f} m, yaw {np.degrees(yaw):.2f} deg"
    )
    if st.why_fallback:
        click.echo(f"fallback: {st.why_fallback}", err=True)
    click.echo(f"wrote {output}", err=True)
