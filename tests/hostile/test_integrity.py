"""Model file integrity and atomic output (issue 4, part 4).

* Every stored array has a SHA-256 in the header, verified on load: any change to an array (a value,
  its dtype, its shape) or to its checksum is refused, by ``rbgp info`` too.
* Loading never executes code: no pickle (``allow_pickle=False``), so a model file carrying a
  pickled payload is refused and the payload never runs.
* Every output file (models, CSVs, per-step scores, recordings, figures) is written to a hidden
  temporary name in the destination folder and renamed onto it: a failure part way leaves neither a
  partial file nor the temporary one, and an existing file stays as it was.
"""

from __future__ import annotations

import json
import os
import pickle
import shutil
from pathlib import Path

import numpy as np
import pytest

from rbgp_cli.errors import InputError
from rbgp_cli.io.model_store import FORMAT_VERSION, array_sha256, load_model, read_header, save_model
from tests.hostile import builders as B
from tests.hostile.conftest import run_cli

ARRAYS = ("X", "Y", "y_scale", "starts", "durations")


def leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in Path(folder).iterdir() if p.name.endswith(".tmp"))


# ---------------------------------------------------------------------------------------------- checksums


def test_a_saved_model_stores_the_checksum_of_every_array(tiny_model):
    header, arrays = B.read_model_npz(tiny_model)
    assert set(header["checksums"]) == {*ARRAYS, "header"} and set(arrays) == set(ARRAYS)  # and the header's own
    for name in ARRAYS:
        assert header["checksums"][name] == array_sha256(arrays[name])
    model, loaded_header = load_model(tiny_model)
    assert loaded_header["checksums"] == header["checksums"]


