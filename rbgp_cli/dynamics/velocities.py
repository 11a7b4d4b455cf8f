"""Velocities of a demonstration by forward differences (MATH.md §4, paper sec. 2 and 4.3).

For samples (t_k, R_k, p_k), k = 0..N−1, strictly increasing t:

    ω_k = log(R_{k+1} R_kᵀ) / Δt_k        (world-frame angular velocity, rad/s)
    v_k = (p_{k+1} − p_k) / Δt_k          (world-frame velocity of the body origin, m/s)

Training pairs are (g_k, ξ_k), k = 0..N−2. Integrating ξ_k with
:func:`rbgp_cli.geometry.se3.integrate_quat` reproduces the samples to round-off, also across θ = π,
because rotation vectors and Euler angles are never differenced directly.
"""

from __future__ import annotations

import math

import numpy as np

from rbgp_cli.dynamics.trajectory import Trajectory
from rbgp_cli.errors import InputError
from rbgp_cli.geometry.so3 import log_quat, quat_conjugate, quat_multiply

__all__ = ["forward_differences", "MAX_STEP_ANGLE"]

#: A step rotating by (nearly) π cannot tell its direction: the sampling is too coarse (MATH.md §4).
MAX_STEP_ANGLE = math.pi - 1e-6


def forward_differences(traj: Trajectory) -> tuple[np.ndarray, np.ndarray]:
    """World-frame velocities ξ_k = (ω_k, v_k) by forward differences.

    Parameters
    ----------
    traj : a clean Trajectory (strictly increasing t, unit quaternions x, y, z, w), N >= 2 samples

    Returns
    -------
    xi : shape (N−1, 6) = (ωx, ωy, ωz, vx, vy, vz), rad/s and m/s
    dt : shape (N−1,), seconds
    """
    n = len(traj)
    if n < 2:
        raise InputError(f"needs at least 2 samples for a velocity, has {n}", path=traj.source or traj.name or None)
    dt = np.diff(traj.t)
    if not np.all(dt > 0):
        k = int(np.argmax(~(dt > 0)))
        raise InputError(
            f"times are not strictly increasing at sample {k + 1}",
            path=traj.source or traj.name or None,
            hint="sort the samples by time and remove duplicates",
        )
    q = traj.quat
    dq = quat_multiply(q[1:], quat_conjugate(q[:-1]))  # R_{k+1} R_kᵀ
    rot = log_quat(dq)  # canonical, angle in [0, π]
    ang = np.linalg.norm(rot, axis=-1)
    if np.any(ang >= MAX_STEP_ANGLE):
        k = int(np.argmax(ang >= MAX_STEP_ANGLE))
        raise InputError(
            f"the rotation between samples {k} and {k + 1} is {math.degrees(ang[k]):.1f}°, too coarse to tell its direction",
            path=traj.source or traj.name or None,
            hint="record at a higher rate or check for lost frames and quaternion order",
        )
    omega = rot / dt[:, None]
    v = np.diff(traj.position, axis=0) / dt[:, None]
    return np.concatenate([omega, v], axis=1), dt
