"""Qualisys QTM 6DOF TSV exports (``*_6D.tsv``) -> raw :class:`~rbgp_cli.dynamics.trajectory.Trajectory`.

The format (ECOSYSTEM.md §2.1; checked against the 2010 exports in shared/realdata and a 2020 export,
shiplab/dt_cv data/basin/raw/M510A-IRR-EKFPID-020019_6D.tsv)
    * Key/value header lines, tab separated: ``FILE_VERSION`` (absent before 2.0.0), ``NO_OF_FRAMES``,
      ``NO_OF_BODIES``, ``FREQUENCY`` (Hz, or ``EXT`` for an external timebase), ``TIME_STAMP``,
      any number of ``EVENT <name> <frame> <time>`` lines, ``DATA_INCLUDED 6D``,
      ``BODY_NAMES <name1> <name2> ...``. The column header is found by its content, not by counting
      lines (EVENT lines shift it).
    * Current layout: ``Frame  Time  <Body> X  Y  Z  Roll  Pitch  Yaw  Residual  Rot[0] .. Rot[8]``
      then the next body's ``<Body> X`` ..., and a trailing tab.
    * Old layout (2010 exports): no Frame/Time columns (time = row / FREQUENCY), one anonymous header
      `` X  Y  Z  Yaw  Pitch  Roll  Residual  Rot[0] .. Rot[8]`` for the first body only; every body's
      block is followed by an empty column (so rows end with a tab); names come from ``BODY_NAMES``.
    * An export without the key/value header starts directly with the ``Frame  Time ...`` line;
      names then come from the columns and times from the Time column.
    * Units: positions in **mm**, angles in **degrees**, Time in seconds.
    * ``Rot[0..8]`` is the rotation matrix body -> world in **column-major** order
      (``Rot[1] = r21``, ``Rot[3] = r12``), ``P_world = R P_body + P_origin``. It is preferred to the
      Euler angles (the user can redefine the Euler convention in QTM). Each matrix is checked for
      orthonormality and det = +1; a row that fails falls back to its Euler angles (with a warning).
    * Euler angles, when used: the three angle columns, **in the order the header lists them**, are an
      intrinsic sequence with Roll about X, Pitch about Y, Yaw about Z. The QTM default header
      ``Roll Pitch Yaw`` gives ``R = Rx(roll) Ry(pitch) Rz(yaw)`` (scipy ``"XYZ"``), the 2010 header
      ``Yaw Pitch Roll`` gives ``R = Rz(yaw) Ry(pitch) Rx(roll)`` (scipy ``"ZYX"``); both were
      verified against the files' own Rot[] to 5e-6. ``ReadOptions.euler_order`` overrides this
      (scipy notation, applied to the angle columns in file order).
    * Lost frames: ``null``/``NaN``/empty cells, an all-zero Rot[], or ``Residual`` = -1 (QTM writes
      zeros and -1 when a body is not tracked). They are kept as NaN rows; cleaning happens later.
"""

from __future__ import annotations

import re

import numpy as np

from rbgp_cli.dynamics.trajectory import Trajectory
from rbgp_cli.errors import InputError, NotPoseData, warn
from rbgp_cli.io import vendor
from rbgp_cli.io.export import write_qtm_tsv
from rbgp_cli.io.formats import Format
from rbgp_cli.io.options import ReadOptions
from rbgp_cli.io.vendor import metres_per, numeric_cells, quat_from_valid, read_text, reader_guard, select_bodies

__all__ = ["sniff", "detect", "not_6d", "read", "describe", "FORMAT"]

_KEY = re.compile(r"^[A-Z][A-Z0-9]*(?:_[A-Z0-9]+)+$")
_BARE_KEYS = {"FREQUENCY", "DESCRIPTION", "EVENT"}
#: QTM's names for the rotation about each axis (Qualisys standard Euler definition).
ANGLE_AXES = {"roll": "X", "pitch": "Y", "yaw": "Z"}
ROT_FIELDS = tuple(f"Rot[{k}]" for k in range(9))
#: Rot[] rows whose ``max |R Rᵀ - I|`` exceeds this are not rotations (exports print 5 decimals, so
#: real matrices are orthonormal to ~1e-5).
ORTHONORMAL_TOL = 1e-3
_HINT = "export the 6DOF data from QTM as TSV (File > Export > TSV, 6D)"


