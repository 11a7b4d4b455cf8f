"""The GP's residual gain g, chosen by leaving demonstrations out at the level of the rollout
(docs/method.md §7, "The residual's gain").

The motion model's velocity is the prior mean (the start-conditioned mean path, its feed-forward and
pull) plus the GP's posterior mean of the residual, scaled by a gain g:

    ξ(x) = m(x) + g · μ_GP(x),   μ_GP(x) = k(x, X) α,   α = C⁻¹ y,   C = K + (c f σn² + j) I,

g = 1 the full model, g = 0 the path distribution alone (crossval's "without the GP" row). The noise
calibration (:mod:`rbgp_cli.gp.calibration`) chooses c on held-out *velocities at the held-out
demonstration's own poses*; what users meet is the rollout, where the residual field is integrated off
that path and its errors accumulate. So g is chosen on the rollout: each training demonstration d is
rolled out from its own start for its own duration by the model whose GP has not seen it, and scored
against it.

**The posterior without a demonstration**, from one inverse per hyperparameter set: with B = C⁻¹ and the
rows b of demonstration d, the weights of the posterior on the other rows (the partitioned inverse) are

    α₋d = α_¬b − B_¬b,b (B_bb)⁻¹ α_b     (zero on the rows b),

exactly C_¬b¬b⁻¹ y_¬b, without a refit.

**The prior without a demonstration** (issue 36, seventh pass). The prior mean m steers the rollout as
much as the residual does, and a prior fitted with d predicts d better than a new motion (its mean path
by weight 1/D, its start map's six inputs by their leverage): the left-out rollouts then favour g = 0.
So m₋d is refitted without d (:func:`left_out_priors`: the mean path, the deviations from it, the start
map μ₋d(s) + B₋d(s) c(0) at the model's ridge λ and units, the pull's profile), the GP that has not seen
d is the one on the other rows' residuals from m₋d,

    y_d = y + m(X) − m₋d(X)   (y the GP's targets, the training velocities less m),
    α₋d = C_¬b¬b⁻¹ (y_d)_¬b = (B y_d)_¬b − B_¬b,b (B_bb)⁻¹ (B y_d)_b,

and d's rollout follows m₋d(x) + g k(x, X) α₋d (:class:`StackedPriors`: each rollout row its own m₋d):
the model :func:`~rbgp_cli.dynamics.model.train_model` makes without d, but for what is kept from the
fit on all D: the GP's hyperparameters and noise factor, the start map's ridge λ and units (each chosen
by its own folds over all D), and the rows of the left-out posteriors.

**The criterion.** For each gain g of the grid, J_d(g) = ½ (P_d(g)/P̄(0) + R_d(g)/R̄(0)), with P_d and
R_d the mean squared position (m²) and rotation angle (rad²) error of demonstration d's left-out rollout
against d at the same phases, and P̄(0), R̄(0) their means over the demonstrations at g = 0 (so J is
unit-free and 1 for the path distribution alone on average). The gain with the smallest mean J wins,
unless a smaller gain is within one standard error of the paired differences J_d(g) − J_d(g_best)
(the one-standard-error rule: the simpler model unless the folds' noise cannot explain the gain) or
within EQUIVALENT_FRACTION · J(0) of it (practical equivalence: an improvement too small to matter, however
consistent).

Cost: one Cholesky factor and inverse per hyperparameter set (m³, on at most m = LEFT_OUT_POINTS rows:
:func:`subset_posterior`), the D left-out priors and their targets (one product B [y_1 … y_D] per set),
and one batched rollout of D × G trajectories (D at most LEFT_OUT_DEMOS) at the training step (one
kernel block of (D·G) × m per step and set).
"""

from __future__ import annotations

import time

import numpy as np

__all__ = ["EQUIVALENT_FRACTION", "GAIN_GRID", "choose_residual_gain", "smallest_equivalent", "left_out_weights",
           "left_out_rollout_errors", "left_out_priors", "StackedPriors"]

