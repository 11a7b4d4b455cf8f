"""MCAP reader: pose topics of ROS 2 (CDR) and foxglove (protobuf or JSON) recordings.

Message types that carry a 6D pose (schema names with or without ``/msg/``):

=====================================================  =============================================
ROS 2 ``geometry_msgs/msg/PoseStamped``                ``header.stamp``, ``pose``
``geometry_msgs/msg/PoseWithCovarianceStamped``        ``header.stamp``, ``pose.pose``
``geometry_msgs/msg/TransformStamped``                 ``header.stamp``, ``transform``, child frame
``tf2_msgs/msg/TFMessage``                             per transform; one child frame (``frame``)
``nav_msgs/msg/Odometry``                              ``header.stamp``, ``pose.pose``
``geometry_msgs/msg/PoseArray``                        ``header.stamp``; one trajectory per index
``foxglove.PoseInFrame`` / ``foxglove.PosesInFrame``   ``timestamp``; PosesInFrame: one per index
``foxglove.FrameTransform(s)``                         ``timestamp`` per transform, child frame
``foxglove.Odometry``                                  ``timestamp``, ``pose``
=====================================================  =============================================

Every one names its quaternion components x, y, z, w, so no order is guessed. Times are the
message's own stamp (``ReadOptions.time_source == "header"``, the default) or the MCAP log time
(``"log"``), as float64 seconds since the epoch (spacing ~0.2 µs, far below any mocap rate). A topic
whose header stamps are all zero falls back to log time with a warning.

Reading streams: messages are decoded one at a time and only their floats are kept. A seekable file
reads its summary first (topic list and counts without decoding), then only the chosen topic's
chunks. A pipe (stdin) is read once, front to back (``NonSeekingReader``, ``log_time_order=False``),
collecting every pose topic, and the topic is chosen at the end; samples are sorted by time.

Damaged files (truncated, unfinished, corrupt chunk): the messages before the damage are kept, with a
warning saying how many; nothing usable is an :class:`~rbgp_cli.errors.InputError`.
"""

from __future__ import annotations

import contextlib
import functools
import io
import struct
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from rbgp_cli.dynamics.trajectory import Trajectory
from rbgp_cli.errors import InputError, NotPoseData, closest, warn
from rbgp_cli.io.formats import Format
from rbgp_cli.io.options import ReadOptions

__all__ = ["read", "read_stream", "read_all", "describe", "detect", "MAGIC", "POSE_SCHEMAS", "is_pose_schema", "FORMAT"]

MAGIC = b"\x89MCAP0\r\n"


def detect(head: bytes) -> bool:
    """The MCAP magic, or all of a file too short to hold it that begins like it (a file cut in its
    first 8 bytes is a truncated MCAP, not a CSV)."""
    head = bytes(head)
    return head.startswith(MAGIC) or (0 < len(head) < len(MAGIC) and MAGIC.startswith(head))


def _skip_reason(head: bytes, path=None, options=None, complete: bool = False) -> str | None:
    return None if detect(head) else "not an MCAP file"  # pose topics or not: reading decides

#: normalised schema name -> kind
POSE_SCHEMAS = {
    "geometry_msgs/PoseStamped": "pose_stamped",
    "geometry_msgs/PoseWithCovarianceStamped": "pose_cov_stamped",
    "geometry_msgs/TransformStamped": "transform_stamped",
    "tf2_msgs/TFMessage": "tf",
    "nav_msgs/Odometry": "odometry",
    "geometry_msgs/PoseArray": "pose_array",
    "foxglove.PoseInFrame": "fg_pose",
    "foxglove.PosesInFrame": "fg_poses",
    "foxglove.FrameTransform": "fg_transform",
    "foxglove.FrameTransforms": "fg_transforms",
    "foxglove.Odometry": "fg_odometry",
}
_FRAME_KINDS = {"transform_stamped", "tf", "fg_transform", "fg_transforms"}  # select by child frame
_INDEX_KINDS = {"pose_array", "fg_poses"}  # one trajectory per pose index
_SUPPORTED = (
    "geometry_msgs/msg/PoseStamped, PoseWithCovarianceStamped, TransformStamped, PoseArray, "
    "tf2_msgs/msg/TFMessage, nav_msgs/msg/Odometry, foxglove.PoseInFrame, PosesInFrame, "
    "FrameTransform(s), foxglove.Odometry"
)


def _normalise_schema(name: str | None) -> str:
    if not name:
        return ""
    n = name.strip().replace("::msg::", "/").replace("::", "/").replace("/msg/", "/")
    return n


def is_pose_schema(name: str | None) -> bool:
    """True for a schema name rbgp reads poses from (``geometry_msgs/msg/PoseStamped``, ...)."""
    return _normalise_schema(name) in POSE_SCHEMAS


