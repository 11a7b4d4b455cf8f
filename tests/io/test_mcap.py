"""MCAP reader (rbgp_cli.io.mcap): every writer and encoding reads back to the same poses and times;
topic and frame choice; damaged files; pipes."""

from __future__ import annotations

import io
import os
import threading
import warnings

import numpy as np
import pytest

from rbgp_cli.errors import InputError, RbgpWarning
from rbgp_cli.io import mcap as rmcap
from rbgp_cli.io.options import ReadOptions

from tests.helpers import NonSeekable

from . import mcap_fixtures as F

ROS_TYPES = [
    "geometry_msgs/msg/PoseStamped",
    "geometry_msgs/msg/PoseWithCovarianceStamped",
    "geometry_msgs/msg/TransformStamped",
    "nav_msgs/msg/Odometry",
]


def check(trajs, stamps, pos, q, frames=None, offset_ns=0):
    frames = range(len(trajs)) if frames is None else frames
    assert len(trajs) == len(frames)
    for tr, f in zip(trajs, frames):
        np.testing.assert_allclose(tr.t, (stamps + offset_ns) / 1e9, rtol=0, atol=1e-9)
        np.testing.assert_allclose(tr.position, pos[f], rtol=0, atol=1e-12)
        np.testing.assert_allclose(tr.quat, q[f], rtol=0, atol=1e-12)


def read_quiet(path, **kw):
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        out = rmcap.read(path, ReadOptions(**kw))
    return out, [str(x.message) for x in w if issubclass(x.category, RbgpWarning)]


# -------------------------------------------------------------------------------------------- encodings
@pytest.mark.parametrize("type_name", ROS_TYPES)
def test_ros2_types_read_back(tmp_path, type_name):
    p = tmp_path / "ros.mcap"
    truth = F.write_ros2(p, type_name)
    trajs, warns = read_quiet(p)
    check(trajs, *truth)
    assert warns == []
    info = trajs[0].info
    assert info["format"] == "mcap" and info["topic"] == "/pose" and info["schema"] == type_name
    assert info["time_source"] == "header" and info["frame_id"] == "world"
    assert info["rate_hz"] == pytest.approx(100.0)
    assert trajs[0].name == "/pose" and trajs[0].source == f"{p}:/pose"


def test_tf_message_needs_a_frame_when_it_has_several(tmp_path):
    p = tmp_path / "tf.mcap"
    stamps, pos, q = F.write_ros2(p, "tf2_msgs/msg/TFMessage")
    with pytest.raises(InputError, match=r"topic /pose: transforms to several child frames: a \(50\), b \(50\).*choose one with frame, e.g. frame a"):
        rmcap.read(p)
    check(rmcap.read(p, ReadOptions(frame="b")), stamps, pos, q, frames=[1])
    trajs = rmcap.read(p, ReadOptions(frame="/a"))  # leading slashes do not matter
    check(trajs, stamps, pos, q, frames=[0])
    assert trajs[0].name == "/pose:a" and trajs[0].info["child_frame_id"] == "a"
    with pytest.raises(InputError, match=r"no transforms to child frame 'c'; child frames are: a, b"):
        rmcap.read(p, ReadOptions(frame="c"))


@pytest.mark.parametrize("type_name", ["PoseInFrame", "FrameTransform"])
def test_protobuf_single_pose_types(tmp_path, type_name):
    p = tmp_path / "pb.mcap"
    truth = F.write_protobuf(p, type_name)
    trajs, _ = read_quiet(p)
    check(trajs, *truth)
    assert trajs[0].info["message_encoding"] == "protobuf"


def test_protobuf_poses_in_frame_gives_one_trajectory_per_index(tmp_path):
    p = tmp_path / "pb.mcap"
    truth = F.write_protobuf(p, "PosesInFrame")
    trajs, _ = read_quiet(p)
    check(trajs, *truth)
    assert [t.name for t in trajs] == ["/pose[0]", "/pose[1]"]


