"""Progress: bars on a terminal (a real pseudo-terminal), sparse lines in a pipe, nothing with -q,
and the library's reports (training: outputs × evaluations; rollout: steps) through one interface."""

from __future__ import annotations

import io
import os
import select
import subprocess
import sys
import time

import pytest

from rbgp_cli.cli.progress import BarProgress, LineProgress, format_duration, make_progress
from rbgp_cli.progress import Progress, Task, as_progress
from tests.cli.common import CSV_DIR, run

FAST = ["--max-points", "100", "--restarts", "1", "--share-hyperparameters"]


@pytest.fixture(scope="module")
def model(tmp_path_factory):
    path = tmp_path_factory.mktemp("progress") / "m.rbgp"
    res = run("-q", "train", CSV_DIR, "-o", path, *FAST)
    assert res.exit_code == 0, res.stderr
    return path


class Clock:
    def __init__(self):
        self.now = 100.0

    def __call__(self):
        return self.now


class Recorder(Progress):
    """Records what the library reports."""

    def __init__(self):
        self.messages, self.tasks = [], []

    def message(self, text):
        self.messages.append(text)

    def task(self, description, *, total=None, unit=""):
        rec = {"description": description, "total": total, "unit": unit, "advanced": 0.0, "statuses": [],
               "closed": None}
        self.tasks.append(rec)

        class T(Task):
            def advance(self, amount=1.0):
                rec["advanced"] += amount

            def update(self, *, completed=None, total=None, status=None):
                if status is not None:
                    rec["statuses"].append(status)

            def close(self, ok=True):
                rec["closed"] = ok

        return T()


# ---------------------------------------------------------------------------------------------- lines
def test_lines_are_sparse_a_short_task_prints_only_its_closing_line():
    out, clock = io.StringIO(), Clock()
    p = LineProgress(out, interval=10.0, clock=clock)
    with p.task("rollout", total=390, unit="steps") as t:
        for _ in range(390):
            t.advance()
            clock.now += 0.001
    assert out.getvalue() == "rbgp: rollout: 390/390 steps in 0.4 s\n"


def test_lines_report_every_interval_with_elapsed_and_remaining_time():
    out, clock = io.StringIO(), Clock()
    p = LineProgress(out, interval=10.0, clock=clock)
    with p.task("training", total=6, unit="outputs") as t:
        for k in range(6):
            for e in range(40):
                clock.now += 0.25  # one output: 40 evaluations, 10 s
                t.update(status=f"output {k}: {e + 1} evaluations")
            t.advance()
    lines = out.getvalue().splitlines()
    # a line every 10 s (6 outputs × 10 s = 60 s) plus the closing line
    assert len(lines) == 7, lines
    assert lines[0] == "rbgp: training: 0/6 outputs (output 0: 40 evaluations), 10 s elapsed"
    assert lines[2] == "rbgp: training: 2/6 outputs (output 2: 40 evaluations), 30 s elapsed, about 1:00 min left"
    assert lines[-1] == "rbgp: training: 6/6 outputs in 1:00 min"


def test_nested_and_failed_tasks_add_no_closing_lines():
    out, clock = io.StringIO(), Clock()
    p = LineProgress(out, interval=10.0, clock=clock)
    with p.task("cross-validation", total=2, unit="folds") as folds:
        for _ in range(2):
            with p.task("training", total=6, unit="outputs") as t:
                t.advance(6)
            folds.advance()
    assert out.getvalue() == "rbgp: cross-validation: 2/2 folds in 0.0 s\n"
    out.truncate(0), out.seek(0)
    with pytest.raises(RuntimeError):
        with p.task("rollout", total=10, unit="steps"):
            raise RuntimeError("diverged")
    assert out.getvalue() == ""


def test_durations_read_naturally():
    assert [format_duration(s) for s in (0.04, 4.25, 37.4, 125, 3725)] == ["0.0 s", "4.2 s", "37 s", "2:05 min",
                                                                           "1:02:05 h"]


# ---------------------------------------------------------------------------------------------- choice
class FakeTerminal(io.StringIO):
    def isatty(self):
        return True


