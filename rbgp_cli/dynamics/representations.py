"""The three model representations the paper compares (docs/method.md §4, §6), behind one interface.

Each representation says how a demonstration becomes (input, output) training pairs, and how one
integration step turns a predicted output into the next state. States are arrays of shape (B, d)
(B trajectories advanced together), inputs of the GP are the states themselves.

==============  ===============================  ===============================  ===================
representation  state / GP input                 GP output                        integration step
==============  ===============================  ===============================  ===================
axis-angle      (rx, ry, rz, x, y, z) canonical  ξ = (ω, v) world frame (§4)      R' = exp(ω dt) R,
                rotation vector (the paper's)                                     p' = p + v dt
euler           (roll, pitch, yaw, x, y, z),     d/dt of the unwrapped angles,    addition
                extrinsic xyz, unwrapped along   v
                each demonstration
quaternion      (qx, qy, qz, qw, x, y, z), sign  (q̇, v) by finite differences     addition, then q
                continuous, one hemisphere                                        projected to |q|=1
==============  ===============================  ===============================  ===================

The paper's dual-quaternion kernel is not specified in its text; the ``quaternion`` baseline uses
unit quaternions with the S³ angle (docs/method.md §6).
"""

from __future__ import annotations

import numpy as np

from rbgp_cli.dynamics.trajectory import Trajectory
from rbgp_cli.dynamics.velocities import forward_differences
from rbgp_cli.geometry.se3 import integrate_quat
from rbgp_cli.geometry.so3 import (
    euler_from_quat,
    exp_quat,
    quat_conjugate,
    quat_multiply,
    quat_from_euler,
    quat_from_rotvec,
    quat_make_continuous,
    quat_normalize,
    rotvec_from_quat,
)

__all__ = ["Representation", "AxisAngle", "Euler", "Quaternion", "REPRESENTATIONS", "make_representation", "representation_from_dict"]


class Representation:
    """Interface: training pairs from demonstrations and the integration step of a rollout."""

    name: str = ""
    input_names: tuple = ()
    output_names: tuple = ()
    rotation_dims: int = 3

    def prepare(self, trajs: list[Trajectory]) -> None:
        """Fix any data-dependent convention (e.g. the quaternion hemisphere) from the demonstrations."""

    def training_pairs(self, traj: Trajectory) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(X, Y, dt): inputs (N−1, d), outputs (N−1, L), time steps (N−1,) of one demonstration."""
        raise NotImplementedError

    def pairs_from_segment(self, seg) -> tuple[np.ndarray, np.ndarray]:
        """(X, Y) of one :class:`~rbgp_cli.dynamics.velocities.VelocitySegment`.

        Forward-difference segments (ξ has one row fewer than the poses) use the representation's
        own differences of its coordinates over the segment's steps, so that integrating them back
        reproduces the segment exactly; local-polynomial segments convert the instantaneous
        world-frame velocity ξ = (ω, v) at each pose (:meth:`output_from_velocity`).
        """
        if seg.differences:
            X, Y, _ = self.training_pairs(seg.traj)
            return X, Y
        state = self.state_along(seg.traj.quat, seg.traj.position)
        return state, self.output_from_velocity(state, seg.traj.quat, seg.xi)

    def state_along(self, quat: np.ndarray, position: np.ndarray) -> np.ndarray:
        """States (K, d) along one continuous trajectory (angles unwrapped, quaternions continuous)."""
        return self.state_from_pose(quat, position)

    def output_from_velocity(self, state: np.ndarray, quat: np.ndarray, xi: np.ndarray) -> np.ndarray:
        """The GP output (K, L) of a world-frame velocity ξ = (ω, v) (K, 6) at states (K, d)."""
        raise NotImplementedError

    def twist_from_output(self, state: np.ndarray, quat: np.ndarray, output: np.ndarray) -> np.ndarray:
        """The world-frame velocity ξ = (ω, v) (K, 6) that a GP output (K, L) means at states (K, d)
        with rotations ``quat`` (K, 4) (the inverse of :meth:`output_from_velocity`)."""
        raise NotImplementedError

    def state_from_pose(self, quat: np.ndarray, position: np.ndarray) -> np.ndarray:
        """State (B, d) from quaternions (B, 4) x, y, z, w and positions (B, 3)."""
        raise NotImplementedError

    def step(self, state: np.ndarray, output: np.ndarray, dt) -> np.ndarray:
        """Next state (B, d) after integrating the predicted output (B, L) over dt seconds."""
        raise NotImplementedError

    def pose_from_state(self, state: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(quat (B, 4) x, y, z, w, position (B, 3)) of a state."""
        raise NotImplementedError

    def to_dict(self) -> dict:
        return {"name": self.name}


