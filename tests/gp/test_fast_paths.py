"""The fast paths of issue 11: the quasi-Newton polish on all points, per-output fits in worker
processes, and predictions / rollouts from matrix products. Properties: the same optima as L-BFGS-B
from every start on all points, results that do not depend on the number of workers, rollouts equal
to the precise-distance path to 1e-9. No timings (benchmarks/ measures them)."""

from __future__ import annotations

import math
import multiprocessing
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from rbgp_cli.compute import blas_threads, default_jobs, usable_cores
from rbgp_cli.dynamics.model import MotionModel
from rbgp_cli.dynamics.rollout import rollout, starts_near
from rbgp_cli.errors import RbgpRuntimeError
from rbgp_cli.gp import optimise
from rbgp_cli.gp.exact import GaussianProcess, fit_gp
from rbgp_cli.gp.likelihood import INFEASIBLE_NLML
from rbgp_cli.kernels import Kernel, SquaredExponential
from tests.gp.test_gp import poses, smooth_outputs

REPO = Path(__file__).resolve().parents[2]


# ----------------------------------------------------------------------------- the polish
@pytest.mark.parametrize("metric", ["arc", "chordal"])
@pytest.mark.parametrize("shared", [False, True])
@pytest.mark.slow
def test_polish_finds_optima_as_good_as_full_size_lbfgsb(metric, shared):
    """Seeded problems with the paper's (indefinite) kernel and the chordal one: the subsample
    exploration + polish ends at optima at least as good (within the issue's 0.1 %) as L-BFGS-B
    from every start on all points, at stationary points, with far fewer evaluations on all points.
    (A 100-point subsample ranks basins less reliably than the default 400 of 1752: here one
    polish of a second basin finds a better optimum, and one polish ends better than L-BFGS-B.)"""
    X = poses(300, 41)
    Y = smooth_outputs(X, np.random.default_rng(41))[:, [0, 3, 4]]
    kernel = SquaredExponential(metric, 3, 0.7)
    full = fit_gp(X, Y, kernel, restarts=3, seed=2, shared=shared, explore_size=0)
    fast = fit_gp(X, Y, kernel, restarts=3, seed=2, shared=shared, explore_size=100)
    for f_full, f_fast in zip(full.fits, fast.fits):
        assert f_fast.subsample is not None
        assert f_fast.nlml <= f_full.nlml + 1e-3 * abs(f_full.nlml)
    assert sum(f.n_evaluations for f in fast.fits) < 0.6 * sum(f.n_evaluations for f in full.fits)
    assert_no_better_point_nearby(fast, kernel, X, Y)


def assert_no_better_point_nearby(gp, kernel, X, Y):
    """At each polished optimum the NLML decrease that Newton's step with the finite-difference
    Hessian on all points still promises (over the hyperparameters not held at a bound) is below
    10 × the polish's tolerance, POLISH_RTOL · max(|NLML|, n). Outputs refit on the noise margin are
    constrained optima and are skipped."""
    with blas_threads(0):  # as in the fit: a 2-thread pool can be 100× slower on a busy machine
        _check_polished(gp, kernel, X, Y)


def _check_polished(gp, kernel, X, Y):
    pre = kernel.precompute(X)
    for l, fit in enumerate(gp.fits):
        if fit.guarded:
            continue
        y = Y / gp.y_scale if gp.shared else Y[:, l]
        free = [nm for nm in fit.free if nm not in fit.at_bounds]
        spec, _ = optimise.free_spec(kernel, pre, y, None, None, None)
        obj = optimise.Objective(kernel, pre, y, spec, free)
        theta = np.log([fit.values[nm] for nm in free])
        obj.fixed_values.update({nm: fit.values[nm] for nm in fit.values if nm not in free})
        f, g = obj(theta)
        H = optimise.fd_hessian(obj, theta)
        assert H is not None and np.all(np.linalg.eigvalsh(H) > 0), (l, H)
        decrease = 0.5 * g @ np.linalg.solve(H, g)
        assert decrease < 10 * optimise.POLISH_RTOL * max(abs(f), len(X)), (l, decrease, f)


