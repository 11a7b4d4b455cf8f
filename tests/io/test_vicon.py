"""Vicon CSV reader: format facts on hand-built synthetic files (independent of export.py)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rbgp_cli.errors import InputError, RbgpWarning
from rbgp_cli.io import vicon
from rbgp_cli.io.options import ReadOptions


def axis_angle_quat(axis, angle_deg):
    """The quaternion (x, y, z, w) of a rotation by ``angle_deg`` about ``axis``, written out by hand."""
    u = np.asarray(axis, float) / np.linalg.norm(axis)
    h = np.radians(angle_deg) / 2
    return np.array([*(np.sin(h) * u), np.cos(h)])


def same_rotation(q1, q2, atol=1e-12):
    return np.allclose(q1, q2, atol=atol) or np.allclose(q1, -q2, atol=atol)


def section(title, rate, blocks, data, *, units=True, d=","):
    """One section: ``blocks`` [(name, [column labels], [units])], ``data`` rows after Frame, Sub Frame."""
    names = ["", ""] + [c for name, labels, _ in blocks for c in [name] + [""] * (len(labels) - 1)]
    cols = ["Frame", "Sub Frame"] + [c for _, labels, _ in blocks for c in labels]
    unit_row = ["", ""] + [u for _, _, us in blocks for u in us]
    rows = [[title], [str(rate)], names, cols] + ([unit_row] if units else [])
    rows += [[str(i + 1), "0"] + [v if isinstance(v, str) else repr(float(v)) for v in r] for i, r in enumerate(data)]
    return "\n".join(d.join(r) for r in rows) + "\n"


POSE = ["RX", "RY", "RZ", "TX", "TY", "TZ"]
POSE_UNITS = ["deg", "deg", "deg", "mm", "mm", "mm"]
# 120° about (1, 2, 2)/3, at (100, -200, 300) mm
HELICAL = [40.0, 80.0, 80.0]
ROW = [*HELICAL, 100.0, -200.0, 300.0]


def segments(data, names=("Subj:Pelvis",), units=True, d=",", rate=100):
    return section("Segments", rate, [(n, POSE, POSE_UNITS) for n in names], data, units=units, d=d)


def write(tmp_path, text, name="trial.csv"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_helical_angles_are_a_rotation_vector_in_degrees(tmp_path):
    (tr,) = vicon.read(write(tmp_path, segments([ROW, ROW])))
    assert same_rotation(tr.quat[0], axis_angle_quat([1, 2, 2], 120.0))
    np.testing.assert_allclose(tr.position[0], [0.1, -0.2, 0.3], rtol=1e-15)
    np.testing.assert_array_equal(tr.t, [0.0, 0.01])
    assert tr.info["rotation_source"].startswith("helical") and tr.info["length_unit"] == "mm"
    assert tr.name == "Subj:Pelvis" and tr.info["format"] == "vicon"


def test_euler_rotation_needs_an_order(tmp_path):
    path = write(tmp_path, segments([[30.0, -40.0, 110.0, 0, 0, 0]]))
    with pytest.raises(InputError, match="rotation euler needs .*; give it with euler_order") as err:
        vicon.read(path, ReadOptions(rotation="euler"))
    assert err.value.param == ("rotation", "euler_order")
    (tr,) = vicon.read(path, ReadOptions(rotation="euler", euler_order="XYZ"))
    c = {a: (np.cos(np.radians(v)), np.sin(np.radians(v))) for a, v in zip("xyz", (30.0, -40.0, 110.0))}
    rx = np.array([[1, 0, 0], [0, c["x"][0], -c["x"][1]], [0, c["x"][1], c["x"][0]]])
    ry = np.array([[c["y"][0], 0, c["y"][1]], [0, 1, 0], [-c["y"][1], 0, c["y"][0]]])
    rz = np.array([[c["z"][0], -c["z"][1], 0], [c["z"][1], c["z"][0], 0], [0, 0, 1]])
    np.testing.assert_allclose(Rotation.from_quat(tr.quat[0]).as_matrix(), rx @ ry @ rz, atol=1e-12)
    with pytest.raises(InputError, match="rotation 'quaternion' is unknown for Vicon"):
        vicon.read(path, ReadOptions(rotation="quaternion"))


@pytest.mark.parametrize("d", [",", ";", "\t"])
def test_delimiters(tmp_path, d):
    (tr,) = vicon.read(write(tmp_path, segments([ROW], d=d)))
    assert same_rotation(tr.quat[0], axis_angle_quat([1, 2, 2], 120.0))
    assert vicon.sniff(segments([ROW], d=d))


def test_semicolon_with_decimal_comma(tmp_path):
    text = segments([ROW], d=";").replace("100.0;", "100,5;").replace("40.0;", "40,0;")
    (tr,) = vicon.read(write(tmp_path, text))
    np.testing.assert_allclose(tr.position[0], [0.1005, -0.2, 0.3], rtol=1e-15)


def test_only_the_segments_section_gives_poses(tmp_path):
    joints = section("Joints", 100, [("Subj:Knee", POSE, POSE_UNITS)], [[1, 2, 3, 4, 5, 6]] * 2)
    traj = section("Trajectories", 100, [("Subj:LASI", ["X", "Y", "Z"], ["mm"] * 3)], [[1, 2, 3]] * 2)
    devices = section("Devices", 1000, [("Force Plate", ["Fx", "Fy", "Fz"], ["N"] * 3)], [[0, 0, 9.81]] * 4)
    text = devices + "\n" + joints + "\n" + segments([ROW + ROW] * 2, names=("Subj:Pelvis", "Subj:Thigh")) + "\n" + traj
    path = write(tmp_path, text)
    trs = vicon.read(path, ReadOptions(body="all"))
    assert [t.name for t in trs] == ["Subj:Pelvis", "Subj:Thigh"] and all(len(t) == 2 for t in trs)
    assert trs[0].info["sections"] == ["Devices", "Joints", "Segments", "Trajectories"]
    d = vicon.describe(path)
    assert d["pose_section"] == "Segments" and d["bodies"] == ["Subj:Pelvis", "Subj:Thigh"]
    assert [s["title"] for s in d["sections"]] == ["Devices", "Joints", "Segments", "Trajectories"]
    assert d["sections"][0]["rate_hz"] == 1000.0 and d["sections"][0]["frames"] == 4


def test_markers_only_or_joints_only_are_errors(tmp_path):
    traj = section("Trajectories", 100, [("Subj:LASI", ["X", "Y", "Z"], ["mm"] * 3)], [[1, 2, 3]])
    with pytest.raises(InputError, match="no RX,RY,RZ,TX,TY,TZ .*sections are Trajectories"):
        vicon.read(write(tmp_path, traj))
    joints = section("Joints", 100, [("Subj:Knee", POSE, POSE_UNITS)], [[1, 2, 3, 4, 5, 6]])
    with pytest.raises(InputError, match="relative to the parent.*Segments"):
        vicon.read(write(tmp_path, joints))


def test_body_selection_by_segment_name(tmp_path):
    path = write(tmp_path, segments([ROW + [0, 0, 0, 1, 2, 3]], names=("Subj:Pelvis", "Subj:Thigh")))
    with pytest.raises(InputError, match="2 rigid bodies: 'Subj:Pelvis', 'Subj:Thigh'"):
        vicon.read(path)
    (thigh,) = vicon.read(path, ReadOptions(body="Thigh"))
    assert thigh.name == "Subj:Thigh"
    np.testing.assert_allclose(thigh.position[0], [0.001, 0.002, 0.003], rtol=1e-15)
    with pytest.raises(InputError, match="did you mean body 'Subj:Thigh'"):
        vicon.read(path, ReadOptions(body="Thihg"))


def test_units(tmp_path):
    text = segments([ROW]).replace(",mm,mm,mm", ",m,m,m")
    (tr,) = vicon.read(write(tmp_path, text))
    np.testing.assert_allclose(tr.position[0], [100.0, -200.0, 300.0], rtol=1e-15)
    radians = segments([[0.0, 0.0, np.pi / 2, 0, 0, 0]]).replace("deg", "rad")
    (tr,) = vicon.read(write(tmp_path, radians))
    assert same_rotation(tr.quat[0], axis_angle_quat([0, 0, 1], 90.0))
    no_units = write(tmp_path, segments([ROW], units=False))
    with pytest.raises(InputError, match="no units line.*length_unit") as err:
        vicon.read(no_units)
    assert err.value.row == 4
    (tr,) = vicon.read(no_units, ReadOptions(length_unit="cm"))
    np.testing.assert_allclose(tr.position[0], [1.0, -2.0, 3.0], rtol=1e-15)


def test_rate(tmp_path):
    (tr,) = vicon.read(write(tmp_path, segments([ROW] * 3, rate=250)))
    np.testing.assert_array_equal(tr.t, np.arange(3) / 250.0)
    assert tr.info["rate_hz"] == 250.0
    path = write(tmp_path, segments([ROW] * 3, rate="n/a"))
    with pytest.raises(InputError, match="rate line .* not a number.*with rate HZ"):
        vicon.read(path)
    (tr,) = vicon.read(path, ReadOptions(rate=50.0))
    np.testing.assert_array_equal(tr.t, np.arange(3) / 50.0)
    with pytest.warns(RbgpWarning, match="rate 50 is ignored: the file states 100 Hz"):
        vicon.read(write(tmp_path, segments([ROW] * 3)), ReadOptions(rate=50.0))


def test_blank_cells_are_lost_frames(tmp_path):
    data = [ROW, [""] * 6, ROW[:3] + ["", "", ""], ROW]
    (tr,) = vicon.read(write(tmp_path, segments(data)))
    assert np.isnan(tr.quat[[1, 2]]).all() and np.isnan(tr.position[[1, 2]]).all()
    assert np.isfinite(tr.quat[[0, 3]]).all() and tr.info["lost_frames"] == 2
    np.testing.assert_array_equal(tr.t, np.arange(4) / 100.0)


def test_a_file_whose_cells_are_all_blank_is_all_lost(tmp_path):
    (tr,) = vicon.read(write(tmp_path, segments([[""] * 6, [""] * 6])))
    assert np.isnan(tr.quat).all() and np.isnan(tr.position).all() and tr.info["lost_frames"] == 2


def test_truncated_and_non_numeric_rows(tmp_path):
    text = segments([ROW] * 3)
    with pytest.raises(InputError, match="truncated row") as err:
        vicon.read(write(tmp_path, text.rstrip("\n").rsplit(",", 2)[0] + "\n"))
    assert err.value.row == 8  # title, rate, names, columns, units, rows 6..8
    with pytest.raises(InputError, match="'x1' in column TY is not a number") as err:
        vicon.read(write(tmp_path, text.replace("-200.0", "x1", 1)))
    assert err.value.row == 6


def test_not_vicon(tmp_path):
    with pytest.raises(InputError, match="no 'Frame,Sub Frame"):
        vicon.read(write(tmp_path, "a,b,c\n1,2,3\n"))


def test_sniff():
    assert vicon.sniff(segments([ROW]))
    assert vicon.sniff("Trajectories\n100\n,,s:m\nFrame,Sub Frame,X,Y,Z\n,,mm,mm,mm\n")
    assert not vicon.sniff("Format Version,1.23,Take Name,x\n\n,Type,Rigid Body\n")
    assert not vicon.sniff("NO_OF_FRAMES\t3\nFREQUENCY\t100\n")
    assert not vicon.sniff("Frame,Sub Frame,RX\n")  # no section title
    assert not vicon.sniff("")
