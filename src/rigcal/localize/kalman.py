"""Kalman filter fusion of laser, visual and wheel odometry (paper Section VI, Eq. (11)).

State S = [x, y, yaw, vx, vy, yaw_rate] (Eq. (11)): the laser's planar pose in the world
and its velocity, world frame. Process model: a constant-velocity particle driven by
white acceleration noise (Section VI: "the process model is that of a constant-velocity
particle").

Measurements: each odometry increment z = (dx, dy, dyaw) over [t0, t1], the motion in
the rig's frame at t0, with its covariance in that frame. The paper turns increments into
velocity measurements; a velocity measured over [t0, t1] and applied at t1 makes the
filter lag half a step behind a precise input (its heading most, in turns), which cost
the filter centimetres against ICP alone. Here the increment is measured as what it is,
a relative pose, by stochastic cloning (Roumeliotis and Burdick, ICRA 2002): at t0 the
filter appends a copy of its pose to the state, and at t1

    h(S) = ( R(yaw_t0)^T (p_t1 - p_t0),  yaw_t1 - yaw_t0 )

is compared with z (an extended Kalman filter update on the state with its clone); the
clone is dropped once no pending increment starts at t0. Inputs at different rates (ICP
at the laser's, VO at the camera's runs, wheel odometry at the scans') and overlapping
intervals are fused exactly so.

Covariances: the paper gives each input a fixed one (ICP's forward translation and
rotation weigh less than VO's, VO's cross-track less than ICP's). Beyond the paper each
step carries its own (``weights="covariance"``, the default): ICP's from its Hessian at
the solution, inflated along directions the walls do not constrain
(:func:`rigcal.localize.icp_covariance.icp_covariance`); VO's from its tracks' fit and the scale's
votes (:func:`rigcal.localize.vo.run_covariance`); the wheel odometry's from its fixed
noise model (:data:`WHEEL_SIGMAS`, a rate noise over the step's time). A well-constrained
ICP step then pins the pose and VO takes over along a corridor. ``weights="fixed"`` gives
every step the paper's fixed covariance (:data:`ICP_SIGMAS`, :data:`VO_SIGMAS`), with
ICP's degenerate steps and VO's runs without a scale open forward as before. With
``adapt`` (the default) each input's covariances are matched to its innovations (Mehra's
covariance matching, one scale factor per input), as a fit's covariance leaves out what
the fit cannot see. Three more remedies answer what the inputs' consistency against the
simulated truth showed (docs/localization.md, "Consistency of the inputs"): each of ICP's
and VO's steps has its own error and one it shares with the step before (ICP's steps a
scan, VO's runs a frame and a carried scale), both per axis from its measured variance
ratio and lag-1 correlation (``icp_own`` ... ``vo_shared``, :func:`_update`); a VO run
failing a chi-square innovation test, alone or with the runs before it (``gate``,
``gate_window``), is left out; and a VO run is fused only along directions where the
filter knows the motion less well than the run's error, shared part included
(``vo_weak_only``). VO's forward error has a longer memory than a two-run share: a
first-order Gauss-Markov part carried in the state (``vo_memory_s``, its time constant
from the lag-1/2/3 correlations: :func:`gauss_markov_fit`), its forward variance ratio
matched on line (``vo_forward_adapt``) and its forward innovations tested for whiteness
over the last runs (``vo_forward_window``), the forward motion of runs failing that test
left out. Those gates test a run against the filter's prediction, which has taken in VO's
earlier runs; the guard (``vo_guard``, :func:`_vo_guard`) compares VO with ICP alone: VO's
last chained runs against ICP's own steps chained over the same interval, per direction,
under both inputs' error models, VO left out along a direction where they disagree beyond
a chi-square point and ICP's Hessian constrains it (where ICP is degenerate, VO carries the
filter); VO's forward variance ratio is matched against ICP's steps over each run
(``vo_forward_reference``). With ``vo_pays`` (q*; :data:`VO_OPEN_ONLY` in the mode "icp-first") the
guard also leaves VO out along a direction where its chain's modelled variance over the
guard's longest window exceeds q* times ICP's (fusing cannot pay there: even the optimal
filter of two inputs of known errors is worse than the better one on about 45 % of
laps, benchmarks/bench_kf_fusion.py), unless ICP leaves it open.

Odometry-driven prediction (``drive="icp"``, ``rigcal localize --kf driven``; beyond the
paper): instead of the constant-velocity model, ICP's steps drive the prediction as its
control input (Thrun, Burgard and Fox, Probabilistic Robotics, 2005, Section 5.4), their
covariances, own and shared, its process noise (:class:`_Drive`); VO's runs and the wheel
odometry's steps are the measurements, under the same gates and error models. With no
other measurement accepted, the filter's path is ICP's.

The wheel odometry (where a sequence has it; beyond the paper) is the guard's third,
independent witness (``wheel_witness``, :class:`_WheelWitness`, :func:`_witness`):
calibrated against ICP (scale, heading drift per metre), its chain over the guard's
windows tells which of ICP and VO errs where they disagree, and VO is kept (ICP's path
loosened) or left out accordingly; and it is fused calibrated, forward and in yaw
(``wheel_calibrated``). Both are on in every mode but "fixed". The filter's path is
scored and written at the scans' stamps (:func:`path_at`), and ``smooth`` adds the
Rauch-Tung-Striebel backward pass (:class:`_Tape`).

The gyroscope (where a sequence has one; beyond the paper): its yaw turned over each
step of about :data:`GYRO_STEP_S` is a measurement of the yaw alone (:func:`gyro_increments`),
y = yaw_t1 - yaw_t0 + b (t1 - t0) + n, with the gyro's bias b a random-walk state
(:func:`_gyro_bias_walk`) and n its angle random walk, the standard error model of a
rate gyro (IEEE Std 952-1997, Annex C; Groves, Principles of GNSS, Inertial, and
Multisensor Integrated Navigation Systems, 2013, Section 4.4.6: white rate noise, a bias
and its random walk; :data:`GYRO_NOISE`, :data:`GYRO_BIAS_SIGMA`, :data:`GYRO_BIAS_WALK`).
The bias is learned where the rig stands still (``gyro_still_only``, :func:`_still`: ICP's
steps over the gyro's step all slower than :data:`GYRO_STILL_MPS`, :data:`GYRO_STILL_RAD_S`), a
zero-velocity update (Foxlin, "Pedestrian tracking with shoe-mounted inertial sensors", IEEE
CG&A 2005; Groves 2013, Section 15.3): there the true turn is zero and the gyro reads its
bias (``gyro_zero_turn``: its step's model the bias's part alone, unless the reading fails
:data:`GYRO_ZERO_TURN_GATE`), so a drive that begins standing still gives the bias before
the rig moves. Elsewhere the bias is a consider state of the gyro's steps (Schmidt 1966): its
uncertainty weighs them, but they do not move it (other updates move it only through its
correlation with the pose), as ICP's slow heading errors (over the lap) would
otherwise be learned as the gyro's bias (measured: docs/benchmarks.md, "A gyroscope as the
Kalman filter's third heading"). The gyro is also the guard's heading witness
(``gyro_witness``, :class:`_GyroWitness`, :func:`_witness`; on in "icp-first" alone), as the wheels
are its third witness: its yaw chained over the guard's windows, less the bias as learned
(its uncertainty in the test's variance), tells which of ICP and VO errs in yaw where one of
them is off the other two beyond both models (Bar-Shalom, Li and Kirubarajan 2001, Section
5.4, as above), and VO's yaw is kept (ICP's path loosened) or left out accordingly; with
``gyro_fused`` off its steps enter the filter only where the rig stands still (the bias), so
that the driven filters follow ICP unless the gyro and VO both find ICP's heading erring
(measured: docs/benchmarks.md, "The gyroscope as the guard's heading witness").

Options measured on the simulated laps and off in every mode (docs/localization.md): VO's
biases over seconds (``vo_bias_sigma``: a forward scale, a cross-track drift per metre and
a yaw-rate bias as Gauss-Markov states, :func:`_bias_decay`, learned against ICP by a
Schmidt update where the filter knows a run's motion better than the run,
:func:`_learn_bias`; :data:`VO_BIASED`) and the process noise at the level of the drive's
largest velocity change per scan (:data:`DRIVE_PROCESS`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from contextvars import ContextVar
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from rigcal.arrays import FloatArray
from rigcal.geometry import pose_of, se2
from rigcal.localize.icp_covariance import OPEN_SIGMA_M
from rigcal.stats import chi2_isf, chi2_sf

# The paper's fixed covariances (weights="fixed"), as 1-sigma rate noise in the rig's
# frame: forward (m/s), cross-track (m/s), yaw rate (rad/s); a step over dt seconds has
# 1-sigma sigma * dt.
ICP_SIGMAS = (0.10, 0.03, 0.05)
VO_SIGMAS = (0.03, 0.15, 0.02)
# Wheel odometry (beyond the paper; its noise model in both modes): its forward speed is
# good to a few percent of a walking pace, a wheeled base barely slides sideways, and its
# heading drifts most (wheel slip in turns).
WHEEL_SIGMAS = (0.05, 0.02, 0.08)
# OPEN_SIGMA_M (icp_covariance.py): 1-sigma (m) of a step's translation along a direction its input
# does not measure (an ICP step along a corridor whose ends are out of reach, a VO run
# without a scale).
# Kept for the rate form: forward rate noise (m/s) of a step that measures no forward speed.
OPEN_FORWARD_SIGMA = OPEN_SIGMA_M
# The gyroscope's error model (``KfParams.gyro_noise`` ... ``gyro_bias_walk``; the standard
# rate gyro model, module docstring): white rate noise (rad/s/sqrt(Hz): the angle random
# walk), the 1-sigma of the bias at the start (rad/s) and its random walk (rad/s/sqrt(s)).
# A MEMS gyro's datasheet figures, each twice the simulated gyro's
# (rigcal.sim.drive.GYRO_NOISE_DEG_S_RT_HZ ...) or more: the filter does not know the
# device better than its datasheet.
GYRO_NOISE = float(np.radians(0.01))
GYRO_BIAS_SIGMA = float(np.radians(0.2))
GYRO_BIAS_WALK = float(np.radians(0.001))
# The gyro's steps: its yaw turned over the scans' stamps at least this far apart (s).
GYRO_STEP_S = 0.1
# The rig stands still over a gyro step (its bias learned there: ``KfParams.gyro_still_only``)
# where every ICP step within it moved slower than these (m/s, rad/s): a standing rig's ICP
# steps move by their noise (on the simulated laps' stops, 25 ms steps: 0.04 m/s, 0.45 deg/s
# median, 1 deg/s at the 90th percentile), a walking one's by centimetres (0.5-1 m/s). The
# bias is learned against ICP's yaw there, whatever it measured.
GYRO_STILL_MPS = 0.1
GYRO_STILL_RAD_S = float(np.radians(3.0))
# A still step's zero-turn update (``KfParams.gyro_zero_turn``) is made where the gyro's
# reading less the bias it predicts passes the chi-square test at this point (1 dof,
# 0.001); beyond it (a slow turn ICP's steps did not tell from standing), the step is
# taken against ICP's turn as any other.
GYRO_ZERO_TURN_GATE = float(chi2_isf(0.001, 1))
WEIGHTS = ("covariance", "fixed")
# The prediction (``KfParams.drive``): the constant-velocity process model ("", Section VI)
# or driven by an input's steps ("icp": the laser odometry as the control input).
DRIVES = ("", "icp")
# Covariance matching (``KfParams.adapt``): an input's covariance is scaled up by the
# running mean (over about ADAPT_WINDOW steps) of its innovations' NIS per dimension when
# that exceeds 1; a single innovation counts at most NIS_CAP (an outlier step).
ADAPT_WINDOW = 50
NIS_CAP = 25.0
# Each input's error model (``KfParams.icp_own`` ... ``vo_shared``, :func:`_update`): a
# step's error e_k = w_k + s_k -/+ s_(k-1), w_k its own, s_j the part two consecutive steps
# share, both per axis (x or forward, y or cross-track, yaw in the step's frame) as
# fractions of the step's covariance C_k (each axis's standard deviation scaled by the
# fraction's square root). Then e_k has (own + 2 shared) C_k and consecutive steps
# correlate by -/+ shared / (own + 2 shared). Both come from two figures per axis of each
# input measured on laps 1-2 of each loop (benchmarks/bench_kf.py --consistency,
# docs/benchmarks.md): its steps' squared errors over their variance against the truth
# (mean; 1 if C_k were honest) and consecutive steps' error correlation. ICP: its
# translation errs by 2.3 times its Hessian's variance, its yaw by 0.9; consecutive steps
# share a scan, as data of one and model of the next, so with opposite signs. VO (runs
# passing :data:`VO_GATE`): forward 0.7 (its scale's votes are pessimistic), cross-track
# 3.1, yaw 2.7; consecutive runs share the frame between them, its tracks and the scale a
# run carries from the one before, so with the same sign (forward +0.57, beyond the 0.5 a
# two-step share can give, taken as :data:`MAX_LAG1`).
ICP_VARIANCE_RATIO, ICP_LAG1 = (2.29, 2.28, 0.92), (-0.37, -0.26, -0.27)
VO_VARIANCE_RATIO, VO_LAG1 = (0.72, 3.06, 2.74), (0.57, 0.28, 0.34)
# A two-step share gives consecutive errors a correlation of at most 0.5 (own error 0);
# beyond this the share is taken at it, leaving the step a tenth of its error its own.
MAX_LAG1 = 0.45
Axes = tuple[float, float, float]


def shared_error_fractions(ratio: Axes, lag1: Axes) -> tuple[Axes, Axes]:
    """An input's (own, shared) fractions per axis of its steps' covariance from its steps'
    measured variance ratio (squared error over the covariance's variance, per axis) and
    consecutive steps' error correlation ``lag1`` per axis (|lag1| at most
    :data:`MAX_LAG1`): own + 2 shared = ratio, shared = |lag1| ratio."""
    r = np.asarray(ratio, dtype=float)
    rho = np.minimum(np.abs(np.asarray(lag1, dtype=float)), MAX_LAG1)
    if r.shape != (3,) or rho.shape != (3,) or not (r > 0).all():
        raise ValueError(
            f"variance ratios {ratio} and lag-1 correlations {lag1}: expected three each, ratios > 0"
        )
    shared = rho * r
    own = r - 2.0 * shared
    return (float(own[0]), float(own[1]), float(own[2])), (
        float(shared[0]),
        float(shared[1]),
        float(shared[2]),
    )


def _per_axis(v: float | Axes | FloatArray) -> FloatArray:
    """A fraction for every axis, or one per axis, as (3,)."""
    out: FloatArray = np.broadcast_to(np.asarray(v, dtype=float), (3,))
    return out


def gauss_markov_fit(lags: Sequence[float], run_s: float) -> tuple[float, float, float]:
    """A first-order Gauss-Markov error's (share, phi, time constant s) from an input's
    error correlation at lags 1, 2, 3 ... steps (``lags``) of ``run_s`` seconds each.

    An error made of an own white part and a Gauss-Markov part g (g_k = phi g_(k-1) +
    sqrt(1 - phi^2) n_k, unit variance) correlates at lag L by share x phi^L. log c_L =
    log share + L log phi is fitted by least squares over the leading positive
    correlations (Gelb, Applied Optimal Estimation, 1974, Section 3.8: the autocorrelation
    exp(-|dt| / tau)); the share is at most 1 - (1 - 2 MAX_LAG1), leaving a step a tenth
    of its error its own, as :func:`shared_error_fractions` does. No positive lag-1
    correlation: share 0."""
    c = np.asarray(lags, dtype=float)
    if c.ndim != 1 or len(c) < 2 or not np.isfinite(c).all() or not run_s > 0:
        raise ValueError(f"lag correlations {lags} over runs of {run_s} s: expected two or more, runs > 0 s")
    n = int(np.argmax(c <= 0)) if (c <= 0).any() else len(c)
    if n == 0:
        return 0.0, 0.0, 0.0
    if n == 1:  # one lag: phi = share = sqrt(c_1)
        phi = float(np.sqrt(min(c[0], 1.0)))
        share = phi
    else:
        slope, intercept = np.polyfit(np.arange(1, n + 1), np.log(c[:n]), 1)
        phi, share = float(np.exp(min(slope, 0.0))), float(np.exp(intercept))
    share = min(share, 2.0 * MAX_LAG1)
    tau = -run_s / float(np.log(phi)) if 0 < phi < 1 else (np.inf if phi >= 1 else 0.0)
    return share, phi, tau


ICP_OWN, ICP_SHARED = shared_error_fractions(ICP_VARIANCE_RATIO, ICP_LAG1)
VO_OWN, VO_SHARED = shared_error_fractions(VO_VARIANCE_RATIO, VO_LAG1)
# A VO run whose innovation's squared Mahalanobis distance (shared error included) exceeds
# this (chi-square, 3 degrees of freedom, 0.999) is left out (``KfParams.gate``): a wrong
# scale or track set.
VO_GATE = 16.27
# The same test on the last VO_WINDOW runs' distances summed (``KfParams.gate_window``;
# the chi-square point of 3 x VO_WINDOW degrees of freedom at the single gate's tail,
# 32.91 for 4 runs, derived in :func:`run_filter` from ``gate``): runs each within the
# gate that err together. The window spans the runs whose errors correlate (lags 1-3 on
# laps 1-2).
VO_WINDOW = 4
# VO is fused only along directions where the filter's own prediction of the run's motion
# is less certain than the run (generalised eigenvalue above this; ``KfParams.vo_weak_only``).
VO_WEAK_ONLY = 1.0
# VO's forward error's memory (``KfParams.vo_memory_s``, :func:`run_filter`): its runs'
# forward errors correlate beyond what a two-run share gives (laps 1-2: +0.57 at lag 1,
# +0.34 at lag 2, +0.17 at lag 3, over runs of 0.49 s; benchmarks/bench_kf.py
# --consistency). A first-order Gauss-Markov state fitted to them (:func:`gauss_markov_fit`)
# carries that part: 0.90 of the forward variance, 0.54 from one run to the next, a time
# constant of 0.80 s.
VO_FORWARD_LAGS, VO_RUN_S = (0.57, 0.34, 0.17), 0.49
VO_MEMORY_SHARE, VO_MEMORY_PHI, VO_MEMORY_S = gauss_markov_fit(VO_FORWARD_LAGS, VO_RUN_S)
# The whiteness test on VO's forward innovations (``KfParams.vo_forward_window``): under
# the model the filter's innovations are white, so the last W standardized forward
# innovations summed, squared and over W are chi-square with 1 dof; above its 0.999 point
# VO's forward motion is left out of the run (its cross-track and yaw still enter). W spans
# the runs the memory correlates (phi^W below 0.05: 5 runs).
VO_FORWARD_WINDOW = int(np.ceil(np.log(0.05) / np.log(VO_MEMORY_PHI)))
VO_FORWARD_GATE = chi2_isf(0.001, 1)
# The guard against VO where ICP knows better (``KfParams.vo_guard``, :class:`_IcpReference`,
# :func:`_vo_guard`): VO's last chained runs and ICP's own steps chained over the same
# interval are compared per direction of the run (forward, cross-track, yaw), the
# difference over its variance under both inputs' error models (VO's runs' correlations
# included); above the chi-square point (1 dof) the two disagree beyond their errors, and
# the run is left out along that direction unless ICP's own steps leave it open (its
# Hessian's degeneracy: :data:`OPEN_SIGMA_M`), where the difference's variance is ICP's
# open one and the test cannot fire: VO carries the filter. Windows of the last 1, 2, 4 and
# 8 runs (a single bad run shows over the short ones, a bias over the long ones; 8: the
# power of two spanning the runs the forward memory correlates, VO_FORWARD_WINDOW), each at
# the Bonferroni share of the 0.001 tail (:func:`_guard_gate`: 13.41).
VO_GUARD_RUNS = 2 ** int(np.ceil(np.log2(VO_FORWARD_WINDOW)))
VO_GUARD_LEVEL = 0.999
# VO only where it pays (``KfParams.vo_pays``, :func:`_vo_guard`): over the guard's longest
# window VO is left out along a direction where its chain's modelled variance exceeds q*
# times ICP's, unless ICP leaves the direction open. benchmarks/bench_kf_fusion.py: two
# odometries at the laps' error levels (laps 1-2), fused optimally with their true models,
# end above the better input on 42-48 % of laps at every ratio; following ICP does so only
# where VO is the better input (8 % at a window variance ratio of 3.5-4.8, 0.2 % at 31-44),
# fusing is ahead of following ICP on that count below a ratio of 0.7-0.9. VO_OPEN_ONLY:
# q* -> 0, VO only along ICP's open directions (the mode "icp-first").
VO_OPEN_ONLY = 1e-9
# The wheel odometry as the guard's witness (``KfParams.wheel_witness``, :class:`_WheelWitness`):
# its chain over a window, its scale and heading drift per metre calibrated against ICP's
# steps over the distance driven so far, once that is WHEEL_WITNESS_MIN_M (m); its
# covariance there the steps' rate covariances (:data:`WHEEL_SIGMAS`) times the variance
# ratio per axis (forward, cross-track, yaw) its calibrated chain showed against the truth
# over windows of 1, 2, 4 and 8 VO runs (the guard's) on laps 1-2 of each loop (mean
# squared error over the rate model's variance; benchmarks/bench_kf.py --wheel-windows).
# Forward the rate model is pessimistic over short windows (0.09: a wheel's distance noise
# is a fraction of the step, not a rate) and the calibration's scale shows over 8 runs (4.0);
# cross-track grows from 3.5 to 140 times the model with the window, the lever arm of the
# heading's drift, which a sum of the steps' covariances leaves out. The axes are those of
# the frame at the window's end.
WHEEL_WITNESS_MIN_M = 5.0
# The scale's blocks (m of the wheels' distance): about a VO run at a walking pace, so that
# ICP's own error over one (about 2 %) stays below its error where it errs beyond its model.
WHEEL_BLOCK_M = 0.25
WHEEL_WINDOW_RATIO: tuple[Axes, ...] = (
    (0.090, 3.499, 1.238),
    (0.159, 9.605, 1.232),
    (0.503, 33.364, 1.310),
    (4.004, 140.223, 1.358),
)
# VO's errors over seconds (``KfParams.vo_bias_sigma``, ``vo_bias_s``; :func:`_bias_decay`):
# a forward scale factor (its runs' forward error over their forward motion), a cross-track
# drift per metre forward (a small turn of the camera's motion into the laser's frame) and
# a yaw-rate bias (rad/s), each a first-order Gauss-Markov state. On laps 1-2 of each loop
# (benchmarks/bench_kf.py --bias-fit, VO's runs against the truth) these series
# correlate over 3-16 runs (1.5-8 s), not only over the 1-3 runs the shares and the forward
# memory model; :func:`gauss_markov_fit` to their correlations at lags 1 ... gives each
# state's share of the series' mean square (sigma = rms x sqrt(share)) and time constant.
# Carried in the state, a bias is learned where ICP constrains the motion (:func:`_learn_bias`)
# and VO's runs are corrected by it. Off by default (``KfParams.vo_bias_sigma`` zero; on:
# :data:`VO_BIASED`): on the twenty simulated laps it brought no lap to its best input and
# worsened the means (docs/benchmarks.md, "The Kalman filter over ten laps of both loops").
VO_BIAS_RMS = (0.005509, 0.002798, 0.0008952)
VO_BIAS_LAGS = (
    (0.32, 0.24, 0.16, 0.20, 0.11, 0.07, 0.04, 0.02, -0.00),
    (0.14, 0.08, 0.10, 0.14, 0.11, 0.09, 0.09, 0.09, 0.07, 0.06, 0.02, 0.02, 0.08, 0.11, 0.08, 0.02),
    (0.28, 0.12, 0.10, 0.11, 0.11, 0.08, 0.01, -0.01),
)
_BIAS_FITS = [gauss_markov_fit(lags, VO_RUN_S) for lags in VO_BIAS_LAGS]
VO_BIAS_SIGMA: Axes = (
    VO_BIAS_RMS[0] * float(np.sqrt(_BIAS_FITS[0][0])),
    VO_BIAS_RMS[1] * float(np.sqrt(_BIAS_FITS[1][0])),
    VO_BIAS_RMS[2] * float(np.sqrt(_BIAS_FITS[2][0])),
)
VO_BIAS_S: Axes = (float(_BIAS_FITS[0][2]), float(_BIAS_FITS[1][2]), float(_BIAS_FITS[2][2]))
# The process noise matched to the drive (:data:`DRIVE_PROCESS`): the simulated drives'
# velocity changes in steps (laps 1-2, the truth's velocity over each 25 ms scan: half of
# the changes 0, 99 % below 0.06 m/s^1.5, the largest 5.1 / 3.0 m/s^1.5 in x / y and 4.7
# rad/s^1.5 in yaw, over sqrt(dt); benchmarks/bench_kf.py --drive-stats). A white
# acceleration of 0.5 m/s^2 makes such a step a 10-sigma event, which the prediction
# then smooths over many scans; at the largest step's level (1 sigma) the prediction never
# outweighs a step ICP measured. Not the default: see :data:`VO_BIASED`'s note.
DRIVE_ACCEL_SIGMA, DRIVE_YAW_ACCEL_SIGMA = 5.1, 4.7
# The share of each axis's per-run error the bias takes: a run's own and shared parts are
# scaled by 1 - share there, so that its error in all stays what laps 1-2 measured.
VO_BIAS_SHARE: Axes = (float(_BIAS_FITS[0][0]), float(_BIAS_FITS[1][0]), float(_BIAS_FITS[2][0]))


@dataclass(frozen=True)
class Increment:
    """One odometry step: the motion (dx m, dy m, dyaw rad) from t0 to t1 in the rig's
    frame at t0, its covariance (3, 3) in that frame (m^2, m rad, rad^2) and the input it
    came from ("icp", "vo", "wheel")."""

    t0: float
    t1: float
    motion: FloatArray
    covariance: FloatArray
    source: str = ""


@dataclass(frozen=True)
class KfParams:
    """Process noise: white acceleration (m/s^2) and angular acceleration (rad/s^2);
    ``drive``: "" (the constant-velocity process model, Section VI) or the input whose
    steps drive the prediction ("icp": odometry-driven, :class:`_Drive`); ``weights``:
    each step's own covariance ("covariance") or the paper's fixed ones ("fixed");
    ``adapt``: scale each input's covariances up by its innovations' running NIS where
    that exceeds 1 (covariance matching: :data:`ADAPT_WINDOW`); ``vo_guard``: the VO runs
    compared with ICP's own steps over the same interval (:data:`VO_GUARD_RUNS`; 0: no
    guard); ``wheel_input``: the wheel odometry's steps (where given) fused as
    measurements; ``wheel_witness``: the wheel odometry (where given) the guard's third
    witness (:class:`_WheelWitness`, :func:`_witness`; it acts with ``vo_guard``);
    ``wheel_calibrated``: the wheels' steps fused (with ``wheel_input``) calibrated against
    ICP's, forward and yaw (:meth:`_WheelWitness.calibrated_steps`), not as they come
    (both on in every mode but "fixed", the paper's, which fuses them as they come);
    ``smooth``: the forward pass followed by the Rauch-Tung-Striebel backward pass
    (:class:`_Tape`): each pose from all the lap's measurements, offline; ``gyro_noise``,
    ``gyro_bias_sigma``, ``gyro_bias_walk``: the gyroscope's error model (where its steps
    are given: :data:`GYRO_NOISE` ...); ``gyro_still_only``: its bias learned only where the
    rig stands still (:func:`_still`; False: from every step); ``gyro_zero_turn``: there
    against a zero turn (the rig stands, so the gyro reads its bias alone; a zero-velocity
    update) rather than against the turn ICP measured (False); ``gyro_witness``: the gyro
    (where given) the guard's heading witness (:class:`_GyroWitness`, :func:`_witness`; it
    acts with ``vo_guard``); ``gyro_fused``: its steps fused as yaw measurements (False: only
    those over which the rig stands still, its bias's zero-turn updates, enter the filter; the
    others serve the witness alone); ``gyro_where_icp_errs``: with ``gyro_fused`` off, the
    gyro's turn over a VO run over which it found ICP's yaw erring fused after the run
    (:func:`_convicted_turn`); ``anchored``: the causal path as the filter's relative
    estimates chained (:class:`_Anchor`), not its pose in the world (the smoothed path is
    the backward pass's either way)."""

    accel_sigma: float = 0.5
    yaw_accel_sigma: float = 1.0
    weights: str = "covariance"
    adapt: bool = True
    icp_own: float | Axes = ICP_OWN
    icp_shared: float | Axes = ICP_SHARED
    vo_own: float | Axes = VO_OWN
    vo_shared: float | Axes = VO_SHARED
    gate: float = VO_GATE
    gate_window: int = VO_WINDOW
    vo_weak_only: float = VO_WEAK_ONLY
    vo_memory_s: float = VO_MEMORY_S
    vo_memory_share: float = VO_MEMORY_SHARE
    vo_forward_adapt: bool = True
    vo_forward_window: int = VO_FORWARD_WINDOW
    vo_guard: int = VO_GUARD_RUNS
    vo_forward_reference: bool = True
    vo_pays: float = 0.0
    vo_bias_sigma: Axes = (0.0, 0.0, 0.0)
    vo_bias_s: Axes = VO_BIAS_S
    vo_bias_share: Axes = (0.0, 0.0, 0.0)
    drive: str = ""
    wheel_input: bool = True
    wheel_witness: bool = True
    wheel_calibrated: bool = True
    smooth: bool = False
    gyro_noise: float = GYRO_NOISE
    gyro_bias_sigma: float = GYRO_BIAS_SIGMA
    gyro_bias_walk: float = GYRO_BIAS_WALK
    gyro_still_only: bool = True
    gyro_zero_turn: bool = True
    gyro_witness: bool = False
    gyro_fused: bool = True
    gyro_where_icp_errs: bool = False
    anchored: bool = False

    def __post_init__(self) -> None:
        if self.weights not in WEIGHTS:
            raise ValueError(f"weights {self.weights!r}: expected one of {', '.join(WEIGHTS)}")
        if self.drive not in DRIVES:
            raise ValueError(f"drive {self.drive!r}: expected one of {', '.join(map(repr, DRIVES))}")
        if not (self.accel_sigma > 0 and self.yaw_accel_sigma > 0):
            raise ValueError("accel_sigma and yaw_accel_sigma must be > 0")
        for name in ("icp_own", "icp_shared", "vo_own", "vo_shared"):
            v = _per_axis(getattr(self, name))
            if not ((v > 0).all() if name.endswith("own") else (v >= 0).all()):
                raise ValueError(
                    f"{name} {getattr(self, name)}: expected {'> 0' if name.endswith('own') else '>= 0'}"
                )
        if not (self.gyro_noise > 0 and self.gyro_bias_sigma >= 0 and self.gyro_bias_walk >= 0):
            raise ValueError(
                f"gyro_noise {self.gyro_noise}, gyro_bias_sigma {self.gyro_bias_sigma}, gyro_bias_walk "
                f"{self.gyro_bias_walk}: expected noise > 0, the bias's sigmas >= 0"
            )
        if self.gate_window < 1:
            raise ValueError(f"gate_window {self.gate_window}: expected at least 1 run")
        if not self.vo_memory_s >= 0:
            raise ValueError(f"vo_memory_s {self.vo_memory_s}: expected >= 0 s (0: no memory state)")
        if not 0 <= self.vo_memory_share < 1:
            raise ValueError(f"vo_memory_share {self.vo_memory_share}: expected in [0, 1)")
        if self.vo_forward_window < 0:
            raise ValueError(f"vo_forward_window {self.vo_forward_window}: expected >= 0 runs (0: no test)")
        if self.vo_guard < 0:
            raise ValueError(f"vo_guard {self.vo_guard}: expected >= 0 runs (0: no guard)")
        if not self.vo_pays >= 0:
            raise ValueError(f"vo_pays {self.vo_pays}: expected >= 0 (0: no rule; it acts with vo_guard)")
        sigma, tau = np.asarray(self.vo_bias_sigma, dtype=float), np.asarray(self.vo_bias_s, dtype=float)
        share = np.asarray(self.vo_bias_share, dtype=float)
        if (
            sigma.shape != (3,)
            or tau.shape != (3,)
            or share.shape != (3,)
            or not ((sigma >= 0).all() and (tau[sigma > 0] > 0).all() and ((share >= 0) & (share < 1)).all())
        ):
            raise ValueError(
                f"vo_bias_sigma {self.vo_bias_sigma}, vo_bias_s {self.vo_bias_s}, vo_bias_share "
                f"{self.vo_bias_share}: expected three each, sigmas >= 0 (0: no bias state on that "
                "axis), time constants > 0 s, shares in [0, 1)"
            )


# ``rigcal localize --kf``: the filter by name. "weighted": each step's own covariance,
# matched to its input's innovations (the default); "fixed": the paper's filter, every
# step with its input's fixed covariance (Section VI), nothing adapted.
KF_MODES = {
    "weighted": KfParams(),
    "fixed": KfParams(
        weights="fixed",
        adapt=False,
        icp_own=1.0,
        icp_shared=0.0,
        vo_own=1.0,
        vo_shared=0.0,
        gate=0.0,
        gate_window=1,
        vo_weak_only=0.0,
        vo_memory_s=0.0,
        vo_forward_adapt=False,
        vo_forward_window=0,
        vo_guard=0,
        vo_forward_reference=False,
        vo_bias_sigma=(0.0, 0.0, 0.0),
        wheel_witness=False,
        wheel_calibrated=False,
    ),
}
# The weighted filter with VO's bias states (:data:`VO_BIAS_SIGMA`), and with the process
# noise of the drive (:data:`DRIVE_ACCEL_SIGMA`): measured options, not modes of the CLI.
VO_BIASED = dataclasses.replace(
    KF_MODES["weighted"], vo_bias_sigma=VO_BIAS_SIGMA, vo_bias_share=VO_BIAS_SHARE
)
DRIVE_PROCESS = dataclasses.replace(
    KF_MODES["weighted"], accel_sigma=DRIVE_ACCEL_SIGMA, yaw_accel_sigma=DRIVE_YAW_ACCEL_SIGMA
)
# "driven": the weighted filter with ICP's steps as the prediction's control input
# (:func:`run_filter`, ``KfParams.drive``); VO and the wheels are its measurements.
KF_MODES["driven"] = KfParams(drive="icp")
# "icp-first": the driven filter with VO only where ICP leaves the direction open
# (``vo_pays`` at :data:`VO_OPEN_ONLY`): where ICP constrains the motion the path is ICP's
# steps chained; along a corridor ICP cannot fix, VO carries it (docs/localization.md,
# "VO only where it pays"). A gyroscope (where given) is the guard's heading witness and
# not fused (``gyro_witness``, ``gyro_fused``): ICP's heading is left to ICP unless the gyro
# and VO both find it erring (at most its best input on 10 of 10 standstill laps, against
# 6 of 10 with the gyro fused: docs/benchmarks.md, "The gyroscope as the guard's heading
# witness").
KF_MODES["icp-first"] = KfParams(drive="icp", vo_pays=VO_OPEN_ONLY, gyro_witness=True, gyro_fused=False)


@dataclass(frozen=True)
class KfResult:
    """The filtered path: stamps (M,), poses (M, 3) after each update (the first: the
    origin at the earliest stamp) and their covariances (M, 3, 3) (x, y, yaw; world);
    VO's forward variance ratio as matched at the end (``KfParams.vo_forward_adapt``;
    otherwise as set) and the VO runs whose forward motion the whiteness test left out
    (``KfParams.vo_forward_window``); per direction (forward, cross-track, yaw) the VO runs
    the guard left out there (``KfParams.vo_guard``); VO's biases as estimated at the end
    (forward scale, cross-track per metre forward, yaw rate rad/s; ``KfParams.vo_bias_sigma``;
    None without them); the gyroscope's bias (rad/s) at the end and its 1-sigma, and the
    seconds of its steps it was learned from (those over which the rig stood still,
    :func:`_still`; NaN, NaN and 0 without gyro steps); the VO runs over which the gyro, as
    the guard's heading witness (``KfParams.gyro_witness``), found ICP's yaw erring and those
    over which it found VO's."""

    stamps_s: FloatArray
    poses: FloatArray
    covariances: FloatArray
    vo_forward_ratio: float = float("nan")
    vo_forward_left_out: int = 0
    vo_guarded: tuple[int, int, int] = (0, 0, 0)
    vo_bias: FloatArray | None = None
    icp_witnessed: tuple[int, int, int] = (0, 0, 0)
    gyro_bias: float = float("nan")
    gyro_bias_sigma: float = float("nan")
    gyro_still_s: float = 0.0
    gyro_witnessed: tuple[int, int] = (0, 0)


def gyro_increments(stamps_s: FloatArray, yaw_rad: FloatArray, noise: float = GYRO_NOISE) -> list[Increment]:
    """The gyroscope's steps: ``yaw_rad`` (K - 1,) the yaw it turned from each stamp of
    ``stamps_s`` (K,) to the next (NaN: not measured, left out), each a measurement of the
    yaw alone (the translation open, 1-sigma :data:`OPEN_SIGMA_M`) with the angle random
    walk's variance noise^2 (t1 - t0) (rad^2; ``noise`` rad/s/sqrt(Hz)). The bias is the
    filter's state (:func:`_gyro_bias_walk`)."""
    out = []
    for k in range(len(stamps_s) - 1):
        dt = float(stamps_s[k + 1] - stamps_s[k])
        if not (dt > 0 and np.isfinite(yaw_rad[k])):
            continue
        cov = np.diag([OPEN_SIGMA_M**2, OPEN_SIGMA_M**2, noise**2 * dt])
        out.append(
            Increment(
                float(stamps_s[k]), float(stamps_s[k + 1]), np.array([0.0, 0.0, yaw_rad[k]]), cov, "gyro"
            )
        )
    return out


def rate_covariance(sigmas: tuple[float, float, float], dt: float, open_forward: bool = False) -> FloatArray:
    """A step's covariance (3, 3) from 1-sigma rate noise (forward m/s, cross m/s, yaw
    rad/s) over dt seconds; ``open_forward``: it measures no forward motion."""
    var = np.square(np.asarray(sigmas, dtype=float) * dt)
    if open_forward:
        var[0] = OPEN_SIGMA_M**2
    return np.diag(var)


def increments(
    stamps: FloatArray,
    poses: FloatArray,
    covariances: FloatArray | tuple[float, float, float],
    open_forward: NDArray[np.bool_] | None = None,
    measured: NDArray[np.bool_] | None = None,
    source: str = "",
) -> list[Increment]:
    """The steps of an odometry trajectory (poses (N, 3) at stamps (N,)).

    ``covariances``: each step's own (N, 3, 3), the one ending at k at index k (index 0
    unused), a step with a non-finite one left out; or 1-sigma rate noise (forward m/s,
    cross m/s, yaw rad/s: :func:`rate_covariance`) for every step. Where ``open_forward``
    (N,) is True, the step ending there measures no forward motion; where ``measured``
    (N,) is False, the step ending there was not measured at all (a guess of the
    odometry's own) and is left out. Steps of no duration are left out."""
    own = not isinstance(covariances, tuple)
    if own and np.shape(covariances) != (len(stamps), 3, 3):
        raise ValueError(f"covariances of shape {np.shape(covariances)}, expected ({len(stamps)}, 3, 3)")
    out = []
    for k in range(1, len(stamps)):
        dt = float(stamps[k] - stamps[k - 1])
        if dt <= 0 or (measured is not None and not measured[k]):
            continue
        is_open = open_forward is not None and bool(open_forward[k])
        if own:
            cov = np.array(covariances[k], dtype=float)
            if not np.isfinite(cov).all():
                continue
            if is_open:
                cov[0, :] = cov[:, 0] = 0.0
                cov[0, 0] = OPEN_SIGMA_M**2
        else:
            cov = rate_covariance(covariances, dt, is_open)  # type: ignore[arg-type]
        local = pose_of(np.linalg.inv(se2(poses[k - 1])) @ se2(poses[k]))
        out.append(Increment(float(stamps[k - 1]), float(stamps[k]), local, cov, source))
    return out


def vo_increments(
    stamps: FloatArray,
    poses: FloatArray,
    statuses: Sequence[str],
    covariances: FloatArray | None = None,
) -> list[Increment]:
    """Visual odometry's runs as measurements: poses (N, 3) at stamps (N,), each run's
    status (N - 1,) (:class:`rigcal.localize.vo.VoStep`) and, unless the paper's fixed
    covariance is wanted (None), its covariance (N - 1, 3, 3) (``VoStep.covariance``). A
    run without a scale (``no-scale``: its length is a guess) measures no forward motion;
    a failed run (a constant-velocity guess) measures nothing and is left out."""
    if len(statuses) != len(stamps) - 1:
        raise ValueError(f"{len(statuses)} run statuses for {len(stamps)} poses (expected one per run)")
    status = np.array(["ok", *statuses])  # the first pose ends no run
    guessed, failed = status == "no-scale", status == "failed"
    if covariances is None:
        return increments(stamps, poses, VO_SIGMAS, open_forward=guessed, measured=~failed, source="vo")
    if np.shape(covariances) != (len(stamps) - 1, 3, 3):
        expected = f"({len(stamps) - 1}, 3, 3)"
        raise ValueError(f"VO covariances of shape {np.shape(covariances)}, expected {expected}")
    own = np.concatenate([np.full((1, 3, 3), np.nan), covariances])
    return increments(stamps, poses, own, open_forward=guessed, measured=~failed, source="vo")


def fuse(
    measurements: list[Increment], params: KfParams | None = None, at: FloatArray | None = None
) -> tuple[FloatArray, FloatArray]:
    """:func:`run_filter`'s stamps (M,) and poses (M, 3); with ``at``, its path at those
    stamps alone (:func:`path_at`: the laser's scans, so that the filter is scored where
    its inputs are)."""
    res = run_filter(measurements, params)
    if at is not None and len(res.stamps_s):
        res = path_at(res, at)
    return res.stamps_s, res.poses


def path_at(res: KfResult, at: FloatArray) -> KfResult:
    """The filter's path at the stamps ``at`` (K,) within its span (the others dropped):
    a pose it kept at a stamp as it is, one between two kept poses on the constant twist
    between them (:func:`_se2_log`; its covariance the nearer pose's). The filter keeps a
    pose after each update, at the ends of VO's runs (image stamps) as well as of ICP's
    steps (scan stamps); scored at the scans alone, a filter whose path is ICP's scores
    ICP's ATE exactly, where the image stamps' poses would weigh the score by more
    samples of some stretches (docs/localization.md, "Kalman filter")."""
    t = np.asarray(at, dtype=float)
    t = t[(t >= res.stamps_s[0]) & (t <= res.stamps_s[-1])]
    k = np.clip(np.searchsorted(res.stamps_s, t, side="right") - 1, 0, len(res.stamps_s) - 1)
    poses = res.poses[k].copy()
    covs = res.covariances[k].copy()
    for i in np.flatnonzero(res.stamps_s[k] != t):
        a, b = int(k[i]), int(k[i]) + 1
        f = (t[i] - res.stamps_s[a]) / (res.stamps_s[b] - res.stamps_s[a])
        T = se2(res.poses[a]) @ se2(
            _se2_exp(f * _se2_log(pose_of(np.linalg.inv(se2(res.poses[a])) @ se2(res.poses[b]))))
        )
        poses[i] = pose_of(T)
        poses[i, 2] = res.poses[a, 2] + np.angle(np.exp(1j * (poses[i, 2] - res.poses[a, 2])))
        covs[i] = res.covariances[b if f > 0.5 else a]
    return dataclasses.replace(res, stamps_s=t, poses=poses, covariances=covs)


def run_filter(measurements: list[Increment], params: KfParams | None = None) -> KfResult:
    """Run the filter over the increments in time order (Section VI, Eq. (11)); with
    ``params.smooth`` then the backward pass (:class:`_Tape`). See :func:`_run`."""
    params = params or KfParams()
    fused: list[Increment] | None = None  # the wheels' steps the filter fuses, where not as they come
    if params.wheel_calibrated and params.wheel_input:
        wheel = [m for m in measurements if m.source == "wheel"]
        icp = [m for m in measurements if m.source == "icp"]
        if wheel and icp:  # without ICP to calibrate against, the wheels as they came (None)
            fused = _WheelWitness(wheel, _IcpReference(icp, params), params).calibrated_steps()
    token = _TAPE.set(_Tape() if params.smooth else None)
    try:
        return _run(measurements, params, fused)
    finally:
        _TAPE.reset(token)


def _run(measurements: list[Increment], params: KfParams, fused: list[Increment] | None = None) -> KfResult:
    """Run the filter over the increments in time order (Section VI, Eq. (11)); ``fused``:
    the wheels' steps it fuses in place of theirs in ``measurements`` (which the witness
    takes as they came).

    Each increment clones the pose at its start t0 and updates at its end t1 (module
    docstring); at equal stamps updates come before clones, so that a step starting where
    another ends starts from the updated pose. With ``params.icp_shared`` each ICP step's
    error shares a part with the step before (their common scan, :func:`_update`); with
    ``params.gate`` a VO run whose innovation fails the chi-square test is left out; with
    ``params.vo_memory_s`` VO's forward error has a Gauss-Markov part carried in the state
    (:func:`_memory_decay`), its variance ratio matched on line (``vo_forward_adapt``) and
    its innovations tested for whiteness (``vo_forward_window``). With ``params.drive``
    the driving input's steps carry the state between events (:class:`_Drive`) in place of
    the constant-velocity model, and a pose is kept at each of their ends.

    Returns:
        the filtered pose after each update, starting with the origin at the earliest
        stamp, with its covariance (smoothed with ``params.smooth``).
    """
    # At a common end, the shorter step first: a longer one is then compared with the
    # motion the shorter ones already measured.
    raw = params.wheel_input and fused is None
    ms = sorted(
        [m for m in measurements if raw or m.source != "wheel"]
        + (fused if params.wheel_input and fused else []),
        key=lambda m: (m.t1, -m.t0),
    )
    if not ms:
        return KfResult(np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3, 3)))
    # Odometry-driven (``params.drive``): the driving input's steps are the prediction's
    # control input (:class:`_Drive`), the others its measurements; a pose is kept at each
    # driving step's end (event 2).
    drive = _Drive([m for m in ms if m.source == params.drive], params) if params.drive else None
    if drive is not None:
        ms = [m for m in ms if m.source != params.drive]
    # The gyro's steps over which the rig stands still (its bias learned there alone with
    # ``params.gyro_still_only``).
    still = _still(ms, [m for m in measurements if m.source == "icp"])
    if not params.gyro_fused:
        # The gyro's steps where the rig moves serve the witness alone: only its still ones
        # (the bias's) enter the filter.
        ms = [m for i, m in enumerate(ms) if m.source != "gyro" or i in still]
        still = _still(ms, [m for m in measurements if m.source == "icp"])
    # Events (time, 0 = update / 1 = clone / 2 = a driving step's end, index); updates
    # first at equal times.
    events = [(m.t1, 0, i) for i, m in enumerate(ms)] + [(m.t0, 1, i) for i, m in enumerate(ms)]
    if drive is not None:
        events += [(d.t1, 2, -1) for d in drive.steps]
        if not events:
            return KfResult(np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3, 3)))
        events.append((min(e[0] for e in events + [(d.t0, 2, -1) for d in drive.steps]), 2, -1))
    events.sort(key=lambda e: (e[0], e[1], e[2]))
    pending: dict[float, int] = {}  # clone stamp -> increments still to use it
    for m in ms:
        pending[m.t0] = pending.get(m.t0, 0) + 1
    # The state's blocks after the pose and velocity, in state order: the pose clones
    # ("clone", t0), the last ICP scan's shared error ("scan", its stamp), the last VO
    # frame's ("frame", its stamp), each of three, and VO's forward error's Gauss-Markov
    # part ("memory", the end of the last run it was carried to), of one.
    blocks: list[tuple[str, float]] = []
    mean_nis: dict[str, float] = {}  # per input: its innovations' NIS per dimension, running mean
    recent: list[float] = []  # the last VO runs' squared distances (the windowed gate)
    whiteness: list[float] = []  # the last VO runs' standardized forward innovations
    left_out = 0  # VO runs whose forward motion the whiteness test left out
    # The guard (:func:`_vo_guard`): ICP's own steps chained, and VO's last chained runs with
    # their covariances under VO's error model.
    reference = (
        _IcpReference([m for m in measurements if m.source == "icp"], params)
        if params.vo_guard > 0 or params.vo_forward_reference
        else None
    )
    guard_runs: list[tuple[Increment, FloatArray]] = []
    guarded = np.zeros(3, dtype=int)  # VO runs the guard left out, per direction
    wheel_steps = [m for m in measurements if m.source == "wheel"]
    witness = (
        _WheelWitness(wheel_steps, reference, params)
        if reference is not None and params.wheel_witness and params.vo_guard > 0 and wheel_steps
        else None
    )
    witnessed = np.zeros(3, dtype=int)  # VO runs over which the wheels found ICP erring, per direction
    gyro_steps = [m for m in measurements if m.source == "gyro"]
    heading = (
        _GyroWitness(gyro_steps, reference)
        if reference is not None and params.gyro_witness and params.vo_guard > 0 and gyro_steps
        else None
    )
    gyro_witnessed = np.zeros(2, dtype=int)  # VO runs over which the gyro found ICP's / VO's yaw erring
    vo_own, vo_share = _error_model("vo", params)
    forward_ratio = float(vo_own[0] + 2.0 * vo_share[0])  # VO's forward variance ratio, matched on line
    forward_info = float(ADAPT_WINDOW)  # the information its running mean holds (runs of full weight)
    # The windowed gate: the chi-square point of 3 x gate_window dof at the single gate's tail.
    window_gate = chi2_isf(chi2_sf(params.gate, 3), 3 * params.gate_window) if params.gate > 0 else 0.0
    t = events[0][0]
    x = np.zeros(6)
    P = np.diag([1e-12, 1e-12, 1e-12, 1.0, 1.0, 1.0])
    stamps, poses, covs = [t], [x[:3].copy()], [P[:3, :3].copy()]
    tape = _TAPE.get()
    if tape is not None:
        tape.mark(0)
    # The causal path as the filter's relative estimates chained (:class:`_Anchor`); the
    # smoothed path is the backward pass's poses.
    anchor = _Anchor(stamps, poses) if params.anchored and tape is None else None
    for when, kind, i in events:
        if when > t:
            if anchor is not None:
                x, P = anchor.move(x, P, blocks, t)
            if drive is not None:
                x, P = drive.to(x, P, blocks, t, when)
            else:
                x, P = _predict(x, P, when - t, params)
            t = when
        if kind == 2:
            _keep(stamps, poses, covs, t, x, P, tape, anchor, blocks)
            continue
        m = ms[i]
        if kind == 1:
            if ("clone", m.t0) not in blocks:
                x, P = _clone(x, P)
                blocks.append(("clone", m.t0))
            continue
        c = _offset(blocks, ("clone", m.t0))
        scale = max(1.0, mean_nis.get(m.source, 1.0)) if params.adapt else 1.0
        own, share = _error_model(m.source, params)
        vo = m.source == "vo"
        memory: tuple[int, float] | None = None
        if vo and params.vo_memory_s > 0 and m.covariance[0, 0] < (OPEN_SIGMA_M / 10.0) ** 2:
            # Forward: an own part and the Gauss-Markov part (its variance ratio matched on
            # line), no two-run share; cross-track and yaw as before.
            x, P = _memory_decay(x, P, blocks, m.t1, params.vo_memory_s)
            own, share = own.copy(), share.copy()
            own[0], share[0] = forward_ratio * (1.0 - params.vo_memory_share), 0.0
            gain = float(np.sqrt(scale * forward_ratio * params.vo_memory_share * m.covariance[0, 0]))
            memory = (_offset(blocks, ("memory", m.t1)), gain)
        bias: tuple[int, FloatArray] | None = None
        if vo and any(params.vo_bias_sigma):
            # A run's own and shared parts less the bias's share of its error.
            on = np.array(params.vo_bias_sigma) > 0
            rest = 1.0 - np.array(params.vo_bias_share) * on
            own, share = own * rest, share * rest
            # VO's biases over seconds (:func:`_bias_decay`): forward scale and cross-track
            # drift per metre of the run's forward motion (where it is measured), yaw rate
            # over its duration.
            x, P = _bias_decay(x, P, blocks, m.t1, params)
            bias = (_offset(blocks, ("bias", m.t1)), _bias_coefficients(m) * on)
        leave_out: NDArray[np.bool_] | None = None
        gyro_bias: tuple[int, float] | None = None
        if m.source == "gyro":
            # The yaw alone, with the bias's part over the step (module docstring).
            x, P = _gyro_bias_walk(x, P, blocks, m.t1, params)
            gyro_bias = (_offset(blocks, ("gyro", m.t1)), m.t1 - m.t0)
            leave_out = np.array([True, True, False])
        # The gyro's bias learned only from its steps where the rig stands still: a consider
        # state in its other steps' updates.
        consider = (
            gyro_bias[0] if gyro_bias is not None and params.gyro_still_only and i not in still else None
        )
        if gyro_bias is not None and params.gyro_zero_turn and i in still:
            # The rig stands: the gyro reads its bias alone (the pose's turn left out of
            # the step's model; Foxlin 2005's zero-velocity update), unless it reads a turn.
            x_zero, P_zero, inn = _update(
                x,
                P,
                c,
                m,
                own,
                1.0,
                None,
                gate=GYRO_ZERO_TURN_GATE,
                leave_out=leave_out,
                gyro_bias=gyro_bias,
                zero_turn=True,
            )
            if np.isfinite(inn.nis) or not params.gyro_fused:
                # (A still step that reads a turn is left out where the gyro serves the
                # witness alone.)
                if np.isfinite(inn.nis):
                    x, P = x_zero, P_zero
                pending[m.t0] -= 1
                if not pending[m.t0]:
                    x, P = _drop(x, P, _offset(blocks, ("clone", m.t0)))
                    blocks.remove(("clone", m.t0))
                _keep(stamps, poses, covs, t, x, P, tape, anchor, blocks)
                continue
        alone = None
        convicted = False  # the gyro found ICP's yaw erring over the run (its turn fused after it)
        if vo and reference is not None:
            icp_scale = max(1.0, mean_nis.get("icp", 1.0)) if params.adapt else 1.0
            if params.vo_guard > 0:
                gyro = None
                if heading is not None:
                    # The bias as learned so far (the prior where no gyro step has come).
                    held = _block(blocks, "gyro")
                    k = _offset(blocks, held) if held is not None else -1
                    gyro = (
                        (heading, float(x[k]), float(P[k, k]))
                        if held is not None
                        else (heading, 0.0, params.gyro_bias_sigma**2)
                    )
                leave_out, inflate, icp_errs, gyro_errs = _guard(
                    reference,
                    guard_runs,
                    m,
                    own,
                    share,
                    (scale, icp_scale),
                    memory is not None,
                    t,
                    params,
                    witness,
                    gyro,
                )
                witnessed += icp_errs
                gyro_witnessed += gyro_errs
                convicted = bool(gyro_errs[0])
                if inflate.any():
                    # ICP's path over the run erred beyond its model (the wheels' verdict):
                    # the pose's covariance takes that excess in the run's frame (the
                    # clone's), as process noise ICP's steps should have brought.
                    G = _rotation3(float(x[c + 2]))
                    grown = P.copy()
                    grown[:3, :3] += G @ np.diag(inflate) @ G.T
                    x, P = _recorded(x, P, np.eye(len(x)), x, grown)
            if leave_out is not None:
                guarded += leave_out
            if memory is not None and params.vo_forward_reference:
                alone = reference.between(m.t0, m.t1, t, icp_scale)
        x_before = x
        shared: int | None = None
        if share.any():  # m.source is "icp" or "vo": its shared error enters the state
            kind_of = SHARED_BLOCK[m.source]
            old = [b for b in blocks if b[0] == kind_of]
            x, P = _append(x, P, _finite_part(_scaled(m.covariance, share)))
            blocks.append((kind_of, m.t1))
            shared = _offset(blocks, old[-1]) if old and old[-1][1] == m.t0 else -1
        x, P, inn = _update(
            x,
            P,
            c,
            m,
            own,
            scale,
            shared,
            SHARED_SIGN.get(m.source, -1.0),
            gate=params.gate if vo else 0.0,
            weak_only=params.vo_weak_only if vo else 0.0,
            window=(sum(recent), window_gate) if vo and params.gate_window > 1 else None,
            memory=memory,
            bias=bias,
            whiteness=(sum(whiteness), len(whiteness), VO_FORWARD_GATE)
            if memory is not None and params.vo_forward_window > 0
            else None,
            leave_out=leave_out,
            gyro_bias=gyro_bias,
            consider=consider,
        )
        if vo and np.isfinite(inn.d2):
            # The windowed test's last runs, each counted at most at the single gate (a lone
            # outlier is the single test's, not the window's).
            recent.append(min(inn.d2, params.gate) if params.gate > 0 else inn.d2)
            del recent[: max(0, len(recent) - (params.gate_window - 1))]
        left_out += inn.forward_left_out
        if memory is not None and np.isfinite(inn.forward_z):
            whiteness.append(inn.forward_z)
            del whiteness[: max(0, len(whiteness) - (params.vo_forward_window - 1))]
        if memory is not None and params.vo_forward_adapt and np.isfinite(inn.forward_sq):
            # Covariance matching on VO's forward axis alone (Mehra 1972): the run's forward
            # innovation against the pose's prediction, squared, less that prediction's
            # variance A, over the run's forward variance C, is a sample of the ratio
            # (negative ones taken as 0; at most NIS_CAP times the current ratio r). Each
            # sample weighs by its Fisher information, (r C / (A + r C))^2 up to a factor:
            # where the filter's prediction is loose (a corridor ICP leaves open) a run says
            # little about its own error. A running mean over about ADAPT_WINDOW runs of
            # full weight.
            var = forward_ratio * m.covariance[0, 0]
            fsq, fvar = inn.forward_sq, inn.forward_prediction_var
            if alone is not None:
                fvar = float(alone[1][0, 0])
                # Less VO's estimated scale bias (the ratio is that of its errors around it).
                scaled = bias[1][0] * x_before[bias[0]] if bias is not None else 0.0
                fsq = float((m.motion[0] - scaled - alone[0][0]) ** 2 - fvar)
            weight = (var / (var + fvar)) ** 2
            forward_info += weight - forward_info / ADAPT_WINDOW
            sample = min(max(0.0, fsq) / m.covariance[0, 0], NIS_CAP * forward_ratio)
            forward_ratio += weight / forward_info * (sample - forward_ratio)
        if shared is not None:  # the step's shared error is in; the one before is done with
            for b in [b for b in blocks if b[0] == SHARED_BLOCK[m.source] and b[1] != m.t1]:
                x, P = _drop(x, P, _offset(blocks, b))
                blocks.remove(b)
        if convicted and heading is not None and params.gyro_where_icp_errs and not params.gyro_fused:
            x, P = _convicted_turn(x, P, blocks, heading, m, t)
        if np.isfinite(inn.nis):
            # Covariance matching: each input's recent innovations against its covariance.
            mean_nis[m.source] = (
                mean_nis.get(m.source, 1.0)
                + (min(inn.nis, NIS_CAP) - mean_nis.get(m.source, 1.0)) / ADAPT_WINDOW
            )
        pending[m.t0] -= 1
        if not pending[m.t0]:
            x, P = _drop(x, P, _offset(blocks, ("clone", m.t0)))
            blocks.remove(("clone", m.t0))
        _keep(stamps, poses, covs, t, x, P, tape, anchor, blocks)
    gyro_block = _block(blocks, "gyro")
    bias_sigma = float("nan")
    if gyro_block is not None:
        at = _offset(blocks, gyro_block)
        bias_sigma = float(np.sqrt(P[at, at]))
    if tape is not None:  # the backward pass (Rauch, Tung and Striebel 1965)
        smoothed = tape.smooth(x, P)
        poses = [xs[:3].copy() for xs, _ in smoothed]
        covs = [Ps[:3, :3].copy() for _, Ps in smoothed]
    return KfResult(
        np.array(stamps),
        np.array(poses),
        np.array(covs),
        forward_ratio,
        left_out,
        (int(guarded[0]), int(guarded[1]), int(guarded[2])),
        x[_offset(blocks, block) + np.arange(3)].copy() if (block := _block(blocks, "bias")) else None,
        (int(witnessed[0]), int(witnessed[1]), int(witnessed[2])),
        float(x[_offset(blocks, gyro_block)]) if gyro_block is not None else float("nan"),
        bias_sigma,
        float(sum(ms[i].t1 - ms[i].t0 for i in still)),
        (int(gyro_witnessed[0]), int(gyro_witnessed[1])),
    )


