"""Generic CSV / TSV reader: the numbers, the rotation, the trajectories, ``describe`` and the fast path
for large files. Its parts: the table text (:mod:`rbgp_cli.io.csv_table`), which column is what
(:mod:`rbgp_cli.io.csv_columns`, with the vocabulary of :mod:`rbgp_cli.io.vocabulary`), units
(:mod:`rbgp_cli.io.csv_units`); the writer of rbgp's trajectory CSV is
:func:`rbgp_cli.io.export.write_trajectories_csv`.

Columns are found by **name** (case-insensitive; separators ``_ . - space`` are equivalent), never by
position or by guessing from values:

* time: ``t``, ``time``, ``timestamp``, ``stamp``, ``sec`` (also ``header.stamp``-style names ending in
  ``_time`` / ``_stamp``), numbers or ISO 8601 date-times; a ``sec`` + ``nanosec`` pair is added up; no
  time column → ``rate`` (``frame`` / rate when a frame column exists).
* position: ``x y z``, ``pos_x``, ``px``, ``tx``, ``position_x``, ``pose.position.x`` ...
* rotation, in this order of preference:
  quaternion with named components (``qx qy qz qw``, ``quat_x``, ``orientation_x``, ``rot_x..rot_w``,
  ``rx ry rz rw``) in any column order; numbered ``q0..q3`` / ``q1..q4`` (needs ``quat_order``);
  rotation vector ``rx ry rz``; Euler angles about named axes ``rot_x rot_y rot_z`` or ``roll pitch
  yaw`` (needs ``euler_order``, scipy's convention, and degrees/radians from the name or the option).
* several demonstrations in one file: a ``demo`` / ``trial`` / ``trajectory`` / ``episode`` /
  ``sequence`` column; each value becomes ``<file stem>#<value>`` in order of first appearance.

Units come from a suffix of the column name (``x_mm``, ``x [mm]``, ``x(cm)``, ``time_ms``, ``t [ns]``,
``yaw_deg``), from a ``# ... length_unit=m time_unit=s`` comment line above the header (as written by
:func:`write_trajectories_csv`), or from :class:`~rbgp_cli.io.options.ReadOptions`, which wins over the
file. When nothing states a unit: lengths are metres unless the values look like millimetres (median
``|p|`` > 10 → :class:`InputError` hinting ``length_unit mm``), and times are seconds unless the implied
sampling interval is implausible (median dt > 5 s or < 1e-5 s → :class:`InputError` naming the
``time_unit`` that makes it plausible).

Readers return *raw* trajectories (SI units, quaternions x, y, z, w): empty / NaN / ``null`` cells are
lost frames kept as NaN rows for :func:`rbgp_cli.dynamics.prepare.prepare_trajectory`; the cells that
mean "no value" are :data:`rbgp_cli.io.vocabulary.MISSING_TOKENS`, as in every reader.
"""

from __future__ import annotations

import io
import os
import re
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rbgp_cli.dynamics.trajectory import Trajectory
from rbgp_cli.errors import InputError, closest
from rbgp_cli.io.csv_columns import Plan, classify, columns_list, plan_columns, role_key, sniff_pose_columns
from rbgp_cli.io.csv_table import Table, decode, parse_table, split_fields
from rbgp_cli.io.csv_units import angles_in_degrees, infer_length_unit, infer_time_unit
from rbgp_cli.io.export import write_trajectories_csv  # the writer sits with the others
from rbgp_cli.io.formats import Format
from rbgp_cli.io.options import ReadOptions
from rbgp_cli.io.vocabulary import CANONICAL_KEYS, KIND_ROLES, LENGTH_UNITS, MISSING_TOKENS, TIME_UNITS

__all__ = ["read", "read_bytes", "read_text", "describe", "sniff_pose_columns", "write_trajectories_csv",
           "CANONICAL_KEYS", "FORMAT"]

#: Tables at least this large are parsed straight from the file (or bytes): only the columns that are
#: needed, as float64, never as one big decoded string (peak memory about the arrays read instead of
#: ten times the file). Anything that path does not cover falls back to the in-memory text path.
FAST_MIN_BYTES = 1 << 20
_FAST_HEAD = 1 << 16
# a line in the body that the text path would drop: blank, whitespace only, or a comment
_DROPPED_LINE = re.compile(rb"\n(?=[ \t\f\v]*(?:#|\r?\n|\r?\Z))")  # at the newline before such a line
_ODD_BREAKS = re.compile("[\r\x0b\x0c\x1c\x1d\x1e\x85\u2028\u2029]")  # splitlines() would break there
_ISO_START = re.compile(r"\s*\d{4}-\d{2}-\d{2}[T ]\d")


