"""Atomic output: every file rbgp writes (models, CSVs, recordings, figures) appears whole or not at all.

Write to a temporary file in the destination's directory, flush and fsync, then ``os.replace`` it onto
the destination. On any exception the temporary file is removed and the destination is untouched.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path

__all__ = ["atomic_path", "atomic_open"]


@contextlib.contextmanager
def atomic_path(path, suffix: str | None = None):
    """Yield a temporary path beside ``path``; on success rename it onto ``path``.

    For writers that want a file name (e.g. rerun's ``save``, matplotlib's ``savefig``). ``suffix``
    defaults to the destination's suffix so that libraries that look at it still work.
    """
    dest = Path(path)
    directory = dest.parent if str(dest.parent) else Path(".")
    suffix = (dest.suffix if suffix is None else suffix) + ".tmp"
    remove_stale(directory, dest.name, suffix)
    # the writer's pid in the name: a later write can tell a killed writer's leftover from a live one
    fd, tmp = tempfile.mkstemp(prefix=f".{dest.name}.{os.getpid()}-", suffix=suffix, dir=directory)
    os.close(fd)
    try:
        yield Path(tmp)
        os.replace(tmp, dest)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


#: A leftover temporary file without a pid in its name (older rbgp) is stale after this many seconds.
STALE_S = 60.0


def remove_stale(directory, name: str, suffix: str) -> None:
    """Remove what killed writers of ``directory/name`` left (SIGKILL gives no chance to clean up):
    ``.NAME.PID-XXXX<suffix>`` whose PID is no live process, and ``.NAME.XXXX<suffix>`` older than
    :data:`STALE_S` seconds. Best effort: a file that cannot be removed stays."""
    import re
    import time

    pattern = re.compile(rf"\.{re.escape(name)}\.(?:(\d+)-)?[A-Za-z0-9_]+{re.escape(suffix)}")
    try:
        entries = list(os.scandir(directory))
    except OSError:
        return
    for entry in entries:
        m = pattern.fullmatch(entry.name)
        if m is None:
            continue
        with contextlib.suppress(OSError):
            if m.group(1) is not None:
                if _alive(int(m.group(1))):
                    continue
            elif time.time() - entry.stat(follow_symlinks=False).st_mtime < STALE_S:
                continue
            os.unlink(entry.path)


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError, OSError):
        return True  # someone else's process, or cannot tell: leave the file
    return True


@contextlib.contextmanager
def atomic_open(path, mode: str = "w", **kwargs):
    """Open a temporary file beside ``path`` for writing; rename it onto ``path`` when the block ends
    without an exception (after flush + fsync)."""
    if "w" not in mode:
        raise ValueError("atomic_open is for writing ('w' or 'wb')")
    with atomic_path(path) as tmp:
        with open(tmp, mode, **kwargs) as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
