"""Rollout benchmark: 100 trajectories × 626 steps from a model with 1752 training pairs, batched vs one at a time.

    .venv/bin/python benchmarks/bench_rollout.py            # the full run, chordal then arc kernel (a few minutes)
    .venv/bin/python benchmarks/bench_rollout.py --quick    # 20 rollouts × 100 steps from n = 500
    .venv/bin/python benchmarks/bench_rollout.py --time-input phase   # models with the phase input and the mean-path prior
    .venv/bin/python benchmarks/bench_rollout.py --threads --steps 100   # a lone load + rollout: BLAS threads before / today

Model (:func:`build_model`): a shared-hyperparameter exact GP (``fit_gp(..., shared=True,
restarts=1)``) on n synthetic training pairs (benchmarks/_common.py: random poses, outputs a smooth
velocity field ξ = (ω, v) plus noise), wrapped in a ``MotionModel`` with the axis-angle
representation and Δt = 0.01 s, for each kernel of ``--kernel`` in turn: ``chordal`` (the product's
default kernel, se-chordal; its length-scale bounded at 2, see :func:`build_model`) and ``arc`` (the
paper's). With ``--time-input phase`` the model also takes the phase as a last input and has the
mean-path prior. Starts: ``starts_near`` (spread 0.02 m, ~0.007 rad) around 10 random poses.

Measured in one run:

* batched: ``rollout(model, q0, p0, steps, with_std=False)`` — all trajectories share one B × n
  kernel block per step (docs/method.md §8);
* one at a time: ``rollout_one_at_a_time(model, q0, p0, steps)``;
* both must give the same poses (max abs difference of quaternions and positions ≤ 1e-9);
* batched with ``with_std=True`` (adds one triangular solve per step);
* batched Monte Carlo: ``samples=5`` from fewer starts (``--sample-starts``, default 20);
* the batched rollout through the prediction path before issue 11 (pairwise distances with the
  precise small-angle branch for every query block, then the kernel: the kernel's
  ``cross_precompute`` / ``cross_gram`` replaced by ``precompute``; the rest of the code is today's):
  time, and the largest difference of the poses (≤ 1e-9);
* where one batched step's time goes (the kernel block from matrix products, the old distance
  path, kernel, mean, integration step), median over many steps.

With ``--baseline REV`` (e.g. ``main`` or a commit) the same model, saved to a model file, is also
rolled out by the library as it was at REV (``git archive REV`` into a temporary folder, run in a
subprocess with the same BLAS thread limit), alternating with today's code ``--rounds`` times: the
same batched rollout, with ``with_std=True`` and with ``samples=5``; times and the largest pose
difference.

Targets: batched ≥ 3× faster than one at a time; (issue 11) batched ≥ 3× faster than the batched
rollout of the baseline (``--baseline 991b91e``, the library before issue 11; without one, the old
distance path) with the same poses to 1e-9, and with ``samples`` the same per-sample cost. A last
table puts the kernels side by side against the baseline (wall and CPU time).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np  # noqa: E402

from _common import (blas_line, fmt_s, limit_blas_threads, machine_line, median_time, synthetic_data,  # noqa: E402
                     synthetic_poses, velocity_field)

from rbgp_cli.dynamics.model import MotionModel  # noqa: E402
from rbgp_cli.dynamics.representations import AxisAngle  # noqa: E402
from rbgp_cli.dynamics.rollout import rollout, rollout_one_at_a_time, starts_near  # noqa: E402
from rbgp_cli.gp.exact import GaussianProcess, fit_gp  # noqa: E402
from rbgp_cli.kernels import SquaredExponential  # noqa: E402

DT = 0.01


#: Upper bound of the chordal model's length-scale (see build_model).
CHORDAL_MAX_LENGTH_SCALE = 2.0


def build_model(n: int, metric: str, seed: int = 0, time_input: str | None = None):
    """A MotionModel on n training pairs (shared hyperparameters, one start). Returns (model, info).

    Without a time input: n synthetic pairs (random poses, the smooth velocity field plus noise).
    With ``time_input="phase"``: the product's coming default, the phase input and the mean-path
    prior: the same poses with a random phase each (uniform on [0, 1]) as a last input, the outputs
    per unit phase (D·ξ, D = 6.26 s, as ``train_model`` makes them) minus the prior mean, which is
    :func:`~rbgp_cli.dynamics.model.mean_path` (gain 10) of 10 demonstrations that follow the same
    velocity field from 10 random poses for 6.26 s; the kernel is the product with a squared
    exponential on the phase. (Fitting ``train_model`` on those noise-free demonstrations' own pairs
    drives σn to its lower bound: a model too ill-conditioned for poses to 1e-9, see below.)

    The chordal kernel's length-scale is bounded at CHORDAL_MAX_LENGTH_SCALE: the synthetic field
    is linear in the rotation matrix's entries, i.e. quadratic in the quaternion, which is what the
    chordal kernel becomes for λ → ∞, and unbounded the shared fit ends at λ = 63, σf = 74 with
    rcond(K + σn²I) = 7e-10. On such a model round-off of 1e-16 in K grows to ~2e-9 in the poses
    between any two correct implementations (measured: 991b91e against c3c4624), below which "the
    same poses to 1e-9" cannot be asked. At λ = 2 (rotation distances are at most 2): rcond 2e-6.
    The bound changes no cost of a rollout step.
    """
    from rbgp_cli.dynamics.model import mean_path, prior_mean_outputs

    bounds = {"length_scale": (1e-3, CHORDAL_MAX_LENGTH_SCALE)} if metric == "chordal" else None
    rep = AxisAngle()
    q, X, Y = synthetic_data(n, seed=seed)
    trajs = synthetic_demonstrations(10, 626, seed=seed + 5)
    starts = np.array([np.concatenate([tr.quat[0], tr.position[0]]) for tr in trajs])
    durations = np.array([tr.duration for tr in trajs])
    mean = None
    if time_input == "phase":
        phase = np.random.default_rng(seed + 7).uniform(0.0, 1.0, n)
        mean = {"kind": "path", "gain": 10.0, **mean_path(trajs)}
        Y = durations[0] * Y - prior_mean_outputs(rep, X, mean, phase)
        X = np.concatenate([X, phase[:, None]], axis=1)
    elif time_input is not None:
        raise ValueError(f"time_input must be None or 'phase', got {time_input!r}")
    kernel = SquaredExponential(metric, 3, 0.7, time_dims=1 if time_input else 0)
    t0 = time.perf_counter()
    gp = fit_gp(X, Y, kernel, restarts=1, seed=seed, shared=True, bounds=bounds)
    fit_s = time.perf_counter() - t0
    model = MotionModel(rep, gp, DT, starts, durations, time_input=time_input, mean=mean)
    f = gp.fits[0]
    info = {"n": n, "kernel": metric, "time_input": time_input, "prior": "path" if time_input else None,
            "fit_s": fit_s, "evaluations": f.n_evaluations, "infeasible": f.n_infeasible,
            "values": {k: float(v) for k, v in f.values.items()}, "jitter": f.jitter, "rcond": f.rcond}
    return model, info


def synthetic_demonstrations(count: int, steps: int, seed: int = 0):
    """``count`` demonstrations (Trajectory) following :func:`velocity_field` from random poses for
    ``steps`` steps of DT (the exp map of ξ·Δt each step)."""
    from rbgp_cli.dynamics.trajectory import Trajectory
    from rbgp_cli.geometry.se3 import integrate_quat

    q, X = synthetic_poses(count, seed=seed)
    p = X[:, 3:].copy()
    Q, P = [q], [p]
    for _ in range(steps):
        q, p = integrate_quat(q, p, velocity_field(q, p), DT)
        Q.append(q)
        P.append(p)
    Q, P = np.stack(Q, axis=1), np.stack(P, axis=1)
    t = np.arange(steps + 1) * DT
    return [Trajectory(t, Q[b], P[b], name=f"synthetic{b}") for b in range(count)]


class OldDistancePath:
    """The kernel as the prediction path used it before issue 11: the pairwise distances of every
    query block with the precise small-angle branch (``precompute``), then ``gram``."""

    def __init__(self, kernel):
        self._k = kernel

    def __getattr__(self, name):
        return getattr(self._k, name)

    def cross_precompute(self, plan, Xa):
        return self._k.precompute(Xa, plan["Xb"])

    def cross_gram(self, plan, Xa, values):
        K, _ = self._k.gram(self._k.precompute(Xa, plan["Xb"]), values)
        return K


def with_old_distance_path(model):
    """The same model (same fit, same factors) predicting through :class:`OldDistancePath`."""
    gp = model.gp
    twin = GaussianProcess(OldDistancePath(gp.kernel), gp.X, gp.Y, gp.fits, shared=gp.shared, y_scale=gp.y_scale,
                           factors=list(zip(gp._L, gp._alpha)))
    return MotionModel(model.representation, twin, model.dt, model.starts, model.durations,
                       time_input=model.time_input, mean=model.mean)


BASELINE_SCRIPT = r"""
import json, sys, time
import numpy as np
blas = int(sys.argv[3])
if blas > 0:
    from threadpoolctl import threadpool_limits
    _limits = threadpool_limits(limits=blas)
