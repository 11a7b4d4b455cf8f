"""``rbgp inspect`` speaks to people for every format: aligned rows of plain words (what was
recognised, bodies, units, rotation source, rate, lost frames, gaps, the options still needed), never
Python reprs; ``--json`` gives the same as data."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from rbgp_cli.io import export
from rbgp_cli.io.inspect import format_inspect, inspect_file
from rbgp_cli.io.options import ReadOptions

from tests.hostile import builders as B

from . import mcap_fixtures as F

REPR = re.compile(r"[{}\[\]]|\bNone\b")


def two_bodies():
    return [B.smooth_motion(seed=0, name="Subj:Pelvis"), B.smooth_motion(seed=1, name="Subj:Thigh")]


def with_lost_frames(tr, rows=(10, 11, 12)):
    pos, quat = tr.position.copy(), tr.quat.copy()
    pos[list(rows)] = np.nan
    quat[list(rows)] = np.nan
    return tr.with_(position=pos, quat=quat)


def vendor_files(tmp_path) -> dict:
    """Vendor exports as users have them, good and incomplete: {name: (path, what the text must say)}."""
    out = {}

    def put(name, text):
        p = tmp_path / name
        p.write_text(text)
        return p

    one = [with_lost_frames(B.smooth_motion(name="shoe"))]
    p = tmp_path / "qtm_current_6D.tsv"
    export.write_qtm_tsv(one, p, lost="null")
    out["qtm current"] = (p, ["Qualisys QTM TSV", "bodies        1: shoe", "3 lost frames", "Rot matrix",
                              "positions mm, angles deg", "100 Hz"])
    p = tmp_path / "qtm_old_6D.tsv"
    export.write_qtm_tsv(two_bodies(), p, layout="old", euler="ZYX")
    out["qtm old, two bodies"] = (p, ["old, before 2.0.0", "row / FREQUENCY", "still needed  body NAME"])
    text = (tmp_path / "qtm_current_6D.tsv").read_text().replace("FREQUENCY\t100", "FREQUENCY\tEXT")
    text = "\n".join(ln for ln in text.splitlines() if not ln.startswith("FILE_VERSION"))
    text = re.sub(r"(?m)^Frame\tTime\t", "", text)  # no Frame/Time: the rate must come from --rate
    text = "\n".join(ln.split("\t", 2)[2] if ln[:1].isdigit() else ln for ln in text.splitlines())
    out["qtm EXT frequency"] = (put("qtm_ext_6D.tsv", text), ["FREQUENCY EXT", "still needed  rate HZ"])
    out["qtm 3D markers"] = (put("qtm_3D.tsv", "NO_OF_FRAMES\t1\nFREQUENCY\t100\nDATA_INCLUDED\t3D\n"
                                 "MARKER_NAMES\ta\nFrame\tTime\ta X\ta Y\ta Z\n1\t0\t1\t2\t3\n"),
                             ["error:", "3D data, not 6DOF"])
    p = tmp_path / "motive_quat.csv"
    export.write_motive_csv(one, p)
    out["motive quaternion"] = (p, ["OptiTrack Motive CSV", "quaternion x, y, z, w", "m (Length Units Meters)",
                                    "Time (Seconds) column", "up axis       Y", "3 lost frames"])
    p = tmp_path / "motive_euler_122.csv"
    export.write_motive_csv(two_bodies(), p, rotation_type="XYZ", header_labels=False)
    text = p.read_text().splitlines()
    text[0] = re.sub(r",Rotation Type,XYZ|,Length Units,Meters", "", text[0])  # as old exports do
    out["motive euler, nothing stated"] = (put("motive_euler_122.csv", "\n".join(text) + "\n"),
                                           ["rigid bodies  2: Subj:Pelvis, Subj:Thigh", "order not stated",
                                            "length unit   not stated", "still needed  length_unit m|cm|mm",
                                            "euler_order XYZ", "body NAME"])
    out["motive markers only"] = (put("motive_markers.csv",
                                      "Format Version,1.23,Take Name,t,Export Frame Rate,120,Length Units,Meters\n\n"
                                      ",Type,Marker,Marker,Marker\n,Name,m1,m1,m1\n,ID,1,1,1\n"
                                      ",,Position,Position,Position\nFrame,Time (Seconds),X,Y,Z\n0,0,1,2,3\n"),
                                  ["rigid bodies  none", "ignored       1 marker (only", "error:", "no Rigid Body columns"])
    p = tmp_path / "vicon.csv"
    export.write_vicon_csv(two_bodies(), p)
    out["vicon"] = (p, ["Vicon CSV", "segments      2: Subj:Pelvis, Subj:Thigh", "helical (axis-angle)",
                        "length unit   mm", "body NAME"])
    p = tmp_path / "vicon_semicolon.csv"
    export.write_vicon_csv([with_lost_frames(B.smooth_motion(name="Subj:Pelvis"))], p, delimiter=";",
                           decimal_comma=True)
    text = "\n".join(ln for ln in p.read_text().splitlines() if not ln.startswith(";;deg"))  # no units line
    out["vicon no units line"] = (put("vicon_nounits.csv", text + "\n"),
                                  ["delimiter     semicolon", "length unit   not stated",
                                   "still needed  length_unit m|cm|mm", "error:"])
    out["vicon markers only"] = (put("vicon_markers.csv", "Trajectories\n100\n,,Subj:LASI,,\n"
                                     "Frame,Sub Frame,X,Y,Z\n,,mm,mm,mm\n1,0,1,2,3\n"),
                                 ["Trajectories (100 Hz, 1 frame)", "no section with RX RY RZ TX TY TZ"])
    return out


def test_every_vendor_inspect_reads_as_text_without_python_reprs(tmp_path):
    files = vendor_files(tmp_path)
    for name, (path, fragments) in files.items():
        d = inspect_file(path)
        text = format_inspect(d)
        assert not REPR.search(text), (name, REPR.search(text).group(), text)
        for frag in fragments:
            assert frag in text, (name, frag, text)
        json.loads(json.dumps(d))  # --json: plain data


def test_real_vendor_files_inspect_as_text(realdata):
    paths = sorted((realdata / "qtm_6d_tsv").glob("*.tsv")) + sorted((realdata / "motive_csv").glob("*.csv"))
    assert len(paths) >= 3
    for path in paths:
        text = format_inspect(inspect_file(path))
        assert not REPR.search(text), (path, text)
        assert "still needed  " in text  # several bodies; the Motive file also lacks units and order


def test_rows_are_aligned_and_needs_are_data(tmp_path):
    path, _ = vendor_files(tmp_path)["motive euler, nothing stated"]
    d = inspect_file(path)
    assert [n.split()[0] for n in d["needs"]] == ["length_unit", "euler_order", "body"]
    rows = [ln for ln in format_inspect(d).splitlines()[1:] if ln.startswith("  ") and not ln.startswith("   ")]
    labelled = [ln for ln in rows if not ln.startswith("  error:")]
    assert labelled and all(ln[16] != " " and ln[15] == " " for ln in labelled), labelled  # values in one column
    # once the options are given, nothing is still needed and the bodies read
    d = inspect_file(path, ReadOptions(length_unit="m", euler_order="XYZ", body="all"))
    assert d["needs"] == [] and d["error"] is None and len(d["trajectories"]) == 2


@pytest.mark.parametrize("maker", ["csv", "mcap"])
def test_csv_and_mcap_also_say_what_is_still_needed(tmp_path, maker):
    if maker == "csv":
        p = tmp_path / "norate.csv"
        p.write_text("x,y,z,qx,qy,qz,qw\n0,0,0,0,0,0,1\n")
        want = "rate HZ"
    else:
        p = tmp_path / "two.mcap"
        F.write_ros2_topics(p, {"/a": "geometry_msgs/msg/PoseStamped", "/b": "nav_msgs/msg/Odometry"})
        want = "topic NAME"
    d = inspect_file(p)
    assert d["needs"][0].startswith(want)
    text = format_inspect(d)
    assert f"still needed  {want}" in text and "None" not in text and "{" not in text


def test_the_command_prints_the_same_text(tmp_path):
    from typer.testing import CliRunner

    from rbgp_cli.cli.app import app

    files = vendor_files(tmp_path)
    paths = [str(files[k][0]) for k in ("qtm current", "motive euler, nothing stated", "vicon")]
    res = CliRunner().invoke(app, ["inspect", *paths])
    # the Motive file cannot be read without --length-unit and --euler-order: described, and exit 2
    assert res.exit_code == 2 and "1 of 3 files could not be read" in res.stderr, res.stderr
    assert not REPR.search(res.stdout), res.stdout
    assert res.stdout.count("still needed  ") == 2 and res.stdout.count(": Vicon CSV (") == 1
    # the library names the parameters (length_unit, body), the command its flags, in text and JSON
    assert "still needed  --length-unit m|cm|mm" in res.stdout and "--euler-order XYZ" in res.stdout
    assert "--body NAME, or all for every body (2 bodies)" in res.stdout and "length_unit" not in res.stdout
    d = json.loads(CliRunner().invoke(app, ["inspect", paths[1], "--json"]).stdout)
    assert d["format"] == "motive" and d["needs"][0].startswith("--length-unit")
    assert [n.split()[0] for n in d["needs"]] == ["--length-unit", "--euler-order", "--body"]
