"""``jaxgeo ortho IMAGE --dem DEM -o OUT.tif``: orthorectify an image with its model and a DEM.

Orthorectify IMAGE on DEM into a tiled, compressed COG. The model is the image's own RPC (GeoTIFF
tags, .RPB/_RPC.TXT sidecar) unless --model names a model file; a crop's pixel-space geotransform
gives its origin in the model's frame (--image-origin COL,ROW otherwise). Default CRS: the local
UTM zone; default resolution: the image's GSD rounded to a common value (0.497 or 0.532 m: 0.5 m);
the grid's edges are multiples of the resolution (target-aligned pixels; --no-tap: from the
footprint's or --bounds' corner), so the orthos and DSMs of one job at one --res share a grid.
--like RASTER takes the CRS, transform and shape of another raster exactly (not with --crs,
--res, --bounds, --no-tap). Every option is checked before any computation.

The product is made tile by tile: a small one in this process, a large one on worker processes,
one per core (--workers), or on an existing dask cluster (--scheduler ADDRESS: start one with
``dask scheduler`` and ``dask worker ADDRESS`` on each machine, or dask-jobqueue's SLURMCluster /
PBSCluster, whose ``scheduler_address`` you pass here; workers need jaxgeo and the same paths to
the inputs and to the output's folder). Tiles that fail are retried (--retries), then named in
the error; --resume DIR keeps finished tiles in DIR so that the same command run again after an
interruption reuses them; --plan FILE writes the tiles (JSON) without computing them.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import pathlib
import sys
import warnings

from ._common import add_command, add_json, add_out, add_quiet, ours
from ._inputs import add_dem_fill_options, add_image_options
from ._report_option import add_report, report_target
from ._tile_options import add_tile_options


def register(sub) -> None:
    parser = add_command(
        sub, "ortho", "orthorectify an image with its RPCs (or any model file) and a DEM", __doc__
    )
    parser.epilog = __doc__.split("\n\n", 1)[1].strip() + "\n\n" + parser.epilog
    parser.add_argument("image", metavar="IMAGE", help="the image (any raster GDAL reads)")
    parser.add_argument("--dem", required=True, metavar="DEM", help="DEM raster (any CRS)")
    parser.add_argument(
        "--dem-height",
        choices=("ellipsoidal", "orthometric"),
        default=None,
        help="height reference of the DEM values (default: the file's vertical "
        "CRS if it declares EGM96/EGM2008, else ellipsoidal)",
    )
    parser.add_argument(
        "--geoid",
        default=None,
        metavar="GEOID",
        help="egm96 (shipped), egm2008 (PROJ's grid) or a geoid grid file, for orthometric "
        "DEMs (implies --dem-height orthometric)",
    )
    add_dem_fill_options(parser)
    add_image_options(parser)
    parser.add_argument(
        "--crs",
        default=None,
        metavar="CRS",
        help="output CRS, e.g. EPSG:32631 (default: the local UTM zone)",
    )
    parser.add_argument(
        "--res",
        type=float,
        default=None,
        metavar="RES",
        help="output pixel size in CRS units: metres, or degrees in a geographic "
        "CRS (default: the image's GSD)",
    )
    parser.add_argument(
        "--bounds",
        nargs=4,
        type=float,
        default=None,
        metavar=("W", "S", "E", "N"),
        help="output bounds in the output CRS (needs --crs; default: the footprint on the DEM)",
    )
    parser.add_argument(
        "--no-tap",
        action="store_true",
        help="start the grid at the footprint's (or --bounds') west and north edges (default: "
        "its edges are multiples of the resolution, as gdalwarp -tap: products of one job "
        "share a grid)",
    )
    parser.add_argument(
        "--like",
        default=None,
        metavar="RASTER",
        help="the output takes this raster's CRS, transform and shape (an ortho or DSM of the "
        "same job; not with --crs, --res, --bounds, --no-tap)",
    )
    parser.add_argument(
        "--resampling",
        choices=("nearest", "bilinear", "cubic"),
        default="bilinear",
        help="image resampling (default: bilinear)",
    )
    parser.add_argument(
        "--occlusion",
        choices=("off", "nodata", "band"),
        default="off",
        help="terrain hidden from the sensor: nodata, or an extra mask band (default: off)",
    )
    parser.add_argument(
        "--compress",
        choices=("deflate", "zstd", "lzw", "none"),
        default="deflate",
        help="COG compression (default: deflate)",
    )
    parser.add_argument(
        "--max-pixels",
        type=float,
        default=None,
        metavar="N",
        help="refuse a product of more pixels (default: 2e9; 0: no limit)",
    )
    add_tile_options(parser, 1024, "output pixels")
    add_out(parser, "OUT.tif", "the orthoimage (a COG; written only once complete)")
    add_report(parser, "OUT.report.html beside OUT.tif: a quicklook")
    add_quiet(parser)
    add_json(parser)
    parser.set_defaults(func=run)


def _inputs(image, dem, like) -> list[os.PathLike]:  # (a URL: a RemotePath)
    return [*image.inputs, *dem.inputs] + ([pathlib.Path(like)] if like else [])


def run(args: argparse.Namespace) -> int:
    from . import CommandError

    if args.max_pixels is not None and args.max_pixels < 0:
        raise CommandError(f"--max-pixels must be >= 0 (0: no limit), got {args.max_pixels:g}")
    caught = []
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            return _run(args)
    finally:  # jaxgeo's warnings once each, one line (printed even with --quiet)
        shown = set()
        for w in ours(caught):
            if str(w.message) not in shown:
                shown.add(str(w.message))
                print(f"jaxgeo ortho: warning: {w.message}", file=sys.stderr)


def _settings(args: argparse.Namespace):
    """The product's :class:`~jaxgeo.ortho.OrthoSettings` and the tiles'
    :class:`~jaxgeo.tiles.TileSettings` from the arguments."""
    from jaxgeo.ortho import MAX_PIXELS, OrthoError, OrthoSettings
    from jaxgeo.tiles import TileSettings

    from . import CommandError

    if args.like is not None:  # its grid, whole: no option of the grid with it
        given = [opt for opt, v in (("--crs", args.crs), ("--res", args.res),
                                    ("--bounds", args.bounds), ("--no-tap", args.no_tap or None))
                 if v is not None]  # fmt: skip
        if given:
            raise CommandError(f"--like {args.like} gives the output grid (CRS, transform, "
                               f"shape): {', '.join(given)} cannot be given with it")  # fmt: skip
    try:
        settings = OrthoSettings(
            crs=args.crs, res_m=args.res, bounds=args.bounds, resampling=args.resampling,
            occlusion=args.occlusion, tile_px=args.tile or OrthoSettings.tile_px,
            max_pixels=MAX_PIXELS if args.max_pixels is None else args.max_pixels,
            compress=args.compress, tap=not args.no_tap, like=args.like,
        )  # fmt: skip
    except OrthoError as err:  # --like's raster, named as the option
        raise CommandError(f"--{err}" if str(err).startswith("like: ") else str(err)) from None
    tiles = TileSettings(workers=args.workers, scheduler=args.scheduler, retries=args.retries,
                         resume=args.resume, progress=not args.quiet)  # fmt: skip
    return settings, tiles


def _run(args: argparse.Namespace) -> int:
    from jaxgeo.ortho import orthorectify, plan_ortho
    from jaxgeo.tiles import TileError, write_plan

    from ._common import print_json
    from ._inputs import open_dem, open_images
    from ._tile_options import check_tile_options, tiles_kept

    (image,) = open_images([args.image], args)
    dem = open_dem(args)  # its height reference noted
    check_tile_options(args, _inputs(image, dem, args.like), 64)
    settings, tiles = _settings(args)
    page = None if args.plan else report_target(args, _inputs(image, dem, args.like), False)
    if args.plan:
        setup = plan_ortho(image, dem, args.out, settings, overwrite=True)
        write_plan(setup.plan, args.plan, overwrite=args.overwrite)
        plan = setup.plan
        if args.json:
            print_json({"plan": args.plan, "tiles": len(plan), "width": plan.width,
                        "height": plan.height, "tile_px": plan.tile_px})  # fmt: skip
        else:
            crs = setup.crs.to_string()
            print(f"wrote {args.plan}: {len(plan)} tiles of {plan.tile_px} px over "
                  f"{plan.width} x {plan.height} px ({crs}); nothing computed")  # fmt: skip
        return 0
    try:
        report = orthorectify(image, dem, args.out, settings, tiles, overwrite=args.overwrite)
    except (KeyboardInterrupt, TileError):
        tiles_kept(args, "ortho")
        raise
    if page is not None:
        from jaxgeo.report import write_ortho_report

        write_ortho_report(report.path, page, report, overwrite=args.overwrite)
    if args.json:
        print_json({**{k: (str(v) if isinstance(v, pathlib.Path) else v)
                       for k, v in dataclasses.asdict(report).items()},
                    **({"report": str(page)} if page else {})})  # fmt: skip
        return 0
    where = (f"{report.workers} worker(s) at {report.scheduler}" if report.scheduler
             else "this process")  # fmt: skip
    print(f"wrote {report.path}: {report.width} x {report.height} px of {report.res_m:.4g} "
          f"(CRS units), {report.crs}; "
          f"{100 * report.valid_fraction:.1f}% with data; grid error left "
          f"{report.grid_error_px:.2g} px ({100 * report.refined_fraction:.1f}% of blocks "
          f"projected in full); {report.tiles} tiles ({report.empty_tiles} without data, "
          f"{report.reused_tiles} reused) on {where}; {report.seconds:.1f} s")  # fmt: skip
    if args.res is None and args.like is None:
        print(f"resolution {report.res_m:g}: the image's GSD {report.gsd:.4g} rounded to a common "
              "value (--res to choose another)")  # fmt: skip
    if report.occluded_fraction is not None:
        print(f"occluded: {100 * report.occluded_fraction:.2f}% of the output")
    if page is not None:
        print(f"wrote {page}")
    return 0
