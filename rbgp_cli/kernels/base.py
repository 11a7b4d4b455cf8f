"""Hyperparameters described as data, and the kernel interface (STYLE.md §2.7, after scikit-learn).

A kernel here is the *noise-free* covariance k(g_i, g_j); the observation noise σn² δij belongs to
the GP (:mod:`rbgp_cli.gp`), which adds it to the diagonal. Every positive hyperparameter lives in
log space for the optimiser: ``theta = log(value)`` and ``bounds`` are log bounds. A fixed
hyperparameter simply has no slot in ``theta``.

Kernels split their work so that quantities that do not depend on hyperparameters (pairwise
distances, inner products) are computed once per fit:

* ``precompute(Xa, Xb=None) -> dict`` of pairwise arrays, shape (n, m), hyperparameter-free;
* ``gram(pre, values) -> (K, state)`` with ``K`` of shape (n, m);
* ``grad_contract(pre, values, K, state, W, names) -> ndarray``: ``Σ_ij W_ij ∂K_ij/∂log θ`` for the
  named hyperparameters, which is all the marginal-likelihood gradient needs (R&W eq. 5.9) without
  materialising an (n, n, p) tensor;
* ``gram_with_gradient(Xa, values, names)``: K and the full dK/dlogθ, shape (n, n, p), for tests;
* ``cross_plan(Xb)`` and ``cross_precompute(plan, Xa)``: the same pairwise arrays as
  ``precompute(Xa, Xb)`` for many query blocks Xa against one fixed Xb (predictions, rollouts),
  with Xb's part computed once; ``cross_gram(plan, Xa, values)``: K(Xa, Xb) directly, and
  ``cross_grad_contract(plan, Xa, values, K, W, names)``: its gradient contraction, so that a sparse GP
  needs no (n, M) pairwise arrays at all where the kernel fuses both (``fused_cross_gradient``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

__all__ = ["Hyperparameter", "Kernel", "fdot", "output_scale"]


def output_scale(y: np.ndarray) -> float:
    """The scale of zero-mean GP targets: their root mean square, or 1 when they are all (nearly) zero.

    The GP has zero mean (docs/method.md §7), so the prior variance must cover the mean as well as the
    spread: RMS, not the standard deviation (a constant output has std 0, or 1e-16 from round-off,
    which made bounds and scaled targets meaningless).
    """
    rms = float(np.sqrt(np.mean(np.square(y)))) if np.size(y) else 0.0
    return rms if np.isfinite(rms) and rms > 1e-12 else 1.0


def fdot(a: np.ndarray, b: np.ndarray) -> float:
    """Σ_ij a_ij b_ij, via scipy's BLAS (ECOSYSTEM.md §7: keep hot paths on one BLAS library)."""
    from scipy.linalg.blas import ddot

    return float(ddot(np.ascontiguousarray(a).ravel(), np.ascontiguousarray(b).ravel()))


@dataclass(frozen=True)
class Hyperparameter:
    """One positive hyperparameter.

    name : e.g. ``"signal_std"`` (σf), ``"length_scale"`` (λ), ``"rho_rot"`` (ρ1), ``"noise_std"`` (σn)
    value : current (or initial) value, > 0
    bounds : (low, high) on the value (not its log); ``None`` means "data-driven, set at fit time"
    fixed : if True the optimiser does not touch it
    """

    name: str
    value: float
    bounds: tuple[float, float] | None = None
    fixed: bool = False

    @property
    def log_bounds(self) -> tuple[float, float]:
        if self.bounds is None:
            raise ValueError(f"hyperparameter {self.name!r} has no bounds yet")
        return (math.log(self.bounds[0]), math.log(self.bounds[1]))

    def with_value(self, value: float) -> "Hyperparameter":
        return replace(self, value=float(value))


