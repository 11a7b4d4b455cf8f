"""Bhattacharyya distance between generated motions and the demonstrations (docs/method.md §9, paper sec. 4.3).

For two Gaussians N(μ1, S1), N(μ2, S2) in R^k, with Σ = (S1 + S2)/2 and Δ = μ1 − μ2,

    D_B = ⅛ Δᵀ Σ⁻¹ Δ + ½ ln( det Σ / sqrt(det S1 · det S2) )          (Bhattacharyya 1943)

D_B >= 0, = 0 exactly for identical Gaussians, symmetric, and unchanged by any invertible affine map
``x -> A x + b`` applied to both (so the full-covariance score does not depend on the world frame).
For diagonal covariances it is a sum of per-dimension terms (1-D closed form)

    D_B,i = (μ1_i − μ2_i)² / (4 (v1_i + v2_i)) + ½ ln( (v1_i + v2_i) / (2 sqrt(v1_i v2_i)) ).

:func:`evaluate` resamples demonstrations and generated trajectories to T steps of normalised time,
takes the features ``x = (log(R̄_tᵀ R), p)`` in the tangent space at the demonstrations' mean
rotation R̄_t (:mod:`rbgp_cli.evaluation.resample`), fits one Gaussian per step and set (sample mean,
sample variance with ddof = 1, plus a small ridge on the diagonal) and reports D_B per step, its mean
over steps (the paper: 2.9 for the rigid-body GP vs 4.4 for the Euler GP on its shoe data), and the
rotation and translation parts separately.

Conventions: features are (rx, ry, rz, x, y, z), rotation first, radians and metres; the ridge is
absolute, in rad² for the rotation dimensions and m² for the translation ones.

How many trajectories a score needs (:func:`check_sample_sizes`): M trajectories give a per-step sample
covariance of rank at most M − 1, and the ridge stands in for every missing direction. ``"diag"``
needs M >= 2 per set (one trajectory has variance 0: the ridge alone); ``"full"`` needs M >= 7 for the
6×6 total and M >= 4 for its 3×3 rotation and translation parts. Below that the log-determinant term
of D_B is set by the ridge, not by the motions. With one demonstration the reference distribution is
the ridge itself and :func:`evaluate` refuses; every other shortfall (and sets whose spread is below
the ridge) is a warning, and the result says so (``reliable``, ``warnings``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from rbgp_cli.dynamics.trajectory import Trajectory
from rbgp_cli.errors import InputError, warn
from rbgp_cli.evaluation.resample import (
    _check_length,
    mean_rotation,
    normalised_time,
    resample_all,
    tangent_features,
)
from rbgp_cli.wording import plural

__all__ = [
    "bhattacharyya_gaussian",
    "bhattacharyya_diag",
    "EvaluationResult",
    "evaluate",
    "COVARIANCES",
    "DEFAULT_RIDGE",
    "MIN_TRAJECTORIES",
    "SampleSizeCheck",
    "check_sample_sizes",
    "MAX_UPSAMPLING",
    "bhattacharyya_diag_parts",
    "bhattacharyya_gaussian_parts",
]

#: Accepted values of ``evaluate(covariance=...)``.
COVARIANCES = ("diag", "full")
#: Default ridge added to every variance (rad² and m²): 1e-6 is (1 mrad)² and (1 mm)², below what
#: motion capture resolves, so it only matters where a set has (almost) no spread.
DEFAULT_RIDGE = 1e-6
#: Trajectories per set a per-step Gaussian needs before no direction of its covariance is the ridge
#: alone (rank M − 1 >= dimension): ``"diag"`` 2, ``"full"`` 7 (6×6) and 4 for its 3×3 parts.
MIN_TRAJECTORIES = {"diag": 2, "full": 7, "full_parts": 4}
#: A set whose sample variance is below the ridge in more than this fraction of its (step, dimension)
#: entries is reported as having (almost) no spread.
NO_SPREAD_FRACTION = 0.5
#: How :func:`evaluate` handles too few trajectories: raise + warn, warn, or only record in the result.
SAMPLE_SIZE_POLICIES = ("refuse", "warn", "record")
#: ``length`` may exceed the longest demonstration's sample count by at most this factor.
MAX_UPSAMPLING = 4

_LN2 = math.log(2.0)


def _log_cosh(y: np.ndarray) -> np.ndarray:
    """ln cosh y, accurate and >= 0 for every y (including ±inf).

    ``log1p(2 sinh²(y/2))`` for |y| < 1 (no cancellation near 0), ``|y| + log1p(e^{−2|y|}) − ln 2``
    otherwise (no overflow).
    """
    a = np.abs(y)
    small = a < 1.0
    with np.errstate(over="ignore", invalid="ignore"):
        near = np.log1p(2.0 * np.sinh(0.5 * np.where(small, a, 0.0)) ** 2)
        far = a + np.log1p(np.exp(-2.0 * np.where(small, 1.0, a))) - _LN2
    return np.where(small, near, far)


def bhattacharyya_diag(mu1, var1, mu2, var2) -> np.ndarray:
    """Per-dimension Bhattacharyya terms of two Gaussians with diagonal covariances.

    ``D_B,i = Δ_i² / (4 (v1_i + v2_i)) + ½ ln((v1_i + v2_i) / (2 sqrt(v1_i v2_i)))``; their sum over
    the last axis is D_B of the k-dimensional Gaussians. The log term is evaluated as
    ``½ ln cosh(½ ln(v1/v2))`` (the same quantity: (v1 + v2)/(2 sqrt(v1 v2)) = cosh(½ ln(v1/v2))),
    which is >= 0 and exactly 0 for v1 = v2, without round-off below zero.

    Degenerate variances: one variance 0 and the other > 0 gives +inf (the supports differ); both 0
    gives 0 if the means agree and +inf otherwise. Negative variances raise ValueError.

    Parameters
    ----------
    mu1, var1, mu2, var2 : array-like, shape (..., k)
        Means and variances (broadcast against each other).

    Returns
    -------
    ndarray, shape (..., k)
        Nonnegative terms.
    """
    offset, spread = bhattacharyya_diag_parts(mu1, var1, mu2, var2)
    return offset + spread


def bhattacharyya_diag_parts(mu1, var1, mu2, var2) -> tuple[np.ndarray, np.ndarray]:
    """The two parts of :func:`bhattacharyya_diag`, shapes (..., k) each: the *offset* (mean) part
    ``Δ_i² / (4 (v1_i + v2_i))`` and the *spread* (variance) part ``½ ln cosh(½ ln(v1_i/v2_i))``.
    The offset is 0 when the means agree, the spread when the variances do; their sum is D_B,i."""
    arrays = (np.asarray(a, dtype=np.float64) for a in (mu1, var1, mu2, var2))
    mu1, var1, mu2, var2 = np.broadcast_arrays(*arrays)
    if np.any(var1 < 0) or np.any(var2 < 0):
        raise ValueError("bhattacharyya_diag: variances must be >= 0")
    d2 = (mu1 - mu2) ** 2
    vs = var1 + var2
    both_zero = vs == 0
    with np.errstate(divide="ignore", invalid="ignore"):
        maha = np.where(both_zero, np.where(d2 == 0, 0.0, np.inf), d2 / (4.0 * np.where(both_zero, 1.0, vs)))
        y = 0.5 * (np.log(np.where(both_zero, 1.0, var1)) - np.log(np.where(both_zero, 1.0, var2)))
    logterm = 0.5 * _log_cosh(y)  # y = ±inf when exactly one variance is 0 -> +inf
    return maha, logterm


def _logdet_psd(S: np.ndarray) -> np.ndarray:
    """ln det of symmetric PSD matrices (..., k, k): ``2 Σ ln L_ii`` by Cholesky; if any matrix of the
    batch is singular, ``Σ ln λ_i`` by ``eigvalsh`` for the batch (−inf where an eigenvalue is <= 0)."""
    try:
        L = np.linalg.cholesky(S)
    except np.linalg.LinAlgError:
        lam = np.linalg.eigvalsh(S)
        logdet = np.sum(np.log(np.where(lam > 0, lam, 1.0)), axis=-1)
        return np.where(np.all(lam > 0, axis=-1), logdet, -np.inf)
    return 2.0 * np.sum(np.log(np.diagonal(L, axis1=-2, axis2=-1)), axis=-1)


def _not_psd_error() -> ValueError:
    return ValueError(
        "bhattacharyya_gaussian: (S1 + S2)/2 has a negative eigenvalue; covariances must be symmetric "
        "positive semi-definite"
    )


def bhattacharyya_gaussian(mu1, S1, mu2, S2) -> np.ndarray:
    """Bhattacharyya distance of two Gaussians with full covariances, batched over leading axes.

    ``D_B = ⅛ Δᵀ Σ⁻¹ Δ + ½ ln(det Σ / sqrt(det S1 det S2))``, ``Σ = (S1 + S2)/2``, ``Δ = μ1 − μ2``.

    Numerics: ``Σ = L Lᵀ`` (Cholesky), ``Δᵀ Σ⁻¹ Δ = ‖L⁻¹ Δ‖²`` (a sum of squares, never negative),
    ``ln det = 2 Σ ln L_ii`` for Σ, S1 and S2 alike, so no determinant is formed (nothing under- or
    overflows for small or large variances) and identical Gaussians give exactly 0 (then Σ = S1
    bit for bit). The log term is >= 0 in exact arithmetic (ln det is concave); round-off below 0 is
    clipped to 0.

    Degenerate covariances (only reached without a ridge; handled by ``eigh``/``eigvalsh`` instead
    of Cholesky): a singular S1 or S2 with a nonsingular Σ gives +inf (the supports differ); a
    singular Σ gives NaN; a Σ with a clearly negative eigenvalue (below −1e-12 of its largest) means
    an input was not a covariance: ValueError.

    Parameters
    ----------
    mu1, mu2 : array-like, shape (..., k)
    S1, S2 : array-like, shape (..., k, k)
        Symmetric positive (semi-)definite; everything broadcasts over the leading axes.

    Returns
    -------
    ndarray, shape (...)
    """
    offset, spread = bhattacharyya_gaussian_parts(mu1, S1, mu2, S2)
    return offset + spread


def bhattacharyya_gaussian_parts(mu1, S1, mu2, S2) -> tuple[np.ndarray, np.ndarray]:
    """The two parts of :func:`bhattacharyya_gaussian`, shapes (...) each: the *offset* (mean) part
    ``⅛ Δᵀ Σ⁻¹ Δ`` and the *spread* (covariance) part ``½ ln(det Σ / sqrt(det S1 det S2))``; their sum
    is D_B (NaN in both where Σ is singular)."""
    mu1 = np.asarray(mu1, dtype=np.float64)
    mu2 = np.asarray(mu2, dtype=np.float64)
    S1 = np.asarray(S1, dtype=np.float64)
    S2 = np.asarray(S2, dtype=np.float64)
    if mu1.ndim == 0 or mu2.ndim == 0 or mu1.shape[-1] != mu2.shape[-1]:
        raise ValueError(
            f"bhattacharyya_gaussian: means must have shape (..., k), got {mu1.shape} and {mu2.shape}"
        )
    k = mu1.shape[-1]
    for name, S in (("S1", S1), ("S2", S2)):
        if S.ndim < 2 or S.shape[-2:] != (k, k):
            raise ValueError(f"bhattacharyya_gaussian: {name} must have shape (..., {k}, {k}), got {S.shape}")
    batch = np.broadcast_shapes(mu1.shape[:-1], mu2.shape[:-1], S1.shape[:-2], S2.shape[:-2])
    delta = np.broadcast_to(mu1 - mu2, batch + (k,))
    S1 = np.broadcast_to(S1, batch + (k, k))
    S2 = np.broadcast_to(S2, batch + (k, k))
    Sigma = 0.5 * (S1 + S2)

    try:
        L = np.linalg.cholesky(Sigma)  # (..., k, k)
    except np.linalg.LinAlgError:
        L = None
    if L is not None:
        y = np.linalg.solve(L, delta[..., None])[..., 0]  # L⁻¹ Δ, (..., k)
        maha = np.einsum("...i,...i->...", y, y)
        logdet_sigma = 2.0 * np.sum(np.log(np.diagonal(L, axis1=-2, axis2=-1)), axis=-1)
        regular = np.ones(batch, dtype=bool)
    else:  # some Σ singular or not PSD: eigen-decomposition for the whole batch
        lam, V = np.linalg.eigh(Sigma)
        if np.any(lam[..., 0] < -1e-12 * np.maximum(np.abs(lam[..., -1]), np.finfo(float).tiny)):
            raise _not_psd_error()
        regular = lam[..., 0] > 0
        lam_safe = np.where(regular[..., None], lam, 1.0)
        z = np.einsum("...ji,...j->...i", V, delta)  # Vᵀ Δ
        maha = np.sum(z * z / lam_safe, axis=-1)
        logdet_sigma = np.sum(np.log(lam_safe), axis=-1)
    with np.errstate(invalid="ignore"):
        logterm = np.maximum(0.5 * (logdet_sigma - 0.5 * (_logdet_psd(S1) + _logdet_psd(S2))), 0.0)
    return np.where(regular, 0.125 * maha, np.nan), np.where(regular, logterm, np.nan)



@dataclass(frozen=True)
class SampleSizeCheck:
    """Whether two sets of M_G generated trajectories and M_D demonstrations can be scored with a
    covariance (plain data; see :func:`check_sample_sizes`).

    Attributes
    ----------
    refusal : str or None
        Why the score would be the ridge alone (one demonstration), or None.
    warnings : tuple of str
        One sentence per shortfall short of that, each saying how many trajectories are needed.
    needed : dict
        ``{"demos": k, "generated": k}``: how many of each the covariance needs.
    """

    refusal: str | None
    warnings: tuple
    needed: dict

    @property
    def reliable(self) -> bool:
        """True when both sets are large enough for every covariance that is fitted."""
        return self.refusal is None and not self.warnings


def check_sample_sizes(n_generated: int, n_demos: int, covariance: str = "diag",
                       ridge: float = DEFAULT_RIDGE) -> SampleSizeCheck:
    """Are ``n_generated`` and ``n_demos`` trajectories enough for per-step Gaussians with ``covariance``?

    M trajectories give a sample covariance of rank <= M − 1; the ridge fills the other directions,
    and there the log-determinant term ½ ln(det Σ / sqrt(det S1 det S2)) of D_B measures the ridge,
    not the motions. So ``"diag"`` needs M >= 2 per set and ``"full"`` M >= 7 (6×6 total; M >= 4 for
    the 3×3 rotation and translation parts) (:data:`MIN_TRAJECTORIES`).

    One demonstration is refused (the reference distribution is a point plus the ridge: every
    number it gives measures the ridge); fewer generated trajectories than needed, or fewer
    demonstrations than ``"full"`` needs, are warnings. Cheap (no data): callers such as
    cross-validation can check a split before generating anything.
    """
    if covariance not in COVARIANCES:
        raise InputError(f"unknown covariance {covariance!r}", hint="use 'diag' or 'full'")
    need = MIN_TRAJECTORIES[covariance]
    parts = MIN_TRAJECTORIES["full_parts"]
    refusal = None
    warnings_: list[str] = []
    if n_demos < MIN_TRAJECTORIES["diag"]:
        refusal = (
            f"cannot score against {plural(n_demos, 'demonstration')}: the demonstrations' per-step "
            f"variance would be the ridge ({ridge:g} rad², m²) alone, so the score would measure the ridge, "
            f"not the motions; covariance {covariance} needs at least {need} demonstrations"
        )
    for n, what in ((n_demos, "demonstrations"), (n_generated, "generated trajectories")):
        if what == "demonstrations" and refusal is not None:
            continue
        if n < MIN_TRAJECTORIES["diag"]:
            one = "1 demonstration" if what == "demonstrations" else "1 generated trajectory"
            few = f"only {one}" if n == 1 else f"no {what}"
            warnings_.append(
                f"{few}: the per-step variance is the ridge ({ridge:g}) alone, so the variance part of "
                f"the score measures the ridge, not the motions; covariance {covariance} needs at least "
                f"{need} {what}"
            )
        elif covariance == "full" and n < need:
            msg = (
                f"{n} {what} give a 6×6 per-step covariance of rank at most {n - 1}, so in {need - n} of its 6 "
                f"directions the variance is the ridge ({ridge:g}) alone and the total measures it; "
                f"covariance full needs at least {need} {what}"
            )
            if n < parts:
                msg += f" (the rotation and translation parts at least {parts})"
            warnings_.append(msg + "; covariance diag needs 2")
    return SampleSizeCheck(refusal=refusal, warnings=tuple(warnings_),
                           needed={"demos": need, "generated": need})


def _spread_warning(var: np.ndarray, ridge: float, what: str) -> str | None:
    """A warning when more than :data:`NO_SPREAD_FRACTION` of a set's per-step variances (T, 6), without
    the ridge, are below the ridge (the set barely varies, so those terms measure the ridge)."""
    if ridge <= 0:
        return None
    frac = float(np.mean(var < ridge))
    if frac <= NO_SPREAD_FRACTION:
        return None
    return (f"the {what} barely differ: at {100 * frac:.0f} % of the steps and dimensions their variance is "
            f"below the ridge ({ridge:g} rad², m²), so those terms of the score measure the ridge")


@dataclass
class EvaluationResult:
    """Per-step and mean Bhattacharyya distances between generated trajectories and demonstrations.

    Features are ``(rx, ry, rz, x, y, z)``: the rotation vector of ``R̄_tᵀ R`` (rad) and the position
    (m), docs/method.md §9. The parts: with ``covariance="diag"`` the rotation (translation) part is the
    sum of the per-dimension terms of the 3 rotation (translation) dimensions and the total is their
    sum; with ``"full"`` the total uses the full 6×6 covariances and each part its 3×3 block, so the
    parts need not add up to the total (they ignore rotation-translation correlation).

    Attributes
    ----------
    steps : int
        T, the number of resampled steps.
    n_generated, n_demos : int
        Number of generated trajectories and of demonstrations.
    covariance : str
        ``"diag"`` or ``"full"``.
    ridge : float
        Added to every variance (rad², m²).
    per_step, per_step_rotation, per_step_translation : ndarray, shape (T,)
        D_B per step: total, rotation part, translation part.
    mean, rotation, translation : float
        Their means over the T steps.
    per_step_offset, per_step_spread : ndarray, shape (T,)
        The two parts of the per-step total (they add up to it): the *offset*, ⅛ Δᵀ Σ⁻¹ Δ (diag: Σ_i
        Δ_i² / (4 (v_d,i + v_g,i))), how far the generated set's mean is from the demonstrations' in
        units of their pooled spread; the *spread*, ½ ln(det Σ / √(det Σ_d det Σ_g)), how much the two
        sets' spreads differ (too narrow or too wide alike). docs/method.md §9.
    offset, spread : float
        Their means over the T steps (offset + spread = mean).
    s : ndarray, shape (T,)
        Normalised time of each step, ``j/(T − 1)``.
    reference : ndarray, shape (T, 4)
        The demonstrations' chordal mean rotation per step (quaternions x, y, z, w).
    demo_mean, demo_std, gen_mean, gen_std : ndarray, shape (T, 6)
        Per-step sample mean and standard deviation (ddof = 1; 0 for a single trajectory; without
        the ridge) of the features of the demonstrations and of the generated trajectories.
    warnings : tuple of str
        Why the score is not (fully) trustworthy: too few trajectories for the covariance
        (:func:`check_sample_sizes`), sets that barely vary, a refusal recorded instead of raised.
    reliable : bool
        True when there are no such warnings.
    """

    steps: int
    n_generated: int
    n_demos: int
    covariance: str
    ridge: float
    per_step: np.ndarray
    per_step_rotation: np.ndarray
    per_step_translation: np.ndarray
    mean: float
    rotation: float
    translation: float
    per_step_offset: np.ndarray
    per_step_spread: np.ndarray
    offset: float
    spread: float
    s: np.ndarray
    reference: np.ndarray
    demo_mean: np.ndarray
    demo_std: np.ndarray
    gen_mean: np.ndarray
    gen_std: np.ndarray
    warnings: tuple = ()

    @property
    def reliable(self) -> bool:
        return not self.warnings

    def to_dict(self, include_series: bool = False) -> dict:
        """Plain data (floats, ints, str, lists) for JSON output.

        ``{"bhattacharyya": {"mean", "rotation", "translation", "offset", "spread"}, "steps", "n_generated",
        "n_demos", "covariance", "ridge", "reliable", "warnings"}`` (``reliable`` false and
        ``warnings`` saying why and how many trajectories are needed when the sets are too small for
        the covariance or barely vary), plus ``"per_step": {"s", "total", "rotation",
        "translation", "offset", "spread"}`` (lists of length T) when ``include_series``. Non-finite values (only
        possible with ``ridge=0``) stay ``inf``/``nan`` floats.
        """
        out = {
            "bhattacharyya": {
                "mean": float(self.mean),
                "rotation": float(self.rotation),
                "translation": float(self.translation),
                "offset": float(self.offset),
                "spread": float(self.spread),
            },
            "steps": int(self.steps),
            "n_generated": int(self.n_generated),
            "n_demos": int(self.n_demos),
            "covariance": str(self.covariance),
            "ridge": float(self.ridge),
            "reliable": bool(self.reliable),
            "warnings": list(self.warnings),
        }
        if include_series:
            out["per_step"] = {
                "s": [float(v) for v in self.s],
                "total": [float(v) for v in self.per_step],
                "rotation": [float(v) for v in self.per_step_rotation],
                "translation": [float(v) for v in self.per_step_translation],
                "offset": [float(v) for v in self.per_step_offset],
                "spread": [float(v) for v in self.per_step_spread],
            }
        return out


def _moments(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-step sample mean (T, 6) and covariance (T, 6, 6) of features x (M, T, 6).

    ddof = 1 for M >= 2; a single trajectory has covariance 0 (the ridge makes it usable).
    """
    M = x.shape[0]
    mu = x.mean(axis=0)
    if M < 2:
        return mu, np.zeros(mu.shape + (mu.shape[-1],))
    c = x - mu
    return mu, np.einsum("mti,mtj->tij", c, c) / (M - 1)


