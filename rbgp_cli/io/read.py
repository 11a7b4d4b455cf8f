"""The one entry point for reading demonstrations: format detection and dispatch.

``read_demonstrations(["a.csv", "take_6D.tsv", "run.mcap", "-"], options)`` returns raw
:class:`~rbgp_cli.dynamics.trajectory.Trajectory` objects (SI units, quaternions x, y, z, w; lost
frames as NaN rows), to be cleaned by :func:`rbgp_cli.dynamics.prepare.prepare_all`.

The format is detected from the **content**, not the file name (``ReadOptions.format`` overrides):
each format registered in :mod:`rbgp_cli.io.formats` is asked in turn whether the first 8 KiB look
like it (MCAP: its magic bytes; QTM: its header keys or a ``Frame<TAB>Time`` column line; Motive: a
first line ``Format Version,``; Vicon: a section title and a rate line; C3D: its header's 0x50 and
processor type; BVH: ``HIERARCHY``), and a file no format
recognises is a generic CSV/TSV table (:mod:`rbgp_cli.io.csv`). Reading dispatches to the format's
``read`` (``read_stream`` / ``read_bytes`` for stdin).

Directories and patterns: a directory stands for the files in it (not its subdirectories), a glob
pattern (``'data/*_6D.tsv'``) for the files it matches, both sorted by name. Among those, files that
hold no pose data (a README, a LICENSE, notes, ``.DS_Store``, calibration files, tables without pose
columns, MCAP files without pose topics, QTM 3D-marker exports) are skipped, and one warning counts and
names them; a directory or pattern that leaves nothing to read is an error. Whether a file is pose data
is decided from its content: its first 8 KiB (binary, empty, a table header without pose columns),
else by reading it (:class:`~rbgp_cli.errors.NotPoseData`), so no file is parsed twice. A file named
explicitly is read, and is an error if it is not pose data.
"""

from __future__ import annotations

import contextlib
import glob
import io
import os
import re
import sys
from dataclasses import dataclass, field
from pathlib import Path

from rbgp_cli.dynamics.trajectory import Trajectory
from rbgp_cli.errors import InputError, NotPoseData, warn
from rbgp_cli.io import formats
from rbgp_cli.io.mcap import MAGIC as MCAP_MAGIC
from rbgp_cli.io.options import ReadOptions
from rbgp_cli.io.special import PrefixedRaw

__all__ = ["read_demonstrations", "read_sources", "list_sources", "SourceList", "read_file", "read_stream",
           "detect_format", "expand_sources", "skip_reason", "MCAP_MAGIC", "check_line_lengths", "MAX_LINE_BYTES"]  # fmt: skip

_HEAD = formats.HEAD_BYTES
#: A streamed format (one with ``read_stream``) is recognised from this many first bytes of stdin.
_PEEK = len(MCAP_MAGIC)
#: At most this many skipped files are named in the note (the rest are counted).
_NOTE_NAMES = 8


