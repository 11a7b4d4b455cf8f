"""``rbgp crossval --given F``: a motion under way, predicted from its first fraction F (docs/method.md §13).

Each held-out demonstration is split at its sample nearest to t_0 + F·D: the seen part (from its start
to that sample) is given, the remainder (from that sample to the end) is to be predicted, without its
duration. The columns per method and F:

- ``end_pos`` (m), ``end_rot`` (rad): the predicted final pose's distance to the real one;
- ``end_time`` (s): |predicted end time − real end time|;
- ``rest_pos`` (m), ``rest_rot`` (rad): the remainder's RMSE, prediction and truth each resampled to 100
  steps of its own normalised time;
- ``cov_pos``, ``cov_rot``: how often the real remainder lies in the 90 % prediction region of K sampled
  continuations (:func:`~rbgp_cli.evaluation.coverage.prediction_coverage`; methods without samples: none),
  ``cov_pos_se``, ``cov_rot_se`` their standard errors over the held-out motions
  (:func:`~rbgp_cli.evaluation.coverage.coverage_se`);
- ``cov_end_time``: how often the real end time lies in the predicted end time's 90 % band (the held-out motions'
  fraction; methods without a band: none), ``cov_end_time_se`` its standard error over the held-out motions;
- ``left_data`` of ``left_of``: how many of the predicted continuations (the mean and each sample) leave the
  training demonstrations' envelope (:mod:`~rbgp_cli.dynamics.envelope`), each row at its phase of the whole motion
  (:func:`~rbgp_cli.dynamics.envelope.continuation_phases`); the held-out remainders themselves, checked at their true
  phases, are the floor (:func:`under_way_fold`'s ``("floor", F)``).

Methods: ``rbgp`` (:class:`~rbgp_cli.dynamics.anticipation.Anticipator` with the model's GP dynamics),
``no-GP`` (the same, its mean the conditioned path alone), ``nearest`` (the training demonstration and
duration whose poses at phases τ/D best match the seen poses, time-scaled to that duration: no bands),
``promp`` and ``promp-ridge`` (a ProMP of ``movement-primitives`` over the ProMP peer's curves
(log(R̄_0ᵀR), p), its weight distribution the mean and covariance of each demonstration's regression
weights, with phase estimation: the duration maximising the seen poses' likelihood under the ProMP times a log-normal prior of
the training durations, then conditioned on the seen poses via the package's ``condition_position``: with
the tracker's noise, 1 mm / 1 mrad (plain), or a ridge σ chosen by leaving training demonstrations out).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from rbgp_cli.dynamics.trajectory import Trajectory

__all__ = ["FRACTIONS", "METHODS", "COLUMNS", "split_seen", "UnderWayScores", "score", "nearest_continuation",
           "PhaseProMP", "under_way_fold", "add_paired", "left_of"]

#: The fractions crossval --given takes by default.
FRACTIONS = (0.2, 0.4, 0.6, 0.8)
#: Row names.
METHODS = ("rbgp", "no-GP", "nearest", "promp", "promp-ridge")
#: The per-motion columns (m, rad, s, m, rad) that the paired comparison takes.
COLUMNS = ("end_pos", "end_rot", "end_time", "rest_pos", "rest_rot")
#: The row the others are paired against.
REFERENCE = "rbgp"
#: ProMP conditioning noise (rad, m) of the plain peer: a tracker's.
PROMP_PLAIN_STD = 1e-3
#: Ridge σ (in the curve's units, rad and m) tried for the regularised ProMP.
PROMP_RIDGE_GRID = (0.003, 0.01, 0.03, 0.1, 0.3)
#: Seen points that enter the peers' phase estimate and conditioning (as rbgp's).
PEER_POINTS = 12
_T = 100


def split_seen(traj: Trajectory, fraction: float) -> tuple[Trajectory, Trajectory]:
    """(seen, rest): the samples up to the one nearest t_0 + F·D (at least two), and from that sample on."""
    F = float(fraction)
    target = traj.t[0] + F * traj.duration
    j = int(np.clip(np.argmin(np.abs(traj.t - target)), 1, len(traj.t) - 2))
    seen = Trajectory(traj.t[: j + 1], traj.quat[: j + 1], traj.position[: j + 1], name=traj.name)
    rest = Trajectory(traj.t[j:], traj.quat[j:], traj.position[j:], name=traj.name)
    return seen, rest


@dataclass
class UnderWayScores:
    """Per held-out motion of one method at one F (see the module docstring), in the order they were
    scored: ``end_pos``, ``end_rot``, ``end_time`` (one value each), ``motion_sq`` ((Σ squared position
    error, Σ squared rotation error, steps) of its remainder), ``index`` (its place in the input order, or
    None); ``coverage`` the pooled :class:`~rbgp_cli.evaluation.coverage.Coverage` (None without samples);
    ``motion_coverage`` per motion with samples (position inside, position count, rotation inside, rotation
    count): the coverages' standard errors over the motions; ``end_time_in`` per motion with an end-time band
    whether it held the real end time (1.0 or 0.0)."""

    end_pos: list = field(default_factory=list)
    end_rot: list = field(default_factory=list)
    end_time: list = field(default_factory=list)
    motion_sq: list = field(default_factory=list)
    index: list = field(default_factory=list)
    coverage: object = None
    motion_coverage: list = field(default_factory=list)
    #: per motion with an end-time band: 1.0 where it held the real end time, else 0.0
    end_time_in: list = field(default_factory=list)
    #: per motion checked against the envelope: (continuations that left it, continuations checked)
    left: list = field(default_factory=list)

    @property
    def sp(self) -> float:
        """Σ over motions of the remainders' squared position errors (m²)."""
        return float(sum(m[0] for m in self.motion_sq))

    @property
    def sr(self) -> float:
        """Σ over motions of the remainders' squared rotation errors (rad²)."""
        return float(sum(m[1] for m in self.motion_sq))

    @property
    def n(self) -> int:
        """Steps summed in :attr:`sp` and :attr:`sr`."""
        return int(sum(m[2] for m in self.motion_sq))

    def add(self, other: "UnderWayScores") -> "UnderWayScores":
        cov = self.coverage if other.coverage is None else (other.coverage if self.coverage is None else self.coverage + other.coverage)
        return UnderWayScores(self.end_pos + other.end_pos, self.end_rot + other.end_rot, self.end_time + other.end_time,
                              self.motion_sq + other.motion_sq, self.index + other.index, cov,
                              self.motion_coverage + other.motion_coverage, self.end_time_in + other.end_time_in,
                              self.left + other.left)

    def with_index(self, index: int) -> "UnderWayScores":
        """The same scores of one motion, labelled with its place in the input order."""
        return UnderWayScores(self.end_pos, self.end_rot, self.end_time, self.motion_sq, [int(index)] * len(self.end_pos),
                              self.coverage, self.motion_coverage, self.end_time_in, self.left)

    def to_dict(self) -> dict:
        nan = float("nan")
        n = self.n
        out = {"end_pos": float(np.mean(self.end_pos)) if self.end_pos else nan,
               "end_rot": float(np.mean(self.end_rot)) if self.end_rot else nan,
               "end_time": float(np.mean(self.end_time)) if self.end_time else nan,
               "rest_pos": float(np.sqrt(self.sp / n)) if n else nan,
               "rest_rot": float(np.sqrt(self.sr / n)) if n else nan,
               "cov_pos": nan, "cov_rot": nan, "band_pos": nan, "band_rot": nan, "motions": len(self.end_pos),
               "cov_pos_se": nan, "cov_rot_se": nan, "cov_end_time": nan, "cov_end_time_se": nan,
               "left_data": int(sum(a for a, _ in self.left)) if self.left else None,
               "left_of": int(sum(b for _, b in self.left)) if self.left else None}
        if self.coverage is not None:
            c = self.coverage.to_dict()
            out.update(cov_pos=c["coverage_position"], cov_rot=c["coverage_rotation"], band_pos=c["band_position"],
                       band_rot=c["band_rotation"])
        if self.motion_coverage and len(self.motion_coverage) == len(self.end_pos):
            # over the motions (coverage_se: a motion scored twice, by its index, counts once)
            from rbgp_cli.evaluation.coverage import coverage_se

            m = np.asarray(self.motion_coverage, dtype=np.float64)
            unit = self.index if len(self.index) == len(m) and None not in self.index else None
            for key, (a, b) in (("cov_pos_se", (0, 1)), ("cov_rot_se", (2, 3))):
                se = coverage_se(m[:, a], m[:, b], unit)
                out[key] = nan if se is None else se
        if self.end_time_in and len(self.end_time_in) == len(self.end_pos):
            from rbgp_cli.evaluation.coverage import coverage_se

            inside = np.asarray(self.end_time_in, dtype=np.float64)
            unit = self.index if len(self.index) == len(inside) and None not in self.index else None
            se = coverage_se(inside, np.ones_like(inside), unit)
            out.update(cov_end_time=float(inside.mean()), cov_end_time_se=nan if se is None else se)
        return out

    def per_motion(self, names: list | None = None, sources: list | None = None) -> list[dict]:
        """[{"index", "name", "source", "end_pos", "end_rot", "end_time", "rest_pos", "rest_rot", "scored"}, ...], one per
        held-out motion sorted by index. A motion scored by several splits (``--repeats``, ``--train-size``)
        is one entry, as crossval's start-only ``per_motion`` is: its end errors the mean over those splits,
        its remainder's RMSEs √(Σ/steps) pooled over them, with samples its ``cov_pos``, ``cov_rot`` (steps
        inside over steps scored, pooled); ``scored`` how many splits held it out. Motions without an index
        stay one entry per scoring. ``name`` only with ``names`` (the input order's names) and an index;
        ``source`` likewise with ``sources`` (the files they were read from), where the motion has one."""
        from rbgp_cli.evaluation.crossval import motion_source

        covs = self.motion_coverage if len(self.motion_coverage) == len(self.end_pos) else None
        groups: dict = {}
        for k in range(len(self.end_pos)):
            i = self.index[k] if k < len(self.index) else None
            groups.setdefault(("k", k) if i is None else ("i", int(i)), []).append(k)
        out = []
        for key, ks in groups.items():
            i = None if key[0] == "k" else key[1]
            sp, sr, c = (float(sum(self.motion_sq[k][j] for k in ks)) for j in range(3))
            cov = {}
            if covs is not None:
                a, n, b, m = (float(sum(covs[k][j] for k in ks)) for j in range(4))
                cov = {"cov_pos": a / n if n else float("nan"), "cov_rot": b / m if m else float("nan")}
            out.append({"index": i, **({"name": names[i]} if names is not None and i is not None else {}),
                        **motion_source(sources, i),
                        "end_pos": float(np.mean([self.end_pos[k] for k in ks])),
                        "end_rot": float(np.mean([self.end_rot[k] for k in ks])),
                        "end_time": float(np.mean([self.end_time[k] for k in ks])),
                        "rest_pos": float(np.sqrt(sp / c)) if c else float("nan"),
                        "rest_rot": float(np.sqrt(sr / c)) if c else float("nan"), **cov, "scored": len(ks)})
        return sorted(out, key=lambda m: (m["index"] is None, m["index"] if m["index"] is not None else 0))


