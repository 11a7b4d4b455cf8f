"""End-to-end tests of the command line on sample_data/, as a user runs it."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from rbgp_cli.io.model_store import FORMAT_VERSION
from tests.cli.common import CSV_DIR, REPO, assert_help_imports_none_of, run

MCAP = REPO / "sample_data" / "shoe_demos.mcap"
FAST = ["--max-points", "150", "--restarts", "1", "--share-hyperparameters"]


def assert_one_line_error(res, code=2, *fragments):
    assert res.exit_code == code, (res.exit_code, res.stdout, res.stderr)
    err = res.stderr.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("rbgp: error:"), res.stderr
    assert "Traceback" not in res.stderr and res.stdout == ""
    for f in fragments:
        assert f in err[0], err[0]


@pytest.fixture(scope="module")
def model(tmp_path_factory):
    path = tmp_path_factory.mktemp("model") / "shoe.rbgp"
    res = run("train", CSV_DIR, "-o", path, *FAST, "--json")
    assert res.exit_code == 0, res.stderr
    summary = json.loads(res.stdout)
    assert summary["demos"] == 9 and summary["points"] == 150 and summary["representation"] == "axis-angle"
    assert path.exists()
    return path


def test_train_summary_goes_to_stderr_and_json_to_stdout(tmp_path):
    out = tmp_path / "m.rbgp"
    res = run("train", CSV_DIR, "-o", out, *FAST, "--representation", "euler")
    assert res.exit_code == 0
    assert res.stdout == ""  # data only on stdout, and there is none without --json
    assert "demonstrations: 9" in res.stderr and "NLML" in res.stderr and "safeguards" in res.stderr


def test_info_shows_provenance(model):
    res = run("info", model, "--json")
    assert res.exit_code == 0
    h = json.loads(res.stdout)
    assert h["format"] == "rbgp-model" and h["version"] == FORMAT_VERSION == 9  # exact and sparse models (9: the shrinkage of the bands)
    names = [i["name"] for i in h["provenance"]["inputs"]]
    assert len(names) == 9 and all(len(i["sha256"]) == 64 for i in h["provenance"]["inputs"])
    assert h["provenance"]["train_options"]["max_points"] == 150
    text = run("info", model)
    assert text.exit_code == 0 and "axis-angle" in text.stdout


BARE_POSES = "rx,ry,rz,x,y,z\n0.1,0.2,0.3,0.3,0.0,1.1\n0.0,0.0,0.0,0.5,0.1,0.8\n"


def predict_table(model, tmp_path, text):
    """``rbgp predict`` on a poses CSV holding ``text``: (header line, values (rows, columns))."""
    poses = tmp_path / "poses.csv"
    poses.write_text(text)
    res = run("predict", model, poses)
    assert res.exit_code == 0, res.stderr
    lines = res.stdout.strip().splitlines()
    return lines[0], np.array([[float(v) for v in ln.split(",")] for ln in lines[1:]])


def test_predict_writes_mean_and_std_per_pose(model, tmp_path):
    """The default model takes the phase: poses come with times (a trajectory), one row out per pose."""
    header, vals = predict_table(model, tmp_path, "t,rx,ry,rz,x,y,z\n0.0,0.1,0.2,0.3,0.3,0.0,1.1\n1.0,0.0,0.0,0.0,0.5,0.1,0.8\n")
    assert header.startswith("t,x,y,z,qx,qy,qz,qw,mean_wx") and "std_vz" in header
    assert vals.shape == (2, 8 + 12) and np.all(np.isfinite(vals)) and np.all(vals[:, -6:] >= 0)


def test_predict_on_a_rollout_file_keeps_its_trajectories_apart(model, tmp_path):
    """A file of several trajectories (a rollout's): a trajectory column first, with their own names (before: dropped,
    the rows told apart only by t falling back to 0); one trajectory: no such column."""
    import csv

    gen = tmp_path / "gen.csv"
    assert run("rollout", model, "--count", 3, "-o", gen).exit_code == 0
    res = run("predict", model, gen)
    assert res.exit_code == 0, res.stderr
    rows = list(csv.reader(res.stdout.splitlines()))
    assert rows[0][:2] == ["trajectory", "t"]
    names = [r[0] for r in rows[1:]]
    assert sorted(set(names)) == ["0", "1", "2"] and names == sorted(names, key=int)  # in the file's order
    one = run("predict", model, CSV_DIR / "shoe_01.csv")
    assert one.exit_code == 0 and one.stdout.splitlines()[0].startswith("t,x,y,z,qx,qy,qz,qw,")


def test_predict_without_times_for_a_phase_model_says_what_to_give(model, tmp_path):
    poses = tmp_path / "poses.csv"
    poses.write_text(BARE_POSES)
    res = run("predict", model, poses)
    assert res.exit_code == 2 and "Traceback" not in res.stderr
    assert "phase" in res.stderr and "time column" in res.stderr and "--time-input none" in res.stderr, res.stderr


def test_predict_at_bare_poses_with_a_model_of_the_pose_alone(tmp_path):
    model = tmp_path / "pose_only.rbgp"
    res = run("train", CSV_DIR, "-o", model, *FAST, "--time-input", "none", "--prior", "none")
    assert res.exit_code == 0, res.stderr
    header, vals = predict_table(model, tmp_path, BARE_POSES)
    assert header.startswith("x,y,z,qx,qy,qz,qw,mean_wx") and "std_vz" in header
    assert vals.shape == (2, 7 + 12) and np.all(np.isfinite(vals)) and np.all(vals[:, -6:] >= 0)


def test_rollout_csv_reads_back(model, tmp_path):
    out = tmp_path / "gen.csv"
    res = run("rollout", model, "--count", 4, "--steps", 50, "--samples", 2, "--output-rate", 0, "-o", out, "--json")
    assert res.exit_code == 0, res.stderr
    meta = json.loads(res.stdout)
    assert meta["trajectories"] == 4 and meta["steps"] == 50
    from rbgp_cli.io.options import ReadOptions
    from rbgp_cli.io.read import read_demonstrations

    trajs = read_demonstrations([str(out)], ReadOptions())
    assert len(trajs) == 4 + 4 * 2 and all(len(t) == 51 for t in trajs)
    header = out.read_text().splitlines()[1]
    assert header.startswith("trajectory,t,x,y,z,qx,qy,qz,qw") and "std_wx" in header


def test_rollout_from_explicit_start_and_demos(model, tmp_path):
    res = run("rollout", model, "--start", "0.1 0.2 0.3 0.3 0.0 1.1", "--steps", 10, "--no-std", "--output-rate", 0)
    assert res.exit_code == 0 and res.stdout.count("\n") == 1 + 1 + 11  # comment, header, 11 rows
    res = run("rollout", model, "--from-demos", CSV_DIR, "--count", 3, "--steps", 5, "--no-std", "--output-rate", 0)
    assert res.exit_code == 0 and res.stdout.count("\n") == 2 + 3 * 6


def _by_trajectory(path):
    from rbgp_cli.io.options import ReadOptions
    from rbgp_cli.io.read import read_demonstrations

    return read_demonstrations([str(path)], ReadOptions())


def test_from_demos_rolls_out_one_start_per_demonstration_in_the_order_read_and_pairs_the_goals(model, tmp_path):
    """`rollout --from-demos A B C --start-spread 0` is what a user types to roll out from held-out starts: one
    trajectory per demonstration, trajectory i at demonstration i's start (the order read, as docs/commands.md says
    --goals pairs them), and with --goals in that order each motion ends at its own demonstration's goal."""
    from rbgp_cli.io.options import ReadOptions
    from rbgp_cli.io.read import read_demonstrations

    files = sorted(CSV_DIR.glob("*.csv"))[:3][::-1]  # not the folder's order: the order given is the order read
    demos = read_demonstrations([str(f) for f in files], ReadOptions())
    goals = tmp_path / "goals.csv"
    goals.write_text("qx,qy,qz,qw,x,y,z\n" + "".join(
        ",".join(f"{v:.9f}" for v in (*d.quat[-1], *d.position[-1])) + "\n" for d in demos))
    out = tmp_path / "gen.csv"
    res = run("rollout", model, "--from-demos", *files, "--start-spread", 0, "--goals", goals, "--each-duration",
              "--no-std", "-o", out)
    assert res.exit_code == 0, res.stderr
    gen = _by_trajectory(out)
    assert len(gen) == 3
    for g, d in zip(gen, demos):
        assert np.allclose(g.position[0], d.position[0], atol=1e-6)
        assert abs(abs(float(np.dot(g.quat[0], d.quat[0]))) - 1.0) < 1e-9
        assert np.linalg.norm(g.position[-1] - d.position[-1]) < 5e-3  # its own goal, not another demonstration's
        assert abs(g.duration - d.duration) < 0.02
    # --count cycles through them in the same order: start 3 is demonstration 0's, start 4 demonstration 1's
    res = run("rollout", model, "--from-demos", *files, "--start-spread", 0, "--count", 5, "--steps", 3, "--no-std",
              "-o", out)
    assert res.exit_code == 0, res.stderr
    starts = np.array([g.position[0] for g in _by_trajectory(out)])
    assert np.allclose(starts, np.array([demos[i % 3].position[0] for i in range(5)]), atol=1e-6)


