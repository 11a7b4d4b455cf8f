"""Exceptions shared by every layer (this module imports nothing from rbgp).

The command line maps them to exit codes and one line on stderr:

* :class:`InputError` (bad input or bad usage): exit code 2.
* :class:`RbgpRuntimeError` (a computation that failed on valid input): exit code 1.

Messages are one line and say *where* (file, row, topic) and *what to do*. They name the Python
API's parameters (``steps``, ``quat_order``), never the command line's flags: ``param=`` says which
one-word names are parameters (where a "; " part of the message starts with one, and anywhere in
the hint: "pass rate HZ"), names with an underscore are parameters anyway, and the command line
writes its options instead (``rbgp_cli.cli.common.as_flags``: ``--steps``, ``--quat-order``).
"""

from __future__ import annotations

__all__ = ["RbgpError", "InputError", "NotPoseData", "RbgpRuntimeError", "RbgpWarning", "warn", "closest"]


class RbgpError(Exception):
    """Base class of rbgp's own errors."""

    exit_code = 1

    def __init__(
        self,
        message: str,
        *,
        path: str | None = None,
        row: int | None = None,
        topic: str | None = None,
        hint: str | None = None,
        param: str | tuple[str, ...] | None = None,
    ) -> None:
        self.message = message
        #: the library parameter the message is about (e.g. "steps"), named as the Python API names it,
        #: or a tuple of them (a message that names two: ("rate", "columns")); the command line shows
        #: the matching options instead (--steps) where the message or one of its "; " parts starts
        #: with the name, and anywhere in the hint (rbgp_cli.cli.common.as_flags); names with an
        #: underscore (max_points) anywhere
        self.param = param
        self.path = None if path is None else str(path)
        self.row = row
        self.topic = topic
        self.hint = hint
        super().__init__(self.format())

    def format(self) -> str:
        """One line: ``FILE:ROW: [topic T: ]message (hint)``."""
        where = ""
        if self.path is not None:
            where = self.path
            if self.row is not None:
                where += f":{self.row}"
            where += ": "
        elif self.row is not None:
            where = f"row {self.row}: "
        if self.topic is not None:
            where += f"topic {self.topic}: "
        text = where + self.message
        if self.hint:
            text += f"; {self.hint}"
        return " ".join(text.split())  # one line, always


class InputError(RbgpError, ValueError):
    """The input (a file, an option, a start pose) cannot be used as given. Exit code 2."""

    exit_code = 2


class NotPoseData(InputError):
    """The file can be read but holds no pose data at all: a table without pose columns, an MCAP file
    without pose topics, a Motive export without rigid bodies, a QTM 3D-marker export. A file named
    explicitly is an error like any other (exit code 2, same message); a file found in a directory is
    skipped instead, and ``reason`` (a few words) names it in the one note that lists skipped files."""

    def __init__(self, message: str, *, reason: str, **kwargs) -> None:
        self.reason = reason
        super().__init__(message, **kwargs)


class RbgpRuntimeError(RbgpError, RuntimeError):
    """A computation failed although its input was valid (e.g. no hyperparameters gave a positive
    definite Gram matrix). Exit code 1."""

    exit_code = 1


def closest(name: str, candidates) -> str | None:
    """The candidate closest to ``name`` (for "did you mean" hints), or None."""
    import difflib

    cands = [str(c) for c in candidates]
    lower = {c.lower(): c for c in cands}
    hit = difflib.get_close_matches(name.lower(), list(lower), n=1, cutoff=0.6)
    return lower[hit[0]] if hit else None


class RbgpWarning(UserWarning):
    """Something was repaired or looks suspicious but the result is still correct (e.g. "dropped 3
    lost frames"). The command line prints these to stderr as ``rbgp: warning: ...``. One made by
    :func:`warn` keeps its parts in ``error`` (an :class:`RbgpError`: message, path, ``param``), so
    that the command line can name its options as it does for errors."""

    error: RbgpError | None = None


def warn(message: str, *, path: str | None = None, row: int | None = None, topic: str | None = None,
         hint: str | None = None, param: str | tuple[str, ...] | None = None) -> None:
    """Emit an :class:`RbgpWarning` whose text names the file/row/topic like the errors do, with
    ``hint`` after it; ``param`` names the parameter(s) it is about, as for :class:`RbgpError`."""
    import warnings

    error = RbgpError(message, path=path, row=row, topic=topic, hint=hint, param=param)
    w = RbgpWarning(error.format())
    w.error = error
    warnings.warn(w, stacklevel=2)
