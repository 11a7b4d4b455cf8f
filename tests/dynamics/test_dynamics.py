"""Velocities, integration, representations and rollouts."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rbgp_cli.dynamics.model import train_model, training_set
from rbgp_cli.dynamics.representations import make_representation
from rbgp_cli.dynamics.rollout import rollout, rollout_one_at_a_time, starts_near
from rbgp_cli.dynamics.trajectory import Trajectory
from rbgp_cli.dynamics.velocities import forward_differences
from rbgp_cli.errors import InputError


def crossing_pi_trajectory(n=200, seed=0):
    """A rotation whose angle passes θ = π (canonical rotation vector flips), non-uniform times."""
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.004, 0.007, n))
    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    ang = np.linspace(math.pi - 0.6, math.pi + 0.6, n)
    wobble = Rotation.from_rotvec(0.05 * np.sin(np.linspace(0, 6, n))[:, None] * np.array([1.0, 0, 0]))
    rot = wobble * Rotation.from_rotvec(ang[:, None] * axis)
    q = rot.as_quat()
    q *= np.where(q[:, 3:] < 0, -1.0, 1.0)  # canonical w >= 0: the stored sign flips at θ = π too
    p = np.stack([np.sin(t), np.cos(2 * t), 0.1 * t], 1)
    return Trajectory(t, q, p, name="pi")


def test_trajectory_crosses_pi_in_canonical_form():
    r = crossing_pi_trajectory().poses[:, :3]
    assert np.max(np.linalg.norm(np.diff(r, axis=0), axis=1)) > 3.0  # the flip is there


@pytest.mark.parametrize("representation", ["axis-angle", "euler", "quaternion"])
def test_integrating_exact_differences_reproduces_the_demonstration(representation):
    """docs/method.md §4: integrating a demonstration's own forward differences reproduces it to 1e-9,
    also across θ = π (and across the Euler angles' ±180° for the baseline)."""
    tr = crossing_pi_trajectory()
    rep = make_representation(representation)
    rep.prepare([tr])
    X, Y, dt = rep.training_pairs(tr)
    state = rep.state_from_pose(tr.quat[:1], tr.position[:1])
    qs, ps = [], []
    for k in range(len(dt)):
        state = rep.step(state, Y[k : k + 1], dt[k])
        q, p = rep.pose_from_state(state)
        qs.append(q[0])
        ps.append(p[0])
    qs, ps = np.array(qs), np.array(ps)
    dots = np.abs(np.sum(qs * tr.quat[1:], axis=1))
    assert np.max(1 - dots) < 1e-12  # |<q, q_true>| = 1: same rotation (up to sign)
    np.testing.assert_allclose(ps, tr.position[1:], atol=1e-9)


def test_forward_differences_match_scipy_relative_rotation():
    tr = crossing_pi_trajectory()
    xi, dt = forward_differences(tr)
    rel = Rotation.from_quat(tr.quat[1:]) * Rotation.from_quat(tr.quat[:-1]).inv()
    np.testing.assert_allclose(xi[:, :3] * dt[:, None], rel.as_rotvec(), atol=1e-12)


def test_too_coarse_rotation_step_is_rejected():
    q = Rotation.from_rotvec([[0, 0, 0], [0, 0, math.pi]]).as_quat()
    tr = Trajectory([0.0, 0.1], q, np.zeros((2, 3)), source="coarse.csv")
    with pytest.raises(InputError, match="too coarse"):
        forward_differences(tr)


def test_euler_inputs_are_unwrapped_and_quaternions_on_one_hemisphere():
    tr = crossing_pi_trajectory()
    eul = make_representation("euler")
    X, Y, _ = eul.training_pairs(tr)
    assert np.max(np.abs(np.diff(X[:, :3], axis=0))) < 0.5  # no ±2π jumps
    qrep = make_representation("quaternion")
    qrep.prepare([tr])
    X, Y, _ = qrep.training_pairs(tr)
    assert np.all(np.sum(X[1:, :4] * X[:-1, :4], axis=1) > 0)  # sign-continuous
    assert float(X[0, :4] @ qrep.reference) > 0


def smooth_demos(k=4, n=120, seed=0):
    rng = np.random.default_rng(seed)
    out = []
    for i in range(k):
        t = np.arange(n) / 60.0
        s = t / t[-1]
        r = (0.4 + 1.8 * s + 0.05 * rng.normal())[:, None] * np.array([0.2, 0.3, 0.93])
        p = np.stack([0.5 * s + 0.02 * rng.normal(), 0.2 * np.sin(np.pi * s), 0.8 - 0.3 * s], 1)
        out.append(Trajectory(t, Rotation.from_rotvec(r).as_quat(), p, name=f"d{i}"))
    return out


@pytest.fixture(scope="module")
def small_model():
    return train_model(smooth_demos(), subsample=None, max_points=120, restarts=1, seed=0, shared=True)


def test_training_set_subsamples_deterministically():
    demos = smooth_demos()
    rep = make_representation("axis-angle")
    X1, Y1, i1 = training_set(demos, rep, subsample=0.1, seed=3)
    X2, Y2, i2 = training_set(demos, rep, subsample=0.1, seed=3)
    assert i1["pairs"] == 4 * 119 and i1["points"] == round(0.1 * 4 * 119)
    np.testing.assert_array_equal(X1, X2)
    assert not np.array_equal(training_set(demos, rep, subsample=0.1, seed=4)[2]["indices"], i1["indices"])


def test_batched_rollout_equals_one_at_a_time(small_model):
    q0, p0 = starts_near(small_model.starts, 5, 0.02, seed=1)
    a = rollout(small_model, q0, p0, 60, with_std=False)
    b = rollout_one_at_a_time(small_model, q0, p0, 60)
    np.testing.assert_allclose(a.position, b.position, atol=1e-9)  # BLAS gemv vs gemm round-off
    np.testing.assert_allclose(np.abs(np.sum(a.quat * b.quat, -1)), 1.0, atol=1e-12)


def test_rollout_shapes_std_and_seeded_samples(small_model):
    q0, p0 = starts_near(small_model.starts, 3, 0.02, seed=2)
    r1 = rollout(small_model, q0, p0, 40, samples=4, seed=9)
    r2 = rollout(small_model, q0, p0, 40, samples=4, seed=9)
    assert r1.quat.shape == (3, 41, 4) and r1.position.shape == (3, 41, 3) and r1.std.shape == (3, 41, 6)
    assert r1.sample_quat.shape == (3, 4, 41, 4)
    np.testing.assert_array_equal(r1.sample_position, r2.sample_position)
    assert np.all(r1.std >= 0)
    # the samples start from the same pose; these demonstrations differ by their start alone (their
    # start-regression residuals are round-off), so a typical motion from a start is its mean rollout
    np.testing.assert_allclose(r1.sample_position[:, :, 0], np.repeat(r1.position[:, None, 0], 4, axis=1))
    np.testing.assert_allclose(r1.sample_position, np.repeat(r1.position[:, None], 4, axis=1), atol=1e-9)
    assert len(r1.trajectories(include_samples=True)) == 3 + 12
    # per-step Monte Carlo samples spread around it
    r3 = rollout(small_model, q0, p0, 40, samples=4, seed=9, sampling="step")
    assert np.std(r3.sample_position[:, :, -1], axis=1).max() > 1e-6


def test_rollout_follows_the_demonstrations(small_model):
    """Started at a demonstration's start, the mean rollout ends near where the demonstrations end."""
    demos = smooth_demos()
    res = rollout(small_model, small_model.starts[:1, :4], small_model.starts[:1, 4:], 119, dt=1 / 60.0, with_std=False)
    end = np.mean([d.position[-1] for d in demos], axis=0)
    assert np.linalg.norm(res.position[0, -1] - end) < 0.1


def test_starts_near_is_seeded_and_spread():
    base = np.array([[0, 0, 0, 1, 0.1, 0.2, 0.3], [0, 0, 0.38268343, 0.92387953, -0.1, 0.0, 0.5]])
    q, p = starts_near(base, 50, 0.02, seed=0)
    q2, p2 = starts_near(base, 50, 0.02, seed=0)
    np.testing.assert_array_equal(p, p2)
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1, atol=1e-12)
    assert 0.01 < np.std(p[:, 0] - np.where(p[:, 0] > 0, 0.1, -0.1)) < 0.04
    with pytest.raises(InputError):
        starts_near(base, 0, 0.02)


