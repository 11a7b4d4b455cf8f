"""Tables from scripts/under_way_paired.py's records: per cell the two methods' values, their paired
difference over the held-out motions with its standard error, and the folds' spread of the difference.

Usage: python scripts/under_way_table.py RECORDS.json [A [B]]   (default A = base, B = promp-ridge)
       python scripts/under_way_table.py RECORDS.json --summary  (every method's columns)
       python scripts/under_way_table.py --crossval NAME=OUT.json ...  (``rbgp --json crossval --given F``'s
       output: one markdown row per set, F and method, each value with its paired z against rbgp's row,
       then per set the Done-when verdict of each cell, :func:`verdicts`)

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


def crossval_rows(name, result):
    """Markdown rows of one ``crossval --given F --json`` result: value (z of the paired Δ against rbgp)."""
    out = []
    for r in result["rows"]:
        cells = []
        for c in METRICS:
            v = r[c]
            p = (r.get("paired") or {}).get(c)
            z = "" if not p or p["z"] is None else f" ({p['z']:+.1f}{'!' if abs(p['z']) >= 2 else ''})"
            cells.append(("—" if v is None else f"{v:.3f}") + z)
        cov = "—" if r["cov_pos"] is None else f"{r['cov_pos']:.2f} / {r['cov_rot']:.2f}"
        out.append(f"| {name} | {r['given']:g} | {r['method']} | " + " | ".join(cells) + f" | {cov} |")
    return out


PEERS = ("nearest", "promp", "promp-ridge")


def verdicts(result, row="rbgp"):
    """Per F and column, ``row`` against the best peer (the one with the smallest value): "pass" (no
    worse), "fail (z)" with |z| of the paired Δ below 2 (within noise), "FAIL (z)" at 2 or more."""
    by = {(r["given"], r["method"]): r for r in result["rows"]}
    out = {}
    for F in sorted({r["given"] for r in result["rows"]}):
        ref = by.get((F, row))
        if ref is None:
            continue
        for c in METRICS:
            peers = [by[(F, m)] for m in PEERS if (F, m) in by]
            if not peers:  # measured without the peers: nothing to judge against
                continue
            best = min(peers, key=lambda r: r[c])
            if ref[c] <= best[c] + 5e-4:  # level at the tables' three decimals counts as no worse
                out[(F, c)] = "pass"
                continue
            from rbgp_cli.evaluation.crossval import paired_difference

            mine = {m["index"]: m[c] for m in ref["per_motion"]}
            theirs = [(mine[m["index"]], m[c]) for m in best["per_motion"] if m["index"] in mine]
            z = paired_difference([b for _, b in theirs], [a for a, _ in theirs])["z"]  # the row − the peer
            z = float("nan") if z is None else z
            out[(F, c)] = f"{'FAIL' if abs(z) >= 2 else 'fail'} ({best['method']} {best[c]:.3f}, z {z:+.1f})"
    return out


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    if argv and argv[0] == "--crossval":
        print("| set | F | method | end m | end rad | t s | rest m | rest rad | cov pos / rot |")
        print("|---|---|---|---|---|---|---|---|---|")
        results = [(a.split("=", 1)[0], json.load(open(a.split("=", 1)[1]))) for a in argv[1:]]
        for name, res in results:
            print("\n".join(crossval_rows(name, res)))
        for name, res in results:
            for row in ("rbgp", "no-GP"):
                print(f"\n{name}, {row} against the best peer (cells not passed):")
                for (F, c), v in verdicts(res, row).items():
                    if v != "pass":
                        print(f"  F = {F:g} {c}: {v}")
        return
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
