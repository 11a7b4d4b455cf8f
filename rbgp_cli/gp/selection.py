"""Which GP to keep: the exact GP on a subset of the points or the sparse GP on all of them, measured on
demonstrations left out (issue 21: more data must never make a model worse).

Both posteriors use the same hyperparameters (the exact GP's fit on the subset, which chose them for the
sparse GP too: :func:`rbgp_cli.gp.sparse.fit_sparse_gp` with ``hyper="exact"``), so what is compared is
only what the extra points do to the predictions. Grouped K-fold over demonstrations: for each fold the
exact posterior on the subset's rows of the other demonstrations and the sparse posterior (the same
number of farthest-point inducing poses, chosen among the other demonstrations' poses) on all their
rows (at most ``max_rows``, a random subset otherwise) predict the left-out demonstrations' outputs;
the score is the squared error summed over outputs, each divided by its variance.
"""

from __future__ import annotations

import numpy as np

__all__ = ["held_out_comparison", "CHECK_FOLDS", "CHECK_MAX_ROWS", "CHECK_TEST_ROWS"]

#: Folds of the demonstrations for the comparison.
CHECK_FOLDS = 3
#: At most this many rows for each fold's sparse posterior (O(rows M²) each), and ...
CHECK_MAX_ROWS = 16000
#: ... at most this many left-out rows predicted per fold.
CHECK_TEST_ROWS = 2000


def held_out_comparison(sparse, groups: np.ndarray, *, folds: int = CHECK_FOLDS, seed: int = 0,
                        max_rows: int = CHECK_MAX_ROWS, test_rows: int = CHECK_TEST_ROWS) -> dict | None:
    """Held-out error of the sparse posterior on all rows against the exact posterior on the subset.

    ``sparse``: a fitted :class:`~rbgp_cli.gp.sparse.SparseGP` whose ``hyper_gp`` / ``hyper_rows`` are the
    exact GP that chose its hyperparameters and the rows it used; ``groups`` (n,): the demonstration of
    each training row. Returns ``{"exact", "sparse"}`` (relative squared errors: 1 = predicting zero),
    ``"folds"`` and ``"rows"`` (rows per fold's sparse posterior), or None when there are fewer than two
    demonstrations or no exact fit to compare with.
    """
    from rbgp_cli.compute import blas_threads
    from rbgp_cli.gp.exact import GaussianProcess
    from rbgp_cli.gp.sparse import SparseGP, select_inducing

    exact, rows = getattr(sparse, "hyper_gp", None), getattr(sparse, "hyper_rows", None)
    groups = np.asarray(groups)
    ids = np.unique(groups)
    if exact is None or len(ids) < 2:
        return None
    k = int(min(folds, len(ids)))
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 21]))
    fold = (rng.permutation(len(ids)) % k)[np.searchsorted(ids, groups)]  # a demonstration's rows share a fold
    X, Y = sparse.X, sparse.Y
    var = np.maximum(np.var(Y, axis=0), 1e-300)
    in_subset = np.zeros(len(X), dtype=bool)
    in_subset[np.asarray(rows)] = True
    err = {"exact": 0.0, "sparse": 0.0, "zero": 0.0}
    used = []
    with blas_threads(0):
        for f in range(k):
            test = np.flatnonzero(fold == f)
            train = np.flatnonzero(fold != f)
            ex_rows = train[in_subset[train]]
            if len(test) == 0 or len(ex_rows) < 2:
                continue
            if len(train) > max_rows:
                train = np.sort(rng.choice(train, max_rows, replace=False))
            if len(test) > test_rows:
                test = np.sort(rng.choice(test, test_rows, replace=False))
            Z = X[train[select_inducing(X[train], sparse.n_inducing, sparse.kernel, seed=seed, method="farthest")]]
            ex = GaussianProcess(exact.kernel, X[ex_rows], Y[ex_rows], exact.fits, shared=exact.shared, y_scale=exact.y_scale)
            sp = SparseGP(sparse.kernel, X[train], Y[train], Z, sparse.fits, shared=sparse.shared, y_scale=sparse.y_scale)
            Yt = Y[test]
            err["exact"] += float(np.sum((ex.predict(X[test]) - Yt) ** 2 / var))
            err["sparse"] += float(np.sum((sp.predict(X[test]) - Yt) ** 2 / var))
            err["zero"] += float(np.sum(Yt ** 2 / var))
            used.append(int(len(train)))
    if not used or err["zero"] <= 0:
        return None
    return {"exact": err["exact"] / err["zero"], "sparse": err["sparse"] / err["zero"], "folds": len(used),
            "rows": used}
