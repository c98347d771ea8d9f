"""``rigcal intrinsics``: camera intrinsics from chessboard images (OpenCV detection, mrcal solve)."""

from __future__ import annotations

import json
from pathlib import Path

import click

from rigcal.cli.options import board_options, force_option, json_option, output_option
from rigcal.cli.types import GridSize, Real


def _lensmodel(ctx: click.Context, param: click.Parameter, value: str) -> str:
    """An unknown lens model is a usage error, found before any image is read."""
    from rigcal.calib.intrinsics import check_lensmodel
    from rigcal.errors import InputError

    try:
        return check_lensmodel(value, "--lensmodel")
    except InputError as exc:
        raise click.BadParameter(str(exc).split(": ", 1)[1]) from None


@click.command("intrinsics")
@click.argument("images", nargs=-1, type=click.Path(path_type=Path))
@board_options
@click.option(
    "--corners",
    "corners_file",
    type=click.Path(path_type=Path),
    help="Use pre-detected corners (mrcal corners.vnl: filename x y level) instead of detecting.",
)
@click.option(
    "--imagersize",
    type=GridSize("640x480"),
    help="WxH of the images, with --corners when the images are not given (e.g. 640x480).",
)
@click.option(
    "--lensmodel",
    default="LENSMODEL_OPENCV8",
    show_default=True,
    callback=_lensmodel,
    help="mrcal lens model, e.g. LENSMODEL_OPENCV5, LENSMODEL_OPENCV8, "
    "LENSMODEL_SPLINED_STEREOGRAPHIC_order=3_Nx=16_Ny=12_fov_x_deg=100.",
)
@click.option("--focal-px", type=Real(min=1.0), help="Rough focal length for the seed [image width].")
@output_option("The .cameramodel to write.")
@click.option(
    "--save-corners", type=click.Path(path_type=Path), help="Also write the detected corners (corners.vnl)."
)
@force_option("Overwrite existing outputs.")
@json_option("Print the result as JSON on stdout.")
def intrinsics(
    images: tuple[Path, ...],
    board: tuple[int, int] | None,
    charuco: tuple[int, int] | None,
    marker_m: float | None,
    dictionary: str,
    square_m: float,
    corners_file: Path | None,
    imagersize: tuple[int, int] | None,
    lensmodel: str,
    focal_px: float | None,
    output: Path,
    save_corners: Path | None,
    force: bool,
    as_json: bool,
) -> None:
    """Calibrate a camera's intrinsics from IMAGES of a chessboard or ChArUco board.

    Corners are found with OpenCV (or read from --corners), and the lens model is fitted by
    mrcal with outlier rejection. Writes a mrcal .cameramodel (which rig files and picking
    files can use) holding the solve, and prints the RMS and worst reprojection errors,
    per-image RMS, outliers, and mrcal's projection uncertainty at the centre and corners.

    \b
    Examples:
      rigcal intrinsics calib/*.jpg --board 9x6 --square-m 0.025 -o camera.cameramodel
      rigcal intrinsics calib/*.png --board 10x7 --square-m 0.03 --lensmodel LENSMODEL_OPENCV5 \\
          -o cam.cameramodel --save-corners corners.vnl --json
      rigcal intrinsics --corners corners.vnl --imagersize 640x480 --board 9x6 --square-m 0.025 \\
          -o camera.cameramodel
      rigcal intrinsics shots/*.png --charuco 8x6 --square-m 0.04 --marker-m 0.03 -o cam.cameramodel
    """
    from rigcal.calib.intrinsics import (
        Board,
        CharucoBoard,
        detect_charuco,
        detect_corners,
        other_board_sizes,
        read_corners_vnl,
        solve_intrinsics,
        write_corners_vnl,
    )
    from rigcal.io.files import atomic_write_text, check_writable

    if (board is None) == (charuco is None):
        raise click.UsageError("give exactly one of --board WxH (chessboard) and --charuco WxH (ChArUco)")
    wxh = "x".join(map(str, board or charuco or ()))  # the board's size as given, for the messages
    charuco_board = None
    if charuco is not None:
        if marker_m is None:
            raise click.UsageError("--charuco needs --marker-m")
        sx, sy = charuco
        try:
            charuco_board = CharucoBoard(sx, sy, square_m, marker_m, dictionary)
        except ValueError as exc:
            raise click.UsageError(str(exc)) from None
        charuco_board.opencv()  # checks the dictionary name
        spec = charuco_board.grid
    else:
        assert board is not None
        w_n, h_n = board
        spec = Board(w_n, h_n, square_m)
    sources = [*images, *([corners_file] if corners_file else [])]
    check_writable(output, force, sources)
    if save_corners is not None:
        check_writable(save_corners, force, [*sources, output])
    if corners_file is not None:
        if imagersize is not None:
            size = imagersize
        elif images:
            from rigcal.io.images import image_size

            size = image_size(images[0])
        else:
            raise click.UsageError("with --corners, give --imagersize WxH or one of the images")
        det = read_corners_vnl(corners_file, spec, size)
    else:
        if not images:
            raise click.UsageError("give the chessboard images, or --corners")
        det = (
            detect_charuco(list(images), charuco_board)
            if charuco_board
            else detect_corners(list(images), spec)
        )
    for name in det.missing:
        click.echo(f"board not found in {name}", err=True)
    hint = ""
    if det.missing and charuco_board is None and corners_file is None:
        found = other_board_sizes([Path(p) for p in det.missing], spec)
        if found:
            name, (w, h) = next(iter(found.items()))
            hint = (
                f"a {w}x{h} chessboard is detected in {name} (--board counts inner corners per row x column)"
            )
            click.echo(f"board {wxh} not found in {len(det.missing)} images; {hint}", err=True)
    from rigcal.calib.intrinsics import MIN_IMAGES
    from rigcal.errors import CalibrationError

    if len(det.paths) < MIN_IMAGES and hint:
        raise CalibrationError(
            f"the {wxh} board was found in {len(det.paths)} image(s), {MIN_IMAGES} are needed; {hint}"
        )
    result = solve_intrinsics(det, spec, lensmodel, focal_px)
    what = f"board {wxh}" if board else f"ChArUco {wxh} ({dictionary})"
    text = _model_text(result.model, f"rigcal intrinsics: {len(det.paths)} images, {what}, {square_m:g} m")
    atomic_write_text(output, text, force=force)
    if save_corners is not None:
        atomic_write_text(save_corners, write_corners_vnl(det), force=force)
    from rigcal.calib.report import intrinsics_report

    doc, table = intrinsics_report(result, det, output)
    if as_json:
        click.echo(json.dumps(doc, indent=1))
        return
    click.echo(table)
    for message in result.warnings:
        click.echo(f"warning: {message}", err=True)
    click.echo(f"wrote {output}", err=True)


def _model_text(model: object, note: str) -> str:
    import io

    buf = io.StringIO()
    model.write(buf, note=note)  # type: ignore[attr-defined]
    return buf.getvalue()
