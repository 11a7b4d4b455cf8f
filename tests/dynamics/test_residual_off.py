"""At g = 0 the GP's residual mean is multiplied by zero, so it is not evaluated
(``MotionModel.residual_off``; docs/method.md §7, "The residual's gain"). Oracle: the same model whose
GP is evaluated and multiplied by 0 as before (a subclass that never reports the residual off) gives
the same numbers everywhere the mean goes (rollouts, samples, bands, goals, a motion under way); a
counter on the GP shows that the g = 0 model did not call it; a model with g ≠ 0 still adds g · μ_GP."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from rbgp_cli.dynamics.anticipation import Anticipator
from rbgp_cli.dynamics.model import MotionModel, train_model
from rbgp_cli.dynamics.rollout import rollout_conditioned, rollout_for
from tests.dynamics.test_residual_gain import family


class _Evaluated(MotionModel):
    """The computation before the skip: the GP evaluated and its mean multiplied by g even at g = 0."""

    @property
    def residual_off(self) -> bool:
        return False


class _Counting:
    """A GP wrapper that counts predictions."""

    def __init__(self, gp):
        self._gp, self.calls = gp, 0

    def __getattr__(self, name):
        return getattr(self._gp, name)

    def predict(self, *args, **kwargs):
        self.calls += 1
        return self._gp.predict(*args, **kwargs)


@pytest.fixture(scope="module")
def fitted():
    demos = family("field", n=10)
    # a GP that has learnt a residual (family "field": a bend only the GP expresses), its gain set to 0
    model = train_model(demos[:8], shared=True, explore_size=0, residual_gain=0.0)
    return model, demos


def _pair(model):
    """(the g = 0 model with a counting GP, the same model evaluating its GP)."""
    off = replace(model, gp=_Counting(model.gp))
    on = replace(model)
    on.__class__ = _Evaluated
    return off, on


def _starts(demos):
    return np.array([t.quat[0] for t in demos]), np.array([t.position[0] for t in demos])


@pytest.mark.slow
def test_the_mean_at_g0_is_the_prior_mean_without_calling_the_gp(fitted):
    model, demos = fitted
    off, on = _pair(model)
    assert off.residual_off and not on.residual_off
    rng = np.random.default_rng(0)
    X = model.gp.X[rng.choice(len(model.gp.X), 40, replace=False)] + rng.normal(0.0, 0.01, (40, model.gp.X.shape[1]))
    dev = rng.normal(0.0, 0.02, (40, 6))
    for kw in ({}, {"start_dev": dev}):
        np.testing.assert_array_equal(off.predict_output(X, **kw), on.predict_output(X, **kw))
    np.testing.assert_array_equal(off.residual(X), on.residual(X))
    assert off.gp.calls == 0
    # the GP's residual is not zero here, so evaluating it and multiplying by 0 is a real difference in work
    assert np.max(np.abs(model.gp.predict(X))) > 1e-3
    # the std is the GP's own: asked for, it is evaluated
    mu, sd = off.predict_output(X, return_std=True)
    np.testing.assert_array_equal(mu, on.predict_output(X))
    assert off.gp.calls == 1 and np.all(sd > 0)
    q, p = demos[0].quat[:5], demos[0].position[:5]
    tau = np.linspace(0.0, 0.4, 5)
    np.testing.assert_array_equal(off.predict(q, p, return_std=False, tau=tau), on.predict(q, p, return_std=False, tau=tau))
    assert off.gp.calls == 1


@pytest.mark.slow
def test_rollouts_samples_bands_goals_and_continuations_at_g0_are_those_with_the_gp_evaluated(fitted):
    model, demos = fitted
    off, on = _pair(model)
    q0, p0 = _starts(demos[7:])
    durations = [t.duration for t in demos[7:]]
    a = rollout_for(off, q0, p0, durations, with_std=False, samples=4, seed=2)
    b = rollout_for(on, q0, p0, durations, with_std=False, samples=4, seed=2)
    for name in ("quat", "position", "sample_quat", "sample_position", "band_position", "band_rotation"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert off.gp.calls == 0
    # with the std along the mean trajectories the GP is evaluated (its std), the poses the same
    c = rollout_for(off, q0, p0, durations, with_std=True)
    np.testing.assert_array_equal(c.position, a.position)
    assert off.gp.calls > 0
    calls = off.gp.calls
    goal = dict(goal_quat=np.array([t.quat[-1] for t in demos[7:]]), goal_position=np.array([t.position[-1] for t in demos[7:]]))
    a = rollout_conditioned(off, q0, p0, durations=durations, samples=3, seed=1, **goal)
    b = rollout_conditioned(on, q0, p0, durations=durations, samples=3, seed=1, **goal)
    for name in ("quat", "position", "sample_position", "band_position"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    seen = demos[9]
    k = len(seen.t) // 3
    ca = Anticipator(model.paths, off).continuation(seen.t[:k], seen.quat[:k], seen.position[:k], samples=3, seed=4)
    cb = Anticipator(model.paths, on).continuation(seen.t[:k], seen.quat[:k], seen.position[:k], samples=3, seed=4)
    np.testing.assert_array_equal(ca.position, cb.position)
    np.testing.assert_array_equal(ca.quat, cb.quat)
    assert off.gp.calls == calls


@pytest.mark.slow
def test_a_nonzero_gain_still_adds_its_share_of_the_gp(fitted):
    model, _ = fitted
    half = replace(model, residual_gain=0.5)
    assert not half.residual_off
    X = model.gp.X[::7]
    prior = model.prior_mean(X)
    np.testing.assert_allclose(half.predict_output(X), prior + 0.5 * model.gp.predict(X), rtol=0, atol=1e-12)
    np.testing.assert_allclose(half.residual(X), 0.5 * model.gp.predict(X), rtol=0, atol=1e-15)
    # and differs from the prior alone where the GP has learnt something
    assert np.max(np.abs(half.predict_output(X) - prior)) > 1e-4