from rbgp_cli.io.model_store import load_model
from rbgp_cli.dynamics.rollout import rollout
model, _ = load_model(sys.argv[1])
z = np.load(sys.argv[2])
q0, p0, steps, k = z["q0"], z["p0"], int(z["steps"]), int(z["sample_starts"])
rollout(model, q0[:2], p0[:2], 3, with_std=False)  # warm-up
out = {}
c0 = time.process_time(); t0 = time.perf_counter(); r = rollout(model, q0, p0, steps, with_std=False)
out["batched_s"] = time.perf_counter() - t0; out["batched_cpu_s"] = time.process_time() - c0
np.savez(sys.argv[4], quat=r.quat, position=r.position)
if int(z["extras"]):
    c0 = time.process_time(); t0 = time.perf_counter(); rollout(model, q0, p0, steps, with_std=True)
    out["batched_std_s"] = time.perf_counter() - t0; out["batched_std_cpu_s"] = time.process_time() - c0
    c0 = time.process_time(); t0 = time.perf_counter(); rollout(model, q0[:k], p0[:k], steps, samples=5, seed=0, with_std=False)
    out["samples_s"] = time.perf_counter() - t0; out["samples_cpu_s"] = time.process_time() - c0
print(json.dumps(out))
"""


def baseline_source(rev: str, folder: str) -> str:
    """``git archive REV`` of this repository, unpacked into ``folder``; returns the folder."""
    import subprocess
    import tarfile

    root = Path(__file__).resolve().parents[1]
    tar = Path(folder) / "src.tar"
    with open(tar, "wb") as fh:
        subprocess.run(["git", "-C", str(root), "archive", rev], stdout=fh, check=True)
    with tarfile.open(tar) as tf:
        tf.extractall(Path(folder) / "src")
    return str(Path(folder) / "src")


THREADS_SCRIPT = r"""
import contextlib, json, sys, time
t0, c0 = time.perf_counter(), time.process_time()
mode, model_path, starts_path, poses_path = sys.argv[1:5]
import numpy as np
from rbgp_cli.dynamics.rollout import rollout
from rbgp_cli.gp import exact
from rbgp_cli.io.model_store import load_model
t1, c1 = time.perf_counter(), time.process_time()
if mode == "old":  # before issue 24: the loaded model's factorisation on the BLAS pool as it is
    kept = exact.blas_threads
    exact.blas_threads = lambda n: contextlib.nullcontext()
