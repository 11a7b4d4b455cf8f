"""rbgp_cli.cli"""

import os as _os
import signal as _signal

_INTERRUPTED = b"rbgp: interrupted\n"


def _exit_now(signum, frame):  # pragma: no cover - runs in a process that then ends
    if signum == _signal.SIGINT:
        _os.write(2, _INTERRUPTED)
    _os._exit(128 + signum)


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
