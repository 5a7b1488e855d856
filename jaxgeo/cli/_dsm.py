"""``jaxgeo dsm``: a digital surface model from two or more images and their sensor models.

    jaxgeo dsm IMG1 IMG2 [IMG3 ...] [--model IMG=FILE ...] [--image-origin IMG=COL,ROW ...]
               [--roi X Y W H] [--res M] [--crs EPSG:n] [--triangulation {intersect,los_midpoint}]
               [--no-register] [--band-rows N] [--orientation adjusted_models.json]
               [--keep DIR] [--quiet] [--json] -o dsm.tif [--overwrite]

IMG1 is the reference: each pair (IMG1, IMGi) is rectified, matched densely (SGM) and
triangulated; the points are pooled into one height per cell (median; bands: height above the
WGS84 ellipsoid, count, spread, filled, height_sigma). ``height_sigma`` is the height's
standard deviation per cell (m): the matching's (from each disparity's correlation peak) and,
with ``--orientation DIR/adjusted_models.json`` (written by ``jaxgeo adjust --out DIR``, whose
adjusted RPCs are the images' models), the adjusted models' posterior uncertainty, propagated
through the intersection; without it the models' orientation error is not in the sigma (vendor
RPCs carry a few pixels of bias that no sigma here describes). ``--roi`` in pixels of IMG1
(default: all of it); ``--res`` metres (default 0.5); CRS default the local UTM zone (a
projected CRS in metres; a geographic CRS is refused). ``--keep DIR`` writes each pair's
intermediate products. Dense matching runs over bands of ``--band-rows`` epipolar rows (default
512), so its memory follows the band, not the image.
Everything given is checked before any computation: the images and
their models, the ROI, the CRS, the output (never an input) and the DSM's size.
"""

from __future__ import annotations

import argparse
import math
import time

from ._common import (
    add_command,
    add_dem_options,
    add_heights,
    add_image_options,
    add_json,
    add_out,
    add_quiet,
    add_tile_options,
    check_dem_options,
    check_roi,
    check_tile_options,
    dem_inputs,
    guard_outputs,
    open_dem,
    open_images,
    print_json,
)

MAX_CELLS = 400_000_000
"""Largest DSM (cells) made without ``--max-cells``: 20 000 x 20 000."""


def register(sub) -> None:
    parser = add_command(sub, "dsm", "digital surface model from a stereo pair or triplet", __doc__)
    parser.add_argument("images", nargs="+", metavar="IMG", help="images, the reference first")
    add_image_options(parser)
    parser.add_argument(
        "--roi",
        type=int,
        nargs=4,
        metavar=("X", "Y", "W", "H"),
        help="region of the reference image, pixels (default: the whole image)",
    )
    parser.add_argument("--res", type=float, default=0.5, help="cell size, m (default 0.5)")
    parser.add_argument(
        "--crs", help="output CRS, a projected CRS in metres, e.g. EPSG:32631 (default: local UTM)"
    )
    parser.add_argument(
        "--triangulation",
        choices=("intersect", "los_midpoint"),
        default="intersect",
        help="least-squares intersection (default) or the midpoint of the two lines of sight",
    )
    parser.add_argument(
        "--no-register",
        action="store_true",
        help="with 3+ images, keep each pair's height offset (default: removed; see the docs)",
    )
    parser.add_argument(
        "--band-rows",
        type=int,
        default=512,
        metavar="N",
        help="epipolar rows per band of dense matching (default 512; memory follows it)",
    )
    parser.add_argument(
        "--orientation",
        metavar="JSON",
        help="adjusted_models.json of `jaxgeo adjust --out` for these images: their posterior "
        "bias sigmas enter the height_sigma band (default: matching only)",
    )
    add_dem_options(parser, "its heights over the footprint, +-50 m, give the tie points' range")
    add_heights(parser)
    parser.add_argument(
        "--max-hole",
        type=float,
        default=4.0,
        metavar="M",
        help="interpolate holes up to M metres across (flagged in the 'filled' band; default 4, "
        "0: none)",
    )
    parser.add_argument("--keep", metavar="DIR", help="write intermediate products to this folder")
    parser.add_argument(
        "--max-cells",
        type=float,
        default=MAX_CELLS,
        metavar="N",
        help=f"refuse a DSM larger than N cells (default {MAX_CELLS:.0e})",
    )
    add_tile_options(parser, 1024, "DSM cells (a scene larger than 2048 px is made tile by tile)")
    add_quiet(parser)
    add_json(parser)
    add_out(parser, "DSM.tif", "the DSM GeoTIFF to write")
    parser.set_defaults(func=run)


