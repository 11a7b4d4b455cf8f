"""Issue 37, tenth pass: the duration of a motion under way in studies of five, under other seen fits.

Usage:
    python scripts/duration_few.py DIR [--body NAME] [--train-size 5] [--folds 5] [--seed 0] [--rules]

(``--train-size 0``: crossval's own folds, every other demonstration trained on.)

On crossval's own subsets (``rbgp crossval DIR --train-size N``: :func:`rbgp_cli.evaluation.crossval.make_splits`),
each subset's path distribution is fitted as ``rbgp train`` fits it (:func:`rbgp_cli.dynamics.paths.fit_paths`,
:func:`rbgp_cli.dynamics.anticipation.fit_seen`), and every held-out demonstration's first F (crossval's
:func:`rbgp_cli.evaluation.under_way.split_seen`) gives an end time t_0 + D̂ (:meth:`Anticipator.estimate`, the
weights' median) under:

- ``chosen``: the (τ², r) fit_seen chose for the duration (what crossval's rbgp row uses);
- ``r=R``: a fixed (τ² = 0.01, r = R), R in 0.8, 3.2, 12.8;
- ``σ=0.3``: a fixed τ² = 0.01 with a tolerance of 0.3 rad and m for every coordinate (twelfth pass);
- ``cross×K``: the chosen (τ², r) with the covariance between ln D and the path times K (0, 0.5): the seen part
  fitted without (or with half) its learnt relation to the duration;
- ``median``: the training durations' median alone (no seen part; at least the seen span);
- ``ridge ProMP``: the regularised ProMP peer's own duration estimate (:class:`~rbgp_cli.evaluation.under_way.PhaseProMP`
  with :func:`~rbgp_cli.evaluation.under_way.ridge_std`), what crossval's promp-ridge row uses.

With ``--rules`` (twenty-eighth pass), also the choice made by other rules among fit_seen's candidates, on the same
left-out beginnings (:func:`~rbgp_cli.dynamics.anticipation._duration_loo`):

- ``rule 2 SE``: the loosest candidate within two standard errors of the best (fit_seen takes one);
- ``rule per demo``: within one standard error, each left-out demonstration's four beginnings averaged first (the
  standard error over demonstrations, not beginnings);
- ``rule 12 poses``: within one standard error, the beginnings estimated with 12 seen poses and 32 durations (the
  continuation's) instead of the live update's 6 and 16.

Prints the mean |end time error| (s) per F and the choices per subset. Nothing here changes rbgp; it measures
(docs/defaults.md, issue 37, tenth and twenty-eighth passes).
"""

from __future__ import annotations

import argparse

import numpy as np

FRACTIONS = (0.2, 0.4, 0.6, 0.8)


def main(argv=None):
    from rbgp_cli.dynamics.anticipation import (DURATION_FEW_BELOW, SEEN_FRACTIONS, Anticipator, _duration_loo,
                                                _loosest_within, fit_seen)
    from rbgp_cli.dynamics.paths import fit_paths
    from rbgp_cli.evaluation.crossval import make_splits
    from rbgp_cli.evaluation.under_way import PhaseProMP, ridge_std, split_seen
    from rbgp_cli.io.read import ReadOptions
    from rbgp_cli.workflows import load_demonstrations

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dir")
    ap.add_argument("--body", default=None)
    ap.add_argument("--train-size", type=int, default=5)
    ap.add_argument("--folds", type=int, default=5)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--rules", action="store_true", help="also the choices of other rules (slower)")
    args = ap.parse_args(argv)

    class Scaled(Anticipator):
        """The anticipator with the ln D – path covariance of its duration weights times ``kappa``."""

        kappa = 1.0

        def _constants(self):
            c = self.__dict__.get("_fc")
            if c is None:
                c = super()._constants()
                c["uL"] = c["uL"] * self.kappa  # Σ_ℓ,path's low-rank part; Σ_ℓℓ (uLuL) unchanged
            return c

    trajs, _, _ = load_demonstrations([args.dir], ReadOptions(body=args.body) if args.body else ReadOptions())
    splits = make_splits(len(trajs), args.folds, args.seed, "random", args.train_size or None)
    errors: dict = {}
    picks = []
    for train_idx, test_idx in splits:
        train = [trajs[i] for i in train_idx]
        paths = fit_paths(train)
        fit_seen(paths, train)
        picks.append((paths.duration_smooth, paths.duration_tolerance, paths.duration_sigma))
        ants = {"chosen": Anticipator(paths, None)}
        for r in (0.8, 3.2, 12.8):
            ants[f"r={r:g}"] = Anticipator(paths, None, duration_smooth=0.01, duration_tolerance=r)
        ants["σ=0.3"] = Anticipator(paths, None, duration_smooth=0.01, duration_sigma=0.3)
        for k in (0.0, 0.5):
            a = Scaled(paths, None)
            a.kappa = k
            ants[f"cross×{k:g}"] = a
        if args.rules:
            errs = _duration_loo(paths, train, per_beginning=True)
            errs12 = _duration_loo(paths, train, per_beginning=True, points=12, grid_size=32)
            few = len(train) < DURATION_FEW_BELOW
            per_demo = {c: e.reshape(-1, len(SEEN_FRACTIONS)).mean(axis=1) for c, e in errs.items()}
            for name, (E, k) in {"rule 2 SE": (errs, 2.0), "rule per demo": (per_demo, 1.0),
                                 "rule 12 poses": (errs12, 1.0)}.items():
                c = _loosest_within(E, k) if few else min(E, key=lambda c: float(np.mean(E[c])))
                ants[name] = Anticipator(paths, None, duration_smooth=c[0], duration_tolerance=c[1], duration_sigma=c[2])
        promp = PhaseProMP(train, ridge_std(train, seed=args.seed))
        median = float(np.exp(np.median(paths.log_durations)))
        for i in test_idx:
            tr = trajs[i]
            for F in FRACTIONS:
                seen, _ = split_seen(tr, F)
                for name, a in ants.items():
                    est = a.estimate(seen.t, seen.quat, seen.position)
                    errors.setdefault(name, {f: [] for f in FRACTIONS})[F].append(abs(est.end_time - tr.t[-1]))
                errors.setdefault("median", {f: [] for f in FRACTIONS})[F].append(
                    abs(tr.t[0] + max(median, seen.duration) - tr.t[-1]))
                tau, Y = promp._seen(seen)
                errors.setdefault("ridge ProMP", {f: [] for f in FRACTIONS})[F].append(
                    abs(tr.t[0] + promp.duration(tau, Y) - tr.t[-1]))
    what = f"subsets of {args.train_size}" if args.train_size else "folds"
    print(f"{args.dir}: {len(splits)} {what}; fit_seen's duration (τ², r, σ) per subset: {picks}")
    print("| seen fit | " + " | ".join(f"F = {F:g}" for F in FRACTIONS) + " |")
    print("|---|" + "---|" * len(FRACTIONS))
    for name, per_F in errors.items():
        print(f"| {name} | " + " | ".join(f"{np.mean(per_F[F]):.3f}" for F in FRACTIONS) + " |")


if __name__ == "__main__":
    main()
