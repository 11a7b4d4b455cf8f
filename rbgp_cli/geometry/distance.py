"""Distances between rotations and poses, elementwise and as pairwise matrices (docs/method.md §5; eq. 14, 19).

Conventions (from :mod:`rbgp_cli.geometry.conventions`)
    * Rotations as canonical rotation vectors ``r`` (..., 3) or quaternions ``q`` (..., 4) with
      components x, y, z, w (any sign, normalised here). Poses (..., 6) = (rx, ry, rz, x, y, z),
      rotation first, metres.
    * float64, vectorised; elementwise functions broadcast their arguments.

Rotation distances (S³ angle ``φ = acos|⟨q1, q2⟩|`` between the unit quaternions)
    * arc (geodesic) distance ``d_arc = 2φ ∈ [0, π]``, the angle of ``R1ᵀR2`` (eq. 14 with the
      absolute value docs/method.md adds);
    * chordal distance ``d_ch = 2 sin φ = 2 sqrt(1 − ⟨q1, q2⟩²) = 2 sin(d_arc/2) ∈ [0, 2]``;
    * the S³ angle ``φ`` itself (the quaternion baseline's distance, half of ``d_arc``).

Numerics
    ``acos`` and ``1 − c²`` lose precision as ``c = |⟨q1, q2⟩| -> 1`` (an absolute error of ~1e-16 in
    c becomes ~1e-8 in φ at φ = 0). After aligning signs (``⟨q1, q2⟩ >= 0``), with
    ``‖q1 − q2‖ = 2 sin(φ/2)`` and ``‖q1 + q2‖ = 2 cos(φ/2)``, the elementwise functions use
    ``d_arc = 4·atan2(‖q1 − q2‖, ‖q1 + q2‖)`` and ``d_ch = ‖q1 − q2‖·‖q1 + q2‖``, which are accurate
    to a few ulp everywhere, including exactly 0 for equal quaternions.

    The pairwise matrices use the Gram matrix ``⟨qa_i, qb_j⟩`` and ``acos`` / ``sqrt(1 − c²)`` for
    the bulk of the pairs, and a difference-based formula for the pairs with
    ``φ < PAIRWISE_PRECISE_ANGLE`` (0.01 rad), where the Gram formula would be inaccurate: the
    elementwise formula on the gathered pairs when they are few, or, when a block has many (data
    clustered within a few degrees), ``‖qa − s·qb‖²`` for the whole block and the series of
    ``asin``. At the switch the Gram formula's absolute error is about ``1e-15/sin φ <= 1e-13`` rad,
    so the matrices agree with the elementwise functions to ~1e-13 (and to ~1e-15 relative for the
    close pairs). Large matrices are computed in row blocks (>= 64 rows, ~65k elements) on up to 4 threads (numpy
    releases the GIL in ufuncs; ``arccos`` dominates the cost), with the Gram products summed
    without BLAS (see ``_gram_block``). n = m = 1752 takes ~35 ms (arc) and ~17 ms (chordal) on
    2 cores, ~70 ms / ~45 ms when all pairs are close.
"""

from __future__ import annotations

import numpy as np

from rbgp_cli.compute import in_worker_process, thread_pool

from rbgp_cli.geometry.so3 import quat_from_rotvec, quat_normalize

__all__ = [
    "PAIRWISE_PRECISE_ANGLE",
    "arc_distance",
    "arc_distance_quat",
    "chordal_distance",
    "chordal_distance_quat",
    "pairwise_rotation_distance",
    "pairwise_quat_distance",
    "pairwise_s3_angle",
    "pairwise_sq_distance",
    "weighted_se3_sq_distance",
    "unit_quats",
    "unit_quats_transposed",
    "gram_sq_rotation_distance",
    "quat_square_features",
    "sq_distance_plan",
    "planned_sq_distance",
    "planned_max_sq_distance",
]

#: Pairs whose S³ angle φ = d_arc/2 is below this (rad) are recomputed by the difference formula.
PAIRWISE_PRECISE_ANGLE = 0.01
_COS_PRECISE = float(np.cos(PAIRWISE_PRECISE_ANGLE))

