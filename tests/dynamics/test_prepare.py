"""rbgp_cli.dynamics.prepare: lost frames, normalisation, sign continuity, time and step checks."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation, Slerp

from rbgp_cli.dynamics.prepare import STEP_LIMIT, prepare_all, prepare_trajectory
from rbgp_cli.dynamics.trajectory import Trajectory
from rbgp_cli.errors import InputError, RbgpWarning


def smooth(n=20, seed=0, dt=0.01):
    """A smooth trajectory: rotation about a fixed axis at 2 rad/s plus a random walk in position."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * dt + 1.0
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    q = Rotation.from_rotvec(np.outer(2.0 * t, axis)).as_quat()
    p = np.cumsum(rng.normal(scale=0.01, size=(n, 3)), axis=0)
    return Trajectory(t=t, quat=q, position=p, name="demo", source="d.csv", info={"first_data_line": 2})


def same_rotation(q1, q2, atol=1e-12):
    return np.all(np.abs(np.abs(np.sum(q1 * q2, axis=-1)) - 1.0) < atol)


def prep(tr, **kw):
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        clean, rep = prepare_trajectory(tr, **kw)
    return clean, rep, [str(x.message) for x in w if issubclass(x.category, RbgpWarning)]


def test_clean_input_passes_unchanged_without_warning():
    tr = smooth()
    clean, rep, warns = prep(tr)
    np.testing.assert_array_equal(clean.t, tr.t)
    np.testing.assert_allclose(clean.quat, tr.quat, atol=1e-15)
    assert rep["lost"] == rep["filled"] == rep["duplicates"] == rep["sign_flips"] == 0
    assert warns == []
    assert clean.info["repairs"] == rep and clean.info["first_data_line"] == 2


def test_nan_rows_and_zero_quaternions_are_dropped():
    tr = smooth()
    q, p, t = tr.quat.copy(), tr.position.copy(), tr.t.copy()
    q[3] = np.nan
    p[7, 1] = np.nan
    q[10] = 0.0  # proto3 default: no rotation recorded
    t[12] = np.inf
    clean, rep, warns = prep(tr.with_(t=t, quat=q, position=p))
    keep = np.setdiff1d(np.arange(20), [3, 7, 10, 12])
    np.testing.assert_array_equal(clean.t, tr.t[keep])
    assert rep["lost"] == 4 and rep["dropped"] == 4 and rep["filled"] == 0
    assert len(warns) == 1 and "dropped 4 lost frames" in warns[0] and "d.csv" in warns[0]


def test_gap_filling_lies_on_the_slerp_between_neighbours():
    tr = smooth(n=30)
    q, p = tr.quat.copy(), tr.position.copy()
    q[5:8] = np.nan  # gap: valid 4 and 8 are 0.04 s apart
    p[20:26] = np.nan  # gap: valid 19 and 26 are 0.07 s apart
    clean, rep, warns = prep(tr.with_(quat=q, position=p), max_gap=0.05)
    assert rep["filled"] == 3 and rep["dropped"] == 6 and rep["lost"] == 9
    assert "filled 3 lost frames" in warns[0] and "dropped 6 lost frames" in warns[0]
    kept_t = np.concatenate([tr.t[:20], tr.t[26:]])
    np.testing.assert_array_equal(clean.t, kept_t)
    # oracle: scipy's Slerp between samples 4 and 8, linear position
    slerp = Slerp(tr.t[[4, 8]], Rotation.from_quat(tr.quat[[4, 8]]))
    expected = slerp(tr.t[5:8]).as_quat()
    assert same_rotation(clean.quat[5:8], expected, atol=1e-12)
    u = (tr.t[5:8] - tr.t[4]) / (tr.t[8] - tr.t[4])
    np.testing.assert_allclose(clean.position[5:8], tr.position[4] + u[:, None] * (tr.position[8] - tr.position[4]), atol=1e-15)
    # the rotation is uniform about one axis, so slerp reproduces the true samples
    assert same_rotation(clean.quat[5:8], tr.quat[5:8], atol=1e-12)


