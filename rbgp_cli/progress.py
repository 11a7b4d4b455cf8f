"""Progress of long computations: reported by the library, drawn by the command line.

The library never prints. A long computation takes ``progress=`` (a :class:`Progress`, a plain
``callable(str)`` for messages, or None) and reports through it::

    progress = as_progress(progress)
    progress("9 demonstrations, 565 training points")           # a message
    with progress.task("training", total=6, unit="outputs") as task:
        for ...:
            task.update(status="output 2: 140 evaluations")      # shown beside the bar
            task.advance()                                       # one output done

Tasks nest (cross-validation folds around the training of each fold); a task that ends with an
exception reports nothing more. This base class reports nothing at all (it is what ``None`` and
``-q`` give); :mod:`rbgp_cli.cli.progress` draws a progress bar with elapsed and remaining time on a
terminal and writes sparse plain lines to a pipe or log. Like :mod:`rbgp_cli.errors`, this module
imports nothing, so every layer may use it.
"""

from __future__ import annotations

__all__ = ["Progress", "Task", "as_progress"]


class Task:
    """One piece of long work with a known (or unknown: None) number of units. Does nothing here."""

    def advance(self, amount: float = 1.0) -> None:
        """``amount`` more units are done."""

    def update(self, *, completed: float | None = None, total: float | None = None,
               status: str | None = None) -> None:
        """Set how many units are done, the total, or the short status text shown beside the bar."""

    def close(self, ok: bool = True) -> None:
        """The task ended (``ok=False``: with an error)."""

    def __enter__(self) -> "Task":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close(ok=exc_type is None)


class Progress:
    """Where long computations report. The base class reports nothing; subclasses draw or print."""

    def __call__(self, message: str) -> None:
        self.message(message)

    def message(self, text: str) -> None:
        """A one-line message (e.g. what is being read, a fitted output's NLML)."""

    def task(self, description: str, *, total: float | None = None, unit: str = "") -> Task:
        """Start a task of ``total`` ``unit`` (e.g. 6 "outputs", 390 "steps", 5 "folds"); use it as a
        context manager, or call its ``close()``."""
        return Task()


class _Messages(Progress):
    """A plain ``callable(str)`` as a Progress: messages go to it, tasks report nothing."""

    def __init__(self, callback) -> None:
        self._callback = callback

    def message(self, text: str) -> None:
        self._callback(text)


def as_progress(progress) -> Progress:
    """``progress`` as a :class:`Progress`: itself, a ``callable(str)`` wrapped (messages only), or,
    for None, one that reports nothing."""
    if isinstance(progress, Progress):
        return progress
    if progress is None:
        return Progress()
    if callable(progress):
        return _Messages(progress)
    raise TypeError(f"progress must be a Progress, a callable(str) or None, not {type(progress).__name__}")