def _corrupt_errors() -> tuple:
    """Exceptions a damaged MCAP raises while it is being read (ECOSYSTEM §1.2).

    mcap bounds a whole record at 4 GiB but trusts the lengths inside one (a chunk's data length): a
    corrupt one asks for an impossible read, OverflowError above sys.maxsize and MemoryError for a
    huge allocation that never happened (so memory is not exhausted and reading can go on). A damaged
    summary makes the seeking reader look up channels that do not exist (KeyError, IndexError)."""
    from mcap.exceptions import McapError

    errs = [McapError, struct.error, ValueError, EOFError, RuntimeError, OSError, OverflowError, MemoryError,
            KeyError, IndexError]  # fmt: skip
    try:
        import zstandard

        errs.append(zstandard.ZstdError)
    except ImportError:  # pragma: no cover - zstandard is a dependency of mcap
        pass
    return tuple(errs)


def _decoder_factories():
    import json

    from mcap.decoder import DecoderFactory
    from mcap_protobuf.decoder import DecoderFactory as ProtobufDecoderFactory
    from mcap_ros2.decoder import DecoderFactory as Ros2DecoderFactory

    class JsonDecoderFactory(DecoderFactory):
        """``json`` messages with a ``jsonschema`` schema (or none); the mcap package ships no JSON
        decoder."""

        def decoder_for(self, message_encoding, schema):
            if message_encoding != "json":
                return None
            if schema is not None and schema.encoding not in ("jsonschema", ""):
                return None
            return json.loads

    return [JsonDecoderFactory(), ProtobufDecoderFactory(), Ros2DecoderFactory()]


# --------------------------------------------------------------------------------------------------
# field access that works on ROS 2 objects, protobuf messages and JSON dicts


class _MissingField(Exception):
    pass


def _get(obj, name: str):
    if isinstance(obj, dict):
        if name not in obj:
            raise _MissingField(name)
        return obj[name]
    try:
        return getattr(obj, name)
    except AttributeError:
        raise _MissingField(name) from None


def _num(obj, name: str) -> float:
    """A numeric leaf; JSON written from protobuf omits zero-valued fields, so a missing leaf is 0."""
    if isinstance(obj, dict):
        return float(obj.get(name, 0.0) or 0.0)
    return float(getattr(obj, name))


def _stamp_ns(ts) -> int:
    """ROS 2 ``{sec, nanosec}``, ROS 1 ``{secs, nsecs}``, protobuf ``{seconds, nanos}``, JSON ``{sec, nsec}``."""
    if isinstance(ts, dict):
        sec = next((ts[k] for k in ("sec", "seconds", "secs") if k in ts), 0)
        ns = next((ts[k] for k in ("nsec", "nanosec", "nanos", "nsecs") if k in ts), 0)
        return int(sec) * 1_000_000_000 + int(ns)
    if isinstance(ts, (int, float)):
        return int(ts)
    for s_name, n_name in (("sec", "nanosec"), ("seconds", "nanos"), ("secs", "nsecs")):
        sec = getattr(ts, s_name, None)
        if sec is not None:
            return int(sec) * 1_000_000_000 + int(getattr(ts, n_name, 0) or 0)
    raise _MissingField("sec")


def _pose7(position, orientation) -> tuple:
    return (
        _num(position, "x"), _num(position, "y"), _num(position, "z"),
        _num(orientation, "x"), _num(orientation, "y"), _num(orientation, "z"), _num(orientation, "w"),
    )  # fmt: skip


