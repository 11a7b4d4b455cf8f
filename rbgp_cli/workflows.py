"""What each command does, as library calls: read → prepare → train / roll out / evaluate.

This module sits at the edge with :mod:`rbgp_cli.io` (it reads files); the core layers below it
never read files. The command line (:mod:`rbgp_cli.cli`) parses arguments, calls one function here
and prints the result.
"""

from __future__ import annotations

import os
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

from rbgp_cli import __version__
from rbgp_cli.errors import InputError, warn
from rbgp_cli.io.options import ReadOptions

__all__ = [
    "expand_paths",
    "check_writable",
    "load_demonstrations",
    "train_from_files",
    "parse_pose",
    "parse_pose_quat",
    "read_start_poses",
    "parse_goal",
    "parse_via",
    "parse_tolerance",
    "goal_options",
    "warn_far_goals",
    "rollout_starts",
    "rollout_model",
    "evaluate_files",
    "generate_like_paper",
    "predict_file",
    "crossval_configs",
    "crossval_files",
    "given_option",
    "left_data",
    "continue_files",
    "continue_motions",
    "follow_stream",
    "SAMPLE_DATA",
]

#: The start perturbation (m per axis; 0.1 rad per 0.3 m) of the paper's protocol (``evaluate --model``, ``rbgp demo``):
#: fixed, so that its scores compare across versions and sets. ``rollout`` draws starts like the demonstrations'
#: instead (:func:`~rbgp_cli.dynamics.rollout.starts_near` with None): the mean rollouts of such starts vary only as
#: much as the starts do, and score worse against the demonstrations' variety (docs/defaults.md, twenty-first pass).
PAPER_START_SPREAD = 0.02

#: The bundled sample demonstrations (made by scripts/make_sample_data.py).
SAMPLE_DATA = Path(__file__).resolve().parents[1] / "sample_data"


def expand_paths(paths, options: ReadOptions | None = None) -> list[str]:
    """Expand directories (their files, sorted) and glob patterns; keep files and '-' as given. Files
    found in a directory or through a pattern that hold no pose data are left out, with one warning
    naming them (:func:`rbgp_cli.io.read.expand_sources`)."""
    from rbgp_cli.io.read import expand_sources

    return expand_sources(paths, options)


def load_demonstrations(sources, options: ReadOptions | None = None, *, max_gap: float | None = None,
                        stdin=None) -> tuple[list, list[dict], list[dict]]:
    """Read and clean demonstrations.

    Returns (demonstrations, repair reports, provenance of the inputs: name, format, sha256). The
    options' cropping and splitting (``split_gap``, ``crop_from``/``crop_to``, ``split_at_rest``) may
    cut one trajectory read into several demonstrations, each said in a warning; the reports are one per
    trajectory read (:func:`rbgp_cli.dynamics.prepare.prepare_all`).
    """
    from rbgp_cli.dynamics.prepare import prepare_all
    from rbgp_cli.io.model_store import file_sha256
    from rbgp_cli.io.read import read_sources

    options = options or ReadOptions()
    sources = list(sources or [])
    if not sources:
        raise InputError("no demonstrations given", hint="pass one or more files or a directory")
    raw, listing = read_sources(sources, options, stdin=stdin)  # skips what is not pose data in folders
    paths = listing.files  # the files read
    if not raw:
        raise InputError("the inputs hold no demonstrations", path=", ".join(paths))
    clean, reports = prepare_all(raw, max_gap=max_gap, **options.prepare_kwargs())
    inputs = []
    for p in paths:
        entry = {"name": p}
        if p != "-" and os.path.isfile(p):
            entry["sha256"] = file_sha256(p)
            entry["bytes"] = os.path.getsize(p)
        inputs.append(entry)
    return clean, reports, inputs


def train_from_files(sources, output, *, options: ReadOptions | None = None, max_gap=None, stdin=None,
                     progress=None, **train_kwargs):
    """``rbgp train``: read + clean demonstrations, train, save atomically. Returns (model, header).

    ``train_kwargs`` go to :func:`rbgp_cli.dynamics.model.train_model` (representation, kernel,
    rho_rot, restarts, seed, noise, shared, subsample, max_points, explore_size).
    """
    from rbgp_cli.dynamics.model import train_model
    from rbgp_cli.io.model_store import save_model

    options = options or ReadOptions()
    check_writable(output)  # fail before minutes of training, not after
    trajs, reports, inputs = load_demonstrations(sources, options, max_gap=max_gap, stdin=stdin)
    model = train_model(trajs, progress=progress, **train_kwargs)
    model.provenance = {
        "rbgp_version": __version__,
        "created_unix": time.time(),
        "inputs": inputs,
        "demonstrations": [
            {"name": t.name, "source": t.source, "samples": len(t), "duration_s": t.duration} for t in trajs
        ],
        "read_options": {k: v for k, v in asdict(options).items() if v is not None},
        "max_gap": max_gap,
        "train_options": {k: (v if isinstance(v, (int, float, str, bool)) or v is None
                              else v.to_dict() if hasattr(v, "to_dict") else str(v))
                          for k, v in train_kwargs.items()},
        "repairs": reports,
    }
    frames = {t.info.get("frame_id") for t in trajs if getattr(t, "info", None)}
    if len(frames) == 1 and None not in frames:  # the demonstrations' frame: rollout's MCAP output names it
        model.provenance["frame_id"] = str(frames.pop())
    header = save_model(model, output)
    return model, header, trajs


def check_writable(path) -> None:
    """Raise InputError unless ``path`` can be created (its folder exists and is writable)."""
    folder = os.path.dirname(os.path.abspath(str(path)))
    if os.path.isdir(str(path)):
        raise InputError("is a directory; give a file name for the output", path=str(path))
    if os.path.exists(str(path)) and not os.path.isfile(str(path)):  # /dev/null, a FIFO: written into
        if not os.access(str(path), os.W_OK):
            raise InputError("cannot write to this device or FIFO (no permission)", path=str(path))
        return
    if not os.path.isdir(folder):
        raise InputError("the output folder does not exist", path=str(path), hint="create it first")
    if not os.access(folder, os.W_OK):
        raise InputError("the output folder is not writable", path=str(path))


_WORDS = {6: "six", 7: "seven"}


def _pose_numbers(text: str, n: int, flag: str, hint: str, what: str | None = None) -> np.ndarray:
    """The ``n`` finite numbers of a pose typed after ``flag`` (spaces or commas between them); ``what``
    names the pose in errors (default "start pose TEXT (FLAG)")."""
    what = f"start pose {text!r} ({flag})" if what is None else what
    try:
        vals = np.array([float(v) for v in text.replace(",", " ").split()])
    except ValueError:
        raise InputError(f"{what} is not {_WORDS[n]} numbers", hint=hint, param=flag) from None
    if vals.shape != (n,) or not np.all(np.isfinite(vals)):
        raise InputError(f"{what} must be {_WORDS[n]} finite numbers", hint=hint, param=flag)
    return vals


def parse_pose(text: str) -> tuple[np.ndarray, np.ndarray]:
    """Parse a start pose "rx ry rz x y z" (rotation vector in rad, position in m; commas allowed)."""
    from rbgp_cli.geometry.so3 import quat_from_rotvec

    # "the start pose", the flag in the hint: the command line names a one-word option only at the start
    # of the message or in the hint (rbgp_cli.cli.common.as_flags), so "(start)" would stay as it is
    vals = _pose_numbers(text, 6, "start", 'write start as "rx ry rz x y z" (rotation vector in rad, m), or a quaternion '
                         'with start_quat "qx qy qz qw x y z"', what=f"the start pose {text!r}")
    return quat_from_rotvec(vals[:3]), vals[3:]


