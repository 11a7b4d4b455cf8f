"""The rollout figure (``rbgp rollout --plot``): six panels over time, one line per mean rollout up to its
own length, the samples' 90 % band, goals at each rollout's end and via-points at their time, drawn at
the features :func:`rollout_features` gives (checked against scipy's ``Rotation``)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rbgp_cli.dynamics.rollout import RolloutResult
from rbgp_cli.viz.plots import ROLLOUT_BAND, plot_rollout, rollout_features

pytest.importorskip("matplotlib")


def _result(B=2, K=8, T=30, seed=0):
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 2.0, T)
    angle = np.linspace(0.0, 1.2, T)[None, :, None] * np.array([0.2, 0.3, 0.9])  # about one axis, growing
    quat = Rotation.from_rotvec((angle + 0.01 * np.arange(B)[:, None, None]).reshape(-1, 3)).as_quat().reshape(B, T, 4)
    pos = np.cumsum(rng.normal(0, 0.01, (B, T, 3)), axis=1)
    sq = np.repeat(quat[:, None], K, axis=1)
    sp = pos[:, None] + rng.normal(0, 0.02, (B, K, T, 3))
    res = RolloutResult(t=t, quat=quat, position=pos, std=None, output_names=(), sample_quat=sq, sample_position=sp,
                        lengths=np.array([T, T - 5]))
    res.goal_quat, res.goal_position = quat[[0, 1], [T - 1, T - 6]], pos[[0, 1], [T - 1, T - 6]]
    res.via = ((1.0, quat[0, 14], pos[0, 14]),)
    return res


def test_features_are_the_rotation_vector_relative_to_the_reference_and_the_position():
    rng = np.random.default_rng(1)
    q = Rotation.random(5, random_state=2).as_quat()
    p = rng.normal(size=(5, 3))
    f = rollout_features(q, p, q[0])
    expected = (Rotation.from_quat(q[0]).inv() * Rotation.from_quat(q)).as_rotvec()
    np.testing.assert_allclose(f[:, :3], expected, atol=1e-9)
    np.testing.assert_allclose(f[:, 3:], p)


@pytest.mark.slow
def test_the_figure_draws_means_to_their_length_bands_goals_and_via_points(tmp_path):
    res = _result()
    path = tmp_path / "r.png"
    fig = plot_rollout(path, res)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert len(fig.axes) == 6
    ax = fig.axes[4]  # translation y
    lines = {ln.get_gid(): ln for ln in ax.get_lines()}
    assert len(lines["mean:1"].get_xdata()) == 25  # the second rollout ends 5 samples early
    np.testing.assert_allclose(lines["mean:0"].get_ydata(), res.position[0, :, 1])
    goal = lines["goal:1"]
    assert goal.get_xdata()[0] == pytest.approx(res.t[24])
    assert goal.get_ydata()[0] == pytest.approx(res.goal_position[1, 1])
    assert lines["via:0"].get_xdata()[0] == pytest.approx(1.0)
    assert lines["via:0"].get_ydata()[0] == pytest.approx(res.via[0][2][1])
    band = [c for c in ax.collections if c.get_gid() == "band:0"]
    assert len(band) == 1
    y = band[0].get_paths()[0].vertices[:, 1]
    lo = np.quantile(res.sample_position[0, :, :, 1], ROLLOUT_BAND[0], axis=0)
    hi = np.quantile(res.sample_position[0, :, :, 1], ROLLOUT_BAND[1], axis=0)
    assert y.min() == pytest.approx(lo.min()) and y.max() == pytest.approx(hi.max())
    assert "goals: crosses" in fig._suptitle.get_text() and "via-point" in fig._suptitle.get_text()


@pytest.mark.slow
def test_without_samples_there_is_no_band(tmp_path):
    res = _result()
    res.sample_quat = res.sample_position = None
    fig = plot_rollout(tmp_path / "r.png", res)
    assert not [c for a in fig.axes for c in a.collections if str(c.get_gid()).startswith("band:")]


@pytest.mark.slow
def test_a_computed_band_is_drawn_about_the_mean_instead_of_the_samples_quantiles(tmp_path):
    res = _result()
    B, T = res.quat.shape[:2]
    res.band_position = np.full((B, T, 3), 0.05)
    res.band_rotation = np.broadcast_to(np.diag([0.01, 0.04, 0.09]), (B, T, 3, 3)).copy()
    fig = plot_rollout(tmp_path / "r.png", res)
    feats = rollout_features(res.quat, res.position, res.quat[0, 0])
    y = [c for c in fig.axes[4].collections if c.get_gid() == "band:0"][0].get_paths()[0].vertices[:, 1]
    assert y.min() == pytest.approx((res.position[0, :, 1] - 0.05).min())
    assert y.max() == pytest.approx((res.position[0, :, 1] + 0.05).max())
    # rotation: per axis of the reference frame, sqrt of the diagonal of R_refᵀ M R_ref
    R_ref = Rotation.from_quat(res.quat[0, 0]).as_matrix()
    half = np.sqrt(np.diag(R_ref.T @ res.band_rotation[0, 0] @ R_ref))
    yr = [c for c in fig.axes[2].collections if c.get_gid() == "band:0"][0].get_paths()[0].vertices[:, 1]
    assert yr.max() == pytest.approx((feats[0, :, 2] + half[2]).max())
    assert "the next motion's 90 % region" in fig._suptitle.get_text()
