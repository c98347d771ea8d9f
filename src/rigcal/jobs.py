"""The commands a batch runs, as library calls: ``rigcal solve``, ``check``, ``localize``
and ``evaluate`` each read their inputs, run their method, write their outputs and return
what the command prints with ``--json``.

The single commands (``rigcal/cli``) and ``rigcal batch`` (:mod:`rigcal.batch.runner`)
both call these functions, so a batch item writes exactly what the single command writes.
How a result was asked for is passed in (``command``, the command line a rig file's
provenance records), never read from ``sys.argv``. Nothing here prints; option values are
checked with the command line's own rules (:mod:`rigcal.calib.options`), so a value the
command refuses is refused here too, naming the option.
"""

from __future__ import annotations

import contextlib
import json
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rigcal.calib.options import (
    DEFAULT_PICK_SIGMA_PX,
    DEFAULT_THRESHOLD_PX,
    LOSS,
    NOISE,
    PICK_SIGMA_PX,
    RANGE_SIGMA_M,
    SEED,
    THRESHOLD_PX,
)
from rigcal.errors import ArgumentError, InputError
from rigcal.io.validate import Real, Whole

if TYPE_CHECKING:
    import numpy as np
    from numpy.typing import NDArray

    from rigcal.io.log_lines import CutLine
    from rigcal.localize.pipeline import Run
    from rigcal.rig import Rig

    FloatArray = NDArray[np.float64]

# check's chance of a false alarm when nothing moved, and the captures a box session needs
# for a fresh solve (fewer: the residual test only).
LEVEL = Real(min=1e-6, max=0.5)
MIN_CAPTURES = Whole(min=3)
# evaluate: stamps of estimate and truth closer than this are matched (evo's --t_max_diff).
MAX_DIFF_S = Real(min=0.0)

# A progress callback: (stage, done, total), as the command line's bars take it.
Progress = Callable[[str, int, int], None]


@contextlib.contextmanager
def _options() -> Iterator[None]:
    """An option's bad value as :class:`~rigcal.errors.ArgumentError` (a usage error, exit
    code 2, at the command line and in a batch item's record), not a bad input file's."""
    try:
        yield
    except ArgumentError:
        raise
    except InputError as exc:
        raise ArgumentError(str(exc)) from None


@dataclass(frozen=True)
class Solved:
    """A solve's outcome: ``doc`` is what ``rigcal solve --json`` prints, ``table`` the
    readable summary, ``rig`` the rig written."""

    doc: dict[str, Any]
    table: str
    rig: Rig