# --------------------------------------------------------------------------------------------------
# reading the numbers


def _row_width(table: Table) -> int:
    """How many fields to read per row: the header's, or more when the first rows end with empty fields
    the header lacks (a trailing delimiter). A longer row among the first 64 is an InputError naming it
    (pandas reports longer rows later in the file, except in the first row, whose extra fields it
    drops with a warning)."""
    width = len(table.header)
    head = [split_fields(row, table.delimiter) for row in table.data_text.split("\n", 64)[:64]]
    for fields in head:
        if len(fields) > width and not any(f.strip() for f in fields[width:]):
            width = len(fields)  # trailing empty fields only: ignored
    for k, fields in enumerate(head):
        if len(fields) > width:
            raise InputError(
                f"row has {len(fields)} fields, the header and the first rows have {width}",
                path=table.source,
                row=int(table.lines[k]),
                hint="check the delimiter and quoting of that row",
            )
    return width


def _csv_kwargs(table: Table, width: int) -> dict:
    """pandas.read_csv arguments shared by both paths: as many columns as ``width`` (short rows, e.g.
    lost frames, get NaN; longer rows are a ParserError), the table's delimiter and decimal mark."""
    kwargs = dict(header=None, names=list(range(width)), index_col=False, decimal=table.decimal, quotechar='"')
    kwargs["sep"] = r"\s+" if table.delimiter == "whitespace" else table.delimiter
    return kwargs


def _read_frame(table: Table, plan: Plan):
    """Parse the data lines (all of them in memory); returns {role: ndarray or list[str]}."""
    import pandas as pd

    demo_col = plan.roles.get("demo")
    dtype = {demo_col.index: "str"} if demo_col is not None else None
    if not table.data_text.strip():
        return None
    width = _row_width(table)
    kwargs = dict(_csv_kwargs(table, width), dtype=dtype, skip_blank_lines=False, low_memory=False)
    try:
        df = pd.read_csv(io.StringIO(table.data_text), **kwargs)
    except pd.errors.ParserError as exc:
        m = re.search(r"Expected (\d+) fields in line (\d+), saw (\d+)", str(exc))
        if m:
            k = int(m.group(2)) - 1
            line = int(table.lines[k]) if 0 <= k < len(table.lines) else None
            raise InputError(
                f"row has {m.group(3)} fields, the header and the first rows have {m.group(1)}",
                path=table.source,
                row=line,
                hint="check the delimiter and quoting of that row",
            ) from None
        raise InputError(f"cannot parse the table: {exc}", path=table.source) from None
    return _columns(df, table, plan)


def _columns(df, table: Table, plan: Plan) -> dict:
    """{role: float64 array, or an object array of str for ``demo``} from the parsed frame, whose
    column labels are the file's column indices. Non-numeric cells other than the missing-value
    tokens are an InputError naming the row."""
    import pandas as pd

    n = len(df)
    out: dict = {}
    for role, col in plan.roles.items():
        if col.index not in df.columns:
            out[role] = np.full(n, np.nan) if role != "demo" else np.full(n, "", dtype=object)
            continue
        series = df[col.index]
        if role == "demo":
            stripped = series.astype("str").str.strip()  # read as text; missing cells stay missing
            empty = (stripped.isna() | (stripped == "")).to_numpy(dtype=bool)
            if empty.any():
                k = int(np.argmax(empty))
                raise InputError(
                    f"empty {col.name!r} cell: every row needs a demonstration id",
                    path=table.source,
                    row=int(table.lines[k]),
                )
            out[role] = stripped.to_numpy(dtype=object)
            continue
        if series.dtype.kind in "fiub":
            out[role] = series.to_numpy(dtype=np.float64)
            continue
        text = series.astype(object)
        if role == "t":
            stamps = _iso_datetimes(text)
            if stamps is not None:
                out[role] = stamps
                out["t_datetime"] = True
                continue
        num = pd.to_numeric(text.where(text.notna(), None), errors="coerce").to_numpy(dtype=np.float64)
        bad = np.isnan(num) & text.notna().to_numpy()
        if bad.any():
            idx = np.flatnonzero(bad)
            lowered = [str(text.iloc[k]).strip().lower() for k in idx]
            real = [k for k, s in zip(idx, lowered) if s not in MISSING_TOKENS]
            if real:
                k = int(real[0])
                if _repeats_header(df, table, k):
                    raise InputError(
                        "a second header line: concatenated files? give them as separate files",
                        path=table.source,
                        row=int(table.lines[k]),
                        hint="pass the files (or their folder) instead of joining them",
                    )
                raise InputError(
                    f"non-numeric value {str(text.iloc[k])!r} in column {col.name!r}",
                    path=table.source,
                    row=int(table.lines[k]),
                    hint="fix the cell, or leave it empty to mark a lost frame",
                )
        out[role] = num
    return out


