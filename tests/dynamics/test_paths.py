"""The path distribution and its conditioning (rbgp_cli/dynamics/paths.py, docs/method.md §12): the
algebra of Gaussian conditioning, and a synthetic family of motions whose path depends linearly on its
start and goal with a known deviation covariance, where the best possible prediction is known."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rbgp_cli.dynamics.paths import PathDistribution, fit_paths
from rbgp_cli.dynamics.trajectory import Trajectory
from rbgp_cli.evaluation.coverage import Coverage, prediction_coverage
from rbgp_cli.geometry.so3 import exp_quat, quat_multiply

S = 51
PHASE = np.linspace(0.0, 1.0, S)
#: the family's spreads: the start and goal offsets (rad, m), and the smooth bridge left in between
START_SD = np.array([0.05, 0.05, 0.05, 0.03, 0.03, 0.03])
MIDDLE_SD = np.array([0.02, 0.02, 0.02, 0.01, 0.01, 0.01])
MIDDLE_LENGTH = 0.15


def mean_path(s):
    """A curved mean path: turning about z by 0.8 s rad, moving 0.5 m along x with an arc in y."""
    quat = exp_quat(np.stack([np.zeros_like(s), np.zeros_like(s), 0.8 * s], axis=-1))
    pos = np.stack([0.5 * s, 0.2 * np.sin(np.pi * s), np.full_like(s, 0.1)], axis=-1)
    return quat, pos


def family_covariance(middle_sd=MIDDLE_SD):
    """The family's covariance over the grid, per coordinate j (S, S): the start offset u and the goal
    offset v enter linearly, δ_j(s) = (1 − s) u_j + s v_j + η_j(s), with u_j, v_j ~ N(0, START_SD_j²)
    and η_j a smooth process of variance middle_sd_j² (squared-exponential over phase)."""
    lin = np.outer(1 - PHASE, 1 - PHASE) + np.outer(PHASE, PHASE)
    K = np.exp(-0.5 * ((PHASE[:, None] - PHASE[None, :]) / MIDDLE_LENGTH) ** 2)
    return [START_SD[j] ** 2 * lin + middle_sd[j] ** 2 * K for j in range(6)]


def draw_family(n, rng, middle_sd=MIDDLE_SD):
    """n deviations (n, S, 6) of the family, their durations (n,) s, and the motions as Trajectory
    objects sampled on the grid (R = exp(δ_rot) R̄(s), p = p̄(s) + δ_pos, t = s·D)."""
    covs = family_covariance(middle_sd)
    dev = np.stack([rng.multivariate_normal(np.zeros(S), C + 1e-12 * np.eye(S), size=n) for C in covs], axis=-1)
    durations = np.exp(rng.normal(np.log(2.0), 0.1, size=n))
    mq, mp = mean_path(PHASE)
    trajs = [Trajectory(PHASE * d, quat_multiply(exp_quat(x[:, :3]), mq), mp + x[:, 3:], name=str(i))
             for i, (x, d) in enumerate(zip(dev, durations))]
    return dev, durations, trajs


def oracle_mean(dev, middle_sd=MIDDLE_SD):
    """The true conditional mean of the family given δ(0) and δ(1) (zero-mean Gaussian, coordinates
    independent): C[:, ends] C[ends, ends]⁻¹ δ(ends), per coordinate; (n, S, 6)."""
    ends = [0, S - 1]
    out = np.empty_like(dev)
    for j, C in enumerate(family_covariance(middle_sd)):
        gain = np.linalg.solve(C[np.ix_(ends, ends)], C[ends, :]).T  # (S, 2)
        out[..., j] = dev[:, ends, j] @ gain.T
    return out


def pose_rmse(q, p, trajs):
    """Position RMSE (m) of poses (n, S, ·) against trajectories sampled on the same grid."""
    return float(np.sqrt(np.mean([(p[i] - t.position) ** 2 for i, t in enumerate(trajs)]) * 3))


def condition_on_ends(paths, tr, duration=True):
    obs = [paths.observe([0.0], tr.quat[:1], tr.position[:1], exact=True),
           paths.observe([1.0], tr.quat[-1:], tr.position[-1:], exact=True)]
    if duration:
        obs.append(paths.observe_duration(tr.duration))
    return paths.condition(*paths.stack(*obs))


@pytest.fixture(scope="module")
def family():
    rng = np.random.default_rng(38)
    _, _, train = draw_family(120, rng)
    fresh_dev, _, fresh = draw_family(60, rng)
    return fit_paths(train), train, fresh_dev, fresh


# --------------------------------------------------------------------------------------------- algebra
@pytest.fixture(scope="module")
def small():
    rng = np.random.default_rng(1)
    _, _, trajs = draw_family(12, rng)
    return fit_paths(trajs), trajs


def test_fewer_than_three_demonstrations_give_no_distribution(small):
    assert fit_paths(small[1][:2]) is None
    assert isinstance(fit_paths(small[1][:3]), PathDistribution)


def test_conditioning_on_an_exact_observation_reproduces_it(small):
    paths, trajs = small
    rng = np.random.default_rng(2)
    phases = np.sort(rng.uniform(0, 1, 4))
    q, p = paths.pose_at(paths.deviations[3], phases)  # poses a demonstration passes
    A, y, r2 = paths.observe(phases, q, p, exact=True)
    cond = paths.condition(A, y, r2)
    # in scaled units the tolerance is 0.5 mm / 1 mrad over each coordinate's spread: well below 1e-2
    np.testing.assert_allclose(A @ cond.mean, y, atol=1e-2)
    q2, p2 = paths.pose_at(cond.deviation, phases)
    np.testing.assert_allclose(p2, p, atol=2e-3)  # within a few tolerances (0.5 mm)


def test_the_conditioned_covariance_is_symmetric_positive_semidefinite_and_pinched(small):
    paths, trajs = small
    _, Sigma = paths.prior()
    cond = condition_on_ends(paths, trajs[0])
    for C in (Sigma, cond.cov):
        np.testing.assert_allclose(C, C.T, atol=1e-12)
        w = np.linalg.eigvalsh(C)
        assert w.min() > -1e-9 * w.max()
    sd = cond.marginal_std()
    assert np.all(sd[0] < 0.05 * sd[S // 2]) and np.all(sd[-1] < 0.05 * sd[S // 2])  # the band pinches at both ends
    assert np.all(np.diag(cond.cov) <= np.diag(Sigma) + 1e-12)  # knowing more never widens it


@settings(max_examples=10, deadline=None)
@given(st.integers(0, 11), st.floats(0.05, 0.95))
def test_matheron_update_of_the_prior_mean_is_the_conditioned_mean(small, d, via):
    paths, trajs = small
    tr = trajs[d]
    k = int(round(via * (S - 1)))
    A, y, r2 = paths.stack(paths.observe([0.0], tr.quat[:1], tr.position[:1], exact=True),
                           paths.observe([PHASE[k]], tr.quat[k:k + 1], tr.position[k:k + 1], tolerance=(0.01, 0.005)))
    m, _ = paths.prior()
    prior_dev, prior_ell = paths.unscale(m)
    moved = paths.update(prior_dev[None], A, y[None], r2, log_duration=np.atleast_1d(prior_ell))[0]
    np.testing.assert_allclose(moved, paths.condition(A, y, r2).deviation, atol=1e-9)


def test_a_batch_of_observation_values_shares_one_factorisation(small):
    paths, trajs = small
    obs = [paths.observe([0.0, 1.0], np.stack([t.quat[0], t.quat[-1]]), np.stack([t.position[0], t.position[-1]]),
                         exact=True) for t in trajs[:3]]
    batch = paths.condition(obs[0][0], np.stack([o[1] for o in obs]), obs[0][2])
    for i, o in enumerate(obs):
        np.testing.assert_allclose(batch.mean[i], paths.condition(*o).mean, atol=1e-10)


# --------------------------------------------------------------------------------------------- the family
@pytest.mark.slow
def test_the_conditioned_mean_recovers_the_true_path_within_ten_percent_of_the_noise_floor(family):
    paths, _, fresh_dev, fresh = family
    means = [paths.pose_at(condition_on_ends(paths, tr).deviation, PHASE) for tr in fresh]
    ours = pose_rmse(np.array([m[0] for m in means]), np.array([m[1] for m in means]), fresh)
    truth = oracle_mean(fresh_dev)  # the best any predictor can do given start and goal
    mq, mp = mean_path(PHASE)
    floor = pose_rmse(None, mp[None] + truth[..., 3:], fresh)
    assert floor > 0.004  # the family leaves a real spread between its ends (MIDDLE_SD 1 cm)
    assert ours <= 1.10 * floor, (ours, floor)
    # and the start alone is far worse: the goal is worth something here
    start_only = [paths.pose_at(paths.condition(*paths.observe([0.0], t.quat[:1], t.position[:1], exact=True)).deviation,
                                PHASE)[1] for t in fresh]
    assert pose_rmse(None, np.array(start_only), fresh) > 1.5 * floor


def _band_coverage(paths, fresh):
    """Coverage of ``fresh`` motions by the band given start, goal and duration
    (:meth:`Conditioned.region` with :meth:`PathDistribution.goal_band_scale`, what rollouts carry and
    crossval measures) around the conditioned mean."""
    from rbgp_cli.evaluation.coverage import band_coverage

    total = Coverage()
    for tr in fresh:
        cond = condition_on_ends(paths, tr)
        q, p = paths.pose_at(cond.deviation, PHASE)
        half, M = cond.region(PHASE, scale=paths.goal_band_scale())
        total = total + band_coverage(Trajectory(tr.t, q, p), half, M, tr, S)
    return total.to_dict()


@pytest.mark.slow
def test_the_bands_hold_fresh_motions_ninety_percent_of_the_time(family):
    paths, _, _, fresh = family
    cov = _band_coverage(paths, fresh)
    assert abs(cov["coverage_position"] - 0.90) <= 0.04, cov
    assert abs(cov["coverage_rotation"] - 0.90) <= 0.04, cov


@pytest.mark.slow
def test_five_demonstrations_give_goal_bands_that_hold_fresh_motions():
    """Studies of 5 demonstrations of the family (issue 38): the bands given start, goal and duration hold
    the fresh motions 0.85–0.95 of the time (pooled over 12 studies, 20 fresh motions each; 0.89 / 0.94
    when written). With the factors kept at 1 or more (the rule below 10 demonstrations before) they
    are wider and hold more (0.90 / 0.95 here, where the left-out factors are near 1; on real sets of 5–7
    the difference is larger: docs/defaults.md, issue 38)."""
    from dataclasses import replace

    rng = np.random.default_rng(55)
    got, kept = Coverage(), Coverage()
    for _ in range(12):
        _, _, train = draw_family(5, rng)
        _, _, fresh = draw_family(20, rng)
        paths = fit_paths(train)
        c = _band_coverage(paths, fresh)
        got = got + _as_coverage(c, len(fresh))
        wide = replace(paths, _goal_scale=tuple(max(1.0, x) for x in paths.goal_band_scale()))
        kept = kept + _as_coverage(_band_coverage(wide, fresh), len(fresh))
    g, k = got.to_dict(), kept.to_dict()
    assert 0.85 <= g["coverage_position"] <= 0.95, g
    assert 0.85 <= g["coverage_rotation"] <= 0.95, g
    assert k["coverage_position"] > g["coverage_position"] and k["coverage_rotation"] > g["coverage_rotation"], (k, g)


def _as_coverage(d, n):
    """A coverage dictionary of n motions of S steps back as counts (to pool studies with equal weight)."""
    return Coverage(round(d["coverage_position"] * 3 * S * n), 3 * S * n, round(d["coverage_rotation"] * S * n), S * n,
                    d["band_position"] * 3 * S * n, d["band_rotation"] * S * n)


@pytest.mark.slow
def test_a_goal_equal_to_a_demonstrations_end_reproduces_that_demonstration():
    # a family almost fully explained by its two ends (the bridge in between 1 mm / 2 mrad)
    rng = np.random.default_rng(7)
    middle = MIDDLE_SD / 10
    _, _, train = draw_family(40, rng, middle_sd=middle)
    paths = fit_paths(train)
    mq, mp = mean_path(PHASE)
    for tr in train[:5]:
        q, p = paths.pose_at(condition_on_ends(paths, tr).deviation, PHASE)
        err = float(np.sqrt(np.mean(np.sum((p - tr.position) ** 2, axis=1))))
        spread = float(np.sqrt(np.mean(np.sum((mp - tr.position) ** 2, axis=1))))
        assert err < 0.004 and err < 0.1 * spread, (err, spread)


def test_the_goal_distance_is_small_for_the_familys_own_goals_and_large_for_a_far_one(small):
    paths, trajs = small
    q0 = np.array([t.quat[0] for t in trajs])
    p0 = np.array([t.position[0] for t in trajs])
    qg = np.array([t.quat[-1] for t in trajs])
    pg = np.array([t.position[-1] for t in trajs])
    own = paths.goal_distance(q0, p0, qg, pg)
    assert np.median(own) < 3.5  # a χ with 6 degrees of freedom has its median at 2.2
    far = paths.goal_distance(q0[:1], p0[:1], qg[:1], pg[:1] + np.array([0.5, 0.0, 0.0]))
    assert far[0] > 10.0


def test_the_pose_distance_is_zero_at_the_conditioned_mean_linear_in_an_offset_and_small_for_own_poses(small):
    paths, trajs = small
    q0 = np.array([t.quat[0] for t in trajs])
    p0 = np.array([t.position[0] for t in trajs])
    k = len(trajs[0]) // 2
    s = np.array([(t.t[k] - t.t[0]) / t.duration for t in trajs])
    qm = np.array([t.quat[k] for t in trajs])
    pm = np.array([t.position[k] for t in trajs])
    own = paths.pose_distance(q0, p0, s, qm, pm)
    assert own.shape == (len(trajs),)
    assert np.median(own) < 3.5  # the family's own poses: a χ with 6 degrees of freedom, median 2.2
    # the start-conditioned mean pose at that phase is at distance 0; an offset in position scales linearly
    A0, y0, r0 = paths.observe([0.0], q0[:1], p0[:1], exact=True)
    mq, mp = paths.pose_at(paths.condition(A0, y0, r0).deviation, s[:1])
    assert paths.pose_distance(q0[:1], p0[:1], s[:1], mq, mp)[0] < 1e-6
    step = np.array([0.0, 0.01, 0.0])
    d1 = paths.pose_distance(q0[:1], p0[:1], s[:1], mq, mp + step)[0]
    d3 = paths.pose_distance(q0[:1], p0[:1], s[:1], mq, mp + 3 * step)[0]
    assert d1 > 0.1 and d3 == pytest.approx(3 * d1, rel=1e-6)
    # at phase 1 it is the goal distance
    qg = np.array([t.quat[-1] for t in trajs])
    pg = np.array([t.position[-1] for t in trajs])
    np.testing.assert_allclose(paths.pose_distance(q0, p0, np.ones(len(trajs)), qg, pg),
                               paths.goal_distance(q0, p0, qg, pg), rtol=1e-12)


# --------------------------------------------------------------------------------------------- the goal's strength
def _ends(paths, dev, ell):
    """(A, y, r²) of the start, the goal and the duration of a deviation path (S, 6) with ln D ``ell``."""
    q, p = paths.pose_at(dev, np.array([0.0, 1.0]))
    return paths.stack(paths.observe([0.0, 1.0], q, p, exact=True), paths.observe_duration(float(np.exp(ell))))


@pytest.mark.slow
def test_goal_strength_keeps_the_fitted_distribution_along_the_demonstrations_and_grows_off_them():
    """Five demonstrations of the family (issue 38, fourth pass): ends six times a demonstration's own
    offsets (far, but along the directions the five vary in) keep λ = 1, the fitted distribution and its
    linear extrapolation; a goal 30 cm off the mean's end in z, a direction they do not span, takes λ ≥ 4
    (8–128 when written), and its conditioned mean still ends at the goal while its middle strays less
    from the mean path than with λ = 1 (the amplified regression on the goal that 5 slower handovers showed)."""
    rng = np.random.default_rng(55)
    for _ in range(6):
        _, _, train = draw_family(5, rng)
        paths = fit_paths(train)
        X = paths.vectors()
        m = X.mean(axis=0)
        along_dev, along_ell = paths.unscale(m + 6.0 * (X[0] - m))
        assert paths.goal_strength(*_ends(paths, along_dev, along_ell)) == 1.0
        m_dev, m_ell = paths.unscale(m)
        q, p = paths.pose_at(m_dev, np.array([0.0, 1.0]))
        p[1, 2] += 0.3
        A, y, r2 = paths.stack(paths.observe([0.0, 1.0], q, p, exact=True), paths.observe_duration(float(np.exp(m_ell))))
        mean_, Sigma, lam = paths.goal_prior(A, y, r2)
        assert lam >= 4.0
        strong = paths.condition(A, y, r2, prior=(mean_, Sigma)).deviation
        fitted = paths.condition(A, y, r2).deviation
        assert abs(strong[-1, 5] - (p[1, 2] - paths.position[-1, 2])) < 0.005  # ends at the goal (5 mm)
        middle = slice(S // 5, 4 * S // 5)
        assert np.abs(strong[middle, 3:]).max() < np.abs(fitted[middle, 3:]).max()


def test_goal_strength_is_one_for_the_familys_own_goals(small):
    """Twelve demonstrations: each one's own start, goal and duration take λ = 1 (they lie where the
    demonstrations vary), so the conditioned mean is the fitted distribution's."""
    paths, trajs = small
    X = paths.vectors()
    lams = [paths.goal_strength(*_ends(paths, *paths.unscale(x))) for x in X]
    assert lams == [1.0] * len(X)


