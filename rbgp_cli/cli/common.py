"""What every command shares: error handling and exit codes, warnings and progress on stderr,
read options, and writing data to a file or stdout. Imports only the standard library and typer at
module level, so ``rbgp --help`` stays fast (no rerun, mcap, pandas or scipy.optimize)."""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import inspect
import json
import os
import sys
import warnings
from pathlib import Path
from typing import Annotated, Optional

import typer

from rbgp_cli.progress import Progress

__all__ = ["command", "as_flags", "flag_words", "progress", "emit_json", "read_options", "with_read_options", "ReadArgs", "READ_PANEL",
           "write_text_output", "check_outputs", "set_quiet", "set_json", "is_quiet"]


def _stderr(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


_QUIET = {"on": False}
_JSON = {"on": False}
#: Ctrl-C has arrived while the command ran (:func:`_signals_as_exceptions`)
_INTERRUPTED = {"on": False}
#: the reporter of the running command (see :func:`_progress_session`)
_REPORTER: dict = {"now": None}


def set_quiet(value: bool) -> None:
    _QUIET["on"] = bool(value)


def set_json(value: bool) -> None:
    """``rbgp --json COMMAND``: the same as ``rbgp COMMAND --json`` (for the commands that have it)."""
    _JSON["on"] = bool(value)


class _CommandProgress(Progress):
    """``progress``: what the running command reports on stderr (never stdout: stdout carries data).

    Call it with a message (``progress("wrote x.rrd")``), or pass it as ``progress=`` to a library
    function, which may open tasks on it (``progress.task("cross-validation", total=5,
    unit="folds")``): a progress bar on a terminal, sparse plain lines otherwise, nothing with ``-q``
    (:mod:`rbgp_cli.cli.progress`)."""

    def _now(self) -> Progress:
        if _REPORTER["now"] is None:  # outside a command (library use, tests): lines, or nothing
            from rbgp_cli.cli.progress import make_progress

            return make_progress(quiet=_QUIET["on"], stream=sys.stderr)
        return _REPORTER["now"]

    def message(self, text: str) -> None:
        self._now().message(text)

    def task(self, description: str, *, total=None, unit: str = ""):
        return self._now().task(description, total=total, unit=unit)


progress = _CommandProgress()


@contextlib.contextmanager
def _progress_session():
    """The reporter for one command run, chosen for the current stderr; its bars stop before the
    command's last words (an error line, or nothing) are printed."""
    from rbgp_cli.cli.progress import make_progress

    reporter = make_progress(quiet=_QUIET["on"], stream=sys.stderr)
    _REPORTER["now"] = reporter
    try:
        yield reporter
    finally:
        _REPORTER["now"] = None
        stop = getattr(reporter, "stop", None)
        if stop is not None:
            stop()


@contextlib.contextmanager
def _signals_as_exceptions():
    """While a command runs: Ctrl-C raises KeyboardInterrupt (``rbgp: interrupted``, exit 130) and
    SIGTERM SystemExit(143), so that worker pools are ended and temporary files removed on the way
    out; the handlers in place before (:func:`rbgp_cli.cli.exit_on_signals`) come back afterwards."""
    import signal
    import threading

    from rbgp_cli.compute import ending_on_sigterm

    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def interrupt(signum, frame):
        # noted, so that a failure it causes is reported as the interruption: a KeyboardInterrupt
        # inside a C extension's import comes out as "ImportError: initialization failed"
        _INTERRUPTED["on"] = True
        raise KeyboardInterrupt

    _INTERRUPTED["on"] = False
    previous = signal.signal(signal.SIGINT, interrupt)
    try:
        with ending_on_sigterm():
            yield
    finally:
        signal.signal(signal.SIGINT, previous)


def is_quiet() -> bool:
    """``-q``: nothing on stderr but warnings and errors (no progress, no summaries)."""
    return _QUIET["on"]


def _show_warning(message, category, filename, lineno, file=None, line=None):
    from rbgp_cli.errors import RbgpWarning

    if issubclass(category, RbgpWarning):  # parameter names with an underscore shown as the options
        from rbgp_cli.errors import RbgpError

        _stderr(f"rbgp: warning: {as_flags(getattr(message, 'error', None) or RbgpError(str(message)))}")
    elif not _QUIET["on"] and os.environ.get("RBGP_DEBUG"):
        _stderr(f"rbgp: warning: {category.__name__}: {message}")


def _resource_error(exc: OSError) -> str | None:
    """The one line for an OSError that is the machine's limit, not a bug: too many open files."""
    import errno

    if exc.errno in (errno.EMFILE, errno.ENFILE):
        limit = ""
        try:
            import resource

            limit = f" (the limit is {resource.getrlimit(resource.RLIMIT_NOFILE)[0]})"
        except (ImportError, OSError, ValueError):  # pragma: no cover - not Unix
            pass
        return (f"rbgp: error: too many open files{limit}: rbgp's worker processes need more; raise the limit "
                "(ulimit -n 1024) or run in this process only with --jobs 1")
    return None


class _Stdout:
    """``sys.stdout`` while a command runs: a write that fails for a reason of the file system (a full
    disk, the file-size limit) is ``cannot write stdout: <reason>`` (exit 1), and writing to a stdout
    that was closed when rbgp started (``>&-``: Python's ``sys.stdout`` is None) is one error line
    (exit 2) instead of an AttributeError."""

    def __init__(self, stream):
        self._stream = stream

    def _closed(self):
        from rbgp_cli.errors import InputError

        return InputError("stdout is closed (>&-): there is nowhere to write the output",
                          hint="redirect it instead (> FILE, > /dev/null), or write to a file with -o FILE")

    def _failed(self, exc: OSError):
        from rbgp_cli.io.atomic import write_error

        _drop_stdout()
        return write_error("stdout", exc)

    def write(self, text):
        if self._stream is None:
            raise self._closed()
        try:
            return self._stream.write(text)
        except BrokenPipeError:
            raise
        except OSError as exc:
            raise self._failed(exc) from None

    def flush(self):
        if self._stream is None:
            return
        try:
            self._stream.flush()
        except BrokenPipeError:
            raise
        except OSError as exc:
            raise self._failed(exc) from None

    def isatty(self) -> bool:
        return self._stream is not None and self._stream.isatty()

    def writelines(self, lines):
        for text in lines:
            self.write(text)

    def __getattr__(self, name):
        if self._stream is None:
            if name in ("buffer", "fileno"):  # a write would follow
                raise self._closed()
            import io

            return getattr(io.StringIO(), name)  # encoding, errors, closed...: what libraries look at
        return getattr(self._stream, name)


def stdout_is_closed() -> bool:
    """True when stdout was closed when rbgp started (``>&-``)."""
    stream = sys.stdout._stream if isinstance(sys.stdout, _Stdout) else sys.stdout
    return stream is None


@contextlib.contextmanager
def _guarded_stdout():
    """:class:`_Stdout` around ``sys.stdout`` while a command runs."""
    previous = sys.stdout
    sys.stdout = previous if isinstance(previous, _Stdout) else _Stdout(previous)
    try:
        yield
    finally:
        if sys.stdout is not previous and isinstance(sys.stdout, _Stdout):
            sys.stdout = previous


_QUIET_HELP = "No progress messages, bars or summaries on stderr (warnings and errors still); also accepted before the command."


def prose(doc: str | None) -> str | None:
    """A docstring as the help shows it: dedented, each paragraph (lines between blank lines) one line,
    so that the terminal wraps it at its width instead of the source file's line breaks showing as
    ragged lines (Typer's rich help keeps a docstring's single newlines). Paragraphs stay apart."""
    if not doc:
        return doc
    paragraphs = [" ".join(line.strip() for line in block.splitlines() if line.strip())
                  for block in inspect.cleandoc(doc).split("\n\n")]
    return "\n\n".join(p for p in paragraphs if p)


#: What to make smaller when a command runs out of memory, by command (None: any other).
_MEMORY_HINTS = {
    "train": "use --max-points or --subsample to train on fewer points (or a lower --train-rate)",
    "crossval": "use --max-points or --subsample to train on fewer points (or a lower --train-rate)",
    "rollout": "ask for fewer or shorter motions (--count, --samples, --duration, --steps, --dt, --output-rate)",
    "evaluate": "score fewer or shorter trajectories (--count, --length)",
    None: "give it less data at once",
}


def command(func):
    """Wrap a command: rbgp errors become one line on stderr with their exit code (2 for bad input,
    1 for runtime failures); any other exception is an internal error (exit 1, no traceback unless
    RBGP_DEBUG=1). Library warnings of type RbgpWarning are printed as ``rbgp: warning: ...``.

    Every command also gets ``-q/--quiet`` (so ``rbgp train ... -q`` works as ``rbgp -q train ...``),
    and ``rbgp --json COMMAND`` sets the command's own ``--json``. Progress reported through
    :data:`progress` while the command runs is drawn for the current stderr."""
    sig = inspect.signature(func, eval_str=True)
    has_json = "json_out" in sig.parameters
    func.__doc__ = prose(func.__doc__)  # functools.wraps copies it to the wrapper Typer reads

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        from rbgp_cli.errors import InputError, RbgpError, RbgpWarning

        if kwargs.pop("rbgp_quiet", False):
            set_quiet(True)
        with warnings.catch_warnings():
            warnings.simplefilter("always", RbgpWarning)
            warnings.simplefilter("ignore", DeprecationWarning)
            warnings.showwarning = _show_warning
            try:
                if _JSON["on"]:
                    if not has_json:
                        raise InputError(f"rbgp {func.__name__} has no --json output", hint="leave out --json")
                    kwargs["json_out"] = True
                with _progress_session(), _signals_as_exceptions(), _guarded_stdout():
                    result = func(*args, **kwargs)
                    sys.stdout.flush()  # a full disk under stdout fails here, inside the command
                    if _INTERRUPTED["on"]:  # a Ctrl-C that a library swallowed (an optional import's except
                        raise KeyboardInterrupt  # ImportError) is still the interruption: never lost silently
                    return result
            except typer.Exit:
                raise
            except RbgpError as exc:
                _stderr(f"rbgp: error: {as_flags(exc)}")
                raise typer.Exit(exc.exit_code) from None
            except KeyboardInterrupt:
                _stderr("rbgp: interrupted")
                raise typer.Exit(130) from None
            except BrokenPipeError:
                # the reader of our stdout went away (e.g. `| head`): not an error of ours
                try:
                    sys.stdout = open(os.devnull, "w")
                except OSError:
                    pass
                raise typer.Exit(0) from None
            except MemoryError:
                _stderr(f"rbgp: error: out of memory; {_MEMORY_HINTS.get(func.__name__, _MEMORY_HINTS[None])}")
                raise typer.Exit(1) from None
            except OSError as exc:
                line = _resource_error(exc)
                if line is None:
                    if os.environ.get("RBGP_DEBUG"):
                        raise
                    text = " ".join(str(exc).split())[:300]
                    line = f"rbgp: internal error: {type(exc).__name__}: {text} (set RBGP_DEBUG=1 for a traceback)"
                _stderr(line)
                raise typer.Exit(1) from None
            except Exception as exc:  # noqa: BLE001 - the last line of defence: no tracebacks for users
                if _INTERRUPTED["on"]:  # a failure Ctrl-C caused (e.g. inside an import) is the interruption
                    _stderr("rbgp: interrupted")
                    raise typer.Exit(130) from None
                if os.environ.get("RBGP_DEBUG"):
                    raise
                text = " ".join(str(exc).split())[:300]
                _stderr(f"rbgp: internal error: {type(exc).__name__}: {text} (set RBGP_DEBUG=1 for a traceback)")
                raise typer.Exit(1) from None

    quiet = inspect.Parameter("rbgp_quiet", inspect.Parameter.KEYWORD_ONLY, default=False,
                              annotation=Annotated[bool, typer.Option("--quiet", "-q", help=_QUIET_HELP)])
    wrapper.__signature__ = sig.replace(parameters=[*sig.parameters.values(), quiet])
    return wrapper


def _option_flags(other_commands: bool = False) -> dict:
    """{Python name: its long flag} of the running command's options (``steps`` → ``--steps``,
    ``fmt`` → ``--format``), from Click's context; {} outside a command. Each option is also there
    under its flag's own name (``format`` → ``--format``: the library's name where the command's
    differs), and an on/off flag under ``NAME=True`` and ``NAME=False`` (``degrees=False`` →
    ``--radians``). ``other_commands``: then also the other commands' options that the running one
    lacks (a message can say what to train or retrain with)."""
    try:  # Typer >= 0.29 vendors click (/work/shared/ECOSYSTEM.md)
        from typer._click.globals import get_current_context
    except ImportError:  # pragma: no cover - an older Typer on click
        from click import get_current_context

    ctx = get_current_context(silent=True)
    if ctx is None:
        return {}

    def commands(cmd):
        yield cmd
        for sub in (getattr(cmd, "commands", None) or {}).values():
            yield from commands(sub)

    flags: dict = {}
    for cmd in (ctx.command, *(commands(ctx.find_root().command) if other_commands else ())):
        own: dict = {}
        for p in cmd.params:
            if getattr(p, "param_type_name", "") == "option" and p.name:
                longs = [o for o in p.opts if o.startswith("--")] or list(p.opts)
                if longs:
                    own[p.name] = longs[0]
                    own.setdefault(longs[0][2:].replace("-", "_"), longs[0])
                    off = [o for o in getattr(p, "secondary_opts", ()) if o.startswith("--")]
                    if getattr(p, "is_flag", False) and off:
                        own[f"{p.name}=True"], own[f"{p.name}=False"] = longs[0], off[0]
        for name, flag in own.items():
            flags.setdefault(name, flag)
    return flags


def as_flags(exc, flags: Optional[dict] = None) -> str:
    """The one-line text of an rbgp error as the command line says it: the library names the
    parameters a message is about, the command line its options (``steps`` → ``--steps``).
    Replaced, as whole words:

    * every option name of the running command with an underscore (``max_points`` →
      ``--max-points``), anywhere;
    * the names in ``exc.param`` (one name, e.g. ``steps``, or a tuple of them), options of the
      running command or else of another one (``rbgp predict``: "train a model with time_input
      none" → ``--time-input none``): with an underscore anywhere, a one-word name at the start of
      the message or of one of its "; "-separated parts and anywhere in the hint, so that the
      message can use the same word plainly ("no time column (columns are ...)"; hint "pass rate
      HZ or columns t=NAME"). An on/off flag's name is replaced only as ``NAME=True`` /
      ``NAME=False`` (``degrees=False`` → ``--radians``), so that "in degrees" stays a plain word.

    A name already written as a flag, or in brackets (``rbgp-cli[plot]``), stays as it is."""
    import re

    own = _option_flags() if flags is None else flags
    flags = _option_flags(other_commands=True) if flags is None else flags
    under = {n for n in own if "_" in n and n != "rbgp_quiet"}
    text = f"{exc.message} {exc.hint or ''}"
    params = (exc.param,) if isinstance(exc.param, str) else tuple(exc.param or ())
    ones = set()
    for param in params:
        for name in ((f"{param}=True", f"{param}=False") if f"{param}=True" in flags else (param,)):
            if name in flags and flags[name] not in text:  # a message that names the flag already
                (under if "_" in name else ones).add(name)
    if not under and not ones:
        return exc.format()

    def pattern(names, start=False):
        alts = "|".join(sorted(map(re.escape, names), key=len, reverse=True))
        before = r"(?:^|(?<=; ))" if start else r"(?<![\w\-/\[])(?<!\d )"
        return re.compile(before + f"({alts})" + r"(?![\w\-/\]])") if names else None

    def sub(text, *patterns):
        for pat in patterns:
            if text is not None and pat is not None:
                text = pat.sub(lambda m: flags[m.group(1)], text)
        return text

    from rbgp_cli.errors import RbgpError

    anywhere = pattern(under | ones)
    message = sub(exc.message, pattern(under), pattern(ones, start=True))
    return RbgpError(message, path=exc.path, row=exc.row, topic=exc.topic, hint=sub(exc.hint, anywhere)).format()


def flag_words(text: str) -> str:
    """Multi-line report text (``rbgp inspect``) with the library's parameter names written as the
    running command's options, as :func:`as_flags` does for one-line errors (``quat_order`` →
    ``--quat-order``; names with an underscore only)."""
    import re

    flags = _option_flags()
    names = {n for n in flags if "_" in n and n != "rbgp_quiet"}
    if not names:
        return text
    pattern = re.compile(r"(?<![\w\-])(?<!\d )(" + "|".join(sorted(map(re.escape, names), key=len, reverse=True)) + r")(?![\w\-])")
    return pattern.sub(lambda m: flags[m.group(1)], text)


def need_flags(text: str) -> str:
    """One entry of what ``rbgp inspect`` says is still needed (:func:`rbgp_cli.io.inspect.needs`):
    it starts with the parameters it needs, joined by "or" (``rate HZ (no time column)``, ``rate or
    columns (see the error)``); those written as the running command's options, and the names with
    an underscore anywhere (:func:`flag_words`)."""
    flags = _option_flags()
    words = text.split(" ")
    for i, w in enumerate(words):
        if w in flags and w != "rbgp_quiet":
            words[i] = flags[w]
        elif w != "or" or i == 0:
            break
    return flag_words(" ".join(words))


def emit_json(obj) -> None:
    """Write JSON to stdout (data), one document, newline-terminated; a float NaN anywhere in it (a
    method without samples has no coverage) is written as null, since JSON has no NaN."""
    sys.stdout.write(json.dumps(_nan_to_null(obj), indent=2, sort_keys=False, default=_json_default,
                                allow_nan=False) + "\n")
    sys.stdout.flush()


def _nan_to_null(obj):
    """``obj`` with every float NaN inside its dicts, lists and numpy arrays replaced by None."""
    if isinstance(obj, dict):
        return {k: _nan_to_null(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_nan_to_null(v) for v in obj]
    if type(obj).__module__ == "numpy" and hasattr(obj, "tolist"):
        return _nan_to_null(obj.tolist())
    return None if isinstance(obj, float) and obj != obj else obj


def _json_default(o):
    import numpy as np

    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def _drop_stdout() -> None:
    """Send what is still buffered for stdout (and anything later) to the null device, so that the
    interpreter's last flush does not fail a second time."""
    try:
        null = os.open(os.devnull, os.O_WRONLY)
        os.dup2(null, sys.stdout.fileno())
        os.close(null)
    except (OSError, ValueError, AttributeError):  # not a real file (CliRunner's capture)
        pass


def check_files(paths: dict, *, what: str = "file") -> None:
    """Refuse '-' for outputs that are files, not streams (a figure, a recording, a folder): ``paths`` maps each
    option's flag (``"--plot"``) to its value; ``what`` names what the option writes."""
    from rbgp_cli.errors import InputError

    for flag, path in paths.items():
        if path is not None and str(path) == "-":
            raise InputError(f"{flag} - would mean stdout, but {flag} writes a {what}", hint=f"give {flag} a {what} name")


def check_outputs(*paths: Optional[str]) -> None:
    """Refuse output paths that cannot be written, before any work (reading, training, rolling out):
    each must name a file whose folder exists and is writable (:func:`rbgp_cli.workflows.check_writable`,
    the check of ``train -o``). None (option not given) and '-' (stdout) pass."""
    from rbgp_cli.workflows import check_writable

    for path in paths:
        if path is not None and str(path) == "-" and stdout_is_closed():
            from rbgp_cli.errors import InputError

            raise InputError("'-' writes to stdout, but stdout is closed (>&-)",
                             hint="redirect it instead (> FILE), or give a file name")
        if path is not None and str(path) != "-":
            check_writable(path)


def write_text_output(path: Optional[str], writer) -> None:
    """Call ``writer(stream)`` on stdout (path None or '-') or on a file written atomically."""
    if path is None or str(path) == "-":
        try:
            writer(sys.stdout)
            sys.stdout.flush()
        except BrokenPipeError:
            raise
        except OSError as exc:  # stdout redirected into a file on a full disk or past the size limit
            from rbgp_cli.io.atomic import write_error

            _drop_stdout()
            raise write_error("stdout", exc) from None
        return
    from rbgp_cli.io.atomic import atomic_open
    from rbgp_cli.workflows import check_writable

    check_writable(path)
    with atomic_open(path, "w", newline="", encoding="utf-8") as fh:
        writer(fh)


# ---------------------------------------------------------------------------------------------
# Read options: one Annotated alias per flag, so every command that reads demonstrations spells them
# the same way.
_READ = READ_PANEL = "Reading demonstrations"
def _format_help() -> str:
    from rbgp_cli.io.formats import help_text  # the registry lists the formats (no reader is imported)

    return help_text()


FormatOpt = Annotated[str, typer.Option("--format", help=_format_help(), rich_help_panel=_READ)]
ColumnsOpt = Annotated[Optional[str], typer.Option("--columns", help="Explicit CSV column mapping, e.g. 't=stamp,qw=w,x=px'.", rich_help_panel=_READ)]
QuatOrderOpt = Annotated[Optional[str], typer.Option("--quat-order", help="xyzw or wxyz: the order of quaternion columns named q0..q3; for columns named qx..qw it overrides the names (the four columns in file order).", rich_help_panel=_READ)]
EulerOrderOpt = Annotated[Optional[str], typer.Option("--euler-order", help="Euler sequence, scipy style: xyz extrinsic, XYZ intrinsic.", rich_help_panel=_READ)]
DegreesOpt = Annotated[Optional[bool], typer.Option("--degrees/--radians", help="Euler angles in degrees or radians (default: from the file).", rich_help_panel=_READ)]
LengthUnitOpt = Annotated[Optional[str], typer.Option("--length-unit", help="m, cm or mm (default: from the file; BVH: cm).", rich_help_panel=_READ)]
TimeUnitOpt = Annotated[Optional[str], typer.Option("--time-unit", help="s, ms, us or ns (default: from the column name).", rich_help_panel=_READ)]
RateOpt = Annotated[Optional[float], typer.Option("--rate", help="Sample rate in Hz when the file has no time column.", rich_help_panel=_READ)]
TopicOpt = Annotated[Optional[str], typer.Option("--topic", help="MCAP topic (default: the only pose topic).", rich_help_panel=_READ)]
FrameOpt = Annotated[Optional[str], typer.Option("--frame", help="Child frame of TF messages.", rich_help_panel=_READ)]
TimeSourceOpt = Annotated[str, typer.Option("--time", help="MCAP time: header (message stamps) or log.", rich_help_panel=_READ)]
BodyOpt = Annotated[Optional[str], typer.Option("--body", help="Rigid body / segment name in vendor exports, C3D cluster or segment ('A,B,C': its markers), BVH joint ('all' for every body).", rich_help_panel=_READ)]
RotationOpt = Annotated[Optional[str], typer.Option("--rotation", help="Vicon RX,RY,RZ: helical (axis-angle, default) or euler.", rich_help_panel=_READ)]
FileOrderOpt = Annotated[str, typer.Option("--file-order", help="The order the files are read in, which is the demonstrations' recording order (band calibration in recording order, the drift test, crossval --order recorded, trajectory names): given (a folder's or a pattern's files in natural name order, take_2 before take_10; files named one by one as given), name (every file in natural name order, also those a shell glob expanded, which sorts take_10 before take_2) or mtime (by modification time, oldest first).", rich_help_panel=_READ)]
MaxGapOpt = Annotated[Optional[float], typer.Option("--max-gap", help="Fill runs of lost frames up to this many seconds by slerp (default: drop them).", rich_help_panel=_READ)]
SplitGapOpt = Annotated[Optional[float], typer.Option("--split-gap", metavar="SECONDS", help="Split a demonstration where no sample arrives for longer than this: a break between takes or a tracker outage (default: 20 × its median sampling interval and at least 2 s; inf keeps it whole).", rich_help_panel=_READ)]
CropFromOpt = Annotated[Optional[float], typer.Option("--crop-from", metavar="SECONDS", help="Keep only the samples from this many seconds after each take's first sample.", rich_help_panel=_READ)]
CropToOpt = Annotated[Optional[float], typer.Option("--crop-to", metavar="SECONDS", help="Keep only the samples up to this many seconds after each take's first sample.", rich_help_panel=_READ)]
SplitAtRestOpt = Annotated[bool, typer.Option("--split-at-rest", help="Cut each take into repetitions separated by rests (see --rest-speed, --rest-time); each repetition is a demonstration.", rich_help_panel=_READ)]
RestSpeedOpt = Annotated[Optional[float], typer.Option("--rest-speed", metavar="M/S", help="With --split-at-rest: at rest below this speed (and 0.3 rad/s), measured over 0.1 s (default 0.03 m/s).", rich_help_panel=_READ)]
RestTimeOpt = Annotated[Optional[float], typer.Option("--rest-time", metavar="SECONDS", help="With --split-at-rest: the shortest rest that separates repetitions; shorter motions are left out (default 0.5 s).", rich_help_panel=_READ)]


def parse_columns(text: Optional[str]) -> Optional[dict]:
    if not text:
        return None
    from rbgp_cli.errors import InputError

    out = {}
    for part in text.split(","):
        if not part.strip():
            continue
        k, eq, v = part.partition("=")
        if not eq or not k.strip() or not v.strip():  # 't=' or '=stamp': a key or a column name missing
            raise InputError(f"--columns entry {part.strip()!r} is not KEY=NAME", hint="e.g. --columns t=stamp,qw=w")
        out[k.strip()] = v.strip()
    return out


def read_options(fmt="auto", columns=None, quat_order=None, euler_order=None, degrees=None, length_unit=None,
                 time_unit=None, rate=None, topic=None, frame=None, time_source="header", body=None, rotation=None,
                 file_order="given", *, split_gap=None, crop_from=None, crop_to=None, split_at_rest=False, rest_speed=None, rest_time=None):
    """Validate the flags and build :class:`rbgp_cli.io.options.ReadOptions`."""
    from rbgp_cli.errors import InputError
    from rbgp_cli.io.formats import choices
    from rbgp_cli.io.options import LENGTH_UNITS, ReadOptions

    if fmt not in choices():
        raise InputError(f"unknown --format {fmt!r}; expected one of {', '.join(choices())}")
    if quat_order is not None and quat_order.lower() not in ("xyzw", "wxyz"):
        raise InputError(f"--quat-order must be xyzw or wxyz, got {quat_order!r}")
    if length_unit is not None and length_unit not in LENGTH_UNITS:
        raise InputError(f"--length-unit must be one of {', '.join(LENGTH_UNITS)}, got {length_unit!r}")
    if time_unit is not None and time_unit not in ("s", "ms", "us", "ns"):
        raise InputError(f"--time-unit must be s, ms, us or ns, got {time_unit!r}")
    if rate is not None and not (rate > 0 and rate < float("inf")):
        raise InputError(f"--rate must be a positive number of Hz, got {rate}")
    if time_source not in ("header", "log"):
        raise InputError(f"--time must be header or log, got {time_source!r}")
    if rotation is not None and rotation not in ("helical", "euler"):
        raise InputError(f"--rotation must be helical or euler, got {rotation!r}")
    if file_order not in ("given", "name", "mtime"):
        raise InputError(f"--file-order must be given, name or mtime, got {file_order!r}")
    for name, v in (("--split-gap", split_gap), ("--rest-speed", rest_speed), ("--rest-time", rest_time)):
        if v is not None and not v > 0:
            raise InputError(f"{name} must be a positive number, got {v}")
    for name, v in (("--crop-from", crop_from), ("--crop-to", crop_to)):
        if v is not None and not (0 <= v < float("inf")):
            raise InputError(f"{name} must be a finite, non-negative number of seconds, got {v}",
                             hint="leave it out to keep the whole take" if v == float("inf") else None)
    if crop_from is not None and crop_to is not None and crop_to <= crop_from:
        raise InputError(f"--crop-to {crop_to:g} must be later than --crop-from {crop_from:g}")
    if not split_at_rest and (rest_speed is not None or rest_time is not None):
        raise InputError("--rest-speed and --rest-time apply to --split-at-rest", hint="add --split-at-rest")
    return ReadOptions(
        format=fmt, columns=parse_columns(columns), quat_order=None if quat_order is None else quat_order.lower(),
        euler_order=euler_order, degrees=degrees, length_unit=length_unit, time_unit=time_unit, rate=rate,
        topic=topic, frame=frame, time_source=time_source, body=body, rotation=rotation, file_order=file_order,
        split_gap=split_gap, crop_from=crop_from, crop_to=crop_to, split_at_rest=bool(split_at_rest),
        rest_speed=rest_speed, rest_time=rest_time,
    )


#: The read options, in the order --help shows them: (parameter name, annotated type, default).
#: :func:`with_read_options` gives a command all of them; add a new read option here and every
#: command that reads demonstrations gets it (tests/cli/test_read_options_cli.py checks that).
_READ_PARAMS = (
    ("fmt", FormatOpt, "auto"), ("columns", ColumnsOpt, None), ("quat_order", QuatOrderOpt, None),
    ("euler_order", EulerOrderOpt, None), ("degrees", DegreesOpt, None), ("length_unit", LengthUnitOpt, None),
    ("time_unit", TimeUnitOpt, None), ("rate", RateOpt, None), ("topic", TopicOpt, None), ("frame", FrameOpt, None),
    ("time_source", TimeSourceOpt, "header"), ("body", BodyOpt, None), ("rotation", RotationOpt, None),
    ("file_order", FileOrderOpt, "given"), ("max_gap", MaxGapOpt, None), ("split_gap", SplitGapOpt, None), ("crop_from", CropFromOpt, None),
    ("crop_to", CropToOpt, None), ("split_at_rest", SplitAtRestOpt, False), ("rest_speed", RestSpeedOpt, None),
    ("rest_time", RestTimeOpt, None),
)


@dataclasses.dataclass(frozen=True)
class ReadArgs:
    """What a command's read options say: ``options`` (:class:`rbgp_cli.io.options.ReadOptions`,
    checked by :func:`read_options`) and ``max_gap`` (seconds, or None: drop lost frames)."""

    options: object
    max_gap: Optional[float] = None


def with_read_options(func=None, *, max_gap: bool = True):
    """Give a command every read option (``--format`` … ``--max-gap``), declared once.

    The command declares one parameter ``read`` instead of the flags; this decorator replaces it in
    the signature Typer sees by the flags of :data:`_READ_PARAMS` (after the command's own options,
    in the "Reading demonstrations" panel of --help) and calls the command with
    ``read=ReadArgs(read_options(...), max_gap)``. Put it under :func:`command`, so that a bad value
    is a one-line error::

        @app.command()
        @command
        @with_read_options
        def train(demos: ..., read: ReadArgs = None): ...

    ``max_gap=False`` leaves ``--max-gap`` out (for a command that reads but does not clean).
    """
    if func is None:
        return functools.partial(with_read_options, max_gap=max_gap)
    sig = inspect.signature(func, eval_str=True)
    if "read" not in sig.parameters:
        raise TypeError(f"{func.__name__}: with_read_options needs a parameter named 'read'")
    specs = [s for s in _READ_PARAMS if max_gap or s[0] != "max_gap"]
    names = [name for name, _, _ in specs]

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        values = {name: kwargs.pop(name, default) for name, _, default in specs}
        gap = values.pop("max_gap", None)
        kwargs["read"] = ReadArgs(read_options(**values), gap)
        return func(*args, **kwargs)

    own = [p for name, p in sig.parameters.items() if name != "read"]
    clash = set(names) & {p.name for p in own}
    if clash:
        raise TypeError(f"{func.__name__}: parameters {sorted(clash)} clash with the read options")
    added = [inspect.Parameter(name, inspect.Parameter.KEYWORD_ONLY, default=default, annotation=annotation)
             for name, annotation, default in specs]
    wrapper.__signature__ = sig.replace(parameters=[*own, *added])
    return wrapper
