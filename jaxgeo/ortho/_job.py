"""One tile of an orthoimage: the pure per-tile function the tile runner maps over the plan.

:class:`OrthoJob` holds everything a tile needs (image path, model, how to open the DEM, the
output grid, options, the padded shapes of the per-tile arrays) and is small enough to send with
every task. A tile reads only what it needs: the DEM window under its ground box (plus the margin
a line of sight travels, with occlusion on) and the image window its pixels fall in, both padded
to fixed shapes so that every tile runs the same compiled programs. Per tile: node lon/lat
(pyproj) -> DEM window -> node projections -> image window -> :func:`._kernel.map_pixels` ->
:func:`._kernel.sample_window` -> a GeoTIFF of the tile's window. Blocks whose check error
exceeds ``tol_px`` fall back to the exact path of :mod:`._mapping` (projected pixel by pixel).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import warnings

import numpy as np

from ..io.internal import open_raster
from ..models import AbstractSensorModel, DEMGrid
from ..tiles import RasterSpec, Tile
from ..tiles.internal import NoData, write_tile
from ._kernel import map_pixels, sample_window
from ._mapping import map_tile, refine
from ._occlusion import occluded_pixels


@dataclasses.dataclass(frozen=True)
class DEMSource:
    """How to open the DEM on a worker: :func:`jaxgeo.io.read_dem` arguments (a geoid by its
    name, found again where the worker runs, or its file; the fill DEM as its own source)."""

    path: str
    offset_m: float = 0.0
    height: str = "ellipsoidal"
    geoid: str | None = None
    band: int = 1
    fill: DEMSource | None = None

    @classmethod
    def of(cls, dem) -> DEMSource:
        geoid = getattr(dem, "geoid", None)
        fill = getattr(dem, "fill", None)
        return cls(str(dem.path), float(dem.offset_m), str(dem.height_reference),
                   None if geoid is None else getattr(geoid, "name", None) or str(geoid.source),
                   int(getattr(dem, "band", 1)),
                   None if fill is None else cls.of(fill))  # fmt: skip


@functools.lru_cache(maxsize=4)
def _open_dem(source: DEMSource):
    from ..io import read_dem

    fill = None if source.fill is None else _open_dem(source.fill)
    with warnings.catch_warnings():  # warned once, in the process that planned the job
        warnings.simplefilter("ignore")
        return read_dem(source.path, source.offset_m, height=source.height, geoid=source.geoid,
                        band=source.band, fill=fill)  # fmt: skip


@functools.lru_cache(maxsize=4)
def _to_lonlat(crs_wkt: str):
    import pyproj

    return pyproj.Transformer.from_crs(pyproj.CRS.from_wkt(crs_wkt), 4326, always_xy=True)


def _bucket(n: int, multiple: int) -> int:
    return int(math.ceil(max(n, 1) / multiple) * multiple)


def pad_dem(grid: DEMGrid, shape: tuple[int, int]) -> DEMGrid:
    """``grid`` padded at its bottom and right to ``shape`` (at least): one edge row/column
    repeated (bilinear heights in its outer half cell unchanged), NaN beyond."""
    z = np.asarray(grid.heights_m)
    rows, cols = max(shape[0], z.shape[0]), max(shape[1], z.shape[1])
    if (rows, cols) == z.shape:
        return grid
    out = np.full((rows + 1, cols + 1), np.nan)
    out[: z.shape[0], : z.shape[1]] = z
    out[z.shape[0], : z.shape[1]] = z[-1]
    out[: z.shape[0] + 1, z.shape[1]] = out[: z.shape[0] + 1, z.shape[1] - 1]
    return DEMGrid(out[:rows, :cols], grid.origin, grid.step, utm_zone=grid.utm_zone)


@dataclasses.dataclass(frozen=True)
class OrthoJob:
    """The per-tile work of one orthoimage (called as ``job(tile, path)`` by the tile runner).

    ``image``: raster path, ``image_size`` ``(width, height)``; ``model`` in the raster's pixel
    frame; ``dem``: a :class:`DEMSource`; ``spec``: the product (bands, dtype, nodata, CRS,
    transform); ``tile_shape`` ``(rows, cols)`` every tile is computed at (multiples of
    ``step_px``), ``window_shape`` and ``dem_shape`` the padded image and DEM windows;
    ``dem_margin_deg`` added around a tile's ground box; ``occlusion`` with ``occ_thresh_m``.
    """

    image: str
    image_size: tuple[int, int]
    model: AbstractSensorModel
    dem: DEMSource
    spec: RasterSpec
    tile_shape: tuple[int, int]
    window_shape: tuple[int, int]
    dem_shape: tuple[int, int]
    dem_margin_deg: float
    resampling: str = "bilinear"
    occlusion: str = "off"
    occ_thresh_m: float = 1.0
    step_px: int = 16
    tol_px: float = 0.01

    # --- the steps of a tile -------------------------------------------------------------
    def nodes(self, tile: Tile) -> np.ndarray:
        """``(nr, nc, 2)`` lon/lat of the tile's nodes (every ``step_px`` px of the product)."""
        a, _, c, _, e, f = self.spec.transform
        th, tw = self.tile_shape
        rr = tile.row + np.arange(0, th + 1, self.step_px)
        cc = tile.col + np.arange(0, tw + 1, self.step_px)
        x = c + (cc + 0.5) * a
        y = f + (rr + 0.5) * e
        xx, yy = np.meshgrid(x, y)
        lon, lat = _to_lonlat(self.spec.crs).transform(xx, yy)
        return np.stack([lon, lat], axis=-1)

    def dem_window(self, nodes: np.ndarray) -> DEMGrid:
        """The DEM under the nodes' box plus the margin, padded to ``dem_shape``."""
        from ..io.internal import dem_coverage

        dem = _open_dem(self.dem)
        ok = np.all(np.isfinite(nodes), axis=-1)
        if not ok.any():
            raise NoData("the tile's ground points cannot be placed on WGS84")
        lo, hi = nodes[ok].min(0), nodes[ok].max(0)
        m = self.dem_margin_deg
        b = dem.bounds_lonlat
        box = (max(lo[0] - m, b[0]), max(lo[1] - m, b[1]), min(hi[0] + m, b[2]),
               min(hi[1] + m, b[3]))  # fmt: skip
        if not (box[2] > box[0] and box[3] > box[1]) or dem_coverage(dem, box) <= 0:
            raise NoData("the DEM does not reach this tile")
        try:
            grid = dem.grid(box)
        except ValueError as err:
            if "only nodata" in str(err):
                raise NoData("the DEM holds only nodata under this tile") from None
            raise
        rows, cols = grid.heights_m.shape
        shape = self.dem_shape
        if rows > shape[0] or cols > shape[1]:  # larger than planned: a larger padded shape
            shape = (_bucket(rows, 32), _bucket(cols, 32))
        return pad_dem(grid, shape)

    def image_window(self, ref, lo, hi):
        """``(col0, row0, cols, rows)`` of the image under positions ``ref + [lo, hi]`` plus
        the resampling's taps (``None``: none of the image)."""
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
            return None
        c0, r0 = (int(v) for v in ref + np.floor(lo) - 3)
        c1, r1 = (int(v) for v in ref + np.ceil(hi) + 4)
        w, h = self.image_size
        c0, r0, c1, r1 = max(c0, 0), max(r0, 0), min(c1, w), min(r1, h)
        if c1 <= c0 or r1 <= r0:
            return None
        return c0, r0, c1 - c0, r1 - r0

    def read_window(self, win) -> np.ndarray:
        """The image window ``(col0, row0, cols, rows)``, zero-padded to ``window_shape``."""
        from rasterio.windows import Window

        c0, r0, cols, rows = win
        wh, ww = self.window_shape
        wh, ww = max(wh, _bucket(rows, 256)), max(ww, _bucket(cols, 256))
        with open_raster(self.image) as src:  # a raster in its own pixel frame
            data = src.read(window=Window(c0, r0, cols, rows))
        out = np.zeros((data.shape[0], wh, ww), dtype=data.dtype)
        out[:, :rows, :cols] = data
        return out

    # --- the tile ----------------------------------------------------------------------
    def __call__(self, tile: Tile, path) -> dict | None:
        import jax.numpy as jnp

        nodes = self.nodes(tile)
        dem = self.dem_window(nodes)
        dtype = "float64" if np.dtype(self.spec.dtype) == np.float64 else "float32"
        xy, ref, lo, hi, err = map_pixels(self.model, dem, nodes, self.step_px, dtype)
        ref, err = np.asarray(ref), np.asarray(err)
        win = self.image_window(ref, np.asarray(lo), np.asarray(hi))
        if win is None:
            raise NoData("the tile sees no pixel of the image")
        refined, error_left = 0, float(np.nanmax(err, initial=0.0))
        xy_abs = lonlat = h = None
        if self.occlusion != "off" or error_left > self.tol_px:
            th, tw = self.tile_shape
            xy_abs, lonlat, h, err_full = map_tile(self.model, dem, nodes, self.step_px, th, tw)
            xy_abs, frac, error_left = refine(self.model, xy_abs, lonlat, h, err_full,
                                              self.step_px, self.tol_px)  # fmt: skip
            refined = int(round(frac * err.size))
            rel = xy_abs - ref
            xy = jnp.asarray(np.moveaxis(rel, -1, 0).astype(dtype))
            with np.errstate(invalid="ignore"), warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN: no window
                span = np.nanmin(rel.reshape(-1, 2), 0), np.nanmax(rel.reshape(-1, 2), 0)
            win = self.image_window(ref, *span)  # the refined positions' own window
            if win is None:
                raise NoData("the tile sees no pixel of the image")
        window = self.read_window(win)
        w, hgt = self.image_size
        offset = np.array(win[:2], dtype=float) - ref
        size = np.array([win[2], win[3]])
        image_box = np.array([-0.5 - win[0], -0.5 - win[1], w - 0.5 - win[0],
                              hgt - 0.5 - win[1]])  # fmt: skip
        nodata = self.spec.nodata if self.spec.nodata is not None else 0
        values, valid, missed = sample_window(window, xy, offset, size, image_box, nodata,
                                              self.resampling, self.spec.dtype)  # fmt: skip
        if int(missed):  # every position that falls in the image must fall in the window read
            raise RuntimeError(f"{tile.describe()}: image window {win} too small (a bug)")
        values, valid = np.asarray(values), np.asarray(valid)
        rows, cols = tile.rows, tile.cols
        values, valid = values[:, :rows, :cols], valid[:rows, :cols]
        values = away_from_nodata(values, valid, nodata)
        n_occ = 0
        if self.occlusion != "off":
            occ = occluded_pixels(self.model, dem, xy_abs[:rows, :cols],
                                  np.asarray(lonlat)[:rows, :cols], np.asarray(h)[:rows, :cols],
                                  self.occ_thresh_m)  # fmt: skip
            occ &= valid
            n_occ = int(occ.sum())
            if self.occlusion == "nodata":
                values = np.where(occ[None], np.asarray(nodata, values.dtype), values)
                valid = valid & ~occ
            else:
                band = np.where(valid, occ.astype(values.dtype), np.asarray(nodata, values.dtype))
                values = np.concatenate([values, band[None]])
        n_valid = int(valid.sum())
        if n_valid == 0 and n_occ == 0:
            return None
        write_tile(path, self.spec, tile.row, tile.col, values)
        return {"valid_px": n_valid, "occluded_px": n_occ, "grid_error_px": error_left,
                "refined_blocks": refined, "blocks": int(err.size)}  # fmt: skip


def away_from_nodata(values: np.ndarray, valid: np.ndarray, nodata) -> np.ndarray:
    """An integer product's valid pixels that equal ``nodata`` moved one step away from it (a
    real 0 of a uint16 image becomes 1 where nodata is 0, the vendors' convention): otherwise a
    reader takes them for pixels the model does not see. Float products (NaN nodata) are
    returned as they are. ``values`` ``(bands, rows, cols)``, ``valid`` ``(rows, cols)``."""
    if not np.issubdtype(values.dtype, np.integer) or nodata is None or nodata != nodata:
        return values
    step = 1 if nodata < np.iinfo(values.dtype).max else -1
    clash = valid[None] & (values == nodata)
    if not clash.any():
        return values
    return np.where(clash, np.asarray(nodata + step, values.dtype), values)
