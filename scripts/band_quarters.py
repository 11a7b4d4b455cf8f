"""Issue 37, ninth pass, later: the continuation bands' coverage per quarter of the remainder, on real sets.

Usage: python scripts/band_quarters.py SET_DIR [--body NAME] [--folds 5] [--train-size N] [--samples 20] [--json OUT.json]
(``--train-size N``: crossval's study of N, --folds random subsets of N trained on, the others held out)

For each fold of ``rbgp crossval SET_DIR --given 0.2 --given 0.4 --given 0.6 --given 0.8`` (its splits,
:func:`~rbgp_cli.evaluation.crossval.make_splits`, seed 0; its training, the command's default options through
:func:`~rbgp_cli.cli.train_options.train_kwargs` and :func:`~rbgp_cli.dynamics.model.train_model`; the samples
seeded as :func:`~rbgp_cli.evaluation.under_way.under_way_fold` seeds them) it draws rbgp's K sampled continuations of
every held-out motion seen to F and scores the real remainder with crossval's per-step test
(:func:`~rbgp_cli.evaluation.coverage.prediction_coverage` on the remainder resampled to 100 steps of its
normalised time), once per quarter of those steps (25 each: the 100 resampled steps cut into four, each quarter
scored by the same function on its own 25 steps, so the quarters sum to the whole). Pooled over motions, per F:
coverage of position (steps × axes) and rotation (steps) per quarter and in total; the total is checked against
crossval's own computation of the same fold (``under_way_fold``, rbgp's row) and the script stops if they differ.

Per fold it also prints the path distribution's chosen τ² (``smooth``, grid paths.SMOOTH_GRID), seen tolerance r
(``seen_tolerance``, anticipation.SEEN_TOLERANCE_GRID) and the rest's (``rest_smooth``, REST_SMOOTH_GRID and τ²;
``rest_tolerance``), each marked ``lo`` / ``hi`` when at the bottom / top of its grid. Nothing here changes rbgp.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

QUARTERS = 4
T = 100  # crossval's steps of the remainder (evaluation.under_way._T)


def quarter_coverages(samples, rest):
    """[Coverage of quarter 1, ..., 4] of ``rest`` by ``samples``: crossval's test on each quarter's steps."""
    from rbgp_cli.dynamics.trajectory import Trajectory
    from rbgp_cli.evaluation.coverage import prediction_coverage
    from rbgp_cli.evaluation.resample import resample_all

    qs, ps = resample_all(samples, T)
    qr, pr = resample_all([rest], T)
    s = np.linspace(0.0, 1.0, T)
    n = T // QUARTERS
    out = []
    for k in range(QUARTERS):
        sl = slice(k * n, (k + 1) * n)
        smp = [Trajectory(s[sl], qs[j, sl], ps[j, sl]) for j in range(len(samples))]
        out.append(prediction_coverage(smp, Trajectory(s[sl], qr[0, sl], pr[0, sl]), n))
    return out


def edge(value, grid):
    g = sorted(float(x) for x in grid)
    return "lo" if np.isclose(value, g[0]) else ("hi" if np.isclose(value, g[-1]) else "")


def main(argv=None):
    from rbgp_cli.cli.app import _D
    from rbgp_cli.cli.train_options import train_kwargs
    from rbgp_cli.dynamics.anticipation import REST_SMOOTH_GRID, SEEN_TOLERANCE_GRID, Anticipator
    from rbgp_cli.dynamics.defaults import DEFAULTS
    from rbgp_cli.dynamics.model import train_model
    from rbgp_cli.dynamics.paths import SMOOTH_GRID, fit_paths
    from rbgp_cli.evaluation.coverage import coverage_se
    from rbgp_cli.evaluation.crossval import make_splits
    from rbgp_cli.evaluation.under_way import FRACTIONS, split_seen, under_way_fold
    from rbgp_cli.io.options import ReadOptions
    from rbgp_cli.workflows import load_demonstrations

    ap = argparse.ArgumentParser()
    ap.add_argument("source")
    ap.add_argument("--body", default=None)
    ap.add_argument("--folds", type=int, default=5)
    ap.add_argument("--train-size", type=int, default=None)
    ap.add_argument("--samples", type=int, default=20)
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    seed = 0
    kwargs = train_kwargs(rho_rot=_D["rho_rot"], restarts=_D["restarts"], explore_size=_D["explore_size"], seed=seed,
                          noise="learn", share_hyperparameters=False, subsample=_D["subsample"],
                          max_points=_D["max_points"], train_rate=_D["train_rate"], smooth_window=_D["smooth_window"],
                          smooth_degree=_D["smooth_degree"], time_input=_D["time_input"], prior=_D["prior"],
                          prior_gain=_D["prior_gain"], inducing=None, hyper_points=None,
                          calibrate_noise=_D["calibrate"], start_conditioning=_D["start_conditioning"],
                          noise_scale=_D["noise_scale"], pull_profile=_D["pull_profile"],
                          residual_gain=_D["residual_gain"])
    options = ReadOptions(body=a.body) if a.body else None
    demos, _, _ = load_demonstrations([a.source], options)
    folds = min(a.folds, len(demos)) if a.train_size is None else a.folds
    splits = make_splits(len(demos), folds, seed, "random", a.train_size)
    # sums (pos in, pos n, rot in, rot n) per (F, quarter); crossval's own pooled Coverage per F
    acc = {(F, k): np.zeros(4) for F in FRACTIONS for k in range(QUARTERS)}
    per = {(F, k): [] for F in FRACTIONS for k in range(QUARTERS)}  # per held-out motion: (index, counts)
    ref = {}
    chosen = []
    t0 = time.time()
    for i, (train_idx, fold) in enumerate(splits):
        train = [demos[j] for j in train_idx]
        test = [demos[j] for j in fold]
        model = train_model(train, representation=DEFAULTS["representation"], kernel=DEFAULTS["kernel"], **kwargs)
        paths = getattr(model, "paths", None) or fit_paths(train)
        tau2, r = float(paths.smooth), float(paths.seen_tolerance)
        rs = float(paths.smooth if paths.rest_smooth is None else paths.rest_smooth)
        rr = float(paths.seen_tolerance if paths.rest_tolerance is None else paths.rest_tolerance)
        row = {"fold": i, "train": len(train), "smooth": tau2, "seen_tolerance": r, "rest_smooth": rs,
               "rest_tolerance": rr, "edges": {"smooth": edge(tau2, SMOOTH_GRID), "seen_tolerance": edge(r, SEEN_TOLERANCE_GRID),
                                               "rest_smooth": edge(rs, tuple(REST_SMOOTH_GRID) + (tau2,)),
                                               "rest_tolerance": edge(rr, SEEN_TOLERANCE_GRID)}}
        chosen.append(row)
        print(f"fold {i}: {len(train)} trained; tau2 {tau2:g} {row['edges']['smooth']}, r {r:g} {row['edges']['seen_tolerance']}, "
              f"rest tau2 {rs:g} {row['edges']['rest_smooth']}, rest r {rr:g} {row['edges']['rest_tolerance']}"
              f"  [{time.time() - t0:.0f} s]", file=sys.stderr, flush=True)
        ant = Anticipator(paths, model)
        for m, tr in enumerate(test):  # the draws as under_way_fold makes them (seed + m per held-out motion)
            for F in FRACTIONS:
                seen, rest = split_seen(tr, F)
                c = ant.continuation(seen.t, seen.quat, seen.position, samples=a.samples, seed=seed + i + m)
                trs = c.trajectories(include_samples=True)
                for k, cov in enumerate(quarter_coverages(trs[1:], rest)):
                    acc[(F, k)] += np.asarray(cov.astuple()[:4], dtype=float)
                    per[(F, k)].append((int(fold[m]), cov.astuple()[:4]))
        own = under_way_fold(model, paths, train, test, FRACTIONS, samples=a.samples, seed=seed + i,
                             methods=("rbgp",), indices=fold)
        for F in FRACTIONS:
            cov = own[("rbgp", F)].coverage
            ref[F] = cov if F not in ref else ref[F] + cov
    rows = []
    for F in FRACTIONS:
        q = [acc[(F, k)] for k in range(QUARTERS)]
        tot = sum(q)
        own = ref[F].astuple()[:4]
        if not np.allclose(tot, own):
            raise SystemExit(f"F = {F}: the quarters sum to {tot.tolist()}, crossval's own to {list(own)}")
        se = []  # over the held-out motions (evaluation.coverage.coverage_se; a motion held out twice counts once)
        for k in range(QUARTERS):
            g = [j for j, _ in per[(F, k)]]
            c = np.asarray([x for _, x in per[(F, k)]], dtype=float)
            se.append([float("nan") if v is None else float(v) for v in (coverage_se(c[:, 0], c[:, 1], g), coverage_se(c[:, 2], c[:, 3], g))])
        rows.append({"given": F, "pos": [float(x[0] / x[1]) for x in q], "rot": [float(x[2] / x[3]) for x in q],
                     "pos_se": [x[0] for x in se], "rot_se": [x[1] for x in se],
                     "pos_total": float(tot[0] / tot[1]), "rot_total": float(tot[2] / tot[3]),
                     "crossval_pos": ref[F].to_dict()["coverage_position"],
                     "crossval_rot": ref[F].to_dict()["coverage_rotation"], "scored": int(tot[3] // T)})
    study = "" if a.train_size is None else f", {a.train_size} trained per split"
    print(f"{a.source} ({len(demos)} motions, {len(splits)} folds{study}, {a.samples} samples): coverage position / rotation")
    print("   F   Q1 (near)     Q2            Q3            Q4 (end)      total         crossval")
    for r in rows:
        cells = "  ".join(f"{p:.2f} / {o:.2f}" for p, o in zip(r["pos"], r["rot"]))
        print(f"  {r['given']:.1f}  {cells}  {r['pos_total']:.3f} / {r['rot_total']:.3f}  "
              f"{r['crossval_pos']:.3f} / {r['crossval_rot']:.3f}")
        print("  ± " + "  ".join(f"{p:.2f} / {o:.2f}" for p, o in zip(r["pos_se"], r["rot_se"])) + "  (standard errors)")
    if a.json:
        with open(a.json, "w") as fh:
            json.dump({"source": a.source, "body": a.body, "folds": len(splits), "train_size": a.train_size,
                       "samples": a.samples, "rows": rows,
                       "chosen": chosen}, fh, indent=1)


if __name__ == "__main__":
    main()
