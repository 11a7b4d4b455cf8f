"""The command line as people type it: several paths after one flag, and global flags anywhere.

A shell expands an unquoted glob before rbgp sees it, so ``rbgp rollout m.rbgp --from-demos
data/*.csv --count 20`` arrives as ``--from-demos data/a.csv data/b.csv ... --count 20``. Click gives
an option one value per flag; this module rewrites the arguments of a subcommand before Click parses
them, so that an option declared with :func:`paths_option` takes **every path after it, up to the
next option** (``--from-demos a b c`` becomes ``--from-demos a --from-demos b --from-demos c``), the
same list a folder or a quoted glob gives. ``--demos=PATH`` (with ``=``) takes exactly one path, and
``--`` ends every list.

Where the list left a required argument without a value (``rbgp rollout --from-demos data/*.csv
m.rbgp``: the model file was taken as a demonstration), the error says so and shows the command
line to write instead (:func:`took_too_much`).

:class:`RbgpGroup` is the Typer group class of the ``rbgp`` app; it applies the rewriting to every
subcommand, so a new command gets it by declaring its path options with :func:`paths_option`.
``-q/--quiet`` and ``--json`` are accepted before and after the subcommand; see
:func:`rbgp_cli.cli.common.command`.
"""

from __future__ import annotations

import shlex
import sys

import typer
from typer.core import TyperGroup

__all__ = ["PATHS_METAVAR", "paths_option", "RbgpGroup", "expand_path_lists", "took_too_much"]

#: The metavar of an option that takes several paths after one flag. The rewriting below recognises
#: such options by it, and ``--help`` shows it, so what the help says and what the parser does agree.
PATHS_METAVAR = "PATH..."

#: What the last rewriting did: the subcommand's name, the arguments as typed, and the runs of paths
#: the path options took, in order (read by :func:`took_too_much` when a command finds an argument
#: missing).
_LAST = {"command": None, "args": [], "runs": []}


def paths_option(*decls: str, help: str, **kwargs):
    """A ``typer.Option`` that takes one or more paths after one flag (and may be repeated).

    Use it with a ``List[str]`` parameter: ``demos: Annotated[Optional[List[str]], paths_option("--demos",
    help="...")] = None``.
    """
    return typer.Option(*decls, help=help, metavar=PATHS_METAVAR, **kwargs)


def _is_paths_option(param) -> bool:
    return getattr(param, "param_type_name", "") == "option" and bool(getattr(param, "multiple", False)) \
        and param.metavar == PATHS_METAVAR


def _takes_value(param) -> bool:
    return not (getattr(param, "is_flag", False) or getattr(param, "count", False))


def _is_option_like(token: str) -> bool:
    """True for ``-x``, ``--xy``, ``--`` (the end of a list); ``-`` (stdin) is a path."""
    return token.startswith("-") and token != "-"


def _options_by_flag(command) -> dict:
    return {flag: p for p in command.params if getattr(p, "param_type_name", "") == "option"
            for flag in [*p.opts, *getattr(p, "secondary_opts", [])]}


def expand_path_lists(command, args: list[str]) -> tuple[list[str], list[tuple[str, list[str]]]]:
    """Rewrite ``args`` of ``command`` (a Click command) so that each path option takes every path after it.

    Returns the rewritten arguments and, in order, (flag as typed, the paths it took) for each
    occurrence of a path option. Values of other options are skipped exactly as Click reads them (an
    option that takes a value takes the next token, whatever it is), and everything after ``--`` is
    left alone.
    """
    by_flag = _options_by_flag(command)
    out: list[str] = []
    runs: list[tuple[str, list[str]]] = []
    i, n = 0, len(args)
    while i < n:
        tok = args[i]
        if tok == "--":
            out.extend(args[i:])
            break
        p = by_flag.get(tok)
        if p is None or not _takes_value(p):
            out.append(tok)  # a positional, a flag, --opt=value, or an unknown option (Click reports it)
            i += 1
            continue
        if not _is_paths_option(p):
            out.extend(args[i:i + 2])
            i += 2
            continue
        j = i + 1
        while j < n and not _is_option_like(args[j]):
            j += 1
        values = args[i + 1:j]
        if not values:  # "--demos" at the end or before another option: Click says it needs a value
            out.append(tok)
        for v in values:
            out.extend([tok, v])
        runs.append((tok, values))
        i = j
    return out, runs


