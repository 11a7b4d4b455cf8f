"""Progress on stderr as the command line shows it (the library reports through :mod:`rbgp_cli.progress`).

* On a terminal: a progress bar per task (rich, which Typer brings), with units done, elapsed and
  remaining time and a short status; messages and warnings scroll above the bars. A nested task (a
  fold's training inside cross-validation) disappears when it ends; a top-level one stays, full.
* In a pipe or log: plain lines, sparse: messages as they come, a line about a task only when it has
  run another ``interval`` seconds since its last line (so a 3-second rollout prints none), and one
  closing line per top-level task with the time it took.
* ``-q``: nothing (warnings and errors still appear: they are not progress).

:func:`make_progress` picks one of these for a stream. Library code never imports this module.
"""

from __future__ import annotations

import os
import sys
import time

from rbgp_cli.progress import Progress, Task

__all__ = ["make_progress", "LineProgress", "BarProgress", "is_terminal", "format_duration"]


def is_terminal(stream) -> bool:
    """True when ``stream`` is an interactive terminal that can redraw a line (not TERM=dumb)."""
    try:
        tty = bool(stream.isatty())
    except (AttributeError, ValueError, OSError):
        return False
    return tty and os.environ.get("TERM", "") != "dumb"


def make_progress(*, quiet: bool = False, stream=None) -> Progress:
    """Nothing with ``quiet``; progress bars when ``stream`` (default stderr) is a terminal; else lines."""
    if quiet:
        return Progress()
    stream = sys.stderr if stream is None else stream
    if is_terminal(stream):
        try:
            import rich.progress  # noqa: F401  (Typer depends on rich; without it: lines)
        except ImportError:
            pass
        else:
            return BarProgress(stream)
    return LineProgress(stream)


def format_duration(seconds: float) -> str:
    """``4.2 s``, ``37 s``, ``2:05 min``, ``1:02:05 h``."""
    s = max(float(seconds), 0.0)
    if s < 10:
        return f"{s:.1f} s"
    if s < 60:
        return f"{s:.0f} s"
    m, sec = divmod(int(round(s)), 60)
    if m < 60:
        return f"{m}:{sec:02d} min"
    h, m = divmod(m, 60)
    return f"{h}:{m:02d}:{sec:02d} h"


def _count(x: float) -> str:
    return f"{x:g}" if x != int(x) else str(int(x))


# ---------------------------------------------------------------------------------------------- lines
class _LineTask(Task):
    def __init__(self, owner: "LineProgress", description: str, total, unit: str, top: bool) -> None:
        self.owner, self.description, self.total, self.unit, self.top = owner, description, total, unit, top
        self.completed = 0.0
        self.status = ""
        self.start = self.last = owner.clock()
        self.closed = False

    def advance(self, amount: float = 1.0) -> None:
        self.completed += amount
        self._maybe_report()

    def update(self, *, completed=None, total=None, status=None) -> None:
        if completed is not None:
            self.completed = float(completed)
        if total is not None:
            self.total = total
        if status is not None:
            self.status = status
        self._maybe_report()

    def _done_text(self) -> str:
        if self.total:
            return f"{_count(self.completed)}/{_count(self.total)} {self.unit}".rstrip()
        return f"{_count(self.completed)} {self.unit}".rstrip()

    def _maybe_report(self) -> None:
        now = self.owner.clock()
        if now - self.last < self.owner.interval:
            return
        self.last = now
        elapsed = now - self.start
        text = f"{self.description}: {self._done_text()}"
        if self.status:
            text += f" ({self.status})"
        text += f", {format_duration(elapsed)} elapsed"
        if self.total and 0 < self.completed < self.total:
            text += f", about {format_duration(elapsed / self.completed * (self.total - self.completed))} left"
        self.owner.message(text)

    def close(self, ok: bool = True) -> None:
        if self.closed:
            return
        self.closed = True
        self.owner._depth -= 1
        if ok and self.top:
            self.owner.message(f"{self.description}: {self._done_text()} in "
                               f"{format_duration(self.owner.clock() - self.start)}")