def add_paired(rows: list[dict], reference: str = REFERENCE) -> None:
    """Give every row of ``rows`` (dicts with ``method``, ``given`` and ``per_motion``) its ``paired``
    comparison with the ``reference`` method's row at the same F: per column of :data:`COLUMNS`,
    :func:`~rbgp_cli.evaluation.crossval.paired_difference` of the two rows' per-motion values over the
    motions both scored (matched by index; a motion held out by several splits is one, :meth:`UnderWayScores.per_motion`): Δ = the row's minus the reference's, mean ± standard error, z,
    closer. The reference's own ``paired`` is None, and so is every row's at an F without a reference."""
    from rbgp_cli.evaluation.crossval import paired_difference

    refs = {r["given"]: r for r in rows if r["method"] == reference}
    for r in rows:
        ref = refs.get(r["given"])
        if ref is None or r is ref or not r.get("per_motion") or not ref.get("per_motion"):
            r["paired"] = None
            continue
        base = {m["index"]: m for m in ref["per_motion"]}
        both = [(base[m["index"]], m) for m in r["per_motion"] if m["index"] in base]
        r["paired"] = {"reference": reference, **{
            key: paired_difference([a[key] for a, _ in both], [b[key] for _, b in both]) for key in COLUMNS}}


def score(mean: Trajectory, samples: list, rest: Trajectory, end_band: tuple | None = None, envelope=None,
          t0: float | None = None) -> UnderWayScores:
    """One held-out remainder's scores (module docstring); ``end_band`` (lo, hi) s the predicted end time's band,
    if the method has one; ``envelope`` (with ``t0`` the seen start): how many of the mean and samples leave it
    (:func:`left_of`)."""
    from rbgp_cli.evaluation.coverage import MIN_SAMPLES, prediction_coverage
    from rbgp_cli.evaluation.crossval import trajectory_errors

    sp, sr, n = trajectory_errors([mean], [rest], _T)
    dq = abs(float(np.dot(mean.quat[-1], rest.quat[-1])) / (np.linalg.norm(mean.quat[-1]) * np.linalg.norm(rest.quat[-1])))
    cov = prediction_coverage(samples, rest, _T) if len(samples) >= MIN_SAMPLES else None
    return UnderWayScores([float(np.linalg.norm(mean.position[-1] - rest.position[-1]))],
                          [float(2.0 * np.arccos(min(1.0, dq)))], [abs(float(mean.t[-1] - rest.t[-1]))], [(sp, sr, n)],
                          [], cov, [] if cov is None else [cov.astuple()[:4]],
                          [] if end_band is None else [float(end_band[0] <= rest.t[-1] <= end_band[1])],
                          [] if envelope is None else [left_of([mean, *samples], envelope, t0)])


