"""Generic CSV reader and the trajectory CSV writer (rbgp_cli.io.csv)."""

from __future__ import annotations

import io

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from rbgp_cli.dynamics.trajectory import Trajectory
from rbgp_cli.errors import InputError
from rbgp_cli.io import csv as rcsv
from rbgp_cli.io.options import ReadOptions

RNG = np.random.default_rng(7)
N = 12
T = 0.25 + np.arange(N) / 100.0
P = RNG.normal(scale=0.4, size=(N, 3))
Q = Rotation.random(N, random_state=3).as_quat()  # x, y, z, w
Q[Q[:, 3] < 0] *= -1


def assert_same_rotations(q1, q2, atol=1e-12):
    """q and -q are the same rotation."""
    d = np.abs(np.sum(np.asarray(q1) * np.asarray(q2), axis=-1))
    assert np.all(np.abs(d - 1.0) < atol), d


def write(tmp_path, text: str, name: str = "demo.csv"):
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return p


def table(header, columns, sep=",", fmt=repr) -> str:
    rows = [sep.join(header)]
    for k in range(N):
        rows.append(sep.join(fmt(float(c[k])) for c in columns))
    return "\n".join(rows) + "\n"


def read1(path, **kw):
    trajs = rcsv.read(path, ReadOptions(**kw))
    assert len(trajs) == 1
    return trajs[0]


# -------------------------------------------------------------------------------------------- naming
XYZW = [Q[:, 0], Q[:, 1], Q[:, 2], Q[:, 3]]
WXYZ = [Q[:, 3], Q[:, 0], Q[:, 1], Q[:, 2]]


@pytest.mark.parametrize(
    "header, quat_cols",
    [
        ("t,x,y,z,qx,qy,qz,qw", XYZW),
        ("time,pos_x,pos_y,pos_z,quat_x,quat_y,quat_z,quat_w", XYZW),
        ("timestamp,px,py,pz,qw,qx,qy,qz", WXYZ),
        ("stamp,tx,ty,tz,rot_x,rot_y,rot_z,rot_w", XYZW),
        ("Time,Position X,Position Y,Position Z,Orientation W,Orientation X,Orientation Y,Orientation Z", WXYZ),
        ("T,X,Y,Z,QX,QY,QZ,QW", XYZW),
        ("time_s,x_m,y_m,z_m,qw,qx,qy,qz", WXYZ),
        ("sec,position.x,position.y,position.z,orientation.x,orientation.y,orientation.z,orientation.w", XYZW),
        ("t,field.pose.position.x,field.pose.position.y,field.pose.position.z,field.pose.orientation.x,"
         "field.pose.orientation.y,field.pose.orientation.z,field.pose.orientation.w", XYZW),
        ("t,translation_x,translation_y,translation_z,rx,ry,rz,rw", XYZW),
        ("t,x,y,z,q_x,q_y,q_z,q_w", XYZW),
    ],
)
def test_naming_schemes_read_the_same_poses(tmp_path, header, quat_cols):
    p = write(tmp_path, table(header.split(","), [T, P[:, 0], P[:, 1], P[:, 2], *quat_cols]))
    tr = read1(p)
    np.testing.assert_array_equal(tr.t, T)
    np.testing.assert_array_equal(tr.position, P)
    np.testing.assert_array_equal(tr.quat, Q)  # reordered by name, not by position
    assert tr.info["format"] == "csv"
    assert set(tr.info["columns"]) >= {"t", "x", "y", "z", "qx", "qy", "qz", "qw"}


def test_wxyz_and_xyzw_files_give_the_same_rotation(tmp_path):
    a = read1(write(tmp_path, table("t,x,y,z,qx,qy,qz,qw".split(","), [T, *P.T, *XYZW]), "a.csv"))
    b = read1(write(tmp_path, table("t,x,y,z,qw,qx,qy,qz".split(","), [T, *P.T, *WXYZ]), "b.csv"))
    np.testing.assert_array_equal(a.quat, b.quat)
    assert a.info["rotation"] == "quaternion xyzw"
    assert b.info["rotation"] == "quaternion wxyz"


