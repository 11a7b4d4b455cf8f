"""`rbgp bench paper`: the eq. 30 dynamics, the conversions its errors rest on, the theorem's Gram
matrices against hand-built ones, the paper's starts, and the command's quick run end to end."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation
from typer.testing import CliRunner

from rbgp_cli.bench import paper as P
from rbgp_cli.cli.app import app
from rbgp_cli.dynamics.model import make_kernel
from rbgp_cli.dynamics.representations import make_representation
from rbgp_cli.geometry.so3 import random_quat, rotvec_from_quat
from rbgp_cli.gp.exact import fit_gp

runner = CliRunner()


# ------------------------------------------------------------------------------------------ eq. 30
def test_component_is_g_of_the_whole_expression():
    """f_i = g(d/c ⊙ d̃ ⋆ c̃), by hand at one point, for every operator combination."""
    r = np.array([0.3, -0.2, 0.7])
    cases = [
        (P._Component("sin", 0, 1.5, False, 2, False, -1 / 3), math.sin(0.3 / 1.5 - 0.7 / (-1 / 3))),
        (P._Component("cos", 1, -1.0, True, 0, True, 1.5), math.cos(-0.2 / -1.0 + 0.3 * 1.5)),
        (P._Component("atan", 2, 1 / 3, True, 2, False, 1.0), math.atan(0.7 * 3 + 0.7)),
        (P._Component("acot", 0, 1.0, False, 0, True, 1.0), math.pi / 2),  # argument exactly 0: MATLAB's π/2
        (P._Component("acot", 1, 1.0, True, 0, True, 1.0), math.atan(1.0 / (-0.2 + 0.3))),
    ]
    for comp, expected in cases:
        assert comp(r) == pytest.approx(expected, abs=1e-14), comp.text()


def test_acot_is_matlabs():
    x = np.array([-2.0, -1e-9, 0.5, 3.0])
    assert np.allclose(P.acot_matlab(x), np.arctan(1 / x))
    assert P.acot_matlab(0.0) == pytest.approx(math.pi / 2)
    assert P.acot_matlab(-0.0) == pytest.approx(-math.pi / 2)
    pos = x[x > 0]
    assert np.allclose(P.acot_matlab(pos), math.pi / 2 - np.arctan(pos))  # the usual acot for x > 0


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_random_dynamics_are_canonical_rotation_vectors(seed):
    """Every component lies in [−π/2, π/2], so ‖f‖ ≤ √3·π/2 < π: f is its own canonical rotation vector."""
    rng = np.random.default_rng(seed)
    dyn = P.RandomDynamics.draw(rng)
    r = rotvec_from_quat(random_quat(rng, 500))
    f = dyn(r)
    assert f.shape == (500, 3) and np.all(np.isfinite(f))
    assert np.all(np.abs(f) <= math.pi / 2 + 1e-15)
    assert np.allclose(rotvec_from_quat(Rotation.from_rotvec(f).as_quat()), f, atol=1e-12)


def test_draws_cover_every_function_constant_and_operator():
    rng = np.random.default_rng(1)
    comps = [c for _ in range(200) for c in P.RandomDynamics.draw(rng).components]
    assert {c.g for c in comps} == {"sin", "cos", "atan", "acot"}
    assert {c.c for c in comps} == {c.c2 for c in comps} == set(P._CONSTANTS)
    assert {c.plus for c in comps} == {c.times for c in comps} == {True, False}
    assert {c.d for c in comps} == {c.d2 for c in comps} == {0, 1, 2}


# ------------------------------------------------------------------------------------------ errors
@pytest.mark.parametrize("name", ["axis-angle", "quaternion", "euler"])
def test_a_perfect_prediction_has_zero_error_in_every_representation(name):
    """Truth → a representation's coordinates → back gives f again, so the RMSE measures only the GP."""
    rng = np.random.default_rng(5)
    f = P.RandomDynamics.draw(rng)(rotvec_from_quat(random_quat(rng, 300)))
    rep = make_representation(name)
    Y = P.rotation_outputs(rep, f)
    assert Y.shape == (300, 4 if name == "quaternion" else 3)
    r_hat, q_hat = P.predicted_rotation(rep, Y)
    assert np.allclose(r_hat, f, atol=1e-12)
    ref = Rotation.from_rotvec(f).as_quat()
    assert np.allclose(np.abs(np.sum(q_hat * ref, axis=1)), 1.0, atol=1e-12)