def test_evaluate_json_schema(model, tmp_path):
    gen = tmp_path / "gen.csv"
    assert run("rollout", model, "--count", 6, "-o", gen, "--no-std").exit_code == 0
    per = tmp_path / "per_step.csv"
    res = run("evaluate", gen, "--demos", CSV_DIR, "--json", "--per-step", per)
    assert res.exit_code == 0, res.stderr
    d = json.loads(res.stdout)
    assert set(d["bhattacharyya"]) == {"mean", "rotation", "translation", "offset", "spread"}
    assert d["n_generated"] == 6 and d["n_demos"] == 9 and d["steps"] > 100
    b = d["bhattacharyya"]
    assert b["mean"] == pytest.approx(b["rotation"] + b["translation"])  # diag: parts add up
    assert b["mean"] == pytest.approx(b["offset"] + b["spread"]) and min(b["offset"], b["spread"]) >= 0
    assert len(per.read_text().splitlines()) == d["steps"] + 1


def test_evaluate_with_model_generates_like_the_paper(model):
    res = run("evaluate", "--model", model, "--count", 5, "--demos", CSV_DIR, "--json")
    assert res.exit_code == 0, res.stderr
    assert json.loads(res.stdout)["n_generated"] == 5


def test_evaluate_given_a_model_file_as_generated_trajectories_points_to_model(model):
    res = run("evaluate", model, "--demos", CSV_DIR)
    assert res.exit_code == 2
    msg = res.stderr.strip().splitlines()
    assert len(msg) == 1 and "is a model file, not generated trajectories" in msg[0] and f"--model {model}" in msg[0], msg


