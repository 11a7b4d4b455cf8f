"""Rollouts that leave the demonstrations (issue 21): warned, marked in the CSV and the JSON, the
--off-data behaviours, and the counts in evaluate and crossval."""

from __future__ import annotations

import csv
import io
import json

import numpy as np
import pytest
from typer.testing import CliRunner

from rbgp_cli.cli.app import app
from rbgp_cli.dynamics.envelope import envelope_from_demos
from rbgp_cli.dynamics.rollout import rollout
from rbgp_cli.io.model_store import load_model, read_header, save_model
from tests.evaluation.test_crossval import _write, reaching_demos

runner = CliRunner()
FAST = ["--max-points", "100", "--restarts", "1", "--share-hyperparameters", "-q"]
FAR = "0 0 1.2 2.5 0.3 1.1"  # 1.7 m beside demonstrations that stay within 0.2 … 0.9 m in x


@pytest.fixture(scope="module")
def narrow(tmp_path_factory):
    """A narrow set of reaching motions, a model of them, and the first demonstration's start pose."""
    root = tmp_path_factory.mktemp("offdata")
    demos = reaching_demos(6)
    folder = _write(demos, root / "demos")
    model = root / "m.rbgp"
    res = runner.invoke(app, ["train", str(folder), "-o", str(model), *FAST, "--residual-gain", "1"])  # the GP's residual on: keep and prior differ
    assert res.exit_code == 0, res.stderr
    from rbgp_cli.geometry.so3 import rotvec_from_quat

    d = demos[0]
    start = " ".join(repr(float(v)) for v in (*rotvec_from_quat(d.quat[0]), *d.position[0]))
    return folder, model, start, demos


def rows_of(path):
    lines = [ln for ln in open(path) if not ln.startswith("#")]
    return list(csv.DictReader(io.StringIO("".join(lines))))


def test_a_rollout_from_a_far_start_warns_and_is_marked_in_the_csv_and_the_json(narrow, tmp_path):
    folder, model, start, _ = narrow
    out = tmp_path / "r.csv"
    res = runner.invoke(app, ["rollout", str(model), "--start", FAR, "--start", start, "-o", str(out), "--json"])
    assert res.exit_code == 0, res.stderr
    assert "1 of 2 rollouts left the demonstrations' envelope" in res.stderr
    assert "#0 at t = 0.00 s (2.50, 0.30, 1.10)" in res.stderr
    summary = json.loads(res.stdout)
    left = summary["left_data"]
    assert summary["off_data"] == "keep"
    assert left["count"] == 1 and left["of"] == 2 and left["envelope"] == "demonstrations"
    assert [e["index"] for e in left["trajectories"]] == [0]
    assert left["trajectories"][0]["t"] == 0.0 and left["trajectories"][0]["position"] == [2.5, 0.3, 1.1]
    rows = rows_of(out)
    far = [float(r["left_data"]) for r in rows if r["trajectory"] == "0"]
    near = [float(r["left_data"]) for r in rows if r["trajectory"] == "1"]
    assert far[0] == 1.0 and len(far) == len(near) > 2
    assert set(near) == {0.0}
    # the marked CSV is read back as trajectories (the reader ignores the extra column)
    res = runner.invoke(app, ["evaluate", str(out), "--demos", str(folder), "--json"])
    assert res.exit_code == 0, res.stderr
    ev = json.loads(res.stdout)["left_data"]
    assert ev["count"] == 1 and ev["of"] == 2 and ev["trajectories"][0]["name"].endswith("0")
    res = runner.invoke(app, ["evaluate", str(out), "--demos", str(folder)])
    assert res.exit_code == 0 and "; 1 of 2 generated left the demonstrations' envelope" in res.stdout


def test_rollouts_from_demonstrated_starts_are_not_flagged(narrow, tmp_path):
    folder, model, start, _ = narrow
    out = tmp_path / "r.csv"
    res = runner.invoke(app, ["rollout", str(model), "--start", start, "--from-demos", str(folder), "--count", "6",
                              "--start-spread", "0.005", "-o", str(out), "--json"])
    assert res.exit_code == 0, res.stderr
    assert json.loads(res.stdout)["left_data"]["count"] == 0
    assert "envelope" not in res.stderr
    assert {float(r["left_data"]) for r in rows_of(out)} == {0.0}
    res = runner.invoke(app, ["evaluate", str(out), "--demos", str(folder), "--json"])
    assert json.loads(res.stdout)["left_data"]["count"] == 0


