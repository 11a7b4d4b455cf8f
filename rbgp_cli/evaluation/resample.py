"""Resampling to a common length, the mean rotation per step, and tangent-space features (docs/method.md §9).

The evaluation compares distributions of poses *at the same phase* of the motion. Every
trajectory is therefore put on normalised time

    s = (t − t_0) / (t_end − t_0) ∈ [0, 1]

and resampled at ``T`` equally spaced values ``s_j = j / (T − 1)``: rotation by slerp between the
two neighbouring samples (shortest arc), translation linearly. The paper (sec. 4.3) resamples to a
common 3.5 s; normalised time is the same thing without a unit.

At each step the demonstrations' mean rotation R̄_t (the chordal mean, the normalised principal
eigenvector of Σ_m q_m q_mᵀ) is the point of tangency of the rotation features

    x = (log(R̄_tᵀ R), p)    shape (6,) = (rx, ry, rz, x, y, z), rotation first,

so the rotation part is a small vector near 0 wherever the demonstrations are (no jump at θ = π)
and does not change when the world frame is rotated (R̄ → R_w R̄, R → R_w R leave R̄ᵀR alone).

Conventions: quaternions x, y, z, w (scalar last), rotation body -> world; positions in metres;
angles in radians; arrays float64. Everything is vectorised over samples and steps (the only
Python loop is over the handful of trajectories in :func:`resample_all`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from rbgp_cli.dynamics.trajectory import Trajectory, interpolate_poses
from rbgp_cli.errors import InputError
from rbgp_cli.geometry.so3 import (
    log_quat,
    quat_canonical,
    quat_conjugate,
    quat_make_continuous,
    quat_multiply,
    quat_normalize,
)

__all__ = ["resample", "resample_all", "mean_rotation", "tangent_features", "normalised_time"]


def _label(traj: Trajectory) -> str:
    """``'name'`` or ``'(unnamed)'`` for messages; the source goes into the error's ``path``."""
    return repr(traj.name) if traj.name else "(unnamed)"


def _check_length(T) -> int:
    """``T`` as an int >= 2 (InputError otherwise)."""
    if isinstance(T, bool) or not isinstance(T, (int, np.integer)):
        raise InputError(f"the number of resampled steps must be an integer, got {T!r}")
    if T < 2:
        raise InputError(f"cannot resample to {T} step(s)", hint="use a length of at least 2")
    return int(T)


def normalised_time(T: int) -> np.ndarray:
    """The T equally spaced steps of normalised time ``s_j = j/(T − 1)``, shape (T,); s_0 = 0, s_{T−1} = 1."""
    return np.linspace(0.0, 1.0, _check_length(T))


def _check_trajectory(traj: Trajectory) -> None:
    """At least two samples, finite values, strictly increasing times (InputError naming the trajectory)."""
    path = traj.source or None
    n = len(traj)
    if n < 2:
        raise InputError(
            f"trajectory {_label(traj)} has {n} sample(s); resampling needs at least 2",
            path=path,
            hint="drop it or record a longer motion",
        )
    finite = np.isfinite(traj.t).all() and np.isfinite(traj.quat).all() and np.isfinite(traj.position).all()
    if not finite:
        raise InputError(
            f"trajectory {_label(traj)} contains non-finite values (lost frames?)",
            path=path,
            hint="drop or repair those samples first (e.g. rbgp_cli.dynamics.prepare.prepare_trajectory)",
        )
    if not np.all(np.diff(traj.t) > 0):
        raise InputError(
            f"trajectory {_label(traj)} has times that are not strictly increasing",
            path=path,
            hint="sort it and remove duplicate time stamps first (prepare_trajectory does this)",
        )
    if np.any(np.einsum("ij,ij->i", traj.quat, traj.quat) == 0):
        raise InputError(f"trajectory {_label(traj)} has a zero quaternion (no rotation)", path=path)


def resample(traj: Trajectory, T: int) -> tuple[np.ndarray, np.ndarray]:
    """Resample a trajectory to ``T`` equally spaced steps of normalised time (docs/method.md §9).

    With samples ``(t_k, q_k, p_k)``, ``k = 0..N−1``, normalised times ``σ_k = (t_k − t_0)/(t_{N−1} − t_0)``
    and targets ``s_j = j/(T − 1)``: find ``k`` with ``σ_k <= s_j <= σ_{k+1}``, ``f = (s_j − σ_k)/(σ_{k+1} − σ_k)``,

        q(s_j) = slerp(q_k, q_{k+1}; f) = q_k ⊗ exp(f · log(q_k* ⊗ q_{k+1}))   (shortest arc)
        p(s_j) = (1 − f) p_k + f p_{k+1}

    The input quaternions are normalised and made sign-continuous first (so a canonicalised
    recording that flips q -> −q when it crosses θ = π is harmless); the output is sign-continuous
    (⟨q_j, q_{j−1}⟩ >= 0) and keeps the sign of the (normalised) first sample. The endpoints are
    exact: ``s = 0`` gives the first sample and ``s = 1`` the last one (normalised), bit for bit.

    Parameters
    ----------
    traj : Trajectory
        Clean trajectory (t (N,) strictly increasing, quat (N, 4) x, y, z, w, position (N, 3) m),
        N >= 2.
    T : int
        Number of output steps, >= 2.

    Returns
    -------
    quat : ndarray, shape (T, 4)
        Unit quaternions x, y, z, w, sign-continuous.
    position : ndarray, shape (T, 3)
        Metres.

    Raises
    ------
    InputError
        Fewer than 2 samples, non-finite values, times not strictly increasing, zero quaternions, or
        ``T < 2``; the message names the trajectory (``traj.source`` as the path, ``traj.name``).
    """
    T = _check_length(T)
    _check_trajectory(traj)
    t = traj.t
    sigma = (t - t[0]) / (t[-1] - t[0])  # (N,), σ_0 = 0 and σ_{N−1} = 1 exactly
    q = quat_make_continuous(quat_normalize(traj.quat))  # (N, 4)
    p = traj.position  # (N, 3)
    s = np.linspace(0.0, 1.0, T)  # (T,)
    return interpolate_poses(sigma, q, p, s)  # endpoints exact: σ_0 = s_0 = 0, σ_{N−1} = s_{T−1} = 1


