"""``rigcal import-carmen``: a CARMEN log (or a g2o file with its laser lines) into a sequence folder."""

from __future__ import annotations

import json
from pathlib import Path

import click

from rigcal.cli.options import force_option, json_option, output_option
from rigcal.cli.stamps import laser_offset_option, stamps_option, warn_cut, warn_stamps
from rigcal.cli.types import Real


@click.command("import-carmen")
@click.argument("log", type=click.Path(path_type=Path))
@output_option("Sequence folder.", "DIR")
@click.option(
    "--flaser-range-max-m",
    type=Real(min=0.0, min_open=True),
    default=50.0,
    show_default=True,
    help="Maximum range of FLASER lines (they carry none); farther returns count as no return.",
)
@stamps_option
@laser_offset_option
@click.option("--no-odometry", is_flag=True, help="Leave the log's wheel odometry out of the folder.")
@force_option("Replace an existing folder.")
@json_option("Print what was written as JSON on stdout.")
def import_carmen(
    log: Path,
    output: Path,
    flaser_range_max_m: float,
    stamps: str,
    laser_offset: str | None,
    no_odometry: bool,
    force: bool,
    as_json: bool,
) -> None:
    """Write the laser scans of LOG as a sequence folder (docs/formats/sequence.md).

    Reads FLASER and ROBOTLASER1 lines from a CARMEN log, or from a g2o file that keeps
    them (the MIT Killian Court log); the logged laser poses (SLAM-corrected in corrected
    logs) become the folder's groundtruth.tum, so `rigcal localize` and `rigcal evaluate`
    score laser odometry on real scans. The folder has no images. The log's wheel
    odometry (its ODOM lines, else the laser lines' odometry poses) is kept as
    odometry.tum with the laser's mounting (--laser-offset, else the log's PARAMs); ICP
    starts from it. Equal stamps and small steps back are repaired (--stamps). A log
    compressed with gzip or bzip2 is read as it is; an incomplete last line (a log cut
    short) is left out with a warning (--stamps strict refuses it).

    \b
    Examples:
      rigcal import-carmen killian.g2o -o killian/
      rigcal import-carmen fr079.log.gz -o fr079/
      rigcal localize killian/ --method icp -o killian-icp/
    """
    import numpy as np

    from rigcal.geometry import make_T, rotvec_to_R
    from rigcal.io.files import check_folder_writable
    from rigcal.io.trajectory import Trajectory, tum_text
    from rigcal.io.wheel_odometry import parse_mounting
    from rigcal.recordings.carmen import carmen_odometry, read_carmen
    from rigcal.recordings.sequence import write_sequence

    mounting = parse_mounting(laser_offset) if laser_offset is not None else None
    check_folder_writable(output, force, [log])
    c = read_carmen(log, flaser_range_max_m, stamps)
    odometry, odometry_how = (None, "left out (--no-odometry)")
    if not no_odometry:
        odometry, odometry_how = carmen_odometry(c, str(log), mounting)
    warn_cut(c.cut, log)
    warn_stamps(c.stamps, "scan stamps")
    warn_stamps(c.odom_stamps, "ODOM stamps")
    T = np.array([make_T(rotvec_to_R([0.0, 0.0, th]), [x, y, 0.0]) for x, y, th in c.laser_poses])
    stamps_s = np.array([s.stamp_s for s in c.scans], dtype=float)
    source = {
        "carmen_log": str(log),
        "laser_lines": len(c.scans),
        "other_lines": c.skipped_lines,
        "stamps": c.stamps.record(stamps) if c.stamps else {"mode": stamps},
        "odometry": odometry_how,
    }
    if c.cut is not None:
        source["incomplete_last_line"] = c.cut.line
    write_sequence(
        output,
        log.name,
        c.scans,
        [],
        None,
        source,
        force=force,
        groundtruth_tum=tum_text(Trajectory(T, stamps_s)),
        odometry=odometry,
    )
    if as_json:
        doc = {
            "output": str(output),
            "scans": len(c.scans),
            "groundtruth": "groundtruth.tum",
            "other_lines_skipped": c.skipped_lines,
            "other_lines_by_kind": c.skipped_kinds,
            "duration_s": float(stamps_s[-1] - stamps_s[0]) if len(stamps_s) else 0.0,
            "stamps_repaired": c.stamps.repaired if c.stamps else 0,
            "odometry": odometry_how if odometry is not None else None,
        }
        click.echo(json.dumps(doc, indent=1))
        return
    click.echo(
        f"wrote {output}/: {len(c.scans)} scans, groundtruth.tum"
        + (f", odometry.tum ({odometry_how})" if odometry is not None else "")
        + f"; {c.skipped_lines} other lines skipped"
        + (f" ({kinds})" if (kinds := _kinds(c.skipped_kinds)) else "")
    )


def _kinds(counts: dict[str, int], most: int = 6) -> str:
    """The skipped lines' kinds, most first: "comment 7, TRUEPOS 5, ..."."""
    shown = [f"{k[:20] if k.isprintable() else ascii(k[:20])} {n}" for k, n in list(counts.items())[:most]]
    return ", ".join(shown) + (f", {len(counts) - most} more kinds" if len(counts) > most else "")
