"""A DSM of a whole scene, tile by tile, on the tile runner (:mod:`jaxgeo.tiles`).

The DSM's grid (map cells of ``res_m`` in a projected CRS) is cut into tiles of ``tile_px`` cells.
A tile is one call of :class:`DSMJob`: the reference-image window that sees the tile's ground
box (its outline, widened by ``margin_m``, projected at the lowest and highest terrain heights),
then, per pair (reference, i), the whole stereo chain of :func:`~jaxgeo.stereo.stereo_pair` on
that window alone: its own tie points, rectification at its own elevation (epipolar lines of a
pushbroom scene are not straight over tens of kilometres), its own vertical disparity and
disparity range, dense matching, triangulation. The points within ``margin_m`` of the tile are
rasterised (:func:`~jaxgeo.stereo.rasterize`: footprints, holes, the height sigma) on the tile's
cells and that margin, and the tile's own cells are written; the mosaic is a COG with the bands of
:data:`~jaxgeo.stereo.DSM_BANDS`. Memory per tile follows the tile, time the scene's area.

A tile where a pair fails (no texture, water, clouds: too few tie points) keeps the other pairs;
a tile where every pair fails is nodata (named in the report), not an error of the scene. With
three or more images each tile removes its pairs' relative height offsets (as the untiled DSM).

An untiled DSM (a small ROI) is a plan of one tile (``plan_dsm(..., tiled=False)``) whose work
(:class:`WholeDSMJob`) is :func:`~jaxgeo.stereo.dsm_from_images` on the ROI, in this process.
Both run through :func:`jaxgeo.tiles.make_product` (work folder, tiles, COG, clean-up).
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
import os
import pathlib
import warnings
from collections.abc import Sequence

import numpy as np

from ..io.internal import file_id
from ..models import AbstractSensorModel
from ..tiles import RasterSpec, Tile, TilePlan, plan_tiles
from ..tiles.internal import NoData, cores, overview_factors, write_tile
from ._binning import map_points_in_box, spacing_xy
from ._dem_check import check_dem
from ._dsm import (
    DSM_BANDS,
    dsm_band_tags,
    dsm_grid,
    local_utm_epsg,
    rasterize_map,
)
from ._heights import (
    HEIGHT_MARGIN_M,
    sample_windows,
    sampled_heights,
    scene_heights,
    tile_tie_heights,
)
from ._pipeline import _height_offsets, dsm_from_images, image_size, stereo_pair
from ._settings import DEFAULT_DSM, DSMSettings
from ._stages import StageTimes, stage
from ._ties import TieError, footprint_dem_heights, validity_heights
from ._triangulation import StereoError, los_heights
from ._uncertainty import Orientation, pair_orientation, resolved_orientation, sigma_covers

TILE_CELLS = 1024
"""Cells a side of a DSM tile (at 0.5 m cells on a 0.5 m GSD image: about 1 000 image px)."""
TILED_MIN_PX = 2048
"""A reference window larger than this (px, either side) is made tile by tile by default."""
CONTEXT_M = 16.0
"""Metres around a tile's box that its window adds for the matching's context (on top of the
margin whose points it keeps)."""


def _margin_m(res_m: float, max_hole_m: float) -> float:
    """Points kept around a tile (m): the footprint of a point and the holes interpolated need
    the neighbours' heights."""
    return float(max_hole_m + 8.0 * res_m)


