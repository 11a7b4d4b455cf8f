"""The one trajectory type every reader produces and every command consumes.

A :class:`Trajectory` is a sampled pose ``T_world_body(t)``:

* ``t``: shape (N,), seconds;
* ``quat``: shape (N, 4), unit quaternions **x, y, z, w** (scalar last), rotation body -> world;
* ``position``: shape (N, 3), metres, origin of the body in the world frame.

Readers may return *raw* trajectories (lost frames as NaN rows, non-unit or sign-flipped quaternions,
unsorted times); :func:`rbgp_cli.dynamics.prepare.prepare_trajectory` turns them into clean ones
(strictly increasing times, finite values, unit quaternions continuous in sign) and reports what it
repaired. ``info`` carries plain-data facts about where the samples came from (file, topic, body,
detected units) and what was repaired; it is what ``rbgp inspect`` and model provenance show.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

__all__ = ["Trajectory", "interpolate_poses"]


@dataclass(frozen=True, eq=False)
class Trajectory:
    """Sampled rigid-body motion ``T_world_body(t)`` (quaternions x, y, z, w; SI units).

    Attributes
    ----------
    t : ndarray, shape (N,)
        Sample times in seconds.
    quat : ndarray, shape (N, 4)
        Rotation body -> world as quaternions (x, y, z, w).
    position : ndarray, shape (N, 3)
        Body origin in the world frame, metres.
    name : str
        A short label (demo name, body name, ``file#demo``).
    source : str
        Where it was read from (path, ``path:topic``, ``-`` for stdin).
    info : dict
        Plain data (str, int, float, lists, dicts): detected units, rate, repairs, warnings.
    """

    t: np.ndarray
    quat: np.ndarray
    position: np.ndarray
    name: str = ""
    source: str = ""
    info: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        t = np.asarray(self.t, dtype=np.float64).reshape(-1)
        q = np.asarray(self.quat, dtype=np.float64).reshape(-1, 4)
        p = np.asarray(self.position, dtype=np.float64).reshape(-1, 3)
        if not (len(t) == len(q) == len(p)):
            raise ValueError(
                f"Trajectory arrays disagree in length: t {len(t)}, quat {len(q)}, position {len(p)}"
            )
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "quat", q)
        object.__setattr__(self, "position", p)

    def __len__(self) -> int:
        return len(self.t)

    @property
    def duration(self) -> float:
        """Last minus first time, seconds (0 for fewer than two samples)."""
        return float(self.t[-1] - self.t[0]) if len(self.t) > 1 else 0.0

    @property
    def poses(self) -> np.ndarray:
        """Pose array, shape (N, 6) = (rx, ry, rz, x, y, z), canonical rotation vectors (docs/method.md §2)."""
        from rbgp_cli.geometry.so3 import rotvec_from_quat

        return np.concatenate([rotvec_from_quat(self.quat), self.position], axis=-1)

    @classmethod
    def from_poses(cls, t, poses, **kwargs) -> "Trajectory":
        """Build from a pose array, shape (N, 6) = (rx, ry, rz, x, y, z)."""
        from rbgp_cli.geometry.so3 import quat_from_rotvec

        poses = np.asarray(poses, dtype=np.float64)
        return cls(t=t, quat=quat_from_rotvec(poses[..., :3]), position=poses[..., 3:], **kwargs)

    def with_(self, **changes) -> "Trajectory":
        """A copy with some fields replaced (``info`` is merged, not replaced)."""
        if "info" in changes:
            changes["info"] = {**self.info, **changes["info"]}
        return replace(self, **changes)

    def slice(self, index) -> "Trajectory":
        """A copy restricted to ``index`` (a slice, boolean mask or integer array)."""
        return replace(self, t=self.t[index], quat=self.quat[index], position=self.position[index])


def interpolate_poses(x: np.ndarray, quat: np.ndarray, position: np.ndarray, x_new: np.ndarray):
    """Poses at new abscissae by slerp (rotation, shortest arc) and linear interpolation (position).

    ``x`` (N,) strictly increasing sample abscissae (times, or normalised time), ``quat`` (..., N, 4)
    x, y, z, w unit quaternions, sign-continuous, ``position`` (..., N, 3) (leading axes: several
    trajectories on the same abscissae); ``x_new`` (T,) inside ``[x_0, x_{N−1}]`` (values outside are
    clamped to the ends). With ``k`` such that ``x_k <= x_new < x_{k+1}`` and
    ``f = (x_new − x_k)/(x_{k+1} − x_k)``:

        q = slerp(q_k, q_{k+1}; f),    p = (1 − f) p_k + f p_{k+1}.

    A target that falls on a sample (f = 0, or the last sample) returns that sample bit for bit.
    Returns ``(quat (..., T, 4), position (..., T, 3))``; quaternions sign-continuous along ``x_new``
    when ``x_new`` is increasing.
    """
    from rbgp_cli.geometry.so3 import quat_make_continuous, slerp

    x = np.asarray(x, dtype=np.float64)
    x_new = np.asarray(x_new, dtype=np.float64)
    k = np.clip(np.searchsorted(x, x_new, side="right") - 1, 0, len(x) - 2)  # (T,)
    f = np.clip((x_new - x[k]) / (x[k + 1] - x[k]), 0.0, 1.0)  # (T,)
    q = slerp(quat[..., k, :], quat[..., k + 1, :], f)
    q = np.where((f == 0.0)[:, None], quat[..., k, :], np.where((f == 1.0)[:, None], quat[..., k + 1, :], q))
    p = (1.0 - f)[:, None] * position[..., k, :] + f[:, None] * position[..., k + 1, :]
    if len(x_new) > 1:
        q = quat_make_continuous(q)
    return q, p
