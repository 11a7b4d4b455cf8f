"""rbgp crossval --grid NAME=V1,V2: any training option repeats, on the same folds, in one table."""

from __future__ import annotations

import json

import pytest
import typer.main
from typer.testing import CliRunner

from rbgp_cli import workflows
from rbgp_cli.cli.app import app
from rbgp_cli.cli.train_options import GRID_LISTS, train_option_names
from tests.evaluation.test_crossval import _write, reaching_demos

runner = CliRunner()
FAST = ["--folds", "3", "--max-points", "60", "--restarts", "1", "--share-hyperparameters", "--jobs", "1", "-q"]


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    return _write(reaching_demos(6), tmp_path_factory.mktemp("grid") / "demos")


def run(*args):
    return runner.invoke(app, ["crossval", *[str(a) for a in args]])


@pytest.mark.slow
def test_two_grids_give_every_combination_labelled_in_the_table_and_the_json(folder):
    res = run(folder, *FAST, "--grid", "prior-gain=3,10", "--grid", "inducing=0,20", "--no-peers", "--json")
    assert res.exit_code == 0, res.stderr
    out = json.loads(res.stdout)
    models = [r for r in out["results"] if r["representation"] != "replay" and not r.get("without_gp")]
    # 2 × 2, each with its row without the GP, and the replay peer, once
    assert len(models) == 4 and len(out["results"]) == 9
    assert sorted((r["options"]["prior-gain"], r["options"]["inducing"]) for r in models) == [
        (3.0, 0), (3.0, 20), (10.0, 0), (10.0, 20)]
    assert {r["label"] for r in models} == {f"axis-angle se-chordal prior-gain={g} inducing={m}"
                                            for g in (3, 10) for m in (0, 20)}
    for r in models:  # the option really reached the fit: inducing 20 trains a sparse GP on every fold
        assert len(r["per_fold"]) == 3
    assert len({r["score"] for r in models}) == 4
    table = run(folder, *FAST, "--grid", "prior-gain=3,10", "--grid", "inducing=0,20")
    assert table.exit_code == 0, table.stderr
    lines = table.stdout.splitlines()
    assert any(line.rstrip().endswith("options") for line in lines)
    for g in (3, 10):
        for m in (0, 20):
            assert sum(line.startswith("axis-angle") and f"prior-gain={g} inducing={m}" in line
                       and "no-GP" not in line for line in lines) == 1


@pytest.mark.slow
def test_a_grid_value_equal_to_the_default_gives_the_numbers_of_the_run_without_grid(folder):
    plain = run(folder, *FAST, "--json")
    from rbgp_cli.dynamics.defaults import DEFAULTS

    gain = DEFAULTS["prior_gain"]
    grid = run(folder, *FAST, "--grid", f"prior-gain={gain:g},default", "--json")  # the default gain twice
    assert plain.exit_code == 0 and grid.exit_code == 0, plain.stderr + grid.stderr
    base = next(r for r in json.loads(plain.stdout)["results"] if r["representation"] == "axis-angle"
                and not r.get("without_gp"))
    rows = [r for r in json.loads(grid.stdout)["results"] if r["representation"] == "axis-angle"
            and not r.get("without_gp")]
    assert len(rows) == 1  # the default's value and 'default' are one value
    for key in ("score", "floor", "position_rmse", "rotation_rmse", "velocity_rmse"):
        assert rows[0][key] == base[key]
    assert base["options"] == {} and rows[0]["options"] == {"prior-gain": gain}


@pytest.mark.parametrize("grid, message", [
    ("prior-gan=3", "'prior-gan' is not a training option; did you mean prior-gain?"),
    ("explore-size=-1", "--grid explore-size=-1: Invalid value for '--explore-size'"),
    ("smooth-degree=two", "--grid smooth-degree=two: Invalid value for '--smooth-degree'"),
    ("rho-rot=abc", "--rho-rot must be a number, got 'abc'"),
    ("time-input=bogus", "--time-input must be one of none, seconds, phase"),
    ("prior-gain", "is not NAME=VALUE"),
    ("prior-gain=3,", "is not NAME=VALUE"),
])
def test_a_bad_option_name_or_value_exits_2_naming_it(folder, grid, message):
    res = run(folder, *FAST, "--grid", grid)
    assert res.exit_code == 2, res.stdout
    assert message in res.stderr
    assert "Traceback" not in res.stderr


def test_a_bad_name_lists_the_valid_ones_and_an_option_given_twice_is_refused(folder):
    res = run(folder, *FAST, "--grid", "nope=1")
    assert res.exit_code == 2 and "expected one of rho-rot, restarts" in res.stderr
    res = run(folder, *FAST, "--prior-gain", "5", "--grid", "prior-gain=3,10")
    assert res.exit_code == 2 and "give --prior-gain or --grid prior-gain=..., not both" in res.stderr
    res = run(folder, *FAST, "--grid", "prior-gain=3", "--grid", "prior-gain=5")
    assert res.exit_code == 2 and "given twice" in res.stderr
    # a combination the options refuse together names the combination
    res = run(folder, *FAST, "--grid", "time-input=none,phase")
    assert res.exit_code == 2 and "(in the --grid combination time-input=none)" in res.stderr


def _crossval_option(name):
    cmd = typer.main.get_command(app).commands["crossval"]
    return next(p for p in cmd.params if p.name == name)


@pytest.mark.slow
def test_every_declared_training_option_is_accepted_by_grid(folder, monkeypatch):
    """Introspected from train_kwargs: an option added there is covered here without editing the test.
    Each gets a grid of its default (spelled as typed) and 'default'; the fold runs are replaced by a
    spy that records the configurations."""
    seen = []

    def spy(sources, configs, **kw):
        seen.append(configs)
        return {"folds": 3, "seed": 0, "demonstrations": 6, "fold_sizes": [2, 2, 2], "floor": 1.0, "results": [],
                "warnings": []}

    monkeypatch.setattr(workflows, "crossval_files", spy)
    names = train_option_names()
    assert {"prior_gain", "inducing", "rho_rot", "share_hyperparameters", "calibrate_noise"} <= set(names)
    for name in names:
        flag = name.replace("_", "-")
        default = _crossval_option(name).default
        typed = str(default).lower() if isinstance(default, bool) else default
        values = "default" if default is None else f"{typed},default"
        res = run(folder, "--grid", f"{flag}={values}", "--no-replay", "--no-peers", "--json")
        assert res.exit_code == 0, (flag, res.stderr)
        configs = seen[-1]
        assert len(configs) == 1, flag  # the default and 'default' are one value
        assert list(configs[0].options) == [flag]
    for name in GRID_LISTS:  # --grid kernel=... is --kernel repeated
        res = run(folder, "--grid", f"{name}={'se,dot' if name == 'kernel' else 'axis-angle,quaternion'}", "--no-replay", "--no-peers")
        assert res.exit_code == 0, res.stderr
        assert len(seen[-1]) == 2
