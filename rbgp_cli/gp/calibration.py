"""How much a fitted GP should trust each training point, measured by leaving demonstrations out.

The GP's likelihood treats every training pair as an independent noisy sample of one velocity field
(docs/method.md §5). Repeated demonstrations are not that: each one deviates smoothly from the others (a
different grasp, speed, hand path), and recorded at a high rate it contributes hundreds of pairs that
share its deviation. The posterior then follows the deviations of the demonstrations it was trained
on, and its predictions for a new demonstration suffer. Measured on ``sample_data/`` and the 30 real
handovers at the recorded rate (benchmarks/README.md), multiplying σn² in the posterior by 2, 4 and 8
lowered the held-out velocity RMSE on every fold.

The hierarchical model behind the fix: a training pair of demonstration d is y = f(x) + g_d(x) + ε
with a deviation g_d of variance s² that is smooth over the length scale, and white noise ε of
variance σn². For a new demonstration only f counts; the n_d pairs of one demonstration near a pose
then carry the information of one sample of variance s² + σn²/n_d, that is of n_d samples of
variance σn² (1 + n_d s²/σn²). So the posterior should use the noise variance

    c σn²,   c = 1 + γ n,

with n the training points and γ = s² n_d / (σn² n) a property of the data, not of how densely it
was sampled. :func:`demonstration_noise_factors` measures c by grouped cross-validation on a random
subset of n_s points (each demonstration held out in turn, the hyperparameters kept): the factor c_s
with the smallest held-out squared error, and γ = (c_s − 1)/n_s. One eigendecomposition of the
subset's Gram matrix serves every demonstration and every factor of the grid (the partitioned
inverse: leaving a block out is a downdate, not a refit).
"""

from __future__ import annotations

import numpy as np

from rbgp_cli.compute import blas_threads, thread_pool, thread_workers
from rbgp_cli.gp.likelihood import NOISE
from rbgp_cli.gp.posterior import Posterior

#: The factors c_s tried on the subset: 1 to 4096 in steps of √2.
FACTOR_GRID = tuple(float(2 ** (k / 2)) for k in range(25))
#: Points of the random subset the cross-validation runs on (one eigendecomposition per fold and output).
CALIBRATION_POINTS = 1000
#: Folds of whole demonstrations: None holds out each demonstration alone (the partitioned inverse makes
#: that cheaper than 5 folds of eigendecompositions); a number k deals the demonstrations to k folds.
CALIBRATION_FOLDS = None


def demonstration_noise_factors(gp: Posterior, groups: np.ndarray, *, points: int = CALIBRATION_POINTS,
                                folds: int | None = CALIBRATION_FOLDS, seed: int = 0,
                                grid: tuple = FACTOR_GRID) -> list[dict] | None:
    """Per fitted hyperparameter set, the factor c ≥ 1 on σn² that predicts held-out demonstrations best.

    ``gp``: a fitted :class:`~rbgp_cli.gp.exact.GaussianProcess` or :class:`~rbgp_cli.gp.sparse.SparseGP`
    on X (n, d), Y (n, L), one hyperparameter set per output or one for all (``shared``: on Y / y_scale,
    errors summed over outputs); ``groups`` (n,) the demonstration of each row. On a seeded random subset
    of at most ``points`` rows, whole demonstrations are held out in turn (``folds`` None: each
    demonstration alone, the default; a number k: k folds of them); for each factor c_s of ``grid`` the
    posterior mean K_ht (K_tt + c_s σn² I)⁻¹ y_t predicts the held-out rows h. With the best c_s,
    c = 1 + (c_s − 1) n / n_s (module docstring).

    Leaving a block h out needs no refit (the partitioned inverse): with C = K + (c_s σn² + j) I on the
    subset, α = C⁻¹ y and B = C⁻¹,

        y_h − K_ht C_tt⁻¹ y_t = (B_hh)⁻¹ α_h,

    and from one eigendecomposition K = Q diag(w) Qᵀ every factor's B = Q diag(1/(w + c_s σn² + j)) Qᵀ
    costs only its blocks B_hh = Q_h diag(·) Q_hᵀ: Σ_h n_h² n_s per factor, n_s³/D for D demonstrations
    of equal size, against an eigendecomposition of each training block with k folds.

    Returns None with fewer than two demonstrations in the subset, else per fit a dict: ``factor`` c,
    ``subset_factor`` c_s, ``points`` n_s, ``folds`` (how many blocks were held out), ``errors``
    (held-out mean squared error per factor of ``grid``, on the outputs as fitted) and ``grid``.
    """
    X, Y, groups = gp.X, gp.Y, np.asarray(groups)
    n = len(X)
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 11]))
    idx = np.sort(rng.permutation(n)[: min(n, int(points))])
    g = groups[idx]
    names = np.unique(g)
    if len(names) < 2:
        return None
    if folds is None:
        k = len(names)
        fold = np.searchsorted(names, g)
    else:
        k = min(int(folds), len(names))
        fold_of_name = np.empty(len(names), dtype=int)
        fold_of_name[rng.permutation(len(names))] = np.arange(len(names)) % k  # demonstrations dealt to folds
        fold = fold_of_name[np.searchsorted(names, g)]
    with blas_threads(0):  # one thread: a BLAS pool spin-waits on a busy machine (compute.blas_threads)
        return _grouped_factors(gp, X[idx], Y[idx], fold, int(k), n, np.asarray(grid, dtype=np.float64))