def solve_files(
    picks: Path,
    output: Path,
    *,
    command: str,
    report_dir: Path | None = None,
    truth: Path | None = None,
    seed: int = 0,
    threshold_px: float = DEFAULT_THRESHOLD_PX,
    pick_sigma_px: float = DEFAULT_PICK_SIGMA_PX,
    range_sigma_m: float | None = None,
    noise: str = "auto",
    range_bias: bool = True,
    loss: str = "cauchy",
    intrinsics_sigma: list[float] | None = None,
    skip_unseen_boards: bool = False,
    paper_endpoints: bool = False,
    level: Any = None,
    force: bool = False,
) -> Solved:
    """``rigcal solve``: the box, board or marker method on a session file (the file's
    ``method`` chooses), writing the rig file and, with ``report_dir``, the report folder.

    Args:
        command: the command line the rig's provenance records.
        level: the reduced solve's priors (:class:`rigcal.calib.board.level.LevelPriors`, board
            sessions only), over the session's ``level:``.

    Raises:
        ArgumentError: a bad option value.
        InputError: a bad input file.
        CalibrationError: the data cannot determine a calibration.
        OutputError: an output exists and ``force`` is False, or overlaps an input.
    """
    from rigcal.calib.board.session import is_board_session
    from rigcal.calib.marker.session import is_marker_session
    from rigcal.calib.options import box_settings
    from rigcal.io.files import check_apart, check_folder_writable, check_writable, load_yaml
    from rigcal.rigfile import write_rig

    with _options():
        seed = SEED.check(seed, None, "--seed")
        threshold_px = THRESHOLD_PX.check(threshold_px, None, "--threshold-px")
        pick_sigma_px = PICK_SIGMA_PX.check(pick_sigma_px, None, "--pick-sigma-px")
        if range_sigma_m is not None:
            range_sigma_m = RANGE_SIGMA_M.check(range_sigma_m, None, "--range-sigma-m")
        noise = NOISE.check(noise, None, "--noise")
        loss = LOSS.check(loss, None, "--loss")
    # Refuse before working: nothing is written unless everything can be.
    inputs = [picks, *([truth] if truth else [])]
    check_writable(output, force, inputs)
    if report_dir is not None:
        # The rig may go inside the report folder (it is written after it), not onto it.
        check_folder_writable(report_dir, force, inputs)
        check_apart(output, [report_dir])
    data = load_yaml(picks, "picking file")
    if level is not None and not is_board_session(data):
        raise InputError(
            f"--level-prior: given for {picks}; the reduced solve is the board method's (method: board)"
        )
    if is_board_session(data) or is_marker_session(data):
        return _solve_plane(
            picks,
            output,
            report_dir,
            truth,
            seed,
            range_sigma_m,
            noise,
            range_bias,
            loss,
            intrinsics_sigma,
            skip_unseen_boards,
            command,
            force,
            marker=is_marker_session(data),
            level=level,
        )
    if intrinsics_sigma is not None:
        raise InputError(
            f"--intrinsics-sigma: got {_sigmas(intrinsics_sigma)!r}; the box method does not take the "
            "camera's uncertainty yet (only board sessions, method: board)"
        )
    from rigcal.calib.box.session import calibrate
    from rigcal.calib.report import report_table
    from rigcal.viz.report_dir import write_box_report

    settings = box_settings(
        threshold_px=threshold_px,
        seed=seed,
        pick_sigma_px=pick_sigma_px,
        loss=loss,
        paper_endpoints=paper_endpoints,
        noise=noise,
    )
    # One rule for both methods: range_sigma_m, else the file's laser.range_sigma_m.
    cal = calibrate(picks, settings, truth, command=command, range_sigma_m=range_sigma_m)
    _check_apart_from(output, report_dir, cal.session.input_files())
    if report_dir is not None:
        write_box_report(report_dir, cal, force=force)
    write_rig(output, cal.rig, force=force)
    doc = {k: cal.report[k] for k in ("summary", "noise", "uncertainty", "rejected", "warnings")}
    doc["rig_file"] = str(output)
    doc["rig"] = cal.rig.to_json()
    if "truth" in cal.report:
        doc["truth"] = cal.report["truth"]
    return Solved(doc, report_table(cal.report), cal.rig)


def _sigmas(values: Sequence[float]) -> str:
    return ",".join(f"{x:g}" for x in values)


def _check_apart_from(output: Path, report_dir: Path | None, files: Iterable[Path]) -> None:
    """The outputs against every file the session read (its scans, images, camera, lists)."""
    from rigcal.io.files import check_apart

    files = list(files)
    check_apart(output, files)
    if report_dir is not None:
        check_apart(report_dir, files)


def _solve_plane(
    session: Path,
    output: Path,
    report_dir: Path | None,
    truth: Path | None,
    seed: int,
    range_sigma_m: float | None,
    noise: str,
    range_bias: bool,
    loss: str,
    intrinsics_sigma: list[float] | None,
    skip_unseen_boards: bool,
    command: str,
    force: bool,
    marker: bool,
    level: Any = None,
) -> Solved:
    """A board session (``method: board``) or a marker session (``method: marker``): the
    plane method, then the same outputs."""
    from rigcal.calib.board.calibrate import board_report_table, calibrate_board
    from rigcal.calib.marker.calibrate import calibrate_marker, marker_report_table
    from rigcal.rigfile import write_rig
    from rigcal.viz.report_dir import write_plane_report

    if marker and intrinsics_sigma is not None:
        raise InputError(
            f"--intrinsics-sigma: got {_sigmas(intrinsics_sigma)!r}; the marker "
            "method does not take the camera's uncertainty yet (only board sessions, method: board)"
        )
    if marker:
        cal: Any = calibrate_marker(
            session, range_sigma_m, truth, command, seed, noise, range_bias, loss=loss
        )
        table = marker_report_table(cal.report)
    else:
        cal = calibrate_board(
            session,
            range_sigma_m,
            truth,
            command,
            seed,
            noise,
            range_bias,
            loss=loss,
            intrinsics_sigma=intrinsics_sigma,
            skip_unseen_boards=skip_unseen_boards,
            level=level,
        )
        table = board_report_table(cal.report)
    _check_apart_from(output, report_dir, cal.session.files)
    if report_dir is not None:
        write_plane_report(report_dir, cal, force=force)
    write_rig(output, cal.rig, force=force)
    doc = dict(cal.report)
    doc["rig_file"] = str(output)
    doc["rig"] = cal.rig.to_json()
    return Solved(doc, table, cal.rig)


