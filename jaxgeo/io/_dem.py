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
"""

from __future__ import annotations

import dataclasses
import math
import os
import pathlib
import warnings
from typing import Any

import numpy as np

from ..errors import JaxgeoWarning
from ..models import AbstractDEM

__all__ = ["DEM", "PLAUSIBLE_HEIGHTS_M", "implausible", "read_dem"]

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
    lat_min, lon_max, lat_max)`` the raster footprint in WGS84 degrees; ``vertical_crs`` the
    name of a vertical CRS the file declares (``None`` if it declares none); ``offset_m``.
    """

    path: pathlib.Path
    shape: tuple[int, int]
    crs: str | None
    bounds_lonlat: tuple[float, float, float, float]
    vertical_crs: str | None
    offset_m: float
    _inverse: Any = dataclasses.field(repr=False)  # world (x, y) -> (col, row), corner-based
    _transformer: Any = dataclasses.field(repr=False)  # WGS84 lon/lat -> raster CRS, or None
    height_reference: str = "ellipsoidal"  # of the file's values; "orthometric": geoid added
    geoid: Any = dataclasses.field(default=None, repr=False)  # io.geoid.GeoidGrid or None

    def describe(self) -> str:
        """The height reference assumed, in words (the CLI prints it)."""
        if self.height_reference == "orthometric":
            name = pathlib.Path(str(self.geoid.source)).name
            ref = f"orthometric heights + {name} undulation -> ellipsoidal"
        else:
            ref = "ellipsoidal heights (WGS84), as read"
        if self.offset_m:
            ref += f", {self.offset_m:+g} m offset"
        return f"DEM {self.path.name}: {ref}"

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

    def __call__(self, lonlat) -> np.ndarray:
        """Ellipsoidal heights (m) at ``lonlat`` ``(..., 2)`` (lon, lat degrees)."""
        import rasterio
        from rasterio.errors import RasterioError
        from rasterio.windows import Window

        pts = np.asarray(lonlat, dtype=float)
        if pts.ndim < 1 or pts.shape[-1] != 2:
            raise ValueError(f"{self.path}: DEM points must have shape (..., 2) lon, lat; got "
                             f"{pts.shape}")  # fmt: skip
        batch = pts.shape[:-1]
        pts = pts.reshape(-1, 2)
        n = len(pts)
        if n == 0:
            return np.zeros(batch)
        bad = ~np.all(np.isfinite(pts), axis=1)
        if bad.any():
            raise ValueError(
                f"{self.path}: {int(bad.sum())} of {n} points have non-finite lon/lat "
                f"(first at index {int(np.flatnonzero(bad)[0])})"
            )
        col, row = self._index(pts)
        rows, cols = self.shape
        with np.errstate(invalid="ignore"):
            outside = ~((col >= 0) & (col <= cols) & (row >= 0) & (row <= rows))
        if outside.any():
            b = self.bounds_lonlat
            raise ValueError(
                f"{self.path}: {int(outside.sum())} of {n} points lie outside the DEM "
                f"({_span(pts[outside])}); it covers lon {b[0]:.5f}..{b[2]:.5f}, lat "
                f"{b[1]:.5f}..{b[3]:.5f}: the DEM must cover the whole area"
            )
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
            with rasterio.open(self.path) as src:
                band = src.read(1, window=window, masked=True)
        except RasterioError as err:  # e.g. a truncated or corrupt file
            raise ValueError(f"{self.path}: cannot read the DEM's heights ({err})") from None
        z = np.ma.getdata(band).astype(float)
        invalid = np.ma.getmaskarray(band) | implausible(z)
        z = np.where(invalid, 0.0, z)
        h = np.zeros(n)
        hole = np.zeros(n, dtype=bool)
        for r, c, w in (
            (r0, c0, (1 - tr) * (1 - tc)),
            (r0, c1, (1 - tr) * tc),
            (r1, c0, tr * (1 - tc)),
            (r1, c1, tr * tc),
        ):
            rr, cc = r - wr0, c - wc0
            h += w * z[rr, cc]
            hole |= invalid[rr, cc] & (w > 0)
        if hole.any():
            raise ValueError(
                f"{self.path}: {int(hole.sum())} of {n} points fall on nodata cells of the DEM "
                f"({_span(pts[hole])}): fill the voids or use a DEM that covers the whole area"
            )
        if self.geoid is not None:
            h = h + self.geoid(pts[:, 0], pts[:, 1])
        return (h + self.offset_m).reshape(batch)


