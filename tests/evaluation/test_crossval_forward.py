"""crossval --order forward (issue 36): every block in recording order predicted from the blocks before
it only, as the next session is. The splits against their definition, the table's and --json's account
of them, the refusals, and a session that drifts over the recording order, where forward folds must
see what random folds hide."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from rbgp_cli.cli.app import app
from rbgp_cli.dynamics.paths import MIN_PATH_DEMOS
from rbgp_cli.errors import InputError, RbgpWarning
from rbgp_cli.evaluation.crossval import (Config, crossval, forward_splits, make_folds, make_splits,
                                          repeated_splits, split_info, splits_text)
from tests.evaluation.test_crossval import QUICK, _write, reaching_demos

runner = CliRunner()
FAST = ["--max-points", "60", "--restarts", "1", "--share-hyperparameters", "--jobs", "1", "--no-peers",
        "--samples", "4", "-q"]


@given(n=st.integers(2, 60), k=st.integers(2, 10), size=st.one_of(st.none(), st.integers(3, 12)))
@settings(max_examples=120, deadline=None)
def test_forward_splits_train_only_on_what_was_recorded_before_each_block(n, k, size):
    """Against the definition, written out independently: the blocks are np.array_split(0…n−1, k); block j
    (j ≥ 2) starting at s is held out with training {0, …, s − 1} (or {s − N, …, s − 1}) when at least
    m = MIN_PATH_DEMOS (or N) demonstrations precede it, and is skipped otherwise."""
    if n < k or (size is not None and size > n - 1):
        with pytest.raises(InputError):
            forward_splits(n, k, size)
        return
    m = MIN_PATH_DEMOS if size is None else size
    blocks = [b.tolist() for b in np.array_split(np.arange(n), k)]
    expected = [(list(range(0 if size is None else b[0] - m, b[0])), b) for b in blocks[1:] if b[0] >= m]
    if not expected:
        with pytest.raises(InputError, match="forward folds need"):
            forward_splits(n, k, size)
        return
    splits, skipped = forward_splits(n, k, size)
    assert [(tr.tolist(), te.tolist()) for tr, te in splits] == expected
    for train, test in splits:
        assert train.max() < test.min()  # strictly earlier, never a neighbour from after the block
        assert len(train) >= m
    # the predicted blocks and the skipped ones are the recorded blocks, each once
    assert sorted([te.tolist() for _, te in splits] + [b.tolist() for b in skipped]) == sorted(blocks)
    assert skipped[0].tolist() == blocks[0]  # the first block only trains
    assert split_info(n, k, "forward", size) == {"blocks": k, "skipped_blocks": [b.tolist() for b in skipped]}
    assert [b.tolist() for b in make_folds(n, k, order="forward")] == blocks


def test_forward_splits_of_ten_in_five_blocks_are_exactly_these_and_warn_of_the_skipped_block():
    with pytest.warns(RbgpWarning, match=r"1 block after the first not predicted \(demonstrations 3–4, 1-based\)"):
        splits = make_splits(10, 5, seed=7, order="forward")
    assert [(a.tolist(), b.tolist()) for a, b in splits] == [
        ([0, 1, 2, 3], [4, 5]), ([0, 1, 2, 3, 4, 5], [6, 7]), ([0, 1, 2, 3, 4, 5, 6, 7], [8, 9])]
    with pytest.warns(RbgpWarning, match="fewer than 4 demonstrations"):
        window = make_splits(10, 5, order="forward", train_size=4)
    assert [(a.tolist(), b.tolist()) for a, b in window] == [([0, 1, 2, 3], [4, 5]), ([2, 3, 4, 5], [6, 7]),
                                                             ([4, 5, 6, 7], [8, 9])]
    res = {"order": "forward", "train_size": None, "splits": [{"train": a.tolist(), "test": b.tolist()}
                                                              for a, b in splits], **split_info(10, 5, "forward")}
    assert splits_text(res) == ("splits: forward in recording order, each block predicted from every demonstration "
                                "before it: [1–4 → 5–6]; [1–6 → 7–8]; [1–8 → 9–10] (not predicted: [1–2]; [3–4])")


def test_forward_refuses_repeats_too_small_a_window_and_too_few_demonstrations():
    with pytest.raises(InputError, match="same on every repeat") as err:
        repeated_splits(20, 4, order="forward", repeats=2)
    assert err.value.param == "repeats"
    with pytest.raises(InputError, match="at least 3") as err:
        make_splits(20, 4, order="forward", train_size=2)
    assert err.value.param == "train_size"
    with pytest.raises(InputError, match="forward folds need 3 demonstrations") as err:
        make_splits(4, 2, order="forward")
    assert err.value.hint == "use folds 3 or more"  # blocks [0, 1], [2], [3]: the last has 3 before it


# ------------------------------------------------------------------------------------ a drifting session
def drifting_reaches(n, drift, seed=1):
    """:func:`reaching_demos` whose goal drifts linearly over the recording order: take i of n reaches
    y + u_i·drift (u_i = i/(n − 1) − 1/2, m), its start unchanged (p(t) += u_i·drift·(1 − e^{−2t}) in y)."""
    out = []
    for i, d in enumerate(reaching_demos(n, seed=seed)):
        reached = 1.0 - np.exp(-2.0 * (d.t - d.t[0]))
        out.append(d.with_(position=d.position + np.outer(reached, [0.0, (i / (n - 1) - 0.5) * drift, 0.0])))
    return out


def _gap(held, random, label="axis-angle se-chordal"):
    """Per motion held out by ``held``'s splits: its RMSE (position + rotation, m + rad) there minus at random."""
    h = {m["index"]: m for m in next(r for r in held["results"] if r["label"] == label)["per_motion"]}
    r = {m["index"]: m for m in next(x for x in random["results"] if x["label"] == label)["per_motion"]}
    return np.array([h[i]["position_rmse"] + h[i]["rotation_rmse"] - r[i]["position_rmse"] - r[i]["rotation_rmse"]
                     for i in sorted(h)])


