"""What a DEM file declares and is checked for when :func:`jaxgeo.io.read_dem` opens it: the band
of heights (a jaxgeo DSM's band described ``height``), the height reference (the file's vertical
CRS or a DSM's tag, ``height=``, ``geoid=``), heights no terrain has, and the agreement of a DEM
with its fill DEM."""

from __future__ import annotations

import dataclasses
import math
import pathlib
import warnings

import numpy as np

from ..errors import JaxgeoWarning
from ._dem import DEM, FILL_MISMATCH_M, HEIGHT_BAND, PLAUSIBLE_HEIGHTS_M, implausible

__all__ = ["fill_difference", "height_band", "height_reference", "refuse_feet", "warn_implausible"]


def height_band(path, src, band) -> tuple[int, str | None]:
    """The band of heights of the open raster ``src`` and the height reference the file declares
    for it (``"ellipsoidal"`` for a jaxgeo DSM's band of heights, its ``heights`` tag; else
    ``None``)."""
    descriptions = [(d or "").strip() for d in src.descriptions]
    tag = str(src.tags().get("heights", "")).lower()
    if band is not None:
        if (
            isinstance(band, bool)
            or not isinstance(band, (int, np.integer))
            or not (1 <= band <= src.count)
        ):
            raise ValueError(f"{path}: band {band!r} is not a band of this raster (1.."
                             f"{src.count})")  # fmt: skip
        band = int(band)
    elif src.count == 1:
        band = 1
    else:
        named = [i for i, d in enumerate(descriptions, start=1) if d.lower() == HEIGHT_BAND]
        if len(named) != 1:
            shown = ", ".join(f"{i}: {d!r}" for i, d in enumerate(descriptions, start=1) if d)
            raise ValueError(
                f"{path}: a DEM must have one band, this raster has {src.count}"
                + (f" ({shown})" if shown else "")
                + f" and {'several' if named else 'none'} described {HEIGHT_BAND!r} (as a "
                "jaxgeo DSM's band of heights): choose the band of heights (band=N)"
            )
        band = named[0]
    dsm = tag.startswith("ellipsoidal") and (
        src.count == 1 or descriptions[band - 1].lower() == HEIGHT_BAND
    )
    refuse_feet(path, src, band)
    return band, "ellipsoidal" if dsm else None


FEET = ("ft", "feet", "foot", "us survey foot", "us-ft", "ftus", "us_survey_foot", "foot_us")
"""Unit names a DEM may declare for heights in feet (band ``units``, a vertical CRS's axis)."""


def refuse_feet(path, src, band: int) -> None:
    """A ``ValueError`` naming the file when the open raster ``src`` declares the heights of
    ``band`` in feet (its band's unit, or its vertical CRS's axis unit): jaxgeo reads metres,
    and a DEM in feet puts the terrain 3.28 times too high (undeclared, the tie points' or the
    model's check finds it: :mod:`jaxgeo.io._plausible`)."""
    import pyproj

    units = [str((src.units or ())[band - 1] or "") if len(src.units or ()) >= band else ""]
    if src.crs is not None:
        crs = pyproj.CRS.from_wkt(src.crs.to_wkt())
        for sub in crs.sub_crs_list if crs.is_compound else []:
            if sub.is_vertical and sub.axis_info:
                units.append(sub.axis_info[0].unit_name or "")
    found = next((u for u in units if u.strip().lower() in FEET), None)
    if found is not None:
        raise ValueError(
            f"{path}: declares the heights of band {band} in {found!r}: jaxgeo reads DEM heights "
            "in metres; convert them first (heights x 0.3048, e.g. gdal_calc.py "
            "--calc='A*0.3048')"
        )


def fill_difference(dem: DEM, max_cells: int = 16_384) -> float | None:
    """Median of ``dem`` minus its fill (m) where both have heights, on a decimated read of
    ``dem``'s raster (``None``: no common cell); warns above :data:`FILL_MISMATCH_M`."""
    import pyproj
    from rasterio.errors import RasterioError

    from ._raster import open_raster

    try:
        with open_raster(dem.path) as src:
            scale = max(1, math.ceil(math.sqrt(src.width * src.height / max_cells)))
            shape = (max(src.height // scale, 1), max(src.width // scale, 1))
            z = src.read(dem.band, out_shape=shape, masked=True)
            t = src.transform
            sx, sy = src.width / shape[1], src.height / shape[0]
            crs_wkt = src.crs.to_wkt()
    except RasterioError as err:
        raise ValueError(f"{dem.path}: cannot read the DEM's heights ({err})") from None
    cc, rr = np.meshgrid((np.arange(shape[1]) + 0.5) * sx, (np.arange(shape[0]) + 0.5) * sy)
    x, y = t.c + t.a * cc + t.b * rr, t.f + t.d * cc + t.e * rr  # cell centres, raster CRS
    if dem.crs is not None:
        to_ll = pyproj.Transformer.from_crs(pyproj.CRS.from_wkt(crs_wkt), 4326, always_xy=True)
        with np.errstate(invalid="ignore"):
            x, y = to_ll.transform(x, y)
    lonlat = np.stack([np.ravel(x), np.ravel(y)], -1)
    values = np.ma.filled(z.astype(float), np.nan).ravel()
    ok = ~implausible(values) & np.all(np.isfinite(lonlat), axis=1)
    if not ok.any():
        return None
    own = values[ok]
    if dem.geoid is not None:
        own = own + dem.geoid(lonlat[ok, 0], lonlat[ok, 1])
    own = own + dem.offset_m
    other = dem.fill.sample(lonlat[ok])
    both = np.isfinite(other)
    if not both.any():
        return None
    diff = float(np.median(own[both] - other[both]))
    if abs(diff) > FILL_MISMATCH_M:
        first = dataclasses.replace(dem, fill=None).describe()
        warnings.warn(
            f"{dem.path}: its heights are {diff:+.1f} m from those of its fill DEM "
            f"{dem.fill.path} (median over {int(both.sum())} cells where both have heights): "
            f"are their height references right? ({first}; fill: "
            f"{dem.fill.describe()}) A geoid left out (orthometric heights read as ellipsoidal) "
            "differs by the undulation, tens of metres",
            JaxgeoWarning,
            stacklevel=3,
        )
    return diff


def height_reference(path, vertical: str | None, height, geoid, declared: str | None = None):
    """Resolve ``(height, geoid)`` against the file's vertical CRS (or ``declared``, the
    reference a jaxgeo DSM states) -> (reference, GeoidGrid)."""
    from ._geoid import read_geoid

    if height not in (None, "ellipsoidal", "orthometric"):
        raise ValueError(f"{path}: height must be 'ellipsoidal' or 'orthometric', got {height!r}")
    if declared == "ellipsoidal" and (height == "orthometric" or geoid is not None):
        raise ValueError(f"{path}: a jaxgeo DSM: its heights are ellipsoidal (WGS84), as the "
                         "file declares; a geoid does not apply to it")  # fmt: skip
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


def warn_implausible(path: pathlib.Path, band: int = 1, max_cells: int = 4_000_000) -> None:
    """Warn (naming the file) when valid-looking cells hold impossible heights: an undeclared
    void marker such as -32768. They are read as nodata. Large rasters are checked on a
    decimated read."""
    from rasterio.errors import RasterioError

    from ._raster import open_raster

    try:
        with open_raster(path) as src:
            scale = max(1, math.ceil(math.sqrt(src.width * src.height / max_cells)))
            shape = (max(src.height // scale, 1), max(src.width // scale, 1))
            band = src.read(band, out_shape=shape, masked=True)
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
