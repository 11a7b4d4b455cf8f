"""Write generated trajectories to MCAP: one topic per trajectory, for ROS 2 tools or Foxglove.

Topics (ROS 2 names: a name token must not start with a digit, so the index follows a word)::

    /rbgp/rollout_<b>                  mean rollout b
    /rbgp/rollout_<b>/sample_<k>       its k-th sampled rollout (rollout --samples)
    /rbgp/rollout_<b>/band             the 90 % band about the mean rollout (ROS 2 only, K >= 2)

Messages, per ``encoding``:

``ros2`` (profile ``ros2``; ROS 2 CDR with the ``ros2msg`` schema text, written by
``mcap_ros2.writer``): rollouts and samples are ``geometry_msgs/msg/PoseStamped``, the band is
``geometry_msgs/msg/PoseWithCovarianceStamped`` whose pose is the mean rollout's and whose covariance
(6 x 6, row-major, order x, y, z, rotation about the fixed X, Y, Z axes as REP 103 states) is, for a
model that gives the next motion's 90 % band (rbgp's sampled rollouts: docs/method.md §11), the
Gaussian covariance whose 90 % regions are that band (:func:`region_covariance`); otherwise (per-step
Monte Carlo samples) the second moment of the K samples about that pose: position
d_p = p_k - p_mean (m), rotation d_r = log(R_k R_mean^T) (rad, world axes), Σ = (1/K) Σ_k d d^T
(:func:`band_covariance`).

``foxglove`` (protobuf, written by ``mcap_protobuf.writer`` with ``foxglove_schemas_protobuf``):
``foxglove.PoseInFrame`` for rollouts and samples; Foxglove has no pose-with-covariance message, so
no band.

Times: each message's log time, publish time and header stamp are ``start_ns + round(t * 1e9)`` (t in
seconds from the trajectory's start). Poses are float64 as rbgp holds them (metres, quaternion x, y,
z, w), so they read back bit for bit. Messages are written in time order across topics.

A folder destination is a rosbag2 bag: ``<folder>/<folder name>_0.mcap`` and the ``metadata.yaml``
(version 5) that ``ros2 bag`` reads. Both a file and a folder are written atomically
(:mod:`rbgp_cli.io.atomic`).
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from rbgp_cli.errors import InputError
from rbgp_cli.io.atomic import atomic_dir, atomic_open

__all__ = ["write_rollouts_mcap", "rollout_topic", "ROLLOUT_TOPIC_RE", "band_covariance", "region_covariance", "ENCODINGS",
           "POSE_STAMPED_MSGDEF", "POSE_COV_STAMPED_MSGDEF"]

ENCODINGS = ("ros2", "foxglove")

#: The topics of generated trajectories (mean rollouts and samples), not the bands.
ROLLOUT_TOPIC_RE = re.compile(r"^/rbgp/rollout_(\d+)(?:/sample_(\d+))?$")

_SEP = "=" * 80
_HEADER = f"""{_SEP}
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id
{_SEP}
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
"""
_POSE = f"""{_SEP}
MSG: geometry_msgs/Pose
Point position
Quaternion orientation
{_SEP}
MSG: geometry_msgs/Point
float64 x
float64 y
float64 z
{_SEP}
MSG: geometry_msgs/Quaternion
float64 x 0
float64 y 0
float64 z 0
float64 w 1
"""
#: ``geometry_msgs/msg/PoseStamped`` with its dependencies, in the gendeps text ``ros2msg`` schemas hold.
POSE_STAMPED_MSGDEF = "std_msgs/Header header\nPose pose\n" + _HEADER + _POSE
#: ``geometry_msgs/msg/PoseWithCovarianceStamped`` with its dependencies.
POSE_COV_STAMPED_MSGDEF = (
    "std_msgs/Header header\nPoseWithCovariance pose\n" + _HEADER
    + f"{_SEP}\nMSG: geometry_msgs/PoseWithCovariance\nPose pose\nfloat64[36] covariance\n" + _POSE
)


def rollout_topic(name: str) -> str:
    """The topic of a trajectory named as :meth:`RolloutResult.trajectories` names them: ``"3"`` ->
    ``/rbgp/rollout_3``, ``"3.s1"`` -> ``/rbgp/rollout_3/sample_1``; other names are made into one
    valid ROS 2 name token under ``/rbgp/``."""
    m = re.fullmatch(r"(\d+)(?:\.s(\d+))?", name)
    if m:
        return f"/rbgp/rollout_{m.group(1)}" + (f"/sample_{m.group(2)}" if m.group(2) is not None else "")
    token = re.sub(r"[^A-Za-z0-9_]", "_", name) or "trajectory"
    return "/rbgp/" + (token if not token[0].isdigit() else "t_" + token)


def band_covariance(quat_mean, pos_mean, quat_samples, pos_samples) -> np.ndarray:
    """Second moment of sampled poses about a mean pose, per step, in REP 103's order.

    quat_mean (N, 4) x, y, z, w and pos_mean (N, 3) m; quat_samples (K, N, 4), pos_samples (K, N, 3).
    Returns (N, 6, 6): Σ = (1/K) Σ_k d_k d_kᵀ with d_k = (p_k − p, log(R_k Rᵀ)) (metres; radians
    about the world's fixed X, Y, Z axes).
    """
    from scipy.spatial.transform import Rotation

    K, N = pos_samples.shape[:2]
    R_inv = Rotation.from_quat(np.asarray(quat_mean)).inv()
    d = np.empty((K, N, 6))
    d[:, :, :3] = pos_samples - pos_mean[None]
    for k in range(K):
        d[k, :, 3:] = (Rotation.from_quat(quat_samples[k]) * R_inv).as_rotvec()
    return np.einsum("kni,knj->nij", d, d) / K


def region_covariance(band_position, band_rotation, level: float = 0.90) -> np.ndarray:
    """The covariance (N, 6, 6), REP 103's order (x, y, z, then rotation about the world's X, Y, Z), of
    the Gaussian whose ``level`` regions are a band (:attr:`rbgp_cli.dynamics.rollout.RolloutResult.band_position`
    (N, 3) m half-widths per axis, ``band_rotation`` (N, 3, 3) rad² regions {e : eᵀ M⁻¹ e ≤ 1}): position
    variances (half / z_(1+level)/2)², rotation M / χ²_3(level), no position–rotation terms. A reader that
    draws the covariance's 90 % region draws the band."""
    from scipy.special import chdtri, ndtri

    half = np.asarray(band_position, dtype=np.float64)
    M = np.asarray(band_rotation, dtype=np.float64)
    cov = np.zeros(half.shape[:-1] + (6, 6))
    cov[..., [0, 1, 2], [0, 1, 2]] = (half / ndtri(0.5 + level / 2.0)) ** 2
    cov[..., 3:, 3:] = M / chdtri(3, 1.0 - level)
    return cov


