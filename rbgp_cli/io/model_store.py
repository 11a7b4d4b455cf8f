"""Model files: one ``.npz`` (zip) of plain arrays plus a JSON header. Never unpickled, no code run.

Layout (format ``rbgp-model``, version :data:`FORMAT_VERSION`):

* ``header``: UTF-8 JSON as a uint8 array — format, version, rbgp version, creation time (UTC),
  representation, kernel, per-output hyperparameters and fit diagnostics, shared mode, time step,
  training summary, provenance (input names and SHA-256, options), and the SHA-256 of every array.
* ``X`` (n, d) training inputs, ``Y`` (n, L) outputs, ``y_scale`` (L,), ``starts`` (D, 7),
  ``durations`` (D,); with a mean-path prior also ``prior_s`` (S,), ``prior_quat`` (S, 4),
  ``prior_position`` (S, 3), ``prior_velocity`` (S − 1, 6).
* Version 2 adds to the header how velocities were estimated (``velocity``), the time input
  (``time_input``: null, "seconds" or "phase") and the prior mean (``prior``: null or kind, gain and
  the goal pose). Version 1 files load as models without them (zero mean, no time input).
* Version 3: a sparse GP (:mod:`rbgp_cli.gp.sparse`; header ``"gp": {"type": "sparse", "inducing": M}``)
  also holds ``Z`` (M, d) inducing inputs and, per hyperparameter set g (one per output, or one shared),
  the posterior's factors ``Lm`` (G, M, M), ``LB`` (G, M, M) and ``c`` (M, L) (the columns of set g's
  outputs); loading checks them against k(Z, Z) instead of refactorising all n points.
* Version 4: ``checksums.header`` is the SHA-256 of the header's :func:`canonical_json` without that
  entry, and ``gp`` is always present (``{"type": "exact"}`` or the sparse one). Versions 1–3 have
  no header checksum and still load (a header checksum is verified wherever present; a file of
  version 4 or later without one is refused).
* Version 5: a mean-path prior trained on forward differences says
  ``"feedforward": "secant"`` (its feed-forward is the path's displacement over one step,
  :func:`rbgp_cli.dynamics.model.path_secant`); without it (every earlier file) the tangent, as that
  model was trained. An rbgp that reads only version 4 refuses these files instead of rolling them
  out with the other feed-forward.
* Version 6: the deviation process says how much its draws are widened
  (``variation.band_scale``: ``rotation`` and ``position`` factors ≥ 1,
  :func:`rbgp_cli.dynamics.variation.band_scale`); files without it sample with factors 1, as they were
  trained. An rbgp that reads only version 5 refuses these files instead of sampling narrower bands.
* Version 7: a start-conditioned path prior whose pull follows the
  demonstrations' convergence says ``"gain_profile": true`` and holds ``prior_gain_profile`` (S, 6), the
  gain per phase and coordinate (:func:`rbgp_cli.dynamics.variation.pull_profile`); without it the
  pull is ``gain`` throughout, as such a model was trained. An rbgp that reads only version 6
  refuses these files instead of rolling them out with the constant pull.
* Version 8: the path distribution that goals, via-points and a motion's seen
  beginning condition (:class:`rbgp_cli.dynamics.paths.PathDistribution`): header ``paths`` (demos,
  steps, smooth, length, seen_tolerance, band_scale) and arrays ``paths_s`` (S,), ``paths_quat`` (S, 4),
  ``paths_position`` (S, 3), ``paths_deviations`` (D, S, 6), ``paths_log_durations`` (D,). Optional:
  files without it load, and refuse a goal or a seen beginning with a message to retrain. Optional in
  ``paths`` (issue 37): ``seen_band_scale``, and ``duration_smooth`` / ``duration_tolerance`` (a motion under
  way's duration weights; files without them weigh durations with ``smooth`` and ``seen_tolerance``) or
  ``duration_sigma`` (the weights' tolerance in rad and m, in place of ``duration_tolerance``; fewer than ten
  demonstrations), ``duration_evidence`` (the seen poses' evidence weight λ in the duration's weights; files
  without it weigh with λ = 1, as before), ``duration_statistic`` ("mode": the duration's point estimate is its
  weights' mode, chosen on the left-out beginnings; files without it take the median, as before), and
  ``rest_smooth`` / ``rest_tolerance`` (the conditioning of its rest, chosen on the left-out final pose; files
  without them condition with ``smooth`` and ``seen_tolerance``, as before) and ``rest_duration_tolerance`` (ln D's
  tolerance there where it is freed; files without it condition on ln D exactly, as before) and
  ``rest_near_tolerance`` (the tolerance of the seen pose one grid step before the last there, which with the last
  says where the motion is heading; files without it add no such pose, as before), and ``seen_band_scales`` ({"fractions",
  "rotation", "position"}: the bands' factors per seen fraction; files without them draw with ``seen_band_scale``
  at every fraction, as before), ``seen_end_band_scales`` (the same form: the end pose's band's own factors, at the
  fractions and 0.95; files without them use ``seen_band_scales``, as before), and ``seen_surprise`` ({"fractions", "reference"}: the left-out seen parts' median
  surprise, which a seen part's bands widen against; files without it widen nothing, as before; an rbgp older than these fields
  refuses a file that has them with its schema's "unknown field" error).
* Version 9 (what this rbgp writes): the deviation process says how much its covariance between
  coordinates is shrunk (``variation.shrinkage``: α in [0, 1],
  :func:`rbgp_cli.dynamics.variation.shrinkage`), which its draws follow; files without it draw with
  α = 0, as they were trained. An rbgp that reads only version 8 refuses these files instead of
  drawing bands of the wrong shape. Optional in version 9: a start-conditioned prior whose map's shift is
  bounded by the demonstrations' reach says ``"start_reach": true`` and holds ``prior_start_reach`` (S, 2),
  the largest rotation (rad) and position (m) deviation per phase (:func:`rbgp_cli.dynamics.variation.start_reach`);
  files without it roll out with the map unbounded, as they were trained, and an rbgp older than the field
  refuses a file that has it with its schema's "unknown field" error. Optional in version 9 as well:
  ``variation.start_surprise`` ({"quat", "position", "mean", "covariance", "reference", "parts"}: the
  demonstrations' start distribution, the left-out starts' upper quartile of surprise, which a start's bands widen
  against, and which part of the band (rotation, position) widens,
  :meth:`rbgp_cli.dynamics.variation.Variation.start_widening`); files without it widen nothing, as before. Since
  the eighteenth pass it is written from 5 demonstrations on with ``"beyond"`` (ρ_max, the largest left-out start's
  surprise, beyond which a start's bands widen in both parts) and ``"reference"`` null where the quartile's widening
  is not kept; files without ``beyond`` widen only as before.

Loading reads the zip itself (never unpickling: .npy members of plain numbers only) with limits
checked before anything large is decompressed: a member may decompress to at most
:data:`MAX_RATIO` × its compressed size + :data:`RATIO_SLACK` (zip bombs reach ~1000×), its .npy
header's shape × itemsize must equal the member's size (a declared 10¹⁰ rows is refused before any
allocation), the header JSON is at most :data:`MAX_HEADER_BYTES`, nested at most
:data:`MAX_HEADER_DEPTH` deep (counted without recursion) with numbers of at most 40 digits. Then
the format name, the header checksum, the version, every array's checksum, every header field
(:mod:`rbgp_cli.io.model_schema`) and every array against the header; finally the GP is rebuilt
(Cholesky re-run). Any failure is an :class:`InputError` naming the file and what to do. Files are
written atomically (temporary name, then rename).
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import io
import json
import math
import os
import re
import tokenize
import zipfile
import zlib

import numpy as np

from rbgp_cli import __version__
from rbgp_cli.errors import InputError, RbgpError
from rbgp_cli.io.atomic import atomic_open

__all__ = ["FORMAT", "FORMAT_VERSION", "save_model", "load_model", "read_header", "file_sha256", "array_sha256",
           "header_sha256", "canonical_json"]

FORMAT = "rbgp-model"
#: The version this rbgp writes (4: the header checksummed, ``gp`` always present); it reads 1–4.
FORMAT_VERSION = 9
#: Limits checked before anything large is read (a model of 10⁶ training points is ~100 MB).
MAX_HEADER_BYTES = 16 << 20
MAX_HEADER_DEPTH = 32
MAX_ARRAY_BYTES = 8 << 30
#: an array may decompress to at most MAX_RATIO × its compressed size + RATIO_SLACK (float data
#: compress ~1.1–3×; deflate's limit, reached by zip bombs of zeros, is ~1030×)
MAX_RATIO = 20
RATIO_SLACK = 8 << 20
MAX_MEMBERS = 64
#: digits of a JSON number (a float's repr has at most 17; Python refuses ints beyond 4300)
_MAX_DIGITS = 40
_ARRAYS = ("X", "Y", "y_scale", "starts", "durations")
#: Arrays of a sparse GP (version 3).
_SPARSE_ARRAYS = ("Z", "Lm", "LB", "c")
#: Arrays of the demonstrations' deviation process (present only when the model has one).
_VARIATION_ARRAYS = ("variation_s", "variation_residuals")
_PATHS_ARRAYS = ("paths_s", "paths_quat", "paths_position", "paths_deviations", "paths_log_durations")
#: Arrays of the mean-path prior (present only when the model has one).
_PRIOR_ARRAYS = {"prior_s": "s", "prior_quat": "quat", "prior_position": "position", "prior_velocity": "velocity"}
#: Arrays of a start-conditioned mean-path prior (header ``prior.start == "conditioned"``).
_START_ARRAYS = {"prior_start_mean": "start_mean", "prior_start_beta": "start_beta"}
#: The pull's gain per phase and coordinate (header ``prior.gain_profile``).
_PROFILE_ARRAY = ("prior_gain_profile", "gain_profile")
#: The demonstrations' reach per phase that bounds the start map's shift (header ``prior.start_reach``).
_REACH_ARRAY = ("prior_start_reach", "start_reach")


def array_sha256(a: np.ndarray) -> str:
    """SHA-256 of an array's dtype, shape and little-endian C-ordered bytes."""
    a = np.ascontiguousarray(a)
    h = hashlib.sha256()
    h.update(str(a.dtype.newbyteorder("<") if a.dtype.byteorder == ">" else a.dtype).encode())
    h.update(str(a.shape).encode())
    h.update(a.astype(a.dtype.newbyteorder("<"), copy=False).tobytes())
    return h.hexdigest()


