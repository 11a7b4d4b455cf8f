"""The command line on C3D and BVH files: inspect lists what they hold, train reads the chosen body,
bad choices are one-line errors naming the file and the option."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from tests.cli.common import REPO, run
from tests.cli.test_realdata_cli import FAST, one_error_line
from tests.io.test_bvh import mixed_bvh
from tests.io.test_c3d import tool_take, write_c3d

pytest.importorskip("ezc3d")


@pytest.mark.slow
def test_inspect_and_train_a_synthetic_c3d(tmp_path):
    labels, xyz, *_ = tool_take(n=120)
    path = write_c3d(tmp_path / "tool.c3d", labels, xyz)
    res = run("inspect", path)
    assert res.exit_code == 0, res.stderr
    assert "tool: 5 markers" in res.stdout and "skin:a" in res.stdout
    desc = json.loads(run("inspect", path, "--json").stdout)["description"]
    assert [c["name"] for c in desc["clusters"]] == ["tool"]
    err = one_error_line(run("train", path, "--body", "tool:m1,tool:m2", "-o", tmp_path / "m.rbgp"))
    assert str(path) in err and "at least 3 markers" in err and "--body" in err
    err = one_error_line(run("train", path, "--body", "tooll", "-o", tmp_path / "m.rbgp"))
    assert "did you mean 'tool'" in err
    assert not (tmp_path / "m.rbgp").exists()


def test_inspect_a_bvh_lists_its_joints_and_train_asks_for_one(tmp_path):
    path = mixed_bvh(tmp_path)
    res = run("inspect", path)
    assert res.exit_code == 0, res.stderr
    assert "hips, spine, arm, hand, leg" in res.stdout and "--body JOINT" in res.stdout
    err = one_error_line(run("train", path, "-o", tmp_path / "m.rbgp"))
    assert "choose a joint" in err and "--body" in err


@pytest.mark.slow
def test_inspect_c3d_in_a_real_process(tmp_path):
    labels, xyz, *_ = tool_take(n=60)
    path = write_c3d(tmp_path / "tool.c3d", labels, xyz, first_frame=11, events=[("Right", "Foot Off", 0.3)])
    res = subprocess.run([sys.executable, "-m", "rbgp_cli", "inspect", str(path)], capture_output=True, text=True,
                         cwd=REPO, timeout=120)
    assert res.returncode == 0, res.stderr
    assert "from frame 11" in res.stdout and "Right Foot Off 0.300 s" in res.stdout


@pytest.mark.slow
@pytest.mark.realdata
def test_the_vicon_box_trains_by_its_cluster(realdata, tmp_path):
    path = realdata / "c3d_vicon" / "box_lift_vicon.c3d"
    if not path.exists():
        pytest.skip("c3d_vicon/box_lift_vicon.c3d not found")
    res = run("inspect", path)
    assert res.exit_code == 0 and "boite: 8 markers" in res.stdout
    tr = json.loads(run("inspect", path, "--body", "boite", "--json").stdout)["trajectories"][0]
    assert tr["samples"] == 580 and tr["duration_s"] == pytest.approx(5.79)
    res = run("train", path, "--body", "boite", "-o", tmp_path / "box.rbgp", *FAST, "--json")
    assert res.exit_code == 0, res.stderr
    assert json.loads(res.stdout)["demos"] == 1 and (tmp_path / "box.rbgp").exists()


@pytest.mark.slow
@pytest.mark.realdata
def test_two_wave_takes_train_by_hand_r(realdata, tmp_path):
    takes = sorted((realdata / "bvh_wave").glob("*.bvh"))[:2]
    if len(takes) < 2:
        pytest.skip("bvh_wave not found")
    res = run("train", *takes, "--body", "Hand_R", "-o", tmp_path / "wave.rbgp", *FAST, "--json")
    assert res.exit_code == 0, res.stderr
    assert json.loads(res.stdout)["demos"] == 2
    assert "sign flip" not in res.stderr  # the reader's quaternions come from matrices: nothing to say


@pytest.mark.parametrize("command", ["inspect", "train"])
def test_warnings_about_a_c3d_on_stdin_name_it_dash_not_a_temporary_file(tmp_path, command):
    """A C3D piped in is read through a temporary file; what rbgp says about it names '-'."""
    labels, xyz, *_ = tool_take(n=120)
    xyz[40:43, 2:5] = float("nan")  # three frames with only two tool markers seen: lost
    path = write_c3d(tmp_path / "tool.c3d", labels, xyz)
    args = ["-", "--body", "tool"] + (["-o", tmp_path / "m.rbgp", *FAST] if command == "train" else [])
    res = run(command, *args, input=path.read_bytes())
    assert res.exit_code == 0, res.stderr
    warnings = [ln for ln in res.stderr.splitlines() if ln.startswith("rbgp: warning:")]
    assert any("3 of 120 frames are lost" in ln for ln in warnings), res.stderr
    assert all(ln.startswith("rbgp: warning: -: ") for ln in warnings), res.stderr
    assert "rbgp-stdin-" not in res.stderr and "/proc/self/fd" not in res.stderr