@dataclass(frozen=True)
class Checked:
    """A check's outcome: ``record`` is the drift log's record (what ``rigcal check
    --json`` prints), ``exit_code`` the verdict's (0 ok, 1 drifted, 6 cannot tell), ``log``
    the drift log appended to (None with ``no_log``)."""

    record: dict[str, Any]
    exit_code: int
    log: Path | None


def check_rig(
    rig: Path,
    *,
    picks: Path | None = None,
    session: Path | None = None,
    sequence: Path | None = None,
    trajectory: Path | None = None,
    wheel_odometry: bool = True,
    level: float = 0.01,
    min_captures: int = 5,
    log: Path | None = None,
    no_log: bool = False,
    plot: Path | None = None,
    force: bool = False,
    progress: Progress | None = None,
) -> Checked:
    """``rigcal check``: test the rig against one new box session (``picks``), board or
    box session (``session``) or drive (``sequence``); append the record to the drift log
    (``log``, by default beside the rig) unless ``no_log``, and draw the history with
    ``plot``. ``trajectory``: with ``sequence``, a TUM file of the laser's poses (a
    ``rigcal localize`` run's) that the check uses instead of its own laser odometry;
    ``wheel_odometry``: with ``sequence``, start that odometry's steps from the drive's
    wheel odometry (False: neither read nor used).

    Raises:
        InputError: not exactly one of picks, session and sequence; a bad value or input.
        OutputError: the log or the plot cannot be written.
    """
    from rigcal.drift.log import EXIT_CODES, append_record, default_log_path, read_log
    from rigcal.errors import OutputError
    from rigcal.io.files import check_apart, check_writable
    from rigcal.rigfile import read_rig

    given = [(n, p) for n, p in (("--picks", picks), ("--session", session), ("--sequence", sequence)) if p]
    if len(given) != 1:
        raise InputError.at(None, "check", [n for n, _ in given], "one of --picks, --session or --sequence")
    with _options():
        level = LEVEL.check(level, None, "--level")
        min_captures = MIN_CAPTURES.check(min_captures, None, "--min-captures")
    kind_flag, source = given[0]
    if trajectory is not None and kind_flag != "--sequence":
        raise InputError.at(None, "--trajectory", str(trajectory), "a drive's check: give it with --sequence")
    inputs = [rig, source, *([trajectory] if trajectory is not None else [])]
    log = log or default_log_path(rig)
    if not no_log:  # only a log that is written must stay apart from the inputs
        check_apart(log, inputs)
    if (plot is not None or not no_log) and log.is_dir():  # an output where a file goes: exit 5
        raise OutputError(f"{log}: is a folder; expected the drift log's file path (--log)")
    if plot is not None:
        from rigcal.viz.charts import check_chart_name

        check_writable(plot, force, [*inputs, log])
        check_chart_name(plot)
    stored = read_rig(rig)
    if kind_flag == "--sequence":
        record = _targetless(rig, stored, source, trajectory, wheel_odometry, level, progress)
    else:
        record = _with_target(rig, stored, source, kind_flag, level, min_captures)
    # The plot (the history and this check) first: a failure there leaves the log as it was.
    history = read_log(log) if (plot is not None or not no_log) and log.exists() else []
    if plot is not None:
        from rigcal.viz.drift_plot import write_drift_plot

        write_drift_plot(plot, [*history, record], force=force)
    if not no_log:
        append_record(log, record)
    return Checked(record, EXIT_CODES[str(record["verdict"])], None if no_log else log)


