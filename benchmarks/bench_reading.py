"""Reading a big pose CSV: peak memory (RSS) and rows per second, rbgp against peers in the same run.

The file: ``t,x,y,z,qx,qy,qz,qw``, 10⁶ rows (``--rows``) of a seeded smooth motion at 100 Hz, positions in
metres with 7 decimals, unit quaternions with 8 (about 86 bytes a row, 86 MB: the size of the file in
the issue). Every reader runs in a fresh Python process that first imports numpy, scipy and pandas (and
the reader), so "above imports" is what reading the file costs; peak RSS is ``ru_maxrss`` of that
process, time the wall time of the read alone (median over ``--repeat`` processes).

Readers:

* rbgp, this checkout: ``rbgp_cli.io.read.read_file(path)`` (what ``rbgp train FILE`` reads with);
* rbgp, the same file piped into stdin: ``read_stream`` of a pipe (``rbgp train - < FILE``);
* rbgp before this change (``--peer-rev``, default 04386b1, the commit before the big-file reader):
  the same call on that revision's ``rbgp_cli`` (``git archive``), the peer the speed-up is measured
  against;
* ``pandas.read_csv(path)``: every column, default options (what a user's own script would do);
* ``pandas.read_csv(path, usecols=..., dtype=float64)``: the floor of the approach (no checks, no
  trajectories).

The rbgp readers also report a checksum of the arrays they return; the run says whether this checkout
and the peer revision read identical values.

    .venv/bin/python benchmarks/bench_reading.py                  # 10⁶ rows, 3 runs each: about 1 min
    .venv/bin/python benchmarks/bench_reading.py --quick          # 10⁵ rows, 1 run each: seconds
    .venv/bin/python benchmarks/bench_reading.py --file my.csv    # your own file (no peer checksum)
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import machine_line  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
#: The last commit before the reader read big files from disk (issue 14): today's reader, as a peer.
DEFAULT_PEER_REV = "04386b1"

# Run in a child process: imports, baseline RSS, the read, peak RSS; prints one JSON line.
_CHILD = r"""
import json, os, resource, sys, time
import numpy as np, scipy.spatial.transform, pandas as pd

def rss_mb():
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024

mode, path = sys.argv[1], sys.argv[2]
if mode.startswith("rbgp"):
    from rbgp_cli.io import read as rread
    from rbgp_cli.io import csv as rcsv
base = rss_mb()
t0 = time.perf_counter()
if mode == "rbgp":
    trajs = rread.read_file(path)
elif mode == "rbgp-stdin":
    trajs = rread.read_stream(sys.stdin.buffer, source="-")
elif mode == "pandas":
    df = pd.read_csv(path)
elif mode == "pandas-usecols":
    df = pd.read_csv(path, usecols=list(range(8)), dtype=np.float64)
seconds = time.perf_counter() - t0
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
out = {"seconds": seconds, "base_mb": base, "peak_mb": peak}
if mode.startswith("rbgp"):
    import rbgp_cli
    out["module"] = rbgp_cli.__file__
    out["rows"] = sum(len(t) for t in trajs)
    out["checksum"] = [float(np.nansum(t.t)) + float(np.nansum(t.position)) + float(np.nansum(np.abs(t.quat)))
                       for t in trajs]
else:
    out["rows"] = len(df)
