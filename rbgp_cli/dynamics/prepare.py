"""Turn raw trajectories (as the readers return them) into clean ones, and say what was repaired.

A clean :class:`~rbgp_cli.dynamics.trajectory.Trajectory` has strictly increasing finite times, finite
positions (metres) and unit quaternions (x, y, z, w) that are continuous in sign, and no step rotates by
π or more (MATH.md §4). :func:`prepare_trajectory` gets there by

1. **lost frames**: rows with a non-finite value or an all-zero quaternion (norm < 1e-9; proto3 and
   foxglove default a missing quaternion to all zeros). They are dropped; with ``max_gap`` an interior
   run of lost frames is filled instead when the two valid samples around it are at most ``max_gap``
   seconds apart (slerp for the rotation, linear for the position, at the lost rows' own times);
2. **normalisation**: quaternions are divided by their norm; a norm further than ``unit_tolerance``
   from 1 is an error, because it means the columns are not a unit quaternion (wrong columns, order or
   units), not noise;
3. **time checks**: exact duplicate samples (same time, same pose) are dropped; the same time with a
   different pose, or time going backwards, is an error;
4. **sign continuity**: ``q`` and ``-q`` are the same rotation; each quaternion is flipped to the
   hemisphere of its predecessor (harmless, counted). The warning names what the data held
   (:func:`sign_change_note`): recorded quaternions that flip sign, a rotation vector that wrapped at
   π, Euler angles that wrapped at ±180°; for rotation matrices the sign is ours, so nothing is said;
5. **step check**: consecutive samples rotating by π or more relative to each other are an error
   (the sampling is too coarse to tell which way the body turned).

This module is core: it uses numpy and :mod:`rbgp_cli.errors` only.
"""

from __future__ import annotations

import numpy as np

from rbgp_cli.dynamics.trajectory import Trajectory
from rbgp_cli.errors import InputError, warn

__all__ = ["prepare_trajectory", "prepare_all", "lost_frame_mask", "line_of", "sign_change_note", "ZERO_QUAT_NORM",
           "STEP_LIMIT"]

#: A quaternion with a smaller norm is "no rotation recorded" (a lost frame), not a rotation.
ZERO_QUAT_NORM = 1e-9
#: Largest accepted rotation between consecutive samples (rad). The relative rotation of two unit
#: quaternions is at most π; within 1e-6 rad of π its direction is decided by rounding noise.
STEP_LIMIT = np.pi - 1e-6
#: Quaternion norm deviations above this are mentioned in the repair summary.
_NOTE_NORM = 1e-3


def lost_frame_mask(traj: Trajectory) -> np.ndarray:
    """Boolean mask, shape (N,): rows with a non-finite value or an all-zero quaternion."""
    finite = np.isfinite(traj.t) & np.all(np.isfinite(traj.quat), axis=1) & np.all(np.isfinite(traj.position), axis=1)
    with np.errstate(invalid="ignore"):
        norm = np.linalg.norm(np.where(np.isfinite(traj.quat), traj.quat, 0.0), axis=1)
    return ~(finite & (norm >= ZERO_QUAT_NORM))


def line_of(traj: Trajectory, k: int) -> int | None:
    """The file line of raw sample ``k`` (0-based) if the reader recorded where its rows are."""
    info = traj.info or {}
    if "first_data_line" in info:
        return int(info["first_data_line"]) + int(k)
    runs = info.get("line_runs")
    if runs:
        for first, count in runs:
            if k < count:
                return int(first) + int(k)
            k -= count
    return None