def test_leading_and_trailing_lost_frames_are_never_filled():
    tr = smooth()
    q = tr.quat.copy()
    q[:2] = np.nan
    q[-1] = np.nan
    clean, rep, _ = prep(tr.with_(quat=q), max_gap=10.0)
    assert rep["filled"] == 0 and len(clean) == 17


def test_far_from_unit_quaternion_is_an_error_naming_the_line():
    tr = smooth()
    q = tr.quat.copy()
    q[6] *= 1.5
    with pytest.raises(InputError) as e:
        prepare_trajectory(tr.with_(quat=q))
    msg = str(e.value)
    assert msg.startswith("d.csv:8: demo: quaternion norm 1.5 at sample 7") and "(columns, quat_order)" in msg


def test_error_without_line_information_names_the_sample():
    tr = smooth()
    q = tr.quat.copy()
    q[6] *= 3
    with pytest.raises(InputError, match=r"^d\.csv: demo: quaternion norm 3 at sample 7 \(t = 1\.06 s\)"):
        prepare_trajectory(Trajectory(tr.t, q, tr.position, name="demo", source="d.csv"))


def test_line_runs_map_samples_to_lines():
    tr = smooth()
    q = tr.quat.copy()
    q[12] *= 2
    bad = Trajectory(tr.t, q, tr.position, name="d", source="f.csv", info={"line_runs": [[2, 10], [40, 10]]})
    with pytest.raises(InputError, match=r"^f\.csv:42: "):
        prepare_trajectory(bad)


def test_slightly_non_unit_quaternions_are_normalised():
    tr = smooth()
    q = tr.quat * np.linspace(0.95, 1.05, 20)[:, None]
    clean, rep, warns = prep(tr.with_(quat=q))
    np.testing.assert_allclose(np.linalg.norm(clean.quat, axis=1), 1.0, atol=1e-15)
    assert same_rotation(clean.quat, tr.quat)
    assert rep["max_norm_deviation"] == pytest.approx(0.05)
    assert "normalised quaternions" in warns[0]


def test_sign_flips_are_repaired_and_rotations_kept():
    tr = smooth()
    signs = np.where(np.random.default_rng(3).random(20) < 0.5, -1.0, 1.0)
    flipped = tr.quat * signs[:, None]
    clean, rep, warns = prep(tr.with_(quat=flipped))
    assert same_rotation(clean.quat, tr.quat)
    assert np.all(np.sum(clean.quat[1:] * clean.quat[:-1], axis=1) > 0)
    assert rep["sign_flips"] == int(np.sum(signs[1:] != signs[:-1]))
    assert "sign flip" in warns[0]


@settings(max_examples=30, deadline=None)
@given(st.lists(st.booleans(), min_size=3, max_size=40), st.integers(0, 2**31 - 1))
def test_sign_continuity_property(flips, seed):
    n = len(flips)
    tr = smooth(n=n, seed=seed % 1000)
    flipped = tr.quat * np.where(flips, -1.0, 1.0)[:, None]
    clean, rep, _ = prep(tr.with_(quat=flipped))
    assert same_rotation(clean.quat, tr.quat)
    assert np.all(np.sum(clean.quat[1:] * clean.quat[:-1], axis=1) >= 0)
    assert rep["sign_flips"] == sum(a != b for a, b in zip(flips[1:], flips[:-1]))


def test_exact_duplicates_are_dropped():
    tr = smooth()
    idx = np.array([0, 1, 2, 2, 3, 4, 5, 5, 5] + list(range(6, 20)))
    dup = tr.slice(idx)
    q = dup.quat.copy()
    q[3] *= -1  # same rotation written with the other sign is still the same pose
    clean, rep, warns = prep(dup.with_(quat=q))
    np.testing.assert_array_equal(clean.t, tr.t)
    assert rep["duplicates"] == 3
    assert "dropped 3 duplicate samples" in warns[0]


