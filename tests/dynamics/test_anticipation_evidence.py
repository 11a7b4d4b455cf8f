"""The end time's band of a motion under way with the seen poses' evidence weighted by λ (issue 37, thirteenth
pass): the tempered weights against an independent computation with the whole covariance and scipy's densities,
fit_seen's rule against its own left-out statistic, the band's coverage of fresh motions, and the model file's
field."""

from __future__ import annotations

import copy

import numpy as np
import pytest
from scipy.stats import norm, t as student

from rbgp_cli.dynamics.anticipation import (DURATION_EVIDENCE_GRID, _ELL_TOL, Anticipator, _evidence_loo,
                                            finite_sample_count, fit_seen)
from rbgp_cli.dynamics.paths import PathDistribution, fit_paths
from rbgp_cli.evaluation.under_way import split_seen

from .test_anticipation import family
from .test_anticipation_bands import _rich_family
from .test_anticipation_modes import _even


@pytest.fixture(scope="module")
def paths():
    demos, _ = family(12, 3)
    return fit_paths(demos)


@pytest.mark.parametrize("lam", [0.5, 0.0625])
def test_the_band_weights_equal_a_prior_times_the_evidence_to_the_power_lambda(paths, lam):
    """weights()' ``band_w`` equal t_ν(ℓ) · [p(y, ℓ) / N(ℓ)]^λ normalised: p(y, ℓ) from
    PathDistribution.duration_posterior (a loop over the grid with Σ's 307 × 307 entries), N and t_ν (ν = D − 1)
    scipy's densities of ℓ = ln D / σ_ℓ with the prior's mean and variance Σ_ℓℓ + ε². The weights themselves (the
    point estimate's) stay the whole evidence's, and so does the end time; the band is the tempered weights'
    quantiles moved onto it."""
    ant = Anticipator(paths, None, points=8, grid_size=12, duration_smooth=0.01, duration_tolerance=0.8,
                      duration_evidence=lam, duration_statistic="median")  # D̂ the median (the mode: its own tests)
    whole = Anticipator(paths, None, points=8, grid_size=12, duration_smooth=0.01, duration_tolerance=0.8,
                        duration_evidence=1.0, duration_statistic="median")
    ref = copy.copy(paths)
    ref.smooth, ref.seen_tolerance = 0.01, 0.8
    m, Sigma = ref.prior()
    sd = np.sqrt(Sigma[-1, -1] + _ELL_TOL ** 2)
    tr = family(1, 11)[0][0]
    for F in (0.25, 0.6):
        seen = _even(tr, F, 8)
        grid, w, terms = ant.weights(seen.t, seen.quat, seen.position)
        _, w2 = ref.duration_posterior(seen.t, seen.quat, seen.position, grid=grid, points=8)
        z = (np.log(grid) / ref.duration_scale - m[-1]) / sd
        want = student.logpdf(z, df=paths.demos - 1) + lam * (np.log(w2) - norm.logpdf(z))
        want = np.exp(want - want.max())
        want /= want.sum()
        np.testing.assert_allclose(terms["band_w"], want, rtol=1e-4, atol=1e-10)
        np.testing.assert_allclose(w, w2, rtol=1e-4, atol=1e-10)
        # the tempered weights are wider: their entropy exceeds the whole evidence's
        ent = lambda p: -np.sum(p[p > 0] * np.log(p[p > 0]))  # noqa: E731
        assert ent(terms["band_w"]) > ent(w)
        e, e1 = ant.estimate(seen.t, seen.quat, seen.position), whole.estimate(seen.t, seen.quat, seen.position)
        assert e.end_time == e1.end_time
        # the band: the tempered weights' 5 % and 95 % quantiles times D̂ / their median (both medians computed
        # here by np.interp over the cells in ln D), at least the seen span, widened to hold D̂
        span = terms["span"]
        edges = np.concatenate([[np.log(grid[0]) - ant._half_step], np.log(grid) + ant._half_step])

        def q(wt, level):
            return max(float(np.exp(np.interp(level, np.concatenate([[0.0], np.cumsum(wt)]), edges))), span)

        D = e.end_time - seen.t[0]
        assert D == pytest.approx(q(w, 0.5), rel=1e-12)
        k = D / q(terms["band_w"], 0.5)
        lo, hi = max(q(terms["band_w"], 0.05) * k, span), max(q(terms["band_w"], 0.95) * k, span)
        # then widened about D̂ in ln D by the seen part's surprise s (1 for a seen part like the median left-out one)
        s = e.band_widening
        lo, hi = max(D * (min(lo, D) / D) ** s, span), D * (max(hi, D) / D) ** s
        np.testing.assert_allclose(np.subtract(e.end_time_band, seen.t[0]), [lo, hi], rtol=1e-12)