def parse_pose_quat(text: str) -> tuple[np.ndarray, np.ndarray]:
    """Parse a start pose "qx qy qz qw x y z" (quaternion x, y, z, w; position in m; commas allowed).

    The quaternion is normalised (q / |q|); a zero one (|q| below the reader's zero threshold) is refused.
    """
    from rbgp_cli.dynamics.prepare import ZERO_QUAT_NORM

    vals = _pose_numbers(text, 7, "start_quat", 'write it as "qx qy qz qw x y z" (quaternion x, y, z, w; m)')
    norm = float(np.linalg.norm(vals[:4]))
    if norm < ZERO_QUAT_NORM:
        raise InputError(f"start pose {text!r} (start_quat) has a zero quaternion, which is no rotation", param="start_quat",
                         hint='give a unit quaternion x y z w first, e.g. "0 0 0 1 x y z" for no rotation')
    _warn_far_from_unit(norm, f"start pose {text!r} (start_quat)", "start_quat")
    return vals[:4] / norm, vals[4:]


def _warn_far_from_unit(norm: float, what: str, flag: str) -> None:
    """A typed quaternion is normalised whatever its length, but one further from unit length than a
    file's rows may be (a digit or the order wrong, more often than a scaled quaternion) is said."""
    from rbgp_cli.dynamics.prepare import UNIT_TOLERANCE
    from rbgp_cli.errors import warn

    if abs(norm - 1.0) > UNIT_TOLERANCE:
        warn(f"the quaternion of the {what} has norm {norm:.4g}, not 1: it was normalised", param=flag,
             hint="check its digits and the order x y z w (a unit quaternion's components lie in [-1, 1])")


_GOAL_HINT = 'write it as "qx qy qz qw x y z" (quaternion x, y, z, w; m)'


def parse_goal(text: str, flag: str = "goal", what: str = "goal pose") -> tuple[np.ndarray, np.ndarray]:
    """Parse a goal pose "qx qy qz qw x y z" (quaternion x, y, z, w, normalised here; position in m;
    commas allowed), as :func:`parse_pose_quat` reads a start."""
    from rbgp_cli.dynamics.prepare import ZERO_QUAT_NORM

    try:
        vals = np.array([float(v) for v in str(text).replace(",", " ").split()])
    except ValueError:
        raise InputError(f"the {what} {text!r} is not seven numbers", hint=_GOAL_HINT, param=flag) from None
    if vals.shape != (7,) or not np.all(np.isfinite(vals)):
        raise InputError(f"the {what} {text!r} must be seven finite numbers", hint=_GOAL_HINT, param=flag)
    norm = float(np.linalg.norm(vals[:4]))
    if norm < ZERO_QUAT_NORM:
        raise InputError(f"the {what} {text!r} has a zero quaternion, which is no rotation", param=flag,
                         hint='give a unit quaternion x y z w first, e.g. "0 0 0 1 x y z" for no rotation')
    _warn_far_from_unit(norm, f"{what} {str(text).strip()!r}", flag)
    return vals[:4] / norm, vals[4:]


def parse_via(text: str) -> tuple[float, np.ndarray, np.ndarray]:
    """Parse a via-point "T: qx qy qz qw x y z" (T seconds after the start, then a pose as
    :func:`parse_goal`). Returns (T, quat (4,) x, y, z, w, position (3,) m)."""
    hint = 'write it as "T: qx qy qz qw x y z" (T seconds after the start; quaternion x, y, z, w; m)'
    head, sep, pose = str(text).partition(":")
    if not sep:
        raise InputError(f"the via-point {text!r} has no time before a colon", hint=hint, param="via")
    try:
        t = float(head)
    except ValueError:
        raise InputError(f"the via-point {text!r}: its time {head.strip()!r} is not a number of seconds", hint=hint,
                         param="via") from None
    if not (np.isfinite(t) and t > 0):
        raise InputError(f"the via-point {text!r}: its time must be a positive number of seconds", hint=hint, param="via")
    q, p = parse_goal(pose, flag="via", what="via-point")
    return t, q, p


def parse_tolerance(text: str) -> tuple[float, float]:
    """Parse a goal tolerance "ROT_RAD POS_M" (one standard deviation of the goal's rotation, rad, and
    position, m; both positive)."""
    hint = 'write it as "ROT_RAD POS_M", e.g. "0.05 0.02" for 0.05 rad and 2 cm'
    try:
        vals = [float(v) for v in str(text).replace(",", " ").split()]
    except ValueError:
        raise InputError(f"the goal tolerance {text!r} is not two numbers", hint=hint,
                         param="goal_tolerance") from None
    from rbgp_cli.dynamics.paths import MAX_GOAL_TOLERANCE

    if len(vals) != 2 or not all(0 < v <= MAX_GOAL_TOLERANCE for v in vals):
        raise InputError(f"the goal tolerance {text!r} must be two positive numbers (up to {MAX_GOAL_TOLERANCE:g})",
                         hint=hint, param="goal_tolerance")
    return vals[0], vals[1]


def goal_options(count: int, *, goal=None, goals=None, via=(), goal_tolerance=None,
                 options: ReadOptions | None = None) -> dict:
    """The goal, via-points and tolerance of ``rbgp rollout`` for ``count`` starts, as keywords of
    :func:`rollout_model`: ``goal`` text (:func:`parse_goal`, one goal for every start) or the poses of
    the file ``goals`` (:func:`read_start_poses`, one per start in the order of the starts), each
    ``via`` text (:func:`parse_via`) and ``goal_tolerance`` text (:func:`parse_tolerance`). Nothing
    given: {} (a rollout from the start alone)."""
    if goal and goals:
        raise InputError("give goal (one goal for every start) or goals FILE (one per start), not both",
                         param=("goal", "goals"))
    out: dict = {}
    if goal:
        q, p = parse_goal(goal)
        out["goal_quat"], out["goal_position"] = np.tile(q, (count, 1)), np.tile(p, (count, 1))
    elif goals:
        q, p = read_start_poses(goals, options)
        if len(q) != count:
            raise InputError(f"the goals file has {len(q)} poses for {count} starts", path=str(goals),
                             hint="give goals one pose per start, in the order of the starts", param="goals")
        out["goal_quat"], out["goal_position"] = q, p
    if via:
        out["via"] = [parse_via(v) for v in via]
    if goal_tolerance:
        if not out:
            raise InputError("goal_tolerance softens a goal or via-point, and none is given",
                             param=("goal_tolerance", "goal", "goals", "via"), hint="add goal POSE, goals FILE or via \"T: POSE\"")
        out["goal_tolerance"] = parse_tolerance(goal_tolerance)
    return out


