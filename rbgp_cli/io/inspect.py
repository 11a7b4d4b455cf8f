"""``rbgp inspect``: what a file holds and how rbgp would read it, without training anything.

:func:`inspect_file` returns plain data (JSON-ready); :func:`format_inspect` renders it for people.
For CSV it lists the columns and what each is taken as, for MCAP the topics (from the summary), for
QTM, Motive and Vicon exports what the header says (layout, bodies, rate, units, rotation source,
time, ignored assets), in aligned rows of plain words; then per trajectory: samples, duration, median
rate, gaps (steps longer than 1.5× the median), lost frames, units and conventions, and the position
range; then the options still needed to train on the file (:func:`needs`). A file rbgp cannot read
still gets a description with the reader's error message. Like the errors, the text names the read
options as :class:`~rbgp_cli.io.options.ReadOptions` does (``rate``, ``quat_order``); ``rbgp
inspect`` writes its flags instead.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np

from rbgp_cli.errors import InputError
from rbgp_cli.io.options import ReadOptions
from rbgp_cli.wording import plural

__all__ = ["inspect_file", "format_inspect", "trajectory_summary", "needs"]

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
                "frame_id", "child_frame_id", "time_source", "body", "demo", "columns",
                "markers", "fit_rms_median_m", "fit_rms_max_m", "fit_rms_tol_m", "frames_over_tol",
                "frames_too_few_markers"):  # fmt: skip
        if key in info:
            out[key] = info[key]
    return out


def _describe(fmt: str, path: str, options: ReadOptions):
    from rbgp_cli.io import formats

    describe = formats.get(fmt).describe
    return describe(path, options) if describe is not None else None


def prepared_summary(traj, options: ReadOptions, max_gap: float | None = None, words=str) -> dict:
    """What train's preparation (:func:`rbgp_cli.dynamics.prepare.prepare_all`, the same call with the
    same options) does to one raw trajectory, as plain data: sample-and-hold repeats and their runs,
    lost frames dropped or filled, duplicates, breaks that split it, gaps no training pair crosses (at
    the default training rate), the demonstrations and repetitions it becomes, a suspect quaternion
    order, or the error train would stop with (``prepare_error``, as ``words(error)`` says it)."""
    from rbgp_cli.dynamics.defaults import DEFAULTS
    from rbgp_cli.dynamics.prepare import prepare_all
    from rbgp_cli.dynamics.velocities import segment_split

    import warnings

    from rbgp_cli.errors import RbgpWarning

    try:
        with warnings.catch_warnings():  # the repairs are reported below, not warned about
            warnings.simplefilter("ignore", RbgpWarning)
            pieces, (rep,) = prepare_all([traj], max_gap=max_gap, quiet=True, **options.prepare_kwargs())
    except InputError as exc:
        return {"prepare_error": words(exc)}
    gaps = []
    thr = None
    for c in pieces:
        if len(c) > 1:
            thr = segment_split(c.t, DEFAULTS["train_rate"])
            d = np.diff(c.t)
            gaps += d[d > thr].tolist()
    brk = [b["gap_s"] for b in rep.get("breaks", [])]
    steps = np.concatenate([np.diff(c.t) for c in pieces]) if pieces else np.empty(0)
    med = float(np.median(steps)) if len(steps) else None
    clean_gaps = steps[steps > _GAP_FACTOR * med] if med else np.empty(0)
    out = {
        # the steps of what train keeps (held and lost samples dropped), breaks apart
        "gaps": {"count": int(len(clean_gaps)), "largest_s": _float(clean_gaps.max()) if len(clean_gaps) else None},
        "held": rep["held"], "held_runs": rep["held_runs"], "lost": rep["lost"], "dropped": rep["dropped"],
        "filled": rep["filled"], "duplicates": rep["duplicates"], "sign_flips": rep["sign_flips"],
        "glitches": rep.get("glitches", 0), "glitch_rows": rep.get("glitch_rows", []),
        "breaks": {"count": len(brk), "largest_s": max(brk) if brk else None,
                   "after_s": [b["after_s"] for b in rep.get("breaks", [])]},
        "training_gaps": {"count": len(gaps), "largest_s": max(gaps) if gaps else None, "longer_than_s": thr},
        "demonstrations": len(pieces),
        "samples_used": int(sum(len(c) for c in pieces)),
        "quat_order_suspect": rep.get("quat_order_suspect"),
    }
    if "rest" in rep:
        out["repetitions"] = int(sum(r["repetitions"] for r in rep["rest"]))
        out["repetition_spans_s"] = [s for r in rep["rest"] for s in r["spans_s"]]
    return out


def inspect_file(path, options: ReadOptions | None = None, stdin=None, *, max_gap: float | None = None,
                 words=str) -> dict:
    """Describe one file (``-``: stdin) as plain data.

    Returns ``{"path", "format", "bytes", "description", "trajectories": [...], "error", "needs"}``:
    ``description`` is the format-specific part (CSV columns and what each is taken as, MCAP topics,
    the vendor reader's ``describe()``), ``trajectories`` one :func:`trajectory_summary` per
    trajectory read, ``error`` the message rbgp would stop with (None when the file reads), and
    ``needs`` the options still needed to train on it (:func:`needs`). ``words(error)`` is the text
    of an error (``str``: as the library says it; the command line names its flags instead).
    """
    options = options or ReadOptions()
    path = str(path)
    if path == "-":
        return _inspect_stdin(options, stdin, max_gap, words)
    from rbgp_cli.io import formats
    from rbgp_cli.io.read import _format_option, detect_format, read_file

    p = Path(path)
    if not p.exists():
        raise InputError("file not found", path=path, hint="check the path")
    if p.is_dir():
        raise InputError("is a directory", path=path, hint="pass the files inside it")
    from rbgp_cli.io.special import is_stream_path, open_stream_path

    if is_stream_path(path):  # a FIFO, <(cat demo.csv): read once, described like stdin
        with open_stream_path(path, "data file") as stream:
            return _inspect_stdin(options, stream, max_gap, words, name=path)
    out: dict = {"path": path, "format": None, "bytes": p.stat().st_size, "description": None,
                 "trajectories": [], "error": None}  # fmt: skip
    if out["bytes"] == 0:
        out["error"] = words(InputError("the file is empty", path=path))
        return _finish(out, options)
    fmt = _format_option(options)
    out["format"] = detect_format(path) if fmt == "auto" else fmt
    try:
        if not formats.get(out["format"]).binary:
            from rbgp_cli.io.read import check_line_lengths

            check_line_lengths(path)  # a file of one 200 MB line: refused after 1 MiB
        out["description"] = _describe(out["format"], path, options)
    except InputError as exc:
        out["error"] = words(exc)
        return _finish(out, options, exc.param)
    entry = formats.get(out["format"])
    error_param = None
    try:
        # inspect shows everything the options leave open (every body, every pose topic)
        trajs = entry.read_all(path, options) if entry.read_all is not None else read_file(path, options)
    except InputError as exc:
        out["error"], error_param = words(exc), exc.param
        trajs = []
    out["trajectories"] = [{**trajectory_summary(t), **prepared_summary(t, options, max_gap, words)} for t in trajs]
    return _finish(out, options, error_param)


def _finish(out: dict, options: ReadOptions, error_param=None) -> dict:
    out["needs"] = needs(out, options, error_param)
    return out


def _inspect_stdin(options: ReadOptions, stdin, max_gap=None, words=str, name: str = "-") -> dict:
    """:func:`inspect_file` of what a stream holds (stdin, a FIFO named ``name``), through a temporary
    file that is gone when this returns, and gone even when the process is killed (SIGKILL) while it
    is being read: it is unlinked as soon as it is opened, and read through ``/proc/self/fd``."""
    import tempfile

    from rbgp_cli.io import formats
    from rbgp_cli.io.read import _format_option, detect_format, warnings_renamed
    from rbgp_cli.io.special import stdin_stream

    stream = stdin_stream(stdin)
    fmt = _format_option(options)
    with tempfile.TemporaryFile(prefix="rbgp-stdin-") as fh:  # unnamed: nothing left if we are killed
        head = stream.read(formats.HEAD_BYTES)
        if not head:
            raise InputError("the input is empty", path=name)
        if fmt == "auto":
            fmt = detect_format(head)
        fh.write(head)
        for block in iter(lambda: stream.read(1 << 20), b""):
            fh.write(block)
        fh.flush()
        tmp = f"/proc/self/fd/{fh.fileno()}"
        if not os.path.exists(tmp):  # pragma: no cover - no /proc: a named file, removed at once after
            return _inspect_named_copy(fh, options, max_gap, words, name, formats.get(fmt).suffix)
        with warnings_renamed(tmp, name, "stdin" if name == "-" else Path(name).stem):
            out = inspect_file(tmp, options, max_gap=max_gap, words=words)
    return _renamed(out, tmp, name)


def _inspect_named_copy(fh, options, max_gap, words, name, suffix) -> dict:  # pragma: no cover - no /proc
    import shutil
    import tempfile

    fh.seek(0)
    fd, tmp = tempfile.mkstemp(prefix="rbgp-stdin-", suffix=suffix)
    try:
        with os.fdopen(fd, "wb") as out_fh:
            shutil.copyfileobj(fh, out_fh)
        from rbgp_cli.io.read import warnings_renamed

        with warnings_renamed(tmp, name, "stdin" if name == "-" else Path(name).stem):
            out = inspect_file(tmp, options, max_gap=max_gap, words=words)
    finally:
        os.unlink(tmp)
    return _renamed(out, tmp, name)


def _renamed(out: dict, tmp: str, name: str) -> dict:
    """``out`` with the temporary file's path replaced by the stream's name."""
    stem, new = Path(tmp).stem, "stdin" if name == "-" else Path(name).stem

    def own_name(v):  # a trajectory named after the file: "STEM", "STEM#2", "STEM:body"
        if isinstance(v, str) and (v == stem or (v.startswith(stem) and v[len(stem)] in "#:/ ")):
            return new + v[len(stem):]
        return fix(v)

    def fix(x):
        if isinstance(x, str):
            return x.replace(f"{tmp}: {stem}", f"{name}: {new}").replace(tmp, name)
        if isinstance(x, dict):
            return {k: own_name(v) if k == "name" else fix(v) for k, v in x.items()}
        if isinstance(x, list):
            return [fix(v) for v in x]
        return x

    return fix(out)


# --------------------------------------------------------------------------------------------------
# what is still needed

def needs(d: dict, options: ReadOptions | None = None, error_param=None) -> list[str]:
    """The options still needed to train on the file described by ``d`` (plain strings, each the
    option, then a value or ``or`` another option, then why: ``rate HZ (no time column)``): those
    the format's description names, those its ``Format.needs`` adds (``body`` / ``topic`` when the
    file holds several bodies or pose topics), and the parameters the reading error is about
    (``error_param``: its :attr:`~rbgp_cli.errors.RbgpError.param`)."""
    options = options or ReadOptions()
    desc = d.get("description") if isinstance(d.get("description"), dict) else {}
    out = list(desc.get("needs") or [])
    from rbgp_cli.io import formats

    entry = formats.get(d["format"]) if d.get("format") in formats.names() else None
    if entry is not None and entry.needs is not None:  # a choice the file leaves open: bodies, topics
        out += entry.needs(desc, options)
    if d.get("error") and error_param:  # the options the error is about (it says why, on the line below)
        have = {n.split()[0] for n in out}
        params = (error_param,) if isinstance(error_param, str) else tuple(error_param)
        names = [p for p in dict.fromkeys(params) if p not in have]
        if names:
            out.append(" or ".join(names) + " (see the error)")
    return out


# --------------------------------------------------------------------------------------------------
# text

_LABEL = 14
_DELIMITERS = {",": "comma", ";": "semicolon", "\t": "tab", "whitespace": "whitespace"}


def _fmt_num(x, unit: str = "", digits: int = 4) -> str:
    if x is None:
        return "-"
    return f"{x:.{digits}g}{unit}"


def _plain(v) -> str:
    """Any plain value as text people read: lists joined by commas, mappings as ``key value; ...``,
    None as ``-`` (never a Python repr)."""
    if v is None:
        return "-"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return _fmt_num(v)
    if isinstance(v, dict):
        return "; ".join(f"{k} {_plain(x)}" for k, x in v.items()) or "-"
    if isinstance(v, (list, tuple)):
        return ", ".join(_plain(x) for x in v) or "-"
    return str(v).replace("Rot[]", "Rot")  # QTM's Rot[0..8] columns, named without brackets


def _row(label: str, value) -> str:
    return f"  {label:<{_LABEL}}{_plain(value)}"



def _rate(desc: dict) -> str:
    r = desc.get("rate_hz")
    return f"{_fmt_num(r)} Hz" if r else "not stated"


_SKIP_KEYS = {"format", "needs"}


def _entry(fmt):
    """The registered :class:`~rbgp_cli.io.formats.Format` named ``fmt``, or None."""
    from rbgp_cli.io import formats

    return formats.get(fmt) if fmt in formats.names() else None


def _title(fmt) -> str:
    entry = _entry(fmt)
    return entry.title if entry is not None else (fmt or "unknown format")


def _rows_any(desc: dict) -> list[str]:
    """A format without its own layout: every field as an aligned row of plain text."""
    return [_row(str(k).replace("_", " "), v) for k, v in desc.items() if k not in _SKIP_KEYS]


#: For the formats' ``describe_rows``: aligned rows of plain words, as every part of inspect writes them.
text_row, plain, fmt_num, rate_text, DELIMITER_NAMES = _row, _plain, _fmt_num, _rate, _DELIMITERS


def _trajectory_rows(tr: dict) -> list[str]:
    lines = [f"  trajectory {tr['name']}:"]
    lines.append(f"    {tr['samples']} samples, {_fmt_num(tr['duration_s'], ' s')}, "
                 f"{_fmt_num(tr['rate_hz'], ' Hz')} median rate")
    g = tr["gaps"]
    gap = f"{g['count']} gaps" + (f" (largest {_fmt_num(g['largest_s'], ' s')})" if g["count"] else "")
    held = tr.get("held") or 0
    lost = f"{tr['lost_frames'] + held} lost frames" + (
        f" ({held} repeat the previous pose exactly, sample-and-hold in {plural(tr.get('held_runs') or 0, 'run')})"
        if held else "")
    lines.append(f"    {lost}, {gap}"
                 + (f", {tr['non_increasing_times']} non-increasing times" if tr["non_increasing_times"] else ""))
    acts = _train_acts(tr)
    if acts:
        lines.append("    train: " + "; ".join(acts))
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
        ts = tr["time_source"]
        conv.append(f"{ts} time" if ts in ("header", "log") else f"time from {ts}")
    if conv:
        lines.append("    " + _plain(", ".join(conv)))
    if tr.get("markers"):  # a rigid fit of markers (C3D): its residuals and the frames it could not fit
        fit = (f"    rigid fit of {len(tr['markers'])} markers: RMS residual median "
               f"{_fmt_num(1e3 * tr['fit_rms_median_m'], ' mm', 3) if tr.get('fit_rms_median_m') is not None else '-'}, "
               f"largest {_fmt_num(1e3 * tr['fit_rms_max_m'], ' mm', 3) if tr.get('fit_rms_max_m') is not None else '-'}")
        lost_fit = [f"{tr['frames_too_few_markers']} with fewer than 3 markers seen" if tr.get("frames_too_few_markers")
                    else "", f"{tr['frames_over_tol']} over {_fmt_num(1e3 * tr['fit_rms_tol_m'], ' mm')} RMS"
                    if tr.get("frames_over_tol") else ""]
        lost_fit = [x for x in lost_fit if x]
        lines.append(fit + (f"; lost: {', '.join(lost_fit)}" if lost_fit else ""))
    if tr.get("position_min_m") is not None:
        rng = ", ".join(f"{a} {lo:.4g} .. {hi:.4g}" for a, lo, hi in zip("xyz", tr["position_min_m"], tr["position_max_m"]))
        lines.append(f"    position {rng} m")
    if tr.get("quat_order_suspect"):
        lines.append(f"    warning: {tr['quat_order_suspect']}")
    if tr.get("prepare_error"):
        lines.append(f"    train would stop: {tr['prepare_error']}")
    return lines


def _train_acts(tr: dict) -> list[str]:
    """What train's preparation does to the trajectory (:func:`prepared_summary`), in words."""
    acts = []
    if tr.get("dropped"):
        acts.append(f"drops {plural(tr['dropped'], 'lost frame')}")
    if tr.get("filled"):
        acts.append(f"fills {plural(tr['filled'], 'lost frame')} (max_gap)")
    if tr.get("duplicates"):
        acts.append(f"drops {plural(tr['duplicates'], 'duplicate sample')}")
    if tr.get("glitches"):
        from rbgp_cli.dynamics.prepare import _rows_text

        acts.append(f"removes {plural(tr['glitches'], 'sample')} off the path as tracker glitches "
                    f"({_rows_text(tr.get('glitch_rows') or [])})")
    used = tr.get("samples_used")
    if used is not None and tr.get("samples") and used < (tr["samples"] - (tr.get("dropped") or 0) - (tr.get("duplicates") or 0)
                                                          - (tr.get("glitches") or 0)):
        acts.append(f"uses {used} of {tr['samples']} samples")
    b = tr.get("breaks") or {}
    if b.get("count"):
        acts.append(f"splits it at {plural(b['count'], 'break')} (up to {_fmt_num(b['largest_s'], ' s')} without a sample; "
                    f"split_gap decides) into {plural(tr['demonstrations'], 'demonstration')}")
    if "repetitions" in tr:
        spans = ", ".join(f"{_fmt_num(a, '', 3)}–{_fmt_num(e, ' s', 3)}" for a, e in tr["repetition_spans_s"][:6])
        acts.append(f"splits it at rest into {plural(tr['repetitions'], 'repetition')} ({spans}"
                    + (" …" if len(tr["repetition_spans_s"]) > 6 else "") + ")")
    g = tr.get("training_gaps") or {}
    if g.get("count"):
        acts.append(f"{plural(g['count'], 'gap')} longer than {_fmt_num(g['longer_than_s'], ' s', 3)} (largest "
                    f"{_fmt_num(g['largest_s'], ' s')}) that no training pair crosses")
    return acts


