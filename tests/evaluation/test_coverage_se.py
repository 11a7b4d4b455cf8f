"""The standard error of a pooled coverage over the held-out motions (coverage_se), against oracles: the
standard error of a mean by hand, a motion-level bootstrap, and crossval's rows and the --given F rows."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rbgp_cli.evaluation.coverage import coverage_se
from rbgp_cli.evaluation.crossval import _per_motion, _sampled_summary
from rbgp_cli.evaluation.under_way import UnderWayScores


def test_equal_counts_give_the_standard_error_of_the_mean_coverage():
    """Three motions of 10 steps, 8, 9 and 10 inside: the coverages 0.8, 0.9, 1.0 have s = 0.1, so the
    standard error of their mean is 0.1 / √3."""
    assert coverage_se([8, 9, 10], [10, 10, 10]) == pytest.approx(0.1 / math.sqrt(3), rel=1e-12)
    rng = np.random.default_rng(3)
    n = np.full(12, 300)
    a = rng.integers(200, 300, size=12)
    assert coverage_se(a, n) == pytest.approx(np.std(a / n, ddof=1) / math.sqrt(12), rel=1e-12)


def test_every_motion_at_the_same_coverage_has_no_standard_error():
    assert coverage_se([9, 18, 27], [10, 20, 30]) == 0.0  # 0.9 each, at different lengths
    assert coverage_se([5, 5], [5, 5]) == 0.0


def test_unequal_lengths_agree_with_a_motion_level_bootstrap():
    """The ratio estimator's SE against the spread of p* = Σ in*/Σ n* over motions drawn with replacement
    (20000 draws): the bootstrap's variance is the formula's × (M − 1) / M to first order."""
    rng = np.random.default_rng(0)
    M = 15
    n = rng.integers(100, 400, size=M)
    a = np.round(n * rng.uniform(0.6, 1.0, size=M)).astype(int)
    pick = rng.integers(0, M, size=(20000, M))
    boot = a[pick].sum(axis=1) / n[pick].sum(axis=1)
    se = coverage_se(a, n)
    assert se > 0
    assert np.std(boot) == pytest.approx(se * math.sqrt((M - 1) / M), rel=0.05)
    assert coverage_se(a, n) != pytest.approx(np.std(a / n, ddof=1) / math.sqrt(M), rel=1e-3)  # lengths count


def test_entries_of_one_motion_are_summed_before_the_standard_error():
    """A motion held out twice (repeats) is one unit: its two entries count as their sum."""
    a, n = [8, 7, 9, 10, 6], [10, 10, 10, 10, 10]
    groups = [0, 1, 0, 2, 1]
    assert coverage_se(a, n, groups) == pytest.approx(coverage_se([17, 13, 10], [20, 20, 10]), rel=1e-12)
    assert coverage_se(a, n, groups) != pytest.approx(coverage_se(a, n))


def test_fewer_than_two_motions_have_no_standard_error():
    assert coverage_se([9], [10]) is None
    assert coverage_se([3, 4, 5], [10, 10, 10], [1, 1, 1]) is None
    assert coverage_se([0, 0], [0, 0]) is None
    with pytest.raises(ValueError):
        coverage_se([1, 2], [3])


def _fold(motion_coverage):
    """One fold's sample columns as run_fold returns them (the pooled coverage the sum of its motions')."""
    c = np.asarray(motion_coverage, dtype=float)
    return {"sample_score": 1.0, "sample_offset": 0.5, "sample_spread": 0.5, "sample_scores": [1.0],
            "coverage": [*c.sum(axis=0).tolist(), 1.0, 1.0], "motion_coverage": c.tolist(),
            "motion_position_sq": [1.0] * len(c), "motion_rotation_sq": [1.0] * len(c), "motion_count": [10] * len(c)}


def test_crossval_rows_pool_repeats_per_motion_and_keep_the_pooled_coverage():
    """Two repeats of two folds over four motions: the row's coverage is the pool of all steps (as before),
    its SE the one of the four motions with each one's two rollouts summed; per_motion has each motion's."""
    # (position inside, count, rotation inside, count) per held-out motion, in the order of its fold
    folds = [np.array([0, 1]), np.array([2, 3]), np.array([3, 0]), np.array([1, 2])]
    cov = [[[27, 30, 9, 10], [21, 30, 6, 10]], [[30, 30, 10, 10], [24, 30, 8, 10]],
           [[18, 30, 7, 10], [29, 30, 10, 10]], [[25, 30, 8, 10], [27, 30, 9, 10]]]
    results = [_fold(c) for c in cov]
    out = _sampled_summary(results, [1.0] * 4, folds)
    flat = np.array([e for c in cov for e in c], dtype=float)
    assert out["coverage_position"] == pytest.approx(flat[:, 0].sum() / flat[:, 1].sum())
    per = {0: [27 + 29, 9 + 10], 1: [21 + 25, 6 + 8], 2: [30 + 27, 10 + 9], 3: [24 + 18, 8 + 7]}
    pos = np.array([per[i][0] / 60 for i in range(4)])  # equal counts: the SE of the mean of the four
    rot = np.array([per[i][1] / 20 for i in range(4)])
    assert out["coverage_position_se"] == pytest.approx(np.std(pos, ddof=1) / 2, rel=1e-12)
    assert out["coverage_rotation_se"] == pytest.approx(np.std(rot, ddof=1) / 2, rel=1e-12)
    pm = _per_motion(folds, results)
    assert [m["coverage_position"] for m in pm] == pytest.approx(pos.tolist())
    assert [m["coverage_rotation"] for m in pm] == pytest.approx(rot.tolist())
    assert [m["coverage_steps"] for m in pm] == [20] * 4
    # one fold alone: its two motions
    one = _sampled_summary(results[:1], [1.0], folds[:1])
    assert one["coverage_position_se"] == pytest.approx(np.std([0.9, 0.7], ddof=1) / math.sqrt(2))


def test_rows_without_per_motion_coverage_have_no_standard_error():
    """Old results (no motion_coverage) and rows without samples: the SE is None, the coverage as before."""
    old = _fold([[27, 30, 9, 10], [21, 30, 6, 10]])
    del old["motion_coverage"]
    out = _sampled_summary([old], [1.0], [np.array([0, 1])])
    assert out["coverage_position"] == pytest.approx(0.8) and out["coverage_position_se"] is None
    assert _sampled_summary([{"score": 1.0}], [1.0])["coverage_rotation_se"] is None


def test_under_way_rows_have_the_standard_error_over_their_motions():
    """--given F: UnderWayScores of three motions added up; cov_pos_se / cov_rot_se are the motions' SE, the
    pooled cov_pos unchanged; a method without samples has NaN (null in --json)."""
    from rbgp_cli.evaluation.coverage import Coverage

    parts = [(27, 30, 9, 10), (21, 30, 6, 10), (30, 30, 10, 10)]
    total = UnderWayScores()
    for i, c in enumerate(parts):
        one = UnderWayScores([0.1], [0.1], [0.1], [(1.0, 1.0, 10)], [], Coverage(*c), [c]).with_index(i)
        total = total.add(one)
    d = total.to_dict()
    assert d["cov_pos"] == pytest.approx(78 / 90) and d["cov_rot"] == pytest.approx(25 / 30)
    assert d["cov_pos_se"] == pytest.approx(np.std([0.9, 0.7, 1.0], ddof=1) / math.sqrt(3), rel=1e-12)
    assert d["cov_rot_se"] == pytest.approx(np.std([0.9, 0.6, 1.0], ddof=1) / math.sqrt(3), rel=1e-12)
    assert [m["cov_pos"] for m in total.per_motion()] == pytest.approx([0.9, 0.7, 1.0])
    none = UnderWayScores([0.1], [0.1], [0.1], [(1.0, 1.0, 10)]).to_dict()
    assert math.isnan(none["cov_pos_se"]) and math.isnan(none["cov_pos"])
    assert math.isnan(none["cov_end_time"]) and math.isnan(none["cov_end_time_se"])


def test_the_end_time_band_coverage_is_the_motions_fraction_inside_with_its_standard_error():
    """--given F's cov_end_time: score() marks whether the real end time lies in the band given; added over four
    motions (one held out twice, which counts once in the SE), the pooled fraction inside and the motions' SE."""
    from rbgp_cli.dynamics.trajectory import Trajectory
    from rbgp_cli.evaluation.under_way import score

    t = np.linspace(0.0, 1.0, 11)
    q = np.tile([0.0, 0.0, 0.0, 1.0], (11, 1))
    p = np.zeros((11, 3))
    rest = Trajectory(t, q, p)
    bands = [(0.9, 1.1), (1.2, 1.4), (0.5, 1.0), (1.0, 2.0), (0.95, 0.99)]  # in, out, in (edge), in (edge), out
    total = UnderWayScores()
    for i, b in zip([0, 1, 2, 3, 3], bands):
        total = total.add(score(rest, [], rest, b).with_index(i))
    d = total.to_dict()
    assert d["cov_end_time"] == pytest.approx(3 / 5)
    inside, count = np.array([1.0, 0.0, 1.0, 1.0]), np.array([1.0, 1.0, 1.0, 2.0])  # motion 3: once in, once out
    # the ratio estimator's SE (coverage_se's formula, written out): √(Σ (inᵢ − p nᵢ)² / (M (M − 1))) / n̄
    want = math.sqrt(np.sum((inside - 0.6 * count) ** 2) / (4 * 3)) / count.mean()
    assert d["cov_end_time_se"] == pytest.approx(want, rel=1e-12) and want == pytest.approx(0.196, abs=1e-3)
    assert math.isnan(score(rest, [], rest).to_dict()["cov_end_time"])  # no band: no coverage


