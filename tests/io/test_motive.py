"""Motive CSV reader: format facts on hand-built synthetic files (independent of export.py)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rbgp_cli.errors import InputError
from rbgp_cli.io import motive
from rbgp_cli.io.options import ReadOptions
from tests.helpers import rx, ry, rz




ELEMENTARY = {"X": rx, "Y": ry, "Z": rz}


def matrices(quat):
    return Rotation.from_quat(quat).as_matrix()


def first_line(rotation_type="XYZ", units="Centimeters", rate="120.000000"):
    pairs = [("Format Version", "1.23"), ("Take Name", "Take 2024-05-01 03.14.15 PM"), ("Capture Frame Rate", rate),
             ("Export Frame Rate", rate), ("Capture Start Time", "2024-05-01 03.14.15.926 PM"),
             ("Total Frames in Take", "3"), ("Total Exported Frames", "3")]
    if rotation_type is not None:
        pairs.append(("Rotation Type", rotation_type))
    if units is not None:
        pairs.append(("Length Units", units))
    pairs.append(("Coordinate Space", "Global"))
    return ",".join(f"{k},{v}" for k, v in pairs)


def motive_text(cols, data, *, first=None, labelled=True, parent=False, timecode=False, rate=120.0):
    """A Motive CSV: ``cols`` are (type, name, field, axis) per data column, ``data`` rows of cells."""
    meta = ["Frame", "Time (Seconds)"] + (["TimeCode"] if timecode else [])
    pad = [""] * (len(meta) - 2)

    def label(s):
        return s if labelled else ""

    lines = [first or first_line(), ""]
    rows = [["", label("Type")] + pad + [c[0] for c in cols],
            ["", label("Name")] + pad + [c[1] for c in cols],
            ["", label("ID")] + pad + [str(100 + sorted({c[1] for c in cols}).index(c[1])) for c in cols]]
    if parent:
        rows.append(["", label("Parent")] + pad + ["" if c[0] != "Bone" else "skel" for c in cols])
    rows.append(["", ""] + pad + [c[2] for c in cols])
    rows.append(meta + [c[3] for c in cols])
    for i, r in enumerate(data):
        rows.append([str(i), repr(i / rate)] + (["00:00:00:00.0"] if timecode else []) + [
            v if isinstance(v, str) else repr(float(v)) for v in r])
    return "\n".join(lines + [",".join(r) for r in rows]) + "\n"


def rigid_body(name, rot_axes="XYZ"):
    return [("Rigid Body", name, "Rotation", a) for a in rot_axes] + [
        ("Rigid Body", name, "Position", a) for a in "XYZ"]


def write(tmp_path, text, name="take.csv"):
    p = tmp_path / name
    p.write_text(text)
    return p


ANGLES = {"X": 30.0, "Y": -40.0, "Z": 110.0}
POS_CM = [12.5, 150.0, -30.0]


# ---------------------------------------------------------------- Euler convention
def test_euler_xyz_row_against_hand_computation(tmp_path):
    """Rotation Type XYZ is relative (intrinsic): first about X, then the new Y, then the new Z,
    R = Rx(X) Ry(Y) Rz(Z) (NaturalPoint: "Changes in Motive's Reported Euler Angles")."""
    path = write(tmp_path, motive_text(rigid_body("cup"), [[ANGLES["X"], ANGLES["Y"], ANGLES["Z"], *POS_CM]]))
    (tr,) = motive.read(path)
    np.testing.assert_allclose(matrices(tr.quat)[0], rx(30) @ ry(-40) @ rz(110), atol=1e-12)
    assert not np.allclose(matrices(tr.quat)[0], rz(110) @ ry(-40) @ rx(30), atol=1e-3)
    np.testing.assert_allclose(tr.position[0], [0.125, 1.5, -0.3], rtol=1e-15)
    assert tr.info["rotation_source"].startswith("euler XYZ deg (Rotation Type XYZ")
    assert tr.info["length_unit"] == "cm" and tr.name == "cup" and tr.t[0] == 0.0


@pytest.mark.parametrize("order", motive.EULER_TYPES)
def test_every_euler_rotation_type_is_intrinsic_in_its_order(tmp_path, order):
    path = write(tmp_path, motive_text(rigid_body("cup"), [[ANGLES["X"], ANGLES["Y"], ANGLES["Z"], *POS_CM]],
                                       first=first_line(rotation_type=order)))
    (tr,) = motive.read(path)
    a, b, c = order
    expected = ELEMENTARY[a](ANGLES[a]) @ ELEMENTARY[b](ANGLES[b]) @ ELEMENTARY[c](ANGLES[c])
    np.testing.assert_allclose(matrices(tr.quat)[0], expected, atol=1e-12)


def test_euler_angles_are_taken_from_the_column_of_their_axis(tmp_path):
    cols = rigid_body("cup", rot_axes="ZXY")
    path = write(tmp_path, motive_text(cols, [[ANGLES["Z"], ANGLES["X"], ANGLES["Y"], *POS_CM]]))
    (tr,) = motive.read(path)
    np.testing.assert_allclose(matrices(tr.quat)[0], rx(30) @ ry(-40) @ rz(110), atol=1e-12)


def test_euler_order_option_overrides_the_header(tmp_path):
    path = write(tmp_path, motive_text(rigid_body("cup"), [[ANGLES["X"], ANGLES["Y"], ANGLES["Z"], *POS_CM]]))
    (extrinsic,) = motive.read(path, ReadOptions(euler_order="zyx"))  # extrinsic z, y, x == intrinsic X, Y, Z
    np.testing.assert_allclose(matrices(extrinsic.quat)[0], rx(30) @ ry(-40) @ rz(110), atol=1e-12)
    (zyx,) = motive.read(path, ReadOptions(euler_order="ZYX"))
    np.testing.assert_allclose(matrices(zyx.quat)[0], rz(110) @ ry(-40) @ rx(30), atol=1e-12)
    assert "euler_order" in zyx.info["rotation_source"]


def test_degrees_false_reads_radians(tmp_path):
    path = write(tmp_path, motive_text(rigid_body("cup"), [[0.5, -0.25, 1.0, *POS_CM]]))
    (tr,) = motive.read(path, ReadOptions(degrees=False))
    np.testing.assert_allclose(matrices(tr.quat)[0], rx(np.degrees(0.5)) @ ry(np.degrees(-0.25)) @ rz(np.degrees(1.0)),
                               atol=1e-12)


def test_quaternion_columns_are_xyzw(tmp_path):
    q = Rotation.from_euler("xyz", [10, 20, 30], degrees=True).as_quat()
    path = write(tmp_path, motive_text(rigid_body("cup", rot_axes="XYZW"), [[*q, *POS_CM]],
                                       first=first_line(rotation_type=None, units="Millimeters")))
    (tr,) = motive.read(path)
    np.testing.assert_allclose(tr.quat[0], q, rtol=1e-15)
    np.testing.assert_allclose(tr.position[0], np.array(POS_CM) / 1000, rtol=1e-15)
    assert tr.info["rotation_source"] == "quaternion xyzw"


@pytest.mark.parametrize("units, scale", [("Meters", 1.0), ("Centimeters", 0.01), ("Millimeters", 0.001)])
def test_length_units_from_the_header(tmp_path, units, scale):
    path = write(tmp_path, motive_text(rigid_body("cup"), [[0, 0, 0, *POS_CM]], first=first_line(units=units)))
    (tr,) = motive.read(path)
    np.testing.assert_allclose(tr.position[0], np.array(POS_CM) * scale, rtol=1e-15)
    (override,) = motive.read(path, ReadOptions(length_unit="mm"))
    np.testing.assert_allclose(override.position[0], np.array(POS_CM) * 1e-3, rtol=1e-15)


# ---------------------------------------------------------------- missing header facts
def test_missing_length_units_names_the_option(tmp_path):
    path = write(tmp_path, motive_text(rigid_body("cup"), [[0, 0, 0, *POS_CM]], first=first_line(units=None)))
    with pytest.raises(InputError) as err:
        motive.read(path)
    assert "does not state Length Units" in str(err.value) and "length_unit m|cm|mm" in str(err.value)
    assert "positions reach 150" in str(err.value) and err.value.row == 1
    (tr,) = motive.read(path, ReadOptions(length_unit="cm"))
    assert tr.info["length_unit"] == "cm"


def test_missing_rotation_type_for_euler_names_the_option(tmp_path):
    path = write(tmp_path, motive_text(rigid_body("cup"), [[0, 0, 0, *POS_CM]], first=first_line(rotation_type=None)))
    with pytest.raises(InputError, match="Rotation Type.*euler_order XYZ"):
        motive.read(path)


def test_both_missing_are_named_in_one_error(tmp_path):
    first = first_line(rotation_type=None, units=None)
    path = write(tmp_path, motive_text(rigid_body("cup"), [[0, 0, 0, *POS_CM]], first=first))
    with pytest.raises(InputError, match="states neither Length Units nor .*length_unit.* and euler_order"):
        motive.read(path)


def test_unknown_length_units(tmp_path):
    path = write(tmp_path, motive_text(rigid_body("cup"), [[0, 0, 0, *POS_CM]], first=first_line(units="Inches")))
    with pytest.raises(InputError, match="unknown Length Units 'Inches'.*length_unit"):
        motive.read(path)


def test_quaternion_rotation_type_with_three_columns_is_an_error(tmp_path):
    path = write(tmp_path, motive_text(rigid_body("cup"), [[0, 0, 0, *POS_CM]], first=first_line("Quaternion")))
    with pytest.raises(InputError, match="Euler convention.*'Quaternion'"):
        motive.read(path)


# ---------------------------------------------------------------- assets
def test_markers_and_bones_are_ignored(tmp_path):
    cols = (rigid_body("cup") + [("Rigid Body", "cup", "Mean Marker Error", "")]
            + [("Rigid Body Marker", "cup:Marker1", "Position", a) for a in "XYZ"]
            + [("Rigid Body Marker", "cup:Marker1", "Marker Quality", "")]
            + [("Marker", "cup:Marker1", "Position", a) for a in "XYZ"]
            + [("Bone", "skel:Hip", "Rotation", a) for a in "XYZW"]
            + [("Bone", "skel:Hip", "Position", a) for a in "XYZ"]
            + [("Bone Marker", "skel:Hip1", "Position", a) for a in "XYZ"]
            + rigid_body("plate"))
    row = [*ANGLES.values(), *POS_CM, 0.01, 1, 2, 3, 0.9, 4, 5, 6, 0, 0, 0, 1, 7, 8, 9, 10, 11, 12, 0, 0, 0, 1, 2, 3]
    path = write(tmp_path, motive_text(cols, [row, row], parent=True))
    cup, plate = motive.read(path, ReadOptions(body="all"))
    assert (cup.name, plate.name) == ("cup", "plate")
    assert cup.info["bodies"] == ["cup", "plate"]
    assert cup.info["ignored_assets"] == {"Bone": 1, "Bone Marker": 1, "Marker": 1, "Rigid Body Marker": 1}
    np.testing.assert_allclose(matrices(cup.quat)[0], rx(30) @ ry(-40) @ rz(110), atol=1e-12)
    np.testing.assert_allclose(plate.position[1], [0.01, 0.02, 0.03], rtol=1e-15)
    d = motive.describe(path)
    assert d["bodies"] == ["cup", "plate"] and d["other_assets"]["Bone"] == ["skel:Hip"]


def test_file_without_rigid_bodies(tmp_path):
    cols = [("Marker", "m1", "Position", a) for a in "XYZ"] + [("Bone", "skel:Hip", "Position", a) for a in "XYZ"]
    path = write(tmp_path, motive_text(cols, [[1, 2, 3, 4, 5, 6]]))
    with pytest.raises(InputError, match="no Rigid Body columns.*Bone: skel:Hip; Marker: m1"):
        motive.read(path)


def test_body_selection(tmp_path):
    cols = rigid_body("RigidBody 01") + rigid_body("RigidBody 02")
    path = write(tmp_path, motive_text(cols, [[0, 0, 0, 1, 2, 3, 0, 0, 0, 4, 5, 6]]))
    with pytest.raises(InputError, match="2 rigid bodies: 'RigidBody 01', 'RigidBody 02'.*use body NAME"):
        motive.read(path)
    with pytest.raises(InputError, match="did you mean body 'RigidBody 02'"):
        motive.read(path, ReadOptions(body="RigidBody 2"))
    (tr,) = motive.read(path, ReadOptions(body="rigidbody 02"))
    np.testing.assert_allclose(tr.position[0], [0.04, 0.05, 0.06], rtol=1e-15)


# ---------------------------------------------------------------- layouts and lost frames
@pytest.mark.parametrize("labelled, parent, timecode",
                         [(False, False, False), (True, False, False), (True, True, True)])
def test_header_variants(tmp_path, labelled, parent, timecode):
    data = [[*ANGLES.values(), *POS_CM], [1, 2, 3, 4, 5, 6], [0, 0, 0, 7, 8, 9]]
    path = write(tmp_path, motive_text(rigid_body("cup"), data, labelled=labelled, parent=parent, timecode=timecode))
    (tr,) = motive.read(path)
    np.testing.assert_array_equal(tr.t, np.arange(3) / 120.0)
    np.testing.assert_allclose(tr.position[2], [0.07, 0.08, 0.09], rtol=1e-15)
    np.testing.assert_allclose(matrices(tr.quat)[0], rx(30) @ ry(-40) @ rz(110), atol=1e-12)
    assert tr.info["rate_hz"] == 120.0


def test_blank_cells_are_lost_frames(tmp_path):
    data = [[0, 0, 0, 1, 2, 3], ["", "", "", "", "", ""], [0, 0, "", 1, 2, 3], [0, 0, 0, 1, 2, 3]]
    (tr,) = motive.read(write(tmp_path, motive_text(rigid_body("cup"), data)))
    assert np.isnan(tr.quat[[1, 2]]).all() and np.isnan(tr.position[[1, 2]]).all()
    assert np.isfinite(tr.quat[[0, 3]]).all() and tr.info["lost_frames"] == 2
    assert np.isfinite(tr.t).all()


# ---------------------------------------------------------------- errors
def test_truncated_and_non_numeric_rows(tmp_path):
    text = motive_text(rigid_body("cup"), [[0, 0, 0, 1, 2, 3]] * 3)
    truncated = text.rstrip("\n").rsplit(",", 3)[0] + "\n"
    with pytest.raises(InputError, match="truncated row") as err:
        motive.read(write(tmp_path, truncated))
    assert err.value.row == 10  # line 1, blank, Type, Name, ID, Rotation/Position, Frame, then rows 8..10
    with pytest.raises(InputError, match="'abc' in column cup Position Y is not a number") as err:
        motive.read(write(tmp_path, text.replace(",2.0,", ",abc,", 1)))
    assert err.value.row == 8


def test_semicolon_file_is_not_a_motive_export(tmp_path):
    text = motive_text(rigid_body("cup"), [[0, 0, 0, 1, 2, 3]]).replace(",", ";")
    assert not motive.sniff(text)
    with pytest.raises(InputError, match="not a Motive CSV export"):
        motive.read(write(tmp_path, text))


def test_header_without_frame_row(tmp_path):
    text = first_line() + "\n\n,,Rigid Body\n,,cup\n"
    with pytest.raises(InputError, match="no 'Frame,Time"):
        motive.read(write(tmp_path, text))


# ---------------------------------------------------------------- sniff and describe
def test_sniff():
    text = motive_text(rigid_body("cup"), [[0, 0, 0, 1, 2, 3]])
    assert motive.sniff(text) and motive.sniff("\ufeff" + text) and motive.sniff('"Format Version","1.21"\n')
    assert not motive.sniff("NO_OF_FRAMES\t3\nFREQUENCY\t100\n")
    assert not motive.sniff("Segments\n100\n,,s:a\nFrame,Sub Frame,RX,RY,RZ,TX,TY,TZ\n")
    assert not motive.sniff("time,x,y,z\n")


def test_describe(tmp_path):
    path = write(tmp_path, motive_text(rigid_body("cup"), [[0, 0, 0, 1, 2, 3]] * 4, first=first_line(units=None)))
    d = motive.describe(path)
    assert d["format"] == "motive" and d["bodies"] == ["cup"] and d["frames"] == 4 and d["rate_hz"] == 120.0
    assert d["length_unit"] is None and d["rotation_type"] == "XYZ" and d["rotation"] == {"cup": "euler XYZ"}
    assert d["header"]["Take Name"].startswith("Take 2024")