@pytest.mark.parametrize("sep", [",", ";", "\t", " "])
def test_delimiters_are_sniffed(tmp_path, sep):
    p = write(tmp_path, table("t x y z qx qy qz qw".split(), [T, *P.T, *XYZW], sep=sep))
    tr = read1(p)
    np.testing.assert_array_equal(tr.position, P)
    np.testing.assert_array_equal(tr.quat, Q)


def test_semicolon_with_decimal_comma(tmp_path):
    text = table("t;x;y;z;qx;qy;qz;qw".split(";"), [T, *P.T, *XYZW], sep=";", fmt=lambda v: repr(v).replace(".", ","))
    tr = read1(write(tmp_path, text))
    np.testing.assert_allclose(tr.position, P, rtol=0, atol=0)
    assert tr.info["delimiter"] == ";"


def test_comments_bom_and_blank_lines(tmp_path):
    body = table("t,x,y,z,qx,qy,qz,qw".split(","), [T, *P.T, *XYZW]).splitlines()
    text = "\ufeff# recorded by hand\n\n" + body[0] + "\n# a comment\n" + "\n".join(body[1:4]) + "\n\n" + "\n".join(body[4:]) + "\n"
    p = tmp_path / "c.csv"
    p.write_bytes(text.encode("utf-8"))
    tr = read1(p)
    np.testing.assert_array_equal(tr.t, T)
    assert "line_runs" in tr.info and tr.info["line_runs"][0] == [5, 3]


def test_numpy_savetxt_header_in_a_comment(tmp_path):
    buf = io.StringIO()
    np.savetxt(buf, np.column_stack([T, P, Q]), header="t x y z qx qy qz qw")
    tr = read1(write(tmp_path, buf.getvalue()))
    np.testing.assert_allclose(tr.quat, Q, rtol=1e-15)


def test_extra_columns_are_ignored(tmp_path):
    header = "trial_note,t,x,y,z,qx,qy,qz,qw,std_wx,std_vx,residual".split(",")
    cols = [np.zeros(N), T, *P.T, *XYZW, np.ones(N), np.ones(N), np.ones(N)]
    tr = read1(write(tmp_path, table(header, cols)))
    np.testing.assert_array_equal(tr.position, P)
    assert "std_wx" not in tr.info["columns"].values()


def test_ambiguous_columns_ask_for_columns_option(tmp_path):
    header = "t,x,y,z,pos_x,pos_y,pos_z,qx,qy,qz,qw,X".split(",")
    p = write(tmp_path, table(header, [T, *P.T, *P.T, *XYZW, P[:, 0]]))
    with pytest.raises(InputError, match=r"several columns could be 'x'.*columns x=NAME"):
        rcsv.read(p)


# -------------------------------------------------------------------------------------------- units
@pytest.mark.parametrize(
    "xname, scale, unit",
    [("x_mm", 1e-3, "mm"), ("x [mm]", 1e-3, "mm"), ("x(cm)", 1e-2, "cm"), ("x_m", 1.0, "m"), ("X [Millimeters]", 1e-3, "mm")],
)
def test_length_unit_from_suffix(tmp_path, xname, scale, unit):
    names = [xname, xname.replace("x", "y").replace("X", "Y"), xname.replace("x", "z").replace("X", "Z")]
    p = write(tmp_path, table(["t", *names, "qx", "qy", "qz", "qw"], [T, *(P.T * 1000 if scale < 1 else P.T), *XYZW]))
    tr = read1(p)
    expected = P * 1000 * scale if scale < 1 else P
    np.testing.assert_allclose(tr.position, expected, rtol=1e-15)
    assert tr.info["length_unit"] == unit and tr.info["length_unit_source"] == "column name"