@pytest.mark.parametrize("rate", [["--output-rate", "0"], []])
def test_off_data_stop_ends_the_trajectory_where_it_left(narrow, tmp_path, rate):
    """On the integration grid and written at the recorded rate (resampled: until the twenty-first pass a stopped
    trajectory among several was written whole there, under a warning that said it ended)."""
    _, model, start, _ = narrow
    out = tmp_path / "r.csv"
    res = runner.invoke(app, ["rollout", str(model), "--start", FAR, "--start", start, "--off-data", "stop", *rate,
                              "-o", str(out), "--json"])
    assert res.exit_code == 0, res.stderr
    assert "they end there (--off-data stop)" in res.stderr
    rows = rows_of(out)
    n0 = sum(r["trajectory"] == "0" for r in rows)
    n1 = sum(r["trajectory"] == "1" for r in rows)
    if rate:
        assert n0 == 2 and n1 == json.loads(res.stdout)["steps"] + 1  # its first sample outside, and one step
    else:  # at the rate: no further than the step after it left
        assert n0 <= 2 < n1
    assert all(r["std_vx"] not in ("", "nan") for r in rows)  # the std columns are cut with it


def test_off_data_prior_follows_the_prior_mean_outside(narrow):
    _, model_path, _, _ = narrow
    model, _ = load_model(model_path)
    q0 = np.array([[0.0, 0.0, np.sin(0.6), np.cos(0.6)]])
    # outside the demonstrations (x 0.2 … 0.9 m) yet near enough that the GP's residual is not zero
    # in floating point (at FAR it underflows: keep and prior would then agree)
    p0 = np.array([[1.2, 0.3, 1.1]])
    res = rollout(model, q0, p0, 3, with_std=False, off_data="prior")
    X0 = model.initial_state(q0, p0)
    D = np.full((1, 1), 3 * model.dt)
    dev = model.start_deviation(q0, p0)  # a start-conditioned model's prior follows the path from its start
    # its velocity over the rollout's own phase step dt/D (the secant feed-forward of a phase model)
    want = model.advance(X0, model.prior_mean(X0, dev, model.phase_step(D[:, 0])), model.dt, D)
    _, p1 = model.representation.pose_from_state(want[:, : model.pose_dims])
    np.testing.assert_allclose(res.position[0, 1], p1[0], atol=1e-12)
    keep = rollout(model, q0, p0, 3, with_std=False, off_data="keep")
    # the GP's residual is not zero there (small: the default noise scale trusts the prior)
    assert not np.allclose(keep.position[0, 1], p1[0], rtol=0.0, atol=1e-12)
    assert res.left["count"] == keep.left["count"] == 1


def test_off_data_prior_needs_a_prior_and_a_bad_mode_exits_2(narrow, tmp_path):
    folder, model, start, _ = narrow
    plain = tmp_path / "plain.rbgp"
    res = runner.invoke(app, ["train", str(folder), "-o", str(plain), *FAST, "--prior", "none"])
    assert res.exit_code == 0, res.stderr
    res = runner.invoke(app, ["rollout", str(plain), "--start", start, "--off-data", "prior"])
    assert res.exit_code == 2 and "this model has none" in res.stderr
    res = runner.invoke(app, ["rollout", str(model), "--start", start, "--off-data", "maybe"])
    assert res.exit_code == 2 and "--off-data must be one of keep, stop, prior" in res.stderr


def test_the_envelope_is_stored_and_an_older_model_file_computes_it_from_its_training_points(narrow, tmp_path):
    _, model_path, start, demos = narrow
    header, _ = read_header(model_path)
    env = header["envelope"]
    assert len(env["lo"]) == 51 and len(env["lo"][0]) == 3 and env["margin"] > 0
    model, _ = load_model(model_path)
    np.testing.assert_allclose(model.envelope.lo, envelope_from_demos(demos).lo)
    model.envelope = None  # a file written before the envelope existed
    old = tmp_path / "old.rbgp"
    save_model(model, old)
    assert "envelope" not in read_header(old)[0]
    res = runner.invoke(app, ["rollout", str(old), "--start", FAR, "--start", start, "-o", str(tmp_path / "r.csv"),
                              "--json"])
    assert res.exit_code == 0, res.stderr
    left = json.loads(res.stdout)["left_data"]
    assert left["count"] == 1 and left["envelope"] == "training points"
    assert "envelope from the model's training points" in res.stderr


