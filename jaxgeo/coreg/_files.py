"""DEM co-registration of raster files: read, resample the reference onto the DSM grid, run
:func:`nuth_kaab`, write the shifted DSM (same grid as the input, atomically, block by block).

The DSM must be in a projected CRS in metres (shifts and slopes are metric); REF and the
stable-terrain mask may be in any CRS and resolution: REF is warped onto the DSM grid (GDAL,
bilinear), the mask with nearest neighbour. Heights are metres in both, in one vertical datum:
REF's values are used as they are, unless REF is given as a :class:`~jaxgeo.io.DEM`
(:func:`jaxgeo.io.read_dem` with its ``height=`` / ``geoid=``), whose heights are then made
ellipsoidal (geoid undulation and offset added on the DSM grid), like a jaxgeo DSM's; a REF
file used as it is while it declares a vertical CRS gets a :class:`CoregistrationWarning`.
The estimate is made on the DSM grid when it has at most ``NuthKaab.max_cells`` cells, else on
a grid decimated by an integer step (DSM averaged, REF warped onto it); the outputs (the
shifted DSM, the height difference) are always written on the full DSM grid, by bands of rows,
so their memory does not grow with the raster.
"""

from __future__ import annotations

import contextlib
import math
import os
import pathlib
import warnings
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from ..io import DEM
from ..io.internal import atomic_output, open_raster, raster_writer, refuse_existing
from ._nuth_kaab import (
    CoregistrationError,
    CoregistrationWarning,
    NuthKaab,
    nuth_kaab,
    shift_heights,
)
from ._result import Coregistration, HeightDifference
from ._stats import dh_stats

WRITE_ROWS = 256


def _same_file(a: pathlib.Path, b: pathlib.Path) -> bool:
    if a.exists() and b.exists():
        return os.path.samefile(a, b)
    return os.path.realpath(a) == os.path.realpath(b)


def _open(path: pathlib.Path, role: str):
    from rasterio.errors import RasterioIOError

    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file ({role})")
    try:
        return open_raster(path)
    except RasterioIOError as err:
        raise CoregistrationError(f"{path}: cannot read it as a raster ({role}): {err}") from None


def _check_dsm_grid(path: pathlib.Path, ds) -> None:
    """A metric projected CRS and a north-up geotransform without rotation."""
    crs = ds.crs
    if crs is None:
        raise CoregistrationError(f"{path}: the DSM has no CRS (a projected CRS in metres needed)")
    if crs.is_geographic:
        raise CoregistrationError(
            f"{path}: the DSM's CRS ({crs.to_string()}) is geographic (degrees); shifts and "
            "slopes need metres: reproject it to a projected CRS first (e.g. gdalwarp -t_srs "
            "EPSG:326xx -r bilinear, the local UTM zone)"
        )
    unit, factor = crs.linear_units_factor
    if not math.isclose(factor, 1.0):
        raise CoregistrationError(
            f"{path}: the DSM's CRS has {unit} units; co-registration needs a CRS in metres"
        )
    t = ds.transform
    if t.b != 0 or t.d != 0 or t.a == 0 or t.e == 0:
        raise CoregistrationError(
            f"{path}: rotated or sheared geotransform ({tuple(t)[:6]}); expected north-up"
        )


def _read_estimation_grid(ds, max_cells: int):
    """Band 1 as float64 (NaN = no data) on the grid the estimate uses: the DSM grid, or the
    grid decimated by the smallest integer step that leaves ``max_cells`` cells or fewer."""
    from affine import Affine
    from rasterio.enums import Resampling

    step = max(1, math.ceil(math.sqrt(ds.width * ds.height / max_cells)))
    shape = (math.ceil(ds.height / step), math.ceil(ds.width / step))
    z = ds.read(1, out_shape=shape, masked=True, resampling=Resampling.average)
    z = np.ma.filled(z.astype(np.float64), np.nan)
    t = ds.transform  # north-up (checked): the decimated grid keeps the corner
    transform = Affine(t.a * ds.width / shape[1], 0.0, t.c, 0.0, t.e * ds.height / shape[0], t.f)
    return z, transform, step


