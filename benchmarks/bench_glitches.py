"""Glitch detection measured: false alarms on real recordings, and what it finds of injected glitches.

Every trajectory of every real file in ``../shared/realdata`` (CSV, TSV and MCAP with pose data; the
options the tests read them with) and of ``sample_data/csv`` is read and prepared as ``rbgp train``
does (:func:`rbgp_cli.dynamics.prepare.prepare_trajectory`, which calls
:func:`rbgp_cli.dynamics.glitches.find_glitches`):

* **false alarms**: samples flagged (or files refused) in the recordings as they are. These files
  are taken to hold no glitch; every flag on them counts as a false alarm.
* **injected glitches**, ``--trials`` per kind per trajectory, each into a copy of the clean
  trajectory at a random sample (seeded):

  - ``jump``: one sample moved by a distance drawn log-uniformly from 0.1 m to 1000 m, in a random
    direction (its rotation unchanged);
  - ``unit block``: ten consecutive rows multiplied by 1000 (millimetres inside a file in metres);
  - ``flip``: one sample's rotation turned by 150°–180° (uniform) about a random axis (position
    unchanged).

  Found: every injected row flagged as a glitch, or the file refused at one of them (a jump that does
  not come back). Collateral: clean rows flagged along with it.

    .venv/bin/python benchmarks/bench_glitches.py                 # 20 trials per kind: about a minute
    .venv/bin/python benchmarks/bench_glitches.py --trials 5      # seconds
    .venv/bin/python benchmarks/bench_glitches.py --markdown table.md
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

import numpy as np

_ROOT = Path(__file__).resolve().parents[1]
if str(_ROOT) not in sys.path:
    sys.path.insert(0, str(_ROOT))

from rbgp_cli.dynamics.prepare import prepare_trajectory  # noqa: E402
from rbgp_cli.errors import InputError, RbgpWarning  # noqa: E402
from rbgp_cli.io.options import ReadOptions  # noqa: E402
from rbgp_cli.io.read import read_demonstrations  # noqa: E402

REALDATA = _ROOT.parent / "shared" / "realdata"
#: The read options the tests use for each folder (tests/cli/test_inspect_train_agree.py).
OPTIONS = {"kth_handover_csv": {"rate": 120.0, "quat_order": "xyzw"}, "mcap_pose": {"topic": "all"},
           "motive_csv": {"body": "all", "length_unit": "cm", "euler_order": "XYZ"}, "qtm_6d_tsv": {"body": "all"}}


def files(realdata: Path):
    for f in sorted(realdata.glob("*/*")):
        if f.parent.name != "mcap_no_pose" and f.is_file() and f.suffix in (".csv", ".tsv", ".mcap"):
            yield f.parent.name, f, OPTIONS.get(f.parent.name, {})
    for f in sorted((_ROOT / "sample_data" / "csv").glob("*.csv")):
        yield "sample_data", f, {}


def prepare(traj):
    """(glitch rows as a set of raw indices, refused at raw index or None)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RbgpWarning)
        try:
            _, rep = prepare_trajectory(traj)
        except InputError as exc:
            if "does not come back" in exc.message:
                return set(), exc.row
            raise
    first = traj.info.get("first_data_line", 1) if traj.info else 1
    flagged = set()
    for kind, a, b in rep["glitch_rows"]:
        lo, hi = (a - first, b - first) if kind == "line" else (a - 1, b - 1)
        flagged.update(range(lo, hi + 1))
    return flagged, None


def _random_axis(rng) -> np.ndarray:
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def inject(clean, kind: str, rng):
    """A copy of the clean trajectory with one glitch; returns (trajectory, injected raw rows)."""
    from scipy.spatial.transform import Rotation

    n = len(clean.t)
    p, q = clean.position.copy(), clean.quat.copy()
    if kind == "jump":
        k = int(rng.integers(n))
        p[k] += 10 ** rng.uniform(-1, 3) * _random_axis(rng)
        rows = [k]
    elif kind == "unit block":
        k = int(rng.integers(n - 10))
        p[k:k + 10] *= 1000.0
        rows = list(range(k, k + 10))
    else:  # flip
        k = int(rng.integers(n))
        turn = Rotation.from_rotvec(np.radians(rng.uniform(150, 180)) * _random_axis(rng))
        q[k] = (turn * Rotation.from_quat(q[k])).as_quat()
        rows = [k]
    info = {"first_data_line": 1}
    return clean.with_(position=p, quat=q, info=info), rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--realdata", type=Path, default=REALDATA)
    ap.add_argument("--trials", type=int, default=20, help="injected glitches per kind per trajectory")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--markdown", type=Path, help="also write the tables here")
    args = ap.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    rows_false: dict = {}
    found: dict = {k: [0, 0, 0] for k in ("jump", "unit block", "flip")}  # found, trials, collateral rows
    for folder, f, opts in files(args.realdata):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RbgpWarning)
            raw = read_demonstrations([str(f)], ReadOptions(**opts))
        for traj in raw:
            flagged, refused = prepare(traj)
            s = rows_false.setdefault(folder, [0, 0, 0, 0])  # trajectories, samples, flagged samples, refused
            s[0] += 1
            s[1] += len(traj.t)
            s[2] += len(flagged)
            s[3] += refused is not None
            if refused is not None or flagged:
                print(f"false alarm: {f.name} {traj.name}: flagged {sorted(flagged)[:10]} refused {refused}")
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RbgpWarning)
                clean, _ = prepare_trajectory(traj)
            if len(clean.t) < 20:
                continue
            for kind in found:
                for _ in range(args.trials):
                    bad, rows = inject(clean, kind, rng)
                    flagged, refused = prepare(bad)
                    refused_idx = None if refused is None else refused - 1
                    ok = set(rows) <= flagged or (refused_idx in rows)
                    found[kind][0] += ok
                    found[kind][1] += 1
                    found[kind][2] += len(flagged - set(rows))
    lines = ["| recordings | trajectories | samples | samples flagged | files refused | false-alarm rate |",
             "|---|---:|---:|---:|---:|---:|"]
    tot = [0, 0, 0, 0]
    for folder, (n, samples, fl, ref) in rows_false.items():
        lines.append(f"| {folder} | {n} | {samples} | {fl} | {ref} | {fl / samples:.2%} |")
        tot = [a + b for a, b in zip(tot, (n, samples, fl, ref))]
    lines.append(f"| all | {tot[0]} | {tot[1]} | {tot[2]} | {tot[3]} | {tot[2] / max(tot[1], 1):.2%} |")
    lines += ["", "| injected | trials | found | found rate | clean rows flagged with it |", "|---|---:|---:|---:|---:|"]
    for kind, (ok, n, coll) in found.items():
        lines.append(f"| {kind} | {n} | {ok} | {ok / max(n, 1):.2%} | {coll} |")
    text = "\n".join(lines)
    print(text)
    if args.markdown:
        args.markdown.write_text(text + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