def _samples(kind: str, msg):
    """Yield (sub, stamp_ns, parent_frame, child_frame, (x, y, z, qx, qy, qz, qw)) from one message."""
    g = _get
    if kind == "pose_stamped":
        h, pose = g(msg, "header"), g(msg, "pose")
        yield None, _stamp_ns(g(h, "stamp")), g(h, "frame_id"), None, _pose7(g(pose, "position"), g(pose, "orientation"))
    elif kind in ("pose_cov_stamped", "odometry"):
        h, pose = g(msg, "header"), g(g(msg, "pose"), "pose")
        child = g(msg, "child_frame_id") if kind == "odometry" else None
        yield None, _stamp_ns(g(h, "stamp")), g(h, "frame_id"), child, _pose7(g(pose, "position"), g(pose, "orientation"))
    elif kind in ("transform_stamped", "tf"):
        for tr in g(msg, "transforms") if kind == "tf" else (msg,):
            h, x = g(tr, "header"), g(tr, "transform")
            child = g(tr, "child_frame_id")
            yield child, _stamp_ns(g(h, "stamp")), g(h, "frame_id"), child, _pose7(g(x, "translation"), g(x, "rotation"))
    elif kind == "pose_array":
        h = g(msg, "header")
        stamp, frame = _stamp_ns(g(h, "stamp")), g(h, "frame_id")
        for i, pose in enumerate(g(msg, "poses")):
            yield i, stamp, frame, None, _pose7(g(pose, "position"), g(pose, "orientation"))
    elif kind in ("fg_pose", "fg_odometry"):
        pose = g(msg, "pose")
        child = g(msg, "body_frame_id") if kind == "fg_odometry" else None
        yield None, _stamp_ns(g(msg, "timestamp")), g(msg, "frame_id"), child, _pose7(g(pose, "position"), g(pose, "orientation"))
    elif kind == "fg_poses":
        stamp, frame = _stamp_ns(g(msg, "timestamp")), g(msg, "frame_id")
        for i, pose in enumerate(g(msg, "poses")):
            yield i, stamp, frame, None, _pose7(g(pose, "position"), g(pose, "orientation"))
    elif kind in ("fg_transform", "fg_transforms"):
        for tr in g(msg, "transforms") if kind == "fg_transforms" else (msg,):
            child = g(tr, "child_frame_id")
            yield child, _stamp_ns(g(tr, "timestamp")), g(tr, "parent_frame_id"), child, _pose7(
                g(tr, "translation"), g(tr, "rotation")
            )


def _frame_key(name) -> str:
    return str(name).strip().lstrip("/")


# --------------------------------------------------------------------------------------------------
# scanning


@dataclass
class _Topic:
    topic: str
    schema: str
    schema_encoding: str
    message_encoding: str
    count: int | None = None

    @property
    def kind(self) -> str | None:
        return POSE_SCHEMAS.get(_normalise_schema(self.schema))

    def label(self) -> str:
        n = "?" if self.count is None else str(self.count)
        return f"{self.topic} ({self.schema or 'no schema'}, {n} messages)"


@dataclass
class _Scan:
    source: str
    options: ReadOptions
    wanted: set | None  # topics to collect (None: every pose topic)
    topics: dict = field(default_factory=dict)  # topic -> _Topic (counts of what was read)
    series: dict = field(default_factory=dict)  # (topic, sub) -> list of tuples
    frames: dict = field(default_factory=dict)  # (topic, sub) -> (parent, child)
    error: Exception | None = None
    messages: int = 0


def _no_decoder(schema, channel, source: str) -> InputError:
    enc = channel.message_encoding
    senc = schema.encoding if schema is not None else "none"
    if senc == "ros2idl":
        msg = (
            f"messages use a ros2idl schema ({schema.name}), which mcap-ros2-support cannot decode "
            "(it reads ros2msg definitions only)"
        )
        hint = "record with ros2msg schemas (rosbag2's default) or convert the file"
    elif enc == "json":
        msg = f"messages are JSON-encoded but the schema {schema.name!r} is a {senc} definition, not a JSON schema"
        hint = "write JSON messages with a jsonschema schema, or ROS 2 messages CDR-encoded"
    else:
        msg = f"no decoder for {enc!r} messages with a {senc!r} schema"
        hint = "rbgp decodes cdr (ros2msg), protobuf and json messages"
    return InputError(msg, path=source, topic=channel.topic, hint=hint)


def _scan(iterator, scan: _Scan, factories: list) -> None:
    """Collect the floats of every wanted pose message; stop (and remember why) at damage."""
    corrupt = _corrupt_errors()
    decoders: dict = {}
    frame_filter = _frame_key(scan.options.frame) if scan.options.frame else None
    it = iter(iterator)
    while True:
        try:
            schema, channel, message = next(it)
        except StopIteration:
            break
        except corrupt as exc:
            scan.error = exc
            break
        topic = channel.topic
        info = scan.topics.get(topic)
        if info is None:
            info = scan.topics[topic] = _Topic(
                topic, schema.name if schema else "", schema.encoding if schema else "",
                channel.message_encoding, 0,
            )  # fmt: skip
        info.count = (info.count or 0) + 1
        kind = info.kind
        if kind is None or (scan.wanted is not None and topic not in scan.wanted):
            continue
        dec = decoders.get(channel.id)
        if dec is None:
            for factory in factories:
                try:
                    # mcap_ros2's message-definition parser prints to stderr before raising; the
                    # error below says it in one line
                    with contextlib.redirect_stderr(io.StringIO()):
                        dec = factory.decoder_for(channel.message_encoding, schema)
                except Exception as exc:  # a schema the factory cannot parse
                    raise InputError(
                        f"cannot parse the schema {schema.name if schema else ''!r} ({type(exc).__name__}: {exc})",
                        path=scan.source,
                        topic=topic,
                    ) from None
                if dec is not None:
                    break
            if dec is None:
                raise _no_decoder(schema, channel, scan.source)
            decoders[channel.id] = dec
        try:
            msg = dec(message.data)
        except Exception as exc:
            raise InputError(
                f"cannot decode message {info.count} ({type(exc).__name__}: {exc})",
                path=scan.source,
                topic=topic,
                hint=f"the messages do not match their schema {info.schema!r}",
            ) from None
        try:
            for sub, stamp, parent, child, pose in _samples(kind, msg):
                if frame_filter is not None and kind in _FRAME_KINDS and _frame_key(sub) != frame_filter:
                    key = (topic, sub)
                    scan.frames.setdefault(key, (parent, child))
                    scan.series.setdefault(key, None)  # remember the frame exists
                    continue
                key = (topic, sub)
                buf = scan.series.get(key)
                if buf is None:
                    buf = scan.series[key] = []
                    scan.frames[key] = (parent, child)
                buf.append((stamp, message.log_time) + pose)
        except (_MissingField, AttributeError, TypeError, ValueError) as exc:
            what = f"field {exc.args[0]!r}" if isinstance(exc, _MissingField) else f"a field ({exc})"
            raise InputError(
                f"message {info.count} lacks {what} of {info.schema}",
                path=scan.source,
                topic=topic,
                hint="the messages do not follow the schema they are registered with",
            ) from None
        scan.messages += 1


