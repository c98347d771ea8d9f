"""From a picking file to a rig and its report: the library side of ``rigcal solve``.

Data flow: picking file -> :func:`rigcal.calib.box.picks.read_picks` -> :class:`CalibProblem`
-> :func:`rigcal.calib.box.solve.solve` -> report + :class:`~rigcal.rig.Rig` -> writers
(:mod:`rigcal.viz.report_dir`, :func:`rigcal.rigfile.write_rig`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from rigcal.calib.box.picks import BoxObservation, PickSession, read_picks
from rigcal.calib.box.solve import CalibProblem, CalibResult, FloatArray, SolveSettings, solve
from rigcal.calib.report import build_report, rig_uncertainty
from rigcal.calib.truth import read_truth
from rigcal.rig import Rig
from rigcal.rigfile import provenance


@dataclass(frozen=True)
class Calibration:
    """A finished calibration: the session, the solve, its report and the rig to write."""

    session: PickSession
    result: CalibResult
    report: dict[str, Any]
    rig: Rig


def calibrate(
    picks_path: str | Path,
    settings: SolveSettings | None = None,
    truth_path: str | Path | None = None,
    command: str = "",
    range_sigma_m: float | None = None,
) -> Calibration:
    """Read a picking file, solve, and build the report and the rig
    (:func:`calibrate_session` on the file's session).

    Raises:
        InputError: bad picking file or any file it names, or a bad truth file.
        CalibrationError: the data cannot determine a calibration.
    """
    T_truth = read_truth(truth_path) if truth_path is not None else None
    session = read_picks(picks_path)
    return calibrate_session(
        session,
        settings,
        T_truth,
        command,
        range_sigma_m,
        inputs=session.input_files(),
        base=Path(picks_path).resolve().parent,
    )


def calibrate_session(
    session: PickSession,
    settings: SolveSettings | None = None,
    T_truth: FloatArray | None = None,
    command: str = "",
    range_sigma_m: float | None = None,
    *,
    inputs: Sequence[Path] = (),
    base: Path | None = None,
) -> Calibration:
    """Solve a session (read from a picking file, or built in memory by the Python API),
    and build the report and the rig: the one box-target solve path of ``rigcal solve``
    and ``rigcal.solve_box``.

    The laser's range noise is ``range_sigma_m`` when given, else the session's
    ``laser.range_sigma_m`` when it has one, else ``settings.noise.range_sigma_m`` (the
    board method's rule, :func:`rigcal.calib.board.calibrate.calibrate_board`).

    Args:
        inputs, base: the files the session was read from and their folder, for the
            rig's provenance (none for a session built in memory).

    Raises:
        CalibrationError: the data cannot determine a calibration.
    """
    settings = settings or SolveSettings()
    if range_sigma_m is None and "range_sigma_m" in session.laser:
        range_sigma_m = float(session.laser["range_sigma_m"])  # validated by read_picks
    if range_sigma_m is not None:
        settings = replace(settings, noise=replace(settings.noise, range_sigma_m=max(range_sigma_m, 1e-5)))
    result = solve(CalibProblem(session.camera, session.observations, settings))
    report = build_report(result, T_truth)
    source = {"camera_source": str(session.camera_path.resolve())} if inputs else {}
    prov = provenance(
        command,
        list(inputs),
        {"method": "box-target (Algorithm 1)", **source, **settings.to_dict()},
        base=base,
    )
    laser = {**session.laser, **scanner_description(session.observations)}
    rig = box_rig(result, report, laser, prov)
    return Calibration(session, result, report, rig)


def box_rig(result: CalibResult, report: dict[str, Any], laser: dict[str, Any], prov: dict[str, Any]) -> Rig:
    """The rig of a box-target solve: its pose, covariance and residual summary."""
    s = report["summary"]
    return Rig(
        T_cam_laser=result.T_cam_laser,
        camera=result.problem.camera,
        covariance=result.covariance,
        laser=laser,
        residuals={
            k: s[k] for k in ("captures", "captures_used", "box_ends", "inlier_ends", "rms_px", "median_px")
        }
        | {"max_px": s["max_px"], "residual_scale": s["residual_scale"]},
        provenance=prov,
        uncertainty=rig_uncertainty(result.covariance_model, report["noise"], report["uncertainty"]),
    )


def scanner_description(observations: Sequence[BoxObservation]) -> dict[str, Any]:
    steps = [o.beam_step_rad for o in observations if o.beam_step_rad > 0]
    return {"angle_increment_deg": round(float(np.degrees(np.median(steps))), 6)} if steps else {}
