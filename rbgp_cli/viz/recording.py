"""Rerun recordings (``.rrd``) of training data, rollouts and evaluations, ready to open in the viewer.

Each function writes one file with its own :class:`rerun.RecordingStream` (never the global one),
recorded into memory and written when the recording is complete (:func:`rbgp_cli.io.atomic.atomic_open`:
whole or not at all), and gives it a default blueprint (a 3D view plus time-series views), so
``rerun FILE.rrd`` opens ready to read.

Conventions: positions in metres; quaternions x, y, z, w (Rerun's own order, passed as they are);
the time line ``time`` is a duration in seconds from the start of each trajectory; the time line
``step`` (evaluation) is the index j of the resampled steps, normalised time ``s_j = j / (T − 1)``.
Whatever does not change over time is logged static. Whole trajectories are logged column-wise
(``send_columns``): one call per entity, never one per sample.

Entity paths
------------
:func:`record_training`
    ``/world``                           view coordinates (z or y up)
    ``/world/demos/<name>/path``         each demonstration as a line strip (static)
    ``/world/demos/<name>/body``         its pose over ``time`` (Transform3D + TransformAxes3D)
    ``/world/training/points``           the GP's training inputs as positions (static Points3D)
    ``/world/training/velocity``         their training outputs' linear velocity (static Arrows3D,
                                         scaled so the median arrow is 5 % of the scene's size)
    ``/metrics/position/<axis>/<name>``  each demonstration's x, y, z over ``time``
:func:`record_rollout`
    ``/world/rollouts/<b>/path``         each mean rollout as a line strip (static)
    ``/world/rollouts/<b>/body``         its pose over ``time``
    ``/world/rollouts/<b>/samples``      its Monte Carlo rollouts, grey and translucent (static)
    ``/metrics/std/<output>``            predictive std of that output over ``time``, one series
                                         per rollout (same colour as in 3D)
    ``/metrics/position/<axis>``         x, y, z over ``time``, one series per rollout
:func:`record_evaluation`
    ``/world/demos/<name>/path|body``    demonstrations (warm colours), poses resampled on ``step``
    ``/world/generated/<name>/path|body``  generated trajectories (grey-blue), likewise
    ``/metrics/bhattacharyya``           per-step D_B: total, rotation, translation, on ``step``
    ``/metrics/features/<dim>``          per-step mean and mean ± 2σ of both sets for each tangent
                                         feature rx, ry, rz (rad) and x, y, z (m), on ``step``
"""

from __future__ import annotations

import contextlib
import uuid
from collections.abc import Sequence

import numpy as np

from rbgp_cli.dynamics.trajectory import Trajectory
from rbgp_cli.errors import InputError
from rbgp_cli.io.atomic import atomic_open

__all__ = ["record_training", "record_rollout", "record_evaluation", "APPLICATION_ID", "FEATURE_NAMES", "UP_AXES"]

#: The application id of every recording rbgp writes.
APPLICATION_ID = "rbgp"
#: Accepted ``up`` values and the Rerun view coordinates they select.
UP_AXES = {"z": "RIGHT_HAND_Z_UP", "y": "RIGHT_HAND_Y_UP"}
#: The evaluation's tangent features (rotation vector at the demonstrations' mean rotation, then position).
FEATURE_NAMES = ("rx", "ry", "rz", "x", "y", "z")
_AXES = ("x", "y", "z")

# tab10, the qualitative palette readers know from matplotlib (RGB)
_PALETTE = np.array(
    [[31, 119, 180], [255, 127, 14], [44, 160, 44], [214, 39, 40], [148, 103, 189],
     [140, 86, 75], [227, 119, 194], [127, 127, 127], [188, 189, 34], [23, 190, 207]], dtype=np.uint8)