def _grouped_factors(gp: Posterior, X, Y, fold, k: int, n: int, c_grid) -> list[dict]:
    """:func:`demonstration_noise_factors` on the subset X (n_s, d), Y (n_s, L) with its blocks
    ``fold`` (n_s,) of ``k``: per hyperparameter set, one eigendecomposition, and the held-out squared
    error of every factor in ``c_grid`` by the partitioned inverse; ``n`` the rows of the whole training
    set. The sets run on threads where cores are free (numpy's LAPACK and BLAS release the GIL; BLAS
    is single-threaded here)."""
    pre = gp.kernel.precompute(X)
    blocks = [np.flatnonzero(fold == j) for j in range(k)]

    def one(group):
        fit, outs = group
        sse = _held_out_errors(gp.kernel.gram(pre, fit.values)[0], Y[:, outs] / gp.y_scale[outs],
                               float(fit.values[NOISE]) ** 2, float(fit.jitter), blocks, c_grid)
        c_s = float(c_grid[int(np.argmin(sse))])
        return {"factor": 1.0 + (c_s - 1.0) * n / len(X), "subset_factor": c_s, "points": len(X),
                "folds": int(k), "errors": (sse / (len(X) * len(outs))).tolist(), "grid": c_grid.tolist()}

    groups = gp.group_outputs()
    threads = min(len(groups), thread_workers(len(groups), 2))
    if threads > 1:
        return list(thread_pool("calibration").map(one, groups))
    return [one(g) for g in groups]


def _held_out_errors(K, y, s2: float, jitter: float, blocks, c_grid) -> np.ndarray:
    """Σ over the blocks h of ‖y_h − K_ht (K_tt + (c σn² + j) I)⁻¹ y_t‖² for every factor c of
    ``c_grid`` (C,), by the partitioned inverse from one eigendecomposition K = Q diag(w) Qᵀ: with
    B = C⁻¹ and α = C⁻¹ y, the residual of block h is (B_hh)⁻¹ α_h. K (n_s, n_s), y (n_s, L).

    Each block's B_hh for every factor at once is one matrix product: its entries (i ≤ j) are
    Σ_k Q_ik Q_jk d_ck with d_ck = 1/(w_k + c σn² + j), so the n_h(n_h + 1)/2 rows Q_ik Q_jk (the
    upper triangle's pairs, n_s columns) times dᵀ (n_s, C) give them, mirrored to the lower triangle:
    half the products of C separate Q_h diag(d_c) Q_hᵀ, and 30 % less time for the whole function
    (issue 35, sixth pass; the same sums in another order: the errors agree to ~1e-15 relative)."""
    w, Q = np.linalg.eigh(K)
    # K + c σn² I is positive definite for c ≥ 1: K + σn² I is (the fit checked it)
    d = 1.0 / np.maximum(w[None, :] + c_grid[:, None] * s2 + jitter, 1e-300)  # (C, n_s)
    alpha = Q @ (d[:, :, None] * (Q.T @ y)[None])  # (C, n_s, L): C⁻¹ y for every factor
    d_t = np.ascontiguousarray(d.T)  # (n_s, C)
    sse = np.zeros(len(c_grid))
    pairs = {}
    for h in blocks:
        m = len(h)
        if m not in pairs:
            pairs[m] = np.triu_indices(m)
        iu, ju = pairs[m]
        Qh = Q[h]  # (n_h, n_s)
        upper = ((Qh[iu] * Qh[ju]) @ d_t).T  # (C, n_h (n_h + 1) / 2): B_hh's upper triangle per factor
        Bhh = np.empty((len(c_grid), m, m))
        Bhh[:, iu, ju] = upper
        Bhh[:, ju, iu] = upper
        r = np.linalg.solve(Bhh, alpha[:, h, :])  # (C, n_h, L): y_h minus its held-out prediction
        sse += np.einsum("cil,cil->c", r, r)
    return sse


