"""crossval --given's pieces: the split, the scores, the peers (issue 37)."""

from __future__ import annotations

import numpy as np
import pytest

from rbgp_cli.dynamics.trajectory import Trajectory
from rbgp_cli.evaluation.under_way import nearest_continuation, score, split_seen
from tests.dynamics.test_anticipation import family


def test_split_seen_shares_the_last_seen_sample():
    tr = family(1, 0)[0][0]
    seen, rest = split_seen(tr, 0.4)
    assert seen.t[-1] == rest.t[0] and rest.t[-1] == tr.t[-1]
    assert abs((seen.t[-1] - tr.t[0]) / tr.duration - 0.4) < 0.02


def test_a_perfect_prediction_scores_zero():
    tr = family(1, 0)[0][0]
    _, rest = split_seen(tr, 0.5)
    sc = score(rest, [], rest).to_dict()
    assert sc["end_pos"] == 0 and sc["end_time"] == 0 and sc["rest_pos"] < 1e-12 and np.isnan(sc["cov_pos"])


def test_nearest_finds_a_training_demonstration_and_its_duration():
    demos, durs = family(6, 2)
    seen, rest = split_seen(demos[3], 0.5)
    c = nearest_continuation(demos, seen)
    assert abs(c.t[-1] - rest.t[-1]) < 0.05 * durs[3]  # itself, at (about) its own duration
    assert np.linalg.norm(c.position[-1] - rest.position[-1]) < 0.01


@pytest.mark.slow
def test_the_promp_peer_estimates_the_duration():
    pytest.importorskip("movement_primitives")
    from rbgp_cli.evaluation.under_way import PhaseProMP

    demos, _ = family(20, 4)
    new, durs = family(4, 9)
    pm = PhaseProMP(demos)
    for tr, D in zip(new, durs):
        seen, rest = split_seen(tr, 0.5)
        tau, Y = pm._seen(seen)
        assert abs(pm.duration(tau, Y) - D) < 0.1 * D
        mean, samples = pm.predict(seen, samples=3)
        assert mean.t[0] == pytest.approx(seen.t[-1]) and len(samples) == 3


# ---------------------------------------------------------------------------------- paired comparisons
def _rows(rng, n=12, shift=0.01):
    """rbgp's and a peer's rows at F = 0.4 with known per-motion values (the peer's order reversed and its
    first motion missing, as a row that could not score one would be)."""
    from rbgp_cli.evaluation.under_way import COLUMNS

    ref = [{"index": i, **{c: float(rng.uniform(0.1, 0.3)) for c in COLUMNS}} for i in range(n)]
    peer = [{"index": m["index"], **{c: m[c] + shift + 0.02 * float(rng.standard_normal()) for c in COLUMNS}}
            for m in ref[1:]][::-1]
    return ([{"method": "rbgp", "given": 0.4, "per_motion": ref}, {"method": "promp", "given": 0.4, "per_motion": peer},
             {"method": "promp", "given": 0.6, "per_motion": peer}], ref, peer)


@pytest.mark.slow
def test_paired_rows_are_scipys_paired_t_on_the_motions_both_scored():
    from scipy.stats import ttest_rel

    from rbgp_cli.evaluation.under_way import COLUMNS, add_paired

    rows, ref, peer = _rows(np.random.default_rng(3))
    add_paired(rows)
    assert rows[0]["paired"] is None  # the reference itself
    assert rows[2]["paired"] is None  # no rbgp row at F = 0.6
    p = rows[1]["paired"]
    assert p["reference"] == "rbgp"
    by_index = {m["index"]: m for m in peer}
    for c in COLUMNS:
        a = np.array([m[c] for m in ref[1:]])
        b = np.array([by_index[m["index"]][c] for m in ref[1:]])
        t = ttest_rel(b, a)
        assert p[c]["motions"] == 11
        assert p[c]["z"] == pytest.approx(t.statistic, rel=1e-12)
        assert p[c]["difference"] == pytest.approx(np.mean(b - a), rel=1e-12)
        assert p[c]["closer"] == int(np.sum(b < a))


