"""The registry of file formats: the one place that lists them.

Each format module (:mod:`rbgp_cli.io.mcap`, :mod:`~rbgp_cli.io.qtm`, :mod:`~rbgp_cli.io.motive`,
:mod:`~rbgp_cli.io.vicon`, :mod:`~rbgp_cli.io.csv`) defines one :class:`Format` record named
``FORMAT``: its name, how to recognise it from the first bytes of a file (``detect``), why a file of
it holds no pose data (``skip_reason``), how to read it (``read``, optionally ``read_stream`` /
``read_bytes`` / ``read_all``), how to describe it for ``rbgp inspect`` (``describe``) and how to
write it (``write``, where rbgp writes it). :mod:`rbgp_cli.io.read` (format detection and dispatch),
:mod:`rbgp_cli.io.inspect` and the command line's ``--format`` choices take everything from here.

The built-in formats are loaded lazily (the command line starts without importing numpy): their
module names are listed once, in :data:`_BUILTIN`, in the order in which detection tries them; the
format whose ``fallback`` is set (CSV) is what a file is when no other format recognises it. Another
format is added with :func:`register` (a plugin or a test), without editing any other module::

    from rbgp_cli.io import formats
    formats.register(formats.Format(name="toy", title="Toy text", detect=lambda head: head.startswith(b"TOY"),
                                    read=read_toy))
"""

from __future__ import annotations

import contextlib
import importlib
from dataclasses import dataclass
from typing import Callable, Optional

__all__ = ["Format", "register", "registered", "unregister", "get", "names", "choices", "all_formats", "detect", "help_text",
           "HEAD_BYTES"]

#: Detection and the skip decision look at this many first bytes of a file.
HEAD_BYTES = 8192

#: The built-in format modules (``rbgp_cli.io.<name>``, each defining ``FORMAT``), in the order the
#: ``--format`` help lists them and detection tries them (the fallback, CSV, last).
_BUILTIN = ("csv", "qtm", "motive", "vicon", "mcap", "c3d", "bvh")

#: The read options (:class:`~rbgp_cli.io.options.ReadOptions` fields) that only some formats use: a file of a
#: format that does not (its :attr:`Format.honours`) is read without them, and the reader says so once.
SPECIFIC_OPTIONS = ("columns", "body", "rotation", "topic", "frame")


def ignored_options(options, fmt: "Format") -> list:
    """The :data:`SPECIFIC_OPTIONS` set in ``options`` that format ``fmt`` does not use ([] when ``fmt`` does
    not say which it uses)."""
    if fmt.honours is None:
        return []
    return [k for k in SPECIFIC_OPTIONS if getattr(options, k, None) and k not in fmt.honours]


@dataclass(frozen=True)
class Format:
    """One file format rbgp reads (and perhaps writes).

    Attributes
    ----------
    name : str
        The ``--format`` value (lower case).
    title : str
        What ``rbgp inspect`` calls it ("Qualisys QTM TSV").
    read : callable
        ``read(path, options) -> list[Trajectory]`` (raw: seconds, metres, quaternions x, y, z, w).
    detect : callable, optional
        ``detect(head: bytes) -> bool``: the first :data:`HEAD_BYTES` bytes look like this format
        (``--format auto``). None: never detected (only read when named).
    skip_reason : callable, optional
        ``skip_reason(head: bytes, path, options, complete: bool) -> str | None``: why a file that
        starts with ``head`` holds no pose data (a few words), or None when it looks like pose data or
        the head cannot tell; ``complete`` says the head is the whole file.
    describe : callable, optional
        ``describe(path, options) -> dict``: plain data for ``rbgp inspect`` (``"needs"``: the options
        still needed, ``"bodies"``: the bodies a vendor export holds).
    describe_rows : callable, optional
        ``describe_rows(description) -> list[str]``: the description as ``rbgp inspect`` prints it
        (aligned rows of plain words); without it every field is one row.
    read_stream : callable, optional
        ``read_stream(binary_stream, options, source) -> list[Trajectory]``: streamed reading of stdin
        (MCAP); without it stdin is read whole and given to ``read_bytes``.
    read_bytes : callable, optional
        ``read_bytes(data, source, options)``; without it stdin goes through a temporary file.
    read_all : callable, optional
        ``read_all(path, options)``: everything the file holds that the options leave open, for
        ``rbgp inspect`` (every body of a vendor export without ``--body``, every pose topic of an MCAP
        file without ``--topic``); without it inspect reads the file as train does.
    needs : callable, optional
        ``needs(description, options) -> list[str]``: options still needed to train on a file of this
        format because it holds several of what one option chooses ("body NAME, ... (3 bodies)"; named as
        :class:`~rbgp_cli.io.options.ReadOptions` names it, first).
    write : callable, optional
        ``write(trajectories, path, **options)``: writes the format (where rbgp does).
    suffix : str
        File name suffix of the temporary file that stdin goes through.
    binary : bool
        A binary format: its ``skip_reason`` also judges empty and blank heads.
    fallback : bool
        What a file is when no format's ``detect`` recognises it (one format: CSV).
    honours : tuple of str, optional
        Which of the read options only some formats use (:data:`SPECIFIC_OPTIONS`) this one uses; None: not
        stated (a plugin), and no option is said to be ignored for it.
    """

    name: str
    title: str
    read: Callable
    detect: Optional[Callable] = None
    skip_reason: Optional[Callable] = None
    describe: Optional[Callable] = None
    describe_rows: Optional[Callable] = None
    read_stream: Optional[Callable] = None
    read_bytes: Optional[Callable] = None
    read_all: Optional[Callable] = None
    needs: Optional[Callable] = None
    write: Optional[Callable] = None
    suffix: str = ".csv"
    binary: bool = False
    fallback: bool = False
    honours: Optional[tuple] = None


