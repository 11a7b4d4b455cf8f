"""Rigid bodies from 3D markers: finding rigid clusters and fitting their pose per frame.

A rigid object tracked by markers (a tool, a head band, a thigh plate, a box) is a group of three or
more markers whose pairwise distances stay constant. :func:`find_clusters` finds such groups in
marker trajectories; :func:`reference_shape` makes a cluster's shape in its own body frame;
:func:`fit_poses` fits that shape to the markers seen in every frame (least squares, Kabsch / SVD with
the reflection guard), giving the pose body -> world and the fit's RMS residual.

Conventions: markers ``(F, n, 3)`` in metres in the world (lab) frame, a lost marker as a NaN row;
rotations as matrices ``R_world_body`` with ``p_world = R_world_body @ p_body + t_world_body``.
The body frame is stated by :func:`reference_shape`: origin at the markers' centroid, axes those of
the lab in the first frame where every marker of the cluster is seen and fits the shape.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["CLUSTER_STD_TOL_M", "FIT_RMS_TOL_M", "MIN_SEEN_TOGETHER", "Cluster", "pair_distance_std",
           "find_clusters", "reference_shape", "fit_poses", "kabsch"]

#: Markers belong to one rigid cluster when every pair's distance varies by at most this robust standard
#: deviation (metres; :func:`pair_distance_std`) over the frames in which both are seen. The box of
#: ../shared/realdata/c3d_vicon keeps its 8 markers within 0.41 mm (std); markers on skin over one bone
#: vary by 1-5 mm.
CLUSTER_STD_TOL_M = 1e-3
#: A frame whose fitted markers are off the reference shape by more than this RMS distance (metres) is
#: a lost frame (a swapped, ghost or wobbling marker): the pose is not trusted there.
FIT_RMS_TOL_M = 5e-3
#: Two markers count as a rigid pair only when seen together in at least this share of the frames.
MIN_SEEN_TOGETHER = 0.5
#: Clusters are found on at most this many frames, evenly spread over the take (a long take costs no more).
MAX_FRAMES = 600


@dataclass(frozen=True)
class Cluster:
    """A group of markers found rigid: ``name``, ``markers`` (indices into the labels), their
    ``labels``, the largest pairwise distance std ``max_std_m`` and the number of frames in which
    every marker is seen (``frames_all_seen``)."""

    name: str
    markers: tuple
    labels: tuple
    max_std_m: float
    frames_all_seen: int


def _column_median(a: np.ndarray) -> np.ndarray:
    """The median of each column of ``a`` (F, k) over its finite values (each column has one at
    least); ``np.nanmedian`` without its slow path (sorting puts NaN last)."""
    srt = np.sort(a, axis=0)
    cnt = np.sum(np.isfinite(a), axis=0)
    cols = np.arange(a.shape[1])
    return 0.5 * (srt[(cnt - 1) // 2, cols] + srt[cnt // 2, cols])


def pair_distance_std(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For markers ``points`` (F, n, 3) (NaN rows lost): ``(spread, together)``, both (n, n): how much
    each pair's distance varies over the frames where both are seen, as a robust standard deviation
    (1.4826 × the median absolute deviation from the median, so that a few frames with a swapped or
    ghost marker do not hide a rigid pair; NaN where fewer than two frames), and the share of frames
    in which both are seen."""
    seen = np.all(np.isfinite(points), axis=-1)  # (F, n)
    n = points.shape[1]
    std = np.full((n, n), np.nan)
    together = (seen.T.astype(float) @ seen.astype(float)) / max(len(points), 1)
    for i in range(n - 1):
        both = seen[:, i : i + 1] & seen[:, i + 1 :]
        d = np.linalg.norm(points[:, i : i + 1] - points[:, i + 1 :], axis=-1)  # (F, n - i - 1)
        d = np.where(both, d, np.nan)
        ok = both.sum(axis=0) >= 2
        if not ok.any():
            continue
        med = _column_median(d[:, ok])
        s = np.full(n - i - 1, np.nan)
        s[ok] = 1.4826 * _column_median(np.abs(d[:, ok] - med))
        std[i, i + 1 :] = s
        std[i + 1 :, i] = s
    return std, together


