"""Cross-validation by demonstration (rbgp crossval): folds, floor, replay peer, errors, determinism."""

from __future__ import annotations

import json
import math
import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from rbgp_cli.cli.app import app
from rbgp_cli.dynamics.trajectory import Trajectory
from rbgp_cli.evaluation import evaluate
from rbgp_cli.evaluation import crossval as cv
from rbgp_cli.evaluation.crossval import REPLAY, Config, crossval, make_folds, replay_nearest, sample_seed, trajectory_errors
from rbgp_cli.geometry.so3 import exp_quat, quat_multiply
from tests.helpers import quat_angle_between

QUICK = {"subsample": 1.0, "max_points": 120, "restarts": 1, "shared": True, "time_input": None, "prior": None,
         "velocity": None}


def reaching_demos(n=8, seed=0, samples=40):
    """Demonstrations of one stable motion: from scattered start poses, the pose converges to a common
    goal as e^{−kt} (p = g + (p0 − g)e^{−kt}, R = exp(e^{−kt} φ0) R_g): a smooth autonomous velocity
    field ξ = −k·(log(R R_gᵀ), p − p_g) that a GP on poses can learn from a few demonstrations."""
    rng = np.random.default_rng(seed)
    goal_p, goal_r = np.array([0.8, 0.3, 1.1]), np.array([0.0, 0.0, 1.2])
    out = []
    for i in range(n):
        T = rng.uniform(1.6, 2.4)
        t = np.linspace(0.0, T, samples)
        decay = np.exp(-2.0 * t)
        p0 = np.array([0.4, -0.2, 0.9]) + rng.normal(0, 0.1, 3)
        phi0 = rng.normal(0, 0.3, 3)
        p = goal_p + decay[:, None] * (p0 - goal_p)
        q = quat_multiply(exp_quat(decay[:, None] * phi0), exp_quat(goal_r))
        out.append(Trajectory(t + rng.uniform(0, 5), q, p, name=f"demo{i}", source=f"demo{i}.csv"))
    return out


@settings(max_examples=60, deadline=None)
@given(n=st.integers(2, 40), k=st.integers(2, 12), seed=st.integers(0, 1000))
def test_folds_hold_out_every_demonstration_once(n, k, seed):
    """Folds partition the demonstrations (each held out exactly once; sizes differ by at most one)."""
    if k > n:
        with pytest.raises(Exception):
            make_folds(n, k, seed)
        return
    folds = make_folds(n, k, seed)
    allidx = np.concatenate(folds)
    assert sorted(allidx.tolist()) == list(range(n))
    sizes = [len(f) for f in folds]
    assert max(sizes) - min(sizes) <= 1 and len(folds) == k
    assert [f.tolist() for f in make_folds(n, k, seed)] == [f.tolist() for f in folds]  # seeded


@pytest.mark.slow
def test_training_never_sees_a_held_out_demonstration(monkeypatch):
    """Every fit trains on exactly the demonstrations outside its fold, and rolls out from the held-out
    ones' own starts: no demonstration leaks across folds."""
    demos = reaching_demos(9)
    seen = []

    def spy(config, train, test, **kw):
        seen.append(({d.name for d in train}, [d.name for d in test]))
        return real(config, train, test, **kw)

    real = cv.run_fold
    monkeypatch.setattr(cv, "run_fold", spy)
    crossval(demos, [Config("axis-angle", "se-chordal", QUICK)], folds=3, jobs=1)
    assert len(seen) == 3
    for train, test in seen:
        assert not train & set(test)
        assert len(train) + len(test) == 9
    assert sorted(n for _, test in seen for n in test) == sorted(d.name for d in demos)


