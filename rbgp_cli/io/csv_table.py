"""The text of a CSV/TSV table (:mod:`rbgp_cli.io.csv`): decoding, the delimiter and decimal mark,
comment lines (and the units they declare) above the header, the header, and the data lines with
their line numbers in the file.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from rbgp_cli.errors import InputError

__all__ = ["Table", "decode", "parse_table", "split_fields", "sniff_delimiter", "is_number"]


@dataclass
class Table:
    source: str
    header: list  # column names as in the file
    header_line: int  # 1-based
    data_text: str  # the data lines joined (comments/blank lines removed)
    lines: np.ndarray  # 1-based file line of every data row
    delimiter: str  # "," ";" "\t" or "whitespace"
    decimal: str
    declared: dict  # from "# key=value" comment lines above the header


def _formats_said() -> str:
    """"rbgp reads …": the registered formats' titles, so that a new format is named here without editing it."""
    from rbgp_cli.io import formats

    return "rbgp reads " + ", ".join(formats.get(n).title for n in formats.names())


def decode(data: bytes, source: str) -> str:
    if not data.strip():
        raise InputError("the file is empty", path=source, hint="export the demonstrations again")
    if data[:2] in (b"\xff\xfe", b"\xfe\xff"):  # UTF-16 with a BOM (Excel's "Unicode Text" export)
        try:
            return data.decode("utf-16")
        except UnicodeDecodeError:
            pass
    head = data[:8192]
    if b"\x00" in head:
        raise InputError(
            "not a text file (it contains binary data)",
            path=source,
            hint=_formats_said(),
        )
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError:
        text = data.decode("latin-1")
    ctrl = sum(1 for ch in text[:4096] if ord(ch) < 32 and ch not in "\r\n\t\f\v")
    if ctrl > 0.05 * min(len(text), 4096):
        raise InputError(
            "not a text file (it contains binary data)",
            path=source,
            hint=_formats_said(),
        )
    return text


def split_fields(line: str, delimiter: str, source: str | None = None, line_no: int | None = None) -> list[str]:
    """The fields of one line (quotes honoured); an InputError for a cell longer than the csv
    module's field limit (128 Ki characters): no pose table has one."""
    import csv as _csv

    if delimiter == "whitespace":
        return line.split()
    try:
        return next(_csv.reader([line], delimiter=delimiter))
    except _csv.Error as exc:
        raise InputError(f"a cell longer than {_csv.field_size_limit()} characters ({exc}): not a table of poses",
                         path=source, row=line_no, hint="check that this is the exported CSV/TSV file") from None


def is_number(s: str) -> bool:
    try:
        float(s.replace(",", "."))
        return True
    except ValueError:
        return False


def sniff_delimiter(line: str) -> str:
    counts = {d: line.count(d) for d in (",", ";", "\t")}
    best = max(counts, key=lambda d: counts[d])
    if counts[best] > 0:
        return best
    return "whitespace"


def parse_table(text: str, source: str) -> Table:
    all_lines = text.splitlines()
    comments: list[tuple[int, str]] = []
    header = None
    header_line = 0
    data_start = None
    for i, line in enumerate(all_lines):
        s = line.strip()
        if not s:
            continue
        if s.startswith("#"):
            comments.append((i, s.lstrip("#").strip()))
            continue
        header, header_line, data_start = s, i + 1, i + 1
        break
    if header is None:
        raise InputError("the file has no header and no data (only comments or blank lines)", path=source)
    delimiter = sniff_delimiter(header)
    names = [f.strip() for f in split_fields(header, delimiter, source, header_line)]
    if names and all(is_number(f) for f in names if f.strip()):
        # No header line. numpy.savetxt writes it as a comment ("# t,x,y,...") just above the data.
        cand_fields = None
        if comments:
            cand = comments[-1][1]
            cand_fields = [f.strip() for f in split_fields(cand, sniff_delimiter(cand), source, comments[-1][0] + 1)]
            if len(cand_fields) != len(names) or any(is_number(f) for f in cand_fields):
                cand_fields = None
        if cand_fields is None:
            raise InputError(
                "no header line: the first line holds numbers",
                path=source,
                row=header_line,
                hint="add a header such as t,x,y,z,qx,qy,qz,qw (rbgp finds columns by name)",
            )
        names = cand_fields
        data_start = header_line - 1
        header_line = comments[-1][0] + 1
        comments = comments[:-1]
    declared: dict = {}
    for _, c in comments:
        for key, value in re.findall(r"(\w+)\s*=\s*([\w]+)", c):
            if key in ("length_unit", "time_unit", "quaternion"):
                declared[key] = value.lower()
    # data lines: drop blank lines and comments, remember the file line of each row
    keep_idx = []
    keep = []
    for i in range(data_start, len(all_lines)):
        line = all_lines[i]
        s = line.lstrip()
        if not s or s.startswith("#"):
            continue
        keep_idx.append(i + 1)
        keep.append(line)
    decimal = "."
    if delimiter == ";" and keep and re.search(r"\d,\d", keep[0]):
        decimal = ","
    return Table(
        source=source,
        header=names,
        header_line=header_line,
        data_text="\n".join(keep),
        lines=np.asarray(keep_idx, dtype=np.int64),
        delimiter=delimiter,
        decimal=decimal,
        declared=declared,
    )
