"""The public Python API (rbgp_cli.api, exported from rbgp_cli): estimator, results, the docs example,
and the errors that name parameters (the command line shows its flags instead)."""

from __future__ import annotations

import ast
import re
import runpy
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import rbgp_cli as rbgp
from rbgp_cli.errors import InputError
from tests.cli.test_cli import CSV_DIR, FAST, run

REPO = Path(__file__).resolve().parents[1]
FAST_KW = dict(max_points=150, restarts=1, share_hyperparameters=True)  # the same options as FAST


@pytest.fixture(scope="module")
def demos():
    return rbgp.read_demonstrations(CSV_DIR)


@pytest.fixture(scope="module")
def gp(demos):
    return rbgp.RigidBodyGP(**FAST_KW).fit(demos)


def test_import_is_light():
    code = ("import sys, rbgp_cli; heavy = [m for m in ('typer', 'rerun', 'mcap', 'scipy.optimize', 'numpy', "
            "'rbgp_cli.api') if m in sys.modules]; print(heavy)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"
    assert rbgp.__version__ and "RigidBodyGP" in rbgp.__all__ and "RigidBodyGP" in dir(rbgp)


def test_read_demonstrations_from_files_and_arrays(demos):
    assert len(demos) == 9
    d = demos[0]
    assert d.quat.shape == (len(d), 4) and d.position.shape == (len(d), 3)
    again = rbgp.read_demonstrations([(d.t, d.quat, d.position), {"t": d.t, "quat": d.quat, "position": d.position}])
    assert len(again) == 2
    np.testing.assert_allclose(again[0].position, d.position)
    with pytest.raises(InputError, match="unknown read option"):
        rbgp.read_demonstrations(CSV_DIR, bogus=1)


def test_fit_predict_rollout_shapes(gp, demos):
    assert gp.summary_["points"] == 150 and gp.output_names_ == ("wx", "wy", "wz", "vx", "vy", "vz")
    mean = gp.predict(demos[0])  # return_std False, as scikit-learn
    mean2, std = gp.predict(demos[0], return_std=True)
    assert mean.shape == std.shape == (len(demos[0]), 6) and np.array_equal(mean, mean2) and np.all(std > 0)
    r = gp.rollout(demos[:2], steps=10, samples=3, seed=1)
    assert r.quat.shape == (2, 11, 4) and r.position.shape == (2, 11, 3) and r.std.shape == (2, 11, 6)
    assert r.sample_quat.shape == (2, 3, 11, 4) and r.sample_position.shape == (2, 3, 11, 3)
    np.testing.assert_allclose(np.linalg.norm(r.quat, axis=-1), 1.0, atol=1e-9)
    assert r.lengths.tolist() == [11, 11]
    # the next motion's 90 % band comes with the samples: zero at the start, positive after it
    assert r.band_position.shape == (2, 11, 3) and r.band_rotation.shape == (2, 11, 3, 3)
    assert np.all(r.band_position[:, 0] == 0.0) and np.all(r.band_position[:, 5:] > 0.0)
    assert r.band_widening.shape == (2, 2) and np.all(r.band_widening >= 1.0)  # by each start's surprise
    f = r.to_frame()
    assert len(f) == 2 * 11 * (1 + 3) and {"trajectory", "sample", "t", "qw", "x", "std_vx", "left_data"} <= set(f.columns)
    d = r.to_dict()
    assert np.array(d["quat"]).shape == (2, 11, 4)
    one = gp.rollout(np.r_[demos[0].quat[0], demos[0].position[0]], duration=1.0)  # a (7,) start, 1 s
    # a duration integrates on the recorded interval, at most 10 steps per 0.1 s training step
    assert one.quat.shape[:2] == (1, 101) and one.sample_quat is None
    np.testing.assert_allclose(one.position[0, 0], demos[0].position[0])


@pytest.mark.slow
def test_rollout_to_goals_through_a_via_point(gp, demos):
    d = demos[1]
    k = len(d) // 2
    t_via = float(d.t[k] - d.t[0])
    r = gp.rollout(demos[1:3], goals=demos[1:3], via=[(t_via, (d.quat[k], d.position[k]))],
                   durations=[d.duration, demos[2].duration], samples=2, return_std=False)
    for b, g in enumerate(demos[1:3]):  # each mean ends at its goal (the demonstration's last pose)
        n = r.lengths[b]
        assert np.linalg.norm(r.position[b, n - 1] - g.position[-1]) < 0.005
    j = int(np.argmin(np.abs(r.t - t_via)))
    assert np.linalg.norm(r.position[0, j] - d.position[k]) < 0.005
    assert r.goal_distance.shape == (2,) and np.all(r.goal_distance < 4.5)
    assert r.via_distance.shape == (2, 1) and r.via_distance[0, 0] < 4.5
    assert gp.rollout(demos[1:2]).via_distance is None


def test_evaluate_result(gp, demos):
    r = gp.rollout(demos, return_std=False)
    e = rbgp.evaluate(r, demos)
    assert np.isfinite(e.mean) and e.mean >= 0 and e.n_generated == 9 and e.n_demos == 9
    assert e.to_dict()["bhattacharyya"]["mean"] == pytest.approx(e.mean)
    assert list(e.to_frame().columns) == ["step", "total", "rotation", "translation"] and len(e.to_frame()) == e.steps


def test_save_load_matches_cli_model(gp, demos, tmp_path):
    """A model trained through the API predicts exactly what the CLI's model with the same options does,
    and survives save/load unchanged."""
    cli_path = tmp_path / "cli.rbgp"
    res = run("train", CSV_DIR, "-o", cli_path, *FAST)
    assert res.exit_code == 0, res.stderr
    path = tmp_path / "api.rbgp"
    gp.save(path)
    loaded = rbgp.RigidBodyGP.load(path)
    cli = rbgp.RigidBodyGP.load(cli_path)
    poses = np.c_[demos[3].quat, demos[3].position]
    tau = np.linspace(0, 1, len(poses))
    m0, s0 = gp.predict(poses, tau=tau, return_std=True)
    for other in (loaded, cli):
        m1, s1 = other.predict(poses, tau=tau, return_std=True)
        np.testing.assert_array_equal(m0, m1)
        np.testing.assert_array_equal(s0, s1)
    assert cli.max_points == 150 and cli.share_hyperparameters is True  # options from the file's provenance
    np.testing.assert_array_equal(gp.rollout(demos[0], steps=5).quat, cli.rollout(demos[0], steps=5).quat)


@pytest.mark.slow
def test_crossval_result(demos):
    cv = rbgp.crossval(demos, rbgp.RigidBodyGP(**FAST_KW), folds=3, samples=0, jobs=1)
    f = cv.to_frame()
    # the estimator, the same fits without the GP, and replay
    assert sorted(f["representation"]) == ["axis-angle", "axis-angle", "replay"] and cv.folds == 3
    assert f["without_gp"].fillna(False).astype(bool).sum() == 1
    assert np.all(np.isfinite(f["score"])) and np.all(f["score"] > 0)
    assert cv.to_dict()["folds"] == 3


def test_library_errors_name_parameters(gp, demos):
    """The library says ``steps``; the command line says ``--steps`` for the same error."""
    from rbgp_cli.dynamics.rollout import rollout

    with pytest.raises(InputError) as err:
        rollout(gp.model_, demos[0].quat[:1], demos[0].position[:1], 0)
    assert err.value.param == "steps" and str(err.value).startswith("steps must be at least 1")
    with pytest.raises(InputError) as err:
        rbgp.RigidBodyGP(subsample=2.0, **FAST_KW).fit(demos)
    assert err.value.param == "subsample" and "--" not in str(err.value)
    with pytest.raises(InputError) as err:
        rbgp.train_options(rho_rot="x")
    assert err.value.param == "rho_rot" and str(err.value) == "rho_rot must be a number, got 'x'"
    with pytest.raises(InputError, match="not fitted"):
        rbgp.RigidBodyGP().predict(np.zeros(7) + [0, 0, 0, 1, 0, 0, 0])
    # the command line's bounds hold for the library too, each error naming its parameter (before: a raw numpy
    # error for max_points 0, a plain ValueError for 1, restarts 0 accepted, and no parameter named)
    for kw, param in ((dict(max_points=0), "max_points"), (dict(max_points=1), "max_points"),
                      (dict(restarts=0), "restarts"), (dict(representation="bogus"), "representation"),
                      (dict(kernel="foo"), "kernel")):
        with pytest.raises(InputError) as err:
            rbgp.RigidBodyGP(**{**FAST_KW, **kw}).fit(demos)
        assert err.value.param == param and "--" not in str(err.value), (kw, err.value)


def test_cli_shows_flags_for_parameters(tmp_path):
    res = run("train", CSV_DIR, "-o", tmp_path / "m.rbgp", "--rho-rot", "x")
    assert res.exit_code == 2 and "rbgp: error: --rho-rot must be a number, got 'x'" in res.stderr
    res = run("train", CSV_DIR, "-o", tmp_path / "m.rbgp", "--subsample", "2")
    assert res.exit_code == 2 and "--subsample must lie in (0, 1]" in res.stderr


def _numbered_quaternion_csv(tmp_path):
    """A CSV whose quaternion columns are q0..q3: their order (w first or last) is the user's to say."""
    t = np.arange(20) * 0.02
    rows = ["t,x,y,z,q0,q1,q2,q3"] + [f"{s:.2f},{0.1 * s:.4f},0,1,1,0,0,0" for s in t]
    path = tmp_path / "numbered.csv"
    path.write_text("\n".join(rows) + "\n")
    return path


def test_reader_errors_name_the_read_option_and_the_cli_its_flag(tmp_path):
    """The same file: rbgp.read_demonstrations says quat_order (param "quat_order"), rbgp train --quat-order."""
    path = _numbered_quaternion_csv(tmp_path)
    with pytest.raises(InputError) as err:
        rbgp.read_demonstrations(path)
    assert err.value.param == "quat_order" and "--" not in str(err.value)
    assert "q0, q1, q2, q3 are numbered" in str(err.value)
    assert err.value.hint == "pass quat_order xyzw (w last) or quat_order wxyz (w first)"
    res = run("train", path, "-o", tmp_path / "m.rbgp", *FAST)
    assert res.exit_code == 2 and "q0, q1, q2, q3 are numbered" in res.stderr
    assert "pass --quat-order xyzw (w last) or --quat-order wxyz (w first)" in res.stderr and "quat_order" not in res.stderr
    assert len(rbgp.read_demonstrations(path, quat_order="wxyz")) == 1

    # two one-word parameters in one hint: rate and columns (param is a tuple)
    nort = tmp_path / "no_time.csv"
    nort.write_text("tme,x,y,z,qx,qy,qz,qw\n" + "".join(f"{i},{0.01 * i},0,1,0,0,0,1\n" for i in range(20)))
    with pytest.raises(InputError) as err:
        rbgp.read_demonstrations(nort)
    assert err.value.param == ("rate", "columns") and "--" not in str(err.value)
    assert "no time column (columns are tme, x, y, z, qx, qy, qz, qw)" in str(err.value)
    assert err.value.hint == "did you mean 'tme'? pass columns t=tme, or rate HZ"
    res = run("inspect", nort)
    assert res.exit_code == 2 and "did you mean 'tme'? pass --columns t=tme, or --rate HZ" in res.stdout
    assert "still needed  --rate HZ (no time column)" in res.stdout and "--columns (see the error)" in res.stdout


def test_library_warnings_name_parameters_and_the_cli_its_flags(tmp_path):
    """warn(param=): the library says "rate 50 is ignored", rbgp inspect "--rate 50 is ignored"."""
    import warnings

    from rbgp_cli.errors import RbgpWarning
    from rbgp_cli.io import export
    from tests.hostile import builders as B

    path = tmp_path / "vicon.csv"
    export.write_vicon_csv([B.smooth_motion(name="Subj:Pelvis")], path, rate=100.0)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        rbgp.read_demonstrations(path, rate=50.0)
    texts = [str(w.message) for w in caught if issubclass(w.category, RbgpWarning)]
    assert any("rate 50 is ignored: the file states 100 Hz" in t and "--rate" not in t for t in texts), texts
    res = run("inspect", path, "--rate", "50")
    assert "rbgp: warning: " in res.stderr and "--rate 50 is ignored: the file states 100 Hz" in res.stderr, res.stderr


def test_as_flags_maps_param_and_underscored_names_only():
    from rbgp_cli.cli.common import as_flags

    flags = {"steps": "--steps", "max_points": "--max-points", "fmt": "--format", "folds": "--folds"}
    e = InputError("steps must be at least 1 (626 steps); max_points too", hint="or max_points 100", param="steps")
    assert as_flags(e, flags) == "--steps must be at least 1 (626 steps); --max-points too; or --max-points 100"
    e = InputError("9 demonstrations cannot make 10 folds", hint="use folds 9 or fewer", param="folds")
    assert as_flags(e, flags) == "9 demonstrations cannot make 10 folds; use --folds 9 or fewer"
    assert as_flags(InputError("steps are many"), flags) == "steps are many"  # not the parameter: left alone


def test_as_flags_maps_several_params_and_on_off_flags():
    from rbgp_cli.cli.common import as_flags

    flags = {"rate": "--rate", "columns": "--columns", "fmt": "--format", "format": "--format",
             "degrees": "--degrees", "degrees=True": "--degrees", "degrees=False": "--radians"}
    # the names of a tuple param, in the hint; the message uses "columns" plainly after its start
    e = InputError("no time column (columns are tme, x, y)", hint="pass rate HZ or columns t=tme",
                   param=("rate", "columns"))
    assert as_flags(e, flags) == "no time column (columns are tme, x, y); pass --rate HZ or --columns t=tme"
    e = InputError("columns qw=w0: the file has no column 'w0' (columns are t, x)", param="columns")
    assert as_flags(e, flags) == "--columns qw=w0: the file has no column 'w0' (columns are t, x)"
    # and where a "; " part of the message starts with it
    e = InputError("with 1 the score measures the ridge; rate 2 needs more; say rate", param="rate")
    assert as_flags(e, flags) == "with 1 the score measures the ridge; --rate 2 needs more; say rate"
    # an on/off flag: NAME=True / NAME=False, the plain word stays
    e = InputError("angles in degrees or radians?", hint="pass degrees=True or degrees=False", param="degrees")
    assert as_flags(e, flags) == "angles in degrees or radians?; pass --degrees or --radians"
    # the flag's own name where the command's parameter is named differently (fmt)
    assert as_flags(InputError("format 'x' is unknown", param="format"), flags) == "--format 'x' is unknown"
    assert as_flags(e, {}) == "angles in degrees or radians?; pass degrees=True or degrees=False"  # no command
    # a name in brackets is not the parameter (a pip extra)
    e = InputError("plot needs matplotlib", hint="pip install 'rbgp-cli[plot]'", param="plot")
    assert as_flags(e, {"plot": "--plot"}) == "--plot needs matplotlib; pip install 'rbgp-cli[plot]'"


def test_cli_option_flags_of_the_running_command():
    """_option_flags: each option under its parameter's name and its flag's, on/off flags as NAME=True/False;
    as_flags maps another command's option only where the error names it as its parameter."""
    import typer
    from typer.testing import CliRunner

    from rbgp_cli.cli.common import _option_flags, as_flags

    app, seen = typer.Typer(), {}

    @app.command()
    def cmd(fmt: str = typer.Option("auto", "--format"), degrees: bool = typer.Option(None, "--degrees/--radians"),
            max_points: int = 0):
        seen.update(_option_flags())
        seen["other"] = _option_flags(other_commands=True)
        e = InputError("model header: time_input = 'x'; max_points too", hint="retrain with time_input none")
        seen["plain"] = as_flags(e)
        seen["param"] = as_flags(InputError(e.message, hint=e.hint, param="time_input"))

    @app.command()
    def train(time_input: str = "phase"):
        pass

    assert CliRunner().invoke(app, ["cmd"]).exit_code == 0
    assert seen["fmt"] == seen["format"] == "--format" and seen["max_points"] == "--max-points"
    assert seen["degrees"] == seen["degrees=True"] == "--degrees" and seen["degrees=False"] == "--radians"
    assert "time_input" not in seen and seen["other"]["time_input"] == "--time-input"
    assert seen["plain"] == "model header: time_input = 'x'; --max-points too; retrain with time_input none"
    assert seen["param"] == "model header: --time-input = 'x'; --max-points too; retrain with --time-input none"


#: A CLI flag in a library message: ``--steps``, ``--quat-order`` (the command line adds them, as_flags).
_FLAG = re.compile(r"(?<![\w-])--[a-z][a-z-]+")
#: Calls whose text reaches the user as an error, a hint or a warning.
_MESSAGE_CALLS = {"InputError", "RbgpRuntimeError", "NotPoseData", "RbgpError", "warn"}


def _message_strings(tree):
    """{(line, text)} of the string constants and f-string parts in the arguments of the message calls,
    of what is raised (``raise _bad(path, "...")``) and of every ``hint=``, and in what their
    arguments' names are assigned (``hint = f"..."; raise InputError(m, hint=hint)``), function by
    function."""
    found = set()

    def strings(node):
        found.update((sub.lineno, sub.value) for sub in ast.walk(node)
                     if isinstance(sub, ast.Constant) and isinstance(sub.value, str))

    scopes = [n for n in ast.walk(tree) if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef))] + [tree]
    for scope in scopes:
        calls = [n for n in ast.walk(scope) if isinstance(n, ast.Call)
                 and (getattr(n.func, "id", None) or getattr(n.func, "attr", None)) in _MESSAGE_CALLS]
        calls += [n.exc for n in ast.walk(scope) if isinstance(n, ast.Raise) and isinstance(n.exc, ast.Call)]
        args = [a for c in calls for a in (*c.args, *(k.value for k in c.keywords if k.arg in (None, "hint")))]
        args += [k.value for n in ast.walk(scope) if isinstance(n, ast.Call) for k in n.keywords if k.arg == "hint"]
        for a in args:
            strings(a)
        names = {n.id for a in args for n in ast.walk(a) if isinstance(n, ast.Name)}
        for node in ast.walk(scope):
            if isinstance(node, (ast.Assign, ast.AugAssign, ast.AnnAssign)) and node.value is not None:
                targets = node.targets if isinstance(node, ast.Assign) else [node.target]
                if any(isinstance(t, ast.Name) and t.id in names for t in targets):
                    strings(node.value)
            elif (isinstance(node, ast.Call) and getattr(node.func, "attr", None) in ("append", "extend")
                  and isinstance(node.func.value, ast.Name) and node.func.value.id in names):
                for a in node.args:
                    strings(a)
    return found


