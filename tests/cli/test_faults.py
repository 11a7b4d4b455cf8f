"""Killed and interrupted runs (issue 24 points 1-3, issue 22 point 5): worker processes end with the
process that started them (SIGKILL, SIGTERM, Ctrl-C), Ctrl-C is one line and exit 130 at any moment,
a killed writer's temporary file is removed by the next write, a Dask study whose workers keep dying
fails with one line naming the fold, and ``-q`` leaves stderr empty."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest
from typer.testing import CliRunner

from rbgp_cli.cli.app import app
from rbgp_cli.compute import usable_cores

psutil = pytest.importorskip("psutil")

REPO = Path(__file__).resolve().parents[2]
CSV_DIR = REPO / "sample_data" / "csv"
#: 312 points, 6 outputs: fits of a few seconds, in 6 worker processes
TRAIN = ["train", CSV_DIR, "--max-points", "400", "--restarts", "1"]
CROSSVAL = ["crossval", CSV_DIR, "--folds", "3", "--max-points", "200", "--restarts", "1", "--jobs", "2"]
runner = CliRunner()
#: this checkout first, whatever the working directory of the child
ENV = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")])))

needs_cores = pytest.mark.skipif(usable_cores() < 2, reason="worker processes start only on two or more cores")


class Run:
    """``python -m rbgp_cli ARGS`` in its own session (a Ctrl-C reaches its whole process group),
    stderr to a file: orphaned workers holding a pipe open would block the reader."""

    def __init__(self, args, cwd):
        self.err = tempfile.TemporaryFile()
        self.proc = subprocess.Popen([sys.executable, "-m", "rbgp_cli", *map(str, args)], cwd=cwd, env=ENV,
                                     stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=self.err,
                                     start_new_session=True)
        self.ps = psutil.Process(self.proc.pid)
        self.t0 = time.monotonic()

    def workers(self):
        """The child processes (workers, and multiprocessing's resource tracker) running now."""
        try:
            return [p for p in self.ps.children(recursive=True) if _alive(p)]
        except psutil.NoSuchProcess:
            return []

    def wait_for_workers(self, n, timeout=60.0):
        while time.monotonic() - self.t0 < timeout:
            kids = [p for p in self.workers() if "resource_tracker" not in " ".join(_cmdline(p))]
            if len(kids) >= n:
                return kids
            assert self.proc.poll() is None, self.stderr()
            time.sleep(0.02)
        raise AssertionError(f"no {n} worker processes after {timeout} s")

    def signal(self, sig, group=False):
        (os.killpg if group else os.kill)(self.proc.pid, sig)

    def wait(self, timeout):
        t = time.monotonic()
        try:
            code = self.proc.wait(timeout)
        finally:
            if self.proc.poll() is None:
                self.proc.kill()
        return code, time.monotonic() - t

    def stderr(self):
        self.err.seek(0)
        return self.err.read().decode(errors="replace")

    def cleanup(self, procs=()):
        for p in [*procs, self.ps]:
            try:
                p.kill()
            except psutil.Error:
                pass
        self.err.close()


def _cmdline(p):
    try:
        return p.cmdline()
    except psutil.Error:
        return []


def _alive(p) -> bool:
    try:
        return p.is_running() and p.status() != psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return False


def _connected(p) -> bool:
    try:
        return any(c.status == psutil.CONN_ESTABLISHED for c in p.net_connections(kind="tcp"))
    except psutil.Error:
        return False


def _assert_all_gone(procs, within=5.0):
    deadline = time.monotonic() + within
    while time.monotonic() < deadline:
        alive = [p for p in procs if _alive(p)]
        if not alive:
            return
        time.sleep(0.05)
    raise AssertionError(f"{len(alive)} of {len(procs)} child processes still running {within} s after their "
                         f"parent ended: {[' '.join(_cmdline(p))[:80] for p in alive]}")


def _args(command, folder):
    if command == "train":
        return [*TRAIN, "-o", folder / "m.rbgp"]
    return [*CROSSVAL, "--scheduler", "local"] if command == "dask" else CROSSVAL


def _leftovers(folder: Path):
    return sorted(p.name for p in folder.iterdir() if p.name.endswith(".tmp"))


@pytest.mark.slow
@needs_cores
@pytest.mark.parametrize("command,sig,delay", [
    *[(c, sig, delay) for c in ("train", "crossval")
      for sig, delay in [(signal.SIGKILL, 0.0), (signal.SIGKILL, 1.0), (signal.SIGTERM, 0.5)]],
    ("dask", signal.SIGKILL, 1.0), ("dask", signal.SIGTERM, 1.0),
])
@pytest.mark.slow
def test_killed_runs_leave_no_worker_and_no_temporary_file(tmp_path, command, sig, delay):
    """Before: all 6 training workers (crossval: its 2) kept running for minutes.
    Dask's workers end with the cluster's process once they have started (Dask's own check, a few
    seconds into a worker's start on a loaded machine)."""
    with _signalled(command, tmp_path, sig, delay) as (run, procs, code, _):
        assert code == (-9 if sig == signal.SIGKILL else 143), run.stderr()
        _assert_all_gone(procs, within=20.0 if command == "dask" else 5.0)
        assert _leftovers(tmp_path) == []
        assert "Traceback" not in run.stderr()


@pytest.mark.slow
@needs_cores
def test_a_crossval_killed_as_its_workers_start_leaves_no_traceback(tmp_path):
    """SIGKILL the moment the first fold worker exists. Before: spawned workers were still reading
    their start-up message from the parent, and each printed multiprocessing's ``EOFError: Ran out of
    input`` traceback (and the resource tracker a leaked-semaphore warning) in 25 of 25 such kills
    (CI met it once with the 0 s delay above). Forked workers read nothing from the parent."""
    for _ in range(5):
        run = Run(CROSSVAL, tmp_path)
        procs = []
        try:
            while not run.workers():
                assert time.monotonic() - run.t0 < 60, "no worker process started"
                assert run.proc.poll() is None, run.stderr()
                time.sleep(0.001)
            procs = run.workers()
            run.signal(signal.SIGKILL)
            assert run.wait(15)[0] == -9
            _assert_all_gone(procs, within=5.0)
            err = run.stderr()
            assert "Traceback" not in err and "leaked" not in err, err
        finally:
            run.cleanup(procs)


@pytest.mark.slow
@needs_cores
@pytest.mark.parametrize("command,group", [("train", False), ("train", True), ("crossval", True), ("dask", True)])
def test_ctrl_c_during_worker_fits_is_one_line_exit_130_at_once(tmp_path, command, group):
    """Before: SIGINT to the main process alone took 8.9 s (the running fits finished first); Ctrl-C
    (the whole process group) during crossval printed ~25 lines of worker tracebacks (Dask: while the
    workers still import, their tracebacks and Dask's exit hook's)."""
    with _signalled(command, tmp_path, signal.SIGINT, 0.5, group=group) as (run, procs, code, seconds):
        err = run.stderr()
        assert code == 130, err
        assert err.rstrip().endswith("rbgp: interrupted"), err
        assert "Traceback" not in err and "KeyboardInterrupt" not in err and "Exception ignored" not in err, err
        assert seconds < (8.0 if command == "dask" else 4.0), seconds  # the fits are not waited for
        _assert_all_gone(procs, within=20.0 if command == "dask" else 5.0)
        assert _leftovers(tmp_path) == []


@contextlib.contextmanager
def _signalled(command, tmp_path, sig, delay, group=False):
    """Start ``rbgp COMMAND``, wait until 2 workers run, wait ``delay`` s, send ``sig`` (to the
    process group with ``group``); yields (run, the workers, exit code, seconds to exit). Cleans up
    whatever is left."""
    if command == "dask":
        pytest.importorskip("distributed")
    run = Run(_args(command, tmp_path), tmp_path)
    procs = []
    try:
        run.wait_for_workers(2)
        time.sleep(delay)
        procs = run.workers()
        run.signal(sig, group=group)
        code, seconds = run.wait(15)
        yield run, procs, code, seconds
    finally:
        run.cleanup(procs)


def _signal_set(pid, field: str, sig) -> bool:
    """Signal ``sig`` is in that process's /proc status mask ``field`` (``SigCgt``: caught, ``SigIgn``: ignored)."""
    try:
        with open(f"/proc/{pid}/status") as fh:
            for line in fh:
                if line.startswith(field + ":"):
                    return bool(int(line.split()[1], 16) >> (sig - 1) & 1)
    except OSError:
        pass
    return False


def _handlers_installed(pid) -> bool:
    """rbgp's entry point has installed its handlers: SIGTERM is caught (Python does not catch it)."""
    return _signal_set(pid, "SigCgt", signal.SIGTERM)


def _sigint_ignored(pid) -> bool:
    """SIGINT is ignored in that process now: :class:`rbgp_cli.compute.start_workers` ignores it while a pool starts
    its processes (so that they inherit the ignoring), and a Ctrl-C then is lost, as documented there."""
    return _signal_set(pid, "SigIgn", signal.SIGINT)


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="reads /proc")
@pytest.mark.parametrize("after", [0.0, 0.3, 0.6])
def test_ctrl_c_early_is_one_line_and_exit_130(tmp_path, after):
    """SIGINT while the command line is still importing or parsing, from the moment the entry point has
    its handlers (before the fix: a KeyboardInterrupt traceback in the first 0.1 s, later exit 130 and
    no message). Python's own start-up before that (site, ~20 ms) is out of reach."""
    run = Run(["train", CSV_DIR, "-o", tmp_path / "m.rbgp", "--max-points", "100", "--restarts", "1", "--jobs", "1"],
              tmp_path)
    try:
        # Python's own start-up (site) comes before any code of ours: wait for the entry point
        while not _handlers_installed(run.proc.pid):
            assert time.monotonic() - run.t0 < 10, "the entry point installed no signal handlers"
            assert run.proc.poll() is None, run.stderr()
            time.sleep(0.002)
        time.sleep(after)
        # not while a pool starts its workers (SIGINT ignored for them to inherit: such a Ctrl-C is lost by design;
        # under a loaded CI the 0.3 s case once landed there and the training ran to its end)
        while _sigint_ignored(run.proc.pid) and run.proc.poll() is None:
            time.sleep(0.001)
        assert run.proc.poll() is None, "the command ended before the signal: " + run.stderr()
        run.signal(signal.SIGINT)
        code, _ = run.wait(15)
        err = run.stderr()
        # 130; rarely (under pytest only, not reproduced outside it) the process ends by the SIGINT
        # itself after the message, which a shell also reports as 130
        assert code in (130, -signal.SIGINT), err
        assert "rbgp: interrupted" in err and "Traceback" not in err and "KeyboardInterrupt" not in err, err
        assert _leftovers(tmp_path) == []
    finally:
        run.cleanup()


