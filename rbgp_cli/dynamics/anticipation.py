"""A motion under way: the rest of it from its seen beginning (docs/method.md §13, MATH.md §12).

The seen samples (t_j, T_j) of a motion that started at t_0 = t[0] lie at phases s_j = (t_j − t_0)/D of
its unknown duration D. rbgp answers three questions with the path distribution N(m, Σ) of
:mod:`rbgp_cli.dynamics.paths` (scaled deviations from the mean path on 51 phases, and ℓ = ln D).

**How long, and where in the motion.** n ≤ ``points`` seen poses at evenly spaced times τ_k ∈ [0, span]
(interpolated: slerp, linear; the first and last seen always among them) are observations of the path at
phases τ_k/D, with the regularising tolerance r (:attr:`PathDistribution.seen_tolerance`, in units of each
coordinate's spread), and ℓ = ln D is observed exactly. On a log-spaced grid of durations D_g (from half
the shortest demonstration to twice the longest, those shorter than the seen span left out)

    w_g ∝ N( (y(D_g), ln D_g) | A_g m, A_g Σ A_gᵀ + R ),     y_k(D) = (log(R_k R̄(τ_k/D)ᵀ), p_k − p̄(τ_k/D)) / σ,

(after Maeda et al. 2017's phase estimation; a log-spaced grid makes the weight the density of ln D). The
weights (and the end pose's band) use their own τ² and r (``paths.duration_smooth``,
``paths.duration_tolerance``: :func:`fit_seen` keeps (0.01, 0.8) or the distribution's own, whichever estimated the
left-out demonstrations' durations best; with fewer than ten demonstrations also (0.01, 3.2) and τ² = 0.01 with,
instead of r, a tolerance σ = 0.3 rad and m for every coordinate (``paths.duration_sigma``, r_c = σ / σ_c), the
loosest within a standard error of the best); the conditioning of the rest uses the distribution's.
The predicted end time is t_0 + D̂ with D̂ the weights' median, or their mode in ln D where that estimated the
left-out durations better (``paths.duration_statistic``, :data:`DURATION_STATISTICS`); the phase of the last seen
sample is span / D̂. Its band is the 5 %/95 % quantiles of the weights with the seen poses' evidence weighted by
λ = ``paths.duration_evidence``, w_g ∝ t_ν(ℓ_g) (w_g / N(ℓ_g))^λ (N the weights' Gaussian prior of ℓ, t_ν its
Student-t, ν = D − 1), times D̂ over their own median (:meth:`Anticipator.band_shift`: their spread, centred on D̂):
:func:`fit_seen` takes the largest λ whose band holds enough left-out durations for 90 % on the next one
(:func:`finite_sample_count` of them, :func:`_evidence_loo`); the
samples draw their durations from these weights, moved the same way. A seen part less like the demonstrations than
their median (widening s > 1, below) has the band and the samples' durations stretched about D̂ in ln D by s,
D̂ (D / D̂)^s (:meth:`Anticipator.stretched`), and λ is chosen for the band so widened. One batched solve over the grid gives the weights and,
per D_g, the conditioned end pose. The end pose is the continuation's end; its band's covariance is the end's conditional
covariance at D̂ as the samples draw it (the path distribution's own τ² and r, the last seen pose exactly) plus the
spread of the per-D_g ends over the weights about their own mean (the duration's part).

**The rest.** At each duration the path distribution, with the rest's own smooth term τ²_rest K_ℓ, is conditioned
on the seen poses (tolerance r_rest), on the last seen pose exactly (:data:`~rbgp_cli.dynamics.paths.GOAL_TOLERANCE`, so the continuation starts where the
motion is) and on ℓ = ln D (exactly, or freed where :func:`fit_seen` finds the path distribution's coupling of ℓ to
the path over-fitted: :data:`REST_FREE_ELL`) and, where :func:`fit_seen` keeps one (``paths.rest_near_tolerance``), on
the pose one grid step D̂ / (S − 1) before the last with its own tolerance: with the last, where the motion is heading
(:meth:`Anticipator._near`, :func:`_choose_near`); the continuation's path is those paths' mean over the duration's weights on the remainder's normalised
time (:meth:`Anticipator._mixed_deviation`; the path at D̂ where one duration carries the weight), and it runs from the
last seen time to t_0 + D̂. Its mean is either that
conditioned path (``model=None``, the path distribution alone) or the model's GP dynamics rolled from the
last seen pose at its phase with the conditioned path as the prior mean's reference (feed-forward along
it and the pull toward it; the GP's residual field says how to move from an off-path pose). K samples draw
D from the weights (jittered within its grid cell) and a path from the distribution conditioned at that D
(Gaussian, scaled so that its 90 % regions are the Student-t predictive's (:func:`draw_scales`), widened by the
seen bands' factors), and displace the mean by the draw's difference from the
conditioned mean at D̂, so duration and path vary together and every sample starts at the last seen pose.

**The tolerance and the bands** (:func:`fit_seen`): each demonstration left out in turn, its first
F ∈ {0.2, 0.4, 0.6, 0.8} seen at its true phases, the rest predicted; r maximises the left-out remainders'
log density (over :data:`SEEN_TOLERANCE_GRID`). From :data:`REST_FROM` demonstrations on, the rest's
(τ²_rest, r_rest) are chosen on the left-out final pose and remainder given the seen part (:func:`_end_loo` with
``remainder``: the others' conditioned mean against the left-out demonstration at phase 1 and at the remainder's
scored phases, in units of each coordinate's spread, summed over the fractions) over :data:`REST_SMOOTH_GRID` ×
:data:`SEEN_TOLERANCE_GRID` and the path distribution's own (τ², r): of the candidates within :data:`REST_SE`
standard errors of the smallest, the one that trusts the seen poses least (:func:`_loosest_rest`);
with fewer, r_rest = r and τ²_rest is whichever of τ² and :data:`REST_FEW_SMOOTH` has the smaller left-out final
pose error (two candidates, not forty: the left-out ends are too few to choose among many). The mean is the rest's
conditioning; the samples' spread about it keeps the path distribution's (τ², r), the distribution the left-out
remainders' density chose, and the factors (c_rot(F), c_pos(F)), one pair per seen fraction F (:func:`seen_band_scales`), make those remainders' 90 % regions
hold about the rest's mean under it (as :func:`~rbgp_cli.dynamics.paths.fit_paths` does for the start-only
draws), narrowing below 1 as the goal bands' do; a draw at D_g takes them at its seen phase span / D_g
(:meth:`Anticipator.band_at`). With :data:`DURATION_SPREAD`, from :data:`SPREAD_FROM` demonstrations on, those
remainders are scored against the samples as they are drawn, each at its own duration, at every grid phase after F
in the remainder's normalised time (:func:`_spread_terms`, :func:`_spread_factors`). A path distribution without
them (an older model file) uses its pooled pair ``seen_band_scale`` ≥ 1 at every phase. Plain conditioning (r → 0) over-fits the seen part and its bands collapse (the plain ProMP's failure).
From :data:`SURPRISE_FROM` demonstrations on the bands also widen with the seen part's surprise: ρ = eᵀG⁻¹e / n, the
seen poses' and ln D̂'s innovation under the path distribution's own Σ and r per observed number, against the
left-out seen parts' median ρ̄_F, s = √max(1, ρ / ρ̄_F) (:func:`surprise_scale`, :meth:`Anticipator.surprise_at`);
the factors are fitted on the left-out needs divided by each one's own s, so a seen part as surprising as the median
keeps them and a later session that drifted, less like the demonstrations, is widened (docs/method.md §13).

**Leaving the demonstrations.** The seen part is "off" when the last seen pose's Mahalanobis distance under
the prior's marginal at its estimated phase exceeds :data:`OFF_DISTANCE` (3.5: a χ with 6 degrees of
freedom, beyond which fewer than 1 in 200 demonstrations lie), or when the motion has already lasted longer
than any duration on the grid.

Only samples up to the last seen one enter: nothing here reads past ``t[-1]``.
"""

from __future__ import annotations

import functools
import math
from collections import deque
from dataclasses import dataclass, field, replace

import numpy as np

from rbgp_cli.dynamics.paths import GOAL_TOLERANCE, NARROW_FROM
from rbgp_cli.dynamics.variation import SURPRISE_FROM, surprise_scale
from rbgp_cli.errors import InputError
from rbgp_cli.geometry.conventions import SMALL_ANGLE
from rbgp_cli.geometry.so3 import PI_TOLERANCE

__all__ = ["Anticipator", "Anticipation", "Continuation", "anticipate", "fit_seen", "seen_band_scales",
           "surprise_scale", "Follower", "initial_rests", "rest_before_moving", "SEEN_TOLERANCE_GRID",
           "SEEN_FRACTIONS", "SEEN_POINTS", "DURATION_GRID", "DURATION_SMOOTH_GRID", "DURATION_TOLERANCE_GRID",
           "REST_SMOOTH_GRID", "REST_FROM", "REST_FEW_SMOOTH", "MIX_WEIGHT", "duration_tolerances"]

#: Regularising tolerances r tried by :func:`fit_seen` (units of each coordinate's spread).
SEEN_TOLERANCE_GRID = (0.05, 0.1, 0.2, 0.4, 0.8, 1.6, 3.2)
#: Fractions of a left-out demonstration seen in :func:`fit_seen`.
SEEN_FRACTIONS = (0.2, 0.4, 0.6, 0.8)
#: The end band's factors are fitted at SEEN_FRACTIONS and at this one, where a motion is nearly done (what
#: ``follow`` reports until the end; twenty-first pass): there the band is the last seen pose's short continuation.
END_LATE = 0.95
#: Seen poses (evenly spaced in time) that enter the phase estimate and the conditioning.
SEEN_POINTS = 12
#: Durations on the grid of the phase estimate, log-spaced over GRID_RANGE times the demonstrations'
#: shortest and longest.
DURATION_GRID = 32
GRID_RANGE = (2.0 / 3.0, 1.5)
#: Above this Mahalanobis distance (a χ with 6 degrees of freedom: fewer than 1 in 200 demonstrations lie
#: beyond 3.5) the last seen pose has left what the demonstrations cover.
OFF_DISTANCE = 3.5
#: The continuation's mean averages the conditioned paths of the duration cells whose weight is at least this
#: fraction of the largest (:meth:`Anticipator._mixed_deviation`; the others' share is left out, renormalised)
MIX_WEIGHT = 1e-3
#: :class:`Follower`: a duration cell whose weight is below this fraction of the largest is not evaluated
#: at the next update (unless it neighbours one that is); every cell is, for the first ACTIVE_AFTER poses
ACTIVE_WEIGHT = 1e-6
ACTIVE_AFTER = 8
#: The duration's weights have their own τ² (smooth shrinkage) and seen tolerance r (units of each coordinate's
#: spread), chosen by :func:`fit_seen` from these and the path distribution's own τ² and r (docs/defaults.md)
DURATION_SMOOTH_GRID = (0.01,)
DURATION_TOLERANCE_GRID = (0.8,)
#: With fewer demonstrations than DURATION_FEW_BELOW, :func:`fit_seen` also weighs this looser (τ², r) for the
#: duration: the seen poses' fit to the few directions of Σ that so few span is worth less there than the
#: durations' own prior (docs/defaults.md, issue 37's tenth pass: the end time of studies of five 2–15 % closer,
#: and with more demonstrations the final pose of the slower handovers worse beyond the scatter)
DURATION_FEW = (0.01, 3.2)
DURATION_FEW_BELOW = NARROW_FROM
#: ... and τ² = DURATION_FEW[0] with a seen tolerance of DURATION_FEW_SIGMA in radians and metres for every
#: coordinate (r_c = σ / σ_c in units of each coordinate's spread σ_c; the ridge ProMP's choice on these sets), the
#: loosest candidate of all: with so few, the spreads a tolerance in their units is scaled by are themselves a guess
#: (docs/defaults.md, issue 37's twelfth pass)
DURATION_FEW_SIGMA = 0.3
#: ... and there it takes the loosest candidate (the tolerance in rad and m, then the largest r, then the smallest
#: τ²) whose left-out error is within this many standard errors of the smallest (:func:`_loosest_within`; the
#: one-standard-error rule of Hastie, Tibshirani and Friedman, §7.10: with four demonstrations per left-out fit the
#: smallest error is a noisy winner; docs/defaults.md, issue 37's eleventh pass)
DURATION_FEW_SE = 1.0
#: Groups the demonstrations are left out in when :func:`fit_seen` chooses the duration's τ² and r
DURATION_FOLDS = 5
#: The weights λ of the seen poses' evidence in the duration's band tried by :func:`fit_seen`,
#: w_g ∝ p(ℓ_g) p(y | ℓ_g)^λ (the prior of ln D whole): the evidence of 6n correlated coordinates under a Gaussian
#: fitted to a few demonstrations is overconfident (with λ = 1 the 90 % end-time bands held 0.16–0.93 of the held-out
#: motions' end times, 0.6–0.85 on most sets); the largest λ whose band holds :func:`finite_sample_count` of the n
#: left-out durations at the bands' level (:func:`_evidence_loo`). The band and the samples' durations use it, moved onto the point estimate; the
#: point estimate (the median) and the end pose keep λ = 1, which estimated the left-out durations best
#: (docs/defaults.md, issue 37's thirteenth pass)
#: Steps of √2 (twenty-second pass: with the band widened by the seen part's surprise the left-out bands hold more at
#: each λ, and a step of 2 left them at 0.94–0.95 where the next λ up held less than 0.90)
DURATION_EVIDENCE_GRID = tuple(float(2.0 ** (-k / 2.0)) for k in range(15))
#: The point estimate D̂ of the duration: the weights' median, or their mode in ln D (refined by a parabola through
#: the log weights, :func:`_log_mode`: the maximum-a-posteriori phase speed of Maeda et al.'s estimate). The median
#: is the best guess under absolute error where the weights describe the durations; a second mode they give to
#: durations no demonstration like this one had pulls it between the two, and the mode does not follow. Chosen per
#: model by :func:`fit_seen` on the left-out beginnings that choose the duration's τ² and r: the mode where its
#: |ln D̂ − ln D| is smaller than the median's by more than DURATION_MODE_SE paired standard errors (docs/defaults.md,
#: issue 37's twenty-seventh pass). ``paths.duration_statistic``: "mode", or None for the median (older files too).
#: The seen part's surprise is measured at the median whichever D̂ is (:meth:`Anticipator._summary`), as its
#: left-out reference is (:func:`_spread_terms`, :func:`_evidence_loo`): a reference the statistic does not move.
DURATION_STATISTICS = ("median", "mode")
DURATION_MODE_SE = 1.0
#: The conditioning of the rest has its own τ² and r, chosen by :func:`fit_seen` on the left-out final pose and
#: remainder from these τ² (and the path distribution's own) × SEEN_TOLERANCE_GRID, from REST_FROM demonstrations on (with fewer
#: the left-out ends are too few to choose among so many: docs/defaults.md, issue 37's fourth pass; see REST_FEW_SMOOTH)
REST_SMOOTH_GRID = (0.01, 0.03, 0.1, 0.3, 1.0)
REST_FROM = NARROW_FROM
#: ... and there it takes the candidate that trusts the seen poses least (the largest r, then the largest τ²) among
#: those whose left-out end-and-remainder error is within this many standard errors of the smallest
#: (:func:`_loosest_rest`; the smallest of 48 noisy errors is an optimistic winner: docs/defaults.md, issue 37's
#: fifteenth pass)
REST_SE = 1.0
#: ... and with fewer, the rest keeps the seen r and takes this τ² instead of the path distribution's own where it
#: predicts the left-out final pose better (:func:`_end_loo`): the seen part's relation to the end then comes mostly
#: from the smooth process, not from the D − 1 directions so few demonstrations span (studies of five: chosen in 5,
#: 4, 4 and 2 of the five subsets of the slower handovers, hand raises, handovers and waves; in no fold of the waves'
#: eight nor of sample_data's six; docs/defaults.md, issue 37's twelfth pass)
REST_FEW_SMOOTH = 10.0
#: ... and then whether the rest's conditioning also sees the pose one grid step of the path (D̂ / 50) before the last seen
#: one, with the best of these tolerances (units of each coordinate's spread, those below r_rest), kept where it beats
#: none by more than REST_SE standard errors, both scored at the left-out demonstrations' estimated durations
#: (:func:`_rest_at_estimates`). With the last seen pose it says where the motion is heading, which r_rest's looseness,
#: chosen against over-fitting the seen part as a whole, leaves out (docs/defaults.md, twenty-fourth pass)
REST_NEAR_GRID = (0.05, 0.1, 0.2, 0.4, 0.8, 1.6)
#: Tolerance of the exactly observed ln D (in units of ln D's spread) and of the last seen pose.
_ELL_TOL = 1e-4
#: ... and of ln D in the rest's conditioning where :func:`fit_seen` frees it (``paths.rest_duration_tolerance``):
#: 10³ spreads, ln D as good as not given, so a duration cell's path differs from another's only by where the seen
#: poses lie on it, not by the path distribution's coupling of ln D to the path (chosen by the rest's left-out
#: end and remainder: over-fitted on the 30 handovers and sample_data, real on the waves and the slower handovers;
#: docs/defaults.md, issue 37's twentieth pass)
REST_FREE_ELL = 1e3


# ----------------------------------------------------------------------------------------- results
@dataclass
class Anticipation:
    """What is known after the seen part: the last seen time ``t`` and the estimated ``phase`` there,
    ``end_time`` (t_0 + D̂) with ``end_time_band`` (5 %, 95 %) on the seen clock, ``end_quat`` (4,) x, y, z, w
    and ``end_position`` (3,) m with their 90 % half-widths ``end_rotation_band`` (rad, the angle) and
    ``end_position_band`` (3,) m, ``off`` (the seen part has left what the demonstrations cover) and
    ``distance`` (the last seen pose's Mahalanobis distance under the prior at its phase), ``band_widening`` (the
    factor s ≥ 1 the bands were widened by for a seen part less like the demonstrations than their median:
    :meth:`Anticipator.surprise_at`)."""

    t: float
    phase: float
    end_time: float
    end_time_band: tuple
    end_quat: np.ndarray
    end_position: np.ndarray
    end_rotation_band: float
    end_position_band: np.ndarray
    off: bool
    distance: float
    band_widening: float = 1.0

    def to_dict(self) -> dict:
        return {"t": float(self.t), "phase": float(self.phase), "end_time": float(self.end_time),
                "end_time_band": [float(x) for x in self.end_time_band],
                "end_quat": [float(x) for x in self.end_quat], "end_position": [float(x) for x in self.end_position],
                "end_rotation_band": float(self.end_rotation_band),
                "end_position_band": [float(x) for x in self.end_position_band],
                "off": bool(self.off), "distance": float(self.distance), "band_widening": float(self.band_widening)}


@dataclass
class Continuation:
    """The predicted rest of a motion: ``t`` (T,) on the seen clock from the last seen time to the predicted
    end; ``quat`` (T, 4) x, y, z, w, ``position`` (T, 3) m the mean; ``samples``: K (t, quat, position)
    triples, each to its own end; ``estimate``: the :class:`Anticipation`; ``duration`` D̂ s."""

    t: np.ndarray
    quat: np.ndarray
    position: np.ndarray
    samples: list
    estimate: Anticipation
    duration: float
    name: str = "0"
    info: dict = field(default_factory=dict)

    def trajectories(self, include_samples: bool = False) -> list:
        """The mean as a :class:`~rbgp_cli.dynamics.trajectory.Trajectory` named ``name`` and, optionally,
        the samples (``name.s0``, …)."""
        from rbgp_cli.dynamics.trajectory import Trajectory

        out = [Trajectory(self.t, self.quat, self.position, name=self.name)]
        if include_samples:
            out += [Trajectory(t, q, p, name=f"{self.name}.s{k}") for k, (t, q, p) in enumerate(self.samples)]
        return out


# ----------------------------------------------------------------------------------------- helpers
def _seen(t, quat, position, points: int, checked: bool = False):
    """The seen motion checked, and n ≤ points poses at evenly spaced times τ (n,) from its start (the first
    and last seen among them): (t (N,), quat (N, 4), position (N, 3), τ (n,), q (n, 4), p (n, 3)); q's signs
    are those of the samples they lie between (every caller takes a canonical log, which does not see them).
    ``checked``: the arrays are already float, finite, increasing in time, unit and sign-continuous (a
    :class:`Follower`'s buffer), so the O(N) checks are skipped."""
    from rbgp_cli.geometry.so3 import quat_make_continuous, quat_normalize

    if not checked:
        t = np.asarray(t, dtype=np.float64).reshape(-1)
        quat = np.asarray(quat, dtype=np.float64).reshape(-1, 4)
        position = np.asarray(position, dtype=np.float64).reshape(-1, 3)
        if len(t) < 1 or len(quat) != len(t) or len(position) != len(t):
            raise InputError("a seen motion needs times, quaternions and positions of the same length, at least one",
                             param="seen")
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(quat)) and np.all(np.isfinite(position))):
            raise InputError("the seen motion has missing (NaN) values", hint="read it with rbgp's readers, which repair them",
                             param="seen")
        if len(t) > 1 and not np.all(np.diff(t) > 0):
            raise InputError("the seen motion's times must increase", param="seen")
        quat = quat_make_continuous(quat_normalize(quat))
    span = float(t[-1] - t[0])
    if len(t) == 1 or span <= 0:
        return t, quat, position, np.zeros(1), quat[:1], position[:1]
    tau = np.linspace(0.0, span, max(int(min(points, len(t))), 2))
    q, p = _slerp_samples(t - t[0], quat, position, tau)
    return t, quat, position, tau, q, p


