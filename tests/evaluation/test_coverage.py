"""The calibration measure of docs/method.md §11 against its oracle: samples and the real motion drawn from
one Gaussian process cover each other at the nominal 90 %."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rbgp_cli.dynamics.trajectory import Trajectory
from rbgp_cli.evaluation.coverage import MIN_SAMPLES, Coverage, band_thresholds, prediction_coverage


def _draws(rng, n, T=15, rot_sd=0.05, pos_sd=0.02):
    """n smooth trajectories of one Gaussian process: a base motion plus a random offset and slope
    (position) and a random constant tangent deviation (rotation), so every step is Gaussian."""
    t = np.linspace(0.0, 2.0, T)
    base_rot = Rotation.from_rotvec(np.outer(t, [0.3, 1.2, -0.4]) + [0.0, 0.0, 2.9])  # passes near θ = π
    base_pos = np.stack([np.sin(t), 0.5 * t, 1.0 + 0.1 * t**2], axis=1)
    out = []
    for _ in range(n):
        dev = Rotation.from_rotvec(rng.normal(0.0, rot_sd, 3))
        q = (base_rot * dev).as_quat()  # body-frame deviation: R̄ exp(v)
        p = base_pos + rng.normal(0.0, pos_sd, 3) + np.outer(t, rng.normal(0.0, pos_sd, 3))
        out.append(Trajectory(t, q, p))
    return out


@pytest.mark.parametrize("K", [8, 20])
@pytest.mark.slow
def test_fresh_draws_of_the_same_process_are_covered_90_percent_of_the_time(K):
    rng = np.random.default_rng(K)
    total = Coverage()
    for _ in range(250):
        draws = _draws(rng, K + 1)
        total = total + prediction_coverage(draws[:K], draws[K], T=15)
    c = total.to_dict()
    assert abs(c["coverage_position"] - 0.90) < 0.03, c
    assert abs(c["coverage_rotation"] - 0.90) < 0.03, c
    assert 0.0 < c["band_position"] < 0.2 and 0.0 < c["band_rotation"] < 0.5


@pytest.mark.slow
def test_samples_too_narrow_or_shifted_cover_less_and_too_wide_cover_more():
    rng = np.random.default_rng(5)
    narrow, wide = Coverage(), Coverage()
    for _ in range(100):
        real = _draws(rng, 1)[0]
        narrow = narrow + prediction_coverage(_draws(rng, 20, rot_sd=0.01, pos_sd=0.004), real, T=15)
        wide = wide + prediction_coverage(_draws(rng, 20, rot_sd=0.2, pos_sd=0.08), real, T=15)
    n, w = narrow.to_dict(), wide.to_dict()
    assert n["coverage_position"] < 0.5 and n["coverage_rotation"] < 0.3, n
    assert w["coverage_position"] > 0.98 and w["coverage_rotation"] > 0.98, w
    assert w["band_position"] > 5 * n["band_position"]


def test_thresholds_are_the_t_and_hotelling_quantiles():
    t, h = band_thresholds(20)
    assert t == pytest.approx(1.7291 * np.sqrt(1 + 1 / 20), rel=1e-4)  # t_{19, 0.95}
    assert h == pytest.approx(21 * 19 * 3 / (20 * 17) * 2.4374, rel=1e-3)  # F_{0.90}(3, 17)
    with pytest.raises(ValueError, match="at least"):
        band_thresholds(MIN_SAMPLES - 1)


def test_identical_samples_give_a_finite_region_and_the_real_motion_outside():
    rng = np.random.default_rng(1)
    one = _draws(rng, 1)[0]
    c = prediction_coverage([one] * 6, _draws(rng, 1)[0], T=10).to_dict()
    assert c["coverage_position"] < 0.2 and c["coverage_rotation"] == 0.0
    assert np.isfinite(c["band_rotation"])
