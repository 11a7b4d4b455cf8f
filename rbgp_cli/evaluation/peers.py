"""The field's own methods as crossval peers: a ProMP and a Cartesian DMP from ``movement-primitives``.

Both come from the optional package ``movement-primitives`` (``pip install "rbgp-cli[peers]"``, which
also brings ``pytransform3d``, its quaternion code); without it :func:`missing` says why and crossval
leaves their rows out with one note. Conventions at the boundary: movement_primitives and pytransform3d
write quaternions w, x, y, z; rbgp is x, y, z, w everywhere, so :func:`_wxyz` / :func:`_xyzw` convert
where an array crosses.

**ProMP** (:class:`ProMPPeer`). The M training demonstrations are resampled to ``steps`` equally spaced
steps of normalised time s ∈ [0, 1] (slerp / linear, :func:`~rbgp_cli.evaluation.resample.resample_all`).
The reference rotation R̄_0 is the chordal mean of their start rotations; each demonstration becomes a
6-dimensional curve

    y(s) = (log(R̄_0ᵀ R(s)), p(s))        (rad, m)

with the rotation vectors made continuous along s (the logarithm of the sign-continuous quaternion
conj(q̄_0) ⊗ q(s), angle in [0, 2π), so a curve that passes θ = π does not jump). The package's ProMP
(``n_basis`` normalised Gaussian basis functions per dimension, weights learnt by its ``imitate``)
models the distribution of these curves. From a new start (R', p') it is conditioned on the via-point
y(0) = (log(R̄_0ᵀ R'), p') with covariance diag(σ_r², σ_r², σ_r², σ_p², σ_p², σ_p²)
(:data:`START_STD`: 0.01 rad and 0.01 m, so the mean starts near, not exactly at, the new start), and the conditioned mean (or K seeded draws from the conditioned distribution)
is mapped back by R(s) = R̄_0 exp(y_r(s)), p(s) = y_p(s), on the time grid t = s·duration.

**DMP** (:func:`dmp_rollouts`). The training demonstration with the nearest start (the replay peer's
choice, :func:`~rbgp_cli.evaluation.crossval.nearest_index`) is imitated by the package's
``CartesianDMP`` (position + unit quaternion, ``n_basis`` weights per dimension, on the demonstration's
own time stamps from 0), then configured with the new start as ``start_y``, that demonstration's last
pose as ``goal_y`` and the held-out duration as execution time, and run open loop at the
demonstration's mean sample interval scaled to that duration.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass

import numpy as np

from rbgp_cli.dynamics.trajectory import Trajectory
from rbgp_cli.evaluation.resample import mean_rotation, resample_all
from rbgp_cli.geometry.so3 import (_log_quat_unit, exp_quat, log_quat, quat_conjugate, quat_make_continuous,
                                   quat_multiply, quat_normalize)

__all__ = ["PROMP", "DMP", "PEERS", "PROMP_BASIS", "DMP_BASIS", "PROMP_STEPS", "START_STD", "missing",
           "ProMPPeer", "fit_promp", "promp_rollouts", "promp_samples", "dmp_rollouts"]

#: Row names of the two peers.
PROMP = "promp"
DMP = "dmp"
PEERS = (PROMP, DMP)
#: Basis functions per dimension (issue 20: 25 for the ProMP; the DMP uses the same number).
PROMP_BASIS = 25
DMP_BASIS = 25
#: Steps of normalised time the training demonstrations are resampled to for the ProMP (its learning
#: holds an (6·steps)² matrix per demonstration) and of its rollouts.
PROMP_STEPS = 100
#: Standard deviation of the start via-point: (rotation rad, position m). Chosen by crossval on the 30
#: handovers (5 folds; position / rotation RMSE, ratio): 0.1 → 0.159 m / 0.305 rad, 15.8; 0.01 → 0.160 /
#: 0.308, 6.7; 0.001 → 0.26 / 0.39 (fold 1); 1e-5 → 0.666 / 0.649, 2.9. The package's learnt weight
#: covariance is nearly singular outside the span of the training demonstrations (its noise variance
#: ~1e-8), so pinning the start much tighter drives the weights far along those directions, while a
#: looser one leaves every rollout on the mean path.
START_STD = (1e-2, 1e-2)


def missing() -> str | None:
    """None when ``movement_primitives`` (and ``pytransform3d``, which its Cartesian DMP needs) can be
    imported, otherwise the reason, as one line for the user."""
    try:
        importlib.import_module("movement_primitives.promp")
        importlib.import_module("movement_primitives.dmp")
    except ImportError as exc:
        return (f"the ProMP and DMP peer rows: movement-primitives is not installed ({exc}); "
                'pip install "rbgp-cli[peers]"')
    return None


def _wxyz(q: np.ndarray) -> np.ndarray:
    """x, y, z, w -> w, x, y, z (last axis)."""
    return np.concatenate([q[..., 3:], q[..., :3]], axis=-1)


def _xyzw(q: np.ndarray) -> np.ndarray:
    """w, x, y, z -> x, y, z, w (last axis)."""
    return np.concatenate([q[..., 1:], q[..., :1]], axis=-1)


def _continuous_log(rel: np.ndarray) -> np.ndarray:
    """Rotation vectors of quaternions ``rel`` (..., N, 4) that are continuous along N: the logarithm of
    the sign-continuous sequence (first sample w >= 0), angle 2·atan2(‖v‖, w) ∈ [0, 2π)."""
    q = quat_normalize(rel)
    q = q * np.where(q[..., :1, 3:] < 0, -1.0, 1.0)
    return _log_quat_unit(quat_make_continuous(q))


# --------------------------------------------------------------------------------------------- ProMP
@dataclass
class ProMPPeer:
    """A ProMP over (log(R̄_0ᵀ R), p) learnt from demonstrations (see the module docstring).

    Attributes: ``promp`` (the package's ``ProMP``, 6 dimensions), ``ref`` (R̄_0, quaternion x, y, z, w),
    ``steps`` (steps of normalised time of the rollouts)."""

    promp: object
    ref: np.ndarray
    steps: int = PROMP_STEPS

    def start_coordinates(self, quat0, pos0) -> np.ndarray:
        """The via-point y(0) = (log(R̄_0ᵀ R'), p') of start poses, shape (S, 6)."""
        q0 = np.atleast_2d(np.asarray(quat0, dtype=np.float64))
        p0 = np.atleast_2d(np.asarray(pos0, dtype=np.float64))
        rel = quat_multiply(np.broadcast_to(quat_conjugate(self.ref), q0.shape), quat_normalize(q0))
        return np.concatenate([log_quat(rel), p0], axis=-1)

    def conditioned(self, quat0, pos0):
        """The package's ProMP conditioned on one start pose as the via-point at s = 0."""
        y0 = self.start_coordinates(quat0, pos0)[0]
        sr, sp = START_STD
        cov = np.diag([sr**2] * 3 + [sp**2] * 3)
        return self.promp.condition_position(y0, y_cov=cov, t=0.0, t_max=1.0)

    def _trajectory(self, y: np.ndarray, duration: float, name: str) -> Trajectory:
        """Curve y (steps, 6) -> Trajectory on t = s·duration."""
        q = quat_multiply(np.broadcast_to(self.ref, (len(y), 4)), exp_quat(y[:, :3]))
        return Trajectory(np.linspace(0.0, float(duration), len(y)), q, y[:, 3:], name=name)

    def mean(self, quat0, pos0, duration: float, name: str = "promp") -> Trajectory:
        """The conditioned mean from one start (quaternion x, y, z, w; m) for ``duration`` seconds."""
        s = np.linspace(0.0, 1.0, self.steps)
        return self._trajectory(self.conditioned(quat0, pos0).mean_trajectory(s), duration, name)

    def samples(self, quat0, pos0, duration: float, k: int, seed: int = 0, name: str = "promp") -> list[Trajectory]:
        """``k`` draws from the conditioned distribution (the package's ``sample_trajectories`` with
        ``numpy.random.RandomState(seed)``: the same seed gives the same draws)."""
        s = np.linspace(0.0, 1.0, self.steps)
        ys = self.conditioned(quat0, pos0).sample_trajectories(s, int(k), np.random.RandomState(int(seed)))
        return [self._trajectory(y, duration, f"{name}.s{i}") for i, y in enumerate(ys)]


def fit_promp(train: list[Trajectory], *, n_basis: int = PROMP_BASIS, steps: int = PROMP_STEPS) -> ProMPPeer:
    """Learn the ProMP peer from training demonstrations (module docstring)."""
    from movement_primitives.promp import ProMP

    q, p = resample_all(train, steps)  # (M, T, 4), (M, T, 3)
    ref = mean_rotation(q[:, :1])[0]  # chordal mean of the start rotations
    rel = quat_multiply(np.broadcast_to(quat_conjugate(ref), q.shape), q)
    Y = np.concatenate([_continuous_log(rel), p], axis=-1)  # (M, T, 6)
    Ts = np.tile(np.linspace(0.0, 1.0, steps), (len(train), 1))
    promp = ProMP(n_dims=6, n_weights_per_dim=int(n_basis))
    promp.imitate(Ts, Y)
    return ProMPPeer(promp, ref, steps)


def promp_rollouts(train: list[Trajectory], quat0, pos0, durations) -> list[Trajectory]:
    """The ProMP row: one conditioned mean per start (quat0 (S, 4) x, y, z, w; pos0 (S, 3); durations (S,))."""
    peer = fit_promp(train)
    return [peer.mean(q, p, d, name="promp") for q, p, d in zip(np.asarray(quat0), np.asarray(pos0), durations)]


def promp_samples(train: list[Trajectory], quat0, pos0, durations, k: int, seed: int = 0) -> list[list[Trajectory]]:
    """``k`` seeded draws of the conditioned ProMP per start (start i uses the seed ``seed + i``), for
    the sample columns: a list of S lists of k trajectories."""
    peer = fit_promp(train)
    return [peer.samples(q, p, d, k, seed=seed + i, name=f"promp{i}")
            for i, (q, p, d) in enumerate(zip(np.asarray(quat0), np.asarray(pos0), durations))]


# --------------------------------------------------------------------------------------------- DMP
def dmp_rollouts(train: list[Trajectory], quat0, pos0, durations, *, n_basis: int = DMP_BASIS) -> list[Trajectory]:
    """The DMP row: per start, a Cartesian DMP of the nearest-start training demonstration, started at
    the new start with that demonstration's goal, for the given duration (module docstring)."""
    from movement_primitives.dmp import CartesianDMP

    from rbgp_cli.evaluation.crossval import nearest_index

    out = []
    for q0, p0, duration in zip(np.asarray(quat0, dtype=np.float64), np.asarray(pos0, dtype=np.float64), durations):
        src = train[nearest_index(train, q0, p0)]
        t = src.t - src.t[0]
        q = quat_make_continuous(quat_normalize(src.quat))
        dmp = CartesianDMP(execution_time=float(t[-1]), dt=float(np.mean(np.diff(t))), n_weights_per_dim=int(n_basis))
        dmp.imitate(t, np.concatenate([src.position, _wxyz(q)], axis=1))
        start_q = quat_normalize(q0)
        start_q = start_q if np.dot(start_q, q[0]) >= 0 else -start_q  # same hemisphere as the demonstration
        dmp.configure(start_y=np.concatenate([p0, _wxyz(start_q)]), goal_y=np.concatenate([src.position[-1], _wxyz(q[-1])]))
        scale = float(duration) / float(t[-1])
        dmp.execution_time_ = float(duration)
        dmp.dt_ = float(np.mean(np.diff(t))) * scale
        T, Y = dmp.open_loop()
        out.append(Trajectory(T, _xyzw(Y[:, 3:]), Y[:, :3], name=f"dmp of {src.name}"))
    return out
