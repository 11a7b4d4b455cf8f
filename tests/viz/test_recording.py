"""Rerun recordings, read back with rerun.chunk.RrdReader: entity paths, row counts, values, time lines,
blueprints, completeness and atomic writing; and that no command loads rerun or matplotlib unasked."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
import warnings
from pathlib import Path

import numpy as np
import pytest

from rbgp_cli.dynamics.model import train_model
from rbgp_cli.errors import InputError
from rbgp_cli.evaluation import evaluate, resample_all
from rbgp_cli.viz.recording import FEATURE_NAMES, record_evaluation, record_rollout, record_training

from . import OUTPUTS, synth_demos, synth_rollout, synth_trajectory

rr = pytest.importorskip("rerun")
REPO = Path(__file__).resolve().parents[2]


# ---------------------------------------------------------------------------------------------
# Reading back
# ---------------------------------------------------------------------------------------------


class Rrd:
    """The chunks of an .rrd by entity path; reading warns -> error (a missing footer is a failure)."""

    def __init__(self, path):
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            self.reader = rr.chunk.RrdReader(str(path))
            self.chunks = self.reader.stream().to_chunks()
            self.reader.store()  # only a complete file (with footer/manifest) supports this
        self.by_entity: dict[str, list] = {}
        for c in self.chunks:
            self.by_entity.setdefault(c.entity_path, []).append(c)

    def entities(self) -> set[str]:
        return set(self.by_entity)

    def static(self, entity: str, column: str):
        """The value of a static component (the latest static row)."""
        rows = [c for c in self.by_entity[entity] if c.is_static and column in c.to_record_batch().schema.names]
        assert rows, f"no static {column} at {entity}"
        return rows[-1].to_record_batch().column(column).to_pylist()[-1]

    def temporal(self, entity: str, timeline: str) -> dict:
        """All temporal rows of an entity sorted by ``timeline``: {column: list}, and the chunks' time lines."""
        chunks = [c for c in self.by_entity[entity] if not c.is_static]
        assert chunks, f"no temporal data at {entity}"
        out: dict[str, list] = {}
        for c in chunks:
            assert list(c.timeline_names) == [timeline], (entity, c.timeline_names)
            rb = c.to_record_batch()
            for name in rb.schema.names:
                if "RowId" not in name:
                    out.setdefault(name, []).extend(rb.column(name).to_pylist())
            out.setdefault("_type", []).append(str(rb.schema.field(timeline).type))
        order = np.argsort(np.array([_num(v) for v in out[timeline]]), kind="stable")
        return {k: ([v[i] for i in order] if k != "_type" else v) for k, v in out.items()}

    def views(self) -> tuple[dict[str, str], list[str]]:
        """The default blueprint: ({view origin: view class}, [time panel's time line])."""
        (bp,) = self.reader.blueprints()
        views, timelines = {}, []
        for c in self.reader.stream(store=bp).to_chunks():
            cols = {n: c.to_record_batch().column(n).to_pylist() for n in c.to_record_batch().schema.names}
            if "ViewBlueprint:space_origin" in cols:
                views[cols["ViewBlueprint:space_origin"][-1][0]] = cols["ViewBlueprint:class_identifier"][-1][0]
            timelines += [row[0] for row in cols.get("TimePanelBlueprint:timeline", [])]
        return views, timelines

    def assert_blueprint(self, timeline: str, series_origins: set[str]) -> None:
        """A 3D view of /world, the expected time-series views, each showing data that exists."""
        views, timelines = self.views()
        assert views.pop("/world") == "3D"
        assert set(views.values()) == {"TimeSeries"}
        assert set(views) == series_origins
        for origin in views:
            assert any(e == origin or e.startswith(origin + "/") for e in self.entities()), origin
        assert timelines == [timeline]

    def num_rows(self, entity: str) -> int:
        return sum(c.num_rows for c in self.by_entity[entity] if not c.is_static)


