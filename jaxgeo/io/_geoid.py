"""Geoid undulation grids: ``N(lon, lat)`` in metres, so that ellipsoidal ``h = H + N``.

    geoid = read_geoid("egm96")                  # PROJ's us_nga_egm96_15.tif, else the shipped grid
    geoid = read_geoid("ventoux/dem/egm96_15_crop_lon3-8_lat42-47.gtx")
    n_m = geoid(lon_deg, lat_deg)

Values are bilinear between grid nodes (the node of a raster cell is its centre; GTX and PROJ
GeoTIFF grids are written that way), as PROJ and shareloc interpolate them; a band scale and
offset are applied.

EGM96 works offline: jaxgeo ships NGA's 15-arcminute grid (``jaxgeo/io/data/egm96_15.tif``, from
``WW15MGH.DAC``, public domain; int16 centimetres, the same values as PROJ's
``us_nga_egm96_15.tif`` to 5 mm; made by ``tools/make_egm96_grid.py``), used when PROJ's grid
is not installed. EGM2008 (2.5-arcminute; tens of MB even compressed) is not shipped: PROJ's
grid or a file.
"""

from __future__ import annotations

import dataclasses
import os
import pathlib

import numpy as np

__all__ = ["GEOID_GRIDS", "GeoidGrid", "read_geoid"]

GEOID_GRIDS = {
    "egm96": ("us_nga_egm96_15.tif", "egm96_15.gtx"),
    "egm2008": ("us_nga_egm08_25.tif", "egm08_25.gtx"),
}
"""Geoid names -> PROJ grid file names searched in pyproj's data directories."""

SHIPPED_GRIDS = {"egm96": pathlib.Path(__file__).parent / "data" / "egm96_15.tif"}
"""Geoid grids that come with jaxgeo, used when PROJ's grid is not installed."""

GEOID_SOURCES = {
    "egm2008": "https://cdn.proj.org/us_nga_egm08_25.tif (PROJ's CDN; `projsync --file "
    "us_nga_egm08_25.tif` on a machine with network) or NGA's EGM2008 2.5-minute grid",
}
"""Where to get a geoid grid jaxgeo does not ship (for the error message)."""


@dataclasses.dataclass(frozen=True, eq=False)
class GeoidGrid:
    """A geoid undulation grid in WGS84 lon/lat; call it as ``geoid(lon_deg, lat_deg) -> N_m``."""

    source: str
    values_m: np.ndarray  # (rows, cols), row 0 at the north
    lon0_deg: float  # node of cell (0, 0)
    lat0_deg: float
    dlon_deg: float
    dlat_deg: float  # negative for north-up grids
    name: str | None = None  # "egm96", "egm2008" when opened by name: found again on a worker

    def __call__(self, lon_deg, lat_deg) -> np.ndarray | float:
        lon = np.asarray(lon_deg, dtype=float)
        lat = np.asarray(lat_deg, dtype=float)
        rows, cols = self.values_m.shape
        period = round(360.0 / abs(self.dlon_deg))  # nodes around the globe
        wrap = cols >= period  # a global grid (with or without its column at +180 repeated)
        c = (lon - self.lon0_deg) / self.dlon_deg
        if wrap:  # node k + period is node k: from 0 up to the last node, then back to node 0
            c = np.mod(c, period)
        r = (lat - self.lat0_deg) / self.dlat_deg
        last = period if wrap else cols - 1
        bad = ~((c >= 0) & (c <= last) & (r >= 0) & (r <= rows - 1))
        if np.any(bad):
            i = int(np.flatnonzero(bad.ravel())[0])
            raise ValueError(
                f"{self.source}: {int(bad.sum())} point(s) lie outside the geoid grid (first at "
                f"lon {lon.ravel()[i]:.5f}, lat {lat.ravel()[i]:.5f}); it covers lon "
                f"{self.lon0_deg:.4f}..{self.lon0_deg + (cols - 1) * self.dlon_deg:.4f}, lat "
                f"{self.lat0_deg + (rows - 1) * self.dlat_deg:.4f}..{self.lat0_deg:.4f}"
            )
        c0 = np.minimum(np.floor(c).astype(np.int64), last - 1)
        r0 = np.minimum(np.floor(r).astype(np.int64), rows - 2)
        tc, tr = c - c0, r - r0
        c1 = (c0 + 1) % period if wrap else c0 + 1
        z = self.values_m
        return np.asarray(
            (1 - tr) * ((1 - tc) * z[r0, c0] + tc * z[r0, c1])
            + tr * ((1 - tc) * z[r0 + 1, c0] + tc * z[r0 + 1, c1])
        )