_METRICS = ("arc", "chordal")

#: Row-block size and the work (n·m) above which blocks are spread over threads.
_BLOCK_ROWS = 64
_BLOCK_ELEMENTS = 65_536
_PARALLEL_MIN_WORK = 200_000
#: Above this fraction of close pairs in a block, their precise distances are computed densely.
_DENSE_FRACTION = 0.02
def _as_array(x, n: int, name: str) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64)
    if a.ndim == 0 or a.shape[-1] != n:
        raise ValueError(f"{name}: expected shape (..., {n}), got {a.shape}")
    return a


def _as_rows(x, n: int | None, name: str) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64)
    if a.ndim != 2 or (n is not None and a.shape[1] != n):
        want = f"(n, {n})" if n is not None else "(n, k)"
        raise ValueError(f"{name}: expected shape {want}, got {a.shape}")
    return a


def _check_metric(metric: str) -> None:
    if metric not in _METRICS:
        raise ValueError(f"metric must be one of {_METRICS}, got {metric!r}")


def _norm(x: np.ndarray) -> np.ndarray:
    return np.sqrt(np.einsum("...i,...i->...", x, x))


def _diff_sum_norms(q1: np.ndarray, q2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``‖q1 − q2‖`` and ``‖q1 + q2‖`` after flipping ``q2`` to ``⟨q1, q2⟩ >= 0`` (unit inputs)."""
    s = np.where(np.sum(q1 * q2, axis=-1, keepdims=True) < 0, -1.0, 1.0)
    q2 = q2 * s
    return _norm(q1 - q2), _norm(q1 + q2)


# ----------------------------------------------------------------------------------------------
# Elementwise
# ----------------------------------------------------------------------------------------------


def arc_distance_quat(q1, q2) -> np.ndarray:
    """Arc (geodesic) distance of rotations given as quaternions (eq. 14 corrected; docs/method.md §5).

    ``d_arc = 2·acos|⟨q1, q2⟩| = 4·atan2(‖q1 − q2‖, ‖q1 + q2‖)`` after sign alignment, in [0, π];
    the angle of ``R1ᵀR2``; invariant to ``q -> −q``. Shapes (..., 4) (x, y, z, w; normalised
    here), broadcast; returns (...).
    """
    q1 = quat_normalize(q1)
    q2 = quat_normalize(q2)
    a, b = _diff_sum_norms(q1, q2)
    return np.minimum(4.0 * np.arctan2(a, b), np.pi)  # min: round-off at exactly π apart


def arc_distance(r1, r2) -> np.ndarray:
    """Arc (geodesic) distance of rotations given as rotation vectors (eq. 14; docs/method.md §5).

    ``d_arc(r1, r2) = 2·acos|⟨q1, q2⟩| ∈ [0, π]``, computed as in :func:`arc_distance_quat`.
    Any rotation vectors (canonical or not). Shapes (..., 3), broadcast; returns (...).
    """
    r1 = _as_array(r1, 3, "arc_distance r1")
    r2 = _as_array(r2, 3, "arc_distance r2")
    return arc_distance_quat(quat_from_rotvec(r1), quat_from_rotvec(r2))


def chordal_distance_quat(q1, q2) -> np.ndarray:
    """Chordal rotation distance of quaternions: ``2·sqrt(1 − ⟨q1, q2⟩²) = 2 sin(d_arc/2)`` (docs/method.md §5).

    Computed as ``‖q1 − q2‖·‖q1 + q2‖`` (= ``4 sin(φ/2) cos(φ/2)``, no cancellation; the product is
    the same for either sign of ``q2``). In [0, 2]. Shapes (..., 4), broadcast; returns (...).
    """
    q1 = quat_normalize(q1)
    q2 = quat_normalize(q2)
    return np.minimum(_norm(q1 - q2) * _norm(q1 + q2), 2.0)  # min: round-off at π apart


def chordal_distance(r1, r2) -> np.ndarray:
    """Chordal rotation distance ``2·sqrt(1 − ⟨q1, q2⟩²) = 2 sin(d_arc/2)`` of rotation vectors.

    ``d_ch² = ½‖q1q1ᵀ − q2q2ᵀ‖²_F``: a Euclidean distance of an embedding of SO(3), so a Gaussian of
    it is positive definite (docs/method.md §5, §6). Shapes (..., 3), broadcast; returns (...) in [0, 2].
    """
    r1 = _as_array(r1, 3, "chordal_distance r1")
    r2 = _as_array(r2, 3, "chordal_distance r2")
    return chordal_distance_quat(quat_from_rotvec(r1), quat_from_rotvec(r2))


# ----------------------------------------------------------------------------------------------
# Pairwise
# ----------------------------------------------------------------------------------------------


def _run_blocks(n: int, m: int, block) -> None:
    """Call ``block(slice)`` on row blocks of an (n, m) result, on threads when it is large.

    A block has at least _BLOCK_ROWS rows and about _BLOCK_ELEMENTS elements, so that a tall,
    narrow matrix (10⁴ query poses × 80 training poses) is not cut into hundreds of tiny tasks
    whose scheduling costs more than their work.
    """
    rows = max(_BLOCK_ROWS, -(-_BLOCK_ELEMENTS // max(m, 1)))
    slices = [slice(i, min(i + rows, n)) for i in range(0, n, rows)]
    # worker processes (one per core already) compute on the calling thread
    if n * m >= _PARALLEL_MIN_WORK and len(slices) > 1 and not in_worker_process():
        for f in [thread_pool("distance").submit(block, sl) for sl in slices]:
            f.result()
    else:
        for sl in slices:
            block(sl)


def _gram_block(a: np.ndarray, bt: np.ndarray, o: np.ndarray) -> None:
    """``o = a @ bt`` for a few columns (k <= 8) without BLAS, as a sum of outer products.

    OpenBLAS worker threads busy-wait for a while after each call and would take the cores our
    own row-block threads need; for k = 3 or 4 the plain sum is as fast anyway.
    """
    np.multiply(a[:, :1], bt[0], out=o)
    if bt.shape[0] > 1:
        tmp = np.empty_like(o)
        for k in range(1, bt.shape[0]):
            np.multiply(a[:, k : k + 1], bt[k], out=tmp)
            o += tmp


def _small_angle_from_sq_chord(d2: np.ndarray, c: np.ndarray, kind: str) -> np.ndarray:
    """Distance of close pairs from ``d2 = ‖qa − s·qb‖²`` (signs aligned) and ``c = |⟨qa, qb⟩|``.

    ``x = sqrt(d2)/2 = sin(φ/2)``; ``φ/2 = asin x = x (1 + x²/6 + 3x⁴/40 + 5x⁶/112 + …)``, the next
    term below 1e-19 relative for φ < PAIRWISE_PRECISE_ANGLE. Chordal: ``‖qa − s qb‖·‖qa + s qb‖``
    with ``‖qa + s qb‖² = 2 + 2c`` (no cancellation). Valid only where ``c > cos(PRECISE_ANGLE)``.
    """
    if kind == "chordal":
        return np.sqrt(d2 * (2.0 + 2.0 * c))
    x2 = 0.25 * d2
    half = np.sqrt(x2) * (1.0 + x2 * (1.0 / 6.0 + x2 * (3.0 / 40.0 + x2 * (5.0 / 112.0))))
    return half * (4.0 if kind == "arc" else 2.0)


def _pairwise_quat(qa: np.ndarray, qb: np.ndarray, kind: str) -> np.ndarray:
    """(n, m) matrix of ``kind`` in {"arc", "chordal", "s3"} between unit quaternions (n,4), (m,4)."""
    n, m = qa.shape[0], qb.shape[0]
    out = np.empty((n, m))
    qbt = np.ascontiguousarray(qb.T)

    def block(sl: slice) -> None:
        o = out[sl]
        qa_blk = qa[sl]
        g = np.empty_like(o)
        _gram_block(qa_blk, qbt, g)  # ⟨qa_i, qb_j⟩
        c = np.abs(g, out=o)
        # Pairs with φ < PAIRWISE_PRECISE_ANGLE get a difference-based formula (module doc).
        close = c > _COS_PRECISE
        n_close = int(np.count_nonzero(close))
        precise = None
        if n_close > _DENSE_FRACTION * close.size:
            # many close pairs (clustered data): ‖qa − s·qb‖² for the whole block, s = sign⟨qa, qb⟩
            sgn = np.copysign(1.0, g, out=g)
            d2 = np.zeros_like(o)
            tmp = np.empty_like(o)
            for k in range(4):
                np.multiply(sgn, qbt[k], out=tmp)
                np.subtract(qa_blk[:, k : k + 1], tmp, out=tmp)
                tmp *= tmp
                d2 += tmp
            precise = _small_angle_from_sq_chord(d2, c, kind)
        elif n_close:
            # a few close pairs: gather them, exactly the elementwise formula
            ii, jj = np.nonzero(close)
            a = qa_blk[ii]
            b = qb[jj]
            b = b * np.where(np.sum(a * b, axis=-1) < 0, -1.0, 1.0)[:, None]
            dn, sn = _norm(a - b), _norm(a + b)
            if kind == "chordal":
                vals = dn * sn
            else:
                vals = np.arctan2(dn, sn) * (4.0 if kind == "arc" else 2.0)
        np.minimum(c, 1.0, out=c)
        if kind == "chordal":
            # 2 sqrt(1 − c²) = 2 sqrt((1 − c)(1 + c))
            tmp = np.add(1.0, c)
            np.subtract(1.0, c, out=o)
            o *= tmp
            np.sqrt(o, out=o)
            o *= 2.0
        else:
            np.arccos(c, out=o)
            if kind == "arc":
                o *= 2.0
        if precise is not None:
            np.copyto(o, precise, where=close)
        elif n_close:
            o[ii, jj] = vals

    _run_blocks(n, m, block)
    return out


def pairwise_quat_distance(q_a, q_b, metric: str = "arc") -> np.ndarray:
    """Pairwise rotation distances between quaternion sets, shape (n, m) (docs/method.md §5).

    ``metric="arc"``: ``2·acos|⟨qa_i, qb_j⟩|`` ∈ [0, π]; ``"chordal"``: ``2·sqrt(1 − ⟨qa_i, qb_j⟩²)``
    ∈ [0, 2]. ``q_a`` (n, 4), ``q_b`` (m, 4), components x, y, z, w, any sign (normalised here).
    Accuracy: equal to :func:`arc_distance_quat` / :func:`chordal_distance_quat` to ~1e-13 (module
    doc).
    """
    _check_metric(metric)
    qa = quat_normalize(_as_rows(q_a, 4, "pairwise_quat_distance q_a"))
    qb = quat_normalize(_as_rows(q_b, 4, "pairwise_quat_distance q_b"))
    return _pairwise_quat(qa, qb, metric)


def pairwise_rotation_distance(r_a, r_b, metric: str = "arc") -> np.ndarray:
    """Pairwise rotation distances between rotation-vector sets, shape (n, m) (eq. 14; docs/method.md §5).

    ``metric="arc"``: ``d_arc = 2·acos|⟨qa_i, qb_j⟩|`` ∈ [0, π]; ``"chordal"``:
    ``d_ch = 2·sqrt(1 − ⟨qa_i, qb_j⟩²) = 2 sin(d_arc/2)`` ∈ [0, 2]. ``r_a`` (n, 3), ``r_b`` (m, 3)
    (rx, ry, rz), converted to quaternions once. Gram matmul for the bulk, the difference formula
    where ``d_arc < 0.02`` rad; equal to :func:`arc_distance` / :func:`chordal_distance` to ~1e-13.
    """
    _check_metric(metric)
    # normalised as in the elementwise functions, so the close pairs agree with them bit for bit
    qa = quat_normalize(quat_from_rotvec(_as_rows(r_a, 3, "pairwise_rotation_distance r_a")))
    qb = quat_normalize(quat_from_rotvec(_as_rows(r_b, 3, "pairwise_rotation_distance r_b")))
    return _pairwise_quat(qa, qb, metric)


def pairwise_s3_angle(q_a, q_b) -> np.ndarray:
    """Pairwise S³ angle ``acos|⟨qa_i, qb_j⟩|`` ∈ [0, π/2] (half of ``d_arc``), shape (n, m).

    The rotation distance of the quaternion baseline (docs/method.md §6). ``q_a`` (n, 4), ``q_b`` (m, 4),
    x, y, z, w, any sign (normalised here). Accurate near 0 as :func:`pairwise_quat_distance`.
    """
    qa = quat_normalize(_as_rows(q_a, 4, "pairwise_s3_angle q_a"))
    qb = quat_normalize(_as_rows(q_b, 4, "pairwise_s3_angle q_b"))
    return _pairwise_quat(qa, qb, "s3")


def pairwise_sq_distance(a, b) -> np.ndarray:
    """Pairwise squared Euclidean distances ``‖a_i − b_j‖²``, shape (n, m); ``a`` (n, k), ``b`` (m, k).

    For ``k <= 8`` (translations, Euler poses) computed directly as ``Σ_l (a_il − b_jl)²`` (scipy's
    ``cdist``): exact
    to round-off, ``>= 0``, exactly 0 for identical rows. For more columns by the expansion
    ``‖a_i‖² + ‖b_j‖² − 2⟨a_i, b_j⟩`` (one matmul) after subtracting the mean of ``b`` from both
    (which shrinks the norms and so the cancellation), clipped at 0; pairs whose result is below
    ``1e-6·(‖a_i‖² + ‖b_j‖²)`` (where the expansion can lose more than ~1e-10 relative) are then
    recomputed directly, so identical rows give exactly 0 there too.
    """
    a = _as_rows(a, None, "pairwise_sq_distance a")
    b = _as_rows(b, None, "pairwise_sq_distance b")
    if a.shape[1] != b.shape[1]:
        raise ValueError(f"pairwise_sq_distance: a has {a.shape[1]} columns, b has {b.shape[1]}")
    n, m, k = a.shape[0], b.shape[0], a.shape[1]
    if n == 0 or m == 0 or k == 0:
        return np.zeros((n, m))

    if k <= 8:
        from scipy.spatial.distance import cdist

        # Σ_l (a_il − b_jl)² in C, one pass (4–9× faster than numpy passes over the columns)
        return cdist(a, b, "sqeuclidean")

    out = np.empty((n, m))
    centre = b.mean(axis=0)
    ac = a - centre
    bc = b - centre
    na = np.einsum("ij,ij->i", ac, ac)
    nb = np.einsum("ij,ij->i", bc, bc)
    np.matmul(ac, bc.T, out=out)
    out *= -2.0
    out += na[:, None]
    out += nb[None, :]
    np.maximum(out, 0.0, out=out)
    ii, jj = np.nonzero(out <= 1e-6 * (na[:, None] + nb[None, :]))
    if ii.size:
        d = a[ii] - b[jj]
        out[ii, jj] = np.einsum("ij,ij->i", d, d)
    return out


def weighted_se3_sq_distance(g_a, g_b, rho_rot: float = 0.7, metric: str = "arc") -> np.ndarray:
    """Squared weighted SE(3) distance matrix (eq. 19): ``ρ1·d_rot(r_i, r_j)² + (1 − ρ1)·‖t_i − t_j‖²``.

    ``d_rot`` is the arc distance (the paper's choice, ``metric="arc"``) or the chordal distance
    (``"chordal"``, whose squared-exponential kernel is positive definite; docs/method.md §6).
    ``rho_rot`` = ρ1 ∈ [0, 1] weighs rotation (paper: 0.7), ρ2 = 1 − ρ1 translation.
    ``g_a`` (n, 6), ``g_b`` (m, 6): (rx, ry, rz, x, y, z), metres. Returns (n, m).
    """
    _check_metric(metric)
    rho = float(rho_rot)
    if not 0.0 <= rho <= 1.0:
        raise ValueError(f"rho_rot must be in [0, 1], got {rho_rot}")
    g_a = _as_rows(g_a, 6, "weighted_se3_sq_distance g_a")
    g_b = _as_rows(g_b, 6, "weighted_se3_sq_distance g_b")
    d_rot = pairwise_rotation_distance(g_a[:, :3], g_b[:, :3], metric=metric)
    d_t2 = pairwise_sq_distance(g_a[:, 3:], g_b[:, 3:])
    d_rot *= d_rot
    d_rot *= rho
    d_t2 *= 1.0 - rho
    d_rot += d_t2
    return d_rot


# ----------------------------------------------------------------------------------------------
# Squared distances for kernels: one matrix product per block (predictions, rollouts)
# ----------------------------------------------------------------------------------------------


def unit_quats(rot, rotation_dims: int) -> np.ndarray:
    """Unit quaternions (n, 4) of rotation vectors (n, 3) or of quaternions (n, 4) (x, y, z, w,
    any sign and norm): the left-hand side of :func:`gram_sq_rotation_distance`."""
    rot = _as_rows(rot, rotation_dims, "unit_quats rot")
    return quat_normalize(quat_from_rotvec(rot) if rotation_dims == 3 else rot)


def unit_quats_transposed(rot, rotation_dims: int) -> np.ndarray:
    """:func:`unit_quats` as a C-contiguous (4, n) array: the right-hand side of
    :func:`gram_sq_rotation_distance`."""
    return np.ascontiguousarray(unit_quats(rot, rotation_dims).T)


def gram_sq_rotation_distance(qa, qbt, metric: str = "arc", scale: float = 1.0, out=None) -> np.ndarray:
    """Squared rotation distances of all pairs from ONE matrix product of unit quaternions.

    ``G = qa @ qbt`` with ``qa`` (m, 4) and ``qbt`` (4, n) unit quaternions (the second set
    transposed, see :func:`unit_quats_transposed`), ``c = min(|G|, 1)``, then elementwise

    * ``"arc"``: ``d² = 4·acos²(c)`` (the square of :func:`arc_distance_quat`);
    * ``"chordal"``: ``d² = 4·(1 − G²)`` (clipped at 0; the square of :func:`chordal_distance_quat`);
    * ``"s3"``: ``d² = acos²(c)`` (the square of :func:`pairwise_s3_angle`).

    Returns ``scale · d²``, shape (m, n), written into ``out`` if given. Accuracy, without a small-angle branch: the
    *squares* are smooth functions of c at c = 1 (``d acos²(c)/dc -> −2``), so the ~2e-16 error of c
    (a 4-term dot product of unit vectors) moves d² by at most ~1e-15 absolute, everywhere. That is
    what a kernel ``exp(−d²/2λ²)`` needs (relative error ≲ 1e-15/λ²); it is not a relative accuracy
    of tiny distances themselves, for which :func:`pairwise_rotation_distance` keeps its precise
    branch (module doc). The work is one matmul and 3–5 passes over the (m, n) block.
    """
    if metric not in ("arc", "chordal", "s3"):
        raise ValueError(f"metric must be one of ('arc', 'chordal', 's3'), got {metric!r}")
    qa = np.ascontiguousarray(qa, dtype=np.float64)
    G = np.matmul(qa, qbt, out=out)
    if metric == "chordal":
        np.square(G, out=G)
        np.subtract(1.0, G, out=G)
        np.maximum(G, 0.0, out=G)
        G *= 4.0 * scale
        return G
    np.abs(G, out=G)
    np.minimum(G, 1.0, out=G)
    np.arccos(G, out=G)
    np.square(G, out=G)
    factor = (4.0 if metric == "arc" else 1.0) * scale
    if factor != 1.0:
        G *= factor
    return G


#: The 10 index pairs (i <= j) of the symmetric products q_i q_j of a quaternion, and the weight of
#: each pair in ⟨qa, qb⟩² = Σ_i qa_i² qb_i² + 2 Σ_{i<j} qa_i qa_j qb_i qb_j.
_PAIRS_I, _PAIRS_J = np.triu_indices(4)
_PAIR_WEIGHTS = np.where(_PAIRS_I == _PAIRS_J, 1.0, 2.0)


def quat_square_features(q, weighted: bool = False, out=None) -> np.ndarray:
    """The 10 products ``q_i q_j`` (i <= j) of each quaternion, shape (m, 10) (into ``out`` if given):
    with the weights (1 on the diagonal, 2 off it) on one side, ``⟨qa, qb⟩² = feat(qa, weighted=True)
    · feat(qb)``, so ``G² = ⟨qa_i, qb_j⟩²`` of all pairs, and with it the squared chordal distance
    ``4(1 − G²)``, is ONE matrix product, linear in the features: scales, other squared distances
    and constants fold into the same product (:meth:`SquaredExponential.cross_gram`). Each product
    of two unit quaternions' features is a sum of 10 terms of magnitude ≤ 2, so G² has an absolute
    error of a few 1e-16, like the square of the 4-term dot product."""
    q = np.asarray(q, dtype=np.float64)
    f = np.multiply(q[:, _PAIRS_I], q[:, _PAIRS_J], out=out)
    if weighted:
        f *= _PAIR_WEIGHTS
    return f


def sq_distance_plan(b) -> dict:
    """The hyperparameter-free part of :func:`planned_sq_distance` for a fixed second set b (n, k)."""
    b = _as_rows(b, None, "sq_distance_plan b")
    centre = b.mean(axis=0) if len(b) else np.zeros(b.shape[1])
    bc = b - centre
    # columns of [−2·b_c, ‖b_c‖², 1] (rows of the transposed matrix), so that
    # [a_c, 1, ‖a_c‖²] @ rhs = ‖a_c‖² − 2⟨a_c, b_c⟩ + ‖b_c‖²
    rhs = np.empty((b.shape[1] + 2, len(b)))
    rhs[:-2] = -2.0 * bc.T
    rhs[-2] = np.einsum("ij,ij->i", bc, bc)
    rhs[-1] = 1.0
    radius = float(np.sqrt(np.max(rhs[-2]))) if len(b) else 0.0
    return {"centre": centre, "rhs": rhs, "k": b.shape[1], "radius": radius}


def planned_max_sq_distance(plan: dict, a) -> float:
    """An upper bound of ``‖a_i − b_j‖²`` over all pairs: ``(max‖a_c‖ + max‖b_c‖)²``."""
    a = _as_rows(a, plan["k"], "planned_max_sq_distance a")
    if len(a) == 0:
        return 0.0
    ac = a - plan["centre"]
    return (float(np.sqrt(np.max(np.einsum("ij,ij->i", ac, ac)))) + plan["radius"]) ** 2


def planned_sq_distance(plan: dict, a, scale: float = 1.0, offset: float = 0.0, out=None) -> np.ndarray:
    """``scale · ‖a_i − b_j‖² + offset`` for all pairs, shape (m, n), by one matrix product with the
    plan of b (:func:`sq_distance_plan`): ``‖a_c‖² − 2⟨a_c, b_c⟩ + ‖b_c‖²`` after subtracting b's mean
    from both (which keeps the norms, and so the cancellation, small); ``scale`` and ``offset`` are
    folded into the product. ``‖a_i − b_j‖²`` is clipped at 0 where ``scale > 0`` (round-off can make
    it about −1e-16). Absolute error about ``1e-16 · (‖a_c‖² + ‖b_c‖²)`` (exact to round-off:
    :func:`pairwise_sq_distance`)."""
    a = _as_rows(a, plan["k"], "planned_sq_distance a")
    ac = a - plan["centre"]
    lhs = np.empty((len(a), plan["k"] + 2))
    lhs[:, :-2] = ac
    lhs[:, -2] = 1.0
    lhs[:, -1] = np.einsum("ij,ij->i", ac, ac)
    if scale != 1.0:
        lhs *= scale
    if offset != 0.0:
        lhs[:, -1] += offset  # multiplies the row of ones
    D = np.matmul(lhs, plan["rhs"], out=out)
    if scale > 0:
        np.maximum(D, offset, out=D)
    return D