def test_make_progress_bars_on_a_terminal_lines_elsewhere_nothing_when_quiet(monkeypatch):
    monkeypatch.setenv("TERM", "xterm-256color")
    assert isinstance(make_progress(stream=FakeTerminal()), BarProgress)
    assert isinstance(make_progress(stream=io.StringIO()), LineProgress)
    assert type(make_progress(quiet=True, stream=FakeTerminal())) is Progress
    monkeypatch.setenv("TERM", "dumb")
    assert isinstance(make_progress(stream=FakeTerminal()), LineProgress)


def test_bars_draw_units_and_times_and_nested_bars_go_away():
    term = FakeTerminal()
    p = BarProgress(term, refresh_per_second=50)
    with p.task("training", total=6, unit="outputs") as t:
        t.update(status="output 2: 17 evaluations")
        t.advance(2)
        with p.task("rollout", total=10, unit="steps") as inner:
            inner.advance(10)
        assert len(p._rich.tasks) == 1  # the nested bar is gone once its task ended
        p.message("hello above the bar")
        time.sleep(0.1)
        t.advance(4)
    text = term.getvalue()
    assert "━" in text and "6/6" in text and "outputs" in text and "output 2: 17 evaluations" in text
    assert "rbgp: hello above the bar" in text
    assert "0:00:0" in text  # elapsed time
    assert p._rich is None  # stopped when the last task ended


# ---------------------------------------------------------------------------------------------- library
@pytest.mark.slow
def test_training_reports_outputs_times_evaluations(model):
    from rbgp_cli.dynamics.model import train_model
    from rbgp_cli.workflows import load_demonstrations

    trajs, _, _ = load_demonstrations([str(f) for f in sorted(CSV_DIR.glob("*.csv"))[:3]])
    rec = Recorder()
    m = train_model(trajs, max_points=80, restarts=2, progress=rec)
    (task,) = [t for t in rec.tasks if t["description"] == "training"]
    assert task["total"] == 6 and task["unit"] == "outputs" and task["advanced"] == 6 and task["closed"] is True
    # the status counts every evaluation of the output being fitted
    last = {}
    for s in task["statuses"]:
        label, count = s.rsplit(": ", 1)
        last[label] = int(count.split()[0])
    assert sorted(last) == [f"output {k}" for k in range(6)]
    assert [last[f"output {k}"] for k in range(6)] == [f.n_evaluations for f in m.gp.fits]
    assert any("NLML" in msg for msg in rec.messages)


def test_rollout_reports_its_steps(model):
    from rbgp_cli.io.model_store import load_model
    from rbgp_cli.workflows import rollout_model

    m, _ = load_model(model)
    rec = Recorder()
    rollout_model(m, m.starts[:2, :4], m.starts[:2, 4:], steps=37, with_std=False, progress=rec)
    (task,) = rec.tasks
    assert (task["description"], task["total"], task["unit"], task["advanced"]) == ("rollout", 37, "steps", 37)
    assert task["statuses"] == ["2 trajectories"] and task["closed"] is True


@pytest.mark.slow
def test_the_demo_is_one_task_around_each_representations_training_and_rollout(tmp_path):
    """The pattern a cross-validation follows: one outer task whose units are folds (here:
    representations), with the training and rollout tasks of each nested inside it."""
    from rbgp_cli.demo import run_demo

    rec = Recorder()
    run_demo(tmp_path / "d", count=3, representations=["axis-angle", "euler"], quick=True, progress=rec)
    descs = [t["description"] for t in rec.tasks]
    # the gain chosen from a cheap fit first (dynamics/model.py) adds a training task before the full fit's
    # where it leaves the gain open: consecutive training tasks are one training here
    descs = [d for k, d in enumerate(descs) if not (k and d == "training" == descs[k - 1])]
    assert descs == ["demo", "training", "rollout", "training", "rollout"]
    outer = rec.tasks[0]
    assert (outer["total"], outer["unit"], outer["advanced"], outer["closed"]) == (2, "representations", 2, True)
    assert outer["statuses"] == ["axis-angle", "euler"]
    out = io.StringIO()
    run_demo(tmp_path / "e", count=3, representations=["axis-angle"], quick=True,
             progress=LineProgress(out, interval=1e9))
    lines = out.getvalue().splitlines()
    assert lines[-1].startswith("rbgp: demo: 1/1 representations in ")
    assert not [ln for ln in lines if ln.startswith(("rbgp: training:", "rbgp: rollout:"))]  # nested: no lines