@pytest.mark.parametrize(
    "tname, factor, unit",
    [("time_ms", 1e3, "ms"), ("t [ns]", 1e9, "ns"), ("time (s)", 1.0, "s"), ("t_us", 1e6, "us"), ("timestamp_ns", 1e9, "ns")],
)
def test_time_unit_from_suffix(tmp_path, tname, factor, unit):
    p = write(tmp_path, table([tname, "x", "y", "z", "qx", "qy", "qz", "qw"], [T * factor, *P.T, *XYZW]))
    tr = read1(p)
    np.testing.assert_allclose(tr.t, T, rtol=1e-12)
    assert tr.info["time_unit"] == unit
    assert tr.info["rate_hz"] == pytest.approx(100.0)


def test_millimetres_without_unit_are_refused_with_a_hint(tmp_path):
    p = write(tmp_path, table("t,x,y,z,qx,qy,qz,qw".split(","), [T, *(P.T * 1000 + 500), *XYZW]))
    with pytest.raises(InputError, match=r"looks like millimetres.*length_unit mm"):
        rcsv.read(p)
    tr = read1(p, length_unit="mm")
    np.testing.assert_allclose(tr.position, P + 0.5, atol=1e-12)
    assert tr.info["length_unit_source"] == "option"


@pytest.mark.parametrize("factor, unit", [(1e3, "ms"), (1e9, "ns")])
def test_time_in_ms_or_ns_without_unit_is_refused_with_the_right_hint(tmp_path, factor, unit):
    p = write(tmp_path, table("t,x,y,z,qx,qy,qz,qw".split(","), [T * factor, *P.T, *XYZW]))
    with pytest.raises(InputError, match=rf"implausible.*time_unit {unit}\b"):
        rcsv.read(p)
    tr = read1(p, time_unit=unit)
    np.testing.assert_allclose(tr.t, T, rtol=1e-12)


def test_sec_and_nanosec_columns_are_added(tmp_path):
    ns = (1_700_000_000 * 10**9 + np.arange(N) * 10_000_000).astype(np.int64)
    sec, nsec = ns // 10**9, ns % 10**9
    p = write(tmp_path, table("sec,nanosec,x,y,z,qx,qy,qz,qw".split(","), [sec, nsec, *P.T, *XYZW], fmt=lambda v: repr(int(v)) if v == int(v) else repr(v)))
    tr = read1(p)
    np.testing.assert_allclose(np.diff(tr.t), 0.01, atol=1e-6)
    assert tr.t[0] == pytest.approx(1.7e9)


def test_iso_datetime_time_column(tmp_path):
    rows = ["timestamp,x,y,z,qx,qy,qz,qw"]
    for k in range(N):
        stamp = f"2024-05-01T12:00:{k * 0.01:09.6f}" if k != 3 else ""
        rows.append(",".join([stamp] + [repr(float(v)) for v in (*P[k], *Q[k])]))
    tr = read1(write(tmp_path, "\n".join(rows) + "\n"))
    assert np.isnan(tr.t[3])
    ok = np.arange(N) != 3
    np.testing.assert_allclose(tr.t[ok] - tr.t[0], np.arange(N)[ok] * 0.01, atol=1e-6)
    assert tr.t[0] == pytest.approx(1714564800.0)
    assert tr.info["time_unit_source"] == "ISO 8601 date-times"


def test_time_of_day_strings_are_not_guessed(tmp_path):
    rows = ["t,x,y,z,qx,qy,qz,qw", "12:00:01,0,0,0,0,0,0,1", "12:00:02,0,0,0,0,0,0,1"]
    with pytest.raises(InputError, match=r":2: non-numeric value '12:00:01' in column 't'"):
        rcsv.read(write(tmp_path, "\n".join(rows) + "\n"))