def test_protobuf_frame_transforms(tmp_path):
    p = tmp_path / "pb.mcap"
    stamps, pos, q = F.write_protobuf(p, "FrameTransforms")
    with pytest.raises(InputError, match="several child frames"):
        rmcap.read(p)
    check(rmcap.read(p, ReadOptions(frame="b")), stamps, pos, q, frames=[1])


def test_json_encoding(tmp_path):
    p = tmp_path / "json.mcap"
    truth = F.write_json(p)
    trajs, _ = read_quiet(p)
    check(trajs, *truth)
    assert trajs[0].info["message_encoding"] == "json"


def test_json_with_ros_field_names_and_a_json_schema_reads(tmp_path):
    p = tmp_path / "json.mcap"
    truth = F.write_json(p, schema_name="geometry_msgs/msg/PoseStamped", ros_layout=True)
    check(rmcap.read(p), *truth)


def test_foxglove_sdk(tmp_path):
    p = tmp_path / "sdk.mcap"
    truth = F.write_foxglove_sdk(p)
    trajs, _ = read_quiet(p)
    check(trajs, *truth)


def test_all_writers_agree(tmp_path):
    """The same ground truth through four writers gives identical arrays."""
    paths = {
        "ros2": (F.write_ros2, ("geometry_msgs/msg/PoseStamped",)),
        "protobuf": (F.write_protobuf, ("PoseInFrame",)),
        "json": (F.write_json, ()),
        "sdk": (F.write_foxglove_sdk, ()),
    }
    results = []
    for name, (fn, args) in paths.items():
        p = tmp_path / f"{name}.mcap"
        fn(p, *args)
        results.append(rmcap.read(p)[0])
    for r in results[1:]:
        np.testing.assert_array_equal(r.t, results[0].t)
        np.testing.assert_array_equal(r.quat, results[0].quat)
        np.testing.assert_array_equal(r.position, results[0].position)


# -------------------------------------------------------------------------------------------- time
def test_header_versus_log_time(tmp_path):
    p = tmp_path / "ros.mcap"
    stamps, pos, q = F.write_ros2(p, "geometry_msgs/msg/PoseStamped")
    check(rmcap.read(p, ReadOptions(time_source="log")), stamps, pos, q, offset_ns=F.LOG_OFFSET_NS)
    assert rmcap.read(p, ReadOptions(time_source="log"))[0].info["time_source"] == "log"
    with pytest.raises(InputError, match="'header' or 'log'"):
        rmcap.read(p, ReadOptions(time_source="publish"))


def test_zero_header_stamps_fall_back_to_log_time(tmp_path):
    p = tmp_path / "zero.mcap"
    stamps, pos, q = F.write_ros2_topics(p, {"/pose": "geometry_msgs/msg/PoseStamped"}, stamps_zero=True)
    trajs, warns = read_quiet(p)
    check(trajs, stamps, pos, q, offset_ns=F.LOG_OFFSET_NS)
    assert trajs[0].info["time_source"] == "log"
    assert any("stamps are zero" in w for w in warns)


def test_messages_out_of_time_order_are_sorted(tmp_path):
    from mcap_ros2.writer import Writer

    stamps, pos, q = F.ground_truth(30)
    order = np.random.default_rng(0).permutation(30)
    p = tmp_path / "shuffled.mcap"
    with open(p, "wb") as fh:
        w = Writer(fh, chunk_size=300)
        s = w.register_msgdef("geometry_msgs/msg/PoseStamped", F.MSGDEFS["geometry_msgs/msg/PoseStamped"])
        for k in order:
            w.write_message("/pose", s, F.ros2_message("geometry_msgs/msg/PoseStamped", int(stamps[k]), pos[0, k], q[0, k]),
                            log_time=int(stamps[k]), publish_time=int(stamps[k]))
        w.finish()
    check(rmcap.read(p), stamps, pos, q)


