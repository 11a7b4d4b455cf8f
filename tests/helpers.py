"""Shared test helpers: double-cover-aware assertions and Hypothesis strategies for rotations and poses.

The assertions compare *rotations*, never raw rotation vectors or quaternions: ``q`` and ``-q`` are the
same rotation, and at θ = π so are ``r`` and ``-r``. Rotation distances are computed with scipy's
``Rotation`` (an independent oracle), not with the code under test.

Strategies mix the cases that break geometry code: Haar-uniform rotations, near the identity
(θ ~ 1e-9 … 1e-5), near π (π − 1e-9 … π − 1e-4) and exactly π, with axes that exercise the eq. 7
tie-break (u_z = 0, u_z = u_y = 0, negative components).
"""

from __future__ import annotations

import io
import math

import numpy as np
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from rbgp_cli.geometry.so3 import AXIS_TOLERANCE, PI_TOLERANCE

PI = math.pi
#: What the eq. 7 tie-break may cost: a canonical vector with π − PI_TOLERANCE < θ < π can be
#: replaced by its twin −r, a rotation up to 2·PI_TOLERANCE rad away (documented in so3).
TIE_ATOL = 2 * PI_TOLERANCE

# ---------------------------------------------------------------------------------------------
# Assertions
# ---------------------------------------------------------------------------------------------


def rotation_angle_between(r1, r2) -> np.ndarray:
    """Angle (rad) of ``R1ᵀ R2`` for rotation vectors (..., 3), by scipy. Shape (...)."""
    r1, r2 = np.broadcast_arrays(np.asarray(r1, dtype=float), np.asarray(r2, dtype=float))
    to_quat = lambda r: Rotation.from_rotvec(r.reshape(-1, 3)).as_quat().reshape(r.shape[:-1] + (4,))  # noqa: E731
    return quat_angle_between(to_quat(r1), to_quat(r2))


def quat_angle_between(q1, q2) -> np.ndarray:
    """Angle (rad) of the rotation between quaternions (..., 4) (x, y, z, w), by scipy."""
    q1 = np.asarray(q1, dtype=float)
    q2 = np.asarray(q2, dtype=float)
    q1, q2 = np.broadcast_arrays(q1, q2)
    shape = q1.shape[:-1]
    a = Rotation.from_quat(q1.reshape(-1, 4))
    b = Rotation.from_quat(q2.reshape(-1, 4))
    return (a.inv() * b).magnitude().reshape(shape)


def assert_rotvecs_close(r1, r2, atol: float = 1e-12, msg: str = "", tie: bool = True) -> None:
    """Rotation vectors (..., 3) describe rotations at most ``atol`` rad apart (θ = π aware).

    With ``tie`` (default) the eq. 7 tie-break's price ``TIE_ATOL`` is added to ``atol``: a
    canonicalised result within ``PI_TOLERANCE`` of π may be its twin.
    """
    d = rotation_angle_between(r1, r2)
    worst = float(np.max(d)) if d.size else 0.0
    tol = atol + (TIE_ATOL if tie else 0.0)
    assert worst <= tol, f"rotations differ by {worst:.3e} rad > {tol:.1e} {msg}"


def assert_poses_close(
    g1, g2, atol: float = 1e-12, atol_t: float | None = None, msg: str = "", tie: bool = True
) -> None:
    """Poses (..., 6) = (rx, ry, rz, x, y, z) are equal up to ``atol`` rad and ``atol_t`` m.

    Rotations are compared by the angle of ``R1ᵀ R2`` (so ``r`` and ``-r`` at θ = π count as equal;
    ``tie`` as in :func:`assert_rotvecs_close`), translations by their largest absolute difference
    (``atol_t`` defaults to ``atol``).
    """
    g1 = np.asarray(g1, dtype=float)
    g2 = np.asarray(g2, dtype=float)
    assert g1.shape[-1] == 6 and g2.shape[-1] == 6, (g1.shape, g2.shape)
    assert np.all(np.isfinite(g1)) and np.all(np.isfinite(g2)), "non-finite pose"
    assert_rotvecs_close(g1[..., :3], g2[..., :3], atol, msg, tie=tie)
    tol_t = atol if atol_t is None else atol_t
    dt = np.max(np.abs(g1[..., 3:] - g2[..., 3:])) if g1.size else 0.0
    assert dt <= tol_t, f"translations differ by {dt:.3e} m > {tol_t:.1e} {msg}"


def assert_quats_close(q1, q2, atol: float = 1e-12, msg: str = "") -> None:
    """Quaternions (..., 4) are equal up to sign: ``min(‖q1 − q2‖, ‖q1 + q2‖) <= atol`` each."""
    q1 = np.asarray(q1, dtype=float)
    q2 = np.asarray(q2, dtype=float)
    assert np.all(np.isfinite(q1)) and np.all(np.isfinite(q2)), "non-finite quaternion"
    d = np.minimum(np.linalg.norm(q1 - q2, axis=-1), np.linalg.norm(q1 + q2, axis=-1))
    worst = float(np.max(d)) if d.size else 0.0
    assert worst <= atol, f"quaternions differ by {worst:.3e} > {atol:.1e} (up to sign) {msg}"