def left_of(trajs: list, envelope, t0: float) -> tuple[int, int]:
    """(how many of ``trajs`` leave ``envelope``, how many were checked): continuations of a motion that started at
    ``t0`` on their clock, the mean first, each row at its phase of the whole motion
    (:func:`~rbgp_cli.dynamics.envelope.continuation_phases`, as ``rollout --given`` checks them)."""
    from rbgp_cli.dynamics.envelope import continuation_phases, left_envelope

    report = left_envelope(trajs, envelope, phases=continuation_phases(trajs, t0), starts=[t0] * len(trajs))
    return int(report["count"]), int(report["of"])


# ---------------------------------------------------------------------------------------- nearest
def nearest_continuation(train: list, seen: Trajectory, grid_size: int = 48) -> Trajectory:
    """The training demonstration d and duration D (log grid from 0.5 min to 2 max of the training
    durations, at least the seen span) whose poses at phases τ/D are nearest the seen poses (mean squared
    position error plus rotation angle² × (1 m/rad)²), time-scaled: its phases from span/D to 1 on
    t_0 + phase·D."""
    from rbgp_cli.dynamics.trajectory import interpolate_poses
    from rbgp_cli.geometry.so3 import quat_conjugate, quat_make_continuous, quat_multiply

    t0, span = float(seen.t[0]), float(seen.duration)
    n = min(PEER_POINTS, len(seen.t))
    tau = np.linspace(0.0, span, n)
    sq, sp = interpolate_poses(seen.t - t0, quat_make_continuous(seen.quat), seen.position, tau)
    durs = np.array([tr.duration for tr in train])
    grid = np.exp(np.linspace(np.log(0.5 * durs.min()), np.log(2 * durs.max()), grid_size))
    grid = grid[grid >= span] if np.any(grid >= span) else np.array([span])
    best = (np.inf, 0, grid[0])
    for i, tr in enumerate(train):  # a loop over demonstrations, each vectorised over the grid
        ph = np.clip(tau[None, :] / grid[:, None], 0, 1).ravel()
        q, p = interpolate_poses((tr.t - tr.t[0]) / tr.duration, quat_make_continuous(tr.quat), tr.position, ph)
        q, p = q.reshape(len(grid), n, 4), p.reshape(len(grid), n, 3)
        dq = quat_multiply(quat_conjugate(q), np.broadcast_to(sq, q.shape))
        ang = 2.0 * np.arctan2(np.linalg.norm(dq[..., :3], axis=-1), np.abs(dq[..., 3]))
        cost = np.mean(np.sum((p - sp) ** 2, axis=-1) + ang ** 2, axis=1)
        g = int(np.argmin(cost))
        if cost[g] < best[0]:
            best = (float(cost[g]), i, float(grid[g]))
    _, i, D = best
    tr = train[i]
    s0 = min(span / D, 1.0)
    ph = np.linspace(s0, 1.0, max(int(round((1 - s0) * len(tr.t))), 2))
    q, p = interpolate_poses((tr.t - tr.t[0]) / tr.duration, quat_make_continuous(tr.quat), tr.position, ph)
    return Trajectory(t0 + ph * D, q, p, name="nearest")


