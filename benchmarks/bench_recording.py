#!/usr/bin/env python3
"""How long does ``record_rollout`` (``rbgp rollout --rerun``) take next to the rollout it records?

1. Recording: ``record_rollout`` of a synthetic RolloutResult (no GP) with 100 trajectories × 626
   samples and the predictive std of 6 outputs, written to a temporary directory. Reported: the
   first call in the process (includes ``import rerun`` and rerun's one-time set-up on the first
   logged message) and the median of the following calls.
2. Rollout: a model trained on ``sample_data/csv`` with about 500 points (10 % subsample capped at
   500, seed 0, one shared set of hyperparameters, one optimiser start: training is not timed), then
   one batched rollout of the same size (100 starts near the demonstrations', 625 steps,
   ``with_std=False``). Its result is recorded too, to check that real data costs the same.
3. The ratio recording / rollout.

Not part of the test suite. Run:  python benchmarks/bench_recording.py [--repeats 3]
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from rbgp_cli.dynamics.rollout import RolloutResult, rollout, starts_near  # noqa: E402
from rbgp_cli.geometry.so3 import exp_quat, quat_make_continuous  # noqa: E402

B, SAMPLES = 100, 626
OUTPUTS = ("wx", "wy", "wz", "vx", "vy", "vz")


def synthetic_result(seed: int = 0) -> RolloutResult:
    """100 smooth random motions × 626 samples at 179 Hz, with made-up stds (no GP)."""
    rng = np.random.default_rng(seed)
    t = np.arange(SAMPLES) / 179.0
    s = t / t[-1]
    start = rng.normal(0.0, 0.05, (B, 1, 3))
    pos = start + np.stack([0.6 * s, 0.15 * np.sin(np.pi * s), -s], axis=1)[None] + 0.01 * rng.normal(size=(B, 1, 3)) * s[None, :, None]
    rv = rng.normal(0.0, 0.2, (B, 1, 3)) + np.array([0.2, 0.1, 2.5])[None, None] * s[None, :, None]
    quat = quat_make_continuous(exp_quat(rv), axis=-2)
    std = np.abs(rng.normal(0.05, 0.01, (B, 1, len(OUTPUTS)))) * (1 + s)[None, :, None]
    return RolloutResult(t=t, quat=quat, position=pos, std=std, output_names=OUTPUTS)


def time_recording(res, directory, repeats: int) -> tuple[float, float, int]:
    """(first call s, median of ``repeats`` further calls s, file size bytes)."""
    from rbgp_cli.viz.recording import record_rollout

    path = os.path.join(directory, "rollout.rrd")
    t0 = time.perf_counter()
    record_rollout(path, res)
    first = time.perf_counter() - t0
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        record_rollout(path, res)
        times.append(time.perf_counter() - t0)
    return first, statistics.median(times), os.path.getsize(path)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)
    load = ", ".join(f"{x:.2f}" for x in os.getloadavg())
    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}; "
          f"load average at start: {load}")

    with tempfile.TemporaryDirectory() as tmp:
        synth = synthetic_result()
        first, warm, size = time_recording(synth, tmp, args.repeats)
        print(f"record_rollout, synthetic {B} x {SAMPLES} (+ std of {len(OUTPUTS)} outputs): first call {first:.3f} s "
              f"(includes import rerun), then median {warm:.3f} s over {args.repeats}; file {size / 1e6:.1f} MB")

        from rbgp_cli import workflows
        from rbgp_cli.dynamics.model import train_model

        demos, _, _ = workflows.load_demonstrations([str(ROOT / "sample_data" / "csv")])
        t0 = time.perf_counter()
        model = train_model(demos, subsample=0.1, max_points=500, seed=0, shared=True, restarts=1)
        print(f"model: axis-angle, {model.summary['points']} training points, shared hyperparameters "
              f"(trained in {time.perf_counter() - t0:.1f} s, not part of the comparison)")
        base = np.array([np.concatenate([t.quat[0], t.position[0]]) for t in demos])
        q0, p0 = starts_near(base, B, 0.02, seed=0)
        t0 = time.perf_counter()
        res = rollout(model, q0, p0, SAMPLES - 1, with_std=False)
        roll = time.perf_counter() - t0
        print(f"batched rollout {B} x {SAMPLES} samples, with_std=False: {roll:.3f} s")
        _, warm_real, size_real = time_recording(res, tmp, args.repeats)
        print(f"record_rollout of that rollout (no std): median {warm_real:.3f} s; file {size_real / 1e6:.1f} MB")

    print(f"ratio recording / rollout: {warm / roll:.2f} (synthetic, with std, warm), "
          f"{first / roll:.2f} (first call), {warm_real / roll:.2f} (the rollout's own result)")
    load = ", ".join(f"{x:.2f}" for x in os.getloadavg())
    print(f"load average at end: {load}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
