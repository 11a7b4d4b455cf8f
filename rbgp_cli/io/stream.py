"""Poses arriving as CSV rows (``rbgp follow``): a header line, then one row at a time.

The header and the first row are read by the CSV reader itself (:func:`rbgp_cli.io.csv.read_text`),
which finds the time, position and rotation columns and their units as it does for a file. When the
rotation is a quaternion in named columns, each later row is split and converted directly (the same
columns and unit factors); any other layout (Euler angles, a rotation matrix, ...) reads each row
through the CSV reader with the header. Rows: SI units and quaternions x, y, z, w out.

A lost frame (a row whose pose cells are empty or NaN, or whose quaternion is zero, as trackers mark an
occluded body) is not a pose: :meth:`RowStream.parse` returns it as :class:`Lost` (its time, where the row has
one), for the caller to skip or fill, as a file's lost frames are dropped or filled.
"""

from __future__ import annotations

import numpy as np

from rbgp_cli.errors import InputError

__all__ = ["RowStream", "Lost", "check_streamable", "open_stream"]


class Lost:
    """A lost frame of a stream (module docstring): ``t`` its time in s (None where the row has none), ``row`` its
    row number."""

    __slots__ = ("t", "row")

    def __init__(self, t, row: int):
        self.t, self.row = t, row

    def __repr__(self) -> str:
        return f"Lost(t={self.t!r}, row={self.row})"


def _lost(cells) -> bool:
    """Pose cells that mark a lost frame: every one empty or NaN."""
    return all(not c.strip() or c.strip().lower() in ("nan", "-nan", "na", "null") for c in cells)

_LENGTH = {"m": 1.0, "mm": 1e-3, "cm": 1e-2, "dm": 0.1, "km": 1e3, "in": 0.0254, "ft": 0.3048}
_TIME = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6, "ns": 1e-9, "min": 60.0}