def detect_format(path_or_head) -> str:
    """The name of the format of a file (:func:`rbgp_cli.io.formats.detect`), from its content.

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
    return formats.detect(head)


def _is_pattern(p: str) -> bool:
    return any(ch in p for ch in "*?[") and not os.path.exists(p)


@dataclass
class SourceList:
    """What a list of sources names: the files to read, in order, and where each came from.

    Attributes
    ----------
    files : list of str
        Paths to read ('-' for stdin), explicit ones as given, directories and patterns expanded.
    found_in : dict
        ``file -> directory or pattern`` for the files that were not named explicitly (a file there
        that is not pose data is skipped rather than an error, unless it is also named explicitly).
    listed : dict
        ``directory or pattern -> number of files it listed``.
    skipped : list of (str, str)
        ``(file, reason)`` of the files skipped as not pose data, in the order they were listed.
    subdirectories : dict
        ``directory -> number of subdirectories`` (not searched; said when a directory yields nothing).
    explicit : set
        The paths named explicitly (never skipped).
    order : dict
        ``file -> position`` in the listing (orders ``skipped``).
    """

    files: list = field(default_factory=list)
    found_in: dict = field(default_factory=dict)
    listed: dict = field(default_factory=dict)
    skipped: list = field(default_factory=list)
    subdirectories: dict = field(default_factory=dict)
    explicit: set = field(default_factory=set)
    order: dict = field(default_factory=dict)

    def may_skip(self, path: str) -> bool:
        """True for a file found in a directory or through a pattern and not also named explicitly."""
        return path in self.found_in and path not in self.explicit

    def skip(self, path: str, reason: str) -> None:
        self.skipped.append((path, reason))
        self.skipped.sort(key=lambda pr: self.order.get(pr[0], 0))  # as listed, however found
        if path in self.files:
            self.files.remove(path)

    def note(self) -> str | None:
        """One line counting and naming the skipped files (grouped by reason), or None."""
        if not self.skipped:
            return None
        groups = {self.found_in.get(p) for p, _ in self.skipped}
        where = groups.pop() if len(groups) == 1 else None
        total = self.listed.get(where) if where else sum(self.listed.values())
        text = f"skipped {len(self.skipped)} of {total} files that hold no pose data: {_named(self.skipped, where)}"
        return f"{where}: {text}" if where else text

    def check_nothing_left(self, read: set) -> None:
        """InputError for a directory or pattern none of whose files was read."""
        for group, count in self.listed.items():
            if any(self.found_in.get(f) == group for f in read):
                continue
            what = "the directory" if os.path.isdir(group) else "the files matching this pattern"
            subdirs = self.subdirectories.get(group, 0)
            if count == 0:
                raise InputError(
                    ("the directory is empty" if os.path.isdir(group) else "no file matches this pattern")
                    + (f" (it has {subdirs} subdirectories, which are not searched)" if subdirs else ""),
                    path=group, hint="pass the data files or the folder that holds them")
            mine = [(p, r) for p, r in self.skipped if self.found_in.get(p) == group]
            raise InputError(
                f"no pose data in {what}: " + _named(mine, group)
                + (f"; {subdirs} subdirectories are not searched" if subdirs else ""),
                path=group,
                hint="`rbgp inspect FILE` says how a file is read; rbgp reads CSV/TSV with pose columns, QTM, "
                "Motive and Vicon exports, MCAP files with pose topics, C3D files with a rigid body and BVH skeletons",
            )


def _named(skipped, where: str | None) -> str:
    """``a, b (no pose columns); c (not a text file) and 3 more``: the first few files by reason, named
    relative to their directory ``where``."""
    base = (where if os.path.isdir(where) else os.path.dirname(where)) if where else None
    by_reason: dict = {}
    for p, reason in skipped[:_NOTE_NAMES]:
        name = os.path.relpath(p, base) if base else p
        by_reason.setdefault(reason, []).append(name)
    text = "; ".join(f"{', '.join(names)} ({reason})" for reason, names in by_reason.items())
    more = len(skipped) - _NOTE_NAMES
    return text + (f" and {more} more" if more > 0 else "")


def _rosbag2_index(path: Path) -> bool:
    """True for a rosbag2 bag's ``metadata.yaml`` (its index, beside the MCAP files that hold the data:
    a bag folder, e.g. from ``rbgp rollout -o DIR/``, reads without a note about it)."""
    if path.name != "metadata.yaml":
        return False
    try:
        with open(path, "rb") as fh:
            return fh.read(64).lstrip().startswith(b"rosbag2_bagfile_information")
    except OSError:
        return False


def natural_key(name: str) -> tuple:
    """Sort key of a file name in natural order: runs of digits compare as numbers, so that
    ``take_2`` comes before ``take_10`` (the recording order of numbered takes; docs/data.md)."""
    return tuple((0, int(part), part) if part.isdigit() else (1, 0, part) for part in re.split(r"(\d+)", str(name)))


#: The values of ``ReadOptions.file_order`` (``--file-order``).
FILE_ORDERS = ("given", "name", "mtime")


def ordered_files(files: list, order: str = "given") -> list:
    """``files`` in the recording order ``order`` says (:class:`~rbgp_cli.io.options.ReadOptions`
    ``file_order``): ``given`` as they are; ``name`` in natural name order of their paths
    (:func:`natural_key`); ``mtime`` by modification time, oldest first, ties in natural name order.
    Stdin (``-``) keeps its place; the others are sorted among themselves (a stable sort)."""
    if order == "given":
        return list(files)
    if order not in FILE_ORDERS:
        raise InputError(f"file_order must be one of {', '.join(FILE_ORDERS)}, got {order!r}", param="file_order")
    where = [k for k, f in enumerate(files) if f != "-"]

    def mtime(f):
        try:
            return os.stat(f).st_mtime_ns
        except OSError:  # unreadable or gone: reading it says so; here it sorts last
            return float("inf")

    if order == "name":
        keyed = sorted((files[k] for k in where), key=natural_key)
    else:
        keyed = sorted((files[k] for k in where), key=lambda f: (mtime(f), natural_key(f)))
    out = list(files)
    for k, f in zip(where, keyed):
        out[k] = f
    return out


def list_sources(paths, options: ReadOptions | None = None) -> SourceList:
    """Expand directories (their files in natural name order, not recursive: :func:`natural_key`) and
    glob patterns (the same order); keep files and ``-`` as given, in the order given. This order is
    the demonstrations' recording order (docs/data.md), unless ``options.file_order`` sorts every file
    by name or by modification time (:func:`ordered_files`). Files found that way whose first 8 KiB show they hold no pose data
    (:func:`skip_reason`) are skipped (``SourceList.skipped``). Raises InputError for a pattern that
    matches nothing."""
    options = options or ReadOptions()
    out = SourceList()
    for p in paths:
        p = str(p)
        if p != "-" and os.path.isdir(p):
            entries = sorted(Path(p).iterdir(), key=lambda c: natural_key(c.name))
            found = [str(c) for c in entries if c.is_file() and not _rosbag2_index(c)]
            out.subdirectories[p] = sum(1 for c in entries if c.is_dir())
        elif p != "-" and _is_pattern(p):
            found = sorted((f for f in glob.glob(p) if os.path.isfile(f)), key=natural_key)
            if not found:
                raise InputError("no file matches this pattern", path=p)
        else:
            out.files.append(p)
            out.explicit.add(p)
            continue
        out.listed[p] = len(found)
        for f in found:
            out.found_in.setdefault(f, p)
            out.files.append(f)
    out.files = ordered_files(out.files, options.file_order)
    out.order = {f: k for k, f in reversed(list(enumerate(out.files)))}
    for f in [f for f in out.files if out.may_skip(f)]:
        reason = skip_reason(f, options)
        if reason is not None:
            out.skip(f, reason)
    return out


def expand_sources(paths, options: ReadOptions | None = None) -> list[str]:
    """The files :func:`list_sources` keeps, after one warning naming the skipped ones; InputError
    for a directory or pattern that leaves nothing (files read later may still be skipped by
    :func:`read_sources`, which reads them)."""
    src = list_sources(paths, options)
    src.check_nothing_left(set(src.files))
    note = src.note()
    if note:
        warn(note)
    return src.files


def skip_reason(path, options: ReadOptions | None = None) -> str | None:
    """Why ``path`` holds no pose data, in a few words, judged from its first 8 KiB; None when it
    looks like pose data or its head cannot tell (reading it then decides).

    Empty files, binary files (images, videos, ``.DS_Store``, zip archives), text that is not a table
    or a table without pose columns (:func:`rbgp_cli.io.csv.sniff_pose_columns`), QTM exports of 3D
    markers, and (with ``format``) files that are not of that format.
    """
    options = options or ReadOptions()
    path = str(path)
    try:
        size = os.path.getsize(path)
        with open(path, "rb") as fh:
            head = fh.read(_HEAD)
    except OSError:
        return None  # reading it says what is wrong
    fmt = _format_option(options)
    if fmt == "auto":
        fmt = detect_format(head)
    entry = formats.get(fmt)
    if not entry.binary and not head.strip(b" \t\r\n"):
        return "empty"
    if entry.skip_reason is None:
        return None
    return entry.skip_reason(head, path, options, complete=size <= len(head))


def _format_option(options: ReadOptions) -> str:
    """``options.format`` in lower case; InputError for a name no format is registered under."""
    fmt = (options.format or "auto").lower()
    choices = formats.choices()
    if fmt not in choices:
        from rbgp_cli.errors import closest

        guess = closest(fmt, choices)
        raise InputError(
            f"unknown format {options.format!r}; formats are {', '.join(choices)}"
            + (f"; did you mean {guess!r}?" if guess else ""), param="format",
        )
    return fmt


def read_file(source, options: ReadOptions | None = None, formats_read: set | None = None) -> list[Trajectory]:
    """Read one file (any supported format) into raw trajectories; ``formats_read``, when given, gets the
    name of the format it was read as.

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

            # names compared without a shared suffix: '.csv' alone made 'motion_025.csv' like 'mot_rest.csv'
            if p.suffix:
                same = {c.stem: c.name for c in p.parent.iterdir() if c.suffix.lower() == p.suffix.lower()}
                stem = closest(p.stem, same)
                guess = same[stem] if stem else closest(p.name, [c.name for c in p.parent.iterdir()
                                                                 if c.suffix.lower() != p.suffix.lower()])
            else:  # a folder, or a file named without its suffix
                guess = closest(p.name, [c.name for c in p.parent.iterdir()])
            if guess:
                hint = f"did you mean {str(p.parent / guess)!r}?"
        raise InputError("file not found", path=source, hint=hint)
    if p.is_dir():
        raise InputError("is a directory", path=source, hint="pass the files inside it (or the directory to rbgp train)")
    from rbgp_cli.io.special import is_stream_path, open_stream_path

    if is_stream_path(source):  # a FIFO, <(cat demo.csv): read once as a stream, like stdin
        with open_stream_path(source, "data file") as stream:
            return read_stream(stream, options, source=source)
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
    entry = formats.get(fmt)
    if not entry.binary:
        check_line_lengths(source)
    if formats_read is not None:
        formats_read.add(entry.name)
    return entry.read(source, options)


