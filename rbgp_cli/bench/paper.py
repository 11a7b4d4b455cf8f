"""``rbgp bench paper``: the paper's Theorem 1 and its claims of sec. 4.1 and 4.2, measured with rbgp's own
kernels, GP and geometry (docs/method.md §6, §10), with statistics over repetitions instead of one run.

Three parts, each runnable alone (:data:`PARTS`); every random draw comes from
``SeedSequence([seed, part, repetition])``, so a part run alone gives the numbers it gives in a full run.

**theorem** (paper Theorem 1: the squared exponential of the geodesic distance is positive definite).
Smallest eigenvalue of the Gram matrix K_ij = exp(−d(r_i, r_j)² / (2λ²)) (σf = 1, no noise) of the
geodesic kernel (d = d_arc, eq. 14) next to the chordal one (d = d_ch = 2 sin(d_arc/2)), on the
counterexample of docs/method.md §6 (8 rotations about one axis, π/4 apart) and on ``repeats`` sets of
uniformly random rotations per size, for a grid of λ (in radians of rotation distance). Eigenvalues of
a PSD matrix computed in float64 can come out negative by round-off, about n·ε·‖K‖ ≤ n²·ε; the
report states that bound next to the chordal numbers.

**runtime** (sec. 4.1: prediction with the axis-angle kernel is faster than with dual quaternions).
Per repetition: 80 random training poses (rotations uniform on SO(3), translations ~ N(0, 0.3²) m)
with one pseudo-random output y ~ N(0, 1) (as the GPML generator the paper used), a GP fitted per
model (:func:`rbgp_cli.gp.exact.fit_gp`, σn learned, one start), then the wall time of predicting
at 10001 new random poses, mean only and mean with standard deviation, the models in a random order
each repetition. BLAS runs single-threaded (threadpoolctl) for every model alike; rbgp's own
prediction still splits the 10001 rows into chunks on its thread pool, as it does for users.
Reported: median and quartiles of the times, the same-run ratio to the axis-angle model per
repetition (median and quartiles), and Welch's t-test of each model against axis-angle.

**accuracy** (sec. 4.2: on random rotation dynamics the rigid-body GP's RMSE is about half that of the
unit-quaternion and Euler-angle GPs). Per repetition one random dynamics f of eq. 30
(:class:`RandomDynamics`), 1000 rotations uniform on SO(3) with their ground truth f, 100 of them
drawn (without replacement) for training, and the prediction at all 1000 scored, as in the paper.
Each model is fitted per output in three settings (:data:`SETTINGS`): one start λ, σf ~ U(0, 3) (the
paper's, λ in the representation's own rotation units) with σn fixed to 1 (the paper) or learned, and
rbgp's own starts (data-driven plus random) with σn learned. Errors of the predicted
rotation: RMSE over the components of the rotation vector (the paper's measure; predicted
quaternions are normalised and Euler angles converted, then both mapped to the canonical rotation
vector) and the root mean square geodesic angle d_arc between predicted and true rotation. Reported
per model: mean, median and 10 % trimmed mean of the per-dynamics RMSE, blow-ups (RMSE above
:data:`BLOW_UP_FACTOR` × the zero predictor's), failed fits, and paired comparisons (median of the
per-dynamics ratios, Wilcoxon signed-rank test, Welch's t-test).

Reading eq. 30 (the paper's text lost its delimiters in extraction): each component is
f_i(θu) = g(d / c ⊙ d̃ ⋆ c̃) with g ∈ {sin, cos, atan, acot}, ⊙ ∈ {+, −}, ⋆ ∈ {×, ÷},
c, c̃ ∈ {±1, ±3/2, ±1/3}, d, d̃ ∈ {θu_1, θu_2, θu_3}, all drawn uniformly and independently. With the
whole expression inside g every |f_i| ≤ π/2, so ‖f‖ ≤ √3·π/2 < π: f is a canonical rotation vector
θ0u0, as the paper describes it, and converts to quaternions and Euler angles without wrapping.
acot is MATLAB's, atan(1/x) in (−π/2, π/2] (the paper's function names are MATLAB's and its
experiments ran in MATLAB). Euler angles are principal values of the extrinsic xyz sequence (rbgp's
Euler representation); the paper's "unwrap" needs an order along a trajectory, which i.i.d. samples
lack. The paper's dual-quaternion GP is not specified in its text; rbgp's quaternion model (unit
quaternions, S³ angle) stands in for it, as in the paper's sec. 4.2.
"""

from __future__ import annotations

import math
import os
import platform
import time
import warnings
import zlib
from dataclasses import dataclass

import numpy as np

from rbgp_cli import __version__
from rbgp_cli.dynamics.model import make_kernel
from rbgp_cli.dynamics.representations import make_representation
from rbgp_cli.errors import RbgpRuntimeError
from rbgp_cli.geometry.distance import arc_distance_quat
from rbgp_cli.geometry.so3 import (
    euler_from_quat,
    quat_from_euler,
    quat_from_rotvec,
    quat_normalize,
    random_quat,
    rotvec_from_quat,
)
from rbgp_cli.gp.exact import fit_gp
from rbgp_cli.kernels import SquaredExponential

__all__ = [
    "PARTS",
    "RandomDynamics",
    "PaperStartKernel",
    "rotation_gram",
    "rotation_outputs",
    "predicted_rotation",
    "acot_matlab",
    "run_theorem",
    "run_runtime",
    "run_accuracy",
    "run_paper_bench",
    "format_report",
    "BLOW_UP_FACTOR",
]

PARTS = ("theorem", "runtime", "accuracy")
_PART_INDEX = {p: i for i, p in enumerate(PARTS)}

