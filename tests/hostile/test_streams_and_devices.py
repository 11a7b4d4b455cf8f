"""Faults, round two (issue 40), as a shell user meets them: devices and FIFOs as outputs and inputs,
closed and full standard streams, too few file descriptors, a killed ``inspect -``, a lost Dask
scheduler. Real subprocesses (``python -m rbgp_cli``) with timeouts: a hang fails the test instead of
the suite. Every case ends in a correct result or one ``rbgp: error:`` line with exit 1 or 2."""

from __future__ import annotations

import os
import shutil
import stat
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from tests.hostile import builders as B

REPO = Path(__file__).resolve().parents[2]
ENV = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")])))
#: No case may take longer (a hang is a failure, not a stuck suite); the slowest measured: 6 s.
TIMEOUT = 120


def rbgp(*args, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, shell_prefix: str | None = None, cwd=None,
         env=None):
    """``python -m rbgp_cli -q ARGS``; with ``shell_prefix`` run through bash after it (``ulimit``,
    ``>&-``). Returns (exit code, stdout bytes, stderr text)."""
    cmd = [sys.executable, "-m", "rbgp_cli", "-q", *map(str, args)]
    if shell_prefix is not None:
        import shlex

        cmd = ["bash", "-c", shell_prefix.replace("RBGP", " ".join(map(shlex.quote, cmd)))]
    res = subprocess.run(cmd, stdin=stdin, stdout=stdout, stderr=subprocess.PIPE, env=env or ENV, cwd=cwd,
                         timeout=TIMEOUT)
    return res.returncode, res.stdout or b"", res.stderr.decode("utf-8", "replace")


def one_error_line(err: str, *fragments) -> str:
    lines = err.strip().splitlines()
    assert "Traceback" not in err and "internal error" not in err, err
    assert len(lines) >= 1 and lines[-1].startswith("rbgp: error: "), err
    assert all(ln.startswith(("rbgp: error: ", "rbgp: warning: ")) for ln in lines), err
    assert sum(ln.startswith("rbgp: error: ") for ln in lines) == 1, err
    for f in fragments:
        assert f in lines[-1], (f, lines[-1])
    return lines[-1]


@pytest.fixture(scope="module")
def demo(tmp_path_factory) -> Path:
    return B.write_csv(tmp_path_factory.mktemp("demo") / "demo.csv")


@pytest.fixture(scope="module")
def model(tmp_path_factory, demo) -> Path:
    path = tmp_path_factory.mktemp("model") / "m.rbgp"
    code, _, err = rbgp("train", demo, "-o", path, *B.FAST, "--jobs", "1")
    assert code == 0, err
    return path


def _writer(path: Path, data: bytes):
    """A thread that writes ``data`` into the FIFO ``path`` (blocks until a reader opens it)."""

    def run():
        with open(path, "wb") as fh:
            fh.write(data)

    th = threading.Thread(target=run, daemon=True)
    th.start()
    return th


def _reader(path: Path, out: list):
    def run():
        with open(path, "rb") as fh:
            out.append(fh.read())

    th = threading.Thread(target=run, daemon=True)
    th.start()
    return th


# ---------------------------------------------------------------------------------------------- devices as outputs
@pytest.mark.slow
def test_rollout_and_train_to_dev_null_write_into_it_and_leave_the_device(model, demo, tmp_path):
    """``-o /dev/null`` renamed a temporary file onto the device (as root: /dev/null became a regular
    file for every program). Now the output is written into it; nothing is left in /dev."""
    before = set(os.listdir("/dev"))
    code, out, err = rbgp("rollout", model, "-o", "/dev/null", cwd=tmp_path)
    assert code == 0 and err == "", err
    code, _, err = rbgp("train", demo, "-o", "/dev/null", *B.FAST, "--jobs", "1", cwd=tmp_path)
    assert code == 0 and err == "", err
    assert stat.S_ISCHR(os.stat("/dev/null").st_mode)
    assert set(os.listdir("/dev")) - before == set()


@pytest.mark.slow
def test_train_to_dev_full_is_one_line_exit_1_and_leaves_the_device(demo, tmp_path):
    if not os.path.exists("/dev/full"):
        pytest.skip("no /dev/full")
    code, _, err = rbgp("train", demo, "-o", "/dev/full", *B.FAST, "--jobs", "1", cwd=tmp_path)
    assert code == 1
    one_error_line(err, "/dev/full", "No space left on device")
    assert stat.S_ISCHR(os.stat("/dev/full").st_mode)


