"""The prior's pull that follows the demonstrations' convergence (docs/method.md §7, "The pull's
profile"): the gain recovers a known rate of convergence, a deviation shrinks as the demonstrations'
spread does, a rollout's step never overshoots, and model files keep the profile."""

from __future__ import annotations

import numpy as np
import pytest

from rbgp_cli.dynamics.model import prior_mean_outputs, pull_gains, train_model
from rbgp_cli.dynamics.representations import AxisAngle
from rbgp_cli.dynamics.variation import PULL_CAP, pull_profile, start_map
from tests.dynamics.test_variation import hierarchical_demos

S = 51
GRID = np.linspace(0.0, 1.0, S)


def _spread(rate, s=GRID, after=0.5):
    """σ(s): 1 up to ``after``, then exp(−rate·(s − after)); a negative rate grows."""
    return np.exp(-rate * np.clip(s - after, 0.0, None))


def _deviations(sigmas, D=60, seed=0):
    """δ_d(s) = w_d ⊙ σ(s) for s > 0 and an independent start δ_d(0) = u_d: the start tells nothing
    about the rest, and each coordinate's spread about any start-conditioned path is ∝ σ_j(s) exactly."""
    rng = np.random.default_rng(seed)
    w, u = rng.normal(size=(D, 6)), 0.01 * rng.normal(size=(D, 6))
    delta = w[:, None, :] * np.stack(sigmas, axis=1)[None]
    delta[:, 0] = u
    return delta


def _profile(delta, floor=1.0):
    cond = start_map(delta, seed=0)
    return pull_profile(delta, cond["mean"], cond["map"], GRID, floor)


def test_the_gain_is_the_known_rate_at_which_the_spread_shrinks():
    """Oracle: σ_j(s) = e^{−k_j (s − 0.5)} after s = 0.5 gives a_j = k_j there (capped at PULL_CAP), and
    the floor (--prior-gain) where the spread holds or grows."""
    rates = [8.0, 40.0, 0.0, -3.0, 3.0, 0.5]
    a = _profile(_deviations([_spread(k) for k in rates]), floor=1.0)
    late = GRID >= 0.58  # windows of 0.1 wholly inside the shrinking part
    np.testing.assert_allclose(a[late, 0], 8.0, rtol=1e-6)
    np.testing.assert_allclose(a[late, 1], PULL_CAP, rtol=1e-9)
    np.testing.assert_allclose(a[late, 4], 3.0, rtol=1e-6)
    assert np.all(a[:, 2] == 1.0) and np.all(a[:, 3] == 1.0) and np.all(a[:, 5] == 1.0)  # 0.5 < floor
    early = (GRID > 0.05) & (GRID <= 0.42)
    assert np.all(a[early] == 1.0)  # nothing shrinks before s = 0.5
    assert np.all(_profile(_deviations([_spread(k) for k in rates]), floor=5.0) >= 5.0)


def _pulled(mean, e0, s0, h):
    """A deviation e0 (m) in x from a resting mean path, carried from phase s0 to 1 by the prior's pull
    alone in explicit steps of h (as a rollout integrates it); returns e(1)/e0."""
    rep = AxisAngle()
    state = np.array([[0.0, 0.0, 0.0, e0, 0.0, 0.0]])
    s = s0
    while s < 1.0 - 1e-12:
        xi = prior_mean_outputs(rep, state, mean, np.array([s]), step=h)
        state = state + h * xi
        s += h
    return state[0, 3] / e0


def _resting_path(profile=None):
    mean = {"kind": "path", "gain": 1.0, "s": GRID, "quat": np.tile([0.0, 0.0, 0.0, 1.0], (S, 1)),
            "position": np.zeros((S, 3)), "velocity": np.zeros((S - 1, 6)), "feedforward": "secant"}
    if profile is not None:
        mean["gain_profile"] = profile
    return mean