def test_euler_outputs_are_scipys_extrinsic_xyz_angles():
    rng = np.random.default_rng(2)
    f = P.RandomDynamics.draw(rng)(rotvec_from_quat(random_quat(rng, 50)))
    ref = Rotation.from_rotvec(f).as_euler("xyz")
    assert np.allclose(P.rotation_outputs(make_representation("euler"), f), ref, atol=1e-12)


def test_a_zero_quaternion_prediction_counts_as_the_identity():
    r_hat, q_hat = P.predicted_rotation(make_representation("quaternion"), np.zeros((2, 4)))
    assert np.all(r_hat == 0) and np.allclose(q_hat, [0, 0, 0, 1])


# ------------------------------------------------------------------------------------------ theorem
def _wrapped(a):
    d = np.abs(a[:, None] - a[None, :]) % (2 * math.pi)
    return np.minimum(d, 2 * math.pi - d)


@pytest.mark.parametrize("lam", [0.5, 1.0, 2.0])
def test_rotation_gram_is_the_gaussian_of_the_rotation_distance(lam):
    """About one axis d_arc is the wrapped angle difference and d_ch = 2 sin(d_arc/2) (hand-built oracle)."""
    a = np.arange(8) * math.pi / 4
    r = P.counterexample_rotations()
    assert np.allclose(Rotation.from_rotvec(r).as_rotvec(), r)  # canonical and about z
    d = _wrapped(a)
    assert np.allclose(P.rotation_gram("arc", r, lam), np.exp(-d**2 / (2 * lam**2)), atol=1e-12)
    assert np.allclose(P.rotation_gram("chordal", r, lam), np.exp(-(2 * np.sin(d / 2)) ** 2 / (2 * lam**2)), atol=1e-12)


def test_theorem_part_finds_the_counterexample_and_a_psd_chordal_kernel():
    th = P.run_theorem(2, seed=0, quick=True)
    by_lam = {c["lambda"]: c for c in th["counterexample"]}
    assert by_lam[2.0]["geodesic"] == pytest.approx(-0.18, abs=0.005)  # docs/method.md §6
    assert by_lam[0.5]["geodesic"] == pytest.approx(0.43, abs=0.005)
    assert th["geodesic_min_eigenvalue"] <= by_lam[2.0]["geodesic"] < 0
    assert th["chordal_min_eigenvalue"] > -1e-9
    assert all(r["chordal_negative_sets"] == 0 for r in th["search"])
    assert len(th["search"]) == len(P.THEOREM_SIZES_QUICK) * len(P.THEOREM_LAMBDAS)


# ------------------------------------------------------------------------------------------ starts
@pytest.mark.slow
def test_paper_start_is_uniform_0_3_and_independent_of_the_output_order():
    rng = np.random.default_rng(3)
    f = P.RandomDynamics.draw(rng)(rotvec_from_quat(random_quat(rng, 60)))
    rep = make_representation("axis-angle")
    X = rep.state_from_pose(Rotation.from_rotvec(f).as_quat(), np.zeros((60, 3)))
    base = make_kernel(rep, "se", rho_rot=0.5)
    kern = P.PaperStartKernel(base, start_seed=11)

    def starts(Y):
        gp = fit_gp(X, Y, kern, noise=1.0, restarts=1, seed=0, explore_size=0)
        assert all(len(fit.starts) >= 1 for fit in gp.fits)
        return [fit.starts[0]["start"] for fit in gp.fits]

    s = starts(f)
    for st_ in s:
        assert 0 < st_["signal_std"] < 3
        # λ is passed as λ·√ρ1; an infeasible start may only have been moved to shorter λ
        assert 0 < st_["length_scale"] / math.sqrt(0.5) < 3
    assert len({round(x["signal_std"], 12) for x in s}) == 3  # a different draw per output
    assert starts(f[:, ::-1]) == s[::-1]


# ------------------------------------------------------------------------------------------ statistics
@pytest.mark.slow
def test_paired_ratio_counts_and_tests():
    b = np.linspace(1.0, 2.0, 12)
    a = 0.5 * b
    c = P._paired(a, b)
    assert c["median_ratio"] == pytest.approx(0.5) and c["ratio_of_means"] == pytest.approx(0.5)
    assert c["a_better"] == 12 and c["pairs"] == 12
    assert c["wilcoxon_p"] < 0.01 and c["welch"]["t"] < 0
    # failed fits (NaN) drop out of the pairs
    c2 = P._paired(np.r_[a, np.nan], np.r_[b, 1.0])
    assert c2["pairs"] == 12