def _warp_onto(ds, shape, transform, crs, resampling: str, fill: float, dtype) -> np.ndarray:
    """Band 1 of ``ds`` warped onto a grid (its no data and the cells it does not cover:
    ``fill``)."""
    import rasterio
    from rasterio.enums import Resampling
    from rasterio.warp import reproject

    src_nodata = ds.nodata
    if src_nodata is None and np.issubdtype(np.dtype(ds.dtypes[0]), np.floating):
        src_nodata = np.nan
    out = np.full(shape, fill, dtype=dtype)
    reproject(
        source=rasterio.band(ds, 1), destination=out, src_nodata=src_nodata,
        dst_transform=transform, dst_crs=crs, dst_nodata=fill,
        resampling=getattr(Resampling, resampling),
    )  # fmt: skip
    return out


def _to_ellipsoidal(dem: DEM, crs, transform, shape) -> np.ndarray | float:
    """What turns ``dem``'s values into WGS84 ellipsoidal heights at the centres of a grid of
    ``crs``: its geoid undulation ``N`` there (orthometric heights: ``h = H + N``) plus its
    ``offset_m``."""
    if dem.geoid is None:
        return dem.offset_m
    from pyproj import Transformer

    rows, cols = np.indices(shape, dtype=np.float64)
    t = transform
    x = t.c + t.a * (cols + 0.5) + t.b * (rows + 0.5)
    y = t.f + t.d * (cols + 0.5) + t.e * (rows + 0.5)
    to_lonlat = Transformer.from_crs(crs.to_wkt(), "EPSG:4326", always_xy=True)
    lon, lat = to_lonlat.transform(x, y)
    return dem.geoid(np.asarray(lon), np.asarray(lat)) + dem.offset_m


def _warn_vertical_as_read(ref_path, ref) -> None:
    """REF given as a file, its values compared as they are: say so when it declares a vertical
    CRS (an orthometric REF against a jaxgeo DSM, ellipsoidal, would be off by the geoid
    undulation, tens of metres, taken for a vertical bias)."""
    import pyproj

    if ref.crs is None:
        return
    crs = pyproj.CRS.from_wkt(ref.crs.to_wkt())
    vertical = [c.name for c in crs.sub_crs_list if c.is_vertical] if crs.is_compound else []
    if vertical:
        warnings.warn(
            f"{ref_path}: REF declares the vertical CRS {vertical[0]!r}; its heights are compared "
            "with the DSM's as they are (one vertical datum assumed; a jaxgeo DSM is "
            "ellipsoidal): give REF's height reference (read_dem(REF, height=, geoid=)) to make "
            "them ellipsoidal",
            CoregistrationWarning,
            stacklevel=3,
        )


def _check_overlap(dsm_path, ref_path, dsm, ref) -> None:
    from rasterio.warp import transform_bounds

    if ref.crs is None:
        raise CoregistrationError(f"{ref_path}: the reference has no CRS")
    try:
        w, s, e, n = transform_bounds(ref.crs, dsm.crs, *ref.bounds, densify_pts=21)
    except Exception as err:  # noqa: BLE001 - PROJ errors have no common base
        raise CoregistrationError(
            f"{ref_path}: its bounds cannot be transformed into the DSM's CRS ({err})"
        ) from None
    b = dsm.bounds
    if not (w < b.right and e > b.left and s < b.top and n > b.bottom):
        raise CoregistrationError(
            f"{dsm_path} and {ref_path} do not overlap (DSM bounds {tuple(round(v, 3) for v in b)}"
            f", REF bounds in the DSM's CRS {tuple(round(v, 3) for v in (w, s, e, n))})"
        )