@pytest.mark.slow
def test_crossval_reports_how_many_rollouts_left(narrow):
    folder, _, _, _ = narrow
    res = runner.invoke(app, ["crossval", str(folder), "--folds", "3", *FAST, "--jobs", "1", "--json"])
    assert res.exit_code == 0, res.stderr
    out = json.loads(res.stdout)
    assert isinstance(out["floor_left_data"], int)
    for r in out["results"]:
        assert isinstance(r["left_data"], int) and 0 <= r["left_data"] <= 6
        assert sum(f["left_data"] for f in r["per_fold"]) == r["left_data"]
    res = runner.invoke(app, ["crossval", str(folder), "--folds", "3", *FAST, "--jobs", "1"])
    header = next(ln for ln in res.stdout.splitlines() if ln.startswith("representation"))  # the table's columns
    assert res.exit_code == 0 and " left" in header


def test_off_data_prior_on_a_model_whose_residual_is_off_says_it_changes_nothing(narrow, tmp_path):
    """With the GP's residual off (gain 0) the motion is the prior's everywhere: off_data prior writes what keep writes,
    and the warning says so instead of claiming a fallback (a new user compared the two files byte for byte)."""
    folder, _, _, _ = narrow
    model = tmp_path / "off.rbgp"
    assert runner.invoke(app, ["train", str(folder), "-o", str(model), *FAST, "--residual-gain", "0"]).exit_code == 0
    out = {}
    for mode in ("keep", "prior"):
        res = runner.invoke(app, ["rollout", str(model), "--start", FAR, "--off-data", mode, "-o", str(tmp_path / f"{mode}.csv")])
        assert res.exit_code == 0, res.stderr
        out[mode] = res.stderr
    assert (tmp_path / "keep.csv").read_text() == (tmp_path / "prior.csv").read_text()
    assert "changes nothing" in out["prior"] and "followed the prior mean" not in out["prior"]
    assert "falls back to the prior's pull" not in out["keep"]


def test_a_continuation_is_checked_at_its_phase_of_the_whole_motion():
    """continuation_phases and left_envelope with phases: a piece that starts mid-motion is held to the boxes of its
    phases in the whole motion, not to the start's: a motion along x from 0 to 1 m in 2 s and its second half; read as
    a whole motion of its own, that second half starts at phase 0, where the demonstrations are near x = 0, and
    leaves. A sample drawn shorter (ending at 1.6 s) starts from the mean's current phase 0.5, not at 1 / 1.6 of its
    own duration (where the demonstrations are near x = 0.6 and the seen pose, 0.5, would be outside), and reaches
    phase 1 at its own end."""
    from rbgp_cli.dynamics.envelope import continuation_phases, envelope_from_points, left_envelope
    from rbgp_cli.dynamics.trajectory import Trajectory

    s = np.linspace(0.0, 1.0, 101)
    env = envelope_from_points(np.c_[s, np.zeros((101, 2))], s, window=0.02, margin_fraction=0.05)
    unit = np.tile([0.0, 0.0, 0.0, 1.0], (51, 1))
    mean = Trajectory(2.0 * s[50:], unit, np.c_[s[50:], np.zeros((51, 2))], name="rest")
    short = Trajectory(np.linspace(1.0, 1.6, 51), unit, mean.position, name="rest.s0")
    phases = continuation_phases([mean, short], 0.0)
    assert np.allclose(phases[0], s[50:]) and np.allclose(phases[1], s[50:])
    whole = left_envelope([mean, short], env, phases=phases, starts=[0.0, 0.0], masks=True)
    assert whole["count"] == 0 and not any(m.any() for m in whole["outside"])
    own = left_envelope([short], env, phases=[(short.t - 0.0) / 1.6], starts=[0.0])  # the sample's own duration
    alone = left_envelope([mean], env)
    assert own["count"] == 1 and own["trajectories"][0]["step"] == 0
    assert alone["count"] == 1 and alone["trajectories"][0]["step"] == 0