def _is_key(cell: str) -> bool:
    return cell in _BARE_KEYS or bool(_KEY.match(cell))


def sniff(head: str) -> bool:
    """True if ``head`` (the first few KiB of text) looks like a QTM TSV export: it starts with
    tab-separated QTM header keys such as ``NO_OF_FRAMES`` or ``FILE_VERSION``, or (an export without
    that header) with the ``Frame<TAB>Time<TAB>`` column header."""
    lines = [ln for ln in head.lstrip("\ufeff").splitlines() if ln.strip()][:3]
    if not lines or "\t" not in lines[0]:
        return False
    first = lines[0].split("\t")[0].strip()
    keys = ("FILE_VERSION", "NO_OF_FRAMES", "NO_OF_CAMERAS", "NO_OF_BODIES", "NO_OF_MARKERS")
    return first in keys or lines[0].startswith("Frame\tTime\t")


#: Header keys that start a QTM export (auto-detection; :func:`sniff` checks a named ``--format qtm``).
_DETECT_KEYS = ("NO_OF_FRAMES", "FILE_VERSION", "NO_OF_CAMERAS", "NO_OF_BODIES", "NO_OF_MARKERS", "FREQUENCY")


def detect(head: bytes) -> bool:
    """Auto-detection from the first bytes of a file: the first non-empty line starts with a QTM header
    key and a tab, or a ``Frame<TAB>Time`` column line is among the first 64 lines."""
    lines, nonempty = vendor.head_lines(head)
    if not nonempty:
        return False
    first = nonempty[0]
    if first.split("\t")[0].strip() in _DETECT_KEYS and "\t" in first:
        return True
    return any(ln.startswith("Frame\tTime") for ln in lines[:64])


def not_6d(head: str) -> str | None:
    """``"QTM 3D data, not 6D"`` when the header in ``head`` says the file holds no 6DOF data
    (``DATA_INCLUDED 3D``: QTM exports the markers and the rigid bodies to separate files), else None."""
    for line in head.lstrip("\ufeff").splitlines()[:64]:
        cells = line.split("\t")
        if cells[0].strip() == "DATA_INCLUDED":
            included = " ".join(c.strip() for c in cells[1:] if c.strip()).upper()
            return f"QTM {included} data, not 6D" if included and "6D" not in included else None
    return None


