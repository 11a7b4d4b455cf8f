"""Hostile inputs, end to end through the command line (issue 4, part 2).

Every case is one row of ``CASES``: a name, a builder that writes the input files into the test's
folder and returns the command line, and what must happen:

* ``error=(...)``: exit code 2; stderr holds exactly one ``rbgp: error:`` line (warnings may come
  before it), containing every fragment (the file's name, the row or topic, what to do); no traceback,
  no "internal error", nothing on stdout, and the output folder is empty: no output file, no leftover
  temporary file.
* otherwise: exit code 0, every ``warning`` fragment (which counts what was repaired) appears in an
  ``rbgp: warning:`` line, and ``check(ctx)`` verifies the result is right, typically that the model
  equals the one trained on the clean file the hostile one was made from.

Inputs live in ``in/``, outputs go to ``out/``, clean reference files and their models to ``ref/``.
A builder may return ``(args, stdin_bytes)`` for a case that reads ``-``.
"""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import pytest

from rbgp_cli.io.model_store import load_model
from tests.hostile import builders as B
from tests.hostile.conftest import run_cli

# ---------------------------------------------------------------------------------------------- harness


@dataclass
class Ctx:
    root: Path
    model_src: Path  # the session's tiny model (copy it before damaging it)

    @property
    def inp(self) -> Path:
        return self.root / "in"

    @property
    def out(self) -> Path:
        return self.root / "out"

    @property
    def ref(self) -> Path:
        return self.root / "ref"

    @property
    def model_out(self) -> Path:
        return self.out / "model.rbgp"

    def model(self, name: str = "tiny.rbgp") -> Path:
        dst = self.inp / name
        shutil.copyfile(self.model_src, dst)
        return dst

    def train(self, *inputs, opts=()) -> list:
        return ["train", *inputs, "-o", self.model_out, *B.FAST, "--json", *opts]


@dataclass
class Case:
    name: str
    build: Callable[[Ctx], list]
    error: tuple = ()
    warning: tuple = ()
    check: Callable[[Ctx, object], None] | None = None


ROWS = B.table(B.smooth_motion())  # t, x, y, z, qx, qy, qz, qw; data row k is on file line k + 2


def rows() -> np.ndarray:
    return ROWS.copy()


def line(k: int) -> int:
    """File line of data row ``k`` in a file written by ``B.write_table`` (header on line 1)."""
    return k + 2


def csv(ctx: Ctx, data, name: str = "demo.csv", **kw) -> Path:
    return B.write_table(ctx.inp / name, data, **kw)


def text(ctx: Ctx, content, name: str = "demo.csv") -> Path:
    p = ctx.inp / name
    if isinstance(content, bytes):
        p.write_bytes(content)
    else:
        p.write_text(content, encoding="utf-8")
    return p


def train_on(builder, name="demo.csv", opts=(), **kw):
    """A case builder: write the rows ``builder()`` returns, then train on them."""

    def build(ctx: Ctx):
        return ctx.train(csv(ctx, builder(), name, **kw), opts=opts)

    return build


def _starts_close(a: np.ndarray, b: np.ndarray, atol: float) -> None:
    """Start poses (qx, qy, qz, qw, x, y, z): q and -q are the same rotation."""
    flip = np.where(np.sum(a[:, :4] * b[:, :4], axis=1) < 0, -1.0, 1.0)
    np.testing.assert_allclose(a[:, :4] * flip[:, None], b[:, :4], rtol=0, atol=atol)
    np.testing.assert_allclose(a[:, 4:], b[:, 4:], rtol=0, atol=atol)


def assert_same_model(a: Path, b: Path, exact: bool = True) -> None:
    """Same training data (bit for bit, or to round-off when not ``exact``) and the same fit.

    With data equal only to round-off (a unit conversion, a normalisation), L-BFGS-B may stop at a
    slightly different point of a flat likelihood (a few % in λ), so then the fits are compared by
    their predictions at the training inputs instead of their hyperparameters.
    """
    (ma, _), (mb, _) = load_model(a), load_model(b)
    atol = 0.0 if exact else 1e-9
    np.testing.assert_allclose(ma.gp.X, mb.gp.X, rtol=0, atol=atol)
    np.testing.assert_allclose(ma.gp.Y, mb.gp.Y, rtol=0, atol=atol * 100)
    _starts_close(ma.starts, mb.starts, atol)
    np.testing.assert_allclose(ma.durations, mb.durations, rtol=0, atol=atol)
    assert ma.dt == pytest.approx(mb.dt, rel=0, abs=atol)
    assert len(ma.gp.fits) == len(mb.gp.fits)
    if exact:
        for fa, fb in zip(ma.gp.fits, mb.gp.fits):
            assert fa.values == fb.values
    else:
        pa = ma.gp.predict(ma.gp.X)
        pb = mb.gp.predict(mb.gp.X)
        scale = np.std(ma.gp.Y, axis=0)
        assert np.max(np.abs(pa - pb) / scale) < 1e-4  # measured: 3e-6 at most


def same_model_as(reference, opts=(), exact=True, name="demo.csv"):
    """check: the model equals the one trained (same options) on the clean rows ``reference()``."""

    def check(ctx: Ctx, res):
        ctx.ref.mkdir(exist_ok=True)
        ref_file = B.write_table(ctx.ref / name, reference())
        ref_model = ctx.ref / "model.rbgp"
        r = run_cli("train", ref_file, "-o", ref_model, *B.FAST, *opts)
        assert r.exit_code == 0, r.stderr
        assert_same_model(ctx.model_out, ref_model, exact=exact)

    return check


def sign_changes(flipped: np.ndarray) -> int:
    return int(np.sum(flipped[1:] != flipped[:-1]))


# ---------------------------------------------------------------------------------------------- CSV builders
def _delete(k):
    return lambda: np.delete(rows(), k, axis=0)


def _nan_rows():
    r = rows()
    r[10:13, 4:8] = np.nan
    return r


def _blank_cells():
    r = rows().astype(object)
    r[40, 1] = ""
    r[41, 5] = ""
    return r


def _null_cells():
    r = rows().astype(object)
    r[50, 4:8] = "null"
    return r


def _inf_cell():
    r = rows()
    r[60, 2] = np.inf
    return r


def _zero_quats(sl=slice(20, 23)):
    def f():
        r = rows()
        r[sl, 4:8] = 0.0
        return r

    return f


def _far_quat():
    r = rows()
    r[30, 4:8] *= 3.0
    return r


def _slightly_off():
    r = rows()
    r[:, 4:8] *= 1.05
    return r


FLIPPED = (np.arange(len(ROWS)) % 3) == 0


def _demo_column():
    """Two demonstrations in one file: 'a' is the whole motion, 'b' a single sample."""
    r = rows().astype(object)
    a = np.concatenate([np.full((len(r), 1), "a", dtype=object), r], axis=1)
    b = np.concatenate([[["b"]], r[:1]], axis=1)
    return np.concatenate([a, b])


