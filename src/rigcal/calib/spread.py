"""Uncertainty from the data: the spread over captures and the pull of the noise settings.

A covariance from the normal equations is only as honest as the noise model behind it;
where the data hold errors the model lacks (a range bias by incidence, a warped board, a
lens model that is slightly off), every capture agrees less with the others than the model
says, and the covariance is too small. Two checks that hold on data never seen before sit
beside it:

- **leave-one-capture-out** (jackknife): re-solve once without each capture, starting
  from the full solution; the jackknife covariance of the C re-solves,
  (C - 1)/C sum (x_i - mean)(x_i - mean)^T, in the covariance's tangent space
  (R_i = Exp(d_i) R, t_i = t + e_i), estimates the estimate's spread whatever the noise
  really is. With few captures each one has a large leverage (6 parameters from 10-20
  captures) and the jackknife over-states the spread (by about 1 / (1 - leverage)), so it
  is compared with what it would be if the noise model were right: the same jackknife of
  the linearised solve under the model's own noise (:func:`expected_jackknife`). Their
  ratio is ``scale``, sqrt(trace(C_model^-1 C_jack) / trace(C_model^-1 E[C_jack])), about
  1 when the model is right; the spread reported is the jackknife corrected by the same
  leverage factor. Where the spread exceeds the model clearly (``scale`` above
  SPREAD_INFLATE_RATIO), the reported covariance is the model's times scale^2, so the rig
  file's uncertainty covers what the captures show.
- **sensitivity** to the noise settings: re-solve with each assumed noise halved and
  doubled and report how far the answer moves, in degrees, millimetres and sigmas. An
  answer that moves by more than its sigma when a setting changes depends on the
  setting, not only on the data.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from rigcal.arrays import FloatArray
from rigcal.geometry import tangent_delta
from rigcal.stats import chi2_ppf, f_ppf

# A spread more than this many times the stated 1-sigma (scale) is warned about.
SPREAD_WARN_RATIO = 2.0
# Above this the covariance is scaled up to the spread; below it the spread is within what
# chance gives 10-20 captures under the model (its scale varies by about +-25 %).
SPREAD_INFLATE_RATIO = 1.5
# A setting that moves the answer by more than this many sigmas is warned about.
SENSITIVITY_WARN_SIGMAS = 1.0
# Fewer captures than this give no jackknife (too few re-solves to estimate a 6x6 spread).
MIN_JACKKNIFE_CAPTURES = 6


@dataclass(frozen=True)
class Spread:
    """Leave-one-capture-out spread of a solve.

    Attributes:
        captures: names of the captures left out in turn.
        shifts: (C, 6) how far leaving each out moves the answer (tangent space).
        covariance: (6, 6) the jackknife covariance, corrected for the captures' leverage.
        scale: the spread in units of the model's stated uncertainty (about 1 when the
            model is honest; see the module docstring).
        ratio_max: the same in the worst direction (sqrt of the largest eigenvalue of
            C_model^-1 C_spread).
    """

    captures: tuple[str, ...]
    shifts: FloatArray
    covariance: FloatArray
    scale: float
    ratio_max: float

    def most_influential(self, cov: FloatArray, k: int = 3) -> list[tuple[str, float, float, float]]:
        """The k captures whose removal moves the answer most, as (name, sigmas under
        ``cov``, degrees, mm)."""
        inv = np.linalg.inv(cov)
        m = np.sqrt(np.einsum("ci,ij,cj->c", self.shifts, inv, self.shifts))
        order = np.argsort(-m)[:k]
        return [
            (
                self.captures[i],
                float(m[i]),
                float(np.degrees(np.linalg.norm(self.shifts[i, :3]))),
                float(1000 * np.linalg.norm(self.shifts[i, 3:])),
            )
            for i in order
        ]

    def to_dict(self, cov: FloatArray) -> dict[str, object]:
        """Plain form for reports and rig files."""
        sig = np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))
        return {
            "method": "leave-one-capture-out (jackknife)",
            "captures": len(self.captures),
            "scale": round(self.scale, 4),
            "ratio_max": round(self.ratio_max, 4),
            "sigma_rotation_deg": [round(float(x), 5) for x in np.degrees(sig[:3])],
            "sigma_translation_mm": [round(float(x), 3) for x in 1000 * sig[3:]],
            "most_influential": [
                {
                    "capture": n,
                    "sigmas": round(s, 3),
                    "rotation_deg": round(d, 5),
                    "translation_mm": round(t, 3),
                }
                for n, s, d, t in self.most_influential(cov)
            ],
            "covariance": [[float(f"{x:.6e}") for x in row] for row in self.covariance],
        }


def expected_jackknife(blocks: Sequence[FloatArray]) -> FloatArray:
    """(6, 6) the expected jackknife covariance of a linear least-squares solve with unit
    noise, from each capture's whitened Jacobian rows (k_c, 6).

    Leaving capture i out moves the solution by B_i z, z the whitened noise:
    B_i = (I - J_i^T J_i)^-1 (J^T - J_i^T E_i) - I^-1 J^T, I = J^T J, E_i picking capture
    i's rows; E[C_jack] = (C - 1)/C sum (B_i - mean B)(B_i - mean B)^T.
    """
    J = np.concatenate(blocks)
    info = J.T @ J
    base = np.linalg.solve(info, J.T)
    B = []
    start = 0
    for b in blocks:
        rows = slice(start, start + len(b))
        start += len(b)
        Jt = J.T.copy()
        Jt[:, rows] = 0.0
        B.append(np.linalg.solve(info - b.T @ b, Jt) - base)
    Bs = np.array(B)
    D = Bs - Bs.mean(axis=0)
    C = len(blocks)
    out: FloatArray = (C - 1) / C * np.einsum("cin,cjn->ij", D, D)
    return out


def leave_one_out(
    refit: Callable[[int], FloatArray],
    T_ref: FloatArray,
    names: Sequence[str],
    cov_model: FloatArray,
    expected: FloatArray,
) -> Spread | None:
    """The jackknife over captures.

    Args:
        refit: i -> T re-solved without capture i (indices into ``names``).
        T_ref: the full solution.
        names: the captures that took part in the solve.
        cov_model: (6, 6) the model covariance to compare with.
        expected: (6, 6) the jackknife covariance the model predicts
            (:func:`expected_jackknife`, in the units of ``cov_model``).

    Returns:
        None with fewer than MIN_JACKKNIFE_CAPTURES captures.
    """
    C = len(names)
    if C < MIN_JACKKNIFE_CAPTURES:
        return None
    shifts = np.array([tangent_delta(refit(i), T_ref) for i in range(C)])
    centred = shifts - shifts.mean(axis=0)
    jack = (C - 1) / C * centred.T @ centred
    Li = np.linalg.inv(np.linalg.cholesky(cov_model))
    leverage = float(np.trace(Li @ expected @ Li.T)) / 6.0
    cov = jack / max(leverage, 1e-12)
    M = Li @ cov @ Li.T
    ev = np.linalg.eigvalsh(0.5 * (M + M.T))
    return Spread(
        tuple(names),
        shifts,
        0.5 * (cov + cov.T),
        float(np.sqrt(max(float(np.trace(M)) / 6.0, 0.0))),
        float(np.sqrt(max(float(ev[-1]), 0.0))),
    )


@dataclass(frozen=True)
class Sensitivity:
    """How far the answer moves when one noise setting is scaled.

    Attributes:
        setting: the setting's name (e.g. ``range_sigma_m``).
        factor: what it was multiplied by.
        value: the value used.
        rotation_deg, translation_mm: the move.
        sigmas: the move's Mahalanobis length under the reported covariance.
    """

    setting: str
    factor: float
    value: float
    rotation_deg: float
    translation_mm: float
    sigmas: float

    def to_dict(self) -> dict[str, object]:
        """Plain form for reports and rig files."""
        return {
            "setting": self.setting,
            "factor": self.factor,
            "value": float(f"{self.value:.6g}"),
            "rotation_deg": round(self.rotation_deg, 5),
            "translation_mm": round(self.translation_mm, 3),
            "sigmas": round(self.sigmas, 3),
        }


SENSITIVITY_FACTORS = (0.5, 2.0)


def sensitivity(
    refit: Callable[[str, float], FloatArray],
    settings: dict[str, float],
    T_ref: FloatArray,
    cov: FloatArray,
    factors: Sequence[float] = SENSITIVITY_FACTORS,
) -> list[Sensitivity]:
    """Re-solve with each setting scaled by each factor.

    Args:
        refit: (setting, value) -> T re-solved with that one setting changed.
        settings: the values used, by name.
        T_ref: the solution.
        cov: the reported covariance (for the moves in sigmas).
    """
    inv = np.linalg.inv(cov)
    out = []
    for name, value in settings.items():
        for f in factors:
            d = tangent_delta(refit(name, value * f), T_ref)
            out.append(
                Sensitivity(
                    name,
                    f,
                    value * f,
                    float(np.degrees(np.linalg.norm(d[:3]))),
                    float(1000 * np.linalg.norm(d[3:])),
                    float(np.sqrt(d @ inv @ d)),
                )
            )
    return out


def honest_covariance(cov_model: FloatArray, spread: Spread | None) -> FloatArray:
    """The model covariance, scaled up to cover the spread over captures where that is
    clearly larger (SPREAD_INFLATE_RATIO)."""
    if spread is None or spread.scale <= SPREAD_INFLATE_RATIO:
        return cov_model
    out: FloatArray = cov_model * max(1.0, spread.scale) ** 2
    return out


def propagated_covariance(
    changed: Callable[[FloatArray], FloatArray], T: FloatArray, values: FloatArray, cov: FloatArray
) -> FloatArray:
    """(6, 6) the covariance an answer inherits from inputs it took as exact (a camera's
    intrinsics, say) whose own (P, P) covariance ``cov`` is known: first-order propagation
    J cov J^T with central differences of a whole re-solve, the inputs moved by +-1 sigma
    along each principal axis of ``cov`` in turn (cov = sum_k s_k s_k^T, so
    J cov J^T = sum_k (J s_k)(J s_k)^T). Independent inputs are a diagonal ``cov``, each
    then moved alone.

    Args:
        changed: (P,) inputs -> the answer re-solved with them.
        T: (4, 4) the answer.
        values: (P,) the inputs as used; cov: (P, P) their covariance (zero rows: exact).
    """
    c = np.asarray(cov, dtype=float)
    diagonal = not np.any(c - np.diag(np.diag(c)))
    if diagonal:
        steps = [np.sqrt(v) * e for v, e in zip(np.diag(c), np.eye(len(c)), strict=True) if v > 0]
    else:
        evals, evecs = np.linalg.eigh(0.5 * (c + c.T))
        tiny = 1e-12 * max(float(evals[-1]), 0.0)
        steps = [np.sqrt(v) * evecs[:, k] for k, v in enumerate(evals) if v > tiny]
    out = np.zeros((6, 6))
    for s in steps:
        g = (tangent_delta(changed(values + s), T) - tangent_delta(changed(values - s), T)) / 2.0
        out += np.outer(g, g)
    return out


def few_dof_factor(dof: int, params: int = 6, level: float = 0.95) -> float:
    """The factor on a covariance whose noise scale was estimated from the data with ``dof``
    degrees of freedom, so that its chi-square bound (``params`` dof, ``level``) still
    covers the answer as often as it says.

    With the noise scale estimated, the squared Mahalanobis error divided by ``params`` is
    F-distributed (``params``, ``dof``), not chi-square / ``params`` (Student-t in one
    dimension): the factor is params * F_level(params, dof) / chi2_level(params). It is
    about 4.3 with 3 dof (5 board poses and a fitted range bias), 1.6 with 9, and tends to
    1 as the data grow. ``dof`` below 1 is taken as 1.
    """
    nu = max(int(dof), 1)
    return params * f_ppf(level, params, nu) / chi2_ppf(level, params)


def uncertainty_warnings(
    spread: Spread | None, sens: Sequence[Sensitivity], cov_model: FloatArray, what: str
) -> list[str]:
    """Warnings that say, in words, when the answer depends on captures or settings.

    Args:
        what: the noise model's assumptions, named in the advice (e.g. "range noise").
    """
    out = []
    if spread is not None and spread.scale > SPREAD_WARN_RATIO:
        worst = ", ".join(
            f"{n} ({s:.1f} sigma: {d:.3f} deg, {t:.1f} mm)"
            for n, s, d, t in spread.most_influential(cov_model)
        )
        out.append(
            f"your answer depends on which captures are used: leaving one out moves it "
            f"{spread.scale:.1f}x as far as the noise model's 1-sigma says (worst direction "
            f"{spread.ratio_max:.1f}x); it moves most without {worst}. The {what} does not "
            "explain the captures' disagreement (a systematic error: range bias, a warped "
            "target, camera model or picks); the covariance has been scaled up to cover it"
        )
    for s in sens:
        if s.sigmas > SENSITIVITY_WARN_SIGMAS:
            out.append(
                f"your answer depends on the settings: {s.setting} x{s.factor:g} ({s.value:.4g}) moves "
                f"it {s.rotation_deg:.3f} deg / {s.translation_mm:.1f} mm ({s.sigmas:.1f} sigma); "
                "the captures do not pin it down on their own: add captures with more varied target poses"
            )
    return out