def _ref_cell_m(ref, dsm_crs, centre) -> tuple[float, float]:
    """The lengths (m, in the DSM's CRS) of one column step and one row step of REF's grid at
    the map point ``centre`` of the DSM's CRS."""
    from pyproj import Transformer

    to_ref = Transformer.from_crs(dsm_crs.to_wkt(), ref.crs.to_wkt(), always_xy=True)
    to_dsm = Transformer.from_crs(ref.crs.to_wkt(), dsm_crs.to_wkt(), always_xy=True)
    x, y = to_ref.transform(*centre)
    t = ref.transform
    xs, ys = to_dsm.transform([x, x + t.a, x + t.b], [y, y + t.d, y + t.e])
    return (math.hypot(xs[1] - xs[0], ys[1] - ys[0]), math.hypot(xs[2] - xs[0], ys[2] - ys[0]))


def _check_determinacy(paths, dsm, ref, z, zref, transform, stable, settings) -> None:
    """Refuse a horizontal fit the reference cannot determine: the heights both rasters share
    (stable ones) must span ``settings.min_ref_cells`` of REF's cells (or of the estimate grid's,
    where REF is finer) in each direction. Between its posts REF is a bilinear surface: a DSM
    over a few of its cells sees a few patches of one slope, whose aspects leave the shift free
    (the iterations swing by tens of metres and stop anywhere)."""
    both = np.isfinite(z) & np.isfinite(zref) & (True if stable is None else stable)
    if settings.vertical_only or int(both.sum()) < settings.min_cells:
        return  # nothing to determine; too few cells: nuth_kaab says so, more directly
    rows, cols = (np.flatnonzero(np.any(both, axis=k)) for k in (1, 0))
    t = transform
    span = ((cols[-1] - cols[0] + 1) * abs(t.a), (rows[-1] - rows[0] + 1) * abs(t.e))
    centre = (t.c + t.a * (cols[0] + cols[-1] + 1) / 2.0,
              t.f + t.e * (rows[0] + rows[-1] + 1) / 2.0)  # fmt: skip
    ref_cell = _ref_cell_m(ref, dsm.crs, centre)
    posts = [s / max(c, abs(g)) for s, c, g in zip(span, ref_cell, (t.a, t.e), strict=True)]
    if min(posts) >= settings.min_ref_cells:
        return
    dsm_path, ref_path = paths
    raise CoregistrationError(
        f"{dsm_path} ({abs(dsm.transform.a):g} x {abs(dsm.transform.e):g} m cells; heights over "
        f"{span[0]:.0f} m east-west x {span[1]:.0f} m north-south shared with the reference) "
        f"spans only {posts[0]:.1f} x {posts[1]:.1f} cells of {ref_path} ({ref_cell[0]:.1f} x "
        f"{ref_cell[1]:.1f} m cells); a horizontal shift needs >= {settings.min_ref_cells:g} "
        "in each direction (fewer: a few bilinear patches of REF, whose slopes and aspects do "
        "not determine it): use a larger DSM, a finer reference, or vertical_only (the "
        "vertical offset alone)",
        settings=("min_ref_cells", "vertical_only"),
    )


def _stable_mask(mask_path, dsm, shape, transform) -> np.ndarray:
    """Stable cells from a mask raster (non-zero = stable; no data and outside = not stable)."""
    with _open(mask_path, "stable-terrain mask") as m:
        if m.crs is None:
            if (m.height, m.width) != (dsm.height, dsm.width):
                raise CoregistrationError(
                    f"{mask_path}: the mask has no CRS and a shape {(m.height, m.width)} other "
                    f"than the DSM's {(dsm.height, dsm.width)}"
                )
            from rasterio.enums import Resampling

            read = m.read(1, out_shape=shape, masked=True, resampling=Resampling.nearest)
            values = np.ma.filled(read.astype(np.float64), np.nan)
        else:
            # no data and outside: NaN, not 0. A GDAL that warps onto a destination no-data
            # value moves valid source values equal to it off it (rasterio 1.5.2's GDAL: every
            # 0 of the mask became 1e-45, non-zero, and the whole DSM counted as stable)
            values = _warp_onto(m, shape, transform, dsm.crs, "nearest", np.nan, np.float32)
    stable = np.isfinite(values) & (values != 0)
    distinct = np.unique(values[np.isfinite(values)])
    if distinct.size > 2:  # a DEM or an image given as the mask: every cell would count
        warnings.warn(
            f"{mask_path}: the stable-terrain mask has {distinct.size} distinct values "
            f"({distinct[0]:g} to {distinct[-1]:g}), not a mask's 0 / non-zero: every non-zero "
            f"cell counts as stable ({stable.mean():.0%} of the DSM's cells)",
            CoregistrationWarning,
            stacklevel=2,
        )
    return stable