def _stamp(ns: int) -> dict:
    sec, nanosec = divmod(int(ns), 1_000_000_000)
    if not -(2**31) <= sec < 2**31:
        raise InputError(f"the time {ns * 1e-9:g} s does not fit a ROS 2 stamp (int32 seconds)",
                         hint="pass a start time between 1901 and 2038", param="start_time")
    return {"sec": sec, "nanosec": nanosec}


def _pose(q, p) -> dict:
    return {"position": {"x": float(p[0]), "y": float(p[1]), "z": float(p[2])},
            "orientation": {"x": float(q[0]), "y": float(q[1]), "z": float(q[2]), "w": float(q[3])}}


def _events(series):
    """(j, index) in time order across the series (each a trajectory sharing the step grid or not)."""
    times = [np.asarray(s["t"]) for s in series]
    order = np.argsort(np.concatenate(times), kind="stable")
    owner = np.concatenate([np.full(len(t), i) for i, t in enumerate(times)])
    step = np.concatenate([np.arange(len(t)) for t in times])
    return zip(owner[order].tolist(), step[order].tolist())


def _series(trajectories, bands, start_ns: int) -> list[dict]:
    out = []
    for tr in trajectories:
        out.append({"topic": rollout_topic(tr.name or str(len(out))), "t": tr.t, "quat": tr.quat,
                    "position": tr.position, "cov": None})
    for b, (t, quat, position, cov) in (bands or {}).items():
        out.append({"topic": f"/rbgp/rollout_{b}/band", "t": t, "quat": quat, "position": position, "cov": cov})
    topics = [s["topic"] for s in out]
    if len(set(topics)) != len(topics):
        raise InputError("two trajectories would share one MCAP topic: " + ", ".join(sorted({x for x in topics if topics.count(x) > 1})))
    for s in out:
        if not len(s["t"]):
            continue
        t = np.asarray(s["t"], dtype=np.float64)
        if not np.all(np.isfinite(t)):
            raise InputError(f"trajectory {s['topic']} has non-finite times")
        s["ns"] = start_ns + np.round(t * 1e9).astype(np.int64)
    return out


