"""Static figures (PNG) of an evaluation, like the paper's Fig. 4 and 5.

matplotlib is imported on first use only (the optional extra ``rbgp-cli[plot]``). The figure is built
as a :class:`matplotlib.figure.Figure` with its own Agg canvas, not through ``pyplot``: nothing
global (backend, open figures) changes in the calling process, and no display is needed.

Conventions: rotations are drawn as the features of the evaluation (MATH.md §9), the rotation vector
``log(R̄_sᵀ R)`` in the tangent space at the demonstrations' mean rotation R̄_s of each step
(``result.reference``), so a rotation through θ = π does not jump; translations as they are, metres;
the horizontal axis is normalised time s ∈ [0, 1].
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from rbgp_cli.dynamics.trajectory import Trajectory
from rbgp_cli.errors import InputError
from rbgp_cli.io.atomic import atomic_path

__all__ = ["plot_evaluation", "distance_axis_top", "FIGSIZE_IN", "DPI", "MAX_LINES", "CLIP_FACTOR"]

#: Figure size in inches and resolution: 12 × 10 in at 100 dpi = 1200 × 1000 pixels.
FIGSIZE_IN = (12.0, 10.0)
DPI = 100
#: At most this many generated (and compare) trajectories are drawn per panel (evenly chosen).
MAX_LINES = 20
#: The distance panel's axis is linear from 0; a few steps more than this many times the 90th
#: percentile of the distances are clipped (and their largest value written in the panel), so the
#: curve stays readable.
CLIP_FACTOR = 10.0

_DIMS = (
    ("rotation $r_x$ (tangent space at the demonstrations' mean rotation)", "$r_x$ [rad]"),
    ("rotation $r_y$ (tangent space at the demonstrations' mean rotation)", "$r_y$ [rad]"),
    ("rotation $r_z$ (tangent space at the demonstrations' mean rotation)", "$r_z$ [rad]"),
    ("translation $x$", "$x$ [m]"),
    ("translation $y$", "$y$ [m]"),
    ("translation $z$", "$z$ [m]"),
)


def _matplotlib():
    """Import the parts of matplotlib used here; InputError if it is not installed."""
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError:
        raise InputError("--plot needs matplotlib", hint="pip install 'rbgp-cli[plot]'") from None
    return Figure, FigureCanvasAgg


def distance_axis_top(values) -> tuple[float, bool]:
    """Upper limit of the linear Bhattacharyya axis (lower limit 0) and whether curves are clipped.

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