def test_floor_is_the_held_out_demonstrations_scored_on_the_same_steps():
    """The floor of a fold is evaluate(held-out, training) with the steps the generated set is scored on."""
    demos = reaching_demos(8)
    res = crossval(demos, [Config(REPLAY)], folds=4, jobs=1, seed=3)
    folds = make_folds(8, 4, 3)
    row = res["results"][0]
    for f, test_idx in enumerate(folds):
        train = [d for i, d in enumerate(demos) if i not in set(test_idx)]
        test = [demos[i] for i in test_idx]
        floor = evaluate(test, train, sample_size="record")
        assert row["per_fold"][f]["floor"] == pytest.approx(floor.mean, rel=1e-12)
    assert res["floor"] == pytest.approx(np.mean([f["floor"] for f in row["per_fold"]]))
    # replaying the held-out demonstrations themselves would score exactly the floor
    assert row["ratio"] == pytest.approx(row["score"] / row["floor"])


def test_replay_moves_the_nearest_demonstration_rigidly():
    demos = reaching_demos(5)
    q_new = quat_multiply(exp_quat(np.array([0.0, 0.3, 0.0])), demos[2].quat[0])
    p_new = demos[2].position[0] + np.array([0.01, 0.0, -0.02])
    rep = replay_nearest(demos, q_new, p_new)
    assert rep.name == "replay of demo2"
    assert quat_angle_between(rep.quat[0], q_new) < 1e-12
    np.testing.assert_allclose(rep.position[0], p_new, atol=1e-15)
    # the relative motion is unchanged: pairwise distances between samples and relative rotations
    src = demos[2]
    np.testing.assert_allclose(np.linalg.norm(rep.position - rep.position[0], axis=1),
                               np.linalg.norm(src.position - src.position[0], axis=1), atol=1e-12)
    rel_rep = quat_angle_between(rep.quat[0][None], rep.quat)
    rel_src = quat_angle_between(src.quat[0][None], src.quat)
    np.testing.assert_allclose(rel_rep, rel_src, atol=1e-9)
    np.testing.assert_allclose(rep.t, src.t - src.t[0])


def test_trajectory_errors_are_zero_for_identical_and_known_for_offsets():
    demos = reaching_demos(3)
    sp, sr, n = trajectory_errors(demos, demos, 30)
    assert sp == pytest.approx(0.0, abs=1e-20) and sr == pytest.approx(0.0, abs=1e-20) and n == 90
    shifted = [d.with_(position=d.position + np.array([0.0, 0.03, 0.04])) for d in demos]
    sp, sr, n = trajectory_errors(shifted, demos, 30)
    assert math.sqrt(sp / n) == pytest.approx(0.05, rel=1e-9)
    turned = [d.with_(quat=quat_multiply(d.quat, exp_quat(np.array([0.2, 0.0, 0.0])))) for d in demos]
    sp, sr, n = trajectory_errors(turned, demos, 30)
    assert math.sqrt(sr / n) == pytest.approx(0.2, rel=1e-9)


@pytest.mark.slow
def test_results_do_not_depend_on_the_number_of_worker_processes():
    demos = reaching_demos(6)
    configs = [Config("axis-angle", "se-chordal", QUICK), Config(REPLAY)]
    a = crossval(demos, configs, folds=3, jobs=1)
    b = crossval(demos, configs, folds=3, jobs=2)
    strip = lambda r: [{k: v for k, v in row.items() if k not in ("train_s", "per_fold")} for row in r["results"]]  # noqa: E731
    assert strip(a) == strip(b)


@pytest.mark.slow
def test_model_rows_and_velocity_rmse_on_a_learnable_motion():
    """On demonstrations of one smooth motion a model generalises to held-out starts: its velocity
    RMSE is far below predicting zero (1.0), and the rows are sorted by score / floor."""
    demos = reaching_demos(8)
    res = crossval(demos, [Config("axis-angle", "se-chordal", QUICK), Config(REPLAY)], folds=4, jobs=1)
    rows = {r["representation"]: r for r in res["results"]}
    assert rows["axis-angle"]["velocity_rmse"] < 0.5
    assert rows[REPLAY]["velocity_rmse"] is None and rows[REPLAY]["train_s"] == 0.0
    assert [r["ratio"] for r in res["results"]] == sorted(r["ratio"] for r in res["results"])
    for r in res["results"]:
        assert len(r["per_fold"]) == 4 and all(np.isfinite([r["score"], r["floor"], r["position_rmse"], r["rotation_rmse"]]))