def file_sha256(path) -> str:
    """SHA-256 of a file's bytes (for provenance)."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _jsonable(x):
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, (np.floating,)):
        return float(x)
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, (np.bool_,)):
        return bool(x)
    return x


def save_model(model, path) -> dict:
    """Write a :class:`~rbgp_cli.dynamics.model.MotionModel` to ``path`` atomically; returns the header."""
    gp = model.gp
    arrays = {
        "X": np.ascontiguousarray(gp.X, dtype=np.float64),
        "Y": np.ascontiguousarray(gp.Y, dtype=np.float64),
        "y_scale": np.ascontiguousarray(gp.y_scale, dtype=np.float64),
        "starts": np.ascontiguousarray(model.starts, dtype=np.float64).reshape(-1, 7),
        "durations": np.ascontiguousarray(model.durations, dtype=np.float64).reshape(-1),
    }
    mean = model.mean
    prior = None
    if mean:
        prior = {"kind": mean["kind"], "gain": float(mean["gain"])}
        if mean["kind"] == "goal":
            prior["goal"] = [float(v) for v in mean["goal"]]
        else:
            for name, key in _PRIOR_ARRAYS.items():
                arrays[name] = np.ascontiguousarray(mean[key], dtype=np.float64)
            if mean.get("feedforward") == "secant":  # the path's secant over a step (dynamics.model.path_secant)
                prior["feedforward"] = "secant"
            if "start_beta" in mean:  # the start-conditioned path (dynamics.model.PathReference)
                prior["start"] = "conditioned"
                for name, key in _START_ARRAYS.items():
                    arrays[name] = np.ascontiguousarray(mean[key], dtype=np.float64)
                if mean.get("gain_profile") is not None:  # the pull's profile (dynamics.variation.pull_profile)
                    prior["gain_profile"] = True
                    arrays[_PROFILE_ARRAY[0]] = np.ascontiguousarray(mean[_PROFILE_ARRAY[1]], dtype=np.float64)
                if mean.get("start_reach") is not None:  # the map's bound (dynamics.variation.start_reach)
                    prior["start_reach"] = True
                    arrays[_REACH_ARRAY[0]] = np.ascontiguousarray(mean[_REACH_ARRAY[1]], dtype=np.float64)
    variation = getattr(model, "variation", None)
    if variation is not None:
        arrays.update(variation.to_arrays())
    paths = getattr(model, "paths", None)
    if paths is not None:
        arrays.update(paths.to_arrays())
    sparse = bool(getattr(gp, "sparse", False))
    if sparse:
        arrays["Z"] = np.ascontiguousarray(gp.Z, dtype=np.float64)
        arrays["Lm"] = np.ascontiguousarray(np.stack([st[0] for st in gp.stats]), dtype=np.float64)
        arrays["LB"] = np.ascontiguousarray(np.stack([st[1] for st in gp.stats]), dtype=np.float64)
        arrays["c"] = np.ascontiguousarray(np.concatenate([st[2] for st in gp.stats], axis=1), dtype=np.float64)
    header = {
        "format": FORMAT,
        "version": FORMAT_VERSION,
        "rbgp_version": __version__,
        "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "representation": model.representation.to_dict(),
        "kernel": gp.kernel.to_dict(),
        "shared": bool(gp.shared),
        "fits": [f.to_dict() for f in gp.fits],
        "dt": float(model.dt),
        "velocity": model.velocity.to_dict(),
        "time_input": model.time_input,
        "prior": prior,
        "input_names": list(model.representation.input_names),
        "output_names": list(model.representation.output_names),
        "summary": _jsonable(model.summary),
        "provenance": _jsonable(model.provenance),
        "checksums": {k: array_sha256(v) for k, v in arrays.items()},
    }
    header["gp"] = {"type": "sparse", "inducing": int(len(gp.Z))} if sparse else {"type": "exact"}
    if variation is not None:
        header["variation"] = {"demos": int(variation.demos), "steps": int(len(variation.s)),
                               "band_scale": {"rotation": float(variation.band_scale[0]),
                                              "position": float(variation.band_scale[1])},
                               "shrinkage": float(variation.shrinkage)}
        if variation.surprise_header() is not None:  # optional: the start's surprise (dynamics/variation.py)
            header["variation"]["start_surprise"] = variation.surprise_header()
    if paths is not None:
        header["paths"] = paths.header()
    if getattr(model, "envelope", None) is not None:  # optional: files without it load (computed then)
        header["envelope"] = model.envelope.to_dict()
    # optional: the gain on the GP's residual mean (dynamics/residual_gain.py); files without it load with 1
    header["residual_gain"] = float(getattr(model, "residual_gain", 1.0))
    header = json.loads(canonical_json(header))  # as a reader will parse it (keys as strings, tuples as lists)
    header["checksums"]["header"] = header_sha256(header)
    raw = canonical_json(header)
    # compressed in memory first: the temporary file then exists only for the write, the fsync and the
    # rename, so that a SIGKILL (which nothing can clean up after) rarely finds one
    buf = io.BytesIO()
    np.savez_compressed(buf, header=np.frombuffer(raw, dtype=np.uint8), **arrays)
    try:
        with atomic_open(path, "wb") as fh:
            fh.write(buf.getbuffer())
    except (FileNotFoundError, NotADirectoryError, PermissionError, IsADirectoryError) as exc:
        raise InputError(f"cannot write the model file ({exc.strerror or type(exc).__name__})", path=str(path),
                         hint="check that the folder exists and is writable") from None
    return header


def _bad(path, what, hint="retrain it with rbgp train or restore it from a backup", param=None):
    return InputError(what, path=str(path), hint=hint, param=param)


def canonical_json(header: dict) -> bytes:
    """The header's canonical serialisation (what its checksum covers): keys sorted, no spaces,
    ASCII only, non-finite numbers as NaN / Infinity, floats as Python's shortest repr."""
    return json.dumps(header, sort_keys=True, separators=(",", ":"), ensure_ascii=True, allow_nan=True).encode("ascii")


