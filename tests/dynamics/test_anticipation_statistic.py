"""The duration's point estimate D̂: the weights' median or their refined mode in ln D, chosen per model on the
left-out beginnings (issue 37, twenty-seventh pass; docs/method.md §13)."""

from __future__ import annotations

import copy

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

import rbgp_cli.dynamics.anticipation as A
from rbgp_cli.dynamics.anticipation import Anticipator, _log_mode, _row_log_modes
from rbgp_cli.dynamics.paths import PathDistribution, fit_paths
from rbgp_cli.evaluation.under_way import split_seen

from .test_anticipation import family


def _log_normal_weights(grid, centre, width):
    """Weights ∝ exp(−(ln D − ln centre)² / (2 width²)) over ``grid``: their log is a parabola in ln D."""
    x = np.log(grid)
    lw = -0.5 * ((x - np.log(centre)) / width) ** 2
    w = np.exp(lw - lw.max())
    return w / w.sum()


@settings(max_examples=60, deadline=None)
@given(st.floats(0.0, 1.0), st.floats(0.05, 0.5), st.integers(0, 10_000))
def test_the_refined_mode_is_the_centre_of_weights_whose_log_is_a_parabola_in_ln_d(u, width, seed):
    """On any log grid, evenly spaced or not, weights whose log is a parabola in ln D give back its vertex exactly
    wherever the vertex lies within the largest weight's cell; the argmax alone is off by up to half a cell."""
    rng = np.random.default_rng(seed)
    x = np.sort(np.log(2.0) + np.cumsum(rng.uniform(0.03, 0.12, 24)))  # an uneven log grid
    grid = np.exp(x)
    j = int(rng.integers(2, 22))
    lo, hi = 0.5 * (x[j - 1] + x[j]), 0.5 * (x[j] + x[j + 1])
    centre = float(np.exp(lo + (0.1 + 0.8 * u) * (hi - lo)))  # inside x_j's cell, so x_j carries the largest weight
    w = _log_normal_weights(grid, centre, width)
    assert int(np.argmax(w)) == j
    assert _log_mode(grid, w, 0.0) == pytest.approx(centre, rel=1e-9)


def test_the_mode_falls_back_to_the_grid_at_its_ends_and_beside_a_zero_weight_and_is_at_least_the_span():
    grid = np.exp(np.linspace(0.0, 1.0, 11))
    w = _log_normal_weights(grid, grid[0] * 0.9, 0.2)  # the vertex beyond the first duration
    assert _log_mode(grid, w, 0.0) == grid[0]
    w = _log_normal_weights(grid, grid[5] * 1.01, 0.2)
    w[4] = 0.0  # a left-out neighbour (shorter than the seen span): no parabola
    assert _log_mode(grid, w, 0.0) == pytest.approx(grid[5])
    assert _log_mode(grid, w, 2.5 * grid[-1]) == 2.5 * grid[-1]
    flat = np.full(11, 1.0 / 11)  # no curvature: the first largest weight's duration
    assert _log_mode(grid, flat, 0.0) == pytest.approx(grid[0])


def test_the_batched_modes_equal_one_at_a_time():
    rng = np.random.default_rng(4)
    grid = np.exp(np.cumsum(rng.uniform(0.02, 0.1, (9, 16)), axis=1))
    w = rng.dirichlet(np.ones(16) * 0.7, size=9)
    w[2, :5] = 0.0
    span = rng.uniform(0.0, 2.0, 9)
    want = [_log_mode(grid[d], w[d], span[d]) for d in range(9)]
    np.testing.assert_allclose(_row_log_modes(grid, w, span), want, rtol=1e-12)  # scalar and numpy logs: an ulp apart


@pytest.fixture(scope="module")
def paths():
    demos, _ = family(12, 3)
    return fit_paths(demos)


def test_with_the_mode_the_end_time_is_the_weights_mode_and_its_band_is_centred_on_it(paths):
    """estimate()'s end time is t_0 + _log_mode of the weights; the band is the band weights' 5 % and 95 % moved
    by D̂ / their median (band_shift), so the band's median is D̂; the samples' durations are drawn from the same
    moved weights. With the median nothing moves: band_shift is 1 where the band's weights are the weights."""
    tr = family(1, 11)[0][0]
    seen, _ = split_seen(tr, 0.4)
    med = Anticipator(paths, None, duration_evidence=1.0, duration_statistic="median")
    mode = Anticipator(paths, None, duration_evidence=1.0, duration_statistic="mode")
    grid, w, terms = mode.weights(seen.t, seen.quat, seen.position)
    span, t0 = terms["span"], float(seen.t[0])
    D = _log_mode(grid, w, span)
    e = mode.estimate(seen.t, seen.quat, seen.position)
    assert e.end_time == pytest.approx(t0 + D, rel=1e-12)
    k = D / mode._duration_quantiles(grid, w, span, (0.5,))[0]
    lo, hi = (x * k for x in mode._duration_quantiles(grid, w, span, (0.05, 0.95)))
    assert e.end_time_band[0] == pytest.approx(t0 + min(lo, D)) and e.end_time_band[1] == pytest.approx(t0 + max(hi, D))
    assert med.band_shift(grid, w, w, span) == 1.0 and mode.band_shift(grid, w, w, span) == pytest.approx(k)
    e_med = med.estimate(seen.t, seen.quat, seen.position)
    assert e_med.end_time == pytest.approx(t0 + med._duration_quantiles(grid, w, span, (0.5,))[0], rel=1e-12)
    c = mode.continuation(seen.t, seen.quat, seen.position, samples=300, seed=2)
    ends = np.array([s[0][-1] for s in c.samples])
    assert abs(np.median(ends) - e.end_time) < 0.02 * (e.end_time - t0)  # the draws are centred on D̂ too
    with pytest.raises(ValueError, match="duration_statistic"):
        Anticipator(paths, None, duration_statistic="mean")


