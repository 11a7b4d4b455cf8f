"""Inputs that are not regular files: named pipes (FIFOs, ``<(cat demo.csv)``), devices, closed stdin.

A FIFO or a pipe is read as a stream, once, front to back, like stdin: ``rbgp train <(cat demo.csv)``
and ``mkfifo f; cat demo.csv > f & rbgp train f`` work. Opening a FIFO nobody writes to would block
forever, so it is opened without blocking and refused after :data:`FIFO_WAIT_S` seconds without a
writer. A device (``/dev/zero``, a disk) is no data file and is refused at once; so is stdin when it
was closed (``<&-``).
"""

from __future__ import annotations

import io
import os
import select
import stat
import sys
import time

from rbgp_cli.errors import InputError

__all__ = ["FIFO_WAIT_S", "PrefixedRaw", "is_stream_path", "open_stream_path", "stdin_stream"]

#: Seconds a FIFO with no writer is waited for before it is refused.
FIFO_WAIT_S = 1.0


def is_stream_path(path) -> bool:
    """True for a path that exists and is not a regular file or a directory (a FIFO, a pipe, a socket
    or a device): it is read with :func:`open_stream_path`, never by size or by seeking."""
    try:
        mode = os.stat(path).st_mode
    except (OSError, ValueError):
        return False
    return not (stat.S_ISREG(mode) or stat.S_ISDIR(mode))


class PrefixedRaw(io.RawIOBase):
    """The bytes already read (``head``), then the rest of ``source``: a file descriptor (an int, read
    with ``os.read`` (blocking) and closed with this stream) or a binary stream (its ``read``; left
    open). Not seekable: what a format sniffer read from a FIFO or stdin is given back this way."""

    def __init__(self, head: bytes, source):
        self._head = head
        self._source = source

    def readable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return False

    def readinto(self, b) -> int:
        if self._head:
            k = min(len(b), len(self._head))
            b[:k] = self._head[:k]
            self._head = self._head[k:]
            return k
        fd = self._source if isinstance(self._source, int) else None
        data = os.read(fd, len(b)) if fd is not None else self._source.read(len(b))
        if not data:
            return 0
        b[: len(data)] = data
        return len(data)

    def fileno(self) -> int:
        if isinstance(self._source, int):
            return self._source
        return super().fileno()  # io.UnsupportedOperation: a stream's descriptor is not ours to hand out

    def close(self) -> None:
        if not self.closed and isinstance(self._source, int):
            try:
                os.close(self._source)
            except OSError:
                pass
        super().close()


def open_stream_path(path, what: str = "file"):
    """Open a path that is not a regular file (:func:`is_stream_path`) as a binary stream.

    A FIFO or pipe: opened without blocking; a writer present (or data waiting) gives a blocking
    stream of everything it writes; none within :data:`FIFO_WAIT_S` seconds is an InputError (nothing
    would ever arrive). A writer that came and went without writing gives an empty stream. A device
    or socket is an InputError. ``what`` names the expected content in the messages.
    """
    path = str(path)
    mode = os.stat(path).st_mode
    if not stat.S_ISFIFO(mode):
        kind = ("a character device" if stat.S_ISCHR(mode) else "a block device" if stat.S_ISBLK(mode)
                else "a socket" if stat.S_ISSOCK(mode) else "not a regular file")
        raise InputError(f"is {kind}, not a {what}", path=path, hint=f"pass a {what}, a FIFO or '-' for stdin")
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    except OSError as exc:
        raise InputError(f"cannot read the FIFO ({exc.strerror or exc})", path=path, hint="check its permissions") from None
    head = b""
    deadline = time.monotonic() + FIFO_WAIT_S
    try:
        while True:
            try:
                head = os.read(fd, 1 << 16)
            except BlockingIOError:  # a writer is there (it may still be starting): wait for it
                break
            if head:
                break
            # no data and no writer now: wait a moment for one (a writer that came and went wakes us)
            left = deadline - time.monotonic()
            ready = select.select([fd], [], [], left)[0] if left > 0 else []
            if not ready:
                raise InputError(f"nothing writes to this FIFO (named pipe): waited {FIFO_WAIT_S:g} s for a writer",
                                 path=path, hint="start the program that writes to it first, or pass the file itself")
            try:
                head = os.read(fd, 1 << 16)
            except BlockingIOError:
                continue
            break  # data, or b"": the writer came and went without writing (an empty input)
        os.set_blocking(fd, True)
    except BaseException:
        os.close(fd)
        raise
    return io.BufferedReader(PrefixedRaw(head, fd), buffer_size=1 << 16)


def stdin_stream(stdin=None):
    """The binary stream ``-`` reads: ``stdin`` if given, else ``sys.stdin.buffer``; an InputError when
    stdin was closed when rbgp started (``<&-``: Python's ``sys.stdin`` is None)."""
    if stdin is not None:
        return stdin
    if sys.stdin is None:
        raise InputError("'-' reads stdin, but stdin is closed (<&-)", path="-",
                         hint="pipe a file in, e.g. rbgp train - < demo.csv, or pass the file itself")
    return getattr(sys.stdin, "buffer", sys.stdin)
