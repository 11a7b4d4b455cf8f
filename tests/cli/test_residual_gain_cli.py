"""rbgp train --residual-gain auto|G: the summary and rbgp info say the gain and how it was set; a bad
value is bad usage named as the option, with no model file written."""

from __future__ import annotations

import json

import pytest

from rbgp_cli.cli.app import app
from rbgp_cli.io.model_store import load_model
from tests.cli.common import CSV_DIR, run, runner

FAST = ["--restarts", "1", "--share-hyperparameters", "--explore-size", "100", "--max-points", "300"]


@pytest.mark.slow
def test_a_given_gain_is_kept_and_shown_and_auto_is_chosen_by_left_out_rollouts(tmp_path):
    path = tmp_path / "g.rbgp"
    res = run("train", CSV_DIR, "-o", path, *FAST, "--residual-gain", "0.5", "--json")
    assert res.exit_code == 0, res.stderr
    rec = json.loads(res.stdout)["residual_gain"]
    assert rec == {"gain": 0.5, "chosen": "given"}
    model, header = load_model(path)
    assert model.residual_gain == 0.5 and header["provenance"]["train_options"]["residual_gain"] == 0.5
    info = run("info", path)
    assert info.exit_code == 0 and "GP residual gain: 0.5 (given)" in info.stdout
    assert json.loads(run("info", path, "--json").stdout)["residual_gain"] == 0.5
    # the default: chosen from the grid by rolling out the 9 demonstrations of sample_data left out
    auto = tmp_path / "a.rbgp"
    res = run("train", CSV_DIR, "-o", auto, *FAST, "--json")
    assert res.exit_code == 0, res.stderr
    rec = json.loads(res.stdout)["residual_gain"]
    assert rec["chosen"] == "left-out rollouts" and rec["gain"] in rec["grid"] and rec["demos"] == 9
    assert rec["error"][rec["grid"].index(0.0)] == pytest.approx(1.0)  # relative to the path distribution's
    assert "GP residual gain" in res.stderr
    assert "chosen by rolling out each of 9 demonstrations" in run("info", auto).stdout


@pytest.mark.slow
@pytest.mark.parametrize("value", ["loud", "-1", "101"])
def test_a_bad_gain_is_bad_usage_named_as_the_option(tmp_path, value):
    res = runner.invoke(app, ["train", str(CSV_DIR), "-o", str(tmp_path / "b.rbgp"), "--residual-gain", value])
    assert res.exit_code == 2, res.output
    assert "--residual-gain" in res.stderr and "Traceback" not in res.stderr
    assert len(res.stderr.strip().splitlines()) <= 2 and not (tmp_path / "b.rbgp").exists()