_WARM = np.array([[214, 39, 40], [255, 127, 14], [227, 119, 194], [188, 189, 34], [140, 86, 75]], dtype=np.uint8)
_DEMO_MEAN = [200, 0, 0]
_GENERATED = [90, 110, 140]
_GEN_MEAN = [20, 20, 20]
_SAMPLE_RGBA = [150, 150, 150, 90]
_LINE = -1.5  # radii < 0 are UI points: lines stay visible at any scene scale
_THIN = -0.75


def _rerun():
    """Import rerun (and its blueprint module) on first use; a clear error if it is missing."""
    try:
        import rerun as rr
        import rerun.blueprint as rrb
    except ImportError:
        raise InputError("rerun needs rerun-sdk", hint="pip install 'rerun-sdk>=0.41'", param="rerun") from None
    return rr, rrb


def _check_up(up: str) -> str:
    if up not in UP_AXES:
        raise InputError(f"up must be z or y, got {up!r}", param="up")
    return up


def _colors(n: int, palette=_PALETTE) -> np.ndarray:
    """n RGB colours, cycling through ``palette``; shape (n, 3) uint8."""
    return palette[np.arange(n) % len(palette)]


def _names(trajs: Sequence[Trajectory], prefix: str) -> list[str]:
    """One unique, non-empty display name per trajectory (``<prefix><index>`` for unnamed ones)."""
    out, seen = [], set()
    for i, tr in enumerate(trajs):
        name = tr.name or f"{prefix}{i}"
        if name in seen:
            name = f"{name}#{i}"
        seen.add(name)
        out.append(name)
    return out


def _part(name: str) -> str:
    """An entity-path part that shows ``name`` as it is (``/``, spaces and ``#`` escaped)."""
    import rerun as rr

    return rr.escape_entity_path_part(str(name))


def _scene_size(*position_arrays) -> float:
    """Size of the scene, metres: the diagonal of the box holding the central 98 % of the finite
    positions along each axis (so a few wild points do not shrink everything else); 1 if empty."""
    pts = np.concatenate([np.asarray(p, dtype=np.float64).reshape(-1, 3) for p in position_arrays])
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    if len(pts) == 0:
        return 1.0
    lo, hi = np.percentile(pts, [1.0, 99.0], axis=0)
    size = float(np.linalg.norm(hi - lo))
    return size if size > 0 else 1.0


@contextlib.contextmanager
def _recording(path, blueprint, name: str):
    """A fresh RecordingStream into memory (rerun's binary stream: the .rrd bytes its file sink
    would write); after the last message is flushed and the stream disconnected, the bytes are
    written with :func:`~rbgp_cli.io.atomic.atomic_open` (whole file or nothing; a failed write is
    ``cannot write PATH: <reason>``). Not rerun's own file sink: when its writes fail (a full disk,
    the file-size limit) rerun 0.41 logs the reason, raises a bare RuntimeError and at times blocks
    in ``save`` for good (2 of 3 tries under a 20 kB size limit)."""
    rr, _ = _rerun()
    rec = rr.RecordingStream(APPLICATION_ID, recording_id=uuid.uuid4())
    rec.set_log_time_enabled(False)  # the wall clock of writing is noise in a data file
    stream = rec.binary_stream()
    try:
        rec.send_blueprint(blueprint, make_active=False, make_default=True)  # as save(default_blueprint=)
        rec.send_recording_name(name)
        yield rec
        rec.flush()
    finally:
        rec.disconnect()
    data = stream.read(flush=True)
    with atomic_open(path, "wb") as fh:
        fh.write(data)


def _log_world(rec, up: str) -> None:
    import rerun as rr

    rec.log("/world", getattr(rr.ViewCoordinates, UP_AXES[up]), static=True)


def _log_body(rec, entity: str, index, quat, position, axis_length: float) -> None:
    """Pose over time at ``entity``: one column-wise Transform3D call plus static axes."""
    import rerun as rr

    rec.log(entity, rr.TransformAxes3D(axis_length), static=True)
    rec.send_columns(
        entity,
        indexes=[index],
        columns=rr.Transform3D.columns(translation=np.asarray(position, dtype=np.float64),
                                       quaternion=np.asarray(quat, dtype=np.float64)),
    )