def _default_length(demos: Sequence[Trajectory]) -> int:
    """Median sample count of the demonstrations, rounded half up."""
    return int(math.floor(float(np.median([len(d) for d in demos])) + 0.5))


def _check_arguments(generated, demos, covariance, ridge, sample_size) -> float:
    """:func:`evaluate`'s arguments checked (InputError, ValueError for ``sample_size``); returns
    ``ridge`` as a float."""
    if not generated:
        raise InputError("no generated trajectories to evaluate", hint="pass at least one")
    if not demos:
        raise InputError("no demonstrations to compare with", hint="pass at least one demonstration")
    if covariance not in COVARIANCES:
        raise InputError(f"unknown covariance {covariance!r}", hint="use 'diag' or 'full'")
    try:
        ridge = float(ridge)
    except (TypeError, ValueError):
        raise InputError(f"ridge must be a number, got {ridge!r}") from None
    if not (math.isfinite(ridge) and ridge >= 0):
        raise InputError(f"ridge must be finite and >= 0, got {ridge}", hint="use e.g. 1e-6")
    if sample_size not in SAMPLE_SIZE_POLICIES:
        raise ValueError(f"sample_size must be one of {SAMPLE_SIZE_POLICIES}, got {sample_size!r}")
    return ridge


def _steps(demos, length) -> int:
    """T, the steps of normalised time: ``length`` (checked against the length rule of
    :func:`evaluate`, with a warning above the longest demonstration) or the demonstrations' median."""
    longest = max(len(d) for d in demos)
    if length is None:
        T = _check_length(max(_default_length(demos), 2))
    else:
        T = _check_length(length)
        if T > MAX_UPSAMPLING * longest:
            raise InputError(
                f"length {T} is more than {MAX_UPSAMPLING}x the longest demonstration ({longest} samples)",
                hint=f"use length at most {MAX_UPSAMPLING * longest}, or omit it for the median "
                f"demonstration's sample count ({_default_length(demos)})", param="length",
            )
        if T > longest:
            warn(
                f"length {T} exceeds the longest demonstration ({longest} samples); "
                "the demonstrations are upsampled by interpolation", param="length"
            )
    return T


