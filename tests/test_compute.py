"""Studies on a Dask cluster: the same results as in this process, in task order; the executors."""

from __future__ import annotations

import math
import os
from pathlib import Path

import pytest

from rbgp_cli.errors import InputError
from rbgp_cli.compute import run_tasks

REPO = Path(__file__).resolve().parents[1]


def _square(x):
    return x * x


def _blas_threads(_):
    import numpy  # noqa: F401  (threadpoolctl sees only the libraries loaded: numpy's OpenBLAS)
    from threadpoolctl import threadpool_info

    return max(p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas")


def _fail(x):
    if x == 2:
        raise ValueError("boom")
    return x


def test_in_process_keeps_order_and_reports_each_result():
    seen = []
    assert run_tasks(_square, [3, 1, 2], jobs=1, on_result=lambda i, r: seen.append((i, r))) == [9, 1, 4]
    assert sorted(seen) == [(0, 9), (1, 1), (2, 4)]
    assert run_tasks(_square, [], jobs=4) == []


@pytest.mark.slow
def test_unknown_scheduler_address_is_an_input_error(monkeypatch):
    pytest.importorskip("distributed")
    monkeypatch.setattr("rbgp_cli.compute.CONNECT_TIMEOUT", "1s")
    with pytest.raises(InputError, match="cannot reach the Dask scheduler"):
        run_tasks(_square, [1], scheduler="tcp://127.0.0.1:9")


@pytest.fixture(scope="module")
def demos():
    from rbgp_cli.workflows import load_demonstrations

    clean, _reports, _inputs = load_demonstrations([str(REPO / "sample_data" / "csv")])
    return clean[:6]


def _strip_times(result):
    """The crossval result without wall-clock times (the only thing allowed to differ)."""
    out = dict(result)
    rows = []
    for row in result["results"]:
        row = {k: v for k, v in row.items() if k not in ("train_s",)}
        row["per_fold"] = [{k: v for k, v in f.items() if k not in ("train_s", "rollout_s")} for f in row["per_fold"]]
        rows.append(row)
    out["results"] = rows
    return out


def _assert_same(a, b, path="result"):
    if isinstance(a, dict):
        assert a.keys() == b.keys(), path
        for k in a:
            _assert_same(a[k], b[k], f"{path}.{k}")
    elif isinstance(a, list):
        assert len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b)):
            _assert_same(x, y, f"{path}[{i}]")
    elif isinstance(a, float) and not (math.isnan(a) and math.isnan(b)):
        # BLAS runs single-threaded on the workers and as configured here: round-off may differ
        assert a == pytest.approx(b, rel=1e-6, abs=1e-9), path
    else:
        assert a == b, path


@pytest.mark.slow
def test_crossval_on_a_local_dask_cluster_matches_in_process(demos):
    pytest.importorskip("distributed")
    from rbgp_cli.evaluation.crossval import REPLAY, Config, crossval

    configs = [
        Config("axis-angle", "se-chordal", train={"max_points": 60, "restarts": 1, "shared": True}),
        Config(REPLAY),
    ]
    here = crossval(demos, configs, folds=3, seed=4, jobs=1)
    messages = []
    dask = crossval(demos, configs, folds=3, seed=4, jobs=2, scheduler="local", progress=messages.append)
    _assert_same(_strip_times(here), _strip_times(dask))
    assert "on the Dask cluster 'local'" in messages[0]
    assert sum(", fold " in m for m in messages) == 6  # one message per finished fit


@pytest.mark.slow
def test_a_running_cluster_by_address_single_threaded_blas_and_failures():
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        address = cluster.scheduler_address
        assert run_tasks(_square, list(range(7)), scheduler=address) == [x * x for x in range(7)]
        assert run_tasks(_blas_threads, [0, 1, 2], scheduler=address) == [1, 1, 1]
        with pytest.raises(Exception, match="boom"):
            run_tasks(_fail, [1, 2, 3], scheduler=address)


