#!/usr/bin/env python3
"""Make the bundled sample demonstrations in ``sample_data/`` (deterministic: same bytes every run).

Nine synthetic trials in the spirit of the paper's shoe-passing study (sec. 4.3): a hand-held shoe
is carried from near the giver's body forward and down to someone's foot while it is turned by well
over 90°. 179 Hz, about 3.5 s each, minimum-jerk timing, with human-like variation between trials in
the start pose, the speed (duration 3.3–3.7 s), the path (lateral and vertical via-point offsets)
and the amount of turning, plus motion-capture noise (0.3 mm, 0.1°). One trial (trial 07) turns far
enough that its rotation angle passes θ = π, where the canonical rotation vector flips (MATH.md §2).

Writes
  sample_data/csv/shoe_01.csv … shoe_09.csv   columns t,x,y,z,qx,qy,qz,qw (s, m, quaternion x,y,z,w)
  sample_data/shoe_demos.mcap                 ROS 2 geometry_msgs/msg/PoseStamped, one topic per
                                              trial: /shoe/trial_01/pose … (header stamps in ns)

Run:  python scripts/make_sample_data.py
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from rbgp_cli.geometry.so3 import exp_quat, quat_make_continuous, quat_multiply, rotvec_from_quat  # noqa: E402

RATE = 179.0
N_TRIALS = 9
PI_TRIAL = 7  # the one trial whose rotation passes θ = π

POSE_STAMPED = """std_msgs/Header header
geometry_msgs/Pose pose
================================================================================
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id
================================================================================
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
================================================================================
MSG: geometry_msgs/Pose
Point position
Quaternion orientation
================================================================================
MSG: geometry_msgs/Point
float64 x
float64 y
float64 z
================================================================================
MSG: geometry_msgs/Quaternion
float64 x 0
float64 y 0
float64 z 0
float64 w 1
"""


def min_jerk(tau: np.ndarray) -> np.ndarray:
    """Minimum-jerk profile s(τ) = 10τ³ − 15τ⁴ + 6τ⁵ on τ ∈ [0, 1]."""
    return tau**3 * (10 - 15 * tau + 6 * tau**2)


def trial(i: int, rng: np.random.Generator):
    """Times (N,) in s, quaternions (N, 4) x,y,z,w and positions (N, 3) in m of trial i (1-based)."""
    duration = rng.uniform(3.3, 3.7)
    n = int(round(duration * RATE)) + 1
    t = np.arange(n) / RATE
    s = min_jerk(t / t[-1])
    # translation: from near the giver's chest (x≈0.25, z≈1.15 m) forward and down to the foot
    p0 = np.array([0.25, 0.0, 1.15]) + rng.normal(0, [0.03, 0.03, 0.02])
    p1 = np.array([0.85, 0.05, 0.12]) + rng.normal(0, [0.03, 0.03, 0.01])
    bump = np.sin(np.pi * s)[:, None] * (np.array([0.0, 0.12, 0.10]) + rng.normal(0, [0.02, 0.04, 0.03]))
    pos = p0 + s[:, None] * (p1 - p0) + bump
    # rotation: a start orientation near 40° about a tilted axis, then a turn of 100–125° about the
    # world y axis (the shoe tipped towards the foot) and a smaller twist about world z; trial 07
    # starts at 90° and turns 140°, so its rotation angle passes θ = π
    axis0 = np.array([0.25, 0.35, 0.9])
    axis0 /= np.linalg.norm(axis0)
    start_angle = np.deg2rad(40.0) + rng.normal(0, np.deg2rad(4.0))
    turn_deg = rng.uniform(100.0, 125.0)
    if i == PI_TRIAL:
        start_angle, turn_deg = np.deg2rad(90.0), 140.0
    q0 = exp_quat(axis0 * start_angle + rng.normal(0, np.deg2rad(3.0), 3))
    turn = np.deg2rad(turn_deg) * s
    twist = np.deg2rad(25.0 + rng.normal(0, 5.0)) * np.sin(0.5 * np.pi * s)
    dq = quat_multiply(exp_quat(turn[:, None] * np.array([0.0, 1.0, 0.0])),
                       exp_quat(twist[:, None] * np.array([0.0, 0.0, 1.0])))
    q = quat_multiply(dq, np.broadcast_to(q0, dq.shape))
    # motion-capture noise
    q = quat_multiply(exp_quat(rng.normal(0, np.deg2rad(0.1), (n, 3))), q)
    pos = pos + rng.normal(0, 0.0003, pos.shape)
    q = quat_make_continuous(q)
    q = q * np.where(q[:1, 3] < 0, -1.0, 1.0)
    return t, q, pos


def crosses_pi(q: np.ndarray) -> bool:
    """True when the canonical rotation vector flips (θ passes π) somewhere along the trial."""
    r = rotvec_from_quat(q)
    return bool(np.any(np.linalg.norm(np.diff(r, axis=0), axis=1) > 1.0))


def main() -> None:
    rng = np.random.default_rng(20260524)
    out_csv = ROOT / "sample_data" / "csv"
    out_csv.mkdir(parents=True, exist_ok=True)
    trials = [trial(i, rng) for i in range(1, N_TRIALS + 1)]
    crossing = [i + 1 for i, (_, q, _) in enumerate(trials) if crosses_pi(q)]
    if crossing != [PI_TRIAL]:
        raise SystemExit(f"expected exactly trial {PI_TRIAL} to cross θ = π, got {crossing}")
    for i, (t, q, p) in enumerate(trials, start=1):
        # times as whole nanoseconds, so the CSV and the MCAP (integer ns stamps) hold the same instants
        ns = np.round(t * 1e9).astype(np.int64)
        lines = ["t,x,y,z,qx,qy,qz,qw"]
        for k in range(len(t)):
            vals = [ns[k] / 1e9, *p[k], *q[k]]
            lines.append(",".join(repr(float(v)) for v in vals))
        (out_csv / f"shoe_{i:02d}.csv").write_text("\n".join(lines) + "\n")
    write_mcap(ROOT / "sample_data" / "shoe_demos.mcap", trials)
    print(f"wrote {N_TRIALS} CSV files to {out_csv} and sample_data/shoe_demos.mcap; trial {PI_TRIAL} crosses θ = π")


def write_mcap(path: Path, trials) -> None:
    from mcap_ros2.writer import Writer

    with open(path, "wb") as fh:
        w = Writer(fh)
        schema = w.register_msgdef("geometry_msgs/msg/PoseStamped", POSE_STAMPED)
        for i, (t, q, p) in enumerate(trials, start=1):
            ns = np.round(t * 1e9).astype(np.int64)
            for k in range(len(t)):
                stamp = int(ns[k])
                msg = {
                    "header": {"stamp": {"sec": stamp // 1_000_000_000, "nanosec": stamp % 1_000_000_000}, "frame_id": "world"},
                    "pose": {
                        "position": {"x": float(p[k, 0]), "y": float(p[k, 1]), "z": float(p[k, 2])},
                        "orientation": {"x": float(q[k, 0]), "y": float(q[k, 1]), "z": float(q[k, 2]), "w": float(q[k, 3])},
                    },
                }
                # log times offset per trial so the bag plays the trials one after another
                w.write_message(f"/shoe/trial_{i:02d}/pose", schema, msg, log_time=stamp + i * 10_000_000_000,
                                publish_time=stamp + i * 10_000_000_000)
        w.finish()


if __name__ == "__main__":
    main()
