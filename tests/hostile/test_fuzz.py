"""Property-based fuzzing of the readers, the MCAP path and the model loader (issue 4, part 3).

Valid small files (a generic CSV and TSV, a QTM 6D TSV, a Motive CSV and a Vicon CSV written with
:mod:`rbgp_cli.io.export`, ROS 2 MCAP files written with mcap_ros2, and a model file of a tiny model)
are mutated byte by byte: bits flipped, ranges deleted, inserted, duplicated or overwritten with
"interesting" bytes (delimiters, NaN, huge integers for length fields), and the file truncated. The
library must then either return clean data or raise :class:`~rbgp_cli.errors.InputError`: any other
exception is a failure, and so is a library warning that data was silently lost (pandas'
ParserWarning); :class:`~rbgp_cli.errors.RbgpWarning` is how repairs are reported and is allowed.
Whatever is returned must be usable: strictly increasing finite times, unit quaternions continuous
in sign, finite positions, and forward differences that can be taken.

CI runs a bounded, derandomized number of examples (profile ``rbgp-ci`` in conftest.py); a long
campaign sets ``RBGP_FUZZ_EXAMPLES`` (docs/FUZZING.md).
"""

from __future__ import annotations

import functools
import io
import itertools
import tempfile
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import event, given, note, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from rbgp_cli.errors import InputError, RbgpWarning
from tests.hostile import builders as B
from tests.hostile.conftest import CI_EXAMPLES, fuzz_settings

# ---------------------------------------------------------------------------------------------- seeds

TEXT_SEEDS = ("demo.csv", "demo.tsv", "take_6D.tsv", "take.csv", "vicon.csv")
MCAP_SEEDS = ("zstd.mcap", "plain.mcap", "lz4.mcap", "tf_json.mcap")


@functools.cache
def seeds() -> dict[str, bytes]:
    """The valid files every mutation starts from, written once per session (short motions: 40
    samples, so a mutation lands in any part of the file with fair probability)."""
    from rbgp_cli.dynamics.model import train_model
    from rbgp_cli.dynamics.prepare import prepare_all
    from rbgp_cli.io.export import write_vicon_csv
    from rbgp_cli.io.model_store import save_model

    tr = B.smooth_motion(n=40)
    with tempfile.TemporaryDirectory(prefix="rbgp-fuzz-seeds-") as d:
        d = Path(d)
        B.write_csv(d / "demo.csv", tr)
        B.write_csv(d / "demo.tsv", tr, delimiter="\t")
        B.write_qtm(d / "take_6D.tsv", tr)
        B.write_motive(d / "take.csv", tr)
        write_vicon_csv([tr.with_(name="sub:shoe")], d / "vicon.csv")
        B.write_mcap(d / "zstd.mcap", tr, chunk_size=1024, compression="zstd")
        B.write_mcap(d / "plain.mcap", tr, chunk_size=1024, compression="none", extra_strings="/chatter")
        B.write_mcap(d / "lz4.mcap", tr, chunk_size=2048, compression="lz4")
        B.write_mcap_json_tf(d / "tf_json.mcap", tr, schema_encoding="jsonschema")
        clean, _ = prepare_all([tr])
        model = train_model(clean, max_points=12, subsample=None, restarts=1, shared=True)
        save_model(model, d / "tiny.rbgp")
        return {p.name: p.read_bytes() for p in d.iterdir()}


# ---------------------------------------------------------------------------------------------- mutations

#: bytes that mean something to a parser: delimiters, quotes, comments, number syntax, NaN-like
#: tokens, line ends, a NUL, MCAP/zip magic, and little-endian lengths from 0 to 2**64 - 1
TOKENS = [
    b",", b";", b"\t", b" ", b"\n", b"\r\n", b'"', b"#", b"-", b".", b"e", b"E", b"1e309", b"-0", b"nan",
    b"null", b"inf", b"0", b"9" * 30, b"\x00", b"\xff", b"\xef\xbb\xbf", b"\x89MCAP0\r\n", b"PK\x03\x04",
    *(v.to_bytes(8, "little") for v in (0, 1, 2**31, 2**32 - 1, 2**40, 2**62, 2**63, 2**64 - 1)),
    *(v.to_bytes(4, "little") for v in (0, 2**31, 2**32 - 1)),
]  # fmt: skip


