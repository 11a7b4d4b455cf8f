"""Rollouts: new motions from start poses by single-step mean prediction (docs/method.md §8, paper sec. 4.3).

From start poses g_0 (B of them, advanced together):

    ξ_k = μ(g_k),      g_{k+1} = step(g_k, ξ_k, Δt)   (exp map for axis-angle, addition for baselines)

All B trajectories share one kernel block per step (B × n), not one per trajectory. Uncertainty:
the latent predictive standard deviation σ(g_k) of every output along each mean trajectory, and
optionally K Monte Carlo rollouts per start that draw ξ_k ~ N(μ(g_k), σ²(g_k)) each step from a
seeded rng.

Leaving the data: each mean trajectory is checked against the demonstrations' envelope
(:mod:`rbgp_cli.dynamics.envelope`, stored in the model): a phase model at its phase t/D (D its
duration, the phase its GP sees); a model without the phase input, whose GP does not see where in the
motion it is, against the box of all the demonstrations' positions. ``outside`` marks the
samples beyond it and ``left`` reports which trajectories left it, when and where first. ``off_data``
says what a rollout does there: ``keep`` (go on as before), ``stop`` (the trajectory ends at its first
sample outside, which is kept so the exit shows, and at least one step is made) or ``prior`` (while a
state is outside, its velocity is the prior mean's alone, ξ = m(g), not the GP's: the mean-path
prior's pull back toward the demonstrations; a model without a prior mean refuses it). The Monte Carlo
samples follow ``prior`` too but are not checked or cut.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rbgp_cli.dynamics.trajectory import Trajectory
from rbgp_cli.errors import InputError, RbgpRuntimeError
from rbgp_cli.geometry.so3 import quat_make_continuous, quat_normalize

__all__ = ["RolloutResult", "rollout", "rollout_for", "rollout_one_at_a_time", "starts_near", "start_vectors"]


@dataclass
class RolloutResult:
    """Rolled-out trajectories.

    t : (S+1,) seconds from the start
    quat : (B, S+1, 4) x, y, z, w (sign-continuous along time); position : (B, S+1, 3) metres
    std : (B, S+1, L) latent predictive std of each output at each state, or None
    output_names : names of the L outputs (e.g. wx ... vz)
    sample_quat : (B, K, S+1, 4) and sample_position : (B, K, S+1, 3) Monte Carlo rollouts, or None
    integration : (steps S, dt seconds) of the integration behind a resampled result, or None
    lengths : (B,) samples each trajectory keeps (its own duration; its Monte Carlo samples alike), or
        None: all S+1. The arrays hold every step for every trajectory; :meth:`trajectories` cuts them.
    outside : (B, S+1) True where a mean trajectory's sample lies outside the demonstrations' envelope
    left : :func:`~rbgp_cli.dynamics.envelope.exits_report` of the mean trajectories, or None
    ends : (B,) index of each mean trajectory's last sample (``off_data="stop"``), or None (all S)
    band_position : (B, S+1, 3) m and band_rotation : (B, S+1, 3, 3) rad²: the 90 % band of the next
        real motion around each mean trajectory (with sampled rollouts of a model that has a variation
        model or a path distribution, else None): |p − p_mean|_j ≤ band_position_j, and eᵀ M⁻¹ e ≤ 1 for
        e = log(R R_meanᵀ), M = band_rotation (:meth:`~rbgp_cli.dynamics.variation.Variation.region`)
    band_widening : (B, 2) the factors s ≥ 1 each start's surprise widened its band's rotation and position part by
        (:meth:`~rbgp_cli.dynamics.variation.Variation.start_widening`), or None
    start_beyond : (B,) each start's surprise over the largest of the demonstrations' own, ρ / ρ_max (above 1: less
        like the demonstrations' starts than any of theirs was like the others';
        :meth:`~rbgp_cli.dynamics.variation.Variation.start_beyond`), or None
    """

    t: np.ndarray
    quat: np.ndarray
    position: np.ndarray
    std: np.ndarray | None
    output_names: tuple
    sample_quat: np.ndarray | None = None
    sample_position: np.ndarray | None = None
    lengths: np.ndarray | None = None
    #: (S, dt) of the integration when :meth:`resampled` put the result on another grid, else None
    integration: tuple | None = None
    outside: np.ndarray | None = None
    left: dict | None = None
    ends: np.ndarray | None = None
    #: the goals (quat (B, 4), position (B, 3)) and via-points [(T s, quat (4,), position (3,))] the mean
    #: trajectories were conditioned on (:func:`rollout_conditioned`), else None / empty
    goal_quat: np.ndarray | None = None
    goal_position: np.ndarray | None = None
    via: tuple = ()
    #: (B,) each goal's distance from where the demonstrations end, in their spreads, or None
    goal_distance: np.ndarray | None = None
    #: (B, V) each via-point's distance from where the demonstrations pass at its phase, or None
    via_distance: np.ndarray | None = None
    #: (B,) the factor λ ≥ 1 on the smooth shrinkage each conditioned motion took
    #: (:meth:`~rbgp_cli.dynamics.paths.PathDistribution.goal_strength`), or None
    goal_strength: np.ndarray | None = None
    band_position: np.ndarray | None = None
    band_rotation: np.ndarray | None = None
    band_widening: np.ndarray | None = None
    start_beyond: np.ndarray | None = None

    @property
    def count(self) -> int:
        return self.quat.shape[0]

    def length(self, b: int) -> int:
        """Samples trajectory ``b`` keeps: its own duration (``lengths``), and no further than where it was
        stopped on leaving the data (``ends``)."""
        n = len(self.t) if self.lengths is None else int(self.lengths[b])
        return n if self.ends is None else min(n, int(self.ends[b]) + 1)

    def trajectories(self, include_samples: bool = False) -> list[Trajectory]:
        """The mean rollouts (names ``0``, ``1``, …) and, optionally, the samples (``0.s0``, …), each
        cut to its own length."""
        n = [self.length(b) for b in range(self.count)]
        out = [Trajectory(self.t[:n[b]], self.quat[b, :n[b]], self.position[b, :n[b]], name=str(b)) for b in range(self.count)]
        if include_samples and self.sample_quat is not None:
            for b in range(self.count):
                for k in range(self.sample_quat.shape[1]):
                    out.append(Trajectory(self.t[:n[b]], self.sample_quat[b, k, :n[b]], self.sample_position[b, k, :n[b]],
                                          name=f"{b}.s{k}"))
        return out

    def resampled(self, rate: float) -> "RolloutResult":
        """The same rollouts at ``rate`` Hz: times t'_j = j / rate for t'_j <= t_S (each trajectory up
        to its own end, or to where it was stopped on leaving the data; when every trajectory ends at the same t_S
        off that grid, t_S is written as well, so that the last row is the motion's end), poses by slerp (rotation)
        and linear interpolation (position) between the
        integration steps around t'_j (:func:`~rbgp_cli.dynamics.trajectory.interpolate_poses`), the
        predictive std linearly. Output times on a step (t'_j = t_k) give that step's state exactly, so
        resampling changes nothing the integration computed; it only adds points between the steps.
        """
        from rbgp_cli.dynamics.trajectory import interpolate_poses

        rate = float(rate)
        if not (np.isfinite(rate) and rate > 0):
            raise InputError(f"the output rate must be a positive number of Hz, got {rate}")
        t = self.t
        ends = t[np.asarray([self.length(b) for b in range(self.count)]) - 1]  # (B,) seconds
        tol = 1e-9 * max(1.0, float(t[-1]))
        if not (float(ends.max()) + tol) * rate < 2.0**62:  # past any integer count of samples: no grid at all
            raise InputError(f"an output rate of {rate:g} Hz is too high for a {float(ends.max()):g} s motion",
                             hint="use output_rate near the recorded rate, or leave it out for that rate",
                             param="output_rate")
        count = np.floor((ends + tol) * rate).astype(int) + 1  # (B,) output samples of each trajectory
        t_new = np.arange(int(count.max())) / rate  # (T,) the times written
        if np.ptp(ends) <= tol and ends[0] - t_new[-1] > tol:  # one end, off the grid: written too (the goal, the end)
            t_new = np.append(t_new, ends[0])
            count = count + 1
        # a target that is a step up to rounding is that step, so those samples are copied bit for bit
        near = np.clip(np.round(t_new / (t[1] - t[0])).astype(int), 0, len(t) - 1)
        x_new = np.where(np.abs(t[near] - t_new) <= tol, t[near], t_new)  # where to interpolate
        quat, pos = interpolate_poses(t, self.quat, self.position, x_new)
        std = None
        if self.std is not None:  # linear, with the same brackets k and fractions f as the poses
            k = np.clip(np.searchsorted(t, x_new, side="right") - 1, 0, len(t) - 2)
            f = np.clip((x_new - t[k]) / (t[k + 1] - t[k]), 0.0, 1.0)[:, None]
            std = (1.0 - f) * self.std[:, k] + f * self.std[:, k + 1]
        if self.band_position is not None:  # linear in time, as the std
            k = np.clip(np.searchsorted(t, x_new, side="right") - 1, 0, len(t) - 2)
            f = np.clip((x_new - t[k]) / (t[k + 1] - t[k]), 0.0, 1.0)
            band_p = (1.0 - f[:, None]) * self.band_position[:, k] + f[:, None] * self.band_position[:, k + 1]
            band_r = (1.0 - f[:, None, None]) * self.band_rotation[:, k] + f[:, None, None] * self.band_rotation[:, k + 1]
        res = RolloutResult(t=t_new, quat=quat, position=pos, std=std, output_names=self.output_names,
                            # each its own length, and no further than where it was stopped (``ends``, in count)
                            lengths=None if self.lengths is None and self.ends is None else count,
                            integration=self.integration or (len(t) - 1, float(t[1] - t[0])))
        if self.sample_quat is not None:
            res.sample_quat, res.sample_position = interpolate_poses(t, self.sample_quat, self.sample_position, x_new)
        if self.outside is not None:  # a written sample is outside where either integration step around it is
            k = np.clip(np.searchsorted(t, x_new, side="right") - 1, 0, len(t) - 1)
            k1 = np.minimum(k + 1, len(t) - 1)
            on = np.abs(t[k] - x_new) <= tol
            res.outside = self.outside[:, k] | (self.outside[:, k1] & ~on[None, :])
            res.left = self.left
        res.goal_quat, res.goal_position, res.via, res.goal_distance = (self.goal_quat, self.goal_position, self.via,
                                                                       self.goal_distance)
        res.via_distance = self.via_distance
        res.goal_strength = self.goal_strength
        res.band_widening, res.start_beyond = self.band_widening, self.start_beyond
        if self.band_position is not None:
            res.band_position, res.band_rotation = band_p, band_r
        return res


def _check_finite(state, step):
    if not np.all(np.isfinite(state)):
        # at the first step the start is the likelier cause (a position in mm, or 1e308) than the model
        hint = ("check the start poses (metres; near the demonstrations'), then the model with rbgp info" if step == 1
                else "check the model with rbgp info")
        raise RbgpRuntimeError(f"the rollout diverged (non-finite state) at step {step}", hint=hint)


#: How sampled rollouts are drawn: ``path`` (one coherent deviation of the demonstrations' kind per
#: sample, :mod:`rbgp_cli.dynamics.variation`; the default where the model has it) or ``step``
#: (independent draws of the velocity from the predictive Gaussian at every step, docs/method.md §8).
SAMPLINGS = ("path", "step")


def rollout(model, start_quat, start_position, steps: int, dt: float | None = None, *, samples: int = 0,
            seed: int = 0, with_std: bool = True, progress=None, durations=None, sampling: str | None = None,
            off_data: str = "keep") -> RolloutResult:
    """Roll out ``model`` (a :class:`~rbgp_cli.dynamics.model.MotionModel`) from B start poses.

    Parameters
    ----------
    start_quat : (B, 4) x, y, z, w;  start_position : (B, 3) metres
    steps : number of integration steps S (the result has S + 1 samples)
    dt : step in seconds (default: the model's, i.e. the demonstrations' median time step)
    samples : K sampled rollouts per start, drawn as ``sampling`` says
    sampling : ``"path"`` (default when the model has a :attr:`~MotionModel.variation`): sample k of
        start b is the mean rollout from b displaced by one typical draw η of the demonstrations'
        deviation process at the trajectory's phase t/duration_b, R = exp(η_rot) R̄_b, p = p̄_b + η_pos
        (zero at the start; :meth:`~rbgp_cli.dynamics.variation.Variation.draw`), and the result carries
        the 90 % band of the next real motion (``band_position``, ``band_rotation``:
        :meth:`~rbgp_cli.dynamics.variation.Variation.region`); ``"step"`` (the default without one):
        Monte Carlo rollouts drawing ξ from the latent predictive Gaussian at every step
    seed : seeds the draws
    with_std : record the predictive std along the mean trajectories (costs one triangular solve per
        step; switch off for speed)
    durations : (B,) seconds each trajectory is meant to last (default steps·dt for all). Only a model
        with a phase input uses it: trajectory b advances its phase by dt/durations[b] per step, so a
        batch of different lengths can share the steps (each is then cut to its own duration).
    progress : optional :class:`rbgp_cli.progress.Progress`: a task "rollout" over the steps
    off_data : ``keep``, ``stop`` or ``prior``: what a trajectory does outside the demonstrations'
        envelope (module docstring); every mode fills ``outside`` and ``left``
    """
    from rbgp_cli.compute import blas_threads

    # Always single-threaded: per step the matrices are only B × n, and a 2-thread OpenBLAS pool
    # made 100 × 626 steps at n = 1752 take 11.0 s instead of 3.8 s on a loaded machine (measured).
    from rbgp_cli.progress import as_progress

    with blas_threads(0), as_progress(progress).task("rollout", total=int(steps), unit="steps") as task:
        if sampling is None:
            sampling = "path" if getattr(model, "variation", None) is not None else "step"
        if sampling not in SAMPLINGS:
            raise InputError(f"unknown sampling {sampling!r}; expected one of {', '.join(SAMPLINGS)}")
        if sampling == "path" and samples:
            if getattr(model, "variation", None) is None:
                raise InputError("this model has no model of how its demonstrations differ (fewer than three, or "
                                 "an older model file)", hint="sample with sampling 'step', or retrain it with rbgp train on three demonstrations or more")
            res = _rollout(model, start_quat, start_position, steps, dt, 0, seed, with_std, task, durations, off_data)
            return _path_samples(model.variation, res, int(samples), seed, durations)
        return _rollout(model, start_quat, start_position, steps, dt, samples, seed, with_std, task, durations, off_data)


def _path_samples(variation, res: RolloutResult, K: int, seed: int, durations) -> RolloutResult:
    """``res`` with K path samples per trajectory: the mean rollout displaced by typical draws of the
    deviation process at each trajectory's phase (see :func:`rollout`), batched over trajectories and
    samples, and the 90 % band of the next real motion at the same phases, widened by each start's surprise."""
    from rbgp_cli.geometry.so3 import exp_quat, quat_multiply

    B = res.count
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 20]))
    dur = np.full(B, res.t[-1]) if durations is None else np.asarray(durations, dtype=np.float64).reshape(B)
    phase = res.t[None, :] / dur[:, None]  # (B, T)
    eta = variation.draw(B * K, rng).reshape(B, K, len(variation.s), 6)
    dev = variation.at(eta, np.broadcast_to(phase[:, None, :], (B, K, len(res.t))))  # (B, K, T, 6)
    res.sample_quat = quat_make_continuous(quat_multiply(exp_quat(dev[..., :3]), res.quat[:, None]))
    res.sample_position = res.position[:, None] + dev[..., 3:]
    # widened by each start's surprise (Variation.start_widening: 1 for a start like the demonstrations')
    res.band_widening = variation.start_widening(res.quat[:, 0], res.position[:, 0])
    res.band_position, res.band_rotation = variation.region(phase, widen=res.band_widening)  # (B, T, 3), (B, T, 3, 3)
    return res


