"""The demonstrations' deviation process (docs/method.md §11 (a)) against a synthetic hierarchical process
whose deviation covariance is known, and sampled rollouts that are coherent new demonstrations."""

from __future__ import annotations

import numpy as np
import pytest

from rbgp_cli.dynamics.trajectory import Trajectory
from rbgp_cli.dynamics.variation import Variation, demonstration_variation
from rbgp_cli.geometry.so3 import exp_quat, quat_multiply
from tests.dynamics.synthetic import timed_demos

SIGMA_POS, SIGMA_ROT = 0.05, 0.08


def hierarchical_demos(n, seed, samples=60):
    """A shared motion plus, per demonstration, its own smooth deviation a_d·s (position, m, and
    rotation, rad, world frame) and a start offset b_d that stays: given the start, the deviation at
    phase s has the known standard deviation σ·s."""

    def pose(rng, s):
        a_pos, b_pos = rng.normal(0, SIGMA_POS, 3), rng.normal(0, 0.03, 3)
        a_rot, b_rot = rng.normal(0, SIGMA_ROT, 3), rng.normal(0, 0.05, 3)
        base_p = np.stack([0.4 * s, 0.2 * np.sin(np.pi * s), 1.0 - 0.3 * s**2], axis=1)
        p = base_p + np.outer(s, a_pos) + b_pos
        base_q = exp_quat(np.outer(s, [0.2, 1.0, 0.4]) + [0.0, 0.0, 2.8])  # through θ = π
        dev = np.outer(s, a_rot) + b_rot
        return quat_multiply(exp_quat(dev), base_q), p

    return timed_demos(n, seed, samples, pose)


def test_draws_reproduce_the_known_deviation_variance_given_the_start():
    v = demonstration_variation(hierarchical_demos(80, 1))
    assert v.dof == 78 and v.residuals.shape == (80, 51, 6)
    assert np.all(v.residuals[:, 0] == 0.0)
    eta = v.draw(4000, np.random.default_rng(2))
    sd = eta.std(axis=0)  # (S, 6)
    want = v.s[:, None] * np.array([SIGMA_ROT] * 3 + [SIGMA_POS] * 3)
    inner = slice(5, 51)  # away from the start, where the variance is ~0 and relative errors meaningless
    np.testing.assert_allclose(sd[inner], want[inner], rtol=0.15)
    assert np.all(sd[0] == 0.0)


@pytest.mark.slow
def test_fresh_demonstrations_fall_inside_the_draws_90_percent_band():
    """Coverage of fresh draws of the process by 20 samples' 90 % regions is 0.90 ± 0.03, averaged over
    training sets (one set of 40 demonstrations estimates the covariance to ±11 % in σ, so a single set's
    coverage varies by more than that): the samples are the conditional mean given the start (here the
    mean path moved by the start's deviation, β = 1) displaced by draws."""
    from rbgp_cli.dynamics.model import mean_path
    from rbgp_cli.evaluation.coverage import Coverage, prediction_coverage
    from rbgp_cli.geometry.so3 import log_quat, quat_conjugate

    rng = np.random.default_rng(5)
    total = Coverage()
    for rep in range(25):
        train = hierarchical_demos(40, 100 + rep)
        v = demonstration_variation(train)
        path = mean_path(train, 51)
        for real in hierarchical_demos(8, 1000 + rep):
            cond = path["position"] + (real.position[0] - path["position"][0])
            start_rot = log_quat(quat_multiply(real.quat[0], quat_conjugate(path["quat"][0])))
            mean_q = quat_multiply(exp_quat(np.broadcast_to(start_rot, (51, 3))), path["quat"])
            samples = [Trajectory(v.s * real.duration, quat_multiply(exp_quat(e[:, :3]), mean_q), cond + e[:, 3:])
                       for e in v.draw(20, rng)]
            total = total + prediction_coverage(samples, real, T=51)
    c = total.to_dict()
    assert abs(c["coverage_position"] - 0.90) < 0.03, c
    assert abs(c["coverage_rotation"] - 0.90) < 0.03, c


def test_too_few_demonstrations_give_no_variation_and_arrays_round_trip():
    assert demonstration_variation(hierarchical_demos(2, 0)) is None
    v = demonstration_variation(hierarchical_demos(5, 0))
    w = Variation.from_arrays(v.to_arrays())
    np.testing.assert_array_equal(w.residuals, v.residuals)
    assert w.dof == v.dof == 3


def test_sampled_rollouts_start_at_the_start_are_smooth_seeded_and_saved_with_the_model(tmp_path):
    from rbgp_cli.dynamics.model import train_model
    from rbgp_cli.dynamics.rollout import rollout, rollout_for
    from rbgp_cli.io.model_store import load_model, save_model

    demos = hierarchical_demos(12, 7)
    m = train_model(demos, max_points=200, restarts=1, shared=True, explore_size=100, jobs=1)
    assert m.variation is not None and m.summary["variation"] == {"demos": 12, "dof": 10}
    q0, p0 = np.array([d.quat[0] for d in demos[:3]]), np.array([d.position[0] for d in demos[:3]])
    a = rollout_for(m, q0, p0, [2.0, 1.5, 2.5], with_std=False, samples=8, seed=4)
    b = rollout_for(m, q0, p0, [2.0, 1.5, 2.5], with_std=False, samples=8, seed=4)
    np.testing.assert_array_equal(a.sample_position, b.sample_position)
    assert a.sample_position.shape == (3, 8, len(a.t), 3)
    np.testing.assert_allclose(a.sample_position[:, :, 0], np.repeat(p0[:, None], 8, axis=1), atol=1e-12)
    # coherent: a sample's step-to-step change is as smooth as the mean's, not a random walk
    jump = np.abs(np.diff(a.sample_position - a.position[:, None], axis=2)).max()
    spread = np.abs(a.sample_position - a.position[:, None]).max()
    assert spread > 0.01 and jump < 0.2 * spread
    # the per-step Monte Carlo rollouts stay one option away
    step = rollout(m, q0, p0, 10, with_std=False, samples=4, seed=4, sampling="step")
    assert step.sample_position.shape == (3, 4, 11, 3)
    path = tmp_path / "m.rbgp"
    save_model(m, path)
    m2, header = load_model(path)
    assert header["variation"] == {"demos": 12, "steps": 51}
    c = rollout_for(m2, q0, p0, [2.0, 1.5, 2.5], with_std=False, samples=8, seed=4)
    np.testing.assert_allclose(c.sample_position, a.sample_position, atol=1e-6)  # the posterior is refactorised on load
    with pytest.raises(Exception, match="unknown sampling"):
        rollout(m, q0, p0, 3, samples=2, sampling="brownian")
