"""The start map's units (issue 36, third pass: ``variation.start_map``'s ``inputs``): the ridge measures
each start coordinate either over its RMS deviation over the whole path (``"path"``) or over its own
spread at the start (``"start"``), and the second is chosen only where it predicts the left-out
demonstrations better by more than one standard error."""

from __future__ import annotations

import numpy as np
import pytest

from rbgp_cli.dynamics.variation import START_INPUTS, _ridge_map, band_calibration, start_map


def _quiet_start_family(D, S, seed, *, gain=4.0, quiet=0.02, loud=0.2, quiet_noise=0.02, loud_noise=0.3):
    """Deviations δ_d(s) (D, S, 6) with a known conditional mean given the start: two quiet start
    coordinates (the first rotation and the first position one, b_dj ~ N(0, quiet²)) that the motion
    amplifies, δ_dj(s) = b_dj (1 + gain·s), and four loud ones (N(0, loud²)) that it forgets,
    δ_dj(s) = b_dj (1 − s)², plus s·n_j·ε_d(s), ε standard normal per phase and coordinate, n_j the
    quiet or loud noise. The quiet start varies little next to what it does later and next to the loud
    ones (the hand raises' start rotation), and the loud coordinates' noise asks for a strong ridge: one
    ridge in path units then regularises the quiet start away."""
    rng = np.random.default_rng(seed)
    s = np.linspace(0.0, 1.0, S)
    b = rng.normal(size=(D, 6)) * np.array([quiet, loud, loud, quiet, loud, loud])
    n = np.array([quiet_noise, loud_noise, loud_noise, quiet_noise, loud_noise, loud_noise])
    delta = b[:, None, :] * _shapes(s, gain)[None]
    return delta + s[None, :, None] * n * rng.normal(size=(D, S, 6)), s


def _shapes(s, gain=4.0):
    """(S, 6): how each start coordinate carries on over phase in :func:`_quiet_start_family`."""
    quiet = np.isin(np.arange(6), [0, 3])
    return np.where(quiet[None], (1.0 + gain * s)[:, None], ((1.0 - s) ** 2)[:, None])


def _truth(start, s, gain=4.0):
    """The true conditional mean of :func:`_quiet_start_family` (T, S, 6) for start deviations (T, 6)
    (the noise is 0 at s = 0, so the start is b itself)."""
    return start[:, None, :] * _shapes(s, gain)[None]


def test_both_units_give_least_squares_as_the_ridge_vanishes():
    """λ → 0: the ridge is the least-squares regression whatever the units (an independent oracle:
    numpy's lstsq of each phase's centred deviations on the centred starts)."""
    rng = np.random.default_rng(3)
    delta = rng.normal(size=(25, 11, 6)) * np.array([0.01, 0.2, 0.05, 0.3, 0.02, 0.1])
    delta[:, 1:] += np.einsum("ij,dj->di", rng.normal(size=(6, 6)), delta[:, 0])[:, None, :]
    scale = np.sqrt(np.mean(delta**2, axis=(0, 1)))
    c = delta - delta.mean(axis=0)
    want = np.stack([np.linalg.lstsq(c[:, 0], c[:, k], rcond=None)[0].T for k in range(11)])  # (S, 6, 6)
    for units in START_INPUTS:
        mu, B = _ridge_map(delta, scale, 1e-12, units)
        np.testing.assert_allclose(mu, delta.mean(axis=0), atol=1e-15)
        np.testing.assert_allclose(B, want, atol=1e-6)


@pytest.mark.slow
def test_the_start_units_are_chosen_where_the_start_varies_little_but_tells_much():
    """:func:`_quiet_start_family` with 15 demonstrations, 8 seeds: the map is told in the start's own
    units in at least 7, and on 500 fresh starts its error in the two quiet coordinates against the true
    conditional mean is below 0.7 of the truth's own RMS (mean over the seeds) and below 0.8 of the error
    of the path-unit map with its own cross-validated λ (which barely conditions on the quiet start: its
    error is about the truth's size)."""
    from rbgp_cli.dynamics.variation import RIDGE_GRID

    chosen, err, err_path = 0, [], []
    quiet = [0, 3]
    for seed in range(8):
        delta, s = _quiet_start_family(15, 21, seed)
        out = start_map(delta)
        chosen += out["inputs"] == "start"
        start = _quiet_start_family(500, 21, 100 + seed)[0][:, 0]
        truth = _truth(start, s)[..., quiet]
        size = np.sqrt(np.mean(truth**2))
        pred = out["mean"][None] + np.einsum("sij,dj->dsi", out["map"], start - out["mean"][0])
        lam = RIDGE_GRID[int(np.argmin(out["errors"]))]  # the path units' own choice
        mu, B = _ridge_map(delta, np.sqrt(np.mean(delta**2, axis=(0, 1))), lam, "path")
        pred_path = mu[None] + np.einsum("sij,dj->dsi", B, start - mu[0])
        err.append(np.sqrt(np.mean((pred[..., quiet] - truth) ** 2)) / size)
        err_path.append(np.sqrt(np.mean((pred_path[..., quiet] - truth) ** 2)) / size)
    assert chosen >= 7
    assert np.mean(err) < 0.7
    assert np.mean(err) < 0.8 * np.mean(err_path)
    assert np.mean(err_path) > 0.8  # the path units' map is nearly the unconditioned mean there


@pytest.mark.slow
def test_a_start_that_tells_nothing_keeps_the_path_units():
    """Deviations independent of their start: the start units never predict better by a standard error
    often (the one-standard-error rule): path units in at least 9 of 10 seeds, and the map stays small."""
    kept = 0
    for seed in range(10):
        rng = np.random.default_rng(seed)
        delta = rng.normal(size=(30, 21, 6)) * np.linspace(0.2, 1.0, 21)[None, :, None]
        delta[:, 0] *= np.array([0.05, 1.0, 1.0, 0.05, 1.0, 1.0])  # two start coordinates barely vary
        out = start_map(delta)
        kept += out["inputs"] == "path"
        assert len(out["errors_start"]) == len(out["errors"])
    assert kept >= 9


@pytest.mark.slow
def test_the_bands_measure_the_map_the_rollout_follows():
    """band_calibration with the start units predicts each left-out demonstration with the start-unit map
    (as the mean rollout does, model.train_model passes the units): on the quiet-start family the rotation
    factor measured with it is smaller than with the path units at the same λ."""
    delta, s = _quiet_start_family(15, 21, 0)
    out = start_map(delta)
    assert out["inputs"] == "start"
    a = band_calibration(delta, s, ridge=out["ridge"], inputs="start")
    b = band_calibration(delta, s, ridge=out["ridge"], inputs="path")
    assert a["band_scale"] != b["band_scale"]  # the left-out errors are those of the map given
    assert a["random"][0] < b["random"][0]  # and the quiet start's rotation is predicted better