def sign_change_note(info: dict | None, count: int) -> str | None:
    """What ``count`` repaired quaternion sign changes mean for the user's data, or None to say nothing.

    The readers record the rotation columns in ``info["rotation"]`` (CSV, MCAP) or
    ``info["rotation_source"]`` (QTM, Motive, Vicon). A quaternion computed from a rotation vector
    r = θu with θ ≤ π changes sign when the recorded vector wraps from θ ≈ π to the opposite side
    (u → −u); one computed from Euler angles changes sign when an angle wraps at ±180°; recorded
    quaternions simply flip between q and −q. Quaternions computed from rotation matrices get their
    sign from the conversion (the matrix has none), so their sign changes say nothing about the data.
    """
    if not count:
        return None
    info = info or {}
    source = str(info.get("rotation_source") or info.get("rotation") or "quaternion").lower()
    times = f"{count} time{'s' * (count != 1)}"
    if "rotation vector" in source or "helical" in source or "rotvec" in source:
        return f"rotation vector wrapped at {'180°' if 'deg' in source else 'π'} {times}, repaired"
    if source.startswith("euler"):
        return f"Euler angles wrapped at {'±180°' if 'deg' in source else '±π'} {times}, repaired"
    if "matrix" in source:
        return None
    return f"fixed {count} quaternion sign flip{'s' * (count != 1)}"


def _where(traj: Trajectory, k: int) -> tuple[int | None, str]:
    """(file line or None, ``"sample 12 (t = 0.4 s)"``) for raw sample ``k`` (0-based); the line goes
    into the error's ``FILE:LINE:`` prefix."""
    t = traj.t[k]
    tt = f" (t = {t:.9g} s)" if np.isfinite(t) else ""
    return line_of(traj, k), f"sample {k + 1}{tt}"


def _error(traj: Trajectory, k: int, message: str, hint: str | None = None) -> InputError:
    line, where = _where(traj, k)
    label = f"{traj.name}: " if traj.name else ""
    return InputError(f"{label}{message.format(where=where)}", path=traj.source or None, row=line, hint=hint)


