"""A window of a DEM file as the models layer's :class:`~jaxgeo.models.DEMGrid`.

The window covering a WGS84 area is read on the host, nodata becomes NaN and orthometric
heights get the geoid undulation of each cell centre, so the grid holds ellipsoidal heights.
Rasters in geographic WGS84 (or in the degrees of a datum PROJ takes as WGS84 there, e.g. NAD83)
and WGS84 UTM are kept on their own grid (the models layer samples both exactly); any other CRS
is resampled (bilinear) onto a geographic grid of about the same cell size, on the host.
"""

from __future__ import annotations

import math

import numpy as np

from ..models import DEMGrid
from ._dem import implausible

__all__ = ["dem_coverage", "dem_grid"]


def dem_coverage(dem, bounds_lonlat) -> float:
    """Fraction (0..1) of the lon/lat box ``bounds_lonlat`` inside the DEM's footprint."""
    w, s, e, n = (float(v) for v in bounds_lonlat)
    bw, bs, be, bn = dem.bounds_lonlat
    iw, ie = max(w, bw), min(e, be)
    is_, in_ = max(s, bs), min(n, bn)
    area = max(e - w, 1e-12) * max(n - s, 1e-12)
    return max(ie - iw, 0.0) * max(in_ - is_, 0.0) / area


def _utm_zone_of(crs) -> int:
    """Signed WGS84 UTM zone of a pyproj CRS (north positive), 0 when it is not one."""
    epsg = crs.to_epsg() or 0
    if 32601 <= epsg <= 32660:
        return epsg - 32600
    if 32701 <= epsg <= 32760:
        return -(epsg - 32700)
    return 0


def _wgs84_degrees(crs, bounds_lonlat) -> bool:
    """Whether a geographic ``crs`` holds WGS84's own degrees over the box: its datum is one PROJ
    takes as WGS84 there (NAD83, ETRS89... without a grid shift: a null transformation, as the
    host-side :class:`~jaxgeo.io.DEM` reads it). Its grid is then kept as it is: a resampled
    copy interpolates twice (0.5 m of height on shareloc's 30" MNT, 1.2e-6 deg on the ground
    a line of sight meets it)."""
    import pyproj

    if not crs.is_geographic or any(
        a.unit_name not in ("degree", "degrees") for a in crs.axis_info
    ):
        return False
    w, s, e, n = bounds_lonlat
    lon, lat = np.array([w, e, w, e, 0.5 * (w + e)]), np.array([s, s, n, n, 0.5 * (s + n)])
    try:
        x, y = pyproj.Transformer.from_crs(4326, crs, always_xy=True).transform(lon, lat)
    except pyproj.exceptions.ProjError:
        return False
    return bool(
        np.all(np.abs(np.asarray(x) - lon) < 1e-10) and np.all(np.abs(np.asarray(y) - lat) < 1e-10)
    )


