"""The README's main command leaves a fresh clone clean: outputs of the main job are not in git.

The README's main command is ``python3 -m venv .venv && .venv/bin/pip install . && .venv/bin/rbgp
demo``. In a fresh clone of the committed HEAD one test makes the virtual environment folder and runs
the clone's own ``rbgp demo --quick`` from the clone's top folder (the README's command with the
quick switch, so it takes seconds, not minutes); another builds the package the way ``pip install .``
does (in the source tree, no dependencies installed). After each, ``git status --porcelain`` must be
empty, and ``rbgp-demo/`` must hold the demo's outputs (so the test really ran the job).
Uncommitted changes of the working tree are not part of the clone: commit first.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def _git(*args, cwd=REPO, check=True):
    return subprocess.run(["git", *args], cwd=cwd, capture_output=True, text=True, check=check)


@pytest.fixture(scope="module")
def clone(tmp_path_factory):
    if shutil.which("git") is None:
        pytest.skip("git is not installed")
    head = _git("rev-parse", "HEAD", check=False)
    if head.returncode != 0:
        pytest.skip("not a git checkout")
    target = tmp_path_factory.mktemp("clone") / "rbgp"
    _git("clone", "--quiet", "--no-checkout", str(REPO), str(target))
    _git("checkout", "--quiet", head.stdout.strip(), cwd=target)
    return target


def _status(clone) -> str:
    return _git("status", "--porcelain", "--untracked-files=all", cwd=clone).stdout


@pytest.mark.slow
def test_the_main_command_leaves_a_fresh_clone_clean(clone):
    assert _status(clone) == ""
    # python3 -m venv .venv (without pip: the folder is what matters to git)
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", ".venv"], cwd=clone, check=True)
    # .venv/bin/rbgp demo, quick: the clone's own code, from the clone's top folder
    env = dict(os.environ, PYTHONPATH=str(clone))
    res = subprocess.run([sys.executable, "-m", "rbgp_cli", "demo", "--quick", "--count", "20"], cwd=clone, env=env,
                         capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr[-3000:]
    assert "axis-angle" in res.stdout
    outputs = sorted(p.name for p in (clone / "rbgp-demo").iterdir())
    assert "axis-angle.rbgp" in outputs and "euler_rollouts.csv" in outputs and "quaternion_per_step.csv" in outputs
    status = _status(clone)
    assert status == "", f"the main command left the checkout dirty:\n{status}"


@pytest.mark.slow
def test_installing_from_a_fresh_clone_leaves_it_clean(clone):
    """``pip install .`` builds in the source tree (``build/``, ``*.egg-info``): build the same way
    (no dependencies installed); skipped where pip cannot get the build backend."""
    build = subprocess.run([sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps",
                            "--wheel-dir", str(clone.parent / "wheels"), "."], cwd=clone, capture_output=True,
                           text=True, timeout=600)
    if build.returncode != 0:
        pytest.skip(f"pip could not build the package here: {build.stderr.strip()[-300:]}")
    assert list((clone.parent / "wheels").glob("rbgp_cli-*.whl"))
    status = _status(clone)
    assert status == "", f"building the package left the checkout dirty:\n{status}"


def test_no_outputs_of_the_main_job_are_tracked():
    listed = _git("ls-files", "rbgp-demo", check=False)
    if listed.returncode != 0:
        pytest.skip("not a git checkout")
    assert listed.stdout == ""
    ignored = _git("check-ignore", "-q", "rbgp-demo/axis-angle.rbgp", check=False)
    assert ignored.returncode == 0, "rbgp-demo/ is not git-ignored"