def _log_series(rec, entity: str, index, values, names, colors, widths=None) -> None:
    """Scalars over time at ``entity``: ``values`` (N, k) is k named series, logged column-wise."""
    import rerun as rr

    values = np.asarray(values, dtype=np.float64)
    values = values.reshape(len(values), -1)
    rec.log(entity, rr.SeriesLines(names=list(names), colors=np.asarray(colors), widths=widths), static=True)
    rec.send_columns(entity, indexes=[index], columns=rr.Scalars.columns(scalars=values))


def _views_per_key(rrb, origin: str, keys, titles, grid_columns: int = 3, name: str | None = None):
    return rrb.Grid(*[rrb.TimeSeriesView(origin=f"{origin}/{_part(k)}", name=t) for k, t in zip(keys, titles)],
                    grid_columns=grid_columns, name=name)


def _panels(rrb, timeline: str):
    return [rrb.BlueprintPanel(state="collapsed"), rrb.SelectionPanel(state="collapsed"),
            rrb.TimePanel(timeline=timeline, state="expanded")]


# ------------------------------------------------------------------------------------------ training
def record_training(path, trajs: Sequence[Trajectory], model, up: str = "z") -> None:
    """Write a recording of the demonstrations and the training points of ``model``.

    Parameters
    ----------
    path : str or Path
        The ``.rrd`` to write (atomically).
    trajs : sequence of Trajectory
        The (clean) demonstrations: t (N,) s, quat (N, 4) x, y, z, w, position (N, 3) m.
    model : MotionModel
        Its training inputs ``model.gp.X`` (n, d) become poses through
        ``model.representation.pose_from_state``; the last three columns of ``model.gp.Y`` (n, L)
        are the linear velocity (m/s) in every representation.
    up : {"z", "y"}
        World up axis.

    Contents: ``/world/demos/<name>/path`` (static strips), ``/world/demos/<name>/body`` (pose over
    ``time``, seconds from the demonstration's start), ``/world/training/points`` and
    ``/world/training/velocity`` (static; arrow length = speed × a scale chosen so the median arrow
    is 5 % of the scene's bounding-box diagonal; the scale in seconds is stored as the recording
    property ``rbgp.arrow_seconds``), ``/metrics/position/<axis>/<name>`` over ``time``.
    Blueprint: the 3D view beside x, y, z time series.
    """
    _check_up(up)
    trajs = list(trajs)
    rr, rrb = _rerun()
    names = _names(trajs, "demo_")
    parts = [_part(n) for n in names]
    colors = _colors(len(trajs))
    X = np.asarray(model.gp.X, dtype=np.float64)
    quat_tr, pos_tr = model.representation.pose_from_state(X[:, : model.pose_dims])
    # the training outputs: the GP's targets plus the prior mean it models the residual of (per second, or
    # per unit phase for a phase model: only their directions and relative lengths are drawn)
    prior = model.prior_mean(X)
    Y = np.asarray(model.gp.Y, dtype=np.float64) + (0.0 if prior is None else prior)
    vel = Y[:, -3:]
    size = _scene_size(pos_tr, *[tr.position for tr in trajs])
    speed = np.linalg.norm(vel, axis=1)
    median = float(np.median(speed)) if len(speed) else 0.0
    arrow_seconds = 0.05 * size / median if median > 0 else 0.0

    blueprint = rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(origin="/world", name="demonstrations and training points"),
            rrb.Vertical(*[rrb.TimeSeriesView(origin=f"/metrics/position/{a}", name=f"{a} [m]") for a in _AXES]),
            column_shares=[2, 1],
        ),
        *_panels(rrb, "time"),
    )
    with _recording(path, blueprint, "rbgp training") as rec:
        _log_world(rec, up)
        rec.send_property("rbgp", rr.AnyValues(kind="training", representation=str(model.representation.name),
                                               training_points=int(len(pos_tr)), arrow_seconds=float(arrow_seconds)))
        for tr, part, name, color in zip(trajs, parts, names, colors):
            base = f"/world/demos/{part}"
            rec.log(f"{base}/path", rr.LineStrips3D([tr.position], colors=[color], radii=_LINE, labels=[name]),
                    static=True)
            index = rr.TimeColumn("time", duration=tr.t - tr.t[0])
            _log_body(rec, f"{base}/body", index, tr.quat, tr.position, 0.04 * size)
            for j, axis in enumerate(_AXES):
                _log_series(rec, f"/metrics/position/{axis}/{part}", index, tr.position[:, j], [name], [color])
        rec.log("/world/training/points", rr.Points3D(pos_tr, colors=[[30, 30, 30]], radii=-2.5), static=True)
        rec.log("/world/training/velocity",
                rr.Arrows3D(origins=pos_tr, vectors=vel * arrow_seconds, colors=[[0, 150, 136]], radii=_THIN),
                static=True)


