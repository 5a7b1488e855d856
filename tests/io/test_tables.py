"""GROUND/OBS tables: values, line numbers in messages, and what a large table keeps in memory."""

from __future__ import annotations

import numpy as np
import pytest

from jaxgeo.io import TableError, read_ground, read_observations
from jaxgeo.io.internal import table_lines

OBS = """# measured by hand
id,image,x,y,sigma_px

P1,left,10.5,20.25,0.3
P1,right,11,21,
# a comment between rows
P2,left,1e2,2.5e1,1
"""


@pytest.mark.parametrize("newline", ["\n", "\r\n"])
def test_observations_values_and_lines(tmp_path, newline):
    path = tmp_path / "obs.csv"
    path.write_bytes(OBS.replace("\n", newline).encode())
    obs = read_observations(path, default_sigma_px=0.7)
    assert obs.point_ids == ("P1", "P1", "P2")
    assert obs.images == ("left", "right", "left")
    np.testing.assert_array_equal(obs.xy, [[10.5, 20.25], [11.0, 21.0], [100.0, 25.0]])
    np.testing.assert_array_equal(obs.sigma_px, [0.3, 0.7, 1.0])
    assert obs.xy.flags.writeable and obs.xy.dtype == np.float64
    # the line of every row, as messages name them (comments and blank lines counted)
    np.testing.assert_array_equal(table_lines(path), [4, 5, 7])
    # one string per image name and per point id, shared by their rows
    assert obs.images[0] is obs.images[2] and obs.point_ids[0] is obs.point_ids[1]


def test_a_point_measured_twice_in_one_image_names_both_lines(tmp_path):
    path = tmp_path / "obs.csv"
    rows = ["id,image,x,y", "A,left,1,1", "B,left,2,2", "A,right,1,1", "C,left,3,3",
            "B,left,2,2", "A,left,5,5", "B,left,9,9"]  # fmt: skip
    path.write_text("\n".join(rows) + "\n")
    # the first repeat in the file (line 6, B in left, first on line 3), not A's on line 7
    with pytest.raises(TableError, match=r"obs.csv:6: point 'B' in image 'left' already "
                                         r"measured on line 3"):  # fmt: skip
        read_observations(path)
    # the same id in another image, or another id in the same image, is no repeat
    path.write_text("\n".join(rows[:5]) + "\n")
    assert len(read_observations(path)) == 4


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("", r"obs.csv: empty table"),
        ("# only a comment\n", r"obs.csv: empty table"),
        ("id,image,x\nP,left,1\n", r"obs.csv:1: header lacks column\(s\) y"),
        ("id,image,x,y\n\nP,left,1\n", r"obs.csv:3: expected 4 fields, got 3"),
        ("id,image,x,y\nP,left,one,2\n", r"obs.csv:2: column 'x' is not a number: 'one'"),
        ("id,image,x,y\nP,left,1,inf\n", r"obs.csv:2: column 'y' is not finite"),
        ("id,image,x,y\n,left,1,2\n", r"obs.csv:2: empty point id or image name"),
        ("id,image,x,y,sigma_px\nP,left,1,2,0\n", r"obs.csv:2: point 'P' has a non-positive"),
        ('id,image,x,y\n"P,left,1,2\nQ,left,1,2\n', r"obs.csv:2: "),
    ],
)
def test_bad_tables_name_the_file_and_line(tmp_path, text, message):
    path = tmp_path / "obs.csv"
    path.write_text(text)
    with pytest.raises(TableError, match=message):
        read_observations(path)


def test_not_utf8_names_the_line(tmp_path):
    path = tmp_path / "obs.csv"
    path.write_bytes(b"id,image,x,y\nP,left,1,2\nQ,l\xe9ft,1,2\n")
    with pytest.raises(TableError, match=r"obs.csv:3: not UTF-8"):
        read_observations(path)


def test_ground_lines_and_values(tmp_path):
    path = tmp_path / "ground.csv"
    path.write_text("id,lon,lat,h,role\n\nG1,77.5,12.9,900,gcp\nG2,77.6,13.0,901.5,check\n")
    ground = read_ground(path)
    assert ground.ids == ("G1", "G2") and ground.role == ("gcp", "check")
    np.testing.assert_array_equal(ground.sigma_m, 0.3)
    np.testing.assert_array_equal(table_lines(path), [3, 4])