@dataclasses.dataclass(frozen=True)
class DSMJob:
    """The per-tile work of one DSM (called as ``job(tile, path)`` by the tile runner).

    ``models``/``paths``: the images, the reference first, each model in its raster's pixels;
    ``epsg``, ``res_m``, ``x0``, ``y0``: the DSM's grid (upper-left corner, m); ``heights``:
    the terrain's lowest and highest height (m, ellipsoidal) the windows are projected at;
    ``margin_m`` (points kept around a tile); ``settings``: the DSM's
    (:class:`~jaxgeo.stereo.DSMSettings`; its ``heights``: the tie points' height range,
    ``None``: each tile finds it by a coarse matching)."""

    models: tuple[AbstractSensorModel, ...]
    paths: tuple[str, ...]
    epsg: int
    res_m: float
    x0: float
    y0: float
    heights: tuple[float, float]
    margin_m: float
    spec: RasterSpec
    settings: DSMSettings = DEFAULT_DSM
    orientation: tuple | None = None
    """Per pair (reference, i) the ``(4, 4)`` shift covariance (px^2), or ``None``."""

    def box(self, tile: Tile, margin_m: float = 0.0) -> tuple[float, float, float, float]:
        """``(xmin, ymin, xmax, ymax)`` of the tile's cells (map m), widened by ``margin_m``."""
        xmin = self.x0 + tile.col * self.res_m - margin_m
        ymax = self.y0 - tile.row * self.res_m + margin_m
        xmax = self.x0 + (tile.col + tile.cols) * self.res_m + margin_m
        ymin = self.y0 - (tile.row + tile.rows) * self.res_m - margin_m
        return xmin, ymin, xmax, ymax

    def window(self, tile: Tile) -> tuple[int, int, int, int] | None:
        """The reference image's window ``(col, row, w, h)`` that sees the tile and its margins
        at every height of ``heights`` (clipped; ``None``: it sees none of it)."""
        box = self.box(tile, self.margin_m + CONTEXT_M)
        return reference_window(self.models[0], self.paths[0], self.epsg, box, self.heights)

    def __call__(self, tile: Tile, path) -> dict:
        with StageTimes() as times:
            stats = self._run(tile, path)
        return {**stats, "stages_s": times.as_dict()}

    def _run(self, tile: Tile, path) -> dict:
        roi = self.window(tile)
        if roi is None:
            raise NoData("the reference image does not see this tile")
        ref, ref_path = self.models[0], self.paths[0]
        kept, sigmas, pairs, spacings = [], [], [], []
        xmin, ymin, xmax, ymax = self.box(tile, self.margin_m)
        for i in range(1, len(self.models)):
            name = pathlib.Path(self.paths[i]).name
            try:
                with warnings.catch_warnings():  # warned once, by the planner
                    warnings.simplefilter("ignore")
                    pair = stereo_pair(
                        (ref, self.models[i]), (ref_path, self.paths[i]),
                        dataclasses.replace(self.settings, roi=roi),
                        orientation=None if self.orientation is None else self.orientation[i - 1],
                    )  # fmt: skip
            except (StereoError, TieError) as err:  # nothing to match here: the others may
                pairs.append({"image": name, "failed": " ".join(str(err).split())})
                continue
            with stage("rasterisation"):  # projected once: the box's points, kept in map m
                idx, xyh = map_points_in_box(pair.points, self.epsg, (xmin, ymin, xmax, ymax))
                # a point's footprint is its own pair's spacing (:func:`_spacing`)
                spacings.append(spacing_xy(xyh[0], xyh[1]) if idx.size > 1 else 0.0)
                kept.append((pair.points, idx, xyh))
                sigmas.append((pair.match_sigma_m[idx], pair.orientation_sigma_m[idx]))
            pairs.append({"image": name, **_small(pair.stats), "points": int(idx.size)})
        usable = [k for k, p in enumerate(kept) if p[1].size]
        if not usable:
            reasons = "; ".join(f"{p['image']}: {p['failed']}" for p in pairs if "failed" in p)
            raise NoData(reasons or "no point of any pair falls in this tile")
        kept = [kept[k] for k in usable]
        sigmas = [sigmas[k] for k in usable]
        with stage("rasterisation"):
            heights = [xyh[2] for _, _, xyh in kept]
            if self.settings.register and len(kept) > 1:
                offsets = _height_offsets([p[i] for p, i, _ in kept], self.res_m, self.epsg)
                heights = [h - off for h, off in zip(heights, offsets, strict=True)]
            pad = int(math.ceil(self.margin_m / self.res_m))
            x0 = self.x0 + (tile.col - pad) * self.res_m
            y0 = self.y0 - (tile.row - pad) * self.res_m
            dsm = rasterize_map(
                (_joined([xyh[0] for _, _, xyh in kept]), _joined([xyh[1] for _, _, xyh in kept]),
                 _joined(heights)),
                self.res_m, self.epsg, origin=(x0, y0),
                shape=(tile.rows + 2 * pad, tile.cols + 2 * pad),
                footprint_m=max(spacings[k] for k in usable),
                max_hole_m=self.settings.max_hole_m,
                sigmas=tuple(_joined(s) for s in zip(*sigmas, strict=True)),
            )  # fmt: skip
            bands = np.stack([b[pad : pad + tile.rows, pad : pad + tile.cols]
                              for b in dsm.bands().values()])  # fmt: skip
        valid = int(np.isfinite(bands[0]).sum())
        if valid == 0:
            raise NoData("no cell of this tile got a height")
        with stage("writing"):
            write_tile(path, self.spec, tile.row, tile.col, bands)
        return {"valid_px": valid, "filled_px": int((bands[3] == 1).sum()),
                "window": list(roi), "pairs": pairs}  # fmt: skip


