"""Issue 37, thirteenth pass: the end time's 90 % band of a motion under way, on crossval's splits.

Usage: python scripts/end_time_band.py SET_DIR [--body NAME] [--folds 5] [--train-size N] [--order random|forward|recorded]

For each split of ``rbgp crossval SET_DIR --given 0.2 --given 0.4 --given 0.6 --given 0.8`` (its splits,
:func:`~rbgp_cli.evaluation.crossval.make_splits`, seed 0) the path distribution of the training demonstrations
(:func:`~rbgp_cli.dynamics.paths.fit_paths`, which chooses the seen poses' evidence weight λ of the band,
``paths.duration_evidence``) estimates every held-out motion's end time from its first F
(:func:`~rbgp_cli.evaluation.under_way.split_seen`) with λ = 1 (the band before the thirteenth pass) and with the
chosen λ. Per F: the fraction of held-out end times inside the band, its mean width (s) and the point estimate's
mean error (s; the same for both, the median keeps λ = 1). The band does not depend on the GP, so no GP is trained.
Nothing here changes rbgp.
"""

from __future__ import annotations

import argparse
import time

import numpy as np


def main(argv=None):
    from rbgp_cli.dynamics.anticipation import Anticipator
    from rbgp_cli.dynamics.paths import fit_paths
    from rbgp_cli.evaluation.crossval import make_splits
    from rbgp_cli.evaluation.under_way import FRACTIONS, split_seen
    from rbgp_cli.io.options import ReadOptions
    from rbgp_cli.workflows import load_demonstrations

    ap = argparse.ArgumentParser()
    ap.add_argument("source")
    ap.add_argument("--body", default=None)
    ap.add_argument("--folds", type=int, default=5)
    ap.add_argument("--train-size", type=int, default=None)
    ap.add_argument("--order", default="random", choices=("random", "forward", "recorded"))
    a = ap.parse_args(argv)
    demos, _, _ = load_demonstrations([a.source], ReadOptions(body=a.body) if a.body else None)
    folds = min(a.folds, len(demos)) if a.train_size is None else a.folds
    t0 = time.time()
    rows = {}
    picks = []
    for train_idx, test_idx in make_splits(len(demos), folds, 0, a.order, a.train_size):
        paths = fit_paths([demos[j] for j in train_idx])
        lam = paths.duration_evidence or 1.0
        picks.append("1" if lam == 1.0 else f"1/{round(1 / lam)}")
        ants = {"lambda = 1": Anticipator(paths, None, duration_evidence=1.0), "chosen": Anticipator(paths, None)}
        for j in test_idx:
            tr = demos[j]
            for F in FRACTIONS:
                seen, _ = split_seen(tr, F)
                for name, ant in ants.items():
                    e = ant.estimate(seen.t, seen.quat, seen.position)
                    lo, hi = e.end_time_band
                    rows.setdefault((name, F), []).append((lo <= tr.t[-1] <= hi, hi - lo, abs(e.end_time - tr.t[-1])))
    study = "" if a.train_size is None else f", {a.train_size} trained per split"
    print(f"{a.source} ({len(demos)} motions, {a.order} splits{study}; {time.time() - t0:.0f} s); λ per split: {' '.join(picks)}")
    print("  " + " " * 10 + "   ".join(f"F = {F}: inside width error" for F in FRACTIONS))
    for name in ("lambda = 1", "chosen"):
        cells = []
        for F in FRACTIONS:
            x = np.asarray(rows[(name, F)], dtype=float)
            cells.append(f"{x[:, 0].mean():>12.2f} {x[:, 1].mean():5.2f} {x[:, 2].mean():6.3f}")
        print(f"  {name:<10}" + " ".join(cells))


if __name__ == "__main__":
    main()