class _Layout:
    """What the header says: key/values, events, columns and the blocks of each body."""

    def __init__(self, path, text):
        self.path = str(path)
        self.lines = text.splitlines()
        self.header: dict[str, list[str]] = {}
        self.events: list[list[str]] = []
        self.header_line = None
        for i, line in enumerate(self.lines):
            if not line.strip():
                continue
            cells = line.split("\t")
            key = cells[0].strip()
            if _is_key(key):
                values = [c.strip() for c in cells[1:]]
                while values and not values[-1]:
                    values.pop()
                if key == "EVENT":
                    self.events.append(values)
                else:
                    self.header.setdefault(key, values)
                continue
            self.header_line = i
            break
        if not self.header and not (
            self.header_line is not None and self.lines[self.header_line].startswith("Frame\tTime\t")
        ):  # an export without the key/value header still starts with the tab-separated column header
            raise InputError("no QTM header (NO_OF_FRAMES, FREQUENCY, BODY_NAMES ...) and no tab-separated "
                             "'Frame, Time, <Body> X ...' column header", path=self.path, hint=_HINT)
        included = " ".join(self.header.get("DATA_INCLUDED", [])).upper()
        if included and "6D" not in included:
            raise NotPoseData(
                f"this QTM file holds {included} data, not 6DOF rigid bodies", path=self.path, hint=_HINT,
                reason=f"QTM {included} data, not 6D",
            )
        if self.header_line is None:
            raise InputError("the file has a QTM header but no column header or data", path=self.path, hint=_HINT)
        cells = [c.strip() for c in self.lines[self.header_line].split("\t")]
        if _is_number(cells[0]):
            raise InputError(
                "the QTM file has no column header line (Frame, Time, <Body> X ...)",
                path=self.path,
                row=self.header_line + 1,
                hint="export again with the header included",
            )
        self.columns = cells
        self._blocks(cells)
        # a row of tabs only is a frame in which every body was lost (2010 layout): keep it
        self.data = [i for i in range(self.header_line + 1, len(self.lines)) if self.lines[i].strip(" ")]

    def _blocks(self, cells):
        meta: dict[str, int] = {}
        blocks: list[tuple[str | None, dict[str, int]]] = []
        current = None
        for j, c in enumerate(cells):
            if not c:
                current = None
                continue
            if c == "X" or c.endswith(" X"):
                current = (c[:-2].strip() or None, {"X": j})  # None: anonymous (2010 layout)
                blocks.append(current)
                continue
            if current is None:
                meta[c] = j
                continue
            name, fields = current
            if name and c.startswith(name + " "):
                c = c[len(name) + 1 :]
            fields.setdefault(c, j)
        if not blocks:
            raise InputError(
                "no rigid-body columns in the column header (expected '<Body> X  Y  Z ... Rot[8]')",
                path=self.path,
                row=self.header_line + 1,
                hint=_HINT,
            )
        names_hdr = self.header.get("BODY_NAMES", [])
        anonymous = all(name is None for name, _ in blocks)
        if anonymous:
            n_bodies = len(names_hdr) or _int(self.header.get("NO_OF_BODIES")) or len(blocks)
            if len(blocks) == 1 and n_bodies > 1:
                # 2010 layout: one header block, every body's block followed by an empty column
                fields = blocks[0][1]
                first, last = min(fields.values()), max(fields.values())
                stride = last - first + 2
                blocks = [(None, {f: j + k * stride for f, j in fields.items()}) for k in range(n_bodies)]
                self._check_separators([first + k * stride - 1 for k in range(1, n_bodies)])
            names = names_hdr if len(names_hdr) == len(blocks) else [f"body{k + 1}" for k in range(len(blocks))]
            blocks = [(names[k], fields) for k, (_, fields) in enumerate(blocks)]
            self.layout = "old" if "Frame" not in meta else "current"
        else:
            blocks = [(name or f"body{k + 1}", fields) for k, (name, fields) in enumerate(blocks)]
            self.layout = "current"
        self.meta = meta
        self.blocks = dict(blocks)
        if len(self.blocks) != len(blocks):
            raise InputError("two bodies in the column header have the same name", path=self.path,
                             row=self.header_line + 1)

    def _check_separators(self, columns):
        """In the 2010 layout every body's block is followed by an empty column; a non-empty cell there
        means the blocks are not where the single header says (and every value would be misread)."""
        first = next((i for i in range(self.header_line + 1, len(self.lines)) if self.lines[i].strip(" ")), None)
        if first is None:
            return
        cells = self.lines[first].split("\t")
        filled = [j for j in columns if j < len(cells) and cells[j].strip()]
        if filled:
            raise InputError(
                f"expected an empty column between the bodies' blocks (column {filled[0] + 1}); "
                "the rows do not match the one-body header",
                path=self.path, row=first + 1, hint=_HINT)

    # facts -------------------------------------------------------------------------------------
    def frequency(self) -> float | None:
        value = (self.header.get("FREQUENCY") or [""])[0]
        try:
            f = float(value)
        except ValueError:
            return None  # e.g. EXT (external timebase)
        return f if f > 0 else None

    def rotation_plan(self, fields, options: ReadOptions):
        """``(rot_cols, angle_cols, euler_seq, euler_source, angle_names)`` for one body's fields;
        ``rot_cols`` is None without Rot[0..8], ``angle_cols`` None unless there are three angle
        columns, ``euler_seq`` None when neither the angle names nor ``euler_order`` define it."""
        rot = [fields[f] for f in ROT_FIELDS] if all(f in fields for f in ROT_FIELDS) else None
        skip = {"X", "Y", "Z", "Residual", *ROT_FIELDS}
        angle_names = [f for f in sorted(fields, key=fields.get) if f not in skip]
        angles = [fields[f] for f in angle_names] if len(angle_names) == 3 else None
        seq, source = None, None
        if angles is not None:
            if options.euler_order:
                seq, source = options.euler_order, "euler_order"
            else:
                axes = [ANGLE_AXES.get(a.lower()) for a in angle_names]
                if None not in axes and len(set(axes)) == 3:
                    seq, source = "".join(axes), "header " + " ".join(angle_names)
        return rot, angles, seq, source, angle_names


