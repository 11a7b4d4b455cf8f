#!/usr/bin/env python3
"""Accuracy of shared versus per-output hyperparameters (docs/method.md §7 asks us to document it).

Leave-one-demonstration-out on sample_data/csv: train on 8 demonstrations (10 % subsample, seed 0),
predict the velocities of the held-out one, report the RMSE per output (rad/s, m/s) relative to the
held-out velocities' RMS, and the training time, for both modes and each representation's kernel.

Run:  .venv/bin/python benchmarks/accuracy_shared.py [--folds 3]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from rbgp_cli.dynamics.model import train_model  # noqa: E402
from rbgp_cli.dynamics.prepare import prepare_all  # noqa: E402
from rbgp_cli.io.options import ReadOptions  # noqa: E402
from rbgp_cli.io.read import read_demonstrations  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--folds", type=int, default=3, help="how many demonstrations to hold out in turn")
    ap.add_argument("--representation", default="axis-angle")
    args = ap.parse_args()
    demos, _ = prepare_all(read_demonstrations([str(ROOT / "sample_data" / "csv")], ReadOptions()))
    rows = {False: [], True: []}
    times = {False: 0.0, True: 0.0}
    for k in range(args.folds):
        train = [d for i, d in enumerate(demos) if i != k]
        held = demos[k]
        for shared in (False, True):
            t0 = time.perf_counter()
            model = train_model(train, representation=args.representation, shared=shared, seed=0)
            times[shared] += time.perf_counter() - t0
            X, Y, _ = model.representation.training_pairs(held)
            pred = model.gp.predict(X)
            rmse = np.sqrt(np.mean((pred - Y) ** 2, axis=0))
            rows[shared].append(rmse / np.sqrt(np.mean(Y**2, axis=0)))
    names = model.representation.output_names
    print(f"held-out relative RMSE ({args.representation}, {args.folds} folds, mean over folds)")
    print("| mode | " + " | ".join(names) + " | mean | train s (total) |")
    print("|---|" + "---|" * (len(names) + 2))
    for shared in (False, True):
        r = np.mean(rows[shared], axis=0)
        print(f"| {'shared' if shared else 'per-output'} | " + " | ".join(f"{v:.3f}" for v in r)
              + f" | {r.mean():.3f} | {times[shared]:.1f} |")


if __name__ == "__main__":
    main()