# -------------------------------------------------------------------------------------------- rotation kinds
def test_numbered_quaternion_asks_for_quat_order_then_works(tmp_path):
    p = write(tmp_path, table("t,x,y,z,q0,q1,q2,q3".split(","), [T, *P.T, *WXYZ]))
    with pytest.raises(InputError, match=r"quat_order xyzw.*quat_order wxyz"):
        rcsv.read(p)
    tr = read1(p, quat_order="wxyz")
    np.testing.assert_array_equal(tr.quat, Q)
    tr2 = read1(p, quat_order="xyzw")
    np.testing.assert_array_equal(tr2.quat, np.stack(WXYZ, axis=-1))


def test_one_based_numbered_quaternion(tmp_path):
    p = write(tmp_path, table("t,x,y,z,q1,q2,q3,q4".split(","), [T, *P.T, *XYZW]))
    with pytest.raises(InputError, match="quat_order"):
        rcsv.read(p)
    np.testing.assert_array_equal(read1(p, quat_order="xyzw").quat, Q)


@pytest.mark.parametrize("order", ["ZYX", "xyz", "YXZ"])
def test_euler_roll_pitch_yaw_with_order_and_degree_suffix(tmp_path, order):
    by_axis = {"x": 0.3 * np.sin(T * 5), "y": 0.2 * np.cos(T * 3), "z": np.linspace(-2.5, 2.5, N)}
    angles = np.stack([by_axis[a] for a in order.lower()], axis=-1)
    expected = Rotation.from_euler(order, angles).as_quat()
    deg = {k: np.rad2deg(v) for k, v in by_axis.items()}
    p = write(tmp_path, table("t,x,y,z,yaw_deg,pitch_deg,roll_deg".split(","), [T, *P.T, deg["z"], deg["y"], deg["x"]]))
    with pytest.raises(InputError, match="euler_order"):
        rcsv.read(p)
    tr = read1(p, euler_order=order)
    assert_same_rotations(tr.quat, expected)
    assert tr.info["rotation"] == f"euler {order} (deg)"


def test_euler_units_come_from_the_option_or_an_error_names_it(tmp_path):
    rpy = np.stack([0.1 * T, -0.2 * T, 0.5 * T], axis=-1)
    p = write(tmp_path, table("t,x,y,z,roll,pitch,yaw".split(","), [T, *P.T, *rpy.T]))
    with pytest.raises(InputError, match=r"degrees or radians.*degrees=True or degrees=False"):
        rcsv.read(p, ReadOptions(euler_order="xyz"))
    tr = read1(p, euler_order="xyz", degrees=False)
    assert_same_rotations(tr.quat, Rotation.from_euler("xyz", rpy).as_quat())
    trd = read1(p, euler_order="xyz", degrees=True)
    assert_same_rotations(trd.quat, Rotation.from_euler("xyz", rpy, degrees=True).as_quat())


def test_rot_x_style_angles_are_euler_and_need_an_order(tmp_path):
    ang = np.stack([0.1 + T, 0.2 - T, 0.3 * T], axis=-1)  # about x, y, z
    p = write(tmp_path, table("t,x,y,z,rot_x_rad,rot_y_rad,rot_z_rad".split(","), [T, *P.T, *ang.T]))
    with pytest.raises(InputError, match="euler_order"):
        rcsv.read(p)
    tr = read1(p, euler_order="ZYX")
    assert_same_rotations(tr.quat, Rotation.from_euler("ZYX", ang[:, ::-1]).as_quat())
    with pytest.raises(InputError, match="each of x, y, z once"):
        rcsv.read(p, ReadOptions(euler_order="ZXZ"))


def test_rotation_vector_columns(tmp_path):
    rv = Rotation.from_quat(Q).as_rotvec()
    p = write(tmp_path, table("t,x,y,z,rx,ry,rz".split(","), [T, *P.T, *rv.T]))
    tr = read1(p)
    assert_same_rotations(tr.quat, Q)
    assert tr.info["rotation"] == "rotation vector (rad)"
    pd = write(tmp_path, table("t,x,y,z,rx_deg,ry_deg,rz_deg".split(","), [T, *P.T, *np.rad2deg(rv).T]), "d.csv")
    assert_same_rotations(read1(pd).quat, Q)


