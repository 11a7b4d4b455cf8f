"""The path distribution's leave-one-out, all demonstrations at once (issue 35), equals the loop over
demonstrations it replaced: the loops below are that code, kept as the oracle."""

from __future__ import annotations

import numpy as np
import pytest

from rbgp_cli.dynamics import anticipation, paths as paths_mod
from rbgp_cli.dynamics.paths import GOAL_TOLERANCE, SELECT_EVERY, fit_paths, held_out_score, left_out_moments
from tests.dynamics.test_paths import draw_family


def loop_held_out_score(e, cov, stats=False):
    """held_out_score as it was: one path, numpy's unbatched calls."""
    L = np.linalg.cholesky(cov + 1e-9 * np.trace(cov) / len(e) * np.eye(len(e)))
    a = np.linalg.solve(L, e)
    logd = -0.5 * a @ a - np.sum(np.log(np.diag(L)))
    if not stats:
        return logd, None, None
    k = len(e) // 6
    ek = e.reshape(k, 6)
    Ck = np.array([cov[6 * i:6 * i + 6, 6 * i:6 * i + 6] for i in range(k)])
    m2 = np.einsum("ki,ki->k", ek[:, :3], np.linalg.solve(Ck[:, :3, :3] + 1e-12 * np.eye(3), ek[:, :3, None])[..., 0])
    z = np.abs(ek[:, 3:]) / np.sqrt(np.maximum(np.einsum("kii->ki", Ck[:, 3:, 3:]), 1e-24))
    return logd, m2, z


def loop_others(Xs, d):
    rest = np.delete(Xs, d, axis=0)
    m = rest.mean(axis=0)
    C = rest - m
    return m, (1.0 + 1.0 / len(rest)) * (C.T @ C) / max(len(rest) - 1, 1)


def loop_loo_scores(paths, smooth, length, stats=False):
    """paths._loo_scores as it was (a loop over demonstrations)."""
    X = paths.vectors()
    D, S = len(X), paths.S
    sel = np.arange(SELECT_EVERY, S - 1, SELECT_EVERY)
    phases = np.concatenate([[0, S - 1], sel])
    idx = (6 * phases[:, None] + np.arange(6)[None]).ravel()
    Xs = X[:, idx]
    Ks = paths.smooth_covariance(smooth, length)[np.ix_(idx, idx)]
    r2 = np.concatenate([(np.array(GOAL_TOLERANCE).repeat(3) / paths.scale) ** 2] * 2)
    logd, m2, z = 0.0, [], []
    for d in range(D):
        m, Sig = loop_others(Xs, d)
        Sigma = Sig + Ks
        S11, S21, S22 = Sigma[:12, :12] + np.diag(r2), Sigma[12:, :12], Sigma[12:, 12:]
        gain = np.linalg.solve(S11, S21.T).T
        mean = m[12:] + gain @ (Xs[d, :12] - m[:12])
        cov = S22 - gain @ S21.T
        ld, m2_d, z_d = loop_held_out_score(Xs[d, 12:] - mean, cov, stats)
        logd += ld
        if stats:
            m2.append(m2_d)
            z.append(z_d)
    if stats:
        return logd / D, np.concatenate(m2), np.concatenate(z)
    return logd / D


def loop_seen_loo(paths, tolerances, stats=False, points=anticipation.SEEN_POINTS):
    """anticipation._seen_loo as it was (a loop over demonstrations and tolerances)."""
    X = paths.vectors()
    D, S, P = len(X), paths.S, X.shape[1]
    Ks = paths.smooth_covariance()
    r_last = (np.array(GOAL_TOLERANCE).repeat(3) / paths.scale) ** 2
    total = np.zeros(len(tolerances))
    count, m2, z = 0, [], []
    for F in anticipation.SEEN_FRACTIONS:
        idx, no = anticipation.seen_split(F, S, P, points)  # the entries, shared; the algebra is the oracle
        Xs = X[:, idx]
        Kss = Ks[np.ix_(idx, idx)]
        for d in range(D):
            m, Sig = loop_others(Xs, d)
            Sigma = Sig + Kss
            Soo, Sot, Stt = Sigma[:no, :no], Sigma[:no, no:], Sigma[no:, no:]
            for i, tol in enumerate(tolerances):
                r2 = np.full(no, float(tol) ** 2)
                r2[-7:-1] = r_last
                r2[-1] = anticipation._ELL_TOL ** 2
                gain = np.linalg.solve(Soo + np.diag(r2), Sot).T
                mean = m[no:] + gain @ (Xs[d, :no] - m[:no])
                cov = Stt - gain @ Sot
                ld, m2_d, z_d = loop_held_out_score(Xs[d, no:] - mean, cov, stats)
                total[i] += ld
                if stats:
                    m2.append(m2_d)
                    z.append(z_d)
            count += 1
    if stats:
        return total / count, np.concatenate(m2), np.concatenate(z)
    return total / count