#: The longest line a text format may have: a pose table with thousands of columns stays far below
#: it, and a file of one 200 MB line is refused after reading this much, not after gigabytes of parsing.
MAX_LINE_BYTES = 1 << 20


class _LineLengths:
    """Feed blocks of a text file; an InputError as soon as a line is longer than :data:`MAX_LINE_BYTES`."""

    def __init__(self, source: str):
        self.source, self.run, self.line = source, 0, 1

    def feed(self, block) -> None:
        import numpy as np

        nl = np.flatnonzero(np.frombuffer(block, dtype=np.uint8) == 10)
        if nl.size:
            lengths = np.diff(nl, prepend=-1) - 1
            lengths[0] += self.run
            k = int(np.argmax(lengths))
            if lengths[k] > MAX_LINE_BYTES:
                self._refuse(self.line + k, int(lengths[k]))
            self.line += int(nl.size)
            self.run = len(block) - int(nl[-1]) - 1
        else:
            self.run += len(block)
        if self.run > MAX_LINE_BYTES:
            self._refuse(self.line, self.run, more=True)

    def _refuse(self, line: int, length: int, more: bool = False):
        raise InputError(
            f"line {line} is {'more than ' if more else ''}{length} bytes long, longer than the "
            f"{MAX_LINE_BYTES >> 20} MiB a line of a pose table may have: not a table of poses (no line breaks?)",
            path=self.source, hint="check that this is the exported CSV/TSV file (one sample per line)")


