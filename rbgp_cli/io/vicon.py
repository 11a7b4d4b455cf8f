"""Vicon Nexus / Tracker CSV exports -> raw :class:`~rbgp_cli.dynamics.trajectory.Trajectory`.

The format (ECOSYSTEM.md §2.3)
    * Sections (``Devices``, ``Joints``, ``Model Outputs``, ``Segments``, ``Trajectories``), separated
      by blank lines. Each has a title line, a rate line (``100``), a names line with
      ``Subject:Segment`` in the first column of each block, the column line
      ``Frame,Sub Frame,RX,RY,RZ,TX,TY,TZ,...`` and a units line (``,,deg,deg,deg,mm,mm,mm``).
    * 6DOF poses are the ``RX RY RZ TX TY TZ`` blocks of the ``Segments`` section (global poses). If
      there is no Segments section, another section with such blocks is used, but never ``Joints``
      (joint transforms are relative to the parent segment).
    * Time: ``t = (Frame - 1) / rate`` (frames count from 1). ``Sub Frame`` only matters for device
      data and is ignored.
    * Lost frames are blank cells; they become NaN rows.
    * Separator ``,`` or ``;`` (some locales; then a decimal comma is accepted too), or a tab.

Rotation (a documented assumption, overridable)
    ``RX, RY, RZ`` are read as the **helical** angles of the segment, i.e. the rotation vector
    ``θ·u`` (axis times angle) in the units line's unit (degrees by default), the Vicon default for
    segment export (ECOSYSTEM.md §2.3, unverified against Vicon's own documentation). With
    ``ReadOptions.rotation == "euler"`` they are Euler angles instead: ``euler_order`` (scipy
    notation, e.g. ``XYZ`` intrinsic) is then required, and each angle is taken from the column of
    its axis (RX for X, ...).

Positions ``TX TY TZ`` are in the units line's unit (mm); ``length_unit`` overrides it and is
required when the file has no units line.
"""

from __future__ import annotations

import csv

import numpy as np

from rbgp_cli.dynamics.trajectory import Trajectory
from rbgp_cli.errors import InputError, NotPoseData, warn
from rbgp_cli.io import vendor
from rbgp_cli.io.export import write_vicon_csv
from rbgp_cli.io.formats import Format
from rbgp_cli.io.options import ReadOptions
from rbgp_cli.io.vendor import metres_per, numeric_cells, quat_from_valid, read_text, reader_guard, select_bodies

__all__ = ["sniff", "detect", "read", "describe", "FORMAT", "SECTIONS"]

SECTIONS = ("Devices", "Joints", "Model Outputs", "Segments", "Trajectories")
_POSE = ("RX", "RY", "RZ", "TX", "TY", "TZ")
_HINT = "export the Segments section from Vicon Nexus/Tracker as CSV"
_ANGLE_UNITS = {"deg": True, "degrees": True, "rad": False, "radians": False}


def _delimiter(lines) -> str | None:
    for line in lines[:200]:
        for d in (",", ";", "\t"):
            if line.startswith(f"Frame{d}"):
                return d
    return None


def detect(head: bytes) -> bool:
    """Auto-detection: the first non-empty line is a section title (``Segments``, ...) and the next one
    a number (the rate)."""
    _, nonempty = vendor.head_lines(head)
    if len(nonempty) < 2 or nonempty[0].strip().strip(",;\t ").strip('"') not in SECTIONS:
        return False
    try:
        float(nonempty[1].strip().strip(",;\t ").replace(",", "."))
    except ValueError:
        return False
    return True


def sniff(head: str) -> bool:
    """True if ``head`` looks like a Vicon CSV export: a section title (``Segments``, ...) on the
    first non-empty line and a ``Frame,Sub Frame`` column line."""
    lines = [ln for ln in head.lstrip("\ufeff").splitlines() if ln.strip(",;\t ")]
    if not lines:
        return False
    title = lines[0].strip().rstrip(",;\t").strip()
    d = _delimiter(lines)
    return title in SECTIONS and d is not None and any(ln.startswith(f"Frame{d}Sub Frame") for ln in lines)