def test_evaluate_against_one_demonstration_refuses_and_one_rollout_warns(model, tmp_path):
    """One demonstration: the per-step spread is the ridge alone, so the score would measure the ridge
    (the issue saw 'bhattacharyya mean 145.25'): exit 2 naming how many are needed. One generated
    trajectory: a warning, and --json says the score is not reliable."""
    one = tmp_path / "one_demo"
    one.mkdir()
    (one / "shoe_01.csv").write_bytes((CSV_DIR / "shoe_01.csv").read_bytes())
    res = run("evaluate", "--model", model, "--count", 5, "--demos", one)
    assert_one_line_error(res, 2, "1 demonstration", "ridge", "at least 2 demonstrations")
    res = run("evaluate", "--model", model, "--count", 1, "--demos", CSV_DIR, "--json")
    assert res.exit_code == 0, res.stderr
    d = json.loads(res.stdout)
    assert d["reliable"] is False and "only 1 generated trajectory" in d["warnings"][0]
    assert "rbgp: warning: only 1 generated trajectory" in res.stderr and "at least 2" in res.stderr
    res = run("evaluate", "--model", model, "--count", 5, "--demos", CSV_DIR, "--covariance", "full", "--json")
    d = json.loads(res.stdout)
    assert d["reliable"] is False and any("needs at least 7 generated" in w for w in d["warnings"])


@pytest.mark.slow
def test_real_subprocess_pipe_rollout_into_evaluate(model):
    """stdout carries only data: rollout -o - | evaluate - works through a real (non-seekable) pipe."""
    env = dict(os.environ, PYTHONWARNINGS="ignore")
    cmd = [sys.executable, "-m", "rbgp_cli"]
    p1 = subprocess.Popen(cmd + ["rollout", str(model), "--count", "5", "--no-std", "-o", "-"], stdout=subprocess.PIPE,
                          stderr=subprocess.PIPE, env=env)
    p2 = subprocess.run(cmd + ["evaluate", "-", "--demos", str(CSV_DIR), "--json"], stdin=p1.stdout,
                        capture_output=True, env=env, timeout=300)
    p1.stdout.close()
    assert p1.wait(timeout=300) == 0
    assert p2.returncode == 0, p2.stderr.decode()
    assert json.loads(p2.stdout)["n_generated"] == 5


