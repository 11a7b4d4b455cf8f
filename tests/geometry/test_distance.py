"""Rotation and pose distances (eq. 14, 19; docs/method.md §5), elementwise and pairwise.
scipy's ``Rotation`` gives the oracle: d_arc(r1, r2) is the angle of R1ᵀR2."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from rbgp_cli.geometry import distance as dist
from rbgp_cli.geometry import so3
from tests.helpers import PI, axes, quats, rotation_angle_between, rotvecs, stacked

FAST = settings(max_examples=60, deadline=None)
MORE = settings(max_examples=150, deadline=None)


# ---------------------------------------------------------------------------------------------
# Elementwise
# ---------------------------------------------------------------------------------------------


@MORE
@given(rotvecs(), rotvecs())
def test_arc_distance_is_the_angle_of_r1t_r2(r1, r2):
    d = dist.arc_distance(r1, r2)
    assert 0.0 <= d <= PI
    np.testing.assert_allclose(d, rotation_angle_between(r1, r2), atol=1e-14)
    assert dist.arc_distance(r2, r1) == d  # symmetric, exactly


@MORE
@given(quats(), quats())
def test_arc_distance_quat_is_invariant_to_sign(q1, q2):
    d = dist.arc_distance_quat(q1, q2)
    assert dist.arc_distance_quat(q1, -q2) == d
    assert dist.arc_distance_quat(-q1, q2) == d
    np.testing.assert_allclose(d, dist.arc_distance(so3.rotvec_from_quat(q1), so3.rotvec_from_quat(q2)), atol=1e-14)


@MORE
@given(rotvecs())
def test_arc_distance_is_zero_for_equal_rotations(r):
    assert dist.arc_distance(r, r) == 0.0
    assert dist.arc_distance(r, so3.canonical_rotvec(r)) < 1e-15 * 4
    if np.linalg.norm(r) == PI:  # the θ = π twin is the same rotation
        assert dist.arc_distance(r, -r) < 1e-15 * 4


@MORE
@given(rotvecs(), rotvecs())
def test_arc_distance_is_positive_for_different_rotations(r1, r2):
    true = rotation_angle_between(r1, r2)
    if true > 1e-9:
        assert dist.arc_distance(r1, r2) > 0.5 * true


@MORE
@given(rotvecs(), rotvecs(), rotvecs())
@pytest.mark.slow
def test_arc_distance_triangle_inequality(a, b, c):
    assert dist.arc_distance(a, c) <= dist.arc_distance(a, b) + dist.arc_distance(b, c) + 1e-14


@MORE
@given(rotvecs(), rotvecs())
def test_chordal_is_2_sin_half_arc(r1, r2):
    d = dist.arc_distance(r1, r2)
    ch = dist.chordal_distance(r1, r2)
    assert 0.0 <= ch <= 2.0
    np.testing.assert_allclose(ch, 2 * math.sin(d / 2), rtol=1e-14, atol=1e-15)
    q1, q2 = so3.quat_from_rotvec(r1), so3.quat_from_rotvec(r2)
    np.testing.assert_allclose(ch, 2 * math.sqrt(max(0.0, 1 - np.dot(q1, q2) ** 2)), atol=1e-7)
    assert dist.chordal_distance_quat(q1, -q2) == dist.chordal_distance_quat(q1, q2)
    assert dist.chordal_distance(r2, r1) == ch


@FAST
@given(axes(), st.floats(-9.0, -1.0))
def test_rotations_close_across_pi_are_close(u, e):
    # (π − ε)u and (π − ε)(−u) are 2ε apart; the printed eq. 14 (no absolute value) says 2π − 2ε
    eps = 10.0**e
    r1, r2 = (PI - eps) * u, -(PI - eps) * u
    # (π − ε itself is rounded to ~4e-16, hence the atol)
    np.testing.assert_allclose(dist.arc_distance(r1, r2), 2 * eps, rtol=1e-6, atol=1e-14)
    np.testing.assert_allclose(dist.chordal_distance(r1, r2), 2 * math.sin(eps), rtol=1e-6, atol=1e-14)
    q1, q2 = so3.quat_from_rotvec(r1), so3.quat_from_rotvec(r2)
    printed = 2 * math.acos(np.clip(np.dot(q1, q2), -1, 1))
    assert printed > PI  # the paper's formula without |·| is wrong here


@FAST
@given(rotvecs(), axes(), st.floats(-12.0, -3.0))
def test_small_distances_are_accurate(r, u, e):
    # acos(⟨q1, q2⟩) would give 0 or ~1e-8 here; the atan2 form keeps ~all digits
    delta = 10.0**e
    q = so3.quat_from_rotvec(r)
    q2 = so3.quat_multiply(q, so3.exp_quat(delta * u))
    # (q2 itself carries round-off ~1e-16, hence the atol)
    np.testing.assert_allclose(dist.arc_distance_quat(q, q2), delta, rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(dist.chordal_distance_quat(q, q2), 2 * math.sin(delta / 2), rtol=1e-9, atol=1e-15)


@FAST
@given(stacked(rotvecs(), (2, 3)), stacked(rotvecs(), (2, 3)))
@pytest.mark.slow
def test_elementwise_distances_vectorise_and_broadcast(a, b):
    for fn in (dist.arc_distance, dist.chordal_distance):
        got = fn(a, b)
        assert got.shape == (2, 3)
        for i in range(2):
            for j in range(3):
                assert got[i, j] == fn(a[i, j], b[i, j])
        np.testing.assert_array_equal(fn(a, b[0, 0]), np.vectorize(lambda i, j: fn(a[i, j], b[0, 0]))(*np.indices((2, 3))))


# ---------------------------------------------------------------------------------------------
# Pairwise
# ---------------------------------------------------------------------------------------------


def _hard_rotation_set(rng, n):
    """Uniform rotations, near-duplicates (1e-12 … 1e-2 rad apart), exact duplicates, half turns
    and their twins: every branch of the pairwise code."""
    base = Rotation.random(n, rng=rng).as_rotvec()
    near = so3.compose_rotvec(
        base[: n // 2], rng.normal(size=(n // 2, 3)) * 10.0 ** rng.uniform(-12, -2, (n // 2, 1))
    )
    u = rng.normal(size=(n // 4, 3))
    u /= np.linalg.norm(u, axis=-1, keepdims=True)
    halves = PI * u
    near_pi = (PI - 10.0 ** rng.uniform(-9, -3, (n // 4, 1))) * u
    return np.concatenate([base, near, base[:5], halves, -halves, near_pi, -near_pi, np.zeros((2, 3))])


@pytest.mark.parametrize("metric", ["arc", "chordal"])
@pytest.mark.parametrize("n", [40, 300])  # the serial and the threaded path
def test_pairwise_rotation_distance_equals_elementwise(metric, n):
    rng = np.random.default_rng(n)
    a = _hard_rotation_set(rng, n)
    b = np.concatenate([a[::3], Rotation.random(50, rng=rng).as_rotvec()])
    # clustered within ~0.5°: nearly every pair takes the precise branch (the dense variant)
    cluster = so3.compose_rotvec(a[0], rng.normal(size=(n, 3)) * 10.0 ** rng.uniform(-12, -2.5, (n, 1)))
    cluster[-3:] = so3.compose_rotvec(np.array([0.0, 0.0, PI]), rng.normal(size=(3, 3)) * 1e-3)  # near π
    elem = dist.arc_distance if metric == "arc" else dist.chordal_distance
    for x, y in [(a, b), (a, a), (cluster, cluster), (cluster, a)]:
        got = dist.pairwise_rotation_distance(x, y, metric=metric)
        assert got.shape == (len(x), len(y))
        want = elem(x[:, None, :], y[None, :, :])
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
        # relative accuracy for the small ones too
        small = want < 0.02
        np.testing.assert_allclose(got[small], want[small], rtol=1e-12, atol=1e-16)
    same = dist.pairwise_rotation_distance(a, a, metric=metric)
    np.testing.assert_array_equal(np.diag(same), 0.0)
    np.testing.assert_array_equal(same, same.T)


def test_pairwise_quat_distance_and_s3_angle():
    rng = np.random.default_rng(11)
    r = _hard_rotation_set(rng, 60)
    q = so3.quat_from_rotvec(r) * rng.choice([-1.0, 1.0], size=(len(r), 1)) * rng.uniform(0.5, 2, (len(r), 1))
    for metric in ("arc", "chordal"):
        np.testing.assert_allclose(
            dist.pairwise_quat_distance(q, q[:20], metric), dist.pairwise_rotation_distance(r, r[:20], metric),
            rtol=0, atol=1e-12,
        )
    half = dist.pairwise_s3_angle(q, q[:20])
    np.testing.assert_allclose(half, dist.pairwise_rotation_distance(r, r[:20]) / 2, atol=1e-12)
    assert np.all((half >= 0) & (half <= PI / 2))
    with pytest.raises(ValueError, match="metric"):
        dist.pairwise_rotation_distance(r, r, metric="geodesic")
    with pytest.raises(ValueError, match=r"\(n, 3\)"):
        dist.pairwise_rotation_distance(r[0], r)


def test_pairwise_rotation_distance_is_fast():
    r = Rotation.random(1752, rng=0).as_rotvec()
    for metric in ("arc", "chordal"):
        dist.pairwise_rotation_distance(r, r, metric)
        t0 = time.perf_counter()
        dist.pairwise_rotation_distance(r, r, metric)
        # ~35 ms (arc) on 2 cores; a generous bound that only catches a wrong algorithm
        assert time.perf_counter() - t0 < 1.0


def test_pairwise_sq_distance_is_exact():
    rng = np.random.default_rng(2)
    for k in (1, 3, 6, 12):  # direct sums, and the expansion with correction for k > 8
        a = rng.normal(size=(70, k)) * 3 + 1e3  # a large common offset
        b = np.concatenate([a[::4], a[:5] + 1e-7, rng.normal(size=(20, k)) + 1e3])
        got = dist.pairwise_sq_distance(a, b)
        want = np.sum((a[:, None, :] - b[None, :, :]) ** 2, axis=-1)
        assert got.shape == (70, len(b))
        assert np.all(got >= 0)
        np.testing.assert_allclose(got, want, rtol=1e-9, atol=0)
        np.testing.assert_array_equal(got[::4][np.arange(len(a[::4])), np.arange(len(a[::4]))], 0.0)
        np.testing.assert_array_equal(np.diag(dist.pairwise_sq_distance(a, a)), 0.0)
    big = rng.normal(size=(700, 3))
    np.testing.assert_allclose(
        dist.pairwise_sq_distance(big, big[:400]), np.sum((big[:, None] - big[None, :400]) ** 2, -1), rtol=1e-14
    )
    assert dist.pairwise_sq_distance(np.zeros((0, 3)), np.zeros((4, 3))).shape == (0, 4)
    with pytest.raises(ValueError, match="columns"):
        dist.pairwise_sq_distance(np.zeros((2, 3)), np.zeros((2, 4)))


@pytest.mark.parametrize("metric", ["arc", "chordal"])
@pytest.mark.parametrize("rho", [0.0, 0.3, 0.7, 1.0])
def test_weighted_se3_sq_distance_is_eq19(metric, rho):
    rng = np.random.default_rng(5)
    ra = _hard_rotation_set(rng, 30)
    ga = np.concatenate([ra, rng.uniform(-5, 5, (len(ra), 3))], axis=-1)
    gb = ga[::2] + np.concatenate([np.zeros((len(ga[::2]), 3)), np.full((len(ga[::2]), 3), 0.01)], axis=-1)
    got = dist.weighted_se3_sq_distance(ga, gb, rho_rot=rho, metric=metric)
    elem = dist.arc_distance if metric == "arc" else dist.chordal_distance
    want = rho * elem(ga[:, None, :3], gb[None, :, :3]) ** 2 + (1 - rho) * np.sum(
        (ga[:, None, 3:] - gb[None, :, 3:]) ** 2, axis=-1
    )
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-14)
    np.testing.assert_array_equal(np.diag(dist.weighted_se3_sq_distance(ga, ga, rho, metric)), 0.0)


def test_weighted_se3_sq_distance_default_is_the_papers():
    g = np.array([[0.0, 0, 0, 0, 0, 0], [0, 0, PI / 2, 1, 0, 0]])
    d = dist.weighted_se3_sq_distance(g, g)
    np.testing.assert_allclose(d[0, 1], 0.7 * (PI / 2) ** 2 + 0.3 * 1.0)
    for bad in (-0.1, 1.5):
        with pytest.raises(ValueError, match="rho_rot"):
            dist.weighted_se3_sq_distance(g, g, rho_rot=bad)


# ---------------------------------------------------------------------------------------------
# Squared distances from one matrix product (the prediction path of the kernels)
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("metric", ["arc", "chordal", "s3"])
def test_gram_sq_rotation_distance_equals_squared_elementwise(metric):
    """d² from one matrix product of unit quaternions, without a small-angle branch, is within
    ~1e-15 (absolute) of the square of the elementwise, precise distance — also for equal,
    near-equal (1e-12 rad), sign-flipped and half-turn pairs (module doc of distance.py)."""
    rng = np.random.default_rng(31)
    a = _hard_rotation_set(rng, 80)
    cluster = so3.compose_rotvec(a[0], rng.normal(size=(60, 3)) * 10.0 ** rng.uniform(-12, -2.5, (60, 1)))
    elem = {"arc": dist.arc_distance, "chordal": dist.chordal_distance, "s3": lambda x, y: dist.arc_distance(x, y) / 2}[metric]
    for x, y in [(a, a), (cluster, cluster), (cluster, a[::2])]:
        qx = so3.quat_from_rotvec(x) * rng.choice([-1.0, 1.0], size=(len(x), 1)) * rng.uniform(0.5, 2, (len(x), 1))
        got = dist.gram_sq_rotation_distance(dist.unit_quats(qx, 4), dist.unit_quats_transposed(y, 3), metric)
        want = elem(x[:, None, :], y[None, :, :]) ** 2
        assert got.shape == (len(x), len(y)) and np.all(got >= 0)
        np.testing.assert_allclose(got, want, rtol=0, atol=8e-15)
    scaled = dist.gram_sq_rotation_distance(dist.unit_quats(a, 3), dist.unit_quats_transposed(a[:7], 3), metric, -0.3)
    np.testing.assert_allclose(scaled, -0.3 * elem(a[:, None, :], a[None, :7, :]) ** 2, rtol=0, atol=4e-15)
    with pytest.raises(ValueError, match="metric"):
        dist.gram_sq_rotation_distance(dist.unit_quats(a, 3), dist.unit_quats_transposed(a, 3), "euclidean")


def test_planned_sq_distance_equals_direct_sums():
    """‖a_i − b_j‖² from one product with b's plan (centred on b's mean): within ~1e-16 of the
    squared norms even for points metres away from the origin; scale and offset folded in."""
    rng = np.random.default_rng(4)
    b = rng.normal(size=(90, 3)) * 0.3 + np.array([5.0, -3.0, 2.0])
    a = np.concatenate([b[::3], b[:4] + 1e-9, rng.normal(size=(25, 3)) * 0.3 + np.array([5.0, -3.0, 2.0])])
    plan = dist.sq_distance_plan(b)
    want = np.sum((a[:, None, :] - b[None, :, :]) ** 2, axis=-1)
    got = dist.planned_sq_distance(plan, a)
    assert np.all(got >= 0)
    np.testing.assert_allclose(got, want, rtol=0, atol=2e-15)
    np.testing.assert_allclose(dist.planned_sq_distance(plan, a, -2.5, 0.7), -2.5 * want + 0.7, rtol=0, atol=1e-14)
    euler = rng.uniform(-PI, PI, (40, 3))
    np.testing.assert_allclose(dist.planned_sq_distance(dist.sq_distance_plan(euler), euler[:9]),
                               np.sum((euler[:9, None] - euler[None]) ** 2, -1), rtol=0, atol=1e-13)