def _slerp_samples(x, quat, position, x_new):
    """Poses at ``x_new`` (n,) inside [x_0, x_(N−1)] of samples at ``x`` (N,) increasing, ``quat`` (N, 4) unit and
    sign-continuous, ``position`` (N, 3): with x_k ≤ x_new < x_(k+1), f its fraction of the interval and c =
    ⟨q_k, q_(k+1)⟩ ≥ 0, Ω = atan2(‖q_(k+1) − c q_k‖, c),

        q = cos(fΩ) q_k + sin(fΩ) (q_(k+1) − c q_k) / sin Ω,    p = (1 − f) p_k + f p_(k+1),

    the slerp of :func:`~rbgp_cli.dynamics.trajectory.interpolate_poses` (q_k ⊗ exp(f log(q_k* ⊗ q_(k+1))),
    the same rotation to rounding) in a dozen array operations: the live update calls it at every pose.
    sin(fΩ)/sin Ω → f as Ω → 0."""
    k = np.minimum(np.maximum(np.searchsorted(x, x_new, side="right") - 1, 0), len(x) - 2)
    x0 = x[k]
    f = np.minimum(np.maximum((x_new - x0) / (x[k + 1] - x0), 0.0), 1.0)
    q0, q1 = quat[k], quat[k + 1]
    c = np.einsum("ni,ni->n", q0, q1)
    d = q1 - c[:, None] * q0
    s = np.sqrt(np.einsum("ni,ni->n", d, d))
    om = np.arctan2(s, c)
    tiny = s < 1e-12
    ratio = np.where(tiny, f, np.sin(f * om) / np.where(tiny, 1.0, s))
    q = np.cos(f * om)[:, None] * q0 + ratio[:, None] * d
    p0 = position[k]
    return q, p0 + f[:, None] * (position[k + 1] - p0)


def _add_kron_i6(out: np.ndarray, K: np.ndarray) -> None:
    """out (..., 6a, 6b) += K (..., a, b) ⊗ I_6 in place (``out`` may be a view): the smooth term τ² K_ℓ ⊗ I_6 of
    Σ adds K_ℓ's entry (a, b) to coordinate c of phase a against coordinate c of phase b, for each c; one strided
    slice per coordinate, not a dense (6a, 6b) Kronecker product (three times faster at the live update's size)."""
    for c in range(6):
        out[..., c::6, c::6] += K


def _diagonal(A: np.ndarray, start: int, stop: int) -> np.ndarray:
    """A writable view (B, stop − start) of the diagonal entries start … stop − 1 of each of a C-contiguous batch of
    square matrices A (B, K, K): the flat entries j (K + 1), a basic strided slice (no fancy-index gather). An A whose
    flat form would be a copy (an addition to it lost) raises AttributeError, as numpy's in-place reshape does (not
    by setting ``shape``: deprecated in NumPy 2.5)."""
    B, K = A.shape[0], A.shape[-1]
    flat = A.reshape(B, K * K)
    if not np.may_share_memory(flat, A):
        raise AttributeError("_diagonal needs a batch of matrices whose flat form is a view (C-contiguous)")
    return flat[:, start * (K + 1):stop * (K + 1):K + 1]


def _left_basis() -> np.ndarray:
    """L(a) with a ⊗ b = L(a) b, as Σ_c a_c L(e_c): (4 components c, 16) (rows of the 4 × 4 matrices), from
    :func:`~rbgp_cli.geometry.so3.quat_multiply` on the basis quaternions."""
    from rbgp_cli.geometry.so3 import quat_multiply

    e = np.eye(4)
    return np.stack([np.stack([quat_multiply(e[c], e[j]) for j in range(4)], axis=1) for c in range(4)]).reshape(4, 16)


_LEFT = _left_basis()


def _log_unit(d: np.ndarray) -> np.ndarray:
    """The canonical rotation vector (..., 3) of unit quaternions d (..., 4) (:func:`~rbgp_cli.geometry.so3.log_quat`
    without its checks and normalisation: θ = 2 atan2(‖v‖, |w|), v θ/‖v‖ signed as w, its series below
    SMALL_ANGLE); angles at π within PI_TOLERANCE go through log_quat (its tie-break)."""
    v, w = d[..., :3], d[..., 3]
    s = np.sqrt(np.einsum("...i,...i->...", v, v))
    aw = np.abs(w)
    theta = 2.0 * np.arctan2(s, aw)
    if theta.size and theta.max() >= np.pi - PI_TOLERANCE:
        from rbgp_cli.geometry.so3 import log_quat

        return log_quat(d)
    sign = np.where(w < 0, -1.0, 1.0)
    small = s < SMALL_ANGLE
    if small.any():
        x2 = (s / np.where(small, aw, 1.0)) ** 2
        scale = np.where(small, 2.0 / np.where(small, aw, 1.0) * (1.0 - x2 / 3.0 + x2 * x2 / 5.0),
                         theta / np.where(small, 1.0, s))
    else:
        scale = theta / s
    return v * (sign * scale)[..., None]


#: The level of the bands the continuations' draws are scaled for (:func:`draw_scales`).
DRAW_LEVEL = 0.90


@functools.lru_cache(maxsize=64)
def draw_scales(nu: int, level: float = DRAW_LEVEL) -> tuple[float, float]:
    """(k_rot, k_pos): the scales of Gaussian draws whose ``level`` regions are those of the Student-t predictive
    with ν degrees of freedom that the bands' factors are fitted against (:func:`seen_band_scales`,
    :func:`_spread_factors`): a rotation's 3-D region m² ≤ 3 F_level(3, ν), a position coordinate's |z| ≤ t_ν,

        k_rot = √(3 F_level(3, ν) / χ²_3,level),    k_pos = t_ν,(1+level)/2 / z_(1+level)/2.

    Why not Student-t draws (u = √(ν/χ²_ν) per draw, as before issue 37's ninth pass): a band is computed from a
    few draws as a Gaussian fits them (crossval's per-axis interval and 3-D Hotelling ellipsoid), and with few
    demonstrations (ν = 3 at five) a draw's heavy tail widens that ellipsoid only along its own direction: with five
    demonstrations the 3-D rotation region of 20 Student-t draws held 0.05–0.11 less than that of 20 such Gaussian
    draws (docs/defaults.md, issue 37's ninth pass); per axis (position) it did not lose. ν → ∞: both → 1."""
    from scipy.special import chdtri, fdtri, ndtri, stdtrit

    nu = max(int(nu), 1)
    return (float(np.sqrt(3.0 * fdtri(3, nu, level) / chdtri(3, 1.0 - level))),
            float(stdtrit(nu, 0.5 + level / 2.0) / ndtri(0.5 + level / 2.0)))


