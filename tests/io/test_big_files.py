"""Big CSV files are parsed from disk, only the needed columns, with fixed dtypes: memory about the
size of the arrays, not ten times the file. That path must give exactly what the in-memory text path
gives (the same trajectories, the same errors), and hand over to it whatever it does not cover."""

from __future__ import annotations

import json
import subprocess
import sys
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from rbgp_cli.errors import InputError
from rbgp_cli.io import csv as rcsv
from rbgp_cli.io import csv_table
from rbgp_cli.io.csv import write_trajectories_csv
from rbgp_cli.io.options import ReadOptions

REPO = Path(__file__).resolve().parents[2]
ROWS = 24_000  # > 1 MiB of text: over FAST_MIN_BYTES


def motion(n: int = ROWS, seed: int = 0):
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 100.0
    p = np.cumsum(0.001 * rng.normal(size=(n, 3)), axis=0) + [0.3, 0.1, 0.8]
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return t, p, q


def table(n=ROWS, *, sep=",", decimal=".", header="t,x,y,z,qx,qy,qz,qw", scale=1.0, cols=None, seed=0) -> list:
    t, p, q = motion(n, seed)
    values = np.column_stack([t, p * scale, q]) if cols is None else cols(t, p * scale, q)
    rows = [sep.join(f"{v:.9g}".replace(".", decimal) if decimal != "." else f"{v:.9g}" for v in r) for r in values]
    return [header.replace(",", sep)] + rows


def via_text(path: Path, options=None):
    """The in-memory text path on the same file (what every file went through before)."""
    return rcsv.read_text(csv_table.decode(path.read_bytes(), str(path)), str(path), options)


def assert_same(a, b):
    assert [t.name for t in a] == [t.name for t in b]
    for x, y in zip(a, b):
        for k in ("t", "quat", "position"):
            np.testing.assert_array_equal(getattr(x, k), getattr(y, k))  # bit for bit, NaN where NaN
        assert x.info == y.info and x.source == y.source


def write(tmp_path, name, lines, *, newline="\n", bom=False, tail="\n", encoding="utf-8") -> Path:
    p = tmp_path / name
    p.write_bytes((("\ufeff" if bom else "") + newline.join(lines) + tail.replace("\n", newline)).encode(encoding))
    assert p.stat().st_size >= rcsv.FAST_MIN_BYTES
    return p


def layouts(tmp_path):
    """{name: (path, options)}: the layouts the fast path reads itself."""
    out = {}
    out["comma"] = (write(tmp_path, "comma.csv", table()), None)
    lines = ["# recorded 2024-05-01; length_unit=mm", "", "time_ms,x_mm,y_mm,z_mm,qw,qx,qy,qz"]
    lines += table(cols=lambda t, p, q: np.column_stack([t * 1000, p, q[:, [3, 0, 1, 2]]]), scale=1000.0)[1:]
    out["crlf, BOM, comment, units"] = (write(tmp_path, "crlf.csv", lines, newline="\r\n", bom=True), None)
    out["semicolon, decimal comma"] = (write(tmp_path, "semi.csv", table(sep=";", decimal=",")), None)
    tab = [ln + "\t" for ln in table(sep="\t")]  # a trailing tab on every line
    out["tab, trailing delimiter"] = (write(tmp_path, "tab.tsv", tab), None)
    out["whitespace"] = (write(tmp_path, "ws.txt", table(sep=" ")), None)
    lost = table()
    for k in (5, 6, 7, 5000):
        lost[k] = ",".join([lost[k].split(",")[0]] + [""] * 7)  # lost frame: empty cells
    lost[9000] = lost[9000].split(",")[0] + ",nan,NaN,null,,,,"
    lost[12000] = ",".join(lost[12000].split(",")[:3])  # a short row
    out["lost frames, short row, blank lines at the end"] = (write(tmp_path, "lost.csv", lost, tail="\n\n\n"), None)
    out["no time column, --rate"] = (write(tmp_path, "rate.csv", [ln.split(",", 1)[1] for ln in table()]),
                                     ReadOptions(rate=100.0))
    out["numbered quaternion, --quat-order"] = (write(tmp_path, "num.csv", table(header="t,x,y,z,q0,q1,q2,q3")),
                                                ReadOptions(quat_order="xyzw"))
    out["unused columns"] = (write(tmp_path, "extra.csv", table(header="t,frame_no,x,y,z,qx,qy,qz,qw,marker_error",
                             cols=lambda t, p, q: np.column_stack([t, np.arange(len(t)), p, q, t * 0 + 0.5]))), None)
    from rbgp_cli.dynamics.trajectory import Trajectory

    trajs = [Trajectory(t=t, quat=q, position=p, name=name)
             for name, (t, p, q) in (("a", motion(5000, 1)), ("b, with a comma", motion(4000, 2)), ("7", motion(6000, 3)))]
    p = tmp_path / "rollouts.csv"
    write_trajectories_csv(trajs, p, extra={"std_wx": [np.full(len(t), 0.5) for t in trajs]})
    out["rbgp's own output: quoted names, demo column, extra column"] = (p, None)
    return out


@pytest.mark.slow
def test_big_files_are_read_from_disk_exactly_as_the_text_path_reads_them(tmp_path, monkeypatch):
    for name, (path, options) in layouts(tmp_path).items():
        expected = via_text(path, options)
        monkeypatch.setattr(rcsv, "read_text", lambda *a, **k: pytest.fail(f"{name}: fell back to the text path"))
        got = rcsv.read(path, options)
        monkeypatch.undo()
        assert_same(got, expected)
        assert sum(len(t) for t in got) > 10_000, name


