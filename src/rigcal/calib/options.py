"""The solve's settings, each with its rule stated once.

``rigcal solve`` declares its options with these rules (as click types:
:func:`rigcal.cli.types.option_type`), and the Python API (``rigcal.solve_box``,
``rigcal.solve_board``) checks its keywords with the same objects (their ``check``), so a
value the command line refuses is refused by the API too, with the same limits.
:func:`box_settings` turns the box method's options into the solver's
:class:`~rigcal.calib.box.solve.SolveSettings` for both.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from rigcal.io.validate import OneOf, Real, Whole

if TYPE_CHECKING:  # the solver is imported where used: ``rigcal --help`` stays instant
    from rigcal.calib.box.solve import SolveSettings

# How the noise is set: "auto" estimates it from the session and uses the estimates (the
# values given are reported beside them); "assumed" uses the values given.
NOISE_MODES = ("auto", "assumed")
# The refinement's robust losses (scipy.optimize.least_squares' names).
LOSSES = ("linear", "huber", "soft_l1", "cauchy")

# The RANSAC stage's inlier threshold (reprojection error, pixels).
THRESHOLD_PX = Real(min=0.1)
# The pick noise (1 sigma, pixels).
PICK_SIGMA_PX = Real(min=1e-3)
# The laser's range noise (1 sigma, metres).
RANGE_SIGMA_M = Real(min=1e-5)
# The board corners' noise (1 sigma, pixels), as a board session's board.corner_sigma_px.
CORNER_SIGMA_PX = Real(min=0.0, min_open=True)
# RANSAC's seed (numpy's generators take any integer >= 0).
SEED = Whole(min=0)
NOISE = OneOf(NOISE_MODES)
# The refinement's robust loss.
LOSS = OneOf(LOSSES)

DEFAULT_THRESHOLD_PX = 6.0
DEFAULT_PICK_SIGMA_PX = 1.0


def box_settings(
    *,
    threshold_px: float = DEFAULT_THRESHOLD_PX,
    seed: int = 0,
    pick_sigma_px: float = DEFAULT_PICK_SIGMA_PX,
    loss: str = "cauchy",
    paper_endpoints: bool = False,
    noise: str = "auto",
) -> SolveSettings:
    """The box method's solver settings from ``rigcal solve``'s options (checked by the
    caller: click for the command line, the types' ``check`` for the API)."""
    from rigcal.calib.box.ransac import RansacParams
    from rigcal.calib.box.refine import NoiseModel, RefineParams
    from rigcal.calib.box.solve import SolveSettings

    return SolveSettings(
        ransac=RansacParams(threshold_px=threshold_px, seed=seed),
        refine=RefineParams(use_side_points=not paper_endpoints, loss=loss),
        noise=NoiseModel(pick_sigma_px=pick_sigma_px),
        noise_mode=noise,
    )
