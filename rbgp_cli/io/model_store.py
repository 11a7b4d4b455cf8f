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
  outputs); loading checks them against k(Z, Z) instead of refactorising all n points. Exact models
  are still written as version 2, which older rbgp reads.

Loading uses ``allow_pickle=False``, checks the format name and version, verifies every checksum,
rebuilds the GP and re-runs its Cholesky factorisation. Any failure is an :class:`InputError`
naming the file and what to do. Files are written atomically (temporary name, then rename).
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import zipfile
import zlib

import numpy as np

from rbgp_cli import __version__
from rbgp_cli.errors import InputError, RbgpError
from rbgp_cli.io.atomic import atomic_open

__all__ = ["FORMAT", "FORMAT_VERSION", "save_model", "load_model", "file_sha256", "array_sha256"]

FORMAT = "rbgp-model"
#: The newest version this rbgp reads and writes (3: sparse GPs; exact models are written as 2).
FORMAT_VERSION = 3
_ARRAYS = ("X", "Y", "y_scale", "starts", "durations")
#: Arrays of a sparse GP (version 3).
_SPARSE_ARRAYS = ("Z", "Lm", "LB", "c")
#: Arrays of the mean-path prior (present only when the model has one).
_PRIOR_ARRAYS = {"prior_s": "s", "prior_quat": "quat", "prior_position": "position", "prior_velocity": "velocity"}


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
    sparse = bool(getattr(gp, "sparse", False))
    if sparse:
        arrays["Z"] = np.ascontiguousarray(gp.Z, dtype=np.float64)
        arrays["Lm"] = np.ascontiguousarray(np.stack([st[0] for st in gp.stats]), dtype=np.float64)
        arrays["LB"] = np.ascontiguousarray(np.stack([st[1] for st in gp.stats]), dtype=np.float64)
        arrays["c"] = np.ascontiguousarray(np.concatenate([st[2] for st in gp.stats], axis=1), dtype=np.float64)
    header = {
        "format": FORMAT,
        "version": 3 if sparse else 2,
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
    if sparse:
        header["gp"] = {"type": "sparse", "inducing": int(len(gp.Z))}
    if getattr(model, "envelope", None) is not None:  # optional: files without it load (computed then)
        header["envelope"] = model.envelope.to_dict()
    raw = json.dumps(header, sort_keys=True, allow_nan=True).encode("utf-8")
    try:
        with atomic_open(path, "wb") as fh:
            np.savez_compressed(fh, header=np.frombuffer(raw, dtype=np.uint8), **arrays)
    except (FileNotFoundError, NotADirectoryError, PermissionError, IsADirectoryError) as exc:
        raise InputError(f"cannot write the model file ({exc.strerror or type(exc).__name__})", path=str(path),
                         hint="check that the folder exists and is writable") from None
    return header


def _bad(path, what, hint="retrain it with rbgp train or restore it from a backup"):
    return InputError(what, path=str(path), hint=hint)


def _head(path, n: int) -> bytes:
    """The first ``n`` bytes of a path or an open binary file (left where it was)."""
    if hasattr(path, "read"):
        pos = path.tell()
        head = path.read(n)
        path.seek(pos)
        return head
    with open(path, "rb") as fh:
        return fh.read(n)


def read_header(path) -> tuple[dict, dict]:
    """Header and arrays of a model file, verified (format, version, checksums); no GP rebuilt."""
    try:
        magic = _head(path, 4)
        if not magic:
            raise _bad(path, "the model file is empty")
        if magic != b"PK\x03\x04":  # np.load would try to unpickle it and suggest allowing that, which misleads
            raise _bad(path, "not an rbgp model file (.rbgp files are zip archives; this one is not)",
                       "pass a file written by rbgp train")
        with np.load(path, allow_pickle=False) as z:
            names = set(z.files)
            if "header" not in names:
                raise _bad(path, "not an rbgp model file (no header)", "pass a file written by rbgp train")
            header_bytes = z["header"].tobytes()
            arrays = {k: z[k] for k in (*_ARRAYS, *_PRIOR_ARRAYS, *_SPARSE_ARRAYS) if k in names}
    except RbgpError:
        raise
    except FileNotFoundError:
        raise InputError("model file not found", path=str(path), hint="check the path") from None
    except IsADirectoryError:
        raise InputError("is a directory, not a model file", path=str(path)) from None
    except (zipfile.BadZipFile, zlib.error, EOFError, ValueError, OSError, KeyError, TypeError,
            NotImplementedError, RuntimeError) as exc:  # zipfile: unknown compression / "encrypted" flag
        raise _bad(path, f"not a readable rbgp model file ({type(exc).__name__}: {str(exc)[:80]})") from None
    try:
        header = json.loads(header_bytes.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError):
        raise _bad(path, "the model header is damaged") from None
    if not isinstance(header, dict) or header.get("format") != FORMAT:
        raise _bad(path, "not an rbgp model file", "pass a file written by rbgp train")
    version = header.get("version")
    if not isinstance(version, int):
        raise _bad(path, "the model header has no valid format version")
    if version > FORMAT_VERSION:
        raise InputError(
            f"model format version {version} is newer than this rbgp supports ({FORMAT_VERSION})",
            path=str(path), hint="upgrade rbgp (pip install -U rbgp-cli)",
        )
    if version < 1:
        raise _bad(path, f"unknown model format version {version}")
    sums = header.get("checksums") or {}
    gp = header.get("gp") or {}
    if not isinstance(gp, dict) or gp.get("type", "exact") not in ("exact", "sparse"):
        raise _bad(path, f"unknown GP type in the model header: {gp!r}")
    for name in _ARRAYS + (_SPARSE_ARRAYS if gp.get("type") == "sparse" else ()):
        if name not in arrays:
            raise _bad(path, f"array {name!r} is missing from the model file")
    for name in arrays:
        if sums.get(name) != array_sha256(arrays[name]):
            raise _bad(path, f"checksum mismatch in array {name!r}: the file is corrupted")
    return header, arrays


def load_model(path):
    """Load and verify a model file; returns a :class:`~rbgp_cli.dynamics.model.MotionModel`."""
    from rbgp_cli.dynamics.model import MotionModel
    from rbgp_cli.dynamics.representations import representation_from_dict
    from rbgp_cli.gp.exact import GaussianProcess, OutputFit
    from rbgp_cli.gp.sparse import SparseGP, SparseOutputFit
    from rbgp_cli.kernels import kernel_from_dict

    header, arrays = read_header(path)
    try:
        rep = representation_from_dict(header["representation"])
        kernel = kernel_from_dict(header["kernel"])
        sparse = (header.get("gp") or {}).get("type") == "sparse"
        fits = [(SparseOutputFit if sparse else OutputFit).from_dict(f) for f in header["fits"]]
        for f in fits:  # every hyperparameter is positive (they are optimised in log space)
            for k, v in f.values.items():
                if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 < v < float("inf"):
                    raise ValueError(f"hyperparameter {k} = {v!r} is not a positive finite number")
                f.values[k] = float(v)  # JSON may hold an integer, which numpy would square into an object
            j = f.jitter
            if isinstance(j, bool) or not isinstance(j, (int, float)) or not 0 <= j < float("inf"):
                raise ValueError(f"jitter = {j!r} is not a non-negative finite number")
            f.jitter = float(j)
        X, Y = arrays["X"], arrays["Y"]
        extra = 1 if header.get("time_input") else 0
        if (X.ndim != 2 or Y.ndim != 2 or len(X) != len(Y) or X.shape[1] != len(rep.input_names) + extra
                or Y.shape[1] != len(rep.output_names)):
            raise ValueError("array shapes disagree with the representation")
        if len(fits) != (1 if header["shared"] else Y.shape[1]):
            raise ValueError("number of fitted outputs disagrees with the data")
        if not (np.all(np.isfinite(X)) and np.all(np.isfinite(Y))):
            raise ValueError("non-finite training data")
        if sparse:
            Z, Lm, LB, c = (arrays[k] for k in _SPARSE_ARRAYS)
            G, M = len(fits), len(Z)
            if (Z.ndim != 2 or Z.shape[1] != X.shape[1] or Lm.shape != (G, M, M) or LB.shape != (G, M, M)
                    or c.shape != (M, Y.shape[1]) or not all(np.all(np.isfinite(a)) for a in (Z, Lm, LB, c))):
                raise ValueError("the sparse GP's arrays disagree with each other")
            for f in fits:
                kj = f.kmm_jitter
                if isinstance(kj, bool) or not isinstance(kj, (int, float)) or not 0 <= kj < 1:
                    raise ValueError(f"kmm_jitter = {kj!r} is not a number in [0, 1)")
            cols = [(0, Y.shape[1])] if header["shared"] else [(g, g + 1) for g in range(G)]
            stats = [(Lm[g], LB[g], c[:, a:b]) for g, (a, b) in enumerate(cols)]
            gp = SparseGP(kernel, X, Y, Z, fits, shared=header["shared"], y_scale=arrays["y_scale"], stats=stats)
        else:
            gp = GaussianProcess(kernel, X, Y, fits, shared=header["shared"], y_scale=arrays["y_scale"])
        dt = float(header["dt"])
        if not (np.isfinite(dt) and dt > 0):
            raise ValueError("invalid time step")
        velocity, time_input, mean = _model_extras(header, arrays, rep, X)
        envelope = None
        if header.get("envelope") is not None:
            from rbgp_cli.dynamics.envelope import Envelope

            envelope = Envelope.from_dict(header["envelope"])
    except RbgpError as exc:
        raise _bad(path, f"the model cannot be rebuilt: {exc.message}") from None
    except (KeyError, TypeError, ValueError, IndexError, AttributeError, ArithmeticError) as exc:
        raise _bad(path, f"the model header is inconsistent ({type(exc).__name__}: {str(exc)[:80]})") from None
    return MotionModel(rep, gp, dt, arrays["starts"], arrays["durations"],
                       summary=header.get("summary", {}), provenance=header.get("provenance", {}),
                       velocity=velocity, time_input=time_input, mean=mean, envelope=envelope), header


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
    for name, key in _PRIOR_ARRAYS.items():
        if name not in arrays:
            raise ValueError(f"array {name!r} of the mean-path prior is missing")
        mean[key] = np.asarray(arrays[name], dtype=np.float64)
    S = len(mean["s"])
    if (S < 2 or mean["quat"].shape != (S, 4) or mean["position"].shape != (S, 3)
            or mean["velocity"].shape != (S - 1, 6) or not all(np.all(np.isfinite(a)) for a in mean.values() if isinstance(a, np.ndarray))
            or not np.all(np.diff(mean["s"]) > 0)):
        raise ValueError("the mean-path prior's arrays are inconsistent")
    return velocity, time_input, mean
