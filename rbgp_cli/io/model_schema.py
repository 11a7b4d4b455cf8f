"""What a model file's header and arrays may hold (the checks behind :func:`rbgp_cli.io.model_store.read_header`).

The header is plain JSON; every field rbgp reads has a declared type and range here, per format
version, and the arrays are checked against it (shape, dtype float64, finiteness). A failure raises
:class:`SchemaError` whose message names the field (``fits[0].values.length_scale = 1e+308 is not a
positive finite number in [1e-12, 1e+12]``); the model store turns it into an InputError naming the file.

To add a header field: add it to :data:`TOP` (``since`` = the first format version that writes it;
older files may lack it) with a checker; free-form sections (``summary``, ``provenance``) accept new
keys without a change here. Unknown top-level keys are refused: a header rbgp did not write, or a
renamed field (which would otherwise be dropped silently, as a renamed ``prior`` was).
"""

from __future__ import annotations

import math
import re

import numpy as np

__all__ = ["SchemaError", "validate_header", "validate_arrays", "HYPERPARAMETER_RANGE", "DT_RANGE", "MAX_OUTPUTS"]


class SchemaError(ValueError):
    """A header field or an array does not match the format; the message names it."""


#: every GP hyperparameter (σf, λ, λτ, σn) lies in this range (they are positive; the bound keeps
#: exp(−d²/2λ²) and σf² finite and distinguishable from a constant)
HYPERPARAMETER_RANGE = (1e-12, 1e12)
#: seconds; a time step outside it would plan 10^300 steps or one step per hour
DT_RANGE = (1e-6, 1e4)
MAX_OUTPUTS = 64
#: at most this many rollout steps for a demonstration's duration (duration / dt)
MAX_STEPS = 1e8
_MAX_LIST = 1_000_000
_MAX_STR = 1 << 20
_HEX64 = re.compile(r"[0-9a-f]{64}")


def _name(path) -> str:
    out = ""
    for p in path:
        out += f"[{p}]" if isinstance(p, int) else (f".{p}" if out else str(p))
    return out or "header"


def _fail(path, value, what: str):
    text = repr(value)
    if len(text) > 60:
        text = text[:57] + "..."
    raise SchemaError(f"{_name(path)} = {text} is not {what}")


