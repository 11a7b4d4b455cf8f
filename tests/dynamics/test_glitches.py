"""Tracker glitches (issue 40): :func:`rbgp_cli.dynamics.glitches.find_glitches` on synthetic motions
with a known answer, and on the real recordings (no false alarm)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from rbgp_cli.dynamics.glitches import MAX_RUN, find_glitches
from rbgp_cli.dynamics.prepare import prepare_trajectory
from rbgp_cli.dynamics.trajectory import Trajectory
from rbgp_cli.errors import InputError, RbgpWarning


def motion(n=200, rate=100.0, speed=1.0, seed=0):
    """A smooth reach: positions along a curve at up to ``speed`` m/s, rotation up to ~2 rad."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / rate
    s = 0.5 - 0.5 * np.cos(np.pi * t / t[-1])  # 0 → 1, at rest at both ends
    length = speed * t[-1] / 1.6
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    p = np.outer(s, direction) * length + 0.1 * np.c_[np.sin(3 * s), np.cos(2 * s), s**2] + 0.5
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    q = Rotation.from_rotvec(np.outer(2.0 * s, axis)).as_quat()
    return t, p, q


def random_axis(rng):
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


@pytest.mark.parametrize("rate,speed", [(30.0, 2.0), (60.0, 1.0), (120.0, 3.0), (256.0, 0.5), (179.0, 1.5)])
def test_clean_motions_at_30_to_256_hz_flag_nothing(rate, speed):
    t, p, q = motion(n=int(3 * rate), rate=rate, speed=speed)
    rng = np.random.default_rng(1)
    p = p + rng.normal(scale=5e-4, size=p.shape)  # half a millimetre of tracker noise
    found = find_glitches(t, p, q)
    assert not found.mask.any() and found.unexplained is None


@settings(max_examples=60, deadline=None, derandomize=True)
@given(k=st.integers(0, 149), log_size=st.floats(-1.0, 3.0), seed=st.integers(0, 1000),
       rate=st.sampled_from([30.0, 100.0, 256.0]))
def test_a_one_sample_jump_of_10_cm_to_1_km_is_found_and_nothing_else(k, log_size, seed, rate):
    t, p, q = motion(n=150, rate=rate)
    p[k] += 10**log_size * random_axis(np.random.default_rng(seed))
    found = find_glitches(t, p, q)
    assert found.unexplained is None
    assert np.flatnonzero(found.mask).tolist() == [k]


@settings(max_examples=40, deadline=None, derandomize=True)
@given(k=st.integers(0, 139), length=st.integers(1, 10), seed=st.integers(0, 1000))
def test_rows_in_millimetres_inside_metres_are_found_as_one_run(k, length, seed):
    t, p, q = motion(n=150, seed=seed % 7)
    k = min(k, 150 - length)
    p[k:k + length] *= 1000.0
    found = find_glitches(t, p, q)
    assert found.unexplained is None
    assert np.flatnonzero(found.mask).tolist() == list(range(k, k + length))


@settings(max_examples=40, deadline=None, derandomize=True)
@given(k=st.integers(0, 149), degrees=st.floats(90.0, 179.99), seed=st.integers(0, 1000))
def test_a_one_sample_rotation_flip_is_found(k, degrees, seed):
    t, p, q = motion(n=150, rate=179.0)
    turn = Rotation.from_rotvec(np.radians(degrees) * random_axis(np.random.default_rng(seed)))
    q[k] = (turn * Rotation.from_quat(q[k])).as_quat()
    found = find_glitches(t, p, q)
    assert np.flatnonzero(found.mask).tolist() == [k]


def test_a_jump_that_stays_is_unexplained_and_prepare_refuses_it_at_its_row():
    t, p, q = motion(n=150)
    p[80:] += [3.0, 0.0, 0.0]
    found = find_glitches(t, p, q)
    assert found.unexplained == 79 and found.jump[0] == pytest.approx(3.0, abs=0.05)
    traj = Trajectory(t=t, quat=q, position=p, name="demo", source="d.csv", info={"first_data_line": 2})
    with pytest.raises(InputError, match="does not come back") as exc:
        prepare_trajectory(traj)
    assert exc.value.row == 82  # sample 81 (index 80) on file line 82


def test_a_run_longer_than_max_run_is_not_a_glitch():
    t, p, q = motion(n=300)
    p[100:100 + MAX_RUN + 20] *= 1000.0
    found = find_glitches(t, p, q)
    assert found.unexplained is not None


def test_prepare_drops_glitches_as_lost_frames_and_names_their_lines():
    t, p, q = motion(n=150)
    p[40] += [0.0, 0.0, 1000.0]
    p[90:95] *= 1000.0
    traj = Trajectory(t=t, quat=q, position=p, name="demo", source="d.csv", info={"first_data_line": 2})
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", RbgpWarning)
        clean, rep = prepare_trajectory(traj)
    assert rep["glitches"] == 6 and rep["dropped"] == 0 and len(clean.t) == 144
    assert rep["glitch_rows"] == [["line", 42, 42], ["line", 92, 96]]
    text = " ".join(str(w.message) for w in caught)
    assert "removed 6 samples off the path" in text and "lines 42, 92–96" in text
    keep = np.setdiff1d(np.arange(150), [40, 90, 91, 92, 93, 94])
    np.testing.assert_array_equal(clean.t, t[keep])


def test_with_max_gap_a_glitch_is_filled_like_a_lost_frame():
    t, p, q = motion(n=150)
    truth = p[40].copy()
    p[40] += [0.0, 0.0, 1000.0]
    traj = Trajectory(t=t, quat=q, position=p, name="demo")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RbgpWarning)
        clean, rep = prepare_trajectory(traj, max_gap=0.05)
    assert rep["glitches"] == 1 and rep["filled"] == 1 and len(clean.t) == 150
    assert np.linalg.norm(clean.position[40] - truth) < 1e-3


@pytest.mark.slow
def test_no_real_recording_is_flagged(realdata):
    """Every trajectory of every real CSV/TSV/MCAP file: no glitch flagged, none refused (the measured
    false-alarm rate of docs/data.md, kept)."""
    from rbgp_cli.io.options import ReadOptions
    from rbgp_cli.io.read import read_demonstrations

    opts = {"kth_handover_csv": {"rate": 120.0, "quat_order": "xyzw"}, "mcap_pose": {"topic": "all"},
            "motive_csv": {"body": "all", "length_unit": "cm", "euler_order": "XYZ"}, "qtm_6d_tsv": {"body": "all"}}
    seen = 0
    for f in sorted(realdata.glob("*/*")):
        if f.parent.name == "mcap_no_pose" or f.suffix not in (".csv", ".tsv", ".mcap"):
            continue
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RbgpWarning)
            for traj in read_demonstrations([str(f)], ReadOptions(**opts.get(f.parent.name, {}))):
                _, rep = prepare_trajectory(traj)
                assert rep["glitches"] == 0, (f.name, traj.name, rep["glitch_rows"])
                seen += 1
    assert seen >= 100
