"""The parts of a trained model that need no GP (``_WithoutGP`` in dynamics/model.py, issue 35): computed
on a thread of their own beside the fit and the calibration, they are the same numbers as computed in
line, and an error on the thread reaches the caller that waits for it."""

from __future__ import annotations

import numpy as np
import pytest

from rbgp_cli.dynamics.model import _WithoutGP, mean_path
from rbgp_cli.geometry.so3 import exp_quat
from tests.dynamics.synthetic import timed_demos


def _demos():
    def pose(rng, s):
        w = rng.normal(0.0, 0.05, 3)
        q = exp_quat(np.outer(s, [0.0, 0.0, 1.2]) + w)
        p = np.outer(s, [0.4, 0.1, 0.0]) + rng.normal(0.0, 0.01, 3) + np.outer(np.sin(np.pi * s), w)
        return q, p

    return timed_demos(8, 5, 40, pose)


def _arrays(side):
    out = [np.asarray(side.variation.band_scale)]
    out += [np.asarray(v) for v in side.paths.to_arrays().values()]
    out.append(np.asarray([side.paths.smooth, side.paths.length, *side.paths.band_scale]))
    return out


@pytest.mark.slow
def test_on_a_thread_the_same_numbers_as_in_line():
    demos = _demos()
    mean = {"kind": "path", "gain": 1.0, **mean_path(demos)}
    inline = _WithoutGP(demos, mean)
    inline()
    threaded = _WithoutGP(demos, mean)
    threaded.start()
    threaded()  # waits
    assert threaded.done and inline.done
    for a, b in zip(_arrays(inline), _arrays(threaded)):
        np.testing.assert_array_equal(a, b)
    assert threaded.envelope is not None or inline.envelope is None
    threaded()  # a second call computes nothing again
    assert threaded.done


def test_an_error_on_the_thread_reaches_the_caller(monkeypatch):
    import rbgp_cli.dynamics.paths as paths

    def broken(*args, **kwargs):
        raise ValueError("paths failed")

    monkeypatch.setattr(paths, "fit_paths", broken)
    side = _WithoutGP(_demos(), None)
    side.start()
    with pytest.raises(ValueError, match="paths failed"):
        side()
    assert not side.done