def test_a_fold_of_one_held_out_demonstration_is_flagged():
    demos = reaching_demos(5)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = crossval(demos, [Config(REPLAY)], folds=4, jobs=1)
    assert any("hold out only one" in str(w.message) for w in caught)
    assert not res["results"][0]["reliable"]


# ----------------------------------------------------------------------------- command line
def _write(demos, folder):
    from rbgp_cli.io.csv import write_trajectories_csv

    folder.mkdir()
    for d in demos:
        write_trajectories_csv([d.with_(t=d.t - d.t[0])], str(folder / f"{d.name}.csv"))
    return folder


@pytest.mark.slow
def test_cli_json_has_the_documented_keys(tmp_path):
    folder = _write(reaching_demos(6), tmp_path / "demos")
    res = CliRunner().invoke(app, ["crossval", str(folder), "--folds", "3", "--representation", "all", "--kernel", "se",
                                   "--max-points", "100", "--restarts", "1", "--share-hyperparameters", "--jobs", "1",
                                   "--no-peers", "--json", "-q"])
    assert res.exit_code == 0, res.stderr
    out = json.loads(res.stdout)
    assert out["folds"] == 3
    keys = {"representation", "kernel", "score", "floor", "ratio", "rotation", "translation", "position_rmse",
            "rotation_rmse", "velocity_rmse", "train_s", "per_fold"}
    reps = {r["representation"] for r in out["results"]}
    assert reps == {"axis-angle", "euler", "quaternion", "replay"}
    for r in out["results"]:
        assert keys <= set(r)
        assert len(r["per_fold"]) == 3
    assert res.stderr == ""  # -q: no progress


@pytest.mark.slow
def test_cli_table_and_bad_options(tmp_path):
    folder = _write(reaching_demos(4), tmp_path / "demos")
    runner = CliRunner()
    res = runner.invoke(app, ["crossval", str(folder), "--folds", "2", "--max-points", "80", "--restarts", "1",
                              "--jobs", "1", "--per-fold", "--no-peers"])
    assert res.exit_code == 0, res.stderr
    assert "representation" in res.stdout and "replay" in res.stdout and "fold 2" in res.stdout
    assert "cross-validation" in res.stderr  # progress on stderr
    res = runner.invoke(app, ["crossval", str(folder), "--folds", "5"])
    assert res.exit_code == 2 and "4 demonstrations cannot make 5 folds" in res.stderr
    res = runner.invoke(app, ["crossval", str(folder), "--representation", "dual-quaternion"])
    assert res.exit_code == 2 and "unknown representation" in res.stderr


