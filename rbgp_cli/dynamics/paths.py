"""The demonstrations as a distribution over paths and durations, and its conditioning on what is
known of a new motion: its start, a goal, via-points, the part already seen (MATH.md §12,
docs/method.md §12).

**The distribution.** On the phase grid s_j = j/(S−1) of the mean path (R̄(s), p̄(s)),
(:func:`rbgp_cli.dynamics.variation.demonstration_deviations`), demonstration d is its deviation
δ_d(s) = (log(R_d(s) R̄(s)ᵀ), p_d(s) − p̄(s)) ∈ ℝ⁶ (world-frame tangent, rotation first) and its log
duration ℓ_d = ln D_d. Scaled per coordinate by its RMS deviation σ_j (and ℓ by its standard
deviation), demonstration d is one vector x_d ∈ ℝ^P, P = 6S + 1 (phase-major, then coordinate, then ℓ).
A new motion is x ~ N(m, Σ) with

    m = mean_d x_d,    Σ = (1 + 1/D) CᵀC / (D − 1) + τ² (K_ℓ ⊗ I_6 ⊕ 1),    K_ℓ(s, s') = exp(−(s − s')² / 2ℓ²),

C (D, P) the centred demonstrations. The first term is the demonstrations' sample covariance
(inflated for the estimated mean), of rank D − 1 at most: alone it says a new motion is a weighted sum
of the demonstrations, and conditioned on many points it over-fits (the plain ProMP's failure, MATH.md
§12). The second is a smooth process of variance τ² per coordinate (in units of that coordinate's
spread) that shrinks Σ toward a full-rank structured covariance: what D demonstrations cannot span
(τ², ℓ chosen by leaving demonstrations out, :func:`fit_paths`).

**Conditioning.** What is known is a set of linear observations of x: a pose T_j at phase s_j gives
y_j = (log(R_j R̄(s_j)ᵀ), p_j − p̄(s_j)) / σ = A_j x + ε_j (A_j interpolates the grid linearly),
ε_j ~ N(0, diag(r_j²)) with r_j the observation's tolerance (a goal: 0.5 mm / 1 mrad; a seen pose:
its tracker noise plus a regularising tolerance chosen by leaving demonstrations out); a known duration
observes ℓ. With A, y, R stacked,

    G = A Σ Aᵀ + R,   x̂ = m + Σ Aᵀ G⁻¹ (y − A m),   Σ̂ = Σ − Σ Aᵀ G⁻¹ A Σ,

(:meth:`PathDistribution.condition`), the mean and covariance of the motions that agree with what is
known. Σ̂ does not depend on y: the constraints' phases fix it, so one factorisation serves a batch.

**Pathwise update** (Matheron's rule, Wilson et al. 2020). A path f drawn from N(m, Σ) becomes a draw of
the conditioned distribution as f + Σ Aᵀ G⁻¹ (y − A f − ε), ε ~ N(0, R). rbgp applies it to a rollout of
the GP dynamics (:meth:`PathDistribution.update`): the rollout from the start is the model's answer to
"how do people move from here", the update bends it, exactly as the path distribution says a motion
between those constraints differs from one without them, so that it passes every constrained pose.

**A motion under way.** The seen samples (t_j, T_j) of a motion that started at t_0 lie at phases
s_j = (t_j − t_0)/D for its unknown duration D. For each D on a grid the joint density of the seen
deviations and ℓ = ln D under N(m, Σ) (with the seen tolerance) is the likelihood of D
(:meth:`PathDistribution.duration_posterior`, after Maeda et al. 2017's phase estimation); the
posterior over the grid weighs the continuations.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["PathDistribution", "Conditioned", "fit_paths", "SMOOTH_GRID", "LENGTH_GRID", "GOAL_TOLERANCE",
           "pose_deviation", "MIN_PATH_DEMOS", "STRENGTH_GRID"]

#: Fewer demonstrations than this give no path distribution (a covariance needs two, its Student-t three).
MIN_PATH_DEMOS = 3
#: τ² tried by :func:`fit_paths` (variance of the smooth shrinkage process, in units of each coordinate's
#: spread squared).
SMOOTH_GRID = (1e-3, 3e-3, 0.01, 0.03, 0.1, 0.3, 1.0)
#: ℓ tried by :func:`fit_paths` (length-scale of the smooth process, in phase).
LENGTH_GRID = (0.05, 0.1, 0.2, 0.4)
#: A goal or via-point's default tolerance: (rotation rad, position m), one standard deviation.
GOAL_TOLERANCE = (1e-3, 5e-4)
#: The largest tolerance a caller may give (rad, m, one std): far softer than no goal at all, and small
#: enough that its variance stays a finite double.
MAX_GOAL_TOLERANCE = 1e100
#: :meth:`PathDistribution.goal_band_scale` narrows the bands as far as the left-out paths say from this
#: many demonstrations on (below, in proportion D / NARROW_FROM on the log scale: a 90 % quantile of fewer
#: left-out paths is less certain), and at most to this factor.
NARROW_FROM = 10
NARROWEST = 0.5
#: A goal further than this many of the demonstrations' spreads from where they end (given the start) is beyond
#: what they support: it is warned about (rbgp_cli.workflows.warn_far_goals), and its default duration is not
#: extrapolated (rollout._goal_durations). The distance is a χ with 6 degrees of freedom, which exceeds 4.5 with
#: probability 0.0025; held out of 5 folds, 2 of the 30 handovers' own goals and 2 of the 40 slower handovers' lie
#: beyond it, none of the 40 hand raises' (docs/method.md §12).
FAR_GOAL = 4.5
#: The scales κ (on the sample covariance) and λ (on the smooth shrinkage) that
#: :meth:`PathDistribution.goal_strength` weighs for what is known of one motion (issue 38, fourth pass).
STRENGTH_GRID = (1.0, 2.0, 4.0, 8.0, 16.0, 32.0, 64.0, 128.0)
#: Every ``SELECT_EVERY``-th grid phase scores a left-out demonstration in :func:`fit_paths`.
SELECT_EVERY = 5


def pose_deviation(mean_quat, mean_position, quat, position) -> np.ndarray:
    """δ = (log(R R̄ᵀ), p − p̄) (..., 6), rotation first, of poses (quat (..., 4) x, y, z, w; position
    (..., 3)) from reference poses of the same shape (or broadcastable)."""
    from rbgp_cli.geometry.so3 import log_quat, quat_conjugate, quat_multiply

    rot = log_quat(quat_multiply(np.asarray(quat, dtype=np.float64), quat_conjugate(np.asarray(mean_quat, dtype=np.float64))))
    return np.concatenate([rot, np.asarray(position, dtype=np.float64) - np.asarray(mean_position, dtype=np.float64)], axis=-1)


def _interpolation(s_grid: np.ndarray, phases: np.ndarray) -> np.ndarray:
    """(n, S) weights that interpolate a function on the grid ``s_grid`` linearly at ``phases`` (n,)
    (clipped to the grid)."""
    x = np.clip(np.asarray(phases, dtype=np.float64).reshape(-1), s_grid[0], s_grid[-1])
    S = len(s_grid)
    k = np.clip(np.searchsorted(s_grid, x, side="right") - 1, 0, S - 2)
    f = (x - s_grid[k]) / (s_grid[k + 1] - s_grid[k])
    W = np.zeros((len(x), S))
    rows = np.arange(len(x))
    W[rows, k] = 1.0 - f
    W[rows, k + 1] += f
    return W


@dataclass
class Conditioned:
    """The path distribution given what is known (module docstring): mean x̂ (P,) and covariance Σ̂
    (P, P) in scaled units, with the distribution that made them (``paths``)."""

    paths: "PathDistribution"
    mean: np.ndarray
    cov: np.ndarray

    @property
    def deviation(self) -> np.ndarray:
        """The conditioned mean deviation (S, 6), rad and m."""
        return self.paths.unscale(self.mean)[0]

    @property
    def duration(self) -> float:
        """The conditioned median duration, seconds: exp of ℓ's conditioned mean."""
        return float(np.exp(self.paths.unscale(self.mean)[1]))

    def duration_spread(self) -> float:
        """ℓ's conditioned standard deviation (a factor exp(±1·this) on the duration)."""
        return float(np.sqrt(max(self.cov[-1, -1], 0.0)) * self.paths.duration_scale)

    def draw(self, count: int, rng: np.random.Generator, *, widen: bool = True,
             scale: tuple | None = None, student: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """``count`` draws (deviations (count, S, 6) rad, m; durations (count,) s) of the conditioned
        distribution, Student-t with ν = D − 2 degrees of freedom (the covariance is estimated from D
        demonstrations: each draw's deviation from the mean scaled by √(ν/χ²_ν)) and, with ``widen``,
        the bands' factors (c_rot, c_pos) on its rotation and position parts: ``scale`` if given (e.g.
        :meth:`PathDistribution.goal_band_scale`), else the distribution's ``band_scale``. With
        ``student=False`` and ``widen=False``: typical motions, the Gaussian N(x̂, Σ̂) (sampled rollouts;
        their band is :meth:`region`)."""
        P = len(self.mean)
        w, V = np.linalg.eigh(0.5 * (self.cov + self.cov.T))
        root = V * np.sqrt(np.clip(w, 0.0, None))[None, :]
        z = rng.standard_normal((int(count), P)) @ root.T  # (count, P)
        nu = max(self.paths.demos - 2, 1)
        if student:
            z *= np.sqrt(nu / rng.chisquare(nu, int(count)))[:, None]
        if widen:
            c_rot, c_pos = self.paths.band_scale if scale is None else scale
            coords = np.tile(np.array([c_rot] * 3 + [c_pos] * 3), self.paths.S)
            z[:, :-1] *= coords
        dev, ell = self.paths.unscale(self.mean[None] + z)
        return dev, np.exp(ell)

    def region(self, phases: np.ndarray, level: float = 0.90, scale: tuple | None = None):
        """The band at ``phases`` (n,): the ``level`` region of :meth:`draw`'s Student-t (ν = D − 2) with
        the factors ``scale`` (default the distribution's ``band_scale``) (issue 36/38): position
        half-widths (n, 3) m, c_pos t_ν √Σ_jj, and the rotation region's matrix M (n, 3, 3) rad²,
        {e : eᵀ M⁻¹ e ≤ 1}, M = c_rot² 3 F_level(3, ν) Σ_rot; Σ the conditioned covariance of the
        deviation at each phase, interpolated as a draw is ((1 − f) x_k + f x_(k+1): its exact covariance)."""
        from rbgp_cli.dynamics.variation import band_quantiles

        S, sc = self.paths.S, self.paths.scale
        cov = self.cov[:-1, :-1].reshape(S, 6, S, 6)
        x = np.clip(np.asarray(phases, dtype=np.float64).reshape(-1), 0.0, 1.0)
        k = np.clip(np.searchsorted(self.paths.s, x, side="right") - 1, 0, S - 2)
        f = ((x - self.paths.s[k]) / (self.paths.s[k + 1] - self.paths.s[k]))[:, None, None]
        cross = cov[k, :, k + 1, :]
        C = (1.0 - f) ** 2 * cov[k, :, k, :] + f ** 2 * cov[k + 1, :, k + 1, :] + f * (1.0 - f) * (cross + cross.transpose(0, 2, 1))
        C = C * sc[None, :, None] * sc[None, None, :]  # rad, m
        q_rot, q_pos = band_quantiles(max(self.paths.demos - 2, 1), level)
        c_rot, c_pos = self.paths.band_scale if scale is None else scale
        half = c_pos * q_pos * np.sqrt(np.maximum(np.einsum("nii->ni", C[:, 3:, 3:]), 0.0))
        return half, (c_rot ** 2 * q_rot) * C[:, :3, :3]

    def marginal_std(self) -> np.ndarray:
        """The conditioned standard deviation per phase and coordinate (S, 6), rad and m."""
        sd = np.sqrt(np.clip(np.diag(self.cov)[:-1], 0.0, None)).reshape(self.paths.S, 6)
        return sd * self.paths.scale[None]


@dataclass
class PathDistribution:
    """The demonstrations as a Gaussian over scaled deviation paths and log durations (module docstring).

    s (S,) phase grid; quat (S, 4), position (S, 3) the mean path; deviations (D, S, 6) δ_d, rad and m;
    log_durations (D,) ln D_d; smooth τ², length ℓ (phase) of the shrinkage process; seen_tolerance:
    the regularising tolerance of a seen pose, in units of the coordinates' spread; band_scale
    (c_rot, c_pos) ≥ 1 on draws (:meth:`Conditioned.draw`).
    """

    s: np.ndarray
    quat: np.ndarray
    position: np.ndarray
    deviations: np.ndarray
    log_durations: np.ndarray
    smooth: float = 0.03
    length: float = 0.1
    seen_tolerance: float = 0.1
    band_scale: tuple = (1.0, 1.0)
    info: dict = field(default_factory=dict)
    #: (c_rot, c_pos) ≥ 1 on the draws of a motion under way (:func:`rbgp_cli.dynamics.anticipation.fit_seen`)
    seen_band_scale: tuple = (1.0, 1.0)
    #: τ² and r of a motion under way's duration weights (:func:`rbgp_cli.dynamics.anticipation.fit_seen`; None:
    #: ``smooth`` and ``seen_tolerance``)
    duration_smooth: float | None = None
    duration_tolerance: float | None = None
    #: the duration weights' seen tolerance in rad and m for every coordinate, in place of ``duration_tolerance``
    #: (fewer than ten demonstrations: :data:`rbgp_cli.dynamics.anticipation.DURATION_FEW_SIGMA`; None: r)
    duration_sigma: float | None = None
    #: the weight λ ∈ (0, 1] of the seen poses' evidence in the duration's band and samples, w_g ∝ p(ℓ_g)
    #: p(y | ℓ_g)^λ (:func:`rbgp_cli.dynamics.anticipation.fit_seen`: the largest λ whose band holds enough left-out
    #: durations for 90 % on the next one, :func:`~rbgp_cli.dynamics.anticipation.finite_sample_count`; None: 1)
    duration_evidence: float | None = None
    #: the duration's point estimate D̂: "mode" (the weights' refined mode in ln D) or None for their median
    #: (:func:`rbgp_cli.dynamics.anticipation.fit_seen`, chosen on the left-out beginnings)
    duration_statistic: str | None = None
    #: τ² and r of a motion under way's conditioning of the rest (:func:`rbgp_cli.dynamics.anticipation.fit_seen`,
    #: chosen on the left-out final pose; None: ``smooth`` and ``seen_tolerance``)
    rest_smooth: float | None = None
    rest_tolerance: float | None = None
    #: ln D's tolerance in that conditioning, in units of its spread, where fit_seen frees it
    #: (:data:`rbgp_cli.dynamics.anticipation.REST_FREE_ELL`; None: exactly, as the duration's weights observe it)
    rest_duration_tolerance: float | None = None
    #: the tolerance of the seen pose one grid step before the last in that conditioning, in units of each
    #: coordinate's spread: with the last seen pose, where the motion is heading (fit_seen; None: the rest's r like
    #: every other seen pose, and no pose added)
    rest_near_tolerance: float | None = None
    #: the draws' factors of a motion under way per seen fraction, {"fractions", "rotation", "position"} (lists;
    #: :func:`rbgp_cli.dynamics.anticipation.seen_band_scales`; None: ``seen_band_scale`` at every fraction)
    seen_band_scales: dict | None = None
    #: the end band's factors per seen fraction, the same form (:func:`rbgp_cli.dynamics.anticipation._end_needs`;
    #: None: ``seen_band_scales``, as files written before them)
    seen_end_band_scales: dict | None = None
    #: the left-out seen parts' median surprise per seen fraction, {"fractions" (F,), "points" (k,) seen poses,
    #: "reference" (k, F)} (lists; the bands of a motion under way seen at that many poses widen by
    #: √max(1, ρ / reference): :meth:`rbgp_cli.dynamics.anticipation.Anticipator.surprise_at`; None: no widening, as
    #: files written before it)
    seen_surprise: dict | None = None
    #: :meth:`goal_band_scale`, computed once
    _goal_scale: tuple | None = field(default=None, repr=False, compare=False)

    # ------------------------------------------------------------------ the Gaussian
    @property
    def demos(self) -> int:
        return int(self.deviations.shape[0])

    @property
    def S(self) -> int:
        return int(len(self.s))

    @property
    def scale(self) -> np.ndarray:
        """Each coordinate's RMS deviation (6,), rad and m (1 where it does not vary)."""
        sc = np.sqrt(np.mean(self.deviations ** 2, axis=(0, 1)))
        return np.where(sc > 1e-12, sc, 1.0)

    @property
    def duration_scale(self) -> float:
        """ℓ's unit: the demonstrations' standard deviation of ln D (at least 0.01)."""
        return float(max(np.std(self.log_durations), 0.01))

    def vectors(self) -> np.ndarray:
        """The demonstrations as scaled vectors x_d (D, P)."""
        D = self.demos
        dev = (self.deviations / self.scale).reshape(D, -1)
        return np.concatenate([dev, (self.log_durations / self.duration_scale)[:, None]], axis=1)

    def unscale(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Scaled vectors x (..., P) → deviations (..., S, 6) in rad and m, and ln D (...,)."""
        x = np.asarray(x, dtype=np.float64)
        dev = x[..., :-1].reshape(x.shape[:-1] + (self.S, 6)) * self.scale
        return dev, x[..., -1] * self.duration_scale

    def smooth_covariance(self, smooth: float | None = None, length: float | None = None) -> np.ndarray:
        """τ² (K_ℓ ⊗ I_6 ⊕ 1) (P, P), module docstring."""
        tau2 = self.smooth if smooth is None else float(smooth)
        ell = self.length if length is None else float(length)
        Ks = np.exp(-0.5 * ((self.s[:, None] - self.s[None, :]) / ell) ** 2)
        P = 6 * self.S + 1
        K = np.zeros((P, P))
        K[:-1, :-1] = np.kron(Ks, np.eye(6))
        K[-1, -1] = 1.0
        return tau2 * K

    def prior(self, vectors: np.ndarray | None = None, smooth: float | None = None, length: float | None = None):
        """(m (P,), Σ (P, P)) of a new motion, from ``vectors`` (default :meth:`vectors`)."""
        X = self.vectors() if vectors is None else vectors
        D = len(X)
        m = X.mean(axis=0)
        C = X - m
        Sigma = (1.0 + 1.0 / D) * (C.T @ C) / max(D - 1, 1) + self.smooth_covariance(smooth, length)
        return m, Sigma

    # ------------------------------------------------------------------ observations
    def observe(self, phases, quat, position, tolerance=None, *, exact: bool = False):
        """The observation operator of poses at phases: A (6n, P), y (6n,), r² (6n,) (module docstring).

        phases (n,); quat (n, 4); position (n, 3). ``tolerance``: (rotation rad, position m) one standard
        deviation per coordinate, or None for the seen tolerance (:attr:`seen_tolerance` in units of the
        spread); ``exact``: :data:`GOAL_TOLERANCE`."""
        from rbgp_cli.dynamics.trajectory import interpolate_poses

        phases = np.asarray(phases, dtype=np.float64).reshape(-1)
        n = len(phases)
        W = _interpolation(self.s, phases)  # (n, S)
        ref_q, ref_p = interpolate_poses(self.s, self.quat, self.position, np.clip(phases, 0.0, 1.0))
        y = pose_deviation(ref_q, ref_p, np.asarray(quat, float).reshape(n, 4), np.asarray(position, float).reshape(n, 3))
        sc = self.scale
        A = np.zeros((n, 6, 6 * self.S + 1))
        for j in range(6):  # six coordinates: a loop of six, each vectorised over the observations
            A[:, j, j:-1:6] = W
        if exact:
            tolerance = GOAL_TOLERANCE
        if tolerance is None:
            r = np.full((n, 6), float(self.seen_tolerance))
        else:
            r = np.broadcast_to(np.repeat(np.asarray(tolerance, dtype=np.float64).reshape(-1, 2), 3, axis=1), (n, 6)) / sc
        return A.reshape(6 * n, -1), (y / sc).reshape(-1), (r ** 2).reshape(-1)

    def observe_duration(self, duration: float, tolerance: float = 1e-3):
        """A (1, P), y (1,), r² (1,): the motion lasts ``duration`` seconds (± ``tolerance`` in ln D)."""
        A = np.zeros((1, 6 * self.S + 1))
        A[0, -1] = 1.0
        return A, np.array([np.log(float(duration)) / self.duration_scale]), np.array([(tolerance / self.duration_scale) ** 2])

    @staticmethod
    def stack(*observations):
        """Stack (A, y, r²) triples into one."""
        A = np.concatenate([o[0] for o in observations], axis=0)
        return A, np.concatenate([o[1] for o in observations]), np.concatenate([o[2] for o in observations])

    # ------------------------------------------------------------------ conditioning
    def condition(self, A, y, r2, prior=None) -> Conditioned:
        """The Gaussian given y = A x + ε, ε ~ N(0, diag r²) (module docstring); ``prior`` (m, Σ) default
        :meth:`prior`. y may be (k,) or (B, k): a batch of observation values with one A (the means
        then have shape (B, P) and share Σ̂)."""
        m, Sigma = self.prior() if prior is None else prior
        SA = Sigma @ A.T  # (P, k)
        G = A @ SA + np.diag(r2)
        L = np.linalg.cholesky(0.5 * (G + G.T))
        from scipy.linalg import cho_solve

        gain = cho_solve((L, True), SA.T).T  # Σ Aᵀ G⁻¹ (P, k)
        innov = np.asarray(y, dtype=np.float64) - (A @ m)
        mean = m + innov @ gain.T
        cov = Sigma - gain @ SA.T
        return Conditioned(self, mean, 0.5 * (cov + cov.T))

    def update(self, deviation: np.ndarray, A, y, r2, log_duration=None, prior=None) -> np.ndarray:
        """Matheron's pathwise update of paths (module docstring): deviations (B, S, 6) rad, m (with ln D
        (B,) if known; else the prior mean's) that should satisfy y (B, k) = A x: returns them plus
        Σ Aᵀ G⁻¹ (y − A x), (B, S, 6). With exact observations the result passes them within the tolerance.
        ``prior`` (m, Σ) default :meth:`prior` (e.g. :meth:`goal_prior`'s)."""
        deviation = np.asarray(deviation, dtype=np.float64)
        B = len(deviation)
        m, Sigma = self.prior() if prior is None else prior
        x = np.empty((B, len(m)))
        x[:, :-1] = (deviation / self.scale).reshape(B, -1)
        x[:, -1] = m[-1] if log_duration is None else np.asarray(log_duration, float) / self.duration_scale
        SA = Sigma @ A.T
        G = A @ SA + np.diag(r2)
        from scipy.linalg import cho_solve

        L = np.linalg.cholesky(0.5 * (G + G.T))
        innov = np.atleast_2d(y) - x @ A.T  # (B, k)
        x = x + cho_solve((L, True), innov.T).T @ SA.T
        return self.unscale(x)[0]

    def goal_strength(self, A, y, r2) -> float:
        """The factor λ ≥ 1 on the smooth shrinkage τ² for one motion's known poses y = A x + ε (a goal,
        via-points; module docstring), from how far they lie, and in which directions, from the
        demonstrations (issue 38, fourth pass; docs/method.md §12).

        Each part of Σ gets a scale, Σ(κ, λ) = κ (1 + 1/D) CᵀC / (D − 1) + λ τ² K, and (κ, λ) ∈
        :data:`STRENGTH_GRID`² maximise the marginal likelihood of y, N(y; A m, A Σ(κ, λ) Aᵀ + R) (a
        type-II maximum for this one motion). The conditional mean depends on the ratio λ/κ alone, and
        λ = max(1, λ/κ) is returned: 1 (the distribution as fitted) when the poses lie where the
        demonstrations vary, or beyond them along those directions (κ grows: the demonstrations'
        linear relation is extrapolated, as before); above 1 when they lie off the directions the
        demonstrations span, where their sample covariance's regression on the goal, estimated from a
        few of them, is a guess that amplifies: with 5 slower handovers, goals 7–23 spreads from where
        they end were bent 0.8–1.2 m off their path in the middle (docs/defaults.md, issue 38)."""
        m, S0 = self.prior(smooth=0.0)
        e = np.asarray(y, dtype=np.float64) - A @ m
        AS = A @ S0 @ A.T
        AK = A @ self.smooth_covariance() @ A.T
        R = np.diag(r2)
        grid = np.asarray(STRENGTH_GRID)
        # every (κ, λ) at once: (g, g, k, k) small Cholesky factors, k the known coordinates
        G = grid[:, None, None, None] * AS + grid[None, :, None, None] * AK + R
        L = np.linalg.cholesky(0.5 * (G + np.swapaxes(G, -1, -2)))
        a = np.linalg.solve(L, np.broadcast_to(e, G.shape[:-1])[..., None])[..., 0]
        ll = -0.5 * np.sum(a**2, axis=-1) - np.sum(np.log(np.diagonal(L, axis1=-2, axis2=-1)), axis=-1)
        i, j = np.unravel_index(int(np.argmax(ll)), ll.shape)  # the first maximum, κ before λ
        return max(1.0, float(grid[j] / grid[i]))

    def goal_prior(self, A, y, r2) -> tuple[np.ndarray, np.ndarray, float]:
        """(m, Σ, λ): the prior a motion with known poses y = A x + ε is conditioned with, its smooth
        shrinkage scaled by :meth:`goal_strength`'s λ: Σ = (1 + 1/D) CᵀC / (D − 1) + λ τ² K."""
        lam = self.goal_strength(A, y, r2)
        m, Sigma = self.prior(smooth=self.smooth * lam)
        return m, Sigma, lam

    def goal_band_scale(self, level: float = 0.90) -> tuple[float, float]:
        """The bands' factors (c_rot, c_pos) for draws given start and goal (:func:`rollout_conditioned
        <rbgp_cli.dynamics.rollout.rollout_conditioned>`): those of :attr:`band_scale`, from the same
        left-out demonstrations (:func:`_band_factors`), but allowed below 1 (down to :data:`NARROWEST`):
        a factor c < 1 is taken as c^w, w = min(1, D / NARROW_FROM) (issue 38): fully from
        :data:`NARROW_FROM` demonstrations on, and with fewer pulled toward 1 (the Student-t predictive)
        in proportion, since the 90 % quantile of fewer left-out paths is less certain. With 5–7
        demonstrations the left-out factors were 0.3–0.9 (τ² at the grid's largest, 1), and with factors
        kept at 1 the bands held 0.95–1.00 of the held-out motions (docs/defaults.md, issue 38).

        Why: τ² and ℓ maximise the left-out demonstrations' *joint* density (:func:`fit_paths`), and a
        covariance estimated from D demonstrations in the scored dimensions (tens) is overconfident
        there, so the density favours a generous τ²; the bands are per-step marginals, which that τ²
        widens. On a synthetic Gaussian family of 120 motions (tests/dynamics/test_paths.py) the bands
        held 0.97 / 0.99 (position / rotation) of fresh motions with the factors kept at 1 or more.

        As the start-only bands do (:func:`rbgp_cli.dynamics.variation.band_calibration`), the factors are
        also measured with contiguous blocks in recording order left out (:func:`goal_blocks`,
        :func:`_block_stats`: what the next session meets when the demonstrations drift over the session),
        and each of (c_rot, c_pos) is the larger of the two before the rule above. With the random left-out
        factors alone the 40 hand raises' goal bands held 0.86 / 0.82 of the blocks held out in recording
        order; with the larger 0.90 / 0.86 (docs/defaults.md, issue 38, sixth pass)."""
        if self._goal_scale is None:
            _, m2, z = _loo_scores(self, self.smooth, self.length, stats=True)
            c = _band_factors(m2, z, self.demos, level)
            if GOAL_BLOCKS and (blocks := goal_blocks(self.demos)) is not None:
                # and as the next session meets them: contiguous blocks in recording order left out (the
                # start-only bands' rule, dynamics/variation.py's band_calibration), the larger factor kept
                c = tuple(max(a, b) for a, b in zip(c, _band_factors(*_block_stats(self, blocks), self.demos, level)))
            w = min(1.0, self.demos / NARROW_FROM)
            self._goal_scale = tuple(max(NARROWEST, x if x >= 1.0 else x ** w) for x in c)
        return self._goal_scale

    def goal_distance(self, start_quat, start_position, goal_quat, goal_position) -> np.ndarray:
        """How far goals lie from where the demonstrations end, given each start: the Mahalanobis
        distance of the goal's deviation under the start-conditioned predictive N(A x̂, A Σ̂ Aᵀ) at phase 1,
        per motion (B,), in units of the demonstrations' spread (a χ with 6 degrees of freedom; 1 is
        typical, above 3.5 a goal fewer than 1 in 200 demonstrations would reach)."""
        B = len(np.atleast_2d(start_quat))
        return self.pose_distance(start_quat, start_position, np.ones(B), goal_quat, goal_position)

    def pose_distance(self, start_quat, start_position, phases, quat, position) -> np.ndarray:
        """How far poses lie from where the demonstrations pass at given phases, given each start: the
        Mahalanobis distance of pose b's deviation at phase s_b under the start-conditioned predictive
        N(A_b x̂, A_b Σ̂ A_bᵀ), (B,), in units of the demonstrations' spread (a χ with 6 degrees of
        freedom). start_quat (B, 4), start_position (B, 3), phases (B,) in [0, 1], quat (B, 4),
        position (B, 3); :meth:`goal_distance` is this at phase 1."""
        q0, p0 = np.atleast_2d(start_quat), np.atleast_2d(start_position)
        B = len(q0)
        phases = np.broadcast_to(np.asarray(phases, dtype=np.float64).reshape(-1), (B,))
        quat = np.broadcast_to(np.asarray(quat, dtype=np.float64).reshape(-1, 4), (B, 4))
        position = np.broadcast_to(np.asarray(position, dtype=np.float64).reshape(-1, 3), (B, 3))
        ob0 = [self.observe([0.0], q[None], p[None], exact=True) for q, p in zip(q0, p0)]
        A0, _, r0 = ob0[0]
        cond = self.condition(A0, np.stack([o[1] for o in ob0]), r0)  # one operator, B start values
        A1, y1, _ = self.observe(phases, quat, position, exact=True)
        A1 = A1.reshape(B, 6, -1)
        e = y1.reshape(B, 6) - np.einsum("bip,bp->bi", A1, cond.mean)  # (B, 6)
        S1 = np.einsum("bip,pq,bjq->bij", A1, cond.cov, A1)  # (B, 6, 6)
        return np.sqrt(np.einsum("bi,bi->b", e, np.linalg.solve(S1, e[..., None])[..., 0]))

    def duration_posterior(self, t, quat, position, grid: np.ndarray | None = None, *, points: int = 12):
        """The posterior over the duration D of a motion seen from its start t[0] to t[-1] (module
        docstring): returns (grid (G,) seconds, weights (G,) summing to 1). ``grid`` default: 48 values
        log-spaced over [max(seen span, 0.5 min D_d), 2 max D_d]. At most ``points`` seen samples (evenly
        spread, the first and last always) enter the likelihood."""
        t = np.asarray(t, dtype=np.float64).reshape(-1)
        quat = np.asarray(quat, dtype=np.float64).reshape(-1, 4)
        position = np.asarray(position, dtype=np.float64).reshape(-1, 3)
        span = float(t[-1] - t[0])
        dmin, dmax = float(np.exp(self.log_durations.min())), float(np.exp(self.log_durations.max()))
        if grid is None:
            lo = max(span, 0.5 * dmin, 1e-3)
            grid = np.exp(np.linspace(np.log(lo), np.log(max(2.0 * dmax, lo * 1.01)), 48))
        grid = np.asarray(grid, dtype=np.float64)
        idx = np.unique(np.round(np.linspace(0, len(t) - 1, min(points, len(t)))).astype(int))
        m, Sigma = self.prior()
        logp = np.full(len(grid), -np.inf)
        for g, D in enumerate(grid):  # a loop over the grid's durations (≤ 48), each one Gaussian density
            if D < span:
                continue
            A, y, r2 = self.stack(self.observe((t[idx] - t[0]) / D, quat[idx], position[idx]),
                                  self.observe_duration(D, tolerance=1e-6))
            G = A @ Sigma @ A.T + np.diag(r2)
            e = y - A @ m
            L = np.linalg.cholesky(0.5 * (G + G.T))
            a = np.linalg.solve(L, e)
            logp[g] = -0.5 * a @ a - np.sum(np.log(np.diag(L)))  # the joint density of (y, ℓ): the grid is uniform in ℓ = ln D, so no Jacobian
        w = np.exp(logp - np.max(logp))
        return grid, w / w.sum()

    def pose_at(self, deviation: np.ndarray, phases: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The poses (quat (..., T, 4), position (..., T, 3)) of deviation paths (..., S, 6) at phases
        (T,) or (..., T): R = exp(δ_rot) R̄(s), p = p̄(s) + δ_pos, δ interpolated linearly."""
        from rbgp_cli.dynamics.trajectory import interpolate_poses
        from rbgp_cli.geometry.so3 import exp_quat, quat_make_continuous, quat_multiply

        dev = np.asarray(deviation, dtype=np.float64)
        ph = np.clip(np.asarray(phases, dtype=np.float64), 0.0, 1.0)
        W = _interpolation(self.s, ph.reshape(-1)).reshape(ph.shape + (self.S,))
        d = np.einsum("...ts,...sj->...tj", W, dev) if ph.ndim > 1 else np.einsum("ts,...sj->...tj", W, dev)
        ref_q, ref_p = interpolate_poses(self.s, self.quat, self.position, ph.reshape(-1))
        ref_q = ref_q.reshape(ph.shape + (4,))
        ref_p = ref_p.reshape(ph.shape + (3,))
        q = quat_make_continuous(quat_multiply(exp_quat(d[..., :3]), ref_q))
        return q, ref_p + d[..., 3:]

    def deviation_of(self, t, quat, position, duration=None) -> np.ndarray:
        """A trajectory's (t (T,), quat (T, 4), position (T, 3)) deviation on the grid (S, 6) (its phase
        (t − t_0)/duration, default its own span)."""
        from rbgp_cli.dynamics.trajectory import interpolate_poses
        from rbgp_cli.geometry.so3 import quat_make_continuous

        t = np.asarray(t, dtype=np.float64)
        dur = float(t[-1] - t[0]) if duration is None else float(duration)
        q, p = interpolate_poses((t - t[0]) / max(dur, 1e-12), quat_make_continuous(np.asarray(quat, float)), np.asarray(position, float), self.s)
        return pose_deviation(self.quat, self.position, q, p)

    # ------------------------------------------------------------------ model files
    def to_arrays(self) -> dict:
        """The arrays a model file keeps (``paths_*``; :mod:`rbgp_cli.io.model_store`, version 8)."""
        c = np.ascontiguousarray
        return {"paths_s": c(self.s, dtype=np.float64), "paths_quat": c(self.quat, dtype=np.float64),
                "paths_position": c(self.position, dtype=np.float64),
                "paths_deviations": c(self.deviations, dtype=np.float64),
                "paths_log_durations": c(self.log_durations, dtype=np.float64)}

    def header(self) -> dict:
        """The header fields a model file keeps (``paths``)."""
        return {"demos": self.demos, "steps": self.S, "smooth": float(self.smooth), "length": float(self.length),
                "seen_tolerance": float(self.seen_tolerance),
                "band_scale": {"rotation": float(self.band_scale[0]), "position": float(self.band_scale[1])},
                "seen_band_scale": {"rotation": float(self.seen_band_scale[0]), "position": float(self.seen_band_scale[1])},
                **({"duration_smooth": float(self.duration_smooth)} if self.duration_smooth is not None else {}),
                **({"duration_tolerance": float(self.duration_tolerance)} if self.duration_tolerance is not None else {}),
                **({"duration_sigma": float(self.duration_sigma)} if self.duration_sigma is not None else {}),
                **({"duration_evidence": float(self.duration_evidence)} if self.duration_evidence is not None else {}),
                **({"duration_statistic": str(self.duration_statistic)} if self.duration_statistic is not None else {}),
                **({"rest_smooth": float(self.rest_smooth)} if self.rest_smooth is not None else {}),
                **({"rest_tolerance": float(self.rest_tolerance)} if self.rest_tolerance is not None else {}),
                **({"rest_duration_tolerance": float(self.rest_duration_tolerance)}
                   if self.rest_duration_tolerance is not None else {}),
                **({"rest_near_tolerance": float(self.rest_near_tolerance)}
                   if self.rest_near_tolerance is not None else {}),
                **({"seen_band_scales": {k: [float(x) for x in self.seen_band_scales[k]]
                                         for k in ("fractions", "rotation", "position")}}
                   if self.seen_band_scales is not None else {}),
                **({"seen_end_band_scales": {k: [float(x) for x in self.seen_end_band_scales[k]]
                                             for k in ("fractions", "rotation", "position")}}
                   if self.seen_end_band_scales is not None else {}),
                **({"seen_surprise": _surprise_copy(self.seen_surprise)} if self.seen_surprise is not None else {})}

    @classmethod
    def from_arrays(cls, arrays: dict, header: dict) -> "PathDistribution":
        """From :meth:`to_arrays`' arrays and :meth:`header`'s fields."""
        bs = header.get("band_scale") or {"rotation": 1.0, "position": 1.0}
        ss = header.get("seen_band_scale") or {"rotation": 1.0, "position": 1.0}
        f = np.asarray
        return cls(f(arrays["paths_s"], float), f(arrays["paths_quat"], float), f(arrays["paths_position"], float),
                   f(arrays["paths_deviations"], float), f(arrays["paths_log_durations"], float),
                   float(header["smooth"]), float(header["length"]), float(header["seen_tolerance"]),
                   (float(bs["rotation"]), float(bs["position"])),
                   seen_band_scale=(float(ss["rotation"]), float(ss["position"])),
                   duration_smooth=None if header.get("duration_smooth") is None else float(header["duration_smooth"]),
                   duration_tolerance=None if header.get("duration_tolerance") is None else float(header["duration_tolerance"]),
                   duration_sigma=None if header.get("duration_sigma") is None else float(header["duration_sigma"]),
                   duration_evidence=None if header.get("duration_evidence") is None else float(header["duration_evidence"]),
                   duration_statistic=None if header.get("duration_statistic") is None else str(header["duration_statistic"]),
                   rest_smooth=None if header.get("rest_smooth") is None else float(header["rest_smooth"]),
                   rest_tolerance=None if header.get("rest_tolerance") is None else float(header["rest_tolerance"]),
                   rest_duration_tolerance=None if header.get("rest_duration_tolerance") is None
                   else float(header["rest_duration_tolerance"]),
                   rest_near_tolerance=None if header.get("rest_near_tolerance") is None
                   else float(header["rest_near_tolerance"]),
                   seen_band_scales=None if header.get("seen_band_scales") is None else
                   {k: [float(x) for x in header["seen_band_scales"][k]] for k in ("fractions", "rotation", "position")},
                   seen_end_band_scales=None if header.get("seen_end_band_scales") is None else
                   {k: [float(x) for x in header["seen_end_band_scales"][k]] for k in ("fractions", "rotation", "position")},
                   seen_surprise=None if header.get("seen_surprise") is None else _surprise_copy(header["seen_surprise"]))


def _surprise_copy(sur: dict) -> dict:
    """``seen_surprise`` as plain lists: {"fractions": [float], "points": [int], "reference": [[float]]}."""
    return {"fractions": [float(x) for x in sur["fractions"]], "points": [int(n) for n in sur["points"]],
            "reference": [[float(x) for x in row] for row in sur["reference"]]}


# ---------------------------------------------------------------------- fitting
def _loo_scores(paths: PathDistribution, smooth: float, length: float, stats: bool = False, setup=None):
    """Leave each demonstration out: condition the others' distribution on its start and end, and score
    the held-out path at every SELECT_EVERY-th phase in between. Only the coordinates involved enter
    (a Gaussian's marginal is its sub-block). Returns the mean log density per demonstration and, with
    ``stats``, the rotation Mahalanobis² (D·k,) and position z-scores (D·k, 3) for the bands' factors.
    All demonstrations at once (:func:`left_out_moments`, :func:`held_out_scores`); ``setup``
    (:func:`_loo_setup`) shares the left-out moments between calls (they do not depend on τ², ℓ)."""
    idx, Xs, r2, moments = _loo_setup(paths) if setup is None else setup
    Ks = paths.smooth_covariance(smooth, length)[np.ix_(idx, idx)]
    logd, m2, z = 0.0, [], []
    for block, m, sample in moments:
        Sigma = sample + Ks  # (B, P, P)
        S11, S21, S22 = Sigma[:, :12, :12] + np.diag(r2), Sigma[:, 12:, :12], Sigma[:, 12:, 12:]
        S12 = np.swapaxes(S21, 1, 2)
        gain = np.swapaxes(np.linalg.solve(S11, S12), 1, 2)  # (B, P − 12, 12)
        mean = m[:, 12:] + (gain @ (Xs[block, :12] - m[:, :12])[..., None])[..., 0]
        cov = S22 - gain @ S12
        ld, m2_b, z_b = held_out_scores(Xs[block, 12:] - mean, cov, stats)
        logd += float(np.sum(ld))
        if stats:
            m2.append(m2_b.reshape(-1))
            z.append(z_b.reshape(-1, 3))
    D = len(Xs)
    if stats:
        return logd / D, np.concatenate(m2), np.concatenate(z)
    return logd / D


def _loo_setup(paths: PathDistribution, moments: bool = True):
    """What :func:`_loo_scores` needs whatever τ² and ℓ: the coordinates involved (start and end first,
    then every SELECT_EVERY-th phase), the demonstrations' vectors there (D, P), the ends' tolerances
    r² (12,) and the left-out moments (:func:`left_out_moments`, as a list; None without ``moments``)."""
    X = paths.vectors()
    S = paths.S
    sel = np.arange(SELECT_EVERY, S - 1, SELECT_EVERY)
    phases = np.concatenate([[0, S - 1], sel])
    idx = (6 * phases[:, None] + np.arange(6)[None]).ravel()  # known first (12), then the scored ones
    Xs = X[:, idx]
    r2 = np.concatenate([(np.array(GOAL_TOLERANCE).repeat(3) / paths.scale) ** 2] * 2)
    return idx, Xs, r2, (list(left_out_moments(Xs)) if moments else None)


#: :func:`left_out_moments` yields this many left-out demonstrations at a time (memory: that many P × P),
#: and holds at most LOO_ELEMENTS numbers of their other demonstrations' rows at once (32 MB).
LOO_BLOCK = 64
LOO_ELEMENTS = 4_000_000


def left_out_moments(Xs: np.ndarray, block: int = LOO_BLOCK):
    """Each demonstration d (a row of Xs (D, P)) left out in turn: the others' mean m_d and the sample
    part of their distribution's covariance, (1 + 1/N) Ĉ_d with N = D − 1 others and Ĉ_d their sample
    covariance (divisor max(N − 1, 1)), as :meth:`PathDistribution.prior` builds it for them (without the
    smooth term τ² K). Yields (indices (B,), m (B, P), (1 + 1/N) Ĉ (B, P, P)) for consecutive blocks of
    at most ``block`` demonstrations (and at most LOO_ELEMENTS numbers of the others' rows at once).

    The same arithmetic as a loop over d (the others' rows, their mean, centred, CᵀC), batched: a
    left-out path's density is a Schur complement of this covariance, and where that is nearly
    singular (few demonstrations, a small τ²: condition numbers of 1e10) it amplifies any rounding;
    a rank-one downdate of the whole set's scatter instead moved such scores by 7e-5 relative."""
    Xs = np.asarray(Xs, dtype=np.float64)
    D, P = Xs.shape
    N = D - 1
    step = max(1, min(int(block), LOO_ELEMENTS // max(N * P, 1)))
    others = np.array([np.delete(np.arange(D), d) for d in range(D)]) if D > 1 else np.zeros((D, 0), int)
    for a in range(0, D, step):
        b = np.arange(a, min(D, a + step))
        rest = Xs[others[b]]  # (B, N, P)
        m = rest.mean(axis=1)
        C = rest - m[:, None]
        cov = np.ascontiguousarray(np.swapaxes(C, 1, 2)) @ C  # contiguous: numpy's batched BLAS product
        cov *= 1.0 + 1.0 / N  # the loop's order of operations, to the last bit
        cov /= max(N - 1, 1)
        yield b, m, cov


def held_out_score(e: np.ndarray, cov: np.ndarray, stats: bool = False):
    """A left-out path's error e (6k,) (k phases × 6 coordinates, scaled) under its predictive covariance
    cov (6k, 6k): its Gaussian log density (without the 2π term; a relative 1e-9 jitter) and, with
    ``stats``, per phase the rotation Mahalanobis² (k,) and the position z-scores (k, 3) of the
    marginals, for the bands' factors (:func:`_band_factors`); else (log density, None, None).
    :func:`held_out_scores` for one path."""
    logd, m2, z = held_out_scores(np.asarray(e)[None], np.asarray(cov)[None], stats)
    return float(logd[0]), (None if m2 is None else m2[0]), (None if z is None else z[0])


def held_out_scores(e: np.ndarray, cov: np.ndarray, stats: bool = False):
    """:func:`held_out_score` of B left-out paths at once: errors e (B, 6k), covariances cov (B, 6k, 6k).
    Returns log densities (B,) and, with ``stats``, m² (B, k) and z (B, k, 3) (else None, None):

        log p = −½ aᵀa − Σ log L_ii,   L Lᵀ = cov + 1e-9 tr(cov)/(6k) I,   L a = e."""
    e = np.asarray(e, dtype=np.float64)
    cov = np.asarray(cov, dtype=np.float64)
    B, n = e.shape
    jitter = 1e-9 * np.trace(cov, axis1=1, axis2=2) / n
    L = np.linalg.cholesky(cov + jitter[:, None, None] * np.eye(n))
    a = np.linalg.solve(L, e[..., None])[..., 0]
    logd = -0.5 * np.einsum("bi,bi->b", a, a) - np.sum(np.log(np.diagonal(L, axis1=1, axis2=2)), axis=1)
    if not stats:
        return logd, None, None
    k = n // 6
    ek = e.reshape(B, k, 6)
    Ck = np.stack([cov[:, 6 * i:6 * i + 6, 6 * i:6 * i + 6] for i in range(k)], axis=1)  # (B, k, 6, 6)
    m2 = np.einsum("bki,bki->bk", ek[..., :3],
                   np.linalg.solve(Ck[..., :3, :3] + 1e-12 * np.eye(3), ek[..., :3, None])[..., 0])
    z = np.abs(ek[..., 3:]) / np.sqrt(np.maximum(np.einsum("bkii->bki", Ck[..., 3:, 3:]), 1e-24))
    return logd, m2, z


#: :meth:`PathDistribution.goal_band_scale` also leaves out this many contiguous blocks in recording order
#: (the demonstrations' order), each at least two long and leaving MIN_PATH_DEMOS + 1 or more (0: not).
GOAL_BLOCKS = 5


def goal_blocks(D: int, blocks: int | None = None) -> list[np.ndarray] | None:
    """The held-out index blocks (contiguous, in recording order) of :meth:`PathDistribution.goal_band_scale`
    for D demonstrations: min(``blocks``, D // 2) of them (default :data:`GOAL_BLOCKS`), or None when fewer
    than two blocks or a block's others would be fewer than MIN_PATH_DEMOS + 1 (a covariance of 3
    demonstrations conditioned on 12 coordinates says little about its band)."""
    k = min(int(GOAL_BLOCKS if blocks is None else blocks), D // 2)
    if k < 2 or D - int(np.ceil(D / k)) < MIN_PATH_DEMOS + 1:
        return None
    return list(np.array_split(np.arange(D), k))


def _block_stats(paths: PathDistribution, blocks: list[np.ndarray]):
    """:func:`_loo_scores`' band statistics (rotation Mahalanobis² (·,), position z-scores (·, 3)) with
    contiguous ``blocks`` of demonstrations left out in turn instead of one: each left-out path is scored
    at every SELECT_EVERY-th phase under the other demonstrations' distribution (their mean and sample
    covariance, (1 + 1/N) Ĉ + τ² K) conditioned on its start and end."""
    idx, Xs, r2, _ = _loo_setup(paths, moments=False)
    Ks = paths.smooth_covariance()[np.ix_(idx, idx)]
    m2, z = [], []
    for test in blocks:
        rest = Xs[np.setdiff1d(np.arange(len(Xs)), test)]
        N = len(rest)
        m = rest.mean(axis=0)
        C = rest - m
        Sigma = (1.0 + 1.0 / N) * (C.T @ C) / max(N - 1, 1) + Ks
        S11, S12 = Sigma[:12, :12] + np.diag(r2), Sigma[:12, 12:]
        gain = np.linalg.solve(S11, S12).T  # (P − 12, 12)
        cov = Sigma[12:, 12:] - gain @ S12
        e = Xs[test, 12:] - (m[12:] + (Xs[test, :12] - m[:12]) @ gain.T)  # (B, P − 12)
        _, m2_b, z_b = held_out_scores(e, np.broadcast_to(cov, (len(test),) + cov.shape), True)
        m2.append(m2_b.reshape(-1))
        z.append(z_b.reshape(-1, 3))
    return np.concatenate(m2), np.concatenate(z)


def _band_factors(m2: np.ndarray, z: np.ndarray, demos: int, level: float = 0.90) -> tuple[float, float]:
    """The factors (c_rot, c_pos) that make the left-out paths' 90 % regions hold at ``level`` against
    the draws' Student-t quantiles (ν = D − 2: a rotation's m²/3 is F(3, ν), a position coordinate
    t_ν), from :func:`_loo_scores`' rotation Mahalanobis² ``m2`` and position z-scores ``z``; unclamped."""
    from scipy.special import fdtri, stdtrit

    nu = max(int(demos) - 2, 1)
    c_rot = np.sqrt(np.quantile(m2, level) / (3.0 * fdtri(3, nu, level)))
    c_pos = np.quantile(np.ravel(z), level) / stdtrit(nu, 0.5 + level / 2.0)
    return float(c_rot), float(c_pos)


def fit_paths(trajs, steps: int = 51, *, level: float = 0.90) -> PathDistribution | None:
    """The path distribution of clean demonstrations (module docstring), None for fewer than
    MIN_PATH_DEMOS. τ² and ℓ maximise the left-out demonstrations' log density given their start and
    end (:func:`_loo_scores`); the bands' factors (c_rot, c_pos) ≥ 1 make the left-out paths' 90 %
    regions hold at ``level`` (as :func:`rbgp_cli.dynamics.variation.band_scale` does for the start-only
    draws) against the draws' own Student-t quantiles (3 F_level(3, ν) for a rotation's m², t_ν for a
    position coordinate)."""
    from rbgp_cli.dynamics.variation import demonstration_deviations

    trajs = list(trajs)
    D = len(trajs)
    if D < MIN_PATH_DEMOS:
        return None
    path, delta = demonstration_deviations(trajs, steps)
    durations = np.array([max(tr.duration, 1e-6) for tr in trajs])
    paths = PathDistribution(np.asarray(path["s"], float), np.asarray(path["quat"], float),
                             np.asarray(path["position"], float), delta, np.log(durations))
    setup = _loo_setup(paths)  # the left-out moments once for the whole grid
    scores = {(tau2, ell): _loo_scores(paths, tau2, ell, setup=setup) for tau2 in SMOOTH_GRID for ell in LENGTH_GRID}
    paths.smooth, paths.length = max(scores, key=scores.get)
    score, m2, z = _loo_scores(paths, paths.smooth, paths.length, stats=True, setup=setup)
    c_rot, c_pos = _band_factors(m2, z, D, level)
    paths.band_scale = (max(1.0, float(c_rot)), max(1.0, float(c_pos)))
    paths.info = {"loo_log_density": float(score), "smooth": paths.smooth, "length": paths.length}
    from rbgp_cli.dynamics.anticipation import fit_seen

    fit_seen(paths, trajs)  # the seen poses' tolerance, the duration's τ² and r, the bands of a motion under way (issue 37)
    return paths
