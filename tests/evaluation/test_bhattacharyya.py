"""Bhattacharyya distance of Gaussians and the evaluation of generated trajectories (docs/method.md §9)."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation, Slerp

from rbgp_cli.dynamics.trajectory import Trajectory
from rbgp_cli.errors import InputError, RbgpWarning
from rbgp_cli.evaluation import (
    MIN_TRAJECTORIES,
    EvaluationResult,
    bhattacharyya_diag,
    bhattacharyya_gaussian,
    check_sample_sizes,
    evaluate,
    mean_rotation,
)
from rbgp_cli.geometry.so3 import exp_quat, quat_canonical, quat_multiply, random_quat, rotate

SETTINGS = settings(max_examples=50, deadline=None)


def random_spd(rng, k, shape=()) -> np.ndarray:
    """Random symmetric positive definite matrices, shape shape + (k, k), eigenvalues spread over decades."""
    A = rng.normal(size=shape + (k, k)) * np.exp(rng.uniform(-3, 1, size=shape + (1, k)))
    return A @ np.swapaxes(A, -1, -2) + 1e-6 * np.eye(k)


# ---------------------------------------------------------------------------------------------
# The formula
# ---------------------------------------------------------------------------------------------


def test_zero_for_identical_gaussians():
    rng = np.random.default_rng(0)
    mu, S = rng.normal(size=(10, 6)), random_spd(rng, 6, (10,))
    assert np.all(bhattacharyya_gaussian(mu, S, mu, S) == 0.0)
    var = rng.uniform(1e-8, 10.0, size=(10, 6))
    assert np.all(bhattacharyya_diag(mu, var, mu, var) == 0.0)


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), k=st.integers(1, 6))
def test_symmetric_and_nonnegative_for_random_spd(seed, k):
    rng = np.random.default_rng(seed)
    mu1, mu2 = rng.normal(size=(2, 5, k)) * rng.uniform(0, 3)
    S1, S2 = random_spd(rng, k, (5,)), random_spd(rng, k, (5,))
    d12 = bhattacharyya_gaussian(mu1, S1, mu2, S2)
    d21 = bhattacharyya_gaussian(mu2, S2, mu1, S1)
    assert d12.shape == (5,)
    assert np.all(np.isfinite(d12)) and np.all(d12 >= 0)
    np.testing.assert_allclose(d12, d21, rtol=1e-9, atol=1e-12)
    v1, v2 = np.exp(rng.uniform(-10, 5, size=(2, 5, k)))
    t12, t21 = bhattacharyya_diag(mu1, v1, mu2, v2), bhattacharyya_diag(mu2, v2, mu1, v1)
    assert np.all(t12 >= 0) and np.array_equal(t12, t21)


@SETTINGS
@given(
    mu1=st.floats(-10, 10), mu2=st.floats(-10, 10),
    s1=st.floats(1e-3, 1e3), s2=st.floats(1e-3, 1e3),
)
def test_one_dimensional_closed_form(mu1, mu2, s1, s2):
    expected = (mu1 - mu2) ** 2 / (4 * (s1**2 + s2**2)) + 0.5 * np.log((s1**2 + s2**2) / (2 * s1 * s2))
    full = bhattacharyya_gaussian([mu1], [[s1**2]], [mu2], [[s2**2]])
    diag = bhattacharyya_diag([mu1], [s1**2], [mu2], [s2**2])
    assert full.shape == () and diag.shape == (1,)
    np.testing.assert_allclose(full, expected, rtol=1e-10, atol=1e-13)
    np.testing.assert_allclose(diag[0], expected, rtol=1e-10, atol=1e-13)


def test_known_value_two_dimensions():
    # Δ = (1, 1), S1 = I, S2 = 2I: Σ = 1.5 I; ⅛·2/1.5 + ½ ln(2.25 / sqrt(1·4)) = 1/6 + ½ ln(9/8)
    d = bhattacharyya_gaussian(np.zeros(2), np.eye(2), np.ones(2), 2 * np.eye(2))
    assert d == pytest.approx(1 / 6 + 0.5 * np.log(9 / 8), rel=1e-14)


def test_full_equals_diag_for_diagonal_covariances():
    rng = np.random.default_rng(2)
    mu1, mu2 = rng.normal(size=(2, 20, 6))
    v1, v2 = np.exp(rng.uniform(-12, 2, size=(2, 20, 6)))
    full = bhattacharyya_gaussian(mu1, v1[..., None] * np.eye(6), mu2, v2[..., None] * np.eye(6))
    np.testing.assert_allclose(full, bhattacharyya_diag(mu1, v1, mu2, v2).sum(-1), rtol=1e-10)


def test_batched_equals_looped_and_broadcasts():
    rng = np.random.default_rng(3)
    mu1, mu2 = rng.normal(size=(2, 4, 3, 5))
    S1, S2 = random_spd(rng, 5, (4, 3)), random_spd(rng, 5, (3,))  # S2 broadcast over the first axis
    batched = bhattacharyya_gaussian(mu1, S1, mu2, S2)
    assert batched.shape == (4, 3)
    looped = np.array([[bhattacharyya_gaussian(mu1[i, j], S1[i, j], mu2[i, j], S2[j]) for j in range(3)]
                       for i in range(4)])
    np.testing.assert_allclose(batched, looped, rtol=1e-12)


def test_invariant_under_common_affine_map():
    rng = np.random.default_rng(4)
    mu1, mu2 = rng.normal(size=(2, 4))
    S1, S2 = random_spd(rng, 4), random_spd(rng, 4)
    A, b = rng.normal(size=(4, 4)), rng.normal(size=4)
    d = bhattacharyya_gaussian(mu1, S1, mu2, S2)
    d_mapped = bhattacharyya_gaussian(A @ mu1 + b, A @ S1 @ A.T, A @ mu2 + b, A @ S2 @ A.T)
    assert d_mapped == pytest.approx(d, rel=1e-9)


def test_degenerate_variances():
    assert bhattacharyya_diag(0.0, 0.0, 0.0, 0.0) == 0.0
    assert bhattacharyya_diag(0.0, 0.0, 1.0, 0.0) == np.inf
    assert bhattacharyya_diag(0.0, 0.0, 0.0, 1.0) == np.inf
    # extreme but valid ratios stay finite (no overflow in the log term)
    assert np.isfinite(bhattacharyya_diag(0.0, 1e-300, 0.0, 1e300))
    assert bhattacharyya_gaussian(np.zeros(2), np.diag([1.0, 0.0]), np.zeros(2), np.eye(2)) == np.inf
    # singular (S1 + S2)/2: undefined without a ridge
    assert np.isnan(bhattacharyya_gaussian(np.zeros(2), np.diag([1.0, 0]), np.ones(2), np.diag([1.0, 0])))
    with pytest.raises(ValueError, match="variances"):
        bhattacharyya_diag(0.0, -1.0, 0.0, 1.0)
    with pytest.raises(ValueError, match="positive"):
        bhattacharyya_gaussian(np.zeros(2), -np.eye(2) + 2 * np.diag([0, 1.0]), np.zeros(2), -np.eye(2))


# ---------------------------------------------------------------------------------------------
# evaluate
# ---------------------------------------------------------------------------------------------

Z = np.array([0.0, 0.0, 1.0])


def make_demos(rng, M=6, *, start=0.2 * np.pi, sweep=0.6 * np.pi, n_range=(40, 70)) -> list[Trajectory]:
    """Demonstrations of one motion: a turn about (mostly) z by ``sweep`` from ``start`` with small
    per-demo variations, a planar path, non-uniform times, different lengths and durations.
    Quaternions canonicalised to w >= 0, as a reader may deliver them (they flip sign at θ = π)."""
    demos = []
    for m in range(M):
        n = int(rng.integers(*n_range))
        t = 1.0 + np.cumsum(rng.uniform(0.5, 1.5, n)) * rng.uniform(0.01, 0.02)
        s = (t - t[0]) / (t[-1] - t[0])
        turn = (start + sweep * s)[:, None] * Z
        wobble = 0.08 * rng.normal(size=3) + 0.05 * np.sin(2 * np.pi * s)[:, None] * rng.normal(size=3)
        q = quat_canonical(quat_multiply(exp_quat(turn), exp_quat(wobble)))
        p = np.stack([0.4 * s, 0.1 * np.sin(np.pi * s), 0.05 * s], axis=-1) + 0.01 * rng.normal(size=3)
        demos.append(Trajectory(t=t, quat=q, position=p, name=f"demo{m}", source="demos.csv"))
    return demos


def jitter(rng, trajs, rot=0.03, pos=0.005) -> list[Trajectory]:
    """Copies with a small random rotation (body frame) and position offset per trajectory and sample."""
    out = []
    for tr in trajs:
        n = len(tr)
        dq = exp_quat(rot * rng.normal(size=3) + 0.3 * rot * rng.normal(size=(n, 3)))
        dp = pos * rng.normal(size=(n, 3))
        out.append(tr.with_(quat=quat_multiply(tr.quat, dq), position=tr.position + dp, name=f"{tr.name}-jit"))
    return out


def transform_world(trajs, q_w, t_w=np.zeros(3)) -> list[Trajectory]:
    """The same motions in a world frame rotated by q_w and shifted by t_w: R -> R_w R, p -> R_w p + t_w."""
    return [tr.with_(quat=quat_multiply(q_w, tr.quat), position=rotate(q_w, tr.position) + t_w)
            for tr in trajs]


@pytest.fixture(scope="module")
def sets():
    rng = np.random.default_rng(10)
    demos = make_demos(rng)
    return demos, jitter(rng, demos)


def test_generated_equal_to_demos_scores_zero(sets):
    demos, _ = sets
    for cov in ("diag", "full"):
        res = evaluate(demos, demos, covariance=cov)
        assert isinstance(res, EvaluationResult)
        assert res.steps == int(np.median([len(d) for d in demos]) + 0.5)
        assert res.per_step.shape == (res.steps,)
        assert np.max(np.abs(res.per_step)) < 1e-12
        assert res.mean < 1e-12 and res.rotation < 1e-12 and res.translation < 1e-12


def test_single_generated_trajectory_is_finite_thanks_to_the_ridge(sets):
    demos, gen = sets
    with pytest.warns(RbgpWarning, match="only 1 generated trajectory.*needs at least 2 generated"):
        res = evaluate(gen[:1], demos)
    assert not res.reliable
    assert res.n_generated == 1 and np.all(res.gen_std == 0.0)  # ddof = 1 needs 2 samples: variance 0
    assert np.all(np.isfinite(res.per_step)) and res.mean > 0
    assert evaluate(gen[:1], demos, ridge=1e-3).mean < res.mean  # a larger ridge forgives more


def test_translation_shift_increases_only_the_translation_part(sets):
    demos, gen = sets
    shifted = [g.with_(position=g.position + [0.05, -0.02, 0.0]) for g in gen]
    for cov in ("diag", "full"):
        base, moved = evaluate(gen, demos, covariance=cov), evaluate(shifted, demos, covariance=cov)
        np.testing.assert_allclose(moved.per_step_rotation, base.per_step_rotation, rtol=1e-12, atol=1e-15)
        assert np.all(moved.per_step_translation > base.per_step_translation)
        assert moved.translation > 10 * base.translation
        assert moved.mean > base.mean


def test_score_is_invariant_to_a_common_change_of_world_frame(sets):
    demos, gen = sets
    rng = np.random.default_rng(11)
    q_w, t_w = random_quat(rng), rng.normal(size=3)
    rotated = (transform_world(gen, q_w), transform_world(demos, q_w))
    identity = np.array([0.0, 0.0, 0.0, 1.0])
    shifted = (transform_world(gen, identity, t_w), transform_world(demos, identity, t_w))
    for cov in ("diag", "full"):
        base = evaluate(gen, demos, covariance=cov)
        rot = evaluate(*rotated, covariance=cov)
        sh = evaluate(*shifted, covariance=cov)
        # features use log(R̄ᵀR): the rotation part does not see a world rotation (nor a translation)
        np.testing.assert_allclose(rot.per_step_rotation, base.per_step_rotation, rtol=1e-8, atol=1e-12)
        np.testing.assert_allclose(sh.per_step_rotation, base.per_step_rotation, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(sh.per_step_translation, base.per_step_translation, rtol=1e-8, atol=1e-12)
    # with full covariances the whole score is invariant (the world change is an orthogonal affine map)
    base, rot = evaluate(gen, demos, covariance="full"), evaluate(*rotated, covariance="full")
    np.testing.assert_allclose(rot.per_step, base.per_step, rtol=1e-7, atol=1e-12)
    np.testing.assert_allclose(rot.per_step_translation, base.per_step_translation, rtol=1e-7, atol=1e-12)


def test_demos_crossing_theta_pi_score_like_any_others():
    rng = np.random.default_rng(12)
    demos = make_demos(rng, start=0.7 * np.pi, sweep=0.6 * np.pi)  # through θ = π
    gen = jitter(rng, demos)
    res = evaluate(gen, demos)
    assert np.all(np.isfinite(res.per_step))
    assert res.rotation < 1.0  # small: the sets differ by a few centiradians
    assert np.max(np.abs(res.demo_mean[:, :3])) < 0.5  # features stay near 0: no jump at π
    # the same motions in a world frame turned by −π about z no longer cross θ = π: same score
    q_w = exp_quat(-np.pi * Z)
    far = evaluate(transform_world(gen, q_w), transform_world(demos, q_w))
    np.testing.assert_allclose(far.per_step_rotation, res.per_step_rotation, rtol=1e-8, atol=1e-12)
    # a rotational difference is seen as one: rotate the generated set's bodies by 0.2 rad
    turned = [g.with_(quat=quat_multiply(g.quat, exp_quat([0.2, 0.0, 0.0]))) for g in gen]
    assert evaluate(turned, demos).rotation > 5 * res.rotation


def test_matches_a_looped_oracle_with_scipy(sets):
    demos, gen = sets
    demos, gen = demos[:4], gen[:3]
    T, ridge = 25, 1e-4
    res = evaluate(gen, demos, length=T, ridge=ridge)

    def resampled(tr):  # scipy Slerp + np.interp on normalised time
        s = (tr.t - tr.t[0]) / (tr.t[-1] - tr.t[0])
        u = np.linspace(0, 1, T)
        rots = Slerp(s, Rotation.from_quat(tr.quat))(u)
        return rots, np.stack([np.interp(u, s, tr.position[:, i]) for i in range(3)], -1)

    rd = [resampled(d) for d in demos]
    rg = [resampled(g) for g in gen]
    expected = np.zeros((T, 6))
    for j in range(T):
        A = sum(np.outer(q, q) for q in (r[0][j].as_quat() for r in rd))
        ref = Rotation.from_quat(np.linalg.eigh(A)[1][:, -1])
        xd = np.array([np.r_[(ref.inv() * r[0][j]).as_rotvec(), r[1][j]] for r in rd])
        xg = np.array([np.r_[(ref.inv() * r[0][j]).as_rotvec(), r[1][j]] for r in rg])
        for i in range(6):
            m1, v1 = xd[:, i].mean(), xd[:, i].var(ddof=1) + ridge
            m2, v2 = xg[:, i].mean(), xg[:, i].var(ddof=1) + ridge
            expected[j, i] = ((m1 - m2) ** 2 / (4 * (v1 + v2))
                              + 0.5 * np.log((v1 + v2) / (2 * np.sqrt(v1 * v2))))
    np.testing.assert_allclose(res.per_step_rotation, expected[:, :3].sum(1), rtol=1e-7)
    np.testing.assert_allclose(res.per_step_translation, expected[:, 3:].sum(1), rtol=1e-7)
    np.testing.assert_allclose(res.per_step, expected.sum(1), rtol=1e-7)
    assert res.mean == pytest.approx(expected.sum(1).mean(), rel=1e-7)
    assert res.ridge == ridge and res.n_demos == 4 and res.n_generated == 3 and res.steps == T
    np.testing.assert_allclose(res.s, np.linspace(0, 1, T))
    assert res.reference.shape == (T, 4) and res.demo_mean.shape == (T, 6) and res.gen_std.shape == (T, 6)


def test_full_parts_come_from_the_blocks(sets):
    demos, gen = sets
    res = evaluate(gen, demos, covariance="full", length=30)
    diag = evaluate(gen, demos, covariance="diag", length=30)
    assert np.all(res.per_step >= 0) and np.all(np.isfinite(res.per_step))
    assert not np.allclose(res.per_step_rotation, diag.per_step_rotation)  # correlations count
    np.testing.assert_allclose(res.reference, diag.reference)


def test_to_dict_is_plain_json(sets):
    demos, gen = sets
    res = evaluate(gen, demos, length=20)
    d = res.to_dict()
    assert set(d) == {"bhattacharyya", "steps", "n_generated", "n_demos", "covariance", "ridge", "reliable",
                      "warnings"}
    assert d["reliable"] is True and d["warnings"] == []
    assert d["bhattacharyya"] == {"mean": res.mean, "rotation": res.rotation, "translation": res.translation,
                                  "offset": res.offset, "spread": res.spread}
    assert d["steps"] == 20 and d["covariance"] == "diag" and d["ridge"] == 1e-6
    full = json.loads(json.dumps(res.to_dict(include_series=True)))
    assert len(full["per_step"]["total"]) == 20
    assert full["per_step"]["rotation"][3] == res.per_step_rotation[3]


def test_mean_rotation_is_the_reference(sets):
    demos, _ = sets
    res = evaluate(demos, demos, length=15)
    from rbgp_cli.evaluation import resample_all

    np.testing.assert_array_equal(res.reference, mean_rotation(resample_all(demos, 15)[0]))


# ---------------------------------------------------------------------------------------------
# Errors
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "which, kwargs, match",
    [
        ("no_gen", {}, "no generated trajectories"),
        ("no_demos", {}, "no demonstrations"),
        ("ok", {"length": 1}, "at least 2"),
        ("ok", {"length": 0}, "at least 2"),
        ("ok", {"length": 10_000},
         r"more than 4x the longest demonstration \(\d+ samples\); use length at most \d+"),
        ("ok", {"covariance": "spherical"}, "unknown covariance 'spherical'; use 'diag' or 'full'"),
        ("ok", {"ridge": -1e-6}, "ridge must be finite and >= 0"),
        ("short_demo", {}, r"demos\.csv: trajectory 'tiny' has 1 sample\(s\)"),
    ],
)
def test_errors(sets, which, kwargs, match):
    demos, gen = sets
    if which == "no_gen":
        gen = []
    elif which == "no_demos":
        demos = []
    elif which == "short_demo":
        demos = demos + [demos[0].slice(slice(0, 1)).with_(name="tiny")]
    with pytest.raises(InputError, match=match) as info:
        evaluate(gen, demos, **kwargs)
    assert info.value.exit_code == 2 and "\n" not in str(info.value)


def test_length_above_the_longest_demo_warns_within_the_limit(sets):
    demos, gen = sets
    longest = max(len(d) for d in demos)
    with pytest.warns(RbgpWarning, match="exceeds the longest demonstration"):
        res = evaluate(gen, demos, length=4 * longest)
    assert res.steps == 4 * longest and np.all(np.isfinite(res.per_step))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        evaluate(gen, demos, length=longest)  # no warning at the limit


# ---------------------------------------------------------------------------------------------
# How many trajectories a score needs
# ---------------------------------------------------------------------------------------------


def test_one_demonstration_is_refused_because_the_score_would_measure_the_ridge(sets):
    demos, gen = sets
    for cov in ("diag", "full"):
        with pytest.raises(InputError, match=rf"1 demonstration: .*ridge.*; covariance {cov} needs at least "
                                             rf"{MIN_TRAJECTORIES[cov]} demonstrations") as info:
            evaluate(gen, demos[:1], covariance=cov)
        assert info.value.exit_code == 2 and "\n" not in str(info.value) and info.value.param == "covariance"
    # why: with one demonstration the number follows the ridge, with six it does not
    one = [evaluate(gen, demos[:1], ridge=r, sample_size="record").mean for r in (1e-6, 1e-7)]
    six = [evaluate(gen, demos, ridge=r).mean for r in (1e-6, 1e-7)]
    assert one[1] > 1.3 * one[0]  # +37 %: a tenth of the ridge adds ~ 6/4 ln 10 to the score
    assert six[1] < 1.05 * six[0]  # +3 %


def test_record_reports_without_raising_or_warning(sets):
    """What cross-validation uses: the verdict is data in the result, nothing is emitted."""
    demos, gen = sets
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        res = evaluate(gen[:1], demos[:1], sample_size="record")
    d = json.loads(json.dumps(res.to_dict()))
    assert d["reliable"] is False and len(d["warnings"]) == 2
    assert "cannot score against 1 demonstration" in d["warnings"][0]
    assert "only 1 generated trajectory" in d["warnings"][1]
    with pytest.warns(RbgpWarning, match="cannot score against 1 demonstration"):
        assert not evaluate(gen, demos[:1], sample_size="warn").reliable
    with pytest.raises(ValueError, match="sample_size"):
        evaluate(gen, demos, sample_size="ignore")


def test_full_covariance_needs_seven_and_its_parts_four(sets):
    demos, gen = sets  # 6 each
    with pytest.warns(RbgpWarning) as record:
        res = evaluate(gen[:3], demos, covariance="full")
    texts = [str(w.message) for w in record]
    assert len(texts) == 2 and not res.reliable
    assert "6 demonstrations" in texts[0] and "needs at least 7 demonstrations" in texts[0]
    assert "parts" not in texts[0]  # 6 >= 4: the 3x3 parts are fine
    assert "3 generated trajectories" in texts[1] and "parts at least 4" in texts[1]
    rng = np.random.default_rng(21)
    demos7 = make_demos(rng, M=7)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        res = evaluate(jitter(rng, demos7), demos7, covariance="full")
        assert res.reliable and res.warnings == ()
        assert evaluate(gen[:2], demos, covariance="diag").reliable  # diag: 2 per set suffice


@pytest.mark.parametrize("cov", ["diag", "full"])
def test_the_rule_is_the_rank_of_the_sample_covariance(cov):
    """Oracle: a set passes exactly when its sample covariance (of random features) has no direction of
    zero variance: all 6 variances > 0 for diag, all 6 eigenvalues > 0 for full."""
    rng = np.random.default_rng(22)
    for n in range(1, 10):
        x = rng.normal(size=(n, 6))
        c = np.cov(x, rowvar=False, ddof=1) if n > 1 else np.zeros((6, 6))
        if cov == "diag":
            spread = bool(np.all(np.diag(c) > 1e-12))
        else:
            spread = bool(np.linalg.eigvalsh(c)[0] > 1e-12 * max(1.0, np.abs(c).max()))
        check = check_sample_sizes(n_generated=n, n_demos=20, covariance=cov)
        assert (not check.warnings) == spread, (cov, n)
        assert check.refusal is None
        assert check_sample_sizes(20, n, cov).refusal is not None if n < 2 else check.reliable == spread
        assert check.needed == {"demos": MIN_TRAJECTORIES[cov], "generated": MIN_TRAJECTORIES[cov]}


def test_sets_without_spread_are_flagged(sets):
    demos, gen = sets
    with pytest.warns(RbgpWarning, match=r"generated trajectories barely differ: at 100 % .*below the ridge"):
        res = evaluate([gen[0]] * 5, demos)
    assert not res.reliable and "barely differ" in res.to_dict()["warnings"][0]


# ---------------------------------------------------------------------------------------------
# Offset and spread: the two parts of the score
# ---------------------------------------------------------------------------------------------


@given(st.integers(0, 10_000), st.integers(1, 6))
@SETTINGS
def test_the_parts_add_up_and_are_each_the_closed_form(seed, k):
    from rbgp_cli.evaluation.bhattacharyya import bhattacharyya_diag_parts, bhattacharyya_gaussian_parts

    rng = np.random.default_rng(seed)
    mu1, mu2 = rng.normal(size=(2, 4, k))
    S1, S2 = random_spd(rng, k, (4,)), random_spd(rng, k, (4,))
    off, spr = bhattacharyya_gaussian_parts(mu1, S1, mu2, S2)
    np.testing.assert_allclose(off + spr, bhattacharyya_gaussian(mu1, S1, mu2, S2), rtol=1e-12, atol=1e-14)
    S = 0.5 * (S1 + S2)  # an independent oracle: the textbook formulas with inverse and determinants
    d = mu1 - mu2
    np.testing.assert_allclose(off, 0.125 * np.einsum("bi,bij,bj->b", d, np.linalg.inv(S), d), rtol=1e-8)
    ref = 0.5 * np.log(np.linalg.det(S) / np.sqrt(np.linalg.det(S1) * np.linalg.det(S2)))
    np.testing.assert_allclose(spr, np.maximum(ref, 0.0), rtol=1e-6, atol=1e-9)
    v1, v2 = np.exp(rng.normal(size=(2, 4, k)))
    doff, dspr = bhattacharyya_diag_parts(mu1, v1, mu2, v2)
    np.testing.assert_allclose(doff, d ** 2 / (4 * (v1 + v2)), rtol=1e-12)
    np.testing.assert_allclose(dspr, 0.5 * np.log((v1 + v2) / (2 * np.sqrt(v1 * v2))), rtol=1e-9, atol=1e-15)
    assert np.all(doff >= 0) and np.all(dspr >= 0)


@pytest.mark.parametrize("cov", ["diag", "full"])
def test_a_shifted_set_is_all_offset_and_a_widened_set_all_spread(sets, cov):
    """The decomposition says *why* a score is high: generated motions off to one side (offset) or too
    narrow / too wide a set (spread)."""
    demos, gen = sets
    base = evaluate(gen, demos, covariance=cov)
    assert base.offset + base.spread == pytest.approx(base.mean, rel=1e-12)
    shifted = evaluate([g.with_(position=g.position + [0.05, 0.0, 0.0]) for g in gen], demos, covariance=cov)
    assert shifted.spread == pytest.approx(base.spread, rel=1e-9, abs=1e-12)  # the same spread
    assert shifted.offset > base.offset + 1.0
    # on a common time grid, positions pushed away from the generated set's own per-step mean by a
    # factor 3: the mean stays
    from rbgp_cli.evaluation import resample_all

    T = base.steps
    q, p = resample_all(gen, T)
    mu = p.mean(axis=0)
    grid = [Trajectory(t=np.linspace(0.0, 1.0, T), quat=q[m], position=p[m]) for m in range(len(gen))]
    again = evaluate(grid, demos, covariance=cov)
    wide = evaluate([g.with_(position=mu + 3.0 * (g.position - mu)) for g in grid], demos, covariance=cov)
    assert wide.offset <= again.offset  # the means stay; the pooled Σ grows, so the offset can only shrink
    assert wide.spread > again.spread + 0.5
    d = wide.to_dict(include_series=True)
    assert d["bhattacharyya"]["offset"] == pytest.approx(wide.offset)
    np.testing.assert_allclose(np.add(d["per_step"]["offset"], d["per_step"]["spread"]), d["per_step"]["total"])