#: :func:`_maximal_cliques` stops after this many steps (a dense graph of many markers) and
#: :func:`find_clusters` then grows cliques greedily instead.
CLIQUE_STEPS = 20_000


def _maximal_cliques(adj: list[set]) -> list[set] | None:
    """Every maximal clique of an undirected graph (Bron–Kerbosch with a pivot), or None after
    :data:`CLIQUE_STEPS` steps."""
    out: list[set] = []
    steps = [0]

    def expand(r: set, p: set, x: set) -> bool:
        steps[0] += 1
        if steps[0] > CLIQUE_STEPS:
            return False
        if not p and not x:
            out.append(r)
            return True
        pivot = max(p | x, key=lambda u: len(adj[u] & p))
        for v in list(p - adj[pivot]):
            if not expand(r | {v}, p & adj[v], x & adj[v]):
                return False
            p = p - {v}
            x = x | {v}
        return True

    return out if expand(set(), set(range(len(adj))), set()) else None


def _greedy_cliques(adj: list[set]) -> list[set]:
    """Cliques grown greedily: from the vertex with the most neighbours left, add the neighbour of
    every member that has the most neighbours, until none is left; repeat on what remains."""
    left = set(range(len(adj)))
    out = []
    while left:
        seed = max(left, key=lambda u: (len(adj[u] & left), -u))
        clique, cand = {seed}, adj[seed] & left
        while cand:
            v = max(cand, key=lambda u: (len(adj[u] & cand), -u))
            clique.add(v)
            cand &= adj[v]
        out.append(clique)
        left -= clique
    return out


def label_prefix(label: str) -> str:
    """The set prefix of a marker label (``"boite:gauche_ext"`` -> ``"boite"``; ``""`` without one)."""
    return label.split(":", 1)[0] if ":" in label else ""


def _bare(label: str) -> str:
    return label.split(":", 1)[1] if ":" in label else label


def _common_start(names) -> str:
    names = list(names)
    first = names[0]
    k = 0
    while k < len(first) and all(len(s) > k and s[k].lower() == first[k].lower() for s in names):
        k += 1
    return first[:k].rstrip("_-. 0123456789")


def cluster_name(labels: list[str], members, taken: set) -> str:
    """A cluster's name: the label prefix its markers share and no other marker has (``boite``), else
    the start their names share (``RTH`` for RTH1..RTH4, ``STER`` for STERl, STERr), else its first
    markers joined by ``+``; ``-2``, ``-3`` ... when taken."""
    mine = [labels[i] for i in members]
    prefixes = {label_prefix(m) for m in mine}
    others = [labels[i] for i in range(len(labels)) if i not in set(members)]
    name = ""
    if len(prefixes) == 1 and "" not in prefixes:
        p = prefixes.pop()
        if not any(label_prefix(o) == p for o in others):
            name = p
    if not name:
        start = _common_start(_bare(m) for m in mine)
        name = start if len(start) >= 2 else "+".join(_bare(m) for m in mine[:3]) + ("+…" if len(mine) > 3 else "")
    base, k = name, 2
    while name.lower() in taken:
        name, k = f"{base}-{k}", k + 1
    taken.add(name.lower())
    return name