def _check_matrices(m):
    """For matrices (N, 3, 3): ``(empty, bad)`` masks: empty = a non-finite or all-zero matrix (QTM's
    lost frame), bad = otherwise not a rotation (``max |R Rᵀ - I| > ORTHONORMAL_TOL`` or det <= 0)."""
    finite = np.all(np.isfinite(m), axis=(1, 2))
    empty = ~finite | np.all(m == 0.0, axis=(1, 2))
    bad = np.zeros(len(m), bool)
    if (~empty).any():
        mm = m[~empty]
        err = np.max(np.abs(mm @ mm.transpose(0, 2, 1) - np.eye(3)), axis=(1, 2))
        bad[~empty] = (err > ORTHONORMAL_TOL) | (np.linalg.det(mm) <= 0)
    return empty, bad


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _int(values) -> int:
    try:
        return int(float((values or [""])[0]))
    except ValueError:
        return 0


def _time_axis(layout: _Layout, values, options: ReadOptions, n: int):
    """Seconds for each data row, and a note on where they came from."""
    f_file = layout.frequency()
    rate = f_file or options.rate
    if options.rate and f_file and abs(options.rate - f_file) > 1e-9 * f_file:
        warn(f"rate {options.rate:g} is ignored: the file states FREQUENCY {f_file:g} Hz", path=layout.path, param="rate")
    if "Time" in values:
        return values["Time"], "Time column", rate
    if rate is None:
        raise InputError(
            "FREQUENCY is not a number (external timebase?) and there is no Time column",
            path=layout.path,
            hint="give the samples per second with rate HZ", param="rate"
        )
    if "Frame" in values:
        return (values["Frame"] - 1.0) / rate, "(Frame - 1) / FREQUENCY", rate
    return np.arange(n) / rate, "row / FREQUENCY", rate


def _column_plans(layout: _Layout, chosen: list, meta_cols: dict, options: ReadOptions, path):
    """Each chosen body's rotation plan (:meth:`_Layout.rotation_plan`) and the columns to read (the
    Frame and Time columns ``meta_cols``, positions, the Rot[] matrix or else the angles, residuals);
    an error for a body without positions or without a rotation it can read."""
    plans, wanted = {}, list(meta_cols.values())
    for name in chosen:
        fields = layout.blocks[name]
        missing = [f for f in ("X", "Y", "Z") if f not in fields]
        if missing:
            raise InputError(f"body {name!r} has no {'/'.join(missing)} column", path=path,
                             row=layout.header_line + 1, hint=_HINT)
        plan = layout.rotation_plan(fields, options)
        rot, angles, seq, _, angle_names = plan
        if rot is None and (angles is None or seq is None):
            what = (f"angle columns {' '.join(angle_names)} of unknown convention" if angles is not None
                    else "no Euler angle columns")
            raise InputError(
                f"body {name!r} has no Rot[0..8] matrix and {what}", path=path, row=layout.header_line + 1,
                hint="give the angles' convention with euler_order (e.g. XYZ for Roll Pitch Yaw)", param="euler_order"
            )
        plans[name] = plan
        wanted += [fields[f] for f in ("X", "Y", "Z")] + (rot or angles)  # angles: only when no Rot[]
        if "Residual" in fields:
            wanted.append(fields["Residual"])
    return plans, wanted


