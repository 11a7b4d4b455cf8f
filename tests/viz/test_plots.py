"""The evaluation figure: pixel size, not blank, one panel per dimension plus the Bhattacharyya panels,
what each panel draws (bands, thinned lines, axes that a divergent rollout does not squash, Monte
Carlo samples apart), no jump at θ = π, the figure without a score, atomic writing, and a clear error
without matplotlib. Assertions are on the matplotlib objects, not on pixels (except size and colour)."""

from __future__ import annotations

import os
import sys

import numpy as np
import pytest

from rbgp_cli.errors import InputError
from rbgp_cli.evaluation import evaluate
from rbgp_cli.viz.plots import MAX_LINES, plot_evaluation

from . import synth_trajectory

pytest.importorskip("matplotlib")


@pytest.fixture(scope="module")
def data():
    # the demonstrations turn by ~3.3 rad about z, so their rotation vectors pass θ = π
    demos = [synth_trajectory(i, 40 + i, turn=3.3, noise=0.001, seed=i) for i in range(5)]
    generated = [synth_trajectory(0.4 * i, 35, turn=3.2, noise=0.002, seed=10 + i) for i in range(MAX_LINES + 5)]
    compare = [synth_trajectory(0.7 * i, 45, turn=2.8, noise=0.004, seed=50 + i) for i in range(6)]
    return demos, generated, compare, evaluate(generated, demos)


@pytest.fixture(scope="module")
def figure(tmp_path_factory, data):
    demos, generated, compare, result = data
    path = tmp_path_factory.mktemp("plot") / "eval.png"
    fig = plot_evaluation(path, result, generated, demos, compare=compare, labels=("rigid-body GP", "Euler GP"))
    return path, fig


def _image(path):
    from matplotlib.image import imread

    return imread(path)  # (rows, cols, channels) floats in [0, 1]


@pytest.mark.slow
def test_png_has_the_stated_size_and_is_not_blank(figure):
    path, _ = figure
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    img = _image(path)
    assert img.shape[:2] == (1000, 1200)  # 12 x 10 in at 100 dpi
    rgb = img[..., :3]
    assert rgb.var() > 0.001
    q = (rgb * 255).round().astype(np.uint32)
    colours = np.unique((q[..., 0] << 16) | (q[..., 1] << 8) | q[..., 2])
    assert len(colours) > 50
    red = (rgb[..., 0] > 0.9) & (rgb[..., 1] < 0.15) & (rgb[..., 2] < 0.15)
    blue = (rgb[..., 2] > 0.6) & (rgb[..., 0] < 0.3)
    assert red.sum() > 500 and blue.sum() > 500  # the demonstrations' mean and the compare set are drawn
    assert os.listdir(path.parent) == [path.name]  # no temporary file left beside it


def test_one_panel_per_dimension_plus_three_distance_panels(figure, data):
    demos, generated, compare, result = data
    _, fig = figure
    axes = fig.axes
    assert len(axes) == 9
    ylabels = [ax.get_ylabel() for ax in axes]
    assert sum("[rad]" in y for y in ylabels) == 3 and sum("[m]" in y for y in ylabels) == 3
    other = evaluate(compare, demos, length=result.steps)
    for j, ax in enumerate(axes[:6]):
        assert len(_by_gid(ax, "line:demonstrations")) == len(demos)  # few: all drawn
        assert len(_by_gid(ax, "line:generated")) == MAX_LINES  # a subset of the generated trajectories
        assert len(_by_gid(ax, "line:compare")) == len(compare)
        (mean,) = _by_gid(ax, "mean:demonstrations")
        assert mean.get_color() == "red" and mean.get_linestyle() == "-"
        np.testing.assert_array_equal(mean.get_ydata(), result.demo_mean[:, j])
        np.testing.assert_array_equal(mean.get_xdata(), result.s)
        (mean_c,) = _by_gid(ax, "mean:compare")
        np.testing.assert_allclose(mean_c.get_ydata(), other.gen_mean[:, j], rtol=1e-12)
        assert len(_by_gid(ax, "band:compare")) == 1
        assert ax.get_xlim() == (0.0, 1.0)
    for ax, series in zip(axes[6:], ("per_step", "per_step_rotation", "per_step_translation")):
        np.testing.assert_array_equal(ax.lines[0].get_ydata(), getattr(result, series))
        np.testing.assert_allclose(ax.lines[1].get_ydata(), getattr(other, series), rtol=1e-12)
    labels = [t.get_text() for t in fig.legends[0].get_texts()]
    assert labels == [f"demonstrations ({len(demos)})", "demonstrations: mean ± 2σ",
                      f"rigid-body GP ({MAX_LINES} of {len(generated)} drawn)", "rigid-body GP: mean ± 2σ",
                      f"Euler GP ({len(compare)})", "Euler GP: mean ± 2σ"]


