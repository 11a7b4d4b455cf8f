"""What should a rollout do once it leaves the demonstrations' envelope? (``rbgp rollout --off-data``)

Cross-validation by demonstration exactly as ``rbgp crossval`` (same folds, same scores), but each
fold's model is trained once and rolled out from the held-out starts with every ``--off-data`` mode
(keep, stop, prior), so the modes are compared on the same fits. Prints, per GP choice and mode: the
score / floor ratio, the position RMSE against the held-out demonstrations (m) and how many rollouts
left the training demonstrations' envelope.

    python benchmarks/bench_off_data.py ../shared/realdata/handover_variation_csv --inducing 0 512
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

MODES = ("keep", "stop", "prior")


def _fold(args):
    from threadpoolctl import threadpool_limits

    from rbgp_cli.dynamics.envelope import envelope_from_demos, left_envelope
    from rbgp_cli.dynamics.model import train_model
    from rbgp_cli.dynamics.rollout import rollout
    from rbgp_cli.dynamics.trajectory import Trajectory
    from rbgp_cli.evaluation import evaluate
    from rbgp_cli.evaluation.crossval import trajectory_errors

    train, test, inducing = args
    with threadpool_limits(1):
        t0 = time.perf_counter()
        model = train_model(train, inducing=inducing, jobs=1)
        train_s = time.perf_counter() - t0
        env = envelope_from_demos(train)
        steps = np.array([max(1, int(round(tr.duration / model.dt))) for tr in test])
        q0 = np.array([tr.quat[0] for tr in test])
        p0 = np.array([tr.position[0] for tr in test])
        floor = evaluate(test, train, sample_size="record").mean
        out = {}
        for mode in MODES:
            res = rollout(model, q0, p0, int(steps.max()), with_std=False, durations=steps * model.dt, off_data=mode)
            gen = []
            for b, s in enumerate(steps):
                n = s + 1 if res.ends is None else min(s + 1, int(res.ends[b]) + 1)
                gen.append(Trajectory(res.t[:n], res.quat[b, :n], res.position[b, :n], name=str(b)))
            score = evaluate(gen, train, sample_size="record")
            sp, _, count = trajectory_errors(gen, test, score.steps)
            out[mode] = {"score": score.mean, "floor": floor, "pos_sq": sp, "count": count,
                         "left": left_envelope(gen, env)["count"]}
    return inducing, out, train_s


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder")
    ap.add_argument("--folds", type=int, default=5)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--inducing", type=int, nargs="+", default=[0, 512])
    ap.add_argument("--jobs", type=int, default=2)
    a = ap.parse_args(argv)
    from rbgp_cli.evaluation.crossval import make_folds
    from rbgp_cli.workflows import load_demonstrations

    demos, _, _ = load_demonstrations([a.folder])
    folds = make_folds(len(demos), a.folds, a.seed)
    tasks = []
    for m in a.inducing:
        for idx in folds:
            held = set(idx.tolist())
            tasks.append(([d for i, d in enumerate(demos) if i not in held], [demos[i] for i in idx], m))
    with ProcessPoolExecutor(a.jobs) as ex:
        results = list(ex.map(_fold, tasks))
    print(f"{a.folder}: {len(demos)} demonstrations, {a.folds} folds, seed {a.seed}")
    print(f"{'inducing':>8} {'mode':<6} {'ratio':>6} {'pos_m':>7} {'left':>5} {'train_s':>8}")
    for m in a.inducing:
        rs = [r for r in results if r[0] == m]
        for mode in MODES:
            per = [r[1][mode] for r in rs]
            ratio = np.mean([p["score"] for p in per]) / np.mean([p["floor"] for p in per])
            pos = math.sqrt(sum(p["pos_sq"] for p in per) / sum(p["count"] for p in per))
            left = sum(p["left"] for p in per)
            print(f"{m:>8} {mode:<6} {ratio:6.2f} {pos:7.3f} {left:>5} {np.mean([r[2] for r in rs]):8.1f}")


if __name__ == "__main__":
    main()
