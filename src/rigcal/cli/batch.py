"""``rigcal batch``: one command over many sessions or sequences, locally or on Ray."""

from __future__ import annotations

import shlex
import sys
from pathlib import Path
from typing import Any

import click

from rigcal.cli.options import json_option, output_option
from rigcal.cli.types import Real


@click.command("batch")
@click.argument("source")
@output_option("Batch folder.", "DIR", file_okay=False)
@click.option(
    "--command",
    "command",
    type=click.Choice(["check", "solve", "localize", "evaluate"]),
    help="The command to run over a glob (a manifest names its own).",
)
@click.option(
    "--set",
    "set_items",
    multiple=True,
    metavar="KEY=VALUE",
    help="An option of every item of a glob, as a manifest key (e.g. rig=rig.yaml, method=icp,kf); "
    "may be repeated.",
)
@click.option(
    "-j",
    "--workers",
    default=0,
    type=click.IntRange(min=0),
    help="Local worker processes [default: one per CPU]; with --ray, at most N items at once "
    "(and with --ray local, the CPUs Ray may use).",
)
@click.option(
    "--ray",
    "ray_address",
    metavar="ADDRESS",
    help="Run the items as Ray tasks: 'local' (start Ray here, on 127.0.0.1 only), 'auto' "
    "(the cluster RAY_ADDRESS names, or the one started on this machine), 'HOST:PORT' (a "
    "cluster's head, from one of its nodes) or 'ray://HOST:PORT' (Ray Client, from anywhere). "
    "Needs rigcal[ray]; docs/batch.md.",
)
@click.option(
    "--ray-timeout",
    "ray_timeout_s",
    default=10.0,
    show_default=True,
    type=Real(min=0.0, min_open=True),
    metavar="SECONDS",
    help="How long to try reaching a named Ray cluster before giving up.",
)
@click.option(
    "--ray-retries",
    default=1,
    show_default=True,
    type=click.IntRange(min=0),
    help="How often Ray runs an item again on another worker when its worker or node dies "
    "(a failing command is never retried).",
)
@click.option("--rerun", is_flag=True, help="Run finished items again instead of skipping them.")
@json_option("Print the summary as JSON on stdout.")
def batch(
    source: str,
    output: Path,
    command: str | None,
    set_items: tuple[str, ...],
    workers: int,
    ray_address: str | None,
    ray_timeout_s: float,
    ray_retries: int,
    rerun: bool,
    as_json: bool,
) -> int:
    """Run check, solve, localize or evaluate over every item of SOURCE: a manifest (a YAML
    file, docs/formats/batch.md) or a quoted glob over the command's main input (picking
    files of check and solve, sequence folders of localize, trajectories of evaluate).

    Each item runs in a worker process, on a local process pool or on a Ray cluster
    (--ray), and writes into OUTPUT/NAME/ exactly what the single command writes, plus
    item.json. A failed item is reported and the others go on. Re-running the same batch
    skips finished items (resume). Writes OUTPUT/summary.csv and summary.json, and for
    drift checks OUTPUT/fleet_drift.png. Exit 0 when every item succeeded, 1 when an item
    failed or a check found drift, 3 for a bad manifest.

    \b
    Examples:
      rigcal batch fleet.yaml -o nightly/
      rigcal batch 'runs/*/' --command localize --set method=icp,kf -o sweep/ -j 2
      rigcal batch 'sessions/*/picks.yaml' --command solve -o solves/
      rigcal batch fleet.yaml -o nightly/ --ray auto
      rigcal batch fleet.yaml -o nightly/ --ray ray://head.lab:10001
    """
    import json

    from rigcal.batch.manifest import glob_items, read_manifest
    from rigcal.batch.runner import BatchSettings, Outcome, run_batch, warning_lines
    from rigcal.batch.summary import rows, write_summary
    from rigcal.errors import InputError
    from rigcal.viz.fleet_plot import write_fleet_png

    if Path(source).suffix in (".yaml", ".yml") and not any(c in source for c in "*?["):
        if command is not None or set_items:
            raise click.UsageError("--command and --set go with a glob; a manifest names its own")
        items = read_manifest(source)
        from rigcal.io.files import check_apart

        check_apart(output, [source])
    else:
        if command is None:
            raise click.UsageError("a glob needs --command (check, solve, localize or evaluate)")
        options: dict[str, Any] = {}
        for text in set_items:
            key, sep, value = text.partition("=")
            if not sep or not key:
                raise InputError.at(None, "--set", text, "KEY=VALUE")
            if key == "iasm":
                options.setdefault(key, []).append(value)
            else:
                options[key] = value
        items = glob_items(source, command, options)

    def report(o: Outcome, done: int, total: int) -> None:
        rec = o.record
        what = "skipped, finished before" if o.resumed else f"{rec['seconds']:.1f} s"
        line = f"[{done}/{total}] {o.item.name}: {rec['status']} ({what})"
        if rec["error"]:
            line += f": {rec['error']}"
        click.echo(line, err=True)
        for warning in warning_lines(str(rec.get("stderr") or "")):
            click.echo(f"warning: {o.item.name}: {warning}", err=True)

    settings = BatchSettings(workers, ray_address, rerun, ray_timeout_s, ray_retries)
    command = "rigcal " + shlex.join(sys.argv[1:]) if sys.argv else "rigcal batch"
    outcomes = run_batch(items, output, settings, report, lambda line: click.echo(line, err=True), command)
    json_path, csv_path = write_summary(output, outcomes)
    wrote = [str(csv_path), str(json_path)]
    if items[0].command == "check":
        plot = [(o.item.name, o.record["status"], o.record["result"]) for o in outcomes]
        wrote.append(str(write_fleet_png(output / "fleet_drift.png", plot)))
    table = rows(outcomes)
    if as_json:
        click.echo(json.dumps(table, indent=1))
    else:
        for r in table:
            click.echo(f"{r['name']}\t{r['status']}" + (f"\t{r['error']}" if r["error"] else ""))
    counts = {s: sum(r["status"] == s for r in table) for s in ("ok", "drifted", "cannot_tell", "failed")}
    click.echo(
        f"{len(table)} items: {counts['ok']} ok, {counts['drifted']} drifted, "
        f"{counts['cannot_tell']} cannot tell, {counts['failed']} failed; "
        f"wrote {', '.join(wrote)}",
        err=True,
    )
    return 1 if counts["failed"] or counts["drifted"] else 0
