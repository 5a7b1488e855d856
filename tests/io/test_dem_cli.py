"""The DEM options on the command line: a DEM that covers ``ortho --bounds`` is enough (the real
Ventoux crop on a piece of SRTM), and the new options' bad uses are named errors (exit 2)."""

import json

import numpy as np
import pyproj
import pytest
import rasterio

from jaxgeo.cli import main
from jaxgeo.io import open_image, read_dem


@pytest.fixture(scope="module")
def crop(real_data):
    d = real_data / "ventoux"
    return {
        "image": d / "left_image.tif",
        "model": real_data / "phr_ventoux__left_image.geom",
        "dem": d / "dem" / "N44E005_srtm90.tif",
    }


def _footprint(crop):
    """lon/lat of the crop's corners and centre on SRTM + EGM96 (three fixed-point steps)."""
    image = open_image(crop["image"], model=crop["model"])
    dem = read_dem(crop["dem"], geoid="egm96")
    w, h = image.size
    xy = np.array([[-0.5, -0.5], [w - 0.5, -0.5], [-0.5, h - 0.5], [w - 0.5, h - 0.5],
                   [(w - 1) / 2, (h - 1) / 2]])  # fmt: skip
    z = np.full(len(xy), 1000.0)
    for _ in range(3):
        g = np.asarray(image.model.localize(xy, z))
        z = dem(g[:, :2])
    return g[:, :2]


def _sub_dem(src_path, out, west, south, east, north):
    """The cells of ``src_path`` over a lon/lat box (whole cells), as a new GeoTIFF."""
    with rasterio.open(src_path) as src:
        win = rasterio.windows.from_bounds(west, south, east, north, src.transform)
        win = win.round_offsets(op="floor").round_lengths(op="ceil")
        z = src.read(1, window=win)
        profile = {**src.profile, "width": z.shape[1], "height": z.shape[0],
                   "transform": src.window_transform(win)}  # fmt: skip
    with rasterio.open(out, "w", **profile) as dst:
        dst.write(z, 1)
    return out


def test_a_dem_that_covers_the_bounds_is_enough(crop, tmp_path, capsys):
    ll = _footprint(crop)
    west, east = ll[:4, 0].min(), ll[:4, 0].max()
    centre = ll[4]
    # SRTM cells (~65 x 90 m) over the western part of the footprint only
    part = _sub_dem(crop["dem"], tmp_path / "west.tif", west - 0.002, ll[:4, 1].min() - 0.002,
                    centre[0], ll[:4, 1].max() + 0.002)  # fmt: skip
    dem = read_dem(part, geoid="egm96")
    assert dem.bounds_lonlat[2] < east  # it does not reach the footprint's eastern edge
    base = ["ortho", str(crop["image"]), "--model", str(crop["model"]), "--dem", str(part),
            "--geoid", "egm96", "--quiet", "--json"]  # fmt: skip
    assert main([*base, "-o", str(tmp_path / "whole.tif")]) == 2
    assert "% of the footprint of" in capsys.readouterr().err
    # bounds: 60 x 60 m around a point 40 m west of the footprint's centre, in UTM 31N
    x, y = pyproj.Transformer.from_crs(4326, 32631, always_xy=True).transform(*centre)
    bounds = [x - 100.0, y - 30.0, x - 40.0, y + 30.0]
    out = tmp_path / "bounds.tif"
    code = main([*base, "--crs", "EPSG:32631", "--bounds", *map(str, bounds), "-o", str(out)])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    report = json.loads(captured.out.strip().splitlines()[-1])
    assert report["valid_fraction"] == pytest.approx(1.0)
    assert "warning" not in captured.err  # no border-on-nodata warning: the bounds are covered
    with rasterio.open(out) as src:
        assert src.bounds.left == pytest.approx(bounds[0]) and src.crs.to_epsg() == 32631


def _write(path, count, descriptions=(), tags=None):
    t = rasterio.Affine(0.01, 0, 5.1, 0, -0.01, 44.3)
    profile = dict(driver="GTiff", width=20, height=20, count=count, dtype="float32",
                   crs="EPSG:4326", transform=t)  # fmt: skip
    with rasterio.open(path, "w", **profile) as dst:
        for b in range(1, count + 1):
            dst.write(np.full((20, 20), 900.0, np.float32), b)
        for b, d in enumerate(descriptions, start=1):
            dst.set_band_description(b, d)
        if tags:
            dst.update_tags(**tags)
    return path


