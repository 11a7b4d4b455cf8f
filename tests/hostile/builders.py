"""Small hostile input files, generated into a test's tmp folder from one known motion.

Every builder starts from :func:`smooth_motion` (seconds, metres, unit quaternions x, y, z, w with
continuous sign), so a repaired file can be compared with the clean file it came from: the model
trained on "the file with NaN rows" must equal the model trained on "the file without those rows".

Nothing here is committed as a binary: the tests write every fixture (CSV, QTM TSV, Motive CSV,
MCAP, model files) into ``tmp_path`` and mutate it there.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from rbgp_cli.dynamics.trajectory import Trajectory

RATE = 100.0  # Hz
N = 120  # samples of one demonstration
COLUMNS = ("t", "x", "y", "z", "qx", "qy", "qz", "qw")
TOPIC = "/shoe/pose"
#: Cheap but real training, as the CLI tests use it.
# pose-only models (no time input, zero prior mean): these tests feed bare poses to predict and rollout
FAST = ("--max-points", "40", "--subsample", "0.3", "--restarts", "1", "--share-hyperparameters", "--time-input", "none",
        "--prior", "none")


def smooth_motion(n: int = N, rate: float = RATE, seed: int = 0, name: str = "demo") -> Trajectory:
    """A smooth hand-over-like motion: angular and linear velocities that change along the way
    (a GP has something to learn), positions 0.1–1 m from the origin, rotations up to ~1.6 rad."""
    t = np.arange(n) / rate
    s = t / t[-1]
    rv = np.stack([0.4 * np.sin(2.5 * s + seed), 0.3 * np.cos(1.7 * s) - 0.3, 1.2 * s**2 + 0.1 * seed], axis=1)
    q = Rotation.from_rotvec(rv).as_quat()  # angles < π: w > 0 throughout, so no sign flips
    p = np.stack([0.3 + 0.2 * np.sin(2 * s), 0.1 * np.cos(3 * s + seed), 0.8 + 0.15 * s**2], axis=1)
    return Trajectory(t=t, quat=q, position=p, name=name)


def table(traj: Trajectory) -> np.ndarray:
    """Rows ``t, x, y, z, qx, qy, qz, qw`` (float array, shape (N, 8))."""
    return np.concatenate([traj.t[:, None], traj.position, traj.quat], axis=1)


def cell(v) -> str:
    if isinstance(v, str):
        return v
    v = float(v)
    return "nan" if v != v else repr(v)


def write_table(path, rows, header=COLUMNS, delimiter: str = ",", decimal: str = ".", comments=()) -> Path:
    """Write a header line and rows (arrays or lists of floats/str; floats with ``repr``)."""
    path = Path(path)
    lines = [f"# {c}" for c in comments]
    lines.append(delimiter.join(header))
    for row in rows:
        cells = [cell(v) for v in row]
        if decimal != ".":
            cells = [c.replace(".", decimal) for c in cells]
        lines.append(delimiter.join(cells))
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def write_csv(path, traj: Trajectory | None = None, **kwargs) -> Path:
    """The generic CSV ``t,x,y,z,qx,qy,qz,qw`` of ``traj`` (default :func:`smooth_motion`)."""
    return write_table(path, table(traj or smooth_motion()), **kwargs)


# ---------------------------------------------------------------------------------------------- vendor
def write_qtm(path, traj: Trajectory | None = None, **kwargs) -> Path:
    """QTM 6D TSV (mm, Rot[] column-major) of one body named ``shoe``."""
    from rbgp_cli.io.export import write_qtm_tsv

    traj = traj or smooth_motion()
    write_qtm_tsv([traj.with_(name="shoe")], path, **kwargs)
    return Path(path)


def write_motive(path, traj: Trajectory | None = None, **kwargs) -> Path:
    """Motive CSV 1.23 (quaternion XYZW, metres) of one rigid body named ``shoe``."""
    from rbgp_cli.io.export import write_motive_csv

    traj = traj or smooth_motion()
    write_motive_csv([traj.with_(name="shoe")], path, **kwargs)
    return Path(path)


# ---------------------------------------------------------------------------------------------- MCAP
def _msgdefs():
    from tests.io.mcap_fixtures import MSGDEFS

    return MSGDEFS


def _stamp(t: float) -> dict:
    ns = int(round(t * 1e9))
    return {"sec": ns // 1_000_000_000, "nanosec": ns % 1_000_000_000}


def _pose_stamped(t, p, q) -> dict:
    return {
        "header": {"stamp": _stamp(t), "frame_id": "world"},
        "pose": {
            "position": {"x": float(p[0]), "y": float(p[1]), "z": float(p[2])},
            "orientation": {"x": float(q[0]), "y": float(q[1]), "z": float(q[2]), "w": float(q[3])},
        },
    }


#: MCAP stamps start here (seconds), so times are not at the epoch.
MCAP_T0 = 1.0


def write_mcap(path, traj: Trajectory | None = None, *, topic: str = TOPIC, chunk_size: int = 1024,
               compression: str = "zstd", finish: bool = True, extra_strings: str | None = None) -> Path:
    """ROS 2 ``geometry_msgs/msg/PoseStamped`` messages (CDR) of ``traj`` on ``topic``, stamps
    ``MCAP_T0 + t``; small chunks (1 KiB) so that a cut or a corrupt chunk leaves some intact ones.
    ``extra_strings`` adds a ``std_msgs/msg/String`` topic of that name."""
    from mcap.writer import CompressionType
    from mcap_ros2.writer import Writer

    traj = traj or smooth_motion()
    defs = _msgdefs()
    comp = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}[compression]
    fh = open(path, "wb")
    w = Writer(fh, chunk_size=chunk_size, compression=comp)
    schema = w.register_msgdef("geometry_msgs/msg/PoseStamped", defs["geometry_msgs/msg/PoseStamped"])
    other = w.register_msgdef("std_msgs/msg/String", defs["std_msgs/msg/String"]) if extra_strings else None
    for k, (t, p, q) in enumerate(zip(traj.t, traj.position, traj.quat)):
        ns = int(round((MCAP_T0 + t) * 1e9))
        w.write_message(topic, schema, _pose_stamped(MCAP_T0 + t, p, q), log_time=ns, publish_time=ns, sequence=k)
        if other is not None:
            w.write_message(extra_strings, other, {"data": f"frame {k}"}, log_time=ns, publish_time=ns)
    if finish:
        w.finish()
    fh.close()
    return Path(path)


def write_mcap_strings(path, topic: str = "/chatter", n: int = 10) -> Path:
    """Only a ``std_msgs/msg/String`` topic: no pose anywhere."""
    from mcap_ros2.writer import Writer

    defs = _msgdefs()
    with open(path, "wb") as fh:
        w = Writer(fh)
        schema = w.register_msgdef("std_msgs/msg/String", defs["std_msgs/msg/String"])
        for k in range(n):
            ns = int((MCAP_T0 + k / RATE) * 1e9)
            w.write_message(topic, schema, {"data": f"hello {k}"}, log_time=ns, publish_time=ns)
        w.finish()
    return Path(path)


def write_mcap_json_tf(path, traj: Trajectory | None = None, *, schema_encoding: str = "ros2msg",
                       topic: str = "/tf", child: str = "shoe") -> Path:
    """``tf2_msgs/msg/TFMessage`` in ROS layout but **JSON-encoded**, registered under the ROS schema
    name with a ``ros2msg`` definition (what some bridges write) or a ``jsonschema`` one."""
    from mcap.writer import Writer

    traj = traj or smooth_motion()
    defs = _msgdefs()
    data = defs["tf2_msgs/msg/TFMessage"].encode() if schema_encoding == "ros2msg" else json.dumps(
        {"title": "tf2_msgs/msg/TFMessage", "type": "object"}).encode()
    with open(path, "wb") as fh:
        w = Writer(fh)
        w.start(profile="", library="rbgp-hostile-tests")
        sid = w.register_schema("tf2_msgs/msg/TFMessage", schema_encoding, data)
        cid = w.register_channel(topic, "json", sid)
        for t, p, q in zip(traj.t, traj.position, traj.quat):
            ns = int(round((MCAP_T0 + t) * 1e9))
            msg = {"transforms": [{
                "header": {"stamp": _stamp(MCAP_T0 + t), "frame_id": "world"},
                "child_frame_id": child,
                "transform": {
                    "translation": {"x": float(p[0]), "y": float(p[1]), "z": float(p[2])},
                    "rotation": {"x": float(q[0]), "y": float(q[1]), "z": float(q[2]), "w": float(q[3])},
                },
            }]}
            w.add_message(cid, log_time=ns, data=json.dumps(msg).encode(), publish_time=ns)
        w.finish()
    return Path(path)


def chunk_data_offsets(path) -> list[int]:
    """File offsets of each chunk's (compressed) data, from the summary's chunk indexes."""
    from tests.io.mcap_fixtures import chunk_data_offsets as offsets

    return offsets(path)


def first_chunk_index_channel_offset(data: bytes) -> int:
    """Offset of the first channel id (u16) in the first ChunkIndex record of the summary section
    (found from the footer: opcode, length, summary_start u64, summary_offset_start u64, crc u32)."""
    import struct

    footer = len(data) - 8 - 29
    assert data[footer] == 0x02, "no footer"
    (summary_start,) = struct.unpack_from("<Q", data, footer + 9)
    off = summary_start
    while off < footer:
        opcode, length = data[off], struct.unpack_from("<Q", data, off + 1)[0]
        if opcode == 0x08:  # ChunkIndex: 4 × u64 times/offsets, then the map's byte length (u32)
            return off + 9 + 32 + 4
        off += 9 + length
    raise ValueError("no chunk index")


def messages_in_first_chunks(path, k: int) -> int:
    """How many messages the first ``k`` chunks (in file order) of an intact MCAP file hold."""
    from mcap.reader import make_reader

    with open(path, "rb") as fh:
        reader = make_reader(fh)
        chunks = sorted(reader.get_summary().chunk_indexes, key=lambda c: c.chunk_start_offset)
        end = chunks[k - 1].message_end_time
        return sum(1 for _, _, m in reader.iter_messages(log_time_order=False) if m.log_time <= end)


# ---------------------------------------------------------------------------------------------- models
def write_model_npz(path, header: dict, arrays: dict, *, checksums: bool = True, header_checksum: bool | None = None,
                    raw_header: bytes | None = None) -> Path:
    """An rbgp model file with the given header and arrays; ``checksums`` recomputes the header's
    array checksums and (``header_checksum``, by default as ``checksums``) the header's own, so only
    what the test changed on purpose is wrong; ``header_checksum=False`` keeps the header's stored
    checksum entry as it is (what a hand edit does). ``raw_header``: these bytes as the header instead."""
    from rbgp_cli.io.model_store import array_sha256, header_sha256

    header = dict(header)
    if checksums:
        old = header.get("checksums") if isinstance(header.get("checksums"), dict) else {}
        header["checksums"] = {k: array_sha256(np.asarray(v)) for k, v in arrays.items()}
        if "header" in old:
            header["checksums"]["header"] = old["header"]
    if checksums if header_checksum is None else header_checksum:
        header["checksums"] = {**header.get("checksums", {}), "header": header_sha256(header)}
    raw = json.dumps(header, sort_keys=True, allow_nan=True).encode("utf-8") if raw_header is None else raw_header
    with open(path, "wb") as fh:
        np.savez(fh, header=np.frombuffer(raw, dtype=np.uint8), **arrays)
    return Path(path)


def as_old_version(header: dict, version: int = 2) -> dict:
    """The header as rbgp wrote it before the header checksum (format versions 1–3): no
    ``checksums.header`` and, for an exact GP, no ``gp`` entry; version 1 also lacks velocity, time
    input and prior (only valid for a model without them)."""
    header = json.loads(json.dumps(header))
    header["version"] = version
    header["checksums"].pop("header", None)
    if (header.get("gp") or {}).get("type") != "sparse":
        header.pop("gp", None)
    if version == 1:
        for key in ("velocity", "time_input", "prior"):
            header.pop(key, None)
    return header


class _RepeatingDeflate:
    """A deflate compressor for :func:`write_zip_bomb`: after the second identical all-zero chunk it
    returns the same compressed block without compressing again (deflate's output for a chunk of
    zeros after zeros, with a sync flush, does not change), so a 2 GB member takes ~1 s to write."""

    def __init__(self, zero_chunk: bytes):
        import zlib

        self.zero, self.c, self.prev, self.block = zero_chunk, zlib.compressobj(9, zlib.DEFLATED, -15), None, None

    def compress(self, data):
        import zlib

        if self.block is not None and data is self.zero:
            return self.block
        out = self.c.compress(data) + self.c.flush(zlib.Z_SYNC_FLUSH)
        if data is self.zero:
            if out == self.prev:
                self.block = out
            self.prev = out
        return out

    def flush(self):
        return self.c.flush()


def write_zip_bomb(path, header: dict, arrays: dict, *, member: str = "X", shape=None, data_bytes: int | None = None,
                   chunk: int = 1 << 24) -> Path:
    """A model file whose ``member`` array is replaced by a float64 .npy of ``shape`` (default: the
    array's own) whose data are ``data_bytes`` zero bytes (default: as many as the shape needs),
    deflated: ~1000:1, so a 2 GB array takes ~2 MB on disk. ``data_bytes`` smaller than the shape
    makes a file that declares more than it holds. The other members and the header are as given."""
    import zipfile

    shape = tuple(np.asarray(arrays[member]).shape if shape is None else shape)
    nbytes = int(np.prod(shape, dtype=object)) * 8 if data_bytes is None else int(data_bytes)
    raw = json.dumps(header, sort_keys=True, allow_nan=True).encode("utf-8")
    zero = bytes(chunk)
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        members = {"header": np.frombuffer(raw, dtype=np.uint8), **{k: v for k, v in arrays.items() if k != member}}
        for name, a in members.items():
            with zf.open(f"{name}.npy", "w", force_zip64=True) as fh:
                np.lib.format.write_array(fh, np.asarray(a), allow_pickle=False)
        fh = zf.open(f"{member}.npy", "w", force_zip64=True)
        fh._compressor = _RepeatingDeflate(zero)
        np.lib.format.write_array_header_1_0(fh, {"descr": "<f8", "fortran_order": False, "shape": shape})
        left = nbytes
        while left > 0:
            fh.write(zero if left >= chunk else bytes(left))
            left -= chunk
        fh.close()
    return Path(path)


def read_model_npz(path_or_bytes) -> tuple[dict, dict]:
    """(header dict, {name: array}) of a model file (a path or its bytes), read without rbgp's checks."""
    import io

    src = io.BytesIO(path_or_bytes) if isinstance(path_or_bytes, bytes) else path_or_bytes
    with np.load(src, allow_pickle=False) as z:
        header = json.loads(z["header"].tobytes().decode("utf-8"))
        arrays = {k: z[k] for k in z.files if k != "header"}
    return header, arrays


def zip_central_entry(data: bytes, name: str) -> int:
    """Offset of the central-directory header (``PK\\1\\2``) of member ``name`` in zip bytes; its
    general-purpose flags are at +8, the compression method at +10."""
    off = data.find(b"PK\x01\x02")
    while off >= 0:
        n = int.from_bytes(data[off + 28:off + 30], "little")
        if data[off + 46:off + 46 + n] == name.encode():
            return off
        off = data.find(b"PK\x01\x02", off + 4)
    raise KeyError(name)


def mutate(data: bytes, *, flip=(), delete=None, insert=None, truncate=None) -> bytes:
    """Byte surgery: flip bits ``[(offset, bit)]``, delete ``(start, stop)``, insert ``(offset, bytes)``,
    truncate to ``truncate`` bytes."""
    d = bytearray(data)
    for off, bit in flip:
        d[off] ^= 1 << bit
    if delete is not None:
        del d[delete[0]:delete[1]]
    if insert is not None:
        d[insert[0]:insert[0]] = insert[1]
    if truncate is not None:
        del d[truncate:]
    return bytes(d)
