"""OptiTrack Motive CSV exports (format 1.2x) -> raw :class:`~rbgp_cli.dynamics.trajectory.Trajectory`.

The format (ECOSYSTEM.md §2.2; OptiTrack "Data Export: CSV" documentation; a real 1.22 export)
    * Line 1: alternating ``key,value`` pairs: ``Format Version``, ``Take Name``,
      ``Capture Frame Rate``, ``Export Frame Rate``, ``Capture Start Time``, ``Total Frames in Take``,
      ``Total Exported Frames``, ``Rotation Type`` (``Quaternion`` or an Euler order such as ``XYZ``),
      ``Length Units`` (``Meters``/``Centimeters``/``Millimeters``), ``Coordinate Space``. Older
      exports (1.22) may omit Rotation Type and Length Units.
    * Line 2 blank; then the rows Type, Name, ID, an optional Parent row (labelled ``,Type,`` ... in
      1.23+, unlabelled in 1.22), a row with ``Rotation``/``Position``/``Mean Marker Error``, and the
      axis row ``Frame,Time (Seconds),X,Y,Z,W,X,Y,Z,...`` (1.24+ may add ``TimeCode`` after Time).
    * Only ``Rigid Body`` columns are poses; ``Marker``, ``Rigid Body Marker``, ``Bone`` and
      ``Bone Marker`` columns are ignored. Rigid-body rotation columns are found by their labels:
      ``X,Y,Z,W`` is a quaternion (scalar last, as rbgp); ``X,Y,Z`` are Euler angles in degrees.
    * Occluded or lost frames are blank cells; they become NaN rows.
    * Motive's world is Y-up, right-handed; rbgp keeps the axes as exported.

Euler angles (the decision and its source)
    NaturalPoint's knowledge-base article "Changes in Motive's Reported Euler Angles" states that
    since Motive 1.6 the Euler order is selectable on CSV export and that the angles are *relative*:
    "XYZ means the rigid body is first rotated about the X axis, then the new Y axis and finally the
    new Z axis" (intrinsic), i.e. ``R = Rx(X) · Ry(Y) · Rz(Z)``, scipy ``"XYZ"``. Before 1.6 the
    output was always *global* (extrinsic) YZX, scipy ``"yzx"``. So a ``Rotation Type`` of ``XYZ``
    (or any permutation) is read as the intrinsic scipy sequence of the same letters, and each angle
    is taken from the column labelled with its axis (so column order does not matter). The
    phausamann/rigid-body-motion loader (``qx * qy * qz`` for ``XYZ``) agrees. When the header does
    not state the rotation type, ``euler_order`` must (``XYZ`` for modern Motive, ``yzx`` for
    pre-1.6 exports); it also overrides the header. Angles are degrees (``degrees=False``: radians).

Length units come from ``Length Units``; without it the reader refuses to guess (cm and mm both
occur) and asks for ``length_unit``, which also overrides the header.
"""

from __future__ import annotations

import csv

import numpy as np

from rbgp_cli.dynamics.trajectory import Trajectory
from rbgp_cli.errors import InputError, NotPoseData, warn
from rbgp_cli.io import vendor
from rbgp_cli.io.export import write_motive_csv
from rbgp_cli.io.formats import Format
from rbgp_cli.io.options import ReadOptions
from rbgp_cli.io.vendor import metres_per, numeric_cells, quat_from_valid, read_text, reader_guard, select_bodies

__all__ = ["sniff", "detect", "read", "describe", "FORMAT", "UNIT_NAMES", "EULER_TYPES"]

#: Motive's ``Length Units`` values -> rbgp unit names.
UNIT_NAMES = {"meters": "m", "meter": "m", "centimeters": "cm", "centimeter": "cm", "millimeters": "mm",
              "millimeter": "mm"}
#: Motive's Euler ``Rotation Type`` values (relative = intrinsic, scipy upper case).
EULER_TYPES = ("XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX")
_HINT = "export from Motive as CSV with the header and Rigid Bodies enabled"
_LABELS = ("Type", "Name", "ID", "Parent")


def detect(head: bytes) -> bool:
    """Auto-detection: the first non-empty line starts with ``Format Version,``."""
    _, nonempty = vendor.head_lines(head)
    return bool(nonempty) and nonempty[0].lstrip().replace('"', "").startswith("Format Version,")


