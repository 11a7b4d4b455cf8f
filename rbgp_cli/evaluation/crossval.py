"""Held-out quality: cross-validation by demonstration (``rbgp crossval``).

The product is only as good as the motions it generates from start poses it has not seen. For K
folds of the demonstrations (seeded; a demonstration is never split across folds), each fold:

1. trains a model on the other folds (exactly the options of ``rbgp train``);
2. rolls out one trajectory from each held-out demonstration's own start pose for its own duration;
3. **score**: the Bhattacharyya distance (docs/method.md §9) of the generated set against the *training*
   demonstrations; **floor**: the same for the held-out demonstrations themselves (same counts, same
   resampling length, same training set): what a fresh real demonstration scores; ``offset`` and
   ``spread`` (and ``floor_offset``, ``floor_spread``, ``sample_offset``, ``sample_spread``) are the
   score's two terms (docs/method.md §9): the generated set's mean away from the demonstrations', and
   its spread unlike theirs;
4. **left_data**: how many generated trajectories leave the training demonstrations' envelope
   (:mod:`rbgp_cli.dynamics.envelope`; ``floor_left_data``: how many held-out demonstrations do);
5. **trajectory errors**: each generated trajectory against the held-out demonstration that starts
   where it starts, on normalised time (T steps, slerp / linear): position RMSE (m) and rotation
   RMSE (rad, the angle of R_genᵀ R_demo);
6. **sampled rollouts** (``samples`` K per start): ``sample_score``, the score of a set of one sample
   per held-out start, as the floor is scored, averaged over the K such sets (``sample_score_one``:
   the first set alone); the coverage of each held-out motion by the 90 % band rbgp gives with its
   samples (the next motion's predictive region around the mean rollout,
   :func:`rbgp_cli.evaluation.coverage.band_coverage`), for a peer without one by its samples' 90 %
   regions;
7. **velocity RMSE** on the held-out training pairs (estimated exactly as the model's training pairs
   were), with each prediction mapped to a world-frame twist (ω, v): ``velocity_rmse`` is the relative
   error √((Σ‖Δω‖²/Σ‖ω‖² + Σ‖Δv‖²/Σ‖v‖²)/2) (1 = no better than predicting zero), with the raw
   parts in rad/s and m/s.

The **replay** peer needs no model: the training demonstration whose start pose is nearest (weighted
chordal SE(3) distance, ρ1 = 0.7) moved rigidly so that it begins at the new start,
T_new(t) = T_start_new · T_start_demo⁻¹ · T_demo(t). The **promp** and **dmp** peers (the field's own
library, optional) are in :mod:`rbgp_cli.evaluation.peers`; their ``train_s`` is their fitting time.

Overall numbers: score, floor, rotation and translation parts are means over folds (the ratio is
score / floor of those means); trajectory and velocity errors are pooled over all held-out
demonstrations, and so are the coverages, each with its standard error over the held-out demonstrations
(``coverage_position_se``, ``coverage_rotation_se``: :func:`rbgp_cli.evaluation.coverage.coverage_se`, a
demonstration held out by several splits counted once); ``train_s`` is the mean training time per fold.

**Paired comparisons.** Every row also keeps its trajectory errors per held-out demonstration
(``per_motion``: its index in the input order, its name, and its position and rotation RMSE
sqrt(sum / count) on the same normalised time grid). Since every row is scored on the same held-out
motions, two rows differ by more than chance only if their per-motion differences do: each row has a
``paired`` comparison with the reference row (the best ranked rbgp model row with its GP), the mean
difference d̄ of per-motion RMSE (row − reference), its standard error s_d/√n, z = d̄ / (s_d/√n) (the
paired t statistic) and the number of motions on which the row is closer (:func:`paired_difference`).

**Repeats** (``repeats`` R > 1): the K folds are drawn again from R seeds (seed, seed + 1, …) and every
configuration runs on all R × K splits; the overall numbers are over all of them, and ``by_repeat``
gives each repetition's own score, floor, ratio and sample ratio. One set of folds can mislead: on the
40 hand raises the floor moved from 0.17 to 0.38 with the fold seed alone, because a take held out at
random has its neighbours in time in the training set (docs/defaults.md).

Folds of every configuration run as independent tasks, in worker processes with single-threaded BLAS
(``jobs``), or in this process (``jobs=1``); results do not depend on ``jobs``.
"""

from __future__ import annotations

import copy
import math
import time
import warnings
from dataclasses import dataclass, field

import numpy as np

from rbgp_cli.compute import usable_cores
from rbgp_cli.dynamics.envelope import envelope_from_demos, left_envelope
from rbgp_cli.dynamics.trajectory import Trajectory
from rbgp_cli.errors import InputError, warn
from rbgp_cli.progress import as_progress
from rbgp_cli.wording import plural
from rbgp_cli.evaluation.bhattacharyya import evaluate
from rbgp_cli.evaluation.peers import PEERS, PROMP
from rbgp_cli.evaluation.resample import resample_all
from rbgp_cli.geometry.so3 import quat_conjugate, quat_multiply, rotate

__all__ = [
    "Config",
    "make_folds",
    "make_splits",
    "forward_splits",
    "split_info",
    "repeated_splits",
    "splits_text",
    "ORDERS",
    "FIXED_ORDERS",
    "replay_nearest",
    "nearest_index",
    "trajectory_errors",
    "per_motion_errors",
    "paired_difference",
    "velocity_errors",
    "run_fold",
    "sample_seed",
    "crossval",
    "REPLAY",
]

#: The representation name of the replay peer row.
REPLAY = "replay"
#: Rotation weight of the start-pose distance that picks the demonstration to replay.
REPLAY_RHO = 0.7


@dataclass(frozen=True)
class Config:
    """One row of the table: a representation and kernel (or the replay peer) and train options;
    ``options``: the options a ``--grid`` set for this row ({CLI name: value}), ``label`` its name."""

    representation: str
    kernel: str | None = None
    train: dict = field(default_factory=dict)
    label: str = ""
    options: dict = field(default_factory=dict)

    @property
    def name(self) -> str:
        if self.label:
            return self.label
        return self.representation if self.kernel is None else f"{self.representation} {self.kernel}"


#: How crossval holds demonstrations out: a seeded random permutation, contiguous blocks in recording
#: order (the order the demonstrations were read: docs/data.md, "Recording order"), or those blocks each
#: predicted from the blocks before it only ("forward": the next session's case, :func:`forward_splits`).
ORDERS = ("random", "recorded", "forward")
#: The orders whose splits do not depend on the fold seed (so ``repeats`` must be 1).
FIXED_ORDERS = ("recorded", "forward")


def make_folds(n: int, k: int, seed: int = 0, order: str = "random") -> list[np.ndarray]:
    """Held-out demonstration indices of ``k`` folds of ``n`` demonstrations, split into k parts whose
    sizes differ by at most one (each part sorted); every index is held out exactly once.
    ``order="random"``: the parts of a seeded permutation; ``"recorded"`` (and ``"forward"``, whose
    blocks they are): contiguous blocks in recording order (0 … n/k − 1, …; the seed is not used), so
    that a block's neighbours in time are not in its training set, as for the next session's
    demonstrations."""
    if order not in ORDERS:
        raise InputError(f"order {order!r} is unknown; expected one of {', '.join(ORDERS)}", param="order")
    if k < 2:
        raise InputError(f"folds must be at least 2, got {k}", param="folds")
    if n < k:
        raise InputError(f"{n} demonstrations cannot make {k} folds", hint=f"use folds {max(2, n)} or fewer"
                         if n >= 2 else "cross-validation needs at least 2 demonstrations", param="folds")
    if order in FIXED_ORDERS:
        return [part.copy() for part in np.array_split(np.arange(n), k)]
    perm = np.random.default_rng(np.random.SeedSequence([int(seed), 2024])).permutation(n)
    return [np.sort(part) for part in np.array_split(perm, k)]


