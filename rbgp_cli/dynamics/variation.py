"""How demonstrations differ from one another, as a coherent random process over phase (docs/method.md §11 (a)).

A GP per velocity output learns the shared motion; what it cannot give is a *new* demonstration: its
likelihood turns the demonstrations' smooth, coherent deviations from each other into white noise σn,
and per-step Monte Carlo draws of that noise integrate to random walks. Here the deviations are
modelled directly. On a phase grid s_j = j/(S−1) (s = (t − t_0)/D), each training demonstration d gives
its deviation from the demonstrations' mean path (:func:`rbgp_cli.dynamics.model.mean_path`) in the mean
path's world-frame tangent space, rotation first (docs/method.md §1),

    δ_d(s) = (log(R_d(s) R̄(s)ᵀ), p_d(s) − p̄(s))  ∈ ℝ⁶.

A sampled rollout starts where it is told to, so its deviation must be drawn *given* the start. With
c_d = δ_d − mean_d δ_d, the part of each coordinate j that the start explains is removed by a least-
squares regression on the start, per coordinate and phase,

    r_dj(s) = c_dj(s) − β_j(s) c_dj(0),   β_j(s) = Σ_d c_dj(s) c_dj(0) / Σ_d c_dj(0)²,

so r_d(0) = 0. The residual functions r_d (D, S, 6) are the model of the variation: a draw is
η(s) = u · √((1 + 1/D) / ν) Σ_d z_d r_d(s), z ~ N(0, I_D), u = √(ν / χ²_ν), ν = D − 2 degrees of freedom
(centring and the regression): a function with the residuals' sample covariance over the whole phase
range (every phase pair, every coordinate pair: coherent), inflated by (1 + 1/D) for the estimated
mean and made Student-t by u for the estimated covariance — the predictive of a new demonstration.
(Without u, 20 draws' 90 % rotation regions held 0.85 of fresh demonstrations when 40 demonstrations
estimated the covariance, 0.90 when 400 did; with it 0.90 either way: tests/dynamics/test_variation.py.) A sampled
rollout is the mean rollout from the same start displaced by a draw: R_k(s) = exp(η_rot(s)) R(s),
p_k(s) = p(s) + η_pos(s) — one smooth alternative way of doing the task, zero at the start.

The bands' scale (:func:`band_scale`). A Gaussian draw with the residuals' covariance holds a new
demonstration as often as promised only if the demonstrations' deviations are Gaussian. Real ones are
not: on the handovers a few demonstrations turn the object another way for much of the motion, so the
held-out rotations lay inside the samples' 90 % region 0.83 of the time, with the median Mahalanobis
distance where a Gaussian puts it and the tail far beyond. So each demonstration d is left out in turn
and predicted from the others as a rollout predicts it (the start map with the model's ridge, and the
prior's pull closing the gap at the start as exp(−a·s)); its error e_d(s) is measured against the
draws' covariance C_−d(s) without it. The factors are the ones that make the nominal regions hold at
the level over all (d, s), s > 0:

    c_rot² = q_0.90(e_rotᵀ C_rot⁻¹ e_rot) / χ²_3(0.90),    c_pos = q_0.90(|e_pos,j| / √C_jj) / z_0.95,

and a draw's rotation is multiplied by c_rot, its position by c_pos. Both are at least 1 (the quantiles
of a few demonstrations are uncertain; the Student-t already widens the draws for that, and a band is
not narrowed below it) and 1 with fewer than MIN_BAND_DEMOS demonstrations. Measured on the real sets
(docs/defaults.md): handovers c_rot 1.19–1.26, slower handovers 1.12–1.22, hand raises 1.02–1.06,
c_pos 0.93–1.09 (so 1 mostly).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rbgp_cli.dynamics.trajectory import Trajectory

__all__ = ["Variation", "demonstration_variation", "demonstration_deviations", "start_regression", "start_map",
           "band_scale", "pull_profile", "STEPS", "MIN_DEMOS", "MIN_BAND_DEMOS", "RIDGE_GRID", "BAND_LEVEL",
           "PULL_CAP", "PULL_WINDOW"]

#: Phase grid of the deviations (as the mean path's).
STEPS = 51
#: Fewer demonstrations than this give no variation model (ν = D − 2 must be positive).
MIN_DEMOS = 3
#: Fewer demonstrations than this keep the bands' scale at 1 (:func:`band_scale`): leaving one out
#: must leave at least four residual functions, so that the rotation covariance has rank 3.
MIN_BAND_DEMOS = 6
#: The level at which :func:`band_scale` makes the bands hold (the level crossval's coverage checks).
BAND_LEVEL = 0.90
#: The largest pull gain per unit phase :func:`pull_profile` gives (the demonstrations' spread shrinking
#: e-fold in a twentieth of the motion); a rollout's step caps it further at 1/h (no overshoot).
PULL_CAP = 20.0
#: The phase window over which :func:`pull_profile` measures how fast the spread shrinks.
PULL_WINDOW = 0.1


@dataclass
class Variation:
    """The demonstrations' deviation process (module docstring).

    s : (S,) phase grid in [0, 1]; residuals : (D, S, 6) the start-conditioned deviations r_d (rad, m),
    rotation first; dof : ν = D − 2; band_scale : (c_rot, c_pos) ≥ 1, the factors on a draw's rotation
    and position (:func:`band_scale`; (1, 1) for model files written before them).
    """

    s: np.ndarray
    residuals: np.ndarray
    dof: int
    band_scale: tuple = (1.0, 1.0)

    @property
    def demos(self) -> int:
        return int(self.residuals.shape[0])

    def draw(self, count: int, rng: np.random.Generator) -> np.ndarray:
        """``count`` deviation functions on the grid, shape (count, S, 6): η = √((1 + 1/D)/ν) u Σ_d z_d r_d,
        its rotation part times c_rot and its position part times c_pos (:attr:`band_scale`)."""
        D = self.demos
        z = rng.standard_normal((int(count), D))
        # each draw's scale: √(ν / χ²_ν), so that a coordinate is Student-t with ν degrees of freedom, the
        # predictive of a new demonstration when the covariance itself is estimated from D of them
        chi = np.sqrt(self.dof / rng.chisquare(self.dof, int(count)))
        scale = np.sqrt((1.0 + 1.0 / D) / self.dof) * chi
        c_rot, c_pos = (float(c) for c in self.band_scale)
        coords = np.array([c_rot] * 3 + [c_pos] * 3)
        return scale[:, None, None] * np.einsum("kd,dsj->ksj", z, self.residuals * coords)

    def at(self, eta: np.ndarray, phase: np.ndarray) -> np.ndarray:
        """Draws ``eta`` (..., S, 6) at phases ``phase`` (..., T) (clipped to [0, 1]) by linear
        interpolation on the grid; shape (..., T, 6)."""
        s = self.s
        x = np.clip(np.asarray(phase, dtype=np.float64), 0.0, 1.0)
        k = np.clip(np.searchsorted(s, x, side="right") - 1, 0, len(s) - 2)
        f = ((x - s[k]) / (s[k + 1] - s[k]))[..., None]
        lo = np.take_along_axis(eta, k[..., None], axis=-2)
        hi = np.take_along_axis(eta, (k + 1)[..., None], axis=-2)
        return (1.0 - f) * lo + f * hi

    def to_arrays(self) -> dict:
        return {"variation_s": np.ascontiguousarray(self.s, dtype=np.float64),
                "variation_residuals": np.ascontiguousarray(self.residuals, dtype=np.float64)}

    @classmethod
    def from_arrays(cls, arrays: dict, band_scale=None) -> "Variation":
        """From :meth:`to_arrays`' arrays and the header's ``band_scale`` ({"rotation", "position"}, or
        None for (1, 1))."""
        r = np.asarray(arrays["variation_residuals"], dtype=np.float64)
        scale = (1.0, 1.0) if not band_scale else (float(band_scale["rotation"]), float(band_scale["position"]))
        return cls(np.asarray(arrays["variation_s"], dtype=np.float64), r, int(r.shape[0]) - 2, scale)


def demonstration_deviations(trajs: list[Trajectory], steps: int = STEPS) -> tuple[dict, np.ndarray]:
    """The demonstrations' mean path (:func:`rbgp_cli.dynamics.model.mean_path` on ``steps`` phases)
    and each one's deviation from it, δ_d(s) = (log(R_d(s) R̄(s)ᵀ), p_d(s) − p̄(s)), shape (D, S, 6)."""
    from rbgp_cli.dynamics.model import mean_path
    from rbgp_cli.dynamics.trajectory import interpolate_poses
    from rbgp_cli.geometry.so3 import log_quat, quat_conjugate, quat_make_continuous, quat_multiply

    path = mean_path(trajs, steps)
    s = path["s"]
    Q, P = [], []
    for tr in trajs:  # a loop over demonstrations (as mean_path's), each resampled in one call
        q, p = interpolate_poses((tr.t - tr.t[0]) / max(tr.duration, 1e-12), quat_make_continuous(tr.quat), tr.position, s)
        Q.append(q)
        P.append(p)
    Q, P = np.array(Q), np.array(P)  # (D, S, 4), (D, S, 3)
    rot = log_quat(quat_multiply(Q, quat_conjugate(path["quat"])[None]))  # world frame: R_d R̄ᵀ
    return path, np.concatenate([rot, P - path["position"][None]], axis=-1)


