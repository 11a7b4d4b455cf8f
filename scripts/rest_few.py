"""Issue 37, twelfth pass: the rest of a motion under way in studies of five, under the two τ² fit_seen chooses from.

Usage:
    python scripts/rest_few.py DIR [--body NAME] [--train-size 5] [--folds 5] [--seed 0]

On crossval's own subsets (``rbgp crossval DIR --train-size N``: :func:`rbgp_cli.evaluation.crossval.make_splits`;
``--train-size 0``: its plain folds), each subset's path distribution is fitted as ``rbgp train`` fits it
(:func:`rbgp_cli.dynamics.paths.fit_paths`, which calls :func:`rbgp_cli.dynamics.anticipation.fit_seen`), and every
held-out demonstration's first F (crossval's :func:`rbgp_cli.evaluation.under_way.split_seen`) is continued by the
path distribution alone (crossval's ``no-GP`` row: :class:`Anticipator` without a model) with the rest conditioned
at the seen r and

- ``own``: the path distribution's own τ² (what the rest used below ten demonstrations before this pass);
- ``smooth``: τ² = REST_FEW_SMOOTH (10);
- ``chosen``: fit_seen's choice (below REST_FROM: the one of the two with the smaller left-out final-pose error,
  :func:`rbgp_cli.dynamics.anticipation._end_loo`).

Prints the choice per subset (1 = smooth) and, per F, the mean final position (m) and rotation (rad) errors and the
remainder's position and rotation RMSE on its own normalised time (crossval's cells). Nothing here changes rbgp; it
measures (docs/defaults.md, issue 37, twelfth pass).
"""

from __future__ import annotations

import argparse
import copy

import numpy as np

FRACTIONS = (0.2, 0.4, 0.6, 0.8)


def main(argv=None):
    from rbgp_cli.dynamics.anticipation import REST_FEW_SMOOTH, Anticipator
    from rbgp_cli.dynamics.paths import fit_paths
    from rbgp_cli.evaluation.crossval import make_splits
    from rbgp_cli.evaluation.under_way import score, split_seen
    from rbgp_cli.io.read import ReadOptions
    from rbgp_cli.workflows import load_demonstrations

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dir")
    ap.add_argument("--body", default=None)
    ap.add_argument("--train-size", type=int, default=5, help="0: crossval's plain folds")
    ap.add_argument("--folds", type=int, default=5)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)

    trajs, _, _ = load_demonstrations([args.dir], ReadOptions(body=args.body) if args.body else ReadOptions())
    splits = make_splits(len(trajs), args.folds, args.seed, "random", args.train_size or None)
    cells: dict = {}  # name -> F -> rows of (final position, final rotation, remainder pos², rot², its length)
    picks = []
    for train_idx, test_idx in splits:
        paths = fit_paths([trajs[i] for i in train_idx])
        picks.append(int(paths.rest_smooth == REST_FEW_SMOOTH and paths.rest_smooth != paths.smooth))
        ants = {"chosen": Anticipator(paths, None)}
        for name, tau2 in (("own", paths.smooth), ("smooth", REST_FEW_SMOOTH)):
            other = copy.copy(paths)
            other.rest_smooth, other.rest_tolerance = tau2, paths.seen_tolerance
            ants[name] = Anticipator(other, None)
        for i in test_idx:
            for F in FRACTIONS:
                seen, rest = split_seen(trajs[i], F)
                for name, a in ants.items():
                    mean = a.continuation(seen.t, seen.quat, seen.position).trajectories()[0]
                    sc = score(mean, [], rest)
                    row = (sc.end_pos[0], sc.end_rot[0], *sc.motion_sq[0])
                    cells.setdefault(name, {f: [] for f in FRACTIONS})[F].append(row)
    print(f"{args.dir}: {len(splits)} splits; the smooth rest chosen per split: {''.join(map(str, picks))}")
    print("| rest | " + " | ".join(f"F = {F:g}: final m / rad, remainder m / rad" for F in FRACTIONS) + " |")
    print("|---|" + "---|" * len(FRACTIONS))
    for name, per_F in cells.items():
        out = []
        for F in FRACTIONS:
            v = np.array(per_F[F])
            out.append(f"{v[:, 0].mean():.4f} / {v[:, 1].mean():.3f}, {np.sqrt(v[:, 2].sum() / v[:, 4].sum()):.4f} / "
                       f"{np.sqrt(v[:, 3].sum() / v[:, 4].sum()):.3f}")
        print(f"| {name} | " + " | ".join(out) + " |")


if __name__ == "__main__":
    main()
