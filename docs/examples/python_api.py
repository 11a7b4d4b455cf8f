"""rbgp from Python, notebook style: read, train, roll out (mean and samples), evaluate, crossvalidate.

Run it from the repository: ``python docs/examples/python_api.py`` (about half a minute on a laptop).
Uses only the public API of ``rbgp_cli``; the options are small ones for speed. Poses everywhere are
quaternions x, y, z, w, positions in metres, times in seconds.

The cells sit in ``main()`` under ``if __name__ == "__main__"``: crossval runs its folds in worker
processes, which start by importing the script (in a notebook, run the cells as they are).
"""

import numpy as np

import rbgp_cli as rbgp

FAST = dict(max_points=150, restarts=1, share_hyperparameters=True)  # fast options for the example


def main() -> dict:
    """Run every cell; returns what they made (for the test)."""
    # %% Read the bundled demonstrations (nine shoe-placing motions, CSV)
    demos = rbgp.read_demonstrations(rbgp.SAMPLE_DATA / "csv")
    print(f"{len(demos)} demonstrations, {sum(len(d) for d in demos)} samples, "
          f"median duration {np.median([d.duration for d in demos]):.2f} s")

    # %% Train: the options of `rbgp train` (FAST: few points, one optimiser start)
    gp = rbgp.RigidBodyGP(**FAST).fit(demos)
    print(f"trained on {gp.summary_['points']} points, outputs {', '.join(gp.output_names_)}, step {gp.dt_:.3f} s")

    # %% Velocity at the first demonstration's poses
    mean, std = gp.predict(demos[0], return_std=True)
    print(f"predicted velocity at {len(mean)} poses, mean |std| {np.mean(std):.4f}")

    # %% Roll out from the first three demonstrations' starts, with 5 sampled rollouts each
    res = gp.rollout(demos[:3], samples=5, seed=0)
    print(f"rollout: {res.count} mean trajectories of {len(res.t)} steps, samples {res.sample_quat.shape}")
    frame = res.to_frame()
    print(f"as a table: {len(frame)} rows, columns {', '.join(frame.columns[:10])}, ...")

    # %% Score mean rollouts from the demonstrations' starts (two each) against the demonstrations
    starts = np.array([np.r_[d.quat[0], d.position[0]] for d in demos])
    gen = gp.rollout(np.repeat(starts, 2, axis=0), return_std=False)
    score = rbgp.evaluate(gen, demos)
    print(f"bhattacharyya mean {score.mean:.3f} (rotation {score.rotation:.3f}, translation {score.translation:.3f}); "
          f"{score.left_data['count']} of {score.left_data['of']} left the demonstrations' envelope")

    # %% Cross-validate by demonstration: 3 folds, against the replay peer
    cv = rbgp.crossval(demos, rbgp.RigidBodyGP(**FAST), folds=3, samples=0)
    table = cv.to_frame()
    print(table[["representation", "score", "floor", "ratio"]].to_string(index=False))
    return {"demos": demos, "gp": gp, "mean": mean, "std": std, "rollout": res, "score": score, "crossval": cv}


if __name__ == "__main__":
    main()