def test_a_killed_writers_temporary_file_is_removed_by_the_next_write(tmp_path):
    """A SIGKILL inside the write window left ``.m.rbgp.XXXX.rbgp.tmp`` for good; the next write of the
    same file removes it (its writer's pid is dead, or, without a pid in the name, it is old), and leaves
    a live writer's file alone."""
    target = tmp_path / "m.rbgp"
    code = ("import sys, time\nfrom rbgp_cli.io.atomic import atomic_open\n"
            f"with atomic_open({str(target)!r}, 'wb') as fh:\n"
            "    fh.write(b'partial'); fh.flush(); print('writing', flush=True); time.sleep(60)\n")
    writer = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, env=ENV)
    try:
        assert writer.stdout.readline() == b"writing\n"
        killed = _leftovers(tmp_path)
        assert len(killed) == 1 and killed[0].startswith(".m.rbgp.")
        writer.kill()
        writer.wait(10)
    finally:
        if writer.poll() is None:
            writer.kill()
    old = tmp_path / ".m.rbgp.k3j_x9qa.rbgp.tmp"  # an older rbgp's name: no pid
    old.write_bytes(b"")
    os.utime(old, (time.time() - 3600, time.time() - 3600))
    live = tmp_path / f".m.rbgp.{os.getpid()}-abcd1234.rbgp.tmp"  # a writer that is still running
    live.write_bytes(b"")
    other = tmp_path / ".other.rbgp.k3j_x9qa.rbgp.tmp"  # another file's
    other.write_bytes(b"")
    os.utime(other, (time.time() - 3600, time.time() - 3600))
    res = runner.invoke(app, ["train", str(CSV_DIR), "-o", str(target), "--max-points", "60", "--restarts", "1",
                              "--share-hyperparameters", "--jobs", "1", "-q"], catch_exceptions=False)
    assert res.exit_code == 0, res.stderr
    assert _leftovers(tmp_path) == sorted([live.name, other.name])
    assert target.read_bytes()[:7] != b"partial"