def calibrate_to_demonstrations(gp: Posterior, groups: np.ndarray, *, seed: int = 0,
                                points: int = CALIBRATION_POINTS,
                                extra_factor: float = 1.0) -> tuple[Posterior, list[dict] | None]:
    """The fitted GP (exact or sparse) with σn² of each hyperparameter set scaled by its factor c
    (:func:`demonstration_noise_factors`) for the posterior; the hyperparameters found by the fit are
    kept in each fit's ``calibration`` record. ``extra_factor`` ≠ 1 multiplies σn² further, as
    :func:`scale_noise` would, in the same posterior. Returns (gp, records); the GP unchanged (but for
    ``extra_factor``) and None when there are fewer than two demonstrations. Costs the
    cross-validation plus one posterior."""
    from dataclasses import replace

    records = demonstration_noise_factors(gp, groups, seed=seed, points=points)
    if records is None:
        return scale_noise(gp, extra_factor), None
    extra = float(extra_factor)
    if not extra > 0:
        raise ValueError(f"extra_factor must be positive, got {extra_factor}")
    fits = []
    for fit, rec in zip(gp.fits, records):
        sn = float(fit.values[NOISE])
        rec = {**rec, "noise_std_fitted": sn, **({"extra_factor": extra} if extra != 1.0 else {})}
        sn_post = sn * float(np.sqrt(rec["factor"])) * (float(np.sqrt(extra)) if extra != 1.0 else 1.0)
        fits.append(replace(fit, values={**fit.values, NOISE: sn_post}, calibration=rec))
    return _with_fits(gp, fits), [f.calibration for f in fits]


def scale_noise(gp: Posterior, factor: float) -> Posterior:
    """The fitted GP (exact or sparse) with σn² of every hyperparameter set multiplied by ``factor`` > 0
    for the posterior (the hyperparameters otherwise kept); each fit's ``calibration`` record keeps it
    as ``extra_factor`` (a record with ``factor`` 1 and the fitted σn is made where there was none). ``factor`` 1 returns ``gp`` itself. Costs one
    posterior. Where the calibration's factor c (chosen on held-out velocities) and the trajectories'
    own error disagree, a further factor moves the mean rollout from the residual field toward the
    prior's motion (docs/method.md §7)."""
    from dataclasses import replace

    factor = float(factor)
    if not factor > 0:
        raise ValueError(f"factor must be positive, got {factor}")
    if factor == 1.0:
        return gp
    fits = [replace(fit, values={**fit.values, NOISE: float(fit.values[NOISE]) * float(np.sqrt(factor))},
                    calibration={**(fit.calibration or {"factor": 1.0, "noise_std_fitted": float(fit.values[NOISE])}),
                                 "extra_factor": factor})
            for fit in gp.fits]
    return _with_fits(gp, fits)


def _with_fits(gp: Posterior, fits: list) -> Posterior:
    """A GP of the same kind and data as ``gp`` with the hyperparameter records ``fits``."""
    if getattr(gp, "sparse", False):
        from rbgp_cli.gp.sparse import SparseGP

        new = SparseGP(gp.kernel, gp.X, gp.Y, gp.Z, fits, shared=gp.shared, y_scale=gp.y_scale)
    else:
        from rbgp_cli.gp.exact import GaussianProcess

        # σn² only grew from the fit's (factors ≥ 1): K + σn²I stays positive definite (and an indefinite
        # kernel's noise margin holds), so the factorisation waits for the first prediction (rbgp train
        # writes the model without one: six n × n Cholesky factorisations saved); else checked here
        grew = all(float(f.values[NOISE]) >= float(g.values[NOISE]) for f, g in zip(fits, gp.fits))
        new = GaussianProcess(gp.kernel, gp.X, gp.Y, fits, shared=gp.shared, y_scale=gp.y_scale, lazy=grew)
    if hasattr(gp, "fit_seconds"):
        new.fit_seconds = gp.fit_seconds
    return new
