"""Which column of a CSV/TSV table is what (:mod:`rbgp_cli.io.csv`): each name is normalised (lower
case, separators equivalent, a unit suffix split off) and matched against the vocabulary of
:mod:`rbgp_cli.io.vocabulary`; the plan then picks the time, position and rotation columns (or the ones
``columns`` names), and :func:`sniff_pose_columns` says from the head of a file whether it holds
pose columns at all.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

from rbgp_cli.errors import InputError, NotPoseData, closest
from rbgp_cli.io.csv_table import decode, parse_table
from rbgp_cli.io.options import ReadOptions
from rbgp_cli.io.vocabulary import (
    CANONICAL_KEYS, DEMO_NAMES, DEMO_SUFFIXES, EULER_AXIS_PREFIXES, FRAME_NAMES, KEY_ROLE, KIND_ROLES,
    NSEC_PARTNERS, NUMBERED_PREFIXES, POS_PREFIXES, QUAT_PREFIXES, ROTATION_KINDS, ROTVEC_PREFIXES,
    ROT_AMBIGUOUS, RPY, TIME_IMPLIED_UNIT, TIME_NAMES, UNIT_TOKENS,
)

__all__ = ["Column", "classify", "Plan", "plan_columns", "role_key", "columns_list", "sniff_pose_columns"]


@dataclass
class Column:
    index: int
    name: str  # as in the file
    base: str  # normalised, unit removed
    unit_kind: str | None = None  # length / time / angle
    unit: str | None = None
    roles: list = field(default_factory=list)  # [(role, rank)]


def _normalise_name(name: str) -> tuple[str, str | None, str | None]:
    """``"X [mm]"`` -> ``("x", "length", "mm")``; ``"time_s"`` -> ``("time", "time", "s")``."""
    s = name.strip().strip("\"'").strip().lower()
    unit = None
    m = re.fullmatch(r"(.*?)\s*[\[\(\{]\s*([^\]\)\}]*?)\s*[\]\)\}]\s*", s)
    if m and m.group(1) and m.group(2) in UNIT_TOKENS:
        s, unit = m.group(1), m.group(2)
    base = re.sub(r"[\s.\-/:\[\]\(\)\{\}]+", "_", s)
    base = re.sub(r"[^0-9a-zµ_]", "", base).strip("_")
    if unit is None:
        parts = base.split("_")
        if len(parts) > 1 and parts[-1] in UNIT_TOKENS:
            unit, base = parts[-1], "_".join(parts[:-1])
    if unit is None:
        return base, None, None
    kind, unit = UNIT_TOKENS[unit]
    return base, kind, unit


def _prefix_candidates(prefix: str):
    """``pose_position`` -> (``pose_position``, 0), (``position``, 1): the prefix itself, then its
    qualified tails (never the empty tail: ``vel_x`` is not ``x``)."""
    yield prefix, 0
    parts = prefix.split("_")
    for k in range(1, len(parts)):
        tail = "_".join(parts[k:])
        if tail:
            yield tail, 1


def classify(index: int, name: str) -> Column:
    base, kind, unit = _normalise_name(name)
    col = Column(index=index, name=name, base=base, unit_kind=kind, unit=unit)
    roles = col.roles

    def tail_match(b: str, names) -> int | None:
        for cand, rank in _prefix_candidates(b):
            if cand in names:
                return rank
        return None

    # time
    if base in TIME_NAMES:
        roles.append(("t", 0))
    elif base in TIME_IMPLIED_UNIT:
        roles.append(("t", 0))
        if unit is None:
            col.unit_kind, col.unit = "time", TIME_IMPLIED_UNIT[base]
    elif re.fullmatch(r".+_(time|timestamp|stamp)", base):
        roles.append(("t", 1))
    if base in FRAME_NAMES:
        roles.append(("frame", 0))
    for suffix in DEMO_SUFFIXES:
        if suffix and not base.endswith(suffix):
            continue
        stem = base[: len(base) - len(suffix)] if suffix else base
        if stem in DEMO_NAMES:
            roles.append(("demo", 0))
            break
    if base in RPY:
        roles.append((base, 0))
    m = re.fullmatch(r"(.*?)_?([0-4])", base)
    if m:
        rank = tail_match(m.group(1), NUMBERED_PREFIXES)
        if rank is not None:
            roles.append((f"qn{m.group(2)}", rank))
    m = re.fullmatch(r"(.*?)_?([xyzw])", base)
    if m and base not in RPY:
        prefix, comp = m.group(1), m.group(2)
        for cand, rank in _prefix_candidates(prefix):
            if rank and not cand:
                continue
            found = False
            if comp != "w" and cand in POS_PREFIXES:
                roles.append((comp, rank))
                found = True
            if cand in QUAT_PREFIXES or cand in ROT_AMBIGUOUS:
                roles.append((f"q{comp}", rank))
                found = True
            if comp != "w":
                if cand in ROTVEC_PREFIXES or ROT_AMBIGUOUS.get(cand) == "rotvec":
                    roles.append((f"r{comp}", rank))
                    found = True
                if cand in EULER_AXIS_PREFIXES or ROT_AMBIGUOUS.get(cand) == "euler_axis":
                    roles.append((f"e{comp}", rank))
                    found = True
            if found:
                break
    return col


@dataclass
class Plan:
    roles: dict  # role -> Column
    rotation: str  # one of ROTATION_KINDS
    columns: list  # all classified columns


def columns_list(cols: list) -> str:
    names = [c.name for c in cols if c.name]
    text = ", ".join(names[:40])
    return text + (", ..." if len(names) > 40 else "")


def role_key(role: str) -> str:
    """The ``columns`` key (or display name) of an internal role."""
    return {"qn0": "q0", "qn1": "q1", "qn2": "q2", "qn3": "q3", "ex": "rot_x", "ey": "rot_y", "ez": "rot_z"}.get(
        role, role
    )


def _candidates(cols: list, role: str, used: set) -> list:
    """The best-ranked columns (not in ``used``) that could hold ``role``."""
    cands = [(rank, c) for c in cols if c.index not in used for (r, rank) in c.roles if r == role]
    if not cands:
        return []
    top = min(rank for rank, _ in cands)
    return [c for rank, c in cands if rank == top]


def _best(cols: list, role: str, used: set, source: str):
    """The unique best-ranked column for ``role`` (None when there is none; InputError when several)."""
    best = _candidates(cols, role, used)
    if len(best) > 1:
        key = role_key(role)
        names = [c.name.strip() for c in best]
        if len(set(names)) < len(names):  # columns maps by name, so it cannot choose between them
            raise InputError(
                f"several columns are named {names[0]!r} (columns "
                + ", ".join(str(c.index + 1) for c in best) + ")",
                path=source,
                hint="rename or delete all but one of them",
            )
        raise InputError(
            f"several columns could be '{key}': " + ", ".join(repr(c.name) for c in best),
            path=source,
            hint=f"choose one with columns {key if key in CANONICAL_KEYS else 'KEY'}=NAME", param="columns"
        )
    return best[0] if best else None


def _missing_error(role_key: str, what: str, cols: list, used: set, source: str) -> InputError:
    # a guess is a column no role claims: 'z_m' is the position's z, never the missing quaternion's qz
    free = [c for c in cols if c.name and c.index not in used and not c.roles]
    unused = [c.name for c in free]
    guess = closest(role_key, unused) or closest(role_key, [c.base for c in free])
    if guess and guess not in unused:  # matched a normalised name: report the file's name
        guess = next(c.name for c in cols if c.base == guess)
    msg = f"{what} column '{role_key}' not found (columns are {columns_list(cols)})"
    if guess:
        msg += f"; did you mean {guess!r}?"
        hint = f"rename the column or pass columns {role_key}={guess}"
    else:
        hint = f"rename the column or pass columns {role_key}=NAME"
    return InputError(msg, path=source, hint=hint, param="columns")


def _renumber_one_based(cols: list) -> None:
    """``q1..q4`` -> roles ``qn0..qn3`` when there is no ``q0``."""
    have = {r for c in cols for r, _ in c.roles}
    if "qn4" in have and "qn0" not in have:
        for c in cols:
            c.roles = [(f"qn{int(r[2]) - 1}", k) if r.startswith("qn") else (r, k) for r, k in c.roles]
    for c in cols:
        c.roles = [(r, k) for r, k in c.roles if r != "qn4"]


def _mapped_roles(cols: list, options: ReadOptions, source: str) -> dict:
    """{role: Column} of the columns ``--columns`` (``options.columns``) names; an error for an unknown
    key or a column the file does not have."""
    by_name = {c.name: c for c in cols}
    by_lower = {c.name.strip().lower(): c for c in cols}
    roles: dict = {}
    for key, fname in dict(options.columns or {}).items():
        k = str(key).strip().lower()
        if k not in CANONICAL_KEYS:
            guess = closest(k, CANONICAL_KEYS)
            raise InputError(
                f"columns key {key!r} is unknown; keys are {', '.join(CANONICAL_KEYS)}"
                + (f"; did you mean {guess!r}?" if guess else ""), param="columns"
            )
        col = by_name.get(fname) or by_lower.get(str(fname).strip().lower())
        if col is None:
            guess = closest(str(fname), [c.name for c in cols])
            raise NotPoseData(
                f"columns {k}={fname}: the file has no column {fname!r} (columns are {columns_list(cols)})"
                + (f"; did you mean {guess!r}?" if guess else ""),
                path=source,
                reason=f"no column {fname!r}", param="columns"
            )
        roles[KEY_ROLE.get(k, k)] = col
    return roles


def _rotation_kind(cols: list, roles: dict, explicit: set, used, source: str) -> str:
    """The rotation's columns family (:data:`ROTATION_KINDS`): the one the mapped roles ``explicit``
    name, else the first complete one among the columns not ``used()``; an error naming what is
    missing otherwise."""
    # rotation kind: explicit keys decide, else the first complete family
    kind = next((k for k in ROTATION_KINDS if explicit & set(KIND_ROLES[k])), None)
    if kind is None:
        for k in ROTATION_KINDS:
            if all(r in roles or _candidates(cols, r, used()) for r in KIND_ROLES[k]):
                kind = k
                break
    if kind is None:
        # name the missing column of the most complete partial family, else say what is expected
        partial = None
        for k in ("quaternion", "numbered", "rpy"):
            have = [r for r in KIND_ROLES[k] if _candidates(cols, r, used())]
            if len(have) >= 2 and (partial is None or len(have) > len(partial[1])):
                partial = (k, have)
        if partial:
            k, have = partial
            missing = next(r for r in KIND_ROLES[k] if r not in have)
            raise _missing_error(role_key(missing), "rotation", cols, used(), source)
        if len(cols) == 1 and re.search(r"[^\w\s\[\]()]", cols[0].name):
            # one "column" full of punctuation: the delimiter is none of those the sniffer knows
            raise NotPoseData(
                f"the header line is a single column ({cols[0].name[:60]!r}): its delimiter is not a comma, "
                "semicolon, tab or spaces",
                path=source,
                hint="save the file comma- or tab-separated",
                reason="not a table",
            )
        raise NotPoseData(
            f"no rotation columns found (columns are {columns_list(cols)}); expected quaternion columns "
            "qx,qy,qz,qw (any order), a rotation vector rx,ry,rz, or Euler angles roll,pitch,yaw",
            path=source,
            hint="map other names with columns qx=NAME,...",
            reason="no pose columns", param="columns"
        )
    return kind


def _pose_roles(cols: list, roles: dict, kind: str, used, source: str) -> None:
    """Add the best column for each rotation role of ``kind`` and for x, y, z to ``roles``; an error
    where one is missing (NotPoseData for a table of rotations only)."""
    no_position = not any(r in roles or _candidates(cols, r, used()) for r in ("x", "y", "z"))
    for r in KIND_ROLES[kind] + ("x", "y", "z"):
        if r in roles:
            continue
        c = _best(cols, r, used(), source)
        if c is None:
            err = _missing_error(role_key(r), "rotation" if r in KIND_ROLES[kind] else "position", cols,
                                 used(), source)  # fmt: skip
            if no_position and r in ("x", "y", "z"):  # rotations only (an IMU log): not poses
                raise NotPoseData(err.message, path=source, hint=err.hint, reason="no position columns", param=err.param)
            raise err
        roles[r] = c


def _time_roles(cols: list, roles: dict, used, source: str) -> None:
    """Add the time column (and its nanoseconds partner, or a seconds/nanoseconds pair) to ``roles``
    unless it is mapped; an error where several columns could be the time."""
    if "t" in roles:
        return
    cands = _candidates(cols, "t", used())
    if len(cands) > 1:
        pair = sec_nsec_pair(cands)
        if pair is None:
            raise InputError(
                "several columns could be the time: " + ", ".join(repr(x.name) for x in cands),
                path=source,
                hint="choose one with columns t=NAME", param="columns"
            )
        roles["t"], roles["t_nsec"] = pair
    elif cands:
        roles["t"] = cands[0]
        partner = nsec_partner(cands[0], cols)
        if partner is not None and partner.index not in used():
            roles["t_nsec"] = partner


def _one_role_each(roles: dict, source: str) -> None:
    """An error where one column has two roles."""
    # one column, one role
    seen: dict = {}
    for r, c in roles.items():
        if c.index in seen:
            raise InputError(
                f"column {c.name!r} is used both as '{role_key(seen[c.index])}' and as '{role_key(r)}'",
                path=source,
                hint="fix the mapping with columns", param="columns"
            )
        seen[c.index] = r


def plan_columns(cols: list, options: ReadOptions, source: str) -> Plan:
    """Which of the classified ``cols`` (:func:`classify`) is which role: the columns ``--columns`` maps,
    then the rotation family, position, time, frame and demo columns; an InputError (NotPoseData where
    the table holds no poses) where that is not clear."""
    _renumber_one_based(cols)
    roles = _mapped_roles(cols, options, source)
    explicit = set(roles)

    def used() -> set:
        return {c.index for c in roles.values()}

    kind = _rotation_kind(cols, roles, explicit, used, source)
    _pose_roles(cols, roles, kind, used, source)
    _time_roles(cols, roles, used, source)
    for r in ("frame", "demo"):
        if r not in roles:
            c = _best(cols, r, used(), source)
            if c is not None:
                roles[r] = c
    _one_role_each(roles, source)
    return Plan(roles=roles, rotation=kind, columns=cols)


def sec_nsec_pair(cands: list):
    if len(cands) != 2:
        return None
    a, b = cands
    units = {a.unit, b.unit}
    if a.base == b.base and units == {"s", "ns"}:
        return (a, b) if a.unit == "s" else (b, a)
    return None


def nsec_partner(tcol: Column, cols: list):
    """``sec`` + ``nanosec`` (ROS split stamps): the nanosecond column beside a ``sec`` column."""
    if tcol.base not in ("sec", "secs"):
        return None
    for c in cols:
        if c is not tcol and c.unit is None and c.base in NSEC_PARTNERS:
            return c
    return None


def sniff_pose_columns(head: bytes, source: str, options: ReadOptions | None = None, *,
                       complete: bool = False) -> str | None:
    """Why a file that starts with ``head`` holds no pose data, in a few words, or None.

    Judged like :func:`read` judges the whole file, on the complete lines of ``head`` (``complete``:
    head is the whole file): "empty", "not a text file", "no table" (comments only), "no header line"
    (numbers only), "not a table" (one column), "no pose columns" (no rotation), "no position columns".
    None when the header names pose columns (even if reading may still fail: such a file is pose
    data with a problem) or when the head ends before the header does.
    """
    options = options or ReadOptions()
    if head[:2] in (b"\xff\xfe", b"\xfe\xff") and not complete:
        head = head[: len(head) // 2 * 2]  # UTF-16: whole code units only
    try:
        text = decode(head, source)
    except InputError as exc:
        return "empty" if "empty" in exc.message else "not a text file"
    if not complete:
        cut = max(text.rfind("\n"), text.rfind("\r"))
        if cut < 0:
            return None  # one line longer than the head
        text = text[:cut]
    try:
        table = parse_table(text, source)
    except InputError as exc:
        if not complete and "no header and no data" in exc.message:
            return None  # comments longer than the head
        return "no header line" if "no header line" in exc.message else "no table"
    cols = [classify(i, name) for i, name in enumerate(table.header)]
    try:
        plan_columns(cols, options, source)
    except NotPoseData as exc:
        return exc.reason
    except InputError:
        return None
    return None