@pytest.mark.slow
def test_forward_folds_of_a_drifting_session_see_the_drift_that_random_folds_hide():
    """20 reaches whose goal drifts 1 m over the recording order. Forward folds train only on earlier takes
    (every training index below every held-out one), whose goals lie short of the block's: on the same
    held-out motions their errors exceed random folds', whose training sets hold each take's neighbours on
    both sides. Expected from the drift alone, per motion: blocks 2–5 miss the training mean goal by
    0.21, 0.32, 0.42, 0.52 m forward against 0.21, 0.04, 0.21, 0.42 m at random, 0.15 m more on average
    (the RMSE over the path a fraction of that). The same takes without the drift show the part that
    fewer training takes alone cost; the two-sided recorded blocks, trained on both sides, do not see it."""
    configs = [Config("axis-angle", "se-chordal", {"max_points": 60, "restarts": 1, "shared": True})]
    runs = {}
    for drift in (0.0, 1.0):
        demos = drifting_reaches(20, drift)
        runs[drift] = {order: crossval(demos, configs, folds=5, jobs=1, samples=0, order=order, without_gp=False)
                       for order in ("forward", "random")}
    fwd = runs[1.0]["forward"]
    assert fwd["order"] == "forward" and fwd["folds"] == 4 and fwd["blocks"] == 5
    assert fwd["skipped_blocks"] == [[0, 1, 2, 3]]
    for sp in fwd["splits"]:
        assert max(sp["train"]) < min(sp["test"]) and sp["train"] == list(range(min(sp["test"])))
    drifting = _gap(fwd, runs[1.0]["random"])
    flat = _gap(runs[0.0]["forward"], runs[0.0]["random"])
    assert len(drifting) == 16
    assert drifting.mean() > 2 * drifting.std(ddof=1) / np.sqrt(len(drifting)), drifting  # worse forward
    assert drifting.mean() > flat.mean() + 0.03, (drifting.mean(), flat.mean())  # and by the drift
    recorded = crossval(drifting_reaches(20, 1.0), configs, folds=5, jobs=1, samples=0, order="recorded",
                        without_gp=False)
    assert _gap(recorded, runs[1.0]["random"])[4:].mean() < 0.5 * drifting.mean()  # the same motions, two-sided


# ------------------------------------------------------------------------------------ the command
@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    return _write(reaching_demos(8), tmp_path_factory.mktemp("forward") / "demos")