#: The gains tried on the GP's residual mean (1: the full model; 0: the path distribution alone).
GAIN_GRID = (0.0, 0.25, 0.5, 1.0)
#: Practical equivalence: a gain whose mean left-out error J improves on a smaller gain's by no more than this
#: fraction of J(0) (= 1, the path distribution alone) is no better, whatever its standard error. J is a mean
#: squared error, so 0.5 % of J is about 0.25 % of an RMSE, an eighth of the 2 % crossval counts as a tie
#: (docs/defaults.md, "the practical-equivalence margin").
EQUIVALENT_FRACTION = 0.005
#: At most this many training rows (a seeded random subset, each standing for n/m rows: σn² × m/n) carry
#: the left-out posteriors: one m³ inverse per hyperparameter set instead of n³ (2000 rows: 8× less).
LEFT_OUT_POINTS = 800
#: At most this many demonstrations (a seeded random choice) are rolled out left out: the rollouts cost
#: in proportion to them, and 20 paired differences already give the one-standard-error rule its scale.
LEFT_OUT_DEMOS = 20


def subset_posterior(gp, points: int = LEFT_OUT_POINTS, seed: int = 0):
    """(gp_m, rows): the exact GP ``gp`` on a seeded random ``points`` of its n training rows (sorted), with
    σn² × m/n in every hyperparameter set, so that each kept row stands for the n/m rows it was drawn from
    (rows repeated r times are exactly one row with noise σn²/r); ``gp`` itself and all rows when n ≤ points.
    Not factorised (the left-out weights make their own inverse)."""
    from dataclasses import replace

    from rbgp_cli.gp.exact import GaussianProcess
    from rbgp_cli.gp.likelihood import NOISE

    n = len(gp.X)
    if n <= int(points) or getattr(gp, "sparse", False):
        return gp, np.arange(n)
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 36]))
    rows = np.sort(rng.choice(n, size=int(points), replace=False))
    shrink = float(np.sqrt(len(rows) / n))
    fits = [replace(f, values={**f.values, NOISE: float(f.values[NOISE]) * shrink}) for f in gp.fits]
    return GaussianProcess(gp.kernel, gp.X[rows], gp.Y[rows], fits, shared=gp.shared, y_scale=gp.y_scale,
                           lazy=True), rows


def left_out_weights(gp, groups, targets=None, demos=None) -> list[np.ndarray] | None:
    """Per hyperparameter set of an exact GP (``gp.group_outputs()``), the posterior weights without each
    demonstration: A (D, n, L_g) with A[d] = α₋d = C_¬b¬b⁻¹ y_¬b on the rows of the other demonstrations and
    zero on d's rows b (module docstring), on the outputs as fitted (y / y_scale). ``groups`` (n,) the
    demonstration (0 … D − 1) of each training row. None for a GP without an exact posterior (sparse).

    ``demos`` (optional, (D',)): only these demonstrations, A (D', n, L_g) in their order. ``targets``
    (optional, (D', n, L), the outputs' units): demonstration d's own targets y_d in place of the GP's Y
    (the residuals of the prior refitted without d, :func:`choose_residual_gain`), α₋d = C_¬b¬b⁻¹ y_d,¬b,
    by the same partitioned inverse: for any y, C_¬b¬b⁻¹ y_¬b = (B y)_¬b − B_¬b,b (B_bb)⁻¹ (B y)_b."""
    from scipy.linalg import lapack

    from rbgp_cli.compute import thread_pool, thread_workers
    from rbgp_cli.gp.likelihood import NOISE

    if getattr(gp, "sparse", False) or not hasattr(gp, "kernel") or not hasattr(gp, "fits"):
        return None
    groups = np.asarray(groups)
    D = int(groups.max()) + 1 if len(groups) else 0
    demos = np.arange(D) if demos is None else np.asarray(demos, dtype=int)
    blocks = [np.flatnonzero(groups == d) for d in demos]
    pre = gp.kernel.precompute(gp.X)

    def one(group):
        fit, outs = group
        K, _ = gp.kernel.gram(pre, fit.values)
        C = np.array(K, order="F", copy=True)
        del K
        C[np.diag_indices_from(C)] += float(fit.values[NOISE]) ** 2 + float(fit.jitter)
        # (single precision was tried: its factorisation underflowed into subnormal numbers, 10× slower)
        c, info = lapack.dpotrf(C, lower=1, clean=1, overwrite_a=1)
        if info != 0:
            return None
        Binv, info = lapack.dpotri(c, lower=1, overwrite_c=1)  # C⁻¹, its lower triangle
        if info != 0:
            return None
        Binv = np.tril(Binv)
        Binv += np.tril(Binv, -1).T
        scale = gp.y_scale[outs]
        if targets is None:
            alpha = Binv @ (np.asarray(gp.Y[:, outs], dtype=np.float64) / scale)  # (n, L_g), shared by every d
            alphas = [alpha] * len(demos)
        else:
            Yd = np.asarray(targets, dtype=np.float64)[:, :, outs] / scale  # (D', n, L_g)
            Lg = len(outs)
            flat = Binv @ Yd.transpose(1, 0, 2).reshape(len(Binv), -1)  # one product for every d
            alphas = list(flat.reshape(len(Binv), len(demos), Lg).transpose(1, 0, 2))
        A = np.empty((len(demos),) + alphas[0].shape)
        for i, b in enumerate(blocks):
            a = alphas[i].copy()
            if len(b):
                a -= Binv[:, b] @ np.linalg.solve(Binv[np.ix_(b, b)], a[b])
                a[b] = 0.0
            A[i] = a
        return A

    groups_ = gp.group_outputs()
    # the sets on threads where cores are free (LAPACK and BLAS release the GIL; BLAS single-threaded here)
    threads = min(len(groups_), thread_workers(len(groups_), 2))
    out = list(thread_pool("residual-gain").map(one, groups_)) if threads > 1 else [one(g) for g in groups_]
    return None if any(a is None for a in out) else out