def _guard(
    reference: _IcpReference,
    runs: list[tuple[Increment, FloatArray]],
    m: Increment,
    own: FloatArray,
    share: FloatArray,
    scales: tuple[float, float],
    memory: bool,
    now: float,
    params: KfParams,
    witness: _WheelWitness | None = None,
    gyro: tuple[_GyroWitness, float, float] | None = None,
) -> tuple[NDArray[np.bool_] | None, FloatArray, NDArray[np.bool_], NDArray[np.bool_]]:
    """The directions of VO's run ``m`` the guard leaves out (:func:`_vo_guard`), or None
    where ICP gives no reference; with the wheels' ``witness`` (:func:`_witness`) VO is kept
    along a direction where the wheels find ICP erring over any window and left out where
    they find VO erring, and the variance to add to ICP's path over the run where ICP errs
    (3,: ICP's excess over the window over its runs) and those directions (3,) come back
    too (zeros and False without). ``gyro`` = (the gyro's witness, its bias rad/s as the
    filter holds it, the bias's variance): the gyro's chained yaw over each window
    (:meth:`_GyroWitness.between`) witnesses the yaw the same way, and whether it found
    ICP's yaw erring and whether VO's (2,) come back last. ``runs`` (VO's last chained
    runs with their modelled covariances) is updated in place; ``own``, ``share``: the
    run's error model per axis (with the forward memory, ``share`` forward 0 and the
    memory's part the rest of the forward variance ratio); ``scales``: VO's and ICP's
    covariance matching factors."""
    total = own + 2.0 * share
    rho = np.divide(share, total, out=np.zeros(3), where=total > 0)
    if memory:
        total[0] = own[0] / (1.0 - params.vo_memory_share)  # own and the Gauss-Markov part
    if runs and runs[-1][0].t1 != m.t0:
        runs.clear()
    runs.append((m, scales[0] * _scaled(m.covariance, total)))
    del runs[: -params.vo_guard]
    correlation = np.zeros((max(len(runs) - 1, 1), 3))
    correlation[0] = rho
    if memory:
        lags = np.arange(1, len(correlation) + 1)
        correlation[:, 0] = params.vo_memory_share * np.exp(-lags * (m.t1 - m.t0) / params.vo_memory_s)
    # The windows: the last 1, 2, 4 ... runs up to ``vo_guard``, each tested at the
    # Bonferroni share of the 0.001 tail (a bias shows over the longer windows, a single
    # bad run over the shorter ones).
    windows = [n for n in _guard_windows(params.vo_guard) if n <= len(runs)]
    gate = _guard_gate(params.vo_guard)
    out: NDArray[np.bool_] | None = None
    icp_errs, vo_errs, inflate = np.zeros(3, dtype=bool), np.zeros(3, dtype=bool), np.zeros(3)
    gyro_errs = np.zeros(2, dtype=bool)
    for n in windows:
        ref = reference.between(runs[-n][0].t0, m.t1, now, scales[1])
        if ref is None:
            continue
        # The rule VO_PAYS over the longest window: the one the lap's error integrates most.
        pays = params.vo_pays if n == windows[-1] else 0.0
        fired = _vo_guard(runs[-n:], ref, correlation[: n - 1], gate, _bias_model(params), pays)[0]
        out = fired if out is None else out | fired
        wheel = witness.between(runs[-n][0].t0, m.t1, now, n) if witness is not None else None
        if wheel is not None:
            i, v, excess = _witness(runs[-n:], ref, wheel, correlation[: n - 1], gate, _bias_model(params))
            icp_errs |= i
            vo_errs |= v
            inflate = np.maximum(inflate, excess / n)
        turn = None
        if gyro is not None:
            turn = gyro[0].between(runs[-n][0].t0, m.t1, now, gyro[1], gyro[2], scales[1])
        if turn is not None:
            i, v, excess = _witness(runs[-n:], ref, turn, correlation[: n - 1], gate, _bias_model(params))
            gyro_errs |= np.array([i[2], v[2]])
            icp_errs |= i
            vo_errs |= v
            inflate = np.maximum(inflate, excess / n)
    if out is not None:
        out = (out & ~icp_errs) | vo_errs
    return out, inflate, icp_errs, gyro_errs


