"""crossval's per-motion errors and the paired comparison of each row with the reference row."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats
from typer.testing import CliRunner

from rbgp_cli.cli.app import app
from rbgp_cli.cli.report import format_crossval
from rbgp_cli.dynamics.trajectory import Trajectory
from rbgp_cli.evaluation import crossval as cv
from rbgp_cli.evaluation.crossval import (REPLAY, Config, crossval, paired_difference, per_motion_errors,
                                          trajectory_errors)
from rbgp_cli.geometry.so3 import exp_quat, quat_multiply
from tests.evaluation.test_crossval import _write, reaching_demos


# ----------------------------------------------------------------------------- paired_difference
def test_paired_difference_is_the_paired_t_statistic_of_hand_made_errors():
    ref = np.array([0.10, 0.12, 0.08, 0.15, 0.11, 0.09, 0.13])
    row = np.array([0.11, 0.12, 0.07, 0.17, 0.13, 0.10, 0.12])
    p = paired_difference(ref, row)
    d = row - ref
    assert p["motions"] == 7
    assert p["difference"] == pytest.approx(d.mean(), abs=1e-15)
    assert p["se"] == pytest.approx(np.std(d, ddof=1) / math.sqrt(7), rel=1e-12)
    assert p["z"] == pytest.approx(stats.ttest_rel(row, ref).statistic, rel=1e-12)
    assert p["closer"] == 2  # motions 3 and 7: the row's error is below the reference's; motion 2 is a tie
    # the other way round: the same size, the other sign, the complementary count without the tie
    q = paired_difference(row, ref)
    assert q["z"] == pytest.approx(-p["z"], rel=1e-12) and q["closer"] == 4


def test_paired_difference_of_a_known_difference_and_its_degenerate_cases():
    rng = np.random.default_rng(3)
    ref = rng.uniform(0.05, 0.2, 400)
    row = ref + 0.01 + rng.normal(0, 0.02, 400)  # truly 0.01 worse, scatter 0.02 per motion
    p = paired_difference(ref, row)
    assert abs(p["difference"] - 0.01) < 3 * 0.02 / 20 and p["se"] == pytest.approx(0.001, rel=0.15)
    assert p["z"] > 5
    same = paired_difference(ref, ref)  # no scatter: no standard error, no z
    assert same["difference"] == 0.0 and same["se"] is None and same["z"] is None and same["closer"] == 0
    one = paired_difference([0.1], [0.2])
    assert one["difference"] == pytest.approx(0.1) and one["se"] is None and one["z"] is None
    with pytest.raises(ValueError, match="same length"):
        paired_difference([0.1, 0.2], [0.1])


# ----------------------------------------------------------------------------- per-motion errors
def _random_trajectories(rng, m, n):
    out = []
    for i in range(m):
        t = np.sort(rng.uniform(0, 2, n))
        t[0], t[-1] = 0.0, 2.0
        q = exp_quat(rng.normal(0, 0.8, (n, 3)))
        out.append(Trajectory(t, q, rng.normal(0, 0.3, (n, 3)), name=f"r{i}"))
    return out


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), m=st.integers(1, 6), T=st.integers(2, 60))
def test_per_motion_sums_pool_to_the_pooled_rmse(seed, m, T):
    """Σ of the per-motion sums over Σ counts is trajectory_errors' pooled RMSE (to 1e-12)."""
    rng = np.random.default_rng(seed)
    gen, ref = _random_trajectories(rng, m, 15), _random_trajectories(rng, m, 21)
    sp, sr, n = trajectory_errors(gen, ref, T)
    mp, mr, mc = per_motion_errors(gen, ref, T)
    assert mp.shape == mr.shape == mc.shape == (m,) and np.all(mc == T) and mc.sum() == n
    assert math.sqrt(mp.sum() / mc.sum()) == pytest.approx(math.sqrt(sp / n), rel=1e-12, abs=1e-15)
    assert math.sqrt(mr.sum() / mc.sum()) == pytest.approx(math.sqrt(sr / n), rel=1e-12, abs=1e-15)