# ------------------------------------------------------------------ the goal bands in recording order
def test_goal_blocks_are_contiguous_and_leave_enough_demonstrations():
    """The blocks :meth:`PathDistribution.goal_band_scale` leaves out in recording order: none for five
    demonstrations (a block of three would leave two), three of two for six, five of eight for forty."""
    from rbgp_cli.dynamics.paths import goal_blocks

    assert goal_blocks(5) is None and goal_blocks(3) is None
    assert [b.tolist() for b in goal_blocks(6)] == [[0, 1], [2, 3], [4, 5]]
    blocks = goal_blocks(40)
    assert len(blocks) == 5 and all(len(b) == 8 for b in blocks)
    assert np.array_equal(np.concatenate(blocks), np.arange(40))


def test_blocks_of_one_give_the_left_out_statistics(small):
    """With every block one demonstration long, the blocks' band statistics are leave-one-out's
    (:func:`_loo_scores`, computed by batched left-out moments: an independent route to the same numbers)."""
    from rbgp_cli.dynamics.paths import _block_stats, _loo_scores

    paths, _ = small
    _, m2, z = _loo_scores(paths, paths.smooth, paths.length, stats=True)
    b_m2, b_z = _block_stats(paths, [np.array([d]) for d in range(paths.demos)])
    np.testing.assert_allclose(b_m2, m2, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(b_z, z, rtol=1e-6, atol=1e-9)


def _drifting(order, amplitude):
    """Thirty motions of the family with a bump in the middle of the path that grows over the
    recording order (−1.5 … 1.5 times ``amplitude`` × (0.03 rad, 0.02 m) at s = ½, zero at both ends),
    read in ``order``."""
    rng = np.random.default_rng(7)
    dev, dur, _ = draw_family(30, rng)
    bump = np.sin(np.pi * PHASE)[:, None] * np.array([0.03, 0.0, 0.0, 0.02, 0.0, 0.0]) * amplitude
    drift = np.linspace(-1.5, 1.5, 30)
    mq, mp = mean_path(PHASE)
    out = []
    for i, k in enumerate(order):
        x = dev[k] + drift[k] * bump
        out.append(Trajectory(PHASE * dur[k], quat_multiply(exp_quat(x[:, :3]), mq), mp + x[:, 3:], name=str(i)))
    return out


@pytest.mark.slow
def test_goal_bands_widen_for_demonstrations_that_drift_over_the_recording_order(monkeypatch):
    """Blocks left out in recording order meet the drift that single demonstrations left out do not (their
    neighbours in time are trained on): the blocks' factors exceed leave-one-out's by 15 % or more when the
    motions drift in the order they are read (1.15 / 1.16 when written), and by under 5 % when the same
    motions are read shuffled (1.005 / 1.009); the goal bands take the larger factor."""
    import rbgp_cli.dynamics.paths as paths_module
    from rbgp_cli.dynamics.paths import _band_factors, _block_stats, _loo_scores, goal_blocks

    def ratio(trajs):
        paths = fit_paths(trajs)
        _, m2, z = _loo_scores(paths, paths.smooth, paths.length, stats=True)
        loo = _band_factors(m2, z, paths.demos)
        blocks = _band_factors(*_block_stats(paths, goal_blocks(paths.demos)), paths.demos)
        return np.array(blocks) / np.array(loo), paths

    drifting, paths = ratio(_drifting(np.arange(30), 2.0))
    shuffled, _ = ratio(_drifting(np.random.default_rng(3).permutation(30), 2.0))
    assert np.all(drifting >= 1.15 - 0.005), drifting
    assert np.all(shuffled < 1.05), shuffled
    with_blocks = np.array(paths.goal_band_scale())
    monkeypatch.setattr(paths_module, "GOAL_BLOCKS", 0)
    paths._goal_scale = None
    without = np.array(paths.goal_band_scale())
    assert np.all(with_blocks > 1.1 * without), (with_blocks, without)
