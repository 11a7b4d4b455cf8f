"""The vendor readers on real exports in ../shared/realdata (skipped when absent; never copied here).

qtm_6d_tsv/: QTM 2010 layout, 3 bodies, 256 Hz, mm, ``Yaw Pitch Roll`` with R = Rz(yaw) Ry(pitch) Rx(roll).
motive_csv/: Motive 1.22, Euler X,Y,Z, 2 rigid bodies plus markers, 60 Hz, no Rotation Type or Length
Units in the header (the values are centimetres; modern Motive's Euler angles are relative XYZ).
"""

from __future__ import annotations

import csv

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rbgp_cli.errors import InputError
from rbgp_cli.io import motive, qtm, vicon
from rbgp_cli.io.options import ReadOptions
from tests.helpers import rx, ry, rz

pytestmark = pytest.mark.realdata

#: The files print 5 decimals: matrices agree with each other and with the angles to ~7e-6.
EXPORT_PRECISION = 2e-5




def files(realdata, folder):
    found = sorted((realdata / folder).glob("*"))
    if not found:
        pytest.skip(f"no files in {folder}")
    return found


def head(path):
    with open(path, encoding="utf-8", errors="replace") as fh:
        return fh.read(4096)


# ---------------------------------------------------------------- QTM
def qtm_raw(path):
    """Header values and each body's 16 raw numbers per row, parsed here independently of the reader."""
    lines = path.read_text().splitlines()
    header = {ln.split("\t")[0]: ln.split("\t")[1:] for ln in lines if ln.split("\t")[0].isupper()}
    start = next(i for i, ln in enumerate(lines) if ln.strip().startswith("X")) + 1
    names = [n for n in header["BODY_NAMES"] if n]
    cells = [ln.split("\t") for ln in lines[start:] if ln.strip(" ")]
    return header, {name: np.array([[float(c) for c in row[17 * k: 17 * k + 16]] for row in cells])
                    for k, name in enumerate(names)}


def test_every_qtm_file_reads_every_body(realdata):
    for path in files(realdata, "qtm_6d_tsv"):
        header, raw = qtm_raw(path)
        trajs = qtm.read(path, ReadOptions(body="all"))
        assert [t.name for t in trajs] == list(raw) == ["Upper Leg IMU", "Foot IMU", "Lower Leg IMU"]
        for tr in trajs:
            assert len(tr) == int(header["NO_OF_FRAMES"][0])
            np.testing.assert_array_equal(tr.t, np.arange(len(tr)) / 256.0)
            assert tr.info["layout"] == "old" and tr.info["rate_hz"] == 256.0 and tr.info["length_unit"] == "mm"
            np.testing.assert_allclose(tr.position, np.where(np.isnan(tr.position), np.nan, raw[tr.name][:, :3] / 1000))
        (foot,) = qtm.read(path, ReadOptions(body="Foot IMU"))
        assert foot.name == "Foot IMU"


def test_qtm_rows_agree_with_their_rot_matrices_and_euler_angles(realdata):
    checked = 0
    for path in files(realdata, "qtm_6d_tsv"):
        _, raw = qtm_raw(path)
        for tr in qtm.read(path, ReadOptions(body="all")):
            vals = raw[tr.name]
            lost = np.all(vals[:, 7:16] == 0.0, axis=1)
            np.testing.assert_array_equal(np.isnan(tr.quat).all(axis=1), lost)
            assert tr.info["lost_frames"] == int(lost.sum())
            got = Rotation.from_quat(tr.quat[~lost]).as_matrix()
            column_major = vals[~lost, 7:16].reshape(-1, 3, 3).transpose(0, 2, 1)  # Rot[1] = r21
            yaw, pitch, roll = vals[~lost, 3], vals[~lost, 4], vals[~lost, 5]
            euler = np.array([rz(y) @ ry(p) @ rx(r) for y, p, r in zip(yaw, pitch, roll)])
            assert np.max(np.abs(got - column_major)) < EXPORT_PRECISION
            assert np.max(np.abs(got - euler)) < EXPORT_PRECISION
            # the conventions matter: row-major Rot[] or the QTM-default angle order would be far off
            assert np.max(np.abs(got - column_major.transpose(0, 2, 1))) > 0.1
            assert np.max(np.abs(got - np.array([rx(r) @ ry(p) @ rz(y) for y, p, r in zip(yaw, pitch, roll)]))) > 0.1
            checked += int((~lost).sum())
    assert checked > 3000