def test_an_optimum_is_a_point_that_was_evaluated_feasible(monkeypatch):
    """L-BFGS-B can end on a rejected (infeasible) trial point after an abnormal line search and
    report the value of another point; the fit must return the best feasible point it evaluated,
    with that point's own NLML (on main the NLML of one point was stored with the values of another)."""
    X = poses(40, 3)
    y = smooth_outputs(X, np.random.default_rng(3))[:, 0]
    kernel = SquaredExponential("chordal", 3, 0.7)
    t0 = math.log(kernel.default_hyperparameters(kernel.precompute(X), y)["length_scale"].value)
    feasible = []

    def toy(kernel_, pre, values, y_, names, margin=0.0):
        # NLML −10 (log λ − t0), decreasing towards a wavy edge beyond which C is "not PD"
        t = math.log(values["length_scale"]) - t0
        if t > 2.0 + 0.3 * math.sin(7.0 * t):
            return INFEASIBLE_NLML, np.zeros(len(names))
        feasible.append(t)
        return -10.0 * t, np.array([-10.0 if nm == "length_scale" else 0.0 for nm in names])

    monkeypatch.setattr(optimise, "nlml_and_gradient", toy)  # the objective looks it up there
    gp = fit_gp(X, y, kernel, noise=0.1, fixed={"signal_std": 1.0}, restarts=1)
    fit = gp.fits[0]
    t = math.log(fit.values["length_scale"]) - t0
    assert t in feasible
    assert fit.nlml == -10.0 * t
    assert fit.nlml == min(-10.0 * s for s in feasible)


# ----------------------------------------------------------------------------- worker processes
@pytest.mark.slow
def test_worker_processes_give_bit_identical_fits_and_predictions():
    X = poses(260, 21)
    Y = smooth_outputs(X, np.random.default_rng(21))[:, :3]
    kernel = SquaredExponential("arc", 3, 0.7)
    lines = []
    one = fit_gp(X, Y, kernel, restarts=2, seed=4, explore_size=90)
    two = fit_gp(X, Y, kernel, restarts=2, seed=4, explore_size=90, jobs=2, progress=lines.append)
    for a, b in zip(one.fits, two.fits):
        assert a.values == b.values and a.nlml == b.nlml
        assert a.n_evaluations == b.n_evaluations and a.starts == b.starts
    assert sorted(line.split(":")[0] for line in lines if line.startswith("output")) == ["output 0", "output 1", "output 2"]
    Xs = poses(40, 5)
    m1, s1 = one.predict(Xs, return_std=True)
    m2, s2 = two.predict(Xs, return_std=True)
    np.testing.assert_array_equal(m1, m2)
    np.testing.assert_array_equal(s1, s2)
    # the Cholesky factors the fit hands over are those a fresh factorisation gives
    fresh = GaussianProcess(kernel, X, Y, one.fits, shared=False)
    np.testing.assert_allclose(fresh.predict(Xs), m1, rtol=1e-12, atol=1e-14)


def test_a_failure_in_a_worker_is_the_same_one_line_error():
    ang = np.linspace(0, 6, 30)
    X = np.stack([np.zeros(30), np.zeros(30), ang, np.zeros(30), np.zeros(30), np.zeros(30)], 1)
    Y = np.stack([np.sin(ang), np.cos(ang)], 1)
    k = SquaredExponential("arc", 3, 0.7)
    with pytest.raises(RbgpRuntimeError, match="positive definite covariance for output 0"):
        fit_gp(X, Y, k, noise=1e-9, fixed={"length_scale": 4.0, "signal_std": 1.0}, restarts=1, jobs=2)


def _context():
    return multiprocessing.get_context("fork" if sys.platform.startswith("linux") else "spawn")


