"""crossval in recording order (--order recorded) and small studies (--train-size N): which
demonstrations each split trains on and holds out, the table's and --json's account of them, and the
Python API's parity (issue 36)."""

from __future__ import annotations

import json
import re
import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from rbgp_cli.cli.app import app
from rbgp_cli.errors import InputError
from rbgp_cli.evaluation.crossval import make_folds, make_splits, splits_text
from tests.evaluation.test_crossval import _write, reaching_demos

runner = CliRunner()
FAST = ["--max-points", "60", "--restarts", "1", "--share-hyperparameters", "--jobs", "1", "--no-peers",
        "--samples", "4", "-q"]


@given(n=st.integers(2, 60), k=st.integers(2, 10))
@settings(max_examples=60, deadline=None)
def test_recorded_folds_are_contiguous_blocks_that_hold_out_every_demonstration_once(n, k):
    if n < k:
        with pytest.raises(InputError):
            make_folds(n, k, order="recorded")
        return
    folds = make_folds(n, k, seed=3, order="recorded")
    assert np.array_equal(np.concatenate(folds), np.arange(n))  # in order, each once
    assert all(np.all(np.diff(f) == 1) for f in folds)  # contiguous
    assert max(map(len, folds)) - min(map(len, folds)) <= 1
    assert [f.tolist() for f in make_folds(n, k, seed=9, order="recorded")] == [f.tolist() for f in folds]  # no seed


@given(n=st.integers(4, 50), size=st.integers(2, 12), k=st.integers(1, 6), seed=st.integers(0, 5))
@settings(max_examples=60, deadline=None)
def test_train_size_splits_train_on_that_many_and_hold_out_the_rest_or_the_later_ones(n, size, k, seed):
    if size > n - 1:
        with pytest.raises(InputError, match="train_size"):
            make_splits(n, k, seed, "random", size)
        return
    from math import comb

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # fewer distinct subsets than asked: said, and as many as there are
        splits = make_splits(n, k, seed, "random", size)
    for train, test in splits:
        assert len(train) == size and len(np.intersect1d(train, test)) == 0 and len(train) + len(test) == n
    assert len(splits) == min(k, comb(n, size))  # distinct subsets (9 choose 8 drew one subset 3 times in 5)
    assert len({tuple(t) for t, _ in splits}) == len(splits)
    windows = make_splits(n, k, seed, "recorded", size)
    assert 1 <= len(windows) <= k
    for train, test in windows:
        assert len(train) == size and np.all(np.diff(train) == 1)  # consecutive
        assert len(test) >= 1 and test.min() == train.max() + 1 and test.max() == n - 1  # every later one
    assert windows[0][0][0] == 0  # the first window starts at the first demonstration


def test_unknown_order_and_train_size_too_large_are_input_errors_naming_the_parameter():
    with pytest.raises(InputError) as err:
        make_folds(10, 2, order="time")
    assert err.value.param == "order"
    with pytest.raises(InputError) as err:
        make_splits(6, 3, train_size=6)
    assert err.value.param == "train_size"


def test_the_splits_line_names_the_demonstrations_in_recording_order():
    n = 12
    res = {"order": "recorded", "train_size": None, "seed": 0,
           "splits": [{"train": a.tolist(), "test": b.tolist()} for a, b in make_splits(n, 3, 0, "recorded")]}
    assert splits_text(res) == "splits: held out in contiguous blocks in recording order: [1–4]; [5–8]; [9–12]"
    res = {"order": "recorded", "train_size": 5, "seed": 0,
           "splits": [{"train": a.tolist(), "test": b.tolist()} for a, b in make_splits(n, 2, 0, "recorded", 5)]}
    assert splits_text(res) == ("splits: trained on 5 consecutive, the later ones held out: [1–5 → 7 held out]; [6–10 → 2 held out]")


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    return _write(reaching_demos(8), tmp_path_factory.mktemp("order") / "demos")


@pytest.mark.slow
def test_crossval_in_recording_order_and_with_a_train_size_say_their_splits_in_the_table_and_json(folder):
    res = runner.invoke(app, ["crossval", str(folder), "--folds", "4", "--order", "recorded", *FAST, "--json"])
    assert res.exit_code == 0, res.stderr
    out = json.loads(res.stdout)
    assert out["order"] == "recorded" and out["train_size"] is None
    assert [sp["test"] for sp in out["splits"]] == [[0, 1], [2, 3], [4, 5], [6, 7]]
    assert all(sorted(sp["train"] + sp["test"]) == list(range(8)) for sp in out["splits"])
    model = next(r for r in out["results"] if r["representation"] == "axis-angle" and not r.get("without_gp"))
    assert [f["n_test"] for f in model["per_fold"]] == [2, 2, 2, 2]
    table = runner.invoke(app, ["crossval", str(folder), "--folds", "2", "--train-size", "5", *FAST])
    assert table.exit_code == 0, table.stderr
    assert "splits: trained on 5 at random, the rest held out: [" in table.stdout
    line = next(x for x in table.stdout.splitlines() if x.startswith("splits:"))
    assert line.count("→ 3 held out") == 2  # two subsets of 5, each holding out the other 3
    assert re.search(r"held-out demonstrations: \d+ of 6\)", table.stdout)  # 2 × 3 held out, not 8
    # the API gives the same splits
    import rbgp_cli as rbgp

    cv = rbgp.crossval(folder, rbgp.RigidBodyGP(restarts=1, max_points=60, share_hyperparameters=True), folds=2,
                       train_size=5, samples=0, jobs=1, replay=False)
    assert cv.result["splits"] == json.loads(runner.invoke(
        app, ["crossval", str(folder), "--folds", "2", "--train-size", "5", *FAST, "--json"]).stdout)["splits"]


def test_crossval_refuses_repeats_in_recording_order_and_a_bad_order_with_exit_2(folder):
    res = runner.invoke(app, ["crossval", str(folder), "--order", "recorded", "--repeats", "2", *FAST])
    assert res.exit_code == 2 and "same on every repeat" in res.stderr and "--repeats" in res.stderr
    res = runner.invoke(app, ["crossval", str(folder), "--order", "time", *FAST])
    assert res.exit_code == 2 and "--order 'time' is unknown" in res.stderr and "Traceback" not in res.stderr
