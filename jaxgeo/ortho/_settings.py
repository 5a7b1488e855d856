"""What an orthoimage is to be: one frozen settings object shared by :func:`plan_ortho` and
:func:`orthorectify` (where its tiles run is :class:`jaxgeo.tiles.TileSettings`)."""

from __future__ import annotations

import dataclasses
import math
import numbers
import os
from collections.abc import Sequence

from ..tiles import OutputGrid
from ..tiles.internal import COMPRESSIONS
from ._kernel import RESAMPLINGS
from ._validate import MAX_PIXELS, OrthoError, check_bounds, check_crs, check_res

OCCLUSIONS = ("off", "nodata", "band")


@dataclasses.dataclass(frozen=True)
class OrthoSettings:
    """The output grid and the options of an orthoimage, checked when made: an
    :class:`OrthoError` (a ``ValueError``) names the field at fault, before any input is read.

    Attributes:
        crs: output CRS (anything pyproj takes: ``"EPSG:32631"``, ``32631``, a
            ``pyproj.CRS``); ``None``: the local UTM zone of the footprint.
        res_m: output pixel size in CRS units (metres; degrees in a geographic CRS); ``None``:
            the image's GSD at its centre rounded to a common value
            (:func:`~jaxgeo.ortho.common_resolution`: 0.497 and 0.532 m give 0.5 m), so that
            the orthoimages of one scene's views share a grid.
        bounds: ``(W, S, E, N)`` in ``crs`` (which must then be given; kept as a tuple of
            floats); ``None``: the footprint on the DEM.
        tap: target-aligned pixels (``gdalwarp -tap``): the grid's edges are multiples of
            ``res_m`` in ``crs`` (the smallest such grid holding the footprint or ``bounds``),
            so that all products of one job at one resolution and CRS share their pixels;
            ``False``: the grid starts at the footprint's (or ``bounds``') west and north edges.
        like: the grid of another raster (a path, read when the settings are made, or a
            :class:`jaxgeo.tiles.OutputGrid`): its CRS, transform and shape, exactly (``rio warp
            --like``); ``crs``, ``res_m``, ``bounds`` and ``tap=False`` cannot be given with it.
        resampling: ``nearest``, ``bilinear`` or ``cubic`` (Keys, a = -0.5).
        occlusion: ``off``; ``nodata`` (pixels hidden from the sensor by terrain are nodata);
            ``band`` (an extra last band, 1 = hidden, 0 = seen).
        nodata: output nodata value; ``None``: NaN for float images, 0 for integer ones (a
            valid pixel equal to it is stored one step away from it: never nodata).
        tile_px: output tile size (px a side; smaller where the resolution is coarser than the
            GSD, so a tile's image window stays bounded).
        step_px: coarse-grid step (output px, even) at which the model is projected exactly.
        tol_px: largest interpolation error (image px) left in a block; above it the block is
            projected pixel by pixel.
        max_pixels: refuse a larger product (``None`` or 0: no limit).
        compress: COG compression (``deflate``, ``zstd``, ``lzw``, ``none``).
    """

    crs: object = None
    res_m: float | None = None
    bounds: Sequence[float] | None = None
    resampling: str = "bilinear"
    occlusion: str = "off"
    nodata: float | None = None
    tile_px: int = 1024
    step_px: int = 16
    tol_px: float = 0.01
    max_pixels: float | None = MAX_PIXELS
    compress: str = "deflate"
    tap: bool = True
    like: str | os.PathLike | OutputGrid | None = None

    def __post_init__(self):
        if not isinstance(self.tap, bool):
            raise OrthoError(f"tap must be True or False, got {self.tap!r}")
        if self.like is not None:
            _take_like(self)
        if self.resampling not in RESAMPLINGS:
            raise OrthoError(f"unknown resampling {self.resampling!r}; expected one of "
                             f"{RESAMPLINGS}")  # fmt: skip
        if self.occlusion not in OCCLUSIONS:
            raise OrthoError(f"unknown occlusion mode {self.occlusion!r}; expected one of "
                             f"{OCCLUSIONS}")  # fmt: skip
        if self.compress not in COMPRESSIONS:
            raise OrthoError(f"unknown compression {self.compress!r}; expected one of "
                             f"{COMPRESSIONS}")  # fmt: skip
        for name in ("tile_px", "step_px"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, numbers.Integral):
                raise OrthoError(f"{name} must be an integer, got {value!r}")
        if self.step_px < 2 or self.step_px % 2:
            raise OrthoError(f"step_px must be an even number >= 2, got {self.step_px}")
        if self.tile_px < 4 * self.step_px:
            raise OrthoError(f"tile_px must be >= {4 * self.step_px} (4 x step_px), got "
                             f"{self.tile_px}")  # fmt: skip
        if not _number(self.tol_px) or not self.tol_px >= 0 or math.isinf(self.tol_px):
            raise OrthoError(f"tol_px must be a finite number >= 0 (image px), got "
                             f"{self.tol_px!r}")  # fmt: skip
        if self.max_pixels is not None and not (_number(self.max_pixels)
                                                and self.max_pixels >= 0):  # fmt: skip
            raise OrthoError(f"max_pixels must be >= 0 (None or 0: no limit), got "
                             f"{self.max_pixels!r}")  # fmt: skip
        if self.nodata is not None and not _number(self.nodata):
            raise OrthoError(f"nodata must be a number (or None), got {self.nodata!r}")
        if self.crs is not None:
            check_crs(self.crs)  # the value given is kept: it is what the plan is made from
        if self.res_m is not None:  # in degrees or not: checked once the GSD is known
            object.__setattr__(self, "res_m", check_res(self.res_m, None, None))
        if self.bounds is not None:
            object.__setattr__(self, "bounds", check_bounds(self.bounds))
            if self.crs is None:
                raise OrthoError("bounds need the output CRS they are in (crs=, --crs)")


def _take_like(s: OrthoSettings) -> None:
    """``s.like`` as an :class:`OutputGrid` (a raster's read); the grid options it excludes."""
    given = [name for name, v in (("crs", s.crs), ("res_m", s.res_m), ("bounds", s.bounds))
             if v is not None] + ([] if s.tap else ["tap=False"])  # fmt: skip
    if given:
        raise OrthoError(f"like gives the output grid (CRS, transform, shape): "
                         f"{', '.join(given)} cannot be given with it")  # fmt: skip
    like = s.like
    if isinstance(like, str | os.PathLike):
        try:
            like = OutputGrid.of_raster(like)
        except ValueError as err:
            raise OrthoError(f"like: {err}") from None
    if not isinstance(like, OutputGrid):
        raise OrthoError(f"like must be a raster path or a jaxgeo.tiles.OutputGrid, got "
                         f"{type(like).__name__}")  # fmt: skip
    like = dataclasses.replace(like, crs=check_crs(like.crs))  # a pyproj CRS, as the plan's
    object.__setattr__(s, "like", like)


def _number(value) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool)