def _repeats_header(df, table: Table, k: int) -> bool:
    """Whether data row ``k`` holds the header's names again (files joined by ``cat a.csv b.csv``)."""
    names = [str(h).strip().lower() for h in table.header]
    cells = ["" if not isinstance(v, str) else v.strip().lower() for v in df.iloc[k].tolist()]
    return len(names) > 1 and cells[: len(names)] == names


def _iso_datetimes(text):
    """Seconds since the epoch (UTC; naive times taken as UTC) if every non-empty cell is an ISO 8601
    date-time such as ``2024-05-01T12:00:00.125``; else None."""
    import pandas as pd

    present = text[text.notna()]
    if present.empty:
        return None
    first = str(present.iloc[0])
    if not re.match(r"\s*\d{4}-\d{2}-\d{2}[T ]\d", first):
        return None
    ts = pd.to_datetime(text.where(text.notna(), None), format="ISO8601", errors="coerce", utc=True)
    if ts[text.notna()].isna().any():
        return None
    secs = (ts - pd.Timestamp("1970-01-01", tz="UTC")) / pd.Timedelta(seconds=1)
    return np.asarray(secs, dtype=np.float64)


# --------------------------------------------------------------------------------------------------
# rotation


def _rotation(plan: Plan, data: dict, options: ReadOptions, source: str):
    """Quaternions (N, 4) x, y, z, w (raw, not normalised) and a description."""
    kind = plan.rotation
    if kind == "quaternion":
        q = np.stack([data["qx"], data["qy"], data["qz"], data["qw"]], axis=-1)
        order = "".join(sorted("xyzw", key=lambda c: plan.roles[f"q{c}"].index))
        chosen = (options.quat_order or "").lower()
        if chosen in ("xyzw", "wxyz") and chosen != order:
            # quat_order overrides the labels: the four columns, in file order, are `chosen`
            in_file = np.stack([data[f"q{c}"] for c in order], axis=-1)
            q = in_file if chosen == "xyzw" else in_file[:, [1, 2, 3, 0]]
            return q, f"quaternion {chosen} (quat_order, over columns labelled {order})"
        return q, f"quaternion {order}" + (" (quat_order)" if chosen == order else "")
    if kind == "numbered":
        names = ", ".join(plan.roles[r].name for r in KIND_ROLES[kind])
        order = (options.quat_order or "").lower()
        if order not in ("xyzw", "wxyz"):
            raise InputError(
                f"quaternion columns {names} are numbered, so their order (scalar first or last) is unknown"
                + (f" (quat_order {options.quat_order!r} is not xyzw or wxyz)" if options.quat_order else ""),
                path=source,
                hint="pass quat_order xyzw (w last) or quat_order wxyz (w first)", param="quat_order"
            )
        raw = np.stack([data[r] for r in KIND_ROLES[kind]], axis=-1)
        q = raw if order == "xyzw" else raw[:, [1, 2, 3, 0]]
        return q, f"quaternion {order} (quat_order)"
    from scipy.spatial.transform import Rotation

    n = len(data["x"])
    q = np.full((n, 4), np.nan)
    if kind == "rotvec":
        rv = np.stack([data["rx"], data["ry"], data["rz"]], axis=-1)
        deg = angles_in_degrees(plan, kind, options, source)
        ok = np.all(np.isfinite(rv), axis=1)
        if ok.any():
            if deg:
                rv = np.deg2rad(rv)
            norms = np.linalg.norm(rv[ok], axis=1)
            if not deg and options.degrees is None and np.median(norms) > 2 * np.pi:
                raise InputError(
                    f"rotation vectors have median length {np.median(norms):.4g}, more than 2π radians",
                    path=source,
                    hint="if they are in degrees pass degrees=True", param="degrees"
                )
            q[ok] = Rotation.from_rotvec(rv[ok]).as_quat()
        return q, "rotation vector (deg)" if deg else "rotation vector (rad)"
    roles = KIND_ROLES[kind]
    axis_of = dict(zip(roles, "xyz"))
    names = ", ".join(plan.roles[r].name for r in roles)
    seq = options.euler_order
    if not seq:
        raise InputError(
            f"Euler angles ({names}) need their rotation order",
            path=source,
            hint="pass euler_order, scipy's convention: lowercase extrinsic (e.g. xyz), uppercase "
            "intrinsic (e.g. ZYX)", param="euler_order"
        )
    if not re.fullmatch(r"[xyz]{3}|[XYZ]{3}", seq) or len(set(seq.lower())) != 3:
        raise InputError(
            f"euler_order {seq!r}: the columns name the axis of each angle, so the order must use each of "
            "x, y, z once, all lowercase (extrinsic) or all uppercase (intrinsic)",
            path=source, param="euler_order"
        )
    deg = angles_in_degrees(plan, kind, options, source)
    by_axis = {axis_of[r]: data[r] for r in roles}
    angles = np.stack([by_axis[a] for a in seq.lower()], axis=-1)
    ok = np.all(np.isfinite(angles), axis=1)
    if ok.any():
        q[ok] = Rotation.from_euler(seq, angles[ok], degrees=deg).as_quat()
    return q, f"euler {seq} ({'deg' if deg else 'rad'})"


