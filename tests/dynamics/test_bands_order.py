"""Bands that hold for the next session and with few demonstrations (issue 36): the demonstrations
left out in recording order, the shrinkage of the deviation covariance, and the drift test over the
recording order, against synthetic processes whose answer is known."""

from __future__ import annotations

import numpy as np
import pytest

from rbgp_cli.dynamics.trajectory import Trajectory
from rbgp_cli.dynamics.variation import (DRIFT_P, demonstration_deviations, demonstration_variation, order_drift,
                                         shrinkage)
from rbgp_cli.geometry.so3 import exp_quat, quat_multiply
from tests.dynamics.synthetic import timed_demos

SIGMA_POS, SIGMA_ROT = 0.05, 0.08


def session(n, seed, drift_pos=0.0, drift_rot=0.0, samples=60, first=0, total=None):
    """``n`` demonstrations of one session in recording order (positions ``first`` … ``first + n − 1``
    of a session of ``total``): a shared motion, per demonstration a smooth deviation a_d·s of known
    standard deviation σ·s and a start offset that stays (as tests/dynamics/test_variation.py), plus a
    drift of the mean path over the session, linear in the position u ∈ [−1/2, 1/2] in the session:
    u·drift·sin(πs) (the peak higher later, the start unchanged), in y (m) and about z (rad)."""
    total = n if total is None else total
    order = iter(range(first, first + n))

    def pose(rng, s):
        u = next(order) / max(total - 1, 1) - 0.5
        a_pos, b_pos = rng.normal(0, SIGMA_POS, 3), rng.normal(0, 0.03, 3)
        a_rot, b_rot = rng.normal(0, SIGMA_ROT, 3), rng.normal(0, 0.05, 3)
        bump = np.sin(np.pi * s)
        p = np.stack([0.4 * s, 0.2 * bump, 1.0 - 0.3 * s**2], axis=1) + np.outer(s, a_pos) + b_pos
        p[:, 1] += u * drift_pos * bump
        dev = np.outer(s, a_rot) + b_rot
        dev[:, 2] += u * drift_rot * bump
        base_q = exp_quat(np.outer(s, [0.2, 1.0, 0.4]) + [0.0, 0.0, 2.8])
        return quat_multiply(exp_quat(dev), base_q), p

    return timed_demos(n, seed, samples, pose)


def _coverage(train, fresh):
    """Coverage of the ``fresh`` demonstrations by the 90 % band of the variation of ``train``
    (:meth:`Variation.region`) around the conditional mean given each one's start (the mean path moved
    by its start deviation, as the bands' calibration at ridge ∞ and gain 0 predicts it)."""
    v = demonstration_variation(train)
    return _coverage_of(v, train, fresh), v


@pytest.mark.slow
def test_blocked_folds_of_a_drifting_session_hold_fresh_later_draws_at_the_level():
    """A session of 40 whose mean path drifts (its peak 12 cm higher and 0.25 rad turned from the first
    demonstration to the last, about 2.5 times the demonstrations' own spread there) held out in five
    contiguous blocks in recording order: the bands of the other 32 hold fresh draws at the held-out
    block's place in the session 0.90 ± 0.04 of the time, position and rotation (pooled over 6
    sessions). Left out at random only, the factors do not see the drift and hold fewer."""
    total, before = None, None
    for rep in range(6):
        demos = session(40, 500 + rep, drift_pos=0.12, drift_rot=0.25)
        for block in np.array_split(np.arange(40), 5):
            train = [d for i, d in enumerate(demos) if i not in set(block.tolist())]
            fresh = session(len(block), 900 + 10 * rep + int(block[0]), drift_pos=0.12, drift_rot=0.25,
                            first=int(block[0]), total=40)
            cov, v = _coverage(train, fresh)
            total = cov if total is None else total + cov
            # the bands cover both kinds of left-out demonstrations: the larger of the two factors
            assert v.band_scale == (max(v.calibration["random"][0], v.calibration["recorded"][0]),
                                    max(v.calibration["random"][1], v.calibration["recorded"][1]))
            from dataclasses import replace

            # the same band with the factors of the random leave-one-out alone: narrower
            narrow = _coverage_of(replace(v, band_scale=tuple(v.calibration["random"])), train, fresh)
            before = narrow if before is None else before + narrow
    c, b = total.to_dict(), before.to_dict()
    assert abs(c["coverage_position"] - 0.90) <= 0.04, c
    assert abs(c["coverage_rotation"] - 0.90) <= 0.04, c
    assert b["coverage_rotation"] < c["coverage_rotation"], (b, c)