def header_sha256(header: dict) -> str:
    """SHA-256 of the header's :func:`canonical_json` without its own entry ``checksums.header``."""
    h = dict(header)
    if isinstance(h.get("checksums"), dict):
        h["checksums"] = {k: v for k, v in h["checksums"].items() if k != "header"}
    return hashlib.sha256(canonical_json(h)).hexdigest()


def _head(path, n: int) -> bytes:
    """The first ``n`` bytes of a path or an open binary file (left where it was)."""
    if hasattr(path, "read"):
        pos = path.tell()
        head = path.read(n)
        path.seek(pos)
        return head
    with open(path, "rb") as fh:
        return fh.read(n)


def _file_size(path) -> int:
    if hasattr(path, "seek"):
        pos = path.tell()
        size = path.seek(0, 2)
        path.seek(pos)
        return size
    return os.path.getsize(path)


_STRING = re.compile(rb'"(?:[^"\\]|\\.)*"')


def _json_depth(raw: bytes) -> int:
    """Deepest nesting of ``[`` / ``{`` in JSON text, strings skipped (no recursion, vectorised)."""
    b = np.frombuffer(_STRING.sub(b'""', raw), dtype=np.uint8)
    step = (np.isin(b, (ord("["), ord("{"))).astype(np.int32) - np.isin(b, (ord("]"), ord("}"))))
    return int(np.max(np.cumsum(step), initial=0))