def format_inspect(d: dict) -> str:
    """Human-readable text of :func:`inspect_file`'s result: what was recognised, then aligned rows
    (bodies or columns or topics, units, rotation source, rate), each trajectory read (samples,
    rate, lost frames, gaps, units, position range), the options still needed, and the error rbgp
    would stop with. Plain words throughout: no Python reprs."""
    fmt = d.get("format")
    size = d.get("bytes", 0)
    lines = [f"{d['path']}: {_title(fmt)} ({size} bytes)"]
    desc = d.get("description")
    if isinstance(desc, dict):
        entry = _entry(fmt)
        lines += (entry.describe_rows if entry is not None and entry.describe_rows else _rows_any)(desc)
    for tr in d.get("trajectories", []):
        lines += _trajectory_rows(tr)
    for k, need in enumerate(d.get("needs") or []):
        lines.append(_row("still needed" if k == 0 else "", need))
    if d.get("error"):
        lines.append(f"  error: {d['error']}")
    return "\n".join(lines)


#: ``rbgp inspect`` on more files than this prints one line per file (full detail with -v).
COMPACT_ABOVE = 5


def _problems(d: dict) -> list[str]:
    """Short words for what train would act on or stop at in one file's description."""
    out = []
    if d.get("error"):
        out.append("unreadable")
    trs = d.get("trajectories") or []
    held = sum(t.get("held") or 0 for t in trs)
    lost = sum(t.get("lost_frames") or 0 for t in trs)
    gaps = sum((t.get("training_gaps") or {}).get("count") or 0 for t in trs)
    breaks = sum((t.get("breaks") or {}).get("count") or 0 for t in trs)
    if held:
        out.append(f"{held} sample-and-hold")
    if lost:
        out.append(plural(lost, "lost frame"))
    if gaps:
        out.append(plural(gaps, "gap"))
    if breaks:
        out.append(plural(breaks, "break"))
    if any(t.get("quat_order_suspect") for t in trs):
        out.append("quaternion order?")
    if any(t.get("prepare_error") for t in trs):
        out.append("train would stop")
    return out


