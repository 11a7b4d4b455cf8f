"""Write trajectories: rbgp's own trajectory CSV, and the vendor layouts QTM 6D TSV, Motive CSV and
Vicon CSV.

Used by the reader round-trip tests and by users who want to hand rbgp's data (demonstrations or
generated motions) to vendor tools. Each writer takes several :class:`Trajectory` objects (one per
body) that share the same times, writes floats with ``repr`` (shortest text that reads back to the
same double, so a round trip is exact up to the unit and rotation conversions, ~1e-15; Euler angles
are the exception within ~1e-5 deg of gimbal lock, where scipy's ``as_euler`` loses up to ~1e-8),
writes lost frames (rows with any NaN) the way the vendor does, and writes atomically
(:func:`rbgp_cli.io.atomic.atomic_open`). The layouts are the ones :mod:`rbgp_cli.io.qtm`,
:mod:`rbgp_cli.io.motive` and :mod:`rbgp_cli.io.vicon` read; see those modules for the format facts.

Inputs follow rbgp's conventions: t in seconds, quaternions x, y, z, w (body -> world), positions in
metres. Euler sequences use scipy notation (upper case = intrinsic).
"""

from __future__ import annotations

import csv
import os
import warnings

import numpy as np

from rbgp_cli.errors import InputError
from rbgp_cli.io.atomic import atomic_open
from rbgp_cli.io.vocabulary import LENGTH_UNITS

__all__ = ["write_trajectories_csv", "write_qtm_tsv", "write_motive_csv", "write_vicon_csv", "MOTIVE_UNITS",
           "WRITE_COLUMNS"]

#: Motive's ``Length Units`` names and rbgp's short names, both accepted by :func:`write_motive_csv`.
MOTIVE_UNITS = {"Meters": "m", "Centimeters": "cm", "Millimeters": "mm"}
_QTM_ANGLE_NAMES = {"X": "Roll", "Y": "Pitch", "Z": "Yaw"}


def _num(x) -> str:
    return repr(float(x))


def _rate_text(rate: float) -> str:
    return str(int(rate)) if float(rate).is_integer() else repr(float(rate))


def _common(trajectories, rate=None):
    """(t, trajectories, names, rate, lost masks); checks the bodies share their times. ``rate`` (Hz)
    is the one given, else 1 / median time step (rounded to an integer within 1e-6), else None."""
    trajs = list(trajectories)
    if not trajs:
        raise InputError("nothing to write: no trajectories")
    t = trajs[0].t
    for tr in trajs[1:]:
        if len(tr.t) != len(t) or not np.array_equal(tr.t, t):
            raise InputError(f"all bodies must share the same times to be written to one file ({tr.name!r} differs)",
                             hint="resample them onto common times first")
    names = [tr.name or f"body{k + 1}" for k, tr in enumerate(trajs)]
    if len(set(names)) != len(names):
        raise InputError(f"body names must be distinct, got {names}")
    if rate is not None:
        if not rate > 0:
            raise ValueError(f"rate must be positive, got {rate!r}")
        return t, trajs, names, float(rate), _lost_rows(trajs)
    if len(t) > 1:
        dt = np.median(np.diff(t))
        if dt > 0:
            rate = 1.0 / dt
            if abs(rate - round(rate)) < 1e-6 * rate:
                rate = float(round(rate))
    return t, trajs, names, rate, _lost_rows(trajs)


def _lost_rows(trajs):
    return [~(np.all(np.isfinite(tr.quat), axis=1) & np.all(np.isfinite(tr.position), axis=1)) for tr in trajs]


def _frame_numbers(t, rate, what: str) -> np.ndarray:
    """Frame numbers (from 1) for times that are ``(frame - 1) / rate``; InputError otherwise."""
    if rate is None:
        raise InputError(f"{what} stores frame numbers and a rate, which the times do not define "
                         "(one frame, or times not increasing)", hint="pass rate=HZ")
    k = np.round(t * rate)
    if np.max(np.abs(k / rate - t)) > 1e-9 * max(1.0, float(np.max(np.abs(t)))):
        raise InputError(f"{what} stores frame numbers: the times must be multiples of 1/rate "
                         f"(rate {rate:g} Hz)", hint="resample onto a uniform grid starting at a multiple of 1/rate")
    return k.astype(np.int64) + 1