def test_library_messages_name_parameters_not_flags():
    """Library errors, hints and warnings name parameters (``quat_order``, ``steps`` with param=);
    only rbgp_cli/cli/ writes ``--flags`` (as_flags turns the names into the running command's options)."""
    bad = ast.parse('def f(n):\n    hint = f"use --steps {n}"\n    raise InputError("x", hint=hint)\n'
                    'def g():\n    warn("ignoring --rate")\n    raise _bad("p", "retrain with fewer --max-points")\n')
    assert sorted(t for _, t in _message_strings(bad) if _FLAG.search(t)) == [
        "ignoring --rate", "retrain with fewer --max-points", "use --steps "]  # the scan sees them
    pkg = REPO / "rbgp_cli"
    found = []
    for path in sorted(pkg.rglob("*.py")):
        if (pkg / "cli") in path.parents:
            continue
        for line, text in sorted(_message_strings(ast.parse(path.read_text(encoding="utf-8")))):
            if _FLAG.search(text):
                found.append(f"{path.relative_to(REPO)}:{line}: {text.strip()!r}")
    assert not found, "library messages that name CLI flags:\n" + "\n".join(found)


@pytest.mark.slow
def test_docs_example_runs(capsys):
    ns = runpy.run_path(str(REPO / "docs" / "examples" / "python_api.py"), run_name="example")
    out = ns["main"]()
    text = capsys.readouterr().out
    assert "9 demonstrations" in text and "bhattacharyya mean" in text and "replay" in text
    r = out["rollout"]
    assert r.quat.shape[0] == 3 and r.sample_quat.shape[:2] == (3, 5)
    assert np.all(np.isfinite(r.position)) and np.all(np.isfinite(r.sample_position))
    assert np.all(np.abs(r.position) < 5)  # metres: the shoe stays near the table
    assert 0 <= out["score"].mean < 10 and np.isfinite(out["score"].rotation)
    f = out["crossval"].to_frame()
    assert len(f) == 3 and np.all(np.isfinite(f["score"])) and np.all(f["ratio"] > 0)
    assert out["mean"].shape == out["std"].shape == (len(out["demos"][0]), 6)


