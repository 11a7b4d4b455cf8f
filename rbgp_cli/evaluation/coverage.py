"""Do the bands hold? The calibration of sampled rollouts against a real motion from the same start
(docs/method.md §11, "Calibration measure"; issue 20).

K sampled rollouts from one start and the real motion from that start are resampled to the same T
steps of normalised time (:func:`rbgp_cli.evaluation.resample.resample_all`). At every step:

- **position**, per axis: the 90 % prediction interval for a new draw from the samples' Gaussian,
  x̄ ± t_{K−1, 0.95} · s · √(1 + 1/K) (s the samples' standard deviation, ddof = 1);
- **rotation**: tangent vectors v_k = log(R̄ᵀ R_k) at the samples' chordal mean R̄
  (:func:`rbgp_cli.evaluation.resample.mean_rotation`), and the real motion's v inside the 90 %
  prediction ellipsoid (v − v̄)ᵀ S⁻¹ (v − v̄) ≤ (K+1)(K−1)·3 / (K(K−3)) · F_{0.90}(3, K−3)
  (Hotelling; S the samples' covariance, ddof = 1).

Coverage is the fraction of steps (position: steps × axes) inside; a perfect Gaussian model has 0.90.

A model that gives its band directly (rbgp's sampled rollouts: the predictive's 90 % region around the
mean rollout, :meth:`rbgp_cli.dynamics.variation.Variation.region`) is measured with that band instead
(:func:`band_coverage`): its samples are typical motions, narrower than the next motion's band, and a
band is what a user gets.
Its standard error (:func:`coverage_se`) is taken over the held-out motions, not the steps: a motion's
steps lie inside or outside together, so ten motions of a hundred steps each are ten observations, not a
thousand.

It comes with the band's width (position: the mean half-width in metres; rotation: the mean radius
√(threshold · λ) of the ellipsoid, averaged over its three axes, in radians): a band is useful only when
it is both honest and narrow.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rbgp_cli.dynamics.trajectory import Trajectory
from rbgp_cli.evaluation.resample import mean_rotation, resample_all, tangent_features

__all__ = ["Coverage", "prediction_coverage", "band_coverage", "band_thresholds", "coverage_se", "LEVEL",
           "MIN_SAMPLES"]

#: The nominal level of the prediction region.
LEVEL = 0.90
#: The rotation's Hotelling region needs K − 3 > 0 degrees of freedom (and a covariance of rank 3).
MIN_SAMPLES = 4
#: Ridge added to the samples' rotation covariance, relative to its trace / 3 (and at least 1e-12 rad²),
#: so that K samples that coincide give a finite (tiny) region rather than a singular one.
RIDGE = 1e-9


@dataclass
class Coverage:
    """Calibration of K samples against one or more real motions (sums, so that starts pool).

    ``position_inside`` / ``position_count``: steps × axes inside the position intervals, out of;
    ``rotation_inside`` / ``rotation_count``: steps inside the rotation ellipsoid, out of;
    ``position_width_sum``, ``rotation_width_sum``: sums of the half-widths (m, rad) over the same counts
    (the rotation's over steps). Add two with ``+``.
    """

    position_inside: int = 0
    position_count: int = 0
    rotation_inside: int = 0
    rotation_count: int = 0
    position_width_sum: float = 0.0
    rotation_width_sum: float = 0.0

    def __add__(self, other: "Coverage") -> "Coverage":
        return Coverage(*(a + b for a, b in zip(self.astuple(), other.astuple())))

    def astuple(self) -> tuple:
        return (self.position_inside, self.position_count, self.rotation_inside, self.rotation_count,
                self.position_width_sum, self.rotation_width_sum)

    def to_dict(self) -> dict:
        """``coverage_position``, ``coverage_rotation`` (fractions, NaN without data) and the bands' mean
        half-widths ``band_position`` (m) and ``band_rotation`` (rad)."""
        def frac(a, b):
            return float(a) / b if b else float("nan")

        return {"coverage_position": frac(self.position_inside, self.position_count),
                "coverage_rotation": frac(self.rotation_inside, self.rotation_count),
                "band_position": frac(self.position_width_sum, self.position_count),
                "band_rotation": frac(self.rotation_width_sum, self.rotation_count)}


def coverage_se(inside, count, groups=None) -> float | None:
    """The standard error of the pooled coverage p = Σ inᵢ / Σ nᵢ over M independent units (held-out motions).

    ``inside``, ``count``: (E,) steps inside and steps scored per entry; ``groups``: (E,) the unit of each
    entry (e.g. a demonstration's index; None: every entry its own unit). Entries of one unit are summed
    first, inᵢ = Σ in, nᵢ = Σ n over its entries (a motion held out by R repeats counts once, its R rollouts
    pooled as its coverage pools them; the pooled p is unchanged by the grouping). Then the ratio
    estimator's standard error (Cochran 1977, §6.3, without the finite-population factor)

        SE = √( Σᵢ (inᵢ − p nᵢ)² / (M (M − 1)) ) / n̄,   n̄ = Σ nᵢ / M,

    with nᵢ all equal the standard error of the mean of the per-motion coverages inᵢ / nᵢ. It treats the
    units as independent (motions held out in one fold share a model, which this does not see) and the
    steps within a unit as wholly dependent. None when M < 2 or nothing was scored; 0 when every unit has
    the same coverage."""
    a = np.asarray(inside, dtype=np.float64).ravel()
    n = np.asarray(count, dtype=np.float64).ravel()
    if a.shape != n.shape:
        raise ValueError(f"coverage_se needs inside and count of one shape, got {a.shape} and {n.shape}")
    if groups is not None:
        g = np.asarray(groups).ravel()
        if g.shape != a.shape:
            raise ValueError(f"coverage_se needs one group per entry, got {g.shape} for {a.shape}")
        _, unit = np.unique(g, return_inverse=True)
        a, n = np.bincount(unit, weights=a), np.bincount(unit, weights=n)
    M = len(a)
    if M < 2 or n.sum() <= 0:
        return None
    p = a.sum() / n.sum()
    return float(np.sqrt(np.sum((a - p * n) ** 2) / (M * (M - 1))) / (n.sum() / M))


def band_thresholds(K: int, level: float = LEVEL) -> tuple[float, float]:
    """(t factor, Hotelling threshold) of the level-``level`` prediction regions for a new draw given K
    samples: t_{K−1, (1+level)/2} · √(1 + 1/K) for one axis, and (K+1)(K−1)·3 / (K(K−3)) · F_level(3, K−3)
    for the squared Mahalanobis distance of a 3-vector."""
    from scipy import stats

    if K < MIN_SAMPLES:
        raise ValueError(f"prediction regions need at least {MIN_SAMPLES} samples, got {K}")
    t = float(stats.t.ppf(0.5 + level / 2.0, K - 1)) * np.sqrt(1.0 + 1.0 / K)
    h = (K + 1) * (K - 1) * 3.0 / (K * (K - 3)) * float(stats.f.ppf(level, 3, K - 3))
    return t, h


def prediction_coverage(samples: list[Trajectory], reference: Trajectory, T: int, level: float = LEVEL) -> Coverage:
    """Coverage of ``reference`` by the prediction regions of ``samples`` (K ≥ MIN_SAMPLES trajectories
    from its start), all resampled to ``T`` steps of normalised time. See the module docstring."""
    K = len(samples)
    t_factor, h = band_thresholds(K, level)
    qs, ps = resample_all(samples, T)  # (K, T, 4), (K, T, 3)
    qr, pr = resample_all([reference], T)  # (1, T, 4), (1, T, 3)
    # position, per axis
    mean = ps.mean(axis=0)
    half = t_factor * ps.std(axis=0, ddof=1)  # (T, 3)
    pos_in = int(np.sum(np.abs(pr[0] - mean) <= half))
    # rotation, in the tangent space at the samples' chordal mean
    ref = mean_rotation(qs)  # (T, 4)
    v = tangent_features(qs, ps, ref)[..., :3]  # (K, T, 3)
    v0 = tangent_features(qr, pr, ref)[0, :, :3]  # (T, 3)
    vbar = v.mean(axis=0)
    D = v - vbar
    S = np.einsum("kti,ktj->tij", D, D) / (K - 1)  # (T, 3, 3)
    ridge = np.maximum(RIDGE * np.trace(S, axis1=1, axis2=2) / 3.0, 1e-12)
    S = S + ridge[:, None, None] * np.eye(3)
    e = v0 - vbar
    m2 = np.einsum("ti,ti->t", e, np.linalg.solve(S, e[..., None])[..., 0])
    rot_in = int(np.sum(m2 <= h))
    radius = np.sqrt(h * np.clip(np.linalg.eigvalsh(S), 0.0, None)).mean(axis=1)  # (T,)
    return Coverage(position_inside=pos_in, position_count=int(half.size), rotation_inside=rot_in,
                    rotation_count=int(T), position_width_sum=float(np.sum(half)), rotation_width_sum=float(np.sum(radius)))


def band_coverage(mean: Trajectory, band_position: np.ndarray, band_rotation: np.ndarray, reference: Trajectory,
                  T: int) -> Coverage:
    """Coverage of ``reference`` by a band given around a ``mean`` trajectory (N samples): position
    half-widths ``band_position`` (N, 3) m and rotation regions ``band_rotation`` (N, 3, 3) rad², the
    region {e : eᵀ M⁻¹ e ≤ 1} of e = log(R R_meanᵀ) (world frame), each on the mean's own samples.
    Both trajectories are resampled to ``T`` steps of normalised time and the band interpolated linearly
    to the same instants; the widths are as :func:`prediction_coverage`'s (mean half-width; mean
    radius √λ over the region's three axes)."""
    from rbgp_cli.geometry.so3 import log_quat, quat_conjugate, quat_multiply

    qm, pm = resample_all([mean], T)
    qr, pr = resample_all([reference], T)
    t = np.asarray(mean.t, dtype=np.float64)
    x = t[0] + np.linspace(0.0, 1.0, T) * (t[-1] - t[0])
    bp = np.asarray(band_position, dtype=np.float64).reshape(len(t), 3)
    bm = np.asarray(band_rotation, dtype=np.float64).reshape(len(t), 9)
    half = np.stack([np.interp(x, t, bp[:, j]) for j in range(3)], axis=1)  # (T, 3)
    M = np.stack([np.interp(x, t, bm[:, j]) for j in range(9)], axis=1).reshape(T, 3, 3)
    ridge = np.maximum(RIDGE * np.trace(M, axis1=1, axis2=2) / 3.0, 1e-24)
    M = M + ridge[:, None, None] * np.eye(3)
    e_pos = pr[0] - pm[0]
    e_rot = log_quat(quat_multiply(qr[0], quat_conjugate(qm[0])))  # (T, 3), world frame
    m2 = np.einsum("ti,ti->t", e_rot, np.linalg.solve(M, e_rot[..., None])[..., 0])
    radius = np.sqrt(np.clip(np.linalg.eigvalsh(M), 0.0, None)).mean(axis=1)
    return Coverage(position_inside=int(np.sum(np.abs(e_pos) <= half)), position_count=int(half.size),
                    rotation_inside=int(np.sum(m2 <= 1.0)), rotation_count=int(T),
                    position_width_sum=float(np.sum(half)), rotation_width_sum=float(np.sum(radius)))
