"""rbgp train chooses the GP residual's gain from a cheap fit first (rbgp_cli/dynamics/model.py,
``train_model``; issue 35's seventh pass): where that fit switches the residual off by a clear margin the
full fit is skipped, and what users get at g = 0 (mean rollouts, samples, bands) is the same as with the
full fit; otherwise the full fit runs as before."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from rbgp_cli.cli.report import _residual_gain_text
from rbgp_cli.dynamics.model import QUICK_HYPER_POINTS, residual_off_clearly, train_model
from rbgp_cli.dynamics.rollout import rollout_for
from tests.dynamics.test_residual_gain import family

SMALL = {"shared": True, "explore_size": 0}


def _choice(error, se, gain=0.0, best=0.0, chosen="left-out rollouts"):
    return {"gain": gain, "best": best, "chosen": chosen, "grid": [0.0, 0.25, 0.5, 1.0], "error": error,
            "standard_error": se}


def test_off_with_room_to_spare_means_no_gain_closer_than_g0_by_half_a_standard_error():
    assert residual_off_clearly(_choice([1.0, 1.02, 1.05, 1.2], [0.0, 0.01, 0.02, 0.05]))
    # the handovers' case: every J within a few tenths of a per cent, none below J(0)
    assert residual_off_clearly(_choice([1.0, 1.0, 1.001, 1.003], [0.0, 0.001, 0.002, 0.004]))
    # a gain better than g = 0 by less than half a standard error: still off
    assert residual_off_clearly(_choice([1.0, 0.996, 1.05, 1.2], [0.0, 0.01, 0.02, 0.05], best=0.25))
    # better by more than half (0.6 SE) but less than one: the rule chose 0, the full fit might not
    assert not residual_off_clearly(_choice([1.0, 0.994, 1.05, 1.2], [0.0, 0.01, 0.02, 0.05], best=0.25))
    assert residual_off_clearly(_choice([1.0, 0.994, 1.05, 1.2], [0.0, 0.01, 0.02, 0.05], best=0.25), margin=1.0)
    # round-off ties (standard errors 0) count as off
    assert residual_off_clearly(_choice([1.0, 1.0 - 1e-12, 1.0, 1.0], [0.0, 0.0, 0.0, 0.0], best=0.25))
    # another gain chosen, a given gain, no choice at all
    assert not residual_off_clearly(_choice([1.0, 0.9, 0.8, 0.7], [0.1, 0.1, 0.1, 0.0], gain=1.0, best=1.0))
    assert not residual_off_clearly({"gain": 0.0, "chosen": "given"})
    assert not residual_off_clearly(None)


def _rollouts(model, test, samples=5):
    res = rollout_for(model, np.array([t.quat[0] for t in test]), np.array([t.position[0] for t in test]),
                      [t.duration for t in test], with_std=False, samples=samples, seed=3)
    return res


@pytest.mark.slow
def test_a_residual_clearly_off_skips_the_full_fit_and_the_rollouts_are_those_of_the_full_fit_at_g0():
    demos = family("noise", n=13, seed=3)
    train, test = demos[:10], demos[10:]
    quick = train_model(train, **SMALL, calibrate=False, noise_scale=1.0)
    rec = quick.summary["residual_gain"]
    assert quick.residual_gain == 0.0 and residual_off_clearly(rec)
    assert rec["fit"]["full_fit"] is False and rec["fit"]["restarts"] == 1 and rec["fit"]["calibration_points"] == 500
    assert quick.summary["gp"]["hyper_points"] == min(QUICK_HYPER_POINTS, len(quick.gp.X))
    # an explicit gain fits as before: three starts on up to 400 points, the same options otherwise
    full = train_model(train, **SMALL, calibrate=False, noise_scale=1.0, residual_gain=0.0)
    assert "fit" not in full.summary["residual_gain"] and full.residual_gain == 0.0
    assert full.summary["gp"]["hyper_points"] == min(400, len(full.gp.X))
    # the hyperparameters differ (a cheaper fit) ...
    assert [f.values for f in quick.gp.fits] != [f.values for f in full.gp.fits]
    # ... and at g = 0 nothing users get depends on them: mean rollouts, samples and bands are the same
    a, b = _rollouts(quick, test), _rollouts(full, test)
    np.testing.assert_array_equal(a.position, b.position)
    np.testing.assert_array_equal(a.quat, b.quat)
    np.testing.assert_array_equal(a.sample_position, b.sample_position)
    np.testing.assert_array_equal(a.band_position, b.band_position)
    np.testing.assert_array_equal(a.band_rotation, b.band_rotation)
    # the summary says so, with the flag that fits the residual
    text = _residual_gain_text(rec)
    assert text.startswith("GP residual off (gain 0)") and "--residual-gain 1" in text and "skipped" in text
    assert "skipped" not in _residual_gain_text(full.summary["residual_gain"])


@pytest.mark.slow
def test_a_residual_the_cheap_fit_leaves_open_gets_todays_full_fit():
    demos = family("field", n=10)
    model = train_model(demos, **SMALL)
    rec = model.summary["residual_gain"]
    assert rec["fit"]["full_fit"] is True and model.residual_gain > 0.0
    # the same GP as training with the gain given (the full fit: the options' starts and points)
    given = train_model(demos, **SMALL, residual_gain=1.0)
    assert model.summary["gp"]["hyper_points"] == given.summary["gp"]["hyper_points"]
    for f, g in zip(model.gp.fits, given.gp.fits):
        assert f.values == g.values
    np.testing.assert_array_equal(_rollouts(replace(model, residual_gain=1.0), demos[:3], 0).position,
                                  _rollouts(given, demos[:3], 0).position)


@pytest.mark.slow
def test_the_paper_scale_options_never_take_the_cheap_fit():
    # bench_train_cli.py's paper-scale job pins --time-input none --prior none: the gain is 1 (not chosen)
    # and the fit is the full one, as before
    demos = family("noise", n=6, seed=1)
    model = train_model(demos, **SMALL, time_input=None, prior=None)
    rec = model.summary["residual_gain"]
    assert rec["gain"] == 1.0 and rec["chosen"] == "default" and "fit" not in rec
    assert model.summary["gp"]["hyper_points"] == min(400, len(model.gp.X))


def test_practical_equivalence_keeps_the_smaller_gain_when_the_improvement_is_too_small_to_matter():
    from rbgp_cli.dynamics.residual_gain import EQUIVALENT_FRACTION, smallest_equivalent

    assert EQUIVALENT_FRACTION == 0.005
    # sample_data/'s case: every J 1.000, consistently a little lower with the residual (kept by either rule)
    assert smallest_equivalent([1.0, 0.99998, 0.99996, 0.99992], [0.0006, 0.0005, 0.0003, 0.0]) == 0
    # better by 0.4 % of J(0) with a standard error of 0.1 %: equivalent; by 0.6 %: the gain is taken
    assert smallest_equivalent([1.0, 0.998, 0.997, 0.996], [0.001, 0.001, 0.001, 0.0]) == 0
    assert smallest_equivalent([1.0, 0.998, 0.996, 0.994], [0.001, 0.001, 0.001, 0.0]) == 1  # ¼: within 0.5 % of the best
    assert smallest_equivalent([1.0, 0.998, 0.996, 0.994], [0.001, 0.001, 0.001, 0.0], equal=0.0) == 3
    # the one-standard-error rule as before: a large improvement within a larger standard error
    assert smallest_equivalent([1.0, 0.9, 0.95, 0.97], [0.15, 0.0, 0.1, 0.1]) == 0
    assert smallest_equivalent([1.0, 0.9, 0.95, 0.97], [0.05, 0.0, 0.1, 0.1]) == 1


def test_off_clearly_weighs_each_gain_against_g0_and_takes_the_equivalence_margin():
    # sample_data/'s cheap fit: the best gain (1) is 8e-5 below J(0); its standard error against the best is
    # 0 (it is the best), against g = 0 6e-4: off by the half standard error, and by the margin
    rec = {**_choice([1.0, 0.99998, 0.99996, 0.99992], [0.00059, 0.00045, 0.0003, 0.0], best=1.0),
           "standard_error_zero": [0.0, 0.00015, 0.0003, 0.0006]}
    assert residual_off_clearly(rec)
    assert residual_off_clearly({k: v for k, v in rec.items() if k != "standard_error_zero"})  # the margin alone
    # better than g = 0 by 0.3 % with standard errors of 0.01 %: half the margin (0.25 %) is exceeded
    rec = {**_choice([1.0, 0.999, 0.998, 0.997], [0.0003, 0.0002, 0.0001, 0.0], best=1.0),
           "standard_error_zero": [0.0, 0.0001, 0.0001, 0.0001]}
    assert not residual_off_clearly(rec)
    assert residual_off_clearly(rec, margin=1.0)


def test_the_summary_names_the_margin_only_for_a_choice_made_with_it():
    rec = _choice([1.0, 0.99998, 0.99996, 0.99992], [0.00059, 0.00045, 0.0003, 0.0], best=1.0)
    assert _residual_gain_text(rec).endswith("within one standard error)")  # an older model file's record
    rec["standard_error_zero"] = [0.0, 0.00015, 0.0003, 0.0006]
    assert _residual_gain_text(rec).endswith("within one standard error or 0.5 %)")