def start_regression(delta: np.ndarray):
    """Per coordinate and phase, the least-squares regression of the deviations δ (D, S, 6) on their
    value at the start (module docstring): returns the mean deviation μ (S, 6), the slope β (S, 6)
    (β(0) = 1 wherever the start varies) and the residuals r (D, S, 6), r(0) = 0.

    E[δ(s) | δ(0)] = μ(s) + β(s) (δ(0) − μ(0)) is the deviation a new demonstration that starts at δ(0)
    is expected to keep (:func:`rbgp_cli.dynamics.model.prior_mean_outputs` pulls toward it)."""
    mu = delta.mean(axis=0)
    c = delta - mu
    c0 = c[:, :1, :]  # (D, 1, 6)
    denom = np.sum(c0**2, axis=0)  # (1, 6)
    varies = denom > 1e-300
    beta = np.where(varies, np.sum(c * c0, axis=0) / np.where(varies, denom, 1.0), 0.0)  # (S, 6)
    beta[0] = np.where(varies[0], 1.0, 0.0)
    r = c - beta[None] * c0
    r[:, 0, :] = 0.0  # exactly (β(0) = 1 wherever the start varies)
    return mu, beta, r


#: Ridge strengths λ tried by :func:`start_map` (on coordinates scaled to unit RMS deviation); ∞ is
#: no conditioning (the mean path, plus the demonstrations' mean deviation).
RIDGE_GRID = (0.001, 0.003, 0.01, 0.03, 0.1, 0.3, 1.0, 3.0, 10.0, float("inf"))
#: Folds of whole demonstrations that choose λ (fewer with fewer demonstrations).
RIDGE_FOLDS = 10