def test_duplicate_time_with_different_pose_is_an_error():
    tr = smooth()
    t = tr.t.copy()
    t[9] = t[8]
    with pytest.raises(InputError, match=r"^d\.csv:11: demo: sample 10 .*same time.*different pose.*demo column"):
        prepare_trajectory(tr.with_(t=t))


def test_time_going_backwards_is_an_error():
    tr = smooth()
    t = tr.t.copy()
    t[[5, 6]] = t[[6, 5]]
    with pytest.raises(InputError, match=r"^d\.csv:8: demo: time goes backwards at sample 7.*sort the rows"):
        prepare_trajectory(tr.with_(t=t))


def test_backwards_time_in_a_lost_frame_does_not_matter():
    tr = smooth()
    t, q = tr.t.copy(), tr.quat.copy()
    t[5], q[5] = 0.0, np.nan
    clean, rep, _ = prep(tr.with_(t=t, quat=q), max_gap=1.0)
    assert rep["lost"] == 1 and rep["filled"] == 0 and len(clean) == 19


@pytest.mark.parametrize("n_valid", [0, 1])
def test_fewer_than_two_samples_is_an_error(n_valid):
    tr = smooth(n=3)
    q = tr.quat.copy()
    q[n_valid:] = np.nan
    with pytest.raises(InputError, match=rf"needs at least 2 samples for a velocity, {n_valid} left of 3 \({3 - n_valid} lost"):
        prepare_trajectory(tr.with_(quat=q))


def test_all_zero_quaternions_explain_the_protobuf_default():
    tr = smooth(n=5)
    with pytest.raises(InputError, match=r"0 left of 5 \(5 lost frames\); 5 samples have an all-zero quaternion"):
        prepare_trajectory(tr.with_(quat=np.zeros((5, 4))))


def test_one_sample_is_an_error():
    tr = smooth(n=1)
    with pytest.raises(InputError, match="needs at least 2 samples for a velocity, 1 left of 1"):
        prepare_trajectory(tr)


def test_a_half_turn_step_is_an_error():
    tr = smooth()
    q = np.tile(np.array([0.0, 0.0, 0.0, 1.0]), (20, 1))
    q[11:] = Rotation.from_rotvec([0, 0, np.pi]).as_quat()  # samples 11 -> 12 (1-based) turn by pi
    with pytest.raises(InputError, match=r"^d\.csv:13: demo: the rotation .* sample 12 .* too coarse"):
        prepare_trajectory(tr.with_(quat=q))


def test_a_large_but_smaller_than_pi_step_passes_the_step_check_and_is_refused_as_a_jump_that_stays():
    """Below π the step's direction can be told (no "π or more" error), but turning by π − 1e-3 in one
    10 ms step and staying there is no motion of this file (issue 40): a glitch that never came back."""
    tr = smooth()
    q = np.tile(np.array([0.0, 0.0, 0.0, 1.0]), (20, 1))
    q[10:] = Rotation.from_rotvec([0, 0, STEP_LIMIT - 1e-3]).as_quat()
    with pytest.raises(InputError, match="does not come back") as exc:
        prep(tr.with_(quat=q))
    assert "π or more" not in str(exc.value)


def test_a_large_but_smaller_than_pi_turn_over_a_few_steps_is_accepted():
    tr = smooth()
    angle = np.clip((np.arange(20) - 8) / 4, 0, 1) * (STEP_LIMIT - 1e-3)  # a half turn over 4 steps: 78 rad/s
    q = Rotation.from_rotvec(np.c_[np.zeros(20), np.zeros(20), angle]).as_quat()
    clean, rep, _ = prep(tr.with_(quat=q))
    assert len(clean) == 20 and rep["glitches"] == 0


def test_invalid_max_gap():
    with pytest.raises(InputError, match="max_gap"):
        prepare_trajectory(smooth(), max_gap=-1)


def test_prepare_all_returns_lists():
    a, b = smooth(seed=1), smooth(seed=2)
    clean, reps = prepare_all([a, b], max_gap=0.1)
    assert len(clean) == len(reps) == 2 and all(r["samples_out"] == 20 for r in reps)


# ---------------------------------------------------------------------------------------------------
# the sign-change warning names what the data held


