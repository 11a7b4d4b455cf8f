"""Sparse GP (SGPR): bound gradient by finite differences, the bound against the exact NLML,
predictions against the exact GP, stored factors, seeded determinism."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rbgp_cli.errors import RbgpRuntimeError
from rbgp_cli.gp.exact import GaussianProcess, fit_gp
from rbgp_cli.gp.likelihood import nlml_and_gradient
from rbgp_cli.gp.results import OutputFit
from rbgp_cli.gp.sparse import (
    RowBlocks,
    SparseGP,
    SparseOutputFit,
    fit_sparse_gp,
    inducing_embedding,
    select_inducing,
    sparse_bound_and_gradient,
)
from rbgp_cli.kernels import SquaredExponential


def poses(n, seed, time_column=False):
    rng = np.random.default_rng(seed)
    X = np.hstack([Rotation.random(n, random_state=seed).as_rotvec(), rng.normal(0, 0.3, (n, 3))])
    if time_column:
        X = np.hstack([X, rng.uniform(0, 1, (n, 1))])
    return X


def field(X, rng=None, noise=0.03):
    R = Rotation.from_rotvec(X[:, :3]).as_matrix()
    Y = np.stack([R[:, 0, 1] + X[:, 3], R[:, 2, 2] * X[:, 4], np.sin(2 * X[:, 5])], 1)
    return Y if rng is None else Y + noise * rng.normal(size=Y.shape)


VALUES = {"signal_std": 1.1, "length_scale": 0.8, "rho_rot": 0.6, "noise_std": 0.3, "time_scale": 0.5}

KERNELS = [
    ("chordal-learn-rho", lambda: SquaredExponential("chordal", 3, 0.6, learn_rho=True), False),
    ("arc", lambda: SquaredExponential("arc", 3, 0.6), False),
    ("chordal-time", lambda: SquaredExponential("chordal", 3, 0.6, learn_rho=True, time_dims=1), True),
]


def _names(k):
    return [nm for nm in k.names if nm != "rho_rot" or k.learn_rho] + ["noise_std"]


@pytest.mark.parametrize("name,make,time_column", KERNELS)
@pytest.mark.parametrize("shared", [False, True])
def test_bound_gradient_matches_finite_differences(name, make, time_column, shared):
    k = make()
    X = poses(60, 1, time_column)
    Y = field(X, np.random.default_rng(2))
    y = Y if shared else Y[:, 0]
    Z = X[select_inducing(X, 15, k, seed=0)]
    blocks = RowBlocks(k, X, Z, block_rows=7)  # several blocks, the last one short
    pre_mm = k.precompute(Z)
    names = _names(k)
    f, g = sparse_bound_and_gradient(k, blocks, pre_mm, VALUES, y, names)
    assert np.isfinite(f)
    for i, nm in enumerate(names):
        h = 1e-5
        up, dn = dict(VALUES), dict(VALUES)
        up[nm] *= math.exp(h)
        dn[nm] *= math.exp(-h)
        fd = (sparse_bound_and_gradient(k, blocks, pre_mm, up, y, [])[0]
              - sparse_bound_and_gradient(k, blocks, pre_mm, dn, y, [])[0]) / (2 * h)
        assert g[i] == pytest.approx(fd, rel=1e-6, abs=1e-6), nm


@pytest.mark.parametrize("name,make,time_column", KERNELS)
def test_bound_equals_exact_nlml_when_inducing_set_is_training_set(name, make, time_column):
    k = make()
    X = poses(50, 3, time_column)
    y = field(X, np.random.default_rng(4))[:, 1]
    names = _names(k)
    f_s, g_s = sparse_bound_and_gradient(k, RowBlocks(k, X, X, block_rows=16), k.precompute(X), VALUES, y, names,
                                         jitter=1e-12)
    f_e, g_e = nlml_and_gradient(k, k.precompute(X), VALUES, y, names)
    assert f_s == pytest.approx(f_e, rel=1e-9)
    np.testing.assert_allclose(g_s, g_e, rtol=1e-7, atol=1e-7)


def test_bound_is_an_upper_bound_on_the_nlml_and_tightens_with_more_inducing_inputs():
    k = SquaredExponential("chordal", 3, 0.7)
    X = poses(120, 5)
    y = field(X, np.random.default_rng(6))[:, 0]
    vals = {"signal_std": 1.0, "length_scale": 0.6, "rho_rot": 0.7, "noise_std": 0.1}
    exact, _ = nlml_and_gradient(k, k.precompute(X), vals, y, [])
    order = select_inducing(X, 120, k, seed=1, method="farthest")
    bounds = []
    for M in (5, 20, 60, 120):
        Z = X[np.sort(order[:M])] if M < 120 else X
        bounds.append(sparse_bound_and_gradient(k, RowBlocks(k, X, Z), k.precompute(Z), vals, y, [], jitter=1e-12)[0])
    assert all(b >= exact - 1e-6 for b in bounds)
    assert bounds[-1] == pytest.approx(exact, rel=1e-9)
    assert bounds[0] > bounds[1] > bounds[2] > exact  # nested sets: the bound only improves


@pytest.mark.parametrize("shared", [False, True])
def test_predictions_equal_the_exact_gp_when_inducing_set_is_training_set(shared):
    k = SquaredExponential("chordal", 3, 0.7)
    X = poses(70, 7)
    Y = field(X, np.random.default_rng(8))
    vals = {"signal_std": 1.1, "length_scale": 0.8, "rho_rot": 0.7, "noise_std": 0.2}
    count = 1 if shared else 3
    scale = np.sqrt(np.mean(Y**2, 0)) if shared else None
    exact = GaussianProcess(k, X, Y, [OutputFit(values=dict(vals), nlml=0.0) for _ in range(count)], shared, scale)
    sparse = SparseGP(k, X, Y, X, [SparseOutputFit(values=dict(vals), nlml=0.0, kmm_jitter=1e-13) for _ in range(count)],
                      shared, scale)
    Xs = poses(40, 9)
    for noisy in (False, True):
        m_e, s_e = exact.predict(Xs, return_std=True, noisy=noisy)
        m_s, s_s = sparse.predict(Xs, return_std=True, noisy=noisy)
        np.testing.assert_allclose(m_s, m_e, atol=1e-8)
        np.testing.assert_allclose(s_s, s_e, atol=1e-7)
    np.testing.assert_allclose(sparse.predict(Xs), sparse.predict(Xs, chunk_elements=70 * 3), atol=1e-12)


def test_stored_factors_rebuild_the_same_posterior_and_are_checked():
    k = SquaredExponential("chordal", 3, 0.7)
    X = poses(300, 10)
    Y = field(X, np.random.default_rng(11))
    gp = fit_sparse_gp(X, Y, k, inducing=40, restarts=1, seed=3)
    Xs = poses(25, 12)
    again = SparseGP(k, X, Y, gp.Z, gp.fits, gp.shared, gp.y_scale, stats=gp.stats)
    recomputed = SparseGP(k, X, Y, gp.Z, gp.fits, gp.shared, gp.y_scale)
    np.testing.assert_array_equal(again.predict(Xs), gp.predict(Xs))
    np.testing.assert_allclose(recomputed.predict(Xs, return_std=True)[1], gp.predict(Xs, return_std=True)[1], atol=1e-9)
    np.testing.assert_allclose(recomputed.predict(Xs), gp.predict(Xs), atol=1e-8)
    bad = [(Lm.copy(), LB, c) for Lm, LB, c in gp.stats]
    bad[1][0][5, 3] += 1e-3  # a factor that no longer matches k(Z, Z)
    with pytest.raises(RbgpRuntimeError):
        SparseGP(k, X, Y, gp.Z, gp.fits, gp.shared, gp.y_scale, stats=bad)


@pytest.mark.slow
def test_fit_is_seeded_and_learns_the_field_from_all_points():
    k = SquaredExponential("chordal", 3, 0.7)
    X = poses(1500, 13)
    Y = field(X, np.random.default_rng(14))
    a = fit_sparse_gp(X, Y, k, inducing=150, restarts=2, seed=5, explore_size=200)
    b = fit_sparse_gp(X, Y, k, inducing=150, restarts=2, seed=5, explore_size=200)
    np.testing.assert_array_equal(a.Z, b.Z)
    assert [f.values for f in a.fits] == [f.values for f in b.fits]
    assert all(f.stages and f.stages[-1]["points"] <= 1500 for f in a.fits)
    Xs = poses(400, 15)
    truth = field(Xs)
    rmse = np.sqrt(np.mean((a.predict(Xs) - truth) ** 2, 0))
    assert np.all(rmse < 0.3 * np.sqrt(np.mean(truth**2, 0)))  # far better than predicting zero
    # the same options on a 150-point subsample, exact: the sparse model on all points is better
    idx = np.random.default_rng(0).choice(1500, 150, replace=False)
    ex = fit_gp(X[idx], Y[idx], k, restarts=2, seed=5)
    assert np.mean(rmse) < np.mean(np.sqrt(np.mean((ex.predict(Xs) - truth) ** 2, 0)))
    m, s = a.predict(Xs, return_std=True)
    assert np.all(s > 0) and np.all(np.isfinite(s))


@pytest.mark.slow
def test_by_default_the_hyperparameters_are_the_exact_gps_on_a_subset_and_the_posterior_uses_all_points():
    """hyper="exact" (the default): the hyperparameters are exactly those fit_gp finds on the same random
    subset (HYPER_EXACT_POINTS of the rows, drawn as the bound's subsets are), never the bound's; the
    inducing poses are farthest-point ones; the posterior is the one recomputed from all of X, Y."""
    from rbgp_cli.gp.sparse import HYPER_EXACT_POINTS

    k = SquaredExponential("chordal", 3, 0.7)
    X = poses(2600, 41)
    Y = field(X, np.random.default_rng(42))[:, :2]
    gp = fit_sparse_gp(X, Y, k, inducing=40, restarts=2, seed=1, explore_size=200)
    perm = np.random.default_rng(np.random.SeedSequence([1, 3])).permutation(len(X))
    idx = np.sort(perm[:HYPER_EXACT_POINTS])
    ex = fit_gp(X[idx], Y[idx], k, restarts=2, seed=1, explore_size=200)
    assert [f.values for f in gp.fits] == [f.values for f in ex.fits]
    for f in gp.fits:
        assert [st["objective"] for st in f.stages] == ["exact NLML"] and f.stages[0]["points"] == HYPER_EXACT_POINTS
    np.testing.assert_array_equal(gp.Z, X[select_inducing(X, 40, k, seed=1, method="farthest")])
    again = SparseGP(k, X, Y, gp.Z, gp.fits, shared=False)
    Xs = poses(100, 43)
    np.testing.assert_allclose(gp.predict(Xs), again.predict(Xs), rtol=1e-9, atol=1e-12)
    with pytest.raises(ValueError, match="hyperparameters"):
        fit_sparse_gp(X[:50], Y[:50], k, inducing=10, hyper="elbo")


@pytest.mark.slow
def test_the_bound_overestimates_the_noise_when_the_inducing_poses_are_too_few():
    """Why the default is hyper="exact" (issue 21): with fewer inducing poses than the field's
    length-scale needs, the collapsed bound explains the rest of the data as noise (the variational
    bias of SGPR) where the exact NLML on a subset finds the small noise the data have (0.05 here)."""
    k = SquaredExponential("chordal", 3, 0.7)
    rng = np.random.default_rng(51)
    X = poses(1200, 52)
    X[:, :3] *= 0.05  # small rotations: the field lives in the positions
    w = rng.normal(size=(3, 20)) * 3.0
    b = rng.uniform(0, 2 * np.pi, 20)
    Y = np.sin(X[:, 3:6] @ w + b).sum(axis=1, keepdims=True) / 3.0 + 0.05 * rng.normal(size=(len(X), 1))
    default = fit_sparse_gp(X, Y, k, inducing=80, restarts=2, seed=0, explore_size=200)
    bound = fit_sparse_gp(X, Y, k, inducing=80, restarts=2, seed=0, explore_size=200, hyper="bound")
    sn_d, sn_b = default.fits[0].values["noise_std"], bound.fits[0].values["noise_std"]
    assert 0.035 < sn_d < 0.07
    assert sn_b > 3 * sn_d, (sn_b, sn_d)


@pytest.mark.slow
def test_hyperparameters_come_from_a_random_subset_and_the_posterior_from_all_points():
    """hyper="bound": the bound covers max(4 M, 2000) random points (HYPER_FACTOR, HYPER_MIN_POINTS), polished
    from the explored optima in a few evaluations; hyper_points=0 covers all n. Either way the posterior
    uses all n: it equals the posterior recomputed from X, Y at the same hyperparameters."""
    k = SquaredExponential("chordal", 3, 0.7)
    X = poses(3000, 21)
    Y = field(X, np.random.default_rng(22))[:, :2]
    gp = fit_sparse_gp(X, Y, k, inducing=40, restarts=2, seed=1, explore_size=200, hyper="bound")
    for f in gp.fits:
        bound = [st for st in f.stages if st["objective"] == "bound"]
        assert [st["points"] for st in bound] == [2000]
        assert bound[0]["evaluations"] <= 30
        kinds = [r["kind"] for r in f.starts]
        assert any("polish (bound, 2000 points)" in kd for kd in kinds)
        # σf ≫ σn here: the smooth start (for the all-noise basin) is not needed
        assert any(r["status"].startswith("not tried") for r in f.starts if r["kind"].startswith("smooth start"))
    again = SparseGP(k, X, Y, gp.Z, gp.fits, shared=False)
    Xs = poses(200, 23)
    np.testing.assert_allclose(gp.predict(Xs), again.predict(Xs), rtol=1e-9, atol=1e-12)
    full = fit_sparse_gp(X, Y, k, inducing=40, restarts=2, seed=1, explore_size=200, hyper_points=0, hyper="bound")
    assert all([st["points"] for st in f.stages if st["objective"] == "bound"][-1] == 3000 for f in full.fits)
    # the bound on all points is at least as good where it was optimised on all of them (within the
    # subset stage's tolerance), and the two models predict alike (a smooth field)
    assert sum(f.nlml for f in full.fits) <= sum(f.nlml for f in gp.fits) + 1.0
    truth = field(Xs)[:, :2]
    r_sub = np.sqrt(np.mean((gp.predict(Xs) - truth) ** 2))
    r_all = np.sqrt(np.mean((full.predict(Xs) - truth) ** 2))
    assert r_sub < 1.2 * r_all


def test_with_every_hyperparameter_fixed_only_the_posterior_is_computed():
    """fixed= covering every hyperparameter (σn included): no bound is optimised, the values are kept, and
    the posterior is the one a fit ending at those values has."""
    k = SquaredExponential("chordal", 3, 0.7)
    X = poses(500, 31)
    Y = field(X, np.random.default_rng(32))[:, :2]
    gp = fit_sparse_gp(X, Y, k, inducing=30, restarts=1, seed=2, explore_size=100, shared=True)
    fixed = fit_sparse_gp(X, Y, k, inducing=30, seed=2, shared=True, fixed=gp.fits[0].values)
    f = fixed.fits[0]
    assert f.values == gp.fits[0].values and f.free == [] and f.stages == [] and f.n_evaluations == 0
    np.testing.assert_array_equal(fixed.Z, gp.Z)
    Xs = poses(50, 33)
    np.testing.assert_allclose(fixed.predict(Xs), gp.predict(Xs), rtol=1e-9, atol=1e-12)
    assert f.nlml == pytest.approx(gp.fits[0].nlml, rel=1e-9)


def test_inducing_poses_come_from_a_seeded_random_candidate_set_when_there_are_many_rows():
    from rbgp_cli.gp.sparse import CANDIDATES_PER_INDUCING

    k = SquaredExponential("chordal", 3, 0.7)
    X = poses(50 * CANDIDATES_PER_INDUCING, 24)  # more rows than 32 candidates per inducing pose for M = 10..40
    for M in (10, 40):
        a = select_inducing(X, M, k, seed=3)
        assert np.array_equal(a, select_inducing(X, M, k, seed=3))
        assert len(a) == M and len(np.unique(a)) == M and a.min() >= 0 and a.max() < len(X)
    assert not np.array_equal(select_inducing(X, 10, k, seed=3), select_inducing(X, 10, k, seed=4))


@pytest.mark.parametrize("method", ["kmeans++", "farthest"])
def test_inducing_selection_is_seeded_distinct_and_spread(method):
    k = SquaredExponential("arc", 3, 0.7)
    X = poses(500, 16)
    X = np.vstack([X, X[:100]])  # duplicates must never be chosen twice
    a = select_inducing(X, 50, k, seed=2, method=method)
    assert np.array_equal(a, select_inducing(X, 50, k, seed=2, method=method))
    assert len(a) == 50 and len(np.unique(a)) == 50
    E = inducing_embedding(k, X)
    assert len({tuple(np.round(E[i], 12)) for i in a}) == 50
    # at most as many as there are distinct rows
    assert len(select_inducing(np.repeat(X[:7], 3, axis=0), 50, k, method=method)) == 7
    # the chordal embedding reproduces the chordal distance (docs/method.md §5), weighted by rho
    kc = SquaredExponential("chordal", 3, 0.7)
    Ec = inducing_embedding(kc, X[:20])
    d2 = np.sum((Ec[:, None] - Ec[None]) ** 2, -1)
    ref = kc.precompute(X[:20])["d2"]
    np.testing.assert_allclose(d2, ref, atol=1e-10)


@pytest.mark.slow
def test_with_every_pose_inducing_the_fit_finds_the_exact_optimum_on_real_handovers(realdata):
    """The trap that made sparse models lose held out: on one crossval fold of the handover recordings
    every start of the first output explored on 400 points ends, on all points, in the all-noise basin
    (σf ≪ σn, λ → 0; bound 1742 for the sparse fit, NLML 1470 for the exact GP's polish), while a
    structured optimum (NLML 1122.9) lies at long length scales. Both fits try a smooth start there
    (the exact GP where its best optimum is all noise), and with Z = X the bound is the exact NLML, so
    both must reach it."""
    import warnings

    from rbgp_cli.dynamics.model import make_kernel, training_set
    from rbgp_cli.dynamics.representations import make_representation
    from rbgp_cli.evaluation.crossval import make_folds
    from rbgp_cli.gp.exact import fit_gp
    from rbgp_cli.gp.sparse import fit_sparse_gp
    from rbgp_cli.dynamics.velocities import VelocityOptions
    from rbgp_cli.workflows import load_demonstrations

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        demos, _, _ = load_demonstrations([str(realdata / "handover_object_csv")])
    held = set(make_folds(len(demos), 5, 0)[3])
    train = [d for i, d in enumerate(demos) if i not in held]
    rep = make_representation("axis-angle")
    X, Y, _ = training_set(train, rep, subsample=None, velocity=VelocityOptions(rate=10.0), time_input="phase")
    kern = make_kernel(rep, "se-chordal", 0.7, False, time_dims=1)
    y = Y[:, :1]
    exact = fit_gp(X, y, kern, restarts=3, seed=0, jobs=1).fits[0]
    sparse = fit_sparse_gp(X, y, kern, inducing=len(X), restarts=3, seed=0).fits[0]
    assert exact.values["signal_std"] > exact.values["noise_std"]  # not the all-noise basin
    assert sparse.values["signal_std"] > sparse.values["noise_std"]
    assert sparse.nlml <= exact.nlml + 1.0, (sparse.nlml, exact.nlml)


@pytest.mark.slow
def test_the_sparse_gp_at_the_defaults_keeps_slow_handovers_inside_the_demonstrated_region(realdata):
    """Issue 21: on the slower, more varied handovers (``handover_variation_csv``) a sparse GP whose
    hyperparameters came from the bound (λ 0.17–0.34, σf up to 16 with M = 512 for 1930 points, where the
    exact NLML finds λ 0.04–0.11) sent rollouts out of the demonstrated region (position RMSE 0.44 m
    against 0.20 m for the exact GP on one fold). With the default (the exact GP's hyperparameters on a
    subset, the sparse posterior on all points) the sparse model is no worse than the exact GP held out
    and stays inside. A smaller version of that fold, so that it runs in the tests: 16 training
    demonstrations, 128 inducing poses."""
    import warnings

    from rbgp_cli.dynamics.model import train_model
    from rbgp_cli.dynamics.rollout import rollout
    from rbgp_cli.dynamics.trajectory import Trajectory
    from rbgp_cli.evaluation.crossval import make_folds, trajectory_errors
    from rbgp_cli.workflows import load_demonstrations

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        demos, _, _ = load_demonstrations([str(realdata / "handover_variation_csv")])
    held = make_folds(len(demos), 5, 0)[1]
    test = [demos[i] for i in held]
    train = [d for i, d in enumerate(demos) if i not in set(held)][::2]
    P = np.concatenate([d.position for d in train])
    lo, hi = P.min(0), P.max(0)

    def held_out(model):
        steps = np.array([max(1, int(round(tr.duration / model.dt))) for tr in test])
        res = rollout(model, np.array([tr.quat[0] for tr in test]), np.array([tr.position[0] for tr in test]),
                      int(steps.max()), with_std=False, durations=steps * model.dt)
        gen = [Trajectory(res.t[: s + 1], res.quat[b, : s + 1], res.position[b, : s + 1]) for b, s in enumerate(steps)]
        sp, _sr, c = trajectory_errors(gen, test, 100)
        pos = np.concatenate([g.position for g in gen])
        margin = 0.25 * (hi - lo)
        outside = int(np.sum(np.any((pos < lo - margin) | (pos > hi + margin), axis=1)))
        return math.sqrt(sp / c), outside

    opts = dict(jobs=1, restarts=2)
    exact = held_out(train_model(train, inducing=0, **opts))
    sparse = held_out(train_model(train, inducing=128, **opts))
    assert sparse[1] == 0, sparse
    assert sparse[0] <= 1.1 * exact[0], (sparse, exact)
