"""Static figures (PNG) of an evaluation, like the paper's Fig. 4 and 5.

matplotlib is imported on first use only (the optional extra ``rbgp-cli[plot]``). The figure is built
as a :class:`matplotlib.figure.Figure` with its own Agg canvas, not through ``pyplot``: nothing
global (backend, open figures) changes in the calling process, and no display is needed.

Conventions: rotations are drawn as the features of the evaluation (docs/method.md §9), the rotation vector
``log(R̄_sᵀ R)`` in the tangent space at the demonstrations' mean rotation R̄_s of each step
(``result.reference``), so a rotation through θ = π does not jump; translations as they are, metres;
the horizontal axis is normalised time s ∈ [0, 1] (no unit). Every curve and band is drawn on the
series the score uses: each trajectory resampled to ``result.steps`` steps
(:func:`rbgp_cli.evaluation.resample_all`) and mapped to those features
(:func:`rbgp_cli.evaluation.tangent_features`); the bands are the per-step sample mean ± 2 sample
standard deviations (ddof = 1) that the score's Gaussians are fitted with.

Large sets stay readable: at most :data:`MAX_LINES` individual lines per set are drawn (evenly
chosen, lighter, the counts in the legend) over the sets' ±2σ bands, and each feature axis spans the
demonstrations and the bulk of the generated trajectories (:func:`feature_axis_limits`), so one
divergent rollout is clipped (and counted in the panel) instead of squashing the axis.
"""

from __future__ import annotations

import re
import textwrap
from collections.abc import Sequence

import numpy as np

from rbgp_cli.dynamics.trajectory import Trajectory
from rbgp_cli.errors import InputError
from rbgp_cli.io.atomic import atomic_path

__all__ = ["plot_evaluation", "plot_rollout", "rollout_features", "distance_axis_top", "feature_axis_limits", "is_monte_carlo_sample", "FIGSIZE_IN",
           "DPI", "MAX_LINES", "CLIP_FACTOR", "NEAR_ZERO", "AXIS_MARGIN", "BULK_WIDTH", "TIME_LABEL"]

#: Figure size in inches and resolution: 12 × 10 in at 100 dpi = 1200 × 1000 pixels.
FIGSIZE_IN = (12.0, 10.0)
DPI = 100
#: At most this many individual trajectories of each set (demonstrations, generated, compare) are
#: drawn per panel, evenly chosen; above it they are drawn lighter and the legend gives the counts.
MAX_LINES = 20
#: The distance panels' axes are linear from 0; a few steps more than this many times the 90th
#: percentile of the distances are clipped (and their largest value written in the panel), so the
#: curve stays readable.
CLIP_FACTOR = 10.0
#: A distance curve whose largest value is below this fraction of its panel's axis (another set's
#: curve sets the scale) gets its largest value written in the panel.
NEAR_ZERO = 0.03
#: Each feature axis is widened by this fraction of its span on both sides.
AXIS_MARGIN = 0.08
#: The bulk of a generated set, per step: median ± this many robust standard deviations
#: (1.4826 × the median absolute deviation), which one divergent trajectory barely moves.
BULK_WIDTH = 4.0
#: The horizontal axis label: normalised time has no unit.
TIME_LABEL = "normalised time (0–1)"

#: Names of Monte Carlo rollouts as ``rbgp rollout --samples K`` writes them (``<start>.s<k>``), also
#: after reading them back from a CSV (``file#<start>.s<k>``).
_SAMPLE_NAME = re.compile(r"(?:^|[#/\\:])\d+\.s\d+$")

_DIMS = (
    ("rotation $r_x$ (tangent space at the demonstrations' mean rotation)", "$r_x$ [rad]"),
    ("rotation $r_y$ (tangent space at the demonstrations' mean rotation)", "$r_y$ [rad]"),
    ("rotation $r_z$ (tangent space at the demonstrations' mean rotation)", "$r_z$ [rad]"),
    ("translation $x$", "$x$ [m]"),
    ("translation $y$", "$y$ [m]"),
    ("translation $z$", "$z$ [m]"),
)

# colours: demonstrations red, generated (mean rollouts) near-black, their Monte Carlo samples
# purple, the compare set blue
_DEMO, _GEN, _SAMPLES, _CMP = "red", "0.15", "tab:purple", "tab:blue"