class LineProgress(Progress):
    """Plain ``rbgp: ...`` lines on ``stream`` (default: stderr at the time of writing), sparse."""

    def __init__(self, stream=None, *, interval: float = 10.0, clock=time.monotonic) -> None:
        self.stream, self.interval, self.clock = stream, float(interval), clock
        self._depth = 0

    def message(self, text: str) -> None:
        stream = sys.stderr if self.stream is None else self.stream
        print(f"rbgp: {text}", file=stream, flush=True)

    def task(self, description: str, *, total=None, unit: str = "") -> Task:
        t = _LineTask(self, description, total, unit, top=self._depth == 0)
        self._depth += 1
        return t


# ---------------------------------------------------------------------------------------------- bars
class _BarTask(Task):
    def __init__(self, owner: "BarProgress", task_id, top: bool) -> None:
        self.owner, self.id, self.top = owner, task_id, top
        self.closed = False

    def advance(self, amount: float = 1.0) -> None:
        self.owner._rich.advance(self.id, amount)

    def update(self, *, completed=None, total=None, status=None) -> None:
        kw = {}
        if completed is not None:
            kw["completed"] = completed
        if total is not None:
            kw["total"] = total
        if status is not None:
            kw["status"] = status
        self.owner._rich.update(self.id, **kw)

    def close(self, ok: bool = True) -> None:
        if not self.closed:
            self.closed = True
            self.owner._closed(self, ok)


class BarProgress(Progress):
    """rich progress bars on ``stream`` (a terminal): description, bar, done/total unit, elapsed,
    remaining, status. Started when the first task starts and stopped when the last one ends;
    stdout is never touched (it carries data)."""

    def __init__(self, stream, *, refresh_per_second: float = 8.0) -> None:
        self.stream = stream
        self.refresh_per_second = refresh_per_second
        self._rich = None
        self._open: list[_BarTask] = []

    def _start(self) -> None:
        from rich.console import Console
        from rich.progress import (
            BarColumn, MofNCompleteColumn, TextColumn, TimeElapsedColumn, TimeRemainingColumn,
        )
        from rich.progress import Progress as RichProgress

        console = Console(file=self.stream, force_terminal=True, highlight=False)
        self._rich = RichProgress(
            TextColumn("{task.description}"),
            BarColumn(bar_width=30),
            MofNCompleteColumn(),
            TextColumn("{task.fields[unit]}"),
            TimeElapsedColumn(),
            TextColumn("•"),
            TimeRemainingColumn(elapsed_when_finished=True),
            TextColumn("{task.fields[status]}"),
            console=console,
            transient=False,
            redirect_stdout=False,  # stdout carries data
            redirect_stderr=True,  # warnings printed meanwhile appear above the bars
            refresh_per_second=self.refresh_per_second,
        )
        self._rich.start()

    def message(self, text: str) -> None:
        if self._rich is not None:
            self._rich.console.print(f"rbgp: {text}", markup=False, highlight=False, soft_wrap=True)
        else:
            print(f"rbgp: {text}", file=self.stream, flush=True)

    def task(self, description: str, *, total=None, unit: str = "") -> Task:
        if self._rich is None:
            self._start()
        task_id = self._rich.add_task(description, total=total, unit=unit, status="")
        t = _BarTask(self, task_id, top=not self._open)
        self._open.append(t)
        return t

    def _closed(self, task: _BarTask, ok: bool) -> None:
        if task in self._open:
            self._open.remove(task)
        if self._rich is None:
            return
        if not (ok and task.top):
            self._rich.remove_task(task.id)  # nested tasks and failed ones leave no bar behind
        if not self._open:
            self.stop()

    def stop(self) -> None:
        """Stop drawing (the last frame stays on the terminal)."""
        if self._rich is not None:
            rich, self._rich = self._rich, None
            rich.stop()
        self._open.clear()
