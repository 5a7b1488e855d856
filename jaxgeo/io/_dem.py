"""Digital elevation models: heights at ``(lon, lat)`` from a single-band raster (GeoTIFF ...).

    dem = read_dem("srtm_ellipsoidal.tif")
    h_m = dem(np.array([[74.5, 27.0], [74.6, 27.1]]))   # (n, 2) lon, lat deg -> (n,) metres

:func:`read_dem` opens any raster rasterio (GDAL) reads, in any CRS: geographic WGS84 rasters
are sampled directly, others through a pyproj transformation of the WGS84 ``(lon, lat)`` to the
raster CRS. Heights are interpolated bilinearly between pixel centres (the usual raster
convention: a pixel's value belongs to its centre); in the outer half pixel of the raster the
edge value is held along the axis that leaves the grid.

Heights are taken as **ellipsoidal** metres on WGS84, like every height in jaxgeo. Most
distributed DEMs (SRTM, Copernicus DEM, ASTER GDEM, ALOS AW3D30) give orthometric heights
above a geoid (EGM96 / EGM2008), tens of metres away from the ellipsoid: convert them first
(e.g. ``gdalwarp -t_srs EPSG:4979`` from a compound source CRS, or add a geoid undulation
grid), or, for a small area where the undulation ``N`` is nearly constant, pass
``offset_m=N`` (``h = H + N``). :attr:`DEM.vertical_crs` names the vertical CRS the file
declares, if any.

A point outside the raster or on a nodata cell raises a ``ValueError`` naming the file, how
many points are affected and where: the DEM must cover everything it is asked about. Values no
terrain has (outside :data:`PLAUSIBLE_HEIGHTS_M`, e.g. an undeclared void value -32768 or -9999)
are nodata, whatever the file declares, and :func:`read_dem` warns when a file holds them.

**A jaxgeo DSM is a DEM.** A raster of several bands is read at its band described ``height``
(what :func:`jaxgeo.stereo.make_dsm` writes: ``height``, ``count``, ``spread``, ...); its NaN
cells (occlusions, water, outside the stereo overlap) are holes, and its heights are ellipsoidal
as its ``heights`` tag declares (a geoid is refused for it). Any other multi-band raster needs
``band=``.

**Holes filled from a second DEM.** ``read_dem("dsm.tif", fill=read_dem("srtm.tif",
geoid="egm96"))``: where the first has no height (its holes, beyond its edges), the second's is
used. Each DEM makes its own values ellipsoidal (its own ``height=`` / ``geoid=`` or its file's
declaration) before one fills the other, so an orthometric SRTM fills an ellipsoidal DSM
correctly, in any CRS. Where both have heights their median difference is measured
(:attr:`DEM.fill_difference_m`, printed by :meth:`DEM.describe`), and a difference over
:data:`FILL_MISMATCH_M` is warned about: the sign of a vertical datum given wrongly.
"""

from __future__ import annotations

import dataclasses
import math
import os
import pathlib
from typing import Any

import numpy as np

from ..models import AbstractDEM
from ._remote import RemotePath

__all__ = ["DEM", "FILL_MISMATCH_M", "PLAUSIBLE_HEIGHTS_M", "implausible", "read_dem"]

FILL_MISMATCH_M = 10.0
"""Median difference (m) between a DEM and its fill DEM, where both have heights, above which
:func:`read_dem` warns: terrain seen by two DEMs (a DSM with its trees and roofs, a bare-earth
DEM) differs by metres, a geoid left out or counted twice by tens of metres."""

HEIGHT_BAND = "height"
"""The description of a jaxgeo DSM's band of heights (``jaxgeo.stereo``'s ``DSM_BANDS``)."""

PLAUSIBLE_HEIGHTS_M = (-500.0, 9000.0)
"""Heights (m) a DEM value may take (the Dead Sea shore to above Everest, geoid to ellipsoid
included); anything else is a void marker or garbage and is read as nodata."""


