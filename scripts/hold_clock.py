"""Issue 37, twenty-ninth pass: a hold longer than the demonstrations' left off a motion's clock, measured (not kept).

Usage:
    python scripts/hold_clock.py DIR [--body NAME] [--train-size N] [--order random|forward] [--folds 5] [--seed 0]
    python scripts/hold_clock.py DIR --insert 1.0

A motion's phase is its seen time over one duration (docs/method.md §13), so a hold in mid-motion reads as a slower
motion. The idea measured here: a hold (a run of samples whose position moved less than a tenth of the
demonstrations' mean speed over the trailing 0.05 s, the test of ``Follower.at_rest``, begun after the motion
started and over once a later sample is not at rest) counts on the clock only up to the longest hold H of the
training demonstrations; the excess of an ended hold is left out of the seen times, the estimate made on that
clock, and its times moved back by what was left out: a motion that resumed after a long hold is predicted as the
demonstrations' motion, later by the hold.

Default: on crossval's own splits (:func:`rbgp_cli.evaluation.crossval.make_splits`, every F of 0.2 … 0.8 as
``crossval --given`` splits a held-out motion), each held-out seen part with an ended hold longer than its training
demonstrations' H is continued by the path distribution (crossval's no-GP row, 20 samples) with and without the
clock, and scored as crossval scores it (:func:`rbgp_cli.evaluation.under_way.score`); prints each such motion and
each F's cell change (the change summed over those motions, divided by the cell's count of held-out motions, so
comparable with crossval's cells). The other held-out motions are continued the same way either way.

``--insert S``: the last demonstration (by name order) held still for S seconds in the middle of its own longest
hold, the path distribution fitted on the others; its estimate from every third seen sample on, with and without
the clock, against its real end.
"""

from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np

FRACTIONS = (0.2, 0.4, 0.6, 0.8)
WINDOW = 0.05


def rest_speed(paths) -> float:
    """A tenth of the mean path's length over exp(mean ln D) (``Follower``'s start speed), m/s."""
    length = float(np.sum(np.linalg.norm(np.diff(paths.position, axis=0), axis=1)))
    return 0.1 * length / float(np.exp(np.mean(paths.log_durations)))


def holds(t, p, v, window=WINDOW):
    """[(a, b)]: runs at rest after the first whole window, a where the first one's window began, b its last."""
    j = np.maximum(np.searchsorted(t, t - window, side="right") - 1, 0)
    span = t - t[j]
    rest = (span >= 0.5 * window) & (np.linalg.norm(p - p[j], axis=1) < v * np.where(span > 0, span, 1.0))
    whole = int(np.searchsorted(t, t[0] + window, side="left"))
    d = np.diff(np.concatenate([[0], rest.astype(np.int8), [0]]))
    out = []
    for r0, r1 in zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1) - 1):
        if r0 <= whole:
            continue
        if out and j[r0] <= out[-1][1]:
            out[-1] = (out[-1][0], int(r1))
        else:
            out.append((int(j[r0]), int(r1)))
    return out


def longest_hold(trajs, v) -> float:
    return max([tr.t[b] - tr.t[a] for tr in trajs for a, b in holds(tr.t, tr.position, v)], default=0.0)


def motion_clock(t, q, p, v, H):
    """(t_c, q, p, left): the ended holds longer than H cut to H (their samples from H on left out but the last)."""
    long = [(a, b) for a, b in holds(t, p, v) if t[b] - t[a] > H and b < len(t) - 1]
    if not long:
        return t, q, p, 0.0
    keep, tc = np.ones(len(t), dtype=bool), t.astype(np.float64).copy()
    for a, b in long:
        keep[a:b] &= t[a:b] - t[a] < H - 0.5 * (t[b] - t[b - 1])
        tc[b:] -= float(t[b] - t[a]) - H
    return tc[keep], q[keep], p[keep], float(t[-1] - tc[keep][-1])


def continuation(ant, seen, H, v, samples, seed, clock):
    """The path distribution's continuation of ``seen``, on the motion's clock if ``clock`` (its times moved back)."""
    t, q, p, left = (seen.t, seen.quat, seen.position, 0.0) if not clock else motion_clock(
        seen.t, seen.quat, seen.position, v, H)
    c = ant.continuation(t, q, p, samples=samples, seed=seed)
    if left:
        e = c.estimate
        est = replace(e, t=e.t + left, end_time=e.end_time + left,
                      end_time_band=tuple(x + left for x in e.end_time_band))
        c = replace(c, t=c.t + left, samples=[(ts + left, sq, sp) for ts, sq, sp in c.samples], estimate=est)
    return c, left


