"""Repeated cross-validation (``crossval(repeats=R)``, ``rbgp crossval --repeats``): R sets of folds from
consecutive seeds, each repetition the run its seed alone would give."""

from __future__ import annotations

import json
import math

import pytest
from typer.testing import CliRunner

from rbgp_cli.cli.app import app
from rbgp_cli.evaluation.crossval import REPLAY, Config, crossval
from rbgp_cli.errors import InputError
from tests.evaluation.test_crossval import QUICK, reaching_demos

KEYS = ("score", "floor", "position_rmse", "rotation_rmse")


def test_each_repetition_is_the_run_of_its_own_fold_seed_and_the_rows_pool_them():
    demos = reaching_demos(9)
    configs = [Config("axis-angle", "se-chordal", QUICK), Config(REPLAY)]
    both = crossval(demos, configs, folds=3, seed=4, repeats=2, samples=5, jobs=1)
    first = crossval(demos, configs, folds=3, seed=4, samples=5, jobs=1)
    second = crossval(demos, configs, folds=3, seed=5, samples=5, jobs=1)
    assert both["repeats"] == 2 and both["folds"] == 3 and len(both["fold_sizes"]) == 3
    assert "by_repeat" not in first["results"][0] and first["repeats"] == 1
    for label in ("axis-angle", "replay"):
        row = next(r for r in both["results"] if r["label"].startswith(label))
        one = next(r for r in first["results"] if r["label"].startswith(label))
        two = next(r for r in second["results"] if r["label"].startswith(label))
        assert [f["repeat"] for f in row["per_fold"]] == [0, 0, 0, 1, 1, 1]
        assert [f["fold"] for f in row["per_fold"]] == [0, 1, 2, 0, 1, 2]
        # the first repetition is the run of seed 4, samples and all (the same draws)
        for f, g in zip(row["per_fold"][:3], one["per_fold"]):
            assert {k: f[k] for k in KEYS + ("sample_score",)} == {k: g[k] for k in KEYS + ("sample_score",)}
        # the second: the folds and models of seed 5 (its samples are drawn afresh)
        for f, g in zip(row["per_fold"][3:], two["per_fold"]):
            assert {k: f[k] for k in KEYS} == {k: g[k] for k in KEYS}
        assert [b["seed"] for b in row["by_repeat"]] == [4, 5]
        assert math.isclose(row["by_repeat"][0]["ratio"], one["ratio"], rel_tol=1e-12)
        assert math.isclose(row["by_repeat"][1]["ratio"], two["ratio"], rel_tol=1e-12)
        # the row is over all six splits
        assert math.isclose(row["score"], sum(f["score"] for f in row["per_fold"]) / 6, rel_tol=1e-12)
        assert math.isclose(row["floor"], (one["floor"] + two["floor"]) / 2, rel_tol=1e-12)
    model = next(r for r in both["results"] if r["label"].startswith("axis-angle"))
    assert all(b["sample_ratio"] is not None and b["sample_ratio"] > 0 for b in model["by_repeat"])


@pytest.mark.parametrize("bad", [0, -1, 1.5, True])
def test_repeats_must_be_a_whole_number_of_at_least_one(bad):
    with pytest.raises(InputError, match="repeats"):
        crossval(reaching_demos(4), [Config(REPLAY)], folds=2, repeats=bad, jobs=1)


def test_the_command_reports_each_repetition(tmp_path):
    from tests.evaluation.test_crossval import _write

    _write(reaching_demos(6), tmp_path / "demos")
    tmp_path = tmp_path / "demos"
    runner = CliRunner()
    res = runner.invoke(app, ["crossval", str(tmp_path), "--folds", "3", "--repeats", "2", "--no-peers", "--samples", "0",
                              "--restarts", "1", "--max-points", "80", "--jobs", "1", "-q"])
    assert res.exit_code == 0, res.output
    assert "2 repeats (fold seeds 0–1)" in res.stdout and "per repetition" in res.stdout
    out = runner.invoke(app, ["crossval", str(tmp_path), "--folds", "3", "--repeats", "2", "--no-peers", "--samples", "0",
                              "--restarts", "1", "--max-points", "80", "--jobs", "1", "-q", "--json"])
    result = json.loads(out.stdout)
    assert result["repeats"] == 2 and all(len(r["by_repeat"]) == 2 for r in result["results"])
    bad = runner.invoke(app, ["crossval", str(tmp_path), "--repeats", "0", "-q"])
    assert bad.exit_code == 2
