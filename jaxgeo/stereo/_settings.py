"""The parameters of a DSM, once: :class:`DSMSettings` (what :func:`~jaxgeo.stereo.make_dsm`,
:func:`~jaxgeo.stereo.plan_dsm`, :func:`~jaxgeo.stereo.dsm_from_images` and
:func:`~jaxgeo.stereo.stereo_pair` share)."""

from __future__ import annotations

import dataclasses
import math
import os

from ..errors import JaxgeoError
from ..tiles import OutputGrid
from ._dense import DEFAULT_SGM, SGMSettings
from ._dsm import MAX_HOLE_M

BAND_ROWS = 512
"""Epipolar rows per band of dense matching (memory grows with the band, not the image)."""
MAX_CELLS = 400_000_000
"""Largest DSM (cells) :func:`~jaxgeo.stereo.make_dsm` makes by default: 20 000 x 20 000."""
TRIANGULATIONS = ("intersect", "los_midpoint")
MIN_TILE_CELLS = 64
"""Smallest DSM tile (cells a side)."""


class DSMSettingsError(JaxgeoError, ValueError):
    """A DSM parameter out of range; ``field`` names the :class:`DSMSettings` field (the
    message starts with it)."""

    def __init__(self, field: str, message: str):
        super().__init__(message)
        self.field = field


@dataclasses.dataclass(frozen=True)
class DSMSettings:
    """What a DSM is made with (the inputs aside: images, models, a DEM, the orientation).

    Attributes:
        res_m: cell size (m).
        epsg: the DSM's CRS, a projected CRS in metres (``None``: the local UTM zone).
        roi: ``(col, row, width, height)`` of the reference image (px; ``None``: all of it).
        heights: the terrain's lowest and highest height (m, ellipsoidal): the tie points'
            height range and the heights the tiles' windows are projected at (``None``: from
            the DEM's heights over the footprint +-50 m where one is given, else sampled by a
            coarse matching).
        max_hole_m: holes up to this size (m across) are interpolated (0: none).
        sgm: the dense matcher's settings (:class:`SGMSettings`).
        triangulation: ``intersect`` (least squares, with a covariance) or ``los_midpoint``.
        band_rows: epipolar rows per band of dense matching (``None``: one band).
        register: with three or more images, remove the pairs' relative height offsets.
        keep: a folder for each pair's intermediate products (``pair_i.npz``; an untiled DSM).
        tile_px: cells a side of a tile (``None``: :data:`~jaxgeo.stereo.TILE_CELLS`, and the
            DSM is tiled only when the reference window is larger than
            :data:`~jaxgeo.stereo.TILED_MIN_PX`); giving it makes the DSM tile by tile.
        max_cells: refuse a larger DSM (cells; ``None``: no limit).
        epi_step: step (px) of the epipolar grids.
        epipolar_tol_px: how far from the models' epipolar curves tie points may lie (px).
        tap: target-aligned cells (``gdalwarp -tap``): the grid's edges are multiples of
            ``res_m`` in the CRS, so that the DSMs and orthoimages of one job at one resolution
            share their cells; ``False``: the grid starts at the footprint's west and north
            edges.
        like: the grid of another raster (a path, read when the settings are made, or a
            :class:`jaxgeo.tiles.OutputGrid`): its CRS (projected, in metres, with an EPSG
            code), transform (square cells) and shape exactly; it sets ``res_m`` and ``epsg``
            (another ``epsg``, a ``res_m`` other than the default and the grid's, or
            ``tap=False`` are refused).
    """

    res_m: float = 0.5
    epsg: int | None = None
    roi: tuple[int, int, int, int] | None = None
    heights: tuple[float, float] | None = None
    max_hole_m: float = MAX_HOLE_M
    sgm: SGMSettings = DEFAULT_SGM
    triangulation: str = "intersect"
    band_rows: int | None = BAND_ROWS
    register: bool = True
    keep: str | os.PathLike | None = None
    tile_px: int | None = None
    max_cells: float | None = MAX_CELLS
    epi_step: int = 30
    epipolar_tol_px: float = 10.0
    tap: bool = True
    like: str | os.PathLike | OutputGrid | None = None

    def __post_init__(self):
        if self.like is not None:
            _take_like(self)
        if self.band_rows is not None and self.band_rows < 1:
            raise DSMSettingsError(
                "band_rows", f"band_rows {self.band_rows}: expected a positive number of rows"
            )
        if not (math.isfinite(self.res_m) and self.res_m > 0):
            raise DSMSettingsError(
                "res_m", f"res_m {self.res_m:g}: expected a positive cell size in metres"
            )
        if not (math.isfinite(self.max_hole_m) and self.max_hole_m >= 0):
            raise DSMSettingsError("max_hole_m", f"max_hole_m {self.max_hole_m:g}: expected "
                                   "metres >= 0")  # fmt: skip
        if self.heights is not None:
            lo, hi = (float(v) for v in self.heights)
            if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
                raise DSMSettingsError(
                    "heights", f"heights {lo:g} {hi:g}: need finite HMIN < HMAX (metres)"
                )
            object.__setattr__(self, "heights", (lo, hi))
        if self.roi is not None:
            if len(self.roi) != 4:
                raise DSMSettingsError("roi", f"roi {self.roi}: expected (col, row, w, h)")
            col, row, w, h = (int(v) for v in self.roi)
            if col < 0 or row < 0 or w <= 0 or h <= 0:
                raise DSMSettingsError("roi", f"roi {col} {row} {w} {h}: need col, row >= 0 "
                                       "and w, h > 0 (px)")  # fmt: skip
            object.__setattr__(self, "roi", (col, row, w, h))
        if self.triangulation not in TRIANGULATIONS:
            raise DSMSettingsError("triangulation", f"triangulation {self.triangulation!r}: "
                                   f"expected one of {TRIANGULATIONS}")  # fmt: skip
        if self.tile_px is not None and self.tile_px < MIN_TILE_CELLS:
            raise DSMSettingsError(
                "tile_px", f"tile_px must be >= {MIN_TILE_CELLS}, got {self.tile_px}"
            )
        if self.epsg is not None:
            object.__setattr__(self, "epsg", int(self.epsg))
        if self.epi_step < 1:
            raise DSMSettingsError("epi_step", f"epi_step {self.epi_step}: expected >= 1 px")
        if not (math.isfinite(self.epipolar_tol_px) and self.epipolar_tol_px > 0):
            raise DSMSettingsError("epipolar_tol_px", f"epipolar_tol_px "
                                   f"{self.epipolar_tol_px:g}: must be > 0")  # fmt: skip