def check_line_lengths(path, source: str | None = None) -> None:
    """An InputError when a line of the text file ``path`` is longer than :data:`MAX_LINE_BYTES`,
    found reading 1 MiB blocks (memory bounded; a one-line file is refused after its first MiB)."""
    checker = _LineLengths(str(path) if source is None else source)
    try:
        with open(path, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                checker.feed(block)
    except OSError as exc:
        raise InputError(f"cannot read the file ({exc.strerror or exc})", path=checker.source) from None


def _seekable(stream) -> bool:
    try:
        return bool(stream.seekable())
    except (AttributeError, ValueError, OSError):
        return False


def _read_text_checked(stream, head: bytes, source: str) -> bytes:
    """``head`` and the rest of ``stream``, read in 1 MiB blocks; an InputError as soon as a line is
    longer than :data:`MAX_LINE_BYTES` (a stream in a binary format has no such lines: its head
    decides, and then it is read whole)."""
    first = head + stream.read(max(0, _HEAD - len(head)))
    blocks = [first]
    checker = _LineLengths(source) if not formats.get(detect_format(first[:_HEAD])).binary else None
    if checker is not None:
        checker.feed(first)
    for block in iter(lambda: stream.read(1 << 20), b""):
        if checker is not None:
            checker.feed(block)
        blocks.append(block)
    return b"".join(blocks)


def read_stream(stream, options: ReadOptions | None = None, source: str = "-") -> list[Trajectory]:
    """Read demonstrations from a binary stream (stdin, a pipe, a BytesIO).

    A format with ``read_stream`` (MCAP, recognised from its magic bytes) is streamed; a pipe is read
    once, front to back. Other formats are read whole, and given to the format's ``read_bytes`` or
    else through a temporary file.
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
        head = stream.read(_PEEK)
        stream.seek(pos)
    else:
        head = b""
        while len(head) < _PEEK:
            chunk = stream.read(_PEEK - len(head))
            if not chunk:
                break
            head += chunk
    if not head:
        raise InputError("the input is empty", path=source, hint="pipe a CSV, TSV or MCAP file into rbgp")
    streamed = formats.get(fmt) if fmt != "auto" else next(
        (f for f in formats.all_formats() if f.read_stream and f.detect and f.detect(head)), None)
    if streamed is not None and streamed.read_stream is not None:
        s = stream if _seekable(stream) else io.BufferedReader(PrefixedRaw(head, stream))
        return streamed.read_stream(s, options, source=source)
    data = _read_text_checked(stream, b"" if _seekable(stream) else head, source)
    entry = formats.get(detect_format(data[:_HEAD]) if fmt == "auto" else fmt)
    if entry.read_bytes is not None:
        return entry.read_bytes(data, source, options)
    import tempfile

    fd, tmp = tempfile.mkstemp(prefix="rbgp-stdin-", suffix=entry.suffix)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        with warnings_renamed(tmp, source, "stdin"):
            trajs = entry.read(tmp, options)
    except InputError as exc:
        raise InputError(exc.message.replace(tmp, source), path=source, row=exc.row, topic=exc.topic, hint=exc.hint,
                         param=exc.param) from None
    finally:
        os.unlink(tmp)
    stem = Path(tmp).stem
    return [t.with_(source=t.source.replace(tmp, source), name=t.name.replace(stem, "stdin")) for t in trajs]


@contextlib.contextmanager
def warnings_renamed(tmp: str, name: str, stem: str):
    """Warnings raised inside, raised again on the way out with the temporary file ``tmp`` (stdin's
    bytes, read through a file) called ``name`` and its stem called ``stem``: a warning about what came
    in on stdin names '-', not a file that is gone when it is printed."""
    import warnings

    from rbgp_cli.errors import RbgpWarning

    old_stem = Path(tmp).stem  # a trajectory named after the file (mkstemp's name; not /proc/self/fd/N's "N")

    def fix(text):
        if text is None:
            return None
        text = str(text).replace(tmp, name)
        return text.replace(old_stem, stem) if old_stem.startswith("rbgp-stdin-") else text

    caught: list = []
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            yield
    finally:
        for w in caught:
            err = getattr(w.message, "error", None)
            if isinstance(w.message, RbgpWarning) and err is not None:
                warn(fix(err.message), path=fix(err.path), row=err.row, topic=err.topic, hint=fix(err.hint),
                     param=err.param)
            else:
                warnings.warn(fix(w.message), w.category, stacklevel=3)


def read_sources(sources, options: ReadOptions | None = None, stdin=None, *,
                 own_rate: bool = False) -> tuple[list[Trajectory], SourceList]:
    """Read every source into raw trajectories, in order; also return what was read and skipped.

    Files found in a directory or through a pattern that hold no pose data are skipped (judged from
    their head, else by the reader raising :class:`~rbgp_cli.errors.NotPoseData`); one
    :class:`~rbgp_cli.errors.RbgpWarning` counts and names them. A directory or pattern that leaves
    nothing to read, and any other problem of any file, is an :class:`InputError`. ``own_rate``: the options' rate is
    the caller's default (a list of poses needs no time column), not the user's, and files that have their own times
    are not said to leave it unused.
    """
    options = options or ReadOptions()
    if isinstance(sources, (str, os.PathLike)):
        sources = [sources]
    listing = list_sources(sources, options)
    out: list[Trajectory] = []
    read: set = set()
    formats_read: set = set()
    stdin_used = False
    for src in list(listing.files):
        if src == "-":
            if stdin_used:
                raise InputError("'-' (stdin) given more than once")
            stdin_used = True
            from rbgp_cli.io.special import stdin_stream

            trajs = read_stream(stdin_stream(stdin), options, source="-")
        else:
            try:
                trajs = read_file(src, options, formats_read)
            except NotPoseData as exc:
                if not listing.may_skip(src):
                    raise
                listing.skip(src, exc.reason)
                continue
        if not trajs:
            raise InputError("no trajectories found in the file", path=src)
        read.add(src)
        out.extend(trajs)
    listing.check_nothing_left(read)
    note = listing.note()
    if note:
        warn(note)
    _say_ignored_options(options, formats_read, out, rate_given=not own_rate)
    return out, listing


def _say_ignored_options(options: ReadOptions, formats_read: set, trajs=(), rate_given: bool = True) -> None:
    """One warning per read option that only some formats use (:data:`~rbgp_cli.io.formats.SPECIFIC_OPTIONS`)
    and that no file read used (``body`` given for CSV files): the user meant it, and it changed nothing. Also one
    for ``rate`` where every file read has a time column, and one where ``length_unit`` overrode the unit the
    position columns' names give (x_m read as millimetres): the option was applied, against the file."""
    named = sorted({str(tr.info.get("length_unit_source", "")) for tr in trajs} - {"", "option"})
    if options.length_unit and any(x.startswith("option, over") for x in named):
        units = sorted({x.rsplit("' ", 1)[-1] for x in named if x.startswith("option, over")})
        warn(f"length_unit {options.length_unit} was applied to position columns whose names say "
             f"{', '.join(units)}: positions read as {options.length_unit}",
             hint="drop length_unit if the column names are right", param="length_unit")
    if rate_given and options.rate and trajs and all(tr.info.get("rate_option_unused") for tr in trajs):
        warn(f"rate {options.rate:g} Hz was given, but the files have a time column "
             f"({trajs[0].info['rate_option_unused']}): their own times are used", param="rate")
    read = [formats.get(n) for n in sorted(formats_read)]
    if not read:
        return
    unused = set.intersection(*(set(formats.ignored_options(options, f)) for f in read))
    for key in (k for k in formats.SPECIFIC_OPTIONS if k in unused):
        users = [f.name for f in map(formats.get, formats.names()) if f.honours and key in f.honours]
        titles = " and ".join(f.title for f in read)
        warn(f"{key} was given but these files are {titles}, which do not use it: read without it",
             hint=f"{key} applies to {', '.join(users)} files", param=key)


def read_demonstrations(sources, options: ReadOptions | None = None, stdin=None, *,
                        own_rate: bool = False) -> list[Trajectory]:
    """Read every source into raw trajectories, in order.

    Parameters
    ----------
    sources : list of str
        File paths, directories (the pose-data files in them, sorted; others are skipped with one
        warning), glob patterns, or ``-`` for stdin.
    options : ReadOptions, optional
    stdin : binary stream, optional
        What ``-`` reads (default ``sys.stdin.buffer``).
    own_rate : bool
        The options' rate is the caller's default, not the user's (:func:`read_sources`).

    Returns
    -------
    list of Trajectory
        Raw (see :mod:`rbgp_cli.io.read`); prepare them with
        :func:`rbgp_cli.dynamics.prepare.prepare_all`.
    """
    return read_sources(sources, options, stdin, own_rate=own_rate)[0]