def test_rotations_do_not_jump_at_pi(figure, data):
    demos, *_ = data
    angles = np.linalg.norm(demos[0].poses[:, :3], axis=1)
    assert angles.max() > np.pi - 0.2  # the raw rotation vectors do reach θ ≈ π ...
    _, fig = figure
    for ax in fig.axes[:3]:
        for line in ax.lines:
            assert np.max(np.abs(np.diff(line.get_ydata()))) < 0.3  # ... the plotted features stay continuous


@pytest.mark.slow
def test_without_compare_and_with_a_title(tmp_path, data):
    demos, generated, _, result = data
    result3 = evaluate(generated[:3], demos)
    fig = plot_evaluation(tmp_path / "a.png", result3, generated[:3], demos, title="my title")
    assert len(fig.axes) == 9
    assert fig.get_suptitle() == "my title"
    for ax in fig.axes[:6]:
        assert len(_by_gid(ax, "line:generated")) == 3 and not _by_gid(ax, "line:compare")
    assert [len(ax.lines) for ax in fig.axes[6:]] == [1, 1, 1]
    assert _image(tmp_path / "a.png").shape[:2] == (1000, 1200)


def test_inputs_that_do_not_match_the_result_are_refused(tmp_path, data):
    demos, generated, _, result = data
    dest = tmp_path / "b.png"
    dest.write_bytes(b"previous")
    with pytest.raises(InputError, match="computed from"):
        plot_evaluation(dest, result, generated[:2], demos)
    assert dest.read_bytes() == b"previous"
    assert os.listdir(tmp_path) == ["b.png"]


def test_missing_matplotlib_is_an_input_error(tmp_path, data, monkeypatch):
    demos, generated, _, result = data
    for name in ("matplotlib", "matplotlib.figure", "matplotlib.backends.backend_agg"):
        monkeypatch.setitem(sys.modules, name, None)
    with pytest.raises(InputError, match="plot needs matplotlib") as info:
        plot_evaluation(tmp_path / "c.png", result, generated, demos)
    assert "pip install 'rbgp-cli[plot]'" in str(info.value)
    assert info.value.exit_code == 2
    assert not (tmp_path / "c.png").exists()


@pytest.mark.slow
def test_distance_panel_stays_linear_when_the_first_step_is_almost_zero(tmp_path, data):
    """Generated trajectories that start where the demonstrations start score ~1e-25 at the first
    step; a log axis would span 25 decades and flatten the curve, so the axis stays linear from 0."""
    demos, *_ = data
    gen = [d.with_(position=d.position + 1e-13 + np.linspace(0.0, 1.0, len(d))[:, None] * 0.02 * (k + 1))
           for k, d in enumerate(demos)]
    result = evaluate(gen, demos)
    assert 0 < result.per_step[0] < 1e-15 and result.per_step.max() > 1.0
    fig = plot_evaluation(tmp_path / "near.png", result, gen, demos)
    ax = fig.axes[6]
    assert ax.get_yscale() == "linear"
    low, high = ax.get_ylim()
    assert low == 0.0 and result.per_step.max() <= high <= 1.3 * result.per_step.max() + 1e-12
    assert not [t for t in ax.texts if "clipped" in t.get_text()]


