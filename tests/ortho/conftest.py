"""Shared fixtures for the orthorectification tests: index images, ellipsoidal DEM crops."""

import numpy as np
import pytest
import rasterio
from affine import Affine

VENTOUX_ORIGIN = (5000.0, 5000.0)  # model pixel of left_image.tif's first pixel


def write_index_image(path, width, height):
    """A 2-band float64 image holding each pixel's own column and row (jaxgeo convention)."""
    col, row = np.meshgrid(np.arange(width, dtype=float), np.arange(height, dtype=float))
    with rasterio.open(path, "w", driver="GTiff", width=width, height=height, count=2,
                       dtype="float64") as dst:  # fmt: skip
        dst.write(np.stack([col, row]))
    return path


def write_dem(path, z, west, north, step):
    profile = dict(driver="GTiff", width=z.shape[1], height=z.shape[0], count=1, dtype="float64",
                   crs="EPSG:4326", transform=Affine(step, 0, west, 0, -step, north),
                   nodata=np.nan)  # fmt: skip
    with rasterio.open(path, "w", **profile) as dst:
        dst.write(z, 1)
    return path


@pytest.fixture(scope="session")
def ventoux_dem_ellipsoidal(real_data, tmp_path_factory):
    """SRTM N44E005 + EGM96 (the shared crop) over lon 5.10..5.30, lat 44.12..44.30: ellipsoidal."""
    from jaxgeo.io._geoid import read_geoid

    dem_dir = real_data / "ventoux" / "dem"
    geoid = read_geoid(dem_dir / "egm96_15_crop_lon3-8_lat42-47.gtx")
    with rasterio.open(dem_dir / "N44E005_srtm90.tif") as src:
        t = src.transform
        c0, r0 = int((5.10 - t.c) / t.a), int((t.f - 44.30) / -t.e)
        c1, r1 = int((5.30 - t.c) / t.a), int((t.f - 44.12) / -t.e)
        win = rasterio.windows.Window(c0, r0, c1 - c0, r1 - r0)
        z = src.read(1, window=win, masked=True).astype(float).filled(np.nan)
        wt = src.window_transform(win)
    rr, cc = np.mgrid[0 : z.shape[0], 0 : z.shape[1]]
    lon, lat = wt.c + (cc + 0.5) * wt.a, wt.f + (rr + 0.5) * wt.e
    z = z + geoid(lon, lat)
    path = tmp_path_factory.mktemp("dem") / "ventoux_ellipsoidal.tif"
    return write_dem(path, z, wt.c, wt.f, wt.a)


@pytest.fixture(scope="session")
def nice_dem_synthetic(tmp_path_factory):
    """Smooth synthetic hills (ellipsoidal, 0..400 m) around the Pleiades Nice scene (no SRTM
    tile of the shared data covers it)."""
    step = 1.0 / 1200.0
    west, north = 7.0, 43.78
    n = 120
    rr, cc = np.mgrid[0:n, 0:n]
    lon, lat = west + (cc + 0.5) * step, north - (rr + 0.5) * step
    z = 200 + 150 * np.sin(lon * 400.0) * np.cos(lat * 300.0) + 50 * np.cos(lon * 900.0)
    path = tmp_path_factory.mktemp("dem") / "nice_synthetic.tif"
    return write_dem(path, z, west, north, step)
