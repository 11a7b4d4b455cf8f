"""Compute: cores, BLAS threads, thread and process pools, and the hand-off to Dask — the one place
rbgp decides where work runs (the maths modules only call these helpers).

* **Cores and BLAS.** :func:`usable_cores` (the affinity mask), :func:`free_cores` (minus the other
  runnable tasks right now), :func:`blas_threads` (single-threaded BLAS for small problems, in worker
  processes and on a busy machine), :func:`in_worker_process`, :func:`default_jobs` (worker processes
  for independent fits, bounded by memory and never nested).
* **Thread pools.** :func:`thread_pool` gives one small named pool per process (row blocks of
  pairwise distances, chunks of GP predictions: numpy's ufuncs and BLAS release the GIL), and
  :func:`thread_workers` how many threads a piece of work should use.
* **Process pools and Dask.** Studies (``rbgp crossval``: configurations × folds) and the exact GP's
  per-output fits are lists of independent tasks. :func:`run_tasks` hands them to one of three
  executors — this process, local worker processes (the standard library's ``ProcessPoolExecutor``,
  :func:`iter_processes`), or a Dask distributed cluster (:func:`iter_dask`) — and returns the
  results in the order of the tasks, whatever the order they finish in; BLAS runs single-threaded
  inside every worker (the tasks are the parallelism).

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

__all__ = ["usable_cores", "free_cores", "free_cores_recently", "in_worker_process", "available_memory",
           "blas_threads", "one_thread", "blas_pools", "default_jobs", "thread_pool", "thread_workers", "fork_context", "worker_init",
           "run_tasks", "iter_processes", "iter_dask", "single_threaded", "die_with_parent", "process_pool",
           "start_workers", "stop_pool", "ending_on_sigterm"]


# ----------------------------------------------------------------------------- cores and BLAS
def usable_cores() -> int:
    """CPUs this process may run on (its affinity mask where the OS has one)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def _runnable_tasks() -> tuple[int, int]:
    """Linux: one scan of /proc/PID/task/TID/stat for the runnable tasks (threads in state R) that do not
    take a core from rbgp: (own, yielding). ``own``: this process's threads, the calling one included.
    OpenBLAS's threads spin for a while after a multi-threaded call and are runnable then: counted as
    other programs' tasks they made a machine with nothing else running look busy (the calibration after
    the posterior's threaded factorisations ran on one thread). ``yielding``: other processes' tasks with
    a higher nice value than this process's: the scheduler gives them a small share of a core this
    process wants (nice 19 against 0: about 1.5 %), so they do not make a core busy for rbgp.
    (0, 0) where /proc cannot be read (yielding 0 where the priority cannot be read)."""
    import glob

    try:
        mine = os.getpriority(os.PRIO_PROCESS, 0)
    except (AttributeError, OSError):
        mine = None
    me = f"/proc/{os.getpid()}/"
    own = yielding = 0
    for path in glob.glob("/proc/[0-9]*/task/[0-9]*/stat"):
        try:
            with open(path, "rb") as fh:
                fields = fh.read().rsplit(b")", 1)[1].split()
        except (OSError, IndexError):
            continue  # the task ended while we looked
        # after the command: state (field 3 of proc(5)), …, nice (field 19)
        if not fields or fields[0] != b"R":
            continue
        if path.startswith(me):
            own += 1
        elif mine is not None and len(fields) > 16 and int(fields[16]) > mine:
            yielding += 1
    return own, yielding


def _own_runnable() -> int:
    """This process's runnable threads, the calling one included (:func:`_runnable_tasks`)."""
    return _runnable_tasks()[0]


def _yielding_runnable() -> int:
    """Other processes' runnable tasks niced below this process (:func:`_runnable_tasks`)."""
    return _runnable_tasks()[1]


def free_cores() -> int:
    """Usable cores that no other runnable task is using right now (at least 1).

    Linux: the usable cores minus the other runnable tasks of the instantaneous count in
    /proc/loadavg, not counting this process's own threads (BLAS threads spinning after a threaded
    call) nor tasks niced below this process (one scan of /proc finds both, :func:`_runnable_tasks`: a
    ``nice -n 19`` batch job beside ``rbgp train`` would otherwise make it fit on one thread while
    the job yields its core); elsewhere minus the 1-minute load average."""
    cores = usable_cores()
    try:
        with open("/proc/loadavg") as fh:
            others = int(fh.read().split()[3].split("/")[0]) - 1  # the count includes this process
        if others > 0:  # the scan costs ~4 ms on a desktop's few hundred tasks: only when it can matter
            own, yielding = _runnable_tasks()
            others -= max(0, own - 1) + yielding
    except (OSError, ValueError, IndexError):
        try:
            others = int(round(os.getloadavg()[0]))
        except (AttributeError, OSError):
            others = 0
    return max(1, cores - max(0, others))