def test_a_deviation_shrinks_as_the_demonstrations_spread_shrinks():
    """Before (a constant pull of 1 per unit phase) a deviation at phase 0.6 kept e^{−0.4} = 67 % of
    itself to the end, where the demonstrations keep e^{−6·0.5}/e^{−6·0.1} = 9 % of their spread; with
    the profile it keeps what they keep."""
    sigma = _spread(6.0)
    profile = _profile(_deviations([sigma] * 6))
    kept = _pulled(_resting_path(profile), 0.01, 0.6, 0.002)
    want = sigma[-1] / sigma[30]
    assert kept == pytest.approx(want, rel=0.15)
    assert _pulled(_resting_path(), 0.01, 0.6, 0.002) == pytest.approx(np.exp(-0.4), rel=0.01)


def test_one_step_never_carries_a_pose_past_its_reference():
    """With a step h the gain is at most 1/|h| (e_{k+1} = (1 − a h) e_k ≥ 0): a profile of 20 on steps of
    0.1 (a 1 s motion on the 10 Hz training grid) pulls with 10 and lands on the path, not past it."""
    mean = _resting_path(np.full((S, 6), PULL_CAP))
    s = np.array([0.3, 0.95])
    assert np.all(pull_gains(mean, s) == PULL_CAP)
    assert np.all(pull_gains(mean, s, 0.1) == 10.0) and np.all(pull_gains(mean, s, -0.1) == 10.0)
    assert np.all(pull_gains(mean, s, 0.01) == PULL_CAP)
    assert _pulled(mean, 0.01, 0.5, 0.1) == pytest.approx(0.0, abs=1e-12)
    assert _pulled(mean, 0.01, 0.5, 0.2) >= 0.0  # no overshoot at any step


def test_the_gain_is_the_grid_intervals_value_at_any_phase():
    profile = np.tile(np.arange(S, dtype=float)[:, None], (1, 6)) + 1.0
    mean = _resting_path(profile)
    a = pull_gains(mean, np.array([0.0, 0.019, 0.02, 0.5, 0.999, 1.0, 1.2]))
    np.testing.assert_array_equal(a[:, 0], [1.0, 1.0, 2.0, 26.0, 50.0, 51.0, 51.0])


def test_training_keeps_the_profile_only_where_asked_and_files_keep_it(tmp_path):
    from rbgp_cli.io.model_store import load_model, save_model

    demos = hierarchical_demos(12, 3, samples=30)
    small = dict(restarts=1, max_points=120)
    model = train_model(demos, **small)
    profile = model.mean["gain_profile"]
    assert profile.shape == (len(model.mean["s"]), 6) and np.all(profile >= model.mean["gain"])
    assert model.summary["prior"]["gain_max"] == pytest.approx(float(profile.max()))
    save_model(model, tmp_path / "m.rbgp")
    loaded, header = load_model(tmp_path / "m.rbgp")
    assert header["prior"]["gain_profile"] is True
    np.testing.assert_array_equal(loaded.mean["gain_profile"], profile)
    plain = train_model(demos, pull_profile=False, **small)
    assert "gain_profile" not in plain.mean and "gain_max" not in plain.summary["prior"]
    save_model(plain, tmp_path / "p.rbgp")
    assert "gain_profile" not in load_model(tmp_path / "p.rbgp")[1]["prior"]
    unconditioned = train_model(demos, start_conditioning=False, **small)
    assert "gain_profile" not in unconditioned.mean  # the profile is about start-conditioned paths


def test_a_file_that_promises_a_profile_without_it_is_refused(tmp_path):
    from rbgp_cli.errors import InputError
    from rbgp_cli.io.model_store import load_model, save_model
    from tests.io.test_model_store_v2 import _rewrite

    model = train_model(hierarchical_demos(8, 4, samples=30), restarts=1, max_points=100)
    save_model(model, tmp_path / "m.rbgp")
    _rewrite(tmp_path / "m.rbgp", tmp_path / "bad.rbgp", drop=("prior_gain_profile",))
    with pytest.raises(InputError, match="prior_gain_profile"):
        load_model(tmp_path / "bad.rbgp")
