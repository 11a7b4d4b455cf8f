"""rbgp rollout -o x.mcap: the same generated motions as the CSV, read by the mcap library's ROS 2
decoder, scored by rbgp evaluate exactly as the CSV is."""

from __future__ import annotations

import json

import numpy as np
import pytest

from rbgp_cli.io import csv as csv_reader
from rbgp_cli.io.mcap_out import rollout_topic
from tests.cli.common import CSV_DIR, run

ARGS = ("--count", "3", "--samples", "2", "--seed", "4")


@pytest.fixture(scope="module")
def outputs(model, tmp_path_factory):
    d = tmp_path_factory.mktemp("rollout_mcap")
    for name in ("g.csv", "g.mcap", "bag/"):
        res = run("rollout", model, *ARGS, "-o", d / name if name != "bag/" else f"{d}/bag/", "-q")
        assert res.exit_code == 0, res.stderr
    return d


def _decode(path):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    out: dict = {}
    with open(path, "rb") as fh:
        for _, channel, message, msg in make_reader(fh, validate_crcs=True, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
            out.setdefault(channel.topic, []).append((message.log_time, msg))
    return out


@pytest.mark.slow
def test_every_pose_equals_the_csvs(outputs):
    csv = csv_reader.read(outputs / "g.csv")
    got = _decode(outputs / "g.mcap")
    assert len(csv) == 3 * 3  # 3 mean rollouts and 2 samples each
    assert set(got) == {rollout_topic(tr.info["demo"]) for tr in csv} | {f"/rbgp/rollout_{b}/band" for b in range(3)}
    for tr in csv:
        rows = got[rollout_topic(tr.info["demo"])]
        pose = np.array([[m.pose.position.x, m.pose.position.y, m.pose.position.z, m.pose.orientation.x,
                          m.pose.orientation.y, m.pose.orientation.z, m.pose.orientation.w] for _, m in rows])
        np.testing.assert_allclose(pose[:, :3], tr.position, atol=1e-9, rtol=0)
        np.testing.assert_allclose(pose[:, 3:], tr.quat, atol=1e-9, rtol=0)
        t = np.array([m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec for _, m in rows])
        np.testing.assert_allclose(t, tr.t, atol=1e-9, rtol=0)  # --start-time 0: the stamps are t
        np.testing.assert_array_equal([lt for lt, _ in rows], np.round(tr.t * 1e9).astype(np.int64))
        assert {m.header.frame_id for _, m in rows} == {"world"}  # CSV demonstrations name no frame
    # the band's pose is the mean rollout's; its covariance is symmetric and positive semi-definite
    band = got["/rbgp/rollout_0/band"]
    cov = np.array([m.pose.covariance for _, m in band]).reshape(-1, 6, 6)
    np.testing.assert_allclose(cov, cov.transpose(0, 2, 1), atol=1e-15)
    assert np.all(np.linalg.eigvalsh(cov) > -1e-12) and np.any(cov[:, 0, 0] > 0)
    np.testing.assert_array_equal([m.pose.pose.position.x for _, m in band], csv[0].position[:, 0])


@pytest.mark.slow
@pytest.mark.parametrize("generated", ["g.mcap", "bag"])
def test_evaluate_scores_the_mcap_as_the_csv(outputs, generated):
    ref = run("evaluate", outputs / "g.csv", "--demos", CSV_DIR, "--json", "-q")
    got = run("evaluate", outputs / generated, "--demos", CSV_DIR, "--json", "-q")
    assert ref.exit_code == 0 and got.exit_code == 0, got.stderr
    a, b = json.loads(ref.stdout), json.loads(got.stdout)
    assert b["n_generated"] == a["n_generated"] == 9 and b["steps"] == a["steps"]
    for key, value in a["bhattacharyya"].items():  # times differ by < 0.5 ns (integer nanoseconds)
        assert b["bhattacharyya"][key] == pytest.approx(value, rel=1e-9, abs=1e-12), key
    assert b["left_data"]["count"] == a["left_data"]["count"]
    assert "skipped" not in got.stderr  # a bag folder's metadata.yaml is its index, not a file to note


def test_evaluate_reads_rollouts_mcap_on_stdin_as_the_file(outputs):
    """Piped (a real pipe: no seeking, no summary first) or redirected, rbgp's own MCAP needs no --topic."""
    import subprocess
    import sys

    ref = run("evaluate", outputs / "g.mcap", "--demos", CSV_DIR, "--json", "-q")
    assert ref.exit_code == 0, ref.stderr
    redirected = run("evaluate", "-", "--demos", CSV_DIR, "--json", "-q", input=(outputs / "g.mcap").read_bytes())
    piped = subprocess.run(f"cat {outputs / 'g.mcap'} | {sys.executable} -m rbgp_cli evaluate - --demos {CSV_DIR} --json -q",
                           shell=True, capture_output=True, text=True, timeout=300)
    for out, err, code in ((redirected.stdout, redirected.stderr, redirected.exit_code),
                           (piped.stdout, piped.stderr, piped.returncode)):
        assert code == 0, err
        a, b = json.loads(ref.stdout), json.loads(out)
        assert b["n_generated"] == a["n_generated"] == 9 and b["bhattacharyya"] == a["bhattacharyya"]


@pytest.mark.slow
def test_options_frame_start_time_foxglove_and_stdout(model, tmp_path):
    res = run("rollout", model, "--count", "1", "--frame-id", "lab", "--start-time", "1700000000.5",
              "--output-format", "mcap", "-o", tmp_path / "g.bin", "-q")
    assert res.exit_code == 0, res.stderr
    rows = _decode(tmp_path / "g.bin")["/rbgp/rollout_0"]
    assert rows[0][0] == 1_700_000_000_500_000_000 and rows[0][1].header.frame_id == "lab"
    assert rows[0][1].header.stamp.sec == 1_700_000_000 and rows[0][1].header.stamp.nanosec == 500_000_000
    res = run("rollout", model, "--count", "1", "--mcap-encoding", "foxglove", "-o", tmp_path / "f.mcap", "-q")
    assert res.exit_code == 0, res.stderr
    from mcap.reader import make_reader

    with open(tmp_path / "f.mcap", "rb") as fh:
        assert {s.name for s in make_reader(fh).get_summary().schemas.values()} == {"foxglove.PoseInFrame"}
    res = run("rollout", model, "--count", "1", "--output-format", "mcap", "-q")
    assert res.exit_code == 0 and res.stdout_bytes.startswith(b"\x89MCAP0\r\n")


@pytest.mark.parametrize("args, message", [
    (["--output-format", "parquet"], "--output-format must be csv or mcap"),
    (["--mcap-encoding", "ros1", "-o", "x.mcap"], "--mcap-encoding must be one of ros2, foxglove"),
    (["--mcap-encoding", "foxglove", "-o", "bag/"], "a rosbag2 folder holds ROS 2 messages"),
    (["--output-format", "csv", "-o", "bag/"], "a CSV needs a file name"),
    (["--start-time", "-1", "-o", "x.mcap"], "--start-time must be seconds since the epoch from 0"),  # log times unsigned
    (["--start-time", "1e308", "-o", "x.mcap"], "--start-time must be seconds since the epoch from 0"),
])
def test_bad_output_choices_are_one_line_errors(model, tmp_path, monkeypatch, args, message):
    monkeypatch.chdir(tmp_path)
    res = run("rollout", model, "--count", "1", *args)
    assert res.exit_code == 2 and message in res.stderr and len(res.stderr.strip().splitlines()) <= 2
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
def test_mcap_to_a_real_pipe(model):
    """stdout as a pipe cannot seek, which the mcap writer does: the file is built in memory first."""
    import io
    import subprocess
    import sys

    from mcap.reader import make_reader

    out = subprocess.run([sys.executable, "-m", "rbgp_cli", "rollout", str(model), "--count", "2",
                          "--output-format", "mcap", "-q"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, timeout=300)
    assert out.returncode == 0, out.stderr.decode()
    summary = make_reader(io.BytesIO(out.stdout), validate_crcs=True).get_summary()
    assert sorted(c.topic for c in summary.channels.values()) == ["/rbgp/rollout_0", "/rbgp/rollout_1"]
