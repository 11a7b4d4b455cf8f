"""SE(3): composition (eq. 16, 17), inverse, action, exp/log and the integration step (docs/method.md §4, §8).
scipy's ``RigidTransform`` and ``scipy.linalg.expm`` are the independent oracles."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.linalg import expm
from scipy.spatial.transform import RigidTransform, Rotation

from rbgp_cli.geometry import se3, so3
from rbgp_cli.geometry.conventions import SMALL_ANGLE
from tests.helpers import (
    PI,
    assert_canonical,
    assert_poses_close,
    assert_rotvecs_close,
    axes,
    poses,
    raw_rotvecs,
    rotation_angle_between,
    stacked,
    translations,
)

FAST = settings(max_examples=60, deadline=None)
MORE = settings(max_examples=100, deadline=None)

IDENTITY = np.zeros(6)


def rigid(g) -> RigidTransform:
    g = np.asarray(g, dtype=float)
    return RigidTransform.from_components(g[..., 3:], Rotation.from_rotvec(g[..., :3]))


def pose_of(tf: RigidTransform) -> np.ndarray:
    return np.concatenate([tf.rotation.as_rotvec(), tf.translation], axis=-1)


def twists():
    """Twists (ω, v) with ‖ω‖ up to 3π, near 0 and near π; v up to ±5 m/s."""
    return st.builds(lambda w, v: np.concatenate([w, v]), raw_rotvecs(), translations())


# ---------------------------------------------------------------------------------------------
# Group operations
# ---------------------------------------------------------------------------------------------


@MORE
@given(poses(), poses())
@pytest.mark.slow
def test_compose_pose_matches_scipy(g2, g1):
    got = se3.compose_pose(g2, g1)
    assert_canonical(got[:3])
    assert_poses_close(got, pose_of(rigid(g2) * rigid(g1)), atol=1e-14, atol_t=1e-13)


@MORE
@given(poses(), st.tuples(*[st.floats(-5, 5)] * 3))
def test_apply_pose_and_inverse_match_scipy(g, p):
    p = np.array(p)
    np.testing.assert_allclose(se3.apply_pose(g, p), rigid(g).apply(p), atol=5e-14)
    inv = se3.inverse_pose(g)
    assert_canonical(inv[:3])
    assert_poses_close(inv, pose_of(rigid(g).inv()), atol=1e-14, atol_t=1e-13)
    np.testing.assert_allclose(se3.apply_pose(inv, se3.apply_pose(g, p)), p, atol=5e-14)


@MORE
@given(poses())
def test_se3_identity_and_inverse(g):
    c = np.concatenate([so3.canonical_rotvec(g[:3]), g[3:]])
    np.testing.assert_allclose(se3.compose_pose(g, IDENTITY), c, atol=2e-15)
    np.testing.assert_allclose(se3.compose_pose(IDENTITY, g), c, atol=2e-15)
    inv = se3.inverse_pose(g)
    assert_poses_close(se3.compose_pose(g, inv), IDENTITY, atol=1e-15 * 4, atol_t=1e-13)
    assert_poses_close(se3.compose_pose(inv, g), IDENTITY, atol=1e-15 * 4, atol_t=1e-13)
    assert_poses_close(se3.inverse_pose(inv), g, atol=1e-15 * 4, atol_t=1e-13)


@MORE
@given(poses(), poses(), poses())
def test_se3_composition_is_associative(a, b, c):
    left = se3.compose_pose(se3.compose_pose(a, b), c)
    right = se3.compose_pose(a, se3.compose_pose(b, c))
    # translations are sums of three rotated vectors: rounding grows with their size, and a composed rotation at
    # θ ≈ π goes through log and exp, whose round trip there loses digits (2.0e-13 for a unit translation after a
    # half turn composed with a 1e-8 rad turn; 1.1e-13 seen before)
    scale = 1.0 + max(np.abs(g[3:]).max() for g in (a, b, c))
    assert_poses_close(left, right, atol=1e-14, atol_t=5e-13 * scale)


# ---------------------------------------------------------------------------------------------
# exp / log
# ---------------------------------------------------------------------------------------------


def twist_matrix(xi):
    m = np.zeros((4, 4))
    m[:3, :3] = so3.skew(xi[:3])
    m[:3, 3] = xi[3:]
    return m


@MORE
@given(twists())
def test_exp_se3_matches_scipy_and_expm(xi):
    g = se3.exp_se3(xi)
    assert_canonical(g[:3])
    ref = RigidTransform.from_exp_coords(xi)
    scale = max(1.0, float(np.linalg.norm(xi[:3])))
    assert_poses_close(g, pose_of(ref), atol=1e-14 * scale, atol_t=1e-13 * scale)
    T = expm(twist_matrix(xi))  # the definition: the 4×4 matrix exponential
    np.testing.assert_allclose(so3.matrix_from_rotvec(g[:3]), T[:3, :3], atol=1e-13 * scale)
    np.testing.assert_allclose(g[3:], T[:3, 3], atol=1e-13 * scale)


@MORE
@given(poses())
def test_log_se3_matches_scipy_and_inverts_exp(g):
    xi = se3.log_se3(g)
    assert_canonical(xi[:3])
    assert_poses_close(se3.exp_se3(xi), g, atol=1e-14, atol_t=1e-13)
    if np.linalg.norm(g[:3]) < PI - 1e-6:  # at π the logarithm is not unique
        np.testing.assert_allclose(xi, rigid(g).as_exp_coords(), atol=1e-13)


@MORE
@given(twists())
def test_log_of_exp_is_the_canonical_twist(xi):
    theta = float(np.linalg.norm(xi[:3]))
    back = se3.log_se3(se3.exp_se3(xi))
    if theta < PI - 1e-6:
        np.testing.assert_allclose(back, xi, atol=1e-12)
    else:  # a different twist with the same exponential
        assert_poses_close(se3.exp_se3(back), se3.exp_se3(xi), atol=1e-13 * theta, atol_t=1e-12 * theta)


def test_exp_log_se3_are_smooth_through_the_series_threshold():
    u = np.array([2.0, -3.0, 6.0]) / 7.0
    v = np.array([0.3, 4.0, -1.2])
    thetas = np.concatenate([np.geomspace(1e-12, 1.0, 60), SMALL_ANGLE * (1 + np.array([-1e-9, 0, 1e-9]))])
    xi = np.concatenate([thetas[:, None] * u, np.broadcast_to(v, (len(thetas), 3))], axis=-1)
    g = se3.exp_se3(xi)
    ref = np.array([expm(twist_matrix(x))[:3, 3] for x in xi])
    np.testing.assert_allclose(g[:, 3:], ref, rtol=0, atol=2e-15 * 8)
    np.testing.assert_allclose(se3.log_se3(g), xi, rtol=0, atol=2e-15 * 8)
    assert np.all(np.isfinite(se3.log_se3(np.array([PI, 0, 0, 1.0, 2.0, 3.0]))))


# ---------------------------------------------------------------------------------------------
# Integration (docs/method.md §4, §8)
# ---------------------------------------------------------------------------------------------


def _demo_crossing_pi(n=400, seed=0):
    """Sample times (nonuniform), rotation matrices (via scipy) and positions of a smooth motion whose
    rotation angle passes through π (and beyond, so its canonical vector flips)."""
    rng = np.random.default_rng(seed)
    t = np.concatenate([[0.0], np.cumsum(rng.uniform(0.004, 0.02, n - 1))])
    s = t / t[-1]
    theta = 2.6 + 1.2 * s + 0.05 * np.sin(9 * s)  # 2.6 -> 3.8 rad
    axis = np.stack([0.3 * np.cos(2 * s), 0.3 * np.sin(3 * s), 1.0 - 0.2 * s], axis=-1)
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    R = Rotation.from_rotvec(theta[:, None] * axis).as_matrix()
    p = np.stack([np.sin(3 * s), 2 * s**2, 0.5 - s], axis=-1) * 1.5
    return t, R, p


def _forward_differences(t, R, p):
    """ω_k = log(R_{k+1} R_kᵀ)/Δt_k, v_k = (p_{k+1} − p_k)/Δt_k, built inline (docs/method.md §4)."""
    dt = np.diff(t)
    rel = R[1:] @ np.swapaxes(R[:-1], -1, -2)
    w = so3.log_so3(rel) / dt[:, None]
    v = np.diff(p, axis=0) / dt[:, None]
    return dt, np.concatenate([w, v], axis=-1)


def test_integrating_exact_forward_differences_reproduces_the_trajectory_across_pi():
    t, R, p = _demo_crossing_pi()
    g = np.concatenate([so3.log_so3(R), p], axis=-1)
    theta = np.linalg.norm(g[:, :3], axis=-1)
    # the demonstration really crosses θ = π: its canonical vectors jump to the other side
    assert theta.max() > PI - 0.01 and np.any(np.sum(g[1:, :3] * g[:-1, :3], axis=-1) < 0)
    dt, xi = _forward_differences(t, R, p)

    # one step from every sample (vectorised) ...
    one_step = se3.integrate_pose(g[:-1], xi, dt)
    assert_poses_close(one_step, g[1:], atol=1e-12, atol_t=1e-12)
    assert_canonical(one_step[:, :3])
    # ... and a whole rollout from the first sample
    rolled = [g[0]]
    for k in range(len(dt)):
        rolled.append(se3.integrate_pose(rolled[-1], xi[k], dt[k]))
    rolled = np.array(rolled)
    assert_poses_close(rolled, g, atol=1e-12, atol_t=1e-12)
    np.testing.assert_allclose(so3.matrix_from_rotvec(rolled[:, :3]), R, atol=1e-12)

    # the same with quaternions: sign-continuous without repair
    q = [Rotation.from_matrix(R[0]).as_quat()]
    pos = [p[0]]
    for k in range(len(dt)):
        qn, pn = se3.integrate_quat(q[-1], pos[-1], xi[k], dt[k])
        q.append(qn)
        pos.append(pn)
    q, pos = np.array(q), np.array(pos)
    assert np.all(np.sum(q[1:] * q[:-1], axis=-1) > 0)
    np.testing.assert_allclose(so3.matrix_from_quat(q), R, atol=1e-12)
    np.testing.assert_allclose(pos, p, atol=1e-12)


@FAST
@given(poses(), twists(), st.floats(1e-4, 0.5))
def test_integrate_pose_is_exp_omega_dt_times_R(g, xi, dt):
    got = se3.integrate_pose(g, xi, dt)
    R_ref = Rotation.from_rotvec(xi[:3] * dt) * Rotation.from_rotvec(g[:3])
    assert_rotvecs_close(got[:3], R_ref.as_rotvec(), atol=1e-14 * max(1, np.linalg.norm(xi[:3]) * dt))
    np.testing.assert_allclose(got[3:], g[3:] + xi[3:] * dt, atol=1e-15 * 8)
    qn, pn = se3.integrate_quat(so3.quat_from_rotvec(g[:3]), g[3:], xi, dt)
    assert_rotvecs_close(so3.rotvec_from_quat(qn), got[:3], atol=1e-14 * max(1, np.linalg.norm(xi[:3]) * dt))
    np.testing.assert_array_equal(pn, got[3:])


def test_integrate_dt_broadcasts():
    rng = np.random.default_rng(4)
    g = np.concatenate([Rotation.random(5, rng=rng).as_rotvec(), rng.normal(size=(5, 3))], axis=-1)
    xi = rng.normal(size=(5, 6))
    dt = rng.uniform(0.01, 0.1, 5)
    each = np.array([se3.integrate_pose(g[k], xi[k], dt[k]) for k in range(5)])
    np.testing.assert_array_equal(se3.integrate_pose(g, xi, dt), each)
    np.testing.assert_array_equal(se3.integrate_pose(g, xi, 0.05), se3.integrate_pose(g, xi, np.full(5, 0.05)))
    # one start pose, many step lengths
    many = se3.integrate_pose(g[0], xi[0], dt)
    assert many.shape == (5, 6)
    np.testing.assert_array_equal(many[3], se3.integrate_pose(g[0], xi[0], dt[3]))
    q, p = se3.integrate_quat(so3.quat_from_rotvec(g[:, :3]), g[:, 3:], xi, dt[:, None][:, 0])
    assert q.shape == (5, 4) and p.shape == (5, 3)


def test_integrate_quat_keeps_the_sign_of_its_input():
    q = np.array([0.0, 0.0, math.sin(1.5), -math.cos(1.5)])  # w < 0
    xi = np.array([0.0, 0.0, 1.0, 0, 0, 0])
    qn, _ = se3.integrate_quat(q, np.zeros(3), xi, 0.01)
    assert qn[3] < 0 and np.dot(qn, q) > 0


# ---------------------------------------------------------------------------------------------
# Vectorisation and errors
# ---------------------------------------------------------------------------------------------


@settings(max_examples=30, deadline=None)
@given(stacked(poses(), (2, 3)), stacked(poses(), (2, 3)))
@pytest.mark.slow
def test_se3_functions_vectorise_over_leading_axes(a, b):
    pts = b[..., 3:]
    cases = [
        (se3.compose_pose(a, b), lambda i, j: se3.compose_pose(a[i, j], b[i, j])),
        (se3.inverse_pose(a), lambda i, j: se3.inverse_pose(a[i, j])),
        (se3.apply_pose(a, pts), lambda i, j: se3.apply_pose(a[i, j], pts[i, j])),
        (se3.exp_se3(a), lambda i, j: se3.exp_se3(a[i, j])),
        (se3.log_se3(a), lambda i, j: se3.log_se3(a[i, j])),
        (se3.integrate_pose(a, b, 0.01), lambda i, j: se3.integrate_pose(a[i, j], b[i, j], 0.01)),
    ]
    for got, one in cases:
        assert got.shape[:2] == (2, 3)
        for i in range(2):
            for j in range(3):
                np.testing.assert_array_equal(got[i, j], one(i, j))


def test_se3_shape_errors():
    with pytest.raises(ValueError, match=r"expected shape \(\.\.\., 6\)"):
        se3.compose_pose(np.zeros(6), np.zeros(7))
    with pytest.raises(ValueError, match=r"expected shape \(\.\.\., 3\)"):
        se3.apply_pose(np.zeros(6), np.zeros(6))


@FAST
@given(axes(), translations())
def test_half_turn_pose_inverse_is_consistent(u, t):
    g = np.concatenate([PI * u, t])
    inv = se3.inverse_pose(g)
    # a half turn is its own inverse rotation, and keeps the eq. 7 vector
    np.testing.assert_allclose(inv[:3], so3.canonical_rotvec(PI * u), atol=1e-15)
    assert rotation_angle_between(inv[:3], g[:3]) < 1e-15 * 4
    assert_poses_close(se3.compose_pose(inv, g), IDENTITY, atol=1e-15 * 4, atol_t=1e-13)