def test_inspect_csv_and_mcap():
    res = run("inspect", CSV_DIR / "shoe_01.csv", "--json")
    assert res.exit_code == 0
    d = json.loads(res.stdout)
    assert d["format"] == "csv"
    res = run("inspect", MCAP)
    assert res.exit_code == 0 and "/shoe/trial_07/pose" in res.stdout


@pytest.mark.slow
def test_a_folder_with_a_licence_and_a_readme_trains(tmp_path):
    """The issue's data/ folder: takes plus the dataset's LICENSE.txt and README.md. Every command that
    takes a folder reads the takes and says once what it skipped; the LICENSE named alone is an error."""
    data = tmp_path / "data"
    data.mkdir()
    for f in sorted(CSV_DIR.glob("*.csv")):
        (data / f.name).write_bytes(f.read_bytes())
    (data / "LICENSE.txt").write_text("Creative Commons Attribution 4.0 International\n\nBy using the Licensed Material\n")
    (data / "README.md").write_text("# Shoe handovers\n\nNine takes at 100 Hz.\n")
    model = tmp_path / "m.rbgp"
    res = run("train", data, "-o", model, *FAST, "--json")
    assert res.exit_code == 0, res.stderr
    assert json.loads(res.stdout)["demos"] == 9
    notes = [ln for ln in res.stderr.splitlines() if ln.startswith("rbgp: warning:")]
    assert notes == [f"rbgp: warning: {data}: skipped 2 of 11 files that hold no pose data: "
                     "LICENSE.txt, README.md (no pose columns)"]
    inputs = json.loads(run("info", model, "--json").stdout)["provenance"]["inputs"]
    assert [Path(i["name"]).name for i in inputs] == sorted(f.name for f in CSV_DIR.glob("*.csv"))
    res = run("rollout", model, "--from-demos", data, "--count", 2, "--steps", 5, "--no-std")
    assert res.exit_code == 0 and res.stderr.count("skipped 2 of 11") == 1
    res = run("evaluate", "--model", model, "--count", 5, "--demos", data, "--json")
    assert res.exit_code == 0 and json.loads(res.stdout)["n_demos"] == 9
    res = run("inspect", data, "--json")
    assert res.exit_code == 0 and len(json.loads(res.stdout)) == 9 and "LICENSE.txt" in res.stderr
    assert_one_line_error(run("train", data / "LICENSE.txt", "-o", model), 2, "LICENSE.txt:", "no rotation columns")


@pytest.mark.slow
def test_help_does_not_import_heavy_modules():
    assert_help_imports_none_of(
        (["--help"], ["train", "--help"], ["rollout", "--help"], ["evaluate", "--help"], ["inspect", "--help"]),
        ("rerun", "mcap", "pandas", "scipy.optimize", "matplotlib"))


