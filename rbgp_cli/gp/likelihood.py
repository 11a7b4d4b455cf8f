"""The exact GP's likelihood: NLML and its gradient, the Cholesky and conditioning helpers, and the
test that accepts a fitted covariance (docs/method.md §6, §7).

Negative log marginal likelihood (R&W Alg. 2.1) with C = K + σn² I = L Lᵀ and α = C⁻¹ y:

    NLML = ½ yᵀα + Σ_i log L_ii + (n/2) log 2π

and its gradient (R&W eq. 5.9) with W = ααᵀ − C⁻¹:

    ∂NLML/∂θ = −½ Σ_ij W_ij ∂C_ij/∂θ

Kernels provide Σ W ∘ ∂K/∂logθ directly (:meth:`Kernel.grad_contract`); the noise term is
∂C/∂log σn = 2σn² I, so its contribution is −σn² tr(W). With L columns in y (one shared set of
hyperparameters) the NLML is the sum over columns with one Cholesky.

Indefinite kernels (docs/method.md §6: the paper's geodesic kernel is not PSD): where C fails its Cholesky,
:func:`nlml_and_gradient` reports the point infeasible (a large finite NLML, ``INFEASIBLE_NLML``, from
which L-BFGS-B's line search backs off). A fitted output is accepted (:func:`accept`) only if C at the
optimum passes Cholesky with a reciprocal condition number above ``MIN_RCOND``; otherwise increasing
jitter (``JITTERS``) is added to the diagonal and reported. :func:`meets_margin` tests the noise margin
(``NOISE_MARGIN``) that an optimum of an indefinite kernel must keep.

All BLAS/LAPACK calls in the evaluation loop go through ``scipy.linalg`` (ECOSYSTEM.md §7).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.linalg import blas, lapack

from rbgp_cli.kernels.base import Kernel

__all__ = ["NOISE", "MIN_RCOND", "INFEASIBLE_NLML", "NOISE_MARGIN", "JITTERS", "cholesky", "rcond",
           "nlml_and_gradient", "symmetrise_lower", "meets_margin", "accept"]

NOISE = "noise_std"
#: Reciprocal condition number below which C = K + σn²I is treated as numerically singular.
MIN_RCOND = 1e-12
#: NLML reported for hyperparameters whose C is not positive definite (finite, so that the
#: L-BFGS-B line search backtracks instead of producing NaNs).
INFEASIBLE_NLML = 1e25
_LOG2PI = math.log(2.0 * math.pi)
#: Indefinite kernels: a fit is accepted only if λ_min(K + σn²I) >= NOISE_MARGIN · σn², i.e. the
#: noise must outweigh K's negative eigenvalues by a margin (tested by the Cholesky of
#: K + (1 − NOISE_MARGIN) σn² I). Cholesky and rcond alone are not enough: with λ_min(C) just above
#: 0, ‖α‖ = ‖C⁻¹y‖ explodes and so do predictions away from the training inputs (measured: held-out
#: RMSE 80–320 instead of 0.03 on 80 random poses). With the margin ‖C⁻¹‖ <= 1/(NOISE_MARGIN σn²),
#: at most 1/NOISE_MARGIN times the bound that holds for every positive semi-definite kernel.
NOISE_MARGIN = 0.25
#: Jitter ladder (relative to σf² + σn²) tried when the optimum is ill conditioned.
JITTERS = (0.0, 1e-10, 1e-8, 1e-6, 1e-4)


def cholesky(K: np.ndarray, noise_var: float, jitter: float = 0.0):
    """Lower Cholesky factor of K + (σn² + jitter) I as a Fortran-ordered array, or None.

    K is symmetric and C-ordered, so its transpose (a free view) is the same matrix in Fortran order.
    """
    C = np.array(K, order="F", copy=True)
    idx = np.arange(C.shape[0])
    C[idx, idx] += noise_var + jitter
    c, info = lapack.dpotrf(C, lower=1, clean=1, overwrite_a=1)
    if info != 0:
        return None
    return c


def rcond(c: np.ndarray, K: np.ndarray, noise_var: float) -> float:
    """Reciprocal 1-norm condition number of C from its Cholesky factor (LAPACK dpocon)."""
    anorm = float(np.max(np.sum(np.abs(K), axis=0)) + noise_var)
    rc, info = lapack.dpocon(c, anorm, uplo="L")
    return float(rc) if info == 0 else 0.0


def nlml_and_gradient(kernel: Kernel, pre: dict, values: dict, y: np.ndarray, grad_names,
                      margin: float = 0.0) -> tuple[float, np.ndarray]:
    """NLML and ∂NLML/∂logθ for the hyperparameters in ``grad_names`` (noise included as ``noise_std``).

    Parameters
    ----------
    pre : kernel.precompute(X), pairwise arrays of shape (n, n)
    values : {name: value} for every hyperparameter of the kernel plus ``noise_std``
    y : shape (n,) or (n, L) — with L columns the NLML is the sum over columns with one shared C
    grad_names : names of the free hyperparameters, in theta order

    margin : with margin > 0 the point is also infeasible unless λ_min(K + σn²I) >= margin·σn² (one
        more Cholesky, of K + (1 − margin)σn²I; see NOISE_MARGIN)

    Returns (INFEASIBLE_NLML, zeros) when K + σn²I is not positive definite (or misses the margin).
    """
    y2 = y.reshape(len(y), -1)
    n, L = y2.shape
    K, state = kernel.gram(pre, values)
    s2 = values[NOISE] ** 2
    if margin > 0 and cholesky(K, (1.0 - margin) * s2) is None:
        return INFEASIBLE_NLML, np.zeros(len(grad_names))
    c = cholesky(K, s2)
    if c is None:
        return INFEASIBLE_NLML, np.zeros(len(grad_names))
    alpha, info = lapack.dpotrs(c, y2, lower=1)  # Line 3 of R&W Alg. 2.1
    logdet_half = float(np.sum(np.log(np.diagonal(c))))
    nlml = 0.5 * float(np.sum(y2 * alpha)) + L * logdet_half + 0.5 * n * L * _LOG2PI
    if len(grad_names) == 0:
        return nlml, np.zeros(0)
    inv, info = lapack.dpotri(c, lower=1, overwrite_c=1)  # lower triangle of C⁻¹, upper is zero
    # W = Σ_l α_l α_lᵀ − L·C⁻¹, built in place (all on scipy's BLAS)
    W = symmetrise_lower(inv)
    W *= -float(L)
    alpha_f = np.asfortranarray(alpha)
    W = blas.dgemm(1.0, alpha_f, alpha_f, beta=1.0, c=W, trans_b=1, overwrite_c=1)
    # W is symmetric bit for bit (dpotri's lower triangle mirrored; α_i α_j = α_j α_i) and Fortran-ordered
    # (LAPACK's): its transpose is the same matrix in C order, which the kernels' contractions (fdot and
    # products with the C-ordered K) read without copying it first: the same numbers, ~1 ms less per
    # evaluation at n = 400 (issue 35, sixth pass)
    if W.flags.f_contiguous and not W.flags.c_contiguous:
        W = W.T
    kernel_names = [nm for nm in grad_names if nm != NOISE]
    g_kernel = kernel.grad_contract(pre, values, K, state, W, kernel_names) if kernel_names else np.zeros(0)
    grad = np.empty(len(grad_names))
    it = iter(g_kernel)
    for i, nm in enumerate(grad_names):
        if nm == NOISE:
            grad[i] = -s2 * float(np.trace(W))
        else:
            grad[i] = -0.5 * next(it)
    return nlml, grad


#: Block size of :func:`symmetrise_lower`'s copies (measured at n = 400, 1208, 1752: 128 was 1.8–3.7×
#: faster than a transposed add of the whole matrix, 64 and 256 within 20 % of it).
_SYM_BLOCK = 128


def symmetrise_lower(a: np.ndarray) -> np.ndarray:
    """The symmetric matrix whose lower triangle is ``a``'s (n, n), made in place and returned: the upper
    triangle becomes the lower one's transpose. Bit for bit ``a + a.T`` with its diagonal halved when
    ``a``'s upper triangle is zero (LAPACK's dpotri output), copied in square blocks so that the
    transposed reads stay in cache (at n = 1752, 5 ms instead of 20 ms: 7 % of an NLML evaluation)."""
    n = a.shape[0]
    for i in range(0, n, _SYM_BLOCK):
        i1 = min(i + _SYM_BLOCK, n)
        block = a[i:i1, i:i1]
        block += np.tril(block, -1).T  # the diagonal block: its zero upper part gets the lower one
        for j in range(i1, n, _SYM_BLOCK):
            j1 = min(j + _SYM_BLOCK, n)
            a[i:i1, j:j1] = a[j:j1, i:i1].T
    return a


# ----------------------------------------------------------------------------- acceptance of an optimum
def meets_margin(kernel, pre, values, K=None) -> bool:
    """λ_min(K + σn²I) >= NOISE_MARGIN σn² (always true for a positive semi-definite kernel, which is
    not tested: one Cholesky factorisation of n × n saved)."""
    if getattr(kernel, "positive_semidefinite", False):
        return True
    if K is None:
        K, _ = kernel.gram(pre, values)
    return cholesky(K, (1.0 - NOISE_MARGIN) * values[NOISE] ** 2) is not None


def accept(kernel, pre, y, values, K=None):
    """Check C = K + σn²I at the optimum; add jitter from a ladder if needed.

    Returns (jitter, rcond, pd, Cholesky factor) or (None, 0.0, False, None)."""
    if K is None:
        K, _ = kernel.gram(pre, values)
    s2 = values[NOISE] ** 2
    scale = float(np.mean(np.diagonal(K))) + s2
    for j, rel in enumerate(JITTERS):
        jitter = rel * scale
        c = cholesky(K, s2, jitter)
        if c is None:
            continue
        rc = rcond(c, K, s2 + jitter)
        if rc >= MIN_RCOND:
            return jitter, rc, (j == 0), c
    return None, 0.0, False, None

