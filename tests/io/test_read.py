"""rbgp_cli.io.read (format sniffing, dispatch, directories, stdin) and rbgp_cli.io.inspect."""

from __future__ import annotations

import io
import json
import os
import subprocess
import sys
import threading

import numpy as np
import pytest

from rbgp_cli.dynamics.trajectory import Trajectory
from rbgp_cli.errors import InputError, RbgpWarning
from rbgp_cli.io import read as rread
from rbgp_cli.io.csv import write_trajectories_csv
from rbgp_cli.io.inspect import format_inspect, inspect_file
from rbgp_cli.io.options import ReadOptions

from tests.helpers import NonSeekable

from . import mcap_fixtures as F

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

CSV_TEXT = "t,x,y,z,qx,qy,qz,qw\n0,0,0,0,0,0,0,1\n0.1,0.1,0,0,0,0,0,1\n0.2,0.2,0,0,0,0,0,1\n"


@pytest.mark.parametrize(
    "head, fmt",
    [
        (b"\x89MCAP0\r\n\x01rest", "mcap"),
        (b"NO_OF_FRAMES\t513\r\nNO_OF_CAMERAS\t3\r\n", "qtm"),
        (b"\xef\xbb\xbfFILE_VERSION\t2.0.0\nNO_OF_FRAMES\t10\n", "qtm"),
        (b"EVENT\tx\t1\t0.1\nFrame\tTime\tbody X\tY\n", "qtm"),
        (b"Format Version,1.23,Take Name,x\n\n,Type,Rigid Body\n", "motive"),
        (b"\nSegments\n100\n,,Sub:Seg\nFrame,Sub Frame,RX\n", "vicon"),
        (b"Trajectories;;;\n120;;;\n", "vicon"),
        (b"Segments,,,\nnot a rate\n", "csv"),
        (CSV_TEXT.encode(), "csv"),
        (b"", "csv"),
    ],
)
def test_detect_format_from_content(head, fmt):
    assert rread.detect_format(head) == fmt


def test_detect_format_from_path_ignores_the_extension(tmp_path):
    p = tmp_path / "really_mcap.csv"
    F.write_strings(p)
    assert rread.detect_format(p) == "mcap"


def test_read_file_dispatches_to_csv_and_mcap(tmp_path):
    c = tmp_path / "a.csv"
    c.write_text(CSV_TEXT)
    assert rread.read_file(c)[0].info["format"] == "csv"
    m = tmp_path / "b.mcap"
    F.write_ros2(m, "geometry_msgs/msg/PoseStamped")
    assert rread.read_file(m)[0].info["format"] == "mcap"


@pytest.mark.parametrize("fmt, head", [("qtm", "NO_OF_FRAMES\t3\n"), ("motive", "Format Version,1.23\n"), ("vicon", "Segments\n100\n")])
def test_vendor_formats_are_dispatched_lazily(tmp_path, monkeypatch, fmt, head):
    from dataclasses import replace

    from rbgp_cli.io import formats

    seen = {}

    def fake_read(path, options):
        seen["path"], seen["options"] = str(path), options
        return [Trajectory(t=[0.0, 1.0], quat=[[0, 0, 0, 1]] * 2, position=[[0, 0, 0]] * 2, name=fmt, source=str(path))]

    p = tmp_path / "export.txt"
    p.write_text(head)
    opts = ReadOptions(body="shoe")
    with formats.registered(replace(formats.get(fmt), read=fake_read), replace=True):  # dispatch goes through the registry
        trajs = rread.read_file(p, opts)
        assert trajs[0].name == fmt and seen == {"path": str(p), "options": opts}
        # stdin goes through a temporary file, but the source says "-"
        trajs = rread.read_demonstrations(["-"], opts, stdin=io.BytesIO(head.encode()))
    assert trajs[0].source == "-" and seen["path"] != "-"
    assert not os.path.exists(seen["path"])
    assert formats.get(fmt).read is not fake_read