def _changed(arrays, name, how):
    a = dict(arrays)
    v = np.array(a[name], copy=True)
    if how == "value":
        v.reshape(-1)[v.size // 2] = np.nextafter(v.reshape(-1)[v.size // 2], np.inf)  # one ulp
    elif how == "dtype":
        v = v.astype(np.float32).astype(np.float64) if v.dtype == np.float32 else v.astype(np.float32)
    elif how == "shape":
        v = v.reshape(-1)
        if v.shape == a[name].shape:  # already flat
            v = v.reshape(1, -1)
    a[name] = v
    return a


@pytest.mark.parametrize("how", ["value", "dtype", "shape"])
@pytest.mark.parametrize("name", ARRAYS)
def test_any_change_to_an_array_is_refused(tiny_model, tmp_path, name, how):
    header, arrays = B.read_model_npz(tiny_model)
    bad = B.write_model_npz(tmp_path / "bad.rbgp", header, _changed(arrays, name, how), checksums=False)
    for load in (load_model, read_header):
        with pytest.raises(InputError, match=f"checksum mismatch in array '{name}'"):
            load(bad)
    res = run_cli("info", bad)
    assert res.exit_code == 2 and res.stderr.startswith(f"rbgp: error: {bad}: checksum mismatch in array '{name}'")


@pytest.mark.parametrize("name", ARRAYS)
def test_a_missing_or_wrong_checksum_is_refused(tiny_model, tmp_path, name):
    header, arrays = B.read_model_npz(tiny_model)
    for checksums in ({k: v for k, v in header["checksums"].items() if k != name},
                      {**header["checksums"], name: "0" * 64}):  # fmt: skip
        bad = B.write_model_npz(tmp_path / "bad.rbgp", {**header, "checksums": checksums}, arrays, checksums=False,
                                header_checksum=True)  # the header's own checksum matches: only the array's is wrong
        with pytest.raises(InputError, match=f"checksum mismatch in array '{name}'"):
            load_model(bad)


@pytest.mark.parametrize("name", ARRAYS)
def test_a_missing_array_is_refused(tiny_model, tmp_path, name):
    header, arrays = B.read_model_npz(tiny_model)
    del arrays[name]
    bad = B.write_model_npz(tmp_path / "bad.rbgp", header, arrays, checksums=False)
    with pytest.raises(InputError, match=f"array '{name}' is missing"):
        load_model(bad)


def test_the_checksum_covers_dtype_shape_and_values_but_not_byte_order_or_memory_layout():
    a = np.arange(12.0).reshape(3, 4)
    h = array_sha256(a)
    assert array_sha256(a.astype(">f8")) == h  # big-endian copy: same numbers
    assert array_sha256(np.asfortranarray(a)) == h  # Fortran order: same numbers
    assert array_sha256(a.astype(np.float32)) != h
    assert array_sha256(a.reshape(4, 3)) != h
    b = a.copy()
    b[1, 2] = np.nextafter(b[1, 2], 0)
    assert array_sha256(b) != h


@pytest.mark.parametrize("version,fragment", [
    (FORMAT_VERSION + 1, "newer than this rbgp supports"),
    (0, "unknown model format version 0"),
    ("1", "no valid format version"),
    (None, "no valid format version"),
])  # fmt: skip
def test_format_versions(tiny_model, tmp_path, version, fragment):
    header, arrays = B.read_model_npz(tiny_model)
    bad = B.write_model_npz(tmp_path / "v.rbgp", {**header, "version": version}, arrays)
    with pytest.raises(InputError, match=fragment):
        load_model(bad)


# ---------------------------------------------------------------------------------------------- no code runs


class _Payload:
    """Unpickling this creates a directory: proof that code ran."""

    def __init__(self, marker):
        self.marker = str(marker)

    def __reduce__(self):
        return (os.mkdir, (self.marker,))


def _object_array(marker) -> np.ndarray:
    a = np.empty(1, dtype=object)
    a[0] = _Payload(marker)
    return a


@pytest.mark.parametrize("where", ARRAYS + ("header",))
def test_a_pickled_array_is_refused_and_never_unpickled(tiny_model, tmp_path, where):
    marker = tmp_path / "code-ran"
    header, arrays = B.read_model_npz(tiny_model)
    members = {"header": np.frombuffer(json.dumps(header).encode(), dtype=np.uint8), **arrays}
    members[where] = _object_array(marker)
    path = tmp_path / "evil.rbgp"
    with open(path, "wb") as fh:
        np.savez(fh, **members)  # numpy pickles object arrays when saving
    for load in (load_model, read_header):
        with pytest.raises(InputError, match="evil.rbgp"):
            load(path)
    res = run_cli("rollout", path, "--steps", "3")
    assert res.exit_code == 2 and "internal error" not in res.stderr
    assert not marker.exists()


@pytest.mark.parametrize("kind", ["pickle", "npy"])
def test_a_pickle_or_npy_file_posing_as_a_model_is_refused(tmp_path, kind):
    marker = tmp_path / "code-ran"
    path = tmp_path / "evil.rbgp"
    if kind == "pickle":
        path.write_bytes(pickle.dumps({"header": _Payload(marker)}))
    else:
        with open(path, "wb") as fh:
            np.save(fh, _object_array(marker), allow_pickle=True)
    with pytest.raises(InputError, match="not an rbgp model file"):
        load_model(path)
    assert not marker.exists()


def test_loading_a_valid_model_never_calls_pickle(tiny_model, monkeypatch):
    def forbidden(*a, **k):
        raise AssertionError("pickle was used while loading a model")

    for name in ("load", "loads", "Unpickler"):
        monkeypatch.setattr(pickle, name, forbidden)
    model, header = load_model(tiny_model)
    assert model.gp.X.shape[0] >= 2


def test_model_store_source_has_no_pickle():
    src = Path(__file__).resolve().parents[2] / "rbgp_cli" / "io" / "model_store.py"
    text = src.read_text()
    assert "allow_pickle=True" not in text and "import pickle" not in text
    # the members are read by rbgp itself (not np.load), and arrays of objects are refused before reading
    assert "np.load(" not in text and "dtype.hasobject" in text


# ---------------------------------------------------------------------------------------------- atomic output


class _Boom(RuntimeError):
    pass


def test_save_model_failing_part_way_leaves_nothing(tiny_model, tmp_path, monkeypatch):
    model, _ = load_model(tiny_model)

    def half_then_fail(fh, **arrays):
        fh.write(b"PK\x03\x04 half a zip")
        raise _Boom("disk full")

    monkeypatch.setattr(np, "savez_compressed", half_then_fail)
    out = tmp_path / "out"
    out.mkdir()
    with pytest.raises(_Boom):
        save_model(model, out / "m.rbgp")
    assert list(out.iterdir()) == []
    # an existing model stays as it was
    shutil.copyfile(tiny_model, out / "m.rbgp")
    before = (out / "m.rbgp").read_bytes()
    with pytest.raises(_Boom):
        save_model(model, out / "m.rbgp")
    assert (out / "m.rbgp").read_bytes() == before and leftovers(out) == []


def test_interrupted_write_leaves_nothing(tmp_path):
    from rbgp_cli.io.atomic import atomic_open

    dest = tmp_path / "gen.csv"
    dest.write_text("old\n")
    with pytest.raises(KeyboardInterrupt):
        with atomic_open(dest, "w") as fh:
            fh.write("new, half")
            raise KeyboardInterrupt
    assert dest.read_text() == "old\n" and leftovers(tmp_path) == []


@pytest.fixture
def renames(monkeypatch):
    """Every os.replace call, as (source, destination)."""
    calls = []
    real = os.replace

    def spy(src, dst, *a, **k):
        calls.append((Path(src), Path(dst)))
        return real(src, dst, *a, **k)

    monkeypatch.setattr(os, "replace", spy)
    return calls


def _assert_renamed_into_place(calls, outputs):
    by_dest = {dst.resolve(): src for src, dst in calls}
    for out in outputs:
        out = Path(out)
        assert out.exists() and out.stat().st_size > 0, out
        src = by_dest.get(out.resolve())
        assert src is not None, f"{out.name} was not renamed into place"
        assert src.parent.resolve() == out.parent.resolve(), "the temporary file must be beside the output"
        assert src.name.startswith(f".{out.name}.") and src.name.endswith(".tmp"), src.name
        assert not src.exists()
    assert leftovers(Path(outputs[0]).parent) == []


def test_every_cli_output_is_renamed_into_place(tmp_path, renames):
    demos = tmp_path / "demos"
    demos.mkdir()
    for k in range(3):
        B.write_csv(demos / f"demo_{k}.csv", B.smooth_motion(seed=k, name=f"demo_{k}"))
    out = tmp_path / "out"
    out.mkdir()
    model = out / "m.rbgp"
    res = run_cli("train", demos, "-o", model, *B.FAST, "--json")
    assert res.exit_code == 0, res.stderr
    poses = tmp_path / "poses.csv"
    poses.write_text("rx,ry,rz,x,y,z\n0.1,0.2,0.3,0.3,0.0,1.1\n")
    assert run_cli("predict", model, poses, "-o", out / "pred.csv").exit_code == 0
    res = run_cli("rollout", model, "--count", "3", "--steps", "20", "-o", out / "gen.csv")
    assert res.exit_code == 0, res.stderr
    res = run_cli("evaluate", out / "gen.csv", "--demos", demos, "--per-step", out / "steps.csv", "--json")
    assert res.exit_code == 0, res.stderr
    _assert_renamed_into_place(renames, [model, out / "pred.csv", out / "gen.csv", out / "steps.csv"])


@pytest.mark.slow
def test_recordings_and_figures_are_renamed_into_place(tmp_path, tiny_model, renames):
    pytest.importorskip("rerun")
    pytest.importorskip("matplotlib")
    demos = tmp_path / "demos"
    demos.mkdir()
    B.write_csv(demos / "demo.csv")
    B.write_csv(demos / "demo2.csv", B.smooth_motion(seed=1))  # one demonstration alone cannot be scored
    res = run_cli("rollout", tiny_model, "--count", "2", "--steps", "10", "-o", tmp_path / "gen.csv",
                  "--rerun", tmp_path / "rollout.rrd")  # fmt: skip
    assert res.exit_code == 0, res.stderr
    res = run_cli("evaluate", tmp_path / "gen.csv", "--demos", demos, "--plot", tmp_path / "eval.png", "--json")
    assert res.exit_code == 0, res.stderr
    _assert_renamed_into_place(renames, [tmp_path / "rollout.rrd", tmp_path / "eval.png"])


def test_a_cli_write_failing_part_way_leaves_the_old_file(tmp_path, tiny_model, monkeypatch):
    """rollout -o gen.csv whose CSV writer fails after some rows: gen.csv keeps its old content."""
    import rbgp_cli.io.csv as csv_mod

    real = csv_mod.write_trajectories_csv

    def fail_half_way(trajs, fh, extra=None):
        real(trajs[:1], fh)
        raise _Boom("the disk went away")

    monkeypatch.setattr(csv_mod, "write_trajectories_csv", fail_half_way)
    dest = tmp_path / "gen.csv"
    dest.write_text("old\n")
    res = run_cli("rollout", tiny_model, "--count", "3", "--steps", "5", "-o", dest)
    assert res.exit_code == 1 and res.stdout == ""
    assert dest.read_text() == "old\n"
    assert leftovers(tmp_path) == []
