"""A jaxgeo DSM as a DEM (its band described ``height``), ``band=``, and holes filled from a
second DEM in another CRS and another vertical reference (``read_dem(..., fill=)``)."""

import dataclasses

import numpy as np
import pyproj
import pytest
import rasterio
from affine import Affine

from jaxgeo.errors import JaxgeoWarning
from jaxgeo.io import read_dem
from jaxgeo.io._dem import FILL_MISMATCH_M
from jaxgeo.io._geoid import read_geoid
from jaxgeo.io.internal import dem_coverage
from jaxgeo.stereo._dsm import DSM_BANDS, DSMGrid, write_dsm

EPSG = 32631  # UTM 31N, over Mont Ventoux (EGM96 undulation ~ 50 m there)
X0, Y0, RES = 680_000.0, 4_896_000.0, 10.0  # DSM upper-left corner (m), cell size
ROWS, COLS = 60, 80
TO_LL = pyproj.Transformer.from_crs(EPSG, 4326, always_xy=True)
TO_MAP = pyproj.Transformer.from_crs(4326, EPSG, always_xy=True)


def _truth(lon, lat):
    """The true surface, ellipsoidal m: a plane in lon/lat (exact under bilinear in lon/lat)."""
    return 1200.0 + 3000.0 * (lon - 5.2) - 2000.0 * (lat - 44.2)


def _write_dsm(path, hole=(slice(20, 35), slice(30, 50))):
    """A DSM as jaxgeo.stereo writes it over the plane, NaN in ``hole`` (rows, cols)."""
    cc, rr = np.meshgrid(np.arange(COLS) + 0.5, np.arange(ROWS) + 0.5)
    lon, lat = TO_LL.transform(X0 + cc * RES, Y0 - rr * RES)
    h = _truth(lon, lat)
    h[hole] = np.nan
    count = np.where(np.isfinite(h), 3.0, 0.0)
    grid = DSMGrid(h.astype(np.float32), count, np.zeros_like(h), X0, Y0, RES, EPSG)
    return write_dsm(grid, path)


def _write_geographic(path, lon0, lat0, step, shape, orthometric_geoid=None):
    """A coarse lon/lat DEM of the plane; with ``orthometric_geoid``, its values are the
    orthometric heights ``H = h - N`` (as SRTM's are)."""
    rows, cols = shape
    cc, rr = np.meshgrid(np.arange(cols) + 0.5, np.arange(rows) + 0.5)
    lon, lat = lon0 + cc * step, lat0 - rr * step
    z = _truth(lon, lat)
    if orthometric_geoid is not None:
        z = z - orthometric_geoid(lon, lat)
    profile = dict(driver="GTiff", height=rows, width=cols, count=1, dtype="float64",
                   crs="EPSG:4326", transform=Affine(step, 0, lon0, 0, -step, lat0))  # fmt: skip
    with rasterio.open(path, "w", **profile) as dst:
        dst.write(z, 1)
    return path


def _hole_points():
    """lon/lat of points well inside the DSM's hole, and inside its valid cells."""
    hole = np.array([[X0 + 40 * RES, Y0 - 27 * RES], [X0 + 35 * RES, Y0 - 30 * RES]])
    valid = np.array([[X0 + 10 * RES, Y0 - 10 * RES], [X0 + 70 * RES, Y0 - 50 * RES]])
    return [np.stack(TO_LL.transform(p[:, 0], p[:, 1]), -1) for p in (hole, valid)]


def test_jaxgeo_dsm_is_read_at_its_height_band(tmp_path):
    path = _write_dsm(tmp_path / "dsm.tif")
    dem = read_dem(path)
    assert dem.band == list(DSM_BANDS).index("height") + 1  # found by its description
    assert dem.height_reference == "ellipsoidal" and "DEM dsm.tif" in dem.describe()
    in_hole, valid = _hole_points()
    np.testing.assert_allclose(dem(valid), _truth(*valid.T), atol=0.02)  # float32, bilinear
    with pytest.raises(ValueError, match=r"dsm.tif: 2 of 2 points fall on nodata cells.*fill"):
        dem(in_hole)
    assert np.isnan(dem.sample(in_hole)).all()
    # the DSM declares ellipsoidal heights: a geoid would add the undulation a second time
    with pytest.raises(ValueError, match="dsm.tif: a jaxgeo DSM: its heights are ellipsoidal"):
        read_dem(path, geoid="egm96")
    with pytest.raises(ValueError, match="a jaxgeo DSM"):
        read_dem(path, height="orthometric")
    # another band by number (the count band: 3 where there are heights)
    count = read_dem(path, band=list(DSM_BANDS).index("count") + 1)
    np.testing.assert_allclose(count(valid), 3.0)


