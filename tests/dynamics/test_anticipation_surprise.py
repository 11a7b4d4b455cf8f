"""The continuation bands widened by the seen part's surprise (issues 36 and 37, sixteenth pass): the widening's
law, its batched innovation against a dense conditioning, the left-out reference it is measured against (the model
file's field is tested with the factors', test_anticipation_bands.py), and a session that drifts, whose bands hold
its motions more often than the unwidened ones."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from rbgp_cli.dynamics import anticipation
from rbgp_cli.dynamics.anticipation import Anticipator, _ELL_TOL, _seen, surprise_scale
from rbgp_cli.dynamics.paths import PathDistribution, fit_paths

from .test_anticipation import family
from .test_anticipation_bands import _rich_family


@pytest.fixture(scope="module")
def paths():
    return fit_paths(family(16, 5)[0])


def test_the_widening_is_one_up_to_the_reference_and_the_root_of_the_ratio_above():
    rho = np.array([0.0, 0.5, 1.0, 2.0, 9.0])
    s = surprise_scale(rho, 1.0)
    np.testing.assert_allclose(s, [1.0, 1.0, 1.0, np.sqrt(2.0), 3.0])
    np.testing.assert_allclose(surprise_scale(rho, 0.5), np.sqrt(np.maximum(1.0, rho / 0.5)))


def test_the_batched_innovation_is_a_dense_conditionings(paths):
    """ρ = eᵀG⁻¹e / n from the low-rank grid terms (Anticipator.surprise) equals the dense form: the seen poses
    (tolerance r) and ℓ = ln D observed through PathDistribution.observe, G = A Σ Aᵀ + diag r², e = y − A m."""
    ant = Anticipator(paths)
    tr = family(3, 77)[0][1]
    for F, D in ((0.3, tr.duration), (0.6, 1.1 * tr.duration), (0.9, 0.95 * tr.duration)):
        k = max(int(F * len(tr.t)), 3)
        t, quat, position, tau, q, p = _seen(tr.t[:k], tr.quat[:k], tr.position[:k], ant.points)
        D = max(D, tau[-1] + 1e-6)
        obs = [paths.observe(np.clip(tau / D, 0, 1), q, p, tolerance=None),
               paths.observe_duration(D, tolerance=_ELL_TOL * ant.lscale)]
        A, y, r2 = paths.stack(*obs)
        r2[: 6 * len(tau)] = ant.tolerance ** 2
        G = A @ ant.Sigma @ A.T + np.diag(r2)
        e = y - A @ ant.m
        dense = float(e @ np.linalg.solve(G, e)) / len(e)
        assert ant.surprise(tau, q, p, D) == pytest.approx(dense, rel=1e-6)


def test_the_reference_is_the_left_out_median_and_files_keep_it(paths, tmp_path):
    """fit_seen stores, per seen fraction and number of seen poses, the median of the left-out demonstrations' ρ;
    the header round-trips it; a path distribution without it (an older file) widens nothing."""
    sur = paths.seen_surprise
    assert sur["fractions"] == list(anticipation.SEEN_FRACTIONS)
    assert sur["points"] == [anticipation.SEEN_POINTS, anticipation.SPREAD_POINTS]
    assert all(len(row) == len(sur["fractions"]) and min(row) > 0 for row in sur["reference"])
    # each anticipator measures against the reference of its own number of seen poses (the live update's 6)
    np.testing.assert_allclose(Anticipator(paths)._surprise[1], sur["reference"][0])
    np.testing.assert_allclose(Anticipator(paths, points=6)._surprise[1], sur["reference"][1])
    back = PathDistribution.from_arrays(paths.to_arrays(), paths.header())
    assert back.seen_surprise == sur
    old = copy.copy(paths)
    old.seen_surprise = None
    tr = family(3, 78)[0][0]
    k = len(tr.t) // 2
    ant_old = Anticipator(old)
    t, quat, position, tau, q, p = _seen(tr.t[:k], tr.quat[:k], tr.position[:k], ant_old.points)
    assert ant_old.surprise_at(tau, q, p, tr.duration) == 1.0
    est = ant_old.estimate(tr.t[:k], tr.quat[:k], tr.position[:k])
    assert est.band_widening == 1.0


def _drifted(n, seed, shift):
    """:func:`_rich_family` motions moved by ``shift`` (3,) m at every phase: a next session whose mean moved."""
    from rbgp_cli.dynamics.trajectory import Trajectory

    return [Trajectory(tr.t, tr.quat, tr.position + np.asarray(shift), name=tr.name) for tr in _rich_family(n, seed)]


@pytest.mark.slow
def test_a_drifted_session_is_widened_and_held_better_and_a_like_one_is_not_widened():
    """Trained on 30 motions of :func:`_rich_family`, 24 fresh ones moved by 3 cm in x, y and z (three of the position's
    spread) are seen up to F = 0.5: their bands widen (median s > 1.2) and hold the real remainder more often than
    the same continuations without the widening, position and rotation (measured 0.35 / 0.91 against 0.26 / 0.81:
    a shift this large stays outside a band about the unshifted paths, and the widening of a per-number surprise
    is mild); 24 fresh motions like the training ones are widened by less (median s < 1.1)."""
    from rbgp_cli.evaluation.under_way import score, split_seen

    trained = fit_paths(_rich_family(30, 0))
    ant = Anticipator(trained)
    bare = copy.copy(trained)
    bare.seen_surprise = None
    ant_bare = Anticipator(bare)
    widen = {}
    for name, group in (("like", _rich_family(24, 2)), ("moved", _drifted(24, 3, [0.03, 0.03, 0.03]))):
        s, cov, cov_bare = [], None, None
        for i, tr in enumerate(group):
            seen, rest = split_seen(tr, 0.5)
            c = ant.continuation(seen.t, seen.quat, seen.position, samples=20 if name == "moved" else 0, seed=i)
            s.append(c.estimate.band_widening)
            if name == "moved":
                trs = c.trajectories(include_samples=True)
                sc = score(trs[0], trs[1:], rest).coverage
                cov = sc if cov is None else cov + sc
                trs = ant_bare.continuation(seen.t, seen.quat, seen.position, samples=20, seed=i).trajectories(include_samples=True)
                sc = score(trs[0], trs[1:], rest).coverage
                cov_bare = sc if cov_bare is None else cov_bare + sc
        widen[name] = float(np.median(s))
    d, b = cov.to_dict(), cov_bare.to_dict()
    assert d["coverage_position"] >= b["coverage_position"] + 0.04, (d, b)
    assert d["coverage_rotation"] >= b["coverage_rotation"] + 0.04, (d, b)
    assert widen["moved"] > 1.2 and widen["like"] < 1.1, widen



def test_stretched_keeps_the_estimate_and_widens_log_distances_by_s():
    """D (x / D)^s: s = 1 returns the durations as they are; D stays; each duration's distance from D in ln D is s
    times its own, on the same side; nothing falls below the seen span."""
    x = np.array([1.2, 1.6, 2.0, 2.5, 3.1])
    assert Anticipator.stretched(x, 2.0, 1.0) is x
    y = Anticipator.stretched(x, 2.0, 1.7)
    np.testing.assert_allclose(np.log(y / 2.0), 1.7 * np.log(x / 2.0), rtol=1e-12)
    assert Anticipator.stretched([1.2, 2.0, 2.5], 2.0, 3.0, span=1.0) == pytest.approx([1.0, 2.0, 2.0 * 1.25 ** 3])


def test_a_surprising_seen_part_widens_its_end_time_band_and_its_samples_durations_by_s(paths):
    """A seen part moved 5 mm off the demonstrations (widened s > 1) against the same path distribution without the
    reference (s = 1): the point estimate is the same, the end time's band is the unwidened one stretched by s about
    it in ln D, and the samples' durations (the same draws) are the unwidened samples' stretched by s (the samples end
    where their durations put them)."""
    bare = copy.copy(paths)
    bare.seen_surprise = None
    tr = family(3, 79)[0][0]
    k = int(0.4 * len(tr.t))
    t, quat, pos = tr.t[:k], tr.quat[:k], tr.position[:k] + 0.005
    c = Anticipator(paths).continuation(t, quat, pos, samples=12, seed=3)
    cb = Anticipator(bare).continuation(t, quat, pos, samples=12, seed=3)
    s = c.estimate.band_widening
    assert s > 1.5 and cb.estimate.band_widening == 1.0
    D = c.estimate.end_time - t[0]
    assert D == pytest.approx(cb.estimate.end_time - t[0], rel=1e-12)
    lo, hi = (x - t[0] for x in c.estimate.end_time_band)
    lo_b, hi_b = (x - t[0] for x in cb.estimate.end_time_band)
    assert np.log(hi / D) == pytest.approx(s * np.log(hi_b / D), rel=1e-9)
    assert lo == pytest.approx(max(D * (lo_b / D) ** s, t[-1] - t[0]), rel=1e-9)
    ends = np.array([smp[0][-1] for smp in c.samples]) - t[0]
    ends_b = np.array([smp[0][-1] for smp in cb.samples]) - t[0]
    np.testing.assert_allclose(np.log(ends / D), s * np.log(ends_b / D), rtol=1e-9, atol=1e-9)


def test_the_evidence_weight_is_chosen_for_the_band_as_widened(monkeypatch):
    """_evidence_loo scores each left-out beginning's end-time band as the continuation reports it, widened by its
    surprise against the left-out median at its fraction: every beginning held unwidened is held widened, at every
    λ, and some beginning is widened (half of them lie above the median)."""
    demos, _ = family(20, 11)
    p = fit_paths(demos)
    widened = anticipation._evidence_loo(p, demos)
    monkeypatch.setattr(anticipation, "SURPRISE_FROM", 10 ** 9)
    plain = anticipation._evidence_loo(p, demos)
    assert widened.keys() == plain.keys() and len(widened) == len(anticipation.DURATION_EVIDENCE_GRID)
    for lam in plain:
        assert np.all(widened[lam] | ~plain[lam]), lam
    assert any(np.any(widened[lam] & ~plain[lam]) for lam in plain)


@pytest.mark.slow
def test_a_slower_drifted_session_has_its_end_times_held_better_and_a_like_one_unchanged():
    """Trained on 30 motions of :func:`family`, 40 fresh ones 30 % slower and moved 5 mm, seen up to F = 0.3 and 0.6:
    their end times lie in the widened end-time band at least 0.9 of the time and 0.05 more often than in the unwidened
    one (measured 0.975 / 0.975 against 0.90 / 0.90: D̂ is the weights' mode here, whose end times miss these motions
    by 1.2 % / 0.9 % in ln D; at their median, 1.7 % / 1.6 %, the unwidened band held 0.80 / 0.85); 40 fresh ones like
    the training motions keep their bands (median widening 1)."""
    from rbgp_cli.dynamics.trajectory import Trajectory
    from rbgp_cli.evaluation.under_way import split_seen

    trained = fit_paths(family(30, 0)[0])
    bare = copy.copy(trained)
    bare.seen_surprise = None
    ant, ant_bare = Anticipator(trained), Anticipator(bare)
    fresh = family(40, 5)[0]
    slow = [Trajectory(tr.t * 1.3, tr.quat, tr.position + 0.005, name=tr.name) for tr in fresh]
    for F in (0.3, 0.6):
        held, held_bare = [], []
        for tr in slow:
            seen, _ = split_seen(tr, F)
            for out, a in ((held, ant), (held_bare, ant_bare)):
                lo, hi = a.estimate(seen.t, seen.quat, seen.position).end_time_band
                out.append(lo <= tr.t[-1] <= hi)
        assert np.mean(held) >= max(0.9, np.mean(held_bare) + 0.05), (F, np.mean(held), np.mean(held_bare))
        like = [ant.estimate(*(lambda s: (s.t, s.quat, s.position))(split_seen(tr, F)[0])).band_widening for tr in fresh]
        assert np.median(like) == 1.0, F