def _distances(covariance, ridge, mu_d, cov_d, var_d, mu_g, cov_g, var_g):
    """D_B per step (T,): the total, its rotation and translation parts, and its offset and spread
    terms, from the sets' per-step means (T, 6), covariances (T, 6, 6) and variances (T, 6) (without
    the ridge)."""
    rot, tra = slice(0, 3), slice(3, 6)
    if covariance == "diag":
        off, spr = bhattacharyya_diag_parts(mu_d, var_d + ridge, mu_g, var_g + ridge)  # (T, 6) each
        terms = off + spr
        per_rot = terms[:, rot].sum(axis=-1)
        per_tra = terms[:, tra].sum(axis=-1)
        per_step = per_rot + per_tra
        per_off, per_spr = off.sum(axis=-1), spr.sum(axis=-1)
    else:
        eye = ridge * np.eye(6)
        S_d, S_g = cov_d + eye, cov_g + eye
        per_off, per_spr = bhattacharyya_gaussian_parts(mu_d, S_d, mu_g, S_g)
        per_step = per_off + per_spr
        per_rot = bhattacharyya_gaussian(mu_d[:, rot], S_d[:, rot, rot], mu_g[:, rot], S_g[:, rot, rot])
        per_tra = bhattacharyya_gaussian(mu_d[:, tra], S_d[:, tra, tra], mu_g[:, tra], S_g[:, tra, tra])
    return per_step, per_rot, per_tra, per_off, per_spr