# -------------------------------------------------------------------------------------------- choosing
def test_no_pose_topic(tmp_path):
    p = tmp_path / "chatter.mcap"
    F.write_strings(p)
    with pytest.raises(InputError, match=r"no pose topic found; topics are: /chatter \(std_msgs/msg/String, 5 messages\)"):
        rmcap.read(p)
    # inspect says it too, under the topics (it lists them and exits 0, as for any file it can describe)
    from rbgp_cli.io.inspect import format_inspect, inspect_file

    text = format_inspect(inspect_file(p))
    assert "pose data     none: no topic of a pose message type" in text, text
    F.write_ros2(tmp_path / "pose.mcap", "geometry_msgs/msg/PoseStamped", n=5)
    assert "pose data" not in format_inspect(inspect_file(tmp_path / "pose.mcap"))


def test_several_pose_topics_are_listed(tmp_path):
    p = tmp_path / "two.mcap"
    truth = F.write_ros2_topics(p, {"/a/pose": "geometry_msgs/msg/PoseStamped", "/b/odom": "nav_msgs/msg/Odometry"})
    with pytest.raises(InputError) as e:
        rmcap.read(p)
    msg = str(e.value)
    assert "several pose topics: " in msg and "; choose one with topic, e.g. topic /a/pose" in msg
    assert "/a/pose (geometry_msgs/msg/PoseStamped, 20 messages)" in msg and "/b/odom (nav_msgs/msg/Odometry, 20 messages)" in msg
    check(rmcap.read(p, ReadOptions(topic="/b/odom")), *truth)
    check(rmcap.read(p, ReadOptions(topic="a/pose")), *truth)  # leading slash optional


def test_misspelled_topic_is_suggested(tmp_path):
    p = tmp_path / "ros.mcap"
    F.write_ros2(p, "geometry_msgs/msg/PoseStamped", extra_topics={"/chatter": "std_msgs/msg/String"})
    with pytest.raises(InputError, match=r"no topic '/poze'; did you mean '/pose'\?"):
        rmcap.read(p, ReadOptions(topic="/poze"))
    with pytest.raises(InputError, match=r"topic /chatter carries std_msgs/msg/String messages, which hold no pose"):
        rmcap.read(p, ReadOptions(topic="/chatter"))
    assert len(rmcap.read(p)[0]) == 50  # the only pose topic is chosen automatically


def test_json_under_a_ros_schema_is_a_clean_error(tmp_path):
    p = tmp_path / "bad.mcap"
    F.write_json(p, schema_name="geometry_msgs/msg/PoseStamped", schema_encoding="ros2msg", ros_layout=True)
    with pytest.raises(InputError, match=r"topic /pose: messages are JSON-encoded but the schema .* ros2msg"):
        rmcap.read(p)


def test_json_without_the_expected_fields_is_a_clean_error(tmp_path):
    p = tmp_path / "bad.mcap"
    F.write_json(p, schema_name="geometry_msgs/msg/PoseStamped")  # foxglove layout under a ROS name
    with pytest.raises(InputError, match=r"topic /pose: message 1 lacks field 'header'"):
        rmcap.read(p)


def test_ros2idl_schema_is_a_clean_error(tmp_path):
    p = tmp_path / "idl.mcap"
    F.write_raw(p, "/pose", "geometry_msgs/msg/PoseStamped", "ros2idl", b"module geometry_msgs { };", "cdr", [b"\x00" * 8])
    with pytest.raises(InputError, match=r"topic /pose: .*ros2idl.*cannot decode"):
        rmcap.read(p)


def test_undecodable_message_is_a_clean_error(tmp_path):
    p = tmp_path / "garbage.mcap"
    schema = F.MSGDEFS["geometry_msgs/msg/PoseStamped"].encode()
    F.write_raw(p, "/pose", "geometry_msgs/msg/PoseStamped", "ros2msg", schema, "cdr", [b"\x00\x01\x00\x00\xff"])
    with pytest.raises(InputError, match=r"topic /pose: cannot decode message 1"):
        rmcap.read(p)


# -------------------------------------------------------------------------------------------- damage
@pytest.fixture(scope="module")
def chunked(tmp_path_factory):
    """300 PoseStamped in many small zstd chunks, plus a String topic interleaved."""
    p = tmp_path_factory.mktemp("mcap") / "chunked.mcap"
    truth = F.write_ros2(p, "geometry_msgs/msg/PoseStamped", n=300, chunk_size=2000,
                         extra_topics={"/chatter": "std_msgs/msg/String"})
    return p, truth