class _Section:
    """One section; ``column_row`` is the 0-based index of its ``Frame,Sub Frame`` line (so the rate
    line is at file line ``column_row - 1``, the units line at ``column_row + 2``, 1-based)."""

    def __init__(self, title, column_row, rate, names, columns, units, data):
        self.title, self.column_row, self.rate = title, column_row, rate
        self.names, self.columns, self.units, self.data = names, columns, units, data
        self.blocks: dict[str, dict[str, int]] = {}
        current = None
        for j in range(2, len(columns)):
            if j < len(names) and names[j]:
                current = self.blocks.setdefault(names[j], {})
            if current is not None and columns[j]:
                current.setdefault(columns[j], j)

    @property
    def poses(self) -> dict[str, dict[str, int]]:
        return {n: b for n, b in self.blocks.items() if all(c in b for c in _POSE)}


class _Layout:
    def __init__(self, path, text):
        self.path = str(path)
        self.lines = text.splitlines()
        self.delimiter = _delimiter(self.lines)
        if self.delimiter is None:
            raise InputError("no 'Frame,Sub Frame,...' column line: not a Vicon CSV export", path=self.path,
                             hint=_HINT)
        d = self.delimiter
        self.sections: list[_Section] = []
        for c in (i for i, line in enumerate(self.lines) if line.startswith(f"Frame{d}")):
            if c < 2:
                continue
            title_row = self.row(c - 3) if c >= 3 else []
            units, start = None, c + 1
            if start < len(self.lines) and not self.blank(start):
                first = self.row(start)
                if not first[0]:
                    units, start = first, start + 1
            end = start
            while end < len(self.lines) and not self.blank(end):
                end += 1
            rate_row = self.row(c - 2)
            rate = _float(rate_row[0] if rate_row else "", d)
            title = title_row[0] if title_row else ""
            self.sections.append(_Section(title, c, rate, self.row(c - 1), self.row(c), units, list(range(start, end))))
        if not self.sections:
            raise InputError("no section with a 'Frame,Sub Frame' column line", path=self.path, hint=_HINT)

    def row(self, i) -> list[str]:
        """Line ``i`` (0-based) split with the csv module (header rows may quote names)."""
        return [c.strip() for c in next(csv.reader([self.lines[i]], delimiter=self.delimiter), [])]

    def blank(self, i) -> bool:
        return not self.lines[i].strip(self.delimiter + " \t")

    def pose_section(self) -> _Section:
        candidates = [s for s in self.sections if s.poses]
        preferred = [s for s in candidates if s.title == "Segments"] or [s for s in candidates if s.title != "Joints"]
        if preferred:
            return preferred[0]
        titles = ", ".join(s.title or "(untitled)" for s in self.sections)
        if candidates:
            raise NotPoseData(
                "only the Joints section has RX..TZ columns, and joint transforms are relative to the parent "
                "segment, not world poses", path=self.path, hint="export the Segments section (global poses)",
                reason="joints only, no segment poses")
        raise NotPoseData(f"no RX,RY,RZ,TX,TY,TZ (segment pose) columns; the sections are {titles}",
                          path=self.path, hint=_HINT, reason="no segment poses")


def _float(text: str, delimiter: str) -> float | None:
    try:
        value = float(text.replace(",", ".") if delimiter == ";" else text)
    except ValueError:
        return None
    return value if value > 0 else None


def _rotation(options: ReadOptions, path) -> str:
    """How RX, RY, RZ are read: ``helical`` (a rotation vector, the default) or ``euler`` (which then
    needs ``--euler-order``)."""
    rotation = (options.rotation or "helical").lower()
    if rotation not in ("helical", "euler"):
        raise InputError(f"rotation {options.rotation!r} is unknown for Vicon RX,RY,RZ", path=path,
                         hint="use rotation helical (axis-angle, default) or rotation euler", param="rotation")
    if rotation == "euler" and not options.euler_order:
        raise InputError("rotation euler needs the Euler convention of RX,RY,RZ", path=path,
                         hint="give it with euler_order (e.g. XYZ intrinsic, xyz extrinsic)", param=("rotation", "euler_order"))
    return rotation


