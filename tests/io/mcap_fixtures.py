"""Helpers that write small MCAP files (into a test's tmp_path) with known poses and times.

Every writer takes the same ground truth from :func:`ground_truth` so the tests can check that each
encoding reads back to the same poses and times. Times start at 1 s (not the epoch) so that float64
seconds can be compared to 1e-9.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

T0_NS = 1_000_000_000
DT_NS = 10_000_000  # 100 Hz
LOG_OFFSET_NS = 500_000  # log time = header stamp + 0.5 ms

_SEP = "=" * 80

HEADER_DEFS = f"""{_SEP}
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id
{_SEP}
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
"""


def _xyz_def(name: str) -> str:
    """The definition of a geometry_msgs type of three float64 fields x, y, z (Point, Vector3)."""
    return f"{_SEP}\nMSG: geometry_msgs/{name}\nfloat64 x\nfloat64 y\nfloat64 z\n"


QUATERNION_DEF = f"{_SEP}\nMSG: geometry_msgs/Quaternion\nfloat64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n"
POSE_DEFS = f"{_SEP}\nMSG: geometry_msgs/Pose\nPoint position\nQuaternion orientation\n" + _xyz_def("Point") + QUATERNION_DEF
TRANSFORM_DEFS = (f"{_SEP}\nMSG: geometry_msgs/Transform\nVector3 translation\nQuaternion rotation\n"
                  + _xyz_def("Vector3") + QUATERNION_DEF)

MSGDEFS = {
    "geometry_msgs/msg/PoseStamped": "std_msgs/Header header\nPose pose\n" + HEADER_DEFS + POSE_DEFS,
    "geometry_msgs/msg/PoseWithCovarianceStamped": (
        "std_msgs/Header header\nPoseWithCovariance pose\n"
        + HEADER_DEFS
        + f"{_SEP}\nMSG: geometry_msgs/PoseWithCovariance\nPose pose\nfloat64[36] covariance\n"
        + POSE_DEFS
    ),
    "geometry_msgs/msg/TransformStamped": (
        "std_msgs/Header header\nstring child_frame_id\nTransform transform\n" + HEADER_DEFS + TRANSFORM_DEFS
    ),
    "tf2_msgs/msg/TFMessage": (
        "geometry_msgs/TransformStamped[] transforms\n"
        + f"{_SEP}\nMSG: geometry_msgs/TransformStamped\n"
        + "std_msgs/Header header\nstring child_frame_id\nTransform transform\n"
        + HEADER_DEFS
        + TRANSFORM_DEFS
    ),
    "nav_msgs/msg/Odometry": (
        "std_msgs/Header header\nstring child_frame_id\n"
        "geometry_msgs/PoseWithCovariance pose\ngeometry_msgs/TwistWithCovariance twist\n"
        + HEADER_DEFS
        + f"{_SEP}\nMSG: geometry_msgs/PoseWithCovariance\nPose pose\nfloat64[36] covariance\n"
        + POSE_DEFS
        + f"{_SEP}\nMSG: geometry_msgs/TwistWithCovariance\nTwist twist\nfloat64[36] covariance\n"
        + f"{_SEP}\nMSG: geometry_msgs/Twist\nVector3 linear\nVector3 angular\n"
        + _xyz_def("Vector3")
    ),
    "std_msgs/msg/String": "string data\n",
}


def ground_truth(n: int = 50, seed: int = 0, frames: int = 1):
    """Header stamps (ns ints), positions (frames, n, 3) and unit quaternions x,y,z,w (frames, n, 4)."""
    rng = np.random.default_rng(seed)
    stamps = T0_NS + DT_NS * np.arange(n, dtype=np.int64)
    pos = rng.normal(scale=0.5, size=(frames, n, 3))
    q = rng.normal(size=(frames, n, 4))
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    q[q[..., 3] < 0] *= -1
    return stamps, pos, q


def _stamp(ns: int) -> dict:
    return {"sec": int(ns // 1_000_000_000), "nanosec": int(ns % 1_000_000_000)}


def _xyz(p) -> dict:
    return {"x": float(p[0]), "y": float(p[1]), "z": float(p[2])}


def _xyzw(q) -> dict:
    return {"x": float(q[0]), "y": float(q[1]), "z": float(q[2]), "w": float(q[3])}


def _pose(p, q) -> dict:
    return {"position": _xyz(p), "orientation": _xyzw(q)}


def _transform(p, q) -> dict:
    return {"translation": _xyz(p), "rotation": _xyzw(q)}


def ros2_message(type_name: str, ns: int, p, q, child: str = "body", extra=None) -> dict:
    """A plain dict in the layout of the ROS 2 message ``type_name``."""
    header = {"stamp": _stamp(ns), "frame_id": "world"}
    if type_name.endswith("PoseStamped") and "Covariance" not in type_name:
        return {"header": header, "pose": _pose(p, q)}
    if type_name.endswith("PoseWithCovarianceStamped"):
        return {"header": header, "pose": {"pose": _pose(p, q), "covariance": [0.0] * 36}}
    if type_name.endswith("TransformStamped"):
        return {"header": header, "child_frame_id": child, "transform": _transform(p, q)}
    if type_name.endswith("Odometry"):
        zero = {"x": 0.0, "y": 0.0, "z": 0.0}
        return {
            "header": header,
            "child_frame_id": child,
            "pose": {"pose": _pose(p, q), "covariance": [0.0] * 36},
            "twist": {"twist": {"linear": zero, "angular": zero}, "covariance": [0.0] * 36},
        }
    raise ValueError(type_name)


def write_ros2(path, type_name: str, n: int = 50, seed: int = 0, topic: str = "/pose", chunk_size: int = 1024 * 1024,
               extra_topics: dict | None = None, compression=None):  # fmt: skip
    """One topic of ``type_name`` (TFMessage: two child frames ``a`` and ``b`` per message)."""
    from mcap_ros2.writer import Writer

    frames = 2 if type_name.endswith("TFMessage") else 1
    stamps, pos, q = ground_truth(n, seed, frames)
    kw = {} if compression is None else {"compression": compression}
    with open(path, "wb") as fh:
        w = Writer(fh, chunk_size=chunk_size, **kw)
        schema = w.register_msgdef(type_name, MSGDEFS[type_name])
        others = {t: w.register_msgdef(ty, MSGDEFS[ty]) for t, ty in (extra_topics or {}).items()}
        for k, ns in enumerate(stamps):
            if type_name.endswith("TFMessage"):
                msg = {
                    "transforms": [
                        {
                            "header": {"stamp": _stamp(ns), "frame_id": "world"},
                            "child_frame_id": child,
                            "transform": _transform(pos[f, k], q[f, k]),
                        }
                        for f, child in enumerate(("a", "b"))
                    ]
                }
            else:
                msg = ros2_message(type_name, int(ns), pos[0, k], q[0, k])
            w.write_message(topic, schema, msg, log_time=int(ns) + LOG_OFFSET_NS, publish_time=int(ns))
            for t, sch in others.items():
                w.write_message(t, sch, {"data": f"hello {k}"}, log_time=int(ns) + 1, publish_time=int(ns))
        w.finish()
    return stamps, pos, q


def _pb_time(ns: int):
    from google.protobuf.timestamp_pb2 import Timestamp

    ts = Timestamp()
    ts.FromNanoseconds(int(ns))
    return ts


def _pb_pose(p, q):
    from foxglove_schemas_protobuf.Pose_pb2 import Pose
    from foxglove_schemas_protobuf.Quaternion_pb2 import Quaternion
    from foxglove_schemas_protobuf.Vector3_pb2 import Vector3

    return Pose(
        position=Vector3(x=p[0], y=p[1], z=p[2]),
        orientation=Quaternion(x=q[0], y=q[1], z=q[2], w=q[3]),
    )


def write_protobuf(path, type_name: str, n: int = 50, seed: int = 0, topic: str = "/pose"):
    """foxglove_schemas_protobuf messages: PoseInFrame, PosesInFrame (2 poses), FrameTransform,
    FrameTransforms (children a, b)."""
    from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
    from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
    from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
    from foxglove_schemas_protobuf.PosesInFrame_pb2 import PosesInFrame
    from foxglove_schemas_protobuf.Quaternion_pb2 import Quaternion
    from foxglove_schemas_protobuf.Vector3_pb2 import Vector3
    from mcap_protobuf.writer import Writer

    frames = 2 if type_name in ("PosesInFrame", "FrameTransforms") else 1
    stamps, pos, q = ground_truth(n, seed, frames)

    def ft(ns, f, child):
        p, r = pos[f, k], q[f, k]
        return FrameTransform(
            timestamp=_pb_time(ns), parent_frame_id="world", child_frame_id=child,
            translation=Vector3(x=p[0], y=p[1], z=p[2]), rotation=Quaternion(x=r[0], y=r[1], z=r[2], w=r[3]),
        )  # fmt: skip

    with open(path, "wb") as fh, Writer(fh) as w:
        for k, ns in enumerate(stamps):
            ns = int(ns)
            if type_name == "PoseInFrame":
                msg = PoseInFrame(timestamp=_pb_time(ns), frame_id="world", pose=_pb_pose(pos[0, k], q[0, k]))
            elif type_name == "PosesInFrame":
                msg = PosesInFrame(
                    timestamp=_pb_time(ns), frame_id="world", poses=[_pb_pose(pos[f, k], q[f, k]) for f in range(2)]
                )
            elif type_name == "FrameTransform":
                msg = ft(ns, 0, "body")
            elif type_name == "FrameTransforms":
                msg = FrameTransforms(transforms=[ft(ns, f, c) for f, c in enumerate(("a", "b"))])
            else:
                raise ValueError(type_name)
            w.write_message(topic, msg, log_time=ns + LOG_OFFSET_NS, publish_time=ns)
    return stamps, pos, q


POSE_IN_FRAME_JSONSCHEMA = {
    "title": "foxglove.PoseInFrame",
    "type": "object",
    "properties": {"timestamp": {"type": "object"}, "frame_id": {"type": "string"}, "pose": {"type": "object"}},
}


def write_json(path, n: int = 50, seed: int = 0, topic: str = "/pose", schema_name: str = "foxglove.PoseInFrame",
               schema_encoding: str = "jsonschema", ros_layout: bool = False):  # fmt: skip
    """Raw mcap Writer, JSON messages: foxglove.PoseInFrame ({sec, nsec}) or, with ``ros_layout``, a ROS
    PoseStamped layout (used with a ROS schema name to provoke the "JSON under ROS schema" error)."""
    from mcap.writer import Writer

    stamps, pos, q = ground_truth(n, seed)
    with open(path, "wb") as fh:
        w = Writer(fh)
        w.start(profile="", library="rbgp-tests")
        data = (
            MSGDEFS["geometry_msgs/msg/PoseStamped"].encode()
            if schema_encoding == "ros2msg"
            else json.dumps(POSE_IN_FRAME_JSONSCHEMA).encode()
        )
        sid = w.register_schema(schema_name, schema_encoding, data)
        cid = w.register_channel(topic, "json", sid)
        for k, ns in enumerate(stamps):
            ns = int(ns)
            if ros_layout:
                obj = ros2_message("geometry_msgs/msg/PoseStamped", ns, pos[0, k], q[0, k])
            else:
                obj = {
                    "timestamp": {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000},
                    "frame_id": "world",
                    "pose": _pose(pos[0, k], q[0, k]),
                }
            w.add_message(cid, log_time=ns + LOG_OFFSET_NS, data=json.dumps(obj).encode(), publish_time=ns)
        w.finish()
    return stamps, pos, q


def write_foxglove_sdk(path, n: int = 50, seed: int = 0, topic: str = "/pose"):
    """foxglove-sdk (its own Context per file), PoseInFrame messages, protobuf-encoded."""
    import foxglove
    from foxglove.channels import PoseInFrameChannel
    from foxglove.messages import Pose, PoseInFrame, Quaternion, Timestamp, Vector3

    stamps, pos, q = ground_truth(n, seed)
    ctx = foxglove.Context()
    with foxglove.open_mcap(str(path), allow_overwrite=True, context=ctx):
        ch = PoseInFrameChannel(topic, context=ctx)
        for k, ns in enumerate(stamps):
            ns = int(ns)
            p, r = pos[0, k], q[0, k]
            msg = PoseInFrame(
                timestamp=Timestamp(sec=ns // 1_000_000_000, nsec=ns % 1_000_000_000),
                frame_id="world",
                pose=Pose(
                    position=Vector3(x=float(p[0]), y=float(p[1]), z=float(p[2])),
                    orientation=Quaternion(x=float(r[0]), y=float(r[1]), z=float(r[2]), w=float(r[3])),
                ),
            )
            ch.log(msg, log_time=ns + LOG_OFFSET_NS)
    return stamps, pos, q


def write_strings(path, topic: str = "/chatter", n: int = 5):
    """A file with a std_msgs/String topic only (no pose)."""
    from mcap_ros2.writer import Writer

    with open(path, "wb") as fh:
        w = Writer(fh)
        schema = w.register_msgdef("std_msgs/msg/String", MSGDEFS["std_msgs/msg/String"])
        for k in range(n):
            w.write_message(topic, schema, {"data": f"hi {k}"}, log_time=T0_NS + k, publish_time=T0_NS + k)
        w.finish()


def truncate(src, dst, size: int) -> Path:
    """Copy the first ``size`` bytes of ``src`` to ``dst``."""
    data = Path(src).read_bytes()
    Path(dst).write_bytes(data[:size])
    return Path(dst)


def write_ros2_topics(path, topics: dict, n: int = 20, seed: int = 0, stamps_zero: bool = False, finish: bool = True,
                      chunk_size: int = 1024 * 1024):  # fmt: skip
    """Several single-pose ROS 2 topics ({topic: type name}), all with the same poses; with
    ``stamps_zero`` the header stamps are 0 (log times stay real); without ``finish`` the writer is
    left unfinished (no summary, no footer), as after a crash."""
    from mcap_ros2.writer import Writer

    stamps, pos, q = ground_truth(n, seed)
    fh = open(path, "wb")
    w = Writer(fh, chunk_size=chunk_size)
    schemas = {t: w.register_msgdef(ty, MSGDEFS[ty]) for t, ty in topics.items()}
    for k, ns in enumerate(stamps):
        for t, ty in topics.items():
            msg = ros2_message(ty, 0 if stamps_zero else int(ns), pos[0, k], q[0, k])
            w.write_message(t, schemas[t], msg, log_time=int(ns) + LOG_OFFSET_NS, publish_time=int(ns))
    if finish:
        w.finish()  # else: only the chunks already full are in the file, as a crashed recorder leaves it
    fh.close()
    return stamps, pos, q


def write_raw(path, topic: str, schema_name: str, schema_encoding: str, schema_data: bytes, message_encoding: str,
              payloads: list):  # fmt: skip
    """Raw mcap Writer: any schema/encoding, given message payloads (for error cases)."""
    from mcap.writer import Writer

    with open(path, "wb") as fh:
        w = Writer(fh)
        w.start(profile="", library="rbgp-tests")
        sid = w.register_schema(schema_name, schema_encoding, schema_data)
        cid = w.register_channel(topic, message_encoding, sid)
        for k, data in enumerate(payloads):
            ns = T0_NS + k * DT_NS
            w.add_message(cid, log_time=ns, data=data, publish_time=ns)
        w.finish()


def chunk_data_offsets(path) -> list[int]:
    """File offsets of the compressed data of every chunk (from the summary's chunk indexes)."""
    from mcap.reader import make_reader

    with open(path, "rb") as fh:
        summary = make_reader(fh).get_summary()
    return [ci.chunk_start_offset + ci.chunk_length - ci.compressed_size for ci in summary.chunk_indexes]