# --------------------------------------------------------------------------------------------------
# choosing


def _topics_from_summary(summary) -> dict:
    counts = summary.statistics.channel_message_counts if summary.statistics else {}
    out = {}
    for cid, ch in sorted(summary.channels.items()):
        schema = summary.schemas.get(ch.schema_id)
        t = _Topic(
            ch.topic, schema.name if schema else "", schema.encoding if schema else "", ch.message_encoding,
            counts.get(cid, 0) if summary.statistics else None,
        )  # fmt: skip
        if ch.topic in out:  # one topic, several channels
            prev = out[ch.topic]
            prev.count = None if prev.count is None or t.count is None else prev.count + t.count
        else:
            out[ch.topic] = t
    return out


def _listing(topics) -> str:
    return ", ".join(t.label() for t in topics)


def _choose_topic(topics: dict, options: ReadOptions, source: str) -> _Topic:
    pose = [t for t in topics.values() if t.kind is not None]
    if options.topic:
        want = options.topic
        t = topics.get(want) or next(
            (x for x in topics.values() if x.topic.strip("/") == want.strip("/")), None
        )
        if t is None or t.kind is None:
            # a file with no pose topic at all holds no pose data (skipped when found in a directory)
            error = InputError if pose else functools.partial(NotPoseData, reason="no pose topic")
        if t is None:
            guess = closest(want, list(topics))
            raise error(
                f"no topic {want!r}"
                + (f"; did you mean {guess!r}?" if guess else "")
                + (f"{' ' if guess else '; '}pose topics are: {_listing(pose)}" if pose else f" (the file has no pose topic; topics are: {_listing(topics.values()) or 'none'})"),
                path=source,
                hint="pass topic with one of them", param="topic",
            )
        if t.kind is None:
            raise error(
                f"topic {t.topic} carries {t.schema or 'schemaless'} messages, which hold no pose"
                + (f"; pose topics are: {_listing(pose)}" if pose else "; the file has no pose topic"),
                path=source,
                hint=f"rbgp reads {_SUPPORTED}",
            )
        return t
    if not pose:
        listing = _listing(topics.values()) if topics else "none (the file holds no messages)"
        raise NotPoseData(
            f"no pose topic found; topics are: {listing}",
            path=source,
            hint=f"rbgp reads {_SUPPORTED}",
            reason="no pose topic",
        )
    nonempty = [t for t in pose if t.count != 0]
    if len(nonempty) == 1:
        return nonempty[0]
    if not nonempty:
        raise InputError(f"the pose topics hold no messages: {_listing(pose)}", path=source)
    raise InputError(
        f"several pose topics: {_listing(nonempty)}",
        path=source,
        hint=f"choose one with topic, e.g. topic {nonempty[0].topic}", param="topic"
    )


