"""The one place that states rbgp's conventions (docs/method.md §1). Every docstring repeats what applies.

Units
    Inside rbgp everything is SI: seconds, metres, radians. Other units (mm, cm, degrees, ms, ns)
    are converted by the readers in :mod:`rbgp_cli.io` and nowhere else.

Quaternions
    Hamilton product, components ordered **x, y, z, w** (scalar last), as scipy, ROS, MCAP and Rerun.
    Shape ``(..., 4)``. Readers convert other orders at the boundary, from column names or options,
    never by guessing from values.

Poses
    A pose ``T_world_body`` maps body coordinates to world coordinates: ``p_world = R p_body + t``.
    Pose arrays are ``g = (r, t)``, shape ``(..., 6)`` = ``(rx, ry, rz, x, y, z)``: **rotation
    first**, as the paper's ``g = (θu, v)``; ``r = θu`` is the canonical rotation vector in the
    closed ball of radius π with the eq. 7 tie-break at θ = π (see :mod:`rbgp_cli.geometry.so3`).

Velocities
    ``ξ = (ω, v)``, shape ``(..., 6)``: ``ω`` the angular velocity in the world frame (rad/s),
    ``v`` the velocity of the body origin in the world frame (m/s). Rotation first.

Arrays
    float64, vectorised over leading axes.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "QUAT_ORDER",
    "POSE_COLUMNS",
    "VELOCITY_COLUMNS",
    "ROTATION_SLICE",
    "TRANSLATION_SLICE",
    "DTYPE",
    "EPS",
    "SMALL_ANGLE",
    "eps_for",
]

#: Component order of every quaternion array inside rbgp (scalar last).
QUAT_ORDER = "xyzw"
#: Names of the six pose components, rotation first.
POSE_COLUMNS = ("rx", "ry", "rz", "x", "y", "z")
#: Names of the six velocity components, rotation first.
VELOCITY_COLUMNS = ("wx", "wy", "wz", "vx", "vy", "vz")
ROTATION_SLICE = slice(0, 3)
TRANSLATION_SLICE = slice(3, 6)
DTYPE = np.float64
#: Machine epsilon of float64.
EPS = float(np.finfo(np.float64).eps)
#: Below this angle (rad) series expansions replace sin(θ)/θ and friends: the truncation error of the
#: second-order series, O(θ⁴) ≈ 1e-16 relative, is then below float64 round-off.
SMALL_ANGLE = 1e-4


def eps_for(dtype) -> float:
    """Machine epsilon of ``dtype`` (float32 or float64)."""
    return float(np.finfo(np.dtype(dtype)).eps)
