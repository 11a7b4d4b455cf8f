"""The start-only bands widened by the start's surprise (issue 36, seventeenth pass; dynamics/variation.py, "The
start's surprise"): the law against an independent computation (scipy's rotations, numpy's inverse), the reference
as the upper quartile of the starts left out, the threshold in demonstrations and the choice to keep it, fresh draws
of a family whose unusual people start elsewhere, and the model file."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rbgp_cli.dynamics.variation import (START_BEYOND_FROM, START_SURPRISE_FROM, START_SURPRISE_QUANTILE,
                                         band_calibration, demonstration_deviations, demonstration_variation,
                                         start_covariance, start_surprise)
from rbgp_cli.geometry.so3 import exp_quat, quat_multiply
from tests.dynamics.synthetic import timed_demos
from tests.dynamics.test_variation import SIGMA_POS, SIGMA_ROT, hierarchical_demos


def people(n, seed, start=1.0, spread=1.0, other=0.0, samples=60):
    """``n`` demonstrations of tests/dynamics/test_variation.py's hierarchical process whose start offsets are
    ``start`` times as spread and whose own deviations ``spread`` times as large; with ``other`` > 0 that fraction of
    them (at random) starts three times as far off and deviates three times as much: people who do the task another
    way from another place, so that an unusual start says the motion will be unusual too."""

    def pose(rng, s):
        k = 3.0 if other and rng.random() < other else 1.0
        a_pos, b_pos = rng.normal(0, k * spread * SIGMA_POS, 3), rng.normal(0, k * start * 0.03, 3)
        a_rot, b_rot = rng.normal(0, k * spread * SIGMA_ROT, 3), rng.normal(0, k * start * 0.05, 3)
        p = np.stack([0.4 * s, 0.2 * np.sin(np.pi * s), 1.0 - 0.3 * s**2], axis=1) + np.outer(s, a_pos) + b_pos
        base_q = exp_quat(np.outer(s, [0.2, 1.0, 0.4]) + [0.0, 0.0, 2.8])
        return quat_multiply(exp_quat(np.outer(s, a_rot) + b_rot), base_q), p

    return timed_demos(n, seed, samples, pose)


@pytest.fixture(scope="module")
def trained():
    demos = people(40, 7, other=0.25)
    v = demonstration_variation(demos)
    assert v.calibration["start_widening"]["rotation"], v.calibration  # the start says who deviates: kept
    return demos, v


def test_the_widening_is_the_starts_mahalanobis_distance_against_the_upper_quartile(trained):
    """s = √max(1, ρ / ρ̄), ρ = cᵀ Σ_0⁻¹ c / 6 of c = (log(R R̄(0)ᵀ), p − p̄(0)) − μ(0): recomputed with scipy's
    rotation vector and numpy's inverse, for starts from a hair (θ ≈ 1e-7) to far off the anchor; the mean start
    is not widened, and a start moved further along the same direction is widened more."""
    _, v = trained
    info = v.start_surprise
    assert info is not None and info["reference"] > 0
    anchor = Rotation.from_quat(info["quat"])
    inv = np.linalg.inv(info["covariance"])
    rng = np.random.default_rng(3)
    for size in (1e-7, 1e-3, 0.05, 0.3, 1.0):
        for _ in range(4):
            rotvec = rng.normal(size=3)
            rotvec *= size / np.linalg.norm(rotvec)
            R = Rotation.from_rotvec(rotvec + info["mean"][:3]) * anchor
            p = info["position"] + info["mean"][3:] + size * rng.normal(size=3) * 0.1
            c = np.concatenate([(R * anchor.inv()).as_rotvec(), p - info["position"]]) - info["mean"]
            rho = float(c @ inv @ c) / 6.0
            want = np.sqrt(max(1.0, rho / info["reference"]))
            beyond = np.sqrt(max(1.0, rho / info["beyond"]))  # every part, beyond the least typical demonstration
            got = v.start_widening(R.as_quat()[None], p[None])
            np.testing.assert_allclose(got, [[want if info["parts"][0] else beyond, want if info["parts"][1] else beyond]],
                                       rtol=1e-7)
            np.testing.assert_allclose(v.start_beyond(R.as_quat()[None], p[None]), [rho / info["beyond"]], rtol=1e-7)
    mean_start = Rotation.from_rotvec(info["mean"][:3]) * anchor
    assert np.all(v.start_widening(mean_start.as_quat()[None], (info["position"] + info["mean"][3:])[None]) == 1.0)
    far = [v.start_widening(mean_start.as_quat()[None], (info["position"] + info["mean"][3:] + [k * 0.03, 0, 0])[None]).max()
           for k in (1.0, 3.0, 6.0, 12.0)]
    assert far[0] <= far[1] < far[2] < far[3] and far[3] > 3.0, far


def test_the_reference_is_the_upper_quartile_of_the_starts_left_out_one_at_a_time(trained):
    """ρ̄ is the START_SURPRISE_QUANTILE quantile of each demonstration's start against the others' mean start and
    covariance (a loop here, the batched left-out scores in the library), and Σ_0 is the shrunk sample covariance
    plus the tracker's tolerance: symmetric positive definite, its variances at least the sample's."""
    demos, v = trained
    _, delta = demonstration_deviations(demos)
    c0 = delta[:, 0]
    rho = []
    for d in range(len(c0)):
        rest = np.delete(c0, d, axis=0)
        mu = rest.mean(axis=0)
        rho.append(float(start_surprise(c0[d] - mu, start_covariance(rest - mu))))
    np.testing.assert_allclose(v.start_surprise["reference"], np.quantile(rho, START_SURPRISE_QUANTILE), rtol=1e-9)
    np.testing.assert_allclose(v.start_surprise["beyond"], max(1.0, np.max(rho)), rtol=1e-9)
    assert np.max(rho) > 1.0  # the floor of 1 (starts all alike) is not what is tested here
    np.testing.assert_allclose(band_calibration(delta, v.s)["start_surprises"], rho, rtol=1e-9)
    cov = start_covariance(c0 - c0.mean(axis=0))
    np.testing.assert_allclose(cov, cov.T, atol=0.0)
    assert np.linalg.eigvalsh(cov).min() > 0
    assert np.all(np.diag(cov) >= np.var(c0, axis=0, ddof=1) * (1 - 1e-12))
    np.testing.assert_allclose(v.start_surprise["covariance"], cov, rtol=1e-12)


def test_fewer_demonstrations_than_the_threshold_widen_only_beyond_and_a_part_widens_where_it_narrows_the_bands():
    """Below START_SURPRISE_FROM the upper quartile would be a quantile of a handful of heavy-tailed surprises: no
    choice is made, and only a start beyond every left-out demonstration's (ρ > ρ_max) is widened, by √(ρ / ρ_max) in
    both parts; below START_BEYOND_FROM nothing is. From START_SURPRISE_FROM on each part (rotation, position) widens
    against the quartile only where its left-out bands are narrower with it (the record gives the ratio); for Gaussian
    starts independent of the motion that gain is nil on average, and a part not kept widens a far start only by
    √(ρ / ρ_max)."""
    far_q, far_p = np.array([[0.0, 0.0, 0.0, 1.0]]), np.array([[5.0, 5.0, 5.0]])
    few = demonstration_variation(people(START_SURPRISE_FROM - 1, 4, other=0.25))
    assert few.start_surprise["reference"] is None and "start_widening" not in few.calibration
    assert not any(few.start_surprise["parts"])
    beyond = few.start_beyond(far_q, far_p)
    assert beyond[0] > 100.0  # metres off starts spread by centimetres
    np.testing.assert_allclose(few.start_widening(far_q, far_p), np.sqrt(beyond)[:, None] * [[1.0, 1.0]], rtol=1e-12)
    fewer = demonstration_variation(people(START_BEYOND_FROM - 1, 4))
    assert fewer.start_surprise is None and np.all(fewer.start_widening(far_q, far_p) == 1.0)
    assert fewer.start_beyond(far_q, far_p) is None
    ratios = []
    for seed in range(4):
        v = demonstration_variation(hierarchical_demos(40, 5 + seed))
        sw = v.calibration["start_widening"]
        beyond = np.sqrt(v.start_beyond(far_q, far_p)[0])
        for j, name in enumerate(("rotation", "position")):  # a part widens iff its left-out bands narrow with it
            assert sw[name] == (sw["mean_width_ratio"][j] < 1.0), sw
            assert (v.start_widening(far_q, far_p)[0, j] > beyond * (1 + 1e-9)) == sw[name]
        assert (v.start_surprise["reference"] is None) == (not sw["rotation"] and not sw["position"])
        ratios.append(sw["mean_width_ratio"])
    assert np.min(np.mean(ratios, axis=0)) > 0.99, ratios  # a start that says nothing narrows nothing to speak of


@pytest.mark.slow
def test_where_the_start_says_who_deviates_the_widened_bands_hold_at_the_level_and_are_narrower():
    """Trained on 32 of the mixture whose unusual people also start elsewhere, the rotation part widens in most
    training sets (its factor above 1 has room to fall for the usual starts; the position part's Student-t band
    already holds the mixture, its factor at 1, so widening there would only add width and is mostly not kept).
    Fresh draws of the same mixture (pooled over 5 training sets) are held at least as often as by the same model
    without the start's surprise (0.95 in rotation here: the mixture's quantile is over-covered either way), and by
    a narrower rotation band on average: the width goes to the unusual takes, whose rotation bands are widened by
    more than a third on average."""
    import rbgp_cli.dynamics.variation as V
    from tests.dynamics.test_bands_order import _coverage_of

    wide, plain, ratio, kept = None, None, [], 0
    for rep in range(5):
        train = people(32, 40 + rep, other=0.25)
        v = demonstration_variation(train)
        keep, V.START_SURPRISE_FROM = V.START_SURPRISE_FROM, 10**6
        try:
            v0 = demonstration_variation(train)  # the same model without the start's surprise
        finally:
            V.START_SURPRISE_FROM = keep
        fresh = people(16, 80 + rep, other=0.25)
        a, b = _coverage_of(v, train, fresh), _coverage_of(v0, train, fresh)
        wide, plain = (a, b) if wide is None else (wide + a, plain + b)
        if v.calibration["start_widening"]["rotation"]:
            kept += 1
            unusual = people(8, 120 + rep, start=3.0, spread=3.0)
            ratio.append(v.start_widening(np.array([d.quat[0] for d in unusual]),
                                          np.array([d.position[0] for d in unusual]))[:, 0])
    assert kept >= 3, kept
    c, b = wide.to_dict(), plain.to_dict()
    # as often held as without the widening (at least the level's lower edge), on a narrower rotation band
    for part in ("position", "rotation"):
        assert c[f"coverage_{part}"] >= max(0.86, b[f"coverage_{part}"] - 0.01), (c, b)
    assert c["band_rotation"] < b["band_rotation"] and c["band_position"] <= b["band_position"] * (1 + 1e-9), (c, b)
    assert np.mean(np.concatenate(ratio)) > 1.33, ratio


def test_a_model_file_keeps_the_start_reference_and_one_without_it_widens_nothing(tmp_path):
    """The start's surprise round-trips through a model file (the widening of a far start is the same after
    loading); a file without it (older) loads and widens nothing; a malformed one is refused naming the field."""
    from rbgp_cli.dynamics.model import train_model
    from rbgp_cli.errors import InputError
    from rbgp_cli.io.model_store import load_model, save_model
    from tests.dynamics.test_anticipation_bands import rewrite_paths_header

    demos = people(24, 9, other=0.25, samples=30)
    model = train_model(demos, restarts=1, shared=True, explore_size=0, max_points=150)
    assert model.variation.start_surprise is not None, model.variation.calibration
    save_model(model, tmp_path / "m.rbgp")
    loaded, _ = load_model(tmp_path / "m.rbgp")
    q = np.array([d.quat[0] for d in demos[:3]])
    p = np.array([d.position[0] for d in demos[:3]]) + [[1.0, 0.0, 0.0]]  # tens of the starts' spreads off
    want = model.variation.start_widening(q, p)
    assert np.all(want.max(axis=1) > 1.5), want
    np.testing.assert_allclose(loaded.variation.start_widening(q, p), want, rtol=1e-12)

    rewrite_paths_header(tmp_path / "m.rbgp", lambda v: v.pop("start_surprise"), tmp_path / "old.rbgp", section="variation")
    old, _ = load_model(tmp_path / "old.rbgp")
    assert old.variation.start_surprise is None and np.all(old.variation.start_widening(q, p) == 1.0)

    def seventeenth(v):  # a file of the seventeenth pass: the quartile's widening, no ρ_max
        v["start_surprise"].pop("beyond")
        v["start_surprise"]["reference"], v["start_surprise"]["parts"] = 1.0, [False, False]

    rewrite_paths_header(tmp_path / "m.rbgp", seventeenth, tmp_path / "s17.rbgp", section="variation")
    s17, _ = load_model(tmp_path / "s17.rbgp")
    assert s17.variation.start_beyond(q, p) is None and np.all(s17.variation.start_widening(q, p) == 1.0)

    def bad(v):
        v["start_surprise"]["covariance"][0][0] = -1.0

    rewrite_paths_header(tmp_path / "m.rbgp", bad, tmp_path / "bad.rbgp", section="variation")
    with pytest.raises(InputError, match="start_surprise"):
        load_model(tmp_path / "bad.rbgp")


def test_a_start_beyond_every_demonstrations_own_widens_its_band_and_the_usual_starts_keep_theirs():
    """Trained on usual people only (whose start says nothing about their motion), fresh people who start three times
    as far off and deviate three times as much lie beyond ρ_max and are widened by √(ρ / ρ_max): their bands hold them
    far more often than the same bands without the widening. Fresh usual people are rarely beyond (an exchangeable
    start is, with probability at most 1/(D + 1)) and are held as before."""
    from dataclasses import replace

    from tests.dynamics.test_bands_order import _coverage_of

    wide_u, plain_u, wide_n, plain_n, flagged = None, None, None, None, []
    for rep in range(3):
        train = people(24, 300 + rep)
        v = demonstration_variation(train)
        v0 = replace(v, start_surprise={**v.start_surprise, "beyond": None})  # the same bands, never widened beyond
        unusual, usual = people(8, 400 + rep, start=3.0, spread=3.0), people(16, 500 + rep)
        flagged.append(v.start_beyond(np.array([d.quat[0] for d in usual]), np.array([d.position[0] for d in usual])))
        parts = [_coverage_of(m, train, fresh) for m in (v, v0) for fresh in (unusual, usual)]
        if wide_u is None:
            wide_u, wide_n, plain_u, plain_n = parts
        else:
            wide_u, wide_n, plain_u, plain_n = (a + b for a, b in zip((wide_u, wide_n, plain_u, plain_n), parts))
    wu, pu, wn, pn = (x.to_dict() for x in (wide_u, plain_u, wide_n, plain_n))
    # here 0.54 / 0.35 → 0.63 / 0.55: three times the deviations need more than ρ says (ρ_max of 24 is far out), but
    # the width goes where it is needed
    assert wu["coverage_position"] > pu["coverage_position"] + 0.05 and wu["coverage_rotation"] > pu["coverage_rotation"] + 0.15, (wu, pu)
    # wider where they are beyond (in rotation the upper quartile's widening, kept here, already widens them)
    assert wu["band_position"] > 1.3 * pu["band_position"] and wu["band_rotation"] > 1.05 * pu["band_rotation"], (wu, pu)
    for part in ("position", "rotation"):
        assert abs(wn[f"coverage_{part}"] - pn[f"coverage_{part}"]) <= 0.01, (wn, pn)
        assert wn[f"band_{part}"] <= 1.02 * pn[f"band_{part}"], (wn, pn)
    assert np.mean(np.concatenate(flagged) > 1.0) <= 0.1, flagged


def test_a_goal_conditioned_band_from_a_start_beyond_widens_by_the_same_factor():
    """Given the goal, the band of a start beyond every demonstration's is the goal band times √(ρ / ρ_max) in both
    parts (the position half-widths × w, the rotation region's matrix × w²); a demonstration's own start is not
    widened."""
    from dataclasses import replace

    from rbgp_cli.dynamics.model import train_model
    from rbgp_cli.dynamics.rollout import rollout_conditioned

    demos = people(12, 11, samples=30)
    model = train_model(demos, restarts=1, shared=True, explore_size=0, max_points=150)
    q = np.array([demos[0].quat[0], demos[0].quat[0]])
    p = np.array([demos[0].position[0], demos[0].position[0] + [0.3, 0.0, 0.0]])  # its own start, and ten spreads off
    gq, gp = np.array([demos[0].quat[-1]] * 2), np.array([demos[0].position[-1]] * 2)
    res = rollout_conditioned(model, q, p, goal_quat=gq, goal_position=gp, samples=2, durations=np.full(2, 1.0))
    plain = replace(model, variation=replace(model.variation, start_surprise=None))
    ref = rollout_conditioned(plain, q, p, goal_quat=gq, goal_position=gp, samples=2, durations=np.full(2, 1.0))
    beyond = model.variation.start_beyond(q, p)
    assert beyond[0] < 1.0 < 4.0 < beyond[1], beyond
    w = np.sqrt(np.maximum(1.0, beyond))
    np.testing.assert_allclose(res.band_widening, np.stack([w, w], axis=1), rtol=1e-12)
    np.testing.assert_allclose(res.band_position, ref.band_position * w[:, None, None], rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(res.band_rotation, ref.band_rotation * (w**2)[:, None, None, None], rtol=1e-9, atol=1e-18)
    np.testing.assert_allclose(res.position, ref.position, atol=1e-12)  # the mean does not move
