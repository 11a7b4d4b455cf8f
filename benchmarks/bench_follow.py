"""How fast does ``rbgp follow`` update? (issue 37: a motion under way, live)

The path distribution is fitted on the demonstrations of a set; each of a few of them is then streamed
through :class:`rbgp_cli.dynamics.anticipation.Follower` at 100 Hz and at 256 Hz (QTM's rate), resampled
(slerp, linear) from the recording, after one second at rest. Every ``push`` is timed (wall clock,
``time.perf_counter``) and by this process's CPU time (``time.process_time``: what it would take on an idle
core, near enough; 10 ms resolution on some systems); the first motion's first 10 updates are a warm-up and not counted. Printed per
rate: the median and the 99th percentile of the update time as a fraction of the frame period (the
target: both below 0.5), and the update time itself in ms. Single-threaded BLAS, as ``rbgp follow`` runs.

``--against DIR``: DIR is another checkout of rbgp (a folder holding ``rbgp_cli/``); its
``rbgp_cli/dynamics/anticipation.py`` (that module alone, over this checkout's other modules) follows the
same stream in the same process, each pose pushed to both in alternating order, on the same path
distribution. Printed: this checkout's CPU time per update over the other's (median and 99th percentile)
and the largest difference between their estimates. On a shared, loaded machine the ratio holds where the
absolute times do not.

    .venv/bin/python benchmarks/bench_follow.py ../shared/realdata/hand_raise_csv
    .venv/bin/python benchmarks/bench_follow.py sample_data/csv --motions 3
    .venv/bin/python benchmarks/bench_follow.py ../shared/realdata/hand_raise_csv --motions 3 --against ../main
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def _other_module(folder: str):
    """The anticipation module of another checkout, loaded under its own name."""
    import importlib.util

    path = Path(folder) / "rbgp_cli" / "dynamics" / "anticipation.py"
    if not path.is_file():
        raise SystemExit(f"--against: {path} not found (give a checkout of rbgp, the folder holding rbgp_cli/)")
    spec = importlib.util.spec_from_file_location("rbgp_against_anticipation", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up by name
    spec.loader.exec_module(module)
    return module


def _difference(a, b) -> float:
    """The largest absolute difference between two estimates' times, phase and end position."""
    if a is None or b is None:
        return 0.0 if a is None and b is None else float("inf")
    return float(max(abs(a.end_time - b.end_time), abs(a.phase - b.phase),
                     np.max(np.abs(np.asarray(a.end_position) - np.asarray(b.end_position)))))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", nargs="?", default="sample_data/csv")
    ap.add_argument("--motions", type=int, default=5, help="demonstrations streamed per rate")
    ap.add_argument("--rates", default="100,256")
    ap.add_argument("--against", default=None, help="another checkout of rbgp: its Follower timed beside this one's")
    args = ap.parse_args(argv)

    from threadpoolctl import threadpool_limits

    from rbgp_cli.dynamics.anticipation import Follower
    from rbgp_cli.dynamics.paths import fit_paths
    from rbgp_cli.dynamics.trajectory import interpolate_poses
    from rbgp_cli.geometry.so3 import quat_make_continuous
    from rbgp_cli.workflows import load_demonstrations

    other = _other_module(args.against) if args.against else None
    demos, _, _ = load_demonstrations([args.data])
    with threadpool_limits(1):
        paths = fit_paths(demos)
        for rate in (float(r) for r in args.rates.split(",")):
            times, cpu, first, cpu_other, diff = [], [], [], [], 0.0
            for i, tr in enumerate(demos[: args.motions]):
                t = np.arange(0.0, tr.duration, 1.0 / rate)
                q, p = interpolate_poses(tr.t - tr.t[0], quat_make_continuous(tr.quat), tr.position, t)
                rest = np.arange(-1.0, 0.0, 1.0 / rate)
                f = Follower(paths)
                g = other.Follower(paths) if other else None
                seen_first = None
                for j, tj in enumerate(rest):
                    f.push(tj, q[0], p[0])
                    if g is not None:
                        g.push(tj, q[0], p[0])
                for j, tj in enumerate(t):
                    if g is not None and j % 2:  # the other first on every other pose
                        c = time.process_time()
                        ref = g.push(tj, q[j], p[j])
                        dco = time.process_time() - c
                    a, c = time.perf_counter(), time.process_time()
                    out = f.push(tj, q[j], p[j])
                    dt, dc = time.perf_counter() - a, time.process_time() - c
                    if g is not None and not j % 2:
                        c = time.process_time()
                        ref = g.push(tj, q[j], p[j])
                        dco = time.process_time() - c
                    if g is not None:
                        diff = max(diff, _difference(out, ref))
                    if out is not None and seen_first is None:
                        seen_first = tj
                    if i > 0 or j >= 10:
                        times.append(dt)
                        cpu.append(dc)
                        if g is not None:
                            cpu_other.append(dco)
                first.append(np.nan if seen_first is None else seen_first)
            ms = np.array(times) * 1e3
            period = 1e3 / rate
            print(f"{rate:g} Hz: {len(ms)} updates; median {np.median(ms):.2f} ms = {np.median(ms) / period:.2f} of a frame, "
                  f"99th percentile {np.percentile(ms, 99):.2f} ms = {np.percentile(ms, 99) / period:.2f}; "
                  f"first prediction {np.nanmax(first):.3f} s after the start at the latest; "
                  f"CPU time per update: median {np.median(cpu) * 1e3:.2f} ms = {np.median(cpu) * 1e3 / period:.2f}, "
                  f"99th percentile {np.percentile(cpu, 99) * 1e3:.2f} ms = {np.percentile(cpu, 99) * 1e3 / period:.2f}")
            if other is not None:
                co = np.array(cpu_other)
                print(f"    against {args.against}: its CPU time per update median {np.median(co) * 1e3:.2f} ms, 99th "
                      f"percentile {np.percentile(co, 99) * 1e3:.2f} ms; this one's over its: median "
                      f"{np.median(cpu) / np.median(co):.2f}, 99th percentile {np.percentile(cpu, 99) / np.percentile(co, 99):.2f}; "
                      f"largest difference between the estimates {diff:.1e} (s, phase, m)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