def test_format_option_overrides_sniffing(tmp_path):
    p = tmp_path / "a.csv"
    p.write_text(CSV_TEXT)
    with pytest.raises(InputError, match="not an MCAP file"):
        rread.read_file(p, ReadOptions(format="mcap"))
    with pytest.raises(InputError, match=r"unknown format 'cvs'.*did you mean 'csv'"):
        rread.read_file(p, ReadOptions(format="cvs"))


def test_missing_file_suggests_a_close_name(tmp_path):
    (tmp_path / "demo_01.csv").write_text(CSV_TEXT)
    with pytest.raises(InputError, match=r"demo_1\.csv: file not found; did you mean .*demo_01\.csv"):
        rread.read_file(tmp_path / "demo_1.csv")


def test_missing_file_suggests_no_name_that_only_shares_the_suffix(tmp_path):
    (tmp_path / "mot_rest.csv").write_text(CSV_TEXT)
    with pytest.raises(InputError, match=r"motion_025\.csv: file not found; check the path"):
        rread.read_file(tmp_path / "motion_025.csv")
    with pytest.raises(InputError, match=r"did you mean .*mot_rest\.csv"):
        rread.read_file(tmp_path / "mot_rset.csv")
    (tmp_path / "hand_raise_csv").mkdir()
    with pytest.raises(InputError, match=r"did you mean .*hand_raise_csv"):  # a folder's name, without a suffix
        rread.read_file(tmp_path / "hand_rise_csv")


def test_a_missing_quaternion_column_is_not_matched_to_a_position_column(tmp_path):
    f = tmp_path / "d.csv"
    f.write_text("time_s,x_m,y_m,z_m,qw,qx,qy\n0,0,0,0,1,0,0\n0.1,0.1,0,0,1,0,0\n")
    with pytest.raises(InputError, match=r"rotation column 'qz' not found") as err:
        rread.read_file(f)
    assert "z_m" not in str(err.value).split("(columns are")[1].split(")", 1)[1], str(err.value)


def test_a_binary_file_is_refused_naming_every_format_rbgp_reads(tmp_path):
    f = tmp_path / "d.csv"
    f.write_bytes(bytes(range(256)) * 8)
    with pytest.raises(InputError, match="not a text file") as err:
        rread.read_file(f)
    assert all(w in str(err.value) for w in ("C3D", "BVH", "MCAP", "Qualisys")), str(err.value)


def test_a_read_option_no_file_uses_is_said_once_and_one_some_file_uses_is_not(tmp_path):
    for k in range(3):
        (tmp_path / f"d{k}.csv").write_text(CSV_TEXT)
    with pytest.warns(RbgpWarning) as caught:
        rread.read_sources([str(tmp_path)], ReadOptions(body="Hand_R"))
    said = [str(w.message) for w in caught if "body was given" in str(w.message)]
    assert len(said) == 1 and "generic CSV" in said[0] and "bvh" in said[0], said
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error", RbgpWarning)
        rread.read_sources([str(tmp_path)], ReadOptions(columns={"t": "t"}))  # CSV uses columns: nothing said


def test_directory_empty_and_unreadable_files(tmp_path):
    with pytest.raises(InputError, match="is a directory"):
        rread.read_file(tmp_path)
    e = tmp_path / "e.csv"
    e.write_bytes(b"")
    with pytest.raises(InputError, match=r"e\.csv: the file is empty"):
        rread.read_file(e)
    if os.geteuid() != 0:  # root reads anything
        u = tmp_path / "u.csv"
        u.write_text(CSV_TEXT)
        u.chmod(0)
        with pytest.raises(InputError, match="cannot read"):
            rread.read_file(u)


def test_expand_sources_and_directories(tmp_path):
    """A directory stands for its files (sorted, not recursive); the content decides what is data, not
    the suffix: notes.txt with pose columns is read, README.md is not."""
    d = tmp_path / "data"
    d.mkdir()
    for name in ("b.csv", "a.CSV", "c.mcap", "notes.txt"):
        (d / name).write_text(CSV_TEXT)
    (d / "README.md").write_text("# Takes\n\nRecorded on Monday.\n")
    (d / "sub").mkdir()
    with pytest.warns(RbgpWarning, match=r"data: skipped 1 of 5 files that hold no pose data: README\.md \(no pose columns\)"):
        got = rread.expand_sources([str(d), "-", "x.csv"])
    assert got == [str(d / n) for n in ("a.CSV", "b.csv", "c.mcap", "notes.txt")] + ["-", "x.csv"]
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="empty: the directory is empty"):
        rread.expand_sources([str(tmp_path / "empty")])
    (tmp_path / "empty" / "take1").mkdir()
    with pytest.raises(InputError, match="1 subdirectories, which are not searched"):
        rread.expand_sources([str(tmp_path / "empty")])


