"""Sparse GP (SGPR, rbgp_cli.gp.sparse) against the exact GP: time, memory, accuracy, held-out quality.

Part 1 (default), synthetic: the six smooth outputs of ``_common.synthetic_data`` (random poses,
noise 0.05). In one run, each fit in a fresh Python process (so that its peak RSS is its own), one
after the other: the exact GP (``fit_gp``) on n = 2000 random points and, as peer, the sparse GP
(``fit_sparse_gp``, M = DEFAULT_INDUCING, 256) on n = 100 000 — both per-output hyperparameters, 3 starts, the chordal
kernel (ρ1 = 0.7) — plus the sizes around the crossover (``--sizes``). Reported: wall time of the fit,
peak RSS of the process (``ru_maxrss``) and above the imports and data, held-out RMSE against the
noise-free field at 3000 unseen poses (the outputs' RMS is ≈ 0.35), and the ratio of each sparse fit's
time to the exact GP's at 2000 points measured in the same run.

Part 2 (``--crossval``), real recordings: ``rbgp_cli.evaluation.crossval`` on
``../shared/realdata/handover_object_csv`` (30 handovers, 5 folds) and on ``sample_data/csv`` (9 shoe
demonstrations, 3 folds), seed 0, axis-angle with the chordal kernel and every other option the
default of ``rbgp train`` (per-output hyperparameters, phase input, mean-path prior), all pairs
(``subsample=1``) at a velocity rate of 10 Hz and at the recorded rate (sample_data: recorded rate
only, ``--sample-rates``): the exact GP on at most 2000 points (``inducing=0``) against the sparse GP
on all points (``inducing=512``; ``--every-pose`` adds M = n at the fixed rates), each without and
with the noise calibration by held-out demonstrations (``rbgp train --calibrate-noise``;
``--calibrate off|both|only``).

    .venv/bin/python benchmarks/bench_sparse.py --blas-threads 1     # part 1 (~15 min here, loaded)
    .venv/bin/python benchmarks/bench_sparse.py --quick              # n = 1000 exact vs 20 000 sparse
    .venv/bin/python benchmarks/bench_sparse.py --crossval           # part 2 (~15 min here)
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from _common import blas_line, machine_line  # noqa: E402

_CHILD = r'''
import json, resource, sys, time
sys.path.insert(0, {here!r})
import numpy as np
from _common import limit_blas_threads, synthetic_data, velocity_field
limit_blas_threads({threads!r})
from rbgp_cli.gp.exact import fit_gp
from rbgp_cli.gp.sparse import fit_sparse_gp
from rbgp_cli.kernels import SquaredExponential
kind, n, M, hyper_points = {kind!r}, {n}, {M}, {hyper_points!r}
q, X, Y = synthetic_data(n, seed=1)
qs, Xs, _ = synthetic_data(3000, seed=99)
truth = velocity_field(qs, Xs[:, 3:])
k = SquaredExponential("chordal", 3, 0.7)
base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
t0 = time.perf_counter()
if kind == "exact":
    gp = fit_gp(X, Y, k, restarts=3, seed=0)
    evals = sum(f.n_evaluations for f in gp.fits)
    stages = None
else:
    gp = fit_sparse_gp(X, Y, k, inducing=M, restarts=3, seed=0, hyper_points=hyper_points)
    evals = sum(f.n_evaluations for f in gp.fits)
    stages = [[(s["points"], s["evaluations"]) for s in f.stages] for f in gp.fits]
fit_s = time.perf_counter() - t0
rmse = np.sqrt(np.mean((gp.predict(Xs) - truth) ** 2, axis=0))
t1 = time.perf_counter()
gp.predict(Xs, return_std=True)
pred_s = time.perf_counter() - t1
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print(json.dumps({{"kind": kind, "n": n, "M": M, "hyper_points": hyper_points, "fit_s": fit_s, "rmse": rmse.tolist(), "rmse_mean": float(rmse.mean()),
                  "nlml": float(sum(f.nlml for f in gp.fits)), "evaluations_all_points": int(evals), "stages": stages,
                  "peak_rss_mb": peak / 1024, "above_start_mb": (peak - base) / 1024, "predict_3000_std_s": pred_s,
                  "load": os.getloadavg()[0] if hasattr(os, "getloadavg") else None}}))
'''.replace("import json, resource, sys, time", "import json, os, resource, sys, time")


def run_child(kind: str, n: int, M: int, threads, hyper_points=None) -> dict:
    code = _CHILD.format(here=str(HERE), threads=threads, kind=kind, n=n, M=M, hyper_points=hyper_points)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    result = json.loads(out.stdout.strip().splitlines()[-1])
    print(json.dumps(result), file=sys.stderr, flush=True)  # each run as it ends (a long run may be stopped)
    return result


def part1(args) -> str:
    runs = []
    exact_sizes = [1000] if args.quick else [int(s) for s in args.sizes.split(",")]
    sparse_sizes = [20000] if args.quick else [int(s) for s in args.sparse_sizes.split(",")]
    ref = 1000 if args.quick else 2000
    for n in exact_sizes:
        print(f"exact n={n} ...", file=sys.stderr, flush=True)
        runs.append(run_child("exact", n, 0, args.blas_threads))
    hypers = [None if h == "default" else int(h) for h in args.hyper_points.split(",")]
    for n in sparse_sizes:
        for h in hypers:
            print(f"sparse n={n} M={args.inducing} hyper_points={h or 'default'} ...", file=sys.stderr, flush=True)
            runs.append(run_child("sparse", n, args.inducing, args.blas_threads, h))
    t_ref = next(r["fit_s"] for r in runs if r["kind"] == "exact" and r["n"] == ref)
    lines = [f"Measured {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; {machine_line()}. {blas_line()}",
             "", f"| GP | n | M | hyperparameters from | fit (s) | fit / exact at n = {ref} | evaluations on all points | peak RSS (MB) | "
             "RSS above start (MB) | held-out RMSE (mean of 6) | predict mean+std at 3000 poses (s) | load |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in runs:
        hp = "–" if r["kind"] == "exact" else (r.get("hyper_points") or "default")
        lines.append(f"| {r['kind']} | {r['n']} | {r['M'] or '–'} | {hp} | {r['fit_s']:.1f} | {r['fit_s'] / t_ref:.2f} | "
                     f"{r['evaluations_all_points']} | {r['peak_rss_mb']:.0f} | {r['above_start_mb']:.0f} | "
                     f"{r['rmse_mean']:.4f} | {r['predict_3000_std_s']:.3f} | {r['load']:.1f} |")
    lines.append("")
    for r in runs:
        if r["stages"]:
            lines.append(f"- sparse n = {r['n']}: (points, evaluations) per stage and output: "
                         + "; ".join(", ".join(f"{p}:{e}" for p, e in st) for st in r["stages"]))
    if args.json:
        Path(args.json).write_text(json.dumps(runs, indent=1))
    return "\n".join(lines)


def part2(args) -> str:
    from rbgp_cli.dynamics.velocities import VelocityOptions
    from rbgp_cli.evaluation.crossval import Config, crossval
    from rbgp_cli.workflows import load_demonstrations

    sets = []
    real = HERE.parent.parent / "shared" / "realdata" / "handover_object_csv"
    if real.is_dir() and "handover" in args.sets:
        sets.append(("handovers (30)", str(real), args.rates, 5))
    if "sample" in args.sets:
        # 3 folds: with 5, some folds of the 9 demonstrations hold out one, whose score rests on the
        # ridge variance (crossval warns) and swamps the mean
        sets.append(("sample_data", str(HERE.parent / "sample_data" / "csv"), args.sample_rates, 3))
    lines = [f"Measured {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; {machine_line()}", "",
             "| data | velocities | GP | points per fold | score / floor | score | position RMSE (m) | rotation RMSE (rad) | "
             "velocity RMSE (rel.) | ω RMSE (rad/s) | v RMSE (m/s) | train (s/fold) |",
             "|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for name, path, rates, folds in sets:
        demos, _r, _i = load_demonstrations([path])
        for rate in [None if r == "recorded" else float(r) for r in rates.split(",")]:
            # every other option the default of rbgp train (per-output hyperparameters, 3 starts, ...)
            base = {"velocity": VelocityOptions(rate=rate), "subsample": 1.0, "seed": 0}
            configs = []
            for cal in {"off": [False], "both": [False, True], "only": [True]}[args.calibrate]:
                extra, tag = ({"calibrate": True}, ", calibrated") if cal else ({}, "")
                configs += [Config("axis-angle", "se-chordal", train={**base, **extra, "inducing": 0, "max_points": 2000},
                                   label=f"exact, ≤ 2000 points{tag}"),
                            Config("axis-angle", "se-chordal", train={**base, **extra, "inducing": args.inducing},
                                   label=f"sparse M = {args.inducing}, all points{tag}")]
            if rate is not None and args.every_pose:
                configs.append(Config("axis-angle", "se-chordal", train={**base, "inducing": 10**6}, label="sparse, every pose inducing"))
            t0 = time.perf_counter()
            res = crossval(demos, configs, folds=folds, seed=0, jobs=args.jobs)
            print(f"{name} rate={rate}: {time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
            for row in sorted(res["results"], key=lambda r: r["label"]):
                pts = sorted({f.get("points", 0) for f in row["per_fold"]})
                lines.append(f"| {name} | {'%g Hz' % rate if rate else 'recorded'} | {row['label']} | {pts[0]}–{pts[-1]} | "
                             f"{row['ratio']:.3f} | {row['score']:.3f} | {row['position_rmse']:.4f} | {row['rotation_rmse']:.4f} | "
                             f"{row['velocity_rmse']:.4f} | {row['velocity_rmse_angular']:.4f} | {row['velocity_rmse_linear']:.4f} | "
                             f"{row['train_s']:.1f} |")
    return "\n".join(lines)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--crossval", action="store_true", help="part 2: held-out quality on real recordings")
    ap.add_argument("--sizes", default="1000,2000", help="exact GP sizes")
    ap.add_argument("--sparse-sizes", default="10000,100000", help="sparse GP sizes")
    ap.add_argument("--inducing", type=int, default=None, help="M (default: the library's DEFAULT_INDUCING)")
    ap.add_argument("--hyper-points", default="default",
                    help="part 1: the sparse fits' hyper_points, comma-separated ('default': the library's)")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--sets", default="handover,sample", help="part 2: handover and/or sample")
    ap.add_argument("--rates", default="10,recorded", help="part 2: velocity rates for the handover set")
    ap.add_argument("--sample-rates", default="recorded", help="part 2: velocity rates for sample_data")
    ap.add_argument("--every-pose", action="store_true", help="part 2: also a sparse GP with every pose inducing (at fixed rates)")
    ap.add_argument("--calibrate", choices=["off", "both", "only"], default="both",
                    help="part 2: without and/or with the noise calibration by held-out demonstrations (rbgp train --calibrate-noise)")
    ap.add_argument("--blas-threads", type=int, default=None)
    ap.add_argument("--json")
    ap.add_argument("--markdown")
    args = ap.parse_args()
    if args.inducing is None:
        from rbgp_cli.gp.sparse import DEFAULT_INDUCING

        args.inducing = DEFAULT_INDUCING
    text = part2(args) if args.crossval else part1(args)
    print(text)
    if args.markdown:
        Path(args.markdown).write_text(text + "\n")


if __name__ == "__main__":
    os.environ.setdefault("PYTHONHASHSEED", "0")
    main()
