"""Shared setup of the hostile-input suite: hypothesis profiles, the CLI runner, a tiny model.

Hypothesis profiles (applied per test with ``@fuzz_settings``, never globally, so the other test
folders keep their own settings):

* ``rbgp-ci`` (default): few examples, ``derandomize=True`` (the same inputs on every run, so CI is
  reproducible), no deadline, no example database;
* ``rbgp-fuzz``: a long campaign, chosen by setting ``RBGP_FUZZ_EXAMPLES`` (examples per test);
  random inputs, failures saved in ``.hypothesis/`` and replayed first. See docs/FUZZING.md.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest
from hypothesis import HealthCheck, settings
from typer.testing import CliRunner

from rbgp_cli.cli.app import app
from tests.hostile import builders as B

#: examples per fuzz test in CI (the whole tests/hostile run stays well under 90 s on 2 cores)
CI_EXAMPLES = 200

_HEALTH = [HealthCheck.too_slow, HealthCheck.data_too_large, HealthCheck.function_scoped_fixture,
           HealthCheck.filter_too_much]  # fmt: skip
settings.register_profile(
    "rbgp-ci", max_examples=CI_EXAMPLES, deadline=None, derandomize=True, database=None,
    suppress_health_check=_HEALTH, print_blob=True,
)  # fmt: skip
settings.register_profile(
    "rbgp-fuzz", max_examples=int(os.environ.get("RBGP_FUZZ_EXAMPLES") or 20000), deadline=None,
    derandomize=False, suppress_health_check=_HEALTH, print_blob=True,
)  # fmt: skip
PROFILE = "rbgp-fuzz" if os.environ.get("RBGP_FUZZ_EXAMPLES") else "rbgp-ci"
#: decorator for every fuzz test
fuzz_settings = settings(settings.get_profile(PROFILE))

_runner = CliRunner()


def run_cli(*args, input=None):
    """``rbgp -q ARGS`` in-process; returns click's Result (stdout and stderr kept apart)."""
    return _runner.invoke(app, ["-q", *(str(a) for a in args)], input=input, catch_exceptions=False)


@pytest.fixture(scope="session")
def tiny_model_path(tmp_path_factory) -> Path:
    """A small model trained through the CLI on :func:`builders.smooth_motion` (read-only: copy it)."""
    folder = tmp_path_factory.mktemp("tiny-model")
    demo = B.write_csv(folder / "demo.csv")
    path = folder / "tiny.rbgp"
    res = run_cli("train", demo, "-o", path, *B.FAST)
    assert res.exit_code == 0, res.stderr
    return path


@pytest.fixture
def tiny_model(tiny_model_path, tmp_path) -> Path:
    """A private copy of the tiny model in this test's folder."""
    dst = tmp_path / "tiny.rbgp"
    shutil.copyfile(tiny_model_path, dst)
    return dst
