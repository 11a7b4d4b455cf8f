"""rbgp rollout --given, rbgp follow and rbgp crossval --given (issue 37: a motion under way)."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from tests.cli.common import CSV_DIR, REPO, run


def _prefix(src, dst, fraction):
    lines = src.read_text().splitlines()
    n = len(lines) - 1
    dst.write_text("\n".join(lines[: 1 + int(n * fraction)]) + "\n")
    return lines


@pytest.mark.slow
def test_rollout_given_continues_each_file_from_its_last_seen_sample(model, tmp_path):
    first = tmp_path / "a.csv"
    lines = _prefix(CSV_DIR / "shoe_01.csv", first, 0.4)
    _prefix(CSV_DIR / "shoe_02.csv", tmp_path / "b.csv", 0.6)
    out = tmp_path / "rest.csv"
    res = run("--json", "rollout", model, "--given", first, tmp_path / "b.csv", "--samples", 4, "-o", out)
    assert res.exit_code == 0, res.stderr
    summary = json.loads(res.stdout)
    assert [m["trajectory"] for m in summary["motions"]] == ["0", "1"]
    m0 = summary["motions"][0]
    last_seen = float(first.read_text().splitlines()[-1].split(",")[0])
    assert m0["t"] == pytest.approx(last_seen)
    assert 0.0 < m0["phase"] < 1.0 and m0["end_time_band"][0] <= m0["end_time"] <= m0["end_time_band"][1]
    true_end = float(lines[-1].split(",")[0])
    assert abs(m0["end_time"] - true_end) < 0.15 * true_end
    text = out.read_text().splitlines()
    rows = [r.split(",") for r in text if r and not r.startswith("#") and not r.startswith("trajectory")]
    names = {r[0].strip('"') for r in rows}
    assert names == {"0", "1", "0.s0", "0.s1", "0.s2", "0.s3", "1.s0", "1.s1", "1.s2", "1.s3"}
    first_row = next(r for r in rows if r[0].strip('"') == "0")
    assert float(first_row[1]) == pytest.approx(last_seen)  # on the seen file's own clock


def test_rollout_given_refuses_start_poses(model, tmp_path):
    res = run("rollout", model, "--given", CSV_DIR / "shoe_01.csv", "--count", 1, "--duration", 2)
    assert res.exit_code == 2
    assert "--given" in res.stderr and len(res.stderr.strip().splitlines()) == 1


@pytest.mark.slow
def test_follow_reads_a_pipe_and_prints_one_json_line_per_prediction(model, tmp_path):
    lines = (CSV_DIR / "shoe_01.csv").read_text().splitlines()
    header, first = lines[0], lines[1].split(",")
    rest_rows = [",".join([f"{-1.0 + 0.02 * i:.3f}"] + first[1:]) for i in range(50)]  # 1 s at rest first
    proc = subprocess.Popen([sys.executable, "-m", "rbgp_cli", "follow", str(model), "--every", "50"],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO)
    out, err = proc.communicate("\n".join([header] + rest_rows + lines[1:]) + "\n", timeout=300)
    assert proc.returncode == 0, err
    got = [json.loads(x) for x in out.splitlines()]
    assert len(got) >= 3
    assert all(g["motion"] == 0 for g in got)
    assert got[0]["start"] >= 0.0 and got[0]["t"] - got[0]["start"] < 0.1
    phases = [g["phase"] for g in got]
    assert phases == sorted(phases) and phases[-1] > 0.5
    true_end = float(lines[-1].split(",")[0])
    assert abs(got[-1]["end_time"] - true_end) < 0.1 * true_end
    for g in got:
        assert len(g["end_position"]) == 3 and len(g["end_position_band"]) == 3 and g["off"] in (True, False)


def test_follow_bad_row_is_one_line_error(model):
    text = "t,x,y,z,qx,qy,qz,qw\n0,0,0,0,0,0,0,1\n0.01,0,0,abc,0,0,0,1\n"
    res = run("follow", model, "--no-detect", input=text)
    assert res.exit_code == 2
    msg = res.stderr.strip().splitlines()
    assert len(msg) == 1 and "row 3" in msg[0]


def test_crossval_given_refuses_a_fraction_outside_0_1(tmp_path):
    res = run("crossval", CSV_DIR, "--given", "1.5")
    assert res.exit_code == 2 and "between 0 and 1" in res.stderr
    res = run("crossval", CSV_DIR, "--given", "half")
    assert res.exit_code == 2 and "--given" in res.stderr


@pytest.mark.slow
def test_crossval_given_rows(tmp_path):
    res = run("--json", "crossval", CSV_DIR, "--given", "0.3", "--folds", 3, "--samples", 5, "--no-peers",
              "--restarts", 1, "--max-points", 150)
    assert res.exit_code == 0, res.stderr
    rows = json.loads(res.stdout)["rows"]
    assert [r["method"] for r in rows] == ["rbgp", "no-GP"]
    for r in rows:
        assert r["given"] == 0.3 and r["motions"] == 9
        assert np.isfinite(r["end_pos"]) and np.isfinite(r["rest_pos"]) and 0.0 <= r["cov_pos"] <= 1.0


def test_crossval_given_json_writes_missing_coverage_as_null(monkeypatch):
    """The nearest demonstration has no samples, so no coverage: --json writes null where the table writes '-'
    (JSON has no NaN; the run failed with an internal error after the whole cross-validation before)."""
    from rbgp_cli import workflows

    nan = float("nan")
    row = dict(method="nearest", given=0.4, end_pos=0.1, end_rot=0.2, end_time=0.3, rest_pos=0.1, rest_rot=0.2,
               cov_pos=nan, cov_rot=nan, band_pos=nan, band_rot=nan, motions=9)
    monkeypatch.setattr(workflows, "crossval_under_way",
                        lambda *a, **k: {"rows": [row], "folds": 3, "samples": 5, "inputs": []})
    res = run("--json", "crossval", CSV_DIR, "--given", "0.4", "--folds", 3)
    assert res.exit_code == 0, res.stderr
    out = json.loads(res.stdout)["rows"][0]
    assert out["cov_pos"] is None and out["band_rot"] is None and out["end_pos"] == 0.1
    res = run("crossval", CSV_DIR, "--given", "0.4", "--folds", 3)
    assert res.exit_code == 0 and "nearest" in res.stdout and " -" in res.stdout