# -------------------------------------------------------------------------------------------- options
def test_columns_option_maps_names(tmp_path):
    p = write(tmp_path, table("stamp_value,a,b,c,i,j,k,w".split(","), [T, *P.T, *XYZW]))
    with pytest.raises(InputError, match="columns"):
        rcsv.read(p)
    cols = {"t": "stamp_value", "x": "a", "y": "b", "z": "c", "qx": "i", "qy": "j", "qz": "k", "qw": "w"}
    tr = read1(p, columns=cols)
    np.testing.assert_array_equal(tr.quat, Q)
    np.testing.assert_array_equal(tr.t, T)
    assert tr.info["columns"]["qw"] == "w"


def test_columns_option_partial_mapping(tmp_path):
    p = write(tmp_path, table("stamp,x,y,z,qx,qy,qz,w".split(","), [T, *P.T, *XYZW]))
    tr = read1(p, columns={"t": "stamp", "qw": "w"})
    np.testing.assert_array_equal(tr.quat, Q)


def test_columns_option_errors(tmp_path):
    p = write(tmp_path, table("t,x,y,z,qx,qy,qz,qw".split(","), [T, *P.T, *XYZW]))
    with pytest.raises(InputError, match=r"columns key 'qq' is unknown"):
        rcsv.read(p, ReadOptions(columns={"qq": "x"}))
    with pytest.raises(InputError, match=r"no column 'qww'.*did you mean 'qw'"):
        rcsv.read(p, ReadOptions(columns={"qw": "qww"}))


def test_no_time_column_needs_rate(tmp_path):
    p = write(tmp_path, table("x,y,z,qx,qy,qz,qw".split(","), [*P.T, *XYZW]))
    with pytest.raises(InputError, match=r"no time column \(columns are x, y, z, qx, qy, qz, qw\); pass rate HZ"):
        rcsv.read(p)
    tr = read1(p, rate=50)
    np.testing.assert_allclose(tr.t, np.arange(N) / 50)
    assert tr.info["rate_hz"] == pytest.approx(50)


def test_frame_column_with_rate_keeps_gaps(tmp_path):
    frames = np.arange(N) + (np.arange(N) >= 6) * 3  # 3 frames missing
    p = write(tmp_path, table("frame,x,y,z,qx,qy,qz,qw".split(","), [frames, *P.T, *XYZW]))
    tr = read1(p, rate=100)
    np.testing.assert_allclose(tr.t, frames / 100)


def test_demo_column_splits_in_order_of_first_appearance(tmp_path):
    demo = np.array(["b"] * 4 + ["a"] * 4 + ["b"] * 4)
    rows = ["trial,t,x,y,z,qx,qy,qz,qw"]
    for k in range(N):
        rows.append(",".join([demo[k]] + [repr(float(v)) for v in (T[k], *P[k], *Q[k])]))
    p = write(tmp_path, "\n".join(rows) + "\n", "takes.csv")
    trajs = rcsv.read(p)
    assert [t.name for t in trajs] == ["takes#b", "takes#a"]
    np.testing.assert_array_equal(trajs[0].position, P[demo == "b"])
    np.testing.assert_array_equal(trajs[1].quat, Q[demo == "a"])
    assert trajs[0].info["line_runs"] == [[2, 4], [10, 4]]
    assert trajs[1].info["first_data_line"] == 6


# -------------------------------------------------------------------------------------------- errors
def test_misspelled_quaternion_column_is_suggested(tmp_path):
    p = write(tmp_path, table("t,x,y,z,qx,qy,qz,qww".split(","), [T, *P.T, *XYZW]))
    with pytest.raises(InputError) as e:
        rcsv.read(p)
    msg = str(e.value)
    assert "'qw' not found" in msg and "did you mean 'qww'" in msg and "columns qw=qww" in msg
    assert "columns are t, x, y, z, qx, qy, qz, qww" in msg