def _positionals_needed(command) -> list[tuple[str, int]]:
    """(metavar, how many) of each required argument: 1, or 1 for "one or more" (nargs=-1)."""
    need = []
    for p in command.params:
        if getattr(p, "param_type_name", "") == "argument" and p.required:
            need.append(((p.name or "ARG").upper(), 1 if p.nargs == -1 else max(int(p.nargs), 1)))
    return need


def _count_positionals(command, args: list[str]) -> int:
    by_flag = _options_by_flag(command)
    count, i = 0, 0
    while i < len(args):
        tok = args[i]
        if tok == "--":
            return count + len(args) - i - 1
        p = by_flag.get(tok)
        if p is not None:
            i += 2 if _takes_value(p) else 1
            continue
        if not _is_option_like(tok):
            count += 1
        i += 1
    return count


def _shorten(values: list[str], keep: int = 3) -> str:
    if len(values) <= keep + 1:
        return " ".join(shlex.quote(v) for v in values)
    return " ".join(shlex.quote(v) for v in values[:keep - 1]) + " … " + shlex.quote(values[-1])


def took_too_much(what: str, missing: int = 1, *, alternative: str | None = None) -> str | None:
    """The message for "``what`` is missing" when a path list of the last command line took the
    last ``missing`` paths after it: which flag took them, and the command line to write instead
    (those paths moved before the list). The last list typed is meant; None when it took no more than
    ``missing`` paths (then it cannot have taken them from something else)."""
    if not _LAST["runs"] or _LAST["command"] is None:
        return None
    flag, run = _LAST["runs"][-1]
    if len(run) <= missing:
        return None
    moved = run[-missing:]
    kept = run[:-missing]
    typed = list(_LAST["args"])
    # rebuild the command line: the moved paths first, the list without them where it was
    fixed: list[str] = []
    i = 0
    done = False
    while i < len(typed):
        tok = typed[i]
        if not done and tok == flag and typed[i + 1:i + 1 + len(run)] == run:
            fixed.append(f"{flag} {_shorten(kept)}")
            i += 1 + len(run)
            done = True
            continue
        fixed.append(shlex.quote(tok))
        i += 1
    suggestion = " ".join(["rbgp", _LAST["command"], *(shlex.quote(m) for m in moved), *fixed])
    names = " ".join(moved)
    msg = (f"{what} missing: {flag} takes every path after it up to the next option, so it also took {names}; "
           f"if {'that is' if missing == 1 else 'those are'} meant as {what}, write {'it' if missing == 1 else 'them'} "
           f"before the list: {suggestion}")
    if alternative:
        msg += f" ({alternative})"
    return msg


def _usage_errors():
    """Click's (NoArgsIsHelpError, UsageError) classes, from the click Typer uses."""
    try:  # Typer >= 0.29 vendors click (/work/shared/ECOSYSTEM.md)
        from typer._click.exceptions import NoArgsIsHelpError, UsageError
    except ImportError:  # pragma: no cover - an older Typer on click
        from click.exceptions import NoArgsIsHelpError, UsageError
    return NoArgsIsHelpError, UsageError


def _usage_error_line(exc) -> None:
    """Click's usage error (an option's value out of range, an unknown option, a missing argument) as
    rbgp says every bad-usage error: one line on stderr, ``rbgp: error: MESSAGE; see rbgp CMD --help``,
    then exit 2. (Typer would draw a box of five or more lines with the usage above it.)"""
    ctx = getattr(exc, "ctx", None)
    where = ctx.command_path if ctx is not None else "rbgp"
    msg = " ".join(exc.format_message().split()).rstrip(".")
    print(f"rbgp: error: {msg}; see {where} --help", file=sys.stderr, flush=True)
    raise typer.Exit(exc.exit_code)