def _with_target(
    rig_path: Path, stored: Rig, source: Path, flag: str, level: float, min_captures: int
) -> dict[str, Any]:
    """A box or board session's check record."""
    from rigcal.calib.board.session import is_board_session
    from rigcal.calib.box.picks import read_picks
    from rigcal.drift.log import drift_record
    from rigcal.drift.target import DriftSettings, check_drift, check_drift_board
    from rigcal.io.files import load_yaml

    if stored.covariance is None:
        raise InputError(
            f"{rig_path}: uncertainty: missing; a drift check needs the stored calibration's covariance "
            "(re-solve the rig with `rigcal solve`)"
        )
    settings = DriftSettings(level=level, min_captures_for_solve=min_captures)
    board = is_board_session(load_yaml(source, "picking file" if flag == "--picks" else "session file"))
    if board and flag == "--picks":
        raise InputError(
            f"{source}: method: got 'board'; expected a box picking file for --picks: check a board "
            f"session with `rigcal check {rig_path} --session {source}`"
        )
    if board:
        return drift_record(check_drift_board(stored, source, settings), source, kind="board")
    return drift_record(check_drift(stored, read_picks(source), settings), source, kind="box")


def _targetless(
    rig_path: Path,
    stored: Rig,
    sequence: Path,
    trajectory: Path | None,
    wheel_odometry: bool,
    level: float,
    progress: Progress | None,
) -> dict[str, Any]:
    """A drive's targetless check record (with ``trajectory``: its laser motion from that
    TUM file instead of the check's own odometry)."""
    import dataclasses
    import time
    from concurrent.futures import ThreadPoolExecutor

    from rigcal.drift.frames import FRAME_RATE_HZ, frames_ahead, used_frames
    from rigcal.localize.image_cache import EarlyFrames, ImageCache
    from rigcal.recordings.sequence import read_sequence

    def timed_read() -> tuple[Any, float, EarlyFrames | None]:
        t0 = time.perf_counter()
        early: list[EarlyFrames] = []

        def decode_early(folder: Path, stamps_s: Any, files: list[str]) -> None:
            """The check's frames (drift/frames.py) start decoding on another thread as soon
            as the image index is read, while the scans are read and the check's modules
            import."""
            frames = used_frames(stamps_s, FRAME_RATE_HZ)[: frames_ahead(cam.width_px, cam.height_px)]
            paths = [(i, folder / files[i]) for i in frames]
            early.append(EarlyFrames(paths, (cam.height_px, cam.width_px), ImageCache()))

        try:
            seq = read_sequence(sequence, on_images=decode_early)
        except BaseException:
            for e in early:
                e.stop()
            raise
        return seq, time.perf_counter() - t0, early[0] if early else None

    # The drive is read (inflating scans.npz and numpy's work on the scans, mostly outside
    # the interpreter's lock) on a second thread while the check's modules import, its
    # frames decoding on a third.
    cam = stored.camera
    with ThreadPoolExecutor(1, thread_name_prefix="rigcal-read") as pool:
        read = pool.submit(timed_read)
        from rigcal.drift.log import targetless_record
        from rigcal.drift.targetless import TargetlessSettings, check_targetless, same_camera
        from rigcal.localize.streams import Streams, require_returns

        seq, read_s, early = read.result()
    try:
        require_returns(sequence, seq)
        # Streams keep frames as decoded (their default feature tracks' settings do not
        # equalise), so the early frames are the frames the check would decode itself.
        cache = early.cache if early is not None else ImageCache()
        streams = Streams(seq, stored, {"read_s": read_s}, _image_cache=cache)
        streams.use_wheel_odometry = wheel_odometry  # False: odometry.tum is not even read
        same_camera(stored, streams, rig_path)
        streams.progress = progress
        streams.odometry_covariance = False  # the check uses the odometry's poses only
        settings = TargetlessSettings(level=level)
        if trajectory is not None:
            from rigcal.drift.trajectory import trajectory_odometry

            streams.use_laser_odometry(trajectory_odometry(trajectory, streams))
            settings = dataclasses.replace(settings, scan_rate_hz=None)  # every scan's pose is known
    finally:
        if early is not None:
            early.stop()  # the check decodes the rest itself
    result = check_targetless(stored, streams, settings)
    return targetless_record(result, sequence, trajectory)