def test_misspelled_position_column_is_suggested(tmp_path):
    p = write(tmp_path, table("t,x,yy,z,qx,qy,qz,qw".split(","), [T, *P.T, *XYZW]))
    with pytest.raises(InputError, match=r"position column 'y' not found.*did you mean 'yy'"):
        rcsv.read(p)


def test_no_rotation_columns(tmp_path):
    p = write(tmp_path, table("t,x,y,z,a,b".split(","), [T, *P.T, T, T]))
    with pytest.raises(InputError, match=r"no rotation columns found \(columns are t, x, y, z, a, b\)"):
        rcsv.read(p)


def test_non_numeric_cell_names_line_and_column(tmp_path):
    text = table("t,x,y,z,qx,qy,qz,qw".split(","), [T, *P.T, *XYZW]).splitlines()
    cells = text[4].split(",")
    cells[2] = "1.2.3"
    text[4] = ",".join(cells)
    p = write(tmp_path, "# comment\n" + "\n".join(text) + "\n")
    with pytest.raises(InputError) as e:
        rcsv.read(p)
    msg = str(e.value)
    assert msg.startswith(f"{p}:6: ") and "'1.2.3'" in msg and "column 'y'" in msg


def test_empty_cells_and_null_are_lost_frames(tmp_path):
    text = table("t,x,y,z,qx,qy,qz,qw".split(","), [T, *P.T, *XYZW]).splitlines()
    text[3] = f"{float(T[2])!r},,,,,,,"
    text[5] = f"{float(T[4])!r},null,NaN,nan," + ",".join(repr(float(v)) for v in Q[4])
    tr = read1(write(tmp_path, "\n".join(text) + "\n"))
    assert np.isnan(tr.position[2]).all() and np.isnan(tr.quat[2]).all()
    assert np.isnan(tr.position[4]).all() and not np.isnan(tr.quat[4]).any()
    assert np.isfinite(tr.position[[0, 1, 3, 5]]).all()


def test_row_with_too_many_fields(tmp_path):
    text = table("t,x,y,z,qx,qy,qz,qw".split(","), [T, *P.T, *XYZW]).splitlines()
    text[3] += ",1.0"
    with pytest.raises(InputError, match=r":4: row has 9 fields"):
        rcsv.read(write(tmp_path, "\n".join(text) + "\n"))


def test_short_first_row_and_trailing_delimiters(tmp_path):
    text = table("t,x,y,z,qx,qy,qz,qw".split(","), [T, *P.T, *XYZW]).splitlines()
    text[1] = f"{float(T[0])!r},,"  # a lost frame written short
    text[2:] = [line + "," for line in text[2:]]  # every other row ends with a delimiter
    tr = read1(write(tmp_path, "\n".join(text) + "\n"))
    assert np.isnan(tr.position[0]).all() and np.isnan(tr.quat[0]).all()
    np.testing.assert_array_equal(tr.position[1:], P[1:])


@pytest.mark.parametrize(
    "content, match",
    [
        ("", "empty"),
        ("t,x,y,z,qx,qy,qz,qw\n", r":1: the file has a header but no data rows"),
        (bytes(np.random.default_rng(1).integers(0, 256, 2000, dtype=np.uint8)), "not a text file"),
        ("0.0,1,2,3,0,0,0,1\n0.1,1,2,3,0,0,0,1\n", r":1: no header line.*add a header"),
    ],
    ids=["empty", "header-only", "binary-garbage", "numbers-without-header"],
)
def test_a_file_without_demonstrations_is_an_input_error(tmp_path, content, match):
    p = tmp_path / "demo.csv"
    p.write_bytes(content if isinstance(content, bytes) else content.encode("utf-8"))
    with pytest.raises(InputError, match=match):
        rcsv.read(p)


def test_missing_file():
    with pytest.raises(InputError, match="file not found"):
        rcsv.read("/nonexistent/demo.csv")