def find_clusters(points: np.ndarray, labels, *, std_tol: float = CLUSTER_STD_TOL_M,
                  min_together: float = MIN_SEEN_TOGETHER) -> list[Cluster]:
    """Rigid clusters among markers ``points`` (F, n, 3) (metres, NaN rows lost).

    Two markers are a rigid pair when the robust standard deviation of their distance
    (:func:`pair_distance_std`) is at most ``std_tol`` over the frames where both are seen (at most
    :data:`MAX_FRAMES` frames, evenly spaced), and they are seen together in at least
    ``min_together`` of the frames. A cluster is a largest set of three or more markers every pair of
    which is rigid (a maximal clique of that graph), taken largest first and without sharing markers.
    Named by :func:`cluster_name`; sorted by size, then name.
    """
    labels = [str(x) for x in labels]
    step = max(1, len(points) // MAX_FRAMES)
    std, together = pair_distance_std(points[::step])
    rigid = (std <= std_tol) & (together >= min_together)
    np.fill_diagonal(rigid, False)
    adj = [set(np.flatnonzero(rigid[i]).tolist()) for i in range(len(labels))]
    cliques = _maximal_cliques(adj)
    if cliques is None:
        cliques = _greedy_cliques(adj)
    cliques = sorted((c for c in cliques if len(c) >= 3), key=lambda c: (-len(c), sorted(c)))
    used: set = set()
    taken: set = set()
    seen = np.all(np.isfinite(points), axis=-1)
    out = []
    for c in cliques:
        c = sorted(c - used)
        if len(c) < 3 or not all(rigid[i, j] for i in c for j in c if i != j):
            continue
        used |= set(c)
        sub = std[np.ix_(c, c)]
        out.append(Cluster(name=cluster_name(labels, c, taken), markers=tuple(c), labels=tuple(labels[i] for i in c),
                           max_std_m=float(np.nanmax(sub)), frames_all_seen=int(np.all(seen[:, c], axis=1).sum())))
    return sorted(out, key=lambda cl: (-len(cl.markers), cl.name))


def kabsch(ref: np.ndarray, obs: np.ndarray, weights: np.ndarray):
    """Least-squares rigid fits ``obs ≈ R ref + t`` for a batch of frames.

    Parameters
    ----------
    ref : array (n, 3)
        The shape in the body frame.
    obs : array (F, n, 3)
        The markers in the world frame per frame (values where ``weights`` is 0 are ignored; may be NaN).
    weights : array (F, n)
        1 for a seen marker, 0 for a lost one (any non-negative weights).

    Returns
    -------
    R : (F, 3, 3), t : (F, 3), rms : (F,)
        ``R_world_body``, ``t_world_body`` minimising ``Σ w_i |R ref_i + t - obs_i|²`` (Kabsch: the SVD
        of the weighted cross-covariance ``H = Σ w_i (ref_i - c_ref)(obs_i - c_obs)ᵀ = U S Vᵀ``,
        ``R = V diag(1, 1, det(V Uᵀ)) Uᵀ`` so that det R = +1, the reflection guard), and the weighted
        RMS distance of the fitted markers. Frames with no weight give NaN.
    """
    w = np.asarray(weights, float)
    obs = np.where(w[..., None] > 0, obs, 0.0)
    total = w.sum(axis=1)  # (F,)
    safe = np.where(total > 0, total, 1.0)
    c_ref = (w @ ref) / safe[:, None]  # (F, 3)
    c_obs = np.einsum("fn,fnk->fk", w, obs) / safe[:, None]
    a = ref[None] - c_ref[:, None]  # (F, n, 3)
    b = obs - c_obs[:, None]
    h = np.einsum("fn,fni,fnj->fij", w, a, b)  # (F, 3, 3)
    u, _, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(vt.transpose(0, 2, 1) @ u.transpose(0, 2, 1)))
    d = np.where(d == 0, 1.0, d)
    fix = np.tile(np.eye(3), (len(w), 1, 1))
    fix[:, 2, 2] = d
    rot = vt.transpose(0, 2, 1) @ fix @ u.transpose(0, 2, 1)
    t = c_obs - np.einsum("fij,fj->fi", rot, c_ref)
    fitted = np.einsum("fij,nj->fni", rot, ref) + t[:, None]
    err2 = np.where(w > 0, np.sum((fitted - obs) ** 2, axis=-1), 0.0)
    rms = np.sqrt((w * err2).sum(axis=1) / safe)
    bad = total <= 0
    rot[bad], t[bad], rms[bad] = np.nan, np.nan, np.nan
    return rot, t, rms