def test_qtm_euler_fallback_reproduces_the_matrices(realdata):
    """Reading the angles instead of Rot[] (as for files without Rot[]) gives the same rotations."""
    path = files(realdata, "qtm_6d_tsv")[0]
    _, raw = qtm_raw(path)
    (tr,) = qtm.read(path, ReadOptions(body="Foot IMU"))
    vals = raw["Foot IMU"]
    from_angles = Rotation.from_euler("ZYX", vals[:, 3:6], degrees=True).as_matrix()  # header order Yaw Pitch Roll
    assert np.max(np.abs(Rotation.from_quat(tr.quat).as_matrix() - from_angles)) < EXPORT_PRECISION


# ---------------------------------------------------------------- Motive
def test_motive_file_needs_units_and_euler_order(realdata):
    for path in files(realdata, "motive_csv"):
        with pytest.raises(InputError) as err:
            motive.read(path, ReadOptions(body="RigidBody 01"))
        assert "length_unit" in str(err.value) and "euler_order" in str(err.value)
        with pytest.raises(InputError, match="2 rigid bodies: 'RigidBody 01', 'RigidBody 02'"):
            motive.read(path, ReadOptions(length_unit="cm", euler_order="XYZ"))


def test_motive_rows_against_hand_computation(realdata):
    for path in files(realdata, "motive_csv"):
        with open(path, newline="") as fh:
            rows = list(csv.reader(fh))
        names, fields = rows[3], rows[5]
        trajs = motive.read(path, ReadOptions(body="all", length_unit="cm", euler_order="XYZ"))
        assert [t.name for t in trajs] == ["RigidBody 01", "RigidBody 02"]
        for tr in trajs:
            rot = [j for j, (n, f) in enumerate(zip(names, fields)) if n == tr.name and f == "Rotation"]
            pos = [j for j, (n, f) in enumerate(zip(names, fields)) if n == tr.name and f == "Position"]
            data = np.array([[float(r[j]) for j in rot + pos] for r in rows[7:]])
            expected = np.array([rx(a) @ ry(b) @ rz(c) for a, b, c in data[:, :3]])  # relative X, then Y, then Z
            np.testing.assert_allclose(Rotation.from_quat(tr.quat).as_matrix(), expected, atol=1e-12)
            np.testing.assert_allclose(tr.position, data[:, 3:] / 100.0, rtol=1e-15)
            np.testing.assert_array_equal(tr.t, [float(r[1]) for r in rows[7:]])
            assert len(tr) == 227 and tr.info["rate_hz"] == 60.0 and tr.info["lost_frames"] == 0
            assert tr.info["ignored_assets"]["Marker"] == 11
            # near-static bodies: heights of 1.5-1.6 m are plausible in cm, not in mm
            assert 1.4 < np.median(tr.position[:, 1]) < 1.7


# ---------------------------------------------------------------- sniffing and describe
def test_sniffers_recognise_their_own_files_only(realdata):
    sniffers = {"qtm": qtm.sniff, "motive": motive.sniff, "vicon": vicon.sniff}
    expected = {"qtm_6d_tsv": "qtm", "motive_csv": "motive", "handover_object_csv": None, "kth_handover_csv": None}
    for folder, owner in expected.items():
        for path in files(realdata, folder)[:5]:
            text = head(path)
            assert {name: f(text) for name, f in sniffers.items()} == {n: n == owner for n in sniffers}, path


def test_describe_real_files(realdata):
    (q,) = files(realdata, "qtm_6d_tsv")[:1]
    d = qtm.describe(q)
    assert d["bodies"] == ["Upper Leg IMU", "Foot IMU", "Lower Leg IMU"] and d["rate_hz"] == 256.0
    assert d["layout"] == "old" and d["frames"] == int(d["header"]["NO_OF_FRAMES"])
    (m,) = files(realdata, "motive_csv")
    d = motive.describe(m)
    assert d["bodies"] == ["RigidBody 01", "RigidBody 02"] and d["frames"] == 227 and d["rate_hz"] == 60.0
    assert d["length_unit"] is None and d["rotation_type"] is None
    assert d["header"]["Format Version"] == "1.22"
