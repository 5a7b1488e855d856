"""DSM rasterisation: one height per cell from the 3D points, small holes interpolated.

Points ``(lon_deg, lat_deg, h_m)`` are projected to a map CRS (local UTM by default) and binned
into a north-up grid of ``res_m`` cells; a cell's height is the median of its points (ellipsoidal
metres), with the point count and spread (standard deviation) as extra bands. Then:

1. **Footprints.** Dense matching gives about one point per image pixel; when that spacing is
   close to the cell size, the two lattices alias and a regular pattern of cells receives no
   point (a lattice of single-cell pinholes, ~1 % of the cells on a Pleiades pair at 0.5 m). A
   point stands for the ground around it up to the point spacing, so a cell holding no point
   takes the median of the points within ``footprint_m`` of its centre (still a measurement:
   ``filled`` 0; ``count`` says how many points).
2. **Small holes.** A hole (a connected set of empty cells that does not reach the grid's edge)
   at most ``max_hole_m`` across is interpolated from its rim (Laplace: the smoothest surface
   through the rim), as s2p's and CARS's DSMs fill small gaps; the ``filled`` band marks these
   cells. Larger voids (occlusions behind buildings, water, no texture) stay empty (NaN).

The GeoTIFF is tiled (256 x 256), DEFLATE, written atomically; its bands are named
(:data:`DSM_BANDS`, band descriptions ``height``, ``count``, ``spread``, ``filled``,
``height_sigma``: the height's standard deviation, :mod:`._uncertainty`).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from ..geodesy import utm_epsg, utm_zone
from ..io.internal import atomic_output, raster_writer
from ..tiles import OutputGrid
from ._binning import _footprint_fill, _median_per_cell, _transformer, spacing_xy
from ._binning import point_spacing as point_spacing  # :mod:`._pipeline`'s, the tests'
from ._triangulation import StereoError
from ._uncertainty import cell_sigma

MAX_HOLE_M = 4.0
"""Largest hole (m across) interpolated by default: a few cells of occlusion or of a failed
match, never a void."""

DSM_BANDS = {
    "height": ("m", "height above the WGS84 ellipsoid (m): median of the cell's points"),
    "count": ("", "number of points the height comes from (0: interpolated)"),
    "spread": ("m", "standard deviation of those points' heights (m)"),
    "filled": ("", "1: height interpolated from the rim of a small hole, 0: measured"),
    "height_sigma": (
        "m",
        "standard deviation of the height (m): matching and orientation, propagated through "
        "the intersection, combined over the cell's points",
    ),
}
"""The DSM's bands in file order: name -> (unit, meaning). A new band (e.g. ``height_sigma``) is
a :class:`DSMGrid` field and an entry here."""


def dsm_band_tags(sigma_covers: str = "") -> tuple[tuple[tuple[str, str], ...], ...]:
    """Per band of :data:`DSM_BANDS` its tags: ``meaning``, and for ``height_sigma`` what it
    covers (``covers``: :func:`~._uncertainty.sigma_covers`, e.g. the matching and the models'
    a priori orientation error), when given."""
    return tuple(
        (("meaning", meaning),)
        + ((("covers", sigma_covers),) if name == "height_sigma" and sigma_covers else ())
        for name, (_, meaning) in DSM_BANDS.items()
    )


@dataclass(frozen=True)
class DSMGrid:
    """A rasterised DSM: ``height`` (NaN: no data), ``count``, ``spread``, ``filled`` (1 where
    the height is interpolated), ``height_sigma`` (m; NaN/``None``: unknown) ``(rows, cols)``;
    ``x0, y0`` the map coordinates of the upper-left corner of the first cell; ``res_m``;
    ``epsg``."""

    height: np.ndarray
    count: np.ndarray
    spread: np.ndarray
    x0: float
    y0: float
    res_m: float
    epsg: int
    filled: np.ndarray | None = None
    height_sigma: np.ndarray | None = None

    @property
    def transform(self):
        from affine import Affine

        return Affine(self.res_m, 0.0, self.x0, 0.0, -self.res_m, self.y0)

    def bands(self) -> dict[str, np.ndarray]:
        """The bands of :data:`DSM_BANDS` by name, in file order, as float32 with NaN where the
        height is NaN."""
        empty = ~np.isfinite(self.height)
        filled = self.filled if self.filled is not None else np.zeros(self.height.shape, np.uint8)
        nan = np.full(self.height.shape, np.nan, np.float32)
        out = {}
        for name in DSM_BANDS:
            value = filled if name == "filled" else getattr(self, name)
            value = nan if value is None else np.asarray(value, np.float32)
            out[name] = np.where(empty, np.float32(np.nan), value)
        return out


def local_utm_epsg(lon_deg: float, lat_deg: float) -> int:
    """EPSG code of the UTM zone of a point (north or south)."""
    return utm_epsg(utm_zone(lon_deg, lat_deg), north=lat_deg >= 0)


def to_map(points: np.ndarray, epsg: int) -> np.ndarray:
    """``(n, 3)`` lon/lat/h -> ``(n, 3)`` map x, y and h."""
    x, y = _transformer(4326, epsg).transform(points[:, 0], points[:, 1])
    return np.stack([np.asarray(x), np.asarray(y), points[:, 2]], axis=-1)


def small_holes(height: np.ndarray, max_cells: float) -> np.ndarray:
    """Mask of the cells of holes in ``height``: connected sets of NaN cells (4-neighbours) not
    reaching the grid's edge, each cell within ``max_cells / 2`` cells of a finite one (the hole
    is at most ``max_cells`` across)."""
    from scipy import ndimage

    empty = ~np.isfinite(height)
    if not empty.any() or max_cells < 1:
        return np.zeros(height.shape, bool)
    labels, n = ndimage.label(empty)
    edge = np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]]))
    depth = ndimage.distance_transform_edt(empty)  # cells to the nearest finite cell
    deepest = ndimage.maximum(depth, labels, index=np.arange(1, n + 1))
    small = np.zeros(n + 1, bool)
    small[1:] = np.asarray(deepest) <= max_cells / 2 + 1e-9
    small[edge] = False
    return small[labels]


def laplace_fill(height: np.ndarray, holes: np.ndarray) -> np.ndarray:
    """``height`` with the ``holes`` cells replaced by the solution of Laplace's equation with
    the surrounding finite cells as boundary values (every hole cell must have its 4
    neighbours inside the grid and each hole a finite rim)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.linalg import spsolve

    out = np.array(height, dtype=float)
    rows, cols = np.nonzero(holes)
    n = rows.size
    if n == 0:
        return out
    index = np.full(height.shape, -1, np.int64)
    index[rows, cols] = np.arange(n)
    diag = np.zeros(n)
    rhs = np.zeros(n)
    ii, jj = [], []
    for dr, dc in ((-1, 0), (1, 0), (0, -1), (0, 1)):
        rr, cc = rows + dr, cols + dc
        other = index[rr, cc]
        unknown = other >= 0
        value = out[rr, cc]
        known = ~unknown & np.isfinite(value)
        diag += unknown | known
        rhs[known] += value[known]
        ii.append(np.flatnonzero(unknown))
        jj.append(other[unknown])
    ii, jj = np.concatenate(ii), np.concatenate(jj)
    a = coo_matrix((np.full(ii.size, -1.0), (ii, jj)), shape=(n, n)).tocsr()
    a = a + coo_matrix((diag, (np.arange(n), np.arange(n))), shape=(n, n)).tocsr()
    out[rows, cols] = spsolve(a.tocsc(), rhs)
    return out