def test_a_few_spikes_are_clipped_and_said_so():
    from rbgp_cli.viz.plots import CLIP_FACTOR, distance_axis_top

    smooth = np.linspace(0.5, 2.0, 100)
    assert distance_axis_top(smooth) == (pytest.approx(1.3 * 2.0), False)
    spiky = smooth.copy()
    spiky[[3, 50]] = 1e4
    top, clipped = distance_axis_top(spiky)
    assert clipped and top == pytest.approx(1.3 * CLIP_FACTOR * np.percentile(spiky, 90))
    assert top < 1e3
    assert distance_axis_top([np.nan, np.inf]) == (1.0, False)
    assert distance_axis_top(np.zeros(5)) == (pytest.approx(1.3e-12), False)


@pytest.mark.slow
def test_the_clipped_panel_names_the_largest_distance(tmp_path, data):
    from dataclasses import replace

    demos, generated, _, result = data
    spiky = result.per_step.copy()
    spiky[5] = 1e6
    fig = plot_evaluation(tmp_path / "spike.png", replace(result, per_step=spiky), generated, demos)
    ax = fig.axes[6]
    assert ax.get_yscale() == "linear" and ax.get_ylim()[1] < 1e5
    assert [t.get_text() for t in ax.texts] == ["clipped: largest $D_B$ = 1e+06"]


# ---------------------------------------------------------------------------------------------- large sets
def _by_gid(ax, gid):
    return [a for a in list(ax.lines) + list(ax.collections) if a.get_gid() == gid]


def _band_limits(ax, key):
    """(x, low, high) of the band ``band:<key>`` of a panel, from the polygon fill_between drew."""
    (band,) = _by_gid(ax, f"band:{key}")
    v = band.get_paths()[0].vertices
    return v[:, 0], v[:, 1]


@pytest.fixture(scope="module")
def large(tmp_path_factory):
    """100 demonstrations, 100 generated trajectories of which one diverges (y runs off to -5 m)."""
    demos = [synth_trajectory(0.05 * i, 40, noise=0.001, seed=i) for i in range(100)]
    gen = [synth_trajectory(0.05 * i + 0.02, 36, noise=0.002, seed=300 + i) for i in range(100)]
    bad = gen[7]
    gen[7] = bad.with_(position=bad.position + np.linspace(0.0, 1.0, len(bad))[:, None] ** 2 * [0.0, -5.0, 0.0])
    result = evaluate(gen, demos)
    fig = plot_evaluation(tmp_path_factory.mktemp("large") / "large.png", result, gen, demos)
    return demos, gen, result, fig


@pytest.mark.slow
def test_a_divergent_rollout_does_not_squash_the_axis(large):
    from rbgp_cli.viz.plots import _features

    demos, gen, result, fig = large
    x_d = _features(demos, result)
    for j, ax in enumerate(fig.axes[:6]):
        lo_d = min(x_d[:, :, j].min(), (result.demo_mean[:, j] - 2 * result.demo_std[:, j]).min())
        hi_d = max(x_d[:, :, j].max(), (result.demo_mean[:, j] + 2 * result.demo_std[:, j]).max())
        low, high = ax.get_ylim()
        span = hi_d - lo_d
        # the demonstrations fill the axis: it reaches a little beyond them (the generated set is close)
        assert lo_d - 0.5 * span <= low <= lo_d and hi_d <= high <= hi_d + 0.5 * span, (j, low, high, lo_d, hi_d)
    y = fig.axes[4]
    assert y.get_ylim()[0] > -0.5  # not -5 m
    (note,) = [t.get_text() for t in y.texts]
    assert "1 of 100" in note and "clipped" in note


