"""The DSM of images, one call (:func:`make_dsm`): what ``jaxgeo dsm`` does; the run of a
planned DSM (:func:`tiled_dsm`, through :func:`jaxgeo.tiles.make_product`).

Always through a tile plan (:func:`~jaxgeo.stereo.plan_dsm`): a reference window larger than
:data:`~jaxgeo.stereo.TILED_MIN_PX` px a side, or any tile option (a tile size, workers, a
scheduler, a resume folder, a plan file), makes the DSM tile by tile (:class:`DSMJob`, on
worker processes started before the planning so that their start overlaps it); a smaller one
is a plan of one tile run in this process (:class:`WholeDSMJob`: the ROI's stereo chain in one
piece, :func:`~jaxgeo.stereo.dsm_from_images`). Everything given is checked before any
computation: the images, the ROI, the DSM's size (``max_cells``).
"""

from __future__ import annotations

import dataclasses
import math
import os
import sys
import time
from collections.abc import Sequence

import numpy as np

from .._runtime.progress import say
from ..io import SensorImage, open_image
from ..tiles import EmptyProduct, TileError, TileSettings, TileStats, make_product
from ..tiles.internal import DEFAULT_TILES, WorkerPool
from ._dsm import DSM_BANDS
from ._report import DSMReport
from ._settings import DEFAULT_DSM, DSMSettings, DSMSettingsError
from ._tiled import TILED_MIN_PX, DSMSetup, dsm_workers, plan_dsm
from ._triangulation import StereoError
from ._uncertainty import Orientation, vendor_orientation


def footprint_cells(image: SensorImage, settings: DSMSettings) -> tuple[float, float]:
    """Approximate DSM size (rows, cols) of ``settings.roi`` of ``image`` at ``settings.res_m``:
    its corners localised at the model's reference height, in the output CRS (NaN: the model
    cannot localise them)."""
    import pyproj

    from ..geodesy import utm_epsg, utm_zone

    x, y, w, h = settings.roi if settings.roi is not None else (0, 0, *image.size)
    corners = np.array([[x, y], [x + w, y], [x, y + h], [x + w, y + h]], dtype=float) - 0.5
    height = float(np.asarray(image.model.reference_ground())[2])
    ground = np.asarray(image.model.localize(corners, np.full(4, height)))
    if not np.all(np.isfinite(ground)):
        return (math.nan, math.nan)
    lon, lat = float(ground[:, 0].mean()), float(ground[:, 1].mean())
    epsg = settings.epsg or utm_epsg(utm_zone(lon, lat), north=lat >= 0)
    tr = pyproj.Transformer.from_crs(4326, epsg, always_xy=True)
    mx, my = tr.transform(ground[:, 0], ground[:, 1])
    return (np.ptp(my) / settings.res_m, np.ptp(mx) / settings.res_m)


def is_tiled(image: SensorImage, settings: DSMSettings, tiles: TileSettings) -> bool:
    """Tile by tile: asked for (a tile size or a tile option other than ``retries`` and
    ``progress``), or a reference window over :data:`TILED_MIN_PX` px a side."""
    asked = settings.tile_px is not None or any(
        v is not None for v in (tiles.workers, tiles.scheduler, tiles.resume, tiles.plan)
    )
    _, _, w, h = settings.roi if settings.roi is not None else (0, 0, *image.size)
    return asked or max(w, h) > TILED_MIN_PX


def _check(images: Sequence[SensorImage], settings: DSMSettings) -> None:
    """The ROI inside the reference image; a DSM of at least 4 and at most ``max_cells``
    cells."""
    ref = images[0]
    if settings.roi is not None:
        x, y, w, h = settings.roi
        width, height = ref.size
        if x + w > width or y + h > height:
            raise DSMSettingsError(
                "roi", f"roi {x} {y} {w} {h}: not inside {ref.path} ({width} x {height} px; "
                "need X, Y >= 0, W, H > 0, X + W <= width, Y + H <= height)",
            )  # fmt: skip
    rows, cols = footprint_cells(ref, settings)
    if settings.like is not None:  # its grid, whole
        rows, cols = float(settings.like.height), float(settings.like.width)
    res = settings.res_m
    if settings.max_cells is not None and math.isfinite(rows) and rows * cols > settings.max_cells:
        raise DSMSettingsError(
            "max_cells", f"the DSM would have about {rows:.0f} x {cols:.0f} cells at res_m "
            f"{res:g} m (more than max_cells {settings.max_cells:.0e}); raise res_m or max_cells",
        )  # fmt: skip
    if math.isfinite(rows) and rows * cols < 4:
        raise DSMSettingsError(
            "res_m", f"the DSM would have about {rows:.1f} x {cols:.1f} cells at res_m {res:g} "
            "m: lower res_m",
        )  # fmt: skip


