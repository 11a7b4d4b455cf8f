"""rbgp train --calibrate-noise: the summary gives the factors, the model file keeps the fitted σn and
predicts with the scaled one after loading; crossval takes the option too."""

from __future__ import annotations

import json

import numpy as np
import pytest

from rbgp_cli.cli.app import app
from rbgp_cli.cli.report import format_train_summary
from rbgp_cli.io.model_store import load_model, read_header
from tests.cli.common import CSV_DIR, run, runner

FAST = ["--restarts", "1", "--share-hyperparameters", "--explore-size", "100", "--max-points", "400"]


@pytest.mark.parametrize("gp", ["exact", "sparse"])
@pytest.mark.slow
def test_train_calibrate_noise_scales_the_posterior_noise_and_the_model_file_says_how(tmp_path, gp):
    path = tmp_path / "m.rbgp"
    extra = ["--inducing", "48"] if gp == "sparse" else []
    res = run("train", CSV_DIR, "-o", path, *FAST, *extra, "--calibrate-noise", "--json")
    assert res.exit_code == 0, res.stderr
    summary = json.loads(res.stdout)
    cal = summary["gp"]["calibration"]
    assert len(cal["noise_variance_factors"]) == 1 and cal["noise_variance_factors"][0] >= 1
    # each training demonstration of sample_data (9) held out alone, on at most 1000 points
    assert cal["folds"] in (8, 9) and cal["points"] <= 1000
    assert "noise calibration: sigma_n^2 x" in res.stderr
    assert "by held-out demonstrations (fitted σn=" in format_train_summary(summary)
    out = summary["outputs"][0]
    fitted = out["calibration"]["noise_std_fitted"]
    # the calibrated factor, times the default noise scale (dynamics/defaults.py) after it
    scale = out["calibration"].get("extra_factor", 1.0)
    assert scale == summary["gp"]["noise_scale"]
    assert out["values"]["noise_std"] == pytest.approx(fitted * np.sqrt(out["calibration"]["factor"] * scale))
    header, _arrays = read_header(path)
    assert header["provenance"]["train_options"]["calibrate"] is True
    model, _ = load_model(path)
    stored = model.gp.fits[0].calibration
    assert stored["factor"] == pytest.approx(out["calibration"]["factor"]) and stored["errors"] == out["calibration"]["errors"]
    # the loaded posterior is the one with the scaled noise, recomputed from the training points
    kind = type(model.gp)
    args = (model.gp.kernel, model.gp.X, model.gp.Y) + ((model.gp.Z,) if gp == "sparse" else ())
    again = kind(*args, model.gp.fits, shared=True, y_scale=model.gp.y_scale)
    np.testing.assert_allclose(model.gp.predict(model.gp.X[:40]), again.predict(model.gp.X[:40]), atol=1e-8)
    res = run("info", path)
    assert res.exit_code == 0 and "by held-out demonstrations; fitted σn=" in res.stdout + res.stderr
    # the default is calibrated (dynamics/defaults.py); --no-calibrate-noise: no calibration, the fitted σn
    res = run("train", CSV_DIR, "-o", tmp_path / "default.rbgp", *FAST, *extra, "--json")
    assert json.loads(res.stdout)["gp"]["calibration"] == cal
    res = run("train", CSV_DIR, "-o", tmp_path / "plain.rbgp", *FAST, *extra, "--no-calibrate-noise", "--json")
    plain = json.loads(res.stdout)
    # no calibration: the fitted σn, times the default noise scale alone (its own record)
    assert plain["gp"].get("calibration") is None
    record = plain["outputs"][0]["calibration"]
    assert record["factor"] == 1.0 and record["extra_factor"] == plain["gp"]["noise_scale"]
    res = run("train", CSV_DIR, "-o", tmp_path / "raw.rbgp", *FAST, *extra, "--no-calibrate-noise",
              "--noise-scale", "1", "--json")
    assert json.loads(res.stdout)["outputs"][0]["calibration"] is None  # nothing scaled, nothing recorded


@pytest.mark.slow
def test_crossval_takes_the_option():
    res = run("crossval", CSV_DIR, "--folds", "3", *FAST, "--representation", "axis-angle", "--calibrate-noise", "--no-peers", "--json")
    assert res.exit_code == 0, res.stderr
    rows = json.loads(res.stdout)["results"]
    assert any(r.get("velocity_rmse") is not None and np.isfinite(r["score"]) for r in rows)


@pytest.mark.slow
def test_train_noise_scale_multiplies_the_calibrated_noise_and_the_model_file_keeps_it(tmp_path):
    # the gain given, so that both runs take the full fit: with `auto` the cheap fit's verdict on the
    # residual depends on the noise scale, and one run may keep the cheap fit's hyperparameters
    pinned = [*FAST, "--residual-gain", "1"]
    res = run("train", CSV_DIR, "-o", tmp_path / "a.rbgp", *pinned, "--noise-scale", "1", "--json")
    base = json.loads(res.stdout)["outputs"][0]
    path = tmp_path / "b.rbgp"
    res = run("train", CSV_DIR, "-o", path, *pinned, "--noise-scale", "16", "--json")
    assert res.exit_code == 0, res.stderr
    summary = json.loads(res.stdout)
    out = summary["outputs"][0]
    assert summary["gp"]["noise_scale"] == 16.0 and "noise scale: sigma_n^2 x 16" in res.stderr
    assert out["values"]["noise_std"] == pytest.approx(base["values"]["noise_std"] * 4.0)
    assert out["calibration"]["extra_factor"] == 16.0
    header, _ = read_header(path)
    assert header["provenance"]["train_options"]["noise_scale"] == 16.0
    model, _ = load_model(path)
    assert model.gp.fits[0].values["noise_std"] == pytest.approx(out["values"]["noise_std"])
    # below 1 is bad usage, named as the option
    res = runner.invoke(app, ["train", str(CSV_DIR), "-o", str(tmp_path / "c.rbgp"), "--noise-scale", "0.5"])
    assert res.exit_code == 2 and "--noise-scale" in res.stderr and not (tmp_path / "c.rbgp").exists()


def test_the_summary_names_each_factor_on_the_noise():
    """With the noise scale on by default, the summary said "σn² × 1 by held-out demonstrations" where
    no calibration ran (one demonstration) and left the noise scale out where one did."""
    from rbgp_cli.cli.report import _noise_factors

    only_scale = {"factor": 1.0, "noise_std_fitted": 0.1, "extra_factor": 256.0}
    assert _noise_factors(only_scale) == "σn² × 256 noise scale"
    both = {"factor": 16.0, "noise_std_fitted": 0.1, "errors": [0.5, 0.4], "extra_factor": 256.0}
    assert _noise_factors(both) == "σn² × 256 noise scale × 16 by held-out demonstrations"
    calibrated_to_one = {"factor": 1.0, "noise_std_fitted": 0.1, "errors": [0.5]}
    assert _noise_factors(calibrated_to_one) == "σn² × 1 by held-out demonstrations"
