"""The automatic choice between the exact GP on a subset and the sparse GP on all points (issue 21):
measured on demonstrations left out, at the hyperparameters the exact GP chose."""

from __future__ import annotations

import numpy as np
import pytest

from rbgp_cli.gp.selection import held_out_comparison
from rbgp_cli.gp.sparse import fit_sparse_gp
from rbgp_cli.kernels import SquaredExponential

from tests.gp.test_sparse import field, poses


def _demos(n_demos, per, seed, offset=0.0):
    """Rows grouped in 'demonstrations'; ``offset``: each demonstration's own constant deviation."""
    X = poses(n_demos * per, seed)
    X[:, :3] *= 0.3
    rng = np.random.default_rng(seed + 1)
    groups = np.repeat(np.arange(n_demos), per)
    dev = offset * rng.normal(size=(n_demos, 3))[groups]
    return X, field(X, rng) + dev, groups


def test_where_the_points_are_independent_samples_more_of_them_predict_better_and_the_sparse_gp_is_kept():
    k = SquaredExponential("chordal", 3, 0.7)
    X, Y, groups = _demos(30, 60, 3)
    gp = fit_sparse_gp(X, Y, k, inducing=150, restarts=1, seed=0, explore_size=200, hyper_points=300)
    assert gp.hyper_gp is not None and len(gp.hyper_rows) == 300
    check = held_out_comparison(gp, groups, seed=0)
    assert check["folds"] == 3 and check["sparse"] < check["exact"] < 1.0, check


def test_the_comparison_uses_only_other_demonstrations_and_is_seeded():
    k = SquaredExponential("chordal", 3, 0.7)
    X, Y, groups = _demos(12, 40, 5, offset=0.3)
    gp = fit_sparse_gp(X, Y, k, inducing=60, restarts=1, seed=0, explore_size=200, hyper_points=200)
    a = held_out_comparison(gp, groups, seed=1)
    assert a == held_out_comparison(gp, groups, seed=1)
    assert all(r < len(X) for r in a["rows"]) and sum(a["rows"]) == 2 * len(X)  # each row trains in k − 1 = 2 folds
    assert held_out_comparison(gp, np.zeros(len(X), dtype=int)) is None  # one demonstration: nothing to hold out


@pytest.mark.parametrize("keeps", [True, False])
def test_train_model_keeps_the_sparse_gp_only_where_it_measures_no_worse(monkeypatch, keeps):
    """The automatic choice (points above SPARSE_ABOVE and --max-points) fits the sparse GP, then keeps it
    only when the held-out check says it is no worse; else the model is the exact GP on the subset that
    chose the hyperparameters, and the summary says why."""
    import rbgp_cli.dynamics.model as model_mod
    import rbgp_cli.gp.selection as sel
    from rbgp_cli.workflows import load_demonstrations

    demos, _, _ = load_demonstrations(["sample_data/csv"])
    monkeypatch.setattr(model_mod, "SPARSE_ABOVE", 100)
    real = sel.held_out_comparison

    def rigged(gp, groups, **kw):
        out = real(gp, groups, **kw)
        return dict(out, sparse=out["exact"] * (0.5 if keeps else 2.0))

    monkeypatch.setattr(sel, "held_out_comparison", rigged)
    m = model_mod.train_model(demos, max_points=150, hyper_points=150, restarts=1, shared=True, explore_size=100, jobs=1)
    gp = m.summary["gp"]
    assert "check" in gp and gp["forced"] is False
    if keeps:
        assert gp["type"] == "sparse" and "kept" in gp["reason"] and getattr(m.gp, "sparse", False)
        assert m.summary["points"] > 150
    else:
        assert gp["type"] == "exact" and "instead" in gp["reason"] and not getattr(m.gp, "sparse", False)
        assert m.summary["points"] == 150 and len(m.gp.X) == 150
    q, p = m.starts[:2, :4], m.starts[:2, 4:]
    from rbgp_cli.dynamics.rollout import rollout

    res = rollout(m, q, p, 5, with_std=True)
    assert np.all(np.isfinite(res.position)) and np.all(np.isfinite(res.std))


def test_the_fallback_exact_gp_has_max_points_rows_at_the_sparse_fits_hyperparameters(monkeypatch):
    """With fewer hyperparameter points than --max-points (the default: 1000 against 2000), the exact GP
    the automatic choice compares with and falls back on is widened to --max-points rows (the
    hyperparameter subset among them) at the same hyperparameters: as strong as --inducing 0's."""
    import rbgp_cli.dynamics.model as model_mod
    import rbgp_cli.gp.selection as sel
    from rbgp_cli.workflows import load_demonstrations

    demos, _, _ = load_demonstrations(["sample_data/csv"])
    monkeypatch.setattr(model_mod, "SPARSE_ABOVE", 100)
    real = sel.held_out_comparison
    seen = {}

    def rigged(gp, groups, **kw):
        seen["rows"] = np.asarray(gp.hyper_rows)
        out = real(gp, groups, **kw)
        return dict(out, sparse=out["exact"] * 2.0)  # the exact GP wins

    monkeypatch.setattr(sel, "held_out_comparison", rigged)
    m = model_mod.train_model(demos, max_points=150, hyper_points=90, restarts=1, shared=True, explore_size=60, jobs=1)
    gp = m.summary["gp"]
    assert gp["type"] == "exact" and gp["hyper_points"] == 90 and "random 150 of them" in gp["reason"]
    assert len(seen["rows"]) == 150 and len(np.unique(seen["rows"])) == 150
    assert m.summary["points"] == 150 and len(m.gp.X) == 150
    fitted = [f.values for f in m.gp.fits]
    forced = model_mod.train_model(demos, inducing=40, hyper_points=90, restarts=1, shared=True, explore_size=60, jobs=1,
                                   calibrate=False, noise_scale=1.0)
    noise = "noise_std"
    assert [{k: v for k, v in f.items() if k != noise} for f in fitted] == \
        [{k: v for k, v in f.values.items() if k != noise} for f in forced.gp.fits]
