"""C3D in: rigid clusters from markers, the per-frame rigid fit, stored ROTATION bodies, the spec's lost
points / units / first frame / events, and one-line errors. Synthetic files are written with ezc3d
(the library the reader uses), with a known rigid motion; the oracles are that motion and scipy's
``Rotation.align_vectors``."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from rbgp_cli.errors import InputError, NotPoseData
from rbgp_cli.io import c3d, markers
from rbgp_cli.io.options import ReadOptions
from rbgp_cli.io.vocabulary import LENGTH_UNITS
from rbgp_cli.io.read import detect_format, read_demonstrations, read_sources
from tests.helpers import rotation_angle_between

ezc3d = pytest.importorskip("ezc3d")

RATE = 100.0
#: the tool's markers in its own frame, metres (not coplanar, ~10 cm apart)
TOOL = np.array([[0.0, 0.0, 0.0], [0.12, 0.0, 0.01], [0.0, 0.09, 0.0], [0.05, 0.04, 0.07], [0.1, 0.1, -0.02]])


def true_motion(n: int):
    """A known smooth rigid motion: ``R_world_tool`` (n, 3, 3) and ``p_world_tool`` (n, 3), metres."""
    s = np.linspace(0.0, 1.0, n)
    rotvec = np.stack([0.8 * np.sin(2 * s), 1.2 * s, 0.3 * np.cos(3 * s)], axis=1)
    pos = np.stack([0.2 + 0.4 * s, -0.1 + 0.2 * np.sin(3 * s), 0.7 + 0.3 * s**2], axis=1)
    return Rotation.from_rotvec(rotvec).as_matrix(), pos


def write_c3d(path, labels, xyz_m, *, unit="mm", residual=None, first_frame=1, events=(), rotations=None,
              rotation_labels=()):
    """A C3D file written by ezc3d: markers ``xyz_m`` (F, n, 3) in metres (NaN: lost, written as
    residual -1), in ``unit``; ``residual`` (F, n) overrides the residual words."""
    scale = {"mm": 1e3, "m": 1.0, "cm": 1e2}[unit]
    f, n, _ = xyz_m.shape
    c = ezc3d.c3d()
    c["parameters"]["POINT"]["RATE"]["value"] = [RATE]
    c["parameters"]["POINT"]["LABELS"]["value"] = tuple(labels)
    c["parameters"]["POINT"]["UNITS"]["value"] = [unit]
    pts = np.ones((4, n, f))
    pts[:3] = np.nan_to_num(xyz_m * scale).transpose(2, 1, 0)
    res = np.zeros((1, n, f)) if residual is None else np.asarray(residual, float).T[None].copy()
    res[0][np.isnan(xyz_m).any(-1).T] = -1.0
    c["data"]["points"] = pts
    c["data"]["meta_points"]["residuals"] = res
    if rotations is not None:
        c["data"]["rotations"] = rotations
        c.add_parameter("ROTATION", "LABELS", list(rotation_labels))
    if events:
        c.add_parameter("EVENT", "USED", [len(events)])
        c.add_parameter("EVENT", "CONTEXTS", [e[0] for e in events])
        c.add_parameter("EVENT", "LABELS", [e[1] for e in events])
        c.add_parameter("EVENT", "TIMES", np.array([[0.0] * len(events), [e[2] for e in events]]))
    c["header"]["points"]["first_frame"] = first_frame - 1  # ezc3d counts frames from 0
    c.write(str(path))
    return path


def tool_take(n=200, noise=3e-4, seed=0):
    """Markers of the tool (5, rigid, noisy) and 3 skin markers that drift apart, and the truth."""
    rng = np.random.default_rng(seed)
    r, p = true_motion(n)
    tool = np.einsum("fij,nj->fni", r, TOOL) + p[:, None] + rng.normal(0, noise, (n, len(TOOL), 3))
    skin = np.cumsum(rng.normal(0, 2e-3, (n, 3, 3)), axis=0) + np.array([[0.5, 0, 1], [0.6, 0, 1], [0.5, 0.1, 1]])
    labels = [f"tool:m{k + 1}" for k in range(len(TOOL))] + ["skin:a", "skin:b", "skin:c"]
    return labels, np.concatenate([tool, skin], axis=1), r, p


def expected_pose(r, p, ref_frame: int):
    """The reader's convention: origin at the markers' centroid, axes of the lab at the first
    complete frame -> ``R_world_body = R(t) R(ref)ᵀ``, ``p = R(t) mean(TOOL) + p(t)``."""
    return r @ r[ref_frame].T, np.einsum("fij,j->fi", r, TOOL.mean(axis=0)) + p


# ------------------------------------------------------------------------------------------------
# the fit itself

@settings(max_examples=40, deadline=None)
@given(st.integers(0, 10_000), st.integers(3, 9))
def test_kabsch_agrees_with_scipy_align_vectors(seed, n):
    rng = np.random.default_rng(seed)
    ref = rng.normal(0, 0.1, (n, 3))
    rot = Rotation.random(random_state=seed)
    obs = rot.apply(ref) + rng.normal(0, 0.5, 3) + rng.normal(0, 1e-3, (n, 3))
    w = np.ones(n)
    w[rng.choice(n, size=max(0, n - 3 - rng.integers(0, n - 2)), replace=False)] = 0.0  # >= 3 seen
    r_fit, t_fit, rms = markers.kabsch(ref, obs[None], w[None])
    keep = w > 0
    c_ref, c_obs = ref[keep].mean(0), obs[keep].mean(0)
    oracle, _ = Rotation.align_vectors(obs[keep] - c_obs, ref[keep] - c_ref)
    assert rotation_angle_between(Rotation.from_matrix(r_fit[0]).as_rotvec(), oracle.as_rotvec()) < 1e-7
    assert np.allclose(t_fit[0], c_obs - r_fit[0] @ c_ref, atol=1e-12)
    fitted = ref[keep] @ r_fit[0].T + t_fit[0]
    assert np.isclose(rms[0], np.sqrt(np.mean(np.sum((fitted - obs[keep]) ** 2, axis=1))))


def test_kabsch_never_returns_a_reflection():
    ref = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    mirrored = ref * np.array([1, 1, -1])  # the best orthogonal fit is a reflection
    r, _, rms = markers.kabsch(ref, mirrored[None], np.ones((1, 4)))
    assert np.isclose(np.linalg.det(r[0]), 1.0)
    assert rms[0] > 0.1  # a rotation cannot match a mirror image


def test_fit_poses_marks_frames_with_too_few_or_collinear_markers_lost():
    shape = TOOL - TOOL.mean(axis=0)
    pts = np.repeat(shape[None], 4, axis=0).copy()
    pts[1, 2:] = np.nan  # two seen
    pts[2, [0, 2, 4]] = np.nan  # two seen
    line = np.array([[0, 0, 0], [0.1, 0, 0], [0.2, 0, 0], [0.0, 0.1, 0.0], [0.1, 0.1, 0.05]])
    pts_line = np.repeat(line[None], 2, axis=0).copy()
    pts_line[1, 3:] = np.nan  # the three seen lie on a line
    *_, lost = markers.fit_poses(pts, shape)
    assert lost.tolist() == [False, True, True, False]
    *_, lost_line = markers.fit_poses(pts_line, line - line.mean(axis=0))
    assert lost_line.tolist() == [False, True]


# ------------------------------------------------------------------------------------------------
# synthetic C3D files

def test_a_known_rigid_motion_with_noise_and_dropped_markers_is_recovered(tmp_path):
    labels, xyz, r, p = tool_take()
    rng = np.random.default_rng(1)
    residual = np.zeros(xyz.shape[:2])
    drop = rng.random((len(xyz), 5)) < 0.25
    drop[0] = False  # the first frame sees every marker: the reference frame
    xyz[:, :5][drop] = np.nan  # residual -1, coordinates zero
    kept = rng.random((len(xyz), 5)) < 0.05  # interpolated coordinates kept, but residual -1
    kept[0] = False
    residual[:, :5][kept & ~drop] = -1.0
    zeros = np.zeros((len(xyz), 5), bool)
    zeros[10, 1] = True  # a lost point written as zeros with a valid residual
    xyz[10, 1] = 0.0
    few = [40, 41, 42]
    xyz[few, 2:5] = np.nan  # only two markers seen: no pose
    path = write_c3d(tmp_path / "tool.c3d", labels, xyz, residual=residual, first_frame=50,
                     events=[("Left", "Foot Strike", 0.75)])
    assert detect_format(path) == "c3d"
    (tr,) = read_demonstrations([str(path)], ReadOptions(body="tool"))
    assert tr.info["format"] == "c3d" and tr.info["markers"] == labels[:5]
    assert np.allclose(tr.t, (49 + np.arange(len(xyz))) / RATE)  # frame k at (k - 1) / rate
    assert tr.info["first_frame"] == 50 and tr.info["events"] == [["Left", "Foot Strike", 0.75]]
    seen = (~drop & ~kept).sum(axis=1)
    seen[10] -= int(not drop[10, 1] and not kept[10, 1])
    seen[few] = np.minimum(seen[few], 2)
    lost = np.isnan(tr.position).any(axis=1)
    assert lost[few].all()
    assert (lost == (seen < 3)).all(), "frames are lost exactly where fewer than three markers are seen"
    r_exp, p_exp = expected_pose(r, p, 0)
    ok = ~lost
    # noise 0.3 mm per coordinate on markers ~10 cm apart: ~0.3 mm / ~0.3 mrad from 3-5 markers
    pos_err = np.linalg.norm(tr.position[ok] - p_exp[ok], axis=1)
    ang_err = rotation_angle_between(Rotation.from_quat(tr.quat[ok]).as_rotvec(), Rotation.from_matrix(r_exp[ok]).as_rotvec())
    assert pos_err.max() < 2e-3 and np.median(pos_err) < 5e-4
    assert ang_err.max() < 0.03 and np.median(ang_err) < 6e-3
    rms = np.array([np.nan if v is None else v for v in tr.info["fit_rms_m"]])
    assert np.nanmedian(rms[ok]) < 1e-3 and np.isnan(rms[few]).all()


def test_inspect_finds_the_rigid_cluster_and_not_the_drifting_markers(tmp_path):
    labels, xyz, *_ = tool_take()
    path = write_c3d(tmp_path / "tool.c3d", labels, xyz)
    desc = c3d.describe(path)
    assert [c["name"] for c in desc["clusters"]] == ["tool"]
    assert desc["clusters"][0]["markers"] == labels[:5]
    assert desc["clusters"][0]["max_distance_std_m"] < 1e-3
    assert [p["label"] for p in desc["points"]] == labels
    # with one rigid body the file reads without naming it, and by its markers too
    (a,) = c3d.read(path)
    (b,) = c3d.read(path, ReadOptions(body=",".join(labels[:5])))
    assert np.allclose(a.position, b.position) and np.allclose(a.quat, b.quat)


def test_a_frame_with_a_swapped_marker_is_lost_not_fitted(tmp_path):
    labels, xyz, *_ = tool_take(noise=1e-4)
    xyz[30, [0, 1]] = xyz[30, [1, 0]]  # two labels swapped for one frame: 12 cm off
    (tr,) = c3d.read(write_c3d(tmp_path / "swap.c3d", labels, xyz), ReadOptions(body="tool"))
    lost = np.isnan(tr.position).any(axis=1)
    assert lost.tolist() == [i == 30 for i in range(len(xyz))]
    assert tr.info["frames_over_tol"] == 1 and tr.info["fit_rms_m"][30] > markers.FIT_RMS_TOL_M
    # the swapped frame is left out of the reference shape: the other frames fit as well as the noise
    # (0.1 mm per coordinate on 5 markers: ~0.13 mm RMS)
    assert np.nanmedian(np.array([np.nan if v is None else v for v in tr.info["fit_rms_m"]])) < 2.5e-4
    xyz[0, [0, 1]] = xyz[0, [1, 0]]  # a swap in the first frame too: the body frame is the next one's
    (tr,) = c3d.read(write_c3d(tmp_path / "swap0.c3d", labels, xyz), ReadOptions(body="tool"))
    assert "at frame 2" in tr.info["body_frame"] and tr.info["frames_over_tol"] == 2


@pytest.mark.parametrize("unit", ["mm", "cm", "m"])
def test_point_units_are_followed_and_length_unit_overrides_them(tmp_path, unit):
    labels, xyz, *_ = tool_take(noise=0.0)
    (mm,) = c3d.read(write_c3d(tmp_path / "mm.c3d", labels, xyz), ReadOptions(body="tool"))
    other = write_c3d(tmp_path / f"{unit}.c3d", labels, xyz, unit=unit)
    (tr,) = c3d.read(other, ReadOptions(body="tool"))
    assert tr.info["length_unit"] == unit and np.allclose(tr.position, mm.position, atol=1e-6)
    # said otherwise, the file's numbers are taken in that unit (m: the tool 100 or 1000 times larger)
    (forced,) = c3d.read(other, ReadOptions(body="tool", length_unit="m"))
    assert forced.info["length_unit_source"] == "length_unit"
    assert np.allclose(forced.position, mm.position / LENGTH_UNITS[unit], rtol=1e-5, atol=1e-6 / LENGTH_UNITS[unit])


def test_a_stored_rotation_body_is_read_as_stored(tmp_path):
    labels, xyz, r, p = tool_take(n=50)
    mats = np.zeros((4, 4, 1, 50))
    mats[:3, :3, 0] = r.transpose(1, 2, 0)
    mats[:3, 3, 0] = (p * 1e3).T  # POINT:UNITS mm
    mats[3, 3, 0] = 1.0
    mats[:, :, 0, 7] = np.nan  # a lost frame
    path = write_c3d(tmp_path / "seg.c3d", labels, xyz, rotations=mats, rotation_labels=["pelvis"])
    desc = c3d.describe(path)
    assert desc["stored_bodies"] == ["pelvis"] and set(desc["bodies"]) == {"pelvis", "tool"}
    (tr,) = c3d.read(path, ReadOptions(body="Pelvis"))
    assert tr.info["body_kind"] == "stored 6-DOF body"
    ok = np.arange(50) != 7
    assert np.isnan(tr.position[7]).all() and not np.isnan(tr.position[ok]).any()
    assert np.allclose(tr.position[ok], p[ok], atol=1e-6)
    assert rotation_angle_between(Rotation.from_quat(tr.quat[ok]).as_rotvec(),
                                  Rotation.from_matrix(r[ok]).as_rotvec()).max() < 1e-5
    with pytest.raises(InputError, match="2 rigid bodies"):
        c3d.read(path)  # two to choose from
    assert {t.name for t in c3d.read(path, ReadOptions(body="all"))} == {"pelvis", "tool"}


# ------------------------------------------------------------------------------------------------
# bad input: one line naming the file and what to do

def one_line(exc, path) -> str:
    text = str(exc.value)
    assert "\n" not in text and str(path) in text
    return text


def test_unknown_body_too_few_markers_and_a_single_marker_are_one_line_errors(tmp_path):
    labels, xyz, *_ = tool_take(n=30)
    path = write_c3d(tmp_path / "tool.c3d", labels, xyz)
    with pytest.raises(InputError) as exc:
        c3d.read(path, ReadOptions(body="tol"))
    assert "did you mean 'tool'" in one_line(exc, path)
    with pytest.raises(InputError) as exc:
        c3d.read(path, ReadOptions(body="tool:m1,tool:m2"))
    assert "at least 3 markers" in one_line(exc, path)
    with pytest.raises(InputError) as exc:
        c3d.read(path, ReadOptions(body="tool:m1,tool:m2,tool:m9"))
    assert "no marker labelled 'tool:m9'" in one_line(exc, path)
    with pytest.raises(InputError) as exc:
        c3d.read(path, ReadOptions(body="m1"))
    assert "is one marker" in one_line(exc, path)
    xyz2 = xyz.copy()
    xyz2[:, 0] = np.nan
    xyz2[::2, 1] = np.nan
    labels2 = ["RTH1", "RTH2", "RTH3", "X4", "X5"] + labels[5:]
    with pytest.raises(InputError) as exc:
        c3d.read(write_c3d(tmp_path / "rth.c3d", labels2, xyz2), ReadOptions(body="RTH"))
    assert "no frame sees all 3 markers" in one_line(exc, tmp_path / "rth.c3d")


def test_truncated_and_non_c3d_files_are_one_line_errors(tmp_path):
    labels, xyz, *_ = tool_take(n=60)
    data = write_c3d(tmp_path / "tool.c3d", labels, xyz).read_bytes()
    data_start = (int.from_bytes(data[16:18], "little") - 1) * 512  # header word 9: the first data block
    end = data_start + 60 * len(labels) * 16  # float storage: 4 words of 4 bytes per point and frame
    assert len(data) >= end
    for cut in (end - 1, len(data) // 2, 700, 300):
        bad = tmp_path / f"cut{cut}.c3d"
        bad.write_bytes(data[:cut])
        with pytest.raises(InputError) as exc:
            c3d.read(bad, ReadOptions(body="tool"))
        one_line(exc, bad)
    text = tmp_path / "notes.c3d"
    text.write_text("hello")
    with pytest.raises(InputError) as exc:
        read_demonstrations([str(text)], ReadOptions(format="c3d"))
    assert "not a C3D file" in one_line(exc, text)


def test_a_crash_of_the_c3d_library_is_an_input_error(tmp_path, monkeypatch):
    """ezc3d (C++) ends the process on some damaged files; rbgp reads in a process of its own."""
    import os
    import signal
    import sys

    if not sys.platform.startswith("linux"):
        pytest.skip("the reading process is forked on Linux only (monkeypatch reaches it there)")
    labels, xyz, *_ = tool_take(n=20)
    path = write_c3d(tmp_path / "tool.c3d", labels, xyz)
    monkeypatch.setattr(c3d, "_ezc3d_contents", lambda p: os.kill(os.getpid(), signal.SIGSEGV))
    c3d._cache.clear()
    with pytest.raises(InputError) as exc:
        c3d.read(path, ReadOptions(body="tool"))
    assert "SIGSEGV" in one_line(exc, path) and "damaged" in str(exc.value)


@pytest.mark.slow
@settings(max_examples=40, deadline=None, derandomize=True)
@given(st.lists(st.tuples(st.integers(0, 2), st.integers(0, 10**6), st.integers(1, 64), st.integers(0, 255)),
                min_size=1, max_size=5))
def test_damaged_c3d_files_read_or_are_input_errors(edits):
    """Bytes flipped, overwritten or deleted anywhere (a deletion in the parameter section made ezc3d
    crash in-process): the reader returns trajectories or raises InputError, nothing else."""
    import tempfile
    from pathlib import Path

    labels, xyz, *_ = tool_take(n=30)
    with tempfile.TemporaryDirectory() as d:
        data = bytearray(write_c3d(Path(d) / "base.c3d", labels, xyz).read_bytes())
        for op, at, length, value in edits:
            i = at % len(data)
            if op == 0:
                data[i] ^= 1 << (value % 8)
            elif op == 1:
                data[i] = value
            else:
                del data[i : i + length]
        bad = Path(d) / "bad.c3d"
        bad.write_bytes(bytes(data))
        try:
            trajs = c3d.read(bad, ReadOptions(body="tool"))
        except InputError as exc:
            assert "\n" not in str(exc) and str(bad) in str(exc)
        else:
            assert all(len(t.t) == len(t.quat) == len(t.position) for t in trajs)


def test_a_c3d_without_any_rigid_body_is_skipped_in_a_folder(tmp_path):
    rng = np.random.default_rng(3)
    skin = np.cumsum(rng.normal(0, 3e-3, (40, 4, 3)), axis=0) + rng.normal(0, 0.2, (1, 4, 3))
    folder = tmp_path / "takes"
    folder.mkdir()
    labels, xyz, *_ = tool_take(n=40)
    write_c3d(folder / "a_tool.c3d", labels, xyz)
    write_c3d(folder / "b_skin.c3d", ["s1", "s2", "s3", "s4"], skin)
    with pytest.warns(Warning, match="b_skin.c3d"):
        trajs, listing = read_sources([str(folder)])
    assert [t.name for t in trajs] == ["tool"] and listing.skipped[0][1] == "C3D markers without a rigid cluster"
    with pytest.raises(NotPoseData):
        c3d.read(folder / "b_skin.c3d")


# ------------------------------------------------------------------------------------------------
# the real Vicon trial

@pytest.mark.slow
@pytest.mark.realdata
def test_the_vicon_box_lift_reads_the_box_cluster(realdata):
    path = realdata / "c3d_vicon" / "box_lift_vicon.c3d"
    if not path.exists():
        pytest.skip("c3d_vicon/box_lift_vicon.c3d not found")
    desc = c3d.describe(path)
    box = [c for c in desc["clusters"] if c["name"] == "boite"]
    assert len(box) == 1 and len(box[0]["markers"]) == 8
    assert all(m.startswith("boite:") for m in box[0]["markers"])
    assert desc["frames"] == 580 and desc["rate_hz"] == 100.0 and desc["length_unit"] == "mm"
    assert sum(p["lost_frames"] for p in desc["points"][:8]) == 24  # box markers lost (residual -1)
    (tr,) = c3d.read(path, ReadOptions(body="boite"))
    assert len(tr) == 580 and np.isclose(tr.t[-1] - tr.t[0], 5.79)
    lost = np.isnan(tr.position).any(axis=1)
    assert tr.info["lost_frames"] == int(lost.sum()) and not lost.all()
    # the box goes from ~0.70 m up to ~1.03 m
    assert 0.65 < np.nanmin(tr.position[:, 2]) < 0.75 and 1.0 < np.nanmax(tr.position[:, 2]) < 1.08
    # frames that lost box markers are fitted from the others: the same pose as with every marker,
    # checked by dropping markers from complete frames
    take = c3d.load(path)
    pts = take.points[:, :8].copy()
    full = np.flatnonzero(np.isfinite(pts).all(axis=(1, 2)))
    shape, _, _ = markers.reference_shape(pts)
    r_all, t_all, *_ = markers.fit_poses(pts[full], shape)
    dropped = pts[full].copy()
    dropped[:, [0, 2, 5]] = np.nan  # the 5 others remain
    r_d, t_d, *_ = markers.fit_poses(dropped, shape)
    assert np.nanmax(np.linalg.norm(t_all - t_d, axis=1)) < 3e-3
    assert np.median(np.linalg.norm(t_all - t_d, axis=1)) < 5e-4


def test_cliques_fall_back_to_greedy_growth_on_a_dense_graph(monkeypatch):
    # two rigid groups {0,1,2,3} and {4,5,6} plus a spurious edge 3-4
    adj = [set() for _ in range(7)]
    for group in ((0, 1, 2, 3), (4, 5, 6)):
        for i in group:
            adj[i] |= set(group) - {i}
    adj[3].add(4)
    adj[4].add(3)
    exact = markers._maximal_cliques(adj)
    assert sorted(map(sorted, exact)) == [[0, 1, 2, 3], [3, 4], [4, 5, 6]]
    monkeypatch.setattr(markers, "CLIQUE_STEPS", 2)
    assert markers._maximal_cliques(adj) is None
    assert sorted(map(sorted, markers._greedy_cliques(adj))) == [[0, 1, 2, 3], [4, 5, 6]]


def test_the_column_median_skips_nan_as_numpy_does():
    rng = np.random.default_rng(5)
    a = rng.normal(size=(31, 9))
    a[rng.random(a.shape) < 0.3] = np.nan
    a[:2, 0] = 1.0  # at least one finite value per column
    assert np.allclose(markers._column_median(a), np.nanmedian(a, axis=0))


def test_trial_actual_fields_give_frame_numbers_past_the_headers_16_bits():
    # Vicon keeps frame numbers above 65535 in TRIAL:ACTUAL_START_FIELD / ACTUAL_END_FIELD (low, high words)
    params = {"TRIAL": {"ACTUAL_START_FIELD": {"value": [4464, 1]}, "ACTUAL_END_FIELD": {"value": [-1, 1]}}}
    assert c3d._actual_fields(params) == (70000, 131071)
    assert c3d._actual_fields({"TRIAL": {}}) is None
