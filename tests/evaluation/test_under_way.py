"""crossval --given's pieces: the split, the scores, the peers (issue 37)."""

from __future__ import annotations

import numpy as np
import pytest

from rbgp_cli.evaluation.under_way import nearest_continuation, score, split_seen
from tests.dynamics.test_anticipation import family


def test_split_seen_shares_the_last_seen_sample():
    tr = family(1, 0)[0][0]
    seen, rest = split_seen(tr, 0.4)
    assert seen.t[-1] == rest.t[0] and rest.t[-1] == tr.t[-1]
    assert abs((seen.t[-1] - tr.t[0]) / tr.duration - 0.4) < 0.02


def test_a_perfect_prediction_scores_zero():
    tr = family(1, 0)[0][0]
    _, rest = split_seen(tr, 0.5)
    sc = score(rest, [], rest).to_dict()
    assert sc["end_pos"] == 0 and sc["end_time"] == 0 and sc["rest_pos"] < 1e-12 and np.isnan(sc["cov_pos"])


def test_nearest_finds_a_training_demonstration_and_its_duration():
    demos, durs = family(6, 2)
    seen, rest = split_seen(demos[3], 0.5)
    c = nearest_continuation(demos, seen)
    assert abs(c.t[-1] - rest.t[-1]) < 0.05 * durs[3]  # itself, at (about) its own duration
    assert np.linalg.norm(c.position[-1] - rest.position[-1]) < 0.01


@pytest.mark.slow
def test_the_promp_peer_estimates_the_duration():
    pytest.importorskip("movement_primitives")
    from rbgp_cli.evaluation.under_way import PhaseProMP

    demos, _ = family(20, 4)
    new, durs = family(4, 9)
    pm = PhaseProMP(demos)
    for tr, D in zip(new, durs):
        seen, rest = split_seen(tr, 0.5)
        tau, Y = pm._seen(seen)
        assert abs(pm.duration(tau, Y) - D) < 0.1 * D
        mean, samples = pm.predict(seen, samples=3)
        assert mean.t[0] == pytest.approx(seen.t[-1]) and len(samples) == 3
