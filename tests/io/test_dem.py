"""``read_dem``: bilinear heights from GeoTIFFs in geographic and UTM CRSs, clear errors."""

import numpy as np
import pyproj
import pytest
import rasterio
from affine import Affine

from jaxgeo.io import DEM, read_dem

LON0, LAT0, STEP = 74.0, 27.5, 0.01  # upper-left corner, pixel size (deg)


def from_origin(west, north, xsize, ysize):  # rasterio's, without its deprecated Affine `*`
    return Affine(xsize, 0.0, west, 0.0, -ysize, north)


def _write(path, z, crs, transform, nodata=None, count=1):
    profile = dict(driver="GTiff", height=z.shape[0], width=z.shape[1], count=count,
                   dtype="float64", crs=crs, transform=transform, nodata=nodata)  # fmt: skip
    with rasterio.open(path, "w", **profile) as dst:
        for b in range(1, count + 1):
            dst.write(z, b)
    return path


def _plane(x, y):
    return 250.0 + 1200.0 * (x - LON0) - 800.0 * (y - LAT0)


def _geographic(tmp_path, rows=30, cols=40, name="geo.tif", **kw):
    col, row = np.meshgrid(np.arange(cols) + 0.5, np.arange(rows) + 0.5)  # pixel centres
    z = _plane(LON0 + col * STEP, LAT0 - row * STEP)
    return _write(tmp_path / name, z, "EPSG:4326", from_origin(LON0, LAT0, STEP, STEP), **kw), z


def test_geographic_plane_is_exact(tmp_path):
    path, _ = _geographic(tmp_path)
    dem = read_dem(path)
    assert isinstance(dem, DEM) and dem.crs is None and dem.shape == (30, 40)
    rng = np.random.default_rng(0)
    # anywhere between the first and last pixel centres: bilinear reproduces a plane exactly
    lonlat = np.stack([rng.uniform(LON0 + 0.005, LON0 + 0.395, 200),
                       rng.uniform(LAT0 - 0.295, LAT0 - 0.005, 200)], axis=-1)  # fmt: skip
    np.testing.assert_allclose(dem(lonlat), _plane(*lonlat.T), atol=1e-9)
    assert dem(lonlat[:6].reshape(3, 2, 2)).shape == (3, 2)
    # the outer half pixel holds the edge value across the edge
    edge = np.array([[LON0 + 0.001, LAT0 - 0.1234]])
    np.testing.assert_allclose(dem(edge), _plane(LON0 + 0.005, LAT0 - 0.1234), atol=1e-9)
    np.testing.assert_allclose(read_dem(path, offset_m=-42.5)(lonlat), dem(lonlat) - 42.5)
    b = dem.bounds_lonlat
    np.testing.assert_allclose(b, (LON0, LAT0 - 0.3, LON0 + 0.4, LAT0), atol=1e-9)


def test_utm_plane_is_exact(tmp_path):
    utm = pyproj.CRS.from_epsg(32643)  # UTM 43N, central meridian 75 E
    to_utm = pyproj.Transformer.from_crs(4326, utm, always_xy=True)
    e0, n0 = (round(v, -3) for v in to_utm.transform(74.4, 27.3))
    res, rows, cols = 30.0, 50, 60
    col, row = np.meshgrid(np.arange(cols) + 0.5, np.arange(rows) + 0.5)
    e, n = e0 + col * res, n0 - row * res

    def plane(e, n):
        return 500.0 + 0.02 * (e - e0) - 0.01 * (n - n0)

    path = _write(tmp_path / "utm.tif", plane(e, n), utm, from_origin(e0, n0, res, res))
    dem = read_dem(path)
    assert dem.crs is not None
    rng = np.random.default_rng(1)
    en = np.stack([rng.uniform(e0 + 20, e0 + 1770, 100), rng.uniform(n0 - 1470, n0 - 20, 100)], -1)
    lon, lat = pyproj.Transformer.from_crs(utm, 4326, always_xy=True).transform(*en.T)
    np.testing.assert_allclose(dem(np.stack([lon, lat], -1)), plane(*en.T), atol=1e-6)
    with pytest.raises(ValueError, match="outside the DEM"):
        dem(np.array([[74.0, 27.0]]))


def test_outside_and_nodata_are_refused(tmp_path):
    path, z = _geographic(tmp_path)
    dem = read_dem(path)
    far = np.array([[LON0 + 0.1, LAT0 - 0.1], [LON0 + 0.5, LAT0 - 0.1], [LON0 - 1, LAT0 + 1]])
    with pytest.raises(ValueError, match=r"2 of 3 points lie outside the DEM") as err:
        dem(far)
    assert str(path) in str(err.value) and "lon 73.00000..74.50000" in str(err.value)
    z = z.copy()
    z[10, 20] = -9999.0  # centre at lon0 + 0.205, lat0 - 0.105
    path = _write(tmp_path / "holes.tif", z, "EPSG:4326", from_origin(LON0, LAT0, STEP, STEP),
                  nodata=-9999.0)  # fmt: skip
    dem = read_dem(path)
    near = np.array([[LON0 + 0.21, LAT0 - 0.1], [LON0 + 0.3, LAT0 - 0.2]])
    with pytest.raises(ValueError, match=r"holes.tif: 1 of 2 points fall on nodata cells"):
        dem(near)
    # at the neighbouring pixel centre the void has zero weight: still a valid height
    ok = np.array([[LON0 + 0.215, LAT0 - 0.105]])
    np.testing.assert_allclose(dem(ok), _plane(*ok.T), atol=1e-9)
    z[10, 20] = np.nan  # NaN voids without a nodata value
    dem = read_dem(_write(tmp_path / "nan.tif", z, "EPSG:4326",
                          from_origin(LON0, LAT0, STEP, STEP)))  # fmt: skip
    with pytest.raises(ValueError, match="nodata"):
        dem(near)
    with pytest.raises(ValueError, match="non-finite"):
        dem(np.array([[np.nan, 27.0]]))


def test_bad_files(tmp_path):
    with pytest.raises(FileNotFoundError, match="missing.tif"):
        read_dem(tmp_path / "missing.tif")
    (tmp_path / "text.tif").write_text("not a raster\n")
    with pytest.raises(ValueError, match="text.tif: not a raster"):
        read_dem(tmp_path / "text.tif")
    _, z = _geographic(tmp_path)
    t = from_origin(LON0, LAT0, STEP, STEP)
    with pytest.raises(ValueError, match="one band, this raster has 2"):
        read_dem(_write(tmp_path / "two.tif", z, "EPSG:4326", t, count=2))
    with pytest.raises(ValueError, match="no CRS"):
        read_dem(_write(tmp_path / "nocrs.tif", z, None, t))
