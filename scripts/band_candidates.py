"""Issues 36 and 38, eighth pass: the bands' factors under other rules, on crossval's own folds and fits.

Usage:
    python scripts/band_candidates.py record OUT.pkl DIR [crossval options ...]
    python scripts/band_candidates.py table OUT.pkl [OUT.pkl ...]

``record`` runs ``rbgp crossval DIR [options] --jobs 1 --no-peers --no-replay`` in this process and keeps,
per fold, what the coverage under other factors needs: each held-out motion's errors at every scored step
in units of the band at factor 1 (position |e_j| / half-width_j · c_pos, rotation √(eᵀ M⁻¹ e) · c_rot, M the
band's region; :func:`rbgp_cli.evaluation.coverage.band_coverage`'s resampling and interpolation), the
factors the model used (``variation.band_scale``, or ``paths.goal_band_scale()`` with ``--given goal``),
its training demonstrations' deviations and start map (the options ``band_calibration`` was given) and its
path distribution. A step is inside a band with factors c' exactly when its error in those units is ≤ c',
so every rule below is scored on the same mean rollouts (the factors move nothing else: RMSE and sample
ratio are unchanged by construction).

``table`` checks that the kept factors reproduce crossval's coverage counts, then prints the pooled
coverage (position / rotation) of each candidate rule:

- start-only bands (:func:`rbgp_cli.dynamics.variation.band_calibration`): ``forward`` (a third kind of
  left-out split, each block in recording order predicted from the blocks before it once at least
  MIN_BAND_DEMOS precede it, c = the largest of the three kinds), ``forward-pooled`` (those forward splits
  and the recorded blocks in one quantile, c = the larger of it and the random one), ``one-SE`` (each kind's
  factor at its one-standard-error upper bound, the standard error of its log from a jackknife over the
  left-out demonstrations);
- goal bands (:meth:`rbgp_cli.dynamics.paths.PathDistribution.goal_band_scale`): ``forward`` (forward splits as
  above, scored as the blocks are, against ν = D − 2), ``forward-own-nu`` and ``own-nu`` (every left-out split
  scored against its own model's Student-t quantiles, ν = N − 2 of its N, as the start-only factors are);
- both: every factor × k (``scale``), to show how far the pooled cells move at all.

Nothing here changes rbgp; it measures (docs/defaults.md, issues 36 and 38, eighth pass).
"""

from __future__ import annotations

import pickle
import sys

import numpy as np

LEVEL = 0.90
SCALES = (0.98, 0.99, 0.995, 1.005, 1.01, 1.02, 1.05, 1.1, 1.2)


# ----------------------------------------------------------------------------------------------- record
def _units(gen, real, T):
    """Errors of ``real`` against the band around ``gen`` (info["band"]) in units of that band, at T steps
    of normalised time, as band_coverage measures them: (position (T, 3), rotation (T,))."""
    from rbgp_cli.evaluation.resample import resample_all
    from rbgp_cli.geometry.so3 import log_quat, quat_conjugate, quat_multiply

    bp, bm = gen.info["band"]
    qm, pm = resample_all([gen], T)
    qr, pr = resample_all([real], T)
    t = np.asarray(gen.t, float)
    x = t[0] + np.linspace(0.0, 1.0, T) * (t[-1] - t[0])
    bp = np.asarray(bp, float).reshape(len(t), 3)
    bm = np.asarray(bm, float).reshape(len(t), 9)
    half = np.stack([np.interp(x, t, bp[:, j]) for j in range(3)], axis=1)
    M = np.stack([np.interp(x, t, bm[:, j]) for j in range(9)], axis=1).reshape(T, 3, 3)
    M = M + np.maximum(1e-9 * np.trace(M, axis1=1, axis2=2) / 3.0, 1e-24)[:, None, None] * np.eye(3)
    a = np.abs(pr[0] - pm[0])
    e = log_quat(quat_multiply(qr[0], quat_conjugate(qm[0])))
    m2 = np.einsum("ti,ti->t", e, np.linalg.solve(M, e[..., None])[..., 0])
    with np.errstate(divide="ignore", invalid="ignore"):  # phase 0: no error, no width (inside)
        u = np.where(half > 0, a / np.where(half > 0, half, 1.0), np.where(a <= 0, 0.0, np.inf))
    return u, np.sqrt(m2)