class Mutant:
    """A mutated seed file; its repr (what hypothesis prints for a failure) is the recipe, not the
    bytes (a plain class: hypothesis would print every field of a dataclass)."""

    __slots__ = ("name", "data", "ops")

    def __init__(self, name: str, data: bytes, ops: tuple):
        self.name, self.data, self.ops = name, data, ops

    def __repr__(self) -> str:
        return f"Mutant({self.name!r}, {len(self.data)} bytes, ops={list(self.ops)!r})"


@st.composite
def mutated(draw, names) -> Mutant:
    """A seed file with 1–4 operations applied at positions drawn as fractions of the current
    length, so every region of the file is reachable."""
    name = draw(st.sampled_from(names))
    data = bytearray(seeds()[name])
    ops = []

    def pos(size):
        return min(size, int(draw(st.floats(0, 1, exclude_max=True)) * (size + 1)))

    for _ in range(draw(st.integers(1, 4))):
        op = draw(st.sampled_from(["flip", "delete", "insert", "duplicate", "overwrite", "truncate"]))
        n = len(data)
        if op == "flip" and n:
            i, bit = pos(n - 1), draw(st.integers(0, 7))
            data[i] ^= 1 << bit
            ops.append((op, i, bit))
        elif op == "delete" and n:
            i, k = pos(n - 1), draw(st.integers(1, 64))
            del data[i:i + k]
            ops.append((op, i, k))
        elif op == "insert":
            i = pos(n)
            chunk = draw(st.sampled_from(TOKENS) | st.binary(min_size=1, max_size=16))
            data[i:i] = chunk
            ops.append((op, i, chunk))
        elif op == "duplicate" and n:
            i, k, j = pos(n - 1), draw(st.integers(1, 256)), pos(n)
            data[j:j] = data[i:i + k]
            ops.append((op, i, k, j))
        elif op == "overwrite" and n:
            i, chunk = pos(n - 1), draw(st.sampled_from(TOKENS))
            data[i:i + len(chunk)] = chunk
            ops.append((op, i, chunk))
        elif op == "truncate":
            i = pos(n)
            del data[i:]
            ops.append((op, i))
    return Mutant(name, bytes(data), tuple(ops))


_counter = itertools.count()


def write(folder: Path, name: str, data: bytes) -> Path:
    """A fresh file per example (re-writing one name costs ~4 ms a time on this file system)."""
    p = folder / f"{next(_counter)}-{name}"
    p.write_bytes(data)
    return p


# ---------------------------------------------------------------------------------------------- checks


def assert_clean(trajs) -> None:
    """What prepare_all returns is fit to train on (docs/method.md §4)."""
    from rbgp_cli.dynamics.velocities import forward_differences

    assert trajs
    for tr in trajs:
        assert len(tr) >= 2
        assert np.all(np.isfinite(tr.t)) and np.all(np.diff(tr.t) > 0)
        assert np.all(np.isfinite(tr.position)) and np.all(np.isfinite(tr.quat))
        np.testing.assert_allclose(np.linalg.norm(tr.quat, axis=1), 1.0, atol=1e-12)
        assert np.all(np.sum(tr.quat[1:] * tr.quat[:-1], axis=1) >= 0)
        xi, _ = forward_differences(tr)
        assert np.all(np.isfinite(xi))


def read_and_prepare(sources, stdin=None):
    """read_demonstrations + prepare_all; returns the clean trajectories or the InputError."""
    from rbgp_cli.dynamics.prepare import prepare_all
    from rbgp_cli.io.options import ReadOptions
    from rbgp_cli.io.read import read_demonstrations

    with warnings.catch_warnings():
        # (the filter added last wins)
        warnings.simplefilter("error", UserWarning)  # a library saying it dropped something: a failure
        warnings.simplefilter("ignore", RbgpWarning)  # repairs are reported, that is fine
        warnings.simplefilter("ignore", RuntimeWarning)  # numpy on absurd values; the outcome is checked
        warnings.simplefilter("ignore", DeprecationWarning)
        try:
            clean, _ = prepare_all(read_demonstrations(sources, ReadOptions(), stdin=stdin))
        except InputError as exc:
            event("InputError")
            return exc
    assert_clean(clean)
    event("clean data")
    return clean


