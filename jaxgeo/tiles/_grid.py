"""The grid of a raster product: its CRS, north-up transform and shape, taken from another raster
(``like``, as ``rio warp --like``) or made to cover bounds at a resolution with its corners on
multiples of that resolution (target-aligned pixels, as ``gdalwarp -tap``), so that the products
of one job (orthoimages, DSMs) share a grid cell for cell."""

from __future__ import annotations

import dataclasses
import math
import os

ALIGN_TOL = 1e-6
"""A coordinate within this fraction of a pixel of a multiple of the resolution is that multiple
(``3.3 / 1.1`` is ``2.9999999999999996`` in floating point: not one pixel more)."""


def _floor(v: float) -> int:
    k = round(v)
    return int(k) if abs(v - k) < ALIGN_TOL else math.floor(v)


def _ceil(v: float) -> int:
    k = round(v)
    return int(k) if abs(v - k) < ALIGN_TOL else math.ceil(v)


def _multiple(k: int, res: float) -> float:
    """``k * res`` at 15 significant digits: ``698000.1``, not ``698000.1000000001`` (the same
    value for every grid, and nanometres from the product)."""
    return float(f"{k * res:.15g}")


@dataclasses.dataclass(frozen=True)
class OutputGrid:
    """A north-up output raster: ``crs`` (a pyproj CRS), ``res_m`` (pixel width, CRS units: metres,
    or degrees in a geographic CRS), ``west``/``north`` (the outer corner of the first pixel, CRS
    units), ``width``/``height`` (pixels); ``res_y_m``: the pixel height where it differs from its
    width (a raster read by :meth:`of_raster`; ``None``: square pixels); ``source``: the raster
    it was read from (``None``: made), no part of its identity.

    :meth:`of_raster` reads another raster's grid; :meth:`covering` makes one over bounds."""

    crs: object
    res_m: float
    west: float
    north: float
    width: int
    height: int
    res_y_m: float | None = None
    source: str | None = dataclasses.field(default=None, compare=False)

    @property
    def res_y(self) -> float:
        """Pixel height (CRS units, > 0)."""
        return self.res_m if self.res_y_m is None else self.res_y_m

    @property
    def transform(self):
        from affine import Affine

        return Affine(self.res_m, 0.0, self.west, 0.0, -self.res_y, self.north)

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """``(W, S, E, N)`` of the outer pixel edges (CRS units)."""
        return (self.west, self.north - self.height * self.res_y,
                self.west + self.width * self.res_m, self.north)  # fmt: skip

    @classmethod
    def covering(cls, bounds, crs, res_m: float, tap: bool = True) -> OutputGrid:
        """The grid of square ``res_m`` pixels that covers ``bounds`` ``(W, S, E, N)`` in ``crs``.

        ``tap`` (target-aligned pixels, the default): its edges are the multiples of ``res_m``
        around the bounds (the smallest such grid that holds them), so that every grid made
        at one resolution in one CRS shares its pixels with every other; ``tap=False``: its
        upper-left corner is ``(W, N)`` exactly, and it reaches ``E`` and ``S`` (or just past)."""
        w, s, e, n = (float(v) for v in bounds)
        if not (e > w and n > s):
            raise ValueError(f"empty output bounds {tuple(bounds)}")
        if not (math.isfinite(res_m) and res_m > 0):
            raise ValueError(f"the output resolution must be > 0, got {res_m}")
        res = float(res_m)
        if tap:
            west, north = _multiple(_floor(w / res), res), _multiple(_ceil(n / res), res)
        else:
            west, north = w, n
        width = _ceil((e - west) / res)
        height = _ceil((north - s) / res)
        return cls(crs, res, west, north, max(width, 1), max(height, 1))

    @classmethod
    def of_raster(cls, path: str | os.PathLike) -> OutputGrid:
        """The grid of the raster at ``path`` (its CRS, transform and shape, as
        ``rio warp --like``); a ``ValueError`` naming the file when it has none to give: no CRS
        (a satellite image in its own pixels), a rotated or sheared transform, rows that run
        south to north. Only its metadata is read."""
        import pyproj

        from ..io.internal import open_raster

        path = os.fspath(path)
        if not os.path.isfile(path):
            raise ValueError(f"{path}: no such file (a raster whose grid to take)")
        try:
            with open_raster(path) as src:
                crs, t, width, height = src.crs, src.transform, src.width, src.height
        except Exception as err:  # rasterio's errors are not ValueErrors
            first = str(err).split("\n")[0]
            raise ValueError(f"{path}: not a raster GDAL reads ({first})") from None
        if crs is None:
            raise ValueError(f"{path}: this raster has no CRS (a satellite image in its own "
                             "pixels?): it has no map grid to give")  # fmt: skip
        if t.b != 0 or t.d != 0:
            raise ValueError(f"{path}: its transform is rotated or sheared ({tuple(t)[:6]}); "
                             "a north-up grid is needed")  # fmt: skip
        if not (t.a > 0 and t.e < 0):
            raise ValueError(f"{path}: its pixels do not run west to east and north to south "
                             f"(transform {tuple(t)[:6]}); a north-up grid is needed")  # fmt: skip
        crs = pyproj.CRS.from_user_input(crs.to_wkt())
        if crs.is_compound:  # the horizontal part: heights are not the grid's business
            crs = next((c for c in crs.sub_crs_list if not c.is_vertical), crs)
        res_y = -float(t.e)
        return cls(crs, float(t.a), float(t.c), float(t.f), int(width), int(height),
                   None if res_y == float(t.a) else res_y, source=path)  # fmt: skip