def _slerp(q0: np.ndarray, q1: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Spherical interpolation, shapes (K, 4), (K, 4), (K,): unit quaternions, same hemisphere."""
    dot = np.clip(np.sum(q0 * q1, axis=1), -1.0, 1.0)
    omega = np.arccos(dot)
    so = np.sin(omega)
    small = so < 1e-9
    safe = np.where(small, 1.0, so)
    w0 = np.where(small, 1.0 - u, np.sin((1.0 - u) * omega) / safe)
    w1 = np.where(small, u, np.sin(u * omega) / safe)
    q = w0[:, None] * q0 + w1[:, None] * q1
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def prepare_trajectory(
    traj: Trajectory, *, max_gap: float | None = None, unit_tolerance: float = 0.1
) -> tuple[Trajectory, dict]:
    """Clean a raw trajectory; return ``(clean, report)``.

    Parameters
    ----------
    traj : Trajectory
        Raw samples: t (N,) seconds, quat (N, 4) x, y, z, w (any norm, any sign), position (N, 3)
        metres; lost frames as NaN rows or all-zero quaternions.
    max_gap : float, optional
        Fill interior runs of lost frames when the valid samples around them are at most this many
        seconds apart (slerp / linear interpolation at the lost rows' times). Default: drop them.
    unit_tolerance : float
        Largest accepted ``| |q| - 1 |`` of a recorded quaternion before normalising.

    Returns
    -------
    clean : Trajectory
        Strictly increasing times, unit sign-continuous quaternions; ``info["repairs"]`` = report.
    report : dict
        Plain data: ``samples_in``, ``samples_out``, ``lost``, ``filled``, ``dropped`` (lost frames
        dropped), ``duplicates``, ``sign_flips``, ``max_norm_deviation``.

    Raises
    ------
    InputError
        Quaternion far from unit norm, duplicate time with a different pose, time going backwards,
        fewer than 2 samples left, or a step rotating by π or more. The message names the file line
        (from ``info["first_data_line"]`` / ``info["line_runs"]``) or the sample number.
    """
    if max_gap is not None and not (np.isfinite(max_gap) and max_gap >= 0):
        raise InputError(f"max_gap must be a non-negative number of seconds, got {max_gap!r}")
    t, q, p = traj.t, traj.quat, traj.position
    n = len(t)
    lost = lost_frame_mask(traj)
    valid = ~lost
    vi = np.flatnonzero(valid)
    norms = np.linalg.norm(q[vi], axis=1)
    dev = np.abs(norms - 1.0)
    if len(vi) and dev.max() > unit_tolerance:
        j = int(np.argmax(dev > unit_tolerance))
        raise _error(
            traj,
            int(vi[j]),
            f"quaternion norm {norms[j]:.6g} at {{where}} is far from 1 (tolerance {unit_tolerance:g})",
            hint="check which columns hold the quaternion, their order and units (--columns, --quat-order); "
            "a unit quaternion's components lie in [-1, 1]",
        )
    # sample-and-hold (MATH.md §4.1): a valid sample that repeats its predecessor's pose bit for bit at
    # a later time is the tracker holding the last pose, not motion: a lost frame like any other
    held = np.zeros(n, dtype=bool)
    if len(vi) > 1:
        a, b = vi[:-1], vi[1:]
        same_q = np.all(q[a] == q[b], axis=1) | np.all(q[a] == -q[b], axis=1)
        held[b] = same_q & np.all(p[a] == p[b], axis=1) & (t[b] > t[a])
    n_held = int(held.sum())
    if n_held:
        lost = lost | held
        valid = ~lost
        keep_v = ~held[vi]
        vi, norms = vi[keep_v], norms[keep_v]
    qn = np.full_like(q, np.nan)
    qn[vi] = q[vi] / norms[:, None]

    # times of the valid samples: strictly increasing, exact duplicates dropped
    tv = t[vi]
    dt = np.diff(tv)
    back = np.flatnonzero(dt < 0)
    if back.size:
        k = int(back[0])
        raise _error(
            traj,
            int(vi[k + 1]),
            f"time goes backwards at {{where}}, after t = {tv[k]:.9g} s",
            hint="sort the rows by time, or split the demonstrations with a demo column",
        )
    same = np.flatnonzero(dt == 0)
    dup_raw = np.zeros(n, dtype=bool)
    if same.size:
        a, b = vi[same], vi[same + 1]
        equal_p = np.all(p[a] == p[b], axis=1)
        equal_q = np.all(q[a] == q[b], axis=1) | np.all(q[a] == -q[b], axis=1)
        differ = ~(equal_p & equal_q)
        if differ.any():
            j = int(np.argmax(differ))
            raise _error(
                traj,
                int(b[j]),
                "{where} has the same time as the sample before it but a different pose",
                hint="remove one of them, or split interleaved demonstrations or bodies with a demo column",
            )
        dup_raw[b] = True
    keep = valid & ~dup_raw

    # fill interior gaps of lost frames
    fill_idx = np.empty(0, dtype=np.int64)
    fill_q = np.empty((0, 4))
    fill_p = np.empty((0, 3))
    if max_gap is not None and lost.any():
        kept = np.flatnonzero(keep)
        li = np.flatnonzero(lost & np.isfinite(t))
        pos = np.searchsorted(kept, li)
        interior = (pos > 0) & (pos < len(kept))
        li, pos = li[interior], pos[interior]
        a, b = kept[pos - 1], kept[pos]
        ok = (t[b] - t[a] <= max_gap) & (t[a] < t[li]) & (t[li] < t[b])
        # the lost rows of one gap must be in time order among themselves
        for gap_start in np.unique(a[ok]):
            rows = ok & (a == gap_start)
            if np.any(np.diff(t[li[rows]]) <= 0):
                ok &= ~rows
        li, a, b = li[ok], a[ok], b[ok]
        if li.size:
            u = (t[li] - t[a]) / (t[b] - t[a])
            qa, qb = qn[a], qn[b]
            qb = np.where((np.sum(qa * qb, axis=1) < 0)[:, None], -qb, qb)
            fill_q = _slerp(qa, qb, u)
            fill_p = p[a] + u[:, None] * (p[b] - p[a])
            fill_idx = li
    rows = np.concatenate([np.flatnonzero(keep), fill_idx])
    order = np.argsort(rows, kind="stable")
    rows = rows[order]
    q_out = np.concatenate([qn[keep], fill_q])[order]
    p_out = np.concatenate([p[keep], fill_p])[order]
    t_out = t[rows]
    n_lost = int(lost.sum()) - n_held
    n_filled = int(fill_idx.size)
    if len(rows) < 2:
        finite_q = np.all(np.isfinite(q), axis=1)
        n_zero = int(np.sum(finite_q & (np.linalg.norm(np.where(np.isfinite(q), q, 0.0), axis=1) < ZERO_QUAT_NORM)))
        hint = "check that the file holds a whole demonstration and that the right columns were used"
        if n_zero:
            hint = (f"{n_zero} samples have an all-zero quaternion (an unset protobuf/foxglove Quaternion "
                    "defaults to w = 0): the recorder did not fill in the orientation")  # fmt: skip
        raise InputError(
            f"{traj.name + ': ' if traj.name else ''}needs at least 2 samples for a velocity, "
            f"{len(rows)} left of {n} ({n_lost} lost frames"
            + (f", {int(dup_raw.sum())} duplicates" if dup_raw.any() else "")
            + ")",
            path=traj.source or None,
            hint=hint,
        )

    # sign continuity
    d = np.sum(q_out[1:] * q_out[:-1], axis=1)
    flips = d < 0
    sign = np.concatenate([[1.0], np.cumprod(np.where(flips, -1.0, 1.0))])
    q_out = q_out * sign[:, None]

    # no step of π or more
    step = 4.0 * np.arctan2(
        np.linalg.norm(q_out[1:] - q_out[:-1], axis=1), np.linalg.norm(q_out[1:] + q_out[:-1], axis=1)
    )
    big = np.flatnonzero(step >= STEP_LIMIT)
    if big.size:
        k = int(big[0])
        raise _error(
            traj,
            int(rows[k + 1]),
            f"the rotation from the previous sample to {{where}} is {step[k]:.6g} rad (π or more): the "
            "sampling is too coarse to tell which way the body turned",
            hint="record at a higher rate, or remove the corrupted sample",
        )

    report = {
        "samples_in": int(n),
        "samples_out": int(len(rows)),
        "lost": n_lost,
        "filled": n_filled,
        "dropped": n_lost + n_held - n_filled,
        "held": n_held,
        "duplicates": int(dup_raw.sum()),
        "sign_flips": int(flips.sum()),
        "max_norm_deviation": float(dev.max()) if len(vi) else 0.0,
    }
    parts = []
    if n_held:
        parts.append(f"{n_held} sample{'s' * (n_held != 1)} repeat{'s' * (n_held == 1)} the previous pose exactly "
                     "(the tracker held it): treated as lost frame" + "s" * (n_held != 1))
    if report["dropped"]:
        parts.append(f"dropped {report['dropped']} lost frame{'s' * (report['dropped'] != 1)}")
    if n_filled:
        parts.append(f"filled {n_filled} lost frame{'s' * (n_filled != 1)}")
    if report["duplicates"]:
        parts.append(f"dropped {report['duplicates']} duplicate sample{'s' * (report['duplicates'] != 1)}")
    sign_note = sign_change_note(traj.info, report["sign_flips"])
    if sign_note:
        parts.append(sign_note)
    if report["max_norm_deviation"] > _NOTE_NORM:
        parts.append(f"normalised quaternions (largest | |q| - 1 | = {report['max_norm_deviation']:.3g})")
    if parts:
        label = f"{traj.name}: " if traj.name else ""
        warn(label + ", ".join(parts), path=traj.source or None)
    clean = traj.with_(t=t_out, quat=q_out, position=p_out, info={"repairs": report})
    return clean, report


def prepare_all(trajectories, **kwargs) -> tuple[list[Trajectory], list[dict]]:
    """:func:`prepare_trajectory` for each trajectory; returns (clean trajectories, reports)."""
    clean, reports = [], []
    for traj in trajectories:
        c, r = prepare_trajectory(traj, **kwargs)
        clean.append(c)
        reports.append(r)
    return clean, reports
