"""A motion model: a representation, a fitted GP on its training pairs, and how it was made.

:func:`train_model` is the one library call behind ``rbgp train``: demonstrations → training pairs
(MATH.md §4, §6) → subsample (paper sec. 4.3: 10 % random) → exact GP fit (MATH.md §7).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from rbgp_cli.dynamics.representations import Representation, make_representation
from rbgp_cli.dynamics.trajectory import Trajectory
from rbgp_cli.errors import InputError
from rbgp_cli.gp.exact import GaussianProcess, default_jobs, fit_gp
from rbgp_cli.kernels import DotProduct, Kernel, SquaredExponential

__all__ = ["MotionModel", "make_kernel", "training_set", "train_model", "KERNELS"]

KERNELS = ("se", "se-chordal", "dot")


def make_kernel(representation: Representation, kernel: str = "se", rho_rot: float = 0.7, learn_rho: bool = False) -> Kernel:
    """The kernel for a representation (MATH.md §6).

    ``se`` is the paper's squared exponential on the representation's own rotation distance: the
    geodesic arc distance for axis-angle (eq. 24), Euclidean on Euler angles, the S³ angle for
    quaternions. ``se-chordal`` replaces the rotation distance by the chordal one (PD for every λ; not
    defined on Euler angles). ``dot`` is the dot-product kernel (eq. 22).
    """
    rd = representation.rotation_dims
    if kernel == "se":
        metric = {"axis-angle": "arc", "euler": "euclidean", "quaternion": "s3"}[representation.name]
        return SquaredExponential(metric, rd, rho_rot, learn_rho)
    if kernel == "se-chordal":
        if representation.name == "euler":
            raise InputError("--kernel se-chordal needs a rotation representation (axis-angle or quaternion), not euler")
        return SquaredExponential("chordal", rd, rho_rot, learn_rho)
    if kernel == "dot":
        return DotProduct(rd, rho_rot, learn_rho)
    raise InputError(f"unknown kernel {kernel!r}; expected one of {', '.join(KERNELS)}")


@dataclass
class MotionModel:
    """Everything needed to predict and to say how it was made.

    representation : how poses become GP inputs and outputs integrate back
    gp : the fitted GP (inputs X (n, d), outputs Y (n, L))
    dt : the demonstrations' median time step, seconds (default rollout step)
    starts : demonstrations' start poses, shape (D, 7) = (qx, qy, qz, qw, x, y, z)
    durations : demonstrations' durations, seconds, shape (D,)
    summary : plain-data training summary; provenance : inputs, options, version, time
    """

    representation: Representation
    gp: GaussianProcess
    dt: float
    starts: np.ndarray
    durations: np.ndarray
    summary: dict = field(default_factory=dict)
    provenance: dict = field(default_factory=dict)

    def predict(self, quat, position, return_std: bool = True, noisy: bool = False):
        """Output mean and std at poses (quat (m, 4) x, y, z, w; position (m, 3))."""
        X = self.representation.state_from_pose(np.asarray(quat, float).reshape(-1, 4), np.asarray(position, float).reshape(-1, 3))
        return self.gp.predict(X, return_std=return_std, noisy=noisy)


def training_set(trajs: list[Trajectory], representation: Representation, *, subsample: float | None = 0.1,
                 max_points: int | None = None, seed: int = 0):
    """All training pairs of all demonstrations, then a seeded random subset.

    Returns X (n, d), Y (n, L) and a dict with ``pairs`` (before subsampling), ``points`` (after),
    ``per_demo`` pair counts and the chosen ``indices`` into the concatenated pairs.
    """
    if not trajs:
        raise InputError("no demonstrations given", hint="pass one or more demonstration files")
    representation.prepare(trajs)
    Xs, Ys, per_demo = [], [], []
    for tr in trajs:
        X, Y, _ = representation.training_pairs(tr)
        Xs.append(X)
        Ys.append(Y)
        per_demo.append(len(X))
    X = np.concatenate(Xs)
    Y = np.concatenate(Ys)
    n = len(X)
    if n < 2:  # two samples give one velocity: nothing for a GP to fit (nor a length scale to learn)
        sources = sorted({tr.source or tr.name for tr in trajs if tr.source or tr.name})
        raise InputError(
            f"the demonstrations give {n} training pair{'s' * (n != 1)} (one velocity per two consecutive "
            "samples); a GP needs at least 2",
            path=", ".join(sources) or None,
            hint="train on demonstrations with 3 or more samples",
        )
    rng = np.random.default_rng(seed)
    k = n
    if subsample is not None:
        if not 0 < subsample <= 1:
            raise InputError(f"--subsample must lie in (0, 1], got {subsample}")
        k = max(min(n, 2), int(round(subsample * n)))
    if max_points is not None:
        k = min(k, int(max_points))
    idx = np.sort(rng.choice(n, size=k, replace=False)) if k < n else np.arange(n)
    return X[idx], Y[idx], {"pairs": int(n), "points": int(len(idx)), "per_demo": per_demo, "indices": idx}


def train_model(
    trajs: list[Trajectory],
    *,
    representation: str = "axis-angle",
    kernel: str = "se",
    rho_rot: float | str = 0.7,
    restarts: int = 3,
    seed: int = 0,
    noise=None,
    shared: bool = False,
    subsample: float | None = 0.1,
    max_points: int | None = 2000,
    euler_order: str = "xyz",
    progress=None,
    explore_size: int | None = None,
    jobs: int | None = None,
) -> MotionModel:
    """Train a motion model on clean demonstrations (see :func:`rbgp_cli.dynamics.prepare.prepare_all`).

    ``rho_rot`` is ρ1 of eq. 19 (a number in (0, 1)) or ``"learn"``. ``noise`` is None to learn σn or
    a fixed standard deviation. ``explore_size``: the optimiser's starts explore a random subset of
    this many training points first (see :func:`rbgp_cli.gp.exact.fit_gp`; None: its default, 0: off). ``jobs``:
    worker processes for the per-output fits (None: :func:`rbgp_cli.gp.exact.default_jobs`: one per
    output if memory allows, 1 inside a worker process or on a single core). Returns the model; its ``summary`` holds demos, pairs, points, the
    hyperparameters and NLML per output, the safeguards used and the time taken.
    """
    t0 = time.perf_counter()
    rep = make_representation(representation, order=euler_order) if representation == "euler" else make_representation(representation)
    learn_rho = rho_rot == "learn"
    rho = 0.7 if learn_rho else float(rho_rot)
    if not learn_rho and not 0 < rho < 1:
        raise InputError(f"--rho-rot must lie strictly between 0 and 1 (or be 'learn'), got {rho_rot}")
    kern = make_kernel(rep, kernel, rho, learn_rho)
    X, Y, info = training_set(trajs, rep, subsample=subsample, max_points=max_points, seed=seed)
    if progress:
        progress(f"{len(trajs)} demonstrations, {info['pairs']} pairs, training on {info['points']} points "
                 f"({rep.name}, kernel {kernel}, {'shared' if shared else 'per-output'} hyperparameters)")
    if jobs is None:
        jobs = default_jobs(1 if shared else Y.shape[1], len(X))
    gp = fit_gp(X, Y, kern, noise=noise, restarts=restarts, seed=seed, shared=shared, progress=progress,
                explore_size=explore_size, jobs=jobs)
    dts = np.concatenate([np.diff(tr.t) for tr in trajs])
    starts = np.array([np.concatenate([tr.quat[0], tr.position[0]]) for tr in trajs])
    durations = np.array([tr.duration for tr in trajs])
    names = ["all"] if shared else list(rep.output_names)
    summary = {
        "representation": rep.name,
        "kernel": kernel,
        "rotation_metric": getattr(kern, "metric", None),
        "demos": len(trajs),
        "pairs": info["pairs"],
        "points": info["points"],
        "shared_hyperparameters": bool(shared),
        "outputs": [
            {"output": nm, **{k: v for k, v in f.to_dict().items() if k not in ("starts",)}}
            for nm, f in zip(names, gp.fits)
        ],
        "safeguards": {
            "jitter_used": any(f.jitter > 0 for f in gp.fits),
            "all_positive_definite": all(f.positive_definite for f in gp.fits),
            "infeasible_evaluations": int(sum(f.n_infeasible for f in gp.fits)),
            "refit_with_noise_margin": [nm for nm, f in zip(names, gp.fits) if f.guarded],
        },
        "seconds": time.perf_counter() - t0,
    }
    return MotionModel(rep, gp, float(np.median(dts)), starts, durations, summary=summary)
