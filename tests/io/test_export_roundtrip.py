"""Write with rbgp_cli.io.export, read back with the vendor readers: the same poses to float precision."""

from __future__ import annotations

import tempfile
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from rbgp_cli.dynamics.trajectory import Trajectory
from rbgp_cli.errors import InputError
from rbgp_cli.io import export, motive, qtm, vicon
from rbgp_cli.io.options import ReadOptions

SETTINGS = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def assert_same_poses(expected: Trajectory, got: Trajectory, rot_atol=1e-12):
    """Same times, same lost rows (NaN), positions to 1e-12 and rotations to ``rot_atol`` (q ~ -q)."""
    assert got.name == expected.name
    np.testing.assert_array_equal(got.t, expected.t)
    lost = ~(np.all(np.isfinite(expected.quat), axis=1) & np.all(np.isfinite(expected.position), axis=1))
    np.testing.assert_array_equal(np.isnan(got.quat).all(axis=1), lost)
    assert np.isnan(got.position[lost]).all() and np.isfinite(got.position[~lost]).all()
    assert got.info["lost_frames"] == int(lost.sum())
    np.testing.assert_allclose(got.position[~lost], expected.position[~lost], rtol=1e-12, atol=1e-12)
    q_exp = expected.quat[~lost] / np.linalg.norm(expected.quat[~lost], axis=1, keepdims=True)
    q_got = got.quat[~lost]
    sign = np.where(np.sum(q_exp * q_got, axis=1) < 0, -1.0, 1.0)
    np.testing.assert_allclose(q_got * sign[:, None], q_exp, rtol=0, atol=rot_atol)


