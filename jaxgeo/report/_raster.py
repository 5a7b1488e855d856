"""Rasters read for a picture: decimated to a screen's size, never whole.

A product may be 40 000 px square; a figure shows at most :data:`MAX_SIDE_PX` cells a side,
read by GDAL's decimated read (``out_shape``: the COG's overviews where it has them, else
nearest cells), so the memory a report needs does not grow with the scene.
"""

from __future__ import annotations

import dataclasses
import os

import numpy as np

from ..io.internal import open_raster

MAX_SIDE_PX = 900
"""Largest side (cells) of a raster read for a figure."""


@dataclasses.dataclass(frozen=True)
class Quicklook:
    """Bands of a raster read at a reduced size: ``bands`` ``(k, rows, cols)`` float64 with NaN
    for nodata; ``extent`` ``(left, right, bottom, top)`` in the CRS's units; ``crs`` its
    name (``""`` when the raster has none); ``step`` the decimation (cells of the file per
    cell read, >= 1); ``names`` the band descriptions; ``transform`` the affine transform of
    the decimated grid; ``crs_wkt`` its CRS (``None``: none)."""

    bands: np.ndarray
    extent: tuple[float, float, float, float]
    crs: str
    step: float
    names: tuple[str, ...]
    transform: object
    crs_wkt: str | None
    units: str


def read_quicklook(
    path: str | os.PathLike, bands: tuple[int, ...] | None = None, max_side: int = MAX_SIDE_PX
) -> Quicklook:
    """``bands`` (1-based; default all) of ``path`` read at most ``max_side`` cells a side."""
    with open_raster(path) as ds:
        bands = tuple(range(1, ds.count + 1)) if bands is None else bands
        step = max(1.0, max(ds.width, ds.height) / max_side)
        shape = (len(bands), max(1, round(ds.height / step)), max(1, round(ds.width / step)))
        data = ds.read(list(bands), out_shape=shape, masked=True).astype(np.float64)
        data = np.ma.filled(data, np.nan)
        b = ds.bounds
        crs = ds.crs
        name = "" if crs is None else (crs.to_string() or crs.to_wkt()[:40])
        units = ""
        if crs is not None:
            units = "degrees" if crs.is_geographic else (crs.linear_units or "m")
            units = {"metre": "m", "meter": "m"}.get(units, units)
        transform = ds.transform @ ds.transform.scale(ds.width / shape[2], ds.height / shape[1])
        names = tuple(ds.descriptions[i - 1] or f"band {i}" for i in bands)
        return Quicklook(data, (b.left, b.right, b.bottom, b.top), name, step, names,
                         transform, None if crs is None else crs.to_wkt(), units)  # fmt: skip


def label_axes(ax, look: Quicklook) -> None:
    """Axis labels of a map of ``look`` in its CRS's units; at most 5 ticks along x (long
    labels such as 681 440 do not run into each other)."""
    from matplotlib.ticker import MaxNLocator

    unit = look.units or "px"
    geographic = unit == "degrees"
    ax.set_xlabel("longitude (°)" if geographic else f"easting ({unit})")
    ax.set_ylabel("latitude (°)" if geographic else f"northing ({unit})")
    ax.ticklabel_format(useOffset=False, style="plain")
    ax.xaxis.set_major_locator(MaxNLocator(5))


def band_index(look: Quicklook, name: str) -> int | None:
    """The index in ``look.bands`` of the band described ``name`` (``None``: none)."""
    return look.names.index(name) if name in look.names else None


def hillshade(z: np.ndarray, cell_m: float, azimuth_deg: float = 315.0,
              altitude_deg: float = 45.0) -> np.ndarray:  # fmt: skip
    """Hillshade in [0, 1] of heights ``z`` (m) on square cells of ``cell_m`` metres, lit from
    ``azimuth_deg`` (clockwise from north) at ``altitude_deg``; NaN where ``z`` is NaN."""
    drow, deast = np.gradient(z, cell_m)
    dnorth = -drow  # rows go south
    az, alt = np.radians(azimuth_deg), np.radians(altitude_deg)
    light = (np.sin(az) * np.cos(alt), np.cos(az) * np.cos(alt), np.sin(alt))  # east, north, up
    shade = (-deast * light[0] - dnorth * light[1] + light[2]) / np.sqrt(1 + deast**2 + dnorth**2)
    return np.clip(shade, 0.0, 1.0)


def percentile_stretch(values: np.ndarray, low: float = 2.0, high: float = 98.0):
    """The ``(vmin, vmax)`` of a display stretch: the ``low`` and ``high`` percentiles of the
    finite values (``(0, 1)`` when there are none; widened when they are equal)."""
    finite = values[np.isfinite(values)]
    if finite.size == 0:
        return 0.0, 1.0
    lo, hi = (float(v) for v in np.percentile(finite, (low, high)))
    return (lo, hi) if hi > lo else (lo - 0.5, lo + 0.5)
