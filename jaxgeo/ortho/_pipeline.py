"""Orthorectification of an image with any sensor model and a DEM, tile by tile.

For each output tile: ground cells -> WGS84 lon/lat (pyproj, on coarse nodes) -> DEM height ->
image ``(x, y)`` by the model's vmapped ``project`` (coarse grid plus first-order height
correction, refined in full where the check error exceeds ``tol_px``; :mod:`._mapping`) -> the
image window the tile needs is read and resampled (:mod:`._resample`). Memory is bounded by the
tile size; the output is written to a temporary tiled GeoTIFF and turned into a COG (tiled,
DEFLATE, overviews, CRS) renamed onto the target at the end.
"""

from __future__ import annotations

import dataclasses
import math
import os
import pathlib
import tempfile
import time

import numpy as np

from ..io import DEM, read_dem
from ..models import AbstractSensorModel, DEMGrid, DEMStatus
from ._grid import (
    OutputGrid,
    default_crs,
    dem_for_image,
    footprint,
    ground_sample_distance,
    localize_on_dem_padded,
)
from ._grid import output_grid as make_output_grid
from ._mapping import map_tile, refine
from ._occlusion import occluded_pixels
from ._resample import RESAMPLINGS, sample_window

OCCLUSIONS = ("off", "nodata", "band")