@pytest.fixture(scope="module", params=[3, 12, pytest.param(70, marks=pytest.mark.slow)])
def fitted(request):
    """Path distributions of 3 (the fewest), 12 and 70 demonstrations (70 > LOO_BLOCK: two blocks)."""
    _, _, trajs = draw_family(request.param, np.random.default_rng(35 + request.param))
    return fit_paths(trajs)


def test_left_out_moments_equal_the_loop():
    rng = np.random.default_rng(4)
    # an outlying demonstration as well
    Xs = np.vstack([rng.normal(0, 1, (9, 17)), rng.normal(30, 5, (1, 17))])
    got = list(left_out_moments(Xs, block=4))
    assert [len(b) for b, _, _ in got] == [4, 4, 2]
    for b, m, Sig in got:
        for row, d in enumerate(b):
            m_want, S_want = loop_others(Xs, d)
            np.testing.assert_allclose(m[row], m_want, rtol=1e-13, atol=1e-13)
            np.testing.assert_allclose(Sig[row], S_want, rtol=1e-12, atol=1e-12 * np.max(np.abs(S_want)))


def test_held_out_score_of_one_equals_the_unbatched_one():
    rng = np.random.default_rng(5)
    A = rng.normal(size=(24, 24))
    cov = A @ A.T + 0.1 * np.eye(24)
    e = rng.normal(size=24)
    want = loop_held_out_score(e, cov, stats=True)
    got = held_out_score(e, cov, stats=True)
    np.testing.assert_allclose(got[0], want[0], rtol=1e-13)
    np.testing.assert_allclose(got[1], want[1], rtol=1e-12)
    np.testing.assert_allclose(got[2], want[2], rtol=1e-12)


def test_loo_scores_equal_the_loop(fitted):
    """Every (τ², ℓ) of the grid scores as in the loop, and the same one wins. Where τ² is small and
    the demonstrations few, the left-out predictive covariance is nearly singular (condition numbers
    of 1e10: a sample covariance of rank D − 2 plus 1e-3 K) and amplifies the round-off of any
    reordering of the arithmetic (numpy's batched products): there the two agree to 1e-5 relative,
    on log densities of −1e7 that no choice comes near."""
    grid = [(t, ell) for t in paths_mod.SMOOTH_GRID for ell in paths_mod.LENGTH_GRID]
    got = np.array([paths_mod._loo_scores(fitted, t, ell) for t, ell in grid])
    want = np.array([loop_loo_scores(fitted, t, ell) for t, ell in grid])
    np.testing.assert_allclose(got, want, rtol=1e-5)
    assert np.argmax(got) == np.argmax(want)
    assert grid[int(np.argmax(got))] == (fitted.smooth, fitted.length)
    np.testing.assert_allclose(paths_mod._loo_scores(fitted, fitted.smooth, fitted.length),
                               loop_loo_scores(fitted, fitted.smooth, fitted.length), rtol=1e-11)
    got = paths_mod._loo_scores(fitted, fitted.smooth, fitted.length, stats=True)
    want = loop_loo_scores(fitted, fitted.smooth, fitted.length, stats=True)
    for g, w in zip(got, want):
        np.testing.assert_allclose(g, w, rtol=1e-10, atol=1e-12)


def test_seen_loo_equals_the_loop(fitted):
    grid = anticipation.SEEN_TOLERANCE_GRID
    got, want = anticipation._seen_loo(fitted, grid), loop_seen_loo(fitted, grid)
    np.testing.assert_allclose(got, want, rtol=1e-9)
    assert np.argmax(got) == np.argmax(want)
    assert grid[int(np.argmax(got))] == fitted.seen_tolerance
    got = anticipation._seen_loo(fitted, [fitted.seen_tolerance], stats=True)
    want = loop_seen_loo(fitted, [fitted.seen_tolerance], stats=True)
    for g, w in zip(got, want):
        np.testing.assert_allclose(g, w, rtol=1e-10, atol=1e-12)
