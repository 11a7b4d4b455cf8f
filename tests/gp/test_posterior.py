"""The posterior protocol (rbgp_cli.gp.posterior): a fitted exact GP and a fitted sparse GP both offer
what the motion model, rollouts, model files and the calibration use, with predictions of one shape."""

from __future__ import annotations

import inspect
import typing

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rbgp_cli.gp.exact import GaussianProcess, fit_gp
from rbgp_cli.gp.posterior import Posterior
from rbgp_cli.gp.sparse import SparseGP, fit_sparse_gp
from rbgp_cli.kernels import SquaredExponential


def _data(n, seed):
    rng = np.random.default_rng(seed)
    X = np.hstack([Rotation.random(n, random_state=seed).as_rotvec(), rng.normal(0, 0.3, (n, 3))])
    Y = np.stack([np.sin(X[:, 0]) + 0.5 * X[:, 3], X[:, 4] ** 2, np.cos(X[:, 5])], 1)
    return X, Y + 0.02 * rng.normal(size=Y.shape)


@pytest.fixture(scope="module", params=[False, True], ids=["per-output", "shared"])
def gps(request):
    X, Y = _data(120, 3)
    kernel = SquaredExponential("chordal", 3, 0.7)
    exact = fit_gp(X, Y, kernel, restarts=1, seed=0, shared=request.param)
    sparse = fit_sparse_gp(X, Y, kernel, inducing=30, restarts=1, seed=0, shared=request.param)
    return X, Y, exact, sparse


def test_both_fitted_gps_are_posteriors(gps):
    _X, _Y, exact, sparse = gps
    assert isinstance(exact, GaussianProcess) and isinstance(sparse, SparseGP)
    assert isinstance(exact, Posterior)
    assert isinstance(sparse, Posterior)


def test_something_without_the_members_is_not_a_posterior(gps):
    _X, _Y, exact, _sparse = gps

    class MeanOnly:  # what a GP-like object without the training data or the std would offer
        kernel, fits, shared = exact.kernel, exact.fits, exact.shared

        def predict(self, Xs, return_std=False, noisy=False, chunk_elements=2_000_000, manage_threads=True):
            return exact.predict(Xs)

    assert not isinstance(MeanOnly(), Posterior)


@pytest.mark.parametrize("name", ["predict", "predict_mean", "group_outputs"])
def test_the_predict_methods_take_the_protocols_arguments(name):
    """runtime_checkable only checks that the members exist: the signatures are compared here."""
    want = inspect.signature(getattr(Posterior, name)).parameters
    for cls in (GaussianProcess, SparseGP):
        have = inspect.signature(getattr(cls, name)).parameters
        assert list(have) == list(want), (cls, list(have))
        assert [p.default for p in have.values()] == [p.default for p in want.values()], cls


def test_predictions_have_the_same_shapes(gps):
    X, Y, exact, sparse = gps
    Xs = _data(37, 9)[0]
    L = Y.shape[1]
    for gp in (exact, sparse):
        assert gp.n_outputs == L and gp.X.shape == X.shape and gp.Y.shape == Y.shape
        assert gp.y_scale.shape == (L,) and len(gp.fits) == (1 if gp.shared else L)
        mean = gp.predict(Xs)
        m2, std = gp.predict(Xs, return_std=True)
        m3, std_noisy = gp.predict(Xs, return_std=True, noisy=True, manage_threads=False)
        assert mean.shape == std.shape == std_noisy.shape == (len(Xs), L)
        np.testing.assert_array_equal(gp.predict_mean(Xs), mean)
        np.testing.assert_allclose(m2, mean, rtol=0, atol=1e-12)
        np.testing.assert_allclose(m3, mean, rtol=0, atol=1e-12)
        assert np.all(std >= 0) and np.all(std_noisy > std)
    # one query point, given as a flat vector: (1, L) from both
    assert exact.predict(Xs[0]).shape == sparse.predict(Xs[0]).shape == (1, L)


def test_the_motion_model_holds_a_posterior():
    from rbgp_cli.dynamics.model import MotionModel

    assert typing.get_type_hints(MotionModel)["gp"] is Posterior


def test_group_outputs_cover_every_output_once(gps):
    _X, Y, exact, sparse = gps
    for gp in (exact, sparse):
        groups = gp.group_outputs()
        assert sorted(o for _fit, outs in groups for o in outs) == list(range(Y.shape[1]))
        assert [fit for fit, _outs in groups] == list(gp.fits)