@pytest.mark.parametrize("n", [1, 5, 8, 9, 10, 19, 20, 24, 96, 128, 160, 1000])
@pytest.mark.parametrize("level", [0.5, 0.9, 0.95])
def test_the_finite_sample_count_is_the_fewest_held_that_guarantee_the_level(n, level):
    """For n + 1 exchangeable scores a band that is the k-th smallest of the first n holds the last with probability
    exactly k / (n + 1) (its rank is uniform on 1 … n + 1): finite_sample_count is the smallest such k reaching the
    level, at most n (then the level cannot be guaranteed and every one must be held). It never asks fewer than the
    plain share k / n ≥ level."""
    k = finite_sample_count(n, level)
    assert 1 <= k <= n
    if k < n:
        assert k / (n + 1) >= level - 1e-12 > (k - 1) / (n + 1)
    else:  # n too small to reach the level: all of them
        assert (n - 1) / (n + 1) < level
    assert k >= int(np.ceil(level * n - 1e-9))  # never fewer than the plain share asks
    # a simulation of the guarantee (exchangeable uniform scores): the next one is held at the level or above
    if n in (9, 19, 24) and level == 0.9:
        u = np.random.default_rng(n).random((40000, n + 1))
        kth = np.sort(u[:, :n], axis=1)[:, k - 1]
        assert np.mean(u[:, n] <= kth) >= level - 0.005


def test_fit_seen_takes_the_largest_lambda_whose_left_out_band_holds_enough():
    """fit_seen's λ is the largest of DURATION_EVIDENCE_GRID whose band held at least finite_sample_count(n, 0.90) of
    the n left-out durations (_evidence_loo), else the smallest; the model keeps None for λ = 1. On the rich family
    with durations spread 20 % and five demonstrations the whole evidence's band does not hold (its λ = 1 row is
    below 0.90)."""
    for demos in (family(12, 3)[0], _rich_family(5, 1, spread=0.2)):
        p = fit_paths(demos)
        inside = _evidence_loo(p, demos)
        held = {lam: float(np.mean(v)) for lam, v in inside.items()}
        assert set(held) == set(DURATION_EVIDENCE_GRID)
        need = int(np.ceil(0.9 * (len(inside[1.0]) + 1) - 1e-9))
        ok = [lam for lam, v in inside.items() if v.sum() >= min(need, len(v))]
        want = max(ok) if ok else min(held)
        assert (p.duration_evidence or 1.0) == want
        assert p.info["duration_evidence"] == want and p.info["duration_loo_coverage"] == held[want]
    assert held[1.0] < 0.9 and p.duration_evidence < 1.0  # the five: tempered
    # without the demonstrations there is nothing to leave out: λ stays as it was
    q = fit_seen(copy.deepcopy(p))
    assert q.duration_evidence == p.duration_evidence


@pytest.mark.slow
def test_the_end_time_band_holds_fresh_motions_where_the_whole_evidence_does_not():
    """Fitted on 30 motions of the rich family with durations spread 5 % (ln D), 40 fresh motions seen to F = 0.2,
    0.4, 0.6 and 0.8: the chosen λ's 90 % end-time band holds 0.88–0.98 of their end times (measured 0.93), the
    whole evidence's 0.84 (its band too narrow); the end times themselves are the same."""
    trained = fit_paths(_rich_family(30, 1, spread=0.05))
    assert trained.duration_evidence is not None and trained.duration_evidence < 1.0
    ant = Anticipator(trained, None)
    whole = Anticipator(trained, None, duration_evidence=1.0)
    held, held1 = [], []
    for tr in _rich_family(40, 101, spread=0.05):
        for F in (0.2, 0.4, 0.6, 0.8):
            seen, _ = split_seen(tr, F)
            e, e1 = ant.estimate(seen.t, seen.quat, seen.position), whole.estimate(seen.t, seen.quat, seen.position)
            assert e.end_time == e1.end_time
            held.append(e.end_time_band[0] <= tr.t[-1] <= e.end_time_band[1])
            held1.append(e1.end_time_band[0] <= tr.t[-1] <= e1.end_time_band[1])
    assert 0.88 <= np.mean(held) <= 0.98, np.mean(held)
    assert np.mean(held1) < 0.87, np.mean(held1)


