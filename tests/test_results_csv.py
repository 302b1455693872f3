"""The two CSV readers of result folders (``read_run_seeds``, ``read_rows``) share one reading
path: each reading problem is a DkfsimError naming the file and, where it has one, the line."""

from __future__ import annotations

import pytest

from dkfsim.config.results import read_rows, read_run_seeds
from dkfsim.core.errors import DkfsimError

GOOD = "run,seed,estimate,component,mse\n0,7,fused,position,0.5\n\n1,8,fused,position,0.25\n"

CASES = {
    "wrong header": ("a,b\n0,1\n", ["not a", "its header"]),
    "not UTF-8": (b"run,seed,estimate,component\n\xff\xfe\n", ["not a UTF-8 text file"]),
    "a field over the csv module's limit": ('run,seed,estimate,component\n0,1,"' + "x" * 200_000 + '",p\n',
                                            ["cannot read as CSV", "field larger than field limit"]),
}


@pytest.mark.parametrize("reader", [read_run_seeds, read_rows])
@pytest.mark.parametrize("case", sorted(CASES))
def test_each_reading_problem_names_the_file(tmp_path, reader, case):
    text, words = CASES[case]
    path = tmp_path / "runs.csv"
    path.write_bytes(text if isinstance(text, bytes) else text.encode())
    with pytest.raises(DkfsimError) as info:
        reader(path)
    assert str(path) in str(info.value)
    for word in words:
        assert word in str(info.value)


def test_both_readers_skip_blank_lines_and_read_every_row(tmp_path):
    path = tmp_path / "runs.csv"
    path.write_text(GOOD)
    assert read_run_seeds(path) == {0: 7, 1: 8}
    rows = read_rows(path)
    assert [(r["run"], r["seed"], r["mse"]) for r in rows] == [(0, 7, 0.5), (1, 8, 0.25)]


def test_line_numbers_count_the_header_and_blank_lines(tmp_path):
    path = tmp_path / "runs.csv"
    path.write_text(GOOD + "\n1,9,fused,position,0.1\n")
    with pytest.raises(DkfsimError, match=r"line 6: run 1 has two seeds"):
        read_run_seeds(path)
    path.write_text(GOOD + "2,9,fused\n")
    with pytest.raises(DkfsimError, match=r"line 5: 3 cells for 5 columns"):
        read_rows(path)
    path.write_text("run,seed,estimate,component,mse,mse\n")
    with pytest.raises(DkfsimError, match="names a column twice"):
        read_rows(path)