def _joined(arrays: Sequence[np.ndarray]) -> np.ndarray:
    """The arrays end to end (one array itself: no copy of a million values)."""
    return arrays[0] if len(arrays) == 1 else np.concatenate(arrays)


def _small(stats: dict) -> dict:
    """The numbers of a pair's stats worth keeping per tile (JSON)."""
    keys = ("n_ties", "h_ref_m", "vertical_disparity_px", "disparity_range_px", "disparity_fill",
            "triangulation_lattice_error_m", "sigma_lattice_jacobian_error")  # fmt: skip
    out = {}
    for k in keys:
        if k in stats:
            v = stats[k]
            out[k] = [float(x) for x in v] if isinstance(v, (tuple, list)) else float(v)
    return out


def reference_window(model, path, epsg, box, heights) -> tuple[int, int, int, int] | None:
    """The window ``(col, row, w, h)`` of the image ``path`` (its ``model``) that sees the map
    ``box = (xmin, ymin, xmax, ymax)`` (EPSG ``epsg``) at the heights ``(lo, hi)``: its outline
    projected at both (clipped to the image; ``None``: none of it)."""
    import pyproj

    t = np.linspace(0.0, 1.0, 9)
    xmin, ymin, xmax, ymax = box
    xs = np.concatenate([xmin + t * (xmax - xmin), xmin + t * (xmax - xmin),
                         np.full_like(t, xmin), np.full_like(t, xmax)])  # fmt: skip
    ys = np.concatenate([np.full_like(t, ymin), np.full_like(t, ymax),
                         ymin + t * (ymax - ymin), ymin + t * (ymax - ymin)])  # fmt: skip
    lon, lat = pyproj.Transformer.from_crs(epsg, 4326, always_xy=True).transform(xs, ys)
    ground = np.concatenate([np.stack([lon, lat, np.full_like(xs, h)], -1) for h in heights])
    xy = np.asarray(model.project(ground))
    xy = xy[np.all(np.isfinite(xy), axis=1)]
    if not len(xy):
        return None
    w, h = image_size(path)
    c0, r0 = (int(v) for v in np.floor(xy.min(0)))
    c1, r1 = (int(v) for v in np.ceil(xy.max(0)) + 1)
    c0, r0, c1, r1 = max(c0, 0), max(r0, 0), min(c1, w), min(r1, h)
    if c1 - c0 < 32 or r1 - r0 < 32:  # a sliver at the image's edge: nothing to match
        return None
    return c0, r0, c1 - c0, r1 - r0