def _units(section, first: dict, options: ReadOptions, path):
    """(length unit, metres per unit, degrees?) of the first chosen segment's columns ``first``: the
    options' or the section's units line; an error where neither says."""
    units = section.units or []
    if options.length_unit:
        length_unit = options.length_unit
    elif first["TX"] < len(units) and units[first["TX"]]:
        length_unit = units[first["TX"]]
    else:
        raise InputError("no units line under the column line, so the length unit is unknown", path=path,
                         row=section.column_row + 1, hint="give it with length_unit m|cm|mm", param="length_unit")
    scale = metres_per(length_unit, path=path, hint="use length_unit m|cm|mm")
    if options.degrees is not None:
        degrees = bool(options.degrees)
    else:
        stated = units[first["RX"]].lower() if first["RX"] < len(units) else ""
        if stated and stated not in _ANGLE_UNITS:
            raise InputError(f"unknown angle unit {stated!r} for RX", path=path, row=section.column_row + 2,
                             hint="say whether angles are degrees with degrees=True / degrees=False", param="degrees")
        degrees = _ANGLE_UNITS.get(stated, True)
    return length_unit, scale, degrees


def _rate(section, options: ReadOptions, path) -> float:
    """The section's rate in Hz (or ``--rate`` where the file gives none; a warning where they disagree)."""
    rate = section.rate or options.rate
    if section.rate is None and options.rate is None:
        raise InputError(f"the rate line of section {section.title!r} is not a number", path=path,
                         row=section.column_row - 1, hint="give the samples per second with rate HZ", param="rate")
    if options.rate and section.rate and abs(options.rate - section.rate) > 1e-9 * section.rate:
        warn(f"rate {options.rate:g} is ignored: the file states {section.rate:g} Hz", path=path, param="rate")
    return rate


@reader_guard("a Vicon CSV export", _HINT)
def read(path, options: ReadOptions | None = None) -> list[Trajectory]:
    """Read the selected segments of a Vicon CSV export.

    Returns one raw :class:`Trajectory` per selected segment (``options.body`` matches
    ``Subject:Segment`` or the segment name alone; None -> the only one, ``"all"`` -> every one):
    t in seconds, quaternions x, y, z, w (segment -> world), positions in metres, lost frames as NaN.
    """
    options = options or ReadOptions()
    layout = _Layout(path, read_text(path))
    section = layout.pose_section()
    poses = section.poses
    aliases = {n.split(":", 1)[1]: n for n in poses if ":" in n}
    if len(set(aliases.values())) != len(aliases) or len(aliases) != len({a.lower() for a in aliases}):
        aliases = {}
    chosen = select_bodies(list(poses), options.body, path=path, aliases=aliases)

    rotation = _rotation(options, path)
    first = poses[chosen[0]]
    length_unit, scale, degrees = _units(section, first, options, path)
    rate = _rate(section, options, path)

    rows = [layout.lines[i].split(layout.delimiter) for i in section.data]
    line_no = [i + 1 for i in section.data]
    labels = {j: f"{section.columns[j]}" for j in range(len(section.columns))}
    wanted = sorted({0} | {poses[n][c] for n in chosen for c in _POSE})
    table = numeric_cells(rows, wanted, line_no, path=path, labels=labels, hint=_HINT,
                          decimal_comma=layout.delimiter == ";")
    col = {j: table[:, k] for k, j in enumerate(wanted)}
    t = (col[0] - 1.0) / rate

    from scipy.spatial.transform import Rotation as R

    out = []
    for name in chosen:
        b = poses[name]
        pos = np.stack([col[b[c]] for c in ("TX", "TY", "TZ")], axis=1) * scale
        lost = ~np.all(np.isfinite(pos), axis=1)
        if rotation == "helical":
            rv = np.stack([col[b[c]] for c in ("RX", "RY", "RZ")], axis=1)
            rv = np.deg2rad(rv) if degrees else rv
            lost |= ~np.all(np.isfinite(rv), axis=1)
            quat = quat_from_valid(~lost, R.from_rotvec, rv)
            source = f"helical (rotation vector) {'deg' if degrees else 'rad'}"
        else:
            seq = options.euler_order
            ang = np.stack([col[b["R" + a.upper()]] for a in seq], axis=1)
            lost |= ~np.all(np.isfinite(ang), axis=1)
            quat = quat_from_valid(~lost, lambda a: R.from_euler(seq, a, degrees=degrees), ang)
            source = f"euler {seq} {'deg' if degrees else 'rad'} (euler_order)"
        pos[lost] = np.nan
        info = {
            "format": "vicon",
            "layout": f"vicon csv, section {section.title or '(untitled)'}, delimiter {layout.delimiter!r}",
            "body": name,
            "bodies": list(poses),
            "length_unit": length_unit,
            "rotation_source": source,
            "rate_hz": rate,
            "time_source": "(Frame - 1) / rate",
            "lost_frames": int(lost.sum()),
            "sections": [s.title for s in layout.sections],
        }
        out.append(Trajectory(t=t, quat=quat, position=pos, name=name, source=str(path), info=info))
    return out