@pytest.mark.slow
def test_crossval_command_passes_scheduler_and_inducing(monkeypatch):
    """The command line hands --scheduler to the executor (an unreachable one is a one-line input
    error) and --inducing to every fold's training."""
    pytest.importorskip("distributed")
    from typer.testing import CliRunner

    from rbgp_cli.cli.app import app
    from rbgp_cli.cli.train_options import train_kwargs

    monkeypatch.setattr("rbgp_cli.compute.CONNECT_TIMEOUT", "1s")
    res = CliRunner().invoke(app, ["crossval", str(REPO / "sample_data" / "csv"), "--folds", "3", "--max-points", "50",
                                   "--restarts", "1", "--scheduler", "tcp://127.0.0.1:9", "--inducing", "16"])
    assert res.exit_code == 2, res.stderr
    assert "cannot reach the Dask scheduler" in res.stderr and "Traceback" not in res.stderr
    kw = train_kwargs(rho_rot="0.7", restarts=1, explore_size=0, seed=0, noise="learn", share_hyperparameters=True,
                      subsample=1.0, max_points=50, train_rate=0.0, smooth_window=0.0, smooth_degree=2,
                      time_input="none", prior="none", prior_gain=1.0, inducing=16)
    assert kw["inducing"] == 16


def _die(x):
    os._exit(3)  # a worker killed (or out of memory) while running this task


def _die_once(marker):
    if not os.path.exists(marker):
        open(marker, "w").close()
        os._exit(3)
    return "done"


@pytest.mark.slow
def test_a_lost_local_worker_is_retried_once_then_named():
    """Before: the generic ``internal error: BrokenProcessPool`` at the first lost worker."""
    import tempfile

    from rbgp_cli.errors import RbgpRuntimeError

    with tempfile.TemporaryDirectory() as d:
        marker = os.path.join(d, "lost")
        assert run_tasks(_die_once, [marker, marker], jobs=2) == ["done", "done"]
    with pytest.raises(RbgpRuntimeError, match=r"ended unexpectedly \(killed, or out of memory\) 2 times; "
                                               r"unfinished: fit A, fit B"):
        run_tasks(_die, [0, 1], jobs=2, label=lambda i: f"fit {'AB'[i]}")


def _sleep(seconds):
    import time

    time.sleep(seconds)
    return seconds


@pytest.mark.slow
def test_a_dask_study_with_no_worker_left_fails_within_the_timeout(monkeypatch):
    """Before: with every worker gone the study waited forever, with no output."""
    distributed = pytest.importorskip("distributed")
    import threading
    import time

    from rbgp_cli.errors import RbgpRuntimeError

    monkeypatch.setattr("rbgp_cli.compute.NO_WORKER_TIMEOUT", 2.0)
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None) as cluster:
        outcome = {}

        def study():
            try:
                outcome["result"] = run_tasks(_sleep, [3.0, 3.0, 3.0], scheduler=cluster.scheduler_address,
                                              label=lambda i: f"fold {i + 1}")
            except Exception as exc:  # noqa: BLE001 - the test looks at it
                outcome["error"] = exc

        thread = threading.Thread(target=study, daemon=True)
        t0 = time.monotonic()
        thread.start()
        time.sleep(1.0)
        cluster.scale(0)  # every worker gone, the tasks unfinished
        thread.join(30)
        assert not thread.is_alive(), "the study still waits with no worker"
        assert time.monotonic() - t0 < 15
    err = outcome.get("error")
    assert isinstance(err, RbgpRuntimeError), outcome
    assert "no Dask worker left for 2 s" in str(err) and "fold " in str(err)