def _rollout_result(rep, states, sstates, std, steps, dt, B, K, pd, envelope, duration, phase_of, off_data):
    """The :class:`RolloutResult` of the integrated states (steps + 1, B, d) (``sstates`` (steps + 1,
    B·K, d) of the samples, ``std`` (steps + 1, B, L) or None): poses, where they leave the
    ``envelope`` and, with ``off_data="stop"``, where each trajectory ends."""
    from rbgp_cli.dynamics.envelope import exits_report

    quat, pos = rep.pose_from_state(states[..., :pd].reshape(-1, pd))
    quat = quat_make_continuous(quat.reshape(steps + 1, B, 4).transpose(1, 0, 2))
    pos = pos.reshape(steps + 1, B, 3).transpose(1, 0, 2)
    res = RolloutResult(
        t=np.arange(steps + 1) * dt, quat=quat, position=pos,
        std=None if std is None else std.transpose(1, 0, 2), output_names=tuple(rep.output_names),
    )
    t = res.t
    res.outside = envelope.outside(pos, phase_of(t[None, :], duration))
    res.left = exits_report(res.outside, t, pos, envelope)
    if off_data == "stop":
        first = np.where(res.outside.any(axis=1), res.outside.argmax(axis=1), steps)
        res.ends = np.maximum(first, 1)
    if K > 0:
        sq, sp = rep.pose_from_state(sstates[..., :pd].reshape(-1, pd))
        res.sample_quat = quat_make_continuous(sq.reshape(steps + 1, B, K, 4).transpose(1, 2, 0, 3))
        res.sample_position = sp.reshape(steps + 1, B, K, 3).transpose(1, 2, 0, 3)
    return res


