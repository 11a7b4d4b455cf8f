"""A motion under way (issue 37): phase and end time from a seen beginning, the continuation, causality."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rbgp_cli.dynamics.anticipation import MIX_WEIGHT, Anticipator, Follower, anticipate
from rbgp_cli.dynamics.paths import fit_paths
from rbgp_cli.dynamics.trajectory import Trajectory
from rbgp_cli.errors import InputError

RATE = 50.0


def _minjerk(s):
    return 10 * s**3 - 15 * s**4 + 6 * s**5


def family(n, seed, *, t0=0.0):
    """``n`` motions with a known phase-dependent path and random durations: along x a minimum-jerk
    reach of 0.6 ± 0.03 m, an arc in y whose height varies (0.15 ± 0.03 m), a rotation about z of 1 rad along the
    same profile plus a motion-specific wobble; durations log-normal around 2 s (±20 %), sampled at 50 Hz.
    Returns the trajectories and their durations."""
    rng = np.random.default_rng(seed)
    out, durs = [], []
    for d in range(n):
        D = float(np.exp(np.log(2.0) + 0.2 * rng.standard_normal()))
        t = np.arange(0.0, D + 1e-9, 1.0 / RATE)
        t[-1] = min(t[-1], D)
        s = t / D
        h = 0.15 + 0.03 * rng.standard_normal()
        w = 0.05 * rng.standard_normal()
        reach = 0.6 + 0.03 * rng.standard_normal()
        pos = np.stack([reach * _minjerk(s), h * np.sin(np.pi * s), 0.01 * rng.standard_normal() * s], axis=1)
        ang = 1.0 * _minjerk(s) + w * np.sin(np.pi * s)
        quat = Rotation.from_rotvec(np.stack([np.zeros_like(ang), np.zeros_like(ang), ang], axis=1)).as_quat()
        out.append(Trajectory(t + t0, quat, pos, name=f"d{d}"))
        durs.append(D)
    return out, np.array(durs)


@pytest.fixture(scope="module")
def trained():
    demos, _ = family(24, 0)
    return demos, fit_paths(demos)


def _seen(tr, F):
    k = int(np.argmin(np.abs(tr.t - (tr.t[0] + F * tr.duration))))
    return Trajectory(tr.t[: k + 1], tr.quat[: k + 1], tr.position[: k + 1], name=tr.name), k


@pytest.mark.slow
def test_phase_and_end_time_after_a_quarter(trained):
    _, paths = trained
    new, durs = family(12, 1, t0=5.0)
    ant = Anticipator(paths)
    for tr, D in zip(new, durs):
        seen, k = _seen(tr, 0.25)
        est = ant.estimate(seen.t, seen.quat, seen.position)
        true_phase = (seen.t[-1] - tr.t[0]) / D
        assert abs(est.phase - true_phase) <= 0.05, (est.phase, true_phase)
        assert abs(est.end_time - tr.t[-1]) <= 0.05 * D, (est.end_time, tr.t[-1])
        assert est.end_time_band[0] <= est.end_time <= est.end_time_band[1]
        assert not est.off


@pytest.mark.slow
def test_the_continuation_of_a_training_demonstrations_beginning_follows_it(trained):
    demos, paths = trained
    ant = Anticipator(paths)
    for tr in demos[:4]:
        seen, k = _seen(tr, 0.4)
        c = ant.continuation(seen.t, seen.quat, seen.position, dt=1.0 / RATE)
        assert c.t[0] == pytest.approx(seen.t[-1])
        assert np.allclose(c.position[0], seen.position[-1], atol=2e-3)  # it starts where the motion is
        # its end lies nearer the demonstration's own end than the ends typically lie from their mean
        ends = np.array([d.position[-1] for d in demos])
        spread = np.sqrt(np.mean(np.sum((ends - ends.mean(axis=0)) ** 2, axis=1)))
        assert np.linalg.norm(c.position[-1] - tr.position[-1]) < spread
        # and its path follows the demonstration's rest better than the other demonstrations' rests do
        s = np.linspace(0, 1, 30)

        def rest_of(d, a):  # d's positions from phase a to 1 at 30 even steps
            return np.array([np.interp(a + (1 - a) * s, (d.t - d.t[0]) / d.duration, d.position[:, j]) for j in range(3)]).T

        a = (seen.t[-1] - tr.t[0]) / tr.duration
        own = rest_of(tr, a)
        got = np.array([np.interp(s, (c.t - c.t[0]) / (c.t[-1] - c.t[0]), c.position[:, j]) for j in range(3)]).T
        rmse = np.sqrt(np.mean(np.sum((got - own) ** 2, axis=1)))
        others = [np.sqrt(np.mean(np.sum((rest_of(d, a) - own) ** 2, axis=1))) for d in demos if d is not tr]
        assert rmse < np.median(others), (rmse, np.median(others))


@pytest.mark.slow
def test_the_prediction_never_uses_samples_after_the_last_seen_one(trained):
    from rbgp_cli.evaluation.under_way import split_seen

    _, paths = trained
    tr = family(1, 7)[0][0]
    seen, rest = split_seen(tr, 0.3)
    other = Trajectory(tr.t, tr.quat.copy(), tr.position.copy(), name="x")
    other.position[len(seen.t):] += 0.5  # a different future
    other.quat[len(seen.t):] = [0.0, 0.0, 0.0, 1.0]
    seen2, _ = split_seen(other, 0.3)
    a = anticipate(paths, seen.t, seen.quat, seen.position, samples=5, seed=3)
    b = anticipate(paths, seen2.t, seen2.quat, seen2.position, samples=5, seed=3)
    assert np.array_equal(a.position, b.position) and np.array_equal(a.quat, b.quat)
    assert all(np.array_equal(x[2], y[2]) for x, y in zip(a.samples, b.samples))
    # the stream: the estimate after pose k is the same whatever comes after it
    f1, f2 = Follower(paths, detect=False), Follower(paths, detect=False)
    for j in range(len(seen.t)):
        e1 = f1.push(tr.t[j], tr.quat[j], tr.position[j])
        e2 = f2.push(other.t[j], other.quat[j], other.position[j])
    assert e1.to_dict() == e2.to_dict()


@pytest.mark.slow
def test_samples_draw_duration_and_path_and_start_at_the_last_seen_pose(trained):
    _, paths = trained
    tr = family(1, 11)[0][0]
    seen, _ = _seen(tr, 0.3)
    c = anticipate(paths, seen.t, seen.quat, seen.position, samples=12, seed=1)
    ends = np.array([t[-1] for t, _, _ in c.samples])
    assert len(c.samples) == 12 and np.std(ends) > 0  # durations differ
    for t, q, p in c.samples:
        assert t[0] == pytest.approx(seen.t[-1])
        assert np.linalg.norm(p[0] - seen.position[-1]) < 0.02
        assert np.allclose(np.linalg.norm(q, axis=1), 1.0)
    names = [x.name for x in c.trajectories(include_samples=True)]
    assert names[:3] == ["0", "0.s0", "0.s1"]


def test_a_stream_starts_at_the_departure_from_rest(trained):
    _, paths = trained
    tr = family(1, 5)[0][0]
    rest_t = np.arange(0.0, 1.0, 1.0 / RATE)
    f = Follower(paths)
    outs = [f.push(t, tr.quat[0], tr.position[0]) for t in rest_t]
    assert all(o is None for o in outs)  # nothing at rest
    t_move = tr.t + 1.0
    first = None
    for j in range(len(tr.t)):
        o = f.push(t_move[j], tr.quat[j], tr.position[j])
        if o is not None and first is None:
            first = t_move[j]
    assert first is not None and first - t_move[0] <= 0.1  # the first prediction within 0.1 s of the start
    assert abs(f.start - t_move[0]) <= 0.1


def test_a_hold_in_mid_motion_reads_at_rest_and_as_a_slower_motion(trained):
    """A held pose (0.5 s still at 40 % of a motion, 0.1 mm of noise) is reported at rest, while the motion on
    either side of it is not. The estimate reads the hold as a slower motion (docs/method.md §13: one time-scaling of
    the demonstrations): the end time moves later and its band widens, the phase does not run on to the motion's
    end (it stays near 0.4: 0.40 → 0.36 here), and once the motion resumes the end band holds the real end."""
    _, paths = trained
    tr = family(1, 7)[0][0]
    k = int(0.4 * len(tr.t))
    rng = np.random.default_rng(0)
    f = Follower(paths, detect=False)
    moving = []
    for j in range(k + 1):
        f.push(tr.t[j], tr.quat[j], tr.position[j])
        moving.append(f.at_rest)
    assert not any(moving[2:])
    before = f.push(tr.t[k] + 1.0 / RATE, tr.quat[k], tr.position[k])
    held = []
    for t in tr.t[k] + np.arange(2, 26) / RATE:
        held.append((f.push(t, tr.quat[k], tr.position[k] + 1e-4 * rng.standard_normal(3)), f.at_rest))
    assert all(a for _, a in held[1:])
    last = held[-1][0]
    assert last.end_time > before.end_time + 0.5 * 0.5  # later by at least half the hold
    assert last.end_time_band[1] - last.end_time_band[0] > before.end_time_band[1] - before.end_time_band[0]
    assert max(e.phase for e, _ in held) < 0.5
    true_end = tr.t[-1] + 0.5
    after = []
    for j in range(k + 1, len(tr.t)):
        est = f.push(tr.t[j] + 0.5, tr.quat[j], tr.position[j])
        after.append(f.at_rest)
        assert est.end_time_band[0] <= true_end <= est.end_time_band[1]
    assert not any(after[2:-10])  # moving again (the last poses slow to the end)


def test_bad_seen_input_is_one_clear_error(trained):
    _, paths = trained
    ant = Anticipator(paths)
    with pytest.raises(InputError, match="increase"):
        ant.estimate([0.0, 0.0, 0.1], np.tile([0, 0, 0, 1.0], (3, 1)), np.zeros((3, 3)))
    with pytest.raises(InputError, match="NaN"):
        ant.estimate([0.0, 0.1], np.tile([0, 0, 0, 1.0], (2, 1)), np.array([[0, 0, 0], [np.nan, 0, 0]]))
    with pytest.raises(InputError, match="path distribution"):
        Anticipator(None)


@pytest.mark.slow
def test_the_api_predicts_the_rest_and_follows_a_stream():
    import rbgp_cli as rbgp

    demos, _ = family(8, 3)
    gp = rbgp.RigidBodyGP(restarts=1, max_points=150).fit(demos)
    assert gp.model_.paths is not None
    seen, _ = _seen(demos[0], 0.4)
    c = gp.predict_rest(seen, samples=4, seed=0)
    assert c.t[0] == pytest.approx(seen.t[-1]) and len(c.samples) == 4
    assert np.linalg.norm(c.position[0] - seen.position[-1]) < 5e-3  # the GP's rollout starts at the last seen pose
    # the end pose it reports is where the rolled continuation ends (the JSON's end is the CSV's last row)
    assert np.array_equal(c.estimate.end_position, c.position[-1]) and np.array_equal(c.estimate.end_quat, c.quat[-1])
    both = gp.predict_rest([seen, seen])
    assert [x.name for x in both] == ["0", "1"] and np.array_equal(both[0].position, both[1].position)
    f = gp.follower(detect=False)
    est = [f.push(t, q, p) for t, q, p in zip(seen.t, seen.quat, seen.position)][-1]
    assert est.t == pytest.approx(seen.t[-1]) and 0.2 < est.phase < 0.6


def test_the_stream_evaluates_only_the_live_duration_cells_and_loses_nothing(trained):
    """Follower restricts the duration grid to the cells that carried weight at the last update and their
    neighbours (the live update's cost); every estimate must equal the full grid's (an independent
    Anticipator on the same buffer) to within the weight left out."""
    _, paths = trained
    tr = family(1, 13)[0][0]
    f = Follower(paths, detect=False)
    full = Anticipator(paths, None, points=f.anticipator.points, grid_size=len(f.anticipator.grid), mix_end=False)
    evaluated = []
    for j in range(len(tr.t)):
        e = f.push(tr.t[j], tr.quat[j], tr.position[j])
        ref = full.estimate(tr.t[: j + 1], tr.quat[: j + 1], tr.position[: j + 1])
        assert e.end_time == pytest.approx(ref.end_time, rel=1e-6)
        assert e.phase == pytest.approx(ref.phase, rel=1e-6)
        np.testing.assert_allclose(e.end_position, ref.end_position, atol=1e-7)
        np.testing.assert_allclose(e.end_position_band, ref.end_position_band, rtol=1e-5, atol=1e-9)
        if f._active is not None:
            evaluated.append(int(f._active.sum()))
    # the restriction does bite once the duration is known (else it would be no saving)
    assert evaluated and min(evaluated) < len(f.anticipator.grid) // 2


def test_the_reported_end_pose_is_the_continuations_end(trained):
    """The estimate's end pose (``rollout --given --json``, ``rbgp follow``) is the continuation's: the rest's
    conditioning with its last seen pose exact (:meth:`Anticipator.rest_end`, in the batched grid form the live
    update affords) against the dense conditioning's end entries at durations off the estimate; the mean's average
    over the duration's weights against a loop over the kept cells; the reported end against the continuation's
    last row; the live follower reports the rest's conditioned end at its median duration."""
    demos, paths = trained
    ant = Anticipator(paths, None)
    tr = family(1, 17)[0][0]
    for F in (0.25, 0.5, 0.8):
        seen, _ = _seen(tr, F)
        grid, w, terms = ant.weights(seen.t, seen.quat, seen.position)
        tau, q, p = terms["seen"][3:]
        for D in (0.8 * tr.duration, tr.duration, 1.3 * tr.duration):
            dense = ant._conditioned_mean(tau, q, p, seen.quat[-1], seen.position[-1], D)[0][ant._end]
            np.testing.assert_allclose(ant.rest_end(tau, q, p, D), dense, rtol=1e-6, atol=1e-7)
        # the mean averages the conditioned paths over the duration's weights: its end is the weighted mean of the
        # dense conditioned ends (a loop over the kept cells), and it passes through the last seen pose
        keep = w >= MIX_WEIGHT * w.max()
        if F == 0.25:
            assert np.count_nonzero(keep) >= 2  # early on the duration is uncertain: the average is over several
        est = ant._summary(grid, w, terms)
        # where one cell carries the weight, the end is the one conditioned at D̂ itself (its median or mode)
        at = grid[keep] if np.count_nonzero(keep) >= 2 else np.array([est.end_time - seen.t[0]])
        share = w[keep] / w[keep].sum() if len(at) > 1 else np.ones(1)
        dense_ends = np.array([ant._conditioned_mean(tau, q, p, seen.quat[-1], seen.position[-1], d)[0][ant._end]
                               for d in at])
        mixed = share @ dense_ends
        end_hat = ant._at_estimate(tau, q, p, est.end_time - seen.t[0], grid, w)[0]
        np.testing.assert_allclose(end_hat, mixed, rtol=1e-6, atol=1e-7)
        dev = ant._mixed_deviation(tau, q, p, seen.quat[-1], seen.position[-1], grid, w, est.end_time - seen.t[0])
        np.testing.assert_allclose(dev[-1], mixed * paths.scale, rtol=1e-6, atol=1e-7)
        s0 = min(tau[-1] / (est.end_time - seen.t[0]), 1.0)
        q0, p0 = paths.pose_at(dev, np.array([s0]))
        assert np.linalg.norm(p0[0] - seen.position[-1]) < 2e-3
        c = ant.continuation(seen.t, seen.quat, seen.position)
        np.testing.assert_allclose(c.estimate.end_position, c.position[-1], atol=1e-9)
        assert abs(np.dot(c.estimate.end_quat, c.quat[-1])) > 1 - 1e-12
        # the seen part's last pose is kept: a different last pose moves the reported end
        moved = ant.estimate(seen.t, seen.quat, seen.position + np.array([0.0, 0.0, 0.02]) * (seen.t == seen.t[-1])[:, None])
        assert np.linalg.norm(moved.end_position - c.estimate.end_position) > 1e-3
    # the live follower affords one conditioning of the rest per update: its end is the rest's at D̂ (median or mode)
    f = Follower(paths, detect=False)
    live = Anticipator(paths, None, points=f.anticipator.points, grid_size=len(f.anticipator.grid), mix_end=False)
    seen, _ = _seen(tr, 0.25)
    est = [f.push(t, q, p) for t, q, p in zip(seen.t, seen.quat, seen.position)][-1]
    grid, w, terms = live.weights(seen.t, seen.quat, seen.position)
    end = paths.unscale(np.append(np.zeros(6 * (paths.S - 1)), [*live.rest_end(*terms["seen"][3:], est.end_time - seen.t[0]), 0.0]))[0][-1]
    np.testing.assert_allclose(est.end_position, paths.position[-1] + end[3:], atol=1e-6)


def test_the_end_band_is_the_samples_conditional_covariance_plus_the_durations_spread(trained):
    """The end pose's band: its covariance is the end's conditional covariance at D̂ as the samples draw it (the dense
    conditioning with the path distribution's own τ² and r, the last seen pose exactly) plus the spread of the ends
    conditioned for the weights, about their own mean; so it narrows as the end comes near (until the twentieth pass
    the ends' offset from the centre counted as spread, and a handover's band grew to 3.6 rad at 98 % seen), and the
    rotation's is an angle of at most π."""
    _, paths = trained
    ant = Anticipator(paths, None)
    tr = family(1, 17)[0][0]
    bands = []
    for F in (0.3, 0.6, 0.9, 0.97):
        seen, _ = _seen(tr, F)
        grid, w, terms = ant.weights(seen.t, seen.quat, seen.position)
        tau, q, p = terms["seen"][3:]
        est = ant._summary(grid, w, terms)
        D = est.end_time - seen.t[0]
        cov_own = ant._at_estimate(tau, q, p, D)[2]
        A, _, r2 = ant._observations(tau, q, p, seen.quat[-1], seen.position[-1], D, rest=False)
        gain = ant._gain(A, r2, rest=False)
        dense = (ant.Sigma - gain @ A @ ant.Sigma)[np.ix_(ant._end, ant._end)]
        np.testing.assert_allclose(cov_own, dense, rtol=1e-5, atol=1e-9)
        # the band's own width, its factors (fitted per seen fraction) and widening divided out
        c_rot, c_pos = ant.end_band_at(est.phase)
        s = est.band_widening
        bands.append((est.end_rotation_band / (c_rot * s), float(np.linalg.norm(est.end_position_band)) / (c_pos * s)))
        assert est.end_rotation_band <= np.pi
    bands = np.array(bands)
    assert np.all(bands[-1] < 0.5 * bands[0]), bands  # near the end the covariance's band is a fraction of its early width
    assert np.all(np.diff(bands[1:], axis=0) < 0), bands  # and it narrows as more is seen


def test_the_strided_kronecker_and_diagonal_helpers_match_their_dense_forms():
    """The batched grid terms add τ² K ⊗ I_6 and the tolerances through strided views (_add_kron_i6, _diagonal):
    equal to numpy's dense Kronecker product and diagonal, on views inside a larger matrix, and a view that would
    need a copy (the additions lost) is refused."""
    from rbgp_cli.dynamics.anticipation import _add_kron_i6, _diagonal

    rng = np.random.default_rng(3)
    K = rng.normal(size=(2, 3, 4))
    out = np.zeros((2, 1 + 18, 1 + 24))
    _add_kron_i6(out[:, 1:, 1:], K)
    assert np.array_equal(out[:, 1:, 1:], np.stack([np.kron(k, np.eye(6)) for k in K]))
    assert not out[:, 0].any() and not out[:, :, 0].any()
    A = rng.normal(size=(3, 5, 5))
    before = A.copy()
    _diagonal(A, 1, 4)[...] += 10.0
    expect = before.copy()
    for j in range(1, 4):
        expect[:, j, j] += 10.0
    assert np.array_equal(A, expect)
    with pytest.raises(AttributeError):
        _diagonal(A[:, :4, :4], 0, 2)