def record(out_path: str, args: list[str]) -> None:
    import rbgp_cli.dynamics.model as model_mod
    import rbgp_cli.evaluation.crossval as cv
    from rbgp_cli.dynamics.variation import demonstration_deviations
    from rbgp_cli.gp.posterior import PriorOnly

    goal = "--given" in args and args[args.index("--given") + 1] == "goal"
    folds, last = [], {}
    fold_scores, side_init = cv._fold_scores, model_mod._WithoutGP.__init__

    def side(self, trajs, mean, *a, **k):  # the demonstrations the model's bands were computed from
        last["trajs"] = list(trajs)
        side_init(self, trajs, mean, *a, **k)

    def scores(gen, drawn, model, train, test, length, covariance):
        out = fold_scores(gen, drawn, model, train, test, length, covariance)
        if model is None or isinstance(model.gp, PriorOnly):
            return out
        c = tuple(model.paths.goal_band_scale()) if goal else tuple(model.variation.band_scale)
        up, ur = zip(*[_units(g, r, out["steps"]) for g, r in zip(gen, test)])
        path, delta = demonstration_deviations(last["trajs"])
        prior = model.summary.get("prior") or {}
        ridge = prior.get("start_ridge")
        paths = model.paths
        paths._goal_scale = None
        pull = float(model.mean["gain"]) if model.mean is not None and model.mean["kind"] == "path" else 0.0
        folds.append(dict(goal=goal, c=c, upos=[u * c[1] for u in up], urot=[u * c[0] for u in ur],
                          coverage=out.get("coverage"), delta=delta, s=np.asarray(path["s"], float),
                          ridge=float("inf") if ridge is None else float(ridge),
                          inputs=prior.get("start_inputs", "path"), gain=pull, paths=paths))
        return out

    cv._fold_scores, model_mod._WithoutGP.__init__ = scores, side
    sys.argv = ["rbgp", "crossval", *args, "--jobs", "1", "--no-peers", "--no-replay"]
    from rbgp_cli.cli.app import main

    try:
        main()
    except SystemExit:
        pass
    with open(out_path, "wb") as f:
        pickle.dump(folds, f)


# ----------------------------------------------------------------------------------------------- rules
def _inside(f, c) -> np.ndarray:
    """(position inside, position count, rotation inside, rotation count) of fold ``f`` with factors c."""
    up = np.concatenate([u.ravel() for u in f["upos"]])
    ur = np.concatenate([u.ravel() for u in f["urot"]])
    return np.array([np.sum(up <= c[1]), up.size, np.sum(ur <= c[0]), ur.size], float)