def _coordinate_scale(delta: np.ndarray) -> np.ndarray:
    """Each coordinate's RMS deviation (6,) (1 where it does not vary): the units of the ridge map."""
    scale = np.sqrt(np.mean(delta**2, axis=(0, 1)))
    return np.where(scale > 1e-12, scale, 1.0)


def _ridge_map(delta: np.ndarray, scale: np.ndarray, lam: float):
    """μ (S, 6) and the ridge regression B (S, 6, 6) of the deviations δ (D, S, 6) at every phase on
    their start value, in coordinates scaled by ``scale`` (6,) (see :func:`start_map`)."""
    mu = delta.mean(axis=0)
    S = delta.shape[1]
    if not np.isfinite(lam):
        return mu, np.zeros((S, 6, 6))
    c = (delta - mu) / scale  # (D, S, 6)
    c0 = c[:, 0, :]
    D = len(delta)
    C00 = c0.T @ c0 / D + lam * np.eye(6)
    Cs0 = np.einsum("dsi,dj->sij", c, c0) / D  # (S, 6, 6)
    B = np.linalg.solve(C00.T, Cs0.transpose(0, 2, 1)).transpose(0, 2, 1)  # Cs0 C00⁻¹ (C00 symmetric)
    # back to rad, m; C order, as a model file gives it back (einsum's sums then match bit for bit)
    return mu, np.ascontiguousarray(B * scale[None, :, None] / scale[None, None, :])


