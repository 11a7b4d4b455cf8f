"""Resampling on normalised time, chordal mean rotation and tangent features (docs/method.md §9)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation, Slerp

from rbgp_cli.dynamics.trajectory import Trajectory
from rbgp_cli.errors import InputError
from rbgp_cli.evaluation import mean_rotation, resample, resample_all, tangent_features
from rbgp_cli.geometry.so3 import exp_quat, quat_canonical, quat_multiply, quat_normalize, random_quat

SETTINGS = settings(max_examples=40, deadline=None)


def quat_dist(a, b) -> np.ndarray:
    """Sign-aware distance between quaternions: min(‖a − b‖, ‖a + b‖), shape (...)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    return np.minimum(np.linalg.norm(a - b, axis=-1), np.linalg.norm(a + b, axis=-1))


def random_trajectory(rng, n, *, uniform=False, name="demo", flip_signs=True) -> Trajectory:
    """A smooth random trajectory with n samples; quaternions with random signs (as a raw reader may give)."""
    if uniform:
        t = 2.0 + 0.01 * np.arange(n)
    else:
        t = 2.0 + np.cumsum(rng.uniform(0.005, 0.02, n))
    s = (t - t[0]) / (t[-1] - t[0])
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    rotvec = np.outer(s, axis) * rng.uniform(0.5, 3.0) + 0.2 * np.sin(3 * s)[:, None] * rng.normal(size=3)
    q = quat_multiply(exp_quat(rotvec), random_quat(rng))
    if flip_signs:
        q = q * rng.choice([-1.0, 1.0], size=(n, 1))
    p = np.stack([np.sin(s), s**2, 0.3 * s], axis=-1) + rng.normal(size=3)
    return Trajectory(t=t, quat=q, position=p, name=name, source="synthetic.csv")


def test_identity_when_T_equals_N_on_uniform_times():
    rng = np.random.default_rng(0)
    traj = random_trajectory(rng, 57, uniform=True)
    q, p = resample(traj, len(traj))
    assert q.shape == (57, 4) and p.shape == (57, 3)
    assert np.max(quat_dist(q, traj.quat)) < 1e-12
    np.testing.assert_allclose(p, traj.position, rtol=0, atol=1e-12)


def test_endpoints_are_exact():
    rng = np.random.default_rng(1)
    traj = random_trajectory(rng, 33)
    q, p = resample(traj, 100)
    qn = quat_normalize(traj.quat)
    assert quat_dist(q[0], qn[0]) == 0.0
    assert quat_dist(q[-1], qn[-1]) == 0.0
    assert np.array_equal(p[0], traj.position[0]) and np.array_equal(p[-1], traj.position[-1])


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(2, 40), T=st.integers(2, 120))
def test_rotation_follows_slerp_geodesic_scipy_oracle(seed, n, T):
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.01, 1.0, n))
    q_in = random_quat(rng, n) * rng.choice([-1.0, 1.0], size=(n, 1))  # large steps, random signs
    p_in = rng.normal(size=(n, 3))
    traj = Trajectory(t=t, quat=q_in, position=p_in)
    q, p = resample(traj, T)
    times = t[0] + np.linspace(0.0, 1.0, T) * (t[-1] - t[0])
    times = np.clip(times, t[0], t[-1])
    expected = Slerp(t, Rotation.from_quat(q_in))(times).as_quat()
    assert np.max(quat_dist(q, expected)) < 1e-9
    expected_p = np.stack([np.interp(times, t, p_in[:, i]) for i in range(3)], axis=-1)
    np.testing.assert_allclose(p, expected_p, rtol=0, atol=1e-9)
    # unit and sign-continuous output
    np.testing.assert_allclose(np.linalg.norm(q, axis=-1), 1.0, atol=1e-12)
    assert np.all(np.sum(q[1:] * q[:-1], axis=-1) >= 0)


def test_crossing_theta_pi_has_no_jumps():
    # rotation about z from 0.8π to 1.2π; canonicalised quaternions (w >= 0) flip sign at π
    n, T = 50, 301
    t = np.linspace(0.0, 2.0, n)
    angle = np.linspace(0.8 * np.pi, 1.2 * np.pi, n)
    axis = np.array([0.3, -0.2, 1.0]) / np.linalg.norm([0.3, -0.2, 1.0])
    q_in = quat_canonical(exp_quat(angle[:, None] * axis))
    assert np.any(np.sum(q_in[1:] * q_in[:-1], axis=-1) < 0)  # the input really jumps in sign
    traj = Trajectory(t=t, quat=q_in, position=np.zeros((n, 3)))
    q, _ = resample(traj, T)
    step = 0.4 * np.pi / (T - 1)
    # consecutive unit quaternions Δθ apart: ‖Δq‖ = 2 sin(Δθ/4) <= Δθ/2 (a sign jump would give ≈ 2)
    assert np.all(np.linalg.norm(q[1:] - q[:-1], axis=-1) <= 0.5 * step + 1e-12)
    expected = exp_quat(np.linspace(0.8 * np.pi, 1.2 * np.pi, T)[:, None] * axis)
    assert np.max(quat_dist(q, expected)) < 1e-12


def test_resample_all_stacks():
    rng = np.random.default_rng(3)
    trajs = [random_trajectory(rng, n) for n in (10, 25, 7)]
    q, p = resample_all(trajs, 20)
    assert q.shape == (3, 20, 4) and p.shape == (3, 20, 3)
    q1, p1 = resample(trajs[1], 20)
    assert np.array_equal(q[1], q1) and np.array_equal(p[1], p1)