def forward_splits(D: int, blocks: int, least: int):
    """Each of min(blocks, D // 2) contiguous blocks in recording order predicted from the blocks before it,
    when at least ``least`` demonstrations precede it: [(train, test), ...] or None."""
    k = min(int(blocks), D // 2)
    if k < 2:
        return None
    parts = np.array_split(np.arange(D), k)
    out = [(np.concatenate(parts[:b]), parts[b]) for b in range(1, k) if sum(map(len, parts[:b])) >= least]
    return out or None


def _start_grouped(f, splits):
    """Left-out errors per held-out demonstration in units of its left-out model's Student-t quantiles."""
    from rbgp_cli.dynamics import variation as V

    scale = V._coordinate_scale(f["delta"])
    out = {}
    for train, test in splits:
        a, b, _ = V._held_out_errors(f["delta"], f["s"], train, test, ridge=f["ridge"], gain=f["gain"], scale=scale,
                                  inputs=f["inputs"])
        q_rot, q_pos = V.band_quantiles(len(train) - 2, LEVEL)
        for i, d in enumerate(test):
            out.setdefault(int(d), []).append((a[i].ravel() / q_rot, b[i].ravel() / q_pos))
    return out


def _factor(groups, keys=None):
    keys = sorted(groups) if keys is None else keys
    m2 = np.concatenate([x for k in keys for x, _ in groups[k]])
    z = np.concatenate([y for k in keys for _, y in groups[k]])
    return np.array([np.sqrt(np.quantile(m2, LEVEL)), np.quantile(z, LEVEL)])


def _one_se(groups):
    """The factor at its one-SE upper bound: c exp(se), se of log c by a jackknife over demonstrations."""
    keys = sorted(groups)
    n = len(keys)
    logs = np.log([_factor(groups, [k for k in keys if k != d]) for d in keys])
    se = np.sqrt((n - 1) / n * np.sum((logs - logs.mean(axis=0)) ** 2, axis=0))
    return _factor(groups) * np.exp(se)


def start_rule(f, rule: str):
    from rbgp_cli.dynamics import variation as V

    D = len(f["delta"])
    loo = [(np.setdiff1d(np.arange(D), [d]), np.array([d])) for d in range(D)]
    blocks = V._order_blocks(D, V.ORDER_BLOCKS)
    kinds = {"random": _start_grouped(f, loo)}
    if blocks is not None:
        kinds["recorded"] = _start_grouped(f, blocks)
    fw = forward_splits(D, V.ORDER_BLOCKS, V.MIN_BAND_DEMOS)
    if rule == "kept":
        c = np.max([_factor(g) for g in kinds.values()], axis=0)
    elif rule == "forward":
        if fw is not None:
            kinds["forward"] = _start_grouped(f, fw)
        c = np.max([_factor(g) for g in kinds.values()], axis=0)
    elif rule == "forward-pooled":
        if fw is not None and blocks is not None:
            both = {}
            for g in (kinds["recorded"], _start_grouped(f, fw)):
                for k, v in g.items():
                    both.setdefault(k, []).extend(v)
            kinds["recorded"] = both
        c = np.max([_factor(g) for g in kinds.values()], axis=0)
    elif rule == "one-SE":
        c = np.max([_one_se(g) for g in kinds.values()], axis=0)
    else:
        raise ValueError(rule)
    return np.maximum(1.0, c)


def _goal_split_stats(paths, splits, own_nu: bool):
    """paths._block_stats with explicit (train, test) splits, in units of ν = D − 2's quantiles (the
    blocks' scoring), or with ``own_nu`` of each split's own model (ν = N − 2 of its N), expressed in
    ν = D − 2's units so that paths._band_factors applies unchanged."""
    from scipy.special import fdtri, stdtrit

    from rbgp_cli.dynamics import paths as P

    idx, Xs, r2, _ = P._loo_setup(paths, moments=False)
    Ks = paths.smooth_covariance()[np.ix_(idx, idx)]
    nd = max(paths.demos - 2, 1)
    m2, z = [], []
    for train, test in splits:
        rest = Xs[train]
        N = len(rest)
        m = rest.mean(axis=0)
        C = rest - m
        Sigma = (1.0 + 1.0 / N) * (C.T @ C) / max(N - 1, 1) + Ks
        S11, S12 = Sigma[:12, :12] + np.diag(r2), Sigma[:12, 12:]
        gain = np.linalg.solve(S11, S12).T
        cov = Sigma[12:, 12:] - gain @ S12
        e = Xs[test, 12:] - (m[12:] + (Xs[test, :12] - m[:12]) @ gain.T)
        _, a, b = P.held_out_scores(e, np.broadcast_to(cov, (len(test),) + cov.shape), True)
        nu = max(N - 2, 1) if own_nu else nd
        m2.append(a.reshape(-1) * fdtri(3, nd, LEVEL) / fdtri(3, nu, LEVEL))
        z.append(b.reshape(-1, 3) * stdtrit(nd, 0.5 + LEVEL / 2) / stdtrit(nu, 0.5 + LEVEL / 2))
    return np.concatenate(m2), np.concatenate(z)


def goal_rule(f, rule: str):
    from rbgp_cli.dynamics import paths as P

    if rule not in ("kept", "own-nu", "forward", "forward-own-nu"):
        raise ValueError(rule)
    paths = f["paths"]
    D = paths.demos
    own = rule in ("own-nu", "forward-own-nu")
    loo = [(np.setdiff1d(np.arange(D), [d]), np.array([d])) for d in range(D)]
    if own:
        c = P._band_factors(*_goal_split_stats(paths, loo, True), D)
    else:
        _, m2, z = P._loo_scores(paths, paths.smooth, paths.length, stats=True)
        c = P._band_factors(m2, z, D)
    if (blocks := P.goal_blocks(D)) is not None:
        b = P._band_factors(*_goal_split_stats(paths, [(np.setdiff1d(np.arange(D), t), t) for t in blocks], own), D)
        c = tuple(max(x, y) for x, y in zip(c, b))
    if rule.startswith("forward") and (fw := forward_splits(D, P.GOAL_BLOCKS, P.MIN_PATH_DEMOS + 1)) is not None:
        c = tuple(max(x, y) for x, y in zip(c, P._band_factors(*_goal_split_stats(paths, fw, own), D)))
    w = min(1.0, D / P.NARROW_FROM)
    return np.array([max(P.NARROWEST, x if x >= 1.0 else x ** w) for x in c])


def table(path: str) -> None:
    folds = pickle.load(open(path, "rb"))
    goal = folds[0].get("goal", "goal" in path)
    for f in folds:  # the kept factors reproduce crossval's own counts
        assert np.array_equal(_inside(f, f["c"])[:4], np.asarray(f["coverage"][:4], float)), (path, f["coverage"])
    rules = ("kept", "own-nu", "forward", "forward-own-nu") if goal else ("kept", "forward", "forward-pooled", "one-SE")
    rule_of = goal_rule if goal else start_rule
    print(path)
    for rule in rules:
        cs = [rule_of(f, rule) for f in folds]
        if rule == "kept":
            assert all(np.allclose(c, f["c"]) for c, f in zip(cs, folds)), "the kept rule must give the model's factors"
        parts = [_inside(f, c) for f, c in zip(folds, cs)]
        t = sum(parts)
        print(f"  {rule:15s} {t[0] / t[1]:.3f} / {t[2] / t[3]:.3f}   factors rot/pos per fold: "
              + ", ".join(f"{c[0]:.2f}/{c[1]:.2f}" for c in cs))
        print(f"  {'':15s} coverage per fold: " + ", ".join(f"{x[0] / x[1]:.2f}/{x[2] / x[3]:.2f}" for x in parts))
    cells = []
    for k in SCALES:
        t = sum(_inside(f, np.asarray(f["c"]) * k) for f in folds)
        cells.append(f"×{k:g} {t[0] / t[1]:.4f}/{t[2] / t[3]:.4f}")
    print("  scale           " + " · ".join(cells))


if __name__ == "__main__":
    if len(sys.argv) >= 4 and sys.argv[1] == "record":
        record(sys.argv[2], sys.argv[3:])
    elif len(sys.argv) >= 3 and sys.argv[1] == "table":
        for p in sys.argv[2:]:
            table(p)
    else:
        sys.exit(__doc__)
