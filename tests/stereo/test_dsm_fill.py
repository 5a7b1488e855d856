"""DSM rasterisation fills like s2p (issue 27, item 7): no pinhole lattice when the points'
spacing aliases against the cells, small holes interpolated from their rim and flagged in the
``filled`` band, large voids and holes at the grid's edge left empty; named bands on file."""

import numpy as np
import pytest
import rasterio

from jaxgeo.stereo import DSM_BANDS, DSMGrid, rasterize, write_dsm
from jaxgeo.stereo._dsm import laplace_fill, small_holes, to_map

EPSG = 32631
X0, Y0 = 698000.0, 4793000.0  # grid origin (upper-left), metres, UTM 31N
SIZE_M = 60.0


def _lattice(spacing_m=0.52, angle_deg=10.0):
    """Points on a rotated lattice (the epipolar pixel grid seen on the ground) over a plane
    rising 5 cm per metre east and 2 cm per metre south: lon/lat/h and map x/y."""
    n = int(SIZE_M * 1.6 / spacing_m)
    i, j = np.meshgrid(np.arange(-n // 2, n // 2), np.arange(-n // 2, n // 2))
    a = np.radians(angle_deg)
    u, v = spacing_m * i.ravel(), spacing_m * j.ravel()
    x = X0 + SIZE_M / 2 + np.cos(a) * u - np.sin(a) * v
    y = Y0 - SIZE_M / 2 + np.sin(a) * u + np.cos(a) * v
    keep = (x > X0 + 1) & (x < X0 + SIZE_M - 1) & (y < Y0 - 1) & (y > Y0 - SIZE_M + 1)
    x, y = x[keep], y[keep]
    import pyproj

    lon, lat = pyproj.Transformer.from_crs(EPSG, 4326, always_xy=True).transform(x, y)
    h = 100.0 + 0.05 * (x - X0) + 0.02 * (Y0 - y)
    return np.stack([lon, lat, h], axis=1), x, y


def _plane(dsm):
    rows, cols = dsm.height.shape
    xc = dsm.x0 + (np.arange(cols) + 0.5) * dsm.res_m
    yc = dsm.y0 - (np.arange(rows) + 0.5) * dsm.res_m
    return 100.0 + 0.05 * (xc[None, :] - X0) + 0.02 * (Y0 - yc[:, None])


def _grid(points, **kw):
    shape = (int(SIZE_M / 0.5), int(SIZE_M / 0.5))
    return rasterize(points, 0.5, epsg=EPSG, origin=(X0, Y0), shape=shape, **kw)


def _interior(dsm, margin_cells=6):
    m = np.zeros(dsm.height.shape, bool)
    m[margin_cells:-margin_cells, margin_cells:-margin_cells] = True
    return m


def test_footprints_remove_the_pinhole_lattice():
    points, _, _ = _lattice()
    plain = _grid(points, footprint_m=0.0, max_hole_m=0.0)
    inside = _interior(plain)
    pinholes = ~np.isfinite(plain.height) & inside
    assert pinholes.mean() > 0.02  # the aliasing: one point per 0.52 m, cells of 0.5 m
    dsm = _grid(points, max_hole_m=0.0)  # footprint: the points' spacing (estimated)
    assert np.isfinite(dsm.height[inside]).all()
    assert not dsm.filled.any()  # measured, not interpolated
    assert dsm.count[inside].min() >= 1 and (dsm.count[pinholes] >= 1).all()
    err = np.abs(dsm.height - _plane(dsm))[inside]
    assert err.max() < 0.05  # a neighbour within 0.52 m: < 3 cm of slope


def _without(points, x, y, cx, cy, radius_m):
    return points[np.hypot(x - cx, y - cy) > radius_m]


def test_small_holes_interpolated_and_flagged_large_voids_kept():
    points, x, y = _lattice()
    small = (X0 + 15.0, Y0 - 15.0)
    large = (X0 + 40.0, Y0 - 40.0)
    points = _without(points, x, y, *small, 1.5)  # 3 m across
    xy = to_map(points, EPSG)
    points = _without(points, xy[:, 0], xy[:, 1], *large, 7.5)  # 15 m across
    dsm = _grid(points)
    inside = _interior(dsm)
    rows, cols = dsm.height.shape
    xc = dsm.x0 + (np.arange(cols) + 0.5) * 0.5
    yc = dsm.y0 - (np.arange(rows) + 0.5) * 0.5
    dist_small = np.hypot(xc[None, :] - small[0], yc[:, None] - small[1])
    dist_large = np.hypot(xc[None, :] - large[0], yc[:, None] - large[1])
    hole = dist_small < 0.9  # deeper in than any footprint reaches
    assert hole.sum() >= 9 and (dsm.filled[hole] == 1).all()
    assert np.all(dsm.count[dsm.filled == 1] == 0)
    # Laplace through the rim of a plane is the plane
    assert np.abs(dsm.height - _plane(dsm))[dsm.filled == 1].max() < 0.02
    void = dist_large < 6.5
    assert np.isnan(dsm.height[void]).all() and not dsm.filled[void].any()
    assert np.isfinite(dsm.height[inside & (dist_large > 8.5)]).all()
    # no interpolation asked: the small hole stays
    assert np.isnan(_grid(points, max_hole_m=0.0).height[hole]).all()


def test_small_holes_never_at_the_grid_edge():
    h = np.ones((20, 20))
    h[5:8, 5:8] = np.nan  # 3 cells across, inside
    h[0:3, 10:12] = np.nan  # at the edge: only part of its rim is known
    h[10:19, 2:11] = np.nan  # 9 cells across
    mask = small_holes(h, max_cells=8)
    assert mask[5:8, 5:8].all() and mask.sum() == 9
    filled = laplace_fill(h, mask)
    np.testing.assert_allclose(filled[5:8, 5:8], 1.0)
    assert np.isnan(filled[0:3, 10:12]).all() and np.isnan(filled[10:19, 2:11]).all()


def test_write_dsm_named_bands(tmp_path):
    points, x, y = _lattice()
    points = _without(points, x, y, X0 + 20.0, Y0 - 30.0, 1.5)
    dsm = _grid(points)
    assert list(DSM_BANDS) == ["height", "count", "spread", "filled", "height_sigma"]
    out = write_dsm(dsm, tmp_path / "dsm.tif")
    with rasterio.open(out) as f:
        assert f.count == 5
        assert f.descriptions == ("height", "count", "spread", "filled", "height_sigma")
        assert f.units[4] == "m" and np.isnan(f.read(5)).all()  # no point sigmas: unknown
        assert f.units[0] == "m" and np.isnan(f.nodata)
        assert "interpolated" in f.tags(4)["meaning"]
        height, count, filled = f.read(1), f.read(2), f.read(4)
    np.testing.assert_array_equal(height, dsm.height)
    empty = np.isnan(height)
    assert empty.any() and np.isnan(filled[empty]).all() and np.isnan(count[empty]).all()
    assert set(np.unique(filled[~empty])) == {0.0, 1.0}
    np.testing.assert_array_equal(filled[~empty], dsm.filled[~empty])


def test_dsmgrid_without_filled_band_is_all_measured():
    h = np.array([[1.0, np.nan]], np.float32)
    grid = DSMGrid(h, np.array([[2, 0]]), np.zeros((1, 2), np.float32), 0.0, 0.0, 1.0, EPSG)
    bands = grid.bands()
    assert list(bands) == list(DSM_BANDS)
    assert bands["filled"][0, 0] == 0 and np.isnan(bands["filled"][0, 1])


def test_rasterize_refuses_a_bad_resolution():
    with pytest.raises(ValueError, match="resolution"):
        rasterize(np.zeros((3, 3)), 0.0)