# --------------------------------------------------------------------------------------------------
# public API


def _stem(source: str) -> str:
    if source in ("-", ""):
        return "stdin"
    return Path(source).stem


def read(path, options: ReadOptions | None = None) -> list[Trajectory]:
    """Read one CSV/TSV file into raw trajectories (one per demo id, or one for the file).

    A file of at least :data:`FAST_MIN_BYTES` is parsed from disk, only the needed columns, with fixed
    dtypes (memory-mapped for the checks), when its layout allows (UTF-8, one header, no blank or
    comment lines among the rows, numbers where numbers belong); otherwise, and for smaller files,
    the whole text is parsed in memory. Both give the same trajectories and the same errors.

    Parameters
    ----------
    path : str or Path
    options : ReadOptions, optional

    Returns
    -------
    list of Trajectory
        Raw: seconds, metres, quaternions x, y, z, w; lost frames are NaN rows.
    """
    path = str(path)
    options = options or ReadOptions()
    with file_errors(path):
        if os.path.getsize(path) >= max(FAST_MIN_BYTES, 1):
            out = _read_mapped(path, options)
            if out is not None:
                return out
        data = Path(path).read_bytes()
    return read_bytes(data, path, options)


@contextmanager
def file_errors(path: str, folder_hint: str = "pass the files inside it"):
    """Opening or reading ``path`` inside this block: a missing file, a folder or another OS error becomes one
    :class:`~rbgp_cli.errors.InputError` naming the file."""
    try:
        yield
    except FileNotFoundError:
        raise InputError("file not found", path=path, hint="check the path") from None
    except IsADirectoryError:
        raise InputError("is a directory, not a file", path=path, hint=folder_hint) from None
    except OSError as exc:
        raise InputError(f"cannot read the file ({exc.strerror or exc})", path=path) from None


def _read_mapped(path: str, options: ReadOptions):
    """The fast path on a memory map of the file (None: the text path must read it)."""
    import mmap

    try:
        with open(path, "rb") as fh, mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as buf:
            fast = _fast_plan(buf, path, options)  # unmapped before parsing, so its pages leave RSS
    except (ValueError, OSError):  # not mappable (a pipe, a special file): read it as text
        return None
    return _fast_parse(fast, lambda: open(path, "rb"), options, path) if fast else None


def read_bytes(data: bytes, source: str, options: ReadOptions | None = None) -> list[Trajectory]:
    """Like :func:`read` for the bytes of a file (e.g. stdin); ``source`` names it in messages."""
    options = options or ReadOptions()
    if len(data) >= FAST_MIN_BYTES:
        fast = _fast_plan(data, source, options)
        out = _fast_parse(fast, lambda: io.BytesIO(data), options, source) if fast else None  # shares the bytes
        if out is not None:
            return out
    return read_text(decode(data, source), source, options)


