"""The format registry (rbgp_cli.io.formats): one place lists the formats, and a format registered
there (a toy reader here) is read, offered by --format and described by inspect without other edits."""

from __future__ import annotations

import io
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from rbgp_cli.dynamics.trajectory import Trajectory
from rbgp_cli.io import formats
from rbgp_cli.io.inspect import format_inspect, inspect_file
from rbgp_cli.io.options import ReadOptions
from rbgp_cli.io.read import detect_format, read_demonstrations, skip_reason
from tests.cli.test_cli import assert_one_line_error, run

REPO = Path(__file__).resolve().parents[2]


def _toy_read(path, options=None):
    """TOY files: a first line ``TOY``, then ``t x y z`` rows (identity rotation)."""
    rows = np.array([[float(c) for c in ln.split()] for ln in Path(path).read_text().splitlines()[1:] if ln.strip()])
    n = len(rows)
    return [Trajectory(t=rows[:, 0], quat=np.tile([0.0, 0.0, 0.0, 1.0], (n, 1)), position=rows[:, 1:4],
                       name=Path(path).stem, source=str(path), info={"format": "toy"})]


def _toy_describe(path, options=None):
    return {"format": "toy", "rows": len(Path(path).read_text().splitlines()) - 1, "needs": []}


TOY = formats.Format(
    name="toy", title="Toy pose text", read=_toy_read, describe=_toy_describe,
    detect=lambda head: head.startswith(b"TOY\n"),
    skip_reason=lambda head, path, options=None, complete=False: None if head.startswith(b"TOY\n") else "not a toy file",
)


def _toy_file(path: Path, n: int = 40) -> Path:
    path.write_text("TOY\n" + "".join(f"{a} {0.1 * np.sin(a)} {0.05 * a} 0.0\n" for a in (np.arange(n) * 0.01).tolist()))
    return path


def test_the_builtin_formats_are_listed_once_and_load_lazily():
    assert formats.names() == ("csv", "qtm", "motive", "vicon", "mcap", "c3d", "bvh")
    assert formats.choices()[0] == "auto"
    for name in formats.names():
        fmt = formats.get(name)
        assert fmt.name == name and fmt.read is not None and fmt.describe is not None
    assert [f.name for f in formats.all_formats() if f.fallback] == ["csv"]
    writers = {f.name for f in formats.all_formats() if f.write is not None}
    assert {"csv", "qtm", "motive", "vicon"} <= writers and not writers & {"c3d", "bvh"}  # read-only formats
    with pytest.raises(ValueError, match="already registered"):
        formats.register(formats.Format(name="qtm", title="x", read=_toy_read))
    with pytest.raises(ValueError, match="auto"):
        formats.register(formats.Format(name="auto", title="x", read=_toy_read))