# ------------------------------------------------------------------------------------------ rollout
def record_rollout(path, res, up: str = "z") -> None:
    """Write a recording of rolled-out trajectories, their predictive std and Monte Carlo samples.

    Parameters
    ----------
    path : str or Path
        The ``.rrd`` to write (atomically).
    res : RolloutResult
        t (S+1,) s; quat (B, S+1, 4) x, y, z, w; position (B, S+1, 3) m; std (B, S+1, L) or None;
        output_names (L,); sample_quat / sample_position (B, K, S+1, ·) or None.
    up : {"z", "y"}
        World up axis.

    Contents: ``/world/rollouts/<b>/path`` (static strip), ``/world/rollouts/<b>/body`` (pose over
    ``time``), ``/world/rollouts/<b>/samples`` (K grey translucent strips, static, when sampled),
    ``/metrics/std/<output>`` (one series per rollout, when ``res.std`` is not None) and
    ``/metrics/position/<axis>`` (one series per rollout), all over ``time`` = ``res.t`` seconds; a
    conditioned rollout's goals at ``/world/rollouts/<b>/goal`` and via-points at ``/world/via/<i>``
    (static axes and a labelled point at the pose; ``res.goal_quat``, ``res.goal_position``, ``res.via``).
    Blueprint: the 3D view beside tabs of std and position time series.
    """
    _check_up(up)
    rr, rrb = _rerun()
    t = np.asarray(res.t, dtype=np.float64)
    quat = np.asarray(res.quat, dtype=np.float64)
    pos = np.asarray(res.position, dtype=np.float64)
    B = quat.shape[0]
    if quat.shape[:2] != (B, len(t)) or pos.shape != (B, len(t), 3):
        raise ValueError(f"record_rollout: quat {quat.shape} and position {pos.shape} do not match t ({len(t)},)")
    names = [str(b) for b in range(B)]
    colors = _colors(B)
    outputs = [str(o) for o in res.output_names]
    has_std = res.std is not None
    has_samples = res.sample_position is not None
    size = _scene_size(pos)

    tabs = []
    if has_std:
        tabs.append(_views_per_key(rrb, "/metrics/std", outputs, [f"std {o}" for o in outputs], name="predictive std"))
    pos_views = rrb.Vertical(*[rrb.TimeSeriesView(origin=f"/metrics/position/{a}", name=f"{a} [m]") for a in _AXES],
                             name="position")
    tabs.append(pos_views)
    blueprint = rrb.Blueprint(
        rrb.Horizontal(rrb.Spatial3DView(origin="/world", name="rollouts"), rrb.Tabs(*tabs), column_shares=[3, 2]),
        *_panels(rrb, "time"),
    )
    with _recording(path, blueprint, "rbgp rollout") as rec:
        _log_world(rec, up)
        rec.send_property("rbgp", rr.AnyValues(kind="rollout", trajectories=int(B), steps=int(len(t) - 1),
                                               samples_per_start=int(res.sample_position.shape[1]) if has_samples else 0))
        index = rr.TimeColumn("time", duration=t)
        # each trajectory up to its own length (res.lengths, rollouts of different durations)
        lengths = [len(t) if getattr(res, "lengths", None) is None else int(res.lengths[b]) for b in range(B)]
        after = np.arange(len(t))[None, :] >= np.asarray(lengths)[:, None]  # (B, S+1): past a trajectory's end
        for b in range(B):
            base, n = f"/world/rollouts/{b}", lengths[b]
            rec.log(f"{base}/path", rr.LineStrips3D([pos[b, :n]], colors=[colors[b]], radii=_LINE, labels=[names[b]]),
                    static=True)
            _log_body(rec, f"{base}/body", rr.TimeColumn("time", duration=t[:n]), quat[b, :n], pos[b, :n], 0.04 * size)
            if has_samples:
                rec.log(f"{base}/samples",
                        rr.LineStrips3D(np.asarray(res.sample_position[b][:, :n], dtype=np.float64),
                                        colors=[_SAMPLE_RGBA], radii=_THIN), static=True)
        _log_aims(rec, res, colors, 0.04 * size)
        pos = np.where(after[..., None], np.nan, pos)  # the series end where their trajectory ends
        if has_std:
            std = np.where(after[..., None], np.nan, np.asarray(res.std, dtype=np.float64))  # (B, S+1, L)
            for j, out in enumerate(outputs):
                _log_series(rec, f"/metrics/std/{_part(out)}", index, std[:, :, j].T, names, colors)
        for j, axis in enumerate(_AXES):
            _log_series(rec, f"/metrics/position/{axis}", index, pos[:, :, j].T, names, colors)