def _parse_int(text: str) -> int:
    if len(text.lstrip("-")) > _MAX_DIGITS:
        raise ValueError(f"an integer of {len(text)} digits")
    return int(text)


def _parse_float(text: str) -> float:
    if len(text) > _MAX_DIGITS + 30:
        raise ValueError(f"a number of {len(text)} characters")
    return float(text)


def _parse_header(path, raw: bytes) -> dict:
    """The header JSON, parsed with bounded size, depth and number lengths."""
    if len(raw) > MAX_HEADER_BYTES:
        raise _bad(path, f"the model header is {len(raw)} bytes, more than the {MAX_HEADER_BYTES >> 20} MiB a model header may have")
    if _json_depth(raw) > MAX_HEADER_DEPTH:
        raise _bad(path, f"the model header is nested more than {MAX_HEADER_DEPTH} levels deep: not a header rbgp wrote")
    try:
        header = json.loads(raw.decode("utf-8"), parse_int=_parse_int, parse_float=_parse_float)
    except UnicodeDecodeError:
        raise _bad(path, "the model header is damaged (not UTF-8)") from None
    except RecursionError:  # not reached after the depth check; kept as a guard
        raise _bad(path, "the model header is nested too deeply") from None
    except ValueError as exc:  # json.JSONDecodeError, and the number limits above
        raise _bad(path, f"the model header is damaged ({str(exc)[:80]})") from None
    return header


