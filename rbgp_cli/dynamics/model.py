"""A motion model: a representation, a fitted GP on its training pairs, and how it was made.

:func:`train_model` is the one library call behind ``rbgp train``: demonstrations → training pairs
(docs/method.md §4, §6) → subsample (paper sec. 4.3: 10 % random) → exact GP fit (docs/method.md §7).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from rbgp_cli.compute import blas_threads, default_jobs
from rbgp_cli.dynamics.representations import Representation, make_representation
from rbgp_cli.dynamics.defaults import DEFAULT_KERNELS, DEFAULTS, EXACT_HYPER_POINTS
from rbgp_cli.dynamics.trajectory import Trajectory
from rbgp_cli.dynamics.velocities import VelocityOptions, estimate_velocities, integration_drift, window_problem
from rbgp_cli.errors import InputError, warn
from rbgp_cli.gp.exact import ExactSpec, fit_gp
from rbgp_cli.gp.posterior import Posterior
from rbgp_cli.kernels import DotProduct, Kernel, SquaredExponential
from rbgp_cli.wording import plural

__all__ = ["MotionModel", "make_kernel", "training_set", "train_model", "choose_gp", "KERNELS", "DEFAULTS", "default_velocity"]

KERNELS = ("se", "se-chordal", "dot")
#: What the GP sees besides the pose: nothing (the paper), seconds since the start, or the phase.
TIME_INPUTS = (None, "seconds", "phase")
#: The GP's prior mean: zero (the paper), a pull toward the goal, or the demonstrations' mean path.
PRIORS = (None, "goal", "path")
#: A rollout integrates with at most this many steps per training step (:attr:`MotionModel.rollout_dt`).
ROLLOUT_SUBSTEPS = 10


def make_kernel(representation: Representation, kernel: str = "se", rho_rot: float = 0.7, learn_rho: bool = False,
                time_dims: int = 0) -> Kernel:
    """The kernel for a representation (docs/method.md §6).

    ``se`` is the paper's squared exponential on the representation's own rotation distance: the
    geodesic arc distance for axis-angle (eq. 24), Euclidean on Euler angles, the S³ angle for
    quaternions. ``se-chordal`` replaces the rotation distance by the chordal one (PD for every λ; not
    defined on Euler angles). ``dot`` is the dot-product kernel (eq. 22).
    """
    rd = representation.rotation_dims
    if kernel == "se":
        metric = {"axis-angle": "arc", "euler": "euclidean", "quaternion": "s3"}[representation.name]
        return SquaredExponential(metric, rd, rho_rot, learn_rho, time_dims)
    if kernel == "se-chordal":
        if representation.name == "euler":
            raise InputError("kernel se-chordal needs a rotation representation (axis-angle or quaternion), not euler",
                             param="kernel")
        return SquaredExponential("chordal", rd, rho_rot, learn_rho, time_dims)
    if kernel == "dot":
        if time_dims:
            raise InputError("kernel dot takes no time input", hint="use kernel se or se-chordal; the dot product "
                             "needs time_input none and prior none (or goal)", param=("kernel", "time_input", "prior"))
        return DotProduct(rd, rho_rot, learn_rho)
    raise InputError(f"unknown kernel {kernel!r}; expected one of {', '.join(KERNELS)}", param="kernel")


@dataclass
class MotionModel:
    """Everything needed to predict and to say how it was made.

    representation : how poses become GP inputs and outputs integrate back
    gp : the fitted GP, exact or sparse (a :class:`~rbgp_cli.gp.posterior.Posterior`): inputs X (n, d),
        outputs Y (n, L)
    dt : the training step, seconds (default rollout step): 1/rate when velocities were estimated on a
        resampled grid, else the demonstrations' median time step
    starts : demonstrations' start poses, shape (D, 7) = (qx, qy, qz, qw, x, y, z)
    durations : demonstrations' durations, seconds, shape (D,)
    summary : plain-data training summary; provenance : inputs, options, version, time
    velocity : how the training velocities were estimated (held-out pairs are made the same way)
    time_input : None, or ``"seconds"`` (time since the demonstration's start is a last GP input) or
        ``"phase"`` (normalised time s = (t − t_0)/D is a last input, and the outputs are velocities
        per unit phase, D·ξ, so that a rollout of any duration D' traverses the learned motion once)
    variation : the demonstrations' deviation process over phase (docs/method.md §11 (a)), or None
    mean : None (zero-mean GP, docs/method.md §7), ``{"kind": "goal", "gain": a, "goal": (7,)}`` or
        ``{"kind": "path", "gain": a, "s", "quat", "position", "velocity"}``: the prior mean of the
        outputs (:func:`prior_mean_outputs`, per second or per unit phase) converted to the
        representation's outputs; the GP models the residual, as in stable dynamical systems learned
        from demonstration
    envelope : where the demonstrations went (:class:`~rbgp_cli.dynamics.envelope.Envelope`, stored at
        training time), or None (a model file from before): :meth:`data_envelope` then computes it from
        the training points
    """

    representation: Representation
    gp: Posterior
    dt: float
    starts: np.ndarray
    durations: np.ndarray
    summary: dict = field(default_factory=dict)
    provenance: dict = field(default_factory=dict)
    velocity: VelocityOptions = field(default_factory=VelocityOptions)
    time_input: str | None = None
    mean: dict | None = None
    #: how the demonstrations differ (:class:`rbgp_cli.dynamics.variation.Variation`), for sampled
    #: rollouts that are new demonstrations; None for fewer than three or an older model file
    variation: object | None = None
    #: the demonstrations' position envelope over phase (:mod:`rbgp_cli.dynamics.envelope`), or None
    envelope: object = None
    #: the demonstrations as a distribution over paths and durations, conditioned on goals, via-points
    #: and a motion's seen beginning (:class:`rbgp_cli.dynamics.paths.PathDistribution`); None for fewer
    #: than three demonstrations or a model file from before format 8
    paths: object | None = None
    #: g, the gain on the GP's residual mean (docs/method.md §7, "The residual's gain"): the velocity is
    #: m(x) + g · μ_GP(x); 1 the full model (and every model file without it), 0 the path distribution
    #: alone; chosen by leaving demonstrations out (:mod:`rbgp_cli.dynamics.residual_gain`)
    residual_gain: float = 1.0

    @property
    def recorded_rate(self) -> float | None:
        """The demonstrations' recorded sample rate, Hz (1 / their median time step, after cleaning),
        or None for a model file written before rbgp stored it (``summary["recorded_rate_hz"]``)."""
        rate = self.summary.get("recorded_rate_hz") if isinstance(self.summary, dict) else None
        return float(rate) if isinstance(rate, (int, float)) and np.isfinite(rate) and rate > 0 else None

    @property
    def rollout_dt(self) -> float:
        """The step, seconds, that rollouts given a duration integrate with unless told otherwise: the
        demonstrations' recorded sample interval where it is finer than the training step ``dt``, but
        no finer than dt / ROLLOUT_SUBSTEPS; else ``dt`` (also for a model file without the recorded rate).

        Written at the recorded rate, every output sample is then an integrated state instead of an
        interpolation between steps ``dt`` apart, which cuts a curved motion's corners the same way
        for every rollout (docs/method.md §8: on the hand raises at 30 Hz, a shared offset; the sampled
        set scored 1.40 times the floor on the 0.1 s step, 1.26 integrated at 30 Hz)."""
        rate = self.recorded_rate
        if rate is None or 1.0 / rate >= self.dt:
            return float(self.dt)
        return float(max(1.0 / rate, self.dt / ROLLOUT_SUBSTEPS))

    def data_envelope(self):
        """The demonstrations' envelope (:mod:`rbgp_cli.dynamics.envelope`): the stored one, or for a
        model file without it one computed from the training inputs (their positions, at their phase
        for a phase model, else one box for the whole motion; ``source`` says so)."""
        if self.envelope is not None:
            return self.envelope
        cached = self.__dict__.get("_envelope_from_points")
        if cached is None:
            from rbgp_cli.dynamics.envelope import envelope_from_points

            X = np.asarray(self.gp.X, dtype=np.float64)
            _, pos = self.representation.pose_from_state(X[:, : self.pose_dims])
            phase = np.clip(X[:, -1], 0.0, 1.0) if self.time_input == "phase" else None
            cached = envelope_from_points(pos, phase, source="training points")
            self.__dict__["_envelope_from_points"] = cached
        return cached

    @property
    def pose_dims(self) -> int:
        """Columns of the representation's state (the GP input without the time column)."""
        return len(self.representation.input_names)

    def initial_state(self, quat, position) -> np.ndarray:
        """GP inputs (B, d) at the start of rollouts from poses (quat (B, 4) x, y, z, w; position (B, 3))."""
        X = self.representation.state_from_pose(np.asarray(quat, float).reshape(-1, 4), np.asarray(position, float).reshape(-1, 3))
        if self.time_input:
            X = np.concatenate([X, np.zeros((len(X), 1))], axis=1)
        return X

    def advance(self, X, output, dt: float, duration: float) -> np.ndarray:
        """One rollout step from inputs X (B, d) with predicted outputs (B, L) over ``dt`` seconds of a
        rollout lasting ``duration`` seconds (the phase mode divides by it)."""
        d = self.pose_dims
        if self.time_input == "phase":
            nxt = self.representation.step(X[:, :d], output / duration, dt)
            return np.concatenate([nxt, X[:, d:] + dt / duration], axis=1)
        if self.time_input == "seconds":
            nxt = self.representation.step(X[:, :d], output, dt)
            return np.concatenate([nxt, X[:, d:] + dt], axis=1)
        return self.representation.step(X, output, dt)

    def path_reference(self) -> PathReference | None:
        """The mean-path prior's :class:`PathReference` (built once), or None without one."""
        if not self.mean or self.mean.get("kind") != "path":
            return None
        cached = self.__dict__.get("_path_reference")
        if cached is None or cached[0] is not self.mean:
            cached = (self.mean, PathReference(self.mean))
            self.__dict__["_path_reference"] = cached
        return cached[1]

    def start_deviation(self, quat, position) -> np.ndarray | None:
        """Per start pose (quat (B, 4), position (B, 3)) the deviation the start-conditioned prior
        carries through the motion (:meth:`PathReference.start_deviation`), (B, 6); None for a model
        whose prior is not start-conditioned."""
        path = self.path_reference()
        if path is None or not path.conditioned:
            return None
        return path.start_deviation(quat, position)

    def phase_step(self, durations=None, dt: float | None = None):
        """The phase step h = dt / D over which a mean-path prior with a secant feed-forward
        (``mean["feedforward"] == "secant"``, :func:`path_secant`) means its velocity: one step of
        ``dt`` seconds (default the training step) of a motion lasting ``durations`` seconds (scalar
        or (m,)), by default the demonstrations' median duration; None for any other model (the tangent)."""
        if not self.mean or self.mean.get("feedforward") != "secant" or self.time_input != "phase":
            return None
        if durations is None:
            durations = float(np.median(self.durations)) if len(self.durations) else 1.0
        return float(self.dt if dt is None else dt) / np.asarray(durations, dtype=np.float64)

    def prior_mean(self, X, start_dev=None, step=None) -> np.ndarray | None:
        """The prior mean of the outputs at inputs X (m, d), or None for a zero-mean GP; ``start_dev``
        (m, 6): each row's start deviation (:meth:`start_deviation`) for a start-conditioned prior
        (None: the mean path's own start, δ(0) = μ(0)); ``step`` (scalar or (m,)): the phase step of a
        secant feed-forward (default :meth:`phase_step`; ignored by a model with the tangent)."""
        if not self.mean:
            return None
        phase = X[:, -1] if self.time_input == "phase" else None
        if self.mean.get("feedforward") != "secant":
            step = None
        elif step is None:
            step = self.phase_step()
        return prior_mean_outputs(self.representation, X[:, : self.pose_dims], self.mean, phase,
                                  path=self.path_reference(), start_dev=start_dev, step=step)

    def without_residual(self) -> "MotionModel":
        """This model with the GP's residual field switched off (:class:`rbgp_cli.gp.posterior.PriorOnly`):
        its velocities are the prior mean's alone (the start-conditioned mean path, its feed-forward
        and pull), its samples the same deviation process; what ``rbgp crossval`` rolls out for its
        rows without the GP. Shares every array with this model."""
        from dataclasses import replace

        from rbgp_cli.gp.posterior import PriorOnly

        return replace(self, gp=PriorOnly(self.gp))

    def residual(self, X, manage_threads: bool = True) -> np.ndarray:
        """The GP's residual mean at inputs X (m, d) times the model's :attr:`residual_gain` g, (m, L):
        what the velocity adds to the prior mean (g = 1: the GP's posterior mean itself). At g = 0 the
        product is zero and the GP is not evaluated (:attr:`residual_off`)."""
        if self.residual_off:
            return np.zeros((len(X), self.gp.n_outputs))
        out = self.gp.predict(X, manage_threads=manage_threads)
        g = float(self.residual_gain)
        return out if g == 1.0 else g * out

    @property
    def residual_off(self) -> bool:
        """Whether the residual's gain is exactly g = 0: the velocity is the prior mean alone, m(x) + 0 · μ_GP(x),
        so that every prediction of the mean skips the GP (its kernel block against the n training inputs,
        the costly part of a rollout step); the std (``return_std``) is the GP's own and still evaluates it.
        The numbers are those of the product (up to the sign of an exact zero)."""
        return float(self.residual_gain) == 0.0

    def predict_output(self, X, return_std: bool = False, manage_threads: bool = True, start_dev=None, step=None):
        """Outputs (velocities in the representation's coordinates, per second or per unit phase) at
        inputs X (m, d): the prior mean plus the GP's prediction, its mean times the residual gain g
        (:attr:`residual_gain`; the std is the GP's own) (``start_dev``, ``step``: :meth:`prior_mean`). The mean
        alone at g = 0 is the prior mean's, the GP not evaluated (:attr:`residual_off`)."""
        if self.residual_off and not return_std:
            m = self.prior_mean(np.asarray(X, dtype=np.float64), start_dev, step)
            return np.zeros((len(X), self.gp.n_outputs)) if m is None else m
        out = self.gp.predict(X, return_std=return_std, manage_threads=manage_threads)
        g = float(self.residual_gain)
        if g != 1.0:
            out = (g * out[0], out[1]) if return_std else g * out
        m = self.prior_mean(np.asarray(X, dtype=np.float64), start_dev, step)
        if m is None:
            return out
        if return_std:
            return out[0] + m, out[1]
        return out + m

    def predict(self, quat, position, return_std: bool = True, noisy: bool = False, tau=None, start=None):
        """Output mean and std at poses (quat (m, 4) x, y, z, w; position (m, 3)); ``tau`` (m,) the
        time since the start (seconds or phase, as the model was trained) for models with a time input.

        ``start``: the pose (quat (4,) or (m, 4), position (3,) or (m, 3)) at which the motion through
        these poses started. A start-conditioned prior (docs/method.md §7) is then the path from that
        start, as in a rollout from it; without it, the mean path itself (a typical start)."""
        X = self.representation.state_from_pose(np.asarray(quat, float).reshape(-1, 4), np.asarray(position, float).reshape(-1, 3))
        if self.time_input:
            if tau is None:
                raise InputError(f"this model takes the {'phase' if self.time_input == 'phase' else 'time since the start'} "
                                 "as an input", hint="give a time column with the poses")
            X = np.concatenate([X, np.asarray(tau, float).reshape(-1, 1)], axis=1)
        if self.residual_off and not return_std:  # g = 0: the mean is the prior's, the GP not evaluated
            mean, std = np.zeros((len(X), self.gp.n_outputs)), None
        else:
            mean, std = self.gp.predict(X, return_std=True, noisy=noisy)
            mean = float(self.residual_gain) * mean
        dev = None
        if start is not None:
            dev = self.start_deviation(np.asarray(start[0], float).reshape(-1, 4), np.asarray(start[1], float).reshape(-1, 3))
            if dev is not None:
                dev = np.broadcast_to(dev, (len(X), 6))
        m = self.prior_mean(X, dev)
        if m is not None:
            mean = mean + m
        return (mean, std) if return_std else mean


class PathReference:
    """The mean path's pose and velocity at phases (``mean["kind"] == "path"``, :func:`mean_path`):
    :func:`~rbgp_cli.dynamics.trajectory.interpolate_poses` (slerp of the rotation, linear
    position) with the per-interval parts of the slerp computed once, ``q(f) = q̂_k ⊗ exp(f·φ_k)``
    with ``q̂_k`` the normalised k-th quaternion and ``φ_k = log(q̂_k* ⊗ ±q̂_{k+1})`` — the same
    arithmetic as :func:`~rbgp_cli.geometry.so3.slerp` (a rollout asks for it every step)."""

    def __init__(self, mean: dict):
        from rbgp_cli.geometry.so3 import _log_quat_unit, quat_conjugate, quat_multiply, quat_normalize

        self.s = np.asarray(mean["s"], dtype=np.float64)
        self.quat = np.asarray(mean["quat"], dtype=np.float64)
        self.position = np.asarray(mean["position"], dtype=np.float64)
        self.velocity = np.asarray(mean["velocity"], dtype=np.float64)
        q0, q1 = quat_normalize(self.quat[:-1]), quat_normalize(self.quat[1:])
        q1 = q1 * np.where(np.sum(q0 * q1, axis=-1, keepdims=True) < 0, -1.0, 1.0)
        self._q0 = q0
        self._phi = _log_quat_unit(quat_normalize(quat_multiply(quat_conjugate(q0), q1)))
        #: start conditioning (``mean["start_mean"]``, ``mean["start_beta"]``, :func:`start_conditioning`):
        #: μ, β (S, 6) on the grid and their per-interval slopes per unit phase
        self.conditioned = "start_beta" in mean
        if self.conditioned:
            self.start_mean = np.asarray(mean["start_mean"], dtype=np.float64)
            self.start_beta = np.asarray(mean["start_beta"], dtype=np.float64)
            ds = np.diff(self.s)[:, None]
            self._dmu = np.diff(self.start_mean, axis=0) / ds
            self._dbeta = np.diff(self.start_beta, axis=0) / ds.reshape((-1,) + (1,) * (self.start_beta.ndim - 1))
            #: the farthest the demonstrations went from the mean path at each phase (S, 2), rotation (rad) and
            #: position (m) (:func:`~rbgp_cli.dynamics.variation.start_reach`); None: the map is not bounded
            reach = mean.get("start_reach")
            self.start_reach = None if reach is None else np.asarray(reach, dtype=np.float64)

    def start_deviation(self, quat, position) -> np.ndarray:
        """c = δ(0) − μ(0) (m, 6) of start poses (quat (m, 4), position (m, 3)): their deviation from
        the mean path's first pose, δ(0) = (log(R_0 R̄(0)ᵀ), p_0 − p̄(0)), less the demonstrations' mean
        deviation there (zero for a path without start conditioning)."""
        from rbgp_cli.geometry.so3 import log_quat, quat_conjugate, quat_multiply

        quat = np.asarray(quat, dtype=np.float64).reshape(-1, 4)
        position = np.asarray(position, dtype=np.float64).reshape(-1, 3)
        if not self.conditioned:
            return np.zeros((len(quat), 6))
        rot = log_quat(quat_multiply(quat, quat_conjugate(self.quat[:1])))
        return np.concatenate([rot, position - self.position[:1]], axis=1) - self.start_mean[:1]

    def conditioned_at(self, s: np.ndarray, dev: np.ndarray, step=None):
        """The start-conditioned path at phases s (m,) for start deviations ``dev`` (m, 6)
        (:meth:`start_deviation`): with Δ(s) = μ(s) + B(s) dev (linear between grid phases; B (S, 6, 6)
        from :func:`~rbgp_cli.dynamics.variation.start_map`, or per-coordinate β(s) ⊙ dev), the
        pose (exp(Δ_rot) R̄(s), p̄(s) + Δ_pos) and the twist per unit phase ξ̄(s) + Δ'(s) (to first
        order in Δ_rot); shapes (m, 4), (m, 3), (m, 6). With the demonstrations' reach ρ(s) (S, 2)
        (``mean["start_reach"]``, :func:`~rbgp_cli.dynamics.variation.start_reach`) the shift B(s) dev is
        bounded per block b (rotation, position): scaled by min(1, max(|dev_b|, ρ_b(s)) / |(B(s) dev)_b|),
        so a start the map has not seen is not extrapolated farther than any demonstration went (a start
        within theirs keeps the linear map); its slope is scaled alike. With ``step`` h (scalar or (m,),
        > 0) the twist is the secant over one step instead (:func:`path_secant`)."""
        from rbgp_cli.dynamics.variation import bound_shift
        from rbgp_cli.geometry.so3 import exp_quat, quat_multiply

        if step is not None:
            return self._over_step(self.conditioned_at, s, step, dev)
        q, p, ff = self.at(s)
        x = self.s
        s = np.clip(np.asarray(s, dtype=np.float64).reshape(-1), x[0], x[-1])
        k = np.clip(np.searchsorted(x, s, side="right") - 1, 0, len(x) - 2)
        f = np.clip((s - x[k]) / (x[k + 1] - x[k]), 0.0, 1.0)[:, None]
        mu = (1.0 - f) * self.start_mean[k] + f * self.start_mean[k + 1]
        if self.start_beta.ndim == 3:  # the map B(s) (S, 6, 6) of variation.start_map
            g = f[:, :, None]
            beta = (1.0 - g) * self.start_beta[k] + g * self.start_beta[k + 1]
            slope = np.einsum("mij,mj->mi", self._dbeta[k], dev)
            reach = None if self.start_reach is None else (1.0 - f) * self.start_reach[k] + f * self.start_reach[k + 1]
            shift, kb = bound_shift(np.einsum("mij,mj->mi", beta, dev), dev, reach)  # ≤ max(|dev_b|, ρ_b(s))
            delta = mu + shift
            slope = slope * kb
        else:  # per-coordinate slopes β(s) (S, 6) (model files of rbgp 0.x before the map)
            beta = (1.0 - f) * self.start_beta[k] + f * self.start_beta[k + 1]
            delta = mu + beta * dev
            slope = self._dbeta[k] * dev
        q = quat_multiply(exp_quat(delta[:, :3]), q)
        return q, p + delta[:, 3:], ff + self._dmu[k] + slope

    @staticmethod
    def _over_step(pose_at, s, step, *args):
        """``pose_at(s, *args)``'s pose at s and, as its velocity, the secant to its pose at s + step
        (:func:`path_secant`)."""
        q, p, _ = pose_at(s, *args)
        s_next = np.asarray(s, dtype=np.float64).reshape(-1) + np.asarray(step, dtype=np.float64)
        q2, p2, _ = pose_at(np.broadcast_to(s_next, np.shape(q)[:1]), *args)
        return q, p, path_secant(q, p, q2, p2, step)

    def at(self, s: np.ndarray, step=None):
        """(quat (T, 4), position (T, 3), velocity (T, 6)) at phases s (T,), clamped to the path; the
        velocity is the mean path's twist per unit phase on the grid interval, or with ``step`` h
        (scalar or (T,), > 0) the secant over [s, s + h] (:func:`path_secant`)."""
        from rbgp_cli.geometry.so3 import exp_quat, quat_make_continuous, quat_multiply

        if step is not None:
            return self._over_step(self.at, s, step)
        x = self.s
        s = np.clip(np.asarray(s, dtype=np.float64).reshape(-1), x[0], x[-1])
        k = np.clip(np.searchsorted(x, s, side="right") - 1, 0, len(x) - 2)
        f = np.clip((s - x[k]) / (x[k + 1] - x[k]), 0.0, 1.0)
        q = quat_multiply(self._q0[k], exp_quat(f[..., None] * self._phi[k]))
        q = np.where((f == 0.0)[:, None], self.quat[k], np.where((f == 1.0)[:, None], self.quat[k + 1], q))
        p = (1.0 - f)[:, None] * self.position[k] + f[:, None] * self.position[k + 1]
        if len(s) > 1:
            q = quat_make_continuous(q)
        return q, p, self.velocity[k]


def path_secant(q, p, q_next, p_next, step) -> np.ndarray:
    """The constant twist per unit phase that carries the pose (q, p) to (q_next, p_next) in one
    phase step h, in the convention of a rollout's step (:func:`~rbgp_cli.geometry.se3.integrate_quat`,
    q' = exp(ω h) ⊗ q, p' = p + v h):

        ξ = (log(q_next ⊗ q*), p_next − p) / h,   shapes (m, 4), (m, 3), ..., h scalar or (m,) → (m, 6).

    The tangent of the path at s is what a rollout's Euler step would need to be exact at a vanishing
    step; over a step of finite h it cuts corners wherever the path curves (on the hand raises, 20
    steps a motion, 1 cm and 0.05 rad of bias; docs/method.md §7). The secant lands on the path."""
    from rbgp_cli.geometry.so3 import log_quat, quat_conjugate, quat_multiply

    h = np.asarray(step, dtype=np.float64)
    h = h.reshape(-1, 1) if h.ndim else h
    return np.concatenate([log_quat(quat_multiply(q_next, quat_conjugate(q))), p_next - p], axis=1) / h


def prior_mean_outputs(representation: Representation, state: np.ndarray, mean: dict, phase=None,
                       path: PathReference | None = None, start_dev: np.ndarray | None = None,
                       step=None) -> np.ndarray:
    """The prior mean as the representation's outputs at ``state`` (m, d).

    ``goal``: ξ_m = a·(log(R_goal Rᵀ), p_goal − p), a pull toward the demonstrations' mean final
    pose. ``path`` (phase input only): ξ_m = ξ̄(s) + a·(log(R̄(s) Rᵀ), p̄(s) − p), the velocity of the
    demonstrations' mean path at phase s (per unit phase) plus a pull toward its pose at s
    (:func:`mean_path`); ``phase`` (m,) gives s. ``path``: the :class:`PathReference` of ``mean``
    if the caller keeps one (built here otherwise).
    With start conditioning (``mean["start_beta"]``, :func:`start_conditioning`) and ``start_dev``
    (m, 6) each row's start deviation (:meth:`PathReference.start_deviation`), the reference is that
    row's start-conditioned path (:meth:`PathReference.conditioned_at`) instead of the mean path: the
    pull keeps the deviation the demonstrations keep from such a start (docs/method.md §11).
    ``step`` (scalar or (m,)): the phase step h over which the velocity is meant, as a rollout's
    step or a forward difference of the training pairs: ξ̄ is then the reference's secant over
    [s, s + h] (:func:`path_secant`) instead of its tangent (None or 0).
    A start-conditioned path with a profile (``mean["gain_profile"]``) pulls each coordinate with its
    own gain at the phase (:func:`pull_gains`, docs/method.md §7 "The pull's profile") instead of a.
    """
    from rbgp_cli.geometry.so3 import log_quat, quat_conjugate, quat_multiply

    a = float(mean["gain"])
    quat, pos = representation.pose_from_state(state)
    if mean["kind"] == "path":
        path = path or PathReference(mean)
        s = np.asarray(phase, dtype=np.float64).reshape(-1)
        m = len(s)
        h = None if step is None else np.broadcast_to(np.asarray(step, dtype=np.float64), (m,))
        if h is not None and not np.all(h > 0):
            if np.any(h > 0):
                raise ValueError("phase steps must all be positive, or all zero (the tangent)")
            h = None
        if path.conditioned and start_dev is not None:
            ref_q, ref_p, ff = path.conditioned_at(s, np.broadcast_to(np.asarray(start_dev, dtype=np.float64), (m, 6)), h)
        else:
            if m > 1 and np.all(s == s[0]) and (h is None or np.all(h == h[0])):
                # a rollout's trajectories share their phase (unless their durations differ): the
                # reference pose once, for every row (the same numbers as row by row)
                s = s[:1]
                h = None if h is None else h[:1]
            ref_q, ref_p, ff = path.at(s, h)
            if len(s) < m:
                ref_q, ref_p = np.broadcast_to(ref_q, (m, 4)), np.broadcast_to(ref_p, (m, 3))
    else:
        goal = np.asarray(mean["goal"], dtype=np.float64)
        ref_q, ref_p = np.broadcast_to(goal[:4], quat.shape), goal[4:]
        ff = 0.0
    rot = log_quat(quat_multiply(ref_q, quat_conjugate(quat)))
    if mean["kind"] == "path" and mean.get("gain_profile") is not None:
        a = pull_gains(mean, phase, h)
    xi = ff + a * np.concatenate([rot, ref_p - pos], axis=1)
    return representation.output_from_velocity(state, quat, xi)


def pull_gains(mean: dict, phase, step=None) -> np.ndarray:
    """The pull's gains (m, 6) at phases (m,) of a mean path with a profile (``mean["gain_profile"]``
    (S, 6) on ``mean["s"]``, :func:`~rbgp_cli.dynamics.variation.pull_profile`): the grid interval's
    value (its left end), and with a step h (scalar or (m,), nonzero) at most 1/|h|, so that one step
    of a rollout never carries a pose past its reference (e_{k+1} = (1 − a h) e_k ≥ 0)."""
    s = np.clip(np.asarray(phase, dtype=np.float64).reshape(-1), 0.0, 1.0)
    grid = np.asarray(mean["s"], dtype=np.float64)
    prof = np.asarray(mean["gain_profile"], dtype=np.float64)
    a = prof[np.clip(np.searchsorted(grid, s, side="right") - 1, 0, len(grid) - 1)]
    if step is not None:
        h = np.abs(np.broadcast_to(np.asarray(step, dtype=np.float64), s.shape))
        a = np.minimum(a, 1.0 / np.maximum(h, 1e-12)[:, None])
    return a


def mean_path(trajs: list[Trajectory], steps: int = 51) -> dict:
    """The demonstrations' mean path over phase s = (t − t_0)/D: at ``steps`` phases the chordal mean
    rotation (principal eigenvector of Σ q qᵀ) and the mean position, and per interval the twist per
    unit phase that carries one mean pose to the next (ξ̄_k = (log(R̄_{k+1} R̄_kᵀ), p̄_{k+1} − p̄_k)/Δs)."""
    from rbgp_cli.dynamics.trajectory import interpolate_poses
    from rbgp_cli.geometry.so3 import log_quat, quat_conjugate, quat_make_continuous, quat_multiply

    s = np.linspace(0.0, 1.0, steps)
    Q, P = [], []
    for tr in trajs:
        q, p = interpolate_poses((tr.t - tr.t[0]) / max(tr.duration, 1e-12), quat_make_continuous(tr.quat), tr.position, s)
        Q.append(q)
        P.append(p)
    Q, P = np.array(Q), np.array(P)  # (D, S, 4), (D, S, 3)
    _, V = np.linalg.eigh(np.einsum("dsi,dsj->sij", Q, Q))
    q_mean = quat_make_continuous(V[:, :, -1])
    p_mean = P.mean(axis=0)
    ds = np.diff(s)[:, None]
    vel = np.concatenate([log_quat(quat_multiply(q_mean[1:], quat_conjugate(q_mean[:-1]))), np.diff(p_mean, axis=0)], axis=1) / ds
    return {"s": s, "quat": q_mean, "position": p_mean, "velocity": vel}


def goal_pose(trajs: list[Trajectory]) -> np.ndarray:
    """The demonstrations' mean final pose (7,): chordal mean rotation (principal eigenvector of
    Σ q qᵀ, x, y, z, w) and mean position."""
    Q = np.array([tr.quat[-1] for tr in trajs])
    w, V = np.linalg.eigh(Q.T @ Q)
    q = V[:, -1]
    q = q if q[3] >= 0 else -q
    return np.concatenate([q, np.mean([tr.position[-1] for tr in trajs], axis=0)])


def default_velocity() -> VelocityOptions:
    """How training velocities are estimated unless told otherwise (:data:`DEFAULTS`)."""
    return VelocityOptions(rate=DEFAULTS["train_rate"], window=DEFAULTS["smooth_window"], degree=DEFAULTS["smooth_degree"])


def demonstration_pairs(trajs: list[Trajectory], representation: Representation,
                        velocity: VelocityOptions | None = None, time_input: str | None = None,
                        with_steps: bool = False):
    """Training pairs of every demonstration (docs/method.md §4, §4.1), before any subsampling.

    With a ``time_input`` the inputs get a last column: seconds since the demonstration's start, or
    its phase (t − t_0)/D with outputs multiplied by D (velocities per unit phase).
    Returns X (n, d), Y (n, L), per-demonstration pair counts, and the velocity segments; with
    ``with_steps`` also each pair's phase step (t_{k+1} − t_k)/D (n,), the step its forward difference
    spans, or None where the velocities are not forward differences over phase.
    """
    velocity = velocity or VelocityOptions()
    Xs, Ys, per_demo, segments, steps = [], [], [], [], []
    for tr in trajs:
        segs = estimate_velocities(tr, velocity)
        count = 0
        for seg in segs:
            X, Y = representation.pairs_from_segment(seg)
            if time_input:
                tau = seg.traj.t[: len(X)] - seg.t0
                if time_input == "phase":
                    D = max(tr.duration, 1e-9)
                    tau = tau / D
                    Y = Y * D
                    steps.append(np.diff(seg.traj.t)[: len(X)] / D)
                X = np.concatenate([X, tau[:, None]], axis=1)
            Xs.append(X)
            Ys.append(Y)
            count += len(X)
        per_demo.append(count)
        segments.extend(segs)
    d, L = len(representation.input_names) + (1 if time_input else 0), len(representation.output_names)
    X = np.concatenate(Xs) if Xs else np.zeros((0, d))
    Y = np.concatenate(Ys) if Ys else np.zeros((0, L))
    if with_steps:
        forward = time_input == "phase" and not velocity.window  # forward differences, not local polynomials
        return X, Y, per_demo, segments, (np.concatenate(steps) if steps else np.zeros(0)) if forward else None
    return X, Y, per_demo, segments


def training_set(trajs: list[Trajectory], representation: Representation, *, subsample: float | None = 0.1,
                 max_points: int | None = None, seed: int = 0, velocity: VelocityOptions | None = None,
                 time_input: str | None = None):
    """All training pairs of all demonstrations, then a seeded random subset.

    Returns X (n, d), Y (n, L) and a dict with ``pairs`` (before subsampling), ``points`` (after),
    ``per_demo`` pair counts, the chosen ``indices`` into the concatenated pairs, the velocity
    ``segments`` and the chosen pairs' ``phase_steps`` (:func:`demonstration_pairs`; None unless forward
    differences over phase).
    """
    if not trajs:
        raise InputError("no demonstrations given", hint="pass one or more demonstration files")
    representation.prepare(trajs)
    problem = window_problem(trajs, velocity or VelocityOptions())
    if problem:
        raise InputError(problem, hint="use a longer smooth_window or 0 for forward differences", param="smooth_window")
    X, Y, per_demo, segments, steps = demonstration_pairs(trajs, representation, velocity, time_input, with_steps=True)
    n = len(X)
    if n < 2:  # two samples give one velocity: nothing for a GP to fit (nor a length scale to learn)
        sources = sorted({tr.source or tr.name for tr in trajs if tr.source or tr.name})
        raise InputError(
            f"the demonstrations give {n} training pair{'s' * (n != 1)} (one velocity per two consecutive "
            + (f"samples of the {velocity.rate:g} Hz training grid" if velocity and velocity.rate else "samples")
            + "); a GP needs at least 2",
            path=", ".join(sources) or None,
            hint="train on demonstrations with 3 or more samples"
                 + (f" spanning at least {2 / velocity.rate:g} s, or keep the recorded samples with train_rate 0"
                    if velocity and velocity.rate else ""),
        )
    rng = np.random.default_rng(seed)
    k = n
    if subsample is not None:
        if not 0 < subsample <= 1:
            raise InputError(f"subsample must lie in (0, 1], got {subsample}", param="subsample")
        k = max(min(n, 2), int(round(subsample * n)))
    if max_points is not None:
        k = min(k, int(max_points))
    idx = np.sort(rng.choice(n, size=k, replace=False)) if k < n else np.arange(n)
    return X[idx], Y[idx], {"pairs": int(n), "points": int(len(idx)), "per_demo": per_demo, "indices": idx,
                            "segments": segments, "phase_steps": None if steps is None else steps[idx]}


#: Automatic choice: above this many training points (and above ``max_points``) a sparse GP on all of
#: them replaces the exact GP on a random ``max_points`` (benchmarks/bench_sparse.py measures where the
#: exact GP stops being affordable).
SPARSE_ABOVE = 3000


def _keep_sparse_if_no_worse(gp, gp_choice: dict, info: dict, seed: int, progress) -> tuple[Posterior, dict]:
    """The automatic choice's check (issue 21): the sparse GP on all points is kept only where, on
    demonstrations left out (:func:`rbgp_cli.gp.selection.held_out_comparison`), it predicts no worse
    than the exact GP on the subset that chose its hyperparameters; otherwise that exact GP is the model."""
    from rbgp_cli.gp.selection import held_out_comparison

    groups = np.repeat(np.arange(len(info["per_demo"])), info["per_demo"])[info["indices"]]
    check = held_out_comparison(gp, groups, seed=seed)
    if check is None:
        return gp, gp_choice
    gp_choice = dict(gp_choice, check={"held_out_error_exact": round(check["exact"], 4),
                                       "held_out_error_sparse": round(check["sparse"], 4), "folds": check["folds"]})
    verdict = (f"held out by demonstration ({check['folds']} folds), relative error {check['sparse']:.4f} "
               f"sparse on all points against {check['exact']:.4f} exact on {len(gp.hyper_rows)}")
    if check["sparse"] <= check["exact"]:
        gp_choice["reason"] += f"; kept: {verdict}"
        if progress:
            progress(f"sparse GP kept: {verdict}")
        return gp, gp_choice
    exact = gp.hyper_gp
    if isinstance(exact, ExactSpec):
        exact = exact.build(gp.X[gp.hyper_rows], gp.Y[gp.hyper_rows])
    exact.fit_seconds = getattr(gp, "fit_seconds", 0.0)
    if progress:
        progress(f"the exact GP instead: {verdict}")
    return exact, {"type": "exact", "inducing": None, "forced": False, "check": gp_choice["check"],
                   "hyper_points": gp_choice.get("hyper_points"), "hyperparameters": gp_choice.get("hyperparameters"),
                   "reason": f"{gp_choice['reason']}; the exact GP on a random {len(gp.hyper_rows)} of them at those "
                             f"hyperparameters instead: {verdict} (--inducing {gp.n_inducing} keeps the sparse GP)"}


def choose_gp(points: int, inducing: int | None, max_points: int | None, kernel: str) -> dict:
    """Which GP to train on ``points`` training points (after ``--subsample``), and why.

    ``inducing`` None (automatic): the exact GP on at most ``max_points`` of them (as before) unless
    there are more than both ``max_points`` and SPARSE_ABOVE; then a sparse GP with DEFAULT_INDUCING
    inducing poses on all of them, so that most of the data is not thrown away (the dot-product kernel
    always stays exact: its Gram matrix has rank 6). 0: the exact GP (on at most ``max_points``).
    M > 0: a sparse GP with M inducing poses (at most ``points``) on all points; ``max_points`` never
    drops points from a sparse GP.
    Returns {"type": "exact" | "sparse", "inducing": M or None, "forced": bool, "reason": str}.
    """
    from rbgp_cli.gp.sparse import DEFAULT_INDUCING

    if inducing is not None and int(inducing) < 0:
        raise InputError(f"inducing must be 0 (exact GP) or a positive number of inducing poses, got {inducing}",
                         param="inducing")
    capped = max_points is not None and points > max_points
    cap = f": exact GP on a random {max_points} of {points} training points" if capped else ""
    if inducing:
        if kernel == "dot":
            raise InputError("inducing needs a squared-exponential kernel: the dot-product kernel's Gram matrix "
                             "has rank 6, so a sparse approximation gains nothing", hint="use kernel se or se-chordal",
                             param="inducing")
        M = min(int(inducing), points)
        return {"type": "sparse", "inducing": M, "forced": True,
                "reason": f"--inducing {int(inducing)}: {M} inducing poses for all {points} training points"}
    if inducing == 0:
        return {"type": "exact", "inducing": None, "forced": True, "reason": "--inducing 0" + cap}
    if points > max(SPARSE_ABOVE, max_points or 0) and kernel != "dot":
        M = min(DEFAULT_INDUCING, points)
        keep = f"a random {max_points}" if max_points is not None else f"all {points}"
        return {"type": "sparse", "inducing": M, "forced": False,
                "reason": f"{points} training points are more than the exact GP affords (above {SPARSE_ABOVE}): a "
                          f"sparse GP with {M} inducing poses uses all of them (--inducing 0: the exact GP on {keep})"}
    return {"type": "exact", "inducing": None, "forced": False, "reason": cap[2:]}


def train_model(
    trajs: list[Trajectory],
    *,
    representation: str = DEFAULTS["representation"],
    kernel: str | None = DEFAULTS["kernel"],
    rho_rot: float | str = DEFAULTS["rho_rot"],
    restarts: int = DEFAULTS["restarts"],
    seed: int = 0,
    noise=None,
    shared: bool = False,
    subsample: float | None = DEFAULTS["subsample"],
    max_points: int | None = DEFAULTS["max_points"],
    euler_order: str = "xyz",
    progress=None,
    explore_size: int | None = None,
    velocity: VelocityOptions | None = None,
    time_input: str | None = DEFAULTS["time_input"],
    prior: str | None = DEFAULTS["prior"],
    prior_gain: float = DEFAULTS["prior_gain"],
    jobs: int | None = None,
    inducing: int | None = None,
    hyper_points: int | None = None,
    calibrate: bool = DEFAULTS["calibrate"],
    start_conditioning: bool = DEFAULTS["start_conditioning"],
    noise_scale: float = DEFAULTS["noise_scale"],
    pull_profile: bool = DEFAULTS["pull_profile"],
    residual_gain: float | str = DEFAULTS["residual_gain"],
) -> MotionModel:
    """Train a motion model on clean demonstrations (see :func:`rbgp_cli.dynamics.prepare.prepare_all`).

    ``rho_rot`` is ρ1 of eq. 19 (a number in (0, 1)) or ``"learn"``. ``noise`` is None to learn σn or
    a fixed standard deviation. ``explore_size``: the optimiser's starts explore a random subset of
    this many training points first (see :func:`rbgp_cli.gp.exact.fit_gp`; None: its default, 0: off).
    ``velocity``: how training velocities are estimated (:class:`VelocityOptions`). ``time_input``:
    None, ``"seconds"`` or ``"phase"`` (see :class:`MotionModel`). ``prior``: the GP's prior mean,
    None (zero, the paper), ``"goal"`` (a pull toward the demonstrations' mean final pose) or
    ``"path"`` (the demonstrations' mean path over phase: its velocity plus a pull toward it; needs
    the phase input), with the pull's gain ``prior_gain`` (per unit phase, or per second). ``jobs``:
    worker processes for the per-output fits (None: :func:`rbgp_cli.compute.default_jobs`: one per
    output if memory allows, 1 inside a worker process or on a single core).
    Returns the model; its ``summary`` holds demos, pairs, points, the hyperparameters and NLML per
    output, the safeguards used and the time taken.

    ``inducing`` chooses the GP (:func:`choose_gp`): None (automatic) trains the exact GP on at most
    ``max_points`` points (as before) unless more than both ``max_points`` and SPARSE_ABOVE are left after
    ``subsample``, and then a sparse GP (:mod:`rbgp_cli.gp.sparse`) with DEFAULT_INDUCING inducing poses
    on all of them; 0 forces the exact GP; M > 0 forces a sparse GP with M inducing poses on all points.
    ``max_points`` never drops points from a sparse GP. ``summary["gp"]`` says which and why.
    ``calibrate``: after the fit, scale σn² of the posterior by the factor that predicts held-out
    demonstrations best (:func:`rbgp_cli.gp.calibration.calibrate_to_demonstrations`; the fitted σn is
    kept in each output's ``calibration``); ``summary["gp"]["calibration"]`` gives the factors.
    ``noise_scale`` ≥ 1: after that, σn² of the posterior is multiplied by this factor as well
    (:func:`rbgp_cli.gp.calibration.scale_noise`; 1: not), so the mean rollout leans further on the prior.
    ``hyper_points`` (sparse GP only): the hyperparameters are the exact GP's fit on at most this many
    random points (None: 1000, HYPER_EXACT_POINTS; 0: all), and the posterior uses all
    (:func:`rbgp_cli.gp.sparse.fit_sparse_gp`, ``hyper="exact"``); ``summary["gp"]["hyper_points"]`` is
    how many the fit covered and ``summary["gp"]["hyperparameters"]`` says which objective chose them.
    ``start_conditioning`` (mean-path prior, 3 or more demonstrations): the prior pulls each
    trajectory toward the mean path displaced by the deviation the demonstrations keep from its start
    (:func:`rbgp_cli.dynamics.variation.start_map`, its ridge chosen by cross-validation over the
    demonstrations) instead of toward the mean path itself; the
    training residuals use each demonstration's own start, a rollout its start (docs/method.md §11).
    ``residual_gain``: g ≥ 0 on the GP's residual mean (:attr:`MotionModel.residual_gain`), or ``"auto"``:
    chosen by rolling out each demonstration with the GP that has not seen it
    (:func:`rbgp_cli.dynamics.residual_gain.choose_residual_gain`; 1 where it cannot be: a sparse GP, no
    phase input, fewer than three demonstrations); ``summary["residual_gain"]`` says which and why.
    """
    t0 = time.perf_counter()
    rep, kernel, kern = _checked_model_options(representation, kernel, rho_rot, time_input, prior, prior_gain, euler_order)
    # what the command line's bounds say, for the library's callers too (a raw numpy error otherwise)
    if max_points is not None and not (isinstance(max_points, (int, np.integer)) and max_points >= 2):
        raise InputError(f"max_points must be a whole number of at least 2 (a GP needs two points), got {max_points!r}",
                         param="max_points")
    if not (isinstance(restarts, (int, np.integer)) and restarts >= 1):
        raise InputError(f"restarts must be a whole number of at least 1, got {restarts!r}", param="restarts")
    velocity = velocity or default_velocity()
    X, Y, info = training_set(trajs, rep, subsample=subsample, max_points=None, seed=seed, velocity=velocity,
                              time_input=time_input)
    trajs, info = _without_empty_demos(trajs, info, velocity)
    gp_choice = choose_gp(info["points"], inducing, max_points, kernel)
    if gp_choice["type"] == "exact" and max_points is not None and info["points"] > max_points:
        X, Y, info = training_set(trajs, rep, subsample=subsample, max_points=max_points, seed=seed, velocity=velocity,
                                  time_input=time_input)
    mean, start_dev = _prior_of(trajs, info, prior, prior_gain, start_conditioning, seed, pull_profile)
    if mean is not None:
        step = None
        if mean.get("feedforward") == "secant":  # each pair's own phase step: its forward difference's
            step = info["phase_steps"]
        Y = Y - prior_mean_outputs(rep, X[:, : len(rep.input_names)], mean, X[:, -1] if time_input == "phase" else None,
                                   start_dev=start_dev, step=step)
    if progress:
        progress(f"{plural(len(trajs), 'demonstration')}, {info['pairs']} pairs, training on {info['points']} points "
                 f"({rep.name}, kernel {kernel}, {'shared' if shared else 'per-output'} hyperparameters)")
    fit = dict(noise=noise, restarts=restarts, seed=seed, shared=shared, progress=progress, explore_size=explore_size)
    side = _WithoutGP(trajs, mean)
    exact = gp_choice["type"] != "sparse"  # (a sparse fit may fall back on the exact GP: then fitted already)
    if not exact:
        gp, gp_choice, info = _fit_sparse(X, Y, kern, gp_choice, info, hyper_points, jobs, max_points=max_points, **fit)
        gp = _scaled_posterior_noise(gp, gp_choice, info, calibrate, noise_scale, seed, progress)
        side()
    recorded_dt = float(np.median(np.concatenate([np.diff(tr.t) for tr in trajs])))
    dt = 1.0 / velocity.rate if velocity.rate is not None else recorded_dt
    starts = np.array([np.concatenate([tr.quat[0], tr.position[0]]) for tr in trajs])
    durations = np.array([tr.duration for tr in trajs])

    def motion_model(gp):
        return MotionModel(rep, gp, float(dt), starts, durations, velocity=velocity, time_input=time_input, mean=mean,
                           variation=side.variation, envelope=side.envelope, paths=side.paths)

    gain = None
    quick = exact and _gain_first(residual_gain, time_input, mean, trajs)
    if exact:
        # the work that needs no GP runs on a thread of this process, started while the worker processes
        # fit the GP (when one of them has no output left), and goes on beside the posterior on all rows and
        # the calibration; BLAS single-threaded throughout, as the fit and the calibration run it
        with blas_threads(0):
            # the calibration and the noise scale make a posterior of their own: the fit's factors are not needed
            replaced = bool(calibrate) or noise_scale != 1.0
            if quick:  # the gain chosen from a cheap fit first: the full fit only if the residual may pay
                hp = EXACT_HYPER_POINTS if hyper_points is None else int(hyper_points)
                gp_q, choice_q = _fit_exact(X, Y, kern, dict(gp_choice), min(QUICK_HYPER_POINTS, hp) if hp > 0
                                            else QUICK_HYPER_POINTS, jobs,
                                            dict(fit, restarts=1, beside=side.start, factorise=not replaced))
                gp_q = _scaled_posterior_noise(gp_q, choice_q, info, calibrate, noise_scale, seed, progress,
                                               QUICK_CALIBRATION_POINTS)
                side()  # waits for the thread
                model = motion_model(gp_q)
                gain = _residual_gain_of(model, trajs, info, residual_gain, progress, seed)
                if residual_off_clearly(gain):
                    gp, gp_choice = gp_q, choice_q
                    gain["fit"] = {"full_fit": False, "hyper_points": int(choice_q["hyper_points"]), "restarts": 1,
                                   "calibration_points": QUICK_CALIBRATION_POINTS,
                                   "reason": "the GP's residual is off already with a cheap fit (no other gain closer "
                                   "than g = 0 by half a standard error; one start on at most "
                                   f"{QUICK_HYPER_POINTS} points, the noise calibrated on at most "
                                   f"{QUICK_CALIBRATION_POINTS}); the full fit was skipped"}
                    if progress:
                        progress("GP residual off already with a cheap fit: the full fit was skipped "
                                 "(--residual-gain 1 fits it)")
                else:
                    if progress:
                        progress("the cheap fit leaves the GP's residual gain open: the full fit")
                    gain = None
            if gain is None:
                gp, gp_choice = _fit_exact(X, Y, kern, gp_choice, hyper_points, jobs,
                                           dict(fit, beside=side.start, factorise=not replaced))
                gp = _scaled_posterior_noise(gp, gp_choice, info, calibrate, noise_scale, seed, progress)
                side()  # waits for the thread (at once when the cheap fit ran it)
    if gain is None:
        model = motion_model(gp)
        gain = _residual_gain_of(model, trajs, info, residual_gain, progress, seed)
        if quick:
            gain["fit"] = {"full_fit": True, "reason": "a cheap fit first (one start on at most "
                           f"{QUICK_HYPER_POINTS} points, the noise calibrated on at most {QUICK_CALIBRATION_POINTS}) "
                           "did not switch the GP's residual off with half a standard error to spare"}
    model.summary = _train_summary(rep, kernel, kern, trajs, info, shared, velocity, gp, gp_choice, mean, side.variation,
                                   time_input, recorded_dt, t0, paths=side.paths)
    model.summary["residual_gain"] = gain
    return model


#: The cheap fit that chooses the residual's gain first (:func:`train_model` with ``residual_gain="auto"``): the
#: hyperparameters from one start (the data-driven one) on a random this many training points, ...
QUICK_HYPER_POINTS = 200
#: ... and the noise calibrated on at most this many (the full fit's: 1000, gp.calibration.CALIBRATION_POINTS;
#: its eigendecompositions cost 8× less). On the five real and sample sets the choice's margins moved by
#: at most 0.1 standard errors (docs/defaults.md, issue 35's seventh pass).
QUICK_CALIBRATION_POINTS = 500


def _gain_first(residual_gain, time_input, mean, trajs) -> bool:
    """Whether :func:`train_model` chooses the residual's gain from a cheap fit first: ``"auto"`` with what
    the choice needs (the phase input, the mean-path prior, three demonstrations; an exact GP)."""
    auto = residual_gain is None or (isinstance(residual_gain, str) and residual_gain == "auto")
    return bool(auto and time_input == "phase" and mean is not None and len(trajs) >= 3)


def residual_off_clearly(gain: dict | None, margin: float = 0.5) -> bool:
    """Whether a gain choice (``summary["residual_gain"]`` of :func:`_residual_gain_of`) switched the GP's
    residual off with room to spare: g = 0 chosen, and no other gain's mean left-out error J(g) below J(0)
    by more than ``margin`` standard errors of the paired differences J_d(g) − J_d(0), or by more than
    ``margin`` times the practical-equivalence margin ε J(0) (ε = EQUIVALENT_FRACTION, 0.5 %;
    :func:`rbgp_cli.dynamics.residual_gain.choose_residual_gain`):

        J(g) − J(0) ≥ −margin · max(SE₀(g), ε J(0))   for every g ≠ 0   (and round-off: 1e-9 · J(0)).

    SE₀ is the record's ``standard_error_zero``; a record without it (a model file from before) has the
    standard errors against the best gain, the same where the best is g = 0.

    The one-standard-error rule keeps g = 0 while the best gain improves on it by less than one SE; with
    ``margin`` = ½ the cheap fit's choice holds even if the full fit's hyperparameters moved every J(g)
    by half a standard error in the residual's favour. (The first form of this test asked J(g) − J(0) >
    +1 SE: with the prior left out of the criterion, J(g) lies within a few tenths of a per cent of J(0)
    on the handovers and hand raises, and the full fit ran after the cheap one for nothing; issue 35's
    seventh pass in docs/defaults.md.)"""
    if not gain or gain.get("chosen") != "left-out rollouts" or gain.get("gain") != 0.0:
        return False
    from rbgp_cli.dynamics.residual_gain import EQUIVALENT_FRACTION

    grid, err = gain["grid"], gain["error"]
    se = gain.get("standard_error_zero") or gain["standard_error"]
    i0 = grid.index(0.0)
    tol = 1e-9 * abs(err[i0])
    equal = EQUIVALENT_FRACTION * abs(err[i0])
    return all(err[i] - err[i0] >= -margin * max(se[i], equal) - tol for i in range(len(grid)) if i != i0)


def _residual_gain_of(model, trajs, info, residual_gain, progress, seed: int = 0) -> dict:
    """Set ``model.residual_gain``: the number given, or with ``"auto"`` the gain chosen by leaving
    demonstrations out (:func:`rbgp_cli.dynamics.residual_gain.choose_residual_gain`; 1 where it cannot
    be chosen). Returns the summary's record: {"gain", "chosen": "given" | "left-out rollouts" | "default",
    and the choice's errors, or a "reason"}."""
    if residual_gain is None or (isinstance(residual_gain, str) and residual_gain == "auto"):
        from rbgp_cli.dynamics.residual_gain import choose_residual_gain

        groups = np.repeat(np.arange(len(info["per_demo"])), info["per_demo"])[np.asarray(info["indices"])]
        with blas_threads(0):
            choice = None if model.mean is None else choose_residual_gain(model, trajs, groups, seed=seed,
                                                                            phase_steps=info.get("phase_steps"))
        if choice is None:
            model.residual_gain = 1.0
            return {"gain": 1.0, "chosen": "default",
                    "reason": "not chosen: needs an exact GP with the phase input, a prior mean and 3 demonstrations"}
        model.residual_gain = choice["gain"]
        if progress:
            progress(f"GP residual gain {choice['gain']:g} (left-out rollouts of {choice['demos']} demonstrations, "
                     "relative error " + ", ".join(f"{g:g}: {e:.3f}" for g, e in zip(choice["grid"], choice["error"]))
                     + f"; {choice['seconds']:.2f} s)")
        return {**{k: (round(v, 6) if isinstance(v, float) else v) for k, v in choice.items()},
                "error": [round(v, 5) for v in choice["error"]],
                "standard_error": [round(v, 5) for v in choice["standard_error"]],
                "position_rmse": [round(v, 6) for v in choice["position_rmse"]],
                "rotation_rmse": [round(v, 6) for v in choice["rotation_rmse"]], "chosen": "left-out rollouts"}
    g = float(residual_gain)
    if not (np.isfinite(g) and 0.0 <= g <= 100.0):
        raise InputError(f"residual_gain must be 'auto' or a number from 0 to 100, got {residual_gain}",
                         param="residual_gain")
    model.residual_gain = g
    return {"gain": g, "chosen": "given"}


class _WithoutGP:
    """The parts of a trained model that do not depend on the GP: the demonstrations' variation (the
    bands' scale measures each demonstration left out against the mean rollout's own prediction of it:
    the start map's ridge, ∞ without conditioning, and the pull that closes a start's gap), the path
    distribution and the envelope. :meth:`start` computes them on a thread of their own, the call
    waits for it (or computes them, if not started) and re-raises its error. :func:`train_model` hands
    ``start`` to the exact GP's fit, which calls it when a worker process has no output left
    (:func:`rbgp_cli.gp.exact.fit_gp`'s ``beside``): the thread then runs on the core that worker
    leaves idle, and on beside the posterior on all rows and the noise calibration, which need the fit
    and used to wait for it (issue 35, fourth pass). The same numbers as after the fit (BLAS
    single-threaded in both)."""

    def __init__(self, trajs, mean):
        self.trajs, self.mean = trajs, mean
        self.done = False
        self._thread = None
        self._error = None

    def start(self):
        """Compute on a thread of its own (daemon: an error elsewhere does not wait for it)."""
        import threading

        if self.done or self._thread is not None:
            return

        def run():
            try:
                self._compute()
            except BaseException as exc:  # re-raised by the call that waits
                self._error = exc

        self._thread = threading.Thread(target=run, name="rbgp-without-gp", daemon=True)
        self._thread.start()

    def __call__(self):
        if self._thread is not None:
            self._thread.join()
            self._thread = None
            if self._error is not None:
                raise self._error
        self._compute()

    def _compute(self):
        if self.done:
            return
        from rbgp_cli.dynamics.envelope import envelope_from_demos
        from rbgp_cli.dynamics.paths import fit_paths
        from rbgp_cli.dynamics.variation import demonstration_variation

        mean = self.mean
        ridge = float(mean["start_ridge"]) if mean is not None and "start_ridge" in mean else float("inf")
        gain = float(mean["gain"]) if mean is not None and mean["kind"] == "path" else 0.0
        inputs = mean.get("start_inputs", "path") if mean is not None else "path"
        self.variation = demonstration_variation(self.trajs, ridge=ridge, gain=gain, inputs=inputs)
        self.paths = fit_paths(self.trajs)
        self.envelope = envelope_from_demos(self.trajs)
        self.done = True


def _checked_model_options(representation, kernel, rho_rot, time_input, prior, prior_gain, euler_order):
    """:func:`train_model`'s model options checked (InputError naming the parameter): the
    representation, the kernel's name and the kernel (with ρ1 fixed, or learned for ``"learn"``)."""
    if representation not in DEFAULT_KERNELS:
        raise InputError(f"unknown representation {representation!r}; expected one of {', '.join(DEFAULT_KERNELS)}",
                         param="representation")
    kernel = kernel or DEFAULT_KERNELS[representation]
    rep = make_representation(representation, order=euler_order) if representation == "euler" else make_representation(representation)
    learn_rho = rho_rot == "learn"
    rho = 0.7 if learn_rho else float(rho_rot)
    if not learn_rho and not 0 < rho < 1:
        raise InputError(f"rho_rot must lie strictly between 0 and 1 (or be 'learn'), got {rho_rot}", param="rho_rot")
    if time_input not in TIME_INPUTS:
        raise InputError(f"unknown time input {time_input!r}; expected one of none, seconds, phase")
    if prior not in PRIORS:
        raise InputError(f"unknown prior {prior!r}; expected one of none, goal, path")
    if prior == "path" and time_input != "phase":
        raise InputError(f"prior path (the default) follows the phase, but time_input is {time_input or 'none'}",
                         hint="add prior none (or goal), or use time_input phase", param="prior")
    if prior and not (np.isfinite(prior_gain) and prior_gain >= 0):
        raise InputError(f"prior_gain must be a non-negative number, got {prior_gain}", param="prior_gain")
    return rep, kernel, make_kernel(rep, kernel, rho, learn_rho, time_dims=1 if time_input else 0)


def _without_empty_demos(trajs, info, velocity):
    """The demonstrations that give at least one training pair (and ``info["per_demo"]`` for them); the
    others are not demonstrations of the motion (no start, duration or path of their own): one warning."""
    empty = [k for k, c in enumerate(info["per_demo"]) if c == 0]
    if not empty:
        return trajs, info
    names = [trajs[k].name or trajs[k].source or f"demonstration {k + 1}" for k in empty]
    shown = ", ".join(names[:8]) + (f" and {len(names) - 8} more" if len(names) > 8 else "")
    grid = f"the {velocity.rate:g} Hz training grid" if velocity.rate else "the recorded samples"
    warn(f"left out {len(empty)} of {len(trajs)} demonstrations that give no training pair on {grid} "
         f"(too few samples or too short): {shown}")
    keep = [k for k, c in enumerate(info["per_demo"]) if c > 0]
    info["per_demo"] = [info["per_demo"][k] for k in keep]
    return [trajs[k] for k in keep], info


def _prior_of(trajs, info, prior, prior_gain, start_conditioning, seed, pull_profile=False):
    """The prior mean (docs/method.md §7: ``path``, ``goal`` or None) and, for a start-conditioned mean
    path (3 or more demonstrations), each training row's start deviation (n, 6), else None. With
    ``pull_profile`` a start-conditioned path's pull gain follows the demonstrations' convergence
    (``mean["gain_profile"]`` (S, 6), :func:`~rbgp_cli.dynamics.variation.pull_profile`)."""
    mean = None
    if prior == "path":
        mean = {"kind": "path", "gain": float(prior_gain), **mean_path(trajs)}
        if info.get("phase_steps") is not None:  # forward differences: the path's secant over each step
            mean["feedforward"] = "secant"
    elif prior == "goal":
        mean = {"kind": "goal", "gain": float(prior_gain), "goal": goal_pose(trajs).tolist()}
    start_dev = None
    if mean is not None and mean["kind"] == "path" and start_conditioning and len(trajs) >= 3:
        from rbgp_cli.dynamics.variation import demonstration_deviations, pull_profile as profile_of, start_map, start_reach

        _, delta = demonstration_deviations(trajs, len(mean["s"]))
        cond = start_map(delta, seed=seed)
        mean["start_mean"], mean["start_beta"], mean["start_ridge"] = cond["mean"], cond["map"], cond["ridge"]
        mean["start_inputs"] = cond["inputs"]  # the map's units (issue 36); moved to the summary with the ridge
        mean["start_reach"] = start_reach(delta, cond["mean"])  # the map's shift bounded by the demonstrations' reach
        if pull_profile:
            mean["gain_profile"] = profile_of(delta, cond["mean"], cond["map"], np.asarray(mean["s"]), float(prior_gain))
        demo_of_row = np.repeat(np.arange(len(trajs)), info["per_demo"])[np.asarray(info["indices"])]
        start_dev = PathReference(mean).start_deviation(np.array([tr.quat[0] for tr in trajs]),
                                                        np.array([tr.position[0] for tr in trajs]))[demo_of_row]
    return mean, start_dev


def _widen_exact(gp, max_points, seed) -> None:
    """Make the sparse fit's exact GP (``gp.hyper_gp`` on ``gp.hyper_rows``, the subset that chose the
    hyperparameters) the one the automatic choice compares with and falls back on: the same
    hyperparameters on a random ``max_points`` of the rows (those rows among them), so that the
    fallback is as strong as ``--inducing 0``'s exact GP on as many points. Nothing changes when the
    subset has ``max_points`` rows already."""
    rows = np.asarray(gp.hyper_rows)
    want = min(len(gp.X), int(max_points) if max_points else len(rows))
    if want <= len(rows):
        return
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 31]))
    extra = rng.choice(np.setdiff1d(np.arange(len(gp.X)), rows), size=want - len(rows), replace=False)
    rows = np.sort(np.concatenate([rows, extra]))
    exact = gp.hyper_gp
    # factorised only if it becomes the model (_keep_sparse_if_no_worse): its Cholesky factors, one
    # max_points² matrix per output (6 × 32 MB at 2000 points), were most of a big file's peak memory
    gp.hyper_gp = ExactSpec(exact.kernel, exact.fits, exact.shared, exact.y_scale)
    gp.hyper_rows = rows