def resample_all(trajs: Sequence[Trajectory], T: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`resample` every trajectory to ``T`` steps and stack them.

    Returns ``quat`` of shape (M, T, 4) (x, y, z, w; each row sign-continuous along T) and
    ``position`` of shape (M, T, 3) (metres), M = ``len(trajs)`` >= 1.
    """
    trajs = list(trajs)
    if not trajs:
        raise InputError("no trajectories to resample")
    parts = [resample(tr, T) for tr in trajs]  # a loop over trajectories, not samples
    return np.stack([a for a, _ in parts]), np.stack([b for _, b in parts])


def mean_rotation(quat) -> np.ndarray:
    """Chordal mean rotation per step: the principal eigenvector of ``Σ_m q_m q_mᵀ`` (docs/method.md §9).

    For each step t, the unit quaternion q̄_t maximising ``Σ_m ⟨q̄, q_{m,t}⟩²`` is the normalised
    eigenvector of the largest eigenvalue of the 4×4 matrix ``A_t = Σ_m q_{m,t} q_{m,t}ᵀ``; its
    rotation minimises the sum of squared chordal distances ``Σ_m d_ch(R̄, R_m)²`` (docs/method.md §5:
    ``d_ch² = 4(1 − ⟨q̄, q⟩²)``). ``q qᵀ`` does not change under ``q -> −q``, so the result does not
    depend on the input signs (bit for bit). It is equivariant: rotating all inputs by a fixed
    ``R_w`` on the left rotates the mean the same way. (Markley et al., "Averaging quaternions",
    J. Guidance, Control, and Dynamics 30(4), 2007.)

    One batched ``numpy.linalg.eigh`` over the T steps. The sign of the output is chosen
    continuous over t (``⟨q̄_t, q̄_{t−1}⟩ >= 0``) with ``w >= 0`` at t = 0. If the largest
    eigenvalue is repeated (e.g. two rotations exactly π apart) the mean is not unique and one of
    the candidates is returned. Example: for ``R̄ exp(±δ)`` the eigenvalues are ``2cos²(‖δ‖/2)``
    (vector q̄) and ``2sin²(‖δ‖/2)`` (vector ``q̄ ⊗ (u, 0)``), so the mean is R̄ for ``‖δ‖ < π/2``
    and the other midpoint ``R̄ exp(π u)`` of the two rotations' geodesic circle beyond.

    Parameters
    ----------
    quat : array-like, shape (M, T, 4)
        M rotations at each of T steps, quaternions x, y, z, w (normalised here).

    Returns
    -------
    ndarray, shape (T, 4)
        Unit quaternions x, y, z, w.
    """
    q = np.asarray(quat, dtype=np.float64)
    if q.ndim != 3 or q.shape[-1] != 4 or q.shape[0] < 1:
        raise ValueError(f"mean_rotation: expected shape (M, T, 4) with M >= 1, got {q.shape}")
    q = quat_normalize(q)
    A = np.einsum("mti,mtj->tij", q, q)  # (T, 4, 4), symmetric PSD
    _, vecs = np.linalg.eigh(A)  # eigenvalues ascending
    mean = vecs[:, :, -1]  # (T, 4), unit
    mean = quat_make_continuous(mean)
    first = mean[0]
    flip = -1.0 if np.dot(quat_canonical(first), first) < 0 else 1.0
    return mean * flip


def tangent_features(quat, position, ref) -> np.ndarray:
    """Features in the tangent space at the reference rotation: ``x = (log(R̄_tᵀ R), p)`` (docs/method.md §9).

    The rotation part is the canonical rotation vector of ``conj(q̄_t) ⊗ q`` (the rotation taking
    R̄_t to R, expressed in the reference's body frame: ``R = R̄_t exp([x_r]×)``), in the closed ball
    of radius π; the translation part is the position as is. ``x_r`` is 0 for ``R = R̄_t`` and
    does not depend on the signs of ``q`` or ``q̄``.

    Parameters
    ----------
    quat : array-like, shape (M, T, 4)
        Rotations, quaternions x, y, z, w.
    position : array-like, shape (M, T, 3)
        Positions, metres.
    ref : array-like, shape (T, 4)
        Reference rotation per step (e.g. :func:`mean_rotation` of the demonstrations).

    Returns
    -------
    ndarray, shape (M, T, 6)
        ``(rx, ry, rz, x, y, z)``: radians (rotation vector), metres.
    """
    q = np.asarray(quat, dtype=np.float64)
    p = np.asarray(position, dtype=np.float64)
    r = np.asarray(ref, dtype=np.float64)
    if q.ndim != 3 or q.shape[-1] != 4:
        raise ValueError(f"tangent_features: quat must have shape (M, T, 4), got {q.shape}")
    if p.shape != q.shape[:2] + (3,):
        raise ValueError(f"tangent_features: position must have shape {q.shape[:2] + (3,)}, got {p.shape}")
    if r.shape != (q.shape[1], 4):
        raise ValueError(f"tangent_features: ref must have shape ({q.shape[1]}, 4), got {r.shape}")
    rel = quat_multiply(quat_conjugate(quat_normalize(r))[None], quat_normalize(q))  # (M, T, 4)
    return np.concatenate([log_quat(rel), p], axis=-1)
