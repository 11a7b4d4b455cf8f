"""BLAS threads in loading a model, rollouts and predictions (issue 24, point 8): a lone
``rbgp rollout --count 60`` on a 1208-point model used 4.7× the CPU of OPENBLAS_NUM_THREADS=1, all
of it in the Cholesky factorisation of the loaded model, which ran on every BLAS thread. The model's
factors, rollouts and predictions are the same whatever the thread setting."""

from __future__ import annotations

import numpy as np
import pytest

threadpoolctl = pytest.importorskip("threadpoolctl")

from rbgp_cli.dynamics.model import MotionModel  # noqa: E402
from rbgp_cli.dynamics.representations import AxisAngle  # noqa: E402
from rbgp_cli.dynamics.rollout import rollout, starts_near  # noqa: E402
from rbgp_cli import compute  # noqa: E402
from rbgp_cli.gp import exact  # noqa: E402
from rbgp_cli.gp.exact import GaussianProcess, fit_gp  # noqa: E402
from rbgp_cli.kernels import SquaredExponential  # noqa: E402


def _blas_threads_now() -> int:
    return max(p["num_threads"] for p in threadpoolctl.threadpool_info() if p["user_api"] == "blas")


@pytest.fixture(scope="module")
def model():
    """A small pose-only model on a smooth velocity field (shared hyperparameters, one start)."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(3)
    n = 300
    q = Rotation.random(n, rng=rng).as_quat()
    p = rng.normal(0.0, 0.3, (n, 3))
    rep = AxisAngle()
    X = rep.state_from_pose(q, p)
    Y = np.concatenate([np.sin(X[:, :3]), np.cos(X[:, 3:])], axis=1) + rng.normal(0.0, 0.01, (n, 6))
    gp = fit_gp(X, Y, SquaredExponential("chordal", 3, 0.7), restarts=1, seed=0, shared=True)
    starts = np.concatenate([q[:5], p[:5]], axis=1)
    return MotionModel(rep, gp, 0.01, starts, np.full(5, 1.0))


def _loaded(model) -> GaussianProcess:
    """The GP as a loaded model file builds it: the factors computed anew."""
    gp = model.gp
    return GaussianProcess(gp.kernel, gp.X, gp.Y, gp.fits, shared=gp.shared, y_scale=gp.y_scale)


@pytest.mark.parametrize("cap", [None, 1])
def test_a_loaded_model_factorises_single_threaded(model, monkeypatch, cap):
    """The factorisation of a loaded model ran on every BLAS thread (no limit at all)."""
    seen = []
    cholesky = exact.cholesky  # imported from rbgp_cli.gp.likelihood; the factorisation looks it up in exact

    def spy(*args, **kwargs):
        seen.append(_blas_threads_now())
        return cholesky(*args, **kwargs)

    monkeypatch.setattr(exact, "cholesky", spy)
    with threadpoolctl.threadpool_limits(limits=2 if cap is None else cap, user_api="blas"):
        _loaded(model)
    assert seen and set(seen) == {1}, seen


def test_rollouts_and_predictions_do_not_depend_on_the_blas_threads(model):
    q0, p0 = starts_near(model.starts, 8, 0.02, seed=1)
    out = {}
    for threads in (1, 2):
        with threadpoolctl.threadpool_limits(limits=threads, user_api="blas"):
            twin = MotionModel(model.representation, _loaded(model), model.dt, model.starts, model.durations)
            res = rollout(twin, q0, p0, 40, with_std=True, samples=2, seed=0)
            Xs = twin.initial_state(q0, p0)
            mean, std = twin.gp.predict(np.repeat(Xs, 50, axis=0), return_std=True)
        out[threads] = (res, mean, std, twin.gp._L[0])
    (r1, m1, s1, L1), (r2, m2, s2, L2) = out[1], out[2]
    np.testing.assert_allclose(L1, L2, rtol=0, atol=1e-12)
    for a, b in ((r1.quat, r2.quat), (r1.position, r2.position), (r1.std, r2.std), (r1.sample_position, r2.sample_position),
                 (m1, m2), (s1, s2)):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-9)


def test_large_predictions_spread_over_row_threads_run_blas_single_threaded(model, monkeypatch):
    """Above PARALLEL_PREDICT_MIN query × training pairs a prediction runs row chunks on its own
    threads (one per free core); a multi-threaded BLAS inside each of them oversubscribed the cores."""
    rng = np.random.default_rng(5)
    gp = model.gp
    n = 2 * compute.SINGLE_THREAD_BELOW  # where predictions used to leave the BLAS pool on
    X = gp.X[rng.integers(0, len(gp.X), n)] + rng.normal(0.0, 0.05, (n, gp.X.shape[1]))
    big = GaussianProcess(gp.kernel, X, rng.normal(0.0, 1.0, (n, gp.Y.shape[1])), gp.fits, shared=gp.shared)
    monkeypatch.setattr(compute, "free_cores", lambda: 2)
    monkeypatch.setattr(compute, "free_cores_recently", lambda: 2)
    monkeypatch.setattr(compute, "in_worker_process", lambda: False)
    m = exact.PARALLEL_PREDICT_MIN // n + 10
    assert exact._prediction_workers(m * n) == 2
    seen = []
    rows = GaussianProcess._predict_rows

    def spy(self, *args):
        seen.append(_blas_threads_now())
        return rows(self, *args)

    monkeypatch.setattr(GaussianProcess, "_predict_rows", spy)
    Xs = X[rng.integers(0, n, m)]
    with threadpoolctl.threadpool_limits(limits=2, user_api="blas"):
        mean, std = big.predict(Xs, return_std=True)
        assert _blas_threads_now() == 2  # restored afterwards
    assert len(seen) >= 2 and set(seen) == {1}, seen
    with threadpoolctl.threadpool_limits(limits=1, user_api="blas"):
        mean1, std1 = big.predict(Xs, return_std=True)
    np.testing.assert_allclose(mean, mean1, rtol=0, atol=1e-9)
    np.testing.assert_allclose(std, std1, rtol=0, atol=1e-9)