def test_the_surprise_is_measured_at_the_median_whichever_the_point_estimate(paths):
    """The seen part's surprise ρ and the widening it gives are the same for a median and a mode anticipator (both
    measure ρ at the weights' median, as fit_seen's left-out reference does); so are the reference's left-out ρ
    (_spread_terms) for a path distribution whose D̂ is the mode and one whose D̂ is the median. A motion moved off
    the family is widened (s > 1), so the equality is not that of two ones."""
    from rbgp_cli.dynamics.anticipation import _seen, _spread_terms
    from rbgp_cli.dynamics.trajectory import Trajectory

    tr = family(1, 12)[0][0]
    moved = Trajectory(tr.t, tr.quat, tr.position + 0.01, name=tr.name)
    seen, _ = split_seen(moved, 0.5)
    med = Anticipator(paths, None, duration_statistic="median")
    mode = Anticipator(paths, None, duration_statistic="mode")
    e_med, e_mode = (a.estimate(seen.t, seen.quat, seen.position) for a in (med, mode))
    assert e_mode.end_time != e_med.end_time  # the point estimates differ
    assert e_mode.band_widening == pytest.approx(e_med.band_widening, rel=1e-9) and e_med.band_widening > 1.0
    grid, w, terms = med.weights(seen.t, seen.quat, seen.position)
    rho = med.surprise(*terms["seen"][3:], med._duration_quantiles(grid, w, terms["span"], (0.5,))[0])
    assert e_med.band_widening == pytest.approx(med.surprise_at(*terms["seen"][3:], e_med.end_time - seen.t[0], rho=rho))
    p_med, p_mode = copy.copy(paths), copy.copy(paths)
    p_med.duration_statistic, p_mode.duration_statistic = None, "mode"
    for F in A.SEEN_FRACTIONS:
        a, b = _spread_terms(p_med, F), _spread_terms(p_mode, F)
        np.testing.assert_allclose(b["rho"], a["rho"], rtol=1e-9)
        np.testing.assert_allclose(b["rho_live"], a["rho_live"], rtol=1e-9)
        assert not np.allclose(b["e"], a["e"])  # the remainders are timed at each one's D̂: these move


def test_a_second_mode_pulls_the_median_between_the_two_and_not_the_mode():
    """Weights with a sharp peak at 4 s (45 % of the mass) and a broad one about 7 s (55 %): the median lies between
    the two (where little weight is), the mode stays at 4 s."""
    grid = np.exp(np.linspace(np.log(2.0), np.log(10.0), 32))
    w = 0.45 * _log_normal_weights(grid, 4.0, 0.03) + 0.55 * _log_normal_weights(grid, 7.0, 0.15)
    ant = Anticipator.__new__(Anticipator)
    ant._half_step = 0.5 * (np.log(grid[1]) - np.log(grid[0]))
    median = ant._duration_quantiles(grid, w, 0.0, (0.5,))[0]
    assert 4.5 < median < 6.5
    assert _log_mode(grid, w, 0.0) == pytest.approx(4.0, rel=0.01)


def test_fit_seen_takes_the_mode_only_where_it_timed_the_left_out_beginnings_closer_by_a_standard_error(monkeypatch):
    """_choose_statistic: the mode where its per-beginning |ln D̂ − ln D| is smaller than the median's by more than
    DURATION_MODE_SE paired standard errors; None (the median) where it is worse, or better by less."""
    p = copy.copy(fit_paths(family(12, 3)[0]))
    p.info = {}
    base = np.linspace(0.05, 0.15, 40)
    noise = np.random.default_rng(0).normal(size=40)
    noise -= noise.mean()
    cases = {"mode": base - 0.01 + 0.01 * noise,  # closer by 0.01, SE 0.0016
             None: base - 0.001 + 0.02 * noise}  # closer by 0.001, SE 0.003: within one standard error
    for want, modes in cases.items():
        monkeypatch.setattr(A, "_duration_loo", lambda *a, modes=modes, **k: {k["candidates"][0]: modes})
        A._choose_statistic(p, [], (0.01, 0.8, None), base)
        assert p.duration_statistic == want
        assert p.info["duration_statistic"] == (want or "median")
        assert p.info["duration_mode_gain"] == pytest.approx(np.mean(modes - base))


def test_the_model_file_keeps_the_statistic_and_refuses_another():
    from rbgp_cli.cli.report import _paths_text
    from rbgp_cli.io.model_schema import TOP

    rng = np.random.default_rng(0)
    D, S = 5, 51
    paths = PathDistribution(np.linspace(0, 1, S), np.tile([0, 0, 0, 1.0], (S, 1)), np.zeros((S, 3)),
                             rng.normal(size=(D, S, 6)), rng.normal(size=D), duration_statistic="mode")
    header = paths.header()
    assert header["duration_statistic"] == "mode"
    TOP["paths"][1](header, ("paths",))
    assert PathDistribution.from_arrays(paths.to_arrays(), header).duration_statistic == "mode"
    assert "weights' mode" in _paths_text(header)
    with pytest.raises(Exception, match="duration_statistic"):
        TOP["paths"][1](dict(header, duration_statistic="mean"), ("paths",))
    old = {k: v for k, v in header.items() if k != "duration_statistic"}
    assert PathDistribution.from_arrays(paths.to_arrays(), old).duration_statistic is None
    assert "mode" not in _paths_text(old)
    paths.duration_statistic = None
    assert "duration_statistic" not in paths.header()
