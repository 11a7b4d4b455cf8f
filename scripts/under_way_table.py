"""Tables from scripts/under_way_paired.py's records: per cell the two methods' values, their paired
difference over the held-out motions with its standard error, and the folds' spread of the difference.

Usage: python scripts/under_way_table.py RECORDS.json [A [B]]   (default A = base, B = promp-ridge)
       python scripts/under_way_table.py RECORDS.json --summary  (every method's columns)

end_pos, end_rot, end_time are means over the motions: the difference's standard error is the paired
differences' standard deviation / √n. rest_pos, rest_rot are pooled RMSEs √(mean of each motion's mean
square): the difference √ā − √b̄ and its standard error by the delta method (each motion's
a_i / (2√ā) − b_i / (2√b̄)). The folds' spread is the standard deviation over the folds of the same
difference computed on each fold's motions alone.
"""

from __future__ import annotations

import json
import sys

import numpy as np

METRICS = ("end_pos", "end_rot", "end_time", "rest_pos", "rest_rot")


def per_motion(rec, metric):
    if metric.startswith("rest"):
        s = np.asarray(rec["sp" if metric == "rest_pos" else "sr"]) / np.asarray(rec["n"])
        return s  # mean squares
    return np.asarray(rec[metric])


def value(x, metric):
    return float(np.sqrt(np.mean(x))) if metric.startswith("rest") else float(np.mean(x))


def paired(a, b, metric):
    """(difference, its standard error) of value(a) − value(b)."""
    n = len(a)
    if metric.startswith("rest"):
        ga, gb = np.sqrt(np.mean(a)), np.sqrt(np.mean(b))
        infl = a / (2 * ga) - b / (2 * gb)
        return float(ga - gb), float(np.std(infl, ddof=1) / np.sqrt(n))
    d = a - b
    return float(np.mean(d)), float(np.std(d, ddof=1) / np.sqrt(n))


def load(path):
    res = json.load(open(path))
    recs = {}
    for k, v in res["records"].items():
        name, F = k.rsplit("|", 1)
        recs[(name, float(F))] = v
    return res, recs


def compare(res, recs, A="base", B="promp-ridge"):
    fold_of = np.asarray(res["fold_of"])
    # records are appended per fold in test order, motion by motion: the same order as fold_of
    Fs = sorted({F for (_, F) in recs})
    rows = []
    for F in Fs:
        if (A, F) not in recs or (B, F) not in recs:
            continue
        for metric in METRICS:
            a, b = per_motion(recs[(A, F)], metric), per_motion(recs[(B, F)], metric)
            d, se = paired(a, b, metric)
            fd = [value(a[fold_of == f], metric) - value(b[fold_of == f], metric) for f in np.unique(fold_of)]
            rows.append(dict(F=F, metric=metric, a=value(a, metric), b=value(b, metric), diff=d, se=se,
                             fold_sd=float(np.std(fd, ddof=1)), folds_worse=int(np.sum(np.asarray(fd) > 0)),
                             folds=len(fd)))
    return rows


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    res, recs = load(argv[0])
    if len(argv) > 1 and argv[1] == "--summary":
        names = sorted({n for (n, _) in recs}, key=lambda n: (n.startswith("sweep"), n))
        Fs = sorted({F for (_, F) in recs})
        print("| method | " + " | ".join(f"F={F} end m / rad, t s, rest m / rad" for F in Fs) + " |")
        for n in names:
            cells = []
            for F in Fs:
                r = recs.get((n, F))
                if r is None:
                    cells.append("—")
                    continue
                v = [value(per_motion(r, m), m) for m in METRICS]
                cells.append("{:.3f} / {:.3f}, {:.3f}, {:.3f} / {:.3f}".format(*v))
            print(f"| {n} | " + " | ".join(cells) + " |")
        return
    A = argv[1] if len(argv) > 1 else "base"
    B = argv[2] if len(argv) > 2 else "promp-ridge"
    print(f"| F | column | {A} | {B} | difference ± s.e. | difference / s.e. | folds' s.d. | folds {A} behind |")
    print("|---|---|---|---|---|---|---|---|")
    for r in compare(res, recs, A, B):
        print(f"| {r['F']} | {r['metric']} | {r['a']:.3f} | {r['b']:.3f} | {r['diff']:+.4f} ± {r['se']:.4f} | "
              f"{(r['diff'] / r['se'] if r['se'] > 0 else 0.0):+.1f} | {r['fold_sd']:.4f} | {r['folds_worse']} of {r['folds']} |")


if __name__ == "__main__":
    main()
