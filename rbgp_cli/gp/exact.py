"""Exact Gaussian-process regression with hyperparameters from the marginal likelihood (docs/method.md §7).

One zero-mean GP per output dimension l (paper sec. 3.2, eq. 20–21), or one shared set of
hyperparameters for all outputs after scaling each by its root mean square (``shared=True``: one
Cholesky per evaluation for all outputs).

Negative log marginal likelihood (R&W Alg. 2.1) with C = K + σn² I = L Lᵀ and α = C⁻¹ y:

    NLML = ½ yᵀα + Σ_i log L_ii + (n/2) log 2π

and its gradient (R&W eq. 5.9) with W = ααᵀ − C⁻¹:

    ∂NLML/∂θ = −½ Σ_ij W_ij ∂C_ij/∂θ

Kernels provide Σ W ∘ ∂K/∂logθ directly (:meth:`Kernel.grad_contract`); the noise term is
∂C/∂log σn = 2σn² I, so its contribution is −σn² tr(W).

Indefinite kernels (docs/method.md §6: the paper's geodesic kernel is not PSD): where C fails its Cholesky,
the optimiser is told the point is infeasible (a large finite NLML, from which L-BFGS-B's line search
backs off) and keeps going. A fitted output is accepted only if C at the optimum passes Cholesky with
a reciprocal condition number above ``MIN_RCOND``; otherwise increasing jitter is added to the
diagonal and reported. If nothing works the fit raises :class:`RbgpRuntimeError` — a model whose
predictions can explode is never returned.

Starts (docs/method.md §7): L-BFGS-B in log space from the data-driven start plus ``restarts − 1`` random
ones from a seeded rng. The starts exist to find the best basin, and at n = 1752 all of them usually
end in the same one, each costing 15–50 full-size evaluations. So for n > 2·SUBSAMPLE_SIZE the starts
run on a random subsample of SUBSAMPLE_SIZE points (an evaluation there costs (400/1752)³ ≈ 1 % of a
full one). On all points the fit then polishes the best subsample optimum (and any other that is
nearly as good and distinct) by projected quasi-Newton steps whose first Hessian is the subsample's,
scaled to n points (:func:`_polish`): 4–10 evaluations on all points per output instead of 15–50.

Per-output fits can run in worker processes (``fit_gp(..., jobs=)``), one output per task, BLAS
single-threaded in each; every fit runs BLAS single-threaded, so its result never depends on the
machine's load or on ``jobs``.

All BLAS/LAPACK calls in the evaluation loop go through ``scipy.linalg`` (ECOSYSTEM.md §7).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import blas, lapack, solve_triangular

from rbgp_cli.compute import (blas_threads, fork_context, process_pool, start_workers, stop_pool, thread_pool,
                              thread_workers, worker_init)
from rbgp_cli.errors import RbgpRuntimeError
from rbgp_cli.kernels.base import Hyperparameter, Kernel, output_scale

__all__ = ["OutputFit", "GaussianProcess", "fit_gp", "nlml_and_gradient", "MIN_RCOND", "NOISE"]

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
_JITTERS = (0.0, 1e-10, 1e-8, 1e-6, 1e-4)
#: An infeasible start is moved by this much in log λ (down) and log σn (up), at most _START_MOVES times.
_START_STEP = math.log(1.25)
_START_MOVES = 16
#: Above 2·SUBSAMPLE_SIZE points the starts explore a random subsample of this size first; on all
#: points the best optimum is polished, and the optima of other starts that are distinct there (max
#: |Δ log θ| > DISTINCT_LOG) and whose subsample NLML is within BASIN_GAP of the best.
SUBSAMPLE_SIZE = 400
DISTINCT_LOG = 0.1
#: A subsample optimum whose NLML is worse than the best one's by more than this is not polished on
#: all points. The subsample is a uniform random subset, so its NLML difference estimates the full
#: one scaled by m/n: a gap of 10 there (a likelihood ratio of e⁻¹⁰) is a gap of ~10·n/m on all
#: points. On recorded demonstrations such optima were degenerate (σn at its lower bound, or λ
#: 5–10× off) and their polishes ended in the best optimum anyway, after 15–55 evaluations each.
BASIN_GAP = 10.0
#: ... and whose subsample NLML differs from every optimum already chosen by more than this: optima
#: that fit the subsample equally well at different θ lie on one flat ridge (on recorded motions: the
#: pure-noise fit, λ at its lower bound and σf → 0, where λ no longer matters), and their polishes
#: met in the same optimum after 17–36 evaluations each.
DISTINCT_NLML = 0.1
#: L-BFGS-B's relative-reduction tolerance on the subsample (its default is 2.2e-9).
EXPLORE_FTOL = 1e-7


# ----------------------------------------------------------------------------- linear algebra
#: Predictions with at least this many query × training pairs are spread over the free cores, in row
#: chunks on threads (numpy's ufuncs and BLAS release the GIL; the kernel's exp, arccos and products
#: dominate). One rollout step of 100 trajectories against 1752 training points (175 200 pairs) stays
#: on one thread: its chunks are ~0.2 ms of work each, and handing them over cost more than it saved
#: (the same rollout of 100 × 626 steps, chordal kernel, load 2.4 on 2 cores: 0.44 s wall / 0.53 s
#: CPU on two threads, 0.32–0.34 s on one).
PARALLEL_PREDICT_MIN = 1_000_000


def _prediction_workers(work: int) -> int:
    """Threads for a prediction of ``work`` query × training pairs (:func:`rbgp_cli.compute.thread_workers`
    above PARALLEL_PREDICT_MIN). At load 2 on 2 cores a rollout of 100 × 626 steps at n = 1752 took
    0.44 s (0.55 s CPU) on two threads and 0.33 s on one (chordal kernel; 0.66 s / 0.63 s with the
    arc kernel, measured)."""
    return thread_workers(work, PARALLEL_PREDICT_MIN)


def _cholesky(K: np.ndarray, noise_var: float, jitter: float = 0.0):
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


def _rcond(c: np.ndarray, K: np.ndarray, noise_var: float) -> float:
    """Reciprocal 1-norm condition number of C from its Cholesky factor (LAPACK dpocon)."""
    anorm = float(np.max(np.sum(np.abs(K), axis=0)) + noise_var)
    rcond, info = lapack.dpocon(c, anorm, uplo="L")
    return float(rcond) if info == 0 else 0.0


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
    if margin > 0 and _cholesky(K, (1.0 - margin) * s2) is None:
        return INFEASIBLE_NLML, np.zeros(len(grad_names))
    c = _cholesky(K, s2)
    if c is None:
        return INFEASIBLE_NLML, np.zeros(len(grad_names))
    alpha, info = lapack.dpotrs(c, y2, lower=1)  # Line 3 of R&W Alg. 2.1
    logdet_half = float(np.sum(np.log(np.diagonal(c))))
    nlml = 0.5 * float(np.sum(y2 * alpha)) + L * logdet_half + 0.5 * n * L * _LOG2PI
    if len(grad_names) == 0:
        return nlml, np.zeros(0)
    inv, info = lapack.dpotri(c, lower=1, overwrite_c=1)  # lower triangle of C⁻¹, upper is zero
    # W = Σ_l α_l α_lᵀ − L·C⁻¹, built in place (all on scipy's BLAS)
    W = inv
    W += inv.T  # full symmetric, diagonal doubled
    idx = np.arange(n)
    W[idx, idx] *= 0.5
    W *= -float(L)
    alpha_f = np.asfortranarray(alpha)
    W = blas.dgemm(1.0, alpha_f, alpha_f, beta=1.0, c=W, trans_b=1, overwrite_c=1)
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


# ----------------------------------------------------------------------------- results
@dataclass
class OutputFit:
    """What the fit of one output (or of all outputs, in shared mode) found and how.

    values : final hyperparameters {name: value} (noise_std included)
    nlml : negative log marginal likelihood at ``values`` (summed over outputs in shared mode, on the
        standardised outputs)
    jitter : diagonal jitter added to K + σn²I to pass Cholesky / the conditioning check (0 if none)
    rcond : reciprocal condition number of K + (σn² + jitter) I
    positive_definite : K + σn²I (without jitter) passed Cholesky and the conditioning check
    n_evaluations, n_infeasible : NLML evaluations on all n points, and how many of them met a
        non-PD matrix (evaluations on the exploration subsample are counted in ``subsample``)
    starts : per start {"start": {...}, "nlml": final, "status": message, "evaluations": k}
    at_bounds : names of free hyperparameters that ended at a bound
    guarded : the first optimum missed the noise margin (λ_min(K + σn²I) < NOISE_MARGIN σn², possible
        only with an indefinite kernel) and the output was refit with the margin enforced
    subsample : None, or {"size", "evaluations", "infeasible"} when the starts explored a random
        subsample first (n > 2·SUBSAMPLE_SIZE; see :func:`fit_gp`)
    calibration : None, or how σn² was scaled for the posterior by leaving demonstrations out
        (:func:`rbgp_cli.gp.calibration.demonstration_noise_factors`): then ``values[noise_std]`` is the
        posterior's √c σn and ``calibration["noise_std_fitted"]`` the σn at which ``nlml`` was found
    """

    values: dict
    nlml: float
    jitter: float = 0.0
    rcond: float = float("nan")
    positive_definite: bool = True
    n_evaluations: int = 0
    n_infeasible: int = 0
    starts: list = field(default_factory=list)
    at_bounds: list = field(default_factory=list)
    free: list = field(default_factory=list)
    seconds: float = 0.0
    guarded: bool = False
    subsample: dict | None = None
    calibration: dict | None = None

    def to_dict(self) -> dict:
        return {
            "values": {k: float(v) for k, v in self.values.items()},
            "nlml": float(self.nlml),
            "jitter": float(self.jitter),
            "rcond": float(self.rcond),
            "positive_definite": bool(self.positive_definite),
            "n_evaluations": int(self.n_evaluations),
            "n_infeasible": int(self.n_infeasible),
            "starts": self.starts,
            "at_bounds": list(self.at_bounds),
            "free": list(self.free),
            "seconds": float(self.seconds),
            "guarded": bool(self.guarded),
            "subsample": self.subsample,
            "calibration": self.calibration,
        }

    @classmethod
    def from_dict(cls, d: dict) -> "OutputFit":
        return cls(**{k: d[k] for k in cls.__dataclass_fields__ if k in d})


class GaussianProcess:
    """A fitted exact GP with L outputs on inputs X (n, d).

    ``groups`` lists the hyperparameter sets: one per output (default) or one shared by all outputs
    (``shared``), each with its Cholesky factor and its α = C⁻¹ y (on the RMS-scaled outputs
    y / scale in shared mode; predictions are scaled back). ``factors``: per group (L, α) as
    :func:`fit_gp` has just computed and checked them; without it they are computed and checked here
    (a loaded model). Predictions build the kernel block against X from matrix products
    (:meth:`Kernel.cross_plan`, :meth:`Kernel.cross_gram`).
    """

    def __init__(self, kernel: Kernel, X: np.ndarray, Y: np.ndarray, fits: list, shared: bool, y_scale=None, *,
                 factors=None):
        self.kernel = kernel
        self.X = np.ascontiguousarray(X, dtype=np.float64)
        self.Y = np.ascontiguousarray(np.asarray(Y, dtype=np.float64).reshape(len(X), -1))
        self.fits = list(fits)
        self.shared = bool(shared)
        self.y_scale = np.ones(self.Y.shape[1]) if y_scale is None else np.asarray(y_scale, dtype=np.float64)
        if factors is None:
            # single-threaded, as the fit that made them: a lone `rbgp rollout --count 60` at n = 1208
            # spent up to 4.7x the CPU of one thread here (two Cholesky factorisations per group on
            # the BLAS pool, whose threads then spin-wait), and was slower in wall time too (issue 24;
            # benchmarks/bench_rollout.py --threads)
            with blas_threads(0):
                self._factorise()
        else:
            # from fit_gp, which has just computed and checked them: per group (L, α)
            self._L = [np.asarray(Lc) for Lc, _a in factors]
            self._alpha = [np.asarray(a) for _Lc, a in factors]
        self._cross = None
        self._scaled = {}

    @property
    def n_outputs(self) -> int:
        return self.Y.shape[1]

    def _group_outputs(self):
        if self.shared:
            return [(self.fits[0], list(range(self.n_outputs)))]
        return [(f, [l]) for l, f in enumerate(self.fits)]

    def _factorise(self) -> None:
        """Cholesky factors and α for every group, with each fit's recorded jitter; verified."""
        pre = self.kernel.precompute(self.X)
        self._L = []
        self._alpha = []
        for fit, outs in self._group_outputs():
            K, _ = self.kernel.gram(pre, fit.values)
            s2 = fit.values[NOISE] ** 2
            c = _cholesky(K, s2, fit.jitter)
            if c is None or _cholesky(K, (1.0 - NOISE_MARGIN) * s2 + fit.jitter) is None:
                raise RbgpRuntimeError(
                    "the stored hyperparameters do not give a well-conditioned positive definite covariance",
                    hint="refit the model (rbgp train)",
                )
            y = self.Y[:, outs] / self.y_scale[outs]
            alpha, _ = lapack.dpotrs(c, np.asfortranarray(y), lower=1)
            self._L.append(np.tril(c))
            self._alpha.append(np.asarray(alpha))

    def predict(self, Xs, return_std: bool = False, noisy: bool = False, chunk_elements: int = 2_000_000,
                manage_threads: bool = True):
        """Predictive mean (and standard deviation) at query inputs.

        Parameters
        ----------
        Xs : shape (m, d)
        return_std : also return the standard deviation
        noisy : std of a new noisy observation (σ² + σn²) instead of the latent function's σ
        chunk_elements : query rows are processed in chunks of at most chunk_elements / n rows, so
            10⁵ query points never allocate n × 10⁵ at once

        Returns
        -------
        mean : shape (m, L);  std : shape (m, L) if requested.
        Latent variances k** − k*ᵀC⁻¹k* that come out negative (possible with an indefinite kernel, or
        from round-off) are clipped to 0; ``self.last_clipped`` counts them.

        ``manage_threads=False`` skips the BLAS thread limit (about 1 ms per call) for callers that set
        it once around many calls (rollouts: see :func:`blas_threads`). Otherwise BLAS runs as
        :func:`blas_threads` decides for n training points, and single-threaded when the rows are
        spread over this module's prediction threads (:func:`_prediction_workers`): those threads
        take the free cores already, and a BLAS pool in each of them would oversubscribe them.
        """
        if not manage_threads:
            return self._predict(Xs, return_std, noisy, chunk_elements)
        n = len(self.X)
        m = np.size(Xs) // max(self.X.shape[1], 1)
        with blas_threads(n if _prediction_workers(m * n) == 1 else 0):
            return self._predict(Xs, return_std, noisy, chunk_elements)

    def _predict(self, Xs, return_std, noisy, chunk_elements):
        Xs = np.ascontiguousarray(np.asarray(Xs, dtype=np.float64).reshape(-1, self.X.shape[1]))
        m, n = len(Xs), len(self.X)
        mean = np.empty((m, self.n_outputs))
        std = np.empty((m, self.n_outputs)) if return_std else None
        step = max(1, int(chunk_elements // max(n, 1)))
        block = getattr(self.kernel, "mean_block_elements", None)
        if block and not return_std and m * n > block:
            # cache-sized row blocks of equal size for a kernel that makes several elementwise passes
            # (not with the std, whose triangular solve prefers wide right-hand sides)
            step = min(step, -(-m // -(-m * n // block)))
        workers = _prediction_workers(m * n)
        if workers > 1:
            # at least one chunk per worker, so that large predictions use every core
            step = min(step, -(-m // workers))
        starts = range(0, m, step)
        self._cross_plan()  # before any threads
        if workers > 1 and len(starts) > 1:
            clipped = sum(thread_pool("predict").map(
                lambda a: self._predict_rows(Xs, a, a + step, mean, std, noisy), starts))
        else:
            clipped = sum(self._predict_rows(Xs, a, a + step, mean, std, noisy) for a in starts)
        self.last_clipped = int(clipped)
        return (mean, std) if return_std else mean

    def _cross_plan(self) -> dict:
        """The kernel's training-side data for predictions (:meth:`Kernel.cross_plan`), built once."""
        if self._cross is None:
            self._cross = self.kernel.cross_plan(self.X)
        return self._cross

    def _predict_rows(self, Xs, a, b, mean, std, noisy) -> int:
        """Mean (and std) of query rows a:b into ``mean`` / ``std``; returns how many variances were clipped."""
        Xc = Xs[a:b]
        plan = self._cross_plan()
        groups = self._group_outputs()
        # the pairwise distances once for all groups; with one group, distances and kernel fused
        pre = self.kernel.cross_precompute(plan, Xc) if len(groups) > 1 else None
        clipped = 0
        for g, ((fit, outs), Lc, alpha) in enumerate(zip(groups, self._L, self._alpha)):
            if pre is None:
                Ks = self.kernel.cross_gram(plan, Xc, fit.values)  # (mc, n)
            else:
                Ks, _ = self.kernel.gram(pre, fit.values)
            scale = self.y_scale[outs]
            alpha_scaled = self._alpha_scaled(g, alpha, scale)
            if len(outs) == mean.shape[1]:  # shared: all outputs at once, straight into the result
                np.matmul(Ks, alpha_scaled, out=mean[a:b])
            else:
                mean[a:b, outs] = Ks @ alpha_scaled
            if std is not None:
                # v = L⁻¹ k*, written over Ks (its transpose is the Fortran-ordered right-hand side)
                v = solve_triangular(Lc, Ks.T, lower=True, check_finite=False, overwrite_b=True)
                var = self.kernel.diag(Xc, fit.values) - np.einsum("ij,ij->j", v, v)
                clipped += int(np.sum(var < 0))
                var = np.maximum(var, 0.0)
                if noisy:
                    var = var + fit.values[NOISE] ** 2 + fit.jitter
                std[a:b, outs] = np.sqrt(var)[:, None] * scale
        return clipped

    def _alpha_scaled(self, group: int, alpha, scale) -> np.ndarray:
        """α · scale of a group (the outputs' scale folded into the mean's weights), built once."""
        cache = self._scaled
        if group not in cache:
            cache[group] = np.ascontiguousarray(alpha * scale)
        return cache[group]

    def predict_mean(self, Xs) -> np.ndarray:
        """Predictive mean, shape (m, L) (single-step mean prediction, docs/method.md §8)."""
        return self.predict(Xs)


# ----------------------------------------------------------------------------- fitting
def _free_spec(kernel: Kernel, pre: dict, y: np.ndarray, noise, fixed: dict | None, bounds: dict | None):
    """All hyperparameters (kernel + noise) with data-driven starts and bounds, and the free names."""
    spec = dict(kernel.default_hyperparameters(pre, y))
    sy = output_scale(y)
    if noise is None or noise == "learn":
        spec[NOISE] = Hyperparameter(NOISE, 0.1 * sy, (1e-6 * sy, 10.0 * sy))
    else:
        spec[NOISE] = Hyperparameter(NOISE, float(noise), (float(noise), float(noise)), fixed=True)
    for name, v in (fixed or {}).items():
        if name not in spec:
            raise ValueError(f"unknown hyperparameter {name!r}; known: {sorted(spec)}")
        spec[name] = Hyperparameter(name, float(v), (float(v), float(v)), fixed=True)
    for name, b in (bounds or {}).items():
        if name in spec and not spec[name].fixed:
            lo, hi = float(b[0]), float(b[1])
            spec[name] = Hyperparameter(name, min(max(spec[name].value, lo), hi), (lo, hi))
    free = [nm for nm in [*kernel.names, NOISE] if nm in spec and not spec[nm].fixed]
    return spec, free


def _random_start(spec: dict, free: list, rng: np.random.Generator) -> np.ndarray:
    """A random start in log space around the data-driven one: λ and λτ × e^U(−1.5,1), σf × e^U(−1,1),
    σn × e^U(−3,1), ρ1 ~ U(0.1, 0.9), each clipped into its bounds."""
    widths = {"length_scale": (-1.5, 1.0), "signal_std": (-1.0, 1.0), NOISE: (-3.0, 1.0), "time_scale": (-1.5, 1.0)}
    theta = np.empty(len(free))
    for i, nm in enumerate(free):
        h = spec[nm]
        lo, hi = h.log_bounds
        if nm == "rho_rot":
            t = math.log(rng.uniform(0.1, 0.9))
        else:
            a, b = widths.get(nm, (-1.0, 1.0))
            t = math.log(h.value) + rng.uniform(a, b)
        theta[i] = min(max(t, lo), hi)
    return theta


def _move_towards_feasible(theta, free, log_bounds, step: float, noise_step: float | None = None) -> np.ndarray:
    """One move of a point whose K + σn²I is not positive definite towards the region where it is:
    log λ down by ``step`` and log σn up by ``noise_step`` (default ``step``), within the bounds
    (σn also when λ is not free). Returns a new array."""
    theta = np.array(theta, dtype=np.float64)
    noise_step = step if noise_step is None else noise_step
    if "length_scale" not in free:
        noise_step = step
    for i, nm in enumerate(free):
        if nm == "length_scale":
            theta[i] = max(theta[i] - step, log_bounds[i][0])
        elif nm == NOISE:
            theta[i] = min(theta[i] + noise_step, log_bounds[i][1])
    return theta


class _Objective:
    """NLML and its gradient in log θ for one target (vector, or matrix in shared mode) on one set of
    points, counting evaluations and infeasible ones (non-PD C, or the noise margin missed)."""

    def __init__(self, kernel, pre, y, spec, free, margin=0.0, on_evaluation=None):
        self.kernel, self.pre, self.y, self.free, self.margin = kernel, pre, y, list(free), margin
        self.on_evaluation = on_evaluation
        self.fixed_values = {nm: h.value for nm, h in spec.items() if nm not in free}
        self.log_bounds = [spec[nm].log_bounds for nm in free]
        self.counter = {"evals": 0, "infeasible": 0}

    def values_of(self, theta) -> dict:
        v = dict(self.fixed_values)
        v.update({nm: math.exp(t) for nm, t in zip(self.free, theta)})
        return v

    def __call__(self, theta):
        theta = np.array(theta, dtype=np.float64)
        last = getattr(self, "_last", None)
        if last is not None and np.array_equal(last[0], theta):
            # the same point again (L-BFGS-B's first call at a start we have just checked)
            return last[1], last[2].copy()
        self.counter["evals"] += 1
        f, g = self._evaluate(theta)
        if self.on_evaluation is not None:
            self.on_evaluation()
        if f >= INFEASIBLE_NLML:
            self.counter["infeasible"] += 1
        self._last = (theta, f, np.array(g))
        return f, g

    def _evaluate(self, theta):
        # looked up at call time: the benchmarks time the evaluations by wrapping this function
        return nlml_and_gradient(self.kernel, self.pre, self.values_of(theta), self.y, self.free, self.margin)


def _fit_one(kernel, pre, y, spec, free, restarts, rng, max_iter, margin=0.0, theta_starts=None, kinds=None,
             ftol=None, on_evaluation=None):
    """Minimise the NLML for one target (vector, or matrix in shared mode) from several starts with L-BFGS-B.

    The starts are the data-driven one and ``restarts − 1`` random ones, or ``theta_starts`` (log
    values of the free hyperparameters) labelled ``kinds`` in the records. Returns (best (θ, NLML) or
    None, one record per start, evaluation counters, θ -> values, per start its optimum (θ, NLML) or
    None if it found no feasible point). ``on_evaluation()`` is called after every NLML evaluation."""
    from scipy.optimize import minimize

    obj = _Objective(kernel, pre, y, spec, free, margin, on_evaluation)
    log_bounds = obj.log_bounds
    penalty = {"ref": None}
    seen = {"best": None}

    def objective(theta):
        f, g = obj(theta)
        if f < INFEASIBLE_NLML and (seen["best"] is None or f < seen["best"][1]):
            seen["best"] = (np.array(theta, dtype=np.float64), f)
        if f >= INFEASIBLE_NLML and penalty["ref"] is not None:
            # Infeasible: report a value well above this run's start (so the line search backs
            # off) but not so far above that its interpolation collapses to a zero step, which
            # L-BFGS-B would take for convergence.
            ref = penalty["ref"]
            return ref + max(10.0, abs(ref)), np.zeros_like(g)
        return f, g

    if theta_starts is not None:
        starts = [np.array(t, dtype=np.float64) for t in theta_starts]
        kinds = list(kinds) if kinds is not None else ["given"] * len(starts)
    else:
        starts = [np.array([math.log(spec[nm].value) for nm in free])]
        starts += [_random_start(spec, free, rng) for _ in range(max(0, restarts - 1))]
        kinds = ["data-driven"] + ["random"] * (len(starts) - 1)
    best = None
    records = []
    optima = []
    for s, theta0 in enumerate(starts):
        theta0 = np.clip(theta0, [b[0] for b in log_bounds], [b[1] for b in log_bounds])
        # an infeasible start is moved in small steps towards shorter length-scales and more
        # noise, where K + σn²I is positive definite (the optimum of the arc kernel often lies just
        # inside that boundary, so large steps would land far from it)
        penalty["ref"] = None
        for _ in range(_START_MOVES):
            f0, _g = objective(theta0)
            if f0 < INFEASIBLE_NLML:
                break
            theta0 = _move_towards_feasible(theta0, free, log_bounds, _START_STEP)
        ev0 = obj.counter["evals"]
        penalty["ref"] = f0 if f0 < INFEASIBLE_NLML else None
        if not free:
            res_x, res_f, msg = theta0, f0, "no free hyperparameters"
        else:
            seen["best"] = None
            options = {"maxiter": max_iter} if ftol is None else {"maxiter": max_iter, "ftol": ftol}
            res = minimize(objective, theta0, jac=True, method="L-BFGS-B", bounds=log_bounds, options=options)
            msg = str(res.message)
            # the best feasible point this run evaluated: after an abnormal line-search end res.x may be
            # an infeasible trial point and res.fun the penalty (or another point's value)
            res_x, res_f = seen["best"] if seen["best"] is not None else (res.x, INFEASIBLE_NLML)
        records.append({
            "start": {nm: float(math.exp(t)) for nm, t in zip(free, theta0)},
            "nlml": float(res_f),
            "status": msg,
            "evaluations": obj.counter["evals"] - ev0,
            "kind": kinds[s],
        })
        if res_f < INFEASIBLE_NLML:
            optima.append((np.array(res_x), res_f))
            if best is None or res_f < best[1]:
                best = (np.array(res_x), res_f)
        else:
            optima.append(None)
    return best, records, obj.counter, obj.values_of, optima


# ----------------------------------------------------------------------------- polish on all points
#: The polish on all points stops when the NLML decrease that Newton's model still predicts is below
#: POLISH_RTOL · max(|NLML|, n). At n = 1752 that is ~2e-4: hyperparameters within ~0.1 % of the
#: optimum along any direction of curvature ≳ 100 (the likelihood is that flat only along ridges
#: where predictions do not change either).
POLISH_RTOL = 1e-7
#: A polish that has not converged after this many evaluations on all points hands over to L-BFGS-B.
POLISH_MAX_EVALS = 25
#: Log step of the finite-difference Hessian on the subsample.
_FD_STEP = 1e-4
#: An infeasible polish start (the subsample optimum of an indefinite kernel often lies just outside
#: the positive definite region of all points: at n = 1752 the optimum's λ was ~18 % shorter) moves λ
#: down by this factor per try; σn, which the subsample estimates well, stays.
_POLISH_MOVE = math.log(1.1)
_POLISH_MOVE_NOISE = 0.0
#: Largest polish step in any log hyperparameter (a factor e).
_MAX_STEP = 1.0


def _fd_hessian(obj: _Objective, theta) -> np.ndarray | None:
    """Hessian of the NLML in log θ by central differences of the analytic gradient (2p evaluations,
    symmetrised); None if a neighbour is infeasible or the result is not finite."""
    p = len(theta)
    H = np.empty((p, p))
    for i in range(p):
        e = np.zeros(p)
        e[i] = _FD_STEP
        fp, gp = obj(theta + e)
        fm, gm = obj(theta - e)
        if fp >= INFEASIBLE_NLML or fm >= INFEASIBLE_NLML:
            return None
        H[:, i] = (gp - gm) / (2.0 * _FD_STEP)
    H = 0.5 * (H + H.T)
    return H if np.all(np.isfinite(H)) else None


def _polish(obj: _Objective, theta0, H, n: int, known=(), max_evals: int = POLISH_MAX_EVALS,
            atol: float | None = None) -> dict:
    """Minimise ``obj`` from ``theta0`` (near the optimum) by a projected quasi-Newton method.

    Steps p = −H⁻¹g on the hyperparameters that are not held at a bound by their gradient (H made
    positive definite by taking |eigenvalues|), at most _MAX_STEP in any log θ, with backtracking
    until the NLML decreases (Armijo); H starts from ``H`` (the subsample's Hessian scaled to n
    points: the NLML is a sum over the points) and is updated by damped BFGS. Stops when the
    predicted decrease −½gᵀp < POLISH_RTOL · max(|NLML|, n) (or < ``atol`` nats if given) ("converged"), when the line search
    cannot decrease the NLML ("stalled"), after ``max_evals`` evaluations ("budget"), or when it
    comes within DISTINCT_LOG of an optimum in ``known`` (θ, NLML) without being better than it
    ("joined an earlier basin").

    Returns {"theta", "nlml" (INFEASIBLE_NLML if no feasible point was found), "status", "start"}.
    """
    lo = np.array([b[0] for b in obj.log_bounds])
    hi = np.array([b[1] for b in obj.log_bounds])
    theta = np.clip(np.array(theta0, dtype=np.float64), lo, hi)
    ev0 = obj.counter["evals"]
    f, g = obj(theta)
    for _ in range(_START_MOVES):
        if f < INFEASIBLE_NLML:
            break
        theta = _move_towards_feasible(theta, obj.free, obj.log_bounds, _POLISH_MOVE, _POLISH_MOVE_NOISE)
        f, g = obj(theta)
    start = theta.copy()
    if f >= INFEASIBLE_NLML:
        return {"theta": theta, "nlml": f, "status": "no feasible start", "start": start}
    # a positive definite start (|eigenvalues|), which damped BFGS keeps positive definite
    w, V = np.linalg.eigh(0.5 * (H + H.T))
    w = np.maximum(np.abs(w), 1e-10 * max(float(np.max(np.abs(w))), 1e-300))
    H = (V * w) @ V.T
    status = "budget"
    while obj.counter["evals"] - ev0 < max_evals:
        held = ((theta <= lo + 1e-12) & (g > 0)) | ((theta >= hi - 1e-12) & (g < 0))
        F = ~held
        p = np.zeros_like(theta)
        if np.any(F):
            w, V = np.linalg.eigh(H[np.ix_(F, F)])
            w = np.abs(w)
            w = np.maximum(w, 1e-10 * max(float(np.max(w)), 1e-300))
            p[F] = -(V @ ((V.T @ g[F]) / w))
        decrease = -0.5 * float(g @ p)
        if decrease <= (POLISH_RTOL * max(abs(f), n) if atol is None else atol):
            status = "converged"
            break
        p *= min(1.0, _MAX_STEP / float(np.max(np.abs(p))))
        a = 1.0
        accepted = False
        while obj.counter["evals"] - ev0 < max_evals:
            t_new = np.clip(theta + a * p, lo, hi)
            d = t_new - theta
            if float(np.max(np.abs(d))) < 1e-10:
                break
            f_new, g_new = obj(t_new)
            gd = float(g @ d)
            if f_new < INFEASIBLE_NLML and f_new <= f + 1e-4 * gd:
                accepted = True
                break
            if f_new >= INFEASIBLE_NLML:
                a *= 0.5
            else:  # minimum of the quadratic through f, g·d and f_new, kept within [0.1a, 0.5a]
                a *= min(0.5, max(0.1, -gd / (2.0 * (f_new - f - gd))))
        if not accepted:
            status = "stalled" if obj.counter["evals"] - ev0 < max_evals else "budget"
            break
        s, yv = d, g_new - g
        Hs = H @ s
        sHs, sy = float(s @ Hs), float(s @ yv)
        if sHs > 0:
            if sy < 0.2 * sHs:  # Powell's damping keeps H positive definite
                r = 0.8 * sHs / (sHs - sy)
                yv = r * yv + (1.0 - r) * Hs
                sy = float(s @ yv)
            H = H - np.outer(Hs, Hs) / sHs + np.outer(yv, yv) / sy
        theta, f, g = t_new, f_new, g_new
        if any(np.max(np.abs(theta - tk)) <= DISTINCT_LOG and f >= fk - POLISH_RTOL * max(abs(fk), n)
               for tk, fk in known):
            status = "joined an earlier basin"
            break
    return {"theta": theta, "nlml": f, "status": status, "start": start}


def _smooth_start(spec: dict, free: list) -> np.ndarray | None:
    """A start at long length scales (4 × the data-driven λ, 10 × λτ, σf = RMS(y), σn = RMS(y)/2) for
    fits whose best optimum is the all-noise basin (:func:`_all_noise`); None if σf or σn is fixed.
    On 400-point subsets of recorded motions every start of some outputs ends in an optimum that on
    more points is the all-noise basin (σf ≪ σn, λ and λτ at their lower bounds), which neither
    L-BFGS-B nor the polish leaves, while a structured optimum at long length scales is far better:
    handover recordings, 964 points: 1742 against 1199; sample_data at the recorded rate, 2000 points
    of a crossval fold (the exact GP): vx 711, vy 763, vz 528 against 320, 332, 239 from this start."""
    if "signal_std" not in free or NOISE not in free:
        return None
    sy = spec["signal_std"].value
    start = {"signal_std": sy, NOISE: 0.5 * sy}
    if "length_scale" in spec:
        start["length_scale"] = 4.0 * spec["length_scale"].value
    if "time_scale" in spec:
        start["time_scale"] = 10.0 * spec["time_scale"].value
    theta = np.array([math.log(start.get(nm, spec[nm].value)) for nm in free])
    lo = np.array([spec[nm].log_bounds[0] for nm in free])
    hi = np.array([spec[nm].log_bounds[1] for nm in free])
    return np.clip(theta, lo, hi)


def _all_noise(free, theta) -> bool:
    """σf < σn at log hyperparameters θ: the optimum explains less than the noise (False when either
    is fixed)."""
    v = dict(zip(free, theta))
    return "signal_std" in v and NOISE in v and v["signal_std"] < v[NOISE]


def _optima_best(optima) -> float:
    """The lowest NLML among a list of optima (θ, NLML) or None entries (inf if there is none)."""
    return min((o[1] for o in optima if o is not None), default=math.inf)


def _meets_margin(kernel, pre, values, K=None) -> bool:
    """λ_min(K + σn²I) >= NOISE_MARGIN σn² (always true for a positive semi-definite kernel)."""
    if K is None:
        K, _ = kernel.gram(pre, values)
    return _cholesky(K, (1.0 - NOISE_MARGIN) * values[NOISE] ** 2) is not None


def _accept(kernel, pre, y, values, K=None):
    """Check C = K + σn²I at the optimum; add jitter from a ladder if needed.

    Returns (jitter, rcond, pd, Cholesky factor) or (None, 0.0, False, None)."""
    if K is None:
        K, _ = kernel.gram(pre, values)
    s2 = values[NOISE] ** 2
    scale = float(np.mean(np.diagonal(K))) + s2
    for j, rel in enumerate(_JITTERS):
        jitter = rel * scale
        c = _cholesky(K, s2, jitter)
        if c is None:
            continue
        rc = _rcond(c, K, s2 + jitter)
        if rc >= MIN_RCOND:
            return jitter, rc, (j == 0), c
    return None, 0.0, False, None


@dataclass(frozen=True)
class _FitOptions:
    noise: object
    restarts: int
    fixed: dict | None
    bounds: dict | None
    max_iter: int


def _fit_target(kernel, pre, y, label, rng, o: _FitOptions, sub=None, pre_sub=None, on_evaluation=None):
    """Fit one target (an output, or all outputs scaled in shared mode): returns (OutputFit, L, α)
    with L the lower Cholesky factor of K + (σn² + jitter)I at the optimum and α = C⁻¹y."""
    t0 = time.perf_counter()
    n = len(y)
    spec, free = _free_spec(kernel, pre, y, o.noise, o.fixed, o.bounds)
    obj = _Objective(kernel, pre, y, spec, free, on_evaluation=on_evaluation)
    values_of = obj.values_of
    best, records, sub_info = None, [], None
    counter = {"evals": 0, "infeasible": 0}
    if sub is not None and free:
        # Explore: every start on the subsample. On all points: a quasi-Newton polish of the best
        # subsample optimum, and of each other optimum that lies in a basin not reached before.
        _b, records_s, counter_s, _v, optima = _fit_one(kernel, pre_sub, y[sub], spec, free, o.restarts, rng, o.max_iter,
                                                        ftol=EXPLORE_FTOL, on_evaluation=on_evaluation)
        records = [{**r, "kind": r["kind"] + f" (subsample of {len(sub)})"} for r in records_s]
        basins, basin_nlml = [], []
        for theta, f_s in sorted((x for x in optima if x is not None), key=lambda t: t[1]):
            if (f_s <= _optima_best(optima) + BASIN_GAP
                    and all(np.max(np.abs(theta - b)) > DISTINCT_LOG for b in basins)
                    and all(abs(f_s - fb) > DISTINCT_NLML for fb in basin_nlml)):
                basins.append(theta)
                basin_nlml.append(f_s)
        obj_s = _Objective(kernel, pre_sub, y[sub], spec, free, on_evaluation=on_evaluation)
        polished = []
        for theta_s in basins:
            ev0 = obj.counter["evals"]
            H = _fd_hessian(obj_s, theta_s)
            if H is not None:
                res = _polish(obj, theta_s, H * (n / len(sub)), n, polished)
                th, fv, status, start = res["theta"], res["nlml"], res["status"], res["start"]
            else:
                th, fv, status, start = theta_s, INFEASIBLE_NLML, "no Hessian on the subsample", theta_s
            records.append({"start": {nm: float(math.exp(t)) for nm, t in zip(free, start)}, "nlml": float(fv),
                            "status": status, "evaluations": obj.counter["evals"] - ev0, "kind": "polish (all points)"})
            if status in ("budget", "stalled") or fv >= INFEASIBLE_NLML:
                # hand over to L-BFGS-B on all points (from the polish's best point, or, if it found
                # no feasible one, from the subsample optimum with the usual infeasible-start moves)
                b2, rec2, c2, _v, _o = _fit_one(kernel, pre, y, spec, free, 1, rng, o.max_iter, theta_starts=[th],
                                                kinds=["L-BFGS-B after the polish (all points)"],
                                                on_evaluation=on_evaluation)
                records += rec2
                counter = {k: counter[k] + c2[k] for k in counter}
                if b2 is not None:
                    th, fv = b2
            if fv < INFEASIBLE_NLML:
                polished.append((np.array(th), fv))
                if best is None or fv < best[1]:
                    best = (np.array(th), fv)
        counter = {k: counter[k] + obj.counter[k] for k in counter}
        sub_info = {"size": len(sub), "evaluations": counter_s["evals"] + obj_s.counter["evals"],
                    "infeasible": counter_s["infeasible"] + obj_s.counter["infeasible"]}
    if best is None:
        best, rec_full, c_full, _v, _ = _fit_one(kernel, pre, y, spec, free, o.restarts, rng, o.max_iter,
                                                 on_evaluation=on_evaluation)
        records += rec_full
        counter = {k: counter[k] + c_full[k] for k in counter}
    smooth = _smooth_start(spec, free)
    if best is not None and smooth is not None and _all_noise(free, best[0]):
        # the all-noise basin: one more start at long length scales, on all points, kept if better
        b2, rec2, c2, _v, _ = _fit_one(kernel, pre, y, spec, free, 1, rng, o.max_iter, theta_starts=[smooth],
                                       kinds=["smooth start, the best optimum being all noise (all points)"],
                                       on_evaluation=on_evaluation)
        records += rec2
        counter = {k: counter[k] + c2[k] for k in counter}
        if b2 is not None and b2[1] < best[1]:
            best = b2
    guarded = False
    K = None
    if best is not None:
        K, _ = kernel.gram(pre, values_of(best[0]))
        if not _meets_margin(kernel, pre, values_of(best[0]), K):
            # The optimum sits where K's negative eigenvalues nearly cancel the noise (indefinite
            # kernel, docs/method.md §6): refit with the margin enforced at every evaluation, from that
            # optimum (moved into the feasible region by the infeasible-start rule) and the
            # data-driven start.
            guarded = True
            data_start = [math.log(spec[nm].value) for nm in free]
            best2, records2, counter2, _v, _ = _fit_one(
                kernel, pre, y, spec, free, 1, rng, o.max_iter, margin=NOISE_MARGIN,
                theta_starts=[best[0], data_start], kinds=["optimum (margin)", "data-driven (margin)"],
                on_evaluation=on_evaluation)
            records += records2
            counter = {k: counter[k] + counter2[k] for k in counter}
            best = best2
            K = None
    if best is None:
        raise RbgpRuntimeError(
            f"no hyperparameters gave a positive definite covariance for {label}",
            hint="use --kernel se-chordal, fix a smaller length-scale, or learn the noise",
        )
    values = values_of(best[0])
    if K is None:
        K, _ = kernel.gram(pre, values)
    jitter, rc, pd, c = _accept(kernel, pre, y, values, K)
    if jitter is None:
        raise RbgpRuntimeError(
            f"the fitted covariance for {label} is numerically singular even with jitter",
            hint="use --kernel se-chordal or subsample fewer, less redundant points",
        )
    del K
    alpha, _info = lapack.dpotrs(c, np.asfortranarray(y.reshape(n, -1)), lower=1)
    at_bounds = []
    for nm, t in zip(free, best[0]):
        lo, hi = spec[nm].log_bounds
        if abs(t - lo) < 1e-6 or abs(t - hi) < 1e-6:
            at_bounds.append(nm)
    fit = OutputFit(
        values=values, nlml=float(best[1]), jitter=float(jitter), rcond=rc, positive_definite=pd,
        n_evaluations=counter["evals"], n_infeasible=counter["infeasible"], starts=records,
        at_bounds=at_bounds, free=list(free), seconds=time.perf_counter() - t0, guarded=guarded,
        subsample=sub_info,
    )
    return fit, np.tril(c), np.asarray(alpha)


# ----------------------------------------------------------------------------- worker processes
_WORKER: dict = {}


def _worker_fit(task):
    """Fit one output in a worker; the pairwise distances are computed once per worker and fit call."""
    token, X, y, kernel, l, label, seeds, o, sub = task
    cached = _WORKER.get("pre")
    if cached is None or cached[0] != token:
        _WORKER["pre"] = None  # free the previous call's matrices first
        pre = kernel.precompute(X)
        pre_sub = kernel.precompute(X[sub]) if sub is not None else None
        _WORKER["pre"] = cached = (token, pre, pre_sub)
    _token, pre, pre_sub = cached
    return l, _fit_target(kernel, pre, y, label, np.random.default_rng(seeds), o, sub, pre_sub)


def _fit_outputs_in_workers(X, Y, kernel, o, seeds, sub, jobs, progress, task):
    """Per-output fits in ``jobs`` worker processes (BLAS single-threaded in each); results in output order."""
    import os

    token = (os.getpid(), time.perf_counter_ns())
    L = Y.shape[1]
    tasks = [(token, X, np.ascontiguousarray(Y[:, l]), kernel, l, f"output {l}", seeds[l], o, sub) for l in range(L)]
    results = [None] * L
    failures = {}
    ctx = fork_context()
    if ctx.get_start_method() == "fork":
        # the pairwise distances once, here: forked workers read them (copy-on-write, never written)
        # instead of computing them once each (measured: 6 workers spent 30 % more CPU than one process)
        _WORKER["pre"] = (token, kernel.precompute(X), kernel.precompute(X[sub]) if sub is not None else None)
    try:
        return _collect_worker_fits(tasks, jobs, ctx, progress, task, results, failures)
    finally:
        _WORKER.pop("pre", None)


def _collect_worker_fits(tasks, jobs, ctx, progress, task, results, failures):
    from concurrent.futures import as_completed
    from concurrent.futures.process import BrokenProcessPool

    # workers that end with this process (killed or not), and end at once on an error or Ctrl-C
    with process_pool(jobs, context=ctx, init=worker_init) as pool:
        with start_workers():
            futures = {pool.submit(_worker_fit, t): t[4] for t in tasks}
        try:
            for fut in as_completed(futures):
                if fut.cancelled():
                    continue
                exc = fut.exception()
                if exc is not None:
                    # the outputs not started yet are not needed; the running ones finish
                    failures[futures[fut]] = exc
                    for other in futures:
                        other.cancel()
                    continue
                l, res = fut.result()
                results[l] = res
                fit = res[0]
                # the worker's evaluations, counted as the fit in this process counts them
                total = fit.n_evaluations + (fit.subsample["evaluations"] if fit.subsample else 0)
                task.update(status=f"output {l}: {total} evaluations")
                task.advance()
                _report(progress, f"output {l}", fit)
        except BaseException:
            stop_pool(pool)
            raise
    if failures:
        # the error of the first output that failed, as the fit in one process would raise it
        first = min(failures)
        if isinstance(failures[first], BrokenProcessPool):
            raise RbgpRuntimeError("a worker process fitting the outputs ended unexpectedly (out of memory?)",
                                   hint="train with --jobs 1") from failures[first]
        raise failures[first]
    return results


def _report(progress, label, fit) -> None:
    explored = f" + {fit.subsample['evaluations']} on a {fit.subsample['size']}-point subset" if fit.subsample else ""
    progress(f"{label}: NLML {fit.nlml:.4g} after {fit.n_evaluations} evaluations{explored}"
             f" ({fit.n_infeasible} infeasible), {fit.seconds:.2f} s")


# ----------------------------------------------------------------------------- fit_gp
def fit_gp(
    X,
    Y,
    kernel: Kernel,
    *,
    noise=None,
    restarts: int = 3,
    seed: int = 0,
    shared: bool = False,
    fixed: dict | None = None,
    bounds: dict | None = None,
    max_iter: int = 200,
    progress=None,
    explore_size: int | None = None,
    jobs: int = 1,
) -> GaussianProcess:
    """Fit one GP per output column of Y (or one shared set of hyperparameters) by minimising the NLML.

    Parameters
    ----------
    X : shape (n, d) — inputs (e.g. poses (rx, ry, rz, x, y, z))
    Y : shape (n, L) — outputs (e.g. velocities (ωx, ωy, ωz, vx, vy, vz))
    kernel : a :class:`Kernel`
    noise : None / "learn" to learn σn, or a number to fix σn (the paper fixes σn = 1)
    restarts : number of starts per output: the data-driven start plus ``restarts − 1`` random ones.
        With more than 2·``explore_size`` points every start runs with L-BFGS-B on a random
        subsample of ``explore_size`` points (the same for all outputs, drawn from ``seed``). On all
        n points the best subsample optimum is then polished by a quasi-Newton method whose first
        Hessian is the subsample's (finite differences of the gradient, scaled by n / explore_size),
        usually in 4–10 evaluations, as is the optimum of any other start that reached a basin of
        its own (its log θ more than DISTINCT_LOG from a better one's); the fit keeps the best. A
        polish that does not converge hands over to L-BFGS-B.
    explore_size : size of that subsample (default SUBSAMPLE_SIZE = 400); 0 runs every start with
        L-BFGS-B on all points
    seed : seeds the random starts (same data, options and seed → bit-identical hyperparameters)
    shared : one set of hyperparameters for all outputs, each output scaled by its root mean square
    fixed : {name: value} hyperparameters to hold fixed (signal_std, length_scale, rho_rot, noise_std)
    bounds : {name: (low, high)} to override the data-driven bounds
    progress : optional :class:`rbgp_cli.progress.Progress` (or callable(str) for the messages): a
        task "training" over the outputs (one in shared mode) whose status counts the evaluations of
        the output being fitted (in worker processes: the outputs done), and one message per fitted
        output
    jobs : worker processes for the per-output fits (each output in one worker, BLAS
        single-threaded there; the results do not depend on ``jobs``); 1 fits in this process.
        :func:`rbgp_cli.compute.default_jobs` gives the usual choice. Ignored with ``shared`` or a single output.
    """
    X = np.ascontiguousarray(np.asarray(X, dtype=np.float64))
    Y = np.asarray(Y, dtype=np.float64).reshape(len(X), -1)
    if len(X) < 2:
        raise ValueError("a GP needs at least 2 training points")
    if not (np.all(np.isfinite(X)) and np.all(np.isfinite(Y))):
        raise ValueError("training inputs and outputs must be finite")
    restarts = max(1, int(restarts))
    explore = SUBSAMPLE_SIZE if explore_size is None else int(explore_size)
    if explore < 0:
        raise ValueError(f"explore_size must be >= 0, got {explore_size}")
    jobs = int(jobs)
    if jobs < 1:
        raise ValueError(f"jobs must be >= 1, got {jobs}")
    o = _FitOptions(noise=noise, restarts=restarts, fixed=fixed, bounds=bounds, max_iter=int(max_iter))
    from rbgp_cli.progress import as_progress

    progress = as_progress(progress)
    # BLAS single-threaded whatever the machine: the optimiser's path must not depend on how busy the
    # machine is (a 2-thread pool changes the round-off, and on the arc kernel's indefinite edge that
    # changed an optimum), and parallelism comes from the worker processes
    with blas_threads(0), progress.task("training", total=1 if shared else Y.shape[1], unit="outputs") as task:
        return _fit_gp(X, Y, kernel, o, seed, shared, progress, explore, jobs, task)


def _fit_gp(X, Y, kernel, o, seed, shared, progress, explore, jobs, task):
    L = Y.shape[1]
    n = len(X)
    ss = np.random.SeedSequence(int(seed))
    sub = None
    if explore > 1 and n > 2 * explore:
        sub = np.sort(np.random.default_rng(np.random.SeedSequence([int(seed), 1])).choice(n, explore, replace=False))
    if shared:
        scale = np.array([output_scale(Y[:, l]) for l in range(L)])
        targets = [(Y / scale, "all outputs")]
        seeds = [ss]
    else:
        scale = None
        targets = [(Y[:, l], f"output {l}") for l in range(L)]
        seeds = ss.spawn(L)
    if jobs > 1 and len(targets) > 1:
        jobs = min(jobs, len(targets))
        progress(f"fitting {len(targets)} outputs in {jobs} worker processes")
        results = _fit_outputs_in_workers(X, Y, kernel, o, seeds, sub, jobs, progress, task)
    else:
        pre = kernel.precompute(X)
        pre_sub = kernel.precompute(X[sub]) if sub is not None else None
        results = []
        for (y, label), s in zip(targets, seeds):
            evaluations = [0]

            def tick(label=label, evaluations=evaluations):
                evaluations[0] += 1
                task.update(status=f"{label}: {evaluations[0]} evaluations")

            res = _fit_target(kernel, pre, y, label, np.random.default_rng(s), o, sub, pre_sub, on_evaluation=tick)
            results.append(res)
            task.advance()
            _report(progress, label, res[0])
    return GaussianProcess(kernel, X, Y, [r[0] for r in results], shared=shared, y_scale=scale,
                           factors=[(r[1], r[2]) for r in results])
