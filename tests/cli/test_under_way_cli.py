"""rbgp rollout --given, rbgp follow and rbgp crossval --given (issue 37: a motion under way)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.cli.common import CSV_DIR, REPO, run


def _prefix(src, dst, fraction):
    lines = src.read_text().splitlines()
    n = len(lines) - 1
    dst.write_text("\n".join(lines[: 1 + int(n * fraction)]) + "\n")
    return lines


@pytest.mark.slow
def test_rollout_given_continues_each_file_from_its_last_seen_sample(model, tmp_path):
    first = tmp_path / "a.csv"
    lines = _prefix(CSV_DIR / "shoe_01.csv", first, 0.4)
    _prefix(CSV_DIR / "shoe_02.csv", tmp_path / "b.csv", 0.6)
    out = tmp_path / "rest.csv"
    res = run("--json", "rollout", model, "--given", first, tmp_path / "b.csv", "--samples", 4, "-o", out)
    assert res.exit_code == 0, res.stderr
    summary = json.loads(res.stdout)
    assert [m["trajectory"] for m in summary["motions"]] == ["0", "1"]
    m0 = summary["motions"][0]
    last_seen = float(first.read_text().splitlines()[-1].split(",")[0])
    assert m0["t"] == pytest.approx(last_seen)
    assert 0.0 < m0["phase"] < 1.0 and m0["end_time_band"][0] <= m0["end_time"] <= m0["end_time_band"][1]
    true_end = float(lines[-1].split(",")[0])
    assert abs(m0["end_time"] - true_end) < 0.15 * true_end
    text = out.read_text().splitlines()
    rows = [r.split(",") for r in text if r and not r.startswith("#") and not r.startswith("trajectory")]
    names = {r[0].strip('"') for r in rows}
    assert names == {"0", "1", "0.s0", "0.s1", "0.s2", "0.s3", "1.s0", "1.s1", "1.s2", "1.s3"}
    first_row = next(r for r in rows if r[0].strip('"') == "0")
    assert float(first_row[1]) == pytest.approx(last_seen)  # on the seen file's own clock


@pytest.mark.slow
def test_rollout_given_says_when_a_seen_part_unlike_the_demonstrations_widens_its_bands(model, tmp_path):
    """The first half of shoe_01 as recorded: bands as calibrated (band_widening below 1.5, no warning); the same half
    with a wiggle of 2 cm in y and z that no demonstration has: widened, and stderr says by how much."""
    import math

    lines = _prefix(CSV_DIR / "shoe_01.csv", tmp_path / "plain.csv", 0.5)
    T = float(lines[-1].split(",")[0])
    rows = [lines[0]]
    for line in (tmp_path / "plain.csv").read_text().splitlines()[1:]:
        f = line.split(",")
        t = float(f[0])
        f[2] = repr(float(f[2]) + 0.02 * math.sin(6 * math.pi * t / T))
        f[3] = repr(float(f[3]) + 0.02 * math.sin(4 * math.pi * t / T))
        rows.append(",".join(f))
    (tmp_path / "wiggle.csv").write_text("\n".join(rows) + "\n")
    out = {}
    for name in ("plain", "wiggle"):
        res = run("--json", "rollout", model, "--given", tmp_path / f"{name}.csv", "-o", tmp_path / f"{name}_rest.csv")
        assert res.exit_code == 0, res.stderr
        out[name] = (json.loads(res.stdout)["motions"][0], res.stderr)
    plain, wiggle = out["plain"][0], out["wiggle"][0]
    assert 1.0 <= plain["band_widening"] < 1.5 and "widened" not in out["plain"][1]
    assert wiggle["band_widening"] >= 1.5 and not wiggle["off"]
    assert f"widened ×{wiggle['band_widening']:.2f}" in out["wiggle"][1]
    assert wiggle["end_rotation_band"] > plain["end_rotation_band"]
    # several such motions: one warning with the range and the trajectories, not one line per file
    (tmp_path / "wiggle2.csv").write_text("\n".join(rows) + "\n")
    res = run("rollout", model, "--given", tmp_path / "plain.csv", tmp_path / "wiggle.csv", tmp_path / "wiggle2.csv",
              "-o", tmp_path / "three.csv")
    said = [x for x in res.stderr.splitlines() if "widened" in x]
    assert res.exit_code == 0 and len(said) == 1, res.stderr
    assert "2 of 3 seen motions" in said[0] and "(trajectories 1, 2; band_widening)" in said[0], said


@pytest.mark.slow
def test_rollout_given_marks_and_names_continuations_that_leave_the_demonstrations_envelope(model, tmp_path):
    """Half of shoe_01 as recorded: its continuation and samples stay inside the demonstrations' envelope (left_data
    0 on every row, false in --json, no warning); the same half moved 1 m along x, where no demonstration goes: the
    continuations are extrapolations, every one is marked (left_data 1 from its first row) and one warning names
    them; the Python API gives the same rows."""
    _prefix(CSV_DIR / "shoe_01.csv", tmp_path / "plain.csv", 0.5)
    lines = (tmp_path / "plain.csv").read_text().splitlines()
    moved = [lines[0]] + [",".join([f[0], repr(float(f[1]) + 1.0), *f[2:]]) for f in (x.split(",") for x in lines[1:])]
    (tmp_path / "moved.csv").write_text("\n".join(moved) + "\n")
    out = {}
    for name in ("plain", "moved"):
        res = run("--json", "rollout", model, "--given", tmp_path / f"{name}.csv", "--samples", 3,
                  "-o", tmp_path / f"{name}_rest.csv")
        assert res.exit_code == 0, res.stderr
        rows = [r.split(",") for r in (tmp_path / f"{name}_rest.csv").read_text().splitlines()
                if r and not r.startswith("#")]
        col = rows[0].index("left_data")
        out[name] = (json.loads(res.stdout)["motions"][0], res.stderr, {r[0].strip('"'): [] for r in rows[1:]})
        for r in rows[1:]:
            out[name][2][r[0].strip('"')].append(float(r[col]))
    plain, moved = out["plain"], out["moved"]
    assert plain[0]["left_data"] is False and plain[0]["samples_left_data"] == 0 and "envelope" not in plain[1]
    assert set(plain[2]) == {"0", "0.s0", "0.s1", "0.s2"} and all(v == 0.0 for x in plain[2].values() for v in x)
    assert moved[0]["off"] and moved[0]["left_data"] is True and moved[0]["samples_left_data"] == 3
    assert all(x[0] == 1.0 for x in moved[2].values())
    said = [x for x in moved[1].splitlines() if "envelope" in x]
    assert len(said) == 1 and "4 of 4 continuations" in said[0] and "0.s0 at t = " in said[0], moved[1]
    from rbgp_cli.api import RigidBodyGP

    (cont,) = RigidBodyGP.load(model).predict_rest(str(tmp_path / "moved.csv"), samples=3)
    assert len(cont.info["left_data"]) == 4 and all(rows[0] for rows in cont.info["left_data"])


def test_rollout_given_refuses_start_poses(model, tmp_path):
    res = run("rollout", model, "--given", CSV_DIR / "shoe_01.csv", "--count", 1, "--duration", 2)
    assert res.exit_code == 2
    assert "--given" in res.stderr and len(res.stderr.strip().splitlines()) == 1


@pytest.mark.parametrize("args,named", [
    (["--goal", "0 0 0 1 0.8 0.06 0.13"], "--goal"),
    (["--via", "1: 0 0 0 1 0.8 0.06 0.13"], "--via"),
    (["--output-rate", "50"], "--output-rate"),
    (["--count", "5"], "--count"),
    (["--off-data", "stop"], "--off-data"),
])
def test_rollout_given_refuses_what_it_would_ignore(model, tmp_path, args, named):
    res = run("rollout", model, "--given", CSV_DIR / "shoe_01.csv", *args, "-o", tmp_path / "rest.csv")
    assert res.exit_code == 2, res.stderr
    msg = res.stderr.strip().splitlines()
    assert len(msg) == 1 and "--given" in msg[0] and named in msg[0], res.stderr
    assert "drop it, or drop --given" in msg[0], msg  # one option: "it"
    assert not (tmp_path / "rest.csv").exists()


def test_rollout_given_refuses_an_mcap_output_naming_only_what_was_given(model, tmp_path):
    res = run("rollout", model, "--given", CSV_DIR / "shoe_01.csv", "-o", tmp_path / "rest.mcap")
    assert res.exit_code == 2
    msg = res.stderr.strip().splitlines()
    assert len(msg) == 1 and "an MCAP output" in msg[0] and "--rerun" not in msg[0] and "--plot" not in msg[0], msg


@pytest.mark.slow
def test_follow_reads_a_pipe_and_prints_one_json_line_per_prediction(model, tmp_path):
    lines = (CSV_DIR / "shoe_01.csv").read_text().splitlines()
    header, first = lines[0], lines[1].split(",")
    rest_rows = [",".join([f"{-1.0 + 0.02 * i:.3f}"] + first[1:]) for i in range(50)]  # 1 s at rest first
    proc = subprocess.Popen([sys.executable, "-m", "rbgp_cli", "follow", str(model), "--every", "50"],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO)
    out, err = proc.communicate("\n".join([header] + rest_rows + lines[1:]) + "\n", timeout=300)
    assert proc.returncode == 0, err
    got = [json.loads(x) for x in out.splitlines()]
    assert len(got) >= 3
    assert all(g["motion"] == 0 for g in got)
    assert got[0]["start"] >= 0.0 and got[0]["t"] - got[0]["start"] < 0.1
    # its phase 0 is before the departure by the rest the demonstrations begin with (at most that), here the same
    # for every line of the motion
    assert 0.0 < got[0]["rest_before"] <= 1.0 and len({g["rest_before"] for g in got}) == 1
    phases = [g["phase"] for g in got]
    assert phases == sorted(phases) and phases[-1] > 0.5
    true_end = float(lines[-1].split(",")[0])
    assert abs(got[-1]["end_time"] - true_end) < 0.1 * true_end
    for g in got:
        assert len(g["end_position"]) == 3 and len(g["end_position_band"]) == 3 and g["off"] in (True, False)
    assert not any(g["at_rest"] for g in got[1:])  # the shoe moves on after its slow departure


def test_follow_bad_row_is_one_line_error(model):
    text = "t,x,y,z,qx,qy,qz,qw\n0,0,0,0,0,0,0,1\n0.01,0,0,abc,0,0,0,1\n"
    res = run("follow", model, "--no-detect", input=text)
    assert res.exit_code == 2
    msg = [x for x in res.stderr.strip().splitlines() if "warning" not in x]  # the origin is off: said as a warning
    assert len(msg) == 1 and "row 3" in msg[0]


@pytest.mark.parametrize("rows", [["0,0,0,0,0,0,3,1"], ["0,0,0,0,0,0,0,1", "0.01,0,0,0,0,0,3,1"]])
def test_follow_refuses_a_quaternion_far_from_unit_as_the_file_reader_does(model, rows):
    res = run("follow", model, "--no-detect", input="t,x,y,z,qx,qy,qz,qw\n" + "\n".join(rows) + "\n")
    assert res.exit_code == 2, res.stderr
    msg = [x for x in res.stderr.strip().splitlines() if "warning" not in x]  # an off motion is also said
    assert len(msg) == 1 and f"row {len(rows) + 1}" in msg[0] and "far from 1" in msg[0], res.stderr


@pytest.mark.parametrize("time", ["0.005", "0.01"])
def test_follow_names_the_row_whose_time_does_not_increase(model, time):
    text = f"t,x,y,z,qx,qy,qz,qw\n0,0,0,0,0,0,0,1\n0.01,0,0,0,0,0,0,1\n{time},0,0,0,0,0,0,1\n"
    res = run("follow", model, "--no-detect", input=text)
    assert res.exit_code == 2, res.stderr
    msg = [x for x in res.stderr.strip().splitlines() if "warning" not in x]  # an off motion is also said
    assert len(msg) == 1 and "stdin:4" in msg[0] and "time order" in msg[0], res.stderr


@pytest.mark.parametrize("count,args,hint", [(9, ["--folds", "3", "--train-size", "2"], "--train-size 3 or more"),
                                             (4, ["--folds", "2"], "--folds 4 (one held out at a time)")])
def test_crossval_given_says_when_a_split_trains_on_too_few(tmp_path, count, args, hint):
    for src in sorted(CSV_DIR.glob("*.csv"))[:count]:
        (tmp_path / src.name).write_bytes(src.read_bytes())
    res = run("crossval", tmp_path, "--given", "0.5", "--no-peers", *args)
    assert res.exit_code == 2, res.stderr
    msg = res.stderr.strip().splitlines()
    assert len(msg) == 1 and "a split here trains on" in msg[0] and hint in msg[0], res.stderr
    assert "retrain" not in msg[0]  # not about a model file: the user trained none


def test_follow_a_stream_without_a_time_column_takes_its_times_from_the_rate(model):
    """As a file without a time column is read (row / --rate): each streamed row is not at t = 0."""
    rows = [ln.split(",") for ln in (CSV_DIR / "shoe_01.csv").read_text().splitlines()[1:41]]
    text = "x,y,z,qx,qy,qz,qw\n" + "\n".join(",".join(r[1:]) for r in rows) + "\n"
    res = run("follow", model, "--no-detect", "--rate", "200", input=text)
    assert res.exit_code == 0, res.stderr
    times = [json.loads(ln)["t"] for ln in res.stdout.splitlines()]
    assert len(times) >= 30 and times == pytest.approx([k / 200 for k in range(40)][-len(times):])


def test_crossval_given_refuses_a_fraction_outside_0_1(tmp_path):
    res = run("crossval", CSV_DIR, "--given", "1.5")
    assert res.exit_code == 2 and "between 0 and 1" in res.stderr
    res = run("crossval", CSV_DIR, "--given", "half")
    assert res.exit_code == 2 and "--given" in res.stderr


@pytest.mark.slow
def test_crossval_given_rows(tmp_path):
    res = run("--json", "crossval", CSV_DIR, "--given", "0.3", "--folds", 3, "--samples", 5, "--no-peers",
              "--restarts", 1, "--max-points", 150)
    assert res.exit_code == 0, res.stderr
    rows = json.loads(res.stdout)["rows"]
    # --no-peers leaves out the ProMPs (of movement-primitives); the nearest demonstration stays, as with --given goal
    assert [r["method"] for r in rows] == ["rbgp", "no-GP", "nearest"]
    for r in rows:
        assert r["given"] == 0.3 and r["motions"] == 9
        assert np.isfinite(r["end_pos"]) and np.isfinite(r["rest_pos"])
        assert r["method"] == "nearest" or 0.0 <= r["cov_pos"] <= 1.0  # the nearest has no samples
        # every demonstration held out once, its own scores averaging to the row's
        assert [m["index"] for m in r["per_motion"]] == list(range(9))
        # each names the file it was read from (a BVH take's name is its joint's, the same in every file)
        assert [Path(m["source"]).name for m in r["per_motion"]] == sorted(p.name for p in CSV_DIR.glob("*.csv"))
        assert np.mean([m["end_pos"] for m in r["per_motion"]]) == pytest.approx(r["end_pos"], rel=1e-9)
    assert rows[0]["paired"] is None and rows[1]["paired"]["reference"] == "rbgp"
    d = [b["end_time"] - a["end_time"] for a, b in zip(rows[0]["per_motion"], rows[1]["per_motion"])]
    assert rows[1]["paired"]["end_time"]["difference"] == pytest.approx(np.mean(d), abs=1e-12)


def test_crossval_given_json_writes_missing_coverage_as_null(monkeypatch):
    """The nearest demonstration has no samples, so no coverage: --json writes null where the table writes '-'
    (JSON has no NaN; the run failed with an internal error after the whole cross-validation before)."""
    from rbgp_cli import workflows

    nan = float("nan")
    row = dict(method="nearest", given=0.4, end_pos=0.1, end_rot=0.2, end_time=0.3, rest_pos=0.1, rest_rot=0.2,
               cov_pos=nan, cov_rot=nan, band_pos=nan, band_rot=nan, motions=9)
    monkeypatch.setattr(workflows, "crossval_under_way",
                        lambda *a, **k: {"rows": [row], "folds": 3, "samples": 5, "inputs": []})
    res = run("--json", "crossval", CSV_DIR, "--given", "0.4", "--folds", 3)
    assert res.exit_code == 0, res.stderr
    out = json.loads(res.stdout)["rows"][0]
    assert out["cov_pos"] is None and out["band_rot"] is None and out["end_pos"] == 0.1
    res = run("crossval", CSV_DIR, "--given", "0.4", "--folds", 3)
    assert res.exit_code == 0 and "nearest" in res.stdout and " -" in res.stdout


@pytest.mark.slow
def test_crossval_given_prints_and_writes_the_paired_comparison(monkeypatch):
    """The paired section under the --given F table and the per_motion / paired blocks of --json, from
    per-motion values whose paired differences are known: the peer's end position is 10 mm further on every
    motion but one (z far beyond 2: `!`), its end time the same as rbgp's on every motion (se 0: z null)."""
    from rbgp_cli import workflows
    from rbgp_cli.evaluation.under_way import COLUMNS, add_paired

    nan = float("nan")
    rng = np.random.default_rng(1)
    ref = [{"index": i, "name": f"m{i}", **{c: float(rng.uniform(0.1, 0.2)) for c in COLUMNS}} for i in range(8)]
    peer = [{**m, "end_pos": m["end_pos"] + (0.010 if i else -0.001) + 0.001 * float(rng.standard_normal()),
             "end_rot": m["end_rot"] + 0.01 * float(rng.standard_normal())} for i, m in enumerate(ref)]
    base = dict(given=0.4, end_pos=0.1, end_rot=0.2, end_time=0.3, rest_pos=0.1, rest_rot=0.2, cov_pos=0.9,
                cov_rot=0.9, band_pos=0.1, band_rot=0.2, motions=8)
    rows = [dict(base, method="rbgp", per_motion=ref),
            dict(base, method="nearest", cov_pos=nan, cov_rot=nan, band_pos=nan, band_rot=nan, per_motion=peer)]
    add_paired(rows)
    expected = rows[1]["paired"]["end_pos"]
    monkeypatch.setattr(workflows, "crossval_under_way", lambda *a, **k: {
        "rows": rows, "folds": 3, "samples": 5, "inputs": [], "paired_reference": "rbgp"})
    res = run("--json", "crossval", CSV_DIR, "--given", "0.4", "--folds", 3)
    assert res.exit_code == 0, res.stderr
    out = json.loads(res.stdout)
    assert out["paired_reference"] == "rbgp" and out["rows"][0]["paired"] is None
    p = out["rows"][1]["paired"]
    assert p["end_pos"]["z"] == pytest.approx(expected["z"]) and p["end_pos"]["z"] > 5
    assert p["end_pos"]["closer"] == 1 and p["end_pos"]["motions"] == 8
    assert p["end_time"]["difference"] == 0.0 and p["end_time"]["z"] is None and p["end_time"]["se"] is None
    assert out["rows"][1]["cov_pos"] is None
    assert [m["index"] for m in out["rows"][1]["per_motion"]] == list(range(8))
    assert out["rows"][1]["per_motion"][3]["end_pos"] == pytest.approx(peer[3]["end_pos"])

    res = run("crossval", CSV_DIR, "--given", "0.4", "--folds", 3)
    assert res.exit_code == 0, res.stderr
    lines = res.stdout.splitlines()
    head = next(i for i, x in enumerate(lines) if x.startswith("paired against rbgp at the same F on the 8"))
    row = next(x for x in lines[head:] if x.split()[:2] == ["0.4", "nearest"])
    assert f"{expected['difference']:+.4f} ± {expected['se']:.4f} z {expected['z']:+.2f} !" in row
    assert "+0.0000 ± -" in row  # the end time: no scatter, no z
    assert row.rstrip().endswith(" / ".join(str(rows[1]["paired"][c]["closer"]) for c in COLUMNS))
    assert not any(x.split()[:2] == ["0.4", "rbgp"] for x in lines[head:])  # the reference has no paired row