def test_default_jobs_never_nests_worker_pools():
    assert default_jobs(1) == 1
    # one worker per task up to one per core: more CPU-bound workers than cores take the cores from
    # other programs on a busy machine and gain nothing on an idle one (issue 35)
    assert default_jobs(6) == (min(6, usable_cores()) if usable_cores() >= 2 else 1)
    assert default_jobs(6) <= usable_cores()
    assert default_jobs(6, n=10**7) == 1  # 6 × (10⁷)² doubles: no machine holds two of those
    with ProcessPoolExecutor(1, mp_context=_context()) as pool:
        assert pool.submit(default_jobs, 6).result() == 1
    with pytest.raises(ValueError, match="jobs"):
        fit_gp(poses(5, 1), np.zeros(5), SquaredExponential("chordal"), jobs=0)


@pytest.mark.slow
def test_train_jobs_option_gives_the_same_model(tmp_path):
    from rbgp_cli.cli.app import app
    from rbgp_cli.io.model_store import read_header

    runner = CliRunner()
    common = ["train", str(REPO / "sample_data" / "csv"), "--max-points", "120", "--restarts", "2", "--json"]
    headers = []
    for jobs in ("1", "2"):
        out = tmp_path / f"m{jobs}.rbgp"
        res = runner.invoke(app, [*common, "-o", str(out), "--jobs", jobs], catch_exceptions=False)
        assert res.exit_code == 0, res.stderr
        headers.append(read_header(out))
    (h1, a1), (h2, a2) = headers
    assert [f["values"] for f in h1["fits"]] == [f["values"] for f in h2["fits"]]
    np.testing.assert_array_equal(a1["X"], a2["X"])


# ----------------------------------------------------------------------------- predictions, rollouts
class PreciseDistances(SquaredExponential):
    """The prediction path before issue 11: pairwise distances with the precise small-angle branch
    for every query block, then the kernel (Kernel's default cross_precompute / cross_gram)."""

    def cross_precompute(self, plan, Xa):
        return Kernel.cross_precompute(self, plan, Xa)

    def cross_gram(self, plan, Xa, values):
        return Kernel.cross_gram(self, plan, Xa, values)


def _synthetic_model(kernel: str, shared: bool, n: int = 300):
    """A motion model on random poses with a smooth velocity field plus noise (σ = 0.05; like the
    benchmarks' data): a well-conditioned GP, so that round-off stays round-off along a rollout."""
    from rbgp_cli.dynamics.representations import make_representation
    from scipy.spatial.transform import Rotation
    from tests.gp.test_gp import vector_field

    X = poses(n, 12)
    q = Rotation.from_rotvec(X[:, :3]).as_quat()
    Y = vector_field(q, X[:, 3:]) + 0.05 * np.random.default_rng(12).normal(size=(n, 6))
    metric = "arc" if kernel == "se" else "chordal"
    gp = fit_gp(X, Y, SquaredExponential(metric, 3, 0.7), restarts=1, seed=0, shared=shared)
    starts = np.concatenate([q[:10], X[:10, 3:]], axis=1)
    return MotionModel(make_representation("axis-angle"), gp, 0.01, starts, np.full(10, 3.0))


def _with_kernel(model, kernel):
    gp = model.gp
    twin = GaussianProcess(kernel, gp.X, gp.Y, gp.fits, shared=gp.shared, y_scale=gp.y_scale)
    return MotionModel(model.representation, twin, model.dt, model.starts, model.durations)


@pytest.mark.parametrize("kernel", ["se", "se-chordal"])
@pytest.mark.parametrize("shared", [True, False])
@pytest.mark.slow
def test_rollouts_equal_the_precise_distance_path(kernel, shared):
    """Batched rollouts through the matrix-product kernel (fused for shared hyperparameters, one
    distance block for all outputs otherwise) give the poses of the precise path to 1e-9 after 300
    steps, and the same predictive std. (A model whose noise ran to its lower bound amplifies any
    round-off, the order of a BLAS sum included, far beyond that: not this test's subject.)"""
    model = _synthetic_model(kernel, shared)
    k = model.gp.kernel
    precise = _with_kernel(model, PreciseDistances(k.metric, k.rotation_dims, k.rho_rot, k.learn_rho))
    q0, p0 = starts_near(model.starts, 12, 0.02, seed=3)
    fast = rollout(model, q0, p0, 300, with_std=True)
    slow = rollout(precise, q0, p0, 300, with_std=True)
    assert np.max(np.abs(fast.position - slow.position)) <= 1e-9
    assert np.max(1.0 - np.abs(np.sum(fast.quat * slow.quat, -1))) <= 1e-15
    # σ = sqrt(σf² − ‖L⁻¹k*‖²) cancels near the data: round-off of σf² · 1e-16 is what remains
    np.testing.assert_allclose(fast.std, slow.std, rtol=1e-6, atol=1e-9)
    travelled = np.linalg.norm(fast.position[:, -1] - fast.position[:, 0], axis=1)
    assert np.all(travelled > 0.1)  # the rollouts go somewhere: the comparison means something