#: Seconds for which :func:`free_cores_recently` reuses a look-up (a rollout step takes ~0.5 ms).
FREE_CORES_TTL = 0.2
_FREE_CORES = [float("-inf"), 1]


def free_cores_recently() -> int:
    """:func:`free_cores`, reused for FREE_CORES_TTL seconds (reading /proc/loadavg costs ~7 µs, the scan for niced
    tasks on a busy machine ~4 ms)."""
    import time

    now = time.monotonic()
    if now - _FREE_CORES[0] > FREE_CORES_TTL:
        _FREE_CORES[:] = [now, free_cores()]
    return _FREE_CORES[1]


def in_worker_process() -> bool:
    """True in a process started by multiprocessing (rbgp's pools, Dask's workers): it runs one task
    per core already, so it starts no threads or pools of its own."""
    import multiprocessing

    return multiprocessing.parent_process() is not None


def available_memory() -> int | None:
    """Bytes of memory available to new processes (Linux: MemAvailable), or None if unknown."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return int(os.sysconf("SC_AVPHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (AttributeError, OSError, ValueError):
        return None


#: Below this many training points BLAS/LAPACK runs single-threaded: a multi-threaded OpenBLAS costs more
#: in synchronisation than it saves on small matrices, and on a loaded machine its spin-waiting made
#: one NLML evaluation at n = 80 take 8–150 ms instead of 0.5 ms (measured).
SINGLE_THREAD_BELOW = 700
_CONTROLLER = []


def blas_threads(n: int):
    """Context manager: BLAS/LAPACK single-threaded for problems with n < SINGLE_THREAD_BELOW points
    (n = 0 forces it), inside worker processes, and when fewer than two cores are free (a
    multi-threaded OpenBLAS pool spin-waits for its threads; on a busy machine they lose whole time
    slices: one NLML evaluation at n = 1752 took 0.93 s with 2 threads instead of 0.23 s with one,
    measured at load 4). Otherwise the pools are left as they are. The threadpoolctl controller is
    built once: building it scans the loaded libraries (about 0.9 ms), reusing it costs about 0.015 ms."""
    import contextlib

    if n >= SINGLE_THREAD_BELOW and not in_worker_process() and free_cores() >= 2:
        return contextlib.nullcontext()
    if not _CONTROLLER:
        try:
            from threadpoolctl import ThreadpoolController
        except ImportError:  # pragma: no cover - threadpoolctl is a dependency; stay usable without it
            return contextlib.nullcontext()
        _CONTROLLER.append(ThreadpoolController())
    return _CONTROLLER[0].limit(limits=1, user_api="blas")


#: n × n float64 matrices a worker holds at once while fitting one GP output on n points (distances,
#: K, C, C⁻¹ / W, W ∘ K and the factor it returns).
WORKER_MATRICES = 6


def default_jobs(tasks: int, n: int | None = None) -> int:
    """Worker processes for ``tasks`` independent fits on ``n`` points each: one per task, at most one
    per usable core, while half the available memory holds them (WORKER_MATRICES n × n matrices
    each); 1 inside a worker process, so that pools never nest (e.g. under cross-validation folds
    that run in workers of their own), and 1 on a single core.

    No more workers than cores: the fits are CPU-bound (BLAS single-threaded in each worker), so more
    add nothing on an idle machine, and on a busy one six workers on two cores took a larger share
    of the cores from the other programs than rbgp's own (issue 35: the paper-scale run at load 4–9
    took 57–116 s where the same machine quiet took 13 s)."""
    if tasks <= 1 or in_worker_process() or usable_cores() < 2:
        return 1
    jobs = min(int(tasks), usable_cores())
    if n:
        avail = available_memory()
        if avail is not None:
            jobs = min(jobs, max(1, int(0.5 * avail // (WORKER_MATRICES * 8 * n * n))))
    return max(1, jobs)


# ----------------------------------------------------------------------------- thread pools
#: Threads of every :func:`thread_pool` (at most this many, and at most the CPU count).
POOL_THREADS = 4
_THREAD_POOLS: dict = {}


def thread_pool(name: str):
    """The process's shared ``ThreadPoolExecutor`` called ``name`` (created on first use, and again
    in a forked child). Work that submits to one pool and waits must not run on the same pool: the
    GP's prediction chunks (pool "predict") wait for distance blocks (pool "distance")."""
    from concurrent.futures import ThreadPoolExecutor

    pool = _THREAD_POOLS.get(name)
    if pool is None or pool[1] != os.getpid():
        pool = (ThreadPoolExecutor(max_workers=max(1, min(POOL_THREADS, os.cpu_count() or 1)),
                                   thread_name_prefix=f"rbgp-{name}"), os.getpid())
        _THREAD_POOLS[name] = pool
    return pool[0]