def _euler(quat, seq, rotation):
    with warnings.catch_warnings():  # "gimbal lock detected": the angles still represent the rotation
        warnings.simplefilter("ignore", UserWarning)
        return rotation.from_quat(quat).as_euler(seq, degrees=True)


def _valid_rot(quat, lost, fn, width):
    out = np.zeros((len(quat), width))
    if np.any(~lost):
        out[~lost] = fn(quat[~lost])
    return out


def write_qtm_tsv(trajectories, path, *, length_unit: str = "mm", layout: str = "current", euler: str = "XYZ",
                  lost: str = "zeros", rate: float | None = None) -> None:
    """Write a QTM 6DOF TSV export.

    Parameters
    ----------
    trajectories : iterable of Trajectory
        One per body, same times (seconds). Quaternions x, y, z, w; positions in metres.
    path : path-like
        Destination (written atomically).
    length_unit : {"mm", "cm", "m"}
        Unit of the X, Y, Z columns (QTM writes mm; the file does not state it, so a reader needs
        ``length_unit`` for anything else).
    layout : {"current", "old"}
        ``current``: ``FILE_VERSION 2.0.0`` and ``Frame Time <Body> X Y Z <angles> Residual Rot[0..8]``;
        ``old`` (2010): no Frame/Time columns (times must be ``k / rate`` from 0), one anonymous block
        header, an empty column after every body, CRLF line ends.
    euler : str
        Intrinsic sequence of the three angle columns (Roll = X, Pitch = Y, Yaw = Z), in column
        order: ``XYZ`` writes ``Roll Pitch Yaw`` (QTM's default), ``ZYX`` writes ``Yaw Pitch Roll``.
    lost : {"zeros", "null", "empty"}
        How lost frames are written: QTM's zeros with Residual -1, or ``null`` / empty cells.
    rate : float, optional
        FREQUENCY in Hz; default 1 / the median time step (``EXT`` for one frame in the current layout).
    """
    from scipy.spatial.transform import Rotation

    if layout not in ("current", "old"):
        raise ValueError(f"layout must be 'current' or 'old', got {layout!r}")
    if len(euler) != 3 or set(euler) != {"X", "Y", "Z"}:
        raise ValueError(f"euler must be an intrinsic sequence of X, Y, Z (e.g. 'XYZ'), got {euler!r}")
    if lost not in ("zeros", "null", "empty"):
        raise ValueError(f"lost must be 'zeros', 'null' or 'empty', got {lost!r}")
    scale = 1.0 / LENGTH_UNITS[length_unit]
    t, trajs, names, rate, lost_rows = _common(trajectories, rate)
    if layout == "old":
        frames = _frame_numbers(t, rate, "the old QTM layout")
        if frames[0] != 1:
            raise InputError("the old QTM layout has no Time column, so the times must start at 0")
    else:
        frames = np.arange(1, len(t) + 1)
    angle_names = [_QTM_ANGLE_NAMES[a] for a in euler]
    fields = ["X", "Y", "Z", *angle_names, "Residual", *(f"Rot[{k}]" for k in range(9))]

    blocks = []  # per body: (N, 16) strings
    for tr, gone in zip(trajs, lost_rows):
        m = _valid_rot(tr.quat, gone, lambda q: Rotation.from_quat(q).as_matrix().transpose(0, 2, 1).reshape(-1, 9), 9)
        ang = _valid_rot(tr.quat, gone, lambda q: _euler(q, euler, Rotation), 3)
        pos = np.where(gone[:, None], 0.0, tr.position) * scale
        residual = np.where(gone, -1.0, 0.0)
        values = np.concatenate([pos, ang, residual[:, None], m], axis=1)
        text = [[_num(v) for v in row] for row in values]
        if lost != "zeros":
            token = "null" if lost == "null" else ""
            for i in np.flatnonzero(gone):
                text[i] = [token] * len(fields)
        blocks.append(text)

    header = [] if layout == "old" else [["FILE_VERSION", "2.0.0"]]
    header += [
        ["NO_OF_FRAMES", str(len(t))],
        ["NO_OF_CAMERAS", "0"],
        ["NO_OF_BODIES", str(len(trajs))],
        ["FREQUENCY", _rate_text(rate) if rate else "EXT"],
        ["NO_OF_ANALOG", "0"],
        ["ANALOG_FREQUENCY", "0"],
        ["DESCRIPTION", "--"],
        ["TIME_STAMP", "2000-01-01, 00:00:00", "0.0"],
        ["DATA_INCLUDED", "6D"],
        ["BODY_NAMES", *names],
    ]
    newline = "\r\n" if layout == "old" else "\n"
    with atomic_open(path, "w", encoding="utf-8", newline="") as fh:
        for row in header:
            fh.write("\t".join(row) + newline)
        if layout == "old":
            fh.write("\t".join(" " + f for f in fields) + newline)
            for i in range(len(t)):
                fh.write("\t".join(c for b in blocks for c in [*b[i], ""]) + newline)  # empty column after each body
        else:
            cols = ["Frame", "Time"] + [c for name in names for c in [f"{name} X", *fields[1:]]]
            fh.write("\t".join(cols) + "\t" + newline)
            for i in range(len(t)):
                fh.write(f"{frames[i]}\t{_num(t[i])}\t" + "".join("\t".join(b[i]) + "\t" for b in blocks) + newline)


