"""QTM 6D TSV reader: format facts on hand-built synthetic files (independent of export.py)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rbgp_cli.errors import InputError, RbgpWarning
from rbgp_cli.io import qtm
from rbgp_cli.io.options import ReadOptions
from tests.helpers import rx, ry, rz


# ---------------------------------------------------------------- oracles written out by hand


def matrices(quat):
    return Rotation.from_quat(quat).as_matrix()


def cell(v):
    return v if isinstance(v, str) else repr(float(v))


def qtm_text(bodies, *, layout="current", angles=("Roll", "Pitch", "Yaw"), rot=True, freq="100", events=(),
             version=True, data_included="6D"):
    """A QTM TSV as QTM writes it. ``bodies``: {name: {"pos": (N,3) mm, "ang": (N,3) deg in the column
    order of ``angles``, "rot": (N,3,3) matrices, "res": (N,)}}; cells may be strings ("null")."""
    names = list(bodies)
    n = len(next(iter(bodies.values()))["pos"])
    head = ["FILE_VERSION\t2.0.0"] if version else []
    head += [f"NO_OF_FRAMES\t{n}", "NO_OF_CAMERAS\t4", f"NO_OF_BODIES\t{len(names)}", f"FREQUENCY\t{freq}",
             "NO_OF_ANALOG\t0", "ANALOG_FREQUENCY\t0", "DESCRIPTION\t--",
             "TIME_STAMP\t2020-01-22, 17:47:17\t22107.99179716"]
    head += [f"EVENT\t{e}\t{k}\t{k / 100:.5f}" for k, e in enumerate(events, start=2)]
    head += [f"DATA_INCLUDED\t{data_included}", "BODY_NAMES\t" + "\t".join(names)]
    fields = ["X", "Y", "Z", *angles, "Residual"] + ([f"Rot[{k}]" for k in range(9)] if rot else [])

    def block(b, i):
        vals = list(b["pos"][i]) + list(b["ang"][i]) + [b.get("res", [0.7] * n)[i]]
        if rot:
            r = b["rot"][i]
            vals += list(r) if len(r) == 9 else list(np.asarray(r).T.reshape(9))  # column-major
        return [cell(v) for v in vals]

    if layout == "current":
        cols = ["Frame", "Time"] + [c for name in names for c in [f"{name} X", *fields[1:]]]
        lines = ["\t".join(cols) + "\t"]
        lines += ["\t".join([str(i + 1), f"{i / 100:.5f}"] + [c for b in bodies.values() for c in block(b, i)]) + "\t"
                  for i in range(n)]
    else:
        lines = ["\t".join(" " + f for f in fields)]
        lines += ["\t".join(c for b in bodies.values() for c in [*block(b, i), ""]) for i in range(n)]
    return "\r\n".join(head + lines) + "\r\n"


def random_body(rng, n, order="XYZ"):
    """Random angles (deg) and their matrices composed by hand, intrinsic ``order`` in column order."""
    ang = rng.uniform([-180, -85, -180], [180, 85, 180], size=(n, 3))
    elem = {"X": rx, "Y": ry, "Z": rz}
    rot = np.array([elem[order[0]](a) @ elem[order[1]](b) @ elem[order[2]](c) for a, b, c in ang])
    return {"pos": rng.uniform(-2000, 2000, size=(n, 3)), "ang": ang, "rot": rot}


def write(tmp_path, text, name="take_6D.tsv"):
    p = tmp_path / name
    p.write_text(text, newline="")
    return p


# ---------------------------------------------------------------- Rot[] and Euler conventions
def test_rot_is_read_column_major_not_row_major(tmp_path):
    # 90° about +z: columns are the body axes in world coordinates; R is not symmetric, so reading
    # Rot[] row-major would give the inverse (-90°) rotation.
    r = rz(90.0)
    flat_column_major = [r[0, 0], r[1, 0], r[2, 0], r[0, 1], r[1, 1], r[2, 1], r[0, 2], r[1, 2], r[2, 2]]
    assert flat_column_major[1] == pytest.approx(1.0)  # Rot[1] = r21
    body = {"pos": [[1000.0, -250.0, 12.5]], "ang": [[0.0, 0.0, 90.0]], "rot": [flat_column_major]}
    (tr,) = qtm.read(write(tmp_path, qtm_text({"cup": body})))
    np.testing.assert_allclose(matrices(tr.quat)[0], r, atol=1e-12)
    assert not np.allclose(matrices(tr.quat)[0], r.T, atol=0.5)
    np.testing.assert_allclose(tr.quat[0] * np.sign(tr.quat[0, 3]), [0, 0, np.sqrt(0.5), np.sqrt(0.5)], atol=1e-12)
    np.testing.assert_allclose(tr.position[0], [1.0, -0.25, 0.0125], rtol=1e-15)
    assert tr.info["rotation_source"].startswith("Rot[] matrix")
    assert tr.info["length_unit"] == "mm" and tr.info["format"] == "qtm"


@pytest.mark.parametrize("layout", ["current", "old"])
@pytest.mark.parametrize("angles, order", [(("Roll", "Pitch", "Yaw"), "XYZ"), (("Yaw", "Pitch", "Roll"), "ZYX")])
def test_euler_and_rot_agree_with_hand_composition(tmp_path, layout, angles, order):
    """Roll is about X, Pitch about Y, Yaw about Z, composed intrinsically in header order:
    'Roll Pitch Yaw' -> Rx Ry Rz (QTM default), 'Yaw Pitch Roll' -> Rz Ry Rx (2010 files)."""
    rng = np.random.default_rng(3)
    bodies = {"a": random_body(rng, 40, order), "b": random_body(rng, 40, order)}
    with_rot = qtm.read(write(tmp_path, qtm_text(bodies, layout=layout, angles=angles), "r.tsv"),
                        ReadOptions(body="all"))
    euler_only = qtm.read(write(tmp_path, qtm_text(bodies, layout=layout, angles=angles, rot=False), "e.tsv"),
                          ReadOptions(body="all"))
    for name, a, b in zip(bodies, with_rot, euler_only):
        assert a.name == b.name == name
        np.testing.assert_allclose(matrices(a.quat), bodies[name]["rot"], atol=1e-12)
        np.testing.assert_allclose(matrices(b.quat), bodies[name]["rot"], atol=1e-12)
        assert b.info["rotation_source"].startswith(f"euler {order} deg")
        np.testing.assert_allclose(a.position, bodies[name]["pos"] / 1000.0, rtol=1e-15)


def test_euler_order_option_overrides_header_names(tmp_path):
    rng = np.random.default_rng(4)
    body = random_body(rng, 10, "ZXY")  # columns hold angles of an intrinsic Z, X, Y sequence
    path = write(tmp_path, qtm_text({"b": body}, angles=("Rotation 1", "Rotation 2", "Rotation 3"), rot=False))
    with pytest.raises(InputError, match="euler_order"):
        qtm.read(path)
    (tr,) = qtm.read(path, ReadOptions(euler_order="ZXY"))
    np.testing.assert_allclose(matrices(tr.quat), body["rot"], atol=1e-12)


def test_non_orthonormal_rot_row_falls_back_to_euler(tmp_path):
    rng = np.random.default_rng(5)
    body = random_body(rng, 5)
    body["rot"] = body["rot"].copy()
    body["rot"][2] = body["rot"][2] * 1.5  # scaled: not a rotation
    body["rot"][3] = -body["rot"][3]  # orthonormal but a reflection (det -1)
    path = write(tmp_path, qtm_text({"b": body}))
    with pytest.warns(RbgpWarning, match="2 Rot\\[\\] matrices are not rotations; used the Euler angles"):
        (tr,) = qtm.read(path)
    np.testing.assert_allclose(matrices(tr.quat)[2], body["rot"][2] / 1.5, atol=1e-12)
    np.testing.assert_allclose(matrices(tr.quat)[3], -body["rot"][3], atol=1e-12)
    assert tr.info["lost_frames"] == 0
    unusable_angles = qtm_text(  # "Extra" is no QTM angle name, so no Euler fallback
        {"b": body}, angles=("Roll", "Pitch")).replace("\tPitch\tResidual", "\tPitch\tExtra\tResidual")
    with pytest.warns(RbgpWarning, match="kept as lost frames"):
        (tr,) = qtm.read(write(tmp_path, unusable_angles, "n.tsv"))
    assert tr.info["lost_frames"] == 2 and np.isnan(tr.quat[[2, 3]]).all() and np.isfinite(tr.quat[[0, 1, 4]]).all()


# ---------------------------------------------------------------- layout facts
def test_event_lines_and_missing_file_version_shift_the_header(tmp_path):
    rng = np.random.default_rng(6)
    body = random_body(rng, 6)
    text = qtm_text({"rb": body}, events=("start", "stop", "mark"), version=False)
    (tr,) = qtm.read(write(tmp_path, text))
    assert len(tr) == 6
    assert tr.info["events"] == [["start", "2", "0.02000"], ["stop", "3", "0.03000"], ["mark", "4", "0.04000"]]
    assert tr.info["file_version"] is None
    np.testing.assert_allclose(tr.t, np.arange(6) / 100.0, atol=1e-12)


def test_old_layout_time_is_row_over_frequency(tmp_path):
    rng = np.random.default_rng(7)
    bodies = {"Upper": random_body(rng, 9), "Lower": random_body(rng, 9)}
    trs = qtm.read(write(tmp_path, qtm_text(bodies, layout="old", freq="256", version=False)), ReadOptions(body="all"))
    assert [t.name for t in trs] == ["Upper", "Lower"]
    for tr in trs:
        np.testing.assert_array_equal(tr.t, np.arange(9) / 256.0)
        assert tr.info["layout"] == "old" and tr.info["rate_hz"] == 256.0
    np.testing.assert_allclose(trs[1].position, bodies["Lower"]["pos"] / 1000, rtol=1e-15)


def test_export_without_key_value_header(tmp_path):
    rng = np.random.default_rng(19)
    bodies = {"a": random_body(rng, 5), "b": random_body(rng, 5)}
    text = qtm_text(bodies)
    columns_and_rows = text[text.index("Frame\tTime"):]
    assert qtm.sniff(columns_and_rows)
    trs = qtm.read(write(tmp_path, columns_and_rows), ReadOptions(body="all"))
    assert [t.name for t in trs] == ["a", "b"] and trs[0].info["rate_hz"] is None
    np.testing.assert_allclose(trs[1].t, np.arange(5) / 100.0, atol=1e-12)
    np.testing.assert_allclose(matrices(trs[1].quat), bodies["b"]["rot"], atol=1e-12)


def test_external_frequency_needs_rate_without_time_column(tmp_path):
    rng = np.random.default_rng(8)
    path = write(tmp_path, qtm_text({"b": random_body(rng, 4)}, layout="old", freq="EXT"))
    with pytest.raises(InputError, match="give the samples per second with rate HZ") as err:
        qtm.read(path)
    assert err.value.param == "rate"
    (tr,) = qtm.read(path, ReadOptions(rate=50.0))
    np.testing.assert_array_equal(tr.t, np.arange(4) / 50.0)


def test_old_layout_rows_that_do_not_match_the_single_header_are_refused(tmp_path):
    rng = np.random.default_rng(9)
    text = qtm_text({"a": random_body(rng, 3), "b": random_body(rng, 3)}, layout="old")
    broken = text.replace("\t\t", "\t")  # no empty column between the bodies
    with pytest.raises(InputError, match="empty column between the bodies"):
        qtm.read(write(tmp_path, broken), ReadOptions(body="all"))


# ---------------------------------------------------------------- lost frames
@pytest.mark.parametrize("token", ["null", "NaN", ""])
def test_lost_frame_tokens_become_nan_rows(tmp_path, token):
    rng = np.random.default_rng(10)
    body = random_body(rng, 5)
    body["pos"] = body["pos"].astype(object)
    body["pos"][1] = [token] * 3
    path = write(tmp_path, qtm_text({"b": body}))
    (tr,) = qtm.read(path)
    assert np.isnan(tr.position[1]).all() and np.isnan(tr.quat[1]).all()
    assert np.isfinite(tr.position[[0, 2, 3, 4]]).all() and np.isfinite(tr.quat[[0, 2, 3, 4]]).all()
    assert tr.info["lost_frames"] == 1


def test_qtm_zero_rows_with_residual_minus_one_are_lost(tmp_path):
    rng = np.random.default_rng(11)
    body = random_body(rng, 4)
    body["pos"][2], body["ang"][2] = 0.0, 0.0
    body["rot"] = body["rot"].copy()
    body["rot"][2] = 0.0
    body["res"] = [0.4, 0.3, -1.0, 0.5]
    (tr,) = qtm.read(write(tmp_path, qtm_text({"b": body})))
    assert np.isnan(tr.quat[2]).all() and np.isnan(tr.position[2]).all()
    assert tr.info["lost_frames"] == 1
    assert np.isfinite(tr.t).all()  # the frame's time stays


# ---------------------------------------------------------------- bodies and options
def test_body_selection(tmp_path):
    rng = np.random.default_rng(12)
    bodies = {name: random_body(rng, 3) for name in ("Upper Leg IMU", "Foot IMU", "Lower Leg IMU")}
    path = write(tmp_path, qtm_text(bodies))
    with pytest.raises(InputError, match="3 rigid bodies: 'Upper Leg IMU', 'Foot IMU', 'Lower Leg IMU'.*use body NAME, or body all"):
        qtm.read(path)
    (foot,) = qtm.read(path, ReadOptions(body="foot imu"))
    assert foot.name == "Foot IMU"
    np.testing.assert_allclose(matrices(foot.quat), bodies["Foot IMU"]["rot"], atol=1e-12)
    with pytest.raises(InputError, match="no rigid body named 'Foot'.*did you mean body 'Foot IMU'"):
        qtm.read(path, ReadOptions(body="Foot"))
    assert [t.name for t in qtm.read(path, ReadOptions(body="all"))] == list(bodies)


def test_length_unit_option(tmp_path):
    rng = np.random.default_rng(13)
    body = random_body(rng, 3)
    (tr,) = qtm.read(write(tmp_path, qtm_text({"b": body})), ReadOptions(length_unit="cm"))
    np.testing.assert_allclose(tr.position, body["pos"] / 100.0, rtol=1e-15)
    assert tr.info["length_unit"] == "cm"
    with pytest.raises(InputError, match="unknown length unit 'inch'"):
        qtm.read(write(tmp_path, qtm_text({"b": body})), ReadOptions(length_unit="inch"))


# ---------------------------------------------------------------- errors: one line, file and row
def test_truncated_row_names_its_line(tmp_path):
    rng = np.random.default_rng(14)
    text = qtm_text({"b": random_body(rng, 4)}, version=False)
    text = text[: text.rstrip().rfind("\t", 0, len(text) - 60)]  # cut inside the last row
    with pytest.raises(InputError) as err:
        qtm.read(write(tmp_path, text))
    assert err.value.row == 15 and "truncated row" in str(err.value)  # 10 header lines, columns, 4 rows


def test_non_numeric_cell_names_row_and_column(tmp_path):
    rng = np.random.default_rng(15)
    body = random_body(rng, 4)
    body["ang"] = body["ang"].astype(object)
    body["ang"][3][1] = "12,5"
    with pytest.raises(InputError) as err:
        qtm.read(write(tmp_path, qtm_text({"b": body}, rot=False)))
    assert err.value.row == 16 and "'12,5' in column Pitch is not a number" in str(err.value)
    (tr,) = qtm.read(write(tmp_path, qtm_text({"b": body})))  # with Rot[] the angles are not needed
    np.testing.assert_allclose(matrices(tr.quat), body["rot"], atol=1e-12)


def test_comma_separated_file_is_not_read_as_qtm(tmp_path):
    rng = np.random.default_rng(16)
    text = qtm_text({"b": random_body(rng, 2)}).replace("\t", ",")
    with pytest.raises(InputError, match="no QTM header .* and no tab-separated"):
        qtm.read(write(tmp_path, text))


@pytest.mark.parametrize(
    "text, match",
    [
        ("", "empty"),
        ("NO_OF_FRAMES\t0\nFREQUENCY\t100\nDATA_INCLUDED\t3D\nMARKER_NAMES\ta\tb\n", "3D data, not 6DOF"),
        ("NO_OF_FRAMES\t1\nFREQUENCY\t100\nBODY_NAMES\tb\n1\t0.0\t1\t2\t3\n", "no column header"),
        ("NO_OF_FRAMES\t1\nFREQUENCY\t100\nBODY_NAMES\tb\n", "no column header or data"),
        ("NO_OF_FRAMES\t1\nBODY_NAMES\tb\nFrame\tTime\tSomething\n", "no rigid-body columns"),
    ],
)
def test_malformed_files_give_input_errors(tmp_path, text, match):
    with pytest.raises(InputError, match=match) as err:
        qtm.read(write(tmp_path, text))
    assert "\n" not in str(err.value) and str(tmp_path) in str(err.value)


def test_missing_file(tmp_path):
    with pytest.raises(InputError, match="file not found"):
        qtm.read(tmp_path / "nope.tsv")


# ---------------------------------------------------------------- sniff and describe
def test_sniff(tmp_path):
    rng = np.random.default_rng(17)
    assert qtm.sniff(qtm_text({"b": random_body(rng, 2)}))
    assert qtm.sniff(qtm_text({"b": random_body(rng, 2)}, version=False))
    assert not qtm.sniff("Format Version,1.23,Take Name,x\n\n,Type,Rigid Body\n")
    assert not qtm.sniff("Segments\n100\n,,s:a\nFrame,Sub Frame,RX,RY,RZ,TX,TY,TZ\n")
    assert not qtm.sniff("t,x,y,z,qx,qy,qz,qw\n0,1,2,3,0,0,0,1\n")


def test_describe_without_parsing_numbers(tmp_path):
    rng = np.random.default_rng(18)
    body = random_body(rng, 5)
    body["pos"] = body["pos"].astype(object)
    body["pos"][4][0] = "garbage"  # describe does not look at the numbers
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        d = qtm.describe(write(tmp_path, qtm_text({"a": body, "b": random_body(rng, 5)}, events=("go",))))
    assert d["format"] == "qtm" and d["layout"] == "current" and d["bodies"] == ["a", "b"]
    assert d["frames"] == 5 and d["rate_hz"] == 100.0 and d["length_unit"] == "mm"
    assert d["header"]["FILE_VERSION"] == "2.0.0" and d["events"] == [["go", "2", "0.02000"]]
    assert d["body_details"]["a"]["rotation"].startswith("Rot[] matrix")