@pytest.mark.parametrize(
    "traj, match",
    [
        (Trajectory(t=[0.0], quat=[[0, 0, 0, 1.0]], position=[[0, 0, 0.0]], name="one", source="a.csv"),
         r"a\.csv: trajectory 'one' has 1 sample"),
        (Trajectory(t=[0.0, 0.0], quat=[[0, 0, 0, 1.0]] * 2, position=np.zeros((2, 3)), name="dup"),
         "not strictly increasing"),
        (Trajectory(t=[0.0, 1.0], quat=[[0, 0, 0, 1.0], [np.nan] * 4], position=np.zeros((2, 3))),
         "non-finite"),
    ],
)
def test_bad_trajectories_raise_input_error(traj, match):
    with pytest.raises(InputError, match=match):
        resample(traj, 10)


@pytest.mark.parametrize("T", [1, 0, -3, 2.5])
def test_bad_length_raises(T):
    traj = Trajectory(t=[0.0, 1.0], quat=[[0, 0, 0, 1.0]] * 2, position=np.zeros((2, 3)))
    with pytest.raises(InputError):
        resample(traj, T)


# ---------------------------------------------------------------------------------------------
# mean_rotation
# ---------------------------------------------------------------------------------------------


def test_mean_of_identical_rotations_is_that_rotation():
    rng = np.random.default_rng(4)
    q = random_quat(rng, 30)  # (T,)
    stacked = np.broadcast_to(q, (5, 30, 4)) * np.array([1, -1, 1, -1, 1.0])[:, None, None]
    mean = mean_rotation(stacked)
    assert mean.shape == (30, 4)
    assert np.max(quat_dist(mean, q)) < 1e-12


def test_mean_is_invariant_to_sign_flips():
    rng = np.random.default_rng(5)
    center = random_quat(rng, 40)
    q = quat_multiply(center, exp_quat(0.3 * rng.normal(size=(7, 40, 3))))
    flipped = q * rng.choice([-1.0, 1.0], size=(7, 40, 1))
    assert np.array_equal(mean_rotation(q), mean_rotation(flipped))


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1))
def test_two_rotations_symmetric_about_center_give_center(seed):
    rng = np.random.default_rng(seed)
    T = 12
    center = random_quat(rng, T)
    delta = rng.normal(size=(T, 3))
    # ‖δ‖ < π/2: the two rotations are less than π apart, so R̄ (and not R̄·exp(π u), the other
    # midpoint of their geodesic circle) is the nearer midpoint
    delta *= rng.uniform(0.0, 1.5, size=(T, 1)) / np.linalg.norm(delta, axis=-1, keepdims=True)
    q = np.stack([quat_multiply(center, exp_quat(delta)), quat_multiply(center, exp_quat(-delta))])
    assert np.max(quat_dist(mean_rotation(q), center)) < 1e-9


def test_mean_sign_is_continuous_and_starts_with_nonnegative_w():
    rng = np.random.default_rng(6)
    # a path through θ = π, so per-step eigenvectors come with arbitrary signs
    angle = np.linspace(0.5 * np.pi, 1.5 * np.pi, 80)
    base = exp_quat(angle[:, None] * np.array([0.0, 0.0, 1.0]))
    q = quat_multiply(base, exp_quat(0.05 * rng.normal(size=(6, 80, 3))))
    q = quat_canonical(q) * rng.choice([-1.0, 1.0], size=(6, 80, 1))
    mean = mean_rotation(q)
    assert mean[0, 3] >= 0
    assert np.all(np.sum(mean[1:] * mean[:-1], axis=-1) > 0)
    np.testing.assert_allclose(np.linalg.norm(mean, axis=-1), 1.0, atol=1e-12)


def test_mean_is_equivariant_under_world_rotation():
    rng = np.random.default_rng(7)
    q = quat_multiply(random_quat(rng, 10), exp_quat(0.4 * rng.normal(size=(5, 10, 3))))
    q_w = random_quat(rng)
    rotated_mean = mean_rotation(quat_multiply(q_w, q))
    assert np.max(quat_dist(rotated_mean, quat_multiply(q_w, mean_rotation(q)))) < 1e-12


# ---------------------------------------------------------------------------------------------
# tangent_features
# ---------------------------------------------------------------------------------------------


def test_tangent_features_recover_the_body_frame_offset():
    rng = np.random.default_rng(8)
    M, T = 4, 15
    ref = random_quat(rng, T)
    x = rng.normal(size=(M, T, 3))
    x *= rng.uniform(0.0, 3.0, size=(M, T, 1)) / np.linalg.norm(x, axis=-1, keepdims=True)  # ‖x‖ < π
    q = quat_multiply(ref, exp_quat(x)) * rng.choice([-1.0, 1.0], size=(M, T, 1))
    p = rng.normal(size=(M, T, 3))
    feats = tangent_features(q, p, ref * -1.0)
    assert feats.shape == (M, T, 6)
    np.testing.assert_allclose(feats[..., :3], x, atol=1e-10)
    assert np.array_equal(feats[..., 3:], p)
    # oracle: scipy's rotation vector of R̄ᵀR
    oracle = (Rotation.from_quat(np.broadcast_to(ref, (M, T, 4)).reshape(-1, 4)).inv()
              * Rotation.from_quat(q.reshape(-1, 4))).as_rotvec().reshape(M, T, 3)
    np.testing.assert_allclose(feats[..., :3], oracle, atol=1e-10)


def test_tangent_features_shape_errors():
    with pytest.raises(ValueError, match="ref must have shape"):
        tangent_features(np.zeros((2, 5, 4)) + [0, 0, 0, 1], np.zeros((2, 5, 3)), np.zeros((4, 4)))
