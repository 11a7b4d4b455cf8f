"""Are two model files the same model? Every array and every number in the headers, to a tolerance.

    .venv/bin/python scripts/compare_models.py A.rbgp B.rbgp [--rtol 1e-12]

Times, provenance and checksums are ignored (they differ between any two runs). Prints the largest
relative difference of each array or header field that differs, and exits 1 if any exceeds ``rtol``
(relative to the larger magnitude, with an absolute floor of ``rtol`` as well).
"""

from __future__ import annotations

import argparse
import io
import json
import sys
import zipfile

import numpy as np

IGNORED = {"seconds", "created_unix", "provenance", "sha256", "checksums", "checksum", "header_sha256",
           "arrays_sha256", "time_s", "created"}


def arrays_and_header(path):
    out = {}
    with zipfile.ZipFile(path) as z:
        for name in z.namelist():
            out[name[:-4]] = np.load(io.BytesIO(z.read(name)), allow_pickle=False)
    header = json.loads(bytes(out.pop("header")).decode()) if out["header"].dtype.kind in "uiS" else None
    return out, header


def walk(a, b, path, diffs, rtol):
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b)):
            if k in IGNORED:
                continue
            if k not in a or k not in b:
                diffs.append((f"{path}.{k}", "missing on one side"))
                continue
            walk(a[k], b[k], f"{path}.{k}", diffs, rtol)
    elif isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            diffs.append((path, f"length {len(a)} != {len(b)}"))
            return
        for i, (x, y) in enumerate(zip(a, b)):
            walk(x, y, f"{path}[{i}]", diffs, rtol)
    elif isinstance(a, (int, float)) and isinstance(b, (int, float)) and not isinstance(a, bool):
        d = abs(a - b) / max(abs(a), abs(b), 1.0)
        if d > rtol:
            diffs.append((path, f"{a!r} != {b!r} (rel {d:.2e})"))
    elif a != b:
        diffs.append((path, f"{str(a)[:80]!r} != {str(b)[:80]!r}"))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("a")
    ap.add_argument("b")
    ap.add_argument("--rtol", type=float, default=1e-12)
    args = ap.parse_args(argv)
    A, ha = arrays_and_header(args.a)
    B, hb = arrays_and_header(args.b)
    diffs = []
    for k in sorted(set(A) | set(B)):
        if k not in A or k not in B:
            diffs.append((k, "array missing on one side"))
            continue
        x, y = np.asarray(A[k], dtype=float), np.asarray(B[k], dtype=float)
        if x.shape != y.shape:
            diffs.append((k, f"shape {x.shape} != {y.shape}"))
            continue
        d = float(np.max(np.abs(x - y) / np.maximum(np.maximum(np.abs(x), np.abs(y)), 1.0))) if x.size else 0.0
        if d > args.rtol or not np.array_equal(np.isnan(x), np.isnan(y)):
            diffs.append((k, f"max rel diff {d:.2e}"))
        elif d > 0:
            print(f"  {k}: equal to {d:.1e}")
    if ha is not None or hb is not None:
        walk(ha, hb, "header", diffs, args.rtol)
    for k, msg in diffs:
        print(f"DIFF {k}: {msg}")
    print("same model" if not diffs else f"{len(diffs)} differences")
    return 1 if diffs else 0


if __name__ == "__main__":
    sys.exit(main())
