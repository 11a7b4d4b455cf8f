#!/usr/bin/env python3
"""Make ``docs/figure.png``: the rigid-body GP vs the Euler GP on the bundled sample data, like the
paper's Fig. 4/5 (deterministic: every seed is fixed).

1. Read the nine demonstrations in ``sample_data/csv``.
2. Train an axis-angle model (the paper's rigid-body GP) and an Euler-angle model with rbgp's
   defaults (as ``rbgp demo`` does; :mod:`rbgp_cli.dynamics.defaults`), seed 0.
3. Roll out COUNT trajectories from each model, from the same starts near the demonstrations'
   (``starts_near``, spread 0.02 m, seed 0), each as long as the demonstrations' median duration
   (``workflows.generate_like_paper``).
4. Evaluate both sets against the demonstrations (Bhattacharyya distance per step, diagonal
   covariances, MATH.md §9) and draw the figure (``viz.plots.plot_evaluation``): 1200 × 1000 px, each
   set's per-step mean ± 2σ band, at most 20 of its rollouts as lines, the distance per step.

Run:  python scripts/make_figure.py [--out docs/figure.png] [--count 100]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from rbgp_cli import workflows  # noqa: E402
from rbgp_cli.dynamics.model import train_model  # noqa: E402
from rbgp_cli.evaluation import evaluate  # noqa: E402
from rbgp_cli.viz.plots import plot_evaluation  # noqa: E402

COUNT = 100
SETTINGS = dict(seed=0)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(ROOT / "docs" / "figure.png"))
    ap.add_argument("--count", type=int, default=COUNT)
    args = ap.parse_args(argv)

    demos, _, _ = workflows.load_demonstrations([str(ROOT / "sample_data" / "csv")])
    generated, results, points = {}, {}, {}
    for rep in ("axis-angle", "euler"):
        t0 = time.perf_counter()
        model = train_model(demos, representation=rep, **SETTINGS)
        t1 = time.perf_counter()
        generated[rep] = workflows.generate_like_paper(model, demos, count=args.count, spread=0.02, seed=0).trajectories()
        results[rep] = evaluate(generated[rep], demos)
        points[rep] = model.summary["points"]
        print(f"{rep}: {points[rep]} training points, trained in {t1 - t0:.1f} s, {args.count} rollouts in "
              f"{time.perf_counter() - t1:.1f} s; Bhattacharyya mean {results[rep].mean:.3f} "
              f"(rotation {results[rep].rotation:.3f}, translation {results[rep].translation:.3f})", file=sys.stderr)

    title = (f"Sample data ({len(demos)} shoe-passing demonstrations): {args.count} rollouts each, "
             f"mean Bhattacharyya distance rigid-body GP {results['axis-angle'].mean:.2f}, "
             f"Euler GP {results['euler'].mean:.2f}\n"
             f"(both trained with rbgp's defaults on {points['axis-angle']} points, seed 0; "
             f"starts near the demonstrations', spread 0.02 m)")
    plot_evaluation(args.out, results["axis-angle"], generated["axis-angle"], demos, compare=generated["euler"],
                    labels=("rigid-body GP (axis-angle)", "Euler GP"), title=title)
    print(f"wrote {args.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