def _log_aims(rec, res, colors, axis_length: float) -> None:
    """A conditioned rollout's goals (``/world/rollouts/<b>/goal``: the pose's axes and a labelled
    point, in its trajectory's colour) and via-points (``/world/via/<i>``, labelled "via T s"), static."""
    import rerun as rr

    gq, gp = getattr(res, "goal_quat", None), getattr(res, "goal_position", None)
    if gq is not None and gp is not None:
        for b in range(len(gp)):
            entity = f"/world/rollouts/{b}/goal"
            rec.log(entity, rr.Transform3D(translation=np.asarray(gp[b], np.float64),
                                           quaternion=rr.Quaternion(xyzw=np.asarray(gq[b], np.float64))), static=True)
            rec.log(entity, rr.TransformAxes3D(axis_length), static=True)
            rec.log(entity, rr.Points3D([[0.0, 0.0, 0.0]], colors=[colors[b]], radii=-6.0, labels=["goal"]), static=True)
    for i, (tv, qv, pv) in enumerate(getattr(res, "via", ()) or ()):
        entity = f"/world/via/{i}"
        rec.log(entity, rr.Transform3D(translation=np.asarray(pv, np.float64),
                                       quaternion=rr.Quaternion(xyzw=np.asarray(qv, np.float64))), static=True)
        rec.log(entity, rr.TransformAxes3D(axis_length), static=True)
        rec.log(entity, rr.Points3D([[0.0, 0.0, 0.0]], colors=[[255, 255, 255]], radii=-6.0, labels=[f"via {tv:g} s"]),
                static=True)


