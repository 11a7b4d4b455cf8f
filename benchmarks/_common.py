"""Shared synthetic data and helpers for the benchmarks (not part of the library).

Poses: rotations drawn uniformly (Haar) from SO(3), stored as canonical rotation vectors
(rx, ry, rz); translations ~ N(0, 0.3²) m per axis. Outputs: six smooth functions of the *rotation*
(functions of the rotation matrix R, so they are well defined and continuous on SO(3), also across
the θ = π wrap of the rotation vector) and of the translation, plus Gaussian noise:

    ω = −k · vee((R − Rᵀ)/2) + 0.3 · (R e_z) × e_x        (= −k sin θ u + …: pulls towards the identity)
    v = −t + 0.2 · R e_z + 0.1 · sin(3 t)

so the six outputs can also be read as a velocity field ξ = (ω, v) (world frame) for rollouts.

Everything is seeded: the same ``seed`` gives bit-identical data.
"""

from __future__ import annotations

import functools
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np

# Run from a checkout without installing: make ``rbgp_cli`` importable.
_ROOT = Path(__file__).resolve().parents[1]
if str(_ROOT) not in sys.path:
    sys.path.insert(0, str(_ROOT))

from rbgp_cli.geometry.so3 import matrix_from_quat, random_quat, rotvec_from_quat  # noqa: E402

__all__ = ["synthetic_poses", "velocity_field", "synthetic_data", "median_time", "machine_line", "fmt_s",
           "limit_blas_threads", "blas_line"]

#: Standard deviation of the observation noise added to every output.
NOISE_STD = 0.05
#: Standard deviation (m) of each translation coordinate.
TRANSLATION_STD = 0.3


def synthetic_poses(n: int, seed: int = 0):
    """``n`` random poses: (quat (n, 4) x, y, z, w with w >= 0, X (n, 6) = (rx, ry, rz, x, y, z)).

    Rotations uniform on SO(3) as canonical rotation vectors; translations ~ N(0, 0.3²) per axis.
    """
    rng = np.random.default_rng(seed)
    q = random_quat(rng, n)
    t = rng.normal(0.0, TRANSLATION_STD, (n, 3))
    return q, np.concatenate([rotvec_from_quat(q), t], axis=1)


def velocity_field(quat: np.ndarray, t: np.ndarray, k: float = 0.8) -> np.ndarray:
    """The noise-free smooth outputs ξ = (ω, v), shape (n, 6), at poses (quat (n, 4), t (n, 3))."""
    R = matrix_from_quat(quat)  # (n, 3, 3)
    A = 0.5 * (R - np.swapaxes(R, -1, -2))
    axis = np.stack([A[:, 2, 1], A[:, 0, 2], A[:, 1, 0]], axis=1)  # sin θ · u
    ez = R[:, :, 2]
    w = -k * axis + 0.3 * np.cross(ez, np.array([1.0, 0.0, 0.0]))
    v = -t + 0.2 * ez + 0.1 * np.sin(3.0 * t)
    return np.concatenate([w, v], axis=1)


def synthetic_data(n: int, seed: int = 0, noise_std: float = NOISE_STD):
    """(quat (n, 4), X (n, 6), Y (n, 6)): random poses and noisy smooth outputs (module docstring)."""
    q, X = synthetic_poses(n, seed)
    rng = np.random.default_rng(seed + 1_000_003)
    Y = velocity_field(q, X[:, 3:]) + rng.normal(0.0, noise_std, (n, 6))
    return q, X, Y


def median_time(fn, repeats: int = 7, warmup: int = 1) -> tuple[float, list[float]]:
    """Median wall time (s) of ``fn()`` over ``repeats`` calls after ``warmup`` untimed ones."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), times


def compile_package() -> str:
    """Write rbgp_cli's bytecode (``__pycache__``, ignored by git) before timing whole processes, as an
    installed package has it (pip compiles a wheel's modules at install). Without it, where
    ``PYTHONDONTWRITEBYTECODE`` is set (as on this project's shared machine), every process that imports
    rbgp compiles its modules from source: 0.12 s of CPU for ``rbgp train``'s start-up imports alone and
    about 0.5 s in all, measured in issue 35's fourth pass. Returns a line for the log."""
    import subprocess

    root = Path(__file__).resolve().parents[1]
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    res = subprocess.run([sys.executable, "-m", "compileall", "-q", str(root / "rbgp_cli")], env=env,
                         capture_output=True, text=True)
    return "rbgp_cli's bytecode " + ("written (compileall)" if res.returncode == 0 else
                                     f"NOT written ({res.stderr.strip()[-200:]})")


def machine_line() -> str:
    """One line describing the machine and the load when called."""
    try:
        load = ", ".join(f"{x:.2f}" for x in os.getloadavg())
    except OSError:
        load = "n/a"
    import numpy
    import scipy

    return (f"rbgp {git_revision()}; {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, "
            f"numpy {numpy.__version__}, scipy {scipy.__version__}; load average (1, 5, 15 min): {load}")


@functools.lru_cache(maxsize=None)
def git_revision() -> str:
    """Short commit of the checkout the library is imported from (+ "-dirty" if rbgp_cli/ has local changes),
    as it was at the first call (the start of the run: the library's modules are imported then)."""
    import subprocess

    try:
        rev = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=_ROOT, capture_output=True, text=True,
                             timeout=10).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--", "rbgp_cli"], cwd=_ROOT, capture_output=True,
                               text=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return "unknown revision"
    return (rev or "unknown revision") + ("-dirty" if dirty else "")


def limit_blas_threads(n: int | None):
    """Limit every BLAS/OpenMP pool in the process (numpy's and scipy's OpenBLAS, sklearn's OpenMP) to
    ``n`` threads for the rest of the run (threadpoolctl, a scikit-learn dependency). None: leave them."""
    if n is None:
        return None
    from threadpoolctl import threadpool_limits

    return threadpool_limits(limits=int(n))


def blas_line() -> str:
    """The BLAS pools loaded in this process and their thread counts."""
    try:
        from threadpoolctl import threadpool_info
    except ImportError:
        return "BLAS pools: unknown (threadpoolctl not installed)"
    parts = [f"{Path(d['filepath']).name} ({d['internal_api']}, {d['num_threads']} threads)" for d in threadpool_info()]
    return "BLAS pools: " + "; ".join(parts)


def fmt_s(x: float) -> str:
    """Seconds with about three significant digits."""
    if x != x:  # NaN
        return "–"
    if x >= 100:
        return f"{x:.0f}"
    if x >= 10:
        return f"{x:.1f}"
    if x >= 1:
        return f"{x:.2f}"
    return f"{x:.3g}"
