"""Atomic output: every file rbgp writes (models, CSVs, recordings, figures) appears whole or not at all.

Write to a temporary file in the destination's directory, flush and fsync, give it the mode a plain
``open(path, "w")`` would give (an existing destination's own mode, else ``0o666 & ~umask``), then
``os.replace`` it onto the destination. On any exception the temporary file is removed and the
destination is untouched.

A destination that exists and is not a regular file (``/dev/null``, ``/dev/full``, a FIFO) is written
*into*, never replaced: renaming onto ``/dev/null`` as root would break it for every other program.
The output is made in a private temporary file and its bytes copied into the device (a FIFO with no
reader is refused after :data:`FIFO_READER_WAIT_S` seconds; ``/dev/full`` is "no space left").

A write that fails for a reason of the file system (no space left, the file-size limit, no
permission, a read-only file system, the folder gone) is one :class:`~rbgp_cli.errors.RbgpError`
``cannot write PATH: <reason>``: exit code 2 (:class:`~rbgp_cli.errors.InputError`) for what the
user fixes by choosing another path (permission, read-only, missing folder), 1
(:class:`~rbgp_cli.errors.RbgpRuntimeError`) for the machine's limits (space, quota, size limit, I/O).
"""

from __future__ import annotations

import contextlib
import errno
import os
import stat
import tempfile
from pathlib import Path

from rbgp_cli.errors import InputError, RbgpRuntimeError

__all__ = ["atomic_path", "atomic_open", "atomic_dir", "new_file_mode", "write_error"]

#: Write failures of the chosen path: another path fixes them (exit code 2).
_PATH_ERRNOS = frozenset({errno.EACCES, errno.EPERM, errno.EROFS, errno.ENOENT, errno.ENOTDIR, errno.EISDIR})
#: Write failures of the machine: space, quota, the file-size limit, the device (exit code 1).
_LIMIT_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EIO})


def _umask() -> int:
    """The process's umask, read without changing it where Linux shows it (``os.umask`` sets it, and
    another thread creating a file in between would get the temporary value)."""
    try:
        with open("/proc/self/status", encoding="ascii", errors="replace") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    old = os.umask(0o022)
    os.umask(old)
    return old


def new_file_mode(path) -> int:
    """The permission bits ``open(path, "w")`` leaves ``path`` with: an existing file's own, else
    ``0o666 & ~umask`` (0o644 under the usual umask 022)."""
    try:
        st = os.stat(path)
    except OSError:
        return 0o666 & ~_umask()
    # (the permission bits only: writing a file clears its set-user/group-id bits)
    return st.st_mode & 0o777 if stat.S_ISREG(st.st_mode) else 0o666 & ~_umask()


def write_error(dest, exc: OSError):
    """``cannot write PATH: reason`` as the error class its errno calls for."""
    cls = InputError if exc.errno in _PATH_ERRNOS else RbgpRuntimeError
    return cls(f"cannot write {dest}: {exc.strerror or exc}")


@contextlib.contextmanager
def _temporary_file(dest: Path, prefix: str, suffix: str, directory=None):
    """Create an empty temporary file (``tempfile.mkstemp(prefix, suffix, dir=directory)``; None: the
    system's temporary folder), yield its path, and remove it however the block ends (a file the block
    renamed onto ``dest`` is no longer there to remove). A file-system failure creating it, or one the
    writer raises with a path or limit errno, is ``cannot write DEST: <reason>`` (:func:`write_error`)."""
    try:
        fd, tmp = tempfile.mkstemp(prefix=prefix, suffix=suffix, dir=directory)
    except OSError as exc:
        raise write_error(dest, exc) from None
    os.close(fd)
    try:
        yield Path(tmp)
    except OSError as exc:
        if exc.errno in _PATH_ERRNOS or exc.errno in _LIMIT_ERRNOS:
            raise write_error(dest, exc) from None
        raise
    finally:
        with contextlib.suppress(OSError):
            os.unlink(tmp)


@contextlib.contextmanager
def atomic_path(path, suffix: str | None = None):
    """Yield a temporary path beside ``path``; on success fsync it, give it the mode of a plain
    ``open(path, "w")`` (:func:`new_file_mode`) and rename it onto ``path``.

    For writers that want a file name (e.g. rerun's ``save``, matplotlib's ``savefig``). ``suffix``
    defaults to the destination's suffix so that libraries that look at it still work. A file-system
    failure anywhere (creating, writing, syncing, renaming) is ``cannot write PATH: <reason>``.
    """
    dest = Path(path)
    if _not_a_regular_file(dest):  # /dev/null, /dev/full, a FIFO: written into, never replaced
        with _into_special(dest, suffix) as tmp:
            yield tmp
        return
    directory = dest.parent if str(dest.parent) else Path(".")
    suffix = (dest.suffix if suffix is None else suffix) + ".tmp"
    remove_stale(directory, dest.name, suffix)
    # the writer's pid in the name: a later write can tell a killed writer's leftover from a live one
    with _temporary_file(dest, f".{dest.name}.{os.getpid()}-", suffix, directory) as tmp:
        yield tmp
        try:
            fd = os.open(tmp, os.O_RDONLY)  # the writer may be a library that closed the file itself
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
            os.chmod(tmp, new_file_mode(dest))
            os.replace(tmp, dest)
        except OSError as exc:
            raise write_error(dest, exc) from None


