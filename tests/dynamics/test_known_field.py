"""A known velocity field on SE(3) as the oracle: demonstrations integrated from it, velocities
predicted at unseen poses and compared with the field itself (issue 9).

The field ξ(R, p) = (ω, v) mixes the body's axes with the world's, so the rotations it drives sweep
1.2–1.6 rad per demonstration and reach angles above 2 rad; translations relax toward a point.
Eight demonstrations of 3 s at 100 Hz from nearby starts (a set of demonstrations of one motion, as
users record them) train the model; three others from the same start distribution give the unseen
poses. The score is the RMSE of the predicted twists relative to that of predicting zero.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rbgp_cli.dynamics.model import train_model
from rbgp_cli.dynamics.trajectory import Trajectory
from rbgp_cli.geometry.se3 import integrate_quat
from rbgp_cli.geometry.so3 import matrix_from_quat

CENTRE = np.array([0.5, 0.0, 1.0])


def field(quat, position):
    """World-frame twist (ω, v) (m, 6) at poses (quat (m, 4) x, y, z, w; position (m, 3))."""
    R = matrix_from_quat(quat)
    w = np.cross(R[..., :, 0], [0.0, 0.0, 1.0]) + 0.5 * R[..., :, 1] + 0.3 * np.sin(2 * position)
    v = 0.3 * R[..., :, 2] - 0.6 * (position - CENTRE)
    return np.concatenate([w, v], axis=-1)


def demonstrations(n, seed, duration=3.0, rate=100, substeps=10):
    rng = np.random.default_rng(seed)
    q = Rotation.from_rotvec(np.array([0.6, -0.4, 0.3]) + rng.normal(0.0, 0.3, (n, 3))).as_quat()
    p = rng.normal(CENTRE, 0.1, (n, 3))
    h = 1.0 / rate
    Q, P = [q], [p]
    for _ in range(int(round(duration * rate))):
        for _ in range(substeps):  # exp-map steps of h/10: the demonstrations follow the field closely
            q, p = integrate_quat(q, p, field(q, p), h / substeps)
        Q.append(q)
        P.append(p)
    Q, P = np.stack(Q, axis=1), np.stack(P, axis=1)
    t = np.arange(Q.shape[1]) * h
    return [Trajectory(t, Q[i], P[i], name=f"field_{seed}_{i}") for i in range(n)]


@pytest.fixture(scope="module")
def data():
    return demonstrations(8, 1), demonstrations(3, 2)


def relative_rmse(model, unseen, count=300):
    """RMSE of the model's twists at ``count`` poses of the unseen demonstrations (at their phase or
    time, for models that take one), relative to the RMSE of predicting zero."""
    q = np.concatenate([d.quat for d in unseen])
    p = np.concatenate([d.position for d in unseen])
    tau = np.concatenate([(d.t - d.t[0]) / (d.duration if model.time_input == "phase" else 1.0) for d in unseen])
    # each pose's own demonstration's start (a start-conditioned prior follows the path from it)
    q0 = np.concatenate([np.repeat(d.quat[:1], len(d.t), axis=0) for d in unseen])
    p0 = np.concatenate([np.repeat(d.position[:1], len(d.t), axis=0) for d in unseen])
    pick = np.linspace(0, len(q) - 1, count).astype(int)
    q, p, tau, q0, p0 = q[pick], p[pick], tau[pick], q0[pick], p0[pick]
    out = model.predict(q, p, return_std=False, tau=tau if model.time_input else None, start=(q0, p0))
    if model.time_input == "phase":
        out = out / unseen[0].duration  # outputs per unit phase -> per second (all last 3 s)
    X = model.representation.state_from_pose(q, p)
    twist = model.representation.twist_from_output(X, q, out)
    truth = field(q, p)
    return float(np.sqrt(np.mean((twist - truth) ** 2)) / np.sqrt(np.mean(truth**2)))


@pytest.mark.slow
def test_the_field_turns_the_body_widely(data):
    train, _ = data
    swept = [np.linalg.norm((Rotation.from_quat(d.quat[-1]) * Rotation.from_quat(d.quat[0]).inv()).as_rotvec()) for d in train]
    largest = [np.linalg.norm(Rotation.from_quat(d.quat).as_rotvec(), axis=1).max() for d in train]
    assert min(swept) > 1.0 and max(largest) > 2.0


@pytest.mark.slow
def test_default_kernel_and_velocities_learn_the_field(data):
    """Default options (chordal kernel, velocities at 10 Hz, all pairs, the phase input) with a zero
    prior mean: the GP's own velocity field is within 10 % of the truth at unseen poses (measured 0.04;
    the geodesic kernel with the paper's subsample at the recorded rate: issue 9 measured 0.85 on its field)."""
    train, unseen = data
    model = train_model(train, prior=None)
    assert model.summary["kernel"] == "se-chordal" and model.time_input == "phase"
    assert relative_rmse(model, unseen) <= 0.10


@pytest.mark.slow
def test_the_default_prior_mean_costs_field_accuracy_but_stays_bounded(data):
    """With the default mean-path prior the GP models the residual of a pull toward the demonstrations'
    mean path; off the training demonstrations that pull is not the field, and the error grows (measured
    0.19 here, against 0.04 without it; README, "How the defaults were chosen"). It must stay a
    correction of the field, not replace it."""
    train, unseen = data
    with_prior = relative_rmse(train_model(train), unseen)
    assert with_prior <= 0.35
