"""Rollouts: new motions from start poses by single-step mean prediction (MATH.md §8, paper sec. 4.3).

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

__all__ = ["RolloutResult", "rollout", "rollout_one_at_a_time", "starts_near"]


@dataclass
class RolloutResult:
    """Rolled-out trajectories.

    t : (S+1,) seconds from the start
    quat : (B, S+1, 4) x, y, z, w (sign-continuous along time); position : (B, S+1, 3) metres
    std : (B, S+1, L) latent predictive std of each output at each state, or None
    output_names : names of the L outputs (e.g. wx ... vz)
    sample_quat : (B, K, S+1, 4) and sample_position : (B, K, S+1, 3) Monte Carlo rollouts, or None
    outside : (B, S+1) True where a mean trajectory's sample lies outside the demonstrations' envelope
    left : :func:`~rbgp_cli.dynamics.envelope.exits_report` of the mean trajectories, or None
    ends : (B,) index of each mean trajectory's last sample (``off_data="stop"``), or None (all S)
    """

    t: np.ndarray
    quat: np.ndarray
    position: np.ndarray
    std: np.ndarray | None
    output_names: tuple
    sample_quat: np.ndarray | None = None
    sample_position: np.ndarray | None = None
    outside: np.ndarray | None = None
    left: dict | None = None
    ends: np.ndarray | None = None

    @property
    def count(self) -> int:
        return self.quat.shape[0]

    def length(self, b: int) -> int:
        """Samples of mean trajectory b (all S + 1 unless it was stopped where it left the data)."""
        return len(self.t) if self.ends is None else int(self.ends[b]) + 1

    def trajectories(self, include_samples: bool = False) -> list[Trajectory]:
        """The mean rollouts (names ``0``, ``1``, …; cut at ``ends``) and, optionally, the samples (``0.s0``, …)."""
        out = [Trajectory(self.t[: self.length(b)], self.quat[b, : self.length(b)], self.position[b, : self.length(b)],
                          name=str(b)) for b in range(self.count)]
        if include_samples and self.sample_quat is not None:
            for b in range(self.count):
                for k in range(self.sample_quat.shape[1]):
                    out.append(Trajectory(self.t, self.sample_quat[b, k], self.sample_position[b, k], name=f"{b}.s{k}"))
        return out


def _check_finite(state, step):
    if not np.all(np.isfinite(state)):
        raise RbgpRuntimeError(f"the rollout diverged (non-finite state) at step {step}", hint="check the model with rbgp info")


def rollout(model, start_quat, start_position, steps: int, dt: float | None = None, *, samples: int = 0,
            seed: int = 0, with_std: bool = True, progress=None, durations=None, off_data: str = "keep") -> RolloutResult:
    """Roll out ``model`` (a :class:`~rbgp_cli.dynamics.model.MotionModel`) from B start poses.

    Parameters
    ----------
    start_quat : (B, 4) x, y, z, w;  start_position : (B, 3) metres
    steps : number of integration steps S (the result has S + 1 samples)
    dt : step in seconds (default: the model's, i.e. the demonstrations' median time step)
    samples : K Monte Carlo rollouts per start (ξ drawn from the latent predictive Gaussian each step)
    seed : seeds the Monte Carlo draws
    with_std : record the predictive std along the mean trajectories (costs one triangular solve per
        step; switch off for speed)
    durations : (B,) seconds each trajectory is meant to last (default steps·dt for all). Only a model
        with a phase input uses it: trajectory b advances its phase by dt/durations[b] per step, so a
        batch of different lengths can share the steps (each is then cut to its own duration).
    progress : optional :class:`rbgp_cli.progress.Progress`: a task "rollout" over the steps
    off_data : ``keep``, ``stop`` or ``prior``: what a trajectory does outside the demonstrations'
        envelope (module docstring); every mode fills ``outside`` and ``left``
    """
    from rbgp_cli.gp.exact import blas_threads

    # Always single-threaded: per step the matrices are only B × n, and a 2-thread OpenBLAS pool
    # made 100 × 626 steps at n = 1752 take 11.0 s instead of 3.8 s on a loaded machine (measured).
    from rbgp_cli.progress import as_progress

    with blas_threads(0), as_progress(progress).task("rollout", total=int(steps), unit="steps") as task:
        return _rollout(model, start_quat, start_position, steps, dt, samples, seed, with_std, task, durations, off_data)


def _rollout(model, start_quat, start_position, steps, dt, samples, seed, with_std, task, durations, off_data="keep"):
    from rbgp_cli.dynamics.envelope import OFF_DATA, exits_report

    if off_data not in OFF_DATA:
        raise InputError(f"--off-data must be one of {', '.join(OFF_DATA)}, got {off_data!r}")
    if off_data == "prior" and not model.mean:
        raise InputError("--off-data prior falls back to the model's prior mean, and this model has none",
                         hint="use --off-data keep or stop, or train with --prior path (or goal)")
    envelope = model.data_envelope()
    if model.time_input != "phase":  # its GP does not see the phase: where the demonstrations went at any time
        envelope = envelope.overall()
    rep, gp = model.representation, model.gp
    dt = float(model.dt if dt is None else dt)
    if not np.isfinite(dt) or dt <= 0:
        raise InputError(f"--dt must be a positive number of seconds, got {dt}")
    steps = int(steps)
    if steps < 1:
        raise InputError(f"--steps must be at least 1, got {steps}")
    q0 = quat_normalize(np.asarray(start_quat, dtype=np.float64).reshape(-1, 4))
    p0 = np.asarray(start_position, dtype=np.float64).reshape(-1, 3)
    B, K = len(q0), int(samples)
    task.update(status=f"{B} trajectories" + (f", {K} Monte Carlo samples each" if K else ""))
    duration = np.full((B, 1), steps * dt) if durations is None else np.asarray(durations, dtype=np.float64).reshape(B, 1)
    if not np.all(np.isfinite(duration) & (duration > 0)):
        raise InputError("rollout durations must be positive numbers of seconds")
    state = model.initial_state(q0, p0)
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

    def fall_back(X, mu, k, dur):
        """--off-data prior: the prior mean's velocity where X (at step k) is outside the envelope."""
        off = envelope.outside(rep.pose_from_state(X[:, :pd])[1], phase_of(k * dt, dur[:, 0]))
        if np.any(off):
            mu = mu.copy()
            mu[off] = model.prior_mean(X[off])
        return mu

    for k in range(steps + 1):
        last = k == steps
        if with_std:
            mu, sd = model.predict_output(state, return_std=True, manage_threads=False)
            std[k] = sd / duration if model.time_input == "phase" else sd  # per second
        elif not last:
            mu = model.predict_output(state, manage_threads=False)
        if not last:
            if off_data == "prior":
                mu = fall_back(state, mu, k, duration)
            state = model.advance(state, mu, dt, duration)
            _check_finite(state, k + 1)
            states[k + 1] = state
            if K > 0:
                smu, ssd = model.predict_output(sstate, return_std=True, manage_threads=False)
                if off_data == "prior":
                    smu = fall_back(sstate, smu, k, np.repeat(duration, K, axis=0))
                sstate = model.advance(sstate, smu + ssd * rng.standard_normal(smu.shape), dt, np.repeat(duration, K, axis=0))
                _check_finite(sstate, k + 1)
                sstates[k + 1] = sstate
        if not last:
            task.advance()
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


