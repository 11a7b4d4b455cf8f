"""Issue 37, fourth pass: per held-out motion, rbgp's path distribution (crossval --given F's ``no-GP`` row)
against the ridge ProMP peer, and candidate ways of choosing the conditioning's strength.

Usage: python scripts/under_way_paired.py SET_DIR OUT.json [--folds 5]

For each fold (crossval's folds, seed 0) it fits the path distribution on the training demonstrations
(as ``crossval --given`` does), sees each held-out demonstration's first F and records, per motion, the
final-pose error (m, rad), the end time's error (s) and the remainder's squared-error sums for:

- ``base``: the anticipation before the fourth pass (the conditioned path, no GP, with the path
  distribution's τ² and the seen tolerance r); ``rest``: as it is now (the rest's own τ² and r, fit_seen);
- ``promp-ridge``: the ridge ProMP peer (its σ chosen by leaving training demonstrations out);
  ``promp-ridge@rbgp-D``: the same conditioned at ``base``'s duration instead of its own;
- ``sweep:τ²:r``: the conditioning with a fixed τ² and seen tolerance r (the last seen pose exact);
- ``grid-ridge``: the ProMP's ridge map on rbgp's grid (τ² ≈ 0, no exact last pose, r chosen by leaving
  demonstrations out on the remainder's position RMSE at the true duration, as the peer's σ is);
- ``end-loo``: τ² and r chosen by leaving training demonstrations out on the end-given-seen error itself
  (one choice for every F), ``end-loo-F``: one choice per F.
It also writes each fold's choices. Nothing here changes rbgp; it measures.
"""

from __future__ import annotations

import argparse
import copy
import json
import sys
import time

import numpy as np

from rbgp_cli.dynamics.anticipation import SEEN_FRACTIONS, SEEN_POINTS, Anticipator, _ELL_TOL, seen_split
from rbgp_cli.dynamics.paths import GOAL_TOLERANCE, fit_paths, left_out_moments
from rbgp_cli.evaluation.crossval import make_folds
from rbgp_cli.evaluation.under_way import FRACTIONS, PhaseProMP, ridge_std, score, split_seen
from rbgp_cli.workflows import load_demonstrations

SMOOTHS = (0.01, 0.03, 0.1, 0.3, 1.0)
TOLS = (0.05, 0.1, 0.2, 0.4, 0.8, 1.6, 3.2)
TINY = 1e-6


class Variant(Anticipator):
    """The anticipator with its conditioning's τ² and r given, and optionally no exact last pose."""

    def __init__(self, paths, smooth, tol, exact_last=True):
        p = copy.copy(paths)
        p.smooth = float(smooth)
        p.seen_tolerance = float(tol)
        p.rest_smooth = p.rest_tolerance = None  # the conditioning with exactly these
        # the duration's weights keep the fitted τ² and r: only the path's conditioning changes
        sigma = getattr(paths, "duration_sigma", None)  # a tolerance in rad and m (fewer than ten), else r
        super().__init__(p, None, duration_smooth=paths.duration_smooth if paths.duration_smooth is not None else paths.smooth,
                         duration_tolerance=None if sigma is not None else (
                             paths.duration_tolerance if paths.duration_tolerance is not None else paths.seen_tolerance),
                         duration_sigma=sigma)
        self.exact_last = exact_last

    def _observations(self, tau, q, p, last_q, last_p, D):
        A, y, r2 = super()._observations(tau, q, p, last_q, last_p, D)
        if not self.exact_last:
            n = 6 * len(tau)
            keep = np.r_[np.arange(n), [len(y) - 1]]  # drop the exact last pose
            A, y, r2 = A[keep], y[keep], r2[keep]
        return A, y, r2


