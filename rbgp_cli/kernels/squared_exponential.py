"""Squared-exponential kernels on SE(3) (paper eq. 24, docs/method.md §6).

    k(g_i, g_j) = σf² · exp(−d²(g_i, g_j) / (2 λ²)),
    d²(g_i, g_j) = ρ1 · d_rot(r_i, r_j)² + (1 − ρ1) · ‖t_i − t_j‖²        (eq. 19)

The rotation distance ``d_rot`` is chosen by ``metric``:

* ``"arc"``: d_arc = 2·acos|⟨q_i, q_j⟩| (eq. 14 with the absolute value) on canonical rotation vectors
  — the paper's rigid-body kernel. **Not positive semi-definite in general** (docs/method.md §6: Theorem 1
  is false); the GP guards against the resulting indefinite Gram matrices.
* ``"chordal"``: d_ch = 2·sqrt(1 − ⟨q_i, q_j⟩²) — a Euclidean distance of an embedding of SO(3),
  so the kernel is positive definite for every λ and ρ1. Our robust variant.
* ``"euclidean"``: ‖a_i − a_j‖ on the rotation coordinates as given (the Euler-angle baseline).
* ``"s3"``: acos|⟨q_i, q_j⟩| on unit quaternions (the quaternion baseline; half of d_arc).

Inputs X have shape (n, k + 3): rotation coordinates first (k = 3 for rotation vectors or Euler angles,
k = 4 for quaternions x, y, z, w), translation (metres) last. With ``time_dims = 1`` a last column holds
the time since the demonstration's start (or its phase), and the kernel is the product with a squared
exponential on it (still positive definite when the pose kernel is):

    k(x_i, x_j) = σf² · exp(−d²(g_i, g_j) / (2 λ²) − (τ_i − τ_j)² / (2 λτ²))

Hyperparameters: ``signal_std`` σf, ``length_scale`` λ, ``rho_rot`` ρ1 (fixed by default at the
paper's 0.7, or learned). Gradients with respect to their logs:

    ∂K/∂log σf = 2 K
    ∂K/∂log λ  = K ∘ d² / λ²
    ∂K/∂log ρ1 = −K ∘ ρ1 (d_rot² − ‖Δt‖²) / (2 λ²)
    ∂K/∂log λτ = K ∘ Δτ² / λτ²
"""

from __future__ import annotations

import math

import numpy as np

from rbgp_cli.kernels.base import Hyperparameter, Kernel, fdot, output_scale

__all__ = ["SquaredExponential", "ROTATION_METRICS"]

ROTATION_METRICS = ("arc", "chordal", "euclidean", "s3")
#: Smallest exponent −d²/(2λ²) used in a prediction's K(X*, X) (see :meth:`SquaredExponential.cross_gram`).
MIN_EXPONENT = -345.0
#: In the training Gram matrix K(X, X), entries whose exponent −d²/(2λ²) lies below this are exactly
#: zero (see :meth:`SquaredExponential.gram`): e^ZERO_EXPONENT ≈ 1e-75, whose products of two stay
#: normal double-precision numbers.
ZERO_EXPONENT = 0.5 * MIN_EXPONENT
#: Largest squared rotation distance of each metric on unit quaternions (arc: π², chordal: 4, s3: (π/2)²).
_MAX_SQ_ROTATION = {"arc": math.pi**2, "chordal": 4.0, "s3": (math.pi / 2) ** 2}