def _convicted_turn(
    x: FloatArray,
    P: FloatArray,
    blocks: list[tuple[str, float]],
    heading: _GyroWitness,
    m: Increment,
    now: float,
) -> tuple[FloatArray, FloatArray]:
    """The state after the gyro's turn over VO's run ``m`` (:meth:`_GyroWitness.between`, as
    the witness takes it: less the bias the state holds, the bias's variance in the turn's),
    fused against the run's clone: where the gyro, as the guard's witness, found ICP's yaw
    erring, the heading is the gyro's rather than VO's alone (``KfParams.gyro_where_icp_errs``).
    No bias learned yet (no still step so far) or no turn to be had: the state as it was."""
    held = _block(blocks, "gyro")
    if held is None or ("clone", m.t0) not in blocks:
        return x, P
    at = _offset(blocks, held)
    turn = heading.between(m.t0, m.t1, now, float(x[at]), float(P[at, at]))
    if turn is None:
        return x, P
    step = Increment(m.t0, m.t1, turn[0], turn[1], "gyro")
    x, P, _ = _update(x, P, _offset(blocks, ("clone", m.t0)), step, leave_out=np.array([True, True, False]))
    return x, P


def _bias_model(params: KfParams) -> tuple[FloatArray, FloatArray] | None:
    """VO's biases' (sigma (3,), time constant s (3,)) (``KfParams.vo_bias_sigma``,
    ``vo_bias_s``; an axis without a bias: time constant 1 s), or None without them."""
    sigma = np.asarray(params.vo_bias_sigma, dtype=float)
    if not sigma.any():
        return None
    return sigma, np.where(sigma > 0, np.asarray(params.vo_bias_s, dtype=float), 1.0)