def _member_info(zf: zipfile.ZipFile, path, name: str, disk: int) -> zipfile.ZipInfo:
    """The zip entry of array ``name``, refused before reading if it declares more than a model
    file can hold: beyond the file, beyond :data:`MAX_RATIO` × its compressed size (+ slack), or
    beyond :data:`MAX_ARRAY_BYTES`."""
    info = zf.getinfo(f"{name}.npy")
    if info.compress_size > disk or info.header_offset > disk:
        raise _bad(path, f"array {name!r}: its zip entry claims more bytes than the file has (the file is cut or damaged)")
    limit = min(MAX_ARRAY_BYTES, MAX_RATIO * info.compress_size + RATIO_SLACK)
    if info.file_size > limit:
        raise _bad(path, f"array {name!r} would decompress to {info.file_size} bytes from {info.compress_size}, more than "
                         f"{'the limit' if limit == MAX_ARRAY_BYTES else f'{MAX_RATIO}× its compressed size'}: "
                         "not a model rbgp wrote (a zip bomb?)")
    return info


def _read_array(zf: zipfile.ZipFile, info: zipfile.ZipInfo, path, name: str) -> np.ndarray:
    """One .npy member: its header (dtype, shape) checked against the member's size before the data
    are read, then exactly that many bytes read into a new array (never pickled)."""
    with zf.open(info) as fp:
        version = np.lib.format.read_magic(fp)
        if version == (1, 0):
            shape, fortran, dtype = np.lib.format.read_array_header_1_0(fp)
        elif version == (2, 0):
            shape, fortran, dtype = np.lib.format.read_array_header_2_0(fp)
        else:
            raise _bad(path, f"array {name!r} uses .npy format version {version}, which rbgp does not write")
        if dtype.hasobject or dtype.kind not in "fiub" or dtype.fields is not None:
            raise _bad(path, f"array {name!r} has dtype {dtype}; a model file holds numbers only")
        if len(shape) > 3 or any(not isinstance(s, int) or s < 0 for s in shape):
            raise _bad(path, f"array {name!r} declares the shape {shape}, not one a model file holds")
        nbytes = math.prod(shape) * dtype.itemsize
        data_bytes = info.file_size - fp.tell()
        if nbytes != data_bytes:
            raise _bad(path, f"array {name!r} declares the shape {shape} ({nbytes} bytes) but holds {data_bytes} bytes: "
                             "the file is damaged or not written by rbgp")
        buf = np.empty(nbytes, dtype=np.uint8)
        view, pos = memoryview(buf), 0
        while pos < nbytes:
            k = fp.readinto(view[pos:pos + (1 << 20)])  # 1 MiB: faster than larger reads (measured)
            if not k:
                raise _bad(path, f"array {name!r} is cut short")
            pos += k
        fp.read(1)  # reach the end of the member, so that zipfile checks its CRC
    return buf.view(dtype).reshape(shape, order="F" if fortran else "C")


#: A model read from a FIFO (``<(cat model.rbgp)``) is held in memory: at most this many bytes.
MAX_STREAMED_MODEL_BYTES = 1 << 30


def _seekable_source(path):
    """``path`` itself, or for a FIFO or pipe (:func:`rbgp_cli.io.special.is_stream_path`) its bytes
    in memory (zip needs to seek); a device is refused, and so is a FIFO nobody writes to."""
    if hasattr(path, "read"):
        return path
    if str(path) == "-":  # stdin carries the data of the commands that read it (follow's rows, evaluate's rollouts)
        raise InputError("the model '-' is stdin, and a model is not read from stdin",
                         hint="pass the model file's path, e.g. shoe.rbgp")
    from rbgp_cli.io.special import is_stream_path, open_stream_path

    if not is_stream_path(path):
        return path
    with open_stream_path(path, "model file") as stream:
        data = stream.read(MAX_STREAMED_MODEL_BYTES + 1)
    if len(data) > MAX_STREAMED_MODEL_BYTES:
        raise _bad(path, f"the stream holds more than {MAX_STREAMED_MODEL_BYTES >> 20} MiB, more than a model file "
                         "read from a pipe may have", "pass the model file itself")
    return io.BytesIO(data)