def left_out_rollout_errors(model, trajs, groups, gains=GAIN_GRID, weights=None, return_poses: bool = False,
                            gp=None, priors=None):
    """Each demonstration rolled out from its own start for its own duration with every gain g of
    ``gains`` on the residual of the GP that has not seen it (:func:`left_out_weights`), batched: D × G
    trajectories advance together at the model's training step. Returns (P, R), each (D, G): the mean
    squared position error (m²) and rotation angle (rad²) against the demonstration at the rollout's
    phases k/S_d, k = 1 … S_d. None where the GP has no exact posterior. With ``return_poses`` also the
    rollouts' poses, quat (S + 1, D·G, 4) and position (S + 1, D·G, 3) (row d·G + j: demonstration d, gain
    j; its first S_d + 1 steps), and the steps S_d (D,). ``gp``: the GP whose left-out posteriors roll out
    (default the model's; :func:`subset_posterior`), ``groups`` its rows'. ``priors``: a
    :class:`StackedPriors` whose reference d is the prior mean refitted without demonstration d
    (:func:`left_out_priors`), which then steers d's rollouts instead of the model's own prior."""
    from rbgp_cli.dynamics.trajectory import interpolate_poses
    from rbgp_cli.geometry.so3 import log_quat, quat_conjugate, quat_make_continuous, quat_multiply

    gp = model.gp if gp is None else gp
    A = left_out_weights(gp, groups) if weights is None else weights
    if A is None:
        return None
    gains = np.asarray(gains, dtype=np.float64)
    D, G = len(trajs), len(gains)
    demo = np.repeat(np.arange(D), G)  # row r: demonstration demo[r] with gain g_row[r]
    g_row = np.tile(gains, D)
    q0 = np.array([tr.quat[0] for tr in trajs])[demo]
    p0 = np.array([tr.position[0] for tr in trajs])[demo]
    dt = float(model.dt)
    dur_d = np.array([tr.duration for tr in trajs])
    steps_d = np.maximum(1, np.round(dur_d / dt).astype(int))
    dur = (steps_d * dt)[demo]
    S = int(steps_d.max())
    X = model.initial_state(q0, p0)
    if priors is None:
        dev = model.start_deviation(q0, p0)
    else:
        dev = priors.start_deviation(q0, p0, demo)
    step = model.phase_step(dur, dt)
    # rows whose gain is 0 need no GP; the others' weights, each row's own α₋d times its gain
    live = np.flatnonzero(g_row != 0)
    # longest demonstrations first: the rows still running at step k are then a prefix (views, not copies)
    live = live[np.argsort(-steps_d[demo[live]], kind="stable")]
    plan = gp.kernel.cross_plan(gp.X)
    grp = gp.group_outputs()
    W = [g_row[live, None, None] * A_g[demo[live]] for A_g in A]  # (R_live, n, L_g)
    pd = model.pose_dims
    L = gp.n_outputs
    Xs = np.empty((S + 1,) + X.shape)
    Xs[0] = X
    steps_live = steps_d[demo[live]]
    for k in range(S):
        if priors is None:
            mu = model.prior_mean(X, dev, step)
        else:
            mu = priors.outputs(model.representation, X, demo, dev, step)
        m = int(np.count_nonzero(steps_live > k))  # live rows whose demonstration has not ended (a prefix)
        on = slice(0, m)
        if m:
            Xl = X[live[on]]
            pre = gp.kernel.cross_precompute(plan, Xl) if len(grp) > 1 else None
            res = np.zeros((m, L))
            for (fit, outs), Wg in zip(grp, W):
                Ks = gp.kernel.cross_gram(plan, Xl, fit.values) if pre is None else gp.kernel.gram(pre, fit.values)[0]
                res[:, outs] = np.einsum("rn,rnl->rl", Ks, Wg[on]) * gp.y_scale[outs]
            mu = mu.copy()
            mu[live[on]] += res
        X = model.advance(X, mu, dt, dur[:, None])
        Xs[k + 1] = X
    quat, pos = model.representation.pose_from_state(Xs[..., :pd].reshape(-1, pd))
    quat = quat.reshape(S + 1, D * G, 4)
    pos = pos.reshape(S + 1, D * G, 3)
    P = np.empty((D, G))
    R = np.empty((D, G))
    for d, tr in enumerate(trajs):
        n_d = int(steps_d[d])
        s = np.arange(1, n_d + 1) / n_d  # the rollout's phases (its last step ends at phase 1)
        tq, tp = interpolate_poses((tr.t - tr.t[0]) / max(tr.duration, 1e-12), quat_make_continuous(tr.quat),
                                   tr.position, s)
        rows = slice(d * G, (d + 1) * G)
        rq = quat[1:n_d + 1, rows].transpose(1, 0, 2)  # (G, n_d, 4)
        rp = pos[1:n_d + 1, rows].transpose(1, 0, 2)
        P[d] = np.mean(np.sum((rp - tp[None]) ** 2, axis=-1), axis=1)
        ang = log_quat(quat_multiply(rq.reshape(-1, 4), quat_conjugate(np.broadcast_to(tq[None], rq.shape).reshape(-1, 4))))
        R[d] = np.mean(np.sum(ang.reshape(G, n_d, 3) ** 2, axis=-1), axis=1)
    return (P, R, quat, pos, steps_d) if return_poses else (P, R)


