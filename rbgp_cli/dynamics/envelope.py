"""Where the demonstrations went: the envelope a generated motion is checked against.

A GP knows nothing far from its training poses: there it returns its prior (the mean-path prior's
pull, or zero), and a rollout that got there may run anywhere. The **envelope** of a set of
demonstrations is, at each phase s = (t − t_0)/D of the motion (S = :data:`PHASES` phases in [0, 1]),
the per-axis box of the positions the demonstrations reach within ±:data:`WINDOW` of that phase,
widened on every side by a margin of :data:`MARGIN_FRACTION` of the demonstrations' largest per-axis
extent (at least :data:`MIN_MARGIN` m):

    lo_j = min {p_i(t) : |s(t) − s_j| ≤ w} − m,   hi_j = max {…} + m,   m = max(0.05, 0.25 · max_a (max p_a − min p_a)).

A position p at phase s is **outside** when some axis leaves [lo_j, hi_j] for the phase s_j nearest
to s (s clamped to [0, 1], so a rollout longer than the demonstrations is held to their end box). The
window tolerates motions that run early or late; the margin, positions a little beside the
demonstrations. A generated trajectory **left the data** when one of its samples is outside; its
first exit is reported (index, time, position).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Envelope", "envelope_from_demos", "envelope_from_points", "left_envelope", "continuation_phases",
           "exits_report", "describe",
           "PHASES", "WINDOW", "MARGIN_FRACTION", "MIN_MARGIN", "OFF_DATA"]

#: Phases of the envelope (s_j = j / (S − 1)).
PHASES = 51
#: Half-width of the phase window each box covers.
WINDOW = 0.1
#: The margin as a fraction of the demonstrations' largest per-axis extent, and its floor in metres.
MARGIN_FRACTION = 0.25
MIN_MARGIN = 0.05
#: What a rollout does once it has left the envelope (``rbgp rollout --off-data``).
OFF_DATA = ("keep", "stop", "prior")
_BINS = 200


@dataclass
class Envelope:
    """Per-phase position boxes. lo, hi : (S, 3) metres at phases linspace(0, 1, S), without the
    margin; margin : metres added on every side; source : what it was computed from."""

    lo: np.ndarray
    hi: np.ndarray
    margin: float
    source: str = "demonstrations"

    def outside(self, position, phase) -> np.ndarray:
        """True where a position (..., 3) at phase (...) lies beyond its box plus the margin."""
        S = len(self.lo)
        k = np.rint(np.clip(np.nan_to_num(np.asarray(phase, dtype=np.float64), nan=1.0), 0.0, 1.0) * (S - 1)).astype(int)
        p = np.asarray(position, dtype=np.float64)
        with np.errstate(invalid="ignore"):
            out = np.any((p < self.lo[k] - self.margin) | (p > self.hi[k] + self.margin), axis=-1)
        return out | ~np.all(np.isfinite(p), axis=-1)

    def overall(self) -> "Envelope":
        """The same envelope without the phase: every phase gets the box of all of them."""
        S = len(self.lo)
        return Envelope(np.repeat(self.lo.min(axis=0)[None], S, 0), np.repeat(self.hi.max(axis=0)[None], S, 0),
                        self.margin, self.source)

    def to_dict(self) -> dict:
        """Plain data for a model header: lo, hi (S × 3 lists, m), margin (m), source."""
        return {"lo": self.lo.tolist(), "hi": self.hi.tolist(), "margin": float(self.margin), "source": self.source}

    @classmethod
    def from_dict(cls, d: dict) -> "Envelope":
        """Inverse of :meth:`to_dict`; ValueError when the arrays are not S × 3 (S ≥ 2) finite with lo ≤ hi."""
        lo, hi = np.asarray(d["lo"], dtype=np.float64), np.asarray(d["hi"], dtype=np.float64)
        margin = float(d["margin"])
        if (lo.ndim != 2 or lo.shape[1] != 3 or lo.shape != hi.shape or len(lo) < 2 or not np.all(np.isfinite(lo))
                or not np.all(np.isfinite(hi)) or np.any(lo > hi) or not (np.isfinite(margin) and margin >= 0)):
            raise ValueError("the demonstrations' envelope in the model header is inconsistent")
        return cls(lo, hi, margin, str(d.get("source", "demonstrations")))


def envelope_from_points(position, phase=None, *, phases: int = PHASES, window: float = WINDOW,
                         margin_fraction: float = MARGIN_FRACTION, source: str = "demonstrations") -> Envelope:
    """The envelope of positions (N, 3) at phases (N,) in [0, 1] (None: one box for every phase)."""
    p = np.asarray(position, dtype=np.float64).reshape(-1, 3)
    extent = float(np.max(p.max(axis=0) - p.min(axis=0)))
    margin = max(MIN_MARGIN, margin_fraction * extent)
    if phase is None:
        return Envelope(np.repeat(p.min(axis=0)[None], phases, 0), np.repeat(p.max(axis=0)[None], phases, 0), margin, source)
    b = np.clip((np.asarray(phase, dtype=np.float64).reshape(-1) * _BINS).astype(int), 0, _BINS - 1)
    mn = np.full((_BINS, 3), np.inf)
    mx = np.full((_BINS, 3), -np.inf)
    np.minimum.at(mn, b, p)
    np.maximum.at(mx, b, p)
    centres = (np.arange(_BINS) + 0.5) / _BINS
    s = np.linspace(0.0, 1.0, phases)
    near = np.abs(centres[None, :] - s[:, None]) <= window + 0.5 / _BINS  # (S, bins)
    lo = np.where(near[:, :, None], mn[None], np.inf).min(axis=1)
    hi = np.where(near[:, :, None], mx[None], -np.inf).max(axis=1)
    empty = ~np.isfinite(lo).all(axis=1)  # a window without points (sparse training points): the whole box
    lo[empty], hi[empty] = p.min(axis=0), p.max(axis=0)
    return Envelope(lo, hi, margin, source)


def envelope_from_demos(trajs, **kwargs) -> Envelope:
    """The envelope of demonstrations (every sample at its phase (t − t_0)/D)."""
    pos = np.concatenate([tr.position for tr in trajs])
    phase = np.concatenate([(tr.t - tr.t[0]) / max(tr.duration, 1e-12) for tr in trajs])
    return envelope_from_points(pos, phase, **kwargs)


def exits_report(outside: np.ndarray, t: np.ndarray, position: np.ndarray, envelope: Envelope) -> dict:
    """Summary of a (B, T) mask of samples outside, along positions (B, T, 3) at times t (T,) or (B, T):
    ``{"count", "of", "margin_m", "envelope", "trajectories": [{"index", "step", "t", "position"}]}``
    (the first exit of each trajectory that left)."""
    outside = np.asarray(outside, dtype=bool)
    left = np.flatnonzero(outside.any(axis=1))
    first = outside[left].argmax(axis=1)
    tt = np.broadcast_to(np.asarray(t, dtype=np.float64), outside.shape)
    return {
        "count": int(len(left)), "of": int(outside.shape[0]), "margin_m": float(envelope.margin),
        "envelope": envelope.source,
        "trajectories": [{"index": int(b), "step": int(k), "t": float(tt[b, k]),
                          "position": [float(v) for v in position[b, k]]} for b, k in zip(left, first)],
    }


def continuation_phases(trajs, t0: float) -> list:
    """The phases of the rows of continuations of one motion under way that started at ``t0`` (their clock, s):
    ``trajs[0]`` the mean, from the last seen time to the predicted end, at s = (t − t_0) / D̂; every other (a sample,
    drawn with its own duration) from the same current phase s_0 = (t_last − t_0) / D̂ to 1 at its own end,

        s = s_0 + (1 − s_0) (t − t_last) / (t_end − t_last),

    so that a sample drawn shorter or longer is held to the boxes of the phases still ahead of the motion, not to those
    its own duration would put the seen pose at (a seen pose at 80 % of the motion read at 95 % by a short draw is
    where the demonstrations are at 80 %). For trajectories that all end together (one duration) this is
    (t − t_0) / D for each. Returns [(T_b,)]."""
    first = trajs[0]
    s0 = float((first.t[0] - t0) / max(first.t[-1] - t0, 1e-12))
    return [s0 + (1.0 - s0) * (tr.t - tr.t[0]) / max(float(tr.t[-1] - tr.t[0]), 1e-12) for tr in trajs]


def left_envelope(trajs, envelope: Envelope, phases=None, starts=None, masks: bool = False) -> dict:
    """Which trajectories (each on its own phase (t − t_0)/D) leave ``envelope``: :func:`exits_report`
    with the index into ``trajs`` and the time since the trajectory's start. ``phases``: [(T_b,)] per trajectory, its
    rows' phases in the motion it is part of (a continuation of a motion under way: :func:`continuation_phases`),
    with ``starts`` [t_0 s] that motion's start on its clock (``t`` is then reported since t_0); None: each trajectory
    is a whole motion (t_0 = t[0], D its duration). ``masks``: also ``"outside"``, per trajectory a (T_b,) bool of
    its samples outside."""
    if not trajs:
        return exits_report(np.zeros((0, 1), bool), np.zeros(1), np.zeros((0, 1, 3)), envelope)
    T = max(len(tr.t) for tr in trajs)
    mask = np.zeros((len(trajs), T), dtype=bool)
    tt = np.zeros((len(trajs), T))
    pos = np.zeros((len(trajs), T, 3))
    for b, tr in enumerate(trajs):  # one vectorised check per trajectory (their lengths differ)
        tau = tr.t - (tr.t[0] if starts is None else starts[b])
        n = len(tau)
        mask[b, :n] = envelope.outside(tr.position, tau / max(tr.duration, 1e-12) if phases is None else phases[b])
        tt[b, :n], pos[b, :n] = tau, tr.position
    report = exits_report(mask, tt, pos, envelope)
    if masks:
        report["outside"] = [mask[b, :len(tr.t)] for b, tr in enumerate(trajs)]
    return report


def describe(report: dict, what: str = "rollouts", limit: int = 5) -> str:
    """One line: how many left, and where and when the first few did."""
    items = [f"{e['name'] if 'name' in e else '#' + str(e['index'])} at t = {e['t']:.2f} s "
             f"({', '.join(f'{v:.2f}' for v in e['position'])})"
             for e in report["trajectories"][:limit]]
    more = len(report["trajectories"]) - len(items)
    return (f"{report['count']} of {report['of']} {what} left the demonstrations' envelope (by more than "
            f"{report['margin_m']:.2g} m beside where the demonstrations go at that phase): " + "; ".join(items)
            + (f"; and {more} more" if more > 0 else ""))
