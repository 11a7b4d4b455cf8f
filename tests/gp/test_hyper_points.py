"""Hyperparameters from a random subset of the training points, the posterior on all of them
(``fit_gp(..., hyper_points=h)``, issue 35). Oracles: the hyperparameters are those of a fit on the
subset alone (same seed, same options), and the posterior is the one a GP built from those
hyperparameters on all rows computes and checks by itself (a loaded model's path)."""

from __future__ import annotations

import numpy as np
import pytest

from rbgp_cli.gp.exact import GaussianProcess, fit_gp
from rbgp_cli.gp.posterior import PriorOnly
from rbgp_cli.kernels import SquaredExponential
from tests.gp.test_gp import poses, smooth_outputs


@pytest.mark.slow
@pytest.mark.parametrize("shared", [False, True])
def test_subset_hyperparameters_and_a_posterior_on_every_row(shared):
    X = poses(300, 3)
    Y = smooth_outputs(X, np.random.default_rng(3))[:, :3]
    k = SquaredExponential("chordal")
    gp = fit_gp(X, Y, k, restarts=1, seed=5, shared=shared, hyper_points=120)
    rows = gp.hyper_subset
    assert len(rows) == 120 and len(np.unique(rows)) == 120 and np.all(np.diff(rows) > 0)
    alone = fit_gp(X[rows], Y[rows], k, restarts=1, seed=5, shared=shared)
    for a, b in zip(gp.fits, alone.fits):
        assert a.values == pytest.approx(b.values, rel=1e-12)
    # the posterior uses all 300 rows: the same as a GP that factorises them itself
    assert len(gp.X) == 300
    ref = GaussianProcess(k, X, Y, gp.fits, shared=shared, y_scale=gp.y_scale)
    Xq = poses(40, 9)
    m1, s1 = gp.predict(Xq, return_std=True)
    m2, s2 = ref.predict(Xq, return_std=True)
    np.testing.assert_allclose(m1, m2, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(s1, s2, rtol=1e-9, atol=1e-12)
    # and it is not the subset's posterior: the other 180 rows move the mean
    assert np.max(np.abs(m1 - alone.predict(Xq))) > 1e-6


@pytest.mark.slow
def test_hyper_points_at_or_above_n_is_the_full_fit():
    X = poses(100, 4)
    Y = smooth_outputs(X, np.random.default_rng(4))[:, :2]
    k = SquaredExponential("chordal")
    a = fit_gp(X, Y, k, restarts=1, seed=1, hyper_points=100)
    b = fit_gp(X, Y, k, restarts=1, seed=1)
    assert not hasattr(a, "hyper_subset")
    assert [f.values for f in a.fits] == [f.values for f in b.fits]


def test_prior_only_predicts_the_prior():
    X = poses(80, 6)
    Y = smooth_outputs(X, np.random.default_rng(6))[:, :2]
    k = SquaredExponential("chordal")
    gp = fit_gp(X, Y, k, restarts=1, seed=0)
    off = PriorOnly(gp)
    Xq = poses(25, 7)
    mean, std = off.predict(Xq, return_std=True)
    assert mean.shape == (25, 2) and np.all(mean == 0.0)
    for l, fit in enumerate(gp.fits):  # the prior's std: σf, and √(σf² + σn²) for a new observation
        np.testing.assert_allclose(std[:, l], fit.values["signal_std"], rtol=1e-12)
        _, noisy = off.predict(Xq, return_std=True, noisy=True)
        np.testing.assert_allclose(noisy[:, l], np.hypot(fit.values["signal_std"], fit.values["noise_std"]),
                                   rtol=1e-9)
    assert off.X is gp.X and off.fits is gp.fits  # everything else is the GP's


@pytest.mark.parametrize("metric", ["chordal", "euclidean"])
def test_kernels_that_skip_the_margin_test_are_positive_semidefinite(metric):
    """The noise margin is not tested for kernels that declare themselves positive semi-definite:
    their Gram matrices' smallest eigenvalue is ≥ 0 (to round-off) at every length scale tried."""
    from rbgp_cli.kernels import DotProduct

    X = poses(150, 11)
    for k in (SquaredExponential(metric), DotProduct()):
        assert k.positive_semidefinite
        pre = k.precompute(X)
        for ls in (0.05, 0.3, 1.0, 5.0):
            values = {"signal_std": 1.3, "length_scale": ls, "noise_std": 0.1}
            values = {n: values.get(n, 0.7) for n in k.names} | {"noise_std": 0.1}
            K, _ = k.gram(pre, values)
            assert np.linalg.eigvalsh(K)[0] >= -1e-9 * np.max(np.diag(K))
    assert not SquaredExponential("arc").positive_semidefinite  # the paper's geodesic kernel is not (MATH.md §6)
