"""Every command that reads demonstrations (or poses, or trajectories) takes the same read options
(issue 22, point 3): ``rbgp rollout --from-demos`` on an MCAP with several pose topics needs
``--topic`` as ``rbgp train`` does."""

from __future__ import annotations

import json

import pytest
import typer.main

from rbgp_cli.cli.app import app
from rbgp_cli.cli.common import READ_PANEL
from tests.cli.test_cli import MCAP, assert_one_line_error, run

#: What a parameter that reads demonstrations is called (besides any PATH... list option).
_READS = {"demos", "from_demos", "starts", "poses", "files", "generated", "compare"}
#: Read options a command may leave out, and why.
_EXEMPT: dict = {}  # every command that reads demonstrations takes every read option (inspect too: it runs train's preparation)


def _commands(group, prefix=""):
    for name, cmd in group.commands.items():
        if hasattr(cmd, "commands"):
            yield from _commands(cmd, prefix + name + " ")
        else:
            yield prefix + name, cmd


def _reads_demonstrations(cmd) -> bool:
    from rbgp_cli.cli.args import PATHS_METAVAR

    for p in cmd.params:
        help_text = (getattr(p, "help", None) or "").lower()
        if p.name in _READS or getattr(p, "metavar", None) == PATHS_METAVAR \
                or (p.param_type_name == "argument" and "demonstration" in help_text):
            return True
    return False


def _flags(cmd) -> set:
    return {o for p in cmd.params if p.param_type_name == "option" for o in [*p.opts, *p.secondary_opts]}


def _read_flags(cmd) -> set:
    return {o for p in cmd.params if p.param_type_name == "option" and getattr(p, "rich_help_panel", None) == READ_PANEL
            for o in [*p.opts, *p.secondary_opts]}


def test_every_command_that_reads_demonstrations_takes_every_read_option():
    group = typer.main.get_command(app)
    commands = dict(_commands(group))
    expected = _read_flags(commands["train"])
    assert {"--format", "--columns", "--quat-order", "--euler-order", "--degrees", "--radians", "--length-unit",
            "--time-unit", "--rate", "--topic", "--frame", "--time", "--body", "--rotation", "--max-gap"} <= expected
    readers = {name for name, cmd in commands.items() if _reads_demonstrations(cmd)}
    assert {"train", "predict", "rollout", "evaluate", "inspect", "crossval"} <= readers, readers
    for name in sorted(readers):
        missing = expected - _flags(commands[name]) - _EXEMPT.get(name, set())
        assert not missing, f"rbgp {name} lacks the read options {sorted(missing)}"
        # and they are the same options: the same panel, so --help groups them the same way
        assert _read_flags(commands[name]) == expected - _EXEMPT.get(name, set()), name


def test_rollout_from_demos_in_a_multi_topic_mcap_takes_topic(model, tmp_path):
    res = run("rollout", model, "--from-demos", MCAP, "--count", 2, "--steps", 5)
    assert_one_line_error(res, 2, "--topic")  # the hint names an option that rollout has:
    out = tmp_path / "gen.csv"
    res = run("rollout", model, "--from-demos", MCAP, "--topic", "/shoe/*", "--count", 3, "--steps", 5, "-o", out, "--json")
    assert res.exit_code == 0, res.stderr
    assert json.loads(res.stdout)["trajectories"] == 3
    one = run("rollout", model, "--from-demos", MCAP, "--topic", "/shoe/trial_02/pose", "--start-spread", 0, "--steps", 5)
    assert one.exit_code == 0, one.stderr
    first = one.stdout.splitlines()[2].split(",")  # after the units comment and the header
    # the start is trial 2's first pose exactly (no spread)
    from rbgp_cli.io.options import ReadOptions
    from rbgp_cli.io.read import read_demonstrations

    (trial,) = read_demonstrations([str(MCAP)], ReadOptions(topic="/shoe/trial_02/pose"))
    assert [float(v) for v in first[2:5]] == pytest.approx(list(trial.position[0]), abs=1e-12)


def test_rollout_starts_and_predict_read_with_the_read_options(model, tmp_path):
    """--starts and predict's poses honour --columns/--length-unit like train's demonstrations."""
    starts = tmp_path / "starts.csv"
    starts.write_text("a,b,c,px,py,pz\n0.1,0.2,0.3,300,0,1100\n")
    res = run("rollout", model, "--starts", starts, "--columns", "rx=a,ry=b,rz=c,x=px,y=py,z=pz", "--length-unit", "mm",
              "--steps", 3)
    assert res.exit_code == 0, res.stderr
    row = res.stdout.splitlines()[2].split(",")
    assert [float(v) for v in row[2:5]] == pytest.approx([0.3, 0.0, 1.1], abs=1e-12)
    res = run("predict", model, MCAP, "--topic", "/shoe/trial_01/pose")
    assert res.exit_code == 0, res.stderr
    assert len(res.stdout.strip().splitlines()) == 1 + 640  # a header and one row per pose of that topic


def test_rollout_rate_is_the_read_rate_and_says_so_without_files(model):
    """--rate is the sample rate of files without a time column, in rollout as everywhere; given with
    no file to read it would do nothing, so rollout says which option sets the output rate."""
    res = run("rollout", model, "--rate", 100, "--steps", 3)
    assert_one_line_error(res, 2, "--rate", "--output-rate")
