"""The hyperparameter optimiser shared by the exact GP (:mod:`rbgp_cli.gp.exact`) and the sparse GP
(:mod:`rbgp_cli.gp.sparse`): starts, L-BFGS-B per start, the polish on all points, basins (docs/method.md §7).

Starts: L-BFGS-B in log space from the data-driven start plus ``restarts − 1`` random ones from a
seeded rng (:func:`free_spec`, :func:`random_start`, :func:`fit_one`). Where C = K + σn²I is not
positive definite (an indefinite kernel, docs/method.md §6) the objective is infeasible
(:func:`rbgp_cli.gp.likelihood.nlml_and_gradient`); an infeasible start is moved towards shorter
length-scales and more noise, and an infeasible trial point is reported a little above the run's
start so that the line search backs off and the optimiser keeps going.

The starts exist to find the best basin, and at n = 1752 all of them usually end in the same one, each
costing 15–50 full-size evaluations. So for n > 2·SUBSAMPLE_SIZE the starts run on a random subsample
of SUBSAMPLE_SIZE points (an evaluation there costs (400/1752)³ ≈ 1 % of a full one). On all points the
fit then polishes the best subsample optimum (and any other that is nearly as good and distinct:
DISTINCT_LOG, DISTINCT_NLML, BASIN_GAP) by projected quasi-Newton steps whose first Hessian is the
subsample's (:func:`fd_hessian`), scaled to n points (:func:`polish`): 4–10 evaluations on all points
per output instead of 15–50. A best optimum in the all-noise basin gets one more start at long length
scales (:func:`smooth_start`, :func:`all_noise`); an optimum that misses the noise margin is refit with
the margin enforced. :func:`fit_target` does all of this for one target and returns its
:class:`~rbgp_cli.gp.results.OutputFit` with the accepted Cholesky factor and α.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
from scipy.linalg import lapack

from rbgp_cli.errors import RbgpRuntimeError
from rbgp_cli.gp.likelihood import INFEASIBLE_NLML, NOISE, NOISE_MARGIN, accept, meets_margin, nlml_and_gradient
from rbgp_cli.gp.results import OutputFit
from rbgp_cli.kernels.base import Hyperparameter, Kernel, output_scale

__all__ = ["SUBSAMPLE_SIZE", "DISTINCT_LOG", "BASIN_GAP", "DISTINCT_NLML", "EXPLORE_FTOL", "POLISH_RTOL",
           "POLISH_MAX_EVALS", "free_spec", "random_start", "Objective", "fit_one", "fd_hessian", "polish",
           "smooth_start", "all_noise", "FitOptions", "fit_target", "training_data", "fit_targets"]

#: An infeasible start is moved by this much in log λ (down) and log σn (up), at most _START_MOVES times.
_START_STEP = math.log(1.25)
_START_MOVES = 16
#: Above 2·SUBSAMPLE_SIZE points the starts explore a random subsample of this size first; on all
#: points the best optimum is polished, and the optima of other starts that are distinct there (max
#: |Δ log θ| > DISTINCT_LOG) and whose subsample NLML is within BASIN_GAP of the best.
SUBSAMPLE_SIZE = 400
DISTINCT_LOG = 0.1
#: A subsample optimum whose NLML is worse than the best one's by more than this is not polished on
#: all points. The subsample is a uniform random subset, so its NLML difference estimates the full
#: one scaled by m/n: a gap of 10 there (a likelihood ratio of e⁻¹⁰) is a gap of ~10·n/m on all
#: points. On recorded demonstrations such optima were degenerate (σn at its lower bound, or λ
#: 5–10× off) and their polishes ended in the best optimum anyway, after 15–55 evaluations each.
BASIN_GAP = 10.0
#: ... and whose subsample NLML differs from every optimum already chosen by more than this: optima
#: that fit the subsample equally well at different θ lie on one flat ridge (on recorded motions: the
#: pure-noise fit, λ at its lower bound and σf → 0, where λ no longer matters), and their polishes
#: met in the same optimum after 17–36 evaluations each.
DISTINCT_NLML = 0.1
#: L-BFGS-B's relative-reduction tolerance on the subsample (its default is 2.2e-9).
EXPLORE_FTOL = 1e-7


# ----------------------------------------------------------------------------- what is fitted
def training_data(X, Y) -> tuple[np.ndarray, np.ndarray]:
    """The training inputs X as a C-contiguous float64 array (n, d) and outputs Y as float64 (n, L),
    checked as the exact and the sparse GP need them: at least 2 rows, all finite (ValueError)."""
    X = np.ascontiguousarray(np.asarray(X, dtype=np.float64))
    Y = np.asarray(Y, dtype=np.float64).reshape(len(X), -1)
    if len(X) < 2:
        raise ValueError("a GP needs at least 2 training points")
    if not (np.all(np.isfinite(X)) and np.all(np.isfinite(Y))):
        raise ValueError("training inputs and outputs must be finite")
    return X, Y


def fit_targets(Y: np.ndarray, shared: bool, ss: np.random.SeedSequence):
    """What gets its own hyperparameters: one target per output column of Y (n, L), or with ``shared``
    one target, every output divided by its root mean square (:func:`output_scale`).

    Returns (targets, scale, seeds): ``targets`` [(y, label)], y of shape (n,) (``"output l"``) or
    (n, L) (``"all outputs"``); ``scale`` (L,) or None; ``seeds`` one SeedSequence per target
    (``ss`` itself when shared, else ``ss.spawn(L)``)."""
    L = Y.shape[1]
    if shared:
        scale = np.array([output_scale(Y[:, l]) for l in range(L)])
        return [(Y / scale, "all outputs")], scale, [ss]
    return [(Y[:, l], f"output {l}") for l in range(L)], None, ss.spawn(L)


# ----------------------------------------------------------------------------- starts and L-BFGS-B
def free_spec(kernel: Kernel, pre: dict, y: np.ndarray, noise, fixed: dict | None, bounds: dict | None):
    """All hyperparameters (kernel + noise) with data-driven starts and bounds, and the free names."""
    spec = dict(kernel.default_hyperparameters(pre, y))
    sy = output_scale(y)
    if noise is None or noise == "learn":
        spec[NOISE] = Hyperparameter(NOISE, 0.1 * sy, (1e-6 * sy, 10.0 * sy))
    else:
        spec[NOISE] = Hyperparameter(NOISE, float(noise), (float(noise), float(noise)), fixed=True)
    for name, v in (fixed or {}).items():
        if name not in spec:
            raise ValueError(f"unknown hyperparameter {name!r}; known: {sorted(spec)}")
        spec[name] = Hyperparameter(name, float(v), (float(v), float(v)), fixed=True)
    for name, b in (bounds or {}).items():
        if name in spec and not spec[name].fixed:
            lo, hi = float(b[0]), float(b[1])
            spec[name] = Hyperparameter(name, min(max(spec[name].value, lo), hi), (lo, hi))
    free = [nm for nm in [*kernel.names, NOISE] if nm in spec and not spec[nm].fixed]
    return spec, free


def random_start(spec: dict, free: list, rng: np.random.Generator) -> np.ndarray:
    """A random start in log space around the data-driven one: λ and λτ × e^U(−1.5,1), σf × e^U(−1,1),
    σn × e^U(−3,1), ρ1 ~ U(0.1, 0.9), each clipped into its bounds."""
    widths = {"length_scale": (-1.5, 1.0), "signal_std": (-1.0, 1.0), NOISE: (-3.0, 1.0), "time_scale": (-1.5, 1.0)}
    theta = np.empty(len(free))
    for i, nm in enumerate(free):
        h = spec[nm]
        lo, hi = h.log_bounds
        if nm == "rho_rot":
            t = math.log(rng.uniform(0.1, 0.9))
        else:
            a, b = widths.get(nm, (-1.0, 1.0))
            t = math.log(h.value) + rng.uniform(a, b)
        theta[i] = min(max(t, lo), hi)
    return theta


def _move_towards_feasible(theta, free, log_bounds, step: float, noise_step: float | None = None) -> np.ndarray:
    """One move of a point whose K + σn²I is not positive definite towards the region where it is:
    log λ down by ``step`` and log σn up by ``noise_step`` (default ``step``), within the bounds
    (σn also when λ is not free). Returns a new array."""
    theta = np.array(theta, dtype=np.float64)
    noise_step = step if noise_step is None else noise_step
    if "length_scale" not in free:
        noise_step = step
    for i, nm in enumerate(free):
        if nm == "length_scale":
            theta[i] = max(theta[i] - step, log_bounds[i][0])
        elif nm == NOISE:
            theta[i] = min(theta[i] + noise_step, log_bounds[i][1])
    return theta


class Objective:
    """NLML and its gradient in log θ for one target (vector, or matrix in shared mode) on one set of
    points, counting evaluations and infeasible ones (non-PD C, or the noise margin missed)."""

    def __init__(self, kernel, pre, y, spec, free, margin=0.0, on_evaluation=None):
        self.kernel, self.pre, self.y, self.free, self.margin = kernel, pre, y, list(free), margin
        self.on_evaluation = on_evaluation
        self.fixed_values = {nm: h.value for nm, h in spec.items() if nm not in free}
        self.log_bounds = [spec[nm].log_bounds for nm in free]
        self.counter = {"evals": 0, "infeasible": 0}

    def values_of(self, theta) -> dict:
        v = dict(self.fixed_values)
        v.update({nm: math.exp(t) for nm, t in zip(self.free, theta)})
        return v

    def __call__(self, theta):
        theta = np.array(theta, dtype=np.float64)
        last = getattr(self, "_last", None)
        if last is not None and np.array_equal(last[0], theta):
            # the same point again (L-BFGS-B's first call at a start we have just checked)
            return last[1], last[2].copy()
        self.counter["evals"] += 1
        f, g = self._evaluate(theta)
        if self.on_evaluation is not None:
            self.on_evaluation()
        if f >= INFEASIBLE_NLML:
            self.counter["infeasible"] += 1
        self._last = (theta, f, np.array(g))
        return f, g

    def _evaluate(self, theta):
        # looked up at call time as this module's global: benchmarks/bench_training.py times the
        # evaluations by wrapping rbgp_cli.gp.optimise.nlml_and_gradient
        return nlml_and_gradient(self.kernel, self.pre, self.values_of(theta), self.y, self.free, self.margin)


def fit_one(kernel, pre, y, spec, free, restarts, rng, max_iter, margin=0.0, theta_starts=None, kinds=None,
             ftol=None, on_evaluation=None):
    """Minimise the NLML for one target (vector, or matrix in shared mode) from several starts with L-BFGS-B.

    The starts are the data-driven one and ``restarts − 1`` random ones, or ``theta_starts`` (log
    values of the free hyperparameters) labelled ``kinds`` in the records. Returns (best (θ, NLML) or
    None, one record per start, evaluation counters, θ -> values, per start its optimum (θ, NLML) or
    None if it found no feasible point). ``on_evaluation()`` is called after every NLML evaluation."""
    from scipy.optimize import minimize

    obj = Objective(kernel, pre, y, spec, free, margin, on_evaluation)
    log_bounds = obj.log_bounds
    penalty = {"ref": None}
    seen = {"best": None}

    def objective(theta):
        f, g = obj(theta)
        if f < INFEASIBLE_NLML and (seen["best"] is None or f < seen["best"][1]):
            seen["best"] = (np.array(theta, dtype=np.float64), f)
        if f >= INFEASIBLE_NLML and penalty["ref"] is not None:
            # Infeasible: report a value well above this run's start (so the line search backs
            # off) but not so far above that its interpolation collapses to a zero step, which
            # L-BFGS-B would take for convergence.
            ref = penalty["ref"]
            return ref + max(10.0, abs(ref)), np.zeros_like(g)
        return f, g

    if theta_starts is not None:
        starts = [np.array(t, dtype=np.float64) for t in theta_starts]
        kinds = list(kinds) if kinds is not None else ["given"] * len(starts)
    else:
        starts = [np.array([math.log(spec[nm].value) for nm in free])]
        starts += [random_start(spec, free, rng) for _ in range(max(0, restarts - 1))]
        kinds = ["data-driven"] + ["random"] * (len(starts) - 1)
    best = None
    records = []
    optima = []
    for s, theta0 in enumerate(starts):
        theta0 = np.clip(theta0, [b[0] for b in log_bounds], [b[1] for b in log_bounds])
        # an infeasible start is moved in small steps towards shorter length-scales and more
        # noise, where K + σn²I is positive definite (the optimum of the arc kernel often lies just
        # inside that boundary, so large steps would land far from it)
        penalty["ref"] = None
        for _ in range(_START_MOVES):
            f0, _g = objective(theta0)
            if f0 < INFEASIBLE_NLML:
                break
            theta0 = _move_towards_feasible(theta0, free, log_bounds, _START_STEP)
        ev0 = obj.counter["evals"]
        penalty["ref"] = f0 if f0 < INFEASIBLE_NLML else None
        if not free:
            res_x, res_f, msg = theta0, f0, "no free hyperparameters"
        else:
            seen["best"] = None
            options = {"maxiter": max_iter} if ftol is None else {"maxiter": max_iter, "ftol": ftol}
            res = minimize(objective, theta0, jac=True, method="L-BFGS-B", bounds=log_bounds, options=options)
            msg = str(res.message)
            # the best feasible point this run evaluated: after an abnormal line-search end res.x may be
            # an infeasible trial point and res.fun the penalty (or another point's value)
            res_x, res_f = seen["best"] if seen["best"] is not None else (res.x, INFEASIBLE_NLML)
        records.append({
            "start": {nm: float(math.exp(t)) for nm, t in zip(free, theta0)},
            "nlml": float(res_f),
            "status": msg,
            "evaluations": obj.counter["evals"] - ev0,
            "kind": kinds[s],
        })
        if res_f < INFEASIBLE_NLML:
            optima.append((np.array(res_x), res_f))
            if best is None or res_f < best[1]:
                best = (np.array(res_x), res_f)
        else:
            optima.append(None)
    return best, records, obj.counter, obj.values_of, optima


# ----------------------------------------------------------------------------- polish on all points
#: The polish on all points stops when the NLML decrease that Newton's model still predicts is below
#: POLISH_RTOL · max(|NLML|, n). At n = 1752 that is ~2e-4: hyperparameters within ~0.1 % of the
#: optimum along any direction of curvature ≳ 100 (the likelihood is that flat only along ridges
#: where predictions do not change either).
POLISH_RTOL = 1e-7
#: A polish that has not converged after this many evaluations on all points hands over to L-BFGS-B.
POLISH_MAX_EVALS = 25
#: Log step of the finite-difference Hessian on the subsample.
_FD_STEP = 1e-4
#: An infeasible polish start (the subsample optimum of an indefinite kernel often lies just outside
#: the positive definite region of all points: at n = 1752 the optimum's λ was ~18 % shorter) moves λ
#: down by this factor per try; σn, which the subsample estimates well, stays.
_POLISH_MOVE = math.log(1.1)
_POLISH_MOVE_NOISE = 0.0
#: Largest polish step in any log hyperparameter (a factor e).
_MAX_STEP = 1.0


def fd_hessian(obj: Objective, theta) -> np.ndarray | None:
    """Hessian of the NLML in log θ by central differences of the analytic gradient (2p evaluations,
    symmetrised); None if a neighbour is infeasible or the result is not finite."""
    p = len(theta)
    H = np.empty((p, p))
    for i in range(p):
        e = np.zeros(p)
        e[i] = _FD_STEP
        fp, gp = obj(theta + e)
        fm, gm = obj(theta - e)
        if fp >= INFEASIBLE_NLML or fm >= INFEASIBLE_NLML:
            return None
        H[:, i] = (gp - gm) / (2.0 * _FD_STEP)
    H = 0.5 * (H + H.T)
    return H if np.all(np.isfinite(H)) else None


def polish(obj: Objective, theta0, H, n: int, known=(), max_evals: int = POLISH_MAX_EVALS,
            atol: float | None = None) -> dict:
    """Minimise ``obj`` from ``theta0`` (near the optimum) by a projected quasi-Newton method.

    Steps p = −H⁻¹g on the hyperparameters that are not held at a bound by their gradient (H made
    positive definite by taking |eigenvalues|), at most _MAX_STEP in any log θ, with backtracking
    until the NLML decreases (Armijo); H starts from ``H`` (the subsample's Hessian scaled to n
    points: the NLML is a sum over the points) and is updated by damped BFGS. Stops when the
    predicted decrease −½gᵀp < POLISH_RTOL · max(|NLML|, n) (or < ``atol`` nats if given) ("converged"), when the line search
    cannot decrease the NLML ("stalled"), after ``max_evals`` evaluations ("budget"), or when it
    comes within DISTINCT_LOG of an optimum in ``known`` (θ, NLML) without being better than it
    ("joined an earlier basin").

    Returns {"theta", "nlml" (INFEASIBLE_NLML if no feasible point was found), "status", "start"}.
    """
    lo = np.array([b[0] for b in obj.log_bounds])
    hi = np.array([b[1] for b in obj.log_bounds])
    theta = np.clip(np.array(theta0, dtype=np.float64), lo, hi)
    ev0 = obj.counter["evals"]
    f, g = obj(theta)
    for _ in range(_START_MOVES):
        if f < INFEASIBLE_NLML:
            break
        theta = _move_towards_feasible(theta, obj.free, obj.log_bounds, _POLISH_MOVE, _POLISH_MOVE_NOISE)
        f, g = obj(theta)
    start = theta.copy()
    if f >= INFEASIBLE_NLML:
        return {"theta": theta, "nlml": f, "status": "no feasible start", "start": start}
    # a positive definite start (|eigenvalues|), which damped BFGS keeps positive definite
    w, V = np.linalg.eigh(0.5 * (H + H.T))
    w = np.maximum(np.abs(w), 1e-10 * max(float(np.max(np.abs(w))), 1e-300))
    H = (V * w) @ V.T
    status = "budget"
    while obj.counter["evals"] - ev0 < max_evals:
        held = ((theta <= lo + 1e-12) & (g > 0)) | ((theta >= hi - 1e-12) & (g < 0))
        F = ~held
        p = np.zeros_like(theta)
        if np.any(F):
            w, V = np.linalg.eigh(H[np.ix_(F, F)])
            w = np.abs(w)
            w = np.maximum(w, 1e-10 * max(float(np.max(w)), 1e-300))
            p[F] = -(V @ ((V.T @ g[F]) / w))
        decrease = -0.5 * float(g @ p)
        if decrease <= (POLISH_RTOL * max(abs(f), n) if atol is None else atol):
            status = "converged"
            break
        p *= min(1.0, _MAX_STEP / float(np.max(np.abs(p))))
        a = 1.0
        accepted = False
        while obj.counter["evals"] - ev0 < max_evals:
            t_new = np.clip(theta + a * p, lo, hi)
            d = t_new - theta
            if float(np.max(np.abs(d))) < 1e-10:
                break
            f_new, g_new = obj(t_new)
            gd = float(g @ d)
            if f_new < INFEASIBLE_NLML and f_new <= f + 1e-4 * gd:
                accepted = True
                break
            if f_new >= INFEASIBLE_NLML:
                a *= 0.5
            else:  # minimum of the quadratic through f, g·d and f_new, kept within [0.1a, 0.5a]
                a *= min(0.5, max(0.1, -gd / (2.0 * (f_new - f - gd))))
        if not accepted:
            status = "stalled" if obj.counter["evals"] - ev0 < max_evals else "budget"
            break
        s, yv = d, g_new - g
        Hs = H @ s
        sHs, sy = float(s @ Hs), float(s @ yv)
        if sHs > 0:
            if sy < 0.2 * sHs:  # Powell's damping keeps H positive definite
                r = 0.8 * sHs / (sHs - sy)
                yv = r * yv + (1.0 - r) * Hs
                sy = float(s @ yv)
            H = H - np.outer(Hs, Hs) / sHs + np.outer(yv, yv) / sy
        theta, f, g = t_new, f_new, g_new
        if any(np.max(np.abs(theta - tk)) <= DISTINCT_LOG and f >= fk - POLISH_RTOL * max(abs(fk), n)
               for tk, fk in known):
            status = "joined an earlier basin"
            break
    return {"theta": theta, "nlml": f, "status": status, "start": start}


def smooth_start(spec: dict, free: list) -> np.ndarray | None:
    """A start at long length scales (4 × the data-driven λ, 10 × λτ, σf = RMS(y), σn = RMS(y)/2) for
    fits whose best optimum is the all-noise basin (:func:`all_noise`); None if σf or σn is fixed.
    On 400-point subsets of recorded motions every start of some outputs ends in an optimum that on
    more points is the all-noise basin (σf ≪ σn, λ and λτ at their lower bounds), which neither
    L-BFGS-B nor the polish leaves, while a structured optimum at long length scales is far better:
    handover recordings, 964 points: 1742 against 1199; sample_data at the recorded rate, 2000 points
    of a crossval fold (the exact GP): vx 711, vy 763, vz 528 against 320, 332, 239 from this start."""
    if "signal_std" not in free or NOISE not in free:
        return None
    sy = spec["signal_std"].value
    start = {"signal_std": sy, NOISE: 0.5 * sy}
    if "length_scale" in spec:
        start["length_scale"] = 4.0 * spec["length_scale"].value
    if "time_scale" in spec:
        start["time_scale"] = 10.0 * spec["time_scale"].value
    theta = np.array([math.log(start.get(nm, spec[nm].value)) for nm in free])
    lo = np.array([spec[nm].log_bounds[0] for nm in free])
    hi = np.array([spec[nm].log_bounds[1] for nm in free])
    return np.clip(theta, lo, hi)


def all_noise(free, theta) -> bool:
    """σf < σn at log hyperparameters θ: the optimum explains less than the noise (False when either
    is fixed)."""
    v = dict(zip(free, theta))
    return "signal_std" in v and NOISE in v and v["signal_std"] < v[NOISE]


def _optima_best(optima) -> float:
    """The lowest NLML among a list of optima (θ, NLML) or None entries (inf if there is none)."""
    return min((o[1] for o in optima if o is not None), default=math.inf)


# ----------------------------------------------------------------------------- one target
@dataclass(frozen=True)
class FitOptions:
    """The options of one :func:`rbgp_cli.gp.exact.fit_gp` call that the fit of every target shares."""

    noise: object
    restarts: int
    fixed: dict | None
    bounds: dict | None
    max_iter: int
    #: return the Cholesky factor and α with each fit (False: only the checked fit; the posterior
    #: factorises at its first prediction, or never when the caller replaces it: rbgp train's
    #: calibrated posterior)
    factors: bool = True


def _explore_then_polish(kernel, pre, y, spec, free, obj, rng, o: FitOptions, sub, pre_sub, on_evaluation):
    """:func:`fit_target` on more than 2·SUBSAMPLE_SIZE points: every start on the rows ``sub`` of y (n,)
    or (n, L), then on all points the polish of each distinct subsample basin (``obj``: the objective on
    all points), L-BFGS-B where a polish stalls. Returns (best, records, counter, sub_info): best
    (θ, NLML) on all points or None, the starts' records, the evaluations on all points and those on
    the subsample."""
    n = len(y)
    best = None
    counter = {"evals": 0, "infeasible": 0}
    # Explore: every start on the subsample. On all points: a quasi-Newton polish of the best
    # subsample optimum, and of each other optimum that lies in a basin not reached before.
    _b, records_s, counter_s, _v, optima = fit_one(kernel, pre_sub, y[sub], spec, free, o.restarts, rng, o.max_iter,
                                                    ftol=EXPLORE_FTOL, on_evaluation=on_evaluation)
    records = [{**r, "kind": r["kind"] + f" (subsample of {len(sub)})"} for r in records_s]
    basins, basin_nlml = [], []
    for theta, f_s in sorted((x for x in optima if x is not None), key=lambda t: t[1]):
        if (f_s <= _optima_best(optima) + BASIN_GAP
                and all(np.max(np.abs(theta - b)) > DISTINCT_LOG for b in basins)
                and all(abs(f_s - fb) > DISTINCT_NLML for fb in basin_nlml)):
            basins.append(theta)
            basin_nlml.append(f_s)
    obj_s = Objective(kernel, pre_sub, y[sub], spec, free, on_evaluation=on_evaluation)
    polished = []
    for theta_s in basins:
        ev0 = obj.counter["evals"]
        H = fd_hessian(obj_s, theta_s)
        if H is not None:
            res = polish(obj, theta_s, H * (n / len(sub)), n, polished)
            th, fv, status, start = res["theta"], res["nlml"], res["status"], res["start"]
        else:
            th, fv, status, start = theta_s, INFEASIBLE_NLML, "no Hessian on the subsample", theta_s
        records.append({"start": {nm: float(math.exp(t)) for nm, t in zip(free, start)}, "nlml": float(fv),
                        "status": status, "evaluations": obj.counter["evals"] - ev0, "kind": "polish (all points)"})
        if status in ("budget", "stalled") or fv >= INFEASIBLE_NLML:
            # hand over to L-BFGS-B on all points (from the polish's best point, or, if it found
            # no feasible one, from the subsample optimum with the usual infeasible-start moves)
            b2, rec2, c2, _v, _o = fit_one(kernel, pre, y, spec, free, 1, rng, o.max_iter, theta_starts=[th],
                                            kinds=["L-BFGS-B after the polish (all points)"],
                                            on_evaluation=on_evaluation)
            records += rec2
            counter = {k: counter[k] + c2[k] for k in counter}
            if b2 is not None:
                th, fv = b2
        if fv < INFEASIBLE_NLML:
            polished.append((np.array(th), fv))
            if best is None or fv < best[1]:
                best = (np.array(th), fv)
    counter = {k: counter[k] + obj.counter[k] for k in counter}
    sub_info = {"size": len(sub), "evaluations": counter_s["evals"] + obj_s.counter["evals"],
                "infeasible": counter_s["infeasible"] + obj_s.counter["infeasible"]}
    return best, records, counter, sub_info


def _refit_with_margin(kernel, pre, y, spec, free, rng, o: FitOptions, best, values_of, on_evaluation):
    """An optimum ``best`` (θ, NLML) of :func:`fit_target` whose covariance misses the noise margin
    (:func:`rbgp_cli.gp.likelihood.meets_margin`) is fitted again with the margin enforced. Returns
    (best, K, guarded, records, counter): the optimum kept (None if no feasible one), its Gram matrix
    K (None when refitted), whether it was refitted, and the refit's records and evaluations."""
    records, counter = [], {"evals": 0, "infeasible": 0}
    guarded = False
    K = None
    if best is not None:
        K, _ = kernel.gram(pre, values_of(best[0]))
        if not meets_margin(kernel, pre, values_of(best[0]), K):
            # The optimum sits where K's negative eigenvalues nearly cancel the noise (indefinite
            # kernel, docs/method.md §6): refit with the margin enforced at every evaluation, from that
            # optimum (moved into the feasible region by the infeasible-start rule) and the
            # data-driven start.
            guarded = True
            data_start = [math.log(spec[nm].value) for nm in free]
            best2, records2, counter2, _v, _ = fit_one(
                kernel, pre, y, spec, free, 1, rng, o.max_iter, margin=NOISE_MARGIN,
                theta_starts=[best[0], data_start], kinds=["optimum (margin)", "data-driven (margin)"],
                on_evaluation=on_evaluation)
            records += records2
            counter = {k: counter[k] + counter2[k] for k in counter}
            best = best2
            K = None
    return best, K, guarded, records, counter