def load_or_refuse(path) -> None:
    """load_model: an InputError, or a model whose predictions at its own starts are finite (std >= 0)."""
    from rbgp_cli.io.model_store import load_model

    try:
        model, _ = load_model(path)
    except InputError:
        event("InputError")
        return
    event("loaded")
    tau = np.zeros(len(model.starts)) if model.time_input else None  # the default model takes the phase
    mean, std = model.predict(model.starts[:, :4], model.starts[:, 4:], tau=tau)
    assert np.all(np.isfinite(mean)) and np.all(np.isfinite(std)) and np.all(std >= 0)


class _Pipe(io.RawIOBase):
    """A non-seekable stream, like stdin from a pipe (the MCAP reader then reads front to back)."""

    def __init__(self, data: bytes):
        self._buf = io.BytesIO(data)

    def readable(self):
        return True

    def readinto(self, b):
        chunk = self._buf.read(len(b))
        b[: len(chunk)] = chunk
        return len(chunk)


# ---------------------------------------------------------------------------------------------- fuzz tests


@pytest.fixture(scope="module")
def fuzz_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("fuzz")


@pytest.mark.parametrize(
    "names, pipe",
    [(TEXT_SEEDS, False), (MCAP_SEEDS, False), (MCAP_SEEDS, True)],
    ids=["text-file", "mcap-file", "mcap-pipe"],
)
@fuzz_settings
@given(data=st.data())
@pytest.mark.slow
def test_fuzz_readers(names, pipe, data, fuzz_dir):
    """Mutated files: clean data or InputError, nothing else. CSV / TSV / QTM / Motive / Vicon bytes;
    MCAP files (seekable: summary first, then a linear scan after damage); and the same MCAP bytes on
    a non-seekable stream (``rbgp train - < rec.mcap`` through a pipe)."""
    case = data.draw(mutated(names), label="case")
    if pipe:
        read_and_prepare(["-"], stdin=io.BufferedReader(_Pipe(case.data)))
    else:
        read_and_prepare([str(write(fuzz_dir, case.name, case.data))])


@fuzz_settings
@given(case=mutated(("tiny.rbgp",)))
def test_fuzz_model_loader(case, fuzz_dir):
    """Model files, mutated: a verified model or InputError; a model that loads predicts finitely."""
    load_or_refuse(write(fuzz_dir, case.name, case.data))


@st.composite
def model_headers(draw):
    """A valid model whose JSON header has one value replaced (or removed), with correct array
    checksums, the header's own recomputed: what a buggy writer makes, which only the field checks catch."""
    header, _ = B.read_model_npz(seeds()["tiny.rbgp"])
    paths = []

    def walk(obj, prefix):
        if prefix and prefix[0] in ("provenance", "summary", "checksums", "created", "rbgp_version"):
            return
        if prefix:
            paths.append(prefix)
        if isinstance(obj, dict):
            for k, v in obj.items():
                walk(v, prefix + (k,))
        elif isinstance(obj, list):
            for i, v in enumerate(obj):
                walk(v, prefix + (i,))

    walk(header, ())
    path = draw(st.sampled_from(paths))
    junk = st.one_of(st.none(), st.booleans(), st.integers(-2**70, 2**70), st.floats(allow_nan=True),
                     st.text(max_size=8), st.just([]), st.just({}), st.lists(st.integers(), max_size=3))
    target = header
    for k in path[:-1]:
        target = target[k]
    if isinstance(target, dict) and draw(st.booleans()):
        del target[path[-1]]
        return header, ("del", path)
    value = draw(junk)
    target[path[-1]] = value
    return header, ("set", path, value)


