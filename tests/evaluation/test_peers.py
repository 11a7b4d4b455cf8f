"""The ProMP and DMP peer rows of rbgp crossval (movement-primitives): they are what the package itself
gives for the same inputs, start where they should, and are left out with one note without it."""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest
from typer.testing import CliRunner

from rbgp_cli.cli.app import app
from rbgp_cli.evaluation import peers
from rbgp_cli.evaluation.crossval import make_folds, nearest_index
from rbgp_cli.geometry.so3 import quat_make_continuous
from rbgp_cli.workflows import SAMPLE_DATA, load_demonstrations
from tests.helpers import quat_angle_between

FAST = ["--max-points", "120", "--restarts", "1", "--share-hyperparameters"]


@pytest.fixture(scope="module")
def fold():
    """One fold of sample_data/csv (3 folds, seed 0): (train, test)."""
    demos, _, _ = load_demonstrations([SAMPLE_DATA / "csv"])
    held = set(make_folds(len(demos), 3, 0)[0].tolist())
    return [d for i, d in enumerate(demos) if i not in held], [demos[i] for i in sorted(held)]


@pytest.mark.slow
def test_promp_row_is_the_packages_conditioned_mean(fold):
    """Our ProMP row equals the package's ProMP called directly on the same data, with the tangent
    coordinates computed independently here (scipy rotations, x, y, z, w): a wrong conversion or a
    wrong reference rotation fails."""
    mp = pytest.importorskip("movement_primitives.promp")
    from scipy.spatial.transform import Rotation

    from rbgp_cli.evaluation.resample import resample_all

    train, test = fold
    T = peers.PROMP_STEPS
    q, p = resample_all(train, T)
    R = Rotation.from_quat(q.reshape(-1, 4))
    starts = Rotation.from_quat(q[:, 0])
    ref = starts.mean()  # chordal L2 mean of the start rotations, as mean_rotation
    rv = (ref.inv() * R).as_rotvec().reshape(len(train), T, 3)
    assert np.max(np.linalg.norm(rv, axis=-1)) < np.pi - 0.1  # no unwrapping needed on this set
    Y = np.concatenate([rv, p], axis=-1)
    s = np.linspace(0.0, 1.0, T)
    promp = mp.ProMP(n_dims=6, n_weights_per_dim=25)
    promp.imitate(np.tile(s, (len(train), 1)), Y)

    quat0 = np.array([tr.quat[0] for tr in test])
    pos0 = np.array([tr.position[0] for tr in test])
    rows = peers.promp_rollouts(train, quat0, pos0, [tr.duration for tr in test])
    assert len(rows) == len(test)
    for tr, row in zip(test, rows):
        y0 = np.concatenate([(ref.inv() * Rotation.from_quat(tr.quat[0])).as_rotvec(), tr.position[0]])
        cond = promp.condition_position(y0, y_cov=np.diag([peers.START_STD[0] ** 2] * 3 + [peers.START_STD[1] ** 2] * 3))
        want = cond.mean_trajectory(s.copy())
        want_q = (ref * Rotation.from_rotvec(want[:, :3])).as_quat()
        np.testing.assert_allclose(row.position, want[:, 3:], atol=1e-6)
        assert np.max(quat_angle_between(row.quat, want_q)) < 1e-6
        assert row.t[0] == 0.0 and row.t[-1] == pytest.approx(tr.duration)
        # conditioned on the start: it begins nearer to it than the unconditioned mean does
        prior = promp.mean_trajectory(s.copy())[0]
        prior_q = (ref * Rotation.from_rotvec(prior[:3])).as_quat()
        near = np.linalg.norm(row.position[0] - tr.position[0]) + quat_angle_between(row.quat[0], tr.quat[0])
        assert near < np.linalg.norm(prior[3:] - tr.position[0]) + quat_angle_between(prior_q, tr.quat[0])


@pytest.mark.slow
def test_promp_samples_are_seeded_draws_around_the_mean(fold):
    pytest.importorskip("movement_primitives.promp")
    train, test = fold
    peer = peers.fit_promp(train)
    tr = test[0]
    a = peer.samples(tr.quat[0], tr.position[0], tr.duration, 20, seed=3)
    b = peer.samples(tr.quat[0], tr.position[0], tr.duration, 20, seed=3)
    c = peer.samples(tr.quat[0], tr.position[0], tr.duration, 20, seed=4)
    assert len(a) == 20 and [x.name for x in a[:2]] == ["promp.s0", "promp.s1"]
    assert all(np.array_equal(x.position, y.position) and np.array_equal(x.quat, y.quat) for x, y in zip(a, b))
    assert not np.array_equal(a[0].position, c[0].position)
    P = np.stack([x.position for x in a])  # (K, T, 3)
    spread = P.std(axis=0)
    assert np.all(spread[0] < 2 * peers.START_STD[1])  # held at the start by the via-point
    assert np.max(spread) > 0  # draws differ
    mean = peer.mean(tr.quat[0], tr.position[0], tr.duration)
    assert np.max(np.abs(P.mean(axis=0) - mean.position)) < 4 * np.max(spread) / np.sqrt(20) + 1e-9
    many = peers.promp_samples(train[:3], [t.quat[0] for t in test], [t.position[0] for t in test],
                               [t.duration for t in test], 2, seed=0)
    assert len(many) == len(test) and all(len(m) == 2 for m in many)