@pytest.mark.parametrize("fraction", [0.02, 0.1, 0.3, 0.5, 0.77, 0.9, 0.97, 0.999])
def test_truncated_file_recovers_the_prefix_or_fails_cleanly(tmp_path, chunked, fraction):
    src, (stamps, pos, q) = chunked
    size = int(os.path.getsize(src) * fraction)
    p = F.truncate(src, tmp_path / "cut.mcap", size)
    try:
        trajs, warns = read_quiet(p)
    except InputError as exc:
        assert fraction < 0.1, f"nothing recovered from {fraction:.0%} of the file: {exc}"
        assert "truncated or corrupt" in str(exc) or "no pose topic found before the damage" in str(exc)
        return
    n = len(trajs[0])
    assert 0 < n <= 300
    check(trajs, stamps[:n], pos[:, :n], q[:, :n])
    assert len(warns) == 1 and f"recovered {n} pose samples" in warns[0] and "truncated or corrupt" in warns[0]
    assert trajs[0].info["recovered"] is True
    if fraction >= 0.5:
        assert n >= 300 * (fraction - 0.2)


def test_tiny_and_empty_files(tmp_path, chunked):
    src, _ = chunked
    with pytest.raises(InputError, match="truncated|empty"):
        rmcap.read(F.truncate(src, tmp_path / "t.mcap", 12))
    with pytest.raises(InputError, match="empty|truncated"):
        rmcap.read(F.truncate(src, tmp_path / "e.mcap", 0))
    (tmp_path / "n.mcap").write_bytes(b"hello, not an mcap file at all")
    with pytest.raises(InputError, match="not an MCAP file"):
        rmcap.read(tmp_path / "n.mcap")


def test_corrupted_zstd_chunk_keeps_the_chunks_before_it(tmp_path, chunked):
    src, (stamps, pos, q) = chunked
    offsets = F.chunk_data_offsets(src)
    data = bytearray(src.read_bytes())
    k = len(offsets) // 2
    data[offsets[k] : offsets[k] + 8] = b"\xde\xad\xbe\xef" * 2  # destroy the zstd frame header
    p = tmp_path / "corrupt.mcap"
    p.write_bytes(bytes(data))
    trajs, warns = read_quiet(p)
    n = len(trajs[0])
    assert 0 < n < 300
    check(trajs, stamps[:n], pos[:, :n], q[:, :n])
    assert "ZstdError" in warns[0] and f"recovered {n}" in warns[0]


def test_bit_flip_in_an_uncompressed_chunk_is_caught_by_its_crc(tmp_path):
    from mcap.writer import CompressionType

    src = tmp_path / "plain.mcap"
    stamps, pos, q = F.write_ros2(src, "geometry_msgs/msg/PoseStamped", n=200, chunk_size=2000,
                                  compression=CompressionType.NONE)
    offsets = F.chunk_data_offsets(src)
    data = bytearray(src.read_bytes())
    k = len(offsets) // 2
    data[offsets[k] + 200] ^= 0x10  # one bit inside a message: decodes, but to a wrong pose
    p = tmp_path / "flip.mcap"
    p.write_bytes(bytes(data))
    trajs, warns = read_quiet(p)
    n = len(trajs[0])
    assert 0 < n < 200
    check(trajs, stamps[:n], pos[:, :n], q[:, :n])  # only the intact chunks before it
    assert "CRC" in warns[0] or "crc" in warns[0]


def test_corrupted_first_chunk_is_an_error(tmp_path, chunked):
    src, _ = chunked
    offsets = F.chunk_data_offsets(src)
    data = bytearray(src.read_bytes())
    data[offsets[0] : offsets[0] + 8] = b"\x00" * 8
    p = tmp_path / "corrupt.mcap"
    p.write_bytes(bytes(data))
    with pytest.raises(InputError, match="truncated or corrupt"):
        rmcap.read(p)