@pytest.mark.parametrize(
    "args,fragments",
    [
        (["train", "missing.csv", "-o", "{tmp}/m.rbgp"], ["missing.csv"]),
        (["train", str(CSV_DIR), "-o", "{tmp}/m.rbgp", "--rho-rot", "1.5"], ["--rho-rot"]),
        (["train", str(CSV_DIR), "-o", "{tmp}/m.rbgp", "--kernel", "matern"], ["kernel"]),
        (["train", str(CSV_DIR), "-o", "{tmp}/m.rbgp", "--representation", "euler", "--kernel", "se-chordal"], ["se-chordal"]),
        (["train", str(CSV_DIR), "-o", "{tmp}/nodir/m.rbgp", "--max-points", "20"], ["folder does not exist"]),
        (["rollout", "{tmp}/none.rbgp"], ["not found"]),
        (["evaluate", "x.csv"], ["--demos"]),
        (["train", str(CSV_DIR), "-o", "{tmp}/m.rbgp", "--columns", "t="], ["--columns entry 't=' is not KEY=NAME"]),
        (["train", str(CSV_DIR), "-o", "{tmp}/m.rbgp", "--columns", "=stamp"], ["--columns entry '=stamp' is not KEY=NAME"]),
        # Click's own usage errors: one line too, not Typer's box with the usage above it
        (["rollout", "{tmp}/none.rbgp", "--samples", "-1"], ["--samples", "rbgp rollout --help"]),
        (["crossval", str(CSV_DIR), "--folds", "1"], ["--folds", "rbgp crossval --help"]),
        (["train", str(CSV_DIR), "-o", "{tmp}/m.rbgp", "--bogus"], ["--bogus", "rbgp train --help"]),
        (["rollout"], ["Missing argument", "rbgp rollout --help"]),
        (["trian"], ["No such command 'trian'", "rbgp --help"]),
        (["--bogus", "info"], ["--bogus", "rbgp --help"]),
        # a negative seed: numpy's generators take none (it was an internal error, exit 1)
        (["train", str(CSV_DIR), "-o", "{tmp}/m.rbgp", "--seed", "-1"], ["--seed", "greater than or equal to 0"]),
        (["crossval", str(CSV_DIR), "--seed", "-1"], ["--seed"]),
        (["rollout", "{tmp}/none.rbgp", "--seed", "-1"], ["--seed"]),
        (["evaluate", "--model", "{tmp}/none.rbgp", "--demos", str(CSV_DIR), "--seed", "-1"], ["--seed"]),
        (["bench", "paper", "theorem", "--seed", "-1"], ["--seed"]),
    ],
)
def test_bad_usage_exits_2_with_one_line_and_no_output_file(tmp_path, args, fragments):
    args = [a.replace("{tmp}", str(tmp_path)) for a in args]
    res = run(*args)
    assert_one_line_error(res, 2, *fragments)
    assert not (tmp_path / "m.rbgp").exists()
    assert not any(p.name.endswith(".tmp") for p in tmp_path.rglob("*"))


@pytest.mark.parametrize("args", [
    ["rollout", "{model}", "--count", "1", "-o", "r.csv", "--plot", "-"],
    ["rollout", "{model}", "--count", "1", "-o", "r.csv", "--rerun", "-"],
    ["evaluate", str(CSV_DIR / "shoe_01.csv"), str(CSV_DIR / "shoe_02.csv"), "--demos", str(CSV_DIR), "--plot", "-"],
    ["train", str(CSV_DIR), "-o", "m.rbgp", "--rerun", "-"],
    ["demo", "--quick", "--out", "-"],
    ["bench", "paper", "theorem", "--quick", "--json", "--markdown", "-"],  # the Markdown, then the JSON
])
def test_a_figure_recording_or_folder_to_dash_is_refused_not_written_under_that_name(model, tmp_path, monkeypatch, args):
    monkeypatch.chdir(tmp_path)
    res = run(*[a.replace("{model}", str(model)) for a in args])
    flag = args[args.index("-") - 1]
    assert_one_line_error(res, 2, f"{flag} - would mean stdout", f"give {flag} a")
    assert list(tmp_path.iterdir()) == []


def test_evaluate_per_step_to_stdout_is_the_csv_alone():
    gen = [CSV_DIR / "shoe_01.csv", CSV_DIR / "shoe_02.csv"]
    res = run("evaluate", *gen, "--demos", CSV_DIR, "--per-step", "-", "-q")
    assert res.exit_code == 0, res.stderr
    lines = res.stdout.strip().splitlines()
    assert lines[0].startswith("step,s,bhattacharyya") and all(ln[0].isdigit() for ln in lines[1:])
    assert res.stderr.startswith("bhattacharyya mean")  # the summary, beside the data
    res = run("evaluate", *gen, "--demos", CSV_DIR, "--per-step", "-", "--json")
    assert_one_line_error(res, 2, "--json", "--per-step FILE")


def test_train_to_stdout_is_refused_not_written_to_a_file_named_dash(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    res = run("train", CSV_DIR, "-o", "-", *FAST)
    assert_one_line_error(res, 2, "-o NAME.rbgp")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("args", [["info", "-"], ["rollout", "-", "--count", "1"], ["follow", "-"]])
def test_a_model_named_dash_is_stdin_and_refused_as_such(tmp_path, monkeypatch, args):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "-").write_bytes(b"PK\x03\x04 not a model")  # not read as a file named '-' either
    res = run(*args, input="t,x,y,z,qx,qy,qz,qw\n")
    assert_one_line_error(res, 2, "a model is not read from stdin", "pass the model file's path")