def is_model_file(path) -> bool:
    """Whether ``path`` is a file that looks like an rbgp model (a zip archive holding a ``header`` member), for a
    message where one is given as data; False for anything else, a pipe or an unreadable file."""
    try:
        if not os.path.isfile(path) or _head(path, 4) != b"PK\x03\x04":
            return False
        with zipfile.ZipFile(path) as zf:
            return any(n.startswith("header") for n in zf.namelist())
    except (OSError, zipfile.BadZipFile, ValueError):
        return False


def _open_zip(path, src=None) -> zipfile.ZipFile:
    src = path if src is None else src
    magic = _head(src, 4)
    if not magic:
        raise _bad(path, "the model file is empty")
    if magic != b"PK\x03\x04":  # np.load would try to unpickle it and suggest allowing that, which misleads
        raise _bad(path, "not an rbgp model file (.rbgp files are zip archives; this one is not)",
                   "pass a file written by rbgp train")
    return zipfile.ZipFile(src)


def read_header(path) -> tuple[dict, dict]:
    """Header and arrays of a model file, verified; no GP rebuilt.

    Order: sizes from the zip directory (before anything is decompressed), the header (size, depth,
    numbers, format, its checksum, version), every array's declared shape against its member's
    size, the arrays' checksums, then every header field and every array against the header
    (:mod:`rbgp_cli.io.model_schema`). Raises :class:`InputError` naming the file."""
    from rbgp_cli.io.model_schema import SchemaError, validate_arrays, validate_header

    src = _seekable_source(path)
    try:
        disk = _file_size(src)
        with _open_zip(path, src) as zf:
            names = {n[:-4] for n in zf.namelist() if n.endswith(".npy")}
            if len(zf.infolist()) > MAX_MEMBERS:
                raise _bad(path, f"the model file has {len(zf.infolist())} members, more than a model file holds")
            if "header" not in names:
                raise _bad(path, "not an rbgp model file (no header)", "pass a file written by rbgp train")
            info = _member_info(zf, path, "header", disk)
            if info.file_size > MAX_HEADER_BYTES + 1024:
                raise _bad(path, f"the model header is {info.file_size} bytes, more than the "
                                 f"{MAX_HEADER_BYTES >> 20} MiB a model header may have")
            raw = _read_array(zf, info, path, "header")
            if raw.dtype != np.uint8 or raw.ndim != 1:
                raise _bad(path, "the model header is damaged (not a byte string)")
            header, version = _check_header(path, _parse_header(path, raw.tobytes()))
            known = (*_ARRAYS, *_PRIOR_ARRAYS, *_START_ARRAYS, _PROFILE_ARRAY[0], _REACH_ARRAY[0], *_SPARSE_ARRAYS, *_VARIATION_ARRAYS,
                     *_PATHS_ARRAYS)
            infos = {k: _member_info(zf, path, k, disk) for k in known if k in names}
            total = sum(i.file_size for i in infos.values())
            if total > MAX_RATIO * disk + RATIO_SLACK:
                raise _bad(path, f"the arrays would decompress to {total} bytes from a {disk}-byte file: "
                                 "not a model rbgp wrote (a zip bomb?)")
            arrays = {k: _read_array(zf, i, path, k) for k, i in infos.items()}
    except RbgpError:
        raise
    except FileNotFoundError:
        raise InputError("model file not found", path=str(path), hint="check the path") from None
    except IsADirectoryError:
        raise InputError("is a directory, not a model file", path=str(path)) from None
    except MemoryError:
        raise _bad(path, "not enough memory to read the model file's arrays") from None
    except (zipfile.BadZipFile, zlib.error, EOFError, ValueError, OSError, KeyError, TypeError,
            NotImplementedError, RuntimeError,  # zipfile: unknown compression / "encrypted" flag
            SyntaxError, tokenize.TokenError) as exc:  # numpy's .npy header parser on a damaged header
        raise _bad(path, f"not a readable rbgp model file ({type(exc).__name__}: {str(exc)[:80]})") from None
    sums = header.get("checksums")
    if not isinstance(sums, dict):
        raise _bad(path, "the model header is inconsistent: checksums is missing or not an object")
    gp = header.get("gp") or {}
    sparse = isinstance(gp, dict) and gp.get("type") == "sparse"
    for name in _ARRAYS + (_SPARSE_ARRAYS if sparse else ()):
        if name not in arrays:
            raise _bad(path, f"array {name!r} is missing from the model file")
    for name in arrays:
        if sums.get(name) != array_sha256(arrays[name]):
            raise _bad(path, f"checksum mismatch in array {name!r}: the file is corrupted")
    try:
        header = validate_header(header, version)
        validate_arrays(header, arrays)
    except SchemaError as exc:
        raise _bad(path, f"the model header is inconsistent: {exc}") from None
    return header, arrays


