"""``rbgp evaluate --plot`` end to end: the figure of a large set, and the figure when no score is possible."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tests.cli.common import CSV_DIR, run

pytest.importorskip("matplotlib")


@pytest.fixture()
def one_demo(tmp_path):
    one = tmp_path / "one_demo"
    one.mkdir()
    (one / "shoe_01.csv").write_bytes((CSV_DIR / "shoe_01.csv").read_bytes())
    return one


def _png(path: Path) -> bool:
    return path.exists() and path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and path.stat().st_size > 10_000


@pytest.mark.slow
def test_one_demonstration_with_plot_writes_the_figure_and_exits_2_for_the_missing_score(tmp_path, one_demo):
    """One long take as the only demonstration: no score (exit 2, the same one error line as without
    --plot), but the figure the user asked for is written, without the score panels."""
    gen = sorted(CSV_DIR.glob("*.csv"))[1:]
    fig = tmp_path / "fig.png"
    res = run("evaluate", *gen, "--demos", one_demo, "--plot", fig, "--per-step", tmp_path / "per.csv")
    assert res.exit_code == 2, (res.stdout, res.stderr)
    assert res.stdout == ""  # no score on stdout
    errors = [line for line in res.stderr.splitlines() if line.startswith("rbgp: error:")]
    assert len(errors) == 1 and "cannot score against 1 demonstration" in errors[0], res.stderr
    assert "figure" in errors[0] and str(fig) in errors[0]  # says the figure was still written
    assert "Traceback" not in res.stderr
    assert _png(fig)
    assert not (tmp_path / "per.csv").exists()  # no per-step series without a score
    # without --plot: the refusal as before, nothing written
    res = run("evaluate", *gen, "--demos", one_demo, "--json")
    assert res.exit_code == 2 and res.stdout == ""
    assert "cannot score against 1 demonstration" in res.stderr and "figure" not in res.stderr


@pytest.mark.slow
def test_one_demonstration_with_plot_and_model_still_rolls_out(tmp_path, one_demo):
    model = tmp_path / "m.rbgp"
    assert run("train", CSV_DIR, "-o", model, "--max-points", "100", "--restarts", "1",
               "--share-hyperparameters", "-q").exit_code == 0
    fig = tmp_path / "fig.png"
    res = run("evaluate", "--model", model, "--count", 4, "--demos", one_demo, "--plot", fig)
    assert res.exit_code == 2 and "cannot score against 1 demonstration" in res.stderr
    assert _png(fig)
    res = run("evaluate", "--model", model, "--count", 4, "--demos", one_demo)  # unchanged: refused up front
    assert res.exit_code == 2 and res.stderr.count("rbgp:") == 1


def test_plot_help_says_what_happens_without_a_score():
    res = run("evaluate", "--help")
    text = " ".join(res.stdout.replace("│", " ").split())
    assert "without the score panels" in text and "exits 2" in text


@pytest.mark.slow
def test_a_scored_plot_still_exits_0(tmp_path):
    gen = sorted(CSV_DIR.glob("*.csv"))[:4]
    fig = tmp_path / "fig.png"
    res = run("evaluate", *gen, "--demos", CSV_DIR, "--plot", fig, "--json")
    assert res.exit_code == 0, res.stderr
    assert json.loads(res.stdout)["n_demos"] == 9 and _png(fig)


@pytest.mark.parametrize("name,magic", [("fig.pdf", b"%PDF"), ("fig.svg", b"<?xml")])
def test_the_figure_format_follows_the_suffix(tmp_path, name, magic):
    """--plot x.pdf writes a PDF (before: PNG data under a .pdf name), .svg an SVG."""
    gen = sorted(CSV_DIR.glob("*.csv"))[:4]
    res = run("evaluate", *gen, "--demos", CSV_DIR, "--plot", tmp_path / name)
    assert res.exit_code == 0, res.stderr
    assert (tmp_path / name).read_bytes()[: len(magic)] == magic


def test_a_figure_suffix_rbgp_cannot_write_is_refused_before_the_work(model, tmp_path):
    res = run("rollout", model, "--count", 1, "-o", tmp_path / "r.csv", "--plot", tmp_path / "fig.jpg")
    assert res.exit_code == 2
    msg = res.stderr.strip().splitlines()
    assert len(msg) == 1 and ".png, .pdf, .svg, not .jpg" in msg[0], msg
    assert not (tmp_path / "r.csv").exists() and not (tmp_path / "fig.jpg").exists()