def test_other_multiband_rasters_need_a_band(tmp_path):
    z = np.full((10, 12), 100.0)
    profile = dict(driver="GTiff", height=10, width=12, count=3, dtype="float64",
                   crs="EPSG:4326", transform=Affine(0.01, 0, 5.0, 0, -0.01, 44.3))  # fmt: skip
    with rasterio.open(tmp_path / "rgb.tif", "w", **profile) as dst:
        for b in (1, 2, 3):
            dst.write(z * b, b)
        dst.set_band_description(1, "red")
    with pytest.raises(
        ValueError,
        match=r"rgb.tif: a DEM must have one band, this raster has "
        r"3 \(1: 'red'\) and none described 'height'.*band=N",
    ):
        read_dem(tmp_path / "rgb.tif")
    dem = read_dem(tmp_path / "rgb.tif", band=2)
    np.testing.assert_allclose(dem(np.array([[5.05, 44.25]])), 200.0)
    assert "(band 2)" in dem.describe()
    for band in (0, 4, True):
        with pytest.raises(ValueError, match=r"is not a band of this raster \(1..3\)"):
            read_dem(tmp_path / "rgb.tif", band=band)


def test_an_orthometric_dem_fills_an_ellipsoidal_dsm(tmp_path):
    """The rule: each DEM makes its own values ellipsoidal (the DSM as declared, SRTM-like
    orthometric heights with their geoid) before one fills the other."""
    egm96 = read_geoid("egm96")
    dsm = _write_dsm(tmp_path / "dsm.tif")
    srtm = _write_geographic(tmp_path / "srtm.tif", 5.05, 44.30, 0.002, (120, 160), egm96)
    fill = read_dem(srtm, geoid="egm96")
    dem = read_dem(dsm, fill=fill)
    in_hole, valid = _hole_points()
    n_m = egm96(in_hole[:, 0], in_hole[:, 1])
    assert np.all((n_m > 45) & (n_m < 55))  # the undulation the rule must not lose
    np.testing.assert_allclose(dem(in_hole), _truth(*in_hole.T), atol=0.05)
    np.testing.assert_allclose(dem(valid), _truth(*valid.T), atol=0.02)  # the DSM's own
    assert abs(dem.fill_difference_m) < 0.05
    assert "its holes filled from DEM srtm.tif: orthometric heights" in dem.describe()
    # beyond the DSM's edges, inside the fill's: the fill's heights
    beyond = np.array([[5.10, 44.25], [5.30, 44.10]])
    assert np.isnan(read_dem(dsm).sample(beyond)).all()
    np.testing.assert_allclose(dem(beyond), _truth(*beyond.T), atol=0.05)
    with pytest.raises(
        ValueError,
        match=r"1 of 1 points have no height, neither in this DEM "
        r"nor in its fill .*srtm.tif",
    ):
        dem(np.array([[6.0, 44.2]]))
    # the grid over the hole (UTM, the DSM's cells): every cell filled, ellipsoidal
    lo, hi = in_hole.min(0) - 0.001, in_hole.max(0) + 0.001
    grid = dem.grid((lo[0], lo[1], hi[0], hi[1]))
    z = np.asarray(grid.heights_m)
    assert grid.utm_zone == 31 and np.isfinite(z).all()
    rows, cols = np.meshgrid(np.arange(z.shape[0]), np.arange(z.shape[1]), indexing="ij")
    x, y = grid.origin[0] + cols * grid.step[0], grid.origin[1] + rows * grid.step[1]
    np.testing.assert_allclose(z, _truth(*TO_LL.transform(x, y)), atol=0.05)
    # the same fill with its geoid forgotten: warned, with the size of the mismatch
    with pytest.warns(
        JaxgeoWarning,
        match=r"dsm.tif: its heights are \+5\d\.\d m from those "
        r"of its fill DEM .*srtm.tif",
    ):
        wrong = read_dem(dsm, fill=read_dem(srtm))
    assert wrong.fill_difference_m > FILL_MISMATCH_M


