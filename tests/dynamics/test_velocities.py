"""Velocities from real motion capture (docs/method.md §4.1): resampling, local polynomial derivatives on SE(3),
gaps, sample-and-hold, and what the representations make of them."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from rbgp_cli.dynamics.model import demonstration_pairs, train_model
from rbgp_cli.dynamics.prepare import prepare_trajectory
from rbgp_cli.dynamics.representations import make_representation
from rbgp_cli.dynamics.trajectory import Trajectory
from rbgp_cli.dynamics.velocities import (
    VelocityOptions,
    estimate_velocities,
    integration_drift,
    local_polynomial,
)
from rbgp_cli.errors import InputError
from tests.helpers import quat_angle_between


def polynomial_motion(coef_angle, coef_pos, axis, t):
    """Rotation about a fixed ``axis`` by the polynomial angle Σ c_i t^i, and a polynomial translation.

    Returns the trajectory and the true world-frame velocity ξ(t) = (θ'(t) u, p'(t)), from scipy."""
    u = np.asarray(axis, float) / np.linalg.norm(axis)
    ang = np.polyval(coef_angle[::-1], t)
    dang = np.polyval(np.polyder(np.asarray(coef_angle[::-1])), t)
    rot = Rotation.from_rotvec(ang[:, None] * u)
    q = rot.as_quat()
    q *= np.where(q[:, 3:] < 0, -1.0, 1.0)  # canonical, so the stored sign flips where θ passes π
    P = np.stack([np.polyval(c[::-1], t) for c in coef_pos], axis=1)
    dP = np.stack([np.polyval(np.polyder(np.asarray(c[::-1])), t) for c in coef_pos], axis=1)
    return Trajectory(t, q, P, name="poly"), np.concatenate([dang[:, None] * u, dP], axis=1)


def _irregular_times(n, seed, span=2.0):
    rng = np.random.default_rng(seed)
    steps = rng.uniform(0.8, 1.2, n - 1)
    return np.concatenate([[0.0], np.cumsum(steps)]) * span / steps.sum()


@pytest.mark.parametrize("degree", [2, 3])
@pytest.mark.parametrize("rate", [None, 20.0])
def test_local_polynomial_is_exact_on_polynomial_motion_across_pi(degree, rate):
    """docs/method.md §4.1: exact for a rotation about a fixed axis by a polynomial angle of degree <= d and a
    polynomial translation, also where the angle passes θ = π (the canonical form jumps there)."""
    t = _irregular_times(120, seed=degree)
    coef = [2.6, 0.9, -0.25] + ([0.04] if degree == 3 else [])
    pos = [[0.1, 1.0, -0.3] + ([0.05] if degree == 3 else []), [0.0, -0.5, 0.2], [1.0, 0.0, 0.0]]
    tr, _ = polynomial_motion(coef, pos, [0.2, -1.0, 0.4], t)
    angles = np.polyval(coef[::-1], t)
    assert angles.min() < math.pi < angles.max()  # the motion crosses θ = π
    segs = estimate_velocities(tr, VelocityOptions(rate=rate, window=0.3, degree=degree))
    assert len(segs) == 1
    seg = segs[0]
    assert len(seg.xi) == len(seg.traj)  # instantaneous velocities, one per pose
    _, xi_true = polynomial_motion(coef, pos, [0.2, -1.0, 0.4], seg.traj.t)
    np.testing.assert_allclose(seg.xi, xi_true, atol=1e-9)
    truth, _ = polynomial_motion(coef, pos, [0.2, -1.0, 0.4], seg.traj.t)
    assert np.max(quat_angle_between(seg.traj.quat, truth.quat)) < 1e-10  # smoothed pose = true pose
    np.testing.assert_allclose(seg.traj.position, truth.position, atol=1e-10)


def test_local_polynomial_of_lower_degree_is_not_exact():
    """A cubic motion is not reproduced by a degree-2 fit (the test above could not pass vacuously)."""
    t = np.linspace(0, 2, 100)
    tr, xi_true = polynomial_motion([0.0, 0.5, 0.0, 0.8], [[0, 0, 0, 1.0], [0, 1.0], [0, 1.0]], [0, 0, 1], t)
    q, p, xi, ok = local_polynomial(t, tr.quat, tr.position, t, 0.4, 2)
    assert ok.all()
    assert np.max(np.abs(xi - xi_true)) > 1e-3


@settings(max_examples=25, deadline=None)
@given(rate=st.sampled_from([None, 7.0, 25.0]), seed=st.integers(0, 10_000))
def test_forward_differences_on_a_grid_integrate_back_exactly(rate, seed):
    """Forward differences (window 0), resampled or not: integrating ξ_k over the grid steps from the
    first pose reproduces every grid pose (drift at round-off), also across θ = π."""
    t = _irregular_times(90, seed)
    rng = np.random.default_rng(seed)
    coef = [float(rng.uniform(2.5, 3.0)), float(rng.uniform(0.3, 0.6)), float(rng.uniform(-0.3, 0.3))]
    tr, _ = polynomial_motion(coef, [[0, 0.4], [1.0, -0.2, 0.3], [0.5]], rng.normal(size=3), t)
    segs = estimate_velocities(tr, VelocityOptions(rate=rate))
    drift = integration_drift(segs)
    assert drift["max_position_m"] < 1e-9 and drift["max_rotation_rad"] < 1e-9
    if rate is not None:
        np.testing.assert_allclose(np.diff(segs[0].traj.t), 1.0 / rate, rtol=1e-9)
        assert segs[0].traj.t[0] == t[0]


def test_resampled_poses_lie_on_the_recorded_motion():
    """The grid poses interpolate the samples (slerp, linear): on a constant-velocity motion they are exact."""
    t = _irregular_times(60, 3)
    tr, _ = polynomial_motion([0.2, 1.5], [[0.0, 0.3], [1.0], [0.0, -0.1]], [1, 1, 0], t)
    seg = estimate_velocities(tr, VelocityOptions(rate=13.0))[0]
    truth, xi_true = polynomial_motion([0.2, 1.5], [[0.0, 0.3], [1.0], [0.0, -0.1]], [1, 1, 0], seg.traj.t)
    assert np.max(quat_angle_between(seg.traj.quat, truth.quat)) < 1e-12
    np.testing.assert_allclose(seg.xi, xi_true[:-1], atol=1e-12)


def test_no_training_pair_crosses_a_long_gap():
    """A stretch of lost tracking longer than 4 median steps splits the demonstration into segments."""
    t = np.arange(100) * 0.01
    tr, _ = polynomial_motion([0.0, 1.0], [[0.0, 1.0], [0.0], [0.0]], [0, 0, 1], t)
    gappy = tr.slice(np.r_[0:40, 60:100])  # 0.2 s of lost frames
    for opts in (VelocityOptions(), VelocityOptions(rate=20.0), VelocityOptions(window=0.05)):
        segs = estimate_velocities(gappy, opts)
        assert len(segs) == 2, opts
        assert segs[0].traj.t[-1] <= 0.39 + 1e-12 and segs[1].traj.t[0] >= 0.6 - 1e-12
    # a gap of two frames does not split
    assert len(estimate_velocities(tr.slice(np.r_[0:40, 42:100]), VelocityOptions())) == 1


def test_window_too_short_for_the_rate_is_refused():
    t = np.arange(50) / 30.0
    tr, _ = polynomial_motion([0.0, 1.0], [[0.0, 1.0], [0.0], [0.0]], [0, 0, 1], t)
    with pytest.raises(InputError, match="smoothing window of 0.04 s holds 2 sample"):
        train_model([tr, tr], velocity=VelocityOptions(window=0.04), subsample=1.0)


@pytest.mark.parametrize("bad", [dict(rate=0.0), dict(rate=-5.0), dict(window=-0.1), dict(degree=0), dict(degree=7),
                                 dict(rate=float("nan"))])
def test_velocity_options_are_checked(bad):
    with pytest.raises(InputError):
        VelocityOptions(**bad)


@pytest.mark.parametrize("representation", ["axis-angle", "euler", "quaternion"])
def test_representations_convert_instantaneous_velocities(representation):
    """Local-polynomial pairs in the baselines' coordinates equal the derivative of their own states
    (central differences of the exact motion), and twist_from_output inverts output_from_velocity."""
    t = np.linspace(0, 2, 401)
    tr, xi = polynomial_motion([2.8, 0.6, -0.2], [[0, 1.0], [0.5, 0, 0.2], [0.0]], [0.3, 0.5, -1.0], t)
    rep = make_representation(representation)
    rep.prepare([tr])
    state = rep.state_along(tr.quat, tr.position)
    out = rep.output_from_velocity(state, tr.quat, xi)
    jump = np.max(np.abs(state[2:] - state[:-2]), axis=1) > 0.5  # the canonical rotation vector flips at π
    assert jump.sum() <= (2 if representation == "axis-angle" else 0)
    central = ((state[2:] - state[:-2]) / (t[2] - t[0]))[~jump]
    np.testing.assert_allclose(out[1:-1][~jump], central, atol=2e-4 * np.abs(central).max())
    np.testing.assert_allclose(rep.twist_from_output(state, tr.quat, out), xi, atol=1e-6)


def test_time_input_columns():
    """With a time input the last GP input is the time since the start (seconds) or the phase, and
    phase outputs are velocities per unit phase (D·ξ)."""
    t = 1.0 + np.linspace(0, 2, 41)
    tr, _ = polynomial_motion([0.0, 1.0], [[0.0, 1.0], [0.0], [0.0]], [0, 0, 1], t)
    rep = make_representation("axis-angle")
    X0, Y0, _, _ = demonstration_pairs([tr], rep, VelocityOptions())
    Xs, Ys, _, _ = demonstration_pairs([tr], rep, VelocityOptions(), "seconds")
    Xp, Yp, _, _ = demonstration_pairs([tr], rep, VelocityOptions(), "phase")
    np.testing.assert_allclose(Xs[:, -1], t[:-1] - 1.0)
    np.testing.assert_allclose(Xp[:, -1], (t[:-1] - 1.0) / 2.0)
    np.testing.assert_allclose(Ys, Y0)
    np.testing.assert_allclose(Yp, 2.0 * Y0)


# ----------------------------------------------------------------------------- sample-and-hold
def test_sample_and_hold_runs_become_lost_frames():
    """docs/method.md §4.1: bit-identical poses at later times are the tracker holding the last pose; all but
    the first of a run are lost frames (dropped, or filled with max_gap), and the warning says so."""
    t = np.arange(12) * 0.01
    q = np.tile([0.0, 0.0, 0.0, 1.0], (12, 1))
    p = np.zeros((12, 3))
    p[:, 0] = t
    p[5:9] = p[4]  # held for four frames, then the true pose again
    raw = Trajectory(t, q, p, name="held", source="held.csv")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        clean, report = prepare_trajectory(raw)
    assert report["held"] == 4 and report["dropped"] == 4 and report["lost"] == 0
    np.testing.assert_array_equal(clean.t, np.r_[t[:5], t[9:]])
    assert any("4 samples repeat the previous pose exactly" in str(w.message) for w in caught)
    filled, rep2 = prepare_trajectory(raw, max_gap=0.1)
    assert rep2["filled"] == 4 and len(filled) == 12
    np.testing.assert_allclose(filled.position[:, 0], t, atol=1e-15)  # linear motion restored
    # the forward difference over the hold is the average velocity, not 4 zeros and one 5x spike
    xi = estimate_velocities(clean, VelocityOptions())[0].xi
    np.testing.assert_allclose(xi[:, 3], 1.0, atol=1e-9)


def test_a_pose_held_with_the_sign_flipped_is_still_held_but_motion_is_not():
    t = np.arange(5) * 0.1
    q = np.tile([0.0, 0.0, 0.6, 0.8], (5, 1))
    q[2] *= -1  # same rotation, other sign, same position: held
    p = np.zeros((5, 3))
    p[3:, 2] = [0.1, 0.2]  # moves afterwards
    _, report = prepare_trajectory(Trajectory(t, q, p))
    assert report["held"] == 2  # samples 1 and 2 repeat sample 0
    p2 = p.copy()
    p2[:, 0] = np.arange(5) * 1e-9  # tiny motion: not a hold
    _, report2 = prepare_trajectory(Trajectory(t, q, p2))
    assert report2["held"] == 0
