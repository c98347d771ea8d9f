"""``rigcal lines``: the line segments of a scan, to help picking the box side."""

from __future__ import annotations

import json
from pathlib import Path

import click

from rigcal.cli.options import force_option, json_option
from rigcal.cli.types import Real


@click.command("lines")
@click.argument("scan", type=click.Path(path_type=Path))
@click.option("--png", type=click.Path(path_type=Path), help="Also draw the scan with numbered segments.")
@force_option("Overwrite an existing PNG.")
@json_option("Print the segments as JSON on stdout.")
@click.option(
    "--range-sigma-m",
    type=Real(min=0.0, min_open=True, max=1.0, max_open=True),
    help="The scanner's range noise, as in the picking file's laser.range_sigma_m "
    "(thresholds scale with it; the same value gives the same segment ids) [default: 0.01].",
)
def lines(scan: Path, png: Path | None, force: bool, as_json: bool, range_sigma_m: float | None) -> None:
    """List the line segments of SCAN (paper Section III-B), numbered as picking files use them.

    \b
    Examples:
      rigcal lines examples/box-session/scans/cap00.yaml
      rigcal lines scan.yaml --png lines.png --force
      rigcal lines scan.yaml --json | jq '.[] | select(.length_m > 0.5)'
    """
    from rigcal.io.files import check_writable
    from rigcal.lines import LineParams, extract_lines, segments_table
    from rigcal.scan import read_scan

    if png is not None:
        check_writable(png, force, [scan])
    s = read_scan(scan)
    segments = extract_lines(s, LineParams.for_range_noise(range_sigma_m) if range_sigma_m else None)
    if png is not None:
        from rigcal.viz.scan_plot import render_scan_segments

        render_scan_segments(s, segments, png, force=force)
    if as_json:
        doc = [
            {
                "id": g.id,
                "points": len(g.indices),
                "first_beam": int(g.indices[0]),
                "last_beam": int(g.indices[-1]),
                "start_m": [round(float(x), 4) for x in g.start],
                "end_m": [round(float(x), 4) for x in g.end],
                "length_m": round(float(g.length_m), 4),
                "angle_deg": round(float(g.angle_rad) * 180.0 / 3.141592653589793, 3),
                "rms_residual_mm": round(1000.0 * float(g.rms_residual_m), 3),
            }
            for g in segments
        ]
        click.echo(json.dumps(doc, indent=1))
    else:
        click.echo(segments_table(segments), nl=False)
    click.echo(f"{len(segments)} segments" + (f"; drew {png}" if png else ""), err=True)