def splits_mode(args, trajs):
    from rbgp_cli.dynamics.anticipation import Anticipator
    from rbgp_cli.dynamics.envelope import envelope_from_demos
    from rbgp_cli.dynamics.paths import fit_paths
    from rbgp_cli.evaluation.crossval import make_splits
    from rbgp_cli.evaluation.under_way import score, split_seen

    keys = ("end_time", "end_pos", "end_rot", "rem_pos", "cov_pos", "cov_rot")
    count = {F: 0 for F in FRACTIONS}
    change = {F: [] for F in FRACTIONS}
    for train_idx, test_idx in make_splits(len(trajs), args.folds, args.seed, args.order, args.train_size or None):
        for F in FRACTIONS:
            count[F] += len(test_idx)
        train = [trajs[i] for i in train_idx]
        paths = fit_paths(train)
        v = rest_speed(paths)
        H = longest_hold(train, v)
        ant, env = Anticipator(paths, None), envelope_from_demos(train)
        for i in test_idx:
            for F in FRACTIONS:
                seen, rest = split_seen(trajs[i], F)
                if motion_clock(seen.t, seen.quat, seen.position, v, H)[3] == 0.0:
                    continue
                got = {}
                for clock in (False, True):
                    c, left = continuation(ant, seen, H, v, 20, args.seed + i, clock)
                    trs = c.trajectories(include_samples=True)
                    sc = score(trs[0], trs[1:], rest, c.estimate.end_time_band, env, float(seen.t[0]))
                    m, mc = sc.motion_sq[0], sc.motion_coverage[0]
                    got[clock] = dict(end_time=sc.end_time[0], end_pos=sc.end_pos[0], end_rot=sc.end_rot[0],
                                      rem_pos=float(np.sqrt(m[0] / m[2])), cov_pos=mc[0] / mc[1], cov_rot=mc[2] / mc[3],
                                      left=left)
                change[F].append({k: got[True][k] - got[False][k] for k in keys})
                print(f"motion {i} F = {F:g} (H = {H:.2f} s, {got[True]['left']:.2f} s left off): "
                      + ", ".join(f"{k} {got[False][k]:.3f} → {got[True][k]:.3f}" for k in keys), flush=True)
    print("| F | motions with the clock | " + " | ".join(keys) + " |")
    print("|---|---|" + "---|" * len(keys))
    for F in FRACTIONS:
        print(f"| {F:g} | {len(change[F])} of {count[F]} | "
              + " | ".join(f"{sum(c[k] for c in change[F]) / max(count[F], 1):+.4f}" for k in keys) + " |")


def insert_mode(args, trajs):
    from rbgp_cli.dynamics.anticipation import Anticipator
    from rbgp_cli.dynamics.paths import fit_paths

    paths = fit_paths(trajs[:-1])
    tr = trajs[-1]
    v = rest_speed(paths)
    H = longest_hold(trajs[:-1], v)
    own = holds(tr.t, tr.position, v)
    a, b = max(own, key=lambda h: h[1] - h[0]) if own else (len(tr.t) // 2, len(tr.t) // 2)
    mid = (a + b) // 2
    dt = float(np.median(np.diff(tr.t)))
    n = int(round(args.insert / dt))
    t = np.concatenate([tr.t[:mid + 1], tr.t[mid] + dt * np.arange(1, n + 1), tr.t[mid + 1:] + n * dt]) - tr.t[0]
    q = np.concatenate([tr.quat[:mid + 1], np.repeat(tr.quat[mid:mid + 1], n, axis=0), tr.quat[mid + 1:]])
    p = np.concatenate([tr.position[:mid + 1], np.repeat(tr.position[mid:mid + 1], n, axis=0), tr.position[mid + 1:]])
    ant = Anticipator(paths, None)
    print(f"{tr.name}: held {args.insert:g} s more from {t[mid]:.2f} s; H = {H:.2f} s; real end {t[-1]:.2f} s")
    for m in range(3, len(t), 3):
        row = [f"t = {t[m]:.2f}"]
        for clock in (False, True):
            sq, qq, pp, left = (t[:m + 1], q[:m + 1], p[:m + 1], 0.0) if not clock else motion_clock(
                t[:m + 1], q[:m + 1], p[:m + 1], v, H)
            e = ant.estimate(sq, qq, pp)
            lo, hi = (x + left for x in e.end_time_band)
            row.append(f"{'clock' if clock else 'as now'}: phase {e.phase:.2f} end {e.end_time + left:.2f} "
                       f"[{lo:.2f}, {hi:.2f}]" + (f" ({left:.2f} s left off)" if left else ""))
        print(" | ".join(row))


def main(argv=None):
    from rbgp_cli.io.read import ReadOptions
    from rbgp_cli.workflows import load_demonstrations

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dir")
    ap.add_argument("--body", default=None)
    ap.add_argument("--train-size", type=int, default=0)
    ap.add_argument("--order", default="random", choices=("random", "forward"))
    ap.add_argument("--folds", type=int, default=5)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--insert", type=float, default=None, help="hold the last demonstration this many seconds more")
    args = ap.parse_args(argv)
    trajs, _, _ = load_demonstrations([args.dir], ReadOptions(body=args.body) if args.body else ReadOptions())
    if args.insert is not None:
        insert_mode(args, trajs)
    else:
        splits_mode(args, trajs)


if __name__ == "__main__":
    main()