def _check_header(path, header) -> tuple[dict, int]:
    """Format, header checksum and version of a parsed header."""
    if not isinstance(header, dict) or header.get("format") != FORMAT:
        raise _bad(path, "not an rbgp model file", "pass a file written by rbgp train")
    sums = header.get("checksums")
    stored = sums.get("header") if isinstance(sums, dict) else None
    if stored is not None and stored != header_sha256(header):
        raise _bad(path, "checksum mismatch in the model header: it was edited or is corrupted")
    version = header.get("version")
    if not isinstance(version, int) or isinstance(version, bool):
        raise _bad(path, "the model header has no valid format version")
    if version > FORMAT_VERSION:
        raise InputError(
            f"model format version {version} is newer than this rbgp supports ({FORMAT_VERSION})",
            path=str(path), hint="upgrade rbgp (pip install -U rbgp-cli)",
        )
    if version < 1:
        raise _bad(path, f"unknown model format version {version}")
    if version >= 4 and stored is None:
        raise _bad(path, f"the model header has no header checksum (format version {version} always has one): "
                         "it was edited or is corrupted")
    return header, version


def load_model(path):
    """Load and verify a model file; returns a :class:`~rbgp_cli.dynamics.model.MotionModel`."""
    from rbgp_cli.dynamics.model import MotionModel
    from rbgp_cli.dynamics.representations import representation_from_dict
    from rbgp_cli.gp.exact import GaussianProcess
    from rbgp_cli.gp.results import OutputFit
    from rbgp_cli.gp.sparse import SparseGP, SparseOutputFit
    from rbgp_cli.kernels import kernel_from_dict

    header, arrays = read_header(path)  # every field and array checked against the header
    try:
        rep = representation_from_dict(header["representation"])
        kernel = kernel_from_dict(header["kernel"])
        sparse = (header.get("gp") or {}).get("type") == "sparse"
        fits = [(SparseOutputFit if sparse else OutputFit).from_dict(f) for f in header["fits"]]
        X, Y = arrays["X"], arrays["Y"]
        if sparse:
            Z, Lm, LB, c = (arrays[k] for k in _SPARSE_ARRAYS)
            cols = [(0, Y.shape[1])] if header["shared"] else [(g, g + 1) for g in range(len(fits))]
            stats = [(Lm[g], LB[g], c[:, a:b]) for g, (a, b) in enumerate(cols)]
            gp = SparseGP(kernel, X, Y, Z, fits, shared=header["shared"], y_scale=arrays["y_scale"], stats=stats)
        else:
            gp = GaussianProcess(kernel, X, Y, fits, shared=header["shared"], y_scale=arrays["y_scale"])
        dt = float(header["dt"])
        velocity, time_input, mean = _model_extras(header, arrays, rep, X)
        envelope = None
        if header.get("envelope") is not None:
            from rbgp_cli.dynamics.envelope import Envelope

            envelope = Envelope.from_dict(header["envelope"])
    except RbgpError as exc:
        raise _bad(path, f"the model cannot be rebuilt: {exc.message}") from None
    except MemoryError:  # not max_points of a training: this file's GP needs more memory than there is
        n = len(arrays["X"])
        raise _bad(path, f"not enough memory to rebuild the model's GP on {n} training points "
                         f"(an {n} × {n} matrix: {8 * n * n / 2**30:.3g} GiB)",
                   "use a machine with more memory, or retrain it on fewer points (max_points)", param="max_points") from None
    except (KeyError, TypeError, ValueError, IndexError, AttributeError, ArithmeticError) as exc:
        raise _bad(path, f"the model header is inconsistent ({type(exc).__name__}: {str(exc)[:80]})") from None
    _check_predicts(path, gp, X)
    variation = None
    if header.get("variation"):
        from rbgp_cli.dynamics.variation import Variation

        variation = Variation.from_arrays(arrays, header["variation"].get("band_scale"),
                                          header["variation"].get("shrinkage", 0.0),
                                          header["variation"].get("start_surprise"))
    paths = None
    if header.get("paths"):
        from rbgp_cli.dynamics.paths import PathDistribution

        paths = PathDistribution.from_arrays(arrays, header["paths"])
    return MotionModel(rep, gp, dt, arrays["starts"], arrays["durations"],
                       summary=header.get("summary", {}), provenance=header.get("provenance", {}),
                       velocity=velocity, time_input=time_input, mean=mean, variation=variation, envelope=envelope,
                       paths=paths, residual_gain=float(header.get("residual_gain", 1.0))), header


