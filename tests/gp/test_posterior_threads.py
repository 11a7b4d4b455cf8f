"""The posterior on all rows at a subset's hyperparameters (``fit_gp(..., hyper_points=h)``) computed on
threads, one hyperparameter set each, equals the same computed one set after the other (issue 35)."""

from __future__ import annotations

import numpy as np
import pytest

import rbgp_cli.gp.exact as exact
from rbgp_cli.compute import blas_threads
from rbgp_cli.gp.exact import GaussianProcess, _posterior_on_all_rows
from rbgp_cli.gp.results import OutputFit
from rbgp_cli.kernels import SquaredExponential
from tests.gp.test_gp import poses, smooth_outputs


def fitted_on_subset(L=5, n=240, seed=2):
    """A GP 'fitted' on the first 60 rows with given per-output hyperparameters (no optimiser: the test
    is about the posterior's computation), and all n rows."""
    X = poses(n, seed)
    Y = smooth_outputs(X, np.random.default_rng(seed))[:, :L]
    k = SquaredExponential("chordal")
    fits = [OutputFit(values={"signal_std": 0.5 + 0.2 * l, "length_scale": 0.4 + 0.1 * l, "rho_rot": 0.6,
                              "noise_std": 0.05 + 0.01 * l}, nlml=0.0, jitter=0.0, rcond=1.0, positive_definite=True,
                      n_evaluations=0, n_infeasible=0, starts=[], at_bounds=[], free=[], seconds=0.0)
            for l in range(L)]
    sub = GaussianProcess(k, X[:60], Y[:60], fits, shared=False, y_scale=np.ones(L))
    return sub, X, Y


@pytest.mark.parametrize("threads", [2, 3])
def test_threaded_posterior_equals_the_serial_one(monkeypatch, threads):
    sub, X, Y = fitted_on_subset()
    with blas_threads(0):  # as inside fit_gp
        monkeypatch.setattr(exact, "thread_workers", lambda work, min_work: 1)
        serial = _posterior_on_all_rows(sub, X, Y)
        monkeypatch.setattr(exact, "thread_workers", lambda work, min_work: threads)
        threaded = _posterior_on_all_rows(sub, X, Y)
    assert serial is not None and threaded is not None
    assert [f.to_dict() for f in threaded.fits] == [f.to_dict() for f in serial.fits]
    # L and α wait for the first use (rbgp train never predicts with this posterior), then are those of a
    # posterior that factorises all rows itself, bit for bit
    assert all(a is None for a in threaded._alpha)
    threaded._ensure_factors()
    serial._ensure_factors()
    eager = GaussianProcess(sub.kernel, X, Y, threaded.fits, shared=False, y_scale=np.ones(Y.shape[1]))
    for L1, a1, L2, a2 in zip(threaded._L, threaded._alpha, eager._L, eager._alpha):
        np.testing.assert_array_equal(L1, L2)
        np.testing.assert_array_equal(a1, a2)
    for L1, a1, L2, a2 in zip(threaded._L, threaded._alpha, serial._L, serial._alpha):
        np.testing.assert_array_equal(L1, L2)
        np.testing.assert_array_equal(a1, a2)
    # the factors are those of all n rows: L Lᵀ = K + σn² I
    k, pre = sub.kernel, sub.kernel.precompute(X)
    for fit, L in zip(threaded.fits, threaded._L):
        K, _ = k.gram(pre, fit.values)
        np.testing.assert_allclose(L @ L.T, K + fit.values["noise_std"] ** 2 * np.eye(len(X)), atol=1e-12)


def test_threaded_factorisation_of_a_model_equals_the_serial_one(monkeypatch):
    """GaussianProcess without factors (a loaded model, a calibrated posterior) factorises every set on
    threads: the same factors and α as one set after the other."""
    sub, X, Y = fitted_on_subset(L=4, n=200, seed=7)
    monkeypatch.setattr(exact, "thread_workers", lambda work, min_work: 1)
    serial = GaussianProcess(sub.kernel, X, Y, sub.fits, shared=False, y_scale=np.ones(4))
    monkeypatch.setattr(exact, "thread_workers", lambda work, min_work: 2)
    threaded = GaussianProcess(sub.kernel, X, Y, sub.fits, shared=False, y_scale=np.ones(4))
    for L1, a1, L2, a2 in zip(threaded._L, threaded._alpha, serial._L, serial._alpha):
        np.testing.assert_array_equal(L1, L2)
        np.testing.assert_array_equal(a1, a2)
    Xq = poses(30, 8)
    np.testing.assert_array_equal(threaded.predict(Xq), serial.predict(Xq))


def test_a_calibrated_posterior_factorises_at_its_first_prediction(monkeypatch):
    """scale_noise (σn² grown) builds the posterior without factorising it; the first prediction does,
    and predicts exactly as a posterior factorised at once. A factor below 1 is factorised (checked) at once."""
    from rbgp_cli.gp.calibration import scale_noise

    sub, X, Y = fitted_on_subset(L=3, n=150, seed=9)
    gp = GaussianProcess(sub.kernel, X, Y, sub.fits, shared=False, y_scale=np.ones(3))
    grown = scale_noise(gp, 4.0)
    assert grown._L is None
    eager = GaussianProcess(sub.kernel, X, Y, grown.fits, shared=False, y_scale=np.ones(3))
    Xq = poses(20, 10)
    m1, s1 = grown.predict(Xq, return_std=True)
    m2, s2 = eager.predict(Xq, return_std=True)
    np.testing.assert_array_equal(m1, m2)
    np.testing.assert_array_equal(s1, s2)
    assert grown._L is not None
    assert scale_noise(gp, 0.5)._L is not None
