"""The one entry point for reading demonstrations: format detection and dispatch.

``read_demonstrations(["a.csv", "take_6D.tsv", "run.mcap", "-"], options)`` returns raw
:class:`~rbgp_cli.dynamics.trajectory.Trajectory` objects (SI units, quaternions x, y, z, w; lost
frames as NaN rows), to be cleaned by :func:`rbgp_cli.dynamics.prepare.prepare_all`.

The format is detected from the **content**, not the file name (``ReadOptions.format`` overrides):

* ``mcap``: the MCAP magic bytes ``\\x89MCAP0\\r\\n``;
* ``qtm``: Qualisys TSV header keys (``NO_OF_FRAMES``, ``FILE_VERSION``, ...) or a ``Frame<TAB>Time``
  column line near the top;
* ``motive``: the first line starts with ``Format Version,``;
* ``vicon``: the first non-empty line is a section title (``Segments``, ``Model Outputs``,
  ``Trajectories``, ``Joints``, ``Devices``) followed by a rate line;
* ``csv``: anything else (generic named columns, :mod:`rbgp_cli.io.csv`).
"""

from __future__ import annotations

import io
import os
import sys
from pathlib import Path

from rbgp_cli.dynamics.trajectory import Trajectory
from rbgp_cli.errors import InputError
from rbgp_cli.io.options import FORMATS, ReadOptions

__all__ = ["read_demonstrations", "read_file", "read_stream", "detect_format", "expand_sources", "MCAP_MAGIC",
           "DATA_SUFFIXES"]  # fmt: skip

MCAP_MAGIC = b"\x89MCAP0\r\n"
#: What ``expand_sources`` picks up inside a directory.
DATA_SUFFIXES = (".csv", ".tsv", ".mcap")
_HEAD = 8192
_QTM_KEYS = ("NO_OF_FRAMES", "FILE_VERSION", "NO_OF_CAMERAS", "NO_OF_BODIES", "NO_OF_MARKERS", "FREQUENCY")
_VICON_SECTIONS = ("Segments", "Model Outputs", "Trajectories", "Joints", "Devices")
_VENDOR = ("qtm", "motive", "vicon")


def detect_format(path_or_head) -> str:
    """``"mcap"``, ``"qtm"``, ``"motive"``, ``"vicon"`` or ``"csv"`` from the content.

    Parameters
    ----------
    path_or_head : str, Path or bytes
        A file path (its first 8 KiB are read) or the first bytes of the data.
    """
    if isinstance(path_or_head, (bytes, bytearray, memoryview)):
        head = bytes(path_or_head[:_HEAD])
    else:
        with open(path_or_head, "rb") as fh:
            head = fh.read(_HEAD)
    if _is_mcap_head(head):
        return "mcap"
    text = head.decode("utf-8-sig", errors="replace").lstrip("\ufeff")
    lines = text.splitlines()
    nonempty = [ln for ln in lines if ln.strip(" \t,;")]
    if not nonempty:
        return "csv"
    first = nonempty[0]
    key = first.split("\t")[0].strip()
    if key in _QTM_KEYS and "\t" in first:
        return "qtm"
    if any(ln.startswith("Frame\tTime") for ln in lines[:64]):
        return "qtm"
    if first.lstrip().replace('"', "").startswith("Format Version,"):
        return "motive"
    title = first.strip().strip(",;\t ").strip('"')
    if title in _VICON_SECTIONS and len(nonempty) > 1:
        rate = nonempty[1].strip().strip(",;\t ").replace(",", ".")
        try:
            float(rate)
            return "vicon"
        except ValueError:
            pass
    return "csv"


def _is_mcap_head(head: bytes) -> bool:
    """The MCAP magic, or all of a file too short to hold it that begins like it (a file cut in its
    first 8 bytes is a truncated MCAP, not a CSV)."""
    return head.startswith(MCAP_MAGIC) or (0 < len(head) < len(MCAP_MAGIC) and MCAP_MAGIC.startswith(head))


def expand_sources(paths) -> list[str]:
    """Paths with directories replaced by the data files inside them (``*.csv``, ``*.tsv``,
    ``*.mcap``, sorted; not recursive). ``-`` (stdin) and files are kept as given; a directory
    without data files is an :class:`InputError`."""
    out: list[str] = []
    for p in paths:
        p = str(p)
        if p != "-" and os.path.isdir(p):
            found = sorted(
                str(c) for c in Path(p).iterdir() if c.is_file() and c.suffix.lower() in DATA_SUFFIXES
            )
            if not found:
                raise InputError(
                    "the directory holds no .csv, .tsv or .mcap files", path=p, hint="pass the data files themselves"
                )
            out.extend(found)
        else:
            out.append(p)
    return out


def _format_option(options: ReadOptions) -> str:
    fmt = (options.format or "auto").lower()
    if fmt not in FORMATS:
        from rbgp_cli.errors import closest

        guess = closest(fmt, FORMATS)
        raise InputError(
            f"unknown format {options.format!r}; formats are {', '.join(FORMATS)}"
            + (f"; did you mean {guess!r}?" if guess else "")
        )
    return fmt


def _vendor(fmt: str):
    import importlib

    try:
        return importlib.import_module(f"rbgp_cli.io.{fmt}")
    except ImportError as exc:  # pragma: no cover - the vendor readers ship with rbgp
        raise InputError(f"the {fmt} reader is not available ({exc})") from None