def test_the_samples_draw_their_durations_from_the_band_weights(paths):
    """The sampled continuations' end times spread as the band's weights: with λ = 1/16 their spread is wider
    than with the whole evidence (200 samples, the same seed)."""
    tr = family(1, 11)[0][0]
    seen, _ = split_seen(tr, 0.4)
    ends = {}
    for lam in (1.0, 0.0625):
        ant = Anticipator(paths, None, duration_evidence=lam)
        c = ant.continuation(seen.t, seen.quat, seen.position, samples=200, seed=3)
        ends[lam] = np.array([s[0][-1] for s in c.samples])
        lo, hi = c.estimate.end_time_band
        assert 0.85 <= np.mean((ends[lam] >= lo) & (ends[lam] <= hi)) <= 0.97  # the samples and the band agree
    assert np.std(np.log(ends[0.0625])) > 1.3 * np.std(np.log(ends[1.0]))


def test_the_model_file_keeps_lambda_and_refuses_one_outside_zero_to_one():
    from rbgp_cli.io.model_schema import TOP

    rng = np.random.default_rng(0)
    D, S = 5, 51
    paths = PathDistribution(np.linspace(0, 1, S), np.tile([0, 0, 0, 1.0], (S, 1)), np.zeros((S, 3)),
                             rng.normal(size=(D, S, 6)), rng.normal(size=D), duration_evidence=0.125)
    header = paths.header()
    assert header["duration_evidence"] == 0.125
    TOP["paths"][1](header, ("paths",))
    assert PathDistribution.from_arrays(paths.to_arrays(), header).duration_evidence == 0.125
    for bad in (0.0, -0.5, 1.5):
        with pytest.raises(Exception, match="duration_evidence"):
            TOP["paths"][1](dict(header, duration_evidence=bad), ("paths",))
    old = {k: v for k, v in header.items() if k != "duration_evidence"}
    assert PathDistribution.from_arrays(paths.to_arrays(), old).duration_evidence is None
    paths.duration_evidence = None
    assert "duration_evidence" not in paths.header()


def test_train_and_info_say_how_much_the_end_time_band_weighs_the_seen_poses():
    """rbgp train's summary and rbgp info print the path distribution's line (cli.report._paths_text): with λ < 1 it
    names the weight; with λ = 1 (None) it says nothing of it. The header a model file keeps carries λ."""
    from rbgp_cli.cli.report import _paths_text

    p = fit_paths(_rich_family(5, 1, spread=0.2))
    assert p.duration_evidence is not None and p.duration_evidence < 1.0
    line = _paths_text(p.header())
    assert f"×{p.duration_evidence:.3g}" in line and "end-time band" in line
    p.duration_evidence = None
    assert "end-time band" not in _paths_text(p.header())


@pytest.mark.slow
def test_studies_of_five_hold_fresh_end_times_with_the_finite_sample_count():
    """Eight studies of five motions of the rich family (durations spread 20 % in ln D), each seen to F = 0.2 … 0.8 by
    40 fresh motions: with λ chosen by finite_sample_count the 90 % end-time band holds 0.91 of their end times on
    average (measured); with the plain share (held / n ≥ 0.90, 18 of the 20 left-out beginnings) it held 0.84, one
    study 0.68: the largest λ that passes by luck is too narrow for the next motion."""
    fresh = _rich_family(40, 999, spread=0.2)
    seen = [(split_seen(tr, F)[0], tr.t[-1]) for tr in fresh for F in (0.2, 0.4, 0.6, 0.8)]
    rule, plain = [], []
    for study in range(8):
        demos = _rich_family(5, 10 + study, spread=0.2)
        p = fit_paths(demos)
        inside = _evidence_loo(p, demos)
        share = [lam for lam, v in inside.items() if np.mean(v) >= 0.9 - 1e-12]
        for lam, out in (((p.duration_evidence or 1.0), rule), (max(share) if share else min(inside), plain)):
            ant = Anticipator(p, None, duration_evidence=lam)
            bands = [ant.estimate(s.t, s.quat, s.position).end_time_band for s, _ in seen]
            out.append(np.mean([lo <= T <= hi for (lo, hi), (_, T) in zip(bands, seen)]))
    assert np.mean(rule) >= 0.88, rule
    assert np.mean(rule) >= np.mean(plain) + 0.04, (rule, plain)