def sniff(head: str) -> bool:
    """True if ``head`` starts like a Motive CSV export (``Format Version,<v>,...``)."""
    first = head.lstrip("\ufeff").lstrip().split("\n", 1)[0]
    return first.replace('"', "").startswith("Format Version,")


class _Layout:
    """The 7-ish header rows of a Motive CSV, column by column."""

    def __init__(self, path, text):
        self.path = str(path)
        self.lines = text.splitlines()
        first = next(csv.reader(self.lines[:1]), [])
        if not first or first[0].strip() != "Format Version":
            raise InputError("not a Motive CSV export (line 1 must start with 'Format Version,')",
                             path=self.path, row=1, hint=_HINT)
        cells = [c.strip() for c in first]
        self.header = {k: v for k, v in zip(cells[0::2], cells[1::2]) if k}
        head_end = min(len(self.lines), 64)
        rows = list(csv.reader(self.lines[:head_end]))
        axis_row = next((i for i in range(1, len(rows)) if rows[i] and rows[i][0].strip() == "Frame"), None)
        if axis_row is None:
            raise InputError("no 'Frame,Time (Seconds),...' row in the header", path=self.path, hint=_HINT)
        self.axis_line = axis_row + 1
        width = len(rows[axis_row])

        def pad(r):
            return [c.strip() for c in r] + [""] * (width - len(r))

        above = [i for i in range(1, axis_row) if any(c.strip() for c in rows[i])]
        labelled = {}
        unlabelled = []
        for i in above:
            r = pad(rows[i])
            if len(r) > 1 and r[1] in _LABELS:
                labelled[r[1]] = r
            else:
                unlabelled.append(r)
        if not unlabelled:
            raise InputError("no Rotation/Position row above the Frame row", path=self.path, row=self.axis_line,
                             hint=_HINT)
        self.field = unlabelled[-1]
        rest = unlabelled[:-1]
        if "Type" not in labelled:  # 1.22: Type, Name, ID[, Parent] without labels
            labelled.update({label: r for label, r in zip(_LABELS, rest)})
        if "Type" not in labelled or "Name" not in labelled:
            raise InputError("the header has no Type and Name rows", path=self.path, row=self.axis_line, hint=_HINT)
        self.type, self.name = labelled["Type"], labelled["Name"]
        self.axis = pad(rows[axis_row])
        first_data = 0  # Frame, Time (Seconds)[, TimeCode] come first; the Type/Name labels sit above them
        while first_data < width and (self.axis[first_data] == "Frame" or self.axis[first_data].startswith("Time")):
            first_data += 1
        self.meta = {self.axis[j]: j for j in range(first_data)}
        self.bodies: dict[str, dict[str, dict[str, int]]] = {}
        self.others: dict[str, set[str]] = {}
        for j in range(first_data, width):
            kind, name = self.type[j], self.name[j]
            if not kind:
                continue
            if kind != "Rigid Body":
                self.others.setdefault(kind, set()).add(name)
                continue
            field = self.field[j]
            if field in ("Rotation", "Position"):
                self.bodies.setdefault(name, {"Rotation": {}, "Position": {}})[field].setdefault(self.axis[j], j)
        self.data = [i for i in range(self.axis_line, len(self.lines)) if self.lines[i].strip(", \t")]

    def rate(self) -> float | None:
        for key in ("Export Frame Rate", "Capture Frame Rate"):
            try:
                value = float(self.header.get(key, ""))
            except ValueError:
                continue
            if value > 0:
                return value
        return None

    def rotation_kind(self, name) -> str:
        axes = set(self.bodies[name]["Rotation"])
        if {"X", "Y", "Z", "W"} <= axes:
            return "quaternion"
        if {"X", "Y", "Z"} <= axes:
            return "euler"
        raise InputError(f"rigid body {name!r} has rotation columns {sorted(axes)}; expected X,Y,Z,W or X,Y,Z",
                         path=self.path, row=self.axis_line, hint=_HINT)

    def euler_order(self, options: ReadOptions) -> tuple[str | None, str]:
        if options.euler_order:
            return options.euler_order, "euler_order"
        stated = self.header.get("Rotation Type", "")
        if stated.upper() in EULER_TYPES:
            return stated.upper(), f"Rotation Type {stated} (Motive: relative = intrinsic)"
        return None, stated

    def length_unit(self, options: ReadOptions) -> str | None:
        if options.length_unit:
            return options.length_unit
        stated = self.header.get("Length Units")
        if stated is None:
            return None
        unit = UNIT_NAMES.get(stated.lower())
        if unit is None:
            raise InputError(f"unknown Length Units {stated!r}", path=self.path, row=1,
                             hint="give the unit with length_unit m|cm|mm", param="length_unit")
        return unit

    def other_assets(self) -> dict[str, list[str]]:
        return {k: sorted(v) for k, v in sorted(self.others.items())}


