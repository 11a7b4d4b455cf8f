"""What the CLI tests share: the bundled sample data and ``run``, the command line in-process."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from typer.testing import CliRunner

from rbgp_cli.cli.app import app

REPO = Path(__file__).resolve().parents[2]
CSV_DIR = REPO / "sample_data" / "csv"
runner = CliRunner()


def run(*args, input=None):
    """``rbgp ARGS`` in-process (the arguments as strings, ``input`` on stdin); click's Result, with
    stdout and stderr apart and any exception raised, not caught."""
    return runner.invoke(app, [str(a) for a in args], input=input, catch_exceptions=False)


def assert_help_imports_none_of(commands, modules) -> None:
    """In a fresh interpreter, ``rbgp ARGS`` for each argument list in ``commands`` (``--help`` ones)
    exits 0 and leaves every module in ``modules`` unimported (what --help costs stays small)."""
    code = (
        "import sys\n"
        "from typer.testing import CliRunner\n"
        "from rbgp_cli.cli.app import app\n"
        f"for args in {[list(c) for c in commands]!r}:\n"
        "    assert CliRunner().invoke(app, args).exit_code == 0, args\n"
        f"bad = [m for m in {tuple(modules)!r} if m in sys.modules]\n"
        "assert not bad, bad\n"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stdout + res.stderr
