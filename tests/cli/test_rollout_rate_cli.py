"""Rollouts at the recording rate, per-start durations and quaternion starts (issue 22, point 7)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from rbgp_cli.io.options import ReadOptions
from rbgp_cli.io.read import read_demonstrations
from tests.cli.test_cli import CSV_DIR, assert_one_line_error, run

START = "0.1 0.2 0.3 0.3 0.0 1.1"


def _table(path):
    """(header names, values) of a rollout CSV: the units comment, a header, one row per sample."""
    lines = path.read_text().splitlines()
    assert lines[0].startswith("#")
    names = lines[1].split(",")
    rows = [ln.split(",") for ln in lines[2:]]
    return names, [r[0].strip('"') for r in rows], np.array([[float(v) for v in r[1:]] for r in rows])


def _recorded_rate():
    demos = read_demonstrations([str(CSV_DIR)], ReadOptions())
    return 1.0 / float(np.median(np.concatenate([np.diff(d.t) for d in demos])))


def test_the_model_stores_the_recorded_rate(model):
    res = run("info", model, "--json")
    assert res.exit_code == 0
    h = json.loads(res.stdout)
    assert h["dt"] == pytest.approx(0.1)  # trained on the 10 Hz grid
    assert h["summary"]["recorded_rate_hz"] == pytest.approx(_recorded_rate(), rel=1e-12)
    assert 170 < h["summary"]["recorded_rate_hz"] < 190


def test_rollout_is_written_at_the_recorded_rate_by_default(model, tmp_path):
    out = tmp_path / "gen.csv"
    res = run("rollout", model, "--start", START, "--duration", 2.0, "-o", out, "--json")
    assert res.exit_code == 0, res.stderr
    meta = json.loads(res.stdout)
    rate = _recorded_rate()
    # integrated on the recorded interval, but at most 10 steps per 0.1 s training step (180 Hz data)
    assert meta["steps"] == 200 and meta["dt"] == pytest.approx(0.01) and meta["output_rate_hz"] == pytest.approx(rate)
    names, traj, v = _table(out)
    assert names[:9] == ["trajectory", "t", "x", "y", "z", "qx", "qy", "qz", "qw"]
    assert names[9:] == [f"std_{n}" for n in ("wx", "wy", "wz", "vx", "vy", "vz")] + ["left_data"]
    n = int(np.floor(2.0 * rate + 1e-9)) + 1
    off = 2.0 - (n - 1) / rate > 1e-9  # the end, off the rate's grid, is written as the last row
    assert v.shape == (n + off, 15) and set(traj) == {"0"}
    np.testing.assert_allclose(v[:n, 0], np.arange(n) / rate, rtol=0, atol=1e-12)  # times on the rate
    assert v[-1, 0] == pytest.approx(2.0)
    assert np.all(np.isfinite(v)) and np.all(v[:, 8:14] > 0) and set(v[:, 14]) <= {0.0, 1.0}
    np.testing.assert_allclose(np.linalg.norm(v[:, 4:8], axis=1), 1.0, atol=1e-12)


def test_output_rate_resamples_between_the_integration_steps_and_keeps_them(model, tmp_path):
    """--output-rate 50 on the 10 Hz training step: every 5th row is the 10 Hz rollout's row (poses and
    stds unchanged: the model is integrated on its step either way); rows between are slerp/linear."""
    grid, fine = tmp_path / "grid.csv", tmp_path / "fine.csv"
    args = ["rollout", model, "--start", START, "--steps", 20, "--samples", 1]
    assert run(*args, "--output-rate", 0, "-o", grid).exit_code == 0
    res = run(*args, "--output-rate", 50, "-o", fine)
    assert res.exit_code == 0, res.stderr
    _, tg, g = _table(grid)
    _, tf, f = _table(fine)
    assert tg.count("0") == 21 and tf.count("0") == 101 and tf.count("0.s0") == 101  # samples resampled too
    g, f = g[np.array(tg) == "0"], f[np.array(tf) == "0"]
    np.testing.assert_allclose(g[:, 0], np.arange(21) * 0.1, atol=1e-12)
    np.testing.assert_allclose(f[:, 0], np.arange(101) / 50, atol=1e-12)
    np.testing.assert_allclose(f[::5], g, rtol=0, atol=1e-12)
    # between the steps: positions and stds linear, rotations on the geodesic (slerp at f = 0.4)
    np.testing.assert_allclose(f[2::5, 1:4], 0.6 * g[:-1, 1:4] + 0.4 * g[1:, 1:4], atol=1e-12)
    np.testing.assert_allclose(f[2::5, 8:14], 0.6 * g[:-1, 8:14] + 0.4 * g[1:, 8:14], atol=1e-12)
    from scipy.spatial.transform import Rotation, Slerp

    for k in (0, 7, 19):
        s = Slerp([0, 1], Rotation.from_quat(g[k:k + 2, 4:8]))(0.4)
        assert (s.inv() * Rotation.from_quat(f[5 * k + 2, 4:8])).magnitude() < 1e-10


def test_a_model_file_without_the_recorded_rate_keeps_the_training_grid(model, tmp_path):
    from rbgp_cli.io.model_store import load_model, save_model

    m, _ = load_model(model)
    m.summary.pop("recorded_rate_hz")  # as in a model file written before rbgp stored it
    old = tmp_path / "old.rbgp"
    save_model(m, old)
    res = run("rollout", old, "--start", START, "--steps", 5, "--no-std")
    assert res.exit_code == 0, res.stderr
    t = [float(ln.split(",")[1]) for ln in res.stdout.splitlines()[2:]]
    np.testing.assert_allclose(t, np.arange(6) * 0.1, atol=1e-12)


def test_each_duration_gives_each_start_its_demonstrations_duration(model, tmp_path):
    out = tmp_path / "each.csv"
    res = run("rollout", model, "--from-demos", CSV_DIR, "--count", 9, "--start-spread", 0, "--each-duration",
              "--start", START, "--duration", 1.0, "-o", out)
    assert res.exit_code == 0, res.stderr
    names, traj, v = _table(out)
    assert "std_vz" in names
    demos = read_demonstrations([str(CSV_DIR)], ReadOptions())
    rate = _recorded_rate()
    ids = list(dict.fromkeys(traj))
    assert ids == [str(b) for b in range(10)]
    ends = []
    for b in ids:  # one block of rows per trajectory, times on the rate, from 0 to its own end
        rows = v[np.array(traj) == b]
        assert np.all(np.isfinite(rows))
        n = len(rows)
        np.testing.assert_allclose(rows[:, 0], np.arange(n) / rate, atol=1e-12)
        ends.append(rows[-1, 0])
        if b == "0":  # the --start pose: --duration
            want = 1.0
        else:  # drawn near (here: at) a demonstration's start: that demonstration's duration
            (d,) = [d for d in demos if np.allclose(d.position[0], rows[0, 1:4], atol=1e-12)]
            want = round(d.duration / 0.01) * 0.01  # on the integration steps (0.01 s: 180 Hz, 10 per training step)
        assert want - 1 / rate < rows[-1, 0] <= want + 1e-9, (b, rows[-1, 0], want)
    assert len({round(e, 3) for e in ends}) > 3  # not one duration for all


def test_each_duration_needs_demonstrations():
    assert_one_line_error(run("rollout", "missing.rbgp", "--each-duration"), 2, "--from-demos")


@pytest.mark.parametrize("dt", ["0", "nan", "-0.01", "inf"])
@pytest.mark.parametrize("more", [[], ["--duration", "2"], ["--goal", "0 0 0 1 0.8 0.06 0.13"]])
def test_a_dt_that_is_not_a_positive_number_is_bad_input_not_an_internal_error(model, tmp_path, dt, more):
    res = run("rollout", model, "--dt", dt, *more, "-q", "-o", tmp_path / "r.csv")
    assert_one_line_error(res, 2, "--dt must be a positive number of seconds")
    assert not (tmp_path / "r.csv").exists()


@pytest.mark.parametrize("args,fragment", [(["--duration", "-1"], "--duration must be a positive"),
                                           (["--dt", "0"], "--dt must be a positive"),
                                           (["--off-data", "maybe"], "--off-data must be one of")])
def test_a_bad_rollout_option_without_a_start_is_the_only_line_on_stderr(model, tmp_path, args, fragment):
    """Without a start the rollout says which starts it drew; a bad option stops it before that."""
    assert_one_line_error(run("rollout", model, *args, "-o", tmp_path / "r.csv"), 2, fragment)


def test_an_infinite_start_spread_is_bad_input(model, tmp_path):
    res = run("rollout", model, "--start-spread", "inf", "--count", 2, "-o", tmp_path / "r.csv")
    assert_one_line_error(res, 2, "--start-spread must be a non-negative number of metres")


def test_a_rollout_that_diverges_at_once_points_at_the_start(model, tmp_path):
    res = run("rollout", model, "--start", "0 0 0 1e308 0 1", "--steps", 3, "-q", "-o", tmp_path / "r.csv")
    assert_one_line_error(res, 1, "diverged", "at step 1", "check the start poses (metres")
    assert not (tmp_path / "r.csv").exists()


def test_an_output_rate_too_high_for_a_grid_is_bad_input_not_an_internal_error(model, tmp_path):
    res = run("rollout", model, "--output-rate", "1e308", "--steps", 3, "-q", "-o", tmp_path / "r.csv")
    assert_one_line_error(res, 2, "--output-rate", "too high")
    assert not (tmp_path / "r.csv").exists()


@pytest.mark.parametrize("starts", [["--start", START], ["--start-quat", "0 0 0 1 0.3 0 1.1"], ["--starts", str(CSV_DIR / "shoe_01.csv")]])
def test_count_with_start_poses_and_nothing_to_draw_from_is_refused(model, tmp_path, starts):
    res = run("rollout", model, *starts, "--count", 5, "-o", tmp_path / "r.csv")
    assert_one_line_error(res, 2, "--count 5", "--from-demos")
    assert not (tmp_path / "r.csv").exists()


@pytest.mark.parametrize("flag,pose", [
    ("--start-quat", "0 0 0.8 0.92 0.3 0 1.1"),  # 0.38 mistyped: norm 1.22
    ("--goal", "0 0 0.8 0.92 0.3 0 1.1"),
    ("--via", "1: 0 0 0.1 0.5 0.3 0 1.1"),  # norm 0.51
])
def test_a_typed_quaternion_far_from_unit_length_is_normalised_with_a_warning(model, tmp_path, flag, pose):
    res = run("rollout", model, flag, pose, "--duration", 2, "--no-std", "-o", tmp_path / "r.csv")
    assert res.exit_code == 0, res.stderr
    said = [ln for ln in res.stderr.splitlines() if "it was normalised" in ln]
    assert len(said) == 1 and said[0].startswith("rbgp: warning:") and "x y z w" in said[0], res.stderr
    near = run("rollout", model, flag, pose.replace("0.8 0.92", "0.38 0.92").replace("0.1 0.5", "0.3 0.95"),
               "--duration", 2, "--no-std", "-o", tmp_path / "r.csv")  # a few digits' rounding: no warning
    assert near.exit_code == 0 and "normalised" not in near.stderr, near.stderr


def test_start_quat_is_the_same_start_as_the_rotation_vector(model):
    half = float(np.sqrt(0.5))
    by_vec = run("rollout", model, "--start", f"0 0 {np.pi / 2!r} 0.3 0 1.1", "--steps", 3, "--output-rate", 0)
    by_quat = run("rollout", model, "--start-quat", f"0 0 {half!r} {half!r} 0.3 0 1.1", "--steps", 3, "--output-rate", 0)
    scaled = run("rollout", model, "--start-quat", "0,0,2,2,0.3,0,1.1", "--steps", 3, "--output-rate", 0)  # normalised
    assert by_vec.exit_code == by_quat.exit_code == scaled.exit_code == 0, by_quat.stderr + scaled.stderr
    a, b, c = ([[float(x) for x in ln.split(",")[1:]] for ln in r.stdout.splitlines()[2:]] for r in (by_vec, by_quat, scaled))
    np.testing.assert_allclose(b, a, atol=1e-12)
    np.testing.assert_allclose(c, a, atol=1e-12)
    np.testing.assert_allclose(b[0][4:8], [0, 0, half, half], atol=1e-15)
    both = run("rollout", model, "--start", START, "--start-quat", "0 0 0 1 0.3 0 1.1", "--steps", 3, "--output-rate", 0)
    assert both.exit_code == 0 and both.stdout.count("\n") == 2 + 2 * 4  # --start first, then --start-quat


@pytest.mark.parametrize("pose,fragment", [
    ("0 0 0 0 0.3 0 1.1", "zero quaternion"),
    ("0 0 nan 1 0.3 0 1.1", "seven finite numbers"),
    ("0 0 0 1 0.3 0", "seven finite numbers"),
    ("0 0 0 one 0.3 0 1.1", "seven numbers"),
])
def test_bad_start_quat_is_one_clear_line(model, pose, fragment):
    assert_one_line_error(run("rollout", model, "--start-quat", pose), 2, "--start-quat", fragment)


def test_each_duration_recording_draws_each_rollout_for_its_own_duration(model, tmp_path):
    pytest.importorskip("rerun")
    from tests.viz.test_recording import Rrd

    out, rrd = tmp_path / "each.csv", tmp_path / "each.rrd"
    res = run("rollout", model, "--from-demos", CSV_DIR, "--count", 3, "--each-duration", "--output-rate", 0,
              "-o", out, "--rerun", rrd)
    assert res.exit_code == 0, res.stderr
    _, traj, _ = _table(out)
    rec = Rrd(rrd)
    rows = [rec.num_rows(f"/world/rollouts/{b}/body") for b in range(3)]
    assert rows == [traj.count(str(b)) for b in range(3)] and len(set(rows)) > 1


def test_an_output_rate_whose_grid_misses_the_end_still_writes_the_end(model, tmp_path):
    """--output-rate 0.5 on a 3.5 s motion: rows at 0, 2 s and its end (before: 0 and 2 s, the file ending mid-motion)."""
    out = tmp_path / "r.csv"
    res = run("rollout", model, "--start", START, "--duration", 3.5, "--output-rate", 0.5, "--json", "-o", out)
    assert res.exit_code == 0, res.stderr
    _, _, v = _table(out)
    np.testing.assert_allclose(v[:, 0], [0.0, 2.0, 3.5], atol=0.02)
    full = tmp_path / "full.csv"
    assert run("rollout", model, "--start", START, "--duration", 3.5, "-o", full).exit_code == 0
    _, _, w = _table(full)
    np.testing.assert_allclose(v[-1, 1:8], w[-1, 1:8], atol=1e-6)  # the same end pose as at the recorded rate