def _no_rigid_bodies(layout: _Layout, path) -> NotPoseData:
    """The error for an export without rigid bodies, naming the assets it has instead."""
    others = layout.other_assets()
    listed = "; ".join(f"{k}: {', '.join(v)}" for k, v in others.items()) or "none"
    return NotPoseData(f"no Rigid Body columns (only rigid bodies are poses); other assets: {listed}",
                       path=path, row=layout.axis_line,
                       hint="enable Rigid Bodies in Motive's CSV export options",
                       reason="no rigid bodies, only " + (", ".join(k.lower() + "s" for k in others) or "markers"))


def _numbers(layout: _Layout, chosen: list, path):
    """The numbers of the columns the chosen bodies, the time and the frame need: returns (col, cols,
    time_col, frame_col), ``col`` {column index: values (N,)}, ``cols`` {body: {"Position": [3
    indices], "Rotation": [indices X, Y, Z(, W)]}}, the Time and Frame column indices or None."""
    rows = list(csv.reader(layout.lines[i] for i in layout.data))
    line_no = [i + 1 for i in layout.data]
    labels = {j: f"{layout.name[j]} {layout.field[j]} {layout.axis[j]}".strip() for j in range(len(layout.axis))}
    time_col = next((j for a, j in layout.meta.items() if a.startswith("Time") and a != "TimeCode"), None)
    frame_col = layout.meta.get("Frame")
    cols = {name: {f: [layout.bodies[name][f][a] for a in axes if a in layout.bodies[name][f]]
                   for f, axes in (("Position", "XYZ"), ("Rotation", "XYZW"))} for name in chosen}
    for name in chosen:
        if len(cols[name]["Position"]) != 3:
            raise InputError(f"rigid body {name!r} has no Position X,Y,Z columns", path=path,
                             row=layout.axis_line, hint=_HINT)
    wanted = sorted({j for c in cols.values() for js in c.values() for j in js}
                    | {j for j in (time_col, frame_col) if j is not None})
    table = numeric_cells(rows, wanted, line_no, path=path, labels=labels, hint=_HINT)
    col = {j: table[:, k] for k, j in enumerate(wanted)}
    return col, cols, time_col, frame_col


def _check_header_states(unit, seq, seq_source, kinds: dict, col: dict, cols: dict, path) -> None:
    """An error naming the options to give where the header states neither the length unit nor (for
    Euler rotations) the Euler convention."""
    missing = []
    if unit is None:
        peak = max((np.nanmax(np.abs(col[j])) for c in cols.values() for j in c["Position"]
                    if np.isfinite(col[j]).any()), default=float("nan"))
        missing.append(("Length Units", f"length_unit m|cm|mm (positions reach {peak:.4g})"))
    if seq is None and "euler" in kinds.values():
        stated = f" (it says {seq_source!r})" if seq_source else ""
        missing.append(("the Euler convention (Rotation Type)" + stated,
                        "euler_order XYZ (Motive 1.6+ exports relative XYZ; pre-1.6: yzx)"))
    if missing:
        what = (f"states neither {missing[0][0]} nor {missing[1][0]}" if len(missing) == 2
                else f"does not state {missing[0][0]}")
        raise InputError(f"the header {what}", path=path, row=1,
                         hint="give " + " and ".join(h for _, h in missing), param=tuple(h.split()[0] for _, h in missing))