@reader_guard("a Vicon CSV export", _HINT)
def describe(path, options: ReadOptions | None = None) -> dict:
    """Plain-data summary for ``rbgp inspect`` (sections, segments, units, rate, frames), without
    parsing the numbers."""
    options = options or ReadOptions()
    layout = _Layout(path, read_text(path))
    sections = [
        {
            "title": s.title,
            "rate_hz": s.rate,
            "frames": len(s.data),
            "blocks": list(s.blocks),
            "pose_blocks": list(s.poses),
            "units": sorted({u for u in (s.units or [])[2:] if u}),
        }
        for s in layout.sections
    ]
    try:
        pose = layout.pose_section()
    except InputError:
        pose = None
    needs, length_unit, angle_unit = [], None, None
    if pose is not None and pose.poses:
        first = next(iter(pose.poses.values()))
        units = pose.units or []
        length_unit = options.length_unit or (units[first["TX"]] if first["TX"] < len(units) else None) or None
        angle_unit = (units[first["RX"]] if first["RX"] < len(units) else None) or None
        if length_unit is None:
            needs.append("length_unit m|cm|mm (no units line under the column line)")
        if pose.rate is None and not options.rate:
            needs.append(f"rate HZ (the rate line of section {pose.title!r} is not a number)")
        if (options.rotation or "").lower() == "euler" and not options.euler_order:
            needs.append("euler_order (rotation euler needs the convention of RX, RY, RZ)")
    return {
        "format": "vicon",
        "delimiter": layout.delimiter,
        "sections": sections,
        "bodies": list(pose.poses) if pose else [],
        "pose_section": pose.title if pose else None,
        "rotation": (options.rotation or "helical") if pose else None,
        "frames": len(pose.data) if pose else 0,
        "rate_hz": (pose.rate or options.rate) if pose else None,
        "length_unit": length_unit,
        "angle_unit": angle_unit,
        "needs": needs,
    }


def describe_rows(desc: dict) -> list[str]:
    """The text rows of ``rbgp inspect`` for :func:`describe`'s result."""
    from rbgp_cli.io.inspect import (
        text_row as _row, fmt_num as _fmt_num, rate_text as _rate, DELIMITER_NAMES as _DELIMITERS,
    )
    from rbgp_cli.wording import plural as _plural

    sections = desc.get("sections") or []
    lines = [_row("sections", "; ".join(
        f"{s['title'] or '(untitled)'} ({_fmt_num(s['rate_hz'])} Hz, {_plural(s['frames'], 'frame')})" for s in sections))]
    lines.append(_row("delimiter", _DELIMITERS.get(desc.get("delimiter"), desc.get("delimiter"))))
    if desc.get("pose_section"):
        lines.append(_row("poses from", f"section {desc['pose_section']}, {desc.get('frames')} frames at {_rate(desc)}"))
        bodies = desc.get("bodies") or []
        lines.append(_row("segments", f"{len(bodies)}: " + ", ".join(bodies)))
        rot = desc.get("rotation")
        lines.append(_row("rotation", f"RX RY RZ as {'a helical (axis-angle) rotation vector' if rot == 'helical' else 'Euler angles'}"
                                      f" in {desc.get('angle_unit') or 'deg'}"
                                      + (" (default; --rotation euler --euler-order ORDER if they are Euler angles)"
                                         if rot == "helical" else "")))
        lines.append(_row("length unit", desc.get("length_unit") or "not stated (no units line)"))
        lines.append(_row("time", "(Frame - 1) / rate"))
    else:
        lines.append(_row("poses from", "no section with RX RY RZ TX TY TZ columns"))
    return lines


FORMAT = Format(
    name="vicon", title="Vicon CSV", detect=detect, read=read, describe=describe, describe_rows=describe_rows,
    skip_reason=vendor.skip_reason(sniff, "Vicon"), read_all=vendor.read_every_body(read), needs=vendor.body_needs,
    write=write_vicon_csv,
    honours=("body", "rotation"),
)