def _bias_coefficients(m: Increment) -> FloatArray:
    """What VO's biases (forward scale, cross-track per metre, yaw rate) add to run ``m``'s
    error per unit of bias (3,): its forward motion where it measures one, twice, and its
    duration."""
    measured = float(m.covariance[0, 0] < (OPEN_SIGMA_M / 10.0) ** 2)
    return np.array([measured * m.motion[0], measured * m.motion[0], m.t1 - m.t0])


def _guard_windows(runs: int) -> list[int]:
    """The guard's windows, in VO runs: 1, 2, 4 ... up to ``runs``."""
    return [2**j for j in range(int(np.log2(runs)) + 1)] if runs > 0 else []


def _guard_gate(runs: int) -> float:
    """The chi-square point (1 dof) each of the guard's windows is tested at: the 0.001
    tail shared among them (Bonferroni), so that a run's direction is left out by chance
    no more often than by the whiteness test's 0.999 point."""
    return chi2_isf((1.0 - VO_GUARD_LEVEL) / max(1, len(_guard_windows(runs))), 1)


def _keep(
    stamps: list[float],
    poses: list[FloatArray],
    covs: list[FloatArray],
    t: float,
    x: FloatArray,
    P: FloatArray,
    tape: _Tape | None = None,
    anchor: _Anchor | None = None,
    blocks: list[tuple[str, float]] | None = None,
) -> None:
    """The pose and its covariance at ``t`` appended to the output (replacing the last at
    the same stamp): the state's pose, or with an ``anchor`` the filter's motion since the
    last output stamp chained onto that output (:class:`_Anchor`); the ``tape``'s mark of
    that output where smoothing."""
    pose = anchor.pose(x, blocks or []) if anchor is not None else x[:3].copy()
    if stamps[-1] == t:
        poses[-1], covs[-1] = pose, P[:3, :3].copy()
    else:
        stamps.append(t)
        poses.append(pose)
        covs.append(P[:3, :3].copy())
    if tape is not None:
        tape.mark(len(stamps) - 1)


