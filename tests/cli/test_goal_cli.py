"""``rbgp rollout --goal/--goals/--via/--goal-tolerance`` and ``rbgp crossval --given goal`` (issue 38):
the motion ends at the goal and passes the via-points, bad poses are one-line errors, far goals warn."""

from __future__ import annotations

import json

import numpy as np
import pytest

from rbgp_cli.io.read import read_demonstrations
from rbgp_cli.io.options import ReadOptions
from tests.cli.common import CSV_DIR, run
from tests.cli.test_cli import FAST, assert_one_line_error


def demo_ends():
    """The first sample demonstration's start, middle and final poses as "qx qy qz qw x y z" texts, and it."""
    tr = read_demonstrations([str(sorted(CSV_DIR.glob("*.csv"))[0])], ReadOptions())[0]

    def text(k):
        return " ".join(f"{v:.9g}" for v in np.concatenate([tr.quat[k], tr.position[k]]))

    return text(0), text(len(tr) // 2), text(-1), tr


def read_rollout(path):
    """{name: Trajectory} of a rollout CSV (the reader names them FILE#NAME)."""
    return {t.name.split("#")[-1]: t for t in read_demonstrations([str(path)], ReadOptions())}


def angle(q1, q2):
    return 2.0 * np.arccos(min(1.0, abs(float(np.dot(q1, q2)))))


@pytest.mark.slow
def test_the_mean_ends_at_the_goal_and_passes_the_via_point(model, tmp_path):
    start, middle, goal, tr = demo_ends()
    t_via = round(0.5 * tr.duration, 3)
    k = int(np.argmin(np.abs(tr.t - tr.t[0] - t_via)))
    via = " ".join(f"{v:.9g}" for v in np.concatenate([tr.quat[k], tr.position[k]]))
    out = tmp_path / "to_goal.csv"
    res = run("rollout", model, "--start-quat", start, "--goal", goal, "--via", f"{t_via}: {via}",
              "--duration", f"{tr.duration:.6f}", "--samples", "5", "--no-std", "-o", out, "--json")
    assert res.exit_code == 0, res.stderr
    summary = json.loads(res.stdout)
    assert summary["goal_distance"][0] < 4.5  # the demonstration's own goal is not an extrapolation
    assert "standard deviations" not in res.stderr
    trajs = read_rollout(out)
    mean = trajs["0"]
    assert np.linalg.norm(mean.position[-1] - tr.position[-1]) < 0.005
    assert angle(mean.quat[-1], tr.quat[-1]) < 0.01
    j = int(np.argmin(np.abs(mean.t - t_via)))
    assert abs(mean.t[j] - t_via) < 0.01  # a written sample at the via-point's time (179 Hz)
    assert np.linalg.norm(mean.position[j] - tr.position[k]) < 0.005
    assert angle(mean.quat[j], tr.quat[k]) < 0.01
    # the samples pinch at the goal and the via-point and spread between them
    ends = np.array([trajs[f"0.s{i}"].position[-1] for i in range(5)])
    mid = np.array([trajs[f"0.s{i}"].position[len(mean) // 4] for i in range(5)])
    assert np.max(np.linalg.norm(ends - tr.position[-1], axis=1)) < 0.005
    assert np.std(mid, axis=0).max() > 5 * np.std(ends, axis=0).max()


@pytest.mark.slow
def test_a_goal_far_from_where_the_demonstrations_end_is_warned_about(model, tmp_path):
    start, _, goal, tr = demo_ends()
    far = goal.split()[:4] + [f"{tr.position[-1][0] + 1.0:.6f}"] + goal.split()[5:]
    res = run("rollout", model, "--start-quat", start, "--goal", " ".join(far), "-o", tmp_path / "far.csv")
    assert res.exit_code == 0, res.stderr
    assert "standard deviations from where the demonstrations end: this motion is an extrapolation" in res.stderr
    assert "--goal" in res.stderr  # the hint names the flag
    mean = read_rollout(tmp_path / "far.csv")["0"]
    assert np.linalg.norm(mean.position[-1] - tr.position[-1] - [1.0, 0, 0]) < 0.005  # it still goes there


@pytest.mark.slow
def test_a_goal_so_far_that_its_duration_extrapolates_keeps_a_duration_like_the_demonstrations(model, tmp_path):
    """ln D given the start and goal is linear in the goal: 50 m off, it extrapolates to a motion of a few
    microseconds. The duration is kept within 2/3 of the shortest demonstration's and 1.5 of the longest's, with a
    warning; a duration given is taken as given."""
    from rbgp_cli.dynamics.anticipation import GRID_RANGE

    start, _, goal, tr = demo_ends()
    far = goal.split()[:4] + ["50", "50", "50"]
    res = run("rollout", model, "--start-quat", start, "--goal", " ".join(far), "--no-std", "-o", tmp_path / "far.csv")
    assert res.exit_code == 0, res.stderr
    assert "lies beyond theirs" in res.stderr and "it is kept within" in res.stderr, res.stderr
    durs = [t.duration for t in read_demonstrations([str(p) for p in sorted(CSV_DIR.glob("*.csv"))], ReadOptions())]
    mean = read_rollout(tmp_path / "far.csv")["0"]
    assert GRID_RANGE[0] * min(durs) - 0.02 <= mean.duration <= GRID_RANGE[1] * max(durs) + 0.02
    res = run("rollout", model, "--start-quat", start, "--goal", " ".join(far), "--duration", "0.5", "--no-std",
              "-o", tmp_path / "given.csv")
    assert res.exit_code == 0 and "it is kept within" not in res.stderr, res.stderr
    assert abs(read_rollout(tmp_path / "given.csv")["0"].duration - 0.5) < 0.02


def test_a_goal_beyond_the_demonstrations_gets_their_pace_over_the_longer_way(model):
    """A goal moved away from where a demonstration ends, 5 cm at a time: within FAR_GOAL spreads the default duration
    is the conditional one given the start and goal; beyond, the one at the goal moved back to FAR_GOAL spreads times
    (L + the extra way) / L, so that it is continuous there and grows as the goal goes farther (before, ln D
    extrapolated linearly and a hand raise's far goal got a motion shorter than every demonstration's)."""
    from rbgp_cli.dynamics.paths import FAR_GOAL
    from rbgp_cli.dynamics.rollout import _goal_durations
    from rbgp_cli.io.model_store import load_model

    paths = load_model(model)[0].paths
    tr = demo_ends()[3]
    q0, p0 = tr.quat[:1], tr.position[:1]
    way = tr.position[-1] - tr.position[0]
    ks = np.arange(0, 61)
    gp = tr.position[-1] + 0.05 * ks[:, None] * way / np.linalg.norm(way)
    gq = np.repeat(tr.quat[-1:], len(ks), axis=0)
    qs, ps = np.repeat(q0, len(ks), axis=0), np.repeat(p0, len(ks), axis=0)
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        dur = _goal_durations(paths, qs, ps, gq, gp, None, ())
    dist = paths.goal_distance(qs, ps, gq, gp)
    beyond = dist > FAR_GOAL
    assert beyond.any() and not beyond.all(), dist
    inside = [paths.condition(*paths.stack(paths.observe([0.0], q0, p0, exact=True),
                                           paths.observe([1.0], gq[k:k + 1], gp[k:k + 1], exact=True))).duration
              for k in np.flatnonzero(~beyond)]
    np.testing.assert_allclose(dur[~beyond], inside, rtol=1e-9)
    d = np.diff(dur)
    assert np.all(np.abs(d) < 0.1 * dur[:-1]), dur  # no jump where the rule changes
    from rbgp_cli.dynamics.anticipation import GRID_RANGE

    hi = GRID_RANGE[1] * np.exp(paths.log_durations.max())  # then kept there, with a warning
    free = beyond[1:] & beyond[:-1] & (dur[1:] < hi - 1e-9)
    assert free.sum() >= 5 and np.all(d[free] > 0), dur  # farther beyond: longer
    demos = [t.duration for t in read_demonstrations([str(p) for p in sorted(CSV_DIR.glob("*.csv"))], ReadOptions())]
    assert dur[-1] > np.median(demos), (dur[-1], demos)


@pytest.mark.slow
def test_goals_file_one_per_start_in_the_order_of_the_starts(model, tmp_path):
    start, _, goal, tr = demo_ends()
    goals = tmp_path / "goals.csv"
    g = np.concatenate([tr.quat[-1], tr.position[-1]])
    rows = [g, g + np.array([0, 0, 0, 0, 0.02, 0, 0])]
    goals.write_text("qx,qy,qz,qw,x,y,z\n" + "\n".join(",".join(f"{v:.9g}" for v in r) for r in rows) + "\n")
    out = tmp_path / "two.csv"
    res = run("rollout", model, "--start-quat", start, "--start-quat", start, "--goals", goals, "--no-std", "-o", out)
    assert res.exit_code == 0, res.stderr
    trajs = read_rollout(out)
    for b in range(2):
        assert np.linalg.norm(trajs[str(b)].position[-1] - rows[b][4:]) < 0.005
    res = run("rollout", model, "--start-quat", start, "--goals", goals, "-o", tmp_path / "x.csv")
    assert_one_line_error(res, 2, "2 poses for 1 starts", "--goals")
    assert not (tmp_path / "x.csv").exists()


@pytest.mark.slow
def test_a_softer_goal_ends_near_it_not_at_it(model, tmp_path):
    start, _, goal, tr = demo_ends()
    off = np.concatenate([tr.quat[-1], tr.position[-1] + [0.05, 0.0, 0.0]])
    out = tmp_path / "soft.csv"
    res = run("rollout", model, "--start-quat", start, "--goal", " ".join(f"{v:.9g}" for v in off),
              "--goal-tolerance", "0.5 0.5", "--no-std", "-o", out)
    assert res.exit_code == 0, res.stderr
    end = read_rollout(out)["0"].position[-1]
    # a tolerance of 0.5 m is loose: the motion ends between where the demonstrations would and the goal
    assert 0.002 < np.linalg.norm(end - off[4:]) < 0.05


@pytest.mark.parametrize("args,fragments", [
    (["--goal", "1 2 3"], ["goal pose", "seven finite numbers", "qx qy qz qw x y z"]),
    (["--goal", "a b c d e f g"], ["goal pose", "not seven numbers"]),
    (["--goal", "0 0 0 0 1 2 3"], ["zero quaternion"]),
    (["--goal", ""], ["goal pose ''", "seven finite numbers"]),  # an empty goal is not no goal
    (["--via", "0 0 0 1 0 0 0"], ["via-point", "no time before a colon", "T: qx qy qz qw x y z"]),
    (["--via", "x: 0 0 0 1 0 0 0"], ["via-point", "not a number of seconds"]),
    (["--via", "-1: 0 0 0 1 0 0 0"], ["positive number of seconds"]),
    (["--via", "1: 0 0 0 1 0 0"], ["via-point", "seven finite numbers"]),
    (["--goal", "0 0 0 1 0 0 0", "--goal-tolerance", "0.1"], ["two positive numbers"]),
    (["--goal", "0 0 0 1 0 0 0", "--goal-tolerance", "1e200 1e200"], ["two positive numbers (up to 1e+100)"]),  # var. overflows
    (["--goal-tolerance", "0.1 0.1"], ["--goal-tolerance softens", "--goal POSE"]),
    (["--goal", "0 0 0 1 0 0 0", "--steps", "5"], ["--duration"]),
    (["--goal", "0 0 0 1 0 0 0", "--via", "100: 0 0 0 1 0 0 0", "--duration", "2"], ["via-point at 100 s", "outside the motion"]),
])
def test_bad_goal_and_via_text_is_a_one_line_error(model, tmp_path, args, fragments):
    out = tmp_path / "r.csv"
    assert_one_line_error(run("rollout", model, "--start-quat", demo_ends()[0], *args, "-o", out), 2, *fragments)
    assert not out.exists()


@pytest.mark.parametrize("args", [["--goal", "1 2 3"], ["--via", "1 2 3"], ["--goal", "0 0 0 1 0 0 0", "--goal-tolerance", "a"]])
def test_a_bad_goal_without_a_start_is_the_only_line_on_stderr(model, tmp_path, args):
    """Without a start the rollout says which starts it drew; a mistyped goal stops it before that."""
    out = tmp_path / "r.csv"
    assert_one_line_error(run("rollout", model, *args, "-o", out), 2, "write it as")
    assert not out.exists()


def test_crossval_given_must_be_goal():
    assert_one_line_error(run("crossval", CSV_DIR, "--given", "middle"), 2, "--given takes goal or a seen fraction F")


@pytest.mark.slow
def test_crossval_given_goal_rows_and_end_errors(tmp_path):
    res = run("crossval", CSV_DIR, "--given", "goal", "--folds", "3", "--samples", "5", "--jobs", "1", "--no-peers",
              *FAST, "--json")
    assert res.exit_code == 0, res.stderr
    out = json.loads(res.stdout)
    assert out["given"] == "goal"
    rows = {(r["representation"], bool(r.get("without_gp"))): r for r in out["results"]}
    assert set(rows) == {("nearest", False), ("axis-angle", False), ("axis-angle", True)}
    for key in (("axis-angle", False), ("axis-angle", True)):
        r = rows[key]
        assert r["end_position"] < 0.005 and r["end_rotation"] < 0.01  # the 5 mm / 0.01 rad
        assert 0.5 < r["coverage_position"] <= 1.0 and r["position_rmse"] < 0.2
    assert rows[("nearest", False)]["end_position"] < 1e-6  # its offsets are blended in exactly
    table = run("crossval", CSV_DIR, "--given", "goal", "--folds", "3", "--samples", "0", "--jobs", "1", "--no-peers",
                "--no-without-gp", *FAST)
    assert table.exit_code == 0, table.stderr
    header = next(line for line in table.stdout.splitlines() if line.startswith("representation"))
    assert header.split()[-2:] == ["end_mm", "end_mrad"]


@pytest.mark.slow
def test_a_via_point_far_from_where_the_demonstrations_pass_is_warned_about_and_plotted(model, tmp_path):
    pytest.importorskip("matplotlib")
    start, _, goal, tr = demo_ends()
    t_via = round(0.5 * tr.duration, 3)
    k = int(np.argmin(np.abs(tr.t - tr.t[0] - t_via)))
    near = np.concatenate([tr.quat[k], tr.position[k]])
    far = near + np.array([0, 0, 0, 0, 0.0, 0.0, 1.0])  # a metre above the demonstration's own pose
    text = lambda v: " ".join(f"{x:.9g}" for x in v)  # noqa: E731
    res = run("rollout", model, "--start-quat", start, "--goal", goal, "--via", f"{t_via}: {text(near)}",
              "--duration", f"{tr.duration:.6f}", "-o", tmp_path / "near.csv")
    assert res.exit_code == 0, res.stderr
    assert "standard deviations" not in res.stderr  # the demonstration's own pose is not an extrapolation
    png = tmp_path / "far.png"
    res = run("rollout", model, "--start-quat", start, "--goal", goal, "--via", f"{t_via}: {text(far)}",
              "--duration", f"{tr.duration:.6f}", "--samples", "4", "-o", tmp_path / "far.csv", "--plot", png)
    assert res.exit_code == 0, res.stderr
    assert f"the via-point at {t_via:g} s is" in res.stderr
    assert "standard deviations from where the demonstrations pass at that time: this motion is an extrapolation" in res.stderr
    assert "--via" in res.stderr  # the hint names the flag
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000


def test_plot_is_refused_with_given(model, tmp_path):
    out = tmp_path / "r.png"
    res = run("rollout", model, "--given", CSV_DIR / "shoe_01.csv", "--plot", out)
    assert_one_line_error(res, 2, "--given writes CSV", "--plot")
    assert not out.exists()