def problems(tmp_path):
    """{name: path}: layouts the fast path hands to the text path (deep in the file, past the head)."""
    base = table()
    out = {}

    def variant(name, k, line, **kw):
        lines = list(base)
        lines[k] = line
        out[name] = write(tmp_path, name.replace(" ", "_") + ".csv", lines, **kw)

    variant("non-numeric cell", 20_000, base[20_000].replace(",", ",oops,", 1).rsplit(",", 1)[0])
    variant("a row with too many fields", 15_000, base[15_000] + ",1.5")
    variant("a blank line among the rows", 15_000, "")
    variant("a comment line among the rows", 15_000, "# the subject paused here")
    variant("a missing-value token only the text path knows", 15_000, base[15_000].split(",")[0] + ",Null,NONE,n/a,,,,")
    lines = ["trial," + base[0]] + [("take" if k < 20_000 else "caf\u00e9") + "," + ln for k, ln in enumerate(base[1:])]
    out["latin-1"] = write(tmp_path, "latin1.csv", lines, encoding="latin-1")  # é far from the head
    iso = ["time,x,y,z,qx,qy,qz,qw"] + [f"2024-05-01T12:{k // 6000:02d}:{(k // 100) % 60:02d}.{k % 100:02d}0," + ln.split(",", 1)[1]
                                        for k, ln in enumerate(base[1:])]
    out["ISO date-times"] = write(tmp_path, "iso.csv", iso)
    return out


@pytest.mark.slow
def test_what_the_fast_path_does_not_cover_reads_or_fails_like_the_text_path(tmp_path):
    for name, path in problems(tmp_path).items():
        try:
            expected = via_text(path)
        except InputError as exc:
            with pytest.raises(InputError) as info:
                rcsv.read(path)
            assert str(info.value) == str(exc), name  # the same message, row number included
            assert {"non-numeric cell": ":20001: non-numeric value 'oops'",
                    "a row with too many fields": ":15001: row has 9 fields"}[name] in str(exc)
            continue
        assert_same(rcsv.read(path), expected)


@pytest.mark.slow
def test_reading_a_big_table_needs_about_its_size_in_memory(tmp_path):
    """Peak of the memory Python and numpy allocate while reading (tracemalloc: the arrays, the text)
    stays under 3× the file (the text path needs about 6×: bytes, text, lines, a joined copy)."""
    sys.path.insert(0, str(REPO / "benchmarks"))
    from bench_reading import write_pose_csv

    path = tmp_path / "poses.csv"
    write_pose_csv(path, 60_000)
    size = path.stat().st_size
    rcsv.read(path)  # imports and caches outside the measurement
    tracemalloc.start()
    try:
        (traj,) = rcsv.read(path)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert len(traj) == 60_000
    assert peak < 3 * size, f"peak {peak / size:.1f}x the file size"


@pytest.mark.slow
def test_the_benchmark_reports_peak_rss_and_rows_per_second(tmp_path):
    out = tmp_path / "bench.json"
    res = subprocess.run([sys.executable, str(REPO / "benchmarks" / "bench_reading.py"), "--rows", "20000",
                          "--repeat", "1", "--no-pandas", "--peer-rev", "", "--json", str(out)],
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    d = json.loads(out.read_text())
    assert d["rows"] == 20_000 and d["file_mb"] > 1
    ours = d["readers"][0]
    assert ours["peak_mb"] > ours["base_mb"] > 0 and ours["seconds"] > 0 and ours["rows"] == 20_000
    assert "rows/s" in res.stdout and "peak RSS" in res.stdout


@pytest.mark.slow
def test_describe_counts_the_rows_of_a_big_file_without_decoding_it(tmp_path):
    """``rbgp inspect`` on a big file: the header from the head, the rows counted on a memory map, the
    same count as the text path (blank and comment lines are not rows)."""
    files = [path for path, _ in layouts(tmp_path).values()] + list(problems(tmp_path).values())
    for path in files:
        expected = len(csv_table.parse_table(csv_table.decode(path.read_bytes(), str(path)), str(path)).lines)
        d = rcsv.describe(path)
        assert d["data_rows"] == expected, path.name


def test_a_numeric_big_file_is_parsed_without_importing_pandas(tmp_path):
    """Plain numbers go through numpy's parser: pandas (~65 MB of memory once imported, as much as the
    poses of a 10⁶-row file) is not imported to read them."""
    path = write(tmp_path, "plain.csv", table())
    code = ("import sys\nfrom rbgp_cli.io.read import read_file\n"
            f"tr = read_file({str(path)!r})\nprint(len(tr[0]), 'pandas' in sys.modules)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=REPO)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == [str(ROWS), "False"]


def test_empty_cells_deep_in_a_big_file_read_as_the_text_path_reads_them(tmp_path):
    """An empty cell (a lost frame) is not a number for numpy's parser: the pandas parse reads the file,
    with the same result as the text path."""
    lines = table()
    for k in (12_000, 12_001, 20_000):
        lines[k] = lines[k].split(",")[0] + ",,,,,,,"
    path = write(tmp_path, "lost.csv", lines)
    got = rcsv.read(path)
    assert_same(got, via_text(path))
    assert np.isnan(got[0].position).any()


@pytest.mark.slow
def test_the_memory_benchmark_prints_the_ratio_of_peak_rss_to_the_file_size():
    res = subprocess.run([sys.executable, str(REPO / "benchmarks" / "bench_memory.py"), "--rows", "3000"],
                         capture_output=True, text=True, timeout=600, cwd=REPO)
    assert res.returncode == 0, res.stderr
    last = res.stdout.strip().splitlines()[-1]
    assert last.startswith("ratio peak RSS / file size of rbgp train: ")
    assert float(last.split(": ")[1].split()[0]) > 0
    assert "rbgp --version (imports)" in res.stdout and "pandas.read_csv" in res.stdout