# -------------------------------------------------------------------------------------------- writer
def _traj(name, n, seed):
    rng = np.random.default_rng(seed)
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return Trajectory(t=np.cumsum(rng.uniform(0.001, 0.1, n)), quat=q, position=rng.normal(scale=3, size=(n, 3)), name=name)


def test_write_read_round_trip_with_extra_columns(tmp_path):
    trajs = [_traj("demo 1", 7, 0), _traj("b,with comma", 5, 1), _traj("", 3, 2)]
    trajs[0].position[2] = np.nan  # lost frames survive the round trip
    extra = {"std_wx": np.arange(15.0), "std_vz": [np.ones(7), np.zeros(5), np.full(3, 2.0)]}
    path = tmp_path / "out.csv"
    rcsv.write_trajectories_csv(trajs, path, extra=extra)
    text = path.read_text()
    assert text.splitlines()[1] == "trajectory,t,x,y,z,qx,qy,qz,qw,std_wx,std_vz"
    back = rcsv.read(path)
    assert [b.info["demo"] for b in back] == ["demo 1", "b,with comma", "2"]
    assert [b.name for b in back] == ["out#demo 1", "out#b,with comma", "out#2"]
    for a, b in zip(trajs, back):
        np.testing.assert_array_equal(a.t, b.t)
        np.testing.assert_array_equal(a.quat, b.quat)
        np.testing.assert_array_equal(a.position, b.position)


def test_write_to_stream_and_reject_bad_extra(tmp_path):
    buf = io.StringIO()
    rcsv.write_trajectories_csv([_traj("a", 4, 0), _traj("a", 2, 1)], buf)
    assert buf.getvalue().count("\n") == 8
    assert [t.info["demo"] for t in rcsv.read_text(buf.getvalue(), "x.csv")] == ["a", "a#1"]
    with pytest.raises(ValueError, match="rows"):
        rcsv.write_trajectories_csv([_traj("a", 4, 0)], io.StringIO(), extra={"s": np.ones(3)})


finite = st.floats(allow_nan=False, allow_infinity=False, width=64, min_value=-1e6, max_value=1e6)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    data=st.lists(st.lists(finite, min_size=7, max_size=7), min_size=2, max_size=8),
    names=st.lists(st.text(alphabet="ab #,\"'x", min_size=1, max_size=5), min_size=1, max_size=3,
                   unique_by=lambda s: s.strip()),
)
@example(data=[[0.0] * 7, [1e300] * 7], names=["#a", " ", '"q"'])
def test_round_trip_property(tmp_path, data, names):
    """Any float64 values (large positions included: the file states metres) read back bit-identical."""
    arr = np.array(data)
    trajs = [
        Trajectory(t=np.arange(len(arr)) * 0.01 + k, quat=arr[:, :4], position=arr[:, 4:], name=name)
        for k, name in enumerate(names)
    ]
    buf = io.StringIO()
    rcsv.write_trajectories_csv(trajs, buf)
    back = rcsv.read_text(buf.getvalue(), "mem.csv")
    assert len(back) == len(trajs)
    for k, (a, b) in enumerate(zip(trajs, back)):
        assert b.info["demo"] == (a.name.strip() or str(k))
        np.testing.assert_array_equal(a.quat, b.quat)
        np.testing.assert_array_equal(a.position, b.position)
        np.testing.assert_array_equal(a.t, b.t)


def test_describe_lists_columns_and_roles(tmp_path):
    p = write(tmp_path, table("time_ms,x,y,z,qw,qx,qy,qz,extra".split(","), [T * 1e3, *P.T, *WXYZ, T]))
    d = rcsv.describe(p)
    taken = {c["name"]: c["taken_as"] for c in d["columns"]}
    assert taken == {"time_ms": "t", "x": "x", "y": "y", "z": "z", "qw": "qw", "qx": "qx", "qy": "qy", "qz": "qz", "extra": None}
    assert d["columns"][0]["unit"] == "ms" and d["problem"] is None