def _rollout(model, start_quat, start_position, steps, dt, samples, seed, with_std, task, durations, off_data="keep"):
    """:func:`rollout`'s integration: the B mean trajectories and, with ``samples`` = K, K Monte Carlo
    rollouts per start (a latent velocity drawn at every step from ``seed``), advanced in one loop."""
    from rbgp_cli.dynamics.envelope import OFF_DATA

    if off_data not in OFF_DATA:
        raise InputError(f"off_data must be one of {', '.join(OFF_DATA)}, got {off_data!r}", param="off_data")
    if off_data == "prior" and not model.mean:
        raise InputError("off_data prior falls back to the model's prior mean, and this model has none",
                         hint="use off_data keep or stop, or train with prior path (or goal)", param="off_data")
    envelope = model.data_envelope()
    if model.time_input != "phase":  # its GP does not see the phase: where the demonstrations went at any time
        envelope = envelope.overall()
    rep, gp = model.representation, model.gp
    dt = float(model.dt if dt is None else dt)
    if not np.isfinite(dt) or dt <= 0:
        raise InputError(f"dt must be a positive number of seconds, got {dt}", param="dt")
    steps = int(steps)
    if steps < 1:
        raise InputError(f"steps must be at least 1, got {steps}", param="steps")
    q0 = quat_normalize(np.asarray(start_quat, dtype=np.float64).reshape(-1, 4))
    p0 = np.asarray(start_position, dtype=np.float64).reshape(-1, 3)
    B, K = len(q0), int(samples)
    task.update(status=f"{B} trajectories" + (f", {K} Monte Carlo samples each" if K else ""))
    duration = np.full((B, 1), steps * dt) if durations is None else np.asarray(durations, dtype=np.float64).reshape(B, 1)
    if not np.all(np.isfinite(duration) & (duration > 0)):
        raise InputError("rollout durations must be positive numbers of seconds")
    state = model.initial_state(q0, p0)
    # a start-conditioned prior: each trajectory's own reference path, from its start (None: the mean path)
    dev = model.start_deviation(q0, p0) if hasattr(model, "start_deviation") else None
    sdev = None if dev is None or K == 0 else np.repeat(dev, K, axis=0)
    # a secant feed-forward: the reference's displacement over each trajectory's own phase step dt/D
    step = model.phase_step(duration[:, 0], dt)
    sstep = None if step is None or K == 0 else np.repeat(step, K)
    d = state.shape[1]
    L = gp.n_outputs
    states = np.empty((steps + 1, B, d))
    states[0] = state
    std = np.empty((steps + 1, B, L)) if with_std else None
    rng = np.random.default_rng(seed)
    if K > 0:
        sstate = np.repeat(state, K, axis=0)  # (B*K, d), sample k of start b at row b*K + k
        sstates = np.empty((steps + 1, B * K, d))
        sstates[0] = sstate
    pd = model.pose_dims

    def phase_of(t, dur):  # a phase model's own phase (what it feeds the GP); others: one box for all
        return t / dur

    def fall_back(X, mu, k, dur, dev, h):
        """``off_data="prior"``: the prior mean's velocity where X (at step k) is outside the envelope."""
        off = envelope.outside(rep.pose_from_state(X[:, :pd])[1], phase_of(k * dt, dur[:, 0]))
        if np.any(off):
            mu = mu.copy()
            mu[off] = model.prior_mean(X[off], None if dev is None else dev[off], None if h is None else h[off])
        return mu

    for k in range(steps + 1):
        last = k == steps
        if with_std:
            mu, sd = model.predict_output(state, return_std=True, manage_threads=False, start_dev=dev, step=step)
            std[k] = sd / duration if model.time_input == "phase" else sd  # per second
        elif not last:
            mu = model.predict_output(state, manage_threads=False, start_dev=dev, step=step)
        if not last:
            if off_data == "prior":
                mu = fall_back(state, mu, k, duration, dev, step)
            state = model.advance(state, mu, dt, duration)
            _check_finite(state, k + 1)
            states[k + 1] = state
            if K > 0:
                smu, ssd = model.predict_output(sstate, return_std=True, manage_threads=False, start_dev=sdev, step=sstep)
                if off_data == "prior":
                    smu = fall_back(sstate, smu, k, np.repeat(duration, K, axis=0), sdev, sstep)
                sstate = model.advance(sstate, smu + ssd * rng.standard_normal(smu.shape), dt, np.repeat(duration, K, axis=0))
                _check_finite(sstate, k + 1)
                sstates[k + 1] = sstate
        if not last:
            task.advance()
    return _rollout_result(rep, states, sstates if K > 0 else None, std, steps, dt, B, K, pd, envelope, duration,
                           phase_of, off_data)