# ----------------------------------------------------------------------------------------- the estimator
class Anticipator:
    """The phase estimate and conditioning of a :class:`~rbgp_cli.dynamics.paths.PathDistribution` on a seen
    beginning (module docstring), with its prior (m, Σ) computed once; ``model``: a
    :class:`~rbgp_cli.dynamics.model.MotionModel` whose GP dynamics give the continuation's mean (None: the
    conditioned path); ``mix_end``: the estimate's end pose is the continuation's (the mean over the duration's
    weights of the rest's conditioned ends), or with False the rest's conditioned end at D̂; ``duration_statistic``:
    D̂ the weights' "median" or "mode" (None: the path distribution's choice, :func:`fit_seen`)."""

    def __init__(self, paths, model=None, *, points: int = SEEN_POINTS, grid_size: int = DURATION_GRID,
                 tolerance: float | None = None, duration_smooth: float | None = None,
                 duration_tolerance: float | None = None, duration_sigma: float | None = None,
                 duration_evidence: float | None = None, mix_end: bool = True, duration_statistic: str | None = None):
        if paths is None:
            raise InputError("this model has no path distribution to predict a motion under way (fewer than three "
                             "demonstrations, or a model file from an older rbgp)",
                             hint="retrain it with rbgp train on three demonstrations or more")
        self.paths = paths
        self.model = model
        self.points = int(points)
        #: the estimate's end: the mean over the duration's weights of the rest's conditioned ends (the continuation's),
        #: or with False the one at D̂ (:class:`Follower`: one conditioning per update)
        self.mix_end = bool(mix_end)
        self.tolerance = float(paths.seen_tolerance if tolerance is None else tolerance)
        # the duration's weights (and the estimate's end pose) with their own τ² and r, or σ in rad and m (module
        # docstring): given, else fit_seen's choice, else the path distribution's τ² and seen tolerance
        if duration_smooth is None:
            duration_smooth = getattr(paths, "duration_smooth", None)
        if duration_tolerance is None and duration_sigma is None:
            duration_tolerance = getattr(paths, "duration_tolerance", None)
            duration_sigma = getattr(paths, "duration_sigma", None)
        self.duration_smooth = float(paths.smooth if duration_smooth is None else duration_smooth)
        self.duration_tolerance = float(self.tolerance if duration_tolerance is None else duration_tolerance)
        self.duration_sigma = None if duration_sigma is None else float(duration_sigma)
        self._duration_r2 = duration_tolerances(paths, self.duration_tolerance, self.duration_sigma) ** 2
        if duration_evidence is None:
            duration_evidence = getattr(paths, "duration_evidence", None)
        self.duration_evidence = 1.0 if duration_evidence is None else float(duration_evidence)
        #: D̂: the duration weights' "median" or "mode" (DURATION_STATISTICS; given, else fit_seen's choice)
        self.duration_statistic = str(duration_statistic or getattr(paths, "duration_statistic", None) or "median")
        if self.duration_statistic not in DURATION_STATISTICS:
            raise ValueError(f"duration_statistic {self.duration_statistic!r}: one of {DURATION_STATISTICS}")
        # the rest's mean conditioned with its own τ² and r (fit_seen), else the path distribution's; the samples'
        # spread about it (and the off distance) keep the path distribution's Σ and r
        rest_smooth = getattr(paths, "rest_smooth", None)
        rest_tolerance = getattr(paths, "rest_tolerance", None)
        self.rest_smooth = float(paths.smooth if rest_smooth is None else rest_smooth)
        self.rest_tolerance = float(self.tolerance if (rest_tolerance is None or tolerance is not None) else rest_tolerance)
        rest_ell = getattr(paths, "rest_duration_tolerance", None)
        #: ln D's tolerance in the rest's conditioning (units of its spread): exact, or freed by fit_seen
        self.rest_ell = float(_ELL_TOL if (rest_ell is None or tolerance is not None) else rest_ell)
        rest_near = getattr(paths, "rest_near_tolerance", None)
        #: the tolerance of the near pose in the rest's conditioning (:meth:`_near`; None: no near pose)
        self.rest_near = None if (rest_near is None or tolerance is not None) else float(rest_near)
        self.m, self.Sigma = paths.prior()
        self.Sigma_rest = self.Sigma if self.rest_smooth == paths.smooth else paths.prior(smooth=self.rest_smooth)[1]
        self.scale = paths.scale
        self.lscale = paths.duration_scale
        d = np.exp(paths.log_durations)
        self.grid = np.exp(np.linspace(np.log(GRID_RANGE[0] * d.min()), np.log(GRID_RANGE[1] * d.max()), int(grid_size)))
        self._half_step = 0.5 * (np.log(self.grid[1]) - np.log(self.grid[0])) if len(self.grid) > 1 else 0.0
        S = paths.S
        self._end = 6 * (S - 1) + np.arange(6)
        self._band = getattr(paths, "seen_band_scale", None) or paths.band_scale
        # the factors per seen fraction (fit_seen); files without them keep the pooled pair for every phase
        per_F = getattr(paths, "seen_band_scales", None)
        self._band_F = None if not per_F else (np.asarray(per_F["fractions"], float), np.asarray(per_F["rotation"], float),
                                               np.asarray(per_F["position"], float))
        # the end band's own factors per seen fraction (fit_seen); files without them use the draws' (band_at)
        per_end = getattr(paths, "seen_end_band_scales", None)
        self._end_F = None if not per_end else (np.asarray(per_end["fractions"], float),
                                                np.asarray(per_end["rotation"], float), np.asarray(per_end["position"], float))
        # the left-out reference of the seen part's surprise, for the number of seen poses nearest this one's
        sur = getattr(paths, "seen_surprise", None)
        self._surprise = None
        if sur:
            row = int(np.argmin([abs(int(n) - self.points) for n in sur["points"]]))
            self._surprise = (np.asarray(sur["fractions"], float), np.asarray(sur["reference"][row], float))
        from rbgp_cli.dynamics.model import PathReference

        self._ref = PathReference({"s": paths.s, "quat": paths.quat, "position": paths.position,
                                   "velocity": np.zeros((S - 1, 6))})
        #: the speed a motion leaves rest above (m/s): a tenth of the mean path's length over exp(mean ln D)
        length = float(np.sum(np.linalg.norm(np.diff(paths.position, axis=0), axis=1)))
        self.rest_speed = 0.1 * length / float(np.exp(np.mean(paths.log_durations)))
        #: the longest rest a demonstration begins with (s, initial_rests): a live motion begins at most this long
        #: before it left rest (Follower); a seen part that rests longer is said (rbgp_cli.workflows.continue_motions)
        self.lead = float(np.max(initial_rests(paths, self.rest_speed)))
        #: ... read off the phase grid to its step (s): on the real recordings the demonstrations' own detected
        #: departures (rest_before_moving) come at most 0.04 s after their grid rests
        self.lead_step = float((paths.s[1] - paths.s[0]) * np.exp(np.max(paths.log_durations)))

    def band_at(self, phase: float) -> tuple[float, float]:
        """The bands' factors (c_rot, c_pos) of a motion seen up to ``phase``: :func:`fit_seen`'s per-fraction
        factors interpolated linearly in the phase (the first and last held outside the fractions), or, for a
        path distribution without them (an older model file), the pooled ``seen_band_scale`` at every phase."""
        if self._band_F is None:
            return self._band
        F, rot, pos = self._band_F
        return float(np.interp(phase, F, rot)), float(np.interp(phase, F, pos))

    def end_band_at(self, phase: float) -> tuple[float, float]:
        """The end band's factors (c_rot, c_pos) of a motion seen up to ``phase``: :func:`fit_seen`'s end factors per
        fraction (:func:`_end_needs`) interpolated linearly in the phase (held outside the fractions), each never below
        the draws' :meth:`band_at` there (the left-out statistic sees each beginning at its true phases and is
        optimistic near the end: docs/defaults.md, twenty-first pass); for a path distribution without them (an older
        model file, or fewer than SPREAD_FROM demonstrations) the draws' factors."""
        draws = self.band_at(phase)
        if self._end_F is None:
            return draws
        F, rot, pos = self._end_F
        return max(draws[0], float(np.interp(phase, F, rot))), max(draws[1], float(np.interp(phase, F, pos)))

    def surprise(self, tau, q, p, D) -> float:
        """The seen part's surprise ρ = eᵀG⁻¹e / n of a motion seen at (τ (n_s,) s, q (n_s, 4), p (n_s, 3)) with
        duration D: e = y − A m the seen poses' deviations at phases τ / D and ℓ = ln D against the prior mean,
        G = A Σ Aᵀ + diag r² with the path distribution's own τ² and seen tolerance r on every seen pose (ℓ:
        _ELL_TOL), n = 6 n_s + 1 (:meth:`_grid_terms` at the one duration D)."""
        quad, k6 = self._grid_terms(tau, q, p, np.array([max(float(D), float(tau[-1]), 1e-9)]), tau2=self.paths.smooth,
                                    r2=np.full(6, self.tolerance ** 2))[3:5]
        return float(quad[0]) / k6

    def surprise_at(self, tau, q, p, D, rho: float | None = None) -> float:
        """The bands' widening s = √max(1, ρ / ρ̄_F) (:func:`surprise_scale`) of a motion seen at (τ, q, p) with
        duration D: its :meth:`surprise` ρ (or ``rho``, computed already) against fit_seen's left-out reference ρ̄_F
        interpolated at the seen phase τ[-1] / D (held outside the fractions). 1 for a path distribution without
        the reference."""
        if self._surprise is None:
            return 1.0
        F, ref = self._surprise
        rho = self.surprise(tau, q, p, D) if rho is None else float(rho)
        return float(surprise_scale(rho, np.interp(min(tau[-1] / D, 1.0) if D > 0 else 1.0, F, ref)))

    # -------------------------------------------------------------- the duration's weights (batched)
    def _constants(self):
        """What the batched grid terms need whatever is seen, computed once: Σ = U Uᵀ + τ² (K_ℓ ⊗ I_6 ⊕ 1)
        (:meth:`PathDistribution.prior`) as U (P, D) and K_ℓ (S, S) with the duration's τ², and per grid phase
        k its values and differences to phase k + 1 (a linear interpolation between grid phases is then one
        gather of each): U's rows (S, 6D), K_ℓ (S−1, S−1, 4: K00, K01 − K00, K10 − K00, K11 − K10 − K01 + K00),
        K_ℓ's last column, the prior mean plus the mean path's scaled position (S, 6); the mean path's rotation
        as A_k = q̄_k* and B_k = (−u_k, 0) ⊗ q̄_k* with φ_k = θ_k u_k its log to phase k + 1, so that
        (q̄_k ⊗ exp(f φ_k))* = cos(fθ_k/2) A_k + sin(fθ_k/2) B_k (:meth:`_deviations`)."""
        c = self.__dict__.get("_fc")
        if c is None:
            from rbgp_cli.geometry.so3 import quat_conjugate, quat_multiply

            paths = self.paths
            X = paths.vectors()
            D = len(X)
            U = (X - X.mean(axis=0)).T * np.sqrt((1.0 + 1.0 / D) / max(D - 1, 1))
            s = paths.s
            S = len(s)
            Ks = np.exp(-0.5 * ((s[:, None] - s[None, :]) / paths.length) ** 2)
            U6 = np.ascontiguousarray(U[:-1].reshape(S, 6 * D))
            K4 = np.stack([Ks[:-1, :-1], Ks[:-1, 1:] - Ks[:-1, :-1], Ks[1:, :-1] - Ks[:-1, :-1],
                           Ks[1:, 1:] - Ks[1:, :-1] - Ks[:-1, 1:] + Ks[:-1, :-1]], axis=-1)
            ref = self._ref
            C0 = self.m[:-1].reshape(S, 6).copy()
            C0[:, 3:] += ref.position / self.scale[3:]
            theta = np.linalg.norm(ref._phi, axis=1)
            axis = ref._phi / np.where(theta > 0, theta, 1.0)[:, None]
            A = quat_conjugate(ref._q0)
            B = quat_multiply(np.concatenate([-axis, np.zeros((S - 1, 1))], axis=1), A)
            UE, uL = U[self._end], U[-1]
            # per grid interval, one row for _deviations' single gather: A (4), B (4), C0 (6), its difference (6), θ/2
            dev = np.concatenate([A, B, C0[:-1], np.diff(C0, axis=0), 0.5 * theta[:, None]], axis=1)
            c = self._fc = dict(
                U=U, Ks=Ks, tau2=self.duration_smooth, S=S, D=D, U6=U6[:-1], dU6=np.diff(U6, axis=0), K4=K4,
                dev=dev, inv_scale=1.0 / self.scale, uL=uL, uLuL=float(uL @ uL), UEUE=UE @ UE.T)
        return c

    def _low_rank(self):
        """(U (P, D), K_ℓ (S, S), τ²) of Σ's low-rank-plus-smooth form (:meth:`_constants`)."""
        c = self._constants()
        return c["U"], c["Ks"], c["tau2"]

    def _deviations(self, k, f, q, p):
        """The scaled deviations of seen poses from the prior mean at grid interval k, fraction f (any shape
        (...)): quat q and position p broadcast against (..., 4) and (..., 3); returns (..., 6)

            e = (log(R R̄(s)ᵀ), p − p̄(s)) / σ − m(s),

        R̄(s) the mean path's slerp q̄_k ⊗ exp(f φ_k) (:class:`~rbgp_cli.dynamics.model.PathReference`), p̄ and the
        prior mean m interpolated linearly. The live update calls it for the whole grid at every pose, so it
        is the product and logarithm written out (:meth:`_constants`, :func:`_log_unit`)."""
        c = self._constants()
        g = c["dev"][k]  # (..., 21): A_k, B_k, C0_k, C0_(k+1) − C0_k, θ_k / 2
        a = f * g[..., 20]
        cq = np.cos(a)[..., None] * g[..., :4] + np.sin(a)[..., None] * g[..., 4:8]  # (q̄_k ⊗ exp(f φ_k))*
        Lq = (q @ _LEFT).reshape(q.shape[:-1] + (4, 4))  # q ⊗ · as a matrix
        rot = _log_unit((Lq @ cq[..., None])[..., 0])
        e = np.empty(rot.shape[:-1] + (6,))
        e[..., :3] = rot
        e[..., 3:] = p
        e *= c["inv_scale"]
        e -= g[..., 8:14]
        e -= f[..., None] * g[..., 14:20]
        return e

    def _grid_terms(self, tau, q, p, grid, tau2=None, r2=None, ell2=None):
        """For each duration D_g: log weight, the conditioned end pose's mean (6,) and covariance (6, 6) in
        scaled units (module docstring). Batched over the grid, with Σ's low-rank-plus-smooth form
        (:meth:`_constants`); every linear interpolation between grid phases is a gather of values and
        differences, and the end phase is interpolated as one more seen phase (s = 1). ``tau2``: the smooth term's
        τ², one or one per grid duration (G,) (default the duration's); ``r2``: the seen poses' tolerances², (6,) for
        every pose, (6n,) per seen coordinate or (G, 6n) per grid duration too (default the duration's); ``ell2``: ln D's
        tolerance², one or one per grid duration (G,) (default _ELL_TOL²)."""
        c = self._constants()
        S, D = c["S"], c["D"]
        G_, n = len(grid), len(tau)
        tau2 = np.ones(G_) * (c["tau2"] if tau2 is None else np.asarray(tau2, dtype=np.float64))  # (G,)
        r2 = np.asarray(self._duration_r2 if r2 is None else r2, dtype=np.float64)
        r2 = np.tile(r2, n) if r2.shape == (6,) else r2
        k = np.empty((G_, n + 1), dtype=np.intp)
        f = np.empty((G_, n + 1))
        x = np.minimum(tau[None, :] / grid[:, None], 1.0) * (S - 1)  # the seen phases on the grid (G, n)
        k[:, :n] = np.minimum(x.astype(np.intp), S - 2)
        f[:, :n] = x - k[:, :n]
        k[:, n], f[:, n] = S - 2, 1.0  # the end
        Z = (c["U6"][k] + f[:, :, None] * c["dU6"][k]).reshape(G_, 6 * (n + 1), D)  # A U at the seen and end phases
        K4 = c["K4"][k[:, :, None], k[:, None, :]]  # (G, n + 1, n + 1, 4)
        fi, fj = f[:, :, None], f[:, None, :]
        K = K4[..., 0] + fj * K4[..., 1] + fi * (K4[..., 2] + fj * K4[..., 3])  # K_ℓ interpolated, (G, n + 1, n + 1)
        # one Cholesky factor of the bordered matrix M = [[G, B], [Bᵀ, C]] over (ℓ, the seen poses | the end
        # pose, the innovation e), G the observations' covariance plus their tolerances: its first k6 rows are
        # G's factor L, the next 7 hold (L⁻¹ B)ᵀ = (L⁻¹ Σ_oE, L⁻¹ e)ᵀ whatever C (C only keeps M positive
        # definite: Σ_EE plus a large diagonal), so eᵀG⁻¹e, Σ_Eo G⁻¹ e and Σ_Eo G⁻¹ Σ_oE need no second solve
        k6 = 6 * n + 1
        M = np.zeros((G_, k6 + 7, k6 + 7))
        M[:, 1:k6 + 6, 1:k6 + 6] = Z @ Z.transpose(0, 2, 1)
        _add_kron_i6(M[:, 1:k6 + 6, 1:k6 + 6], tau2[:, None, None] * K)
        M[:, 1:k6 + 6, 0] = Z @ c["uL"]
        M[:, 0, 1:k6 + 6] = M[:, 1:k6 + 6, 0]
        M[:, 0, 0] = c["uLuL"] + tau2 + (_ELL_TOL ** 2 if ell2 is None else np.asarray(ell2, dtype=np.float64))
        _diagonal(M, 1, k6)[...] += r2
        M[:, -1, 0] = np.log(grid) / self.lscale - self.m[-1]
        M[:, -1, 1:k6] = self._deviations(k[:, :n], f[:, :n], q[None], p[None]).reshape(G_, 6 * n)  # e = y − A m
        M[:, :-1, -1] = M[:, -1, :-1]
        big = 1e100  # ≫ any Bᵀ G⁻¹ B here (G ≥ the tolerances' r² > 1e-9 on its diagonal)
        _diagonal(M, k6, k6 + 7)[...] += big
        L = np.linalg.cholesky(M)
        Le = L[:, -1, :k6]  # (G, k6) L⁻¹ e
        LS = L[:, k6:k6 + 6, :k6]  # (G, 6, k6) (L⁻¹ Σ_oE)ᵀ
        quad = np.einsum("gk,gk->g", Le, Le)
        logdet = 2.0 * np.log(_diagonal(L, 0, k6)).sum(axis=1)
        logw = -0.5 * quad - 0.5 * logdet
        end_mean = self.m[self._end][None] + (LS @ Le[:, :, None])[..., 0]
        end_cov = np.repeat(c["UEUE"][None], G_, axis=0)  # Σ_EE − Σ_Eo G⁻¹ Σ_oE, Σ_EE = U_E U_Eᵀ + τ² I
        _diagonal(end_cov, 0, 6)[...] += tau2[:, None]
        end_cov -= LS @ LS.transpose(0, 2, 1)
        return logw, end_mean, end_cov, quad, k6

    def rest_end(self, tau, q, p, D) -> np.ndarray:
        """The rest's conditioned end (6,) in scaled units at duration D: its conditioned mean at phase 1, x̂_end =
        m_end + Σ_E,o G⁻¹ (y − A m) with the rest's τ²_rest on Σ, its r_rest on the seen poses at phases τ / D, the
        last one exactly (:data:`~rbgp_cli.dynamics.paths.GOAL_TOLERANCE`, its precision added to r_rest's) and ℓ =
        ln D with the rest's tolerance (``rest_ell``) (:meth:`_conditioned_mean` at the end's six entries, in :meth:`_grid_terms`' form for one duration:
        the live update can afford it, batched with the :meth:`surprise`: :meth:`_at_estimate`)."""
        return self._at_estimate(tau, q, p, D)[0]

    def _at_estimate(self, tau, q, p, D, grid=None, w=None, near=None, D_rho=None) -> tuple[np.ndarray, float, np.ndarray]:
        """(the continuation's end (6,) scaled, :meth:`surprise` ρ at ``D_rho`` (default D; the continuation's: the
        weights' median), the end's covariance (6, 6) at D as the
        samples draw it) from one batched factorisation (the live update's cost): the rest's conditioned ends
        (:meth:`rest_end`) at the duration cells ``grid`` whose weights ``w`` are kept (:func:`_kept`), averaged with
        those weights normalised (:meth:`_mixed_deviation`'s end; at D alone without them or where one cell carries
        the weight); ρ with the path distribution's own τ² and r; and the end's conditional covariance under the path
        distribution's own τ² and r with the last seen pose exact and ℓ = ln D (the samples' conditioning,
        :meth:`_samples`)."""
        D = max(float(D), float(tau[-1]), 1e-9)
        D_rho = D if D_rho is None else max(float(D_rho), float(tau[-1]), 1e-9)
        nn = 0
        if near is not None and self.rest_near is not None and len(tau) > 1:
            tau, q, p = near
            nn = 1
        n = len(tau)
        keep = None if w is None else _kept(w)
        if keep is None or np.count_nonzero(keep) < 2:
            at, wg = np.array([D]), np.ones(1)
        else:
            at, wg = grid[keep], w[keep] / w[keep].sum()
        G = len(at)
        r2 = np.empty((G + 2, n, 6))  # the rest at each cell, the surprise at D, the samples' conditioning at D
        r2[:G] = self.rest_tolerance ** 2
        r2[G:] = self.tolerance ** 2
        g2 = (np.repeat(np.asarray(GOAL_TOLERANCE, dtype=np.float64), 3) / self.scale) ** 2
        # the last seen pose exact (not for the surprise, row G)
        r2[:G, -1] = 1.0 / (1.0 / r2[:G, -1] + 1.0 / g2)
        r2[G + 1, -1] = 1.0 / (1.0 / r2[G + 1, -1] + 1.0 / g2)
        if nn:
            r2[:G, -2] = self.rest_near ** 2
            r2[G:, -2] = 1e12  # the surprise and the samples' conditioning do not see it
        tau2 = np.full(G + 2, self.rest_smooth)
        tau2[G:] = self.paths.smooth
        ell2 = np.full(G + 2, self.rest_ell ** 2)
        ell2[G:] = _ELL_TOL ** 2
        _, end_mean, end_cov, quad, k6 = self._grid_terms(tau, q, p, np.append(at, [D_rho, D]), tau2=tau2,
                                                          r2=r2.reshape(G + 2, -1), ell2=ell2)
        return wg @ end_mean[:G], float(quad[G]) / (k6 - 6 * nn), end_cov[G + 1]

    def weights(self, t, quat, position, checked: bool = False, active=None):
        """The duration posterior of a motion seen from t[0] to t[-1]: (grid (G,) s, weights (G,)), and the
        per-grid terms (:meth:`_grid_terms`) of the durations kept, with ``band_w`` (G,) the weights with the seen
        poses' evidence weighted by ``duration_evidence`` (:meth:`_tempered`; the end time's band and the samples'
        durations; the weights themselves give the point estimate and the end pose). ``active`` (G_full,) bool: only these
        grid durations are evaluated (the others' weights taken as 0; :class:`Follower` passes the cells
        whose weight was not negligible at the last update and their neighbours); None: all."""
        t, quat, position, tau, q, p = _seen(t, quat, position, self.points, checked)
        span = float(tau[-1])
        keep = self.grid >= span
        if active is not None and np.any(keep & active):
            keep = keep & active
        if not np.any(keep):  # longer already than any plausible duration: it ends now
            grid = np.array([max(span, 1e-6)])
        else:
            grid = self.grid[keep]
        logw, end_mean, end_cov, quad, k = self._grid_terms(tau, q, p, grid)
        w = self._tempered(grid, logw, 1.0)
        band_w = w if self.duration_evidence == 1.0 else self._tempered(grid, logw)
        return grid, w, dict(end_mean=end_mean, end_cov=end_cov, quad=quad, k=k, span=span, band_w=band_w,
                             beyond=not np.any(keep), seen=(t, quat, position, tau, q, p))

    def _tempered(self, grid, logw, evidence: float | None = None):
        """The normalised weights (G,) over ``grid`` from the log weights log N(ℓ_g) + log p(y | ℓ_g) (any constant;
        N the path distribution's marginal of ℓ = ln D (scaled), N(m_ℓ, uᵀu + τ² + ε²) with the duration's τ²,
        :meth:`_constants`, ε = _ELL_TOL) with the seen poses' evidence weighted by λ = ``evidence`` (default
        ``duration_evidence``; :func:`_temper_log`, ν = D − 1)."""
        lam = self.duration_evidence if evidence is None else float(evidence)
        logw = np.asarray(logw, dtype=np.float64)
        if lam != 1.0:
            c = self._constants()
            e = np.log(grid) / self.lscale - self.m[-1]
            logw = _temper_log(logw, e * e, c["uLuL"] + c["tau2"] + _ELL_TOL ** 2, max(self.paths.demos - 1, 1), lam)
        w = np.exp(logw - logw.max())
        return w / w.sum()

    def estimate(self, t, quat, position, checked: bool = False) -> Anticipation:
        """The fast summary (:class:`Anticipation`) of a seen beginning: no path, one batched solve."""
        grid, w, terms = self.weights(t, quat, position, checked)
        return self._summary(grid, w, terms)

    def _summary(self, grid, w, terms) -> Anticipation:
        t = terms["seen"][0]
        t0, span = float(t[0]), terms["span"]
        q = self._duration_quantiles(grid, w, span)
        # D̂ the point estimate (the weights' median or mode); the surprise is measured at their median, D_med, as
        # its left-out reference is (fit_seen: a reference the duration statistic does not move)
        D_med = q[1]
        D = D_med if self.duration_statistic == "median" else self.point(grid, w, span)
        band_w = terms.get("band_w", w)
        if band_w is not w or self.duration_statistic != "median":  # the band's spread, moved to D̂ (band_shift)
            k = self.band_shift(grid, w, band_w, span, D)
            q = [max(x * k, span) for x in self._duration_quantiles(grid, band_w, span, (0.05, 0.95))]
            q = [min(q[0], D), D, max(q[1], D)]
        # the end pose: the continuation's (the rest's conditioned ends averaged over the duration, or with mix_end
        # False at D̂); its band's covariance the samples' conditional one at D̂ plus the spread over the duration's
        # weights of the ends conditioned for the weights, about their own mean (scaled), then unscaled
        E = terms["end_mean"]
        mu, rho, cov_own = self._at_estimate(*terms["seen"][3:], D, *((grid, w) if self.mix_end else (None, None)),
                                             near=self._near(terms["seen"], D), D_rho=D_med)
        d = E - w @ E
        cov = cov_own + (d.T * w) @ d
        sc = self.scale
        mu_u = mu * sc
        cov_u = cov * sc[:, None] * sc[None, :]
        c_rot, c_pos = self.end_band_at(min(span / D, 1.0) if D > 0 else 1.0)
        s_ = self.surprise_at(*terms["seen"][3:], D_med, rho=rho)
        c_rot, c_pos = c_rot * s_, c_pos * s_
        q = self.stretched(q, D, s_, span)
        ref_q, ref_p = self.paths.quat[-1], self.paths.position[-1]
        # exp(μ_rot) ⊗ q̄_end, the product as L(exp(μ_rot)) q̄_end (_LEFT)
        theta = float(np.sqrt(mu_u[:3] @ mu_u[:3]))
        ex = np.empty(4)
        ex[:3] = mu_u[:3] * (np.sin(0.5 * theta) / theta if theta >= SMALL_ANGLE else 0.5 - theta * theta / 48.0)
        ex[3] = np.cos(0.5 * theta)
        end_q = (ex @ _LEFT).reshape(4, 4) @ ref_q
        end_p = ref_p + mu_u[3:]
        # 90 %: a rotation's m² is 3 F(3, ν) for the draws (draw_scales); a position coordinate t_ν (once)
        quantiles = self.__dict__.get("_quantiles")
        if quantiles is None:
            from scipy.special import fdtri, stdtrit

            nu = max(self.paths.demos - 2, 1)
            quantiles = self._quantiles = (float(3.0 * fdtri(3, nu, 0.9)), float(stdtrit(nu, 0.95)))
        # an angle: at most π (any rotation)
        rot_band = min(c_rot * np.sqrt(quantiles[0] * max(np.linalg.eigvalsh(cov_u[:3, :3]).max(), 0.0)), np.pi)
        pos_band = c_pos * quantiles[1] * np.sqrt(np.clip(np.diag(cov_u)[3:], 0.0, None))
        # off: the last seen pose against the prior's marginal at its phase (a χ with 6 degrees of freedom)
        dist = self._distance(terms["seen"][1][-1], terms["seen"][2][-1], min(span / D, 1.0))
        off = bool(terms["beyond"] or dist > OFF_DISTANCE)
        return Anticipation(t=float(t[-1]), phase=float(min(span / D, 1.0)) if D > 0 else 1.0,
                            end_time=t0 + D, end_time_band=(t0 + q[0], t0 + q[2]), end_quat=end_q, end_position=end_p,
                            end_rotation_band=float(rot_band), end_position_band=pos_band, off=off,
                            distance=float(dist), band_widening=float(s_))

    @staticmethod
    def stretched(x, D: float, s: float, span: float = 0.0):
        """Durations ``x`` (any shape, s; D, s and ``span`` scalars or broadcasting with it) moved away from the point
        estimate D by the seen part's widening s in ln D:
        D (x / D)^s, at least ``span``: the end time's band and the samples' durations of a seen part less like the
        demonstrations than their median (:meth:`surprise_at`), widened as its pose bands are (s = 1: unchanged)."""
        if np.ndim(s) == 0 and s == 1.0:
            return x
        out = D * np.power(np.asarray(x, dtype=np.float64) / D, s)
        out = np.maximum(out, span)
        return [float(v) for v in out] if isinstance(x, list) else out

    def band_shift(self, grid, w, band_w, span, D: float | None = None) -> float:
        """The factor k = D̂ / D̂_band that moves the band's weights ``band_w`` onto the point estimate: the ratio of
        D̂ (:meth:`point` of the weights ``w``) to their median (both at least the seen span). The band and the
        samples' durations are the tempered weights' durations times k: their spread, centred where the whole
        evidence puts the end (the tempered median lies toward the prior's, which estimated the held-out durations
        worse). 1 where the band's weights are ``w`` and D̂ is their median. ``D``: D̂, computed already."""
        if band_w is w and self.duration_statistic == "median":
            return 1.0
        D = self.point(grid, w, span) if D is None else float(D)
        Db = self._duration_quantiles(grid, band_w, span, (0.5,))[0]
        return float(D / Db) if Db > 0 else 1.0

    def point(self, grid, w, span) -> float:
        """D̂ (s, at least ``span``): the weights' median (:meth:`_duration_quantiles`) or, with ``duration_statistic``
        "mode", their refined mode in ln D (:func:`_log_mode`)."""
        if self.duration_statistic == "mode":
            return _log_mode(grid, w, span)
        return self._duration_quantiles(grid, w, span, (0.5,))[0]

    def _duration_quantiles(self, grid, w, span, levels=(0.05, 0.5, 0.95)) -> list:
        """The quantiles of D at ``levels`` (default 5 %, 50 % and 95 %; s, at least the seen span) from the weights
        over the grid, each grid value's weight spread evenly over its cell in ln D (half a step each side)."""
        lg = np.log(grid)
        edges = np.concatenate([[lg[0] - self._half_step], lg + self._half_step])
        cw = np.concatenate([[0.0], np.cumsum(w)])
        return [max(float(np.exp(x)), span) for x in np.interp(levels, cw, edges)]

    def _distance(self, quat, position, phase) -> float:
        """The Mahalanobis distance of a pose's deviation at ``phase`` under the prior's marginal there (the
        grid phase nearest; with the seen tolerance r² added), in units of the demonstrations' spread."""
        S = self.paths.S
        j = int(round(phase * (S - 1)))
        x = min(max(float(phase), 0.0), 1.0) * (S - 1)
        k = min(int(x), S - 2)
        # the deviation from the prior mean at the phase, plus the prior mean there, less the grid phase's
        e = self._deviations(np.array([k]), np.array([x - k]), quat, position)[0]
        m6 = self.m[:-1].reshape(S, 6)
        e = e + m6[k] + (x - k) * (m6[k + 1] - m6[k]) - m6[j]
        Cinv = self.__dict__.get("_marginal_inv")
        if Cinv is None:  # per grid phase, (Σ_jj + r² I)⁻¹ (S, 6, 6) of the path distribution's own Σ, computed once
            blocks = np.array([self.Sigma[6 * i:6 * i + 6, 6 * i:6 * i + 6] for i in range(S)])
            Cinv = self._marginal_inv = np.linalg.inv(blocks + self.tolerance ** 2 * np.eye(6))
        return float(np.sqrt(max(e @ Cinv[j] @ e, 0.0)))

    # -------------------------------------------------------------- the rest of the motion
    def _near(self, seen, D):
        """The seen poses (τ, q, p) of the rest's conditioning: ``seen`` (:func:`_seen`'s six arrays) with, where the
        rest has a near tolerance, the pose one grid step D / (S − 1) before the last inserted before it."""
        t, quat, position, tau, q, p = seen
        if self.rest_near is None or len(tau) < 2:
            return tau, q, p
        tn = max(float(tau[-1]) - float(D) / (self.paths.S - 1), 0.0)
        # the two samples about it (the live update calls this at every pose: no pass over the whole buffer)
        k = min(max(int(np.searchsorted(t, t[0] + tn, side="right")) - 1, 0), len(t) - 2)
        qn, pn = _slerp_samples(t[k:k + 2] - t[0], quat[k:k + 2], position[k:k + 2], np.array([tn]))
        n = len(tau)
        tau_n, q_n, p_n = np.empty(n + 1), np.empty((n + 1, 4)), np.empty((n + 1, 3))
        tau_n[:-2], q_n[:-2], p_n[:-2] = tau[:-1], q[:-1], p[:-1]
        tau_n[-2], q_n[-2], p_n[-2] = tn, qn[0], pn[0]
        tau_n[-1], q_n[-1], p_n[-1] = tau[-1], q[-1], p[-1]
        return tau_n, q_n, p_n

    def _observations(self, tau, q, p, last_q, last_p, D, rest: bool = True):
        """(A, y, r²) at duration D: the seen poses (tolerance: the rest's r_rest, or with ``rest=False`` the path
        distribution's r), the last one exactly, and ℓ = ln D (exactly, or with the rest's ``rest_ell``)."""
        paths = self.paths
        obs = [paths.observe(np.clip(tau / D, 0, 1), q, p, tolerance=None),
               paths.observe([min(tau[-1] / D, 1.0)], last_q[None], last_p[None], exact=True),
               paths.observe_duration(D, tolerance=(self.rest_ell if rest else _ELL_TOL) * self.lscale)]
        A, y, r2 = paths.stack(*obs)
        r2[: 6 * len(tau)] = (self.rest_tolerance if rest else self.tolerance) ** 2
        if rest and self.rest_near is not None and len(tau) > 2:  # the pose just before the last (_near)
            r2[6 * (len(tau) - 2): 6 * (len(tau) - 1)] = self.rest_near ** 2
        return A, y, r2

    def _gain(self, A, r2, rest: bool = True):
        """Σ Aᵀ G⁻¹ (P, k) with G = A Σ Aᵀ + diag r² (Σ with the rest's τ², or with ``rest=False`` the path
        distribution's)."""
        from scipy.linalg import cho_factor, cho_solve

        SA = (self.Sigma_rest if rest else self.Sigma) @ A.T
        G = A @ SA + np.diag(r2)
        return cho_solve(cho_factor(0.5 * (G + G.T), lower=True), SA.T).T

    def _conditioned_mean(self, tau, q, p, last_q, last_p, D, rest: bool = True):
        """The conditioned mean x̂ (P,) at duration D and its (A, r², gain) for pathwise draws: with the rest's
        τ² and r (the continuation's mean), or with ``rest=False`` the path distribution's (its samples' spread)."""
        A, y, r2 = self._observations(tau, q, p, last_q, last_p, D, rest)
        gain = self._gain(A, r2, rest)
        return self.m + gain @ (y - A @ self.m), (A, r2, gain)

    def _prior_root(self):
        root = self.__dict__.get("_root")
        if root is None:
            S = 0.5 * (self.Sigma + self.Sigma.T)
            root = np.linalg.cholesky(S + 1e-10 * np.trace(S) / len(S) * np.eye(len(S)))
            self._root = root
        return root

    def _draws(self, count, rng, A, r2, gain, phase: float = 1.0, widen: float = 1.0):
        """``count`` zero-mean draws (count, P) of the conditioned distribution by Matheron's rule,
        η = c ⊙ k ⊙ ((f − m) − gain (A (f − m) + ε)), f ~ N(m, Σ), ε ~ N(0, diag r²), k = (k_rot, k_pos) the
        Gaussian's scales whose 90 % regions are the Student-t's with ν = D − 2 (:func:`draw_scales`) and c the
        seen bands' factors at the seen ``phase`` (:meth:`band_at`), per rotation and position coordinate (ln D's
        entry unscaled: the duration is drawn from the weights)."""
        P = len(self.m)
        z = rng.standard_normal((count, P)) @ self._prior_root().T
        eps = rng.standard_normal((count, len(r2))) * np.sqrt(r2)
        eta = z - (z @ A.T + eps) @ gain.T
        k_rot, k_pos = draw_scales(max(self.paths.demos - 2, 1))
        c_rot, c_pos = self.band_at(phase)
        c_rot, c_pos = c_rot * widen, c_pos * widen
        eta[:, :-1] *= np.tile(np.array([c_rot * k_rot] * 3 + [c_pos * k_pos] * 3), self.paths.S)
        return eta

    def continuation(self, t, quat, position, *, samples: int = 0, seed: int = 0, dt: float | None = None,
                     use_model: bool = True, name: str = "0") -> Continuation:
        """The predicted rest of a motion seen as (t (N,), quat (N, 4), position (N, 3)) (module docstring):
        the mean from t[-1] to the predicted end on the seen clock at step ``dt`` (default the seen
        samples' median interval, else the model's), and ``samples`` continuations drawing the duration
        and the path together (seeded by ``seed``)."""
        grid, w, terms = self.weights(t, quat, position)
        est = self._summary(grid, w, terms)
        t, quat, position, tau, q, p = terms["seen"]
        t0, span = float(t[0]), terms["span"]
        D = max(est.end_time - t0, span + 1e-9)
        if dt is None:
            dt = float(np.median(np.diff(t))) if len(t) > 1 else float(getattr(self.model, "rollout_dt", 0.01) or 0.01)
        tn, qn, pn = self._near(terms["seen"], D)
        mean_x, _ = self._conditioned_mean(tn, qn, pn, quat[-1], position[-1], D)
        dev_hat = self.paths.unscale(mean_x)[0]
        dev = self._mixed_deviation(tn, qn, pn, quat[-1], position[-1], grid, w, D, dev_hat)
        t_out = self._times(t0, span, D, dt)
        if self.model is not None and use_model and _rollable(self.model):
            mq, mp = self._rollout(dev, quat[-1], position[-1], span / D, D, t_out - t0)
        else:
            mq, mp = self.paths.pose_at(dev, (t_out - t0) / D)
        est = replace(est, end_quat=np.array(mq[-1]), end_position=np.array(mp[-1]))  # the JSON's end: the CSV's last row
        out = []
        if samples:
            # the samples' spread about the mean: the path distribution's own conditioning, whose left-out
            # remainders fitted the bands' factors (its mean at D̂ is what each draw's difference is taken from)
            own = dev_hat if (self.Sigma_rest is self.Sigma and self.rest_tolerance == self.tolerance
                              and self.rest_ell == _ELL_TOL and self.rest_near is None) else \
                self.paths.unscale(self._conditioned_mean(tau, q, p, quat[-1], position[-1], D, rest=False)[0])[0]
            k = self.band_shift(grid, w, terms["band_w"], span, D)
            s_ = est.band_widening  # the durations widened about D̂ as the end time's band is (stretched)
            out = self._samples(int(samples), seed, self.stretched(grid * k, D, s_, span + 1e-6), terms["band_w"], tau, q,
                                p, quat[-1], position[-1], own, (t_out, mq, mp), t0, span, D, dt, widen=s_)
        return Continuation(t_out, mq, mp, out, est, D, name=name)

    def _mixed_deviation(self, tau, q, p, last_q, last_p, grid, w, D, dev_hat=None) -> np.ndarray:
        """The continuation's mean path as deviations (S, 6) at duration D: the posterior mean over the duration's
        weights of the rest's conditioned paths, each on the remainder's normalised time. With ŝ_0 = τ_N / D the last
        seen phase at D and u_j = (s_j − ŝ_0) / (1 − ŝ_0) a grid phase's place in the remainder, each kept cell g
        (weight ≥ :data:`MIX_WEIGHT` of the largest) gives the pose (R_g, p_g) of its conditioned path x̂_g at phase
        s_0g + u_j (1 − s_0g), s_0g = τ_N / D_g, and

            δ_j = Σ_g w̃_g (log(R_g R̄(s_j)ᵀ), p_g − p̄(s_j)),   w̃ the kept weights normalised.

        Every x̂_g holds the last seen pose at its own s_0g, so the mean does at ŝ_0; its end (u = 1) is Σ_g w̃_g δ_g(1),
        the conditioned ends' mean (:meth:`_at_estimate`). Where one cell carries the weight it is x̂ at D
        (``dev_hat``, computed if None)."""
        from rbgp_cli.dynamics.paths import pose_deviation

        paths = self.paths
        keep = _kept(w)
        if np.count_nonzero(keep) < 2:
            return paths.unscale(self._conditioned_mean(tau, q, p, last_q, last_p, D)[0])[0] if dev_hat is None else dev_hat
        Dg, wg = grid[keep], w[keep] / w[keep].sum()
        x = np.stack([self._conditioned_mean(tau, q, p, last_q, last_p, d)[0] for d in Dg])  # one solve per kept cell
        dev_g = paths.unscale(x)[0]  # (G, S, 6)
        s0 = min(float(tau[-1]) / D, 1.0)
        u = (paths.s - s0) / (1.0 - s0) if s0 < 1.0 else np.ones_like(paths.s)
        s0g = np.minimum(float(tau[-1]) / Dg, 1.0)[:, None]
        qg, pg = paths.pose_at(dev_g, np.clip(s0g + u[None] * (1.0 - s0g), 0.0, 1.0))
        return np.einsum("g,gsj->sj", wg, pose_deviation(paths.quat, paths.position, qg, pg))

    @staticmethod
    def _times(t0, span, D, dt):
        rest = D - span
        n = max(int(np.floor(rest / dt + 1e-9)), 0)
        t_out = t0 + span + np.arange(n + 1) * dt
        if rest - n * dt > 1e-6 * max(dt, 1e-9):
            t_out = np.append(t_out, t0 + D)
        return t_out

    def _rollout(self, dev, last_q, last_p, s_last, D, tau_out):
        """The model's GP dynamics from the last seen pose at phase s_last, with the conditioned path as the
        prior mean's reference (module docstring), sampled at τ_out (T,) seconds from the start."""
        from rbgp_cli.compute import blas_threads
        from rbgp_cli.dynamics.model import PathReference, prior_mean_outputs
        from rbgp_cli.dynamics.trajectory import interpolate_poses
        from rbgp_cli.geometry.so3 import log_quat, quat_conjugate, quat_make_continuous, quat_multiply

        model, paths = self.model, self.paths
        s = paths.s
        cq, cp = paths.pose_at(dev, s)
        vel = np.concatenate([log_quat(quat_multiply(cq[1:], quat_conjugate(cq[:-1]))), np.diff(cp, axis=0)], axis=1) / np.diff(s)[:, None]
        ref = {"kind": "path", "s": s, "quat": cq, "position": cp, "velocity": vel, "gain": model.mean["gain"]}
        for key in ("gain_profile", "feedforward"):
            if model.mean.get(key) is not None:
                ref[key] = model.mean[key]
        if "gain_profile" in ref and len(np.asarray(ref["gain_profile"])) != len(s):
            ref.pop("gain_profile")
        reference = PathReference(ref)
        dt = float(model.rollout_dt)
        rest = (1.0 - s_last) * D
        steps = max(int(np.ceil(rest / dt - 1e-9)), 1)
        dt = rest / steps
        h = dt / D if ref.get("feedforward") == "secant" else None
        X = model.initial_state(last_q[None], last_p[None])
        X[:, -1] = s_last
        pd = model.pose_dims
        states = [X]
        with blas_threads(0):
            for _ in range(steps):
                mu = model.residual(X, manage_threads=False)  # the GP's residual times the model's gain g
                mu = mu + prior_mean_outputs(model.representation, X[:, :pd], ref, X[:, -1], path=reference, step=h)
                X = model.advance(X, mu, dt, D)
                states.append(X)
        St = np.concatenate(states, axis=0)
        rq, rp = model.representation.pose_from_state(St[:, :pd])
        tt = s_last * D + np.arange(steps + 1) * dt
        return interpolate_poses(tt, quat_make_continuous(rq), rp, np.clip(tau_out, tt[0], tt[-1]))

    def _samples(self, K, seed, grid, w, tau, q, p, last_q, last_p, dev0, mean, t0, span, D0, dt, widen: float = 1.0):
        """K continuations (t, quat, position): at a duration D_k drawn from the weights (its grid cell, then
        uniformly within it; a cell ``widen`` times the grid's step in ln D wide, as :meth:`stretched` leaves it), the mean's deviation at the same phase plus the difference between a draw of
        the distribution conditioned at D_k and the conditioned mean at D̂ (module docstring). One
        conditioning per distinct grid cell drawn."""
        from rbgp_cli.dynamics.paths import _interpolation, pose_deviation
        from rbgp_cli.dynamics.rollout import _from_deviation

        paths = self.paths
        rng = np.random.default_rng(np.random.SeedSequence([int(seed), 37]))
        idx = rng.choice(len(grid), size=K, p=w)
        jitter = rng.uniform(-self._half_step, self._half_step, K) * (len(grid) > 1) * float(widen)
        t_m, mq, mp = mean
        ph_m = (t_m - t0) / D0
        zero = np.zeros((paths.S, 6))
        rq, rp = paths.pose_at(zero, ph_m)
        dev_m = pose_deviation(rq, rp, mq, mp)  # the mean's deviation (T, 6) on its own phases
        out = [None] * K
        for g in np.unique(idx):  # one conditioning per grid cell drawn
            ks = np.flatnonzero(idx == g)
            Dg = float(max(grid[g], span + 1e-6))
            xg, (A, r2, gain) = self._conditioned_mean(tau, q, p, last_q, last_p, Dg, rest=False)
            eta = self._draws(len(ks), rng, A, r2, gain, phase=min(span / Dg, 1.0), widen=widen)  # the factors at this D's seen phase
            draws = paths.unscale(xg[None] + eta)[0]  # (n, S, 6)
            for k, draw in zip(ks, draws):
                Dk = float(max(np.exp(np.log(Dg) + jitter[k]), span + 1e-6))
                tk = self._times(t0, span, Dk, dt)
                phk = (tk - t0) / Dk
                Wk = _interpolation(paths.s, phk)
                dm = np.stack([np.interp(phk, ph_m, dev_m[:, j]) for j in range(6)], axis=1)
                dk = dm + Wk @ (draw - dev0)
                rqk, rpk = paths.pose_at(zero, phk)
                sq, sp = _from_deviation(paths, rqk, rpk, dk)
                out[k] = (tk, sq, sp)
        return out


