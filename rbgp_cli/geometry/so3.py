"""Rotations: canonical rotation vectors, quaternions, matrices, Euler angles (docs/method.md §1–§3).

Conventions (from :mod:`rbgp_cli.geometry.conventions`)
    * Quaternions are Hamilton quaternions with components **x, y, z, w** (scalar last), shape
      ``(..., 4)``. ``q`` and ``-q`` are the same rotation; functions that return a quaternion as a
      *rotation* return ``w >= 0`` unless stated otherwise.
    * A rotation vector ``r = θu`` (shape ``(..., 3)``) is canonical when it lies in the paper's ball
      B̃π (eq. 6, 7): ``θ ∈ [0, π]`` and, at ``θ = π``, the eq. 7 tie-break holds: ``u_z > 0``, or
      ``u_z = 0`` and ``u_y > 0``, or ``u_z = u_y = 0`` and ``u_x > 0``.
    * ``compose_rotvec(r2, r1)`` means "rotate by r1, then by r2": ``q2 ⊗ q1``, ``R2 @ R1``.
    * Rotations act actively on vectors: ``x' = R x``.
    * Radians, float64, vectorised over any leading axes ``...`` (no Python loops over samples).

Numerics
    * Below ``SMALL_ANGLE`` (1e-4 rad) the ratios sin(θ/2)/θ, sin θ/θ, ... use their Taylor series,
      so nothing divides by zero and every map is smooth through the identity.
    * Near θ = π every conversion goes through the quaternion (``2·atan2(‖q_xyz‖, w)``, Shepperd's
      branch selection for matrices), which stays accurate where ``acos``/``trace`` formulas lose
      half their digits.
    * ``PI_TOLERANCE``: an angle within 1e-13 rad of π counts as π for the eq. 7 tie-break, and
      ``AXIS_TOLERANCE``: an axis component with ``|u_i| <= 1e-12`` counts as zero. Conversions
      (rotvec -> quat -> matrix -> quat -> rotvec) perturb θ and u by ~1e-16; without the tolerance a
      half-turn about, e.g., (1, -1, 0)/√2 would come back as ``r`` or ``-r`` depending on round-off.
      With it, the choice is made on the same side every time, so round trips are idempotent. The
      price: a vector with π − 1e-13 < θ < π may be replaced by ``-r``, a rotation at most 2e-13 rad
      away. A consequence: the chosen vector may have, e.g., ``u_z = -1e-14`` when its ``u_y > 0``.
    * NaN in, NaN out (lost frames stay visible); a zero quaternion gives NaN. Finite, valid input
      never gives NaN.

References
    Lang & Hirche, "Computationally efficient rigid-body Gaussian process for motion dynamics"
    (eq. numbers below refer to it, as corrected by docs/method.md); Shepperd, "Quaternion from rotation
    matrix", J. Guidance and Control 1 (1978); Bernardes & Viollet, "Quaternion to Euler angles
    conversion: A direct, general and computationally efficient method", PLoS ONE 17 (2022).
"""

from __future__ import annotations

import re

import numpy as np

from rbgp_cli.geometry.conventions import SMALL_ANGLE

__all__ = [
    "PI_TOLERANCE",
    "AXIS_TOLERANCE",
    "canonical_rotvec",
    "quat_from_rotvec",
    "rotvec_from_quat",
    "matrix_from_rotvec",
    "rotvec_from_matrix",
    "matrix_from_quat",
    "quat_from_matrix",
    "quat_multiply",
    "quat_conjugate",
    "quat_normalize",
    "quat_canonical",
    "quat_make_continuous",
    "compose_rotvec",
    "compose_rotvec_closed_form",
    "inverse_rotvec",
    "skew",
    "exp_so3",
    "log_so3",
    "exp_quat",
    "log_quat",
    "rotate",
    "apply_rotvec",
    "slerp",
    "quat_from_euler",
    "euler_from_quat",
    "matrix_from_euler",
    "euler_from_matrix",
    "random_quat",
]

#: An angle within this distance (rad) of π counts as π for the eq. 7 tie-break (see module doc).
PI_TOLERANCE = 1e-13
#: An axis component (of a unit axis) with absolute value at most this counts as 0 for eq. 7.
AXIS_TOLERANCE = 1e-12


# ----------------------------------------------------------------------------------------------
# Small helpers (unchecked)
# ----------------------------------------------------------------------------------------------


def _as_array(x, n: int, name: str) -> np.ndarray:
    """``x`` as float64 with last axis ``n`` (ValueError naming the expected shape otherwise)."""
    a = np.asarray(x, dtype=np.float64)
    if a.ndim == 0 or a.shape[-1] != n:
        raise ValueError(f"{name}: expected shape (..., {n}), got {a.shape}")
    return a


