"""The duration's weights of a motion under way with their own smooth shrinkage and seen tolerance
(issue 37): the batched grid terms against an independent computation with the whole covariance."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from rbgp_cli.dynamics.anticipation import Anticipator
from rbgp_cli.dynamics.paths import fit_paths
from rbgp_cli.dynamics.trajectory import Trajectory

from .test_anticipation import family


@pytest.fixture(scope="module")
def paths():
    demos, _ = family(12, 3)
    return fit_paths(demos)


def _even(tr, F, n):
    """The first F of a motion, resampled to n evenly spaced samples (so that the anticipator's seen poses are
    the samples themselves, as the full computation takes them)."""
    from rbgp_cli.dynamics.trajectory import interpolate_poses

    span = F * tr.duration
    t = tr.t[0] + np.linspace(0.0, span, n)
    q, p = interpolate_poses(tr.t, tr.quat, tr.position, t)
    return Trajectory(t, q, p)


@pytest.mark.parametrize("smooth,tolerance", [(0.01, 0.8), (0.3, 3.2), (0.003, 0.2)])
def test_the_duration_weights_and_end_pose_equal_the_full_covariance_computation(paths, smooth, tolerance):
    """Anticipator's weights over the duration grid with its own τ² and r equal those of
    PathDistribution.duration_posterior (a loop over the grid with Σ's 307 × 307 entries) on a distribution
    whose τ² and seen tolerance are those values; the end pose's mean and covariance per duration equal the
    Gaussian conditional of PathDistribution.condition."""
    ant = Anticipator(paths, None, points=8, grid_size=12, duration_smooth=smooth, duration_tolerance=tolerance,
                      duration_evidence=1.0)
    ref = copy.copy(paths)
    ref.smooth, ref.seen_tolerance = smooth, tolerance
    tr = family(1, 11)[0][0]
    for F in (0.25, 0.6):
        seen = _even(tr, F, 8)
        grid, w, terms = ant.weights(seen.t, seen.quat, seen.position)
        g2, w2 = ref.duration_posterior(seen.t, seen.quat, seen.position, grid=grid, points=8)
        np.testing.assert_allclose(w, w2, rtol=1e-4, atol=1e-10)
        live = (w > 1e-250) & (w2 > 1e-250)  # the log weights compare where both are representable
        assert live.sum() >= 4  # several durations: the comparison means something
        np.testing.assert_allclose(np.log(w[live]), np.log(w2[live]), rtol=1e-5, atol=1e-3)
        for g in (0, int(np.argmax(w)), len(grid) - 1):
            A, y, r2 = ref.stack(ref.observe((seen.t - seen.t[0]) / grid[g], seen.quat, seen.position),
                                 ref.observe_duration(grid[g], tolerance=1e-4 * ref.duration_scale))
            c = ref.condition(A, y, r2)
            E = slice(6 * (ref.S - 1), 6 * ref.S)
            np.testing.assert_allclose(terms["end_mean"][g], c.mean[E], rtol=1e-6, atol=1e-8)
            np.testing.assert_allclose(terms["end_cov"][g], c.cov[E, E], rtol=1e-6, atol=1e-8)


def test_the_duration_has_its_own_tau_and_tolerance_chosen_on_the_task(paths):
    """fit_paths chooses the duration weights' τ² and r as the candidate whose left-out duration error is
    smallest (so never worse there than the path distribution's own τ² and r); the anticipator uses them by
    default, arguments override them, None on the distribution falls back on its τ² and seen tolerance; a
    model file's header keeps them."""
    from rbgp_cli.dynamics.anticipation import _duration_loo
    from rbgp_cli.dynamics.paths import PathDistribution

    demos, _ = family(12, 3)
    errors = _duration_loo(paths, demos)
    chosen = (paths.duration_smooth, paths.duration_tolerance)
    assert chosen + (None,) == min(errors, key=errors.get) and paths.duration_sigma is None  # twelve: no σ candidate
    assert errors[chosen + (None,)] <= errors[(paths.smooth, paths.seen_tolerance, None)]
    assert 0.0 < errors[chosen + (None,)] < 0.1  # |ln D̂ − ln D| of a family whose durations vary by 20 %
    ant = Anticipator(paths, None)
    assert (ant.duration_smooth, ant.duration_tolerance) == chosen
    assert Anticipator(paths, None, duration_smooth=0.5, duration_tolerance=2.0).duration_tolerance == 2.0
    plain = copy.copy(paths)
    plain.duration_smooth = plain.duration_tolerance = None
    same = Anticipator(plain, None)
    assert (same.duration_smooth, same.duration_tolerance) == (paths.smooth, paths.seen_tolerance)
    np.testing.assert_array_equal(ant.Sigma, same.Sigma)  # the conditioning's prior is the same
    back = PathDistribution.from_arrays(paths.to_arrays(), paths.header())
    assert (back.duration_smooth, back.duration_tolerance) == chosen
    old = {k: v for k, v in paths.header().items() if not k.startswith("duration_")}
    assert PathDistribution.from_arrays(paths.to_arrays(), old).duration_smooth is None  # older model files


def _duration_loo_by_weights(paths, trajs, folds=5, points=6, grid_size=16):
    """The oracle: _duration_loo as a loop over the left-out demonstrations, fractions and candidates, each one call
    of Anticipator.weights on the raw beginning (checks, normalisation and interpolation each time)."""
    from rbgp_cli.dynamics.anticipation import SEEN_FRACTIONS, duration_candidates

    D = paths.demos
    candidates = duration_candidates(paths)
    err, count = {c: 0.0 for c in candidates}, 0
    order = np.random.default_rng(np.random.SeedSequence([37, D])).permutation(D)
    for group in np.array_split(order, min(folds, D)):
        keep = np.setdiff1d(np.arange(D), group)
        rest = copy.copy(paths)
        rest.deviations, rest.log_durations = paths.deviations[keep], paths.log_durations[keep]
        rest.duration_smooth = rest.duration_tolerance = None
        for d in group:
            tr = trajs[d]
            for F in SEEN_FRACTIONS:
                k = int(np.clip(np.argmin(np.abs(tr.t - (tr.t[0] + F * tr.duration))), 1, len(tr.t) - 1))
                for c in candidates:
                    ant = Anticipator(rest, None, points=points, grid_size=grid_size, duration_smooth=c[0],
                                      duration_tolerance=c[1], duration_sigma=c[2])
                    grid, w, terms = ant.weights(tr.t[: k + 1], tr.quat[: k + 1], tr.position[: k + 1])
                    D_hat = ant._duration_quantiles(grid, w, terms["span"])[1]
                    err[c] += abs(np.log(max(D_hat, 1e-9)) - paths.log_durations[d])
                count += 1
    return {c: e / count for c, e in err.items()}


@pytest.mark.slow
@pytest.mark.parametrize("case", ["family", "short beginnings", "five"])
def test_duration_loo_batched_equals_the_loop_over_weights(case):
    """_duration_loo estimates every left-out beginning of a group in one batch per candidate (issue 35): the
    same errors as one Anticipator.weights call per beginning and candidate, to 1e-10. "short beginnings": one
    demonstration sampled so coarsely that its first fifth has fewer seen poses than the rest (not in the
    batch), and one so slow that its beginnings outlast every duration of the grid (weights' own case). "five": a
    study of five, whose candidates include DURATION_FEW and the tolerance in rad and m."""
    from rbgp_cli.dynamics.anticipation import DURATION_FEW, DURATION_FEW_SIGMA, _duration_loo

    demos, _ = family(5 if case == "five" else 10, 5)
    if case == "short beginnings":
        slow = demos[3]
        demos[3] = Trajectory(slow.t * 4.0, slow.quat, slow.position, name="slow")
        coarse = demos[6]
        demos[6] = Trajectory(coarse.t[::12], coarse.quat[::12], coarse.position[::12], name="coarse")
    paths = fit_paths(demos)
    got = _duration_loo(paths, demos)
    want = _duration_loo_by_weights(paths, demos)
    assert got.keys() == want.keys() and len(got) >= 1
    few = {tuple(DURATION_FEW) + (None,), (DURATION_FEW[0], None, DURATION_FEW_SIGMA)}
    assert few <= set(got) if case == "five" else not few & set(got)  # weighed below DURATION_FEW_BELOW only
    for c in want:
        assert abs(got[c] - want[c]) <= 1e-10, (c, got[c], want[c])
    assert all(0.0 < v < 2.0 for v in got.values())


def test_the_loosest_candidate_within_one_standard_error_of_the_best():
    """The one-standard-error rule (_loosest_within): a looser candidate whose paired excess over the best is
    within its standard error is taken; one clearly worse is not, however loose; the tolerance in rad and m is the
    loosest; between equal r the smaller τ²."""
    from rbgp_cli.dynamics.anticipation import _loosest_within

    rng = np.random.default_rng(0)
    best = rng.uniform(0.05, 0.15, 20)
    z = rng.standard_normal(20)
    noisy = best + 0.01 + 0.1 * (z - z.mean()) / z.std(ddof=1)  # 0.01 worse on average, se = 0.1 / √20 ≈ 0.022
    worse = best + 0.05 + 0.001 * rng.standard_normal(20)  # 0.05 worse, se ≈ 0.0002
    tight, loose, own, sigma = (0.01, 0.8, None), (0.01, 3.2, None), (1.0, 3.2, None), (0.01, None, 0.3)
    assert _loosest_within({tight: best, loose: noisy}) == loose
    assert _loosest_within({tight: best, loose: worse}) == tight
    assert _loosest_within({tight: best, loose: worse, (1.0, 1.6, None): noisy}) == (1.0, 1.6, None)
    assert _loosest_within({tight: best, own: noisy, loose: noisy + 1e-3}) == loose
    assert _loosest_within({tight: best, loose: noisy}, k=0.0) == tight
    assert _loosest_within({tight: best, loose: noisy, sigma: noisy + 1e-3}) == sigma
    assert _loosest_within({tight: best, loose: noisy, sigma: worse}) == loose


@pytest.mark.parametrize("n", [5, 12])
def test_fit_seen_takes_the_rule_below_ten_and_the_smallest_error_from_ten_on(n):
    """A study of five takes the one-standard-error choice of the duration's (τ², r, σ) over its left-out errors
    (issue 37, eleventh and twelfth passes), stored in the model file's header; twelve take the smallest mean error."""
    from rbgp_cli.dynamics.anticipation import DURATION_FEW_BELOW, _duration_loo, _loosest_within
    from rbgp_cli.dynamics.paths import PathDistribution

    demos, _ = family(n, 7)
    paths = fit_paths(demos)
    errors = _duration_loo(paths, demos, per_beginning=True)
    assert all(len(e) == 4 * n for e in errors.values())  # every left-out beginning, each candidate
    want = _loosest_within(errors) if n < DURATION_FEW_BELOW else min(errors, key=lambda c: float(np.mean(errors[c])))
    got = (paths.duration_smooth, paths.duration_tolerance, paths.duration_sigma)
    assert got == want
    back = PathDistribution.from_arrays(paths.to_arrays(), paths.header())
    assert (back.duration_smooth, back.duration_tolerance, back.duration_sigma) == got
    means = _duration_loo(paths, demos)
    assert means.keys() == errors.keys()
    for c in means:
        assert abs(means[c] - float(np.mean(errors[c]))) <= 1e-12


def test_a_tolerance_in_radians_and_metres_per_coordinate():
    """(τ², None, σ) weighs each seen coordinate with σ / σ_c in units of its spread; (τ², r, None) with r."""
    from rbgp_cli.dynamics.anticipation import duration_tolerances

    demos, _ = family(5, 7)
    paths = fit_paths(demos)
    ant = Anticipator(paths, None, duration_smooth=0.01, duration_sigma=0.3)
    np.testing.assert_allclose(ant._duration_r2, (0.3 / paths.scale) ** 2, rtol=1e-12)
    assert np.ptp(ant._duration_r2) > 0  # the spreads differ: per coordinate
    np.testing.assert_array_equal(Anticipator(paths, None, duration_smooth=0.01, duration_tolerance=0.8)._duration_r2,
                                  np.full(6, 0.8 ** 2))
    np.testing.assert_array_equal(duration_tolerances(paths, 0.8, 0.3), 0.3 / paths.scale)  # σ wins


def test_a_tolerance_in_radians_and_metres_weighs_as_the_full_covariance_computation(paths):
    """The duration weights with a tolerance σ in rad and m (σ / σ_c per coordinate) equal a loop over the grid
    with Σ's 307 × 307 entries and PathDistribution.observe's own absolute tolerance (σ for rotation and
    position); they differ from a tolerance r in units of the spread."""
    sigma = 0.3
    ant = Anticipator(paths, None, points=8, grid_size=12, duration_smooth=0.01, duration_sigma=sigma)
    ref = copy.copy(paths)
    ref.smooth = 0.01
    m, Sigma = ref.prior()
    tr = family(1, 11)[0][0]
    for F in (0.25, 0.6):
        seen = _even(tr, F, 8)
        grid, w, _ = ant.weights(seen.t, seen.quat, seen.position)
        logp = []
        for D in grid:
            A, y, r2 = ref.stack(ref.observe((seen.t - seen.t[0]) / D, seen.quat, seen.position, tolerance=(sigma, sigma)),
                                 ref.observe_duration(D, tolerance=1e-6))
            G = A @ Sigma @ A.T + np.diag(r2)
            L = np.linalg.cholesky(0.5 * (G + G.T))
            a = np.linalg.solve(L, y - A @ m)
            logp.append(-0.5 * a @ a - np.sum(np.log(np.diag(L))))
        w2 = np.exp(np.array(logp) - max(logp))
        w2 /= w2.sum()
        np.testing.assert_allclose(w, w2, rtol=1e-4, atol=1e-10)
        assert (w > 1e-3).sum() >= 2  # several durations carry weight: the comparison means something
        _, w_r, _ = Anticipator(paths, None, points=8, grid_size=12, duration_smooth=0.01,
                                duration_tolerance=0.8).weights(seen.t, seen.quat, seen.position)
        assert np.abs(w - w_r).max() > 1e-2


def test_the_tolerance_in_radians_and_metres_in_the_model_file():
    """``duration_sigma`` round-trips through the header, the model file's schema accepts it and refuses σ ≤ 0;
    a header without it (older files, or ten demonstrations and more) loads as None."""
    from rbgp_cli.dynamics.paths import PathDistribution
    from rbgp_cli.io.model_schema import TOP

    rng = np.random.default_rng(2)
    S, D = 11, 5
    paths = PathDistribution(np.linspace(0, 1, S), np.tile([0.0, 0.0, 0.0, 1.0], (S, 1)), np.zeros((S, 3)),
                             rng.normal(size=(D, S, 6)), rng.normal(size=D), duration_smooth=0.01, duration_sigma=0.3)
    header = paths.header()
    assert header["duration_sigma"] == 0.3 and "duration_tolerance" not in header
    TOP["paths"][1](header, ("paths",))
    back = PathDistribution.from_arrays(paths.to_arrays(), header)
    assert (back.duration_smooth, back.duration_tolerance, back.duration_sigma) == (0.01, None, 0.3)
    with pytest.raises(Exception, match="duration_sigma"):
        TOP["paths"][1](dict(header, duration_sigma=0.0), ("paths",))
    old = {k: v for k, v in header.items() if k != "duration_sigma"}
    assert PathDistribution.from_arrays(paths.to_arrays(), old).duration_sigma is None

