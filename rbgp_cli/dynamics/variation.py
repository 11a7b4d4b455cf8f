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

so r_d(0) = 0. The residual functions r_d (D, S, 6) are the model of the variation, with ν = D − 2
degrees of freedom (centring and the regression). Two things are made of them (issue 36):

- **A sample** (:meth:`Variation.draw`, what ``rollout --samples`` draws) is one plausible motion: the
  plug-in Gaussian η(s) = √(1/ν) Σ_d z_d r_d(s), z ~ N(0, I_D), a function with the residuals'
  covariance over the whole phase range (every phase pair, every coordinate pair: coherent). A sampled
  rollout is the mean rollout from the same start displaced by a draw: R_k(s) = exp(η_rot(s)) R(s),
  p_k(s) = p(s) + η_pos(s) — one smooth alternative way of doing the task, zero at the start, that
  varies as much as the demonstrations do (not more).
- **A band** (:meth:`Variation.region`) is the 90 % prediction region of the next real motion from
  that start: the predictive of a new demonstration, Student-t with ν degrees of freedom and scale
  matrix C(s) = (1 + 1/D)/ν · Σ r_d(s) r_d(s)ᵀ (inflated for the estimated mean, heavy-tailed for the
  estimated covariance), widened by the factors c below. It is computed, not drawn: per position axis
  |e_j| ≤ c_pos t_ν,0.95 √C_jj, in rotation eᵀ C_rot⁻¹ e ≤ c_rot² · 3 F_0.90(3, ν) (e = log(R Rᵀ_mean),
  p − p_mean). ``draw(predictive=True)`` draws that predictive (its exact 90 % regions are the band).