def test_per_motion_scores_pool_to_the_rows_rmse():
    """Each motion's remainder RMSE is its own √(Σ/steps); the row's pooled RMSE is √ of their mean square
    (every motion has the same steps), and the end columns are the per-motion values' means."""
    from rbgp_cli.evaluation.under_way import UnderWayScores

    rng = np.random.default_rng(0)
    parts = []
    for i in (5, 2, 9):
        tr = family(1, i)[0][0]
        _, rest = split_seen(tr, 0.5)
        off = Trajectory(rest.t * 1.05, rest.quat, rest.position + rng.normal(0, 0.01, 3), name="x")
        parts.append(score(off, [], rest).with_index(i))
    tot = parts[0].add(parts[1]).add(parts[2])
    pm = tot.per_motion([f"m{k}" for k in range(10)])
    assert [m["index"] for m in pm] == [2, 5, 9] and pm[0]["name"] == "m2"
    d = tot.to_dict()
    assert d["rest_pos"] == pytest.approx(np.sqrt(np.mean([m["rest_pos"] ** 2 for m in pm])), rel=1e-12)
    assert d["end_time"] == pytest.approx(np.mean([m["end_time"] for m in pm]), rel=1e-12)
    assert all(m["end_time"] > 0 and m["rest_pos"] > 0.001 for m in pm)


def test_a_motion_held_out_by_several_splits_is_one_motion_and_pairs_with_itself():
    """With --repeats / --train-size a motion is scored by several splits: per_motion gives it one entry
    (end errors averaged, remainder RMSE pooled, ``scored`` the count), and two rows scored alike pair to
    Δ = 0 on every column (keyed by index, the last scoring of a motion used to stand for all of them)."""
    from rbgp_cli.evaluation.under_way import UnderWayScores, add_paired

    rng = np.random.default_rng(1)
    parts = []
    for i in (3, 1, 3, 1, 3):  # motion 3 held out three times, motion 1 twice, with different errors
        tr = family(1, i)[0][0]
        _, rest = split_seen(tr, 0.5)
        off = Trajectory(rest.t * (1 + rng.uniform(0.01, 0.2)), rest.quat, rest.position + rng.normal(0, 0.02, 3), name="x")
        parts.append(score(off, [], rest).with_index(i))
    tot = parts[0]
    for p in parts[1:]:
        tot = tot.add(p)
    pm = tot.per_motion()
    assert [(m["index"], m["scored"]) for m in pm] == [(1, 2), (3, 3)]
    three = [parts[k] for k in (0, 2, 4)]
    assert pm[1]["end_pos"] == pytest.approx(np.mean([p.end_pos[0] for p in three]), rel=1e-12)
    sq = sum(p.motion_sq[0][0] for p in three) / sum(p.motion_sq[0][2] for p in three)
    assert pm[1]["rest_pos"] == pytest.approx(np.sqrt(sq), rel=1e-12)
    assert len({round(p.end_pos[0], 9) for p in three}) == 3  # the scorings differ: averaging is tested
    rows = [{"method": "rbgp", "given": 0.5, "per_motion": pm}, {"method": "no-GP", "given": 0.5, "per_motion": tot.per_motion()}]
    add_paired(rows)
    for key in ("end_pos", "end_rot", "end_time", "rest_pos", "rest_rot"):
        assert rows[1]["paired"][key]["difference"] == 0.0 and rows[1]["paired"][key]["motions"] == 2


@pytest.mark.slow
def test_a_fold_labels_each_motion_with_its_place_in_the_input_order():
    from rbgp_cli.dynamics.paths import fit_paths
    from rbgp_cli.evaluation.under_way import under_way_fold

    demos, _ = family(10, 1)
    out = under_way_fold(None, fit_paths(demos[:8]), demos[:8], demos[8:], (0.5,), samples=0,
                         methods=("no-GP", "nearest"), indices=[17, 4])
    for key in (("no-GP", 0.5), ("nearest", 0.5)):
        pm = out[key].per_motion()
        assert [m["index"] for m in pm] == [4, 17]
        assert pm[1]["end_time"] == pytest.approx(out[key].end_time[0])  # index 17 is the first held out
    # every method's continuations and the held-out remainders themselves checked against the envelope
    assert out[("floor", 0.5)].to_dict()["left_of"] == 2 and out[("no-GP", 0.5)].to_dict()["left_of"] == 2


def test_score_counts_the_continuations_that_leave_the_training_envelope():
    """score with an envelope: of the mean and its samples, those whose rows leave the training demonstrations'
    envelope at their phase of the whole motion (t − t_0) / D; a sample moved 1 m aside leaves, the truth does not."""
    from rbgp_cli.dynamics.envelope import envelope_from_demos

    demos, _ = family(6, 1)
    env = envelope_from_demos(demos[:5])
    seen, rest = split_seen(demos[5], 0.5)
    aside = Trajectory(rest.t, rest.quat, rest.position + [1.0, 0.0, 0.0], name="aside")
    sc = score(rest, [rest, aside], rest, None, env, float(seen.t[0])).to_dict()
    assert (sc["left_data"], sc["left_of"]) == (1, 3)
    assert score(rest, [], rest).to_dict()["left_of"] is None  # no envelope: not checked