def _num(v):
    """A time-line value as a number (Timedelta -> ns)."""
    return v.value if hasattr(v, "value") else v


def seconds(values) -> np.ndarray:
    return np.array([_num(v) for v in values], dtype=np.float64) / 1e9


def vec(values, k: int) -> np.ndarray:
    """A list of one-element batches of k-vectors -> (N, k)."""
    return np.array([row[0] if isinstance(row[0], (list, tuple)) else row for row in values], dtype=np.float64).reshape(-1, k)


def assert_f32_equal(actual, expected):
    """Values stored as float32: equal to ~1e-6 relative."""
    np.testing.assert_allclose(actual, expected, rtol=2e-6, atol=1e-7)


def esc(name: str) -> str:
    return rr.escape_entity_path_part(name)


# ---------------------------------------------------------------------------------------------
# Fixtures
# ---------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def demos():
    return synth_demos()


@pytest.fixture(scope="module")
def tiny_model(demos):
    return train_model(demos, restarts=1, max_points=60, shared=True, seed=0)


@pytest.fixture(scope="module")
def rollout_res():
    return synth_rollout(B=3, steps=24, K=2)


@pytest.fixture(scope="module")
def rollout_file(tmp_path_factory, rollout_res):
    path = tmp_path_factory.mktemp("rollout") / "rollout.rrd"
    record_rollout(path, rollout_res)
    return path


@pytest.fixture(scope="module")
def generated():
    return [synth_trajectory(b + 0.3, 30 + 2 * b, noise=0.002, seed=b) for b in range(4)]


# ---------------------------------------------------------------------------------------------
# record_rollout
# ---------------------------------------------------------------------------------------------


def test_rollout_entities_rows_and_file_metadata(rollout_file, rollout_res):
    rrd = Rrd(rollout_file)
    B, n = rollout_res.quat.shape[:2]
    expected = {"/world"} | {f"/world/rollouts/{b}/{part}" for b in range(B) for part in ("path", "body", "samples")}
    expected |= {f"/metrics/std/{o}" for o in OUTPUTS} | {f"/metrics/position/{a}" for a in "xyz"}
    assert expected <= rrd.entities()
    for b in range(B):
        assert rrd.num_rows(f"/world/rollouts/{b}/body") == n
    for o in OUTPUTS:
        assert rrd.num_rows(f"/metrics/std/{o}") == n
    assert [s.application_id for s in rrd.reader.recordings()] == ["rbgp"]
    rrd.assert_blueprint("time", {f"/metrics/std/{o}" for o in OUTPUTS} | {f"/metrics/position/{a}" for a in "xyz"})
    assert rrd.static("/__properties/rbgp", "trajectories") == [B]
    assert rrd.static("/world", "ViewCoordinates:xyz") == [[3, 5, 1]]  # right, forward, up: z up by default
    # nothing but the recording is left beside it
    assert os.listdir(rollout_file.parent) == [rollout_file.name]


def test_rollout_poses_equal_the_trajectories_on_a_time_line_in_seconds(rollout_file, rollout_res):
    rrd = Rrd(rollout_file)
    for b in range(rollout_res.count):
        rows = rrd.temporal(f"/world/rollouts/{b}/body", "time")
        assert set(rows["_type"]) == {"duration[ns]"}
        np.testing.assert_allclose(seconds(rows["time"]), rollout_res.t, atol=1e-9)
        assert_f32_equal(vec(rows["Transform3D:translation"], 3), rollout_res.position[b])
        assert_f32_equal(vec(rows["Transform3D:quaternion"], 4), rollout_res.quat[b])  # x, y, z, w as given
        assert rrd.static(f"/world/rollouts/{b}/body", "TransformAxes3D:axis_length")[0] > 0
        strip = rrd.static(f"/world/rollouts/{b}/path", "LineStrips3D:strips")
        assert len(strip) == 1
        assert_f32_equal(np.array(strip[0]), rollout_res.position[b])
    # trajectory 0 turns through θ = π: its quaternion's w changes sign and is still stored as given
    assert np.min(rollout_res.quat[0, :, 3]) < 0 < np.max(rollout_res.quat[0, :, 3])


