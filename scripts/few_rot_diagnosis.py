"""Why the continuation bands under-cover the early rotation with few demonstrations (issue 37, ninth pass).

On the synthetic family of tests/dynamics/test_anticipation_bands.py (durations spread 5 % in ln D), for N trained
(two training draws, 12 fresh motions each, F = 0.2 … 0.8), per fresh motion and F:

- ``cv``: crossval's coverage of the remainder by 20 sampled continuations (evaluation.under_way.score);
- ``cv400``: the same measure with 400 samples (the 20-sample band's estimate);
- ``axis``: the rotation scored per tangent axis as position is (a t interval per axis, not the 3-D ellipsoid);
- ``gauss``: the Gaussian level at the true duration: the real remainder's deviation at the grid phases after F
  from the continuation's mean, rotation m² under c² Σ̂ (Σ̂ the conditioned covariance the samples use) against
  3 F_0.9(3, ν), position |e| against c t_ν σ̂ (what the left-out statistic scores);
- ``gauss_hot``: the rotation as ``gauss`` but against the predictive region of a covariance estimated from
  n = D samples in p = 3 dimensions (Hotelling): (n + 1)(n − 1) 3 / (n (n − 3)) F_0.9(3, n − 3), scale (1 + 1/n);
- ``true_var``: the per-phase rotation / position variance of the prior Σ against the generating process's
  (2000 fresh motions about the same mean path), at F = 0.2's remainder.

The draws are the continuation's (Gaussian with the Student-t's 90 % regions, ninth pass); STUDENT=1 draws them
Student-t as before. STAT=every fits the bands' factors at every grid phase after F at the true duration, STAT=spread
with the eighth pass's statistic, both at every number of demonstrations; DRAWS=n training draws (default 2); BIG=k
also scores k samples (default 400; 0: not). The ninth pass's later variants of the factors below 1 (none kept): OWN_NU=1 the
left-out scores against their own model's ν = D − 3, NOW=1 undamped (w = 1), NARROW=n damped with w = min(1, D / n).

Usage: python scripts/few_rot_diagnosis.py N [N ...] (N trained per draw; prints one table per N).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from scipy.special import fdtri, stdtrit

from rbgp_cli.dynamics.anticipation import Anticipator, _seen, _spread_terms  # the original: fit() may patch it
from rbgp_cli.dynamics.paths import fit_paths
from rbgp_cli.evaluation.coverage import band_thresholds
from rbgp_cli.evaluation.resample import mean_rotation, resample_all, tangent_features
from rbgp_cli.evaluation.under_way import split_seen

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from tests.dynamics.test_anticipation_bands import _rich_family  # noqa: E402

FRACTIONS = (0.2, 0.4, 0.6, 0.8)


def rich_family(n, seed, K=5, spread=0.05):
    """tests/dynamics/test_anticipation_bands.py's ``_rich_family``, its durations spread 5 % in ln D."""
    return _rich_family(n, seed, K=K, spread=spread)


def detail(samples, ref, T=100):
    """crossval's per-step tests (evaluation.coverage.prediction_coverage), plus the rotation per tangent axis:
    (pos_in (T, 3) bool, rot_in (T,) bool, rot_axis_in (T, 3) bool)."""
    K = len(samples)
    tf, h = band_thresholds(K)
    qs, ps = resample_all(samples, T)
    qr, pr = resample_all([ref], T)
    mean = ps.mean(axis=0)
    half = tf * ps.std(axis=0, ddof=1)
    pos_in = np.abs(pr[0] - mean) <= half
    R = mean_rotation(qs)
    v = tangent_features(qs, ps, R)[..., :3]
    v0 = tangent_features(qr, pr, R)[0, :, :3]
    vbar = v.mean(axis=0)
    Dv = v - vbar
    S = np.einsum("kti,ktj->tij", Dv, Dv) / (K - 1)
    ridge = np.maximum(1e-9 * np.trace(S, axis1=1, axis2=2) / 3.0, 1e-12)
    S = S + ridge[:, None, None] * np.eye(3)
    e = v0 - vbar
    m2 = np.einsum("ti,ti->t", e, np.linalg.solve(S, e[..., None])[..., 0])
    axis_in = np.abs(e) <= tf * np.sqrt(np.einsum("tii->ti", S))
    return pos_in, m2 <= h, axis_in