def repeated_splits(n: int, k: int, seed: int = 0, order: str = "random", train_size: int | None = None,
                    repeats: int = 1) -> list[tuple[np.ndarray, np.ndarray]]:
    """:func:`make_splits` drawn ``repeats`` times, from the fold seeds seed, seed + 1, …, seed + R − 1,
    repetition by repetition (k splits each; the training demonstrations keep their recording order).
    Refuses (InputError) a repeats that is not a whole number ≥ 1, an unknown ``order``, and repeats with
    ``order="recorded"`` or ``"forward"``, whose folds are the same on every repeat."""
    if isinstance(repeats, bool) or not isinstance(repeats, (int, np.integer)) or repeats < 1:
        raise InputError(f"repeats must be a whole number of at least 1, got {repeats!r}", param="repeats")
    if order not in ORDERS:
        raise InputError(f"order {order!r} is unknown; expected one of {', '.join(ORDERS)}", param="order")
    if order in FIXED_ORDERS and repeats > 1:
        raise InputError("folds in recording order are the same on every repeat",
                         hint=f"use repeats 1 with order {order} (or order random)", param="repeats")
    return [sp for r in range(int(repeats)) for sp in make_splits(n, k, int(seed) + r, order, train_size)]


def make_splits(n: int, k: int, seed: int = 0, order: str = "random", train_size: int | None = None
                ) -> list[tuple[np.ndarray, np.ndarray]]:
    """(training, held-out) demonstration indices of ``k`` splits of ``n`` demonstrations, each sorted.

    Without ``train_size``: the folds of :func:`make_folds` held out, the rest trained on. With
    ``train_size`` N ("train on N, test on the rest", a small study): ``order="random"`` trains on k
    seeded random subsets of N and holds out all the others; ``"recorded"`` trains on k windows of N
    consecutive demonstrations (starts spread evenly from the first to the last that leaves two after
    it, where there are two) and holds out every demonstration recorded after the window (later predicted from earlier).

    ``order="forward"``: the k blocks of ``"recorded"``, each after the first predicted from the
    demonstrations before it only (:func:`forward_splits`: all of them, or with ``train_size`` N the N just
    before it); a block with too few before it is skipped with a warning (RbgpWarning), and none left is
    an InputError."""
    if order == "forward":
        splits, skipped = forward_splits(n, k, train_size)
        later = skipped[1:]  # the first block has nothing before it: it only trains, always
        if later:
            warn(f"forward folds: {plural(len(later), 'block')} after the first not predicted (demonstrations "
                 f"{'; '.join(_ranges(b) for b in later)}, 1-based): fewer than {_forward_minimum(train_size)} "
                 f"demonstrations recorded before {'it' if len(later) == 1 else 'them'}", param="folds")
        return splits
    if train_size is None:
        folds = make_folds(n, k, seed, order)
        return [(np.setdiff1d(np.arange(n), f), f) for f in folds]
    if order not in ORDERS:
        raise InputError(f"order {order!r} is unknown; expected one of {', '.join(ORDERS)}", param="order")
    N = int(train_size)
    if k < 1:
        raise InputError(f"folds must be at least 1, got {k}", param="folds")
    if N < 2 or N > n - 1:
        raise InputError(f"train_size {N} does not leave demonstrations to hold out of {n}"
                         if N >= 2 else f"train_size must be at least 2, got {N}",
                         hint=f"use train_size between 2 and {max(2, n - 1)}", param="train_size")
    if order == "recorded":
        starts = np.unique(np.round(np.linspace(0, max(0, n - N - 2), k)).astype(int))  # ≥ 2 held out where possible
        return [(np.arange(j, j + N), np.arange(j + N, n)) for j in starts]
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 2025]))
    from math import comb

    if comb(n, N) < int(k):  # distinct subsets: as many as there are (9 choose 8: 9)
        warn(f"train_size {N} of {n} demonstrations makes {comb(n, N)} distinct subsets, not {int(k)}: "
             f"{comb(n, N)} splits", param=("train_size", "folds"))
        k = comb(n, N)
    out, seen = [], set()
    while len(out) < k:  # a subset drawn before is drawn again (the same draws as before where none repeats)
        train = np.sort(rng.choice(n, size=N, replace=False))
        if tuple(train) in seen:
            continue
        seen.add(tuple(train))
        out.append((train, np.setdiff1d(np.arange(n), train)))
    return out


def _forward_minimum(train_size: int | None) -> int:
    """The fewest demonstrations a forward split may train on: the path distribution's minimum
    (:data:`~rbgp_cli.dynamics.paths.MIN_PATH_DEMOS`), or the window ``train_size`` itself."""
    from rbgp_cli.dynamics.paths import MIN_PATH_DEMOS

    return MIN_PATH_DEMOS if train_size is None else int(train_size)


