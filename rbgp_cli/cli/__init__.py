"""rbgp_cli.cli"""

import os as _os
import signal as _signal

_INTERRUPTED = b"rbgp: interrupted\n"


def _exit_now(signum, frame):  # pragma: no cover - runs in a process that then ends
    if signum == _signal.SIGINT:
        _os.write(2, _INTERRUPTED)
    _os._exit(128 + signum)


#: Exit codes of a run ended by a signal: Ctrl-C (130) and SIGTERM (143).
SIGNAL_EXITS = (128 + _signal.SIGINT, 128 + _signal.SIGTERM)


def end_signalled_run(code: int) -> None:  # pragma: no cover - ends the process (tested in a subprocess)
    """End a run that a signal interrupted, once the command has cleaned up (its pools stopped, its
    temporary files removed): Python's exit functions run and the standard streams are flushed, then
    the process ends with ``code`` without the C-level teardown. That teardown destroys native thread
    pools (Arrow's, loaded by pandas) whose threads an interruption can leave running, and libstdc++
    then aborts the process ("terminate called without an active exception", exit −6 instead of 130;
    seen once in CI, in a Ctrl-C during training)."""
    import atexit
    import sys

    run_exit_functions = getattr(atexit, "_run_exitfuncs", None)  # CPython's; elsewhere: none to run
    try:
        if run_exit_functions is not None:
            run_exit_functions()
    except BaseException:  # noqa: BLE001 - a second Ctrl-C during the exit functions: end anyway
        pass
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (AttributeError, OSError, ValueError):
            pass
    _os._exit(code)


def exit_on_signals() -> None:
    """First thing in the entry points (``rbgp``, ``python -m rbgp_cli``): until a command runs
    (imports, parsing), Ctrl-C prints ``rbgp: interrupted`` and exits 130 and SIGTERM exits 143, at
    once and without a traceback (nothing is written yet). The command wrapper
    (:func:`rbgp_cli.cli.common.command`) turns them into KeyboardInterrupt / SystemExit while the
    command runs, so that its pools and temporary files are cleaned up, and restores these after."""
    try:
        _signal.signal(_signal.SIGINT, _exit_now)
        _signal.signal(_signal.SIGTERM, _exit_now)
    except (ValueError, OSError):  # not the main thread (embedded use)
        pass
    occupy_closed_streams()


#: The standard streams (0, 1, 2) that were closed when rbgp started (``>&-``, ``<&-``).
CLOSED_STREAMS: set = set()


def occupy_closed_streams() -> None:
    """Open the null device on a standard file descriptor that was closed when the process started
    (``rbgp rollout -o - >&-``), and note it in :data:`CLOSED_STREAMS`: otherwise the next file opened
    (a model's temporary file, a worker's pipe) would get descriptor 1 and anything written to
    stdout would land in it. Python then has ``sys.stdout = None``; the command wrapper turns a write
    to it into one error line (:func:`rbgp_cli.cli.common.command`)."""
    for fd in (0, 1, 2):
        try:
            _os.fstat(fd)
        except OSError:
            try:
                null = _os.open(_os.devnull, _os.O_RDONLY if fd == 0 else _os.O_WRONLY)
                if null != fd:
                    _os.dup2(null, fd)
                    _os.close(null)
            except OSError:  # pragma: no cover - no /dev/null
                continue
            CLOSED_STREAMS.add(fd)


#: glibc's mallopt parameter M_MMAP_THRESHOLD, and the size from which a block gets its own mapping.
_M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD_BYTES = 128 * 1024


def return_freed_memory() -> None:
    """Fix glibc's mmap threshold at 128 KiB (its initial value), so that every freed array of that size
    or more goes back to the system at once. Left dynamic, glibc raises the threshold up to 32 MiB after
    the first big array is freed; later arrays of a few MB to 32 MB (a 10⁶-row file's columns and
    quaternions) then come from the heap, whose freed space the process keeps: `rbgp train` on a
    10⁶-row CSV held ~180 MB more than it used (benchmarks/bench_memory.py). No effect off glibc."""
    import ctypes
    import ctypes.util

    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        libc.mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)
    except (OSError, AttributeError):  # not glibc (musl, macOS, Windows): their allocators differ
        pass
