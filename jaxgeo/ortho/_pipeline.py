"""Orthorectification of an image with any sensor model and a DEM, tile by tile, on all cores.

:func:`orthorectify` = :func:`._plan.plan_ortho` (inputs, footprint, grid, checks, the tile plan),
then the tiles on the tile runner
(:func:`jaxgeo.tiles.run_tiles`: here for a small product, else on dask workers, one per core) as
:class:`._job.OrthoJob` calls, each writing its window, then :func:`jaxgeo.tiles.mosaic_cog`
joins them into a COG renamed onto ``out`` at the end.
"""

from __future__ import annotations

import dataclasses
import os
import pathlib
import time
from collections.abc import Sequence

from ..io import DEM, SensorImage
from ..tiles import EmptyProduct, TileSettings, make_product
from ._plan import plan_ortho
from ._settings import OrthoSettings
from ._validate import OrthoError


@dataclasses.dataclass(frozen=True)
class OrthoReport:
    """What :func:`orthorectify` made: the file, its grid, the quality of the mapping, the run.

    ``grid_error_px``: largest difference (image px) between the coarse-grid mapping and the
    full projection at the block-centre check points left interpolated (refined blocks are
    exact); ``refined_fraction``: share of blocks projected in full; ``valid_fraction``: share
    of output pixels with data; ``occluded_fraction``: share of pixels hidden from the sensor
    (``None`` when occlusion was off); ``tiles``, ``empty_tiles`` (no data), ``reused_tiles``
    (from ``resume``); ``workers`` (0: in this process) and ``scheduler`` (dask address);
    ``gsd``: the image's ground sample distance at its centre (CRS units), of which ``res_m``
    is the rounded value unless a resolution or a grid (``like``) was given.
    """

    path: pathlib.Path
    crs: str
    res_m: float
    width: int
    height: int
    bounds: tuple[float, float, float, float]
    grid_error_px: float
    refined_fraction: float
    valid_fraction: float
    occluded_fraction: float | None
    seconds: float
    tiles: int = 0
    empty_tiles: int = 0
    reused_tiles: int = 0
    workers: int = 0
    scheduler: str | None = None
    gsd: float | None = None


def orthorectify(
    image: str | os.PathLike | SensorImage,
    dem: DEM | str | os.PathLike,
    out: str | os.PathLike,
    settings: OrthoSettings = OrthoSettings(),  # noqa: B008 (frozen: one default is safe)
    tiles: TileSettings = TileSettings(),  # noqa: B008 (frozen)
    *,
    model=None,
    image_origin: Sequence[float] | None = None,
    overwrite: bool = False,
) -> OrthoReport:
    """Orthorectify ``image`` with its model on ``dem`` into the COG ``out``.

    Args:
        image: a raster path (its model: its RPC, or ``model``) or a :class:`jaxgeo.io.SensorImage`.
        dem: a :class:`jaxgeo.io.DEM` (heights made ellipsoidal by ``read_dem``) or a path read
            as ellipsoidal.
        out: the COG written (atomically, once complete; never an input).
        settings: the output grid and options (:class:`OrthoSettings`: CRS, resolution, bounds,
            resampling, occlusion, nodata, tile and coarse-grid sizes, pixel limit, compression).
        tiles: where the tiles run (:class:`jaxgeo.tiles.TileSettings`, for
            :func:`jaxgeo.tiles.run_tiles`): ``workers=None`` = in this process for a small
            product, else one worker process per core; ``0`` = in this process; ``scheduler`` =
            an existing dask cluster's address; ``retries``; ``resume``: a folder for the
            finished tiles, kept after an interruption and reused by the next run with the same
            folder (default: a temporary folder beside ``out``); ``progress``: a bar on stderr.
        model: a sensor model or a model file (default: the raster's own RPC); in the model's
            pixel frame: a crop's pixel-space geotransform gives its origin, ``image_origin``
            ``(col, row)`` overrides it (a conflict is an error). Pixel centres at integers.
        overwrite: replace an existing ``out`` (never an input).

    Returns an :class:`OrthoReport`. Raises :class:`OrthoError` (a ``ValueError``) for options
    or inputs that cannot give a product (before any computation), ``FileExistsError`` for an
    existing ``out``, :class:`jaxgeo.tiles.TileError` naming a tile that kept failing.
    """
    if not isinstance(tiles, TileSettings):
        raise TypeError(f"tiles must be a jaxgeo.tiles.TileSettings, got {type(tiles).__name__}")
    t_start = time.perf_counter()
    # the workers start once the plan is made: a refused input is answered without them
    setup = plan_ortho(image, dem, out, settings, model=model, image_origin=image_origin,
                       overwrite=overwrite)  # fmt: skip
    # the mosaic's overviews: nearest for a nearest-resampled product (classes stay classes)
    overviews = "nearest" if settings.resampling == "nearest" else "average"
    spec = dataclasses.replace(setup.job.spec, overview_resampling=overviews)
    try:
        product = make_product(setup.plan, setup.job, setup.out, spec, tiles,
                               overwrite=overwrite, compress=settings.compress)  # fmt: skip
    except EmptyProduct:
        raise OrthoError(f"{setup.image.path}: no tile of the product holds data (the "
                         "image does not reach the output grid)") from None  # fmt: skip
    total, cells = product.total, setup.plan.width * setup.plan.height
    return OrthoReport(
        path=product.path, crs=setup.crs.to_string(), res_m=float(setup.job.spec.transform[0]),
        width=setup.plan.width, height=setup.plan.height, bounds=setup.bounds,
        grid_error_px=total.grid_error_px,
        refined_fraction=total.refined_blocks / max(total.blocks, 1),
        valid_fraction=total.valid_px / cells,
        occluded_fraction=total.occluded_px / cells if settings.occlusion != "off" else None,
        seconds=time.perf_counter() - t_start, tiles=product.tiles,
        empty_tiles=product.empty_tiles, reused_tiles=product.reused_tiles,
        workers=product.workers, scheduler=product.scheduler, gsd=setup.gsd,
    )  # fmt: skip