def thread_workers(work: int, min_work: int) -> int:
    """Threads for ``work`` units (e.g. query × training pairs): the cores free right now (at most
    POOL_THREADS; :func:`free_cores_recently`) when ``work`` ≥ ``min_work``, else 1; and 1 in worker
    processes, which run one per core already. Such threads do not spin, but they only pay where a
    core is free."""
    if work < min_work or in_worker_process():
        return 1
    return max(1, min(POOL_THREADS, free_cores_recently()))


# ----------------------------------------------------------------------------- process pools
def fork_context():
    """The multiprocessing context for short-lived workers that read this process's arrays: fork on
    Linux (a worker starts in milliseconds and reads the parent's memory copy-on-write), spawn
    elsewhere (macOS, Windows: fork is unsafe or missing)."""
    import multiprocessing

    if sys.platform.startswith("linux"):
        return multiprocessing.get_context("fork")
    return multiprocessing.get_context("spawn")


#: How long to wait for a Dask scheduler given by address.
CONNECT_TIMEOUT = "10s"


def one_thread():
    """Context manager: every BLAS and OpenMP pool limited to one thread (threadpoolctl) while the block
    runs; a no-op without threadpoolctl."""
    import contextlib

    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # pragma: no cover - threadpoolctl is a dependency
        return contextlib.nullcontext()
    return threadpool_limits(limits=1)


def blas_pools() -> list[dict]:
    """The BLAS/OpenMP pools loaded in this process: ``[{"library", "api", "threads"}]`` (threadpoolctl)."""
    try:
        from threadpoolctl import threadpool_info
    except ImportError:  # pragma: no cover - threadpoolctl is a dependency
        return []
    return [{"library": os.path.basename(d.get("filepath", "")), "api": d.get("internal_api"),
             "threads": d.get("num_threads")} for d in threadpool_info()]


def single_threaded(fn, args):
    """``fn(args)`` with BLAS/OpenMP pools limited to one thread (for workers)."""
    with one_thread():
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


def worker_init() -> None:
    """Local worker processes' start-up: BLAS single-threaded for the worker's lifetime (and, through
    :func:`in_worker_process`, no thread pools of its own)."""
    worker_init.limits = one_thread()  # a threadpoolctl limit applies as it is made; kept alive here


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
    """End a process pool now: cancel what has not started, terminate the running workers (on an
    error or an interrupt; ``shutdown(wait=True)`` would wait for their fits to finish) and wait for
    the pool's manager thread to end, so that nothing of the pool is left for the exit handlers."""
    workers = list((getattr(pool, "_processes", None) or {}).values())
    manager = getattr(pool, "_executor_manager_thread", None)  # shutdown() forgets it
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
    # The pool's manager thread notices the terminated workers and closes its wake-up pipe; at exit the
    # standard library writes to every pool's pipe unlocked (3.11), so a SIGTERM exit that overtook the
    # closing printed an "OSError: Bad file descriptor" traceback. Waiting for the thread here settles it.
    if manager is not None:
        try:
            manager.join(5.0)
        except RuntimeError:  # not started
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
        n_jobs = jobs if jobs is not None else min(len(args), usable_cores())
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


def iter_processes(fn, args, n_jobs: int, *, label=None, init=worker_init):
    """Yield ``(index, fn(args[index]))`` as the tasks finish in ``n_jobs`` worker processes
    (:func:`process_pool` in :func:`fork_context`: forked on Linux, where a worker has no start-up
    message to read from its parent, so one killed at any moment leaves no worker printing
    multiprocessing's ``EOFError`` traceback; BLAS single-threaded). A pool that loses a worker (killed, out of
    memory) is started again for the unfinished tasks, :data:`RETRIES` times; then
    :class:`RbgpRuntimeError` names them. On any other error, Ctrl-C or SIGTERM the pending tasks are
    cancelled and the workers terminated at once."""
    from concurrent.futures import as_completed
    from concurrent.futures.process import BrokenProcessPool

    from rbgp_cli.errors import RbgpRuntimeError

    todo = list(range(len(args)))
    for attempt in range(RETRIES + 1):
        pool = process_pool(max(1, min(n_jobs, len(todo))), context=fork_context(), init=init)
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
                           f"unfinished: {_names(todo, label)}", hint="if memory is short, use fewer jobs", param="jobs")


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


