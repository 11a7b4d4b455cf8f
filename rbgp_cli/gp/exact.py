"""Exact Gaussian-process regression with hyperparameters from the marginal likelihood (MATH.md §7).

One zero-mean GP per output dimension l (paper sec. 3.2, eq. 20–21), or one shared set of
hyperparameters for all outputs after scaling each by its root mean square (``shared=True``: one
Cholesky per evaluation for all outputs).

Negative log marginal likelihood (R&W Alg. 2.1) with C = K + σn² I = L Lᵀ and α = C⁻¹ y:

    NLML = ½ yᵀα + Σ_i log L_ii + (n/2) log 2π

and its gradient (R&W eq. 5.9) with W = ααᵀ − C⁻¹:

    ∂NLML/∂θ = −½ Σ_ij W_ij ∂C_ij/∂θ

Kernels provide Σ W ∘ ∂K/∂logθ directly (:meth:`Kernel.grad_contract`); the noise term is
∂C/∂log σn = 2σn² I, so its contribution is −σn² tr(W).

Indefinite kernels (MATH.md §6: the paper's geodesic kernel is not PSD): where C fails its Cholesky,
the optimiser is told the point is infeasible (a large finite NLML, from which L-BFGS-B's line search
backs off) and keeps going. A fitted output is accepted only if C at the optimum passes Cholesky with
a reciprocal condition number above ``MIN_RCOND``; otherwise increasing jitter is added to the
diagonal and reported. If nothing works the fit raises :class:`RbgpRuntimeError` — a model whose
predictions can explode is never returned.

Starts (MATH.md §7): L-BFGS-B in log space from the data-driven start plus ``restarts − 1`` random
ones from a seeded rng. The starts exist to find the best basin, and at n = 1752 all of them usually
end in the same one, each costing 15–50 full-size evaluations. So for n > 2·SUBSAMPLE_SIZE the starts
run on a random subsample of SUBSAMPLE_SIZE points (an evaluation there costs (400/1752)³ ≈ 1 % of a
full one). On all points the fit then runs the data-driven start, and polishes the optimum of each
random start that reached a basin (on the subsample) that no earlier start had reached.

All BLAS/LAPACK calls in the evaluation loop go through ``scipy.linalg`` (ECOSYSTEM.md §7).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import blas, lapack, solve_triangular

from rbgp_cli.errors import RbgpRuntimeError
from rbgp_cli.kernels.base import Hyperparameter, Kernel, output_scale

__all__ = ["OutputFit", "GaussianProcess", "fit_gp", "nlml_and_gradient", "blas_threads", "MIN_RCOND", "NOISE"]

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
#: Above 2·SUBSAMPLE_SIZE points the starts explore a random subsample of this size first; only the
#: random starts whose optima are distinct there (max |Δ log θ| > DISTINCT_LOG) are polished on all points.
SUBSAMPLE_SIZE = 400
DISTINCT_LOG = 0.1


# ----------------------------------------------------------------------------- linear algebra
#: Below this many training points BLAS runs single-threaded: a 2-thread OpenBLAS pool costs more
#: in synchronisation than it saves on small matrices, and on a loaded machine its spin-waiting made
#: one NLML evaluation at n = 80 take 8–150 ms instead of 0.5 ms (measured).
SINGLE_THREAD_BELOW = 700


_CONTROLLER = []


def blas_threads(n: int):
    """Context manager: BLAS/LAPACK single-threaded for problems with n < SINGLE_THREAD_BELOW points
    (n = 0 forces it). The threadpoolctl controller is built once: building it scans the loaded
    libraries (about 0.9 ms), reusing it costs about 0.015 ms."""
    import contextlib

    if n >= SINGLE_THREAD_BELOW:
        return contextlib.nullcontext()
    if not _CONTROLLER:
        try:
            from threadpoolctl import ThreadpoolController
        except ImportError:  # pragma: no cover - threadpoolctl is a dependency; stay usable without it
            return contextlib.nullcontext()
        _CONTROLLER.append(ThreadpoolController())
    return _CONTROLLER[0].limit(limits=1, user_api="blas")


#: Predictions with at least this many query × training pairs are spread over the cores, in row
#: chunks on threads (numpy's ufuncs and BLAS release the GIL; the kernel's exp dominates).
PARALLEL_PREDICT_MIN = 400_000
_PREDICT_POOL = []


def _prediction_workers(work: int) -> int:
    import os

    if work < PARALLEL_PREDICT_MIN:
        return 1
    return max(1, min(4, os.cpu_count() or 1))


def _predict_pool():
    """A thread pool for prediction chunks, separate from the distance pool of
    :mod:`rbgp_cli.geometry.distance` (whose blocks the chunks submit and wait for)."""
    import os
    from concurrent.futures import ThreadPoolExecutor

    if not _PREDICT_POOL or _PREDICT_POOL[0][1] != os.getpid():
        _PREDICT_POOL[:] = [(ThreadPoolExecutor(max_workers=max(1, min(4, os.cpu_count() or 1)),
                                                thread_name_prefix="rbgp-predict"), os.getpid())]
    return _PREDICT_POOL[0][0]


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
        }

    @classmethod
    def from_dict(cls, d: dict) -> "OutputFit":
        return cls(**{k: d[k] for k in cls.__dataclass_fields__ if k in d})


class GaussianProcess:
    """A fitted exact GP with L outputs on inputs X (n, d).

    ``groups`` lists the hyperparameter sets: one per output (default) or one shared by all outputs
    (``shared``), each with its Cholesky factor and its α = C⁻¹ y (on the RMS-scaled outputs
    y / scale in shared mode; predictions are scaled back).
    """

    def __init__(self, kernel: Kernel, X: np.ndarray, Y: np.ndarray, fits: list, shared: bool, y_scale=None):
        self.kernel = kernel
        self.X = np.ascontiguousarray(X, dtype=np.float64)
        self.Y = np.ascontiguousarray(np.asarray(Y, dtype=np.float64).reshape(len(X), -1))
        self.fits = list(fits)
        self.shared = bool(shared)
        self.y_scale = np.ones(self.Y.shape[1]) if y_scale is None else np.asarray(y_scale, dtype=np.float64)
        self._factorise()

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
        it once around many calls (rollouts: see :func:`blas_threads`).
        """
        if not manage_threads:
            return self._predict(Xs, return_std, noisy, chunk_elements)
        with blas_threads(len(self.X)):
            return self._predict(Xs, return_std, noisy, chunk_elements)

    def _predict(self, Xs, return_std, noisy, chunk_elements):
        Xs = np.ascontiguousarray(np.asarray(Xs, dtype=np.float64).reshape(-1, self.X.shape[1]))
        m, n = len(Xs), len(self.X)
        mean = np.empty((m, self.n_outputs))
        std = np.empty((m, self.n_outputs)) if return_std else None
        step = max(1, int(chunk_elements // max(n, 1)))
        workers = _prediction_workers(m * n)
        if workers > 1:
            # at least one chunk per worker, so that large predictions use every core
            step = min(step, -(-m // workers))
        starts = range(0, m, step)
        if workers > 1 and len(starts) > 1:
            clipped = sum(_predict_pool().map(
                lambda a: self._predict_rows(Xs, a, a + step, mean, std, noisy), starts))
        else:
            clipped = sum(self._predict_rows(Xs, a, a + step, mean, std, noisy) for a in starts)
        self.last_clipped = int(clipped)
        return (mean, std) if return_std else mean

    def _predict_rows(self, Xs, a, b, mean, std, noisy) -> int:
        """Mean (and std) of query rows a:b into ``mean`` / ``std``; returns how many variances were clipped."""
        Xc = Xs[a:b]
        pre = self.kernel.precompute(Xc, self.X)
        clipped = 0
        for (fit, outs), Lc, alpha in zip(self._group_outputs(), self._L, self._alpha):
            Ks, _ = self.kernel.gram(pre, fit.values)  # (mc, n)
            scale = self.y_scale[outs]
            mean[a:b, outs] = (Ks @ alpha) * scale
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

    def predict_mean(self, Xs) -> np.ndarray:
        """Predictive mean, shape (m, L) (single-step mean prediction, MATH.md §8)."""
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
    """A random start in log space around the data-driven one: λ × e^U(−1.5,1), σf × e^U(−1,1),
    σn × e^U(−3,1), ρ1 ~ U(0.1, 0.9), each clipped into its bounds."""
    widths = {"length_scale": (-1.5, 1.0), "signal_std": (-1.0, 1.0), NOISE: (-3.0, 1.0)}
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


def _fit_one(kernel, pre, y, spec, free, restarts, rng, max_iter, margin=0.0, theta_starts=None, kinds=None,
             on_evaluation=None):
    """Minimise the NLML for one target (vector, or matrix in shared mode) from several starts.

    The starts are the data-driven one and ``restarts − 1`` random ones, or ``theta_starts`` (log
    values of the free hyperparameters) labelled ``kinds`` in the records. Returns (best (θ, NLML) or
    None, one record per start, evaluation counters, θ -> values, per start its optimum (θ, NLML) or
    None if it found no feasible point). ``on_evaluation()`` is called after every NLML evaluation."""
    from scipy.optimize import minimize

    fixed_values = {nm: h.value for nm, h in spec.items() if nm not in free}
    log_bounds = [spec[nm].log_bounds for nm in free]
    counter = {"evals": 0, "infeasible": 0}

    def values_of(theta):
        v = dict(fixed_values)
        v.update({nm: math.exp(t) for nm, t in zip(free, theta)})
        return v

    penalty = {"ref": None}

    def objective(theta):
        counter["evals"] += 1
        f, g = nlml_and_gradient(kernel, pre, values_of(theta), y, free, margin)
        if on_evaluation is not None:
            on_evaluation()
        if f >= INFEASIBLE_NLML:
            counter["infeasible"] += 1
            if penalty["ref"] is not None:
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
            for i, nm in enumerate(free):
                if nm == "length_scale":
                    theta0[i] = max(theta0[i] - _START_STEP, log_bounds[i][0])
                elif nm == NOISE:
                    theta0[i] = min(theta0[i] + _START_STEP, log_bounds[i][1])
        ev0 = counter["evals"]
        penalty["ref"] = f0 if f0 < INFEASIBLE_NLML else None
        if not free:
            res_x, res_f, msg = theta0, f0, "no free hyperparameters"
        else:
            res = minimize(objective, theta0, jac=True, method="L-BFGS-B", bounds=log_bounds,
                           options={"maxiter": max_iter})
            res_x, res_f, msg = res.x, float(res.fun), str(res.message)
        records.append({
            "start": {nm: float(math.exp(t)) for nm, t in zip(free, theta0)},
            "nlml": float(res_f),
            "status": msg,
            "evaluations": counter["evals"] - ev0,
            "kind": kinds[s],
        })
        if res_f < INFEASIBLE_NLML:
            optima.append((np.array(res_x), res_f))
            if best is None or res_f < best[1]:
                best = (np.array(res_x), res_f)
        else:
            optima.append(None)
    return best, records, counter, values_of, optima


def _meets_margin(kernel, pre, values) -> bool:
    """λ_min(K + σn²I) >= NOISE_MARGIN σn² (always true for a positive semi-definite kernel)."""
    K, _ = kernel.gram(pre, values)
    return _cholesky(K, (1.0 - NOISE_MARGIN) * values[NOISE] ** 2) is not None


def _accept(kernel, pre, y, values):
    """Check C = K + σn²I at the optimum; add jitter from a ladder if needed. Returns (jitter, rcond, pd)."""
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
            return jitter, rc, (j == 0)
    return None, 0.0, False


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
) -> GaussianProcess:
    """Fit one GP per output column of Y (or one shared set of hyperparameters) by minimising the NLML.

    Parameters
    ----------
    X : shape (n, d) — inputs (e.g. poses (rx, ry, rz, x, y, z))
    Y : shape (n, L) — outputs (e.g. velocities (ωx, ωy, ωz, vx, vy, vz))
    kernel : a :class:`Kernel`
    noise : None / "learn" to learn σn, or a number to fix σn (the paper fixes σn = 1)
    restarts : number of starts per output: the data-driven start plus ``restarts − 1`` random ones.
        With more than 2·``explore_size`` points (and restarts > 1) every start first runs on a
        random subsample of ``explore_size`` points (the same for all outputs, drawn from ``seed``). On all n
        points the data-driven start then runs as usual, and the optimum of each random start whose
        subsample optimum differs from the data-driven one's and from each other's by more than
        DISTINCT_LOG in some log θ is polished; the fit keeps the best. Random starts that end in
        the basin already found, the usual case, so cost only cheap subsample evaluations.
    explore_size : size of that subsample (default SUBSAMPLE_SIZE = 400); 0 runs every start on all
        points
    seed : seeds the random starts (same data, options and seed → bit-identical hyperparameters)
    shared : one set of hyperparameters for all outputs, each output scaled by its root mean square
    fixed : {name: value} hyperparameters to hold fixed (signal_std, length_scale, rho_rot, noise_std)
    bounds : {name: (low, high)} to override the data-driven bounds
    progress : optional :class:`rbgp_cli.progress.Progress` (or callable(str) for the messages): a
        task "training" over the outputs (one in shared mode) whose status counts the evaluations of
        the output being fitted, and one message per fitted output
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
    from rbgp_cli.progress import as_progress

    progress = as_progress(progress)
    with blas_threads(len(X)), progress.task("training", total=1 if shared else Y.shape[1], unit="outputs") as task:
        return _fit_gp(X, Y, kernel, noise, restarts, seed, shared, fixed, bounds, max_iter, progress, explore, task)


def _fit_gp(X, Y, kernel, noise, restarts, seed, shared, fixed, bounds, max_iter, progress, explore, task):
    pre = kernel.precompute(X)
    L = Y.shape[1]
    ss = np.random.SeedSequence(int(seed))
    fits = []
    if shared:
        scale = np.array([output_scale(Y[:, l]) for l in range(L)])
        targets = [(Y / scale, "all outputs")]
        rngs = [np.random.default_rng(ss)]
    else:
        scale = None
        targets = [(Y[:, l], f"output {l}") for l in range(L)]
        rngs = [np.random.default_rng(s) for s in ss.spawn(L)]
    n = len(X)
    sub = None
    if explore > 1 and n > 2 * explore and restarts > 1:
        sub = np.sort(np.random.default_rng(np.random.SeedSequence([int(seed), 1])).choice(n, explore, replace=False))
        pre_sub = kernel.precompute(X[sub])
    for (y, label), rng in zip(targets, rngs):
        t0 = time.perf_counter()
        evaluations = [0]

        def tick(label=label, evaluations=evaluations):
            evaluations[0] += 1
            task.update(status=f"{label}: {evaluations[0]} evaluations")

        spec, free = _free_spec(kernel, pre, y, noise, fixed, bounds)
        sub_info = None
        if sub is not None and free:
            # Explore: every start on the subsample. On all points: the data-driven start, and a
            # polish of every optimum of a random start that lies in a basin not reached before.
            _b, records_s, counter_s, _v, optima = _fit_one(kernel, pre_sub, y[sub], spec, free, restarts, rng, max_iter,
                                                            on_evaluation=tick)
            seen = [optima[0][0]] if optima[0] is not None else []
            polish = []
            for theta, _f in sorted((o for o in optima[1:] if o is not None), key=lambda t: t[1]):
                if all(np.max(np.abs(theta - p)) > DISTINCT_LOG for p in seen):
                    seen.append(theta)
                    polish.append(theta)
            data_start = np.array([math.log(spec[nm].value) for nm in free])
            best, records, counter, values_of, _ = _fit_one(
                kernel, pre, y, spec, free, 1, rng, max_iter, theta_starts=[data_start, *polish],
                kinds=["data-driven (all points)"] + ["polish (all points)"] * len(polish), on_evaluation=tick)
            records = [{**r, "kind": r["kind"] + f" (subsample of {explore})"} for r in records_s] + records
            sub_info = {"size": explore, "evaluations": counter_s["evals"], "infeasible": counter_s["infeasible"]}
        else:
            best, records, counter, values_of, _ = _fit_one(kernel, pre, y, spec, free, restarts, rng, max_iter,
                                                            on_evaluation=tick)
        guarded = False
        if best is not None and not _meets_margin(kernel, pre, values_of(best[0])):
            # The optimum sits where K's negative eigenvalues nearly cancel the noise (indefinite
            # kernel, MATH.md §6): refit with the margin enforced at every evaluation, from that
            # optimum (moved into the feasible region by the infeasible-start rule) and the
            # data-driven start.
            guarded = True
            data_start = [math.log(spec[nm].value) for nm in free]
            best2, records2, counter2, values_of, _ = _fit_one(
                kernel, pre, y, spec, free, 1, rng, max_iter, margin=NOISE_MARGIN,
                theta_starts=[best[0], data_start], kinds=["optimum (margin)", "data-driven (margin)"],
                on_evaluation=tick)
            records += records2
            counter = {k: counter[k] + counter2[k] for k in counter}
            best = best2
        if best is None:
            raise RbgpRuntimeError(
                f"no hyperparameters gave a positive definite covariance for {label}",
                hint="use --kernel se-chordal, fix a smaller length-scale, or learn the noise",
            )
        values = values_of(best[0])
        jitter, rc, pd = _accept(kernel, pre, y, values)
        if jitter is None:
            raise RbgpRuntimeError(
                f"the fitted covariance for {label} is numerically singular even with jitter",
                hint="use --kernel se-chordal or subsample fewer, less redundant points",
            )
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
        fits.append(fit)
        task.advance()
        explored = f" + {sub_info['evaluations']} on a {sub_info['size']}-point subset" if sub_info else ""
        progress(f"{label}: NLML {fit.nlml:.4g} after {fit.n_evaluations} evaluations{explored}"
                 f" ({fit.n_infeasible} infeasible), {fit.seconds:.2f} s")
    return GaussianProcess(kernel, X, Y, fits, shared=shared, y_scale=scale)
