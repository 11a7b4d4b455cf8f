"""What rbgp writes, as a user on a shared machine meets it: numbers that read back as numbers, the
file mode a plain ``open(..., "w")`` gives, output paths checked before the work, and write failures
(full disk, file-size limit, no permission) as one line that names the file (issues 22 and 24)."""

from __future__ import annotations

import errno
import json
import os
import stat
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from tests.cli.test_cli import CSV_DIR, FAST, REPO, assert_one_line_error, run


@pytest.fixture
def umask_022():
    old = os.umask(0o022)
    try:
        yield
    finally:
        os.umask(old)


def mode(path) -> int:
    return stat.S_IMODE(os.stat(path).st_mode)


def no_temp_files(folder) -> bool:
    return not any(p.name.endswith(".tmp") for p in folder.rglob("*"))


# --------------------------------------------------------------------------- per-step CSVs (22.1)
def test_evaluate_per_step_csv_reads_back_as_numbers(model, tmp_path):
    """The ``s`` column was written as ``np.float64(0.0)``: pandas read strings."""
    import pandas as pd

    per = tmp_path / "per_step.csv"
    res = run("evaluate", "--model", model, "--count", 5, "--demos", CSV_DIR, "--per-step", per, "--json")
    assert res.exit_code == 0, res.stderr
    steps = json.loads(res.stdout)["steps"]
    df = pd.read_csv(per)
    assert list(df.columns) == ["step", "s", "bhattacharyya", "rotation", "translation", "offset", "spread"]
    np.testing.assert_allclose(df["offset"] + df["spread"], df["bhattacharyya"], rtol=1e-12)
    assert all(pd.api.types.is_numeric_dtype(df[c]) for c in df.columns), df.dtypes
    np.testing.assert_array_equal(df["step"].to_numpy(), np.arange(steps))
    np.testing.assert_allclose(df["s"].to_numpy(), np.arange(steps) / (steps - 1), rtol=0, atol=1e-15)
    assert "np." not in per.read_text()


def test_demo_per_step_csv_reads_back_as_numbers(tmp_path):
    import pandas as pd

    out = tmp_path / "demo"
    res = run("demo", "--quick", "--count", 4, "--representations", "euler", "--out", out, "--json")
    assert res.exit_code == 0, res.stderr
    df = pd.read_csv(out / "euler_per_step.csv")
    assert all(pd.api.types.is_numeric_dtype(df[c]) for c in df.columns), df.dtypes
    assert df["s"].iloc[0] == 0.0 and df["s"].iloc[-1] == 1.0
    mean = json.loads(res.stdout)["representations"]["euler"]["bhattacharyya"]["mean"]
    assert df["bhattacharyya"].mean() == pytest.approx(mean, rel=1e-12)


def test_json_writer_turns_numpy_scalars_into_numbers():
    from rbgp_cli.cli.common import _json_default

    for v in (np.float32(0.5), np.int64(3), np.bool_(True)):
        assert json.loads(json.dumps({"v": v}, default=_json_default))["v"] == v.item()


# --------------------------------------------------------------------------- file modes (22.2)
@pytest.mark.slow
def test_every_output_gets_the_mode_of_a_plain_open(model, tmp_path, umask_022):
    """Outputs were 0600 (mkstemp's mode): colleagues could not read them. Under umask 022: 0644."""
    m = tmp_path / "m.rbgp"
    assert run("train", CSV_DIR, "-o", m, *FAST, "--rerun", tmp_path / "train.rrd").exit_code == 0
    gen = tmp_path / "gen.csv"
    res = run("rollout", model, "--count", 3, "--steps", 20, "--no-std", "-o", gen, "--rerun", tmp_path / "r.rrd")
    assert res.exit_code == 0, res.stderr
    res = run("evaluate", "--model", model, "--count", 3, "--demos", CSV_DIR, "--per-step", tmp_path / "p.csv",
              "--plot", tmp_path / "fig.png", "--rerun", tmp_path / "e.rrd")
    assert res.exit_code == 0, res.stderr
    poses = tmp_path / "poses.csv"
    poses.write_text("t,rx,ry,rz,x,y,z\n0.0,0.1,0.2,0.3,0.3,0.0,1.1\n1.0,0.0,0.0,0.0,0.5,0.1,0.8\n")
    assert run("predict", model, poses, "-o", tmp_path / "pred.csv").exit_code == 0
    made = ["m.rbgp", "train.rrd", "gen.csv", "r.rrd", "p.csv", "fig.png", "e.rrd", "pred.csv"]
    assert {f: oct(mode(tmp_path / f)) for f in made} == {f: oct(0o644) for f in made}
    assert no_temp_files(tmp_path)