# ---------------------------------------------------------------------------------------- ProMP
class PhaseProMP:
    """The ProMP peer (:func:`~rbgp_cli.evaluation.peers.fit_promp`) with phase estimation and conditioning
    on a seen beginning (module docstring); ``std``: the conditioning noise (curve units, rad and m)."""

    def __init__(self, train: list, std: float = PROMP_PLAIN_STD):
        from movement_primitives.promp import ProMP

        from rbgp_cli.evaluation.peers import PROMP_BASIS, PROMP_STEPS, ProMPPeer, _continuous_log
        from rbgp_cli.evaluation.resample import mean_rotation, resample_all
        from rbgp_cli.geometry.so3 import quat_conjugate, quat_multiply

        # the ProMP peer's curves (peers.fit_promp), its weights by the package's per-demonstration
        # regression (ProMP.weights) and their sample mean and covariance (Paraschos et al. 2013), not the
        # package's EM (imitate: minutes per fit, and leaving demonstrations out fits it many times)
        q, p = resample_all(train, PROMP_STEPS)
        ref = mean_rotation(q[:, :1])[0]
        rel = quat_multiply(np.broadcast_to(quat_conjugate(ref), q.shape), q)
        Y = np.concatenate([_continuous_log(rel), p], axis=-1)  # (M, T, 6)
        T = np.linspace(0.0, 1.0, PROMP_STEPS)
        promp = ProMP(n_dims=6, n_weights_per_dim=PROMP_BASIS)
        W = np.array([promp.weights(T, y, lmbda=1e-6) for y in Y])
        cov = np.cov(W, rowvar=False) + 1e-8 * np.eye(W.shape[1])
        promp.from_weight_distribution(W.mean(axis=0), cov)
        self.peer = ProMPPeer(promp, ref, PROMP_STEPS)
        ld = np.log([tr.duration for tr in train])
        self.ell_mean, self.ell_std = float(np.mean(ld)), float(max(np.std(ld), 0.01))
        self.durations = np.exp(ld)
        self.std = float(std)

    def _seen(self, seen: Trajectory):
        from rbgp_cli.dynamics.trajectory import interpolate_poses
        from rbgp_cli.evaluation.peers import _continuous_log
        from rbgp_cli.geometry.so3 import quat_conjugate, quat_make_continuous, quat_multiply

        t0, span = float(seen.t[0]), float(seen.duration)
        n = min(PEER_POINTS, len(seen.t))
        tau = np.linspace(0.0, span, n)
        q, p = interpolate_poses(seen.t - t0, quat_make_continuous(seen.quat), seen.position, tau)
        rel = quat_multiply(np.broadcast_to(quat_conjugate(self.peer.ref), q.shape), q)
        return tau, np.concatenate([_continuous_log(rel), p], axis=-1)  # (n,), (n, 6)

    def _full(self):
        """The ProMP's mean (N, 6) and covariance (6N, 6N, dimension-major) on N = 201 phases of [0, 1]: the
        package normalises the times it is given by their last, so partial ranges are read off this grid."""
        full = self.__dict__.get("_grid")
        if full is None:
            s = np.linspace(0.0, 1.0, 201)
            full = self._grid = (s, self.peer.promp.mean_trajectory(s), self.peer.promp.cov_trajectory(s))
        return full

    def duration(self, tau, Y, grid_size: int = 48) -> float:
        """The duration maximising N(Y | mean(τ/D), cov(τ/D) + σ² I) · N(ln D | prior) on a log grid (the
        ProMP's mean and covariance at the grid phase nearest τ/D)."""
        s, mean, cov = self._full()
        N = len(s)
        span = float(tau[-1])
        grid = np.exp(np.linspace(np.log(0.5 * self.durations.min()), np.log(2 * self.durations.max()), grid_size))
        grid = grid[grid >= span] if np.any(grid >= span) else np.array([max(span, 1e-6)])
        best, arg = -np.inf, grid[0]
        y = Y.T.ravel()  # dimension-major, as the package's covariance
        for D in grid:  # a loop over the grid's durations, each one Gaussian density
            idx = np.round(np.clip(tau / D, 0, 1) * (N - 1)).astype(int)
            I = (np.arange(6)[:, None] * N + idx[None, :]).ravel()
            m = mean[idx].T.ravel()
            C = cov[np.ix_(I, I)] + (self.std ** 2 + 1e-10) * np.eye(len(y))
            try:
                L = np.linalg.cholesky(C)
            except np.linalg.LinAlgError:
                continue
            a = np.linalg.solve(L, y - m)
            lp = -0.5 * a @ a - np.sum(np.log(np.diag(L))) - 0.5 * ((np.log(D) - self.ell_mean) / self.ell_std) ** 2
            if lp > best:
                best, arg = lp, D
        return float(arg)

    def predict(self, seen: Trajectory, samples: int = 0, seed: int = 0, D: float | None = None):
        """(mean Trajectory, samples): the conditioned ProMP's continuation from the last seen time."""
        tau, Y = self._seen(seen)
        D = self.duration(tau, Y) if D is None else float(D)
        promp = self.peer.promp
        cov = (self.std ** 2) * np.eye(6)
        for tk, yk in zip(tau, Y):  # condition on each seen point in turn (the same as jointly)
            promp = promp.condition_position(yk, y_cov=cov, t=min(tk / D, 1.0), t_max=1.0)
        s0 = min(float(tau[-1]) / D, 1.0)
        ph = np.linspace(s0, 1.0, max(int(round((1 - s0) * self.peer.steps)), 2))
        t = float(seen.t[0]) + ph * D
        mean = self._traj(promp.mean_trajectory(ph), t, "promp")
        out = []
        if samples:
            ys = promp.sample_trajectories(ph, int(samples), np.random.RandomState(int(seed)))
            out = [self._traj(y, t, f"promp.s{k}") for k, y in enumerate(ys)]
        return mean, out

    def _traj(self, y, t, name):
        from rbgp_cli.geometry.so3 import exp_quat, quat_multiply

        q = quat_multiply(np.broadcast_to(self.peer.ref, (len(y), 4)), exp_quat(y[:, :3]))
        return Trajectory(t, q, y[:, 3:], name=name)