def _start_coordinates(q, p, q_ref, p_ref):
    """(log(R R_refᵀ), p − p_ref) by scipy's Rotation, an oracle independent of rbgp's so3."""
    rot = (Rotation.from_quat(q) * Rotation.from_quat(q_ref).inv()).as_rotvec()
    return np.concatenate([rot, p - p_ref], axis=1)


def test_default_starts_keep_the_demonstrations_mean_and_covariance():
    """spread None: the drawn starts have the starts' own mean and covariance (a smoothed bootstrap), and vary
    only where the starts do (here z is the same for all: no drawn start moves in z)."""
    rng = np.random.default_rng(3)
    n = 8
    rot = Rotation.from_rotvec(rng.normal(0, 0.05, (n, 3)) + [0.3, -0.2, 1.0])
    pos = np.column_stack([rng.normal(0.4, 0.004, n), rng.normal(-0.1, 0.010, n), np.full(n, 0.9)])
    base = np.column_stack([rot.as_quat(), pos])
    q, p, near = starts_near(base, 40000, None, seed=1, return_index=True, in_order=True)
    np.testing.assert_array_equal(near, np.arange(40000) % n)
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1, atol=1e-12)
    np.testing.assert_allclose(p[:, 2], 0.9, atol=1e-12)
    c0 = _start_coordinates(base[:, :4], base[:, 4:], base[0, :4], base[0, 4:])
    c = _start_coordinates(q, p, base[0, :4], base[0, 4:])
    sd0 = c0.std(axis=0, ddof=1)
    np.testing.assert_allclose(c.mean(axis=0), c0.mean(axis=0), atol=0.03 * sd0.max())
    keep = sd0 > 0
    np.testing.assert_allclose(np.cov(c[:, keep].T), np.cov(c0[:, keep].T), rtol=0.06, atol=0.06 * sd0.max() ** 2)
    # each drawn start stays nearer its own demonstration's start than the others', on average
    d_own = np.linalg.norm(c[:, 3:] - c0[near, 3:], axis=1).mean()
    d_other = np.linalg.norm(c[:, 3:] - c0[(near + 1) % n, 3:], axis=1).mean()
    assert d_own < d_other


def test_default_starts_from_one_start_use_the_fixed_spread_or_the_shape_of_other_starts():
    base = np.array([[0, 0, 0, 1, 0.1, 0.2, 0.3]])
    q, p = starts_near(base, 4000, None, seed=0)
    assert 0.018 < np.std(p[:, 0]) < 0.022
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1, atol=1e-12)
    # with other starts of the motion (a model's), moved about the one start with their covariance times h²
    rng = np.random.default_rng(4)
    shape = np.column_stack([Rotation.from_rotvec(rng.normal(0, 0.03, (30, 3))).as_quat(),
                             rng.normal(0, [0.002, 0.005, 0.0], (30, 3))])
    q, p = starts_near(base, 40000, None, seed=1, shape=shape)
    from rbgp_cli.dynamics.rollout import start_bandwidth

    h = start_bandwidth(30)
    np.testing.assert_allclose(p.mean(axis=0), base[0, 4:], atol=2e-4)
    np.testing.assert_allclose(np.cov((p - base[0, 4:]).T)[:2, :2], h * h * np.cov(shape[:, 4:6].T), rtol=0.06, atol=1e-9)
    np.testing.assert_allclose(p[:, 2], 0.3, atol=1e-12)  # no spread in z among the shape's starts: none drawn
