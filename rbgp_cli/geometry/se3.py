"""Rigid motions SE(3): composition, inverse, action, exponential map, integration (docs/method.md §3, §4, §8).

Conventions (from :mod:`rbgp_cli.geometry.conventions`)
    * A pose array is ``g = (r, t)``, shape ``(..., 6)`` = ``(rx, ry, rz, x, y, z)``: **rotation
      first**, ``r`` the canonical rotation vector (eq. 6, 7), ``t`` in metres. It maps body to world
      coordinates: ``p_world = R(r) p_body + t``.
    * A velocity / twist array is ``ξ = (ω, v)``, shape ``(..., 6)``: rotation first; ``ω`` in rad/s
      (world frame), ``v`` in m/s.
    * Quaternions x, y, z, w. Every function returns canonical rotation vectors.
    * float64, vectorised over leading axes; shapes broadcast.
"""

from __future__ import annotations

import numpy as np

from rbgp_cli.geometry.conventions import SMALL_ANGLE
from rbgp_cli.geometry.so3 import (
    apply_rotvec,
    canonical_rotvec,
    compose_rotvec,
    exp_quat,
    inverse_rotvec,
    quat_multiply,
    quat_normalize,
)

__all__ = [
    "compose_pose",
    "inverse_pose",
    "apply_pose",
    "exp_se3",
    "log_se3",
    "integrate_pose",
    "integrate_quat",
]


def _as_array(x, n: int, name: str) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64)
    if a.ndim == 0 or a.shape[-1] != n:
        raise ValueError(f"{name}: expected shape (..., {n}), got {a.shape}")
    return a


def _norm(x: np.ndarray) -> np.ndarray:
    return np.sqrt(np.einsum("...i,...i->...", x, x))


def _dt(dt) -> np.ndarray:
    """``dt`` as float64 with a trailing axis of length 1, for broadcasting against (..., 3)."""
    return np.asarray(dt, dtype=np.float64)[..., None]


def compose_pose(g2, g1) -> np.ndarray:
    """Composition ``g2 ∘ g1`` (apply g1, then g2) (eq. 16, 17).

    ``(r2, t2) ∘ (r1, t1) = (r2 ∘ r1, R(r2) t1 + t2)``, with ``r2 ∘ r1`` computed through quaternions
    (eq. 8, :func:`~rbgp_cli.geometry.so3.compose_rotvec`) and ``R(r2) t1`` by Rodrigues (eq. 17).
    If ``g1 = T_B_C`` and ``g2 = T_A_B`` then the result is ``T_A_C``.
    Shapes (..., 6) (rx, ry, rz, x, y, z), broadcast; returns a canonical pose (..., 6).
    """
    g2 = _as_array(g2, 6, "compose_pose g2")
    g1 = _as_array(g1, 6, "compose_pose g1")
    r = compose_rotvec(g2[..., :3], g1[..., :3])
    t = apply_rotvec(g2[..., :3], g1[..., 3:]) + g2[..., 3:]
    return np.concatenate([r, t], axis=-1)


def inverse_pose(g) -> np.ndarray:
    """Inverse pose ``g⁻¹ = (r⁻¹, −R(r)ᵀ t) = (canonical(−r), −R(−r) t)``.

    Shape (..., 6) (rx, ry, rz, x, y, z) -> (..., 6); ``compose_pose(inverse_pose(g), g)`` is the
    identity.
    """
    g = _as_array(g, 6, "inverse_pose")
    r, t = g[..., :3], g[..., 3:]
    return np.concatenate([inverse_rotvec(r), -apply_rotvec(-r, t)], axis=-1)


def apply_pose(g, p) -> np.ndarray:
    """Map points by a pose: ``R(r) p + t`` (body -> world for ``g = T_world_body``; eq. 17).

    Shapes: ``g`` (..., 6) (rx, ry, rz, x, y, z), ``p`` (..., 3), broadcast; returns (..., 3).
    """
    g = _as_array(g, 6, "apply_pose g")
    p = _as_array(p, 3, "apply_pose p")
    return apply_rotvec(g[..., :3], p) + g[..., 3:]