def ridge_std(train: list, *, folds: int = 5, fractions=(0.2, 0.6), seed: int = 0) -> float:
    """The ridge σ of the regularised ProMP: leave training demonstrations out (``folds`` groups), see their
    first F at their true duration, and keep the σ of :data:`PROMP_RIDGE_GRID` with the smallest remainder
    position RMSE."""
    from rbgp_cli.evaluation.crossval import make_folds

    err = {s: 0.0 for s in PROMP_RIDGE_GRID}
    for fold in make_folds(len(train), min(folds, len(train)), seed):
        rest = [train[j] for j in range(len(train)) if j not in set(fold)]
        if len(rest) < 2:
            continue
        peer = PhaseProMP(rest)
        for j in fold:
            for F in fractions:
                seen, remainder = split_seen(train[j], F)
                for s in PROMP_RIDGE_GRID:
                    peer.std = s
                    mean, _ = peer.predict(seen, D=train[j].duration)
                    sc = score(mean, [], remainder)
                    err[s] += sc.sp
    return float(min(err, key=err.get))


# ---------------------------------------------------------------------------------------- one fold
def under_way_fold(model, paths, train: list, test: list, fractions=FRACTIONS, *, samples: int = 20, seed: int = 0,
                   methods=METHODS, indices=None) -> dict:
    """Scores {(method, F): UnderWayScores} of one fold, and {("floor", F): UnderWayScores} with only the held-out
    remainders' ``left``: ``model`` and ``paths`` fitted on ``train``;
    ``indices``: the held-out motions' places in the input order (default 0, 1, … in ``test``'s order),
    which label their per-motion scores."""
    from rbgp_cli.dynamics.anticipation import Anticipator
    from rbgp_cli.dynamics.envelope import envelope_from_demos

    out = {}
    env = envelope_from_demos(train)
    ants = {}
    if "rbgp" in methods:
        ants["rbgp"] = Anticipator(paths, model)
    if "no-GP" in methods:
        ants["no-GP"] = Anticipator(paths, None)
    promps = {}
    if "promp" in methods or "promp-ridge" in methods:
        from rbgp_cli.evaluation.peers import missing

        if missing() is None:
            if "promp" in methods:
                promps["promp"] = PhaseProMP(train)
            if "promp-ridge" in methods:
                promps["promp-ridge"] = PhaseProMP(train, ridge_std(train, seed=seed))
    indices = list(range(len(test))) if indices is None else [int(j) for j in indices]
    for i, tr in enumerate(test):
        for F in fractions:
            seen, rest = split_seen(tr, F)
            t0 = float(seen.t[0])
            for name, ant in ants.items():
                c = ant.continuation(seen.t, seen.quat, seen.position, samples=samples, seed=seed + i)
                trs = c.trajectories(include_samples=True)
                _add(out, (name, F), score(trs[0], trs[1:], rest, c.estimate.end_time_band, env, t0).with_index(indices[i]))
            if "nearest" in methods:
                _add(out, ("nearest", F), score(nearest_continuation(train, seen), [], rest, None, env, t0).with_index(indices[i]))
            for name, pm in promps.items():
                mean, smp = pm.predict(seen, samples=samples, seed=seed + i)
                _add(out, (name, F), score(mean, smp, rest, None, env, t0).with_index(indices[i]))
            # the floor: the real remainder itself, at its true duration
            _add(out, ("floor", F), UnderWayScores(index=[indices[i]], left=[left_of([rest], env, t0)]))
    return out


def _add(out, key, sc):
    out[key] = sc if key not in out else out[key].add(sc)