def _fit_exact(X, Y, kern, gp_choice, hyper_points, jobs, fit):
    """The exact GP on all rows of X, Y, its hyperparameters from the NLML of a random
    ``hyper_points`` of them (None: EXACT_HYPER_POINTS; 0: all; :func:`rbgp_cli.gp.exact.fit_gp`).
    Returns (gp, gp_choice), ``gp_choice`` saying how many points chose the hyperparameters."""
    hp = EXACT_HYPER_POINTS if hyper_points is None else int(hyper_points)
    hp = len(X) if hp <= 0 else min(len(X), hp)
    if jobs is None:
        jobs = default_jobs(1 if fit["shared"] else Y.shape[1], hp)
    gp = fit_gp(X, Y, kern, jobs=jobs, hyper_points=hp if hp < len(X) else None, **fit)
    covered = len(getattr(gp, "hyper_subset", X))
    gp_choice["hyper_points"] = covered
    gp_choice["hyperparameters"] = "the exact GP's NLML"
    if covered < len(X):
        why = f"hyperparameters from the NLML of a random {covered} of them (--hyper-points 0: all), the posterior on all"
        gp_choice["reason"] = f"{gp_choice['reason']}; {why}" if gp_choice["reason"] else why
    return gp, gp_choice


def _fit_sparse(X, Y, kern, gp_choice, info, hyper_points, jobs, *, noise, restarts, seed, shared, progress,
                explore_size, max_points=None):
    """The sparse GP of ``gp_choice`` on all points (:func:`rbgp_cli.gp.sparse.fit_sparse_gp`), or,
    chosen automatically, the exact GP on a random ``max_points`` of them at the same hyperparameters
    where that measures better (:func:`_widen_exact`, :func:`_keep_sparse_if_no_worse`). Returns (gp,
    gp_choice, info), ``gp_choice`` saying which and why."""
    from rbgp_cli.gp.sparse import HYPER_EXACT_POINTS, fit_sparse_gp

    if progress:
        progress(f"sparse GP: {gp_choice['reason']}")
    if jobs is None:  # worker processes for the exact fit that chooses the hyperparameters
        hp = len(X) if hyper_points == 0 else min(len(X), hyper_points or HYPER_EXACT_POINTS)
        jobs = default_jobs(1 if shared else Y.shape[1], hp)
    gp = fit_sparse_gp(X, Y, kern, inducing=gp_choice["inducing"], noise=noise, restarts=restarts, seed=seed,
                       shared=shared, progress=progress, explore_size=explore_size, hyper_points=hyper_points,
                       jobs=jobs)
    gp_choice["inducing"] = int(gp.n_inducing)
    # the stage that chose the hyperparameters: the exact GP's fit on a subset (the default) or the bound
    stages = [st for f in gp.fits for st in f.stages]
    last = "bound" if any(st["objective"] == "bound" for st in stages) else "exact NLML"
    covered = max((int(st["points"]) for st in stages if st["objective"] == last), default=len(X))
    gp_choice["hyper_points"] = covered
    gp_choice["hyperparameters"] = "the bound" if last == "bound" else "the exact GP's NLML"
    if covered < len(X):
        gp_choice["reason"] += (f"; hyperparameters from {gp_choice['hyperparameters']} on a random {covered} of them "
                                "(--hyper-points 0: all), the posterior on all")
    else:
        gp_choice["reason"] += f"; hyperparameters from {gp_choice['hyperparameters']} on all of them"
    if not gp_choice["forced"] and getattr(gp, "hyper_gp", None) is not None:
        _widen_exact(gp, max_points, seed)
        rows = gp.hyper_rows
        gp, gp_choice = _keep_sparse_if_no_worse(gp, gp_choice, info, seed, progress)
        if gp_choice["type"] == "exact":  # the training points are now the subset's
            info = dict(info, indices=np.asarray(info["indices"])[rows], points=int(len(rows)))
    return gp, gp_choice, info