def _max_fields(buf, offset: int, delimiter: bytes, chunk: int = 1 << 22) -> int:
    """The largest number of ``delimiter``-separated fields on one line of ``buf[offset:]`` (no
    quoting), counted in chunks of whole lines (bounded memory, numpy speed)."""
    most, start, end = 0, offset, len(buf)
    while start < end:
        stop = min(start + chunk, end)
        if stop < end:
            cut = buf.rfind(b"\n", start, stop)
            stop = cut + 1 if cut >= start else end
        a = np.frombuffer(buf, dtype=np.uint8, count=stop - start, offset=start)
        ends = np.flatnonzero(a == 10)  # each line's last byte: its newline ...
        if a[-1] != 10:
            ends = np.append(ends, len(a) - 1)  # ... or the end of the file
        delims = np.flatnonzero(a == delimiter[0])
        per_line = np.diff(np.searchsorted(delims, ends, side="right"), prepend=0)
        most = max(most, int(per_line.max(initial=0)) + 1)
        start = stop
    return most


@dataclass
class _Fast:
    """How to parse a table straight from its bytes (see :func:`_fast_plan`)."""

    table: Table
    cols: list
    plan: Plan
    offset: int  # byte offset of the first data row
    kwargs: dict  # for pandas.read_csv


def _fast_plan(buf, source: str, options: ReadOptions):
    """How to parse the table in ``buf`` (bytes or a memory map of the file) without building its
    text, or None when the text path must read it.

    The header, the column plan and the first rows come from the first 64 KiB, through the same
    functions as the text path (so the same errors); the rest of ``buf`` is only scanned (no line
    the text path would drop, no row with too many fields). None (text path) for what only the text
    path handles: UTF-16 or non-UTF-8 text, line breaks other than LF/CRLF, blank or comment lines
    among the rows, ISO date-times, rows with too many fields (the text path names them).
    """
    head = bytes(buf[:_FAST_HEAD])
    if head[:2] in (b"\xff\xfe", b"\xfe\xff") or b"\x00" in head:
        return None
    cut = head.rfind(b"\n")
    if cut < 0:
        return None
    head = head[: cut + 1]
    try:
        text = head.decode("utf-8-sig")
    except UnicodeDecodeError:
        return None
    if _ODD_BREAKS.search(text.replace("\r\n", "\n")):
        return None
    ctrl = sum(1 for ch in text[:4096] if ord(ch) < 32 and ch not in "\r\n\t\f\v")
    if ctrl > 0.05 * min(len(text), 4096):
        return None  # binary: the text path says so
    try:
        table = parse_table(text, source)
    except InputError:
        return None  # e.g. comments longer than the head: the text path decides
    if len(table.lines) == 0 or np.any(np.diff(table.lines) != 1):
        return None
    cols = [classify(i, name) for i, name in enumerate(table.header)]
    plan = plan_columns(cols, options, source)
    width = _row_width(table)
    if "t" in plan.roles:
        first = split_fields(table.data_text.split("\n", 1)[0], table.delimiter)
        k = plan.roles["t"].index
        if k < len(first) and _ISO_START.match(first[k]):
            return None
    # the byte offset of the first data row, and no line the text path would drop after it
    first_line = int(table.lines[0])
    offset = 0
    for _ in range(first_line - 1):
        offset = head.index(b"\n", offset) + 1
    end = len(buf)
    m = _DROPPED_LINE.search(buf, max(offset - 1, 0))
    if m is not None and m.start() < end - 1:
        if end - m.start() > _FAST_HEAD or bytes(buf[m.start():]).strip(b"\r\n"):
            return None  # not just blank lines at the very end (pandas skips those)
    used = sorted({c.index for c in plan.roles.values()})
    demo = plan.roles.get("demo")
    if table.delimiter != "whitespace" and buf.find(b'"', offset) < 0:
        # only the needed columns; pandas then accepts rows with too many fields, so count them first
        if _max_fields(buf, offset, table.delimiter.encode()) > width:
            return None
        usecols, numeric = used, used
    else:  # quoted fields may hold delimiters: let pandas check the field count, on every column
        usecols, numeric = None, range(width)
    dtype = {j: np.float64 for j in numeric}
    if demo is not None:
        dtype[demo.index] = str
    kwargs = dict(_csv_kwargs(table, width), usecols=usecols, dtype=dtype, skip_blank_lines=True,
                  encoding="utf-8", engine="c", low_memory=True)  # fmt: skip
    return _Fast(table=table, cols=cols, plan=plan, offset=offset, kwargs=kwargs)


