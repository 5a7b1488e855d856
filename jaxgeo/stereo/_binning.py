"""A DSM's points binned into its map cells (:mod:`._dsm`), at the cost of a tile's million
points: the points of a tile's box projected once (by a cubic fitted to the projection over the
box, checked against pyproj), their spacing, the median/count/spread per cell by sums (a sort
only for cells of three or more points), and the footprint fill's nearest points by a search
over the neighbouring cells. Each shortcut gives what the direct computation gives (a sort of
every point, a KD-tree, pyproj on every point: bit for bit, the projection within a micrometre),
tested against it in ``tests/stereo/test_rasterize_cost.py``."""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np


@functools.lru_cache(maxsize=8)
def _transformer(source: int, target: int):
    """The pyproj transformer ``source`` -> ``target`` (EPSG codes, x = lon first), built once
    per process: building one costs milliseconds, a tile calls it per pair."""
    import pyproj

    return pyproj.Transformer.from_crs(source, target, always_xy=True)


MAP_FIT_TOLERANCE_M = 1e-6
"""Largest error (m) of the cubic that stands for the map projection over a tile
(:class:`_LocalProjection`): a micrometre, far below a cell and the points' own precision (over a
tile of a few hundred metres the fit is good to ~1e-8 m); above it, pyproj projects every
point."""