def write_motive_csv(trajectories, path, *, rotation_type: str = "Quaternion", length_unit: str = "Meters",
                     header_labels: bool = True, rate: float | None = None) -> None:
    """Write a Motive CSV export (format 1.23 with labelled header rows, or 1.22 without).

    Parameters
    ----------
    trajectories : iterable of Trajectory
        One rigid body each, same times (seconds). Quaternions x, y, z, w; positions in metres.
    rotation_type : str
        ``Quaternion`` (columns X, Y, Z, W) or a Motive Euler order (``XYZ``, ``ZYX``, ...): relative
        (intrinsic) angles in degrees, written in columns labelled X, Y, Z by axis.
    length_unit : str
        ``Meters``/``Centimeters``/``Millimeters`` (or ``m``/``cm``/``mm``).
    header_labels : bool
        Write the ``Type``/``Name``/``ID`` labels in column 2 (1.23+); False writes them blank (1.22).
    rate : float, optional
        Capture/Export Frame Rate in Hz; default 1 / the median time step (the Time column is exact).

    Lost frames are written as blank cells, as Motive does.
    """
    from scipy.spatial.transform import Rotation

    unit = MOTIVE_UNITS.get(length_unit, length_unit)
    if unit not in LENGTH_UNITS:
        raise ValueError(f"length_unit must be one of {list(MOTIVE_UNITS)}, got {length_unit!r}")
    unit_name = {v: k for k, v in MOTIVE_UNITS.items()}[unit]
    euler = rotation_type.upper() if rotation_type != "Quaternion" else None
    if euler is not None and (len(euler) != 3 or set(euler) != {"X", "Y", "Z"}):
        raise ValueError(f"rotation_type must be 'Quaternion' or an order such as 'XYZ', got {rotation_type!r}")
    t, trajs, names, rate, lost_rows = _common(trajectories, rate)
    scale = 1.0 / LENGTH_UNITS[unit]
    rot_axes = ["X", "Y", "Z"] if euler else ["X", "Y", "Z", "W"]
    width = len(rot_axes) + 3

    rate_text = _rate_text(rate) if rate else "0"
    first = ["Format Version", "1.23" if header_labels else "1.22", "Take Name", "rbgp export",
             "Capture Frame Rate", rate_text, "Export Frame Rate", rate_text,
             "Capture Start Time", "2000-01-01 12.00.00.000 AM", "Total Frames in Take", str(len(t)),
             "Total Exported Frames", str(len(t)), "Rotation Type", euler or "Quaternion",
             "Length Units", unit_name, "Coordinate Space", "Global"]
    label = (lambda s: s) if header_labels else (lambda s: "")
    rows = [
        first,
        [],
        ["", label("Type")] + ["Rigid Body"] * (width * len(trajs)),
        ["", label("Name")] + [n for n in names for _ in range(width)],
        ["", label("ID")] + [str(k + 1) for k in range(len(trajs)) for _ in range(width)],
        ["", ""] + (["Rotation"] * len(rot_axes) + ["Position"] * 3) * len(trajs),
        ["Frame", "Time (Seconds)"] + (rot_axes + ["X", "Y", "Z"]) * len(trajs),
    ]
    cells = []
    for tr, gone in zip(trajs, lost_rows):
        if euler:
            ang = _valid_rot(tr.quat, gone, lambda q: _euler(q, euler, Rotation), 3)
            rot = ang[:, [euler.index(a) for a in "XYZ"]]  # columns by axis label
        else:
            rot = tr.quat
        values = np.concatenate([rot, tr.position * scale], axis=1)
        text = [[_num(v) for v in row] for row in values]
        for i in np.flatnonzero(gone):
            text[i] = [""] * width
        cells.append(text)
    with atomic_open(path, "w", encoding="utf-8", newline="") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerows(rows)
        for i in range(len(t)):
            w.writerow([str(i), _num(t[i])] + [c for body in cells for c in body[i]])


