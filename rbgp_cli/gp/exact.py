"""Exact Gaussian-process regression with hyperparameters from the marginal likelihood (docs/method.md §7):
the exact posterior (:class:`GaussianProcess`), the per-output fits in worker processes, and
:func:`fit_gp`.

One zero-mean GP per output dimension l (paper sec. 3.2, eq. 20–21), or one shared set of
hyperparameters for all outputs after scaling each by its root mean square (``shared=True``: one
Cholesky per evaluation for all outputs).

The likelihood (NLML and gradient, R&W Alg. 2.1 and eq. 5.9; the Cholesky, conditioning and margin
checks) lives in :mod:`rbgp_cli.gp.likelihood`; the optimiser (starts, L-BFGS-B, the subsample
exploration and the polish on all points, basins) in :mod:`rbgp_cli.gp.optimise`, shared with the
sparse GP; the fit record :class:`~rbgp_cli.gp.results.OutputFit` in :mod:`rbgp_cli.gp.results`.

Indefinite kernels (docs/method.md §6: the paper's geodesic kernel is not PSD): a fitted output is
accepted only if C = K + σn²I at the optimum passes Cholesky with a reciprocal condition number above
``MIN_RCOND`` (jitter from a ladder otherwise, reported). If nothing works the fit raises
:class:`RbgpRuntimeError` — a model whose predictions can explode is never returned; a loaded model
whose stored hyperparameters miss the noise margin is refused the same way.

Per-output fits can run in worker processes (``fit_gp(..., jobs=)``), one output per task, BLAS
single-threaded in each; every fit runs BLAS single-threaded, so its result never depends on the
machine's load or on ``jobs``.

All BLAS/LAPACK calls go through ``scipy.linalg`` (ECOSYSTEM.md §7).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from scipy.linalg import lapack, solve_triangular

from rbgp_cli.compute import (blas_threads, fork_context, process_pool, start_workers, stop_pool, thread_pool,
                              thread_workers, worker_init)
from rbgp_cli.errors import RbgpRuntimeError
from rbgp_cli.gp.likelihood import NOISE, NOISE_MARGIN, cholesky
from rbgp_cli.gp.optimise import SUBSAMPLE_SIZE, FitOptions, fit_target, fit_targets, training_data
from rbgp_cli.kernels.base import Kernel

__all__ = ["GaussianProcess", "ExactSpec", "fit_gp"]


# ----------------------------------------------------------------------------- posterior
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


@dataclass(frozen=True)
class ExactSpec:
    """A fitted exact GP before its factorisation: the kernel, the fits (hyperparameters), shared or per
    output, the output scale. What the sparse GP keeps of the exact fit that chose its hyperparameters
    (the automatic choice of GP compares with it, :func:`rbgp_cli.gp.selection.held_out_comparison`,
    and falls back on it): its Cholesky factors, one n² matrix per output, are made by :meth:`build`
    only if it becomes the model, instead of being held through the sparse posterior (a 10⁶-row
    file's peak memory)."""

    kernel: Kernel
    fits: list
    shared: bool
    y_scale: object

    def build(self, X, Y) -> "GaussianProcess":
        """The GaussianProcess on inputs X (n, d) and outputs Y (n, L) at these hyperparameters."""
        return GaussianProcess(self.kernel, X, Y, self.fits, shared=self.shared, y_scale=self.y_scale)


class GaussianProcess:
    """A fitted exact GP with L outputs on inputs X (n, d).

    ``groups`` lists the hyperparameter sets: one per output (default) or one shared by all outputs
    (``shared``), each with its Cholesky factor and its α = C⁻¹ y (on the RMS-scaled outputs
    y / scale in shared mode; predictions are scaled back). ``factors``: per group (L, α) as
    :func:`fit_gp` has just computed and checked them; without it they are computed and checked here
    (a loaded model), or with ``lazy`` at the first prediction (a posterior whose σn² only grew from
    checked ones: :func:`rbgp_cli.gp.calibration.scale_noise`). Predictions build the kernel block against X from matrix products
    (:meth:`Kernel.cross_plan`, :meth:`Kernel.cross_gram`).
    """

    def __init__(self, kernel: Kernel, X: np.ndarray, Y: np.ndarray, fits: list, shared: bool, y_scale=None, *,
                 factors=None, lazy: bool = False):
        self.kernel = kernel
        self.X = np.ascontiguousarray(X, dtype=np.float64)
        self.Y = np.ascontiguousarray(np.asarray(Y, dtype=np.float64).reshape(len(X), -1))
        self.fits = list(fits)
        self.shared = bool(shared)
        self.y_scale = np.ones(self.Y.shape[1]) if y_scale is None else np.asarray(y_scale, dtype=np.float64)
        if factors is None:
            self._L = self._alpha = None
            if not lazy:  # else factorised at the first prediction (rbgp train writes the calibrated
                self._ensure_factors()  # posterior without ever predicting with it)
        else:
            # from fit_gp, which has just computed and checked them: per group (L, α), or (c, None) with c
            # LAPACK's lower Cholesky factor (upper triangle zero), whose L and α are made at first use
            # (_complete): rbgp train replaces this posterior by the calibrated one without using them
            self._L = [np.asarray(Lc) for Lc, _a in factors]
            self._alpha = [None if a is None else np.asarray(a) for _Lc, a in factors]
        self._cross = None
        self._scaled = {}

    def _complete(self) -> None:
        """L (C-ordered) and α = C⁻¹ y of the groups given as LAPACK's factor only: the numbers the fit
        would have made at once (np.tril of the factor, dpotrs), made here at their first use."""
        if self._alpha is None or all(a is not None for a in self._alpha):
            return
        for g, (_fit, outs) in enumerate(self.group_outputs()):
            if self._alpha[g] is None:
                c = self._L[g]
                y = self.Y[:, outs] / self.y_scale[outs]
                alpha, _info = lapack.dpotrs(c, np.asfortranarray(y), lower=1)
                self._L[g], self._alpha[g] = np.tril(c), np.asarray(alpha)

    @property
    def n_outputs(self) -> int:
        return self.Y.shape[1]

    def group_outputs(self):
        """``[(fit, outputs)]``: each fit with the output columns it serves (the Posterior protocol)."""
        if self.shared:
            return [(self.fits[0], list(range(self.n_outputs)))]
        return [(f, [l]) for l, f in enumerate(self.fits)]

    def _ensure_factors(self) -> None:
        """Factorise (:meth:`_factorise`) unless done. Single-threaded BLAS, as the fit that made the
        hyperparameters: a lone `rbgp rollout --count 60` at n = 1208 spent up to 4.7x the CPU of one
        thread here (two Cholesky factorisations per group on the BLAS pool, whose threads then
        spin-wait), and was slower in wall time too (issue 24; benchmarks/bench_rollout.py --threads)."""
        if self._L is None:
            with blas_threads(0):
                self._factorise()
        else:
            self._complete()

    def _factorise(self) -> None:
        """Cholesky factors and α for every group, with each fit's recorded jitter; verified. The
        groups run on threads where cores are free (:func:`_over_groups`: the same numbers)."""
        pre = self.kernel.precompute(self.X)

        def one(group):
            fit, outs = group
            K, _ = self.kernel.gram(pre, fit.values)
            s2 = fit.values[NOISE] ** 2
            c = cholesky(K, s2, fit.jitter)
            if c is None or (not self.kernel.positive_semidefinite
                             and cholesky(K, (1.0 - NOISE_MARGIN) * s2 + fit.jitter) is None):
                raise RbgpRuntimeError(
                    "the stored hyperparameters do not give a well-conditioned positive definite covariance",
                    hint="refit the model (rbgp train)",
                )
            del K
            y = self.Y[:, outs] / self.y_scale[outs]
            alpha, _ = lapack.dpotrs(c, np.asfortranarray(y), lower=1)
            return np.tril(c), np.asarray(alpha)

        done = _over_groups(self.group_outputs(), one)
        self._L = [L for L, _a in done]
        self._alpha = [a for _L, a in done]

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
        self._ensure_factors()  # before any threads (a lazily built posterior)
        self._cross_plan()
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
        groups = self.group_outputs()
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
    return l, fit_target(kernel, pre, y, label, np.random.default_rng(seeds), o, sub, pre_sub)


def _fit_outputs_in_workers(X, Y, kernel, o, seeds, sub, jobs, progress, task, beside=None):
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
        return _collect_worker_fits(tasks, jobs, ctx, progress, task, results, failures, beside)
    finally:
        _WORKER.pop("pre", None)


def _collect_worker_fits(tasks, jobs, ctx, progress, task, results, failures, beside=None):
    from concurrent.futures import as_completed
    from concurrent.futures.process import BrokenProcessPool

    # workers that end with this process (killed or not), and end at once on an error or Ctrl-C
    with process_pool(jobs, context=ctx, init=worker_init) as pool:
        try:
            # inside the try: a pool that fails while starting its workers (too many open files) ends
            # them, instead of leaving started workers that the exit handlers wait for forever
            with start_workers():
                futures = {pool.submit(_worker_fit, t): t[4] for t in tasks}
            # this process's own work (beside) runs once a worker has no output left to fit, on the core it
            # leaves idle while the others finish; every worker has been forked by then (a fork context starts
            # them all at the first submit), so no thread of ours is alive at any fork
            running = len(futures)
            if beside is not None and running < jobs:
                beside()
                beside = None
            for fut in as_completed(futures):
                running -= 1
                if not fut.cancelled():
                    _collect_one(fut, futures, results, failures, progress, task)
                if beside is not None and not failures and running < jobs:
                    beside()
                    beside = None
        except BaseException:
            stop_pool(pool)
            raise
    if failures:
        # the error of the first output that failed, as the fit in one process would raise it
        first = min(failures)
        if isinstance(failures[first], BrokenProcessPool):
            raise RbgpRuntimeError("a worker process fitting the outputs ended unexpectedly (out of memory?)",
                                   hint="train with jobs 1", param="jobs") from failures[first]
        raise failures[first]
    return results


def _collect_one(fut, futures, results, failures, progress, task) -> None:
    """The result of one finished output's future into ``results`` (and the progress), or its error into
    ``failures`` (the outputs not started yet are then cancelled: not needed; the running ones finish)."""
    exc = fut.exception()
    if exc is not None:
        failures[futures[fut]] = exc
        for other in futures:
            other.cancel()
        return
    l, res = fut.result()
    results[l] = res
    fit = res[0]
    # the worker's evaluations, counted as the fit in this process counts them
    total = fit.n_evaluations + (fit.subsample["evaluations"] if fit.subsample else 0)
    task.update(status=f"output {l}: {total} evaluations")
    task.advance()
    _report(progress, f"output {l}", fit)


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
    hyper_points: int | None = None,
    beside=None,
    factorise: bool = True,
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
    hyper_points : None or 0 fits the hyperparameters on all n points (as above); a number below n fits
        them on a seeded random subset of that many rows (every option above applies to the subset)
        and the posterior (Cholesky factor and α) on all n rows at those hyperparameters, with the
        jitter ladder of :func:`rbgp_cli.gp.likelihood.accept` on all rows. The NLML is a sum over
        the points, so the subset's optimum estimates the full one; each evaluation costs (h/n)³ of
        one on all points. Where the subset's hyperparameters fail the covariance checks on all rows
        (an indefinite kernel's noise margin), that output is fitted on all points instead.
    beside : None, or a callable (no arguments) that this process runs exactly once before fit_gp returns:
        with worker processes, as soon as one of them has no output left to fit (at once with fewer
        outputs than workers), while the others finish theirs; else after the fit. The caller's own
        work that does not need the GP (rbgp train: the path distribution, the bands' scale) then runs
        on the core that a quiet machine leaves idle at the fit's end instead of after it. BLAS is
        single-threaded while it runs, as for the whole fit; its exceptions end the workers and
        propagate.
    factorise : False returns the posterior without its Cholesky factors and α (the fit's checks made all the
        same): it factorises at its first prediction, with the same numbers. For a caller that replaces
        the posterior (rbgp train's noise calibration makes a new one): at n = 1752 the factor is 24.5 MB
        per output, copied, pickled and sent from each worker process for nothing.
    """
    X, Y = training_data(X, Y)
    restarts = max(1, int(restarts))
    explore = SUBSAMPLE_SIZE if explore_size is None else int(explore_size)
    if explore < 0:
        raise ValueError(f"explore_size must be >= 0, got {explore_size}")
    jobs = int(jobs)
    if jobs < 1:
        raise ValueError(f"jobs must be >= 1, got {jobs}")
    o = FitOptions(noise=noise, restarts=restarts, fixed=fixed, bounds=bounds, max_iter=int(max_iter),
                   factors=bool(factorise))
    from rbgp_cli.progress import as_progress

    progress = as_progress(progress)
    # BLAS single-threaded whatever the machine: the optimiser's path must not depend on how busy the
    # machine is (a 2-thread pool changes the round-off, and on the arc kernel's indefinite edge that
    # changed an optimum), and parallelism comes from the worker processes
    beside = _once(beside)
    with blas_threads(0), progress.task("training", total=1 if shared else Y.shape[1], unit="outputs") as task:
        if hyper_points and len(X) > int(hyper_points):
            rows = np.sort(np.random.default_rng(np.random.SeedSequence([int(seed), 2])).choice(
                len(X), int(hyper_points), replace=False))
            # the subset's own factors are never used: the posterior on all rows factorises its own
            from dataclasses import replace

            on_subset = _fit_gp(X[rows], Y[rows], kernel, replace(o, factors=False), seed, shared, progress, explore,
                                jobs, task, beside)
            gp = _posterior_on_all_rows(on_subset, X, Y, factorise)
            if gp is not None:
                gp.hyper_subset = rows
            else:
                progress(f"the hyperparameters of a random {int(hyper_points)} points fail the covariance checks "
                         f"on all {len(X)}; fitting on all points")
        else:
            gp = None
        if gp is None:
            gp = _fit_gp(X, Y, kernel, o, seed, shared, progress, explore, jobs, task, beside)
        beside()  # the fit ran in this process (a fit in workers ran it already: then nothing)
    return gp


def _once(fn):
    """``fn`` (or nothing) as a callable that runs it the first time only."""
    done = [fn is None]

    def run():
        if not done[0]:
            done[0] = True
            fn()
    return run


def _over_groups(groups, one) -> list:
    """``[one(g) for g in groups]``, the groups (hyperparameter sets) shared between threads where cores
    are free (:func:`rbgp_cli.compute.thread_workers`), at most one set per thread at a time (each holds
    a few n × n matrices). Each set's numbers are those of the loop: LAPACK releases the GIL, and the
    callers run BLAS single-threaded (a 2000-point Cholesky per set, six sets: the posterior of the
    default exact GP after its fit, and every model file loaded)."""
    groups = list(groups)
    threads = min(len(groups), thread_workers(len(groups), 2))
    if threads <= 1:
        return [one(g) for g in groups]

    def share(k):
        return [one(g) for g in groups[k::threads]]

    done = [None] * len(groups)
    for k, part in enumerate(thread_pool("posterior").map(share, range(threads))):
        done[k::threads] = part
    return done


def _posterior_on_all_rows(gp: GaussianProcess, X, Y, factorise: bool = True) -> GaussianProcess | None:
    """The exact posterior on all rows X (n, d), Y (n, L) at the hyperparameters ``gp`` fitted on a
    subset of them: per hyperparameter set C = K + (σn² + jitter) I with the jitter of
    :func:`rbgp_cli.gp.likelihood.accept` on all rows (its rcond and positive definiteness recorded
    in the fit), L its Cholesky factor and α = C⁻¹ y; None where a set fails those checks or (an
    indefinite kernel) the noise margin. The sets run on threads where cores are free (LAPACK releases
    the GIL, BLAS is single-threaded here: the same numbers as one after the other). ``factorise``
    False: the checks only, the posterior factorised at its first prediction (fit_gp's ``factorise``)."""
    from dataclasses import replace

    from rbgp_cli.gp.likelihood import accept, meets_margin

    kernel = gp.kernel
    pre = kernel.precompute(X)
    Y2 = np.asarray(Y, dtype=np.float64).reshape(len(X), -1)

    def one(group):
        fit, outs = group
        K, _ = kernel.gram(pre, fit.values)
        if not meets_margin(kernel, pre, fit.values, K):
            return None
        y = Y2[:, outs] / gp.y_scale[outs]
        jitter, rc, pd, c = accept(kernel, pre, y, fit.values, K)
        if jitter is None:
            return None
        del K
        # L and α at the posterior's first prediction (GaussianProcess._complete): rbgp train calibrates σn²
        # and never predicts with this posterior (a 2000-point factor's copy and solve per set saved)
        return replace(fit, jitter=float(jitter), rcond=rc, positive_definite=pd), (c, None)

    done = _over_groups(gp.group_outputs(), one)
    if any(r is None for r in done):
        return None
    return GaussianProcess(kernel, X, Y2, [r[0] for r in done], shared=gp.shared, y_scale=gp.y_scale,
                           factors=[r[1] for r in done] if factorise else None, lazy=not factorise)


def _fit_gp(X, Y, kernel, o, seed, shared, progress, explore, jobs, task, beside=None):
    n = len(X)
    ss = np.random.SeedSequence(int(seed))
    sub = None
    if explore > 1 and n > 2 * explore:
        sub = np.sort(np.random.default_rng(np.random.SeedSequence([int(seed), 1])).choice(n, explore, replace=False))
    targets, scale, seeds = fit_targets(Y, shared, ss)
    if jobs > 1 and len(targets) > 1:
        jobs = min(jobs, len(targets))
        progress(f"fitting {len(targets)} outputs in {jobs} worker processes")
        results = _fit_outputs_in_workers(X, Y, kernel, o, seeds, sub, jobs, progress, task, beside)
    else:
        pre = kernel.precompute(X)
        pre_sub = kernel.precompute(X[sub]) if sub is not None else None
        results = []
        for (y, label), s in zip(targets, seeds):
            evaluations = [0]

            def tick(label=label, evaluations=evaluations):
                evaluations[0] += 1
                task.update(status=f"{label}: {evaluations[0]} evaluations")

            res = fit_target(kernel, pre, y, label, np.random.default_rng(s), o, sub, pre_sub, on_evaluation=tick)
            results.append(res)
            task.advance()
            _report(progress, label, res[0])
    return GaussianProcess(kernel, X, Y, [r[0] for r in results], shared=shared, y_scale=scale,
                           factors=[(r[1], r[2]) for r in results] if o.factors else None, lazy=not o.factors)
