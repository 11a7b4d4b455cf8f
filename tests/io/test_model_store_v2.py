"""Model files, format version 2: velocity options, time input and prior mean survive a round trip, and
version-1 files (written before them) still load as zero-mean models without a time input."""

from __future__ import annotations

import json

import numpy as np
import pytest

from rbgp_cli.dynamics.model import train_model
from rbgp_cli.dynamics.rollout import rollout
from rbgp_cli.dynamics.velocities import VelocityOptions
from rbgp_cli.errors import InputError
from rbgp_cli.io.model_store import FORMAT_VERSION, header_sha256, load_model, save_model
from tests.evaluation.test_crossval import reaching_demos

SMALL = {"subsample": 1.0, "max_points": 80, "restarts": 1, "shared": True, "kernel": "se-chordal"}


@pytest.mark.parametrize("options", [
    {"time_input": "phase", "prior": "path", "prior_gain": 7.0, "velocity": VelocityOptions(rate=8.0)},
    {"time_input": "seconds", "prior": "goal", "prior_gain": 2.0, "velocity": VelocityOptions(rate=10.0, window=0.3)},
    {"time_input": None, "prior": None, "velocity": VelocityOptions()},
])
def test_round_trip_keeps_what_prediction_needs(tmp_path, options):
    demos = reaching_demos(5)
    model = train_model(demos, **SMALL, **options)
    path = tmp_path / "m.rbgp"
    header = save_model(model, path)
    assert header["version"] == FORMAT_VERSION == 8  # version 8: the path distribution
    loaded, h = load_model(path)
    assert loaded.time_input == model.time_input and loaded.velocity == model.velocity
    assert (loaded.mean is None) == (model.mean is None)
    if model.mean:
        assert loaded.mean["kind"] == model.mean["kind"] and loaded.mean["gain"] == model.mean["gain"]
        assert loaded.mean.get("feedforward") == model.mean.get("feedforward")
        assert (model.mean.get("feedforward") == "secant") == (options["prior"] == "path")  # forward differences
    q0, p0 = np.array([d.quat[0] for d in demos[:3]]), np.array([d.position[0] for d in demos[:3]])
    a = rollout(model, q0, p0, 12, with_std=True, durations=[1.2, 1.0, 0.8])
    b = rollout(loaded, q0, p0, 12, with_std=True, durations=[1.2, 1.0, 0.8])
    np.testing.assert_allclose(b.position, a.position, atol=1e-9)
    np.testing.assert_allclose(b.std, a.std, atol=1e-9)
    # the path distribution (version 8) comes back whole: the same goal-conditioned mean
    assert loaded.paths is not None and loaded.paths.header() == model.paths.header()
    A, y, r2 = model.paths.observe([0.0, 1.0], [d.quat[0] for d in demos[:2]], [d.position[-1] for d in demos[:2]], exact=True)
    np.testing.assert_allclose(loaded.paths.condition(A, y, r2).mean, model.paths.condition(A, y, r2).mean, atol=1e-12)


def _rewrite(path, out, change_header=None, drop=()):
    """Copy a model file, editing its header (and re-checksumming nothing: arrays are kept as they are)."""
    with np.load(path, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files if k not in drop}
    header = json.loads(arrays.pop("header").tobytes().decode())
    if change_header:
        change_header(header)
        if "header" in header["checksums"]:  # as a writer would: the edit is what the test checks, not the checksum
            header["checksums"]["header"] = header_sha256(header)
    raw = json.dumps(header).encode()
    with open(out, "wb") as fh:  # a file object: savez would append .npz to the name
        np.savez_compressed(fh, header=np.frombuffer(raw, dtype=np.uint8), **arrays)


def test_version_1_files_still_load(tmp_path):
    demos = reaching_demos(5)
    model = train_model(demos, **SMALL, time_input=None, prior=None, velocity=VelocityOptions())
    save_model(model, tmp_path / "v2.rbgp")

    def as_v1(h):  # what rbgp wrote as version 1: no velocity, time input, prior, gp entry or header checksum
        h["version"] = 1
        for key in ("velocity", "time_input", "prior", "gp"):
            h.pop(key)
        h["checksums"].pop("header")

    _rewrite(tmp_path / "v2.rbgp", tmp_path / "v1.rbgp", as_v1)
    old, header = load_model(tmp_path / "v1.rbgp")
    assert header["version"] == 1 and old.time_input is None and old.mean is None
    assert old.velocity == VelocityOptions()
    X = model.gp.X[:7]
    np.testing.assert_allclose(old.predict_output(X), model.predict_output(X), atol=1e-12)


def test_damaged_prior_is_refused(tmp_path):
    demos = reaching_demos(5)
    model = train_model(demos, **SMALL, time_input="phase", prior="path", velocity=VelocityOptions(rate=8.0))
    save_model(model, tmp_path / "m.rbgp")
    _rewrite(tmp_path / "m.rbgp", tmp_path / "nogain.rbgp", lambda h: h["prior"].update(gain=float("nan")))
    with pytest.raises(InputError, match=r"prior\.gain = nan"):
        load_model(tmp_path / "nogain.rbgp")
    _rewrite(tmp_path / "m.rbgp", tmp_path / "noarr.rbgp", drop=("prior_s",))
    with pytest.raises(InputError, match="prior_s"):
        load_model(tmp_path / "noarr.rbgp")
    _rewrite(tmp_path / "m.rbgp", tmp_path / "time.rbgp", lambda h: h.update(time_input=None))
    with pytest.raises(InputError, match="inconsistent"):
        load_model(tmp_path / "time.rbgp")
    # a prior array changed after writing: its checksum no longer matches
    with np.load(tmp_path / "m.rbgp", allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    arrays["prior_position"] = arrays["prior_position"] + 1e-3
    with open(tmp_path / "bent.rbgp", "wb") as fh:
        np.savez_compressed(fh, **arrays)
    with pytest.raises(InputError, match="checksum mismatch in array 'prior_position'"):
        load_model(tmp_path / "bent.rbgp")