def _matplotlib():
    """Import the parts of matplotlib used here; InputError if it is not installed."""
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError:
        raise InputError("plot needs matplotlib", hint="pip install 'rbgp-cli[plot]'", param="plot") from None
    return Figure, FigureCanvasAgg


#: The figure formats a plot's file suffix chooses (matplotlib's Agg and vector back ends, no other package).
FIGURE_FORMATS = ("png", "pdf", "svg")


def figure_format(path) -> str:
    """The format of a figure written to ``path``, from its suffix (none: PNG); an InputError for another suffix,
    before any work (a .pdf written as PNG data would open nowhere)."""
    import os

    ext = os.path.splitext(str(path))[1].lower().lstrip(".")
    if not ext:
        return "png"
    if ext not in FIGURE_FORMATS:
        raise InputError(f"a figure is written as {', '.join('.' + f for f in FIGURE_FORMATS)}, not .{ext}",
                         path=str(path), hint="name the figure FILE.png, FILE.pdf or FILE.svg", param="plot")
    return ext


def is_monte_carlo_sample(traj: Trajectory) -> bool:
    """True for a Monte Carlo rollout as ``rbgp rollout --samples`` names it (``3.s0``, ``file#3.s0``)."""
    return bool(_SAMPLE_NAME.search(traj.name or ""))


def distance_axis_top(values) -> tuple[float, bool]:
    """Upper limit of a linear Bhattacharyya axis (lower limit 0) and whether curves are clipped.

    1.3 × the largest finite distance (room for the legend), or, when that largest value exceeds
    ``CLIP_FACTOR`` × the 90th percentile (a few spikes), 1.3 × that bound. Never a log axis: a
    first step scoring ~1e-30 (identical starts) would make it span 30 decades and hide the curve.
    """
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    if not len(v):
        return 1.0, False
    top = float(v.max())
    bound = CLIP_FACTOR * float(np.percentile(v, 90))
    clipped = bound > 0 and top > bound
    return 1.3 * max(bound if clipped else top, 1e-12), clipped


def feature_axis_limits(demos, band_low, band_high, groups=()) -> tuple[float, float]:
    """Limits of one feature axis: the demonstrations and the bulk of each generated set, plus a margin.

    The range covers every demonstration (``demos``, shape (M_D, T)), their ±2σ band
    (``band_low``, ``band_high``, shape (T,)) and, for each generated set in ``groups`` (arrays
    (M, T)), its bulk per step, ``median ± BULK_WIDTH · 1.4826 · MAD`` (about ±4σ for Gaussian
    spread, moved little by a few divergent trajectories) but no further than the set's own extremes
    at that step; it is then widened by ``AXIS_MARGIN`` of
    its span on each side (at least 1e-3, a milliradian or millimetre, so a constant feature gets a
    visible axis). Trajectories beyond it are clipped by the axes, not allowed to stretch them.
    """
    parts = [np.ravel(demos), np.ravel(band_low), np.ravel(band_high)]
    for x in groups:
        x = np.asarray(x, dtype=np.float64)
        if x.size == 0:
            continue
        med = np.median(x, axis=0)  # (T,)
        wide = BULK_WIDTH * 1.4826 * np.median(np.abs(x - med), axis=0)
        parts += [np.maximum(med - wide, x.min(axis=0)), np.minimum(med + wide, x.max(axis=0))]
    v = np.concatenate(parts)
    v = v[np.isfinite(v)]
    if not len(v):
        return -1.0, 1.0
    lo, hi = float(v.min()), float(v.max())
    pad = max(AXIS_MARGIN * (hi - lo), 1e-3)
    return lo - pad, hi + pad


def _subset(n: int, k: int = MAX_LINES) -> np.ndarray:
    """At most ``k`` indices out of ``n``, evenly spread (all of them when n <= k)."""
    if n <= k:
        return np.arange(n)
    return np.unique(np.round(np.linspace(0, n - 1, k)).astype(int))


def _features(trajs, result) -> np.ndarray:
    """Tangent features (M, T, 6) of ``trajs`` resampled to the evaluation's T steps."""
    from rbgp_cli.evaluation import resample_all, tangent_features

    q, p = resample_all(trajs, int(result.steps))
    return tangent_features(q, p, result.reference)


