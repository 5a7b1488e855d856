"""Everything before the first tile of an orthoimage: inputs, footprint, grid, checks, tile plan.

:func:`plan_ortho` works on the host: the image (raster, model, pixel frame:
:func:`jaxgeo.io.open_image`), the DEM under the image's footprint, the footprint on it, the
output grid (default: the local UTM zone at the image's GSD), the checks of the options that
need the inputs (:mod:`._validate`: resolution against the GSD, bounds against the footprint,
size; the others are checked when the :class:`._settings.OrthoSettings` is made), and the tile
plan with each tile's ground box and image window, and the per-tile job
(:class:`._job.OrthoJob`) with the padded shapes all tiles compute with.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
import os
import pathlib
from collections.abc import Sequence

import numpy as np

from .._runtime.kept import kept
from ..io import DEM, SensorImage, open_image, read_dem
from ..io.internal import file_id, open_raster, refuse_existing
from ..tiles import RasterSpec, TilePlan, plan_tiles
from ..tiles.internal import overview_factors
from ._grid import common_resolution, default_crs, dem_for_image, footprint, ground_sample_distance
from ._grid import output_grid as make_output_grid
from ._job import DEMSource, OrthoJob
from ._settings import OrthoSettings
from ._validate import (
    M_PER_DEG,
    OrthoError,
    check_bounds_cover,
    check_crs,
    check_res,
    check_size,
)

WINDOW_MAX_PX = 2048
"""A tile's image window is kept near this size (px a side): a resolution coarser than the GSD
gets smaller tiles, so memory per tile stays bounded whatever the resolution."""


@dataclasses.dataclass(frozen=True)
class OrthoSetup:
    """An orthoimage ready to run: the per-tile ``job``, the tile ``plan``, the ``image`` and
    the output ``out``; ``crs`` (pyproj) and ``bounds`` of the output grid; ``gsd``: the image's
    ground sample distance at its centre (CRS units)."""

    job: OrthoJob
    plan: TilePlan
    image: SensorImage
    out: pathlib.Path
    crs: object
    bounds: tuple[float, float, float, float]
    gsd: float = math.nan


def _model_digest(model) -> str:
    import jax

    h = hashlib.sha256(type(model).__qualname__.encode())
    for leaf in jax.tree.leaves(model):
        h.update(np.ascontiguousarray(np.asarray(leaf)).tobytes())
    return h.hexdigest()


def _file_id(path) -> dict:
    return file_id(path)  # a URL: its address and the server's size and ETag


@kept
def _project(model, ground):
    return model.project(ground)


def _tile_inputs(plan_tiles_list, grid, crs, model, h_range, img_size, margin_deg):
    """Per tile: its WGS84 ground box and the image window it reads (px, clipped; ``None`` when
    it sees no pixel of the image), from its outline projected at the DEM's lowest and highest
    heights."""
    import pyproj

    to_ll = pyproj.Transformer.from_crs(crs, 4326, always_xy=True)
    t = np.linspace(0.0, 1.0, 5)
    zero, one = np.zeros_like(t), np.ones_like(t)
    outline = np.concatenate([np.stack(pair, -1) for pair in ((t, zero), (t, one), (zero, t),
                                                              (one, t))])  # fmt: skip
    xs, ys = [], []
    for tile in plan_tiles_list:
        xs.append(grid.west + (tile.col + outline[:, 0] * tile.cols) * grid.res_m)
        ys.append(grid.north - (tile.row + outline[:, 1] * tile.rows) * grid.res_y)
    lon, lat = to_ll.transform(np.concatenate(xs), np.concatenate(ys))
    ll = np.stack([lon, lat], -1).reshape(len(plan_tiles_list), len(outline), 2)
    ground = np.concatenate([np.concatenate([ll, np.full(ll.shape[:2] + (1,), h)], -1)
                             for h in h_range], axis=1)  # fmt: skip
    xy = np.asarray(_project(model, ground.reshape(-1, 3)))
    xy = xy.reshape(len(plan_tiles_list), -1, 2)
    w, h = img_size
    out = {}
    for k, tile in enumerate(plan_tiles_list):
        lo, hi = ll[k].min(0) - margin_deg, ll[k].max(0) + margin_deg
        box = [float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])]
        p = xy[k][np.all(np.isfinite(xy[k]), axis=-1)]
        window = None
        if len(p):
            c0, r0 = np.floor(p.min(0) - 3).astype(int)
            c1, r1 = np.ceil(p.max(0) + 4).astype(int)
            c0, r0, c1, r1 = max(c0, 0), max(r0, 0), min(c1, w), min(r1, h)
            if c1 > c0 and r1 > r0:
                window = [int(c0), int(r0), int(c1 - c0), int(r1 - r0)]
        out[tile.id] = {"lonlat_box": box, "image_window": window}
    return out


def _balanced_tile(width: int, height: int, tile: int, step_px: int) -> int:
    """For a small product (two tiles a side at most, more than one in all): the tile size (px
    a side, at most ``tile``) that splits it into as many tiles as ``tile`` does, but of even
    sizes. Every tile is computed at one padded shape, so a product slightly larger than a tile
    computed its edge tiles whole: 1052 x 1086 px in 1024 px tiles, 4.2 M positions for 1.1 M
    pixels (3.6x the work); in 544 px tiles 1.2 M. A multiple of ``step_px`` and of the COG's
    largest overview decimation (the tiles' overviews still align with the product's);
    ``tile`` itself otherwise (a larger product's edge tiles are a smaller share of its work),
    or where no smaller size keeps the count."""
    nx, ny = math.ceil(width / tile), math.ceil(height / tile)
    if nx == ny == 1 or max(nx, ny) > 2:
        return tile
    factors = overview_factors(width, height)
    q = math.lcm(step_px, factors[-1] if factors else 1)
    even = math.ceil(max(math.ceil(width / nx), math.ceil(height / ny)) / q) * q
    return even if even < tile else tile


def plan_ortho(
    image: str | os.PathLike | SensorImage,
    dem: DEM | str | os.PathLike,
    out: str | os.PathLike,
    settings: OrthoSettings = OrthoSettings(),  # noqa: B008 (frozen: one default is safe)
    *,
    model=None,
    image_origin: Sequence[float] | None = None,
    overwrite: bool = False,
) -> OrthoSetup:
    """Everything :func:`orthorectify` checks and plans before computing a tile (the same
    arguments but ``tiles``); raises :class:`OrthoError` (or ``ValueError``/``FileExistsError``)
    naming what is wrong, before any computation when it is an option."""
    if not isinstance(settings, OrthoSettings):
        raise TypeError(f"settings must be an OrthoSettings, got {type(settings).__name__}")
    if dem is None or out is None:
        raise TypeError("plan_ortho needs a dem and an out path")
    out = refuse_existing(out, overwrite)  # first: nothing is read for an output kept
    if isinstance(image, SensorImage):
        if model is not None or image_origin is not None:
            raise TypeError("give model and image_origin to open_image, not with a SensorImage")
        sensor = image
    else:
        sensor = open_image(image, model=model, origin=image_origin)
    if sensor.path is None or sensor.size is None:
        raise OrthoError(f"image {sensor.name}: orthorectification needs the raster")
    if not isinstance(dem, DEM):
        dem = read_dem(dem, height="ellipsoidal")
    out = pathlib.Path(out)
    inputs = [*sensor.inputs, *dem.inputs]
    for p in inputs:
        if out.resolve() == p.resolve():
            raise OrthoError(f"{out}: this output is an input (image, model or DEM); name another")
    s = settings  # checked when made (crs, res_m, bounds: the degrees once the GSD is known)
    like = s.like  # an OutputGrid (a raster's, read when the settings were made)
    if like is not None and like.source is not None:
        if out.resolve() == pathlib.Path(like.source).resolve():
            raise OrthoError(f"{out}: this output is the raster whose grid it takes (like); "
                             "name another")  # fmt: skip
    resampling, occlusion, step_px, tol_px = s.resampling, s.occlusion, s.step_px, s.tol_px
    out_crs = like.crs if like is not None else check_crs(s.crs) if s.crs is not None else None
    box = s.bounds
    asked = box if box is not None else like.bounds if like is not None else None

    width, height = sensor.size
    with open_raster(sensor.path) as src:  # a raster in its own pixel frame
        bands, dtype = src.count, src.dtypes[0]
    model = sensor.model
    need = None  # the output asked for: a DEM that covers it is enough
    if asked is not None:  # --bounds or the --like grid
        import pyproj

        to_ll = pyproj.Transformer.from_crs(out_crs, 4326, always_xy=True)
        need = to_ll.transform_bounds(*asked, densify_pts=21)
    dem_grid = dem_for_image(model, dem, width, height, source=str(sensor.path), need=need)
    ground = footprint(model, dem_grid, width, height, source=str(dem.path), warn=need is None)
    out_crs = out_crs if out_crs is not None else default_crs(ground)
    gsd = ground_sample_distance(model, dem_grid, out_crs, width, height)
    gsd_m = gsd * M_PER_DEG if out_crs.is_geographic else gsd
    import pyproj

    tr = pyproj.Transformer.from_crs(4326, out_crs, always_xy=True)
    fx, fy = tr.transform(ground[:, 0], ground[:, 1])
    poly = np.stack([fx, fy], -1)
    if like is not None:  # its grid exactly; a product with data, and not over the limit
        what = f"the grid of {like.source}" if like.source else "the grid given (like)"
        check_bounds_cover(like.bounds, poly, str(sensor.path), what)
        grid = like
        check_size(grid.width, grid.height, grid.res_m, s.max_pixels, gsd, min_side=1)
    else:
        res = check_res(s.res_m if s.res_m is not None else common_resolution(gsd), out_crs, gsd_m)
        if box is not None:
            check_bounds_cover(box, poly, str(sensor.path))
        grid = make_output_grid(ground, out_crs, res, box, s.tap)
        check_size(grid.width, grid.height, res, s.max_pixels, gsd)
    res = max(grid.res_m, grid.res_y)  # the coarser side sizes the tiles and the occlusion test

    # tiles: the image window of a tile stays near WINDOW_MAX_PX whatever the resolution
    # (20 % over: the common resolution, up to 16 % coarser than the GSD, keeps full tiles)
    scale = res / gsd
    tile = min(int(s.tile_px), max(int(1.2 * WINDOW_MAX_PX / 2 / max(scale, 1e-9)), 4 * step_px))
    if tile < s.tile_px:  # a power of two: the tiles' overviews align with the product's
        tile = 2 ** int(math.log2(tile))
    tile = max(tile // step_px * step_px, 4 * step_px)
    tile = _balanced_tile(grid.width, grid.height, tile, step_px)
    th = min(tile, math.ceil(grid.height / step_px) * step_px)
    tw = min(tile, math.ceil(grid.width / step_px) * step_px)
    # (the plan keeps the power-of-two size: a product smaller than it is one tile)
    # the DEM a tile reads: its ground box plus (occlusion) the horizontal travel of a line
    # of sight from the lowest terrain to the highest
    z = np.asarray(dem_grid.heights_m)
    lo, hi = float(np.nanmin(z)), float(np.nanmax(z))  # numpy: no eager jax program to compile
    sensor.check_heights(lo, hi, pathlib.Path(dem.path).name)  # warns outside the RPC's range
    lat0 = float(np.mean(ground[:, 1]))
    margin_deg = 0.0
    occ_thresh = max(2.0 * (res * M_PER_DEG if out_crs.is_geographic else res), 0.5)
    if occlusion != "off":
        c = np.array([(width - 1) / 2, (height - 1) / 2])
        g0 = np.asarray(model.localize(c, lo))
        g1 = np.asarray(model.localize(c, hi + 10.0))
        coslat = math.cos(math.radians(lat0))
        travel_deg = math.hypot((g1[0] - g0[0]) * coslat, g1[1] - g0[1])  # of latitude
        cell_deg = float(np.abs(np.asarray(dem_grid.step)).max())
        if dem_grid.utm_zone != 0:
            cell_deg /= M_PER_DEG
        margin_deg = (1.2 * travel_deg + 2 * cell_deg) / coslat  # as degrees of longitude

    plan0 = plan_tiles("ortho", grid.width, grid.height, tile)  # the windows, then the inputs
    per_tile = _tile_inputs(plan0.tiles, grid, out_crs, model, (lo - 1.0, hi + 1.0),
                            (width, height), margin_deg)  # fmt: skip
    # padded shapes every tile computes with (one compiled program for all)
    wins = [v["image_window"] for v in per_tile.values() if v["image_window"] is not None]
    slope_pad = 64
    win_rows = max([w[3] for w in wins], default=64) + slope_pad
    win_cols = max([w[2] for w in wins], default=64) + slope_pad
    window_shape = (int(math.ceil(win_rows / 128) * 128), int(math.ceil(win_cols / 128) * 128))
    step = np.abs(np.asarray(dem_grid.step))
    if dem_grid.utm_zone != 0:  # metres: as degrees at this latitude (upper bound)
        step = step / (M_PER_DEG * np.array([1.0, 1.0]))
    cells = []
    for v in per_tile.values():
        b = v["lonlat_box"]
        cells.append(((b[3] - b[1]) / step[1], (b[2] - b[0]) / step[0]))
    cells = np.max(np.asarray(cells), axis=0) + 8
    dem_shape = (int(math.ceil(cells[0] / 8) * 8), int(math.ceil(cells[1] / 8) * 8))

    is_float = np.issubdtype(np.dtype(dtype), np.floating)
    nodata = s.nodata
    if nodata is None:
        nodata = float("nan") if is_float else 0
    out_bands = bands + (1 if occlusion == "band" else 0)
    t = grid.transform
    # the COG's overviews made by the tiles (in parallel) when every level aligns with them
    factors = overview_factors(grid.width, grid.height)
    if factors and tile % factors[-1]:
        factors = ()
    overviews = "nearest" if resampling == "nearest" else "average"
    spec = RasterSpec(out_bands, str(dtype), nodata, out_crs.to_wkt(),
                      (t.a, t.b, t.c, t.d, t.e, t.f), factors, overviews)  # fmt: skip
    source = DEMSource.of(dem)
    job = OrthoJob(
        image=str(sensor.path), image_size=(width, height), model=model, dem=source, spec=spec,
        tile_shape=(th, tw), window_shape=window_shape, dem_shape=dem_shape,
        dem_margin_deg=margin_deg, resampling=resampling, occlusion=occlusion,
        occ_thresh_m=occ_thresh, step_px=step_px, tol_px=tol_px,
    )  # fmt: skip
    nd = "nan" if isinstance(nodata, float) and math.isnan(nodata) else nodata
    job_model = _model_digest(model)
    fields = dataclasses.fields(job)
    job_text = repr({f.name: getattr(job, f.name) for f in fields if f.name != "model"})
    job_dict = {  # what the tiles depend on (not the output's name: a renamed output resumes)
        "image": _file_id(sensor.path),
        "image_size": [width, height],
        "image_origin": list(sensor.origin),
        "model": type(sensor.source_model).__name__,
        "model_file": str(sensor.model_path) if sensor.model_path else None,
        "model_sha256": job_model,
        "dem": {**dataclasses.asdict(source), **_file_id(dem.path)},
        "crs": out_crs.to_string(),
        "crs_wkt": out_crs.to_wkt(),
        "res": [grid.res_m, grid.res_y],
        "transform": list(spec.transform),
        "width": grid.width,
        "height": grid.height,
        "bands": out_bands,
        "dtype": str(dtype),
        "nodata": nd,
        "resampling": resampling,
        "occlusion": occlusion,
        "step_px": step_px,
        "tol_px": tol_px,
        "tile_shape": list(job.tile_shape),
        "window_shape": list(window_shape),
        "dem_shape": list(dem_shape),
        "dem_margin_deg": margin_deg,
        "overviews": list(spec.overviews),
        # everything a tile depends on (a folder of tiles of another job is never resumed)
        "job_sha256": hashlib.sha256(job_text.encode() + job_model.encode()).hexdigest(),
    }
    plan = plan_tiles("ortho", grid.width, grid.height, tile, 0, job=job_dict,
                      inputs=lambda t: per_tile[t.id])  # fmt: skip
    return OrthoSetup(job, plan, sensor, out, out_crs, grid.bounds, gsd)
