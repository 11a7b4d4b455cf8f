"""Rollout benchmark: 100 trajectories × 626 steps from a model with 1752 training pairs, batched vs one at a time.

    .venv/bin/python benchmarks/bench_rollout.py            # the full run (a few minutes on a busy machine)
    .venv/bin/python benchmarks/bench_rollout.py --quick    # 20 rollouts × 100 steps from n = 500

Model: a shared-hyperparameter exact GP (``fit_gp(..., shared=True, restarts=1)``, the paper's arc
kernel unless ``--kernel chordal``) on n synthetic training pairs (benchmarks/_common.py: random
poses, outputs a smooth velocity field ξ = (ω, v) plus noise), wrapped in a ``MotionModel`` with the
axis-angle representation and Δt = 0.01 s. Starts: ``starts_near`` (spread 0.02 m, ~0.007 rad)
around 10 random poses.

Measured in one run:

* batched: ``rollout(model, q0, p0, steps, with_std=False)`` — all trajectories share one B × n
  kernel block per step (MATH.md §8);
* one at a time: ``rollout_one_at_a_time(model, q0, p0, steps)``;
* both must give the same poses (max abs difference of quaternions and positions ≤ 1e-9);
* batched with ``with_std=True`` (adds one triangular solve per step);
* batched Monte Carlo: ``samples=5`` from fewer starts (``--sample-starts``, default 20);
* where one batched step's time goes (distance block, kernel, mean, integration step), median over
  many steps.

Target: batched ≥ 3× faster than one at a time.
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

from _common import blas_line, fmt_s, limit_blas_threads, machine_line, median_time, synthetic_data, synthetic_poses  # noqa: E402

from rbgp_cli.dynamics.model import MotionModel  # noqa: E402
from rbgp_cli.dynamics.representations import AxisAngle  # noqa: E402
from rbgp_cli.dynamics.rollout import rollout, rollout_one_at_a_time, starts_near  # noqa: E402
from rbgp_cli.gp.exact import fit_gp  # noqa: E402
from rbgp_cli.kernels import SquaredExponential  # noqa: E402

DT = 0.01


def build_model(n: int, metric: str, seed: int = 0):
    """A MotionModel on n synthetic training pairs (shared hyperparameters, one start). Returns (model, info)."""
    q, X, Y = synthetic_data(n, seed=seed)
    t0 = time.perf_counter()
    gp = fit_gp(X, Y, SquaredExponential(metric, 3, 0.7), restarts=1, seed=seed, shared=True)
    fit_s = time.perf_counter() - t0
    qb, Xb = synthetic_poses(10, seed=seed + 5)
    base = np.concatenate([qb, Xb[:, 3:]], axis=1)
    model = MotionModel(AxisAngle(), gp, DT, base, np.full(len(base), 6.26))
    f = gp.fits[0]
    info = {"n": n, "kernel": metric, "fit_s": fit_s, "evaluations": f.n_evaluations, "infeasible": f.n_infeasible,
            "values": {k: float(v) for k, v in f.values.items()}, "jitter": f.jitter}
    return model, info


def step_profile(model, q0, p0, repeats: int = 50) -> dict:
    """Median time of the parts of one batched step (B = len(q0)) at the start poses."""
    gp, rep = model.gp, model.representation
    state = rep.state_from_pose(q0, p0)
    fit = gp.fits[0]
    out = {}
    out["predict_mean_ms"] = median_time(lambda: gp.predict(state), repeats)[0] * 1e3
    out["predict_mean_std_ms"] = median_time(lambda: gp.predict(state, return_std=True), repeats)[0] * 1e3
    pre = gp.kernel.precompute(state, gp.X)
    out["distance_ms"] = median_time(lambda: gp.kernel.precompute(state, gp.X), repeats)[0] * 1e3
    out["kernel_ms"] = median_time(lambda: gp.kernel.gram(pre, fit.values), repeats)[0] * 1e3
    Ks, _ = gp.kernel.gram(pre, fit.values)
    alpha = gp._alpha[0] if hasattr(gp, "_alpha") else None
    if alpha is not None:
        out["mean_matmul_ms"] = median_time(lambda: Ks @ alpha, repeats)[0] * 1e3
    mu = gp.predict(state)
    out["integration_ms"] = median_time(lambda: rep.step(state, mu, DT), repeats)[0] * 1e3
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=None, help="training pairs (default 1752; --quick: 500)")
    ap.add_argument("--count", type=int, default=None, help="rollouts (default 100; --quick: 20)")
    ap.add_argument("--steps", type=int, default=None, help="steps per rollout (default 626; --quick: 100)")
    ap.add_argument("--sample-starts", type=int, default=None, help="starts for the samples=5 run (default 20)")
    ap.add_argument("--kernel", choices=("arc", "chordal"), default="arc")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--json", default=None)
    ap.add_argument("--markdown", default=None)
    ap.add_argument("--blas-threads", type=int, default=None,
                    help="limit numpy's and scipy's OpenBLAS (and OpenMP) to this many threads (default: leave as is)")
    args = ap.parse_args(argv)
    _limits = limit_blas_threads(args.blas_threads)  # noqa: F841 (kept alive for the whole run)
    n = args.n or (500 if args.quick else 1752)
    count = args.count or (20 if args.quick else 100)
    steps = args.steps or (100 if args.quick else 626)
    sample_starts = args.sample_starts or (5 if args.quick else 20)

    started = time.strftime("%H:%M")
    print(f"bench_rollout — {time.strftime('%Y-%m-%d %H:%M %Z')}; {machine_line()}\n{blas_line()}", flush=True)
    model, info = build_model(n, args.kernel)
    print(f"model: n = {n}, kernel {args.kernel}, shared fit {info['fit_s']:.1f} s ({info['evaluations']} evaluations, "
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

    res["step_profile_B"] = count
    res["step_profile"] = step_profile(model, q0, p0)
    res["step_profile_1"] = step_profile(model, q0[:1], p0[:1], repeats=200)
    res["load_end"] = os.getloadavg()[0]

    kevals = count * steps * n
    lines = [f"Measured {time.strftime('%Y-%m-%d %H:%M %Z')} (run started {started}); {machine_line()}. {blas_line()}.", "",
             f"Model: n = {n} training pairs, {args.kernel} kernel, shared hyperparameters (fit {fmt_s(info['fit_s'])} s, "
             f"{info['evaluations']} evaluations); Δt = {DT} s; median distance travelled {res['median_travel_m']:.2f} m.", "",
             f"| {count} rollouts × {steps} steps | time (s) | per step (ms) |",
             "|---|---:|---:|",
             f"| batched, `with_std=False` | {fmt_s(res['batched_s'])} | {res['batched_s'] / steps * 1e3:.2f} |",
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
             "One step, median (ms): " + ", ".join(
                 f"B = {b}: " + ", ".join(f"{k.removesuffix('_ms')} {v:.3g}" for k, v in prof.items())
                 for b, prof in ((count, res["step_profile"]), (1, res["step_profile_1"]))),
             f"Load average (1 min): {res['load_batched']:.1f} after the batched run, {res['load_single']:.1f} after the "
             f"one-at-a-time run, {res['load_end']:.1f} at the end."]
    text = "\n".join(lines)
    print("\n" + text)
    if args.markdown:
        Path(args.markdown).write_text(text + "\n")
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=1))
    return 0 if res["same_poses"] else 1


if __name__ == "__main__":
    raise SystemExit(main())