def test_the_tables_print_each_coverage_with_its_standard_error():
    """crossval's and crossval --given F's tables: ``0.87±0.07`` in the coverage columns, the coverage alone
    without an SE, ``-`` without a coverage; the header keeps its column names."""
    from rbgp_cli.cli.report import _cov_cell, format_under_way

    assert _cov_cell(0.8667, 0.0667, 9) == "0.87±0.07"
    assert _cov_cell(0.8667, None, 9) == "     0.87" and _cov_cell(None, None, 9) == "        -"
    assert _cov_cell(float("nan"), float("nan"), 9).strip() == "-"
    nan = float("nan")
    base = dict(given=0.4, end_pos=0.1, end_rot=0.2, end_time=0.3, rest_pos=0.1, rest_rot=0.2, band_pos=0.1,
                band_rot=0.2, motions=3)
    rows = [dict(base, method="rbgp", cov_pos=0.8667, cov_rot=0.8333, cov_pos_se=0.0882, cov_rot_se=0.1202,
                 cov_end_time=0.6667, cov_end_time_se=0.3333, left_data=2, left_of=63),
            dict(base, method="nearest", cov_pos=nan, cov_rot=nan, cov_pos_se=nan, cov_rot_se=nan, cov_end_time=nan,
                 cov_end_time_se=nan),
            dict(base, method="promp", cov_pos=0.5, cov_rot=0.25)]  # rows of an older result: no SE, no end band
    floor = [{"given": 0.4, "left_data": 0, "left_of": 3}]
    lines = format_under_way({"rows": rows, "folds": 3, "samples": 5, "floor_left_data": floor}).splitlines()
    head = next(i for i, x in enumerate(lines) if x.split()[:2] == ["given", "method"])
    assert lines[head].split()[-4:] == ["cov_pos", "cov_rot", "cov_end", "left"]
    assert lines[head + 1].split()[-4:] == ["0.87±0.09", "0.83±0.12", "0.67±0.33", "2/63"]
    assert lines[head + 2].split()[-4:] == ["-", "-", "-", "-"]
    assert lines[head + 3].split()[-4:] == ["0.50", "0.25", "-", "-"]
    assert len({len(x) for x in lines[head:head + 4]}) == 1  # the columns stay aligned
    assert "(the held-out remainders themselves: 0 of 3 at 0.4)" in lines[0]
