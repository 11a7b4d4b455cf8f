"""Real recordings in ../shared/realdata (read in place, never copied): generic CSV and MCAP."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from rbgp_cli.dynamics.prepare import prepare_trajectory
from rbgp_cli.errors import InputError
from rbgp_cli.io.options import ReadOptions
from rbgp_cli.io.read import read_demonstrations, read_file

pytestmark = pytest.mark.realdata

VICON = "/vicon/t265_tracker/t265_tracker"
ODOM = "/camera/odom/sample"


def test_handover_object_csv_files_read(realdata):
    files = sorted((realdata / "handover_object_csv").glob("*.csv"))
    assert len(files) == 30
    trajs = read_demonstrations([str(realdata / "handover_object_csv")])
    assert len(trajs) == 30
    for f, tr in zip(files, trajs):
        assert tr.source == str(f)
        assert tr.info["columns"] == {"t": "time_s", "x": "x_m", "y": "y_m", "z": "z_m",
                                      "qx": "qx", "qy": "qy", "qz": "qz", "qw": "qw"}  # fmt: skip
        assert tr.info["rotation"] == "quaternion wxyz"  # scalar first, from the names
        assert tr.info["length_unit"] == "m" and tr.info["time_unit"] == "s"
        assert tr.info["rate_hz"] == pytest.approx(30.0, rel=1e-6)
        assert 2.0 < tr.duration < 10.5
        assert np.all(np.isfinite(tr.quat)) and np.allclose(np.linalg.norm(tr.quat, axis=1), 1.0, atol=1e-6)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # sign flips are repaired with a warning
            clean, rep = prepare_trajectory(tr)
        assert rep["lost"] == 0 and len(clean) == len(tr)
    # the scalar column really is first: the first file starts with |w| ~ 1 and small x, y, z
    first = trajs[0].quat[0]
    assert abs(first[3]) > 0.99 and np.all(np.abs(first[:3]) < 0.05)


def test_kth_csv_asks_for_rate_then_quaternion_order(realdata):
    f = realdata / "kth_handover_csv" / "baton_pose_saved.csv"
    with pytest.raises(InputError, match=r"no time column \(columns are .*; pass rate HZ"):
        read_file(f)
    with pytest.raises(InputError, match=r"q0, q1, q2, q3 are numbered.*quat_order xyzw"):
        read_file(f, ReadOptions(rate=120))
    tr = read_file(f, ReadOptions(rate=120, quat_order="xyzw"))[0]
    assert len(tr) == 801 and tr.duration == pytest.approx(800 / 120)
    # q3 is the scalar: the baton starts near identity (q3 ~ -1)
    assert tr.quat[0, 3] == pytest.approx(-0.99959284, abs=1e-6)
    angle = 2 * np.arccos(min(1.0, abs(tr.quat[0, 3])))
    assert angle < 0.1


def test_kth_hands_read_with_the_same_options(realdata):
    opts = ReadOptions(rate=120, quat_order="xyzw")
    for name in ("giver_RHand_pose_saved.csv", "taker_RHand_pose_saved.csv"):
        tr = read_file(realdata / "kth_handover_csv" / name, opts)[0]
        assert np.allclose(np.linalg.norm(tr.quat, axis=1), 1.0, atol=1e-6)
        assert np.all(np.abs(tr.position) < 3.0)


@pytest.mark.parametrize("topic, rate, n", [(VICON, 50.0, 57), (ODOM, 200.0, 228)])
def test_mcap_pose_topics(realdata, topic, rate, n):
    f = realdata / "mcap_pose" / "rbm_vicon_t265.mcap"
    tr = read_file(f, ReadOptions(topic=topic))[0]
    assert len(tr) == n
    assert tr.info["rate_hz"] == pytest.approx(rate, rel=0.02)
    assert np.all(np.isfinite(tr.quat)) and np.all(np.isfinite(tr.position))
    assert np.allclose(np.linalg.norm(tr.quat, axis=1), 1.0, atol=1e-6)
    assert tr.t[0] == pytest.approx(1594684035.8, abs=0.5)  # epoch seconds of the recording
    assert 1.0 < tr.duration < 1.2
    clean, rep = prepare_trajectory(tr)
    assert rep["lost"] == 0 and len(clean) == n


def test_mcap_pose_without_topic_lists_both_candidates(realdata):
    f = realdata / "mcap_pose" / "rbm_vicon_t265.mcap"
    with pytest.raises(InputError) as e:
        read_file(f)
    msg = str(e.value)
    assert "several pose topics" in msg and VICON in msg and ODOM in msg
    assert "sensor_msgs/msg/Imu" not in msg  # IMU topics carry no pose


def test_mcap_no_pose_files_say_so(realdata):
    files = sorted((realdata / "mcap_no_pose").rglob("*.mcap"))
    assert len(files) >= 6  # talker, cdr_test, only_services, only_topics, a 3-part split bag
    for f in files:
        with pytest.raises(InputError, match="no pose topic") as e:
            read_file(f)
        assert str(f) in str(e.value)
    # the split bag as a directory: every part says the same
    with pytest.raises(InputError, match="no pose topic"):
        read_demonstrations([str(realdata / "mcap_no_pose" / "multiple_files")])
