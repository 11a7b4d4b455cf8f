"""Training and prediction benchmark: rbgp's exact GP against scikit-learn, on the same synthetic data.

    .venv/bin/python benchmarks/bench_training.py --blas-threads 1   # n = 80, 500, 1752 (~10 min)
    .venv/bin/python benchmarks/bench_training.py --quick            # n = 80, 300, one repeat: ~1 min
    .venv/bin/python benchmarks/bench_training.py --sizes 80,500 --no-sklearn

Data (benchmarks/_common.py): rotations uniform on SO(3) as canonical rotation vectors,
translations ~ N(0, 0.3²) m, six smooth outputs of the pose plus N(0, 0.05²) noise.

Measured at every n, in one run:

* ours, per output: ``fit_gp(X, Y, SquaredExponential("arc", 3, 0.7), restarts=3, seed=0)`` in this
  process (``jobs=1``, one core) — wall time, total NLML evaluations on all points (Σ
  OutputFit.n_evaluations; the issue's target is at most 12 per output on average), on the
  exploration subsample (above 800 points the starts explore 400 points first, then the best optimum
  is polished on all points), infeasible ones (Σ n_infeasible), and Σ NLML of the optima found;
* the same fit in worker processes (``jobs=default_jobs(6, n)``: one per output; BLAS
  single-threaded in each; the same optima bit for bit);
* where n > 800, the same with ``explore_size=0`` (L-BFGS-B from every start on all points, the
  method before the exploration): the reference for "the same optima" (Σ NLML within 0.1 %);
* ours, shared hyperparameters (``shared=True``), same numbers;
* the time of ONE ``nlml_and_gradient`` evaluation at the fitted (typical, feasible) hyperparameters,
  median of several, and the overhead ratio fit_time / (evaluations × t_eval) (target ≤ 1.3). The
  evaluations inside the fit are also timed one by one (by wrapping the library function; nothing
  else changes), which gives fit_time / Σ(in-fit evaluation times): the same question asked in a
  way that the machine's load cannot skew (both sides are measured at the same moments). Only for
  fits in this process (jobs = 1);
* scikit-learn: ``GaussianProcessRegressor(ConstantKernel()*RBF() + WhiteKernel(),
  n_restarts_optimizer=2, random_state=0)``, six separate models on (Euler xyz angles, translation);
  wall time and number of log-marginal-likelihood evaluations; with ``--sklearn-threads 2`` also
  with its BLAS on 2 threads (the peer of our worker processes on both cores);
* the same fits of ours with the chordal rotation distance (docs/method.md §6, §10);
* test RMSE of every model against the noise-free outputs at 2000 unseen poses (so a faster fit is
  not bought with a worse model);
* prediction of mean and std at 10001 unseen poses from the n = 80 models: ours
  (``GaussianProcess.predict(..., return_std=True)``) vs scikit-learn's ``predict(return_std=True)``
  summed over its 6 models.

Targets at n = 1752 (issue 11): per-output fit ≥ 15× faster than scikit-learn's 6 fits on the same
cores, with at most 12 evaluations on all points per output on average and the same optima (Σ NLML
within 0.1 % of L-BFGS-B from every start on all points, same held-out RMSE); shared ≥ 50×;
overhead ratio ≤ 1.3; prediction at n = 80 no slower than scikit-learn's.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import statistics
import sys
import time
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np  # noqa: E402

from _common import blas_line, fmt_s, limit_blas_threads, machine_line, synthetic_data, synthetic_poses, velocity_field  # noqa: E402

import rbgp_cli.compute as compute  # noqa: E402
import rbgp_cli.gp.exact as exact  # noqa: E402
import rbgp_cli.gp.likelihood as likelihood  # noqa: E402
import rbgp_cli.gp.optimise as optimise  # noqa: E402
from rbgp_cli.geometry.so3 import euler_from_quat  # noqa: E402
from rbgp_cli.kernels import SquaredExponential  # noqa: E402

TEST_POINTS = 2000
PRED_POINTS = 10001


# ------------------------------------------------------------------------------ timing of evaluations
class EvalTimer:
    """Wraps ``optimise.nlml_and_gradient`` (looked up as a module global of :mod:`rbgp_cli.gp.optimise` by
    the fit's objective, :class:`rbgp_cli.gp.optimise.Objective`) to time each call.

    Adds one ``perf_counter`` pair per call (~1 µs); records (seconds, feasible) per evaluation.
    """

    def __init__(self):
        self.records: list[tuple[float, bool]] = []
        self._orig = optimise.nlml_and_gradient

    def __enter__(self):
        orig = self._orig

        def timed(*a, **kw):
            t0 = time.perf_counter()
            out = orig(*a, **kw)
            self.records.append((time.perf_counter() - t0, out[0] < likelihood.INFEASIBLE_NLML))
            return out

        optimise.nlml_and_gradient = timed
        return self

    def __exit__(self, *exc):
        optimise.nlml_and_gradient = self._orig

    @property
    def total(self) -> float:
        return sum(t for t, _ in self.records)

    @property
    def infeasible_time(self) -> float:
        return sum(t for t, ok in self.records if not ok)


def time_one_evaluation(kernel, X, gp, repeats: int) -> float:
    """Median time of one nlml_and_gradient at the fitted hyperparameters (cycling over the outputs)."""
    pre = kernel.precompute(X)
    if gp.shared:
        jobs = [(gp.fits[0], gp.Y / gp.y_scale)]
    else:
        jobs = [(f, gp.Y[:, l]) for l, f in enumerate(gp.fits)]
    calls = [(f.values, y, list(f.free)) for f, y in jobs]
    # the same BLAS thread policy as fit_gp (single-threaded BLAS in every fit since issue 11)
    policy = getattr(compute, "blas_threads", None)
    with policy(0) if policy is not None else contextlib.nullcontext():
        likelihood.nlml_and_gradient(kernel, pre, calls[0][0], calls[0][1], calls[0][2])  # warm-up
        times = []
        for r in range(repeats):
            values, y, free = calls[r % len(calls)]
            t0 = time.perf_counter()
            f, _ = likelihood.nlml_and_gradient(kernel, pre, values, y, free)
            times.append(time.perf_counter() - t0)
            if f >= likelihood.INFEASIBLE_NLML:
                raise RuntimeError("the fitted hyperparameters are infeasible: cannot time a typical evaluation")
    return statistics.median(times)


def cpu_seconds() -> float:
    """CPU time of this process (all its threads) and of its finished child processes (the fit's
    workers, reaped when its pool shuts down): on a busy machine a steadier measure than wall time."""
    import resource

    ch = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + ch.ru_utime + ch.ru_stime


def rmse(pred: np.ndarray, truth: np.ndarray) -> float:
    """Root mean squared error over all outputs (each output has std ≈ 0.3)."""
    return float(np.sqrt(np.mean((pred - truth) ** 2)))


# ------------------------------------------------------------------------------ ours
def bench_ours(X, Y, metric: str, shared: bool, eval_repeats: int, Xt, Yt_true, explore_size=None, jobs=1) -> dict:
    """One fit of ours. ``explore_size=None`` is the library's default (starts explore a subsample
    first above 800 points); 0 runs every start on all points. ``jobs`` > 1: outputs in worker
    processes (the in-fit evaluation times are then not seen here)."""
    kernel = SquaredExponential(metric, 3, 0.7)
    kw = {} if explore_size is None else {"explore_size": explore_size}
    if jobs > 1:
        kw["jobs"] = jobs
    with EvalTimer() as et:
        c0 = cpu_seconds()
        t0 = time.perf_counter()
        gp = exact.fit_gp(X, Y, kernel, restarts=3, seed=0, shared=shared, **kw)
        fit_time = time.perf_counter() - t0
        cpu = cpu_seconds() - c0
    evals = sum(f.n_evaluations for f in gp.fits)
    t_eval = time_one_evaluation(kernel, X, gp, eval_repeats)
    label = f"ours {'shared' if shared else 'per-output'} ({metric})"
    if explore_size == 0:
        label += ", every start on all points"
    if jobs > 1:
        label += f", {jobs} worker processes"
    in_fit = et.total if et.records else float("nan")
    return {
        "kind": label,
        "subsample_evaluations": sum((getattr(f, "subsample", None) or {}).get("evaluations", 0) for f in gp.fits),
        "nlml_sum": float(sum(f.nlml for f in gp.fits)),
        "metric": metric,
        "shared": shared,
        "fit_s": fit_time,
        "evaluations": evals,
        "infeasible": sum(f.n_infeasible for f in gp.fits),
        "infeasible_s": et.infeasible_time,
        "jobs": jobs,
        "cpu_s": cpu,
        "in_fit_eval_s": in_fit,
        "t_eval_s": t_eval,
        "ratio": fit_time / (evals * t_eval) if jobs == 1 else float("nan"),
        "ratio_in_fit": fit_time / in_fit,
        "evaluations_per_output": evals / len(gp.fits) if not shared else float(evals),
        "jitter_used": any(f.jitter > 0 for f in gp.fits),
        # outputs whose first optimum missed the library's noise margin and were refit with it (if the
        # library has that safeguard; docs/method.md §6)
        "guarded": sum(bool(getattr(f, "guarded", False)) for f in gp.fits),
        "rmse": rmse(gp.predict(Xt), Yt_true),
        "load": os.getloadavg()[0],
        "_gp": gp,
    }


# ------------------------------------------------------------------------------ scikit-learn
def sklearn_regressor_class():
    from sklearn.gaussian_process import GaussianProcessRegressor

    class CountingGPR(GaussianProcessRegressor):
        """GaussianProcessRegressor that counts its log-marginal-likelihood evaluations."""

        n_lml_calls = 0

        def log_marginal_likelihood(self, *a, **kw):
            type(self).n_lml_calls += 1
            return super().log_marginal_likelihood(*a, **kw)

    return CountingGPR


def euler_inputs(quat: np.ndarray, X: np.ndarray) -> np.ndarray:
    return np.concatenate([euler_from_quat(quat, "xyz"), X[:, 3:]], axis=1)


def bench_sklearn(q, X, Y, Eq_test, Yt_true, threads=None) -> dict:
    """scikit-learn's six fits; ``threads``: its BLAS/OpenMP pools limited to that many threads for
    the fit (None: as the run set them)."""
    from sklearn.exceptions import ConvergenceWarning
    from sklearn.gaussian_process.kernels import RBF, ConstantKernel, WhiteKernel
    from threadpoolctl import threadpool_limits

    cls = sklearn_regressor_class()
    cls.n_lml_calls = 0
    E = euler_inputs(q, X)
    models = []
    limit = threadpool_limits(limits=threads) if threads else contextlib.nullcontext()
    with limit, warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ConvergenceWarning)
        c0 = cpu_seconds()
        t0 = time.perf_counter()
        for l in range(Y.shape[1]):
            m = cls(ConstantKernel() * RBF() + WhiteKernel(), n_restarts_optimizer=2, random_state=0)
            m.fit(E, Y[:, l])
            models.append(m)
        fit_time = time.perf_counter() - t0
        cpu = cpu_seconds() - c0
    pred = np.stack([m.predict(Eq_test) for m in models], axis=1)
    return {
        "kind": "scikit-learn, 6 fits (Euler)" + (f", BLAS on {threads} thread{'s' * (threads > 1)}" if threads else ""),
        "threads": threads,
        "fit_s": fit_time,
        "cpu_s": cpu,
        "evaluations": cls.n_lml_calls,
        "t_eval_s": fit_time / max(cls.n_lml_calls, 1),
        "convergence_warnings": sum(issubclass(w.category, ConvergenceWarning) for w in caught),
        "rmse": rmse(pred, Yt_true),
        "load": os.getloadavg()[0],
        "_models": models,
    }


# ------------------------------------------------------------------------------ prediction
def bench_prediction(gp_ours, gp_shared, sk_models, repeats: int) -> dict:
    """Mean and std at PRED_POINTS unseen poses. The contenders are timed in turn within each repeat,
    so that a change of the machine's load hits all of them; medians and the median paired ratio."""
    qp, Xp = synthetic_poses(PRED_POINTS, seed=7)
    Ep = euler_inputs(qp, Xp)
    jobs = {"ours_s": lambda: gp_ours.predict(Xp, return_std=True)}
    if gp_shared is not None:
        jobs["ours_shared_s"] = lambda: gp_shared.predict(Xp, return_std=True)
    if sk_models:
        jobs["sklearn_s"] = lambda: [m.predict(Ep, return_std=True) for m in sk_models]
    for fn in jobs.values():  # warm-up
        fn()
    times = {k: [] for k in jobs}
    for _ in range(repeats):
        for k, fn in jobs.items():
            t0 = time.perf_counter()
            fn()
            times[k].append(time.perf_counter() - t0)
    out = {"points": PRED_POINTS}
    out.update({k: statistics.median(v) for k, v in times.items()})
    if sk_models:
        out["paired_ratio"] = statistics.median(s / o for s, o in zip(times["sklearn_s"], times["ours_s"]))
    out["load"] = os.getloadavg()[0]
    return out


