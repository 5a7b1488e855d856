"""Scene metadata: Cartosat-1-like text and JSON read the same scenes; errors name the fault."""

import json
import pathlib

import numpy as np
import pytest

from jaxgeo.io import read_metadata, write_metadata_json
from jaxgeo.models import SceneMetadata

DATA = pathlib.Path(__file__).parent / "data"
TEXT = DATA / "cartosat1_stereo_meta.txt"
JSON = DATA / "cartosat1_stereo_meta.json"


def test_text_example_values():
    fore, aft = read_metadata(TEXT)
    assert fore.image_id == "BANDF_hobart_fore" and aft.image_id == "BANDA_hobart_aft"
    assert (fore.n_cols, fore.n_rows) == (12000, 12000)
    np.testing.assert_array_equal(fore.corners[0], [147.1130, -42.7350, 35.5])  # own height
    np.testing.assert_array_equal(fore.corners[2], [147.3960, -43.0480, 20.0])  # corner_h_m
    assert fore.along_track_angle_deg == 26.0 and aft.along_track_angle_deg == -5.0
    assert aft.across_track_angle_deg == 0.0  # default
    assert fore.focal_length_mm == 1945.0 and fore.pixel_size_um == 7.0
    assert fore.line_time_s == pytest.approx(0.336e-3)
    assert aft.first_line_time_s - fore.first_line_time_s == 52.0
    assert fore.epoch_utc == "2006-10-01T00:12:30.000Z"
    np.testing.assert_allclose(fore.corner_pixels()[2], [11999.0, 11999.0])


def test_text_and_json_read_the_same(tmp_path):
    from_text = read_metadata(TEXT)
    assert read_metadata(JSON) == from_text
    out = write_metadata_json(from_text, tmp_path / "meta.json")
    assert read_metadata(out) == from_text
    single = tmp_path / "one.json"  # one object instead of a list
    single.write_text(json.dumps(from_text[1].to_dict()))
    assert read_metadata(single) == [from_text[1]]
    wrapped = tmp_path / "wrapped.json"
    wrapped.write_text(json.dumps({"scenes": [s.to_dict() for s in from_text]}))
    assert read_metadata(wrapped) == from_text


def test_write_is_atomic_and_never_overwrites(tmp_path):
    scenes = read_metadata(TEXT)
    path = tmp_path / "meta.json"
    path.write_text("precious")
    with pytest.raises(FileExistsError, match="overwrite=True"):
        write_metadata_json(scenes, path)
    assert path.read_text() == "precious"
    write_metadata_json(scenes, path, overwrite=True)
    assert read_metadata(path) == scenes
    assert [p.name for p in tmp_path.iterdir()] == ["meta.json"]  # no temporary left


def test_missing_fields_are_all_named(tmp_path):
    text = tmp_path / "bad.txt"
    text.write_text("[scene_a]\nNoPixels = 100\nNoScans = 100\nProdULLat = 1.0\n")
    with pytest.raises(ValueError) as err:
        read_metadata(text)
    msg = str(err.value)
    assert str(text) in msg and "'scene_a'" in msg
    for name in ("ul_lon_deg", "ur_lat_deg", "ll_lon_deg", "flying_height_m", "along_track"):
        assert name in msg
    assert "ul_lat_deg" not in msg.split("field(s):")[1]  # given as ProdULLat
    js = tmp_path / "bad.json"
    js.write_text(json.dumps([{"image_id": "x", "n_cols": 10, "corners": [[0, 0, 0]] * 4}]))
    with pytest.raises(ValueError, match="'x' is missing required field.*n_rows, flying_height_m"):
        read_metadata(js)


def test_bad_values_name_key_and_line(tmp_path):
    lines = TEXT.read_text().splitlines()
    idx = next(i for i, line in enumerate(lines) if line.startswith("flying_height_m"))
    lines[idx] = "flying_height_m = six hundred km"
    bad = tmp_path / "bad.txt"
    bad.write_text("\n".join(lines))
    with pytest.raises(ValueError, match=f"bad.txt:{idx + 1}: flying_height_m must be a number"):
        read_metadata(bad)
    bad.write_text("[a]\nn_cols 12000\n")
    with pytest.raises(ValueError, match="bad.txt:2: expected 'key = value'"):
        read_metadata(bad)
    bad.write_text("n_cols = 10\nn_cols = 12\n")
    with pytest.raises(ValueError, match="bad.txt:2: duplicate key 'n_cols'"):
        read_metadata(bad)
    bad.write_text("")
    with pytest.raises(ValueError, match="no scene metadata"):
        read_metadata(bad)
    scene = read_metadata(TEXT)[0].to_dict()
    for key, value, expected in (
        ("n_cols", 12.5, "n_cols must be an integer"),
        ("line_time_s", "fast", "line_time_s must be a number"),
        ("pixel_size_um", -7.0, "pixel_size_um must be positive"),
        ("corners", [[0, 0]] * 4, r"corners must have shape \(4, 3\)"),
        ("colour", "red", "unknown field"),
    ):
        broken = tmp_path / f"{key}.json"
        broken.write_text(json.dumps({**scene, key: value}))
        with pytest.raises(ValueError, match=expected):
            read_metadata(broken)
    broken.write_text("{ not json")
    with pytest.raises(ValueError, match="invalid JSON"):
        read_metadata(broken)


def test_scene_is_frozen_and_validated():
    scene = read_metadata(TEXT)[0]
    with pytest.raises(AttributeError):
        scene.n_cols = 5
    with pytest.raises(ValueError):
        scene.corners[0, 0] = 0.0  # read-only array
    with pytest.raises(ValueError, match="latitude"):
        SceneMetadata("x", 10, 10, [[0, 95, 0]] * 4, 6e5, 0.0)
    assert scene != read_metadata(TEXT)[1]