def test_the_cli_starts_without_importing_a_reader():
    code = ("import sys; import rbgp_cli.cli.app; "
            "print(sorted(m for m in sys.modules if m.startswith('rbgp_cli.io.')), 'numpy' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO, check=True).stdout
    assert out.strip() == "['rbgp_cli.io.formats'] False"


def test_a_registered_toy_format_is_read_detected_and_skipped_without_other_edits(tmp_path):
    folder = tmp_path / "takes"
    folder.mkdir()
    _toy_file(folder / "a.toy")
    (folder / "notes.txt").write_text("not pose data\n")
    assert detect_format(folder / "a.toy") == "csv"  # unknown before it is registered
    with formats.registered(TOY):
        assert detect_format(folder / "a.toy") == "toy"
        trajs = read_demonstrations([folder / "a.toy"])
        assert len(trajs) == 1 and trajs[0].info["format"] == "toy" and len(trajs[0]) == 40
        # named explicitly, a folder, stdin: all dispatch to the toy reader
        assert read_demonstrations([folder / "a.toy"], ReadOptions(format="toy"))[0].info["format"] == "toy"
        with pytest.warns(UserWarning, match="notes.txt"):
            assert [t.name for t in read_demonstrations([folder])] == ["a"]
        data = (folder / "a.toy").read_bytes()
        assert read_demonstrations(["-"], stdin=io.BytesIO(data))[0].info["format"] == "toy"
        assert skip_reason(folder / "notes.txt", ReadOptions(format="toy")) == "not a toy file"
        d = inspect_file(folder / "a.toy")
        assert d["format"] == "toy" and d["description"]["rows"] == 40 and d["error"] is None
        assert len(d["trajectories"]) == 1 and d["trajectories"][0]["samples"] == 40
        text = format_inspect(d)
        assert text.splitlines()[0].endswith("Toy pose text (%d bytes)" % len(data)) and "rows" in text
    assert "toy" not in formats.names()
    with pytest.raises(Exception, match="unknown format 'toy'"):
        read_demonstrations([folder / "a.toy"], ReadOptions(format="toy"))


def test_a_registered_toy_format_is_a_format_choice_of_the_cli(tmp_path):
    path = _toy_file(tmp_path / "a.toy")
    with formats.registered(TOY):
        res = run("inspect", "--format", "toy", path)
        assert res.exit_code == 0, res.stderr
        assert "Toy pose text" in res.stdout and "40 samples" in res.stdout
        res = run("inspect", path)  # detected
        assert res.exit_code == 0 and "Toy pose text" in res.stdout
        assert_one_line_error(run("inspect", "--format", "tyo", path), 2, "unknown --format 'tyo'", "toy")
    assert_one_line_error(run("inspect", "--format", "toy", path), 2, "unknown --format 'toy'")


@pytest.mark.slow
def test_the_format_help_comes_from_the_registry():
    code = ("import sys; from rbgp_cli.io import formats; "
            "formats.register(formats.Format(name='toy', title='Toy', read=print)); "
            "from typer.testing import CliRunner; from rbgp_cli.cli.app import app; "
            "print(CliRunner().invoke(app, ['inspect', '--help'], terminal_width=200).stdout)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO, check=True).stdout
    text = " ".join(out.replace("│", " ").split())  # the help wraps the list at spaces
    assert "auto | csv | qtm | motive | vicon | mcap | c3d | bvh | toy" in text and "…" not in out


def test_every_reader_shares_one_missing_value_vocabulary(tmp_path):
    """The union of the two former lists: '#N/A' and '<NA>' (spreadsheets, pandas) are lost frames in
    the vendor exports too, as they were in CSV; other text is still an error naming the cell."""
    from rbgp_cli.errors import InputError
    from rbgp_cli.io import vendor
    from rbgp_cli.io.vocabulary import MISSING_TOKENS

    assert {"#n/a", "<na>", "null", "n/a", ""} <= MISSING_TOKENS
    cells = vendor.numeric_cells([["1.5", "#N/A"], ["<NA>", " null "]], [0, 1], [3, 4], path="x.tsv")
    assert cells[0, 0] == 1.5 and np.isnan(cells[[0, 1, 1], [1, 0, 1]]).all()
    with pytest.raises(InputError, match="x.tsv:4: cell 'abc' in column #2 is not a number"):
        vendor.numeric_cells([["1", "2"], ["3", "abc"]], [0, 1], [3, 4], path="x.tsv")
    # end to end: a QTM export with '#N/A' cells reads them as a lost frame
    from rbgp_cli.io import qtm
    from rbgp_cli.io.export import write_qtm_tsv

    n = 5
    traj = Trajectory(t=np.arange(n) * 0.01, quat=np.tile([0.0, 0.0, 0.0, 1.0], (n, 1)),
                      position=np.full((n, 3), 0.1), name="shoe")
    p = tmp_path / "a_6D.tsv"
    write_qtm_tsv([traj], p, rate=100.0)
    lines = p.read_text().splitlines()
    k = next(i for i, ln in enumerate(lines) if ln.startswith("Frame\t")) + 3
    cells = lines[k].split("\t")
    cells[2] = "#N/A"
    lines[k] = "\t".join(cells)
    p.write_text("\n".join(lines) + "\n")
    got = qtm.read(p)[0]
    assert got.info["lost_frames"] == 1 and np.isnan(got.position[2]).all()