model, _ = load_model(model_path)
if mode == "old":
    exact.blas_threads = kept
t2, c2 = time.perf_counter(), time.process_time()
z = np.load(starts_path)
r = rollout(model, z["q0"], z["p0"], int(z["steps"]), with_std=bool(z["with_std"]))
t3, c3 = time.perf_counter(), time.process_time()
np.savez(poses_path, quat=r.quat, position=r.position)
print(json.dumps({"imports_s": t1 - t0, "imports_cpu_s": c1 - c0, "load_s": t2 - t1, "load_cpu_s": c2 - c1,
                  "rollout_s": t3 - t2, "rollout_cpu_s": c3 - c2}))
"""

#: The three ways of running ``THREADS_SCRIPT``: (label, mode argument, extra environment).
THREAD_MODES = (("before (BLAS pool for the load)", "old", {}), ("today", "new", {}),
                ("today, OPENBLAS_NUM_THREADS=1", "new", {"OPENBLAS_NUM_THREADS": "1"}))


def run_threads(args, n: int, count: int, steps: int) -> tuple[dict, list]:
    """``--threads``: what a lone ``rbgp rollout`` costs in wall and CPU time (issue 24, point 8).

    The model (``build_model`` with the first kernel of ``--kernel``) is saved to a model file; each
    round runs, in fresh processes one after the other, the load of that file and the batched rollout
    of ``count`` starts × ``steps``: as the library did before issue 24 (the loaded model's Cholesky
    factorisations on the BLAS pool as it is), as it does today (single-threaded, as the fit), and
    today with ``OPENBLAS_NUM_THREADS=1`` (the issue's reference). CPU time is the whole process's
    (every thread; ``getrusage`` of the finished child, imports included) and the load + rollout part
    measured inside it; the poses must agree to 1e-9."""
    import resource
    import subprocess
    import tempfile

    from rbgp_cli.io.model_store import save_model

    metric = [k.strip() for k in args.kernel.split(",") if k.strip()][0]
    print(f"bench_rollout --threads — {time.strftime('%Y-%m-%d %H:%M %Z')}; {machine_line()}\n{blas_line()}", flush=True)
    model, info = build_model(n, metric)
    q0, p0 = starts_near(model.starts, count, 0.02, seed=0)
    rounds = []
    root = str(Path(__file__).resolve().parents[1])
    with tempfile.TemporaryDirectory() as tmp:
        model_path, starts_path = os.path.join(tmp, "model.rbgp"), os.path.join(tmp, "starts.npz")
        save_model(model, model_path)
        np.savez(starts_path, q0=q0, p0=p0, steps=steps, with_std=int(args.with_std))
        for rnd in range(args.rounds):
            row, got = {}, {}
            for label, mode, extra in THREAD_MODES:
                env = dict(os.environ, PYTHONPATH=root, **extra)
                poses = os.path.join(tmp, f"poses_{mode}_{len(extra)}.npz")
                before = resource.getrusage(resource.RUSAGE_CHILDREN)
                t0 = time.perf_counter()
                out = subprocess.run([sys.executable, "-c", THREADS_SCRIPT, mode, model_path, starts_path, poses],
                                     env=env, capture_output=True, text=True, cwd=root)
                wall = time.perf_counter() - t0
                after = resource.getrusage(resource.RUSAGE_CHILDREN)
                if out.returncode != 0:
                    raise RuntimeError(f"{label}: {out.stderr[-2000:]}")
                res = json.loads(out.stdout.strip().splitlines()[-1])
                res["process_s"] = wall
                res["process_cpu_s"] = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
                with np.load(poses) as z:
                    got[label] = (z["quat"], z["position"])
                row[label] = res
            ref_q, ref_p = got[THREAD_MODES[1][0]]
            for label, (q, p) in got.items():
                row[label]["max_abs_diff"] = max(float(np.max(np.abs(q - ref_q))), float(np.max(np.abs(p - ref_p))))
            rounds.append({"modes": row, "load": os.getloadavg()[0]})
            print(f"round {rnd + 1}: " + "; ".join(
                f"{k}: {v['process_s']:.2f} s wall, {v['process_cpu_s']:.2f} s CPU" for k, v in row.items()), flush=True)
    best = lambda label, key: min(r["modes"][label][key] for r in rounds)  # noqa: E731
    old, new = THREAD_MODES[0][0], THREAD_MODES[1][0]
    what = f"{count} rollouts × {steps} steps" + (" with std" if args.with_std else "")
    lines = [f"Measured {time.strftime('%Y-%m-%d %H:%M %Z')}; {machine_line()}. {blas_line()} (as they are).", "",
             f"Model: n = {n} training pairs, {metric} kernel, shared hyperparameters; saved to a model file, then "
             f"in a fresh process per run: load it and roll out {what} ({args.rounds} alternating rounds, best of each; "
             "load average (1 min) after each round: " + ", ".join(f"{r['load']:.1f}" for r in rounds) + ").", "",
             "| a lone load + rollout | process (s) | process, CPU (s) | load (s) | load, CPU (s) | rollout (s) "
             "| rollout, CPU (s) | max \\|Δ\\| to today |", "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for label, _mode, _env in THREAD_MODES:
        lines.append(f"| {label} | {fmt_s(best(label, 'process_s'))} | {fmt_s(best(label, 'process_cpu_s'))} "
                     f"| {fmt_s(best(label, 'load_s'))} | {fmt_s(best(label, 'load_cpu_s'))} | {fmt_s(best(label, 'rollout_s'))} "
                     f"| {fmt_s(best(label, 'rollout_cpu_s'))} | {max(r['modes'][label]['max_abs_diff'] for r in rounds):.1e} |")
    ratio_cpu = best(old, "process_cpu_s") / best(new, "process_cpu_s")
    ratio_wall = best(old, "process_s") / best(new, "process_s")
    same = max(r["modes"][k]["max_abs_diff"] for r in rounds for k in r["modes"]) <= 1e-9
    lines += ["", f"Before / today, the whole process: **{ratio_cpu:.2f}× the CPU time, {ratio_wall:.2f}× the wall time** "
              f"(load + rollout alone: {best(old, 'load_cpu_s') + best(old, 'rollout_cpu_s'):.2f} s / "
              f"{best(new, 'load_cpu_s') + best(new, 'rollout_cpu_s'):.2f} s CPU). Same poses to 1e-9: {'yes' if same else 'NO'}."]
    return {"model": info, "count": count, "steps": steps, "rounds": rounds, "cpu_ratio": ratio_cpu,
            "wall_ratio": ratio_wall, "same_poses": same}, lines


def run_baseline(src: str, model_path: str, starts_path: str, poses_path: str, blas: int | None) -> dict:
    """One rollout run of the baseline library (a subprocess importing ``src``)."""
    import subprocess

    env = dict(os.environ, PYTHONPATH=src)
    out = subprocess.run([sys.executable, "-c", BASELINE_SCRIPT, model_path, starts_path, str(blas or 0), poses_path],
                         env=env, capture_output=True, text=True, cwd=src)
    if out.returncode != 0:
        raise RuntimeError(f"baseline rollout failed: {out.stderr[-2000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def step_profile(model, q0, p0, repeats: int = 50) -> dict:
    """Median time of the parts of one batched step (B = len(q0)) at the start poses."""
    gp = model.gp
    state = model.initial_state(q0, p0)
    fit = gp.fits[0]
    out = {}
    out["predict_mean_ms"] = median_time(lambda: gp.predict(state), repeats)[0] * 1e3
    out["predict_mean_std_ms"] = median_time(lambda: gp.predict(state, return_std=True), repeats)[0] * 1e3
    plan = gp.kernel.cross_plan(gp.X)
    out["kernel_block_ms"] = median_time(lambda: gp.kernel.cross_gram(plan, state, fit.values), repeats)[0] * 1e3
    pre = gp.kernel.precompute(state, gp.X)
    out["old_distance_ms"] = median_time(lambda: gp.kernel.precompute(state, gp.X), repeats)[0] * 1e3
    out["old_kernel_ms"] = median_time(lambda: gp.kernel.gram(pre, fit.values), repeats)[0] * 1e3
    Ks, _ = gp.kernel.gram(pre, fit.values)
    alpha = gp._alpha[0] if hasattr(gp, "_alpha") else None
    if alpha is not None:
        out["mean_matmul_ms"] = median_time(lambda: Ks @ alpha, repeats)[0] * 1e3
    if model.mean:
        out["prior_mean_ms"] = median_time(lambda: model.prior_mean(state), repeats)[0] * 1e3
    mu = model.predict_output(state)
    duration = len(q0) and float(model.durations[0])
    out["integration_ms"] = median_time(lambda: model.advance(state, mu, DT, duration), repeats)[0] * 1e3
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=None, help="training pairs (default 1752; --quick: 500)")
    ap.add_argument("--count", type=int, default=None, help="rollouts (default 100; --quick: 20)")
    ap.add_argument("--steps", type=int, default=None, help="steps per rollout (default 626; --quick: 100)")
    ap.add_argument("--sample-starts", type=int, default=None, help="starts for the samples=5 run (default 20)")
    ap.add_argument("--kernel", default="chordal,arc",
                    help="comma-separated kernels, each measured in turn: chordal (se-chordal, the product's "
                         "default kernel) and/or arc (the paper's; default: chordal,arc)")
    ap.add_argument("--time-input", choices=("none", "phase"), default="none",
                    help="phase: the model takes the phase as a last input and has the mean-path prior "
                         "(see build_model; default none)")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--json", default=None)
    ap.add_argument("--markdown", default=None)
    ap.add_argument("--blas-threads", type=int, default=None,
                    help="limit numpy's and scipy's OpenBLAS (and OpenMP) to this many threads (default: leave as is)")
    ap.add_argument("--baseline", default=None, metavar="REV",
                    help="also roll out the same model with the library at this git revision (e.g. main)")
    ap.add_argument("--rounds", type=int, default=2, help="alternating rounds of baseline and today's code (default 2)")
    ap.add_argument("--threads", action="store_true",
                    help="only the BLAS-thread comparison of issue 24: a lone load + rollout in fresh processes as "
                         "before and as today, wall and CPU time (default n = 1208, 60 rollouts × 626 steps)")
    ap.add_argument("--with-std", action="store_true", help="with --threads: roll out with the predictive std")
    args = ap.parse_args(argv)
    if args.threads:
        res, lines = run_threads(args, args.n or 1208, args.count or 60, args.steps or 626)
        text = "\n".join(lines)
        print("\n" + text)
        if args.markdown:
            Path(args.markdown).write_text(text + "\n")
        if args.json:
            Path(args.json).write_text(json.dumps({k: v for k, v in res.items()}, indent=1))
        return 0 if res["same_poses"] else 1
    _limits = limit_blas_threads(args.blas_threads)  # noqa: F841 (kept alive for the whole run)
    n = args.n or (500 if args.quick else 1752)
    count = args.count or (20 if args.quick else 100)
    steps = args.steps or (100 if args.quick else 626)
    sample_starts = args.sample_starts or (5 if args.quick else 20)

    kernels = [k.strip() for k in args.kernel.split(",") if k.strip()]
    for k in kernels:
        if k not in ("chordal", "arc"):
            ap.error(f"--kernel: unknown kernel {k!r} (chordal, arc)")
    time_input = None if args.time_input == "none" else args.time_input
    all_lines, summaries, ok = [], [], True
    for metric in kernels:
        res, lines = run_kernel(args, metric, n, count, steps, sample_starts, time_input)
        all_lines += [f"#### {metric} kernel" + (", phase input and mean-path prior" if time_input else ""), ""] + lines + [""]
        summaries.append(res)
        ok = ok and res["same_poses"] and res["old_same_poses"]
    if args.baseline and len(summaries) > 1:
        all_lines += summary_table(summaries, count, steps)
    text = "\n".join(all_lines)
    print("\n" + text)
    if args.markdown:
        Path(args.markdown).write_text(text + "\n")
    if args.json:
        Path(args.json).write_text(json.dumps(summaries, indent=1))
    return 0 if ok else 1


def summary_table(summaries, count, steps) -> list:
    """One row per kernel: the batched mean rollout against the baseline (best of the rounds)."""
    rev = summaries[0]["baseline"]["rev"]
    out = [f"**Batched `with_std=False`, {count} rollouts × {steps} steps, against `{rev}`** (best of the rounds)", "",
           f"| kernel | model | `{rev}` (s) | today (s) | ratio | `{rev}`, CPU (s) | today, CPU (s) | ratio of CPU times "
           "| max \\|Δ\\| | load (1 min) |", "|---|---|---:|---:|---:|---:|---:|---:|---:|---|"]
    for res in summaries:
        rows = res["baseline"]["rounds"]
        best = lambda who, key: min(r[who][key] for r in rows)  # noqa: E731
        model = "phase + path prior" if res["model"]["time_input"] else "pose only"
        loads = ", ".join(f"{r['load']:.1f}" for r in rows)
        out.append(f"| {res['model']['kernel']} | {model} | {fmt_s(best('baseline', 'batched_s'))} "
                   f"| {fmt_s(best('today', 'batched_s'))} | {best('baseline', 'batched_s') / best('today', 'batched_s'):.1f}× "
                   f"| {fmt_s(best('baseline', 'batched_cpu_s'))} | {fmt_s(best('today', 'batched_cpu_s'))} "
                   f"| {best('baseline', 'batched_cpu_s') / best('today', 'batched_cpu_s'):.1f}× "
                   f"| {max(r['max_abs_diff'] for r in rows):.1e} | {loads} |")
    return out


def run_kernel(args, metric, n, count, steps, sample_starts, time_input):
    """The whole measurement for one kernel; returns (results, markdown lines)."""
    started = time.strftime("%H:%M")
    print(f"bench_rollout — {time.strftime('%Y-%m-%d %H:%M %Z')}; {machine_line()}\n{blas_line()}", flush=True)
    model, info = build_model(n, metric, time_input=time_input)
    print(f"model: n = {n}, kernel {metric}, time input {time_input}, shared fit {info['fit_s']:.1f} s ({info['evaluations']} evaluations, "
          f"{info['infeasible']} infeasible), hyperparameters {info['values']}", flush=True)
    q0, p0 = starts_near(model.starts, count, 0.02, seed=0)

    res = {"model": info, "count": count, "steps": steps, "dt": DT}
    t0 = time.perf_counter()
    batched = rollout(model, q0, p0, steps, with_std=False)
    res["batched_s"] = time.perf_counter() - t0
    res["load_batched"] = os.getloadavg()[0]
    print(f"batched, with_std=False: {res['batched_s']:.2f} s (load {res['load_batched']:.1f})", flush=True)

    t0 = time.perf_counter()
    single = rollout_one_at_a_time(model, q0, p0, steps)
    res["single_s"] = time.perf_counter() - t0
    res["load_single"] = os.getloadavg()[0]
    print(f"one at a time: {res['single_s']:.2f} s (load {res['load_single']:.1f})", flush=True)
    res["max_abs_diff_quat"] = float(np.max(np.abs(batched.quat - single.quat)))
    res["max_abs_diff_position"] = float(np.max(np.abs(batched.position - single.position)))
    res["same_poses"] = max(res["max_abs_diff_quat"], res["max_abs_diff_position"]) <= 1e-9
    res["ratio"] = res["single_s"] / res["batched_s"]
    travelled = np.linalg.norm(batched.position[:, -1] - batched.position[:, 0], axis=1)
    res["median_travel_m"] = float(np.median(travelled))

    old_model = with_old_distance_path(model)
    t0 = time.perf_counter()
    old = rollout(old_model, q0, p0, steps, with_std=False)
    res["old_path_s"] = time.perf_counter() - t0
    res["load_old"] = os.getloadavg()[0]
    res["old_max_abs_diff_quat"] = float(np.max(np.abs(batched.quat - old.quat)))
    res["old_max_abs_diff_position"] = float(np.max(np.abs(batched.position - old.position)))
    res["old_same_poses"] = max(res["old_max_abs_diff_quat"], res["old_max_abs_diff_position"]) <= 1e-9
    res["old_ratio"] = res["old_path_s"] / res["batched_s"]
    print(f"batched through the old distance path: {res['old_path_s']:.2f} s (load {res['load_old']:.1f})", flush=True)

    t0 = time.perf_counter()
    with_std = rollout(model, q0, p0, steps, with_std=True)
    res["batched_std_s"] = time.perf_counter() - t0
    res["std_range"] = [float(np.min(with_std.std)), float(np.max(with_std.std))]
    print(f"batched, with_std=True: {res['batched_std_s']:.2f} s", flush=True)

    t0 = time.perf_counter()
    sampled = rollout(model, q0[:sample_starts], p0[:sample_starts], steps, samples=5, seed=0, with_std=False)
    res["samples_s"] = time.perf_counter() - t0
    res["sample_starts"] = sample_starts
    assert sampled.sample_quat.shape == (sample_starts, 5, steps + 1, 4)
    t0 = time.perf_counter()
    rollout(model, q0[:sample_starts], p0[:sample_starts], steps, with_std=False)
    res["samples_baseline_s"] = time.perf_counter() - t0
    print(f"batched, samples=5 from {sample_starts} starts: {res['samples_s']:.2f} s "
          f"(the same {sample_starts} mean rollouts alone: {res['samples_baseline_s']:.2f} s)", flush=True)

    if args.baseline:
        import tempfile

        from rbgp_cli.io.model_store import load_model, save_model

        with tempfile.TemporaryDirectory() as tmp:
            src = baseline_source(args.baseline, tmp)
            model_path, starts_path = os.path.join(tmp, "model.rbgp"), os.path.join(tmp, "starts.npz")
            save_model(model, model_path)
            loaded, _ = load_model(model_path)
            rollout(loaded, q0[:2], p0[:2], 3, with_std=False)  # warm-up
            rounds = []
            for rnd in range(args.rounds):
                extras = rnd == 0
                np.savez(starts_path, q0=q0, p0=p0, steps=steps, sample_starts=sample_starts, extras=int(extras))
                base = run_baseline(src, model_path, starts_path, os.path.join(tmp, "poses.npz"), args.blas_threads)
                with np.load(os.path.join(tmp, "poses.npz")) as z:
                    bq, bp = z["quat"], z["position"]
                c0, t0 = time.process_time(), time.perf_counter()
                now = rollout(loaded, q0, p0, steps, with_std=False)
                mine = {"batched_s": time.perf_counter() - t0, "batched_cpu_s": time.process_time() - c0}
                if extras:
                    c0, t0 = time.process_time(), time.perf_counter()
                    rollout(loaded, q0, p0, steps, with_std=True)
                    mine["batched_std_s"] = time.perf_counter() - t0
                    mine["batched_std_cpu_s"] = time.process_time() - c0
                    c0, t0 = time.process_time(), time.perf_counter()
                    rollout(loaded, q0[:sample_starts], p0[:sample_starts], steps, samples=5, seed=0, with_std=False)
                    mine["samples_s"] = time.perf_counter() - t0
                    mine["samples_cpu_s"] = time.process_time() - c0
                diff = max(float(np.max(np.abs(now.quat - bq))), float(np.max(np.abs(now.position - bp))))
                rounds.append({"baseline": base, "today": mine, "max_abs_diff": diff, "load": os.getloadavg()[0]})
                print(f"round {rnd + 1}: baseline {args.baseline} {base}, today {mine}, max |Δ| {diff:.1e}", flush=True)
        res["baseline"] = {"rev": args.baseline, "rounds": rounds}

    res["step_profile_B"] = count
    res["step_profile"] = step_profile(model, q0, p0)
    res["step_profile_1"] = step_profile(model, q0[:1], p0[:1], repeats=200)
    res["load_end"] = os.getloadavg()[0]

    kevals = count * steps * n
    lines = [f"Measured {time.strftime('%Y-%m-%d %H:%M %Z')} (run started {started}); {machine_line()}. {blas_line()}.", "",
             f"Model: n = {n} training pairs, {metric} kernel" + (" with the phase input and the mean-path prior" if time_input else "") + f", shared hyperparameters (fit {fmt_s(info['fit_s'])} s, "
             f"{info['evaluations']} evaluations, λ = {info['values']['length_scale']:.3g}, rcond {info['rcond']:.1e}); Δt = {DT} s; median distance travelled {res['median_travel_m']:.2f} m.", "",
             f"| {count} rollouts × {steps} steps | time (s) | per step (ms) |",
             "|---|---:|---:|",
             f"| batched, `with_std=False` | {fmt_s(res['batched_s'])} | {res['batched_s'] / steps * 1e3:.2f} |",
             f"| batched, `with_std=False`, through the old distance path | {fmt_s(res['old_path_s'])} "
             f"| {res['old_path_s'] / steps * 1e3:.2f} |",
             f"| one at a time (`rollout_one_at_a_time`) | {fmt_s(res['single_s'])} | {res['single_s'] / steps * 1e3:.2f} |",
             f"| batched, `with_std=True` | {fmt_s(res['batched_std_s'])} | {res['batched_std_s'] / steps * 1e3:.2f} |",
             f"| batched, `samples=5` from {sample_starts} starts ({sample_starts} mean + {5 * sample_starts} sampled) "
             f"| {fmt_s(res['samples_s'])} | {res['samples_s'] / steps * 1e3:.2f} |",
             f"| batched, the same {sample_starts} starts without samples | {fmt_s(res['samples_baseline_s'])} "
             f"| {res['samples_baseline_s'] / steps * 1e3:.2f} |",
             "",
             f"Batched / one at a time: **{res['ratio']:.1f}× faster** (target ≥ 3×: {'met' if res['ratio'] >= 3 else 'NOT met'}). "
             f"Same poses: max |Δq| = {res['max_abs_diff_quat']:.1e}, max |Δp| = {res['max_abs_diff_position']:.1e} m "
             f"(≤ 1e-9: {'yes' if res['same_poses'] else 'NO'}). `with_std=True` costs "
             f"{res['batched_std_s'] / res['batched_s']:.2f}× the mean-only rollout. Kernel evaluations in the batched run: "
             f"{kevals:.2e} ({kevals / res['batched_s'] / 1e6:.0f} M/s).",
             "",
             f"Batched / batched through the old distance path: **{res['old_ratio']:.1f}× faster** (target ≥ 3×: "
             f"{'met' if res['old_ratio'] >= 3 else 'NOT met'}). Same poses: max |Δq| = {res['old_max_abs_diff_quat']:.1e}, "
             f"max |Δp| = {res['old_max_abs_diff_position']:.1e} m (≤ 1e-9: {'yes' if res['old_same_poses'] else 'NO'}). "
             f"Per sampled trajectory (`samples=5`): {(res['samples_s'] - res['samples_baseline_s']) / (5 * sample_starts) * 1e3:.1f} ms, "
             f"per mean trajectory without std: {res['batched_s'] / count * 1e3:.1f} ms, with std: "
             f"{res['batched_std_s'] / count * 1e3:.1f} ms.",
             "",
             "One step, median (ms): " + ", ".join(
                 f"B = {b}: " + ", ".join(f"{k.removesuffix('_ms')} {v:.3g}" for k, v in prof.items())
                 for b, prof in ((count, res["step_profile"]), (1, res["step_profile_1"]))),
             f"Load average (1 min): {res['load_batched']:.1f} after the batched run, {res['load_single']:.1f} after the "
             f"one-at-a-time run, {res['load_end']:.1f} at the end."]
    if "baseline" in res:
        b = res["baseline"]
        rows = b["rounds"]
        best = lambda who, key: min(r[who][key] for r in rows if key in r[who])  # noqa: E731
        first = rows[0]
        lines += ["", f"**Against the library at `{b['rev']}`** (the same model file and starts; {len(rows)} alternating "
                  "rounds, best time of each; with std and samples in the first round)", "",
                  f"| {count} rollouts × {steps} steps | `{b['rev']}` (s) | today (s) | ratio | `{b['rev']}`, CPU (s) "
                  "| today, CPU (s) | ratio of CPU times |", "|---|---:|---:|---:|---:|---:|---:|"]
        for key, label in (("batched", "batched, `with_std=False`"), ("batched_std", "batched, `with_std=True`"),
                           ("samples", f"`samples=5` from {sample_starts} starts")):
            w, c = key + "_s", key + "_cpu_s"
            lines.append(f"| {label} | {fmt_s(best('baseline', w))} | {fmt_s(best('today', w))} "
                         f"| {best('baseline', w) / best('today', w):.1f}× | {fmt_s(best('baseline', c))} "
                         f"| {fmt_s(best('today', c))} | {best('baseline', c) / best('today', c):.1f}× |")
        per_old = (first["baseline"]["samples_s"]) / (6 * sample_starts) * 1e3
        per_new = (first["today"]["samples_s"]) / (6 * sample_starts) * 1e3
        r = best("baseline", "batched_s") / best("today", "batched_s")
        rc = best("baseline", "batched_cpu_s") / best("today", "batched_cpu_s")
        worst = max(x["max_abs_diff"] for x in rows)
        lines += ["", f"Batched, today / `{b['rev']}`: **{r:.1f}× faster** in wall time, {rc:.1f}× in CPU time "
                  f"(target ≥ 3×: {'met' if r >= 3 else 'NOT met'}); "
                  f"same poses: max |Δ| = {worst:.1e} (≤ 1e-9: {'yes' if worst <= 1e-9 else 'NO'}). Per trajectory of the "
                  f"`samples=5` run (mean + samples): {per_old:.1f} ms at `{b['rev']}`, {per_new:.1f} ms today; a mean "
                  f"trajectory without std: {best('today', 'batched_s') / count * 1e3:.1f} ms today. "
                  "Load average (1 min) after each round: " + ", ".join(f"{x['load']:.1f}" for x in rows) + "."]
    return res, lines


if __name__ == "__main__":
    raise SystemExit(main())