def rollout_for(model, start_quat, start_position, durations, dt: float | None = None, **kwargs) -> RolloutResult:
    """Roll out B starts, each for its own duration ``durations`` (B,) seconds.

    Trajectory b takes S_b = round(D_b / dt) steps (at least 1; dt by default the model's rollout step,
    :attr:`~rbgp_cli.dynamics.model.MotionModel.rollout_dt`: the recorded sample interval); all
    are advanced together for max S_b steps (a phase model advances trajectory b's phase by
    dt / (S_b dt) per step, see :func:`rollout`), and ``lengths`` = S_b + 1 cuts each of them (and its
    Monte Carlo samples) to its own duration in :meth:`RolloutResult.trajectories`. ``kwargs`` go to
    :func:`rollout` (samples, seed, with_std, progress).
    """
    dt = float(model.rollout_dt if dt is None else dt)
    durations = np.asarray(durations, dtype=np.float64).reshape(-1)
    if not np.all(np.isfinite(durations) & (durations > 0)):
        raise InputError("every rollout duration must be a positive number of seconds")
    steps = np.maximum(1, np.round(durations / dt).astype(int))  # (B,)
    res = rollout(model, start_quat, start_position, int(steps.max()), dt, durations=steps * dt, **kwargs)
    res.lengths = steps + 1
    if res.outside is not None:  # a trajectory past its own end is not a rollout that left the data
        from rbgp_cli.dynamics.envelope import exits_report

        res.outside = res.outside & (np.arange(len(res.t))[None, :] < res.lengths[:, None])
        res.left = exits_report(res.outside, res.t, res.position, model.data_envelope())
    return res