def assert_canonical(r, pi_tol: float = PI_TOLERANCE, axis_tol: float = AXIS_TOLERANCE) -> None:
    """Rotation vectors (..., 3) lie in the canonical ball B̃π (eq. 6, 7).

    θ <= π (plus round-off); where θ is within ``pi_tol`` of π the first component among u_z, u_y,
    u_x with ``|u_i| > axis_tol`` is positive.
    """
    r = np.asarray(r, dtype=float).reshape(-1, 3)
    theta = np.linalg.norm(r, axis=-1)
    assert np.all(theta <= PI + 4e-16 * PI), f"angle above π: {theta.max()!r}"
    for v, t in zip(r[theta >= PI - pi_tol], theta[theta >= PI - pi_tol]):
        u = v / t
        lead = next((c for c in (u[2], u[1], u[0]) if abs(c) > axis_tol), None)
        assert lead is not None and lead > 0, f"eq. 7 tie-break violated at θ = π: {v!r}"


# ---------------------------------------------------------------------------------------------
# Strategies
# ---------------------------------------------------------------------------------------------

_unit_float = st.floats(-1.0, 1.0, allow_nan=False, allow_infinity=False)


def _normalise(v) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


def axes() -> st.SearchStrategy[np.ndarray]:
    """Unit vectors: generic directions plus the coordinate axes and the u_z = 0 plane."""
    generic = st.tuples(_unit_float, _unit_float, _unit_float).filter(
        lambda v: math.hypot(*v) > 1e-3
    ).map(_normalise)
    in_xy_plane = st.floats(-PI, PI).map(lambda a: np.array([math.cos(a), math.sin(a), 0.0]))
    coordinate = st.sampled_from(
        [np.array(v, dtype=float) for v in
         [(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)]]
    )
    return st.one_of(generic, in_xy_plane, coordinate)


def uniform_rotvecs() -> st.SearchStrategy[np.ndarray]:
    """Haar-uniform rotations (scipy's sampler, seeded by Hypothesis), as canonical-ish rotvecs."""
    return st.integers(0, 2**32 - 1).map(lambda s: Rotation.random(rng=s).as_rotvec())


def angles() -> st.SearchStrategy[float]:
    """Rotation angles in [0, π]: uniform, near 0, near π, exactly 0 and exactly π."""
    return st.one_of(
        st.floats(0.0, PI),
        st.floats(-9.0, -5.0).map(lambda e: 10.0**e),
        st.floats(-9.0, -4.0).map(lambda e: PI - 10.0**e),
        st.just(PI),
        st.just(0.0),
    )


def rotvecs() -> st.SearchStrategy[np.ndarray]:
    """Rotation vectors θu with θ ∈ [0, π] (shape (3,)), weighted towards the hard cases."""
    axis_angle = st.builds(lambda u, t: t * u, axes(), angles())
    exactly_pi = axes().map(lambda u: PI * u)
    return st.one_of(uniform_rotvecs(), axis_angle, exactly_pi)


def raw_rotvecs() -> st.SearchStrategy[np.ndarray]:
    """Any rotation vectors (not canonical): ‖r‖ up to 4π, the θ = π twins, and ``rotvecs()``."""
    big = st.builds(lambda u, t: t * u, axes(), st.floats(0.0, 4 * PI))
    near_2pi = st.builds(lambda u, e: (2 * PI - 10.0**e) * u, axes(), st.floats(-9.0, -3.0))
    return st.one_of(rotvecs(), big, near_2pi, rotvecs().map(lambda r: -r))


def quats() -> st.SearchStrategy[np.ndarray]:
    """Unit quaternions (x, y, z, w) of ``rotvecs()`` with a random sign, shape (4,).

    Built from θ and u directly (``(sin(θ/2) u, cos(θ/2))``), not with the code under test.
    """

    def make(r, sign):
        t = float(np.linalg.norm(r))
        u = r / t if t > 0 else np.zeros(3)
        return sign * np.concatenate([math.sin(t / 2) * u, [math.cos(t / 2)]])

    return st.builds(make, rotvecs(), st.sampled_from([1.0, -1.0]))


def translations(scale: float = 5.0) -> st.SearchStrategy[np.ndarray]:
    f = st.floats(-scale, scale, allow_nan=False, allow_infinity=False)
    return st.tuples(f, f, f).map(lambda v: np.array(v, dtype=float))


def poses() -> st.SearchStrategy[np.ndarray]:
    """Poses (rx, ry, rz, x, y, z), shape (6,): ``rotvecs()`` and translations up to ±5 m."""
    return st.builds(lambda r, t: np.concatenate([r, t]), rotvecs(), translations())


def stacked(strategy: st.SearchStrategy[np.ndarray], shape: tuple[int, ...]) -> st.SearchStrategy[np.ndarray]:
    """Arrays of shape ``shape + item.shape`` drawn element by element from ``strategy``."""
    n = int(np.prod(shape))
    return st.lists(strategy, min_size=n, max_size=n).map(
        lambda items: np.stack(items).reshape(shape + items[0].shape)
    )


# ---------------------------------------------------------------- elementary rotations, by hand
# Independent oracles for the vendor readers' Euler conventions: the rotation matrix about one
# world axis by an angle in degrees, written out (no library involved).
def rx(a):
    c, s = np.cos(np.radians(a)), np.sin(np.radians(a))
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def ry(a):
    c, s = np.cos(np.radians(a)), np.sin(np.radians(a))
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def rz(a):
    c, s = np.cos(np.radians(a)), np.sin(np.radians(a))
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


class NonSeekable(io.RawIOBase):
    """A byte stream that cannot seek and returns at most ``chunk`` bytes per read, like a pipe."""

    def __init__(self, data: bytes, chunk: int = 777):
        self._b = io.BytesIO(data)
        self._chunk = int(chunk)

    def readable(self):
        return True

    def seekable(self):
        return False

    def readinto(self, b):
        part = self._b.read(min(len(b), self._chunk))
        b[: len(part)] = part
        return len(part)