def format_compact(d: dict) -> str:
    """One line for one file: format, trajectories, samples, duration, rate, problems (or the error)."""
    trs = d.get("trajectories") or []
    rates = [t["rate_hz"] for t in trs if t.get("rate_hz")]
    dur = sum(t.get("duration_s") or 0.0 for t in trs)
    head = (f"{d['path']}: {_title(d.get('format'))}, "
            f"{plural(len(trs), 'trajectory').replace('trajectorys', 'trajectories')}, "
            f"{sum(t['samples'] for t in trs)} samples, {_fmt_num(dur, ' s')}"
            + (f", {_fmt_num(float(np.median(rates)), ' Hz')}" if rates else ""))
    probs = _problems(d)
    line = head + (f"; {', '.join(probs)}" if probs else "")
    if d.get("error"):
        line += f"\n  error: {d['error']}"
    for t in trs:
        if t.get("prepare_error"):
            line += f"\n  train would stop: {t['prepare_error']}"
    return line


def format_summary(results: list[dict]) -> str:
    """The last line of ``rbgp inspect`` on several files: files, trajectories and demonstrations,
    total duration, rates, and how many files have each problem."""
    trs = [t for d in results for t in d.get("trajectories") or []]
    rates = [t["rate_hz"] for t in trs if t.get("rate_hz")]
    dur = sum(t.get("duration_s") or 0.0 for t in trs)
    demos = sum(t.get("demonstrations", 1) for t in trs if not t.get("prepare_error"))
    counts: dict = {}
    for d in results:
        for p in _problems(d):
            key = p.split(" ", 1)[1] if p[0].isdigit() else p
            key = {"lost frame": "lost frames", "gap": "gaps", "break": "breaks"}.get(key, key)
            counts[key] = counts.get(key, 0) + 1
    rate = ("" if not rates else f", {_fmt_num(min(rates), ' Hz')}" if _fmt_num(min(rates)) == _fmt_num(max(rates))
            else f", {_fmt_num(min(rates))}–{_fmt_num(max(rates), ' Hz')}")
    probs = "; problems: " + ", ".join(f"{v} with {k}" if k not in ("unreadable", "train would stop") else
                                       f"{v} {'unreadable' if k == 'unreadable' else 'that train would stop at'}"
                                       for k, v in counts.items()) if counts else "; no problems"
    return (f"{plural(len(results), 'file')}, {plural(len(trs), 'trajectory').replace('trajectorys', 'trajectories')}"
            f" -> {plural(demos, 'demonstration')}, {_fmt_num(dur, ' s')} in all{rate}{probs}")