@pytest.mark.slow
def test_quiet_train_prints_nothing_on_stderr_json_still_prints_the_summary(tmp_path):
    """-q: the 11-line training summary is information, not a warning (before: printed anyway)."""
    args = ["train", str(CSV_DIR), "-o", str(tmp_path / "m.rbgp"), "--max-points", "60", "--restarts", "1",
            "--share-hyperparameters", "--jobs", "1"]
    res = runner.invoke(app, [*args, "-q"], catch_exceptions=False)
    assert res.exit_code == 0 and res.stderr == "" and res.stdout == "", res.stderr
    res = runner.invoke(app, ["-q", *args, "--json"], catch_exceptions=False)
    assert res.exit_code == 0 and res.stderr == "", res.stderr
    assert '"points": 60' in res.stdout


@pytest.mark.slow
@needs_cores
def test_a_dask_study_whose_workers_keep_dying_fails_with_one_line_naming_the_fold(tmp_path):
    """Every Dask worker killed as soon as it runs a fit: one retry of the fold, then one error line
    naming it (exit 1) within a bounded time, no Dask log lines or tracebacks, no process left."""
    pytest.importorskip("distributed")
    run = Run([*CROSSVAL, "--scheduler", "local"], tmp_path)
    killed, procs = set(), []
    try:
        while " fold " not in run.stderr() and time.monotonic() - run.t0 < 60:  # the cluster runs fits
            assert run.proc.poll() is None, run.stderr()
            time.sleep(0.1)
        while run.proc.poll() is None and time.monotonic() - run.t0 < 90:
            for p in run.workers():
                if "resource_tracker" in " ".join(_cmdline(p)):
                    continue
                procs.append(p)
                try:
                    # up (connected to the scheduler: killing a worker that is still starting ends
                    # its nanny for good), and given a fit
                    if p.pid not in killed and time.time() - p.create_time() > 1.5 and _connected(p):
                        p.kill()
                        killed.add(p.pid)
                except psutil.Error:
                    pass
            time.sleep(0.1)
        code, _ = run.wait(5)
        err = run.stderr()
        assert code == 1, err
        last = err.strip().splitlines()[-1]
        assert last.startswith("rbgp: error: ") and " fold " in last, err
        # the fold lost twice, or (when no worker came back) the timeout
        assert "was lost with its Dask worker" in last or "no Dask worker left for" in last, err
        assert "Traceback" not in err and "distributed." not in err and "CommClosedError" not in err, err
        assert all(ln.startswith("rbgp: ") for ln in err.strip().splitlines()), err
        _assert_all_gone(procs)
    finally:
        run.cleanup(procs)


