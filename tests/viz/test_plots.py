"""The evaluation figure: pixel size, not blank, one panel per dimension plus the Bhattacharyya panel,
what each panel draws, no jump at θ = π, atomic writing, and a clear error without matplotlib."""

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


def test_one_panel_per_dimension_plus_the_bhattacharyya_panel(figure, data):
    demos, generated, compare, result = data
    _, fig = figure
    axes = fig.axes
    assert len(axes) == 7
    ylabels = [ax.get_ylabel() for ax in axes]
    assert sum("[rad]" in y for y in ylabels) == 3 and sum("[m]" in y for y in ylabels) == 3
    for j, ax in enumerate(axes[:6]):
        styles = [line.get_linestyle() for line in ax.lines]
        assert styles.count(":") == len(demos)
        assert styles.count("--") == MAX_LINES  # a subset of the generated trajectories
        assert styles.count("-.") == len(compare)
        (mean,) = [line for line in ax.lines if line.get_linestyle() == "-"]
        assert mean.get_color() == "red"
        np.testing.assert_array_equal(mean.get_ydata(), result.demo_mean[:, j])
        np.testing.assert_array_equal(mean.get_xdata(), result.s)
        assert ax.get_xlim() == (0.0, 1.0)
    last = axes[6]
    np.testing.assert_array_equal(last.lines[0].get_ydata(), result.per_step)
    np.testing.assert_array_equal(last.lines[1].get_ydata(), result.per_step_rotation)
    np.testing.assert_array_equal(last.lines[2].get_ydata(), result.per_step_translation)
    other = evaluate(compare, demos, length=result.steps)
    np.testing.assert_allclose(last.lines[3].get_ydata(), other.per_step, rtol=1e-12)
    labels = [t.get_text() for t in fig.legends[0].get_texts()]
    assert labels == ["demonstrations", "demonstrations' mean", "rigid-body GP", "Euler GP"]


def test_rotations_do_not_jump_at_pi(figure, data):
    demos, *_ = data
    angles = np.linalg.norm(demos[0].poses[:, :3], axis=1)
    assert angles.max() > np.pi - 0.2  # the raw rotation vectors do reach θ ≈ π ...
    _, fig = figure
    for ax in fig.axes[:3]:
        for line in ax.lines:
            assert np.max(np.abs(np.diff(line.get_ydata()))) < 0.3  # ... the plotted features stay continuous


def test_without_compare_and_with_a_title(tmp_path, data):
    demos, generated, _, result = data
    result3 = evaluate(generated[:3], demos)
    fig = plot_evaluation(tmp_path / "a.png", result3, generated[:3], demos, title="my title")
    assert len(fig.axes) == 7
    assert fig.get_suptitle() == "my title"
    for ax in fig.axes[:6]:
        styles = [line.get_linestyle() for line in ax.lines]
        assert styles.count("--") == 3 and styles.count("-.") == 0
    assert len(fig.axes[6].lines) == 3
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
    with pytest.raises(InputError, match="--plot needs matplotlib") as info:
        plot_evaluation(tmp_path / "c.png", result, generated, demos)
    assert "pip install 'rbgp-cli[plot]'" in str(info.value)
    assert info.value.exit_code == 2
    assert not (tmp_path / "c.png").exists()


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


def test_the_clipped_panel_names_the_largest_distance(tmp_path, data):
    from dataclasses import replace

    demos, generated, _, result = data
    spiky = result.per_step.copy()
    spiky[5] = 1e6
    fig = plot_evaluation(tmp_path / "spike.png", replace(result, per_step=spiky), generated, demos)
    ax = fig.axes[6]
    assert ax.get_yscale() == "linear" and ax.get_ylim()[1] < 1e5
    assert [t.get_text() for t in ax.texts] == ["clipped: largest $D_B$ = 1e+06"]