def _select_subs(scan: _Scan, topic: _Topic, options: ReadOptions, *, select_all: bool) -> list:
    keys = [k for k in scan.series if k[0] == topic.topic]
    if topic.kind in _FRAME_KINDS and not select_all:
        frames = sorted({k[1] for k in keys}, key=str)
        counts = {k[1]: len(scan.series[k] or ()) for k in keys}
        if options.frame:
            want = _frame_key(options.frame)
            hit = [k for k in keys if _frame_key(k[1]) == want and scan.series[k]]
            if not hit:
                guess = closest(options.frame, [str(f) for f in frames])
                raise InputError(
                    f"no transforms to child frame {options.frame!r}; child frames are: "
                    + (", ".join(str(f) for f in frames) or "none")
                    + (f"; did you mean {guess!r}?" if guess else ""),
                    path=scan.source,
                    topic=topic.topic,
                    hint="pass frame with one of them", param="frame"
                )
            return hit
        if len(frames) > 1:
            raise InputError(
                "transforms to several child frames: "
                + ", ".join(f"{f} ({counts[f]})" for f in frames),
                path=scan.source,
                topic=topic.topic,
                hint=f"choose one with frame, e.g. frame {frames[0]}", param="frame"
            )
    return [k for k in keys if scan.series[k]]


def _time_source(options: ReadOptions) -> str:
    ts = (options.time_source or "header").lower()
    if ts not in ("header", "log"):
        raise InputError(f"time source {options.time_source!r} is not 'header' or 'log'")
    return ts


def _trajectory(scan: _Scan, topic: _Topic, key, time_source: str, source: str) -> Trajectory:
    rows = scan.series[key]
    stamps = np.fromiter((r[0] for r in rows), dtype=np.int64, count=len(rows))
    logs = np.fromiter((r[1] for r in rows), dtype=np.int64, count=len(rows))
    vals = np.array([r[2:] for r in rows], dtype=np.float64).reshape(-1, 7)
    sub = key[1]
    if sub is None:
        name = topic.topic
    elif isinstance(sub, int):
        name = f"{topic.topic}[{sub}]"
    elif topic.kind in ("tf", "fg_transforms") or sum(1 for k in scan.series if k[0] == topic.topic) > 1:
        name = f"{topic.topic}:{_frame_key(sub)}"
    else:
        name = topic.topic
    used = time_source
    if time_source == "header" and not np.any(stamps):
        used = "log"
        warn("all message stamps are zero; using the log time instead", path=source, topic=name)
    ns = stamps if used == "header" else logs
    order = np.argsort(ns, kind="stable")
    ns = ns[order]
    vals = vals[order]
    sec, rem = np.divmod(ns, 1_000_000_000)
    t = sec.astype(np.float64) + rem.astype(np.float64) * 1e-9
    d = np.diff(t)
    d = d[d > 0]
    parent, child = scan.frames.get(key, (None, None))
    info = {
        "format": "mcap",
        "topic": topic.topic,
        "schema": topic.schema,
        "message_encoding": topic.message_encoding,
        "time_source": used,
        "messages": int(len(rows)),
        "rate_hz": float(1.0 / np.median(d)) if len(d) else None,
        "length_unit": "m",
        "rotation": "quaternion xyzw",
    }
    if parent:
        info["frame_id"] = str(parent)
    if child:
        info["child_frame_id"] = str(child)
    if isinstance(sub, int):
        info["pose_index"] = sub
    if scan.error is not None:
        info["recovered"] = True
    return Trajectory(t=t, quat=vals[:, 3:], position=vals[:, :3], name=name, source=f"{source}:{name}", info=info)


# --------------------------------------------------------------------------------------------------
# public API


def _scan_stream(stream, source: str, options: ReadOptions, *, select_all: bool):
    """Read the messages of the wanted topics from ``stream`` (seekable: the summary's topics, then one
    topic or all pose topics; after damage or without a summary: a linear scan of every record).
    Returns (scan, topics, chosen, seekable, start): the :class:`_Scan`, {topic: :class:`_Topic`},
    the topic chosen from the summary (or None), and where the stream starts; None when ``select_all``
    finds no pose topic in the summary."""
    from mcap.exceptions import InvalidMagic
    from mcap.reader import NonSeekingReader, SeekingReader

    factories = _decoder_factories()
    corrupt = _corrupt_errors()
    chosen: _Topic | None = None
    topics: dict = {}
    scan = None
    seekable = False
    try:
        seekable = bool(stream.seekable())
    except (AttributeError, ValueError, OSError):
        seekable = False
    start = stream.tell() if seekable else 0
    if seekable:
        summary = None
        try:
            reader = SeekingReader(stream, validate_crcs=True)
            summary = reader.get_summary()
        except InvalidMagic:
            raise InputError("not an MCAP file (bad magic bytes)", path=source) from None
        except corrupt:
            summary = None
        if summary is not None:
            topics = _topics_from_summary(summary)
            if select_all:
                wanted = {t.topic for t in topics.values() if t.kind is not None}
                if not wanted:
                    return None
            else:
                chosen = _choose_topic(topics, options, source)
                wanted = {chosen.topic}
            scan = _Scan(source, options, wanted)
            _scan(reader.iter_messages(topics=sorted(wanted), log_time_order=False), scan, factories)
            if scan.error is None:
                # counts from the summary are authoritative
                for t, info in scan.topics.items():
                    if t in topics:
                        info.count = topics[t].count if topics[t].count is not None else info.count
        if scan is None or scan.error is not None:
            stream.seek(start)
            wanted = {chosen.topic} if chosen is not None else None
            scan = _Scan(source, options, wanted)
            reader = NonSeekingReader(stream, validate_crcs=True)
            _scan(reader.iter_messages(log_time_order=False), scan, factories)
    else:
        scan = _Scan(source, options, None)
        reader = NonSeekingReader(stream, validate_crcs=True)
        _scan(reader.iter_messages(log_time_order=False), scan, factories)
    if not topics or scan.error is not None:
        topics = dict(scan.topics)
        # channels that were announced but had no (readable) message
        for ch in getattr(reader, "_channels", {}).values():
            if ch.topic not in topics:
                schemas = getattr(reader, "_schemas", {})
                sc = schemas.get(ch.schema_id)
                topics[ch.topic] = _Topic(
                    ch.topic, sc.name if sc else "", sc.encoding if sc else "", ch.message_encoding, 0
                )
    return scan, topics, chosen, seekable, start