def _band(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-step mean and standard deviation (T, 6) of features (M, T, 6), as the evaluation fits them."""
    from rbgp_cli.evaluation.bhattacharyya import _moments

    mu, cov = _moments(x)
    return mu, np.sqrt(np.diagonal(cov, axis1=-2, axis2=-1))


def _count_label(what: str, n: int) -> str:
    """Legend name of a set's individual lines: its size, and how many are drawn when it is thinned."""
    drawn = len(_subset(n))
    return f"{what} ({n})" if drawn == n else f"{what} ({drawn} of {n} drawn)"


class _Set:
    """One set of trajectories as drawn: features (M, T, 6), band (mean, std (T, 6)), style."""

    def __init__(self, key, label, x, mean, std, color, ls, lines=True):
        self.key, self.label, self.x, self.mean, self.std = key, label, x, mean, std
        self.color, self.ls, self.lines = color, ls, lines

    @property
    def n(self) -> int:
        return self.x.shape[0]


def _plot_sets(result, generated, demos, compare, gen_label, cmp_label):
    """The sets drawn (:class:`_Set`: demonstrations first, then the generated set, split into mean
    rollouts and Monte Carlo samples when it mixes both, and ``compare``) and the evaluation of
    ``compare`` against the same demonstrations (None without it)."""
    from rbgp_cli.evaluation import evaluate

    sets = [_Set("demonstrations", "demonstrations", _features(demos, result), result.demo_mean, result.demo_std,
                 _DEMO, "-")]
    x_g = _features(generated, result)  # (M_G, T, 6)
    is_sample = np.array([is_monte_carlo_sample(t) for t in generated])
    if is_sample.any() and not is_sample.all():
        n_s = int(is_sample.sum())
        sets.append(_Set("generated", f"{gen_label}: mean rollouts", x_g[~is_sample], *_band(x_g[~is_sample]),
                         _GEN, "--"))
        sets.append(_Set("samples", f"Monte Carlo samples ({n_s})", x_g[is_sample],
                         *_band(x_g[is_sample]), _SAMPLES, ":", lines=False))
    else:
        sets.append(_Set("generated", gen_label, x_g, result.gen_mean, result.gen_std, _GEN, "--"))
    res_c = None
    if compare:
        res_c = evaluate(compare, demos, length=int(result.steps), covariance=result.covariance, ridge=result.ridge,
                         sample_size="record")  # the main evaluation already said what it had to
        sets.append(_Set("compare", cmp_label, _features(compare, result), res_c.gen_mean, res_c.gen_std, _CMP, "-."))
    return sets, res_c


def _distance_row(fig, grid, s, result, res_c, gen_label, cmp_label) -> None:
    """The bottom row: the per-step distance, its rotation and its translation part, one panel each,
    ``result`` solid and ``res_c`` (the compare set's evaluation, or None) dash-dotted."""
    parts = (("per_step", "mean", f"Bhattacharyya distance per step ({result.covariance}, "
                                   f"{result.n_demos} demos)"),
             ("per_step_rotation", "rotation", "its rotation part"),
             ("per_step_translation", "translation", "its translation part"))
    for k, (series, mean, heading) in enumerate(parts):
        ax = fig.add_subplot(grid[3, 2 * k:2 * k + 2])
        curves = [(getattr(result, series), getattr(result, mean), gen_label, "-", "black")]
        if res_c is not None:
            curves.append((getattr(res_c, series), getattr(res_c, mean), cmp_label, "-.", _CMP))
        _distance_panel(ax, s, curves)
        ax.set_title(heading, fontsize=10)
        ax.set_xlabel(TIME_LABEL)
        if k == 0:
            ax.set_ylabel("$D_B$ [–]")


def _figure_title(title, result, res_c, gen_label, cmp_label, refusal) -> str:
    """The figure's title: ``title``, or the mean distances (without a score: the set against the
    demonstrations); with the ``refusal`` of a score, why there is none."""
    scored = refusal is None
    if title is None:
        if scored:
            title = f"{gen_label}: mean Bhattacharyya distance {result.mean:.2f}"
            if res_c is not None:
                title += f"   {cmp_label}: {res_c.mean:.2f}"
        else:
            title = f"{gen_label} against {result.n_demos} demonstration{'s' if result.n_demos != 1 else ''}"
    if not scored:
        why = refusal.split(":")[0] + (";" + refusal.rsplit(";", 1)[1] if ";" in refusal else "")
        title += "\n" + textwrap.fill(f"no score: {why}", 140)
    return title


def plot_evaluation(path, result, generated: Sequence[Trajectory], demos: Sequence[Trajectory],
                    compare: Sequence[Trajectory] | None = None, labels=("generated", "compare"),
                    title: str | None = None):
    """Draw demonstrations, generated trajectories (and a second set) per dimension with their ±2σ
    bands, and the per-step Bhattacharyya distance; save a 1200 × 1000 px PNG atomically.

    Six feature panels over normalised time s ∈ [0, 1]: rotation r_x, r_y, r_z (rad, tangent space at
    the demonstrations' per-step mean rotation) in the left column, translation x, y, z (m) in the
    right one. In each: the demonstrations' band, per-step mean ± 2σ (``result.demo_mean``,
    ``result.demo_std``), filled red, with its mean as a solid red line; the generated set's band,
    light grey outlined dashed, with its mean dashed black (``result.gen_mean``, ``result.gen_std``);
    ``compare`` likewise in blue, dash-dotted. When ``generated`` holds Monte Carlo rollouts (names ``<start>.s<k>``, from
    ``rbgp rollout --samples``), the mean rollouts and the samples get separate bands (samples
    purple) and only the mean rollouts are drawn as lines; the score still uses them all. Individual
    lines: at most :data:`MAX_LINES` per set, evenly chosen, thin and light. The axis covers the
    demonstrations and the bulk of each generated set (:func:`feature_axis_limits`); the panel says
    how many generated trajectories leave it.

    Bottom row: the per-step distance, total, rotation part and translation part in separate panels
    with their own linear axes from 0 (so a part near zero is still readable), ``generated`` solid
    and ``compare`` (evaluated against the same demonstrations with the same length, covariance
    and ridge) dash-dotted. When ``result`` cannot be a score (one demonstration: the refusal of
    :func:`rbgp_cli.evaluation.check_sample_sizes`, recorded with ``evaluate(...,
    sample_size="record")``), the bottom row is left out and the figure says why.

    Parameters
    ----------
    path : str or Path
        PNG to write (atomically).
    result : EvaluationResult
        :func:`rbgp_cli.evaluation.evaluate` of ``generated`` against ``demos``.
    generated, demos : sequence of Trajectory
        The trajectories ``result`` was computed from (seconds, metres, quaternions x, y, z, w).
    compare : sequence of Trajectory, optional
        A second generated set (e.g. the Euler GP's rollouts), drawn in another colour.
    labels : (str, str)
        Legend names of ``generated`` and ``compare``.
    title : str, optional
        Figure title (default: the mean Bhattacharyya distances).

    Returns
    -------
    matplotlib.figure.Figure
        The figure, for callers that want to inspect or re-save it: 6 feature axes then 3 distance
        axes (6 axes without a score). Bands are ``PolyCollection`` objects with the gid
        ``band:<set>`` and set means lines with the gid ``mean:<set>``, individual lines
        ``line:<set>``, where ``<set>`` is ``demonstrations``, ``generated``, ``samples`` or ``compare``.
    """
    from rbgp_cli.evaluation import check_sample_sizes

    Figure, FigureCanvasAgg = _matplotlib()
    generated, demos = list(generated), list(demos)
    compare = list(compare) if compare else None
    if len(generated) != result.n_generated or len(demos) != result.n_demos:
        raise InputError(
            f"the evaluation was computed from {result.n_generated} generated trajectories and {result.n_demos} "
            f"demonstrations, but {len(generated)} and {len(demos)} were given to plot")
    gen_label, cmp_label = (list(labels) + ["compare"])[:2]
    refusal = check_sample_sizes(result.n_generated, result.n_demos, result.covariance, result.ridge).refusal

    s = np.asarray(result.s)
    sets, res_c = _plot_sets(result, generated, demos, compare, gen_label, cmp_label)
    demo_set, others = sets[0], sets[1:]

    fig = Figure(figsize=FIGSIZE_IN, dpi=DPI, layout="constrained")
    FigureCanvasAgg(fig)
    scored = refusal is None
    grid = fig.add_gridspec(4 if scored else 3, 6)  # 6 columns: 2 × 3 feature panels, 3 × 2 distance panels
    handles: dict = {}
    for j, (name, ylabel) in enumerate(_DIMS):
        ax = fig.add_subplot(grid[j % 3, 3 * (j // 3):3 * (j // 3) + 3])
        _feature_panel(ax, j, s, demo_set, others, handles)
        ax.set_title(name, fontsize=10)
        ax.set_ylabel(ylabel)
        if j % 3 == 2:
            ax.set_xlabel(TIME_LABEL)
        else:
            ax.tick_params(labelbottom=False)
    order = [k for st in sets for k in (f"line:{st.key}", f"band:{st.key}") if k in handles]
    fig.legend([handles[k][0] for k in order], [handles[k][1] for k in order], loc="outside lower center",
               ncols=4 if len(order) <= 4 else 3, fontsize=9, frameon=False)

    if scored:
        _distance_row(fig, grid, s, result, res_c, gen_label, cmp_label)

    title = _figure_title(title, result, res_c, gen_label, cmp_label, refusal)
    fig.suptitle(title, fontsize=12)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format=figure_format(path), dpi=DPI)
    return fig


def _feature_panel(ax, j, s, demo_set, others, handles) -> None:
    """One feature dimension j: bands (beneath), thinned individual lines, the sets' means, clipped axis."""
    from matplotlib.colors import to_rgba
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    for st in [demo_set] + others:  # bands first, beneath every line
        if st.n < 2:  # one trajectory has no spread: its mean is the line itself
            continue
        lo, hi = st.mean[:, j] - 2.0 * st.std[:, j], st.mean[:, j] + 2.0 * st.std[:, j]
        alpha = 0.2 if st.key == "demonstrations" else 0.07
        ax.fill_between(s, lo, hi, color=st.color, alpha=alpha, lw=0, gid=f"band:{st.key}")
        if st.key != "demonstrations":  # the reference band is filled, the others also outlined
            for edge in (lo, hi):
                ax.plot(s, edge, ls=st.ls, lw=0.9, color=st.color, alpha=0.8, gid=f"edge:{st.key}")
        handles.setdefault(f"band:{st.key}", (
            (Patch(facecolor=to_rgba(st.color, alpha + 0.1), lw=0.9, linestyle=st.ls,
                   edgecolor="none" if st.key == "demonstrations" else st.color),
             Line2D([], [], color=st.color, ls=st.ls, lw=1.6)),
            f"{st.label}: mean ± 2σ"))
    for st in others + [demo_set]:  # the demonstrations' lines on top, so the reference stays visible
        if not st.lines:
            continue
        idx = _subset(st.n)
        thinned = len(idx) < st.n
        width = 0.6 if thinned else 0.9
        alpha = 0.35 if thinned else 0.6
        ls = "-" if st.key == "demonstrations" else st.ls
        for i in idx:
            ax.plot(s, st.x[i, :, j], ls=ls, lw=width, color=st.color, alpha=alpha, gid=f"line:{st.key}")
        handles.setdefault(f"line:{st.key}", (Line2D([], [], color=st.color, ls=ls, lw=width, alpha=alpha),
                                              _count_label(st.label, st.n)))
    for st in others + [demo_set]:
        lw = 2.2 if st.key == "demonstrations" else 1.6
        ax.plot(s, st.mean[:, j], ls=st.ls, lw=lw, color=st.color, gid=f"mean:{st.key}")

    lo, hi = feature_axis_limits(demo_set.x[:, :, j], demo_set.mean[:, j] - 2 * demo_set.std[:, j],
                                 demo_set.mean[:, j] + 2 * demo_set.std[:, j], [st.x[:, :, j] for st in others])
    ax.set_ylim(lo, hi)
    ax.set_xlim(0.0, 1.0)
    ax.grid(True, lw=0.3, alpha=0.5)
    out = []
    for st in others:
        v = st.x[:, :, j]
        k = int(np.sum(np.any((v < lo) | (v > hi), axis=1)))
        if k:
            out.append(f"{k} of {st.n} {st.label}")
    if out:
        ax.text(0.995, 0.02, "beyond this axis (clipped): " + ", ".join(out), transform=ax.transAxes, ha="right",
                va="bottom", fontsize=7.5, gid="clip-note",
                bbox=dict(boxstyle="round,pad=0.2", facecolor="white", edgecolor="0.6", alpha=0.85))


def _distance_panel(ax, s, curves) -> None:
    """Per-step distances ``curves`` [(series (T,), mean, label, linestyle, colour)] on a linear axis from 0."""
    finite = np.concatenate([np.asarray(c[0])[np.isfinite(c[0])] for c in curves])
    top, clipped = distance_axis_top(finite)
    for series, mean, label, ls, color in curves:
        text = f"{label} (mean {mean:.3g})"
        v = np.asarray(series)[np.isfinite(series)]
        if len(v) and float(v.max()) < NEAR_ZERO * top:  # flattened against 0 by a larger curve: say its size
            text = f"{label} (mean {mean:.3g}, at most {float(v.max()):.2g}: flat at this scale)"
        ax.plot(s, series, ls=ls, lw=1.8, color=color, label=text)
    ax.set_ylim(0.0, top)
    if clipped:
        ax.text(0.99, 0.97, f"clipped: largest $D_B$ = {float(finite.max()):.3g}", transform=ax.transAxes,
                ha="right", va="top", fontsize=8)
    ax.set_xlim(0.0, 1.0)
    ax.grid(True, lw=0.3, alpha=0.5)
    ax.legend(fontsize=7.5, loc="upper left")


# ------------------------------------------------------------------------------------------ rollouts

#: The quantiles of a rollout's Monte Carlo samples drawn as its band: the 90 % region.
ROLLOUT_BAND = (0.05, 0.95)

_ROLLOUT_DIMS = (
    ("rotation $r_x$ (relative to the first rollout's start)", "$r_x$ [rad]"),
    ("rotation $r_y$ (relative to the first rollout's start)", "$r_y$ [rad]"),
    ("rotation $r_z$ (relative to the first rollout's start)", "$r_z$ [rad]"),
    ("translation $x$", "$x$ [m]"),
    ("translation $y$", "$y$ [m]"),
    ("translation $z$", "$z$ [m]"),
)


def rollout_features(quat, position, quat_ref) -> np.ndarray:
    """Poses as the six drawn features: ``(log(R_refᵀ R), p)``, shape (..., 6).

    ``quat`` (..., 4) x, y, z, w and ``position`` (..., 3) m; ``quat_ref`` (4,) the reference rotation
    R_ref (the first rollout's start). The rotation part is the rotation vector of R_refᵀ R in the
    reference's frame (rad), continuous as long as the motion stays within π of the reference.
    """
    from rbgp_cli.geometry.so3 import log_quat, quat_conjugate, quat_multiply

    rel = quat_multiply(quat_conjugate(np.asarray(quat_ref, np.float64)), np.asarray(quat, np.float64))
    return np.concatenate([log_quat(rel), np.asarray(position, np.float64)], axis=-1)


def plot_rollout(path, res, title: str | None = None):
    """Draw rolled-out motions over time, their samples' 90 % bands, goals and via-points; save a PNG.

    Six panels over time t (s) from the start: rotation r_x, r_y, r_z (rad, :func:`rollout_features`:
    ``log(R_refᵀ R)`` with R_ref the first mean rollout's start rotation) in the left column,
    translation x, y, z (m) in the right one. Each mean rollout b (at most :data:`MAX_LINES`, evenly
    chosen) is a line up to its own length (``res.length(b)``), its band filled in its colour: the
    next motion's 90 % region rbgp computed (``res.band_position`` (B, S+1, 3) m, per axis about the
    mean; ``res.band_rotation`` (B, S+1, 3, 3), the region {e : eᵀ M⁻¹ e ≤ 1} of e = log(R R_meanᵀ),
    drawn per axis of the reference frame as ± sqrt((R_refᵀ M R_ref)_ii), to first order in e; the band
    ``rbgp crossval`` scores), or without one, the per-time quantiles :data:`ROLLOUT_BAND` of its
    Monte Carlo samples (``res.sample_quat`` (B, K, S+1, 4), K ≥ 2). A conditioned
    rollout's goal (``res.goal_quat`` (B, 4), ``res.goal_position`` (B, 3)) is a cross at the
    rollout's end time; via-points (``res.via``: [(T s, quat (4,), position (3,))]) are diamonds at T.
    Samples past the demonstrations' envelope (``res.outside``) are marked with small circles.

    Returns the :class:`matplotlib.figure.Figure` (6 axes). Gids: ``mean:<b>``, ``band:<b>``,
    ``goal:<b>``, ``via:<i>``, ``outside:<b>``.
    """
    Figure, FigureCanvasAgg = _matplotlib()
    t = np.asarray(res.t, np.float64)
    quat, pos = np.asarray(res.quat, np.float64), np.asarray(res.position, np.float64)
    B = quat.shape[0]
    shown = _subset(B)
    lengths = [res.length(b) for b in range(B)]
    ref = quat[0, 0]
    feats = rollout_features(quat, pos, ref)  # (B, S+1, 6)
    has_samples = res.sample_quat is not None and res.sample_quat.shape[1] >= 2
    band_p, band_r = getattr(res, "band_position", None), getattr(res, "band_rotation", None)
    computed = band_p is not None and band_r is not None
    if computed:  # the next motion's 90 % region rbgp computed: per axis, about the mean
        from rbgp_cli.geometry.so3 import matrix_from_quat

        R_ref = matrix_from_quat(ref)
        M = np.einsum("ji,btjk,kl->btil", R_ref, np.asarray(band_r, np.float64), R_ref)  # R_refᵀ M R_ref
        half = np.concatenate([np.sqrt(np.clip(np.diagonal(M, axis1=-2, axis2=-1), 0.0, None)),
                               np.asarray(band_p, np.float64)], axis=-1)  # (B, S+1, 6)
        lo, hi = feats - half, feats + half
    elif has_samples:
        sfeat = rollout_features(res.sample_quat, res.sample_position, ref)  # (B, K, S+1, 6)
        lo, hi = np.quantile(sfeat, ROLLOUT_BAND, axis=1)  # (B, S+1, 6) each
    gq, gp = getattr(res, "goal_quat", None), getattr(res, "goal_position", None)
    goal = rollout_features(gq, gp, ref) if gq is not None and gp is not None else None  # (B, 6)
    via = list(getattr(res, "via", ()) or ())
    via_feat = [rollout_features(q, p, ref) for _, q, p in via]
    outside = getattr(res, "outside", None)

    from matplotlib import colormaps

    cmap = colormaps["tab10"]
    fig = Figure(figsize=(12.0, 8.0), dpi=DPI, layout="constrained")
    FigureCanvasAgg(fig)
    grid = fig.add_gridspec(3, 2)
    for j, (name, ylabel) in enumerate(_ROLLOUT_DIMS):
        ax = fig.add_subplot(grid[j % 3, j // 3])
        for i, b in enumerate(shown):
            n, color = lengths[b], cmap(i % 10)
            if computed or has_samples:
                ax.fill_between(t[:n], lo[b, :n, j], hi[b, :n, j], color=color, alpha=0.15, lw=0, gid=f"band:{b}")
            ax.plot(t[:n], feats[b, :n, j], color=color, lw=1.4, gid=f"mean:{b}",
                    label=f"rollout {b}" if j == 0 and i < 10 else None)
            if outside is not None and np.any(outside[b, :n]):
                k = np.flatnonzero(outside[b, :n])
                ax.plot(t[k], feats[b, k, j], "o", ms=2.5, mfc="none", color=color, gid=f"outside:{b}")
            if goal is not None:
                ax.plot([t[n - 1]], [goal[b, j]], "X", ms=8, color=color, mec="black", mew=0.6, gid=f"goal:{b}")
        for i, ((tv, _, _), f) in enumerate(zip(via, via_feat)):
            ax.plot([tv], [f[j]], "D", ms=6, color="white", mec="black", mew=1.0, gid=f"via:{i}")
        ax.set_title(name, fontsize=10)
        ax.set_ylabel(ylabel)
        ax.set_xlim(0.0, float(t[max(lengths) - 1]) if len(t) > 1 else 1.0)
        ax.grid(True, lw=0.3, alpha=0.5)
        if j % 3 == 2:
            ax.set_xlabel("time from the start [s]")
        else:
            ax.tick_params(labelbottom=False)
    parts = [f"{B} rollout{'s' if B != 1 else ''}" + (f" ({len(shown)} drawn)" if len(shown) < B else "")]
    if computed:
        parts.append("bands: the next motion's 90 % region")
    elif has_samples:
        parts.append(f"bands: 90 % of {res.sample_quat.shape[1]} samples each")
    if goal is not None:
        parts.append("goals: crosses")
    if via:
        parts.append(f"{len(via)} via-point{'s' if len(via) != 1 else ''}: diamonds")
    if outside is not None and np.any(outside):
        parts.append("circles: outside the demonstrations")
    fig.suptitle(title or "; ".join(parts), fontsize=12)
    if B > 1:
        fig.axes[0].legend(fontsize=7.5, loc="best")
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format=figure_format(path), dpi=DPI)
    return fig