def test_coverage_of_a_dem_and_its_fill(tmp_path):
    dsm = _write_dsm(tmp_path / "dsm.tif")  # lon 5.2525..5.2623, lat 44.1894..44.1950
    # a fill over the DSM's eastern half and beyond, to 5.30 E, 44.15..44.20 N
    small = _write_geographic(tmp_path / "small.tif", 5.258, 44.20, 0.002, (25, 21))
    own = read_dem(dsm)
    dem = read_dem(dsm, fill=read_dem(small))
    a, b = own.bounds_lonlat, read_dem(small).bounds_lonlat
    assert dem.own_bounds_lonlat == a
    assert dem.bounds_lonlat == (min(a[0], b[0]), min(a[1], b[1]), max(a[2], b[2]),
                                 max(a[3], b[3]))  # fmt: skip
    w, s, e, n = a
    east = (w + 0.5 * (e - w), s, 5.28, n)  # half on the DSM, the rest on the fill only
    assert dem_coverage(own, east) < 0.9 and dem_coverage(dem, east) == pytest.approx(1.0)
    assert dem_coverage(dem, a) == pytest.approx(1.0)
    assert dem_coverage(dem, (5.4, 44.0, 5.5, 44.1)) == 0.0
    # exact for a union of boxes: a box around both holds their areas less their overlap
    box = (min(a[0], b[0]) - 0.01, min(a[1], b[1]), max(a[2], b[2]), max(a[3], b[3]) + 0.01)
    area = (box[2] - box[0]) * (box[3] - box[1])
    overlap = (min(a[2], b[2]) - max(a[0], b[0])) * (min(a[3], b[3]) - max(a[1], b[1]))
    union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - overlap
    assert dem_coverage(dem, box) == pytest.approx(union / area, rel=1e-9)
    assert dem_coverage(dem, box) < 0.9


def test_a_filled_dem_reopens_on_a_worker(tmp_path):
    """The ortho tiles open the DEM again from its description: band and fill included."""
    from jaxgeo.ortho._job import DEMSource, _open_dem

    dsm = _write_dsm(tmp_path / "dsm.tif")
    srtm = _write_geographic(tmp_path / "srtm.tif", 5.05, 44.30, 0.002, (120, 160),
                             read_geoid("egm96"))  # fmt: skip
    dem = read_dem(dsm, fill=read_dem(srtm, geoid="egm96"))
    source = DEMSource.of(dem)
    assert source.band == dem.band and source.fill.geoid == "egm96"  # by name: any machine
    assert dataclasses.asdict(source)["fill"]["path"] == str(srtm)  # in the job's JSON
    again = _open_dem(source)
    in_hole, _ = _hole_points()
    np.testing.assert_allclose(again(in_hole), dem(in_hole), atol=1e-9)
    assert dem.inputs[:2] == [dsm, srtm]  # and the geoid's file


def test_a_fine_dem_asked_for_far_beyond_its_edges_is_averaged(tmp_path, monkeypatch):
    """A 10 m DSM filled over a box 30 times its size: its cells averaged, not a huge grid."""
    from jaxgeo.io import _dem_grid

    dsm = _write_dsm(tmp_path / "dsm.tif")
    srtm = _write_geographic(tmp_path / "srtm.tif", 5.05, 44.30, 0.002, (120, 160))
    dem = read_dem(dsm, fill=read_dem(srtm))
    box = (5.15, 44.12, 5.33, 44.26)
    full = dem.grid(box)
    monkeypatch.setattr(_dem_grid, "MAX_FILLED_CELLS", 10_000)
    small = dem.grid(box)
    z = np.asarray(small.heights_m)
    assert z.size <= 10_000 < np.asarray(full.heights_m).size and np.isfinite(z).all()
    assert abs(small.step[0]) > 2 * RES  # coarser cells, the same UTM frame
    rows, cols = np.meshgrid(np.arange(z.shape[0]), np.arange(z.shape[1]), indexing="ij")
    x, y = small.origin[0] + cols * small.step[0], small.origin[1] + rows * small.step[1]
    err = np.abs(z - _truth(*TO_LL.transform(x, y)))
    # exact but for coarse cells across the DSM's edges and hole: their average is over the
    # part the DSM covers, off the cell's centre on this 4 % slope (a few metres at most)
    assert np.median(err) < 0.01 and (err > 0.5).mean() < 0.01 and err.max() < 3.0