def _write_ros2(fh, series, frame_id: str) -> dict:
    from mcap_ros2.writer import Writer

    counts: dict = {}
    w = Writer(fh)
    pose_schema = w.register_msgdef("geometry_msgs/msg/PoseStamped", POSE_STAMPED_MSGDEF)
    cov_schema = None
    if any(s["cov"] is not None for s in series):
        cov_schema = w.register_msgdef("geometry_msgs/msg/PoseWithCovarianceStamped", POSE_COV_STAMPED_MSGDEF)
    for i, j in _events(series):
        s = series[i]
        ns = int(s["ns"][j])
        header = {"stamp": _stamp(ns), "frame_id": frame_id}
        pose = _pose(s["quat"][j], s["position"][j])
        if s["cov"] is None:
            msg, schema = {"header": header, "pose": pose}, pose_schema
        else:
            msg = {"header": header, "pose": {"pose": pose, "covariance": [float(v) for v in s["cov"][j].ravel()]}}
            schema = cov_schema
        counts[s["topic"]] = counts.get(s["topic"], 0) + 1
        w.write_message(s["topic"], schema, msg, log_time=ns, publish_time=ns, sequence=j)
    w.finish()
    return counts


def _write_foxglove(fh, series, frame_id: str) -> dict:
    from foxglove_schemas_protobuf.Pose_pb2 import Pose
    from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
    from foxglove_schemas_protobuf.Quaternion_pb2 import Quaternion
    from foxglove_schemas_protobuf.Vector3_pb2 import Vector3
    from google.protobuf.timestamp_pb2 import Timestamp
    from mcap_protobuf.writer import Writer

    counts: dict = {}
    w = Writer(fh)
    for i, j in _events(series):
        s = series[i]
        ns = int(s["ns"][j])
        q, p = s["quat"][j], s["position"][j]
        ts = Timestamp()
        ts.FromNanoseconds(ns)
        msg = PoseInFrame(timestamp=ts, frame_id=frame_id,
                          pose=Pose(position=Vector3(x=float(p[0]), y=float(p[1]), z=float(p[2])),
                                    orientation=Quaternion(x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3]))))
        counts[s["topic"]] = counts.get(s["topic"], 0) + 1
        w.write_message(s["topic"], msg, log_time=ns, publish_time=ns, sequence=j)
    w.finish()
    return counts