def test_bands_of_demonstrations_and_generated_are_the_scores_mean_and_2_sigma(large):
    _, _, result, fig = large
    for j, ax in enumerate(fig.axes[:6]):
        for key, mean, std in (("demonstrations", result.demo_mean, result.demo_std),
                               ("generated", result.gen_mean, result.gen_std)):
            xs, ys = _band_limits(ax, key)
            T = len(result.s)
            # fill_between's polygon: the lower edge forward, the upper edge backward
            low = np.interp(result.s, xs[1:T + 1], ys[1:T + 1])
            np.testing.assert_allclose(low, mean[:, j] - 2 * std[:, j], atol=1e-12)
            assert np.isclose(ys.max(), (mean[:, j] + 2 * std[:, j]).max())
            (m,) = _by_gid(ax, f"mean:{key}")
            np.testing.assert_array_equal(m.get_ydata(), mean[:, j])


def test_lines_are_thinned_above_the_count_and_the_legend_says_so(large):
    _, _, _, fig = large
    for ax in fig.axes[:6]:
        assert len(_by_gid(ax, "line:demonstrations")) == MAX_LINES
        assert len(_by_gid(ax, "line:generated")) == MAX_LINES
        assert all(line.get_alpha() < 0.5 for line in _by_gid(ax, "line:generated"))
    labels = [t.get_text() for t in fig.legends[0].get_texts()]
    assert f"demonstrations ({MAX_LINES} of 100 drawn)" in labels
    assert f"generated ({MAX_LINES} of 100 drawn)" in labels
    assert "demonstrations: mean ± 2σ" in labels and "generated: mean ± 2σ" in labels


def test_the_time_axis_is_labelled_without_a_unit(large):
    _, _, _, fig = large
    labels = {ax.get_xlabel() for ax in fig.axes if ax.get_xlabel()}
    assert labels == {"normalised time (0–1)"}


@pytest.mark.slow
def test_each_part_of_the_score_has_its_own_axis(tmp_path, data):
    """A rotation part of ~0.003 beside a translation part of ~1 is readable on its own axis."""
    demos, generated, _, result = data
    fig = plot_evaluation(tmp_path / "parts.png", result, generated, demos)
    total, rot, tra = fig.axes[6:9]
    for ax, series in ((total, result.per_step), (rot, result.per_step_rotation),
                       (tra, result.per_step_translation)):
        np.testing.assert_array_equal(ax.lines[0].get_ydata(), series)
        low, high = ax.get_ylim()
        assert low == 0.0 and series.max() <= high <= 1.3 * series.max() + 1e-12


@pytest.mark.slow
def test_a_part_flattened_by_the_other_set_is_written_out(tmp_path, data):
    demos, generated, compare, result = data
    far = [c.with_(position=c.position + 0.3) for c in compare]  # translation part far larger than ours
    fig = plot_evaluation(tmp_path / "flat.png", result, generated, demos, compare=far)
    texts = [t.get_text() for t in fig.axes[8].get_legend().get_texts()]
    assert "flat at this scale" in texts[0] and "at most" in texts[0]
    assert "flat" not in texts[1]


