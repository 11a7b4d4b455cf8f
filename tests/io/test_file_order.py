"""The recording order (``ReadOptions.file_order``, ``--file-order``): as given, by natural name, or by
modification time; stdin keeps its place; a bad value is one error naming the option."""

from __future__ import annotations

import os

import pytest

from rbgp_cli.errors import InputError
from rbgp_cli.io.options import ReadOptions
from rbgp_cli.io.read import list_sources, ordered_files
from tests.cli.common import CSV_DIR, run
from tests.cli.test_cli import assert_one_line_error


def _takes(tmp_path, names, mtimes):
    for name, m in zip(names, mtimes):
        f = tmp_path / name
        f.write_bytes((CSV_DIR / "shoe_01.csv").read_bytes())
        os.utime(f, ns=(m * 10**9, m * 10**9))
    return [str(tmp_path / n) for n in names]


def test_given_name_and_mtime_orders(tmp_path):
    # as a shell glob gives them: take_1, take_10, take_2 (lexicographic); recorded 2, 10, 1 (mtime)
    files = _takes(tmp_path, ["take_1.csv", "take_10.csv", "take_2.csv"], [1_700_000_300, 1_700_000_100, 1_700_000_200])
    assert ordered_files(files, "given") == files
    assert [os.path.basename(f) for f in ordered_files(files, "name")] == ["take_1.csv", "take_2.csv", "take_10.csv"]
    assert [os.path.basename(f) for f in ordered_files(files, "mtime")] == ["take_10.csv", "take_2.csv", "take_1.csv"]
    # a folder is read the same way: its files in natural order by default, by mtime when asked
    assert [os.path.basename(f) for f in list_sources([str(tmp_path)]).files] == ["take_1.csv", "take_2.csv", "take_10.csv"]
    by_time = list_sources([str(tmp_path)], ReadOptions(file_order="mtime")).files
    assert [os.path.basename(f) for f in by_time] == ["take_10.csv", "take_2.csv", "take_1.csv"]


def test_equal_times_fall_back_on_the_name_and_stdin_keeps_its_place(tmp_path):
    files = _takes(tmp_path, ["b_10.csv", "b_9.csv"], [1_700_000_000, 1_700_000_000])
    assert [os.path.basename(f) for f in ordered_files(files, "mtime")] == ["b_9.csv", "b_10.csv"]
    assert ordered_files([files[0], "-", files[1]], "name") == [files[1], "-", files[0]]


def test_a_bad_order_is_one_error():
    with pytest.raises(InputError, match="file_order must be one of given, name, mtime"):
        ordered_files(["a.csv"], "date")
    assert_one_line_error(run("inspect", CSV_DIR, "--file-order", "date"), 2, "--file-order must be given, name or mtime")
