"""Run independent tasks in order-preserving fashion: in this process, in local worker processes
(the standard library's ``ProcessPoolExecutor``), or on a Dask distributed cluster.

Studies (``rbgp crossval``: configurations × folds) are lists of independent fits. :func:`run_tasks`
hands them to one of three executors and returns the results in the order of the tasks, whatever the
order they finish in; BLAS runs single-threaded inside every worker (the tasks are the parallelism).

Dask (``pip install "rbgp-cli[distributed]"``) is imported only when a ``scheduler`` is given:
``"local"`` starts a ``LocalCluster`` of ``jobs`` single-threaded worker processes for the call;
anything else is the address of a running scheduler (``tcp://host:8786``). Each task runs under
threadpoolctl's one-thread limit on whatever worker takes it, so workers need no special start-up.
Results are the same as in this process: every task is a pure function of its arguments (seeded).
"""

from __future__ import annotations

import os

__all__ = ["run_tasks", "iter_dask", "single_threaded"]

#: How long to wait for a Dask scheduler given by address.
CONNECT_TIMEOUT = "10s"


def single_threaded(fn, args):
    """``fn(args)`` with BLAS/OpenMP pools limited to one thread (for workers)."""
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # pragma: no cover - threadpoolctl is a dependency
        return fn(args)
    with threadpool_limits(limits=1):
        return fn(args)


def _worker_init() -> None:
    """Local worker processes: BLAS single-threaded for the worker's lifetime."""
    try:
        from threadpoolctl import threadpool_limits

        _worker_init.limits = threadpool_limits(limits=1)
    except ImportError:  # pragma: no cover
        pass


def run_tasks(fn, args: list, *, jobs: int | None = None, scheduler: str | None = None, on_result=None) -> list:
    """``[fn(a) for a in args]``, possibly in parallel; results in the order of ``args``.

    Parameters
    ----------
    fn : a module-level function (picklable), called once per element of ``args``
    jobs : local worker processes (None: one per core, at most len(args); 1: in this process, unless a
        ``scheduler`` is given); with ``scheduler="local"`` the number of Dask workers
    scheduler : None (standard library executors), ``"local"`` (a Dask ``LocalCluster`` for this call)
        or the address of a Dask scheduler (:func:`iter_dask`)
    on_result : optional ``callable(index, result)``, called in this process as each task finishes
    """
    args = list(args)
    results: list = [None] * len(args)
    if not args:
        return results
    if scheduler:
        pairs = iter_dask(fn, args, jobs=jobs, scheduler=scheduler)
    else:
        n_jobs = jobs if jobs is not None else min(len(args), os.cpu_count() or 1)
        n_jobs = max(1, min(int(n_jobs), len(args)))
        pairs = ((i, fn(a)) for i, a in enumerate(args)) if n_jobs == 1 else _iter_processes(fn, args, n_jobs)
    for i, r in pairs:
        results[i] = r
        if on_result is not None:
            on_result(i, r)
    return results


def _iter_processes(fn, args, n_jobs):
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed

    ex = ProcessPoolExecutor(max_workers=n_jobs, mp_context=multiprocessing.get_context("spawn"), initializer=_worker_init)
    try:
        futs = {ex.submit(fn, a): i for i, a in enumerate(args)}
        for fut in as_completed(futs):
            yield futs[fut], fut.result()
    except BaseException:
        ex.shutdown(wait=False, cancel_futures=True)
        raise
    ex.shutdown(wait=True)


def iter_dask(fn, args: list, *, jobs: int | None = None, scheduler: str = "local"):
    """Yield ``(index, fn(args[index]))`` as the tasks finish on a Dask cluster.

    ``scheduler="local"``: a ``LocalCluster`` of ``jobs`` (default: one per core, at most len(args))
    single-threaded worker processes, closed afterwards; otherwise the address of a running scheduler.
    Every task runs with BLAS limited to one thread (:func:`single_threaded`). On an error, or when the
    caller stops iterating, the pending tasks are cancelled. Raises :class:`InputError` when
    ``distributed`` is not installed or the scheduler cannot be reached.
    """
    from rbgp_cli.errors import InputError, RbgpRuntimeError

    try:
        from distributed import Client, LocalCluster, as_completed
    except ImportError:
        raise InputError("--scheduler needs Dask's distributed scheduler, which is not installed",
                         hint='pip install "rbgp-cli[distributed]"') from None
    cluster = None
    try:
        if scheduler == "local":
            n = max(1, min(int(jobs or os.cpu_count() or 1), len(args)))
            cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None)
            client = Client(cluster)
        else:
            try:
                client = Client(scheduler, timeout=CONNECT_TIMEOUT)
            except (OSError, TimeoutError, ValueError) as exc:
                raise InputError(f"cannot reach the Dask scheduler at {scheduler!r} ({type(exc).__name__})",
                                 hint="start one with 'dask scheduler' (and workers with 'dask worker ADDRESS'), "
                                      "or use --scheduler local") from None
        with client:
            # pure=False: identical arguments (two configurations that happen to be equal) still both run
            futs = [client.submit(single_threaded, fn, a, pure=False) for a in args]
            index = {f.key: i for i, f in enumerate(futs)}
            try:
                for fut in as_completed(futs):
                    try:
                        r = fut.result()
                    except (InputError, RbgpRuntimeError):
                        raise
                    except Exception as exc:  # a task that failed on a worker fails the study, as in-process
                        raise RbgpRuntimeError(f"a task failed on a Dask worker: {type(exc).__name__}: {exc}") from exc
                    yield index[fut.key], r
            finally:
                client.cancel([f for f in futs if not f.done()])
    finally:
        if cluster is not None:
            cluster.close()