@pytest.mark.parametrize("args,target,names", [
    (["rollout", "{model}", "--count", "3", "-q", "-o", "{tmp}/g.csv"], "rollout_model", ["--count", "--duration"]),
    (["evaluate", "{tmp}/g.csv", "--demos", str(CSV_DIR)], "evaluate_files", ["--length"]),
    (["train", str(CSV_DIR), "-q", "-o", "{tmp}/m.rbgp"], "train_from_files", ["--max-points", "--train-rate"]),
])
def test_out_of_memory_says_what_to_make_smaller_for_that_command(model, tmp_path, monkeypatch, args, target, names):
    import rbgp_cli.workflows as wf

    def boom(*a, **k):
        raise MemoryError

    monkeypatch.setattr(wf, target, boom)
    (tmp_path / "g.csv").write_text((CSV_DIR / "shoe_01.csv").read_text())
    res = run(*[a.replace("{model}", str(model)).replace("{tmp}", str(tmp_path)) for a in args])
    assert_one_line_error(res, 1, "out of memory", *names)
    if args[0] != "train":
        assert "--max-points" not in res.stderr  # a training option, for a command that trains nothing


def test_evaluate_length_errors_name_the_option(tmp_path):
    res = run("evaluate", CSV_DIR / "shoe_01.csv", CSV_DIR / "shoe_02.csv", "--demos", CSV_DIR, "--length", "100000")
    assert_one_line_error(res, 2, "--length 100000 is more than", "use --length at most 2604")


@pytest.mark.parametrize("count,args,hint,not_hint", [
    (2, ["--folds", "2"], "record 4 demonstrations or more", "--folds 2 or fewer"),  # it ran with 2 folds
    (9, ["--folds", "2", "--train-size", "8"], "--train-size 7 or less", "--folds"),  # folds do not change it
])
def test_crossval_one_held_out_warning_gives_advice_that_helps(tmp_path, count, args, hint, not_hint):
    for src in sorted(CSV_DIR.glob("*.csv"))[:count]:
        (tmp_path / src.name).write_bytes(src.read_bytes())
    res = run("crossval", tmp_path, *args, "--no-peers", "--samples", "2", "-q", *FAST)
    assert res.exit_code == 0, res.stderr
    (line,) = [ln for ln in res.stderr.splitlines() if "hold out only one" in ln]
    assert hint in line and not_hint not in line.split("; ", 1)[1], line


@pytest.mark.parametrize("option,value", [("--noise", "1e154"), ("--noise-scale", "1e308"), ("--train-rate", "1e308"),
                                          ("--smooth-window", "1e308")])
def test_train_options_too_large_for_a_double_are_bad_input_not_an_internal_error(tmp_path, option, value):
    res = run("train", CSV_DIR, "-o", tmp_path / "m.rbgp", option, value, *FAST)
    assert_one_line_error(res, 2, option)
    assert not (tmp_path / "m.rbgp").exists()


def test_a_recording_whose_pose_never_changes_says_why_nothing_is_left(tmp_path):
    rows = "".join(f"{0.01 * k:.2f},0.1,0.2,0.3,0,0,0,1\n" for k in range(100))
    (tmp_path / "still.csv").write_text("t,x,y,z,qx,qy,qz,qw\n" + rows)
    res = run("train", tmp_path / "still.csv", "-o", tmp_path / "m.rbgp")
    assert_one_line_error(res, 2, "still.csv", "1 left of 100", "99 repeating the previous pose exactly",
                          "the pose never changes")
    assert not (tmp_path / "m.rbgp").exists()


@pytest.mark.parametrize("pose", ["1 2 3", "a b c d e f", "nan 0 0 0 0 0", "0 0 0 0 0 inf"])
def test_malformed_start_poses(model, pose):
    res = run("rollout", model, "--start", pose)
    assert_one_line_error(res, 2, "start pose", 'write --start as "rx ry rz x y z"')
    assert "(start)" not in res.stderr and "--start pose" not in res.stderr  # the option, named as typed


def test_model_file_errors(tmp_path):
    bad = tmp_path / "bad.rbgp"
    bad.write_bytes(b"not a model at all")
    assert_one_line_error(run("info", bad), 2, "bad.rbgp")


