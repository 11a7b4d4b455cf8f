"""``rbgp demo``: the main job on the bundled sample data, for each representation:
train (rbgp's defaults, :mod:`rbgp_cli.dynamics.defaults`) → 100 rollouts from unseen starts near
the demonstrations' → Bhattacharyya distance to the demonstrations (docs/method.md §9)."""

from __future__ import annotations

import os
import time
from pathlib import Path

from rbgp_cli.errors import InputError

__all__ = ["run_demo", "find_sample_data"]


def find_sample_data() -> Path:
    """``./sample_data/csv`` if it exists (running from a checkout), else the copy beside the package."""
    for base in (Path.cwd() / "sample_data", Path(__file__).resolve().parents[1] / "sample_data"):
        if (base / "csv").is_dir():
            return base / "csv"
    raise InputError("sample_data/csv not found", hint="run rbgp demo from the repository's top folder")


def run_demo(out, *, count: int = 100, representations=("axis-angle", "euler", "quaternion"), data=None,
             seed: int = 0, quick: bool = False, progress=None) -> dict:
    """Train, roll out and evaluate each representation; write models, rollouts and per-step scores to
    ``out``; return the scores as plain data.

    ``quick`` trains on at most 200 points with one shared set of hyperparameters (a smoke test of
    the whole path in seconds; the scores are then not the default ones)."""
    from rbgp_cli import workflows
    from rbgp_cli.cli.report import write_per_step
    from rbgp_cli.dynamics.rollout import start_vectors, starts_near
    from rbgp_cli.evaluation import evaluate
    from rbgp_cli.io.atomic import atomic_open
    from rbgp_cli.io.csv import write_trajectories_csv
    from rbgp_cli.progress import as_progress

    import numpy as np

    progress = as_progress(progress)

    if os.path.exists(out) and not os.path.isdir(out):
        raise InputError("is a file, not a folder", path=str(out), hint="give a folder for the demo's outputs as out", param="out")
    try:
        os.makedirs(out, exist_ok=True)  # before the work, which fills it
    except OSError as exc:
        raise InputError(f"cannot create the folder: {exc.strerror or exc}", path=str(out)) from None
    if not os.access(out, os.W_OK):
        raise InputError("the output folder is not writable", path=str(out))
    data = Path(data) if data else find_sample_data()
    demos, _, _ = workflows.load_demonstrations([str(data)])
    base = start_vectors(demos)
    q0, p0 = starts_near(base, count, workflows.PAPER_START_SPREAD, seed=seed)
    duration = float(np.median([t.duration for t in demos]))
    scores = {"data": str(data), "demonstrations": len(demos), "rollouts": count, "quick": quick, "representations": {}}
    with progress.task("demo", total=len(representations), unit="representations") as task:
        for rep in representations:
            task.update(status=rep)
            progress(f"[{rep}] training")
            t0 = time.perf_counter()
            extra = {"max_points": 200, "shared": True, "restarts": 1} if quick else {}
            model, _, _ = workflows.train_from_files([str(data)], os.path.join(out, f"{rep}.rbgp"), representation=rep,
                                                     seed=seed, progress=progress, **extra)
            t1 = time.perf_counter()
            progress(f"[{rep}] {count} rollouts of {duration:.2f} s")
            res = workflows.rollout_model(model, q0, p0, duration=duration, with_std=False, progress=progress)
            t2 = time.perf_counter()
            gen = res.trajectories()
            write_trajectories_csv(gen, os.path.join(out, f"{rep}_rollouts.csv"))
            result = evaluate(gen, demos)
            with atomic_open(os.path.join(out, f"{rep}_per_step.csv"), "w") as fh:
                write_per_step(result, fh)
            entry = result.to_dict()
            entry["train_seconds"] = t1 - t0
            entry["rollout_seconds"] = t2 - t1
            entry["training_points"] = model.summary["points"]
            scores["representations"][rep] = entry
            b = entry["bhattacharyya"]
            progress(f"[{rep}] Bhattacharyya mean {b['mean']:.3f} (rotation {b['rotation']:.3f}, translation {b['translation']:.3f})")
            task.advance()
    return scores