class _Anchor:
    """The causal path as the filter's relative estimates chained. Every input is an
    increment, so the filter's pose in the world is unobservable: an update moves it only
    by the linearisation's leak (the EKF's inconsistency under a large heading
    uncertainty; Huang, Mourikis and Roumeliotis, "Observability-based rules for designing
    consistent EKF SLAM estimators", IJRR 2010), which over a long real log (a heading
    uncertainty of 0.3 rad, a lever arm of 50 m) moved a pose and its clone together by
    metres where the increment corrected their relative motion by centimetres. So the
    state holds a copy of its pose at an output stamp (the block ("anchor", stamp), taken
    as the state moves on from the last output stamp unless an increment from an earlier
    stamp is still pending), updated with the rest, and each output pose is that stamp's
    output composed with the motion from the copy to the current pose: an update's
    correction of the motion since the copy reaches the path, a move of both alike does
    not. Without any update this is the state's own pose."""

    def __init__(self, stamps: list[float], poses: list[FloatArray]) -> None:
        self.stamps, self.poses = stamps, poses
        self.base = poses[-1].copy()  # the output at the anchor's stamp

    def move(
        self, x: FloatArray, P: FloatArray, blocks: list[tuple[str, float]], t: float
    ) -> tuple[FloatArray, FloatArray]:
        """Before the state leaves ``t``: where ``t`` is the last output stamp, the copy of
        the pose there (replacing the one before)."""
        held = _block(blocks, "anchor")
        if self.stamps[-1] != t or (held is not None and held[1] == t):
            return x, P
        if any(kind == "clone" and at < t for kind, at in blocks):
            # An increment from an earlier stamp is still to come: its correction of the
            # motion since then is to reach the path, so the copy stays where it is.
            return x, P
        if held is not None:
            x, P = _drop(x, P, _offset(blocks, held))
            blocks.remove(held)
        x, P = _clone(x, P)
        blocks.append(("anchor", t))
        self.base = self.poses[-1].copy()
        return x, P

    def pose(self, x: FloatArray, blocks: list[tuple[str, float]]) -> FloatArray:
        """The output pose for the state ``x``."""
        held = _block(blocks, "anchor")
        if held is None:
            return x[:3].copy()
        a = _offset(blocks, held)
        out = pose_of(se2(self.base) @ np.linalg.inv(se2(x[a : a + 3])) @ se2(x[:3]))
        out[2] = self.base[2] + (x[2] - x[a + 2])  # the heading unwrapped, as the state's
        return out


def _se2_log(motion: FloatArray) -> FloatArray:
    """The twist (u_x m, u_y m, w rad) whose constant application over a unit time moves
    by ``motion`` (dx, dy, dyaw): the SE(2) logarithm."""
    w = float(np.angle(np.exp(1j * motion[2])))
    a, b = _se2_v(w)
    V = np.array([[a, -b], [b, a]])
    return np.array([*np.linalg.solve(V, motion[:2]), w])


def _se2_exp(twist: FloatArray) -> FloatArray:
    """The motion (dx, dy, dyaw) of a twist applied for a unit time: the SE(2) exponential."""
    a, b = _se2_v(float(twist[2]))
    return np.array([a * twist[0] - b * twist[1], b * twist[0] + a * twist[1], twist[2]])


def _se2_v(w: float) -> tuple[float, float]:
    """sin(w) / w and (1 - cos(w)) / w (their series near w = 0)."""
    if abs(w) < 1e-6:
        return 1.0 - w * w / 6.0, w / 2.0
    return float(np.sin(w) / w), float((1.0 - np.cos(w)) / w)


class _Drive:
    """The odometry-driven prediction (``KfParams.drive``; Thrun, Burgard and Fox,
    Probabilistic Robotics, 2005, Section 5.4: odometry as the control input of the
    motion model): the driving input's step u over [t0, t1], with covariance C, moves the
    pose from t0 to t1 as its constant twist xi = log(u) (:func:`_se2_log`): a part of the
    step from t to t' applies exp(f xi), f = (t' - t) / (t1 - t0), with process noise
    f x own x C (own: the input's own fraction, :func:`_error_model`) in the rig's frame,
    so the parts compose to the step exactly and a pose between scans (a VO run's end) is
    where the step puts it. At the step's end its shared error enters as in
    :func:`_update`: the true motion is u - w_k - s_k + s_(k-1) (ICP: scan k's noise, in
    step k and, with the opposite sign, in step k + 1; Bar-Shalom, Li and Kirubarajan
    2001, Section 8.2), s_k appended to the state and s_(k-1) dropped once in. With no
    other measurement the filter's poses are the driving input's steps chained. Where no
    step covers the time (a skipped scan pair), the constant-velocity model carries the
    pose at the last step's velocity."""

    def __init__(self, steps: list[Increment], params: KfParams) -> None:
        self.steps = sorted(steps, key=lambda m: (m.t0, m.t1))
        self.params = params
        self.own, self.share = _error_model(params.drive, params)
        self.next = 0  # the first step not yet finished

    def to(
        self, x: FloatArray, P: FloatArray, blocks: list[tuple[str, float]], t: float, when: float
    ) -> tuple[FloatArray, FloatArray]:
        """The state carried from ``t`` to ``when`` (``blocks`` updated in place)."""
        while t < when:
            while self.next < len(self.steps) and self.steps[self.next].t1 <= t:
                self.next += 1
            d = self.steps[self.next] if self.next < len(self.steps) else None
            if d is None or d.t0 > t:  # no step covers t: constant velocity to the next
                end = when if d is None else min(when, d.t0)
                x, P = _predict(x, P, end - t, self.params)
                t = end
                continue
            end = min(when, d.t1)
            x, P = self._part(x, P, d, (end - t) / (d.t1 - d.t0))
            if end == d.t1:
                x, P = self._shared(x, P, blocks, d)
                self.next += 1
            t = end
        return x, P

    def _part(self, x: FloatArray, P: FloatArray, d: Increment, f: float) -> tuple[FloatArray, FloatArray]:
        """The pose moved by the part f of step ``d``, its velocity the step's."""
        xi = _se2_log(d.motion)
        u = _se2_exp(f * xi)
        c, s = np.cos(x[2]), np.sin(x[2])
        R = np.array([[c, -s], [s, c]])
        F = np.eye(len(x))
        F[:2, 2] = [-s * u[0] - c * u[1], c * u[0] - s * u[1]]  # d(R(yaw) u) / d yaw
        G = np.eye(3)
        G[:2, :2] = R
        x0, P0 = x, P
        x = x.copy()
        x[:2] += R @ u[:2]
        x[2] += u[2]
        P = F @ P @ F.T
        P[:3, :3] += f * G @ _scaled(d.covariance, self.own) @ G.T
        # The velocity (the constant-velocity model's, where no step covers the time): the
        # step's, in the world; its uncertainty the step's.
        dt = d.t1 - d.t0
        x[3:6] = G @ xi / dt
        P[3:6, :] = P[:, 3:6] = 0.0
        P[3:6, 3:6] = G @ d.covariance @ G.T / dt**2
        if not np.isfinite(P[3:6, 3:6]).all() or np.trace(P[3:6, 3:6]) > 1e4:
            P[3:6, 3:6] = np.diag([1.0, 1.0, 1.0])
        F[3:6, :] = 0.0  # the velocity is the step's, whatever it was
        return _recorded(x0, P0, F, x, P)

    def _shared(
        self, x: FloatArray, P: FloatArray, blocks: list[tuple[str, float]], d: Increment
    ) -> tuple[FloatArray, FloatArray]:
        """The step's shared error in at its end: pose -= G (s_k - s_(k-1))."""
        if not self.share.any():
            return x, P
        kind = SHARED_BLOCK[self.params.drive]
        old = [b for b in blocks if b[0] == kind]
        x, P = _append(x, P, _finite_part(_scaled(d.covariance, self.share)))
        blocks.append((kind, d.t1))
        c, s = np.cos(x[2] - d.motion[2]), np.sin(x[2] - d.motion[2])  # the step's start frame
        G = np.eye(3)
        G[:2, :2] = [[c, -s], [s, c]]
        T = np.eye(len(x))
        n = len(x)
        T[:3, n - 3 :] = -G
        if old and old[-1][1] == d.t0:
            at = _offset(blocks, old[-1])
            T[:3, at : at + 3] = G
        x, P = _recorded(x, P, T, T @ x, T @ P @ T.T)
        for b in old:
            x, P = _drop(x, P, _offset(blocks, b))
            blocks.remove(b)
        return x, P