#: Repetitions per part when --repeats is not given (quick: a smoke run).
DEFAULT_REPEATS = 50
QUICK_REPEATS = 2

#: Rotation weight ρ1 used where the inputs are rotations only (zero translations): d² = ρ1·d_rot²,
#: so a rotation length-scale λ is passed to the kernel as λ·√ρ1.
_RHO_ROTATION_ONLY = 0.5

# -- theorem
THEOREM_LAMBDAS = (0.25, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0)
THEOREM_SIZES = (8, 50, 200)
THEOREM_SIZES_QUICK = (8, 50)

# -- runtime (paper sec. 4.1)
RUNTIME_TRAIN = 80
RUNTIME_QUERY = 10001
RUNTIME_RHO = 0.7  # the paper's ρ1 for SE(3) poses
RUNTIME_TRANSLATION_STD = 0.3
#: (representation, kernel) pairs; the first is the reference of the same-run ratios.
RUNTIME_MODELS = (("axis-angle", "se"), ("quaternion", "se"), ("euler", "se"), ("axis-angle", "se-chordal"))

# -- accuracy (paper sec. 4.2)
ACCURACY_POINTS = 1000
ACCURACY_TRAIN = 100
ACCURACY_MODELS = (("axis-angle", "se"), ("axis-angle", "se-chordal"), ("quaternion", "se"), ("euler", "se"))
#: Fit settings (label, σn, the paper's starts?): the paper's (σn = 1, one start λ, σf ~ U(0, 3)), the same
#: start with σn learned, and rbgp's own starts (the data-driven one and two random ones) with σn learned.
SETTINGS = (("σn = 1, paper's start", 1.0, True), ("σn learned, paper's start", None, True),
            ("σn learned, rbgp's 3 starts", None, False))
RBGP_RESTARTS = 3
#: A fit "blew up" when its rotation-vector RMSE exceeds this many times the zero predictor's.
BLOW_UP_FACTOR = 10.0
TRIM = 0.1
#: Paired comparisons (a, b): ratio a/b per dynamics.
ACCURACY_COMPARISONS = (
    (("axis-angle", "se"), ("euler", "se")),
    (("axis-angle", "se"), ("quaternion", "se")),
    (("axis-angle", "se-chordal"), ("euler", "se")),
    (("axis-angle", "se-chordal"), ("axis-angle", "se")),
)
PAPER_START_INTERVAL = (0.0, 3.0)


def _label(rep: str, kernel: str) -> str:
    names = {("axis-angle", "se"): "rigid-body (axis-angle, geodesic)",
             ("axis-angle", "se-chordal"): "axis-angle, chordal",
             ("quaternion", "se"): "unit quaternion (S³ angle)",
             ("euler", "se"): "Euler angles (Euclidean)"}
    return names.get((rep, kernel), f"{rep}, {kernel}")


def _key(rep: str, kernel: str) -> str:
    return f"{rep}/{kernel}"


def _rng(seed: int, part: str, index: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([int(seed), _PART_INDEX[part], int(index)]))


# ================================================================================================ theorem
def rotation_gram(metric: str, rotvecs: np.ndarray, length_scale: float) -> np.ndarray:
    """K_ij = exp(−d(r_i, r_j)² / (2λ²)) for rotations only (σf = 1, no noise), shape (n, n).

    ``metric``: "arc" (the paper's geodesic kernel, eq. 24 with ρ2 = 0) or "chordal". Built with
    :class:`~rbgp_cli.kernels.SquaredExponential` on poses with zero translation, whose d² is
    ρ1·d_rot², so λ is passed as λ·√ρ1. ``rotvecs``: shape (n, 3).
    """
    r = np.asarray(rotvecs, dtype=np.float64).reshape(-1, 3)
    X = np.concatenate([r, np.zeros_like(r)], axis=1)
    rho = _RHO_ROTATION_ONLY
    k = SquaredExponential(metric, rotation_dims=3, rho_rot=rho)
    return k(X, None, {"signal_std": 1.0, "length_scale": float(length_scale) * math.sqrt(rho), "rho_rot": rho})


def _min_eig(K: np.ndarray) -> float:
    from scipy.linalg import eigvalsh

    return float(eigvalsh(K, subset_by_index=[0, 0], check_finite=False)[0])


def counterexample_rotations() -> np.ndarray:
    """docs/method.md §6: 8 rotations about the z axis, π/4 apart, as canonical rotation vectors, shape (8, 3)."""
    angles = np.arange(8) * (math.pi / 4)
    q = np.stack([np.zeros(8), np.zeros(8), np.sin(angles / 2), np.cos(angles / 2)], axis=1)
    return rotvec_from_quat(q)