def test_read_demonstrations_reads_a_directory_in_order(tmp_path):
    trajs = [Trajectory(t=np.arange(4) * 0.1, quat=np.tile([0, 0, 0, 1.0], (4, 1)), position=np.full((4, 3), k), name=f"d{k}")
             for k in range(3)]
    for k, tr in enumerate(trajs):
        write_trajectories_csv([tr], tmp_path / f"demo_{k}.csv")
    out = rread.read_demonstrations([str(tmp_path)])
    assert [t.position[0, 0] for t in out] == [0.0, 1.0, 2.0]


def test_stdin_csv_and_mcap(tmp_path):
    out = rread.read_demonstrations(["-"], stdin=io.BytesIO(CSV_TEXT.encode()))
    assert out[0].source == "-" and out[0].name == "stdin" and len(out[0]) == 3
    m = tmp_path / "b.mcap"
    stamps, pos, q = F.write_protobuf(m, "PoseInFrame")
    for stream in (io.BytesIO(m.read_bytes()), io.BufferedReader(NonSeekable(m.read_bytes(), chunk=5))):
        tr = rread.read_demonstrations(["-"], stdin=stream)[0]
        np.testing.assert_allclose(tr.position, pos[0], atol=1e-12)
        np.testing.assert_allclose(tr.t, stamps / 1e9, atol=1e-9)
        assert tr.source == "-:/pose"


def test_stdin_only_once_and_not_empty():
    with pytest.raises(InputError, match="more than once"):
        rread.read_demonstrations(["-", "-"], stdin=io.BytesIO(CSV_TEXT.encode()))
    with pytest.raises(InputError, match="input is empty"):
        rread.read_demonstrations(["-"], stdin=io.BytesIO(b""))


def test_stdin_terminal_is_refused():
    class Tty(io.BytesIO):
        def isatty(self):
            return True

    with pytest.raises(InputError, match="stdin is a terminal"):
        rread.read_demonstrations(["-"], stdin=Tty(CSV_TEXT.encode()))


def test_real_pipe_in_a_subprocess(tmp_path):
    """stdin of a real process is a non-seekable pipe."""
    m = tmp_path / "r.mcap"
    stamps, pos, q = F.write_ros2(m, "nav_msgs/msg/Odometry", n=300)
    code = ("import sys, json; from rbgp_cli.io.read import read_demonstrations; "
            "t = read_demonstrations(['-'])[0]; print(json.dumps([len(t), t.position[-1].tolist(), sys.stdin.buffer.seekable()]))")
    res = subprocess.run([sys.executable, "-c", code], input=m.read_bytes(), capture_output=True, cwd=REPO, timeout=120)
    assert res.returncode == 0, res.stderr.decode()
    n, last, seekable = json.loads(res.stdout)
    assert n == 300 and not seekable
    np.testing.assert_allclose(last, pos[0, -1], atol=1e-12)


def test_os_pipe_csv():
    r, w = os.pipe()
    th = threading.Thread(target=lambda: (os.write(w, CSV_TEXT.encode()), os.close(w)))
    th.start()
    with os.fdopen(r, "rb") as fh:
        out = rread.read_demonstrations(["-"], stdin=fh)
    th.join()
    np.testing.assert_allclose(out[0].position[:, 0], [0, 0.1, 0.2])