class RowStream:
    """Parse rows of one CSV table that arrive one at a time (module docstring). ``header``: the header
    line; ``options``: the :class:`~rbgp_cli.io.options.ReadOptions`; ``source``: the name in errors."""

    def __init__(self, header: str, options=None, source: str = "stdin"):
        from rbgp_cli.io.options import ReadOptions

        self.header = header.rstrip("\r\n")
        self.options = options or ReadOptions()
        self.source = source
        self._fast = None
        self._row = 1
        self._last_t = None  # the previous row's time (s)
        self._rate = None  # with no time column, the rate option: a row's time is its index / rate
        self._rows = 0  # data rows parsed

    def _first(self, line: str):
        from rbgp_cli.io.csv import read_text
        from rbgp_cli.io.csv_table import parse_table

        trajs = read_text(self.header + "\n" + line + "\n", self.source, self.options)
        if len(trajs) != 1 or len(trajs[0].t) != 1:
            raise InputError("a streamed row must hold one pose of one rigid body", path=self.source, row=self._row + 1,
                             hint="stream one body's rows (time, position, quaternion)")
        info = trajs[0].info
        cols = info.get("columns") or {}
        if "t" not in cols and info.get("rate_option_hz"):  # each row read alone would be at t = 0
            self._rate = float(info["rate_option_hz"])
        kind = str(info.get("rotation", ""))
        if kind.startswith("quaternion") and all(k in cols for k in ("t", "x", "y", "z", "qx", "qy", "qz", "qw")):
            table = parse_table(self.header + "\n" + line + "\n", self.source)
            names = list(table.header)
            try:
                idx = [names.index(cols[k]) for k in ("t", "x", "y", "z", "qx", "qy", "qz", "qw")]
            except ValueError:
                idx = None
            lu, tu = info.get("length_unit", "m"), info.get("time_unit", "s")
            if idx is not None and lu in _LENGTH and tu in _TIME:
                self._fast = (idx, table.delimiter, _LENGTH[lu], _TIME[tu])
        return trajs[0]

    def parse(self, line: str):
        """(t s, quat (4,) x, y, z, w, position (3,) m) of one data row, :class:`Lost` for a lost frame (module
        docstring), or None for a blank line."""
        line = line.rstrip("\r\n")
        self._row += 1
        if not line.strip():
            return None
        if self._row == 2 or self._fast is None:
            tr = self._first(line) if self._row == 2 else self._slow(line)
            q = np.asarray(tr.quat[0], dtype=float)
            t = float(tr.t[0]) if self._rate is None else self._rows / self._rate  # a file's row / rate
            self._rows += 1
            if not (np.all(np.isfinite(q)) and np.all(np.isfinite(tr.position[0])) and np.linalg.norm(q) > 1e-9):
                return Lost(self._in_order(t) if np.isfinite(t) else None, self._row)
            return self._in_order(t), q / self._unit_norm(q), tr.position[0].astype(float)
        idx, delim, lf, tf = self._fast
        parts = line.split(delim) if delim not in ("whitespace", None) else line.split()
        try:
            v = [float(parts[i]) for i in idx]
        except (IndexError, ValueError):
            if len(parts) > max(idx) and _lost([parts[i] for i in idx[1:]]):
                try:
                    t = float(parts[idx[0]]) * tf
                except ValueError:
                    t = None
                return Lost(self._in_order(t) if t is not None and np.isfinite(t) else None, self._row)
            raise InputError(f"row {self._row} is not a pose row like the header says ({line[:60]!r})",
                             path=self.source, row=self._row,
                             hint="stream rows with the header's columns, numbers only (a lost frame: its pose cells "
                                  "empty or NaN)") from None
        q = np.array(v[4:8])
        if not np.all(np.isfinite(v[1:])) or np.linalg.norm(q) < 1e-9:
            return Lost(self._in_order(v[0] * tf) if np.isfinite(v[0]) else None, self._row)
        return self._in_order(v[0] * tf), q / self._unit_norm(q), np.array(v[1:4]) * lf

    def _in_order(self, t: float) -> float:
        """A row's time, refused where it does not come after the previous row's."""
        if self._last_t is not None and not t > self._last_t:
            raise InputError(f"row {self._row} is at t = {t:g} s, not after the previous row's {self._last_t:g} s",
                             path=self.source, row=self._row, hint="stream the rows in time order, each time once")
        self._last_t = t
        return t

    def _unit_norm(self, q) -> float:
        """The norm of a row's quaternion, refused (as the file reader refuses it) where it is far from 1."""
        from rbgp_cli.dynamics.prepare import UNIT_TOLERANCE

        nq = float(np.linalg.norm(q))
        if not abs(nq - 1.0) <= UNIT_TOLERANCE:
            raise InputError(f"row {self._row} has a quaternion of norm {nq:.6g}, far from 1 (tolerance {UNIT_TOLERANCE:g})",
                             path=self.source, row=self._row, param="columns",
                             hint="check the column mapping, the quaternion order and units (columns, quat_order); "
                             "a unit quaternion's components lie in [-1, 1]")
        return nq

    def _slow(self, line: str):
        from rbgp_cli.io.csv import read_text

        trajs = read_text(self.header + "\n" + line + "\n", self.source, self.options)
        if len(trajs) != 1 or len(trajs[0].t) != 1:
            raise InputError(f"row {self._row} does not hold one pose", path=self.source, row=self._row,
                             hint="stream one body's rows")
        return trajs[0]


def check_streamable(header: str, source: str, path: str | None = None) -> None:
    """Refuse, in one line, a stream that is not CSV rows: a file of a format read whole (QTM, Motive, Vicon, C3D,
    BVH, MCAP: recognised from the file's first bytes when ``path`` names it, else from the ``header`` line), or
    binary data. ``header``: the stream's first line as read (text, undecodable bytes as surrogates)."""
    from rbgp_cli.io import formats
    from rbgp_cli.io.csv_table import decode
    from rbgp_cli.io.read import detect_format

    head = header.encode("utf-8", "surrogateescape")
    fmt = detect_format(path) if path else formats.detect(head)
    if fmt != "csv":
        raise InputError(f"{formats.get(fmt).title}: a format read from whole files, and a stream is CSV rows (a "
                         "header line, then one pose per row)", path=source, param="format",
                         hint="stream a CSV of time, position and quaternion columns; a recorded file in that "
                              "format is continued whole, as a seen beginning")
    decode(head, source)  # binary data: "not a text file", naming the formats rbgp reads


def open_stream(path: str):
    """A CSV file opened to be read as a stream of text lines (``rbgp follow MODEL FILE``), a missing or unreadable
    file one clear error (:func:`~rbgp_cli.io.csv.file_errors`)."""
    from rbgp_cli.io.csv import file_errors

    with file_errors(path, "pass one CSV file, or - for stdin"):
        return open(path, "r", encoding="utf-8", errors="surrogateescape", newline="")