def euler_tolerance(bodies, seq):
    """scipy's ``as_euler`` treats rotations within ~1e-5 deg of gimbal lock as locked and then loses up
    to ~1e-8 (measured); everywhere else Euler round trips are exact to ~1e-15."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        mids = [Rotation.from_quat(b.quat[np.isfinite(b.quat).all(axis=1)]).as_euler(seq, degrees=True)[:, 1]
                for b in bodies if np.isfinite(b.quat).all(axis=1).any()]
    near_lock = any(np.any(np.abs(np.abs(m) - 90.0) < 1e-4) for m in mids)
    return 1e-7 if near_lock else 1e-12


# ---------------------------------------------------------------- random poses (hypothesis)
unit = st.floats(-1.0, 1.0, allow_nan=False)


@st.composite
def rotations(draw):
    """Quaternions x, y, z, w: uniform-ish, near the identity, and at or near θ = π."""
    kind = draw(st.sampled_from(["uniform", "near_identity", "near_pi", "pi"]))
    if kind == "uniform":
        q = np.array([draw(unit) for _ in range(4)])
        if np.linalg.norm(q) < 0.1:
            q = np.array([0.0, 0.0, 0.0, 1.0])
        return q / np.linalg.norm(q)
    axis = np.array([draw(unit) for _ in range(3)])
    axis = axis / np.linalg.norm(axis) if np.linalg.norm(axis) > 0.1 else np.array([0.0, 0.0, 1.0])
    eps = draw(st.sampled_from([0.0, 1e-12, 1e-9, 1e-6, 1e-3]))
    angle = {"near_identity": eps, "near_pi": np.pi - eps, "pi": np.pi}[kind]
    return np.array([*(np.sin(angle / 2) * axis), np.cos(angle / 2)])


@st.composite
def bodies(draw, uniform_times=True, max_bodies=3):
    n = draw(st.integers(1, 6))
    k = draw(st.integers(1, max_bodies))
    rate = draw(st.sampled_from([50.0, 100.0, 120.0, 256.0, 240.0]))
    if uniform_times or n == 1:
        t = np.arange(n) / rate
    else:
        t = np.cumsum([0.0] + [draw(st.floats(1e-4, 0.1)) for _ in range(n - 1)]) + draw(st.floats(0, 100))
    out = []
    for b in range(k):
        quat = np.array([draw(rotations()) for _ in range(n)])
        pos = np.array([[draw(st.floats(-5.0, 5.0, allow_nan=False)) for _ in range(3)] for _ in range(n)])
        lost = np.array([draw(st.booleans()) and draw(st.booleans()) for _ in range(n)])
        quat[lost] = np.nan
        pos[lost] = np.nan
        out.append(Trajectory(t=t, quat=quat, position=pos, name=f"Subject{b}:Body {b}", info={"rate": rate}))
    return out


def roundtrip(write, read, trajs, suffix, options):
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"take{suffix}"
        write(trajs, path)
        with open(path) as fh:
            head = fh.read(4096)
        sniffed = {name: mod.sniff(head) for name, mod in (("qtm", qtm), ("motive", motive), ("vicon", vicon))}
        return read(path, options), sniffed


@SETTINGS
@given(trajs=bodies(), layout=st.sampled_from(["current", "old"]), euler=st.sampled_from(["XYZ", "ZYX", "YXZ"]),
       unit=st.sampled_from(["mm", "cm", "m"]), lost=st.sampled_from(["zeros", "null", "empty"]))
@pytest.mark.slow
def test_qtm_roundtrip(trajs, layout, euler, unit, lost):
    def write(trs, path):
        export.write_qtm_tsv(trs, path, layout=layout, euler=euler, length_unit=unit, lost=lost,
                             rate=trs[0].info["rate"])

    back, sniffed = roundtrip(write, qtm.read, trajs, "_6D.tsv",
                              ReadOptions(body="all", length_unit=None if unit == "mm" else unit))
    assert sniffed == {"qtm": True, "motive": False, "vicon": False}
    for a, b in zip(trajs, back, strict=True):
        assert_same_poses(a, b)
        assert b.info["layout"] == layout and b.info["rotation_source"].startswith("Rot[]")


@SETTINGS
@given(trajs=bodies(uniform_times=False))
@pytest.mark.slow
def test_qtm_current_layout_keeps_irregular_times(trajs):
    back, _ = roundtrip(export.write_qtm_tsv, qtm.read, trajs, "_6D.tsv", ReadOptions(body="all"))
    for a, b in zip(trajs, back, strict=True):
        assert_same_poses(a, b)


@SETTINGS
@given(trajs=bodies(uniform_times=False), rotation_type=st.sampled_from(["Quaternion", "XYZ", "ZXY", "YZX"]),
       unit=st.sampled_from(["Meters", "Centimeters", "Millimeters"]), labels=st.booleans())
@pytest.mark.slow
def test_motive_roundtrip(trajs, rotation_type, unit, labels):
    def write(trs, path):
        export.write_motive_csv(trs, path, rotation_type=rotation_type, length_unit=unit, header_labels=labels)

    back, sniffed = roundtrip(write, motive.read, trajs, ".csv", ReadOptions(body="all"))
    assert sniffed == {"qtm": False, "motive": True, "vicon": False}
    tol = 1e-12 if rotation_type == "Quaternion" else euler_tolerance(trajs, rotation_type)
    for a, b in zip(trajs, back, strict=True):
        assert_same_poses(a, b, rot_atol=tol)
        assert b.info["length_unit"] == export.MOTIVE_UNITS[unit]


@SETTINGS
@given(trajs=bodies(), style=st.sampled_from([(",", False), (";", False), (";", True), ("\t", False)]),
       rotation=st.sampled_from(["helical", "XYZ", "zyx"]), unit=st.sampled_from(["mm", "cm", "m"]))
@pytest.mark.slow
def test_vicon_roundtrip(trajs, style, rotation, unit):
    delimiter, comma = style
    euler = None if rotation == "helical" else rotation

    def write(trs, path):
        export.write_vicon_csv(trs, path, delimiter=delimiter, decimal_comma=comma, length_unit=unit,
                               rotation="euler" if euler else "helical", euler_order=euler,
                               rate=trs[0].info["rate"])

    options = ReadOptions(body="all", rotation="euler" if euler else None, euler_order=euler)
    back, sniffed = roundtrip(write, vicon.read, trajs, ".csv", options)
    assert sniffed == {"qtm": False, "motive": False, "vicon": True}
    tol = euler_tolerance(trajs, euler) if euler else 1e-12
    for a, b in zip(trajs, back, strict=True):
        assert_same_poses(a, b, rot_atol=tol)


# ---------------------------------------------------------------- deterministic cases
def half_turns():
    """Rotations by exactly π about several axes (the rotation vector's ambiguous end), and just below."""
    axes = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, -1, 0], [1, 2, -2], [-3, 1, 5]], float)
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = np.repeat([np.pi, np.pi - 1e-9], len(axes))
    axes = np.tile(axes, (2, 1))
    quat = np.concatenate([np.sin(angles / 2)[:, None] * axes, np.cos(angles / 2)[:, None]], axis=1)
    t = np.arange(len(quat)) / 100.0
    pos = np.linspace([-1, 2, 0.5], [3, -2, 1.5], len(quat))
    return [Trajectory(t=t, quat=quat, position=pos, name="Sub:half"),
            Trajectory(t=t, quat=quat[::-1].copy(), position=-pos, name="Sub:other")]


@pytest.mark.parametrize("fmt", ["qtm-current", "qtm-old", "motive-quat", "motive-euler", "vicon-helical"])
def test_half_turns_survive_every_format(tmp_path, fmt):
    trajs = half_turns()
    path = tmp_path / "f"
    if fmt.startswith("qtm"):
        export.write_qtm_tsv(trajs, path, layout=fmt.split("-")[1])
        back = qtm.read(path, ReadOptions(body="all"))
    elif fmt.startswith("motive"):
        export.write_motive_csv(trajs, path, rotation_type="Quaternion" if fmt.endswith("quat") else "XYZ")
        back = motive.read(path, ReadOptions(body="all"))
    else:
        export.write_vicon_csv(trajs, path)
        back = vicon.read(path, ReadOptions(body="all"))
    for a, b in zip(trajs, back, strict=True):
        assert_same_poses(a, b)


