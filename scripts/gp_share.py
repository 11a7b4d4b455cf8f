"""What the GP's residual field adds where dynamics should matter most (issue 35; docs/defaults.md).

    .venv/bin/python scripts/gp_share.py ../shared/realdata/hand_raise_csv [more folders] [--folds 5]

Two cases, each measured with the full model and with the same fit's GP switched off
(:meth:`rbgp_cli.dynamics.model.MotionModel.without_residual`: the path distribution alone):

* **pushed off its path mid-way.** For each held-out demonstration (K folds, seeded as crossval's) and
  each phase s0 in 0.3, 0.5, 0.7: its pose at s0 displaced by ``--push`` metres in a seeded random
  direction (and as many tenths of a radian about a random axis), rolled out from there at phase s0
  for the rest of the demonstration's duration, the reference path conditioned on the demonstration's
  own start (as a robot that saw the motion begin knows it); scored against the demonstration's
  remainder: position and rotation RMSE over the remainder, and the final pose's error.
* **far starts.** The demonstrations whose starts lie farthest from the others' (Mahalanobis distance
  of the six start coordinates, the top ``--far`` fraction) are held out together and the model is
  trained on the rest: every held-out start lies outside the demonstrated start region. Each is rolled
  out from its own start for its own duration; position / rotation RMSE on normalised time, as crossval.

Prints one table per set; ``--json FILE`` writes the numbers.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from rbgp_cli.dynamics.model import train_model  # noqa: E402
from rbgp_cli.dynamics.rollout import rollout_for  # noqa: E402
from rbgp_cli.evaluation.crossval import make_folds, trajectory_errors  # noqa: E402
from rbgp_cli.geometry.so3 import exp_quat, log_quat, quat_conjugate, quat_multiply  # noqa: E402
from rbgp_cli.dynamics.trajectory import interpolate_poses  # noqa: E402
from rbgp_cli.workflows import load_demonstrations  # noqa: E402

PHASES = (0.3, 0.5, 0.7)


def pushed_rollout(model, demo, s0: float, push: float, rng):
    """Roll ``model`` out from ``demo``'s pose at phase s0 displaced by ``push`` m (and push/10 rad),
    for the rest of its duration at the model's rollout step; returns (t, quat, pos) of the rollout
    and the demonstration's poses at the same times."""
    D = demo.duration
    t0 = demo.t[0]
    q_s, p_s = interpolate_poses(demo.t - t0, demo.quat, demo.position, np.array([s0 * D]))
    u = rng.normal(size=3)
    u /= np.linalg.norm(u)
    a = rng.normal(size=3)
    a /= np.linalg.norm(a)
    q_start = quat_multiply(exp_quat((push / 10.0) * a)[None], q_s)
    p_start = p_s + push * u
    dt = model.rollout_dt
    steps = max(1, int(round((1.0 - s0) * D / dt)))
    X = model.initial_state(q_start, p_start)
    if model.time_input == "phase":
        X[:, -1] = s0
    dev = model.start_deviation(demo.quat[:1], demo.position[:1])
    step = model.phase_step(np.array([D]), dt)
    dur = np.array([[D]])
    states = [X]
    for _ in range(steps):
        mu = model.predict_output(X, start_dev=dev, step=step)
        X = model.advance(X, mu, dt, dur)
        states.append(X)
    S = np.concatenate(states)
    q, p = model.representation.pose_from_state(S[:, : model.pose_dims])
    t = s0 * D + dt * np.arange(steps + 1)
    qd, pd = interpolate_poses(demo.t - t0, demo.quat, demo.position, np.minimum(t, D))
    return q, p, qd, pd


def pose_errors(q, p, qd, pd):
    dq = quat_multiply(quat_conjugate(qd), q)
    ang = np.linalg.norm(log_quat(dq), axis=-1)
    dp = np.linalg.norm(p - pd, axis=-1)
    return float(np.sqrt(np.mean(dp**2))), float(np.sqrt(np.mean(ang**2))), float(dp[-1]), float(ang[-1])


