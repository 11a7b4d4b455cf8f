"""Peak memory of ``rbgp train`` on a big pose CSV, as a ratio to the file's size.

The file: ``t,x,y,z,qx,qy,qz,qw``, 10⁶ rows (``--rows``) of the seeded smooth motion at 100 Hz that
``bench_reading.py`` writes (about 86 bytes a row, 86 MB), in a temporary folder. Each run is a
fresh ``rbgp train FILE -o MODEL -q`` process (the console script, so the imports count too), with
the default options unless ``--args`` says otherwise; its peak is ``ru_maxrss`` of the waited
children (the largest of the command and its worker processes). Also measured in the same run, as
peers: ``rbgp --version`` (the interpreter and the command line's imports: the floor), and a fresh
Python that reads the file with ``pandas.read_csv`` (what a user's own script would hold).

    .venv/bin/python benchmarks/bench_memory.py                 # 10⁶ rows: about a minute
    .venv/bin/python benchmarks/bench_memory.py --rows 200000   # quicker
    .venv/bin/python benchmarks/bench_memory.py --args "--jobs 1"
"""

from __future__ import annotations

import argparse
import os
import resource
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import machine_line  # noqa: E402
from bench_reading import write_pose_csv  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def peak_mb(cmd: list[str], cwd: Path) -> tuple[float, float]:
    """(peak RSS in MiB of the process and its children, wall seconds) of one command run to its end.

    ``ru_maxrss`` of RUSAGE_CHILDREN is the largest peak among the waited-for descendants so far, so
    each command runs in its own ``python`` wrapper that reports only its own children."""
    code = ("import resource, subprocess, sys, time\n"
            "t = time.perf_counter()\n"
            "rc = subprocess.run(sys.argv[1:], stdout=subprocess.DEVNULL).returncode\n"
            "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss, time.perf_counter() - t, rc)\n")
    out = subprocess.run([sys.executable, "-c", code, *cmd], cwd=cwd, capture_output=True, text=True, check=True)
    kb, seconds, rc = out.stdout.split()
    if int(rc) != 0:
        raise SystemExit(f"{' '.join(cmd)} failed with exit code {rc}:\n{out.stderr}")
    return int(kb) / 1024, float(seconds)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rows", type=int, default=1_000_000)
    ap.add_argument("--args", default="", help="extra options for rbgp train (quoted)")
    args = ap.parse_args(argv)
    rbgp = str(Path(sys.executable).with_name("rbgp"))
    print(machine_line())
    with tempfile.TemporaryDirectory(prefix="rbgp-bench-memory-") as tmp:
        tmp = Path(tmp)
        csv = tmp / "big.csv"
        t0 = time.perf_counter()
        write_pose_csv(csv, args.rows)
        size_mb = os.path.getsize(csv) / 2**20
        print(f"file: {args.rows} rows, {size_mb:.1f} MiB (written in {time.perf_counter() - t0:.1f} s)")
        floor, _ = peak_mb([rbgp, "--version"], tmp)
        pandas, pandas_s = peak_mb([sys.executable, "-c", "import pandas, sys; pandas.read_csv(sys.argv[1])", str(csv)], tmp)
        train, train_s = peak_mb([rbgp, "train", str(csv), "-o", str(tmp / "m.rbgp"), "-q", *shlex.split(args.args)], tmp)
    print(f"{'run':<40} {'peak RSS MiB':>12} {'/ file size':>12} {'seconds':>8}")
    for name, mb, s in (("rbgp --version (imports)", floor, None), ("python: pandas.read_csv(file)", pandas, pandas_s),
                        (f"rbgp train file {args.args}".strip(), train, train_s)):
        print(f"{name:<40} {mb:12.1f} {mb / size_mb:12.2f} {'' if s is None else f'{s:8.1f}'}")
    print(f"ratio peak RSS / file size of rbgp train: {train / size_mb:.2f} (goal: below 3)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
