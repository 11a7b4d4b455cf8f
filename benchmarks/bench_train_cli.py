"""The whole `rbgp train` command on recorded demonstrations against scikit-learn, and under load.

    .venv/bin/python benchmarks/bench_train_cli.py                      # handover demos, kernels se and se-chordal
    .venv/bin/python benchmarks/bench_train_cli.py --kernels se --no-load
    .venv/bin/python benchmarks/bench_train_cli.py --demos sample_data/csv --no-sklearn

The job is the paper's (issue 35: "pose only, exact GP, n = 1752"): ``rbgp train`` runs with
``PAPER_GP`` = ``--train-rate 0 --inducing 0 --time-input none --prior none`` besides the options below,
so that its GP sees the pose alone (no phase input, zero prior mean), on the recorded samples (30 Hz on
the handovers: 3645 pairs, of which a random 1752 make the exact GP). Without them the command would
run today's defaults: velocities at 10 Hz (since aef1b82: 1208 pairs on the handovers, so n = 1208,
not 1752, and scikit-learn's O(n³) fits 3× cheaper), the phase input (a fourth hyperparameter) and the
path prior (40 evaluations on all points per output instead of 8), a sparse GP above 3000 points.
The noise calibration (``--calibrate-noise``, rbgp's default) stays on: it is work scikit-learn does
not do, and counted against rbgp.

For each kernel, in one run:

1. ``rbgp train DEMOS -o MODEL PAPER_GP --subsample 1 --max-points 1752 --hyper-points 0 --kernel K --json``
   (per-output hyperparameters; ``--jobs`` as given, default the command's own choice) as a subprocess:
   wall time of the whole command (interpreter start, imports, reading and preparing the files, the fit,
   writing the model file), and the fit's own time and evaluations from its JSON summary;
2. scikit-learn's six fits (``ConstantKernel()*RBF() + WhiteKernel()``, ``n_restarts_optimizer=2``,
   ``random_state=0``, one model per output) on the very arrays stored in the model file (X: rotation
   vector and translation, Y: the six velocities; the run checks X has 6 columns and ``--max-points``
   rows), with its BLAS pools as they are (``--sklearn-threads`` to limit them), its evaluations of the
   likelihood counted, and the ratio (target ≥ 15×);
3. the same ``rbgp train`` while ``--load-procs`` busy loops (default: one per usable core, i.e.
   another program using every core) run, between two runs on the machine as it is; the ratio loaded
   / as-is (target ≤ 2), and a check that the model is the same. Linux shares the cores between
   *sessions* first where autogroup scheduling is on (``/proc/sys/kernel/sched_autogroup_enabled``,
   the default of most desktop and many server kernels), then between the tasks of a session: a
   program started from another terminal is another session. ``--load-session new`` (default) starts
   the busy loops in a session of their own, like such a program; ``same`` in the benchmark's
   session (every task then competes with every other, as without autogroup); ``both`` runs both.
   With ``--sklearn-busy`` scikit-learn's six fits run beside the same busy loops too, for the ratio
   with every core busy (target ≥ 15× as well; minutes): as they run by default and, unless
   ``--sklearn-threads`` is given, a second time with its BLAS on one thread (what a careful user does
   beside other work: with two BLAS threads and a core taken, OpenBLAS's threads spin-wait for each
   other; one likelihood evaluation at n = 1752 took 6.7–9.7 s of wall time with two threads beside a
   busy loop against 1.9–2.4 s with one, issue 35's sixth pass). The target is judged against the
   faster of the two.

rbgp_cli's bytecode is written before timing (``_common.compile_package``), as an installed package has it.
The machine "as it is" may be shared: the 1-minute load average and the number of runnable tasks
are printed with every run.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np  # noqa: E402

from _common import compile_package, fmt_s, machine_line  # noqa: E402
from rbgp_cli.io.model_store import read_header  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_DEMOS = ROOT.parent / "shared" / "realdata" / "handover_object_csv"


def runnable() -> str:
    try:
        with open("/proc/loadavg") as fh:
            parts = fh.read().split()
        return f"load {parts[0]}, runnable {parts[3]}"
    except OSError:
        return f"load {os.getloadavg()[0]:.2f}"


#: The paper's GP (issue 35's "pose only, exact GP"): the recorded samples (not 10 Hz), the exact GP
#: whatever the number of pairs, the pose as the only input, a zero prior mean.
PAPER_GP = ["--train-rate", "0", "--inducing", "0", "--time-input", "none", "--prior", "none"]


def run_train(demos: str, out: str, kernel: str, jobs: int | None, max_points: int) -> dict:
    """One `rbgp train` subprocess; returns wall time and its JSON summary."""
    # --hyper-points 0: the hyperparameters from all points, as scikit-learn's fits (the default
    # fits them on a random 400, issue 35, which would not be the same job)
    cmd = [sys.executable, "-m", "rbgp_cli", "train", demos, "-o", out, *PAPER_GP, "--subsample", "1",
           "--max-points", str(max_points), "--hyper-points", "0", "--kernel", kernel, "--json"]
    if jobs is not None:
        cmd += ["--jobs", str(jobs)]
    before = runnable()
    c0 = children_cpu()
    t0 = time.perf_counter()
    res = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
    wall = time.perf_counter() - t0
    cpu = children_cpu() - c0
    if res.returncode != 0:
        raise RuntimeError(f"rbgp train failed ({res.returncode}): {res.stderr[-2000:]}")
    summary = json.loads(res.stdout)
    return {"wall_s": wall, "cpu_s": cpu, "summary": summary, "before": before, "after": runnable()}


def children_cpu() -> float:
    """CPU seconds of the finished child processes, their own children included (the workers)."""
    import resource

    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return ru.ru_utime + ru.ru_stime


def busy_loops(count: int, new_session: bool) -> list[subprocess.Popen]:
    """``count`` processes that each keep one core busy (pure Python loops, no I/O), in a session of
    their own (``new_session``) or in this one."""
    return [subprocess.Popen([sys.executable, "-c", "while True:\n    pass"], start_new_session=new_session)
            for _ in range(count)]


def stop(procs: list[subprocess.Popen]) -> None:
    for p in procs:
        p.kill()
    for p in procs:
        p.wait()


def sklearn_fits(X: np.ndarray, Y: np.ndarray, threads: int | None) -> dict:
    """scikit-learn's six fits on X (n, 6), Y (n, 6): wall and CPU seconds, and its likelihood
    evaluations (with gradient, over the 3 starts of each output) counted by a subclass that only
    counts the calls."""
    from sklearn.exceptions import ConvergenceWarning
    from sklearn.gaussian_process import GaussianProcessRegressor
    from sklearn.gaussian_process.kernels import RBF, ConstantKernel, WhiteKernel

    import contextlib

    from threadpoolctl import threadpool_limits

    calls = [0]

    class Counted(GaussianProcessRegressor):
        def log_marginal_likelihood(self, *args, **kwargs):
            calls[0] += 1
            return super().log_marginal_likelihood(*args, **kwargs)

    limit = threadpool_limits(limits=threads) if threads else contextlib.nullcontext()
    before = runnable()
    with limit, warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        c0 = time.process_time()
        t0 = time.perf_counter()
        for l in range(Y.shape[1]):
            Counted(ConstantKernel() * RBF() + WhiteKernel(), n_restarts_optimizer=2,
                    random_state=0).fit(X, Y[:, l])
        wall = time.perf_counter() - t0
        cpu = time.process_time() - c0
    return {"wall_s": wall, "cpu_s": cpu, "before": before, "after": runnable(), "n": int(len(X)),
            "evaluations": calls[0]}


def fits_of(path: str) -> list:
    header, _ = read_header(path)
    return [f["values"] for f in header["fits"]]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--demos", default=str(DEFAULT_DEMOS), help="demonstration files or folder (default: the handover recordings)")
    ap.add_argument("--kernels", default="se,se-chordal", help="comma-separated --kernel values (default se,se-chordal)")
    ap.add_argument("--max-points", type=int, default=1752)
    ap.add_argument("--jobs", type=int, default=None, help="--jobs for rbgp train (default: the command's own choice)")
    ap.add_argument("--no-sklearn", action="store_true")
    ap.add_argument("--sklearn-threads", type=int, default=None, help="limit scikit-learn's BLAS pools (default: as they are)")
    ap.add_argument("--no-load", action="store_true", help="skip the run under load")
    ap.add_argument("--sklearn-busy", action="store_true",
                    help="also run scikit-learn's six fits beside the busy loops (minutes), for the busy ratio")
    ap.add_argument("--load-procs", type=int, default=None, help="busy loops for the loaded run (default: usable cores)")
    ap.add_argument("--load-session", choices=("new", "same", "both"), default="new",
                    help="start the busy loops in a session of their own (default), in this one, or both in turn")
    ap.add_argument("--json", default=None)
    ap.add_argument("--markdown", default=None)
    args = ap.parse_args(argv)
    if not Path(args.demos).exists():
        print(f"demonstrations not found: {args.demos}", file=sys.stderr)
        return 2
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:
        cores = os.cpu_count() or 1
    load_procs = args.load_procs or cores
    started = time.strftime("%H:%M")
    print(f"bench_train_cli — {time.strftime('%Y-%m-%d %H:%M %Z')}; {machine_line()}", flush=True)
    print(compile_package(), flush=True)  # rbgp train's imports from bytecode, as an installed package
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        for kernel in args.kernels.split(","):
            r = results[kernel] = {}
            model = os.path.join(tmp, f"{kernel}.rbgp")
            r["as_is_1"] = run_train(args.demos, model, kernel, args.jobs, args.max_points)
            summ = r["as_is_1"]["summary"]
            print(f"{kernel}: rbgp train {r['as_is_1']['wall_s']:.2f} s (CPU {r['as_is_1']['cpu_s']:.1f} s; fit "
                  f"{summ['seconds']:.2f} s; {summ['pairs']} pairs, {summ['points']} points; "
                  f"{r['as_is_1']['before']})", flush=True)
            _, arrays = read_header(model)
            if arrays["X"].shape[1] != 6 or len(arrays["X"]) != min(args.max_points, summ["pairs"]):
                print(f"the model's X is {arrays['X'].shape}: not the paper's pose-only GP on "
                      f"{args.max_points} points", file=sys.stderr)
                return 1
            if not args.no_sklearn:
                r["sklearn"] = sklearn_fits(arrays["X"], arrays["Y"], args.sklearn_threads)
                print(f"{kernel}: scikit-learn, 6 fits on the model's {len(arrays['X'])} points: {r['sklearn']['wall_s']:.1f} s "
                      f"(CPU {r['sklearn']['cpu_s']:.0f} s; {r['sklearn']['evaluations']} evaluations; "
                      f"{r['sklearn']['before']})", flush=True)
            if not args.no_load:
                sessions = ("new", "same") if args.load_session == "both" else (args.load_session,)
                for session in sessions:
                    loaded_model = os.path.join(tmp, f"{kernel}-loaded.rbgp")
                    procs = busy_loops(load_procs, session == "new")
                    try:
                        time.sleep(1.0)
                        r[f"loaded_{session}"] = run_train(args.demos, loaded_model, kernel, args.jobs, args.max_points)
                        if args.sklearn_busy and not args.no_sklearn:  # the peer beside the same busy loops
                            _, arrays = read_header(model)
                            r[f"sklearn_loaded_{session}"] = sklearn_fits(arrays["X"], arrays["Y"], args.sklearn_threads)
                            print(f"{kernel}: scikit-learn with {load_procs} busy loops ({session} session) "
                                  f"{r[f'sklearn_loaded_{session}']['wall_s']:.1f} s", flush=True)
                            if args.sklearn_threads is None:  # and as a careful user runs it: one BLAS thread
                                r[f"sklearn1_loaded_{session}"] = sklearn_fits(arrays["X"], arrays["Y"], 1)
                                print(f"{kernel}: scikit-learn, its BLAS on one thread, with {load_procs} busy loops "
                                      f"({session} session) {r[f'sklearn1_loaded_{session}']['wall_s']:.1f} s", flush=True)
                    finally:
                        stop(procs)
                    r[f"same_model_{session}"] = fits_of(loaded_model) == fits_of(model)
                    print(f"{kernel}: rbgp train with {load_procs} busy loops ({session} session) "
                          f"{r[f'loaded_{session}']['wall_s']:.2f} s ({r[f'loaded_{session}']['before']}); "
                          f"same model: {r[f'same_model_{session}']}", flush=True)
                    time.sleep(1.0)
                r["as_is_2"] = run_train(args.demos, model, kernel, args.jobs, args.max_points)
                print(f"{kernel}: rbgp train again {r['as_is_2']['wall_s']:.2f} s ({r['as_is_2']['before']})", flush=True)

    lines = [f"Measured {time.strftime('%Y-%m-%d %H:%M %Z')} (run started {started}); {machine_line()}.", "",
             f"`rbgp train {Path(args.demos).name} {' '.join(PAPER_GP)} --subsample 1 --max-points {args.max_points} "
             "--hyper-points 0 --kernel K` "
             f"(per-output hyperparameters{'' if args.jobs is None else f', --jobs {args.jobs}'}), whole command; "
             "scikit-learn's six fits on the arrays stored in the model file"
             + ("" if args.sklearn_threads is None else f" (its BLAS on {args.sklearn_threads} thread(s))") + ".", "",
             "| kernel | n | rbgp train as is (s) | of which the fit (s) | evaluations on all points per output | sklearn (s) "
             "| sklearn's evaluations | sklearn / rbgp train | the same in CPU time | busy loops | rbgp train then (s) "
             "| loaded / as is | same model |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|---|---:|---:|---|"]
    loaded_keys = [k for k in ("loaded_new", "loaded_same")]
    for kernel, r in results.items():
        runs = [r[k] for k in ("as_is_1", "as_is_2") if k in r]
        as_is = sum(x["wall_s"] for x in runs) / len(runs)
        summ = r["as_is_1"]["summary"]
        per_output = np.mean([o["n_evaluations"] for o in summ["outputs"]])
        sk = r.get("sklearn")
        sk_s = fmt_s(sk["wall_s"]) if sk else "–"
        sk_ratio = f"{sk['wall_s'] / as_is:.1f}×" if sk else "–"
        cpu_as_is = sum(x["cpu_s"] for x in runs) / len(runs)
        sk_cpu = f"{sk['cpu_s'] / cpu_as_is:.1f}× ({sk['cpu_s']:.0f} s / {cpu_as_is:.1f} s)" if sk else "–"
        times = " / ".join(fmt_s(x["wall_s"]) for x in runs)
        present = [k for k in loaded_keys if k in r] or [None]
        for i, key in enumerate(present):
            ld = r.get(key) if key else None
            who = f"{load_procs}, {key.split('_')[1]} session" if key else "–"
            ld_s = fmt_s(ld["wall_s"]) if ld else "–"
            ld_ratio = f"{ld['wall_s'] / as_is:.2f}" if ld else "–"
            same = ("yes" if r["same_model_" + key.split("_")[1]] else "NO") if ld else "–"
            sk_ev = str(sk["evaluations"]) if sk else "–"
            head = (f"| {kernel} | {summ['points']} | {times} | {summ['seconds']:.2f} | {per_output:.1f} | {sk_s} | {sk_ev} "
                    f"| {sk_ratio} | {sk_cpu} ") if i == 0 else "| | | | | | | | | "
            lines.append(head + f"| {who} | {ld_s} | {ld_ratio} | {same} |")
    lines += ["", "Load before each run: " + "; ".join(
        f"{kernel} {k}: {r[k]['before']}" for kernel, r in results.items()
        for k in ("as_is_1", "sklearn", "loaded_new", "loaded_same", "as_is_2") if k in r), "", "**Targets**", ""]
    for kernel, r in results.items():
        runs = [r[k] for k in ("as_is_1", "as_is_2") if k in r]
        as_is = sum(x["wall_s"] for x in runs) / len(runs)
        for key in loaded_keys:
            if f"sklearn_{key}" in r:
                x_default = r[f"sklearn_{key}"]["wall_s"] / r[key]["wall_s"]
                one = r.get(f"sklearn1_{key}")
                x = min(x_default, one["wall_s"] / r[key]["wall_s"]) if one else x_default
                both = (f" (its BLAS as by default {x_default:.1f}×, on one thread "
                        f"{one['wall_s'] / r[key]['wall_s']:.1f}×; the faster counts)") if one else ""
                lines.append(f"- {kernel}: with every core busy ({key.split('_')[1]} session), whole command ≥ 15× "
                             f"faster than scikit-learn's six fits beside the same busy loops: {x:.1f}× wall{both} — "
                             f"{'met' if x >= 15 else 'NOT met'}")
        if "sklearn" in r:
            x = r["sklearn"]["wall_s"] / as_is
            xc = r["sklearn"]["cpu_s"] / (sum(x["cpu_s"] for x in runs) / len(runs))
            lines.append(f"- {kernel}: whole command ≥ 15× faster than scikit-learn's six fits: {x:.1f}× wall, "
                         f"{xc:.1f}× CPU time — {'met' if x >= 15 else 'NOT met'}")
        for key in loaded_keys:
            if key in r:
                y = r[key]["wall_s"] / as_is
                lines.append(f"- {kernel}: with every core busy ({key.split('_')[1]} session) no worse than 2× the time "
                             f"as is: {y:.2f}× — {'met' if y <= 2 else 'NOT met'}")
    text = "\n".join(lines)
    print("\n" + text)
    if args.markdown:
        Path(args.markdown).write_text(text + "\n")
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1, default=str))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
