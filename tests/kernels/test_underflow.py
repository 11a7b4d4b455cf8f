"""The training Gram matrix at short length-scales: no subnormal numbers in K, in its Cholesky factor or
in C⁻¹ (their arithmetic is ~100 times slower on x86; issue 35 measured 140–200 ms per evaluation at
n = 400 instead of 7 ms), and the entries kept equal to the formula."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import lapack
from scipy.spatial.transform import Rotation

from rbgp_cli.gp.likelihood import cholesky, nlml_and_gradient
from rbgp_cli.kernels import SquaredExponential
from rbgp_cli.kernels.squared_exponential import ZERO_EXPONENT

TINY = np.finfo(np.float64).tiny


def no_subnormals(a) -> bool:
    a = np.abs(np.asarray(a))
    return bool(np.all((a == 0.0) | (a >= TINY)))


def short_scale_problem(metric="chordal", time_dims=1, n=120, seed=3):
    rng = np.random.default_rng(seed)
    rot = Rotation.random(n, random_state=seed).as_rotvec()
    X = np.hstack([rot, rng.normal(0, 0.3, (n, 3))])
    if time_dims:
        X = np.hstack([X, np.sort(rng.uniform(0, 1, (n, 1)), axis=0)])
    k = SquaredExponential(metric, 3, 0.7, False, time_dims)
    # σf = 1e-4 and λ, λτ short enough that most pairs lie between e^-172.5 and e^-745: the old floor
    # (exponents raised to -345) left K's off-diagonal at 1e-158, whose products in the Cholesky
    # factor underflowed
    values = {"signal_std": 1e-4, "length_scale": 0.02, "rho_rot": 0.7, "noise_std": 0.06}
    if time_dims:
        values["time_scale"] = 0.004
    return k, X, values


def exponent_of(pre, d2, values):
    """−d²/(2λ²) − Δτ²/(2λτ²) in the kernel's own order of operations (so that exp of it is bit-equal)."""
    lam = values["length_scale"]
    e = np.multiply(d2, -0.5 / (lam * lam))
    if "tau2" in pre:
        lt = values["time_scale"]
        e -= (0.5 / (lt * lt)) * pre["tau2"]
    return e


@pytest.mark.parametrize("metric,time_dims", [("chordal", 1), ("chordal", 0), ("arc", 0)])
def test_gram_is_zero_below_the_cut_and_exact_above(metric, time_dims):
    k, X, values = short_scale_problem(metric, time_dims)
    pre = k.precompute(X)
    K, d2 = k.gram(pre, values)
    exponent = exponent_of(pre, d2, values)
    below = exponent < ZERO_EXPONENT
    assert 0.3 < below.mean() < 1.0  # the case exercises the cut
    assert np.all(K[below] == 0.0)
    np.testing.assert_array_equal(K[~below], values["signal_std"] ** 2 * np.exp(exponent[~below]))
    assert no_subnormals(K)


@pytest.mark.parametrize("metric,time_dims", [("chordal", 1), ("arc", 0)])
def test_cholesky_and_inverse_free_of_subnormals(metric, time_dims):
    """The factorisation and C⁻¹ multiply entries of the factor with each other: every such product of
    two nonzero entries is a normal number (with the old floor, 1e-157² underflowed)."""
    k, X, values = short_scale_problem(metric, time_dims)
    pre = k.precompute(X)
    K, _ = k.gram(pre, values)
    c = cholesky(K, values["noise_std"] ** 2)
    assert c is not None and no_subnormals(c)
    smallest = np.min(np.abs(c[c != 0.0]))
    assert smallest * smallest >= TINY
    inv, info = lapack.dpotri(c.copy(order="F"), lower=1)
    assert info == 0 and no_subnormals(inv)
    # the likelihood's gradient is finite and the time scale's part is exactly what the kept entries give
    names = ["signal_std", "length_scale", "noise_std"] + (["time_scale"] if time_dims else [])
    f, g = nlml_and_gradient(k, pre, values, np.random.default_rng(0).normal(0, 0.1, len(X)), names)
    assert np.isfinite(f) and np.all(np.isfinite(g))


def test_long_length_scales_unchanged():
    """No exponent reaches the cut: K is σf² exp(exponent), bit for bit."""
    k, X, values = short_scale_problem("chordal", 1)
    values = {**values, "length_scale": 0.7, "time_scale": 0.3, "signal_std": 1.3}
    pre = k.precompute(X)
    K, d2 = k.gram(pre, values)
    exponent = exponent_of(pre, d2, values)
    assert exponent.min() > ZERO_EXPONENT
    np.testing.assert_array_equal(K, 1.3**2 * np.exp(exponent))
