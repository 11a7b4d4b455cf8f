"""Data folders as users have them: takes next to a README, a LICENSE, notes, .DS_Store, calibration
files and other exports. rbgp reads what is pose data, skips the rest with one warning naming it, and
fails only when nothing is left; a file named explicitly that is not pose data is still an error."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

from rbgp_cli.errors import InputError, NotPoseData, RbgpWarning
from rbgp_cli.io import read as rread
from rbgp_cli.io.options import ReadOptions

from tests.hostile import builders as B

from . import mcap_fixtures as F

LICENSE = "MIT License\n\nCopyright (c) 2024 The Lab\n\nPermission is hereby granted, free of charge, to any person\n"
README = "# Shoe handover takes\n\nThree takes, 100 Hz, metres.\n\n| file | take |\n|---|---|\n| demo_0.csv | 1 |\n"
QTM_3D = ("NO_OF_FRAMES\t2\nNO_OF_CAMERAS\t8\nNO_OF_MARKERS\t2\nFREQUENCY\t100\nDATA_INCLUDED\t3D\n"
          "MARKER_NAMES\tm1\tm2\nFrame\tTime\tm1 X\tm1 Y\tm1 Z\tm2 X\tm2 Y\tm2 Z\n"
          "1\t0.00\t1\t2\t3\t4\t5\t6\n2\t0.01\t1\t2\t3\t4\t5\t6\n")
MOTIVE_MARKERS = ("Format Version,1.23,Take Name,t,Export Frame Rate,120,Length Units,Meters\n\n"
                  ",Type,Marker,Marker,Marker\n,Name,m1,m1,m1\n,ID,1,1,1\n,,Position,Position,Position\n"
                  "Frame,Time (Seconds),X,Y,Z\n0,0,1,2,3\n1,0.008,1,2,3\n")


def user_folder(root: Path, takes: int = 3) -> tuple[Path, dict]:
    """``takes`` demonstrations and, beside them, what recording folders hold. Returns the folder and
    {file name: the reason it is skipped}."""
    d = root / "data"
    d.mkdir()
    for k in range(takes):
        B.write_csv(d / f"demo_{k}.csv", B.smooth_motion(seed=k, name=f"demo_{k}"))
    others = {
        "LICENSE": (LICENSE, "no pose columns"),
        "README.md": (README, "no pose columns"),
        "notes.txt": ("take 2: the subject dropped the shoe, redo\n", "no pose columns"),
        "calibration.xml": ('<?xml version="1.0"?>\n<calibration><camera id="1" fx="1200.5"/></calibration>\n',
                            "no pose columns"),
        "markers.csv": ("time,x,y,z\n0,0.1,0.2,0.3\n0.01,0.1,0.2,0.3\n", "no pose columns"),
        "imu.csv": ("time,qx,qy,qz,qw\n0,0,0,0,1\n0.01,0,0,0,1\n", "no position columns"),
        "take_3d.tsv": (QTM_3D, "QTM 3D data, not 6D"),
        "markers_only.csv": (MOTIVE_MARKERS, "no rigid bodies, only markers"),
        "empty.csv": ("", "empty"),
    }
    for name, (text, _) in others.items():
        (d / name).write_text(text)
    (d / ".DS_Store").write_bytes(b"\x00\x00\x00\x01Bud1\x00\x00\x10\x00\x00\x00\x08\x00" * 40)
    (d / "photo.jpg").write_bytes(b"\xff\xd8\xff\xe0\x00\x10JFIF\x00" + bytes(range(256)) * 20)
    F.write_strings(d / "chatter.mcap")
    (d / "sub").mkdir()  # not searched
    B.write_csv(d / "sub" / "nested.csv")
    reasons = {name: why for name, (_, why) in others.items()}
    reasons.update({".DS_Store": "not a text file", "photo.jpg": "not a text file", "chatter.mcap": "no pose topic"})
    return d, reasons


def test_a_folder_with_a_licence_readme_and_other_files_reads_only_the_takes(tmp_path):
    d, reasons = user_folder(tmp_path)
    with pytest.warns(RbgpWarning) as record:
        trajs, listing = rread.read_sources([str(d)])
    assert [t.name for t in trajs] == ["demo_0", "demo_1", "demo_2"]
    assert listing.files == [str(d / f"demo_{k}.csv") for k in range(3)]
    assert {Path(p).name: why for p, why in listing.skipped} == reasons
    notes = [str(w.message) for w in record]
    assert len(notes) == 1  # ONE note, counting and naming the skipped files
    note = notes[0]
    assert note.startswith(f"{d}: skipped {len(reasons)} of {len(reasons) + 3} files that hold no pose data: ")
    names = sorted(reasons)
    assert all(name in note for name in names[:8]) and not any(name in note for name in names[8:])
    assert "and 4 more" in note and "\n" not in note
    assert "LICENSE, README.md, calibration.xml, markers.csv (no pose columns)" in note  # grouped by reason


def test_an_explicitly_named_file_that_is_not_pose_data_stays_an_error(tmp_path):
    d, _ = user_folder(tmp_path)
    with pytest.raises(NotPoseData, match=r"LICENSE: no rotation columns found \(columns are MIT, License\)"):
        rread.read_demonstrations([str(d / "LICENSE")])
    with pytest.raises(InputError, match="chatter.mcap: no pose topic found"):
        rread.read_demonstrations([str(d), str(d / "chatter.mcap")])
    with pytest.raises(InputError, match=r"take_3d\.tsv: this QTM file holds 3D data, not 6DOF"):
        rread.read_demonstrations([str(d / "take_3d.tsv")])


def test_pose_data_with_a_problem_in_a_folder_is_still_an_error(tmp_path):
    """Skipping is for files that are not pose data; a take with a bad cell must not vanish silently."""
    d, _ = user_folder(tmp_path)
    bad = d / "demo_1.csv"
    lines = bad.read_text().splitlines()
    lines[5] = lines[5].replace(lines[5].split(",")[2], "oops", 1)
    bad.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match=r"demo_1\.csv:6: non-numeric value 'oops'"):
        rread.read_demonstrations([str(d)])
    partial = d / "demo_2.csv"  # a quaternion missing a component: pose columns, one of them misnamed
    partial.write_text("t,x,y,z,qx,qy,qz,w_\n0,0,0,0,0,0,0,1\n")
    bad.unlink()
    with pytest.raises(InputError, match=r"demo_2\.csv: rotation column 'qw' not found"):
        rread.read_demonstrations([str(d)])


def test_a_folder_with_nothing_usable_says_what_it_found(tmp_path):
    d, reasons = user_folder(tmp_path, takes=0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the error says it all; no separate note
        with pytest.raises(InputError) as info:
            rread.read_demonstrations([str(d)])
    msg = str(info.value)
    assert msg.startswith(f"{d}: no pose data in the directory: ") and "\n" not in msg
    assert "LICENSE, README.md" in msg and "(no pose columns)" in msg and "and 4 more" in msg
    assert "; 1 subdirectories are not searched" in msg and "rbgp inspect FILE" in msg


def test_a_pattern_is_read_like_a_folder(tmp_path):
    d, _ = user_folder(tmp_path)
    pattern = str(d / "*m*")  # 3 takes and 7 others (a pattern's * does not match hidden files)
    with pytest.warns(RbgpWarning, match=r"\*m\*: skipped 7 of 10 files .*: README\.md, calibration\.xml"):
        trajs = rread.read_demonstrations([pattern])
    assert [t.name for t in trajs] == ["demo_0", "demo_1", "demo_2"]
    with pytest.raises(InputError, match=r"no file matches this pattern"):
        rread.read_demonstrations([str(d / "*.c3d")])


def test_skipped_files_are_judged_from_their_head_without_being_read(tmp_path, monkeypatch):
    """Cheap: a big file that is not pose data is never parsed (only its first 8 KiB are looked at),
    and a take is parsed once."""
    d, _ = user_folder(tmp_path, takes=2)
    rng = np.random.default_rng(0)
    (d / "video.mp4").write_bytes(b"\x00\x00\x00\x18ftypmp42" + rng.bytes(4_000_000))
    (d / "marker_log.csv").write_text("time,x,y,z\n" + "0.01,1.5,2.5,3.5\n" * 300_000)
    opened = []
    real = rread.read_file
    monkeypatch.setattr(rread, "read_file", lambda src, options=None, seen=None: opened.append(Path(src).name) or real(src, options, seen))
    with pytest.warns(RbgpWarning, match="skipped 14 of 16 files"):
        trajs, listing = rread.read_sources([str(d)])
    assert len(trajs) == 2
    assert {Path(p).name: r for p, r in listing.skipped}["video.mp4"] == "not a text file"
    assert {Path(p).name: r for p, r in listing.skipped}["marker_log.csv"] == "no pose columns"
    # the readers saw the takes, and only the files whose head cannot tell (vendor exports, MCAP)
    assert opened == ["chatter.mcap", "demo_0.csv", "demo_1.csv", "markers_only.csv"]


def test_skip_reason_from_the_head(tmp_path):
    """What the head tells, file by file (None: pose data, or read it to know)."""
    cases = {
        "t,x,y,z,qx,qy,qz,qw\n0,0,0,0,0,0,0,1\n": None,
        "# rbgp trajectories\ntrajectory,t,x,y,z,qx,qy,qz,qw\n": None,
        "x,y,z,qx,qy,qz\n": None,  # pose columns with a problem: the reader says which
        "t,qx,qy,qz,qw\n0,0,0,0,1\n": "no position columns",
        "   \n\n": "empty",
        "# only\n# comments\n": "no table",
        "0,1,2\n3,4,5\n": "no header line",
        "a|b|c\n1|2|3\n": "not a table",
        "frame,u,v\n1,320,240\n": "no pose columns",
    }
    for k, (text, expected) in enumerate(cases.items()):
        p = tmp_path / f"f{k}.csv"
        p.write_text(text)
        assert rread.skip_reason(p) == expected, text
    long_comment = tmp_path / "long.csv"  # the header lies beyond the first 8 KiB: read it to know
    long_comment.write_text("# " + "x" * 10_000 + "\nt,x,y,z,qx,qy,qz,qw\n0,0,0,0,0,0,0,1\n")
    assert rread.skip_reason(long_comment) is None
    readme = tmp_path / "README"
    readme.write_text(README)
    assert rread.skip_reason(readme, ReadOptions(format="mcap")) == "not an MCAP file"
    assert rread.skip_reason(readme, ReadOptions(format="motive")) == "not a Motive export"
    mapped = tmp_path / "odd.csv"  # --columns maps names the sniffer would not know
    mapped.write_text("stamp,px,py,pz,ox,oy,oz,ow\n0,0,0,0,0,0,0,1\n0.1,0,0,0,0,0,0,1\n")
    assert rread.skip_reason(mapped) == "no pose columns"
    opts = ReadOptions(columns={"qx": "ox", "qy": "oy", "qz": "oz", "qw": "ow", "t": "stamp"})
    assert rread.skip_reason(mapped, opts) is None
    assert rread.skip_reason(readme, opts) == "no column 'ox'"