def read_file(source, options: ReadOptions | None = None) -> list[Trajectory]:
    """Read one file (any supported format) into raw trajectories.

    Raises
    ------
    InputError
        Missing, unreadable, empty file, a directory, or content the format's reader rejects.
    """
    options = options or ReadOptions()
    source = str(source)
    p = Path(source)
    if not p.exists():
        hint = "check the path"
        if p.parent.is_dir():
            from rbgp_cli.errors import closest

            guess = closest(p.name, [c.name for c in p.parent.iterdir()])
            if guess:
                hint = f"did you mean {str(p.parent / guess)!r}?"
        raise InputError("file not found", path=source, hint=hint)
    if p.is_dir():
        raise InputError("is a directory", path=source, hint="pass the files inside it (or the directory to rbgp train)")
    try:
        size = p.stat().st_size
        with open(source, "rb") as fh:
            head = fh.read(_HEAD)
    except OSError as exc:
        raise InputError(f"cannot read the file ({exc.strerror or exc})", path=source, hint="check its permissions") from None
    if size == 0:
        raise InputError("the file is empty", path=source, hint="export or record it again")
    fmt = _format_option(options)
    if fmt == "auto":
        fmt = detect_format(head)
    if fmt == "mcap":
        from rbgp_cli.io import mcap

        return mcap.read(source, options)
    if fmt == "csv":
        from rbgp_cli.io import csv

        return csv.read(source, options)
    return _vendor(fmt).read(source, options)


class _PrefixedRaw(io.RawIOBase):
    """Bytes already read from a non-seekable stream, then the rest of the stream."""

    def __init__(self, head: bytes, stream):
        self._head = head
        self._stream = stream

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
        data = self._stream.read(len(b))
        if not data:
            return 0
        b[: len(data)] = data
        return len(data)


def _seekable(stream) -> bool:
    try:
        return bool(stream.seekable())
    except (AttributeError, ValueError, OSError):
        return False


def read_stream(stream, options: ReadOptions | None = None, source: str = "-") -> list[Trajectory]:
    """Read demonstrations from a binary stream (stdin, a pipe, a BytesIO).

    MCAP (sniffed from the magic bytes) is streamed; a pipe is read once, front to back. Text
    formats are read whole; vendor formats go through a temporary file.
    """
    options = options or ReadOptions()
    fmt = _format_option(options)
    if isinstance(stream, io.TextIOBase):
        stream = stream.buffer
    try:
        tty = bool(stream.isatty())
    except (AttributeError, ValueError, OSError):
        tty = False
    if tty:
        raise InputError("'-' reads stdin, but stdin is a terminal", path=source,
                         hint="pipe a file in, e.g. rbgp train - < demo.csv")  # fmt: skip
    if _seekable(stream):
        pos = stream.tell()
        head = stream.read(len(MCAP_MAGIC))
        stream.seek(pos)
    else:
        head = b""
        while len(head) < len(MCAP_MAGIC):
            chunk = stream.read(len(MCAP_MAGIC) - len(head))
            if not chunk:
                break
            head += chunk
    if not head:
        raise InputError("the input is empty", path=source, hint="pipe a CSV, TSV or MCAP file into rbgp")
    if fmt == "mcap" or (fmt == "auto" and _is_mcap_head(head)):
        from rbgp_cli.io import mcap

        s = stream if _seekable(stream) else io.BufferedReader(_PrefixedRaw(head, stream))
        return mcap.read_stream(s, options, source=source)
    data = stream.read() if _seekable(stream) else head + stream.read()
    if fmt == "auto":
        fmt = detect_format(data[:_HEAD])
    if fmt == "csv":
        from rbgp_cli.io import csv

        return csv.read_bytes(data, source, options)
    import tempfile

    module = _vendor(fmt)
    suffix = ".tsv" if fmt == "qtm" else ".csv"
    fd, tmp = tempfile.mkstemp(prefix="rbgp-stdin-", suffix=suffix)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        trajs = module.read(tmp, options)
    except InputError as exc:
        raise InputError(exc.message.replace(tmp, source), path=source, row=exc.row, topic=exc.topic, hint=exc.hint) from None
    finally:
        os.unlink(tmp)
    stem = Path(tmp).stem
    return [t.with_(source=t.source.replace(tmp, source), name=t.name.replace(stem, "stdin")) for t in trajs]


def read_demonstrations(sources, options: ReadOptions | None = None, stdin=None) -> list[Trajectory]:
    """Read every source into raw trajectories, in order.

    Parameters
    ----------
    sources : list of str
        File paths, directories (their ``*.csv``, ``*.tsv``, ``*.mcap``, sorted) or ``-`` for stdin.
    options : ReadOptions, optional
    stdin : binary stream, optional
        What ``-`` reads (default ``sys.stdin.buffer``).

    Returns
    -------
    list of Trajectory
        Raw (see :mod:`rbgp_cli.io.read`); prepare them with
        :func:`rbgp_cli.dynamics.prepare.prepare_all`.
    """
    options = options or ReadOptions()
    if isinstance(sources, (str, os.PathLike)):
        sources = [sources]
    out: list[Trajectory] = []
    stdin_used = False
    for src in expand_sources(sources):
        if src == "-":
            if stdin_used:
                raise InputError("'-' (stdin) given more than once")
            stdin_used = True
            stream = stdin if stdin is not None else sys.stdin.buffer
            trajs = read_stream(stream, options, source="-")
        else:
            trajs = read_file(src, options)
        if not trajs:
            raise InputError("no trajectories found in the file", path=src)
        out.extend(trajs)
    return out