def test_a_failure_that_ctrl_c_caused_is_reported_as_the_interruption(capsys):
    """Ctrl-C inside a C extension's import comes out of the import as "ImportError: initialization
    failed" (seen when the SIGINT met scipy.special's first import at the end of training): reported
    as the interruption (exit 130), not as an internal error; without a Ctrl-C it stays one; and where a
    library swallows it and the command runs to its end, it is still the interruption."""
    import typer

    from rbgp_cli.cli.common import command

    @command
    def interrupted_import():
        try:
            os.kill(os.getpid(), signal.SIGINT)  # the command's handler raises KeyboardInterrupt here
            time.sleep(5)
        except KeyboardInterrupt:
            raise ImportError("initialization failed") from None

    @command
    def broken():
        raise ImportError("initialization failed")

    @command
    def swallowed():  # a library's optional import: except ImportError, and carry on
        try:
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(5)
        except (KeyboardInterrupt, ImportError):
            pass
        return 0

    with pytest.raises(typer.Exit) as exc:  # the command ran to its end, but Ctrl-C was pressed: not exit 0 (a CI
        swallowed()  # run once saw `train` finish after a SIGINT at 0.3 s, test_ctrl_c_early_is_one_line_and_exit_130)
    assert exc.value.exit_code == 130 and "rbgp: interrupted" in capsys.readouterr().err

    with pytest.raises(typer.Exit) as exc:
        interrupted_import()
    assert exc.value.exit_code == 130 and "rbgp: interrupted" in capsys.readouterr().err
    with pytest.raises(typer.Exit) as exc:
        broken()
    err = capsys.readouterr().err
    assert exc.value.exit_code == 1 and "internal error: ImportError" in err and "interrupted" not in err


