"""crossval's rows without the GP (issue 35): the same fits with the GP's residual switched off.
Oracle: a GP whose noise is scaled so far that its posterior mean vanishes predicts what the prior
alone predicts, so its row equals the row without the GP; with the GP at work the two differ."""

from __future__ import annotations

import numpy as np
import pytest

from rbgp_cli.evaluation.crossval import REPLAY, Config, crossval
from tests.evaluation.test_crossval import reaching_demos

PATH = {"subsample": 1.0, "max_points": 150, "restarts": 1, "shared": True, "calibrate": False}
COLUMNS = ("score", "position_rmse", "rotation_rmse", "velocity_rmse", "sample_score", "coverage_position")


@pytest.mark.slow
def test_a_muted_gp_equals_its_row_without_the_gp_and_a_working_one_does_not():
    demos = reaching_demos(8)
    muted = Config("axis-angle", "se-chordal", {**PATH, "noise_scale": 1e12}, label="muted")
    working = Config("axis-angle", "se-chordal", {**PATH, "noise_scale": 1.0, "residual_gain": 1.0}, label="working")
    res = crossval(demos, [muted, working, Config(REPLAY)], folds=4, jobs=1, samples=6)
    rows = {r["label"]: r for r in res["results"]}
    assert set(rows) == {"muted", "muted, without the GP", "working", "working, without the GP", REPLAY}
    assert rows["muted, without the GP"]["without_gp"] and not rows["muted"].get("without_gp")
    for c in COLUMNS:
        assert rows["muted"][c] == pytest.approx(rows["muted, without the GP"][c], rel=1e-6, abs=1e-9), c
    # the same fits: the rows without the GP of both configurations follow the same prior mean
    assert rows["muted, without the GP"]["position_rmse"] == pytest.approx(
        rows["working, without the GP"]["position_rmse"], rel=1e-9)
    # a GP at its fitted noise learns this motion's residual: its velocities differ from the prior's
    assert abs(rows["working"]["velocity_rmse"] - rows["working, without the GP"]["velocity_rmse"]) > 1e-3
    assert rows[REPLAY].get("without_gp") is None  # peers have no such row


@pytest.mark.slow
def test_no_row_without_the_gp_for_a_zero_mean_gp_or_when_switched_off():
    demos = reaching_demos(6)
    quick = {"subsample": 1.0, "max_points": 100, "restarts": 1, "shared": True, "time_input": None,
             "prior": None, "velocity": None}
    res = crossval(demos, [Config("axis-angle", "se-chordal", quick)], folds=3, jobs=1, samples=0)
    assert len(res["results"]) == 1  # nothing to switch off: the zero-mean GP has no prior motion
    path = {**PATH, "max_points": 80}
    res = crossval(demos, [Config("axis-angle", "se-chordal", path)], folds=3, jobs=1, samples=0,
                   without_gp=False)
    assert len(res["results"]) == 1
    assert np.isfinite(res["results"][0]["position_rmse"])


@pytest.mark.slow
def test_at_g0_the_row_without_the_gp_is_the_model_row_and_each_fold_says_its_gain(monkeypatch):
    # oracle: the rows without the GP rolled out again (the skip switched off) equal the ones taken over
    from rbgp_cli.evaluation import crossval as cv

    demos = reaching_demos(8)
    off = Config("axis-angle", "se-chordal", {**PATH, "residual_gain": 0.0}, label="off")
    reused = crossval(demos, [off], folds=4, jobs=1, samples=6)
    monkeypatch.setattr(cv, "_same_without_gp", lambda *a: False)
    again = crossval(demos, [off], folds=4, jobs=1, samples=6)
    for a, b in zip(reused["results"], again["results"]):
        assert a["label"] == b["label"]
        for c in COLUMNS + ("coverage_rotation", "score_ratio"):
            assert a.get(c) == b.get(c), (a["label"], c)
        assert [f["residual_gain"] for f in a["per_fold"]] == [0.0] * 4
        assert [f["position_rmse"] for f in a["per_fold"]] == [f["position_rmse"] for f in b["per_fold"]]


def test_the_row_without_the_gp_is_taken_over_only_at_g0_with_samples_that_do_not_read_the_gp():
    from types import SimpleNamespace

    from rbgp_cli.evaluation.crossval import _same_without_gp

    def model(g, variation):
        return SimpleNamespace(residual_off=g == 0.0, residual_gain=g, variation=variation)

    assert _same_without_gp(model(0.0, object()), 20, None)
    assert _same_without_gp(model(0.0, None), 0, None)
    assert _same_without_gp(model(0.0, None), 20, "goal")  # the conditioned samples are the path distribution's
    assert not _same_without_gp(model(0.0, None), 20, None)  # per-step samples draw from the GP's std
    assert not _same_without_gp(model(0.5, object()), 20, None)
