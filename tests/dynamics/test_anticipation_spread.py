"""The bands of a motion under way scored against the samples as they are drawn (issue 37, eighth pass): each left-out
remainder against continuations at their own durations (:func:`~rbgp_cli.dynamics.anticipation._spread_terms`),
checked against a direct computation with the others' full covariance, one duration at a time; the rule that turns
them into factors; and the coverage of fresh continuations of motions whose durations vary."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.special import fdtri, stdtrit

from rbgp_cli.dynamics import anticipation
from rbgp_cli.dynamics.anticipation import (SEEN_POINTS, SPREAD_GRID, SPREAD_KEEP, SPREAD_POINTS, SPREAD_SUB, GRID_RANGE,
                                            _ELL_TOL, _log_mode, _spread_factors, _spread_terms, seen_split)
from rbgp_cli.dynamics.paths import GOAL_TOLERANCE, fit_paths, pose_deviation

from .test_anticipation import family
from .test_anticipation_bands import _rich_family


@pytest.fixture(scope="module")
def paths():
    p = anticipation.fit_seen(fit_paths(family(9, 3)[0]), spread=True)
    p.duration_evidence = 0.25  # the duration's band tempered (fit_seen leaves it as the demonstrations ask)
    return anticipation.fit_seen(p, spread=True, duration=False)


def _direct(paths, d, F, rest):
    """_spread_terms' rows of left-out demonstration d at fraction F, by the definition: the others' mean and
    covariance (np.cov), the observation operator of PathDistribution.observe, full P × P solves, one duration at a
    time (a loop over the grid's cells and their sub-durations)."""
    X = paths.vectors()
    S, P, Dn = paths.S, X.shape[1], len(X)
    others = np.delete(X, d, axis=0)
    m = others.mean(axis=0)
    sample = (1.0 + 1.0 / (Dn - 1)) * np.cov(others, rowvar=False)
    r_last = (np.array(GOAL_TOLERANCE).repeat(3) / paths.scale) ** 2
    dur = np.exp(paths.log_durations)
    Dd = dur[d]

    def seen(points, near=False):
        idx, no = seen_split(F, S, P, points, near=near)
        js = idx[:no - 1:6] // 6
        return js, paths.s[js] * Dd

    def cond(js, times, Dur, tau2, tol, ell=_ELL_TOL, near=None, exact=True):
        q, p = paths.pose_at(paths.deviations[d], paths.s[js])
        A, y, r2 = paths.observe(np.minimum(times / Dur, 1.0), q, p)
        r2[:] = tol ** 2
        if exact:
            r2[-6:] = r_last
        if near is not None:
            r2[-12:-6] = near ** 2
        Al, yl, rl = paths.observe_duration(Dur, tolerance=ell * paths.duration_scale)
        A, y, r2 = np.vstack([A, Al]), np.concatenate([y, yl]), np.concatenate([r2, rl])
        Sg = sample + paths.smooth_covariance(tau2)
        G = A @ Sg @ A.T + np.diag(r2)
        e = y - A @ m
        x = m + Sg @ A.T @ np.linalg.solve(G, e)
        cov = Sg - Sg @ A.T @ np.linalg.solve(G, A @ Sg)
        return x, cov, -0.5 * e @ np.linalg.solve(G, e) - 0.5 * np.linalg.slogdet(G)[1]

    js, times = seen(SEEN_POINTS)
    span = times[-1]
    J = js[-1]
    jt = np.arange(J + 1, S)
    u = (jt - J) / (S - 1 - J)
    tau2, r = paths.smooth, paths.seen_tolerance
    own, cov, _ = cond(js, times, Dd, tau2, r)
    mu = cond(*seen(SEEN_POINTS, near=len(rest) > 3), Dd, *rest)[0] if rest is not None else own
    blocks = np.array([cov[6 * j:6 * j + 6, 6 * j:6 * j + 6] for j in jt])
    # the duration's weights on the others' grid, then SPREAD_SUB durations per cell kept
    od = np.delete(dur, d)
    grid = np.exp(np.linspace(np.log(GRID_RANGE[0] * od.min()), np.log(GRID_RANGE[1] * od.max()), SPREAD_GRID))
    half = 0.5 * (np.log(grid[1]) - np.log(grid[0]))
    js6, times6 = seen(SPREAD_POINTS)
    dsm = paths.smooth if paths.duration_smooth is None else paths.duration_smooth
    dtol = paths.seen_tolerance if paths.duration_tolerance is None else paths.duration_tolerance
    lw = np.array([cond(js6, times6, g, dsm, dtol, exact=False)[2] if g >= span else -np.inf for g in grid])
    lam = 1.0 if paths.duration_evidence is None else paths.duration_evidence

    def median(wt):  # each cell's weight spread evenly over it in ln D; at least the seen span
        edges = np.concatenate([[np.log(grid[0]) - half], np.log(grid) + half])
        return max(float(np.exp(np.interp(0.5, np.concatenate([[0.0], np.cumsum(wt)]), edges))), span)

    shift = 1.0
    mode = paths.duration_statistic == "mode"
    w1 = np.exp(lw - lw.max())
    if lam != 1.0:  # the seen poses' evidence weighted by λ about the others' prior of ℓ, whole as its Student-t
        v = (sample + paths.smooth_covariance(dsm))[-1, -1] + _ELL_TOL ** 2
        e2 = (np.log(grid) / paths.duration_scale - m[-1]) ** 2
        nu = Dn - 2
        lw = -0.5 * (nu + 1) * np.log1p(e2 / (nu * v)) + lam * (lw + 0.5 * e2 / v)
    if lam != 1.0 or mode:  # onto the whole evidence's D̂: its median, or its mode in ln D
        wt = np.exp(lw - lw.max())
        point = _log_mode(grid, w1 / w1.sum(), span) if mode else median(w1 / w1.sum())
        shift = point / median(wt / wt.sum())
    w = np.exp(lw - lw.max())
    w /= w.sum()
    zero = np.zeros((S, 6))
    ref_q, ref_p = paths.pose_at(zero, paths.s[jt])
    ys, ws = [], []
    for g in np.flatnonzero(w > SPREAD_KEEP * w.max()):
        for o in (2.0 * np.arange(SPREAD_SUB) + 1.0 - SPREAD_SUB) / SPREAD_SUB:
            Dg = max(np.exp(np.log(grid[g] * shift) + o * half), span * (1 + 1e-9))
            x = cond(js, times, Dg, tau2, r)[0]
            s0 = min(span / Dg, 1.0)
            q, p = paths.pose_at(paths.unscale(x)[0], s0 + u * (1.0 - s0))
            ys.append(pose_deviation(ref_q, ref_p, q, p) / paths.scale)
            ws.append(w[g] / SPREAD_SUB)
    ys, ws = np.array(ys), np.array(ws) / np.sum(ws)
    ybar = np.einsum("g,gtc->tc", ws, ys)
    V = np.einsum("g,gtc,gtd->tcd", ws, ys - ybar, ys - ybar)
    x6 = lambda v: v[:-1].reshape(S, 6)[jt]  # noqa: E731
    e = X[d, :-1].reshape(S, 6)[jt] - x6(mu) - (ybar - x6(own))
    mid = np.concatenate([[0.0], 0.5 * (u[1:] + u[:-1]), [1.0]])
    return {"e": e, "V": V, "C": blocks, "w": np.diff(mid)}


@pytest.mark.parametrize("F, rest", [(0.2, (1.0, 3.2)), (0.8, (1.0, 3.2)), (0.6, (1.0, 3.2, 1e3, 0.1))])
def test_the_batched_terms_equal_the_direct_computation(paths, F, rest):
    """(τ²_rest, r_rest), and with ln D freed and the near pose at its tolerance (the grid phase before the last)."""
    got = _spread_terms(paths, F, rest=rest)
    T = len(got["w"]) // paths.demos
    for d in (0, 4, 8):
        want = _direct(paths, d, F, rest)
        rows = slice(d * T, (d + 1) * T)
        for key in ("e", "V", "C", "w"):
            np.testing.assert_allclose(got[key][rows], want[key], rtol=1e-9, atol=1e-9 * np.abs(want[key]).max(),
                                       err_msg=key)


def test_without_the_durations_spread_the_rule_is_the_left_out_statistics_at_every_phase(paths):
    """With V = 0 and even weights the needs are the seventh pass's left-out statistics (|e|/σ against t_ν and
    eᵀC⁻¹e against 3 F(3, ν)) and the factors their 90 % quantiles (the smallest value with 90 % at or below it)."""
    terms = _spread_terms(paths, 0.6)
    X = paths.vectors()
    S = paths.S
    T = len(terms["w"]) // paths.demos
    flat = dict(terms, V=np.zeros_like(terms["V"]), w=np.ones_like(terms["w"]))
    c_rot, c_pos = _spread_factors(flat, paths.demos)
    e, C = terms["e"], terms["C"]
    m2 = np.einsum("ri,ri->r", e[:, :3], np.linalg.solve(C[:, :3, :3], e[:, :3, None])[..., 0])
    z = np.abs(e[:, 3:]) / np.sqrt(np.einsum("rii->ri", C[:, 3:, 3:]))
    nu = paths.demos - 2
    want_rot = np.sqrt(np.sort(m2)[int(np.ceil(0.9 * len(m2))) - 1] / (3.0 * fdtri(3, nu, 0.9)))
    want_pos = np.sort(z.ravel())[int(np.ceil(0.9 * z.size)) - 1] / stdtrit(nu, 0.95)
    np.testing.assert_allclose([c_rot, c_pos], [want_rot, want_pos], rtol=1e-6)
    # a duration spread only ever lowers what a phase needs
    c_rot_V, c_pos_V = _spread_factors(dict(flat, V=terms["V"]), paths.demos)
    assert c_rot_V <= c_rot + 1e-12 and c_pos_V <= c_pos + 1e-12
    assert T == S - 1 - int(round(0.6 * (S - 1)))
    assert X.shape[0] * T == len(e)


def test_fit_seen_keeps_the_rule_of_before_when_asked_and_below_spread_from(paths):
    """spread=False is the seventh pass's statistic, spread=True the samples'; the default is the latter from
    SPREAD_FROM demonstrations on (nine here) and the former below (four)."""
    import copy

    before = anticipation.fit_seen(copy.deepcopy(paths), spread=False)
    after = anticipation.fit_seen(copy.deepcopy(paths), spread=True)
    assert before.seen_tolerance == after.seen_tolerance and before.seen_band_scale == after.seen_band_scale
    assert before.seen_band_scales != after.seen_band_scales
    assert paths.demos >= anticipation.SPREAD_FROM  # nine: the default is the samples' statistic
    assert anticipation.fit_seen(copy.deepcopy(paths)).seen_band_scales == after.seen_band_scales
    four = copy.deepcopy(paths)  # below SPREAD_FROM the seventh pass's statistic
    keep = four.deviations[:4], four.log_durations[:4]
    four.deviations, four.log_durations = keep
    assert four.demos < anticipation.SPREAD_FROM
    assert anticipation.fit_seen(copy.deepcopy(four)).seen_band_scales == \
        anticipation.fit_seen(copy.deepcopy(four), spread=False).seen_band_scales


@pytest.mark.slow
def test_fresh_continuations_of_motions_whose_durations_vary_fall_in_their_bands_late(monkeypatch):
    """30 motions of the rich family with durations spread 5 % (ln D): 48 fresh ones seen up to F = 0.8 lie inside
    the 90 % bands of 20 sampled continuations 0.85–0.97 of the time in position and 0.85–0.98 in rotation (this
    family's late position over-covers a little: over three draws of 48 fresh motions .944 / .966 / .961 at the
    twentieth pass's code, .954 / .950 / .964 at the twenty-second's, whose end-time band and samples' durations
    widen with the seen part's surprise and whose λ grid steps by √2). Measured
    (twentieth pass, 48 motions): .944 / .973 with ln D freed in the rest (fit_seen's choice here), .943 / .967 with
    it exact; at F = 0.2, 0.4 and 0.6 .909 / .942, .884 / .903, .890 / .875. Until the twentieth pass the test saw
    12 motions (at the eighth pass .889 / .879; with the seventh pass's statistic, at the true durations, .891 /
    .787), whose coverage moves by several hundredths from seed to seed: the same code held .953 in position on
    them. The rotation's late over-coverage on this family is what the wider rotation bound admits."""
    from rbgp_cli.dynamics.anticipation import Anticipator
    from rbgp_cli.evaluation.under_way import score, split_seen

    monkeypatch.setattr(anticipation, "DURATION_SPREAD", True)
    trained = fit_paths(_rich_family(30, 0, spread=0.05))
    ant = Anticipator(trained)
    cov = None
    for i, tr in enumerate(_rich_family(48, 1, spread=0.05)):
        seen, rest = split_seen(tr, 0.8)
        c = ant.continuation(seen.t, seen.quat, seen.position, samples=20, seed=i)
        trs = c.trajectories(include_samples=True)
        sc = score(trs[0], trs[1:], rest).coverage
        cov = sc if cov is None else cov + sc
    d = cov.to_dict()
    assert 0.85 <= d["coverage_position"] <= 0.97, d
    assert 0.85 <= d["coverage_rotation"] <= 0.98, d