def _fast_parse(fast: _Fast, reopen, options: ReadOptions, source: str):
    """Parse the rows as :func:`_fast_plan` planned, from the stream ``reopen()`` (positioned at the
    first row), into raw trajectories; None when a cell is not a number or a standard missing-value
    token, or a row is malformed (the text path then names it)."""
    from dataclasses import replace

    first_line = int(fast.table.lines[0])
    data = _numeric_columns(fast, reopen)  # numbers only: numpy's parser, without importing pandas
    if data is not None:
        n = len(next(iter(data.values())))
    else:
        import pandas as pd

        try:
            with reopen() as stream:
                stream.seek(fast.offset)
                df = pd.read_csv(stream, **fast.kwargs)
        except (ValueError, pd.errors.ParserError, UnicodeDecodeError, OverflowError):
            return None
        n = len(df)
    table = replace(fast.table, lines=np.arange(first_line, first_line + n, dtype=np.int64), data_text="")
    if data is None:
        data = _columns(df, table, fast.plan)
        del df
    return _trajectories(table, fast.cols, fast.plan, data, options, source)


def _numeric_columns(fast: _Fast, reopen) -> dict | None:
    """{role: float64 column} parsed by ``numpy.loadtxt`` when every needed cell is a plain number (or
    nan/inf) in an unquoted table with a '.' decimal mark and no demo column; None otherwise (an empty
    or missing-value cell, a short row, text: the pandas path reads or names it).

    Why not pandas here: importing pandas costs ~65 MB of memory, as much as the poses of a 10⁶-row
    file, and numpy's parser fills one (rows, columns) array without a copy per column."""
    usecols = fast.kwargs.get("usecols")
    if usecols is None or fast.table.decimal != "." or "demo" in fast.plan.roles:
        return None
    try:
        with reopen() as stream:
            stream.seek(fast.offset)
            arr = np.loadtxt(stream, delimiter=fast.table.delimiter, usecols=usecols, dtype=np.float64,
                             comments=None, ndmin=2, encoding="utf-8", quotechar=None)
    except (ValueError, UnicodeDecodeError, OverflowError):
        return None
    if arr.shape[0] == 0:
        return None
    pos = {c: k for k, c in enumerate(usecols)}
    return {role: arr[:, pos[col.index]] for role, col in fast.plan.roles.items()}


def read_text(text: str, source: str, options: ReadOptions | None = None) -> list[Trajectory]:
    """Like :func:`read` for already decoded text."""
    options = options or ReadOptions()
    table = parse_table(text, source)
    cols = [classify(i, name) for i, name in enumerate(table.header)]
    plan = plan_columns(cols, options, source)
    data = _read_frame(table, plan)
    return _trajectories(table, cols, plan, data, options, source)


def _groups(demo) -> dict:
    """{demo id: row indices (ascending)} in order of first appearance."""
    import pandas as pd

    codes, uniques = pd.factorize(np.asarray(demo, dtype=object), sort=False)
    order = np.argsort(codes, kind="stable")
    bounds = np.cumsum(np.bincount(codes, minlength=len(uniques)))[:-1]
    return dict(zip(uniques.tolist(), np.split(order, bounds)))


