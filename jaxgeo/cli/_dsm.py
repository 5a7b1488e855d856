"""``jaxgeo dsm``: a digital surface model from two or more images and their sensor models.

    jaxgeo dsm IMG1 IMG2 [IMG3 ...] [--model IMG=FILE ...] [--image-origin IMG=COL,ROW ...]
               [--roi X Y W H] [--res M] [--crs EPSG:n] [--like RASTER] [--no-tap]
               [--triangulation {intersect,los_midpoint}]
               [--no-register] [--matcher {jax,opencv}] [--matcher-memory MB] [--band-rows N]
               [--orientation adjusted_models.json]
               [--keep DIR] [--quiet] [--json] -o dsm.tif [--overwrite]

IMG1 is the reference: each pair (IMG1, IMGi) is rectified, matched densely (SGM) and
triangulated; the points are pooled into one height per cell (median; bands: height above the
WGS84 ellipsoid, count, spread, filled, height_sigma). ``height_sigma`` is the height's
standard deviation per cell (m): the matching's (from each disparity's correlation peak) and,
with ``--orientation DIR/adjusted_models.json`` (written by ``jaxgeo adjust --out DIR``, whose
adjusted RPCs are the images' models), the adjusted models' posterior uncertainty (no larger
than the a priori where the ties left a direction open), propagated through the intersection;
without it, the models' a priori orientation error (the RPC's ERR_BIAS/ERR_RAND where its vendor
states them, else 0.7 px per image and axis; the band's ``covers`` tag and the summary say
which). ``--roi``
in pixels of IMG1 (default: all of it); ``--res`` metres (default 0.5); CRS default the local UTM
zone (a projected CRS in metres; a geographic CRS is refused); the grid's edges are multiples of
--res (target-aligned cells, as the orthos': the products of one job share a grid; ``--no-tap``:
from the footprint's corner); ``--like RASTER`` takes another raster's grid (CRS, transform,
shape; not with --res, --crs, --no-tap). ``--keep DIR`` writes each pair's
intermediate products. Dense matching runs over bands of ``--band-rows`` epipolar rows (default
512), so its memory follows the band, not the image; ``--matcher`` picks OpenCV's SGBM (the
default on a CPU) or the census SGM in JAX (the default where JAX's device is a GPU or TPU).
Everything given is checked before any computation: the images and
their models, the ROI, the CRS, the output (never an input) and the DSM's size.
"""

from __future__ import annotations

import argparse
import re
import sys

from ._common import (
    add_command,
    add_json,
    add_out,
    add_quiet,
    guard_outputs,
    ours,
    print_json,
)
from ._inputs import (
    add_dem_options,
    add_heights,
    add_image_options,
    check_dem_options,
    check_roi,
    dem_inputs,
    open_dem,
    open_images,
)
from ._report_option import add_report, report_target
from ._tile_options import add_tile_options, check_tile_options, tiles_kept

MAX_CELLS = 400_000_000
"""Largest DSM (cells) made without ``--max-cells``: 20 000 x 20 000 (``jaxgeo.stereo.MAX_CELLS``;
not imported here: ``jaxgeo --help`` does not load jax)."""
OPTIONS = {"res_m": "--res", "max_cells": "--max-cells", "max_hole_m": "--max-hole",
           "band_rows": "--band-rows", "heights": "--heights", "roi": "--roi", "keep": "--keep",
           "tile_px": "--tile", "triangulation": "--triangulation"}  # fmt: skip
"""The option of each :class:`jaxgeo.stereo.DSMSettings` field a command-line user sets."""


def register(sub) -> None:
    parser = add_command(sub, "dsm", "digital surface model from a stereo pair or triplet", __doc__)
    arg = parser.add_argument
    arg("images", nargs="+", metavar="IMG", help="images, the reference first")
    add_image_options(parser)
    arg("--roi", type=int, nargs=4, metavar=("X", "Y", "W", "H"),
        help="region of the reference image, pixels (default: the whole image)")  # fmt: skip
    arg("--res", type=float, default=None, help="cell size, m (default 0.5)")
    arg("--crs", help="output CRS, a projected CRS in metres, e.g. EPSG:32631 (default: local UTM)")
    arg("--like", metavar="RASTER",
        help="the DSM takes this raster's CRS, transform and shape (an ortho or DSM of the same "
        "job; not with --res, --crs, --no-tap)")  # fmt: skip
    arg("--no-tap", action="store_true",
        help="start the grid at the footprint's west and north edges (default: its edges are "
        "multiples of --res, as gdalwarp -tap)")  # fmt: skip
    arg("--triangulation", choices=("intersect", "los_midpoint"), default="intersect",
        help="least-squares intersection (default) or the midpoint of the two lines of "
        "sight")  # fmt: skip
    arg("--no-register", action="store_true",
        help="with 3+ images, keep each pair's height offset (default: removed; see the "
        "docs)")  # fmt: skip
    arg("--matcher", choices=("jax", "opencv"), default=None,
        help="dense matcher: census SGM in JAX (on JAX's default device) or OpenCV's SGBM "
        "(default: jax when that device is a GPU or TPU, else opencv)")  # fmt: skip
    arg("--matcher-memory", type=float, default=None, metavar="MB",
        help="memory a band of the jax matcher may use (default: 80%% of a GPU's free memory, "
        "25%% of the host's available memory on a CPU); bands are matched in chunks of rows "
        "that fit")  # fmt: skip
    arg("--band-rows", type=int, default=512, metavar="N",
        help="epipolar rows per band of dense matching (default 512; memory follows "
        "it)")  # fmt: skip
    arg("--orientation", metavar="JSON",
        help="adjusted_models.json of `jaxgeo adjust --out` for these images: their posterior "
        "bias sigmas enter the height_sigma band (default: the a priori, the RPC's "
        "ERR_BIAS/ERR_RAND or 0.7 px per image; the band's covers tag says which)")  # fmt: skip
    add_dem_options(parser, "its heights over the footprint, +-50 m, give the tie points' range")
    add_heights(parser)
    arg("--max-hole", type=float, default=4.0, metavar="M",
        help="interpolate holes up to M metres across (flagged in the 'filled' band; default 4, "
        "0: none)")  # fmt: skip
    arg("--keep", metavar="DIR", help="write intermediate products to this folder")
    arg("--max-cells", type=float, default=MAX_CELLS, metavar="N",
        help=f"refuse a DSM larger than N cells (default {MAX_CELLS:.0e})")  # fmt: skip
    add_tile_options(parser, 1024, "DSM cells (a scene larger than 2048 px is made tile by tile)")
    add_quiet(parser)
    add_json(parser)
    add_out(parser, "DSM.tif", "the DSM GeoTIFF to write")
    add_report(parser, "DSM.report.html beside DSM.tif: hillshade, filled cells, height_sigma")
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