def read_start_poses(path, options: ReadOptions | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Poses from a file, one per row (any pose columns the CSV reader knows): rollout starts, or the
    poses ``rbgp predict`` evaluates. Returns unit quaternions (m, 4) x, y, z, w and positions (m, 3).

    Every row must be a pose: finite values and a quaternion within 0.1 of unit norm (the tolerance of
    :func:`~rbgp_cli.dynamics.prepare.prepare_trajectory`); the error names the file line otherwise.
    """
    from rbgp_cli.dynamics.prepare import ZERO_QUAT_NORM, line_of
    from rbgp_cli.io.read import read_demonstrations

    opts = options or ReadOptions()
    own_rate = opts.rate is None
    if own_rate:
        from dataclasses import replace

        opts = replace(opts, rate=1.0)  # a list of poses needs no time column
    trajs = read_demonstrations([str(path)], opts, own_rate=own_rate)
    q = np.concatenate([t.quat for t in trajs]) if trajs else np.zeros((0, 4))
    p = np.concatenate([t.position for t in trajs]) if trajs else np.zeros((0, 3))
    if len(q) == 0:
        raise InputError("no poses in the file", path=str(path))
    finite = np.all(np.isfinite(q), 1) & np.all(np.isfinite(p), 1)
    with np.errstate(invalid="ignore"):
        norm = np.linalg.norm(np.where(np.isfinite(q), q, 0.0), axis=1)
    bad = ~finite | ~(np.abs(norm - 1.0) <= 0.1)
    if np.any(bad):
        k = int(np.argmax(bad))
        offsets = np.cumsum([0] + [len(t) for t in trajs])
        j = int(np.searchsorted(offsets, k, side="right")) - 1
        if not finite[k]:
            what, hint = "has a value that is not a finite number", "remove or fix that row"
        elif norm[k] < ZERO_QUAT_NORM:
            what, hint = "has an all-zero quaternion", "remove or fix that row"
        else:
            what = f"has a quaternion of norm {norm[k]:.6g}, far from 1"
            hint = "check the column mapping and the quaternion order (columns, quat_order)"
        raise InputError(f"pose {k + 1} {what}", path=str(path), row=line_of(trajs[j], k - offsets[j]), hint=hint,
                         param="columns")
    return q / norm[:, None], p


def predict_file(model, path, options: ReadOptions | None = None, noisy: bool = False, max_gap: float | None = None,
                 names: list | None = None):
    """``rbgp predict``: velocity mean and std at every pose of a file.

    Returns (t or None, quat (m, 4), position (m, 3), mean (m, L), std (m, L)); ``names``, a list, gets each row's
    trajectory name where the file holds trajectories, as the file names them (the reader's ``FILE#`` prefix, the
    same for all, left out). For a model without a
    time input the file is a list of poses (:func:`read_start_poses`); with one it holds trajectories
    with times, and each pose gets its time since its trajectory's start (seconds, or the phase
    t/D for a phase model, whose outputs per unit phase are divided by D: per second); ``max_gap``
    fills their lost frames as in training (:func:`load_demonstrations`).
    """
    if not model.time_input:
        q, p = read_start_poses(path, options)
        mean, std = model.predict(q, p, return_std=True, noisy=noisy)
        return None, q, p, mean, std
    from rbgp_cli.dynamics.prepare import prepare_all
    from rbgp_cli.io.read import read_demonstrations

    try:
        raw = read_demonstrations([str(path)], options or ReadOptions())
    except InputError as e:
        if "no time column" not in str(e) or (options and options.rate):
            raise
        what = "the phase (t − t0)/duration" if model.time_input == "phase" else "the time since the start"
        raise InputError(f"this model takes {what} as an input, and the poses have no time column", path=str(path),
                         hint="give the poses as trajectories with a time column t (or rate HZ), or train a model of "
                              "the pose alone with time_input none and prior none", param=("rate", "time_input", "prior")) from None
    trajs, _ = prepare_all(raw, max_gap=max_gap)
    ts, qs, ps, means, stds = [], [], [], [], []
    for tr in trajs:
        tau = tr.t - tr.t[0]
        scale = max(tr.duration, 1e-12) if model.time_input == "phase" else 1.0
        mean, std = model.predict(tr.quat, tr.position, return_std=True, noisy=noisy,
                                  tau=tau / scale if model.time_input == "phase" else tau,
                                  start=(tr.quat[0], tr.position[0]))
        ts.append(tr.t)
        if names is not None:
            names.extend([tr.name] * len(tr.t))
        qs.append(tr.quat)
        ps.append(tr.position)
        means.append(mean / scale)
        stds.append(std / scale)
    if names is not None:
        heads = {str(x).split("#", 1)[0] for x in names}
        if len(heads) == 1 and all("#" in str(x) for x in names):  # one file's trajectories: its own names
            names[:] = [str(x).split("#", 1)[1] for x in names]
    return (np.concatenate(ts), np.concatenate(qs), np.concatenate(ps), np.concatenate(means), np.concatenate(stds))


def rollout_starts(model, *, start=(), start_quat=(), starts=None, from_demos=None, count: int | None = None,
                   start_spread: float | None = None, seed: int = 0, options: ReadOptions | None = None, max_gap=None,
                   each_duration: bool = False, duration=None, progress=None):
    """The start poses of ``rbgp rollout``, in this order: each ``start`` text ("rx ry rz x y z",
    :func:`parse_pose`), each ``start_quat`` text (:func:`parse_pose_quat`), the poses of the file
    ``starts`` (:func:`read_start_poses`), and ``count`` starts drawn near the start poses of the
    demonstrations ``from_demos`` in the order they are read, start i near demonstration i mod D
    (:func:`~rbgp_cli.dynamics.rollout.starts_near`, ``start_spread`` m or None for starts drawn like the
    demonstrations' own, from one file with the spread of the model's stored starts, ``seed``; ``count`` None: one per
    demonstration, so that a goals file in the demonstrations' order pairs each goal with its own start).
    None of them given: ``count`` (None: 1) starts near the model's stored start poses (its first one as it
    is when ``count`` is 1 and the spread 0).

    Returns (quat (B, 4) x, y, z, w, position (B, 3) m, durations (B,) s or None): with
    ``each_duration`` each start drawn near a demonstration lasts as long as it, the others
    ``duration`` (default the model's median demonstration duration).
    """
    from rbgp_cli.dynamics.rollout import start_vectors, starts_near

    if start_spread is not None and not (np.isfinite(start_spread) and start_spread >= 0):  # inf: every start at infinity
        raise InputError(f"start_spread must be a non-negative number of metres, got {start_spread:g}", param="start_spread")
    qs, ps, durs = [], [], []
    for s in start or []:
        q, p = parse_pose(s)
        qs.append(q[None])
        ps.append(p[None])
    for s in start_quat or []:
        q, p = parse_pose_quat(s)
        qs.append(q[None])
        ps.append(p[None])
    if starts:
        q, p = read_start_poses(starts, options)
        qs.append(q)
        ps.append(p)
    given = sum(len(q) for q in qs)  # starts that are not drawn near a demonstration
    if given and not from_demos and count not in (None, 1):  # count draws starts, and none are drawn: it would do nothing
        raise InputError(f"count {count} is how many starts to draw near the demonstrations' start poses, and with "
                         "start poses given none are drawn", param="count",
                         hint="add from_demos FILES to draw them there as well, or drop count")
    if from_demos:
        demos, _, _ = load_demonstrations(from_demos, options, max_gap=max_gap)
        q, p, near = starts_near(start_vectors(demos), len(demos) if count is None else count, start_spread, seed=seed,
                                 return_index=True, in_order=True, shape=model.starts)  # one file: the model's spread
        qs.append(q)
        ps.append(p)
        durs = [demos[i].duration for i in near]
    if not qs:
        count = 1 if count is None else count
        m_starts = model.starts
        q, p = (starts_near(m_starts, count, start_spread, seed=seed) if count > 1 or start_spread != 0
                else (m_starts[:1, :4], m_starts[:1, 4:]))
        qs.append(q)
        ps.append(p)
        if progress is not None:
            progress(f"no start given: {len(q)} start(s) near the demonstrations' start poses stored in the model")
    durations = None
    if each_duration:
        other = float(np.median(model.durations)) if duration is None else float(duration)
        durations = np.concatenate([np.full(given, other), durs])
    return np.concatenate(qs), np.concatenate(ps), durations


def rollout_model(model, quat, pos, *, steps=None, duration=None, dt=None, samples=0, seed=0, with_std=True,
                  progress=None, durations=None, rate=None, off_data: str = "keep", goal_quat=None,
                  goal_position=None, via=(), goal_tolerance=None):
    """``rbgp rollout``: steps from ``steps``, or ``duration`` / dt, or the demonstrations' median duration.

    ``durations`` (B,) seconds: each trajectory its own duration instead (``steps``/``duration`` are
    then ignored; :func:`~rbgp_cli.dynamics.rollout.rollout_for`).

    ``dt``: the integration step, by default the model's rollout step for a duration
    (:attr:`~rbgp_cli.dynamics.model.MotionModel.rollout_dt`, the recorded sample interval, so that
    a rollout written at the recorded rate is integrated at every sample it writes) and the training
    step for ``steps`` (``steps`` counts steps of the dynamics as learned).
    ``rate`` (Hz): write the result at this rate instead of the integration grid: the poses and stds
    are interpolated between the steps (:meth:`~rbgp_cli.dynamics.rollout.RolloutResult.resampled`);
    None keeps the integration grid.

    ``off_data`` (keep, stop, prior): what a rollout does outside the demonstrations' envelope
    (:mod:`rbgp_cli.dynamics.rollout`); rollouts that left it are named in one warning (the result's
    ``left`` lists them).

    ``goal_quat`` (B, 4) / ``goal_position`` (B, 3), ``via`` [(T s, quat (4,), position (3,)), ...],
    ``goal_tolerance`` (rad, m) or None (reach them): the motions end at the goals and pass the
    via-points (:func:`~rbgp_cli.dynamics.rollout.rollout_conditioned`, docs/method.md §12); their
    duration is ``durations``, else ``duration``, else the path distribution's conditional duration
    given start and goal (``steps`` is refused: a goal fixes where the motion ends, not a step count).
    Goals far from where the demonstrations end are warned about (:func:`warn_far_goals`).
    """
    from rbgp_cli.dynamics.envelope import describe
    from rbgp_cli.dynamics.rollout import rollout, rollout_for
    from rbgp_cli.errors import warn

    if dt is None:
        dt = model.dt if steps is not None and durations is None else model.rollout_dt
    step = float(dt)
    if not np.isfinite(step) or step <= 0:  # before it divides a duration into steps
        raise InputError(f"dt must be a positive number of seconds, got {step:g}", param="dt")
    kwargs = {"samples": samples, "seed": seed, "with_std": with_std, "progress": progress, "off_data": off_data}
    if goal_quat is not None or via:
        res = _rollout_to_goal(model, quat, pos, steps=steps, duration=duration, durations=durations, dt=step,
                               goal_quat=goal_quat, goal_position=goal_position, via=via,
                               goal_tolerance=goal_tolerance, rate=None if rate is None or abs(float(rate) * step - 1.0) <= 1e-9 else rate,
                               **kwargs)
    elif durations is not None:
        res = rollout_for(model, quat, pos, durations, step, **kwargs)
    else:
        if steps is None:
            dur = float(np.median(model.durations)) if duration is None else float(duration)
            if not np.isfinite(dur) or dur <= 0:
                raise InputError(f"duration must be a positive number of seconds, got {dur}", param="duration")
            steps = max(1, int(round(dur / step)))
        res = rollout(model, quat, pos, steps, step, **kwargs)
    if res.left and res.left["count"]:
        residual_off = float(getattr(model, "residual_gain", 1.0)) == 0.0  # the motion is the prior's already
        then = {"keep": "they went on (off_data stop ends them there" + ("" if residual_off else
                                                                        ", prior falls back to the prior's pull") + ")",
                "stop": "they end there (off_data stop)",
                "prior": ("they went on: this model's GP residual is off (gain 0), so its motion is the prior's "
                          "everywhere and off_data prior changes nothing (off_data stop ends them)" if residual_off else
                          "they followed the prior mean while outside (off_data prior)")}[off_data]
        warn(describe(res.left) + f"; {then}"
             + ("; envelope from the model's training points (an older model file)" if res.left["envelope"] != "demonstrations" else ""))
    var = getattr(model, "variation", None)
    res.start_beyond = None if var is None else var.start_beyond(quat, pos)
    _note_unlike_starts(res)
    _note_widened_starts(res)
    if rate is not None and abs(float(rate) * step - 1.0) > 1e-9 and res.goal_distance is None and not res.via:
        res = res.resampled(rate)  # at 1/dt the grid is the integration grid (a conditioned one is resampled before it is bent)
    return res


def _shown(idx) -> str:
    """Rollout numbers for a warning: the first eight, then how many more."""
    return ", ".join(str(int(b)) for b in idx[:8]) + (f" and {len(idx) - 8} more" if len(idx) > 8 else "")


def _note_unlike_starts(res) -> None:
    """One warning naming the sampled rollouts whose start is less like the demonstrations' starts than any of theirs
    was like the others' (``start_beyond`` above 1, :meth:`~rbgp_cli.dynamics.variation.Variation.start_beyond`):
    held out, such starts' motions differed from the demonstrations more than the others' (docs/defaults.md,
    eighteenth pass), and their bands are widened by √(ρ / ρ_max)."""
    from rbgp_cli.errors import warn

    beyond, w = getattr(res, "start_beyond", None), getattr(res, "band_widening", None)
    if beyond is None or w is None:
        return
    far = np.flatnonzero(np.asarray(beyond) > 1.0)
    if len(far):
        lo, hi = float(np.min(beyond[far])), float(np.max(beyond[far]))
        by = f"{lo:.2g}" if f"{lo:.2g}" == f"{hi:.2g}" else f"{lo:.2g}–{hi:.2g}"
        widen = np.max(np.asarray(w)[far], axis=-1)
        wl, wh = float(widen.min()), float(widen.max())
        wby = f"×{wl:.2f}" if round(wl, 2) == round(wh, 2) else f"×{wl:.2f}–×{wh:.2f}"
        warn(f"{len(far)} of {len(beyond)} starts are less like the demonstrations' starts than any of theirs is like "
             f"the others' ({by} × the least typical one's surprise): their motions may differ from every "
             f"demonstration, and their bands are widened {wby} (rollouts {_shown(far)}; start_beyond)")


def _note_widened_starts(res) -> None:
    """One warning naming the rollouts whose start's surprise widened their bands by WIDENING_NOTE or more
    (:meth:`~rbgp_cli.dynamics.variation.Variation.start_widening`), but for those :func:`_note_unlike_starts` names."""
    w = getattr(res, "band_widening", None)
    if w is None:
        return
    w = np.max(np.asarray(w), axis=-1)  # (B,): the larger of the rotation and position part's
    beyond = getattr(res, "start_beyond", None)
    unlike = np.zeros(len(w), dtype=bool) if beyond is None else np.asarray(beyond) > 1.0
    far = np.flatnonzero((w >= WIDENING_NOTE) & ~unlike)
    if len(far):
        shown = _shown(far)
        lo, hi = float(np.min(w[far])), float(np.max(w[far]))
        by = f"×{lo:.2f}" if round(lo, 2) == round(hi, 2) else f"×{lo:.2f}–×{hi:.2f}"
        warn(f"{len(far)} of {len(w)} starts are less like the demonstrations' starts than three in four of theirs: "
             f"their bands are widened {by} (rollouts {shown}; band_widening)")


from rbgp_cli.dynamics.paths import FAR_GOAL  # noqa: E402  (warned about by warn_far_goals)


def warn_far_goals(distance) -> None:
    """One warning naming the goals further than :data:`FAR_GOAL` spreads from where the
    demonstrations end (``distance`` (B,), :meth:`~rbgp_cli.dynamics.paths.PathDistribution.goal_distance`)."""
    from rbgp_cli.errors import warn

    d = np.asarray(distance, dtype=np.float64).reshape(-1)
    far = np.flatnonzero(d > FAR_GOAL)
    if len(far) == 0:
        return
    worst = float(d[far].max())
    if len(d) == 1:
        what = f"the goal is {worst:.1f} standard deviations from where the demonstrations end: this motion is an extrapolation"
    elif len(far) == 1:
        what = (f"the goal of trajectory {int(far[0])} is {worst:.1f} standard deviations from where the demonstrations "
                "end: that motion is an extrapolation")
    else:
        listed = ", ".join(map(str, far[:8])) + (", ..." if len(far) > 8 else "")
        what = (f"{len(far)} of {len(d)} goals are up to {worst:.1f} standard deviations from where the demonstrations "
                f"end (trajectories {listed}): those motions are extrapolations")
    warn(what, hint="check the goal's frame and units, or record demonstrations that end there", param=("goal", "goals"))


def warn_far_via(distance, via) -> None:
    """One warning naming the via-points further than :data:`FAR_GOAL` spreads from where the
    demonstrations pass at their phase, given the start (``distance`` (B, V),
    :meth:`~rbgp_cli.dynamics.paths.PathDistribution.pose_distance`; ``via`` [(T s, quat, position)])."""
    from rbgp_cli.errors import warn

    d = np.asarray(distance, dtype=np.float64).reshape(-1, len(via))
    worst = d.max(axis=0)  # (V,) the furthest over the starts
    far = np.flatnonzero(worst > FAR_GOAL)
    if len(far) == 0:
        return
    if len(via) == 1:
        what = (f"the via-point at {float(via[0][0]):g} s is {worst[0]:.1f} standard deviations from where the "
                "demonstrations pass at that time: this motion is an extrapolation")
    else:
        listed = ", ".join(f"{float(via[i][0]):g} s ({worst[i]:.1f})" for i in far)
        what = (f"{len(far)} of {len(via)} via-points lie far from where the demonstrations pass at their time "
                f"(standard deviations: {listed}): this motion is an extrapolation")
    warn(what, hint="check the time, frame and units of via, or record demonstrations that pass there", param="via")


def _rollout_to_goal(model, quat, pos, *, steps, duration, durations, dt, goal_quat, goal_position, via,
                     goal_tolerance, samples, seed, with_std, progress, off_data, rate=None):
    """:func:`rollout_model` with a goal or via-points: checks, durations, the conditioned rollout, the
    far-goal warning."""
    from rbgp_cli.dynamics.rollout import rollout_conditioned

    if steps is not None:
        raise InputError("a goal or via-point fixes where the motion goes, and steps counts integration steps",
                         hint="give duration SECONDS, or neither (the duration the demonstrations suggest for "
                              "this start and goal)", param=("steps", "duration"))
    paths = getattr(model, "paths", None)
    if paths is None:
        raise InputError("this model has no path distribution to condition on a goal or via-points (it was trained "
                         "on fewer than three demonstrations, or by an older rbgp)",
                         hint="retrain it with rbgp train on three demonstrations or more", param=("goal", "via"))
    B = len(np.atleast_2d(quat))
    if durations is None and duration is not None:
        dur = float(duration)
        if not np.isfinite(dur) or dur <= 0:
            raise InputError(f"duration must be a positive number of seconds, got {dur}", param="duration")
        durations = np.full(B, dur)
    res = rollout_conditioned(model, quat, pos, goal_quat=goal_quat, goal_position=goal_position, via=list(via),
                              durations=durations, goal_tolerance=goal_tolerance, samples=samples, seed=seed,
                              dt=dt, with_std=with_std, progress=progress, off_data=off_data, rate=rate)
    if res.goal_distance is not None:
        warn_far_goals(res.goal_distance)
    if getattr(res, "via_distance", None) is not None:
        warn_far_via(res.via_distance, res.via)
    return res


def continue_files(model, sources, *, options: ReadOptions | None = None, max_gap=None, samples: int = 0, seed: int = 0,
                   paths=None, progress=None) -> list:
    """``rbgp rollout --given``: each motion read from ``sources`` (files, folders, patterns; cleaned as
    demonstrations are) is the seen beginning of a new motion; returns one
    :class:`~rbgp_cli.dynamics.anticipation.Continuation` per motion, in the order read, named 0, 1, …
    (its samples ``0.s0``, …), on the seen file's own clock (docs/method.md §13). ``paths``: the path
    distribution (default the model's)."""
    seen, _, _ = load_demonstrations(sources, options, max_gap=max_gap)
    return continue_motions(model, seen, samples=samples, seed=seed, paths=paths)


def continue_motions(model, seen, *, samples: int = 0, seed: int = 0, dt: float | None = None, paths=None) -> list:
    """One :class:`~rbgp_cli.dynamics.anticipation.Continuation` per seen beginning of ``seen`` (Trajectories on their
    own clocks), named 0, 1, … (``seed + i`` seeds the i-th one's samples; ``dt`` their step, default the seen
    samples' median interval), with what ``rollout --given`` says of them on stderr: a seen motion that rests longer
    before it moves than any demonstration (``info["rest_before_moving"]``, s), the seen motions that are off or
    widened (:func:`_note_seen`), and the continuations that leave the demonstrations' envelope
    (:func:`_note_left_continuations`, ``info["left_data"]``; a model without an envelope: not checked)."""
    from rbgp_cli.dynamics.anticipation import Anticipator, rest_before_moving

    ant = Anticipator(getattr(model, "paths", None) if paths is None else paths, model)
    out, off, wide = [], [], []
    for i, tr in enumerate(seen):
        c = ant.continuation(tr.t, tr.quat, tr.position, samples=samples, seed=seed + i, dt=dt, name=str(i))
        c.info["source"] = tr.source or tr.name
        rest = rest_before_moving(tr.t, tr.position, ant.rest_speed)
        if rest > ant.lead + ant.lead_step:  # a recording begun earlier than the demonstrations' (method.md §13)
            c.info["rest_before_moving"] = rest
            warn(f"the seen motion rests {rest:.2f} s before it moves, longer than any demonstration does (at most "
                 f"{ant.lead:.2f} s): the estimate counts that rest as part of the motion; if the recording began "
                 f"earlier than theirs, read it with crop_from {rest - ant.lead:.2f} (s)", path=c.info["source"])
        if c.estimate.off:
            off.append(i)
        elif c.estimate.band_widening >= WIDENING_NOTE:
            wide.append(i)
        out.append(c)
    _note_seen(out, off, wide)
    envelope = model.data_envelope() if hasattr(model, "data_envelope") else None
    if envelope is not None:
        _note_left_continuations(out, envelope)
    return out


def _note_left_continuations(conts, envelope) -> dict:
    """Which continuations (mean and samples) leave the demonstrations' ``envelope``, each row at its phase of the
    whole motion (:func:`~rbgp_cli.dynamics.envelope.continuation_phases`: the mean's (t − t_0) / D̂ with t_0 the seen
    start, a sample's from the same current phase to 1 at its own end): each continuation's ``info["left_data"]`` is
    a list, the mean's then its samples', of (T,) bool rows outside (what ``rollout --given`` writes in its left_data
    column); one warning names those that left (as ``rollout`` does), the times since the seen start. Returns
    :func:`~rbgp_cli.dynamics.envelope.left_envelope`'s report."""
    from rbgp_cli.dynamics.envelope import continuation_phases, describe, left_envelope

    trajs, phases, starts, owner = [], [], [], []
    for i, c in enumerate(conts):
        t0 = float(c.t[-1]) - float(c.duration)  # the seen start: the mean ends at t_0 + D̂
        own = c.trajectories(include_samples=True)
        trajs += own
        phases += continuation_phases(own, t0)
        starts += [t0] * len(own)
        owner += [i] * len(own)
    report = left_envelope(trajs, envelope, phases=phases, starts=starts, masks=True)
    for c in conts:
        c.info["left_data"] = []
    for i, rows in zip(owner, report.pop("outside")):
        conts[i].info["left_data"].append(rows)
    for e in report["trajectories"]:
        e["name"] = trajs[e["index"]].name
    if report["count"]:
        warn(describe(report, what="continuations (means and samples)") + "; they are extrapolations there "
             "(rows marked in the left_data column)")
    return report


def _note_seen(conts, off, wide) -> None:
    """What ``rollout --given`` says of the seen motions ``off`` (beyond the demonstrations) and ``wide`` (bands
    widened ×WIDENING_NOTE or more), given by their indices in ``conts``: naming the file when there is one such
    motion, else one warning for each kind with the range and the trajectories (as the start's notes do)."""
    for idx, kind in ((off, "off"), (wide, "wide")):
        if not idx:
            continue
        est = [conts[i].estimate for i in idx]
        if kind == "off":
            d = [e.distance for e in est]
            what = (f"left what the demonstrations cover (distance {min(d):.2f}" + (f"–{max(d):.2f}" if len(d) > 1 else "")
                    + " in units of the demonstrations' spread): the continuation is an extrapolation")
        else:
            w = [e.band_widening for e in est]
            what = (f"less like the demonstrations than most of them: the bands are widened ×{min(w):.2f}"
                    + (f"–×{max(w):.2f}" if len(w) > 1 else ""))
        field = "off" if kind == "off" else "band_widening"
        if len(idx) == 1:
            warn(f"the seen motion {'is' if kind == 'wide' else 'has'} {what} ({field})", path=conts[idx[0]].info["source"])
        else:
            verb = "are" if kind == "wide" else "have"
            warn(f"{len(idx)} of {len(conts)} seen motions {verb} {what} (trajectories {_shown(idx)}; {field})")


#: ``rollout`` (from a start, or ``--given`` a seen beginning) says on stderr when a motion's bands are widened by
#: at least this factor (its surprise 2.25 × the reference; docs/method.md §11 and §13)
WIDENING_NOTE = 1.5


def follow_stream(model, lines, *, options: ReadOptions | None = None, every: int = 1, detect: bool = True,
                  paths=None, source: str = "stdin", max_gap: float | None = None, path: str | None = None):
    """``rbgp follow``: poses arriving as CSV rows (``lines``: an iterator of text lines, the header first)
    followed live (:class:`~rbgp_cli.dynamics.anticipation.Follower`). Yields one dict per ``every`` poses
    of a motion under way: ``t``, ``start`` (when the motion left rest), ``rest_before`` (s: how much of the rest
    before it begins the motion, as the demonstrations begin at rest; its phase 0 is at ``start − rest_before``,
    :class:`~rbgp_cli.dynamics.anticipation.Follower`), ``motion`` (0, 1, … across
    repetitions), ``phase``, ``end_time`` and its 90 % band, the end pose with its 90 % bands, ``off``, ``at_rest`` (the
    pose at rest now, :attr:`~rbgp_cli.dynamics.anticipation.Follower.at_rest`: a hold in mid-motion). ``path``: the
    file the lines come from (None: a pipe), whose first bytes tell a format read whole from CSV rows.

    Lost frames (:class:`~rbgp_cli.io.stream.Lost`) are skipped, the first said in a warning and their count at the
    end; with ``max_gap`` (s) a run of them no longer than that is filled when the next pose arrives, at the lost
    rows' times, by slerp and linear interpolation between the poses around it (as a file's are,
    :func:`~rbgp_cli.dynamics.prepare.prepare_all`), each filled pose pushed before the new one. A motion that turns
    ``off`` (beyond the demonstrations), or whose bands are widened ×1.5 or more, is said once per motion on
    stderr (the JSON lines carry the numbers)."""
    from rbgp_cli.dynamics.anticipation import Follower
    from rbgp_cli.geometry.so3 import slerp
    from rbgp_cli.io.stream import Lost, RowStream, check_streamable

    fmt = getattr(options, "format", "auto") if options is not None else "auto"
    if fmt not in ("auto", "csv"):  # the other formats are files read whole (binary, or a header block)
        raise InputError(f"format {fmt} is read from whole files, and a stream is CSV rows (a header line, then one "
                         "pose per row)", path=source, param="format",
                         hint="stream a CSV of time, position and quaternion columns; a recorded file in that "
                              "format is continued whole, as a seen beginning")
    follower = Follower(getattr(model, "paths", None) if paths is None else paths, detect=detect)
    header = next(iter(lines), None)
    if header is None or not header.strip():
        raise InputError("no header line on the stream", path=source, hint="send the CSV's header line first")
    check_streamable(header, source, path)
    rows = RowStream(header, options, source)
    count, motion = 0, None
    lost: list = []  # the lost rows since the last pose
    n_lost = n_filled = 0
    last = None  # the last pose pushed (t, quat, position)
    said: set = set()  # (motion, what) said on stderr

    def push(row):
        nonlocal count, motion
        est = follower.push(*row)
        if est is None:
            return None
        if follower.motion != motion:
            motion, count = follower.motion, 0
        count += 1
        for what, on in (("off", est.off), ("wide", est.band_widening >= 1.5)):
            if on and (motion, what) not in said:
                said.add((motion, what))
                warn(f"motion {motion} at t = {est.t:g} s: " + (
                    "the seen motion has left what the demonstrations cover (off): its prediction is an extrapolation"
                    if what == "off" else f"the seen part is less like the demonstrations than the left-out ones: its "
                    f"bands are widened ×{est.band_widening:.2f} (band_widening)"), path=source)
        if (count - 1) % max(int(every), 1):
            return None
        return dict(motion=int(motion), start=float(follower.start), rest_before=follower.rest_before, **est.to_dict(),
                    at_rest=follower.at_rest)

    for line in lines:
        row = rows.parse(line)
        if row is None:
            continue
        if isinstance(row, Lost):
            if not n_lost:
                warn(f"row {row.row} is a lost frame (its pose empty or NaN): "
                     + (f"runs of lost frames up to {max_gap:g} s are filled when the next pose arrives, longer ones "
                        "skipped" if max_gap else "lost frames are skipped"), path=source)
            n_lost += 1
            lost.append(row)
            continue
        if lost and max_gap and last is not None and row[0] - last[0] <= max_gap and all(x.t is not None for x in lost):
            for x in lost:  # filled between the poses around the run, at the lost rows' own times
                f = (x.t - last[0]) / (row[0] - last[0])
                out = push((x.t, slerp(last[1], row[1], f), (1 - f) * last[2] + f * row[2]))
                n_filled += 1
                if out is not None:
                    yield out
        lost = []
        last = row
        out = push(row)
        if out is not None:
            yield out
    if n_lost:
        warn(f"{n_lost} lost frame{'s' if n_lost != 1 else ''} on the stream: {n_filled} filled, "
             f"{n_lost - n_filled} skipped", path=source)


def crossval_under_way(sources, fractions, train_kwargs: dict, *, options: ReadOptions | None = None, max_gap=None,
                       folds: int = 5, seed: int = 0, samples: int = 20, progress=None, peers: bool = True,
                       repeats: int = 1, order: str = "random", train_size: int | None = None) -> dict:
    """``rbgp crossval --given F``: per fold, train on the others (``train_kwargs``, the default
    representation and kernel), see each held-out demonstration's first fraction F and predict the rest
    (:mod:`rbgp_cli.evaluation.under_way`). The splits are crossval's
    (:func:`~rbgp_cli.evaluation.crossval.make_splits`: ``folds`` folds, or with ``train_size`` N that many
    subsets of N trained on and the others held out; ``order``, with ``"forward"`` ``folds`` blocks each
    predicted from those before it, the result's ``"folds"`` the splits used and ``"blocks"``,
    ``"skipped_blocks"`` as crossval's; ``repeats`` times with fold seeds ``seed``, ``seed`` + 1, ...);
    split i's samples are seeded ``seed`` + i. Returns ``{"rows": [{method, given, end_pos, ..., per_motion,
    paired}], "folds", "samples", "inputs", "paired_reference"}``, rows in the order F, then method; each row's
    ``per_motion`` its scores per held-out demonstration (index in the input order, name) and ``paired`` its
    paired comparison with rbgp's row at the same F (:func:`~rbgp_cli.evaluation.under_way.add_paired`;
    None for rbgp's own)."""
    from rbgp_cli.dynamics.defaults import DEFAULTS
    from rbgp_cli.dynamics.model import train_model
    from rbgp_cli.dynamics.paths import fit_paths
    from rbgp_cli.evaluation.crossval import repeated_splits, split_info
    from rbgp_cli.evaluation.peers import missing
    from rbgp_cli.evaluation.under_way import METHODS, REFERENCE, add_paired, under_way_fold
    from rbgp_cli.progress import as_progress

    fractions = [float(f) for f in fractions]
    for f in fractions:
        if not 0.0 < f < 1.0:
            raise InputError(f"a seen fraction must lie between 0 and 1, got {f:g}", param="given",
                             hint="give F such as 0.2, 0.4, 0.6, 0.8")
    demos, _, inputs = load_demonstrations(sources, options, max_gap=max_gap)
    if len(demos) < 4:
        raise InputError(f"crossval with a seen fraction needs at least 4 demonstrations, got {len(demos)}",
                         hint="the path distribution needs 3 in every training fold")
    methods = [m for m in METHODS if peers or m in ("rbgp", "no-GP", "nearest")]  # peers: the ProMPs (as --given goal)
    if peers and missing() is not None:
        from rbgp_cli.errors import warn

        warn("left out " + missing())
    folds = min(int(folds), len(demos)) if train_size is None else int(folds)
    splits = repeated_splits(len(demos), folds, seed, order, train_size, repeats)
    fewest = min(len(train_idx) for train_idx, _ in splits)
    if fewest < 3:  # each split's path distribution: none from fewer than three
        raise InputError(f"crossval with a seen fraction trains on at least 3 demonstrations in every split, and a split "
                         f"here trains on {fewest}", hint="use train_size 3 or more" if train_size is not None
                         else f"use folds {len(demos)} (one held out at a time), or record more demonstrations",
                         param=("train_size", "folds"))
    info = split_info(len(demos), folds, order, train_size)
    if info:  # forward: the splits used, not the blocks
        folds = len(splits)
    tot: dict = {}
    prog = as_progress(progress)
    with prog.task("crossval under way", total=len(splits), unit="folds") as task:
        for i, (train_idx, fold) in enumerate(splits):
            train = [demos[j] for j in train_idx]
            test = [demos[j] for j in fold]
            model = train_model(train, representation=DEFAULTS["representation"], kernel=DEFAULTS["kernel"],
                                **train_kwargs)
            paths = getattr(model, "paths", None) or fit_paths(train)
            out = under_way_fold(model, paths, train, test, fractions, samples=samples, seed=seed + i, methods=methods,
                                 indices=fold)
            for k, v in out.items():
                tot[k] = v if k not in tot else tot[k].add(v)
            task.advance()
    names, sources = [d.name for d in demos], [d.source for d in demos]
    rows = [dict(method=m, given=F, **tot[(m, F)].to_dict(), per_motion=tot[(m, F)].per_motion(names, sources))
            for F in fractions for m in methods if (m, F) in tot]
    add_paired(rows)  # each row's "paired" against rbgp's at the same F
    floor = {F: tot[("floor", F)].to_dict() for F in fractions if ("floor", F) in tot}
    return {"rows": rows, "folds": folds, "samples": samples, "inputs": [i["name"] for i in inputs],
            "floor_left_data": [{"given": F, "left_data": v["left_data"], "left_of": v["left_of"]} for F, v in floor.items()],
            "paired_reference": REFERENCE, "repeats": int(repeats), "order": order, "seed": int(seed),
            "train_size": None if train_size is None else int(train_size),
            "splits": [{"train": [int(j) for j in tr], "test": [int(j) for j in te]} for tr, te in splits], **info}


def generate_like_paper(model, demos, count=100, spread=PAPER_START_SPREAD, seed=0, progress=None):
    """The paper's protocol (sec. 4.3): ``count`` rollouts from unseen starts near the demonstrations'
    start poses, each as long as the demonstrations' median duration, at the model's rollout step
    (:attr:`~rbgp_cli.dynamics.model.MotionModel.rollout_dt`)."""
    from rbgp_cli.dynamics.rollout import start_vectors, starts_near

    starts = start_vectors(demos) if demos else model.starts
    q, p = starts_near(starts, count, spread, seed=seed)
    dur = float(np.median([t.duration for t in demos])) if demos else float(np.median(model.durations))
    return rollout_model(model, q, p, duration=dur, with_std=False, progress=progress)


def evaluate_files(generated_sources, demo_sources, *, options: ReadOptions | None = None, max_gap=None,
                   length=None, covariance="diag", stdin=None, model=None, count=100, spread=PAPER_START_SPREAD, seed=0,
                   progress=None, unscored=False):
    """``rbgp evaluate``: Bhattacharyya distance between generated trajectories and demonstrations.

    ``generated_sources`` are files of generated trajectories ('-' for stdin); or, with ``model``,
    ``count`` trajectories are generated like the paper. Returns (EvaluationResult, generated, demos).

    Too few demonstrations for a score (one: :func:`rbgp_cli.evaluation.check_sample_sizes`) raise
    InputError, before any rollout; with ``unscored`` (a figure is wanted all the same) the result
    is returned instead, with the refusal recorded in it (:func:`score_refusal` tells), and the
    other sample-size warnings are still emitted.
    """
    from rbgp_cli.evaluation import evaluate
    from rbgp_cli.evaluation.bhattacharyya import check_sample_sizes

    demos, _, _ = load_demonstrations(demo_sources, options, max_gap=max_gap)
    if model is not None:
        refusal = check_sample_sizes(count, len(demos), covariance).refusal
        if refusal is not None and not unscored:  # before seconds of rollouts that could not be scored
            raise InputError(refusal, hint="pass more demonstrations (e.g. a folder of takes)", param="covariance")
        generated = generate_like_paper(model, demos, count=count, spread=spread, seed=seed,
                                        progress=progress).trajectories()
    else:
        if not generated_sources:
            raise InputError("no generated trajectories given", hint="pass a file (or - for stdin) or model MODEL", param="model")
        from rbgp_cli.io.model_store import is_model_file

        for src in generated_sources:
            if src != "-" and is_model_file(src):
                raise InputError("is a model file, not generated trajectories", path=str(src),
                                 hint=f"to score its rollouts: model {src} count N", param=("model", "count"))
        generated, _, _ = load_demonstrations(generated_sources, ReadOptions(), stdin=stdin)
    if unscored and check_sample_sizes(len(generated), len(demos), covariance).refusal is not None:
        result = evaluate(generated, demos, length=length, covariance=covariance, sample_size="record")
        for note in result.warnings[1:]:  # [0] is the refusal, which the caller reports as the error
            warn(note, param="covariance")
        return result, generated, demos
    result = evaluate(generated, demos, length=length, covariance=covariance)
    return result, generated, demos


def score_refusal(result) -> str | None:
    """Why ``result`` is no score (one demonstration, recorded by ``evaluate_files(unscored=True)``), or None."""
    from rbgp_cli.evaluation.bhattacharyya import check_sample_sizes

    return check_sample_sizes(result.n_generated, result.n_demos, result.covariance, result.ridge).refusal


def left_data(generated, demos) -> dict:
    """Which generated trajectories leave the envelope of ``demos`` (:mod:`rbgp_cli.dynamics.envelope`,
    each on its own phase): ``{"count", "of", "margin_m", "envelope", "trajectories": [...]}``, with
    each trajectory's name next to its index."""
    from rbgp_cli.dynamics.envelope import envelope_from_demos, left_envelope

    report = left_envelope(list(generated), envelope_from_demos(demos))
    for e in report["trajectories"]:
        e["name"] = generated[e["index"]].name
    return report


def crossval_configs(representations, kernels, train_kwargs: dict, replay: bool = True, variants=None,
                     peers: bool = True):
    """The rows of ``rbgp crossval``: every representation × kernel × variant of the training options,
    plus the replay peer and (``peers``, when movement-primitives is installed, else a note) the ProMP
    and DMP peers of :mod:`rbgp_cli.evaluation.peers`. ``all`` stands for the three representations; a kernel a representation does
    not have (the chordal distance on Euler angles) is left out for it, with a note in the returned list.

    ``variants``: None (one row per representation × kernel with ``train_kwargs``) or a list of
    ``(label, options, kwargs)`` (:func:`rbgp_cli.cli.train_options.grid_variants`, ``--grid``): each
    representation × kernel runs with each ``kwargs``, its row labelled with ``label`` and carrying
    ``options`` ({option: value}). The peers train no GP and stay one row each."""
    from rbgp_cli.dynamics.defaults import DEFAULT_KERNELS, DEFAULTS
    from rbgp_cli.dynamics.model import KERNELS
    from rbgp_cli.dynamics.representations import REPRESENTATIONS
    from rbgp_cli.evaluation.crossval import REPLAY, Config

    reps: list[str] = []
    for r in representations or [DEFAULTS["representation"]]:
        for name in (REPRESENTATIONS if r == "all" else [r]):
            if name not in REPRESENTATIONS:
                raise InputError(f"unknown representation {name!r}; expected one of {', '.join(REPRESENTATIONS)} or all")
            if name not in reps:
                reps.append(name)
    kerns = list(dict.fromkeys(kernels or []))
    for k in kerns:
        if k not in KERNELS:
            raise InputError(f"unknown kernel {k!r}; expected one of {', '.join(KERNELS)}")
    variants = list(variants) if variants else [("", {}, train_kwargs)]
    configs, skipped = [], []

    def add(r, k):
        for label, options, kw in variants:
            configs.append(Config(r, k, dict(kw), label=f"{r} {k} {label}" if label else "", options=dict(options)))

    for r in reps:
        for k in kerns or [DEFAULT_KERNELS[r]]:
            if r == "euler" and k == "se-chordal":
                skipped.append("euler with se-chordal (Euler angles have no chordal distance; euler runs with se)")
                if "se" not in kerns:
                    add(r, "se")
                continue
            add(r, k)
    if replay:
        configs.append(Config(REPLAY))
    if peers:
        from rbgp_cli.evaluation.peers import PEERS, missing

        note = missing()
        if note:
            skipped.append(note)
        else:
            configs.extend(Config(name) for name in PEERS)
    return configs, skipped


def given_option(text) -> dict:
    """``rbgp crossval --given``: ``goal`` → {"given": "goal"} (each held-out demonstration's final pose
    and duration given, :mod:`rbgp_cli.evaluation.given_goal`); None → {}."""
    if text is None:
        return {}
    if str(text).strip().lower() == "goal":
        return {"given": "goal"}
    raise InputError(f"given must be goal, got {text!r}", param="given",
                     hint="goal gives each held-out demonstration's final pose and duration")


def crossval_files(sources, configs, *, options: ReadOptions | None = None, max_gap=None, folds: int = 5,
                   seed: int = 0, jobs: int | None = None, length=None, covariance="diag", progress=None,
                   scheduler: str | None = None, samples: int | None = None, repeats: int = 1,
                   without_gp: bool = True, order: str = "random", train_size: int | None = None,
                   given: str | None = None) -> dict:
    """``rbgp crossval``: read and clean the demonstrations, cross-validate every configuration on the
    same folds (:func:`rbgp_cli.evaluation.crossval.crossval`); returns its result plus the inputs."""
    from rbgp_cli.evaluation.crossval import crossval

    demos, _, inputs = load_demonstrations(sources, options, max_gap=max_gap)
    from rbgp_cli.evaluation.crossval import SAMPLES

    result = crossval(demos, configs, folds=folds, seed=seed, jobs=jobs, length=length, covariance=covariance,
                      progress=progress, scheduler=scheduler, samples=SAMPLES if samples is None else samples,
                      repeats=repeats, without_gp=without_gp, order=order, train_size=train_size, given=given)
    result["inputs"] = [i["name"] for i in inputs]
    return result