def end_loo(paths, smooths, tols, *, exact_last=True, points=SEEN_POINTS):
    """Each training demonstration left out: its first F (SEEN_FRACTIONS) seen at its true phases and ln D,
    the others' conditioned mean at the end. Returns the mean scaled squared end error (len(smooths),
    len(tols), len(F)), and the mean end position (m) and rotation (rad) errors of the same shape."""
    X = paths.vectors()
    S, P = paths.S, X.shape[1]
    sc = paths.scale
    r_last = (np.array(GOAL_TOLERANCE).repeat(3) / sc) ** 2
    end = 6 * (S - 1) + np.arange(6)
    sq = np.zeros((len(smooths), len(tols), len(SEEN_FRACTIONS)))
    ep, er = np.zeros_like(sq), np.zeros_like(sq)
    K1 = paths.smooth_covariance(1.0)
    for fi, F in enumerate(SEEN_FRACTIONS):
        idx, no = seen_split(F, S, P, points)
        idx = np.concatenate([idx[:no], end])
        Xs = X[:, idx]
        Kss = K1[np.ix_(idx, idx)]
        count = 0
        for block, m, samp in left_out_moments(Xs):
            inn = Xs[block, :no] - m[:, :no]
            for a, tau2 in enumerate(smooths):
                Sig = samp + tau2 * Kss
                Soo, Sot = Sig[:, :no, :no], Sig[:, :no, no:]
                for b, tol in enumerate(tols):
                    r2 = np.full(no, float(tol) ** 2)
                    if exact_last:
                        r2[-7:-1] = r_last
                    r2[-1] = _ELL_TOL ** 2
                    gain = np.swapaxes(np.linalg.solve(Soo + np.diag(r2), Sot), 1, 2)
                    e = Xs[block, no:] - (m[:, no:] + np.einsum("bij,bj->bi", gain, inn))
                    sq[a, b, fi] += np.sum(e ** 2)
                    ep[a, b, fi] += np.sum(np.linalg.norm(e[:, 3:] * sc[3:], axis=1))
                    er[a, b, fi] += np.sum(np.linalg.norm(e[:, :3] * sc[:3], axis=1))
            count += len(block)
        sq[..., fi] /= count
        ep[..., fi] /= count
        er[..., fi] /= count
    return sq, ep, er


def grid_ridge_tol(paths, trajs, tols, fractions=(0.2, 0.6)):
    """The ProMP peer's rule on rbgp's grid: τ² ≈ 0, no exact last pose, the r with the smallest left-out
    remainder position RMSE at the true duration (leave-one-out, batched)."""
    X = paths.vectors()
    S, P = paths.S, X.shape[1]
    sc = paths.scale
    err = np.zeros(len(tols))
    K1 = paths.smooth_covariance(1.0)
    for F in fractions:
        J = int(round(F * (S - 1)))
        seen = np.unique(np.round(np.linspace(0, J, min(SEEN_POINTS, J + 1))).astype(int))
        rest = np.arange(J, S)
        io = np.concatenate([(6 * seen[:, None] + np.arange(6)).ravel(), [P - 1]])
        it = (6 * rest[:, None] + np.arange(3, 6)).ravel()
        idx = np.concatenate([io, it])
        no = len(io)
        Xs = X[:, idx]
        Kss = TINY * K1[np.ix_(idx, idx)]
        for block, m, samp in left_out_moments(Xs):
            Sig = samp + Kss
            Soo, Sot = Sig[:, :no, :no], Sig[:, :no, no:]
            inn = Xs[block, :no] - m[:, :no]
            for b, tol in enumerate(tols):
                r2 = np.full(no, float(tol) ** 2)
                r2[-1] = _ELL_TOL ** 2
                gain = np.swapaxes(np.linalg.solve(Soo + np.diag(r2), Sot), 1, 2)
                e = (Xs[block, no:] - (m[:, no:] + np.einsum("bij,bj->bi", gain, inn))).reshape(len(block), -1, 3) * sc[3:]
                err[b] += np.sum(e ** 2)
    return float(tols[int(np.argmin(err))])


