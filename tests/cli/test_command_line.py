"""The command line as people type it: unquoted shell globs after one flag, -q/--json after (or
before) the command name, and a clear way out when a path list takes a file meant for something else."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import typer
from hypothesis import given, settings
from hypothesis import strategies as st

from rbgp_cli.cli.app import app
from rbgp_cli.cli.args import PATHS_METAVAR, expand_path_lists
from tests.cli.common import CSV_DIR, run

FAST = ["--max-points", "100", "--restarts", "1", "--share-hyperparameters"]
BIN = Path(sys.executable).parent


def bash(script: str, cwd: Path) -> subprocess.CompletedProcess:
    """``bash -c SCRIPT``: the shell expands unquoted globs, as when a user types the line."""
    env = dict(os.environ, PATH=f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}")
    return subprocess.run(["bash", "-c", script], cwd=cwd, env=env, capture_output=True, text=True, timeout=300)


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    """A folder with ``data/`` (three demonstrations) and ``m.rbgp`` (a small model)."""
    folder = tmp_path_factory.mktemp("typed")
    (folder / "data").mkdir()
    for f in sorted(CSV_DIR.glob("*.csv"))[:3]:
        shutil.copy(f, folder / "data")
    res = run("-q", "train", folder / "data", "-o", folder / "m.rbgp", *FAST)
    assert res.exit_code == 0, res.stderr
    return folder


def _command(name):
    return typer.main.get_command(app).commands[name]


# ---------------------------------------------------------------------------------------------- globs
@pytest.mark.slow
def test_unquoted_glob_after_one_flag_means_the_same_as_the_folder(work):
    """rollout --from-demos data/*.csv (expanded by bash) gives the same starts as --from-demos data."""
    res = bash("rbgp rollout m.rbgp --from-demos data/*.csv --count 4 --steps 5 --no-std -o glob.csv", work)
    assert res.returncode == 0, res.stderr
    folder = run("rollout", work / "m.rbgp", "--from-demos", work / "data", "--count", 4, "--steps", 5, "--no-std",
                 "-o", work / "folder.csv")
    assert folder.exit_code == 0, folder.stderr
    assert (work / "glob.csv").read_text() == (work / "folder.csv").read_text()


@pytest.mark.slow
def test_evaluate_with_model_and_an_unquoted_glob(work):
    res = bash("rbgp evaluate --model m.rbgp --count 4 --demos data/*.csv --json", work)
    assert res.returncode == 0, res.stderr
    by_folder = run("evaluate", "--model", work / "m.rbgp", "--count", 4, "--demos", work / "data", "--json")
    assert by_folder.exit_code == 0, by_folder.stderr
    assert json.loads(res.stdout) == json.loads(by_folder.stdout)
    assert json.loads(res.stdout)["n_demos"] == 3


@pytest.mark.slow
def test_a_list_that_took_the_model_says_what_to_write_and_that_works(work):
    """--from-demos data/*.csv m.rbgp: the model file went into the list; the one-line error shows the
    command line to type instead, and running that line succeeds."""
    res = bash("rbgp rollout --from-demos data/*.csv m.rbgp --count 2 --steps 3 --no-std --output-rate 0 -o fixed.csv", work)
    assert res.returncode == 2
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("rbgp: error: MODEL missing: --from-demos"), res.stderr
    suggested = re.search(r"write it before the list: (rbgp rollout .*)$", lines[0]).group(1)
    assert suggested == ("rbgp rollout m.rbgp --from-demos data/shoe_01.csv data/shoe_02.csv data/shoe_03.csv "
                         "--count 2 --steps 3 --no-std --output-rate 0 -o fixed.csv")
    again = bash(suggested, work)
    assert again.returncode == 0, again.stderr
    assert (work / "fixed.csv").read_text().count("\n") == 2 + 2 * 4


@pytest.mark.slow
def test_generated_file_after_the_demo_list(work):
    """evaluate --demos data/*.csv gen.csv: gen.csv went into the list, and no --model was given."""
    assert run("rollout", work / "m.rbgp", "--count", 3, "--steps", 30, "--no-std", "-o", work / "gen.csv").exit_code == 0
    res = bash("rbgp evaluate --demos data/*.csv gen.csv", work)
    assert res.returncode == 2
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and "took gen.csv" in lines[0] and "--model MODEL" in lines[0], res.stderr
    assert "rbgp evaluate gen.csv --demos data/shoe_01.csv data/shoe_02.csv" in lines[0]
    ok = bash("rbgp evaluate gen.csv --demos data/*.csv --json", work)
    assert ok.returncode == 0, ok.stderr
    assert json.loads(ok.stdout)["n_generated"] == 3 and json.loads(ok.stdout)["n_demos"] == 3


@pytest.mark.slow
def test_compare_takes_several_files_too(work, tmp_path):
    pytest.importorskip("matplotlib")
    for k in (1, 2):
        assert run("rollout", work / "m.rbgp", "--count", 2, "--steps", 20, "--no-std", "--seed", k,
                   "-o", work / f"cmp_{k}.csv").exit_code == 0
    res = run("evaluate", work / "data" / "shoe_01.csv", "--demos", *sorted((work / "data").glob("*.csv")),
              "--plot", tmp_path / "f.png", "--compare", work / "cmp_1.csv", work / "cmp_2.csv")
    assert res.exit_code == 0, res.stderr
    assert (tmp_path / "f.png").stat().st_size > 10_000


# ---------------------------------------------------------------------------------------------- rewriting
def test_rewriting_rules_on_the_real_commands():
    rollout = _command("rollout")
    out, runs = expand_path_lists(rollout, ["m", "--from-demos", "a", "b", "-", "--count", "3"])
    assert out == ["m", "--from-demos", "a", "--from-demos", "b", "--from-demos", "-", "--count", "3"]
    assert runs == [("--from-demos", ["a", "b", "-"])]
    # '--' ends the list; '--flag=value' is one value; other options keep their values, even '-...'
    out, _ = expand_path_lists(rollout, ["--from-demos", "a", "--", "m"])
    assert out == ["--from-demos", "a", "--", "m"]
    out, _ = expand_path_lists(rollout, ["--from-demos=a", "m"])
    assert out == ["--from-demos=a", "m"]
    out, _ = expand_path_lists(rollout, ["m", "--start", "-0.1 0 0 0 0 1", "--from-demos", "a", "-o", "-"])
    assert out == ["m", "--start", "-0.1 0 0 0 0 1", "--from-demos", "a", "-o", "-"]
    out, runs = expand_path_lists(rollout, ["m", "--from-demos", "a", "--from-demos", "b", "c"])
    assert out == ["m", "--from-demos", "a", "--from-demos", "b", "--from-demos", "c"]
    assert runs == [("--from-demos", ["a"]), ("--from-demos", ["b", "c"])]
    # an option that takes one path is not a list: evaluate's --per-step, train's -o
    out, _ = expand_path_lists(_command("evaluate"), ["--per-step", "s.csv", "g.csv", "--demos", "d1", "d2"])
    assert out == ["--per-step", "s.csv", "g.csv", "--demos", "d1", "--demos", "d2"]


def test_every_option_that_takes_demonstrations_takes_a_list():
    multi = {(name, opt) for name, cmd in typer.main.get_command(app).commands.items() for p in cmd.params
             if getattr(p, "metavar", None) == PATHS_METAVAR for opt in p.opts}
    assert {("rollout", "--from-demos"), ("evaluate", "--demos"), ("evaluate", "--compare")} <= multi
    help_text = run("rollout", "--help").stdout
    assert PATHS_METAVAR in help_text


_path = st.text(alphabet="abcxyz_./0123456789", min_size=1, max_size=8)


@settings(max_examples=100, deadline=None, derandomize=True, database=None)
@given(st.lists(st.lists(_path, min_size=1, max_size=4), min_size=1, max_size=3), _path, st.booleans())
@pytest.mark.slow
def test_parsed_lists_hold_exactly_the_paths_typed(runs, model, model_first):
    """Any mix of runs of paths after --from-demos: Click ends up with every path, in order."""
    typed = [model] if model_first else []
    for run_ in runs:
        typed += ["--from-demos", *run_, "--count", "2"]
    out, took = expand_path_lists(_command("rollout"), typed)
    assert took == [("--from-demos", r) for r in runs]
    values = [out[i + 1] for i, tok in enumerate(out) if tok == "--from-demos"]
    assert values == [p for r in runs for p in r]
    assert (model in out and out.index(model) == 0) if model_first else True


# ---------------------------------------------------------------------------------------------- -q, --json
def test_quiet_after_the_command_name(work, tmp_path):
    loud = run("train", work / "data", "-o", tmp_path / "a.rbgp", *FAST)
    assert loud.exit_code == 0 and "rbgp: all outputs: NLML" in loud.stderr
    quiet = run("train", work / "data", "-o", tmp_path / "b.rbgp", *FAST, "-q")
    assert quiet.exit_code == 0, quiet.stderr
    assert quiet.stderr == ""  # -q: no progress and no summary (issue 22: the summary is information)
    quiet_long = run("rollout", work / "m.rbgp", "--steps", 20, "--no-std", "--quiet")
    assert quiet_long.exit_code == 0 and quiet_long.stderr == "" and quiet_long.stdout.startswith("#")
    assert "--quiet" in run("train", "--help").stdout


@pytest.mark.slow
def test_quiet_after_the_command_name_in_a_real_shell(work):
    res = bash("rbgp rollout m.rbgp --steps 20 --no-std -q -o q.csv", work)
    assert res.returncode == 0 and res.stderr == "", res.stderr
    res = bash("rbgp -q rollout m.rbgp --steps 20 --no-std -o q.csv", work)
    assert res.returncode == 0 and res.stderr == "", res.stderr


def test_json_before_or_after_the_command_name(work):
    after = run("info", work / "m.rbgp", "--json")
    before = run("--json", "info", work / "m.rbgp")
    assert after.exit_code == before.exit_code == 0
    assert json.loads(before.stdout) == json.loads(after.stdout)
    res = run("--json", "predict", work / "m.rbgp", CSV_DIR / "shoe_01.csv")
    assert res.exit_code == 2 and res.stdout == ""
    assert res.stderr.strip() == "rbgp: error: rbgp predict has no --json output; leave out --json"
