"""DSM rasterisation: one height per cell from the 3D points in it.

Points ``(lon_deg, lat_deg, h_m)`` are projected to a map CRS (local UTM by default), each
falls in one cell of a north-up grid of ``res_m`` cells; a cell's height is the median of its
points (ellipsoidal metres), with the point count and spread (standard deviation) as extra
bands. Empty cells are NaN. The GeoTIFF is tiled (256 x 256), DEFLATE, written atomically.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from ..geodesy import utm_epsg, utm_zone
from ..io import atomic_output


@dataclass(frozen=True)
class DSMGrid:
    """A rasterised DSM: ``height``, ``count``, ``spread`` ``(rows, cols)``; ``x0, y0`` the map
    coordinates of the upper-left corner of the first cell; ``res_m``; ``epsg``."""

    height: np.ndarray
    count: np.ndarray
    spread: np.ndarray
    x0: float
    y0: float
    res_m: float
    epsg: int

    @property
    def transform(self):
        from affine import Affine

        return Affine(self.res_m, 0.0, self.x0, 0.0, -self.res_m, self.y0)


def local_utm_epsg(lon_deg: float, lat_deg: float) -> int:
    """EPSG code of the UTM zone of a point (north or south)."""
    return utm_epsg(utm_zone(lon_deg, lat_deg), north=lat_deg >= 0)


def to_map(points: np.ndarray, epsg: int) -> np.ndarray:
    """``(n, 3)`` lon/lat/h -> ``(n, 3)`` map x, y and h."""
    import pyproj

    tr = pyproj.Transformer.from_crs(4326, epsg, always_xy=True)
    x, y = tr.transform(points[:, 0], points[:, 1])
    return np.stack([np.asarray(x), np.asarray(y), points[:, 2]], axis=-1)


def rasterize(
    points: np.ndarray,
    res_m: float,
    epsg: int | None = None,
    origin: tuple[float, float] | None = None,
    shape: tuple[int, int] | None = None,
) -> DSMGrid:
    """Grid ``(n, 3)`` lon/lat/h points (NaN rows ignored) at ``res_m``.

    ``epsg`` default: the local UTM zone of the points' median; ``origin`` (upper-left corner)
    and ``shape`` default to the points' extent snapped to multiples of ``res_m``.
    """
    if res_m <= 0:
        raise ValueError(f"rasterize: resolution must be positive, got {res_m}")
    points = np.asarray(points, dtype=float)
    points = points[np.all(np.isfinite(points), axis=1)]
    if points.shape[0] == 0:
        raise ValueError("rasterize: no valid 3D point")
    if epsg is None:
        lon, lat = np.median(points[:, 0]), np.median(points[:, 1])
        epsg = local_utm_epsg(float(lon), float(lat))
    xyh = to_map(points, epsg)
    if origin is None:
        origin = (
            float(np.floor(xyh[:, 0].min() / res_m) * res_m),
            float(np.ceil(xyh[:, 1].max() / res_m) * res_m),
        )
    x0, y0 = origin
    if shape is None:
        shape = (
            int(np.ceil((y0 - xyh[:, 1].min()) / res_m)) + 1,
            int(np.ceil((xyh[:, 0].max() - x0) / res_m)) + 1,
        )
    rows, cols = shape
    col = np.floor((xyh[:, 0] - x0) / res_m).astype(np.int64)
    row = np.floor((y0 - xyh[:, 1]) / res_m).astype(np.int64)
    inside = (row >= 0) & (row < rows) & (col >= 0) & (col < cols)
    cell, h = row[inside] * cols + col[inside], xyh[inside, 2]
    order = np.lexsort((h, cell))
    cell, h = cell[order], h[order]
    count = np.bincount(cell, minlength=rows * cols)
    start = np.concatenate([[0], np.cumsum(count)[:-1]])
    filled = count > 0
    lo = start[filled] + (count[filled] - 1) // 2
    hi = start[filled] + count[filled] // 2
    height = np.full(rows * cols, np.nan)
    height[filled] = 0.5 * (h[lo] + h[hi])
    total = np.bincount(cell, weights=h, minlength=rows * cols)
    total2 = np.bincount(cell, weights=h * h, minlength=rows * cols)
    spread = np.full(rows * cols, np.nan)
    mean = total[filled] / count[filled]
    spread[filled] = np.sqrt(np.maximum(total2[filled] / count[filled] - mean**2, 0.0))
    return DSMGrid(
        height=height.reshape(shape).astype(np.float32),
        count=count.reshape(shape).astype(np.uint16 if count.max() < 65535 else np.uint32),
        spread=spread.reshape(shape).astype(np.float32),
        x0=float(x0),
        y0=float(y0),
        res_m=float(res_m),
        epsg=int(epsg),
    )


def write_dsm(dsm: DSMGrid, path: str | os.PathLike, overwrite: bool = False):
    """Tiled GeoTIFF: band 1 height (float32, NaN nodata, ellipsoidal m), band 2 count, band 3
    spread (m)."""
    import rasterio

    rows, cols = dsm.height.shape
    profile = dict(
        driver="GTiff",
        width=cols,
        height=rows,
        count=3,
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
    with out as tmp, rasterio.open(tmp, "w", **profile) as dst:
        dst.write(dsm.height, 1)
        dst.write(dsm.count.astype(np.float32), 2)
        dst.write(dsm.spread, 3)
        dst.set_band_description(1, "height above WGS84 ellipsoid (m), median")
        dst.set_band_description(2, "number of points")
        dst.set_band_description(3, "standard deviation of the points' heights (m)")
    return path
