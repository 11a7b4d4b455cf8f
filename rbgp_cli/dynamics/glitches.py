"""Tracker glitches: samples that jump implausibly far and come back (docs/data.md, "Glitches").

A glitch is the most common defect of real motion capture: a marker swapped for one sample (the
body 10 cm or 1 km off), a few rows written in millimetres inside a file in metres, the rotation
flipped by ~180° for one frame. Learned from, one such sample gives velocities thousands of times
the motion's. What is implausible is judged against the file's own motion, with robust statistics
(median and MAD, which a few bad samples do not move), so that a fast hand raise at 30 Hz and a
slow drift at 256 Hz are each measured against themselves:

1. **jumps that go out and come back** (runs of 1 to :data:`MAX_RUN` samples, any size above the
   jump threshold). A step is a *jump* when its speed is above ``max(K_SPEED · s_v, FLOOR_SPEED)``
   (position) or ``max(K_SPEED · s_ω, FLOOR_ROT_SPEED)`` (rotation), with ``s = median + 1.4826 ·
   MAD`` of the file's step speeds (each step's time at least half the median step, so that two
   messages stamped a microsecond apart are no jump). A jump out at step k and a later jump at step
   j ≤ k + MAX_RUN such that going straight from sample k to sample j + 1 is *not* a jump make
   samples k+1 … j a glitch. A jump at the start or end of the file whose short side has at most
   MAX_RUN samples makes that side a glitch. A jump that does not come back is *unexplained*: the
   caller refuses the file there (a glitch or two recordings joined cannot be told apart).
2. **single samples off the path** (the small ones, 0.1 m at 30 Hz, that are no jump): the residual
   of sample k from the interpolation of its neighbours (linear in position, nlerp in rotation, at
   its own time; extrapolation from the two nearest for the first and last sample, with twice the threshold) above
   ``max(K_RESIDUAL · s_r, FLOOR_RESIDUAL)`` (position) or ``max(K_RESIDUAL · s_r, FLOOR_ROT_RESIDUAL)``
   (rotation), where it is the largest of its neighbours' residuals and theirs are at least a quarter
   of it (a one-sample spike pulls its neighbours' interpolations toward it: their residuals are half
   its own; a corner of the path, or motion starting at once, leaves theirs near 0). Only where both adjacent steps are at
   most :data:`GAP_FACTOR` median steps (interpolation across a gap says nothing). Two passes.

The thresholds were chosen on the real recordings in ``../shared/realdata`` and measured with
``benchmarks/bench_glitches.py`` (the table in docs/data.md). Core module: numpy only.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["find_glitches", "Glitches", "robust_scale", "MAX_RUN", "K_SPEED", "FLOOR_SPEED", "FLOOR_ROT_SPEED",
           "K_RESIDUAL", "FLOOR_RESIDUAL", "FLOOR_ROT_RESIDUAL", "GAP_FACTOR"]

#: A step faster than K_SPEED × the file's robust speed scale (and than the floors) is a jump.
K_SPEED = 10.0
#: m/s: no step slower than this is a jump (the fastest real step measured: 2.1 m/s).
FLOOR_SPEED = 10.0
#: rad/s: no step turning slower than this is a jump (the fastest real step measured: 53 rad/s).
FLOOR_ROT_SPEED = 100.0
#: A glitch run (out and back) has at most this many samples.
MAX_RUN = 50
#: A sample further from its neighbours' interpolation than K_RESIDUAL × the file's robust residual
#: scale (and than the floors) is off the path.
K_RESIDUAL = 8.0
#: m: no sample closer than this to its neighbours' interpolation is off the path (real: 14 mm at most).
FLOOR_RESIDUAL = 0.03
#: rad: the same for the rotation (real: 0.23 rad at most).
FLOOR_ROT_RESIDUAL = 0.5
#: The residual test applies where both adjacent steps are at most this many median steps.
GAP_FACTOR = 4.0


def robust_scale(x: np.ndarray) -> float:
    """``median(x) + 1.4826 · MAD(x)``: the upper end of the typical values, unmoved by a few outliers."""
    if x.size == 0:
        return 0.0
    med = float(np.median(x))
    return med + 1.4826 * float(np.median(np.abs(x - med)))


def _angles(qa: np.ndarray, qb: np.ndarray) -> np.ndarray:
    """Rotation angles (K,) in [0, π] between unit quaternions (K, 4) (x, y, z, w), sign-blind:
    ``4 · atan2(|qa − s qb|, |qa + s qb|)`` with ``s`` the sign of ``⟨qa, qb⟩`` (exact near 0)."""
    s = np.where(np.sum(qa * qb, axis=1) < 0, -1.0, 1.0)[:, None]
    return 4.0 * np.arctan2(np.linalg.norm(qa - s * qb, axis=1), np.linalg.norm(qa + s * qb, axis=1))


@dataclass
class Glitches:
    """What :func:`find_glitches` found in K samples.

    Attributes
    ----------
    mask : (K,) bool, the glitch samples
    runs : list of (first, stop) index ranges of the glitch samples, in order
    unexplained : index k of the first jump (step k → k + 1) that does not come back, or None
    jump : (metres, radians, seconds) of that jump
    thresholds : the thresholds used (plain data, for reports)
    """

    mask: np.ndarray
    runs: list = field(default_factory=list)
    unexplained: int | None = None
    jump: tuple = (0.0, 0.0, 0.0)
    thresholds: dict = field(default_factory=dict)


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    d = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist()))


def _jumps(t, p, q, glitch, dt_min, v_max, w_max) -> tuple[int | None, tuple]:
    """Stage 1: mark out-and-back runs in ``glitch``; the first unexplained jump (or None)."""
    K = len(t)
    dt = np.maximum(np.diff(t), dt_min)
    dist = np.linalg.norm(np.diff(p, axis=0), axis=1)
    turn = _angles(q[1:], q[:-1])
    J = np.flatnonzero((dist / dt > v_max) | (turn / dt > w_max))
    # the other end of a run is a jump too, of at least half the threshold (a spike on a fast motion
    # jumps out at 10.3 m/s and back at 8.9 m/s): not an ordinary step many samples away
    half = (dist / dt > 0.5 * v_max) | (turn / dt > 0.5 * w_max)

    def straight(a: int, b: int) -> bool:  # sample a to sample b without a jump
        span = max(t[b] - t[a], dt_min)
        return (np.linalg.norm(p[b] - p[a]) / span <= v_max
                and _angles(q[b][None], q[a][None])[0] / span <= w_max)

    for k in J.tolist():
        if glitch[k] or glitch[k + 1]:  # a step into or out of a run already found
            continue
        # out at k and back: the first later sample reachable from sample k (samples k+1 … j off)
        forward = next((j for j in range(k + 1, min(k + MAX_RUN, K - 2) + 1) if half[j] and straight(k, j + 1)),
                       None)
        # back at k: the nearest earlier sample from which sample k+1 is reachable (samples i+1 … k off)
        backward = next((i for i in range(k - 1, max(k - MAX_RUN, 0) - 1, -1)
                         if half[i] and not glitch[i] and straight(i, k + 1)), None)
        # the shortest explanation wins (a run out first, on a tie): a run that comes back, or a short
        # start or end of the file; a start cannot be off when sample k is reached again (forward),
        # nor an end when sample k+1 is (backward)
        options = []
        if forward is not None:
            options.append((forward - k, 0, k + 1, forward + 1))
        if backward is not None:
            options.append((k - backward, 1, backward + 1, k + 1))
        marked = np.flatnonzero(glitch[: k + 1])  # none, or a start run 0 … m − 1 this extends
        from_start = marked.size == 0 or (marked[0] == 0 and marked[-1] == marked.size - 1)
        if forward is None and k + 1 <= MAX_RUN and k + 1 < K - (k + 1) and from_start:  # (extending a start run)
            options.append((k + 1, 2, 0, k + 1))
        if backward is None and K - (k + 1) <= MAX_RUN and K - (k + 1) < k + 1:
            options.append((K - (k + 1), 2, k + 1, K))
        if not options:
            return k, (float(dist[k]), float(turn[k]), float(t[k + 1] - t[k]))
        _, _, a, b = min(options)
        glitch[a:b] = True
    return None, (0.0, 0.0, 0.0)


def _residuals(t, p, q) -> tuple[np.ndarray, np.ndarray]:
    """Position (m) and rotation (rad) distance (K,) of each sample from the interpolation of its two
    neighbours at its own time (the first and last: extrapolated from the two nearest)."""
    K = len(t)
    prev = np.r_[1, np.arange(K - 2), K - 3] if K >= 3 else np.zeros(K, int)
    nxt = np.r_[2, np.arange(2, K), K - 2] if K >= 3 else np.zeros(K, int)
    u = (t - t[prev]) / (t[nxt] - t[prev])
    p_hat = p[prev] + u[:, None] * (p[nxt] - p[prev])
    # nlerp: the same path as slerp, exactly the midpoint at u = 1/2 (a regular grid), and the
    # neighbours of a sample are close; three times faster on 10⁶ rows
    qa, qb = q[prev], q[nxt]
    qb = qb * np.where(np.sum(qa * qb, axis=1) < 0, -1.0, 1.0)[:, None]
    q_hat = (1.0 - u)[:, None] * qa + u[:, None] * qb
    q_hat /= np.linalg.norm(q_hat, axis=1, keepdims=True)
    return np.linalg.norm(p - p_hat, axis=1), _angles(q, q_hat)


#: A spike's neighbours are pulled toward it: their residuals are about half its own (a corner of
#: the path, motion starting at once, leaves its neighbours' near 0). At least this fraction of it.
NEIGHBOUR_SHARE = 0.25


def _spikes(r: np.ndarray, limit) -> np.ndarray:
    """Mask (K,) of the residuals ``r`` above ``limit`` that are the largest of their neighbours' and
    whose neighbours' are at least :data:`NEIGHBOUR_SHARE` of them (the first and last sample: their
    one neighbour)."""
    left = np.r_[np.nan, np.nan, r[1:-2], r[-2]]  # an end's (extrapolated) residual is no neighbour's measure
    right = np.r_[r[1], r[2:-1], np.nan, np.nan]
    top = (r >= np.fmax(left, right))
    support = np.fmin(left, right) >= NEIGHBOUR_SHARE * r  # fmin: the ends have one neighbour
    return (r > limit) & top & support


def find_glitches(t, p, q) -> Glitches:
    """Find the glitch samples of one clean trajectory (the module docstring says how).

    Parameters
    ----------
    t : (K,) strictly increasing seconds
    p : (K, 3) metres
    q : (K, 4) unit quaternions x, y, z, w (any signs)
    """
    t = np.asarray(t, dtype=np.float64)
    p = np.asarray(p, dtype=np.float64)
    q = np.asarray(q, dtype=np.float64)
    K = len(t)
    glitch = np.zeros(K, dtype=bool)
    if K < 5:
        return Glitches(glitch)
    steps = np.diff(t)
    med_dt = float(np.median(steps))
    dt_min = 0.5 * med_dt
    dt = np.maximum(steps, dt_min)
    v = np.linalg.norm(np.diff(p, axis=0), axis=1) / dt
    w = _angles(q[1:], q[:-1]) / dt
    v_max = max(K_SPEED * robust_scale(v), FLOOR_SPEED)
    w_max = max(K_SPEED * robust_scale(w), FLOOR_ROT_SPEED)
    unexplained, jump = _jumps(t, p, q, glitch, dt_min, v_max, w_max)
    thresholds = {"speed_m_s": v_max, "turn_rad_s": w_max}
    if unexplained is not None:
        return Glitches(glitch, _runs(glitch), unexplained, jump, thresholds)
    r_max = rr_max = None
    changed = True
    for attempt in range(3):  # interior samples first: a spike next to an end spoils its extrapolation
        idx = np.flatnonzero(~glitch)
        if len(idx) < 5:
            break
        ti = t[idx]
        if changed:  # (the same samples as the attempt before: the same residuals)
            r, rr = _residuals(ti, p[idx], q[idx])
        gaps = np.diff(ti)
        short = gaps <= GAP_FACTOR * med_dt
        testable = np.r_[short[0] & short[1], short[:-1] & short[1:], short[-1] & short[-2]]
        if r_max is None:  # the file's own scale, once, from every testable sample
            r_max = max(K_RESIDUAL * robust_scale(r[testable]), FLOOR_RESIDUAL)
            rr_max = max(K_RESIDUAL * robust_scale(rr[testable]), FLOOR_ROT_RESIDUAL)
        if attempt == 0:
            testable[[0, -1]] = False
        # an end is extrapolated, not interpolated: its threshold is twice (a constant acceleration
        # leaves 3 × the interpolation's residual there, a removed sample next to it more)
        ends = np.ones(len(idx))
        ends[[0, -1]] = 2.0
        off = testable & (_spikes(r, r_max * ends) | _spikes(rr, rr_max * ends))
        if not off.any() and attempt > 0:
            break
        glitch[idx[off]] = True
        changed = bool(off.any())
    thresholds.update({"residual_m": r_max, "residual_rad": rr_max})
    return Glitches(glitch, _runs(glitch), None, (0.0, 0.0, 0.0), thresholds)