class AxisAngle(Representation):
    """The paper's rigid-body GP: pose (θu, v) with canonical rotation vectors; outputs ξ = (ω, v)."""

    name = "axis-angle"
    input_names = ("rx", "ry", "rz", "x", "y", "z")
    output_names = ("wx", "wy", "wz", "vx", "vy", "vz")
    rotation_dims = 3

    def training_pairs(self, traj):
        xi, dt = forward_differences(traj)
        X = np.concatenate([rotvec_from_quat(traj.quat[:-1]), traj.position[:-1]], axis=1)
        return X, xi, dt

    def state_from_pose(self, quat, position):
        return np.concatenate([rotvec_from_quat(quat), position], axis=-1)

    def output_from_velocity(self, state, quat, xi):
        return np.array(xi, dtype=np.float64, copy=True)

    def twist_from_output(self, state, quat, output):
        return np.array(output, dtype=np.float64, copy=True)

    def step(self, state, output, dt):
        q, p = integrate_quat(quat_from_rotvec(state[..., :3]), state[..., 3:], output, dt)
        return np.concatenate([rotvec_from_quat(q), p], axis=-1)

    def pose_from_state(self, state):
        return quat_from_rotvec(state[..., :3]), state[..., 3:].copy()


class Euler(Representation):
    """Baseline: Euler angles (extrinsic ``order``, default xyz = roll, pitch, yaw) unwrapped along each
    demonstration, plus translation; outputs their finite-difference derivatives; integration by addition."""

    name = "euler"
    output_names = ("droll", "dpitch", "dyaw", "vx", "vy", "vz")
    rotation_dims = 3

    def __init__(self, order: str = "xyz"):
        self.order = order
        self.input_names = ("roll", "pitch", "yaw", "x", "y", "z")

    def _angles(self, quat):
        return np.unwrap(euler_from_quat(quat, self.order), axis=0)

    def training_pairs(self, traj):
        dt = np.diff(traj.t)
        forward_differences(traj)  # same checks (monotone time, steps below π)
        a = self._angles(traj.quat)
        X = np.concatenate([a[:-1], traj.position[:-1]], axis=1)
        Y = np.concatenate([np.diff(a, axis=0), np.diff(traj.position, axis=0)], axis=1) / dt[:, None]
        return X, Y, dt

    def state_from_pose(self, quat, position):
        return np.concatenate([euler_from_quat(quat, self.order), position], axis=-1)

    def state_along(self, quat, position):
        return np.concatenate([self._angles(quat), position], axis=-1)

    def output_from_velocity(self, state, quat, xi):
        """Euler-angle rates of ω by a central difference of the rotation, ±ε·ω about R (ε = 1e-6 s),
        unwrapped against the state's angles; v unchanged."""
        eps = 1e-6
        a = state[:, :3]
        plus = euler_from_quat(quat_multiply(exp_quat(xi[:, :3] * eps), quat), self.order)
        minus = euler_from_quat(quat_multiply(exp_quat(-xi[:, :3] * eps), quat), self.order)
        wrap = lambda b: a + (np.mod(b - a + np.pi, 2.0 * np.pi) - np.pi)  # noqa: E731 - nearest copy of b to a
        rates = (wrap(plus) - wrap(minus)) / (2.0 * eps)
        return np.concatenate([rates, xi[:, 3:]], axis=-1)

    def twist_from_output(self, state, quat, output):
        """ω = log(R(a + ȧε) R(a − ȧε)ᵀ)/(2ε) (ε = 1e-6 s) for Euler-angle rates ȧ; v unchanged."""
        eps = 1e-6
        a, rates = state[:, :3], output[:, :3]
        plus = quat_from_euler(a + rates * eps, self.order)
        minus = quat_from_euler(a - rates * eps, self.order)
        omega = rotvec_from_quat(quat_multiply(plus, quat_conjugate(minus))) / (2.0 * eps)
        return np.concatenate([omega, output[:, 3:]], axis=-1)

    def step(self, state, output, dt):
        h = np.asarray(dt, dtype=np.float64)
        return state + output * (h[..., None] if h.ndim else h)

    def pose_from_state(self, state):
        return quat_from_euler(state[..., :3], self.order), state[..., 3:].copy()

    def to_dict(self):
        return {"name": self.name, "order": self.order}