def test_written_qtm_rot_is_column_major(tmp_path):
    quat = Rotation.from_euler("z", [[90.0]], degrees=True).as_quat()
    tr = Trajectory(t=[0.0], quat=quat, position=[[0.001, 0.002, 0.003]], name="b")
    export.write_qtm_tsv([tr], tmp_path / "b.tsv")
    lines = (tmp_path / "b.tsv").read_text().splitlines()
    header = lines[-2].split("\t")
    row = dict(zip(header, lines[-1].split("\t")))
    assert float(row["Rot[1]"]) == pytest.approx(1.0)  # r21: +x body axis points along +y world
    assert float(row["Rot[3]"]) == pytest.approx(-1.0)  # r12
    assert float(row["b X"]) == pytest.approx(1.0) and float(row["Yaw"]) == pytest.approx(90.0)
    assert lines[0] == "FILE_VERSION\t2.0.0" and lines[-1].endswith("\t")


def test_old_qtm_layout_matches_the_2010_shape(tmp_path):
    trajs = half_turns()
    export.write_qtm_tsv(trajs, tmp_path / "o.tsv", layout="old", euler="ZYX")
    raw = (tmp_path / "o.tsv").read_bytes()
    assert b"\r\n" in raw and b"FILE_VERSION" not in raw and b"Frame" not in raw
    lines = raw.decode().splitlines()
    assert lines[10].split("\t")[3:6] == [" Yaw", " Pitch", " Roll"]
    assert len(lines[11].split("\t")) == 2 * 17  # each body's 16 cells + an empty column


@pytest.mark.parametrize("lost", ["zeros", "null", "empty"])
def test_qtm_lost_encodings(tmp_path, lost):
    trajs = []
    for k, tr in enumerate(half_turns()):
        quat, pos = tr.quat.copy(), tr.position.copy()
        quat[[2, 5]] = np.nan
        pos[7 + k] = np.nan if k == 0 else pos[7 + k]
        trajs.append(tr.with_(quat=quat, position=pos))
    export.write_qtm_tsv(trajs, tmp_path / "l.tsv", lost=lost, layout="old")
    lost_row = (tmp_path / "l.tsv").read_text().splitlines()[11 + 2].split("\t")
    assert lost_row[:7] == {"zeros": ["0.0"] * 6 + ["-1.0"], "null": ["null"] * 7, "empty": [""] * 7}[lost]
    back = qtm.read(tmp_path / "l.tsv", ReadOptions(body="all"))
    for a, b in zip(trajs, back):
        assert_same_poses(a, b)
    assert back[0].info["lost_frames"] == 3 and back[1].info["lost_frames"] == 2


# ---------------------------------------------------------------- writer refusals
def test_bodies_must_share_times(tmp_path):
    a, b = half_turns()
    b = b.with_(t=b.t + 0.5)
    for write in (export.write_qtm_tsv, export.write_motive_csv, export.write_vicon_csv):
        with pytest.raises(InputError, match="share the same times"):
            write([a, b], tmp_path / "x")
    assert not (tmp_path / "x").exists()


def test_frame_based_layouts_need_uniform_times(tmp_path):
    (a, _) = half_turns()
    jitter = a.with_(t=a.t + np.r_[0, 1e-4, np.zeros(len(a) - 2)])
    with pytest.raises(InputError, match="multiples of 1/rate"):
        export.write_vicon_csv([jitter], tmp_path / "v.csv")
    with pytest.raises(InputError, match="multiples of 1/rate"):
        export.write_qtm_tsv([jitter], tmp_path / "q.tsv", layout="old")
    with pytest.raises(InputError, match="start at 0"):
        export.write_qtm_tsv([a.with_(t=a.t + 0.5)], tmp_path / "q.tsv", layout="old")
    export.write_qtm_tsv([jitter], tmp_path / "q.tsv")  # the current layout stores the times
    assert_same_poses(jitter, qtm.read(tmp_path / "q.tsv")[0])
    single = a.slice(slice(0, 1))
    with pytest.raises(InputError, match="pass rate=HZ"):
        export.write_vicon_csv([single], tmp_path / "v.csv")
    export.write_vicon_csv([single], tmp_path / "v.csv", rate=200.0)
    assert vicon.read(tmp_path / "v.csv")[0].info["rate_hz"] == 200.0


def test_writer_arguments_are_checked(tmp_path):
    trajs = half_turns()
    with pytest.raises(ValueError, match="layout"):
        export.write_qtm_tsv(trajs, tmp_path / "x", layout="new")
    with pytest.raises(ValueError, match="intrinsic sequence"):
        export.write_qtm_tsv(trajs, tmp_path / "x", euler="xyz")
    with pytest.raises(ValueError, match="rotation_type"):
        export.write_motive_csv(trajs, tmp_path / "x", rotation_type="Matrix")
    with pytest.raises(ValueError, match="length_unit"):
        export.write_motive_csv(trajs, tmp_path / "x", length_unit="Inches")
    with pytest.raises(ValueError, match="decimal_comma"):
        export.write_vicon_csv(trajs, tmp_path / "x", decimal_comma=True)
    with pytest.raises(ValueError, match="euler_order"):
        export.write_vicon_csv(trajs, tmp_path / "x", rotation="euler")
    assert not (tmp_path / "x").exists()
