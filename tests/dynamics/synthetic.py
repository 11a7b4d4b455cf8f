"""Synthetic demonstrations shared by the tests of the demonstrations' variation."""

from __future__ import annotations

import numpy as np

from rbgp_cli.dynamics.trajectory import Trajectory


def timed_demos(n, seed, samples, pose):
    """``n`` demonstrations, each of a random duration in [1.5, 2.5] s sampled at ``samples`` even steps
    from t = 3 s, named ``d0``, ``d1``, ...; ``pose(rng, s)`` gives each one's unit quaternions
    (samples, 4) and positions (samples, 3) at its phase ``s = t / T`` (shape (samples,)), drawing its
    own randomness from ``rng`` (one generator seeded by ``seed``, after the duration's draw)."""
    rng = np.random.default_rng(seed)
    out = []
    for d in range(n):
        T = rng.uniform(1.5, 2.5)
        t = np.linspace(0.0, T, samples)
        q, p = pose(rng, t / T)
        out.append(Trajectory(t + 3.0, q, p, name=f"d{d}"))
    return out