def gaussian_level(ant, seen, tr, c):
    """The real remainder at its true duration against the conditioned Gaussian the samples draw from (module
    docstring): (pos_in (J, 3), rot_in (J,), rot_hot_in (J,), rot_axis_in (J, 3), phases (J,), m2 (J,)) at the
    grid phases after the seen span."""
    paths = ant.paths
    _, quat, pos, tau, q, p = _seen(seen.t, seen.quat, seen.position, ant.points)
    D = tr.duration
    mean_rest, _ = ant._conditioned_mean(tau, q, p, quat[-1], pos[-1], D, rest=True)
    _, (A, r2, gain) = ant._conditioned_mean(tau, q, p, quat[-1], pos[-1], D, rest=False)
    cov = ant.Sigma - gain @ (A @ ant.Sigma)
    S = paths.S
    x_true = paths.deviation_of(tr.t, tr.quat, tr.position) / paths.scale  # (S, 6) scaled, at true phases
    span = tau[-1]
    js = np.flatnonzero(paths.s > span / D + 1e-9)
    js = js[js < S]
    e = x_true[js] - mean_rest[:-1].reshape(S, 6)[js]
    C = np.stack([cov[6 * j:6 * j + 6, 6 * j:6 * j + 6] for j in js])
    nu = max(paths.demos - 2, 1)
    c_rot, c_pos = c
    m2 = np.einsum("ji,ji->j", e[:, :3], np.linalg.solve(C[:, :3, :3], e[:, :3, None])[..., 0])
    rot_in = m2 <= c_rot ** 2 * 3 * fdtri(3, nu, 0.9)
    n = paths.demos
    hot = (n + 1) * (n - 1) * 3 / (n * max(n - 3, 1)) * fdtri(3, max(n - 3, 1), 0.9) / (1 + 1 / n)
    rot_hot_in = m2 <= c_rot ** 2 * hot
    sd = np.sqrt(np.einsum("jii->ji", C))
    pos_in = np.abs(e[:, 3:]) <= c_pos * stdtrit(nu, 0.95) * sd[:, 3:]
    axis_in = np.abs(e[:, :3]) <= c_rot * stdtrit(nu, 0.95) * sd[:, :3]
    u = (paths.s[js] - span / D) / (1 - span / D)
    return pos_in, rot_in, rot_hot_in, axis_in, u, m2


def true_variances(paths, n=2000, seed=999):
    """Per grid phase, the generating process's rotation and position variance (S, 6) about the fitted mean path
    (rad², m²), from ``n`` fresh motions each at its own duration; and the prior Σ's (S, 6)."""
    fresh = rich_family(n, seed)
    dev = np.stack([paths.deviation_of(t.t, t.quat, t.position) for t in fresh])  # (n, S, 6)
    true = dev.var(axis=0) + (dev.mean(axis=0)) ** 2  # about the mean path: its bias counts
    m, Sigma = paths.prior()
    prior = np.diag(Sigma)[:-1].reshape(paths.S, 6) * paths.scale ** 2
    bias = (m[:-1].reshape(paths.S, 6) * paths.scale - dev.mean(axis=0)) ** 2
    return true, prior, bias


def every_phase_terms(paths, F, rest=None, ctx=None):
    """:func:`~rbgp_cli.dynamics.anticipation._spread_terms` at the remainder's true duration (V = 0, ȳ = x̂): the
    left-out remainders scored at every grid phase after F, each weighted by its share of the remainder's time."""
    return _spread_terms(paths, F, rest=rest, ctx=ctx, duration=False)