def run_theorem(repeats: int, seed: int = 0, quick: bool = False, progress=None) -> dict:
    """Smallest Gram eigenvalues of the geodesic and the chordal kernel (module docstring, **theorem**).

    Returns ``{"geodesic_min_eigenvalue", "chordal_min_eigenvalue"`` (the smallest over everything
    computed), ``"counterexample"`` (one row per λ), ``"search"`` (one row per set size and λ: min and
    median over the sets, how many sets had an eigenvalue below −roundoff), ``"roundoff_bound"``
    (per size, n²·ε), ``"lambdas"``, ``"sizes"``, ``"sets"``, ``"seconds"``}.
    """
    t0 = time.perf_counter()
    eps = float(np.finfo(np.float64).eps)
    r8 = counterexample_rotations()
    counter = []
    for lam in THEOREM_LAMBDAS:
        counter.append({"lambda": lam, "geodesic": _min_eig(rotation_gram("arc", r8, lam)),
                        "chordal": _min_eig(rotation_gram("chordal", r8, lam))})
    sizes = THEOREM_SIZES_QUICK if quick else THEOREM_SIZES
    search = []
    for n in sizes:
        tol = n * n * eps
        geo = np.empty((repeats, len(THEOREM_LAMBDAS)))
        cho = np.empty_like(geo)
        for s in range(repeats):
            r = rotvec_from_quat(random_quat(_rng(seed, "theorem", n * 100_000 + s), n))
            for j, lam in enumerate(THEOREM_LAMBDAS):
                geo[s, j] = _min_eig(rotation_gram("arc", r, lam))
                cho[s, j] = _min_eig(rotation_gram("chordal", r, lam))
        for j, lam in enumerate(THEOREM_LAMBDAS):
            search.append({
                "n": n, "lambda": lam, "sets": repeats,
                "geodesic_min": float(geo[:, j].min()), "geodesic_median": float(np.median(geo[:, j])),
                "geodesic_negative_sets": int(np.sum(geo[:, j] < -tol)),
                "chordal_min": float(cho[:, j].min()), "chordal_negative_sets": int(np.sum(cho[:, j] < -tol)),
                "roundoff_bound": tol,
            })
        if progress:
            progress(f"theorem: {repeats} random sets of {n} rotations")
    geo_all = [c["geodesic"] for c in counter] + [s["geodesic_min"] for s in search]
    cho_all = [c["chordal"] for c in counter] + [s["chordal_min"] for s in search]
    return {
        "geodesic_min_eigenvalue": float(min(geo_all)),
        "chordal_min_eigenvalue": float(min(cho_all)),
        "counterexample": counter,
        "search": search,
        "lambdas": list(THEOREM_LAMBDAS),
        "sizes": list(sizes),
        "sets": int(repeats),
        "seconds": time.perf_counter() - t0,
    }


# ================================================================================================ runtime
def _random_poses(rng: np.random.Generator, n: int):
    return random_quat(rng, n), rng.normal(0.0, RUNTIME_TRANSLATION_STD, (n, 3))


def _welch(a, b) -> dict:
    from scipy import stats

    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    a, b = a[np.isfinite(a)], b[np.isfinite(b)]
    if len(a) < 2 or len(b) < 2:
        return {"t": None, "df": None, "p": None}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = stats.ttest_ind(a, b, equal_var=False)
    df = getattr(res, "df", None)
    return {"t": _num(res.statistic), "df": _num(df), "p": _num(res.pvalue)}


def _quartiles(x) -> dict:
    x = np.asarray(x, dtype=np.float64)
    x = x[np.isfinite(x)]
    if len(x) == 0:
        return {"median": None, "q25": None, "q75": None}
    q25, med, q75 = np.percentile(x, [25, 50, 75])
    return {"median": float(med), "q25": float(q25), "q75": float(q75)}


