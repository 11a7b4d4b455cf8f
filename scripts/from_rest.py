"""Issue 37, twenty-ninth pass: a seen part that rests longer before it moves than any demonstration, cut to begin
the demonstrations' longest rest before it moves (measured, not kept: ``rollout --given`` warns instead).

Usage:
    python scripts/from_rest.py DIR [--body NAME] [--train-size N] [--order random|forward] [--folds 5] [--seed 0]
                                [--idle S]

On crossval's own splits (:func:`rbgp_cli.evaluation.crossval.make_splits`; every F of 0.2 … 0.8 as ``crossval
--given`` splits a held-out motion, after ``--idle`` seconds more at its first pose: a recording begun earlier), each
held-out seen part that rests longer before it moves (:func:`~rbgp_cli.dynamics.anticipation.rest_before_moving`)
than the training demonstrations' longest rest (``Anticipator.lead``) and one grid step is cut to begin ``lead``
before it moves. It is continued by the path distribution (crossval's no-GP row, 20 samples) cut and as it is, and
scored as crossval scores it (:func:`rbgp_cli.evaluation.under_way.score`; a continuation too short to score, as a
part read as already over is, counts its end time and pose only). Printed: each such motion, and each F's cell change
(summed over those motions, divided by the cell's count of held-out motions, as crossval's cells average); the other
held-out motions would be continued the same way either way.
"""

from __future__ import annotations

import argparse

import numpy as np

FRACTIONS = (0.2, 0.4, 0.6, 0.8)
KEYS = ("end_time", "end_pos", "end_rot", "rem_pos", "cov_pos", "cov_rot", "time_in")


def main(argv=None):
    from rbgp_cli.dynamics.anticipation import Anticipator, rest_before_moving
    from rbgp_cli.dynamics.envelope import envelope_from_demos
    from rbgp_cli.dynamics.paths import fit_paths
    from rbgp_cli.dynamics.trajectory import Trajectory
    from rbgp_cli.evaluation.crossval import make_splits
    from rbgp_cli.errors import InputError
    from rbgp_cli.evaluation.under_way import score, split_seen
    from rbgp_cli.io.read import ReadOptions
    from rbgp_cli.workflows import load_demonstrations

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dir")
    ap.add_argument("--body", default=None)
    ap.add_argument("--train-size", type=int, default=0)
    ap.add_argument("--order", default="random", choices=("random", "forward"))
    ap.add_argument("--folds", type=int, default=5)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--idle", type=float, default=0.0)
    args = ap.parse_args(argv)
    trajs, _, _ = load_demonstrations([args.dir], ReadOptions(body=args.body) if args.body else ReadOptions())
    count = {F: 0 for F in FRACTIONS}
    change = {F: [] for F in FRACTIONS}
    for train_idx, test_idx in make_splits(len(trajs), args.folds, args.seed, args.order, args.train_size or None):
        for F in FRACTIONS:
            count[F] += len(test_idx)
        train = [trajs[i] for i in train_idx]
        paths = fit_paths(train)
        ant, env = Anticipator(paths, None), envelope_from_demos(train)
        for i in test_idx:
            tr = trajs[i]
            for F in FRACTIONS:
                seen, rest = split_seen(tr, F)
                if args.idle:
                    dt = float(np.median(np.diff(seen.t)))
                    n = int(round(args.idle / dt))
                    seen = Trajectory(np.concatenate([seen.t[0] - dt * np.arange(n, 0, -1), seen.t]),
                                      np.concatenate([np.repeat(seen.quat[:1], n, axis=0), seen.quat]),
                                      np.concatenate([np.repeat(seen.position[:1], n, axis=0), seen.position]))
                waited = rest_before_moving(seen.t, seen.position, ant.rest_speed)
                if waited <= ant.lead + ant.lead_step:
                    continue
                k = int(np.searchsorted(seen.t, seen.t[0] + waited - ant.lead, side="left"))
                got = {}
                for cut, (t, q, p) in ((True, (seen.t[k:], seen.quat[k:], seen.position[k:])),
                                       (False, (seen.t, seen.quat, seen.position))):
                    c = ant.continuation(t, q, p, samples=20, seed=args.seed + i)
                    trs = c.trajectories(include_samples=True)
                    try:
                        sc = score(trs[0], trs[1:], rest, c.estimate.end_time_band, env, float(tr.t[0]))
                        m, mc = sc.motion_sq[0], sc.motion_coverage[0]
                        got[cut] = dict(end_time=sc.end_time[0], end_pos=sc.end_pos[0], end_rot=sc.end_rot[0],
                                        rem_pos=float(np.sqrt(m[0] / m[2])), cov_pos=mc[0] / mc[1],
                                        cov_rot=mc[2] / mc[3], time_in=sc.end_time_in[0], left=float(t[0] - seen.t[0]))
                    except InputError:  # read as over already: its end time and pose only
                        e = c.estimate
                        lo, hi = e.end_time_band
                        from rbgp_cli.geometry.so3 import log_quat, quat_conjugate, quat_multiply

                        rot = log_quat(quat_multiply(np.asarray(e.end_quat)[None], quat_conjugate(tr.quat[-1:])))[0]
                        got[cut] = dict(end_time=abs(e.end_time - tr.t[-1]),
                                        end_pos=float(np.linalg.norm(e.end_position - tr.position[-1])),
                                        end_rot=float(np.linalg.norm(rot)), rem_pos=np.nan, cov_pos=np.nan,
                                        cov_rot=np.nan, time_in=float(lo <= tr.t[-1] <= hi), left=0.0)
                change[F].append({k: got[True][k] - got[False][k] for k in KEYS})
                print(f"motion {i} F = {F:g} ({got[True]['left']:.2f} s cut): "
                      + ", ".join(f"{k} {got[False][k]:.3f} → {got[True][k]:.3f}" for k in KEYS), flush=True)
    print("| F | motions cut | " + " | ".join(KEYS) + " |")
    print("|---|---|" + "---|" * len(KEYS))
    for F in FRACTIONS:
        print(f"| {F:g} | {len(change[F])} of {count[F]} | "
              + " | ".join(f"{np.nansum([c[k] for c in change[F]]) / max(count[F], 1):+.4f}" for k in KEYS) + " |")


if __name__ == "__main__":
    main()
