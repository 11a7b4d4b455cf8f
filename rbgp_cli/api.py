"""The Python API: read demonstrations, fit a motion model, roll it out, score and cross-validate.

A thin facade over the library (:mod:`rbgp_cli.io.read`, :mod:`rbgp_cli.dynamics`,
:mod:`rbgp_cli.evaluation`, :mod:`rbgp_cli.io.model_store`) in the manner of scikit-learn: an estimator
:class:`RigidBodyGP` with the options of ``rbgp train`` and the same defaults, and plain result objects
with ``to_dict()`` and ``to_frame()`` (a pandas DataFrame; pandas is imported only there).

Pose layout, the same everywhere in this API
--------------------------------------------
* quaternions ``(..., 4)`` in the order **x, y, z, w** (unit norm),
* positions ``(..., 3)`` in **metres**, times in **seconds**,
* a start pose or a list of poses is one array ``(n, 7) = (qx, qy, qz, qw, x, y, z)``, or a pair
  ``(quat (n, 4), position (n, 3))``; one pose may be given as a ``(7,)`` array.

Errors are :class:`rbgp_cli.errors.InputError` (a :class:`ValueError`) naming the parameter
(``exc.param``); the command line shows the matching ``--option`` instead.

Examples
--------
>>> import rbgp_cli as rbgp
>>> demos = rbgp.read_demonstrations(rbgp.SAMPLE_DATA / "csv")
>>> model = rbgp.RigidBodyGP(restarts=1, max_points=150, share_hyperparameters=True).fit(demos)
>>> res = model.rollout(demos[0], steps=20)
>>> res.quat.shape, res.position.shape
((1, 21, 4), (1, 21, 3))
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rbgp_cli.dynamics.defaults import DEFAULTS
from rbgp_cli.errors import InputError

__all__ = [
    "read_demonstrations", "RigidBodyGP", "Rollout", "Evaluation", "Crossval", "evaluate", "crossval",
    "start_poses", "train_options",
]


# --------------------------------------------------------------------------------------------- poses
def _goal_keywords(count: int, goals, via, goal_tolerance) -> dict:
    """:meth:`RigidBodyGP.rollout`'s goals, via-points and tolerance as keywords of
    :func:`~rbgp_cli.workflows.rollout_model` (goals broadcast to ``count`` starts)."""
    from rbgp_cli.dynamics.trajectory import Trajectory

    out: dict = {}
    if goals is not None:
        if isinstance(goals, Trajectory):
            goals = [goals]
        if isinstance(goals, (list, tuple)) and goals and all(isinstance(t, Trajectory) for t in goals):
            goals = (np.array([t.quat[-1] for t in goals]), np.array([t.position[-1] for t in goals]))
        gq, gp = start_poses(goals)
        if len(gq) not in (1, count):
            raise InputError(f"{len(gq)} goals for {count} starts", param="goals", hint="give one goal, or one per start")
        out["goal_quat"], out["goal_position"] = np.broadcast_to(gq, (count, 4)).copy(), np.broadcast_to(gp, (count, 3)).copy()
    if via:
        points = []
        for item in via:
            try:
                tv, pose = item
                tv = float(tv)
            except (TypeError, ValueError):
                raise InputError(f"a via-point must be a pair (T seconds, pose), got {item!r}", param="via") from None
            if not (np.isfinite(tv) and tv > 0):
                raise InputError(f"a via-point's time must be a positive number of seconds, got {tv}", param="via")
            qv, pv = start_poses(pose)
            points.append((tv, qv[0], pv[0]))
        out["via"] = points
    if goal_tolerance is not None:
        from rbgp_cli.dynamics.paths import MAX_GOAL_TOLERANCE

        tol = np.asarray(goal_tolerance, dtype=np.float64).reshape(-1)
        if tol.shape != (2,) or not np.all((tol > 0) & (tol <= MAX_GOAL_TOLERANCE)):
            raise InputError(f"goal_tolerance must be two positive numbers (rad, m) up to {MAX_GOAL_TOLERANCE:g}, "
                             f"got {goal_tolerance!r}", param="goal_tolerance")
        out["goal_tolerance"] = (float(tol[0]), float(tol[1]))
    return out


def start_poses(poses) -> tuple[np.ndarray, np.ndarray]:
    """Poses in the API's layout as ``(quat (n, 4) x, y, z, w unit, position (n, 3) m)``.

    Parameters
    ----------
    poses : array (7,) or (n, 7) ``(qx, qy, qz, qw, x, y, z)``; a pair ``(quat, position)``; a
        :class:`~rbgp_cli.dynamics.trajectory.Trajectory` (its first pose) or a list of them.

    Examples
    --------
    >>> q, p = start_poses([0, 0, 0, 1, 0.1, 0.2, 0.3])
    >>> q.shape, p.tolist()
    ((1, 4), [[0.1, 0.2, 0.3]])
    """
    from rbgp_cli.dynamics.prepare import ZERO_QUAT_NORM
    from rbgp_cli.dynamics.trajectory import Trajectory

    if isinstance(poses, Trajectory):
        poses = [poses]
    if isinstance(poses, (list, tuple)) and poses and all(isinstance(t, Trajectory) for t in poses):
        from rbgp_cli.dynamics.rollout import start_vectors

        v = start_vectors(poses)
        q, p = v[:, :4], v[:, 4:]
    elif isinstance(poses, tuple) and len(poses) == 2 and np.ndim(poses[0]) >= 1 and np.shape(poses[0])[-1] == 4:
        q = np.asarray(poses[0], float).reshape(-1, 4)
        p = np.asarray(poses[1], float).reshape(-1, 3)
    else:
        a = np.asarray(poses, float)
        if a.ndim not in (1, 2) or a.shape[-1] != 7:
            raise InputError(f"poses must be an array (n, 7) of qx, qy, qz, qw, x, y, z, got shape {a.shape}",
                             param="poses", hint="or a pair (quat (n, 4), position (n, 3))")
        a = a.reshape(-1, 7)
        q, p = a[:, :4], a[:, 4:]
    if len(q) != len(p) or len(q) == 0:
        raise InputError(f"poses: {len(q)} quaternions and {len(p)} positions", param="poses")
    if not (np.all(np.isfinite(q)) and np.all(np.isfinite(p))):
        raise InputError("poses must be finite numbers", param="poses")
    norm = np.linalg.norm(q, axis=1)
    if np.any(norm < ZERO_QUAT_NORM):
        raise InputError("poses hold a zero quaternion, which is no rotation", param="poses",
                         hint="quaternions are x, y, z, w: (0, 0, 0, 1) is no rotation")
    return q / norm[:, None], p


# --------------------------------------------------------------------------------------------- reading
def _as_trajectory(item, i: int):
    from rbgp_cli.dynamics.trajectory import Trajectory

    if isinstance(item, Trajectory):
        return item
    if isinstance(item, dict):
        t, q, p = item.get("t"), item.get("quat"), item.get("position")
        name = str(item.get("name", i))
    else:
        t, q, p = item
        name = str(i)
    if t is None or q is None or p is None:
        raise InputError("a demonstration given as a dict needs the keys t, quat and position", param="sources")
    return Trajectory(np.asarray(t, float), np.asarray(q, float), np.asarray(p, float), name=name, source="array")


def read_demonstrations(sources, *, max_gap: float | None = None, **read_options) -> list:
    """Read and clean demonstrations, as ``rbgp train`` does.

    Parameters
    ----------
    sources : a path (file or folder, str or Path), a list of them, or arrays: one or a list of
        ``(t (n,), quat (n, 4), position (n, 3))`` tuples or dicts with the keys t, quat, position
        (and optionally name), or :class:`~rbgp_cli.dynamics.trajectory.Trajectory` objects.
    max_gap : fill runs of lost frames up to this many seconds by slerp (default: drop them).
    **read_options : the fields of :class:`rbgp_cli.io.options.ReadOptions` (``format``, ``columns``
        (a dict), ``quat_order``, ``euler_order``, ``degrees``, ``length_unit``, ``time_unit``, ``rate``,
        ``topic``, ``frame``, ``time_source``, ``body``, ``rotation``, ``split_gap``, ``crop_from``,
        ``crop_to``, ``split_at_rest``, ``rest_speed``, ``rest_time``): as the options of ``rbgp train``.

    Returns
    -------
    list of Trajectory
        Each with ``t`` (n,) s, ``quat`` (n, 4) x, y, z, w and ``position`` (n, 3) m, ``name`` and ``source``.

    Examples
    --------
    >>> import rbgp_cli as rbgp
    >>> demos = rbgp.read_demonstrations(rbgp.SAMPLE_DATA / "csv")
    >>> len(demos), demos[0].quat.shape[1], demos[0].position.shape[1]
    (9, 4, 3)
    """
    from rbgp_cli.io.options import ReadOptions

    try:
        options = ReadOptions(**read_options)
    except TypeError as exc:
        import dataclasses

        names = [f.name for f in dataclasses.fields(ReadOptions)]
        raise InputError(f"unknown read option: {exc}", hint=f"expected some of {', '.join(names)}") from None
    items = sources if isinstance(sources, (list, tuple)) else [sources]
    if isinstance(sources, tuple) and len(sources) == 3 and not isinstance(sources[0], (str, Path)):
        items = [sources]  # one (t, quat, position)
    if not items:
        raise InputError("no demonstrations given", param="sources", hint="pass one or more files or a directory")
    if all(isinstance(s, (str, Path)) for s in items):
        from rbgp_cli.workflows import load_demonstrations

        demos, _, _ = load_demonstrations([str(s) for s in items], options, max_gap=max_gap)
        return demos
    from rbgp_cli.dynamics.prepare import prepare_all

    raw = [_as_trajectory(s, i) for i, s in enumerate(items)]
    demos, _ = prepare_all(raw, max_gap=max_gap, **options.prepare_kwargs())
    return demos


def _demos(demos) -> list:
    from rbgp_cli.dynamics.trajectory import Trajectory

    if isinstance(demos, (list, tuple)) and demos and all(isinstance(t, Trajectory) for t in demos):
        return list(demos)
    return read_demonstrations(demos)


# --------------------------------------------------------------------------------------------- options
def _number(value, name: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a number, got {value!r}", param=name) from None
    if not np.isfinite(v):
        raise InputError(f"{name} must be finite, got {value!r}", param=name)
    return v


def _choice(value, name: str, choices: tuple):
    value = "none" if value is None else value
    if value not in choices:
        raise InputError(f"{name} must be one of {', '.join(choices)}, got {value!r}", param=name)
    return None if value == "none" else value


#: Largest fixed noise std and noise scale accepted: far beyond any use (velocities in rad/s and m/s;
#: the defaults are learnt and 256), and small enough that σn², with the calibration's factors (up to
#: 4096) and the scale, stays a finite double.
MAX_NOISE = 1e50
MAX_NOISE_SCALE = 1e100


def train_options(*, rho_rot=DEFAULTS["rho_rot"], restarts: int = DEFAULTS["restarts"],
                  explore_size: int = DEFAULTS["explore_size"], seed: int = 0, noise="learn",
                  share_hyperparameters: bool = False, subsample: float = DEFAULTS["subsample"],
                  max_points: int = DEFAULTS["max_points"], train_rate=DEFAULTS["train_rate"],
                  smooth_window: float = DEFAULTS["smooth_window"], smooth_degree: int = DEFAULTS["smooth_degree"],
                  time_input=DEFAULTS["time_input"], prior=DEFAULTS["prior"], prior_gain: float = DEFAULTS["prior_gain"],
                  inducing: int | None = None, hyper_points: int | None = None,
                  calibrate_noise: bool = DEFAULTS["calibrate"],
                  start_conditioning: bool = DEFAULTS["start_conditioning"],
                  noise_scale: float = DEFAULTS["noise_scale"],
                  pull_profile: bool = DEFAULTS["pull_profile"],
                  residual_gain=DEFAULTS["residual_gain"]) -> dict:
    """Check the training options (named and spelled as ``rbgp train``'s, with ``_`` for ``-``) and
    build the keyword arguments of :func:`rbgp_cli.dynamics.model.train_model` (without representation,
    kernel and jobs). ``noise`` is ``"learn"`` or a positive number; ``time_input`` and ``prior`` accept
    None or ``"none"``; ``train_rate`` 0 or None keeps the recorded samples; ``noise_scale`` ≥ 1;
    ``residual_gain`` ``"auto"`` or a number from 0 to 100 (the gain on the GP's residual mean).

    Examples
    --------
    >>> train_options(noise=1.0)["noise"]
    1.0
    """
    from rbgp_cli.dynamics.velocities import VelocityOptions

    rho = rho_rot if rho_rot == "learn" else _number(rho_rot, "rho_rot")
    noise_v = None if noise == "learn" else _number(noise, "noise")
    if noise_v is not None and not 0 < noise_v <= MAX_NOISE:
        raise InputError(f"noise must be 'learn' or a positive number up to {MAX_NOISE:g}, got {noise}", param="noise")
    time_in = _choice(time_input, "time_input", ("none", "seconds", "phase"))
    prior_v = _choice(prior, "prior", ("none", "goal", "path"))
    scale = _number(noise_scale, "noise_scale")
    if not 1.0 <= scale <= MAX_NOISE_SCALE:
        raise InputError(f"noise_scale must be a number from 1 to {MAX_NOISE_SCALE:g}, got {noise_scale}",
                         param="noise_scale")
    try:
        gain = "auto" if str(residual_gain).strip().lower() == "auto" else float(residual_gain)
    except (TypeError, ValueError):
        gain = float("nan")
    if gain != "auto" and not (np.isfinite(gain) and 0.0 <= gain <= 100.0):
        raise InputError(f"residual_gain must be 'auto' or a number from 0 to 100, got {residual_gain}",
                         param="residual_gain", hint="1 is the GP's full residual, 0 the path distribution alone")
    if prior_v == "path" and time_in != "phase":
        raise InputError("prior path follows the phase of the motion", param="prior",
                         hint="add time_input phase, or use prior goal or none")
    return {
        "rho_rot": rho, "restarts": restarts, "explore_size": explore_size, "seed": seed, "noise": noise_v,
        "shared": share_hyperparameters, "subsample": subsample, "max_points": max_points,
        "velocity": VelocityOptions(rate=train_rate or None, window=smooth_window, degree=smooth_degree),
        "time_input": time_in, "prior": prior_v, "prior_gain": prior_gain, "inducing": inducing,
        **({"hyper_points": hyper_points} if hyper_points is not None else {}),
        "calibrate": bool(calibrate_noise),
        "start_conditioning": bool(start_conditioning),
        "noise_scale": scale,
        "pull_profile": bool(pull_profile),
        "residual_gain": gain,
    }


# --------------------------------------------------------------------------------------------- results
def _frame(records):
    import pandas as pd

    return pd.DataFrame.from_records(records)


@dataclass
class Rollout:
    """Rolled-out motions: B mean trajectories on a common grid, their std and K samples per start.

    Attributes
    ----------
    t : (S,) seconds from the start
    quat : (B, S, 4) x, y, z, w;  position : (B, S, 3) metres
    std : (B, S, L) predictive std of the L velocity outputs (``output_names``), or None
    sample_quat : (B, K, S, 4) and sample_position : (B, K, S, 3), or None (``samples=0``)
    lengths : (B,) samples each mean trajectory keeps (shorter when it was stopped or has its own
        duration); the arrays are padded past it with the values the integration gave
    left_data : (B, S) True where a mean trajectory lies outside the demonstrations' envelope
    result : the library's :class:`~rbgp_cli.dynamics.rollout.RolloutResult`
    """

    t: np.ndarray
    quat: np.ndarray
    position: np.ndarray
    std: np.ndarray | None
    output_names: tuple
    sample_quat: np.ndarray | None
    sample_position: np.ndarray | None
    lengths: np.ndarray
    left_data: np.ndarray | None
    result: object = field(repr=False, default=None)

    @classmethod
    def _of(cls, res) -> "Rollout":
        lengths = np.array([res.length(b) for b in range(res.count)], int)
        return cls(t=res.t, quat=res.quat, position=res.position, std=res.std, output_names=tuple(res.output_names),
                   sample_quat=res.sample_quat, sample_position=res.sample_position, lengths=lengths,
                   left_data=res.outside, result=res)

    @property
    def count(self) -> int:
        """B, the number of mean trajectories."""
        return int(self.quat.shape[0])

    @property
    def goal_distance(self) -> np.ndarray | None:
        """(B,) how far each goal lies from where the demonstrations end given its start, in their
        spreads (docs/method.md §12; above 4.5 rbgp warns), or None without goals."""
        return getattr(self.result, "goal_distance", None)

    @property
    def via_distance(self) -> np.ndarray | None:
        """(B, V) how far each via-point lies from where the demonstrations pass at its phase given each
        start, in their spreads (docs/method.md §12; above 4.5 rbgp warns), or None without via-points."""
        return getattr(self.result, "via_distance", None)

    @property
    def band_position(self) -> np.ndarray | None:
        """(B, S, 3) m: per axis the half-width of the 90 % band of the next real motion around each mean
        trajectory (with samples from a model with a variation model or a goal; docs/method.md §11), or None.
        The samples are typical motions; the band is wider (it carries the estimates' uncertainty)."""
        return getattr(self.result, "band_position", None)

    @property
    def band_rotation(self) -> np.ndarray | None:
        """(B, S, 3, 3) rad²: the band's rotation region {e : eᵀ M⁻¹ e ≤ 1} of e = log(R R_meanᵀ) (world
        frame), or None (see :attr:`band_position`)."""
        return getattr(self.result, "band_rotation", None)

    @property
    def band_widening(self) -> np.ndarray | None:
        """(B, 2): the factors ≥ 1 each start's surprise widened its band's rotation and position part by (a start
        less like the demonstrations' starts than any of theirs, :attr:`start_beyond`; or than three in four of
        theirs, where the model keeps that; docs/method.md §11), or None (no band)."""
        return getattr(self.result, "band_widening", None)

    @property
    def start_beyond(self) -> np.ndarray | None:
        """(B,): each start's surprise over the largest of the demonstrations' own (each left out against the
        others), ρ / ρ_max: above 1 a start less like the demonstrations' starts than any of theirs was like the
        others', whose band is widened by √(ρ / ρ_max) (docs/method.md §11); None for a model of fewer than five
        demonstrations or an older model file."""
        return getattr(self.result, "start_beyond", None)

    def trajectories(self, include_samples: bool = False) -> list:
        """The mean trajectories (names ``0``, ``1``, …) and optionally the samples (``0.s0``, …) as
        :class:`~rbgp_cli.dynamics.trajectory.Trajectory` objects, each cut to its length (what
        :func:`evaluate` takes)."""
        return self.result.trajectories(include_samples=include_samples)

    def to_dict(self) -> dict:
        """Plain lists: ``{"t", "quat", "position", "std", "output_names", "lengths", "sample_quat",
        "sample_position", "left_data"}`` (None where absent)."""
        def lst(a):
            return None if a is None else np.asarray(a).tolist()

        return {"t": lst(self.t), "quat": lst(self.quat), "position": lst(self.position), "std": lst(self.std),
                "output_names": list(self.output_names), "lengths": lst(self.lengths),
                "sample_quat": lst(self.sample_quat), "sample_position": lst(self.sample_position),
                "left_data": lst(self.left_data)}

    def to_frame(self, include_samples: bool = True):
        """One row per trajectory and time: columns ``trajectory, sample, t, qx, qy, qz, qw, x, y, z``
        (``sample`` -1 for the mean, else k), then ``std_<output>`` (means only) and ``left_data``."""
        import pandas as pd

        parts = []
        for b in range(self.count):
            n = int(self.lengths[b])
            d = {"trajectory": b, "sample": -1, "t": self.t[:n]}
            d.update(zip(("qx", "qy", "qz", "qw"), self.quat[b, :n].T))
            d.update(zip(("x", "y", "z"), self.position[b, :n].T))
            if self.std is not None:
                d.update({f"std_{o}": self.std[b, :n, j] for j, o in enumerate(self.output_names)})
            if self.left_data is not None:
                d["left_data"] = self.left_data[b, :n]
            parts.append(pd.DataFrame(d))
            if include_samples and self.sample_quat is not None:
                for k in range(self.sample_quat.shape[1]):
                    d = {"trajectory": b, "sample": k, "t": self.t[:n]}
                    d.update(zip(("qx", "qy", "qz", "qw"), self.sample_quat[b, k, :n].T))
                    d.update(zip(("x", "y", "z"), self.sample_position[b, k, :n].T))
                    parts.append(pd.DataFrame(d))
        return pd.concat(parts, ignore_index=True)


@dataclass
class Evaluation:
    """Scores of generated trajectories against demonstrations (per-step Bhattacharyya distance).

    Attributes
    ----------
    mean, rotation, translation : float, the distance averaged over the steps (lower is closer)
    per_step : (T,) the total per step;  steps, n_generated, n_demos : int
    left_data : {"count", "of", ...}: generated trajectories that left the demonstrations' envelope
    result : the library's :class:`~rbgp_cli.evaluation.bhattacharyya.EvaluationResult`
    """

    mean: float
    rotation: float
    translation: float
    per_step: np.ndarray
    steps: int
    n_generated: int
    n_demos: int
    left_data: dict
    result: object = field(repr=False, default=None)

    def to_dict(self) -> dict:
        """What ``rbgp evaluate --json`` prints."""
        return {**self.result.to_dict(), "left_data": self.left_data}

    def to_frame(self):
        """The per-step series: columns ``step, total, rotation, translation``."""
        r = self.result
        return _frame({"step": i, "total": float(a), "rotation": float(b), "translation": float(c)}
                      for i, (a, b, c) in enumerate(zip(r.per_step, r.per_step_rotation, r.per_step_translation)))


@dataclass
class Crossval:
    """Cross-validation by demonstration: one row per configuration (see ``rbgp crossval``).

    Attributes
    ----------
    rows : list of dict, one per configuration (``name``, ``score``, ``floor``, …, as ``--json``)
    folds : int;  result : the whole result dict (what ``rbgp crossval --json`` prints)
    """

    rows: list
    folds: int
    result: dict = field(repr=False, default_factory=dict)

    def to_dict(self) -> dict:
        return dict(self.result)

    def to_frame(self):
        """One row per configuration, the scalar fields of each row as columns."""
        return _frame({k: v for k, v in r.items() if not isinstance(v, (list, dict))} for r in self.rows)


# --------------------------------------------------------------------------------------------- estimator
class RigidBodyGP:
    """The rigid-body Gaussian process motion model, with the options of ``rbgp train``.

    Parameters are ``rbgp train``'s options with ``_`` for ``-`` and the same defaults
    (:data:`rbgp_cli.dynamics.defaults.DEFAULTS`): ``representation`` (axis-angle, euler, quaternion),
    ``kernel`` (None: the representation's own), ``rho_rot``, ``restarts``, ``explore_size``, ``seed``,
    ``noise`` ("learn" or a number), ``share_hyperparameters``, ``subsample``, ``max_points``,
    ``time_input`` (none, seconds, phase), ``prior`` (none, goal, path), ``prior_gain``,
    ``train_rate`` (Hz; 0 keeps the recorded samples), ``smooth_window``, ``smooth_degree``,
    ``inducing``, ``hyper_points``, ``calibrate_noise``, ``start_conditioning``, ``noise_scale``, ``pull_profile``,
    ``jobs`` (0: automatic).

    Attributes
    ----------
    model_ : the fitted :class:`~rbgp_cli.dynamics.model.MotionModel`
    summary_ : dict, what ``rbgp train --json`` prints (points, hyperparameters, NLML, times)
    output_names_ : tuple, the names of the velocity outputs ``predict`` returns
    dt_ : float, the integration step in seconds

    Examples
    --------
    >>> import rbgp_cli as rbgp
    >>> demos = rbgp.read_demonstrations(rbgp.SAMPLE_DATA / "csv")
    >>> gp = rbgp.RigidBodyGP(restarts=1, max_points=150, share_hyperparameters=True).fit(demos)
    >>> mean, std = gp.predict(demos[0], return_std=True)
    >>> mean.shape == std.shape == (len(demos[0]), 6)
    True
    """

    def __init__(self, representation: str = DEFAULTS["representation"], kernel: str | None = DEFAULTS["kernel"], *,
                 rho_rot=DEFAULTS["rho_rot"], restarts: int = DEFAULTS["restarts"],
                 explore_size: int = DEFAULTS["explore_size"], seed: int = 0, noise="learn",
                 share_hyperparameters: bool = False, subsample: float = DEFAULTS["subsample"],
                 max_points: int = DEFAULTS["max_points"], time_input=DEFAULTS["time_input"],
                 prior=DEFAULTS["prior"], prior_gain: float = DEFAULTS["prior_gain"],
                 train_rate=DEFAULTS["train_rate"], smooth_window: float = DEFAULTS["smooth_window"],
                 smooth_degree: int = DEFAULTS["smooth_degree"], inducing: int | None = None,
                 hyper_points: int | None = None, calibrate_noise: bool = DEFAULTS["calibrate"],
                 start_conditioning: bool = DEFAULTS["start_conditioning"],
                 noise_scale: float = DEFAULTS["noise_scale"], pull_profile: bool = DEFAULTS["pull_profile"],
                 residual_gain=DEFAULTS["residual_gain"], jobs: int = 0):
        self.representation = representation
        self.kernel = kernel
        self.rho_rot = rho_rot
        self.restarts = restarts
        self.explore_size = explore_size
        self.seed = seed
        self.noise = noise
        self.share_hyperparameters = share_hyperparameters
        self.subsample = subsample
        self.max_points = max_points
        self.time_input = time_input
        self.prior = prior
        self.prior_gain = prior_gain
        self.train_rate = train_rate
        self.smooth_window = smooth_window
        self.smooth_degree = smooth_degree
        self.inducing = inducing
        self.hyper_points = hyper_points
        self.calibrate_noise = calibrate_noise
        self.start_conditioning = start_conditioning
        self.noise_scale = noise_scale
        self.pull_profile = pull_profile
        self.residual_gain = residual_gain
        self.jobs = jobs

    _TRAIN = ("rho_rot", "restarts", "explore_size", "seed", "noise", "share_hyperparameters", "subsample",
              "max_points", "train_rate", "smooth_window", "smooth_degree", "time_input", "prior", "prior_gain",
              "inducing", "hyper_points", "calibrate_noise", "start_conditioning", "noise_scale", "pull_profile",
              "residual_gain")

    def get_params(self, deep: bool = True) -> dict:
        """The constructor's parameters (scikit-learn convention)."""
        return {k: getattr(self, k) for k in ("representation", "kernel", *self._TRAIN, "jobs")}

    def set_params(self, **params) -> "RigidBodyGP":
        for k, v in params.items():
            if k not in self.get_params():
                raise InputError(f"unknown parameter {k!r}", param=k)
            setattr(self, k, v)
        return self

    def __repr__(self) -> str:
        return f"RigidBodyGP(representation={self.representation!r}, kernel={self.kernel!r})"

    def _train_kwargs(self) -> dict:
        return {"representation": self.representation, "kernel": self.kernel, "jobs": self.jobs or None,
                **train_options(**{k: getattr(self, k) for k in self._TRAIN})}

    def fit(self, demos, progress=None) -> "RigidBodyGP":
        """Train on demonstrations (a list of Trajectory from :func:`read_demonstrations`, or anything
        it reads). Returns self.

        Examples
        --------
        >>> import rbgp_cli as rbgp
        >>> gp = rbgp.RigidBodyGP(restarts=1, max_points=150).fit(rbgp.SAMPLE_DATA / "csv")
        >>> gp.summary_["demos"]
        9
        """
        from rbgp_cli.dynamics.model import train_model

        trajs = _demos(demos)
        self.model_ = train_model(trajs, progress=progress, **self._train_kwargs())
        self._fitted()
        return self

    def _fitted(self) -> None:
        self.summary_ = dict(self.model_.summary)
        self.output_names_ = tuple(self.model_.representation.output_names)
        self.dt_ = float(self.model_.dt)

    def _check(self):
        if not hasattr(self, "model_"):
            raise InputError("this RigidBodyGP is not fitted yet", hint="call fit(demos) or RigidBodyGP.load(path)")
        return self.model_

    def predict(self, poses, *, tau=None, return_std: bool = False, noisy: bool = False):
        """The velocity (the model's outputs ``output_names_``) at poses.

        Parameters
        ----------
        poses : (n, 7) ``(qx, qy, qz, qw, x, y, z)``, a pair (quat, position), or a Trajectory (all its poses)
        tau : (n,) the time since the start (seconds, or the phase t/D of a phase model); needed by a
            model with a time input. For a Trajectory it defaults to its own time (or phase), and a
            start-conditioned model follows the path from the trajectory's first pose.
        return_std : also return the predictive std (False, as scikit-learn)
        noisy : the std of a new noisy observation instead of the latent function's

        Returns
        -------
        mean : (n, L), or (mean, std) with ``return_std``. For a phase model given a Trajectory, per second.
        """
        from rbgp_cli.dynamics.trajectory import Trajectory

        m = self._check()
        scale, first = 1.0, None
        if isinstance(poses, Trajectory):
            q, p = poses.quat, poses.position
            first = (q[0], p[0])  # a start-conditioned prior follows the path from its own start
            if tau is None and m.time_input:
                tau = poses.t - poses.t[0]
                if m.time_input == "phase":
                    scale = max(poses.duration, 1e-12)
                    tau = tau / scale
        else:
            q, p = start_poses(poses)
        mean, std = m.predict(q, p, return_std=True, noisy=noisy, tau=tau, start=first)
        return (mean / scale, std / scale) if return_std else mean / scale

    def rollout(self, start, *, duration: float | None = None, steps: int | None = None, dt: float | None = None,
                samples: int = 0, seed: int = 0, return_std: bool = True, off_data: str = "keep",
                rate: float | None = None, goals=None, via=(), durations=None, goal_tolerance=None) -> Rollout:
        """Generate motions from start poses by single-step mean prediction (``rbgp rollout``).

        Parameters
        ----------
        start : start poses: (7,) or (n, 7) ``(qx, qy, qz, qw, x, y, z)``, a pair (quat, position), or
            Trajectory objects (their first pose)
        duration : seconds (default: the demonstrations' median duration); or ``steps``, not both
        steps : integration steps
        dt : integration step in seconds (default: the model's rollout step, the recorded sample
            interval, for a duration; the training step for ``steps``)
        samples : sampled rollouts per start;  seed : seeds the draws
        return_std : record the predictive std along the mean trajectories
        off_data : keep, stop or prior: what a rollout does outside the demonstrations' envelope
        rate : resample the result to this rate (Hz); None: the integration grid
        goals : where the motions end (docs/method.md §12): poses as ``start`` takes them, one for every
            start or one per start (Trajectory objects: their *last* pose); the mean ends there and the
            samples' bands pinch there
        via : via-points ``[(T, pose), ...]``: T seconds after the start, pose (7,) ``(qx, qy, qz, qw, x, y, z)``
            or a pair (quat, position)
        durations : (n,) seconds, each start its own duration (default with a goal: what the
            demonstrations suggest for that start and goal; without one: ``duration``)
        goal_tolerance : (rad, m), one standard deviation of how far from the goal and via-points the
            motion may end or pass (default: reach them)

        Returns
        -------
        Rollout

        Examples
        --------
        >>> import rbgp_cli as rbgp
        >>> demos = rbgp.read_demonstrations(rbgp.SAMPLE_DATA / "csv")
        >>> gp = rbgp.RigidBodyGP(restarts=1, max_points=150).fit(demos)
        >>> r = gp.rollout(demos[:2], steps=10, samples=3)
        >>> r.sample_quat.shape
        (2, 3, 11, 4)
        """
        from rbgp_cli.workflows import rollout_model

        m = self._check()
        if steps is not None and duration is not None:
            raise InputError("give steps or duration, not both", param="steps")
        if off_data not in ("keep", "stop", "prior"):
            raise InputError(f"off_data must be keep, stop or prior, got {off_data!r}", param="off_data")
        q, p = start_poses(start)
        aims = _goal_keywords(len(q), goals, via, goal_tolerance)
        if durations is not None:
            durations = np.asarray(durations, dtype=np.float64).reshape(-1)
            if durations.shape != (len(q),) or not np.all(np.isfinite(durations) & (durations > 0)):
                raise InputError(f"durations must be {len(q)} positive numbers of seconds, one per start", param="durations")
        res = rollout_model(m, q, p, steps=steps, duration=duration, dt=dt, samples=samples, seed=seed,
                            with_std=return_std, rate=rate, off_data=off_data, durations=durations, **aims)
        return Rollout._of(res)

    def predict_rest(self, seen, *, samples: int = 0, seed: int = 0, dt: float | None = None, paths=None):
        """The rest of a motion under way from its seen beginning (``rbgp rollout --given``, docs/method.md §13).

        Parameters
        ----------
        seen : a Trajectory (its t, quat, position from the motion's start to the last seen sample), a list
            of them, or anything :func:`read_demonstrations` reads (each motion read is one seen beginning)
        samples : continuations drawn per motion, the duration and the path together;  seed : seeds them
        dt : the continuation's step in seconds (default the seen samples' median interval)
        paths : the path distribution (default the model's, ``model_.paths``)

        Returns
        -------
        A :class:`~rbgp_cli.dynamics.anticipation.Continuation` (a list for a list or a source): ``t``, ``quat``,
        ``position`` from the last seen time to the predicted end on the seen clock, ``samples``, and
        ``estimate`` (phase, end time and end pose with 90 % bands, ``off``), and ``info["left_data"]``: the mean's
        then each sample's (T,) bool rows outside the demonstrations' envelope (warned about on stderr, as the seen
        motions that are off or less like the demonstrations are). Nothing after the last seen sample is used.
        """
        from rbgp_cli.dynamics.trajectory import Trajectory
        from rbgp_cli.workflows import continue_motions

        m = self._check()
        single = isinstance(seen, Trajectory)
        items = [seen] if single else (list(seen) if isinstance(seen, (list, tuple)) and all(isinstance(x, Trajectory) for x in seen)
                                       else _demos(seen))
        out = continue_motions(m, items, samples=samples, seed=seed, dt=dt, paths=paths)
        return out[0] if single else out

    def follower(self, *, paths=None, **options):
        """An incremental :class:`~rbgp_cli.dynamics.anticipation.Follower` for a stream of poses (``rbgp follow``):
        ``push(t, quat, position)`` returns the current estimate (phase, end time and end pose with 90 %
        bands, ``off``) or None at rest. ``options``: the Follower's (``points``, ``grid_size``, ``window``,
        ``start_speed``, ``keep``, ``detect``, ``rest``, ``lead``)."""
        from rbgp_cli.dynamics.anticipation import Follower

        m = self._check()
        return Follower(getattr(m, "paths", None) if paths is None else paths, **options)

    def save(self, path) -> dict:
        """Write the model file (atomically; the format ``rbgp train -o`` writes). Returns its header."""
        from rbgp_cli.io.model_store import save_model

        return save_model(self._check(), str(path))

    @classmethod
    def load(cls, path) -> "RigidBodyGP":
        """A fitted estimator from a model file (written by :meth:`save` or ``rbgp train``); the
        constructor's parameters are those the file was trained with, where it records them."""
        from rbgp_cli.io.model_store import load_model

        model, header = load_model(str(path))
        opts = ((header.get("provenance") or {}).get("train_options") or {})
        self = cls(representation=model.representation.name if hasattr(model.representation, "name") else DEFAULTS["representation"])
        self.set_params(**_params_of(opts))
        self.model_ = model
        self.header_ = dict(header)
        self._fitted()
        return self


def _params_of(train_options: dict) -> dict:
    """The estimator's parameters from a model file's ``provenance.train_options`` (the keyword
    arguments of :func:`~rbgp_cli.dynamics.model.train_model`, as :func:`train_options` builds them)."""
    names = {"shared": "share_hyperparameters", "calibrate": "calibrate_noise"}
    out = {}
    for k, v in (train_options or {}).items():
        k = names.get(k, k)
        if k == "velocity" and isinstance(v, dict):
            out.update(train_rate=v.get("rate_hz") or 0.0, smooth_window=v.get("window_s", 0.0),
                       smooth_degree=v.get("degree", DEFAULTS["smooth_degree"]))
        elif k == "noise":
            out[k] = "learn" if v is None else v
        elif k in RigidBodyGP._TRAIN or k in ("representation", "kernel", "jobs"):
            out[k] = v
    return out


# --------------------------------------------------------------------------------------------- scoring
def evaluate(generated, demos, *, length: int | None = None, covariance: str = "diag") -> Evaluation:
    """Score generated trajectories against demonstrations (``rbgp evaluate``).

    Parameters
    ----------
    generated : a :class:`Rollout` (its mean trajectories), a list of Trajectory, or files
    demos : a list of Trajectory (:func:`read_demonstrations`) or files
    length : steps of the common normalised time (default: the demonstrations' median)
    covariance : diag or full

    Returns
    -------
    Evaluation

    Examples
    --------
    >>> import rbgp_cli as rbgp
    >>> demos = rbgp.read_demonstrations(rbgp.SAMPLE_DATA / "csv")
    >>> rbgp.evaluate(demos[:4], demos[4:]).mean >= 0
    True
    """
    from rbgp_cli.evaluation import evaluate as _evaluate
    from rbgp_cli.workflows import left_data

    if covariance not in ("diag", "full"):
        raise InputError(f"covariance must be diag or full, got {covariance!r}", param="covariance")
    gen = generated.trajectories() if isinstance(generated, Rollout) else _demos(generated)
    dem = _demos(demos)
    r = _evaluate(gen, dem, length=length, covariance=covariance)
    return Evaluation(mean=float(r.mean), rotation=float(r.rotation), translation=float(r.translation),
                      per_step=np.asarray(r.per_step), steps=int(r.steps), n_generated=int(r.n_generated),
                      n_demos=int(r.n_demos), left_data=left_data(gen, dem), result=r)


def crossval(demos, estimators=None, *, folds: int = 5, seed: int = 0, replay: bool = True, peers: bool = False,
             samples: int | None = None, length: int | None = None, covariance: str = "diag",
             jobs: int | None = None, repeats: int = 1, without_gp: bool = True, order: str = "random",
             train_size: int | None = None, given: str | None = None) -> Crossval:
    """Cross-validate by demonstration (``rbgp crossval``): each configuration is trained on the other
    folds and rolled out from each held-out demonstration's start, on the same folds.

    Parameters
    ----------
    demos : a list of Trajectory or files
    estimators : a :class:`RigidBodyGP` (its options, unfitted is fine), a list of them, or None (the defaults)
    folds, seed : K folds of a seeded permutation of the demonstrations
    repeats : R sets of K folds (fold seeds seed … seed + R − 1), each row over all of them, with
        ``by_repeat`` per repetition (``rbgp crossval --repeats``)
    replay : add the replay peer;  peers : add the ProMP and DMP peers (needs movement-primitives)
    samples : sampled rollouts per held-out start for the sample columns (None: the CLI's default; 0: none)
    length, covariance : as :func:`evaluate`;  jobs : worker processes (None: one per core)
    without_gp : beside every estimator with a prior mean, a row of the same fits with the GP's residual
        switched off (``"without_gp": True``): the path distribution alone (``rbgp crossval --without-gp``)
    order : ``"random"`` folds, ``"recorded"``: contiguous blocks in the demonstrations' order (the
        recording order: files as read), or ``"forward"``: those blocks, each after the first predicted
        from the demonstrations before it only, the next session's case (``rbgp crossval --order``)
    train_size : N: train on N demonstrations and hold out the rest, ``folds`` times (random subsets, or
        windows of N consecutive ones with the later ones held out; forward: the N just before each
        block; ``rbgp crossval --train-size``)
    given : None, or ``"goal"``: each held-out demonstration's final pose and duration are given too, the
        rows roll out to that goal beside the goal-conditioned peers (``rbgp crossval --given goal``)

    Returns
    -------
    Crossval

    Examples
    --------
    >>> import rbgp_cli as rbgp
    >>> cv = rbgp.crossval(rbgp.SAMPLE_DATA / "csv", rbgp.RigidBodyGP(restarts=1, max_points=100),
    ...                    folds=3, samples=0, jobs=1)
    >>> len(cv.rows)  # the estimator, the same fits without the GP, replay
    3
    """
    from rbgp_cli.evaluation.crossval import SAMPLES
    from rbgp_cli.evaluation.crossval import crossval as _crossval
    from rbgp_cli.workflows import crossval_configs

    ests = [RigidBodyGP()] if estimators is None else (
        [estimators] if isinstance(estimators, RigidBodyGP) else list(estimators))
    trajs = _demos(demos)
    configs = []
    for i, est in enumerate(ests):
        kw = est._train_kwargs()
        rep, kern = kw.pop("representation"), kw.pop("kernel")
        kw.pop("jobs")
        cfgs, _ = crossval_configs([rep], [kern] if kern else None, kw, replay=False, peers=False)
        configs.extend(cfgs)
    extra, _ = crossval_configs([DEFAULTS["representation"]], None, {}, replay=replay, peers=peers)
    configs.extend(extra[1:])  # the peers only
    result = _crossval(trajs, configs, folds=folds, seed=seed, jobs=jobs, length=length, covariance=covariance,
                       samples=SAMPLES if samples is None else samples, repeats=repeats, without_gp=without_gp,
                       order=order, train_size=train_size, given=given)
    return Crossval(rows=list(result.get("results", [])), folds=int(result.get("folds", folds)), result=result)