def _times(layout: _Layout, col: dict, time_col, frame_col, options: ReadOptions, path):
    """(t (N,) seconds, where they come from, the rate in Hz or None): the Time column, else the
    frames over the header's (or ``--rate``'s) frame rate; a warning where ``--rate`` disagrees with the
    header."""
    rate = layout.rate()
    if time_col is not None:
        t, time_source = col[time_col], layout.axis[time_col]
        if "millisecond" in time_source.lower():
            t = t * 1e-3
    else:
        rate = rate or options.rate
        if rate is None or frame_col is None:
            raise InputError("no Time column and no frame rate in the header", path=path,
                             hint="give the samples per second with rate HZ", param="rate")
        t, time_source = col[frame_col] / rate, "Frame / frame rate"
    if options.rate and layout.rate() and abs(options.rate - layout.rate()) > 1e-9 * layout.rate():
        warn(f"rate {options.rate:g} is ignored: the header states {layout.rate():g} Hz", path=path, param="rate")
    return t, time_source, rate


@reader_guard("a Motive CSV export", _HINT)
def read(path, options: ReadOptions | None = None) -> list[Trajectory]:
    """Read the selected rigid bodies of a Motive CSV export.

    Returns one raw :class:`Trajectory` per selected body (``options.body``: None -> the only rigid
    body, ``"all"`` -> every one): t in seconds, quaternions x, y, z, w (body -> world), positions in
    metres, lost frames as NaN rows. Raises InputError naming ``length_unit`` / ``euler_order``
    when the header does not state the length unit / the Euler convention.
    """
    options = options or ReadOptions()
    layout = _Layout(path, read_text(path))
    if not layout.bodies:
        raise _no_rigid_bodies(layout, path)
    chosen = select_bodies(list(layout.bodies), options.body, path=path)
    kinds = {name: layout.rotation_kind(name) for name in chosen}
    seq, seq_source = layout.euler_order(options)
    unit = layout.length_unit(options)
    degrees = True if options.degrees is None else bool(options.degrees)

    col, cols, time_col, frame_col = _numbers(layout, chosen, path)
    _check_header_states(unit, seq, seq_source, kinds, col, cols, path)
    scale = metres_per(unit, path=path, hint="use length_unit m|cm|mm")

    t, time_source, rate = _times(layout, col, time_col, frame_col, options, path)

    from scipy.spatial.transform import Rotation as R

    out = []
    for name in chosen:
        body = layout.bodies[name]
        pos = np.stack([col[j] for j in cols[name]["Position"]], axis=1) * scale
        if kinds[name] == "quaternion":
            rot = np.stack([col[body["Rotation"][a]] for a in "XYZW"], axis=1)
            lost = ~np.all(np.isfinite(pos), axis=1) | ~np.all(np.isfinite(rot), axis=1)
            lost |= np.all(rot == 0.0, axis=1)
            quat = np.where(lost[:, None], np.nan, rot)
            source = "quaternion xyzw"
        else:
            angles = np.stack([col[body["Rotation"][a.upper()]] for a in seq], axis=1)
            lost = ~np.all(np.isfinite(pos), axis=1) | ~np.all(np.isfinite(angles), axis=1)
            quat = quat_from_valid(~lost, lambda a: R.from_euler(seq, a, degrees=degrees), angles)
            source = f"euler {seq} {'deg' if degrees else 'rad'} ({seq_source})"
        pos[lost] = np.nan
        info = {
            "format": "motive",
            "layout": f"motive csv {layout.header.get('Format Version', '?')}",
            "body": name,
            "bodies": list(layout.bodies),
            "length_unit": unit,
            "rotation_source": source,
            "rate_hz": rate,
            "time_source": time_source,
            "lost_frames": int(lost.sum()),
            "up_axis": "Y (Motive default; axes kept as exported)",
            "ignored_assets": {k: len(v) for k, v in layout.other_assets().items()},
        }
        out.append(Trajectory(t=t, quat=quat, position=pos, name=name, source=str(path), info=info))
    return out