def record(out, key, sc):
    d = out.setdefault(key, {"end_pos": [], "end_rot": [], "end_time": [], "sp": [], "sr": [], "n": [], "fold": []})
    d["end_pos"] += sc.end_pos
    d["end_rot"] += sc.end_rot
    d["end_time"] += sc.end_time
    d["sp"].append(sc.sp)
    d["sr"].append(sc.sr)
    d["n"].append(sc.n)


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("source")
    ap.add_argument("out")
    ap.add_argument("--folds", type=int, default=5)
    ap.add_argument("--no-sweep", action="store_true")
    ap.add_argument("--no-promp", action="store_true")
    a = ap.parse_args(argv)
    demos, _, _ = load_demonstrations([a.source])
    folds = make_folds(len(demos), a.folds, 0)
    out, choices = {}, []
    t_start = time.time()
    for i, fold in enumerate(folds):
        held = set(int(j) for j in fold)
        train = [d for j, d in enumerate(demos) if j not in held]
        test = [demos[j] for j in fold]
        paths = fit_paths(train)
        before = copy.copy(paths)
        before.rest_smooth = before.rest_tolerance = None  # the anticipation before the fourth pass
        variants = {"base": Anticipator(before, None), "rest": Anticipator(paths, None)}
        smooths = tuple(sorted(set(SMOOTHS) | {float(paths.smooth)}))  # the fitted choice among the candidates
        tols = tuple(sorted(set(TOLS) | {float(paths.seen_tolerance)}))
        sq, ep, er = end_loo(paths, smooths, tols)
        a_, b_ = np.unravel_index(np.argmin(sq.sum(axis=2)), sq.shape[:2])
        variants["end-loo"] = Variant(paths, smooths[a_], tols[b_])
        perF = [np.unravel_index(np.argmin(sq[..., fi]), sq.shape[:2]) for fi in range(len(SEEN_FRACTIONS))]
        gtol = grid_ridge_tol(paths, train, TOLS + (0.025,))
        variants["grid-ridge"] = Variant(paths, TINY, gtol, exact_last=False)
        variants["grid-ridge-last"] = Variant(paths, TINY, gtol, exact_last=True)
        if not a.no_sweep:
            for s in SMOOTHS:
                for r in TOLS:
                    variants[f"sweep:{s}:{r}"] = Variant(paths, s, r)
        perF_vars = {F: Variant(paths, smooths[perF[fi][0]], tols[perF[fi][1]]) for fi, F in enumerate(FRACTIONS)}
        choices.append({"fold": i, "fitted": [paths.smooth, paths.seen_tolerance],
                        "duration": [paths.duration_smooth, paths.duration_tolerance, getattr(paths, "duration_sigma", None)],
                        "end_loo": [smooths[a_], tols[b_]],
                        "end_loo_F": [[smooths[x], tols[y]] for x, y in perF], "grid_ridge_tol": gtol,
                        "loo_end_pos": ep.mean(axis=2).tolist(), "loo_end_rot": er.mean(axis=2).tolist(),
                        "loo_sq": sq.sum(axis=2).tolist(), "smooths": smooths, "tols": tols,
                        "loo_sq_base": float(np.sum(end_loo(paths, [paths.smooth], [paths.seen_tolerance])[0])),
                        "loo_sq_best": float(sq.sum(axis=2)[a_, b_])})
        promp = None if a.no_promp else PhaseProMP(train, ridge_std(train, seed=i))
        for tr in test:
            for F in FRACTIONS:
                seen, rest = split_seen(tr, F)
                D_hat = None
                for name, ant in variants.items():
                    c = ant.continuation(seen.t, seen.quat, seen.position)
                    record(out, (name, F), score(c.trajectories()[0], [], rest))
                    D_hat = c.duration if name == "base" else D_hat
                c = perF_vars[F].continuation(seen.t, seen.quat, seen.position)
                record(out, ("end-loo-F", F), score(c.trajectories()[0], [], rest))
                if promp is not None:
                    mean, _ = promp.predict(seen)
                    record(out, ("promp-ridge", F), score(mean, [], rest))
                    mean, _ = promp.predict(seen, D=D_hat)  # the peer's map at rbgp's duration
                    record(out, ("promp-ridge@rbgp-D", F), score(mean, [], rest))
        print(f"fold {i} done {time.time() - t_start:.0f} s: {choices[-1]}", file=sys.stderr, flush=True)
    # the fold of each motion
    fold_of = np.concatenate([np.full(len(f), i) for i, f in enumerate(folds)]).tolist()
    res = {"source": a.source, "fold_of": fold_of, "choices": choices,
           "records": {f"{k[0]}|{k[1]}": v for k, v in out.items()}}
    with open(a.out, "w") as fh:
        json.dump(res, fh)


if __name__ == "__main__":
    main()
