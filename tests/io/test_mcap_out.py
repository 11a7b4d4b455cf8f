"""The MCAP writer of generated trajectories (rbgp_cli/io/mcap_out.py): read back by the mcap library's
own ROS 2 / protobuf decoders and by rosbags (a rosbag2 reader independent of mcap), checked with CRCs,
and the band's covariance against a direct per-step computation."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rbgp_cli.dynamics.trajectory import Trajectory
from rbgp_cli.errors import InputError
from rbgp_cli.io import mcap as mcap_reader
from rbgp_cli.io.mcap_out import band_covariance, rollout_topic, write_rollouts_mcap

T0 = 1_700_000_000_123_456_789  # a start time in ns, not a multiple of a second


def _trajs(seed=0, n=40):
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 50.0
    out = []
    for name in ("0", "1", "0.s0", "0.s1", "0.s2", "1.s0", "1.s1", "1.s2"):
        out.append(Trajectory(t.copy(), Rotation.random(n, random_state=rng).as_quat(), rng.normal(size=(n, 3)), name=name))
    out[1] = Trajectory(t[:25].copy(), out[1].quat[:25], out[1].position[:25], name="1")  # its own length
    return out


def _decoded(path):
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory as Pb
    from mcap_ros2.decoder import DecoderFactory as Ros2

    with open(path, "rb") as fh:
        reader = make_reader(fh, validate_crcs=True, decoder_factories=[Ros2(), Pb()])
        summary = reader.get_summary()
        msgs = list(reader.iter_decoded_messages(log_time_order=True))
    return summary, msgs


def test_topic_names_are_valid_ros2_names():
    assert rollout_topic("0") == "/rbgp/rollout_0"
    assert rollout_topic("12.s3") == "/rbgp/rollout_12/sample_3"
    for name in ("0", "7.s1", "3x", "my take", ""):
        tokens = rollout_topic(name).strip("/").split("/")
        assert all(tok and not tok[0].isdigit() and tok.replace("_", "a").isalnum() for tok in tokens), name


def test_ros2_poses_and_times_decode_exactly(tmp_path):
    trajs = _trajs()
    path = tmp_path / "g.mcap"
    counts = write_rollouts_mcap(trajs, path, frame_id="lab", start_ns=T0)
    summary, msgs = _decoded(path)
    assert summary is not None and summary.statistics.message_count == sum(len(t) for t in trajs)
    assert counts == {rollout_topic(t.name): len(t) for t in trajs}
    assert {s.name for s in summary.schemas.values()} == {"geometry_msgs/msg/PoseStamped"}
    assert {s.encoding for s in summary.schemas.values()} == {"ros2msg"}
    assert {c.message_encoding for c in summary.channels.values()} == {"cdr"}
    log_times = [m.message.log_time for m in msgs]
    assert log_times == sorted(log_times)  # written in time order across topics
    by_topic = {}
    for m in msgs:
        by_topic.setdefault(m.channel.topic, []).append(m)
    for tr in trajs:
        got = by_topic[rollout_topic(tr.name)]
        assert len(got) == len(tr)
        d = [g.decoded_message for g in got]
        pose = np.array([[x.pose.position.x, x.pose.position.y, x.pose.position.z, x.pose.orientation.x,
                          x.pose.orientation.y, x.pose.orientation.z, x.pose.orientation.w] for x in d])
        np.testing.assert_array_equal(pose[:, :3], tr.position)
        np.testing.assert_array_equal(pose[:, 3:], tr.quat)
        stamps = np.array([x.header.stamp.sec * 10**9 + x.header.stamp.nanosec for x in d])
        want = T0 + np.round(tr.t * 1e9).astype(np.int64)
        np.testing.assert_array_equal(stamps, want)
        np.testing.assert_array_equal([g.message.log_time for g in got], want)
        assert {x.header.frame_id for x in d} == {"lab"}


def test_rbgp_reads_back_every_generated_topic_in_csv_order(tmp_path):
    trajs = _trajs()
    path = tmp_path / "g.mcap"
    write_rollouts_mcap(trajs, path, start_ns=0)
    back = mcap_reader.read(path)
    assert [b.info["topic"] for b in back] == [rollout_topic(t.name) for t in trajs]
    for a, b in zip(trajs, back):
        np.testing.assert_allclose(b.t, a.t, atol=1e-9, rtol=0)  # integer nanoseconds
        np.testing.assert_array_equal(b.quat, a.quat)
        np.testing.assert_array_equal(b.position, a.position)


def test_band_covariance_against_a_loop():
    rng = np.random.default_rng(3)
    K, N = 5, 7
    qm, pm = Rotation.random(N, random_state=rng).as_quat(), rng.normal(size=(N, 3))
    qs = np.stack([(Rotation.from_rotvec(0.1 * rng.normal(size=(N, 3))) * Rotation.from_quat(qm)).as_quat() for _ in range(K)])
    ps = pm + 0.01 * rng.normal(size=(K, N, 3))
    cov = band_covariance(qm, pm, qs, ps)
    for j in range(N):
        d = []
        for k in range(K):
            rot = Rotation.from_quat(qs[k, j]) * Rotation.from_quat(qm[j]).inv()  # world-frame deviation
            d.append(np.concatenate([ps[k, j] - pm[j], rot.as_rotvec()]))
        d = np.array(d)
        np.testing.assert_allclose(cov[j], d.T @ d / K, atol=1e-15)
        assert np.all(np.linalg.eigvalsh(cov[j]) > -1e-15)


def test_band_topic_is_a_pose_with_covariance_and_not_read_as_a_trajectory(tmp_path):
    trajs = _trajs()
    samples = [t for t in trajs if t.name.startswith("0.s")]
    cov = band_covariance(trajs[0].quat, trajs[0].position, np.stack([s.quat for s in samples]),
                          np.stack([s.position for s in samples]))
    path = tmp_path / "g.mcap"
    write_rollouts_mcap(trajs, path, bands={0: (trajs[0].t, trajs[0].quat, trajs[0].position, cov)})
    _, msgs = _decoded(path)
    band = [m for m in msgs if m.channel.topic == "/rbgp/rollout_0/band"]
    assert band and band[0].schema.name == "geometry_msgs/msg/PoseWithCovarianceStamped"
    got = np.array([m.decoded_message.pose.covariance for m in band]).reshape(-1, 6, 6)
    np.testing.assert_array_equal(got, cov)
    np.testing.assert_array_equal([m.decoded_message.pose.pose.position.x for m in band], trajs[0].position[:, 0])
    assert len(mcap_reader.read(path)) == len(trajs)  # the band is not a generated trajectory


def test_foxglove_pose_in_frame(tmp_path):
    trajs = _trajs()
    path = tmp_path / "f.mcap"
    write_rollouts_mcap(trajs, path, encoding="foxglove", frame_id="map", start_ns=T0)
    summary, msgs = _decoded(path)
    assert {s.name for s in summary.schemas.values()} == {"foxglove.PoseInFrame"}
    first = [m for m in msgs if m.channel.topic == "/rbgp/rollout_1"]
    d = first[-1].decoded_message
    assert d.frame_id == "map"
    assert d.timestamp.ToNanoseconds() == T0 + round(trajs[1].t[-1] * 1e9)
    assert (d.pose.orientation.x, d.pose.orientation.w, d.pose.position.z) == (
        trajs[1].quat[-1, 0], trajs[1].quat[-1, 3], trajs[1].position[-1, 2])
    with pytest.raises(InputError, match="Foxglove has no message"):
        write_rollouts_mcap(trajs, tmp_path / "x.mcap", encoding="foxglove", bands={0: None})


def test_rosbag2_folder_plays_through_rosbags(tmp_path):
    """rosbags (pure Python, independent of mcap) reads the folder as ros2 bag does: metadata.yaml,
    the MCAP storage plugin and CDR against its own ROS 2 type store."""
    pytest.importorskip("rosbags")
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    trajs = _trajs()
    samples = [t for t in trajs if t.name.startswith("0.s")]
    cov = band_covariance(trajs[0].quat, trajs[0].position, np.stack([s.quat for s in samples]),
                          np.stack([s.position for s in samples]))
    bag = tmp_path / "bag"
    write_rollouts_mcap(trajs, bag, folder=True, start_ns=T0, frame_id="lab",
                        bands={0: (trajs[0].t, trajs[0].quat, trajs[0].position, cov)})
    assert sorted(p.name for p in bag.iterdir()) == ["bag_0.mcap", "metadata.yaml"]
    store = get_typestore(Stores.ROS2_HUMBLE)
    got: dict = {}
    with Reader(bag) as reader:
        assert reader.message_count == sum(len(t) for t in trajs) + len(trajs[0])
        assert reader.start_time == T0
        for conn, stamp, raw in reader.messages():
            msg = store.deserialize_cdr(raw, conn.msgtype)
            got.setdefault(conn.topic, []).append((stamp, msg))
    for tr in trajs:
        rows = got[rollout_topic(tr.name)]
        assert [s for s, _ in rows] == list(T0 + np.round(tr.t * 1e9).astype(np.int64))
        pos = np.array([[m.pose.position.x, m.pose.position.y, m.pose.position.z] for _, m in rows])
        quat = np.array([[m.pose.orientation.x, m.pose.orientation.y, m.pose.orientation.z, m.pose.orientation.w] for _, m in rows])
        np.testing.assert_array_equal(pos, tr.position)
        np.testing.assert_array_equal(quat, tr.quat)
        assert rows[0][1].header.frame_id == "lab"
    band = got["/rbgp/rollout_0/band"]
    np.testing.assert_array_equal(np.array([m.pose.covariance for _, m in band]).reshape(-1, 6, 6), cov)


def test_a_non_empty_folder_is_not_replaced_and_nothing_is_left_on_failure(tmp_path):
    bag = tmp_path / "bag"
    bag.mkdir()
    (bag / "keep.txt").write_text("mine")
    with pytest.raises(InputError, match="not empty"):
        write_rollouts_mcap(_trajs(), bag, folder=True)
    assert [p.name for p in bag.iterdir()] == ["keep.txt"]
    bad = _trajs()
    bad[0] = Trajectory(bad[0].t * np.nan, bad[0].quat, bad[0].position, name="0")
    with pytest.raises(InputError, match="non-finite times"):
        write_rollouts_mcap(bad, tmp_path / "g.mcap")
    with pytest.raises(InputError, match="non-finite times"):
        write_rollouts_mcap(bad, tmp_path / "newbag", folder=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bag"]


@pytest.mark.parametrize("encoding", ["ros2", "foxglove"])
def test_the_file_passes_the_mcap_librarys_checks(tmp_path, encoding):
    """What the mcap library validates: every record parses, the chunks' CRCs hold (StreamReader with validate_crcs), the file ends with the magic, and the summary (statistics,
    chunk and message indexes) agrees with what the records hold."""
    from mcap.reader import make_reader
    from mcap.records import Chunk, DataEnd, Footer, Header, Message, MessageIndex
    from mcap.stream_reader import StreamReader

    trajs = _trajs()
    path = tmp_path / "g.mcap"
    write_rollouts_mcap(trajs, path, encoding=encoding, start_ns=T0)
    with open(path, "rb") as fh:
        records = list(StreamReader(fh, validate_crcs=True).records)
    kinds = [type(r) for r in records]
    assert kinds[0] is Header and kinds[-1] is Footer and DataEnd in kinds
    # (the mcap writer leaves the data section's CRC 0, "not computed" in the specification; chunks have theirs)
    assert all(c.uncompressed_crc != 0 for c in records if isinstance(c, Chunk))
    messages = [r for r in records if isinstance(r, Message)]
    indexed = sum(len(r.records) for r in records if isinstance(r, MessageIndex))
    assert len(messages) == indexed == sum(len(t) for t in trajs)
    assert path.read_bytes().endswith(b"\x89MCAP0\r\n")
    with open(path, "rb") as fh:
        reader = make_reader(fh, validate_crcs=True)
        summary = reader.get_summary()
        stats = summary.statistics
        assert stats.message_count == len(messages)
        assert stats.message_start_time == min(m.log_time for m in messages) == T0
        assert stats.message_end_time == max(m.log_time for m in messages)
        per_channel = {summary.channels[c].topic: n for c, n in stats.channel_message_counts.items()}
        assert per_channel == {rollout_topic(t.name): len(t) for t in trajs}
        assert len(list(reader.iter_messages())) == len(messages)


def test_region_covariance_has_the_band_as_its_90_percent_regions():
    """The band topic's covariance (rbgp's band, issue 36): a Gaussian with it holds 90 % per position
    axis inside the band's half-widths and 90 % of its rotations inside the band's region (checked by
    drawing from it), in REP 103's order with no position–rotation terms."""
    from rbgp_cli.io.mcap_out import region_covariance

    rng = np.random.default_rng(3)
    half = np.array([[0.02, 0.05, 0.01], [0.1, 0.03, 0.07]])
    A = rng.normal(size=(2, 3, 3))
    M = A @ A.transpose(0, 2, 1) * 0.01 + 1e-4 * np.eye(3)
    cov = region_covariance(half, M)
    assert cov.shape == (2, 6, 6) and np.all(cov[:, :3, 3:] == 0.0) and np.all(cov[:, 3:, :3] == 0.0)
    for n in range(2):
        x = rng.multivariate_normal(np.zeros(6), cov[n], size=40000)
        np.testing.assert_allclose(np.mean(np.abs(x[:, :3]) <= half[n], axis=0), 0.90, atol=0.01)
        m2 = np.einsum("ki,ki->k", x[:, 3:], np.linalg.solve(M[n], x[:, 3:].T).T)
        assert abs(np.mean(m2 <= 1.0) - 0.90) < 0.01