@dataclass(frozen=True)
class _LocalProjection:
    """The map projection lon/lat (degrees) -> x, y (m) over a small geographic box, as a cubic
    polynomial in the box's normalised coordinates (10 terms per axis), fitted on pyproj's
    values and checked against them (:meth:`fit`). Over a 1 Mpx tile it costs a fifth of pyproj
    (numpy over cache-sized chunks)."""

    centre: tuple[float, float]  # lon, lat (deg) of the box's centre
    scale: tuple[float, float]  # 1 / the box's half-sides (1/deg)
    cx: tuple[float, ...]  # x coefficients, :data:`_TERMS` order (m)
    cy: tuple[float, ...]

    _TERMS = ((0, 0), (0, 1), (0, 2), (0, 3), (1, 0), (1, 1), (1, 2), (2, 0), (2, 1), (3, 0))
    """(power of u, power of v): u east, v north, both in [-1, 1] over the box."""

    @classmethod
    def fit(cls, bounds, epsg: int) -> _LocalProjection | None:
        """The cubic over ``bounds = (west, south, east, north)`` (deg), or ``None`` where it
        misses pyproj by more than :data:`MAP_FIT_TOLERANCE_M` on a grid between its nodes."""
        w, s, e, n = bounds
        centre, half = ((w + e) / 2, (s + n) / 2), ((e - w) / 2, (n - s) / 2)
        if not (half[0] > 0 and half[1] > 0):
            return None
        tr = _transformer(4326, epsg)
        nodes = np.concatenate([[-1.0], np.cos(np.pi * (np.arange(10) + 0.5) / 10), [1.0]])
        u, v = (a.ravel() for a in np.meshgrid(nodes, nodes))
        x, y = tr.transform(centre[0] + half[0] * u, centre[1] + half[1] * v)
        design = np.stack([u**i * v**j for i, j in cls._TERMS], axis=1)
        coef, *_ = np.linalg.lstsq(design, np.stack([x, y], axis=1), rcond=None)
        local = cls(centre, (1 / half[0], 1 / half[1]), tuple(coef[:, 0]), tuple(coef[:, 1]))
        check = np.linspace(-1.0, 1.0, 23)
        u, v = (a.ravel() for a in np.meshgrid(check, check))
        lon, lat = centre[0] + half[0] * u, centre[1] + half[1] * v
        x, y = tr.transform(lon, lat)
        px, py = local(lon, lat)
        worst = max(np.max(np.abs(px - x)), np.max(np.abs(py - y)))
        return local if worst <= MAP_FIT_TOLERANCE_M else None

    def __call__(self, lon: np.ndarray, lat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Map ``x, y`` (m) of ``lon, lat`` (deg, inside the box)."""
        size = lon.shape[0]
        x, y = np.empty(size), np.empty(size)
        chunk = min(size, 32768)  # temporaries that stay in cache and are allocated once
        u, v, t, w = (np.empty(chunk) for _ in range(4))
        for start in range(0, size, chunk):
            m = min(chunk, size - start)
            uu, vv, tt, ww = u[:m], v[:m], t[:m], w[:m]
            np.subtract(lon[start : start + m], self.centre[0], out=uu)
            uu *= self.scale[0]
            np.subtract(lat[start : start + m], self.centre[1], out=vv)
            vv *= self.scale[1]
            for out, c in ((x, self.cx), (y, self.cy)):
                c00, c01, c02, c03, c10, c11, c12, c20, c21, c30 = c
                # u (c10 + c11 v + c12 v^2 + u (c20 + c21 v + c30 u))
                np.multiply(vv, c21, out=tt)
                tt += c20
                np.multiply(uu, c30, out=ww)
                tt += ww
                tt *= uu
                np.multiply(vv, c12, out=ww)
                ww += c11
                ww *= vv
                ww += c10
                tt += ww
                tt *= uu
                # + c00 + v (c01 + v (c02 + c03 v))
                np.multiply(vv, c03, out=ww)
                ww += c02
                ww *= vv
                ww += c01
                ww *= vv
                ww += c00
                np.add(tt, ww, out=out[start : start + m])
        return x, y


def map_points_in_box(
    points: np.ndarray, epsg: int, box: tuple[float, float, float, float]
) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """The ``(n, 3)`` lon/lat/h ``points`` whose map coordinates (EPSG ``epsg``) lie in
    ``box = (xmin, ymin, xmax, ymax)`` (m; ``xmin <= x < xmax``, ``ymin <= y < ymax``), all
    three coordinates finite: their indices (ascending) and their map ``(x, y, h)`` columns.

    Only the points within the box's geographic bounds (widened by ~10 m) are projected (a
    tile's window sees its context too), by a cubic fitted to the projection over those bounds
    (:class:`_LocalProjection`, within :data:`MAP_FIT_TOLERANCE_M` of pyproj), else by pyproj."""
    xmin, ymin, xmax, ymax = box
    # the box's outline, densified (a map straight line is not a meridian or a parallel)
    t = np.linspace(0.0, 1.0, 33)
    ex = np.concatenate([xmin + (xmax - xmin) * t, np.full(33, xmax),
                         xmax - (xmax - xmin) * t, np.full(33, xmin)])  # fmt: skip
    ey = np.concatenate([np.full(33, ymin), ymin + (ymax - ymin) * t,
                         np.full(33, ymax), ymax - (ymax - ymin) * t])  # fmt: skip
    lon, lat = (np.asarray(v) for v in _transformer(epsg, 4326).transform(ex, ey))
    idx, local = None, None
    if np.all(np.isfinite(lon)) and np.all(np.isfinite(lat)):
        dlat = 1e-4  # ~11 m: far beyond the densified outline's sag
        dlon = dlat / max(np.cos(np.radians(min(np.max(np.abs(lat)) + dlat, 89.0))), 1e-3)
        bounds = (lon.min() - dlon, lat.min() - dlat, lon.max() + dlon, lat.max() + dlat)
        lon_p, lat_p = points[:, 0], points[:, 1]
        near = (lon_p >= bounds[0]) & (lon_p <= bounds[2])
        near &= lat_p >= bounds[1]
        near &= lat_p <= bounds[3]
        idx = np.flatnonzero(near)
        local = _LocalProjection.fit(bounds, epsg)
    # contiguous columns of the points near the box
    lon, lat, h = (points[:, j] if idx is None else points[:, j][idx] for j in range(3))
    if local is not None:
        x, y = local(lon, lat)
    else:  # projected in place: no further copy
        lon, lat = (np.array(v, float, order="C", copy=idx is None) for v in (lon, lat))
        x, y = _transformer(4326, epsg).transform(lon, lat, inplace=True)
    idx = np.arange(points.shape[0]) if idx is None else idx
    keep = (x >= xmin) & (x < xmax) & (y >= ymin) & (y < ymax) & np.isfinite(h)
    if keep.all():
        return idx, (x, y, np.ascontiguousarray(h))
    return idx[keep], (x[keep], y[keep], h[keep])


def point_spacing(xy: np.ndarray, sample: int = 20000) -> float:
    """Median distance (map units) from a point to its nearest neighbour (a sample of them:
    with many more points, those of a central square holding about ``4 * sample``, whose inner
    part is queried; a tree of a million points cost a second)."""
    return spacing_xy(xy[:, 0], xy[:, 1], sample)


def spacing_xy(x: np.ndarray, y: np.ndarray, sample: int = 20000) -> float:
    """:func:`point_spacing` of the points ``(x, y)`` given as two columns (no ``(n, 2)``
    copy of a million points)."""
    from scipy.spatial import cKDTree

    n = x.shape[0]
    if n < 2:
        return 0.0
    tree_x, tree_y, query_x, query_y = x, y, x, y
    if n > 8 * sample:
        lo = np.array([x.min(), y.min()])
        hi = np.array([x.max(), y.max()])
        half = 0.5 * np.sqrt(np.prod(hi - lo) * 4 * sample / n)
        cx, cy = np.median(x[:: n // sample]), np.median(y[:: n // sample])
        off = np.abs(x - cx)
        np.maximum(off, np.abs(y - cy), out=off)  # the Chebyshev distance to the centre
        inner = off <= 0.7 * half
        if np.count_nonzero(inner) >= sample // 4:
            square = off <= half
            tree_x, tree_y, query_x, query_y = x[square], y[square], x[inner], y[inner]
    step = max(query_x.shape[0] // sample, 1)
    tree = cKDTree(np.stack([tree_x, tree_y], axis=-1))
    dist, _ = tree.query(np.stack([query_x[::step], query_y[::step]], axis=-1), k=2)
    return float(np.median(dist[:, 1]))


def _median_per_cell(cell, h, size):
    """Median, count and standard deviation of ``h`` per cell index (NaN / 0 where empty).

    Dense matching puts one or two points in most cells: their median is their mean, from the
    per-cell sums (bit for bit: a sum of one or two values does not depend on their order);
    only the points of cells with three or more are sorted, and those cells' sums are taken in
    sorted order (as a sort of every point would)."""
    count = np.bincount(cell, minlength=size)
    total = np.bincount(cell, weights=h, minlength=size)
    total2 = np.bincount(cell, weights=h * h, minlength=size)
    many = np.flatnonzero(count >= 3)
    median = None
    if many.size:
        sel = count[cell] >= 3
        c, v = cell[sel], h[sel]
        v = v[np.lexsort((v, c))]
        k = count[many]
        start = np.cumsum(k) - k
        median = 0.5 * (v[start + (k - 1) // 2] + v[start + k // 2])
        which = np.repeat(np.arange(many.size), k)
        total[many] = np.bincount(which, weights=v, minlength=many.size)
        total2[many] = np.bincount(which, weights=v * v, minlength=many.size)
    with np.errstate(invalid="ignore", divide="ignore"):  # empty cells: 0 / 0 = NaN
        mean = total / count
        spread = total2 / count
    spread -= mean * mean
    np.sqrt(np.maximum(spread, 0.0, out=spread), out=spread)  # NaN stays NaN
    if median is not None:
        mean[many] = median
    return mean, count, spread


def _nearest_within(pxy, cells, grid_shape, targets, centres, k, radius_m, reach):
    """Per target cell, the (up to) ``k`` nearest points within ``radius_m`` of its centre, as
    :meth:`scipy.spatial.cKDTree.query` (``k``, ``distance_upper_bound``) gives them: distances
    ascending (``inf`` past the last one found) and indices (``len(px)`` there), found among
    the points of the cells within ``reach`` cells (a point within ``radius_m <= reach``
    cells of a centre lies in one). ``cells``: each point's cell index in ``grid_shape``;
    ``targets``: the target cells' indices; ``centres``: their centres (x, y). Distances are
    computed as the tree does (squared sum, kept if below ``radius_m**2``, then the square
    root); ``None`` where a cell holds too many points for this cell-by-cell search."""
    px, py = pxy
    nr, nc = grid_shape
    count = np.bincount(cells, minlength=nr * nc)
    most = int(count.max(initial=0))
    side = 2 * reach + 1
    if most == 0 or side * side * most > 400:
        return None
    order = np.argsort(cells, kind="stable")  # points by cell
    start = np.cumsum(count) - count
    tr, tc = np.divmod(targets, nc)
    cx, cy = centres[:, 0], centres[:, 1]
    bound = radius_m * radius_m
    # the k best so far per target, ascending: a candidate bubbles down past the larger ones
    # (a later candidate at an equal distance stays behind: ties go to the first seen)
    best_d2 = [np.full(targets.size, np.inf) for _ in range(k)]
    best_i = [np.full(targets.size, px.size) for _ in range(k)]
    for dr in range(-reach, reach + 1):
        for dc in range(-reach, reach + 1):
            r, c = tr + dr, tc + dc
            ok = (r >= 0) & (r < nr) & (c >= 0) & (c < nc)
            cell = np.where(ok, r * nc + c, 0)
            n = np.where(ok, count[cell], 0)
            for j in range(most):
                # the targets whose neighbour holds a (j+1)-th point (few past the first)
                rows = slice(None) if j == 0 else np.flatnonzero(j < n)
                i = order[np.minimum(start[cell[rows]] + j, order.size - 1)]
                dx = px[i] - cx[rows]
                dy = py[i] - cy[rows]
                d2 = dx * dx + dy * dy
                d2[~((j < n[rows]) & (d2 < bound))] = np.inf
                for p in range(k):
                    held_d2, held_i = best_d2[p][rows], best_i[p][rows]
                    better = d2 < held_d2
                    new_d2, new_i = np.where(better, d2, held_d2), np.where(better, i, held_i)
                    d2, i = np.where(better, held_d2, d2), np.where(better, held_i, i)
                    best_d2[p][rows], best_i[p][rows] = new_d2, new_i
    d2k, idxk = np.stack(best_d2, axis=1), np.stack(best_i, axis=1)
    return np.sqrt(d2k), np.where(np.isfinite(d2k), idxk, px.size)


def _footprint_fill(grids, xyh, origin, res_m, radius_m, k=4, extra=(), cells=None):
    """Empty cells of ``grids = (height, count, spread)`` (cells of ``res_m``, upper-left
    corner ``origin = (x0, y0)``) within ``radius_m`` of points ``xyh`` (columns x, y, h):
    median, count and spread of the (up to ``k``) nearest points within that radius of the cell
    centre (in place); each ``(grid, values)`` of ``extra`` (per-point values) takes the mean of
    those points' values. ``cells``: the points' ``(row, col, cell)`` on the grid, when known
    (``cell``: ``row * cols + col`` where every point is on the grid, else ``None``)."""
    from scipy import ndimage

    height, count, spread = grids
    x0, y0 = origin
    x, y, h = xyh
    reach = int(np.ceil(radius_m / res_m))
    near = ndimage.binary_dilation(np.isfinite(height), iterations=reach)
    target = near & ~np.isfinite(height)
    rows, cols = np.nonzero(target)
    if rows.size == 0:
        return
    centres = np.stack([x0 + (cols + 0.5) * res_m, y0 - (rows + 0.5) * res_m], axis=-1)
    nr, nc = height.shape
    if cells is None:
        cells = (np.floor((y0 - y) / res_m).astype(np.int64),
                 np.floor((x - x0) / res_m).astype(np.int64), None)  # fmt: skip
    row, col, flat = cells
    # a point within ``radius_m`` (<= ``reach`` cells) of an empty cell's centre lies in a cell
    # within ``reach`` of it, on the grid or up to ``reach`` cells off it: the candidates are
    # the points of those cells (few where the empty cells are few, not the whole tile's)
    if flat is not None:  # every point on the grid (a tile's): its cells as they are
        grid, pad, cell = (nr, nc), 0, flat
        around = ndimage.binary_dilation(target, np.ones((3, 3), bool), iterations=reach)
        cand = np.flatnonzero(around.ravel()[cell])
    else:  # the grid widened by ``reach`` cells
        grid, pad = (nr + 2 * reach, nc + 2 * reach), reach
        pr, pc = row + pad, col + pad
        cell = np.where((pr >= 0) & (pr < grid[0]) & (pc >= 0) & (pc < grid[1]),
                        pr * grid[1] + pc, -1)  # fmt: skip
        wide = np.zeros(grid, bool)
        wide[pad : pad + nr, pad : pad + nc] = target
        around = ndimage.binary_dilation(wide, np.ones((3, 3), bool), iterations=reach)
        cand = np.flatnonzero(cell >= 0)
        cand = cand[around.ravel()[cell[cand]]]
    if cand.size == 0:
        return
    targets = (rows + pad) * grid[1] + cols + pad
    found = _nearest_within((x[cand], y[cand]), cell[cand], grid, targets, centres, k,
                            radius_m, reach)  # fmt: skip
    if found is None:  # too many points in a cell for the table: a tree
        from scipy.spatial import cKDTree

        tree = cKDTree(np.stack([x[cand], y[cand]], axis=-1))
        found = tree.query(centres, k=k, distance_upper_bound=radius_m)
    dist, idx = found
    found = np.isfinite(dist)
    n = found.sum(axis=1)
    some = n > 0
    safe = np.minimum(idx, cand.size - 1)[some]
    heights = np.where(found[some], h[cand[safe]], np.nan)
    r, c = rows[some], cols[some]
    height[r, c] = np.nanmedian(heights, axis=1)
    count[r, c] = n[some]
    spread[r, c] = np.nanstd(heights, axis=1)
    for grid_values, values in extra:
        v = np.where(found[some], values[cand[safe]], np.nan)
        grid_values[r, c] = np.nanmean(v, axis=1)
