"""Every command's help reads as prose: paragraphs wrapped by the terminal, not by the source file's
line breaks; and option help that is still true."""

from __future__ import annotations

import re

import pytest
import typer
from typer.testing import CliRunner

from rbgp_cli.cli.app import app
from rbgp_cli.cli.common import prose

COLUMNS = 200


def _commands():
    """Every command path: [], ["train"], ..., ["bench"], ["bench", "paper"]."""
    out = []

    def walk(cmd, path):
        out.append(path)
        for name, sub in sorted((getattr(cmd, "commands", None) or {}).items()):
            walk(sub, [*path, name])

    walk(typer.main.get_command(app), [])
    return out


def _help(path, columns=COLUMNS) -> str:
    res = CliRunner().invoke(app, [*path, "--help"], env={"COLUMNS": str(columns), "TERMINAL_WIDTH": str(columns)})
    assert res.exit_code == 0, res.output
    return res.stdout


def ragged_breaks(text: str, columns: int) -> list[str]:
    """Line breaks inside a paragraph that the terminal did not make: the next line continues the same
    paragraph (the same column in the description, or the help column of a panel's row) and its first
    word would have fitted on the line before."""
    found = []
    lines = text.splitlines()
    listed, listing = [], False  # plain layout: whether each line is in an Arguments:, Options: or Commands: list
    for line in lines:
        if re.fullmatch(r"[A-Z][\w ]*:", line):
            listing = True
        elif line and not line.startswith(" "):
            listing = False
        listed.append(listing)
    for i, (a, b) in enumerate(zip(lines, lines[1:])):
        boxed = a.startswith("│") and b.startswith("│")
        ia, ib = (a[1:-1], b[1:-1]) if boxed else (a, b)
        width = len(ia) if boxed else columns
        if not ia.strip() or not ib.strip():
            continue
        start_a = len(ia) - len(ia.lstrip())
        start_b = len(ib) - len(ib.lstrip())
        if boxed:  # a continuation row is blank up to the help column, where row a's text also runs
            if start_b <= start_a or start_b >= len(ia) or ia[start_b - 1] != " " or ia[start_b] == " ":
                continue
        elif start_b != start_a:
            continue
        word = ib.split()[0]
        if word.startswith("["):  # Typer's own line for [default: ...] / [required]: its layout, not ours
            continue
        if boxed and (word.startswith("-") or ib.lstrip().startswith("*")):  # the next option's row
            continue
        if not boxed and listed[i + 1] and start_b == 2:  # plain layout: a list's next row (its term at 2)
            continue
        if boxed and ia.lstrip().startswith("*") and start_b == start_a + 1 + len(ia[start_a + 1:]) - len(ia[start_a + 1:].lstrip()):
            continue  # an optional argument's row after a required one's: it starts where that one's name does
        if len(ia.rstrip()) + 1 + len(word) <= width - 2:
            found.append(f"{ia.rstrip()}⏎{ib.strip()[:40]}")
    return found


def test_the_check_finds_a_hard_wrapped_paragraph():
    """The oracle itself: a docstring's own line breaks (as Typer's rich help keeps them) are found, and
    the same text as one paragraph per line is not."""
    hard = "First paragraph.\n\nThe second one is long enough\nto have been wrapped by hand\nin the source file."

    def make(doc):
        sub = typer.Typer(add_completion=False)

        def go(x: int = 1):
            pass

        go.__doc__ = doc
        sub.command()(go)
        return sub

    for doc, ragged in ((hard, True), (prose(hard), False)):
        res = CliRunner().invoke(make(doc), ["--help"], env={"COLUMNS": str(COLUMNS)})
        assert bool(ragged_breaks(res.stdout, COLUMNS)) is ragged, res.stdout


@pytest.mark.slow
@pytest.mark.parametrize("columns", [COLUMNS, 90])
def test_no_command_help_has_a_ragged_paragraph(columns):
    for path in _commands():
        text = _help(path, columns)
        assert not ragged_breaks(text, columns), (path, ragged_breaks(text, columns))


def test_every_docstring_paragraph_is_one_line():
    """What Typer is given: each help paragraph without a line break of the source file."""
    cmd = typer.main.get_command(app)
    todo = [cmd]
    while todo:
        c = todo.pop()
        todo.extend((getattr(c, "commands", None) or {}).values())
        for paragraph in (c.help or "").split("\n\n"):
            assert "\n" not in paragraph, (c.name, paragraph[:80])
        for p in c.params:
            assert "\n" not in (getattr(p, "help", None) or ""), (c.name, p.name)


def test_samples_help_says_where_samples_come_from():
    text = " ".join(_help(["rollout"]).split())
    assert "predictive Gaussian" not in text
    assert "variation model" in text and "fewer than 3 demonstrations" in text


@pytest.mark.parametrize("path", [["train"], ["crossval"], ["bench", "paper"], []])
def test_narrow_terminals_get_the_plain_list_and_wide_ones_the_panels(path):
    """Below PANELS_FROM columns the help is Click's plain two-column list, filling the terminal (no line longer
    than it less Click's margin of 2) and shorter than the panels (at 80 columns the panels ran `rbgp train --help` to
    448 lines); from PANELS_FROM on it is Typer's boxed panels."""
    from rbgp_cli.cli.args import PANELS_FROM

    narrow, wide = _help(path, 80), _help(path, PANELS_FROM)
    assert "╭" not in narrow and "Options:" in narrow
    assert "╭" in wide
    assert max(len(line) for line in narrow.splitlines()) <= 78
    if path == ["train"]:
        assert len(narrow.splitlines()) < 250, len(narrow.splitlines())


@pytest.mark.parametrize("path", [[], ["bench"]])
@pytest.mark.parametrize("columns", [80, 120])
def test_a_command_run_without_arguments_prints_its_help_in_either_layout(path, columns):
    """`rbgp` and `rbgp bench` alone print their help on stdout and exit 2, in the panels and in the plain list (Typer
    prints only the panels itself: the plain layout's help was lost, an empty exit 2)."""
    res = CliRunner().invoke(app, path, env={"COLUMNS": str(columns), "TERMINAL_WIDTH": str(columns)})
    assert res.exit_code == 2
    assert "Usage: rbgp" in res.stdout and "Commands" in res.stdout
    assert ("╭" in res.stdout) is (columns >= 100)