def _unreadable(scan: _Scan, topics: dict, chosen, stream, seekable: bool, start: int, source: str) -> InputError:
    """The error for a file whose damage (``scan.error``) came before any message: not an MCAP file,
    empty, cut before its first message, or no pose topic before the damage."""
    from mcap.exceptions import EndOfFile, InvalidMagic

    exc = scan.error
    if isinstance(exc, InvalidMagic):
        return InputError("not an MCAP file (bad magic bytes)", path=source)
    if not topics and isinstance(exc, (EndOfFile, struct.error)):  # a short read: cut before any record
        empty = False
        if seekable:
            stream.seek(0, 2)
            empty = stream.tell() <= start
        return InputError(
            "the file is empty"
            if empty
            else f"the MCAP file is truncated or corrupt: it ends before its first message ({type(exc).__name__})",
            path=source,
            hint="record or copy the file again",
        )
    if chosen is None and not any(t.kind for t in topics.values()):
        return InputError(
            f"no pose topic found before the damage (the file is truncated or corrupt: "
            f"{type(exc).__name__}: {exc}); topics are: {_listing(topics.values()) or 'none'}",
            path=source,
            hint="run `mcap recover` on it, or record it again",
        )
    return InputError(
        f"the MCAP file is truncated or corrupt ({type(exc).__name__}: {exc}) and no pose message "
        "could be read before the damage",
        path=source,
        hint="run `mcap recover` on it, or record it again",
    )


def _read(stream, source: str, options: ReadOptions, *, select_all: bool) -> list[Trajectory]:
    options = options or ReadOptions()
    time_source = _time_source(options)
    found = _scan_stream(stream, source, options, select_all=select_all)
    if found is None:
        return []
    scan, topics, chosen, seekable, start = found
    if scan.error is not None and scan.messages == 0:
        raise _unreadable(scan, topics, chosen, stream, seekable, start, source) from None
    if select_all:
        if not any(t.kind for t in topics.values()):
            _choose_topic(topics, replace(options, topic=None), source)  # says so: no pose topic found
        out = []
        for t in topics.values():
            if t.kind is None:
                continue
            for key in _select_subs(scan, t, options, select_all=True):
                out.append(_trajectory(scan, t, key, time_source, source))
        return out
    if chosen is None and options.topic is None:  # read without a summary (a pipe): rbgp rollout's file?
        from rbgp_cli.io.mcap_out import ROLLOUT_TOPIC_RE

        if any(ROLLOUT_TOPIC_RE.match(t.topic) for t in topics.values() if t.kind is not None):
            return _in_rollout_order([_trajectory(scan, t, key, time_source, source) for t in topics.values()
                                      if t.kind is not None for key in _select_subs(scan, t, options, select_all=True)])
    if chosen is None:
        chosen = _choose_topic(topics, options, source)
    keys = _select_subs(scan, chosen, options, select_all=False)
    if not keys:
        raise InputError("the topic holds no pose messages", path=source, topic=chosen.topic)
    out = [_trajectory(scan, chosen, key, time_source, source) for key in keys]
    if scan.error is not None:
        n = sum(len(scan.series[k]) for k in keys)
        exc = scan.error
        warn(
            f"the file is truncated or corrupt ({type(exc).__name__}: {str(exc)[:120]}); recovered {n} pose "
            "samples from before the damage",
            path=source,
            topic=chosen.topic,
        )
    return out


