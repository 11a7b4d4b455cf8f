"""A sparse model through the command line and the model file: train --inducing, the automatic
choice and what the summary says, the stored posterior, exact models marked exact, damaged sparse files."""

from __future__ import annotations

import json
import zipfile

import numpy as np
import pytest

from rbgp_cli.cli.app import app
from rbgp_cli.dynamics.model import SPARSE_ABOVE, choose_gp
from rbgp_cli.errors import InputError
from rbgp_cli.io.model_store import load_model, read_header, save_model
from tests.cli.common import CSV_DIR, run, runner

FAST = ["--restarts", "1", "--share-hyperparameters", "--kernel", "se-chordal", "--explore-size", "100"]


@pytest.fixture(scope="module")
def sparse_model(tmp_path_factory):
    path = tmp_path_factory.mktemp("sparse") / "s.rbgp"
    res = run("train", CSV_DIR, "-o", path, *FAST, "--subsample", "0.3", "--inducing", "40", "--json")
    assert res.exit_code == 0, res.stderr
    return path, json.loads(res.stdout)


def test_train_inducing_writes_a_sparse_model_that_says_so(sparse_model):
    path, summary = sparse_model
    assert summary["gp"]["type"] == "sparse" and summary["gp"]["inducing"] == 40 and summary["gp"]["forced"]
    assert summary["points"] == round(0.3 * summary["pairs"])  # --max-points (2000) dropped nothing
    header, arrays = read_header(path)
    assert header["version"] == 8 and header["gp"] == {"type": "sparse", "inducing": 40}
    assert arrays["Z"].shape == (40, 7) and arrays["Lm"].shape  # inducing inputs: pose and phase == (1, 40, 40) and arrays["c"].shape == (40, 6)
    assert arrays["X"].shape[0] == summary["points"]  # every training point is kept
    # the inducing poses are training poses
    assert all(np.any(np.all(arrays["X"] == z, axis=1)) for z in arrays["Z"])


@pytest.mark.slow
def test_hyper_points_choose_how_many_points_the_bound_covers_and_the_summary_says_so(tmp_path):
    base = ["train", CSV_DIR, *FAST, "--train-rate", "30", "--inducing", "32", "--json"]
    res = run(*base, "-o", tmp_path / "a.rbgp", "--hyper-points", "300")
    assert res.exit_code == 0, res.stderr
    gp = json.loads(res.stdout)["gp"]
    points = json.loads(res.stdout)["points"]
    assert points > 300 and gp["hyper_points"] == 300 and "random 300 of them" in gp["reason"]
    header, arrays = read_header(tmp_path / "a.rbgp")
    assert arrays["X"].shape[0] == points  # the posterior keeps every point
    assert header["provenance"]["train_options"]["hyper_points"] == 300
    # the default covers max(4 M, 2000) points: here all of them, and the summary adds nothing
    res = run(*base, "-o", tmp_path / "b.rbgp")
    gp = json.loads(res.stdout)["gp"]
    assert gp["hyper_points"] == points and "random" not in gp["reason"]


def test_loaded_sparse_model_predicts_as_when_trained_and_rolls_out(sparse_model, tmp_path):
    path, _ = sparse_model
    model, _ = load_model(path)
    X = model.gp.X[:50]
    again = type(model.gp)(model.gp.kernel, model.gp.X, model.gp.Y, model.gp.Z, model.gp.fits, model.gp.shared,
                           model.gp.y_scale)  # recomputed from all training points
    np.testing.assert_allclose(model.gp.predict(X), again.predict(X), atol=1e-8)
    out = tmp_path / "r.csv"
    res = run("rollout", path, "--count", "3", "--duration", "0.5", "-o", out)
    assert res.exit_code == 0, res.stderr
    rows = [r for r in out.read_text().splitlines() if not r.startswith("#")]
    assert len(rows) > 3 and "std_wx" in rows[0]
    res = run("info", path)
    assert res.exit_code == 0 and "version 8" in res.stdout and "sparse GP: 40 inducing poses" in res.stdout


def test_damaged_sparse_factors_are_refused(sparse_model, tmp_path):
    path, _ = sparse_model
    model, _ = load_model(path)
    model.gp.stats[0][0][3, 1] += 1e-3  # a factor that no longer matches k(Z, Z), checksums rewritten
    bad = tmp_path / "bad.rbgp"
    save_model(model, bad)
    with pytest.raises(InputError, match="cannot be rebuilt"):
        load_model(bad)
    # an array missing from a file whose header says sparse
    broken = tmp_path / "broken.rbgp"
    with zipfile.ZipFile(path) as zin, zipfile.ZipFile(broken, "w") as zout:
        for item in zin.infolist():
            if item.filename != "Lm.npy":
                zout.writestr(item, zin.read(item.filename))
    res = run("rollout", broken, "--count", "1", "--duration", "0.1")
    assert res.exit_code == 2 and "'Lm' is missing" in res.stderr


def test_exact_models_are_written_as_exact(tmp_path):
    path = tmp_path / "e.rbgp"
    res = run("train", CSV_DIR, "-o", path, *FAST, "--max-points", "120", "--json")
    assert res.exit_code == 0, res.stderr
    summary = json.loads(res.stdout)
    assert summary["gp"]["type"] == "exact" and "random 120 of" in summary["gp"]["reason"]
    header, arrays = read_header(path)
    assert header["version"] == 8 and header["gp"] == {"type": "exact"} and "Z" not in arrays
    model, _ = load_model(path)
    assert not getattr(model.gp, "sparse", False)


def test_automatic_choice_rule():
    # the exact GP up to max(SPARSE_ABOVE, max_points) points, capped at max_points, as before
    assert choose_gp(565, None, 150, "se")["type"] == "exact"
    assert "random 150 of 565" in choose_gp(565, None, 150, "se")["reason"]
    assert choose_gp(SPARSE_ABOVE, None, 2000, "se")["type"] == "exact"
    assert choose_gp(4000, None, 5000, "se")["type"] == "exact"
    # above both: sparse on all points, and the summary says why and how to force the exact GP
    auto = choose_gp(SPARSE_ABOVE + 1, None, 2000, "se-chordal")
    assert auto["type"] == "sparse" and not auto["forced"] and auto["inducing"] == 256
    assert "--inducing 0" in auto["reason"] and str(SPARSE_ABOVE + 1) in auto["reason"]
    assert choose_gp(10**5, None, None, "se")["type"] == "sparse"
    # the dot-product kernel stays exact; forcing a sparse one is an input error
    assert choose_gp(10**5, None, 2000, "dot")["type"] == "exact"
    with pytest.raises(InputError, match="dot-product"):
        choose_gp(10**5, 64, 2000, "dot")
    # forced either way; never more inducing poses than points
    assert choose_gp(10**5, 0, 2000, "se")["type"] == "exact"
    assert choose_gp(30, 512, 2000, "se")["inducing"] == 30


def test_inducing_with_the_dot_kernel_is_a_one_line_error(tmp_path):
    res = run("train", CSV_DIR, "-o", tmp_path / "d.rbgp", "--kernel", "dot", "--inducing", "32",
              "--time-input", "none", "--prior", "none")
    assert res.exit_code == 2 and "dot-product" in res.stderr and "Traceback" not in res.stderr


def test_crossval_help_names_the_distributed_extra():
    """Rich markup would read "[distributed]" as a style tag and print `pip install "rbgp-cli"`."""
    res = runner.invoke(app, ["crossval", "--help"], env={"COLUMNS": "400"})
    assert res.exit_code == 0 and 'pip install "rbgp-cli[distributed]"' in res.stdout, res.stdout