@dataclasses.dataclass(frozen=True)
class WholeDSMJob:
    """The work of an untiled DSM, the one tile of its plan (``job(tile, path)``, in this
    process): :func:`~jaxgeo.stereo.dsm_from_images` over the ROI (``settings.roi``) on the
    tile's cells, with each pair's stats (``pairs``) and the median ``height_sigma``. ``dem``
    (the tie points' height range where ``settings.heights`` is not given) and ``progress``
    (a bar per pair) are not part of the job's identity."""

    models: tuple[AbstractSensorModel, ...]
    paths: tuple[str, ...]
    epsg: int
    res_m: float
    x0: float
    y0: float
    spec: RasterSpec
    settings: DSMSettings = DEFAULT_DSM
    orientation: object = dataclasses.field(default=None, compare=False, repr=False)
    dem: object = dataclasses.field(default=None, compare=False, repr=False)
    progress: bool = dataclasses.field(default=False, compare=False, repr=False)

    def __call__(self, tile: Tile, path) -> dict:
        x0 = self.x0 + tile.col * self.res_m
        y0 = self.y0 - tile.row * self.res_m
        dsm, stats = dsm_from_images(
            self.models, self.paths, self.settings, origin=(x0, y0), shape=(tile.rows, tile.cols),
            dem=self.dem, orientation=self.orientation, progress=self.progress,
        )  # fmt: skip
        bands = np.stack(list(dsm.bands().values()))
        valid = int(np.isfinite(bands[0]).sum())
        if valid == 0:
            raise NoData("no cell got a height")
        write_tile(path, self.spec, tile.row, tile.col, bands)
        sigma = bands[4][np.isfinite(bands[4])]
        median = round(float(np.median(sigma)), 4) if sigma.size else None
        return {"valid_px": valid, "filled_px": int((bands[3] == 1).sum()),
                "pairs": [_json(st) for st in stats], "median_height_sigma_m": median}  # fmt: skip


def _json(value):
    """``value`` with numpy numbers and arrays, and tuples, as JSON types."""
    if isinstance(value, dict):
        return {str(k): _json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json(v) for v in value]
    if isinstance(value, np.ndarray):
        return _json(value.tolist())
    if isinstance(value, np.generic):
        return value.item()
    return value


@dataclasses.dataclass(frozen=True)
class DSMSetup:
    """A DSM ready to run: the per-tile ``job`` (:class:`DSMJob`, or :class:`WholeDSMJob`
    for the one tile of an untiled DSM) and the tile ``plan``."""

    job: DSMJob | WholeDSMJob
    plan: TilePlan

    @property
    def tiled(self) -> bool:
        return isinstance(self.job, DSMJob)


def _file_id(path) -> dict:
    return file_id(path)  # a URL: its address and the server's size and ETag


def _model_digest(models) -> str:
    import jax

    h = hashlib.sha256()
    for model in models:
        h.update(type(model).__qualname__.encode())
        for leaf in jax.tree.leaves(model):
            h.update(np.ascontiguousarray(np.asarray(leaf)).tobytes())
    return h.hexdigest()


def dsm_heights(
    models, paths, settings: DSMSettings, dem=None, tiled: bool = True
) -> tuple[tuple[float, float], str]:
    """The terrain's height range (m, ellipsoidal) over ``settings.roi`` and where it comes
    from: ``settings.heights`` (``"given"``), else the DEM's heights over the footprint +-50 m
    (``"dem"``), else the tie points' (``"tie points"``: :func:`scene_heights`; for an untiled
    DSM, ``tiled=False``, within the models' whole validity cube, whose points it keeps, and
    each window once), else the reference model's validity range. A DEM unlike the images is
    refused (:func:`~._dem_check.check_dem`)."""
    if settings.heights is not None:
        return settings.heights, "given"
    roi = settings.roi or (0, 0, *image_size(paths[0]))
    if dem is not None:
        lo, hi = footprint_dem_heights(models[0], dem, roi)
        check_dem(models, paths, sample_windows(roi)[0], dem, (lo, hi))  # refuses a wrong DEM
        return (lo - HEIGHT_MARGIN_M, hi + HEIGHT_MARGIN_M), "dem"
    if tiled:
        heights = scene_heights(models, paths, roi)
    else:
        windows = list(dict.fromkeys(sample_windows(roi)))
        heights = sampled_heights(models, paths, windows, validity_heights(models[0]))
    if heights is not None:
        return heights, "tie points"
    return (los_heights if tiled else validity_heights)(models[0]), "the model's validity range"