def _read_rows(ds, start: int, stop: int, nodata) -> np.ndarray:
    """Rows ``start:stop`` of band 1 (float64, NaN = no data), NaN rows beyond the raster."""
    from rasterio.windows import Window

    out = np.full((stop - start, ds.width), np.nan)
    r0, r1 = max(start, 0), min(stop, ds.height)
    if r0 < r1:
        z = ds.read(1, window=Window(0, r0, ds.width, r1 - r0), masked=True)
        out[r0 - start : r1 - start] = np.ma.filled(z.astype(np.float64), np.nan)
    return out


def _profile(ds, nodata: float) -> dict:
    return dict(
        driver="GTiff", width=ds.width, height=ds.height, count=1, dtype="float32",
        crs=ds.crs, transform=ds.transform, nodata=nodata, tiled=True, blockxsize=256,
        blockysize=256, compress="deflate", predictor=3, BIGTIFF="IF_SAFER",
    )  # fmt: skip


def _ref_rows(ref, ref_dem, ds, start: int, stop: int) -> np.ndarray:
    """REF on rows ``start:stop`` of the DSM grid (bilinear, NaN = no data), its heights made
    ellipsoidal when it is a DEM: the values the estimate compares with, cell for cell."""
    from affine import Affine

    g = ds.transform  # north-up (checked): the band's grid starts ``start`` rows down
    t = Affine(g.a, 0.0, g.c, 0.0, g.e, g.f + g.e * start)
    shape = (stop - start, ds.width)
    z = _warp_onto(ref, shape, t, ds.crs, "bilinear", np.nan, np.float64)
    if ref_dem is not None:
        z += _to_ellipsoidal(ref_dem, ds.crs, t, shape)
    return z