def _block(blocks: list[tuple[str, float]], kind: str) -> tuple[str, float] | None:
    """The state's block of that kind, if any."""
    return next((b for b in blocks if b[0] == kind), None)


def _offset(blocks: list[tuple[str, float]], block: tuple[str, float]) -> int:
    """A block's index in the state: after the pose and velocity (6) and the blocks before
    it (three each, the memory one)."""
    return 6 + sum(BLOCK_SIZE.get(k, 3) for k, _ in blocks[: blocks.index(block)])


def _memory_decay(
    x: FloatArray, P: FloatArray, blocks: list[tuple[str, float]], t1: float, tau_s: float
) -> tuple[FloatArray, FloatArray]:
    """The state with VO's forward Gauss-Markov error carried to ``t1`` (appended, of unit
    variance, at the first run; ``blocks`` updated in place): g(t1) = phi g(t) +
    sqrt(1 - phi^2) n with phi = exp(-(t1 - t) / tau_s) (Gelb 1974, Table 3.8-1; Bar-Shalom,
    Li and Kirubarajan 2001, Section 8.2: a correlated measurement error augmented to the
    state). Lazy: no other measurement reads it, so it is carried only when a run needs it."""
    old = [b for b in blocks if b[0] == "memory"]
    if not old:
        x, P = _append(x, P, np.ones((1, 1)))
        blocks.append(("memory", t1))
        return x, P
    at = _offset(blocks, old[0])
    phi = float(np.exp(-max(0.0, t1 - old[0][1]) / tau_s))
    x0, P0 = x, P
    x = x.copy()
    x[at] *= phi
    P = P.copy()
    P[at, :] *= phi
    P[:, at] *= phi
    P[at, at] += 1.0 - phi**2
    blocks[blocks.index(old[0])] = ("memory", t1)
    F = np.eye(len(x))
    F[at, at] = phi
    return _recorded(x0, P0, F, x, P)


def _bias_decay(
    x: FloatArray, P: FloatArray, blocks: list[tuple[str, float]], t1: float, params: KfParams
) -> tuple[FloatArray, FloatArray]:
    """The state with VO's biases (forward scale, cross-track per metre forward, yaw rate
    rad/s; ``params.vo_bias_sigma``, ``vo_bias_s``) carried to ``t1`` (appended at the
    first run, zero with their stationary variances): each a first-order Gauss-Markov
    process, b(t1) = phi b(t) + sigma sqrt(1 - phi^2) n, phi = exp(-(t1 - t) / tau) (Gelb
    1974, Table 3.8-1; Bar-Shalom, Li and Kirubarajan 2001, Section 8.2). Lazy, as
    :func:`_memory_decay`."""
    var = np.square(np.asarray(params.vo_bias_sigma, dtype=float))
    old = [b for b in blocks if b[0] == "bias"]
    if not old:
        x, P = _append(x, P, np.diag(var))
        blocks.append(("bias", t1))
        return x, P
    at = _offset(blocks, old[0]) + np.arange(3)
    tau = np.where(var > 0, np.asarray(params.vo_bias_s, dtype=float), 1.0)
    phi = np.exp(-max(0.0, t1 - old[0][1]) / tau)
    x0, P0 = x, P
    x = x.copy()
    x[at] *= phi
    P = P.copy()
    P[at, :] *= phi[:, None]
    P[:, at] *= phi[None, :]
    P[at, at] += var * (1.0 - phi**2)
    blocks[blocks.index(old[0])] = ("bias", t1)
    F = np.eye(len(x))
    F[at, at] = phi
    return _recorded(x0, P0, F, x, P)


def _still(ms: list[Increment], icp: list[Increment]) -> set[int]:
    """The indices of the gyro's steps in ``ms`` over which the rig stands still: ICP's
    steps cover the step and each moved slower than :data:`GYRO_STILL_MPS` and
    :data:`GYRO_STILL_RAD_S`."""
    if not icp:
        return set()
    icp = sorted(icp, key=lambda m: m.t0)
    t0 = np.array([m.t0 for m in icp])
    t1 = np.array([m.t1 for m in icp])
    moved = np.array(
        [
            np.hypot(m.motion[0], m.motion[1]) >= GYRO_STILL_MPS * (m.t1 - m.t0)
            or abs(m.motion[2]) >= GYRO_STILL_RAD_S * (m.t1 - m.t0)
            for m in icp
        ]
    )
    out = set()
    for i, m in enumerate(ms):
        if m.source != "gyro":
            continue
        a, b = np.searchsorted(t1, m.t0, side="right"), np.searchsorted(t0, m.t1, side="left")
        covered = (
            b > a and t0[a] <= m.t0 and t1[b - 1] >= m.t1 and bool((t0[a + 1 : b] == t1[a : b - 1]).all())
        )
        if covered and not moved[a:b].any():
            out.add(i)
    return out


def _gyro_bias_walk(
    x: FloatArray, P: FloatArray, blocks: list[tuple[str, float]], t1: float, params: KfParams
) -> tuple[FloatArray, FloatArray]:
    """The state with the gyroscope's bias (rad/s) carried to ``t1`` (appended at its first
    step, zero with variance ``params.gyro_bias_sigma``^2; ``blocks`` updated in place): a
    random walk, b(t1) = b(t) + ``gyro_bias_walk`` sqrt(t1 - t) n (the rate random walk of
    the rate gyro model; Groves 2013, Section 4.4.6). Lazy, as :func:`_memory_decay`."""
    old = _block(blocks, "gyro")
    if old is None:
        x, P = _append(x, P, np.array([[params.gyro_bias_sigma**2]]))
        blocks.append(("gyro", t1))
        return x, P
    at = _offset(blocks, old)
    grown = P.copy()
    grown[at, at] += params.gyro_bias_walk**2 * max(0.0, t1 - old[1])
    blocks[blocks.index(old)] = ("gyro", t1)
    return _recorded(x, P, np.eye(len(x)), x, grown)


# The state block holding each input's shared error, and the sign it enters the step after
# with (:func:`_update`).
SHARED_BLOCK = {"icp": "scan", "vo": "frame"}
BLOCK_SIZE = {"memory": 1, "gyro": 1}  # the other blocks are of three
SHARED_SIGN = {"icp": -1.0, "vo": 1.0}


def _error_model(source: str, params: KfParams) -> tuple[FloatArray, FloatArray]:
    """An input's (own, shared) fractions per axis (3,) of its steps' covariance."""
    own, shared = {"icp": (params.icp_own, params.icp_shared), "vo": (params.vo_own, params.vo_shared)}.get(
        source, (1.0, 0.0)
    )
    return _per_axis(own), _per_axis(shared)


def _scaled(cov: FloatArray, fractions: FloatArray) -> FloatArray:
    """A covariance (3, 3) with each axis's standard deviation scaled by the square root of
    its fraction (3,)."""
    d = np.sqrt(fractions)
    out: FloatArray = d[:, None] * cov * d[None, :]
    return out


