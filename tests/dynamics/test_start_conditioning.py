"""The start-conditioned mean-path prior (``train_model(start_conditioning=True)``, docs/method.md §11):
each motion is pulled toward the mean path displaced by the deviation the demonstrations keep from a
start like its own, instead of toward the mean path itself."""

from __future__ import annotations

import numpy as np
import pytest

from rbgp_cli.dynamics.model import PathReference, train_model
from rbgp_cli.dynamics.rollout import rollout_for
from rbgp_cli.dynamics.trajectory import interpolate_poses
from rbgp_cli.dynamics.variation import demonstration_deviations, start_regression
from rbgp_cli.geometry.so3 import exp_quat, quat_make_continuous, quat_multiply
from tests.dynamics.synthetic import timed_demos

FAST = dict(restarts=1, max_points=400, shared=True, explore_size=0)


def offset_demos(n, seed, samples=80, drift=1.0):
    """A shared reaching motion (0.5 m, a 0.6 rad turn), each demonstration moved by its own start
    offset b_d that stays for the whole motion (β = 1: sd 0.05 m, 0.08 rad), plus a smooth deviation
    a_d·s that the start does not predict (sd 0.01 m, 0.02 rad at the end)."""

    def pose(rng, s):
        e = 0.5 - 0.5 * np.cos(np.pi * s)  # smooth start and stop
        p = np.stack([0.5 * e, 0.1 * np.sin(np.pi * s), 1.0 - 0.2 * e], axis=1)
        p = p + rng.normal(0, 0.05, 3) + drift * np.outer(s, rng.normal(0, 0.01, 3))
        rot = np.outer(e, [0.0, 0.2, 0.6]) + rng.normal(0, 0.08, 3) + drift * np.outer(s, rng.normal(0, 0.02, 3))
        return quat_multiply(exp_quat(rot), exp_quat(np.array([0.1, 0.0, 0.3]))), p

    return timed_demos(n, seed, samples, pose)


@pytest.fixture(scope="module")
def demos():
    """24 offset demonstrations to train on, 6 held out."""
    d = offset_demos(30, 11)
    return d[:24], d[24:]


def _position_rmse(res, truth) -> float:
    """Each rollout against the held-out motion from its start, on normalised time."""
    err = []
    for g, real in zip(res.trajectories(), truth):
        s = np.linspace(0.0, 1.0, 51)
        _, pg = interpolate_poses((g.t - g.t[0]) / g.duration, quat_make_continuous(g.quat), g.position, s)
        _, pr = interpolate_poses((real.t - real.t[0]) / real.duration, quat_make_continuous(real.quat), real.position, s)
        err.append(np.sum((pg - pr) ** 2, axis=1))
    return float(np.sqrt(np.mean(np.concatenate(err))))


def test_the_regression_recovers_an_offset_that_stays(demos):
    train, _ = demos
    _, delta = demonstration_deviations(train)
    mu, beta, r = start_regression(delta)
    assert mu.shape == beta.shape == (51, 6) and r.shape == (24, 51, 6)
    # the start offsets carry through: β ≈ 1 everywhere; the smooth part a_d·s is independent of the
    # start and only adds scatter to the estimate (sd ≈ 0.2/√24 ≈ 0.04 at s = 1)
    np.testing.assert_allclose(beta[:, 3:], 1.0, atol=0.2)
    np.testing.assert_allclose(beta[:, :3], 1.0, atol=0.3)  # (the rotation offset composes with the turn)
    assert np.all(r[:, 0] == 0.0)


