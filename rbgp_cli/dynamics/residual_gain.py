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

exactly C_¬b¬b⁻¹ y_¬b, without a refit. The hyperparameters, the calibrated noise and the path
distribution are the model's own (fitted with d): only the GP's residual is left out; the mean path
then knows d a little (weight 1/D), which favours smaller gains, the conservative side.

**The criterion.** For each gain g of the grid, J_d(g) = ½ (P_d(g)/P̄(0) + R_d(g)/R̄(0)), with P_d and
R_d the mean squared position (m²) and rotation angle (rad²) error of demonstration d's left-out rollout
against d at the same phases, and P̄(0), R̄(0) their means over the demonstrations at g = 0 (so J is
unit-free and 1 for the path distribution alone on average). The gain with the smallest mean J wins,
unless a smaller gain is within one standard error of the paired differences J_d(g) − J_d(g_best)
(the one-standard-error rule: the simpler model unless the folds' noise cannot explain the gain).

Cost: one Cholesky factor and inverse per hyperparameter set (m³, on at most m = LEFT_OUT_POINTS rows:
:func:`subset_posterior`), and one batched rollout of D × G trajectories (D at most LEFT_OUT_DEMOS) at the training step (one
kernel block of (D·G) × m per step and set).
"""

from __future__ import annotations

import time

import numpy as np

__all__ = ["GAIN_GRID", "choose_residual_gain", "left_out_weights", "left_out_rollout_errors"]

#: The gains tried on the GP's residual mean (1: the full model; 0: the path distribution alone).
GAIN_GRID = (0.0, 0.25, 0.5, 1.0)
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


def left_out_weights(gp, groups) -> list[np.ndarray] | None:
    """Per hyperparameter set of an exact GP (``gp.group_outputs()``), the posterior weights without each
    demonstration: A (D, n, L_g) with A[d] = α₋d = C_¬b¬b⁻¹ y_¬b on the rows of the other demonstrations and
    zero on d's rows b (module docstring), on the outputs as fitted (y / y_scale). ``groups`` (n,) the
    demonstration (0 … D − 1) of each training row. None for a GP without an exact posterior (sparse)."""
    from scipy.linalg import lapack

    from rbgp_cli.compute import thread_pool, thread_workers
    from rbgp_cli.gp.likelihood import NOISE

    if getattr(gp, "sparse", False) or not hasattr(gp, "kernel") or not hasattr(gp, "fits"):
        return None
    groups = np.asarray(groups)
    D = int(groups.max()) + 1 if len(groups) else 0
    blocks = [np.flatnonzero(groups == d) for d in range(D)]
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
        y = np.asarray(gp.Y[:, outs], dtype=np.float64) / gp.y_scale[outs]
        alpha = Binv @ y  # (n, L_g)
        A = np.empty((D,) + alpha.shape)
        for d, b in enumerate(blocks):
            a = alpha.copy()
            if len(b):
                a -= Binv[:, b] @ np.linalg.solve(Binv[np.ix_(b, b)], alpha[b])
                a[b] = 0.0
            A[d] = a
        return A

    groups_ = gp.group_outputs()
    # the sets on threads where cores are free (LAPACK and BLAS release the GIL; BLAS single-threaded here)
    threads = min(len(groups_), thread_workers(len(groups_), 2))
    out = list(thread_pool("residual-gain").map(one, groups_)) if threads > 1 else [one(g) for g in groups_]
    return None if any(a is None for a in out) else out


def left_out_rollout_errors(model, trajs, groups, gains=GAIN_GRID, weights=None, return_poses: bool = False,
                            gp=None):
    """Each demonstration rolled out from its own start for its own duration with every gain g of
    ``gains`` on the residual of the GP that has not seen it (:func:`left_out_weights`), batched: D × G
    trajectories advance together at the model's training step. Returns (P, R), each (D, G): the mean
    squared position error (m²) and rotation angle (rad²) against the demonstration at the rollout's
    phases k/S_d, k = 1 … S_d. None where the GP has no exact posterior. With ``return_poses`` also the
    rollouts' poses, quat (S + 1, D·G, 4) and position (S + 1, D·G, 3) (row d·G + j: demonstration d, gain
    j; its first S_d + 1 steps), and the steps S_d (D,). ``gp``: the GP whose left-out posteriors roll out
    (default the model's; :func:`subset_posterior`), ``groups`` its rows'."""
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
    dev = model.start_deviation(q0, p0)
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
        mu = model.prior_mean(X, dev, step)
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


def choose_residual_gain(model, trajs, groups, gains=GAIN_GRID, points: int = LEFT_OUT_POINTS,
                         seed: int = 0) -> dict | None:
    """The gain g on the GP's residual mean that predicts left-out demonstrations' rollouts best (module
    docstring: the criterion J and the one-standard-error rule toward the smaller gain).

    ``model``: a trained :class:`~rbgp_cli.dynamics.model.MotionModel` (an exact GP, a phase input);
    ``trajs``: its D training demonstrations in the order of ``groups`` (n,), each training row's
    demonstration. The left-out posteriors rest on at most ``points`` rows (:func:`subset_posterior`, seeded
    by ``seed``). Returns None with fewer than three demonstrations or without an exact GP, else
    {"gain", "grid", "error" (mean J per gain), "standard_error" (of J(g) − J(g_best) per gain),
    "best" (the gain with the smallest mean J), "demos", "position_rmse", "rotation_rmse" (m, rad per
    gain, pooled over the demonstrations), "points" (rows of the left-out posteriors), "seconds"}. At
    most LEFT_OUT_DEMOS demonstrations (seeded) are left out and rolled out; ``demos`` says how many."""
    t0 = time.perf_counter()
    if len(trajs) < 3 or model.time_input != "phase":
        return None
    gains = np.asarray(sorted(set(float(g) for g in gains) | {0.0}), dtype=np.float64)
    gp, rows = subset_posterior(model.gp, points, seed)
    A = left_out_weights(gp, np.asarray(groups)[rows])
    if A is None:
        return None
    D = len(trajs)
    pick = np.arange(D)
    if D > LEFT_OUT_DEMOS:
        rng = np.random.default_rng(np.random.SeedSequence([int(seed), 37]))
        pick = np.sort(rng.choice(D, size=LEFT_OUT_DEMOS, replace=False))
    trajs = [trajs[i] for i in pick]
    errs = left_out_rollout_errors(model, trajs, None, gains, weights=[Ag[pick] for Ag in A], gp=gp)
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
    chosen = best
    for i in range(best):  # the smallest gain within one standard error of the best
        if mean[i] - mean[best] <= se[i]:
            chosen = i
            break
    return {"gain": float(gains[chosen]), "grid": gains.tolist(), "error": mean.tolist(),
            "standard_error": se.tolist(), "best": float(gains[best]), "demos": len(trajs), "points": int(len(rows)),
            "position_rmse": np.sqrt(P.mean(axis=0)).tolist(), "rotation_rmse": np.sqrt(R.mean(axis=0)).tolist(),
            "seconds": time.perf_counter() - t0}