def forward_splits(n: int, k: int, train_size: int | None = None
                   ) -> tuple[list[tuple[np.ndarray, np.ndarray]], list[np.ndarray]]:
    """Forward-chaining splits in recording order: the ``k`` contiguous blocks B₁ … B_k of
    :func:`make_folds` (``order="recorded"``), and for each block B_j (j ≥ 2) that starts at index s_j the
    split (training, held out) = ({0, …, s_j − 1}, B_j) (an expanding window), or with ``train_size`` N
    ({s_j − N, …, s_j − 1}, B_j) (a sliding window of the N just before it). Every training index is
    smaller than every held-out one. A block with fewer than m demonstrations before it (m =
    MIN_PATH_DEMOS, the path distribution's minimum, or N) is skipped; B₁ always is.

    Returns (splits, skipped): the splits in block order (each array sorted) and the skipped blocks'
    indices (B₁ first). InputError: an unknown size (N < MIN_PATH_DEMOS or N ≥ n), and no block left."""
    from rbgp_cli.dynamics.paths import MIN_PATH_DEMOS

    blocks = make_folds(n, k, order="forward")
    if train_size is not None:
        N = int(train_size)
        if N < MIN_PATH_DEMOS or N > n - 1:
            raise InputError(f"train_size {N} does not leave demonstrations to hold out of {n}" if N >= MIN_PATH_DEMOS
                             else f"forward folds train on at least {MIN_PATH_DEMOS} demonstrations (the path "
                                  f"distribution's minimum), got train_size {N}",
                             hint=f"use train_size between {MIN_PATH_DEMOS} and {max(MIN_PATH_DEMOS, n - 1)}",
                             param="train_size")
    m = _forward_minimum(train_size)
    splits, skipped = [], [blocks[0]]
    for block in blocks[1:]:
        s = int(block[0])
        if s < m:
            skipped.append(block)
            continue
        splits.append((np.arange(0 if train_size is None else s - m, s), block))
    if not splits:
        fits = [j for j in range(2, n + 1) if n - n // j >= m]  # the last block, the smallest, starts at n − ⌊n/k⌋
        raise InputError(f"forward folds need {m} demonstrations recorded before a block; {n} in {k} blocks "
                         "leave none", param="folds",
                         hint=(f"use folds {fits[0]} or more" if fits else
                               f"forward folds need more than {m} demonstrations"))
    return splits, skipped


def split_info(n: int, k: int, order: str = "random", train_size: int | None = None) -> dict:
    """What a result says about its splits beyond the splits themselves: with ``order="forward"``
    ``{"blocks": k, "skipped_blocks": [[indices], ...]}`` (the blocks never held out, 0-based, the first
    always among them: :func:`forward_splits`); otherwise {}."""
    if order != "forward":
        return {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        _, skipped = forward_splits(n, k, train_size)
    return {"blocks": int(k), "skipped_blocks": [b.tolist() for b in skipped]}


def _ranges(idx) -> str:
    """Indices (0-based, sorted) as 1-based runs: [0, 1, 2, 5] → "1–3, 6"."""
    idx = [int(i) + 1 for i in idx]
    runs, start = [], None
    for j, i in enumerate(idx):
        if start is None:
            start = i
        if j + 1 == len(idx) or idx[j + 1] != i + 1:
            runs.append(f"{start}" if start == i else f"{start}–{i}")
            start = None
    return ", ".join(runs)


def splits_text(result: dict, limit: int = 6) -> str:
    """One line saying which demonstrations (1-based, in recording order) each split trained on and held
    out, from :func:`crossval`'s result (its ``order``, ``train_size`` and ``splits``)."""
    splits = result.get("splits") or []
    order, size = result.get("order", "random"), result.get("train_size")
    if order == "forward":
        head = ("forward in recording order, each block predicted from every demonstration before it" if size is None
                else f"forward in recording order, each block predicted from the {size} just before it")
        parts = [f"{_ranges(sp['train'])} → {_ranges(sp['test'])}" for sp in splits[:limit]]
        skipped = result.get("skipped_blocks") or []
        more = f"; and {len(splits) - limit} more" if len(splits) > limit else ""
        return (f"splits: {head}: " + "; ".join(f"[{p}]" for p in parts) + more
                + (f" (not predicted: {'; '.join(f'[{_ranges(b)}]' for b in skipped)})" if skipped else ""))
    if size is None:
        head = ("held out in contiguous blocks in recording order" if order == "recorded"
                else f"held out at random (fold seed {result.get('seed', 0)})")
        parts = [_ranges(sp["test"]) for sp in splits[:limit]]
    else:
        head = (f"trained on {size} consecutive, the later ones held out" if order == "recorded"
                else f"trained on {size} at random, the rest held out")
        parts = [f"{_ranges(sp['train'])} → {len(sp['test'])} held out" for sp in splits[:limit]]  # a count: not "4"
    more = f"; and {len(splits) - limit} more" if len(splits) > limit else ""
    return f"splits: {head}: " + "; ".join(f"[{p}]" for p in parts) + more


# --------------------------------------------------------------------------------------------- peers
def nearest_index(train: list[Trajectory], quat0: np.ndarray, pos0: np.ndarray, rho_rot: float = REPLAY_RHO) -> int:
    """Index of the training demonstration whose start pose is nearest to (quat0, pos0):
    d² = ρ1·d_ch² + (1 − ρ1)·‖Δp‖² (chordal rotation distance d_ch = 2·sqrt(1 − ⟨q1, q2⟩²), docs/method.md §5)."""
    starts_q = np.array([tr.quat[0] for tr in train])
    starts_p = np.array([tr.position[0] for tr in train])
    c = np.clip(np.abs(starts_q @ quat0), 0.0, 1.0)
    d2 = rho_rot * 4.0 * (1.0 - c * c) + (1.0 - rho_rot) * np.sum((starts_p - pos0) ** 2, axis=1)
    return int(np.argmin(d2))


def replay_nearest(train: list[Trajectory], quat0: np.ndarray, pos0: np.ndarray, rho_rot: float = REPLAY_RHO) -> Trajectory:
    """The training demonstration with the nearest start pose, moved rigidly to start at (quat0, pos0).

    Nearest by d² = ρ1·d_ch² + (1 − ρ1)·‖Δp‖² (chordal rotation distance d_ch = 2·sqrt(1 − ⟨q1, q2⟩²),
    docs/method.md §5). The motion is carried by the rigid transform that maps the demonstration's start pose
    onto the new one: R(t) ↦ R_s' R_sᵀ R(t), p(t) ↦ R_s' R_sᵀ (p(t) − p_s) + p_s'.
    """
    src = train[nearest_index(train, quat0, pos0, rho_rot)]
    dq = quat_multiply(quat0, quat_conjugate(src.quat[0]))  # R_s' R_sᵀ
    q = quat_multiply(np.broadcast_to(dq, src.quat.shape), src.quat)
    p = rotate(np.broadcast_to(dq, src.quat.shape), src.position - src.position[0]) + pos0
    return Trajectory(src.t - src.t[0], q, p, name=f"replay of {src.name}")


# --------------------------------------------------------------------------------------------- errors
def _step_errors(generated: list[Trajectory], reference: list[Trajectory], T: int) -> tuple[np.ndarray, np.ndarray]:
    """Per step of ``T`` of normalised time, paired trajectories' position differences p_gen − p_ref
    (M, T, 3) in m and rotation angles ∠(R_refᵀ R_gen) (M, T) in rad."""
    qg, pg = resample_all(generated, T)  # (M, T, 4), (M, T, 3)
    qr, pr = resample_all(reference, T)
    dq = quat_multiply(quat_conjugate(qr), qg)
    ang = 2.0 * np.arctan2(np.linalg.norm(dq[..., :3], axis=-1), np.abs(dq[..., 3]))
    return pg - pr, ang


def trajectory_errors(generated: list[Trajectory], reference: list[Trajectory], T: int) -> tuple[float, float, int]:
    """Sums of squared position (m²) and rotation (rad²) errors between paired trajectories resampled
    to ``T`` steps of normalised time, and the number of steps summed. RMSE = sqrt(sum / count)."""
    dp, ang = _step_errors(generated, reference, T)
    return float(np.sum(dp**2)), float(np.sum(ang**2)), int(ang.shape[0] * T)


def per_motion_errors(generated: list[Trajectory], reference: list[Trajectory], T: int
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`trajectory_errors` per pair: for each of the M paired trajectories, the sums over its
    ``T`` steps of normalised time of the squared position errors ‖p_gen − p_ref‖² (m², shape (M,)) and
    rotation errors ∠(R_refᵀ R_gen)² (rad², (M,)), and the steps summed (M,) (each T). Motion m's RMSE
    is sqrt(sum_m / count_m); the pooled RMSE sqrt(Σ sum / Σ count) is :func:`trajectory_errors`'."""
    dp, ang = _step_errors(generated, reference, T)
    return np.sum(dp**2, axis=(1, 2)), np.sum(ang**2, axis=1), np.full(ang.shape[0], int(T))


def velocity_errors(model, demos: list[Trajectory]) -> dict:
    """Squared-error sums of the model's world-frame twist predictions on the held-out pairs of
    ``demos`` (made with the model's own velocity estimator), and the sums of the pairs' squares."""
    from rbgp_cli.dynamics.velocities import estimate_velocities

    rep = model.representation
    sums = {"dw2": 0.0, "dv2": 0.0, "w2": 0.0, "v2": 0.0, "pairs": 0}
    states, quats, xis, scale, devs, steps = [], [], [], [], [], []
    for tr in demos:
        D = max(tr.duration, 1e-9)
        dev = model.start_deviation(tr.quat[:1], tr.position[:1])  # its own start (a conditioned prior)
        for seg in estimate_velocities(tr, model.velocity):
            K = len(seg.xi)
            X = rep.state_along(seg.traj.quat, seg.traj.position)[:K]
            tau = seg.traj.t[:K] - seg.t0
            if model.time_input == "phase":
                X = np.concatenate([X, tau[:, None] / D], axis=1)
            elif model.time_input == "seconds":
                X = np.concatenate([X, tau[:, None]], axis=1)
            states.append(X)
            quats.append(seg.traj.quat[:K])
            xis.append(seg.xi)
            scale.append(np.full(K, D if model.time_input == "phase" else 1.0))
            steps.append(np.diff(seg.traj.t)[:K] / D)  # each pair's phase step (a secant feed-forward's)
            if dev is not None:
                devs.append(np.repeat(dev, K, axis=0))
    if not states:
        return sums
    X, Q, XI = np.concatenate(states), np.concatenate(quats), np.concatenate(xis)
    # a secant feed-forward (forward differences over phase, by construction): each pair's own step
    step = np.concatenate(steps) if model.phase_step() is not None else None
    out = model.predict_output(X, start_dev=np.concatenate(devs) if devs else None, step=step) / np.concatenate(scale)[:, None]  # per second
    tw = rep.twist_from_output(X[:, : model.pose_dims], Q, out)
    sums["dw2"] = float(np.sum((tw[:, :3] - XI[:, :3]) ** 2))
    sums["dv2"] = float(np.sum((tw[:, 3:] - XI[:, 3:]) ** 2))
    sums["w2"] = float(np.sum(XI[:, :3] ** 2))
    sums["v2"] = float(np.sum(XI[:, 3:] ** 2))
    sums["pairs"] = int(len(X))
    return sums


# --------------------------------------------------------------------------------------------- one fold
#: Sampled rollouts per held-out start for the sample columns (docs/method.md §11: K = 20).
SAMPLES = 20


def sample_seed(seed: int, fold: int, repeat: int = 0) -> int:
    """The seed of fold ``fold``'s sampled rollouts (of repetition ``repeat``): one stream per fold (from
    the train options' seed), so that the folds' draws are independent of each other instead of the
    same normal numbers again."""
    key = [int(seed), 8311, int(fold)] + ([int(repeat)] if repeat else [])
    return int(np.random.SeedSequence(key).generate_state(1)[0])


def _generate(config: Config, train: list[Trajectory], test: list[Trajectory], samples: int = 0, fold: int = 0,
              repeat: int = 0):
    """Generated trajectories (one per held-out demonstration), training seconds, the model or None,
    and per held-out start its ``samples`` sampled rollouts (a list of lists; None for the replay peer or
    without samples), seeded by :func:`sample_seed` of the fold and repetition."""
    if config.representation == REPLAY:
        return [replay_nearest(train, tr.quat[0], tr.position[0]) for tr in test], 0.0, None, None
    if config.representation in PEERS:  # ProMP / DMP from movement-primitives (rbgp_cli.evaluation.peers)
        from rbgp_cli.evaluation import peers

        run = peers.promp_rollouts if config.representation == PROMP else peers.dmp_rollouts
        starts = ([tr.quat[0] for tr in test], [tr.position[0] for tr in test], [tr.duration for tr in test])
        t0 = time.perf_counter()
        gen = run(train, *starts)
        gen = [g.with_(name=f"{config.representation} from {tr.name}") for g, tr in zip(gen, test)]
        drawn = None  # the DMP is deterministic: no samples; the ProMP's are its conditioned distribution's
        if samples > 0 and config.representation == PROMP:
            drawn = peers.promp_samples(train, *starts, k=samples, seed=sample_seed(0, fold, repeat))
        return gen, time.perf_counter() - t0, None, drawn
    from rbgp_cli.dynamics.model import train_model

    t0 = time.perf_counter()
    model = train_model(train, representation=config.representation, kernel=config.kernel, **config.train)
    train_s = time.perf_counter() - t0
    gen, drawn = _model_rollouts(model, test, samples, sample_seed(config.train.get("seed", 0), fold, repeat))
    return gen, train_s, model, drawn


def _model_rollouts(model, test: list[Trajectory], samples: int, seed: int):
    """A model's mean rollout from each held-out start for its duration, named after it, and per start
    its ``samples`` sampled rollouts (None without samples)."""
    from rbgp_cli.dynamics.rollout import rollout_for

    q0 = np.array([tr.quat[0] for tr in test])
    p0 = np.array([tr.position[0] for tr in test])
    res = rollout_for(model, q0, p0, [tr.duration for tr in test], with_std=False,  # each its own duration
                      samples=samples, seed=seed)
    trajs = res.trajectories(include_samples=samples > 0)
    gen = [g.with_(name=f"from {tr.name}") for g, tr in zip(trajs[: len(test)], test)]
    gen = with_bands(gen, res)
    drawn = None
    if samples > 0:  # trajectories() lists the samples start by start after the means
        rest = trajs[len(test):]
        drawn = [rest[b * samples:(b + 1) * samples] for b in range(len(test))]
    return gen, drawn


def with_bands(gen: list[Trajectory], res) -> list[Trajectory]:
    """The mean trajectories ``gen`` of a rollout result ``res`` with its 90 % band (if it has one) in
    their ``info["band"]``: (position half-widths (n, 3), rotation regions (n, 3, 3)) on their own samples."""
    if getattr(res, "band_position", None) is None:
        return gen
    return [g.with_(info={"band": (res.band_position[b, :len(g.t)], res.band_rotation[b, :len(g.t)])})
            for b, g in enumerate(gen)]


def _sample_columns(drawn, train: list[Trajectory], test: list[Trajectory], T: int, covariance: str,
                    gen: list[Trajectory] | None = None) -> dict | None:
    """The variety and calibration columns of one fold (docs/method.md §11): ``sample_score``, a set of one
    sampled rollout per held-out start scored against the training demonstrations as ``score`` is
    (the mean over the K such sets, ``sample_scores`` each one's), and the coverage of each held-out
    motion by the band its mean trajectory in ``gen`` carries (``info["band"]``, :func:`with_bands`;
    :func:`rbgp_cli.evaluation.coverage.band_coverage`), else by its start's samples' 90 % regions
    (:func:`rbgp_cli.evaluation.coverage.prediction_coverage`); sums that pool over folds."""
    from rbgp_cli.evaluation.coverage import MIN_SAMPLES, Coverage, band_coverage, prediction_coverage

    if not drawn:
        return None
    # every sample index k makes a set of one sample per start; the score is their mean over the K
    # sets (the same expectation as one set's, without the luck of one draw: on 8 held-out hand raises
    # one set's score varies by ±25 % from draw to draw)
    sets = [evaluate([d[k] for d in drawn], train, length=T, covariance=covariance, sample_size="record")
            for k in range(min(len(d) for d in drawn))]
    each = []  # one Coverage per held-out motion, in the order of ``test``
    if gen is not None and all("band" in g.info for g in gen):
        each = [band_coverage(g, *g.info["band"], real, T) for g, real in zip(gen, test)]
    elif len(drawn[0]) >= MIN_SAMPLES:
        each = [prediction_coverage(d, real, T) for d, real in zip(drawn, test)]
    cov = sum(each, Coverage())
    scores = [float(e.mean) for e in sets]
    return {"sample_score": float(np.mean(scores)), "sample_offset": float(np.mean([e.offset for e in sets])),
            "sample_spread": float(np.mean([e.spread for e in sets])), "sample_scores": scores,
            "coverage": list(cov.astuple()),
            # (position inside, position count, rotation inside, rotation count) per held-out motion: the SEs
            "motion_coverage": [list(c.astuple()[:4]) for c in each]}


def run_fold(config: Config, train: list[Trajectory], test: list[Trajectory], *, length: int | None = None,
             covariance: str = "diag", samples: int = SAMPLES, fold: int = 0, repeat: int = 0,
             given: str | None = None) -> dict:
    """Train (unless replay), generate from the held-out starts, and score one fold (plain data);
    ``samples`` sampled rollouts per held-out start give the sample columns (0: none); ``fold`` and
    ``repeat`` its number and repetition (the samples' seed, :func:`sample_seed`); ``given="goal"``:
    each held-out demonstration's final pose and duration are given too
    (:mod:`rbgp_cli.evaluation.given_goal`), and the row has end errors."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        t0 = time.perf_counter()
        seed = sample_seed(config.train.get("seed", 0), fold, repeat)
        if given == "goal":
            from rbgp_cli.evaluation.given_goal import end_errors, generate_given_goal, model_goal_rollouts

            gen, train_s, model, drawn = generate_given_goal(config, train, test, samples, seed)
        else:
            gen, train_s, model, drawn = _generate(config, train, test, samples=samples, fold=fold, repeat=repeat)
        gen_s = time.perf_counter() - t0 - train_s
        out = _fold_scores(gen, drawn, model, train, test, length, covariance)
        out.update(train_s=train_s, rollout_s=gen_s)
        if given == "goal":
            out["end"] = end_errors(gen, test)
        if model is not None and model.mean:
            # the same fit with the GP's residual switched off: the path distribution alone, from the
            # same starts with the same draws (what the GP adds, issue 35)
            t0 = time.perf_counter()
            if _same_without_gp(model, samples, given):  # g = 0: the model's rows are already the path distribution's
                out["without_gp"] = {**copy.deepcopy(out), "rollout_s": time.perf_counter() - t0}
            else:
                prior = model.without_residual()
                gen0, drawn0 = (model_goal_rollouts if given == "goal" else _model_rollouts)(prior, test, samples, seed)
                out["without_gp"] = {**_fold_scores(gen0, drawn0, prior, train, test, length, covariance),
                                     "train_s": train_s, "rollout_s": time.perf_counter() - t0}
                if given == "goal":
                    out["without_gp"]["end"] = end_errors(gen0, test)
    warned = {str(w.message) for w in caught}
    out["warnings"] = sorted(warned | set(out["warnings"]))
    if "without_gp" in out:
        out["without_gp"]["warnings"] = out["warnings"]
    return out


def _same_without_gp(model, samples: int, given: str | None) -> bool:
    """Whether a fold's row without the GP would repeat its model row's computation: the residual's gain is
    g = 0 (:attr:`~rbgp_cli.dynamics.model.MotionModel.residual_off`: the mean velocity is the prior mean's
    either way, from the same starts, and the velocity errors with it) and the samples do not draw on the GP's
    std (the path distribution's draws, or none). Per-step Monte Carlo samples (a model without a variation
    model) draw from the GP's std, which the row without the GP replaces by the prior's."""
    if not getattr(model, "residual_off", False):
        return False
    return given == "goal" or samples == 0 or getattr(model, "variation", None) is not None


def _fold_scores(gen, drawn, model, train: list[Trajectory], test: list[Trajectory], length, covariance) -> dict:
    """One fold's columns for the generated trajectories ``gen`` (one per held-out demonstration) and
    their samples ``drawn``: the score and its parts, trajectory errors, the velocity errors of
    ``model`` (None for a peer), the sample columns and how many left the training envelope."""
    score = evaluate(gen, train, length=length, covariance=covariance, sample_size="record")
    T = score.steps
    mp, mr, mc = per_motion_errors(gen, test, T)  # the pooled sums are theirs (trajectory_errors')
    sp, sr, count = float(np.sum(mp)), float(np.sum(mr)), int(np.sum(mc))
    out = {
        "score": score.mean, "rotation": score.rotation, "translation": score.translation,
        "offset": score.offset, "spread": score.spread,
        "reliable": bool(getattr(score, "reliable", True)),
        "steps": T, "position_sq": sp, "rotation_sq": sr, "count": count,
        # per held-out demonstration, in the order of ``test`` (the fold's indices): the paired comparisons
        "motion_position_sq": mp.tolist(), "motion_rotation_sq": mr.tolist(), "motion_count": mc.tolist(),
        "velocity": velocity_errors(model, test) if model is not None else None,
        "left_data": left_envelope(gen, envelope_from_demos(train))["count"],
        "warnings": sorted(set(score.warnings)),
    }
    if model is not None:
        out["points"] = int(model.summary.get("points", 0))
        # the residual's gain the fold's training chose (and whether the full fit ran: issue 35's cheap fit)
        out["residual_gain"] = float(getattr(model, "residual_gain", 1.0))
        fit = (model.summary.get("residual_gain") or {}).get("fit")
        if fit is not None:
            out["full_fit"] = bool(fit.get("full_fit"))
    sampled = _sample_columns(drawn, train, test, T, covariance, gen)
    if sampled is not None:
        out.update(sampled)
    return out


def _task(args):
    config, train, test, length, covariance, samples, fold, repeat, given = args
    return run_fold(config, train, test, length=length, covariance=covariance, samples=samples, fold=fold,
                    repeat=repeat, given=given)


def _run_in_processes(args: list, n_jobs: int, label=None):
    """Yield (index, result) of ``_task(a)`` for every ``a`` in ``args`` as they finish, in ``n_jobs``
    worker processes (forked on Linux) with single-threaded BLAS that end with this process
    (:func:`rbgp_cli.compute.iter_processes`: on an error, Ctrl-C or SIGTERM the pending tasks are
    cancelled and the workers stopped; a lost worker's fits are run again once, then named)."""
    from rbgp_cli.compute import iter_processes

    return iter_processes(_task, args, n_jobs, label=label)


# --------------------------------------------------------------------------------------------- all folds
def _pooled_rmse(total: float, count: int) -> float:
    return math.sqrt(total / count) if count else float("nan")


def _velocity_summary(parts: list[dict]) -> dict:
    if not parts or any(p is None for p in parts):
        return {"velocity_rmse": None, "velocity_rmse_angular": None, "velocity_rmse_linear": None}
    s = {k: sum(p[k] for p in parts) for k in ("dw2", "dv2", "w2", "v2", "pairs")}
    if s["pairs"] == 0:
        return {"velocity_rmse": None, "velocity_rmse_angular": None, "velocity_rmse_linear": None}
    rel_w = s["dw2"] / s["w2"] if s["w2"] > 0 else float("nan")
    rel_v = s["dv2"] / s["v2"] if s["v2"] > 0 else float("nan")
    return {
        "velocity_rmse": math.sqrt(0.5 * (rel_w + rel_v)),
        "velocity_rmse_angular": math.sqrt(s["dw2"] / s["pairs"]),
        "velocity_rmse_linear": math.sqrt(s["dv2"] / s["pairs"]),
    }


def _per_motion(folds: list[np.ndarray], results: list[dict], names: list[str] | None = None,
                sources: list | None = None) -> list[dict] | None:
    """Per held-out demonstration (by its index in the input order, its ``name`` and, when it was read from
    a file, its ``source``: the name alone repeats across files, e.g. a BVH joint's): its position and
    rotation RMSE, sqrt(Σ sum / Σ count) over every split that held it out (one with a single set of
    folds; R with ``repeats`` R; those of its subsets with ``train_size``); sorted by index, the
    demonstrations never held out left out; with sampled coverage also its ``coverage_position`` and
    ``coverage_rotation`` (steps inside over steps scored, pooled over the same splits) and
    ``coverage_steps`` (the rotation's steps scored; the position's are three per step). None when the
    results carry no per-motion sums."""
    if not results or any("motion_count" not in r for r in results):
        return None
    sums: dict[int, np.ndarray] = {}
    covs: dict[int, np.ndarray] = {}
    with_cov = all(r.get("motion_coverage") for r in results)
    for test_idx, r in zip(folds, results):
        for i, a, b, c in zip(test_idx, r["motion_position_sq"], r["motion_rotation_sq"], r["motion_count"]):
            sums[int(i)] = sums.get(int(i), np.zeros(3)) + (a, b, c)
        if with_cov:
            for i, c in zip(test_idx, r["motion_coverage"]):
                covs[int(i)] = covs.get(int(i), np.zeros(4)) + np.asarray(c, dtype=np.float64)

    def coverage(i):
        if i not in covs:
            return {}
        a = covs[i]
        return {"coverage_position": float(a[0] / a[1]) if a[1] else None,
                "coverage_rotation": float(a[2] / a[3]) if a[3] else None, "coverage_steps": int(a[3])}

    return [{"index": i, **({"name": names[i]} if names is not None else {}), **motion_source(sources, i),
             "position_rmse": math.sqrt(v[0] / v[2]), "rotation_rmse": math.sqrt(v[1] / v[2]), **coverage(i)}
            for i, v in sorted(sums.items())]


def motion_source(sources: list | None, i: int | None) -> dict:
    """A per-motion row's {"source": the file demonstration i was read from}, or {} without ``sources``, without
    an index or when it has none (built in Python)."""
    return {"source": str(sources[i])} if sources is not None and i is not None and sources[i] is not None else {}


def paired_difference(reference, row) -> dict:
    """The paired comparison of a row's per-motion errors ``row`` with the reference row's ``reference``
    (two arrays (n,), the same n held-out motions in the same order, e.g. per-motion RMSEs).

    With dᵢ = rowᵢ − referenceᵢ: ``difference`` d̄ = Σdᵢ / n (negative: the row is closer on average),
    ``se`` = s_d / √n with s_d² = Σ(dᵢ − d̄)² / (n − 1), ``z`` = d̄ / se (the paired t statistic,
    ``scipy.stats.ttest_rel(row, reference).statistic``; |z| ≥ 2: a difference beyond the motions'
    own scatter at about 5 %, for n of 30 or more), ``closer`` = #{dᵢ < 0}, the motions on which the
    row is closer, and ``motions`` = n. ``se`` and ``z`` are None with n < 2 or s_d = 0."""
    a, b = np.asarray(reference, dtype=float), np.asarray(row, dtype=float)
    if a.shape != b.shape or a.ndim != 1:
        raise ValueError(f"paired_difference needs two arrays of the same length, got shapes {a.shape} and {b.shape}")
    d = b - a
    n = len(d)
    mean = float(np.mean(d)) if n else None
    se = float(np.std(d, ddof=1) / math.sqrt(n)) if n > 1 else None
    ok = se is not None and se > 0
    return {"difference": mean, "se": se if ok else None, "z": mean / se if ok else None,
            "closer": int(np.sum(d < 0)), "motions": int(n)}


def _reference_row(rows: list[dict]) -> dict | None:
    """The row the others are paired against: the first (best ranked) rbgp model row with its GP (not
    a peer, not a row without the GP), else the first row."""
    from rbgp_cli.evaluation.given_goal import NEAREST

    peers = {REPLAY, NEAREST, *PEERS}
    model = [r for r in rows if r["representation"] not in peers and not r.get("without_gp")]
    return (model or rows or [None])[0]


def _add_paired(rows: list[dict]) -> str | None:
    """Give every row but the reference (:func:`_reference_row`) its ``paired`` comparison with it
    (:func:`paired_difference` of the per-motion position and rotation RMSEs; the reference's own is
    None); returns the reference's label (None without per-motion errors)."""
    ref = _reference_row(rows)
    if ref is None or not ref.get("per_motion"):
        return None
    base = {m["index"]: m for m in ref["per_motion"]}
    for r in rows:
        if r is ref or not r.get("per_motion"):
            r["paired"] = None
            continue
        both = [(base[m["index"]], m) for m in r["per_motion"] if m["index"] in base]
        r["paired"] = {"reference": ref["label"], **{
            key: paired_difference([a[f"{key}_rmse"] for a, _ in both], [b[f"{key}_rmse"] for _, b in both])
            for key in ("position", "rotation")}}
    return ref["label"]


def _row(config: Config, folds: list[np.ndarray], floors: list, results: list[dict], k: int | None = None,
         seeds: list[int] | None = None, names: list[str] | None = None, sources: list | None = None) -> dict:
    """One configuration's row over its splits (``k`` folds per repetition, ``seeds`` the repetitions'
    fold seeds; by default one repetition; ``names`` and ``sources`` the demonstrations', for ``per_motion``)."""
    k = len(folds) if k is None else int(k)
    per_fold = []
    for i, (test_idx, floor, r) in enumerate(zip(folds, floors, results)):
        entry = {
            "fold": i % k, **({"repeat": i // k} if len(folds) > k else {}), "n_test": int(len(test_idx)),
            "score": r["score"], "floor": floor.mean, "ratio": r["score"] / floor.mean if floor.mean > 0 else float("inf"),
            "rotation": r["rotation"], "translation": r["translation"],
            "floor_rotation": floor.rotation, "floor_translation": floor.translation,
            "offset": r["offset"], "spread": r["spread"], "floor_offset": floor.offset, "floor_spread": floor.spread,
            "position_rmse": _pooled_rmse(r["position_sq"], r["count"]),
            "rotation_rmse": _pooled_rmse(r["rotation_sq"], r["count"]),
            **_velocity_summary([r["velocity"]]),
            "train_s": r["train_s"], "rollout_s": r["rollout_s"],
            "left_data": r.get("left_data"),
            "reliable": bool(r.get("reliable", True) and floor.reliable),
        }
        for key in ("points", "residual_gain", "full_fit"):
            if key in r:
                entry[key] = r[key]
        entry.update(_sampled_summary([r], [floor.mean], [test_idx]))
        per_fold.append(entry)
    score = float(np.mean([r["score"] for r in results]))
    floor = float(np.mean([f.mean for f in floors]))
    count = sum(r["count"] for r in results)
    extra = {}
    if len(folds) > k:  # each repetition's own numbers, as a run with its seed alone would give them
        extra["by_repeat"] = []
        for j in range(len(folds) // k):
            part = slice(j * k, (j + 1) * k)
            sc = float(np.mean([r["score"] for r in results[part]]))
            fl = float(np.mean([f.mean for f in floors[part]]))
            extra["by_repeat"].append({"seed": None if seeds is None else int(seeds[j]), "score": sc, "floor": fl,
                                       "ratio": sc / fl if fl > 0 else float("inf"),
                                       "sample_ratio": _sampled_summary(results[part], [f.mean for f in floors[part]])["sample_ratio"]})
    return {
        "representation": config.representation,
        "kernel": config.kernel,
        "label": config.name,
        "options": dict(config.options),
        "score": score,
        "floor": floor,
        "ratio": score / floor if floor > 0 else float("inf"),
        "rotation": float(np.mean([r["rotation"] for r in results])),
        "translation": float(np.mean([r["translation"] for r in results])),
        "offset": float(np.mean([r["offset"] for r in results])),
        "spread": float(np.mean([r["spread"] for r in results])),
        "floor_offset": float(np.mean([f.offset for f in floors])),
        "floor_spread": float(np.mean([f.spread for f in floors])),
        "position_rmse": _pooled_rmse(sum(r["position_sq"] for r in results), count),
        "rotation_rmse": _pooled_rmse(sum(r["rotation_sq"] for r in results), count),
        **_velocity_summary([r["velocity"] for r in results]),
        "train_s": float(np.mean([r["train_s"] for r in results])),
        **_sampled_summary(results, [f.mean for f in floors], folds),
        **_end_summary(results),
        "left_data": sum(int(r.get("left_data") or 0) for r in results),
        "reliable": all(e["reliable"] for e in per_fold),
        **extra,
        "per_fold": per_fold,
        "per_motion": _per_motion(folds, results, names, sources),
    }


def _end_summary(results: list[dict]) -> dict:
    """With a goal given (``given="goal"``): the mean end errors over all held-out motions,
    ``end_position`` (m) and ``end_rotation`` (rad); otherwise nothing."""
    if not results or any("end" not in r for r in results):
        return {}
    n = sum(r["end"][2] for r in results)
    return {"end_position": sum(r["end"][0] for r in results) / n, "end_rotation": sum(r["end"][1] for r in results) / n}


def _sampled_summary(results: list[dict], floors: list[float], folds: list | None = None) -> dict:
    """sample_score (mean over folds), sample_ratio (over the mean floor), the pooled coverage columns and
    their standard errors over the held-out motions ``coverage_position_se`` / ``coverage_rotation_se``
    (:func:`~rbgp_cli.evaluation.coverage.coverage_se`, a motion held out by several splits, ``folds`` the
    splits' held-out indices, counted once; None with fewer than two motions), or all None where the row
    has no samples (the replay peer, or samples=0)."""
    from rbgp_cli.evaluation.coverage import Coverage, coverage_se

    keys = ("sample_score", "sample_ratio", "sample_score_one", "sample_offset", "sample_spread", "coverage_position",
            "coverage_rotation", "band_position", "band_rotation", "coverage_position_se", "coverage_rotation_se")
    if not results or any("sample_score" not in r for r in results):
        return dict.fromkeys(keys)
    score = float(np.mean([r["sample_score"] for r in results]))
    floor = float(np.mean(floors))
    total = Coverage()
    for r in results:
        total = total + Coverage(*r["coverage"])
    cov = {k: (None if not math.isfinite(v) else v) for k, v in total.to_dict().items()}
    cov["coverage_position_se"] = cov["coverage_rotation_se"] = None
    if all(r.get("motion_coverage") for r in results):
        each = np.array([c for r in results for c in r["motion_coverage"]], dtype=np.float64).reshape(-1, 4)
        unit = (np.concatenate([np.asarray(f, dtype=np.int64) for f in folds]) if folds is not None
                else np.arange(len(each)))
        cov["coverage_position_se"] = coverage_se(each[:, 0], each[:, 1], unit)
        cov["coverage_rotation_se"] = coverage_se(each[:, 2], each[:, 3], unit)
    parts = {k: float(np.mean([r[k] for r in results])) for k in ("sample_offset", "sample_spread")}
    # the first set alone (one draw per start), as a single `rollout --samples 1` per start would score
    one = float(np.mean([r["sample_scores"][0] for r in results])) if all(r.get("sample_scores") for r in results) else None
    return {"sample_score": score, "sample_ratio": score / floor if floor > 0 else float("inf"), "sample_score_one": one,
            **parts, **cov}


def _goal_configs(configs: list[Config], given: str | None = "goal") -> list[Config]:
    """The rows of ``given="goal"``: the model configurations and the ProMP / DMP peers as they are
    (their goal-conditioned forms, :mod:`rbgp_cli.evaluation.given_goal`), the replay peer replaced by
    the nearest demonstration with its end offsets blended in; ``given`` None: ``configs`` as they are."""
    from rbgp_cli.evaluation.given_goal import NEAREST

    if given is None:
        return list(configs)
    if given != "goal":
        raise InputError(f"given must be goal, got {given!r}", param="given")
    return [Config(NEAREST) if c.representation == REPLAY else c for c in configs]


def crossval(demos: list[Trajectory], configs: list[Config], *, folds: int = 5, seed: int = 0,
             jobs: int | None = None, length: int | None = None, covariance: str = "diag",
             progress=None, scheduler: str | None = None, samples: int = SAMPLES, repeats: int = 1,
             without_gp: bool = True, order: str = "random", train_size: int | None = None,
             given: str | None = None) -> dict:
    """Cross-validate every configuration on the same folds (see the module docstring).

    Parameters
    ----------
    demos : clean demonstrations (at least ``folds``)
    configs : rows to compute (model configurations and/or ``Config(REPLAY)``)
    folds, seed : K folds of a seeded permutation of the demonstrations
    repeats : R ≥ 1 sets of K folds, from the seeds seed, seed + 1, …, seed + R − 1 (module docstring)
    jobs : worker processes (None: one per core, at most the number of tasks; 1: in this process)
    length, covariance : passed to :func:`~rbgp_cli.evaluation.bhattacharyya.evaluate`
    progress : a :class:`rbgp_cli.progress.Progress` (or callable(str), or None): a task over the fits,
        and one message per finished fit
    scheduler : None, ``"local"`` (a Dask ``LocalCluster`` of ``jobs`` workers) or the address of a Dask
        scheduler: the fits run there (:func:`rbgp_cli.compute.iter_dask`); the results are the same
    samples : sampled rollouts per held-out start (``rbgp rollout --samples``, seeded per fold from the
        train options' seed, :func:`sample_seed`) for the columns of docs/method.md §11: ``sample_score`` /
        ``sample_ratio`` (a set of one sample per start, scored as ``score``: the mean over the K sets;
        ``sample_score_one`` the first set's), ``coverage_position`` / ``coverage_rotation`` (the held-out motion
        inside the 90 % band rbgp gives with its samples, a peer's samples' 90 % prediction regions;
        0.90 for honest bands) and the bands'
        mean half-widths ``band_position`` (m) / ``band_rotation`` (rad); 0: none (those columns None)
    without_gp : beside every model row with a prior mean, a row "…, without the GP" from the same fits
        with the GP's residual switched off (:meth:`MotionModel.without_residual`): the path
        distribution alone, rolled out from the same starts with the same draws (``"without_gp": True``
        in the row); its velocity RMSE is the prior mean's
    order : ``"random"`` (the default) or ``"recorded"``: hold out contiguous blocks in recording order
        (the demonstrations' order in ``demos``), so that a block's neighbours in time are not trained
        on, as for the next session (:func:`make_splits`; the seed does not move the folds); or
        ``"forward"``: those blocks, each after the first predicted from the demonstrations before it
        only (:func:`forward_splits`; ``folds`` is then the number of blocks, the result's ``"folds"`` the
        splits used)
    train_size : None, or N: train on N demonstrations and hold out the rest, ``folds`` times (random
        subsets, or windows of N consecutive ones with the later ones held out; :func:`make_splits`);
        with ``order="forward"`` each block is predicted from the N just before it
    given : None (each row generates from the held-out start alone) or ``"goal"``: the held-out
        demonstrations' final poses and durations are given too, the peers are the goal-conditioned ones
        (:mod:`rbgp_cli.evaluation.given_goal`: nearest, promp, dmp; a ``replay`` configuration is left
        out) and every row has ``end_position`` (m) / ``end_rotation`` (rad), its mean motions' end errors

    Returns ``{"folds": K, "repeats": R, "seed", "demonstrations", "fold_sizes", "order", "train_size",
    "splits": [{"train": [...], "test": [...]}, ...] (demonstration indices, 0-based, in recording
    order), "results": [row, ...]}`` (forward: also ``"blocks"`` and ``"skipped_blocks"``,
    :func:`split_info`)
    with the rows sorted by score / floor (best first); each row as in the module docstring (with
    ``by_repeat`` when R > 1; its ``per_fold`` entries then say their ``repeat``), its ``per_motion``
    ([{"index", "name", "position_rmse", "rotation_rmse"}, ...], one per demonstration held out, pooled
    over the splits that held it out) and its ``paired`` comparison with the reference row
    (``{"reference": label, "position": {...}, "rotation": {...}}`` of :func:`paired_difference`;
    None for the reference row itself), whose label is ``"paired_reference"``.
    """
    demos = list(demos)
    configs = _goal_configs(configs, given)
    index_splits = repeated_splits(len(demos), folds, seed, order, train_size, repeats)
    seeds = [int(seed) + r for r in range(int(repeats))]
    fold_idx = [test_idx for _, test_idx in index_splits]
    k = len(index_splits) // len(seeds)
    splits = [([demos[i] for i in train_idx], [demos[i] for i in test_idx]) for train_idx, test_idx in index_splits]
    smallest = min(len(f) for f in fold_idx)
    if smallest < 2:
        if train_size is not None and len(demos) - 2 >= 2:
            hint, param = f"use train_size {len(demos) - 2} or less (at least 2 held out)", "train_size"
        elif train_size is None and len(demos) >= 4:
            hint, param = f"use folds {len(demos) // 2} or fewer (at least 2 held out per fold)", "folds"
        else:  # no split of so few holds out two and trains on two
            hint, param = "record 4 demonstrations or more (two held out in each of two folds)", None
        warn(f"with {k} folds of {len(demos)} demonstrations some folds hold out only one: a score "
             "of one trajectory rests on the ridge variance, not on the motions", hint=hint, param=param)
    floors = [evaluate(test, train, length=length, covariance=covariance, sample_size="record") for train, test in splits]
    # the held-out demonstrations themselves against the training envelope: what real new motions do
    floor_left = sum(left_envelope(test, envelope_from_demos(train))["count"] for train, test in splits)
    tasks = [(c, f) for c in configs for f in range(len(splits))]
    args = [(c, splits[f][0], splits[f][1], length, covariance, samples, f % k, f // k, given) for c, f in tasks]
    n_jobs = jobs if jobs is not None else min(len(tasks), usable_cores())
    n_jobs = max(1, min(int(n_jobs), len(tasks)))
    results: list = [None] * len(tasks)
    caught: set = set()
    progress = as_progress(progress)
    progress(f"{len(demos)} demonstrations in {k} " + (f"forward folds of {folds} blocks" if order == "forward" else "folds")
             + f" ({', '.join(str(len(f)) for f in fold_idx[:k])} held out)"
             + (f" × {len(seeds)} repeats (fold seeds {seeds[0]}–{seeds[-1]})" if len(seeds) > 1 else "") + "; "
             f"{len(configs)} configuration{'s' * (len(configs) != 1)}, {len(tasks)} fits"
             + (f" on the Dask cluster {scheduler!r}" if scheduler else f" in {n_jobs} worker processes" if n_jobs > 1 else ""))

    def name_of(f):  # a split's name in messages
        return f"fold {f % k + 1}/{k}" + (f" of repeat {f // k + 1}/{len(seeds)}" if len(seeds) > 1 else "")

    def label(i):
        c, f = tasks[i]
        return f"{c.name} {name_of(f)}"

    with progress.task("cross-validation", total=len(tasks), unit="fits") as bar:
        def done(i, r):
            results[i] = r
            caught.update(r.get("warnings", []))
            c, f = tasks[i]
            msg = (f"{c.name}, {name_of(f)}: score {r['score']:.3f} (floor {floors[f].mean:.3f})"
                   + (f", trained in {r['train_s']:.1f} s" if r["train_s"] else ""))
            bar.update(completed=sum(x is not None for x in results), status=msg)  # the count includes this fit
            progress(msg)

        if scheduler:
            from rbgp_cli.compute import iter_dask

            for i, r in iter_dask(_task, args, jobs=jobs, scheduler=scheduler, label=label):
                done(i, r)
        elif n_jobs == 1:
            for i, a in enumerate(args):
                done(i, _task(a))
        else:
            for i, r in _run_in_processes(args, n_jobs, label=label):
                done(i, r)
    rows, names, sources = [], [d.name for d in demos], [d.source for d in demos]
    for ci, c in enumerate(configs):
        res = [results[ci * len(splits) + f] for f in range(len(splits))]
        rows.append(_row(c, fold_idx, floors, res, k=k, seeds=seeds, names=names, sources=sources))
        if without_gp and all("without_gp" in r for r in res):
            off = Config(c.representation, c.kernel, c.train, label=f"{c.name}, without the GP", options=c.options)
            row = _row(off, fold_idx, floors, [r["without_gp"] for r in res], k=k, seeds=seeds, names=names, sources=sources)
            rows.append({**row, "without_gp": True})
    rows.sort(key=lambda r: (r["ratio"], r["label"]))
    return {
        "folds": k,
        "repeats": len(seeds),
        "seed": int(seed),
        "demonstrations": len(demos),
        "fold_sizes": [int(len(f)) for f in fold_idx[:k]],
        "order": order,
        "train_size": None if train_size is None else int(train_size),
        "splits": [{"train": tr.tolist(), "test": te.tolist()} for tr, te in index_splits],
        **split_info(len(demos), folds, order, train_size),
        "floor": float(np.mean([f.mean for f in floors])),
        "floor_left_data": int(floor_left),
        **({"given": given} if given else {}),
        "paired_reference": _add_paired(rows),  # and each row's "paired"
        "results": rows,
        "warnings": sorted(caught | {w for f in floors for w in f.warnings}),
    }