def read_dem(
    path: str | os.PathLike,
    offset_m: float = 0.0,
    *,
    height: str | None = None,
    geoid: str | os.PathLike | None = None,
) -> DEM:
    """Open a single-band height raster (GeoTIFF or anything rasterio reads) as a :class:`DEM`.

    Args:
        path: the raster; its CRS may be any (geographic or projected, e.g. UTM); nodata cells
            (the nodata value, a mask band, or NaN) are refused when a point needs them.
        offset_m: added to every height: e.g. a constant geoid undulation ``N`` (m) to turn
            orthometric heights ``H`` into ellipsoidal ``h = H + N`` over a small area. jaxgeo
            takes the result as WGS84 ellipsoidal heights (see the module docstring).
        height: ``"ellipsoidal"`` (values are WGS84 ellipsoidal heights) or ``"orthometric"``
            (values are above the geoid ``geoid``; ``h = H + N``). ``None``: orthometric with
            the file's own vertical CRS when it declares EGM96/EGM2008, else ellipsoidal.
        geoid: ``"egm96"``, ``"egm2008"`` (PROJ grids pyproj finds) or a geoid grid file path
            (GTX/GeoTIFF); only with orthometric heights.

    Raises ``FileNotFoundError`` for a missing path, ``ValueError`` naming the file when it is
    not a raster, has more than one band, or has no CRS or transform.
    """
    import pyproj
    import rasterio
    from rasterio.errors import NotGeoreferencedWarning, RasterioIOError
    from rasterio.warp import transform_bounds

    path = pathlib.Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: DEM file not found")
    offset_m = float(offset_m)
    if not math.isfinite(offset_m):
        raise ValueError(f"{path}: offset_m must be finite, got {offset_m}")
    try:
        with warnings.catch_warnings():  # no transform: refused below, with the file named
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            src = rasterio.open(path)
    except RasterioIOError as err:
        raise ValueError(f"{path}: not a raster rasterio/GDAL can read ({err})") from None
    with src:
        if src.count != 1:
            raise ValueError(f"{path}: a DEM must have one band, this raster has {src.count}")
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
    reference, geoid_grid = _height_reference(path, vertical, height, geoid)
    _warn_implausible(path)
    return DEM(path, shape, crs_out, bounds_lonlat, vertical, offset_m, inverse, transformer,
               reference, geoid_grid)  # fmt: skip


def _height_reference(path, vertical: str | None, height, geoid):
    """Resolve ``(height, geoid)`` against the file's vertical CRS -> (reference, GeoidGrid)."""
    from ._geoid import read_geoid

    if height not in (None, "ellipsoidal", "orthometric"):
        raise ValueError(f"{path}: height must be 'ellipsoidal' or 'orthometric', got {height!r}")
    declared = None
    if vertical is not None:
        v = vertical.upper().replace(" ", "")
        declared = (
            "egm2008" if ("EGM2008" in v or "EGM08" in v) else "egm96" if "EGM96" in v else None
        )
    if height is None:
        if geoid is not None or declared is not None:
            height = "orthometric"
        elif vertical is not None:
            raise ValueError(f"{path}: the file declares vertical CRS {vertical!r}, which jaxgeo "
                             "does not know: pass height= and geoid= explicitly")  # fmt: skip
        else:
            height = "ellipsoidal"
    if height == "ellipsoidal":
        if geoid is not None:
            raise ValueError(f"{path}: a geoid only applies to orthometric heights "
                             "(height='orthometric')")  # fmt: skip
        return "ellipsoidal", None
    geoid = geoid if geoid is not None else declared
    if geoid is None:
        raise ValueError(f"{path}: orthometric heights need a geoid ('egm96', 'egm2008' or a "
                         "geoid grid file)")  # fmt: skip
    return "orthometric", read_geoid(geoid)


def _warn_implausible(path: pathlib.Path, max_cells: int = 4_000_000) -> None:
    """Warn (naming the file) when valid-looking cells hold impossible heights: an undeclared
    void marker such as -32768. They are read as nodata. Large rasters are checked on a
    decimated read."""
    import rasterio
    from rasterio.errors import RasterioError

    try:
        with rasterio.open(path) as src:
            scale = max(1, math.ceil(math.sqrt(src.width * src.height / max_cells)))
            shape = (max(src.height // scale, 1), max(src.width // scale, 1))
            band = src.read(1, out_shape=shape, masked=True)
    except RasterioError as err:  # a truncated or corrupt file: refused when opened
        raise ValueError(f"{path}: cannot read the DEM's heights ({err})") from None
    z = np.ma.getdata(band).astype(float)
    bad = implausible(z) & ~np.ma.getmaskarray(band) & np.isfinite(z)
    if bad.any():
        values = np.unique(z[bad])
        shown = ", ".join(f"{v:g}" for v in values[:3]) + (", ..." if len(values) > 3 else "")
        warnings.warn(
            f"{path}: {100 * bad.mean():.2g}% of the cells hold heights no terrain has ({shown}; "
            f"plausible: {PLAUSIBLE_HEIGHTS_M[0]:g}..{PLAUSIBLE_HEIGHTS_M[1]:g} m) without being "
            "declared nodata: they are read as nodata (voids)",
            JaxgeoWarning,
            stacklevel=3,
        )