class Quaternion(Representation):
    """Baseline: unit quaternion (x, y, z, w) made sign-continuous along each demonstration and put on
    one hemisphere (⟨q, q_ref⟩ >= 0 at each demonstration's start), plus translation; outputs (q̇, v) by
    finite differences; integration by addition and projection of q back to unit length."""

    name = "quaternion"
    input_names = ("qx", "qy", "qz", "qw", "x", "y", "z")
    output_names = ("dqx", "dqy", "dqz", "dqw", "vx", "vy", "vz")
    rotation_dims = 4

    def __init__(self, reference=None):
        self.reference = None if reference is None else np.asarray(reference, dtype=np.float64)

    def prepare(self, trajs):
        if self.reference is None and trajs:
            self.reference = quat_normalize(trajs[0].quat[0])

    def _continuous(self, quat):
        q = quat_make_continuous(quat_normalize(quat))
        ref = self.reference if self.reference is not None else q[0]
        return q * (1.0 if float(q[0] @ ref) >= 0 else -1.0)

    def training_pairs(self, traj):
        dt = np.diff(traj.t)
        forward_differences(traj)
        q = self._continuous(traj.quat)
        X = np.concatenate([q[:-1], traj.position[:-1]], axis=1)
        Y = np.concatenate([np.diff(q, axis=0), np.diff(traj.position, axis=0)], axis=1) / dt[:, None]
        return X, Y, dt

    def state_from_pose(self, quat, position):
        q = quat_normalize(quat)
        if self.reference is not None:
            q = q * np.where(q @ self.reference >= 0, 1.0, -1.0)[..., None]
        return np.concatenate([q, position], axis=-1)

    def state_along(self, quat, position):
        return np.concatenate([self._continuous(quat), position], axis=-1)

    def output_from_velocity(self, state, quat, xi):
        """q̇ = ½ (ω, 0) ⊗ q for the (sign-continuous) q of the state; v unchanged."""
        q = state[:, :4]
        w = np.concatenate([xi[:, :3], np.zeros((len(xi), 1))], axis=-1)
        return np.concatenate([0.5 * quat_multiply(w, q), xi[:, 3:]], axis=-1)

    def twist_from_output(self, state, quat, output):
        """ω = 2·vec(q̇ ⊗ q*) (the part of q̇ tangent to the unit sphere) at the state's unit q."""
        q = quat_normalize(state[:, :4])
        omega = 2.0 * quat_multiply(output[:, :4], quat_conjugate(q))[:, :3]
        return np.concatenate([omega, output[:, 4:]], axis=-1)

    def step(self, state, output, dt):
        h = np.asarray(dt, dtype=np.float64)
        h = h[..., None] if h.ndim else h
        nxt = state + output * h
        nxt[..., :4] = quat_normalize(nxt[..., :4])
        return nxt

    def pose_from_state(self, state):
        return quat_normalize(state[..., :4]), state[..., 4:].copy()

    def to_dict(self):
        return {"name": self.name, "reference": None if self.reference is None else self.reference.tolist()}


REPRESENTATIONS = ("axis-angle", "euler", "quaternion")


def make_representation(name: str, **kwargs) -> Representation:
    """Representation by name: ``axis-angle``, ``euler`` or ``quaternion``."""
    if name == "axis-angle":
        return AxisAngle()
    if name == "euler":
        return Euler(kwargs.get("order", "xyz"))
    if name == "quaternion":
        return Quaternion(kwargs.get("reference"))
    raise ValueError(f"unknown representation {name!r}; expected one of {', '.join(REPRESENTATIONS)}")


def representation_from_dict(d: dict) -> Representation:
    """Inverse of :meth:`Representation.to_dict` (model files)."""
    d = dict(d)
    return make_representation(d.pop("name"), **d)