def test_rollout_std_series_are_named_and_equal_the_std(rollout_file, rollout_res):
    rrd = Rrd(rollout_file)
    B = rollout_res.count
    for j, o in enumerate(OUTPUTS):
        rows = rrd.temporal(f"/metrics/std/{o}", "time")
        np.testing.assert_allclose(seconds(rows["time"]), rollout_res.t, atol=1e-9)
        values = np.array(rows["Scalars:scalars"])  # (S+1, B), float64
        np.testing.assert_allclose(values, rollout_res.std[:, :, j].T, rtol=1e-12)
        assert rrd.static(f"/metrics/std/{o}", "SeriesLines:names") == [str(b) for b in range(B)]
    pos_x = np.array(rrd.temporal("/metrics/position/x", "time")["Scalars:scalars"])
    np.testing.assert_allclose(pos_x, rollout_res.position[:, :, 0].T, rtol=1e-12)


def test_rollout_samples_are_dimmed_strips(rollout_file, rollout_res):
    rrd = Rrd(rollout_file)
    K = rollout_res.sample_position.shape[1]
    for b in range(rollout_res.count):
        strips = rrd.static(f"/world/rollouts/{b}/samples", "LineStrips3D:strips")
        assert len(strips) == K
        assert_f32_equal(np.array(strips), rollout_res.sample_position[b])
        (rgba,) = rrd.static(f"/world/rollouts/{b}/samples", "LineStrips3D:colors")
        (mean_rgba,) = rrd.static(f"/world/rollouts/{b}/path", "LineStrips3D:colors")
        assert rgba & 0xFF < 255 and mean_rgba & 0xFF == 255  # samples translucent, mean opaque
        r, g, bl = (rgba >> 24) & 0xFF, (rgba >> 16) & 0xFF, (rgba >> 8) & 0xFF
        assert r == g == bl  # grey


def test_rollout_without_std_or_samples(tmp_path):
    res = synth_rollout(B=2, steps=10, K=0, with_std=False)
    path = tmp_path / "plain.rrd"
    record_rollout(path, res, up="y")
    rrd = Rrd(path)
    assert not any(e.startswith("/metrics/std") or e.endswith("/samples") for e in rrd.entities())
    assert rrd.num_rows("/world/rollouts/1/body") == 11
    assert rrd.num_rows("/metrics/position/z") == 11
    rrd.assert_blueprint("time", {f"/metrics/position/{a}" for a in "xyz"})


def test_up_axis_selects_the_view_coordinates(tmp_path):
    res = synth_rollout(B=1, steps=4, K=0, with_std=False)
    got = {}
    for up in ("z", "y"):
        record_rollout(tmp_path / f"{up}.rrd", res, up=up)
        got[up] = Rrd(tmp_path / f"{up}.rrd").static("/world", "ViewCoordinates:xyz")
    d = rr.components.ViewCoordinates.ViewDir
    right, up_, forward, back = d.Right.value, d.Up.value, d.Forward.value, d.Back.value
    assert got["z"] == [[right, forward, up_]]  # RIGHT_HAND_Z_UP: x right, y forward, z up
    assert got["y"] == [[right, up_, back]]  # RIGHT_HAND_Y_UP: x right, y up, z back
    with pytest.raises(InputError, match="up must be z or y"):
        record_rollout(tmp_path / "x.rrd", res, up="x")
    assert not (tmp_path / "x.rrd").exists()


# ---------------------------------------------------------------------------------------------
# record_training
# ---------------------------------------------------------------------------------------------