def _kept(w: np.ndarray) -> np.ndarray:
    """The duration cells (G,) bool whose weight is at least :data:`MIX_WEIGHT` of the largest: those the
    continuation's mean averages over."""
    w = np.asarray(w, dtype=np.float64)
    return w >= MIX_WEIGHT * w.max()


def _rollable(model) -> bool:
    """A model whose GP dynamics can continue a motion mid-way: phase input and a mean-path prior."""
    return getattr(model, "time_input", None) == "phase" and bool(model.mean) and model.mean.get("kind") == "path"


def anticipate(paths, t, quat, position, *, model=None, samples: int = 0, seed: int = 0, dt: float | None = None,
               name: str = "0", points: int = SEEN_POINTS) -> Continuation:
    """The rest of a motion seen as (t (N,) s, quat (N, 4) x, y, z, w, position (N, 3) m) from its start
    (module docstring): :meth:`Anticipator.continuation`."""
    return Anticipator(paths, model, points=points).continuation(t, quat, position, samples=samples, seed=seed,
                                                                 dt=dt, name=name)


# ----------------------------------------------------------------------------------------- fitting r
def seen_split(F: float, S: int, P: int, points: int, near: bool = False) -> tuple[np.ndarray, int]:
    """The path vector's entries a left-out demonstration is seen at and scored on, when its first
    fraction F is seen: (idx, no), the first ``no`` of ``idx`` the seen ones (at most ``points`` phases of
    the S up to F, 6 coordinates each, and ln D, entry P − 1), the rest the scored ones (every
    SELECT_EVERY-th phase after F and the last, 6 coordinates each). ``near``: the grid phase just before the
    last seen one is among the seen (the rest's near pose, :attr:`Anticipator.rest_near`): the seen entries'
    second-to-last six."""
    from rbgp_cli.dynamics.paths import SELECT_EVERY

    J = int(round(F * (S - 1)))
    seen = np.unique(np.round(np.linspace(0, J, min(points, J + 1))).astype(int))
    if near and J >= 1:
        seen = np.union1d(seen, [J - 1])
    scored = np.unique(np.concatenate([np.arange(J + SELECT_EVERY, S - 1, SELECT_EVERY), [S - 1]]))
    io = np.concatenate([(6 * seen[:, None] + np.arange(6)).ravel(), [P - 1]])
    it = (6 * scored[:, None] + np.arange(6)).ravel()
    return np.concatenate([io, it]), len(io)


def _seen_loo(paths, tolerances, stats: bool = False, points: int = SEEN_POINTS, smooth: float | None = None,
              by_fraction: bool = False, rest: tuple | None = None):
    """Leave each demonstration out; see its first F (each of SEEN_FRACTIONS) at its true phases on the grid
    (≤ points grid phases, the last exactly) and its ln D; score the rest (every 5th grid phase after F,
    and the end) by its log density under the others' distribution so conditioned, for each tolerance of
    ``tolerances``. Only the coordinates involved enter (a Gaussian's marginal is its sub-block). Returns
    the mean log density per tolerance and, with ``stats`` (one tolerance), the rotation Mahalanobis² and
    position z-scores of the scored phases (for the bands' factors). All demonstrations at once
    (:func:`~rbgp_cli.dynamics.paths.left_out_moments`, :func:`~rbgp_cli.dynamics.paths.held_out_scores`).
    ``smooth``: the τ² of the others' distribution (default the path distribution's). ``by_fraction`` (with
    ``stats``): the Mahalanobis² and z-scores as lists, one array per fraction of SEEN_FRACTIONS. ``rest`` (τ²_rest,
    r_rest[, ln D's tolerance]), with ``stats``: the scores' errors are taken from the mean conditioned with these (the mean a
    continuation follows), their covariance still the one of ``smooth`` and the tolerance (its samples' spread)."""
    from rbgp_cli.dynamics.paths import GOAL_TOLERANCE, SELECT_EVERY, held_out_scores, left_out_moments

    X = paths.vectors()
    S, P = paths.S, X.shape[1]
    Ks = paths.smooth_covariance(smooth)
    K_rest = None if rest is None else paths.smooth_covariance(rest[0])
    r_last = (np.array(GOAL_TOLERANCE).repeat(3) / paths.scale) ** 2
    total = np.zeros(len(tolerances))
    count, m2, z = 0, [], []
    m2_F, z_F = [], []
    near = float(rest[3]) if rest is not None and len(rest) > 3 and rest[3] is not None else None
    for F in SEEN_FRACTIONS:
        start = len(m2)
        idx, no = seen_split(F, S, P, points)
        Xs = X[:, idx]
        Kss = Ks[np.ix_(idx, idx)]
        # the rest's mean sees the grid phase just before the last too, where it has a near tolerance
        idx_r, no_r = seen_split(F, S, P, points, near=True) if near is not None else (idx, no)
        Xr = X[:, idx_r]
        moments_r = left_out_moments(Xr) if near is not None else None
        for block, m, Sigma in left_out_moments(Xs):  # the others' Gaussian per left-out d, (B, ...)
            innovation = Xs[block, :no] - m[:, :no]
            mr, Sr0 = (m, Sigma) if moments_r is None else next(moments_r)[1:]
            mean_rest = None
            if rest is not None and stats:  # the continuation's mean: the rest's τ² and r
                Sr = Sr0 + K_rest[np.ix_(idx_r, idx_r)]
                r2 = np.full(no_r, float(rest[1]) ** 2)
                r2[-7:-1] = r_last
                r2[-1] = (float(rest[2]) if len(rest) > 2 else _ELL_TOL) ** 2
                if near is not None and no_r >= 13:
                    r2[-13:-7] = near ** 2
                g = np.swapaxes(np.linalg.solve(Sr[:, :no_r, :no_r] + np.diag(r2), Sr[:, :no_r, no_r:]), 1, 2)
                mean_rest = mr[:, no_r:] + np.einsum("bij,bj->bi", g, Xr[block, :no_r] - mr[:, :no_r])
            Sigma += Kss
            Soo, Sot, Stt = Sigma[:, :no, :no], Sigma[:, :no, no:], Sigma[:, no:, no:]
            for i, tol in enumerate(tolerances):
                r2 = np.full(no, float(tol) ** 2)
                r2[-7:-1] = r_last
                r2[-1] = _ELL_TOL ** 2
                gain = np.swapaxes(np.linalg.solve(Soo + np.diag(r2), Sot), 1, 2)  # (B, nt, no)
                mean = m[:, no:] + np.einsum("bij,bj->bi", gain, innovation) if mean_rest is None else mean_rest
                cov = Stt - gain @ Sot
                ld, m2_b, z_b = held_out_scores(Xs[block, no:] - mean, cov, stats)
                total[i] += float(np.sum(ld))
                if stats:
                    m2.append(m2_b.reshape(-1))
                    z.append(z_b.reshape(-1, 3))
            count += len(block)
        if stats:
            m2_F.append(np.concatenate(m2[start:]))
            z_F.append(np.concatenate(z[start:]))
    if stats and by_fraction:
        return total / count, m2_F, z_F
    if stats:
        return total / count, np.concatenate(m2), np.concatenate(z)
    return total / count