def _rotation_sq_distance(metric: str, A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Pairwise squared rotation distance, shape (n, m), for rotation blocks A (n, k), B (m, k)."""
    from rbgp_cli.geometry import distance

    if metric == "euclidean":
        return distance.pairwise_sq_distance(A, B)
    if metric == "s3":
        if A.shape[-1] != 4:
            raise ValueError("the 's3' rotation metric needs quaternion inputs (x, y, z, w)")
        from rbgp_cli.geometry.so3 import rotvec_from_quat

        # acos|<q1,q2>| = d_arc / 2
        d = distance.pairwise_rotation_distance(rotvec_from_quat(A), rotvec_from_quat(B), metric="arc")
        d *= 0.5
        return np.square(d, out=d)
    if metric in ("arc", "chordal"):
        if A.shape[-1] == 4:
            from rbgp_cli.geometry.so3 import rotvec_from_quat

            A, B = rotvec_from_quat(A), rotvec_from_quat(B)
        d = distance.pairwise_rotation_distance(A, B, metric=metric)
        return np.square(d, out=d)
    raise ValueError(f"unknown rotation metric {metric!r}; expected one of {ROTATION_METRICS}")


class SquaredExponential(Kernel):
    """σf² exp(−(ρ1 d_rot² + (1−ρ1)‖Δt‖²) / (2λ²)) on (rotation, translation) inputs (eq. 24).

    Parameters
    ----------
    metric : "arc" | "chordal" | "euclidean" | "s3" (see module docstring)
    rotation_dims : number of leading rotation columns of X (3 or 4); the last 3 are translation
    rho_rot : ρ1 in (0, 1); the rotation weight of eq. 19 (paper: 0.7)
    learn_rho : learn ρ1 (in log space, bounds [0.01, 0.99]) instead of fixing it
    time_dims : 0, or 1 for a trailing time / phase column with its own length-scale ``time_scale`` λτ
    """

    kind = "squared_exponential"
    #: k = σf² k̃ with k̃ free of σf (the sparse GP's bound has a closed-form σf gradient then)
    signal_scaled = True

    @property
    def mean_block_elements(self) -> int | None:
        """Query × training pairs per row block of a mean-only prediction (GaussianProcess.predict):
        ~88 000 (700 KB; the product's result and the rotation term of a block stay in a 2 MB L2
        cache through the arccos, square, add and exp passes) for the metrics whose rotation term
        is elementwise work; None (one block) for the chordal kernel, whose exponent is one product.
        Measured at B = 100, n = 1752 (two blocks of 50 rows), predictions alternating: arc 1.01 ->
        0.82 ms, chordal 0.41 -> 0.39 ms (but 8 -> 15 ms at m = 3000, from the per-block work)."""
        return None if self.metric == "chordal" else 88_000

    def __init__(self, metric: str = "arc", rotation_dims: int = 3, rho_rot: float = 0.7, learn_rho: bool = False,
                 time_dims: int = 0):
        if metric not in ROTATION_METRICS:
            raise ValueError(f"unknown rotation metric {metric!r}; expected one of {ROTATION_METRICS}")
        if not 0.0 < rho_rot < 1.0:
            raise ValueError(f"rho_rot must lie strictly between 0 and 1, got {rho_rot}")
        self.metric = metric
        self.rotation_dims = int(rotation_dims)
        self.rho_rot = float(rho_rot)
        self.learn_rho = bool(learn_rho)
        if time_dims not in (0, 1):
            raise ValueError(f"time_dims must be 0 or 1, got {time_dims}")
        self.time_dims = int(time_dims)
        self.names = ("signal_std", "length_scale", "rho_rot") + (("time_scale",) if time_dims else ())

    # ------------------------------------------------------------------ precomputation (once per fit)
    def precompute(self, Xa, Xb=None) -> dict:
        """Hyperparameter-free pairwise squared distances, each shape (n, m).

        With ρ1 fixed only ``d2`` = ρ1·d_rot² + (1−ρ1)·‖Δt‖² is kept; with ρ1 learned, ``rot2`` and
        ``trans2`` separately (d² is formed per evaluation, one fused n² pass).
        """
        from rbgp_cli.geometry.distance import pairwise_sq_distance

        Xa = np.asarray(Xa, dtype=np.float64)
        Xb = Xa if Xb is None else np.asarray(Xb, dtype=np.float64)
        k = self.rotation_dims
        rot2 = _rotation_sq_distance(self.metric, Xa[:, :k], Xb[:, :k])
        trans2 = pairwise_sq_distance(Xa[:, k:k + 3], Xb[:, k:k + 3])
        extra = {"tau2": pairwise_sq_distance(Xa[:, k + 3:], Xb[:, k + 3:])} if self.time_dims else {}
        if self.learn_rho:
            return {"rot2": rot2, "trans2": trans2, **extra}
        rot2 *= self.rho_rot
        trans2 *= 1.0 - self.rho_rot
        rot2 += trans2
        return {"d2": rot2, **extra}

    def cross_plan(self, Xb) -> dict:
        """Training-side data for :meth:`cross_precompute`: unit quaternions (4, n) of the rotations
        (or the Euclidean plan of the rotation coordinates) and the plan of the translations."""
        from rbgp_cli.geometry import distance

        Xb = np.ascontiguousarray(Xb, dtype=np.float64)
        k = self.rotation_dims
        plan = {"Xb": Xb, "trans": distance.sq_distance_plan(Xb[:, k:k + 3])}
        if self.time_dims:
            plan["tau"] = distance.sq_distance_plan(Xb[:, k + 3:])
        if self.metric == "euclidean":
            plan["rot"] = distance.sq_distance_plan(Xb[:, :k])
        else:
            if self.metric == "s3" and k != 4:
                raise ValueError("the 's3' rotation metric needs quaternion inputs (x, y, z, w)")
            plan["quat_t"] = distance.unit_quats_transposed(Xb[:, :k], k)
        # the right-hand side of the exponent's product (see cross_gram): rows [q_i q_j (10, chordal
        # only); −2 t_c (3); ‖t_c‖²; (−2 τ_c; τ_c²;) 1], translations and times centred
        rows = [distance.quat_square_features(plan["quat_t"].T).T] if self.metric == "chordal" else []
        rows.append(plan["trans"]["rhs"][:-1])
        if self.time_dims:
            rows.append(plan["tau"]["rhs"][:-1])
        rows.append(np.ones((1, len(Xb))))
        plan["exponent_rhs"] = np.ascontiguousarray(np.concatenate(rows, axis=0))
        return plan

    def cross_precompute(self, plan, Xa) -> dict:
        """:meth:`precompute` (Xa, Xb) for query rows Xa (m, d) against the plan's Xb, from matrix
        products (:func:`~rbgp_cli.geometry.distance.gram_sq_rotation_distance`,
        :func:`~rbgp_cli.geometry.distance.planned_sq_distance`) instead of elementwise pair work.
        d² agrees with :meth:`precompute` to ~1e-15 · (1 + ‖t‖²) absolute, so K to that over 2λ²
        relative; the fit keeps the precise distances."""
        from rbgp_cli.geometry import distance

        Xa = np.asarray(Xa, dtype=np.float64)
        k = self.rotation_dims
        learn = self.learn_rho
        rho = 1.0 if learn else self.rho_rot
        if self.metric == "euclidean":
            rot2 = distance.planned_sq_distance(plan["rot"], Xa[:, :k], rho)
        else:
            qa = distance.unit_quats(Xa[:, :k], k)
            rot2 = distance.gram_sq_rotation_distance(qa, plan["quat_t"], self.metric, rho)
        trans2 = distance.planned_sq_distance(plan["trans"], Xa[:, k:k + 3], 1.0 if learn else 1.0 - rho)
        extra = {"tau2": distance.planned_sq_distance(plan["tau"], Xa[:, k + 3:])} if self.time_dims else {}
        if learn:
            return {"rot2": rot2, "trans2": trans2, **extra}
        rot2 += trans2
        return {"d2": rot2, **extra}

    def cross_gram(self, plan, Xa, values) -> np.ndarray:
        """K(Xa, Xb) = σf² exp(−d²/2λ² [− Δτ²/2λτ²]) for query rows Xa against the plan's Xb, fused for
        one set of hyperparameters: everything of the exponent that is linear in features of the two
        sides comes out of ONE matrix product ``lhs @ rhs`` (``rhs``: the plan's ``exponent_rhs``,
        translations and times centred on the training set's means):

            a(1−ρ1) ‖t_a − t_b‖² [+ a_τ (τ_a − τ_b)²] + log σf²  [+ 4aρ1 (1 − G²) for the chordal kernel]

        with ``a = −1/(2λ²)``, ``a_τ = −1/(2λτ²)``, ``lhs`` = [[−4aρ1 · w∘(qa_i qa_j),] a(1−ρ1) t_a,c,
        a(1−ρ1), [a_τ τ_a,c, a_τ,] a(1−ρ1)‖t_a,c‖² [+ a_τ τ_a,c²] + log σf² [+ 4aρ1]]: for the chordal
        kernel ``G² = ⟨qa_i, qb_j⟩²`` is linear in the quaternions' square features
        (:func:`~rbgp_cli.geometry.distance.quat_square_features`), so its whole exponent is that one
        product; the other metrics add their rotation term (arc, s3: from the quaternion Gram
        matrix, :func:`~rbgp_cli.geometry.distance.gram_sq_rotation_distance`). Then one ``exp``.
        No clipping of 1 − G² or ‖Δt‖² at 0: their round-off (≲ 1e-15 absolute) moves K by that times
        |a| relative, as the clipped form did. Equal to :meth:`gram` of :meth:`precompute` to
        ~1e-15·(1 + ‖t‖²)/λ² relative, with the same floor of the exponent (MIN_EXPONENT) where the
        bound from the largest distances says it can matter."""
        from rbgp_cli.geometry import distance

        Xa = np.asarray(Xa, dtype=np.float64)
        k = self.rotation_dims
        m = len(Xa)
        rho = values["rho_rot"] if self.learn_rho else self.rho_rot
        a = -0.5 / values["length_scale"] ** 2
        log_sf2 = 2.0 * math.log(values["signal_std"])
        chordal = self.metric == "chordal"
        rhs = plan["exponent_rhs"]
        lhs = np.empty((m, rhs.shape[0]))
        j = 0
        if chordal:
            qa = distance.unit_quats(Xa[:, :k], k)
            distance.quat_square_features(qa, weighted=True, out=lhs[:, :10])
            lhs[:, :10] *= -4.0 * a * rho
            j = 10
        at = a * (1.0 - rho)
        tp = plan["trans"]
        tc = Xa[:, k:k + 3] - tp["centre"]
        np.multiply(tc, at, out=lhs[:, j:j + 3])
        lhs[:, j + 3] = at
        tn = np.einsum("ij,ij->i", tc, tc)
        # the largest ‖t_a − t_b‖² is at most (max ‖t_a,c‖ + max ‖t_b,c‖)²
        bound = at * (math.sqrt(float(np.max(tn))) + tp["radius"]) ** 2 if m else 0.0
        const = lhs[:, -1]
        np.multiply(tn, at, out=const)
        const += log_sf2 + (4.0 * a * rho if chordal else 0.0)
        if self.time_dims:
            a_tau = -0.5 / values["time_scale"] ** 2
            tau_p = plan["tau"]
            tau_c = Xa[:, k + 3] - tau_p["centre"][0]
            np.multiply(tau_c, a_tau, out=lhs[:, j + 4])
            lhs[:, j + 5] = a_tau
            const += a_tau * tau_c * tau_c
            bound += a_tau * distance.planned_max_sq_distance(tau_p, Xa[:, k + 3:])
        E = np.matmul(lhs, rhs)
        if chordal:
            rot_max = _MAX_SQ_ROTATION["chordal"]
        elif self.metric == "euclidean":
            E += distance.planned_sq_distance(plan["rot"], Xa[:, :k], a * rho)
            rot_max = distance.planned_max_sq_distance(plan["rot"], Xa[:, :k])
        else:
            qa = distance.unit_quats(Xa[:, :k], k)
            E += distance.gram_sq_rotation_distance(qa, plan["quat_t"], self.metric, a * rho)
            rot_max = _MAX_SQ_ROTATION[self.metric]
        if a * rho * rot_max + bound < MIN_EXPONENT:
            np.maximum(E, MIN_EXPONENT + log_sf2, out=E)
        np.exp(E, out=E)
        return E

    @property
    def positive_semidefinite(self) -> bool:
        """The chordal and Euclidean distances embed isometrically in a Euclidean space, so the squared
        exponential of them is positive definite for every λ; the geodesic (arc) and S³ angles are not
        (docs/method.md §6, MATH.md §6)."""
        return self.metric in ("chordal", "euclidean")

    @property
    def fused_cross_gradient(self) -> bool:
        """The chordal kernel's exponent is one product of features (:meth:`cross_gram`), and so is
        its gradient contraction (:meth:`cross_grad_contract`)."""
        return self.metric == "chordal"

    def cross_grad_contract(self, plan, Xa, values, K, W, names) -> np.ndarray:
        """Σ_ij W_ij ∂K_ij/∂log θ for K = :meth:`cross_gram` (plan, Xa, values), shape (m, n).

        The gradients (module docstring) need S_q = Σ_ij E_ij q_ij with E = W ∘ K for the pair arrays
        q ∈ {1, d_rot², ‖Δt‖², Δτ²}. For the chordal kernel each q is bilinear in the features whose
        product is :meth:`cross_gram`'s exponent (``lhs_q @ rhs`` with the plan's ``exponent_rhs``), so
        with P = E rhsᵀ (ONE product, (m, F), F ≤ 17) every S_q = Σ_i ⟨lhs_q,i, P_i⟩:

            d_rot² = 4 − 4 w∘sq(qa) · sq(qb),   ‖Δt‖² = ‖t_a,c‖² − 2 t_a,c · t_b,c + ‖t_b,c‖²  (Δτ² alike)

        and then ∂/∂log σf: 2 S_1, ∂/∂log λ: (ρ1 S_rot + (1 − ρ1) S_t) / λ², ∂/∂log ρ1:
        −ρ1 (S_rot − S_t) / (2λ²), ∂/∂log λτ: S_τ / λτ². No (m, n) pairwise arrays; the round-off is
        that of :meth:`cross_gram`'s exponent (~1e-15 of Σ|E| per S_q). Other metrics: the base
        class's route through :meth:`cross_precompute`."""
        if self.metric != "chordal":
            return super().cross_grad_contract(plan, Xa, values, K, W, names)
        from rbgp_cli.geometry import distance

        Xa = np.asarray(Xa, dtype=np.float64)
        k = self.rotation_dims
        E = np.multiply(W, K)
        rhs = plan["exponent_rhs"]  # rows: sq(qb) (10), −2 t_b,c (3), ‖t_b,c‖², [−2 τ_b,c, τ_b,c²,] 1
        P = np.matmul(E, rhs.T)
        one = P[:, -1]
        s_one = float(np.sum(one))
        qa = distance.unit_quats(Xa[:, :k], k)
        s_rot = 4.0 * s_one - 4.0 * float(np.einsum("ij,ij->", distance.quat_square_features(qa, weighted=True), P[:, :10]))
        tc = Xa[:, k:k + 3] - plan["trans"]["centre"]
        s_t = (float(np.einsum("ij,ij->", tc, P[:, 10:13])) + float(np.sum(P[:, 13]))
               + float(np.dot(np.einsum("ij,ij->i", tc, tc), one)))
        lam2 = values["length_scale"] ** 2
        rho = values["rho_rot"] if self.learn_rho else self.rho_rot
        out = np.empty(len(names))
        for i, name in enumerate(names):
            if name == "signal_std":
                out[i] = 2.0 * s_one
            elif name == "length_scale":
                out[i] = (rho * s_rot + (1.0 - rho) * s_t) / lam2
            elif name == "rho_rot":
                out[i] = -rho / (2.0 * lam2) * (s_rot - s_t)
            elif name == "time_scale":
                tau_c = Xa[:, k + 3] - plan["tau"]["centre"][0]
                s_tau = float(np.dot(tau_c, P[:, 14])) + float(np.sum(P[:, 15])) + float(np.dot(tau_c * tau_c, one))
                out[i] = s_tau / values["time_scale"] ** 2
            else:
                raise KeyError(name)
        return out

    def _d2(self, pre: dict, values: dict) -> np.ndarray:
        if "d2" in pre:
            return pre["d2"]
        rho = values["rho_rot"]
        d2 = pre["rot2"] * rho
        d2 += (1.0 - rho) * pre["trans2"]
        return d2

    # ------------------------------------------------------------------ Gram matrix and gradient
    def gram(self, pre: dict, values: dict):
        """K = σf² exp(−d²/(2λ²)), shape (n, m). The returned state is d² (reused by the gradient).

        Entries whose exponent lies below ZERO_EXPONENT are exactly 0: exp(−d²/2λ²) < e⁻¹⁷²·⁵ ≈ 1e-75
        (relative to σf²) changes nothing that double precision resolves in C = K + σn²I (its
        eigenvalues move by at most n·1e-75·σf², against the round-off of ~1e-16·σf² and the
        smallest eigenvalue ≥ 1e-12·‖C‖ that an accepted fit keeps), and it keeps the exp and
        everything downstream (Cholesky, C⁻¹, the gradient) free of subnormal numbers, whose
        arithmetic costs ~100 times a normal number's on x86. Raising the exponent to a floor instead
        (as :meth:`cross_gram` does for predictions) does not: the Cholesky factor's products of two
        floored entries underflow (at λ near its lower bound and σf = 1e-4 an evaluation at n = 400
        took 140–200 ms instead of 7 ms, measured in issue 35)."""
        d2 = self._d2(pre, values)
        lam = values["length_scale"]
        K = np.multiply(d2, -0.5 / (lam * lam))
        if "tau2" in pre:
            lt = values["time_scale"]
            K -= (0.5 / (lt * lt)) * pre["tau2"]
        if K.size and float(K.min()) < ZERO_EXPONENT:
            keep = K >= ZERO_EXPONENT
            np.maximum(K, ZERO_EXPONENT, out=K)
            np.exp(K, out=K)
            K *= keep
        else:
            np.exp(K, out=K)
        K *= values["signal_std"] ** 2
        return K, d2

    def grad_contract(self, pre, values, K, state, W, names) -> np.ndarray:
        """Σ_ij W_ij ∂K_ij/∂logθ for θ in ``names`` (see the module docstring for the formulas).

        ``K`` and ``state`` (the d²) are what :meth:`gram` returned; ``W`` has the shape of K.
        """
        lam2 = values["length_scale"] ** 2
        out = np.empty(len(names))
        WK = None
        for i, name in enumerate(names):
            if name == "signal_std":
                out[i] = 2.0 * fdot(W, K)
            elif name == "length_scale":
                if WK is None:
                    WK = W * K
                out[i] = fdot(WK, state) / lam2
            elif name == "rho_rot":
                if WK is None:
                    WK = W * K
                rho = values["rho_rot"]
                out[i] = -rho / (2.0 * lam2) * (fdot(WK, pre["rot2"]) - fdot(WK, pre["trans2"]))
            elif name == "time_scale":
                if WK is None:
                    WK = W * K
                out[i] = fdot(WK, pre["tau2"]) / values["time_scale"] ** 2
            else:
                raise KeyError(name)
        return out

    def gram_with_gradient(self, Xa, values, names):
        pre = self.precompute(Xa)
        K, d2 = self.gram(pre, values)
        n = K.shape[0]
        dK = np.empty((n, n, len(names)))
        lam2 = values["length_scale"] ** 2
        for i, name in enumerate(names):
            if name == "signal_std":
                dK[..., i] = 2.0 * K
            elif name == "length_scale":
                dK[..., i] = K * d2 / lam2
            elif name == "rho_rot":
                dK[..., i] = -K * values["rho_rot"] * (pre["rot2"] - pre["trans2"]) / (2.0 * lam2)
            elif name == "time_scale":
                dK[..., i] = K * pre["tau2"] / values["time_scale"] ** 2
        return K, dK

    def diag(self, X, values) -> np.ndarray:
        return np.full(len(X), values["signal_std"] ** 2)

    # ------------------------------------------------------------------ starts and description
    def default_hyperparameters(self, pre: dict, y: np.ndarray) -> dict:
        """Data-driven start (docs/method.md §7): λ ~ median pairwise distance, σf ~ RMS(y); bounds scale
        with the data (λ within [1e-3, 1e2] × median distance, σf within [1e-3, 1e2] × RMS(y)); the time
        scale λτ (with ``time_dims``) starts at half the median time difference."""
        d2 = self._d2(pre, {"rho_rot": self.rho_rot})
        n = d2.shape[0]
        iu = np.triu_indices(n, 1) if n <= 600 else _sample_pairs(n)
        med = float(np.sqrt(np.median(d2[iu]))) if n > 1 else 1.0
        if not np.isfinite(med) or med <= 0:
            med = 1.0
        sy = output_scale(y)
        out = {
            "signal_std": Hyperparameter("signal_std", sy, (1e-3 * sy, 1e2 * sy)),
            "length_scale": Hyperparameter("length_scale", med, (1e-3 * med, 1e2 * med)),
            "rho_rot": Hyperparameter("rho_rot", self.rho_rot, (0.01, 0.99), fixed=not self.learn_rho),
        }
        if self.time_dims:
            tau2 = pre["tau2"]
            mt = float(np.sqrt(np.median(tau2[iu]))) if n > 1 else 1.0
            if not np.isfinite(mt) or mt <= 0:
                mt = 1.0
            # start at half the median time difference: demonstrations change over a fraction of their
            # duration, and from the median itself most starts on the hand-raise takes descended into
            # the all-noise basin (λ, λτ → 0, σf ≪ σn; NLML 704 against 144, measured)
            out["time_scale"] = Hyperparameter("time_scale", 0.5 * mt, (1e-3 * mt, 1e2 * mt))
        return out

    def to_dict(self) -> dict:
        return {
            "kind": self.kind,
            "metric": self.metric,
            "rotation_dims": self.rotation_dims,
            "rho_rot": self.rho_rot,
            "learn_rho": self.learn_rho,
            "time_dims": self.time_dims,
        }


def _sample_pairs(n: int, k: int = 200_000):
    """A fixed, deterministic sample of index pairs i < j (for medians of large matrices)."""
    rng = np.random.default_rng(12345)
    i = rng.integers(0, n, k)
    j = rng.integers(0, n, k)
    keep = i < j
    return i[keep], j[keep]