@pytest.mark.slow
def test_demo_quick_prints_three_scores(tmp_path):
    res = run("demo", "--quick", "--count", "5", "--out", tmp_path / "demo", "--json")
    assert res.exit_code == 0, res.stderr
    d = json.loads(res.stdout)
    assert set(d["representations"]) == {"axis-angle", "euler", "quaternion"}
    for rep in d["representations"].values():
        assert np.isfinite(rep["bhattacharyya"]["mean"])
    assert (tmp_path / "demo" / "axis-angle.rbgp").exists()


@pytest.mark.slow
def test_csv_and_mcap_give_the_same_model(tmp_path):
    """The sample data's CSV files and its ROS 2 MCAP (one topic per trial) hold the same instants and
    poses, so the models agree (times pass through integer nanoseconds: same to ~1e-9 s)."""
    a, b = tmp_path / "csv.rbgp", tmp_path / "mcap.rbgp"
    assert run("train", CSV_DIR, "-o", a, *FAST).exit_code == 0
    res = run("train", MCAP, "--topic", "/shoe/*", "-o", b, *FAST)
    assert res.exit_code == 0, res.stderr
    from rbgp_cli.io.model_store import load_model

    (ma, _), (mb, _) = load_model(a), load_model(b)
    np.testing.assert_allclose(ma.gp.X, mb.gp.X, rtol=0, atol=1e-12)
    np.testing.assert_allclose(ma.gp.Y, mb.gp.Y, rtol=1e-6, atol=1e-9)
    # The optimiser stops when its step is ~1e-5 relative (L-BFGS-B's tolerance), so inputs that differ
    # by 1e-9 s may stop it a hair apart along a flat direction of the likelihood (seen: signal std
    # 29.47267 against 29.47298 with numpy 2.4 / scipy 1.17): the hyperparameters agree to 1e-4, and
    # what they are for, the predicted velocities, agree far closer than the velocities' own scale.
    for fa, fb in zip(ma.gp.fits, mb.gp.fits):
        for k in fa.values:
            assert fa.values[k] == pytest.approx(fb.values[k], rel=1e-4)
    mean_a, std_a = ma.gp.predict(ma.gp.X, return_std=True)
    mean_b, std_b = mb.gp.predict(ma.gp.X, return_std=True)
    scale = np.std(ma.gp.Y, axis=0)
    assert np.all(np.abs(mean_a - mean_b) <= 1e-4 * scale)
    np.testing.assert_allclose(std_a, std_b, rtol=1e-4)


def test_mcap_topic_pattern_errors_name_the_topics():
    res = run("train", MCAP, "--topic", "/hand/*", "-o", "/tmp/never.rbgp")
    assert_one_line_error(res, 2, "/hand/*")
    res = run("train", MCAP, "--topic", "/nope", "-o", "/tmp/never.rbgp")  # no close name to suggest
    assert_one_line_error(res, 2, "no topic '/nope'; pose topics are: /shoe/trial_01/pose", "--topic")


@pytest.mark.slow
def test_train_explore_size_reaches_the_fit_and_the_provenance(tmp_path):
    """--explore-size N: above 2N training points the starts explore N points first (reported per
    output and recorded in the model's provenance); 0 runs every start on all points."""
    base = ["--max-points", "150", "--restarts", "2", "--share-hyperparameters", "--json"]
    on, off = tmp_path / "on.rbgp", tmp_path / "off.rbgp"
    res = run("train", CSV_DIR, "-o", on, *base, "--explore-size", "50")
    assert res.exit_code == 0, res.stderr
    sub = json.loads(res.stdout)["outputs"][0]["subsample"]
    assert sub["size"] == 50 and sub["evaluations"] > 0
    res = run("train", CSV_DIR, "-o", off, *base, "--explore-size", "0")
    assert res.exit_code == 0, res.stderr
    assert json.loads(res.stdout)["outputs"][0]["subsample"] is None
    info = json.loads(run("info", on, "--json").stdout)
    assert info["provenance"]["train_options"]["explore_size"] == 50
    assert run("train", CSV_DIR, "-o", tmp_path / "bad.rbgp", "--explore-size", "-1").exit_code == 2
    assert not (tmp_path / "bad.rbgp").exists()
    text = run("train", CSV_DIR, "-o", on, *base[:-1], "--explore-size", "50")
    assert "explored a random subset of 50 points" in text.stderr