@pytest.mark.slow
def test_rollout_into_a_fifo_writes_the_csv_into_it_and_keeps_the_fifo(model, tmp_path):
    fifo = tmp_path / "out.fifo"
    os.mkfifo(fifo)
    got: list = []
    th = _reader(fifo, got)
    code, _, err = rbgp("rollout", model, "-o", fifo)
    th.join(TIMEOUT)
    assert code == 0, err
    header = got[0].split(b"\n")[1].split(b",")  # after the "# rbgp trajectories: ..." line
    assert {b"t", b"x", b"y", b"z", b"qx", b"qy", b"qz", b"qw"} <= set(header), header
    assert got[0].count(b"\n") > 10
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)


@pytest.mark.slow
def test_a_fifo_nobody_reads_is_refused_not_waited_for(model, tmp_path):
    fifo = tmp_path / "out.fifo"
    os.mkfifo(fifo)
    code, _, err = rbgp("rollout", model, "-o", fifo)
    assert code == 2
    one_error_line(err, "out.fifo", "nothing reads from this FIFO")
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)


# ---------------------------------------------------------------------------------------------- FIFOs as inputs
@pytest.mark.slow
@pytest.mark.parametrize("command", ["train", "info", "rollout", "inspect", "predict"])
def test_a_fifo_without_a_writer_is_refused_within_seconds(command, tmp_path, model):
    """``train``, ``info`` and ``rollout`` blocked forever in open()."""
    fifo = tmp_path / "in.fifo"
    os.mkfifo(fifo)
    args = {"train": ["train", fifo, "-o", tmp_path / "m.rbgp"], "info": ["info", fifo],
            "rollout": ["rollout", fifo, "-o", tmp_path / "r.csv"], "inspect": ["inspect", fifo],
            "predict": ["predict", model, fifo]}[command]
    code, out, err = rbgp(*args)
    assert code == 2, err
    one_error_line(err, "in.fifo", "nothing writes to this FIFO")
    assert out == b"" and not (tmp_path / "m.rbgp").exists() and not (tmp_path / "r.csv").exists()


@pytest.mark.slow
def test_process_substitution_and_a_fifo_with_a_writer_are_read_as_streams(demo, model, tmp_path):
    """``rbgp train <(cat demo.csv)`` was "the file is empty" (a pipe has no size); the model equals
    the one trained on the file itself."""
    from tests.hostile.test_hostile_cli import assert_same_model

    ref = tmp_path / "ref.rbgp"
    assert rbgp("train", demo, "-o", ref, *B.FAST, "--jobs", "1")[0] == 0
    sub = tmp_path / "sub.rbgp"
    cmd = f"{sys.executable} -m rbgp_cli -q train <(cat {demo}) -o {sub} {' '.join(B.FAST)} --jobs 1"
    res = subprocess.run(["bash", "-c", cmd], env=ENV, capture_output=True, timeout=TIMEOUT)
    assert res.returncode == 0, res.stderr
    assert_same_model(sub, ref)
    fifo = tmp_path / "in.fifo"
    os.mkfifo(fifo)
    th = _writer(fifo, demo.read_bytes())
    via_fifo = tmp_path / "fifo.rbgp"
    code, _, err = rbgp("train", fifo, "-o", via_fifo, *B.FAST, "--jobs", "1")
    th.join(TIMEOUT)
    assert code == 0, err
    assert_same_model(via_fifo, ref)
    res = subprocess.run(["bash", "-c", f"{sys.executable} -m rbgp_cli -q info <(cat {model})"], env=ENV,
                         capture_output=True, timeout=TIMEOUT)
    assert res.returncode == 0 and b"rbgp-model version" in res.stdout, res.stderr


@pytest.mark.slow
def test_a_device_given_as_input_is_refused_at_once(tmp_path):
    code, _, err = rbgp("train", "/dev/zero", "-o", tmp_path / "m.rbgp")
    assert code == 2
    one_error_line(err, "/dev/zero", "is a character device")


# ---------------------------------------------------------------------------------------------- standard streams
@pytest.mark.slow
@pytest.mark.parametrize("command", ["info", "inspect --json"])
def test_stdout_on_a_full_disk_is_one_line_exit_1(command, model, demo):
    if not os.path.exists("/dev/full"):
        pytest.skip("no /dev/full")
    args = ["info", model] if command == "info" else ["inspect", "--json", demo]
    with open("/dev/full", "wb") as full:
        code, _, err = rbgp(*args, stdout=full)
    assert code == 1
    one_error_line(err, "cannot write stdout", "No space left on device")