def start_map(delta: np.ndarray, *, grid=RIDGE_GRID, folds: int = RIDGE_FOLDS, seed: int = 0) -> dict:
    """How a new demonstration's deviation from the mean path depends on its start (docs/method.md §11).

    For deviations δ (D, S, 6) (:func:`demonstration_deviations`), the conditional mean of a new one
    given its start value δ(0) is, for jointly Gaussian deviations with ridge-regularised covariance,

        E[δ(s) | δ(0)] = μ(s) + B(s) (δ(0) − μ(0)),   B(s) = C_s0 (C_00 + λ I)⁻¹,

    with μ the mean deviation, C_s0 = mean_d c_d(s) c_d(0)ᵀ and c_d = (δ_d − μ) / σ per coordinate
    (σ the coordinates' RMS deviation, so one λ suits radians and metres; B is returned in physical
    units). Every coordinate of the start informs every coordinate of the motion, as a ProMP's
    conditioning does (there the regulariser is the weight prior). λ is chosen from ``grid`` by
    cross-validation over ``folds`` folds of whole demonstrations (squared error of the scaled held-out
    deviations over all phases after the start); λ = ∞ (no conditioning) competes, so a start that tells nothing about
    the rest of the motion leaves the mean path. Returns ``{"mean": μ (S, 6), "map": B (S, 6, 6),
    "ridge": λ, "errors": per λ the held-out mean squared error}``; with fewer than MIN_DEMOS + 1
    demonstrations λ = ∞.
    """
    delta = np.asarray(delta, dtype=np.float64)
    D = len(delta)
    scale = _coordinate_scale(delta)
    grid = tuple(float(g) for g in grid)
    errors = np.zeros(len(grid))
    if D > MIN_DEMOS:
        k = min(int(folds), D)
        fold = np.empty(D, dtype=int)
        fold[np.random.default_rng(np.random.SeedSequence([int(seed), 17])).permutation(D)] = np.arange(D) % k
        for j in range(k):
            held, rest = delta[fold == j], delta[fold != j]
            for i, lam in enumerate(grid):
                mu, B = _ridge_map(rest, scale, lam)
                pred = mu[None] + np.einsum("sij,dj->dsi", B, held[:, 0, :] - mu[0])
                # phase 0 is the start itself, known to the rollout: not a test of the map
                errors[i] += float(np.sum(((pred[:, 1:] - held[:, 1:]) / scale) ** 2))
        errors /= delta[:, 1:].size
        best = int(np.argmin(errors))
    else:
        best = grid.index(float("inf")) if float("inf") in grid else len(grid) - 1
    lam = grid[best]
    mu, B = _ridge_map(delta, scale, lam)
    return {"mean": mu, "map": B, "ridge": lam, "errors": errors.tolist()}