# ------------------------------------------------------------------------------ report
def ratio(a, b) -> str:
    return "–" if a is None or b is None else f"{a / b:.1f}×"

#: rows of the evaluation table, in order: key, and the training-time table's column title
RUNS = [
    ("po_arc", "ours per-output (arc)"),
    ("po_arc_w", "ours per-output (arc), in worker processes"),
    ("sh_arc", "ours shared (arc)"),
    ("po_chordal", "ours per-output (chordal)"),
    ("po_chordal_w", "ours per-output (chordal), in worker processes"),
    ("sh_chordal", "ours shared (chordal)"),
    ("po_arc_all", "ours per-output (arc), every start on all points"),
]


def print_report(results: dict, pred: dict | None, header: str) -> list[str]:
    lines = [header, ""]
    sizes = sorted(results)
    g = lambda d: fmt_s(d["fit_s"]) if d else "–"  # noqa: E731
    # Table 1: training times
    lines += ["**Training time (s)** — wall clock, one run; ratios = how many times faster than scikit-learn "
              "(1 core: its BLAS on 1 thread vs our fit in one process; 2 cores: its BLAS on 2 threads vs our fit "
              "in worker processes, single-threaded BLAS each; CPU time: the same 1-core ratio in CPU seconds, "
              "which a busy machine disturbs much less than wall time)", "",
              "| n | sklearn, 1 thread | sklearn, 2 threads | " + " | ".join(t for _, t in RUNS)
              + " | per-output, 1 core | per-output, 2 cores | shared, 1 core | per-output, 1 core, CPU time |",
              "|---:|" + "---:|" * (len(RUNS) + 6)]
    for n in sizes:
        r = results[n]
        sk1, sk2 = r.get("sklearn"), r.get("sklearn_2")
        po, po2, sh = r.get("po_arc"), r.get("po_arc_w"), r.get("sh_arc")
        lines.append(f"| {n} | {g(sk1)} | {g(sk2)} | " + " | ".join(g(r.get(k)) for k, _ in RUNS)
                     + f" | {ratio(sk1 and sk1['fit_s'], po and po['fit_s'])} | {ratio(sk2 and sk2['fit_s'], po2 and po2['fit_s'])} "
                     f"| {ratio(sk1 and sk1['fit_s'], sh and sh['fit_s'])} | {ratio(sk1 and sk1['cpu_s'], po and po['cpu_s'])} |")
    # Table 2: evaluations and overhead
    lines += ["", "**Evaluations and overhead** — evaluations on all points (per output on average) and on the "
              "exploration subsample; t_eval: one NLML+gradient at the fitted hyperparameters, median; "
              "ratio = fit / (evaluations × t_eval) (target ≤ 1.3); in-fit = fit / Σ(times of the fit's own "
              "evaluations), insensitive to load changes between the fit and the t_eval measurement (both only "
              "for fits in this process); load = 1-min load average after the fit", "",
              "| n | model | evaluations, all points (per output) | on the subsample | infeasible (time); refits "
              "| t_eval (ms) | fit / (evals × t_eval) | fit / Σ in-fit evals | Σ NLML | test RMSE | load |",
              "|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    f2 = lambda x, fmt: "–" if x != x else format(x, fmt)  # noqa: E731
    for n in sizes:
        for key in [k for k, _ in RUNS] + ["sklearn", "sklearn_2"]:
            d = results[n].get(key)
            if not d:
                continue
            if key.startswith("sklearn"):
                lines.append(f"| {n} | {d['kind']} | {d['evaluations']} | – | – | {d['t_eval_s'] * 1e3:.1f} (fit / evals) "
                             f"| – | – | – | {d['rmse']:.4f} | {d['load']:.1f} |")
            else:
                per = "" if d["shared"] else f" ({d['evaluations_per_output']:.1f})"
                lines.append(f"| {n} | {d['kind']} | {d['evaluations']}{per} | {d['subsample_evaluations']} "
                             f"| {d['infeasible']} ({fmt_s(d['infeasible_s']) if d['jobs'] == 1 else '–'} s); {d['guarded']} "
                             f"| {d['t_eval_s'] * 1e3:.1f} | {f2(d['ratio'], '.2f')} | {f2(d['ratio_in_fit'], '.3f')} "
                             f"| {d['nlml_sum']:.2f} | {d['rmse']:.4f} | {d['load']:.1f} |")
    if pred:
        lines += ["", f"**Prediction of mean and std at {pred['points']} poses, models from n = {pred['n']}** (each timed "
                  f"{pred['repeats']} times, in turn)", "",
                  "| ours per-output (s) | ours shared (s) | sklearn, 6 models (s) | sklearn / ours per-output "
                  "(median of paired ratios) | load |",
                  "|---:|---:|---:|---:|---:|"]
        pr = f"{pred['paired_ratio']:.2f}×" if "paired_ratio" in pred else "–"
        lines.append(f"| {fmt_s(pred['ours_s'])} | {fmt_s(pred.get('ours_shared_s', float('nan')))} "
                     f"| {fmt_s(pred.get('sklearn_s', float('nan')))} | {pr} | {pred['load']:.1f} |")
    mine = [(k, d) for n in sizes for k, d in results[n].items() if d and not k.startswith("sklearn")]
    inf_arc = sum(d["infeasible"] for k, d in mine if "arc" in k)
    inf_ch = sum(d["infeasible"] for k, d in mine if "chordal" in k)
    lines += ["", f"Infeasible (non-PD) evaluations met by ours: {inf_arc} with the arc kernel, {inf_ch} with the chordal kernel."]
    return lines


def check_targets(results: dict, pred: dict | None, n_target: int = 1752) -> list[str]:
    out = ["", "**Targets**", ""]
    r = results.get(n_target)
    met = lambda ok: "met" if ok else "NOT met"  # noqa: E731
    if r is None:
        out.append(f"- (n = {n_target} not run: training targets not checked)")
    else:
        po, po2, sh, sk, sk2 = r.get("po_arc"), r.get("po_arc_w"), r.get("sh_arc"), r.get("sklearn"), r.get("sklearn_2")
        if sk:
            a = sk["fit_s"] / po["fit_s"]
            ac = sk["cpu_s"] / po["cpu_s"]
            out.append(f"- per-output ≥ 15× faster than sklearn at n = {n_target}, one core each: {a:.1f}× wall, "
                       f"{ac:.1f}× CPU time — {met(a >= 15)}")
            if po2 and sk2:
                a2 = sk2["fit_s"] / po2["fit_s"]
                out.append(f"- per-output ≥ 15× faster, both cores each ({po2['jobs']} worker processes vs BLAS on 2 "
                           f"threads): {a2:.1f}× — {met(a2 >= 15)}")
            elif po2:
                a2 = sk["fit_s"] / po2["fit_s"]
                out.append(f"- per-output in {po2['jobs']} worker processes vs sklearn on one core: {a2:.1f}× (not the same cores)")
            b = sk["fit_s"] / sh["fit_s"]
            bc = sk["cpu_s"] / sh["cpu_s"]
            out.append(f"- shared ≥ 50× faster than sklearn at n = {n_target}, one core each: {b:.1f}× wall, {bc:.1f}× CPU "
                       f"time — {met(b >= 50)}")
        for key in ("po_arc", "po_chordal"):
            d = r.get(key)
            if d:
                e = d["evaluations_per_output"]
                out.append(f"- at most 12 evaluations on all points per output ({d['kind']}): {e:.1f} — {met(e <= 12)}")
        ref = r.get("po_arc_all")
        if ref:
            rel = abs(po["nlml_sum"] - ref["nlml_sum"]) / abs(ref["nlml_sum"])
            out.append(f"- same optima as every start on all points (Σ NLML within 0.1 %): {po['nlml_sum']:.3f} vs "
                       f"{ref['nlml_sum']:.3f} ({rel:.1e} relative) — {met(rel <= 1e-3)}; held-out RMSE "
                       f"{po['rmse']:.4f} vs {ref['rmse']:.4f}")
        if po2:
            same = po2["nlml_sum"] == po["nlml_sum"] and po2["rmse"] == po["rmse"]
            out.append(f"- {po2['jobs']} worker processes give the same fit bit for bit: {'yes' if same else 'NO'}")
        for d in (po, sh):
            out.append(f"- overhead ≤ 1.3 ({d['kind']}): fit/(evals×t_eval) {d['ratio']:.2f}, fit/Σ in-fit "
                       f"{d['ratio_in_fit']:.3f} — {met(d['ratio'] <= 1.3)}"
                       f"{'' if d['ratio'] <= 1.3 or d['ratio_in_fit'] > 1.3 else ' by the first measure (met by the in-fit one)'}")
    if pred and "paired_ratio" in pred:
        x = pred["paired_ratio"]
        out.append(f"- prediction at n = {pred['n']} no slower than sklearn: {x:.2f}× — {met(x >= 1)}")
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes", default=None, help="comma-separated training sizes (default 80,500,1752)")
    ap.add_argument("--quick", action="store_true", help="n = 80, 300 and fewer repeats (about a minute)")
    ap.add_argument("--no-sklearn", action="store_true", help="skip scikit-learn")
    ap.add_argument("--sklearn-threads", default="1",
                    help="comma-separated BLAS thread counts for scikit-learn's fits (default 1; '1,2' also times it "
                         "on 2 threads, the peer of our worker processes on both cores)")
    ap.add_argument("--no-chordal", action="store_true", help="skip the chordal-kernel fits")
    ap.add_argument("--no-workers", action="store_true", help="skip the fits in worker processes")
    ap.add_argument("--workers", type=int, default=None,
                    help="worker processes for those fits (default: the library's default_jobs, one per output)")
    ap.add_argument("--no-all-starts", action="store_true",
                    help="skip the comparison fit with every start on all points (explore_size=0), run where n > 800")
    ap.add_argument("--pred-n", type=int, default=80, help="training size of the models used for prediction")
    ap.add_argument("--json", default=None, help="also write the numbers to this JSON file")
    ap.add_argument("--markdown", default=None, help="also write the tables to this file")
    ap.add_argument("--blas-threads", type=int, default=None,
                    help="limit numpy's and scipy's OpenBLAS (and OpenMP) to this many threads (default: leave as is)")
    args = ap.parse_args(argv)
    if not args.no_sklearn:
        import sklearn.gaussian_process  # noqa: F401 (load its thread pools before limiting them)
    _limits = limit_blas_threads(args.blas_threads)  # noqa: F841 (kept alive for the whole run)
    sizes = [int(s) for s in args.sizes.split(",")] if args.sizes else ([80, 300] if args.quick else [80, 500, 1752])
    sk_threads = [int(t) for t in args.sklearn_threads.split(",")]
    repeats = 3 if args.quick else 7
    pred_n = args.pred_n if args.pred_n in sizes or not args.quick else sizes[0]
    if pred_n not in sizes:
        sizes = sorted(set(sizes) | {pred_n})
    header = f"bench_training — {time.strftime('%Y-%m-%d %H:%M %Z')}; {machine_line()}\n{blas_line()}"
    print(header, flush=True)
    started = time.strftime("%H:%M")

    qt, Xt = synthetic_poses(TEST_POINTS, seed=99)
    Yt_true = velocity_field(qt, Xt[:, 3:])
    Et = euler_inputs(qt, Xt)
    results, pred_models = {}, {}
    for n in sizes:
        q, X, Y = synthetic_data(n, seed=0)
        r = results[n] = {}
        ev_rep = 6 if args.quick else 9  # single evaluations timed (cycling over the outputs' hyperparameters)
        for metric in ("arc",) if args.no_chordal else ("arc", "chordal"):
            for shared in (False, True):
                key = f"{'sh' if shared else 'po'}_{metric}"
                runs = [(key, None, 1)]
                if not shared and not args.no_workers:
                    runs.append((key + "_w", None, args.workers or compute.default_jobs(Y.shape[1], n)))
                if key == "po_arc" and n > 2 * optimise.SUBSAMPLE_SIZE and not args.no_all_starts:
                    runs.append(("po_arc_all", 0, 1))
                for key_, explore, jobs in runs:
                    d = r[key_] = bench_ours(X, Y, metric, shared, ev_rep, Xt, Yt_true, explore, jobs)
                    print(f"n={n:5d} {d['kind']:48s} fit {d['fit_s']:8.2f} s  evals {d['evaluations']:4d} + "
                          f"{d['subsample_evaluations']} on the subsample "
                          f"(infeasible {d['infeasible']}, refits {d['guarded']})  t_eval {d['t_eval_s'] * 1e3:7.1f} ms  "
                          f"ratio {d['ratio']:.2f} in-fit {d['ratio_in_fit']:.3f}  Σ NLML {d['nlml_sum']:.3f}  "
                          f"rmse {d['rmse']:.4f}  load {d['load']:.1f}", flush=True)
        if not args.no_sklearn:
            for t in sk_threads:
                key = "sklearn" if t == sk_threads[0] else f"sklearn_{t}"
                if t == 2 and t != sk_threads[0]:
                    key = "sklearn_2"
                d = r[key] = bench_sklearn(q, X, Y, Et, Yt_true, threads=t)
                print(f"n={n:5d} {d['kind']:48s} fit {d['fit_s']:8.2f} s  evals {d['evaluations']:4d}  "
                      f"per eval {d['t_eval_s'] * 1e3:7.1f} ms  rmse {d['rmse']:.4f}  "
                      f"({d['convergence_warnings']} convergence warnings)  load {d['load']:.1f}", flush=True)
        if n == pred_n:
            pred_models = {"ours": r["po_arc"]["_gp"], "shared": r["sh_arc"]["_gp"],
                           "sklearn": r.get("sklearn", {}).get("_models")}
        for d in r.values():  # free the large arrays
            d.pop("_gp", None)
            d.pop("_models", None)

    pred = None
    if pred_models:
        pred = bench_prediction(pred_models["ours"], pred_models["shared"], pred_models["sklearn"], repeats)
        pred.update(n=pred_n, repeats=repeats)
        print(f"prediction at {PRED_POINTS} poses (n = {pred_n}): ours {pred['ours_s']:.3f} s, shared "
              f"{pred['ours_shared_s']:.3f} s, sklearn {pred.get('sklearn_s', float('nan')):.3f} s", flush=True)

    lines = print_report(results, pred, f"Measured {time.strftime('%Y-%m-%d %H:%M %Z')} (run started {started}); "
                                        f"{machine_line()}. {blas_line()}.")
    lines += check_targets(results, pred)
    text = "\n".join(lines)
    print("\n" + text)
    if args.markdown:
        Path(args.markdown).write_text(text + "\n")
    if args.json:
        Path(args.json).write_text(json.dumps({"sizes": sizes, "results": {str(k): v for k, v in results.items()},
                                               "prediction": pred, "machine": machine_line()}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
