"""rbgp train and rbgp info say when the demonstrations drift over the recording order, with the
figure (issue 36); the recording order is the files' natural name order."""

from __future__ import annotations

import re

import numpy as np
import pytest
from typer.testing import CliRunner

from rbgp_cli.cli.app import app
from tests.dynamics.test_bands_order import session

runner = CliRunner()
FAST = ["--max-points", "80", "--restarts", "1", "--share-hyperparameters"]


def _write(demos, folder, names):
    from rbgp_cli.io.csv import write_trajectories_csv

    folder.mkdir()
    for d, name in zip(demos, names):
        write_trajectories_csv([d.with_(t=d.t - d.t[0])], str(folder / f"{name}.csv"))
    return folder


@pytest.mark.slow
def test_train_and_info_say_the_drift_over_the_recording_order_with_its_figure(tmp_path):
    demos = session(24, 5, drift_pos=0.12)
    # take_1 … take_24: natural order is the recording order (take_10 after take_9, not after take_1)
    folder = _write(demos, tmp_path / "drift", [f"take_{k + 1}" for k in range(24)])
    res = runner.invoke(app, ["train", str(folder), "-o", str(tmp_path / "m.rbgp"), *FAST])
    assert res.exit_code == 0, res.stderr
    line = next(x for x in res.stderr.splitlines() if "drift over the recording order" in x)
    cm = float(re.search(r"moves up to ([0-9.]+) cm", line).group(1))
    assert 7.0 <= cm <= 17.0, line  # the peak rises 12 cm from the first take to the last
    assert float(re.search(r"p = ([0-9.e-]+)", line).group(1)) < 0.01
    assert "crossval --order forward" in line  # where the next session's coverage is measured
    assert "--train-size N" in line  # and how to measure training on the latest takes only
    info = runner.invoke(app, ["info", str(tmp_path / "m.rbgp")])
    assert info.exit_code == 0 and "drift over the recording order" in info.stdout
    # the same takes named in a random order: nothing to say
    order = np.random.default_rng(1).permutation(24)
    shuffled = _write([demos[i] for i in order], tmp_path / "shuffled", [f"take_{k + 1}" for k in range(24)])
    res = runner.invoke(app, ["train", str(shuffled), "-o", str(tmp_path / "s.rbgp"), *FAST])
    assert res.exit_code == 0, res.stderr
    assert "drift over the recording order" not in res.stderr
    assert "in blocks in recording order" in res.stderr  # the bands' factors were still measured both ways


def test_the_summary_says_when_the_bands_cannot_be_calibrated_or_the_drift_not_tested():
    from rbgp_cli.cli.report import _variation_text

    five = _variation_text({"demos": 5, "band_scale": {"rotation": 1.2, "position": 1.0}, "shrinkage": 0.5,
                            "calibration": {"random": [1.2, 1.0], "recorded": None}, "drift": None})
    assert "shrunk by 0.50" in five and "widened ×1.2 in rotation" in five and "cannot be tested" in five
    three = _variation_text({"demos": 3, "band_scale": {"rotation": 1.0, "position": 1.0}, "shrinkage": 0.9,
                             "calibration": {"random": None, "recorded": None}, "drift": None})
    assert "too few demonstrations (3) to calibrate" in three
    old = _variation_text({"demos": 30, "band_scale": {"rotation": 1.2, "position": 1.0}})  # a model file before issue 36
    assert "left out fall inside" in old and "drift" not in old and "shrunk" not in old


@pytest.mark.slow
def test_file_order_mtime_recovers_the_recording_order_of_takes_named_out_of_order(tmp_path):
    import os

    demos = session(24, 5, drift_pos=0.12)
    order = np.random.default_rng(1).permutation(24)
    folder = _write([demos[i] for i in order], tmp_path / "renamed", [f"take_{k + 1}" for k in range(24)])
    for k, i in enumerate(order):  # each file's modification time is when its take was recorded
        os.utime(folder / f"take_{k + 1}.csv", ns=(1_700_000_000_000_000_000 + int(i) * 10**9,) * 2)
    res = runner.invoke(app, ["train", str(folder), "-o", str(tmp_path / "m.rbgp"), "--file-order", "mtime", *FAST])
    assert res.exit_code == 0, res.stderr
    line = next(x for x in res.stderr.splitlines() if "drift over the recording order" in x)
    assert float(re.search(r"p = ([0-9.e-]+)", line).group(1)) < 0.01