# ----------------------------------------------------------------------------- cores, BLAS, thread pools
def test_thread_workers_are_one_below_the_threshold_at_most_the_pool_and_one_in_a_worker(monkeypatch):
    from concurrent.futures import ProcessPoolExecutor

    from rbgp_cli import compute

    monkeypatch.setattr(compute, "free_cores_recently", lambda: 3)
    assert compute.thread_workers(99, 100) == 1
    assert compute.thread_workers(100, 100) == min(3, compute.POOL_THREADS)
    monkeypatch.setattr(compute, "free_cores_recently", lambda: 64)
    assert compute.thread_workers(10**9, 100) == compute.POOL_THREADS
    with ProcessPoolExecutor(1, mp_context=compute.fork_context()) as pool:
        assert pool.submit(compute.in_worker_process).result() is True
        assert pool.submit(compute.thread_workers, 10**9, 1).result() == 1
    assert compute.in_worker_process() is False


def test_thread_pools_are_one_per_name_and_process():
    from concurrent.futures import ProcessPoolExecutor

    from rbgp_cli import compute

    a = compute.thread_pool("test-a")
    assert compute.thread_pool("test-a") is a and compute.thread_pool("test-b") is not a
    assert a.submit(lambda: 7).result() == 7
    with ProcessPoolExecutor(1, mp_context=compute.fork_context()) as pool:  # a forked child builds its own
        assert pool.submit(_pool_result).result() == 8


def _pool_result():
    from rbgp_cli import compute

    return compute.thread_pool("test-a").submit(lambda: 8).result()


def test_blas_threads_limits_small_problems_and_one_thread_limits_every_pool():
    import numpy  # noqa: F401  (loads OpenBLAS: run alone, this module had not, and threadpoolctl saw no pool)
    import threadpoolctl

    from rbgp_cli import compute

    with threadpoolctl.threadpool_limits(limits=2, user_api="blas"):
        with compute.blas_threads(0):
            assert {p["num_threads"] for p in threadpoolctl.threadpool_info() if p["user_api"] == "blas"} == {1}
        with compute.one_thread():
            assert {p["threads"] for p in compute.blas_pools()} == {1}
        assert {p["num_threads"] for p in threadpoolctl.threadpool_info() if p["user_api"] == "blas"} == {2}


def test_a_pytest_xdist_worker_runs_blas_on_one_thread():
    """tests/conftest.py sets OPENBLAS_NUM_THREADS=1 in each pytest-xdist worker before numpy loads
    (two workers with two BLAS threads each took four threads on the two cores); if numpy were imported
    first, the pool would have one thread per core. A value set by the caller is kept."""
    if not os.environ.get("PYTEST_XDIST_WORKER"):
        pytest.skip("not a pytest-xdist worker")
    assert _blas_threads(0) == int(os.environ["OPENBLAS_NUM_THREADS"])


@pytest.mark.slow
def test_a_stopped_pool_leaves_no_manager_thread_for_the_exit_handlers():
    """Before: ``stop_pool`` returned with the pool's manager thread still closing its wake-up pipe, and
    a SIGTERM exit that overtook it printed the standard library's "Bad file descriptor" traceback
    (CI, crossval killed after 0.5 s)."""
    import time

    from rbgp_cli.compute import process_pool, start_workers, stop_pool

    for delay in (0.0, 0.3, 1.0):  # while the workers start, and while they run
        pool = process_pool(2)
        with start_workers():
            futures = [pool.submit(_sleep, 30.0) for _ in range(4)]
        time.sleep(delay)
        manager = pool._executor_manager_thread
        assert manager is not None and manager.is_alive()
        stop_pool(pool)
        assert not manager.is_alive(), delay
        assert all(f.done() for f in futures)


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/loadavg").exists(), reason="Linux /proc only")
def test_a_niced_busy_process_does_not_count_as_a_busy_core(monkeypatch):
    """A ``nice -n 19`` loop beside rbgp is a runnable task in /proc/loadavg but yields its core: the
    scan finds it (state R, higher nice) and free_cores does not subtract it."""
    import subprocess
    import sys
    import time

    from rbgp_cli import compute

    if os.getpriority(os.PRIO_PROCESS, 0) >= 19:
        pytest.skip("this test process is niced to the limit already")
    before = compute._yielding_runnable()
    loop = subprocess.Popen(["nice", "-n", "19", sys.executable, "-c", "while True: pass"])
    try:
        found = 0
        for _ in range(50):  # until the loop runs (a fresh interpreter starts in ~50 ms)
            time.sleep(0.05)
            found = compute._yielding_runnable()
            if found > before:
                break
        assert found >= before + 1
        # free_cores: the loop is in the runnable count and taken out again
        counts = iter(["0.0 0.0 0.0 3/100 1\n"] * 2)
        real_open = open

        def fake_open(path, *args, **kwargs):
            if path == "/proc/loadavg":
                import io
                return io.StringIO(next(counts))
            return real_open(path, *args, **kwargs)

        monkeypatch.setattr("builtins.open", fake_open)
        monkeypatch.setattr(compute, "usable_cores", lambda: 4)
        # (own runnable threads: the caller alone, niced runnable tasks of other processes)
        monkeypatch.setattr(compute, "_runnable_tasks", lambda: (1, 1))
        assert compute.free_cores() == 3  # 4 cores − (3 runnable − this one − the niced one)
        monkeypatch.setattr(compute, "_runnable_tasks", lambda: (1, 0))
        assert compute.free_cores() == 2
    finally:
        loop.kill()
        loop.wait()