def _as_matrix(x, name: str) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64)
    if a.ndim < 2 or a.shape[-2:] != (3, 3):
        raise ValueError(f"{name}: expected shape (..., 3, 3), got {a.shape}")
    return a


def _norm(x: np.ndarray) -> np.ndarray:
    """Euclidean norm over the last axis, shape ``x.shape[:-1]``."""
    return np.sqrt(np.einsum("...i,...i->...", x, x))


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Inner product over the last axis (broadcasting)."""
    return np.sum(a * b, axis=-1)


def _sin_half_over_angle(theta: np.ndarray) -> np.ndarray:
    """sin(θ/2)/θ, with its Taylor series 1/2 − θ²/48 + θ⁴/3840 below ``SMALL_ANGLE``."""
    small = theta < SMALL_ANGLE
    if not np.any(small):
        return np.sin(0.5 * theta) / theta
    safe = np.where(small, 1.0, theta)
    t2 = theta * theta
    return np.where(small, 0.5 - t2 / 48.0 + t2 * t2 / 3840.0, np.sin(0.5 * safe) / safe)


def _eq7_sign(v: np.ndarray) -> np.ndarray:
    """+1 or −1 per vector, so that ``sign * v`` satisfies the eq. 7 tie-break.

    Decides on u_z, then u_y, then u_x, treating ``|u_i| <= AXIS_TOLERANCE·‖v‖`` as zero. The rule
    depends on ``v`` only through its direction and is odd (``_eq7_sign(-v) == -_eq7_sign(v)``),
    so ``v`` and ``-v`` are always mapped to the same vector. Zero vectors get +1.
    """
    tol = AXIS_TOLERANCE * _norm(v)
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    s = np.where(np.abs(z) > tol, np.sign(z), np.where(np.abs(y) > tol, np.sign(y), np.sign(x)))
    return np.where(s == 0, 1.0, s)


def _log_quat_unit(q: np.ndarray) -> np.ndarray:
    """Rotation vector ``θu`` of a *unit* quaternion, ``θ = 2·atan2(‖q_xyz‖, w) ∈ [0, 2π]``.

    No sign flip and no tie-break: with ``w >= 0`` the result lies in the ball of radius π. The
    ratio θ/‖q_xyz‖ uses the series ``2/w·(1 − x²/3 + x⁴/5)``, ``x = ‖q_xyz‖/w``, below
    ``SMALL_ANGLE``.
    """
    v = q[..., :3]
    w = q[..., 3]
    s = _norm(v)
    theta = 2.0 * np.arctan2(s, w)
    small = (s < SMALL_ANGLE) & (w > 0)
    if not np.any(small):
        return v * (theta / s)[..., None]
    safe_s = np.where(small, 1.0, s)
    safe_w = np.where(small, w, 1.0)
    x2 = (s / safe_w) ** 2
    scale = np.where(small, 2.0 / safe_w * (1.0 - x2 / 3.0 + x2 * x2 / 5.0), theta / safe_s)
    return v * scale[..., None]


# ----------------------------------------------------------------------------------------------
# Quaternion algebra
# ----------------------------------------------------------------------------------------------


def quat_normalize(q) -> np.ndarray:
    """Unit quaternion ``q / ‖q‖``, shape (..., 4), components x, y, z, w. Sign is kept.

    A zero quaternion gives NaN (it is no rotation).
    """
    q = _as_array(q, 4, "quat_normalize")
    n = _norm(q)[..., None]
    if np.all(n > 0):  # the usual case, without the masks (rollouts call this every step)
        return q / n
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, q / np.where(n > 0, n, 1.0), np.nan)


def quat_canonical(q) -> np.ndarray:
    """The same quaternion with ``w >= 0`` (shape (..., 4), x, y, z, w; not normalised).

    ``q`` and ``-q`` are the same rotation; this picks ``w > 0``, and at ``w == 0`` (exactly) the
    eq. 7 rule on the vector part (its last non-zero component among z, y, x positive).
    """
    q = _as_array(q, 4, "quat_canonical")
    w = q[..., 3]
    s = np.where(w > 0, 1.0, np.where(w < 0, -1.0, _eq7_sign_exact(q[..., :3])))
    return q * s[..., None]


def _eq7_sign_exact(v: np.ndarray) -> np.ndarray:
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    s = np.where(z != 0, np.sign(z), np.where(y != 0, np.sign(y), np.sign(x)))
    return np.where(s == 0, 1.0, s)


def quat_conjugate(q) -> np.ndarray:
    """Conjugate ``(−x, −y, −z, w)``, shape (..., 4); the inverse rotation of a unit quaternion."""
    q = _as_array(q, 4, "quat_conjugate")
    return np.concatenate([-q[..., :3], q[..., 3:]], axis=-1)


def quat_multiply(q2, q1) -> np.ndarray:
    """Hamilton product ``q2 ⊗ q1``: rotate by ``q1`` first, then by ``q2`` (docs/method.md §3).

    With ``q = (v, w)`` (x, y, z, w order)::

        w = w2 w1 − v2·v1,    v = w2 v1 + w1 v2 + v2 × v1

    Shapes (..., 4) and (..., 4), broadcast against each other. No normalisation, no sign change.
    """
    q2 = _as_array(q2, 4, "quat_multiply q2")
    q1 = _as_array(q1, 4, "quat_multiply q1")
    x2, y2, z2, w2 = q2[..., 0], q2[..., 1], q2[..., 2], q2[..., 3]
    x1, y1, z1, w1 = q1[..., 0], q1[..., 1], q1[..., 2], q1[..., 3]
    out = np.empty(np.broadcast_shapes(q2.shape, q1.shape))
    # component by component (np.cross and the concatenation cost more than the arithmetic here)
    out[..., 0] = w2 * x1 + w1 * x2 + (y2 * z1 - z2 * y1)
    out[..., 1] = w2 * y1 + w1 * y2 + (z2 * x1 - x2 * z1)
    out[..., 2] = w2 * z1 + w1 * z2 + (x2 * y1 - y2 * x1)
    out[..., 3] = w2 * w1 - (x2 * x1 + y2 * y1 + z2 * z1)
    return out


def quat_make_continuous(q, axis: int = -2) -> np.ndarray:
    """Flip signs along a sequence so that consecutive quaternions have ``⟨q_k, q_{k−1}⟩ >= 0``.

    ``q`` has shape (..., N, ..., 4) with the sequence along ``axis`` (default −2, i.e. (..., N, 4)).
    The first quaternion keeps its sign. With ``d_k = sign⟨q_k, q_{k−1}⟩`` (+1 at 0), the flip of
    ``q_k`` is the cumulative product ``d_1 ⋯ d_k`` (exact in floating point), so no Python loop is
    needed. The quaternions are not normalised; only signs change.
    """
    q = _as_array(q, 4, "quat_make_continuous")
    ax = axis if axis >= 0 else q.ndim + axis
    if not 0 <= ax < q.ndim - 1:
        raise ValueError(f"quat_make_continuous: axis {axis} is not a sequence axis of {q.shape}")
    qs = np.moveaxis(q, ax, -2)
    if qs.shape[-2] < 2:
        return q.copy()
    d = np.sum(qs[..., 1:, :] * qs[..., :-1, :], axis=-1)
    step = np.where(d < 0, -1.0, 1.0)
    flips = np.concatenate([np.ones_like(step[..., :1]), np.cumprod(step, axis=-1)], axis=-1)
    return np.moveaxis(qs * flips[..., None], -2, ax)


# ----------------------------------------------------------------------------------------------
# Rotation vectors <-> quaternions (eq. 6, 7, 11)
# ----------------------------------------------------------------------------------------------


def exp_quat(omega) -> np.ndarray:
    """Exponential map R³ -> S³: ``(sin(θ/2) u, cos(θ/2))`` with ``θ = ‖ω‖``, ``u = ω/θ`` (eq. 11).

    Shape (..., 3) -> (..., 4), components x, y, z, w. This is the true exponential on unit
    quaternions: for ``‖ω‖ > π`` it returns ``w < 0`` (no canonicalisation), which keeps
    ``exp_quat(ω dt) ⊗ q`` continuous in sign for small steps. sin(θ/2)/θ uses its series below
    ``SMALL_ANGLE``.
    """
    omega = _as_array(omega, 3, "exp_quat")
    theta = _norm(omega)
    out = np.empty(omega.shape[:-1] + (4,))
    np.multiply(omega, _sin_half_over_angle(theta)[..., None], out=out[..., :3])
    np.cos(0.5 * theta, out=out[..., 3])
    return out


def quat_from_rotvec(r) -> np.ndarray:
    """Unit quaternion of a rotation vector, ``w >= 0`` (eq. 6, 11; docs/method.md §2).

    ``q = ±(sin(θ/2) u, cos(θ/2))``, ``θ = ‖r‖``, ``u = r/θ``; shape (..., 3) -> (..., 4), x, y, z, w.
    Any ``r`` is accepted (angles above π are folded by the sign flip).
    """
    q = exp_quat(r)
    return q * np.where(q[..., 3:] < 0, -1.0, 1.0)


def rotvec_from_quat(q) -> np.ndarray:
    """Canonical rotation vector of a quaternion (eq. 6, 7; docs/method.md §2).

    Normalise ``q``, flip it to ``w >= 0``, ``θ = 2·atan2(‖q_xyz‖, w) ∈ [0, π]``,
    ``u = q_xyz/‖q_xyz‖`` (identity -> 0, via a series below ``SMALL_ANGLE``), then at θ = π (within
    ``PI_TOLERANCE``) the eq. 7 tie-break. Shape (..., 4) -> (..., 3). ``q`` and ``-q`` give the
    same vector.
    """
    q = quat_normalize(q)
    q = q * np.where(q[..., 3:] < 0, -1.0, 1.0)
    r = _log_quat_unit(q)
    return _tie_break(r)


def _tie_break(r: np.ndarray) -> np.ndarray:
    """Apply the eq. 7 tie-break to rotation vectors with ``θ >= π − PI_TOLERANCE`` (``θ <= π``)."""
    near_pi = _norm(r) >= np.pi - PI_TOLERANCE
    if not np.any(near_pi):
        return r
    return np.where(near_pi[..., None], r * _eq7_sign(r)[..., None], r)


def log_quat(q) -> np.ndarray:
    """Logarithm S³ -> canonical ball B̃π: the canonical rotation vector of ``q`` (eq. 6, 7, 11).

    Same as :func:`rotvec_from_quat`; shape (..., 4) -> (..., 3).
    """
    return rotvec_from_quat(q)


def canonical_rotvec(r) -> np.ndarray:
    """Fold any rotation vector into the canonical ball B̃π (eq. 6, 7; docs/method.md §2).

    ``θ = ‖r‖``: vectors with ``θ < π − PI_TOLERANCE`` are already canonical and are returned
    unchanged (bit for bit); the others go through the quaternion: ``θ > π`` becomes
    ``(2π − θ)(−u)`` (modulo 2π), and ``θ = π`` gets the eq. 7 tie-break (u_z > 0, or u_z = 0 and
    u_y > 0, or u_z = u_y = 0 and u_x > 0; tolerances in the module doc). Shape (..., 3) -> (..., 3).
    Idempotent: ``canonical_rotvec(canonical_rotvec(r))`` is ``canonical_rotvec(r)`` (bit for bit
    for θ < π − ``PI_TOLERANCE``, to round-off near π, and never its twin).
    """
    r = _as_array(r, 3, "canonical_rotvec")
    inside = _norm(r) < np.pi - PI_TOLERANCE
    if np.all(inside):
        return r.copy()
    return np.where(inside[..., None], r, rotvec_from_quat(quat_from_rotvec(r)))


def inverse_rotvec(r) -> np.ndarray:
    """Inverse rotation as a canonical vector: ``canonical(−r)`` (eq. 7; at θ = π it is ``r``).

    Shape (..., 3) -> (..., 3).
    """
    r = _as_array(r, 3, "inverse_rotvec")
    return canonical_rotvec(-r)


def compose_rotvec(r2, r1) -> np.ndarray:
    """Composition ``r2 ∘ r1`` (rotate by r1, then r2) as a canonical vector (eq. 8; docs/method.md §3).

    Computed through quaternions: ``rotvec(q(r2) ⊗ q(r1))``. Shapes (..., 3), broadcast.
    """
    r2 = _as_array(r2, 3, "compose_rotvec r2")
    r1 = _as_array(r1, 3, "compose_rotvec r1")
    return rotvec_from_quat(quat_multiply(quat_from_rotvec(r2), quat_from_rotvec(r1)))


def compose_rotvec_closed_form(r2, r1) -> np.ndarray:
    """The paper's closed form of ``r2 ∘ r1`` (eq. 8), corrected; a test oracle only.

    From ``q3 = q2 ⊗ q1`` with ``qi = (sin(θi/2) ui, cos(θi/2))`` (inputs canonicalised first)::

        a  = cos((θ1 + θ2)/2),  b = sin(θ2/2)·sin(θ1/2),  c = 1 − u2·u1   (printed: 1 + u2·u1)
        θ3 = 2·acos(a + b·c)                                          ∈ [0, 2π]
        u3 = (sin(θ1/2)cos(θ2/2) u1 + cos(θ1/2)sin(θ2/2) u2 + b (u2 × u1)) / sqrt(1 − (a + b·c)²)

    ``θ3 > π`` is folded to ``(2π − θ3, −u3)``; ``1 − (a + b·c)² = 0`` (the identity, where the
    formula is 0/0) gives 0; the result gets the eq. 7 tie-break. ``acos`` makes it lose about half
    the digits near the identity (errors ~1e-8 rad); use :func:`compose_rotvec` for real work.
    Shapes (..., 3), broadcast.
    """
    r2 = canonical_rotvec(r2)
    r1 = canonical_rotvec(r1)
    t1, t2 = _norm(r1), _norm(r2)
    u1 = r1 / np.where(t1 > 0, t1, 1.0)[..., None]  # u = 0 at θ = 0: its terms vanish anyway
    u2 = r2 / np.where(t2 > 0, t2, 1.0)[..., None]
    s1, c1 = np.sin(t1 / 2), np.cos(t1 / 2)
    s2, c2 = np.sin(t2 / 2), np.cos(t2 / 2)
    a = np.cos((t1 + t2) / 2)
    b = s2 * s1
    c = 1.0 - _dot(u2, u1)
    w3 = np.clip(a + b * c, -1.0, 1.0)
    theta3 = 2.0 * np.arccos(w3)
    num = (s1 * c2)[..., None] * u1 + (c1 * s2)[..., None] * u2 + b[..., None] * np.cross(u2, u1)
    den = np.sqrt(1.0 - w3 * w3)
    ok = den > 0
    u3 = num / np.where(ok, den, 1.0)[..., None]
    fold = theta3 > np.pi
    theta3 = np.where(fold, 2 * np.pi - theta3, theta3)
    u3 = np.where(fold[..., None], -u3, u3)
    r3 = np.where(ok[..., None], theta3[..., None] * u3, 0.0)
    return _tie_break(r3)


# ----------------------------------------------------------------------------------------------
# Matrices (eq. 10, 12)
# ----------------------------------------------------------------------------------------------


def skew(v) -> np.ndarray:
    """Cross-product matrix ``[v]×`` (eq. 10): ``[v]× x = v × x``. Shape (..., 3) -> (..., 3, 3)."""
    v = _as_array(v, 3, "skew")
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    o = np.zeros_like(x)
    return np.stack(
        [np.stack([o, -z, y], -1), np.stack([z, o, -x], -1), np.stack([-y, x, o], -1)], axis=-2
    )


def matrix_from_rotvec(r) -> np.ndarray:
    """Rotation matrix of a rotation vector by Rodrigues' formula (eq. 12).

    ``R = cos θ I + sin θ [u]× + (1 − cos θ) u uᵀ``, written as
    ``R = I + A [r]× + B [r]×²`` with ``A = sin θ/θ``, ``B = 2 sin²(θ/2)/θ²`` (Taylor series
    ``1 − θ²/6 + θ⁴/120`` and ``1/2 − θ²/24 + θ⁴/720`` below ``SMALL_ANGLE``; ``2 sin²(θ/2)``
    instead of ``1 − cos θ`` avoids cancellation). Any ``θ``. Shape (..., 3) -> (..., 3, 3).
    """
    r = _as_array(r, 3, "matrix_from_rotvec")
    theta = _norm(r)
    small = theta < SMALL_ANGLE
    safe = np.where(small, 1.0, theta)
    t2 = theta * theta
    a = np.where(small, 1.0 - t2 / 6.0 + t2 * t2 / 120.0, np.sin(safe) / safe)
    h = _sin_half_over_angle(theta)
    b = 2.0 * h * h
    k = skew(r)
    kk = k @ k
    return np.eye(3) + a[..., None, None] * k + b[..., None, None] * kk


def exp_so3(omega) -> np.ndarray:
    """Exponential map so(3) -> SO(3), ``R = exp([ω]×)`` by Rodrigues' formula (eq. 11, 12).

    Shape (..., 3) -> (..., 3, 3); any ``‖ω‖`` (same as :func:`matrix_from_rotvec`).
    """
    return matrix_from_rotvec(omega)


def matrix_from_quat(q) -> np.ndarray:
    """Rotation matrix of a quaternion (x, y, z, w; normalised first). Shape (..., 4) -> (..., 3, 3).

    ``R = (w² − v·v) I + 2 v vᵀ + 2 w [v]×``.
    """
    q = quat_normalize(q)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz = x * y, x * z, y * z
    wx, wy, wz = w * x, w * y, w * z
    rows = [
        [1 - 2 * (yy + zz), 2 * (xy - wz), 2 * (xz + wy)],
        [2 * (xy + wz), 1 - 2 * (xx + zz), 2 * (yz - wx)],
        [2 * (xz - wy), 2 * (yz + wx), 1 - 2 * (xx + yy)],
    ]
    return np.stack([np.stack(row, axis=-1) for row in rows], axis=-2)


def quat_from_matrix(R) -> np.ndarray:
    """Unit quaternion (x, y, z, w), ``w >= 0``, of a rotation matrix; Shepperd's method.

    Of the four expressions ``4w² = 1 + tr R``, ``4x² = 1 + 2R₀₀ − tr R``, ... the largest is
    used, and the other three components come from sums and differences of off-diagonal
    elements, so no square root of a small number is ever taken (accurate at θ ≈ π, where
    ``tr R ≈ −1``). A slightly non-orthogonal ``R`` gives the nearest such quaternion, normalised.
    Shape (..., 3, 3) -> (..., 4).
    """
    R = _as_matrix(R, "quat_from_matrix")
    r00, r11, r22 = R[..., 0, 0], R[..., 1, 1], R[..., 2, 2]
    tr = r00 + r11 + r22
    # Candidates (each is 4·q·q_i for its pivot i), stacked on axis −2: pivot x, y, z, w.
    cand_x = np.stack([1 + 2 * r00 - tr, R[..., 1, 0] + R[..., 0, 1],
                       R[..., 2, 0] + R[..., 0, 2], R[..., 2, 1] - R[..., 1, 2]], axis=-1)
    cand_y = np.stack([R[..., 1, 0] + R[..., 0, 1], 1 + 2 * r11 - tr,
                       R[..., 2, 1] + R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0]], axis=-1)
    cand_z = np.stack([R[..., 2, 0] + R[..., 0, 2], R[..., 2, 1] + R[..., 1, 2],
                       1 + 2 * r22 - tr, R[..., 1, 0] - R[..., 0, 1]], axis=-1)
    cand_w = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0],
                       R[..., 1, 0] - R[..., 0, 1], 1 + tr], axis=-1)
    cands = np.stack([cand_x, cand_y, cand_z, cand_w], axis=-2)
    pivot = np.argmax(np.stack([r00, r11, r22, tr], axis=-1), axis=-1)
    q = np.take_along_axis(cands, pivot[..., None, None], axis=-2)[..., 0, :]
    return quat_canonical(quat_normalize(q))


def rotvec_from_matrix(R) -> np.ndarray:
    """Canonical rotation vector of a rotation matrix (eq. 6, 7), via :func:`quat_from_matrix`.

    Robust at θ ≈ π (no ``acos((tr R − 1)/2)``). Shape (..., 3, 3) -> (..., 3).
    """
    return rotvec_from_quat(quat_from_matrix(R))


def log_so3(R) -> np.ndarray:
    """Logarithm SO(3) -> canonical ball B̃π (inverse of eq. 11, 12). Shape (..., 3, 3) -> (..., 3)."""
    return rotvec_from_matrix(R)


# ----------------------------------------------------------------------------------------------
# Acting on vectors (eq. 12, 17)
# ----------------------------------------------------------------------------------------------


def rotate(q, x) -> np.ndarray:
    """Rotate vectors by quaternions: ``x' = q ⊗ (x, 0) ⊗ q*``, i.e. ``R(q) x``.

    ``x' = x + 2w (v × x) + 2 v × (v × x)`` for unit ``q = (v, w)`` (``q`` is normalised first).
    Shapes (..., 4) and (..., 3), broadcast; returns (..., 3).
    """
    q = quat_normalize(q)
    x = _as_array(x, 3, "rotate x")
    v, w = q[..., :3], q[..., 3:]
    t = 2.0 * np.cross(v, x)
    return x + w * t + np.cross(v, t)


def apply_rotvec(r, x) -> np.ndarray:
    """Rodrigues' formula on vectors (eq. 12, 17): ``R(θu) x = x cos θ + sin θ (u × x) + u (u·x)(1 − cos θ)``.

    Written as ``x + A (r × x) + B r × (r × x)`` with the coefficients of
    :func:`matrix_from_rotvec` (series below ``SMALL_ANGLE``). Shapes (..., 3), broadcast.
    """
    r = _as_array(r, 3, "apply_rotvec r")
    x = _as_array(x, 3, "apply_rotvec x")
    theta = _norm(r)
    small = theta < SMALL_ANGLE
    safe = np.where(small, 1.0, theta)
    t2 = theta * theta
    a = np.where(small, 1.0 - t2 / 6.0 + t2 * t2 / 120.0, np.sin(safe) / safe)[..., None]
    h = _sin_half_over_angle(theta)
    b = (2.0 * h * h)[..., None]
    rx = np.cross(r, x)
    return x + a * rx + b * np.cross(r, rx)


# ----------------------------------------------------------------------------------------------
# Interpolation
# ----------------------------------------------------------------------------------------------


def slerp(q0, q1, s) -> np.ndarray:
    """Spherical linear interpolation along the shortest arc from ``q0`` (s = 0) to ``q1`` (s = 1).

    ``q1`` is first flipped to ``⟨q0, q1⟩ >= 0``; then ``q(s) = q0 ⊗ exp(s · log(q0* ⊗ q1))``, which
    equals ``(sin((1−s)Ω) q0 + sin(sΩ) q1)/sin Ω`` but stays exact when ``q0 ≈ q1`` (Ω -> 0: the
    series in exp/log replace the 0/0). The result keeps the sign of ``q0`` (continuous in ``s``,
    not canonicalised; ``s = 0`` returns the normalised ``q0``). Rotations exactly π apart have
    two shortest arcs; one of them is taken.

    Shapes: ``q0``, ``q1`` (..., 4) (x, y, z, w; normalised here); ``s`` broadcast against their
    leading axes (a scalar, or e.g. shape (T,) with ``q0``, ``q1`` of shape (4,) or (T, 4)).
    Returns shape ``broadcast(q0.shape[:-1], q1.shape[:-1], s.shape) + (4,)``.
    """
    q0 = quat_normalize(q0)
    q1 = quat_normalize(q1)
    s = np.asarray(s, dtype=np.float64)
    q1 = q1 * np.where(np.sum(q0 * q1, axis=-1, keepdims=True) < 0, -1.0, 1.0)
    delta = quat_multiply(quat_conjugate(q0), q1)  # scalar part ⟨q0, q1⟩ >= 0
    phi = _log_quat_unit(quat_normalize(delta))  # θ <= π, no tie-break
    return quat_multiply(q0, exp_quat(s[..., None] * phi))


# ----------------------------------------------------------------------------------------------
# Euler angles (scipy semantics)
# ----------------------------------------------------------------------------------------------

_AXIS_INDEX = {"x": 0, "y": 1, "z": 2}


def _parse_order(order: str) -> tuple[list[int], bool]:
    """Axis indices and ``extrinsic`` flag of an Euler sequence such as 'xyz', 'ZYX', 'zyz'."""
    if not isinstance(order, str) or len(order) != 3:
        raise ValueError(f"Euler order must be 3 letters such as 'xyz' or 'ZYX', got {order!r}")
    extrinsic = re.fullmatch(r"[xyz]{3}", order) is not None
    intrinsic = re.fullmatch(r"[XYZ]{3}", order) is not None
    if not (extrinsic or intrinsic):
        raise ValueError(
            f"Euler order must use only x, y, z (extrinsic) or only X, Y, Z (intrinsic), got {order!r}"
        )
    if order[0] == order[1] or order[1] == order[2]:
        raise ValueError(f"Euler order must not repeat an axis consecutively, got {order!r}")
    return [_AXIS_INDEX[c] for c in order.lower()], extrinsic


def quat_from_euler(angles, order: str, degrees: bool = False) -> np.ndarray:
    """Quaternion (x, y, z, w; ``w >= 0``) from Euler angles, scipy ``Rotation.from_euler`` semantics.

    ``order``: three letters from x, y, z, lowercase for extrinsic (rotations about the fixed
    world axes) or uppercase for intrinsic (about the rotating body axes); any of the 12
    sequences, Tait–Bryan ('xyz') or proper Euler ('zyz'). With elementary quaternions
    ``q_i(α) = (sin(α/2) e_i, cos(α/2))``::

        extrinsic 'abc', angles (α, β, γ):  q = q_c(γ) ⊗ q_b(β) ⊗ q_a(α)
        intrinsic 'ABC', angles (α, β, γ):  q = q_a(α) ⊗ q_b(β) ⊗ q_c(γ)

    Shape (..., 3) -> (..., 4); ``degrees=True`` reads the angles in degrees.
    """
    axes, extrinsic = _parse_order(order)
    angles = _as_array(angles, 3, "quat_from_euler angles")
    if degrees:
        angles = np.deg2rad(angles)
    elem = []
    for n, axis in enumerate(axes):
        half = 0.5 * angles[..., n]
        qe = np.zeros(angles.shape[:-1] + (4,))
        qe[..., axis] = np.sin(half)
        qe[..., 3] = np.cos(half)
        elem.append(qe)
    if extrinsic:
        q = quat_multiply(elem[2], quat_multiply(elem[1], elem[0]))
    else:
        q = quat_multiply(elem[0], quat_multiply(elem[1], elem[2]))
    return quat_canonical(q)


def euler_from_quat(q, order: str, degrees: bool = False) -> np.ndarray:
    """Euler angles of quaternions (x, y, z, w), scipy ``Rotation.as_euler`` semantics.

    ``order`` as in :func:`quat_from_euler`. Ranges: first and third angle in [−π, π), the
    second in [0, π] (proper Euler, e.g. 'zyz') or [−π/2, π/2] (Tait–Bryan, e.g. 'xyz').
    At gimbal lock (second angle within 1e-7 rad of 0 or π for proper Euler, ±π/2 for
    Tait–Bryan) the third angle is set to 0 and the first carries the whole rotation about the
    locked axis, as scipy does (no warning is issued).

    Method: Bernardes & Viollet (2022), the direct quaternion-to-Euler conversion that works for
    every sequence: permute (and for Tait–Bryan, mix) the components into (a, b, c, d), then
    ``θ2 = 2·atan2(hypot(c, d), hypot(a, b))``, ``θ1, θ3 = atan2(b, a) ∓ atan2(d, c)``.
    Shape (..., 4) -> (..., 3).
    """
    axes, extrinsic = _parse_order(order)
    q = quat_normalize(q)
    i, j, k = axes if extrinsic else axes[::-1]
    proper = i == k
    if proper:
        k = 3 - i - j
    sign = float((i - j) * (j - k) * (k - i) // 2)  # +1 for an even permutation (i, j, k)
    qi, qj, qk, qw = q[..., i], q[..., j], q[..., k], q[..., 3]
    if proper:
        a, b, c, d = qw, qi, qj, qk * sign
    else:
        a, b, c, d = qw - qj, qi + qk * sign, qj + qw, qk * sign - qi
    half_sum = np.arctan2(b, a)
    half_diff = np.arctan2(d, c)
    second = 2.0 * np.arctan2(np.hypot(c, d), np.hypot(a, b))
    eps = 1e-7
    lock0 = np.abs(second) <= eps
    lockpi = np.abs(second - np.pi) <= eps
    regular = ~(lock0 | lockpi)
    # Gimbal lock: all of the rotation about the locked axis goes into the first angle (in the
    # order given), the third is 0.
    locked_first = np.where(lock0, 2.0 * half_sum, 2.0 * half_diff * (-1.0 if extrinsic else 1.0))
    first_in_seq = np.where(regular, half_sum - half_diff, locked_first if extrinsic else 0.0)
    third_in_seq = np.where(regular, half_sum + half_diff, 0.0 if extrinsic else locked_first)
    if not proper:
        third_in_seq = third_in_seq * sign
        second = second - np.pi / 2
    # (first_in_seq, third_in_seq) refer to the reversed sequence for intrinsic orders
    if extrinsic:
        out = np.stack([first_in_seq, second, third_in_seq], axis=-1)
    else:
        out = np.stack([third_in_seq, second, first_in_seq], axis=-1)
    out = (out + np.pi) % (2 * np.pi) - np.pi
    return np.rad2deg(out) if degrees else out


def matrix_from_euler(angles, order: str, degrees: bool = False) -> np.ndarray:
    """Rotation matrix from Euler angles (scipy semantics, see :func:`quat_from_euler`).

    Shape (..., 3) -> (..., 3, 3).
    """
    return matrix_from_quat(quat_from_euler(angles, order, degrees=degrees))


def euler_from_matrix(R, order: str, degrees: bool = False) -> np.ndarray:
    """Euler angles of rotation matrices (scipy semantics, see :func:`euler_from_quat`).

    Shape (..., 3, 3) -> (..., 3).
    """
    return euler_from_quat(quat_from_matrix(R), order, degrees=degrees)


# ----------------------------------------------------------------------------------------------
# Random rotations
# ----------------------------------------------------------------------------------------------


def random_quat(rng: np.random.Generator, shape=()) -> np.ndarray:
    """Rotations drawn uniformly (Haar measure) from SO(3), as unit quaternions (x, y, z, w), ``w >= 0``.

    A normalised 4-D standard normal vector is uniform on S³, hence its rotation is uniform on
    SO(3). ``rng`` is a ``numpy.random.Generator``; ``shape`` an int or tuple (leading axes).
    Returns shape ``shape + (4,)``.
    """
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"random_quat: rng must be a numpy.random.Generator, got {type(rng).__name__}")
    shape = (shape,) if np.ndim(shape) == 0 else tuple(shape)
    g = rng.standard_normal(shape + (4,))
    n = _norm(g)[..., None]
    # a standard normal vector is 0 with probability 0; guard anyway
    g = np.where(n > 0, g / np.where(n > 0, n, 1.0), np.array([0.0, 0.0, 0.0, 1.0]))
    return g * np.where(g[..., 3:] < 0, -1.0, 1.0)