_registered: dict = {}  # name -> Format, for formats added with register()
_loaded: dict = {}  # name -> Format of the built-in modules imported so far


def register(fmt: Format, *, replace: bool = False) -> Format:
    """Add a format (detected after the built-in ones, before the fallback); returns it.

    Raises ValueError for a name that is taken (unless ``replace``) or is ``auto``."""
    name = fmt.name.lower()
    if name != fmt.name or not name or name == "auto":
        raise ValueError(f"a format name must be lower case and not 'auto', got {fmt.name!r}")
    if not replace and (name in _BUILTIN or name in _registered):
        raise ValueError(f"format {name!r} is already registered")
    _registered[name] = fmt
    return fmt


@contextlib.contextmanager
def registered(fmt: Format, *, replace: bool = False):
    """Register ``fmt`` for the duration of a ``with`` block (tests, a plugin tried out); the format
    it replaced, if any, is back afterwards."""
    before = _registered.get(fmt.name)
    register(fmt, replace=replace)
    try:
        yield fmt
    finally:
        if before is None:
            _registered.pop(fmt.name, None)
        else:
            _registered[fmt.name] = before


def unregister(name: str) -> None:
    """Remove a format added with :func:`register` (built-in formats stay)."""
    _registered.pop(name, None)


def names() -> tuple:
    """The format names, in detection order (without importing any reader)."""
    return tuple(dict.fromkeys((*_BUILTIN, *_registered)))


def choices() -> tuple:
    """The values ``ReadOptions.format`` / ``--format`` accept: ``auto`` and every format name."""
    return ("auto", *names())


def help_text() -> str:
    """The ``--format`` help of the command line."""
    return f"{' | '.join(choices())} (auto sniffs the content)."  # spaced: a narrow terminal wraps it


def get(name: str) -> Format:
    """The :class:`Format` named ``name`` (KeyError if none is)."""
    if name in _registered:
        return _registered[name]
    if name not in _BUILTIN:
        raise KeyError(name)
    if name not in _loaded:
        fmt = importlib.import_module(f"rbgp_cli.io.{name}").FORMAT
        assert fmt.name == name, f"rbgp_cli.io.{name} registers {fmt.name!r}"
        _loaded[name] = fmt
    return _loaded[name]


def all_formats() -> list:
    """Every :class:`Format`, in detection order."""
    return [get(n) for n in names()]


def detect(head: bytes) -> str:
    """The name of the first format whose ``detect`` recognises ``head``, else the fallback's."""
    formats = all_formats()
    for fmt in formats:
        if fmt.detect is not None and not fmt.fallback and fmt.detect(head):
            return fmt.name
    return next(f.name for f in formats if f.fallback)