def _sign_flips():
    r = rows()
    r[FLIPPED, 4:8] *= -1
    return r


def _unsorted():
    r = rows()
    r[[30, 31]] = r[[31, 30]]
    return r


def _duplicates():
    r = rows()
    return np.insert(r, 51, [r[50], r[50]], axis=0)


def _dup_time():
    r = rows()
    r[51, 0] = r[50, 0]
    return r


def _time_scaled(scale):
    def f():
        r = rows()
        r[:, 0] *= scale
        return r

    return f


def _length_scaled(scale):
    def f():
        r = rows()
        r[:, 1:4] *= scale
        return r

    return f


def _step_of_pi():
    """From row 60 on, the body is turned by π about z; row 60 repeats row 59's orientation turned,
    so the step 59 -> 60 is exactly a half turn: its direction cannot be told."""
    from scipy.spatial.transform import Rotation

    r = rows()
    half = Rotation.from_rotvec([0.0, 0.0, np.pi])
    q = r[:, 4:8].copy()
    q[60] = q[59]
    r[60:, 4:8] = (half * Rotation.from_quat(q[60:])).as_quat()
    return r


def _one_sample_off(k, metres):
    def f():
        r = rows()
        r[k, 1:4] += metres * np.array([0.6, 0.0, 0.8])
        return r

    return f


def _rows_in_mm(a, b):
    """Rows a … b − 1 in millimetres inside a file in metres (a recorder switching units for a moment)."""

    def f():
        r = rows()
        r[a:b, 1:4] *= 1000.0
        return r

    return f


def _rotation_flip(k, degrees=179.95):
    """Row k's rotation turned by ``degrees`` about x (one frame, 10 ms, then back): below the π the
    step check refuses, far beyond the motion's own turning."""
    from scipy.spatial.transform import Rotation

    def f():
        r = rows()
        r[k, 4:8] = (Rotation.from_rotvec([np.radians(degrees), 0.0, 0.0]) * Rotation.from_quat(r[k, 4:8])).as_quat()
        return r

    return f


def _jump_that_stays():
    r = rows()
    r[60:, 1:4] += np.array([5.0, 0.0, 0.0])  # from row 60 on, 5 m away in 10 ms, and it stays
    return r


def _mcap_rows_in_mm(ctx: Ctx):
    traj = B.smooth_motion()
    p = traj.position.copy()
    p[40:50] *= 1000.0
    return ctx.train(B.write_mcap(ctx.inp / "rec.mcap", traj.with_(position=p)))


def _velocities_like_the_clean_files(ctx: Ctx, res):
    """The model learned the motion's velocities (below 3 m/s and rad/s), not the glitch's (10⁵)."""
    m, _ = load_model(ctx.model_out)
    assert np.max(np.abs(m.gp.Y * m.gp.y_scale)) < 3.0


def _wxyz():
    return rows()[:, [0, 1, 2, 3, 7, 4, 5, 6]]


def _first(n):
    return lambda: rows()[:n]


def _non_numeric():
    r = rows().astype(object)
    r[18, 3] = "abc"
    return r


def _extra_field(ctx: Ctx, k: int) -> Path:
    lines = B.write_table(ctx.inp / "demo.csv", rows()).read_text().splitlines()
    lines[line(k) - 1] += ",5.0"
    return text(ctx, "\n".join(lines) + "\n")


def _semicolon_decimal_comma(ctx: Ctx):
    return ctx.train(csv(ctx, rows(), delimiter=";", decimal=","))


def _numbers_only(ctx: Ctx):
    lines = B.write_table(ctx.inp / "demo.csv", rows()).read_text().splitlines()
    return ctx.train(text(ctx, "\n".join(lines[1:]) + "\n"))


def _binary_file(ctx: Ctx) -> Path:
    rng = np.random.default_rng(7)
    return text(ctx, rng.integers(0, 256, 3000, dtype=np.uint8).tobytes())


def _binary(ctx: Ctx):
    return ctx.train(_binary_file(ctx))


def _header(names):
    return tuple(names.split(","))


# ---------------------------------------------------------------------------------------------- vendor builders
def _traj_with_lost(rows_lost):
    tr = B.smooth_motion()
    q = tr.quat.copy()
    q[rows_lost] = np.nan
    return tr.with_(quat=q)


def _qtm_lost(ctx: Ctx):
    return ctx.train(B.write_qtm(ctx.inp / "take_6D.tsv", _traj_with_lost([30, 31, 32])))


def _qtm_truncated(ctx: Ctx):
    p = B.write_qtm(ctx.inp / "take_6D.tsv")
    data = p.read_text()
    lines = data.splitlines()
    cut = len("\n".join(lines[:70])) + 1 + len(lines[70]) // 2  # in the middle of file line 71
    p.write_text(data[:cut])
    return ctx.train(p)


def _motive_lost(ctx: Ctx):
    return ctx.train(B.write_motive(ctx.inp / "take.csv", _traj_with_lost([40, 41, 42])))


def _motive_header_cut(ctx: Ctx):
    p = B.write_motive(ctx.inp / "take.csv")
    p.write_text("\n".join(p.read_text().splitlines()[:4]) + "\n")
    return ctx.train(p)


def _close_to_csv_model(ctx: Ctx, res, drop=()):
    """A vendor file (mm, Euler/matrix columns) converts to the same numbers up to round-off."""
    ctx.ref.mkdir(exist_ok=True)
    ref_file = B.write_table(ctx.ref / "demo.csv", np.delete(rows(), list(drop), axis=0))
    r = run_cli("train", ref_file, "-o", ctx.ref / "model.rbgp", *B.FAST)
    assert r.exit_code == 0, r.stderr
    assert_same_model(ctx.model_out, ctx.ref / "model.rbgp", exact=False)


# ---------------------------------------------------------------------------------------------- MCAP builders
def _mcap(ctx: Ctx, **kw) -> Path:
    return B.write_mcap(ctx.inp / "rec.mcap", **kw)


def _mcap_cut(frac):
    def build(ctx: Ctx):
        p = _mcap(ctx)
        data = p.read_bytes()
        p.write_bytes(data[: int(len(data) * frac)])
        return ctx.train(p)

    return build


def _mcap_corrupt_chunk(which):
    def build(ctx: Ctx):
        p = _mcap(ctx, chunk_size=4096)
        off = B.chunk_data_offsets(p)[which]
        p.write_bytes(B.mutate(p.read_bytes(), flip=[(off + k, 3) for k in range(4, 12)]))
        return ctx.train(p)

    return build


def _mcap_chunk_length(which, value):
    """A chunk record whose data length field (the u64 before the data) is corrupt."""

    def build(ctx: Ctx):
        p = _mcap(ctx, chunk_size=4096)
        off = B.chunk_data_offsets(p)[which]
        data = bytearray(p.read_bytes())
        data[off - 8:off] = int(value).to_bytes(8, "little")
        p.write_bytes(bytes(data))
        return ctx.train(p)

    return build