def _phase_model(kernel: str, n: int = 300):
    """The product's coming default: a phase input (last column) and the mean-path prior, on the
    synthetic poses of :func:`_synthetic_model` with random phases; the path is that of three
    demonstrations following the same field (outputs per unit phase, D = 3 s, minus the prior)."""
    from rbgp_cli.dynamics.model import mean_path, prior_mean_outputs
    from rbgp_cli.dynamics.representations import make_representation
    from rbgp_cli.dynamics.trajectory import Trajectory
    from rbgp_cli.geometry.se3 import integrate_quat
    from scipy.spatial.transform import Rotation
    from tests.gp.test_gp import vector_field

    rng = np.random.default_rng(13)
    X = poses(n, 13)
    q = Rotation.from_rotvec(X[:, :3]).as_quat()
    D = 3.0
    qd, pd = q[:3], X[:3, 3:]
    Q, P = [qd], [pd]
    for _ in range(150):
        qd, pd = integrate_quat(qd, pd, vector_field(qd, pd), D / 150)
        Q.append(qd)
        P.append(pd)
    t = np.linspace(0.0, D, 151)
    demos = [Trajectory(t, np.array(Q)[:, b], np.array(P)[:, b]) for b in range(3)]
    rep = make_representation("axis-angle")
    mean = {"kind": "path", "gain": 10.0, **mean_path(demos)}
    phase = rng.uniform(0.0, 1.0, n)
    Y = D * (vector_field(q, X[:, 3:]) + 0.05 * rng.normal(size=(n, 6))) - prior_mean_outputs(rep, X, mean, phase)
    metric = "arc" if kernel == "se" else "chordal"
    gp = fit_gp(np.hstack([X, phase[:, None]]), Y, SquaredExponential(metric, 3, 0.7, time_dims=1), restarts=1,
                seed=0, shared=True)
    starts = np.concatenate([q[:3], X[:3, 3:]], axis=1)
    return MotionModel(rep, gp, D / 150, starts, np.full(3, D), time_input="phase", mean=mean)


@pytest.mark.parametrize("kernel", ["se", "se-chordal"])
@pytest.mark.slow
def test_rollouts_with_phase_and_path_prior_equal_the_precise_path(kernel):
    """A model with the phase input and the mean-path prior: the fast path (the phase term in the
    same matrix product; the prior's reference pose computed once per step for trajectories that
    share their phase) gives the precise path's poses to 1e-9, also for a batch whose trajectories
    have different durations (phases), and each trajectory of a batch is the one rolled out alone."""
    model = _phase_model(kernel)
    k = model.gp.kernel
    twin = _with_kernel(model, PreciseDistances(k.metric, k.rotation_dims, k.rho_rot, k.learn_rho, k.time_dims))
    precise = MotionModel(twin.representation, twin.gp, model.dt, model.starts, model.durations,
                          time_input="phase", mean=model.mean)
    q0, p0 = starts_near(model.starts, 8, 0.02, seed=5)
    for durations in (None, np.linspace(2.5, 3.5, 8)):
        fast = rollout(model, q0, p0, 150, durations=durations, with_std=False)
        slow = rollout(precise, q0, p0, 150, durations=durations, with_std=False)
        assert np.max(np.abs(fast.position - slow.position)) <= 1e-9
        assert np.max(1.0 - np.abs(np.sum(fast.quat * slow.quat, -1))) <= 1e-15
        travelled = np.linalg.norm(fast.position[:, -1] - fast.position[:, 0], axis=1)
        assert np.all(travelled > 0.05)
    alone = rollout(model, q0[2:3], p0[2:3], 150, with_std=False)
    batched = rollout(model, q0, p0, 150, with_std=False)
    assert np.max(np.abs(alone.position[0] - batched.position[2])) <= 1e-9