def test_training_recording_demos_points_and_arrows(tmp_path, demos, tiny_model):
    path = tmp_path / "train.rrd"
    record_training(path, demos, tiny_model)
    rrd = Rrd(path)
    names = ["trial 1", "file.csv#a/b", "demo_2"]  # unnamed -> demo_<index>
    for tr, name in zip(demos, names):
        base = f"/world/demos/{esc(name)}"
        assert {f"{base}/path", f"{base}/body"} <= rrd.entities()
        assert rrd.num_rows(f"{base}/body") == len(tr)
        rows = rrd.temporal(f"{base}/body", "time")
        np.testing.assert_allclose(seconds(rows["time"]), tr.t - tr.t[0], atol=1e-9)
        assert_f32_equal(vec(rows["Transform3D:translation"], 3), tr.position)
        assert_f32_equal(vec(rows["Transform3D:quaternion"], 4), tr.quat)
        assert_f32_equal(np.array(rrd.static(f"{base}/path", "LineStrips3D:strips")[0]), tr.position)
        assert rrd.static(f"{base}/path", "LineStrips3D:labels") == [name]
        z = np.array(rrd.temporal(f"/metrics/position/z/{esc(name)}", "time")["Scalars:scalars"])[:, 0]
        np.testing.assert_allclose(z, tr.position[:, 2], rtol=1e-12)

    rrd.assert_blueprint("time", {f"/metrics/position/{a}" for a in "xyz"})

    _, pos = tiny_model.representation.pose_from_state(tiny_model.gp.X[:, : tiny_model.pose_dims])
    points = np.array(rrd.static("/world/training/points", "Points3D:positions"))
    assert points.shape == (len(tiny_model.gp.X), 3)
    assert_f32_equal(points, pos)
    origins = np.array(rrd.static("/world/training/velocity", "Arrows3D:origins"))
    vectors = np.array(rrd.static("/world/training/velocity", "Arrows3D:vectors"))
    assert_f32_equal(origins, pos)
    scale = rrd.static("/__properties/rbgp", "arrow_seconds")[0]
    assert scale > 0
    # the linear velocity of the training pairs (the GP's targets plus the prior mean), one common scale
    prior = tiny_model.prior_mean(tiny_model.gp.X)
    assert_f32_equal(vectors, (tiny_model.gp.Y + (0 if prior is None else prior))[:, -3:] * scale)
    extent = np.ptp(np.concatenate([tr.position for tr in demos]), axis=0)
    median = np.median(np.linalg.norm(vectors, axis=1))
    assert 0.01 * np.linalg.norm(extent) < median < 0.1 * np.linalg.norm(extent)  # visible, not dominating


# ---------------------------------------------------------------------------------------------
# record_evaluation
# ---------------------------------------------------------------------------------------------


def test_evaluation_recording(tmp_path, demos, generated):
    result = evaluate(generated, demos, length=25)
    path = tmp_path / "eval.rrd"
    record_evaluation(path, result, generated, demos)
    rrd = Rrd(path)
    T = result.steps
    assert {"/metrics/bhattacharyya"} | {f"/metrics/features/{d}" for d in FEATURE_NAMES} <= rrd.entities()
    assert len([e for e in rrd.entities() if e.startswith("/world/demos/") and e.endswith("/path")]) == len(demos)
    assert len([e for e in rrd.entities() if e.startswith("/world/generated/") and e.endswith("/path")]) == len(generated)

    rrd.assert_blueprint("step", {"/metrics/bhattacharyya"} | {f"/metrics/features/{d}" for d in FEATURE_NAMES})

    rows = rrd.temporal("/metrics/bhattacharyya", "step")
    assert rows["_type"] == ["int64"]
    assert rows["step"] == list(range(T))
    values = np.array(rows["Scalars:scalars"])
    np.testing.assert_allclose(values, np.stack([result.per_step, result.per_step_rotation,
                                                 result.per_step_translation], axis=1), rtol=1e-12)
    assert rrd.static("/metrics/bhattacharyya", "SeriesLines:names") == ["total", "rotation", "translation"]
    for j, d in enumerate(FEATURE_NAMES):
        v = np.array(rrd.temporal(f"/metrics/features/{d}", "step")["Scalars:scalars"])
        md, sd, mg, sg = result.demo_mean[:, j], result.demo_std[:, j], result.gen_mean[:, j], result.gen_std[:, j]
        np.testing.assert_allclose(v, np.stack([md, md - 2 * sd, md + 2 * sd, mg, mg - 2 * sg, mg + 2 * sg], 1),
                                   rtol=1e-12, atol=1e-15)

    # the poses on the step time line are the resampled trajectories; the strips the originals
    q_g, p_g = resample_all(generated, T)
    body = rrd.temporal("/world/generated/generated_1/body", "step")
    assert_f32_equal(vec(body["Transform3D:translation"], 3), p_g[1])
    assert_f32_equal(vec(body["Transform3D:quaternion"], 4), q_g[1])
    assert_f32_equal(np.array(rrd.static("/world/generated/generated_1/path", "LineStrips3D:strips")[0]), generated[1].position)
    demo_color = rrd.static(f"/world/demos/{esc('trial 1')}/path", "LineStrips3D:colors")
    gen_color = rrd.static("/world/generated/generated_0/path", "LineStrips3D:colors")
    assert demo_color != gen_color
    assert rrd.static("/__properties/rbgp", "bhattacharyya_mean") == [pytest.approx(result.mean)]


