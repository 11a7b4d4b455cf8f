"""Where `rbgp train` at the defaults spends its time, stage by stage (issue 35).

    .venv/bin/python benchmarks/profile_train.py                         # every set in ../shared/realdata
    .venv/bin/python benchmarks/profile_train.py --demos sample_data/csv --rounds 3
    .venv/bin/python benchmarks/profile_train.py --cprofile fit_paths    # the top functions of one stage
    .venv/bin/python benchmarks/profile_train.py --paper-scale --sets handover_object_csv   # bench_train_cli.py's job

Runs the same library calls as ``rbgp train DEMOS -o MODEL`` (:func:`rbgp_cli.workflows.train_from_files`)
in this process, with each stage's function wrapped: CPU seconds of this process
(``time.process_time``) plus those of the worker processes that ended during the stage
(``RUSAGE_CHILDREN``: the GP's fit workers), and wall seconds. The start-up (interpreter and the
imports of ``rbgp --help``-free ``rbgp train``) is measured apart, as a subprocess that imports
what the command imports and exits. The machine may be shared: CPU time per stage is the figure to
trust, wall time moves with the load (printed).

``--paper-scale`` profiles the job of ``bench_train_cli.py`` instead of the defaults: the paper's pose-only
exact GP (``--train-rate 0 --inducing 0 --subsample 1 --max-points 1752 --hyper-points 0 --kernel se-chordal
--time-input none --prior none``).

Stages nest (the drift test runs inside the variation's stage); each row is the stage's own time,
the inner stages' included, and ``rest`` is what no row covers. The variation, the path distribution
and the envelope run on a thread of their own beside the fit and the calibration (since issue 35's
fourth pass): their rows give that thread's CPU time, and the fit's and the calibration's rows (the
process's CPU while they ran) include whatever of it ran meanwhile.

Each round prints the thread counts that ``compute.thread_workers`` chose and the stage that asked (the
posterior on all rows and the noise calibration run their hyperparameter sets on that many threads): one
thread where two cores were idle doubles those stages' wall time.
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import os
import resource
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))
REALDATA = ROOT.parent / "shared" / "realdata"
SETS = ("handover_object_csv", "hand_raise_csv", "handover_variation_csv", "bvh_wave")
#: The body each set is read with (``rbgp train --body``): the waves are raw BVH skeletons.
BODY = {"bvh_wave": "Hand_R"}

#: (label, module, attribute, module whose name for it to patch): the stages of train_from_files, in
#: the order they run. Patched where they are looked up (a ``from … import`` inside a function looks
#: the attribute up on its module at each call, so patching the defining module covers those).
STAGES = (
    ("reading and cleaning", "rbgp_cli.workflows", "load_demonstrations"),
    ("training pairs (velocities)", "rbgp_cli.dynamics.model", "training_set"),
    ("mean path, start map, pull profile", "rbgp_cli.dynamics.model", "_prior_of"),
    ("  start map (ridge by CV)", "rbgp_cli.dynamics.variation", "start_map"),
    ("  pull profile", "rbgp_cli.dynamics.variation", "pull_profile"),
    ("GP fit (hyperparameters + posterior)", "rbgp_cli.dynamics.model", "_fit_exact"),
    ("  posterior on all rows", "rbgp_cli.gp.exact", "_posterior_on_all_rows"),
    ("noise calibration", "rbgp_cli.dynamics.model", "_scaled_posterior_noise"),
    ("residual gain (left-out rollouts)", "rbgp_cli.dynamics.residual_gain", "choose_residual_gain"),
    ("variation (bands' scale, drift)", "rbgp_cli.dynamics.variation", "demonstration_variation"),
    ("  band calibration", "rbgp_cli.dynamics.variation", "band_calibration"),
    ("  drift over recording order", "rbgp_cli.dynamics.variation", "order_drift"),
    ("path distribution", "rbgp_cli.dynamics.paths", "fit_paths"),
    ("  fit_seen (anticipation)", "rbgp_cli.dynamics.anticipation", "fit_seen"),
    ("envelope", "rbgp_cli.dynamics.envelope", "envelope_from_demos"),
    ("writing the model file", "rbgp_cli.io.model_store", "save_model"),
)


def cpu_now() -> float:
    """CPU seconds of this process and of its children that have ended."""
    me = time.process_time()
    ch = resource.getrusage(resource.RUSAGE_CHILDREN)
    return me + ch.ru_utime + ch.ru_stime


class Recorder:
    def __init__(self):
        self.rows: dict[str, list[float]] = {}
        self.profilers: dict[str, object] = {}
        self.cprofile: str | None = None
        #: (stage, threads, work) of every compute.thread_workers decision in the main thread's stages:
        #: the posterior on all rows and the calibration take one thread where /proc shows other runnable
        #: tasks at that instant (compute.free_cores), which doubles their wall time
        self.threads: list[tuple[str, int, int]] = []

    def wrap(self, label, fn):
        @functools.wraps(fn)
        def timed(*args, **kwargs):
            prof = None
            if self.cprofile and self.cprofile in (fn.__name__, label.strip()):
                import cProfile

                prof = self.profilers.setdefault(label, cProfile.Profile())
            # a stage on a thread of its own (rbgp train's work without the GP, beside the fit): that
            # thread's CPU, not the process's (which counts the fit's workers and the main thread too)
            on_side = threading.current_thread() is not threading.main_thread()
            cpu = time.thread_time if on_side else cpu_now
            c0, w0 = cpu(), time.perf_counter()
            if prof is not None:
                prof.enable()
            try:
                return fn(*args, **kwargs)
            finally:
                if prof is not None:
                    prof.disable()
                row = self.rows.setdefault(label, [0.0, 0.0, 0])
                row[0] += cpu() - c0
                row[1] += time.perf_counter() - w0
                row[2] += 1
        return timed


@contextlib.contextmanager
def patched(recorder: Recorder):
    import importlib

    saved = []
    for label, mod_name, attr in STAGES:
        mod = importlib.import_module(mod_name)
        orig = getattr(mod, attr)
        saved.append((mod, attr, orig))
        setattr(mod, attr, recorder.wrap(label, orig))
    # names imported at module level elsewhere (``from rbgp_cli.x import f`` at the top of a module)
    extra = []
    for mod_name in ("rbgp_cli.dynamics.model", "rbgp_cli.dynamics.variation", "rbgp_cli.dynamics.paths"):
        mod = importlib.import_module(mod_name)
        for _label, src_name, attr in STAGES:
            src = importlib.import_module(src_name)
            if mod is not src and getattr(mod, attr, None) is not None and attr in vars(mod):
                extra.append((mod, attr, vars(mod)[attr]))
                setattr(mod, attr, getattr(src, attr))
    # the thread-count decisions, with the innermost stage they were made in
    stage_of = {attr: label.strip() for label, _m, attr in STAGES}
    for mod_name in ("rbgp_cli.compute", "rbgp_cli.gp.calibration", "rbgp_cli.gp.exact"):
        mod = importlib.import_module(mod_name)
        orig = vars(mod)["thread_workers"]
        extra.append((mod, "thread_workers", orig))
        setattr(mod, "thread_workers", _traced_thread_workers(recorder, orig, stage_of))
    try:
        yield
    finally:
        for mod, attr, orig in saved + extra:
            setattr(mod, attr, orig)


def _traced_thread_workers(recorder: Recorder, orig, stage_of: dict):
    @functools.wraps(orig)
    def traced(work, min_work):
        n = orig(work, min_work)
        frame, stage = sys._getframe(1), "?"
        while frame is not None:
            if frame.f_code.co_name in stage_of:
                stage = stage_of[frame.f_code.co_name]
                break
            frame = frame.f_back
        recorder.threads.append((stage, n, int(work)))
        return n
    return traced


def startup_cost(rounds: int) -> tuple[float, float]:
    """Best (CPU s, wall s) of a process that imports what ``rbgp train`` imports before training
    (the command-line app and the train path's modules) and exits."""
    code = ("import rbgp_cli.cli.app, rbgp_cli.workflows, rbgp_cli.dynamics.model, rbgp_cli.io.read, "
            "rbgp_cli.dynamics.variation, rbgp_cli.dynamics.paths, rbgp_cli.io.model_store")
    best = (float("inf"), float("inf"))
    for _ in range(rounds):
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-c", code], check=True, cwd=ROOT)
        wall = time.perf_counter() - t0
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu = after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime
        best = (min(best[0], cpu), min(best[1], wall))
    return best


#: ``rbgp train``'s options of ``bench_train_cli.py`` (the paper's pose-only exact GP at n = 1752)
PAPER_SCALE = dict(train_rate=0, inducing=0, subsample=1.0, max_points=1752, hyper_points=0, time_input="none",
                   prior="none")


def profile_once(demos: str, out: str, cprofile: str | None, paper_scale: bool = False):
    from rbgp_cli.api import train_options
    from rbgp_cli.io.options import ReadOptions
    from rbgp_cli.workflows import train_from_files

    kwargs = dict(train_options(**PAPER_SCALE), kernel="se-chordal") if paper_scale else {}
    kwargs["options"] = ReadOptions(body=BODY.get(Path(demos).name))
    rec = Recorder()
    rec.cprofile = cprofile
    c0, w0 = cpu_now(), time.perf_counter()
    with patched(rec):
        train_from_files([demos], out, **kwargs)
    total = (cpu_now() - c0, time.perf_counter() - w0)
    return rec, total


def load_line() -> str:
    try:
        with open("/proc/loadavg") as fh:
            return "load " + " ".join(fh.read().split()[:4])
    except OSError:
        return "load n/a"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sets", nargs="*", default=list(SETS), help="folders of ../shared/realdata")
    ap.add_argument("--demos", nargs="*", default=[], help="other folders of demonstrations")
    ap.add_argument("--rounds", type=int, default=2, help="runs per set; the least CPU per stage is kept")
    ap.add_argument("--cprofile", help="a stage's function name: print its top functions by cumulative time")
    ap.add_argument("--paper-scale", action="store_true",
                    help="bench_train_cli.py's job (the paper's pose-only exact GP at n = 1752) instead of the defaults")
    args = ap.parse_args(argv)
    folders = [str(REALDATA / s) for s in args.sets if (REALDATA / s).is_dir()] + list(args.demos)
    su_cpu, su_wall = startup_cost(args.rounds)
    print(f"start-up (imports of rbgp train, a process of its own): CPU {su_cpu:.2f} s, wall {su_wall:.2f} s  "
          f"{load_line()}")
    with tempfile.TemporaryDirectory() as tmp:
        for folder in folders:
            best: dict[str, list[float]] = {}
            totals = []
            rec = None
            for r in range(args.rounds):
                rec, total = profile_once(folder, os.path.join(tmp, "m.rbgp"), args.cprofile if r == 0 else None,
                                          args.paper_scale)
                totals.append(total)
                print(f"round {r + 1}: {total[1]:.2f} s wall; threads chosen (compute.thread_workers): "
                      + (", ".join(f"{st} {n}" for st, n, _w in rec.threads) or "none") + f"  {load_line()}",
                      flush=True)
                for label, (cpu, wall, calls) in rec.rows.items():
                    b = best.setdefault(label, [cpu, wall, calls])
                    b[0], b[1] = min(b[0], cpu), min(b[1], wall)
                if r == 0 and rec.profilers:
                    import pstats

                    for label, prof in rec.profilers.items():
                        print(f"--- cProfile of {label.strip()} ---")
                        pstats.Stats(prof).sort_stats("cumulative").print_stats(25)
            tot_cpu = min(t[0] for t in totals)
            tot_wall = min(t[1] for t in totals)
            print(f"\n{Path(folder).name}  ({load_line()})")
            print(f"{'stage':<40} {'CPU s':>7} {'wall s':>7} {'calls':>5}")
            top = 0.0
            for label, _m, _a in STAGES:
                if label in best:
                    cpu, wall, calls = best[label]
                    print(f"{label:<40} {cpu:7.2f} {wall:7.2f} {calls:5d}")
                    if not label.startswith(" "):
                        top += cpu
            print(f"{'rest (summary, checks, …)':<40} {max(0.0, tot_cpu - top):7.2f}")
            print(f"{'train_from_files in all':<40} {tot_cpu:7.2f} {tot_wall:7.2f}")
            print(f"{'+ start-up':<40} {su_cpu:7.2f} {su_wall:7.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