def off_path(demos, folds: int, push: float, seed: int) -> dict:
    rows = {"with the GP": [], "without the GP": []}
    for f, test_idx in enumerate(make_folds(len(demos), folds, seed)):
        held = set(test_idx.tolist())
        train = [d for i, d in enumerate(demos) if i not in held]
        model = train_model(train)
        prior = model.without_residual()
        for i in test_idx:
            for s0 in PHASES:
                for name, m in (("with the GP", model), ("without the GP", prior)):
                    rng = np.random.default_rng([seed, int(i), int(s0 * 10)])  # the same push for both
                    rows[name].append(pose_errors(*pushed_rollout(m, demos[i], s0, push, rng)))
        print(f"  off-path fold {f + 1}/{folds}", file=sys.stderr, flush=True)
    return {k: np.sqrt(np.mean(np.square(v), axis=0)).tolist() for k, v in rows.items()}


def far_starts(demos, fraction: float) -> dict:
    S = np.array([np.concatenate([log_quat(d.quat[0]), d.position[0]]) for d in demos])
    C = np.cov(S.T) + 1e-12 * np.eye(6)
    diff = S - S.mean(axis=0)
    m2 = np.einsum("ij,jk,ik->i", diff, np.linalg.inv(C), diff)
    k = max(2, int(round(fraction * len(demos))))
    far = np.argsort(m2)[-k:]
    train = [d for i, d in enumerate(demos) if i not in set(far.tolist())]
    test = [demos[i] for i in far]
    model = train_model(train)
    out = {"held_out": int(k), "mahalanobis": np.sqrt(m2[far]).round(2).tolist()}
    for name, m in (("with the GP", model), ("without the GP", model.without_residual())):
        res = rollout_for(m, np.array([d.quat[0] for d in test]), np.array([d.position[0] for d in test]),
                          [d.duration for d in test], with_std=False)
        gen = res.trajectories()[: len(test)]
        sp, sr, n = trajectory_errors(gen, test, 100)
        left = 0 if res.outside is None else int(np.sum(np.any(res.outside, axis=1)))
        out[name] = [float(np.sqrt(sp / n)), float(np.sqrt(sr / n)), left]
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("folders", nargs="+")
    ap.add_argument("--folds", type=int, default=5)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--push", type=float, nargs="*", default=[0.05])
    ap.add_argument("--far", type=float, default=0.2)
    ap.add_argument("--json")
    args = ap.parse_args(argv)
    out = {}
    for folder in args.folders:
        demos, _, _ = load_demonstrations([folder])
        name = Path(folder.rstrip("/")).name
        res = {"far": far_starts(demos, args.far)}
        for push in args.push:
            res[f"push {push}"] = off_path(demos, args.folds, push, args.seed)
        out[name] = res
        print(f"{name} ({len(demos)} demonstrations)")
        far = res["far"]
        print(f"  far starts ({far['held_out']} held out, Mahalanobis {min(far['mahalanobis'])}–{max(far['mahalanobis'])}):"
              f" position / rotation RMSE with the GP {far['with the GP'][0]:.4f} m / {far['with the GP'][1]:.4f} rad,"
              f" without {far['without the GP'][0]:.4f} / {far['without the GP'][1]:.4f}; left the envelope"
              f" {far['with the GP'][2]} / {far['without the GP'][2]}")
        for push in args.push:
            r = res[f"push {push}"]
            w, wo = r["with the GP"], r["without the GP"]
            print(f"  pushed {push} m at phase 0.3/0.5/0.7: remainder RMSE with the GP {w[0]:.4f} m / {w[1]:.4f} rad,"
                  f" final {w[2]:.4f} m / {w[3]:.4f} rad; without {wo[0]:.4f} / {wo[1]:.4f}, final {wo[2]:.4f} / {wo[3]:.4f}",
                  flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
