"""``rbgp crossval --given goal``: each held-out demonstration's start, final pose and duration are given,
and every row generates a motion between them (docs/method.md §12).

Rows:

- **rbgp** (every model configuration): :func:`~rbgp_cli.dynamics.rollout.rollout_conditioned` from the
  held-out start to its final pose for its duration, the samples drawn from the conditioned path
  distribution; its row **without the GP** rolls out the same fit with the GP's residual switched off
  (the path distribution and the prior's pull alone).
- **nearest** (:func:`nearest_blended`): the training demonstration nearest by start *and* goal, on the
  held-out motion's normalised time, with its start offset blended out and its end offset blended in
  by a minimum-jerk weight, so that it starts at the start and ends at the goal.
- **promp** (:func:`promp_goal_rollouts`): the ProMP peer of :mod:`rbgp_cli.evaluation.peers`
  conditioned on the start at s = 0 and on the goal at s = 1 (the same via-point covariance at both
  ends); its samples are draws of that doubly conditioned distribution.
- **dmp** (:func:`dmp_goal_rollouts`): the package's Cartesian DMP of the demonstration nearest by
  start and goal, run from the new start to the new goal for the held-out duration.

Every generated motion is then scored as in :mod:`rbgp_cli.evaluation.crossval` (trajectory errors on
normalised time, coverage of the samples' 90 % regions, the sample score), plus **end errors**: the
distance (m) and angle (rad) between each mean motion's last pose and the goal it was given.
"""

from __future__ import annotations

import time

import numpy as np

from rbgp_cli.dynamics.trajectory import Trajectory
from rbgp_cli.geometry.so3 import exp_quat, log_quat, quat_conjugate, quat_make_continuous, quat_multiply, quat_normalize

__all__ = ["GOAL", "NEAREST", "nearest_by_start_and_goal", "nearest_blended", "promp_goal_rollouts",
           "promp_goal_samples", "dmp_goal_rollouts", "model_goal_rollouts", "generate_given_goal", "end_errors"]

#: The value of crossval's ``given`` that selects these rows.
GOAL = "goal"
#: The row of the nearest demonstration (by start and goal) with its end offsets blended in.
NEAREST = "nearest"
#: Rotation weight of the start-and-goal distance (as the replay peer's start distance).
NEAREST_RHO = 0.7


def _pose_d2(q, p, quat, pos, rho: float) -> np.ndarray:
    """ρ·d_ch² + (1 − ρ)·‖Δp‖² between one pose (q (4,), p (3,)) and poses (n, 4), (n, 3) (chordal
    rotation distance d_ch = 2·sqrt(1 − ⟨q1, q2⟩²), docs/method.md §5)."""
    c = np.clip(np.abs(np.asarray(quat) @ np.asarray(q)), 0.0, 1.0)
    return rho * 4.0 * (1.0 - c * c) + (1.0 - rho) * np.sum((np.asarray(pos) - p) ** 2, axis=1)


def nearest_by_start_and_goal(train: list[Trajectory], q0, p0, qg, pg, rho: float = NEAREST_RHO) -> int:
    """Index of the training demonstration whose start and final poses are together nearest to a
    start (q0, p0) and goal (qg, pg): the sum of the two weighted squared distances (:func:`_pose_d2`)."""
    d2 = (_pose_d2(q0, p0, np.array([t.quat[0] for t in train]), np.array([t.position[0] for t in train]), rho)
          + _pose_d2(qg, pg, np.array([t.quat[-1] for t in train]), np.array([t.position[-1] for t in train]), rho))
    return int(np.argmin(d2))


def _min_jerk(s: np.ndarray) -> np.ndarray:
    """w(s) = 10 s³ − 15 s⁴ + 6 s⁵: 0 at s = 0 and 1 at s = 1 with zero velocity and acceleration at both."""
    return s ** 3 * (10.0 - 15.0 * s + 6.0 * s * s)


def nearest_blended(train: list[Trajectory], q0, p0, qg, pg, duration: float) -> Trajectory:
    """The nearest demonstration by start and goal, bent to the given start and goal.

    With s = (t − t_0)/D_d its phase and w(s) the minimum-jerk weight, its start offset
    a = (log(R_0 R_d(0)ᵀ), p_0 − p_d(0)) fades out and its end offset b = (log(R_g R_d(1)ᵀ), p_g − p_d(1))
    fades in (world-frame tangent, rotation first):
    R(s) = exp((1 − w) a_rot + w b_rot) R_d(s), p(s) = p_d(s) + (1 − w) a_pos + w b_pos, on t = s·duration.
    """
    src = train[nearest_by_start_and_goal(train, q0, p0, qg, pg)]
    q = quat_make_continuous(quat_normalize(src.quat))
    s = (src.t - src.t[0]) / max(src.duration, 1e-12)
    w = _min_jerk(s)[:, None]
    a_rot = log_quat(quat_multiply(quat_normalize(q0), quat_conjugate(q[0])))
    b_rot = log_quat(quat_multiply(quat_normalize(qg), quat_conjugate(q[-1])))
    rot = (1.0 - w) * a_rot[None] + w * b_rot[None]
    pos = src.position + (1.0 - w) * (np.asarray(p0) - src.position[0])[None] + w * (np.asarray(pg) - src.position[-1])[None]
    quat = quat_make_continuous(quat_multiply(exp_quat(rot), q))
    return Trajectory(s * float(duration), quat, pos, name=f"{src.name} to the goal")


