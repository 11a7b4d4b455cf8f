"""The whole `rbgp train` command at the defaults against a whole process that fits a ProMP (issue 35).

    .venv/bin/python benchmarks/bench_train_promp.py                  # every set in ../shared/realdata, quiet and busy
    .venv/bin/python benchmarks/bench_train_promp.py --sets hand_raise_csv --rounds 3 --no-busy
    .venv/bin/python benchmarks/bench_train_promp.py --demos sample_data/csv
    .venv/bin/python benchmarks/bench_train_promp.py --fold-rounds 0      # the whole processes only

For each set of demonstrations, in one run, alternated ``--rounds`` times (the best of the rounds is
kept on each side, and the ratio of the bests printed; target at most 3):

* **rbgp**: ``rbgp train DEMOS -o MODEL -q`` as a subprocess at the defaults: the interpreter's start,
  the imports, reading and cleaning the files, the fit, the calibration, the bands' scale and writing
  the model file;
* **ProMP**: ``python -c ...`` as a subprocess that reads and cleans the same files with the same reader
  (rbgp's ``load_demonstrations``: the peers read what rbgp reads; the waves' raw BVH takes with
  ``ReadOptions(body="Hand_R")`` as ``rbgp train --body Hand_R`` reads them) and fits ``movement-primitives``' ProMP
  as ``rbgp crossval``'s ProMP row does (:func:`rbgp_cli.evaluation.peers.fit_promp`: 6 dimensions, its
  basis functions on normalised time), then writes its weights' mean and covariance with ``numpy.savez``.
  Run twice per round: **as it runs by default** (numpy's OpenBLAS with one thread per core) and **with
  one BLAS thread** (``OPENBLAS_NUM_THREADS=1`` and its MKL/OpenMP equivalents, what a careful user
  sets beside other work). The ProMP's EM makes ~360 pseudo-inverses of 150 × 150 matrices (SVDs, whose
  Householder steps are many small BLAS calls); with two BLAS threads and the other core taken, each call
  waits for a thread that is not running (perf: 94 % of the process's CPU in OpenBLAS's
  ``blas_thread_server`` / ``exec_blas`` spin-wait), and the process takes 40–50× its quiet time. The
  ratio is judged against the faster of the two ProMP processes (``ratio``); the one against the
  default process is printed as well (``ratio vs default``).

Wall time and CPU time (the child's user + system, its workers included) are printed for each. With
``--busy`` (the default runs both) a second CPU-bound process (a Python busy loop, in a session of its
own like another user's program) runs beside both for the whole measurement.

**Crossval's time per fold** (``--fold-rounds``, default 1; 0: not measured): on the same set and its
first fold of ``rbgp crossval``'s five (seed 0), :func:`rbgp_cli.evaluation.crossval.run_fold` in a
forked worker process (as crossval runs its folds: BLAS on one thread, no nested pool) for rbgp at the
defaults (the fit on the other four fifths, the mean and 20 sampled rollouts
from each held-out start, the same without the GP's residual, the scores) against the ProMP peer's
row on the same fold (its fit, conditioned rollouts and samples, the scores): wall and CPU seconds
(the fold's worker process), the best of the rounds, and their ratio.

The machine may be shared: the load average is printed with every run. Before timing, rbgp_cli's
bytecode is written (``_common.compile_package``), as an installed package has it.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import compile_package, machine_line  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
REALDATA = ROOT.parent / "shared" / "realdata"
#: The sets of ../shared/realdata that hold several demonstrations of one motion (the others are
#: single recordings for the readers: one demonstration is too few for a ProMP's covariance).
SETS = ("handover_object_csv", "hand_raise_csv", "handover_variation_csv", "bvh_wave")
#: The body each set is read with (both sides: ``rbgp train --body`` and the ProMP process's reader); the
#: waves are raw BVH skeletons, whose right hand is the moving body.
BODY = {"bvh_wave": "Hand_R"}

PROMP_SCRIPT = """
import sys, numpy as np
from rbgp_cli.io.options import ReadOptions
from rbgp_cli.workflows import load_demonstrations
from rbgp_cli.evaluation.peers import fit_promp
body = None if sys.argv[2] == "-" else sys.argv[2]
trajs, _, _ = load_demonstrations(sys.argv[3:], ReadOptions(body=body))
peer = fit_promp(trajs)
np.savez(sys.argv[1], mean=peer.promp.weight_mean, cov=peer.promp.weight_cov, ref=peer.ref)
"""


#: What a careful user sets for a process of small matrix products beside other work: one BLAS thread.
ONE_BLAS_THREAD = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def run_timed(cmd: list[str], env: dict | None = None) -> tuple[float, float]:
    """(wall s, CPU s of the child and its children) of one command, which must succeed; ``env``: variables
    set on top of this process's environment."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True,
                          env=None if env is None else {**os.environ, **env})
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(cmd[:3])} failed ({proc.returncode}): {proc.stderr.strip()[-500:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu


def load_line() -> str:
    try:
        with open("/proc/loadavg") as fh:
            parts = fh.read().split()
        return f"load {parts[0]}, runnable {parts[3]}"
    except OSError:
        return "load n/a"


def measure(demos: str, rounds: int, tmp: str, installed: bool = True) -> dict:
    """Best wall / CPU of rbgp train and of the ProMP process over ``rounds`` alternated runs (both read the
    set's body, :data:`BODY`, where it has one)."""
    body = BODY.get(Path(demos).name)
    rbgp = [str(Path(sys.executable).parent / "rbgp"), "train", demos, "-o", os.path.join(tmp, "model.rbgp"), "-q"]
    rbgp += ["--body", body] if body else []
    promp = [sys.executable, "-c", PROMP_SCRIPT, os.path.join(tmp, "promp.npz"), body or "-", demos]
    runs = {"rbgp": [], "promp": [], "promp1": []}
    for _ in range(rounds):
        for name, cmd, env in (("rbgp", rbgp, None), ("promp", promp, None), ("promp1", promp, ONE_BLAS_THREAD)):
            if name == "promp" and not installed:  # not run: its two BLAS threads spin on a loaded machine
                runs[name].append((float("nan"), float("nan")))
                continue
            runs[name].append(run_timed(cmd, env))
    best = {k: (min(w for w, _ in v), min(c for _, c in v)) for k, v in runs.items()}
    faster = float(np.nanmin([best["promp"][0], best["promp1"][0]]))
    return {"rbgp_wall": best["rbgp"][0], "rbgp_cpu": best["rbgp"][1], "promp_wall": best["promp"][0],
            "promp_cpu": best["promp"][1], "promp1_wall": best["promp1"][0], "promp1_cpu": best["promp1"][1],
            "ratio": best["rbgp"][0] / faster, "ratio_default": best["rbgp"][0] / best["promp"][0],
            "cpu_ratio": best["rbgp"][1] / float(np.nanmin([best["promp"][1], best["promp1"][1]])), "runs": runs,
            "load": load_line()}


def cpu_now() -> float:
    """CPU seconds of this process and of its children that have ended (the fit's workers)."""
    ch = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + ch.ru_utime + ch.ru_stime


def measure_fold(demos: str, rounds: int, folds: int = 5, fold: int = 0) -> dict:
    """Best wall / CPU of crossval's fold ``fold`` of ``folds`` (seed 0) for rbgp at the defaults and for
    the ProMP peer, alternated ``rounds`` times (:func:`rbgp_cli.evaluation.crossval.run_fold`)."""
    import warnings

    from rbgp_cli.compute import fork_context, process_pool, worker_init
    from rbgp_cli.evaluation.crossval import Config, make_folds, run_fold
    from rbgp_cli.evaluation.peers import PROMP
    from rbgp_cli.io.options import ReadOptions
    from rbgp_cli.workflows import load_demonstrations

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        trajs, _, _ = load_demonstrations([demos], ReadOptions(body=BODY.get(Path(demos).name)))
    held = set(make_folds(len(trajs), folds, 0)[fold].tolist())
    train = [t for i, t in enumerate(trajs) if i not in held]
    test = [t for i, t in enumerate(trajs) if i in held]
    configs = {"rbgp": Config("axis-angle"), "promp": Config(PROMP)}
    runs = {"rbgp": [], "promp": []}
    for _ in range(rounds):
        for name, config in configs.items():
            # as crossval runs a fold: in a worker process of its own (forked), BLAS on one thread,
            # rbgp's per-output fits in that process (no nested pool)
            c0, w0 = cpu_now(), time.perf_counter()
            with process_pool(1, context=fork_context(), init=worker_init) as pool:
                pool.submit(run_fold, config, train, test, fold=fold).result()
            runs[name].append((time.perf_counter() - w0, cpu_now() - c0))
    best = {k: (min(w for w, _ in v), min(c for _, c in v)) for k, v in runs.items()}
    return {"rbgp_wall": best["rbgp"][0], "rbgp_cpu": best["rbgp"][1], "promp_wall": best["promp"][0],
            "promp_cpu": best["promp"][1], "ratio": best["rbgp"][0] / best["promp"][0],
            "cpu_ratio": best["rbgp"][1] / best["promp"][1], "train": len(train), "held_out": len(test),
            "load": load_line()}


def busy_process() -> subprocess.Popen:
    """A CPU-bound Python loop in a session of its own (another program on the machine)."""
    return subprocess.Popen([sys.executable, "-c", "while True: pass"], start_new_session=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sets", nargs="*", default=list(SETS), help="folders of ../shared/realdata")
    ap.add_argument("--demos", nargs="*", default=[], help="other folders of demonstrations")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--busy", action=argparse.BooleanOptionalAction, default=True,
                    help="also measure beside a second CPU-bound process")
    ap.add_argument("--quiet-runs", action=argparse.BooleanOptionalAction, default=True,
                    help="measure on the machine as it is")
    ap.add_argument("--fold-rounds", type=int, default=1,
                    help="rounds of crossval's first fold, rbgp against the ProMP peer (0: not measured)")
    ap.add_argument("--installed-peer", action=argparse.BooleanOptionalAction, default=True,
                    help="also run the ProMP process as installed (two BLAS threads: minutes on a loaded machine); "
                         "without it only the one-BLAS-thread process, the faster one, is run")
    ap.add_argument("--json", help="also write the numbers to this file")
    args = ap.parse_args(argv)
    folders = [str(REALDATA / s) for s in args.sets if (REALDATA / s).is_dir()] + list(args.demos)
    print(machine_line())
    print(compile_package())  # both processes import rbgp_cli: as installed, from bytecode
    print("ProMP s: the ProMP process as it runs by default / with one BLAS thread (whole processes only); ratio:"
          " rbgp against the faster of the two (vs default: against the default process)")
    print(f"{'set':<26} {'measured':<14} {'condition':<9} {'rbgp s':>8} {'ProMP s':>15} {'ratio':>6} {'vs default':>10}"
          f" {'rbgp CPU':>9} {'ProMP CPU':>15} {'CPU ratio':>9}  load")
    out = []
    conditions = (["as it is"] if args.quiet_runs else []) + (["busy"] if args.busy else [])
    with tempfile.TemporaryDirectory() as tmp:
        for folder in folders:
            for cond in conditions:
                loop = busy_process() if cond == "busy" else None
                name = Path(folder).name
                try:
                    # each part printed as soon as it is measured
                    parts = [("whole process", lambda: measure(folder, args.rounds, tmp, args.installed_peer))]
                    if args.fold_rounds > 0:
                        parts.append(("crossval fold", lambda: measure_fold(folder, args.fold_rounds)))
                    for what, run in parts:
                        r = run()
                        pw, pc = f"{r['promp_wall']:.2f}", f"{r['promp_cpu']:.2f}"
                        if "promp1_wall" in r:
                            pw, pc = f"{pw} / {r['promp1_wall']:.2f}", f"{pc} / {r['promp1_cpu']:.2f}"
                        print(f"{name:<26} {what:<14} {cond:<9} {r['rbgp_wall']:8.2f} {pw:>15} {r['ratio']:6.2f}"
                              f" {r.get('ratio_default', r['ratio']):10.2f} {r['rbgp_cpu']:9.2f} {pc:>15}"
                              f" {r['cpu_ratio']:9.2f}  {r['load']}", flush=True)
                        out.append({"set": name, "measured": what, "condition": cond, **r})
                finally:
                    if loop is not None:
                        loop.kill()
                        loop.wait()
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