def test_atomic_writer_follows_the_umask_and_keeps_an_existing_files_mode(tmp_path):
    from rbgp_cli.io.atomic import atomic_open, atomic_path

    old = os.umask(0o027)
    try:
        with atomic_open(tmp_path / "a.txt") as fh:
            fh.write("x")
        assert mode(tmp_path / "a.txt") == 0o640
        with atomic_path(tmp_path / "b.bin") as tmp:
            with open(tmp, "w") as fh:  # a library writing to the name it was given
                fh.write("y")
        assert mode(tmp_path / "b.bin") == 0o640
        os.chmod(tmp_path / "a.txt", 0o604)  # open(..., "w") on an existing file keeps its mode
        with atomic_open(tmp_path / "a.txt") as fh:
            fh.write("z")
        assert mode(tmp_path / "a.txt") == 0o604 and (tmp_path / "a.txt").read_text() == "z"
    finally:
        os.umask(old)


def test_demo_outputs_are_readable_by_others(tmp_path, umask_022):
    out = tmp_path / "demo"
    assert run("demo", "--quick", "--count", 3, "--representations", "euler", "--out", out).exit_code == 0
    files = sorted(p.name for p in out.iterdir())
    assert files == ["euler.rbgp", "euler_per_step.csv", "euler_rollouts.csv"]
    assert all(mode(out / f) == 0o644 for f in files), {f: oct(mode(out / f)) for f in files}


# --------------------------------------------------------------------------- output paths up front (22.4)
@pytest.fixture
def no_training(monkeypatch):
    """Training, rollouts or scoring would fail the test: the check must come before the work."""
    import rbgp_cli.dynamics.model as model_mod
    import rbgp_cli.dynamics.rollout as rollout_mod
    import rbgp_cli.workflows as wf

    def boom(*a, **k):
        raise AssertionError("the work started before the output paths were checked")

    monkeypatch.setattr(model_mod, "train_model", boom)
    monkeypatch.setattr(rollout_mod, "rollout", boom)
    monkeypatch.setattr(wf, "evaluate_files", boom)
    monkeypatch.setattr(wf, "crossval_files", boom)
    monkeypatch.setattr(wf, "load_demonstrations", boom)
    monkeypatch.setattr(wf, "predict_file", boom)
    import rbgp_cli.bench.paper as paper

    monkeypatch.setattr(paper, "run_paper_bench", boom)


@pytest.mark.parametrize("args,bad", [
    (["train", str(CSV_DIR), "-o", "{tmp}/m.rbgp", "--rerun", "{tmp}/missing/t.rrd"], "{tmp}/missing/t.rrd"),
    (["rollout", "{model}", "-o", "{tmp}/gen.csv", "--rerun", "{tmp}/missing/r.rrd"], "{tmp}/missing/r.rrd"),
    (["rollout", "{model}", "-o", "{tmp}/missing/gen.csv"], "{tmp}/missing/gen.csv"),
    (["evaluate", "--model", "{model}", "--demos", str(CSV_DIR), "--plot", "{tmp}/missing/f.png"], "{tmp}/missing/f.png"),
    (["evaluate", "--model", "{model}", "--demos", str(CSV_DIR), "--rerun", "{tmp}/missing/e.rrd"], "{tmp}/missing/e.rrd"),
    (["evaluate", "--model", "{model}", "--demos", str(CSV_DIR), "--per-step", "{tmp}/missing/p.csv"], "{tmp}/missing/p.csv"),
    (["evaluate", "--model", "{model}", "--demos", str(CSV_DIR), "--plot", "{tmp}"], "{tmp}"),
    (["predict", "{model}", str(CSV_DIR / "shoe_01.csv"), "-o", "{tmp}/missing/p.csv"], "{tmp}/missing/p.csv"),
    (["demo", "--quick", "--out", "{tmp}/afile"], "{tmp}/afile"),
    (["bench", "paper", "theorem", "--quick", "--markdown", "{tmp}/missing/paper.md"], "{tmp}/missing/paper.md"),
])
def test_output_paths_are_checked_before_the_work(model, tmp_path, no_training, args, bad):
    (tmp_path / "afile").write_text("not a folder")
    sub = lambda a: a.replace("{tmp}", str(tmp_path)).replace("{model}", str(model))  # noqa: E731
    res = run(*[sub(a) for a in args])
    assert_one_line_error(res, 2, sub(bad))
    assert not (tmp_path / "m.rbgp").exists() and not (tmp_path / "gen.csv").exists()
    assert no_temp_files(tmp_path)


def test_plot_without_matplotlib_says_so_before_the_work(model, tmp_path, no_training, monkeypatch):
    for name in ("matplotlib", "matplotlib.figure", "matplotlib.backends.backend_agg"):
        monkeypatch.setitem(sys.modules, name, None)
    res = run("evaluate", "--model", model, "--demos", CSV_DIR, "--plot", tmp_path / "f.png")
    assert_one_line_error(res, 2, "--plot needs matplotlib", "rbgp-cli[plot]")
    assert not (tmp_path / "f.png").exists()


