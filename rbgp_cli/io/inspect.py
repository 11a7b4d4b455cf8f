"""``rbgp inspect``: what a file holds and how rbgp would read it, without training anything.

:func:`inspect_file` returns plain data (JSON-ready); :func:`format_inspect` renders it for people.
For CSV it lists the columns and what each is taken as, for MCAP the topics (from the summary), for
vendor formats whatever the reader's ``describe()`` returns; then per trajectory: samples, duration,
median rate, gaps (steps longer than 1.5× the median), lost frames, units and conventions, and the
position range. A file rbgp cannot read still gets a description with the reader's error message.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np

from rbgp_cli.errors import InputError
from rbgp_cli.io.options import ReadOptions

__all__ = ["inspect_file", "format_inspect", "trajectory_summary"]

_GAP_FACTOR = 1.5


def _float(x):
    return None if x is None or not np.isfinite(x) else float(x)


def trajectory_summary(traj) -> dict:
    """Samples, duration, median rate, gaps, lost frames, units and position range of one raw
    trajectory (plain data)."""
    from rbgp_cli.dynamics.prepare import lost_frame_mask

    lost = lost_frame_mask(traj)
    good = ~lost
    t = traj.t[good]
    t = t[np.isfinite(t)]
    dt = np.diff(t)
    pos_dt = dt[dt > 0]
    med = float(np.median(pos_dt)) if len(pos_dt) else None
    gaps = dt[dt > _GAP_FACTOR * med] if med else np.empty(0)
    p = traj.position[good]
    info = traj.info or {}
    out = {
        "name": traj.name,
        "source": traj.source,
        "samples": int(len(traj)),
        "lost_frames": int(lost.sum()),
        "start_s": _float(t[0]) if len(t) else None,
        "duration_s": _float(t[-1] - t[0]) if len(t) > 1 else 0.0,
        "rate_hz": (1.0 / med) if med else None,
        "gaps": {"count": int(len(gaps)), "largest_s": _float(gaps.max()) if len(gaps) else None},
        "non_increasing_times": int(np.sum(dt <= 0)),
        "position_min_m": [float(v) for v in p.min(axis=0)] if len(p) else None,
        "position_max_m": [float(v) for v in p.max(axis=0)] if len(p) else None,
    }
    for key in ("length_unit", "length_unit_source", "time_unit", "time_unit_source", "rotation", "rotation_source", "topic",
                "frame_id", "child_frame_id", "time_source", "body", "demo", "columns"):  # fmt: skip
        if key in info:
            out[key] = info[key]
    return out


def _describe(fmt: str, path: str, options: ReadOptions):
    if fmt == "csv":
        from rbgp_cli.io import csv

        return csv.describe(path, options)
    if fmt == "mcap":
        from rbgp_cli.io import mcap

        return mcap.describe(path, options)
    import importlib

    module = importlib.import_module(f"rbgp_cli.io.{fmt}")
    fn = getattr(module, "describe", None)
    return fn(path, options) if fn is not None else None


def inspect_file(path, options: ReadOptions | None = None, stdin=None) -> dict:
    """Describe one file (``-``: stdin) as plain data.

    Returns ``{"path", "format", "bytes", "description", "trajectories": [...], "error"}``:
    ``description`` is the format-specific part (CSV columns and what each is taken as, MCAP topics,
    the vendor reader's ``describe()``), ``trajectories`` one :func:`trajectory_summary` per
    trajectory read, and ``error`` the message rbgp would stop with (None when the file reads).
    """
    options = options or ReadOptions()
    path = str(path)
    if path == "-":
        return _inspect_stdin(options, stdin)
    from rbgp_cli.io.read import _format_option, detect_format, read_file

    p = Path(path)
    if not p.exists():
        raise InputError("file not found", path=path, hint="check the path")
    if p.is_dir():
        raise InputError("is a directory", path=path, hint="pass the files inside it")
    out: dict = {"path": path, "format": None, "bytes": p.stat().st_size, "description": None,
                 "trajectories": [], "error": None}  # fmt: skip
    if out["bytes"] == 0:
        out["error"] = str(InputError("the file is empty", path=path))
        return out
    fmt = _format_option(options)
    out["format"] = detect_format(path) if fmt == "auto" else fmt
    try:
        out["description"] = _describe(out["format"], path, options)
    except InputError as exc:
        out["error"] = str(exc)
        return out
    try:
        if out["format"] == "mcap" and not options.topic:
            from rbgp_cli.io import mcap

            trajs = mcap.read_all(path, options)
        elif out["format"] in ("qtm", "motive", "vicon") and options.body is None:
            from dataclasses import replace

            trajs = read_file(path, replace(options, body="all"))  # inspect shows every body
        else:
            trajs = read_file(path, options)
    except InputError as exc:
        out["error"] = str(exc)
        trajs = []
    out["trajectories"] = [trajectory_summary(t) for t in trajs]
    return out


def _inspect_stdin(options: ReadOptions, stdin) -> dict:
    import tempfile

    from rbgp_cli.io.read import MCAP_MAGIC, detect_format

    stream = stdin if stdin is not None else sys.stdin.buffer
    data = stream.read()
    if not data:
        raise InputError("the input is empty", path="-")
    fmt = (options.format or "auto").lower()
    if fmt == "auto":
        fmt = "mcap" if data.startswith(MCAP_MAGIC) else detect_format(data[:8192])
    suffix = {"mcap": ".mcap", "qtm": ".tsv"}.get(fmt, ".csv")
    fd, tmp = tempfile.mkstemp(prefix="rbgp-stdin-", suffix=suffix)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        out = inspect_file(tmp, options)
    finally:
        os.unlink(tmp)

    def fix(x):
        if isinstance(x, str):
            return x.replace(tmp, "-").replace(Path(tmp).stem, "stdin")
        if isinstance(x, dict):
            return {k: fix(v) for k, v in x.items()}
        if isinstance(x, list):
            return [fix(v) for v in x]
        return x

    return fix(out)


# --------------------------------------------------------------------------------------------------
# text


def _fmt_num(x, unit: str = "", digits: int = 4) -> str:
    if x is None:
        return "-"
    return f"{x:.{digits}g}{unit}"


def format_inspect(d: dict) -> str:
    """Human-readable text of :func:`inspect_file`'s result."""
    lines = [f"{d['path']}: {d.get('format') or 'unknown'} ({d.get('bytes', 0)} bytes)"]
    desc = d.get("description")
    if d.get("format") == "csv" and isinstance(desc, dict):
        lines.append(f"  delimiter {desc.get('delimiter')!r}, header on line {desc.get('header_line')}, "
                     f"{desc.get('data_rows')} data rows")  # fmt: skip
        lines.append("  columns:")
        for c in desc.get("columns", []):
            taken = c.get("taken_as") or "(ignored)"
            unit = f" [{c['unit']}]" if c.get("unit") else ""
            lines.append(f"    {c['name']!s:<24} -> {taken}{unit}")
        if desc.get("problem") and not d.get("error"):
            lines.append(f"  problem: {desc['problem']}")
    elif d.get("format") == "mcap" and isinstance(desc, dict):
        lines.append(f"  profile {desc.get('profile')!r}, library {desc.get('library')!r}, "
                     f"{desc.get('messages')} messages" + ("" if desc.get("summary") else " (no summary: scanned)"))  # fmt: skip
        if desc.get("damaged"):
            lines.append(f"  damaged: {desc['damaged']}")
        lines.append("  topics:")
        for t in desc.get("topics", []):
            mark = "pose" if t.get("pose") else "    "
            lines.append(f"    {mark} {t['topic']:<36} {t['schema'] or '(no schema)'} "
                         f"[{t['message_encoding']}] {t['messages'] if t['messages'] is not None else '?'} messages")  # fmt: skip
    elif isinstance(desc, dict):
        for k, v in desc.items():
            if isinstance(v, (list, dict)) and len(str(v)) > 200:
                v = str(v)[:200] + "..."
            lines.append(f"  {k}: {v}")
    for tr in d.get("trajectories", []):
        lines.append(f"  trajectory {tr['name']}:")
        lines.append(f"    {tr['samples']} samples, {_fmt_num(tr['duration_s'], ' s')}, "
                     f"{_fmt_num(tr['rate_hz'], ' Hz')} median rate")  # fmt: skip
        g = tr["gaps"]
        gap = f"{g['count']} gaps" + (f" (largest {_fmt_num(g['largest_s'], ' s')})" if g["count"] else "")
        lines.append(f"    {tr['lost_frames']} lost frames, {gap}"
                     + (f", {tr['non_increasing_times']} non-increasing times" if tr["non_increasing_times"] else ""))  # fmt: skip
        conv = []
        if "length_unit" in tr:
            conv.append(f"length {tr['length_unit']}" + (f" ({tr['length_unit_source']})" if "length_unit_source" in tr else ""))
        if "time_unit" in tr:
            conv.append(f"time {tr['time_unit']}" + (f" ({tr['time_unit_source']})" if "time_unit_source" in tr else ""))
        if "rotation" in tr:
            conv.append(f"rotation {tr['rotation']}")
        elif "rotation_source" in tr:
            conv.append(f"rotation from {tr['rotation_source']}")
        if "time_source" in tr:
            conv.append(f"{tr['time_source']} time")
        if conv:
            lines.append("    " + ", ".join(conv))
        if tr.get("position_min_m") is not None:
            lo = ", ".join(f"{v:.4g}" for v in tr["position_min_m"])
            hi = ", ".join(f"{v:.4g}" for v in tr["position_max_m"])
            lines.append(f"    position range [{lo}] .. [{hi}] m")
    if d.get("error"):
        lines.append(f"  error: {d['error']}")
    return "\n".join(lines)