def plot_evaluation(path, result, generated: Sequence[Trajectory], demos: Sequence[Trajectory],
                    compare: Sequence[Trajectory] | None = None, labels=("generated", "compare"),
                    title: str | None = None):
    """Draw demonstrations, generated trajectories (and a second set) per dimension, and the per-step
    Bhattacharyya distance; save a 1200 × 1000 px PNG atomically.

    Seven panels over normalised time s: rotation r_x, r_y, r_z (rad, tangent space at the
    demonstrations' per-step mean rotation) in the left column, translation x, y, z (m) in the
    right column, and across the bottom the per-step Bhattacharyya distance (total, rotation,
    translation) of ``generated``, plus the total of ``compare`` (evaluated against the same
    demonstrations with the same length, covariance and ridge) when given. Demonstrations are thin
    dotted coloured lines and their mean a solid red one; ``generated`` dashed black, ``compare``
    blue dash-dotted (at most :data:`MAX_LINES` of each, evenly chosen).

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
        The figure (7 axes), for callers that want to inspect or re-save it.
    """
    from rbgp_cli.evaluation import evaluate

    Figure, FigureCanvasAgg = _matplotlib()
    generated, demos = list(generated), list(demos)
    compare = list(compare) if compare else None
    if len(generated) != result.n_generated or len(demos) != result.n_demos:
        raise InputError(
            f"the evaluation was computed from {result.n_generated} generated trajectories and {result.n_demos} "
            f"demonstrations, but {len(generated)} and {len(demos)} were given to plot")
    gen_label, cmp_label = (list(labels) + ["compare"])[:2]

    s = np.asarray(result.s)
    x_d = _features(demos, result)  # (M_D, T, 6)
    x_g = _features(generated, result)  # (M_G, T, 6)
    x_c = _features(compare, result) if compare else None
    res_c = None
    if compare:
        res_c = evaluate(compare, demos, length=int(result.steps), covariance=result.covariance, ridge=result.ridge,
                         sample_size="record")  # the main evaluation already said what it had to

    fig = Figure(figsize=FIGSIZE_IN, dpi=DPI, layout="constrained")
    FigureCanvasAgg(fig)
    grid = fig.add_gridspec(4, 2, height_ratios=[1, 1, 1, 1.1])
    demo_colors = _demo_colors(len(demos))
    axes = []
    for j, (name, ylabel) in enumerate(_DIMS):
        ax = fig.add_subplot(grid[j % 3, j // 3])
        axes.append(ax)
        if x_c is not None:
            for n, i in enumerate(_subset(len(compare))):
                ax.plot(s, x_c[i, :, j], ls="-.", lw=0.8, color="tab:blue", alpha=0.75,
                        label=cmp_label if n == 0 else None)
        for n, i in enumerate(_subset(len(generated))):
            ax.plot(s, x_g[i, :, j], ls="--", lw=0.8, color="0.15", alpha=0.7, label=gen_label if n == 0 else None)
        for m in range(len(demos)):  # on top, so the reference stays visible
            ax.plot(s, x_d[m, :, j], ls=":", lw=1.3, color=demo_colors[m],
                    label="demonstrations" if m == 0 else None)
        ax.plot(s, result.demo_mean[:, j], ls="-", lw=2.2, color="red", label="demonstrations' mean")
        ax.set_title(name, fontsize=10)
        ax.set_ylabel(ylabel)
        ax.grid(True, lw=0.3, alpha=0.5)
        ax.set_xlim(0.0, 1.0)
        if j % 3 == 2:
            ax.set_xlabel("normalised time s")
        else:
            ax.tick_params(labelbottom=False)
    handles = dict(zip(*reversed(axes[0].get_legend_handles_labels())))
    order = ["demonstrations", "demonstrations' mean", gen_label, cmp_label]
    fig.legend([handles[k] for k in order if k in handles], [k for k in order if k in handles],
               loc="outside lower center", ncols=4, fontsize=9, frameon=False)

    ax = fig.add_subplot(grid[3, :])
    axes.append(ax)
    ax.plot(s, result.per_step, color="black", lw=2.0, label=f"{gen_label}: total (mean {result.mean:.2f})")
    ax.plot(s, result.per_step_rotation, color="tab:red", lw=1.2, label=f"{gen_label}: rotation ({result.rotation:.2f})")
    ax.plot(s, result.per_step_translation, color="tab:green", lw=1.2,
            label=f"{gen_label}: translation ({result.translation:.2f})")
    if res_c is not None:
        ax.plot(s, res_c.per_step, color="tab:blue", ls="-.", lw=2.0, label=f"{cmp_label}: total (mean {res_c.mean:.2f})")
    finite = np.concatenate([result.per_step[np.isfinite(result.per_step)],
                             res_c.per_step[np.isfinite(res_c.per_step)] if res_c is not None else []])
    top, clipped = distance_axis_top(finite)
    ax.set_ylim(0.0, top)
    if clipped:
        ax.text(0.99, 0.97, f"clipped: largest $D_B$ = {float(finite.max()):.3g}", transform=ax.transAxes,
                ha="right", va="top", fontsize=8)
    ax.set_title(f"Bhattacharyya distance to the demonstrations per step ({result.covariance} covariance, "
                 f"{result.n_demos} demonstrations)", fontsize=10)
    ax.set_xlabel("normalised time s")
    ax.set_ylabel("$D_B$ [–]")
    ax.set_xlim(0.0, 1.0)
    ax.grid(True, lw=0.3, alpha=0.5)
    ax.legend(fontsize=8, ncols=2, loc="upper left")

    if title is None:
        title = f"{gen_label}: mean Bhattacharyya distance {result.mean:.2f}"
        if res_c is not None:
            title += f"   {cmp_label}: {res_c.mean:.2f}"
    fig.suptitle(title, fontsize=12)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=DPI)
    return fig


def _demo_colors(n: int) -> list:
    """n distinct colours for the demonstrations (a perceptual colour map, red-free at the ends)."""
    from matplotlib import colormaps

    cmap = colormaps["viridis"]
    return [cmap(v) for v in np.linspace(0.05, 0.9, max(n, 1))][:n]