def _open(path):
    path = str(path)
    p = Path(path)
    if not p.exists():
        raise InputError("file not found", path=path, hint="check the path")
    if p.is_dir():
        raise InputError("is a directory, not an MCAP file", path=path, hint="pass the .mcap files inside it")
    try:
        return open(path, "rb")
    except OSError as exc:
        raise InputError(f"cannot read the file ({exc.strerror or exc})", path=path) from None


def _is_pattern(topic: str | None) -> bool:
    return bool(topic) and (topic == "all" or any(ch in topic for ch in "*?["))


def _read_matching(stream, source: str, options: ReadOptions) -> list[Trajectory]:
    """``topic="all"`` or a glob (``'/shoe/*'``): every matching pose topic, one demonstration each."""
    import fnmatch

    pattern = options.topic
    trajs = _read(stream, source, replace(options, topic=None), select_all=True)
    if pattern != "all":
        trajs = [t for t in trajs if fnmatch.fnmatchcase(t.info.get("topic", ""), pattern)
                 or fnmatch.fnmatchcase(t.info.get("topic", "").strip("/"), pattern.strip("/"))]
    if not trajs:
        raise InputError(f"no pose topic matches {pattern!r}", path=source,
                         hint="list the topics with rbgp inspect, then pass topic NAME or a pattern like '/body/*'",
                         param="topic")
    return trajs


def read(path, options: ReadOptions | None = None) -> list[Trajectory]:
    """Read the pose topic of an MCAP file (``options.topic``; automatic when there is one; a file
    written by ``rbgp rollout``: every generated trajectory, without the bands).

    ``options.topic`` may also be ``all`` or a glob pattern (``'/shoe/*'``): then every matching pose
    topic becomes one demonstration (e.g. one topic per trial). Returns raw trajectories (seconds,
    metres, quaternions x, y, z, w), one per topic / child frame / pose index, sorted by time.
    """
    options = options or ReadOptions()
    with _open(path) as fh:
        if _is_pattern(options.topic):
            return _read_matching(fh, str(path), options)
        if options.topic is None and _has_rollout_topics(fh):
            return _read_rollouts(fh, str(path), options)
        return _read(fh, str(path), options, select_all=False)


def _has_rollout_topics(fh) -> bool:
    """True when the summary of a seekable MCAP lists topics rbgp rollout writes
    (:data:`rbgp_cli.io.mcap_out.ROLLOUT_TOPIC_RE`); the stream is left where it was."""
    from mcap.reader import SeekingReader

    from rbgp_cli.io.mcap_out import ROLLOUT_TOPIC_RE

    try:
        if not fh.seekable():
            return False
        start = fh.tell()
    except (AttributeError, ValueError, OSError):
        return False
    try:
        summary = SeekingReader(fh).get_summary()
    except _corrupt_errors():
        summary = None
    finally:
        fh.seek(start)
    return summary is not None and any(ROLLOUT_TOPIC_RE.match(ch.topic) for ch in summary.channels.values())


def _read_rollouts(fh, source: str, options: ReadOptions) -> list[Trajectory]:
    """Every generated trajectory of a file rbgp rollout wrote (its mean rollouts, then their samples,
    the order of rollout's CSV), not the bands: one trajectory each."""
    return _in_rollout_order(_read(fh, source, replace(options, topic=None), select_all=True))


def _in_rollout_order(trajs) -> list[Trajectory]:
    """The trajectories of generated topics among ``trajs``, mean rollouts first, then their samples."""
    from rbgp_cli.io.mcap_out import ROLLOUT_TOPIC_RE

    keyed = []
    for tr in trajs:
        m = ROLLOUT_TOPIC_RE.match(tr.info.get("topic", ""))
        if m:
            keyed.append(((m.group(2) is not None, int(m.group(1)), int(m.group(2) or 0)), tr))
    return [tr for _, tr in sorted(keyed, key=lambda kv: kv[0])]


def read_stream(stream, options: ReadOptions | None = None, source: str = "-") -> list[Trajectory]:
    """Like :func:`read` for an open binary stream (stdin, a pipe: read once, front to back)."""
    options = options or ReadOptions()
    if _is_pattern(options.topic):
        return _read_matching(stream, source, options)
    if options.topic is None and _has_rollout_topics(stream):  # stdin redirected from a file rbgp rollout wrote
        return _read_rollouts(stream, source, options)
    return _read(stream, source, options, select_all=False)


def read_all(path, options: ReadOptions | None = None) -> list[Trajectory]:
    """Every pose topic of the file, every child frame and pose index (for ``rbgp inspect``)."""
    with _open(path) as fh:
        return _read(fh, str(path), options or ReadOptions(), select_all=True)