@pytest.mark.slow
def test_a_conditioned_rollout_keeps_its_starts_offset_where_the_mean_path_prior_loses_it():
    """Offsets that stay and nothing else: the conditioned prior is the answer by itself. With the GP's
    residual switched off (a huge noise scale) and a strong pull, the conditioned prior's rollouts
    keep each start's offset, as the held-out demonstrations do, and the mean path's pull removes it.
    (With the residual on, the GP learns to cancel the pull near each training demonstration; since
    the feed-forward is the path's secant it does so at new starts too: 0.57 mm without conditioning
    against 0.56 mm with it, where the tangent's left 6.4 mm against 1.1 mm.)"""
    d = offset_demos(30, 11, drift=0.0)
    train, test = d[:24], d[24:]
    q0 = np.array([t.quat[0] for t in test])
    p0 = np.array([t.position[0] for t in test])
    durations = [t.duration for t in test]
    errors = {}
    for flag in (False, True):
        model = train_model(train, start_conditioning=flag, prior_gain=10.0, noise_scale=1e12, **FAST)
        assert model.summary["prior"]["start_conditioned"] is flag
        assert (model.start_deviation(q0, p0) is None) is (not flag)
        errors[flag] = _position_rmse(rollout_for(model, q0, p0, durations, with_std=False), test)
    # without conditioning the pull (gain 10 per unit phase) removes the start offset (sd 0.05 m per
    # axis) within a tenth of the motion; with it the offset stays, as in the demonstrations
    assert errors[True] < 0.5 * errors[False], errors


@pytest.mark.slow
def test_the_conditioned_path_at_the_mean_start_is_the_mean_path_plus_its_mean_deviation(demos):
    from rbgp_cli.geometry.so3 import exp_quat, quat_multiply

    train, _ = demos
    model = train_model(train, start_conditioning=True, **FAST)
    path = PathReference(model.mean)
    s = np.linspace(0.0, 1.0, 17)
    q, p, ff = path.conditioned_at(s, np.zeros((17, 6)))  # c = 0: a start at the mean start deviation
    q_bar, p_bar, ff_bar = path.at(s)
    mu = np.array([np.interp(s, path.s, path.start_mean[:, j]) for j in range(6)]).T
    np.testing.assert_allclose(p, p_bar + mu[:, 3:], atol=1e-12)
    dots = np.abs(np.sum(q * quat_multiply(exp_quat(mu[:, :3]), q_bar), axis=1))
    np.testing.assert_allclose(dots, 1.0, atol=1e-12)
    # and the start deviation of the mean path's own first pose shifted by μ(0) is zero
    c = path.start_deviation(quat_multiply(exp_quat(path.start_mean[:1, :3]), path.quat[:1]),
                             path.position[:1] + path.start_mean[:1, 3:])
    np.testing.assert_allclose(c, 0.0, atol=1e-12)


@pytest.mark.slow
def test_the_conditioned_prior_survives_the_model_file(demos, tmp_path):
    from rbgp_cli.io.model_store import load_model, save_model

    train, test = demos
    model = train_model(train, start_conditioning=True, **FAST)
    path = tmp_path / "m.rbgp"
    save_model(model, path)
    loaded, header = load_model(path)
    assert header["prior"]["start"] == "conditioned"
    q0 = np.array([t.quat[0] for t in test])
    p0 = np.array([t.position[0] for t in test])
    a = rollout_for(model, q0, p0, [1.0] * len(test), with_std=False)
    b = rollout_for(loaded, q0, p0, [1.0] * len(test), with_std=False)
    np.testing.assert_array_equal(a.position, b.position)
    np.testing.assert_allclose(loaded.mean["start_beta"], model.mean["start_beta"], rtol=0, atol=0)


def _synthetic_deviations(D, S, seed, coupling):
    """Deviations δ (D, S, 6) = c_d + A(s) c_d + noise: a start c_d (sd 1 per coordinate) whose
    effect on the motion is ``coupling`` (6, 6) growing with phase, plus independent noise."""
    rng = np.random.default_rng(seed)
    s = np.linspace(0.0, 1.0, S)
    c = rng.normal(size=(D, 6))
    delta = c[:, None, :] + s[None, :, None] * (c @ coupling.T)[:, None, :]
    return delta + 0.05 * rng.normal(size=delta.shape) * s[None, :, None]