def _end_loo(paths, smooths, tolerances, points: int = SEEN_POINTS, *, remainder: bool = False,
             per_demo: bool = False, ell: float = _ELL_TOL, near: float | None = None) -> np.ndarray:
    """The left-out final pose given the seen part, for each τ² of ``smooths`` and r of ``tolerances``: each
    demonstration left out, its first F (each of SEEN_FRACTIONS) seen at its true phases (≤ ``points`` grid
    phases, the last exactly, as the continuation sees it) and its ln D, and the others' distribution (its
    smooth term τ² K_ℓ) conditioned on them; the error e (6,) of the conditioned mean at phase 1 against the
    left-out end, in units of each coordinate's spread. Returns the mean over the left-out demonstrations of
    eᵀe, summed over the fractions: (len(smooths), len(tolerances)). Batched over the demonstrations
    (:func:`~rbgp_cli.dynamics.paths.left_out_moments`); only the coordinates involved enter.

    ``remainder``: the error of the whole rest as well, eᵀe at the end plus (1/k) Σ_j e_jᵀe_j over the k phases the
    remainder is scored at (:func:`seen_split`: every SELECT_EVERY-th after F and the end), what crossval scores a
    continuation by (its final pose and its remainder's RMSE). ``per_demo``: the sums per left-out demonstration,
    (len(smooths), len(tolerances), D), instead of their mean. ``ell``: ln D's tolerance (units of its spread; the
    default exactly, :data:`REST_FREE_ELL` as good as not given). ``near``: the grid phase just before the last seen
    one seen too, with this tolerance (:func:`seen_split` with ``near``; None: not added)."""
    from rbgp_cli.dynamics.paths import GOAL_TOLERANCE, left_out_moments

    X = paths.vectors()
    S, P = paths.S, X.shape[1]
    K1 = paths.smooth_covariance(1.0)
    r_last = (np.array(GOAL_TOLERANCE).repeat(3) / paths.scale) ** 2
    end = 6 * (S - 1) + np.arange(6)
    out = np.zeros((len(smooths), len(tolerances), len(X)))
    for F in SEEN_FRACTIONS:
        idx, no = seen_split(F, S, P, points, near=near is not None)
        if not remainder:
            idx = np.concatenate([idx[:no], end])  # the seen entries (ln D last), then the end's six
        k = (len(idx) - no) // 6  # the scored phases, the end last
        Xs = X[:, idx]
        K = K1[np.ix_(idx, idx)]
        for block, m, sample in left_out_moments(Xs):
            innovation = Xs[block, :no] - m[:, :no]
            for a, tau2 in enumerate(smooths):
                Sigma = sample + float(tau2) * K
                Soo, Sot = Sigma[:, :no, :no], Sigma[:, :no, no:]
                for b, tol in enumerate(tolerances):
                    r2 = np.full(no, float(tol) ** 2)
                    r2[-7:-1] = r_last
                    r2[-1] = float(ell) ** 2
                    if near is not None and no >= 13:
                        r2[-13:-7] = float(near) ** 2
                    gain = np.swapaxes(np.linalg.solve(Soo + np.diag(r2), Sot), 1, 2)  # (B, 6k, no)
                    e = Xs[block, no:] - m[:, no:] - np.einsum("bij,bj->bi", gain, innovation)
                    sq = np.sum(e[:, -6:] ** 2, axis=1)
                    if remainder:
                        sq = sq + np.sum(e * e, axis=1) / k
                    out[a, b, block] += sq
    return out if per_demo else out.mean(axis=2)


def _loosest_rest(errors: np.ndarray, smooths, tolerances, k: float = REST_SE) -> tuple[float, float]:
    """The one-standard-error rule of :func:`_loosest_within` over the rest's candidates: ``errors``
    (len(smooths), len(tolerances), D) per left-out demonstration (:func:`_end_loo` with ``per_demo``); of the
    candidates within k standard errors of the smallest mean, the one that trusts the seen poses least (the
    largest r), then the smoothest (the largest τ²). Returns (τ², r)."""
    E = np.asarray(errors, dtype=np.float64)
    per = {(float(t2), float(r)): E[i, j] for i, t2 in enumerate(smooths) for j, r in enumerate(tolerances)}
    return _loosest_within(per, k, looseness=lambda c: (c[1], c[0]))


def _choose_statistic(paths, trajs, pick, median_errors, k: float = DURATION_MODE_SE) -> None:
    """``paths.duration_statistic``: "mode" where the left-out beginnings of :func:`_duration_loo` (with the chosen
    (τ², r, σ) ``pick``) estimate their durations closer with the weights' mode than with their median
    (``median_errors``, |ln D̂ − ln D| per beginning), by more than ``k`` standard errors of the paired difference;
    else None (the median)."""
    paths.duration_statistic = None
    modes = _duration_loo(paths, trajs, per_beginning=True, statistic="mode", candidates=[pick])
    if not modes:
        return
    d = modes[pick] - np.asarray(median_errors, dtype=np.float64)
    se = float(np.std(d, ddof=1) / np.sqrt(len(d))) if len(d) > 1 else 0.0
    if float(np.mean(d)) < -k * se:
        paths.duration_statistic = "mode"
    paths.info.update(duration_statistic=paths.duration_statistic or "median",
                      duration_mode_gain=float(np.mean(d)), duration_mode_gain_se=se)


def _choose_near(paths) -> None:
    """Whether the rest's conditioning sees the near pose (one grid step before the last seen one), and at which
    tolerance (``paths.rest_near_tolerance``): scored at the left-out demonstrations' estimated durations
    (:func:`_rest_at_estimates`; at a wrong duration the near pose reads a wrong heading), the best of REST_NEAR_GRID's
    tolerances below r_rest, kept only where it beats no near pose by more than REST_SE standard errors of their
    paired difference (the simpler conditioning, without it, otherwise). After the duration's τ², r and λ, which the
    estimated durations use."""
    rest = (float(paths.rest_smooth), float(paths.rest_tolerance), float(paths.rest_duration_tolerance or _ELL_TOL))
    cands = [float(x) for x in REST_NEAR_GRID if x < rest[1]]
    near, rn = {}, np.inf
    if cands:
        E = _rest_at_estimates(paths, [rest] + [(*rest, c) for c in cands])
        near = {np.inf: E[0], **dict(zip(cands, E[1:]))}
        best = min(cands, key=lambda c: float(np.mean(near[c])))
        rn = _loosest_within({np.inf: near[np.inf], best: near[best]}, REST_SE, looseness=lambda c: c)
    paths.rest_near_tolerance = None if not np.isfinite(rn) else float(rn)
    paths.info = dict(paths.info or {}, rest_near_tolerance=paths.rest_near_tolerance,
                      rest_near_loo={("none" if not np.isfinite(c) else str(c)): float(np.mean(e - near[np.inf]))
                                     for c, e in near.items()} if near else None)


def fit_seen(paths, trajs=None, *, level: float = 0.90, duration: bool = True, spread: bool | None = None):
    """Choose the seen poses' regularising tolerance r, the rest's own τ² and r and the bands' factors of a motion
    under way by leaving demonstrations out (module docstring); sets ``paths.seen_tolerance``,
    ``paths.rest_smooth`` and ``paths.rest_tolerance`` (from REST_FROM demonstrations on over the grids by the
    one-standard-error rule, :func:`_loosest_rest`, then at those ln D exact or freed by the same rule,
    ``paths.rest_duration_tolerance``; with fewer the seen r and the better of τ² and :data:`REST_FEW_SMOOTH`,
    ln D exact) and
    ``paths.seen_band_scale`` and returns ``paths``. With the demonstrations ``trajs`` (in the path
    distribution's order) and ``duration``, also the duration weights' own τ² and r
    (:func:`_duration_loo`; ``paths.duration_smooth``, ``paths.duration_tolerance``), chosen before the bands'
    factors (the smallest mean left-out error; with fewer than :data:`DURATION_FEW_BELOW` demonstrations the loosest
    candidate within :data:`DURATION_FEW_SE` standard errors of it, :func:`_loosest_within`, which may be a tolerance
    in rad and m, ``paths.duration_sigma``), which ``spread``
    (default :data:`DURATION_SPREAD`) scores against the samples' durations drawn from
    those weights (:func:`_spread_terms`; by default from :data:`SPREAD_FROM` demonstrations on); else at the
    remainders' true durations (:func:`_seen_loo`). With that statistic and from :data:`SURPRISE_FROM`
    demonstrations on, also ``paths.seen_surprise``: the left-out seen parts' median surprise per fraction (at
    SEEN_POINTS and at the live update's SPREAD_POINTS seen poses), each left-out need divided by its own
    :func:`surprise_scale` before the factors' quantile; and ``paths.seen_end_band_scales``, the end band's factors
    (:func:`_end_needs`), each at least what the live estimator's left-out misses ask (:func:`_estimated_end_needs`,
    kept in ``paths.info["end_band_live"]``)."""
    from rbgp_cli.dynamics.paths import _band_factors

    scores = dict(zip(SEEN_TOLERANCE_GRID, _seen_loo(paths, SEEN_TOLERANCE_GRID)))
    r = max(scores, key=scores.get)
    paths.seen_tolerance = float(r)
    paths.info = dict(paths.info or {}, seen_tolerance=float(r), seen_loo_log_density=float(scores[r]))
    rest = (float(paths.smooth), float(r))
    if paths.demos >= REST_FROM:  # the rest's own τ² and r: the left-out end and remainder given the seen part
        smooths = sorted(set(REST_SMOOTH_GRID) | {rest[0]})
        tols = sorted(set(SEEN_TOLERANCE_GRID) | {rest[1]})
        per = _end_loo(paths, smooths, tols, remainder=True, per_demo=True)
        rest = _loosest_rest(per, smooths, tols)
        err = per.mean(axis=2)
        # then ln D in it, exact or freed, by the same rule at that τ² and r (freed: the looser)
        exact = per[smooths.index(rest[0]), tols.index(rest[1])]
        freed = _end_loo(paths, [rest[0]], [rest[1]], remainder=True, per_demo=True, ell=REST_FREE_ELL)[0, 0]
        pick = _loosest_within({_ELL_TOL: exact, REST_FREE_ELL: freed}, REST_SE, looseness=lambda c: c)
        paths.rest_duration_tolerance = None if pick == _ELL_TOL else float(pick)
        paths.info.update(rest_duration_tolerance=float(pick), rest_duration_freed_loo=float(np.mean(freed - exact)))
        paths.rest_near_tolerance = None  # chosen after the duration's weights (_choose_near)
    else:  # few left-out ends: only the path distribution's own τ² against one smooth τ², at the seen r
        err = _end_loo(paths, [rest[0], REST_FEW_SMOOTH], [rest[1]])[:, 0]
        if err[1] < err[0]:  # ties keep the path distribution's own
            rest = (float(REST_FEW_SMOOTH), rest[1])
        paths.rest_duration_tolerance = None  # ln D exact
        paths.rest_near_tolerance = None  # no near pose
    paths.rest_smooth, paths.rest_tolerance = rest
    paths.info.update(rest_smooth=rest[0], rest_tolerance=rest[1], rest_end_loo=float(err.min()))
    # the samples' spread keeps the path distribution's conditioning; its factors from the same left-out remainders:
    # pooled over F and ≥ 1 about its own mean (as before the seventh pass; what files without the per-F ones use),
    # and per F about the mean the continuation follows (the rest's conditioning), allowed below 1
    _, m2, z = _seen_loo(paths, [r], stats=True)
    c_rot, c_pos = _band_factors(m2, z, paths.demos, level)
    paths.seen_band_scale = (max(1.0, c_rot), max(1.0, c_pos))
    if duration:
        errors = _duration_loo(paths, trajs, per_beginning=True)
        if errors:
            few = paths.demos < DURATION_FEW_BELOW
            pick = _loosest_within(errors) if few else min(errors, key=lambda c: float(np.mean(errors[c])))
            (paths.duration_smooth, paths.duration_tolerance, paths.duration_sigma) = pick
            paths.info.update(duration_smooth=pick[0], duration_tolerance=pick[1], duration_sigma=pick[2],
                              duration_loo_error=float(np.mean(errors[pick])))
            _choose_statistic(paths, trajs, pick, errors[pick])
            inside = _evidence_loo(paths, trajs, level=level)
            if inside:  # the largest λ whose band holds enough left-out durations (finite_sample_count), else the smallest
                held = {lam: float(np.mean(v)) for lam, v in inside.items()}
                ok = [lam for lam, v in inside.items() if int(np.sum(v)) >= finite_sample_count(len(v), level)]
                lam = max(ok) if ok else min(held)
                paths.duration_evidence = None if lam == 1.0 else float(lam)
                paths.info.update(duration_evidence=float(lam), duration_loo_coverage=held[lam])
    if paths.demos >= REST_FROM:
        _choose_near(paths)
    own = rest == (float(paths.smooth), float(r)) and paths.rest_duration_tolerance is None and paths.rest_near_tolerance is None
    if paths.rest_duration_tolerance is not None or paths.rest_near_tolerance is not None:
        rest = (*rest, float(paths.rest_duration_tolerance or _ELL_TOL))
    if paths.rest_near_tolerance is not None:
        rest = (*rest, float(paths.rest_near_tolerance))
    if spread is None:
        spread = DURATION_SPREAD and paths.demos >= SPREAD_FROM
    if spread:  # the remainders against the samples as drawn, each at its own duration (eighth pass)
        ctx = _spread_context(paths)
        raw, refs, ends = [], [], []
        for F in (*SEEN_FRACTIONS, END_LATE):
            # the samples' durations widened about each one's D̂ by its surprise as the continuation's are, against the
            # left-out median at this fraction (beyond the fractions the last one's reference, as surprise_at)
            widen = None
            if paths.demos >= SURPRISE_FROM:
                widen = "median" if F in SEEN_FRACTIONS else refs[-1][0]
            terms = _spread_terms(paths, F, rest=None if own else rest, ctx=ctx, widen_reference=widen)
            scale = None
            if paths.demos >= SURPRISE_FROM:  # the left-out seen parts' median surprise at this fraction
                if F in SEEN_FRACTIONS:
                    ref = float(np.median(terms["rho"]))
                    refs.append([ref, float(np.median(terms["rho_live"]))] if "rho_live" in terms else [ref, ref])
                else:  # beyond the fractions the band widens against the last one's reference (surprise_at)
                    ref = refs[-1][0]
                scale = surprise_scale(terms["rho"], ref)
            # the end band's needs at every fraction, the draws' factors at SEEN_FRACTIONS
            ends.append(_end_needs(paths, terms, level, scale=scale))
            if F in SEEN_FRACTIONS:
                raw.append(_spread_factors(terms, paths.demos, level,
                                           scale=None if scale is None else np.repeat(scale, terms["T"])))
        paths.seen_band_scales = _narrowed(raw, paths.demos)
        paths.seen_end_band_scales = _narrowed([(_weighted_quantile(r, np.ones(len(r)), level),
                                                 _weighted_quantile(q.ravel(), np.ones(q.size), level)) for r, q in ends],
                                               paths.demos, fractions=(*SEEN_FRACTIONS, END_LATE))
        paths.seen_surprise = None if not refs else {
            "fractions": [float(F) for F in SEEN_FRACTIONS], "points": [SEEN_POINTS, SPREAD_POINTS],
            "reference": [[x[0] for x in refs], [x[1] for x in refs]]}
        live = _estimated_end_needs(paths, trajs, level)
        if live is not None:  # also what the live estimator itself missed the left-out ends by: never narrower
            sc = paths.seen_end_band_scales
            sc["rotation"] = [max(a, b) for a, b in zip(sc["rotation"], live["rotation"])]
            sc["position"] = [max(a, b) for a, b in zip(sc["position"], live["position"])]
            paths.info.update(end_band_live=live)
    else:
        _, m2_F, z_F = _seen_loo(paths, [r], stats=True, by_fraction=True, rest=None if own else rest)
        paths.seen_band_scales = seen_band_scales(m2_F, z_F, paths.demos, level)
    return paths


def seen_band_scales(m2_F, z_F, demos: int, level: float = 0.90) -> dict:
    """The bands' factors per seen fraction: {"fractions": SEEN_FRACTIONS, "rotation": [c_rot per F],
    "position": [c_pos per F]}, from the left-out remainders' rotation Mahalanobis² ``m2_F`` and position
    z-scores ``z_F`` at each fraction (:func:`_seen_loo` with ``by_fraction``): at each F the factors that make
    those remainders' 90 % regions hold at ``level`` under the Student-t regions the draws realise (ν = D − 2,
    :func:`draw_scales`;
    :func:`~rbgp_cli.dynamics.paths._band_factors`), allowed below 1 as the goal bands' are
    (:meth:`~rbgp_cli.dynamics.paths.PathDistribution.goal_band_scale`): c < 1 taken as c^w, w = min(1, D /
    NARROW_FROM), and never below NARROWEST. :meth:`Anticipator.band_at` interpolates them in the seen phase."""
    from rbgp_cli.dynamics.paths import _band_factors

    return _narrowed([_band_factors(m2, z, demos, level) for m2, z in zip(m2_F, z_F)], demos)


def _narrowed(raw, demos: int, fractions=SEEN_FRACTIONS) -> dict:
    """:func:`seen_band_scales`' dictionary from the unclamped factors ``raw`` [(c_rot, c_pos) per fraction of
    ``fractions``]: c < 1 taken as c^w, w = min(1, D / NARROW_FROM), never below NARROWEST."""
    from rbgp_cli.dynamics.paths import NARROWEST

    w = min(1.0, demos / NARROW_FROM)
    c = [[max(NARROWEST, x if x >= 1.0 else x ** w) for x in pair] for pair in raw]
    return {"fractions": [float(F) for F in fractions], "rotation": [float(x[0]) for x in c],
            "position": [float(x[1]) for x in c]}


def _estimated_end_needs(paths, trajs, level: float = 0.90, folds: int = DURATION_FOLDS,
                         fractions=(*SEEN_FRACTIONS, END_LATE)) -> dict | None:
    """The end band's factors per fraction from the live estimator itself: the demonstrations ``trajs`` left out in
    ``folds`` groups (:func:`_left_out_beginnings`), each seen up to each of ``fractions`` of its own samples and
    estimated by :class:`Follower`'s anticipator of the others (SPREAD_POINTS seen poses, SPREAD_GRID durations, the
    end at D̂; the factors and the surprise reference fitted so far). A band of factor c holds the end where
    c ≥ c_used |ê| / band (ê the final pose's error: the rotation angle, each position coordinate; c_used the
    factor the estimate applied, its widening s divided out with it). The left-out statistic at the true phases
    (:func:`_end_needs`) does not see the estimated phase's error, which moves the end where the seen part determines
    the path (docs/defaults.md, twenty-second pass). Returns :func:`_narrowed`'s dictionary of the ``level``
    quantiles per fraction (None without the trajectories)."""
    from rbgp_cli.dynamics.paths import MIN_PATH_DEMOS
    from rbgp_cli.geometry.so3 import log_quat, quat_conjugate, quat_multiply

    if trajs is None or len(trajs) != paths.demos or paths.demos < MIN_PATH_DEMOS + 1:
        return None
    nf = len(fractions)
    rot, pos = [[] for _ in range(nf)], [[] for _ in range(nf)]
    for rest, seen, _poses, left_out, at_f in _left_out_beginnings(paths, trajs, folds, SPREAD_POINTS, fractions=fractions):
        ant = Anticipator(rest, None, points=SPREAD_POINTS, grid_size=SPREAD_GRID, mix_end=False)
        for (t, quat, position), d, f in zip(seen, left_out, at_f):
            est = ant.estimate(t, quat, position, checked=True)
            c_rot, c_pos = ant.end_band_at(est.phase)
            tr = trajs[d]
            err = log_quat(quat_multiply(est.end_quat[None], quat_conjugate(np.asarray(tr.quat[-1], float)[None])))[0]
            rot[f].append(c_rot * float(np.linalg.norm(err)) / max(est.end_rotation_band, 1e-12))
            pos[f].extend(c_pos * np.abs(est.end_position - tr.position[-1]) / np.maximum(est.end_position_band, 1e-12))
    if not rot[0]:
        return None
    return _narrowed([(_weighted_quantile(np.asarray(r), np.ones(len(r)), level),
                       _weighted_quantile(np.asarray(p), np.ones(len(p)), level)) for r, p in zip(rot, pos)],
                     paths.demos, fractions=fractions)


def _end_needs(paths, terms, level: float = 0.90, scale=None) -> tuple[np.ndarray, np.ndarray]:
    """Each left-out end's need of the end band that :meth:`Anticipator._summary` reports, from the scored remainders
    of :func:`_spread_terms` at their last phase (the end, u = 1): with ê the end's error and Σ = C + V its
    covariance there (the own conditional one and the duration's spread, unscaled: rad and m), the rotation band
    c · √(3 F_level(3, ν) λ_max(Σ_rot)) holds the end when c ≥ |ê_rot| / √(3 F λ_max), a position coordinate's
    c · t_ν σ_i when c ≥ |ê_i| / (t_ν σ_i) (ν = D − 2, the quantiles the band uses). ``scale`` (D,): each need
    divided by its demonstration's :func:`surprise_scale`, which the band multiplies by. Returns (c_rot (D,),
    c_pos (D, 3))."""
    from scipy.special import fdtri, stdtrit

    nu = max(int(paths.demos) - 2, 1)
    T = int(terms["T"])
    sc = np.asarray(paths.scale, dtype=np.float64)
    e = terms["e"].reshape(-1, T, 6)[:, -1] * sc
    cov = (terms["C"] + terms["V"]).reshape(-1, T, 6, 6)[:, -1] * sc[:, None] * sc[None, :]
    lam = np.maximum(np.linalg.eigvalsh(cov[:, :3, :3])[:, -1], 1e-30)
    c_rot = np.linalg.norm(e[:, :3], axis=1) / np.sqrt(3.0 * fdtri(3, nu, level) * lam)
    sig = np.sqrt(np.maximum(np.einsum("dii->di", cov[:, 3:, 3:]), 1e-30))
    c_pos = np.abs(e[:, 3:]) / (stdtrit(nu, 0.5 + level / 2.0) * sig)
    if scale is not None:
        c_rot = c_rot / scale
        c_pos = c_pos / np.asarray(scale)[:, None]
    return c_rot, c_pos