def rollout_one_at_a_time(model, start_quat, start_position, steps: int, dt: float | None = None) -> RolloutResult:
    """The unbatched reference: each start rolled out alone (for benchmarks and tests)."""
    parts = [rollout(model, q[None], p[None], steps, dt, with_std=False) for q, p in zip(start_quat, start_position)]
    return RolloutResult(parts[0].t, np.concatenate([r.quat for r in parts]), np.concatenate([r.position for r in parts]),
                         None, parts[0].output_names)


def start_vectors(trajs) -> np.ndarray:
    """The start pose of each trajectory as one row ``(qx, qy, qz, qw, x, y, z)``: (D, 7), what
    :func:`starts_near` and ``MotionModel.starts`` hold."""
    return np.array([np.concatenate([t.quat[0], t.position[0]]) for t in trajs], dtype=np.float64).reshape(-1, 7)


#: The isotropic start perturbation (metres) used when the starts cannot shape one: fewer than two of them.
START_SPREAD_FALLBACK = 0.02


def start_bandwidth(n: int, dims: int = 6) -> float:
    """Silverman's rule for a Gaussian kernel in ``dims`` dimensions on ``n`` points,
    h = (4 / (n (d + 2)))^(1/(d + 4)): the kernel's share of the drawn starts' spread
    (:func:`starts_near`; n = 6: 0.78, n = 40: 0.65)."""
    return float((4.0 / (max(n, 1) * (dims + 2))) ** (1.0 / (dims + 4)))