def _clone(x: FloatArray, P: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The state with a copy of its pose appended, and its covariance (the copy fully
    correlated with the pose)."""
    n = len(x)
    J = np.vstack([np.eye(n), np.eye(n)[:3]])
    return _recorded(x, P, J, np.concatenate([x, x[:3]]), J @ P @ J.T)


def _append(x: FloatArray, P: FloatArray, cov: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The state with a zero-mean block appended, of covariance ``cov`` (k, k), independent
    of the rest."""
    n, k = len(x), len(cov)
    out = np.zeros((n + k, n + k))
    out[:n, :n], out[n:, n:] = P, cov
    return _recorded(x, P, np.eye(n + k, n), np.concatenate([x, np.zeros(k)]), out)


def _drop(x: FloatArray, P: FloatArray, at: int) -> tuple[FloatArray, FloatArray]:
    """The state without its block of three at index ``at`` (marginalised out)."""
    keep = np.r_[0:at, at + 3 : len(x)]
    return _recorded(x, P, np.eye(len(x))[keep], x[keep], P[np.ix_(keep, keep)])


def _finite_part(cov: FloatArray) -> FloatArray:
    """A step's covariance (3, 3) without the directions it leaves open (variance above
    (OPEN_SIGMA_M / 10)^2: ICP along a corridor), which are no measurement error shared
    with the next step."""
    w, v = np.linalg.eigh(0.5 * (cov + cov.T))
    w = np.where(w > (OPEN_SIGMA_M / 10.0) ** 2, 0.0, np.maximum(w, 0.0))
    out: FloatArray = (v * w) @ v.T
    return out


@dataclass(frozen=True)
class Innovation:
    """What an update saw: the innovation's NIS per dimension without the covariance
    matching's factor (what the matching follows), its squared Mahalanobis distance over
    all three dimensions, and for a VO run with the forward memory (else NaN) its forward
    innovation standardized under the whole model (the whiteness test's) and its forward
    innovation against the pose's prediction alone, squared, less that prediction's
    variance, and that variance (m^2; the forward ratio's matching); whether the whiteness
    test left the forward direction out."""

    nis: float = float("nan")
    d2: float = float("nan")
    forward_z: float = float("nan")
    forward_sq: float = float("nan")
    forward_prediction_var: float = float("nan")
    forward_left_out: bool = False


def _update(
    x: FloatArray,
    P: FloatArray,
    c: int,
    m: Increment,
    own: float | FloatArray = 1.0,
    adapt: float = 1.0,
    shared: int | None = None,
    sign: float = -1.0,
    gate: float = 0.0,
    weak_only: float = 0.0,
    window: tuple[float, float] | None = None,
    memory: tuple[int, float] | None = None,
    bias: tuple[int, FloatArray] | None = None,
    whiteness: tuple[float, int, float] | None = None,
    leave_out: NDArray[np.bool_] | None = None,
    gyro_bias: tuple[int, float] | None = None,
    consider: int | None = None,
    zero_turn: bool = False,
) -> tuple[FloatArray, FloatArray, Innovation]:
    """The EKF update with increment ``m`` against the clone at state index ``c``: h(S) is
    the motion from the clone's pose to the current one in the clone's frame. The step's
    own error has its covariance scaled per axis by ``own`` (:func:`_scaled`), times
    ``adapt`` (the covariance matching's factor). Also returns what the innovation was
    (:class:`Innovation`).

    ``shared`` (an index): the step's error is e_k = w_k + s_k + ``sign`` s_(k-1), w_k its
    own, s_j the error the step boundary j brings
    into both steps it is part of: for ICP (sign -1) scan j's noise, data of step j and
    model of step j + 1, with opposite signs (chained, they cancel); for VO (sign +1) frame
    j's tracks and the scale run j + 1 carries from run j, with the same sign. s_k is the
    state's last block (the step's covariance scaled by :data:`ICP_SHARED` or
    :data:`VO_SHARED`, :func:`_finite_part`), s_(k-1) the block at ``shared`` (-1: none, the step
    before was another input's). Measurement noise correlated in time, modelled by
    augmenting the state (Bar-Shalom, Li and Kirubarajan 2001, Section 8.2; the small turn
    between the two steps' frames is neglected).

    ``memory`` = (index, gain): the step's forward error has a further part gain x g, g the
    unit-variance Gauss-Markov state at that index (:func:`_memory_decay`). ``bias`` =
    (index, coefficients (3,)): the step's error along each axis has a further part
    coefficient x b, b the state's block of three at that index (VO's biases:
    :func:`_bias_decay`). ``gyro_bias`` = (index, seconds): the step's yaw has a further
    part seconds x b, b the gyroscope's bias at that index (:func:`_gyro_bias_walk`).
    ``consider`` (an index): that state is a consider state in this update (its gain 0, its
    covariance with the rest kept exact by the Joseph form; Schmidt 1966). ``zero_turn``:
    the step's yaw is known to be zero (the rig stands), so the model's yaw is the bias's
    part alone (a zero-velocity update; Foxlin 2005, Groves 2013, Section 15.3).

    ``gate`` > 0: when the innovation's squared Mahalanobis distance d2 (shared error
    included) exceeds it, or ``window`` = (the last runs' d2 summed, its gate) and that sum
    with d2 exceeds its gate, nothing is updated (the state comes back as it was).

    ``whiteness`` = (the last runs' standardized forward innovations summed, their count,
    the gate): when that sum with this run's, squared over the count, exceeds the gate
    (chi-square, 1 dof: under the model the innovations are white), the forward direction
    is left out of the update. ``leave_out`` (3,): directions of the step's frame (forward,
    cross-track, yaw) left out of the update as well (the guard's, :func:`_vo_guard`).

    ``weak_only`` > 0: only the directions along which the filter's own prediction of the
    motion (pose and clone, without the shared error) is less certain than the step's error
    (own and shared) by more than that ratio are updated.
    """
    cyaw, syaw = np.cos(x[c + 2]), np.sin(x[c + 2])
    Rt = np.array([[cyaw, syaw], [-syaw, cyaw]])  # R(yaw_t0)^T
    d = x[:2] - x[c : c + 2]
    h = np.array([*(Rt @ d), x[2] - x[c + 2]])
    H = np.zeros((3, len(x)))
    H[:2, :2] = Rt
    H[:2, c : c + 2] = -Rt
    H[:2, c + 2] = np.array([[-syaw, cyaw], [-cyaw, -syaw]]) @ d  # d(R^T d) / d yaw_t0
    H[2, 2], H[2, c + 2] = 1.0, -1.0
    if zero_turn:
        h[2], H[2, 2], H[2, c + 2] = 0.0, 0.0, 0.0
    R0 = _scaled(m.covariance, _per_axis(own))
    Rm = adapt * R0
    Hs = np.zeros_like(H)  # the correlated errors' part of H (shared, memory)
    if shared is not None:
        n = len(x)
        Hs[:, n - 3 :] = np.eye(3)
        if shared >= 0:
            Hs[:, shared : shared + 3] = sign * np.eye(3)
    if memory is not None:
        Hs[0, memory[0]] = memory[1]
    if bias is not None:
        Hs[[0, 1, 2], bias[0] + np.arange(3)] = bias[1]
    if gyro_bias is not None:
        Hs[2, gyro_bias[0]] = gyro_bias[1]
    Hp = H.copy()  # the pose's part
    h, H = h + Hs @ x, H + Hs
    y = m.motion - h
    y[2] = np.angle(np.exp(1j * y[2]))
    HPH = H @ P @ H.T
    S = HPH + Rm
    d2 = float(y @ np.linalg.solve(S, y))
    if gate > 0 and (d2 > gate or (window is not None and window[0] + d2 > window[1])):
        return x, P, Innovation(d2=d2)
    forward_z = forward_sq = forward_var = float("nan")
    left_out = False
    if memory is not None and (gate <= 0 or d2 <= gate):
        forward_z = float(y[0] / np.sqrt(S[0, 0]))
        y0 = y[0] + (Hs @ x)[0]  # against the pose's prediction alone
        forward_var = float((Hp @ P @ Hp.T)[0, 0])
        forward_sq = float(y0**2 - forward_var)
    drop = np.zeros(3, dtype=bool) if leave_out is None else np.asarray(leave_out, dtype=bool).copy()
    if whiteness is not None and np.isfinite(forward_z):
        total, count, limit = whiteness
        left_out = (total + forward_z) ** 2 / (count + 1) > limit
        drop[0] |= left_out
    if drop.all():
        return x, P, Innovation(float("nan"), d2, forward_z, forward_sq, forward_var, left_out)
    if drop.any():
        T0 = np.eye(3)[~drop]  # the directions kept
        H, Hs, Hp, y, R0, Rm = T0 @ H, T0 @ Hs, T0 @ Hp, T0 @ y, T0 @ R0 @ T0.T, T0 @ Rm @ T0.T
        HPH = H @ P @ H.T
        S = HPH + Rm
    inn = Innovation(float("nan"), d2, forward_z, forward_sq, forward_var, left_out)
    if weak_only > 0:
        # Only the directions along which the filter knows the motion less well than the
        # step does (generalised eigenvectors of the two covariances, ratio above
        # ``weak_only``): elsewhere the step would add little and bring its own errors.
        err = Rm + Hs @ P @ Hs.T  # the step's error: its own and the correlated parts
        Li = np.linalg.inv(np.linalg.cholesky(err))
        lam, V = np.linalg.eigh(Li @ Hp @ P @ Hp.T @ Li.T)
        keep = lam > weak_only
        if bias is not None and not keep.all():
            return _learn_bias(x, P, H, y, Rm, R0, (Li.T @ V).T, keep, bias[0], inn)
        if not keep.any():
            return x, P, inn
        T = (Li.T @ V[:, keep]).T  # rows: the kept directions, whitened by the step's error
        H, y, R0, Rm, HPH = T @ H, T @ y, T @ R0 @ T.T, T @ Rm @ T.T, T @ HPH @ T.T
        S = HPH + Rm
    nis = float(y @ np.linalg.solve(HPH + R0, y)) / len(y)
    K = np.linalg.solve(S, H @ P).T  # P H^T S^-1 (S and P symmetric)
    if consider is not None:
        K[consider, :] = 0.0
    x = x + K @ y
    A = np.eye(len(x)) - K @ H
    P = A @ P @ A.T + K @ Rm @ K.T  # Joseph form: stays symmetric, positive
    return x, P, Innovation(nis, d2, forward_z, forward_sq, forward_var, left_out)


def _learn_bias(
    x: FloatArray,
    P: FloatArray,
    H: FloatArray,
    y: FloatArray,
    Rm: FloatArray,
    R0: FloatArray,
    T: FloatArray,
    keep: NDArray[np.bool_],
    at: int,
    inn: Innovation,
) -> tuple[FloatArray, FloatArray, Innovation]:
    """The update of a VO run with bias states (at index ``at``, three) where the filter
    knows some directions of its motion better than the run (``keep`` False along rows of
    ``T``, the directions whitened by the run's error): along those the run updates its
    biases alone (a Schmidt, or consider, update: the other states' gains set to 0;
    Schmidt 1966, Brink 2017), along the others every state as in :func:`_update`. So
    VO's drift is learned against ICP where ICP fixes the motion, and VO moves the pose
    only where the filter is weaker than it. The Joseph form keeps the covariance
    consistent with any gain."""
    H, y, Rm, R0 = T @ H, T @ y, T @ Rm @ T.T, T @ R0 @ T.T
    HPH = H @ P @ H.T
    if keep.any():  # the covariance matching's NIS, over the directions the pose takes
        k = np.ix_(keep, keep)
        nis = float(y[keep] @ np.linalg.solve(HPH[k] + R0[k], y[keep])) / int(keep.sum())
        inn = dataclasses.replace(inn, nis=nis)
    K = np.linalg.solve(HPH + Rm, H @ P).T
    others = np.ones(len(x), dtype=bool)
    others[at : at + 3] = False
    K[np.ix_(others, ~keep)] = 0.0
    x = x + K @ y
    A = np.eye(len(x)) - K @ H
    P = A @ P @ A.T + K @ Rm @ K.T
    return x, P, inn


def _predict(x: FloatArray, P: FloatArray, dt: float, params: KfParams) -> tuple[FloatArray, FloatArray]:
    """The constant-velocity prediction of the pose and velocity over dt; clones stay."""
    F = np.eye(len(x))
    F[:3, 3:6] = dt * np.eye(3)
    q = np.array([params.accel_sigma, params.accel_sigma, params.yaw_accel_sigma]) ** 2
    # White-acceleration noise integrated over dt, per axis: [[dt^3/3, dt^2/2], [dt^2/2, dt]].
    Q = np.zeros((len(x), len(x)))
    Q[:3, :3] = np.diag(q * dt**3 / 3.0)
    Q[:3, 3:6] = Q[3:6, :3] = np.diag(q * dt**2 / 2.0)
    Q[3:6, 3:6] = np.diag(q * dt)
    return _recorded(x, P, F, F @ x, F @ P @ F.T + Q)


def _rotation3(yaw: float) -> FloatArray:
    """The (3, 3) map of a motion (dx, dy, dyaw) from a frame turned by ``yaw`` into the
    frame it was turned from."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


class _IcpReference:
    """ICP's own path over an interval, the guard's reference (:func:`_vo_guard`): its steps
    chained, causally. A step counts once it has ended (``now``); the part of the interval
    after the last ended step (at most one step: a VO run ends between two scans) is
    carried at that step's constant twist, as :class:`_Drive` carries a step's parts. Whole
    steps are crossed at once: their chained poses and their own covariances turned into
    the chain's frame are summed ahead (prefix sums), so an interval costs a few steps'
    work however many it spans."""

    def __init__(self, steps: list[Increment], params: KfParams, source: str = "icp") -> None:
        self.steps = sorted(steps, key=lambda m: (m.t0, m.t1))
        self.t1s = np.array([m.t1 for m in self.steps])
        self.own, self.share = _error_model(source, params)
        # The distance (m) and turn (rad) of the steps ended by each step's end, summed
        # (the wheel witness's calibration, :class:`_WheelWitness`).
        self.distance = np.cumsum([float(np.hypot(*m.motion[:2])) for m in self.steps])
        self.turn = np.cumsum([float(m.motion[2]) for m in self.steps])
        # The steps leaving their forward direction open (a corridor's), counted up to each
        # step's end: their distance is no measurement (the wheels' calibration skips them).
        self.open = np.cumsum([m.covariance[0, 0] >= (OPEN_SIGMA_M / 10.0) ** 2 for m in self.steps])
        n = len(self.steps)
        # The chain's pose at each step's start (and the last one's end), its yaw, and the
        # steps' own covariances in the chain's frame summed before each step.
        self.poses = np.empty((n + 1, 3, 3))
        self.yaws = np.empty(n + 1)
        self.prefix = np.zeros((n + 1, 3, 3))
        T = np.eye(3)
        for k, d in enumerate(self.steps):
            self.poses[k], self.yaws[k] = T, np.arctan2(T[1, 0], T[0, 0])
            G = _rotation3(float(self.yaws[k]))
            self.prefix[k + 1] = self.prefix[k] + G @ _scaled(d.covariance, self.own) @ G.T
            T = T @ se2(d.motion)
        self.poses[n], self.yaws[n] = T, np.arctan2(T[1, 0], T[0, 0])
        # The last step of the unbroken run of steps (each starting where the one before ends) from each.
        self.run_end = np.arange(n)
        for k in range(n - 2, -1, -1):
            if self.steps[k + 1].t0 == self.steps[k].t1:
                self.run_end[k] = self.run_end[k + 1]

    def ended(self, now: float) -> tuple[float, float]:
        """The distance (m) and turn (rad) of the steps ended by ``now``, summed."""
        k = int(np.searchsorted(self.t1s, now, side="right"))
        return (float(self.distance[k - 1]), float(self.turn[k - 1])) if k else (0.0, 0.0)

    def between(
        self, a: float, b: float, now: float, scale: float = 1.0
    ) -> tuple[FloatArray, FloatArray] | None:
        """ICP's motion (dx, dy, dyaw) from ``a`` to ``b`` in the rig's frame at ``a``, and
        its covariance (3, 3) under ICP's error model (the steps' own parts summed, the
        shared parts of the first and last step: within the chain they cancel; times
        ``scale``, the covariance matching's factor), from the steps ended by ``now``; None
        where ICP's steps leave a gap."""
        k = int(np.searchsorted(self.t1s, a, side="right"))
        T, C, t = np.eye(3), np.zeros((3, 3)), a
        ends: list[tuple[FloatArray, FloatArray]] = []  # (rotation, covariance) of the first and last step
        while t < b:
            d = self.steps[k] if k < len(self.steps) else None
            if d is not None and d.t0 == t and d.t1 <= min(b, now):
                # Whole steps k ... last, ended by now and within the interval, at once.
                ended = int(np.searchsorted(self.t1s, min(b, now), side="right")) - 1
                last = min(int(self.run_end[k]), ended)
                turn = float(np.arctan2(T[1, 0], T[0, 0])) - float(self.yaws[k])
                G = _rotation3(turn)
                C += G @ (self.prefix[last + 1] - self.prefix[k]) @ G.T
                ends = [
                    ends[0] if ends else (_rotation3(turn + float(self.yaws[k])), d.covariance),
                    (_rotation3(turn + float(self.yaws[last])), self.steps[last].covariance),
                ]
                T = T @ np.linalg.inv(self.poses[k]) @ self.poses[last + 1]
                t, k = self.steps[last].t1, last + 1
                continue
            if d is not None and d.t0 <= t and d.t1 <= now:
                end = min(b, d.t1)
                k += 1
            else:
                # The step has not ended (or ICP has none yet): the last ended one's twist, from its
                # end on, for at most its length; a gap in ICP's steps: no reference.
                d = self.steps[k - 1] if k > 0 else None
                if d is None or d.t1 != t or d.t1 > now or b - t > d.t1 - d.t0:
                    return None
                end = b
            f = (end - t) / (d.t1 - d.t0)
            G = _rotation3(float(np.arctan2(T[1, 0], T[0, 0])))
            C += f * G @ _scaled(d.covariance, self.own) @ G.T
            ends = [ends[0] if ends else (G, d.covariance), (G, d.covariance)]
            T = T @ se2(_se2_exp(f * _se2_log(d.motion)))
            t = end
        for G, cov in ends:
            C += G @ _finite_part(_scaled(cov, self.share)) @ G.T
        return pose_of(T), scale * C


def _vo_guard(
    runs: list[tuple[Increment, FloatArray]],
    icp: tuple[FloatArray, FloatArray],
    correlation: FloatArray,
    gate: float,
    bias: tuple[FloatArray, FloatArray] | None = None,
    pays: float = 0.0,
) -> tuple[NDArray[np.bool_], FloatArray]:
    """The directions (forward, cross-track, yaw of the last run's frame) along which VO's
    chained runs and ICP's own steps over the same interval disagree beyond their errors,
    or (``pays`` > 0) along which VO's chain's variance exceeds ``pays`` times ICP's
    (fusing VO cannot pay there: :data:`VO_PAYS`), and the test's statistics (3,).

    ``runs``: VO's chained runs (each starting where the one before ends), each with its
    covariance under VO's error model (own and correlated parts); ``icp``: ICP's motion
    over the same interval and its covariance (:meth:`_IcpReference.between`), both in the
    rig's frame at the first run's start; ``correlation`` (L, 3): VO's runs' error
    correlation per axis at lags 1 ... L (forward from its Gauss-Markov memory, cross-track
    and yaw their lag-1 share); ``bias``: VO's biases' (sigma (3,), time constant (3,)),
    whose part of the runs' errors correlates as exp(-|t_i - t_j| / tau) (:func:`_bias_decay`).

    The chain's covariance is sum_ij G_i D_i C_ij D_j G_j^T (G_i a run's frame in the
    first's, D_i its standard deviations, C_ij the correlation of runs |i - j| apart; the
    run's own covariance where i = j), the difference's that plus ICP's (the two inputs'
    errors are independent). Each direction's squared difference over its variance is
    chi-square with 1 dof where both inputs' error models hold (Bar-Shalom, Li and
    Kirubarajan 2001, Section 5.4: a test of a measurement's consistency with another
    estimate of the same quantity); above ``gate`` VO is left out along it, unless ICP's
    steps leave it open (variance above (OPEN_SIGMA_M / 10)^2: a corridor ICP cannot fix,
    where VO carries the filter). So is a direction where V_aa > ``pays`` A_aa (ICP
    constraining it)."""
    vo, V, G = _vo_chain(runs, correlation, bias)
    d = vo - icp[0]
    d[2] = np.angle(np.exp(1j * d[2]))
    # In the last run's frame: its directions are the ones the update can leave out.
    d, V, A = G.T @ d, G.T @ V @ G, G.T @ icp[1] @ G
    stat = d**2 / np.diag(V + A)
    fired = stat > gate
    if pays > 0:
        fired |= np.diag(V) > pays * np.diag(A)
    out: NDArray[np.bool_] = fired & (np.diag(A) < (OPEN_SIGMA_M / 10.0) ** 2)
    return out, stat


def _vo_chain(
    runs: list[tuple[Increment, FloatArray]],
    correlation: FloatArray,
    bias: tuple[FloatArray, FloatArray] | None = None,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """VO's chained runs (:func:`_vo_guard`'s ``runs``, ``correlation``, ``bias``): their
    motion (3,) and its covariance (3, 3), both in the first run's frame, and the last
    run's frame in the first's (3, 3)."""
    T = np.eye(3)
    frames, sds = [], []
    V = np.zeros((3, 3))
    for m, cov in runs:
        G = _rotation3(float(np.arctan2(T[1, 0], T[0, 0])))
        frames.append(G)
        sds.append(np.sqrt(np.diag(cov)))
        V += G @ cov @ G.T
        T = T @ se2(m.motion)
    coef = [_bias_coefficients(m) for m, _ in runs]
    mid = [0.5 * (m.t0 + m.t1) for m, _ in runs]
    for i in range(len(runs)):
        for j in range(len(runs)):
            lag = abs(i - j)
            if 0 < lag <= len(correlation):
                V += frames[i] @ np.diag(correlation[lag - 1] * sds[i] * sds[j]) @ frames[j].T
            if bias is not None:
                b = bias[0] ** 2 * np.exp(-abs(mid[i] - mid[j]) / bias[1]) * coef[i] * coef[j]
                V += frames[i] @ np.diag(b) @ frames[j].T
    return pose_of(T), V, frames[-1]


class _WheelWitness:
    """The wheel odometry as the guard's third, independent witness (``KfParams.wheel_witness``,
    :func:`_witness`). The wheels' errors are mostly systematic (a wheel radius's scale
    error, a heading drift per metre from the wheel base: rigcal.sim.drive's model of them,
    and that of every differential drive), small per step; so their chain over a window of
    a few runs, corrected by a scale and a drift per metre calibrated against ICP's steps
    over all the distance driven so far (causally: the steps ended by ``now``), errs by its
    white noise alone. Before :data:`WHEEL_WITNESS_MIN_M` of calibration it gives no
    verdict."""

    def __init__(self, steps: list[Increment], icp: _IcpReference, params: KfParams) -> None:
        self.wheel = _IcpReference(steps, params, "wheel")
        self.icp = icp
        # The times the wheels had driven each further WHEEL_BLOCK_M (their distance
        # interpolated over their steps' ends): the scale's blocks.
        t1s, dist = self.wheel.t1s, self.wheel.distance
        marks = np.arange(1, int(dist[-1] // WHEEL_BLOCK_M) + 1) * WHEEL_BLOCK_M if len(dist) else np.zeros(0)
        self.blocks = np.interp(marks, dist, t1s) if len(marks) else np.zeros(0)
        self.start = float(steps[0].t0) if steps else 0.0

    def calibration(self, now: float) -> tuple[float, float] | None:
        """The wheels' scale (their distance over the true one) and heading drift (rad/m)
        from the steps ended by ``now``; None before :data:`WHEEL_WITNESS_MIN_M`. The
        scale: the median over the blocks of :data:`WHEEL_BLOCK_M` of the wheels' distance
        over ICP's, so that a stretch where ICP errs beyond its model (less than half the
        distance) does not move it, blocks where ICP leaves the travel open (a corridor)
        left out; the drift: the wheels' turn less ICP's over the distance."""
        dw, tw = self.wheel.ended(now)
        di, ti = self.icp.ended(now)
        if dw < WHEEL_WITNESS_MIN_M or di <= 0:
            return None
        ends = np.r_[self.start, self.blocks[self.blocks <= now]]
        icp_dist = np.diff(np.interp(ends, self.icp.t1s, self.icp.distance))
        # A block with a step ICP leaves open forward (a corridor's) measures no scale.
        opened = np.diff(
            self.icp.open[np.clip(np.searchsorted(self.icp.t1s, ends), 0, len(self.icp.t1s) - 1)]
        )
        moved = (icp_dist > 0) & (opened == 0)
        if not moved.any():
            return None
        return float(np.median(WHEEL_BLOCK_M / icp_dist[moved])), (tw - ti) / dw

    def calibrated_steps(self) -> list[Increment]:
        """The wheels' steps as a filter input (``KfParams.wheel_calibrated``): each with
        the calibration at its end (causal), its forward motion and turn (cross-track open:
        the heading's lever arm correlates it over steps), their covariance the steps' rate
        covariance times the ratio of one-run windows (:data:`WHEEL_WINDOW_RATIO`: forward
        0.09, yaw 1.24 on laps 1-2). Where no calibration is to be had yet (the first
        :data:`WHEEL_WITNESS_MIN_M`, or ICP open along the travel all the way: a corridor) a
        step over which ICP leaves the travel open is fused as it came
        (:data:`WHEEL_SIGMAS`): the wheels carry the filter there; one where ICP constrains
        it is left out (its scale error would only pull ICP's path)."""
        out = []
        ratio = np.asarray(WHEEL_WINDOW_RATIO[0])
        icp = self.icp
        for m in self.wheel.steps:
            cal = self.calibration(m.t1)
            if cal is None:
                k = np.clip(np.searchsorted(icp.t1s, [m.t0, m.t1]), 0, len(icp.t1s) - 1)
                if len(icp.t1s) and (
                    icp.open[k[1]] > icp.open[k[0]]
                    or icp.steps[k[1]].covariance[0, 0] >= (OPEN_SIGMA_M / 10.0) ** 2
                ):
                    out.append(m)
                continue
            scale, drift = cal
            dist = float(np.hypot(*m.motion[:2]))
            motion = np.array([m.motion[0] / scale, m.motion[1] / scale, m.motion[2] - drift * dist])
            cov = _scaled(m.covariance, ratio)
            cov[1, :] = cov[:, 1] = 0.0
            cov[1, 1] = OPEN_SIGMA_M**2
            out.append(Increment(m.t0, m.t1, motion, cov, "wheel"))
        return out

    def between(self, a: float, b: float, now: float, runs: int = 1) -> tuple[FloatArray, FloatArray] | None:
        """The wheels' calibrated motion (dx, dy, dyaw) from ``a`` to ``b`` in the rig's
        frame at ``a`` and its covariance (3, 3) (the steps' own, times
        :data:`WHEEL_WINDOW_RATIO` per axis for a window of ``runs`` VO runs, 1, 2, 4, 8 or
        more); None before the calibration or over a gap."""
        cal = self.calibration(now)
        ref = self.wheel.between(a, b, now) if cal is not None else None
        if cal is None or ref is None:
            return None
        scale, drift = cal
        arc = float(
            np.interp(b, self.wheel.t1s, self.wheel.distance)
            - np.interp(a, self.wheel.t1s, self.wheel.distance)
        )
        motion = ref[0].copy()
        motion[:2] /= scale
        motion[2] -= drift * arc
        ratio = WHEEL_WINDOW_RATIO[min(int(np.log2(max(runs, 1))), len(WHEEL_WINDOW_RATIO) - 1)]
        R = _rotation3(float(motion[2]))  # the ratio's axes: those of the frame at b
        return motion, R @ _scaled(R.T @ ref[1] @ R, np.asarray(ratio)) @ R.T


class _GyroWitness:
    """The gyroscope as the guard's heading witness (``KfParams.gyro_witness``,
    :func:`_witness`): its steps' yaw chained over a window, less its bias as the filter
    holds it. An inertial sensor's errors are its own (the rate gyro model's angle random
    walk and bias, module docstring), independent of the laser's and the camera's; with the
    bias learned at a standstill (to 0.006 deg/s over 3 s) its yaw over the guard's longest
    window (8 runs, 4 s) is good to about 0.5 mrad, where ICP's heading errs by milliradians.
    It witnesses the yaw alone (its translation open)."""

    def __init__(self, steps: list[Increment], reference: _IcpReference) -> None:
        self.steps = sorted(steps, key=lambda m: (m.t1, m.t0))
        self.t0s = np.array([m.t0 for m in self.steps])
        self.t1s = np.array([m.t1 for m in self.steps])
        self.reference = reference

    def between(
        self, a: float, b: float, now: float, bias: float, bias_var: float, scale: float = 1.0
    ) -> tuple[FloatArray, FloatArray] | None:
        """The gyro's motion from ``a`` to ``b`` (its translation 0 and open, variance
        :data:`OPEN_SIGMA_M`^2) and its covariance (3, 3): the yaw of its whole steps within
        the interval ended by ``now``, chained, less ``bias`` (rad/s) times their span, with
        the steps' own variance and the bias's (``bias_var`` times the span squared). The
        parts of the interval before the first such step and after the last (a VO run
        starts and ends between the gyro's steps, each under 0.1 s) are ICP's own turn over
        them (:meth:`_IcpReference.between`, its variance, times ``scale``, added): a part of
        a step taken at its mean rate, or at the last ended step's past it, errs by the
        rate's jumps within it, which the simulated drives make (their velocity changes in
        steps) and the gyro's steps cannot show (measured: docs/localization.md, "The
        gyroscope as the guard's heading witness"). Against ICP's chain those parts cancel:
        the test is over the gyro's steps. None where the gyro's steps leave a gap (a part
        longer than the gyro step it lies under included), none lies within, or ICP gives
        no reference."""
        i = int(np.searchsorted(self.t0s, a, side="left"))
        j = int(np.searchsorted(self.t1s, min(b, now), side="right"))
        steps = self.steps[i:j]
        if not steps or any(steps[k + 1].t0 != steps[k].t1 for k in range(len(steps) - 1)):
            return None
        g0, g1 = steps[0].t0, steps[-1].t1
        # Each part under one gyro step (ICP's turn fills no gap in the gyro's).
        before = a == g0 or (i > 0 and self.steps[i - 1].t1 == g0 and self.steps[i - 1].t0 <= a)
        after = b == g1 or (j < len(self.steps) and self.steps[j].t0 == g1 and self.steps[j].t1 >= b)
        if not (before and after):
            return None
        yaw = sum(float(m.motion[2]) for m in steps) - bias * (g1 - g0)
        var = sum(float(m.covariance[2, 2]) for m in steps) + bias_var * (g1 - g0) ** 2
        for lo, hi in ((a, g0), (g1, b)):
            if hi > lo:
                part = self.reference.between(lo, hi, now, scale)
                if part is None:
                    return None
                yaw += float(part[0][2])
                var += float(part[1][2, 2])
        return np.array([0.0, 0.0, yaw]), np.diag([OPEN_SIGMA_M**2, OPEN_SIGMA_M**2, var])


def _witness(
    runs: list[tuple[Increment, FloatArray]],
    icp: tuple[FloatArray, FloatArray],
    wheel: tuple[FloatArray, FloatArray],
    correlation: FloatArray,
    gate: float,
    bias: tuple[FloatArray, FloatArray] | None = None,
) -> tuple[NDArray[np.bool_], NDArray[np.bool_], FloatArray]:
    """The wheels' verdict over a window (:func:`_vo_guard`'s ``runs``, ``icp``,
    ``correlation``, ``bias``; ``wheel``: the wheels' calibrated motion over the same
    interval and its covariance, :meth:`_WheelWitness.between`), per direction of the last
    run's frame: where ICP errs (its chain and the wheels' disagree beyond both models, VO's
    and the wheels' do not), where VO errs (the other way round; not along a direction
    ICP leaves open, where VO carries the filter), and ICP's squared error beyond its
    model and the wheels' where it errs (m^2, rad^2; 0 elsewhere). Two tests of one
    estimate against another (Bar-Shalom, Li and Kirubarajan 2001, Section 5.4), each at
    ``gate`` (chi-square, 1 dof): with three independent inputs, the one that disagrees
    with both others is the one that errs."""
    vo, V, G = _vo_chain(runs, correlation, bias)

    def off(a: FloatArray, b: FloatArray) -> FloatArray:
        d = a - b
        d[2] = np.angle(np.exp(1j * d[2]))
        out: FloatArray = G.T @ d
        return out

    dv, di = off(vo, wheel[0]), off(icp[0], wheel[0])
    v, a, w = (np.diag(G.T @ c @ G) for c in (V, icp[1], wheel[1]))
    vo_off, icp_off = dv**2 / (v + w) > gate, di**2 / (a + w) > gate
    icp_errs = icp_off & ~vo_off
    vo_errs = vo_off & ~icp_off & (a < (OPEN_SIGMA_M / 10.0) ** 2)
    excess = np.where(icp_errs, np.maximum(0.0, di**2 - a - w), 0.0)
    return icp_errs, vo_errs, excess


class _Tape:
    """The filter's transitions, kept for the Rauch-Tung-Striebel backward pass
    (``KfParams.smooth``; Rauch, Tung and Striebel 1965; Bar-Shalom, Li and Kirubarajan
    2001, Section 8.6). Every change of the state between two updates is a linear(ised)
    map x' = F x (+ noise): the prediction (constant velocity or a driving step's part),
    a clone appended, a block of correlated error appended or marginalised, a
    Gauss-Markov state's decay, a covariance grown. Each is kept as the filtered state
    before it (x, P: all updates so far in), F and the state after it (x', P'); the
    backward pass runs them in reverse,

        C = P F^T P'^+,   x_s = x + C (x_s' - x'),   P_s = P + C (P_s' - P') C^T,

    P'^+ the pseudo-inverse (a clone makes P' singular: its copy carries no more than the
    pose), so that each kept output pose takes in the measurements after it. The
    filter's gates, guard and weights stay the forward pass's: the backward pass only
    spreads what was fused."""

    def __init__(self) -> None:
        self.ops: list[tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]] = []
        self.marks: dict[int, int] = {}  # output index -> transitions before it

    def record(self, x: FloatArray, P: FloatArray, F: FloatArray, x1: FloatArray, P1: FloatArray) -> None:
        self.ops.append((x, P, F, x1, P1))

    def mark(self, index: int) -> None:
        """Output ``index`` is the state after the transitions so far (and the updates)."""
        self.marks[index] = len(self.ops)

    def smooth(self, x: FloatArray, P: FloatArray) -> list[tuple[FloatArray, FloatArray]]:
        """The smoothed state (x, P) at each marked output, from the last filtered one."""
        at: dict[int, list[int]] = {}
        for index, n in self.marks.items():
            at.setdefault(n, []).append(index)
        out: dict[int, tuple[FloatArray, FloatArray]] = {}
        xs, Ps = x, P
        for j in range(len(self.ops), -1, -1):
            for index in at.get(j, []):
                out[index] = (xs, Ps)
            if j == 0:
                break
            x0, P0, F, x1, P1 = self.ops[j - 1]
            C = np.linalg.lstsq(P1, F @ P0, rcond=None)[0].T  # P0 F^T P1^+ (P1 symmetric)
            xs = x0 + C @ (xs - x1)
            Ps = P0 + C @ (Ps - P1) @ C.T
        return [out[i] for i in sorted(out)]


# The tape of the run_filter call under way (None: not smoothing).
_TAPE: ContextVar[_Tape | None] = ContextVar("kalman_tape", default=None)


def _recorded(
    x: FloatArray, P: FloatArray, F: FloatArray, x1: FloatArray, P1: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """(x1, P1), the transition x -> x1 = F x (+ noise) kept on the tape where smoothing."""
    tape = _TAPE.get()
    if tape is not None:
        tape.record(x, P, F, x1, P1)
    return x1, P1
