"""Issue 36, tenth pass: would a model of the drift over the recording order predict the next session?

Usage:
    python scripts/drift_models.py DIR [--body NAME] [--folds 5] [--seed 0]

The hand raises drift over their session (``rbgp train`` says so; p = 0.001) and the bands hold their
next session 0.76 / 0.80 (``crossval --order forward``). The issue names the cure to try: "if a
between-session component of variation (a trend over recording order, or a variance of session means)
is what explains it, model it". This measures three such models against the kept one, in the space
where rbgp's path distribution lives: each demonstration d's deviation δ_d(s) (D, S, 6) from the mean
path of all of them (:func:`rbgp_cli.dynamics.variation.demonstration_deviations`; the mean path only
fixes the coordinates, the same for every model), predicted for each held-out take from its start value
δ(0) and its place i in the recording order (0-based, the order the files are read):

- ``kept``: the product's start map, μ + B(δ(0) − μ(0)) (:func:`rbgp_cli.dynamics.variation.start_map`,
  its ridge chosen by its own folds of the training takes);
- ``trend``: the kept map plus a straight line over the order fitted to its residuals,
  a(s) + b(s)(i − ī) per coordinate (least squares; the held-out take's own i, so a later block is
  extrapolated);
- ``latest-N``: the kept map fitted to the N training takes recorded last (a sliding window; N = 10, 5);
- ``level``: the kept map plus a Gaussian process over the order on its residuals,
  r_d ~ GP(0, v (ρ k_L(i, i') + (1 − ρ) δ_ii')), k_L squared-exponential in i with length-scale L takes,
  v per output column, ρ (the share of the variance that is a slowly varying session level) and L by the
  marginal likelihood pooled over the columns (ρ = 0 is the kept model). Its prediction is the level's
  posterior mean at i, its variance v (1 − ρ + ρ(1 − k*ᵀ K⁻¹ k*)) + the plug-in v / n: it widens where
  the level is extrapolated (the next session), not where it is interpolated (random folds).

Scores over the held-out takes and phases s > 0: position RMSE (m), rotation RMSE (rad), and the share of
coordinates inside a Gaussian 90 % interval with that model's predictive variance (for kept, trend and
latest-N: the training residuals' per-column variance × (1 + 1/n), n the training takes). The intervals
are per coordinate, not rbgp's bands (no Student-t, no left-out factors): compare models with each other,
not with crossval's coverage. Three splits: ``forward`` (each of the ``--folds`` recording-order blocks
after the first from the blocks before it), ``recorded`` (each block from the others), ``random``
(``--folds`` random folds, ``--seed``).

Nothing here changes rbgp; it measures (docs/defaults.md, issue 36, tenth pass).
"""

from __future__ import annotations

import argparse

import numpy as np
from scipy.stats import norm

RHO_GRID = (0.0, 0.05, 0.1, 0.2, 0.3, 0.5, 0.7)
LENGTH_GRID = (2.0, 5.0, 10.0, 20.0, 40.0)
WINDOWS = (10, 5)


def kept_prediction(delta_train, x0_test):
    """The product's start map fitted to ``delta_train`` (n, S, 6), at the held-out starts ``x0_test``
    (m, 6): (m, S, 6), and the training residuals (n, S, 6)."""
    from rbgp_cli.dynamics.variation import start_map

    sm = start_map(delta_train)
    mu, B = sm["mean"], sm["map"]

    def at(x0):
        return mu[None] + np.einsum("sij,mj->msi", B, x0 - mu[0][None])

    return at(x0_test), delta_train - at(delta_train[:, 0])


def _kernel(a, b, length):
    return np.exp(-(a[:, None] - b[None, :]) ** 2 / (2.0 * length**2))


def level_fit(order, resid):
    """ρ, L by the pooled marginal likelihood of the residual columns ``resid`` (n, C) at recording
    places ``order`` (n,), each column's variance v profiled out."""
    n, C = resid.shape
    best = None
    for rho in RHO_GRID:
        for length in LENGTH_GRID:
            K = rho * _kernel(order, order, length) + (1.0 - rho) * np.eye(n)
            L = np.linalg.cholesky(K + 1e-9 * np.eye(n))
            a = np.linalg.solve(L, resid)
            v = np.maximum(np.mean(a**2, axis=0), 1e-300)
            ll = -0.5 * n * np.sum(np.log(v)) - C * np.sum(np.log(np.diag(L)))
            if best is None or ll > best[0]:
                best = (ll, rho, length)
            if rho == 0.0:
                break  # L does not enter
    return best[1], best[2]


