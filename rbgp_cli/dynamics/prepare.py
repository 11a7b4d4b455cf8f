"""Turn raw trajectories (as the readers return them) into clean ones, and say what was repaired.

A clean :class:`~rbgp_cli.dynamics.trajectory.Trajectory` has strictly increasing finite times, finite
positions (metres) and unit quaternions (x, y, z, w) that are continuous in sign, and no step rotates by
π or more (docs/method.md §4). :func:`prepare_trajectory` gets there by

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

import os
from dataclasses import dataclass

import numpy as np

from rbgp_cli.dynamics.trajectory import Trajectory
from rbgp_cli.errors import InputError, warn

__all__ = ["prepare_trajectory", "prepare_all", "lost_frame_mask", "line_of", "sign_change_note", "ZERO_QUAT_NORM",
           "STEP_LIMIT", "split_at_breaks", "break_threshold", "crop_trajectory", "RestSplit", "split_at_rest",
           "speeds", "quaternion_order_note", "BREAK_FACTOR", "BREAK_SECONDS", "UNIT_TOLERANCE"]

#: A quaternion with a smaller norm is "no rotation recorded" (a lost frame), not a rotation.
ZERO_QUAT_NORM = 1e-9
#: A quaternion whose norm is further from 1 than this is not a unit quaternion (wrong columns, order
#: or units), not noise: an error, where one nearer is normalised.
UNIT_TOLERANCE = 0.1
#: Largest accepted rotation between consecutive samples (rad). The relative rotation of two unit
#: quaternions is at most π; within 1e-6 rad of π its direction is decided by rounding noise.
STEP_LIMIT = np.pi - 1e-6
#: Quaternion norm deviations above this are mentioned in the repair summary.
_NOTE_NORM = 1e-3


def lost_frame_mask(traj: Trajectory) -> np.ndarray:
    """Boolean mask, shape (N,): rows with a non-finite value or an all-zero quaternion."""
    finite = np.isfinite(traj.t) & np.all(np.isfinite(traj.quat), axis=1) & np.all(np.isfinite(traj.position), axis=1)
    norm = np.zeros(len(finite))
    for c in range(4):  # column by column: no temporary of the quaternions' size (big files)
        col = traj.quat[:, c]
        norm += np.where(np.isfinite(col), col, 0.0) ** 2
    return ~(finite & (np.sqrt(norm) >= ZERO_QUAT_NORM))


def _rows(x: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """``x[rows]``, or ``x`` itself (no copy) when ``rows`` is every row in order (the usual case: a
    big file's copies were most of its peak memory)."""
    return x if len(rows) == len(x) else x[rows]


def _pairs(x: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(x[rows[:-1]], x[rows[1:]]): views when ``rows`` is every row in order."""
    if len(rows) == len(x):
        return x[:-1], x[1:]
    return x[rows[:-1]], x[rows[1:]]


def _same_rows(a: np.ndarray, b: np.ndarray, either_sign: bool = False) -> np.ndarray:
    """Rows of ``a`` equal to those of ``b`` bit for bit (or to ``-b``), column by column (no temporary
    of the arrays' size)."""
    same = np.ones(len(a), dtype=bool)
    neg = np.ones(len(a), dtype=bool) if either_sign else None
    for c in range(a.shape[1]):
        same &= a[:, c] == b[:, c]
        if either_sign:
            neg &= a[:, c] == -b[:, c]
    return same | neg if either_sign else same


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


def _error(traj: Trajectory, k: int, message: str, hint: str | None = None, param=None) -> InputError:
    line, where = _where(traj, k)
    label = f"{traj.name}: " if traj.name else ""
    return InputError(f"{label}{message.format(where=where)}", path=traj.source or None, row=line, hint=hint,
                      param=param)


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


def _unit_norms(traj: Trajectory, vi: np.ndarray, unit_tolerance: float) -> tuple[np.ndarray, np.ndarray]:
    """The norms (V,) of the recorded quaternions of the valid rows ``vi`` and their deviations from 1;
    an InputError where one deviates by more than ``unit_tolerance`` (not a unit quaternion)."""
    q = _rows(traj.quat, vi)
    norms = np.linalg.norm(q, axis=1)  # (not einsum: its sums differ in the last bit with the memory layout)
    dev = np.abs(norms - 1.0)
    if len(vi) and dev.max() > unit_tolerance:
        j = int(np.argmax(dev > unit_tolerance))
        raise _error(
            traj,
            int(vi[j]),
            f"quaternion norm {norms[j]:.6g} at {{where}} is far from 1 (tolerance {unit_tolerance:g})",
            hint="check the column mapping, the quaternion order and units (columns, quat_order); "
            "a unit quaternion's components lie in [-1, 1]", param="columns",
        )
    return norms, dev


def _held_samples(t: np.ndarray, q: np.ndarray, p: np.ndarray, vi: np.ndarray) -> tuple[np.ndarray, int, int]:
    """Rows (mask (N,)) among the valid rows ``vi`` that repeat their valid predecessor's pose exactly
    at a later time, their count and the number of runs they form."""
    n = len(t)
    # sample-and-hold (docs/method.md §4.1): a valid sample that repeats its predecessor's pose bit for bit at
    # a later time is the tracker holding the last pose, not motion: a lost frame like any other
    held = np.zeros(n, dtype=bool)
    if len(vi) > 1:
        same = _same_rows(*_pairs(q, vi), either_sign=True) & _same_rows(*_pairs(p, vi))
        ta, tb = _pairs(t, vi)
        held[vi[1:]] = same & (tb > ta)
    n_held = int(held.sum())
    held_runs = int(np.sum(held[1:] & ~held[:-1]) + held[0]) if n else 0
    return held, n_held, held_runs


def _exact_duplicates(traj: Trajectory, vi: np.ndarray) -> np.ndarray:
    """Check the times of the valid rows ``vi``: an InputError where time goes backwards or a time
    repeats with a different pose; returns the mask (N,) of the exact duplicates (same time and pose)."""
    t, q, p = traj.t, traj.quat, traj.position
    n = len(t)
    # times of the valid samples: strictly increasing, exact duplicates dropped
    tv = _rows(t, vi)
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
        equal_p = _same_rows(p[a], p[b])
        equal_q = _same_rows(q[a], q[b], either_sign=True)
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
    return dup_raw


def _filled_gaps(t, p, qn, lost, keep, max_gap):
    """With ``max_gap``, the lost rows inside gaps of at most ``max_gap`` seconds between two kept rows
    (masks ``lost``, ``keep`` (N,)), interpolated at their own times from the unit quaternions ``qn``
    (N, 4) (slerp) and positions ``p`` (N, 3) (linear): (rows (F,), quaternions (F, 4), positions (F, 3))."""
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
    return fill_idx, fill_q, fill_p


def _too_few_samples(traj: Trajectory, rows: np.ndarray, n: int, n_lost: int, dup_raw: np.ndarray,
                     n_held: int = 0) -> InputError:
    """The error for a trajectory with fewer than 2 clean ``rows`` left of ``n``, saying what was lost
    (with a hint where the recorder left the quaternions all zero, or repeated one pose throughout)."""
    q = traj.quat
    finite_q = np.all(np.isfinite(q), axis=1)
    n_zero = int(np.sum(finite_q & (np.linalg.norm(np.where(np.isfinite(q), q, 0.0), axis=1) < ZERO_QUAT_NORM)))
    hint = "check that the file holds a whole demonstration and that the right columns were used"
    if n_zero:
        hint = (f"{n_zero} samples have an all-zero quaternion (an unset protobuf/foxglove Quaternion "
                "defaults to w = 0): the recorder did not fill in the orientation")  # fmt: skip
    elif n_held:
        hint = ("the pose never changes: a demonstration must move (rows repeating the previous pose exactly "
                "are the tracker holding a lost body's last pose, dropped as lost frames)")
    return InputError(
        f"{traj.name + ': ' if traj.name else ''}needs at least 2 samples for a velocity, "
        f"{len(rows)} left of {n} ({n_lost} lost frames"
        + (f", {n_held} repeating the previous pose exactly" if n_held else "")
        + (f", {int(dup_raw.sum())} duplicates" if dup_raw.any() else "")
        + ")",
        path=traj.source or None,
        hint=hint,
    )


def _continuous_signs(q_out: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit quaternions (K, 4) with each flipped into its predecessor's hemisphere, and where a sign
    changed (mask (K − 1,))."""
    # sign continuity
    d = np.sum(q_out[1:] * q_out[:-1], axis=1)
    flips = d < 0
    if not flips.any():
        return q_out, flips
    sign = np.concatenate([[1.0], np.cumprod(np.where(flips, -1.0, 1.0))])
    q_out = q_out * sign[:, None]
    return q_out, flips


def _check_steps(traj: Trajectory, q_out: np.ndarray, rows: np.ndarray) -> None:
    """An InputError at the first step between consecutive clean quaternions (K, 4) (raw ``rows``
    (K,)) that rotates by π or more."""
    # no step of π or more
    step = np.empty(max(len(q_out) - 1, 0))
    for a in range(0, len(step), 1 << 16):  # in blocks: no temporary of the quaternions' size
        b = min(a + (1 << 16), len(step))
        q1, q0 = q_out[a + 1 : b + 1], q_out[a:b]
        step[a:b] = 4.0 * np.arctan2(np.linalg.norm(q1 - q0, axis=1), np.linalg.norm(q1 + q0, axis=1))
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


def _glitch_rows(traj: Trajectory, qn: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """Mask (N,) of the raw rows among ``keep`` that are tracker glitches
    (:func:`rbgp_cli.dynamics.glitches.find_glitches`); an InputError at a jump that does not come
    back. A step of π or more is refused first, as before (:func:`_check_steps`)."""
    from rbgp_cli.dynamics.glitches import MAX_RUN, find_glitches

    rows = np.flatnonzero(keep)
    out = np.zeros(len(keep), dtype=bool)
    if len(rows) < 5:
        return out
    q_cont, _ = _continuous_signs(qn[rows])
    _check_steps(traj, q_cont, rows)
    found = find_glitches(traj.t[rows], traj.position[rows], q_cont)
    if found.unexplained is not None:
        k = found.unexplained
        metres, radians, seconds = found.jump
        raise _error(
            traj, int(rows[k + 1]),
            f"the pose jumps by {metres:.3g} m and {np.degrees(radians):.3g}° in {seconds * 1e3:.3g} ms at {{where}} "
            f"(faster than {found.thresholds['speed_m_s']:.3g} m/s or {found.thresholds['turn_rad_s']:.3g} rad/s, "
            f"far beyond this file's own motion) and does not come back within {MAX_RUN} samples: a tracker "
            "glitch, or recordings in different units or frames joined",
            hint="remove the rows from there on (or before), or keep one part with crop_from or crop_to",
            param=("crop_from", "crop_to"))
    out[rows[found.mask]] = True
    return out


def _row_runs(traj: Trajectory, mask: np.ndarray) -> list:
    """Runs of raw rows in ``mask`` as ``[first, last]`` file lines (or 1-based sample numbers when
    the reader did not record lines), for reports and warnings."""
    idx = np.flatnonzero(mask)
    if not idx.size:
        return []
    cuts = np.flatnonzero(np.diff(idx) != 1) + 1
    out = []
    for run in np.split(idx, cuts):
        a, b = line_of(traj, int(run[0])), line_of(traj, int(run[-1]))
        out.append([a, b] if a is not None and b is not None else [int(run[0]) + 1, int(run[-1]) + 1])
    if line_of(traj, 0) is None:
        return [["sample", *r] for r in out]
    return [["line", *r] for r in out]


def _rows_text(runs: list, most: int = 8) -> str:
    """``lines 52–61, 120`` (or ``samples …``) from :func:`_row_runs`, the first ``most`` runs."""
    if not runs:
        return ""
    word = runs[0][0]
    items = [f"{a}" if a == b else f"{a}–{b}" for _, a, b in runs[:most]]
    many = len(runs) > 1 or runs[0][1] != runs[0][2]
    more = f" and {len(runs) - most} more" if len(runs) > most else ""
    return f"{word}{'s' * many} {', '.join(items)}{more}"


def _warn_repairs(traj: Trajectory, report: dict) -> None:
    """One warning listing what :func:`prepare_trajectory` repaired (its ``report``), if anything."""
    n_held, n_filled = report["held"], report["filled"]
    parts = []
    if n_held:
        parts.append(f"{n_held} sample{'s' * (n_held != 1)} repeat{'s' * (n_held == 1)} the previous pose exactly "
                     "(the tracker held it): treated as lost frame" + "s" * (n_held != 1))
    if report["dropped"]:
        parts.append(f"dropped {report['dropped']} lost frame{'s' * (report['dropped'] != 1)}")
    if n_filled:
        parts.append(f"filled {n_filled} lost frame{'s' * (n_filled != 1)}")
    if report.get("glitches"):
        n = report["glitches"]
        parts.append(f"removed {n} sample{'s' * (n != 1)} off the path (tracker glitch{'es' * (n != 1)}: "
                     f"{'a jump' if n == 1 else 'jumps'} far beyond the file's own motion that came back), "
                     f"as lost frames: {_rows_text(report['glitch_rows'])}")
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


def prepare_trajectory(
    traj: Trajectory, *, max_gap: float | None = None, unit_tolerance: float = UNIT_TOLERANCE
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
    norms, dev = _unit_norms(traj, vi, unit_tolerance)
    # sample-and-hold: the tracker holding the last pose is a lost frame (docs/method.md §4.1)
    held, n_held, held_runs = _held_samples(t, q, p, vi)
    if n_held:
        lost = lost | held
        valid = ~lost
        keep_v = ~held[vi]
        vi, norms = vi[keep_v], norms[keep_v]
    if len(vi) == n:  # every row valid (a big file's usual case): one array, no copies
        qn = q / norms[:, None]
    else:
        qn = np.full_like(q, np.nan)
        qn[vi] = q[vi] / norms[:, None]
    dup_raw = _exact_duplicates(traj, vi)
    keep = valid & ~dup_raw
    glitch = _glitch_rows(traj, qn, keep)
    n_glitch = int(glitch.sum())
    if n_glitch:  # a tracker glitch is a lost frame: dropped, or filled like one with max_gap
        lost, keep = lost | glitch, keep & ~glitch
    fill_idx, fill_q, fill_p = _filled_gaps(t, p, qn, lost, keep, max_gap)
    if fill_idx.size == 0 and keep.all():  # nothing dropped or filled: the raw arrays are the clean ones
        rows, q_out, p_out, t_out = np.arange(n), qn, p, t
    else:
        rows = np.concatenate([np.flatnonzero(keep), fill_idx])
        order = np.argsort(rows, kind="stable")
        rows = rows[order]
        q_out = np.concatenate([qn[keep], fill_q])[order]
        p_out = np.concatenate([p[keep], fill_p])[order]
        t_out = t[rows]
    del qn
    n_lost = int(lost.sum()) - n_held - n_glitch
    n_filled = int(fill_idx.size)
    n_filled_glitch = int(np.isin(fill_idx, np.flatnonzero(glitch)).sum()) if n_glitch else 0
    if len(rows) < 2:
        raise _too_few_samples(traj, rows, n, n_lost, dup_raw, n_held)
    q_out, flips = _continuous_signs(q_out)
    _check_steps(traj, q_out, rows)
    report = {
        "samples_in": int(n),
        "samples_out": int(len(rows)),
        "lost": n_lost,
        "filled": n_filled,
        "dropped": n_lost + n_held - (n_filled - n_filled_glitch),
        "glitches": n_glitch,
        "glitch_rows": _row_runs(traj, glitch),
        "held": n_held,
        "held_runs": held_runs,
        "duplicates": int(dup_raw.sum()),
        "sign_flips": int(flips.sum()),
        "max_norm_deviation": float(dev.max()) if len(vi) else 0.0,
    }
    _warn_repairs(traj, report)
    clean = traj.with_(t=t_out, quat=q_out, position=p_out, info={"repairs": report})
    return clean, report


#: A step between clean samples longer than BREAK_FACTOR × the median step *and* longer than
#: BREAK_SECONDS is a break (between takes, or a tracker outage), not a pause in one motion: the
#: demonstration is split there (``split_gap`` sets an absolute threshold instead).
BREAK_FACTOR = 20.0
BREAK_SECONDS = 2.0


def break_threshold(t: np.ndarray, split_gap: float | None = None) -> float:
    """Seconds: a step longer than this splits a demonstration (:func:`split_at_breaks`).

    ``split_gap`` None: max(BREAK_FACTOR × median step, BREAK_SECONDS); a number: that number
    (``inf``: never split). ``t`` (N,) strictly increasing."""
    if split_gap is not None:
        if not (split_gap > 0):
            raise InputError(f"split_gap must be a positive number of seconds (or inf), got {split_gap!r}", param="split_gap")
        return float(split_gap)
    dt = np.diff(t)
    med = float(np.median(dt)) if len(dt) else 0.0
    return max(BREAK_FACTOR * med, BREAK_SECONDS)


def _piece(traj: Trajectory, a: int, b: int, label: str, k: int) -> Trajectory:
    info = dict(traj.info or {})
    info["piece_of"] = traj.name
    return traj.with_(t=traj.t[a:b], quat=traj.quat[a:b], position=traj.position[a:b],
                      name=f"{traj.name}#{label}{k}", info=info)


def split_at_breaks(traj: Trajectory, split_gap: float | None = None, *, quiet: bool = False):
    """Split a clean trajectory where no sample arrives for longer than :func:`break_threshold`.

    Returns ``(pieces, breaks)``: the pieces with at least 2 samples (named ``NAME#part1``, ...;
    the trajectory itself when there is no break) and one plain-data record per break
    (``after_s``: time since the start where it begins, ``gap_s``). Pieces of a single sample are
    left out. Unless ``quiet``, one warning names the file, where and how long the breaks are, and
    the option that decides (``--split-gap``).
    """
    t = traj.t
    thr = break_threshold(t, split_gap)
    dt = np.diff(t)
    cut = np.flatnonzero(dt > thr)
    if not cut.size:
        if split_gap is not None and not quiet and len(dt):
            kept = dt[dt > break_threshold(t)]
            if kept.size:  # kept whole on request: say what that means for the planned duration
                warn(f"{(traj.name + ': ') if traj.name else ''}kept whole with split_gap {split_gap:g}: its "
                     f"duration {t[-1] - t[0]:.4g} s includes {kept.size} stretch{'es' * (kept.size != 1)} without a "
                     f"sample (up to {kept.max():.4g} s), and so do the rollouts planned from it",
                     path=traj.source or None)
        return [traj], []
    t0 = float(t[0])
    breaks = [{"after_s": float(t[k] - t0), "gap_s": float(dt[k])} for k in cut]
    bounds = np.concatenate([[0], cut + 1, [len(t)]])
    pieces, lone = [], 0
    for a, b in zip(bounds[:-1], bounds[1:]):
        if b - a < 2:
            lone += 1
            continue
        pieces.append((int(a), int(b)))
    out = [_piece(traj, a, b, "part", k + 1) for k, (a, b) in enumerate(pieces)]
    if not quiet:
        med = float(np.median(dt))
        where = "; ".join(f"{_secs(r['gap_s'])} after t = {_secs(r['after_s'])}" for r in breaks[:3])
        more = f" and {len(breaks) - 3} more" if len(breaks) > 3 else ""
        label = f"{traj.name}: " if traj.name else ""
        how = (f"split_gap {thr:g} s" if split_gap is not None else
               f"longer than {BREAK_FACTOR:g} × the median step {med:.3g} s and {BREAK_SECONDS:g} s; split_gap SECONDS "
               "sets the threshold, split_gap inf keeps it whole")
        warn(f"{label}no sample for {where}{more}: a break, not motion; split into {len(out)} demonstration"
             f"{'s' * (len(out) != 1)} there" + (f" ({lone} lone sample{'s' * (lone != 1)} left out)" if lone else "")
             + f" ({how})", path=traj.source or None)
    return out, breaks


def _secs(x: float) -> str:
    return f"{x:.4g} s"


def crop_trajectory(traj: Trajectory, start: float | None = None, end: float | None = None) -> Trajectory:
    """The raw samples whose time since the take's start (its first finite time) lies in
    [``start``, ``end``] seconds (None: unbounded). Rows without a finite time are kept inside the
    kept span (lost frames there). Raises InputError when nothing is left."""
    if start is None and end is None:
        return traj
    for name, v in (("crop_from", start), ("crop_to", end)):
        if v is not None and not (np.isfinite(v) and v >= 0):
            raise InputError(f"{name} must be a finite, non-negative number of seconds, got {v!r}", param=name)
    if start is not None and end is not None and end <= start:
        raise InputError(f"crop_to {end:g} s must be later than crop_from {start:g} s", param="crop_to")
    t = traj.t
    fin = np.isfinite(t)
    if not fin.any():
        return traj
    t0 = float(t[fin][0])
    rel = t - t0
    lo = -np.inf if start is None else start
    hi = np.inf if end is None else end
    inside = fin & (rel >= lo) & (rel <= hi)
    if inside.sum() < 2:
        span = float(np.nanmax(rel))
        raise InputError(f"{traj.name + ': ' if traj.name else ''}cropping to {lo if start is not None else 0:g} .. "
                         f"{'end' if end is None else format(end, 'g')} s leaves {int(inside.sum())} sample(s); the take "
                         f"lasts {span:.4g} s", path=traj.source or None,
                         hint="times of crop_from / crop_to are seconds since the take's first sample")
    idx = np.flatnonzero(inside)
    a, b = int(idx[0]), int(idx[-1]) + 1
    info = {k: v for k, v in (traj.info or {}).items() if k not in ("first_data_line", "line_runs")}
    info["cropped_s"] = [float(lo if start is not None else 0.0), float(rel[b - 1])]
    lines = [line_of(traj, k) for k in (a, b - 1)]
    if lines[0] is not None and lines[1] - lines[0] == b - 1 - a:
        info["first_data_line"] = int(lines[0])
    from dataclasses import replace

    return replace(traj, t=t[a:b], quat=traj.quat[a:b], position=traj.position[a:b], info=info)


#: A quaternion order is suspect when, on every row, the component that would be the scalar in the
#: other order has |value| >= this (cos 15°): the labelled order then reads a rotation within 30° of a
#: half-turn about one axis throughout, the other order a motion within 30° of the identity.
SUSPECT_COMPONENT = float(np.cos(np.radians(15.0)))


def quaternion_order_note(traj: Trajectory) -> str | None:
    """A warning text when the quaternion columns' labelled order looks swapped, else None.

    Only for quaternions read from named CSV columns (``info["rotation"]`` = ``quaternion xyzw`` or
    ``quaternion wxyz``, not chosen by ``--quat-order``). Permuting a quaternion's components keeps
    every dot product, so both orders give the same step angles (the same angular speed and
    continuity); what differs is where the motion sits. w-first data labelled x, y, z, w reads as a
    near-constant half-turn about x (|qx| ≈ 1 on every row, |qw| small), x-first data labelled
    w, x, y, z as one about z; the other order then reads a motion near the identity, which is where
    calibrated rigid bodies usually are. Warn when every row is within 30° of that half-turn
    (:data:`SUSPECT_COMPONENT`); a body that really stays upside down about that axis looks the same,
    so the text says how to confirm the order.
    """
    rot = str((traj.info or {}).get("rotation") or "")
    if (traj.info or {}).get("format") != "csv" or not rot.startswith("quaternion ") or "quat_order" in rot or len(traj) < 2:
        return None
    labelled = rot.split()[1]
    if labelled not in ("xyzw", "wxyz"):
        return None
    comp = 0 if labelled == "xyzw" else 2  # ours (x, y, z, w): the other order's scalar
    q = traj.quat
    if float(np.min(np.abs(q[:, comp]))) < SUSPECT_COMPONENT:
        return None
    other = "wxyz" if labelled == "xyzw" else "xyzw"
    axis = "xyz"[comp]
    names = ", ".join(f"q{c}" for c in labelled)
    return (f"the quaternion columns ({names}) put every row within 30° of a half-turn about {axis} "
            f"(|q{axis}| >= {SUSPECT_COMPONENT:.3f}, |qw| <= {np.sqrt(1 - SUSPECT_COMPONENT ** 2):.2f}); read as "
            f"{', '.join(other)} they are a motion near the identity: if the columns are really in that order, "
            f"pass quat_order {other}; if the body does stay turned, quat_order {labelled} confirms the labels")


@dataclass(frozen=True)
class RestSplit:
    """Split one long take into repetitions at rests (``--split-at-rest``).

    speed : m/s. A sample is at rest when the body's speed, measured over ``window`` seconds around
        it, is below this, and its angular speed below ``angular_speed`` rad/s.
    min_rest : seconds. Only rests at least this long separate repetitions; a motion shorter than
        this between two rests is a twitch, not a repetition, and is left out.
    """

    speed: float = 0.03
    angular_speed: float = 0.3
    min_rest: float = 0.5
    window: float = 0.1

    def __post_init__(self):
        for name, v in (("rest_speed", self.speed), ("rest_time", self.min_rest)):
            if not (np.isfinite(v) and v > 0):
                raise InputError(f"{name} must be a positive number, got {v!r}", param=name)


def speeds(traj: Trajectory, window: float) -> tuple[np.ndarray, np.ndarray]:
    """Linear (m/s) and angular (rad/s) speed at each sample, shapes (N,), by central differences of
    the interpolated pose over ``window`` seconds (clamped to the take): |p(t+w/2) − p(t−w/2)| / Δ and
    angle(R(t+w/2) R(t−w/2)ᵀ) / Δ, Δ the clamped span."""
    from rbgp_cli.dynamics.trajectory import interpolate_poses
    from rbgp_cli.geometry.so3 import quat_make_continuous

    t = traj.t
    lo = np.clip(t - 0.5 * window, t[0], t[-1])
    hi = np.clip(t + 0.5 * window, t[0], t[-1])
    q = quat_make_continuous(traj.quat)
    qa, pa = interpolate_poses(t, q, traj.position, lo)
    qb, pb = interpolate_poses(t, q, traj.position, hi)
    span = np.maximum(hi - lo, 1e-12)
    v = np.linalg.norm(pb - pa, axis=1) / span
    dot = np.abs(np.sum(qa * qb, axis=1))
    ang = 2.0 * np.arccos(np.clip(dot, 0.0, 1.0))
    return v, ang / span


def _runs_of(mask: np.ndarray) -> list[tuple[int, int]]:
    """[a, b) index ranges of the True runs of ``mask``."""
    m = np.concatenate([[False], mask, [False]]).astype(np.int8)
    d = np.diff(m)
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist()))


def _rest_rule(rest: RestSplit) -> str:
    """What counts as rest, for the warnings of :func:`split_at_rest`."""
    return (f"rest: speed below {rest.speed:g} m/s and {rest.angular_speed:g} rad/s for at least {rest.min_rest:g} s; "
            "rest_speed and rest_time decide")


def split_at_rest(traj: Trajectory, rest: RestSplit, *, quiet: bool = False, say_whole: bool = True):
    """Cut a clean take into repetitions separated by rests (docs/method.md §4.1 conventions).

    Rest samples: linear speed < ``rest.speed`` and angular speed < ``rest.angular_speed``
    (:func:`speeds` over ``rest.window``). Rest runs shorter than ``rest.min_rest`` count as motion;
    each remaining motion run, widened by one sample on each side (so it starts and ends at rest), is a
    repetition named ``NAME#rep1``, ...; motion runs shorter than ``rest.min_rest`` are left out.
    Returns ``(repetitions, record)``, record = plain data (``repetitions``, ``rests``,
    ``twitches``, ``spans_s``: [start, end] of each repetition, seconds since the take's start). With
    no rest found the take comes back whole (and, unless ``quiet`` or not ``say_whole``, a warning says so; the
    record has ``no_rest``: :func:`prepare_all` says it once for all takes).
    """
    t = traj.t
    n = len(t)
    v, w = speeds(traj, rest.window)
    still = (v < rest.speed) & (w < rest.angular_speed)
    rests = [(a, b) for a, b in _runs_of(still) if t[b - 1] - t[a] >= rest.min_rest]
    moving = np.ones(n, dtype=bool)
    for a, b in rests:
        moving[a:b] = False
    reps, twitches = [], 0
    for a, b in _runs_of(moving):
        a0, b0 = max(a - 1, 0), min(b + 1, n)
        if t[b0 - 1] - t[a0] < rest.min_rest or b0 - a0 < 3:
            twitches += 1
            continue
        reps.append((a0, b0))
    t0 = float(t[0])
    label = f"{traj.name}: " if traj.name else ""
    how = _rest_rule(rest)
    record = {"repetitions": len(reps), "rests": len(rests), "twitches": twitches,
              "spans_s": [[float(t[a] - t0), float(t[b - 1] - t0)] for a, b in reps]}
    if len(reps) <= 1 and not rests:
        if not quiet and say_whole:
            warn(f"{label}split_at_rest found no rest: kept as one demonstration ({how})", path=traj.source or None)
        record["no_rest"] = True
        record["repetitions"] = 1
        record["spans_s"] = [[0.0, float(t[-1] - t0)]]
        return [traj], record
    if not reps:
        raise InputError(f"{label}split_at_rest found only rest, no motion ({how})", path=traj.source or None)
    out = [_piece(traj, a, b, "rep", k + 1) for k, (a, b) in enumerate(reps)]
    if not quiet:
        spans = ", ".join(f"{s:.3g}–{e:.3g} s" for s, e in record["spans_s"][:6]) + (" …" if len(reps) > 6 else "")
        warn(f"{label}split at rest into {len(out)} repetition{'s' * (len(out) != 1)} ({spans})"
             + (f"; left out {twitches} motion{'s' * (twitches != 1)} shorter than {rest.min_rest:g} s" if twitches else "")
             + f" ({how})", path=traj.source or None)
    return out, record


def prepare_all(trajectories, *, max_gap: float | None = None, unit_tolerance: float = UNIT_TOLERANCE,
                crop: tuple | None = None, split_gap: float | None = None, rest: RestSplit | None = None,
                quiet: bool = False) -> tuple[list[Trajectory], list[dict]]:
    """Clean each trajectory and cut it into demonstrations; returns (demonstrations, reports).

    Per raw trajectory: :func:`crop_trajectory` (``crop`` = (start, end) seconds since the take's
    start, or None), :func:`prepare_trajectory`, :func:`split_at_breaks` (``split_gap``), then with
    ``rest`` :func:`split_at_rest`; and :func:`quaternion_order_note` warns about a suspect
    quaternion order. ``reports`` has one entry per *raw* trajectory (its repair report plus
    ``breaks`` and ``pieces``, and ``repetitions`` with ``rest``); the demonstrations list may be
    longer. ``quiet`` suppresses the warnings of splitting (``rbgp inspect`` reports them itself).
    """
    clean, reports = [], []
    whole: list = []  # takes split_at_rest found no rest in: said once, below
    for traj in trajectories:
        if crop is not None:
            traj = crop_trajectory(traj, *crop)
        c, r = prepare_trajectory(traj, max_gap=max_gap, unit_tolerance=unit_tolerance)
        note = quaternion_order_note(c)
        r["quat_order_suspect"] = note
        if note and not quiet:
            warn((f"{c.name}: " if c.name else "") + note, path=c.source or None)
        pieces, breaks = split_at_breaks(c, split_gap, quiet=quiet)
        r["breaks"] = breaks
        if rest is not None:
            reps, r["rest"] = [], []
            for piece in pieces:
                got, rec = split_at_rest(piece, rest, quiet=quiet, say_whole=False)
                if rec.get("no_rest"):
                    whole.append(os.path.basename(piece.source) if piece.source else (piece.name or ""))
                reps += got
                r["rest"].append(rec)
            pieces = reps
        r["pieces"] = len(pieces)
        clean.extend(pieces)
        reports.append(r)
    if whole and not quiet:
        named = ", ".join(n for n in whole[:4] if n) + (f" and {len(whole) - 4} more" if len(whole) > 4 else "")
        warn(f"split_at_rest found no rest in {len(whole)} of {sum(len(r['rest']) for r in reports if 'rest' in r)} "
             f"takes{' (' + named + ')' if named else ''}: each kept as one demonstration ({_rest_rule(rest)})")
    return clean, reports