def test_per_motion_errors_of_known_offsets():
    """Each demonstration shifted by its own distance and turned by its own angle: those are its RMSEs."""
    demos = reaching_demos(4)
    shifts, angles = [0.01, 0.02, 0.05, 0.0], [0.3, 0.0, 0.1, 0.2]
    moved = [d.with_(position=d.position + np.array([0.0, s, 0.0]),
                     quat=quat_multiply(d.quat, exp_quat(np.array([0.0, 0.0, a]))))
             for d, s, a in zip(demos, shifts, angles)]
    mp, mr, mc = per_motion_errors(moved, demos, 25)
    np.testing.assert_allclose(np.sqrt(mp / mc), shifts, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(np.sqrt(mr / mc), angles, rtol=1e-9, atol=1e-9)


def test_per_motion_pools_a_motion_over_every_split_that_held_it_out():
    """With repeats a demonstration is held out once per repetition: its RMSE pools those sums."""
    folds = [np.array([0, 2]), np.array([1]), np.array([2, 1]), np.array([0])]
    res = [{"motion_position_sq": [4.0, 1.0], "motion_rotation_sq": [1.0, 0.0], "motion_count": [10, 10]},
           {"motion_position_sq": [9.0], "motion_rotation_sq": [4.0], "motion_count": [10]},
           {"motion_position_sq": [3.0, 7.0], "motion_rotation_sq": [2.0, 4.0], "motion_count": [10, 10]},
           {"motion_position_sq": [6.0], "motion_rotation_sq": [5.0], "motion_count": [20]}]
    out = cv._per_motion(folds, res, ["a", "b", "c"])
    assert [m["index"] for m in out] == [0, 1, 2] and [m["name"] for m in out] == ["a", "b", "c"]
    assert all("source" not in m for m in out)  # motions built in Python have no file
    sourced = cv._per_motion(folds, res, ["hand", "hand", "hand"], ["t1.bvh", None, "t3.bvh"])
    assert [m.get("source") for m in sourced] == ["t1.bvh", None, "t3.bvh"]
    assert [m["position_rmse"] for m in out] == pytest.approx([math.sqrt(10 / 30), math.sqrt(16 / 20), math.sqrt(4 / 20)])
    assert [m["rotation_rmse"] for m in out] == pytest.approx([math.sqrt(6 / 30), math.sqrt(8 / 20), math.sqrt(2 / 20)])
    assert cv._per_motion(folds, [{}] * 4) is None  # results without per-motion sums (an old worker's)


def _row(label, rep, pos, rot=None, **extra):
    pm = [{"index": i, "position_rmse": p, "rotation_rmse": (rot or pos)[i]} for i, p in enumerate(pos)]
    return {"label": label, "representation": rep, "per_motion": pm, **extra}


def test_the_reference_is_the_best_ranked_model_row_with_its_gp():
    rows = [_row("replay", REPLAY, [0.1, 0.2, 0.3]), _row("euler se, without the GP", "euler", [0.2, 0.2, 0.2], without_gp=True),
            _row("euler se", "euler", [0.1, 0.3, 0.2]), _row("nearest", "nearest", [0.3, 0.3, 0.3]),
            _row("quaternion se", "quaternion", [0.1, 0.1, 0.1])]
    assert cv._add_paired(rows) == "euler se"
    assert rows[2]["paired"] is None
    for r in rows[:2] + rows[3:]:
        assert r["paired"]["reference"] == "euler se"
        want = paired_difference([0.1, 0.3, 0.2], [m["position_rmse"] for m in r["per_motion"]])
        assert r["paired"]["position"] == want
    assert rows[4]["paired"]["position"]["closer"] == 2
    peers = [_row("replay", REPLAY, [0.1, 0.2]), _row("promp", "promp", [0.2, 0.1])]
    assert cv._add_paired(peers) == "replay"  # no model row: the first row


# ----------------------------------------------------------------------------- crossval and its table
def test_crossval_rows_carry_per_motion_errors_that_pool_to_their_rmse():
    """Replay rows (no fit, fast): per-motion RMSEs of every held-out demonstration, by index and name,
    whose pooled RMSE (each motion has T steps) is the row's position / rotation RMSE to 1e-12."""
    demos = reaching_demos(7)
    for repeats in (1, 2):
        res = crossval(demos, [Config(REPLAY)], folds=3, jobs=1, samples=0, repeats=repeats)
        row = res["results"][0]
        pm = row["per_motion"]
        assert [m["index"] for m in pm] == list(range(7)) and [m["name"] for m in pm] == [d.name for d in demos]
        pos, rot = np.array([m["position_rmse"] for m in pm]), np.array([m["rotation_rmse"] for m in pm])
        assert math.sqrt(np.mean(pos**2)) == pytest.approx(row["position_rmse"], rel=1e-12)
        assert math.sqrt(np.mean(rot**2)) == pytest.approx(row["rotation_rmse"], rel=1e-12)
        assert res["paired_reference"] == "replay" and row["paired"] is None


def test_given_goal_rows_carry_them_too():
    """--given goal goes through the same rows: the nearest peer's per-motion errors pool to its RMSE."""
    demos = reaching_demos(6)
    res = crossval(demos, [Config(REPLAY)], folds=3, jobs=1, samples=0, given="goal")
    row = res["results"][0]
    assert row["representation"] == "nearest" and len(row["per_motion"]) == 6
    pos = np.array([m["position_rmse"] for m in row["per_motion"]])
    assert math.sqrt(np.mean(pos**2)) == pytest.approx(row["position_rmse"], rel=1e-12)


def test_the_text_shows_the_paired_section_and_marks_large_z():
    demos = reaching_demos(6)
    res = crossval(demos, [Config(REPLAY)], folds=3, jobs=1, samples=0)
    base = res["results"][0]
    worse = {**base, "label": "replay, moved", "per_motion": [{**m, "position_rmse": m["position_rmse"] + 0.01 * (1 + i % 2)}
                                                               for i, m in enumerate(base["per_motion"])]}
    res["results"] = [worse, base]
    res["paired_reference"] = cv._add_paired([base, worse])  # the reference: the first row (no model rows)
    text = format_crossval(res)
    table, _, section = text.partition("\n\npaired against replay on the 6 held-out motions")
    assert section and "representation" in table
    line = next(ln for ln in section.splitlines() if ln.strip().startswith("replay, moved"))
    p = worse["paired"]["position"]
    assert f"{p['difference']:+.4f} ± {p['se']:.4f} z {p['z']:+.2f} !" in line  # z = 4.5: marked
    assert line.rstrip().endswith("0 / 0")  # closer on no motion
    assert worse["paired"]["rotation"]["z"] is None and "+0.0000 ± -" in line


def test_the_text_notes_when_most_fits_switched_the_gp_off_across_gp_rows():
    """Rows that differ only in the GP's representation or kernel, where most fits chose gain 0: one note under the
    table (a new user read three alike rows as three alike representations); none for one GP row or gains of 1."""
    demos = reaching_demos(6)
    res = crossval(demos, [Config(REPLAY)], folds=3, jobs=1, samples=0)
    base = res["results"][0]

    def gp_row(rep, kernel, gains):
        return {**base, "representation": rep, "kernel": kernel, "label": f"{rep} {kernel}",
                "per_fold": [{**f, "residual_gain": g} for f, g in zip(base["per_fold"], gains)]}

    res["paired_reference"] = None
    res["results"] = [gp_row("axis-angle", "se-chordal", [0.0, 0.0, 0.0]), gp_row("euler", "se", [0.0, 0.25, 1.0])]
    assert "note: 4 of 6 fits switched the GP's residual off" in format_crossval(res)
    res["results"] = [gp_row("axis-angle", "se-chordal", [1.0, 1.0, 0.0]), gp_row("euler", "se", [1.0, 0.25, 1.0])]
    assert "note:" not in format_crossval(res)
    res["results"] = [gp_row("axis-angle", "se-chordal", [0.0, 0.0, 0.0])]
    assert "note:" not in format_crossval(res)


@pytest.mark.slow
def test_cli_json_and_table_have_the_paired_comparisons(tmp_path):
    folder = _write(reaching_demos(6), tmp_path / "demos")
    fast = ["--folds", "3", "--max-points", "60", "--restarts", "1", "--share-hyperparameters", "--jobs", "1",
            "--no-peers", "--samples", "0", "-q"]
    res = CliRunner().invoke(app, ["crossval", str(folder), *fast, "--json"])
    assert res.exit_code == 0, res.stderr
    out = json.loads(res.stdout)
    rows = {r["label"]: r for r in out["results"]}
    assert out["paired_reference"] == "axis-angle se-chordal" and rows["axis-angle se-chordal"]["paired"] is None
    for label in ("replay", "axis-angle se-chordal, without the GP"):
        p = rows[label]["paired"]
        assert p["reference"] == "axis-angle se-chordal"
        for key in ("position", "rotation"):
            mine = [m[f"{key}_rmse"] for m in rows[label]["per_motion"]]
            ref = [m[f"{key}_rmse"] for m in rows["axis-angle se-chordal"]["per_motion"]]
            assert p[key]["motions"] == 6 and p[key]["difference"] == pytest.approx(np.mean(np.subtract(mine, ref)))
    assert [m["index"] for m in rows["replay"]["per_motion"]] == list(range(6))
    assert all(m["name"].startswith(f"demo{m['index']}") for m in rows["replay"]["per_motion"])  # file demoI.csv
    text = CliRunner().invoke(app, ["crossval", str(folder), *fast])
    assert text.exit_code == 0, text.stderr
    head, _, section = text.stdout.partition("\n\npaired against axis-angle se-chordal on the 6 held-out motions")
    assert section and "replay" in section and "Δpos_m" in section
    header = next(ln for ln in head.splitlines() if ln.startswith("representation"))
    assert header.split()[-2:] == ["train_s", "left"]  # the table's columns as before
