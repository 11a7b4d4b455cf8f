"""Exact GP: NLML gradient, textbook formulas, optimum, safeguards, determinism, chunked prediction."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rbgp_cli.errors import RbgpRuntimeError
from rbgp_cli.gp.exact import GaussianProcess, fit_gp
from rbgp_cli.gp.likelihood import INFEASIBLE_NLML, nlml_and_gradient
from rbgp_cli.gp.results import OutputFit
from rbgp_cli.kernels import DotProduct, SquaredExponential


def poses(n, seed):
    rng = np.random.default_rng(seed)
    return np.hstack([Rotation.random(n, random_state=seed).as_rotvec(), rng.normal(0, 0.3, (n, 3))])


def smooth_outputs(X, rng, noise=0.02):
    q = Rotation.from_rotvec(X[:, :3]).as_quat()
    q *= np.sign(q[:, 3:4] + 1e-300)
    Y = np.stack([q[:, 0] + 0.5 * X[:, 3], q[:, 1] * X[:, 4], 0.3 * q[:, 2], np.sin(2 * X[:, 3]), X[:, 4] ** 2, np.cos(X[:, 5])], 1)
    return Y + noise * rng.normal(size=Y.shape)


def assert_stationary_or_at_bounds(gp, kernel, X, Y):
    """∂NLML/∂log θ ≈ 0 on all training points for every free hyperparameter not at a bound."""
    pre = kernel.precompute(X)
    for l, fit in enumerate(gp.fits):
        y = Y / gp.y_scale if gp.shared else Y[:, l]
        _, g = nlml_and_gradient(kernel, pre, fit.values, y, fit.free)
        for name, gi in zip(fit.free, g):
            if name not in fit.at_bounds:
                assert abs(gi) < 1e-2 * max(1.0, abs(fit.nlml)) ** 0.5, (name, gi)


KERNELS = [
    ("arc", lambda: SquaredExponential("arc", 3, 0.7)),
    ("arc-learn-rho", lambda: SquaredExponential("arc", 3, 0.7, learn_rho=True)),
    ("chordal", lambda: SquaredExponential("chordal", 3, 0.6, learn_rho=True)),
    ("dot", lambda: DotProduct(3, 0.5, learn_rho=True)),
]


@pytest.mark.parametrize("name,make", KERNELS)
@pytest.mark.parametrize("shared", [False, True])
def test_nlml_gradient_matches_finite_differences(name, make, shared):
    k = make()
    X = poses(40, 1)
    Y = smooth_outputs(X, np.random.default_rng(2))
    y = Y / Y.std(0) if shared else Y[:, 0]
    vals = {"signal_std": 1.1, "length_scale": 0.6, "rho_rot": k.rho_rot, "noise_std": 0.3}
    names = [n for n in k.names if n != "rho_rot" or k.learn_rho] + ["noise_std"]
    pre = k.precompute(X)
    f, g = nlml_and_gradient(k, pre, vals, y, names)
    assert f < INFEASIBLE_NLML
    for i, nm in enumerate(names):
        h = 1e-5
        up, dn = dict(vals), dict(vals)
        up[nm] *= math.exp(h)
        dn[nm] *= math.exp(-h)
        fd = (nlml_and_gradient(k, pre, up, y, [])[0] - nlml_and_gradient(k, pre, dn, y, [])[0]) / (2 * h)
        assert g[i] == pytest.approx(fd, rel=1e-5, abs=1e-6), nm


def test_nlml_and_prediction_match_textbook_formulas():
    """R&W eq. 2.25, 2.26, 2.30 computed directly with dense solves on a small case."""
    rng = np.random.default_rng(0)
    X = poses(9, 4)
    y = rng.normal(size=9)
    k = SquaredExponential("chordal", 3, 0.7)
    vals = {"signal_std": 0.8, "length_scale": 0.9, "rho_rot": 0.7, "noise_std": 0.2}
    K = k(X, None, vals)
    C = K + 0.04 * np.eye(9)
    nlml_ref = 0.5 * y @ np.linalg.solve(C, y) + 0.5 * np.linalg.slogdet(C)[1] + 4.5 * math.log(2 * math.pi)
    f, _ = nlml_and_gradient(k, k.precompute(X), vals, y, [])
    assert f == pytest.approx(nlml_ref, rel=1e-12)

    fit = OutputFit(values=vals, nlml=f)
    gp = GaussianProcess(k, X, y[:, None], [fit], shared=False)
    Xs = poses(5, 5)
    Ks = k(Xs, X, vals)
    mean_ref = Ks @ np.linalg.solve(C, y)
    var_ref = 0.64 - np.einsum("ij,ji->i", Ks, np.linalg.solve(C, Ks.T))
    mean, std = gp.predict(Xs, return_std=True)
    np.testing.assert_allclose(mean[:, 0], mean_ref, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(std[:, 0] ** 2, var_ref, rtol=1e-9, atol=1e-12)
    _, std_noisy = gp.predict(Xs, return_std=True, noisy=True)
    np.testing.assert_allclose(std_noisy[:, 0] ** 2, var_ref + 0.04, rtol=1e-9)


@pytest.mark.parametrize("shared", [False, True])
def test_fit_ends_at_a_stationary_point_or_a_bound(shared):
    X = poses(60, 3)
    Y = smooth_outputs(X, np.random.default_rng(3))[:, :3]
    k = SquaredExponential("chordal", 3, 0.7, learn_rho=True)
    gp = fit_gp(X, Y, k, restarts=2, seed=1, shared=shared)
    assert_stationary_or_at_bounds(gp, k, X, Y)
    for fit in gp.fits:
        assert fit.positive_definite and fit.jitter == 0.0


def test_fit_is_bit_identical_for_the_same_seed():
    X = poses(50, 8)
    Y = smooth_outputs(X, np.random.default_rng(8))
    a = fit_gp(X, Y, SquaredExponential("arc", 3, 0.7), restarts=3, seed=5)
    b = fit_gp(X, Y, SquaredExponential("arc", 3, 0.7), restarts=3, seed=5)
    for fa, fb in zip(a.fits, b.fits):
        assert fa.values == fb.values  # exact equality, not approx
        assert fa.nlml == fb.nlml


def test_fixed_hyperparameters_stay_fixed():
    X = poses(30, 9)
    Y = smooth_outputs(X, np.random.default_rng(9))[:, :2]
    gp = fit_gp(X, Y, SquaredExponential("arc", 3, 0.7), noise=1.0, fixed={"length_scale": 0.5}, restarts=2)
    for f in gp.fits:
        assert f.values["noise_std"] == 1.0 and f.values["length_scale"] == 0.5
        assert f.free == ["signal_std"]


def vector_field(quat, pos):
    """A known smooth velocity field on SE(3): ω = R e_x (rad/s), v = −t + 0.2 R e_z (m/s)."""
    R = Rotation.from_quat(quat).as_matrix()
    return np.hstack([R[:, :, 0], -pos + 0.2 * R[:, :, 2]])


@pytest.mark.parametrize("representation", ["axis-angle", "euler", "quaternion"])
@pytest.mark.slow
def test_learns_a_smooth_vector_field_to_held_out_accuracy(representation):
    """Held-out RMSE of every output below 0.15 × its standard deviation (stated bound), for each
    representation with its own kernel (docs/method.md §6), on poses spread around a centre pose."""
    from rbgp_cli.dynamics.model import make_kernel
    from rbgp_cli.dynamics.representations import make_representation

    rng = np.random.default_rng(21)
    n = 300
    centre = Rotation.from_rotvec([0.3, -0.4, 0.5])
    rot = Rotation.from_rotvec(rng.normal(0, 0.5, (n, 3))) * centre
    quat, pos = rot.as_quat(), rng.normal(0, 0.3, (n, 3))
    Y = vector_field(quat, pos) + 0.005 * rng.normal(size=(n, 6))
    rep = make_representation(representation)
    rep.prepare([])
    X = rep.state_from_pose(quat, pos)
    gp = fit_gp(X[:240], Y[:240], make_kernel(rep, "se", 0.7), restarts=1, seed=0)
    rmse = np.sqrt(np.mean((gp.predict(X[240:]) - Y[240:]) ** 2, axis=0))
    assert np.all(rmse < 0.15 * Y.std(axis=0)), rmse / Y.std(axis=0)


def test_prediction_in_chunks_equals_prediction_at_once():
    X = poses(40, 12)
    Y = smooth_outputs(X, np.random.default_rng(12))
    gp = fit_gp(X, Y, SquaredExponential("arc", 3, 0.7), restarts=1)
    Xs = poses(1000, 13)
    m1, s1 = gp.predict(Xs, return_std=True)
    m2, s2 = gp.predict(Xs, return_std=True, chunk_elements=40 * 7)  # 7 rows per chunk
    np.testing.assert_allclose(m1, m2, rtol=1e-10, atol=1e-12)  # gemm vs gemv round-off
    np.testing.assert_allclose(s1, s2, rtol=1e-10, atol=1e-12)
    assert np.all(s1 >= 0) and np.all(np.isfinite(m1))


@pytest.mark.parametrize("shared", [False, True])
def test_prediction_on_threads_equals_serial_prediction(monkeypatch, shared):
    """Large predictions run in row chunks on a thread pool: same numbers as one serial pass,
    every row written (the output arrays start uninitialised), clipped variances counted."""
    import rbgp_cli.gp.exact as exact

    X = poses(60, 14)
    Y = smooth_outputs(X, np.random.default_rng(14))
    gp = fit_gp(X, Y, SquaredExponential("arc", 3, 0.7), restarts=1, shared=shared)
    Xs = poses(2001, 15)
    monkeypatch.setattr(exact, "PARALLEL_PREDICT_MIN", 10**12)
    m1, s1 = gp.predict(Xs, return_std=True, noisy=True)
    c1 = gp.last_clipped
    monkeypatch.setattr(exact, "PARALLEL_PREDICT_MIN", 0)
    monkeypatch.setattr(exact, "_prediction_workers", lambda work: 3)  # 3 workers even on 1 core
    m2, s2 = gp.predict(Xs, return_std=True, noisy=True, chunk_elements=60 * 101)
    np.testing.assert_allclose(m2, m1, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(s2, s1, rtol=1e-10, atol=1e-12)
    assert gp.last_clipped == c1
    np.testing.assert_allclose(gp.predict(Xs[:5]), m1[:5], rtol=1e-10, atol=1e-12)


def test_indefinite_kernel_points_are_infeasible_not_errors():
    """On the 8-rotation counterexample with tiny noise, long length-scales make K + σn²I indefinite:
    the NLML reports the point as infeasible instead of raising, and the fit still returns a model
    whose covariance passed Cholesky."""
    ang = np.arange(8) * math.pi / 4
    r = Rotation.from_rotvec(ang[:, None] * np.array([0, 0, 1.0])).as_rotvec()
    X = np.hstack([r, np.zeros((8, 3))])
    y = np.sin(ang)
    k = SquaredExponential("arc", 3, 0.99)
    vals = {"signal_std": 1.0, "length_scale": 2.0, "rho_rot": 0.99, "noise_std": 1e-3}
    f, g = nlml_and_gradient(k, k.precompute(X), vals, y, ["length_scale"])
    assert f == INFEASIBLE_NLML and np.all(g == 0)
    gp = fit_gp(X, y, k, noise=1e-3, restarts=3, seed=0)
    fit = gp.fits[0]
    assert fit.n_infeasible >= 0 and np.isfinite(fit.nlml) and fit.rcond >= 1e-12
    # the accepted model predicts finite, bounded values everywhere on the circle
    ang_s = np.linspace(0, 2 * math.pi, 97)
    Xs = np.hstack([Rotation.from_rotvec(ang_s[:, None] * np.array([0, 0, 1.0])).as_rotvec(), np.zeros((97, 3))])
    mean, std = gp.predict(Xs, return_std=True)
    assert np.all(np.isfinite(mean)) and np.max(np.abs(mean)) < 10


def test_no_feasible_start_raises_a_runtime_error():
    ang = np.arange(8) * math.pi / 4
    X = np.hstack([Rotation.from_rotvec(ang[:, None] * np.array([0, 0, 1.0])).as_rotvec(), np.zeros((8, 3))])
    k = SquaredExponential("arc", 3, 0.99)
    with pytest.raises(RbgpRuntimeError, match="positive definite"):
        fit_gp(X, np.sin(ang), k, noise=1e-9, fixed={"length_scale": 4.0, "signal_std": 1.0}, restarts=1)


@pytest.mark.parametrize("shared", [False, True])
def test_constant_and_zero_outputs_give_sane_hyperparameters(shared):
    """A constant output (std ~1e-16 from round-off) or an all-zero one must not drive the scales to
    1e13 (seen with noiseless synthetic demonstrations before the RMS scaling)."""
    X = poses(60, 14)
    rng = np.random.default_rng(14)
    Y = np.column_stack([np.full(60, 0.3) + 1e-16 * rng.normal(size=60), np.zeros(60), np.sin(X[:, 3])])
    gp = fit_gp(X, Y, SquaredExponential("chordal", 3, 0.7), restarts=2, seed=0, shared=shared)
    for fit in gp.fits:
        assert fit.values["signal_std"] < 1e3 and fit.values["noise_std"] < 1e3
    mean, std = gp.predict(poses(20, 15), return_std=True)
    assert np.all(np.isfinite(mean)) and np.max(np.abs(mean)) < 2 and np.max(std) < 2


@pytest.mark.slow
def test_indefinite_kernel_fit_never_explodes_away_from_the_data():
    """Regression: 80 uniformly random rotations, the paper's arc kernel, per-output fits. Cholesky and
    rcond passed but λ_min(K + σn²I) was ~1e-12 σf²: held-out RMSE 25–320 instead of ~0.1. The noise
    margin (λ_min >= NOISE_MARGIN σn², refit when missed) keeps every output bounded."""
    from rbgp_cli.gp.likelihood import NOISE_MARGIN

    def data(n, seed):
        rng = np.random.default_rng(seed)
        rot = Rotation.random(n, random_state=seed)
        t = rng.normal(0, 0.3, (n, 3))
        R = rot.as_matrix()
        Y = np.hstack([-0.8 * rot.as_rotvec() / np.maximum(np.linalg.norm(rot.as_rotvec(), axis=1, keepdims=True), 1e-9)
                       * np.sin(np.linalg.norm(rot.as_rotvec(), axis=1, keepdims=True)), -t + 0.2 * R[:, :, 2]])
        return np.hstack([rot.as_rotvec(), t]), Y + 0.01 * rng.normal(size=Y.shape)

    X, Y = data(80, 0)
    Xt, Yt = data(500, 1)
    k = SquaredExponential("arc", 3, 0.7)
    gp = fit_gp(X, Y, k, restarts=3, seed=0)
    rmse = np.sqrt(np.mean((gp.predict(Xt) - Yt) ** 2, axis=0))
    assert np.all(rmse < 0.5 * np.sqrt(np.mean(Yt**2, axis=0)) + 0.05), rmse
    for fit in gp.fits:
        K = k(X, None, fit.values)
        lam = np.linalg.eigvalsh(K + fit.values["noise_std"] ** 2 * np.eye(80)).min()
        assert lam >= NOISE_MARGIN * fit.values["noise_std"] ** 2 * (1 - 1e-9)
    assert any(f.guarded for f in gp.fits)  # this data does trigger the safeguard


@pytest.mark.parametrize("shared", [False, True])
@pytest.mark.slow
def test_subsample_exploration_reaches_the_optimum_of_full_size_restarts(shared):
    """Above 2·explore_size points the starts run on a subsample first; on all points the best
    subsample optimum (and any other basin) is polished by quasi-Newton steps: same optimum (NLML,
    hyperparameters) as three full-size L-BFGS-B starts, far fewer full-size evaluations, the
    exploration recorded, bit-identical per seed."""
    X = poses(260, 21)
    Y = smooth_outputs(X, np.random.default_rng(21))[:, [0, 2, 3]]
    kernel = SquaredExponential("chordal", 3, 0.7)
    full = fit_gp(X, Y, kernel, restarts=3, seed=3, shared=shared, explore_size=0)
    sub = fit_gp(X, Y, kernel, restarts=3, seed=3, shared=shared, explore_size=90)
    again = fit_gp(X, Y, kernel, restarts=3, seed=3, shared=shared, explore_size=90)
    small = fit_gp(X[:180], Y[:180], kernel, restarts=3, seed=3, shared=shared, explore_size=90)
    assert all(f.subsample is None for f in full.fits + small.fits)  # off, and 180 <= 2·90
    for f_full, f_sub, f_again in zip(full.fits, sub.fits, again.fits):
        assert f_sub.subsample["size"] == 90 and f_sub.subsample["evaluations"] > 0
        kinds = [s["kind"] for s in f_sub.starts]
        assert kinds[:4] == ["data-driven (subsample of 90)", "random (subsample of 90)",
                             "random (subsample of 90)", "polish (all points)"]
        assert all(k == "polish (all points)" for k in kinds[4:])
        assert all(s["status"] == "converged" for s in f_sub.starts[3:])
        assert f_sub.nlml == pytest.approx(f_full.nlml, abs=1e-3)
        for nm in f_sub.free:
            assert f_sub.values[nm] == pytest.approx(f_full.values[nm], rel=1e-2), nm
        assert f_again.values == f_sub.values
    assert sum(f.n_evaluations for f in sub.fits) < 0.5 * sum(f.n_evaluations for f in full.fits)
    assert_stationary_or_at_bounds(sub, kernel, X, Y)  # an optimum on all points, not the subsample's
    with pytest.raises(ValueError, match="explore_size"):
        fit_gp(X, Y, kernel, explore_size=-1)


def test_subsample_exploration_polishes_each_new_basin(monkeypatch):
    """Every basin the starts reached on the subsample is polished on all points, best first (one
    polish per basin, even from far away); the best result is kept."""
    import rbgp_cli.gp.optimise as optimise

    X = poses(200, 22)
    Y = smooth_outputs(X, np.random.default_rng(22))[:, :1]
    kernel = SquaredExponential("chordal", 3, 0.7)
    real_fit_one = optimise.fit_one
    # per start (data-driven, random, random, random): the third is the data-driven basin again,
    # the second and fourth are one new basin (0.05 apart < DISTINCT_LOG)
    fake = [np.log([0.5, 0.8, 0.1]), np.log([0.3, 3.0, 0.05]), np.log([0.5, 0.8, 0.1]) + 0.05,
            np.log([0.3, 3.0, 0.05]) + 0.05]

    def fit_one(kernel_, pre, y, spec, free, restarts, rng, max_iter, margin=0.0, theta_starts=None, kinds=None,
                **kw):
        if theta_starts is None:  # the exploration on the subsample
            best, records, counter, values_of, _ = real_fit_one(kernel_, pre, y, spec, free, restarts, rng, max_iter,
                                                                **kw)
            return best, records, counter, values_of, [(t, float(i)) for i, t in enumerate(fake)]
        return real_fit_one(kernel_, pre, y, spec, free, restarts, rng, max_iter, margin, theta_starts, kinds, **kw)

    monkeypatch.setattr(optimise, "fit_one", fit_one)  # looked up there by fit_target
    gp = fit_gp(X, Y, kernel, restarts=4, seed=0, explore_size=60)
    full_runs = [s for s in gp.fits[0].starts if "all points" in s["kind"]]
    assert [s["kind"] for s in full_runs] == ["polish (all points)", "polish (all points)"]
    assert full_runs[0]["status"] == "converged"
    assert full_runs[1]["status"] in ("converged", "joined an earlier basin")
    assert full_runs[0]["start"]["length_scale"] == pytest.approx(0.8)
    assert full_runs[1]["start"]["length_scale"] == pytest.approx(3.0)
    assert gp.fits[0].nlml == pytest.approx(min(s["nlml"] for s in full_runs))