def _left_jacobian_coeffs(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``B = (1 − cos θ)/θ²`` and ``C = (θ − sin θ)/θ³`` of ``V(ω) = I + B[ω]× + C[ω]×²``.

    Series below ``SMALL_ANGLE``: ``B = 1/2 − θ²/24 + θ⁴/720``, ``C = 1/6 − θ²/120 + θ⁴/5040``.
    ``B`` is computed as ``2 sin²(θ/2)/θ²`` (no cancellation). ``C`` cancels for small θ above the
    threshold, but it multiplies ``[ω]×²`` (size θ²), so its absolute contribution stays at
    round-off level.
    """
    small = theta < SMALL_ANGLE
    safe = np.where(small, 1.0, theta)
    t2 = theta * theta
    half = np.sin(0.5 * safe) / safe
    b = np.where(small, 0.5 - t2 / 24.0 + t2 * t2 / 720.0, 2.0 * half * half)
    c = np.where(small, 1.0 / 6.0 - t2 / 120.0 + t2 * t2 / 5040.0, (safe - np.sin(safe)) / safe**3)
    return b, c


def exp_se3(xi) -> np.ndarray:
    """The SE(3) exponential of a twist ``ξ = (ω, v)`` (the 4×4 matrix exponential of [[ω]×, v; 0, 0]).

    ``exp(ξ) = (exp(ω), V(ω) v)`` with the left Jacobian of SO(3)
    ``V(ω) = I + (1 − cos θ)/θ² [ω]× + (θ − sin θ)/θ³ [ω]×²``, ``θ = ‖ω‖`` (Taylor series below
    ``SMALL_ANGLE``). The rotation part is the canonical vector of ``ω`` (eq. 11, 12; for
    ``‖ω‖ > π`` it is folded into the ball, the translation still uses the full ``ω``).
    Same as scipy's ``RigidTransform.from_exp_coords`` (which orders ``[rx, ry, rz, vx, vy, vz]``).
    Shape (..., 6) (ωx, ωy, ωz, vx, vy, vz) -> pose (..., 6) (rx, ry, rz, x, y, z).
    """
    xi = _as_array(xi, 6, "exp_se3")
    w, v = xi[..., :3], xi[..., 3:]
    b, c = _left_jacobian_coeffs(_norm(w))
    wv = np.cross(w, v)
    t = v + b[..., None] * wv + c[..., None] * np.cross(w, wv)
    return np.concatenate([canonical_rotvec(w), t], axis=-1)


def log_se3(g) -> np.ndarray:
    """The SE(3) logarithm: the twist ``ξ = (ω, v)`` with ``exp_se3(ξ) = g`` and ``ω`` canonical.

    ``ω = r`` (canonical, θ ∈ [0, π]) and ``v = V(ω)⁻¹ t`` with
    ``V⁻¹ = I − ½[ω]× + D [ω]×²``, ``D = (1 − (θ/2) cot(θ/2))/θ²`` (series
    ``1/12 + θ²/720 + θ⁴/30240`` below ``SMALL_ANGLE``; finite up to θ = π, where D = 1/π²).
    At θ = π the logarithm is not unique; this one follows the eq. 7 choice of ``r``.
    Shape (..., 6) pose (rx, ry, rz, x, y, z) -> twist (..., 6) (ωx, ωy, ωz, vx, vy, vz).
    """
    g = _as_array(g, 6, "log_se3")
    w = canonical_rotvec(g[..., :3])
    t = g[..., 3:]
    theta = _norm(w)
    small = theta < SMALL_ANGLE
    safe = np.where(small, 1.0, theta)
    t2 = theta * theta
    half = 0.5 * safe
    d = np.where(
        small,
        1.0 / 12.0 + t2 / 720.0 + t2 * t2 / 30240.0,
        (1.0 - half * np.cos(half) / np.sin(half)) / (safe * safe),
    )
    wt = np.cross(w, t)
    v = t - 0.5 * wt + d[..., None] * np.cross(w, wt)
    return np.concatenate([w, v], axis=-1)


def integrate_pose(g, xi, dt) -> np.ndarray:
    """One integration (rollout) step (docs/method.md §4, §8): ``R' = exp(ω dt) R``, ``p' = p + v dt``.

    In rotation vectors: ``r' = (ω dt) ∘ r`` (eq. 8, 11), returned canonical. Integrating the exact
    forward differences ``ω_k = log(R_{k+1} R_kᵀ)/Δt_k``, ``v_k = (p_{k+1} − p_k)/Δt_k`` reproduces
    the samples to round-off, also across θ = π.

    Shapes: ``g`` (..., 6) pose (rx, ry, rz, x, y, z); ``xi`` (..., 6) velocity (ωx, ωy, ωz, vx,
    vy, vz) in the world frame (rad/s, m/s); ``dt`` seconds, broadcast against the leading axes
    (a scalar or shape (...)). Returns the pose (..., 6).
    """
    g = _as_array(g, 6, "integrate_pose g")
    xi = _as_array(xi, 6, "integrate_pose xi")
    h = _dt(dt)
    r = compose_rotvec(xi[..., :3] * h, g[..., :3])
    p = g[..., 3:] + xi[..., 3:] * h
    return np.concatenate(np.broadcast_arrays(r, p), axis=-1)


def integrate_quat(q, p, xi, dt) -> tuple[np.ndarray, np.ndarray]:
    """:func:`integrate_pose` for trajectories kept as quaternions: ``q' = exp(ω dt) ⊗ q``, ``p' = p + v dt``.

    ``q'`` is **not** canonicalised: it stays continuous in sign with ``q`` (``⟨q', q⟩ > 0`` for
    steps below π), so a sequence built by repeated steps needs no sign repair. ``q'`` is
    renormalised to stop round-off from drifting off the unit sphere over long rollouts.

    Shapes: ``q`` (..., 4) (x, y, z, w), ``p`` (..., 3) metres, ``xi`` (..., 6) (ω, v),
    ``dt`` seconds broadcast against the leading axes. Returns ``(q', p')``.
    """
    q = _as_array(q, 4, "integrate_quat q")
    p = _as_array(p, 3, "integrate_quat p")
    xi = _as_array(xi, 6, "integrate_quat xi")
    h = _dt(dt)
    q_next = quat_normalize(quat_multiply(exp_quat(xi[..., :3] * h), q))
    return q_next, p + xi[..., 3:] * h