def _not_a_regular_file(dest: Path) -> bool:
    """True when ``dest`` exists (after symlinks) and is neither a regular file nor a directory: a
    device or a FIFO, which a rename would replace (``/dev/null`` for every other program)."""
    try:
        mode = os.stat(dest).st_mode
    except (OSError, ValueError):
        return False
    return not (stat.S_ISREG(mode) or stat.S_ISDIR(mode))


#: Seconds a FIFO given as the output waits for a reader before it is refused.
FIFO_READER_WAIT_S = 1.0


def _open_special(dest: Path) -> int:
    """A descriptor open for writing on the device or FIFO ``dest`` (no truncation, no creation). A
    FIFO nobody reads from is refused after :data:`FIFO_READER_WAIT_S` seconds instead of blocking."""
    import time

    mode = os.stat(dest).st_mode
    if not stat.S_ISFIFO(mode):
        return os.open(dest, os.O_WRONLY)
    deadline = time.monotonic() + FIFO_READER_WAIT_S
    while True:
        try:
            fd = os.open(dest, os.O_WRONLY | os.O_NONBLOCK)
        except OSError as exc:
            if exc.errno != errno.ENXIO:  # ENXIO: no reader yet
                raise
            if time.monotonic() > deadline:
                raise InputError(f"cannot write {dest}: nothing reads from this FIFO (named pipe)",
                                 hint="start the program that reads it first, or write to a file") from None
            time.sleep(0.02)
            continue
        os.set_blocking(fd, True)
        return fd


@contextlib.contextmanager
def _into_special(dest: Path, suffix: str | None):
    """:func:`atomic_path` for a device or FIFO: the writer writes a private temporary file (outside
    the device's folder), whose bytes are then copied into ``dest``, which is never renamed onto,
    truncated or chmod-ed. Whole-or-nothing cannot hold for a device; a failure before the copy
    writes nothing into it."""
    import shutil

    suffix = (dest.suffix if suffix is None else suffix) + ".tmp"
    with _temporary_file(dest, f".rbgp-{os.getpid()}-", suffix) as tmp:
        yield tmp
        try:
            out = _open_special(dest)
            with open(tmp, "rb") as src, os.fdopen(out, "wb") as dst:
                shutil.copyfileobj(src, dst, 1 << 20)
        except BrokenPipeError:
            raise InputError(f"cannot write {dest}: the program reading the FIFO went away") from None
        except OSError as exc:
            raise write_error(dest, exc) from None


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
    without an exception (after closing and fsync: :func:`atomic_path`)."""
    if "w" not in mode:
        raise ValueError("atomic_open is for writing ('w' or 'wb')")
    with atomic_path(path) as tmp:
        with open(tmp, mode, **kwargs) as fh:
            yield fh


@contextlib.contextmanager
def atomic_dir(path):
    """Yield a temporary folder beside ``path`` to fill; on success fsync its files and rename it onto
    ``path`` (which must not exist, or be an empty folder: a non-empty one is never replaced). For
    outputs that are a folder (a rosbag2 bag). On any exception the temporary folder is removed."""
    import shutil

    dest = Path(path)
    directory = dest.parent if str(dest.parent) else Path(".")
    if dest.is_dir() and any(dest.iterdir()):
        raise InputError("the output folder exists and is not empty", path=str(dest),
                         hint="give a new folder name (or remove the old one)")
    if dest.exists() and not dest.is_dir():
        raise InputError("exists and is not a folder", path=str(dest), hint="give a new folder name")
    try:
        tmp = Path(tempfile.mkdtemp(prefix=f".{dest.name}.{os.getpid()}-", suffix=".tmp", dir=directory))
    except OSError as exc:
        raise write_error(dest, exc) from None
    try:
        try:
            yield tmp
        except OSError as exc:
            if exc.errno in _PATH_ERRNOS or exc.errno in _LIMIT_ERRNOS:
                raise write_error(dest, exc) from None
            raise
        try:
            for entry in tmp.iterdir():
                fd = os.open(entry, os.O_RDONLY)
                try:
                    os.fsync(fd)
                finally:
                    os.close(fd)
                os.chmod(entry, new_file_mode(dest / entry.name))
            os.chmod(tmp, 0o777 & ~_umask())
            os.replace(tmp, dest)  # an empty folder at dest is replaced; POSIX rename
        except OSError as exc:
            raise write_error(dest, exc) from None
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