def reference_shape(points: np.ndarray, *, rms_tol: float = FIT_RMS_TOL_M) -> tuple[np.ndarray, int, int]:
    """A cluster's shape in its body frame from its markers ``points`` (F, n, 3) (NaN rows lost).

    Uses the frames where every marker is seen. It starts from the most typical of them (the frame
    whose pairwise distances are closest to their medians over those frames, so that a frame with a
    swapped marker is not the start), fits every complete frame onto the shape (:func:`kabsch`) and
    averages those that fit within ``rms_tol`` and within 3× the median fit (+ 0.1 mm), three times.
    The body frame: origin at the markers' centroid, axes those of the world in the first complete
    frame that fits (the pose there is the identity rotation at the centroid).

    Returns ``(shape (n, 3), that frame, number of frames averaged)``; the frame is -1 and the shape
    NaN when no frame sees every marker.
    """
    full = np.all(np.isfinite(points), axis=(1, 2))
    idx = np.flatnonzero(full)
    if len(idx) == 0:
        return np.full(points.shape[1:], np.nan), -1, 0
    cand = idx[:: max(1, len(idx) // 200)]
    dist = np.linalg.norm(points[cand][:, :, None] - points[cand][:, None, :], axis=-1)  # (k, n, n)
    start = cand[int(np.argmin(np.max(np.abs(dist - np.median(dist, axis=0)), axis=(1, 2))))]
    shape = points[start] - points[start].mean(axis=0)
    ones = np.ones((len(idx), len(shape)))
    keep = np.ones(len(idx), bool)
    for _ in range(3):
        rot, t, rms = kabsch(shape, points[idx], ones)
        keep = rms <= min(rms_tol, 3.0 * float(np.median(rms)) + 1e-4)
        if not keep.any():
            keep = rms <= np.min(rms)
        back = np.einsum("fji,fnj->fni", rot[keep], points[idx][keep] - t[keep, None])  # Rᵀ (obs - t)
        shape = back.mean(axis=0)
        shape = shape - shape.mean(axis=0)
    _, _, rms = kabsch(shape, points[idx], ones)
    ref = int(idx[np.argmax(rms <= rms_tol)]) if (rms <= rms_tol).any() else int(idx[np.argmin(rms)])
    r0, _, _ = kabsch(shape, points[ref][None], np.ones((1, len(shape))))
    return shape @ r0[0].T, ref, int(keep.sum())


def fit_poses(points: np.ndarray, shape: np.ndarray, *, rms_tol: float = FIT_RMS_TOL_M, min_markers: int = 3):
    """The pose of a rigid cluster in every frame.

    Parameters
    ----------
    points : array (F, n, 3)
        The cluster's markers in the world frame, metres, NaN rows for lost markers.
    shape : array (n, 3)
        Its reference shape in the body frame (:func:`reference_shape`).
    rms_tol : float
        Frames whose fit leaves a larger RMS distance (metres) are lost.
    min_markers : int
        Frames with fewer seen markers are lost (three are needed for a rotation; they must not lie on a
        line: frames whose seen markers span less than 1 mm across their second principal direction are
        lost too).

    Returns
    -------
    R : (F, 3, 3), t : (F, 3), rms : (F,), seen : (F,), lost : (F,) bool
        ``R_world_body``, ``t_world_body`` (NaN where lost), the fit's RMS residual (metres, NaN with too
        few markers), the number of markers seen per frame, and the lost frames.
    """
    seen_mask = np.all(np.isfinite(points), axis=-1)
    seen = seen_mask.sum(axis=1)
    rot, t, rms = kabsch(shape, points, seen_mask.astype(float))
    centre = (seen_mask.astype(float) @ shape) / np.maximum(seen, 1)[:, None]  # (F, 3): the seen markers' centroid
    centred = np.where(seen_mask[..., None], shape[None] - centre[:, None], 0.0)
    sv = np.linalg.svd(centred, compute_uv=False)  # (F, 3)
    flat = sv[:, 1] / np.sqrt(np.maximum(seen, 1)) < 1e-3
    few = (seen < min_markers) | flat
    rms = np.where(seen < min_markers, np.nan, rms)
    lost = few | ~(rms <= rms_tol)
    rot[lost] = np.nan
    t[lost] = np.nan
    return rot, t, rms, seen, lost