def rasterize(
    points: np.ndarray,
    res_m: float,
    epsg: int | None = None,
    origin: tuple[float, float] | None = None,
    shape: tuple[int, int] | None = None,
    footprint_m: float | None = None,
    max_hole_m: float = MAX_HOLE_M,
    sigmas: tuple[np.ndarray, np.ndarray] | None = None,
) -> DSMGrid:
    """Grid ``(n, 3)`` lon/lat/h points (NaN rows ignored) at ``res_m`` (module docstring).

    ``epsg`` default: the local UTM zone of the points' median; ``origin`` (upper-left corner)
    and ``shape`` default to the points' extent snapped to multiples of ``res_m``.
    ``footprint_m``: how far from a point an empty cell's centre may lie to take its height
    (default: the points' median spacing; 0: each point in its own cell only).
    ``max_hole_m``: the largest hole interpolated, metres across (0: none).
    ``sigmas``: each point's height sigma from the matching and from the orientation (m,
    :mod:`._uncertainty`), combined per cell into ``height_sigma`` (:func:`cell_sigma`;
    interpolated cells: the sigma interpolated like the height); ``None``: ``height_sigma``
    unknown (NaN).
    """
    if not res_m > 0:
        raise ValueError(f"rasterize: resolution must be positive, got {res_m}")
    points = np.asarray(points, dtype=float)
    good = np.all(np.isfinite(points), axis=1)
    points = points[good]
    if sigmas is not None:
        sigmas = tuple(np.asarray(v, float)[good] for v in sigmas)
    if points.shape[0] == 0:
        raise ValueError("rasterize: no valid 3D point")
    if epsg is None:
        lon, lat = np.median(points[:, 0]), np.median(points[:, 1])
        epsg = local_utm_epsg(float(lon), float(lat))
    x, y = _transformer(4326, epsg).transform(points[:, 0], points[:, 1])
    xyh = (np.asarray(x, float), np.asarray(y, float), np.ascontiguousarray(points[:, 2]))
    return rasterize_map(xyh, res_m, epsg, origin, shape, footprint_m, max_hole_m, sigmas)