def output_epsg(crs: str | None) -> int | None:
    """The EPSG code of ``--crs`` (``None``: local UTM), refused unless projected in metres."""
    from . import CommandError

    if crs is None:
        return None
    import pyproj

    try:
        parsed = pyproj.CRS.from_user_input(crs)
    except pyproj.exceptions.CRSError:
        raise CommandError(
            f"--crs {crs!r}: not a CRS PROJ knows (expected e.g. EPSG:32631)"
        ) from None
    if not parsed.is_projected:
        raise CommandError(
            f"--crs {crs!r}: {parsed.name} is not a projected CRS; a DSM's cells are in metres "
            "(--res is metres): use a projected CRS such as the local UTM zone (the default)"
        )
    unit = parsed.axis_info[0].unit_name if parsed.axis_info else "metre"
    if unit not in ("metre", "meter"):
        raise CommandError(f"--crs {crs!r}: its unit is {unit}, expected metres")
    code = parsed.to_epsg()
    if code is None:
        raise CommandError(f"--crs {crs!r}: give the CRS by its EPSG code")
    return int(code)


def footprint_cells(image, roi, res_m: float, epsg: int | None) -> tuple[float, float]:
    """Approximate DSM size (rows, cols) of ``roi`` of ``image`` at ``res_m``: its corners
    localised at the model's reference height, in the output CRS."""
    import numpy as np
    import pyproj

    from ..geodesy import utm_epsg, utm_zone

    x, y, w, h = roi if roi is not None else (0, 0, *image.size)
    corners = np.array([[x, y], [x + w, y], [x, y + h], [x + w, y + h]], dtype=float) - 0.5
    height = float(np.asarray(image.model.reference_ground())[2])
    ground = np.asarray(image.model.localize(corners, np.full(4, height)))
    if not np.all(np.isfinite(ground)):
        return (math.nan, math.nan)
    lon, lat = float(ground[:, 0].mean()), float(ground[:, 1].mean())
    epsg = epsg or utm_epsg(utm_zone(lon, lat), north=lat >= 0)
    tr = pyproj.Transformer.from_crs(4326, epsg, always_xy=True)
    mx, my = tr.transform(ground[:, 0], ground[:, 1])
    return ((np.ptp(my) / res_m), (np.ptp(mx) / res_m))


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from ..stereo import dsm_from_images, write_dsm
    from . import CommandError

    if len(args.images) < 2:
        raise CommandError("give at least two images (the reference first)")
    if args.band_rows < 1:
        raise CommandError(f"--band-rows {args.band_rows}: expected a positive number of rows")
    if not (math.isfinite(args.res) and args.res > 0):
        raise CommandError(f"--res {args.res:g}: expected a positive cell size in metres")
    if not (math.isfinite(args.max_hole) and args.max_hole >= 0):
        raise CommandError(f"--max-hole {args.max_hole:g}: expected metres >= 0")
    check_dem_options(args)
    epsg = output_epsg(args.crs)
    images = open_images(args.images, args)
    inputs = [p for im in images for p in im.inputs] + dem_inputs(args)
    orientation = None
    if args.orientation is not None:
        from ..stereo import OrientationError, orientation_covariances

        inputs.append(args.orientation)
        try:
            orientation = orientation_covariances(args.orientation, [im.name for im in images])
        except OrientationError as err:
            raise CommandError(str(err)) from None
    check_tile_options(args, inputs, 64)
    if args.keep is not None:
        guard_outputs([], inputs, True)  # the folder is created; its files are new names
    roi = check_roi(args.roi, images[0]) if args.roi is not None else None
    rows, cols = footprint_cells(images[0], roi, args.res, epsg)
    if math.isfinite(rows) and rows * cols > args.max_cells:
        raise CommandError(
            f"the DSM would have about {rows:.0f} x {cols:.0f} cells at --res {args.res:g} m "
            f"(more than --max-cells {args.max_cells:.0e}); raise --res or --max-cells"
        )
    if math.isfinite(rows) and rows * cols < 4:
        raise CommandError(
            f"the DSM would have about {rows:.1f} x {cols:.1f} cells at --res {args.res:g} m: "
            "lower --res"
        )
    if _tiled(args, images[0], roi):
        return _run_tiled(args, images, roi, epsg, orientation)
    dsm, stats = dsm_from_images(
        [im.model for im in images],
        [im.path for im in images],
        roi=roi,
        res_m=args.res,
        epsg=epsg,
        method=args.triangulation,
        keep_dir=args.keep,
        progress=not args.quiet,
        register=not args.no_register,
        band_rows=args.band_rows,
        dem=open_dem(args),
        height_range_m=tuple(args.heights) if args.heights else None,
        max_hole_m=args.max_hole,
        orientation=orientation,
    )
    write_dsm(dsm, args.out, overwrite=args.overwrite)
    filled = float(np.isfinite(dsm.height).mean())
    interpolated = float((dsm.filled == 1).mean())
    result = {
        "output": str(args.out),
        "epsg": dsm.epsg,
        "res_m": dsm.res_m,
        "shape": list(dsm.height.shape),
        "filled": round(filled, 4),
        "interpolated": round(interpolated, 4),
        "median_height_sigma_m": _median(dsm.height_sigma),
        "pairs": [
            {"images": [images[0].name, images[i + 1].name], **st} for i, st in enumerate(stats)
        ],
    }
    if args.json:
        print_json(result)
        return 0
    rows, cols = dsm.height.shape
    print(f"wrote {args.out}: {cols} x {rows} cells of {dsm.res_m:g} m, EPSG:{dsm.epsg}, "
          f"{100 * filled:.1f}% with a height (ellipsoidal, m), {100 * interpolated:.1f}% "
          "of them interpolated (band 'filled'); median height_sigma "
          f"{result['median_height_sigma_m'] or float('nan'):.2f} m")  # fmt: skip
    for pair in result["pairs"]:
        a, b = pair["images"]
        parts = [f"{pair.get('n_ties', '?')} ties"]
        if pair.get("n_points_outside_validity"):
            parts.append(f"{pair['n_points_outside_validity']} points outside the models' "
                         "validity cube dropped")  # fmt: skip
        if "vertical_disparity_px" in pair:
            parts.append(f"vertical disparity {pair['vertical_disparity_px']:+.2f} px removed")
        if "disparity_fill" in pair:
            parts.append(f"{100 * pair['disparity_fill']:.1f}% of pixels matched")
        if "height_offset_removed_m" in pair:
            parts.append(f"height offset {pair['height_offset_removed_m']:+.2f} m removed")
        print(f"  {a} - {b}: " + ", ".join(parts))
    return 0


