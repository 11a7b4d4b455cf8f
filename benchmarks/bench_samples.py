"""Sampled rollouts against mean rollouts (issue 20: "20 samples per start for 35 starts at most 5×
the mean rollouts' time", measured as a ratio in one run, never asserted in a test).

A model is trained once with the defaults (the 30 handovers of ../shared/realdata when present, else
the bundled sample data). Then, for 35 start poses (the demonstrations' own starts, cycled), each
repetition times

* ``mean``: the mean rollouts with their predictive std (``rollout(starts)``, what ``rbgp rollout``
  does), and
* ``samples``: the same plus 20 sampled rollouts per start (``rollout(starts, samples=20)``: each one
  coherent draw of the demonstrations' deviation process, docs/method.md §11),

alternating the two so that machine load falls on both alike; the ratio of the medians is printed.

    python benchmarks/bench_samples.py [--repeats 5] [--starts 35] [--samples 20] [--data DIR]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import machine_line  # noqa: E402

import rbgp_cli as rbgp  # noqa: E402

REALDATA = Path(__file__).resolve().parents[2] / "shared" / "realdata" / "handover_object_csv"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--starts", type=int, default=35)
    ap.add_argument("--samples", type=int, default=20)
    ap.add_argument("--data", type=Path, default=REALDATA if REALDATA.is_dir() else rbgp.SAMPLE_DATA / "csv")
    args = ap.parse_args(argv)
    demos = rbgp.read_demonstrations(args.data)
    t0 = time.perf_counter()
    gp = rbgp.RigidBodyGP().fit(demos)
    train_s = time.perf_counter() - t0
    starts = [demos[i % len(demos)] for i in range(args.starts)]
    gp.rollout(starts[:2], samples=2)  # warm-up (imports, caches)
    times = {"mean": [], "samples": []}
    for _ in range(args.repeats):
        for kind in ("mean", "samples"):
            t = time.perf_counter()
            out = gp.rollout(starts, samples=args.samples if kind == "samples" else 0)
            times[kind].append(time.perf_counter() - t)
    assert out.sample_position is not None and out.sample_position.shape[:2] == (args.starts, args.samples)
    med = {k: statistics.median(v) for k, v in times.items()}
    print(machine_line())
    print(f"data: {args.data} ({len(demos)} demonstrations), trained with the defaults in {train_s:.1f} s")
    print(f"{args.starts} starts, median of {args.repeats}: mean rollouts {med['mean']:.3f} s; "
          f"with {args.samples} samples per start ({args.starts * args.samples} sampled trajectories) {med['samples']:.3f} s")
    ratio = med["samples"] / med["mean"]
    print(f"samples / mean: {ratio:.2f}x (target <= 5x: {'met' if ratio <= 5 else 'NOT met'})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