@dataclasses.dataclass(frozen=True)
class OrthoReport:
    """What :func:`orthorectify` made: the file, its grid and the quality of the mapping.

    ``grid_error_px``: largest difference (image px) between the coarse-grid mapping and the
    full projection at the block-centre check points left interpolated (refined blocks are
    exact); ``refined_fraction``: share of blocks projected in full; ``valid_fraction``: share
    of output pixels with data; ``occluded_fraction``: share of pixels hidden from the sensor
    (``None`` when occlusion was off).
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


def _check_out(out: pathlib.Path, overwrite: bool):
    if out.exists() and not overwrite:
        raise FileExistsError(f"{out}: refusing to overwrite an existing file (pass overwrite)")
    if not out.parent.exists():
        raise FileNotFoundError(f"{out.parent}: output directory does not exist")


def _tile_shape(grid: OutputGrid, tile_px: int, step: int) -> tuple[int, int]:
    th = min(tile_px, grid.height)
    tw = min(tile_px, grid.width)
    return int(math.ceil(th / step) * step), int(math.ceil(tw / step) * step)


def _nodes_lonlat(grid: OutputGrid, to_ll, r0: int, c0: int, th: int, tw: int, step: int):
    rr = r0 + np.arange(0, th + 1, step)
    cc = c0 + np.arange(0, tw + 1, step)
    x = grid.west + (cc + 0.5) * grid.res_m
    y = grid.north - (rr + 0.5) * grid.res_m
    xx, yy = np.meshgrid(x, y)
    lon, lat = to_ll.transform(xx, yy)
    return np.stack([lon, lat], axis=-1)


def _occlusion(model, dem_grid: DEMGrid, xy, lonlat, h, every: int, thresh_m: float):
    """Occluded pixels of a tile: a pixel is hidden if its line of sight meets the DEM first
    (every pixel, by the ground-space march of :mod:`._occlusion`; ``every`` is unused)."""
    return occluded_pixels(model, dem_grid, xy, lonlat, h, thresh_m)


def _occlusion_march(model, dem_grid: DEMGrid, xy, lonlat, h, every: int, thresh_m: float):
    """The former per-step march with :func:`~jaxgeo.models.localize_on_dem` on every
    ``every``-th pixel, spread to its block (exact but minutes on a 1 m DEM; kept to compare).
    """
    sub_xy = xy[::every, ::every]
    sub_ll = lonlat[::every, ::every]
    sub_h = h[::every, ::every]
    ok = np.all(np.isfinite(sub_xy), axis=-1) & np.isfinite(sub_h)
    occluded = np.zeros(sub_xy.shape[:2], dtype=bool)
    if ok.any():
        g, st = localize_on_dem_padded(model, sub_xy[ok], dem_grid)
        ll = sub_ll[ok]
        dlat = (g[:, 1] - ll[:, 1]) * 111_320.0
        dlon = (g[:, 0] - ll[:, 0]) * 111_320.0 * np.cos(np.radians(ll[:, 1]))
        dist = np.hypot(dlat, dlon)
        occluded[ok] = (st == DEMStatus.OK) & (dist > thresh_m)
    full = np.repeat(np.repeat(occluded, every, axis=0), every, axis=1)
    return full[: xy.shape[0], : xy.shape[1]]


def orthorectify(
    image: str | os.PathLike,
    model: AbstractSensorModel,
    dem: DEM | str | os.PathLike,
    out: str | os.PathLike,
    *,
    crs=None,
    res_m: float | None = None,
    bounds: tuple[float, float, float, float] | None = None,
    resampling: str = "bilinear",
    occlusion: str = "off",
    image_origin: tuple[float, float] = (0.0, 0.0),
    nodata: float | None = None,
    tile_px: int = 1024,
    step_px: int = 16,
    tol_px: float = 0.01,
    overwrite: bool = False,
    progress: bool = True,
) -> OrthoReport:
    """Orthorectify ``image`` with ``model`` on ``dem`` into the COG ``out``.

    Args:
        image: any raster rasterio reads; all bands, any dtype.
        model: any sensor model; model image coordinates = file pixel ``(col, row)`` +
            ``image_origin`` (for crops of a larger product); jaxgeo convention (pixel centres
            at integers).
        dem: a :class:`jaxgeo.io.DEM` (heights made ellipsoidal by ``read_dem``) or a path read
            as ellipsoidal.
        crs: output CRS (anything pyproj takes, e.g. ``"EPSG:32631"``); default the local UTM
            zone. res_m: output pixel size in CRS units; default the image's GSD at its centre.
        bounds: ``(W, S, E, N)`` in the output CRS; default the footprint on the DEM.
        resampling: ``nearest``, ``bilinear`` or ``cubic`` (Keys, a = -0.5).
        occlusion: ``off``; ``nodata`` (pixels hidden from the sensor by terrain are nodata);
            ``band`` (an extra last band, 1 = hidden, 0 = seen).
        nodata: output nodata value; default NaN for float images, 0 for integer ones.
        tile_px, step_px, tol_px: tile size, coarse-grid step (px), refinement tolerance (px).
        overwrite: replace an existing ``out`` (never by default).

    Returns an :class:`OrthoReport`. Raises ``ValueError`` when the DEM does not cover the
    footprint (with the covered share), ``FileExistsError`` for an existing ``out``.
    """
    import pyproj
    import rasterio
    import rasterio.shutil
    from rasterio.windows import Window

    t_start = time.perf_counter()
    out = pathlib.Path(out)
    _check_out(out, overwrite)
    if resampling not in RESAMPLINGS:
        raise ValueError(f"unknown resampling {resampling!r}; expected one of {RESAMPLINGS}")
    if occlusion not in OCCLUSIONS:
        raise ValueError(f"unknown occlusion mode {occlusion!r}; expected one of {OCCLUSIONS}")
    if step_px < 2 or step_px % 2:
        raise ValueError(f"step_px must be an even number >= 2, got {step_px}")
    if not isinstance(dem, DEM):
        dem = read_dem(dem, height="ellipsoidal")
    ox, oy = (float(v) for v in image_origin)
    with rasterio.open(image) as src:
        width, height, bands, dtype = src.width, src.height, src.count, src.dtypes[0]
    from ..models import Biased, ShiftBias

    # a crop: the wrapped model speaks file pixels (file = model - origin, eq. 2 with B0 = ox)
    if ox or oy:
        model = Biased(model, ShiftBias(np.array([ox, oy])))
    dem_grid = dem_for_image(model, dem, width, height, source=str(image))
    ground = footprint(model, dem_grid, width, height)
    crs = pyproj.CRS.from_user_input(crs) if crs is not None else default_crs(ground)
    if res_m is None:
        res_m = ground_sample_distance(model, dem_grid, crs, width, height)
    grid = make_output_grid(ground, crs, res_m, bounds)
    to_ll = pyproj.Transformer.from_crs(crs, 4326, always_xy=True)
    is_float = np.issubdtype(np.dtype(dtype), np.floating)
    if nodata is None:
        nodata = float("nan") if is_float else 0
    out_bands = bands + (1 if occlusion == "band" else 0)
    th, tw = _tile_shape(grid, tile_px, step_px)
    # DEM cell size in metres, for the occlusion sampling and threshold
    cell = np.abs(np.asarray(dem_grid.step))
    cell_m = float(cell.min() * (111_320.0 if dem_grid.utm_zone == 0 else 1.0))
    occ_every = max(1, int(0.25 * cell_m / grid.res_m))
    occ_thresh = max(2.0 * grid.res_m, 0.5)

    tiles = [(r, c) for r in range(0, grid.height, th) for c in range(0, grid.width, tw)]
    errors, refined, n_valid, n_occ = [], [], 0, 0
    fd, tmp = tempfile.mkstemp(prefix=f".{out.name}.", suffix=".tmp.tif", dir=out.parent)
    os.close(fd)
    tmp2 = tmp[:-8] + ".cog.tif"
    profile = dict(
        driver="GTiff", width=grid.width, height=grid.height, count=out_bands, dtype=dtype,
        crs=crs.to_wkt(), transform=grid.transform, nodata=nodata, tiled=True,
        # the temporary tiles only need to stay small on disk: fast ZSTD level 1 (the COG
        # copy below compresses once more, with DEFLATE, for every reader)
        blockxsize=256, blockysize=256, compress="zstd", zstd_level=1, BIGTIFF="IF_SAFER",
    )  # fmt: skip
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=len(tiles), desc="ortho", unit="tile")
    try:
        with rasterio.open(image) as src, rasterio.open(tmp, "w", **profile) as dst:
            for r0, c0 in tiles:
                nodes = _nodes_lonlat(grid, to_ll, r0, c0, th, tw, step_px)
                xy, lonlat, h, err = map_tile(model, dem_grid, nodes, step_px, th, tw)
                xy, frac, err_left = refine(model, xy, lonlat, h, err, step_px, tol_px)
                errors.append(err_left)
                refined.append(frac)
                lonlat, h = np.asarray(lonlat), np.asarray(h)
                rows, cols = min(th, grid.height - r0), min(tw, grid.width - c0)
                xy, lonlat, h = xy[:rows, :cols], lonlat[:rows, :cols], h[:rows, :cols]
                fx, fy = xy[..., 0], xy[..., 1]
                good = np.isfinite(fx) & np.isfinite(fy)
                data = np.full((bands, rows, cols), nodata, dtype=float)
                valid = np.zeros((rows, cols), dtype=bool)
                if good.any():
                    pad = 3
                    x0 = max(int(np.floor(fx[good].min())) - pad, 0)
                    y0 = max(int(np.floor(fy[good].min())) - pad, 0)
                    x1 = min(int(np.ceil(fx[good].max())) + pad + 1, width)
                    y1 = min(int(np.ceil(fy[good].max())) + pad + 1, height)
                    if x1 > x0 and y1 > y0:
                        win = src.read(window=Window(x0, y0, x1 - x0, y1 - y0)).astype(float)
                        # a window clipped by the image edge: positions beyond it are invalid
                        vals, ok = sample_window(win, fx - x0, fy - y0, resampling)
                        ok &= (fx >= -0.5) & (fx <= width - 0.5) & (fy >= -0.5)
                        ok &= fy <= height - 0.5
                        valid = ok & good
                        data = np.where(valid[None], vals, nodata)
                occ = None
                if occlusion != "off":
                    occ = _occlusion(model, dem_grid, xy, lonlat, h, occ_every, occ_thresh)
                    occ &= valid
                    n_occ += int(occ.sum())
                    if occlusion == "nodata":
                        data = np.where(occ[None], nodata, data)
                        valid &= ~occ
                n_valid += int(valid.sum())
                if not is_float:
                    info = np.iinfo(np.dtype(dtype))
                    data = np.clip(np.rint(np.nan_to_num(data)), info.min, info.max)
                window = Window(c0, r0, cols, rows)
                dst.write(data.astype(dtype), indexes=list(range(1, bands + 1)), window=window)
                if occlusion == "band":
                    band = np.where(valid, occ.astype(float), nodata).astype(dtype)
                    dst.write(band, out_bands, window=window)
                if bar is not None:
                    bar.update(1)
        rasterio.shutil.copy(
            tmp, tmp2, driver="COG", COMPRESS="DEFLATE", OVERVIEWS="AUTO",
            RESAMPLING="NEAREST" if resampling == "nearest" else "AVERAGE", BIGTIFF="IF_SAFER",
        )  # fmt: skip
        _check_out(out, overwrite)
        os.replace(tmp2, out)
    finally:
        if bar is not None:
            bar.close()
        for p in (tmp, tmp2):
            if os.path.exists(p):
                os.unlink(p)
    total = grid.width * grid.height
    return OrthoReport(
        path=out,
        crs=crs.to_string(),
        res_m=grid.res_m,
        width=grid.width,
        height=grid.height,
        bounds=(
            grid.west,
            grid.north - grid.height * grid.res_m,
            grid.west + grid.width * grid.res_m,
            grid.north,
        ),  # fmt: skip
        grid_error_px=float(max(errors) if errors else 0.0),
        refined_fraction=float(np.mean(refined)) if refined else 0.0,
        valid_fraction=n_valid / total,
        occluded_fraction=(n_occ / total) if occlusion != "off" else None,
        seconds=time.perf_counter() - t_start,
    )
