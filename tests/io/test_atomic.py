"""Atomic outputs (``jaxgeo.io._atomic``): a CSV table streamed row by row appears whole or not at
all, never over an existing file unless asked."""

import csv
import io
import os

import pytest

from jaxgeo.io._atomic import atomic_write_csv

HEADER = ["id", "image", "vx_px"]
ROWS = [["P1", "left", repr(0.1)], ["P,2", "right", repr(-2.5e-7)], ["P3", 'a "b"', "nan"]]


def _text(header, rows):
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header)
    w.writerows(rows)
    return buf.getvalue()


def test_rows_written_as_the_csv_module_writes_them(tmp_path):
    path = atomic_write_csv(tmp_path / "t.csv", HEADER, (r for r in ROWS))
    assert path.read_bytes() == _text(HEADER, ROWS).encode()  # quoting, "\n" line ends
    assert os.listdir(tmp_path) == ["t.csv"]  # no temporary file left


def test_refuses_an_existing_file_unless_asked(tmp_path):
    path = tmp_path / "t.csv"
    path.write_text("mine\n")
    with pytest.raises(FileExistsError, match="t.csv"):
        atomic_write_csv(path, HEADER, ROWS)
    assert path.read_text() == "mine\n"
    atomic_write_csv(path, HEADER, ROWS, overwrite=True)
    assert path.read_text() == _text(HEADER, ROWS)


def test_a_failure_while_rows_are_formed_leaves_nothing(tmp_path):
    def rows():
        yield ROWS[0]
        raise ValueError("row 2 cannot be formed")

    path = tmp_path / "t.csv"
    with pytest.raises(ValueError, match="row 2"):
        atomic_write_csv(path, HEADER, rows())
    assert os.listdir(tmp_path) == []
    path.write_text("mine\n")
    with pytest.raises(ValueError, match="row 2"):
        atomic_write_csv(path, HEADER, rows(), overwrite=True)
    assert path.read_text() == "mine\n"  # the existing file untouched