def _turning(n=60, dt=0.02, rate=4.0):
    """A body turning about z through θ = π (rotation angle 2.4 → 4.7 rad)."""
    t = np.arange(n) * dt
    return t, Rotation.from_rotvec(np.outer(2.4 + rate * t, [0.0, 0.0, 1.0]))


def _write_csv(path, header, rows):
    path.write_text(",".join(header) + "\n" + "\n".join(",".join(repr(float(v)) for v in r) for r in rows) + "\n")


def _read_and_prepare(path, **opts):
    from rbgp_cli.io.options import ReadOptions
    from rbgp_cli.io.read import read_demonstrations

    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        (raw,) = read_demonstrations([str(path)], ReadOptions(**opts))
        clean, rep = prepare_trajectory(raw)
    return raw, clean, rep, [str(x.message) for x in w if issubclass(x.category, RbgpWarning)]


def test_a_rotation_vector_csv_that_wraps_at_pi_is_called_that(tmp_path):
    t, rot = _turning()
    rv = rot.as_rotvec()  # canonical: wraps from θ ≈ π to the opposite side once
    assert np.sum(np.linalg.norm(np.diff(rv, axis=0), axis=1) > 3) == 1
    path = tmp_path / "rotvec.csv"
    _write_csv(path, ["t", "x", "y", "z", "rx", "ry", "rz"], np.column_stack([t, np.zeros((len(t), 3)), rv]))
    raw, clean, rep, warns = _read_and_prepare(path)
    assert raw.info["rotation"] == "rotation vector (rad)"
    assert rep["sign_flips"] == 1
    assert warns == [f"{path}: rotvec: rotation vector wrapped at π 1 time, repaired"]
    assert not any("quaternion" in w for w in warns)
    np.testing.assert_array_less(0.0, np.sum(clean.quat[1:] * clean.quat[:-1], axis=1))


def test_euler_angles_that_wrap_at_180_degrees_are_called_that(tmp_path):
    t, rot = _turning()
    eul = rot.as_euler("xyz", degrees=True)  # yaw jumps from +180° to −180°
    path = tmp_path / "euler.csv"
    _write_csv(path, ["t", "x", "y", "z", "roll", "pitch", "yaw"], np.column_stack([t, np.zeros((len(t), 3)), eul]))
    _, _, rep, warns = _read_and_prepare(path, euler_order="xyz", degrees=True)
    assert rep["sign_flips"] == 1
    assert warns == [f"{path}: euler: Euler angles wrapped at ±180° 1 time, repaired"]


def test_recorded_quaternions_that_flip_keep_their_name(tmp_path):
    t, rot = _turning()
    q = rot.as_quat()
    q[20:30] *= -1
    path = tmp_path / "quat.csv"
    _write_csv(path, ["t", "x", "y", "z", "qx", "qy", "qz", "qw"], np.column_stack([t, np.zeros((len(t), 3)), q]))
    _, _, rep, warns = _read_and_prepare(path)
    assert rep["sign_flips"] >= 2
    assert warns == [f"{path}: quat: fixed {rep['sign_flips']} quaternion sign flips"]


@pytest.mark.parametrize("info,expected", [
    ({"rotation_source": "helical (rotation vector) deg"}, "rotation vector wrapped at 180° 2 times, repaired"),
    ({"rotation_source": "helical (rotation vector) rad"}, "rotation vector wrapped at π 2 times, repaired"),
    ({"rotation_source": "euler XYZ rad (header Roll Pitch Yaw)"}, "Euler angles wrapped at ±π 2 times, repaired"),
    ({"rotation_source": "Rot[] matrix (column-major)"}, None),  # the sign is the conversion's, not the data's
    ({"rotation": "quaternion xyzw"}, "fixed 2 quaternion sign flips"),
    ({}, "fixed 2 quaternion sign flips"),
])
def test_sign_change_note_for_every_reader(info, expected):
    from rbgp_cli.dynamics.prepare import sign_change_note

    assert sign_change_note(info, 2) == expected
    assert sign_change_note(info, 0) is None