def _times(table: Table, cols: list, plan: Plan, data, options: ReadOptions, groups: dict, source: str):
    """(t (n,) seconds, the facts of the time for ``info``): the time column (seconds + nanoseconds,
    ISO dates, or its unit inferred), else ``--rate`` per frame or per row of each demonstration
    (``groups``); an error, naming a likely time column, without either."""
    n = len(data["x"])
    # time
    if "t" in plan.roles:
        if data.get("t_datetime"):
            t = data["t"]
            unit, unit_source = "s", "ISO 8601 date-times"
        elif "t_nsec" in plan.roles:
            t = data["t"] + data["t_nsec"] * 1e-9
            unit, unit_source = "s", "sec + nanosec columns"
        else:
            unit, unit_source = infer_time_unit(plan, table, options, data["t"], groups)
            t = data["t"] * TIME_UNITS[unit]
        time_info = {"time_unit": unit, "time_unit_source": unit_source}
        if options.rate:  # the file's own times are used; the reader says the rate was not (read_sources)
            time_info["rate_option_unused"] = plan.roles["t"].name
    else:
        if not options.rate:
            tcands = [c.name for c in cols if any(w in c.base for w in ("time", "stamp", "sec"))]
            if not tcands:  # a misspelled time column ('tme', 'tiem'): the closest unused name
                used = {c.index for c in plan.roles.values()}
                guess = closest("time", [c.name for c in cols if c.index not in used])
                tcands = [guess] if guess else []
            raise InputError(
                f"no time column (columns are {columns_list(cols)})",
                path=source,
                hint=(f"did you mean {tcands[0]!r}? pass columns t={tcands[0]}, or rate HZ" if tcands else "pass rate HZ"),
                param=("rate", "columns") if tcands else "rate",
            )
        rate = float(options.rate)
        if not np.isfinite(rate) or rate <= 0:
            raise InputError(f"rate must be a positive number of Hz, got {options.rate!r}", param="rate")
        t = np.empty(n)
        if "frame" in plan.roles:
            t = data["frame"] / rate
            time_info = {"time_unit": "frame / rate", "time_unit_source": "frame column and --rate"}
        else:
            for idx in groups.values():
                t[idx] = np.arange(len(t[idx])) / rate
            time_info = {"time_unit": "row / rate", "time_unit_source": "--rate"}
        time_info["rate_option_hz"] = rate
    return t, time_info


def _trajectories(table: Table, cols: list, plan: Plan, data, options: ReadOptions, source: str) -> list:
    """Raw trajectories from the parsed columns: demonstrations split by the ``demo`` column, times,
    units, rotations and the facts in ``info``."""
    if data is None or len(data["x"]) == 0:
        raise InputError("the file has a header but no data rows", path=source, row=table.header_line,
                         hint="the export stopped before the first sample: export or record it again")
    # groups of rows (demonstrations); one group is a slice, so its arrays are views, not copies
    groups = _groups(data["demo"]) if "demo" in plan.roles else {None: slice(None)}
    t, time_info = _times(table, cols, plan, data, options, groups, source)
    position = np.stack([data["x"], data["y"], data["z"]], axis=-1)
    length_unit, length_source = infer_length_unit(plan, table, options, position)
    if LENGTH_UNITS[length_unit] != 1.0:
        position *= LENGTH_UNITS[length_unit]  # a new array (np.stack): scaled in place
    quat, rotation = _rotation(plan, data, options, source)
    colmap = {}
    order = {k: i for i, k in enumerate(("t", "t_nsec", "frame", "demo", "x", "y", "z"))}
    for role, col in sorted(plan.roles.items(), key=lambda rc: (order.get(rc[0], 99), rc[1].index)):
        colmap[role_key(role)] = col.name
    base_info = {
        "format": "csv",
        "columns": colmap,
        "delimiter": table.delimiter,
        "length_unit": length_unit,
        "length_unit_source": length_source,
        **time_info,
        "rotation": rotation,
    }
    stem = _stem(source)
    out = []
    for demo, idx in groups.items():
        tt = t[idx]
        d = np.diff(tt[np.isfinite(tt)])
        d = d[d > 0]
        info = dict(base_info)
        info["rate_hz"] = float(1.0 / np.median(d)) if len(d) else None
        lines = table.lines[idx]
        if len(lines) and np.all(np.diff(lines) == 1):
            info["first_data_line"] = int(lines[0])
        else:
            info["line_runs"] = _runs(lines)
        name = stem
        if demo is not None:
            info["demo"] = demo
            name = f"{stem}#{demo}"
        out.append(Trajectory(t=tt, quat=quat[idx], position=position[idx], name=name, source=source, info=info))
    return out


def _runs(lines: np.ndarray) -> list:
    """[[first_line, count], ...] for the consecutive runs of ``lines``."""
    if len(lines) == 0:
        return []
    breaks = np.flatnonzero(np.diff(lines) != 1) + 1
    starts = np.concatenate([[0], breaks])
    ends = np.concatenate([breaks, [len(lines)]])
    return [[int(lines[s]), int(e - s)] for s, e in zip(starts, ends)]


