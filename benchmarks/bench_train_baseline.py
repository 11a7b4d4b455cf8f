"""`rbgp train` at the defaults, this checkout against an earlier revision, alternated in one run.

Issue 20's target: training at the defaults takes at most 2x the time it took when the issue was filed
(the variation model, the start map, the calibration and the noise scale all run inside `train`). The
baseline is the source tree of ``--baseline`` (default: the parent of the first commit of that issue's
work, 4a0998b^), unpacked with ``git archive`` into a temporary folder and run with ``PYTHONPATH``
pointing there, in the same virtual environment; this checkout runs the same way. Each repeat trains
once with each, in alternating order, so that a change in the machine's load reaches both.

    .venv/bin/python benchmarks/bench_train_baseline.py
    .venv/bin/python benchmarks/bench_train_baseline.py --demos ../shared/realdata/hand_raise_csv --repeats 5

Reported: the median wall time of the whole command (interpreter start, imports, reading, the fit,
writing the model) of each tree, and the ratio this / baseline.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
sys.path.insert(0, str(HERE))

from _common import machine_line  # noqa: E402

#: The parent of the first commit of issue 20's work: the code as it was when the issue was filed.
BASELINE = "4a0998b^"
TARGET = 2.0


def _unpack(rev: str, folder: Path) -> str:
    """The tree of ``rev`` in ``folder``; returns the full commit id."""
    commit = subprocess.run(["git", "-C", str(REPO), "rev-parse", rev], check=True, capture_output=True,
                            text=True).stdout.strip()
    archive = subprocess.run(["git", "-C", str(REPO), "archive", commit, "rbgp_cli"], check=True,
                             capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(folder)], input=archive, check=True)
    return commit


def _train(tree: Path, demos: list[str], out: Path) -> float:
    env = {**os.environ, "PYTHONPATH": str(tree)}
    t0 = time.perf_counter()
    run = subprocess.run([sys.executable, "-m", "rbgp_cli", "train", *demos, "-o", str(out), "-q"], env=env,
                         capture_output=True, text=True)
    seconds = time.perf_counter() - t0
    if run.returncode != 0:
        raise SystemExit(f"rbgp train failed in {tree}: {run.stderr.strip()[-400:]}")
    return seconds


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--demos", nargs="+", default=[str(REPO.parent / "shared/realdata/handover_object_csv")])
    ap.add_argument("--baseline", default=BASELINE, help="the revision to compare with (default %(default)s)")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="rbgp_baseline_") as tmp:
        tmp = Path(tmp)
        (tmp / "base").mkdir()
        commit = _unpack(args.baseline, tmp / "base")
        trees = {"this checkout": REPO, f"baseline {commit[:7]}": tmp / "base"}
        times: dict[str, list[float]] = {name: [] for name in trees}
        for r in range(args.repeats):
            order = list(trees) if r % 2 == 0 else list(trees)[::-1]
            for name in order:
                times[name].append(_train(trees[name], args.demos, tmp / "m.rbgp"))
    med = {name: statistics.median(v) for name, v in times.items()}
    print(machine_line())
    print(f"data: {' '.join(args.demos)}; rbgp train at the defaults, {args.repeats} alternated repeats")
    for name, v in times.items():
        print(f"  {name}: median {med[name]:.1f} s ({', '.join(f'{x:.1f}' for x in v)})")
    this, base = med["this checkout"], med[f"baseline {commit[:7]}"]
    ratio = this / base
    print(f"this / baseline: {ratio:.2f}x (target <= {TARGET:g}x: {'met' if ratio <= TARGET else 'NOT met'})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