def _body_quaternions(name: str, plan, fields: dict, col: dict, pos, lost, rows, line_no, labels, degrees, path):
    """One body's quaternions (N, 4) and where they come from: its Rot[] matrices (the Euler angles
    for rows whose matrix is not a rotation, or those rows lost, with a warning), else its angles.
    Marks the rows without a rotation in ``lost`` (N,) (changed in place)."""
    from scipy.spatial.transform import Rotation as R  # the io edge may use scipy

    rot, angles, seq, seq_source, angle_names = plan
    if rot is not None:
        m = np.stack([col[j] for j in rot], axis=1).reshape(-1, 3, 3).transpose(0, 2, 1)  # column-major
        empty, bad = _check_matrices(m)
        lost |= empty
        bad &= ~lost
        quat = quat_from_valid(~lost & ~bad, R.from_matrix, m)
        source = "Rot[] matrix (column-major)"
        if bad.any():
            if angles is not None and seq is not None:
                idx = np.flatnonzero(bad)
                eul = numeric_cells([rows[i] for i in idx], angles, [line_no[i] for i in idx], path=path,
                                    labels=labels, hint=_HINT)
                use = np.all(np.isfinite(eul), axis=1)
                lost[idx[~use]] = True
                quat[idx[use]] = R.from_euler(seq, eul[use], degrees=degrees).as_quat()
                warn(f"body {name!r}: {int(bad.sum())} Rot[] matrices are not rotations; "
                     f"used the Euler angles ({seq}) for those rows", path=path)
            else:
                lost |= bad
                warn(f"body {name!r}: {int(bad.sum())} Rot[] matrices are not rotations; kept as lost frames",
                     path=path)
    else:
        eul = np.stack([col[j] for j in angles], axis=1)
        finite = np.all(np.isfinite(eul), axis=1)
        lost |= ~finite
        if "Residual" not in fields:
            lost |= finite & np.all(eul == 0.0, axis=1) & np.all(pos == 0.0, axis=1)
        quat = quat_from_valid(~lost, lambda a: R.from_euler(seq, a, degrees=degrees), eul)
        source = f"euler {seq} {'deg' if degrees else 'rad'} ({seq_source})"
    return quat, source


@reader_guard("a QTM 6D TSV file", _HINT)
def read(path, options: ReadOptions | None = None) -> list[Trajectory]:
    """Read the selected rigid bodies of a QTM 6DOF TSV export.

    Returns one raw :class:`Trajectory` per selected body (``options.body``: None -> the only body,
    ``"all"`` -> every body): t in seconds, quaternions x, y, z, w (body -> world), positions in metres
    (the file's mm unless ``options.length_unit`` says otherwise), lost frames as NaN rows.
    """
    options = options or ReadOptions()
    layout = _Layout(path, read_text(path))
    chosen = select_bodies(list(layout.blocks), options.body, path=path)
    scale = metres_per(options.length_unit or "mm", path=path, hint="use length_unit m|cm|mm")
    degrees = True if options.degrees is None else bool(options.degrees)

    rows = [layout.lines[i].split("\t") for i in layout.data]
    line_no = [i + 1 for i in layout.data]
    labels = {j: c for j, c in enumerate(layout.columns)}
    meta_cols = {k: layout.meta[k] for k in ("Frame", "Time") if k in layout.meta}
    plans, wanted = _column_plans(layout, chosen, meta_cols, options, path)
    wanted = sorted(set(wanted))
    table = numeric_cells(rows, wanted, line_no, path=path, labels=labels, hint=_HINT)
    col = {j: table[:, k] for k, j in enumerate(wanted)}

    t, time_source, rate = _time_axis(layout, {k: col[j] for k, j in meta_cols.items()}, options, len(rows))
    out = []
    for name in chosen:
        fields = layout.blocks[name]
        rot, angles, seq, seq_source, angle_names = plans[name]
        pos = np.stack([col[fields[f]] for f in ("X", "Y", "Z")], axis=1) * scale
        lost = ~np.all(np.isfinite(pos), axis=1)
        if "Residual" in fields:
            lost |= col[fields["Residual"]] < 0  # QTM writes -1 for an untracked body
        quat, source = _body_quaternions(name, plans[name], fields, col, pos, lost, rows, line_no, labels, degrees,
                                         path)
        pos[lost] = np.nan
        quat[lost] = np.nan
        info = {
            "format": "qtm",
            "layout": layout.layout,
            "body": name,
            "bodies": list(layout.blocks),
            "length_unit": options.length_unit or "mm",
            "rotation_source": source,
            "rate_hz": rate,
            "time_source": time_source,
            "lost_frames": int(lost.sum()),
            "file_version": (layout.header.get("FILE_VERSION") or [None])[0],
            "events": [list(e) for e in layout.events],
        }
        if angles is not None:
            info["angle_columns"] = angle_names
        out.append(Trajectory(t=t, quat=quat, position=pos, name=name, source=str(path), info=info))
    return out


