"""`rbgp inspect` says what `train` then finds (issue 22.6): the same preparation, the same counts;
a file that cannot be read makes the exit code 2; many files get one line each and a summary; `rbgp
info` prints no Python dicts; a quaternion order that looks swapped is warned about (issue 22.10)."""

from __future__ import annotations

import json
import re
import warnings
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rbgp_cli.errors import RbgpWarning
from rbgp_cli.io.inspect import inspect_file
from rbgp_cli.io.options import ReadOptions
from tests.cli.test_cli import CSV_DIR, MCAP, REPO, run
from tests.conftest import REALDATA

HEADER = "t,x,y,z,qx,qy,qz,qw"


def _csv(path, t, p, q, header=HEADER):
    rows = [header] + [",".join(repr(float(v)) for v in (tt, *pp, *qq)) for tt, pp, qq in zip(t, p, q)]
    path.write_text("\n".join(rows) + "\n")
    return path


def _held(tmp_path):
    """shoe_01 at 179 Hz with the tracker holding the pose: 3 runs of repeated rows (12 samples)."""
    data = np.loadtxt(CSV_DIR / "shoe_01.csv", delimiter=",", skiprows=1)
    for a, b in ((100, 104), (300, 305), (500, 503)):
        data[a + 1:b + 1, 1:] = data[a, 1:]
    return _csv(tmp_path / "held.csv", data[:, 0], data[:, 1:4], data[:, 4:8])


def test_inspect_counts_the_sample_and_hold_that_train_drops(tmp_path):
    f = _held(tmp_path)
    tr = json.loads(run("inspect", f, "--json").stdout)["trajectories"][0]
    assert tr["held"] == 12 and tr["held_runs"] == 3 and tr["dropped"] == 12
    text = run("inspect", f).stdout
    assert "12 lost frames (12 repeat the previous pose exactly, sample-and-hold in 3 runs)" in text
    assert "train: drops 12 lost frames" in text
    res = run("train", f, "-o", tmp_path / "m.rbgp", "--max-points", "100", "--restarts", "1", "--share-hyperparameters")
    assert res.exit_code == 0 and "12 samples repeat the previous pose exactly" in res.stderr


def _files():
    out = [(str(f), {}) for f in sorted((REPO / "sample_data" / "csv").glob("*.csv"))]
    out.append((str(MCAP), {"topic": "all"}))
    if REALDATA.is_dir():
        for f in sorted(REALDATA.glob("*/*")):
            if f.parent.name == "mcap_no_pose" or not f.is_file() or f.suffix not in (".csv", ".tsv", ".mcap"):
                continue
            opts = {"kth_handover_csv": {"rate": 120.0, "quat_order": "xyzw"}, "mcap_pose": {"topic": "all"},
                    "motive_csv": {"body": "all", "length_unit": "cm", "euler_order": "XYZ"}, "qtm_6d_tsv": {"body": "all"}}.get(f.parent.name, {})
            out.append((str(f), opts))
    return out


_KEYS = ("held", "held_runs", "lost", "dropped", "filled", "duplicates", "sign_flips")


@pytest.mark.parametrize("path,opts", _files(), ids=lambda v: Path(v).name if isinstance(v, str) else "")
def test_inspect_reports_what_trains_preparation_reports(path, opts):
    """Every bundled and real file: inspect's sample-and-hold, lost-frame, gap and break counts are the
    reports of train's own preparation (workflows.load_demonstrations) with the same options."""
    from rbgp_cli.workflows import load_demonstrations

    options = ReadOptions(**opts)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RbgpWarning)
        d = inspect_file(path, options)
        demos, reports, _ = load_demonstrations([path], options)
    assert d["error"] is None
    trs = d["trajectories"]
    assert len(trs) == len(reports) and sum(t["demonstrations"] for t in trs) == len(demos)
    for tr, rep in zip(trs, reports):
        assert "prepare_error" not in tr
        assert {k: tr[k] for k in _KEYS} == {k: rep[k] for k in _KEYS}
        assert tr["breaks"]["count"] == len(rep["breaks"])
        assert tr["lost_frames"] == rep["lost"]
        assert tr["quat_order_suspect"] is None  # real recordings: no false alarm


def test_a_truncated_mcap_makes_inspect_exit_2_and_the_others_are_still_described(tmp_path):
    bad = tmp_path / "cut.mcap"
    bad.write_bytes(MCAP.read_bytes()[:30000])
    res = run("inspect", bad, CSV_DIR / "shoe_01.csv")
    assert res.exit_code == 2
    assert "trajectory shoe_01" in res.stdout and "error:" in res.stdout
    err = res.stderr.strip().splitlines()
    assert err[-1].startswith("rbgp: error: 1 of 2 files could not be read") and str(bad) in err[-1]
    assert run("inspect", CSV_DIR / "shoe_01.csv").exit_code == 0


