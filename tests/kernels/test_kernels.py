"""Kernels: symmetry, positive semi-definiteness (and the paper's counterexample), analytic gradients."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from rbgp_cli.kernels import DotProduct, SquaredExponential, kernel_from_dict

ALL_KERNELS = [
    ("se-arc", lambda learn: SquaredExponential("arc", 3, 0.7, learn)),
    ("se-chordal", lambda learn: SquaredExponential("chordal", 3, 0.6, learn)),
    ("se-euclidean", lambda learn: SquaredExponential("euclidean", 3, 0.7, learn)),
    ("se-s3", lambda learn: SquaredExponential("s3", 4, 0.7, learn)),
    ("se-chordal-quat", lambda learn: SquaredExponential("chordal", 4, 0.7, learn)),
    ("dot", lambda learn: DotProduct(3, 0.4, learn)),
]


def poses(n, seed, quat=False):
    rng = np.random.default_rng(seed)
    rot = Rotation.random(n, random_state=seed)
    r = rot.as_quat() if quat else rot.as_rotvec()
    return np.hstack([r, rng.normal(0, 0.3, (n, 3))])


def values_for(kernel):
    return {"signal_std": 1.3, "length_scale": 0.7, "rho_rot": kernel.rho_rot}


@pytest.mark.parametrize("name,make", ALL_KERNELS)
def test_gram_symmetric_and_matches_cross_gram(name, make):
    k = make(False)
    X = poses(12, 1, quat=k.rotation_dims == 4)
    K = k(X, None, values_for(k))
    assert K.shape == (12, 12)
    np.testing.assert_allclose(K, K.T, rtol=0, atol=1e-14)
    # the cross-covariance path (prediction) gives the same numbers as the training path
    np.testing.assert_allclose(k(X[:5], X, values_for(k)), K[:5], rtol=1e-13, atol=1e-14)
    np.testing.assert_allclose(np.diagonal(K), k.diag(X, values_for(k)), rtol=1e-12)


@pytest.mark.parametrize("name,make", ALL_KERNELS)
@pytest.mark.parametrize("learn", [False, True])
def test_analytic_gradient_matches_finite_differences(name, make, learn):
    k = make(learn)
    X = poses(7, 3, quat=k.rotation_dims == 4)
    vals = values_for(k)
    names = ["signal_std", "length_scale", "rho_rot"] if isinstance(k, SquaredExponential) else ["signal_std", "rho_rot"]
    if not learn:
        names.remove("rho_rot")
    K, dK = k.gram_with_gradient(X, vals, names)
    # the contraction path used by the optimiser agrees with the explicit tensor
    K2, dK2 = type(k).__mro__[1].gram_with_gradient(k, X, vals, names)
    np.testing.assert_allclose(dK2, dK, rtol=1e-10, atol=1e-12)
    for i, nm in enumerate(names):
        h = 1e-6
        up, dn = dict(vals), dict(vals)
        up[nm] *= math.exp(h)
        dn[nm] *= math.exp(-h)
        fd = (k(X, None, up) - k(X, None, dn)) / (2 * h)
        np.testing.assert_allclose(dK[..., i], fd, rtol=1e-6, atol=1e-8, err_msg=f"{name}: d/dlog {nm}")


def min_eig(K):
    return float(np.linalg.eigvalsh(K).min())


@settings(max_examples=25, deadline=None)
@given(
    lam=st.floats(0.05, 20.0),
    rho=st.floats(0.05, 0.95),
    seed=st.integers(0, 10_000),
)
def test_chordal_and_dot_gram_matrices_are_psd_at_any_length_scale(lam, rho, seed):
    X = poses(40, seed)
    for k in (SquaredExponential("chordal", 3, rho), DotProduct(3, rho)):
        K = k(X, None, {"signal_std": 1.0, "length_scale": lam, "rho_rot": rho})
        assert min_eig(K) > -1e-9 * max(1.0, float(np.max(np.abs(K)))), type(k).__name__


def eight_rotations():
    """docs/method.md §6: 8 rotations about one axis, π/4 apart; d_arc is the wrapped angle difference."""
    ang = np.arange(8) * math.pi / 4
    r = Rotation.from_rotvec(ang[:, None] * np.array([0.0, 0.0, 1.0])).as_rotvec()
    return np.hstack([r, np.zeros((8, 3))])


@pytest.mark.parametrize("lam,expected", [(0.5, 0.43), (1.0, -0.004), (2.0, -0.18)])
def test_paper_kernel_is_not_psd_counterexample(lam, expected):
    """The paper's Theorem 1 is false: the geodesic SE kernel's Gram matrix has negative eigenvalues.

    ρ1 = 1 up to the weight (we use ρ1 → d² = ρ1 d_arc², so λ is scaled by √ρ1 to match σf = 1,
    λ = lam on the pure rotation distance). This is why the GP must treat K + σn²I as possibly
    indefinite (infeasible hyperparameters, Cholesky checks, jitter).
    """
    rho = 0.7
    k = SquaredExponential("arc", 3, rho)
    K = k(eight_rotations(), None, {"signal_std": 1.0, "length_scale": lam * math.sqrt(rho), "rho_rot": rho})
    assert min_eig(K) == pytest.approx(expected, abs=0.006)
    # the chordal variant on the same rotations stays PSD
    Kc = SquaredExponential("chordal", 3, rho)(eight_rotations(), None, {"signal_std": 1.0, "length_scale": lam * math.sqrt(rho), "rho_rot": rho})
    assert min_eig(Kc) > -1e-12


def test_paper_kernel_random_rotations_indefinite_at_long_length_scale():
    r = Rotation.random(200, random_state=7).as_rotvec()
    X = np.hstack([r, np.zeros((200, 3))])
    k = SquaredExponential("arc", 3, 0.5)
    K = k(X, None, {"signal_std": 1.0, "length_scale": 2.0 * math.sqrt(0.5), "rho_rot": 0.5})
    assert min_eig(K) < -0.5  # docs/method.md §6 reports about −1.8


def test_arc_kernel_invariant_to_quaternion_sign_and_canonical_twin():
    """At θ = π, r and −r are the same rotation: the kernel must not tell them apart."""
    k = SquaredExponential("arc", 3, 0.7)
    u = np.array([0.0, 0.6, 0.8])
    X1 = np.array([[*(math.pi * u), 0.1, 0.2, 0.3], [0.1, 0.2, 0.3, 0.0, 0.0, 0.0]])
    X2 = X1.copy()
    X2[0, :3] = -math.pi * u
    v = {"signal_std": 1.0, "length_scale": 0.8, "rho_rot": 0.7}
    np.testing.assert_allclose(k(X1, None, v), k(X2, None, v), atol=1e-12)


@pytest.mark.parametrize("name,make", ALL_KERNELS)
def test_kernel_description_round_trips(name, make):
    k = make(True)
    k2 = kernel_from_dict(k.to_dict())
    X = poses(5, 2, quat=k.rotation_dims == 4)
    np.testing.assert_array_equal(k(X, None, values_for(k)), k2(X, None, values_for(k)))


TIME_KERNELS = [
    ("se-arc-time", lambda learn: SquaredExponential("arc", 3, 0.7, learn, time_dims=1)),
    ("se-chordal-quat-time", lambda learn: SquaredExponential("chordal", 4, 0.7, learn, time_dims=1)),
]


@pytest.mark.parametrize("name,make", ALL_KERNELS + TIME_KERNELS)
@pytest.mark.parametrize("learn", [False, True])
def test_prediction_path_matches_the_training_path(name, make, learn):
    """cross_precompute / cross_gram (matrix products, used by predictions and rollouts) give the
    same K(Xa, Xb) as precompute (the precise pairwise distances): d² to ~1e-15 absolute, so K to
    ~1e-15/λ² relative, also for query points equal to or 1e-9 from training points, and with short
    length-scales (exponents below the underflow floor)."""
    k = make(learn)
    quat = k.rotation_dims == 4
    timed = getattr(k, "time_dims", 0)
    offset = np.r_[np.zeros(k.rotation_dims), [3.0, -2.0, 1.0]]  # metres from the origin
    Xb = poses(50, 8, quat=quat) + offset
    Xq = poses(15, 9, quat=quat) + offset
    if timed:  # seconds since the start
        Xb = np.hstack([Xb, np.random.default_rng(8).uniform(0, 5, (50, 1))])
        Xq = np.hstack([Xq, np.random.default_rng(9).uniform(0, 5, (15, 1))])
    Xa = np.concatenate([Xb[:6], Xb[6:10] + 1e-9, Xq])
    plan = k.cross_plan(Xb)
    for lam in (0.7, 0.02):
        vals = {**values_for(k), "length_scale": lam, **({"time_scale": 1.3} if timed else {})}
        want = k(Xa, Xb, vals)
        K_pre, _ = k.gram(k.cross_precompute(plan, Xa), vals)
        rtol = 4e-15 / lam**2
        np.testing.assert_allclose(K_pre, want, rtol=rtol, atol=1e-15)
        np.testing.assert_allclose(k.cross_gram(plan, Xa, vals), want, rtol=rtol, atol=1e-15)


@pytest.mark.parametrize("name,make", ALL_KERNELS + TIME_KERNELS + [
    ("se-chordal-time", lambda learn: SquaredExponential("chordal", 3, 0.6, learn, time_dims=1))])
@pytest.mark.parametrize("learn", [False, True])
def test_cross_gradient_contraction_matches_the_training_path(name, make, learn):
    """cross_grad_contract (the sparse GP's row blocks; for the chordal kernel sums of features times
    one matrix product, no pairwise arrays) equals grad_contract of the precise pairwise distances,
    with translations metres from the origin and query points on and next to the second set."""
    k = make(learn)
    quat = k.rotation_dims == 4
    timed = getattr(k, "time_dims", 0)
    offset = np.r_[np.zeros(k.rotation_dims), [3.0, -2.0, 1.0]]
    Xb = poses(40, 18, quat=quat) + offset
    Xq = poses(25, 19, quat=quat) + offset
    if timed:
        Xb = np.hstack([Xb, np.random.default_rng(18).uniform(0, 5, (40, 1))])
        Xq = np.hstack([Xq, np.random.default_rng(19).uniform(0, 5, (25, 1))])
    Xa = np.concatenate([Xb[:5], Xb[5:8] + 1e-9, Xq])
    vals = {**values_for(k), **({"time_scale": 1.3} if timed else {})}
    names = [nm for nm in k.names if nm != "rho_rot" or learn]
    W = np.random.default_rng(20).normal(size=(len(Xa), len(Xb)))
    pre = k.precompute(Xa, Xb)
    K, state = k.gram(pre, vals)
    want = k.grad_contract(pre, vals, K, state, W, names)
    plan = k.cross_plan(Xb)
    got = k.cross_grad_contract(plan, Xa, vals, k.cross_gram(plan, Xa, vals), W, names)
    scale = float(np.sum(np.abs(W * K)))  # the sums the contraction is made of
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-13 * scale * 30)
    assert k.fused_cross_gradient == (getattr(k, "metric", None) == "chordal")