@pytest.mark.slow
def test_monte_carlo_samples_get_their_own_band(tmp_path):
    """A rollout CSV with samples (names 3, 3.s0, 3.s1, ... as rbgp rollout --samples writes them, and
    file#3.s0 after reading back): mean rollouts and samples are drawn as two bands."""
    from rbgp_cli.evaluation.bhattacharyya import _moments
    from rbgp_cli.io.csv import write_trajectories_csv
    from rbgp_cli.viz.plots import _features, is_monte_carlo_sample
    from rbgp_cli import workflows
    from rbgp_cli.io.options import ReadOptions

    from . import synth_rollout

    demos = [synth_trajectory(i, 30, noise=0.001, seed=i) for i in range(4)]
    res = synth_rollout(B=5, steps=30, K=4)
    write_trajectories_csv(res.trajectories(include_samples=True), tmp_path / "mc.csv")
    gen, _, _ = workflows.load_demonstrations([str(tmp_path / "mc.csv")], ReadOptions())
    samples = np.array([is_monte_carlo_sample(t) for t in gen])
    assert samples.sum() == 20 and (~samples).sum() == 5
    result = evaluate(gen, demos)
    fig = plot_evaluation(tmp_path / "mc.png", result, gen, demos)
    x = _features(gen, result)
    for key, part in (("generated", x[~samples]), ("samples", x[samples])):
        mu, cov = _moments(part)
        sd = np.sqrt(np.diagonal(cov, axis1=-2, axis2=-1))
        for j, ax in enumerate(fig.axes[:6]):
            (m,) = _by_gid(ax, f"mean:{key}")
            np.testing.assert_allclose(m.get_ydata(), mu[:, j], atol=1e-12)
            _, ys = _band_limits(ax, key)
            assert np.isclose(ys.max(), (mu[:, j] + 2 * sd[:, j]).max())
    for ax in fig.axes[:6]:
        assert len(_by_gid(ax, "line:generated")) == 5 and not _by_gid(ax, "line:samples")
    labels = [t.get_text() for t in fig.legends[0].get_texts()]
    assert "Monte Carlo samples (20): mean ± 2σ" in labels


def test_sample_names():
    from rbgp_cli.dynamics.trajectory import Trajectory
    from rbgp_cli.viz.plots import is_monte_carlo_sample

    t = synth_trajectory(0, 5)
    named = lambda n: Trajectory(t.t, t.quat, t.position, name=n)  # noqa: E731
    assert is_monte_carlo_sample(named("3.s0")) and is_monte_carlo_sample(named("roll#12.s7"))
    assert not is_monte_carlo_sample(named("3")) and not is_monte_carlo_sample(named("shoe.s01.csv"))
    assert not is_monte_carlo_sample(named("take.s1"))


def test_axis_limits_cover_the_demonstrations_and_the_bulk_of_the_generated_set():
    from rbgp_cli.viz.plots import AXIS_MARGIN, feature_axis_limits

    demos = np.linspace(0.0, 1.0, 10)[None, :] + np.zeros((5, 1))
    band = demos[0]
    gen = demos[[0, 1, 2, 3]] + np.array([[0.0], [0.05], [-0.05], [0.02]])
    wild = np.vstack([gen, -5.0 * np.ones(10)])
    low, high = feature_axis_limits(demos, band, band, [gen])  # the generated set's own extremes
    span = 1.1
    assert low == pytest.approx(-0.05 - AXIS_MARGIN * span) and high == pytest.approx(1.05 + AXIS_MARGIN * span)
    low_w, high_w = feature_axis_limits(demos, band, band, [wild])  # the divergent one moves it a little only
    assert -0.5 < low_w <= low and high <= high_w < 1.3
    # a constant feature (one demonstration's rotation at its own mean) still gets a visible axis
    low, high = feature_axis_limits(np.zeros((1, 10)), np.zeros(10), np.zeros(10))
    assert low < 0 < high


@pytest.mark.slow
def test_without_a_score_the_figure_has_no_score_panels_and_says_why(tmp_path, data):
    demos, generated, _, _ = data
    result = evaluate(generated, demos[:1], sample_size="record")
    fig = plot_evaluation(tmp_path / "one.png", result, generated, demos[:1])
    assert len(fig.axes) == 6
    assert "no score: cannot score against 1 demonstration" in fig.get_suptitle()
    assert not _by_gid(fig.axes[0], "band:demonstrations")  # one trajectory has no spread
    assert _by_gid(fig.axes[0], "band:generated")
    assert _image(tmp_path / "one.png").shape[:2] == (1000, 1200)