def test_crossval_given_passes_train_size_order_and_repeats(monkeypatch):
    """--train-size, --order and --repeats reach crossval --given F (they were ignored: a five-demonstration
    study silently ran the five folds of the whole set)."""
    from rbgp_cli import workflows

    seen = {}
    monkeypatch.setattr(workflows, "crossval_under_way",
                        lambda *a, **k: seen.update(k) or {"rows": [], "folds": 2, "samples": 5, "inputs": []})
    res = run("--json", "crossval", CSV_DIR, "--given", "0.4", "--train-size", 5, "--folds", 2, "--repeats", 2)
    assert res.exit_code == 0, res.stderr
    assert (seen["train_size"], seen["folds"], seen["repeats"], seen["order"]) == (5, 2, 2, "random")
    res = run("--json", "crossval", CSV_DIR, "--given", "0.4", "--train-size", 5, "--order", "recorded")
    assert res.exit_code == 0, res.stderr
    assert (seen["train_size"], seen["repeats"], seen["order"]) == (5, 1, "recorded")


def test_crossval_under_way_trains_on_each_split_of_make_splits(monkeypatch):
    """With ``train_size`` N each split trains on N demonstrations and scores all the others, ``repeats`` times with
    fold seeds seed, seed + 1 (crossval's :func:`make_splits`), each split's samples seeded seed + its index."""
    from rbgp_cli import workflows
    from rbgp_cli.dynamics import model as model_mod
    from rbgp_cli.evaluation import under_way
    from rbgp_cli.evaluation.crossval import make_splits

    calls = []

    class Fake:
        paths = object()

    monkeypatch.setattr(model_mod, "train_model", lambda train, **k: Fake())
    monkeypatch.setattr(under_way, "under_way_fold",
                        lambda model, paths, train, test, fractions, **k: calls.append((train, test, k)) or {})
    out = workflows.crossval_under_way([CSV_DIR], [0.4], {}, folds=3, seed=4, repeats=2, train_size=5, peers=False)
    want = make_splits(9, 3, 4, "random", 5) + make_splits(9, 3, 5, "random", 5)
    assert len(calls) == 6 and out["train_size"] == 5 and out["repeats"] == 2
    for i, ((train, test, k), (tr_idx, te_idx)) in enumerate(zip(calls, want)):
        assert len(train) == 5 and len(test) == 4
        names = [d.name for d in train] + [d.name for d in test]
        assert len(set(names)) == 9  # the held-out ones are all the others
        assert [int(j) for j in k["indices"]] == [int(j) for j in te_idx]
        assert k["seed"] == 4 + i
    assert out["splits"] == [{"train": tr.tolist(), "test": te.tolist()} for tr, te in want]
    assert len({tuple(s["train"]) for s in out["splits"]}) > 1  # the subsets differ
    from rbgp_cli.errors import InputError

    with pytest.raises(InputError, match="recording order"):
        workflows.crossval_under_way([CSV_DIR], [0.4], {}, folds=3, repeats=2, order="recorded", peers=False)