def write_vicon_csv(trajectories, path, *, delimiter: str = ",", rotation: str = "helical",
                    euler_order: str | None = None, length_unit: str = "mm", decimal_comma: bool = False,
                    rate: float | None = None) -> None:
    """Write the Segments section of a Vicon Nexus CSV export.

    Parameters
    ----------
    trajectories : iterable of Trajectory
        One segment each (names like ``Subject:Segment``), same times ``(frame - 1) / rate``.
    delimiter : {",", ";", "\\t"}
    rotation : {"helical", "euler"}
        RX, RY, RZ as the rotation vector θ·u in degrees (Vicon's helical angles), or as Euler
        angles in degrees of ``euler_order`` (scipy notation), each in the column of its axis.
    length_unit : {"mm", "cm", "m"}
        Unit of TX, TY, TZ, stated in the units line.
    decimal_comma : bool
        Write ``1,5`` for 1.5 (only with ``delimiter=";"``, as in some locales).
    rate : float, optional
        The rate line in Hz; default 1 / the median time step (required for a single frame).

    Lost frames are written as blank cells.
    """
    from scipy.spatial.transform import Rotation

    if delimiter not in (",", ";", "\t"):
        raise ValueError(f"delimiter must be ',', ';' or a tab, got {delimiter!r}")
    if decimal_comma and delimiter != ";":
        raise ValueError("decimal_comma needs delimiter ';'")
    if rotation not in ("helical", "euler") or (rotation == "euler" and not euler_order):
        raise ValueError("rotation must be 'helical', or 'euler' with euler_order")
    scale = 1.0 / LENGTH_UNITS[length_unit]
    t, trajs, names, rate, lost_rows = _common(trajectories, rate)
    frames = _frame_numbers(t, rate, "a Vicon CSV")
    cells = []
    for tr, gone in zip(trajs, lost_rows):
        if rotation == "helical":
            rot = _valid_rot(tr.quat, gone, lambda q: np.rad2deg(Rotation.from_quat(q).as_rotvec()), 3)
        else:
            ang = _valid_rot(tr.quat, gone, lambda q: _euler(q, euler_order, Rotation), 3)
            rot = ang[:, [euler_order.upper().index(a) for a in "XYZ"]]
        values = np.concatenate([rot, tr.position * scale], axis=1)
        text = [[_num(v) for v in row] for row in values]
        if decimal_comma:
            text = [[c.replace(".", ",") for c in row] for row in text]
        for i in np.flatnonzero(gone):
            text[i] = [""] * 6
        cells.append(text)
    rows = [
        ["Segments"],
        [_rate_text(rate) if rate else ""],
        ["", ""] + [c for n in names for c in [n, "", "", "", "", ""]],
        ["Frame", "Sub Frame"] + ["RX", "RY", "RZ", "TX", "TY", "TZ"] * len(trajs),
        ["", ""] + ["deg", "deg", "deg", length_unit, length_unit, length_unit] * len(trajs),
    ]
    with atomic_open(path, "w", encoding="utf-8", newline="") as fh:
        w = csv.writer(fh, delimiter=delimiter, lineterminator="\n")
        w.writerows(rows)
        for i in range(len(t)):
            w.writerow([str(frames[i]), "0"] + [c for body in cells for c in body[i]])
        fh.write("\n")