def _dask_result(fut, i: int, label):
    """The result of task ``i``'s finished future; its InputError or RbgpRuntimeError as raised, any
    other failure (the worker lost on every try, or an exception in the task) as RbgpRuntimeError."""
    from rbgp_cli.errors import InputError, RbgpRuntimeError

    try:
        r = fut.result()
    except (InputError, RbgpRuntimeError):
        raise
    except Exception as exc:
        if _scheduler_lost(exc):
            raise _lost_scheduler_error(label, [i]) from None
        if type(exc).__name__ == "KilledWorker":
            raise RbgpRuntimeError(f"{_names([i], label)} was lost with its Dask worker "
                                   "(killed, or out of memory) on every try",
                                   hint="check the cluster's memory, or run without scheduler",
                                   param="scheduler") from None
        # a task that failed on a worker fails the study, as in-process
        raise RbgpRuntimeError(f"a task failed on a Dask worker: {type(exc).__name__}: {exc}") from exc
    return r


def _scheduler_lost(exc: BaseException) -> bool:
    """True for what a client raises when its scheduler is gone: its futures cancelled
    (``FuturesCancelledError``, a ``CancelledError``), the connection closed or refused."""
    from concurrent.futures import CancelledError

    names = {type(e).__name__ for e in type(exc).__mro__}
    return (isinstance(exc, (CancelledError, OSError, TimeoutError))
            or bool(names & {"FuturesCancelledError", "CommClosedError", "CancelledError"}))


def _lost_scheduler_error(label, unfinished):
    from rbgp_cli.errors import RbgpRuntimeError

    what = f"; unfinished: {_names(unfinished, label)}" if unfinished else ""
    return RbgpRuntimeError(f"lost the Dask scheduler (stopped or killed) while the tasks ran{what}",
                            hint="restart it, or run without scheduler", param="scheduler")


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
        raise InputError("scheduler needs Dask's distributed scheduler, which is not installed",
                         hint='pip install "rbgp-cli[distributed]"', param="scheduler") from None
    cluster = None
    restore = _quiet_dask()
    try:
        if scheduler == "local":
            n = max(1, min(int(jobs or usable_cores()), len(args)))
            try:
                # the workers' stderr to /dev/null: a Ctrl-C while they import prints their tracebacks
                with dask.config.set({"distributed.scheduler.allowed-failures": RETRIES}), _children_stderr_off():
                    cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None)
            except BaseException as exc:  # Ctrl-C, or e.g. a worker killed while it started ("Nanny failed")
                _forget_half_started_clusters()
                if not isinstance(exc, Exception):
                    raise
                raise RbgpRuntimeError(f"the local Dask cluster did not start ({type(exc).__name__}: {exc})",
                                       hint="run without scheduler", param="scheduler") from exc
            client = Client(cluster)
        else:
            try:
                client = Client(scheduler, timeout=CONNECT_TIMEOUT)
            except (OSError, TimeoutError, ValueError) as exc:
                raise InputError(f"cannot reach the Dask scheduler at {scheduler!r} ({type(exc).__name__}); start one "
                                 "with 'dask scheduler' (and workers with 'dask worker ADDRESS')",
                                 hint="or use scheduler local", param="scheduler") from None
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
                        yield i, _dask_result(fut, i, label)
            except (InputError, RbgpRuntimeError):
                raise
            except Exception as exc:  # wait() or nthreads() with the scheduler gone
                if not _scheduler_lost(exc):
                    raise
                raise _lost_scheduler_error(label, sorted(index[f.key] for f in pending)) from None
            finally:
                try:
                    client.cancel([f for f in futs if not f.done()])
                except Exception:  # noqa: BLE001 - the scheduler is gone: nothing left to cancel
                    pass
    except BaseException as exc:
        if not isinstance(exc, Exception):  # interrupted: the process ends, and the cluster's workers
            restore = lambda: None  # noqa: E731 - report their ends while it does; keep Dask quiet
        raise
    finally:
        if cluster is not None:
            cluster.close()
        restore()
