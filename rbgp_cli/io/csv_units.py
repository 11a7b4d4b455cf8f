"""Units of a CSV/TSV table (:mod:`rbgp_cli.io.csv`): from the options, a unit suffix of the column
name, a ``# length_unit=...`` comment, or else inferred from the values (millimetres that look like
metres, implausible sampling intervals), with an error naming the option that decides.
"""

from __future__ import annotations

import numpy as np

from rbgp_cli.errors import InputError
from rbgp_cli.io.csv_columns import Plan
from rbgp_cli.io.csv_table import Table
from rbgp_cli.io.options import ReadOptions
from rbgp_cli.io.vocabulary import KIND_ROLES, LENGTH_UNITS, TIME_UNITS

__all__ = ["infer_length_unit", "infer_time_unit", "angles_in_degrees"]

_MM_THRESHOLD = 10.0  # median |position| above this, in "metres", looks like millimetres
_DT_MAX, _DT_MIN = 5.0, 1e-5  # plausible median sampling interval in seconds


def infer_length_unit(plan: Plan, table: Table, options: ReadOptions, position: np.ndarray):
    if options.length_unit:
        if options.length_unit not in LENGTH_UNITS:
            raise InputError(
                f"unknown length unit {options.length_unit!r}; use one of {', '.join(LENGTH_UNITS)}",
                param="length_unit",
            )
        named = {plan.roles[r].unit for r in "xyz" if plan.roles[r].unit_kind == "length"}
        if named and named != {options.length_unit}:  # the option wins, and the reader says so (read_sources)
            return options.length_unit, f"option, over the column names' {', '.join(sorted(named))}"
        return options.length_unit, "option"
    units = {plan.roles[r].unit for r in "xyz" if plan.roles[r].unit_kind == "length"}
    if len(units) > 1:
        raise InputError(
            f"the position columns disagree on units ({', '.join(sorted(units))})",
            path=table.source,
            hint="pass length_unit to override", param="length_unit"
        )
    if units:
        return units.pop(), "column name"
    if table.declared.get("length_unit") in LENGTH_UNITS:
        return table.declared["length_unit"], "file comment"
    finite = np.all(np.isfinite(position), axis=1)
    if finite.any():
        p = position if finite.all() else position[finite]  # no copy of a table without lost frames
        med = float(np.median(np.sqrt(np.einsum("ij,ij->i", p, p))))
        if med > _MM_THRESHOLD:
            names = ",".join(plan.roles[r].name for r in "xyz")
            raise InputError(
                f"positions ({names}) have no unit and their median distance from the origin is "
                f"{med:.4g}, which looks like millimetres, not metres",
                path=table.source,
                hint="pass length_unit mm (or cm, or m if they really are metres)", param="length_unit"
            )
    return "m", "assumed"


def infer_time_unit(plan: Plan, table: Table, options: ReadOptions, t: np.ndarray, groups):
    if options.time_unit:
        if options.time_unit not in TIME_UNITS:
            raise InputError(f"unknown time unit {options.time_unit!r}; use one of {', '.join(TIME_UNITS)}")
        return options.time_unit, "option"
    col = plan.roles["t"]
    if col.unit_kind == "time":
        return col.unit, "column name"
    if col.unit_kind is not None:
        raise InputError(
            f"time column {col.name!r} has a {col.unit_kind} unit ({col.unit})",
            path=table.source,
            hint="pass time_unit s|ms|us|ns", param="time_unit"
        )
    if table.declared.get("time_unit") in TIME_UNITS:
        return table.declared["time_unit"], "file comment"
    diffs = []
    for idx in groups.values():
        tt = t[idx]
        tt = tt[np.isfinite(tt)]
        d = np.diff(tt)
        diffs.append(d[d > 0])
    d = np.concatenate(diffs) if diffs else np.empty(0)
    if len(d):
        med = float(np.median(d))
        if med > _DT_MAX or med < _DT_MIN:
            suggestion = None
            for unit in ("ms", "us", "ns"):
                if 1e-4 <= med * TIME_UNITS[unit] <= 1.0:
                    suggestion = unit
                    break
            if suggestion is None:
                for unit in ("ms", "us", "ns"):
                    if _DT_MIN <= med * TIME_UNITS[unit] <= _DT_MAX:
                        suggestion = unit
                        break
            what = f"{1.0 / med:.4g} Hz" if med > 0 else "?"
            hint = (
                f"pass time_unit {suggestion} ({1.0 / (med * TIME_UNITS[suggestion]):.4g} Hz)"
                if suggestion
                else "pass time_unit s|ms|us|ns, or rate HZ with columns to ignore the time column"
            )
            raise InputError(
                f"time column {col.name!r} has no unit and read as seconds its median step is {med:.4g} s "
                f"({what}), which is implausible for motion capture",
                path=table.source,
                hint=hint, param="time_unit" if suggestion else ("time_unit", "rate", "columns"),
            )
    return "s", "assumed"


def angles_in_degrees(plan: Plan, kind: str, options: ReadOptions, source: str) -> bool:
    cols = [plan.roles[r] for r in KIND_ROLES[kind]]
    units = {c.unit for c in cols if c.unit_kind == "angle"}
    if options.degrees is not None:
        return bool(options.degrees)
    if len(units) > 1:
        raise InputError(
            "the angle columns disagree on units (deg and rad)", path=source, hint="pass degrees=True or degrees=False",
            param="degrees",
        )
    if units:
        return units.pop() == "deg"
    if kind == "rotvec":
        return False
    names = ", ".join(c.name for c in cols)
    raise InputError(
        f"Euler angles ({names}) do not say whether they are degrees or radians",
        path=source,
        hint="pass degrees=True or degrees=False (or name the columns e.g. roll_deg)", param="degrees"
    )