@pytest.mark.skipif(not Path("/proc/self/task").exists(), reason="Linux /proc only")
def test_this_process_s_own_busy_threads_do_not_count_as_other_programs(monkeypatch):
    """A thread of this process in a GIL-free numpy product is runnable: the scan counts it among this
    process's own tasks (not among the niced ones of other processes) beside the caller, and free_cores does not count it as another program's task (BLAS threads spinning after
    a threaded factorisation made an idle machine look busy to the calibration)."""
    import io
    import threading

    import numpy as np

    from rbgp_cli import compute

    A = np.random.default_rng(0).standard_normal((300, 300))
    stop = threading.Event()

    def busy():
        while not stop.is_set():
            A @ A  # releases the GIL

    worker = threading.Thread(target=busy)
    worker.start()
    seen = 0
    try:
        for _ in range(200):
            seen = max(seen, compute._own_runnable())
            if seen >= 2:
                break
    finally:
        stop.set()
        worker.join()
    assert seen >= 2
    real_open = open

    def fake_open(path, *args, **kwargs):
        return io.StringIO("0.0 0.0 0.0 3/100 1\n") if path == "/proc/loadavg" else real_open(path, *args, **kwargs)

    monkeypatch.setattr("builtins.open", fake_open)
    monkeypatch.setattr(compute, "usable_cores", lambda: 2)
    monkeypatch.setattr(compute, "_runnable_tasks", lambda: (3, 0))  # the caller and two spinning BLAS threads
    assert compute.free_cores() == 2
    monkeypatch.setattr(compute, "_runnable_tasks", lambda: (1, 0))  # the two are other programs'
    assert compute.free_cores() == 1


def test_free_cores_scans_the_tasks_once_and_only_when_others_run(monkeypatch):
    """free_cores reads both counts (own threads, niced tasks) from one scan of /proc, and none when
    /proc/loadavg shows no other runnable task."""
    import io

    from rbgp_cli import compute

    scans = []
    line = ["0.0 0.0 0.0 4/100 1\n"]
    real_open = open

    def fake_open(path, *args, **kwargs):
        return io.StringIO(line[0]) if path == "/proc/loadavg" else real_open(path, *args, **kwargs)

    def scan():
        scans.append(1)
        return 2, 1  # the caller and a spinning BLAS thread; one niced task

    monkeypatch.setattr("builtins.open", fake_open)
    monkeypatch.setattr(compute, "usable_cores", lambda: 4)
    monkeypatch.setattr(compute, "_runnable_tasks", scan)
    assert compute.free_cores() == 3  # 4 − (4 runnable − the caller − its thread − the niced task)
    assert len(scans) == 1
    line[0] = "0.0 0.0 0.0 1/100 1\n"  # the caller alone: no scan
    assert compute.free_cores() == 4
    assert len(scans) == 1
