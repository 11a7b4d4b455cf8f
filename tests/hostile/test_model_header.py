"""The model file's header (issue 24, points 5 and 6).

* The header is covered by a checksum (``checksums.header``: SHA-256 of the header's canonical JSON
  without that entry): an edit by hand is refused, by ``rbgp info`` as by every loading command.
* Every field is validated on load, for old files (versions 1–3, no header checksum) as for new
  ones: types, ranges, required and unknown keys, and every array's shape, dtype and finiteness
  against the header. ``rbgp info`` runs the same validation as a load.
* Hostile files are refused quickly, before anything large is read: zip bombs (a compression-ratio
  limit), declared shapes larger than the member, a deeply nested or oversized header, numbers
  with thousands of digits. Each refusal is exit 2 and one line naming the file.
"""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from rbgp_cli.errors import InputError
from rbgp_cli.io.model_store import FORMAT_VERSION, header_sha256, load_model, read_header
from tests.hostile import builders as B
from tests.hostile.conftest import run_cli

ROOT = Path(__file__).resolve().parents[2]
#: a model with a time input and a mean-path prior (what `rbgp train` makes by default)
PATH_PRIOR = (*B.FAST[:-4], "--time-input", "phase", "--prior", "path")


@pytest.fixture(scope="session")
def prior_model_path(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("prior-model")
    for k in range(2):
        B.write_csv(folder / f"demo_{k}.csv", B.smooth_motion(seed=k, name=f"demo_{k}"))
    path = folder / "prior.rbgp"
    res = run_cli("train", folder, "-o", path, *PATH_PRIOR)
    assert res.exit_code == 0, res.stderr
    return path


def refused(path, fragment: str = "", *commands):
    """Every command refuses ``path`` with exit 2 and one line ``rbgp: error: PATH: ...``."""
    for args in commands or (("info", path), ("rollout", path, "--steps", "3", "--count", "1")):
        res = run_cli(*args)
        lines = res.stderr.strip().splitlines()
        assert res.exit_code == 2, (args, res.stderr)
        assert res.stdout == "" and "internal error" not in res.stderr and "Traceback" not in res.stderr
        assert lines and lines[0].startswith(f"rbgp: error: {path}: "), res.stderr
        assert fragment in lines[0], (fragment, res.stderr)
        assert len([ln for ln in lines if not ln.startswith("  ")]) == 1, res.stderr  # one line (and its hint)


def rollout_csv(path) -> str:
    res = run_cli("rollout", path, "--steps", "6", "--count", "2")
    assert res.exit_code == 0, res.stderr
    return res.stdout


# ---------------------------------------------------------------------------------------------- header checksum

#: the edits of the fault run, and a few like them: (name, function editing the header in place)
EDITS = {
    "rename prior": lambda h: h.update(priors=h.pop("prior")),
    "length scale 1e308": lambda h: h["fits"][0]["values"].update(length_scale=1e308),
    "dt 1e-300": lambda h: h.update(dt=1e-300),
    "version true": lambda h: h.update(version=True),
    "shared flipped": lambda h: h.update(shared=not h["shared"]),
    "prior gain": lambda h: h["prior"].update(gain=1e300),
    "time input": lambda h: h.update(time_input="seconds"),
    "kernel metric": lambda h: h["kernel"].update(metric="nope"),
    "rename fits": lambda h: h.update(fit=h.pop("fits")),
    "output names": lambda h: h.update(output_names=h["output_names"][::-1]),
}


def test_a_saved_model_checksums_its_header(prior_model_path):
    header, _ = B.read_model_npz(prior_model_path)
    assert header["version"] == FORMAT_VERSION == 8
    assert header["checksums"]["header"] == header_sha256(header)
    # the checksum covers every field but itself, in canonical form (key order, spacing do not matter)
    assert header_sha256(dict(reversed(list(header.items())))) == header["checksums"]["header"]
    assert header_sha256({**header, "dt": header["dt"] * (1 + 1e-15)}) != header["checksums"]["header"]
    _, loaded = load_model(prior_model_path)
    assert loaded["checksums"]["header"] == header["checksums"]["header"]


@pytest.mark.parametrize("edit", sorted(EDITS))
def test_a_header_edited_by_hand_is_refused(prior_model_path, tmp_path, edit):
    header, arrays = B.read_model_npz(prior_model_path)
    EDITS[edit](header)
    bad = B.write_model_npz(tmp_path / "edited.rbgp", header, arrays, header_checksum=False)
    refused(bad, "checksum mismatch in the model header")


@pytest.mark.parametrize("edit", sorted(EDITS))
def test_a_header_edit_with_a_recomputed_checksum_is_refused_by_validation(prior_model_path, tmp_path, edit):
    """Someone who recomputes the checksum (or a buggy writer) still meets the field checks."""
    header, arrays = B.read_model_npz(prior_model_path)
    EDITS[edit](header)
    bad = B.write_model_npz(tmp_path / "edited.rbgp", header, arrays)
    refused(bad, "model header")


@pytest.mark.parametrize("edit", sorted(EDITS))
def test_an_old_version_file_edited_by_hand_is_refused_by_validation(prior_model_path, tmp_path, edit):
    header, arrays = B.read_model_npz(prior_model_path)
    header = B.as_old_version(header, 2)
    EDITS[edit](header)
    bad = B.write_model_npz(tmp_path / "edited.rbgp", header, arrays, header_checksum=False)
    refused(bad, "model header")


def test_a_new_version_file_without_a_header_checksum_is_refused(prior_model_path, tmp_path):
    header, arrays = B.read_model_npz(prior_model_path)
    del header["checksums"]["header"]
    bad = B.write_model_npz(tmp_path / "nosum.rbgp", header, arrays, header_checksum=False)
    refused(bad, "no header checksum")


@pytest.mark.parametrize("version", [1, 2])
def test_old_version_files_load_and_give_the_same_outputs(tiny_model, prior_model_path, tmp_path, version):
    """Versions 1 and 2 (exact GPs, no header checksum) load as before: the same rollout, byte for byte."""
    source = tiny_model if version == 1 else prior_model_path  # version 1 had no time input or prior
    header, arrays = B.read_model_npz(source)
    old = B.write_model_npz(tmp_path / f"v{version}.rbgp", B.as_old_version(header, version), arrays,
                            header_checksum=False)  # fmt: skip
    assert "header" not in B.read_model_npz(old)[0]["checksums"]
    assert rollout_csv(old) == rollout_csv(source)
    res = run_cli("info", old)
    assert res.exit_code == 0 and f"version {version}" in res.stdout


def test_an_old_file_with_a_header_checksum_has_it_verified(prior_model_path, tmp_path):
    header, arrays = B.read_model_npz(prior_model_path)
    header = B.as_old_version(header, 2)
    good = B.write_model_npz(tmp_path / "good.rbgp", header, arrays)
    assert rollout_csv(good) == rollout_csv(prior_model_path)
    header["checksums"]["header"] = "0" * 64
    bad = B.write_model_npz(tmp_path / "bad.rbgp", header, arrays, header_checksum=False)
    refused(bad, "checksum mismatch in the model header")


def test_save_and_load_round_trip_unchanged(prior_model_path, tmp_path):
    from rbgp_cli.io.model_store import save_model

    model, header = load_model(prior_model_path)
    again = tmp_path / "again.rbgp"
    save_model(model, again)
    h2, a2 = B.read_model_npz(again)
    _, a1 = B.read_model_npz(prior_model_path)
    assert set(a1) == set(a2) and all(np.array_equal(a1[k], a2[k]) for k in a1)
    assert {k: v for k, v in h2.items() if k not in ("created", "checksums")} == \
        {k: v for k, v in header.items() if k not in ("created", "checksums")}
    assert rollout_csv(again) == rollout_csv(prior_model_path)


# ---------------------------------------------------------------------------------------------- field validation


@pytest.mark.parametrize("field,value,fragment", [
    ("version", True, "format version"),
    ("version", 4.0, "format version"),
    ("dt", 1e-300, "dt = "),
    ("dt", float("nan"), "dt = "),
    ("dt", "0.1", "dt = "),
    ("shared", 1, "shared = "),
    ("time_input", "minutes", "time_input = "),
    ("input_names", ["a", "b"], "input_names"),
    ("representation", {"name": "axis-angle", "order": "xyz"}, "representation"),
    ("kernel", {"kind": "squared_exponential"}, "kernel"),
    ("summary", [], "summary = "),
    ("provenance", {"inputs": [{"name": "a", "sha256": 5}]}, "provenance"),
    ("unknown_key", 1, "unknown field 'unknown_key'"),
])  # fmt: skip
def test_header_fields_are_validated(prior_model_path, tmp_path, field, value, fragment):
    header, arrays = B.read_model_npz(prior_model_path)
    header[field] = value
    bad = B.write_model_npz(tmp_path / "bad.rbgp", header, arrays)
    for load in (load_model, read_header):
        with pytest.raises(InputError, match="model header"):
            load(bad)
    refused(bad, fragment)


@pytest.mark.parametrize("field", ["format", "representation", "kernel", "fits", "dt", "shared", "velocity", "time_input",
                                   "prior", "gp", "input_names", "output_names", "checksums"])  # fmt: skip
def test_a_missing_header_field_is_refused(prior_model_path, tmp_path, field):
    header, arrays = B.read_model_npz(prior_model_path)
    del header[field]
    keep = field == "checksums"  # (the builder would write them again)
    bad = B.write_model_npz(tmp_path / "bad.rbgp", header, arrays, checksums=not keep, header_checksum=not keep)
    refused(bad)


@pytest.mark.parametrize("name,shape", [
    ("X", "cols"), ("X", "rows"), ("X", "flat"), ("Y", "cols"), ("Y", "rows"), ("Y", "flat"),
    ("y_scale", "rows"), ("y_scale", "2d"), ("starts", "cols"), ("starts", "rows"), ("starts", "flat"),
    ("durations", "rows"), ("durations", "2d"), ("prior_s", "rows"), ("prior_quat", "cols"),
    ("prior_position", "cols"), ("prior_velocity", "rows"), ("X", "int"), ("durations", "float32"),
])  # fmt: skip
def test_info_and_load_refuse_arrays_of_the_wrong_shape_or_dtype(prior_model_path, tmp_path, name, shape):
    """With the checksums recomputed: only the shape checks against the header can catch these."""
    header, arrays = B.read_model_npz(prior_model_path)
    a = arrays[name]
    arrays[name] = {
        "cols": lambda: np.concatenate([a, a[:, :1]], axis=1),
        "rows": lambda: a[:-1],
        "flat": lambda: a.reshape(-1),
        "2d": lambda: a.reshape(1, -1),
        "int": lambda: np.round(a).astype(np.int64),
        "float32": lambda: a.astype(np.float32),
    }[shape]()
    bad = B.write_model_npz(tmp_path / "bad.rbgp", header, arrays)
    refused(bad, name)


@pytest.mark.parametrize("name,value", [("y_scale", np.nan), ("y_scale", 0.0), ("y_scale", -1.0), ("durations", 0.0),
                                        ("durations", np.inf), ("starts", np.nan), ("X", np.inf)])  # fmt: skip
def test_non_finite_or_non_positive_arrays_are_refused(prior_model_path, tmp_path, name, value):
    header, arrays = B.read_model_npz(prior_model_path)
    arrays[name] = arrays[name].copy()
    arrays[name].reshape(-1)[0] = value
    bad = B.write_model_npz(tmp_path / "bad.rbgp", header, arrays)
    refused(bad, name)


def test_renamed_keys_are_refused_by_info_without_an_internal_error(prior_model_path, tmp_path):
    header, arrays = B.read_model_npz(prior_model_path)
    for key in ("dt", "shared", "fits", "kernel", "representation", "format"):
        h = json.loads(json.dumps(header))
        h[key + "_renamed"] = h.pop(key)
        bad = B.write_model_npz(tmp_path / f"{key}.rbgp", h, arrays)
        refused(bad, "", ("info", bad), ("info", bad, "--json"))


# ---------------------------------------------------------------------------------------------- hostile contents


def test_a_deeply_nested_header_is_refused(tiny_model, tmp_path):
    header, arrays = B.read_model_npz(tiny_model)
    raw = b'{"format": "rbgp-model", "version": 4, "summary": ' + b"[" * 200_000 + b"]" * 200_000 + b"}"
    bad = B.write_model_npz(tmp_path / "deep.rbgp", header, arrays, raw_header=raw)
    refused(bad, "nested")


def test_brackets_inside_strings_do_not_count_as_nesting(tiny_model, tmp_path):
    header, arrays = B.read_model_npz(tiny_model)
    header["provenance"]["note"] = "[" * 1000 + '\\"{' * 100
    good = B.write_model_npz(tmp_path / "strings.rbgp", header, arrays)
    assert run_cli("info", good).exit_code == 0


@pytest.mark.parametrize("number", [b"1" * 5000, b"1" * 5000 + b".5", b"1e99999", b"-" + b"9" * 400])
def test_a_number_with_thousands_of_digits_is_refused(tiny_model, tmp_path, number):
    header, arrays = B.read_model_npz(tiny_model)
    header["dt"] = "@DT@"
    raw = json.dumps(header, sort_keys=True).encode().replace(b'"@DT@"', number)
    bad = B.write_model_npz(tmp_path / "long.rbgp", header, arrays, raw_header=raw)
    refused(bad, "model header")


def test_an_oversized_header_is_refused(tiny_model, tmp_path):
    header, arrays = B.read_model_npz(tiny_model)
    header["provenance"]["padding"] = "x" * (17 << 20)
    bad = B.write_model_npz(tmp_path / "big.rbgp", header, arrays, header_checksum=False)
    refused(bad, "header", ("info", bad))


@pytest.mark.parametrize("shape", [(10**10, 7), (2**62, 7), (7, 10**10)])
def test_declared_shapes_larger_than_the_member_are_refused_before_reading(tiny_model, tmp_path, shape):
    header, arrays = B.read_model_npz(tiny_model)
    bad = B.write_zip_bomb(tmp_path / "huge.rbgp", header, arrays, member="X", shape=shape, data_bytes=4096)
    t0 = time.perf_counter()
    refused(bad, "'X'", ("info", bad))
    assert time.perf_counter() - t0 < 5


def test_the_starts_of_the_wrong_shape_are_refused(tiny_model, tmp_path):
    header, arrays = B.read_model_npz(tiny_model)
    arrays["starts"] = np.concatenate([arrays["starts"]] * 2).reshape(-1)[:-1]  # (2·D·7 − 1,): cannot be (D, 7)
    bad = B.write_model_npz(tmp_path / "starts.rbgp", header, arrays)
    refused(bad, "'starts'")


def test_nan_y_scale_is_refused_at_load_not_as_a_diverged_rollout(tiny_model, tmp_path):
    header, arrays = B.read_model_npz(tiny_model)
    arrays["y_scale"] = np.full_like(arrays["y_scale"], np.nan)
    bad = B.write_model_npz(tmp_path / "nan.rbgp", header, arrays)
    refused(bad, "'y_scale'")


def _limited():
    resource.setrlimit(resource.RLIMIT_AS, (1 << 30, 1 << 30))


def run_limited(*args, timeout=60):
    """``python -m rbgp_cli ARGS`` under an address-space limit of 1 GiB; (exit code, stderr, seconds)."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    t0 = time.perf_counter()
    res = subprocess.run([sys.executable, "-m", "rbgp_cli", "-q", *map(str, args)], capture_output=True, text=True,
                         env=env, preexec_fn=_limited, timeout=timeout)  # fmt: skip
    return res.returncode, res.stderr, time.perf_counter() - t0


@pytest.fixture(scope="session")
def bombs(tiny_model_path, tmp_path_factory) -> dict:
    """The fault run's hostile files: zip bombs of ~2 GB and ~6 GB of zeros (1.97 and 5.9 MB on
    disk), and a member declaring 10¹⁰ rows."""
    folder = tmp_path_factory.mktemp("bombs")
    header, arrays = B.read_model_npz(tiny_model_path)
    d = arrays["X"].shape[1]
    return {
        "2GB": B.write_zip_bomb(folder / "bomb2.rbgp", header, arrays, member="X", shape=((2 << 30) // (8 * d), d)),
        "6GB": B.write_zip_bomb(folder / "bomb6.rbgp", header, arrays, member="Y", shape=((6 << 30) // 48, 6)),
        "1e10 rows": B.write_zip_bomb(folder / "rows.rbgp", header, arrays, member="X", shape=(10**10, d),
                                      data_bytes=1 << 20),
    }


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["2GB", "6GB", "1e10 rows"])
def test_zip_bombs_are_refused_quickly_under_a_1_gib_memory_limit(bombs, kind):
    path = bombs[kind]
    assert path.stat().st_size < 7 << 20
    for command in (("info", path), ("rollout", path, "--steps", "3")):
        code, err, seconds = run_limited(*command)
        lines = err.strip().splitlines()
        assert code == 2, err
        assert lines[0].startswith(f"rbgp: error: {path}: ") and "internal error" not in err, err
        assert "--max-points" not in err and "out of memory" not in err
        assert len([ln for ln in lines if not ln.startswith("  ")]) == 1, err
        assert seconds < 20, seconds


@pytest.mark.slow
def test_a_valid_model_loads_under_the_same_memory_limit(prior_model_path):
    code, err, _ = run_limited("info", prior_model_path)
    assert code == 0, err


# ---------------------------------------------------------------------------------------------- every field


JUNK = (None, True, 0, -1, 1e308, float("nan"), "x", [], {}, [1, 2])


def _paths(obj, prefix=()):
    """Every path into a JSON value; of a list's items only the first two (the rest repeat them), and
    of the display-only parts (summary, provenance, each fit's optimiser starts) the first levels."""
    if prefix:
        yield prefix
    if prefix[:1] in (("summary",), ("provenance",)) and len(prefix) >= 3 or "starts" in prefix[1:3]:
        return
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from _paths(v, prefix + (k,))
    elif isinstance(obj, list):
        for i, v in enumerate(obj[:2]):
            yield from _paths(v, prefix + (i,))


@pytest.mark.slow
@pytest.mark.parametrize("source", ["tiny", "prior"])
def test_every_single_field_mutation_is_refused_or_gives_a_working_model(tiny_model_path, prior_model_path, tmp_path,
                                                                         source):
    """Each field of a valid header set to each junk value (or removed), header checksum recomputed:
    load_model refuses it (InputError) or returns a model that predicts finite values, and ``rbgp
    info``'s report is built without an error."""
    from rbgp_cli.cli.report import format_model_info

    path = tiny_model_path if source == "tiny" else prior_model_path
    header, arrays = B.read_model_npz(path)
    paths = [p for p in _paths(header) if p[:2] != ("checksums", "header")]
    outcomes = {"refused": 0, "loaded": 0}
    for k, p in enumerate(paths):
        for value in (*JUNK, "<delete>"):
            h = json.loads(json.dumps(header))
            target = h
            for key in p[:-1]:
                target = target[key]
            if value == "<delete>":
                if not isinstance(target, dict):
                    continue
                del target[p[-1]]
            else:
                target[p[-1]] = value
            f = B.write_model_npz(tmp_path / f"{k}.rbgp", h, arrays)
            try:
                model, loaded = load_model(f)
            except InputError as exc:
                assert str(f) in str(exc) or exc.path == str(f)
                outcomes["refused"] += 1
                continue
            outcomes["loaded"] += 1
            tau = np.zeros(len(model.starts)) if model.time_input else None
            mean, std = model.predict(model.starts[:, :4], model.starts[:, 4:], tau=tau)
            assert np.all(np.isfinite(mean)) and np.all(np.isfinite(std)), (p, value)
            format_model_info(str(f), {**loaded, "training_points": len(model.gp.X)})
    assert outcomes["refused"] > 0 and outcomes["loaded"] > 0, outcomes


def test_a_gp_too_large_for_memory_is_refused_naming_the_file(tiny_model, monkeypatch):
    """Not the training's "use --max-points" hint: the file is what is too big."""
    from rbgp_cli.gp import exact

    def no_memory(self, *a, **k):
        raise MemoryError

    monkeypatch.setattr(exact.GaussianProcess, "_factorise", no_memory)
    res = run_cli("rollout", tiny_model, "--steps", "3")
    assert res.exit_code == 2 and res.stderr.startswith(f"rbgp: error: {tiny_model}: not enough memory to rebuild")
    assert "--max-points" in res.stderr and "out of memory; use --max-points or --subsample" not in res.stderr


def test_an_old_sparse_file_version_3_loads_and_gives_the_same_outputs(tmp_path):
    folder = tmp_path / "demos"
    folder.mkdir()
    for k in range(2):
        B.write_csv(folder / f"demo_{k}.csv", B.smooth_motion(seed=k, name=f"demo_{k}"))
    path = tmp_path / "sparse.rbgp"
    res = run_cli("train", folder, "-o", path, *B.FAST, "--inducing", "12")
    assert res.exit_code == 0, res.stderr
    header, arrays = B.read_model_npz(path)
    assert header["version"] == 8 and header["gp"]["type"] == "sparse" and "Z" in arrays  # (at most 12 inducing poses)
    old = B.write_model_npz(tmp_path / "v3.rbgp", B.as_old_version(header, 3), arrays, header_checksum=False)
    assert rollout_csv(old) == rollout_csv(path)
    h = B.as_old_version(header, 3)
    del h["gp"]  # version 3 always says what GP it holds: without it the sparse arrays would be ignored
    refused(B.write_model_npz(tmp_path / "nogp.rbgp", h, arrays, header_checksum=False), "gp is missing")
