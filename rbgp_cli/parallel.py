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

Worker processes end with the process that started them, however it ends (:func:`die_with_parent`,
every local pool's start-up: the exact GP's per-output fits, cross-validation folds; Dask's own
workers watch their parent too); on an error, Ctrl-C or SIGTERM a pool is ended at once
(:func:`stop_pool`, :func:`ending_on_sigterm`), and workers ignore Ctrl-C (:func:`start_workers`).
A lost worker's tasks are run once more (:data:`RETRIES`), then the error names them.
"""

from __future__ import annotations

import os
import sys

__all__ = ["run_tasks", "iter_dask", "single_threaded", "die_with_parent", "process_pool", "start_workers", "stop_pool",
           "ending_on_sigterm"]

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


#: Seconds between a worker's checks that the process that started it is still there.
PARENT_CHECK_S = 0.5
#: How often a local pool that lost a worker (killed, out of memory) is started again for the unfinished
#: tasks, and how often Dask may lose a worker while it runs the same task, before the study fails.
RETRIES = 1
#: Seconds a Dask study waits with no live worker (and unfinished tasks) before it fails.
NO_WORKER_TIMEOUT = 30.0


def die_with_parent(parent_pid: int | None = None, init=None) -> None:
    """Worker-process start-up (every pool's ``initializer``): the worker ends with its parent.

    * Linux: ``prctl(PR_SET_PDEATHSIG, SIGKILL)`` (via ctypes), so the kernel kills the worker the
      moment the process (thread) that started it ends, even by SIGKILL;
    * everywhere: a daemon thread that checks every :data:`PARENT_CHECK_S` seconds that
      ``os.getppid()`` is still ``parent_pid`` and ends the worker at once when it is not (an orphan is
      adopted by another process);
    * SIGINT is ignored (Ctrl-C reaches the whole process group; the parent ends its workers; a worker
      inherits the ignoring from :func:`start_workers`, for its imports before this runs); SIGTERM
      ends the worker at once (a forked worker would otherwise run the parent's handler).

    ``parent_pid`` defaults to the pid of the process that started this one (multiprocessing's record,
    else ``os.getppid()``); ``init`` is then called (the pool's own start-up, e.g. BLAS threads)."""
    import signal
    import threading

    if parent_pid is None:
        import multiprocessing

        parent = multiprocessing.parent_process()
        parent_pid = parent.pid if parent is not None and parent.pid else os.getppid()
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, signal.SIG_DFL)  # a forked worker inherits the parent's handler
    if sys.platform.startswith("linux"):
        try:
            import ctypes

            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(1, int(signal.SIGKILL), 0, 0, 0)  # 1 = PR_SET_PDEATHSIG
        except (OSError, AttributeError):  # pragma: no cover - no prctl: the thread below still checks
            pass
    if os.getppid() != parent_pid:  # the parent ended before this worker was set up
        os._exit(1)

    def _watch():
        import time

        while True:
            time.sleep(PARENT_CHECK_S)
            if os.getppid() != parent_pid:
                os._exit(1)

    threading.Thread(target=_watch, name="rbgp-parent-watch", daemon=True).start()
    if init is not None:
        init()


def _worker_init() -> None:
    """Local worker processes: BLAS single-threaded for the worker's lifetime."""
    try:
        from threadpoolctl import threadpool_limits

        _worker_init.limits = threadpool_limits(limits=1)
    except ImportError:  # pragma: no cover
        pass


def process_pool(max_workers: int, *, context=None, init=None):
    """A ``ProcessPoolExecutor`` of ``max_workers`` workers that end with this process
    (:func:`die_with_parent`, then ``init`` in each). ``context``: a multiprocessing context (default
    spawn). Submit its tasks inside :func:`start_workers` and end it with :func:`stop_pool` on an error."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    ctx = context if context is not None else multiprocessing.get_context("spawn")
    return ProcessPoolExecutor(max_workers=max_workers, mp_context=ctx, initializer=die_with_parent,
                               initargs=(os.getpid(), init))


class start_workers:
    """``with start_workers(): pool.submit(...)``: SIGINT ignored in this process while the pool (or a
    Dask ``LocalCluster``) starts its processes, so that they start ignoring it (an ignored signal stays
    ignored across fork and exec, and Python keeps it so): a Ctrl-C while a worker is still importing
    would print its traceback. The parent ends its workers itself. A Ctrl-C inside the block (the
    ``submit`` calls: milliseconds; a cluster's start: seconds) is lost. Main thread only."""

    def __enter__(self):
        import signal
        import threading

        self._previous = None
        if threading.current_thread() is threading.main_thread():
            self._previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
        return self

    def __exit__(self, *exc):
        import signal

        if self._previous is not None:
            signal.signal(signal.SIGINT, self._previous)
        return False


def stop_pool(pool) -> None:
    """End a process pool now: cancel what has not started and terminate the running workers (on an
    error or an interrupt; ``shutdown(wait=True)`` would wait for their fits to finish)."""
    workers = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for proc in workers:
        try:
            proc.terminate()
        except (OSError, ValueError, AttributeError):  # already gone or closed
            pass
    for proc in workers:
        try:
            proc.join(2.0)
        except (OSError, ValueError, AssertionError, AttributeError):
            pass


class ending_on_sigterm:
    """``with ending_on_sigterm():`` SIGTERM raises ``SystemExit(143)`` in the main thread, so that the
    ``finally`` blocks run (pools stopped, temporary files removed) instead of the process vanishing
    with its workers still running. Does nothing outside the main thread."""

    def __enter__(self):
        import signal
        import threading

        self._previous = None
        if threading.current_thread() is threading.main_thread():
            self._previous = signal.signal(signal.SIGTERM, _raise_exit)
        return self

    def __exit__(self, *exc):
        import signal

        if self._previous is not None:
            signal.signal(signal.SIGTERM, self._previous)
        return False


def _raise_exit(signum, frame):
    raise SystemExit(128 + signum)


def run_tasks(fn, args: list, *, jobs: int | None = None, scheduler: str | None = None, on_result=None,
              label=None) -> list:
    """``[fn(a) for a in args]``, possibly in parallel; results in the order of ``args``.

    Parameters
    ----------
    fn : a module-level function (picklable), called once per element of ``args``
    jobs : local worker processes (None: one per core, at most len(args); 1: in this process, unless a
        ``scheduler`` is given); with ``scheduler="local"`` the number of Dask workers
    scheduler : None (standard library executors), ``"local"`` (a Dask ``LocalCluster`` for this call)
        or the address of a Dask scheduler (:func:`iter_dask`)
    on_result : optional ``callable(index, result)``, called in this process as each task finishes
    label : optional ``callable(index) -> str`` naming a task in the error when it is lost with its
        worker (:data:`RETRIES` + 1 times)
    """
    args = list(args)
    results: list = [None] * len(args)
    if not args:
        return results
    if scheduler:
        pairs = iter_dask(fn, args, jobs=jobs, scheduler=scheduler, label=label)
    else:
        n_jobs = jobs if jobs is not None else min(len(args), os.cpu_count() or 1)
        n_jobs = max(1, min(int(n_jobs), len(args)))
        pairs = ((i, fn(a)) for i, a in enumerate(args)) if n_jobs == 1 else iter_processes(fn, args, n_jobs, label=label)
    for i, r in pairs:
        results[i] = r
        if on_result is not None:
            on_result(i, r)
    return results


def _names(indices, label) -> str:
    names = [label(i) if label is not None else f"task {i + 1}" for i in sorted(indices)]
    return ", ".join(names[:4]) + (f" and {len(names) - 4} more" if len(names) > 4 else "")


def iter_processes(fn, args, n_jobs: int, *, label=None, init=_worker_init):
    """Yield ``(index, fn(args[index]))`` as the tasks finish in ``n_jobs`` fresh (spawned) worker
    processes (:func:`process_pool`; BLAS single-threaded). A pool that loses a worker (killed, out of
    memory) is started again for the unfinished tasks, :data:`RETRIES` times; then
    :class:`RbgpRuntimeError` names them. On any other error, Ctrl-C or SIGTERM the pending tasks are
    cancelled and the workers terminated at once."""
    from concurrent.futures import as_completed
    from concurrent.futures.process import BrokenProcessPool

    from rbgp_cli.errors import RbgpRuntimeError

    todo = list(range(len(args)))
    for attempt in range(RETRIES + 1):
        pool = process_pool(max(1, min(n_jobs, len(todo))), init=init)
        finished, broken = set(), False
        try:
            with ending_on_sigterm():
                with start_workers():
                    futs = {pool.submit(fn, args[i]): i for i in todo}
                for fut in as_completed(futs):
                    try:
                        r = fut.result()
                    except BrokenProcessPool:
                        broken = True
                        break
                    finished.add(futs[fut])
                    yield futs[fut], r
        except BaseException:
            stop_pool(pool)
            raise
        if not broken:
            pool.shutdown(wait=True)
            return
        stop_pool(pool)
        todo = [i for i in todo if i not in finished]
    raise RbgpRuntimeError(f"a worker process ended unexpectedly (killed, or out of memory) {RETRIES + 1} times; "
                           f"unfinished: {_names(todo, label)}", hint="if memory is short, use fewer --jobs")


def _quiet_dask():
    """Dask's own log lines (worker losses, CommClosedError tracebacks) off stderr, in this process and
    in the workers it starts, unless RBGP_DEBUG is set; returns the function that restores them."""
    import logging

    if os.environ.get("RBGP_DEBUG"):
        return lambda: None
    roots = ("distributed", "tornado", "asyncio")
    import distributed  # noqa: F401 - its logging set-up first (levels per logger, e.g. distributed.client)

    names = {*roots, *(n for n in logging.root.manager.loggerDict if n.split(".")[0] in roots)}
    levels = {n: logging.getLogger(n).level for n in names}
    env = os.environ.get("DASK_LOGGING__DISTRIBUTED")
    os.environ["DASK_LOGGING__DISTRIBUTED"] = "critical"  # read by the worker processes as they start
    for n in names:
        if n in roots or levels[n] != logging.NOTSET:  # the others follow their parent
            logging.getLogger(n).setLevel(logging.CRITICAL + 1)

    def restore():
        for n, level in levels.items():
            logging.getLogger(n).setLevel(level)
        if env is None:
            os.environ.pop("DASK_LOGGING__DISTRIBUTED", None)
        else:
            os.environ["DASK_LOGGING__DISTRIBUTED"] = env

    return restore


def _forget_half_started_clusters() -> None:
    """A cluster interrupted while it started cannot be closed (Dask's exit hook would print its
    AssertionError traceback); its workers end with this process."""
    try:
        from distributed.deploy.spec import SpecCluster

        SpecCluster._instances.clear()
    except (ImportError, AttributeError):  # pragma: no cover - another distributed version
        pass


class _children_stderr_off:
    """While the block runs, file descriptor 2 is /dev/null, so that the processes started in it (Dask's
    workers: their stderr is only Dask's log lines, and tracebacks of a Ctrl-C that reaches them while
    they import) write nowhere; this process's stderr comes back afterwards. Not with RBGP_DEBUG."""

    def __enter__(self):
        self._saved = None
        if os.environ.get("RBGP_DEBUG"):
            return self
        try:
            sys.stderr.flush()
            self._saved = os.dup(2)
            null = os.open(os.devnull, os.O_WRONLY)
            os.dup2(null, 2)
            os.close(null)
        except (OSError, ValueError, AttributeError):
            self._saved = None
        return self

    def __exit__(self, *exc):
        if self._saved is not None:
            os.dup2(self._saved, 2)
            os.close(self._saved)
        return False


def iter_dask(fn, args: list, *, jobs: int | None = None, scheduler: str = "local", label=None):
    """Yield ``(index, fn(args[index]))`` as the tasks finish on a Dask cluster.

    ``scheduler="local"``: a ``LocalCluster`` of ``jobs`` (default: one per core, at most len(args))
    single-threaded worker processes, closed afterwards (its workers end with this process); otherwise
    the address of a running scheduler. Every task runs with BLAS limited to one thread
    (:func:`single_threaded`). A task whose worker dies is run again on another (the local cluster
    allows :data:`RETRIES` such losses per task, a remote scheduler its own setting), then
    :class:`RbgpRuntimeError` names it (``label(index)``); with no live worker for
    :data:`NO_WORKER_TIMEOUT` seconds the study fails too. Dask's log lines stay off stderr unless
    RBGP_DEBUG is set. On an error, or when the caller stops iterating, the pending tasks are
    cancelled. Raises :class:`InputError` when ``distributed`` is not installed or the scheduler
    cannot be reached.
    """
    import time

    from rbgp_cli.errors import InputError, RbgpRuntimeError

    try:
        import dask
        from distributed import Client, LocalCluster, wait
    except ImportError:
        raise InputError("--scheduler needs Dask's distributed scheduler, which is not installed",
                         hint='pip install "rbgp-cli[distributed]"') from None
    cluster = None
    restore = _quiet_dask()
    try:
        if scheduler == "local":
            n = max(1, min(int(jobs or os.cpu_count() or 1), len(args)))
            try:
                # the workers' stderr to /dev/null: a Ctrl-C while they import prints their tracebacks
                with dask.config.set({"distributed.scheduler.allowed-failures": RETRIES}), _children_stderr_off():
                    cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None)
            except BaseException as exc:  # Ctrl-C, or e.g. a worker killed while it started ("Nanny failed")
                _forget_half_started_clusters()
                if not isinstance(exc, Exception):
                    raise
                raise RbgpRuntimeError(f"the local Dask cluster did not start ({type(exc).__name__}: {exc})",
                                       hint="run without --scheduler") from exc
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
            pending, alone_since = set(futs), None
            try:
                while pending:
                    try:
                        done, pending = wait(pending, timeout=1.0, return_when="FIRST_COMPLETED")
                    except TimeoutError:
                        done = set()
                    if not done:  # nothing finished this second: is anyone still working?
                        if client.nthreads():
                            alone_since = None
                        elif alone_since is None:
                            alone_since = time.monotonic()
                        elif time.monotonic() - alone_since > NO_WORKER_TIMEOUT:
                            raise RbgpRuntimeError(
                                f"no Dask worker left for {NO_WORKER_TIMEOUT:g} s; unfinished: "
                                f"{_names([index[f.key] for f in pending], label)}",
                                hint="check the cluster's workers (killed, or out of memory?)")
                        continue
                    alone_since = None
                    for fut in sorted(done, key=lambda f: index[f.key]):
                        i = index[fut.key]
                        try:
                            r = fut.result()
                        except (InputError, RbgpRuntimeError):
                            raise
                        except Exception as exc:
                            if type(exc).__name__ == "KilledWorker":
                                raise RbgpRuntimeError(f"{_names([i], label)} was lost with its Dask worker "
                                                       "(killed, or out of memory) on every try",
                                                       hint="check the cluster's memory, or run without --scheduler"
                                                       ) from None
                            # a task that failed on a worker fails the study, as in-process
                            raise RbgpRuntimeError(f"a task failed on a Dask worker: {type(exc).__name__}: {exc}") from exc
                        yield i, r
            finally:
                client.cancel([f for f in futs if not f.done()])
    except BaseException as exc:
        if not isinstance(exc, Exception):  # interrupted: the process ends, and the cluster's workers
            restore = lambda: None  # noqa: E731 - report their ends while it does; keep Dask quiet
        raise
    finally:
        if cluster is not None:
            cluster.close()
        restore()