def _coverage_of(v, train, fresh):
    """:func:`_coverage` with a given variation ``v`` (of ``train``): the band rbgp gives (what crossval
    measures, :func:`rbgp_cli.evaluation.coverage.band_coverage`), widened by each start's surprise."""
    from rbgp_cli.dynamics.model import mean_path
    from rbgp_cli.evaluation.coverage import Coverage, band_coverage
    from rbgp_cli.geometry.so3 import log_quat, quat_conjugate

    path = mean_path(train, 51)
    total = Coverage()
    for real in fresh:
        half, M = v.region(v.s, widen=v.start_widening(real.quat[:1], real.position[:1])[0])  # as a rollout widens it
        cond = path["position"] + (real.position[0] - path["position"][0])
        start_rot = log_quat(quat_multiply(real.quat[0], quat_conjugate(path["quat"][0])))
        mean_q = quat_multiply(exp_quat(np.broadcast_to(start_rot, (51, 3))), path["quat"])
        total = total + band_coverage(Trajectory(v.s * real.duration, mean_q, cond), half, M, real, T=51)
    return total


@pytest.mark.slow
def test_five_demonstrations_of_a_known_process_give_bands_that_hold_fresh_draws():
    """Five demonstrations (a normal small study) of the known process: the bands hold fresh draws at
    least 0.85 of the time, position and rotation (pooled over 30 studies of 5, 8 fresh demonstrations
    each). Without the shrinkage and the calibration (rank ≤ 3 covariance, factors 1) rotation held less."""
    from dataclasses import replace

    total, plain = None, None
    for rep in range(30):
        train = session(5, 700 + rep)
        fresh = session(8, 1700 + rep)
        cov, v = _coverage(train, fresh)
        total = cov if total is None else total + cov
        old = _coverage_of(replace(v, shrinkage=0.0, band_scale=(1.0, 1.0)), train, fresh)
        plain = old if plain is None else plain + old
    c, p = total.to_dict(), plain.to_dict()
    assert c["coverage_position"] >= 0.85, c
    assert c["coverage_rotation"] >= 0.85, c
    assert p["coverage_rotation"] < c["coverage_rotation"], (p, c)


def test_the_drift_test_fires_on_a_drifting_session_and_keeps_its_level_on_exchangeable_ones():
    """The permutation test of :func:`order_drift` on the deviations: a session with a drift of the
    mean path is found (p < DRIFT_P) with the figure near the truth; demonstrations in no particular
    order (20 sessions without drift, and one drifting session reordered at random) are not, except at
    about the test's level."""
    demos = session(40, 3, drift_pos=0.12)
    _, delta = demonstration_deviations(demos)
    found = order_drift(delta, [d.duration for d in demos])
    assert found["drift"] and found["p_value"] < DRIFT_P, found
    assert found["position_m"] == pytest.approx(0.12, abs=0.05)  # the peak's change, first to last
    assert abs(found["position_phase"] - 0.5) <= 0.2
    shuffled = [demos[i] for i in np.random.default_rng(0).permutation(40)]
    _, delta_s = demonstration_deviations(shuffled)
    assert not order_drift(delta_s, [d.duration for d in shuffled])["drift"]
    p = []
    for rep in range(20):
        quiet = session(30, 40 + rep)
        _, dq = demonstration_deviations(quiet)
        p.append(order_drift(dq, [d.duration for d in quiet], permutations=199)["p_value"])
    p = np.array(p)
    assert np.sum(p < 0.05) <= 3, p  # at the 5 % level, 1 of 20 expected; 4 or more has probability 1.6 %
    assert 0.25 < np.mean(p) < 0.75, p  # uniform on exchangeable data: mean 1/2
    assert order_drift(delta[:5], [1.0] * 5) is None  # too few to test


