"""``rigcal warm-up``: compile every numba kernel ahead, so no later command waits for it."""

from __future__ import annotations

import contextlib
import io
import tempfile

import click

# The commands a newcomer runs, on small simulated data: together they call every kernel
# (P3P and Horn in the solves, line extraction, ICP and its grid search, the odometry's
# line carrying, IASM's matching, the image reader), with the argument types real runs use;
# the targetless check's kernel is called directly (its drives take long to simulate).
_COMMANDS = (
    "simulate box-session -o {tmp}/box --captures 8 --no-images",
    "solve {tmp}/box/picks.yaml -o {tmp}/box-rig.yaml",
    "lines {tmp}/box/scans/cap00.yaml",
    "simulate board-session -o {tmp}/board --captures 8",
    "solve {tmp}/board/board_session.yaml -o {tmp}/board-rig.yaml",
    "simulate world -o {tmp}/seq --duration-s 3",
    "localize {tmp}/seq --method icp,icp-p2p,vo,kf,iasm,hiasm -o {tmp}/loc",
)


@click.command("warm-up")
@click.pass_context
def warm_up(ctx: click.Context) -> None:
    """Compile rigcal's numba kernels now and cache them, so that the first solve or
    localize does not spend its first seconds (or minute, on a slow machine) compiling.

    Runs the simulate, solve, lines and localize commands on small simulated data in a
    temporary folder, then says how many kernels it compiled and where they are cached.
    With every kernel already cached it prints nothing. The cache is numba's: __pycache__
    beside rigcal's sources, or NUMBA_CACHE_DIR when that is set (set it to a writable
    folder for a read-only install; docs/development.md).

    \b
    Examples:
      rigcal warm-up
      NUMBA_CACHE_DIR=~/.cache/rigcal-numba rigcal warm-up
    """
    import time

    from rigcal.cli.main import cli
    from rigcal.cli.progress import configure
    from rigcal.errors import RigcalError
    from rigcal.jit import COMPILED

    before = len(COMPILED)
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="rigcal-warm-up-") as tmp:
        for command in _COMMANDS:
            args = [a.format(tmp=tmp) for a in command.split()]
            sink = io.StringIO()
            try:
                with contextlib.redirect_stdout(sink), contextlib.redirect_stderr(sink):
                    cli.main(args=["-q", *args], prog_name="rigcal", standalone_mode=False)
            except RigcalError as exc:  # pragma: no cover - a bug: the data are rigcal's own
                raise RuntimeError(f"rigcal {' '.join(args)} failed: {exc}\n{sink.getvalue()}") from exc
    from rigcal.drift.sampling import compile_now

    compile_now()
    root = ctx.find_root().obj or {}
    configure(root.get("verbose", 0), root.get("quiet", False))  # the inner -q changed the level
    new = COMPILED[before:]
    if new:
        nowhere = "nowhere (no writable cache folder: set NUMBA_CACHE_DIR)"
        where = sorted({c.cache_dir or nowhere for c in new})
        click.echo(
            f"compiled {len(new)} kernels in {time.perf_counter() - t0:.0f} s; cached in " + ", ".join(where),
            err=True,
        )