class Kernel:
    """Base class: a covariance function on rows of X (see module docstring for the protocol)."""

    #: short identifier stored in model files
    kind: str = ""
    #: names of the hyperparameters, in theta order
    names: tuple[str, ...] = ()

    @property
    def positive_semidefinite(self) -> bool:
        """True when every Gram matrix of this kernel is positive semi-definite, for every
        hyperparameter value (docs/method.md §6): then λ_min(K + σn²I) ≥ σn² and the noise margin
        (:data:`rbgp_cli.gp.likelihood.NOISE_MARGIN`) holds without a test. False unless a kernel says so."""
        return False

    def precompute(self, Xa: np.ndarray, Xb: np.ndarray | None = None) -> dict:
        raise NotImplementedError

    def gram(self, pre: dict, values: dict) -> tuple[np.ndarray, object]:
        raise NotImplementedError

    def grad_contract(self, pre: dict, values: dict, K: np.ndarray, state, W: np.ndarray, names) -> np.ndarray:
        raise NotImplementedError

    def diag(self, X: np.ndarray, values: dict) -> np.ndarray:
        """Prior variance k(x, x), shape (m,)."""
        raise NotImplementedError

    # -- predictions: many query blocks against one fixed second set (the training inputs) --------
    def cross_plan(self, Xb: np.ndarray) -> dict:
        """Hyperparameter-free data of the fixed second argument Xb (n, d) of K(Xa, Xb), computed
        once and reused by :meth:`cross_precompute` for every query block (predictions, rollouts)."""
        return {"Xb": np.ascontiguousarray(Xb, dtype=np.float64)}

    def cross_precompute(self, plan: dict, Xa: np.ndarray) -> dict:
        """``precompute(Xa, Xb)`` for the Xb of ``plan``, for :meth:`gram`. Kernels may compute it
        faster, equal to ``precompute`` up to round-off in K (each kernel says how close)."""
        return self.precompute(Xa, plan["Xb"])

    def cross_gram(self, plan: dict, Xa: np.ndarray, values: dict) -> np.ndarray:
        """K(Xa, Xb), shape (m, n), for the Xb of ``plan``: :meth:`gram` of :meth:`cross_precompute`
        (kernels may fuse the two for one set of hyperparameters)."""
        K, _ = self.gram(self.cross_precompute(plan, Xa), values)
        return K

    #: True where :meth:`cross_grad_contract` needs no pairwise arrays (it is then cheaper to call per
    #: evaluation than to cache :meth:`precompute`'s arrays; the sparse GP's row blocks use it).
    fused_cross_gradient: bool = False

    def cross_grad_contract(self, plan: dict, Xa: np.ndarray, values: dict, K: np.ndarray, W: np.ndarray,
                            names) -> np.ndarray:
        """``Σ_ij W_ij ∂K_ij/∂log θ`` for ``K = cross_gram(plan, Xa, values)`` (shape (m, n)), as
        :meth:`grad_contract` of :meth:`cross_precompute`; kernels may fuse it."""
        pre = self.cross_precompute(plan, Xa)
        _K, state = self.gram(pre, values)
        return self.grad_contract(pre, values, K, state, W, names)

    def default_hyperparameters(self, pre: dict, y: np.ndarray) -> dict:
        """Data-driven start values (docs/method.md §7) and bounds, as ``{name: Hyperparameter}``."""
        raise NotImplementedError

    def to_dict(self) -> dict:
        """Plain-data description (for model files)."""
        raise NotImplementedError

    # -- for tests and users: the full Gram matrix and its gradient ------------------------------
    def __call__(self, Xa: np.ndarray, Xb: np.ndarray | None, values: dict) -> np.ndarray:
        """K(Xa, Xb), shape (n, m), with hyperparameter values given as ``{name: value}``."""
        K, _ = self.gram(self.precompute(Xa, Xb), values)
        return K

    def gram_with_gradient(self, Xa: np.ndarray, values: dict, names) -> tuple[np.ndarray, np.ndarray]:
        """K(Xa, Xa), shape (n, n), and dK/dlogθ, shape (n, n, p) for the p given ``names``.

        Built by contracting with unit matrices, so it tests exactly the code path the optimiser uses.
        """
        pre = self.precompute(Xa)
        K, state = self.gram(pre, values)
        n = K.shape[0]
        dK = np.empty((n, n, len(names)))
        for i in range(n):
            for j in range(n):
                E = np.zeros((n, n))
                E[i, j] = 1.0
                dK[i, j] = self.grad_contract(pre, values, K, state, E, names)
        return K, dK