@pytest.mark.parametrize(
    ("extra", "words"),
    [
        (["--dem", "{two}"], "this raster has 2 (1: 'a', 2: 'b')... (--dem-band N)"),
        (["--dem", "{two}", "--dem-band", "3"], "band 3 is not a band of this raster (1..2)"),
        (["--dem", "{dsm}", "--geoid", "egm96"], "a jaxgeo DSM: its heights are ellipsoidal"),
        (["--dem", "{one}", "--dem-fill-geoid", "egm96"], "--dem-fill-geoid needs --dem-fill"),
        (["--dem", "{one}", "--dem-fill", "{missing}"], "missing.tif: DEM file not found"),
        (["--dem", "{one}", "--dem-fill", "{two}"], "--dem-fill: {two}: a DEM must have one band"),
    ],
)
def test_bad_dem_options_are_named(crop, tmp_path, capsys, extra, words):
    files = {
        "one": _write(tmp_path / "one.tif", 1),
        "two": _write(tmp_path / "two.tif", 2, ("a", "b")),
        "dsm": _write(
            tmp_path / "dsm.tif", 2, ("height", "count"), {"heights": "ellipsoidal (WGS84), m"}
        ),  # fmt: skip
        "missing": tmp_path / "missing.tif",
    }
    argv = ["ortho", str(crop["image"]), "--model", str(crop["model"]), "--quiet",
            "-o", str(tmp_path / "out.tif"), *(e.format(**files) for e in extra)]  # fmt: skip
    assert main(argv) == 2
    err = capsys.readouterr().err
    for part in words.format(**files).split("..."):
        assert part in err, err
    assert "Traceback" not in err and not (tmp_path / "out.tif").exists()


def test_dsm_heights_range_tolerates_holes_of_a_dsm_dem(crop, tmp_path):
    """``dsm``/``match --dem dsm.tif``: a point of the ROI's 5 x 5 grid on a hole of the DSM
    takes the others' median height (it was an error); a DEM far away is still named."""
    from jaxgeo.stereo._dsm import DSMGrid, write_dsm
    from jaxgeo.stereo._ties import TieError, footprint_dem_heights

    ll = _footprint(crop)
    srtm = read_dem(crop["dem"], geoid="egm96")
    to_map = pyproj.Transformer.from_crs(4326, 32631, always_xy=True)
    x, y = to_map.transform(ll[:, 0], ll[:, 1])
    x0, y0, res = np.floor(x.min()) - 100, np.ceil(y.max()) + 100, 2.0
    rows, cols = int((y0 - y.min() + 100) / res), int((x.max() + 100 - x0) / res)
    cc, rr = np.meshgrid(x0 + (np.arange(cols) + 0.5) * res, y0 - (np.arange(rows) + 0.5) * res)
    lon, lat = pyproj.Transformer.from_crs(32631, 4326, always_xy=True).transform(cc, rr)
    h = srtm(np.stack([lon, lat], -1))
    cx, cy = to_map.transform(*ll[4])
    h[np.hypot(cc - cx, rr - cy) < 40] = np.nan  # a hole under the crop's centre
    path = write_dsm(DSMGrid(h.astype(np.float32), np.ones_like(h), np.zeros_like(h), x0, y0,
                             res, 32631), tmp_path / "dsm.tif")  # fmt: skip
    image = open_image(crop["image"], model=crop["model"])
    dsm = read_dem(path)
    with pytest.raises(ValueError, match="nodata cells"):
        dsm(ll[4:5])  # the centre of the ROI's grid is on the hole
    lo, hi = footprint_dem_heights(image.model, dsm, (0, 0, *image.size))
    ref = footprint_dem_heights(image.model, srtm, (0, 0, *image.size))
    # the DSM is SRTM resampled: its range lies within SRTM's over its (wider, 90 m) cells
    assert ref[0] - 0.01 <= lo < hi <= ref[1] + 0.01 and hi - lo > 20
    far = write_dsm(DSMGrid(h.astype(np.float32), np.ones_like(h), np.zeros_like(h),
                            x0 + 5000, y0, res, 32631), tmp_path / "far.tif")  # fmt: skip
    with pytest.raises((TieError, ValueError), match="far.tif"):
        footprint_dem_heights(image.model, read_dem(far), (0, 0, *image.size))