def smallest_equivalent(mean, se, equal: float = EQUIVALENT_FRACTION) -> int:
    """The index of the gain :func:`choose_residual_gain` keeps, from the mean left-out errors J (G,) over the
    sorted grid (J[0] = J(0)) and the standard errors (G,) of J_d(g) − J_d(ĝ) against the best gain ĝ: the
    smallest gain i with J(i) − J(ĝ) ≤ max(SE(i), ``equal`` · J(0)) (the one-standard-error rule, or practical
    equivalence: a residual of no consequence makes every J equal to a few parts in 10⁵ with a standard error
    near zero, a consistent improvement nobody would see)."""
    mean = np.asarray(mean, dtype=np.float64)
    best = int(np.argmin(mean))
    margin = max(float(equal), 1e-9) * abs(float(mean[0]))  # at least round-off's reach
    for i in range(best):
        if mean[i] - mean[best] <= max(float(se[i]), margin):
            return i
    return best


def choose_residual_gain(model, trajs, groups, gains=GAIN_GRID, points: int = LEFT_OUT_POINTS,
                         seed: int = 0, *, phase_steps=None, left_out_prior: bool = True) -> dict | None:
    """The gain g on the GP's residual mean that predicts left-out demonstrations' rollouts best (module
    docstring: the criterion J and the one-standard-error rule toward the smaller gain).

    ``model``: a trained :class:`~rbgp_cli.dynamics.model.MotionModel` (an exact GP, a phase input);
    ``trajs``: its D training demonstrations in the order of ``groups`` (n,), each training row's
    demonstration. The left-out posteriors rest on at most ``points`` rows (:func:`subset_posterior`, seeded
    by ``seed``). Returns None with fewer than three demonstrations or without an exact GP, else
    {"gain", "grid", "error" (mean J per gain), "standard_error" (of J(g) − J(g_best) per gain),
    "best" (the gain with the smallest mean J), "demos", "position_rmse", "rotation_rmse" (m, rad per
    gain, pooled over the demonstrations), "points" (rows of the left-out posteriors), "prior" ("left
    out" or "shared"), "seconds"}. At most LEFT_OUT_DEMOS demonstrations (seeded) are left out and
    rolled out; ``demos`` says how many.

    ``left_out_prior`` (the default): the prior mean that steers d's rollout is refitted without d as
    well (:func:`left_out_priors`: the mean path, the start map, the pull's profile), and the GP that has
    not seen d is the one on the other rows' residuals from that prior (:func:`left_out_weights`'
    ``targets``): the model :func:`~rbgp_cli.dynamics.model.train_model` would make without d at the
    same hyperparameters, noise and start-map ridge. False: the model's own prior for every rollout (the
    criterion until issue 36's seventh pass, optimistic for g = 0). ``phase_steps`` (n,): each training
    row's phase step (``info["phase_steps"]`` of :func:`~rbgp_cli.dynamics.model.training_set`), for the
    residuals' secant feed-forward; None: the training step over the row's demonstration's duration."""
    t0 = time.perf_counter()
    if len(trajs) < 3 or model.time_input != "phase":
        return None
    gains = np.asarray(sorted(set(float(g) for g in gains) | {0.0}), dtype=np.float64)
    gp, rows = subset_posterior(model.gp, points, seed)
    groups = np.asarray(groups)[rows]
    D = len(trajs)
    pick = np.arange(D)
    if D > LEFT_OUT_DEMOS:
        rng = np.random.default_rng(np.random.SeedSequence([int(seed), 37]))
        pick = np.sort(rng.choice(D, size=LEFT_OUT_DEMOS, replace=False))
    priors = targets = None
    if left_out_prior and model.mean:
        priors, targets = _left_out_targets(model, trajs, gp, groups, pick,
                                            None if phase_steps is None else np.asarray(phase_steps)[rows])
    A = left_out_weights(gp, groups, targets=targets, demos=pick)
    if A is None:
        return None
    trajs = [trajs[i] for i in pick]
    errs = left_out_rollout_errors(model, trajs, None, gains, weights=A, gp=gp, priors=priors)
    P, R = errs
    # each part relative to the path distribution's own (g = 0); a part it reproduces to round-off
    # (demonstrations that never turn, or never move) is left out: its ratio would be round-off's
    parts = [E / float(np.mean(E[:, 0])) for E, tiny in ((P, 1e-20), (R, 1e-20)) if float(np.mean(E[:, 0])) > tiny]
    if not parts:
        return None
    J = sum(parts) / len(parts)  # (D, G)
    mean = J.mean(axis=0)
    best = int(np.argmin(mean))
    diff = J - J[:, best:best + 1]
    se = diff.std(axis=0, ddof=1) / np.sqrt(len(trajs))
    chosen = smallest_equivalent(mean, se)
    # the standard errors of J_d(g) − J_d(0), what residual_off_clearly weighs each gain against g = 0 with
    se0 = (J - J[:, :1]).std(axis=0, ddof=1) / np.sqrt(len(trajs))
    return {"gain": float(gains[chosen]), "grid": gains.tolist(), "error": mean.tolist(),
            "standard_error": se.tolist(), "standard_error_zero": se0.tolist(), "best": float(gains[best]),
            "demos": len(trajs), "points": int(len(rows)),
            "prior": "left out" if priors is not None else "shared", "position_rmse": np.sqrt(P.mean(axis=0)).tolist(), "rotation_rmse": np.sqrt(R.mean(axis=0)).tolist(),
            "seconds": time.perf_counter() - t0}