def _take_like(s: DSMSettings) -> None:
    """``s.like`` as an :class:`OutputGrid` (a raster's, read) whose CRS and cells a DSM can
    have; ``res_m`` and ``epsg`` set from it."""
    import pyproj

    like = s.like
    if isinstance(like, str | os.PathLike):
        try:
            like = OutputGrid.of_raster(like)
        except ValueError as err:
            raise DSMSettingsError("like", f"like: {err}") from None
    if not isinstance(like, OutputGrid):
        raise DSMSettingsError("like", "like must be a raster path or a jaxgeo.tiles.OutputGrid, "
                               f"got {type(like).__name__}")  # fmt: skip
    name = like.source or "the grid given (like)"
    crs = pyproj.CRS.from_user_input(like.crs)
    unit = crs.axis_info[0].unit_name if crs.axis_info else ""
    code = crs.to_epsg()
    if not crs.is_projected or unit not in ("metre", "meter") or code is None:
        raise DSMSettingsError("like", f"like: {name}: its CRS ({crs.name}) is not a projected "
                               "CRS in metres with an EPSG code, as a DSM's is")  # fmt: skip
    if abs(like.res_y - like.res_m) > 1e-9 * like.res_m:
        raise DSMSettingsError("like", f"like: {name}: its cells are {like.res_m:g} x "
                               f"{like.res_y:g} m; a DSM's cells are square")  # fmt: skip
    default = DSMSettings.__dataclass_fields__["res_m"].default
    given = ([f"res_m {s.res_m:g}"] if s.res_m not in (default, like.res_m) else []) + (
        [f"epsg {s.epsg}"] if s.epsg not in (None, code) else []) + (
        [] if s.tap else ["tap=False"])  # fmt: skip
    if given:
        raise DSMSettingsError("like", f"like: {name} gives the grid (EPSG:{code}, "
                               f"{like.res_m:g} m cells): {', '.join(given)} cannot be given "
                               "with it")  # fmt: skip
    object.__setattr__(s, "like", like)
    object.__setattr__(s, "res_m", float(like.res_m))
    object.__setattr__(s, "epsg", int(code))


DEFAULT_DSM = DSMSettings()
"""The default :class:`DSMSettings` (0.5 m cells, local UTM, the whole reference image)."""
