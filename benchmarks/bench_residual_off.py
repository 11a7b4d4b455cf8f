"""What skipping the GP at g = 0 saves (``MotionModel.residual_off``: the residual's mean is multiplied by 0,
so it is not evaluated; docs/method.md §7, "The residual's gain").

A model file with g = 0 (``rbgp train`` at the defaults chooses it on every real set) and the demonstrations
it was trained on; each job runs on the model as it is and on the same model with its GP evaluated and
multiplied by 0 (the code before the skip), alternating ``--rounds`` times; printed: the median CPU and wall
seconds of each, their ratio (before / after) and the largest difference of the results (0: the same
numbers). Single-threaded BLAS, as rollouts run.

Jobs: the mean rollout from every demonstration's start for its own duration with 20 path samples and the
bands (``rbgp rollout --from-demos DIR --each-duration --samples 20 --no-std``), the same with the latent
std along the mean (the default of ``rbgp rollout``: the std is the GP's, so it is still evaluated), the
rollouts conditioned on each demonstration's own goal (``--goal``, 20 samples), and each demonstration's
continuation from its first half (``rbgp rollout --given``, 20 samples).

    .venv/bin/python benchmarks/bench_residual_off.py MODEL.rbgp ../shared/realdata/handover_object_csv
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("model")
    ap.add_argument("data")
    ap.add_argument("--body", default=None)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--samples", type=int, default=20)
    args = ap.parse_args(argv)

    from threadpoolctl import threadpool_limits

    from rbgp_cli.dynamics.anticipation import Anticipator
    from rbgp_cli.dynamics.model import MotionModel
    from rbgp_cli.dynamics.rollout import rollout_conditioned, rollout_for
    from rbgp_cli.io.model_store import load_model
    from rbgp_cli.io.options import ReadOptions
    from rbgp_cli.workflows import load_demonstrations

    class Evaluated(MotionModel):  # the code before: the GP evaluated and multiplied by g = 0
        @property
        def residual_off(self) -> bool:
            return False

    model, _ = load_model(args.model)
    if not model.residual_off:
        raise SystemExit(f"{args.model}: the residual's gain is {model.residual_gain:g}, not 0: nothing is skipped")
    before = replace(model)
    before.__class__ = Evaluated
    demos, _, _ = load_demonstrations([args.data], ReadOptions(body=args.body) if args.body else None)
    q0 = np.array([t.quat[0] for t in demos])
    p0 = np.array([t.position[0] for t in demos])
    qg = np.array([t.quat[-1] for t in demos])
    pg = np.array([t.position[-1] for t in demos])
    dur = [t.duration for t in demos]
    K = args.samples

    def given(m):
        ant = Anticipator(m.paths, m)
        out = []
        for i, t in enumerate(demos):
            k = max(2, len(t.t) // 2)
            c = ant.continuation(t.t[:k], t.quat[:k], t.position[:k], samples=K, seed=i)
            out.append(c.position)
        return np.concatenate(out)

    jobs = {
        "rollout, samples, bands (--no-std)": lambda m: rollout_for(m, q0, p0, dur, with_std=False, samples=K).position,
        "rollout with the std (default)": lambda m: rollout_for(m, q0, p0, dur, with_std=True, samples=K).position,
        "rollout to each goal (--goal)": lambda m: rollout_conditioned(m, q0, p0, goal_quat=qg, goal_position=pg,
                                                                      durations=dur, samples=K).position,
        "continuation of the first half (--given)": given,
    }
    print(f"{args.model}: g = {model.residual_gain:g}, {len(model.gp.X)} training rows, {len(demos)} starts, "
          f"{K} samples each; medians of {args.rounds} alternating rounds")
    print(f"{'job':44s} {'CPU before':>10s} {'after':>7s} {'ratio':>6s} {'wall before':>11s} {'after':>7s} {'ratio':>6s}  max |diff|")
    with threadpool_limits(1):
        for name, job in jobs.items():
            t = {"before": [], "after": []}
            diff = 0.0
            for _ in range(args.rounds):
                out = {}
                for label, m in (("before", before), ("after", model)):
                    c0, w0 = time.process_time(), time.perf_counter()
                    out[label] = job(m)
                    t[label].append((time.process_time() - c0, time.perf_counter() - w0))
                diff = max(diff, float(np.max(np.abs(out["before"] - out["after"]))))
            cb, wb = np.median(t["before"], axis=0)
            ca, wa = np.median(t["after"], axis=0)
            print(f"{name:44s} {cb:10.2f} {ca:7.2f} {cb / ca:6.2f} {wb:11.2f} {wa:7.2f} {wb / wa:6.2f}  {diff:.1e}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
