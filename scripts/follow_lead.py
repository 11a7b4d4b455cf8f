"""Issue 37, twenty-ninth pass: ``rbgp follow`` with the rest before a departure as the motion's beginning.

Usage:
    python scripts/follow_lead.py DIR [--body NAME] [--folds 5] [--seed 0] [--idle S] [--train-size N]

On crossval's folds (:func:`rbgp_cli.evaluation.crossval.make_splits`, at random; with ``--train-size N`` its subsets
of N, as ``crossval --train-size N``), each held-out recording is
streamed into a :class:`rbgp_cli.dynamics.anticipation.Follower` of the other demonstrations' path distribution (after
``--idle`` seconds more at its first pose: a stream that waited longer than the recording), once as it is (the rest
before the departure, at most ``lead``, begins the motion) and once with ``lead=0`` (the motion begins at its
departure, as before this pass). At each F of 0.2 … 0.8 of the recording (its own clock) the live estimate is
scored: |end time error| s, whether the 90 % end time band held the real end, and the final position's error m.
Beside them, the anticipator the Follower uses (6 seen poses, 16 durations, the end at D̂) on the recording's first F
from its first sample (what ``rollout --given`` of that part estimates, with the live update's settings). Motions
that have not left rest by F are left out of every row at that F (how many are counted is printed).
"""

from __future__ import annotations

import argparse

import numpy as np

FRACTIONS = (0.2, 0.4, 0.6, 0.8)


def main(argv=None):
    from rbgp_cli.dynamics.anticipation import Anticipator, Follower
    from rbgp_cli.dynamics.paths import fit_paths
    from rbgp_cli.evaluation.crossval import make_splits
    from rbgp_cli.io.read import ReadOptions
    from rbgp_cli.workflows import load_demonstrations

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dir")
    ap.add_argument("--body", default=None)
    ap.add_argument("--folds", type=int, default=5)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--idle", type=float, default=0.0)
    ap.add_argument("--train-size", type=int, default=0)
    args = ap.parse_args(argv)
    trajs, _, _ = load_demonstrations([args.dir], ReadOptions(body=args.body) if args.body else ReadOptions())
    rows = ("rollout --given", "follow, lead 0", "follow")
    score = {r: {F: [] for F in FRACTIONS} for r in rows}  # (|end time error|, held, |final position error|)
    for train_idx, test_idx in make_splits(len(trajs), args.folds, args.seed, "random", args.train_size or None):
        train = [trajs[i] for i in train_idx]
        paths = fit_paths(train)
        ant = Anticipator(paths, None, points=6, grid_size=16, mix_end=False)
        for i in test_idx:
            tr = trajs[i]
            dt = float(np.median(np.diff(tr.t)))
            n = int(round(args.idle / dt))
            t = np.concatenate([tr.t[0] - dt * np.arange(n, 0, -1), tr.t])
            q = np.concatenate([np.repeat(tr.quat[:1], n, axis=0), tr.quat])
            p = np.concatenate([np.repeat(tr.position[:1], n, axis=0), tr.position])
            marks = {F: tr.t[0] + F * tr.duration for F in FRACTIONS}
            live = {}
            for row, lead in (("follow, lead 0", 0.0), ("follow", None)):
                f = Follower(paths, lead=lead)
                got = {}
                for k in range(len(t)):
                    e = f.push(t[k], q[k], p[k])
                    for F, m in marks.items():
                        if F not in got and t[k] >= m:
                            got[F] = e
                live[row] = got
            for F in FRACTIONS:
                if live["follow"].get(F) is None or live["follow, lead 0"].get(F) is None:
                    continue  # not under way yet
                k = int(np.searchsorted(tr.t, marks[F]))
                ests = {"rollout --given": ant.estimate(tr.t[:k + 1], tr.quat[:k + 1], tr.position[:k + 1]),
                        **{r: live[r][F] for r in live}}
                for r, e in ests.items():
                    score[r][F].append((abs(e.end_time - tr.t[-1]), float(e.end_time_band[0] <= tr.t[-1] <= e.end_time_band[1]),
                                        float(np.linalg.norm(e.end_position - tr.position[-1]))))
    print(f"{args.dir}, idle {args.idle:g} s: end time error s / its band held / final position error m")
    print("| | " + " | ".join(f"F = {F:g} (n = {len(score['follow'][F])})" for F in FRACTIONS) + " |")
    print("|---|" + "---|" * len(FRACTIONS))
    for r in rows:
        cells = []
        for F in FRACTIONS:
            a = np.array(score[r][F]).reshape(-1, 3)
            cells.append("–" if not len(a) else f"{a[:, 0].mean():.3f} / {a[:, 1].mean():.2f} / {a[:, 2].mean():.3f}")
        print(f"| {r} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