@dataclass(frozen=True)
class Localized:
    """A localization's outcome: ``run`` the methods' results, ``doc`` its summary (what
    ``rigcal localize --json`` prints and summary.json holds)."""

    run: Run
    doc: dict[str, Any]


def localize_sequence(
    sequence: Path,
    output: Path,
    *,
    methods: str = "icp",
    rig: Path | None = None,
    kitti: bool = False,
    iasm: Sequence[str] = (),
    tracks: Sequence[str] = (),
    wheel_odometry: bool = True,
    loop_closure: bool = False,
    pose_graph: str = "auto",
    kf: str = "weighted",
    kf_smooth: bool = False,
    place_recognition: str = "images",
    force: bool = False,
    progress: Progress | None = None,
    gyro: bool = True,
) -> Localized:
    """``rigcal localize``: each method (comma-separated names) over the sequence folder,
    the output folder written by :func:`rigcal.viz.localize_output.write_run`.

    Args:
        iasm, tracks: ``KEY=VALUE`` settings of IASM and H-IASM, and of the feature tracks.
        pose_graph: the loop closures' pose-graph back end: ``auto`` (GTSAM where
            installed, else scipy), ``scipy`` or ``gtsam``.
        kf: the Kalman filter: ``weighted`` (each step's own covariance), ``fixed``
            (the paper's fixed covariances), ``driven`` (weighted, ICP's steps driving
            the prediction) or ``icp-first`` (driven, VO only along directions ICP
            leaves open), :data:`rigcal.localize.kalman.KF_MODES`.
        kf_smooth: that filter followed by its backward pass (the Rauch-Tung-Striebel
            smoother, ``KfParams.smooth``).
        place_recognition: loop closure's proposals from the keyframes' images
            (``images``, where the sequence has them) or none (``none``).
        gyro: the Kalman filter fuses the sequence's gyroscope (when it has one); False
            ignores it.

    Raises:
        ArgumentError: an unknown method or setting (the command line's usage errors).
        InputError: a sequence that cannot be localized.
        OutputError: ``output`` exists and ``force`` is False.
    """
    from rigcal.io.files import check_folder_writable
    from rigcal.localize.kalman import KF_MODES
    from rigcal.localize.loop_closure import LoopParams
    from rigcal.localize.pipeline import (
        parse_iasm_settings,
        parse_methods,
        parse_track_settings,
        run,
        summary,
    )
    from rigcal.localize.place_recognition import PlaceParams
    from rigcal.localize.pose_graph import gtsam_available
    from rigcal.viz.localize_output import write_run

    with _options():
        lc_params = LoopParams(backend=pose_graph)
        if lc_params.pose_graph == "gtsam" and not gtsam_available():
            raise InputError.at(
                None,
                "--pose-graph",
                pose_graph,
                "auto or scipy: GTSAM is not installed (pip install rigcal[gtsam])",
            )
        if place_recognition not in ("images", "none"):
            raise InputError.at(None, "--place-recognition", place_recognition, "images or none")
        if kf not in KF_MODES:
            raise InputError.at(None, "--kf", kf, f"one of {', '.join(KF_MODES)}")
        names = parse_methods(methods)
        iasm_params = parse_iasm_settings(list(iasm))
        track_params = parse_track_settings(list(tracks))
    check_folder_writable(output, force, [sequence, *([rig] if rig else [])])
    r = run(
        sequence,
        names,
        rig_file=rig,
        progress=progress,
        iasm=iasm_params,
        tracks=track_params,
        wheel_odometry=wheel_odometry,
        loop_closure=lc_params if loop_closure else None,
        kf=replace(KF_MODES[kf], smooth=kf_smooth),
        place_recognition=PlaceParams() if place_recognition == "images" else None,
        gyro=gyro,
    )
    write_run(r, sequence, output, force=force, kitti=kitti)
    return Localized(r, summary(r, sequence))