def split_scores(delta, order, train, test):
    """Every model's prediction errors (m, S, 6) and z-scores (m, S, 6) for one split."""
    n = len(train)
    x0 = delta[test, 0]
    out = {}
    pred, R = kept_prediction(delta[train], x0)
    var = np.mean(R**2, axis=0) * (1.0 + 1.0 / n)
    err = delta[test] - pred
    out["kept"] = (err, err / np.sqrt(np.maximum(var, 1e-300))[None])

    # trend: a line over the recording order on the kept map's residuals
    ot = order[train] - order[train].mean()
    F = np.stack([np.ones(n), ot], axis=1)
    coef, *_ = np.linalg.lstsq(F, R.reshape(n, -1), rcond=None)
    Rt = R.reshape(n, -1) - F @ coef
    tpred = pred + (np.stack([np.ones(len(test)), order[test] - order[train].mean()], axis=1) @ coef).reshape(pred.shape)
    var_t = np.mean(Rt**2, axis=0).reshape(R.shape[1:]) * (1.0 + 1.0 / n)
    err = delta[test] - tpred
    out["trend"] = (err, err / np.sqrt(np.maximum(var_t, 1e-300))[None])

    for w in WINDOWS:
        if n > w:
            latest = np.asarray(train)[np.argsort(order[train])[-w:]]
            p, Rw = kept_prediction(delta[latest], x0)
            v = np.mean(Rw**2, axis=0) * (1.0 + 1.0 / w)
        else:
            p, v = pred, var
        err = delta[test] - p
        out[f"latest-{w}"] = (err, err / np.sqrt(np.maximum(v, 1e-300))[None])

    # level: a GP over the recording order on the kept map's residuals
    Rf = R.reshape(n, -1)
    rho, length = level_fit(order[train], Rf)
    K = rho * _kernel(order[train], order[train], length) + (1.0 - rho) * np.eye(n)
    Ks = rho * _kernel(order[test], order[train], length)
    Kinv_R = np.linalg.solve(K, Rf)
    v = np.mean(Rf * Kinv_R, axis=0)  # the profiled variance per column
    post = (1.0 - rho) + rho - np.sum(Ks * np.linalg.solve(K, Ks.T).T, axis=1)  # (m,)
    lpred = pred + (Ks @ Kinv_R).reshape(pred.shape)
    sd = np.sqrt(np.outer(post + 1.0 / n, v)).reshape(pred.shape)
    err = delta[test] - lpred
    out["level"] = (err, err / sd)
    out["_level_hyper"] = (rho, length)
    return out


def splits(D, folds, seed):
    blocks = np.array_split(np.arange(D), folds)
    rng = np.random.default_rng(seed)
    rand = np.array_split(rng.permutation(D), folds)
    return {
        "forward": [(np.concatenate(blocks[:k]), blocks[k]) for k in range(1, folds) if sum(map(len, blocks[:k])) >= 4],
        "recorded": [(np.setdiff1d(np.arange(D), b), b) for b in blocks],
        "random": [(np.setdiff1d(np.arange(D), b), np.sort(b)) for b in rand],
    }


def main(argv=None):
    from rbgp_cli.io.read import ReadOptions
    from rbgp_cli.dynamics.variation import demonstration_deviations
    from rbgp_cli.workflows import load_demonstrations

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dir")
    ap.add_argument("--body", default=None)
    ap.add_argument("--folds", type=int, default=5)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    options = ReadOptions(body=args.body) if args.body else ReadOptions()
    trajs, _, _ = load_demonstrations([args.dir], options)
    _, delta = demonstration_deviations(trajs)
    D = len(delta)
    order = np.arange(D, dtype=float)
    c90 = norm.ppf(0.95)
    print(f"{args.dir}: {D} demonstrations")
    print("| split | model | position RMSE m | rotation RMSE rad | inside 90 % pos / rot | level ρ, L per split |")
    print("|---|---|---|---|---|---|")
    for name, parts in splits(D, args.folds, args.seed).items():
        results = [split_scores(delta, order, tr, te) for tr, te in parts]
        for model in ("kept", "trend", *(f"latest-{w}" for w in WINDOWS), "level"):
            E = np.concatenate([r[model][0] for r in results])[:, 1:]
            Z = np.concatenate([r[model][1] for r in results])[:, 1:]
            pos = np.sqrt(np.mean(np.sum(E[..., 3:] ** 2, axis=-1)))
            rot = np.sqrt(np.mean(np.sum(E[..., :3] ** 2, axis=-1)))
            inside = (np.mean(np.abs(Z[..., 3:]) <= c90), np.mean(np.abs(Z[..., :3]) <= c90))
            hyper = ", ".join(f"{r['_level_hyper'][0]:g}/{r['_level_hyper'][1]:g}" for r in results) if model == "level" else ""
            print(f"| {name} | {model} | {pos:.4f} | {rot:.3f} | {inside[0]:.2f} / {inside[1]:.2f} | {hyper} |")


if __name__ == "__main__":
    main()