def duration_candidates(paths) -> list[tuple]:
    """The (τ², r, σ) candidates :func:`_duration_loo` weighs for the duration of ``paths``, each a τ² and either a
    tolerance r in units of each coordinate's spread (σ None) or σ in rad and m (r None): those of
    :data:`DURATION_SMOOTH_GRID` × :data:`DURATION_TOLERANCE_GRID`, with fewer than :data:`DURATION_FEW_BELOW`
    demonstrations :data:`DURATION_FEW` and (DURATION_FEW's τ², :data:`DURATION_FEW_SIGMA`), and the path
    distribution's own τ² and seen tolerance (sorted: the r's, then σ)."""
    cands = {(float(a), float(b), None) for a in DURATION_SMOOTH_GRID for b in DURATION_TOLERANCE_GRID}
    cands.add((float(paths.smooth), float(paths.seen_tolerance), None))
    if paths.demos < DURATION_FEW_BELOW:
        cands.add((float(DURATION_FEW[0]), float(DURATION_FEW[1]), None))
        cands.add((float(DURATION_FEW[0]), None, float(DURATION_FEW_SIGMA)))
    return sorted(cands, key=lambda c: (c[2] is not None, c[0], c[1] or 0.0, c[2] or 0.0))


def finite_sample_count(n: int, level: float) -> int:
    """How many of ``n`` left-out cases a band must hold to be trusted at ``level`` on the next one: ⌈level (n + 1)⌉,
    at most n (the finite-sample quantile of split conformal prediction: for n exchangeable cases a band that holds
    that many holds a new case with probability at least ``level``). The plain share k / n ≥ level asks for one or
    two fewer: with the 20 left-out beginnings of five demonstrations 18 (19 here), and picking the largest evidence
    weight that passes the plain share picks whichever passed by luck (studies of five held 0.76 at 20 % seen)."""
    return int(min(n, np.ceil(float(level) * (n + 1) - 1e-9)))


def _loosest_within(errors: dict, k: float = DURATION_FEW_SE, looseness=None):
    """The one-standard-error rule over ``errors`` {(τ², r, σ): per-beginning left-out errors (n,)}, all scored on the
    same left-out beginnings: with e* the candidate of the smallest mean error, the candidates c whose paired
    difference d = e_c − e* has mean(d) ≤ k · sd(d) / √n; of these the loosest: a tolerance σ in rad and m (the
    largest), else the largest r (the seen poses trusted least), and between equal r (the path distribution's own r
    on the grid's) the smaller τ², which the studies of five measured closer (docs/defaults.md, issue 37's eleventh
    and twelfth passes). ``looseness``: another order of the candidates (the largest is taken), as
    :func:`_loosest_rest`'s."""
    best = min(errors, key=lambda c: float(np.mean(errors[c])))
    within = []
    for c, e in errors.items():
        d = np.asarray(e, dtype=np.float64) - np.asarray(errors[best], dtype=np.float64)
        se = float(np.std(d, ddof=1) / np.sqrt(len(d))) if len(d) > 1 else 0.0
        if float(np.mean(d)) <= k * se:
            within.append(c)
    if looseness is None:
        looseness = lambda c: (c[2] is not None, c[2] or 0.0, c[1] or 0.0, -c[0])  # noqa: E731
    return max(within, key=looseness)


def duration_tolerances(paths, tolerance: float | None = None, sigma: float | None = None) -> np.ndarray:
    """The duration weights' seen tolerance per coordinate (6,), in units of each coordinate's spread σ_c
    (``paths.scale``): σ / σ_c for a tolerance ``sigma`` in rad and m, else r = ``tolerance`` for every coordinate.
    Both None: the path distribution's (``paths.duration_sigma``, else ``paths.duration_tolerance``, else its seen
    tolerance)."""
    if tolerance is None and sigma is None:
        sigma = getattr(paths, "duration_sigma", None)
        tolerance = getattr(paths, "duration_tolerance", None)
        if tolerance is None:
            tolerance = paths.seen_tolerance
    if sigma is not None:
        return float(sigma) / np.asarray(paths.scale, dtype=np.float64)
    return np.full(6, float(tolerance))


def _left_out_beginnings(paths, trajs, folds: int, points: int, fractions=SEEN_FRACTIONS):
    """The left-out beginnings :func:`_duration_loo`, :func:`_evidence_loo` and :func:`_estimated_end_needs` score,
    per group of demonstrations left out (``folds`` groups in a fixed random order): (the others' path distribution,
    the group's seen beginnings [(t, quat, position)] (each left-out demonstration's first F on its own clock, every
    F of ``fractions``), their seen poses [(τ, q, p)] (``points`` of them), the left-out demonstration of each
    beginning (n,), the index of its F in ``fractions`` (n,)). Nothing when fewer than MIN_PATH_DEMOS would be
    left."""
    import copy

    from rbgp_cli.dynamics.paths import MIN_PATH_DEMOS

    D = paths.demos
    order = np.random.default_rng(np.random.SeedSequence([37, D])).permutation(D)
    for group in np.array_split(order, min(int(folds), D)):
        keep = np.setdiff1d(np.arange(D), group)
        if len(keep) < MIN_PATH_DEMOS:
            continue
        rest = copy.copy(paths)
        rest.deviations, rest.log_durations = paths.deviations[keep], paths.log_durations[keep]
        # the group's seen beginnings (each left-out demonstration at each fraction), checked, normalised and
        # sign-continuous once per demonstration (what _seen does to each beginning: row by row, and continuity
        # runs from the start, so the whole motion's first rows are the beginning's own, bit for bit), their
        # seen poses once for every candidate
        seen = []
        for d in group:
            tr = trajs[d]
            t_all, quat_all, pos_all = _seen(tr.t, tr.quat, tr.position, points)[:3]
            for F in fractions:
                k = int(np.clip(np.argmin(np.abs(tr.t - (tr.t[0] + F * tr.duration))), 1, len(tr.t) - 1))
                seen.append((t_all[: k + 1], quat_all[: k + 1], pos_all[: k + 1]))
        poses = [_seen(*s, points, checked=True)[3:] for s in seen]  # τ, q, p of each
        yield rest, seen, poses, np.repeat(group, len(fractions)), np.tile(np.arange(len(fractions)), len(group))


def _duration_loo(paths, trajs, *, folds: int = DURATION_FOLDS, points: int = 6, grid_size: int = 16,
                  per_beginning: bool = False, statistic: str = "median", candidates=None) -> dict:
    """The duration's τ² and r by leaving demonstrations out on the task itself: the demonstrations in
    ``folds`` groups; each group's first F (each of SEEN_FRACTIONS) seen on its own clock, its duration
    estimated (the weights' median; with ``points`` seen poses and ``grid_size`` durations, as the live
    :class:`Follower`'s, for speed) by the others' path distribution with each
    candidate (τ², r, σ) of :func:`duration_candidates` (or of ``candidates``; the seen poses' evidence whole, λ = 1),
    D̂ the weights' ``statistic`` ("median" or "mode", :meth:`Anticipator.point`). Returns
    {(τ², r, σ): mean |ln D̂ − ln D|} ({} without the trajectories or with fewer than MIN_PATH_DEMOS + 1
    demonstrations); ``per_beginning``: {(τ², r, σ): |ln D̂ − ln D| (n,)} per left-out beginning, in the same order
    for every candidate (:func:`_left_out_beginnings`)."""
    from rbgp_cli.dynamics.paths import MIN_PATH_DEMOS

    if trajs is None or len(trajs) != paths.demos or paths.demos < MIN_PATH_DEMOS + 1:
        return {}
    candidates = duration_candidates(paths) if candidates is None else list(candidates)
    err = {c: [] for c in candidates}
    for rest, seen, poses, left_out, _at_f in _left_out_beginnings(paths, trajs, folds, points):
        rest.duration_smooth = rest.duration_tolerance = rest.duration_sigma = None
        for c in candidates:
            ant = Anticipator(rest, None, points=points, grid_size=grid_size, duration_smooth=c[0],
                              duration_tolerance=c[1], duration_sigma=c[2], duration_evidence=1.0,
                              duration_statistic=statistic)
            err[c].extend(abs(np.log(max(D_hat, 1e-9)) - paths.log_durations[d])
                          for d, D_hat in zip(left_out, _duration_points(ant, seen, poses)))
    if not err[candidates[0]]:
        return {}
    if per_beginning:
        return {c: np.asarray(e, dtype=np.float64) for c, e in err.items()}
    return {c: float(np.mean(e)) for c, e in err.items()}


def _evidence_loo(paths, trajs, *, folds: int = DURATION_FOLDS, points: int = SEEN_POINTS,
                  grid_size: int = DURATION_GRID, evidences=DURATION_EVIDENCE_GRID, level: float = 0.90) -> dict:
    """Whether the end time's band holds each left-out duration, per evidence weight λ: the beginnings of
    :func:`_duration_loo` (with the anticipator's own seen poses and grid), the others' path distribution with the
    duration's own τ² and r or σ as ``paths`` has them; the band of level ``level`` is what
    :meth:`Anticipator._summary` reports, the (1 − level)/2 and (1 + level)/2 quantiles of the weights with the
    evidence weighted by λ, moved by :meth:`Anticipator.band_shift` onto the median of the whole evidence's
    weights (the point estimate) and widened to hold it; from SURPRISE_FROM demonstrations on, then widened about
    it by the seen part's surprise as the continuation widens it (:meth:`Anticipator.stretched`, s =
    :func:`surprise_scale` of the beginning's :meth:`Anticipator.surprise` at its point estimate against the
    left-out beginnings' median at the same fraction), so that λ is chosen for the band as it is reported.
    Returns {λ: inside (n,) bool} per left-out beginning; {} as :func:`_duration_loo`."""
    from rbgp_cli.dynamics.paths import MIN_PATH_DEMOS

    if trajs is None or len(trajs) != paths.demos or paths.demos < MIN_PATH_DEMOS + 1:
        return {}
    lams = [float(lam) for lam in evidences]
    bands = {lam: [] for lam in lams}  # (lo, hi) per beginning
    true, meds, spans, rhos, fracs = [], [], [], [], []
    lo_p, hi_p = 0.5 - level / 2.0, 0.5 + level / 2.0
    for rest, seen, poses, left_out, at_f in _left_out_beginnings(paths, trajs, folds, points):
        ant = Anticipator(rest, None, points=points, grid_size=grid_size, duration_evidence=1.0)
        for i, (d, (grid, lw, span)) in enumerate(zip(left_out, _duration_weights(ant, seen, poses, log=True))):
            w1 = ant._tempered(grid, lw, 1.0)
            med = ant.point(grid, w1, span)  # D̂
            true.append(float(np.exp(paths.log_durations[d])))
            meds.append(med)
            spans.append(span)
            fracs.append(at_f[i])
            # the surprise at the weights' median, as the continuation measures it (Anticipator._summary)
            rho_at = med if ant.duration_statistic == "median" else ant._duration_quantiles(grid, w1, span, (0.5,))[0]
            rhos.append(ant.surprise(*poses[i], rho_at) if paths.demos >= SURPRISE_FROM else 0.0)
            for lam in lams:
                wl = w1 if lam == 1.0 else ant._tempered(grid, lw, lam)
                k = ant.band_shift(grid, w1, wl, span)
                lo, hi = (max(x * k, span) for x in ant._duration_quantiles(grid, wl, span, (lo_p, hi_p)))
                bands[lam].append((min(lo, med), max(hi, med)))
    if not true:
        return {}
    true, meds, spans, rhos, fracs = (np.asarray(x, dtype=np.float64) for x in (true, meds, spans, rhos, fracs))
    widen = np.ones(len(true))
    if paths.demos >= SURPRISE_FROM:  # each beginning's widening against the median at its fraction
        for f in np.unique(fracs):
            at = fracs == f
            widen[at] = surprise_scale(rhos[at], float(np.median(rhos[at])))
    out = {}
    for lam in lams:
        b = np.asarray(bands[lam], dtype=np.float64)
        lo, hi = (Anticipator.stretched(b[:, j], meds, widen, spans) for j in (0, 1))
        out[lam] = (lo <= true) & (true <= hi)
    return out


def _duration_points(ant, seen, poses) -> list:
    """The point estimate D̂ (s) that :meth:`Anticipator.weights` and :meth:`Anticipator.point` give for each seen
    beginning of ``seen`` [(t (N,), quat (N, 4), position (N, 3))], checked, unit and sign-continuous as
    :func:`_seen` leaves them, and ``poses`` [(τ (n,), q (n, 4), p (n, 3))] its seen poses (:func:`_seen` with the
    anticipator's ``points``): :func:`_duration_weights`' weights, their median or mode (the anticipator's
    ``duration_statistic``)."""
    return [ant.point(grid, w, span) for grid, w, span in _duration_weights(ant, seen, poses)]


def _duration_weights(ant, seen, poses, log: bool = False) -> list:
    """[(grid (G,) s, weights (G,), span s)] per seen beginning of ``seen`` (as :func:`_duration_points` takes
    them): :meth:`Anticipator.weights`' grid and weights, their log weights computed for all the beginnings at once: :meth:`Anticipator._grid_terms`'
    log weight, −½ eᵀG⁻¹e − ½ log det G, with the beginnings × the grid's durations as one batch (its end pose's mean
    and covariance, which :func:`_duration_loo` does not use, left out). The same numbers as the loop over
    ``weights`` to rounding (tests/dynamics/test_anticipation_modes.py); a beginning longer than every duration of
    the grid, or with another number of seen poses than the first, goes through ``weights`` itself. ``log``: the
    log weights (any constant) in place of the weights."""
    out = [None] * len(seen)
    n0 = len(poses[0][0]) if seen else 0
    full = ant.grid
    batch = [i for i, (tau, _q, _p) in enumerate(poses) if len(tau) == n0 and n0 > 1 and np.any(full >= tau[-1])]
    for i in sorted(set(range(len(seen))) - set(batch)):
        grid, w, terms = ant.weights(*seen[i], checked=True)
        out[i] = (grid, np.log(np.maximum(w, 1e-300)) if log else w, terms["span"])
    if not batch:
        return out
    U, Ks, tau2 = ant._low_rank()
    S, P = ant.paths.S, len(ant.m)
    B, G0, n = len(batch), len(full), n0
    tau = np.repeat(np.stack([poses[i][0] for i in batch]), G0, axis=0)  # (B·G0, n): row b·G0 + g
    grid = np.tile(full, B)  # (B·G0,)
    q = np.repeat(np.stack([poses[i][1] for i in batch]), G0, axis=0)
    p = np.repeat(np.stack([poses[i][2] for i in batch]), G0, axis=0)
    G_ = len(grid)
    ph = np.minimum(tau / grid[:, None], 1.0)  # (G_, n)
    x = ph * (S - 1)
    k = np.minimum(x.astype(int), S - 2)
    f = x - k
    I0 = (6 * k[:, :, None] + np.arange(6)).reshape(G_, 6 * n)
    w1 = np.repeat(f, 6, axis=1)
    w0 = 1.0 - w1
    AU = w0[:, :, None] * U[I0] + w1[:, :, None] * U[I0 + 6]  # (G_, 6n, D)
    g0, g1 = 1.0 - f, f
    Kint = (g0[:, :, None] * g0[:, None, :] * Ks[k[:, :, None], k[:, None, :]]
            + g0[:, :, None] * g1[:, None, :] * Ks[k[:, :, None], k[:, None, :] + 1]
            + g1[:, :, None] * g0[:, None, :] * Ks[k[:, :, None] + 1, k[:, None, :]]
            + g1[:, :, None] * g1[:, None, :] * Ks[k[:, :, None] + 1, k[:, None, :] + 1])
    k6 = 6 * n + 1
    # the bordered matrix [[G, e], [eᵀ, big]]: its Cholesky factor's last row holds (L⁻¹ e)ᵀ
    M = np.zeros((G_, k6 + 1, k6 + 1))
    Gm = M[:, :k6, :k6]
    Gm[:, :-1, :-1] = AU @ AU.transpose(0, 2, 1)
    _add_kron_i6(Gm[:, :-1, :-1], tau2 * Kint)
    uL = U[P - 1]
    Gm[:, :-1, -1] = AU @ uL
    Gm[:, -1, :-1] = Gm[:, :-1, -1]
    Gm[:, -1, -1] = uL @ uL + tau2 + _ELL_TOL ** 2
    dg = np.arange(6 * n)
    Gm[:, dg, dg] += np.tile(ant._duration_r2, n)
    e = M[:, :k6, k6]
    e[:, :-1] = ant._deviations(k, f, q, p).reshape(G_, 6 * n)  # y − A m, as the live update computes it
    e[:, -1] = np.log(grid) / ant.lscale - ant.m[-1]
    M[:, k6, :k6] = e
    M[:, k6, k6] = 1e100
    L = np.linalg.cholesky(M)
    Le = L[:, k6, :k6]
    logw = (-0.5 * np.einsum("gk,gk->g", Le, Le)
            - np.sum(np.log(np.diagonal(L[:, :k6, :k6], axis1=1, axis2=2)), axis=1)).reshape(B, G0)
    for row, i in enumerate(batch):
        span = float(poses[i][0][-1])
        keep = full >= span
        out[i] = (full[keep], logw[row, keep] if log else ant._tempered(full[keep], logw[row, keep], 1.0), span)
    return out


# ----------------------------------------------------------------------------------------- the duration's part of the bands
#: :func:`fit_seen` scores the left-out remainders against the samples as they are drawn: each at its own duration
#: (:func:`_spread_terms`), not at the remainder's true duration (docs/defaults.md, issue 37's eighth pass)
DURATION_SPREAD = True
#: ... from this many demonstrations on (fewer: the seventh pass's statistic, at the true durations). Ten until the
#: thirteenth pass; since the samples draw their durations from the tempered weights, whose spread the statistic at
#: the true durations does not see, five (docs/defaults.md, issue 37's eighth and thirteenth passes)
SPREAD_FROM = 5
#: :func:`_spread_terms`' duration grid (per left-out demonstration, over GRID_RANGE times the others' durations), the
#: cells kept (weight above SPREAD_KEEP of the largest) and the durations per kept cell (midpoints of equal sub-cells:
#: the samples' uniform jitter within a cell)
SPREAD_GRID = 16
SPREAD_KEEP = 1e-3
SPREAD_SUB = 3
SPREAD_BLOCK = 256
#: seen poses of the duration's weights in :func:`_spread_terms` (as :func:`_duration_loo`'s)
SPREAD_POINTS = 6