def _tiled(args, image, roi) -> bool:
    """Tile by tile: asked for (a tile option), or a reference window over 2048 px a side."""
    from ..stereo import TILED_MIN_PX

    asked = any(v is not None for v in (args.tile, args.workers, args.scheduler, args.resume,
                                        args.plan))  # fmt: skip
    _, _, w, h = roi if roi is not None else (0, 0, *image.size)
    return asked or max(w, h) > TILED_MIN_PX


def _run_tiled(args, images, roi, epsg, orientation) -> int:
    """The DSM tile by tile (:func:`jaxgeo.stereo.tiled_dsm`), or its plan only (``--plan``)."""
    from . import CommandError

    if args.keep is not None:
        raise CommandError("--keep writes the products of an untiled DSM: give a --roi of at "
                           "most 2048 px without tile options")  # fmt: skip
    pool = _early_pool(args)
    try:
        return _plan_and_run(args, images, roi, epsg, orientation, pool)
    finally:
        if pool is not None:
            pool.close()


def _early_pool(args):
    """The worker processes, started now so that their start (importing jax and jaxgeo) overlaps
    the planning (~10 s); ``None`` where the tiles run here (``--workers 0``, one core) or
    nothing runs (``--plan``)."""
    from ..stereo import dsm_workers
    from ..tiles import WorkerPool

    if args.plan or args.workers == 0:
        return None
    if args.scheduler:
        return WorkerPool(0, args.scheduler, args.retries, warm=("jaxgeo.stereo",))
    n = dsm_workers(args.workers)
    return WorkerPool(n, retries=args.retries, warm=("jaxgeo.stereo",)) if n else None