def _write_outputs(dsm_path, ds, ref, ref_dem, result, targets, overwrite, ref_name):
    """The DSM moved by ``result.shift_m`` on its own grid (``targets[0]``) and its difference
    with REF (``targets[1]``), float32, written band of rows by band of rows; returns the
    :class:`HeightDifference` (``None`` without ``targets[1]``)."""
    import rasterio

    out, diff = targets
    t = ds.transform
    step_m = (t.a, t.e)
    margin = int(abs(math.floor(-result.shift_m[1] / t.e))) + 2
    nodata = ds.nodata
    fill = np.nan if nodata is None or not np.isfinite(nodata) else float(nodata)
    dx, dy, dz = result.shift_m
    tags = dict(
        COREGISTRATION_SHIFT_M=f"{dx:.4f} {dy:.4f} {dz:.4f}",
        COREGISTRATION_METHOD="Nuth and Kaab (2011), jaxgeo",
        COREGISTRATION_REFERENCE=ref_name,
        COREGISTRATION_SOURCE=pathlib.Path(dsm_path).name,
    )  # fmt: skip
    if result.tilt_origin_m is not None:
        tags["COREGISTRATION_TILT_M_PER_M"] = "{:.7f} {:.7f}".format(*result.tilt_m_per_m)
        tags["COREGISTRATION_TILT_ORIGIN_M"] = "{:.3f} {:.3f}".format(*result.tilt_origin_m)
    step = result.grid_step  # statistics of the difference on the estimate's sampling
    samples: dict[str, list[np.ndarray]] = {"before": [], "after": []}
    with contextlib.ExitStack() as stack:
        sinks = []
        for path, nd in ((out, fill), (diff, np.nan)):
            if path is None:
                sinks.append(None)
                continue
            sink = atomic_output(path, overwrite=overwrite, suffix=".tif", leftovers=(".aux.xml",))
            sinks.append(stack.enter_context(raster_writer(stack.enter_context(sink),
                                                           _profile(ds, nd))))  # fmt: skip
        aligned_dst, diff_dst = sinks
        for start in range(0, ds.height, WRITE_ROWS):
            stop = min(start + WRITE_ROWS, ds.height)
            window = rasterio.windows.Window(0, start, ds.width, stop - start)
            block = _read_rows(ds, start - margin, stop + margin, nodata)
            z = shift_heights(block, result.shift_m, step_m)[margin : margin + stop - start]
            if result.tilt_origin_m is not None:  # the plane, zero at the estimate's centre
                x0, y0 = result.tilt_origin_m
                east = t.c + t.a * (np.arange(ds.width) + 0.5) - x0
                north = t.f + t.e * (np.arange(start, stop) + 0.5) - y0
                gx, gy = result.tilt_m_per_m
                z = z + gx * east[None, :] + gy * north[:, None]
            if aligned_dst is not None:
                aligned_dst.write(np.where(np.isfinite(z), z, fill).astype(np.float32), 1,
                                  window=window)  # fmt: skip
            if diff_dst is not None:
                zref = _ref_rows(ref, ref_dem, ds, start, stop)
                dh = (z - zref).astype(np.float32)  # NaN where either has no height
                diff_dst.write(dh, 1, window=window)
                keep = (np.arange(start, stop) % step == 0, slice(None, None, step))
                unmoved = block[margin : margin + stop - start] - zref
                samples["before"].append(unmoved[keep[0]][:, keep[1]].ravel())
                samples["after"].append(dh.astype(np.float64)[keep[0]][:, keep[1]].ravel())
        if aligned_dst is not None:
            aligned_dst.set_band_description(1, f"height (m), co-registered onto {ref_name}")
            aligned_dst.update_tags(**tags)
        if diff_dst is None:
            return None
        before, after = (np.concatenate(samples[k]) for k in ("before", "after"))
        if not result.converged:  # the same cells before and after (see Coregistration)
            common = np.isfinite(before) & np.isfinite(after)
            before, after = before[common], after[common]
        before, after = dh_stats(before), dh_stats(after)
        diff_dst.set_band_description(
            1, f"height difference (m): DSM co-registered onto {ref_name} minus it"
        )
        stats = {f"DH_{k.upper()}_{name.upper()}": f"{v:.4f}" if isinstance(v, float) else str(v)
                 for k, st in (("before", before), ("after", after))
                 for name, v in st.as_dict().items()}  # fmt: skip
        diff_dst.update_tags(
            DH_DEFINITION="DSM shifted by COREGISTRATION_SHIFT_M minus REF resampled onto the "
            "DSM's grid (bilinear), metres; NaN where either has no height",
            DH_STATISTICS_GRID_STEP=str(step),
            **tags,
            **stats,
        )
    return HeightDifference(str(diff), before, after, step)