def test_unfinished_recording_recovers_complete_chunks(tmp_path):
    p = tmp_path / "crash.mcap"
    stamps, pos, q = F.write_ros2_topics(p, {"/pose": "geometry_msgs/msg/PoseStamped"}, n=200, finish=False,
                                         chunk_size=1500)
    trajs, warns = read_quiet(p)
    n = len(trajs[0])
    assert 100 < n < 200
    check(trajs, stamps[:n], pos[:, :n], q[:, :n])
    assert "recovered" in warns[0]


# -------------------------------------------------------------------------------------------- streams
def test_non_seekable_stream_reads_the_same(tmp_path):
    p = tmp_path / "two.mcap"
    truth = F.write_ros2_topics(p, {"/a": "geometry_msgs/msg/PoseStamped", "/b": "nav_msgs/msg/Odometry"})
    stream = io.BufferedReader(NonSeekable(p.read_bytes()))
    check(rmcap.read_stream(stream, ReadOptions(topic="/b")), *truth)
    with pytest.raises(InputError, match="several pose topics"):
        rmcap.read_stream(io.BufferedReader(NonSeekable(p.read_bytes())), ReadOptions())


def test_os_pipe(tmp_path):
    p = tmp_path / "pb.mcap"
    truth = F.write_protobuf(p, "PoseInFrame", n=400)
    data = p.read_bytes()
    r, w = os.pipe()

    def feed():
        with os.fdopen(w, "wb") as fh:
            fh.write(data)

    th = threading.Thread(target=feed)
    th.start()
    with os.fdopen(r, "rb") as fh:
        assert not fh.seekable()
        trajs = rmcap.read_stream(fh)
    th.join()
    check(trajs, *truth)


def test_truncated_pipe_keeps_the_prefix(tmp_path, chunked):
    src, (stamps, pos, q) = chunked
    data = src.read_bytes()[: os.path.getsize(src) // 2]
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        trajs = rmcap.read_stream(io.BufferedReader(NonSeekable(data)), ReadOptions(topic="/pose"))
    n = len(trajs[0])
    check(trajs, stamps[:n], pos[:, :n], q[:, :n])
    assert any("recovered" in str(x.message) for x in w)


# -------------------------------------------------------------------------------------------- describe
def test_describe_lists_topics_without_decoding(tmp_path):
    p = tmp_path / "ros.mcap"
    F.write_ros2(p, "geometry_msgs/msg/PoseStamped", extra_topics={"/chatter": "std_msgs/msg/String"})
    d = rmcap.describe(p)
    assert d["summary"] is True and d["messages"] == 100 and d["profile"] == "ros2"
    topics = {t["topic"]: t for t in d["topics"]}
    assert topics["/pose"]["pose"] is True and topics["/pose"]["messages"] == 50
    assert topics["/chatter"]["pose"] is False and topics["/chatter"]["schema"] == "std_msgs/msg/String"


def test_describe_scans_a_file_without_summary(tmp_path, chunked):
    src, _ = chunked
    p = F.truncate(src, tmp_path / "cut.mcap", os.path.getsize(src) // 2)
    d = rmcap.describe(p)
    assert d["summary"] is False and d["damaged"] and 0 < d["messages"] < 600
    assert {t["topic"] for t in d["topics"]} == {"/pose", "/chatter"}


def test_read_all_returns_every_pose_topic_and_frame(tmp_path):
    p = tmp_path / "tf.mcap"
    F.write_ros2(p, "tf2_msgs/msg/TFMessage")
    assert [t.name for t in rmcap.read_all(p)] == ["/pose:a", "/pose:b"]


def test_schema_names_with_and_without_msg():
    assert rmcap.is_pose_schema("geometry_msgs/msg/PoseStamped")
    assert rmcap.is_pose_schema("geometry_msgs/PoseStamped")
    assert rmcap.is_pose_schema("tf2_msgs/msg/TFMessage")
    assert rmcap.is_pose_schema("foxglove.FrameTransforms")
    assert not rmcap.is_pose_schema("sensor_msgs/msg/Imu")