def rasterize_map(
    xyh: tuple[np.ndarray, np.ndarray, np.ndarray],
    res_m: float,
    epsg: int,
    origin: tuple[float, float] | None = None,
    shape: tuple[int, int] | None = None,
    footprint_m: float | None = None,
    max_hole_m: float = MAX_HOLE_M,
    sigmas: tuple[np.ndarray, np.ndarray] | None = None,
) -> DSMGrid:
    """:func:`rasterize` of points already in the map CRS ``epsg``: ``xyh`` their columns x, y
    (m) and h (m), all finite (a tile projects its points once, to keep those of its box)."""
    x, y, h = xyh
    if origin is None:
        origin = (
            float(np.floor(x.min() / res_m) * res_m),
            float(np.ceil(y.max() / res_m) * res_m),
        )
    x0, y0 = origin
    if shape is None:
        shape = (
            int(np.ceil((y0 - y.min()) / res_m)) + 1,
            int(np.ceil((x.max() - x0) / res_m)) + 1,
        )
    rows, cols = shape
    col = np.floor((x - x0) / res_m).astype(np.int64)
    row = np.floor((y0 - y) / res_m).astype(np.int64)
    inside = (row >= 0) & (row < rows) & (col >= 0) & (col < cols)
    every = bool(inside.all())  # a tile's points: no copy of a million rows

    def kept(values):
        return values if every else values[inside]

    cell = kept(row) * cols + kept(col)
    median, count, spread = _median_per_cell(cell, kept(h), rows * cols)
    height, count, spread = (a.reshape(shape) for a in (median, count, spread))
    extra = []
    if sigmas is not None:
        n = np.maximum(count.ravel(), 1)
        for v in sigmas:
            sq = np.nan_to_num(np.asarray(v, float) ** 2, nan=np.inf)
            mean_sq = np.bincount(cell, kept(sq), rows * cols) / n
            extra.append((mean_sq.reshape(shape), sq))
    if footprint_m is None:
        footprint_m = spacing_xy(kept(x), kept(y))
    if footprint_m > 0 and np.isfinite(height).any():
        _footprint_fill((height, count, spread), xyh, (x0, y0), res_m, float(footprint_m),
                        extra=extra, cells=(row, col, cell if every else None))  # fmt: skip
    sigma = None
    if sigmas is not None:
        sigma = cell_sigma(extra[0][0], extra[1][0], spread, count, height, res_m)
        sigma = np.where(np.isfinite(height), sigma, np.nan)
    holes = small_holes(height, max_hole_m / res_m) if max_hole_m > 0 else None
    filled = np.zeros(shape, np.uint8)
    if holes is not None and holes.any():
        height = laplace_fill(height, holes)
        if sigma is not None:
            sigma = laplace_fill(sigma, holes)
        filled[holes] = 1
    return DSMGrid(
        height=height.astype(np.float32),
        count=count.astype(np.uint16 if count.max() < 65535 else np.uint32),
        spread=spread.astype(np.float32),
        x0=float(x0),
        y0=float(y0),
        res_m=float(res_m),
        epsg=int(epsg),
        filled=filled,
        height_sigma=None if sigma is None else sigma.astype(np.float32),
    )


