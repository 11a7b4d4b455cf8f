"""Velocities of a demonstration by forward differences (docs/method.md §4, paper sec. 2 and 4.3).

For samples (t_k, R_k, p_k), k = 0..N−1, strictly increasing t:

    ω_k = log(R_{k+1} R_kᵀ) / Δt_k        (world-frame angular velocity, rad/s)
    v_k = (p_{k+1} − p_k) / Δt_k          (world-frame velocity of the body origin, m/s)

Training pairs are (g_k, ξ_k), k = 0..N−2. Integrating ξ_k with
:func:`rbgp_cli.geometry.se3.integrate_quat` reproduces the samples to round-off, also across θ = π,
because rotation vectors and Euler angles are never differenced directly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rbgp_cli.dynamics.trajectory import Trajectory
from rbgp_cli.errors import InputError
from rbgp_cli.geometry.so3 import exp_quat, log_quat, quat_conjugate, quat_make_continuous, quat_multiply

__all__ = [
    "forward_differences", "MAX_STEP_ANGLE", "VelocityOptions", "VelocitySegment", "estimate_velocities",
    "local_polynomial", "integration_drift", "window_problem", "SEGMENT_GAP_FACTOR",
    "segment_split",
]

#: A step rotating by (nearly) π cannot tell its direction: the sampling is too coarse (docs/method.md §4).
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


# ---------------------------------------------------------------------------------------------
# Velocities from real motion capture (docs/method.md §4.1): resampling and local-polynomial derivatives
# ---------------------------------------------------------------------------------------------

#: A step between consecutive clean samples longer than this many times the demonstration's median
#: step (or than two training steps, whichever is longer) splits the demonstration into segments:
#: no training pair is made across it (lost tracking, or a hold the tracker repeated).
SEGMENT_GAP_FACTOR = 4.0


#: The longest smoothing window accepted (s): far beyond any motion, and short enough for the local fit's
#: scaled times not to underflow.
MAX_WINDOW = 1e6


@dataclass(frozen=True)
class VelocityOptions:
    """How training velocities are estimated from a demonstration (docs/method.md §4, §4.1).

    rate : Hz, or None. Resample each demonstration on a uniform grid of spacing h = 1/rate
        (slerp / linear) before estimating velocities; the rollout step follows it. None keeps the
        recorded samples (and their median step).
    window : seconds. 0: forward differences (exact integration back to the samples). > 0: a local
        polynomial of ``degree`` fitted over this window around each training time, in the
        rotation's tangent space (Savitzky–Golay type): smoothed poses and instantaneous velocities.
    degree : polynomial degree of the local fit (1–4; 2 is the usual choice).
    """

    rate: float | None = None
    window: float = 0.0
    degree: int = 2

    def __post_init__(self):
        if self.rate is not None and not (math.isfinite(self.rate) and self.rate > 0):
            raise InputError(f"the training rate must be a positive number of Hz, got {self.rate}")
        if not (math.isfinite(self.window) and 0 <= self.window <= MAX_WINDOW):  # beyond it the fit's times underflow
            raise InputError(f"the smoothing window (smooth_window) must be a number of seconds from 0 to {MAX_WINDOW:g}, "
                             f"got {self.window}", param="smooth_window")
        if not (isinstance(self.degree, (int, np.integer)) and 1 <= self.degree <= 4):
            raise InputError(f"the local polynomial degree must be 1, 2, 3 or 4, got {self.degree}")

    @property
    def method(self) -> str:
        return "local-polynomial" if self.window > 0 else "forward-differences"

    def to_dict(self) -> dict:
        return {"rate_hz": self.rate, "window_s": self.window, "degree": int(self.degree), "method": self.method}


@dataclass(frozen=True)
class VelocitySegment:
    """Training samples of one gap-free stretch of a demonstration.

    traj : the (resampled and, with a window, smoothed) poses, t (K,), quat (K, 4) x, y, z, w
        sign-continuous, position (K, 3)
    xi : world-frame velocities (ω, v), shape (K−1, 6) for forward differences (ξ_k carries pose k
        to pose k+1 exactly) or (K, 6) for instantaneous local-polynomial velocities
    t0 : the demonstration's first time (so ``traj.t − t0`` is the time since the start)
    """

    traj: Trajectory
    xi: np.ndarray
    t0: float = 0.0

    @property
    def differences(self) -> bool:
        return len(self.xi) == len(self.traj) - 1


def segment_split(t: np.ndarray, rate: float | None = None) -> float:
    """Seconds: a step of a clean demonstration longer than this separates velocity segments (no
    training pair crosses it): max(SEGMENT_GAP_FACTOR × the median step, two training steps 2/rate)."""
    med = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    return max(SEGMENT_GAP_FACTOR * med, 2.0 / rate if rate else 0.0)


def _segments(t: np.ndarray, split: float) -> list[tuple[int, int]]:
    """Index ranges [a, b) of stretches without a step longer than ``split`` seconds."""
    cuts = np.flatnonzero(np.diff(t) > split) + 1
    bounds = np.concatenate([[0], cuts, [len(t)]])
    return [(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:])]


def _grid(t_start: float, t_end: float, rate: float | None, t: np.ndarray) -> np.ndarray:
    """Training times: the samples themselves (rate None) or t_start + k/rate up to t_end."""
    if rate is None:
        return t
    span = (t_end - t_start) * rate
    if not math.isfinite(span):  # a rate near the largest double: no grid at all
        raise InputError(f"a training rate of {rate:g} Hz is too high for a {t_end - t_start:g} s demonstration",
                         hint="use a rate near the recorded one (train_rate 10 is the default)", param="train_rate")
    n = int(math.floor(span + 1e-9))
    return t_start + np.arange(n + 1) / rate


def local_polynomial(t: np.ndarray, quat: np.ndarray, position: np.ndarray, times: np.ndarray,
                     window: float, degree: int = 2):
    """Smoothed poses and world-frame velocities at ``times`` by local polynomial fits on SE(3).

    For each target time τ (docs/method.md §4.1): the window W = the samples within ``window`` seconds
    centred on τ (shifted inside [t_0, t_{N−1}] near the ends, i.e. one-sided there); the reference
    rotation R_τ by slerp between the samples around τ; tangent coordinates φ_j = log(R_j R_τᵀ)
    (world-frame rotation vectors, small because the window is short); least-squares polynomials
    φ̂(s), p̂(s) of ``degree`` in s = t_j − τ. Then

        R̂(τ) = exp(φ̂(0)) R_τ,  p̂(τ) = p̂(0),  ω = J_l(φ̂(0)) φ̂'(0),  v = p̂'(0),

    with J_l the left Jacobian of SO(3). Exact for a rotation about a fixed axis by a polynomial
    angle and a polynomial translation of degree <= ``degree`` (also through θ = π: only relative
    rotations inside the window are logged).

    Shapes: t (N,) strictly increasing, quat (N, 4) x, y, z, w sign-continuous, position (N, 3),
    times (K,) inside [t_0, t_{N−1}]. Returns (quat (K, 4), position (K, 3), xi (K, 6), ok (K,)):
    ``ok`` is False where the window holds fewer than degree + 1 samples (those rows are NaN).
    """
    from rbgp_cli.dynamics.trajectory import interpolate_poses
    from rbgp_cli.geometry.se3 import _left_jacobian_coeffs

    t = np.asarray(t, dtype=np.float64)
    times = np.asarray(times, dtype=np.float64)
    half = 0.5 * window
    lo = np.clip(times - half, t[0], max(t[0], t[-1] - window))
    hi = lo + window
    a = np.searchsorted(t, lo - 1e-12 * max(1.0, abs(t[-1])), side="left")
    b = np.searchsorted(t, hi + 1e-12 * max(1.0, abs(t[-1])), side="right")
    count = b - a  # (K,)
    M = int(max(1, count.max()))
    idx = a[:, None] + np.arange(M)[None, :]  # (K, M)
    mask = idx < b[:, None]
    idx = np.minimum(idx, len(t) - 1)
    q_ref, _ = interpolate_poses(t, quat, position, times)  # (K, 4)
    rel = quat_multiply(quat[idx], quat_conjugate(q_ref)[:, None, :])  # R_j R_τᵀ, (K, M, 4)
    phi = log_quat(rel)  # (K, M, 3)
    s = (t[idx] - times[:, None]) / max(half, 1e-12)  # scaled for conditioning, (K, M)
    V = s[..., None] ** np.arange(degree + 1)  # (K, M, d+1)
    V = V * mask[..., None]
    Y = np.concatenate([phi, position[idx]], axis=-1) * mask[..., None]  # (K, M, 6)
    A = np.einsum("kmi,kmj->kij", V, V)  # (K, d+1, d+1)
    rhs = np.einsum("kmi,kmc->kic", V, Y)  # (K, d+1, 6)
    ok = count >= degree + 1
    A[~ok] = np.eye(degree + 1)
    coef = np.linalg.solve(A, rhs)  # (K, d+1, 6)
    c0, c1 = coef[:, 0, :], coef[:, 1, :] / max(half, 1e-12)
    phi0, dphi = c0[:, :3], c1[:, :3]
    theta = np.linalg.norm(phi0, axis=-1)
    B, C = _left_jacobian_coeffs(theta)
    cross1 = np.cross(phi0, dphi)
    omega = dphi + B[:, None] * cross1 + C[:, None] * np.cross(phi0, cross1)  # J_l(φ̂(0)) φ̂'(0)
    q_hat = quat_multiply(exp_quat(phi0), q_ref)
    xi = np.concatenate([omega, c1[:, 3:]], axis=-1)
    bad = ~ok
    if bad.any():
        q_hat[bad] = np.nan
        xi[bad] = np.nan
    return q_hat, c0[:, 3:], xi, ok


def estimate_velocities(traj: Trajectory, options: VelocityOptions | None = None) -> list[VelocitySegment]:
    """Training samples of a clean demonstration: poses and world-frame velocities (docs/method.md §4, §4.1).

    1. Split at gaps (a step longer than SEGMENT_GAP_FACTOR × the median step, or than two training
       steps): lost tracking that was dropped, or a tracker hold turned into lost frames by
       :func:`~rbgp_cli.dynamics.prepare.prepare_trajectory`. No pair crosses a gap.
    2. Training times per segment: its samples, or a uniform grid of spacing 1/``rate``.
    3. Forward differences (``window`` 0) of the poses at those times (resampled by slerp / linear
       interpolation): ξ_k = (log(R_{k+1} R_kᵀ)/h, (p_{k+1} − p_k)/h); or local polynomial fits
       (:func:`local_polynomial`) giving smoothed poses and instantaneous velocities.

    Returns the segments with at least one training pair (a list, possibly empty).
    """
    options = options or VelocityOptions()
    t = traj.t
    if len(t) < 2:
        raise InputError(f"needs at least 2 samples for a velocity, has {len(t)}", path=traj.source or traj.name or None)
    q = quat_make_continuous(traj.quat)
    split = segment_split(t, options.rate)
    out = []
    for a, b in _segments(t, split):
        ts, qs, ps = t[a:b], q[a:b], traj.position[a:b]
        if len(ts) < 2:
            continue
        grid = _grid(ts[0], ts[-1], options.rate, ts)
        if options.window > 0:
            qg, pg, xi, ok = local_polynomial(ts, qs, ps, grid, options.window, options.degree)
            if not ok.all():
                keep = ok
                grid, qg, pg, xi = grid[keep], qg[keep], pg[keep], xi[keep]
            if len(grid) < 1:
                continue
            seg = traj.with_(t=grid, quat=quat_make_continuous(qg), position=pg, info={})
        else:
            if len(grid) < 2:
                continue
            if options.rate is None:
                seg = traj.with_(t=ts, quat=qs, position=ps, info={})
            else:
                from rbgp_cli.dynamics.trajectory import interpolate_poses

                qg, pg = interpolate_poses(ts, qs, ps, grid)
                seg = traj.with_(t=grid, quat=qg, position=pg, info={})
            xi, _ = forward_differences(seg)
        out.append(VelocitySegment(seg, xi, float(t[0])))
    return out


def window_problem(trajs, options: VelocityOptions) -> str | None:
    """A message if ``options.window`` holds fewer than degree + 1 samples at the demonstrations'
    median rate (the fit would be undetermined everywhere), else None."""
    if options.window <= 0 or not trajs:
        return None
    med = float(np.median(np.concatenate([np.diff(tr.t) for tr in trajs if len(tr) > 1])))
    have = int(math.floor(options.window / med + 1e-9)) + 1
    if have < options.degree + 1:
        need = options.degree * med
        return (f"a smoothing window of {options.window:g} s holds {have} sample(s) at the demonstrations' "
                f"{1.0 / med:.4g} Hz; a degree-{options.degree} fit needs {options.degree + 1} "
                f"(a window of at least {need:.3g} s)")
    return None


def integration_drift(segments: list[VelocitySegment]) -> dict:
    """How far integrating the estimated velocities strays from the training poses (docs/method.md §4.1).

    Each segment is integrated from its first pose with its own steps
    (R_{k+1} = exp(ω_k h_k) R_k, p_{k+1} = p_k + v_k h_k); returns the largest position (m) and
    rotation (rad) error at the segment ends and over all samples, as plain data.
    Forward differences give round-off; local polynomial velocities a small lag.
    """
    from rbgp_cli.geometry.se3 import integrate_quat

    worst_p, worst_r = 0.0, 0.0
    for seg in segments:
        K = len(seg.traj)
        if K < 2:
            continue
        n = K - 1
        hs = np.diff(seg.traj.t)
        xi = seg.xi[:n]
        qq = np.empty((K, 4))
        pp = np.empty((K, 3))
        qq[0], pp[0] = seg.traj.quat[0], seg.traj.position[0]
        for k in range(n):  # a short sequential integration per segment (training-time report only)
            qq[k + 1], pp[k + 1] = integrate_quat(qq[k], pp[k], xi[k], hs[k])
        dq = quat_multiply(quat_conjugate(seg.traj.quat), qq)
        ang = 2.0 * np.arctan2(np.linalg.norm(dq[:, :3], axis=1), np.abs(dq[:, 3]))
        worst_r = max(worst_r, float(ang.max()))
        worst_p = max(worst_p, float(np.linalg.norm(pp - seg.traj.position, axis=1).max()))
    return {"max_position_m": worst_p, "max_rotation_rad": worst_r}