@pytest.mark.slow
@pytest.mark.parametrize("case", ["rollout -o - >&-", "predict >&-", "train - <&-", "train -o FILE >&- works"])
def test_closed_stdin_or_stdout(case, model, tmp_path, demo):
    poses = tmp_path / "poses.csv"
    poses.write_text("rx,ry,rz,x,y,z\n0.1,0.2,0.3,0.3,0.0,1.1\n", encoding="utf-8")
    if case == "rollout -o - >&-":
        code, _, err = rbgp("rollout", model, "-o", "-", shell_prefix="RBGP >&-")
        one_error_line(err, "stdout is closed")
        assert code == 2
    elif case == "predict >&-":
        code, _, err = rbgp("predict", model, poses, shell_prefix="RBGP >&-")
        one_error_line(err, "stdout is closed")
        assert code == 2
    elif case == "train - <&-":
        code, _, err = rbgp("train", "-", "-o", tmp_path / "m.rbgp", shell_prefix="RBGP <&-")
        one_error_line(err, "stdin is closed")
        assert code == 2 and not (tmp_path / "m.rbgp").exists()
    else:  # stdout closed, but nothing goes to it: the model is written, and nothing else into it
        out = tmp_path / "m.rbgp"
        code, _, err = rbgp("train", demo, "-o", out, *B.FAST, "--jobs", "1", shell_prefix="RBGP >&-")
        assert code == 0 and err == "", err
        from rbgp_cli.io.model_store import load_model

        load_model(out)


@pytest.mark.slow
def test_too_few_file_descriptors_end_in_one_line_instead_of_a_hang(demo, tmp_path):
    """``ulimit -n 16; rbgp train …`` printed an internal error (EMFILE) and never exited: the pool's
    started workers waited for work that never came, and the exit handlers for them."""
    code, _, err = rbgp("train", demo, "-o", tmp_path / "m.rbgp", "--max-points", "40", "--restarts", "1",
                        "--jobs", "2", shell_prefix="ulimit -n 16; RBGP")  # worker processes where there are cores
    if code == 0:  # one core: fitted in this process, which 16 descriptors allow
        from rbgp_cli.io.model_store import load_model

        load_model(tmp_path / "m.rbgp")
        return
    assert code == 1, err
    one_error_line(err, "too many open files", "ulimit -n", "--jobs 1")
    assert not (tmp_path / "m.rbgp").exists()


@pytest.mark.slow
def test_a_killed_inspect_of_stdin_leaves_no_copy_behind(demo, tmp_path):
    """``inspect -`` copied stdin into a named temporary file, left behind when it was killed (200 MB for
    the issue's file); now the copy has no name."""
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    env = dict(ENV, TMPDIR=str(tmp))
    proc = subprocess.Popen([sys.executable, "-m", "rbgp_cli", "-q", "inspect", "-"], env=env, stdin=subprocess.PIPE,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        line = b"0.1,0.2,0.3,0.4,0.0,0.0,0.0,1.0\n"
        proc.stdin.write(b"t,x,y,z,qx,qy,qz,qw\n" + line * 200_000)  # returns once most of it was read
        proc.stdin.flush()
        proc.kill()
        proc.wait(TIMEOUT)
    finally:
        if proc.poll() is None:
            proc.kill()
        try:
            proc.stdin.close()
        except BrokenPipeError:
            pass
    assert list(tmp.iterdir()) == []


# ---------------------------------------------------------------------------------------------- Dask
@pytest.mark.slow
def test_a_lost_dask_scheduler_is_one_error_naming_the_unfinished_tasks():
    """The scheduler closed while tasks ran: ``FuturesCancelledError`` came out as an internal error."""
    distributed = pytest.importorskip("distributed")
    from rbgp_cli.compute import run_tasks
    from rbgp_cli.errors import RbgpRuntimeError
    from tests.test_compute import _sleep

    cluster = distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None)
    outcome: dict = {}

    def study():
        try:
            outcome["result"] = run_tasks(_sleep, [3.0, 3.0, 3.0], scheduler=cluster.scheduler_address,
                                          label=lambda i: f"fold {i + 1}")
        except Exception as exc:  # noqa: BLE001 - the test looks at it
            outcome["error"] = exc

    try:
        th = threading.Thread(target=study, daemon=True)
        th.start()
        import time

        time.sleep(1.5)
        cluster.sync(cluster.scheduler.close)
        th.join(TIMEOUT)
        assert not th.is_alive()
    finally:
        cluster.close()
    err = outcome.get("error")
    assert isinstance(err, RbgpRuntimeError), outcome
    assert "lost the Dask scheduler" in str(err) and "fold 1" in str(err)


def test_dev_null_is_a_character_device():
    """Whatever ran before in this session (the suite writes to /dev/null on purpose above)."""
    assert stat.S_ISCHR(os.stat("/dev/null").st_mode)
    assert shutil.which("bash")  # the shell cases need it