def run_runtime(repeats: int, seed: int = 0, progress=None) -> dict:
    """Prediction time at 10001 poses from GPs on 80 poses, per model (module docstring, **runtime**).

    Returns ``{"rows": [{"model", "representation", "kernel", "mean_only": {...}, "mean_std": {...}}],
    "welch": [...], "times": {...}, "repeats", "blas", ...}``; times in seconds.
    """
    from rbgp_cli.compute import blas_pools, one_thread

    t0 = time.perf_counter()
    keys = [_key(*m) for m in RUNTIME_MODELS]
    kinds = ("mean_only", "mean_std")
    times = {k: {kind: [] for kind in kinds} for k in keys}
    skipped = []
    warmed = False
    with one_thread():
        blas = blas_pools()
        for rep_i in range(repeats):
            rng = _rng(seed, "runtime", rep_i)
            q_train, t_train = _random_poses(rng, RUNTIME_TRAIN)
            y = rng.standard_normal(RUNTIME_TRAIN)
            q_query, t_query = _random_poses(rng, RUNTIME_QUERY)
            models = {}
            try:
                for (rep_name, kernel_name), key in zip(RUNTIME_MODELS, keys):
                    rep = make_representation(rep_name)
                    kernel = make_kernel(rep, kernel_name, rho_rot=RUNTIME_RHO)
                    X = rep.state_from_pose(q_train, t_train)
                    gp = fit_gp(X, y[:, None], kernel, noise="learn", restarts=1, seed=rep_i, shared=False,
                                explore_size=0)
                    models[key] = (gp, rep.state_from_pose(q_query, t_query))
            except RbgpRuntimeError as exc:  # no model, no same-run ratio: skip this repetition for all
                skipped.append({"repetition": rep_i, "reason": exc.message})
                continue
            if not warmed:  # thread pools, first-call costs
                for gp, Xq in models.values():
                    gp.predict(Xq, return_std=True)
                warmed = True
            order = [(k, kind) for k in keys for kind in kinds]
            for i in rng.permutation(len(order)):
                key, kind = order[i]
                gp, Xq = models[key]
                start = time.perf_counter()
                gp.predict(Xq, return_std=(kind == "mean_std"))
                times[key][kind].append(time.perf_counter() - start)
            if progress and (rep_i + 1 == repeats or (rep_i + 1) % max(1, repeats // 5) == 0):
                progress(f"runtime: {rep_i + 1}/{repeats} repetitions")
    ref = keys[0]
    rows = []
    welch = []
    for (rep_name, kernel_name), key in zip(RUNTIME_MODELS, keys):
        row = {"model": _label(rep_name, kernel_name), "key": key, "representation": rep_name, "kernel": kernel_name}
        for kind in kinds:
            t = np.array(times[key][kind])
            ratio = t / np.array(times[ref][kind])
            row[kind] = {**_quartiles(t), "mean": float(np.mean(t)), "std": float(np.std(t, ddof=1)) if len(t) > 1 else None,
                         "ratio_to_axis_angle": _quartiles(ratio)}
            if key != ref:
                welch.append({"a": ref, "b": key, "kind": kind, **_welch(times[ref][kind], times[key][kind]),
                              "mean_difference_s": float(np.mean(times[ref][kind]) - np.mean(t))})
        rows.append(row)
    return {
        "repeats": int(repeats),
        "training_points": RUNTIME_TRAIN,
        "prediction_poses": RUNTIME_QUERY,
        "rho_rot": RUNTIME_RHO,
        "blas_threads": 1,
        "blas": blas,
        "reference": ref,
        "rows": rows,
        "welch": welch,
        "times": times,
        "skipped": skipped,
        "seconds": time.perf_counter() - t0,
    }


# ================================================================================================ accuracy
_CONSTANTS = (1.0, -1.0, 1.5, -1.5, 1.0 / 3.0, -1.0 / 3.0)
_CONSTANT_TEXT = {1.0: "1", -1.0: "-1", 1.5: "3/2", -1.5: "-3/2", 1.0 / 3.0: "1/3", -1.0 / 3.0: "-1/3"}
_FUNCTIONS = ("sin", "cos", "atan", "acot")


def acot_matlab(x) -> np.ndarray:
    """MATLAB's acot: atan(1/x) ∈ (−π/2, π/2], with acot(±0) = ±π/2 (discontinuous at 0)."""
    x = np.asarray(x, dtype=np.float64)
    with np.errstate(divide="ignore"):
        return np.arctan(1.0 / x)


_G = {"sin": np.sin, "cos": np.cos, "atan": np.arctan, "acot": acot_matlab}


@dataclass(frozen=True)
class _Component:
    g: str
    d: int
    c: float
    plus: bool
    d2: int
    times: bool
    c2: float

    def __call__(self, r: np.ndarray) -> np.ndarray:
        second = r[..., self.d2] * self.c2 if self.times else r[..., self.d2] / self.c2
        arg = r[..., self.d] / self.c + (second if self.plus else -second)
        return _G[self.g](arg)

    def text(self) -> str:
        c, c2 = _CONSTANT_TEXT[self.c], _CONSTANT_TEXT[self.c2]
        return (f"{self.g}(r{self.d + 1}/({c}) {'+' if self.plus else '-'} "
                f"r{self.d2 + 1}{'*' if self.times else '/'}({c2}))")


class RandomDynamics:
    """A random rotation dynamics of paper eq. 30: f(θu) = θ0u0 with components
    f_i(θu) = g(d / c ⊙ d̃ ⋆ c̃) (reading and conventions: module docstring).

    Call with rotation vectors r (..., 3) (θu = r, components r1, r2, r3); returns f (..., 3), a rotation
    vector with every component in (−π/2, π/2] (so ‖f‖ < π).
    """

    def __init__(self, components):
        self.components = tuple(components)

    @classmethod
    def draw(cls, rng: np.random.Generator) -> "RandomDynamics":
        comps = []
        for _ in range(3):
            comps.append(_Component(
                g=_FUNCTIONS[rng.integers(4)], d=int(rng.integers(3)), c=_CONSTANTS[rng.integers(6)],
                plus=bool(rng.integers(2)), d2=int(rng.integers(3)), times=bool(rng.integers(2)),
                c2=_CONSTANTS[rng.integers(6)]))
        return cls(comps)

    def __call__(self, r) -> np.ndarray:
        r = np.asarray(r, dtype=np.float64)
        return np.stack([c(r) for c in self.components], axis=-1)

    def text(self) -> str:
        return "; ".join(f"f{i + 1} = {c.text()}" for i, c in enumerate(self.components))


class PaperStartKernel(SquaredExponential):
    """rbgp's squared-exponential kernel, started as the paper starts it (sec. 4.2): λ, σf drawn
    i.i.d. from U(0, 3) instead of the data-driven start (bounds unchanged, so a draw outside them is
    clipped by the optimiser). λ is drawn in the units of the rotation distance and passed as λ·√ρ1
    (inputs here are rotations with zero translation, d² = ρ1·d_rot²).

    The draw is seeded by ``start_seed`` and the output column itself (so it does not depend on the
    order in which :func:`~rbgp_cli.gp.exact.fit_gp` visits the outputs); σn's start is rbgp's.
    """

    def __init__(self, base: SquaredExponential, start_seed: int):
        super().__init__(base.metric, base.rotation_dims, base.rho_rot, base.learn_rho)
        self.start_seed = int(start_seed)

    def default_hyperparameters(self, pre: dict, y: np.ndarray) -> dict:
        spec = dict(super().default_hyperparameters(pre, y))
        tag = zlib.crc32(np.ascontiguousarray(y, dtype=np.float64).tobytes())
        lam, sf = np.random.default_rng([self.start_seed, tag]).uniform(*PAPER_START_INTERVAL, 2)
        spec["length_scale"] = spec["length_scale"].with_value(float(lam) * math.sqrt(self.rho_rot))
        spec["signal_std"] = spec["signal_std"].with_value(float(sf))
        return spec


def rotation_outputs(rep, f: np.ndarray) -> np.ndarray:
    """The ground truth rotations f (rotation vectors (n, 3), ‖f‖ < π) in the coordinates of a
    representation ``rep`` (axis-angle: f; quaternion: (x, y, z, w) with w > 0; euler: its angles):
    paper sec. 4.2 converts inputs and outputs alike. Shape (n, 3) or (n, 4)."""
    if rep.name == "axis-angle":
        return np.asarray(f, dtype=np.float64)
    q = quat_from_rotvec(f)  # w >= 0 (w > 0 as ‖f‖ < π)
    if rep.name == "quaternion":
        return q
    return euler_from_quat(q, rep.order)


def predicted_rotation(rep, pred: np.ndarray):
    """Predictions in ``rep``'s coordinates as (rotation vectors (n, 3) as the paper compares them,
    unit quaternions (n, 4)): axis-angle predictions as they are; quaternions normalised (a zero
    prediction counts as the identity) and Euler angles converted, both to canonical rotation vectors."""
    if rep.name == "axis-angle":
        return pred, quat_from_rotvec(pred)
    if rep.name == "quaternion":
        q = quat_normalize(pred)
        q = np.where(np.isfinite(q), q, np.array([0.0, 0.0, 0.0, 1.0]))
    else:
        q = quat_from_euler(pred, rep.order)
    return rotvec_from_quat(q), q


def _accuracy_one(j: int, seed: int):
    """One repetition: a dynamics, its data, and every model × σn setting fitted and scored."""
    rng = _rng(seed, "accuracy", j)
    dyn = RandomDynamics.draw(rng)
    q = random_quat(rng, ACCURACY_POINTS)
    r = rotvec_from_quat(q)
    f = dyn(r)
    q_true = quat_from_rotvec(f)
    train = np.sort(rng.choice(ACCURACY_POINTS, ACCURACY_TRAIN, replace=False))
    start_seed = int(rng.integers(2**31))
    zero_rmse = float(np.sqrt(np.mean(f * f)))
    zero = np.zeros((ACCURACY_POINTS, 3))
    out = {"dynamics": dyn.text(), "zero_rmse": zero_rmse,
           "zero_geodesic_rmse": float(np.sqrt(np.mean(arc_distance_quat(q_true, np.array([0.0, 0.0, 0.0, 1.0])) ** 2))),
           "results": {}}
    for rep_name, kernel_name in ACCURACY_MODELS:
        rep = make_representation(rep_name)
        X = rep.state_from_pose(q, zero)
        Y = rotation_outputs(rep, f)
        base = make_kernel(rep, kernel_name, rho_rot=_RHO_ROTATION_ONLY)
        for label, noise, paper_start in SETTINGS:
            t0 = time.perf_counter()
            res = {"seconds": None, "rmse": None, "geodesic_rmse": None, "failed": None,
                   "infeasible": 0, "guarded": 0}
            try:
                gp = fit_gp(X[train], Y[train], PaperStartKernel(base, start_seed) if paper_start else base,
                            noise="learn" if noise is None else noise,
                            restarts=1 if paper_start else RBGP_RESTARTS, seed=start_seed,
                            shared=False, explore_size=0)
            except RbgpRuntimeError as exc:
                res["failed"] = exc.message
            else:
                pred = gp.predict(X)
                r_hat, q_hat = predicted_rotation(rep, pred)
                res["rmse"] = float(np.sqrt(np.mean((r_hat - f) ** 2)))
                res["geodesic_rmse"] = float(np.sqrt(np.mean(arc_distance_quat(q_hat, q_true) ** 2)))
                res["infeasible"] = int(sum(fit.n_infeasible for fit in gp.fits))
                res["guarded"] = int(sum(fit.guarded for fit in gp.fits))
                res["length_scale"] = [fit.values["length_scale"] / math.sqrt(_RHO_ROTATION_ONLY) for fit in gp.fits]
                res["noise_std"] = [fit.values["noise_std"] for fit in gp.fits]
            res["seconds"] = time.perf_counter() - t0
            out["results"][f"{_key(rep_name, kernel_name)}|{label}"] = res
    return out


def _summary(x) -> dict:
    from scipy import stats

    x = np.asarray(x, dtype=np.float64)
    x = x[np.isfinite(x)]
    if len(x) == 0:
        return {"mean": None, "median": None, "trimmed_mean": None, "std": None, "q25": None, "q75": None}
    return {"mean": float(np.mean(x)), "median": float(np.median(x)),
            "trimmed_mean": float(stats.trim_mean(x, TRIM)),
            "std": float(np.std(x, ddof=1)) if len(x) > 1 else None,
            "q25": float(np.percentile(x, 25)), "q75": float(np.percentile(x, 75))}


def _paired(a, b) -> dict:
    """Paired comparison of per-dynamics errors a and b (lower is better)."""
    from scipy import stats

    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    ok = np.isfinite(a) & np.isfinite(b)
    a, b = a[ok], b[ok]
    out = {"pairs": int(len(a)), "median_ratio": None, "ratio_q25": None, "ratio_q75": None,
           "ratio_of_means": None, "ratio_of_medians": None, "a_better": int(np.sum(a < b)),
           "wilcoxon_statistic": None, "wilcoxon_p": None}
    if len(a) == 0:
        return {**out, "welch": {"t": None, "df": None, "p": None}}
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = a / b
    q = _quartiles(ratio)
    out.update({"median_ratio": q["median"], "ratio_q25": q["q25"], "ratio_q75": q["q75"],
                "ratio_of_means": _num(np.mean(a) / np.mean(b)) if np.mean(b) > 0 else None,
                "ratio_of_medians": _num(np.median(a) / np.median(b)) if np.median(b) > 0 else None})
    if len(a) >= 2 and np.any(a != b):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                w = stats.wilcoxon(a, b)
                out["wilcoxon_statistic"], out["wilcoxon_p"] = _num(w.statistic), _num(w.pvalue)
            except ValueError:
                pass
    out["welch"] = _welch(a, b)
    return out


def run_accuracy(repeats: int, seed: int = 0, progress=None) -> dict:
    """RMSE of the models on ``repeats`` random dynamics of eq. 30 (module docstring, **accuracy**).

    Returns ``{"rows": [per model and σn setting: "rmse" and "geodesic_rmse" summaries, "blow_ups",
    "failed", "median_vs_zero", ...], "comparisons": [...], "dynamics": [formula per repetition],
    "per_dynamics": {config: {"rmse": [...], "geodesic_rmse": [...]}}, "settings": {...}}``.
    """
    t0 = time.perf_counter()
    runs = []
    for j in range(repeats):
        runs.append(_accuracy_one(j, seed))
        if progress and (j + 1 == repeats or (j + 1) % max(1, repeats // 10) == 0):
            progress(f"accuracy: {j + 1}/{repeats} dynamics")
    zero = np.array([run["zero_rmse"] for run in runs])
    per = {}
    rows = []
    for label, _noise, _paper in SETTINGS:
        for rep_name, kernel_name in ACCURACY_MODELS:
            cfg = f"{_key(rep_name, kernel_name)}|{label}"
            res = [run["results"][cfg] for run in runs]
            rmse = np.array([np.nan if x["rmse"] is None else x["rmse"] for x in res])
            geo = np.array([np.nan if x["geodesic_rmse"] is None else x["geodesic_rmse"] for x in res])
            per[cfg] = {"rmse": rmse.tolist(), "geodesic_rmse": geo.tolist()}
            with np.errstate(invalid="ignore"):
                vs_zero = rmse / zero
            rows.append({
                "model": _label(rep_name, kernel_name), "key": _key(rep_name, kernel_name),
                "representation": rep_name, "kernel": kernel_name, "setting": label,
                "rmse": _summary(rmse), "geodesic_rmse": _summary(geo),
                "blow_ups": int(np.sum(vs_zero > BLOW_UP_FACTOR)),
                "failed": int(sum(x["failed"] is not None for x in res)),
                "median_vs_zero": _quartiles(vs_zero)["median"],
                "infeasible_evaluations": int(sum(x["infeasible"] for x in res)),
                "refit_with_noise_margin": int(sum(x["guarded"] for x in res)),
                "median_length_scale": _num(np.median([v for x in res for v in x.get("length_scale", [])]))
                if any(x.get("length_scale") for x in res) else None,
                "fit_seconds": float(sum(x["seconds"] for x in res)),
            })
    comparisons = []
    for label, _noise, _paper in SETTINGS:
        for a, b in ACCURACY_COMPARISONS:
            for err in ("rmse", "geodesic_rmse"):
                ca, cb = f"{_key(*a)}|{label}", f"{_key(*b)}|{label}"
                comparisons.append({"a": _key(*a), "b": _key(*b), "a_model": _label(*a), "b_model": _label(*b),
                                    "setting": label, "error": err, **_paired(per[ca][err], per[cb][err])})
    return {
        "repeats": int(repeats),
        "settings": {
            "points": ACCURACY_POINTS, "training_points": ACCURACY_TRAIN, "test_points": ACCURACY_POINTS,
            "paper_start": "one per output: λ, σf ~ U(0, 3) i.i.d. (λ in the rotation distance's units)",
            "rbgp_starts": f"the data-driven start and {RBGP_RESTARTS - 1} random ones per output",
            "settings": [label for label, _, _ in SETTINGS], "euler_order": "xyz (extrinsic), principal values",
            "acot": "MATLAB: atan(1/x)", "blow_up_factor": BLOW_UP_FACTOR, "trim": TRIM,
        },
        "rows": rows,
        "comparisons": comparisons,
        "dynamics": [run["dynamics"] for run in runs],
        "zero_rmse": _summary(zero),
        "per_dynamics": per,
        "seconds": time.perf_counter() - t0,
    }


# ================================================================================================ all
def _num(x):
    """A float, or None for NaN/inf/None (JSON has no NaN)."""
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def _clean(obj):
    if isinstance(obj, dict):
        return {k: _clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_clean(v) for v in obj]
    if isinstance(obj, (float, np.floating)):
        return _num(obj)
    if isinstance(obj, np.integer):
        return int(obj)
    return obj


def _machine() -> dict:
    import numpy
    import scipy

    try:
        load = [round(x, 2) for x in os.getloadavg()]
    except OSError:
        load = None
    return {"rbgp": __version__, "python": platform.python_version(), "numpy": numpy.__version__,
            "scipy": scipy.__version__, "machine": platform.machine(), "cpus": os.cpu_count(), "load_average": load}


def run_paper_bench(parts=PARTS, *, repeats: int | None = None, seed: int = 0, quick: bool = False,
                    progress=None) -> dict:
    """Run the given parts (see :data:`PARTS`); ``repeats`` is the number of repetitions of each part
    (random rotation sets per size, timing repetitions, random dynamics): default
    :data:`DEFAULT_REPEATS`, or :data:`QUICK_REPEATS` with ``quick`` (which also leaves out the
    200-rotation sets of the theorem search). Returns one plain-data dict with a key per part run,
    plus ``"settings"`` and ``"machine"`` (load average at the start and the end).
    """
    parts = [p for p in PARTS if p in set(parts)]
    n = int(repeats) if repeats is not None else (QUICK_REPEATS if quick else DEFAULT_REPEATS)
    if n < 1:
        raise ValueError("repeats must be at least 1")
    started = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    machine = _machine()
    t0 = time.perf_counter()
    out: dict = {"settings": {"parts": parts, "repeats": n, "seed": int(seed), "quick": bool(quick), "started": started}}
    out["settings"]["command"] = _command(out["settings"])
    if "theorem" in parts:
        out["theorem"] = run_theorem(n, seed, quick=quick, progress=progress)
    if "runtime" in parts:
        out["runtime"] = run_runtime(n, seed, progress=progress)
    if "accuracy" in parts:
        out["accuracy"] = run_accuracy(n, seed, progress=progress)
    machine["load_average_end"] = _machine()["load_average"]
    out["machine"] = machine
    out["seconds"] = time.perf_counter() - t0
    return _clean(out)


# ================================================================================================ report
def _f(x, digits: int = 3) -> str:
    if x is None:
        return "–"
    x = float(x)
    if x == 0:
        return "0"
    if abs(x) >= 1000 or abs(x) < 1e-3:
        return f"{x:.{max(1, digits - 1)}e}"
    return f"{x:.{digits}g}"


def _p(x) -> str:
    if x is None:
        return "–"
    return f"{x:.2g}" if x >= 1e-4 else f"{x:.1e}"


def _table(header, rows, text_columns: int = 1) -> list[str]:
    """A Markdown table; the first ``text_columns`` columns left-aligned, the others right-aligned."""
    lines = ["| " + " | ".join(header) + " |",
             "|" + "|".join("---" if i < text_columns else "---:" for i in range(len(header))) + "|"]
    lines += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return lines


def _command(settings: dict) -> str:
    parts = settings["parts"]
    cmd = "rbgp bench paper"
    if len(parts) == 1:
        cmd += f" {parts[0]}"
    if settings.get("quick"):
        cmd += " --quick"
    return cmd + f" --repeats {settings['repeats']} --seed {settings['seed']}"


def _claims(res: dict) -> list[str]:
    """One row per claim of the paper: what the paper states, what this run measured."""
    rows = []
    th = res.get("theorem")
    if th:
        lam2 = next((c for c in th["counterexample"] if c["lambda"] == 2.0), th["counterexample"][-1])
        bad = sum(r["chordal_negative_sets"] for r in th["search"])
        chordal = (f"chordal kernel: smallest {_f(th['chordal_min_eigenvalue'])}, "
                   + ("never below the round-off bound −n²ε" if bad == 0 else f"{bad} sets below −n²ε"))
        rows.append(["Theorem 1: the geodesic SE kernel is positive definite",
                     "proved for every λ",
                     f"false: smallest Gram eigenvalue {_f(lam2['geodesic'])} at λ = 2 on 8 rotations π/4 apart, "
                     f"{_f(th['geodesic_min_eigenvalue'])} over all sets searched; {chordal}"])
    rt = res.get("runtime")
    if rt:
        by = {r["key"]: r for r in rt["rows"]}
        quat = by["quaternion/se"]["mean_std"]["ratio_to_axis_angle"]["median"]
        eul = by["euler/se"]["mean_std"]["ratio_to_axis_angle"]["median"]
        w = next(x for x in rt["welch"] if x["b"] == "quaternion/se" and x["kind"] == "mean_std")
        rows.append(["Sec. 4.1: predicting with axis-angle is faster than with (dual) quaternions",
                     "yes, t(1998) = 37.8",
                     f"time / axis-angle's (median same-run ratio, mean + std): quaternion {_f(quat)} "
                     f"(Welch t = {_f(w['t'])}, p = {_p(w['p'])}), Euler {_f(eul)}"])
    ac = res.get("accuracy")
    if ac:
        parts = []
        for label, _noise, _paper in SETTINGS:
            c = next(x for x in ac["comparisons"] if x["a"] == "axis-angle/se" and x["b"] == "euler/se"
                     and x["setting"] == label and x["error"] == "rmse")
            parts.append(f"{label}: {_f(c['median_ratio'])} (ratio of means {_f(c['ratio_of_means'])}, "
                         f"Wilcoxon p = {_p(c['wilcoxon_p'])})")
        rows.append(["Sec. 4.2: the rigid-body GP's RMSE is about half the Euler GP's",
                     "mean RMSE ≈ 0.5×, t(5998) = 16",
                     "RMSE rigid-body / Euler, median of the paired ratios: " + "; ".join(parts)])
    return _table(["claim", "paper", "rbgp measures"], rows, text_columns=3) if rows else []


def _theorem_section(th: dict) -> list[str]:
    """Theorem 1's part of the report: the counterexample and the random sets' smallest eigenvalues."""
    lines = []
    lines += ["**Theorem 1.** Smallest eigenvalue of K_ij = exp(−d(r_i, r_j)²/(2λ²)) (σf = 1, no noise), "
              "geodesic d = d_arc against chordal d = 2 sin(d_arc/2); λ in radians.", "",
              "8 rotations about one axis, π/4 apart:", ""]
    lines += _table(["λ", "geodesic", "chordal"],
                    [[_f(c["lambda"]), _f(c["geodesic"]), _f(c["chordal"])] for c in th["counterexample"]])
    lines += ["", f"{th['sets']} sets of uniformly random rotations per size (min and median over the sets; "
              "'negative' counts sets below −n²ε, the round-off bound):", ""]
    lines += _table(["n", "λ", "geodesic min", "geodesic median", "negative sets", "chordal min", "chordal negative sets"],
                    [[r["n"], _f(r["lambda"]), _f(r["geodesic_min"]), _f(r["geodesic_median"]),
                      f"{r['geodesic_negative_sets']}/{r['sets']}", _f(r["chordal_min"]),
                      f"{r['chordal_negative_sets']}/{r['sets']}"] for r in th["search"]])
    lines.append("")
    return lines


def _runtime_section(rt: dict) -> list[str]:
    """Sec. 4.1's part of the report: prediction times, their ratios to axis-angle's and Welch's tests."""
    lines = []
    pools = ", ".join(f"{b['library']} ({b['threads']} thread{'s' if b['threads'] != 1 else ''})" for b in rt["blas"]) or "n/a"
    lines += [f"**Sec. 4.1, prediction time.** {rt['repeats']} repetitions: GPs on {rt['training_points']} random "
              f"poses (ρ1 = {rt['rho_rot']}, one output), prediction at {rt['prediction_poses']} new poses, "
              f"models in a random order each repetition. BLAS single-threaded for every model ({pools}); "
              "rbgp's prediction splits the rows into chunks on its own thread pool, as for users. "
              "Times in ms: median [quartiles]; ratio = time / axis-angle's time in the same repetition."
              + (f" {len(rt['skipped'])} repetitions skipped (a fit failed)." if rt.get("skipped") else ""), ""]
    rows = []
    for r in rt["rows"]:
        cells = [r["model"]]
        for kind in ("mean_only", "mean_std"):
            t = r[kind]
            rr = t["ratio_to_axis_angle"]
            cells += [f"{_f(1e3 * t['median'])} [{_f(1e3 * t['q25'])}–{_f(1e3 * t['q75'])}]",
                      f"{_f(rr['median'])} [{_f(rr['q25'])}–{_f(rr['q75'])}]"]
        rows.append(cells)
    lines += _table(["model", "mean (ms)", "ratio", "mean + std (ms)", "ratio"], rows)
    lines += ["", "Welch's t-test, axis-angle against each model (positive t: axis-angle slower):", ""]
    labels = {r["key"]: r["model"] for r in rt["rows"]}
    lines += _table(["model", "prediction", "t", "df", "p", "mean difference (ms)"], text_columns=2, rows=
                    [[labels[w["b"]], "mean" if w["kind"] == "mean_only" else "mean + std", _f(w["t"]), _f(w["df"]),
                      _p(w["p"]), _f(1e3 * w["mean_difference_s"])] for w in rt["welch"]])
    lines.append("")
    return lines


def _accuracy_section(ac: dict) -> list[str]:
    """Sec. 4.2's part of the report: the errors per setting and model, and the paired comparisons."""
    lines = []
    st = ac["settings"]
    lines += [f"**Sec. 4.2, accuracy.** {ac['repeats']} random dynamics of eq. 30 (f_i = g(d/c ± d̃ ×/÷ c̃), "
              "g ∈ {sin, cos, atan, acot}; acot is MATLAB's atan(1/x), which jumps by π at 0), "
              f"{st['training_points']} training rotations drawn from {st['test_points']} test rotations, as in "
              "the paper. Fitted per output, with the paper's single start λ, σf ~ U(0, 3) and σn = 1 or learned, "
              f"or with rbgp's starts ({st['rbgp_starts']}). Errors per dynamics: RMSE of the rotation-vector "
              "components (the paper's measure; rad) and root mean square geodesic angle (rad); mean, median "
              f"and {int(100 * st['trim'])} % trimmed mean over the dynamics. Euler angles: {st['euler_order']}. "
              f"Blow-up: RMSE above {st['blow_up_factor']:g}× the zero predictor's (median zero-predictor RMSE "
              f"{_f(ac['zero_rmse']['median'])}).", ""]
    rows = []
    for r in ac["rows"]:
        e, g = r["rmse"], r["geodesic_rmse"]
        rows.append([r["setting"], r["model"], f"{_f(e['mean'])} ± {_f(e['std'], 2)}", _f(e["median"]),
                     _f(e["trimmed_mean"]), f"{_f(g['mean'])} ± {_f(g['std'], 2)}", _f(g["median"]),
                     _f(g["trimmed_mean"]), r["blow_ups"], r["failed"],
                     _f(r["median_vs_zero"]), r["refit_with_noise_margin"]])
    lines += _table(["setting", "model", "RMSE mean ± std", "median", "trimmed", "geodesic mean ± std", "median", "trimmed",
                     "blow-ups", "failed", "median / zero predictor", "noise-margin refits"], rows, text_columns=2)
    lines += ["", "Paired comparisons (ratio a / b per dynamics; below 1: a is more accurate):", ""]
    rows = []
    for c in ac["comparisons"]:
        rows.append([c["setting"], f"{c['a_model']} / {c['b_model']}", "rotation vector" if c["error"] == "rmse" else "geodesic",
                     f"{_f(c['median_ratio'])} [{_f(c['ratio_q25'])}–{_f(c['ratio_q75'])}]", _f(c["ratio_of_means"]),
                     f"{c['a_better']}/{c['pairs']}", _p(c["wilcoxon_p"]),
                     f"{_f(c['welch']['t'])} ({_f(c['welch']['df'])})", _p(c["welch"]["p"])])
    lines += _table(["setting", "a / b", "error", "median ratio [quartiles]", "ratio of means", "a better",
                     "Wilcoxon p", "Welch t (df)", "Welch p"], rows, text_columns=3)
    lines.append("")
    return lines


def format_report(res: dict) -> str:
    """The result of :func:`run_paper_bench` as Markdown: the claims, then one section per part."""
    s = res["settings"]
    m = res["machine"]
    load = ", ".join(str(x) for x in (m.get("load_average") or [])) or "n/a"
    load_end = ", ".join(str(x) for x in (m.get("load_average_end") or [])) or "n/a"
    lines = [f"Command: `{s['command']}` (started {s['started']}, {res['seconds']:.0f} s). rbgp {m['rbgp']}, "
             f"Python {m['python']}, numpy {m['numpy']}, scipy {m['scipy']}, {m['machine']}, {m['cpus']} cores; "
             f"load average (1, 5, 15 min) {load} at the start, {load_end} at the end.", ""]
    claims = _claims(res)
    if claims:
        lines += claims + [""]
    th = res.get("theorem")
    if th:
        lines += _theorem_section(th)
    rt = res.get("runtime")
    if rt:
        lines += _runtime_section(rt)
    ac = res.get("accuracy")
    if ac:
        lines += _accuracy_section(ac)
    return "\n".join(lines).rstrip() + "\n"
