"""``fit_gp(..., beside=f)`` (issue 35): the caller's own work runs once in this process, while the worker
processes fit the outputs when there are workers; the fit is the same with or without it, and an error in it
ends the workers and reaches the caller."""

from __future__ import annotations

import multiprocessing

import numpy as np
import pytest

from rbgp_cli.gp.exact import fit_gp
from rbgp_cli.kernels import SquaredExponential
from tests.gp.test_gp import poses, smooth_outputs


def _data():
    X = poses(90, 11)
    return X, smooth_outputs(X, np.random.default_rng(11))[:, :3]


@pytest.mark.slow
@pytest.mark.parametrize("jobs, hyper_points", [(2, None), (2, 60), (1, None), (1, 60)])
def test_beside_runs_once_and_changes_nothing(jobs, hyper_points):
    X, Y = _data()
    k = SquaredExponential("chordal")
    calls = []

    def beside():
        # with workers: they are alive while it runs (it runs beside their fits, not after them)
        calls.append(len(multiprocessing.active_children()))

    gp = fit_gp(X, Y, k, restarts=1, seed=2, jobs=jobs, hyper_points=hyper_points, beside=beside)
    plain = fit_gp(X, Y, k, restarts=1, seed=2, jobs=jobs, hyper_points=hyper_points)
    assert len(calls) == 1
    if jobs > 1:
        assert calls[0] >= 1
    assert [f.values for f in gp.fits] == [f.values for f in plain.fits]
    Xq = poses(10, 12)
    np.testing.assert_array_equal(gp.predict(Xq), plain.predict(Xq))


def test_an_error_beside_the_workers_ends_them_and_propagates():
    X, Y = _data()

    def beside():
        raise ValueError("beside failed")

    with pytest.raises(ValueError, match="beside failed"):
        fit_gp(X, Y, SquaredExponential("chordal"), restarts=1, seed=2, jobs=2, beside=beside)
    for child in multiprocessing.active_children():  # joins the ended ones
        child.join(timeout=5)
    assert not multiprocessing.active_children()


@pytest.mark.slow
@pytest.mark.parametrize("jobs, hyper_points", [(2, None), (1, 60)])
def test_a_posterior_without_factors_predicts_the_same_numbers(jobs, hyper_points):
    """``fit_gp(..., factorise=False)`` (rbgp train, which replaces the posterior by the calibrated one):
    the same fits, no factors made or sent from the workers, and at the first prediction the factors and
    the predictions of the posterior that had them."""
    X, Y = _data()
    k = SquaredExponential("chordal")
    lazy = fit_gp(X, Y, k, restarts=1, seed=2, jobs=jobs, hyper_points=hyper_points, factorise=False)
    eager = fit_gp(X, Y, k, restarts=1, seed=2, jobs=jobs, hyper_points=hyper_points)
    assert lazy._L is None and eager._L is not None
    assert [(f.values, f.jitter, f.rcond) for f in lazy.fits] == [(f.values, f.jitter, f.rcond) for f in eager.fits]
    Xq = poses(10, 12)
    np.testing.assert_array_equal(lazy.predict(Xq), eager.predict(Xq))
    for a, b in zip(lazy._L, eager._L):
        np.testing.assert_array_equal(a, b)
