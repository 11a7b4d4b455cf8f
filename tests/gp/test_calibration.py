"""Noise calibration by held-out demonstrations: on demonstrations that deviate from a shared field the
factor is large and the calibrated posterior predicts new demonstrations better; on independent
samples it stays near 1; the density rule; exact and sparse GPs rebuilt with the scaled σn."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rbgp_cli.gp.calibration import (
    FACTOR_GRID,
    calibrate_to_demonstrations,
    demonstration_noise_factors,
    scale_noise,
)
from rbgp_cli.gp.exact import GaussianProcess, fit_gp
from rbgp_cli.gp.results import OutputFit
from rbgp_cli.gp.sparse import SparseGP, fit_sparse_gp
from rbgp_cli.kernels import SquaredExponential

KERNEL = SquaredExponential("chordal", 3, 0.7)


def shared_field(X):
    R = Rotation.from_rotvec(X[:, :3]).as_matrix()
    return (R[:, 0, 1] + X[:, 3] + np.sin(2 * X[:, 5]))[:, None]


def demonstrations(n_demos, per_demo, seed, deviation=0.1, noise=0.05):
    """Repetitions of one straight motion through pose space (start and end perturbed), densely
    sampled; each demonstration adds its own smooth deviation (an offset and a slope along the path)
    to the shared field, and white noise."""
    base = np.random.default_rng(0)
    a0, b0, c0, e0 = base.normal(0, 0.5, 3), base.normal(0, 0.8, 3), base.normal(0, 0.3, 3), base.normal(0, 0.5, 3)
    rng = np.random.default_rng(seed)
    Xs, Ys, groups = [], [], []
    t = np.linspace(0, 1, per_demo)[:, None]
    for d in range(n_demos):
        a, b = a0 + rng.normal(0, 0.15, 3), b0 + rng.normal(0, 0.15, 3)
        c, e = c0 + rng.normal(0, 0.1, 3), e0 + rng.normal(0, 0.1, 3)
        X = np.hstack([a + t * b, c + t * e])
        g = deviation * (rng.normal() + rng.normal() * t)
        Xs.append(X)
        Ys.append(shared_field(X) + g + noise * rng.normal(size=(per_demo, 1)))
        groups.append(np.full(per_demo, d))
    return np.vstack(Xs), np.vstack(Ys), np.concatenate(groups)


def fitted(X, Y, seed=0):
    """Hyperparameters from the exact GP on a random 300 points, the posterior on all."""
    idx = np.random.default_rng(seed).choice(len(X), 300, replace=False)
    fit = fit_gp(X[idx], Y[idx], KERNEL, restarts=1, seed=seed, explore_size=0)
    return GaussianProcess(KERNEL, X, Y, fit.fits, shared=False)


@pytest.fixture(scope="module")
def deviating():
    X, Y, groups = demonstrations(14, 120, seed=1, deviation=0.1)
    return fitted(X, Y), groups


@pytest.mark.slow
def test_deviating_demonstrations_get_a_large_factor_and_new_ones_are_predicted_better(deviating):
    gp, groups = deviating
    cal, records = calibrate_to_demonstrations(gp, groups, seed=0)
    rec = records[0]
    # (measured: c_s = 512 inside the grid; the fit took the deviations for signal, σn ≈ the white 0.05)
    assert 2 < rec["subset_factor"] < FACTOR_GRID[-1] and rec["factor"] > rec["subset_factor"]
    # the density rule: c − 1 grows with the training points per subset point
    assert rec["factor"] == pytest.approx(1 + (rec["subset_factor"] - 1) * len(gp.X) / rec["points"])
    assert rec["errors"][FACTOR_GRID.index(rec["subset_factor"])] == min(rec["errors"])
    # new demonstrations of the same kind: the calibrated posterior is closer to the shared field
    Xn, _Yn, _g = demonstrations(6, 60, seed=2)
    truth = shared_field(Xn)
    before = np.sqrt(np.mean((gp.predict(Xn) - truth) ** 2))
    after = np.sqrt(np.mean((cal.predict(Xn) - truth) ** 2))
    assert after < 0.5 * before  # measured: 0.054 against 0.218


@pytest.mark.slow
def test_independent_samples_keep_a_factor_near_one():
    rng = np.random.default_rng(3)
    X, Y, groups = demonstrations(14, 120, seed=1, deviation=0.0)
    groups = rng.permutation(groups)  # no demonstration structure: the same data, groups at random
    gp = fitted(X, Y)
    rec = demonstration_noise_factors(gp, groups)[0]
    assert rec["subset_factor"] <= 2 ** 0.5


@pytest.mark.slow
def test_the_calibrated_gp_is_the_gp_with_the_scaled_noise_and_records_the_fitted_one(deviating):
    gp, groups = deviating
    cal, records = calibrate_to_demonstrations(gp, groups, seed=0)
    f0, f1 = gp.fits[0], cal.fits[0]
    assert f1.values["noise_std"] == pytest.approx(f0.values["noise_std"] * np.sqrt(records[0]["factor"]))
    assert f1.calibration["noise_std_fitted"] == f0.values["noise_std"] and f1.nlml == f0.nlml
    assert OutputFit.from_dict(f1.to_dict()).calibration == f1.calibration
    direct = GaussianProcess(KERNEL, gp.X, gp.Y, [OutputFit(values=f1.values, nlml=0.0)], shared=False)
    Xs = gp.X[::37]
    np.testing.assert_allclose(cal.predict(Xs), direct.predict(Xs), rtol=1e-9, atol=1e-12)
    # seeded
    _again, rec2 = calibrate_to_demonstrations(gp, groups, seed=0)
    assert rec2 == records
    # one demonstration: nothing to hold out
    same, none = calibrate_to_demonstrations(gp, np.zeros(len(gp.X), int))
    assert none is None and same is gp


@pytest.mark.slow
def test_a_sparse_gp_is_calibrated_the_same_way():
    X, Y, groups = demonstrations(10, 100, seed=4)
    sp = fit_sparse_gp(X, Y, KERNEL, inducing=60, restarts=1, seed=0, explore_size=200)
    cal, records = calibrate_to_demonstrations(sp, groups, seed=0)
    assert isinstance(cal, SparseGP) and records[0]["factor"] > 1
    direct = SparseGP(KERNEL, X, Y, sp.Z, cal.fits, shared=False)
    np.testing.assert_allclose(cal.predict(X[::29]), direct.predict(X[::29]), rtol=1e-9, atol=1e-12)
    assert not np.allclose(cal.predict(X[::29]), sp.predict(X[::29]))


@pytest.mark.slow
def test_a_further_noise_scale_multiplies_the_calibrated_variance_and_moves_the_mean_toward_the_prior(deviating):
    gp, groups = deviating
    cal, records = calibrate_to_demonstrations(gp, groups, seed=0)
    assert scale_noise(cal, 1.0) is cal
    more = scale_noise(cal, 64.0)
    f1, f2 = cal.fits[0], more.fits[0]
    assert f2.values["noise_std"] == pytest.approx(f1.values["noise_std"] * 8.0)
    assert f2.calibration["extra_factor"] == 64.0 and f2.calibration["factor"] == records[0]["factor"]
    assert f2.calibration["noise_std_fitted"] == gp.fits[0].values["noise_std"]
    assert OutputFit.from_dict(f2.to_dict()).calibration == f2.calibration
    # at the training inputs the mean K (K + c σn² I)⁻¹ y shrinks in every eigendirection of K as c
    # grows, toward the prior mean (zero); the band widens everywhere
    norms = [np.linalg.norm(scale_noise(cal, f).predict(gp.X)) for f in (1.0, 64.0, 1e4, 1e6)]
    assert all(a > b for a, b in zip(norms, norms[1:])) and norms[-1] < 0.01 * norms[0]
    Xs = gp.X[::23]
    _, s1 = cal.predict(Xs, return_std=True)
    _, s2 = more.predict(Xs, return_std=True)
    assert np.all(s2 >= s1 - 1e-12) and np.any(s2 > s1)
    # without a calibration record: one is made with factor 1 and the fitted σn
    plain = scale_noise(gp, 4.0)
    assert plain.fits[0].calibration == {"factor": 1.0, "noise_std_fitted": gp.fits[0].values["noise_std"],
                                         "extra_factor": 4.0}
    with pytest.raises(ValueError):
        scale_noise(gp, 0.0)


@pytest.mark.parametrize("folds", [None, 3])
def test_held_out_errors_equal_explicit_refits_of_the_other_demonstrations(folds):
    """The partitioned inverse (one eigendecomposition for every block and factor) gives the held-out
    errors of explicit predictions K_ht (K_tt + (c σn² + j) I)⁻¹ y_t from the rows of the other
    demonstrations, for each demonstration left out (folds None) and for folds of them."""
    X, Y, groups = demonstrations(8, 40, seed=2)
    gp = fitted(X, Y)
    rec = demonstration_noise_factors(gp, groups, points=250, folds=folds)[0]
    idx = np.sort(np.random.default_rng(np.random.SeedSequence([0, 11])).permutation(len(X))[:250])
    Xs, ys, g = X[idx], Y[idx, 0] / gp.y_scale[0], groups[idx]
    names = np.unique(g)
    if folds is None:
        held = [g == nm for nm in names]
    else:
        rng = np.random.default_rng(np.random.SeedSequence([0, 11]))
        rng.permutation(len(X))  # the subset's draw, then the deal of the demonstrations
        fold_of_name = np.empty(len(names), dtype=int)
        fold_of_name[rng.permutation(len(names))] = np.arange(len(names)) % folds
        fold = fold_of_name[np.searchsorted(names, g)]
        held = [fold == j for j in range(folds)]
    assert rec["folds"] == len(held)
    fit = gp.fits[0]
    K, _ = KERNEL.gram(KERNEL.precompute(Xs), fit.values)
    s2 = fit.values["noise_std"] ** 2
    for c, err in zip(rec["grid"][::6], rec["errors"][::6]):
        sse = 0.0
        for h in held:
            t = ~h
            mean = K[np.ix_(h, t)] @ np.linalg.solve(K[np.ix_(t, t)] + (c * s2 + fit.jitter) * np.eye(t.sum()), ys[t])
            sse += float(np.sum((ys[h] - mean) ** 2))
        assert err == pytest.approx(sse / len(ys), rel=1e-8)


def test_held_out_errors_for_blocks_of_any_size_and_several_outputs():
    """The blocks' B_hh from the pairs of rows (one product for every factor) give the partitioned
    inverse's residuals (B_hh)⁻¹ α_h of an explicit C⁻¹, for blocks of 1, 2 and uneven sizes, in any
    order of rows, with two outputs at once."""
    from rbgp_cli.gp.calibration import _held_out_errors

    rng = np.random.default_rng(5)
    A = rng.normal(size=(23, 23))
    K = A @ A.T / 23
    y = rng.normal(size=(23, 2))
    rows = rng.permutation(23)
    blocks = [np.sort(rows[:1]), np.sort(rows[1:3]), np.sort(rows[3:10]), np.sort(rows[10:])]
    grid = np.array([1.0, 3.0, 40.0])
    got = _held_out_errors(K, y, 0.05, 1e-9, blocks, grid)
    for c, err in zip(grid, got):
        B = np.linalg.inv(K + (c * 0.05 + 1e-9) * np.eye(23))
        alpha = B @ y
        want = sum(float(np.sum(np.linalg.solve(B[np.ix_(h, h)], alpha[h]) ** 2)) for h in blocks)
        assert err == pytest.approx(want, rel=1e-9)