def test_shrinkage_is_near_one_for_independent_coordinates_and_small_for_strongly_coupled_ones():
    """Schäfer–Strimmer's weight: coordinates drawn independently have correlations that are noise
    (α → 1); coordinates that move together (one factor drives all six) keep theirs (α small)."""
    rng = np.random.default_rng(0)
    D, S = 40, 21
    indep = rng.normal(size=(D, S, 6))
    indep[:, 0] = 0.0
    assert shrinkage(indep) > 0.8
    f = rng.normal(size=(D, S, 1))
    coupled = f * np.array([1.0, 0.8, -0.6, 0.5, 1.2, -0.9]) + 0.2 * rng.normal(size=(D, S, 6))
    coupled[:, 0] = 0.0
    assert shrinkage(coupled) < 0.1
    assert 0.0 <= shrinkage(rng.normal(size=(4, S, 6))) <= 1.0


def test_few_demonstrations_get_a_full_rank_draw_and_factors_from_four_on():
    """With 4–6 demonstrations the draws' rotation covariance has rank 3 (shrunk toward its diagonal)
    and the factors come from leaving each out (≥ 1); with 3 they stay 1."""
    for D in (4, 5, 6):
        v = demonstration_variation(session(D, 60 + D))
        assert v.calibration["random"] is not None and min(v.band_scale) >= 1.0
        eta = v.draw(4000, np.random.default_rng(D))
        C = np.cov(eta[:, 30, :3].T)
        assert np.linalg.matrix_rank(C, tol=1e-8 * np.trace(C)) == 3
    v3 = demonstration_variation(session(3, 1))
    assert v3.band_scale == (1.0, 1.0) and v3.calibration == {"random": None, "recorded": None}



@pytest.mark.slow
def test_typical_samples_score_like_fresh_demonstrations_and_predictive_draws_further():
    """Variety (issue 36): one typical sample per fresh start, around the conditional mean given that
    start, scores against five training demonstrations of the known process no further than the fresh
    demonstrations themselves do (the floor; within 10 %, pooled over 12 studies), while one draw of the
    predictive per start (Student-t with ν = 3, the mean's inflation, the factors) scores further:
    the band is not the spread of a typical motion."""
    from rbgp_cli.dynamics.model import mean_path
    from rbgp_cli.evaluation.bhattacharyya import evaluate
    from rbgp_cli.geometry.so3 import log_quat, quat_conjugate

    rng = np.random.default_rng(21)
    typical, predictive, floor = [], [], []
    for rep in range(12):
        train = session(5, 300 + rep)
        fresh = session(20, 1300 + rep)
        v = demonstration_variation(train)
        path = mean_path(train, 51)
        sets = {"typical": [], "predictive": []}
        for kind, eta in (("typical", v.draw(len(fresh), rng)), ("predictive", v.draw(len(fresh), rng, predictive=True))):
            for real, e in zip(fresh, eta):
                cond = path["position"] + (real.position[0] - path["position"][0])
                start_rot = log_quat(quat_multiply(real.quat[0], quat_conjugate(path["quat"][0])))
                mean_q = quat_multiply(exp_quat(np.broadcast_to(start_rot, (51, 3))), path["quat"])
                sets[kind].append(Trajectory(v.s * real.duration, quat_multiply(exp_quat(e[:, :3]), mean_q), cond + e[:, 3:]))
        typical.append(evaluate(sets["typical"], train, length=51, sample_size="record").mean)
        predictive.append(evaluate(sets["predictive"], train, length=51, sample_size="record").mean)
        floor.append(evaluate(fresh, train, length=51, sample_size="record").mean)
    ratio_typical, ratio_predictive = np.mean(typical) / np.mean(floor), np.mean(predictive) / np.mean(floor)
    assert ratio_typical <= 1.1, (ratio_typical, ratio_predictive)  # 0.85 against 1.42 when written
    assert ratio_predictive > ratio_typical + 0.2, (ratio_typical, ratio_predictive)