def _scaled_posterior_noise(gp, gp_choice, info, calibrate, noise_scale, seed, progress, points: int | None = None):
    """The posterior's σn² scaled: by held-out demonstrations (``calibrate``,
    :func:`rbgp_cli.gp.calibration.calibrate_to_demonstrations`, on at most ``points`` rows; None: its
    default), then by ``noise_scale`` (:func:`rbgp_cli.gp.calibration.scale_noise`); ``gp_choice`` records
    the factors."""
    if calibrate:
        from rbgp_cli.gp.calibration import calibrate_to_demonstrations

        groups = np.repeat(np.arange(len(info["per_demo"])), info["per_demo"])[info["indices"]]
        # the noise scale in the same posterior (one factorisation, not two)
        gp, records = calibrate_to_demonstrations(gp, groups, seed=seed, extra_factor=noise_scale,
                                                  **({} if points is None else {"points": int(points)}))
        gp_choice["calibration"] = None if records is None else {
            "noise_variance_factors": [round(r["factor"], 3) for r in records],
            "points": records[0]["points"], "folds": records[0]["folds"]}
        if progress:
            progress("noise calibration: " + ("needs at least two demonstrations; skipped" if records is None else
                     "sigma_n^2 x " + ", ".join(f"{r['factor']:.3g}" for r in records)
                     + f" (each of {records[0]['folds']} demonstrations left out in turn, on {records[0]['points']} points)"))
    if noise_scale != 1.0:
        if not calibrate:
            from rbgp_cli.gp.calibration import scale_noise

            gp = scale_noise(gp, noise_scale)
        gp_choice["noise_scale"] = float(noise_scale)
        if progress:
            progress(f"noise scale: sigma_n^2 x {noise_scale:g} more in the posterior")
    return gp