def test_the_start_map_recovers_a_coupling_across_coordinates():
    """A start in one coordinate that moves another later (B(1) = I + A): the map finds A, where the
    per-coordinate slopes of start_regression cannot see it."""
    from rbgp_cli.dynamics.variation import start_map

    A = np.zeros((6, 6))
    A[3, 0], A[5, 1] = 0.8, -0.5  # rotation about x moves position x, about y moves position z
    delta = _synthetic_deviations(40, 21, 3, A)
    out = start_map(delta)
    assert out["map"].shape == (21, 6, 6) and out["map"].flags.c_contiguous
    assert np.isfinite(out["ridge"]) and out["ridge"] <= 0.1
    np.testing.assert_allclose(out["map"][-1], np.eye(6) + A, atol=0.1)
    np.testing.assert_allclose(out["map"][0], np.eye(6), atol=0.05)
    _, beta, _ = start_regression(delta)
    assert abs(beta[-1, 3] - 1.0) < 0.3  # per coordinate: the coupling is invisible (β = 1 + 0)


def test_a_start_that_tells_nothing_leaves_the_mean_path():
    """Deviations independent of their start value: cross-validation shrinks the map to (nearly) zero.

    With 30 demonstrations the held-out errors of λ ≥ 1 and λ = ∞ differ only by sampling noise, so
    over several seeds the choice is a strong ridge (or ∞) and weak ridges lose clearly."""
    from rbgp_cli.dynamics.variation import start_map

    chosen = []
    for seed in range(6):
        rng = np.random.default_rng(seed)
        delta = rng.normal(size=(30, 21, 6)) * np.linspace(0.2, 1.0, 21)[None, :, None]
        out = start_map(delta)
        errors = np.asarray(out["errors"])
        assert out["ridge"] >= 1.0
        assert errors[-1] <= 1.005 * errors.min()  # no conditioning is as good as the best
        assert errors[0] >= 1.1 * errors[-1]  # and a weak ridge fits the noise
        chosen.append(out["ridge"])
    assert chosen.count(float("inf")) >= 3
    out = start_map(np.random.default_rng(0).normal(size=(30, 21, 6)) * np.linspace(0.2, 1.0, 21)[None, :, None])
    assert out["ridge"] == float("inf") and np.all(out["map"] == 0.0)


def test_predict_given_the_start_uses_the_path_from_that_start_as_a_rollout_does(demos):
    """MotionModel.predict(..., start=) : the prior of a start-conditioned model is the path from the
    given start (the one the GP's residual was trained against, and the one a rollout follows);
    without it, the mean path. The velocities differ where the start is not typical."""
    train, unseen = demos
    model = train_model(train, start_conditioning=True, **FAST)
    d = unseen[0]
    tau = (d.t - d.t[0]) / d.duration
    X = np.concatenate([model.representation.state_from_pose(d.quat, d.position), tau[:, None]], axis=1)
    dev = model.start_deviation(d.quat[:1], d.position[:1])
    assert np.abs(dev).max() > 1e-3  # this start is not the mean start
    want = model.predict_output(X, start_dev=np.broadcast_to(dev, (len(X), 6)))
    got = model.predict(d.quat, d.position, return_std=False, tau=tau, start=(d.quat[0], d.position[0]))
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)
    typical = model.predict(d.quat, d.position, return_std=False, tau=tau)
    np.testing.assert_allclose(typical, model.predict_output(X), rtol=1e-12, atol=1e-12)
    assert np.abs(got - typical).max() > 1e-3
    plain = train_model(train, start_conditioning=False, **FAST)  # no conditioning: the start changes nothing
    np.testing.assert_array_equal(plain.predict(d.quat, d.position, return_std=False, tau=tau, start=(d.quat[0], d.position[0])),
                                  plain.predict(d.quat, d.position, return_std=False, tau=tau))