def starts_near(starts: np.ndarray, count: int, spread: float | None, seed: int = 0, spread_rot: float | None = None,
                return_index: bool = False, in_order: bool = False, shape: np.ndarray | None = None):
    """``count`` start poses near the given ones (paper sec. 4.3: 100 unseen starts near the demos').

    Each new start takes a demonstration start j (cycling through them in a seeded random order; with
    ``in_order``, new start i near start i mod D, so that the i-th output belongs to the i-th input) and
    perturbs it.

    ``spread`` None (the default of ``rbgp rollout``): shaped by the starts themselves, a smoothed
    bootstrap that keeps their mean and covariance. In the coordinates c = (log(R R₀ᵀ), p − p₀) of each
    start about the first one (rotation first), with c̄ their mean, the new start near start j is

        c = c̄ + √(1 − h²) (c_j − c̄) + h Σ_k z_k (c_k − c̄) / √(D − 1),   z ~ N(0, I_D),

    h = :func:`start_bandwidth` (D) (Silverman's rule), so that the new starts have the starts' mean c̄ and
    covariance Σ (the perturbation lies in the span of the starts' own deviations: a coordinate in which
    they do not vary is not varied). With fewer than two starts there is no spread to follow: with ``shape``
    ((M, 7) other starts of the same motion, M ≥ 2, e.g. those a model stores) the start is moved by
    h Σ_k z_k (s_k − s̄) / √(M − 1) of their coordinates (h = :func:`start_bandwidth` (M)), else by the isotropic
    perturbation below with :data:`START_SPREAD_FALLBACK`.

    ``spread`` a number: translation by N(0, spread²) per axis (metres), rotation by exp of a N(0, s_r²)
    rotation vector with s_r = spread_rot (radians; default spread / 0.3 m × 0.1 rad, i.e. about
    0.1 rad per 0.3 m of translation spread).

    starts : (D, 7) = (qx, qy, qz, qw, x, y, z). Returns (quat (count, 4), position (count, 3)), and
    with ``return_index`` also the index (count,) of the start each one was drawn near.
    """
    from rbgp_cli.geometry.so3 import exp_quat, log_quat, quat_conjugate, quat_multiply

    starts = np.asarray(starts, dtype=np.float64).reshape(-1, 7)
    if len(starts) == 0:
        raise InputError("no start poses to draw from")
    if count < 1:
        raise InputError(f"count must be at least 1, got {count}", param="count")
    if spread is not None and not spread >= 0:
        raise InputError(f"spread must be >= 0, got {spread}", param="spread")
    rng = np.random.default_rng(seed)
    if in_order:
        order = np.arange(count) % len(starts)
    else:
        order = np.concatenate([rng.permutation(len(starts)) for _ in range(-(-count // len(starts)))])[:count]
    base = starts[order]
    def coordinates(s):  # (log(R R₀ᵀ), p − p₀) about the first, their mean
        q0, p0 = s[0, :4], s[0, 4:]
        c = np.concatenate([log_quat(quat_multiply(s[:, :4], quat_conjugate(q0))), s[:, 4:] - p0], axis=1)
        return c, c.mean(axis=0)

    if spread is None and len(starts) >= 2:
        n = len(starts)
        c, mean = coordinates(starts)
        h = start_bandwidth(n)
        z = rng.normal(0.0, 1.0, (count, n))
        new = mean + np.sqrt(1.0 - h * h) * (c[order] - mean) + h * (z @ (c - mean)) / np.sqrt(n - 1.0)
        q = quat_multiply(exp_quat(new[:, :3]), np.broadcast_to(starts[0, :4], (count, 4)))
        p = starts[0, 4:] + new[:, 3:]
        return (q, p, order) if return_index else (q, p)
    if spread is None and shape is not None and len(np.reshape(shape, (-1, 7))) >= 2:
        shape = np.asarray(shape, dtype=np.float64).reshape(-1, 7)
        c, mean = coordinates(shape)
        m = len(shape)
        z = rng.normal(0.0, 1.0, (count, m))
        d = start_bandwidth(m) * (z @ (c - mean)) / np.sqrt(m - 1.0)  # world-frame moves with the shape's covariance
        q = quat_multiply(exp_quat(d[:, :3]), base[:, :4])
        p = base[:, 4:] + d[:, 3:]
        return (q, p, order) if return_index else (q, p)
    spread = START_SPREAD_FALLBACK if spread is None else float(spread)
    s_r = spread / 0.3 * 0.1 if spread_rot is None else spread_rot
    dq = exp_quat(rng.normal(0.0, 1.0, (count, 3)) * s_r)
    q = quat_multiply(dq, base[:, :4])
    p = base[:, 4:] + rng.normal(0.0, 1.0, (count, 3)) * spread
    return (q, p, order) if return_index else (q, p)


def rollout_conditioned(model, start_quat, start_position, *, goal_quat=None, goal_position=None, via=(),
                        durations=None, goal_tolerance=None, samples: int = 0, seed: int = 0, dt: float | None = None,
                        with_std: bool = False, paths=None, rate: float | None = None, **kwargs) -> RolloutResult:
    """Roll out B starts toward goals and through via-points (docs/method.md §12).

    start_quat (B, 4), start_position (B, 3); goal_quat (B, 4) or (4,), goal_position (B, 3) or (3,), or
    None for no goal; via: a sequence of (T seconds after the start, quat (4,), position (3,)); durations
    (B,) seconds, default the path distribution's conditional median duration given the start (and goal);
    goal_tolerance: (rad, m) one standard deviation, default :data:`~rbgp_cli.dynamics.paths.GOAL_TOLERANCE`
    (the mean then ends within about 1 mm / 2 mrad); paths: the :class:`~rbgp_cli.dynamics.paths.PathDistribution`
    (default the model's); rate: resample the rollout to this rate (Hz) before it is bent, so that each
    trajectory's last written sample is its goal (None: the integration grid).

    The mean is the model's rollout from the start for that duration (the GP's dynamics and its
    start-conditioned path), bent by the pathwise update of the path distribution (Matheron's rule,
    :meth:`~rbgp_cli.dynamics.paths.PathDistribution.update`) so that it passes the start, the via-points
    and the goal: the bend in between is what the demonstrations say a motion through those poses
    looks like. Durations given by the caller are observations too (ln D, ± 0.001): a motion known
    to be slow bends as the demonstrations' slow ones differ (on the 30 handovers, 5 folds, the
    conditioned mean's position RMSE fell from 0.136 to 0.113 m with it); the rollout's own ln D is
    the start-conditioned mean's, the value it assumed. The K samples per start are the mean plus zero-mean typical draws of the conditioned path
    distribution, N(0, Σ̂) (:meth:`~rbgp_cli.dynamics.paths.Conditioned.draw`); the result's band
    (``band_position``, ``band_rotation``) is the next motion's 90 % region, Student-t with the factors
    :meth:`~rbgp_cli.dynamics.paths.PathDistribution.goal_band_scale` (calibrated on left-out
    demonstrations given their start and end; :meth:`~rbgp_cli.dynamics.paths.Conditioned.region`): both
    pinch at every constraint and widen between them as the demonstrations do. A start beyond every
    demonstration's (:meth:`~rbgp_cli.dynamics.variation.Variation.start_beyond` above 1) widens both parts of
    its band by √(ρ / ρ_max) (``band_widening``).
    """
    from rbgp_cli.dynamics.paths import pose_deviation

    paths = getattr(model, "paths", None) if paths is None else paths
    if paths is None:
        raise InputError("this model has no path distribution to condition on a goal (fewer than three "
                         "demonstrations, or a model file from an older rbgp)",
                         hint="retrain it with rbgp train on three demonstrations or more")
    q0 = quat_normalize(np.asarray(start_quat, dtype=np.float64).reshape(-1, 4))
    p0 = np.asarray(start_position, dtype=np.float64).reshape(-1, 3)
    B = len(q0)
    has_goal = goal_quat is not None
    if has_goal:
        gq = quat_normalize(np.broadcast_to(np.asarray(goal_quat, dtype=np.float64), (B, 4)))
        gp = np.broadcast_to(np.asarray(goal_position, dtype=np.float64), (B, 3))
    tol = goal_tolerance
    # the observations shared by every start's durations: start and goal (the via-points' phases depend on D)
    def constraints(b, D):
        obs = [paths.observe([0.0], q0[b:b + 1], p0[b:b + 1], exact=True)]
        if has_goal:
            obs.append(paths.observe([1.0], gq[b:b + 1], gp[b:b + 1], tolerance=tol, exact=tol is None))
        for (tv, qv, pv) in via:
            obs.append(paths.observe([float(tv) / D], np.asarray(qv, float)[None], np.asarray(pv, float)[None],
                                     tolerance=tol, exact=tol is None))
        if asked is not None:  # a duration the caller knows says how the path goes too (slower, wider, ...)
            obs.append(paths.observe_duration(asked[b]))
        return paths.stack(*obs)

    asked = None if durations is None else np.asarray(durations, dtype=np.float64).reshape(B)
    durations = _goal_durations(paths, q0, p0, gq if has_goal else None, gp if has_goal else None, asked, via)
    res = rollout_for(model, q0, p0, durations, dt=dt, with_std=with_std, **kwargs)
    res.ends = None  # the whole rollout is bent; where the bent one leaves the data is checked below
    if rate is not None:
        res = res.resampled(rate)
    T = len(res.t)
    # each trajectory's phase on its own integration grid: its last sample (round(D/dt) steps) is phase 1
    n_b = np.asarray(res.lengths) if res.lengths is not None else np.full(B, T)
    durations = np.maximum(res.t[n_b - 1], 1e-9)
    phase = np.clip(res.t[None, :] / durations[:, None], 0.0, 1.0)  # (B, T)
    ref_q, ref_p = paths.pose_at(np.zeros((B, paths.S, 6)), phase)  # the mean path at each sample's phase
    dev_t = pose_deviation(ref_q, ref_p, res.quat, res.position)  # (B, T, 6)
    grid = np.stack([paths.deviation_of(res.t[: res.length(b)], res.quat[b, : res.length(b)],
                                        res.position[b, : res.length(b)], duration=durations[b]) for b in range(B)])
    bent = np.empty_like(grid)
    covs = []
    strength = np.ones(B)  # λ per start (PathDistribution.goal_strength)
    for b in range(B):  # per start: its own constraint values (and via phases); small solves
        A, y, r2 = constraints(b, durations[b])
        # the rollout from the start is the model's answer given the start alone: its ln D is the start-
        # conditioned mean, so that a known duration's innovation bends it as the distribution says
        ell0 = np.log(paths.condition(*paths.observe([0.0], q0[b:b + 1], p0[b:b + 1], exact=True)).duration)
        # the mean: a goal or via-point off the directions the demonstrations span takes more of the smooth
        # shrinkage (PathDistribution.goal_strength; λ = 1, the fitted distribution, for poses like theirs);
        # the samples and the band stay the fitted distribution's, whose factors were calibrated with it
        prior = None
        if has_goal or via:
            m_b, Sigma_b, strength[b] = paths.goal_prior(A, y, r2)
            prior = (m_b, Sigma_b)
        bent[b] = paths.update(grid[b:b + 1], A, y[None], r2, log_duration=ell0, prior=prior)[0]
        if samples:
            covs.append(paths.condition(A, y, r2))
    from rbgp_cli.dynamics.paths import _interpolation
    W = _interpolation(paths.s, phase.reshape(-1)).reshape(B, T, paths.S)
    new = dev_t + np.einsum("bts,bsj->btj", W, bent - grid)
    res.quat, res.position = _from_deviation(paths, ref_q, ref_p, new)
    _recheck_envelope(model, res, durations, kwargs.get("off_data", "keep"))
    res.goal_distance = paths.goal_distance(q0, p0, gq, gp) if has_goal else None
    res.goal_strength = strength
    res.via_distance = np.stack([paths.pose_distance(q0, p0, np.clip(float(tv) / durations, 0.0, 1.0), qv, pv)
                                 for tv, qv, pv in via], axis=1) if via else None  # (B, V)
    if has_goal:
        res.goal_quat, res.goal_position = np.array(gq), np.array(gp)
    res.via = tuple((float(tv), np.asarray(qv, float), np.asarray(pv, float)) for tv, qv, pv in via)
    if samples:
        res.sample_quat, res.sample_position = _conditioned_samples(paths, covs, new, W, ref_q, ref_p, int(samples), seed)
        scale = paths.goal_band_scale()
        bands = [covs[b].region(phase[b], scale=scale) for b in range(B)]
        # a start beyond every demonstration's widens both parts by √(ρ / ρ_max) on top of the goal bands' factors
        # (Variation.start_beyond; the upper quartile's widening was calibrated on the start-only bands, not these)
        var = getattr(model, "variation", None)
        beyond = None if var is None else var.start_beyond(q0, p0)
        w = np.ones(B) if beyond is None else np.sqrt(np.maximum(1.0, beyond))
        res.band_widening = np.repeat(w[:, None], 2, axis=1)
        res.band_position = np.stack([h for h, _ in bands]) * w[:, None, None]
        res.band_rotation = np.stack([m for _, m in bands]) * (w**2)[:, None, None, None]
    return res


def _goal_durations(paths, q0, p0, gq, gp, asked, via) -> np.ndarray:
    """:func:`rollout_conditioned`'s durations (B,) s: ``asked``, else the conditional median given the
    start and goal (``gq`` None: the start alone), kept within the durations a motion under way considers
    (:data:`~rbgp_cli.dynamics.anticipation.GRID_RANGE` times the demonstrations' shortest and longest), with a warning
    where that moved one: ln D is linear in the goal, and a goal far off the demonstrations' ends extrapolates it
    (a 50 m goal of a handover model: 0.03 s); every via-point must lie inside them.

    A goal further than :data:`~rbgp_cli.dynamics.paths.FAR_GOAL` spreads from where the demonstrations end (given
    the start; e its deviation from there, d its distance) is not extrapolated: the duration is the one given the
    goal moved back to that distance, e → e · FAR_GOAL / d, times (L + |p_goal − p_back|) / L, L the length of the
    mean path's positions: the demonstrations' pace over the longer way. (A hand raise model given a goal 1 m above
    its reach suggested 0.74 s, the demonstrations' shortest 1.6 s.)"""
    from rbgp_cli.dynamics.anticipation import GRID_RANGE
    from rbgp_cli.dynamics.paths import FAR_GOAL
    from rbgp_cli.errors import warn

    durations = asked
    if durations is None:
        durations = np.empty(len(q0))
        for b in range(len(q0)):
            ob = [paths.observe([0.0], q0[b:b + 1], p0[b:b + 1], exact=True)]
            stretch = 1.0
            if gq is not None:
                A1, y1, r1 = paths.observe([1.0], gq[b:b + 1], gp[b:b + 1], exact=True)
                start = paths.condition(*ob[0])
                pred = A1 @ start.mean
                e = y1 - pred
                d = float(np.sqrt(e @ np.linalg.solve(A1 @ start.cov @ A1.T, e)))
                if d > FAR_GOAL:  # the goal moved back to FAR_GOAL spreads, and the way to the real one walked at its pace
                    y_b = pred + e * (FAR_GOAL / d)
                    p_b = gp[b] + (y_b - y1)[3:] * paths.scale[3:]
                    way = float(np.sum(np.linalg.norm(np.diff(paths.position, axis=0), axis=1)))
                    stretch = 1.0 + float(np.linalg.norm(gp[b] - p_b)) / max(way, 1e-9)
                    y1 = y_b
                ob.append((A1, y1, r1))
            durations[b] = paths.condition(*paths.stack(*ob)).duration * stretch
        d = np.exp(np.asarray(paths.log_durations, dtype=np.float64))
        lo, hi = GRID_RANGE[0] * d.min(), GRID_RANGE[1] * d.max()
        out = np.flatnonzero((durations < lo) | (durations > hi))
        if len(out):
            which = "the motion" if len(durations) == 1 else f"{len(out)} of {len(durations)} motions"
            warn(f"the duration the demonstrations suggest for {which} ({', '.join(f'{x:.3g}' for x in durations[out][:4])}"
                 f"{', ...' if len(out) > 4 else ''} s) lies beyond theirs ({d.min():.3g}–{d.max():.3g} s) by more than "
                 f"they vary: it is kept within {lo:.3g}–{hi:.3g} s", hint="give the duration to set it")
            durations = np.clip(durations, lo, hi)
    for (tv, _, _) in via:
        if not np.all((float(tv) > 0) & (float(tv) < durations)):
            raise InputError(f"a via-point at {float(tv):g} s lies outside the motion (0 to {durations.min():.3g} s)",
                             hint="give T in seconds after the start, within the motion's duration", param="via")
    return np.asarray(durations, dtype=np.float64)


def _conditioned_samples(paths, covs, new, W, ref_q, ref_p, K: int, seed: int):
    """K samples per start (quat (B, K, T, 4), position (B, K, T, 3)): the bent mean deviations ``new``
    (B, T, 6) plus zero-mean draws of each start's conditioned distribution ``covs[b]``, interpolated
    to the samples by ``W`` (B, T, S), around the mean path's poses (ref_q, ref_p) (B, T, ·)."""
    B, T = new.shape[:2]
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 38]))
    sq = np.empty((B, K, T, 4))
    sp = np.empty((B, K, T, 3))
    for b in range(B):
        eta, _ = covs[b].draw(K, rng, widen=False, student=False)  # typical motions (their band: region)
        eta = eta - covs[b].deviation[None]  # zero-mean draws of the conditioned process
        d = new[b][None] + np.einsum("ts,ksj->ktj", W[b], eta)
        sq[b], sp[b] = _from_deviation(paths, ref_q[b][None], ref_p[b][None], d)
    return sq, sp


def _recheck_envelope(model, res: RolloutResult, durations, off_data: str) -> None:
    """``outside`` and ``left`` of the bent mean trajectories (their poses changed), each against the
    envelope at its own phase t/D (a model without the phase input: the box of all the demonstrations'
    positions); with ``off_data="stop"`` each ends at its first sample outside."""
    from rbgp_cli.dynamics.envelope import exits_report

    envelope = model.data_envelope()
    if model.time_input != "phase":
        envelope = envelope.overall()
    B, T = res.quat.shape[:2]
    phase = res.t[None, :] / np.asarray(durations, dtype=np.float64).reshape(B, 1)
    outside = envelope.outside(res.position, phase)
    n = np.asarray(res.lengths) if res.lengths is not None else np.full(B, T)
    outside &= np.arange(T)[None, :] < n[:, None]
    res.outside = outside
    res.left = exits_report(outside, res.t, res.position, model.data_envelope())
    if off_data == "stop":
        res.ends = np.maximum(np.where(outside.any(axis=1), outside.argmax(axis=1), n - 1), 1)


def _from_deviation(paths, ref_q, ref_p, dev):
    """Poses (quat (..., T, 4), position (..., T, 3)) of deviations ``dev`` (..., T, 6) from the mean
    path's poses (ref_q, ref_p) at the same samples: R = exp(δ_rot) R̄, p = p̄ + δ_pos."""
    from rbgp_cli.geometry.so3 import exp_quat, quat_multiply

    q = quat_multiply(exp_quat(dev[..., :3]), np.broadcast_to(ref_q, dev.shape[:-1] + (4,)))
    return quat_make_continuous(q), ref_p + dev[..., 3:]