_ENDS_WITH_A_THREAD_RUNNING = """
import atexit, sys, threading, time
from rbgp_cli.cli import app as cli_app
from rbgp_cli.cli import end_signalled_run

atexit.register(lambda: print("exit functions ran", file=sys.stderr))
threading.Thread(target=time.sleep, args=(60,)).start()  # not a daemon: Python's own teardown would wait for it
sys.stdout.write("unflushed line")
if sys.argv[1] == "end":
    end_signalled_run(130)
cli_app.app = lambda: sys.exit(int(sys.argv[1]))  # a command that ended with this code
cli_app.main()
"""


@pytest.mark.parametrize("code", ["end", "130", "143"])
def test_a_signalled_run_ends_at_once_with_its_code_after_the_exit_functions(code):
    """A run that Ctrl-C (130) or SIGTERM (143) ended skips the C-level teardown, where native thread pools
    still running can abort the process (CI once: ``terminate called without an active exception``, exit
    −6 after ``rbgp: interrupted``). Its exit functions still run and its streams are flushed; a thread
    still running does not hold it (the normal teardown waits for it: that case takes the 60 s)."""
    t0 = time.monotonic()
    run = subprocess.run([sys.executable, "-c", _ENDS_WITH_A_THREAD_RUNNING, code], capture_output=True, text=True,
                         env=ENV, timeout=50)
    assert run.returncode == (130 if code == "end" else int(code)), run.stderr
    assert run.stdout == "unflushed line" and "exit functions ran" in run.stderr, run.stderr
    assert time.monotonic() - t0 < 30


def test_a_run_that_ended_otherwise_keeps_the_normal_teardown():
    """Exit codes other than a signal's go through Python's normal exit (which waits for the thread)."""
    script = _ENDS_WITH_A_THREAD_RUNNING.replace("args=(60,)", "args=(1.5,)")
    t0 = time.monotonic()
    run = subprocess.run([sys.executable, "-c", script, "2"], capture_output=True, text=True, env=ENV, timeout=50)
    assert run.returncode == 2 and "exit functions ran" in run.stderr, run.stderr
    assert time.monotonic() - t0 >= 1.5