def test_follow_takes_json_as_every_command_does_and_prints_the_same_lines(model):
    """follow always prints JSON lines; ``rbgp --json follow`` and ``follow --json`` are accepted (a script that
    passes --json to every command works) and print the same lines, not a refusal."""
    text = (CSV_DIR / "shoe_01.csv").read_text()
    plain = run("follow", model, "--no-detect", "--every", "40", input=text)
    before = run("--json", "follow", model, "--no-detect", "--every", "40", input=text)
    after = run("follow", model, "--no-detect", "--every", "40", "--json", input=text)
    assert plain.exit_code == before.exit_code == after.exit_code == 0, (before.stderr, after.stderr)
    lines = plain.stdout.splitlines()
    assert len(lines) >= 2 and all("phase" in json.loads(x) for x in lines)
    assert before.stdout == plain.stdout == after.stdout


def test_follow_reads_a_file_or_dash_for_stdin_and_refuses_a_whole_file_format(model, tmp_path):
    """``rbgp follow MODEL FILE`` reads the CSV row by row to its end and prints what the same rows on stdin give;
    ``-`` is stdin; a missing file, a folder and a format that is read from whole files (``--format qtm``) are
    each one line and exit 2."""
    text = (CSV_DIR / "shoe_01.csv").read_text()
    piped = run("follow", model, "--no-detect", "--every", "40", input=text)
    dash = run("follow", model, "-", "--no-detect", "--every", "40", input=text)
    from_file = run("follow", model, CSV_DIR / "shoe_01.csv", "--no-detect", "--every", "40")
    assert piped.exit_code == dash.exit_code == from_file.exit_code == 0, (dash.stderr, from_file.stderr)
    assert len(piped.stdout.splitlines()) >= 2 and piped.stdout == dash.stdout == from_file.stdout
    for args, words in (((tmp_path / "none.csv",), "file not found"), ((tmp_path,), "is a directory"),
                        (("--format", "qtm"), "read from whole files")):
        res = run("follow", model, *args, "--no-detect", input=text)
        assert res.exit_code == 2, res.stderr
        msg = res.stderr.strip().splitlines()
        assert len(msg) == 1 and words in msg[0], res.stderr