def _metadata_yaml(file_name: str, series, counts: dict, types: dict) -> str:
    """rosbag2's ``metadata.yaml`` (version 5: per-file entries, QoS as a YAML string)."""
    import json

    ns = [s["ns"] for s in series if "ns" in s and len(s["ns"])]
    first = int(min(a.min() for a in ns)) if ns else 0
    last = int(max(a.max() for a in ns)) if ns else 0
    total = sum(counts.values())
    q = json.dumps  # a JSON string is a valid YAML scalar
    lines = ["rosbag2_bagfile_information:", "  version: 5", "  storage_identifier: mcap",
             f"  duration:\n    nanoseconds: {last - first}",
             f"  starting_time:\n    nanoseconds_since_epoch: {first}",
             f"  message_count: {total}", "  topics_with_message_count:"]
    for s in series:
        lines += ["    - topic_metadata:", f"        name: {q(s['topic'])}", f"        type: {q(types[s['topic']])}",
                  "        serialization_format: cdr", '        offered_qos_profiles: ""',
                  f"      message_count: {counts.get(s['topic'], 0)}"]
    lines += ['  compression_format: ""', '  compression_mode: ""', "  relative_file_paths:", f"    - {q(file_name)}",
              "  files:", f"    - path: {q(file_name)}", f"      starting_time:\n        nanoseconds_since_epoch: {first}",
              f"      duration:\n        nanoseconds: {last - first}", f"      message_count: {total}"]
    return "\n".join(lines) + "\n"


def write_rollouts_mcap(trajectories, destination, *, frame_id: str = "world", start_ns: int = 0,
                        encoding: str = "ros2", bands: dict | None = None, folder: bool = False) -> dict:
    """Write trajectories to an MCAP file (or a rosbag2 folder), one topic each.

    Parameters
    ----------
    trajectories : sequence of Trajectory
        Named as :meth:`~rbgp_cli.dynamics.rollout.RolloutResult.trajectories` names them (``"0"``,
        ``"0.s1"``, ...; see :func:`rollout_topic`). Seconds from the start, metres, x, y, z, w.
    destination : path-like or binary stream
        A path is written atomically; a stream (stdout) is written as it goes.
    frame_id : str
        ``header.frame_id`` (ROS 2) / ``frame_id`` (Foxglove) of every message.
    start_ns : int
        Nanoseconds since the epoch of t = 0: every message's log time and stamp is start_ns + t.
    encoding : {"ros2", "foxglove"}
    bands : dict b -> (t (N,), quat (N, 4), position (N, 3), covariance (N, 6, 6)), optional
        The bands of mean rollout b (ROS 2 only), e.g. from :func:`band_covariance`.
    folder : bool
        Write a rosbag2 folder (``destination``: the folder; the MCAP inside and ``metadata.yaml``).

    Returns ``{topic: message count}``.
    """
    if encoding not in ENCODINGS:
        raise InputError(f"MCAP encoding must be one of {', '.join(ENCODINGS)}, got {encoding!r}", param="encoding")
    if encoding == "foxglove":
        if bands:
            raise InputError("Foxglove has no message for a pose with covariance, so the bands need the ros2 encoding",
                             param="bands")
        if folder:
            raise InputError("a rosbag2 folder holds ROS 2 messages; write the Foxglove encoding to a .mcap file",
                             param="folder")
    series = _series(list(trajectories), bands, int(start_ns))
    write = _write_ros2 if encoding == "ros2" else _write_foxglove
    if not isinstance(destination, (str, os.PathLike)):
        return write(destination, series, frame_id)
    if not folder:
        with atomic_open(destination, "wb") as fh:
            return write(fh, series, frame_id)
    dest = Path(destination)
    name = (dest.name or dest.resolve().name) + "_0.mcap"
    with atomic_dir(dest) as tmp:
        with open(tmp / name, "wb") as fh:
            counts = write(fh, series, frame_id)
        types = {s["topic"]: "geometry_msgs/msg/PoseStamped" if s["cov"] is None
                 else "geometry_msgs/msg/PoseWithCovarianceStamped" for s in series}
        (tmp / "metadata.yaml").write_text(_metadata_yaml(name, series, counts, types), encoding="utf-8")
    return counts