#: The narrowest terminal (columns) that gets Typer's boxed help panels: below it, and when --help is piped to a
#: narrower width, the help is Click's plain two-column list. The panels keep a column for each option's type and
#: wrap the help in what is left, so at 80 columns `rbgp train --help` ran to 448 lines (216 plain).
PANELS_FROM = 100


def help_width() -> int:
    """The width help is laid out for: Typer's TERMINAL_WIDTH if set, else the terminal's (COLUMNS, then the
    terminal itself, else 80)."""
    import os
    import shutil

    env = os.environ.get("TERMINAL_WIDTH")
    if env and env.strip().isdigit():
        return int(env)
    return shutil.get_terminal_size((80, 24)).columns


def set_help_layout(cmd) -> None:
    """Boxed panels (Typer's rich help) from :data:`PANELS_FROM` columns on, Click's plain list below, for ``cmd``
    and every command under it."""
    mode = "rich" if help_width() >= PANELS_FROM else None
    stack = [cmd]
    while stack:
        c = stack.pop()
        if hasattr(c, "rich_markup_mode"):
            c.rich_markup_mode = mode
        stack.extend((getattr(c, "commands", None) or {}).values())


def _show_plain_help(exc) -> None:
    """Print a no-argument invocation's help (``rbgp``, ``rbgp bench``) in the plain layout. Typer prints the panels
    while it builds the help and shows the error itself as nothing. The plain help is only the exception's message,
    so it goes to stdout here, as the panels do (exit 2 either way)."""
    ctx = getattr(exc, "ctx", None)
    if ctx is not None and getattr(ctx.command, "rich_markup_mode", "rich") is None:
        typer.echo(exc.format_message())


class RbgpGroup(TyperGroup):
    """The ``rbgp`` group: rewrites each subcommand's arguments with :func:`expand_path_lists`, stops
    with one clear line when a path list took a required argument, prints Click's usage errors as
    one line (:func:`_usage_error_line`), and lays out help for the terminal's width (:func:`set_help_layout`)."""

    def format_help(self, ctx, formatter):
        set_help_layout(self)
        return super().format_help(ctx, formatter)

    def make_context(self, info_name, args, parent=None, **extra):
        NoArgsIsHelpError, UsageError = _usage_errors()
        # the plain help fills the terminal less Click's margin of 2 (Click stops at 80 columns by default, and a test
        # runner forces 80); subcommands inherit the width
        width = help_width()
        extra.setdefault("max_content_width", width)
        extra.setdefault("terminal_width", max(width - 2, 50))
        try:
            return super().make_context(info_name, args, parent=parent, **extra)
        except NoArgsIsHelpError as exc:
            _show_plain_help(exc)
            raise
        except UsageError as exc:  # the group's own options: rbgp --bogus
            _usage_error_line(exc)

    def invoke(self, ctx):
        NoArgsIsHelpError, UsageError = _usage_errors()
        try:
            return super().invoke(ctx)
        except NoArgsIsHelpError as exc:
            _show_plain_help(exc)
            raise
        except UsageError as exc:  # a subcommand's options and arguments, or an unknown command
            _usage_error_line(exc)

    def resolve_command(self, ctx, args):
        name, cmd, rest = super().resolve_command(ctx, args)
        if cmd is None:
            return name, cmd, rest
        if "--help" in rest or "-h" in rest or not rest:
            set_help_layout(cmd)
        rewritten, runs = expand_path_lists(cmd, list(rest))
        _LAST.update(command=name, args=list(rest), runs=runs)
        if runs and "--help" not in rest:
            have = _count_positionals(cmd, rewritten)
            unfilled, missing = [], 0
            for metavar, count in _positionals_needed(cmd):
                take = min(have, count)
                have -= take
                if take < count:
                    unfilled.append(metavar)
                    missing += count - take
            msg = took_too_much(" and ".join(unfilled), missing) if missing else None
            if msg:
                print(f"rbgp: error: {msg}", file=sys.stderr, flush=True)
                raise typer.Exit(2)
        return name, cmd, rewritten
