"""The live update's arithmetic written out (issue 37, `rbgp follow`): the slerp of the seen samples, the
canonical logarithm and the deviations from the mean path against scipy and rbgp's general functions."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation, Slerp

from rbgp_cli.dynamics.anticipation import Anticipator, _log_unit, _slerp_samples
from rbgp_cli.dynamics.paths import fit_paths, pose_deviation
from rbgp_cli.dynamics.trajectory import interpolate_poses
from rbgp_cli.geometry.so3 import quat_make_continuous

from ..helpers import assert_quats_close, assert_rotvecs_close, rotvecs
from .test_anticipation import family


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), step=st.sampled_from([1e-9, 1e-5, 0.01, 0.3, 1.5]))
def test_the_seen_samples_slerp_equals_scipys(seed, step):
    """_slerp_samples at evenly spaced times equals scipy's Slerp (rotations) and linear interpolation
    (positions), for steps between samples from 1e-9 rad (the series' limit) to 1.5 rad."""
    rng = np.random.default_rng(seed)
    N = int(rng.integers(2, 40))
    x = np.cumsum(rng.uniform(0.01, 1.0, N))
    r = Rotation.random(random_state=seed) * Rotation.from_rotvec(
        np.cumsum(step * rng.normal(size=(N, 3)) / np.sqrt(3), axis=0))
    quat = quat_make_continuous(r.as_quat())
    position = rng.normal(size=(N, 3))
    x_new = np.linspace(x[0], x[-1], int(rng.integers(2, 13)))
    q, p = _slerp_samples(x, quat, position, x_new)
    assert_quats_close(q, Slerp(x, r)(x_new).as_quat(), atol=1e-12)
    np.testing.assert_allclose(p, np.stack([np.interp(x_new, x, position[:, j]) for j in range(3)], axis=1),
                               atol=1e-12)
    assert np.array_equal(q[0], quat[0])  # f = 0 returns the sample itself


@settings(max_examples=200, deadline=None)
@given(r=rotvecs(), flip=st.booleans())
def test_the_written_out_log_is_the_canonical_rotation_vector(r, flip):
    """_log_unit equals the rotation's vector by scipy (either sign of the quaternion), near 0 and near π."""
    q = Rotation.from_rotvec(r).as_quat() * (-1.0 if flip else 1.0)
    v = _log_unit(q[None])[0]
    assert_rotvecs_close(v, r, atol=1e-12)
    assert np.linalg.norm(v) <= np.pi + 1e-12


def test_the_deviations_from_the_mean_path_equal_the_general_computation():
    """Anticipator._deviations (the batched grid terms' and the live update's) at random grid intervals and
    fractions equals pose_deviation from the mean path interpolated by interpolate_poses, scaled, less
    the prior mean interpolated linearly."""
    demos, _ = family(10, 5)
    paths = fit_paths(demos)
    ant = Anticipator(paths, None)
    rng = np.random.default_rng(3)
    S = paths.S
    k = rng.integers(0, S - 1, (5, 7))
    f = rng.uniform(0.0, 1.0, (5, 7))
    f[0, :2] = (0.0, 1.0)
    phases = (k + f) / (S - 1)
    q = Rotation.random(7, random_state=4).as_quat()
    p = rng.normal(size=(7, 3))
    got = ant._deviations(k, f, q[None], p[None])
    rq, rp = interpolate_poses(paths.s, paths.quat, paths.position, phases.ravel())
    dev = pose_deviation(rq, rp, np.broadcast_to(q, (5, 7, 4)).reshape(-1, 4),
                         np.broadcast_to(p, (5, 7, 3)).reshape(-1, 3)) / paths.scale
    m = ant.m[:-1].reshape(S, 6)
    expected = dev.reshape(5, 7, 6) - ((1.0 - f)[..., None] * m[k] + f[..., None] * m[k + 1])
    np.testing.assert_allclose(got, expected, atol=1e-9)
    assert np.abs(expected).max() > 0.5  # poses far off the path: the comparison means something