def fit(trajs):
    """fit_paths, with the bands' statistic chosen by STAT: '' the default, 'spread' the eighth pass's at every D,
    'every' every phase at the true duration."""
    import os

    from rbgp_cli.dynamics import anticipation

    stat = os.environ.get("STAT", "")
    if stat == "every":
        anticipation._spread_terms = every_phase_terms
    if stat:
        anticipation.SPREAD_FROM = 0
    return fit_paths(trajs)


def run(N, samples_big=400):
    acc = {F: dict(cv_pos=[], cv_rot=[], cv_axis=[], big_pos=[], big_rot=[], big_axis=[], g_pos=[], g_rot=[],
                   g_hot=[], g_axis=[], u_rot=[], g_ph=[], g_rotin=[], cv_axis3=[], u_pos=[], g_posin=[]) for F in FRACTIONS}
    factors = []
    var_ratio = []
    draws = int(__import__('os').environ.get('DRAWS', '2'))
    for sd in range(draws):
        trained = fit(rich_family(N, 10 + sd))
        ant = Anticipator(trained)
        factors.append(trained.seen_band_scales)
        true, prior, bias = true_variances(trained)
        var_ratio.append((prior / true))
        for i, tr in enumerate(rich_family(12, 100 + sd)):
            for F in FRACTIONS:
                seen, rest = split_seen(tr, F)
                a = acc[F]
                cont = ant.continuation(seen.t, seen.quat, seen.position, samples=20, seed=i)
                trs = cont.trajectories(include_samples=True)
                pin, rin, ain = detail(trs[1:], rest)
                a["cv_pos"].append(pin.mean()); a["cv_rot"].append(rin.mean()); a["cv_axis"].append(ain.mean())
                a["cv_axis3"].append(ain.mean(axis=0))
                a["u_rot"].append(rin)
                a["u_pos"].append(pin.mean(axis=1))
                if samples_big:
                    big = ant.continuation(seen.t, seen.quat, seen.position, samples=samples_big, seed=i)
                    pin, rin, ain = detail(big.trajectories(include_samples=True)[1:], rest)
                    a["big_pos"].append(pin.mean()); a["big_rot"].append(rin.mean()); a["big_axis"].append(ain.mean())
                c = ant.band_at(cont.estimate.phase)
                gp, gr, gh, ga, ph, m2 = gaussian_level(ant, seen, tr, c)
                a["g_pos"].append(gp.mean()); a["g_rot"].append(gr.mean()); a["g_hot"].append(gh.mean())
                a["g_axis"].append(ga.mean())
                a["g_ph"].append(ph)
                a["g_rotin"].append(gr)
                a["g_posin"].append(gp.mean(axis=1))
    print(f"## {N} trained ({draws} draws x 12 fresh, 20 samples; coverage pooled per motion then averaged)")
    print("factors:", [(np.round(f["rotation"], 2).tolist(), np.round(f["position"], 2).tolist()) for f in factors])
    print("| F | cv pos/rot | rot per axis | 400 samples pos/rot/axis | Gauss pos/rot | Gauss rot, Hotelling | Gauss rot per axis |")
    for F in FRACTIONS:
        a = acc[F]
        m = {k: np.mean(v) if len(v) else np.nan for k, v in a.items() if k not in ("u_rot", "g_ph", "g_rotin", "cv_axis3", "u_pos", "g_posin")}
        print(f"| {F} | {m['cv_pos']:.3f}/{m['cv_rot']:.3f} | {m['cv_axis']:.3f} | {m['big_pos']:.3f}/{m['big_rot']:.3f}/{m['big_axis']:.3f}"
              f" | {m['g_pos']:.3f}/{m['g_rot']:.3f} | {m['g_hot']:.3f} | {m['g_axis']:.3f} |")
    print("rotation per axis x/y/z (cv):", {F: np.round(np.mean(acc[F]["cv_axis3"], axis=0), 3).tolist() for F in FRACTIONS})
    print("rotation in the remainder's quarters (cv):",
          {F: np.round(np.mean(np.stack(acc[F]["u_rot"]).reshape(12 * draws, 4, 25), axis=(0, 2)), 3).tolist() for F in FRACTIONS})
    print("position in the remainder's quarters (cv):",
          {F: np.round(np.mean(np.stack(acc[F]["u_pos"]).reshape(12 * draws, 4, 25), axis=(0, 2)), 3).tolist() for F in FRACTIONS})

    def quarters(F, key="g_rotin"):
        u = np.concatenate(acc[F]["g_ph"])
        r = np.concatenate(acc[F][key])
        q = np.minimum((u * 4).astype(int), 3)
        return [round(float(r[q == k].mean()), 3) for k in range(4)]

    print("rotation in the remainder's quarters (Gauss, pooled over phases):", {F: quarters(F) for F in FRACTIONS})
    print("position in the remainder's quarters (Gauss):", {F: quarters(F, "g_posin") for F in FRACTIONS})
    vr = np.mean(var_ratio, axis=0)  # (S, 6)
    S = vr.shape[0]
    sl = [slice(0, S // 5), slice(S // 5, 2 * S // 5), slice(2 * S // 5, 3 * S // 5), slice(3 * S // 5, 4 * S // 5), slice(4 * S // 5, S)]
    print("prior variance / true variance per phase fifth, rot x,y,z | pos x,y,z:")
    for k, s_ in enumerate(sl):
        print(f"  s {k/5:.1f}-{(k+1)/5:.1f}:", np.round(vr[s_].mean(axis=0), 2).tolist())


def student_draws(self, count, rng, A, r2, gain, phase=1.0):
    """Anticipator._draws as before issue 37's ninth pass: Student-t draws, u = √(ν/χ²_ν) per draw (STUDENT=1)."""
    P = len(self.m)
    z = rng.standard_normal((count, P)) @ self._prior_root().T
    eps = rng.standard_normal((count, len(r2))) * np.sqrt(r2)
    eta = z - (z @ A.T + eps) @ gain.T
    nu = max(self.paths.demos - 2, 1)
    eta *= np.sqrt(nu / rng.chisquare(nu, count))[:, None]
    c_rot, c_pos = self.band_at(phase)
    eta[:, :-1] *= np.tile(np.array([c_rot] * 3 + [c_pos] * 3), self.paths.S)
    return eta


def own_nu_scales(m2_F, z_F, demos, level=0.90):
    """seen_band_scales with a factor below 1 taken from the left-out scores against their own model's quantiles
    (D − 1 demonstrations, ν = D − 3) instead of the full model's (ν = D − 2), then damped as before; factors ≥ 1
    as before (OWN_NU=1; issue 37's ninth pass, later; not kept)."""
    from rbgp_cli.dynamics.anticipation import NARROW_FROM
    from rbgp_cli.dynamics.paths import NARROWEST, _band_factors

    w = min(1.0, demos / NARROW_FROM)
    raw = [_band_factors(m2, z, demos, level) for m2, z in zip(m2_F, z_F)]
    own = [_band_factors(m2, z, demos - 1, level) for m2, z in zip(m2_F, z_F)]
    c = [[x if x >= 1.0 else max(NARROWEST, y ** w) for x, y in zip(a, b)] for a, b in zip(raw, own)]
    return {"fractions": list(FRACTIONS), "rotation": [float(x[0]) for x in c], "position": [float(x[1]) for x in c]}


if __name__ == "__main__":
    import os

    from rbgp_cli.dynamics import anticipation

    if os.environ.get("OWN_NU"):
        anticipation.seen_band_scales = own_nu_scales
    if os.environ.get("NOW"):  # no damping below NARROW_FROM: c < 1 taken as it is
        anticipation.NARROW_FROM = 1
    if os.environ.get("NARROW"):  # the continuation bands' narrowing from this many demonstrations (goal bands untouched)
        anticipation.NARROW_FROM = float(os.environ["NARROW"])
    if os.environ.get("STUDENT"):
        Anticipator._draws = student_draws
    for arg in sys.argv[1:]:
        run(int(arg), samples_big=int(__import__("os").environ.get("BIG", "400")))