def coregister(
    dsm: str | os.PathLike,
    ref: str | os.PathLike | DEM,
    out: str | os.PathLike | None = None,
    *,
    diff: str | os.PathLike | None = None,
    mask: str | os.PathLike | None = None,
    settings: NuthKaab | None = None,
    overwrite: bool = False,
    callback: Callable[..., object] | None = None,
) -> Coregistration:
    """Co-register the DSM file ``dsm`` onto the reference DEM ``ref`` (Nuth and Kääb).

    ``ref``: a raster file, whose values are compared with the DSM's as they are (one vertical
    datum in both), or a :class:`~jaxgeo.io.DEM` (``read_dem(path, height=, geoid=)``), whose
    heights are made ellipsoidal first, like a jaxgeo DSM's (e.g. an orthometric reference:
    ``read_dem("srtm.tif", geoid="egm96")``). ``mask``: a raster of stable terrain (non-zero =
    stable, any CRS); ``settings``: the method's (default ``NuthKaab()``). ``out``: where the
    shifted DSM goes (GeoTIFF, float32, same grid as ``dsm``). ``diff``: where the height
    difference after the alignment goes, ``DSM shifted - REF`` (m; GeoTIFF, float32, on the
    DSM's grid with REF resampled bilinearly onto it, NaN where either has no height; its
    statistics before and after the alignment in ``result.diff`` and in the file's tags
    ``DH_BEFORE_*``, ``DH_AFTER_*``). Both outputs are written atomically, an existing file only
    with ``overwrite``, never one of the inputs. Returns :class:`Coregistration` (``shift_m``
    is what was added to the DSM). Bad input raises :class:`CoregistrationError` (a
    ``ValueError``) naming the file.
    """
    settings = NuthKaab() if settings is None else settings
    ref_dem = ref if isinstance(ref, DEM) else None
    dsm_path = pathlib.Path(dsm)
    ref_path = pathlib.Path(ref_dem.path if ref_dem is not None else ref)
    mask_path = None if mask is None else pathlib.Path(mask)
    targets = tuple(None if t is None else pathlib.Path(t) for t in (out, diff))
    if all(t is not None for t in targets) and _same_file(*targets):
        raise CoregistrationError(f"{targets[0]}: given for both the aligned DSM and the "
                                  "difference")  # fmt: skip
    for target in targets:
        if target is None:
            continue
        for name, given in (("DSM", dsm_path), ("REF", ref_path), ("mask", mask_path)):
            if given is not None and _same_file(target, given):
                raise CoregistrationError(f"{target}: is the input {name}; write elsewhere")
        refuse_existing(target, overwrite)
    with _open(dsm_path, "DSM") as d, _open(ref_path, "reference DEM") as r:
        _check_dsm_grid(dsm_path, d)
        _check_overlap(dsm_path, ref_path, d, r)
        if ref_dem is None:
            _warn_vertical_as_read(ref_path, r)
        z, transform, step = _read_estimation_grid(d, settings.max_cells)
        zref = _warp_onto(r, z.shape, transform, d.crs, "bilinear", np.nan, np.float64)
        if ref_dem is not None:
            zref += _to_ellipsoidal(ref_dem, d.crs, transform, z.shape)
        stable = None if mask_path is None else _stable_mask(mask_path, d, z.shape, transform)
        if not np.any(np.isfinite(z) & np.isfinite(zref)):
            raise CoregistrationError(
                f"{dsm_path} and {ref_path}: no cell has heights in both (their data do not "
                "overlap)"
            )
        _check_determinacy((dsm_path, ref_path), d, r, z, zref, transform, stable, settings)
        try:
            result = nuth_kaab(z, zref, (transform.a, transform.e), stable, settings, callback)
        except CoregistrationError as err:
            raise CoregistrationError(f"{dsm_path} vs {ref_path}: {err}", err.settings) from None
        rows, cols = z.shape  # the plane of tilt=True is zero at the estimate grid's centre
        centre = (transform.c + transform.a * cols / 2.0, transform.f + transform.e * rows / 2.0)
        result = replace(result, grid_step=step, tilt_origin_m=centre if settings.tilt else None)
        if any(t is not None for t in targets):
            written = _write_outputs(dsm_path, d, r, ref_dem, result, targets, overwrite,
                                     ref_path.name)  # fmt: skip
            result = replace(result, output=None if out is None else str(targets[0]),
                             diff=written)  # fmt: skip
    return result