def rollout_one_at_a_time(model, start_quat, start_position, steps: int, dt: float | None = None) -> RolloutResult:
    """The unbatched reference: each start rolled out alone (for benchmarks and tests)."""
    parts = [rollout(model, q[None], p[None], steps, dt, with_std=False) for q, p in zip(start_quat, start_position)]
    return RolloutResult(parts[0].t, np.concatenate([r.quat for r in parts]), np.concatenate([r.position for r in parts]),
                         None, parts[0].output_names)


def starts_near(starts: np.ndarray, count: int, spread: float, seed: int = 0, spread_rot: float | None = None):
    """``count`` start poses near the given ones (paper sec. 4.3: 100 unseen starts near the demos').

    Each new start takes a demonstration start (cycling through them in a seeded random order) and
    perturbs it: translation by N(0, spread²) per axis (metres), rotation by exp of a N(0, s_r²)
    rotation vector with s_r = spread_rot (radians; default spread / 0.3 m × 0.1 rad, i.e. about
    0.1 rad per 0.3 m of translation spread, matching the scale of human start-pose variation).

    starts : (D, 7) = (qx, qy, qz, qw, x, y, z). Returns (quat (count, 4), position (count, 3)).
    """
    from rbgp_cli.geometry.so3 import exp_quat, quat_multiply

    starts = np.asarray(starts, dtype=np.float64).reshape(-1, 7)
    if len(starts) == 0:
        raise InputError("no start poses to draw from")
    if count < 1:
        raise InputError(f"--count must be at least 1, got {count}")
    if spread < 0:
        raise InputError(f"--start-spread must be >= 0, got {spread}")
    rng = np.random.default_rng(seed)
    s_r = spread / 0.3 * 0.1 if spread_rot is None else spread_rot
    order = np.concatenate([rng.permutation(len(starts)) for _ in range(-(-count // len(starts)))])[:count]
    base = starts[order]
    dq = exp_quat(rng.normal(0.0, 1.0, (count, 3)) * s_r)
    q = quat_multiply(dq, base[:, :4])
    p = base[:, 4:] + rng.normal(0.0, 1.0, (count, 3)) * spread
    return q, p
