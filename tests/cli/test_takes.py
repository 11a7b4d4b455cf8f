"""Cutting what was recorded into demonstrations: breaks in time (issue 24.4), cropping and splitting a
long take at rests (issue 22.8), and what `inspect` says about them."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rbgp_cli.dynamics.prepare import RestSplit, prepare_all
from rbgp_cli.errors import RbgpWarning
from rbgp_cli.io.options import ReadOptions
from rbgp_cli.io.read import read_demonstrations
from tests.cli.test_cli import CSV_DIR, FAST, run

HEADER = "t,x,y,z,qx,qy,qz,qw"


def _csv(t, pos, quat) -> str:
    rows = [HEADER] + [",".join(repr(float(v)) for v in (tt, *p, *q)) for tt, p, q in zip(t, pos, quat)]
    return "\n".join(rows) + "\n"


def _shoe(name="shoe_01.csv"):
    data = np.loadtxt(CSV_DIR / name, delimiter=",", skiprows=1)
    return data[:, 0], data[:, 1:4], data[:, 4:8]


def _gap_file(tmp_path, gap=1e6, name="gappy.csv"):
    """shoe_01 with its second half shifted by ``gap`` seconds (a break between two takes)."""
    t, p, q = _shoe()
    t = t.copy()
    t[len(t) // 2:] += gap
    f = tmp_path / name
    f.write_text(_csv(t, p, q))
    return f, t, p


def _warnings(res):
    return [ln for ln in res.stderr.splitlines() if ln.startswith("rbgp: warning:")]


@pytest.mark.parametrize("gap", [1e6, 30.0])
def test_a_long_gap_splits_the_demonstration_and_says_so(tmp_path, gap):
    f, t, p = _gap_file(tmp_path, gap)
    model = tmp_path / "m.rbgp"
    res = run("train", f, "-o", model, *FAST, "--json")
    assert res.exit_code == 0, res.stderr
    notes = [w for w in _warnings(res) if "split" in w]
    assert len(notes) == 1, res.stderr
    step = t[len(t) // 2] - t[len(t) // 2 - 1]
    assert str(f) in notes[0] and f"{step:.4g} s" in notes[0] and "--split-gap" in notes[0]
    assert json.loads(res.stdout)["demos"] == 2
    info = json.loads(run("info", model, "--json").stdout)
    durations = [d["duration_s"] for d in info["provenance"]["demonstrations"]]
    half = t[len(t) // 2 - 1] - t[0]
    assert max(durations) < 2 * half  # no duration spans the gap
    res = run("rollout", model, "--no-std", "--json", "--output-rate", 0, "-o", tmp_path / "r.csv")
    assert res.exit_code == 0, res.stderr
    out = np.genfromtxt(tmp_path / "r.csv", delimiter=",", names=True, skip_header=1)
    # on the integration grid: the planned duration comes from the pieces, not the gap
    meta = json.loads(res.stdout)
    assert meta["steps"] + 1 == len(out) < 2 * half / meta["dt"] + 2
    span = p.max(axis=0) - p.min(axis=0)
    for k, c in enumerate("xyz"):
        assert out[c].min() > p[:, k].min() - span.max() and out[c].max() < p[:, k].max() + span.max()


def test_split_gap_inf_keeps_the_take_whole(tmp_path):
    f, *_ = _gap_file(tmp_path, 30.0)
    clean, reports = prepare_all(read_demonstrations([str(f)], ReadOptions(split_gap=float("inf"))),
                                 split_gap=float("inf"))
    assert len(clean) == 1 and reports[0]["breaks"] == []


def test_a_two_row_demonstration_in_a_folder_is_left_out_by_name(tmp_path):
    data = tmp_path / "data"
    data.mkdir()
    for name in ("shoe_01.csv", "shoe_02.csv", "shoe_03.csv"):
        (data / name).write_bytes((CSV_DIR / name).read_bytes())
    lines = (CSV_DIR / "shoe_04.csv").read_text().splitlines()
    (data / "tiny.csv").write_text("\n".join(lines[:3]) + "\n")  # header + 2 rows: 0 pairs on the 10 Hz grid
    res = run("train", data, "-o", tmp_path / "m.rbgp", *FAST, "--json")
    assert res.exit_code == 0, res.stderr
    assert json.loads(res.stdout)["demos"] == 3
    notes = [w for w in _warnings(res) if "left out 1 of 4 demonstrations" in w]
    assert len(notes) == 1 and "tiny" in notes[0], res.stderr


def test_inspect_reports_the_break_train_acts_on(tmp_path):
    f, *_ = _gap_file(tmp_path, 1e6)
    res = run("inspect", f, "--json")
    assert res.exit_code == 0, res.stderr
    tr = json.loads(res.stdout)["trajectories"][0]
    assert tr["breaks"]["count"] == 1 and tr["breaks"]["largest_s"] == pytest.approx(1e6, rel=1e-3)
    assert tr["demonstrations"] == 2
    text = run("inspect", f).stdout
    assert "break" in text and "2 demonstrations" in text


# ---------------------------------------------------------------------------------------------------
# one long take: cropping and repetitions at rest


def _long_take(reps=3, rate=100.0, rest=1.0, move=1.5, seed=0):
    """Rest, then ``reps`` × (a reach out and back, rest): 1 m/s-scale motions, tracker noise 0.1 mm."""
    rng = np.random.default_rng(seed)
    segs_t, segs_p, segs_a = [], [], []
    t0 = 0.0
    p_rest = np.array([0.3, 0.0, 1.0])
    for k in range(reps):
        tr = np.arange(0, rest, 1 / rate)
        segs_t.append(t0 + tr)
        segs_p.append(np.repeat(p_rest[None], len(tr), 0))
        segs_a.append(np.zeros(len(tr)))
        t0 += rest
        tm = np.arange(0, move, 1 / rate)
        s = 0.5 - 0.5 * np.cos(2 * np.pi * tm / move)  # out and back, at rest at both ends
        segs_t.append(t0 + tm)
        segs_p.append(p_rest + np.outer(s, [0.4, 0.2 * (k + 1) / reps, 0.1]))
        segs_a.append(0.8 * s)
        t0 += move
    tr = np.arange(0, rest + 1 / rate / 2, 1 / rate)
    segs_t.append(t0 + tr)
    segs_p.append(np.repeat(p_rest[None], len(tr), 0))
    segs_a.append(np.zeros(len(tr)))
    t = np.concatenate(segs_t)
    p = np.concatenate(segs_p) + rng.normal(0, 1e-4, (len(t), 3))
    q = Rotation.from_rotvec(np.outer(np.concatenate(segs_a), [0, 0, 1.0])).as_quat()
    return t, p, q


def test_a_long_take_with_three_repetitions_splits_into_three(tmp_path):
    t, p, q = _long_take(3)
    f = tmp_path / "take.csv"
    f.write_text(_csv(t, p, q))
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        clean, reports = prepare_all(read_demonstrations([str(f)], ReadOptions()), rest=RestSplit())
    assert len(clean) == 3 and reports[0]["rest"][0]["repetitions"] == 3
    for k, c in enumerate(clean):  # each repetition holds its whole motion, starting and ending near rest
        start = 1.0 + k * 2.5
        assert c.t[0] <= start + 0.05 and c.t[-1] >= start + 1.5 - 0.05 and c.duration < 2.0
    assert any("3 repetitions" in str(x.message) for x in w if issubclass(x.category, RbgpWarning))
    res = run("train", f, "-o", tmp_path / "m.rbgp", *FAST, "--split-at-rest", "--json")
    assert res.exit_code == 0, res.stderr
    assert json.loads(res.stdout)["demos"] == 3
    res = run("inspect", f, "--split-at-rest")
    assert res.exit_code == 0 and "3 repetitions" in res.stdout, res.stdout
    # without the option the take stays one demonstration
    assert json.loads(run("inspect", f, "--json").stdout)["trajectories"][0]["demonstrations"] == 1


def test_rest_options_need_split_at_rest(tmp_path):
    t, p, q = _long_take(2)
    f = tmp_path / "take.csv"
    f.write_text(_csv(t, p, q))
    res = run("inspect", f, "--rest-time", "0.3")
    assert res.exit_code == 2 and "--split-at-rest" in res.stderr


def test_cropping_keeps_the_samples_between_the_times(tmp_path):
    t, p, q = _long_take(3)
    f = tmp_path / "take.csv"
    f.write_text(_csv(t + 5.0, p, q))  # times relative to the take's first sample, not to 0
    opts = ReadOptions(crop_from=2.0, crop_to=4.5)
    clean, _ = prepare_all(read_demonstrations([str(f)], opts), **opts.prepare_kwargs())
    (c,) = clean
    rel = t  # the same samples, shifted
    kept = (rel >= 2.0 - 1e-9) & (rel <= 4.5 + 1e-9)
    np.testing.assert_allclose(c.t, t[kept] + 5.0)
    np.testing.assert_allclose(c.position, p[kept])
    res = run("inspect", f, "--crop-from", "2", "--crop-to", "4.5", "--json")
    tr = json.loads(res.stdout)["trajectories"][0]
    assert tr["demonstrations"] == 1 and tr["samples_used"] == int(kept.sum())
    res = run("train", f, "-o", tmp_path / "m.rbgp", "--crop-from", "100")
    assert res.exit_code == 2 and "lasts" in res.stderr and "--crop-from" in res.stderr


def test_takes_without_a_rest_are_said_once_for_the_set():
    """--split-at-rest over takes that never rest (a folder of waves): one warning naming how many and which, not one
    per take."""
    from rbgp_cli.dynamics.trajectory import Trajectory

    takes = []
    for k in range(5):
        t = np.arange(0, 2.0, 0.01)
        pos = np.column_stack([0.3 * np.sin(3 * t + k), 0.2 * t, np.zeros_like(t)])  # always moving
        takes.append(Trajectory(t, np.tile([0, 0, 0, 1.0], (len(t), 1)), pos, name=f"wave_{k}", source=f"/d/wave_{k}.csv"))
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        out, _ = prepare_all(takes, rest=RestSplit())
    said = [str(x.message) for x in w if issubclass(x.category, RbgpWarning) and "no rest" in str(x.message)]
    assert len(out) == 5 and len(said) == 1, said
    assert "no rest in 5 of 5 takes" in said[0] and "wave_0.csv" in said[0] and "1 more" in said[0], said