def _proj_dirs() -> list[pathlib.Path]:
    import pyproj

    dirs = [os.environ.get("PROJ_DATA"), os.environ.get("PROJ_LIB")]
    for get in (pyproj.datadir.get_user_data_dir, pyproj.datadir.get_data_dir):
        try:
            dirs.append(get())
        except Exception:  # noqa: BLE001 - a data dir pyproj cannot name is simply not searched
            pass
    out = []
    for d in dirs:
        for part in (d or "").split(os.pathsep):
            if part and pathlib.Path(part).is_dir():
                out.append(pathlib.Path(part))
    return out


def _find_grid(name: str) -> pathlib.Path:
    """PROJ's grid of geoid ``name`` where pyproj's data directories hold it, else the grid
    jaxgeo ships, else a ``ValueError`` saying where to get one."""
    files = GEOID_GRIDS[name]
    dirs = _proj_dirs()
    for d in dirs:
        for f in files:
            if (d / f).is_file():
                return d / f
    shipped = SHIPPED_GRIDS.get(name)
    if shipped is not None and shipped.is_file():
        return shipped
    where = GEOID_SOURCES.get(name, f"PROJ's CDN (`projsync --file {files[0]}`)")
    raise ValueError(
        f"geoid {name!r}: PROJ grid {files[0]} not found in the PROJ data directories "
        f"({', '.join(map(str, dirs)) or 'none'}) and jaxgeo does not ship it; get it from "
        f"{where}, put it in a PROJ data directory (PROJ_DATA) or pass its path as the geoid "
        "(GTX or GeoTIFF)"
    )


def read_geoid(geoid: str | os.PathLike) -> GeoidGrid:
    """Open a geoid grid: ``"egm96"`` / ``"egm2008"`` (PROJ grids) or a grid file path.

    ``"egm96"`` is PROJ's grid where pyproj finds it, else the grid jaxgeo ships (same values to
    5 mm); ``"egm2008"`` needs PROJ's grid (or its file). Raises ``ValueError`` for an unknown
    name, a grid neither installed nor shipped (saying where to get it), or a file that is not a
    single-band geographic raster.
    """
    import rasterio

    name = None
    if isinstance(geoid, str) and geoid.lower() in GEOID_GRIDS:
        name = geoid.lower()
        path = _find_grid(name)
    else:
        path = pathlib.Path(geoid)
        if not path.is_file():
            raise ValueError(
                f"unknown geoid {str(geoid)!r}: expected one of {sorted(GEOID_GRIDS)} or the "
                "path of a geoid grid file"
            )
    with rasterio.open(path) as src:
        if src.crs is not None and not src.crs.is_geographic:
            raise ValueError(f"{path}: a geoid grid must be in geographic lon/lat, got {src.crs}")
        t = src.transform
        if t.b != 0 or t.d != 0:
            raise ValueError(f"{path}: rotated geoid grids are not supported")
        z = src.read(1, masked=True)
        scale, offset = float(src.scales[0]), float(src.offsets[0])
    values = np.ma.filled(z.astype(float), np.nan) * scale + offset  # e.g. int16 cm, scale 0.01
    return GeoidGrid(str(path), values, t.c + 0.5 * t.a, t.f + 0.5 * t.e, float(t.a), float(t.e),
                     name)  # fmt: skip