def _is_num(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


# ---------------------------------------------------------------------------------------------- checkers
# A checker is called as check(value, path) and returns the (possibly normalised) value or raises.


def num(lo=-math.inf, hi=math.inf, *, lo_open=False, finite=True, what=None):
    def check(v, path):
        ok = _is_num(v) and (not finite or math.isfinite(v))
        if ok and finite:
            v = float(v)
            ok = (lo < v if lo_open else lo <= v) and v <= hi
        if not ok:
            _fail(path, v, what or (f"a finite number in {'(' if lo_open else '['}{lo:g}, {hi:g}]" if finite else "a number"))
        return float(v)

    return check


def positive(lo, hi, name="a positive finite number"):
    return num(lo, hi, what=f"{name} in [{lo:g}, {hi:g}]")


def integer(lo, hi):
    def check(v, path):
        if not (isinstance(v, int) and not isinstance(v, bool) and lo <= v <= hi):
            _fail(path, v, f"an integer in [{lo}, {hi}]")
        return v

    return check


def boolean(v, path):
    if not isinstance(v, bool):
        _fail(path, v, "true or false")
    return v


def string(choices=None, max_len=_MAX_STR):
    def check(v, path):
        if not isinstance(v, str) or len(v) > max_len or (choices is not None and v not in choices):
            _fail(path, v, "one of " + ", ".join(repr(c) for c in choices) if choices is not None else "a string")
        return v

    return check


def nullable(check_inner):
    def check(v, path):
        return None if v is None else check_inner(v, path)

    return check


def anything(v, path):
    return v


def list_of(item, min_len=0, max_len=_MAX_LIST):
    def check(v, path):
        if not isinstance(v, list) or not min_len <= len(v) <= max_len:
            _fail(path, v, f"a list of {min_len} to {max_len} items")
        return [item(x, (*path, i)) for i, x in enumerate(v)]

    return check


def obj(fields: dict | None = None, required=(), *, extra: bool = False, extra_value=anything):
    """A JSON object: ``fields`` {key: checker}, ``required`` keys, ``extra`` keys allowed (checked
    by ``extra_value``) or refused."""
    fields = fields or {}

    def check(v, path):
        if not isinstance(v, dict):
            _fail(path, v, "an object")
        for k in required:
            if k not in v:
                raise SchemaError(f"{_name((*path, k))} is missing")
        out = {}
        for k, x in v.items():
            if k in fields:
                out[k] = fields[k](x, (*path, k))
            elif extra:
                out[k] = extra_value(x, (*path, k))
            else:
                raise SchemaError(f"unknown field {_name((*path, k))!r}")
        return out

    return check


# ---------------------------------------------------------------------------------------------- the header

_STR_LIST = list_of(string(max_len=1000))
_DICT_OR_NULL = nullable(obj(extra=True))

_REPRESENTATION = obj({
    "name": string(("axis-angle", "euler", "quaternion")),
    "order": string(max_len=3),
    "reference": nullable(list_of(num(), 4, 4)),
}, ("name",))  # fmt: skip

_KERNEL = obj({
    "kind": string(("squared_exponential", "dot_product")),
    "metric": string(("arc", "chordal", "euclidean", "s3")),
    "rotation_dims": integer(3, 4),
    "rho_rot": num(0.0, 1.0, lo_open=True, what="a number strictly between 0 and 1"),
    "learn_rho": boolean,
    "time_dims": integer(0, 1),
}, ("kind", "rotation_dims", "rho_rot", "learn_rho"))  # fmt: skip

_HYPER = positive(*HYPERPARAMETER_RANGE)
_ANY_NUMBER = num(finite=False)
_COUNT = integer(0, 10**12)

_FIT = obj({
    "values": obj(extra=True, extra_value=_HYPER),
    "nlml": _ANY_NUMBER,
    "jitter": num(0.0, 1e12, what="a non-negative finite number"),
    "rcond": _ANY_NUMBER,
    "positive_definite": boolean,
    "n_evaluations": _COUNT,
    "n_infeasible": _COUNT,
    "starts": list_of(anything),
    "at_bounds": _STR_LIST,
    "free": _STR_LIST,
    "seconds": _ANY_NUMBER,
    "guarded": boolean,
    "subsample": _DICT_OR_NULL,
    "calibration": nullable(obj({"factor": positive(1e-12, 1e12), "noise_std_fitted": _HYPER,
                                 "extra_factor": positive(1e-12, 1e12)},  # the noise scale, when not 1
                                ("factor", "noise_std_fitted"), extra=True)),
    "kmm_jitter": num(0.0, 1.0, what="a number in [0, 1)"),
    "stages": list_of(anything),
}, ("values", "nlml", "jitter"))  # fmt: skip

_VELOCITY = obj({
    "rate_hz": nullable(positive(1e-6, 1e7)),
    "window_s": num(0.0, 1e4, what="a non-negative number of seconds (at most 1e4)"),
    "degree": integer(1, 4),
    "method": string(("forward-differences", "local-polynomial")),
}, ("rate_hz", "window_s", "degree"))  # fmt: skip

_PRIOR = nullable(obj({
    "kind": string(("goal", "path")),
    "gain": num(0.0, 1e6, what="a non-negative finite number (at most 1e6)"),
    "goal": list_of(num(), 7, 7),
    "start": string(("mean", "conditioned")),
    "feedforward": string(("tangent", "secant")),
    "gain_profile": boolean,
    "start_reach": boolean,
}, ("kind", "gain")))  # fmt: skip

_GP = obj({"type": string(("exact", "sparse")), "inducing": integer(1, 10**6)}, ("type",))

_CHECKSUMS = obj(extra=True, extra_value=lambda v, p: v if isinstance(v, str) and _HEX64.fullmatch(v) else _fail(
    p, v, "a SHA-256 (64 lower-case hex digits)"))

_SUMMARY = obj({"seconds": nullable(_ANY_NUMBER)}, extra=True)

_PROVENANCE = obj({
    "inputs": list_of(obj({"name": nullable(string()), "sha256": string(), "bytes": nullable(_COUNT)},
                          extra=True)),
    "train_options": _DICT_OR_NULL,
    "read_options": _DICT_OR_NULL,
    "demonstrations": list_of(obj({"name": nullable(string()), "duration_s": nullable(_ANY_NUMBER)}, extra=True)),
}, extra=True)  # fmt: skip

#: top-level fields: name -> (first version that always writes it, checker)
TOP: dict = {
    "format": (1, string()),
    "version": (1, anything),  # checked by the store before anything else
    "rbgp_version": (1, string(max_len=100)),
    "created": (1, string(max_len=100)),
    "representation": (1, _REPRESENTATION),
    "kernel": (1, _KERNEL),
    "shared": (1, boolean),
    "fits": (1, list_of(_FIT, 1, MAX_OUTPUTS)),
    "dt": (1, positive(*DT_RANGE, name="a positive number of seconds")),
    "input_names": (1, _STR_LIST),
    "output_names": (1, list_of(string(max_len=1000), 1, MAX_OUTPUTS)),
    "summary": (1, _SUMMARY),
    "provenance": (1, _PROVENANCE),
    "checksums": (1, _CHECKSUMS),
    "velocity": (2, _VELOCITY),
    "time_input": (2, nullable(string(("seconds", "phase")))),
    "prior": (2, _PRIOR),
    "gp": (3, _GP),
    # optional (no version always writes them): the demonstrations' position envelope over phase
    # (dynamics/envelope.py) and their deviation process (dynamics/variation.py)
    "envelope": (10**6, nullable(obj({
        "lo": list_of(list_of(num(), 3, 3), 2, 10**5),
        "hi": list_of(list_of(num(), 3, 3), 2, 10**5),
        "margin": num(0.0, 1e9, what="a non-negative finite number of metres"),
        "source": string(("demonstrations", "training points")),
    }, ("lo", "hi", "margin")))),
    "variation": (10**6, nullable(obj({
        "demos": integer(3, 10**7), "steps": integer(2, 10**5),
        # version 6: the factors on the draws' rotation and position (dynamics/variation.band_scale)
        "band_scale": obj({"rotation": num(1.0, 1e6, what="a factor of at least 1"),
                           "position": num(1.0, 1e6, what="a factor of at least 1")}, ("rotation", "position")),
        # version 9: the shrinkage of the covariance between coordinates (dynamics/variation.shrinkage)
        "shrinkage": num(0.0, 1.0, what="a weight in [0, 1]"),
        # optional: the start's surprise, the start-only bands' widening (dynamics/variation.py, seventeenth pass)
        "start_surprise": obj({"quat": list_of(num(-1.0, 1.0, what="a unit quaternion's component"), 4, 4),
                               "position": list_of(num(), 3, 3), "mean": list_of(num(), 6, 6),
                               "covariance": list_of(list_of(num(), 6, 6), 6, 6),
                               "reference": nullable(num(0.0, 1e12, lo_open=True, what="a positive surprise")),
                               "parts": list_of(boolean, 2, 2),
                               "beyond": num(0.0, 1e12, lo_open=True, what="a positive surprise")},
                              ("quat", "position", "mean", "covariance", "reference", "parts")),
    }, ("demos", "steps")))),
    # optional: the gain g on the GP's residual mean (dynamics/residual_gain.py); absent: 1, the full GP
    "residual_gain": (10**6, num(0.0, 100.0, what="a gain from 0 to 100")),
    # version 8 (optional): the path distribution (dynamics/paths.py)
    "paths": (10**6, nullable(obj({
        "demos": integer(3, 10**7), "steps": integer(2, 10**5),
        "smooth": num(0.0, 1e6, what="a non-negative variance"), "length": num(1e-6, 1e6, what="a positive phase length"),
        "seen_tolerance": num(0.0, 1e6, what="a non-negative tolerance"),
        "band_scale": obj({"rotation": num(1.0, 1e6, what="a factor of at least 1"),
                           "position": num(1.0, 1e6, what="a factor of at least 1")}, ("rotation", "position")),
        # optional: the bands of a motion under way (issue 37)
        "seen_band_scale": obj({"rotation": num(1.0, 1e6, what="a factor of at least 1"),
                                "position": num(1.0, 1e6, what="a factor of at least 1")}, ("rotation", "position")),
        # optional: a motion under way's duration weights, their own τ² and tolerance (issue 37)
        "duration_smooth": num(0.0, 1e6, what="a non-negative variance"),
        "duration_tolerance": num(0.0, 1e6, what="a non-negative tolerance"),
        "duration_sigma": num(0.0, 1e6, lo_open=True, what="a positive tolerance in radians and metres"),
        "duration_evidence": num(0.0, 1.0, lo_open=True, what="a weight in (0, 1]"),
        "duration_statistic": string(("median", "mode")),
        # optional: a motion under way's conditioning of the rest, its own τ² and tolerance (issue 37)
        "rest_smooth": num(0.0, 1e6, what="a non-negative variance"),
        "rest_tolerance": num(0.0, 1e6, what="a non-negative tolerance"),
        "rest_duration_tolerance": num(0.0, 1e6, lo_open=True, what="a positive tolerance"),
        "rest_near_tolerance": num(0.0, 1e6, lo_open=True, what="a positive tolerance"),
        # optional: a motion under way's bands' factors per seen fraction (issue 37, seventh pass)
        "seen_band_scales": obj({"fractions": list_of(num(0.0, 1.0, what="a seen fraction in [0, 1]"), 1, 100),
                                 "rotation": list_of(num(0.0, 1e6, what="a non-negative factor"), 1, 100),
                                 "position": list_of(num(0.0, 1e6, what="a non-negative factor"), 1, 100)},
                                ("fractions", "rotation", "position")),
        # optional: a motion under way's end band's factors per seen fraction (twenty-first pass)
        "seen_end_band_scales": obj({"fractions": list_of(num(0.0, 1.0, what="a seen fraction in [0, 1]"), 1, 100),
                                     "rotation": list_of(num(0.0, 1e6, what="a non-negative factor"), 1, 100),
                                     "position": list_of(num(0.0, 1e6, what="a non-negative factor"), 1, 100)},
                                    ("fractions", "rotation", "position")),
        # optional: the left-out seen parts' median surprise per seen fraction, the bands' widening (sixteenth pass)
        "seen_surprise": obj({"fractions": list_of(num(0.0, 1.0, what="a seen fraction in [0, 1]"), 1, 100),
                              "points": list_of(integer(1, 10000), 1, 10),
                              "reference": list_of(list_of(num(0.0, 1e12, lo_open=True, what="a positive surprise"), 1, 100),
                                                   1, 10)},
                             ("fractions", "points", "reference")),
    }, ("demos", "steps", "smooth", "length", "seen_tolerance", "band_scale")))),
}


def validate_header(header: dict, version: int) -> dict:
    """The header with every field checked (numbers as floats where floats are meant); raises
    :class:`SchemaError`. Checks each field's type and range, then how fields agree with each other."""
    for key, (since, _) in TOP.items():
        if since <= version and key not in header:
            raise SchemaError(f"{key} is missing")
    h = obj({k: c for k, (_, c) in TOP.items()})(header, ())
    _agree(h)
    return h


def _agree(h: dict) -> None:
    from rbgp_cli.dynamics.representations import representation_from_dict
    from rbgp_cli.kernels import kernel_from_dict

    extra = set(h["representation"]) - {"name", {"euler": "order", "quaternion": "reference"}.get(h["representation"]["name"])}
    if extra:
        raise SchemaError(f"unknown field 'representation.{sorted(extra)[0]}' (the {h['representation']['name']} "
                          "representation has none)")
    try:
        rep = representation_from_dict(h["representation"])
        if rep.name == "euler":
            from rbgp_cli.geometry.so3 import _parse_order

            _parse_order(rep.order)
        if rep.name == "quaternion" and rep.reference is not None and not 0.5 < np.linalg.norm(rep.reference) < 2:
            raise ValueError("its reference is not a unit quaternion")
    except ValueError as exc:
        raise SchemaError(f"representation = {h['representation']!r} is not valid ({exc})") from None
    if tuple(h["input_names"]) != tuple(rep.input_names):
        _fail(("input_names",), h["input_names"], f"the {rep.name} representation's inputs {list(rep.input_names)}")
    if tuple(h["output_names"]) != tuple(rep.output_names):
        _fail(("output_names",), h["output_names"], f"the {rep.name} representation's outputs {list(rep.output_names)}")
    k = h["kernel"]
    if k["kind"] == "squared_exponential" and "metric" not in k:
        raise SchemaError("kernel.metric is missing")
    try:
        kernel = kernel_from_dict(k)
    except (ValueError, KeyError) as exc:
        raise SchemaError(f"kernel = {k!r} is not valid ({exc})") from None
    if kernel.rotation_dims != rep.rotation_dims:
        _fail(("kernel", "rotation_dims"), k["rotation_dims"], f"{rep.rotation_dims} (the representation's)")
    time_input = h.get("time_input")
    if getattr(kernel, "time_dims", 0) != (1 if time_input else 0):
        _fail(("kernel", "time_dims"), getattr(kernel, "time_dims", 0), f"{1 if time_input else 0} (time input {time_input})")
    n_fits = 1 if h["shared"] else len(h["output_names"])
    if len(h["fits"]) != n_fits:
        raise SchemaError(f"fits has {len(h['fits'])} entries; expected {n_fits} "
                          f"({'shared hyperparameters' if h['shared'] else 'one per output'})")
    need = set(kernel.names) | {"noise_std"}
    for i, f in enumerate(h["fits"]):
        if set(f["values"]) != need:
            raise SchemaError(f"fits[{i}].values has {sorted(f['values'])}; the kernel needs {sorted(need)}")
        if "rho_rot" in f["values"] and not f["values"]["rho_rot"] < 1:
            _fail(("fits", i, "values", "rho_rot"), f["values"]["rho_rot"], "a number strictly between 0 and 1")
    v = h.get("velocity")
    if v is not None and "method" in v and v["method"] != ("local-polynomial" if v["window_s"] > 0 else "forward-differences"):
        _fail(("velocity", "method"), v["method"], f"the method of window_s = {v['window_s']!r}")
    prior = h.get("prior")
    if prior:
        if prior["kind"] == "goal" and "goal" not in prior:
            raise SchemaError("prior.goal is missing")
        if prior["kind"] == "path" and time_input != "phase":
            raise SchemaError(f"prior.kind = 'path' needs the phase as time input, not {time_input!r}")
        if prior["kind"] == "path" and "goal" in prior:
            raise SchemaError("unknown field 'prior.goal' (a path prior has no goal)")
        if prior["kind"] == "goal" and "start" in prior:
            raise SchemaError("unknown field 'prior.start' (a goal prior has no start conditioning)")
        if prior.get("gain_profile") and prior.get("start") != "conditioned":
            raise SchemaError("prior.gain_profile needs a start-conditioned path prior (prior.start = 'conditioned')")
        if prior.get("start_reach") and prior.get("start") != "conditioned":
            raise SchemaError("prior.start_reach needs a start-conditioned path prior (prior.start = 'conditioned')")
    for key in ("seen_band_scales", "seen_end_band_scales"):
        sbs = (h.get("paths") or {}).get(key)
        if sbs is None:
            continue
        F = sbs["fractions"]
        if not (len(sbs["rotation"]) == len(F) and len(sbs["position"]) == len(F)):
            raise SchemaError(f"paths.{key} needs as many rotation and position factors as fractions")
        if any(b <= a for a, b in zip(F, F[1:])):
            _fail(("paths", key, "fractions"), F, "increasing fractions")
    start = (h.get("variation") or {}).get("start_surprise")
    if start is not None:
        cov = np.asarray(start["covariance"], dtype=np.float64)
        if not np.allclose(cov, cov.T, rtol=1e-9, atol=0.0) or np.min(np.linalg.eigvalsh(cov)) <= 0.0:
            raise SchemaError("variation.start_surprise.covariance must be a symmetric positive definite 6 × 6 matrix")
        if abs(float(np.linalg.norm(start["quat"])) - 1.0) > 1e-6:
            _fail(("variation", "start_surprise", "quat"), start["quat"], "a unit quaternion")
    sur = (h.get("paths") or {}).get("seen_surprise")
    if sur is not None:
        F = sur["fractions"]
        if len(sur["reference"]) != len(sur["points"]) or any(len(row) != len(F) for row in sur["reference"]):
            raise SchemaError("paths.seen_surprise needs one reference per fraction for each number of seen poses")
        if any(b <= a for a, b in zip(F, F[1:])):
            _fail(("paths", "seen_surprise", "fractions"), F, "increasing fractions")
    gp = h.get("gp") or {"type": "exact"}
    if gp["type"] == "sparse" and "inducing" not in gp:
        raise SchemaError("gp.inducing is missing")
    if gp["type"] == "exact" and "inducing" in gp:
        raise SchemaError("unknown field 'gp.inducing' (an exact GP has no inducing poses)")


# ---------------------------------------------------------------------------------------------- arrays


def expected_arrays(h: dict) -> set:
    """The array names a validated header needs (exactly these are allowed)."""
    req = {"X", "Y", "y_scale", "starts", "durations"}
    if (h.get("gp") or {}).get("type") == "sparse":
        req |= {"Z", "Lm", "LB", "c"}
    if (h.get("prior") or {}).get("kind") == "path":
        req |= {"prior_s", "prior_quat", "prior_position", "prior_velocity"}
        if h["prior"].get("start") == "conditioned":
            req |= {"prior_start_mean", "prior_start_beta"}
        if h["prior"].get("gain_profile"):
            req |= {"prior_gain_profile"}
        if h["prior"].get("start_reach"):
            req |= {"prior_start_reach"}
    if h.get("variation"):
        req |= {"variation_s", "variation_residuals"}
    if h.get("paths"):
        req |= {"paths_s", "paths_quat", "paths_position", "paths_deviations", "paths_log_durations"}
    return req


def _shape(arrays, name, want, what):
    a = arrays[name]
    if a.shape != tuple(want):
        raise SchemaError(f"array {name!r} has shape {a.shape}; expected {what}")


def _finite(arrays, name, positive_values=False):
    a = arrays[name]
    if not np.all(np.isfinite(a)):
        raise SchemaError(f"array {name!r} holds non-finite values")
    if positive_values and not np.all(a > 0):
        raise SchemaError(f"array {name!r} holds values that are not positive")


def validate_arrays(h: dict, arrays: dict) -> None:
    """Every array against the validated header ``h``: present or absent as it says, float64, its
    shape, finite (and positive where it is a scale or a duration)."""
    req = expected_arrays(h)
    for name in sorted(req):
        if name not in arrays:
            raise SchemaError(f"array {name!r} is missing from the model file")
    for name in sorted(set(arrays) - req):
        raise SchemaError(f"array {name!r} does not belong to this model (its header has no use for it)")
    for name, a in arrays.items():
        if a.dtype.kind != "f" or a.dtype.itemsize != 8:
            raise SchemaError(f"array {name!r} has dtype {a.dtype}; expected float64")
    d = len(h["input_names"]) + (1 if h.get("time_input") else 0)
    L = len(h["output_names"])
    X = arrays["X"]
    n = X.shape[0] if X.ndim == 2 else -1
    _shape(arrays, "X", (max(n, 1), d), f"(n, {d}) with n >= 1 (the inputs {h['input_names']}"
           + (" and the time)" if d > len(h["input_names"]) else ")"))
    _shape(arrays, "Y", (n, L), f"({n}, {L}) (a row per row of array 'X', a column per output)")
    _shape(arrays, "y_scale", (L,), f"({L},)")
    starts = arrays["starts"]
    D = starts.shape[0] if starts.ndim == 2 else -1
    _shape(arrays, "starts", (max(D, 1), 7), "(D, 7) with D >= 1 (qx, qy, qz, qw, x, y, z)")
    _shape(arrays, "durations", (D,), f"({D},) (one per row of array 'starts')")
    for name in ("X", "Y", "starts"):
        _finite(arrays, name)
    for name in ("y_scale", "durations"):
        _finite(arrays, name, positive_values=True)
    qn = np.linalg.norm(starts[:, :4], axis=1)
    if not np.all((qn > 0.5) & (qn < 2)):
        raise SchemaError("array 'starts' holds start orientations that are not unit quaternions")
    if float(np.max(arrays["durations"])) / h["dt"] > MAX_STEPS:
        raise SchemaError(f"array 'durations' holds a duration of more than {MAX_STEPS:g} time steps of {h['dt']:g} s")
    if "prior_s" in req:
        S = arrays["prior_s"].shape[0] if arrays["prior_s"].ndim == 1 else -1
        _shape(arrays, "prior_s", (max(S, 2),), "(S,) with S >= 2")
        _shape(arrays, "prior_quat", (S, 4), f"({S}, 4) (a row per entry of array 'prior_s')")
        _shape(arrays, "prior_position", (S, 3), f"({S}, 3) (a row per entry of array 'prior_s')")
        _shape(arrays, "prior_velocity", (S - 1, 6), f"({S - 1}, 6) (a row per step of array 'prior_s')")
        for name in ("prior_s", "prior_quat", "prior_position", "prior_velocity"):
            _finite(arrays, name)
        if "prior_start_mean" in req:
            _shape(arrays, "prior_start_mean", (S, 6), f"({S}, 6) (a row per entry of array 'prior_s')")
            _finite(arrays, "prior_start_mean")
        if "prior_start_beta" in req:  # the map B(s) (S, 6, 6), or per-coordinate slopes (S, 6) of 0.x files
            beta = arrays["prior_start_beta"]
            if beta.ndim == 3:
                _shape(arrays, "prior_start_beta", (S, 6, 6), f"({S}, 6, 6) (a matrix per entry of array 'prior_s')")
            else:
                _shape(arrays, "prior_start_beta", (S, 6), f"({S}, 6) or ({S}, 6, 6) (per entry of array 'prior_s')")
            _finite(arrays, "prior_start_beta")
        if "prior_gain_profile" in req:
            _shape(arrays, "prior_gain_profile", (S, 6), f"({S}, 6) (a row per entry of array 'prior_s')")
            _finite(arrays, "prior_gain_profile")
            if not np.all(arrays["prior_gain_profile"] >= 0):
                raise SchemaError("array 'prior_gain_profile' holds negative gains")
        if "prior_start_reach" in req:
            _shape(arrays, "prior_start_reach", (S, 2), f"({S}, 2) (a row per entry of array 'prior_s')")
            _finite(arrays, "prior_start_reach")
            if not np.all(arrays["prior_start_reach"] >= 0):
                raise SchemaError("array 'prior_start_reach' holds negative distances")
        if not np.all(np.diff(arrays["prior_s"]) > 0):
            raise SchemaError("array 'prior_s' is not increasing")
    if "variation_s" in req:
        D, S = h["variation"]["demos"], h["variation"]["steps"]
        _shape(arrays, "variation_s", (S,), f"({S},) (variation.steps)")
        _shape(arrays, "variation_residuals", (D, S, 6), f"({D}, {S}, 6) (variation.demos, variation.steps)")
        for name in ("variation_s", "variation_residuals"):
            _finite(arrays, name)
        s = arrays["variation_s"]
        if not (np.all(np.diff(s) > 0) and s[0] == 0.0 and s[-1] == 1.0):
            raise SchemaError("array 'variation_s' is not an increasing grid from 0 to 1")
    if "paths_s" in req:
        D, S = h["paths"]["demos"], h["paths"]["steps"]
        for name, shape in (("paths_s", (S,)), ("paths_quat", (S, 4)), ("paths_position", (S, 3)),
                            ("paths_deviations", (D, S, 6)), ("paths_log_durations", (D,))):
            _shape(arrays, name, shape, f"{shape} (paths.demos, paths.steps)")
            _finite(arrays, name)
        s = arrays["paths_s"]
        if not (np.all(np.diff(s) > 0) and s[0] == 0.0 and s[-1] == 1.0):
            raise SchemaError("array 'paths_s' is not an increasing grid from 0 to 1")
    if "Z" in req:
        G = len(h["fits"])
        Z = arrays["Z"]
        M = Z.shape[0] if Z.ndim == 2 else -1
        if M != h["gp"]["inducing"]:
            raise SchemaError(f"array 'Z' has shape {Z.shape}; expected ({h['gp']['inducing']}, {d}) (gp.inducing)")
        _shape(arrays, "Z", (M, d), f"({M}, {d})")
        _shape(arrays, "Lm", (G, M, M), f"({G}, {M}, {M})")
        _shape(arrays, "LB", (G, M, M), f"({G}, {M}, {M})")
        _shape(arrays, "c", (M, L), f"({M}, {L})")
        for name in ("Z", "Lm", "LB", "c"):
            _finite(arrays, name)