def _mcap_chunk_index_unknown_channel(ctx: Ctx):
    """The summary's first chunk index names channel 99, which does not exist."""
    p = _mcap(ctx)
    data = bytearray(p.read_bytes())
    off = B.first_chunk_index_channel_offset(bytes(data))
    data[off:off + 2] = (99).to_bytes(2, "little")
    p.write_bytes(bytes(data))
    return ctx.train(p)


def _all_samples_read(ctx: Ctx, res):
    """A damaged index over intact data: the linear scan reads every message."""
    m, header = load_model(ctx.model_out)
    assert header["provenance"]["demonstrations"][0]["samples"] == N
    np.testing.assert_allclose(m.starts[0], np.concatenate([ROWS[0, 4:8], ROWS[0, 1:4]]), atol=1e-15)


def _mcap_bad_schema(ctx: Ctx):
    """A ROS 2 message definition the parser rejects (an upper-case package name)."""
    from tests.io.mcap_fixtures import MSGDEFS, write_raw

    text_ = MSGDEFS["geometry_msgs/msg/PoseStamped"].replace("builtin_interfaces/Time", "builtin_interFaces/Time")
    p = ctx.inp / "rec.mcap"
    write_raw(p, B.TOPIC, "geometry_msgs/msg/PoseStamped", "ros2msg", text_.encode(), "cdr", [b"\0" * 64] * 5)
    return ctx.train(p)


def _recovered_prefix(ctx: Ctx, res):
    """The model learned from exactly the messages before the damage, and says so."""
    import re

    warn = next(ln for ln in res.stderr.splitlines() if "recovered" in ln)
    n = int(re.search(r"recovered (\d+) pose samples", warn).group(1))
    assert 2 < n <= len(ROWS)
    m, header = load_model(ctx.model_out)
    assert header["provenance"]["demonstrations"][0]["samples"] == n
    np.testing.assert_allclose(m.starts[0], np.concatenate([ROWS[0, 4:8], ROWS[0, 1:4]]), atol=1e-15)
    assert m.durations[0] == pytest.approx(ROWS[n - 1, 0], abs=1e-9)


def _later_chunk_recovered(ctx: Ctx, res):
    """Damage in chunk 1: exactly the messages of chunk 0 are kept."""
    _recovered_prefix(ctx, res)
    ctx.ref.mkdir(exist_ok=True)
    clean = B.write_mcap(ctx.ref / "clean.mcap", chunk_size=4096)
    assert f"recovered {B.messages_in_first_chunks(clean, 1)} pose samples" in res.stderr


def _mcap_zero_quats(ctx: Ctx):
    tr = B.smooth_motion()
    return ctx.train(_mcap(ctx, traj=tr.with_(quat=np.zeros_like(tr.quat))))


def _json_tf_matches_csv(ctx: Ctx, res):
    """JSON TF with a JSON schema reads like the CSV (times through integer ns: round-off only)."""
    _close_to_csv_model(ctx, res)


# ---------------------------------------------------------------------------------------------- model builders
def _model_bytes(ctx: Ctx) -> bytes:
    return ctx.model_src.read_bytes()