def _early_pool(tiles: TileSettings) -> WorkerPool | None:
    """The worker processes, started now so that their start (importing jax and jaxgeo)
    overlaps the planning (~10 s); ``None`` where the tiles run here (``workers=0``, one core)
    or nothing runs (``plan``)."""
    if tiles.plan or tiles.workers == 0:
        return None
    if tiles.scheduler:
        return WorkerPool(0, tiles.scheduler, tiles.retries, warm=("jaxgeo.stereo",))
    n = dsm_workers(tiles.workers)
    return WorkerPool(n, retries=tiles.retries, warm=("jaxgeo.stereo",)) if n else None


def tiled_dsm(
    setup: DSMSetup,
    out: str | os.PathLike,
    tiles: TileSettings = DEFAULT_TILES,
    *,
    overwrite: bool = False,
    compress: str = "deflate",
    pool: WorkerPool | None = None,
) -> DSMReport:
    """Run the tiles of ``setup`` (:func:`plan_dsm`) and write the DSM as one COG at ``out``
    (atomic: complete or absent; :func:`jaxgeo.tiles.make_product`). ``tiles``: where the
    tiles run (by default one worker process per core when there are several tiles: a tile
    takes tens of seconds, a worker's start a few), ``resume`` (a folder for the finished
    tiles, kept after an interruption and reused by the next run), ``plan`` (only the plan
    written); ``pool``: workers started earlier (:class:`~jaxgeo.tiles.WorkerPool`, e.g. before
    the planning, left open), used instead of ``tiles.workers`` and ``tiles.scheduler``.
    The one tile of an untiled setup runs in this process (its errors as they are raised).
    :class:`StereoError` when no tile gets a height."""
    t0 = time.perf_counter()
    plan = setup.plan
    if not setup.tiled:
        tiles = dataclasses.replace(tiles, workers=0, scheduler=None, retries=0, progress=False)
        pool = None
    elif not tiles.scheduler:
        tiles = dataclasses.replace(tiles, workers=dsm_workers(tiles.workers, len(plan)))
    try:
        product = make_product(plan, setup.job, out, setup.job.spec, tiles, overwrite=overwrite,
                               compress=compress, pool=pool)  # fmt: skip
    except EmptyProduct as err:
        why = err.reasons()
        raise StereoError(f"dsm: no tile of {setup.job.paths[0]} got a height"
                          + (f" ({'; '.join(why)[:300]})" if why else "")) from None  # fmt: skip
    except TileError as err:
        if not setup.tiled and err.__cause__ is not None:  # the DSM's own error, as it was
            raise err.__cause__ from None
        raise
    cells = plan.width * plan.height
    one = next(iter(product.stats.values()), TileStats())
    return DSMReport(
        path=product.path, epsg=setup.job.epsg, res_m=setup.job.res_m, width=plan.width,
        height=plan.height, filled=product.total.valid_px / cells,
        interpolated=product.total.filled_px / cells, seconds=time.perf_counter() - t0,
        tiles=product.tiles, empty_tiles=product.empty_tiles,
        reused_tiles=product.reused_tiles, workers=product.workers,
        scheduler=product.scheduler, tile_stats=product.stats, tiles_s=product.tiles_s,
        mosaic_s=product.mosaic_s, tiled=setup.tiled,
        pairs=() if setup.tiled else tuple(one.details.get("pairs", ())),
        median_height_sigma_m=None if setup.tiled else one.details.get("median_height_sigma_m"),
        plan=plan, plan_path=product.plan_path, height_sigma_covers=_covers(setup.job.spec),
    )  # fmt: skip


def _covers(spec) -> str:
    """The ``covers`` tag of the ``height_sigma`` band of a DSM's raster spec ("" if none)."""
    tags = spec.band_tags[list(DSM_BANDS).index("height_sigma")] if spec.band_tags else ()
    return dict(tags).get("covers", "")