# -------------------------------------------------------------------------------------------- inspect
def test_inspect_csv(tmp_path):
    p = tmp_path / "demo.csv"
    t = np.array([0, 0.01, 0.02, 0.03, 0.08, 0.09, 0.10])
    rows = ["time_ms,x_mm,y_mm,z_mm,qw,qx,qy,qz,note"] + [f"{v * 1000},{k},2,3,1,0,0,0,a" for k, v in enumerate(t)]
    rows[3] = "20,,,,,,,,a"
    p.write_text("\n".join(rows) + "\n")
    d = inspect_file(p)
    assert d["format"] == "csv" and d["error"] is None
    taken = {c["name"]: c["taken_as"] for c in d["description"]["columns"]}
    assert taken["time_ms"] == "t" and taken["qw"] == "qw" and taken["note"] is None
    tr = d["trajectories"][0]
    assert tr["samples"] == 7 and tr["lost_frames"] == 1
    assert tr["rate_hz"] == pytest.approx(100.0)
    assert tr["gaps"]["count"] == 2 and tr["gaps"]["largest_s"] == pytest.approx(0.05)
    assert tr["length_unit"] == "mm" and tr["time_unit"] == "ms" and tr["rotation"] == "quaternion wxyz"
    assert tr["position_max_m"] == pytest.approx([0.006, 0.002, 0.003])
    json.dumps(d)  # plain data
    text = format_inspect(d)
    assert "time_ms" in text and "-> t [ms]" in text and "1 lost frames" in text and "2 gaps" in text


def test_inspect_reports_a_problem_instead_of_failing(tmp_path):
    p = tmp_path / "norate.csv"
    p.write_text("x,y,z,q0,q1,q2,q3\n0,0,0,0,0,0,1\n")
    d = inspect_file(p)
    assert "no time column" in d["error"] and d["trajectories"] == []
    assert [c["taken_as"] for c in d["description"]["columns"]] == ["x", "y", "z", "q0", "q1", "q2", "q3"]
    assert "error: " in format_inspect(d)


def test_inspect_mcap_lists_topics_and_every_pose_trajectory(tmp_path):
    p = tmp_path / "two.mcap"
    F.write_ros2_topics(p, {"/a": "geometry_msgs/msg/PoseStamped", "/b": "nav_msgs/msg/Odometry"})
    d = inspect_file(p)
    assert [t["topic"] for t in d["description"]["topics"]] == ["/a", "/b"]
    assert [t["name"] for t in d["trajectories"]] == ["/a", "/b"]
    assert d["trajectories"][1]["rate_hz"] == pytest.approx(100.0)
    assert "pose /a" in format_inspect(d)


def test_inspect_stdin(tmp_path):
    d = inspect_file("-", stdin=io.BytesIO(CSV_TEXT.encode()))
    assert d["path"] == "-" and d["format"] == "csv" and d["trajectories"][0]["samples"] == 3
    assert "rbgp-stdin" not in json.dumps(d)


def test_an_option_that_contradicts_the_file_is_applied_and_said_once(tmp_path):
    """length_unit mm on columns named x_m … is applied (the option wins) and said in one warning for the set; rate
    on files that have a time column is not used, and that is said too (before: both silent)."""
    text = "time_s,x_m,y_m,z_m,qx,qy,qz,qw\n0,1,0,0,0,0,0,1\n0.1,1.1,0,0,0,0,0,1\n0.2,1.2,0,0,0,0,0,1\n"
    for k in range(3):
        (tmp_path / f"d{k}.csv").write_text(text)
    with pytest.warns(RbgpWarning) as caught:
        trajs, _ = rread.read_sources([str(tmp_path)], ReadOptions(length_unit="mm", rate=100.0))
    said = [str(w.message) for w in caught]
    unit = [x for x in said if "length_unit mm was applied" in x]
    rate = [x for x in said if "rate 100 Hz was given" in x]
    assert len(unit) == 1 and "names say m" in unit[0] and len(rate) == 1 and "time_s" in rate[0], said
    np.testing.assert_allclose(trajs[0].position[:, 0], [1e-3, 1.1e-3, 1.2e-3])
    np.testing.assert_allclose(trajs[0].t, [0.0, 0.1, 0.2])
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error", RbgpWarning)
        rread.read_sources([str(tmp_path)], ReadOptions(length_unit="m"))  # agrees with the names: nothing said