# --------------------------------------------------------------------------------------------- ProMP
def _goal_conditioned(peer, q0, p0, qg, pg):
    """The ProMP peer conditioned on the start at s = 0 and the goal at s = 1 (the goal's rotation vector
    taken on the branch nearest the start-conditioned mean's end, so that a path through θ = π does not
    demand a turn the other way round)."""
    from rbgp_cli.evaluation.peers import START_STD

    sr, sp = START_STD
    cov = np.diag([sr ** 2] * 3 + [sp ** 2] * 3)
    first = peer.conditioned(q0, p0)
    end = first.mean_trajectory(np.array([0.0, 1.0]))[-1]
    yg = peer.start_coordinates(qg, pg)[0]
    r = yg[:3]
    theta = float(np.linalg.norm(r))
    if theta > 1e-9:  # the equivalent rotation vectors r + 2πk r/|r|: the one nearest the mean's end
        axis = r / theta
        options = [r + 2.0 * np.pi * k * axis for k in (-1, 0, 1)]
        yg[:3] = min(options, key=lambda v: float(np.sum((v - end[:3]) ** 2)))
    return first.condition_position(yg, y_cov=cov, t=1.0, t_max=1.0)


def promp_goal_rollouts(train, quat0, pos0, goal_quat, goal_pos, durations, peer=None) -> list[Trajectory]:
    """The goal ProMP row: per start, the mean of the ProMP conditioned on start and goal (``peer``: the
    fitted :class:`~rbgp_cli.evaluation.peers.ProMPPeer`, default fitted on ``train`` here)."""
    from rbgp_cli.evaluation.peers import fit_promp

    peer = fit_promp(train) if peer is None else peer
    s = np.linspace(0.0, 1.0, peer.steps)
    return [peer._trajectory(_goal_conditioned(peer, q0, p0, qg, pg).mean_trajectory(s), d, "promp to the goal")
            for q0, p0, qg, pg, d in zip(quat0, pos0, goal_quat, goal_pos, durations)]


def promp_goal_samples(train, quat0, pos0, goal_quat, goal_pos, durations, k: int, seed: int = 0,
                       peer=None) -> list[list[Trajectory]]:
    """``k`` seeded draws per start of the ProMP conditioned on start and goal (start i: seed + i)."""
    from rbgp_cli.evaluation.peers import fit_promp

    peer = fit_promp(train) if peer is None else peer
    s = np.linspace(0.0, 1.0, peer.steps)
    out = []
    for i, (q0, p0, qg, pg, d) in enumerate(zip(quat0, pos0, goal_quat, goal_pos, durations)):
        ys = _goal_conditioned(peer, q0, p0, qg, pg).sample_trajectories(s, int(k), np.random.RandomState(int(seed) + i))
        out.append([peer._trajectory(y, d, f"promp{i}.s{j}") for j, y in enumerate(ys)])
    return out


# --------------------------------------------------------------------------------------------- DMP
def dmp_goal_rollouts(train, quat0, pos0, goal_quat, goal_pos, durations) -> list[Trajectory]:
    """The goal DMP row: per start, the Cartesian DMP of the demonstration nearest by start and goal,
    configured with the new start and the new goal, run for the given duration."""
    from movement_primitives.dmp import CartesianDMP

    from rbgp_cli.evaluation.peers import DMP_BASIS, _wxyz, _xyzw

    out = []
    for q0, p0, qg, pg, duration in zip(quat0, pos0, goal_quat, goal_pos, durations):
        src = train[nearest_by_start_and_goal(train, q0, p0, qg, pg)]
        t = src.t - src.t[0]
        q = quat_make_continuous(quat_normalize(src.quat))
        dt = float(np.mean(np.diff(t)))
        dmp = CartesianDMP(execution_time=float(t[-1]), dt=dt, n_weights_per_dim=DMP_BASIS)
        dmp.imitate(t, np.concatenate([src.position, _wxyz(q)], axis=1))
        sq = quat_normalize(np.asarray(q0, float))
        sq = sq if np.dot(sq, q[0]) >= 0 else -sq  # the demonstration's hemisphere at each end
        gq = quat_normalize(np.asarray(qg, float))
        gq = gq if np.dot(gq, q[-1]) >= 0 else -gq
        dmp.configure(start_y=np.concatenate([p0, _wxyz(sq)]), goal_y=np.concatenate([pg, _wxyz(gq)]))
        dmp.execution_time_ = float(duration)
        dmp.dt_ = dt * float(duration) / float(t[-1])
        T, Y = dmp.open_loop()
        out.append(Trajectory(T, _xyzw(Y[:, 3:]), Y[:, :3], name=f"dmp of {src.name} to the goal"))
    return out