def _left_out_targets(model, trajs, gp, groups, pick, phase_steps):
    """For :func:`choose_residual_gain`: the :class:`StackedPriors` of the prior refitted without each
    demonstration of ``pick`` (reference i: without pick[i]), and each one's GP targets at the rows of
    ``gp`` (``groups`` (n,) their demonstrations): y_d = y + m(x) − m₋d(x), (len(pick), n, L), the
    residuals of the training velocities from the prior without d, each row at its own demonstration's
    start deviation and phase step (``phase_steps`` (n,) or None: the training step over its duration)."""
    trajs = list(trajs)
    prior = (model.summary or {}).get("prior") or {}  # a trained model keeps the map's ridge and units there
    priors = StackedPriors(left_out_priors(model.mean, trajs, pick, ridge=prior.get("start_ridge"),
                                           inputs=prior.get("start_inputs")) + [model.mean])
    R, n = len(pick), len(gp.X)
    q0 = np.array([tr.quat[0] for tr in trajs])[groups]
    p0 = np.array([tr.position[0] for tr in trajs])[groups]
    steps = phase_steps
    if steps is None and model.mean.get("feedforward") == "secant":
        steps = float(model.dt) / np.array([max(tr.duration, 1e-9) for tr in trajs])[groups]
    if model.mean.get("feedforward") != "secant":
        steps = None
    ref = np.repeat(np.arange(R + 1), n)  # reference i for the rows' copy i; the model's own last
    Xs = np.tile(np.asarray(gp.X, dtype=np.float64), (R + 1, 1))
    qs, ps = np.tile(q0, (R + 1, 1)), np.tile(p0, (R + 1, 1))
    dev = priors.start_deviation(qs, ps, ref)
    m = priors.outputs(model.representation, Xs, ref, dev, None if steps is None else np.tile(steps, R + 1))
    m = m.reshape(R + 1, n, -1)
    return priors, np.asarray(gp.Y, dtype=np.float64)[None] + m[-1][None] - m[:-1]


