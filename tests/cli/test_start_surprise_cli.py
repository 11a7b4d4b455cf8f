"""rbgp rollout widens the bands of a start unlike the demonstrations' starts (issue 36, seventeenth and eighteenth
passes): --json reports each start's band_widening and start_beyond, stderr says which rollouts were widened and by
how much, rbgp train says whether the start's surprise widens the bands."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
from typer.testing import CliRunner

from rbgp_cli.cli.app import app
from tests.cli.test_drift_cli import FAST, _write
from tests.dynamics.test_start_surprise import people

runner = CliRunner()


@pytest.mark.slow
def test_a_far_start_gets_wider_bands_a_warning_and_its_factor_in_json(tmp_path):
    demos = people(24, 9, other=0.25, samples=30)
    folder = _write(demos, tmp_path / "takes", [f"take_{k + 1}" for k in range(24)])
    res = runner.invoke(app, ["train", str(folder), "-o", str(tmp_path / "m.rbgp"), *FAST])
    assert res.exit_code == 0, res.stderr
    assert "widens its bands (rotation" in res.stderr  # the summary says the widening was kept, for which part
    from rbgp_cli.geometry.so3 import log_quat

    near = np.concatenate([log_quat(demos[0].quat[0]), demos[0].position[0]])
    far = near + [0, 0, 0, 1.0, 0, 0]  # a metre off: tens of the starts' spreads
    args = ["rollout", str(tmp_path / "m.rbgp"), "--samples", "3", "--json", "-o", str(tmp_path / "r.csv")]
    for pose in (near, far):
        args += ["--start", " ".join(f"{x:.9g}" for x in pose)]
    res = runner.invoke(app, args)
    assert res.exit_code == 0, res.stderr
    out = json.loads(res.stdout)
    w, beyond = out["band_widening"], out["start_beyond"]
    assert len(w) == 2 and w[0]["rotation"] < 1.5 and w[1]["rotation"] > 3.0, w
    assert beyond[0] < 1.0 < 3.0 < beyond[1], beyond  # a training start is inside, a metre off far beyond
    assert w[1]["position"] >= np.sqrt(beyond[1]) * (1 - 1e-9), (w, beyond)  # every part widened at least √(ρ / ρ_max)
    line = next(x for x in res.stderr.splitlines() if "widened" in x)
    assert re.search(r"1 of 2 starts are less like the demonstrations' starts than any of theirs .*widened ×[0-9.]+ "
                     r"\(rollouts 1; start_beyond\)", line), line
    assert sum("widened" in x for x in res.stderr.splitlines()) == 1  # one warning names it, not two
    # without samples there is no band, and nothing is said about one; the start's surprise is still reported
    res = runner.invoke(app, ["rollout", str(tmp_path / "m.rbgp"), "--start", " ".join(f"{x:.9g}" for x in far),
                              "--json", "-o", str(tmp_path / "m.csv")])
    out = json.loads(res.stdout)
    assert res.exit_code == 0 and out["band_widening"] is None and "widened" not in res.stderr
    assert out["start_beyond"][0] > 3.0, out["start_beyond"]


def test_the_summary_says_whether_the_start_widens_the_bands_and_by_how_much():
    from rbgp_cli.cli.report import _variation_text

    base = {"demos": 40, "band_scale": {"rotation": 1.1, "position": 1.2}, "shrinkage": 0.1, "drift": None}
    kept = _variation_text({**base, "calibration": {"random": [1.0, 1.1], "recorded": [1.1, 1.2], "start_widening": {
        "rotation": True, "position": False, "mean_width_ratio": [0.93, 1.07]}}})
    assert "widens its bands (rotation)" in kept and "7 % narrower in rotation" in kept and "position on" not in kept
    none = _variation_text({**base, "calibration": {"random": [1.0, 1.1], "recorded": [1.1, 1.2], "start_widening": {
        "rotation": False, "position": False, "mean_width_ratio": [1.3, 1.4]}}})
    assert "surprise" not in none and "widens its bands" not in none  # not kept: the bands are as they were (--json has why)
    older = _variation_text({**base, "calibration": {"random": [1.0, 1.1], "recorded": [1.1, 1.2]}})
    assert "surprise" not in older and "widens its bands" not in older


@pytest.mark.slow
def test_starts_drawn_from_the_demonstrations_are_like_theirs_and_a_fixed_spread_is_not(tmp_path):
    """--from-demos draws starts like the demonstrations' own (their mean and covariance): they are not beyond
    every demonstration's start, so their bands are not widened; a fixed perturbation of many of the starts'
    spreads is beyond and said to be (the twenty-first pass: 2 cm was 4–8 spreads of the hand raises')."""
    demos = people(24, 9, other=0.25, samples=30)
    folder = _write(demos, tmp_path / "takes", [f"take_{k + 1}" for k in range(24)])
    model = str(tmp_path / "m.rbgp")
    assert runner.invoke(app, ["train", str(folder), "-o", model, *FAST]).exit_code == 0
    spread = np.std([d.position[0] for d in demos], axis=0).max()
    far = f"{6 * spread:.4f}"  # a fixed perturbation of 6 of the starts' largest spreads per axis
    base = ["rollout", model, "--from-demos", str(folder), "--count", "48", "--samples", "2", "--json"]
    res = runner.invoke(app, base + ["-o", str(tmp_path / "a.csv")])
    assert res.exit_code == 0, res.stderr
    beyond = np.array(json.loads(res.stdout)["start_beyond"])
    assert len(beyond) == 48 and np.mean(beyond > 1.0) <= 0.1, np.sort(beyond)[-5:]
    assert "less like the demonstrations' starts" not in res.stderr or np.any(beyond > 1.0)
    res = runner.invoke(app, base + ["--start-spread", far, "-o", str(tmp_path / "b.csv")])
    assert res.exit_code == 0, res.stderr
    beyond = np.array(json.loads(res.stdout)["start_beyond"])
    assert np.mean(beyond > 1.0) > 0.5 and "less like the demonstrations' starts" in res.stderr, np.sort(beyond)