@pytest.mark.slow
def test_crossval_forward_says_its_splits_in_the_table_and_json_and_given_goal_and_f_use_them(folder):
    res = runner.invoke(app, ["crossval", str(folder), "--folds", "4", "--order", "forward", *FAST, "--json"])
    assert res.exit_code == 0, res.stderr
    out = json.loads(res.stdout)
    assert out["order"] == "forward" and out["folds"] == 2 and out["blocks"] == 4
    assert out["splits"] == [{"train": [0, 1, 2, 3], "test": [4, 5]}, {"train": list(range(6)), "test": [6, 7]}]
    assert out["skipped_blocks"] == [[0, 1], [2, 3]]
    assert "block after the first not predicted (demonstrations 3–4" in res.stderr  # the skipped block, on stderr
    model = next(r for r in out["results"] if r["representation"] == "axis-angle" and not r.get("without_gp"))
    assert [f["n_test"] for f in model["per_fold"]] == [2, 2]
    assert sorted(m["index"] for m in model["per_motion"]) == [4, 5, 6, 7]
    table = runner.invoke(app, ["crossval", str(folder), "--folds", "4", "--order", "forward", "--given", "goal", *FAST])
    assert table.exit_code == 0, table.stderr
    assert "8 demonstrations, 2 forward folds of 4 blocks (2, 2 held out)" in table.stdout
    assert ("splits: forward in recording order, each block predicted from every demonstration before it: "
            "[1–4 → 5–6]; [1–6 → 7–8] (not predicted: [1–2]; [3–4])") in table.stdout
    assert "end_mm" in table.stdout
    under = runner.invoke(app, ["crossval", str(folder), "--folds", "4", "--order", "forward", "--train-size", "4",
                                "--given", "0.5", *FAST, "--json"])
    assert under.exit_code == 0, under.stderr
    u = json.loads(under.stdout)
    assert u["order"] == "forward" and u["folds"] == 2 and u["train_size"] == 4
    assert u["splits"] == [{"train": [0, 1, 2, 3], "test": [4, 5]}, {"train": [2, 3, 4, 5], "test": [6, 7]}]
    assert all(m["index"] in (4, 5, 6, 7) for r in u["rows"] for m in r["per_motion"])


def test_crossval_forward_refuses_bad_combinations_with_exit_2_and_one_line(folder):
    for extra, text in ((["--repeats", "2"], "same on every repeat"),
                        (["--train-size", "2"], "at least 3"),
                        (["--folds", "2", "--train-size", "7"], "forward folds need 7 demonstrations"),
                        (["--given", "0.5", "--repeats", "3"], "same on every repeat")):
        args = ["crossval", str(folder), "--order", "forward", *FAST, *extra]
        res = runner.invoke(app, args if "--folds" in extra else [*args, "--folds", "4"])
        assert res.exit_code == 2, (extra, res.stdout, res.stderr)
        assert text in res.stderr and len(res.stderr.strip().splitlines()) == 1 and "Traceback" not in res.stderr


def test_the_under_way_table_says_which_forward_splits_it_used():
    from rbgp_cli.cli.report import format_under_way

    row = dict(method="rbgp", given=0.5, end_pos=0.1, end_rot=0.2, end_time=0.3, rest_pos=0.1, rest_rot=0.2,
               cov_pos=0.9, cov_rot=0.8, cov_pos_se=0.05, cov_rot_se=0.06)
    with pytest.warns(RbgpWarning):
        splits = make_splits(10, 5, order="forward")
    result = {"rows": [row], "folds": len(splits), "samples": 5, "order": "forward", "train_size": None,
              "splits": [{"train": a.tolist(), "test": b.tolist()} for a, b in splits], **split_info(10, 5, "forward")}
    lines = format_under_way(result).splitlines()
    assert lines[0].startswith("a motion under way: 3 forward folds, 5 samples per motion")
    assert lines[1] == ("splits: forward in recording order, each block predicted from every demonstration before it: "
                        "[1–4 → 5–6]; [1–6 → 7–8]; [1–8 → 9–10] (not predicted: [1–2]; [3–4])")
    assert lines[2].split()[:2] == ["given", "method"]