#: Training inputs at which a loaded model must predict finite velocities (spread over the data).
CHECK_POINTS = 8


def _check_predicts(path, gp, X) -> None:
    """Refuse a model whose GP does not predict finite velocities with finite stds at its own training
    inputs (X all 1e300 with recomputed checksums: distances overflow), so that every command that
    loads a model (``info`` as well as ``rollout``) refuses the same files, before any work."""
    idx = np.unique(np.linspace(0, len(X) - 1, min(CHECK_POINTS, len(X))).astype(int))
    try:
        with np.errstate(all="ignore"):
            mean, std = gp.predict(np.asarray(X)[idx], return_std=True)
        ok = np.all(np.isfinite(mean)) and np.all(np.isfinite(std))
    except (ArithmeticError, ValueError, np.linalg.LinAlgError):
        ok = False
    if not ok:
        raise _bad(path, "the model predicts non-finite velocities at its own training inputs: its arrays are "
                         "damaged or were edited")


def _model_extras(header: dict, arrays: dict, rep, X):
    """Velocity options, time input and prior mean of a version-2 header (version 1: defaults), checked."""
    from rbgp_cli.dynamics.velocities import VelocityOptions

    v = header.get("velocity") or {}
    velocity = VelocityOptions(rate=v.get("rate_hz"), window=float(v.get("window_s", 0.0)), degree=int(v.get("degree", 2)))
    time_input = header.get("time_input")
    if time_input not in (None, "seconds", "phase"):
        raise ValueError(f"unknown time input {time_input!r}")
    if X.shape[1] != len(rep.input_names) + (1 if time_input else 0):
        raise ValueError("the training inputs disagree with the time input")
    prior = header.get("prior")
    if not prior:
        return velocity, time_input, None
    gain = float(prior["gain"])
    if not (np.isfinite(gain) and gain >= 0):
        raise ValueError(f"prior gain {gain!r} is not a non-negative number")
    if prior["kind"] == "goal":
        goal = np.asarray(prior["goal"], dtype=np.float64)
        if goal.shape != (7,) or not np.all(np.isfinite(goal)):
            raise ValueError("the prior's goal pose is not 7 finite numbers")
        return velocity, time_input, {"kind": "goal", "gain": gain, "goal": goal.tolist()}
    if prior["kind"] != "path" or time_input != "phase":
        raise ValueError(f"unknown prior {prior['kind']!r} for time input {time_input!r}")
    mean = {"kind": "path", "gain": gain}
    if prior.get("feedforward") == "secant":  # absent in files before it: the tangent, as they were trained
        mean["feedforward"] = "secant"
    for name, key in _PRIOR_ARRAYS.items():
        if name not in arrays:
            raise ValueError(f"array {name!r} of the mean-path prior is missing")
        mean[key] = np.asarray(arrays[name], dtype=np.float64)
    if prior.get("start") == "conditioned":
        for name, key in _START_ARRAYS.items():
            if name not in arrays:
                raise ValueError(f"array {name!r} of the start-conditioned prior is missing")
            mean[key] = np.asarray(arrays[name], dtype=np.float64)
        if prior.get("gain_profile"):
            if _PROFILE_ARRAY[0] not in arrays:
                raise ValueError(f"array {_PROFILE_ARRAY[0]!r} of the pull's profile is missing")
            mean[_PROFILE_ARRAY[1]] = np.asarray(arrays[_PROFILE_ARRAY[0]], dtype=np.float64)
        if prior.get("start_reach"):  # absent in files before it: the map unbounded, as they were trained
            if _REACH_ARRAY[0] not in arrays:
                raise ValueError(f"array {_REACH_ARRAY[0]!r} of the start map's bound is missing")
            mean[_REACH_ARRAY[1]] = np.asarray(arrays[_REACH_ARRAY[0]], dtype=np.float64)
    S = len(mean["s"])
    if (S < 2 or mean["quat"].shape != (S, 4) or mean["position"].shape != (S, 3)
            or ("start_mean" in mean and mean["start_mean"].shape != (S, 6))
            or ("start_beta" in mean and mean["start_beta"].shape not in ((S, 6), (S, 6, 6)))
            or ("gain_profile" in mean and mean["gain_profile"].shape != (S, 6))
            or ("start_reach" in mean and mean["start_reach"].shape != (S, 2))
            or mean["velocity"].shape != (S - 1, 6) or not all(np.all(np.isfinite(a)) for a in mean.values() if isinstance(a, np.ndarray))
            or not np.all(np.diff(mean["s"]) > 0)):
        raise ValueError("the mean-path prior's arrays are inconsistent")
    return velocity, time_input, mean