@dataclass(frozen=True)
class Evaluated:
    """An evaluation's outcome: ``rows`` (label, figures) per trajectory; ``doc`` what
    ``rigcal evaluate --json`` prints (one object of figures, or one per label)."""

    rows: list[tuple[str, dict[str, Any]]]
    doc: dict[str, Any]
    cut: list[tuple[Path, CutLine]] = field(default_factory=list)  # files read to their last whole line


def evaluate_files(
    trajectories: Sequence[Path],
    gt: Path,
    *,
    max_diff_s: float = 0.01,
    plot: Path | None = None,
    force: bool = False,
    strict: bool = False,
) -> Evaluated:
    """``rigcal evaluate``: score TUM trajectories against the truth (the paper's Table 1
    figures, ATE and RPE as evo), and with ``plot`` chart them. A file copied while it was
    written (an incomplete last line) is read to its last whole line, named in ``cut``;
    ``strict`` refuses it (``--stamps strict``).

    Raises:
        InputError: a bad trajectory, or one with fewer than 2 stamps matching the truth's.
        OutputError: ``plot`` exists and ``force`` is False.
    """
    from rigcal.io.files import check_writable
    from rigcal.io.trajectory import read_tum_cut
    from rigcal.localize.metrics import anchored, associate, evaluate
    from rigcal.localize.pipeline import planar_at

    with _options():
        max_diff_s = MAX_DIFF_S.check(max_diff_s, None, "--max-diff-s")
    if plot is not None:
        from rigcal.viz.charts import check_chart_name

        check_chart_name(plot)
        check_writable(plot, force, [*trajectories, gt])
    cut = []
    truth, gt_cut = read_tum_cut(gt, strict)
    assert truth.stamps_s is not None
    cut += [(gt, gt_cut)] if gt_cut is not None else []
    rows = []
    drawn: dict[str, tuple[FloatArray, FloatArray, FloatArray]] = {}  # label -> (estimate, truth, stamps)
    for path, label in zip(trajectories, labels(trajectories), strict=True):
        est, est_cut = read_tum_cut(path, strict)
        assert est.stamps_s is not None
        cut += [(path, est_cut)] if est_cut is not None else []
        i_est, i_gt = associate(est.stamps_s, truth.stamps_s, max_diff_s)
        if len(i_est) < 2:
            raise InputError.at(
                path,
                "timestamps",
                f"{len(i_est)} within {max_diff_s} s of {gt}",
                "at least 2 stamps matching the truth's (no time overlap to score)",
            )
        poses_est = planar_at(est, est.stamps_s)[i_est]
        poses_gt = planar_at(truth, truth.stamps_s)[i_gt]
        rows.append((label, {**evaluate(poses_est, poses_gt, rounded=False), "matched_poses": len(i_est)}))
        drawn[label] = (anchored(poses_est, poses_gt), poses_gt, est.stamps_s[i_est])
    if plot is not None:
        from rigcal.viz.charts import save_figure
        from rigcal.viz.paths_plot import evaluation_figure

        fig = evaluation_figure(
            planar_at(truth, truth.stamps_s),
            {k: v[0] for k, v in drawn.items()},
            {k: v[1] for k, v in drawn.items()},
            {k: v[2] for k, v in drawn.items()},
        )
        save_figure(plot, fig, force=force)
    return Evaluated(rows, rows[0][1] if len(rows) == 1 else dict(rows), cut)


def labels(paths: Sequence[Path]) -> list[str]:
    """Row labels: the method folder of METHOD/trajectory.tum, else the file's stem, with
    more of each path's folders while two labels would be the same."""
    parts = [(p.parent if p.stem == "trajectory" else p.with_suffix("")).resolve().parts for p in paths]
    for n in range(1, max(len(x) for x in parts) + 1):
        out = ["/".join(x[-n:]) for x in parts]
        if len(set(out)) == len(out):
            return out
    return [str(p) for p in paths]


def as_json(doc: Any) -> str:
    """A job's ``doc`` as the command prints it with ``--json``."""
    return json.dumps(doc, indent=1)