Why two: a draw of the predictive is wider than a demonstration by the parameter uncertainty
(ν/(ν − 2) in variance: 3 with five demonstrations), so a set of such draws is further from the
demonstrations than fresh people are (crossval's sample ratio 1.53 on five hand raises), while the
typical draws' regions are too narrow to hold the next motion (0.73).

The bands' scale (:func:`band_scale`). A Gaussian draw with the residuals' covariance holds a new
demonstration as often as promised only if the demonstrations' deviations are Gaussian. Real ones are
not: on the handovers a few demonstrations turn the object another way for much of the motion, so the
held-out rotations lay inside the samples' 90 % region 0.83 of the time, with the median Mahalanobis
distance where a Gaussian puts it and the tail far beyond. So each demonstration d is left out in turn
and predicted from the others as a rollout predicts it (the start map with the model's ridge, and the
prior's pull closing the gap at the start as exp(−a·s)); its error e_d(s) is measured against the band
of the model without it (its m = D − 1 demonstrations: scale C_m(s), ν_m = m − 2 degrees of freedom).
The factors are the ones that make those bands hold at the level over all (d, s), s > 0:

    c_rot² = q_0.90(e_rotᵀ C_m,rot⁻¹ e_rot / (3 F_0.90(3, ν_m))),    c_pos = q_0.90(|e_pos,j| / (t_ν_m,0.95 √C_m,jj)),

and the band's rotation region is c_rot times wider, its position interval c_pos times. Both are at
least 1 (a band is never narrower than the Student-t predictive) and 1 with fewer than MIN_BAND_DEMOS
demonstrations (:func:`band_calibration`).

Issue 36 (docs/method.md §11). The covariance between coordinates is shrunk toward its diagonal by
Schäfer–Strimmer's weight α (:func:`shrinkage`), so that 3–6 demonstrations do not give a rotation
covariance of too low a rank; the factors are also measured on contiguous blocks left out in recording
order (the rows' order: the order the demonstrations were read), and the bands take the larger
(:func:`band_calibration`); :func:`order_drift` tests whether the demonstrations drift over that order.

The start's surprise (issue 36, seventeenth pass; docs/method.md §11). A band about the mean path cannot hold a
next session whose starts moved (the hand raises' takes 25–32 from 1–24: 0.41 / 0.48). From START_SURPRISE_FROM
demonstrations on, the band of a start c = δ(0) − μ(0) is widened by

    s = √max(1, ρ / ρ̄),   ρ = cᵀ Σ_0⁻¹ c / 6,

Σ_0 the demonstrations' start covariance (:func:`start_covariance`) and ρ̄ the upper quartile
(START_SURPRISE_QUANTILE) of the ρ of the demonstrations left out one at a time, each against the others' Σ_0 and
mean start. The factors c above are fitted on the left-out errors divided by their own s, so a start no more
surprising than three in four of the demonstrations' keeps the factors' band, a more surprising one widens it
and none narrows it (:func:`band_calibration`; :meth:`Variation.start_widening`). The widening is kept where the
left-out bands are narrower with it at the same level (the start's surprise says which motions need more), else
the bands are as without it (:func:`band_calibration`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rbgp_cli.dynamics.trajectory import Trajectory

__all__ = ["Variation", "demonstration_variation", "demonstration_deviations", "start_regression", "start_map", "start_reach",
           "bound_shift", "START_INPUTS", "SURPRISE_FROM", "START_SURPRISE_FROM", "START_SURPRISE_QUANTILE",
           "surprise_scale", "start_covariance", "start_surprise", "START_BEYOND_FROM",
           "band_scale", "band_calibration", "band_quantiles", "shrinkage", "order_drift", "pull_profile", "DRIFT_P", "STEPS", "MIN_DEMOS", "MIN_BAND_DEMOS", "RIDGE_GRID", "BAND_LEVEL",
           "PULL_CAP", "PULL_WINDOW"]

#: Phase grid of the deviations (as the mean path's).
STEPS = 51
#: Fewer demonstrations than this give no variation model (ν = D − 2 must be positive).
MIN_DEMOS = 3
#: Fewer demonstrations than this keep the bands' scale at 1 (:func:`band_scale`): leaving one out
#: must leave three (ν = 1), whose covariance :func:`shrinkage` keeps at rank 3 in rotation.
MIN_BAND_DEMOS = 4
#: The level at which :func:`band_scale` makes the bands hold (the level crossval's coverage checks).
BAND_LEVEL = 0.90
#: The largest pull gain per unit phase :func:`pull_profile` gives (the demonstrations' spread shrinking
#: e-fold in a twentieth of the motion); a rollout's step caps it further at 1/h (no overshoot).
PULL_CAP = 20.0
#: The phase window over which :func:`pull_profile` measures how fast the spread shrinks.
PULL_WINDOW = 0.1
#: The bands widen with the surprise of what is known of a motion (its start here, the seen part of a motion
#: under way in dynamics/anticipation.py) from this many demonstrations on: with fewer the median of the
#: left-out surprises is a poor reference, and widening against it over-covered the studies of five and six
#: (hand raises trained on 6, 0.96–0.98 from 0.89–0.96; docs/defaults.md, sixteenth pass)
SURPRISE_FROM = 8


#: The start-only bands widen with the start's surprise from this many demonstrations on. One left out, the others'
#: start covariance is estimated from m = D − 1 of them in six coordinates: a left-out start's ρ is F(6, m − 6)
#: distributed for Gaussian starts (Hotelling), whose variance is finite only from m = 11 on, and the reference of
#: fewer than sixteen was noise: the 10 waves (8 per fold) widened at 8 lost 0.07 at random folds (docs/defaults.md,
#: seventeenth pass).
START_SURPRISE_FROM = 16
#: The start-only bands widen against this quantile of the left-out starts' surprise ρ (:func:`band_calibration`):
#: one start's ρ is six numbers' (χ²₆ / 6 where the starts are Gaussian: its 90th percentile is twice its median),
#: so against the median half of the starts were widened by chance. Measured on the real sets (the median, 0.75,
#: 0.9; docs/defaults.md, seventeenth pass): the median held the next session of the hand raises best but took
#: their random folds' rotation and the waves' recording order over 0.95; 0.9 mended little.
START_SURPRISE_QUANTILE = 0.75
#: From this many demonstrations on, a start more surprising than every demonstration's start was against the
#: others' (ρ above ρ_max, the largest of the left-out starts' ρ: :func:`band_calibration`'s ``start_surprises``) widens both parts of
#: its band by √(ρ / ρ_max) (:meth:`Variation.start_widening`), whether or not the upper quartile's widening is kept.
#: Held out at random and from subsets of five on the five sets (docs/defaults.md, eighteenth pass), such starts
#: were 2–13 % of the held-out ones and their bands held 0.53–0.92 (sample_data's rotation 0.12–0.16) where the
#: others' held 0.88–0.99; an exchangeable start lies beyond ρ_max with probability at most 1/(D + 1).
START_BEYOND_FROM = 5


def surprise_scale(rho, reference):
    """s = √max(1, ρ / ρ̄): the bands' widening for what is known of a motion (a start, a seen part) whose
    surprise ρ exceeds the reference ρ̄ (a quantile of the left-out demonstrations' ρ)."""
    return np.sqrt(np.maximum(1.0, np.asarray(rho, dtype=np.float64) / max(float(reference), 1e-300)))


@dataclass
class Variation:
    """The demonstrations' deviation process (module docstring).

    s : (S,) phase grid in [0, 1]; residuals : (D, S, 6) the start-conditioned deviations r_d (rad, m),
    rotation first; dof : ν = D − 2; band_scale : (c_rot, c_pos) ≥ 1, the factors on the band's
    rotation and position (:func:`band_calibration`; (1, 1) for model files written before them).
    """

    s: np.ndarray
    residuals: np.ndarray
    dof: int
    band_scale: tuple = (1.0, 1.0)
    #: α in [0, 1], the weight of the draws' part whose coordinates are independent (:func:`shrinkage`;
    #: 0 for model files written before it)
    shrinkage: float = 0.0
    #: how the bands' factors were found (:func:`band_calibration`, plain data; None for a model file)
    calibration: dict | None = None
    #: the demonstrations' drift over the recording order (:func:`order_drift`, plain data, or None)
    drift: dict | None = None
    #: the start's surprise (:meth:`start_widening`; module docstring): {"quat" (4,), "position" (3,) the mean
    #: path's first pose, "mean" (6,) μ(0), "covariance" (6, 6) Σ_0, "reference" ρ̄ the left-out starts' upper quartile
    #: or None, "parts" [rotation, position] which part of the band widens against ρ̄, "beyond" ρ_max the largest
    #: left-out start's ρ (absent in older model files)};
    #: None: no widening (fewer than START_BEYOND_FROM demonstrations, or an older model file)
    start_surprise: dict | None = None

    @property
    def demos(self) -> int:
        return int(self.residuals.shape[0])

    def draw(self, count: int, rng: np.random.Generator, *, predictive: bool = False) -> np.ndarray:
        """``count`` deviation functions on the grid, shape (count, S, 6) (module docstring).

        Default: typical motions, the plug-in Gaussian η = √(1/ν) (√(1 − α) Σ_d z_d r_d + √α Σ_d z'_dj r_dj)
        with the shrunk covariance Σ_α / ν (:func:`shrinkage`): one plausible motion each, what sampled
        rollouts show. ``predictive``: draws of the predictive of the next demonstration, whose exact
        90 % regions are :meth:`region`'s: η = √((1 + 1/D)/ν) u (…), u = √(ν/χ²_ν), its rotation part
        times c_rot and its position part times c_pos (:attr:`band_scale`)."""
        D = self.demos
        z = rng.standard_normal((int(count), D))
        if predictive:
            # each draw's scale: √(ν / χ²_ν), so that a coordinate is Student-t with ν degrees of freedom, the
            # predictive of a new demonstration when the covariance itself is estimated from D of them
            chi = np.sqrt(self.dof / rng.chisquare(self.dof, int(count)))
            scale = np.sqrt((1.0 + 1.0 / D) / self.dof) * chi
            c_rot, c_pos = (float(c) for c in self.band_scale)
            r = self.residuals * np.array([c_rot] * 3 + [c_pos] * 3)
        else:
            scale = np.full(int(count), np.sqrt(1.0 / self.dof))
            r = self.residuals
        eta = np.einsum("kd,dsj->ksj", z, r)
        a = float(self.shrinkage)
        if a > 0.0:  # the shrunk covariance (1 − α) Σ + α diag(Σ): a part with its own weights per coordinate
            zj = rng.standard_normal((int(count), D, 6))
            eta = np.sqrt(1.0 - a) * eta + np.sqrt(a) * np.einsum("kdj,dsj->ksj", zj, r)
        return scale[:, None, None] * eta

    def scale_matrix(self, phase: np.ndarray) -> np.ndarray:
        """The predictive's scale matrix at phases ``phase`` (...,) (clipped to [0, 1]), shape (..., 6, 6):
        C = (1 + 1/D)/ν · Σ_α of the residuals interpolated linearly on the grid, r(x) = (1 − f) r_k + f r_(k+1)
        (the covariance of :meth:`at`'s interpolation of a draw), Σ_α = (1 − α) Σ_d r_d rᵀ_d + α diag."""
        s, r = self.s, self.residuals
        x = np.clip(np.asarray(phase, dtype=np.float64), 0.0, 1.0)
        k = np.clip(np.searchsorted(s, x, side="right") - 1, 0, len(s) - 2)
        f = ((x - s[k]) / (s[k + 1] - s[k]))[..., None, None]
        Ckk = np.einsum("dsi,dsj->sij", r, r)  # (S, 6, 6) on the grid
        Ck1 = np.einsum("dsi,dsj->sij", r[:, :-1], r[:, 1:])  # (S − 1, 6, 6) between neighbours
        Ck1 = Ck1 + Ck1.transpose(0, 2, 1)
        C = (1.0 - f) ** 2 * Ckk[k] + f ** 2 * Ckk[k + 1] + f * (1.0 - f) * Ck1[k]
        return _shrunk(C, float(self.shrinkage)) * (1.0 + 1.0 / self.demos) / self.dof

    def region(self, phase: np.ndarray, level: float = BAND_LEVEL, widen=None) -> tuple[np.ndarray, np.ndarray]:
        """The band: the ``level`` prediction region of the next real motion at phases ``phase`` (...,)
        around the mean rollout (module docstring). Returns the position half-widths (..., 3) m, per
        axis w c_pos t_ν,(1+level)/2 √C_jj, and the rotation region's matrix M (..., 3, 3) rad², the
        region {e : eᵀ M⁻¹ e ≤ 1} of e = log(R Rᵀ_mean) (world frame), M = w² c_rot² 3 F_level(3, ν) C_rot
        (C :meth:`scale_matrix`; c calibrated at BAND_LEVEL); ``widen`` (..., 2) the factors w ≥ 1 on the rotation
        and the position part, its leading axes those of ``phase``'s leading ones (:meth:`start_widening`: (B, 2)
        for phases (B, T); None: 1)."""
        C = self.scale_matrix(phase)
        q_rot, q_pos = band_quantiles(self.dof, level)
        c_rot, c_pos = (float(c) for c in self.band_scale)
        shape = np.shape(phase)
        if widen is None:
            w_rot = w_pos = np.ones(shape)
        else:
            w = np.asarray(widen, dtype=np.float64)
            w = w.reshape(w.shape[:-1] + (1,) * (len(shape) - (w.ndim - 1)) + (2,))
            w_rot, w_pos = np.broadcast_to(w[..., 0], shape), np.broadcast_to(w[..., 1], shape)
        half = (w_pos * c_pos * q_pos)[..., None] * np.sqrt(np.maximum(np.einsum("...ii->...i", C[..., 3:, 3:]), 0.0))
        return half, (w_rot**2 * c_rot**2 * q_rot)[..., None, None] * C[..., :3, :3]

    def start_widening(self, quat, position) -> np.ndarray:
        """The bands' widening (B, 2), rotation and position part, of start poses (quat (B, 4) x, y, z, w; position
        (B, 3) m), from the start's surprise ρ = cᵀ Σ_0⁻¹ c / 6 of c = (log(R R̄(0)ᵀ), p − p̄(0)) − μ(0) (module
        docstring, "The start's surprise"): in both parts √max(1, ρ / ρ_max) (a start beyond every left-out
        demonstration's, ``beyond``), and in each part that :attr:`start_surprise` widens against the upper quartile
        ρ̄ (its ``parts``) the larger of that and √max(1, ρ / ρ̄); ones without :attr:`start_surprise`."""
        info = self.start_surprise
        if not info:
            return np.ones((len(np.asarray(quat).reshape(-1, 4)), 2))
        rho = self._start_rho(quat, position)
        w = surprise_scale(rho, info["beyond"]) if info.get("beyond") else np.ones(len(rho))
        w = np.repeat(w[:, None], 2, axis=1)
        if info.get("reference") is not None and any(info["parts"]):
            wq = surprise_scale(rho, info["reference"])[:, None]
            w = np.where(np.asarray(info["parts"], dtype=bool)[None], np.maximum(w, wq), w)
        return w

    def start_beyond(self, quat, position) -> np.ndarray | None:
        """ρ / ρ_max (B,) of start poses (:meth:`start_widening`): above 1 a start less like the demonstrations'
        starts than every one of theirs was like the others'; None without ``beyond`` (fewer than
        START_BEYOND_FROM demonstrations, or an older model file)."""
        info = self.start_surprise
        if not info or not info.get("beyond"):
            return None
        return self._start_rho(quat, position) / float(info["beyond"])

    def _start_rho(self, quat, position) -> np.ndarray:
        """ρ (B,) of start poses against :attr:`start_surprise` (:meth:`start_widening`)."""
        from rbgp_cli.dynamics.paths import pose_deviation

        info = self.start_surprise
        quat = np.asarray(quat, dtype=np.float64).reshape(-1, 4)
        position = np.asarray(position, dtype=np.float64).reshape(-1, 3)
        c = pose_deviation(info["quat"], info["position"], quat, position) - np.asarray(info["mean"], dtype=np.float64)
        return start_surprise(c, np.asarray(info["covariance"], dtype=np.float64))

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

    def surprise_header(self) -> dict | None:
        """:attr:`start_surprise` as plain lists for a model file's header (None without it)."""
        info = self.start_surprise
        if not info:
            return None
        return {"quat": [float(x) for x in info["quat"]], "position": [float(x) for x in info["position"]],
                "mean": [float(x) for x in info["mean"]],
                "covariance": [[float(x) for x in row] for row in np.asarray(info["covariance"])],
                "reference": None if info.get("reference") is None else float(info["reference"]),
                "parts": [bool(x) for x in info["parts"]],
                **({} if info.get("beyond") is None else {"beyond": float(info["beyond"])})}

    @classmethod
    def from_arrays(cls, arrays: dict, band_scale=None, shrinkage: float = 0.0, start_surprise=None) -> "Variation":
        """From :meth:`to_arrays`' arrays, the header's ``band_scale`` ({"rotation", "position"}, or
        None for (1, 1)), ``shrinkage`` α (0 for files without it) and ``start_surprise``
        (:meth:`surprise_header`; None for files without it: no widening)."""
        r = np.asarray(arrays["variation_residuals"], dtype=np.float64)
        scale = (1.0, 1.0) if not band_scale else (float(band_scale["rotation"]), float(band_scale["position"]))
        info = None if not start_surprise else {
            k: ((None if v is None else float(v)) if k in ("reference", "beyond") else [bool(x) for x in v] if k == "parts"
                else np.asarray(v, dtype=np.float64)) for k, v in start_surprise.items()}
        return cls(np.asarray(arrays["variation_s"], dtype=np.float64), r, int(r.shape[0]) - 2, scale,
                   float(shrinkage or 0.0), start_surprise=info)


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


def _start_scale(delta: np.ndarray) -> np.ndarray:
    """Each coordinate's RMS deviation at the start (6,) over the demonstrations δ (D, S, 6), about their
    mean (1 where the start does not vary): the start map's input units when it is told in the start's own
    units (:func:`start_map`, ``inputs="start"``)."""
    c0 = delta[:, 0] - delta[:, 0].mean(axis=0)
    scale = np.sqrt(np.mean(c0**2, axis=0))
    return np.where(scale > 1e-12, scale, 1.0)


#: The start map's input units (:func:`start_map`): each start coordinate over the deviations' RMS over
#: the whole path (``"path"``, the ridge's units since the map exists), or over its own spread at the start
#: (``"start"``).
START_INPUTS = ("path", "start")


def _ridge_map(delta: np.ndarray, scale: np.ndarray, lam: float, inputs: str = "path"):
    """μ (S, 6) and the ridge regression B (S, 6, 6) of the deviations δ (D, S, 6) at every phase on
    their start value, in coordinates scaled by ``scale`` (6,) (see :func:`start_map`); ``inputs="start"``
    measures the start's coordinates in their own spread at the start (:func:`_start_scale` of ``delta``)
    instead: x = c(0) / σ_0, B = C_sx (C_xx + λ I)⁻¹ / σ_0 (the ridge is per output row, so the outputs'
    units do not change it)."""
    mu = delta.mean(axis=0)
    S = delta.shape[1]
    if not np.isfinite(lam):
        return mu, np.zeros((S, 6, 6))
    if inputs == "start":
        sig0 = _start_scale(delta)
        c = delta - mu  # (D, S, 6), rad and m
        x0 = c[:, 0, :] / sig0
        D = len(delta)
        Cxx = x0.T @ x0 / D + lam * np.eye(6)
        Csx = np.einsum("dsi,dj->sij", c, x0) / D
        B = np.linalg.solve(Cxx.T, Csx.transpose(0, 2, 1)).transpose(0, 2, 1)
        return mu, np.ascontiguousarray(B / sig0[None, None, :])
    if inputs != "path":
        raise ValueError(f"unknown start-map inputs {inputs!r}; expected one of {START_INPUTS}")
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

    with μ the mean deviation, C_s0 = mean_d c_d(s) x_dᵀ, C_00 = mean_d x_d x_dᵀ, c_d = δ_d − μ and
    x_d = c_d(0) / σ per start coordinate (B is returned in physical units, rad and m). Every coordinate
    of the start informs every coordinate of the motion, as a ProMP's conditioning does (there the
    regulariser is the weight prior). The ridge needs units for the start's coordinates: σ is each
    coordinate's RMS deviation over the whole path (``inputs="path"``), so that one λ suits radians and
    metres; or its spread at the start alone (``inputs="start"``), which lets a start coordinate that
    varies little at the start but much later (the hand raises' start rotation: its spread at the start
    is a fraction of its spread over the motion) inform the motion instead of being regularised away.

    λ is chosen from ``grid`` by cross-validation over ``folds`` folds of whole demonstrations (squared
    error of the held-out deviations over all phases after the start, each coordinate over its RMS over
    the path); λ = ∞ (no conditioning) competes, so a start that tells nothing about the rest of the
    motion leaves the mean path. The units: ``"path"`` with its best λ, unless ``"start"``'s best λ
    predicts the held-out demonstrations better by more than one standard error of the mean of their
    paired differences (per demonstration, the same folds): the one-standard-error rule, so the choice
    changes only where the data say so clearly (measured in docs/defaults.md, issue 36's third pass).
    Returns ``{"mean": μ (S, 6), "map": B (S, 6, 6), "ridge": λ, "inputs": "path" or "start",
    "errors": per λ the held-out mean squared error with ``"path"``, "errors_start": the same with
    ``"start"``}``; with fewer than MIN_DEMOS + 1 demonstrations λ = ∞.
    """
    delta = np.asarray(delta, dtype=np.float64)
    D = len(delta)
    scale = _coordinate_scale(delta)
    grid = tuple(float(g) for g in grid)
    per_demo = {units: np.zeros((len(grid), D)) for units in START_INPUTS}
    inputs = "path"
    if D > MIN_DEMOS:
        k = min(int(folds), D)
        fold = np.empty(D, dtype=int)
        fold[np.random.default_rng(np.random.SeedSequence([int(seed), 17])).permutation(D)] = np.arange(D) % k
        for j in range(k):
            test = np.flatnonzero(fold == j)
            held, rest = delta[test], delta[fold != j]
            for units in START_INPUTS:
                for i, lam in enumerate(grid):
                    mu, B = _ridge_map(rest, scale, lam, units)
                    pred = mu[None] + np.einsum("sij,dj->dsi", B, held[:, 0, :] - mu[0])
                    # phase 0 is the start itself, known to the rollout: not a test of the map
                    per_demo[units][i, test] = np.sum(((pred[:, 1:] - held[:, 1:]) / scale) ** 2, axis=(1, 2))
        errors = {units: per_demo[units].sum(axis=1) / delta[:, 1:].size for units in START_INPUTS}
        best = int(np.argmin(errors["path"]))
        best_start = int(np.argmin(errors["start"]))
        gain = per_demo["path"][best] - per_demo["start"][best_start]  # > 0: the start's own units predict better
        se = float(np.std(gain, ddof=1)) / np.sqrt(D)
        if float(np.mean(gain)) > se:
            inputs, best = "start", best_start
    else:
        errors = {units: np.zeros(len(grid)) for units in START_INPUTS}
        best = grid.index(float("inf")) if float("inf") in grid else len(grid) - 1
    lam = grid[best]
    mu, B = _ridge_map(delta, scale, lam, inputs)
    return {"mean": mu, "map": B, "ridge": lam, "inputs": inputs, "errors": errors["path"].tolist(),
            "errors_start": errors["start"].tolist()}


def start_reach(delta: np.ndarray, start_mean: np.ndarray) -> np.ndarray:
    """How far the demonstrations went from the start-conditioned map's mean at each phase: (S, 2), per phase s
    the largest rotation angle and the largest position distance over the demonstrations d,

        ρ_rot(s) = max_d |c_d,rot(s)|,   ρ_pos(s) = max_d |c_d,pos(s)|,   c_d = δ_d − μ,

    of their deviations δ (D, S, 6) about μ (S, 6) (:func:`start_map`'s ``mean``). The start map is linear in
    the start, fitted on starts that may barely vary (handovers picked up from a rest within 2 mm): a start
    the map has never seen, centimetres or tens of their spreads off, is carried through the motion by gains
    that reach 30 and more, metres from every demonstration. The conditioned path's shift B(s)(δ(0) − μ(0)) is
    therefore bounded per phase and block by max(|its start offset|, ρ(s)) (``PathReference.conditioned_at``):
    no farther from the mean path than the farthest demonstration went there, or than the start itself is;
    a start within the demonstrations' keeps the linear map as it is (docs/method.md §7, "The map's reach")."""
    c = np.asarray(delta, dtype=np.float64) - np.asarray(start_mean, dtype=np.float64)[None]
    return np.stack([np.linalg.norm(c[..., :3], axis=-1).max(axis=0), np.linalg.norm(c[..., 3:], axis=-1).max(axis=0)],
                    axis=1)


def bound_shift(shift: np.ndarray, start: np.ndarray, reach: np.ndarray | None):
    """The start map's shift B(s) c bounded by the reach ρ(s) (:func:`start_reach`): per block b (rotation,
    position) scaled by k_b = min(1, max(|c_b|, ρ_b) / |(B c)_b|). ``shift`` (..., 6), ``start`` c (..., 6)
    and ``reach`` (..., 2) broadcast together (None: no bound). Returns (the bounded shift (..., 6), the
    factors k per coordinate (..., 6): k_b on each of its block's three, for the shift's slope)."""
    shift = np.asarray(shift, dtype=np.float64)
    if reach is None:
        return shift, np.ones_like(shift)
    start = np.asarray(start, dtype=np.float64)
    k = np.ones_like(shift)
    for b, sl in ((0, slice(0, 3)), (1, slice(3, 6))):
        size = np.linalg.norm(shift[..., sl], axis=-1)
        cap = np.maximum(np.linalg.norm(start[..., sl], axis=-1), np.asarray(reach)[..., b])
        k[..., sl] = np.where(size > cap, cap / np.where(size > 0, size, 1.0), 1.0)[..., None]
    return shift * k, k


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


def shrinkage(residuals: np.ndarray) -> float:
    """The weight α ∈ [0, 1] that shrinks the residuals' covariance between coordinates toward none,
    Σ_α = (1 − α) Σ + α diag(Σ) per phase (Schäfer & Strimmer 2005, target "D": the correlations
    shrunk toward 0, the variances kept), pooled over the phases s > 0:

        α = Σ_s Σ_{i≠j} Var̂(ρ̂_ij(s)) / Σ_s Σ_{i≠j} ρ̂_ij(s)²,

    ρ̂_ij the residuals' correlations at a phase (D/(D − 1) mean_d x_di x_dj, x the residuals over their
    RMS per coordinate) and Var̂ their estimated variance, D/(D − 1)³ Σ_d (x_di x_dj − mean)². With many
    demonstrations α is small; with few (3–6) the sample covariance of the 3 rotation coordinates has
    rank D − 2 at most and α keeps it from collapsing (:meth:`Variation.draw` draws the diagonal part
    with weights of its own per coordinate, so a draw stays one coherent function of phase).
    residuals : (D, S, 6) → α."""
    r = np.asarray(residuals, dtype=np.float64)[:, 1:]  # phase 0: r = 0
    D = len(r)
    if D < 2:
        return 1.0
    sd = np.sqrt(np.mean(r**2, axis=0))  # (S − 1, 6)
    ok = sd > 1e-12
    x = np.where(ok[None], r / np.where(ok, sd, 1.0)[None], 0.0)
    w = np.einsum("dsi,dsj->dsij", x, x)  # (D, S − 1, 6, 6)
    wbar = w.mean(axis=0)
    rho = wbar * D / (D - 1)
    var = np.sum((w - wbar[None]) ** 2, axis=0) * D / (D - 1) ** 3
    off = ~np.eye(6, dtype=bool)
    num, den = float(np.sum(var[:, off])), float(np.sum(rho[:, off] ** 2))
    if den <= 1e-300:
        return 1.0 if num > 0 else 0.0
    return float(np.clip(num / den, 0.0, 1.0))


def _shrunk(cov: np.ndarray, alpha: float) -> np.ndarray:
    """(1 − α) C + α diag(C) over the last two axes of covariances C (..., 6, 6)."""
    if alpha <= 0.0:
        return cov
    diag = np.einsum("...ii->...i", cov)
    return (1.0 - alpha) * cov + alpha * (diag[..., :, None] * np.eye(cov.shape[-1]))


def start_covariance(c0: np.ndarray) -> np.ndarray:
    """Σ_0 (6, 6) of the centred start deviations c0 (m, 6) (rad, m): their covariance Σ c cᵀ / (m − 1), its
    correlations shrunk by Schäfer–Strimmer's α (:func:`shrinkage`), plus the tracker's tolerance
    (paths.GOAL_TOLERANCE, one standard deviation) on the diagonal, so that a coordinate the demonstrations
    all started at alike does not make every other start infinitely surprising."""
    from rbgp_cli.dynamics.paths import GOAL_TOLERANCE

    c0 = np.asarray(c0, dtype=np.float64)
    m = len(c0)
    alpha = shrinkage(np.stack([np.zeros_like(c0), c0], axis=1))
    tol = np.array([GOAL_TOLERANCE[0]] * 3 + [GOAL_TOLERANCE[1]] * 3) ** 2
    return _shrunk(c0.T @ c0 / max(m - 1, 1), alpha) + np.diag(tol)


def start_surprise(c: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """ρ = cᵀ Σ_0⁻¹ c / 6 (...,) of start deviations c (..., 6) about the mean start, against Σ_0 ``cov`` (6, 6)
    (:func:`start_covariance`): the start's squared Mahalanobis distance per coordinate."""
    c = np.asarray(c, dtype=np.float64)
    return np.einsum("...i,...i->...", c, np.linalg.solve(cov, c.reshape(-1, 6).T).T.reshape(c.shape)) / 6.0


def _held_out_errors(delta: np.ndarray, s: np.ndarray, train: np.ndarray, test: np.ndarray, *, ridge: float,
                     gain: float, scale: np.ndarray, alpha: float | None = None, inputs: str = "path"):
    """The errors of the demonstrations ``test`` predicted from those in ``train`` as a rollout predicts
    them (:func:`band_scale`): (m2 (T, S − 1) the squared Mahalanobis rotation errors, z (T, S − 1, 3)
    the position errors per axis over their standard deviations) against the covariance the draws of
    the training demonstrations' own deviation process would have, C = (1 + 1/m)/ν Σ_α (the Student-t
    draws' scale matrix; :func:`band_scale`), Σ_α the shrunk Σ r rᵀ of their start-regression residuals
    (:func:`shrinkage`; α from them unless given), m of them and ν = m − 2), and rho (T,) the held-out
    starts' surprise against the training ones' (:func:`start_surprise`). ``inputs``: the start map's units
    (:func:`start_map`), as the model's."""
    rest = delta[train]
    m = len(rest)
    _, _, r = start_regression(rest)
    a = shrinkage(r) if alpha is None else float(alpha)
    C = _shrunk(np.einsum("dsi,dsj->sij", r[:, 1:], r[:, 1:]), a) * (1.0 + 1.0 / m) / (m - 2)
    mu, B = _ridge_map(rest, scale, ridge, inputs)
    held = delta[test]
    c0 = held[:, 0] - mu[0]
    rho = start_surprise(c0, start_covariance(rest[:, 0] - mu[0]))
    shift, _ = bound_shift(np.einsum("sij,dj->dsi", B, c0), c0[:, None], start_reach(rest, mu)[None])  # as a rollout
    e = held - mu[None] - shift  # (T, S, 6)
    decay = np.exp(-float(gain) * np.asarray(s, dtype=np.float64))[1:, None]
    e = e[:, 1:] - decay[None] * e[:, :1]
    Cr = C[:, :3, :3]
    tr = np.trace(Cr, axis1=1, axis2=2)[:, None, None] / 3.0
    Cr = Cr + (1e-9 * tr + 1e-24) * np.eye(3)
    m2 = np.einsum("dsi,dsi->ds", e[..., :3], np.linalg.solve(Cr[None], e[..., :3, None])[..., 0])
    sd = np.sqrt(np.maximum(np.einsum("sii->si", C[:, 3:, 3:]), 1e-24))
    return m2, np.abs(e[..., 3:]) / sd[None], rho


def band_quantiles(dof: int, level: float = BAND_LEVEL) -> tuple[float, float]:
    """(q_rot, q_pos): the ``level`` quantiles of the Student-t predictive with ``dof`` = ν degrees of
    freedom: of a rotation's squared Mahalanobis distance against the scale matrix, 3 F_level(3, ν)
    (m²/3 of a trivariate t is F(3, ν)), and of one position coordinate's |t|, t_ν,(1+level)/2."""
    from scipy.special import fdtri, stdtrit  # the quantiles alone, without scipy.stats' import (1.6 s here)

    nu = max(int(dof), 1)
    return 3.0 * float(fdtri(3, nu, level)), float(stdtrit(nu, 0.5 + level / 2.0))


def _scores(delta: np.ndarray, s: np.ndarray, splits, *, ridge: float, gain: float, level: float,
            inputs: str = "path"):
    """The left-out errors of every (train, test) split in ``splits`` against the band of the model of
    its training demonstrations (:func:`_held_out_errors`), in units of that band's own Student-t
    quantiles (ν = m − 2 of its m): rotation m² / (3 F(3, ν)) (N, S − 1) and position |z| / t_ν (N, S − 1, 3),
    the N left-out demonstrations of all splits stacked, and their starts' surprise ρ (N,)."""
    scale = _coordinate_scale(delta)
    m2, z, rho = [], [], []
    for train, test in splits:
        a, b, c = _held_out_errors(delta, s, train, test, ridge=ridge, gain=gain, scale=scale, inputs=inputs)
        q_rot, q_pos = band_quantiles(len(train) - 2, level)
        m2.append(a / q_rot)
        z.append(b / q_pos)
        rho.append(c)
    return np.concatenate(m2), np.concatenate(z), np.concatenate(rho)


def _factors(m2: np.ndarray, z: np.ndarray, level: float, widen=None) -> tuple[float, float]:
    """(c_rot, c_pos) ≥ 1 that put the ``level`` quantile of the normalised errors (:func:`_scores`: m2
    (N, S − 1), z (N, S − 1, 3)) on the bands' edge, each left-out row's errors divided by its own widening
    ``widen`` (N,) (None: 1)."""
    if widen is not None:
        w = np.asarray(widen, dtype=np.float64)
        m2, z = m2 / w[:, None] ** 2, z / w[:, None, None]
    c_rot = np.sqrt(np.quantile(np.ravel(m2), level))
    c_pos = np.quantile(np.ravel(z), level)
    return max(1.0, float(c_rot)), max(1.0, float(c_pos))


#: Contiguous blocks in recording order that :func:`band_calibration` leaves out in turn (with at least
#: BLOCK_MIN demonstrations in each; fewer demonstrations are left out one at a time only).
ORDER_BLOCKS = 5
BLOCK_MIN = 2


def _order_blocks(D: int, blocks: int):
    """The (train, test) splits of :func:`band_calibration`'s blocks in recording order, or None."""
    k = min(int(blocks), D // BLOCK_MIN)
    if k >= 2 and D - int(np.ceil(D / k)) >= MIN_BAND_DEMOS - 1:
        return [(np.setdiff1d(np.arange(D), test), test) for test in np.array_split(np.arange(D), k)]
    return None


def band_calibration(delta: np.ndarray, s: np.ndarray, *, ridge: float = float("inf"), gain: float = 0.0,
                     level: float = BAND_LEVEL, blocks: int = ORDER_BLOCKS, inputs: str = "path",
                     surprise: bool = True) -> dict:
    """The bands' factors from the demonstrations left out, at random and in recording order
    (docs/method.md §11, "The bands' scale"; the rows of ``delta`` (D, S, 6) are in recording order).

    ``random``: each demonstration left out in turn (:func:`band_scale`); ``recorded``: ``blocks``
    contiguous blocks in recording order left out in turn (each at least BLOCK_MIN long), each predicted
    from the others: what the next session meets when the demonstrations drift over the session (its
    neighbours in time are not in the training set). Each left-out error is measured against the band of
    the model without it (:func:`_scores`), each kind gives its factors, and the bands cover both: c = the
    larger of the two per rotation and position. (The quantile of both kinds' errors together was tried:
    on the 40 hand raises' blocks the bands then held 0.87 / 0.85 against 0.89 / 0.87, at random 0.92 /
    0.93 against 0.93 / 0.94.)

    The start's surprise (module docstring), from START_SURPRISE_FROM demonstrations on: each left-out error
    divided by its start's widening s = √max(1, ρ / ρ̄) (ρ̄ the START_SURPRISE_QUANTILE quantile of the ρ of
    those left out one at a time) gives the factors c' of the widened bands, c' s wide. The widening is kept,
    for the rotation and the position part each, where it makes that part's left-out bands narrower at the
    same level:

        log mean(c'_rot s) < log c_rot   (and likewise in position)

    over every left-out demonstration (both kinds), i.e. where the start's surprise says which motions need
    the wider band. Where it does not (the handovers: starts at rest within millimetres, whose ρ has no rank
    correlation with the need; a part whose factor is 1 already), widening some would only add width, as the
    factors cannot fall below 1.

    The widening of a start beyond every left-out demonstration's (ρ > ρ_max, :meth:`Variation.start_widening`)
    is not part of this calibration: the factors are those of the demonstrations as they are, and a start beyond
    them all is widened on top (dividing the left-out errors by it too was measured: it narrowed the 10 waves'
    random folds to 0.855 / 0.900 and the hand raises' next session; docs/defaults.md, eighteenth pass).

    Returns ``{"band_scale": (c_rot, c_pos), "random": (…), "recorded": (…) or None, "shrinkage": α,
    "surprise_reference": ρ̄ or None (kept for neither part), "surprise_parts": (rotation, position) whether
    each part widens, "surprise_width": ((without), (with)) each part's mean log width, or None,
    "start_surprises": (D,) each demonstration's start ρ left out against the others' (their largest is ρ_max,
    :meth:`Variation.start_widening`), or None}``; (1, 1) with
    fewer than MIN_BAND_DEMOS demonstrations. ``ridge``, ``inputs``: the start map's λ and units
    (:func:`start_map`); ``gain`` the pull's constant a; ``surprise`` False: the factors without the start's
    surprise, whatever the number of demonstrations."""
    delta = np.asarray(delta, dtype=np.float64)
    D = len(delta)
    _, _, r = start_regression(delta)
    alpha = shrinkage(r)
    out = {"band_scale": (1.0, 1.0), "random": None, "recorded": None, "shrinkage": alpha,
           "surprise_reference": None, "surprise_parts": (False, False), "surprise_width": None,
           "start_surprises": None}
    if D < MIN_BAND_DEMOS:
        return out
    loo = [(np.setdiff1d(np.arange(D), [d]), np.array([d])) for d in range(D)]
    kinds = [_scores(delta, s, loo, ridge=ridge, gain=gain, level=level, inputs=inputs)]
    out["start_surprises"] = kinds[0][2]  # each start left out against the others' mean and Σ_0
    split = _order_blocks(D, blocks)
    if split is not None:
        kinds.append(_scores(delta, s, split, ridge=ridge, gain=gain, level=level, inputs=inputs))

    def calibrated(ref):  # the factors of each kind and the mean log width of each part, with the widening at ref
        w = [np.ones(len(rho)) if ref is None else surprise_scale(rho, ref) for _, _, rho in kinds]
        per = [_factors(m2, z, level, wk) for (m2, z, _), wk in zip(kinds, w)]
        c = (max(f[0] for f in per), max(f[1] for f in per))
        w = np.concatenate(w)
        return per, c, (float(np.log(np.mean(c[0] * w))), float(np.log(np.mean(c[1] * w))))

    per, c, width = calibrated(None)
    if surprise and D >= START_SURPRISE_FROM:
        ref = float(np.quantile(kinds[0][2], START_SURPRISE_QUANTILE))
        per_s, c_s, width_s = calibrated(ref)
        keep = [width_s[j] < width[j] for j in (0, 1)]  # rotation, position
        out["surprise_width"] = (width, width_s)
        if any(keep):  # each part's factors from the calibration it keeps (a factor is one part's quantile)
            per = [tuple(fs[j] if keep[j] else f[j] for j in (0, 1)) for f, fs in zip(per, per_s)]
            c = tuple(c_s[j] if keep[j] else c[j] for j in (0, 1))
            out["surprise_reference"] = ref
            out["surprise_parts"] = tuple(bool(k) for k in keep)
    out["random"] = per[0]
    out["recorded"] = per[1] if len(per) > 1 else None
    out["band_scale"] = c
    return out


def band_scale(delta: np.ndarray, residuals: np.ndarray, s: np.ndarray, *, ridge: float = float("inf"),
               gain: float = 0.0, level: float = BAND_LEVEL, inputs: str = "path") -> tuple[float, float]:
    """The factors (c_rot, c_pos) ≥ 1 on the band's rotation and position that make the ``level`` bands
    hold the demonstrations, each left out in turn (module docstring, "The bands' scale").

    delta : (D, S, 6) the deviations (:func:`demonstration_deviations`); residuals : unused (kept for
    callers; the left-out models refit their own); s : (S,) the grid. ridge : λ of the start map the mean
    rollout follows (:func:`start_map`; ∞: the mean deviation, no conditioning); gain : the prior's pull
    a per unit phase, which closes a start's gap to that map's prediction as exp(−a·s) (0: the gap
    stays). The left-out demonstration's error is e_d(s) = δ_d(s) − m_−d(s) − exp(−a·s) (δ_d(0) − m_−d(0)),
    m_−d the map fitted without it, against the band of the D − 1 others: scale matrix
    C_−d = (1 + 1/m)/(m − 2) Σ_α,−d (m = D − 1, Σ_α,−d their start-regression residuals' shrunk Σ r rᵀ,
    α their own) and the Student-t quantiles with ν = m − 2 (:func:`band_quantiles`). Returns (1, 1) for
    fewer than MIN_BAND_DEMOS demonstrations (one left out must leave three).
    """
    delta = np.asarray(delta, dtype=np.float64)
    D = len(delta)
    if D < MIN_BAND_DEMOS:
        return 1.0, 1.0
    loo = [(np.setdiff1d(np.arange(D), [d]), np.array([d])) for d in range(D)]
    return _factors(*_scores(delta, s, loo, ridge=ridge, gain=gain, level=level, inputs=inputs)[:2], level)


#: Reorderings of the demonstrations that :func:`order_drift`'s permutation test draws.
DRIFT_PERMUTATIONS = 999
#: :func:`order_drift` calls a drift significant below this p-value (a permutation test: on
#: exchangeable demonstrations it fires at most this often, tests/dynamics/test_order_drift.py).
DRIFT_P = 0.01
#: Fewer demonstrations than this are not tested for drift.
MIN_DRIFT_DEMOS = 6


def order_drift(delta: np.ndarray, durations, *, seed: int = 0, permutations: int = DRIFT_PERMUTATIONS) -> dict | None:
    """Do the demonstrations drift over the recording order (the rows of ``delta``, (D, S, 6))?

    Each demonstration is summarised by 13 features f_dj: its start-conditioned deviation r_d
    (:func:`start_regression`) averaged over phase (6), its start deviation δ_d(0) (6) and its log
    duration. The statistic is the smallest over the features of von Neumann's ratio of successive
    differences to the spread,

        T = min_j Σ_d (f_{d+1, j} − f_{d, j})² / Σ_d (f_{d, j} − f̄_j)²,

    each ratio about 2 for demonstrations in no particular order and small when neighbours in time
    resemble each other (a trend, or sessions), in any one of the features. Its p-value is from ``permutations`` seeded random reorderings
    (p = (1 + #{T_π ≤ T}) / (1 + P)): exact for exchangeable demonstrations whatever their distribution.

    The figures say how large the drift is: the least-squares line of each deviation δ_dj(s) and of the
    duration over the order index, from the first demonstration to the last: ``position_m`` and
    ``rotation_rad``, the path's largest change over phase (norm over x, y, z; at phase
    ``position_phase``, ``rotation_phase``), ``start_m`` the start position's, and ``duration_s``
    (first, last) the fitted durations. Returns
    ``{"statistic", "p_value", "drift": p < DRIFT_P, …}``, or None for fewer than MIN_DRIFT_DEMOS.
    """
    delta = np.asarray(delta, dtype=np.float64)
    dur = np.asarray(durations, dtype=np.float64)
    D = len(delta)
    if D < MIN_DRIFT_DEMOS or len(dur) != D:
        return None
    scale = _coordinate_scale(delta)
    _, _, r = start_regression(delta)
    logd = np.log(np.maximum(dur, 1e-9))
    F = np.concatenate([r.mean(axis=1) / scale, delta[:, 0] / scale, logd[:, None]], axis=1)
    F = F - F.mean(axis=0)
    sd = F.std(axis=0)
    F = F[:, sd > 1e-12] / sd[sd > 1e-12]
    if F.shape[1] == 0:
        return None

    def ratio(G):  # the smallest of the features' ratios: a drift of any one of them
        return float(np.min(np.sum(np.diff(G, axis=0) ** 2, axis=0) / np.sum(G**2, axis=0)))

    T = ratio(F)
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 36]))
    perm = np.array([ratio(F[rng.permutation(D)]) for _ in range(int(permutations))])
    p = float((1 + np.sum(perm <= T)) / (1 + len(perm)))
    o = np.arange(D, dtype=np.float64) - (D - 1) / 2.0
    slope = np.einsum("d,dsj->sj", o, delta - delta.mean(axis=0)) / np.sum(o**2)  # per order step
    change = slope * (D - 1)  # first → last
    pos, rot = np.linalg.norm(change[:, 3:], axis=1), np.linalg.norm(change[:, :3], axis=1)  # (S,)
    dslope = float(np.sum(o * (dur - dur.mean())) / np.sum(o**2))
    return {
        "statistic": T, "p_value": p, "drift": bool(p < DRIFT_P), "demos": int(D),
        "position_m": float(np.max(pos)), "position_phase": float(np.argmax(pos) / max(len(pos) - 1, 1)),
        "rotation_rad": float(np.max(rot)), "rotation_phase": float(np.argmax(rot) / max(len(rot) - 1, 1)),
        "start_m": float(np.linalg.norm(change[0, 3:])),
        "duration_s": [float(dur.mean() - dslope * (D - 1) / 2.0), float(dur.mean() + dslope * (D - 1) / 2.0)],
    }


def demonstration_variation(trajs: list[Trajectory], steps: int = STEPS, *, ridge: float = float("inf"),
                            gain: float = 0.0, inputs: str = "path") -> Variation | None:
    """The deviation process of clean demonstrations in recording order (module docstring), or None for
    fewer than MIN_DEMOS of them; ``ridge``, ``inputs`` (the start map's, :func:`start_map`) and ``gain``
    describe the mean rollout for the bands' scale (:func:`band_calibration`: the demonstrations left out at random and in recording order), and
    :func:`order_drift` says whether they drift over the recording order."""
    trajs = list(trajs)
    D = len(trajs)
    if D < MIN_DEMOS:
        return None
    path, delta = demonstration_deviations(trajs, steps)
    _, _, r = start_regression(delta)
    s = np.asarray(path["s"], dtype=np.float64)
    cal = band_calibration(delta, s, ridge=ridge, gain=gain, inputs=inputs)
    drift = order_drift(delta, [tr.duration for tr in trajs])
    plain = {"random": None if cal["random"] is None else list(cal["random"]),
             "recorded": None if cal["recorded"] is None else list(cal["recorded"])}
    if cal["surprise_width"] is not None:  # whether the start's surprise widens the bands, and why (band_calibration)
        w0, w1 = cal["surprise_width"]
        plain["start_widening"] = {"rotation": bool(cal["surprise_parts"][0]),
                                   "position": bool(cal["surprise_parts"][1]),
                                   "mean_width_ratio": [float(np.exp(w1[j] - w0[j])) for j in (0, 1)]}
    surprise = None
    if D >= START_BEYOND_FROM:  # the start's surprise (module docstring): ρ_max always, ρ̄ where it is kept
        mu0 = delta[:, 0].mean(axis=0)
        ref = cal["surprise_reference"]
        surprise = {"quat": np.asarray(path["quat"][0], dtype=np.float64),
                    "position": np.asarray(path["position"][0], dtype=np.float64), "mean": mu0,
                    "covariance": start_covariance(delta[:, 0] - mu0), "reference": None if ref is None else float(ref),
                    "parts": [bool(k) for k in cal["surprise_parts"]],
                    # at least 1, a start's ρ within the tracker's tolerance (Σ_0's diagonal floor): demonstrations
                    # that all start alike leave ρ_max at 0, and a start off them by the tolerance is not beyond
                    "beyond": max(1.0, float(np.max(cal["start_surprises"])))}
    return Variation(s=s, residuals=r, dof=D - 2, band_scale=cal["band_scale"], shrinkage=cal["shrinkage"],
                     calibration=plain, drift=drift, start_surprise=surprise)