# --------------------------------------------------------------------------------------------------
# rbgp's trajectory CSV (read back by rbgp_cli.io.csv)

WRITE_COLUMNS = ("trajectory", "t", "x", "y", "z", "qx", "qy", "qz", "qw")


def _extra_columns(extra, trajectories) -> list[tuple[str, np.ndarray]]:
    lengths = [len(tr) for tr in trajectories]
    total = sum(lengths)
    out = []
    for name, value in (extra or {}).items():
        if isinstance(value, (list, tuple)) and len(value) == len(trajectories) and all(
            np.ndim(v) >= 1 and len(v) == n for v, n in zip(value, lengths)
        ):
            arr = np.concatenate([np.asarray(v, dtype=np.float64).reshape(len(v), -1) for v in value], axis=0)
        else:
            arr = np.asarray(value, dtype=np.float64)
            arr = arr.reshape(len(arr), -1) if arr.ndim else arr.reshape(1, 1)
        if arr.shape[0] != total:
            raise ValueError(f"extra column {name!r} has {arr.shape[0]} rows, the trajectories have {total}")
        if arr.shape[1] == 1:
            out.append((str(name), arr[:, 0]))
        else:
            out.extend((f"{name}_{j}", arr[:, j]) for j in range(arr.shape[1]))
    return out


def _write(trajectories, fh, extra) -> None:
    extras = _extra_columns(extra, trajectories)
    fh.write("# rbgp trajectories: time_unit=s length_unit=m quaternion=xyzw\n")
    w = csv.writer(fh, lineterminator="\n")
    w.writerow(list(WRITE_COLUMNS) + [n for n, _ in extras])
    offset = 0
    fmt = float.__repr__
    used: set = set()
    for k, tr in enumerate(trajectories):
        label = (tr.name or "").strip() or str(k)
        if label in used:  # the column splits the trajectories again, so names must be unique
            label = f"{label}#{k}"
        used.add(label)
        # always quoted, so that a name starting with '#' is not read back as a comment
        name = '"' + label.replace('"', '""') + '"'
        block = np.concatenate([tr.t[:, None], tr.position, tr.quat], axis=1)
        n = len(tr)
        if extras:
            block = np.concatenate([block, np.stack([a[offset : offset + n] for _, a in extras], axis=1)], axis=1)
        fh.writelines(name + "," + ",".join(map(fmt, row)) + "\n" for row in block.tolist())
        offset += n


def write_trajectories_csv(trajectories, stream_or_path, extra: dict | None = None) -> None:
    """Write trajectories as ``trajectory,t,x,y,z,qx,qy,qz,qw[,extra...]``.

    Floats are written with ``repr`` (shortest text that reads back to the same float64), so
    :func:`rbgp_cli.io.csv.read` returns identical arrays; the ``trajectory`` column holds each
    trajectory's name (its index when empty; a repeated name gets ``#<index>`` appended) and splits
    them again on reading. A first comment line states the units (``time_unit=s length_unit=m
    quaternion=xyzw``), which the reader honours.

    Parameters
    ----------
    trajectories : sequence of Trajectory
        Seconds, metres, quaternions x, y, z, w.
    stream_or_path : text stream, str or Path
        A path is written atomically (whole file or nothing).
    extra : dict of name -> array, optional
        Extra columns, each a 1-D array with one value per written row (all trajectories one after
        the other), a (rows, k) array (written as ``name_0..name_{k-1}``) or a list of per-trajectory
        arrays; e.g. ``{"std_wx": ..., ..., "std_vz": ...}``.
    """
    trajectories = list(trajectories)
    if isinstance(stream_or_path, (str, os.PathLike)):
        with atomic_open(stream_or_path, "w", newline="", encoding="utf-8") as fh:
            _write(trajectories, fh, extra)
    else:
        _write(trajectories, stream_or_path, extra)