@reader_guard("a Motive CSV export", _HINT)
def describe(path, options: ReadOptions | None = None) -> dict:
    """Plain-data summary for ``rbgp inspect`` (header fields, rigid bodies and other assets, units,
    rotation type, frames, rate), without parsing the numbers."""
    options = options or ReadOptions()
    layout = _Layout(path, read_text(path))
    seq, seq_source = layout.euler_order(options)
    try:
        unit = layout.length_unit(options)
    except InputError:
        unit = None
    kinds = {}
    for name in layout.bodies:
        try:
            kinds[name] = layout.rotation_kind(name)
        except InputError:
            kinds[name] = "unknown"
    needs = []
    if unit is None:
        stated = layout.header.get("Length Units")
        needs.append("length_unit m|cm|mm (" + (f"unknown Length Units {stated!r}" if stated else
                                                  "the header states no Length Units") + ")")
    if seq is None and "euler" in kinds.values():
        needs.append("euler_order XYZ for Motive 1.6+ exports, yzx before 1.6 (the header states no Rotation Type)")
    time_col = next((a for a in layout.meta if a.startswith("Time") and a != "TimeCode"), None)
    return {
        "format": "motive",
        "header": dict(layout.header),
        "bodies": list(layout.bodies),
        "rotation": {n: (k if k != "euler" else f"euler {seq or '? (use euler_order)'}") for n, k in kinds.items()},
        "rotation_type": layout.header.get("Rotation Type"),
        "length_unit": unit,
        "length_units_stated": layout.header.get("Length Units"),
        "other_assets": layout.other_assets(),
        "time_columns": list(layout.meta),
        "frames": len(layout.data),
        "rate_hz": layout.rate(),
        "euler_order": seq,
        "euler_order_source": seq_source or None,
        "time_source": f"{time_col} column" if time_col else "Frame / frame rate",
        "up_axis": "Y (Motive default; axes kept as exported)",
        "needs": needs,
    }


def describe_rows(desc: dict) -> list[str]:
    """The text rows of ``rbgp inspect`` for :func:`describe`'s result."""
    from rbgp_cli.io.inspect import text_row as _row, rate_text as _rate
    from rbgp_cli.wording import plural as _plural

    h = desc.get("header", {})
    lines = [_row("export", f"format version {h.get('Format Version', '?')}, take {h.get('Take Name', '-')!s}"
                            + (f", captured {h['Capture Start Time']}" if h.get("Capture Start Time") else ""))]
    frames = f"{desc.get('frames')} exported at {_rate(desc)}"
    if h.get("Capture Frame Rate") and h.get("Capture Frame Rate") != h.get("Export Frame Rate"):
        frames += f" (captured at {h['Capture Frame Rate']} Hz)"
    if h.get("Total Frames in Take"):
        frames += f", {h['Total Frames in Take']} frames in the take"
    lines.append(_row("frames", frames))
    lines.append(_row("time", desc.get("time_source")))
    bodies = desc.get("bodies") or []
    lines.append(_row("rigid bodies", f"{len(bodies)}: " + ", ".join(bodies) if bodies else "none"))
    kinds = set((desc.get("rotation") or {}).values())
    if desc.get("rotation_type"):
        stated = f"Rotation Type {desc['rotation_type']}"
    else:
        stated = "the header states no Rotation Type"
    if kinds == {"quaternion"}:
        rot = "quaternion x, y, z, w"
    elif desc.get("euler_order"):
        rot = f"Euler angles, degrees, order {desc['euler_order']} ({desc.get('euler_order_source')})"
    elif kinds:
        rot = "Euler angles, degrees, order not stated"
    else:
        rot = "-"
    lines.append(_row("rotation", f"{rot}; {stated}" if kinds else rot))
    unit = desc.get("length_unit")
    stated_unit = desc.get("length_units_stated")
    lines.append(_row("length unit", (unit + (f" (Length Units {stated_unit})" if stated_unit else " (option)"))
                      if unit else ("not stated" if not stated_unit else f"unknown: {stated_unit}")))
    others = desc.get("other_assets") or {}
    if others:
        lines.append(_row("ignored", ", ".join(_plural(len(v), k.lower()) for k, v in others.items())
                          + " (only rigid bodies are poses)"))
    lines.append(_row("up axis", desc.get("up_axis")))
    return lines


FORMAT = Format(
    name="motive", title="OptiTrack Motive CSV", detect=detect, read=read, describe=describe,
    describe_rows=describe_rows, skip_reason=vendor.skip_reason(sniff, "Motive"),
    read_all=vendor.read_every_body(read), needs=vendor.body_needs, write=write_motive_csv,
    honours=("body",),
)
