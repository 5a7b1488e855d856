"""A DSM tile's rasterisation made cheap (issue 54, item 1) without changing the product: each
shortcut gives what the direct computation gives, bit for bit (per-cell median by a sort of
every point, footprints by a KD-tree, the box test on every point projected, the spacing's
sample), on points like a tile's (about one per cell, some cells with several)."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from jaxgeo.stereo import rasterize
from jaxgeo.stereo._binning import (
    MAP_FIT_TOLERANCE_M,
    _LocalProjection,
    _median_per_cell,
    _nearest_within,
    map_points_in_box,
    point_spacing,
    spacing_xy,
)
from jaxgeo.stereo._dsm import rasterize_map, to_map

EPSG = 32631
X0, Y0 = 698000.0, 4793000.0


def _sorted_median_per_cell(cell, h, size):
    """The direct computation: every point sorted by (cell, height)."""
    order = np.lexsort((h, cell))
    cell, h = cell[order], h[order]
    count = np.bincount(cell, minlength=size)
    start = np.concatenate([[0], np.cumsum(count)[:-1]])
    has = count > 0
    median = np.full(size, np.nan)
    median[has] = 0.5 * (h[start[has] + (count[has] - 1) // 2] + h[start[has] + count[has] // 2])
    total = np.bincount(cell, weights=h, minlength=size)
    total2 = np.bincount(cell, weights=h * h, minlength=size)
    spread = np.full(size, np.nan)
    mean = total[has] / count[has]
    spread[has] = np.sqrt(np.maximum(total2[has] / count[has] - mean**2, 0.0))
    return median, count, spread


@pytest.mark.parametrize("most", [2, 7])
def test_median_per_cell_is_the_sorted_one_bit_for_bit(most):
    rng = np.random.default_rng(most)
    size = 5000
    cell = np.repeat(np.arange(size), rng.integers(0, most + 1, size))
    rng.shuffle(cell)
    h = 100.0 + rng.normal(0.0, 3.0, cell.size)
    h[::50] = np.round(h[::50])  # equal heights in a cell
    got = _median_per_cell(cell, h, size)
    want = _sorted_median_per_cell(cell, h, size)
    assert (got[1] >= 3).any() == (most > 2)
    for g, w in zip(got, want, strict=True):
        np.testing.assert_array_equal(g, w)


def test_nearest_within_is_the_kd_trees_bit_for_bit():
    rng = np.random.default_rng(3)
    shape, res, radius = (60, 70), 0.5, 0.9  # reach 2 cells
    x = X0 - 1.0 + rng.uniform(0, 36.0, 6000)  # some points off the grid's west and east
    y = Y0 + 1.0 - rng.uniform(0, 31.0, 6000)
    row = np.floor((Y0 - y) / res).astype(np.int64)
    col = np.floor((x - X0) / res).astype(np.int64)
    reach = 2
    grid = (shape[0] + 2 * reach, shape[1] + 2 * reach)
    pr, pc = row + reach, col + reach
    on = (pr >= 0) & (pr < grid[0]) & (pc >= 0) & (pc < grid[1])
    x, y, cells = x[on], y[on], (pr * grid[1] + pc)[on]  # the points that may be in reach
    rows, cols = np.nonzero(rng.uniform(size=shape) < 0.3)
    centres = np.stack([X0 + (cols + 0.5) * res, Y0 - (rows + 0.5) * res], axis=-1)
    targets = (rows + reach) * grid[1] + cols + reach
    dist, idx = _nearest_within((x, y), cells, grid, targets, centres, 4, radius, reach)
    want_d, want_i = cKDTree(np.stack([x, y], axis=-1)).query(
        centres, k=4, distance_upper_bound=radius
    )
    assert np.isfinite(dist).any() and np.isinf(dist).any()  # some found, some not
    np.testing.assert_array_equal(dist, want_d)
    np.testing.assert_array_equal(idx, want_i)


def _lonlat(x, y):
    import pyproj

    lon, lat = pyproj.Transformer.from_crs(EPSG, 4326, always_xy=True).transform(x, y)
    return np.asarray(lon), np.asarray(lat)


@pytest.mark.parametrize("size_m", [1000.0, 200_000.0])
def test_map_points_in_box_is_every_point_projected_and_tested(size_m):
    """A tile's box (1 km): the projection's cubic, within a micrometre of pyproj; a box too
    large for a cubic (200 km): pyproj itself."""
    rng = np.random.default_rng(5)
    x = X0 + rng.uniform(-0.2, 1.2, 20000) * size_m
    y = Y0 - rng.uniform(-0.2, 1.2, 20000) * size_m
    lon, lat = _lonlat(x, y)
    points = np.stack([lon, lat, rng.normal(100.0, 5.0, x.size)], axis=1)
    points[::97, 2] = np.nan
    points[::89, 0] = np.nan
    box = (X0 + 0.01 * size_m, Y0 - 0.99 * size_m, X0 + 0.99 * size_m, Y0 - 0.01 * size_m)
    before = points.copy()
    idx, (mx, my, mh) = map_points_in_box(points, EPSG, box)
    np.testing.assert_array_equal(points, before)  # the input untouched (projected in place)
    xyh = to_map(points, EPSG)
    inside = (np.all(np.isfinite(xyh), axis=1) & (xyh[:, 0] >= box[0]) & (xyh[:, 0] < box[2])
              & (xyh[:, 1] >= box[1]) & (xyh[:, 1] < box[3]))  # fmt: skip
    assert 0 < inside.sum() < x.size - 5000
    np.testing.assert_array_equal(idx, np.flatnonzero(inside))
    np.testing.assert_array_equal(mh, xyh[inside, 2])
    got = np.stack([mx, my], axis=1)
    if size_m < 10_000:
        assert np.abs(got - xyh[inside, :2]).max() <= MAP_FIT_TOLERANCE_M
        assert np.abs(got - xyh[inside, :2]).max() < 1e-7  # measured: ~1e-8 m over 1 km
    else:
        np.testing.assert_array_equal(got, xyh[inside, :2])


def test_the_projections_cubic_is_refused_where_it_misses():
    west, south = _lonlat(np.array([X0]), np.array([Y0 - 1000.0]))
    east, north = _lonlat(np.array([X0 + 1000.0]), np.array([Y0]))
    small = (west[0], south[0], east[0], north[0])
    assert _LocalProjection.fit(small, EPSG) is not None
    assert _LocalProjection.fit((small[0], small[1], small[0] + 3.0, small[1] + 2.0), EPSG) is None


def _old_point_spacing(xy, sample=20000):
    """The spacing's sample as an ``(n, 2)`` array (before the columns)."""
    tree_xy, query = xy, xy
    if xy.shape[0] > 8 * sample:
        lo, hi = xy.min(axis=0), xy.max(axis=0)
        half = 0.5 * np.sqrt(np.prod(hi - lo) * 4 * sample / xy.shape[0])
        centre = np.median(xy[:: xy.shape[0] // sample], axis=0)
        off = np.max(np.abs(xy - centre), axis=1)
        inner = off <= 0.7 * half
        if inner.sum() >= sample // 4:
            tree_xy, query = xy[off <= half], xy[inner]
    step = max(query.shape[0] // sample, 1)
    dist, _ = cKDTree(tree_xy).query(query[::step], k=2)
    return float(np.median(dist[:, 1]))


def test_spacing_of_columns_is_the_arrays():
    rng = np.random.default_rng(9)
    xy = rng.uniform(0.0, 300.0, (60000, 2))
    assert spacing_xy(xy[:, 0], xy[:, 1], sample=5000) == _old_point_spacing(xy, 5000)
    assert point_spacing(xy, sample=5000) == _old_point_spacing(xy, 5000)
    assert point_spacing(xy[:3000]) == _old_point_spacing(xy[:3000])


def test_rasterize_map_is_rasterize():
    rng = np.random.default_rng(11)
    x = X0 + rng.uniform(0.0, 40.0, 5000)
    y = Y0 - rng.uniform(0.0, 40.0, 5000)
    keep = np.hypot(x - X0 - 20.0, y - Y0 + 20.0) > 2.0  # a hole to interpolate
    x, y = x[keep], y[keep]
    h = 50.0 + 0.1 * (x - X0) + rng.normal(0.0, 0.2, x.size)
    sig = (rng.uniform(0.1, 0.3, x.size), np.full(x.size, 0.05))
    lon, lat = _lonlat(x, y)
    points = np.stack([lon, lat, h], axis=1)
    a = rasterize(points, 0.5, epsg=EPSG, sigmas=sig)
    mx, my = to_map(points, EPSG)[:, :2].T
    b = rasterize_map((mx, my, h), 0.5, EPSG, sigmas=sig)
    assert a.filled.any()
    for name, band in a.bands().items():
        np.testing.assert_array_equal(band, b.bands()[name])