@pytest.mark.slow
def test_docstring_examples_run():
    import doctest

    import rbgp_cli.api

    res = doctest.testmod(rbgp_cli.api, optionflags=doctest.ELLIPSIS)
    assert res.attempted >= 9 and res.failed == 0


@pytest.mark.slow
def test_readme_python_section_runs(tmp_path):
    """The README's "Python" section: its code runs as shown (with this checkout's package)."""
    import os
    import re

    text = (REPO / "README.md").read_text().split("## Python", 1)[1].split("\n## ", 1)[0]
    code = "\n".join(re.findall(r"```python\n(.*?)```", text, re.S))
    code = code.replace('"shoe.rbgp"', repr(str(tmp_path / "shoe.rbgp")))
    script = tmp_path / "readme_python.py"
    script.write_text("def main():\n" + "".join(f"    {ln}\n" for ln in code.splitlines())
                      + "\n\nif __name__ == '__main__':\n    main()\n")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
    res = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, cwd=REPO, timeout=300, env=env)
    assert res.returncode == 0, res.stderr[-2000:]
    first = res.stdout.splitlines()[0]
    assert re.fullmatch(r"\(3, \d+, 4\) \(3, 5, \d+, 3\)", first), first
    assert "replay" in res.stdout and "axis-angle" in res.stdout and (tmp_path / "shoe.rbgp").exists()