def write_dsm(dsm: DSMGrid, path: str | os.PathLike, overwrite: bool = False):
    """Tiled GeoTIFF, float32, nodata NaN, one band per entry of :data:`DSM_BANDS` in that order
    (band description = the name; ``units`` and a ``meaning`` tag per band): ``height``
    (ellipsoidal m), ``count``, ``spread`` (m), ``filled`` (1 = interpolated, 0 = measured),
    ``height_sigma`` (m)."""

    bands = dsm.bands()
    rows, cols = dsm.height.shape
    profile = dict(
        driver="GTiff",
        width=cols,
        height=rows,
        count=len(bands),
        dtype="float32",
        crs=f"EPSG:{dsm.epsg}",
        transform=dsm.transform,
        nodata=np.nan,
        tiled=True,
        blockxsize=256,
        blockysize=256,
        compress="deflate",
    )
    out = atomic_output(path, overwrite=overwrite, suffix=".tif", leftovers=(".aux.xml",))
    with out as tmp, raster_writer(tmp, profile) as dst:
        for i, (name, values) in enumerate(bands.items(), start=1):
            dst.write(values, i)
            dst.set_band_description(i, name)
            dst.set_band_unit(i, DSM_BANDS[name][0])
            dst.update_tags(i, meaning=DSM_BANDS[name][1])
        dst.update_tags(heights="ellipsoidal (WGS84), m")
    return path


def dsm_grid(ground, epsg: int, settings, reference) -> tuple[float, float, int, int]:
    """The DSM's grid ``(x0, y0, cols, rows)`` (upper-left corner, map m; cells of
    ``settings.res_m`` in EPSG ``epsg``): ``settings.like``'s, else the grid over the ground
    points ``ground`` (lon, lat, h), its edges on multiples of ``res_m`` unless
    ``settings.tap`` is off (:meth:`jaxgeo.tiles.OutputGrid.covering`). A ``like`` grid that
    misses the footprint of ``reference`` is a :class:`StereoError` (a DSM with no cell)."""
    xyh = to_map(ground, epsg)
    lo, hi = xyh[:, :2].min(axis=0), xyh[:, :2].max(axis=0)
    like = settings.like
    if like is None:
        grid = OutputGrid.covering((lo[0], lo[1], hi[0], hi[1]), epsg, settings.res_m,
                                   settings.tap)  # fmt: skip
    else:
        w, s, e, n = like.bounds
        if not (w < hi[0] and e > lo[0] and s < hi[1] and n > lo[1]):
            raise StereoError(
                f"dsm: the grid of {like.source or 'like'} (W S E N = {w:.10g} {s:.10g} "
                f"{e:.10g} {n:.10g}, EPSG:{epsg}) misses the footprint of {reference} "
                f"({lo[0]:.10g}..{hi[0]:.10g}, {lo[1]:.10g}..{hi[1]:.10g}): the DSM would have "
                "no height"
            )
        grid = like
    return float(grid.west), float(grid.north), int(grid.width), int(grid.height)