@pytest.mark.slow
def test_sample_columns_score_one_sample_per_start_and_pool_the_coverage(monkeypatch):
    """docs/method.md §11 in crossval: sample_score is one sampled rollout per held-out start scored as score is
    (against the training demonstrations), sample_ratio its ratio to the floor, and the coverage columns
    pool the held-out motions' steps over the folds; the replay peer has none; samples=0 turns them off."""
    from rbgp_cli.evaluation.coverage import Coverage, prediction_coverage

    demos = reaching_demos(8)
    configs = [Config("axis-angle", "se-chordal", QUICK), Config(REPLAY)]
    res = crossval(demos, configs, folds=4, jobs=1, samples=6)
    rows = {r["representation"]: r for r in res["results"]}
    row = rows["axis-angle"]
    for key in ("coverage_position", "coverage_rotation"):
        assert 0.0 <= row[key] <= 1.0
    assert row["band_position"] > 0 and row["band_rotation"] > 0
    assert row["sample_ratio"] == pytest.approx(row["sample_score"] / row["floor"])
    assert row["sample_score"] == pytest.approx(np.mean([f["sample_score"] for f in row["per_fold"]]))
    # the score's two terms, for the mean rollouts, the samples and the floor (docs/method.md §9)
    for prefix in ("", "sample_", "floor_"):
        off, spr = row[prefix + "offset"], row[prefix + "spread"]
        assert off >= 0 and spr >= 0
        whole = row["floor"] if prefix == "floor_" else row[prefix + "score"]
        assert off + spr == pytest.approx(whole, rel=1e-9)
    assert rows[REPLAY]["offset"] + rows[REPLAY]["spread"] == pytest.approx(rows[REPLAY]["score"], rel=1e-9)
    assert all(rows[REPLAY][k] is None for k in ("sample_score", "coverage_position", "band_rotation",
                                                 "coverage_position_se"))
    assert row["coverage_position_se"] > 0 and row["coverage_rotation_se"] >= 0
    # one fold recomputed by hand: the model's samples from the held-out starts, seeded as crossval seeds them
    from rbgp_cli.dynamics.model import train_model
    from rbgp_cli.dynamics.rollout import rollout_for

    test_idx = make_folds(len(demos), 4, 0)[0]
    test = [demos[i] for i in test_idx]
    train = [d for i, d in enumerate(demos) if i not in set(test_idx)]
    m = train_model(train, representation="axis-angle", kernel="se-chordal", **QUICK)
    r = rollout_for(m, np.array([t.quat[0] for t in test]), np.array([t.position[0] for t in test]),
                    [t.duration for t in test], with_std=False, samples=6, seed=sample_seed(0, 0))
    trajs = r.trajectories(include_samples=True)[len(test):]
    T = evaluate(test, train).steps  # the length crossval resamples to (the training demonstrations' median)
    fold0 = row["per_fold"][0]
    # the score of each set of one sample per start (sample k of every start), and their mean
    sets = [evaluate([trajs[b * 6 + k] for b in range(len(test))], train, length=T).mean for k in range(6)]
    assert fold0["sample_score"] == pytest.approx(np.mean(sets), rel=1e-9)
    assert fold0["sample_score_one"] == pytest.approx(sets[0], rel=1e-9)
    assert np.std(sets) > 0  # the sets differ: averaging them is not a no-op
    # each fold draws its own numbers: fold 1's samples are not fold 0's seed again
    assert sample_seed(0, 1) != sample_seed(0, 0) and sample_seed(1, 0) != sample_seed(0, 0)
    # the coverage is the band's rbgp gives with its samples (around the mean rollout), not the samples' own
    from rbgp_cli.evaluation.coverage import band_coverage

    cov, own, each = Coverage(), Coverage(), []
    for b, (real, mean) in enumerate(zip(test, r.trajectories()[:len(test)])):
        n = len(mean.t)
        each.append(band_coverage(mean, r.band_position[b, :n], r.band_rotation[b, :n], real, T).to_dict())
        cov = cov + band_coverage(mean, r.band_position[b, :n], r.band_rotation[b, :n], real, T)
        own = own + prediction_coverage(trajs[b * 6:(b + 1) * 6], real, T)
    # the fold's SE over its held-out motions (each T steps: the standard error of their mean coverage)
    for key in ("coverage_position", "coverage_rotation"):
        per = [e[key] for e in each]
        assert fold0[key + "_se"] == pytest.approx(np.std(per, ddof=1) / np.sqrt(len(per)), rel=1e-9, abs=1e-15)
    assert fold0["coverage_position"] == pytest.approx(cov.to_dict()["coverage_position"])
    assert fold0["coverage_rotation"] == pytest.approx(cov.to_dict()["coverage_rotation"])
    assert fold0["band_position"] == pytest.approx(cov.to_dict()["band_position"])
    assert own.to_dict()["band_position"] != pytest.approx(cov.to_dict()["band_position"])
    off = crossval(demos, configs[:1], folds=4, jobs=1, samples=0)["results"][0]
    assert off["sample_score"] is None and off["score"] == pytest.approx(row["score"])
