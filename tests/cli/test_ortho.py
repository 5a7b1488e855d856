"""``jaxgeo ortho`` on a real crop, and every bad input refused before any computation: exit 2,
one line naming the problem, no traceback, no output, no temporary file left, inputs unchanged.

The Ventoux Pleiades crop (500 x 500 px, a pixel-space geotransform at 5000, 5000 of the
product its model describes) on SRTM with the EGM96 undulation.
"""

import hashlib
import json

import numpy as np
import pytest
import rasterio

from jaxgeo.cli import main
from tests.ortho.conftest import write_dem

OUTSIDE_BOUNDS = ["600000", "4800000", "601000", "4801000"]  # UTM 31N, 100 km away


@pytest.fixture(scope="module")
def crop(real_data):
    d = real_data / "ventoux"
    return {
        "image": d / "left_image.tif",
        "model": real_data / "phr_ventoux__left_image.geom",
        "dem": d / "dem" / "N44E005_srtm90.tif",
        "geoid": d / "dem" / "egm96_15_crop_lon3-8_lat42-47.gtx",
    }


def _args(crop, out, *extra):
    return ["ortho", str(crop["image"]), "--model", str(crop["model"]), "--dem", str(crop["dem"]),
            "--geoid", str(crop["geoid"]), "-o", str(out), "--quiet", *extra]  # fmt: skip


def _digests(crop):
    return {k: hashlib.sha256(p.read_bytes()).hexdigest() for k, p in crop.items()}


def test_a_crop_is_orthorectified_in_its_own_pixel_frame(crop, tmp_path, capsys):
    before = _digests(crop)
    out = tmp_path / "ortho.tif"
    assert main(_args(crop, out, "--json")) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["path"] == str(out) and report["crs"] == "EPSG:32631"
    assert report["valid_fraction"] > 0.85 and report["grid_error_px"] < 0.01
    assert report["workers"] == 0 and report["empty_tiles"] == 0
    # the origin given explicitly: the same product (the frame came from the geotransform)
    same = tmp_path / "same.tif"
    assert main(_args(crop, same, "--image-origin", "5000,5000")) == 0
    with rasterio.open(out) as a, rasterio.open(same) as b:
        assert a.transform == b.transform and np.array_equal(a.read(), b.read())
        assert a.overviews(1) and a.profile["tiled"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ortho.tif", "same.tif"]
    assert _digests(crop) == before


CASES = {
    "output is the image": (lambda c, t: c["image"], ["--overwrite"], "is an input"),
    "output is the DEM": (lambda c, t: c["dem"], ["--overwrite"], "is an input"),
    "output is the model": (lambda c, t: c["model"], ["--overwrite"], "is an input"),
    "output folder missing": (lambda c, t: t / "no" / "o.tif", [], "does not exist"),
    "invalid CRS": (None, ["--crs", "EPSG:99999"], "invalid CRS 'EPSG:99999'"),
    "zero resolution": (None, ["--res", "0"], "resolution must be > 0"),
    "negative resolution": (None, ["--res", "-2"], "resolution must be > 0"),
    "degrees as metres": (None, ["--crs", "EPSG:4326", "--res", "0.5"],
                          "degrees given as metres"),
    "bounds outside the footprint": (None, ["--crs", "EPSG:32631", "--bounds", *OUTSIDE_BOUNDS],
                                     "lie outside the footprint"),
    "empty bounds": (None, ["--crs", "EPSG:32631", "--bounds", "1", "1", "0", "2"],
                     "are empty"),
    "bounds without a CRS": (None, ["--bounds", *OUTSIDE_BOUNDS], "need the output CRS"),
    "1 x 1 px": (None, ["--res", "1e6"], "far coarser than the footprint"),
    "too many pixels": (None, ["--res", "0.0005"], "over the limit of 2e+09 px"),
    "limit given": (None, ["--max-pixels", "1000"], "over the limit of 1e+03 px"),
    "origin conflicts with the crop's frame": (None, ["--image-origin", "0,0"], "conflicts"),
    "negative workers": (None, ["--workers", "-1"], "--workers must be >= 0"),
    "plan file is an input": (None, ["--plan", "DEM"], "is an input"),
    "resume is a file": (None, ["--resume", "IMAGE"], "is not a folder"),
}  # fmt: skip


@pytest.mark.parametrize("case", CASES)
def test_bad_input_is_refused_and_nothing_changes(case, crop, tmp_path, capsys):
    where, extra, message = CASES[case]
    before = _digests(crop)
    out = where(crop, tmp_path) if where else tmp_path / "ortho.tif"
    extra = [str(crop["dem"]) if a == "DEM" else str(crop["image"]) if a == "IMAGE" else a
             for a in extra]  # fmt: skip
    assert main(_args(crop, out, *extra)) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err and err.count("\n") == 1, err
    assert err.startswith("jaxgeo ortho: error: ")
    assert list(tmp_path.iterdir()) == []  # no output, nothing temporary left
    assert _digests(crop) == before


def test_existing_output_is_kept(crop, tmp_path, capsys):
    out = tmp_path / "ortho.tif"
    out.write_bytes(b"keep")
    assert main(_args(crop, out)) == 2
    assert "exists; pass --overwrite" in capsys.readouterr().err
    assert out.read_bytes() == b"keep"


def test_image_without_any_model(tmp_path, crop, capsys):
    plain = tmp_path / "plain.tif"
    with rasterio.open(plain, "w", driver="GTiff", width=8, height=8, count=1,
                       dtype="uint8") as dst:  # fmt: skip
        dst.write(np.zeros((1, 8, 8), dtype="uint8"))
    out = tmp_path / "out.tif"
    assert main(["ortho", str(plain), "--dem", str(crop["dem"]), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "plain.tif" in err and "no sensor model" in err
    assert not out.exists()


def test_dem_not_covering_the_footprint(tmp_path, crop, capsys):
    step = 1e-4  # a 20 x 20 m DEM far from the crop
    dem = write_dem(tmp_path / "small.tif", np.zeros((2, 2)), 5.0, 44.5, step)
    out = tmp_path / "out.tif"
    args = ["ortho", str(crop["image"]), "--model", str(crop["model"]), "--dem", str(dem),
            "-o", str(out)]  # fmt: skip
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "small.tif" in err and "covers only" in err and "% of the footprint" in err
    assert not out.exists()