# ------------------------------------------------------------------------------------------ command
def _table_rows(md: str, header_start: str) -> list[list[str]]:
    lines = md.splitlines()
    i = next(k for k, line in enumerate(lines) if line.startswith(header_start))
    rows = []
    for line in lines[i + 2:]:
        if not line.startswith("|"):
            break
        rows.append([c.strip() for c in line.strip("|").split("|")])
    return rows


@pytest.mark.slow
def test_quick_run_json_and_markdown(tmp_path):
    md_path = tmp_path / "paper.md"
    res = runner.invoke(app, ["bench", "paper", "--quick", "--json", "--markdown", str(md_path)], catch_exceptions=False)
    assert res.exit_code == 0, res.stderr
    d = json.loads(res.stdout)
    assert {"theorem", "runtime", "accuracy"} <= set(d)
    assert d["theorem"]["geodesic_min_eigenvalue"] < -0.1 and d["theorem"]["chordal_min_eigenvalue"] > -1e-9
    rt = d["runtime"]
    assert rt["training_points"] == 80 and rt["prediction_poses"] == 10001 and rt["blas_threads"] == 1
    assert [r["key"] for r in rt["rows"]] == [f"{a}/{b}" for a, b in P.RUNTIME_MODELS]
    assert all(r[k]["median"] > 0 for r in rt["rows"] for k in ("mean_only", "mean_std"))
    assert all(len(rt["times"][k]["mean_std"]) == 2 for k in rt["times"])
    ac = d["accuracy"]
    assert ac["settings"]["training_points"] == 100 and ac["settings"]["test_points"] == 1000
    assert len(ac["rows"]) == len(P.SETTINGS) * len(P.ACCURACY_MODELS)
    assert all(r["rmse"]["median"] > 0 and r["geodesic_rmse"]["median"] > 0 for r in ac["rows"])
    assert len(ac["comparisons"]) == len(P.SETTINGS) * len(P.ACCURACY_COMPARISONS) * 2
    assert len(ac["dynamics"]) == 2

    md = md_path.read_text()
    claims = _table_rows(md, "| claim |")
    assert len(claims) == 3 and all(len(r) == 3 for r in claims)
    acc = _table_rows(md, "| setting | model |")
    assert len(acc) == len(P.SETTINGS) * len(P.ACCURACY_MODELS) and all(len(r) == 12 for r in acc)
    times = _table_rows(md, "| model | mean (ms) |")
    assert len(times) == len(P.RUNTIME_MODELS) and all(len(r) == 5 for r in times)
    assert "BLAS single-threaded" in md and d["settings"]["command"] in md


@pytest.mark.slow
def test_a_part_alone_gives_the_numbers_of_the_full_run():
    full = P.run_paper_bench(("theorem", "accuracy"), repeats=1, seed=4, quick=True)
    res = runner.invoke(app, ["bench", "paper", "accuracy", "--repeats", "1", "--seed", "4", "--json"], catch_exceptions=False)
    assert res.exit_code == 0, res.stderr
    alone = json.loads(res.stdout)
    assert set(alone) >= {"accuracy"} and "theorem" not in alone and "runtime" not in alone
    assert alone["accuracy"]["per_dynamics"] == full["accuracy"]["per_dynamics"]
    assert alone["accuracy"]["dynamics"] == full["accuracy"]["dynamics"]
    assert P.run_theorem(1, seed=4, quick=True)["search"] == full["theorem"]["search"]


def test_text_output_and_bad_part():
    res = runner.invoke(app, ["bench", "paper", "theorem", "--quick"], catch_exceptions=False)
    assert res.exit_code == 0 and "| λ | geodesic | chordal |" in res.stdout and "Sec. 4.2" not in res.stdout
    bad = runner.invoke(app, ["bench", "paper", "everything"])
    assert bad.exit_code == 2 and bad.stdout == ""
    assert bad.stderr.strip().startswith("rbgp: error: unknown part 'everything'")


@pytest.mark.slow
def test_bench_help_imports_nothing_heavy():
    from tests.cli.common import assert_help_imports_none_of

    assert_help_imports_none_of((["bench", "--help"], ["bench", "paper", "--help"]),
                                ("rbgp_cli.bench.paper", "scipy.optimize", "scipy.stats", "pandas", "rerun"))