def describe(path, options: ReadOptions | None = None, *, text: str | None = None) -> dict:
    """The header of a CSV file and what each column would be taken as (nothing is converted).

    Returns plain data: ``{"delimiter", "header_line", "columns": [{"name", "taken_as", "unit"}],
    "rotation", "problem"}``; ``problem`` is the message of the error reading would raise about the
    columns (None if they are fine).
    """
    options = options or ReadOptions()
    source = str(path)
    rows = None
    if text is None:
        table, rows = _describe_big(source)
        if table is None:
            text = decode(Path(source).read_bytes(), source)
    if text is not None:
        table = parse_table(text, source)
    cols = [classify(i, name) for i, name in enumerate(table.header)]
    problem = None
    taken: dict = {}
    rotation = None
    needs = []
    try:
        plan = plan_columns(cols, options, source)
        rotation = plan.rotation
        for role, col in plan.roles.items():
            taken[col.index] = role_key(role)
        if "t" not in plan.roles and not options.rate:
            problem = "no time column; pass rate HZ"
            needs.append("rate HZ (no time column)")
        if rotation == "numbered" and (options.quat_order or "").lower() not in ("xyzw", "wxyz"):
            needs.append("quat_order xyzw or wxyz (the quaternion columns are numbered)")
        if rotation in ("euler_axis", "rpy") and not options.euler_order:
            needs.append("euler_order (the Euler angle columns do not say their order)")
    except InputError as exc:
        problem = str(exc)
    columns = [
        {"name": c.name, "taken_as": taken.get(c.index), "unit": c.unit}
        for c in cols
    ]
    return {
        "delimiter": table.delimiter,
        "header_line": table.header_line,
        "data_rows": int(len(table.lines)) if rows is None else rows,
        "declared": table.declared,
        "columns": columns,
        "rotation": rotation,
        "problem": problem,
        "needs": needs,
    }


def _describe_big(source: str):
    """For a file of at least :data:`FAST_MIN_BYTES`: the table parsed from its first 64 KiB and the
    number of data rows counted on a memory map (lines after the header that are not blank or
    comments), without decoding the file; ``(None, None)`` when the head does not hold the header."""
    import mmap

    try:
        if os.path.getsize(source) < max(FAST_MIN_BYTES, 1):
            return None, None
        with open(source, "rb") as fh, mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as buf:
            head = bytes(buf[:_FAST_HEAD])
            cut = head.rfind(b"\n")
            if cut < 0 or head[:2] in (b"\xff\xfe", b"\xfe\xff"):
                return None, None
            try:
                text = head[: cut + 1].decode("utf-8-sig")
            except UnicodeDecodeError:
                text = head[: cut + 1].decode("latin-1")
            try:
                table = parse_table(text, source)
            except InputError:
                return None, None
            if len(table.lines) == 0:
                return None, None
            offset = 0
            for _ in range(int(table.lines[0]) - 1):
                offset = head.index(b"\n", offset) + 1
            newlines = sum(bytes(buf[i : i + (1 << 22)]).count(b"\n") for i in range(offset, len(buf), 1 << 22))
            lines = newlines + (0 if buf[len(buf) - 1 : len(buf)] == b"\n" else 1)
            dropped = sum(1 for _ in _DROPPED_LINE.finditer(buf, offset - 1)) - (buf[-1:] == b"\n")
            return table, int(lines - dropped)
    except (OSError, ValueError):
        return None, None


def describe_rows(desc: dict) -> list[str]:
    """The text rows of ``rbgp inspect`` for :func:`describe`'s result."""
    from rbgp_cli.io.inspect import text_row as _row, DELIMITER_NAMES as _DELIMITERS
    from rbgp_cli.wording import plural as _plural

    lines = [_row("table", f"{_DELIMITERS.get(desc.get('delimiter'), desc.get('delimiter'))}-separated, "
                           f"header on line {desc.get('header_line')}, {_plural(desc.get('data_rows') or 0, 'data row')}")]
    if desc.get("declared"):
        lines.append(_row("declared", ", ".join(f"{k} {v}" for k, v in desc["declared"].items())))
    lines.append("  columns:")
    for c in desc.get("columns", []):
        taken = c.get("taken_as") or "(ignored)"
        unit = f" [{c['unit']}]" if c.get("unit") else ""
        lines.append(f"    {c['name']!s:<24} -> {taken}{unit}")
    return lines


def _skip_reason(head: bytes, path, options: ReadOptions | None = None, complete: bool = False) -> str | None:
    return sniff_pose_columns(head, path, options, complete=complete)


FORMAT = Format(
    name="csv", title="generic CSV", read=read, read_bytes=read_bytes, describe=describe, describe_rows=describe_rows,
    skip_reason=_skip_reason, write=write_trajectories_csv, fallback=True,
    honours=("columns",),
)