def _train_summary(rep, kernel, kern, trajs, info, shared, velocity, gp, gp_choice, mean, variation, time_input,
                   recorded_dt, t0, paths=None) -> dict:
    """The model's ``summary`` (:func:`train_model`): demonstrations, pairs, points, per output the
    hyperparameters and NLML, the safeguards used, the GP chosen, the prior, the variation, the time taken.
    Moves the start map's ridge and units from ``mean`` into it."""
    names = ["all"] if shared else list(rep.output_names)
    summary = {
        "representation": rep.name,
        "kernel": kernel,
        "rotation_metric": getattr(kern, "metric", None),
        "demos": len(trajs),
        "pairs": info["pairs"],
        "points": info["points"],
        "shared_hyperparameters": bool(shared),
        "velocity": {**velocity.to_dict(), "segments": len(info["segments"]),
                     "integration_drift": integration_drift(info["segments"])},
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
    summary["time_input"] = time_input
    summary["recorded_rate_hz"] = 1.0 / recorded_dt  # rollouts are written at this rate by default
    summary["gp"] = gp_choice
    summary["prior"] = None if mean is None else {"kind": mean["kind"], "gain": mean["gain"],
                                                  "start_conditioned": "start_beta" in mean}
    if mean is not None and mean.get("gain_profile") is not None:  # the pull's profile: its largest gain
        summary["prior"]["gain_max"] = float(np.max(mean["gain_profile"]))
    if mean is not None and "start_ridge" in mean:  # the cross-validated ridge (None: ∞, no conditioning)
        lam = float(mean.pop("start_ridge"))
        summary["prior"]["start_ridge"] = lam if np.isfinite(lam) else None
        # the units the start map measures the start in (variation.start_map: "path" or "start")
        summary["prior"]["start_inputs"] = str(mean.pop("start_inputs", "path"))
    summary["variation"] = None if variation is None else {
        "demos": variation.demos, "dof": variation.dof,
        "band_scale": {"rotation": float(variation.band_scale[0]), "position": float(variation.band_scale[1])},
        "shrinkage": float(variation.shrinkage),
        # the factors from the demonstrations left out at random and in contiguous blocks in recording
        # order (dynamics/variation.band_calibration), and the drift over that order (order_drift)
        "calibration": variation.calibration,
        "drift": variation.drift}
    summary["paths"] = None if paths is None else {
        "demos": paths.demos, "smooth": float(paths.smooth), "length": float(paths.length),
        "band_scale": {"rotation": float(paths.band_scale[0]), "position": float(paths.band_scale[1])},
        **({"duration_evidence": float(paths.duration_evidence)} if paths.duration_evidence is not None else {}),
        **({"duration_statistic": str(paths.duration_statistic)} if paths.duration_statistic is not None else {})}
    # the recording order is the order the demonstrations were read (docs/data.md, "Recording order")
    summary["recording_order"] = [tr.name or tr.source or f"demonstration {k + 1}" for k, tr in enumerate(trajs)][:1000]
    return summary