def test_a_plain_callable_still_receives_the_messages():
    got = []
    p = as_progress(got.append)
    p("one")
    with p.task("x", total=3) as t:
        t.advance()
    assert got == ["one"]
    with pytest.raises(TypeError):
        as_progress(42)


# ---------------------------------------------------------------------------------------------- end to end
@pytest.mark.slow
def test_in_a_pipe_the_rollout_prints_one_line_not_one_per_100_steps(model):
    res = run("rollout", model, "--steps", 450, "--count", 2, "--no-std", "-o", "-")
    assert res.exit_code == 0, res.stderr
    lines = res.stderr.splitlines()
    assert [ln for ln in lines if "step" in ln] == [lines[-1]]
    assert lines[-1].startswith("rbgp: rollout: 450/450 steps in ")
    res = run("rollout", model, "--steps", 450, "--count", 2, "--no-std", "-o", "-", "-q")
    assert res.exit_code == 0 and res.stderr == ""


def _run_on_a_terminal(args, timeout=240):
    """Run ``python -m rbgp_cli ARGS`` with stderr on a pseudo-terminal and stdout to a file; returns
    (exit code, stdout, what the terminal received)."""
    import tempfile

    pty = pytest.importorskip("pty")
    master, slave = pty.openpty()
    env = dict(os.environ, TERM="xterm-256color", COLUMNS="120")
    stdout = tempfile.TemporaryFile()  # a file, not a pipe: a full pipe would block the child
    proc = subprocess.Popen([sys.executable, "-m", "rbgp_cli", *map(str, args)], stdout=stdout,
                            stderr=slave, stdin=subprocess.DEVNULL, env=env)
    os.close(slave)
    chunks, deadline = [], time.monotonic() + timeout
    while time.monotonic() < deadline:
        ready, _, _ = select.select([master], [], [], 0.2)
        if ready:
            try:
                data = os.read(master, 65536)
            except OSError:  # the child closed the terminal
                break
            if not data:
                break
            chunks.append(data)
        elif proc.poll() is not None:
            break
    proc.wait(timeout=60)
    os.close(master)
    stdout.seek(0)
    out = stdout.read()
    stdout.close()
    return proc.returncode, out.decode(), b"".join(chunks).decode(errors="replace")


@pytest.mark.slow
def test_on_a_terminal_a_progress_bar_with_times_and_stdout_stays_data(model):
    code, out, term = _run_on_a_terminal(["rollout", model, "--steps", 400, "--count", 3, "--no-std", "--output-rate", 0, "-o", "-"])
    assert code == 0, term
    assert "━" in term and "400/400" in term and "steps" in term and "3 trajectories" in term
    assert "0:00:0" in term  # elapsed / remaining
    assert "step 100/400" not in term
    assert out.startswith("#") and "\x1b" not in out and out.count("\n") == 2 + 3 * 401
    code, out, term = _run_on_a_terminal(["rollout", model, "--steps", 400, "--count", 3, "--no-std", "-q", "--output-rate", 0, "-o", "-"])
    assert code == 0 and term.strip() == "" and out.count("\n") == 2 + 3 * 401


@pytest.mark.slow
def test_on_a_terminal_training_shows_outputs(tmp_path):
    code, _, term = _run_on_a_terminal(["train", CSV_DIR, "-o", tmp_path / "m.rbgp", "--max-points", "100",
                                        "--restarts", "1"])
    assert code == 0, term
    assert "6/6" in term and "outputs" in term and "evaluations" in term and "━" in term
    assert "safeguards:" in term  # the summary follows the bar


@pytest.mark.slow
def test_an_error_stops_the_bar_before_the_error_line(tmp_path):
    bad = tmp_path / "bad.rbgp"
    bad.write_bytes(b"nope")
    code, _, term = _run_on_a_terminal(["rollout", bad, "--steps", 5])
    assert code == 2 and "rbgp: error:" in term and "Traceback" not in term