def fit_target(kernel, pre, y, label, rng, o: FitOptions, sub=None, pre_sub=None, on_evaluation=None):
    """Fit one target (an output, or all outputs scaled in shared mode): returns (OutputFit, L, α)
    with L the lower Cholesky factor of K + (σn² + jitter)I at the optimum and α = C⁻¹y; (OutputFit,
    None, None) with ``o.factors`` False (the optimum checked all the same)."""
    t0 = time.perf_counter()
    n = len(y)
    spec, free = free_spec(kernel, pre, y, o.noise, o.fixed, o.bounds)
    obj = Objective(kernel, pre, y, spec, free, on_evaluation=on_evaluation)
    values_of = obj.values_of
    best, records, sub_info = None, [], None
    counter = {"evals": 0, "infeasible": 0}
    if sub is not None and free:
        best, records, counter, sub_info = _explore_then_polish(kernel, pre, y, spec, free, obj, rng, o, sub, pre_sub,
                                                                on_evaluation)
    if best is None:
        best, rec_full, c_full, _v, _ = fit_one(kernel, pre, y, spec, free, o.restarts, rng, o.max_iter,
                                                 on_evaluation=on_evaluation)
        records += rec_full
        counter = {k: counter[k] + c_full[k] for k in counter}
    smooth = smooth_start(spec, free)
    if best is not None and smooth is not None and all_noise(free, best[0]):
        # the all-noise basin: one more start at long length scales, on all points, kept if better
        b2, rec2, c2, _v, _ = fit_one(kernel, pre, y, spec, free, 1, rng, o.max_iter, theta_starts=[smooth],
                                       kinds=["smooth start, the best optimum being all noise (all points)"],
                                       on_evaluation=on_evaluation)
        records += rec2
        counter = {k: counter[k] + c2[k] for k in counter}
        if b2 is not None and b2[1] < best[1]:
            best = b2
    best, K, guarded, records_m, counter_m = _refit_with_margin(kernel, pre, y, spec, free, rng, o, best, values_of,
                                                                on_evaluation)
    records += records_m
    counter = {k: counter[k] + counter_m[k] for k in counter}
    if best is None:
        raise RbgpRuntimeError(
            f"no hyperparameters gave a positive definite covariance for {label}",
            hint="use kernel se-chordal, fix a smaller length-scale, or learn the noise", param="kernel",
        )
    values = values_of(best[0])
    if K is None:
        K, _ = kernel.gram(pre, values)
    jitter, rc, pd, c = accept(kernel, pre, y, values, K)
    if jitter is None:
        raise RbgpRuntimeError(
            f"the fitted covariance for {label} is numerically singular even with jitter",
            hint="use kernel se-chordal or subsample fewer, less redundant points", param="kernel",
        )
    del K
    alpha = None
    if o.factors:
        alpha, _info = lapack.dpotrs(c, np.asfortranarray(y.reshape(n, -1)), lower=1)
    at_bounds = []
    for nm, t in zip(free, best[0]):
        lo, hi = spec[nm].log_bounds
        if abs(t - lo) < 1e-6 or abs(t - hi) < 1e-6:
            at_bounds.append(nm)
    fit = OutputFit(
        values=values, nlml=float(best[1]), jitter=float(jitter), rcond=rc, positive_definite=pd,
        n_evaluations=counter["evals"], n_infeasible=counter["infeasible"], starts=records,
        at_bounds=at_bounds, free=list(free), seconds=time.perf_counter() - t0, guarded=guarded,
        subsample=sub_info,
    )
    if not o.factors:  # the checks above were made on c; the caller needs no factor (o.factors)
        return fit, None, None
    return fit, np.tril(c), np.asarray(alpha)

