"""Sparse GP regression: the collapsed variational bound of Titsias (2009) (SGPR / VFE).

For n training inputs X, M inducing inputs Z chosen among them, K_mm = k(Z, Z), K_nm = k(X, Z),
Q_nn = K_nm K_mm⁻¹ K_mn and noise variance s = σn², the bound on the log marginal likelihood is
(Titsias 2009, eq. 9)

    F = log N(y | 0, Q_nn + s I) − tr(K_nn − Q_nn) / (2 s)  ≤  log p(y),

and the fit minimises −F (``nlml`` in the fit records: an upper bound on the exact NLML, equal to it
when Z = X). With P = L_m⁻¹ (K_mm + j I = L_m L_mᵀ, j a small jitter), Φ = K_mn K_nm (M × M),
b = K_mn y, C = P Φ Pᵀ, B = I + C / s = L_B L_Bᵀ, c = P b and β = B⁻¹ c (Woodbury and the matrix
determinant lemma):

    −F = n/2 log 2π + n/2 log s + Σ log diag L_B + ½ yᵀy / s − ½ cᵀβ / s² + ½ tr K_nn / s − ½ tr C / s

Gradient (derived here; R&W eq. 5.9 in spirit): with α = Pᵀβ, the derivative of −F with respect to
K_nm, K_mm and diag K_nn is, as matrices to contract with ∂K/∂log θ (:meth:`Kernel.grad_contract`),

    W_nm = 2 K_nm G − y αᵀ / s²,        G    = Pᵀ (B⁻¹ + ββᵀ/s² − I) P / (2 s)
    W_mm = Pᵀ (B⁻¹ + ββᵀ/s² + B − 2 I) P / 2,      ∂(−F)/∂K_ii = 1 / (2 s)

and for s:  ∂(−F)/∂s = n/(2s) − tr(B⁻¹C)/(2s²) − ½ yᵀy/s² − ½ βᵀCβ/s⁴ + cᵀβ/s³ − tr K_nn/(2s²) + tr C/(2s²).
With L outputs sharing one set of hyperparameters (``shared``) every per-output term is summed.

Cost per evaluation: C and c in one pass over row blocks of K_nm (A = L_m⁻¹ K_mb by a triangular
product and the rank-k update: 2 n M²), the M × M algebra (M³), and for the gradient K_nm G per block
(2 n M²) contracted with ∂K_nm/∂log θ: O(n M²) time. The chordal kernel builds each block of K_nm and
its contraction from a few features per row and one matrix product (``Kernel.cross_gram``,
``cross_grad_contract``), so its memory is one block (``block_rows`` × M) of temporaries, and the
blocks of one evaluation are kept for its gradient pass up to KEEP_BYTES; other kernels cache their
hyperparameter-free pairwise arrays per block (O(n M), recomputed per block above ``cache_bytes``).
The σf component of the gradient is the closed form of the M × M terms (k = σf² k̃). All BLAS calls
in the loop go through ``scipy.linalg.blas`` (ECOSYSTEM.md §7).

Prediction (Titsias 2009, eq. 6; the SGPR posterior): mean μ(x) = k_xmᵀ w with w = α / s (O(M) per
pose), latent variance k(x,x) − ‖L_m⁻¹ k_xm‖² + ‖L_B⁻¹ L_m⁻¹ k_xm‖² (O(M²) per pose).

Inducing inputs are M distinct training inputs chosen by k-means++ seeding (D² sampling; Arthur &
Vassilvitskii 2007) or greedy farthest-point selection, seeded, in a Euclidean embedding of the
kernel's distance (:func:`inducing_embedding`); they are not optimised.

The hyperparameters are fitted in stages (:func:`fit_sparse_gp`): the starts on a small random subset
with the exact NLML (as the exact GP explores), then the bound on a random 4M of the points (by
default; up to all of them with ``hyper_points``), polished from the explored optima as the exact GP
polishes; the posterior then uses all points.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import blas, lapack

from rbgp_cli.compute import blas_threads
from rbgp_cli.errors import RbgpRuntimeError
from rbgp_cli.gp.likelihood import INFEASIBLE_NLML, NOISE
from rbgp_cli.gp.optimise import (BASIN_GAP, EXPLORE_FTOL, POLISH_MAX_EVALS, Objective, all_noise, fd_hessian, fit_one,
                                  fit_targets, free_spec, polish, random_start, smooth_start, training_data)
from rbgp_cli.gp.results import OutputFit
from rbgp_cli.kernels.base import Kernel

__all__ = [
    "SparseGP",
    "SparseOutputFit",
    "fit_sparse_gp",
    "sparse_bound_and_gradient",
    "select_inducing",
    "inducing_embedding",
    "RowBlocks",
    "DEFAULT_INDUCING",
    "INDUCING_METHODS",
]

#: Default number of inducing poses. 256 rather than 512 (issue 21, benchmarks/README.md): on 10⁵ pairs of
#: the synthetic field the held-out RMSE was the same (0.0108), and on the 40 slower handovers at the
#: recorded rate (5658–5919 pairs) the cross-validated motions too (position RMSE 0.1751 m either way),
#: while the posterior pass, n·M² per output, takes a quarter of the time.
DEFAULT_INDUCING = 256
#: Inducing inputs are chosen among at most this many random rows per inducing input.
CANDIDATES_PER_INDUCING = 32
INDUCING_METHODS = ("kmeans++", "farthest")
#: Where a sparse GP's hyperparameters come from (``fit_sparse_gp(hyper=...)``): ``exact``, the exact
#: GP's own fit (its NLML) on a random subset of the points, or ``bound``, the collapsed bound −F.
#: ``exact`` is the default: with too few inducing poses for the data's length-scales the bound prefers
#: long length-scales, large σf and a noise that absorbs the rest (the known bias of the variational
#: bound, Bauer, van der Wilk & Rasmussen 2016). On held-out handovers (40 slower ones, a fold of 8,
#: M = 512 for 1930 points) the bound chose λ 0.17–0.34 and σf up to 16 where the exact NLML chose
#: λ 0.04–0.11 and σf ≤ 5.8; the rollouts with the bound's hyperparameters left the demonstrated region
#: (position RMSE 0.44–0.45 m with either inducing selection) and with the exact GP's they did not
#: (0.18 m with farthest-point inducing poses, against 0.20 m for the exact GP itself).
HYPER_SOURCES = ("exact", "bound")
#: Jitter added to K_mm, relative to the mean of its diagonal (its derivative is part of the gradient).
JITTER = 1e-8
#: Jitters tried, in this order, when K_mm + j I fails its Cholesky.
_JITTER_LADDER = (1e-8, 1e-6, 1e-4)
#: Elements of one row block of K_nm (block_rows = this / M): 8 MB per temporary.
BLOCK_ELEMENTS = 1 << 20
#: Cache the hyperparameter-free pairwise arrays of K_nm up to this many bytes (else recompute per block).
CACHE_BYTES = 1 << 30
_LOG2PI = math.log(2.0 * math.pi)


# ----------------------------------------------------------------------------- inducing inputs
def inducing_embedding(kernel: Kernel, X: np.ndarray) -> np.ndarray:
    """Rows of X mapped to a Euclidean space whose distances approximate the kernel's, shape (n, D).

    Squared-exponential kernels on rotations: the chordal embedding of SO(3), e(q) = √2 vec(q qᵀ) with
    ‖e(q1) − e(q2)‖² = 4 (1 − ⟨q1, q2⟩²) = d_ch² (docs/method.md §5; it approximates d_arc to O(d³), and is
    halved for the S³ angle of the quaternion baseline), weighted √ρ1, beside √(1 − ρ1) t; Euclidean
    rotation coordinates (Euler angles) and the dot-product kernel use the coordinates as they are.
    A time / phase column is appended scaled by the ratio of the median pose distance to the median
    time difference (the kernel's data-driven length-scales), so that both count alike.
    """
    from rbgp_cli.geometry.so3 import quat_from_rotvec

    X = np.asarray(X, dtype=np.float64)
    k = int(getattr(kernel, "rotation_dims", 3))
    rho = float(getattr(kernel, "rho_rot", 0.5))
    metric = getattr(kernel, "metric", "euclidean")
    rot = X[:, :k]
    if metric in ("arc", "chordal", "s3"):
        q = rot if k == 4 else quat_from_rotvec(rot)
        q = q / np.linalg.norm(q, axis=1, keepdims=True)
        iu = np.triu_indices(4)
        w = np.where(iu[0] == iu[1], 1.0, math.sqrt(2.0))  # Frobenius norm over the 10 unique entries
        rot = math.sqrt(2.0) * (q[:, iu[0]] * q[:, iu[1]]) * w
        if metric == "s3":
            rot = 0.5 * rot
    pose = np.concatenate([math.sqrt(rho) * rot, math.sqrt(1.0 - rho) * X[:, k:k + 3]], axis=1)
    if getattr(kernel, "time_dims", 0):
        tau = X[:, k + 3:k + 4]
        rng = np.random.default_rng(12345)
        i, j = rng.integers(0, len(X), (2, min(20000, 4 * len(X))))
        dp = float(np.median(np.sum((pose[i] - pose[j]) ** 2, axis=1))) ** 0.5
        dt = float(np.median(np.abs(tau[i, 0] - tau[j, 0])))
        scale = dp / dt if dt > 0 and dp > 0 else 1.0
        pose = np.concatenate([pose, scale * tau], axis=1)
    return np.ascontiguousarray(pose)


def select_inducing(X: np.ndarray, M: int, kernel: Kernel, seed: int = 0, method: str = "kmeans++") -> np.ndarray:
    """Indices of at most M distinct rows of X to serve as inducing inputs, shape (m,), m ≤ M.

    Chosen among all rows, or among a random CANDIDATES_PER_INDUCING·M of them when X has more.
    ``kmeans++``: the first uniformly at random, each next with probability ∝ its squared distance
    to the nearest one chosen (D² sampling); ``farthest``: the first at random, each next the farthest
    from all chosen. Both in :func:`inducing_embedding`, O(min(n, 32 M) M) time, seeded. Fewer than M come back
    when X has fewer distinct rows (in the embedding).
    """
    if method not in INDUCING_METHODS:
        raise ValueError(f"unknown inducing method {method!r}; expected one of {INDUCING_METHODS}")
    n_all = len(X)
    M = int(min(M, n_all))
    if M < 1:
        raise ValueError("at least one inducing input is needed")
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 12]))
    # the candidates: all rows, or a random CANDIDATES_PER_INDUCING·M of them (each step of the
    # selection is a pass over the candidates: 1.05 s for M = 512 among 10⁵ rows, measured)
    cand = np.sort(rng.permutation(n_all)[:CANDIDATES_PER_INDUCING * M]) if n_all > CANDIDATES_PER_INDUCING * M else None
    E = inducing_embedding(kernel, X if cand is None else X[cand])
    n = len(E)
    chosen = [int(rng.integers(n))]

    def sqdist(i):  # ‖E − E_i‖² directly: exactly 0 for duplicate rows
        D = E - E[i]
        return np.einsum("ij,ij->i", D, D)

    d2 = sqdist(chosen[0])
    scale = float(np.max(np.einsum("ij,ij->i", E, E))) + 1.0
    for _ in range(M - 1):
        total = float(np.sum(d2))
        if not total > 1e-24 * scale * n:  # every remaining row duplicates a chosen one
            break
        if method == "farthest":
            i = int(np.argmax(d2))
        else:
            i = int(np.searchsorted(np.cumsum(d2), rng.uniform(0.0, total), side="right"))
            i = min(i, n - 1)
            if d2[i] <= 0.0:  # round-off at the end of the cumulative sum
                i = int(np.argmax(d2))
        chosen.append(i)
        np.minimum(d2, sqdist(i), out=d2)
    chosen = np.array(sorted(chosen), dtype=np.int64)
    return chosen if cand is None else cand[chosen]


# ----------------------------------------------------------------------------- row blocks of K_nm
class RowBlocks:
    """The rows of X in blocks, and each block's K_nm = k(X[a:b], Z) and gradient contraction.

    Kernels with a fused cross gradient (``kernel.fused_cross_gradient``: the chordal kernel) compute
    both from the plan of Z (:meth:`Kernel.cross_plan`) and a few features per row, one matrix product
    each, so nothing of size n × M is kept. Other kernels keep ``kernel.precompute(X[a:b], Z)`` of each
    block (cached while the cache stays below ``cache_bytes``, else recomputed per block).
    """

    def __init__(self, kernel: Kernel, X: np.ndarray, Z: np.ndarray, block_rows: int | None = None,
                 cache_bytes: int = CACHE_BYTES):
        self.kernel = kernel
        self.X = X
        self.Z = Z
        n, M = len(X), len(Z)
        rows = int(block_rows) if block_rows else max(64, BLOCK_ELEMENTS // max(M, 1))
        self.slices = [slice(a, min(a + rows, n)) for a in range(0, n, rows)]
        self.fused = bool(getattr(kernel, "fused_cross_gradient", False))
        self.plan = kernel.cross_plan(Z) if self.fused else None
        self._cache: dict = {}
        self._cache_bytes = int(cache_bytes)
        self._used = 0

    def __len__(self) -> int:
        return len(self.slices)

    def pre(self, i: int) -> dict:
        hit = self._cache.get(i)
        if hit is not None:
            return hit
        sl = self.slices[i]
        p = self.kernel.precompute(self.X[sl], self.Z)
        size = sum(v.nbytes for v in p.values() if isinstance(v, np.ndarray))
        if self._used + size <= self._cache_bytes:
            self._cache[i] = p
            self._used += size
        return p

    def gram(self, i: int, values: dict):
        """(K_b, state): block i of K_nm, shape (rows, M), C-ordered, and what :meth:`grad_contract` needs."""
        if self.fused:
            return self.kernel.cross_gram(self.plan, self.X[self.slices[i]], values), None
        return self.kernel.gram(self.pre(i), values)

    def grad_contract(self, i: int, values: dict, K: np.ndarray, state, W: np.ndarray, names) -> np.ndarray:
        """Σ W ∘ ∂K_b/∂log θ for block i (W of K_b's shape)."""
        if self.fused:
            return self.kernel.cross_grad_contract(self.plan, self.X[self.slices[i]], values, K, W, names)
        return self.kernel.grad_contract(self.pre(i), values, K, state, W, names)

    @property
    def cached_bytes(self) -> int:
        return self._used


def _diag_sum_grad(kernel: Kernel, X: np.ndarray, values: dict, names) -> np.ndarray:
    """Σ_i ∂k(x_i, x_i)/∂log θ for θ in ``names``, shape (p,)."""
    from rbgp_cli.kernels.dot_product import DotProduct
    from rbgp_cli.kernels.squared_exponential import SquaredExponential

    out = np.zeros(len(names))
    if isinstance(kernel, SquaredExponential):  # k(x, x) = σf²
        for i, nm in enumerate(names):
            if nm == "signal_std":
                out[i] = 2.0 * len(X) * values["signal_std"] ** 2
        return out
    if isinstance(kernel, DotProduct):  # k(x, x) = σf² (ρ |r|² + (1 − ρ) |t|²)
        k = kernel.rotation_dims
        r2, t2 = float(np.sum(X[:, :k] ** 2)), float(np.sum(X[:, k:] ** 2))
        sf2, rho = values["signal_std"] ** 2, values["rho_rot"]
        for i, nm in enumerate(names):
            out[i] = 2.0 * sf2 * (rho * r2 + (1 - rho) * t2) if nm == "signal_std" else sf2 * rho * (r2 - t2)
        return out
    for a in range(0, len(X), 64):  # any other kernel: contract each small diagonal block with I
        Xb = X[a:a + 64]
        pre = kernel.precompute(Xb)
        K, st = kernel.gram(pre, values)
        out += kernel.grad_contract(pre, values, K, st, np.eye(len(Xb)), names)
    return out


def _chol(A: np.ndarray):
    c, info = lapack.dpotrf(np.array(A, order="F", copy=True), lower=1, clean=1, overwrite_a=1)
    return c if info == 0 else None


def _sandwich_inv(Lm: np.ndarray, A: np.ndarray) -> np.ndarray:
    """L_m⁻ᵀ A L_m⁻¹ for symmetric A (M × M), symmetrised. Triangular solves, not products with the
    explicit L_m⁻¹: with K_mm ill-conditioned (long length-scales, the jitter's floor) the products
    made the gradient's σf component 10× noisier (±5 around 1.9, measured at n = 2048, M = 512)."""
    Y = blas.dtrsm(1.0, Lm, np.asfortranarray(A), side=0, lower=1, trans_a=1)
    Y = blas.dtrsm(1.0, Lm, Y, side=1, lower=1, trans_a=0, overwrite_b=1)
    return 0.5 * (Y + Y.T)


def _kmm_factor(kernel, pre_mm, values, jitter):
    """(K_mm, state, j, L_m, L_m⁻¹) with K_mm + j I = L_m L_mᵀ, j = rel · mean diag K_mm for the first
    rel of the ladder starting at ``jitter`` that passes; (K_mm, state, None, None, None) if none does.

    L_m⁻¹ is formed explicitly (M³/3) for the pass over the rows, where a triangular matrix product
    (dtrmm) is 1.7× faster than the triangular solve (dtrsm) on this machine's OpenBLAS at M = 512,
    n = 10⁵ (0.31 s against 0.53 s, measured): the error of L_m⁻¹ K_mn is of the order ε cond(L_m)
    either way (the bound agreed to 1e-12 relative), and C = A Aᵀ stays positive semi-definite by
    construction (see :func:`_statistics`)."""
    Kmm, st = kernel.gram(pre_mm, values)
    scale = float(np.mean(np.diagonal(Kmm)))
    for rel in [jitter] + [r for r in _JITTER_LADDER if r > jitter]:
        j = rel * scale
        Lm = _chol(Kmm + j * np.eye(len(Kmm)))
        if Lm is not None:
            Li, info = lapack.dtrtri(Lm, lower=1)
            if info == 0 and np.all(np.isfinite(Li)):
                return Kmm, st, rel, Lm, Li
    return Kmm, st, None, None, None


#: Keep the K_nm blocks of one evaluation for its gradient pass (instead of computing them again) up to
#: this many bytes.
KEEP_BYTES = 1 << 28


def _statistics(blocks: RowBlocks, values, Y, Li, keep: bool = False):
    """C = A Aᵀ (M × M) and c = A Y (M × L) with A = L_m⁻¹ K_mn, in one pass over the row blocks;
    with ``keep`` also the list of (K_b, state) per block (None when they would exceed KEEP_BYTES).

    A is formed block by block (a triangular product, n M² in all) rather than C = L_m⁻¹ Φ L_m⁻ᵀ from
    Φ = K_mn K_nm: when K_mm is ill-conditioned (long length-scales) the rounding of Φ is amplified by
    ‖L_m⁻¹‖² and C came out indefinite (eigenvalue −2.6e-3 where the direct way gives +2e-8, measured
    at n = 1500, M = 256), which made I + C/s fail its Cholesky.
    """
    M = len(blocks.Z)
    C = np.zeros((M, M), order="F")
    c = np.zeros((M, Y.shape[1]), order="F")
    kept = [] if keep and len(blocks.X) * M * 8 <= KEEP_BYTES else None
    for i, sl in enumerate(blocks.slices):
        Kb, st = blocks.gram(i, values)  # (rows, M), C-ordered: Kb.T is Fortran (M, rows)
        A = blas.dtrmm(1.0, Li, Kb.T, side=0, lower=1, overwrite_b=kept is None)  # L_m⁻¹ K_mb
        C = blas.dsyrk(1.0, A, beta=1.0, c=C, trans=0, lower=1, overwrite_c=1)
        c = blas.dgemm(1.0, A, np.asfortranarray(Y[sl]), beta=1.0, c=c, overwrite_c=1)
        if kept is not None:
            kept.append((Kb, st))
    C = np.tril(C)
    C = C + np.tril(C, -1).T
    return C, c, kept


def sparse_bound_and_gradient(kernel: Kernel, blocks: RowBlocks, pre_mm: dict, values: dict, Y: np.ndarray,
                              grad_names, jitter: float = JITTER) -> tuple[float, np.ndarray]:
    """−F (the negative collapsed bound, ≥ NLML) and its gradient with respect to log θ.

    Parameters
    ----------
    blocks : :class:`RowBlocks` of the training inputs X (n, d) against the inducing inputs Z (M, d)
    pre_mm : kernel.precompute(Z)
    values : {name: value} for every hyperparameter plus ``noise_std``
    Y : shape (n,) or (n, L); with L columns the bound is summed over them (one shared set)
    grad_names : free hyperparameters in theta order (``noise_std`` included)
    jitter : K_mm + j I with j = jitter · mean diag K_mm (larger from a ladder if that fails)

    Returns (INFEASIBLE_NLML, zeros) if a Cholesky fails.
    """
    f, g, _ = _bound(kernel, blocks, pre_mm, values, Y, grad_names, jitter, True)
    return f, g


def _bound(kernel, blocks, pre_mm, values, Y, grad_names, jitter, want_grad):
    Y = np.asarray(Y, dtype=np.float64)
    Y = Y.reshape(len(Y), -1)
    n, L = Y.shape
    s = values[NOISE] ** 2
    Kmm, st_mm, rel, Lm, Li = _kmm_factor(kernel, pre_mm, values, jitter)
    if Lm is None:
        return INFEASIBLE_NLML, np.zeros(len(grad_names)), None
    M = len(Kmm)
    names_k = [nm for nm in grad_names if nm != NOISE] if want_grad else []
    C, c, kept = _statistics(blocks, values, Y, Li, keep=bool(names_k))  # L_m⁻¹ Φ L_m⁻ᵀ, L_m⁻¹ K_mn y
    B = C / s
    B[np.diag_indices(M)] += 1.0
    LB = _chol(B)
    if LB is None:
        return INFEASIBLE_NLML, np.zeros(len(grad_names)), None
    beta, _ = lapack.dpotrs(LB, c, lower=1)                              # B⁻¹ c
    tr_knn = float(np.sum(kernel.diag(blocks.X, values)))
    tr_c = float(np.trace(C))
    yy = float(np.sum(Y * Y))
    cb = float(np.sum(c * beta))
    f = (0.5 * n * L * (_LOG2PI + math.log(s)) + L * float(np.sum(np.log(np.diagonal(LB))))
         + 0.5 * yy / s - 0.5 * cb / s**2 + 0.5 * L * (tr_knn - tr_c) / s)
    state = {"Lm": Lm, "LB": LB, "c": c, "rel": rel, "s": s}
    if not want_grad or len(grad_names) == 0:
        return f, np.zeros(len(grad_names)), state
    Binv, _ = lapack.dpotri(LB, lower=1)
    Binv = np.tril(Binv)
    Binv = Binv + np.tril(Binv, -1).T
    mid = beta @ beta.T
    mid /= s**2
    mid += L * Binv
    mid[np.diag_indices(M)] -= L                                          # L B⁻¹ + ββᵀ/s² − L I
    gk = np.zeros(len(names_k))
    if names_k:
        G = _sandwich_inv(Lm, mid)
        G /= 2.0 * s                                                      # (M, M)
        Wmm = _sandwich_inv(Lm, mid + (L / s) * C)
        Wmm *= 0.5
        alpha = np.asfortranarray(blas.dtrsm(1.0, Lm, beta, side=0, lower=1, trans_a=1))  # Pᵀ β, (M, L)
        Gf = np.asfortranarray(G)
        for i, sl in enumerate(blocks.slices):
            Kb, st = kept[i] if kept is not None else blocks.gram(i, values)
            # W_b = 2 K_b G − y_b αᵀ/s², built transposed (M, rows) in Fortran order = (rows, M) C order
            Wt = blas.dgemm(-1.0 / s**2, alpha, np.asfortranarray(Y[sl]), trans_b=1)
            Wt = blas.dgemm(2.0, Gf, Kb.T, beta=1.0, c=Wt, overwrite_c=1)
            gk += blocks.grad_contract(i, values, Kb, st, Wt.T, names_k)
        # the jitter j = rel · tr(K_mm)/M moves with the hyperparameters: ∂(−F)/∂j = tr(W_mm), so K_mm's
        # contraction is with W_mm + rel tr(W_mm)/M · I
        Wmm[np.diag_indices(M)] += rel * float(np.trace(Wmm)) / M
        gk += kernel.grad_contract(pre_mm, values, Kmm, st_mm, Wmm, names_k)
        gk += (0.5 * L / s) * _diag_sum_grad(kernel, blocks.X, values, names_k)
    bcb = float(np.sum(beta * (C @ beta)))
    tr_bc = float(np.sum(Binv * C))
    grad = np.empty(len(grad_names))
    it = iter(gk)
    for i, nm in enumerate(grad_names):
        if nm == NOISE:
            dfds = (0.5 * n * L / s - 0.5 * L * tr_bc / s**2 - 0.5 * yy / s**2
                    - 0.5 * bcb / s**4 + cb / s**3 - 0.5 * L * tr_knn / s**2 + 0.5 * L * tr_c / s**2)
            grad[i] = 2.0 * s * dfds
        elif nm == "signal_std" and getattr(kernel, "signal_scaled", False):
            # k = σf² k̃ and the jitter ∝ mean diag K_mm, so C ∝ σf², c ∝ σf, tr K_nn ∝ σf²: with u = log σf²,
            # ∂(−F)/∂u = L tr(B⁻¹C)/(2s) − (cᵀβ − βᵀCβ/s)/(2s²) + L (tr K_nn − tr C)/(2s), all M × M terms.
            # The contraction of W with K_nm gives the same up to round-off, but as a difference of
            # O(n) sums that cancel: ±5 around 1.9 at n = 2048, M = 512, λ = 39 (measured), enough to stall
            # the line searches on the long ridges of smooth fields.
            next(it)
            grad[i] = 2.0 * (0.5 * L * tr_bc / s - 0.5 * (cb - bcb / s) / s**2 + 0.5 * L * (tr_knn - tr_c) / s)
        else:
            grad[i] = next(it)
    return f, grad, state


# ----------------------------------------------------------------------------- the fitted model
@dataclass
class SparseOutputFit(OutputFit):
    """An :class:`OutputFit` of a sparse GP: ``nlml`` is the negative bound −F (≥ the exact NLML),
    ``jitter`` is 0 (nothing is added to the noise), ``rcond`` that of K_mm + j I, ``kmm_jitter`` the jitter of K_mm relative to the
    mean of its diagonal, ``stages`` per stage of the fit {"points", "evaluations", "objective", "nlml"}."""

    kmm_jitter: float = JITTER
    stages: list = field(default_factory=list)

    def to_dict(self) -> dict:
        return {**super().to_dict(), "kmm_jitter": float(self.kmm_jitter), "stages": self.stages}


class SparseGP:
    """A fitted sparse GP (SGPR posterior) with L outputs on training inputs X (n, d) and inducing
    inputs Z (M, d); the same interface as :class:`~rbgp_cli.gp.exact.GaussianProcess`.

    ``fits`` holds one :class:`OutputFit` per output (or one, ``shared``); its ``nlml`` is the negative
    bound −F and its ``jitter`` the relative jitter of K_mm. ``stats`` optionally gives the
    posterior's factors per group, ``[(L_m, L_B (M, M), c (M, L_g)), ...]`` (what model files store),
    so that nothing is recomputed from X; otherwise they are computed in one pass over X.
    Per group the posterior is kept as L_m, L_B (M × M) and the mean weights w = α / s (M, L_g).
    """

    sparse = True

    def __init__(self, kernel: Kernel, X: np.ndarray, Y: np.ndarray, Z: np.ndarray, fits: list, shared: bool,
                 y_scale=None, stats=None):
        self.kernel = kernel
        self.X = np.ascontiguousarray(X, dtype=np.float64)
        self.Y = np.ascontiguousarray(np.asarray(Y, dtype=np.float64).reshape(len(self.X), -1))
        self.Z = np.ascontiguousarray(Z, dtype=np.float64)
        self.fits = list(fits)
        self.shared = bool(shared)
        self.y_scale = np.ones(self.Y.shape[1]) if y_scale is None else np.asarray(y_scale, dtype=np.float64)
        self.last_clipped = 0
        with blas_threads(0):
            self._factorise(stats)

    @property
    def n_outputs(self) -> int:
        return self.Y.shape[1]

    @property
    def n_inducing(self) -> int:
        return len(self.Z)

    def group_outputs(self):
        """``[(fit, outputs)]``: each fit with the output columns it serves (the Posterior protocol)."""
        if self.shared:
            return [(self.fits[0], list(range(self.n_outputs)))]
        return [(f, [l]) for l, f in enumerate(self.fits)]

    def _factorise(self, stats) -> None:
        """L_m, L_B and the mean weights w = L_m⁻ᵀ L_B⁻ᵀ L_B⁻¹ c / s per group.

        Without ``stats`` they are computed from X, Y (one pass, n M² per group). With ``stats`` =
        ``[(L_m, L_B, c), ...]`` (model files) they are checked instead: L_m L_mᵀ must reproduce
        k(Z, Z) + j I from the stored hyperparameters (relative error below 1e-8, an M³ check), and L_B
        must be a lower Cholesky factor of I + (something positive semi-definite): positive diagonal and
        every eigenvalue of L_B L_Bᵀ at least 1 − 1e-8.
        """
        pre_mm = self.kernel.precompute(self.Z)
        blocks = None
        M = len(self.Z)
        self._Lm, self._LB, self._w, self.stats = [], [], [], []
        bad = RbgpRuntimeError("the stored hyperparameters, inducing poses and posterior factors disagree",
                               hint="refit the model (rbgp train)")
        for g, (fit, outs) in enumerate(self.group_outputs()):
            s = fit.values[NOISE] ** 2
            Kmm, _ = self.kernel.gram(pre_mm, fit.values)
            j = float(getattr(fit, "kmm_jitter", JITTER)) * float(np.mean(np.diagonal(Kmm)))
            Kj = Kmm + j * np.eye(M)
            if stats is None:
                Lm = _chol(Kj)
                if Lm is None:
                    raise bad
                Lm = np.tril(Lm)
                Li, info = lapack.dtrtri(Lm, lower=1)
                if info != 0:
                    raise bad
                y = self.Y[:, outs] / self.y_scale[outs]
                blocks = blocks or RowBlocks(self.kernel, self.X, self.Z, cache_bytes=0)
                C, c, _ = _statistics(blocks, fit.values, y, Li)
                B = C / s
                B[np.diag_indices(M)] += 1.0
                LB = _chol(B)
                if LB is None:
                    raise bad
                LB = np.tril(LB)
            else:
                Lm, LB, c = (np.asarray(a, dtype=np.float64) for a in stats[g])
                if Lm.shape != (M, M) or LB.shape != (M, M) or c.shape != (M, len(outs)):
                    raise bad
                Lm, LB = np.tril(Lm), np.tril(LB)
                if (np.max(np.abs(Lm @ Lm.T - Kj)) > 1e-8 * float(np.max(np.abs(Kj)))
                        or not np.all(np.diagonal(LB) > 0)
                        or _chol(LB @ LB.T - (1.0 - 1e-8) * np.eye(M)) is None):
                    raise bad
            beta, _ = lapack.dpotrs(LB, np.asfortranarray(c), lower=1)
            alpha = blas.dtrsm(1.0, Lm, beta, side=0, lower=1, trans_a=1)
            self._Lm.append(np.ascontiguousarray(Lm))
            self._LB.append(np.ascontiguousarray(LB))
            self._w.append(np.asarray(alpha) / s)
            self.stats.append((self._Lm[-1], self._LB[-1], np.asarray(c)))

    def predict(self, Xs, return_std: bool = False, noisy: bool = False, chunk_elements: int = 2_000_000,
                manage_threads: bool = True):
        """Predictive mean (and standard deviation) at query inputs Xs (m, d); see
        :meth:`GaussianProcess.predict` for the arguments. Mean k_xmᵀ w: O(M) per pose; latent variance
        k(x, x) − ‖L_m⁻¹ k_xm‖² + ‖L_B⁻¹ L_m⁻¹ k_xm‖²: O(M²) per pose."""
        if not manage_threads:
            return self._predict(Xs, return_std, noisy, chunk_elements)
        with blas_threads(0):  # single-threaded, as the fit (see fit_sparse_gp)
            return self._predict(Xs, return_std, noisy, chunk_elements)

    def _predict(self, Xs, return_std, noisy, chunk_elements):
        from scipy.linalg import solve_triangular

        Xs = np.ascontiguousarray(np.asarray(Xs, dtype=np.float64).reshape(-1, self.X.shape[1]))
        m, M = len(Xs), self.n_inducing
        mean = np.empty((m, self.n_outputs))
        std = np.empty((m, self.n_outputs)) if return_std else None
        step = max(1, int(chunk_elements // max(M, 1)))
        clipped = 0
        for a in range(0, m, step):
            Xc = Xs[a:a + step]
            pre = self.kernel.precompute(Xc, self.Z)
            for (fit, outs), Lm, LB, w in zip(self.group_outputs(), self._Lm, self._LB, self._w):
                Ks, _ = self.kernel.gram(pre, fit.values)  # (mc, M)
                scale = self.y_scale[outs]
                mean[a:a + step, outs] = (Ks @ w) * scale
                if std is not None:
                    v = solve_triangular(Lm, Ks.T, lower=True, check_finite=False)
                    u = solve_triangular(LB, v, lower=True, check_finite=False)
                    var = (self.kernel.diag(Xc, fit.values) - np.einsum("ij,ij->j", v, v)
                           + np.einsum("ij,ij->j", u, u))
                    clipped += int(np.sum(var < 0))
                    var = np.maximum(var, 0.0)
                    if noisy:
                        var = var + fit.values[NOISE] ** 2
                    std[a:a + step, outs] = np.sqrt(var)[:, None] * scale
        self.last_clipped = clipped
        return (mean, std) if return_std else mean

    def predict_mean(self, Xs) -> np.ndarray:
        return self.predict(Xs)


# ----------------------------------------------------------------------------- fitting
#: The bound stages run on nested random subsets of STAGE_FACTOR·M, STAGE_FACTOR·GROWTH·M, ... points up
#: to ``hyper_points``; each stage starts from the previous optimum.
STAGE_FACTOR = 4
STAGE_GROWTH = 4
#: The default ``hyper_points``: HYPER_FACTOR·M, i.e. one bound stage, on a random 4M of the points.
#: On 10⁵ points (M = 512) optimising on all of them instead took 7–9× as long and changed the held-out
#: RMSE by at most 1 % on two synthetic fields (0.01072 against 0.01083; 0.0888 against 0.0886, measured
#: with this fit); the bound on more points keeps moving the hyperparameters (towards longer
#: length-scales: with n ≫ M the bound's complexity term fades) without making the posterior better.
HYPER_FACTOR = 4
#: ... and never fewer than the exact GP's default ``--max-points`` (few inducing poses are cheap).
HYPER_MIN_POINTS = 2000
#: The default ``hyper_points`` of ``hyper="exact"``: the exact GP's fit on this many random points
#: chooses the hyperparameters. 1000 rather than 2000 (issue 21): the same held-out RMSE on 10⁵ pairs
#: of the synthetic field (0.0108) and the same cross-validated motions on the slower handovers, at a
#: quarter of the exact fit's time (training per fold 56 → 15 s there).
HYPER_EXACT_POINTS = 1000
#: Several starts in one bound stage race: each gets this many evaluations, then only the best goes on
#: (in the polish of the first stage: every start after the best explored optimum gets this many).
RACE_EVALUATIONS = 5
#: A bound stage on a random subset of the points stops once the quasi-Newton model predicts less than
#: this many nats to gain (on all points: POLISH_RTOL relative, as the exact GP). The subset's optimum
#: is an estimate of the full one anyway; on smooth fields the bound is a long ridge towards long
#: length-scales along which −F falls by ~0.02 nats per evaluation and the predictions do not change.
SUBSET_ATOL = 0.1
#: L-BFGS-B stops when the relative change of −F is below this (the bound is O(n), so L-BFGS-B's
#: default ~2e-9 asks for changes far below what matters at n = 10⁵).
STAGE_FTOL = 1e-7
#: Each bound stage may cost at most the time of this many evaluations on all n points: a stage on
#: k points gets at most max(STAGE_MIN_EVALUATIONS, STAGE_BUDGET · n / k) evaluations (and ``max_iter``).
STAGE_BUDGET = 2.0
STAGE_MIN_EVALUATIONS = 3
#: At most this many bound evaluations in the stage on all points when an earlier bound stage ran;
#: when the stage on all points is the first (n ≤ STAGE_FACTOR·M, where an evaluation is cheap) it
#: runs to convergence (at most FIRST_STAGE_EVALUATIONS): with 3 it stopped up to 30 nats short on the
#: handover recordings (n ≈ 970, M = 512).
FINAL_EVALUATIONS = 3
FIRST_STAGE_EVALUATIONS = 100
#: An output's hyperparameters are settled when no log-hyperparameter moved by more than this between
#: two consecutive bound stages; it then skips the larger stages (the posterior always uses all n).
SETTLED_LOG = 0.05


def _stage_sizes(n: int, M: int, top: int) -> list[int]:
    """Nested subset sizes k, 4k, 16k, ... below min(n, top), then min(n, top), from k = max(4M, 2000)."""
    top = min(n, max(int(top), 2))
    sizes = []
    k = max(STAGE_FACTOR * M, HYPER_MIN_POINTS)
    while k < top:
        sizes.append(k)
        k *= STAGE_GROWTH
    return sizes + [top]


def _minimise(objective, theta0, log_bounds, max_evals, ftol):
    """L-BFGS-B from theta0 with an infeasible-point penalty as in :func:`rbgp_cli.gp.optimise.fit_one`; returns
    (θ, f, converged, message)."""
    from scipy.optimize import minimize

    count = {"n": 0, "ref": None}

    def fun(theta):
        count["n"] += 1
        f, g = objective(theta)
        if f >= INFEASIBLE_NLML and count["ref"] is not None:
            return count["ref"] + max(10.0, abs(count["ref"])), np.zeros_like(g)
        if count["ref"] is None and f < INFEASIBLE_NLML:
            count["ref"] = f
        return f, g

    theta0 = np.clip(theta0, [b[0] for b in log_bounds], [b[1] for b in log_bounds])
    if not len(theta0):
        f, _ = objective(theta0)
        return theta0, f, True, "no free hyperparameters"
    res = minimize(fun, theta0, jac=True, method="L-BFGS-B", bounds=log_bounds,
                   options={"maxfun": int(max_evals), "maxiter": int(max_evals), "ftol": ftol})
    f = float(res.fun)
    return np.array(res.x), f, bool(res.success), str(res.message)


class _StageObjective(Objective):
    """−F on one stage's points (``fn(θ) -> (−F, gradient)``) as the exact GP's objective, for
    :func:`rbgp_cli.gp.optimise.polish`: the same counting and memory of the last point."""

    def __init__(self, fn, free, log_bounds):
        self.fn, self.free, self.log_bounds = fn, list(free), log_bounds
        self.counter = {"evals": 0, "infeasible": 0}
        self.on_evaluation = None

    def _evaluate(self, theta):
        return self.fn(theta)


def _record(st, free, theta0, f, status, evaluations, kind):
    st["records"].append({"start": {nm: float(math.exp(t)) for nm, t in zip(free, theta0)}, "nlml": float(f),
                          "status": status, "evaluations": int(evaluations), "kind": kind})


def _polish_starts(objective, st, free, log_bounds, hessians, scale, points, cap, count, subset):
    """The first bound stage from the explored starts, as the exact GP polishes (:func:`rbgp_cli.gp.optimise.polish`):
    quasi-Newton steps from each start with its Hessian on the explored subset scaled to the stage
    (``scale`` = stage points / subset points: −F, like the NLML, is a sum over the points). The best
    explored optimum gets POLISH_MAX_EVALS evaluations, every other start RACE_EVALUATIONS (it stops
    early where it joins a basin polished before); a polish that runs out of evaluations or stalls
    hands over to L-BFGS-B (at most ``cap`` evaluations) if it is the first or the best so far. On a
    random ``subset`` of the points the polish stops once less than SUBSET_ATOL nats are left to gain.
    The smooth start runs with L-BFGS-B to convergence: always where the stage covers all points (on
    the handover fold of the tests it finds an optimum 3 nats better than the structured one the
    explored optima lead to), on a random subset (large n, where it would cost most) only where the best
    optimum so far explains less than the noise (σf < σn, the all-noise basin). Returns (θ, −F) of the
    best, or None."""
    obj = _StageObjective(objective, free, log_bounds)
    atol = SUBSET_ATOL if subset else None
    polished, best = [], None
    where = f"(bound, {points} points)"
    for i, (theta0, kind, H) in enumerate(zip(st["theta"], st["kinds"], hessians)):
        if kind == "smooth start" and subset and best is not None and not all_noise(free, best[0]):
            _record(st, free, theta0, float("nan"), "not tried: on a subset, and the best optimum has σf ≥ σn", 0,
                    f"{kind} {where}")
            continue
        ev0 = count[0]
        budget = POLISH_MAX_EVALS if i == 0 else RACE_EVALUATIONS
        # L-BFGS-B from the smooth start (far from every explored optimum, where the subset's Hessian
        # says little; on sample_data after 5 polish steps it was still 100 nats behind the all-noise
        # basin, and at convergence 790 nats ahead of it on all points) and where the subset gave no
        # Hessian (an infeasible neighbour); the polish otherwise
        lbfgs = kind == "smooth start" or H is None
        if lbfgs:
            th, f, _ok, msg = _minimise(objective, theta0, log_bounds, cap if i == 0 or kind == "smooth start" else budget,
                                        STAGE_FTOL)
            res = {"theta": th, "nlml": f, "status": msg, "start": theta0}
        else:
            res = polish(obj, theta0, H * scale, points, polished, max_evals=budget, atol=atol)
        th, f, status = res["theta"], res["nlml"], res["status"]
        method = "L-BFGS-B" if lbfgs else "polish"
        _record(st, free, res["start"], f, status, count[0] - ev0, f"{kind}, {method} {where}")
        if status in ("budget", "stalled") and (i == 0 or (best is not None and f < best[1])):
            ev0 = count[0]
            ftol = max(STAGE_FTOL, SUBSET_ATOL / max(abs(f), 1.0)) if subset and f < INFEASIBLE_NLML else STAGE_FTOL
            th2, f2, _ok, msg = _minimise(objective, th, log_bounds, cap, ftol)
            _record(st, free, th, f2, msg, count[0] - ev0, f"{kind}, L-BFGS-B after the polish {where}")
            if f2 < f:
                th, f = th2, f2
        if f < INFEASIBLE_NLML:
            polished.append((np.array(th), f))
            if best is None or f < best[1]:
                best = (np.array(th), f)
    return best


def _race_starts(objective, st, free, log_bounds, cap, count, points):
    """L-BFGS-B from each start (at most ``cap`` evaluations); several starts race: RACE_EVALUATIONS
    each, then only the best goes on. Returns (θ, −F) of the best, or None."""
    race = len(st["theta"]) > 1 and cap > RACE_EVALUATIONS
    runs = []
    for theta0, kind in zip(st["theta"], st["kinds"]):
        ev0 = count[0]
        th, f, ok, msg = _minimise(objective, theta0, log_bounds, RACE_EVALUATIONS if race else cap, STAGE_FTOL)
        _record(st, free, theta0, f, msg, count[0] - ev0, f"{kind} (bound, {points} points" + (", race)" if race else ")"))
        if f < INFEASIBLE_NLML:
            runs.append((f, th, ok, kind))
    if not runs:
        return None
    f, th, ok, kind = min(runs, key=lambda r: r[0])
    best = (th, f)
    if race and not ok:
        ev0 = count[0]
        th2, f2, _ok, msg = _minimise(objective, th, log_bounds, cap - RACE_EVALUATIONS, STAGE_FTOL)
        _record(st, free, th, f2, msg, count[0] - ev0, f"{kind}, the race's best, continued (bound, {points} points)")
        if f2 < f:
            best = (th2, f2)
    return best


def _exact_hyperparameters(X, Y, kernel, idx, targets, specs, state, **fit_options) -> None:
    """``fit_sparse_gp(hyper="exact")``: the exact GP's fit on the rows ``idx`` (a random subset)
    sets each target's log-hyperparameters in ``state`` (and its record of the stage)."""
    from rbgp_cli.gp.exact import ExactSpec, fit_gp

    idx = np.sort(np.asarray(idx))
    t0 = time.perf_counter()
    exact = fit_gp(X[idx], Y[idx], kernel, **fit_options)
    seconds = (time.perf_counter() - t0) / max(len(state), 1)
    # kept on the result, unfactorised: the automatic choice of GP compares with it
    state[0]["exact_gp"] = (ExactSpec(exact.kernel, exact.fits, exact.shared, exact.y_scale), idx)
    for fit, (spec, free), st in zip(exact.fits, specs, state):
        st["theta"] = [np.array([math.log(fit.values[nm]) for nm in free])]
        st["kinds"] = ["the exact GP's optimum"]
        st["records"] = [{**r, "kind": r.get("kind", "start") + f" (exact NLML, {len(idx)} points)"}
                         for r in (fit.starts or [])]
        st["stages"].append({"points": int(len(idx)), "objective": "exact NLML", "evaluations": int(fit.n_evaluations),
                             "value": float(fit.nlml)})
        st["evals"] = int(fit.n_evaluations)
        st["infeasible"] = int(fit.n_infeasible)
        st["seconds"] += seconds


def _stage_plan(hyper: str, hyper_points: int | None, n: int, M: int) -> tuple[int, list[int]]:
    """How many points choose the hyperparameters (``top``: the exact GP's subset, or the last bound
    stage's) and, with ``hyper="bound"``, the stages' subset sizes (:func:`_stage_sizes`)."""
    if hyper_points is None:
        top = max(HYPER_FACTOR * M, HYPER_MIN_POINTS) if hyper == "bound" else HYPER_EXACT_POINTS
    else:
        top = n if int(hyper_points) <= 0 else int(hyper_points)
    sizes = _stage_sizes(n, M, top) if hyper == "bound" else []
    return top, sizes


def _start_state(specs) -> list[dict]:
    """Each target's fit state before the stages, from its (spec, free) in ``specs``: the data-driven
    start, no records yet; ``settled`` (nothing to optimise) when every hyperparameter is fixed."""
    state = []  # per target: {"theta", "f", "records", "stages", "evals", "infeasible", "t"}
    for spec, free in specs:
        # with every hyperparameter fixed there is nothing to optimise: only the posterior is computed
        state.append({"theta": [np.array([math.log(spec[nm].value) for nm in free])], "kinds": ["data-driven"],
                      "records": [], "stages": [], "evals": 0, "infeasible": 0, "seconds": 0.0,
                      "settled": not free})
    return state


def _explore_starts(kernel, X, perm, explore, targets, specs, rngs, state, restarts, max_iter, task) -> None:
    """Stage 1 of ``fit_sparse_gp(hyper="bound")``, *explore*: every start of each target minimises the
    exact NLML on the first ``explore`` rows of ``perm`` (a random subset); each distinct optimum within
    BASIN_GAP of the best, and the smooth start, become the target's starts in ``state``, with their
    Hessians on the subset (for the polish of the first bound stage) and the stage's records."""
    n = len(X)
    idx = np.sort(perm[: min(n, explore)])
    pre_e = kernel.precompute(X[idx])
    for (y, label), (spec, free), rng, st in zip(targets, specs, rngs, state):
        if st["settled"]:
            task.advance()
            continue
        t0 = time.perf_counter()
        count = [0]

        def tick(label=label, count=count):
            count[0] += 1
            task.update(status=f"{label}: exploring, {count[0]} evaluations on {len(idx)} points")

        _b, recs, counter, _v, optima = fit_one(kernel, pre_e, y[idx], spec, free, restarts, rng, max_iter,
                                                ftol=EXPLORE_FTOL, on_evaluation=tick)
        ok = sorted((o for o in optima if o is not None), key=lambda o: o[1])
        if ok:
            # every distinct basin within BASIN_GAP of the best goes on to the bound on more points
            # (as the exact GP's polish does): on 400 points the all-noise basin (σf ≪ σn, λ → 0)
            # can be the best, and only more points tell it from the structured one (measured)
            keep = [ok[0]]
            for o in ok[1:]:
                if o[1] <= ok[0][1] + BASIN_GAP and all(np.max(np.abs(o[0] - k[0])) > 0.1 for k in keep):
                    keep.append(o)
            st["theta"] = [o[0] for o in keep]
            st["kinds"] = ["best explored optimum"] + ["another explored basin"] * (len(keep) - 1)
            smooth = smooth_start(spec, free)
            if smooth is not None:
                st["theta"].append(smooth)
                st["kinds"].append("smooth start")
            # each start's Hessian on the subset, for the quasi-Newton polish of the first bound stage
            obj_e = Objective(kernel, pre_e, y[idx], spec, free, on_evaluation=tick)
            st["hessians"] = [fd_hessian(obj_e, th) for th in st["theta"]]
            st["hessian_points"] = len(idx)
            counter = {key: counter[key] + obj_e.counter[key] for key in counter}
        st["records"] += [{**r, "kind": r["kind"] + f" (exact NLML, {len(idx)} points)"} for r in recs]
        st["stages"].append({"points": int(len(idx)), "objective": "exact NLML", "evaluations": counter["evals"],
                             "value": float(min((o[1] for o in ok), default=float("nan")))})
        st["infeasible"] += counter["infeasible"]
        st["seconds"] += time.perf_counter() - t0
        task.advance()


def _bound_stages(kernel, X, Z, pre_mm, perm, sizes, top, targets, specs, state, max_iter, final_evaluations, jitter,
                  task):
    """Stages 2 and 3 of ``fit_sparse_gp(hyper="bound")``: −F on the nested random subsets of ``sizes``
    (the first ``size`` rows of ``perm``, all rows when ``size >= n``), per target the first stage from
    the explored starts (:func:`_polish_starts`, or racing L-BFGS-B runs: :func:`_race_starts`), each
    later one from the stage before; a target whose hyperparameters settled skips the rest. Updates
    each target's optimum, records and stages in ``state``; returns the last stage's :class:`RowBlocks`
    (None without stages)."""
    n = len(X)
    blocks = None
    for k, size in enumerate(sizes):
        idx = np.arange(n) if size >= n else np.sort(perm[:size])
        blocks = None
        for (y, label), (spec, free), st in zip(targets, specs, state):
            if st.get("settled"):
                task.advance()
                continue
            blocks = blocks or RowBlocks(kernel, X[idx], Z)
            t0 = time.perf_counter()
            fixed_values = {nm: h.value for nm, h in spec.items() if nm not in free}
            log_bounds = [spec[nm].log_bounds for nm in free]
            yk = y[idx]
            count = [0]

            def values_of(theta, fixed_values=fixed_values, free=free):
                v = dict(fixed_values)
                v.update({nm: math.exp(t) for nm, t in zip(free, theta)})
                return v

            def objective(theta, values_of=values_of, yk=yk, free=free, label=label, count=count, st=st):
                count[0] += 1
                task.update(status=f"{label}: bound on {len(yk)} points, {count[0]} evaluations")
                f, g = sparse_bound_and_gradient(kernel, blocks, pre_mm, values_of(theta), yk, free, jitter)
                if f >= INFEASIBLE_NLML:
                    st["infeasible"] += 1
                return f, g

            if st.get("bound_theta") is None:  # the first bound stage: to convergence
                cap = min(max_iter, FIRST_STAGE_EVALUATIONS)
            elif size >= top:
                cap = final_evaluations
            else:
                cap = min(max_iter, max(STAGE_MIN_EVALUATIONS, int(STAGE_BUDGET * top / len(idx))))
            hessians = st.pop("hessians", None)
            if st.get("bound_theta") is None and hessians is not None:
                best = _polish_starts(objective, st, free, log_bounds, hessians, len(idx) / st["hessian_points"],
                                      len(idx), cap, count, subset=size < n)
            else:
                best = _race_starts(objective, st, free, log_bounds, cap, count, len(idx))
            if best is None:
                raise RbgpRuntimeError(f"no hyperparameters gave a positive definite sparse covariance for {label}",
                                       hint="use kernel se-chordal, more noise, or fewer inducing poses", param="kernel")
            prev = st.get("bound_theta")
            st["settled"] = prev is not None and float(np.max(np.abs(best[0] - prev), initial=0.0)) < SETTLED_LOG
            st["theta"], st["kinds"], st["f"], st["bound_theta"] = [best[0]], ["previous stage"], best[1], best[0]
            st["stages"].append({"points": int(len(idx)), "objective": "bound", "evaluations": count[0],
                                 "value": float(best[1])})
            if size >= n:
                st["evals"] = count[0]
            st["seconds"] += time.perf_counter() - t0
            task.advance()
    return blocks


def _posterior_fits(kernel, blocks, pre_mm, n, targets, specs, state, jitter, progress):
    """The SGPR posterior of each target at its optimum, from one pass over ``blocks`` (all n points):
    returns (fits, stats), one :class:`SparseOutputFit` and one (L_m, L_B, c) per target."""
    fits, stats = [], []
    for (y, label), (spec, free), st in zip(targets, specs, state):
        values = {nm: h.value for nm, h in spec.items() if nm not in free}
        values.update({nm: math.exp(t) for nm, t in zip(free, st["theta"][0])})
        f, _g, bstate = _bound(kernel, blocks, pre_mm, values, y, [], jitter, False)
        if bstate is None:
            raise RbgpRuntimeError(f"the fitted sparse covariance for {label} is not positive definite",
                                   hint="use kernel se-chordal or fewer inducing poses", param="kernel")
        stats.append((np.tril(bstate["Lm"]), np.tril(bstate["LB"]), np.asarray(bstate["c"])))
        Lm = stats[-1][0]
        rcond, info = lapack.dpocon(Lm, float(np.max(np.sum(np.abs(Lm @ Lm.T), axis=0))), uplo="L")
        at_bounds = [nm for nm, t in zip(free, st["theta"][0])
                     if min(abs(t - spec[nm].log_bounds[0]), abs(t - spec[nm].log_bounds[1])) < 1e-6]
        fits.append(SparseOutputFit(
            values=values, nlml=float(f), jitter=0.0, rcond=float(rcond) if info == 0 else 0.0, positive_definite=True,
            n_evaluations=st["evals"], n_infeasible=st["infeasible"], starts=st["records"], at_bounds=at_bounds,
            free=list(free), seconds=st["seconds"], kmm_jitter=float(bstate["rel"]), stages=st["stages"]))
        progress(f"{label}: bound {f:.6g} on all {n} points; evaluations per stage "
                 + ", ".join(f"{s['evaluations']} on {s['points']}" for s in st["stages"]))
    return fits, stats


def fit_sparse_gp(
    X,
    Y,
    kernel: Kernel,
    *,
    inducing: int = DEFAULT_INDUCING,
    inducing_method: str | None = None,
    noise=None,
    restarts: int = 3,
    seed: int = 0,
    shared: bool = False,
    fixed: dict | None = None,
    bounds: dict | None = None,
    max_iter: int = 200,
    progress=None,
    explore_size: int | None = None,
    final_evaluations: int = FINAL_EVALUATIONS,
    hyper_points: int | None = None,
    jitter: float = JITTER,
    hyper: str = "exact",
    jobs: int = 1,
) -> SparseGP:
    """Fit a sparse GP (SGPR) with ``inducing`` inducing inputs chosen among the rows of X.

    Parameters as :func:`rbgp_cli.gp.exact.fit_gp`, plus

    inducing : M, the number of inducing inputs (at most the number of distinct rows of X)
    inducing_method : "kmeans++" or "farthest" (:func:`select_inducing`), seeded by ``seed``
    final_evaluations : at most this many bound evaluations in the last stage (when stages before it ran)
    hyper_points : the bound that chooses the hyperparameters covers at most this many random points
        (default max(HYPER_FACTOR·M, HYPER_MIN_POINTS); ``0``: all n); the posterior always uses all n
    jitter : relative jitter of K_mm (:func:`sparse_bound_and_gradient`)
    hyper : where the hyperparameters come from (HYPER_SOURCES). ``"exact"`` (default): the exact GP's
        fit (:func:`rbgp_cli.gp.exact.fit_gp`, with ``noise``, ``restarts``, ``seed``, ``shared``,
        ``fixed``, ``bounds``, ``explore_size`` and ``jobs`` worker processes) on a random
        ``hyper_points`` of the points (default HYPER_EXACT_POINTS; 0: all), then the sparse posterior
        on all n points at those hyperparameters; the inducing
        inputs default to ``farthest`` (they then cover the region the data span evenly, where a
        random D² draw leaves gaps that the short length-scales of the exact fit do not bridge:
        position RMSE 0.18 against 0.29 m in the handover fold above). ``"bound"``: the stages below
        (the inducing inputs default to ``kmeans++``).

    With ``hyper="bound"`` the hyperparameters, per output or shared (docs/method.md §7), come in stages:

    1. *explore*: every start (the data-driven one and ``restarts − 1`` random ones) minimises the
       exact NLML on a random subset of ``explore_size`` points (default 400, the exact GP's tolerance
       EXPLORE_FTOL), and each distinct optimum within BASIN_GAP of the best gets its Hessian there
       by finite differences, as in the exact GP; ``explore_size=0`` runs the starts on the first
       bound stage instead (L-BFGS-B, racing);
    2. *the first bound stage*, on min(n, ``hyper_points``, max(4M, 2000)) random points: each explored optimum
       is polished as the exact GP polishes on all points (:func:`_polish_starts`: quasi-Newton from
       the subset's Hessian scaled to the stage, L-BFGS-B if that stalls); on a subset it stops with
       less than SUBSET_ATOL nats left to gain. Measured at n = 10⁵, M = 512 (synthetic field): 2–5
       bound evaluations per output;
    3. only with ``hyper_points`` above 4M: −F on nested random subsets of 16M, 64M, … points up to
       ``hyper_points``, each from the previous stage's best optimum (L-BFGS-B, relative tolerance
       STAGE_FTOL; a stage on k points at most max(3, STAGE_BUDGET·top/k) evaluations, the one on
       ``hyper_points`` ``final_evaluations``). An output whose hyperparameters moved by less than
       SETTLED_LOG (in log) between two bound stages stops there.

    Then one pass over all n points per output gives the posterior's statistics (O(n M²)). Why the
    hyperparameters come from max(4M, 2000) points by default: optimising the bound on all 10⁵ points
    of two synthetic fields (benchmarks/README.md) took 7–9× as long and moved the hyperparameters
    towards longer length-scales (with n ≫ M the bound's complexity term fades) while the held-out
    RMSE changed by at most 1 %; and 4M points with M inducing poses is nearly the exact GP's
    likelihood on as many points, more than the exact GP's default 2000.

    Stages run for all outputs before the next begins. Kernels with a fused cross gradient (the chordal
    kernel) keep nothing of size n × M; others keep one stage's pairwise arrays (n × M each). Same data,
    options and seed → the same inducing inputs and bit-identical hyperparameters.
    """
    from rbgp_cli.progress import as_progress

    X, Y = training_data(X, Y)
    if int(inducing) < 1:
        raise ValueError(f"the number of inducing inputs must be positive, got {inducing}")
    if hyper not in HYPER_SOURCES:
        raise ValueError(f"unknown source of hyperparameters {hyper!r}; expected one of {HYPER_SOURCES}")
    if inducing_method is None:
        inducing_method = "farthest" if hyper == "exact" else "kmeans++"
    restarts = max(1, int(restarts))
    explore = 400 if explore_size is None else int(explore_size)
    progress = as_progress(progress)
    n = len(Y)
    t_start = time.perf_counter()
    with blas_threads(0):
        Z = X[select_inducing(X, int(inducing), kernel, seed=seed, method=inducing_method)]
    M = len(Z)
    pre_mm = kernel.precompute(Z)
    ss = np.random.SeedSequence(int(seed))
    perm = np.random.default_rng(np.random.SeedSequence([int(seed), 3])).permutation(n)
    sub = np.sort(perm[: min(n, 600)])
    pre_sub = kernel.precompute(X[sub])
    targets, scale, seeds = fit_targets(Y, shared, ss)
    rngs = [np.random.default_rng(s) for s in seeds]
    specs = [free_spec(kernel, pre_sub, y, noise, fixed, bounds) for y, _ in targets]
    progress(f"sparse GP: {M} inducing poses ({inducing_method}) for {n} points")
    top, sizes = _stage_plan(hyper, hyper_points, n, M)
    state = _start_state(specs)
    if hyper == "exact" and any(not st["settled"] for st in state):
        _exact_hyperparameters(X, Y, kernel, perm[: min(n, top)], targets, specs, state, noise=noise, restarts=restarts,
                               seed=seed, shared=shared, fixed=fixed, bounds=bounds, max_iter=max_iter,
                               progress=progress, explore_size=explore_size, jobs=jobs)
    # BLAS single-threaded throughout: on this shared 2-core machine (load ~12) one bound evaluation at
    # n = 2000, M = 256 took 3.8 s with OpenBLAS's 2-thread pools and 0.16 s with one thread (measured;
    # the M × M Cholesky factorisations suffered most, 0.48 s each).
    with blas_threads(0), progress.task("training", total=len(targets) * (len(sizes) + (explore > 1)),
                                        unit="stages") as task:
        # 1. explore: every start on a small subset with the exact NLML
        if hyper == "exact":
            pass  # the exact GP's fit chose them (above)
        elif explore > 1:
            _explore_starts(kernel, X, perm, explore, targets, specs, rngs, state, restarts, max_iter, task)
        else:
            for (y, label), (spec, free), rng, st in zip(targets, specs, rngs, state):
                st["theta"] += [random_start(spec, free, rng) for _ in range(restarts - 1)]
                st["kinds"] += ["random"] * (restarts - 1)
        # 2. the bound on growing subsets, the last one all points
        blocks = _bound_stages(kernel, X, Z, pre_mm, perm, sizes, top, targets, specs, state, max_iter,
                               final_evaluations, jitter, task)
        # the posterior on all points at the optimum (the last stage's cached blocks if it had them all)
        if blocks is None or len(blocks.X) < n:
            blocks = RowBlocks(kernel, X, Z)  # cached (O(n M)) and shared by the outputs
        fits, stats = _posterior_fits(kernel, blocks, pre_mm, n, targets, specs, state, jitter, progress)
    gp = SparseGP(kernel, X, Y, Z, fits, shared=shared, y_scale=scale, stats=stats)
    gp.fit_seconds = time.perf_counter() - t_start
    # hyper="exact": the exact GP whose fit chose the hyperparameters, and its rows (not stored in model files)
    gp.hyper_gp, gp.hyper_rows = state[0].get("exact_gp", (None, None)) if state else (None, None)
    return gp