def pull_profile(delta: np.ndarray, start_mean: np.ndarray, start_map_: np.ndarray, s: np.ndarray, floor: float, *,
                 window: float = PULL_WINDOW, cap: float = PULL_CAP) -> np.ndarray:
    """The prior's pull gain per phase and coordinate that follows the demonstrations' convergence
    (docs/method.md §7, "The pull's profile").

    With the start-conditioned paths Δ_d(s) = μ(s) + B(s) c_d(0) (:func:`start_map`; c_d = δ_d − μ),
    the demonstrations' spread about their own paths is σ_j(s) = √(mean_d r_dj(s)²), r_d = c_d − B c_d(0).
    A deviation that a pull of gain a_j closes obeys e' = −a_j e; one that shrinks as the demonstrations
    do follows e ∝ σ_j, so

        a_j(s) = clip(−(ln σ_j(s + w/2) − ln σ_j(s − w/2)) / w,  floor, cap),

    over a window of w = ``window`` in phase (the grid's intervals nearest to it; one-sided at the ends).
    Where people spread out or keep their spread the gain is the constant ``floor`` (``--prior-gain``);
    where they converge on a common pose (the end of a reach, a hand-over point) it rises, so that a
    rollout converges as they do instead of keeping the deviation it picked up on the way.

    delta (D, S, 6), start_mean μ (S, 6), start_map_ B (S, 6, 6), s (S,) → (S, 6), rotation first.
    """
    delta = np.asarray(delta, dtype=np.float64)
    s = np.asarray(s, dtype=np.float64)
    S = len(s)
    c = delta - np.asarray(start_mean, dtype=np.float64)[None]
    r = c - np.einsum("sij,dj->dsi", np.asarray(start_map_, dtype=np.float64), c[:, 0])
    log_sigma = np.log(np.sqrt(np.mean(r ** 2, axis=0)) + 1e-12)  # (S, 6)
    w = max(1, min(S - 1, int(round(window / float(np.median(np.diff(s)))))))
    hi = np.clip(np.arange(S) - w // 2 + w, w, S - 1)
    lo = hi - w
    rate = -(log_sigma[hi] - log_sigma[lo]) / (s[hi] - s[lo])[:, None]
    return np.clip(rate, float(floor), max(float(cap), float(floor)))


def band_scale(delta: np.ndarray, residuals: np.ndarray, s: np.ndarray, *, ridge: float = float("inf"),
               gain: float = 0.0, level: float = BAND_LEVEL) -> tuple[float, float]:
    """The factors (c_rot, c_pos) ≥ 1 on the draws' rotation and position that make their ``level``
    regions hold the demonstrations, each left out in turn (module docstring, "The bands' scale").

    delta : (D, S, 6) the deviations (:func:`demonstration_deviations`); residuals : (D, S, 6) their
    start-regression residuals r_d (:func:`start_regression`), whose draws are scaled; s : (S,) the grid.
    ridge : λ of the start map the mean rollout follows (:func:`start_map`; ∞: the mean deviation,
    no conditioning); gain : the prior's pull a per unit phase, which closes a start's gap to that
    map's prediction as exp(−a·s) (0: the gap stays). The left-out demonstration's error is
    e_d(s) = δ_d(s) − m_−d(s) − exp(−a·s) (δ_d(0) − m_−d(0)), m_−d the map fitted without it; the
    draws' covariance without it is C_−d(s) = (1 + 1/D)/(ν − 2) · D/(D − 1) · Σ_{d'≠d} r_d' r_d'ᵀ
    (the draws' own, Student-t included). Returns (1, 1) for fewer than MIN_BAND_DEMOS demonstrations.
    """
    # scipy.special, not scipy.stats: the quantiles alone, without stats' import (1.6 s here, measured)
    from scipy.special import chdtri, ndtri

    delta = np.asarray(delta, dtype=np.float64)
    r = np.asarray(residuals, dtype=np.float64)
    D = len(delta)
    if D < MIN_BAND_DEMOS:
        return 1.0, 1.0
    nu = D - 2
    scale = _coordinate_scale(delta)
    decay = np.exp(-float(gain) * np.asarray(s, dtype=np.float64))[1:, None]
    outer = np.einsum("dsi,dsj->dsij", r[:, 1:], r[:, 1:])  # (D, S−1, 6, 6), phase 0 left out (r = 0 there)
    total = outer.sum(axis=0)
    factor = (1.0 + 1.0 / D) / (nu - 2) * D / (D - 1)  # ν − 2 ≥ 2: D ≥ MIN_BAND_DEMOS
    m2, z = [], []
    for d in range(D):  # a loop over demonstrations, each a batch of 6 × 6 solves over phase
        mu, B = _ridge_map(np.delete(delta, d, axis=0), scale, ridge)
        e = delta[d] - mu - np.einsum("sij,j->si", B, delta[d, 0] - mu[0])
        e = e[1:] - decay * e[0]
        C = factor * (total - outer[d])
        Cr = C[:, :3, :3]
        tr = np.trace(Cr, axis1=1, axis2=2)[:, None, None] / 3.0
        Cr = Cr + (1e-9 * tr + 1e-24) * np.eye(3)
        m2.append(np.einsum("si,si->s", e[:, :3], np.linalg.solve(Cr, e[:, :3, None])[..., 0]))
        sd = np.sqrt(np.maximum(np.einsum("sii->si", C[:, 3:, 3:]), 1e-24))
        z.append(np.abs(e[:, 3:]) / sd)
    m2, z = np.concatenate(m2), np.concatenate(z).ravel()
    c_rot = np.sqrt(np.quantile(m2, level) / chdtri(3, 1.0 - level))  # χ²_3's level quantile
    c_pos = np.quantile(z, level) / ndtri(0.5 + level / 2.0)
    return max(1.0, float(c_rot)), max(1.0, float(c_pos))


def demonstration_variation(trajs: list[Trajectory], steps: int = STEPS, *, ridge: float = float("inf"),
                            gain: float = 0.0) -> Variation | None:
    """The deviation process of clean demonstrations (module docstring), or None for fewer than
    MIN_DEMOS of them; ``ridge`` and ``gain`` describe the mean rollout for the bands' scale
    (:func:`band_scale`)."""
    trajs = list(trajs)
    D = len(trajs)
    if D < MIN_DEMOS:
        return None
    path, delta = demonstration_deviations(trajs, steps)
    _, _, r = start_regression(delta)
    s = np.asarray(path["s"], dtype=np.float64)
    return Variation(s=s, residuals=r, dof=D - 2, band_scale=band_scale(delta, r, s, ridge=ridge, gain=gain))