@reader_guard("a QTM 6D TSV file", _HINT)
def describe(path, options: ReadOptions | None = None) -> dict:
    """Plain-data summary for ``rbgp inspect`` (header fields, bodies, units, rotation, frames, rate),
    without parsing the numbers."""
    options = options or ReadOptions()
    layout = _Layout(path, read_text(path))
    bodies = {}
    needs = []
    for name, fields in layout.blocks.items():
        rot, angles, seq, seq_source, angle_names = layout.rotation_plan(fields, options)
        bodies[name] = {
            "rotation": "Rot[] matrix (column-major)" if rot is not None else (
                f"euler {seq} ({seq_source})" if seq else "unknown (use euler_order)"),
            "angle_columns": angle_names,
        }
        if rot is None and not seq and not needs:
            needs.append(f"euler_order (body {name!r} has no Rot[] matrix and angle columns "
                         f"{' '.join(angle_names) or 'none'} of unknown convention)")
    if "Time" in layout.meta:
        time_source = "Time column"
    elif layout.frequency() or options.rate:
        time_source = "(Frame - 1) / FREQUENCY" if "Frame" in layout.meta else "row / FREQUENCY"
    else:
        time_source = None
        freq = (layout.header.get("FREQUENCY") or ["missing"])[0]
        needs.append(f"rate HZ (FREQUENCY is {freq} and there is no Time column)")
    return {
        "format": "qtm",
        "layout": layout.layout,
        "header": {k: (v[0] if len(v) == 1 else v) for k, v in layout.header.items()},
        "events": layout.events,
        "bodies": list(layout.blocks),
        "body_details": bodies,
        "time_columns": [c for c in layout.meta],
        "length_unit": options.length_unit or "mm",
        "angle_unit": "deg",
        "frames": len(layout.data),
        "rate_hz": layout.frequency() or options.rate,
        "time_source": time_source,
        "needs": needs,
    }


def describe_rows(desc: dict) -> list[str]:
    """The text rows of ``rbgp inspect`` for :func:`describe`'s result."""
    from rbgp_cli.io.inspect import text_row as _row, rate_text as _rate

    h = desc.get("header", {})
    version = h.get("FILE_VERSION")
    layout = "current (Frame, Time, <Body> X ...)" if desc.get("layout") == "current" else \
        "old, before 2.0.0 (no Frame/Time columns, one header block for every body)"
    lines = [_row("layout", layout + (f", FILE_VERSION {version}" if version else ""))]
    if h.get("TIME_STAMP"):
        lines.append(_row("recorded", h["TIME_STAMP"] if isinstance(h["TIME_STAMP"], str) else h["TIME_STAMP"][0]))
    freq = h.get("FREQUENCY")
    rate = f"at {_rate(desc)}" if desc.get("rate_hz") else f"at no stated rate (FREQUENCY {freq or 'missing'})"
    lines.append(_row("frames", f"{desc.get('frames')} {rate}"
                                + (f", NO_OF_FRAMES {h['NO_OF_FRAMES']}" if h.get("NO_OF_FRAMES") else "")))
    lines.append(_row("time", desc.get("time_source") or "unknown: FREQUENCY is not a number and there is no Time column"))
    bodies = desc.get("bodies") or []
    lines.append(_row("bodies", f"{len(bodies)}: " + ", ".join(bodies)))
    details = desc.get("body_details") or {}
    rotations = {b: v.get("rotation") for b, v in details.items()}
    if len(set(rotations.values())) <= 1:
        rot = next(iter(rotations.values()), "-")
        angles = next(iter(details.values()), {}).get("angle_columns") or []
        lines.append(_row("rotation", rot + (f"; angle columns {' '.join(angles)}" if angles else "")))
    else:
        lines.append(_row("rotation", "; ".join(f"{b}: {r}" for b, r in rotations.items())))
    lines.append(_row("units", f"positions {desc.get('length_unit')}, angles {desc.get('angle_unit')}"))
    events = desc.get("events") or []
    if events:
        lines.append(_row("events", "; ".join(" ".join(e) for e in events)))
    return lines


FORMAT = Format(
    name="qtm", title="Qualisys QTM TSV", detect=detect, read=read, describe=describe, describe_rows=describe_rows,
    skip_reason=vendor.skip_reason(sniff, "QTM", not_6d), read_all=vendor.read_every_body(read),
    needs=vendor.body_needs, write=write_qtm_tsv, suffix=".tsv",
    honours=("body",),
)