def implausible(z: np.ndarray) -> np.ndarray:
    """Where DEM values are non-finite or outside :data:`PLAUSIBLE_HEIGHTS_M`."""
    lo, hi = PLAUSIBLE_HEIGHTS_M
    with np.errstate(invalid="ignore"):
        return ~((z >= lo) & (z <= hi))


def _span(lonlat: np.ndarray) -> str:
    lo, hi = np.nanmin(lonlat, axis=0), np.nanmax(lonlat, axis=0)
    return f"lon {lo[0]:.5f}..{hi[0]:.5f}, lat {lo[1]:.5f}..{hi[1]:.5f}"


@dataclasses.dataclass(frozen=True, eq=False)
class DEM(AbstractDEM):
    """A height raster opened by :func:`read_dem`; call it as ``dem(lonlat) -> h``.

    ``lonlat`` ``(..., 2)`` WGS84 ``(lon_deg, lat_deg)`` -> ``(...)`` ellipsoidal heights (m),
    bilinear between pixel centres, plus ``offset_m``. The band is read on each call, only the
    window the points need, so a large DEM costs no memory until it is used.

    Attributes: ``path``; ``shape`` ``(rows, cols)``; ``crs`` (the raster CRS as WKT, ``None``
    when it is WGS84 lon/lat and no transformation is needed); ``bounds_lonlat`` ``(lon_min,
    lat_min, lon_max, lat_max)`` the raster footprint in WGS84 degrees (with a ``fill``: the box
    around both footprints, ``raster_bounds_lonlat`` the raster's own); ``vertical_crs`` the
    name of a vertical CRS the file declares (``None`` if it declares none); ``offset_m``;
    ``band`` the band of heights (1-based); ``fill`` the :class:`DEM` that gives the heights
    this one lacks (``None``: none) and ``fill_difference_m`` the median of this DEM minus the
    fill where both have heights (m, ``None``: no common cell).
    """

    path: pathlib.Path | RemotePath  # a URL: read by range requests
    shape: tuple[int, int]
    crs: str | None
    bounds_lonlat: tuple[float, float, float, float]
    vertical_crs: str | None
    offset_m: float
    _inverse: Any = dataclasses.field(repr=False)  # world (x, y) -> (col, row), corner-based
    _transformer: Any = dataclasses.field(repr=False)  # WGS84 lon/lat -> raster CRS, or None
    height_reference: str = "ellipsoidal"  # of the file's values; "orthometric": geoid added
    geoid: Any = dataclasses.field(default=None, repr=False)  # io.geoid.GeoidGrid or None
    band: int = 1
    fill: DEM | None = None
    raster_bounds_lonlat: tuple[float, float, float, float] | None = None  # None: bounds_lonlat
    fill_difference_m: float | None = None

    def describe(self) -> str:
        """The height reference assumed, in words (the CLI prints it)."""
        if self.height_reference == "orthometric":
            name = pathlib.Path(str(self.geoid.source)).name
            ref = f"orthometric heights + {name} undulation -> ellipsoidal"
        else:
            ref = "ellipsoidal heights (WGS84), as read"
        if self.offset_m:
            ref += f", {self.offset_m:+g} m offset"
        what = f"DEM {self.path.name}" + (f" (band {self.band})" if self.band != 1 else "")
        text = f"{what}: {ref}"
        if self.fill is not None:
            diff = ("no cell in common" if self.fill_difference_m is None else
                    f"median difference {self.fill_difference_m:+.2f} m where both have "
                    "heights")  # fmt: skip
            text += f"; its holes filled from {self.fill.describe()} ({diff})"
        return text

    @property
    def inputs(self) -> list[pathlib.Path | RemotePath]:
        """The files this DEM reads: the raster, a geoid file, and those of its fill."""
        out = [self.path]
        if self.geoid is not None and pathlib.Path(str(self.geoid.source)).is_file():
            out.append(pathlib.Path(str(self.geoid.source)))
        return out + (self.fill.inputs if self.fill is not None else [])

    @property
    def own_bounds_lonlat(self) -> tuple[float, float, float, float]:
        """The WGS84 box of this DEM's own raster (``bounds_lonlat`` also spans the fill)."""
        return self.raster_bounds_lonlat or self.bounds_lonlat

    def grid(self, bounds_lonlat, margin_cells: int = 2):
        """The DEM over ``(lon_min, lat_min, lon_max, lat_max)`` as a models-layer ``DEMGrid``.

        Ellipsoidal heights (geoid added), NaN on nodata; raises ``ValueError`` saying how much
        of the area the DEM covers when it does not cover all of it (see ``io.dem_grid``).
        """
        from ._dem_grid import dem_grid

        return dem_grid(self, bounds_lonlat, margin_cells)

    def _index(self, lonlat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Fractional corner-based ``(col, row)`` of WGS84 points (NaN where they cannot map)."""
        x, y = lonlat[:, 0], lonlat[:, 1]
        if self._transformer is not None:
            with np.errstate(invalid="ignore"):
                x, y = self._transformer.transform(x, y)
            x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
        a = self._inverse
        col = a.a * x + a.b * y + a.c
        row = a.d * x + a.e * y + a.f
        return col, row

    def _points(self, lonlat) -> tuple[np.ndarray, tuple[int, ...]]:
        pts = np.asarray(lonlat, dtype=float)
        if pts.ndim < 1 or pts.shape[-1] != 2:
            raise ValueError(f"{self.path}: DEM points must have shape (..., 2) lon, lat; got "
                             f"{pts.shape}")  # fmt: skip
        return pts.reshape(-1, 2), pts.shape[:-1]

    def _own(self, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Heights of this DEM's own raster at finite ``pts`` ``(n, 2)`` (geoid and offset
        added; NaN where it has none) and the masks of the points outside it and on nodata."""
        from rasterio.errors import RasterioError
        from rasterio.windows import Window

        from ._raster import open_raster

        n = len(pts)
        col, row = self._index(pts)
        rows, cols = self.shape
        with np.errstate(invalid="ignore"):
            outside = ~((col >= 0) & (col <= cols) & (row >= 0) & (row <= rows))
        h = np.full(n, np.nan)
        hole = np.zeros(n, dtype=bool)
        inside = np.flatnonzero(~outside)
        if len(inside) == 0:
            return h, outside, hole
        col, row = col[inside], row[inside]
        # pixel centres at integer + 0.5 (corner-based); held at the edge in the outer half pixel
        fc = np.clip(col - 0.5, 0.0, cols - 1.0)
        fr = np.clip(row - 0.5, 0.0, rows - 1.0)
        c0 = np.minimum(np.floor(fc).astype(np.int64), max(cols - 2, 0))
        r0 = np.minimum(np.floor(fr).astype(np.int64), max(rows - 2, 0))
        tc, tr = fc - c0, fr - r0
        c1, r1 = np.minimum(c0 + 1, cols - 1), np.minimum(r0 + 1, rows - 1)
        wc0, wr0 = int(c0.min()), int(r0.min())
        window = Window(wc0, wr0, int(c1.max()) - wc0 + 1, int(r1.max()) - wr0 + 1)
        try:
            with open_raster(self.path) as src:
                band = src.read(self.band, window=window, masked=True)
        except RasterioError as err:  # e.g. a truncated or corrupt file
            raise ValueError(f"{self.path}: cannot read the DEM's heights ({err})") from None
        z = np.ma.getdata(band).astype(float)
        invalid = np.ma.getmaskarray(band) | implausible(z)
        z = np.where(invalid, 0.0, z)
        hi = np.zeros(len(inside))
        hole_in = np.zeros(len(inside), dtype=bool)
        for r, c, w in (
            (r0, c0, (1 - tr) * (1 - tc)),
            (r0, c1, (1 - tr) * tc),
            (r1, c0, tr * (1 - tc)),
            (r1, c1, tr * tc),
        ):
            rr, cc = r - wr0, c - wc0
            hi += w * z[rr, cc]
            hole_in |= invalid[rr, cc] & (w > 0)
        if self.geoid is not None:
            hi = hi + self.geoid(pts[inside, 0], pts[inside, 1])
        hi = np.where(hole_in, np.nan, hi + self.offset_m)
        h[inside] = hi
        hole[inside] = hole_in
        return h, outside, hole

    def sample(self, lonlat) -> np.ndarray:
        """Ellipsoidal heights (m) at ``lonlat`` ``(..., 2)``, NaN where neither this DEM nor
        its fill has one (outside, nodata, non-finite points): :meth:`__call__` without its
        errors."""
        pts, batch = self._points(lonlat)
        h = np.full(len(pts), np.nan)
        finite = np.flatnonzero(np.all(np.isfinite(pts), axis=1))
        if len(finite):
            h[finite] = self._own(pts[finite])[0]
        missing = finite[np.isnan(h[finite])]
        if self.fill is not None and len(missing):
            h[missing] = self.fill.sample(pts[missing])
        return h.reshape(batch)

    def __call__(self, lonlat) -> np.ndarray:
        """Ellipsoidal heights (m) at ``lonlat`` ``(..., 2)`` (lon, lat degrees)."""
        pts, batch = self._points(lonlat)
        n = len(pts)
        if n == 0:
            return np.zeros(batch)
        bad = ~np.all(np.isfinite(pts), axis=1)
        if bad.any():
            raise ValueError(
                f"{self.path}: {int(bad.sum())} of {n} points have non-finite lon/lat "
                f"(first at index {int(np.flatnonzero(bad)[0])})"
            )
        h, outside, hole = self._own(pts)
        if self.fill is not None:
            missing = np.isnan(h)
            if missing.any():
                h[missing] = self.fill.sample(pts[missing])
            left = np.isnan(h)
            if left.any():
                raise ValueError(
                    f"{self.path}: {int(left.sum())} of {n} points have no height, neither in "
                    f"this DEM nor in its fill {self.fill.path} ({_span(pts[left])})"
                )
            return h.reshape(batch)
        if outside.any():
            b = self.bounds_lonlat
            raise ValueError(
                f"{self.path}: {int(outside.sum())} of {n} points lie outside the DEM "
                f"({_span(pts[outside])}); it covers lon {b[0]:.5f}..{b[2]:.5f}, lat "
                f"{b[1]:.5f}..{b[3]:.5f}: the DEM must cover the whole area"
            )
        if hole.any():
            raise ValueError(
                f"{self.path}: {int(hole.sum())} of {n} points fall on nodata cells of the DEM "
                f"({_span(pts[hole])}): fill the voids (a fill DEM: fill=) or use a DEM that "
                "covers the whole area"
            )
        return h.reshape(batch)


def read_dem(
    path: str | os.PathLike,
    offset_m: float = 0.0,
    *,
    height: str | None = None,
    geoid: str | os.PathLike | None = None,
    band: int | None = None,
    fill: DEM | None = None,
) -> DEM:
    """Open a height raster (GeoTIFF or anything rasterio reads, a jaxgeo DSM) as a :class:`DEM`.

    Args:
        path: the raster; its CRS may be any (geographic or projected, e.g. UTM); nodata cells
            (the nodata value, a mask band, or NaN) are refused when a point needs them, unless
            ``fill`` has a height there.
        offset_m: added to every height: e.g. a constant geoid undulation ``N`` (m) to turn
            orthometric heights ``H`` into ellipsoidal ``h = H + N`` over a small area. jaxgeo
            takes the result as WGS84 ellipsoidal heights (see the module docstring).
        height: ``"ellipsoidal"`` (values are WGS84 ellipsoidal heights) or ``"orthometric"``
            (values are above the geoid ``geoid``; ``h = H + N``). ``None``: orthometric with
            the file's own vertical CRS when it declares EGM96/EGM2008, ellipsoidal when it
            declares that (a jaxgeo DSM), else ellipsoidal.
        geoid: ``"egm96"`` (PROJ's grid, else the one jaxgeo ships), ``"egm2008"`` (PROJ's
            grid) or a geoid grid file path (GTX/GeoTIFF); only with orthometric heights.
        band: the band of heights (1-based). ``None``: the only band, or the band described
            ``height`` (a jaxgeo DSM).
        fill: a :class:`DEM` whose heights are used where this one has none (its nodata cells,
            beyond its edges); already made ellipsoidal by its own ``read_dem`` arguments.

    Raises ``FileNotFoundError`` for a missing path, ``ValueError`` naming the file when it is
    not a raster, has several bands and none chosen, or has no CRS or transform.
    """
    import pyproj
    from rasterio.errors import RasterioIOError
    from rasterio.warp import transform_bounds

    from ._dem_checks import fill_difference, height_band, height_reference, warn_implausible
    from ._raster import open_raster
    from ._remote import as_path, is_remote  # (RemotePath: imported above, for the annotation)

    path = as_path(path)  # a URL stays one: GDAL reads the tiles it needs by range requests
    if not is_remote(path) and not path.exists():
        raise FileNotFoundError(f"{path}: DEM file not found")
    offset_m = float(offset_m)
    if not math.isfinite(offset_m):
        raise ValueError(f"{path}: offset_m must be finite, got {offset_m}")
    if fill is not None and not isinstance(fill, DEM):
        raise TypeError(f"fill must be a DEM (read_dem(...)), got {type(fill).__name__}")
    try:
        src = open_raster(path)  # no transform: refused below, with the file named
    except RasterioIOError as err:
        raise ValueError(f"{path}: not a raster rasterio/GDAL can read ({err})") from None
    with src:
        band, declared = height_band(path, src, band)
        if src.crs is None:
            raise ValueError(f"{path}: the raster has no CRS: cannot place it on the ground")
        if src.transform.is_identity or src.transform.determinant == 0:
            raise ValueError(f"{path}: the raster has no usable georeferencing transform")
        shape = (int(src.height), int(src.width))
        wkt = src.crs.to_wkt()
        inverse = ~src.transform
        bounds = src.bounds
        bounds_lonlat = tuple(float(v) for v in transform_bounds(src.crs, "EPSG:4326", *bounds))
    crs = pyproj.CRS.from_wkt(wkt)
    horizontal, vertical = crs, None
    if crs.is_compound:
        subs = crs.sub_crs_list
        horizontal = next((s for s in subs if not s.is_vertical), subs[0])
        vertical = next((s.name for s in subs if s.is_vertical), None)
    elif crs.is_vertical:
        raise ValueError(f"{path}: the raster CRS is vertical only ({crs.name})")
    wgs84 = pyproj.CRS.from_epsg(4326)
    if horizontal.equals(wgs84, ignore_axis_order=True):
        transformer, crs_out = None, None
    else:
        transformer = pyproj.Transformer.from_crs(wgs84, horizontal, always_xy=True)
        crs_out = wkt
    reference, geoid_grid = height_reference(path, vertical, height, geoid, declared)
    if not is_remote(path):  # (a decimated read of a whole file; such cells are nodata anyway)
        warn_implausible(path, band)
    dem = DEM(path, shape, crs_out, bounds_lonlat, vertical, offset_m, inverse, transformer,
              reference, geoid_grid, band)  # fmt: skip
    if fill is None:
        return dem
    fb = fill.bounds_lonlat
    union = (min(bounds_lonlat[0], fb[0]), min(bounds_lonlat[1], fb[1]),
             max(bounds_lonlat[2], fb[2]), max(bounds_lonlat[3], fb[3]))  # fmt: skip
    dem = dataclasses.replace(dem, fill=fill, bounds_lonlat=union,
                              raster_bounds_lonlat=bounds_lonlat)  # fmt: skip
    return dataclasses.replace(dem, fill_difference_m=fill_difference(dem))