def describe(path, options: ReadOptions | None = None) -> dict:
    """Topics of an MCAP file without decoding messages (from the summary when the file has one).

    Returns plain data: ``{"profile", "library", "summary": bool, "messages", "start_s", "end_s",
    "topics": [{"topic", "schema", "schema_encoding", "message_encoding", "messages", "pose"}],
    "damaged": str | None}``.
    """
    from mcap.exceptions import InvalidMagic
    from mcap.reader import NonSeekingReader, SeekingReader

    corrupt = _corrupt_errors()
    out = {"profile": None, "library": None, "summary": False, "messages": None, "start_s": None,
           "end_s": None, "topics": [], "damaged": None}  # fmt: skip
    with _open(path) as fh:
        topics = None
        try:
            reader = SeekingReader(fh)
            header = reader.get_header()
            out["profile"], out["library"] = header.profile, header.library
            summary = reader.get_summary()
            if summary is not None:
                topics = _topics_from_summary(summary)
                out["summary"] = True
                st = summary.statistics
                if st is not None:
                    out["messages"] = int(st.message_count)
                    if st.message_count:
                        out["start_s"] = st.message_start_time / 1e9
                        out["end_s"] = st.message_end_time / 1e9
        except InvalidMagic:
            raise InputError("not an MCAP file (bad magic bytes)", path=str(path)) from None
        except corrupt as exc:
            out["damaged"] = f"{type(exc).__name__}: {exc}"
        if topics is None:
            fh.seek(0)
            reader = NonSeekingReader(fh)
            topics = {}
            first = last = None
            total = 0
            try:
                for schema, channel, message in reader.iter_messages(log_time_order=False):
                    t = topics.get(channel.topic)
                    if t is None:
                        t = topics[channel.topic] = _Topic(
                            channel.topic, schema.name if schema else "", schema.encoding if schema else "",
                            channel.message_encoding, 0,
                        )  # fmt: skip
                    t.count += 1
                    total += 1
                    lt = message.log_time
                    first = lt if first is None else min(first, lt)
                    last = lt if last is None else max(last, lt)
            except corrupt as exc:
                out["damaged"] = f"{type(exc).__name__}: {exc}"
            out["messages"] = total
            out["start_s"] = None if first is None else first / 1e9
            out["end_s"] = None if last is None else last / 1e9
    out["topics"] = [
        {
            "topic": t.topic,
            "schema": t.schema,
            "schema_encoding": t.schema_encoding,
            "message_encoding": t.message_encoding,
            "messages": t.count,
            "pose": t.kind is not None,
        }
        for t in topics.values()
    ]
    return out


def _inspect_read(path, options: ReadOptions | None = None) -> list[Trajectory]:
    """What ``rbgp inspect`` reads: the topic ``topic`` names, else every pose topic."""
    options = options or ReadOptions()
    return read(path, options) if options.topic else read_all(path, options)


def _topic_needs(desc: dict, options: ReadOptions) -> list[str]:
    """``topic`` when the file holds several pose topics with messages and the options name none."""
    pose = [t["topic"] for t in desc.get("topics", []) if t.get("pose") and t.get("messages") != 0]
    if options.topic or len(pose) < 2:
        return []
    return [f"topic NAME, or all / a pattern for one demonstration per topic ({len(pose)} pose topics)"]


def describe_rows(desc: dict) -> list[str]:
    """The text rows of ``rbgp inspect`` for :func:`describe`'s result."""
    from rbgp_cli.io.inspect import text_row as _row

    lines = [_row("profile", desc.get("profile") or "-"), _row("library", desc.get("library") or "-"),
             _row("messages", f"{desc.get('messages') if desc.get('messages') is not None else '?'}"
                              + ("" if desc.get("summary") else " (no summary: scanned)"))]
    if desc.get("damaged"):
        lines.append(_row("damaged", desc["damaged"]))
    lines.append("  topics:")
    for t in desc.get("topics", []):
        mark = "pose" if t.get("pose") else "    "
        n = t["messages"] if t["messages"] is not None else "?"
        lines.append(f"    {mark} {t['topic']:<36} {t['schema'] or '(no schema)'} ({t['message_encoding']}) {n} messages")
    if not any(t.get("pose") for t in desc.get("topics", [])):  # what train would say: nothing here to train on
        lines.append(_row("pose data", "none: no topic of a pose message type (train skips this file, or refuses it "
                                       "alone)"))
    return lines


FORMAT = Format(
    name="mcap", title="MCAP", detect=detect, read=read, describe=describe, describe_rows=describe_rows,
    skip_reason=_skip_reason, read_stream=read_stream, read_all=_inspect_read, needs=_topic_needs,
    suffix=".mcap", binary=True,
    honours=("topic", "frame"),
)