print(json.dumps(out))
"""


def write_pose_csv(path: Path, rows: int, seed: int = 0) -> None:
    """``rows`` rows of t,x,y,z,qx,qy,qz,qw at 100 Hz: a smooth, slowly turning motion about 1 m from
    the origin with 0.1 mm / 0.1 mrad of noise (a file ``rbgp train`` accepts, too)."""
    from rbgp_cli.geometry.so3 import quat_from_rotvec

    rng = np.random.default_rng(seed)
    block = 200_000
    with open(path, "w") as fh:
        fh.write("t,x,y,z,qx,qy,qz,qw\n")
        for start in range(0, rows, block):
            n = min(block, rows - start)
            t = (start + np.arange(n)) / 100.0
            rv = np.stack([0.5 * np.sin(0.1 * t), 0.3 * np.cos(0.07 * t), 0.8 * np.sin(0.05 * t)], axis=1)
            q = quat_from_rotvec(rv + 1e-4 * rng.normal(size=(n, 3)))
            p = np.stack([0.6 + 0.2 * np.sin(0.3 * t), 0.2 * np.cos(0.2 * t), 1.0 + 0.1 * np.sin(0.5 * t)], axis=1)
            p += 1e-4 * rng.normal(size=(n, 3))
            np.savetxt(fh, np.column_stack([t, p, q]), fmt=["%.4f"] + ["%.7f"] * 3 + ["%.8f"] * 4, delimiter=",")


def peer_tree(rev: str, into: Path) -> Path | None:
    """``rbgp_cli`` as of ``rev`` (git archive) in ``into``; None when git or the revision is missing."""
    try:
        archive = subprocess.run(["git", "archive", rev, "rbgp_cli"], cwd=ROOT, capture_output=True, timeout=60)
        if archive.returncode != 0:
            return None
        subprocess.run(["tar", "-x", "-C", str(into)], input=archive.stdout, check=True, timeout=60)
    except (OSError, subprocess.SubprocessError):
        return None
    return into


def run_child(mode: str, path: Path, pythonpath: Path, repeat: int, cwd: Path) -> dict:
    runs = []
    for _ in range(repeat):
        env = dict(os.environ, PYTHONPATH=str(pythonpath), OMP_NUM_THREADS="1")
        stdin = open(path, "rb") if mode == "rbgp-stdin" else subprocess.DEVNULL
        try:
            # a pipe, not the file itself, for stdin: what `rbgp train - < file` gets from a shell pipeline
            if mode == "rbgp-stdin":
                cat = subprocess.Popen(["cat"], stdin=stdin, stdout=subprocess.PIPE)
                res = subprocess.run([sys.executable, "-c", _CHILD, mode, str(path)], stdin=cat.stdout,
                                     capture_output=True, text=True, env=env, timeout=600, cwd=cwd)
                cat.stdout.close()
                cat.wait()
            else:
                res = subprocess.run([sys.executable, "-c", _CHILD, mode, str(path)], stdin=stdin,
                                     capture_output=True, text=True, env=env, timeout=600, cwd=cwd)
        finally:
            if stdin is not subprocess.DEVNULL:
                stdin.close()
        if res.returncode != 0:
            raise RuntimeError(f"{mode} failed: {res.stderr.strip()[-800:]}")
        runs.append(json.loads(res.stdout.strip().splitlines()[-1]))
        module = runs[-1].get("module")
        if module and not Path(module).resolve().is_relative_to(pythonpath.resolve()):
            raise RuntimeError(f"{mode}: imported {module}, not the rbgp_cli under {pythonpath}")
    out = {k: statistics.median(r[k] for r in runs) for k in ("seconds", "base_mb", "peak_mb")}
    out["rows"] = runs[0]["rows"]
    out["checksum"] = runs[0].get("checksum")
    out["seconds_all"] = [r["seconds"] for r in runs]
    out["load"] = os.getloadavg()[0]
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rows", type=int, default=None, help="rows of the generated file (default 10⁶; --quick: 10⁵)")
    ap.add_argument("--file", default=None, help="measure this CSV instead of a generated one")
    ap.add_argument("--repeat", type=int, default=None, help="processes per reader (default 3; --quick: 1)")
    ap.add_argument("--peer-rev", default=DEFAULT_PEER_REV, help="git revision of the peer rbgp reader ('' = none)")
    ap.add_argument("--no-pandas", action="store_true", help="skip the plain pandas readers")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--json", default=None)
    ap.add_argument("--markdown", default=None)
    args = ap.parse_args(argv)
    rows = args.rows or (100_000 if args.quick else 1_000_000)
    repeat = args.repeat or (1 if args.quick else 3)

    print(f"bench_reading — {time.strftime('%Y-%m-%d %H:%M %Z')}; {machine_line()}", flush=True)
    tmp = Path(tempfile.mkdtemp(prefix="rbgp-bench-reading-"))
    (tmp / "cwd").mkdir()  # the children run here: nothing on their '' path entry shadows rbgp_cli
    try:
        if args.file:
            path = Path(args.file).resolve()
        else:
            (tmp / "data").mkdir()
            path = tmp / "data" / "poses.csv"
            t0 = time.perf_counter()
            write_pose_csv(path, rows)
            print(f"wrote {rows} rows, {path.stat().st_size / 1e6:.1f} MB in {time.perf_counter() - t0:.1f} s", flush=True)
        size_mb = path.stat().st_size / 2**20
        readers = [("rbgp", "rbgp, this checkout: `read_file`", ROOT), ("rbgp-stdin", "rbgp, piped into stdin", ROOT)]
        (tmp / "peer").mkdir()
        peer = peer_tree(args.peer_rev, tmp / "peer") if args.peer_rev else None
        if args.peer_rev and peer is None:
            print(f"peer revision {args.peer_rev!r} not available (no git or no such commit): skipped", flush=True)
        if peer is not None:
            readers.append(("rbgp", f"rbgp before this change ({args.peer_rev}): `read_file`", peer))
        if not args.no_pandas:
            readers += [("pandas", "`pandas.read_csv(path)`, every column", ROOT),
                        ("pandas-usecols", "`pandas.read_csv(path, usecols, dtype=float64)`", ROOT)]
        results = []
        for mode, label, pythonpath in readers:
            r = run_child(mode, path, pythonpath, repeat, tmp / "cwd")
            r.update(mode=mode, label=label)
            results.append(r)
            print(f"{label}: {r['seconds']:.2f} s, {r['rows'] / r['seconds'] / 1e6:.2f} M rows/s, peak RSS "
                  f"{r['peak_mb']:.0f} MB ({r['peak_mb'] - r['base_mb']:.0f} MB above the imports; load {r['load']:.1f})",
                  flush=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)

    ours = results[0]
    old = next((r for r in results if r["label"].startswith("rbgp before")), None)
    summary = {"file_mb": size_mb, "rows": ours["rows"], "readers": results,
               "above_imports_over_size": (ours["peak_mb"] - ours["base_mb"]) / size_mb,
               "peak_over_size": ours["peak_mb"] / size_mb}
    if old is not None:
        summary["speedup_vs_peer"] = old["seconds"] / ours["seconds"]
        summary["memory_ratio_vs_peer"] = (old["peak_mb"] - old["base_mb"]) / (ours["peak_mb"] - ours["base_mb"])
        summary["same_values_as_peer"] = old["checksum"] == ours["checksum"] and old["rows"] == ours["rows"]
    lines = [f"Measured {time.strftime('%Y-%m-%d %H:%M %Z')}; {machine_line()}.", "",
             f"File: {ours['rows']:,} rows, {size_mb:.1f} MiB (`t,x,y,z,qx,qy,qz,qw`). Median of {repeat} fresh "
             "processes each; \"above imports\" is peak RSS minus the RSS after importing numpy, scipy and pandas.", "",
             "| reader | time (s) | rows/s | peak RSS (MiB) | above imports (MiB) | above imports / file size |",
             "|---|---:|---:|---:|---:|---:|"]
    for r in results:
        above = r["peak_mb"] - r["base_mb"]
        lines.append(f"| {r['label']} | {r['seconds']:.2f} | {r['rows'] / r['seconds'] / 1e6:.2f} M | {r['peak_mb']:.0f} "
                     f"| {above:.0f} | {above / size_mb:.1f}× |")
    lines.append("")
    verdict = (f"rbgp reads with **{summary['above_imports_over_size']:.1f}× the file size** above the imports "
               f"(target ≤ 3×: {'met' if summary['above_imports_over_size'] <= 3 else 'NOT met'}; "
               f"peak RSS of the whole process {summary['peak_over_size']:.1f}× the file size)")
    if old is not None:
        verdict += (f", **{summary['speedup_vs_peer']:.1f}× faster** and with {summary['memory_ratio_vs_peer']:.1f}× less "
                    f"memory than before ({args.peer_rev}); same values: "
                    f"{'yes' if summary['same_values_as_peer'] else 'NO'}")
    lines.append(verdict + ".")
    text = "\n".join(lines)
    print("\n" + text)
    if args.markdown:
        Path(args.markdown).write_text(text + "\n")
    if args.json:
        Path(args.json).write_text(json.dumps(summary, indent=1))
    return 0 if summary.get("same_values_as_peer", True) else 1


if __name__ == "__main__":
    raise SystemExit(main())