def _loo_rows(ctx, d, dur, tau2, tol, query, *, logw: bool = False, cov: bool = False, quad: bool = False,
              ell: float = _ELL_TOL, near: float | None = None):
    """Batched over rows b: the others' distribution of left-out demonstration d_b (the mean m_d and the sample part
    c (X_o − m_d)ᵀ(X_o − m_d) of :func:`~rbgp_cli.dynamics.paths.left_out_moments`, c = (1 + 1/N)/(N − 1), plus the
    smooth term τ² (K_ℓ ⊗ I_6 ⊕ 1)) conditioned on d_b's seen grid poses (``ctx["js"]``, at true times
    τ_k = s_k D_(d_b)) taken as lying at the phases a_k = min(τ_k / D_b, 1) of the duration D_b = ``dur[b]``: the
    deviation y_k of the pose from the mean path at a_k (tolerance ``tol`` in units of the spread; the last seen
    pose exactly, GOAL_TOLERANCE, unless ``logw``, where every pose has ``tol`` as the duration's weights do) and
    ℓ = ln D_b (tolerance ``ell``, default _ELL_TOL). With G = A Σ Aᵀ + R (A the linear interpolation at the a_k),

        x̂(q) = W(q) m_d + W(q) Σ Aᵀ G⁻¹ (y − A m_d),    W(q) Σ Aᵀ = (W(q) Z)(A Z)ᵀ + τ² K_ℓ(q, a) ⊗ I_6,

    Z the others' centred, scaled rows (as columns; d_b's own column zero). ``query`` (B, T) phases. Returns
    x̂ at the query phases (B, T, 6) scaled; with ``logw`` also −½ eᵀG⁻¹e − ½ log det G (B,) (e = y − A m_d), with
    ``cov`` the conditioned covariance's diagonal blocks at the query phases (B, T, 6, 6), with ``quad`` (last) the
    seen part's surprise eᵀG⁻¹e / (6n + 1) (B,) (:meth:`Anticipator.surprise` when ``logw``). ``near``: the
    second-to-last seen pose's tolerance (the rest's near pose: ``ctx["js"]`` holds its grid phase). No loop over the
    rows: every interpolation is a gather of grid values."""
    X, Ks, S, js = ctx["X"], ctx["Ks"], ctx["S"], ctx["js"]
    Dn = len(X)
    B, n, T = len(d), len(js), query.shape[1]
    c = np.sqrt((1.0 + 1.0 / (Dn - 1)) / max(Dn - 2, 1))
    mask = np.ones((B, Dn))
    mask[np.arange(B), d] = 0.0
    mo = ctx["m_loo"][d]  # (B, P) the others' means
    a = np.minimum(ctx["seen_time"][d] / dur[:, None], 1.0)  # (B, n) the seen poses' phases at D_b

    def interp(ph):
        x = ph * (S - 1)
        k = np.minimum(x.astype(np.intp), S - 2)
        return k, x - k

    ka, fa = interp(a)
    kq, fq = interp(np.clip(query, 0.0, 1.0))
    Xg = ctx["Xg"]  # (S, 6, Dn) the demonstrations' path entries per grid phase
    mg = mo[:, :-1].reshape(B, S, 6)

    def rows_m(k, f):  # W m_d (B, ·, 6) at interval k, fraction f
        bi = np.arange(B)[:, None]
        return (1.0 - f)[..., None] * mg[bi, k] + f[..., None] * mg[bi, k + 1]

    def rows(k, f):  # W X (B, ·, 6, Dn) and W m_d (B, ·, 6)
        return (1.0 - f)[..., None, None] * Xg[k] + f[..., None, None] * Xg[k + 1], rows_m(k, f)

    def kern(k1, f1, k2, f2):  # K_ℓ interpolated in both arguments (B, ·, ·)
        g0, g1, h0, h1 = 1.0 - f1[:, :, None], f1[:, :, None], 1.0 - f2[:, None, :], f2[:, None, :]
        i, j = k1[:, :, None], k2[:, None, :]
        return g0 * h0 * Ks[i, j] + g0 * h1 * Ks[i, j + 1] + g1 * h0 * Ks[i + 1, j] + g1 * h1 * Ks[i + 1, j + 1]

    WXa, Wma = rows(ka, fa)
    k6 = 6 * n + 1
    Za = np.empty((B, k6, Dn))
    Za[:, :-1] = (WXa - Wma[..., None]).reshape(B, 6 * n, Dn)
    Za[:, -1] = X[:, -1][None, :] - mo[:, -1:]
    Za *= c * mask[:, None, :]
    Kaa = kern(ka, fa, ka, fa)
    G = Za @ Za.transpose(0, 2, 1)
    _add_kron_i6(G[:, :6 * n, :6 * n], tau2 * Kaa)
    G[:, -1, -1] += tau2 + float(ell) ** 2
    r2 = np.tile(np.broadcast_to(np.asarray(tol, dtype=np.float64) ** 2, (6,)), n)  # r, or r_c per coordinate
    if not logw:
        r2[-6:] = ctx["r_last"]
    if near is not None and n >= 2:
        r2[-12:-6] = float(near) ** 2
    dg = np.arange(6 * n)
    G[:, dg, dg] += r2
    e = np.empty((B, k6))
    e[:, :-1] = (ctx["ant"]._deviations(ka, fa, ctx["seen_q"][d], ctx["seen_p"][d])
                 + ctx["ant_m"][ka] + fa[..., None] * ctx["ant_dm"][ka] - Wma).reshape(B, 6 * n)
    e[:, -1] = np.log(dur) / ctx["lscale"] - mo[:, -1]
    alpha = np.linalg.solve(G, e[..., None])[..., 0]  # G⁻¹ e
    # W(q) Z β with β = (A Z)ᵀ α: c (W(q) X b − W(q) m_d Σ b), b = mask ⊙ β, without W(q) Z itself
    b = c * np.einsum("bkn,bk->bn", Za, alpha) * mask
    Xb = np.einsum("scn,bn->bsc", Xg, b)  # (B, S, 6)
    bi = np.arange(B)[:, None]
    Wmq = rows_m(kq, fq)
    Kqa = kern(kq, fq, ka, fa)  # (B, T, n)
    mean = (Wmq + ((1.0 - fq)[..., None] * Xb[bi, kq] + fq[..., None] * Xb[bi, kq + 1] - Wmq * b.sum(axis=1)[:, None, None])
            + tau2 * np.einsum("bti,bic->btc", Kqa, alpha[:, :-1].reshape(B, n, 6)))
    out = [mean]
    if logw:
        L = np.linalg.cholesky(G)
        out.append(-0.5 * np.einsum("bk,bk->b", e, alpha) - np.sum(np.log(np.diagonal(L, axis1=1, axis2=2)), axis=1))
    if cov:
        WXq, _ = rows(kq, fq)
        Zq = c * (WXq - Wmq[..., None]) * mask[:, None, None, :]  # (B, T, 6, Dn)
        SqA = np.einsum("btcn,bkn->btck", Zq, Za).reshape(B, 6 * T, k6)  # Σ_qA
        _add_kron_i6(SqA[..., :-1], tau2 * Kqa)
        GS = np.linalg.solve(G, SqA.transpose(0, 2, 1)).reshape(B, k6, T, 6)  # G⁻¹ Σ_Aq
        Kqq = Ks[kq, kq] * (1 - fq) ** 2 + 2 * Ks[kq, kq + 1] * fq * (1 - fq) + Ks[kq + 1, kq + 1] * fq ** 2
        C = np.einsum("btcn,btdn->btcd", Zq, Zq) + tau2 * Kqq[..., None, None] * np.eye(6)
        out.append(C - np.einsum("btck,bktd->btcd", SqA.reshape(B, T, 6, k6), GS))
    if quad:  # the seen part's surprise: eᵀG⁻¹e per observed number
        out.append(np.einsum("bk,bk->b", e, alpha) / k6)
    return tuple(out) if len(out) > 1 else mean


def _spread_context(paths, points: int = SEEN_POINTS):
    """What :func:`_loo_rows` needs whatever the fraction: the demonstrations' vectors X (D, P) and their path
    entries per grid phase (S, 6, D), each one's others' mean (D, P) and durations' grid (D, SPREAD_GRID), K_ℓ,
    an :class:`Anticipator` of the whole distribution (its :meth:`~Anticipator._deviations`, whose prior mean is
    added back), the last seen pose's tolerance r² (6,) and each demonstration's poses on the grid."""
    from rbgp_cli.dynamics.paths import GOAL_TOLERANCE

    X = paths.vectors()
    Dn, P = X.shape
    S = paths.S
    m_loo = (X.sum(axis=0)[None] - X) / (Dn - 1)
    ant = Anticipator(paths)
    am = ant.m[:-1].reshape(S, 6)
    q, p = paths.pose_at(paths.deviations, paths.s)  # (D, S, 4), (D, S, 3) the demonstrations on the grid
    dur = np.exp(paths.log_durations)
    others = np.array([np.delete(dur, i) for i in range(Dn)])
    lo, hi = np.log(GRID_RANGE[0] * others.min(axis=1)), np.log(GRID_RANGE[1] * others.max(axis=1))
    grid = np.exp(lo[:, None] + (hi - lo)[:, None] * np.linspace(0.0, 1.0, SPREAD_GRID)[None])
    return dict(X=X, Xg=np.ascontiguousarray(X[:, :-1].T.reshape(S, 6, Dn)), S=S, m_loo=m_loo,
                Ks=np.exp(-0.5 * ((paths.s[:, None] - paths.s[None, :]) / paths.length) ** 2),
                ant=ant, ant_m=am[:-1], ant_dm=np.diff(am, axis=0), lscale=paths.duration_scale,
                r_last=(np.array(GOAL_TOLERANCE).repeat(3) / paths.scale) ** 2, q=q, p=p, dur=dur, grid=grid,
                half=0.5 * (hi - lo) / (SPREAD_GRID - 1), points=points)


def _seen_at(ctx, paths, js):
    """:func:`_spread_context`'s ``ctx`` with every demonstration seen at the grid phases ``js`` (n,): their times
    ``seen_time`` (D, n) s on each one's own clock, poses ``seen_q`` (D, n, 4) and ``seen_p`` (D, n, 3)."""
    return dict(ctx, js=js, seen_time=ctx["dur"][:, None] * paths.s[js][None], seen_q=ctx["q"][:, js], seen_p=ctx["p"][:, js])


def _spread_terms(paths, F: float, rest: tuple | None = None, ctx=None, duration: bool = True,
                  widen_reference: float | str | None = None) -> dict:
    """The left-out remainders of fraction F against the samples as drawn (module docstring, issue 37's eighth
    pass). Each demonstration d left out, its first F seen at its true phases (:func:`seen_split`'s seen grid
    phases; the last exactly); the remainder scored at every grid phase s_j after F, u_j = (s_j − s_J)/(1 − s_J)
    its normalised time. The samples draw D from the duration's weights (the others' distribution with the
    duration's τ² and r on SPREAD_GRID durations; cells above SPREAD_KEEP of the largest, SPREAD_SUB durations
    each) and follow, at u_j, the phase s_g(u_j) = s0_g + u_j (1 − s0_g), s0_g = s_J D_d / D_g. With y_gj the
    deviation from the mean path at s_j of the own conditioned mean at D_g taken at s_g(u_j) (scaled),

        ȳ_j = Σ_g w_g y_gj,   V_j = Σ_g w_g (y_gj − ȳ_j)(y_gj − ȳ_j)ᵀ,   ê_j = x_dj − μ_j − (ȳ_j − x̂_j),

    μ_j the mean the continuation follows (``rest`` (τ²_rest, r_rest[, ln D's tolerance[, the near pose's]]); None:
    the own) and x̂_j the own conditioned mean at the true duration.
    Returns {"e": ê (R, 6), "V": (R, 6, 6), "C": the own conditioned covariance's
    diagonal blocks at the true duration (R, 6, 6), "w": each scored phase's share of the remainder's normalised
    time (R,), "rho": each left-out seen part's surprise (D,) at its point estimate of D (``duration=False``: at its
    true D) and "rho_live" the same from SPREAD_POINTS seen poses, "T": the scored phases per demonstration},
    R = D × the scored phases, demonstration-major. ``duration=False``: the remainders at their true
    durations alone (V = 0, ȳ = x̂: ê_j = x_dj − μ_j), the statistic without the duration's part.
    ``widen_reference`` (a ρ̄, or "median": the median of "rho"): each left-out demonstration's durations D_g moved
    away from its D̂ by its widening s = :func:`surprise_scale` (ρ, ρ̄) in ln D, D̂ (D_g / D̂)^s, as
    :meth:`Anticipator.stretched` moves the continuation's samples' (None: not moved)."""
    ctx = _spread_context(paths) if ctx is None else ctx
    X, S = ctx["X"], ctx["S"]
    Dn, P = X.shape
    idx, no = seen_split(F, S, P, ctx["points"])
    js = idx[:no - 1:6] // 6  # the seen grid phases
    J = int(js[-1])
    jt = np.arange(J + 1, S)
    T = len(jt)
    u = (jt - J) / (S - 1 - J)
    ctx = _seen_at(ctx, paths, js)
    tau2, r = float(paths.smooth), float(paths.seen_tolerance)
    ds = np.arange(Dn)
    true_q = np.broadcast_to(paths.s[jt], (Dn, T))
    own, C = _loo_rows(ctx, ds, ctx["dur"], tau2, r, true_q, cov=True)
    near = float(rest[3]) if rest is not None and len(rest) > 3 and rest[3] is not None else None
    ctx_mu = ctx
    if near is not None:  # the rest's seen poses: with the grid phase just before the last (seen_split's near)
        idx_n, no_n = seen_split(F, S, P, ctx["points"], near=True)
        jn = idx_n[:no_n - 1:6] // 6
        ctx_mu = _seen_at(ctx, paths, jn)
    mu = own if rest is None or tuple(rest) == (tau2, r) else \
        _loo_rows(ctx_mu, ds, ctx["dur"], float(rest[0]), float(rest[1]), true_q,
                  ell=float(rest[2]) if len(rest) > 2 else _ELL_TOL, near=near)
    x_true = X[:, :-1].reshape(Dn, S, 6)[:, jt]
    mid = np.concatenate([[0.0], 0.5 * (u[1:] + u[:-1]), [1.0]])
    share = np.tile(np.diff(mid), Dn)
    if not duration:
        return {"e": (x_true - mu).reshape(-1, 6), "V": np.zeros((Dn * T, 6, 6)), "C": C.reshape(-1, 6, 6), "w": share,
                "rho": _loo_rows(ctx, ds, ctx["dur"], tau2, r, np.zeros((Dn, 1)), logw=True, quad=True)[2], "T": T}
    w, shift, d_hat, ctx6, d_med = _left_out_weights(paths, F, ctx)
    span, grid = ctx["seen_time"][:, -1], ctx["grid"]
    # the seen part's surprise at each left-out demonstration's median of D, as the continuation computes it
    # (Anticipator.surprise_at), from ctx's seen poses and from the live update's
    rho = _loo_rows(ctx, ds, d_med, tau2, r, np.zeros((Dn, 1)), logw=True, quad=True)[2]
    rho_live = _loo_rows(ctx6, ds, d_med, tau2, r, np.zeros((Dn, 1)), logw=True, quad=True)[2]
    dd, gg = np.nonzero(w > SPREAD_KEEP * w.max(axis=1, keepdims=True))
    off = (2.0 * np.arange(SPREAD_SUB) + 1.0 - SPREAD_SUB) / SPREAD_SUB  # sub-cell midpoints in half steps
    rd = np.repeat(dd, SPREAD_SUB)
    Dg = np.exp(np.log(grid[dd, gg] * shift[dd])[:, None] + off[None] * ctx["half"][dd, None])
    if widen_reference is not None:  # D̂ (D_g / D̂)^s, as the continuation's samples
        ref = float(np.median(rho)) if widen_reference == "median" else float(widen_reference)
        Dg = Anticipator.stretched(Dg, d_hat[dd, None], surprise_scale(rho, ref)[dd, None])
    Dg = np.maximum(Dg.ravel(), span[rd] * (1 + 1e-9))
    wg = np.repeat(w[dd, gg], SPREAD_SUB) / SPREAD_SUB
    s0 = np.minimum(span[rd] / Dg, 1.0)
    q = s0[:, None] + u[None] * (1.0 - s0[:, None])  # (R_g, T)
    # the own conditioned means at D_g, at s_g(u_j) (R_g, T, 6), in blocks of SPREAD_BLOCK rows (memory)
    xg = np.concatenate([_loo_rows(ctx, rd[i:i + SPREAD_BLOCK], Dg[i:i + SPREAD_BLOCK], tau2, r, q[i:i + SPREAD_BLOCK])
                         for i in range(0, len(rd), SPREAD_BLOCK)])
    y = _rebase(paths, xg, q, np.broadcast_to(paths.s[jt], q.shape))
    wsum = np.zeros(Dn)
    np.add.at(wsum, rd, wg)
    wn = wg / wsum[rd]
    ybar = np.zeros((Dn, T, 6))
    np.add.at(ybar, rd, wn[:, None, None] * y)
    dy = y - ybar[rd]
    V = np.zeros((Dn, T, 6, 6))
    np.add.at(V, rd, wn[:, None, None, None] * dy[..., :, None] * dy[..., None, :])
    e_hat = x_true - mu - (ybar - own)
    return {"e": e_hat.reshape(-1, 6), "V": V.reshape(-1, 6, 6), "C": C.reshape(-1, 6, 6), "w": share, "rho": rho,
            "rho_live": rho_live, "T": T}


def _left_out_weights(paths, F: float, ctx):
    """Each left-out demonstration's duration weights seen up to fraction F, as the continuation's samples draw them
    (:func:`_spread_terms`): the others' distribution with the duration's τ² and r on its SPREAD_GRID durations
    (``ctx["grid"]``, those shorter than the seen span left out), SPREAD_POINTS seen poses at their true times, the
    seen poses' evidence weighted by λ (``paths.duration_evidence``). ``ctx``: :func:`_spread_context`'s with the
    fraction's seen grid phases (``js``, ``seen_time``, ``seen_q``, ``seen_p``). Returns (w (D, G) the weights, shift (D,)
    the factor moving them onto the whole evidence's D̂, d_hat (D,) that D̂ (its median, or its mode with
    ``paths.duration_statistic`` "mode"): the point estimate of D, ctx6 the
    context of the SPREAD_POINTS seen poses, d_med (D,) the whole evidence's median, where the seen part's surprise
    is measured)."""
    X, S = ctx["X"], ctx["S"]
    Dn, P = X.shape
    ds = np.arange(Dn)
    # the duration's weights over each left-out demonstration's grid (durations shorter than the seen span left out)
    dsm = float(paths.smooth if paths.duration_smooth is None else paths.duration_smooth)
    dtol = duration_tolerances(paths)
    span = ctx["seen_time"][:, -1]
    grid = ctx["grid"]
    rows_d = np.repeat(ds, SPREAD_GRID)
    idx6, no6 = seen_split(F, S, P, SPREAD_POINTS)
    js6 = idx6[:no6 - 1:6] // 6
    ctx6 = _seen_at(ctx, paths, js6)
    _, lw = _loo_rows(ctx6, rows_d, grid.ravel(), dsm, dtol, np.zeros((len(rows_d), 1)), logw=True)
    lam = 1.0 if paths.duration_evidence is None else float(paths.duration_evidence)
    if lam != 1.0:  # the seen poses' evidence weighted by λ, the others' prior of ℓ kept whole (Anticipator._tempered)
        lw1 = np.where(grid.ravel() >= span[rows_d], lw, -np.inf).reshape(Dn, SPREAD_GRID)
        xl = X[:, -1]
        dev = xl[None, :] - ctx["m_loo"][:, -1:]  # (D, D): others' ℓ about each left-out one's others' mean
        dev[ds, ds] = 0.0
        v = ((1.0 + 1.0 / (Dn - 1)) / max(Dn - 2, 1) * np.sum(dev * dev, axis=1) + dsm + _ELL_TOL ** 2)[rows_d]
        e2 = (np.log(grid.ravel()) / ctx["lscale"] - ctx["m_loo"][rows_d, -1]) ** 2
        lw = _temper_log(lw, e2, v, max(Dn - 2, 1), lam)  # ν: the others' D − 1 durations
    lw = np.where(grid.ravel() >= span[rows_d], lw, -np.inf).reshape(Dn, SPREAD_GRID)
    lw = np.where(np.isfinite(lw).any(axis=1, keepdims=True), lw, np.where(np.arange(SPREAD_GRID) == SPREAD_GRID - 1, 0.0, -np.inf))
    w = np.exp(lw - lw.max(axis=1, keepdims=True))
    w /= w.sum(axis=1, keepdims=True)
    w1 = w  # the whole evidence's weights (λ = 1)
    if lam != 1.0:
        ok = np.isfinite(lw1).any(axis=1)
        w1 = np.exp(lw1 - np.where(ok, lw1.max(axis=1), 0.0)[:, None])
        w1 = np.where(ok[:, None], w1 / np.where(ok, w1.sum(axis=1), 1.0)[:, None], w)
    med = _row_medians(grid, w, ctx["half"], span)
    d_med = med if w1 is w else _row_medians(grid, w1, ctx["half"], span)
    # the samples' durations moved onto the whole evidence's D̂, its median or mode (Anticipator.band_shift; 1 where
    # the weights are the whole evidence's and D̂ their median); each left-out demonstration's point estimate of D
    # as the continuation's
    mode = getattr(paths, "duration_statistic", None) == "mode"
    shift = (_row_log_modes(grid, w1, span) if mode else d_med) / med
    floor = span * (1 + 1e-9)
    return w, shift, np.maximum(med * shift, floor), ctx6, np.maximum(d_med, floor)


def _rest_at_estimates(paths, rests, ctx=None) -> np.ndarray:
    """The left-out final pose and remainder of the continuation's mean at each left-out demonstration's estimated
    duration, for each rest conditioning of ``rests`` [(τ², r, ln D's tolerance, near tolerance or None)]: each
    demonstration d left out, its first F (each of SEEN_FRACTIONS) seen at its true times, its duration estimated as
    the samples' statistic does (:func:`_left_out_weights`: D̂_d), and the others' distribution conditioned at D̂_d on
    those poses, the last exactly, ln D̂_d and, with a near tolerance, the pose D̂_d / (S − 1) before the last
    (interpolated on d's grid path, as :meth:`Anticipator._near` takes it from the seen samples). Its mean at the
    remainder's normalised time u (phase ŝ_0 + u (1 − ŝ_0), ŝ_0 = span / D̂_d) against d at phase s_J + u (1 − s_J), in
    units of each coordinate's spread, at :func:`seen_split`'s scored phases: eᵀe at the end plus (1/k) Σ_j e_jᵀe_j,
    summed over the fractions (:func:`_end_loo`'s criterion, where the seen part's phases are the estimate's, not the
    truth's: a pose read at a wrong phase, such as the near one, is scored as the continuation reads it). Returns
    (len(rests), D)."""
    ctx = _spread_context(paths) if ctx is None else ctx
    X, S = ctx["X"], ctx["S"]
    Dn, P = X.shape
    ds = np.arange(Dn)
    out = np.zeros((len(rests), Dn))
    for F in SEEN_FRACTIONS:
        idx, no = seen_split(F, S, P, ctx["points"])
        js = idx[:no - 1:6] // 6
        jt = idx[no::6] // 6  # the scored phases, the end last
        J = int(js[-1])
        cF = _seen_at(ctx, paths, js)
        d_hat = _left_out_weights(paths, F, cF)[2]
        span = cF["seen_time"][:, -1]
        s0 = np.minimum(span / d_hat, 1.0)
        u = (paths.s[jt] - paths.s[J]) / (1.0 - paths.s[J])
        q = s0[:, None] + u[None] * (1.0 - s0[:, None])  # (D, k)
        x_true = X[:, :-1].reshape(Dn, S, 6)[:, jt]
        t_near = np.maximum(span - d_hat / (S - 1), 0.0)
        qn, pn = paths.pose_at(paths.deviations, (t_near / ctx["dur"])[:, None])  # (D, 1, ·) on each d's own path
        last = len(js) - 1  # the near pose goes before the last seen one
        cN = dict(cF, js=np.insert(js, last, J - 1), seen_time=np.insert(cF["seen_time"], last, t_near, axis=1),
                  seen_q=np.insert(cF["seen_q"], last, qn[:, 0], axis=1), seen_p=np.insert(cF["seen_p"], last, pn[:, 0], axis=1))
        for i, rest in enumerate(rests):
            near = rest[3] if len(rest) > 3 else None
            mu = _loo_rows(cF if near is None else cN, ds, d_hat, float(rest[0]), float(rest[1]), q,
                           ell=float(rest[2]) if len(rest) > 2 else _ELL_TOL, near=near)
            e = x_true - _rebase(paths, mu, q, np.broadcast_to(paths.s[jt], q.shape))
            out[i] += np.sum(e[:, -1] ** 2, axis=1) + np.sum(e * e, axis=(1, 2)) / len(jt)
    return out