def dem_grid(dem, bounds_lonlat, margin_cells: int = 2) -> DEMGrid:
    """Read the window of ``dem`` (an :class:`jaxgeo.io.DEM`) over ``bounds_lonlat``.

    ``bounds_lonlat`` is ``(lon_min, lat_min, lon_max, lat_max)``; ``margin_cells`` cells are
    added around it. Raises ``ValueError`` naming the file and the covered fraction when the DEM
    does not cover the whole box, or when the window holds only nodata.
    """
    import pyproj
    import rasterio
    from rasterio.warp import Resampling, reproject, transform_bounds
    from rasterio.windows import Window, from_bounds

    w, s, e, n = (float(v) for v in bounds_lonlat)
    if not (e > w and n > s):
        raise ValueError(f"{dem.path}: empty area requested {bounds_lonlat}")
    cover = dem_coverage(dem, bounds_lonlat)
    if cover < 1.0 - 1e-9:
        b = dem.bounds_lonlat
        raise ValueError(
            f"{dem.path}: the DEM covers only {100 * cover:.1f}% of the area needed (lon "
            f"{w:.5f}..{e:.5f}, lat {s:.5f}..{n:.5f}); it spans lon {b[0]:.5f}..{b[2]:.5f}, lat "
            f"{b[1]:.5f}..{b[3]:.5f}: use a DEM that covers the whole footprint"
        )
    with rasterio.open(dem.path) as src:
        crs = pyproj.CRS.from_wkt(src.crs.to_wkt())
        if crs.is_compound:
            crs = next((c for c in crs.sub_crs_list if not c.is_vertical), crs.sub_crs_list[0])
        t = src.transform
        box = transform_bounds("EPSG:4326", src.crs, w, s, e, n, densify_pts=21)
        win = from_bounds(*box, transform=t)
        c0 = max(int(math.floor(win.col_off)) - margin_cells, 0)
        r0 = max(int(math.floor(win.row_off)) - margin_cells, 0)
        c1 = min(int(math.ceil(win.col_off + win.width)) + margin_cells, src.width)
        r1 = min(int(math.ceil(win.row_off + win.height)) + margin_cells, src.height)
        window = Window(c0, r0, max(c1 - c0, 2), max(r1 - r0, 2))
        band = src.read(1, window=window, masked=True)
        wt = src.window_transform(window)
        z = np.ma.filled(band.astype(float), np.nan)
        z[implausible(z)] = np.nan  # non-finite, or a void marker the file does not declare
        src_crs = src.crs
    wgs84 = pyproj.CRS.from_epsg(4326)
    zone = _utm_zone_of(crs)
    if crs.equals(wgs84, ignore_axis_order=True) or zone != 0 or _wgs84_degrees(crs, (w, s, e, n)):
        if wt.b != 0 or wt.d != 0:
            zone, geographic = None, False  # rotated: resample below
        else:
            geographic = zone == 0
    else:
        zone = None
    if zone is None:
        # any other CRS (or a rotated grid): resample onto a geographic grid of similar cell size
        lat_mid = 0.5 * (s + n)
        cell_m = math.sqrt(abs(wt.a * wt.e - wt.b * wt.d))
        if crs.is_geographic:
            cell_m *= 111_320.0
        dlat = cell_m / 111_320.0
        dlon = dlat / max(math.cos(math.radians(lat_mid)), 1e-6)
        cols = int(math.ceil((e - w) / dlon)) + 2 * margin_cells + 1
        rows = int(math.ceil((n - s) / dlat)) + 2 * margin_cells + 1
        from affine import Affine

        dst_t = Affine(dlon, 0, w - (margin_cells + 0.5) * dlon, 0, -dlat,
                       n + (margin_cells + 0.5) * dlat)  # fmt: skip
        out = np.full((rows, cols), np.nan)
        reproject(z, out, src_transform=wt, src_crs=src_crs, src_nodata=np.nan,
                  dst_transform=dst_t, dst_crs="EPSG:4326", dst_nodata=np.nan,
                  resampling=Resampling.bilinear)  # fmt: skip
        z, wt, zone, geographic = out, dst_t, 0, True
    rows, cols = z.shape
    origin = (wt.c + 0.5 * wt.a, wt.f + 0.5 * wt.e)
    step = (wt.a, wt.e)
    if dem.geoid is not None or dem.offset_m:
        cc, rr = np.meshgrid(np.arange(cols), np.arange(rows))
        x, y = origin[0] + cc * step[0], origin[1] + rr * step[1]
        if geographic:
            lon, lat = x, y
        else:
            to_ll = pyproj.Transformer.from_crs(crs, wgs84, always_xy=True)
            lon, lat = to_ll.transform(x, y)
        if dem.geoid is not None:
            z = z + dem.geoid(lon, lat)
        z = z + dem.offset_m
    if not np.any(np.isfinite(z)):
        raise ValueError(f"{dem.path}: the DEM holds only nodata over lon {w:.5f}..{e:.5f}, "
                         f"lat {s:.5f}..{n:.5f}")  # fmt: skip
    return DEMGrid(z, origin, step, utm_zone=zone)
