"""Shared fixtures: the real recordings in ../shared/realdata (never copied into the repository)."""

from __future__ import annotations

import os
import stat
from pathlib import Path

# Under pytest-xdist (``-n auto``: one worker per core) a worker's BLAS runs on one thread: two workers
# with a pool of two threads each would take four threads on two cores and spin-wait for each other.
# Set before numpy is first imported (the plugins pytest loads do not import it); tests that need more
# threads ask threadpoolctl for them. Subprocesses started by the tests inherit the setting.
if os.environ.get("PYTEST_XDIST_WORKER"):
    for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(_var, "1")

import pytest  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
REALDATA = Path(os.environ.get("RBGP_REALDATA", REPO.parent / "shared" / "realdata"))


@pytest.fixture(scope="session")
def realdata() -> Path:
    """Path of ../shared/realdata; the test is skipped when it is absent."""
    if not REALDATA.is_dir():
        pytest.skip(f"real recordings not found at {REALDATA}")
    return REALDATA


@pytest.fixture(scope="session", autouse=True)
def dev_null_is_still_a_device_after_the_suite():
    """Issue 40: ``-o /dev/null`` once renamed a file onto the device. The suite writes to /dev/null on
    purpose (tests/hostile/test_streams_and_devices.py); after the whole session it must still be one."""
    yield
    assert stat.S_ISCHR(os.stat("/dev/null").st_mode), "/dev/null is no longer a character device"