def make_dsm(
    images: Sequence[SensorImage | str | os.PathLike],
    out: str | os.PathLike,
    settings: DSMSettings = DEFAULT_DSM,
    tiles: TileSettings = DEFAULT_TILES,
    *,
    dem=None,
    orientation: Orientation = None,
    overwrite: bool = False,
) -> DSMReport:
    """The DSM of ``images`` (the reference first; :class:`jaxgeo.io.SensorImage` or raster
    paths with their RPCs) as a GeoTIFF at ``out`` (a COG with the bands of
    :data:`~jaxgeo.stereo.DSM_BANDS`, written atomically; an existing file only with
    ``overwrite``).

    ``settings``: the DSM's parameters (:class:`~jaxgeo.stereo.DSMSettings`: cells, CRS, ROI,
    heights, matching...). ``tiles``: where the tiles run (:class:`jaxgeo.tiles.TileSettings`;
    ``tiles.plan``: only the plan is written there, nothing computed). A reference window over
    :data:`~jaxgeo.stereo.TILED_MIN_PX` px a side, ``settings.tile_px`` or a tile option makes
    the DSM tile by tile; else it is one tile made in this process (``settings.keep`` only
    then). ``dem`` (a :class:`jaxgeo.io.DEM`): its heights over the footprint, +-50 m, are the
    terrain's height range unless ``settings.heights`` gives it. ``orientation``: the
    covariance of the models' image shifts (px^2, :data:`~jaxgeo.stereo.Orientation`), into
    the ``height_sigma`` band; ``None``: the models' a priori error, the vendor's
    ``ERR_BIAS``/``ERR_RAND`` where an image's RPC states them
    (:attr:`~jaxgeo.io.SensorImage.vendor_accuracy`), else the stated default
    (:func:`~jaxgeo.stereo._uncertainty.vendor_orientation`). ``tiles.progress``: the tiles'
    (or the pairs') progress and one line about the plan on stderr.

    Returns a :class:`DSMReport`. Raises :class:`DSMSettingsError` (naming the field) for
    settings these images cannot take (an ROI outside the reference image, a DSM over
    ``max_cells`` cells, ``keep`` with a tiled DSM) before any computation,
    :class:`StereoError` naming the images when the models do not fit them or no tile gets a
    height, :class:`jaxgeo.tiles.TileError` naming a tile that kept failing.
    """
    t0 = time.perf_counter()
    images = [im if isinstance(im, SensorImage) else open_image(im) for im in images]
    if len(images) < 2:
        raise StereoError("dsm: give at least two images (the reference first)")
    _check(images, settings)
    tiled = is_tiled(images[0], settings, tiles)
    if tiled and settings.keep is not None:
        raise DSMSettingsError("keep", "keep writes the products of an untiled DSM: give a roi "
                               f"of at most {TILED_MIN_PX} px without tile options")  # fmt: skip
    pool = _early_pool(tiles) if tiled else None
    try:
        models, paths = [im.model for im in images], [im.path for im in images]
        accuracies = [im.vendor_accuracy for im in images]
        if orientation is None and any(a is not None and a.known for a in accuracies):
            orientation = vendor_orientation(models, accuracies, [im.name for im in images])
        t_plan = time.perf_counter()
        if tiles.progress and settings.heights is None:  # tens of seconds on a first run
            say("jaxgeo dsm: planning: the terrain's height range from tie points in sample "
                "windows" + (" and the DEM" if dem is not None else ""))  # fmt: skip
        setup = plan_dsm(models, paths, settings, dem=dem, orientation=orientation,
                         tiled=tiled, progress=tiles.progress)  # fmt: skip
        plan, plan_s = setup.plan, time.perf_counter() - t_plan
        if tiled and tiles.progress and not tiles.plan:
            print(f"jaxgeo dsm: {len(plan)} tiles of {plan.tile_px} cells over {plan.width} x "
                  f"{plan.height} cells", file=sys.stderr, flush=True)  # fmt: skip
        # a single tile runs here unless workers were asked for (as tiled_dsm decides)
        asked = tiles.workers or tiles.scheduler
        report = tiled_dsm(setup, out, tiles, overwrite=overwrite,
                           pool=pool if asked or len(plan) > 1 else None)  # fmt: skip
    finally:
        if pool is not None:
            pool.close()
    return dataclasses.replace(report, plan_s=plan_s, seconds=time.perf_counter() - t0,
                               names=tuple(im.name for im in images))  # fmt: skip