def test_prior_mean_of_a_shared_phase_is_the_rowwise_one():
    """prior_mean_outputs computes the path's reference pose once when all rows share the phase:
    bit for bit what each row gives alone."""
    from rbgp_cli.dynamics.model import prior_mean_outputs

    model = _phase_model("se-chordal", n=20)
    X = poses(7, 3)
    for s in (0.0, 0.37, 1.0):
        together = prior_mean_outputs(model.representation, X, model.mean, np.full(7, s))
        rowwise = np.concatenate([prior_mean_outputs(model.representation, X[i:i + 1], model.mean, np.array([s]))
                                  for i in range(7)])
        np.testing.assert_array_equal(together, rowwise)


def test_squared_quaternion_dot_products_are_one_product_of_features():
    """⟨qa, qb⟩² of all pairs = weighted square features of qa @ square features of qb (the chordal
    kernel's one-product exponent), to 1e-15, for unit quaternions of either sign."""
    from rbgp_cli.geometry.distance import quat_square_features
    from scipy.spatial.transform import Rotation

    qa = Rotation.random(30, random_state=1).as_quat() * np.where(np.arange(30) % 2, -1.0, 1.0)[:, None]
    qb = np.concatenate([Rotation.random(40, random_state=2).as_quat(), qa[:5]])
    want = (qa @ qb.T) ** 2
    got = quat_square_features(qa, weighted=True) @ quat_square_features(qb).T
    assert np.max(np.abs(got - want)) <= 1e-15
    np.testing.assert_allclose(np.diag(got[:5, 40:]), 1.0, rtol=0, atol=1e-15)


def test_path_reference_is_the_slerp_of_the_mean_path():
    """PathReference (the slerp's per-interval parts computed once) gives interpolate_poses' poses
    and the interval's velocity bit for bit: between grid points, on them, at the ends and beyond."""
    from rbgp_cli.dynamics.model import PathReference
    from rbgp_cli.dynamics.trajectory import interpolate_poses

    mean = _phase_model("se-chordal", n=20).mean
    s = np.concatenate([np.random.default_rng(4).uniform(0, 1, 30), mean["s"][[0, 7, 50]], [-0.2, 1.3]])
    q, p, v = PathReference(mean).at(s)
    want_q, want_p = interpolate_poses(mean["s"], mean["quat"], mean["position"], np.clip(s, 0, 1))
    np.testing.assert_array_equal(q, want_q)
    np.testing.assert_array_equal(p, want_p)
    k = np.clip(np.searchsorted(mean["s"], np.clip(s, 0, 1), side="right") - 1, 0, len(mean["s"]) - 2)
    np.testing.assert_array_equal(v, mean["velocity"][k])


@pytest.mark.parametrize("n", [1, 5, 127, 128, 129, 300])
def test_the_blocked_symmetrisation_is_bit_for_bit_the_transposed_add(n):
    """likelihood.symmetrise_lower (issue 35): dpotri's lower triangle (upper zero) made symmetric in
    cache-sized blocks gives exactly what W = inv + invᵀ with the diagonal halved gave."""
    from scipy.linalg import lapack

    from rbgp_cli.gp.likelihood import symmetrise_lower

    A = np.random.default_rng(n).standard_normal((n, n))
    c, _ = lapack.dpotrf(np.asfortranarray(A @ A.T + n * np.eye(n)), lower=1, clean=1)
    inv, _ = lapack.dpotri(c, lower=1)
    old = inv.copy(order="F")
    old += inv.T
    old[np.arange(n), np.arange(n)] *= 0.5
    new = symmetrise_lower(inv.copy(order="F"))
    np.testing.assert_array_equal(new, old)
    np.testing.assert_array_equal(new, new.T)
