"""SO(3): canonical rotation vectors (eq. 6, 7), conversions, composition (eq. 8), exp/log (eq. 11, 12),
slerp and Euler angles. scipy's ``Rotation`` is the independent oracle throughout."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation, Slerp

from rbgp_cli.geometry import so3
from rbgp_cli.geometry.conventions import SMALL_ANGLE
from tests.helpers import (
    PI,
    TIE_ATOL,
    assert_canonical,
    assert_quats_close,
    assert_rotvecs_close,
    axes,
    quat_angle_between,
    quats,
    raw_rotvecs,
    rotation_angle_between,
    rotvecs,
    stacked,
)

FAST = settings(max_examples=60, deadline=None)
MORE = settings(max_examples=150, deadline=None)

ALL_ORDERS = [
    "xyz", "xzy", "yxz", "yzx", "zxy", "zyx",  # Tait–Bryan
    "xyx", "xzx", "yxy", "yzy", "zxz", "zyz",  # proper Euler
]


def theta_of(r) -> float:
    return float(np.linalg.norm(r))


# ---------------------------------------------------------------------------------------------
# Canonical form (eq. 6, 7)
# ---------------------------------------------------------------------------------------------


@MORE
@given(raw_rotvecs())
@pytest.mark.slow
def test_canonical_rotvec_is_canonical_same_rotation_and_idempotent(r):
    c = so3.canonical_rotvec(r)
    assert_canonical(c)
    assert_rotvecs_close(c, r, atol=1e-12 * max(1.0, theta_of(r)))
    c2 = so3.canonical_rotvec(c)
    # the same vector again, not its θ = π twin
    np.testing.assert_allclose(c2, c, rtol=0, atol=1e-14)


@MORE
@given(rotvecs())
def test_canonical_rotvec_leaves_the_open_ball_untouched(r):
    if theta_of(r) < PI - 1e-12:
        np.testing.assert_array_equal(so3.canonical_rotvec(r), r)


@MORE
@given(axes())
def test_half_turn_twins_map_to_one_canonical_vector(u):
    # πu and −πu are the same rotation; eq. 7 keeps exactly one of them
    c_plus = so3.canonical_rotvec(PI * u)
    c_minus = so3.canonical_rotvec(-PI * u)
    np.testing.assert_array_equal(c_plus, c_minus)
    assert_canonical(c_plus)
    # and it is the one eq. 7 names (components below AXIS_TOLERANCE count as 0), by hand
    lead = next(c for c in (u[2], u[1], u[0]) if abs(c) > so3.AXIS_TOLERANCE)
    np.testing.assert_allclose(c_plus, PI * u * np.sign(lead), atol=1e-15)


@MORE
@given(axes(), st.floats(0.0, PI))
def test_full_turn_twin_maps_to_the_same_canonical_vector(u, t):
    # θu and (θ − 2π)u are the same rotation
    a = so3.canonical_rotvec(t * u)
    b = so3.canonical_rotvec((t - 2 * PI) * u)
    np.testing.assert_allclose(a, b, atol=1e-12)


def test_eq7_tie_break_cases_exactly():
    cases = {
        (0.0, 0.0, -1.0): (0.0, 0.0, 1.0),  # u_z < 0 -> flip
        (0.6, -0.8, 0.0): (-0.6, 0.8, 0.0),  # u_z = 0, u_y < 0 -> flip
        (-0.6, 0.8, 0.0): (-0.6, 0.8, 0.0),  # u_z = 0, u_y > 0 -> keep
        (-1.0, 0.0, 0.0): (1.0, 0.0, 0.0),  # u_z = u_y = 0, u_x < 0 -> flip
        (0.48, 0.6, -0.64): (-0.48, -0.6, 0.64),
    }
    for u, want in cases.items():
        got = so3.canonical_rotvec(PI * np.array(u))
        np.testing.assert_allclose(got, PI * np.array(want), atol=1e-15)
        # the same from a quaternion and a matrix (axes with exact zeros stay exact zeros)
        q = np.array([*u, 0.0])
        np.testing.assert_allclose(so3.rotvec_from_quat(q), PI * np.array(want), atol=1e-15)
        np.testing.assert_allclose(so3.rotvec_from_quat(-q), PI * np.array(want), atol=1e-15)
        R = Rotation.from_rotvec(PI * np.array(u)).as_matrix()
        np.testing.assert_allclose(so3.rotvec_from_matrix(R), PI * np.array(want), atol=1e-14)


def test_tie_break_tolerance_makes_near_zero_axis_components_count_as_zero():
    # a half turn about (1, -1, ±1e-15)/√2 is, to round-off, one about (1, -1, 0)/√2: both
    # round-off variants must land on the same vector (u_y > 0)
    for uz in (1e-15, -1e-15, 0.0):
        u = np.array([1.0, -1.0, uz]) / math.sqrt(2)
        got = so3.canonical_rotvec(PI * u)
        assert got[1] > 0, (uz, got)
    # just inside the π tolerance the tie-break applies, outside it does not
    u = np.array([0.0, 0.0, -1.0])
    assert so3.canonical_rotvec((PI - 1e-14) * u)[2] > 0
    assert so3.canonical_rotvec((PI - 1e-9) * u)[2] < 0


# ---------------------------------------------------------------------------------------------
# Conversions against scipy
# ---------------------------------------------------------------------------------------------


@MORE
@given(raw_rotvecs())
def test_quat_from_rotvec_matches_scipy(r):
    q = so3.quat_from_rotvec(r)
    assert q[3] >= 0
    assert abs(np.linalg.norm(q) - 1) < 1e-15
    assert_quats_close(q, Rotation.from_rotvec(r).as_quat(), atol=1e-15 * max(1.0, theta_of(r)) * 4)


@MORE
@given(quats())
def test_rotvec_from_quat_matches_scipy_and_is_canonical(q):
    r = so3.rotvec_from_quat(q)
    assert_canonical(r)
    ref = Rotation.from_quat(q).as_rotvec()
    if theta_of(ref) < PI - 1e-6:
        np.testing.assert_allclose(r, ref, rtol=1e-14, atol=1e-15)
    else:  # scipy does not apply eq. 7; compare rotations
        assert_rotvecs_close(r, ref, atol=1e-14)


@MORE
@given(quats(), st.floats(0.1, 10.0))
def test_rotvec_from_quat_is_invariant_to_sign_and_scale(q, scale):
    a = so3.rotvec_from_quat(q)
    np.testing.assert_array_equal(so3.rotvec_from_quat(-q), a)
    np.testing.assert_allclose(so3.rotvec_from_quat(scale * q), a, atol=1e-15 * 8)


@MORE
@given(raw_rotvecs())
def test_matrix_from_rotvec_matches_scipy(r):
    R = so3.matrix_from_rotvec(r)
    np.testing.assert_allclose(R, Rotation.from_rotvec(r).as_matrix(), atol=2e-15 * max(1, theta_of(r)))
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-15 * 4)
    assert abs(np.linalg.det(R) - 1) < 1e-14


@MORE
@given(rotvecs())
def test_rotvec_from_matrix_matches_scipy_and_is_robust_near_pi(r):
    R = Rotation.from_rotvec(r).as_matrix()
    got = so3.rotvec_from_matrix(R)
    assert_canonical(got)
    assert_rotvecs_close(got, r, atol=1e-14)
    np.testing.assert_allclose(got, so3.canonical_rotvec(r), atol=1e-14)
    if theta_of(r) < PI - 1e-6:
        np.testing.assert_allclose(got, Rotation.from_matrix(R).as_rotvec(), atol=1e-14)


@MORE
@given(quats())
def test_quat_matrix_round_trip_and_scipy(q):
    R = so3.matrix_from_quat(q)
    np.testing.assert_allclose(R, Rotation.from_quat(q).as_matrix(), atol=1e-15 * 4)
    back = so3.quat_from_matrix(R)
    assert back[3] >= 0
    assert_quats_close(back, q, atol=1e-15 * 4)
    assert_quats_close(back, Rotation.from_matrix(R).as_quat(), atol=1e-15 * 4)


@MORE
@given(rotvecs())
def test_round_trips_return_the_canonical_vector(r):
    c = so3.canonical_rotvec(r)
    np.testing.assert_allclose(so3.rotvec_from_quat(so3.quat_from_rotvec(r)), c, atol=2e-15)
    np.testing.assert_allclose(so3.rotvec_from_matrix(so3.matrix_from_rotvec(r)), c, atol=4e-15)
    q = so3.quat_from_rotvec(r)
    assert_quats_close(so3.quat_from_matrix(so3.matrix_from_quat(q)), q, atol=1e-15 * 4)


def test_small_angles_are_exact_to_round_off_on_both_sides_of_the_series_threshold():
    u = np.array([2.0, -3.0, 6.0]) / 7.0
    thetas = np.concatenate([
        np.geomspace(1e-300, 1e-1, 200),
        SMALL_ANGLE * (1 + np.array([-1e-3, -1e-12, 0.0, 1e-12, 1e-3])),
    ])
    r = thetas[:, None] * u
    q = so3.quat_from_rotvec(r)
    # relative accuracy of the vector part and of the angle recovered from it
    np.testing.assert_allclose(q[:, :3], np.sin(thetas / 2)[:, None] * u, rtol=4e-16, atol=0)
    np.testing.assert_allclose(so3.rotvec_from_quat(q), r, rtol=4e-16, atol=0)
    R = so3.matrix_from_rotvec(r)
    np.testing.assert_allclose(R[:, 1, 0] - R[:, 0, 1], 2 * np.sin(thetas) * u[2], rtol=4e-15, atol=0)
    np.testing.assert_allclose(so3.rotvec_from_matrix(R)[thetas > 1e-150], r[thetas > 1e-150], rtol=1e-14)


def test_no_nan_for_finite_input_and_nan_for_nan():
    r = np.array([
        [0.0, 0.0, 0.0], [-0.0, 0.0, -0.0], [1e-300, 0, 0], [PI, 0, 0], [0, 0, -PI],
        [2 * PI, 0, 0], [0, 1e8, 0], [3.0, -4.0, 12.0], [1e-5, -1e-5, 1e-5],
    ])
    outs = [
        so3.canonical_rotvec(r), so3.quat_from_rotvec(r), so3.matrix_from_rotvec(r),
        so3.rotvec_from_matrix(so3.matrix_from_rotvec(r)), so3.rotvec_from_quat(so3.quat_from_rotvec(r)),
        so3.inverse_rotvec(r), so3.compose_rotvec(r, r[::-1]), so3.compose_rotvec_closed_form(r, r[::-1]),
        so3.exp_quat(r), so3.apply_rotvec(r, r[::-1]),
    ]
    for o in outs:
        assert np.all(np.isfinite(o))
    assert np.all(np.isnan(so3.rotvec_from_quat([np.nan, 0, 0, 1])))
    assert np.all(np.isnan(so3.rotvec_from_quat([0.0, 0, 0, 0])))


@pytest.mark.parametrize(
    "fn, shape",
    [
        (so3.canonical_rotvec, (3,)), (so3.quat_from_rotvec, (3,)), (so3.rotvec_from_quat, (4,)),
        (so3.matrix_from_rotvec, (3,)), (so3.rotvec_from_matrix, (3, 3)), (so3.matrix_from_quat, (4,)),
        (so3.quat_from_matrix, (3, 3)), (so3.quat_conjugate, (4,)), (so3.quat_normalize, (4,)),
        (so3.quat_canonical, (4,)), (so3.inverse_rotvec, (3,)), (so3.exp_so3, (3,)),
        (so3.log_so3, (3, 3)), (so3.exp_quat, (3,)), (so3.log_quat, (4,)), (so3.skew, (3,)),
        (lambda q: so3.euler_from_quat(q, "ZYX"), (4,)), (lambda a: so3.quat_from_euler(a, "xzx"), (3,)),
    ],
)
def test_unary_functions_vectorise_over_leading_axes(fn, shape):
    rng = np.random.default_rng(7)
    x = rng.normal(size=(2, 3) + shape) * 2
    if shape == (3, 3):
        x = Rotation.random(6, rng=rng).as_matrix().reshape(2, 3, 3, 3)
    x[0, 0] = 0.0 if shape != (3, 3) else np.eye(3)
    x[1, 2, ...] = x[1, 1, ...]  # a repeated element
    if shape == (3,):
        x[1, 1] = PI * np.array([0.6, -0.8, 0.0])  # a half turn
    got = fn(x)
    want = np.stack([np.stack([fn(x[i, j]) for j in range(3)]) for i in range(2)])
    assert got.shape == want.shape
    np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize(
    "fn, s1, s2",
    [
        (so3.quat_multiply, 4, 4), (so3.compose_rotvec, 3, 3), (so3.compose_rotvec_closed_form, 3, 3),
        (so3.rotate, 4, 3), (so3.apply_rotvec, 3, 3),
    ],
)
def test_binary_functions_vectorise_and_broadcast(fn, s1, s2):
    rng = np.random.default_rng(8)
    a = rng.normal(size=(2, 3, s1))
    b = rng.normal(size=(2, 3, s2))
    got = fn(a, b)
    want = np.stack([np.stack([fn(a[i, j], b[i, j]) for j in range(3)]) for i in range(2)])
    np.testing.assert_array_equal(got, want)
    # broadcasting one argument
    got_b = fn(a, b[0, 0])
    np.testing.assert_allclose(got_b[1, 2], fn(a[1, 2], b[0, 0]), atol=0)


def test_shape_errors_are_clear():
    with pytest.raises(ValueError, match=r"expected shape \(\.\.\., 3\)"):
        so3.quat_from_rotvec(np.zeros(4))
    with pytest.raises(ValueError, match=r"expected shape \(\.\.\., 4\)"):
        so3.rotvec_from_quat(np.zeros((2, 3)))
    with pytest.raises(ValueError, match=r"\(\.\.\., 3, 3\)"):
        so3.quat_from_matrix(np.zeros((3, 4)))


# ---------------------------------------------------------------------------------------------
# Quaternion algebra
# ---------------------------------------------------------------------------------------------


@FAST
@given(quats(), quats(), st.tuples(*[st.floats(-5, 5)] * 3))
def test_quat_multiply_matches_scipy_and_rotates_r1_first(q2, q1, x):
    q = so3.quat_multiply(q2, q1)
    ref = (Rotation.from_quat(q2) * Rotation.from_quat(q1)).as_quat()
    assert_quats_close(q, ref, atol=1e-15 * 8)
    x = np.array(x)
    np.testing.assert_allclose(so3.rotate(q, x), so3.rotate(q2, so3.rotate(q1, x)), atol=1e-13)


@FAST
@given(quats(), quats(), quats())
def test_quat_group_axioms(a, b, c):
    one = np.array([0.0, 0.0, 0.0, 1.0])
    np.testing.assert_array_equal(so3.quat_multiply(a, one), a)
    np.testing.assert_array_equal(so3.quat_multiply(one, a), a)
    np.testing.assert_allclose(so3.quat_multiply(a, so3.quat_conjugate(a)), one, atol=4e-16)
    np.testing.assert_allclose(
        so3.quat_multiply(so3.quat_multiply(a, b), c), so3.quat_multiply(a, so3.quat_multiply(b, c)), atol=1e-15
    )


def test_quat_canonical_and_normalize():
    q = np.array([[1.0, 2.0, 3.0, -4.0], [0.0, -1.0, 0.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0, 0, 0, 2.0]])
    c = so3.quat_canonical(q)
    np.testing.assert_array_equal(c, [[-1, -2, -3, 4], [0, 1, 0, 0], [1, 0, 0, 0], [0, 0, 0, 2]])
    n = so3.quat_normalize(q)
    np.testing.assert_allclose(np.linalg.norm(n, axis=-1), 1.0, atol=1e-16 * 2)
    np.testing.assert_allclose(n[0], q[0] / math.sqrt(30))


def test_quat_make_continuous_fixes_flips_along_any_axis():
    rng = np.random.default_rng(3)
    t = np.linspace(0, 4, 400)
    r = np.stack([np.sin(t), 2 * t, 0.5 * np.cos(3 * t)], axis=-1)  # passes θ = π several times
    q = Rotation.from_rotvec(r).as_quat()
    signs = rng.choice([-1.0, 1.0], size=(2, 400))
    noisy = signs[..., None] * q  # (2, 400, 4)
    fixed = so3.quat_make_continuous(noisy)
    assert np.all(np.sum(fixed[:, 1:] * fixed[:, :-1], axis=-1) >= 0)
    np.testing.assert_array_equal(fixed[:, 0], noisy[:, 0])  # first sample keeps its sign
    assert np.all(np.isin(np.sum(fixed * noisy, axis=-1).round(12), [-1.0, 1.0]))  # ± the input
    # the sequence on another axis gives the same
    moved = so3.quat_make_continuous(np.moveaxis(noisy, 1, 0), axis=0)
    np.testing.assert_array_equal(np.moveaxis(moved, 0, 1), fixed)
    # each row as a single sequence gives the same
    np.testing.assert_array_equal(so3.quat_make_continuous(noisy[1]), fixed[1])
    with pytest.raises(ValueError):
        so3.quat_make_continuous(noisy, axis=-1)


# ---------------------------------------------------------------------------------------------
# Composition (eq. 8) and group axioms on rotation vectors
# ---------------------------------------------------------------------------------------------


@MORE
@given(rotvecs(), rotvecs())
def test_compose_rotvec_matches_scipy(r2, r1):
    got = so3.compose_rotvec(r2, r1)
    assert_canonical(got)
    ref = (Rotation.from_rotvec(r2) * Rotation.from_rotvec(r1)).as_rotvec()
    assert_rotvecs_close(got, ref, atol=1e-14)


@MORE
@given(rotvecs(), rotvecs())
@pytest.mark.slow
def test_compose_via_quaternions_equals_corrected_eq8_closed_form(r2, r1):
    a = so3.compose_rotvec(r2, r1)
    b = so3.compose_rotvec_closed_form(r2, r1)
    assert_canonical(b)
    # acos in the closed form loses half the digits near the identity
    assert_rotvecs_close(a, b, atol=1e-7)
    t = theta_of(a)
    if 1e-3 < t < PI - 1e-6:
        np.testing.assert_allclose(b, a, atol=1e-11)


def test_eq8_as_printed_is_wrong_and_the_correction_is_right():
    # the printed text has c = 1 + u2·u1; docs/method.md §3: c = 1 − u2·u1
    r1 = np.array([0.3, -0.2, 0.9])
    r2 = np.array([0.5, 0.4, 1.2])
    t1, t2 = np.linalg.norm(r1), np.linalg.norm(r2)
    u1, u2 = r1 / t1, r2 / t2
    a = math.cos((t1 + t2) / 2)
    b = math.sin(t2 / 2) * math.sin(t1 / 2)
    truth = (Rotation.from_rotvec(r2) * Rotation.from_rotvec(r1)).magnitude()
    assert abs(2 * math.acos(a + b * (1 - u2 @ u1)) - truth) < 1e-12
    assert abs(2 * math.acos(a + b * (1 + u2 @ u1)) - truth) > 0.1


@MORE
@given(rotvecs())
def test_rotvec_group_identity_and_inverse(r):
    zero = np.zeros(3)
    c = so3.canonical_rotvec(r)
    np.testing.assert_allclose(so3.compose_rotvec(r, zero), c, atol=2e-15)
    np.testing.assert_allclose(so3.compose_rotvec(zero, r), c, atol=2e-15)
    inv = so3.inverse_rotvec(r)
    assert_canonical(inv)
    assert_rotvecs_close(inv, Rotation.from_rotvec(r).inv().as_rotvec(), atol=1e-15 * 4)
    # (within PI_TOLERANCE of π, r and its inverse share one canonical vector: the tie price)
    assert np.linalg.norm(so3.compose_rotvec(r, inv)) < 1e-15 * 4 + TIE_ATOL
    assert np.linalg.norm(so3.compose_rotvec(inv, r)) < 1e-15 * 4 + TIE_ATOL
    if theta_of(c) >= PI - 1e-13:  # a half turn is its own inverse, with the same vector
        np.testing.assert_allclose(inv, c, atol=1e-15)


@MORE
@given(rotvecs(), rotvecs(), rotvecs())
def test_rotvec_composition_is_associative(a, b, c):
    left = so3.compose_rotvec(so3.compose_rotvec(a, b), c)
    right = so3.compose_rotvec(a, so3.compose_rotvec(b, c))
    assert_rotvecs_close(left, right, atol=1e-14)
    assert_canonical(left)
    assert_canonical(right)


# ---------------------------------------------------------------------------------------------
# exp / log (eq. 11, 12), acting on vectors
# ---------------------------------------------------------------------------------------------


@MORE
@given(raw_rotvecs())
@pytest.mark.slow
def test_exp_log_so3(omega):
    R = so3.exp_so3(omega)
    np.testing.assert_allclose(R, Rotation.from_rotvec(omega).as_matrix(), atol=2e-15 * max(1, theta_of(omega)))
    w = so3.log_so3(R)
    assert_canonical(w)
    np.testing.assert_allclose(w, so3.canonical_rotvec(omega), atol=4e-15 * max(1, theta_of(omega)))
    np.testing.assert_allclose(so3.exp_so3(w), R, atol=4e-15 * max(1, theta_of(omega)))


@MORE
@given(raw_rotvecs())
def test_exp_log_quat(omega):
    q = so3.exp_quat(omega)
    t = theta_of(omega)
    # the true exponential on S³: no sign flip, also beyond π
    np.testing.assert_allclose(q[3], math.cos(t / 2), atol=1e-16 * 4)
    assert abs(np.linalg.norm(q) - 1) < 1e-15
    assert_quats_close(q, Rotation.from_rotvec(omega).as_quat(), atol=1e-15 * 4 * max(1, t))
    np.testing.assert_allclose(so3.log_quat(q), so3.canonical_rotvec(omega), atol=4e-15 * max(1, t))


@FAST
@given(quats(), rotvecs(), st.tuples(*[st.floats(-5, 5)] * 3))
def test_rotate_and_apply_rotvec_match_scipy(q, r, x):
    x = np.array(x)
    np.testing.assert_allclose(so3.rotate(q, x), Rotation.from_quat(q).apply(x), atol=1e-14)
    np.testing.assert_allclose(so3.rotate(-q, x), so3.rotate(q, x), atol=1e-14)
    np.testing.assert_allclose(so3.apply_rotvec(r, x), Rotation.from_rotvec(r).apply(x), atol=1e-14)
    np.testing.assert_allclose(so3.skew(r) @ x, np.cross(r, x), atol=1e-15)


# ---------------------------------------------------------------------------------------------
# slerp
# ---------------------------------------------------------------------------------------------


@FAST
@given(quats(), quats())
def test_slerp_matches_scipy_and_has_constant_speed(q0, q1):
    s = np.linspace(0.0, 1.0, 11)
    got = so3.slerp(q0, q1, s)
    assert got.shape == (11, 4)
    np.testing.assert_allclose(got[0], q0 / np.linalg.norm(q0), atol=1e-15)
    assert_quats_close(got[-1], q1, atol=1e-14)
    total = quat_angle_between(q0, q1)
    np.testing.assert_allclose(quat_angle_between(q0, got), s * total, atol=1e-13)
    if total < PI - 1e-6:  # two shortest arcs at exactly π apart
        ref = Slerp([0.0, 1.0], Rotation.from_quat([q0, q1]))(s).as_quat()
        assert_quats_close(got, ref, atol=1e-13)
    # continuous in sign: consecutive samples on one hemisphere
    assert np.all(np.sum(got[1:] * got[:-1], axis=-1) > 0)


@FAST
@given(quats(), st.floats(-14.0, -6.0), st.floats(0.0, 1.0))
def test_slerp_is_stable_for_nearly_equal_quaternions(q0, e, s):
    q1 = so3.quat_multiply(q0, so3.exp_quat(np.array([10.0**e, -(10.0**e), 0.0])))
    got = so3.slerp(q0, q1, s)
    assert np.all(np.isfinite(got))
    np.testing.assert_allclose(quat_angle_between(q0, got), s * quat_angle_between(q0, q1), atol=1e-15 * 8)
    np.testing.assert_array_equal(so3.slerp(q0, q0, s), so3.quat_normalize(q0))


def test_slerp_broadcasts_s_against_leading_axes():
    q = Rotation.random(5, rng=1).as_quat()
    s = np.linspace(0, 1, 5)
    got = so3.slerp(q[:-1][None], q[1:][None], s[:, None])  # (5, 4, 4)
    assert got.shape == (5, 4, 4)
    for i in range(5):
        for j in range(4):
            np.testing.assert_allclose(got[i, j], so3.slerp(q[j], q[j + 1], s[i]), atol=1e-16 * 4)


# ---------------------------------------------------------------------------------------------
# Euler angles (all 12 sequences, extrinsic and intrinsic, degrees)
# ---------------------------------------------------------------------------------------------


def _wrap(a):
    return (a + PI) % (2 * PI) - PI


@pytest.mark.parametrize("degrees", [False, True])
@pytest.mark.parametrize("order", ALL_ORDERS + [o.upper() for o in ALL_ORDERS])
def test_euler_matches_scipy(order, degrees):
    rng = np.random.default_rng(abs(hash((order, degrees))) % 2**32)
    rot = Rotation.random(300, rng=rng)
    q = rot.as_quat()
    q[::2] *= -1  # either sign
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref = rot.as_euler(order, degrees=degrees)
    got = so3.euler_from_quat(q, order, degrees=degrees)
    full = 360.0 if degrees else 2 * PI
    np.testing.assert_allclose(_wrap((got - ref) * 2 * PI / full), 0, atol=1e-12)
    np.testing.assert_allclose(so3.euler_from_matrix(rot.as_matrix(), order, degrees=degrees), got, atol=1e-12 * full)
    # from Euler: scipy's rotation; round trip back to the same rotation
    back = so3.quat_from_euler(got, order, degrees=degrees)
    assert np.all(back[:, 3] >= 0)
    assert_quats_close(back, Rotation.from_euler(order, ref, degrees=degrees).as_quat(), atol=1e-14)
    assert_quats_close(back, q, atol=1e-14)
    np.testing.assert_allclose(
        so3.matrix_from_euler(got, order, degrees=degrees), rot.as_matrix(), atol=1e-14
    )
    # angle ranges
    lim = full / 2
    assert np.all((got[:, 0] >= -lim) & (got[:, 0] < lim) & (got[:, 2] >= -lim) & (got[:, 2] < lim))
    if order[0].lower() == order[2].lower():
        assert np.all((got[:, 1] >= 0) & (got[:, 1] <= lim))
    else:
        assert np.all(np.abs(got[:, 1]) <= lim / 2 + 1e-12)


@pytest.mark.parametrize("order", ALL_ORDERS + [o.upper() for o in ALL_ORDERS])
def test_euler_gimbal_lock_like_scipy(order):
    proper = order[0].lower() == order[2].lower()
    locks = [0.0, PI] if proper else [PI / 2, -PI / 2]
    angles = np.array([[a, b, c] for b in locks for a, c in [(0.3, 0.7), (-2.0, 1.1), (3.0, 3.0)]])
    rot = Rotation.from_euler(order, angles)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref = rot.as_euler(order)
    got = so3.euler_from_quat(rot.as_quat(), order)
    np.testing.assert_allclose(_wrap(got - ref), 0, atol=1e-9)
    np.testing.assert_array_equal(got[:, 2], 0.0)  # third angle is zero
    assert_quats_close(so3.quat_from_euler(got, order), rot.as_quat(), atol=1e-12)


@FAST
@given(st.tuples(*[st.floats(-10.0, 10.0)] * 3), st.sampled_from(ALL_ORDERS), st.booleans())
def test_quat_from_euler_matches_scipy_for_any_angles(angles, order, intrinsic):
    order = order.upper() if intrinsic else order
    got = so3.quat_from_euler(np.array(angles), order)
    assert_quats_close(got, Rotation.from_euler(order, angles).as_quat(), atol=1e-14)
    got_deg = so3.quat_from_euler(np.rad2deg(angles), order, degrees=True)
    assert_quats_close(got_deg, got, atol=1e-14)


@pytest.mark.parametrize("bad", ["xy", "xyzx", "xyZ", "xxy", "xyy", "abc", "XXY", 3])
def test_euler_order_validation(bad):
    with pytest.raises(ValueError):
        so3.quat_from_euler(np.zeros(3), bad)
    with pytest.raises(ValueError):
        so3.euler_from_quat(np.array([0, 0, 0, 1.0]), bad)


# ---------------------------------------------------------------------------------------------
# Random rotations
# ---------------------------------------------------------------------------------------------


def test_random_quat_is_uniform_unit_and_reproducible():
    q = so3.random_quat(np.random.default_rng(5), (20000,))
    assert q.shape == (20000, 4)
    np.testing.assert_allclose(np.linalg.norm(q, axis=-1), 1, atol=1e-15)
    assert np.all(q[:, 3] >= 0)
    np.testing.assert_array_equal(q, so3.random_quat(np.random.default_rng(5), 20000))
    assert so3.random_quat(np.random.default_rng(5)).shape == (4,)
    assert so3.random_quat(np.random.default_rng(5), (2, 3)).shape == (2, 3, 4)
    # Haar measure: E[q qᵀ] = I/4 (on S³ with ±q identified), and the rotation angle has density
    # (1 − cos θ)/π, mean π/2 + 2/π
    m = np.einsum("ni,nj->ij", q, q) / len(q)
    np.testing.assert_allclose(m, np.eye(4) / 4, atol=0.01)
    theta = 2 * np.arctan2(np.linalg.norm(q[:, :3], axis=-1), q[:, 3])
    assert abs(theta.mean() - (PI / 2 + 2 / PI)) < 0.02
    with pytest.raises(TypeError):
        so3.random_quat(5)


@FAST
@given(stacked(rotvecs(), (2, 3)), stacked(rotvecs(), (2, 3)))
@pytest.mark.slow
def test_compose_and_conversions_vectorise_on_hard_cases(a, b):
    got = so3.compose_rotvec(a, b)
    for i in range(2):
        for j in range(3):
            np.testing.assert_array_equal(got[i, j], so3.compose_rotvec(a[i, j], b[i, j]))
    np.testing.assert_array_equal(so3.rotvec_from_quat(so3.quat_from_rotvec(a))[1, 2],
                                  so3.rotvec_from_quat(so3.quat_from_rotvec(a[1, 2])))
    assert rotation_angle_between(got, a).shape == (2, 3)