@pytest.mark.slow
def test_dmp_row_starts_at_the_new_start_and_ends_at_the_nearest_goal(fold):
    dmp_mod = pytest.importorskip("movement_primitives.dmp")
    pr = pytest.importorskip("pytransform3d.rotations")
    train, test = fold
    quat0 = np.array([tr.quat[0] for tr in test])
    pos0 = np.array([tr.position[0] for tr in test])
    rows = peers.dmp_rollouts(train, quat0, pos0, [tr.duration for tr in test])
    for tr, row in zip(test, rows):
        src = train[nearest_index(train, tr.quat[0], tr.position[0])]
        assert row.name == f"dmp of {src.name}"
        np.testing.assert_array_equal(row.position[0], tr.position[0])
        assert quat_angle_between(row.quat[0], tr.quat[0]) < 1e-12
        assert row.t[-1] == pytest.approx(tr.duration, rel=0.02)
        assert np.linalg.norm(row.position[-1] - src.position[-1]) < 0.02
        assert quat_angle_between(row.quat[-1], src.quat[-1]) < 0.05

    # Started at the demonstration's own start for its own duration, the DMP reproduces it; the same
    # as the package called directly with pytransform3d's w, x, y, z conversion.
    src = train[0]
    own = peers.dmp_rollouts(train[:1], src.quat[:1], src.position[:1], [src.duration])[0]
    t = src.t - src.t[0]
    dmp = dmp_mod.CartesianDMP(execution_time=t[-1], dt=np.mean(np.diff(t)), n_weights_per_dim=peers.DMP_BASIS)
    wxyz = np.array([pr.quaternion_wxyz_from_xyzw(x) for x in quat_make_continuous(src.quat)])
    dmp.imitate(t, np.concatenate([src.position, wxyz], axis=1))
    _, Y = dmp.open_loop()
    n = min(len(Y), len(own.t))
    np.testing.assert_allclose(own.position[:n], Y[:n, :3], atol=1e-9)
    assert np.max(quat_angle_between(own.quat[:n], np.array([pr.quaternion_xyzw_from_wxyz(x) for x in Y[:n, 3:]]))) < 1e-6
    i = np.minimum(np.searchsorted(t, own.t[:n]), len(t) - 1)
    assert np.max(np.linalg.norm(own.position[:n] - src.position[i], axis=1)) < 0.03
    assert np.max(quat_angle_between(own.quat[:n], src.quat[i])) < 0.1


@pytest.mark.slow
def test_peers_are_left_out_with_one_note_without_the_package(monkeypatch, tmp_path):
    """movement_primitives cannot be imported: crossval runs without the rows and says why once."""
    for name in [m for m in sys.modules if m.split(".")[0] == "movement_primitives"] + ["movement_primitives"]:
        monkeypatch.setitem(sys.modules, name, None)  # importing it raises ImportError
    assert "movement-primitives is not installed" in peers.missing()
    res = CliRunner().invoke(app, ["crossval", str(SAMPLE_DATA / "csv"), "--folds", "3", *FAST, "--jobs", "1",
                                   "--json", "-q"])
    assert res.exit_code == 0, res.stderr
    out = json.loads(res.stdout)
    assert {r["representation"] for r in out["results"]} == {"axis-angle", "replay"}
    assert len(out["skipped"]) == 1 and "movement-primitives is not installed" in out["skipped"][0]
    notes = [line for line in res.stderr.splitlines() if "movement-primitives" in line]
    assert len(notes) == 1 and "rbgp-cli[peers]" in notes[0]


@pytest.mark.slow
def test_crossval_shows_the_promp_and_dmp_rows():
    pytest.importorskip("movement_primitives.dmp")
    res = CliRunner().invoke(app, ["crossval", str(SAMPLE_DATA / "csv"), "--folds", "3", *FAST, "--jobs", "1", "-q"])
    assert res.exit_code == 0, res.stderr
    table = res.stdout.split("paired against")[0]  # the table, without the paired section under it
    lines = {line.split()[0]: line.split() for line in table.splitlines() if line.strip()}
    assert {"promp", "dmp", "replay", "axis-angle"} <= set(lines)
    assert "paired against" in res.stdout
    for name in ("promp", "dmp"):
        score, floor, ratio = (float(x) for x in lines[name][2:5])
        assert np.isfinite([score, floor, ratio]).all() and score > 0
    res = CliRunner().invoke(app, ["crossval", str(SAMPLE_DATA / "csv"), "--folds", "3", *FAST, "--jobs", "1",
                                   "--no-peers", "--json", "-q"])
    out = json.loads(res.stdout)
    assert {r["representation"] for r in out["results"]} == {"axis-angle", "replay"} and out["skipped"] == []