# ------------------------------------------------------------------------------------------ evaluation
def record_evaluation(path, result, generated: Sequence[Trajectory], demos: Sequence[Trajectory],
                      up: str = "z") -> None:
    """Write a recording of demonstrations vs generated trajectories and the per-step scores.

    Parameters
    ----------
    path : str or Path
        The ``.rrd`` to write (atomically).
    result : EvaluationResult
        From :func:`rbgp_cli.evaluation.evaluate` on ``generated`` and ``demos`` (T steps,
        reference (T, 4), per-step D_B and feature means/stds (T, 6)).
    generated, demos : sequence of Trajectory
        Seconds, metres, quaternions x, y, z, w.
    up : {"z", "y"}
        World up axis.

    Contents: ``/world/demos/<name>/path`` (warm colours) and ``/world/generated/<name>/path``
    (grey-blue) as static strips; ``.../body``: each trajectory resampled to the T steps
    (:func:`rbgp_cli.evaluation.resample_all`) as a pose over ``step``, so both sets move in phase;
    ``/metrics/bhattacharyya`` (series total, rotation, translation) and ``/metrics/features/<dim>``
    (series demonstrations mean, −2σ, +2σ and generated mean, −2σ, +2σ) over ``step``
    (normalised time s = step / (T − 1)). Blueprint: the 3D view beside D_B and a 2 × 3 grid of
    feature views.
    """
    from rbgp_cli.evaluation import resample_all

    _check_up(up)
    generated, demos = list(generated), list(demos)
    if not generated or not demos:
        raise InputError("record_evaluation needs generated trajectories and demonstrations")
    rr, rrb = _rerun()
    T = int(result.steps)
    q_d, p_d = resample_all(demos, T)
    q_g, p_g = resample_all(generated, T)
    size = _scene_size(*[tr.position for tr in demos + generated])
    titles = [f"{d} [rad]" for d in FEATURE_NAMES[:3]] + [f"{d} [m]" for d in FEATURE_NAMES[3:]]
    blueprint = rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(origin="/world", name="demonstrations (warm) vs generated (grey-blue)"),
            rrb.Vertical(
                rrb.TimeSeriesView(origin="/metrics/bhattacharyya", name="Bhattacharyya distance per step"),
                _views_per_key(rrb, "/metrics/features", FEATURE_NAMES, titles),
                row_shares=[1, 2],
            ),
            column_shares=[1, 1],
        ),
        *_panels(rrb, "step"),
    )
    with _recording(path, blueprint, "rbgp evaluation") as rec:
        _log_world(rec, up)
        rec.send_property("rbgp", rr.AnyValues(
            kind="evaluation", steps=T, n_generated=int(result.n_generated), n_demos=int(result.n_demos),
            covariance=str(result.covariance), ridge=float(result.ridge), bhattacharyya_mean=float(result.mean),
            bhattacharyya_rotation=float(result.rotation), bhattacharyya_translation=float(result.translation)))
        index = rr.TimeColumn("step", sequence=np.arange(T))
        groups = (("demos", demos, q_d, p_d, _colors(len(demos), _WARM), "demo_"),
                  ("generated", generated, q_g, p_g, np.tile(_GENERATED, (len(generated), 1)), "generated_"))
        for group, trajs, qs, ps, colors, prefix in groups:
            for tr, name, q, p, color in zip(trajs, _names(trajs, prefix), qs, ps, colors):
                base = f"/world/{group}/{_part(name)}"
                rec.log(f"{base}/path", rr.LineStrips3D([tr.position], colors=[color], radii=_LINE, labels=[name]),
                        static=True)
                _log_body(rec, f"{base}/body", index, q, p, 0.03 * size)
        _log_series(rec, "/metrics/bhattacharyya", index,
                    np.stack([result.per_step, result.per_step_rotation, result.per_step_translation], axis=1),
                    ["total", "rotation", "translation"], [[0, 0, 0], [214, 39, 40], [31, 119, 180]], [2.0, 1.5, 1.5])
        for j, dim in enumerate(FEATURE_NAMES):
            md, sd = result.demo_mean[:, j], result.demo_std[:, j]
            mg, sg = result.gen_mean[:, j], result.gen_std[:, j]
            _log_series(
                rec, f"/metrics/features/{dim}", index,
                np.stack([md, md - 2 * sd, md + 2 * sd, mg, mg - 2 * sg, mg + 2 * sg], axis=1),
                ["demonstrations mean", "demonstrations −2σ", "demonstrations +2σ",
                 "generated mean", "generated −2σ", "generated +2σ"],
                [_DEMO_MEAN, [240, 140, 140], [240, 140, 140], _GEN_MEAN, [150, 150, 150], [150, 150, 150]],
                [2.0, 1.0, 1.0, 2.0, 1.0, 1.0],
            )
