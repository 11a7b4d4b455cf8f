"""Issue 37, seventh pass: the bands of a motion under way with one pooled factor against factors per seen
fraction, and the path distribution's cells against the peers, on crossval's folds without the GP's training.

Usage: python scripts/under_way_bands.py SET_DIR OUT.json [--folds 5] [--body NAME] [--samples 20] [--no-peers]
[--spread on|off]  (``--spread``: the factors scored against the samples' durations, issue 37's eighth pass; default
as rbgp's DURATION_SPREAD)

For each fold of ``rbgp crossval --given F`` (:func:`~rbgp_cli.evaluation.crossval.make_folds`, seed 0; the
samples seeded as crossval seeds them) it fits the path distribution on the training demonstrations
(:func:`~rbgp_cli.dynamics.paths.fit_paths`, as ``rbgp train`` does), sees each held-out demonstration's first
F = 0.2, 0.4, 0.6, 0.8 and scores, per motion:

- ``no-GP``: the conditioned path (crossval's ``no-GP`` row: with the residual's gain at 0, chosen on every
  real set, ``rbgp``'s row equals it to a millimetre), its K samples drawn with the bands' factors per seen
  fraction (``paths.seen_band_scales``, what this rbgp does);
- ``no-GP-pooled``: the same mean, its samples drawn with the one pooled factor pair ≥ 1 of before (what a
  model file without the per-fraction factors does);
- with peers: ``nearest``, ``promp``, ``promp-ridge`` as :func:`~rbgp_cli.evaluation.under_way.under_way_fold`
  computes them.

It writes ``rbgp --json crossval --given F``'s layout ({"rows": [...]}, each row with ``per_motion`` and
``paired`` against ``no-GP``), so ``scripts/under_way_table.py --crossval NAME=OUT.json`` gives the table and
the Done-when verdicts. Nothing here changes rbgp; it measures.
"""

from __future__ import annotations

import argparse
import copy
import json
import sys
import time

import numpy as np


def main(argv=None):
    from rbgp_cli.dynamics.paths import fit_paths
    from rbgp_cli.evaluation.crossval import make_folds
    from rbgp_cli.evaluation.under_way import FRACTIONS, _add, add_paired, under_way_fold
    from rbgp_cli.io.options import ReadOptions
    from rbgp_cli.workflows import load_demonstrations

    ap = argparse.ArgumentParser()
    ap.add_argument("source")
    ap.add_argument("out")
    ap.add_argument("--folds", type=int, default=5)
    ap.add_argument("--body", default=None)
    ap.add_argument("--samples", type=int, default=20)
    ap.add_argument("--no-peers", action="store_true")
    ap.add_argument("--spread", choices=("on", "off"), default=None)
    a = ap.parse_args(argv)
    if a.spread is not None:
        from rbgp_cli.dynamics import anticipation

        anticipation.DURATION_SPREAD = a.spread == "on"
    options = ReadOptions(body=a.body) if a.body else None
    demos, _, _ = load_demonstrations([a.source], options)
    folds = make_folds(len(demos), min(a.folds, len(demos)), 0)
    methods = ("no-GP",) + (() if a.no_peers else ("nearest", "promp", "promp-ridge"))
    tot, factors = {}, []
    t_start = time.time()
    for i, fold in enumerate(folds):
        held = set(int(j) for j in fold)
        train = [d for j, d in enumerate(demos) if j not in held]
        test = [demos[j] for j in fold]
        t0 = time.process_time()
        paths = fit_paths(train)
        fit_cpu = time.process_time() - t0
        pooled = copy.copy(paths)
        pooled.seen_band_scales = None  # a model file from before: the pooled pair at every phase
        out = under_way_fold(None, paths, train, test, FRACTIONS, samples=a.samples, seed=i, methods=methods,
                             indices=list(fold))
        old = under_way_fold(None, pooled, train, test, FRACTIONS, samples=a.samples, seed=i, methods=("no-GP",),
                             indices=list(fold))
        for k, v in out.items():
            _add(tot, k, v)
        for (m, F), v in old.items():
            _add(tot, ("no-GP-pooled", F), v)
        factors.append({"fold": i, "pooled": list(paths.seen_band_scale), "per_F": paths.seen_band_scales,
                        "fit_paths_cpu_s": fit_cpu})
        print(f"fold {i} done {time.time() - t_start:.0f} s: {factors[-1]}", file=sys.stderr, flush=True)
    names = [d.name for d in demos]
    order = ("no-GP", "no-GP-pooled", "nearest", "promp", "promp-ridge")
    rows = [dict(method=m, given=F, **tot[(m, F)].to_dict(), per_motion=tot[(m, F)].per_motion(names))
            for F in FRACTIONS for m in order if (m, F) in tot]
    add_paired(rows, reference="no-GP")
    for r in rows:  # JSON has no NaN
        for k, v in list(r.items()):
            if isinstance(v, float) and not np.isfinite(v):
                r[k] = None
    with open(a.out, "w") as fh:
        json.dump({"rows": rows, "folds": len(folds), "samples": a.samples, "paired_reference": "no-GP",
                   "source": a.source, "body": a.body, "factors": factors,
                   "wall_s": time.time() - t_start}, fh)


if __name__ == "__main__":
    main()