# ---------------------------------------------------------------------------------------------
# Completeness and atomic writing
# ---------------------------------------------------------------------------------------------


def test_a_truncated_or_foreign_file_does_not_read(tmp_path, rollout_file):
    data = rollout_file.read_bytes()
    Rrd(rollout_file)  # the complete file reads without any warning
    for name, content in (("half.rrd", data[: len(data) // 2]), ("tail.rrd", data[:-16]),
                          ("text.rrd", b"t,x,y,z\n0,1,2,3\n")):
        bad = tmp_path / name
        bad.write_bytes(content)
        with pytest.raises((RuntimeError, Warning)):
            Rrd(bad)


def test_failure_leaves_the_destination_untouched(tmp_path):
    res = synth_rollout(B=2, steps=6, K=0)
    res.position = res.position[:, :-1]  # inconsistent: one sample short
    dest = tmp_path / "out.rrd"
    dest.write_bytes(b"previous")
    with pytest.raises(ValueError, match="do not match"):
        record_rollout(dest, res)
    assert dest.read_bytes() == b"previous"
    assert os.listdir(tmp_path) == ["out.rrd"]

    res_ok = synth_rollout(B=2, steps=6, K=0)
    res_ok.std = res_ok.std[:, :, :2]  # fewer std columns than output names: fails while recording
    with pytest.raises(IndexError):
        record_rollout(dest, res_ok)
    assert dest.read_bytes() == b"previous"
    assert os.listdir(tmp_path) == ["out.rrd"]


def test_missing_rerun_is_an_input_error(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "rerun", None)
    monkeypatch.setitem(sys.modules, "rerun.blueprint", None)
    with pytest.raises(InputError, match="rerun needs rerun-sdk") as info:
        record_rollout(tmp_path / "r.rrd", synth_rollout(B=1, steps=3, K=0))
    assert info.value.exit_code == 2
    assert not (tmp_path / "r.rrd").exists()


# ---------------------------------------------------------------------------------------------
# The command line
# ---------------------------------------------------------------------------------------------


def _write_demos_csv(path):
    from rbgp_cli.io.csv import write_trajectories_csv

    write_trajectories_csv([synth_trajectory(i, 40, name=f"d{i}") for i in range(3)], str(path))


TRAIN = ["--restarts", "1", "--max-points", "60", "--share-hyperparameters"]


@pytest.mark.slow
def test_commands_without_flags_import_neither_rerun_nor_matplotlib(tmp_path):
    """--help, train, rollout -o FILE and evaluate run in a fresh interpreter without loading either."""
    _write_demos_csv(tmp_path / "demos.csv")
    script = textwrap.dedent(f"""
        import json, sys
        from typer.testing import CliRunner
        from rbgp_cli.cli.app import app
        d = {str(tmp_path)!r}
        runs = [["--help"], ["train", "--help"], ["rollout", "--help"],
                ["train", d + "/demos.csv", "-o", d + "/m.rbgp"] + {TRAIN!r},
                ["rollout", d + "/m.rbgp", "--count", "2", "--steps", "5", "-o", d + "/out.csv"],
                ["evaluate", d + "/out.csv", "--demos", d + "/demos.csv"]]
        codes = [CliRunner().invoke(app, args).exit_code for args in runs]
        print(json.dumps({{"codes": codes, "loaded": [m for m in ("rerun", "matplotlib") if m in sys.modules]}}))
    """)
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, cwd=tmp_path, timeout=120,
                          env={**os.environ, "PYTHONPATH": str(REPO)})
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert out["codes"] == [0] * 6
    assert out["loaded"] == []
    assert (tmp_path / "out.csv").stat().st_size > 0


@pytest.mark.slow
def test_cli_flags_write_readable_files(tmp_path):
    pytest.importorskip("matplotlib")
    from typer.testing import CliRunner

    from rbgp_cli.cli.app import app

    _write_demos_csv(tmp_path / "demos.csv")
    d = str(tmp_path)
    runner = CliRunner()
    runs = [
        ["train", d + "/demos.csv", "-o", d + "/m.rbgp", "--rerun", d + "/train.rrd", "--up", "y"] + TRAIN,
        ["rollout", d + "/m.rbgp", "--count", "3", "--steps", "8", "--samples", "1", "--output-rate", "0", "-o", d + "/out.csv",
         "--rerun", d + "/rollout.rrd"],
        ["rollout", d + "/m.rbgp", "--count", "3", "--steps", "8", "--seed", "1", "-o", d + "/other.csv"],
        ["evaluate", d + "/out.csv", "--demos", d + "/demos.csv", "--rerun", d + "/eval.rrd",
         "--plot", d + "/eval.png", "--compare", d + "/other.csv"],
    ]
    for args in runs:
        r = runner.invoke(app, args)
        assert r.exit_code == 0, (args, r.output)
    assert Rrd(tmp_path / "train.rrd").num_rows(f"/world/demos/{esc('demos#d0')}/body") == 40
    rollout = Rrd(tmp_path / "rollout.rrd")
    assert rollout.num_rows("/world/rollouts/2/body") == 9
    assert "/world/rollouts/0/samples" in rollout.entities()
    assert Rrd(tmp_path / "eval.rrd").num_rows("/metrics/bhattacharyya") == 40
    assert (tmp_path / "eval.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_rollout_goals_and_via_points_are_drawn_at_their_poses(tmp_path):
    res = synth_rollout(B=2, steps=10, K=0, with_std=False)
    res.goal_quat = res.quat[:, -1].copy()
    res.goal_position = res.position[:, -1].copy()
    res.via = ((0.5, res.quat[0, 5].copy(), res.position[0, 5].copy()),)
    path = tmp_path / "goal.rrd"
    record_rollout(path, res)
    rrd = Rrd(path)
    for b in range(2):
        entity = f"/world/rollouts/{b}/goal"
        assert_f32_equal(np.array(rrd.static(entity, "Transform3D:translation")).reshape(3), res.goal_position[b])
        assert rrd.static(entity, "Points3D:labels") == ["goal"]
    assert_f32_equal(np.array(rrd.static("/world/via/0", "Transform3D:translation")).reshape(3), res.position[0, 5])
    assert rrd.static("/world/via/0", "Points3D:labels") == ["via 0.5 s"]
    plain = tmp_path / "plain.rrd"
    record_rollout(plain, synth_rollout(B=1, steps=4, K=0, with_std=False))
    assert not any(e.endswith("/goal") or e.startswith("/world/via") for e in Rrd(plain).entities())