@pytest.mark.skipif(hasattr(os, "geteuid") and os.geteuid() == 0, reason="root may write into any folder")
def test_an_unwritable_plot_folder_is_refused_before_the_work(model, tmp_path, no_training):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        res = run("evaluate", "--model", model, "--demos", CSV_DIR, "--plot", ro / "f.png")
        assert_one_line_error(res, 2, str(ro / "f.png"), "not writable")
    finally:
        ro.chmod(0o700)


# --------------------------------------------------------------------------- write failures (24.7)
def _failing_fsync(err):
    def fsync(fd):
        raise OSError(err, os.strerror(err))
    return fsync


@pytest.mark.parametrize("err,code", [(errno.ENOSPC, 1), (errno.EFBIG, 1), (errno.EROFS, 2), (errno.EACCES, 2)])
def test_a_failing_write_is_one_line_naming_the_file_and_keeps_the_old_one(model, tmp_path, monkeypatch, err, code):
    gen = tmp_path / "gen.csv"
    gen.write_text("old\n")
    import rbgp_cli.io.atomic as atomic

    monkeypatch.setattr(atomic.os, "fsync", _failing_fsync(err))
    res = run("rollout", model, "--count", 2, "--steps", 5, "--no-std", "-o", gen, "-q")
    assert_one_line_error(res, code, f"cannot write {gen}: {os.strerror(err)}")
    assert gen.read_text() == "old\n" and no_temp_files(tmp_path)


@pytest.mark.slow
def test_a_full_disk_under_the_model_and_the_figure(model, tmp_path, monkeypatch):
    """Writes that go through a library (matplotlib's savefig) and the model file."""
    import rbgp_cli.io.atomic as atomic

    (tmp_path / "m.rbgp").write_bytes(b"old model")
    import matplotlib.figure

    def savefig(self, fname, **kw):
        with open(fname, "wb") as fh:
            fh.write(b"\x89PNG")
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", savefig)
    res = run("evaluate", "--model", model, "--count", 3, "--demos", CSV_DIR, "--plot", tmp_path / "f.png", "-q")
    assert_one_line_error(res, 1, f"cannot write {tmp_path / 'f.png'}: No space left on device")
    monkeypatch.setattr(atomic.os, "fsync", _failing_fsync(errno.ENOSPC))
    res = run("train", CSV_DIR, "-o", tmp_path / "m.rbgp", *FAST, "-q")
    assert_one_line_error(res, 1, f"cannot write {tmp_path / 'm.rbgp'}: No space left on device")
    assert (tmp_path / "m.rbgp").read_bytes() == b"old model" and no_temp_files(tmp_path)


@pytest.mark.parametrize("option", ["-o", "--rerun"])
@pytest.mark.slow
def test_a_file_size_limit_is_one_line_in_a_real_process(model, tmp_path, option):
    """RLIMIT_FSIZE with SIGXFSZ ignored (Python's default): the write raises EFBIG ("File too
    large"). With --rerun, rerun's own file sink blocked for good in 2 of 3 runs."""
    pytest.importorskip("resource")
    gen = tmp_path / ("gen.csv" if option == "-o" else "gen.rrd")
    gen.write_text("old\n")
    code = textwrap.dedent(f"""
        import resource, signal, sys
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (2000, 2000))
        from rbgp_cli.cli.app import main
        sys.argv = ["rbgp", "rollout", {str(model)!r}, "--count", "4", "--steps", "50", "--no-std", {option!r}, {str(gen)!r}]
        main()
    """)
    env = dict(os.environ, PYTHONPATH=str(REPO))
    env.pop("RBGP_DEBUG", None)
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, env=env, cwd=tmp_path)
    lines = res.stderr.strip().splitlines()
    assert res.returncode == 1, res.stderr
    assert lines[-1] == f"rbgp: error: cannot write {gen}: File too large", res.stderr
    assert "Traceback" not in res.stderr and "internal error" not in res.stderr
    assert gen.read_text() == "old\n" and no_temp_files(tmp_path)