# --------------------------------------------------------------------------------------------- rbgp
def model_goal_rollouts(model, test: list[Trajectory], samples: int, seed: int):
    """A model's conditioned rollout from each held-out start to its final pose for its duration
    (:func:`~rbgp_cli.dynamics.rollout.rollout_conditioned`), named after it, and per start its
    ``samples`` draws (None without samples)."""
    from rbgp_cli.dynamics.rollout import rollout_conditioned

    q0 = np.array([tr.quat[0] for tr in test])
    p0 = np.array([tr.position[0] for tr in test])
    qg = np.array([tr.quat[-1] for tr in test])
    pg = np.array([tr.position[-1] for tr in test])
    res = rollout_conditioned(model, q0, p0, goal_quat=qg, goal_position=pg, durations=[tr.duration for tr in test],
                              samples=samples, seed=seed)
    trajs = res.trajectories(include_samples=samples > 0)
    gen = [g.with_(name=f"from {tr.name} to its goal") for g, tr in zip(trajs[: len(test)], test)]
    from rbgp_cli.evaluation.crossval import with_bands

    gen = with_bands(gen, res)  # the coverage is measured with the band rbgp gives
    drawn = None
    if samples > 0:
        rest = trajs[len(test):]
        drawn = [rest[b * samples:(b + 1) * samples] for b in range(len(test))]
    return gen, drawn


def generate_given_goal(config, train: list[Trajectory], test: list[Trajectory], samples: int, seed: int):
    """:func:`rbgp_cli.evaluation.crossval._generate` for ``given="goal"``: generated trajectories (one
    per held-out demonstration), training seconds, the model or None, and the samples per start (or None)."""
    from rbgp_cli.evaluation.peers import DMP, PROMP

    q0 = np.array([tr.quat[0] for tr in test])
    p0 = np.array([tr.position[0] for tr in test])
    qg = np.array([tr.quat[-1] for tr in test])
    pg = np.array([tr.position[-1] for tr in test])
    dur = [tr.duration for tr in test]
    t0 = time.perf_counter()
    if config.representation == NEAREST:
        return [nearest_blended(train, a, b, c, d, e) for a, b, c, d, e in zip(q0, p0, qg, pg, dur)], 0.0, None, None
    if config.representation == PROMP:
        from rbgp_cli.evaluation.peers import fit_promp

        peer = fit_promp(train)
        gen = promp_goal_rollouts(train, q0, p0, qg, pg, dur, peer=peer)
        drawn = promp_goal_samples(train, q0, p0, qg, pg, dur, samples, seed=seed, peer=peer) if samples > 0 else None
        return gen, time.perf_counter() - t0, None, drawn
    if config.representation == DMP:
        return dmp_goal_rollouts(train, q0, p0, qg, pg, dur), time.perf_counter() - t0, None, None
    from rbgp_cli.dynamics.model import train_model

    model = train_model(train, representation=config.representation, kernel=config.kernel, **config.train)
    train_s = time.perf_counter() - t0
    if getattr(model, "paths", None) is None:
        from rbgp_cli.errors import InputError

        raise InputError(f"given goal needs a path distribution, and {len(train)} training demonstrations give none",
                         hint="use fewer folds, so that every fold trains on three demonstrations or more",
                         param=("given", "folds"))
    gen, drawn = model_goal_rollouts(model, test, samples, seed)
    return gen, train_s, model, drawn


def end_errors(generated: list[Trajectory], test: list[Trajectory]) -> tuple[float, float, int]:
    """Sums of the end errors of generated motions against the goals they were given (the held-out
    demonstrations' last poses): (Σ distance m, Σ angle rad, count)."""
    dp, dr = 0.0, 0.0
    for g, r in zip(generated, test):
        dp += float(np.linalg.norm(g.position[-1] - r.position[-1]))
        dq = quat_multiply(quat_conjugate(quat_normalize(r.quat[-1])), quat_normalize(g.quat[-1]))
        dr += float(2.0 * np.arctan2(np.linalg.norm(dq[:3]), abs(dq[3])))
    return dp, dr, len(generated)