# ---------------------------------------------------------------------- the prior left out too
def _resampled(trajs, s: np.ndarray):
    """Each demonstration at the phases ``s`` (S,) as :func:`rbgp_cli.dynamics.model.mean_path` resamples
    it: quat (D, S, 4) sign-continuous, position (D, S, 3)."""
    from rbgp_cli.dynamics.trajectory import interpolate_poses
    from rbgp_cli.geometry.so3 import quat_make_continuous

    Q, P = [], []
    for tr in trajs:
        q, p = interpolate_poses((tr.t - tr.t[0]) / max(tr.duration, 1e-12), quat_make_continuous(tr.quat), tr.position, s)
        Q.append(q)
        P.append(p)
    return np.array(Q), np.array(P)


def left_out_priors(mean: dict, trajs, demos, *, ridge: float | None = None, inputs: str | None = None) -> list[dict]:
    """The prior mean ``mean`` (a model's ``mean``, docs/method.md §7) refitted without each demonstration
    d of ``demos`` (indices into ``trajs``, the D demonstrations it was fitted on): what
    :func:`rbgp_cli.dynamics.model.train_model` builds from the other D − 1 with the same options.

    ``path``: the mean path (chordal mean rotation R̄₋d(s), mean position p̄₋d(s), their secant
    velocity per grid interval), the deviations δ of the others from it, the start map
    μ₋d(s) + B₋d(s) c(0) (:func:`rbgp_cli.dynamics.variation._ridge_map`: the ridge regression on the
    others, in their own units) and the pull's profile (:func:`rbgp_cli.dynamics.variation.pull_profile`)
    refitted; the start map's ridge λ and units are the model's (chosen by folds over all D, as the
    GP's hyperparameters are kept: ``mean["start_ridge"]`` and ``mean["start_inputs"]`` during training,
    else ``ridge`` (None: ∞) and ``inputs``). ``goal``: the others' mean final pose. Every other key is the
    model's. Returns one dict per demonstration of ``demos``, in that order."""
    from rbgp_cli.dynamics.model import goal_pose
    from rbgp_cli.dynamics.variation import _coordinate_scale, _ridge_map, pull_profile, start_reach
    from rbgp_cli.geometry.so3 import log_quat, quat_conjugate, quat_make_continuous, quat_multiply

    D = len(trajs)
    if mean["kind"] == "goal":
        return [{**mean, "goal": goal_pose([trajs[k] for k in range(D) if k != d]).tolist()} for d in demos]
    s = np.asarray(mean["s"], dtype=np.float64)
    Q, P = _resampled(trajs, s)  # (D, S, 4), (D, S, 3)
    out = []
    for d in demos:
        keep = np.delete(np.arange(D), d)
        Qk, Pk = Q[keep], P[keep]
        _, V = np.linalg.eigh(np.einsum("dsi,dsj->sij", Qk, Qk))
        q_mean = quat_make_continuous(V[:, :, -1])
        p_mean = Pk.mean(axis=0)
        vel = np.concatenate([log_quat(quat_multiply(q_mean[1:], quat_conjugate(q_mean[:-1]))), np.diff(p_mean, axis=0)],
                             axis=1) / np.diff(s)[:, None]
        m = {**mean, "quat": q_mean, "position": p_mean, "velocity": vel}
        if "start_beta" in mean:
            rot = log_quat(quat_multiply(Qk, quat_conjugate(q_mean)[None]))
            delta = np.concatenate([rot, Pk - p_mean[None]], axis=-1)  # (D − 1, S, 6)
            lam = mean.get("start_ridge", ridge)
            units = mean.get("start_inputs", inputs or "path")
            mu, B = _ridge_map(delta, _coordinate_scale(delta), float("inf") if lam is None else float(lam), units)
            m["start_mean"], m["start_beta"] = mu, B
            if mean.get("start_reach") is not None:  # bounded as the model's (variation.start_reach)
                m["start_reach"] = start_reach(delta, mu)
            if mean.get("gain_profile") is not None:
                m["gain_profile"] = pull_profile(delta, mu, B, s, float(mean["gain"]))
        out.append(m)
    return out


