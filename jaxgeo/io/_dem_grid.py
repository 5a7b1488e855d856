"""A window of a DEM file as the models layer's :class:`~jaxgeo.models.DEMGrid`.

The window covering a WGS84 area is read on the host, nodata becomes NaN and orthometric
heights get the geoid undulation of each cell centre, so the grid holds ellipsoidal heights.
Rasters in geographic WGS84 (or in the degrees of a datum PROJ takes as WGS84 there, e.g. NAD83)
and WGS84 UTM are kept on their own grid (the models layer samples both exactly); any other CRS
is resampled (bilinear) onto a geographic grid of about the same cell size, on the host.

A DEM with a fill DEM (``read_dem(..., fill=)``) gives its grid over the whole area asked for,
beyond its own raster where the fill reaches: the cells without a height of their own take the
fill's (bilinear in the fill at the cell centre, ellipsoidal), so the grid keeps the first DEM's
cells and resolution.
"""

from __future__ import annotations

import math

import numpy as np

from ..models import DEMGrid
from ._dem import implausible

__all__ = ["MAX_FILLED_CELLS", "dem_coverage", "dem_grid"]

MAX_FILLED_CELLS = 16_000_000
"""Most cells of the grid of a DEM with a fill (128 MB of float64): a DSM of a small area at
0.5 m asked for over a whole scene (an ortho plan reads the whole footprint) is read with its
cells averaged by an integer factor beyond this, rather than exhaust the memory."""


def _footprints(dem) -> list[tuple[float, float, float, float]]:
    """The lon/lat boxes of a DEM's raster and of its fill DEMs' rasters."""
    out = []
    while dem is not None:
        out.append(getattr(dem, "own_bounds_lonlat", dem.bounds_lonlat))
        dem = getattr(dem, "fill", None)
    return out


def dem_coverage(dem, bounds_lonlat) -> float:
    """Fraction (0..1) of the lon/lat box ``bounds_lonlat`` inside the DEM's footprint (with
    a fill DEM: inside the union of the footprints)."""
    w, s, e, n = (float(v) for v in bounds_lonlat)
    area = max(e - w, 1e-12) * max(n - s, 1e-12)
    boxes = [(max(w, b[0]), max(s, b[1]), min(e, b[2]), min(n, b[3])) for b in _footprints(dem)]
    boxes = [b for b in boxes if b[2] > b[0] and b[3] > b[1]]
    if not boxes:
        return 0.0
    # exact area of a union of boxes: the cells between their edges, each in a box or not
    xs = sorted({v for b in boxes for v in (b[0], b[2])})
    ys = sorted({v for b in boxes for v in (b[1], b[3])})
    inside = 0.0
    for x0, x1 in zip(xs[:-1], xs[1:], strict=True):
        for y0, y1 in zip(ys[:-1], ys[1:], strict=True):
            cx, cy = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
            if any(b[0] <= cx <= b[2] and b[1] <= cy <= b[3] for b in boxes):
                inside += (x1 - x0) * (y1 - y0)
    return min(inside / area, 1.0)


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
    (with its fill) does not cover the whole box, or when the window holds only nodata.
    """
    import pyproj
    from affine import Affine
    from rasterio.warp import Resampling, reproject, transform_bounds
    from rasterio.windows import Window, from_bounds

    from ._raster import open_raster

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
    fill = getattr(dem, "fill", None)
    with open_raster(dem.path) as src:
        crs = pyproj.CRS.from_wkt(src.crs.to_wkt())
        if crs.is_compound:
            crs = next((c for c in crs.sub_crs_list if not c.is_vertical), crs.sub_crs_list[0])
        t = src.transform
        box = transform_bounds("EPSG:4326", src.crs, w, s, e, n, densify_pts=21)
        win = from_bounds(*box, transform=t)
        c0 = int(math.floor(win.col_off)) - margin_cells
        r0 = int(math.floor(win.row_off)) - margin_cells
        c1 = int(math.ceil(win.col_off + win.width)) + margin_cells
        r1 = int(math.ceil(win.row_off + win.height)) + margin_cells
        if fill is None:  # its own raster only; with a fill, the cells beyond it are filled
            c0, r0, c1, r1 = max(c0, 0), max(r0, 0), min(c1, src.width), min(r1, src.height)
        window = Window(c0, r0, max(c1 - c0, 2), max(r1 - r0, 2))
        read = {"window": window, "masked": True, "boundless": fill is not None}
        factor = math.ceil(math.sqrt(window.width * window.height / MAX_FILLED_CELLS))
        if fill is not None and factor > 1:  # a fine DSM asked for far beyond its edges
            read["out_shape"] = (max(math.ceil(window.height / factor), 2),
                                 max(math.ceil(window.width / factor), 2))  # fmt: skip
            read["resampling"] = Resampling.average
        band = src.read(getattr(dem, "band", 1), **read)
        wt = src.window_transform(window)
        if "out_shape" in read:
            rows, cols = read["out_shape"]
            wt = wt @ Affine.scale(window.width / cols, window.height / rows)
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
    holes = ~np.isfinite(z) if fill is not None else None
    if dem.geoid is not None or dem.offset_m or (holes is not None and holes.any()):
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
        if holes is not None and holes.any():  # the fill's ellipsoidal heights at the centres
            z[holes] = fill.sample(np.stack([lon[holes], lat[holes]], -1))
    if not np.any(np.isfinite(z)):
        raise ValueError(f"{dem.path}: the DEM holds only nodata over lon {w:.5f}..{e:.5f}, "
                         f"lat {s:.5f}..{n:.5f}")  # fmt: skip
    return DEMGrid(z, origin, step, utm_zone=zone)
