"""Fixtures shared by the CLI tests."""

from __future__ import annotations

import pytest

from tests.cli.common import CSV_DIR, run
from tests.cli.test_cli import FAST


@pytest.fixture(scope="session")
def model(tmp_path_factory):
    """A model trained on the bundled CSV sample data (recorded at ~179 Hz) with the fast options, on
    the default 10 Hz grid. Read-only: a test that changes a model writes its own copy. Test modules
    that need a model trained differently define their own ``model`` fixture."""
    path = tmp_path_factory.mktemp("model") / "shoe.rbgp"
    res = run("train", CSV_DIR, "-o", path, *FAST)
    assert res.exit_code == 0, res.stderr
    return path