def _plan_and_run(args, images, roi, epsg, orientation, pool) -> int:
    from ..stereo import TILE_CELLS, footprint_dem_heights, plan_dsm, tiled_dsm
    from ..tiles import TileError, write_plan
    from ._common import note, tiles_kept

    dem = open_dem(args)
    heights = tuple(args.heights) if args.heights else None
    if heights is None and dem is not None:
        lo, hi = footprint_dem_heights(images[0].model, dem, roi or (0, 0, *images[0].size))
        heights = (lo - 50.0, hi + 50.0)
    t_plan = time.perf_counter()
    setup = plan_dsm(
        [im.model for im in images], [im.path for im in images], roi=roi, res_m=args.res,
        epsg=epsg, heights=heights, tie_heights=heights, tile_px=args.tile or TILE_CELLS,
        method=args.triangulation, register=not args.no_register, band_rows=args.band_rows,
        max_hole_m=args.max_hole, orientation=orientation,
    )  # fmt: skip
    plan = setup.plan
    plan_s = time.perf_counter() - t_plan
    if args.plan:
        write_plan(plan, args.plan, overwrite=args.overwrite)
        if args.json:
            print_json({"plan": args.plan, "tiles": len(plan), "width": plan.width,
                        "height": plan.height, "tile_px": plan.tile_px})  # fmt: skip
        else:
            print(f"wrote {args.plan}: {len(plan)} tiles of {plan.tile_px} cells over "
                  f"{plan.width} x {plan.height} cells of {args.res:g} m "
                  f"(EPSG:{setup.job.epsg}); nothing computed")  # fmt: skip
        return 0
    note(f"jaxgeo dsm: {len(plan)} tiles of {plan.tile_px} cells over {plan.width} x "
         f"{plan.height} cells", args.quiet)  # fmt: skip
    try:
        # a single tile runs here unless workers were asked for (as tiled_dsm decides)
        asked = args.workers or args.scheduler
        report = tiled_dsm(setup, args.out, workers=args.workers, scheduler=args.scheduler,
                           resume=args.resume, retries=args.retries, overwrite=args.overwrite,
                           progress=not args.quiet,
                           pool=pool if asked or len(plan) > 1 else None)  # fmt: skip
    except (KeyboardInterrupt, TileError):
        tiles_kept(args, "dsm")
        raise
    empty = {k: v.get("no_data") for k, v in report.tile_stats.items() if "no_data" in v}
    result = {
        "output": str(report.path), "epsg": report.epsg, "res_m": report.res_m,
        "shape": [report.height, report.width], "filled": round(report.filled, 4),
        "interpolated": round(report.interpolated, 4), "tiles": report.tiles,
        "empty_tiles": empty, "reused_tiles": report.reused_tiles, "workers": report.workers,
        "scheduler": report.scheduler, "seconds": round(report.seconds, 1),
        "plan_s": round(plan_s, 1), "tiles_s": round(report.tiles_s, 1),
        "mosaic_s": round(report.mosaic_s, 1),
    }  # fmt: skip
    if args.json:
        print_json({**result, "tile_stats": report.tile_stats})
        return 0
    where = (f"{report.workers} worker(s) at {report.scheduler}" if report.scheduler
             else "this process")  # fmt: skip
    print(f"wrote {report.path}: {report.width} x {report.height} cells of {report.res_m:g} m, "
          f"EPSG:{report.epsg}, {100 * report.filled:.1f}% with a height (ellipsoidal, m), "
          f"{100 * report.interpolated:.1f}% interpolated (band 'filled'); {report.tiles} tiles "
          f"({len(empty)} without data, {report.reused_tiles} reused) on {where}; "
          f"{report.seconds:.1f} s")  # fmt: skip
    for tile_id, why in list(empty.items())[:5]:
        print(f"  tile {tile_id}: no data ({why[:160]})")
    return 0


def _median(values) -> float | None:
    import numpy as np

    if values is None or not np.isfinite(values).any():
        return None
    return round(float(np.nanmedian(values)), 4)