# --------------------------------------------------------------------------- concatenated CSVs (22.11a)
def test_concatenated_csvs_on_stdin_name_the_second_header_line(tmp_path):
    """``cat a.csv b.csv | rbgp train -`` said "non-numeric value 'qx' in column 'qx'"."""
    a, b = (CSV_DIR / "shoe_01.csv").read_text(), (CSV_DIR / "shoe_02.csv").read_text()
    second = len(a.splitlines()) + 1
    res = run("train", "-", "-o", tmp_path / "m.rbgp", *FAST, input=a + b)
    assert_one_line_error(res, 2, f"-:{second}:", "a second header line", "concatenated files?",
                          "give them as separate files")
    assert "non-numeric" not in res.stderr and not (tmp_path / "m.rbgp").exists()
    from rbgp_cli.errors import InputError
    from rbgp_cli.io.csv import read_text

    with pytest.raises(InputError, match=rf"x\.csv:{second + 1}: a second header line"):  # after a comment line
        read_text("# rbgp trajectories: time_unit=s\n" + a + b, "x.csv")
    with pytest.raises(InputError, match=r"x\.csv:3: non-numeric value 'qx' in column 'qx'"):  # one stray cell
        read_text("t,x,y,z,qx,qy,qz,qw\n0,0,0,0,0,0,0,1\n0.1,0,0,0,qx,0,0,1\n", "x.csv")


# --------------------------------------------------------------------------- README and --help (22.11b, c)
def test_the_quick_start_installs_what_the_first_plot_example_needs():
    import re
    import tomllib

    text = (REPO / "README.md").read_text(encoding="utf-8")
    install = next(line for line in text.splitlines() if "pip install" in line)
    assert text.index(install) < text.index("rbgp evaluate gen.csv --demos sample_data/csv/*.csv --plot")
    extras = re.search(r"""pip install ["']?\.\[([\w,-]+)\]""", install)
    assert extras and "plot" in extras.group(1).split(","), install
    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    assert any(d.startswith("matplotlib") for d in project["optional-dependencies"]["plot"])


def _all_help_texts():
    import typer

    from rbgp_cli.cli.app import app

    def walk(cmd, path):
        yield path, cmd
        if hasattr(cmd, "commands"):  # a group (typer's own click)
            for name, sub in cmd.commands.items():
                yield from walk(sub, path + [name])

    for path, _cmd in walk(typer.main.get_command(app), []):
        res = run(*path, "--help")
        assert res.exit_code == 0, (path, res.stderr)
        yield path, res.stdout


@pytest.mark.slow
def test_help_texts_cite_no_file_the_user_does_not_have():
    """MATH.md is not shipped: --help says in words what it meant."""
    texts = dict((" ".join(p), t) for p, t in _all_help_texts())
    assert {"", "train", "rollout", "evaluate", "crossval", "bench paper"} <= set(texts)
    assert [p for p, t in texts.items() if "MATH.md" in t] == []
    assert "exponential map" in " ".join(texts["rollout"].split())


def test_a_recording_that_cannot_be_written_is_one_line(model, tmp_path, monkeypatch):
    """rerun's own file sink, on a failed write, logged the reason, raised a bare RuntimeError
    ('File-writer thread shut down prematurely') and at times blocked for good: the recording is now
    written by the atomic writer."""
    pytest.importorskip("rerun")
    rrd = tmp_path / "r.rrd"
    rrd.write_bytes(b"old recording")
    fsync, full = os.fsync, _failing_fsync(errno.ENOSPC)  # only the recording's (Linux: the fd's file name)
    monkeypatch.setattr(os, "fsync", lambda fd: (full if ".r.rrd." in os.readlink(f"/proc/self/fd/{fd}") else fsync)(fd))
    res = run("rollout", model, "--count", 2, "--steps", 5, "--no-std", "-o", tmp_path / "gen.csv", "--rerun", rrd, "-q")
    assert_one_line_error(res, 1, f"cannot write {rrd}: No space left on device")
    assert rrd.read_bytes() == b"old recording" and no_temp_files(tmp_path)
    assert (tmp_path / "gen.csv").exists()


@pytest.mark.slow
def test_stdout_redirected_into_a_file_past_the_size_limit_is_one_line(model, tmp_path):
    """``rbgp rollout ... > gen.csv`` under a file-size limit: the shell's file is stdout."""
    code = textwrap.dedent(f"""
        import resource, sys
        resource.setrlimit(resource.RLIMIT_FSIZE, (2000, 2000))
        from rbgp_cli.cli.app import main
        sys.argv = ["rbgp", "rollout", {str(model)!r}, "--count", "4", "--steps", "50", "--no-std", "-q"]
        main()
    """)
    env = dict(os.environ, PYTHONPATH=str(REPO))
    env.pop("RBGP_DEBUG", None)
    with open(tmp_path / "gen.csv", "wb") as out:
        res = subprocess.run([sys.executable, "-c", code], stdout=out, stderr=subprocess.PIPE, text=True, timeout=120,
                             env=env, cwd=tmp_path)
    assert res.returncode == 1, res.stderr
    assert res.stderr.strip().splitlines() == ["rbgp: error: cannot write stdout: File too large"], res.stderr