def _cut_model_file(ctx: Ctx) -> Path:
    p = ctx.inp / "tiny.rbgp"
    p.write_bytes(_model_bytes(ctx)[: len(_model_bytes(ctx)) // 2])
    return p


def _model_cut(ctx: Ctx):
    return ["rollout", _cut_model_file(ctx), "--steps", "5", "-o", ctx.out / "gen.csv"]


def _model_flipped(ctx: Ctx):
    import zipfile

    p = ctx.model()
    with zipfile.ZipFile(p) as z:
        info = z.getinfo("X.npy")
    off = info.header_offset + 30 + len(info.filename) + len(info.extra) + info.compress_size // 2
    p.write_bytes(B.mutate(p.read_bytes(), flip=[(off, 0)]))
    return ["info", p]


def _edited_model_file(ctx: Ctx, edit) -> Path:
    header, arrays = B.read_model_npz(ctx.model_src)
    edit(header, arrays)
    return B.write_model_npz(ctx.inp / "tiny.rbgp", header, arrays)


def _model_header_edit(edit, command="info"):
    def build(ctx: Ctx):
        p = _edited_model_file(ctx, edit)
        if command == "info":
            return ["info", p]
        if command == "predict":
            return ["predict", p, text(ctx, GOOD_POSES, "poses.csv"), "-o", ctx.out / "pred.csv"]
        return ["rollout", p, "--steps", "5", "-o", ctx.out / "gen.csv"]

    return build


def _set(key, value):
    def edit(header, arrays):
        header[key] = value

    return edit


def _set_fit(key, value):
    def edit(header, arrays):
        header["fits"][0][key] = value

    return edit


def _fit_values(**values):
    def edit(header, arrays):
        header["fits"][0]["values"].update(values)

    return edit


def _fit_value(key, value):
    def edit(header, arrays):
        header["fits"][0]["values"][key] = value

    return edit


def _predicts_finite(ctx: Ctx, res):
    """A model with an odd but valid header (an integer hyperparameter) predicts finite numbers."""
    lines = (ctx.out / "pred.csv").read_text().splitlines()
    vals = np.array([[float(v) for v in ln.split(",")] for ln in lines[1:]])
    assert vals.shape == (1, 19) and np.all(np.isfinite(vals))


def _model_zip_field(offset_in_entry: int, value: int):
    """Overwrite a byte of X.npy's central-directory entry (flags: +8, compression method: +10)."""

    def build(ctx: Ctx):
        p = ctx.model()
        data = bytearray(p.read_bytes())
        data[B.zip_central_entry(bytes(data), "X.npy") + offset_in_entry] = value
        p.write_bytes(bytes(data))
        return ["rollout", p, "--steps", "5", "-o", ctx.out / "gen.csv"]

    return build


def _model_tampered_array(ctx: Ctx):
    header, arrays = B.read_model_npz(ctx.model_src)
    arrays["Y"] = arrays["Y"].copy()
    arrays["Y"][-1, 1] += 1e-9
    p = B.write_model_npz(ctx.inp / "tiny.rbgp", header, arrays, checksums=False)
    return ["rollout", p, "--steps", "5", "-o", ctx.out / "gen.csv"]


def _model_not_zip(ctx: Ctx):
    p = csv(ctx, rows(), name="tiny.rbgp")
    return ["rollout", p, "--steps", "5", "-o", ctx.out / "gen.csv"]


def _model_npz_without_header(ctx: Ctx):
    p = ctx.inp / "tiny.rbgp"
    with open(p, "wb") as fh:
        np.savez(fh, X=np.zeros((3, 6)))
    return ["info", p]


def _model_member_header_damaged(command):
    """One compressed member (X.npy) whose .npy header lost its closing parenthesis, with a valid CRC
    (damaged before it was compressed, or a flip the zip's checks cannot see): numpy's header parser
    raised tokenize.TokenError, which is no ValueError."""
    import io
    import zipfile

    def build(ctx: Ctx):
        src = zipfile.ZipFile(io.BytesIO(_model_bytes(ctx)))
        p = ctx.inp / "tiny.rbgp"
        with zipfile.ZipFile(p, "w", compression=zipfile.ZIP_DEFLATED) as out:
            for info in src.infolist():
                data = src.read(info)
                if info.filename == "X.npy":
                    head = data[:128].replace(b"), }", b" , }", 1)
                    assert head != data[:128]
                    data = head + data[128:]
                out.writestr(info.filename, data)
        return [command, p] if command == "info" else [command, p, "-o", ctx.out / "r.csv"]

    return build


def _model_huge_inputs(command):
    """X all 1e300 with every checksum recomputed (a buggy writer): the GP predicts NaN; ``info``
    passed it and ``rollout`` refused it later (issue 40)."""

    def build(ctx: Ctx):
        header, arrays = B.read_model_npz(_model_bytes(ctx))
        arrays["X"] = np.full_like(arrays["X"], 1e300)
        p = B.write_model_npz(ctx.inp / "tiny.rbgp", header, arrays)
        return [command, p] if command == "info" else [command, p, "-o", ctx.out / "r.csv"]

    return build


# ---------------------------------------------------------------------------------------------- huge lines
def _huge_column_name(ctx: Ctx):
    """A 1 MiB column name (plus the rest of the header: over the 1 MiB line limit)."""
    return ctx.train(text(ctx, "t," + "x" * (1 << 20) + ",y,z,qx,qy,qz,qw\n" + "0,1,2,3,0,0,0,1\n"))


def _long_column_name(ctx: Ctx):
    """A 200 KiB column name: under the line limit, over the csv module's field limit (128 Ki)."""
    return ctx.train(text(ctx, "t," + "x" * 200_000 + ",y,z,qx,qy,qz,qw\n" + "0,1,2,3,0,0,0,1\n"))


def _one_line_file(header: bool):
    """3 MiB of numbers without a line break (the issue's 200 MB file, smaller: the same refusal)."""

    def build(ctx: Ctx):
        head = ",".join(B.COLUMNS) + "\n" if header else ""
        return ctx.train(text(ctx, head + "0.125," * 500_000))

    return build


# ---------------------------------------------------------------------------------------------- start poses
def _rollout_start(pose):
    def build(ctx: Ctx):
        return ["rollout", ctx.model(), "--start", pose, "--steps", "5", "-o", ctx.out / "gen.csv"]

    return build


def _rollout_starts(content):
    def build(ctx: Ctx):
        p = text(ctx, content, "starts.csv")
        return ["rollout", ctx.model(), "--starts", p, "--steps", "5", "--output-rate", "0", "-o", ctx.out / "gen.csv"]

    return build


def _rollout_starts_at(position, quat):
    """check: the rollout starts exactly at the given pose (quaternion normalised)."""

    def check(ctx: Ctx, res):
        from rbgp_cli.io.read import read_demonstrations

        (gen,) = read_demonstrations([str(ctx.out / "gen.csv")])
        q = np.asarray(quat, float) / np.linalg.norm(quat)
        np.testing.assert_allclose(gen.position[0], position, atol=1e-15)
        np.testing.assert_allclose(gen.quat[0] * np.sign(gen.quat[0] @ q), q, atol=1e-15)
        assert len(gen) == 6

    return check


STARTS_HEADER = "x,y,z,qx,qy,qz,qw\n"
GOOD_POSES = "rx,ry,rz,x,y,z\n0.1,0.2,0.3,0.3,0.0,1.1\n"
GOOD_START = "0.3,0.1,0.8,0,0,0,1\n"


def _predict(content):
    def build(ctx: Ctx):
        p = text(ctx, content, "poses.csv")
        return ["predict", ctx.model(), p, "-o", ctx.out / "pred.csv"]

    return build


# ---------------------------------------------------------------------------------------------- evaluate
def _demos(ctx: Ctx, n: int = 3) -> Path:
    d = ctx.inp / "demos"
    d.mkdir(exist_ok=True)
    for k in range(n):
        B.write_csv(d / f"demo_{k}.csv", B.smooth_motion(seed=k, name=f"demo_{k}"))
    return d


def _evaluate(gen_rows=None, length=None, gen_text=None):
    def build(ctx: Ctx):
        demos = _demos(ctx)
        args = ["evaluate"]
        if gen_text is not None:
            args.append(text(ctx, gen_text, "gen.csv"))
        elif gen_rows is not None:
            args.append(csv(ctx, gen_rows(), "gen.csv"))
        args += ["--demos", demos, "--per-step", ctx.out / "steps.csv", "--json"]
        if length is not None:
            args += ["--length", str(length)]
        return args

    return build


def _steps_written(length):
    def check(ctx: Ctx, res):
        d = json.loads(res.stdout)
        assert d["steps"] == length and d["n_generated"] == 1 and d["n_demos"] == 3
        assert np.isfinite(d["bhattacharyya"]["mean"])
        assert len((ctx.out / "steps.csv").read_text().splitlines()) == length + 1

    return check


# ---------------------------------------------------------------------------------------------- inspect
def _inspect_json(check_json):
    def check(ctx: Ctx, res):
        check_json(json.loads(res.stdout))

    return check


def _inspect_cut_mcap(ctx: Ctx):
    p = _mcap(ctx)
    data = p.read_bytes()
    p.write_bytes(data[: len(data) // 2])
    return ["inspect", p, "--json"]


def _cut_mcap_described(d):
    """inspect describes what it can and says the file is damaged (it reports, it does not fail)."""
    assert d["format"] == "mcap" and d["description"]["damaged"] and d["error"] is None
    (tr,) = d["trajectories"]
    assert tr["topic"] == B.TOPIC and 2 < tr["samples"] < N and tr["lost_frames"] == 0


def test_inspect_describes_binary_garbage_and_exits_2(tmp_path, tiny_model_path):
    """A file inspect cannot read is described (JSON on stdout) and the exit code is 2 (it was 0)."""
    ctx = Ctx(tmp_path, tiny_model_path)
    ctx.inp.mkdir()
    res = run_cli("inspect", _binary_file(ctx), "--json")
    assert res.exit_code == 2 and "Traceback" not in res.stderr
    assert res.stderr.strip().splitlines() == [f"rbgp: error: 1 of 1 file could not be read: {_binary_file(ctx)}"]
    d = json.loads(res.stdout)
    assert d["trajectories"] == [] and "not a text file" in d["error"]


# ---------------------------------------------------------------------------------------------- the table
N = len(ROWS)

CASES = [
    # --- files that hold nothing usable
    Case("empty_file", lambda c: c.train(text(c, "")), error=("demo.csv", "empty")),
    Case("blank_lines_only", lambda c: c.train(text(c, "\n  \n\t\n")), error=("demo.csv", "empty")),
    Case("header_only", lambda c: c.train(text(c, ",".join(B.COLUMNS) + "\n")),
         error=("demo.csv:1:", "header but no data rows", "export or record it again")),
    Case("binary_garbage", _binary, error=("demo.csv", "not a text file", "MCAP")),
    Case("numbers_without_header", _numbers_only, error=("demo.csv:1:", "no header line", "add a header")),
    # --- delimiters
    Case("pipe_delimiter", train_on(rows, delimiter="|"),
         error=("demo.csv", "single column ('t|x|y|z|qx|qy|qz|qw')", "comma- or tab-separated")),
    Case("utf16_with_bom_tab_separated", lambda c: c.train(text(c, csv(c, rows(), "demo.txt", delimiter="\t")
                                                               .read_text().encode("utf-16"), "demo.txt")),
         check=same_model_as(rows, name="demo.txt")),
    Case("utf8_bom_and_crlf", lambda c: c.train(text(c, b"\xef\xbb\xbf" + csv(c, rows()).read_bytes()
                                                     .replace(b"\n", b"\r\n"))),
         check=same_model_as(rows)),
    Case("semicolon_and_decimal_comma", _semicolon_decimal_comma, check=same_model_as(rows)),
    Case("tab_separated", train_on(rows, "demo.tsv", delimiter="\t"), check=same_model_as(rows)),
    # --- columns
    Case("missing_qw_column", train_on(lambda: rows()[:, :7], header=B.COLUMNS[:7]),
         error=("demo.csv", "column 'qw' not found", "columns are t, x, y, z, qx, qy, qz", "--columns qw=")),
    Case("misspelled_qw_column", train_on(rows, header=_header("t,x,y,z,qx,qy,qz,qww")),
         error=("demo.csv", "columns are t, x, y, z, qx, qy, qz, qww", "did you mean 'qww'", "--columns qw=qww")),
    Case("two_columns_named_x", train_on(rows, header=_header("t,x,x,z,qx,qy,qz,qw")),
         error=("demo.csv", "several columns are named 'x' (columns 2, 3)", "rename or delete all but one")),
    Case("columns_option_names_no_column",
         train_on(rows, header=_header("t,x,y,z,qx,qy,qz,W"), opts=("--columns", "qw=w0")),
         error=("demo.csv", "--columns qw=w0", "no column 'w0'", "columns are t, x, y, z, qx, qy, qz, W")),
    Case("misspelled_x_column", train_on(rows, header=_header("t,xx,y,z,qx,qy,qz,qw")),
         error=("demo.csv", "position column 'x' not found", "did you mean 'xx'", "--columns x=xx")),
    Case("misspelled_time_column", train_on(rows, header=_header("tme,x,y,z,qx,qy,qz,qw")),
         error=("demo.csv", "no time column", "columns are tme, x, y", "did you mean 'tme'", "--columns t=tme")),
    Case("ambiguous_quaternion_order", train_on(rows, header=_header("t,x,y,z,q0,q1,q2,q3")),
         error=("demo.csv", "q0, q1, q2, q3", "--quat-order xyzw", "--quat-order wxyz")),
    Case("quaternion_order_given",
         train_on(_wxyz, header=_header("t,x,y,z,q0,q1,q2,q3"), opts=("--quat-order", "wxyz")),
         check=same_model_as(rows)),
    Case("named_columns_w_first", train_on(_wxyz, header=_header("t,x,y,z,qw,qx,qy,qz")), check=same_model_as(rows)),
    # --- lost frames
    Case("nan_rows", train_on(_nan_rows), warning=("demo.csv", "dropped 3 lost frames"),
         check=same_model_as(_delete([10, 11, 12]))),
    Case("blank_cells", train_on(_blank_cells), warning=("dropped 2 lost frames",),
         check=same_model_as(_delete([40, 41]))),
    Case("null_cells", train_on(_null_cells), warning=("dropped 1 lost frame",), check=same_model_as(_delete([50]))),
    Case("infinite_value", train_on(_inf_cell), warning=("dropped 1 lost frame",), check=same_model_as(_delete([60]))),
    Case("some_all_zero_quaternions", train_on(_zero_quats()), warning=("dropped 3 lost frames",),
         check=same_model_as(_delete([20, 21, 22]))),
    Case("every_quaternion_all_zero", train_on(_zero_quats(slice(None))),
         error=("demo.csv", "at least 2 samples", f"{N} samples have an all-zero quaternion")),
    Case("nan_rows_on_stdin", lambda c: (c.train("-"), csv(c, _nan_rows()).read_bytes()),
         warning=("rbgp: warning: -: ", "dropped 3 lost frames"), check=same_model_as(_delete([10, 11, 12]))),
    Case("demo_column_with_a_one_sample_demo",
         lambda c: c.train(csv(c, _demo_column(), header=("demo",) + B.COLUMNS)),
         error=("demo.csv", "demo#b", "at least 2 samples")),
    # --- quaternions
    Case("quaternion_far_from_unit", train_on(_far_quat),
         error=(f"demo.csv:{line(30)}:", "quaternion norm 3", "far from 1", "--columns")),
    Case("quaternions_slightly_off_unit", train_on(_slightly_off), warning=("normalised quaternions", "0.05"),
         check=same_model_as(rows, exact=False)),
    Case("sign_flips", train_on(_sign_flips), warning=(f"fixed {sign_changes(FLIPPED)} quaternion sign flips",),
         check=same_model_as(rows)),
    Case("step_of_pi", train_on(_step_of_pi),
         error=(f"demo.csv:{line(60)}:", "π or more", "record at a higher rate")),
    # --- time
    # --- tracker glitches (issue 40): repaired as lost frames with the rows named, or refused
    Case("one_sample_1_km_off", train_on(_one_sample_off(50, 1000.0)),
         warning=("demo.csv", "removed 1 sample off the path", f"line {line(50)}"), check=same_model_as(_delete([50]))),
    Case("one_sample_10_cm_off", train_on(_one_sample_off(70, 0.1)),
         warning=("removed 1 sample off the path", f"line {line(70)}"), check=same_model_as(_delete([70]))),
    Case("first_sample_100_m_off", train_on(_one_sample_off(0, 100.0)),
         warning=("removed 1 sample off the path", f"line {line(0)}"), check=same_model_as(_delete([0]))),
    Case("ten_rows_in_millimetres", train_on(_rows_in_mm(40, 50)),
         warning=("demo.csv", "removed 10 samples off the path", f"lines {line(40)}–{line(49)}"),
         check=same_model_as(_delete(list(range(40, 50))))),
    Case("rotation_flip_of_179_95_degrees", train_on(_rotation_flip(80)),
         warning=("removed 1 sample off the path", f"line {line(80)}"), check=same_model_as(_delete([80]))),
    Case("rotation_flip_of_120_degrees", train_on(_rotation_flip(30, 120.0)),
         warning=("removed 1 sample off the path", f"line {line(30)}"), check=same_model_as(_delete([30]))),
    Case("one_sample_off_filled_with_max_gap", train_on(_one_sample_off(50, 1000.0), opts=("--max-gap", "0.05")),
         warning=("removed 1 sample off the path", "filled 1 lost frame"), check=_velocities_like_the_clean_files),
    Case("jump_that_does_not_come_back", train_on(_jump_that_stays),
         error=(f"demo.csv:{line(60)}:", "jumps by 5 m", "does not come back", "--crop-from")),
    Case("mcap_ten_messages_in_millimetres", _mcap_rows_in_mm,
         warning=("rec.mcap", "removed 10 samples off the path", "samples 41–50"), check=_velocities_like_the_clean_files),
    Case("unsorted_times", train_on(_unsorted),
         error=(f"demo.csv:{line(31)}:", "time goes backwards", "sort the rows")),
    Case("duplicate_rows", train_on(_duplicates), warning=("dropped 2 duplicate samples",), check=same_model_as(rows)),
    Case("duplicate_time_other_pose", train_on(_dup_time),
         error=(f"demo.csv:{line(51)}:", "same time as the sample before it", "remove one of them")),
    Case("times_in_ms", train_on(_time_scaled(1e3)), error=("demo.csv", "column 't' has no unit", "--time-unit ms")),
    Case("times_in_ns", train_on(_time_scaled(1e9)), error=("demo.csv", "--time-unit ns")),
    Case("times_in_ms_with_option", train_on(_time_scaled(1e3), opts=("--time-unit", "ms")),
         check=same_model_as(rows, exact=False)),
    Case("times_in_ns_named_column", train_on(_time_scaled(1e9), header=("t_ns",) + B.COLUMNS[1:]),
         check=same_model_as(rows, exact=False)),
    # --- too little data
    Case("one_sample", train_on(_first(1)), error=("demo.csv", "at least 2 samples for a velocity")),
    Case("two_samples_one_velocity", train_on(_first(2)), error=("demo.csv", "0 training pairs", "10 Hz training grid", "3 or more samples", "--train-rate 0")),
    # --- units
    Case("millimetres_assumed_metres", train_on(_length_scaled(1e3)),
         error=("demo.csv", "looks like millimetres", "--length-unit mm")),
    Case("millimetres_with_option", train_on(_length_scaled(1e3), opts=("--length-unit", "mm")),
         check=same_model_as(rows, exact=False)),
    Case("millimetres_in_column_names",
         train_on(_length_scaled(1e3), header=("t", "x_mm", "y_mm", "z_mm") + B.COLUMNS[4:]),
         check=same_model_as(rows, exact=False)),
    # --- malformed rows
    Case("non_numeric_cell", train_on(_non_numeric),
         error=(f"demo.csv:{line(18)}:", "non-numeric value 'abc'", "column 'z'", "leave it empty")),
    Case("extra_field_in_a_row", lambda c: c.train(_extra_field(c, 10)),
         error=(f"demo.csv:{line(10)}:", "9 fields", "delimiter")),
    Case("extra_field_in_first_row", lambda c: c.train(_extra_field(c, 0)),
         error=(f"demo.csv:{line(0)}:", "9 fields", "delimiter")),
    # --- vendor exports
    Case("qtm_lost_frames", _qtm_lost, warning=("take_6D.tsv", "dropped 3 lost frames"),
         check=lambda c, r: _close_to_csv_model(c, r, drop=(30, 31, 32))),
    Case("qtm_truncated_row", _qtm_truncated, error=("take_6D.tsv:", "cells")),
    Case("motive_lost_frames", _motive_lost, warning=("take.csv", "dropped 3 lost frames"),
         check=lambda c, r: _close_to_csv_model(c, r, drop=(40, 41, 42))),
    Case("motive_header_cut_short", _motive_header_cut, error=("take.csv", "Frame,Time")),
    # --- MCAP
    Case("mcap_truncated_inside_magic", lambda c: c.train(text(c, b"\x89MCAP0\r", "rec.mcap")),
         error=("rec.mcap", "truncated or corrupt", "record or copy the file again")),
    Case("mcap_truncated_inside_magic_on_stdin", lambda c: (c.train("-"), b"\x89MCAP0\r"),
         error=("rbgp: error: -: ", "truncated or corrupt")),
    Case("mcap_truncated_in_header", _mcap_cut(0.01), error=("rec.mcap", "truncated or corrupt")),
    Case("mcap_truncated_at_40_percent", _mcap_cut(0.4), warning=("rec.mcap", "truncated or corrupt", "recovered"),
         check=_recovered_prefix),
    Case("mcap_truncated_at_90_percent", _mcap_cut(0.9), warning=("rec.mcap", "truncated or corrupt", "recovered"),
         check=_recovered_prefix),
    Case("mcap_unfinished_recording", lambda c: c.train(_mcap(c, finish=False)),
         warning=("rec.mcap", "recovered"), check=_recovered_prefix),
    Case("mcap_corrupt_first_zstd_chunk", _mcap_corrupt_chunk(0),
         error=("rec.mcap", "truncated or corrupt", "no pose message could be read", "record it again")),
    Case("mcap_corrupt_later_zstd_chunk", _mcap_corrupt_chunk(1), warning=("rec.mcap", "topic /shoe/pose", "recovered"),
         check=_later_chunk_recovered),
    Case("mcap_chunk_length_max_u64", _mcap_chunk_length(1, 2**64 - 1),
         warning=("rec.mcap", "OverflowError", "recovered"),
         check=_later_chunk_recovered),
    Case("mcap_chunk_length_2_to_40", _mcap_chunk_length(1, 2**40), warning=("rec.mcap", "MemoryError", "recovered"),
         check=_later_chunk_recovered),
    Case("mcap_first_chunk_length_2_to_40", _mcap_chunk_length(0, 2**40),
         error=("rec.mcap", "truncated or corrupt", "no pose message could be read")),
    Case("mcap_summary_names_unknown_channel", _mcap_chunk_index_unknown_channel, check=_all_samples_read),
    Case("mcap_malformed_message_definition", _mcap_bad_schema,
         error=("rec.mcap", "topic /shoe/pose", "cannot parse the schema", "builtin_interFaces")),
    Case("mcap_no_pose_topic", lambda c: c.train(B.write_mcap_strings(c.inp / "rec.mcap")),
         error=("rec.mcap", "no pose topic found", "/chatter (std_msgs/msg/String", "rbgp reads")),
    Case("mcap_misspelled_topic", lambda c: c.train(_mcap(c, extra_strings="/chatter"), opts=("--topic", "/shoe/poze")),
         error=("rec.mcap", "no topic '/shoe/poze'", "did you mean '/shoe/pose'")),
    Case("mcap_topic_without_poses",
         lambda c: c.train(_mcap(c, extra_strings="/chatter"), opts=("--topic", "/chatter")),
         error=("rec.mcap", "/chatter", "hold no pose", "pose topics are: /shoe/pose")),
    Case("mcap_json_tf_under_ros_schema", lambda c: c.train(B.write_mcap_json_tf(c.inp / "rec.mcap")),
         error=("rec.mcap", "topic /tf", "JSON-encoded", "ros2msg")),
    Case("mcap_json_tf_with_json_schema",
         lambda c: c.train(B.write_mcap_json_tf(c.inp / "rec.mcap", schema_encoding="jsonschema")),
         check=_json_tf_matches_csv),
    Case("mcap_tf_misspelled_child_frame",
         lambda c: c.train(B.write_mcap_json_tf(c.inp / "rec.mcap", schema_encoding="jsonschema"),
                           opts=("--frame", "sheo")),
         error=("rec.mcap", "topic /tf", "no transforms to child frame 'sheo'", "did you mean 'shoe'", "--frame")),
    Case("mcap_topic_pattern_matches_nothing",
         lambda c: c.train(_mcap(c, extra_strings="/chatter"), opts=("--topic", "/hand/*")),
         error=("rec.mcap", "no pose topic matches '/hand/*'", "rbgp inspect")),
    Case("mcap_all_zero_quaternions", _mcap_zero_quats, error=("rec.mcap", "all-zero quaternion", "orientation")),
    # --- model files
    Case("model_truncated", _model_cut, error=("tiny.rbgp", "not a readable rbgp model file", "retrain")),
    Case("model_bit_flipped", _model_flipped, error=("tiny.rbgp", "not a readable rbgp model file")),
    Case("model_array_changed", _model_tampered_array,
         error=("tiny.rbgp", "checksum mismatch in array 'Y'", "corrupted")),
    Case("model_future_version", _model_header_edit(_set("version", 99), "rollout"),
         error=("tiny.rbgp", "version 99 is newer", "upgrade rbgp")),
    Case("model_other_format", _model_header_edit(_set("format", "something-else")),
         error=("tiny.rbgp", "not an rbgp model file")),
    Case("model_marked_encrypted", _model_zip_field(8, 0x01), error=("tiny.rbgp", "not a readable rbgp model file")),
    Case("model_unknown_compression", _model_zip_field(10, 99), error=("tiny.rbgp", "not a readable rbgp model file")),
    Case("model_kernel_not_an_object", _model_header_edit(_set("kernel", []), "rollout"),
         error=("tiny.rbgp", "header is inconsistent", "retrain")),
    Case("model_zero_length_scale", _model_header_edit(_fit_value("length_scale", 0.0), "rollout"),
         error=("tiny.rbgp", "length_scale = 0.0 is not a positive finite number")),
    Case("model_infinite_length_scale", _model_header_edit(_fit_value("length_scale", float("inf")), "rollout"),
         error=("tiny.rbgp", "length_scale = inf")),
    Case("model_integer_signal_std",  # σf² of an int above 3e9 overflows int64: numpy made it an object
         _model_header_edit(_fit_values(signal_std=5_000_000_000, noise_std=1e9), "predict"), check=_predicts_finite),
    Case("model_nan_jitter", _model_header_edit(_set_fit("jitter", float("nan")), "predict"),
         error=("tiny.rbgp", "jitter = nan is not a non-negative finite number")),
    Case("model_negative_signal_std", _model_header_edit(_fit_value("signal_std", -1e308), "rollout"),
         error=("tiny.rbgp", "signal_std = -1e+308")),
    Case("model_is_a_csv", _model_not_zip,
         error=("tiny.rbgp", "not an rbgp model file", "zip archives; this one is not", "written by rbgp train")),
    Case("model_empty_file", lambda c: ["info", text(c, b"", "tiny.rbgp")], error=("tiny.rbgp", "model file is empty")),
    Case("model_npz_without_header", _model_npz_without_header, error=("tiny.rbgp", "no header")),
    Case("model_missing", lambda c: ["info", c.inp / "tiny.rbgp"], error=("tiny.rbgp", "not found")),
    Case("model_member_header_damaged_info", _model_member_header_damaged("info"),
         error=("tiny.rbgp", "not a readable rbgp model file", "TokenError")),
    Case("model_member_header_damaged_rollout", _model_member_header_damaged("rollout"),
         error=("tiny.rbgp", "not a readable rbgp model file")),
    Case("model_inputs_all_1e300_info", _model_huge_inputs("info"),
         error=("tiny.rbgp", "predicts non-finite velocities at its own training inputs")),
    Case("model_inputs_all_1e300_rollout", _model_huge_inputs("rollout"),
         error=("tiny.rbgp", "predicts non-finite velocities at its own training inputs")),
    # --- huge lines (issue 40): refused after reading 1 MiB, one line
    Case("column_name_of_1_mib", _huge_column_name, error=("demo.csv", "line 1 is", "longer than the 1 MiB")),
    Case("column_name_over_the_csv_field_limit", _long_column_name,
         error=("demo.csv:1:", "a cell longer than 131072 characters")),
    Case("one_line_of_3_mib_with_header", _one_line_file(True), error=("demo.csv", "line 2 is more than", "1 MiB")),
    Case("one_line_of_3_mib_without_header", _one_line_file(False), error=("demo.csv", "line 1 is more than", "1 MiB")),
    Case("one_line_of_3_mib_on_stdin", lambda c: (c.train("-"), b"0.125," * 500_000),
         error=("-: line 1 is more than", "1 MiB")),
    Case("predict_with_truncated_model",
         lambda c: ["predict", _cut_model_file(c), text(c, GOOD_POSES, "poses.csv"), "-o", c.out / "pred.csv"],
         error=("tiny.rbgp", "not a readable rbgp model file")),
    Case("evaluate_with_future_model",
         lambda c: ["evaluate", "--model", _edited_model_file(c, _set("version", 99)), "--demos", _demos(c),
                    "--count", "3", "--per-step", c.out / "steps.csv"],
         error=("tiny.rbgp", "version 99 is newer", "upgrade rbgp")),
    # --- start poses
    Case("start_pose_three_numbers", _rollout_start("1 2 3"), error=("start pose '1 2 3'", "rx ry rz x y z")),
    Case("start_pose_nan", _rollout_start("nan 0 0 0.3 0 0.8"), error=("start pose", "finite")),
    Case("start_pose_text", _rollout_start("a b c d e f"), error=("start pose", "six numbers")),
    Case("starts_file_nan_row", _rollout_starts(STARTS_HEADER + GOOD_START + "0.3,nan,0.8,0,0,0,1\n"),
         error=("starts.csv:3:", "pose 2", "not a finite number")),
    Case("starts_file_zero_quaternion", _rollout_starts(STARTS_HEADER + GOOD_START + "0.3,0.1,0.8,0,0,0,0\n"),
         error=("starts.csv:3:", "pose 2", "all-zero quaternion")),
    Case("starts_file_quaternion_far_from_unit", _rollout_starts(STARTS_HEADER + "0.3,0.1,0.8,0,0,0,3\n"),
         error=("starts.csv:2:", "pose 1", "norm 3", "--quat-order")),
    Case("starts_file_blank_line_before_bad_row",
         _rollout_starts(STARTS_HEADER + GOOD_START + "\n# a comment\n" + GOOD_START + "0.3,0.1,,0,0,0,1\n"),
         error=("starts.csv:6:", "pose 3")),
    Case("predict_poses_nan_row", _predict("rx,ry,rz,x,y,z\n0.1,0.2,0.3,0.3,0.0,1.1\n0.1,nan,0.3,0.3,0.0,1.1\n"),
         error=("poses.csv:3:", "pose 2")),
    Case("starts_file_quaternion_slightly_off_unit", _rollout_starts(STARTS_HEADER + "0.3,0.1,0.8,0,0,0.6,0.84\n"),
         check=_rollout_starts_at([0.3, 0.1, 0.8], [0, 0, 0.6, 0.84])),
    Case("starts_file_header_only", _rollout_starts(STARTS_HEADER),
         error=("starts.csv:1:", "no data rows", "export or record it again")),
    Case("starts_file_binary", _rollout_starts(b"\x00\x01\x02" * 50), error=("starts.csv", "not a text file")),
    # --- inspect describes damage instead of failing
    Case("inspect_truncated_mcap", _inspect_cut_mcap, check=_inspect_json(_cut_mcap_described)),
    # --- evaluate
    Case("evaluate_no_generated", _evaluate(), error=("no generated trajectories", "--model")),
    Case("evaluate_generated_header_only", _evaluate(gen_text=",".join(B.COLUMNS) + "\n"),
         error=("gen.csv:1:", "no data rows")),
    Case("evaluate_generated_one_sample", _evaluate(gen_rows=_first(1)), error=("gen.csv", "at least 2 samples")),
    Case("evaluate_length_far_beyond_demos", _evaluate(gen_rows=rows, length=10 * N),
         error=("4x the longest demonstration", f"at most {4 * N}")),
    Case("evaluate_demos_shorter_than_length", _evaluate(gen_rows=rows, length=2 * N),
         warning=(f"length {2 * N} exceeds the longest demonstration ({N} samples)", "upsampled"),
         check=_steps_written(2 * N)),
]


def _ids():
    names = [c.name for c in CASES]
    assert len(names) == len(set(names)), "case names must be unique"
    return names


@pytest.mark.parametrize("case", CASES, ids=_ids())
def test_hostile_input(case: Case, tmp_path, tiny_model_path):
    ctx = Ctx(tmp_path, tiny_model_path)
    for d in (ctx.inp, ctx.out):
        d.mkdir()
    built = case.build(ctx)
    args, stdin = built if isinstance(built, tuple) else (built, None)  # (args, bytes for '-')
    res = run_cli(*args, input=stdin)
    lines = res.stderr.splitlines()
    assert "Traceback" not in res.stderr and "internal error" not in res.stderr, res.stderr
    assert all(ln.startswith(("rbgp: error: ", "rbgp: warning: ")) for ln in lines), res.stderr
    errors = [ln for ln in lines if ln.startswith("rbgp: error: ")]
    warnings = [ln for ln in lines if ln.startswith("rbgp: warning: ")]
    if case.error:
        assert res.exit_code == 2, (res.exit_code, res.stderr)
        assert len(errors) == 1 and lines[-1] == errors[0], res.stderr
        for frag in case.error:
            assert frag in errors[0], (frag, errors[0])
        assert res.stdout == ""
        assert list(ctx.out.iterdir()) == [], "an output (or temporary) file was left behind"
    else:
        assert res.exit_code == 0, res.stderr
        assert not errors
        for frag in case.warning:
            assert any(frag in w for w in warnings), (frag, res.stderr)
        if not case.warning:
            assert not warnings, res.stderr
        if case.check is not None:
            case.check(ctx, res)
        leftovers = [p.name for p in ctx.out.iterdir() if p.name.startswith(".") or p.name.endswith(".tmp")]
        assert leftovers == []


def test_the_table_is_big_enough():
    assert len(CASES) >= 40
    assert sum(1 for c in CASES if c.error) >= 20 and sum(1 for c in CASES if not c.error) >= 10


@pytest.mark.slow
def test_mcap_truncated_at_many_offsets_through_the_cli(tmp_path):
    """``rbgp train`` on a recording cut at 30 offsets from the magic bytes to the footer: each run
    learns from exactly the samples before the cut and says how many, or exits 2 with one line and
    writes nothing (test_fuzz.py cuts at every 13th byte at the library level)."""
    import re

    data = B.write_mcap(tmp_path / "full.mcap").read_bytes()
    cuts = sorted({*np.linspace(0, len(data) - 1, 28).astype(int).tolist(), 3, 9, len(data) - 30})
    seen = set()
    for k, cut in enumerate(cuts):
        src = tmp_path / f"cut{k}.mcap"
        src.write_bytes(data[:cut])
        out = tmp_path / f"out{k}"
        out.mkdir()
        res = run_cli("train", src, "-o", out / "m.rbgp", *B.FAST, "--json")
        lines = res.stderr.splitlines()
        assert "Traceback" not in res.stderr and "internal error" not in res.stderr, (cut, res.stderr)
        if res.exit_code == 2:
            errors = [ln for ln in lines if ln.startswith("rbgp: error: ")]
            assert errors == lines[-1:] and str(src) in errors[0], (cut, res.stderr)
            assert all(ln.startswith("rbgp: warning: ") for ln in lines[:-1]), (cut, res.stderr)
            assert list(out.iterdir()) == [] and res.stdout == ""
            seen.add("exit 2")
            continue
        assert res.exit_code == 0, (cut, res.stderr)
        _, header = load_model(out / "m.rbgp")
        n = header["provenance"]["demonstrations"][0]["samples"]
        if cut < len(data) - 30:  # the last cuts only lose the summary: every sample is there
            assert re.search(rf"recovered {n} pose samples", res.stderr), (cut, res.stderr)
        m, _ = load_model(out / "m.rbgp")
        np.testing.assert_allclose(m.durations[0], ROWS[n - 1, 0], atol=1e-9)
        seen.add("recovered")
    assert seen == {"exit 2", "recovered"}


def test_predict_poses_on_stdin_are_checked_like_a_file(tiny_model):
    poses = b"rx,ry,rz,x,y,z\n0.1,0.2,0.3,0.3,0.0,1.1\n0.1,nan,0.3,0.3,0.0,1.1\n"
    res = run_cli("predict", tiny_model, "-", input=poses)
    assert res.exit_code == 2 and res.stderr.startswith("rbgp: error: -:3: pose 2"), res.stderr