class StackedPriors:
    """R prior means of one kind and grid (:func:`left_out_priors`, and the model's own) evaluated at once,
    each row of a batch with its own: the arithmetic of :class:`rbgp_cli.dynamics.model.PathReference`
    and :func:`rbgp_cli.dynamics.model.prior_mean_outputs` with every array given a leading axis of R
    references, indexed per row by ``ref`` (m,)."""

    def __init__(self, means: list[dict]):
        from rbgp_cli.geometry.so3 import _log_quat_unit, quat_conjugate, quat_multiply, quat_normalize

        self.kind = means[0]["kind"]
        self.gain = float(means[0]["gain"])
        if self.kind == "goal":
            self.goal = np.array([m["goal"] for m in means], dtype=np.float64)  # (R, 7)
            self.conditioned = False
            return
        f = lambda key: np.array([np.asarray(m[key], dtype=np.float64) for m in means])  # noqa: E731
        self.s = np.asarray(means[0]["s"], dtype=np.float64)
        self.quat, self.position, self.velocity = f("quat"), f("position"), f("velocity")
        q0, q1 = quat_normalize(self.quat[:, :-1]), quat_normalize(self.quat[:, 1:])
        q1 = q1 * np.where(np.sum(q0 * q1, axis=-1, keepdims=True) < 0, -1.0, 1.0)
        self._q0 = q0
        self._phi = _log_quat_unit(quat_normalize(quat_multiply(quat_conjugate(q0), q1)))
        self.conditioned = "start_beta" in means[0]
        if self.conditioned:
            self.start_mean, self.start_beta = f("start_mean"), f("start_beta")  # (R, S, 6), (R, S, 6, 6)
            ds = np.diff(self.s)
            self._dmu = np.diff(self.start_mean, axis=1) / ds[None, :, None]
            self._dbeta = np.diff(self.start_beta, axis=1) / ds[None, :, None, None]
            self.start_reach = f("start_reach") if means[0].get("start_reach") is not None else None  # (R, S, 2)
        self.profile = f("gain_profile") if means[0].get("gain_profile") is not None else None

    def start_deviation(self, quat, position, ref) -> np.ndarray | None:
        """c = δ(0) − μ(0) (m, 6) of start poses (quat (m, 4), position (m, 3)) under each row's reference
        ``ref`` (m,) (:meth:`PathReference.start_deviation`); None for priors without start conditioning."""
        from rbgp_cli.geometry.so3 import log_quat, quat_conjugate, quat_multiply

        if not self.conditioned:
            return None
        rot = log_quat(quat_multiply(np.asarray(quat, float), quat_conjugate(self.quat[ref, 0])))
        return np.concatenate([rot, np.asarray(position, float) - self.position[ref, 0]], axis=1) - self.start_mean[ref, 0]

    def _interval(self, s):
        x = self.s
        s = np.clip(np.asarray(s, dtype=np.float64).reshape(-1), x[0], x[-1])
        k = np.clip(np.searchsorted(x, s, side="right") - 1, 0, len(x) - 2)
        return k, np.clip((s - x[k]) / (x[k + 1] - x[k]), 0.0, 1.0)

    def _pose(self, s, ref, dev):
        """The (start-conditioned) reference pose of each row at phases s (m,) (PathReference.at /
        conditioned_at), and its tangent velocity."""
        from rbgp_cli.dynamics.variation import bound_shift
        from rbgp_cli.geometry.so3 import exp_quat, quat_multiply

        k, f = self._interval(s)
        q = quat_multiply(self._q0[ref, k], exp_quat(f[:, None] * self._phi[ref, k]))
        q = np.where((f == 0.0)[:, None], self.quat[ref, k], np.where((f == 1.0)[:, None], self.quat[ref, k + 1], q))
        p = (1.0 - f)[:, None] * self.position[ref, k] + f[:, None] * self.position[ref, k + 1]
        ff = self.velocity[ref, k]
        if self.conditioned and dev is not None:
            mu = (1.0 - f)[:, None] * self.start_mean[ref, k] + f[:, None] * self.start_mean[ref, k + 1]
            g = f[:, None, None]
            beta = (1.0 - g) * self.start_beta[ref, k] + g * self.start_beta[ref, k + 1]
            reach = None if self.start_reach is None else (
                (1.0 - f)[:, None] * self.start_reach[ref, k] + f[:, None] * self.start_reach[ref, k + 1])
            shift, kb = bound_shift(np.einsum("mij,mj->mi", beta, dev), dev, reach)  # as PathReference.conditioned_at
            delta = mu + shift
            q = quat_multiply(exp_quat(delta[:, :3]), q)
            p = p + delta[:, 3:]
            ff = ff + self._dmu[ref, k] + np.einsum("mij,mj->mi", self._dbeta[ref, k], dev) * kb
        return q, p, ff

    def outputs(self, representation, X, ref, dev=None, step=None) -> np.ndarray:
        """The prior mean as the representation's outputs (m, L) at inputs X (m, d) (pose state, then the
        phase), row i under reference ``ref[i]`` with start deviation ``dev[i]`` (:meth:`start_deviation`)
        and phase step ``step`` (scalar or (m,); None: the tangent), as
        :func:`~rbgp_cli.dynamics.model.prior_mean_outputs`."""
        from rbgp_cli.dynamics.model import path_secant
        from rbgp_cli.geometry.so3 import log_quat, quat_conjugate, quat_multiply

        X = np.asarray(X, dtype=np.float64)
        state = X[:, : len(representation.input_names)]
        quat, pos = representation.pose_from_state(state)
        ref = np.asarray(ref, dtype=int).reshape(-1)
        m = len(X)
        a = self.gain
        if self.kind == "goal":
            ref_q, ref_p, ff = self.goal[ref, :4], self.goal[ref, 4:], 0.0
        else:
            s = X[:, -1]
            h = None if step is None else np.broadcast_to(np.asarray(step, dtype=np.float64), (m,))
            if h is not None and not np.all(h > 0):
                h = None
            ref_q, ref_p, ff = self._pose(s, ref, dev)
            if h is not None:  # the secant over one step (PathReference._over_step)
                q2, p2, _ = self._pose(s + h, ref, dev)
                ff = path_secant(ref_q, ref_p, q2, p2, h)
            if self.profile is not None:  # pull_gains per row
                idx = np.clip(np.searchsorted(self.s, np.clip(s, 0.0, 1.0), side="right") - 1, 0, len(self.s) - 1)
                a = self.profile[ref, idx]
                if h is not None:
                    a = np.minimum(a, 1.0 / np.maximum(np.abs(h), 1e-12)[:, None])
        rot = log_quat(quat_multiply(ref_q, quat_conjugate(quat)))
        xi = ff + a * np.concatenate([rot, ref_p - pos], axis=1)
        return representation.output_from_velocity(state, quat, xi)
