"""Tests of rbgp_cli.viz (Rerun recordings, matplotlib figures), and small synthetic data they share.

Everything is seeded and small (tens of samples), so no test needs a trained GP except where the
training points themselves are recorded.
"""

from __future__ import annotations

import numpy as np

from rbgp_cli.dynamics.rollout import RolloutResult
from rbgp_cli.dynamics.trajectory import Trajectory
from rbgp_cli.geometry.so3 import exp_quat, quat_make_continuous

OUTPUTS = ("wx", "wy", "wz", "vx", "vy", "vz")


def synth_trajectory(i: float, n: int = 40, dt: float = 0.02, name: str = "", noise: float = 0.0, seed: int = 0,
                     turn: float = 1.2) -> Trajectory:
    """A smooth motion: forward and down with a sideways arc, turning about z by about ``turn`` rad.

    ``i`` shifts the start and the amount of turning a little (a family of similar motions).
    """
    rng = np.random.default_rng(seed)
    t = np.arange(n) * dt
    s = t / t[-1]
    pos = np.stack([0.3 * s + 0.01 * i, 0.1 * np.sin(np.pi * s), 1.0 - 0.2 * s + 0.005 * i], axis=1)
    pos = pos + noise * rng.normal(size=pos.shape)
    rv = np.stack([0.1 * s, 0.05 * i * s, turn * s + 0.05 * i], axis=1)
    return Trajectory(t, quat_make_continuous(exp_quat(rv)), pos, name=name)


def synth_demos() -> list[Trajectory]:
    """Three demonstrations of different lengths; names that need escaping in entity paths."""
    return [synth_trajectory(0, 40, name="trial 1"), synth_trajectory(1, 36, name="file.csv#a/b"),
            synth_trajectory(2, 44, name="")]


def synth_rollout(B: int = 3, steps: int = 24, K: int = 2, with_std: bool = True, seed: int = 1) -> RolloutResult:
    """A RolloutResult built directly (no GP): B smooth motions, one turning through θ = π, with
    made-up stds (distinct per trajectory, output and step) and K noisy Monte Carlo copies."""
    rng = np.random.default_rng(seed)
    trajs = [synth_trajectory(b, steps + 1, turn=3.6 if b == 0 else 1.0) for b in range(B)]
    t = trajs[0].t
    quat = np.stack([tr.quat for tr in trajs])
    pos = np.stack([tr.position for tr in trajs])
    std = None
    if with_std:
        std = (0.01 * (1 + np.arange(B))[:, None, None] * (1 + np.arange(len(OUTPUTS)))[None, None, :]
               * (1 + t)[None, :, None])
    sq = sp = None
    if K:
        sp = pos[:, None] + 0.01 * np.cumsum(rng.normal(size=(B, K, len(t), 3)), axis=2)
        sq = np.repeat(quat[:, None], K, axis=1)
    return RolloutResult(t=t, quat=quat, position=pos, std=std, output_names=OUTPUTS, sample_quat=sq,
                         sample_position=sp)