def _named(err) -> str:
    """A :class:`~jaxgeo.stereo.DSMSettingsError`'s message with the options for the fields."""
    return re.sub(r"\b(" + "|".join(OPTIONS) + r")\b", lambda m: OPTIONS[m[1]], str(err))


def run(args: argparse.Namespace) -> int:
    import warnings

    caught = []
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            return _run(args)
    finally:  # jaxgeo's warnings (e.g. a DEM unlike the ties) once each, one line
        shown = set()
        for w in ours(caught):
            if str(w.message) not in shown:
                shown.add(str(w.message))
                print(f"jaxgeo dsm: warning: {w.message}", file=sys.stderr)


def _run(args: argparse.Namespace) -> int:
    import dataclasses

    from ..stereo import DSMSettings, DSMSettingsError, SGMSettings, make_dsm
    from ..tiles import TileError, TileSettings
    from . import CommandError

    if len(args.images) < 2:
        raise CommandError("give at least two images (the reference first)")
    if args.like is not None:  # its grid, whole: no option of the grid with it
        given = [o for o, v in (("--res", args.res), ("--crs", args.crs),
                                ("--no-tap", args.no_tap or None)) if v is not None]  # fmt: skip
        if given:
            raise CommandError(f"--like {args.like} gives the DSM's grid (CRS, transform, "
                               f"shape): {', '.join(given)} cannot be given with it")  # fmt: skip
    try:
        settings = DSMSettings(
            res_m=0.5 if args.res is None else args.res, tap=not args.no_tap, like=args.like,
            band_rows=args.band_rows, max_hole_m=args.max_hole,
            triangulation=args.triangulation, register=not args.no_register, keep=args.keep,
            heights=tuple(args.heights) if args.heights else None, tile_px=args.tile,
            max_cells=args.max_cells,
            sgm=SGMSettings(matcher=args.matcher, memory_mb=args.matcher_memory),
        )  # fmt: skip
        check_dem_options(args)
        settings = dataclasses.replace(settings, epsg=output_epsg(args.crs))
        images = open_images(args.images, args)
        inputs = [p for im in images for p in im.inputs] + dem_inputs(args)
        inputs += [args.like] if args.like else []
        orientation = None
        if args.orientation is not None:
            from ..stereo import OrientationError
            from ..stereo.internal import adjusted_orientation

            inputs.append(args.orientation)
            try:  # the posterior, bounded by the models' a priori where the ties left it open
                orientation = adjusted_orientation(args.orientation, [im.name for im in images])
            except OrientationError as err:
                raise CommandError(str(err)) from None
        check_tile_options(args, inputs, 64)
        if args.keep is not None:
            guard_outputs([], inputs, True)  # the folder is created; its files are new names
        if args.roi is not None:
            settings = dataclasses.replace(settings, roi=check_roi(args.roi, images[0]))
        page = None if args.plan else report_target(args, inputs, folder=False)
        tiles = TileSettings(workers=args.workers, scheduler=args.scheduler,
                             retries=args.retries, resume=args.resume,
                             progress=not args.quiet, plan=args.plan)  # fmt: skip
        report = make_dsm(images, args.out, settings, tiles, dem=open_dem(args),
                          orientation=orientation, overwrite=args.overwrite)  # fmt: skip
    except DSMSettingsError as err:  # (a --like path is not rewritten: it may hold "res_m")
        raise CommandError(f"--{err}" if err.field == "like" else _named(err)) from None
    except (KeyboardInterrupt, TileError):
        tiles_kept(args, "dsm")
        raise
    if report.plan_path is not None:
        plan = report.plan
        if args.json:
            print_json({"plan": args.plan, "tiles": len(plan), "width": plan.width,
                        "height": plan.height, "tile_px": plan.tile_px})  # fmt: skip
        else:
            print(f"wrote {args.plan}: {len(plan)} tiles of {plan.tile_px} cells over "
                  f"{plan.width} x {plan.height} cells of {report.res_m:g} m "
                  f"(EPSG:{report.epsg}); nothing computed")  # fmt: skip
        return 0
    result = report.as_dict()
    if not report.tiled:  # the output as named
        result["output"] = str(args.out)
    if page is not None:
        from ..report import write_dsm_report

        result["report"] = str(write_dsm_report(args.out, page, report, overwrite=args.overwrite))
    if args.json:
        print_json(result)
    else:
        print(report.summary(str(args.out)) + (f"\nwrote {page}" if page else ""))
    return 0
