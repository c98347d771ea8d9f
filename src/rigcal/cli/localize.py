"""``rigcal localize`` and ``rigcal evaluate``: trajectories from sequences, and their errors."""

from __future__ import annotations

import json
from pathlib import Path

import click

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
    "Eq. 4), vo (visual odometry with laser scale), kf (Kalman filter of icp and vo), iasm "
    "(image augmented scan matching), hiasm (homography based IASM).",
)
@click.option("-o", "--output", required=True, type=click.Path(path_type=Path), help="Output folder.")
@rig_option
@click.option("--kitti", is_flag=True, help="Also write each trajectory in KITTI form.")
@click.option("--force", is_flag=True, help="Replace an existing output folder.")
@click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON.")
@click.option(
    "--iasm",
    "iasm_items",
    multiple=True,
    metavar="KEY=VALUE",
    help="Change one of IASM's and H-IASM's settings (docs/localization.md), e.g. "
    "snap_max_m=0 or dense_window=true; may be repeated. The summary records them.",
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
) -> None:
    """Estimate the laser's trajectory through SEQUENCE (a sequence folder) with one or
    more methods, run on the same data in the same process.

    Writes METHOD/trajectory.tum (and .kitti) per method, summary.yaml/json with the
    configuration, per-stage timings and, when the sequence has ground truth, the paper's
    Table 1 figures, and paths.png (estimated paths against the truth, as Fig. 8).

    \b
    Examples:
      rigcal simulate world --world corridor-loop -o corridor/
      rigcal localize corridor/ --method icp,vo,kf -o out/
      rigcal localize corridor/ --method iasm,hiasm --iasm snap_max_m=0 -o out-raw/
    """
    from rigcal.errors import InputError
    from rigcal.io.files import check_folder_writable
    from rigcal.localize.pipeline import parse_iasm_settings, parse_methods, run, summary, table

    try:  # bad option values are usage errors (exit code 2)
        names = parse_methods(methods)
        iasm = parse_iasm_settings(iasm_items)
    except InputError as exc:
        raise click.UsageError(str(exc)) from None
    check_folder_writable(output, force, [sequence, *([rig_file] if rig_file else [])])
    bars = _Bars()
    try:
        r = run(
            sequence, names, output, force=force, kitti=kitti, rig_file=rig_file, progress=bars, iasm=iasm
        )
    finally:
        bars.close()
    if as_json:
        click.echo(json.dumps(summary(r, sequence), indent=1))
    elif r.truth is not None:
        click.echo(table([(m.method, m.metrics) for m in r.methods if m.metrics is not None]))
    for m in r.methods:
        click.echo(f"{m.method}: {len(m.stamps_s)} poses, {m.seconds:.1f} s of its own", err=True)
    shared = ", ".join(f"{k.removesuffix('_s')} {v:.1f} s" for k, v in r.timings_s.items())
    click.echo(f"stages: {shared}", err=True)
    ratio = r.duration_s / r.wall_s if r.wall_s > 0 else float("inf")
    click.echo(
        f"{r.duration_s:.1f} s of data in {r.wall_s:.1f} s ({ratio:.2f}x real time); wrote {output}/",
        err=True,
    )


class _Bars:
    """Progress on stderr. Stages may run side by side (the laser odometry runs beside
    the feature tracking), so a terminal gets one live line with every running stage's
    share done; each stage gets a line of its own when it ends."""

    def __init__(self) -> None:
        import sys
        import threading

        self.out = sys.stderr
        self.live = self.out.isatty()
        self.running: dict[str, tuple[int, int, float]] = {}
        self.lock = threading.Lock()
        self.drawn = 0.0

    def __call__(self, stage: str, done: int, total: int) -> None:
        import time

        with self.lock:
            now = time.perf_counter()
            started = self.running.get(stage, (0, 0, now))[2]
            self.running[stage] = (done, total, started)
            if done >= total:
                del self.running[stage]
                self._clear()
                self.out.write(f"{stage}: {total}/{total} in {now - started:.1f} s\n")
                self.out.flush()
                self.drawn = 0.0
            items = self.running.items()
            if self.live and self.running and now - self.drawn > 0.2:
                line = "  ".join(f"{k} {100 * d // max(t, 1)}% ({d}/{t})" for k, (d, t, _) in items)
                self.out.write("\r" + line[:150] + "\x1b[K")
                self.out.flush()
                self.drawn = now

    def _clear(self) -> None:
        if self.live:
            self.out.write("\r\x1b[K")

    def close(self) -> None:
        with self.lock:
            self._clear()
            self.out.flush()