def plan_dsm(
    models: Sequence[AbstractSensorModel],
    paths: Sequence[str | os.PathLike],
    settings: DSMSettings = DEFAULT_DSM,
    *,
    dem=None,
    orientation: Orientation = None,
    tiled: bool = True,
    progress: bool = False,
) -> DSMSetup:
    """The tile plan and per-tile job of the DSM of ``settings.roi`` of the first image (whole
    image by default) from the pairs (first, i).

    The terrain's heights (:func:`dsm_heights`: ``settings.heights``, else ``dem``'s +-50 m,
    else sampled by :func:`scene_heights`, else the reference model's validity range): the
    grid covers the ROI's footprint at their middle, and each tile reads the reference window
    that sees it at both; the tie points' height range is :func:`tile_tie_heights` (the plan's,
    else each tile's coarse matching). ``tiled=False``: a plan of one tile whose work is
    :func:`~jaxgeo.stereo.dsm_from_images` over the ROI (:class:`WholeDSMJob`, run in this
    process; ``progress``: a bar per pair), its grid the ROI's footprint between both heights.
    ``orientation``: :func:`dsm_from_images`.
    """
    if len(models) != len(paths) or len(paths) < 2:
        raise StereoError(f"dsm: give at least two images, each with its model ({len(paths)} "
                          f"images, {len(models)} models)")  # fmt: skip
    tile_px = settings.tile_px or TILE_CELLS
    res_m = settings.res_m
    ref = models[0]
    w, h = image_size(paths[0])
    col, row, rw, rh = settings.roi if settings.roi is not None else (0, 0, w, h)
    (lo, hi), source = dsm_heights(models, paths, settings, dem, tiled)
    covers = sigma_covers(orientation, len(paths))  # None: not adjusted, the a priori sigma
    orientation = resolved_orientation(orientation, len(paths))
    t = np.linspace(0.0, 1.0, 17)
    c, r, one = col - 0.5 + t * rw, row - 0.5 + t * rh, np.ones_like(t)
    edge = np.concatenate([np.stack(xy, -1) for xy in ((c, one * (row - 0.5)),
                           (c, one * (row + rh - 0.5)), (one * (col - 0.5), r),
                           (one * (col + rw - 0.5), r))])  # fmt: skip
    # an untiled DSM keeps every point of its ROI: its grid holds the footprint at both heights
    levels = (0.5 * (lo + hi),) if tiled else (lo, 0.5 * (lo + hi), hi)
    ground = np.concatenate([np.asarray(ref.localize(edge, np.full(len(edge), z)))
                             for z in levels])  # fmt: skip
    if not np.all(np.isfinite(ground)):
        raise StereoError(f"dsm: the model of {paths[0]} cannot localise the edges of the ROI")
    epsg = settings.epsg
    if epsg is None:
        epsg = local_utm_epsg(float(np.median(ground[:, 0])), float(np.median(ground[:, 1])))
    x0, y0, cols, rows = dsm_grid(ground, epsg, settings, paths[0])
    tile = int(tile_px) if tiled else max(rows, cols, 1)
    factors = overview_factors(cols, rows)
    if factors and tile % factors[-1]:
        factors = ()
    names = list(DSM_BANDS)
    spec = RasterSpec(len(names), "float32", float("nan"), _wkt(epsg),
                      (res_m, 0.0, x0, 0.0, -res_m, y0), factors, "average",
                      descriptions=tuple(names),
                      units=tuple(DSM_BANDS[n][0] for n in names),
                      band_tags=dsm_band_tags(covers),
                      tags=(("heights", "ellipsoidal (WGS84), m"),))  # fmt: skip
    grid = dict(models=tuple(models), paths=tuple(str(p) for p in paths), epsg=int(epsg),
                res_m=float(res_m), x0=x0, y0=y0, spec=spec)  # fmt: skip
    if tiled:
        per_pair = tuple(pair_orientation(orientation, len(paths), 0, i)
                         for i in range(1, len(paths)))  # fmt: skip
        tie = tile_tie_heights(models, (lo, hi), source)
        job = DSMJob(**grid, heights=(float(lo), float(hi)),
                     margin_m=_margin_m(res_m, settings.max_hole_m),
                     settings=dataclasses.replace(settings, heights=tie, roi=None),
                     orientation=per_pair)  # fmt: skip
    else:
        job = WholeDSMJob(**grid, settings=dataclasses.replace(settings, epsg=int(epsg)),
                          orientation=orientation, dem=dem, progress=progress)  # fmt: skip
    digest = _model_digest(models)
    fields = [f.name for f in dataclasses.fields(job)
              if f.name not in ("models", "spec", "dem", "progress")]  # fmt: skip
    job_text = repr({f: getattr(job, f) for f in fields}) + digest
    tie_heights = job.settings.heights if tiled else settings.heights
    job_dict = {
        "images": [_file_id(p) for p in paths],
        "models_sha256": digest,
        "roi": [col, row, rw, rh],
        "epsg": int(epsg),
        "res_m": float(res_m),
        "transform": list(spec.transform),
        "width": cols,
        "height": rows,
        "heights_m": [float(lo), float(hi)],
        "heights_from": source,
        "tie_heights_m": None if tie_heights is None else [float(v) for v in tie_heights],
        "margin_m": job.margin_m if tiled else 0.0,
        "method": settings.triangulation,
        "register": settings.register,
        "bands": names,
        "job_sha256": hashlib.sha256(job_text.encode()).hexdigest(),
    }
    if not tiled:
        plan = plan_tiles("dsm", cols, rows, tile, 0, job=job_dict,
                          inputs=lambda t: {"reference_window": [col, row, rw, rh]})  # fmt: skip
        return DSMSetup(job, plan)
    plan0 = plan_tiles("dsm", cols, rows, tile)
    windows = {t.id: job.window(t) for t in plan0.tiles}
    plan = plan_tiles("dsm", cols, rows, tile, 0, job=job_dict,
                      inputs=lambda t: {"reference_window": _listed(windows[t.id]),
                                        "box_m": list(job.box(t)),
                                        "cost": _area(windows[t.id])})  # fmt: skip
    return DSMSetup(job, plan)


def _area(window) -> int:
    """Reference pixels a tile reads (its work: ties, matching, triangulation): 0 for none."""
    return 0 if window is None else int(window[2]) * int(window[3])


def _listed(window):
    return None if window is None else [int(v) for v in window]


def _wkt(epsg: int) -> str:
    import pyproj

    return pyproj.CRS.from_epsg(epsg).to_wkt()


def dsm_workers(workers: int | None, tiles: int | None = None) -> int:
    """Worker processes of a tiled DSM: ``workers`` where given, else one per core on 2+ cores
    (a DSM tile is tens of seconds: workers pay off) for several tiles (``tiles``; unknown
    before the planning, when :func:`make_dsm` starts them: assumed several)."""
    if workers is not None:
        return workers
    return cores() if cores() > 1 and (tiles is None or tiles > 1) else 0