@fuzz_settings
@given(edit=model_headers())
@pytest.mark.slow
def test_fuzz_model_header_values(edit, fuzz_dir):
    header, what = edit
    note(str(what))
    _, arrays = B.read_model_npz(seeds()["tiny.rbgp"])
    load_or_refuse(B.write_model_npz(fuzz_dir / f"{next(_counter)}-h.rbgp", header, arrays))


_runner = CliRunner()


@settings(fuzz_settings, max_examples=max(10, fuzz_settings.max_examples // 4))
@given(case=mutated(("demo.csv", "zstd.mcap", "take_6D.tsv")))
@pytest.mark.slow
def test_fuzz_train_end_to_end(case, fuzz_dir):
    """``rbgp train`` on mutated files: exit 0, or exit 2 with one error line; never a traceback, an
    internal error, or a model file when it fails."""
    from rbgp_cli.cli.app import app

    name, data = case.name, case.data
    src = write(fuzz_dir, name, data)
    out = fuzz_dir / f"{src.name}.rbgp"
    res = _runner.invoke(app, ["-q", "train", str(src), "-o", str(out), *B.FAST, "--subsample", "1", "--json"],
                         catch_exceptions=False)
    lines = res.stderr.splitlines()
    assert "Traceback" not in res.stderr and "internal error" not in res.stderr, res.stderr
    assert all(ln.startswith(("rbgp: error: ", "rbgp: warning: ")) for ln in lines), res.stderr
    event(f"exit {res.exit_code}")
    if res.exit_code == 0:
        assert out.exists()
    else:
        assert res.exit_code == 2, res.stderr
        assert sum(ln.startswith("rbgp: error: ") for ln in lines) == 1 and lines[-1].startswith("rbgp: error: ")
        assert not out.exists() and res.stdout == ""
    assert not list(fuzz_dir.glob(".*.tmp"))


@pytest.mark.slow
def test_mcap_cut_anywhere_gives_a_prefix_of_the_recording_or_input_error(tmp_path):
    """Cut an MCAP file at every 13th byte (file and pipe): what comes back is exactly the first n
    samples of the recording (n >= 2) with a warning, or an InputError; never other samples, never
    another exception. (ECOSYSTEM §1.2 cut at every 7th byte; 13 keeps CI fast and still lands in
    every record type.)"""
    import re

    from rbgp_cli.io.options import ReadOptions
    from rbgp_cli.io.read import read_demonstrations

    truth = B.smooth_motion(n=40)
    data = B.write_mcap(tmp_path / "rec.mcap", truth, chunk_size=512).read_bytes()
    outcomes = set()
    for cut in list(range(0, len(data), 13)) + [len(data) - 1]:
        for source in ("file", "pipe"):
            stdin = None
            if source == "file":
                src = [str(write(tmp_path, "cut.mcap", data[:cut]))]
            else:
                src, stdin = ["-"], io.BufferedReader(_Pipe(data[:cut]))
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                try:
                    (tr,) = read_demonstrations(src, ReadOptions(), stdin=stdin)
                except InputError:
                    outcomes.add("InputError")
                    continue
            n = len(tr)
            assert 1 <= n <= len(truth)
            np.testing.assert_array_equal(tr.quat, truth.quat[:n])
            np.testing.assert_array_equal(tr.position, truth.position[:n])
            np.testing.assert_allclose(tr.t - B.MCAP_T0, truth.t[:n], atol=1e-9)
            texts = [str(w.message) for w in caught if issubclass(w.category, RbgpWarning)]
            if n < len(truth):
                assert any(re.search(rf"recovered {n} pose samples", t) for t in texts), (cut, texts)
            outcomes.add("prefix" if n < len(truth) else "all")
    assert outcomes == {"InputError", "prefix", "all"}


def test_ci_profile_is_bounded():
    """CI runs the derandomized profile with a bounded number of examples (unless asked otherwise)."""
    import os

    if os.environ.get("RBGP_FUZZ_EXAMPLES"):
        pytest.skip("a long fuzzing campaign is running")
    assert fuzz_settings.derandomize and fuzz_settings.deadline is None
    assert fuzz_settings.max_examples == CI_EXAMPLES
