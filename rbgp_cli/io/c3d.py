"""C3D files (Vicon Nexus, QTM, Motive, Optotrak, ART, Visual3D) -> raw :class:`~rbgp_cli.dynamics.trajectory.Trajectory`.

C3D stores 3D **markers** (the POINT group), not rigid bodies; some systems also store 6-DOF segment
poses in C-Motion's ``ROTATION`` group. The file is read with ezc3d (a maintained C3D library; why
this one: docs/data.md), never by a parser of ours. What is taken from it, following the C3D
specification:

* Points: ``POINT:LABELS``, coordinates in ``POINT:UNITS`` (``mm``, ``cm``, ``m``; ``length_unit``
  overrides), already scaled by ``POINT:SCALE`` (a negative scale means float storage; ezc3d applies
  it either way). A point is lost in a frame when its residual word is negative (-1: the coordinates
  are then ignored, also in files that keep interpolated coordinates there; ezc3d gives NaN), and
  also when its three coordinates are exactly zero (writers that mark a lost point that way).
* Time: frame ``k`` of the file (1-based, counting from the header's first frame, which need not be
  1) is at ``t = (k - 1) / POINT:RATE`` seconds, the clock that ``EVENT:TIMES`` (minutes, seconds) uses.
  Events go into ``info["events"]`` as ``[context, label, seconds]``.
* A rigid body is either a stored 6-DOF body (``ROTATION:LABELS``; 4×4 matrices body -> world, their
  translation in ``POINT:UNITS``, at ``POINT:RATE × ROTATION:RATIO``) or a cluster of three or more
  markers (:mod:`rbgp_cli.io.markers`): found by its distances, named by its label prefix
  (``body="boite"``), or named by its markers (``body="RTH1,RTH2,RTH3"``). Its pose per frame is the
  least-squares rigid fit of its reference shape to the markers seen (at least three, not on a line);
  frames with fewer, or whose fit leaves more than :data:`~rbgp_cli.io.markers.FIT_RMS_TOL_M` RMS, are
  lost frames (NaN rows). The body frame of a cluster: origin at its markers' centroid, axes those of
  the lab in the first frame where every marker is seen and fits its shape
  (:func:`~rbgp_cli.io.markers.reference_shape`).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np

from rbgp_cli.dynamics.trajectory import Trajectory
from rbgp_cli.errors import InputError, NotPoseData, closest, warn
from rbgp_cli.io import markers as mk
from rbgp_cli.io.formats import Format
from rbgp_cli.io.options import ReadOptions
from rbgp_cli.io.vendor import metres_per, reader_guard

__all__ = ["detect", "read", "describe", "describe_rows", "FORMAT", "load"]

_HINT = "export the trial again as C3D (the file may be truncated or not a C3D file)"
_BODY_HINT = "use body NAME (a stored 6-DOF segment or a cluster) or body 'A,B,C' (three or more markers)"
_INTEL, _DEC, _MIPS = 84, 85, 86


def detect(head: bytes) -> bool:
    """A C3D file: byte 2 of the header is 0x50, and the parameter section that byte 1 points to
    (512-byte blocks) names a processor type 84 (Intel), 85 (DEC) or 86 (MIPS) in its 4th byte."""
    if len(head) < 2 or head[1] != 0x50 or head[0] < 2:
        return False
    at = (head[0] - 1) * 512 + 3
    return at >= len(head) or head[at] in (_INTEL, _DEC, _MIPS)


def _skip_reason(head: bytes, path=None, options=None, complete: bool = False) -> str | None:
    return None if detect(head) else "not a C3D file"  # rigid bodies or not: reading decides


@dataclass
class Take:
    """What one C3D file holds, in SI units.

    ``points`` (F, n, 3) metres, NaN rows for lost points; ``labels`` (n,); ``rate_hz``; ``first_frame``
    (1-based); ``unit`` (the file's POINT:UNITS or the option) and where it came from; ``events``
    ``[context, label, seconds]``; ``bodies`` the ROTATION labels and ``rotations`` (F_r, m, 4, 4)
    (translation in metres, NaN where lost) at ``rotation_rate_hz``.
    """

    path: str
    labels: list
    points: np.ndarray
    rate_hz: float
    first_frame: int
    unit: str
    unit_source: str
    scale: float | None
    events: list = field(default_factory=list)
    bodies: list = field(default_factory=list)
    rotations: np.ndarray | None = None
    rotation_rate_hz: float | None = None
    analog_channels: int = 0
    _clusters: list | None = None

    @property
    def times(self) -> np.ndarray:
        """``(k - 1) / rate`` for the file's frames k = first_frame, first_frame + 1, ..."""
        return (self.first_frame - 1 + np.arange(len(self.points))) / self.rate_hz

    def clusters(self) -> list:
        """The rigid clusters :func:`rbgp_cli.io.markers.find_clusters` finds (computed once)."""
        if self._clusters is None:
            self._clusters = mk.find_clusters(self.points, self.labels)
        return self._clusters


def _value(params, group: str, name: str, default=None):
    try:
        v = params[group][name]["value"]
    except (KeyError, TypeError):
        return default
    return v


def _first(v, default=None):
    if v is None:
        return default
    try:
        return v[0] if len(v) else default
    except TypeError:
        return v


def _events(params) -> list:
    used = int(_first(_value(params, "EVENT", "USED"), 0) or 0)
    if not used:
        return []
    labels = list(_value(params, "EVENT", "LABELS", []) or [])
    contexts = list(_value(params, "EVENT", "CONTEXTS", []) or [])
    times = np.asarray(_value(params, "EVENT", "TIMES", np.zeros((2, 0))), float).reshape(2, -1)
    out = []
    for k in range(min(used, times.shape[1])):
        seconds = float(60.0 * times[0, k] + times[1, k])  # EVENT:TIMES is (minutes, seconds)
        out.append([str(contexts[k]).strip() if k < len(contexts) else "",
                    str(labels[k]).strip() if k < len(labels) else f"event{k + 1}", seconds])
    return sorted(out, key=lambda e: e[2])


_cache: dict = {}


def load(path, options: ReadOptions | None = None) -> Take:
    """Read a C3D file with ezc3d into a :class:`Take` (InputError for anything it cannot read: not
    C3D, truncated, unknown units)."""
    options = options or ReadOptions()
    path = str(path)
    try:
        st = os.stat(path)
    except OSError as exc:
        raise InputError(f"cannot read the file ({exc.strerror or exc})", path=path) from None
    key = (os.path.abspath(path), st.st_mtime_ns, st.st_size, options.length_unit)
    if key in _cache:
        return _cache[key]
    take = _load(path, options, st.st_size)
    _cache.clear()  # one file at a time: describe, then read, of the same file
    _cache[key] = take
    return take


def _announced_frames(fh, head: bytes) -> int | None:
    """The number of frames the file's 512-byte header announces (words 4 and 5: first and last frame,
    in the byte order of the processor type its parameter section names), or None when it cannot say
    (a last frame of 65535: longer trials keep the real count in TRIAL:ACTUAL_END_FIELD). ezc3d reads
    a truncated file's frames without complaint and rewrites the count, so this is how truncation shows."""
    if len(head) < 10 or head[0] < 2:
        return None
    fh.seek((head[0] - 1) * 512 + 3)
    proc = fh.read(1)
    order = "big" if proc and proc[0] == _MIPS else "little"
    first = int.from_bytes(head[6:8], order)
    last = int.from_bytes(head[8:10], order)
    if last >= 65535 or last < first:
        return None
    return last - first + 1


def _actual_fields(params) -> tuple[int, int] | None:
    """``(first, last)`` frame from ``TRIAL:ACTUAL_START_FIELD`` / ``ACTUAL_END_FIELD`` (each two
    16-bit words, low then high: Vicon's record of frame numbers past the header's 65535), or None."""
    def field(name):
        v = _value(params, "TRIAL", name)
        if v is None or len(v) < 2:
            return None
        return (int(v[0]) & 0xFFFF) + ((int(v[1]) & 0xFFFF) << 16)

    first, last = field("ACTUAL_START_FIELD"), field("ACTUAL_END_FIELD")
    return (first, last) if first is not None and last is not None and last >= first >= 1 else None


#: The parameter groups taken from the file (everything else, e.g. FORCE_PLATFORM, is left).
_GROUPS = ("POINT", "EVENT", "ROTATION", "TRIAL")
#: The reading process may use this many bytes of memory beyond its start, or this many times the file's
#: size if more: a damaged header that announces a huge array ends the reading, not the machine.
_MEMORY_FLOOR, _MEMORY_PER_BYTE = 2 << 30, 40


def _ezc3d_contents(path: str) -> dict:
    """What rbgp takes from ``ezc3d.c3d(path)``, as plain data: the parameter groups of
    :data:`_GROUPS` (``{group: {name: {"value": v}}}``), the header's first frame (0-based) and rate,
    the points (4, n, F), residuals (1, n, F), the number of analog channels and the rotations
    (4, 4, m, F_r)."""
    import ezc3d  # heavy (a compiled extension): only when a C3D file is read

    c = ezc3d.c3d(path)
    params = {g: {k: {"value": v["value"]} for k, v in c["parameters"][g].items() if isinstance(v, dict) and "value" in v}
              for g in _GROUPS if g in c["parameters"]}
    analogs = np.asarray(c["data"]["analogs"])
    rot = c["data"]["rotations"] if "rotations" in c["data"] else None
    return {"parameters": params, "header": dict(c["header"]["points"]),
            "points": np.asarray(c["data"]["points"], float),
            "residuals": np.asarray(c["data"]["meta_points"]["residuals"], float),
            "analog_channels": int(analogs.shape[1]) if analogs.ndim == 3 else 0,
            "rotations": None if rot is None else np.asarray(rot, float)}


def _child(path: str, size: int, conn) -> None:
    """In the reading process: limit its memory, read, send ``("ok", contents)`` or ``("error", text)``."""
    import faulthandler

    from rbgp_cli.compute import die_with_parent

    faulthandler.disable()  # a crash here is reported by the parent as an InputError, not as a dump
    die_with_parent()
    try:
        import resource

        with open("/proc/self/statm") as fh:
            now = int(fh.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
        budget = now + max(_MEMORY_FLOOR, _MEMORY_PER_BYTE * size)
        resource.setrlimit(resource.RLIMIT_AS, (budget, resource.getrlimit(resource.RLIMIT_AS)[1]))
    except (ImportError, OSError, ValueError):  # not Linux: no limit
        pass
    try:
        out = ("ok", _ezc3d_contents(path))
    except MemoryError:
        out = ("error", "MemoryError: the file announces more data than it can hold")
    except Exception as exc:  # ezc3d raises RuntimeError, OSError, IndexError ... for a broken file
        out = ("error", f"{type(exc).__name__}: {' '.join(str(exc).split())[:160]}")
    conn.send(out)
    conn.close()


def _read_isolated(path: str, size: int) -> dict:
    """:func:`_ezc3d_contents` in a short-lived process of its own (forked on Linux): ezc3d is C++ and
    ends the process on some damaged files (a segmentation fault), which must become an InputError
    here, never a crash of rbgp."""
    from rbgp_cli.compute import fork_context

    ctx = fork_context()
    receive, send = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_child, args=(path, size, send), name="rbgp-c3d-reader", daemon=True)
    proc.start()
    send.close()
    try:
        status, payload = receive.recv()
    except EOFError:  # the process ended without an answer
        status, payload = None, None
    finally:
        receive.close()
        proc.join(timeout=30)
        if proc.is_alive():  # pragma: no cover - it answered, then hung
            proc.kill()
            proc.join()
    if status == "ok":
        return payload
    if status is None:
        import signal

        code = proc.exitcode
        why = (f"signal {signal.Signals(-code).name}" if code is not None and code < 0 and -code in
               signal.valid_signals() else f"exit code {code}")
        payload = f"the C3D library stopped on it ({why}): the file is damaged"
    raise InputError(f"cannot read this C3D file ({payload})", path=path, hint=_HINT)


def _load(path: str, options: ReadOptions, size: int) -> Take:
    with open(path, "rb") as fh:
        head = fh.read(512)
        announced = _announced_frames(fh, head)
    if not detect(head):
        raise InputError("not a C3D file (its header does not start with a parameter pointer and 0x50)", path=path,
                         hint=_HINT)
    c = _read_isolated(path, size)
    params = c["parameters"]
    hdr = c["header"]
    pts = c["points"]  # (4, n, F)
    labels = [str(s).strip() for s in (_value(params, "POINT", "LABELS", []) or [])]
    n = pts.shape[1] if pts.ndim == 3 else 0
    labels = (labels + [f"point{k + 1}" for k in range(len(labels), n)])[:n]
    got = pts.shape[2] if pts.ndim == 3 else 0
    first_frame = int(hdr["first_frame"]) + 1
    actual = _actual_fields(params)
    if actual is not None and (announced is None or first_frame >= 65535):  # past the header's 16 bits
        first_frame, announced = actual[0], actual[1] - actual[0] + 1
    if announced is not None and got < announced:
        raise InputError(f"the file is truncated: its header announces {announced} frames but it holds {got}",
                         path=path, hint="export or copy the trial again")
    rate = float(_first(_value(params, "POINT", "RATE"), 0.0) or hdr.get("frame_rate") or 0.0)
    if not rate > 0:
        raise InputError("the file states no point rate (POINT:RATE)", path=path, hint=_HINT)
    file_unit = str(_first(_value(params, "POINT", "UNITS"), "") or "").strip().lower()
    unit_aliases = {"millimeters": "mm", "millimetres": "mm", "meters": "m", "metres": "m", "centimeters": "cm"}
    file_unit = unit_aliases.get(file_unit, file_unit)
    if options.length_unit:
        unit, unit_source = options.length_unit, "length_unit"
    elif file_unit:
        unit, unit_source = file_unit, "POINT:UNITS"
    else:
        unit, unit_source = "mm", "assumed: the file has no POINT:UNITS"
        warn("the file states no POINT:UNITS; read as mm", path=path, param="length_unit")
    scale = metres_per(unit, path=path, hint="give the unit with length_unit m|cm|mm")
    xyz = pts[:3].transpose(2, 1, 0) * scale if n else np.zeros((got, 0, 3))  # (F, n, 3)
    res = c["residuals"]
    lost = ~np.all(np.isfinite(xyz), axis=-1) | np.all(xyz == 0.0, axis=-1)
    if res.size:
        lost |= res[0].T < 0
    xyz[lost] = np.nan
    take = Take(path=path, labels=labels, points=xyz, rate_hz=rate, first_frame=first_frame,
                unit=unit, unit_source=unit_source, scale=_first(_value(params, "POINT", "SCALE")),
                events=_events(params))
    take.analog_channels = c["analog_channels"]
    _rotations(take, c["rotations"], params, scale)
    return take


def _rotations(take: Take, rot, params, scale: float) -> None:
    """The stored 6-DOF bodies (ROTATION group; ``rot`` (4, 4, m, F_r) or None) into ``take`` (matrices
    with metres, NaN where lost)."""
    rot = np.asarray(rot, float) if rot is not None else np.zeros((4, 4, 0, 0))
    if rot.ndim != 4 or rot.shape[2] == 0:
        return
    labels = [str(s).strip() for s in (_value(params, "ROTATION", "LABELS", []) or [])]
    m = rot.shape[2]
    take.bodies = (labels + [f"segment{k + 1}" for k in range(len(labels), m)])[:m]
    mats = rot.transpose(3, 2, 0, 1).copy()  # (F_r, m, 4, 4)
    mats[..., :3, 3] *= scale
    r = mats[..., :3, :3]
    lost = ~np.all(np.isfinite(mats), axis=(-1, -2)) | np.all(r == 0.0, axis=(-1, -2))
    ok = ~lost
    if ok.any():
        rr = r[ok]
        err = np.max(np.abs(rr @ rr.transpose(0, 2, 1) - np.eye(3)), axis=(-1, -2))
        bad = (err > 1e-3) | (np.linalg.det(rr) <= 0)
        idx = np.argwhere(ok)[bad]
        lost[tuple(idx.T)] = True
    mats[lost] = np.nan
    take.rotations = mats
    ratio = float(_first(_value(params, "ROTATION", "RATIO"), 1) or 1)
    take.rotation_rate_hz = float(_first(_value(params, "ROTATION", "RATE"), 0.0) or 0.0) or take.rate_hz * ratio


# --------------------------------------------------------------------------------------------------
# which body

@dataclass(frozen=True)
class _Choice:
    name: str
    kind: str  # "stored" or "cluster"
    index: int = -1  # stored: ROTATION index
    markers: tuple = ()  # cluster: point indices
    found: bool = False  # a cluster found by its distances (else named by the user)


def _candidates(take: Take) -> list[_Choice]:
    stored = [_Choice(b, "stored", index=k) for k, b in enumerate(take.bodies)]
    return stored + [_Choice(c.name, "cluster", markers=c.markers, found=True) for c in take.clusters()]


def _match_marker(token: str, labels: list, path: str) -> int:
    tok = token.strip()
    if tok in labels:
        return labels.index(tok)
    for pool in ([lab.lower() for lab in labels], [mk._bare(lab).lower() for lab in labels]):
        hits = [k for k, lab in enumerate(pool) if lab == tok.lower()]
        if len(hits) == 1:
            return hits[0]
        if len(hits) > 1:
            raise InputError(f"marker {tok!r} matches {len(hits)} labels: " + ", ".join(labels[k] for k in hits),
                             path=path, hint="name it with its prefix, e.g. 'Subject:NAME'", param="body")
    guess = closest(tok, labels + [mk._bare(lab) for lab in labels])
    raise InputError(f"no marker labelled {tok!r} (the file has {len(labels)} points)", path=path,
                     hint=(f"did you mean {guess!r}? " if guess else "") + "`rbgp inspect FILE` lists the labels",
                     param="body")


def _by_prefix(name: str, labels: list) -> list[int]:
    """Points whose label prefix is ``name`` (``boite`` for ``boite:*``) or whose name starts with
    ``name`` followed by a non-letter (``RTH`` for RTH1, RTH_2)."""
    low = name.lower()
    out = []
    for k, lab in enumerate(labels):
        if mk.label_prefix(lab).lower() == low:
            out.append(k)
            continue
        bare = mk._bare(lab)
        if bare.lower().startswith(low) and len(bare) > len(low) and not bare[len(low)].isalpha():
            out.append(k)
    return out


def _choose(take: Take, body: str | None) -> list[_Choice]:
    path = take.path
    cands = _candidates(take)
    if body is None or body == "all":
        if not cands:
            raise NotPoseData(
                f"the file holds {len(take.labels)} markers, no stored 6-DOF body and no rigid cluster of 3 or more "
                f"markers (pairwise distance std within {mk.CLUSTER_STD_TOL_M * 1e3:g} mm)", path=path,
                hint="name three or more markers of one rigid object with body 'A,B,C'", param="body",
                reason="C3D markers without a rigid cluster")
        if body == "all" or len(cands) == 1:
            return cands
        raise InputError(f"the file holds {len(cands)} rigid bodies: " + ", ".join(repr(c.name) for c in cands)
                         + "; choose one", path=path, hint="use body NAME, body all, or body 'A,B,C' (markers)",
                         param="body")
    if "," in body:
        idx = [_match_marker(tok, take.labels, path) for tok in body.split(",") if tok.strip()]
        if len(set(idx)) != len(idx):
            raise InputError(f"body {body!r} names a marker twice", path=path, hint=_BODY_HINT, param="body")
        if len(idx) < 3:
            raise InputError(f"a rigid body needs at least 3 markers; body {body!r} names {len(idx)}", path=path,
                             hint=_BODY_HINT, param="body")
        return [_Choice(body, "cluster", markers=tuple(idx))]
    low = body.lower()
    for c in cands:
        if c.name.lower() == low:
            return [c]
    if low in {lab.lower() for lab in take.labels} | {mk._bare(lab).lower() for lab in take.labels}:
        raise InputError(f"{body!r} is one marker; a rigid body needs at least 3", path=path, hint=_BODY_HINT,
                         param="body")
    idx = _by_prefix(body, take.labels)
    if len(idx) >= 3:
        return [_Choice(body, "cluster", markers=tuple(idx))]
    if idx:
        raise InputError(f"only {len(idx)} markers are labelled {body!r} (" + ", ".join(take.labels[k] for k in idx)
                         + "); a rigid body needs at least 3", path=path, hint=_BODY_HINT, param="body")
    names = [c.name for c in cands]
    guess = closest(body, names + take.labels)
    listed = ", ".join(repr(n) for n in names) if names else "none found"
    raise InputError(f"no body, cluster or marker prefix named {body!r}; the rigid bodies are {listed}", path=path,
                     hint=(f"did you mean {guess!r}? " if guess else "") + "`rbgp inspect FILE` lists them; "
                     + _BODY_HINT, param="body")


# --------------------------------------------------------------------------------------------------
# reading

def _read_stored(take: Take, ch: _Choice) -> Trajectory:
    from scipy.spatial.transform import Rotation as R

    from rbgp_cli.io.vendor import quat_from_valid

    mats = take.rotations[:, ch.index]
    lost = ~np.all(np.isfinite(mats), axis=(-1, -2))
    quat = quat_from_valid(~lost, R.from_matrix, mats[:, :3, :3])
    pos = mats[:, :3, 3].copy()
    pos[lost] = np.nan
    rate = take.rotation_rate_hz or take.rate_hz
    ratio = rate / take.rate_hz
    t = (take.first_frame - 1) / take.rate_hz + np.arange(len(mats)) / rate
    info = _info(take, ch, lost, rate) | {"rotation_source": "ROTATION group (stored 6-DOF body, 4x4 matrix)",
                                          "rotation_ratio": ratio}
    return Trajectory(t=t, quat=quat, position=pos, name=ch.name, source=take.path, info=info)


def _read_cluster(take: Take, ch: _Choice) -> Trajectory:
    from scipy.spatial.transform import Rotation as R

    from rbgp_cli.io.vendor import quat_from_valid

    idx = list(ch.markers)
    pts = take.points[:, idx]
    names = [take.labels[k] for k in idx]
    shape, ref_frame, n_ref = mk.reference_shape(pts)
    if ref_frame < 0:
        lost_counts = np.sum(~np.all(np.isfinite(pts), axis=-1), axis=0)
        worst = int(np.argmax(lost_counts))
        raise InputError(f"no frame sees all {len(idx)} markers of body {ch.name!r}, so its shape is unknown",
                         path=take.path, hint=f"leave out the marker lost most often ({names[worst]}, lost in "
                         f"{int(lost_counts[worst])} of {len(pts)} frames) with body 'A,B,C'", param="body")
    std, _ = mk.pair_distance_std(pts)
    max_std = float(np.nanmax(std)) if np.isfinite(std).any() else float("nan")
    if not ch.found and max_std > mk.CLUSTER_STD_TOL_M:
        warn(f"the markers of body {ch.name!r} are not rigid: a pair's distance varies by {max_std * 1e3:.3g} mm std "
             f"(rigid clusters stay within {mk.CLUSTER_STD_TOL_M * 1e3:g} mm); frames whose fit is off by more than "
             f"{mk.FIT_RMS_TOL_M * 1e3:g} mm RMS are lost", path=take.path)
    rot, trans, rms, seen, lost = mk.fit_poses(pts, shape)
    quat = quat_from_valid(~lost, R.from_matrix, rot)
    pos = trans.copy()
    few = seen < 3
    over = ~few & lost
    good = rms[~lost]
    if few.any() or over.any():
        why = [f"{int(few.sum())} with fewer than 3 markers seen (or 3 on a line)" if few.any() else "",
               f"{int(over.sum())} whose fit is off by more than {mk.FIT_RMS_TOL_M * 1e3:g} mm RMS" if over.any() else ""]
        warn(f"body {ch.name!r}: {int(few.sum() + over.sum())} of {len(pts)} frames are lost frames: "
             + ", ".join(w for w in why if w), path=take.path)
    info = _info(take, ch, lost, take.rate_hz) | {
        "rotation_source": f"rigid fit of {len(idx)} markers (Kabsch rotation matrix)",
        "markers": names,
        "body_frame": f"origin at the markers' centroid, axes of the lab at frame {take.first_frame + ref_frame}",
        "reference_frames": n_ref,
        "marker_distance_std_max_m": max_std,
        "fit_rms_median_m": float(np.median(good)) if len(good) else None,
        "fit_rms_max_m": float(np.max(good)) if len(good) else None,
        "fit_rms_tol_m": mk.FIT_RMS_TOL_M,
        "frames_too_few_markers": int(few.sum()),
        "frames_over_tol": int(over.sum()),
        "fit_rms_m": [None if not np.isfinite(x) else round(float(x), 7) for x in rms],
    }
    return Trajectory(t=take.times, quat=quat, position=pos, name=ch.name, source=take.path, info=info)


def _info(take: Take, ch: _Choice, lost, rate) -> dict:
    return {
        "format": "c3d",
        "body": ch.name,
        "body_kind": "stored 6-DOF body" if ch.kind == "stored" else "marker cluster",
        "bodies": [c.name for c in _candidates(take)],
        "length_unit": take.unit,
        "length_unit_source": take.unit_source,
        "rate_hz": rate,
        "first_frame": take.first_frame,
        "time_source": "(frame - 1) / POINT:RATE",
        "lost_frames": int(np.sum(lost)),
        "events": take.events,
    }


@reader_guard("a C3D file", _HINT)
def read(path, options: ReadOptions | None = None) -> list[Trajectory]:
    """Read the chosen rigid bodies of a C3D file (``options.body``: a stored body, a found cluster, a
    label prefix, ``"A,B,C"`` markers, ``"all"``, or None for the only one).

    Returns raw trajectories: t in seconds on the file's clock (``(frame - 1) / rate``), quaternions
    x, y, z, w (body -> world), positions in metres, NaN rows for lost frames; ``info`` holds the fit's
    residuals (``fit_rms_m`` per frame), the markers, units, rate, first frame and events.
    """
    options = options or ReadOptions()
    take = load(path, options)
    out = []
    for ch in _choose(take, options.body):
        out.append(_read_stored(take, ch) if ch.kind == "stored" else _read_cluster(take, ch))
    return out


def _read_all(path, options: ReadOptions | None = None) -> list[Trajectory]:
    """For ``rbgp inspect``: every body unless the options name one (a file with none reads as none)."""
    from dataclasses import replace

    options = options or ReadOptions()
    if options.body is None:
        take = load(path, options)
        return read(path, replace(options, body="all")) if _candidates(take) else []
    return read(path, options)


@reader_guard("a C3D file", _HINT)
def describe(path, options: ReadOptions | None = None) -> dict:
    """Plain data for ``rbgp inspect``: points (label, frames lost), rigid clusters found, stored
    6-DOF bodies, rate, frames, first frame, units, events."""
    options = options or ReadOptions()
    take = load(path, options)
    lost = np.sum(~np.all(np.isfinite(take.points), axis=-1), axis=0)
    return {
        "format": "c3d",
        "frames": int(len(take.points)),
        "rate_hz": take.rate_hz,
        "first_frame": take.first_frame,
        "duration_s": (len(take.points) - 1) / take.rate_hz if len(take.points) else 0.0,
        "length_unit": take.unit,
        "length_unit_source": take.unit_source,
        "point_scale": None if take.scale is None else float(take.scale),
        "points": [{"label": lab, "lost_frames": int(k)} for lab, k in zip(take.labels, lost)],
        "clusters": [{"name": c.name, "markers": list(c.labels), "max_distance_std_m": c.max_std_m,
                      "frames_all_seen": c.frames_all_seen} for c in take.clusters()],
        "cluster_std_tol_m": mk.CLUSTER_STD_TOL_M,
        "fit_rms_tol_m": mk.FIT_RMS_TOL_M,
        "stored_bodies": list(take.bodies),
        "bodies": [c.name for c in _candidates(take)],
        "events": take.events,
        "analog_channels": take.analog_channels,
        "needs": [],
    }


def _needs(desc: dict, options) -> list[str]:
    bodies = desc.get("bodies") or []
    if options.body is None and len(bodies) > 1:
        return [f"body NAME, or all for every body ({len(bodies)} bodies), or 'A,B,C' for markers"]
    if options.body is None and not bodies and desc.get("points"):
        return ["body 'A,B,C' (three or more markers of one rigid object: no cluster was found)"]
    return []


def describe_rows(desc: dict) -> list[str]:
    """The text rows of ``rbgp inspect`` for :func:`describe`'s result."""
    from rbgp_cli.io.inspect import fmt_num, rate_text, text_row

    rows = [text_row("frames", f"{desc['frames']} at {rate_text(desc)} from frame {desc['first_frame']} "
                               f"({fmt_num(desc['duration_s'], ' s')})")]
    scale = desc.get("point_scale")
    storage = "" if scale is None else (f", POINT:SCALE {scale:g} ({'float' if scale < 0 else 'integer'} storage)")
    rows.append(text_row("units", f"{desc['length_unit']} ({desc['length_unit_source']}){storage}"))
    pts = desc.get("points") or []
    lost = [p for p in pts if p["lost_frames"]]
    rows.append(text_row("points", f"{len(pts)}, {len(lost)} lost in some frames: "
                         + ", ".join(f"{p['label']}" + (f" (lost {p['lost_frames']})" if p["lost_frames"] else "")
                                     for p in pts)))
    clusters = desc.get("clusters") or []
    tol = desc.get("cluster_std_tol_m", mk.CLUSTER_STD_TOL_M) * 1e3
    if not clusters:
        rows.append(text_row("clusters", f"none (no 3 markers keep their distances within {tol:g} mm std)"))
    for k, c in enumerate(clusters):
        rows.append(text_row("clusters" if k == 0 else "",
                             f"{c['name']}: {len(c['markers'])} markers ({', '.join(c['markers'])}), distances within "
                             f"{c['max_distance_std_m'] * 1e3:.2g} mm std, all seen in {c['frames_all_seen']} frames"))
    rows.append(text_row("", f"(a cluster: 3 or more markers whose pairwise distances vary by at most {tol:g} mm, "
                             f"robust std, seen together in half of the frames or more)"))
    stored = desc.get("stored_bodies") or []
    rows.append(text_row("6-DOF bodies", ", ".join(stored) if stored else "none stored (no ROTATION group)"))
    events = desc.get("events") or []
    if events:
        rows.append(text_row("events", "; ".join(f"{(c + ' ') if c else ''}{lab} {s:.3f} s" for c, lab, s in events)))
    if desc.get("analog_channels"):
        rows.append(text_row("analog", f"{desc['analog_channels']} channels (not read)"))
    rows.append(text_row("pose fit", f"least-squares rigid fit per frame; frames with fewer than 3 markers seen or "
                                     f"more than {desc.get('fit_rms_tol_m', mk.FIT_RMS_TOL_M) * 1e3:g} mm RMS are lost"))
    return rows


FORMAT = Format(
    name="c3d", title="C3D", detect=detect, read=read, describe=describe, describe_rows=describe_rows,
    skip_reason=_skip_reason, read_all=_read_all, needs=_needs, suffix=".c3d", binary=True,
    honours=("body",),
)