def _temper_log(logw, e2, v, nu: int, lam: float):
    """The log weights of ln D with the seen poses' evidence weighted by λ and the prior of ℓ kept whole as its
    Student-t predictive: log t_ν(ℓ) + λ (log w − log N(ℓ)), up to a constant, elementwise; ``logw`` the log weights
    log N(ℓ) + log p(y | ℓ) (any constant), ``e2`` (ℓ − m_ℓ)² and ``v`` the prior's variance of ℓ (scaled), ν its
    degrees of freedom: −(ν + 1)/2 ln(1 + e²/(ν v)) + λ (log w + e²/(2 v)). λ → 0: the durations' own predictive."""
    return -0.5 * (nu + 1.0) * np.log1p(e2 / (nu * v)) + lam * (logw + 0.5 * e2 / v)


def _row_medians(grid, w, half, span):
    """Per row d the median duration of weights ``w`` (D, G) over ``grid`` (D, G) s, each grid value's weight spread
    evenly over its cell in ln D (``half`` (D,) its half-width), at least ``span`` (D,): what
    :meth:`Anticipator._duration_quantiles` gives at 50 %, for every row at once."""
    lg = np.log(grid)
    edges = np.concatenate([lg[:, :1] - half[:, None], lg + half[:, None]], axis=1)  # (D, G + 1)
    cw = np.concatenate([np.zeros((len(w), 1)), np.cumsum(w, axis=1)], axis=1)
    j = np.clip((cw < 0.5).sum(axis=1) - 1, 0, w.shape[1] - 1)  # the cell holding the median
    r = np.arange(len(w))
    f = (0.5 - cw[r, j]) / np.maximum(cw[r, j + 1] - cw[r, j], 1e-300)
    return np.maximum(np.exp(edges[r, j] + f * (edges[r, j + 1] - edges[r, j])), span)


def _log_mode(grid, w, span) -> float:
    """The mode of weights ``w`` (G,) over durations ``grid`` (G,) s in x = ln D, refined by the parabola through the log
    weights y at the largest one j and its neighbours (the grid's log spacing need not be even: the live update
    evaluates a subset): x̂ = x_j − ½ [(x_j − x_{j−1})² (y_j − y_{j+1}) − (x_j − x_{j+1})² (y_j − y_{j−1})] /
    [(x_j − x_{j−1})(y_j − y_{j+1}) − (x_j − x_{j+1})(y_j − y_{j−1})], kept within the cell of x_j (half-way to
    each neighbour); x_j itself at the grid's ends, where a neighbour's weight is 0 or where the parabola is not
    concave. Returns e^x̂, at least ``span``: :meth:`Anticipator.point` with "mode". In scalars (the live update
    calls it once per pose; :func:`_row_log_modes` is the same per row)."""
    w = np.asarray(w, dtype=np.float64)
    G = len(w)
    j = int(np.argmax(w))
    x1 = math.log(float(grid[j]))
    out = x1
    if 0 < j < G - 1 and w[j - 1] > 0.0 and w[j + 1] > 0.0:
        x0, x2 = math.log(float(grid[j - 1])), math.log(float(grid[j + 1]))
        y0, y1, y2 = math.log(float(w[j - 1])), math.log(float(w[j])), math.log(float(w[j + 1]))
        a, b = (x1 - x0) * (y1 - y2), (x1 - x2) * (y1 - y0)
        if a - b > 0.0:  # concave through three positive weights
            xv = x1 - 0.5 * ((x1 - x0) * a - (x1 - x2) * b) / (a - b)
            out = min(max(xv, 0.5 * (x0 + x1)), 0.5 * (x1 + x2))
    return max(math.exp(out), float(span))


def _row_log_modes(grid, w, span):
    """:func:`_log_mode` per row d of weights ``w`` (D, G) over ``grid`` (D, G) s, at least ``span`` (D,)."""
    x = np.log(grid)
    D, G = w.shape
    r = np.arange(D)
    j = np.argmax(w, axis=1)
    out = x[r, j].copy()
    inner = (j > 0) & (j < G - 1)
    if G >= 3 and np.any(inner):
        jm, jp = np.clip(j - 1, 0, G - 1), np.clip(j + 1, 0, G - 1)
        with np.errstate(divide="ignore", invalid="ignore"):
            y0, y1, y2 = np.log(w[r, jm]), np.log(w[r, j]), np.log(w[r, jp])
            x0, x1, x2 = x[r, jm], x[r, j], x[r, jp]
            a, b = (x1 - x0) * (y1 - y2), (x1 - x2) * (y1 - y0)
            den = a - b
            ok = inner & np.isfinite(y0) & np.isfinite(y2) & (den > 0)  # concave through three positive weights
            xv = x1 - 0.5 * ((x1 - x0) * a - (x1 - x2) * b) / np.where(ok, den, 1.0)
        out = np.where(ok, np.clip(xv, 0.5 * (x0 + x1), 0.5 * (x1 + x2)), out)
    return np.maximum(np.exp(out), span)


def _rebase(paths, x, q, s):
    """Scaled deviations x (..., 6) from the mean path at phases q (...) re-expressed from the mean path at
    phases s (...): (log(exp(δ_rot) R̄(q) R̄(s)ᵀ), p̄(q) + δ_pos − p̄(s)) / σ, δ = x σ."""
    from rbgp_cli.dynamics.paths import pose_deviation
    from rbgp_cli.geometry.so3 import exp_quat, quat_multiply

    zero = np.zeros((paths.S, 6))
    qq, qp = paths.pose_at(zero, q.reshape(-1))
    sq, sp = paths.pose_at(zero, s.reshape(-1))
    dev = x.reshape(-1, 6) * paths.scale
    out = pose_deviation(sq, sp, quat_multiply(exp_quat(dev[:, :3]), qq), qp + dev[:, 3:])
    return (out / paths.scale).reshape(x.shape)


def _spread_factors(terms, demos: int, level: float = 0.90, scale=None) -> tuple[float, float]:
    """The factors (c_rot, c_pos) the scored remainders of :func:`_spread_terms` need (unclamped): per scored
    phase and position coordinate the smallest c with ê² ≤ c² t_ν² σ² + z² v (σ² the draws' variance, C's
    diagonal; v V's; t_ν the Student-t 95 % quantile the draws realise, ν = D − 2; z the normal's), per rotation the smallest
    c with êᵀ(c² 3 F_0.9(3, ν) C + χ²_3,0.9 V)⁻¹ ê ≤ 1 (bisection in c²; V = 0: c² = êᵀC⁻¹ê / 3F, the rule of
    :func:`~rbgp_cli.dynamics.paths._band_factors`); the factor is the ``level`` quantile of the needs, each
    weighted by its phase's share of the remainder's normalised time. ``scale`` (R,): each row's need divided by it
    first (its demonstration's :func:`surprise_scale`), so that the factors times a seen part's own widening hold."""
    from scipy.special import chdtri, fdtri, ndtri, stdtrit

    nu = max(int(demos) - 2, 1)
    e, V, C, w = terms["e"], terms["V"], terms["C"], terms["w"]
    t2 = stdtrit(nu, 0.5 + level / 2.0) ** 2
    z2 = ndtri(0.5 + level / 2.0) ** 2
    sig2 = np.maximum(np.einsum("rii->ri", C[:, 3:, 3:]), 1e-24)
    v = np.einsum("rii->ri", V[:, 3:, 3:])
    c_pos = np.sqrt(np.maximum(e[:, 3:] ** 2 - z2 * v, 0.0) / (t2 * sig2))  # (R, 3)
    f3, chi = 3.0 * fdtri(3, nu, level), chdtri(3, 1.0 - level)
    # with C = L Lᵀ and L⁻¹ V L⁻ᵀ = Q Λ Qᵀ the form is Σ_i a_i² / (c² 3F + χ² λ_i), a = Qᵀ L⁻¹ ê: decreasing in c²
    L = np.linalg.cholesky(C[:, :3, :3] + 1e-12 * np.eye(3))
    Li = np.linalg.inv(L)
    lam, Q = np.linalg.eigh(Li @ V[:, :3, :3] @ np.swapaxes(Li, 1, 2))
    a2 = np.einsum("rji,rj->ri", Q, np.einsum("rij,rj->ri", Li, e[:, :3])) ** 2
    lam = np.maximum(lam, 0.0)

    def form(c2):
        return np.sum(a2 / np.maximum(c2[:, None] * f3 + chi * lam, 1e-300), axis=1)

    hi = a2.sum(axis=1) / f3  # enough with V = 0 (then exactly êᵀC⁻¹ê / 3F)
    lo = np.zeros_like(hi)
    hi = np.where(form(lo) <= 1.0, 0.0, hi)
    for _ in range(60):  # bisection, every phase at once
        mid = 0.5 * (lo + hi)
        ok = form(mid) <= 1.0
        hi = np.where(ok, mid, hi)
        lo = np.where(ok, lo, mid)
    c_rot = np.sqrt(hi)
    if scale is not None:  # each row's need in units of its demonstration's surprise scale
        c_rot = c_rot / scale
        c_pos = c_pos / scale[:, None]
    return _weighted_quantile(c_rot, w, level), _weighted_quantile(c_pos.ravel(), np.repeat(w, 3), level)


def _weighted_quantile(x, w, level):
    """The smallest x_i with Σ_{x_k ≤ x_i} w_k ≥ level Σ w."""
    o = np.argsort(x)
    cw = np.cumsum(w[o])
    return float(x[o][min(int(np.searchsorted(cw, level * cw[-1])), len(x) - 1)])


# ----------------------------------------------------------------------------------------- streams
def initial_rests(paths, speed: float) -> np.ndarray:
    """How long each demonstration of ``paths`` rests before it moves (D,) s: demonstration d on the phase grid,
    p_d(s_j) = p̄(s_j) + δ_d,pos(s_j), moves at ‖p_d(s_(j+1)) − p_d(s_j)‖ / ((s_(j+1) − s_j) D_d) between grid phases;
    its rest is s_j D_d for the first s_j after which it is faster than ``speed`` (m/s), 0 if it never is (to the
    grid's step, 2 % of its duration on 51 phases)."""
    P = np.asarray(paths.position, dtype=np.float64)[None] + np.asarray(paths.deviations, dtype=np.float64)[:, :, 3:]
    D = np.exp(np.asarray(paths.log_durations, dtype=np.float64))
    v = np.linalg.norm(np.diff(P, axis=1), axis=2) / (np.diff(paths.s)[None] * D[:, None])
    fast = v > speed
    return np.where(fast.any(axis=1), paths.s[np.argmax(fast, axis=1)] * D, 0.0)


def rest_before_moving(t, position, speed: float, window: float = 0.05) -> float:
    """How long a seen part (t (N,) s increasing, position (N, 3) m) rests before it moves (s): it left rest at j(i)
    for the first sample i whose trailing window moved faster than ``speed`` (‖p_i − p_j‖ / (t_i − t_j) > speed, j the
    last sample with t_j ≤ t_i − ``window``, at least half a window seen: :class:`Follower`'s test), t_j(i) − t_0; a
    part still at rest, t_N − t_0."""
    t = np.asarray(t, dtype=np.float64)
    position = np.asarray(position, dtype=np.float64)
    j = np.maximum(np.searchsorted(t, t - window, side="right") - 1, 0)
    span = t - t[j]
    fast = (span >= 0.5 * window) & (np.linalg.norm(position - position[j], axis=1) > speed * np.where(span > 0, span, 1.0))
    return float((t[j[np.argmax(fast)]] if fast.any() else t[-1]) - t[0])


class Follower:
    """A motion under way, followed live (``rbgp follow``): :meth:`push` one pose at a time; it returns the
    current :class:`Anticipation` (or None while at rest before a motion starts).

    A motion starts when the pose leaves rest: its speed over the last ``window`` seconds exceeds
    ``start_speed`` (default a tenth of the demonstrations' mean speed along the mean path); it departed at the
    last sample before that window's speed rose. Its start (phase 0) is where the demonstrations' is: they begin at
    rest for a while before they move (the handovers 0.5 s on average, up to 2.3 s), so the rest seen before the
    departure, since the pose came to rest and at most ``lead`` seconds of it (default the longest the
    demonstrations begin with, :func:`initial_rests`), is the motion's beginning too. It ends when the estimated
    phase has reached 1 and the pose is at rest again; the next departure from rest starts the next motion. The
    seen buffer keeps at most ``keep`` poses (older ones are thinned, every other one, the first kept):
    the update's cost stays bounded however long the motion runs."""

    def __init__(self, paths, *, points: int = 6, grid_size: int = 16, window: float = 0.05,
                 start_speed: float | None = None, keep: int = 512, detect: bool = True, rest: float = 0.25,
                 lead: float | None = None):
        # the end at D̂: the live update affords one conditioning of the rest (method.md §13)
        self.anticipator = Anticipator(paths, None, points=points, grid_size=grid_size, mix_end=False)
        self.start_speed = float(self.anticipator.rest_speed if start_speed is None else start_speed)
        self.window = float(window)
        self.keep = int(keep)
        self.detect = bool(detect)
        self._t, self._q, self._p = [], [], []
        self._moving = not detect
        self._last = None
        #: the current (or last) motion's index: 0, 1, … across repetitions (−1 before the first)
        self.motion = -1 if detect else 0
        self._recent = []  # (t, quat, position) of the last window, for the speed
        self._quiet_since = None  # since when the pose has been at rest (after a motion)
        self._arrays = None  # the buffer as arrays (Follower._buffer)
        self._active = None  # the duration cells evaluated at the next update (Follower._estimate)
        self.rest = float(rest)
        #: at most this much of the rest before a departure (s) begins the motion (phase 0 where the demonstrations'
        #: is: their longest initial rest, initial_rests)
        if lead is None:
            lead = self.anticipator.lead if start_speed is None else np.max(initial_rests(paths, self.start_speed))
        self.lead = max(float(lead), 0.0)
        self._still = deque()  # (t, quat, position) at rest before a departure, the last `lead` seconds of it
        self._departure = None  # when the current (or last) motion left rest

    def _speed(self):
        (ta, _, pa), (tb, _, pb) = self._recent[0], self._recent[-1]
        return float(np.linalg.norm(pb - pa) / (tb - ta)) if tb > ta else 0.0

    def _seen_window(self) -> bool:
        """Whether at least half a ``window`` has been seen, so that its speed may say rest or motion."""
        r = self._recent
        return len(r) >= 2 and r[-1][0] - r[0][0] >= 0.5 * self.window

    @property
    def at_rest(self) -> bool:
        """Whether the pose is at rest now: its speed over the last ``window`` seconds (at least half of it seen)
        below ``start_speed``, the threshold a motion starts above. In mid-motion this is a hold, which the estimate
        does not foresee: its phase is the seen time over one duration, so it reads a hold as a slower motion, the
        prediction of one that resumes at once (docs/method.md §13)."""
        return self._seen_window() and self._speed() < self.start_speed

    def push(self, t: float, quat, position):
        """Add the pose seen at time ``t`` (quat (4,) x, y, z, w; position (3,) m); returns the
        :class:`Anticipation` of the motion under way, or None at rest."""
        t = float(t)
        q = np.asarray(quat, dtype=np.float64).reshape(4)
        p = np.asarray(position, dtype=np.float64).reshape(3)
        if not (np.isfinite(t) and np.all(np.isfinite(q)) and np.all(np.isfinite(p))):
            raise InputError(f"the pose at t = {t:g} has missing values", param="seen")
        if self._recent and t <= self._recent[-1][0]:
            raise InputError(f"the stream's times must increase ({t:g} after {self._recent[-1][0]:g})", param="seen")
        self._recent.append((t, q, p))
        while len(self._recent) > 2 and self._recent[1][0] <= t - self.window:
            self._recent.pop(0)
        if not self._moving:
            self._still.append((t, q, p))
            while self._still[0][0] < self._recent[0][0] - self.lead:  # a departure takes from its window's first on
                self._still.popleft()
            fast = self._seen_window() and self._speed() > self.start_speed
            if not fast and self._quiet_since is None:
                self._quiet_since = t
            armed = self.motion < 0 or (self._quiet_since is not None and t - self._quiet_since >= self.rest)
            if fast and not armed:
                self._quiet_since = None  # still settling after the last motion: not a new one yet
                self._still.clear()
            if fast and armed:
                self._moving = True  # it left rest within the window: it departed at the window's first pose
                self.motion += 1
                self._active = None
                # the motion begins with the rest before it, since the pose came to rest, at most `lead` seconds
                first = self._recent[0][0]
                since = first - self.lead if self._quiet_since is None else max(first - self.lead, self._quiet_since)
                rows = [x for x in self._still if since <= x[0] < first] + self._recent
                self._still.clear()
                self._departure = first
                self._t, self._q, self._p = [x[0] for x in rows], [x[1] for x in rows], [x[2] for x in rows]
                self._arrays = None
            else:
                return None
        else:
            self._t.append(t)
            self._q.append(q)
            self._p.append(p)
        n = len(self._t)
        if n > self.keep:  # thin the older half (the first kept)
            half = n // 2
            sel = list(range(0, half, 2)) + list(range(half, n))
            self._t = [self._t[i] for i in sel]
            self._q = [self._q[i] for i in sel]
            self._p = [self._p[i] for i in sel]
            self._arrays = None
        T, Q, Pp = self._buffer()
        est = self._estimate(T, Q, Pp)
        if self.detect and est.phase >= 0.8 and len(self._recent) >= 2 and self._speed() < self.start_speed:
            self._moving = False  # the motion is over: wait for rest, then the next departure from it
            self._recent = self._recent[-1:]
            self._quiet_since = t
        self._last = est
        return est

    def _estimate(self, T, Q, P):
        """The anticipator's estimate, with the duration grid restricted to the cells that carried weight at
        the last update (relative weight above :data:`ACTIVE_WEIGHT`) and their neighbours: the posterior
        moves by at most one cell per update at the stream's rate, and the cells left out hold a weight the
        summary cannot see. A new motion, or a cell at the active set's edge that gains the most weight,
        widens it again on the next update."""
        a = self.anticipator
        active = None if len(self._t) < ACTIVE_AFTER else self._active
        grid, w, terms = a.weights(T, Q, P, checked=True, active=active)
        full = np.zeros(len(a.grid), dtype=bool)
        if not terms["beyond"]:
            idx = np.searchsorted(a.grid, grid)
            heavy = np.zeros(len(a.grid), dtype=bool)
            bw = terms["band_w"]  # the wider of the two (the band's): its cells hold the quantiles
            heavy[idx[(w > ACTIVE_WEIGHT * w.max()) | (bw > ACTIVE_WEIGHT * bw.max())]] = True
            full = heavy.copy()
            full[1:] |= heavy[:-1]
            full[:-1] |= heavy[1:]
        self._active = full if full.any() else None
        return a._summary(grid, w, terms)

    def _buffer(self):
        """The seen poses as arrays (t (N,), quat (N, 4), position (N, 3)), kept in step with the lists:
        only the new rows are written (the quaternions unit and sign-continuous along the buffer)."""
        n = len(self._t)
        arr = self._arrays
        if arr is None or arr[3] > n or len(arr[0]) < n:
            cap = max(2 * n, 64)
            arr = (np.empty(cap), np.empty((cap, 4)), np.empty((cap, 3)), 0)
        T, Q, P, m = arr
        for i in range(m, n):
            q = self._q[i] / np.linalg.norm(self._q[i])
            if i > 0 and np.dot(q, Q[i - 1]) < 0:
                q = -q
            T[i], Q[i], P[i] = self._t[i], q, self._p[i]
        self._arrays = (T, Q, P, n)
        return T[:n], Q[:n], P[:n]

    @property
    def start(self) -> float | None:
        """The current (or last) motion's start time (None before the first): when it left rest (with ``detect``
        False, the stream's first pose)."""
        if self._departure is not None:
            return self._departure
        return self._t[0] if self._t else None

    @property
    def rest_before(self) -> float:
        """How much of the rest before the current (or last) motion's start begins it (s): its phase 0 is that much
        before :attr:`start` (at most ``lead``; 0 without a motion or with ``detect`` False)."""
        if self._departure is None or not self._t:
            return 0.0
        return float(self._departure - self._t[0])