def evaluate(
    generated: Sequence[Trajectory],
    demos: Sequence[Trajectory],
    *,
    length: int | None = None,
    covariance: str = "diag",
    ridge: float = DEFAULT_RIDGE,
    sample_size: str = "refuse",
) -> EvaluationResult:
    """Bhattacharyya distance between generated trajectories and demonstrations, per step (docs/method.md §9).

    1. Resample every trajectory to ``T = length`` steps of normalised time (default: the median
       sample count of the demonstrations), slerp for rotation, linear for translation
       (:func:`~rbgp_cli.evaluation.resample.resample`).
    2. Reference R̄_t: the chordal mean of the demonstrations' rotations at each step.
    3. Features ``x = (log(R̄_tᵀ R), p)``, shape (6,), for every trajectory and step.
    4. Per step and set, a Gaussian: sample mean; covariance with ddof = 1 (0 for a single
       trajectory); ``ridge`` added to the diagonal (absolute: rad² and m²).
    5. D_B per step. ``"diag"``: per-dimension terms (:func:`bhattacharyya_diag`); rotation part = sum
       over the 3 rotation dimensions, translation part = sum over the 3 translation dimensions,
       total = both. ``"full"``: total from the full 6×6 covariances, parts from the 3×3 blocks
       (:func:`bhattacharyya_gaussian`). M trajectories give a sample covariance of rank <= M − 1,
       so a full 6×6 covariance needs at least 7 trajectories per set; with fewer, its smallest
       eigenvalues are the ridge and the log-determinant term of D_B is dominated by it (the
       3×3 parts need at least 4). Prefer ``"diag"`` for small sets.

    The rotation part does not change when the world frame is rotated (R̄ᵀR is invariant) and has no
    jump at θ = π; with ``"full"`` the translation part and the total are also invariant under a
    common rigid motion of the world (an orthogonal map keeps ``ridge·I``); with ``"diag"`` the
    translation part is invariant under common translations (per-axis variances change when the axes
    rotate).

    Length rule: resampling to more steps than a demonstration has samples only interpolates, which is
    harmless up to a point; ``length`` above ``MAX_UPSAMPLING`` (4) times the longest demonstration's
    sample count is refused (the steps would be almost all interpolation), and ``length`` above the
    longest demonstration's sample count is reported with an :class:`~rbgp_cli.errors.RbgpWarning`.

    Parameters
    ----------
    generated, demos : sequence of Trajectory
        Clean trajectories (>= 2 samples each; quaternions x, y, z, w; metres); at least one of each.
    length : int, optional
        T >= 2; default the median sample count of ``demos`` (rounded half up).
    covariance : {"diag", "full"}
    ridge : float
        >= 0, added to every variance; 0 can give infinite or NaN distances where a set has no spread.
    sample_size : {"refuse", "warn", "record"}
        Too few trajectories for ``covariance`` (:func:`check_sample_sizes`) or sets that barely vary:
        ``"refuse"`` raises InputError for one demonstration and emits an
        :class:`~rbgp_cli.errors.RbgpWarning` for the rest; ``"warn"`` only warns (also for one
        demonstration); ``"record"`` emits nothing (for callers that score many small sets, e.g.
        cross-validation folds, and report once). Every case is recorded in the result's
        ``warnings`` and ``reliable``.

    Returns
    -------
    EvaluationResult

    Raises
    ------
    InputError
        No generated trajectories or no demonstrations, a trajectory with fewer than 2 samples (or
        not clean), ``length < 2`` or above the rule, unknown ``covariance``, negative ridge; one
        demonstration with ``sample_size="refuse"``.
    """
    generated = list(generated)
    demos = list(demos)
    ridge = _check_arguments(generated, demos, covariance, ridge, sample_size)
    sizes = check_sample_sizes(len(generated), len(demos), covariance, ridge)
    if sizes.refusal is not None and sample_size == "refuse":
        raise InputError(sizes.refusal, hint="pass more demonstrations (e.g. a folder of takes)", param="covariance")

    T = _steps(demos, length)
    q_d, p_d = resample_all(demos, T)  # (M_D, T, 4), (M_D, T, 3)
    q_g, p_g = resample_all(generated, T)  # (M_G, T, 4), (M_G, T, 3)
    ref = mean_rotation(q_d)  # (T, 4)
    x_d = tangent_features(q_d, p_d, ref)  # (M_D, T, 6)
    x_g = tangent_features(q_g, p_g, ref)  # (M_G, T, 6)

    mu_d, cov_d = _moments(x_d)  # (T, 6), (T, 6, 6)
    mu_g, cov_g = _moments(x_g)
    var_d = np.diagonal(cov_d, axis1=-2, axis2=-1)  # (T, 6), without the ridge
    var_g = np.diagonal(cov_g, axis1=-2, axis2=-1)
    notes = ([sizes.refusal] if sizes.refusal else []) + list(sizes.warnings)
    for var, n, what in ((var_d, len(demos), "demonstrations"), (var_g, len(generated), "generated trajectories")):
        spread = _spread_warning(var, ridge, what) if n >= 2 else None
        if spread:
            notes.append(spread)
    if sample_size != "record":
        for note in notes:
            warn(note, param="covariance")

    per_step, per_rot, per_tra, per_off, per_spr = _distances(covariance, ridge, mu_d, cov_d, var_d, mu_g, cov_g,
                                                              var_g)

    return EvaluationResult(
        steps=T,
        n_generated=len(generated),
        n_demos=len(demos),
        covariance=covariance,
        ridge=ridge,
        per_step=per_step,
        per_step_rotation=per_rot,
        per_step_translation=per_tra,
        mean=float(np.mean(per_step)),
        rotation=float(np.mean(per_rot)),
        translation=float(np.mean(per_tra)),
        per_step_offset=per_off,
        per_step_spread=per_spr,
        offset=float(np.mean(per_off)),
        spread=float(np.mean(per_spr)),
        s=normalised_time(T),
        reference=ref,
        demo_mean=mu_d,
        demo_std=np.sqrt(var_d),
        gen_mean=mu_g,
        gen_std=np.sqrt(var_g),
        warnings=tuple(notes),
    )