def test_rollout_given_a_file_without_a_time_column_takes_its_times_from_the_rate(model, tmp_path):
    """--rate is the sample rate of a given file without a time column: read with it, not refused, and the
    continuation starts at the last seen sample's time on that clock ((n − 1) / rate)."""
    src = (CSV_DIR / "shoe_01.csv").read_text().splitlines()
    header = src[0].split(",")
    keep = [i for i, name in enumerate(header) if not name.lower().startswith("t")]
    rows = [",".join(line.split(",")[i] for i in keep) for line in src[: 1 + (len(src) - 1) // 2]]
    (tmp_path / "seen.csv").write_text("\n".join(rows) + "\n")
    res = run("--json", "rollout", model, "--given", tmp_path / "seen.csv", "--rate", 50, "-o", tmp_path / "rest.csv")
    assert res.exit_code == 0, res.stderr
    m0 = json.loads(res.stdout)["motions"][0]
    assert m0["t"] == pytest.approx((len(rows) - 2) / 50.0)


def _with_lost_rows(lost: dict) -> str:
    """shoe_01.csv with the rows of ``lost`` (data row index → the pose cells' text) marked as lost frames."""
    lines = (CSV_DIR / "shoe_01.csv").read_text().splitlines()
    out = [lines[0]]
    for i, line in enumerate(lines[1:]):
        f = line.split(",")
        out.append(",".join([f[0]] + [lost[i]] * (len(f) - 1)) if i in lost else line)
    return "\n".join(out) + "\n"


@pytest.mark.slow
def test_follow_skips_lost_frames_or_fills_them_with_max_gap_and_says_so(model):
    """A lost frame on the stream (empty or NaN pose cells, as trackers mark an occluded body) is skipped with one
    warning and a count at the end, not an error that ends the stream; with --max-gap a short run is filled when the
    next pose arrives, one prediction per filled row as for the recorded rows, close to what the complete stream gives
    (the rows are interpolated where the recording had them)."""
    full = run("follow", model, "--no-detect", input=(CSV_DIR / "shoe_01.csv").read_text())
    text = _with_lost_rows({200: "", 201: "", 202: "", 300: "nan"})
    skipped = run("follow", model, "--no-detect", input=text)
    filled = run("follow", model, "--no-detect", "--max-gap", "0.1", input=text)
    assert full.exit_code == skipped.exit_code == filled.exit_code == 0, (skipped.stderr, filled.stderr)
    n_full = len(full.stdout.splitlines())
    assert len(skipped.stdout.splitlines()) == n_full - 4 and len(filled.stdout.splitlines()) == n_full
    assert "row 202 is a lost frame" in skipped.stderr and "4 lost frames on the stream: 0 filled, 4 skipped" in skipped.stderr
    assert "4 filled, 0 skipped" in filled.stderr
    a = [json.loads(x) for x in full.stdout.splitlines()]
    b = [json.loads(x) for x in filled.stdout.splitlines()]
    assert [x["t"] for x in a] == [x["t"] for x in b]
    assert max(abs(x["end_time"] - y["end_time"]) for x, y in zip(a, b)) < 0.01


@pytest.mark.parametrize("kind", ["qtm", "bvh", "mcap"])
def test_follow_refuses_a_file_of_a_whole_file_format_by_its_content_piped_or_named(model, tmp_path, kind):
    """A recorded QTM, BVH or MCAP file given to follow, as a file or piped in: one line naming the format, exit 2
    (before: the CSV parser's error about its header line)."""
    from tests.io import mcap_fixtures as F

    if kind == "mcap":
        path = tmp_path / "take.mcap"
        F.write_ros2(path, "geometry_msgs/msg/PoseStamped", n=20)
    else:
        path = tmp_path / f"take.{'tsv' if kind == 'qtm' else 'bvh'}"
        path.write_text("NO_OF_FRAMES\t10\nNO_OF_CAMERAS\t3\n" if kind == "qtm" else "HIERARCHY\nROOT Hips\n{\n")
    title = {"qtm": "QTM", "bvh": "BVH", "mcap": "MCAP"}[kind]
    for res in (run("follow", model, path), run("follow", model, input=path.read_bytes())):
        assert res.exit_code == 2, res.stderr
        msg = res.stderr.strip().splitlines()
        assert len(msg) == 1 and title in msg[0] and "read from whole files" in msg[0], res.stderr


def test_follow_says_once_on_stderr_when_a_motion_is_off(model):
    """Poses far from every demonstration: the JSON lines say off, and stderr says it once for the motion."""
    lines = (CSV_DIR / "shoe_01.csv").read_text().splitlines()
    moved = [lines[0]] + [",".join([f.split(",")[0], str(float(f.split(",")[1]) + 3.0), *f.split(",")[2:]]) for f in lines[1:]]
    res = run("follow", model, "--no-detect", "--every", "20", input="\n".join(moved) + "\n")
    assert res.exit_code == 0, res.stderr
    got = [json.loads(x) for x in res.stdout.splitlines()]
    assert got and all(g["off"] for g in got)
    said = [x for x in res.stderr.splitlines() if "left what the demonstrations cover" in x]
    assert len(said) == 1 and "motion 0" in said[0], res.stderr