def test_many_files_one_line_each_and_a_summary(tmp_path):
    res = run("inspect", CSV_DIR)
    assert res.exit_code == 0
    lines = res.stdout.strip().splitlines()
    assert len(lines) == 10  # 9 files, one line each, then the summary
    assert all(ln.startswith(str(CSV_DIR)) for ln in lines[:9])
    assert re.match(r"9 files, 9 trajectories -> 9 demonstrations, [\d.]+ s in all, [\d.]+ Hz; no problems", lines[-1]), lines[-1]
    full = run("inspect", CSV_DIR, "-v").stdout
    assert full.count("  trajectory ") == 9 and full.strip().splitlines()[-1] == lines[-1]
    data = tmp_path / "d"
    data.mkdir()
    for f in sorted(CSV_DIR.glob("*.csv")):
        (data / f.name).write_bytes(f.read_bytes())
    _held(data)
    last = run("inspect", data).stdout.strip().splitlines()[-1]
    assert last.startswith("10 files") and "problems: 1 with sample-and-hold" in last


def test_info_prints_no_python_dicts(tmp_path):
    model = tmp_path / "m.rbgp"
    assert run("train", CSV_DIR / "shoe_01.csv", "-o", model, "--max-points", "100", "--restarts", "1",
               "--share-hyperparameters").exit_code == 0
    text = run("info", model).stdout
    assert "kernel: squared_exponential (" in text and "velocity=(degree 2" in text
    assert not re.search(r"[{}]|'\w+':|\bNone\b|\bTrue\b|\bFalse\b", text), text


# ---------------------------------------------------------------------------------------------------
# quaternion order (issue 22.10)


def _motion(n=200, dt=0.01):
    """A slow, smooth motion near the identity (up to 25°), as calibrated rigid bodies are."""
    t = np.arange(n) * dt
    r = Rotation.from_rotvec(np.stack([0.3 * np.sin(t), 0.2 * t, 0.25 * np.sin(2 * t)], axis=1))
    p = np.stack([0.1 * t, 0.05 * np.sin(t), 1.0 + 0.02 * t], axis=1)
    return t, p, r.as_quat()  # x, y, z, w


def test_w_first_data_under_an_x_first_header_is_warned_about(tmp_path):
    t, p, q = _motion()
    f = _csv(tmp_path / "swapped.csv", t, p, q[:, [3, 0, 1, 2]])  # values w, x, y, z under qx, qy, qz, qw
    res = run("train", f, "-o", tmp_path / "m.rbgp", "--max-points", "100", "--restarts", "1", "--share-hyperparameters")
    notes = [ln for ln in res.stderr.splitlines() if "half-turn" in ln]
    assert len(notes) == 1 and "--quat-order wxyz" in notes[0] and str(f) in notes[0], res.stderr
    assert "half-turn" in run("inspect", f).stdout
    # the option decides: read as w-first it is the motion itself, and nothing is said
    res = run("inspect", f, "--quat-order", "wxyz", "--json")
    assert "half-turn" not in res.stderr and json.loads(res.stdout)["trajectories"][0]["quat_order_suspect"] is None
    from rbgp_cli.io.read import read_demonstrations

    (tr,) = read_demonstrations([str(f)], ReadOptions(quat_order="wxyz"))
    assert np.allclose(np.abs(np.sum(tr.quat * q, axis=1)), 1.0)
    res = run("inspect", f, "--quat-order", "xyzw")  # confirms the labels: silent
    assert "half-turn" not in res.stdout + res.stderr


def test_x_first_data_under_a_w_first_header_is_warned_about(tmp_path):
    t, p, q = _motion()
    f = _csv(tmp_path / "swapped.csv", t, p, q, header="t,x,y,z,qw,qx,qy,qz")  # values x, y, z, w
    res = run("inspect", f)
    assert "half-turn about z" in res.stdout and "--quat-order xyzw" in res.stdout


def test_a_correct_order_and_a_genuine_half_turn_motion_are_silent(tmp_path):
    t, p, q = _motion()
    f = _csv(tmp_path / "right.csv", t, p, q)
    res = run("inspect", f)
    assert "half-turn" not in res.stdout + res.stderr
    # a body turning through a half-turn about x (not staying there) is not mistaken for a swap
    r = Rotation.from_rotvec(np.outer(np.pi * (0.5 + t), [1.0, 0, 0]))
    f = _csv(tmp_path / "turning.csv", t, p, r.as_quat())
    res = run("inspect", f)
    assert "half-turn" not in res.stdout + res.stderr