@click.command("evaluate")
@click.argument("trajectory", type=click.Path(path_type=Path))
@click.option("--gt", required=True, type=click.Path(path_type=Path), help="Ground truth (TUM).")
@click.option("--json", "as_json", is_flag=True, help="Print the figures as JSON.")
def evaluate_cmd(trajectory: Path, gt: Path, as_json: bool) -> None:
    """Score a TUM TRAJECTORY against ground truth the way the paper's Table 1 does, plus
    ATE (SE(2)-aligned) and RPE over 1 m and 10 m as evo computes them.

    \b
    Examples:
      rigcal evaluate out/icp/trajectory.tum --gt corridor/groundtruth.tum
    """
    from rigcal.errors import InputError
    from rigcal.io.trajectory import read_tum
    from rigcal.localize.metrics import evaluate
    from rigcal.localize.pipeline import planar_at, table

    est = read_tum(trajectory)
    truth = read_tum(gt)
    assert est.stamps_s is not None
    assert truth.stamps_s is not None
    # Score only where the truth is known: interpolation would clamp outside its span.
    stamps = est.stamps_s[(est.stamps_s >= truth.stamps_s[0]) & (est.stamps_s <= truth.stamps_s[-1])]
    if len(stamps) < 2:
        span = f"{truth.stamps_s[0]:.3f}..{truth.stamps_s[-1]:.3f} s"
        raise InputError(
            f"{trajectory}: {len(stamps)} of {len(est.stamps_s)} poses within the truth's time span "
            f"({gt}: {span}); expected at least 2 (no time overlap to score)"
        )
    if len(stamps) < len(est.stamps_s):
        click.echo(
            f"scored {len(stamps)} of {len(est.stamps_s)} poses (the rest outside {gt}'s span)", err=True
        )
    m = evaluate(planar_at(est, stamps), planar_at(truth, stamps))
    click.echo(json.dumps(m, indent=1) if as_json else table([(trajectory.name, m)]))


@click.command("matches")
@click.argument("sequence", type=click.Path(path_type=Path))
@click.option("--image", "index", required=True, type=click.IntRange(min=0), help="First image of the pair.")
@click.option(
    "--method",
    default="hiasm",
    show_default=True,
    type=click.Choice(["iasm", "hiasm"]),
    help="Matching method.",
)
@click.option(
    "-o", "--output", required=True, type=click.Path(path_type=Path, dir_okay=False), help="PNG to write."
)
@rig_option
@click.option("--force", is_flag=True, help="Replace an existing file.")
def matches(
    sequence: Path, index: int, method: str, output: Path, rig_file: Path | None, force: bool
) -> None:
    """Draw the scan-return correspondences IASM or H-IASM finds between image INDEX and
    the next (as the paper's Fig. 5): inliers green, outliers red. Prints the metric
    chosen, the counts and the step's motion.

    \b
    Examples:
      rigcal matches corridor/ --image 120 --method iasm -o iasm.png
      rigcal matches corridor/ --image 120 --method hiasm -o hiasm.png
    """
    import cv2
    import numpy as np

    from rigcal.errors import InputError
    from rigcal.io.files import atomic_write_bytes, check_writable
    from rigcal.localize.image_matching import step_picture
    from rigcal.localize.streams import open_streams

    check_writable(output, force, [sequence, *([rig_file] if rig_file else [])])
    streams = open_streams(sequence, rig_file)
    if index + 1 >= streams.n_images:
        raise InputError.at(None, "--image", index, f"an image index below {streams.n_images - 1}")
    img, st = step_picture(streams, index, method)
    atomic_write_bytes(output, cv2.imencode(".png", img)[1].tobytes(), force=True)
    n = 0 if st.matches is None else len(st.matches.i1)
    inl = 0 if st.result is None else st.result.inliers
    metric = "-" if st.result is None else st.result.metric
    x, y, yaw = st.motion
    click.echo(
        f"{st.used}: {n} correspondences, {inl} inliers, {metric} metric; "
        f"motion x {x:.3f} m, y {y:.3f} m, yaw {np.degrees(yaw):.2f} deg"
    )
    if st.why_fallback:
        click.echo(f"fallback: {st.why_fallback}", err=True)
    click.echo(f"wrote {output}", err=True)
