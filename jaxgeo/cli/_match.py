"""``jaxgeo match``: verified tie points between images, by SIFT matching guided by their models.

    jaxgeo match IMG1 IMG2 [IMG3 ...] -o TIES.csv [--dem DEM [--dem-height H] [--geoid G]]
                 [--heights HMIN HMAX] [--roi X Y W H] [--tolerance PX] [--sigma PX]
                 [--model IMG=FILE] [--image-origin IMG=COL,ROW] [--overwrite] [--quiet] [--json]

Parse -> :class:`jaxgeo.stereo.MatchSettings` -> :func:`jaxgeo.stereo.match_images` (every pair
matched and each tie verified, :func:`jaxgeo.stereo.tie_points`; the height range from
``--heights``, else ``--dem``, else a coarse matching; ties sharing a keypoint joined into
multi-image points) -> write -> print (a summary per pair: ties kept, rejections by check, the
height range and its source). Output: the observations CSV ``jaxgeo adjust`` reads
(``id,image,x,y,sigma_px``; image = file stem; pixels of the rasters given, integer = pixel
centre). ``--roi`` restricts the keypoints of the first image; ``--tol`` is ``--tolerance``.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import sys

from ._common import add_command, add_json, add_out, add_quiet, guard_outputs, print_json
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

MAX_TOLERANCE_PX = 200.0
"""Largest ``--tolerance``: the candidates of each keypoint grow with the band's width, and so
do time and memory (s2p's 1024 px pair on 2 cores: 8 s at 10 px, 31 s at 100 px, over 12 min
and 4 GB at 400 px). A relative bias larger than this is the models' to fix first (``jaxgeo
adjust`` with a few GCPs). It is also at most a quarter of the smallest image's shorter side:
a wider band no longer constrains the matches."""


class _Spelled(argparse.Action):
    """Store the value and the option as typed (``--tolerance`` or ``--tol``): errors name it."""

    def __call__(self, parser, namespace, values, option_string=None):
        setattr(namespace, self.dest, values)
        setattr(namespace, f"{self.dest}_option", option_string)


def register(sub) -> None:
    parser = add_command(
        sub, "match", "verified tie points by SIFT matching guided by the sensor models", __doc__
    )
    parser.add_argument("images", nargs="+", metavar="IMG",
                        help="images (two or more rasters; each pair is matched)")  # fmt: skip
    add_image_options(parser)
    add_out(parser, "TIES.csv", "the tie points CSV (id,image,x,y,sigma_px) jaxgeo adjust reads")
    add_dem_options(parser, "its heights over the footprint, +-50 m, give the height range")
    add_heights(parser)
    parser.add_argument("--roi", type=int, nargs=4, default=None, metavar=("X", "Y", "W", "H"),
                        help="search only this window of the first image (column, row, width, "
                        "height, px)")  # fmt: skip
    parser.add_argument("--tolerance", "--tol", type=float, default=10.0, metavar="PX",
                        action=_Spelled, help="how far from the models' epipolar curves a match "
                        "may lie (the models' relative bias), px (default 10; at most "
                        f"{MAX_TOLERANCE_PX:g} and a quarter of the images' size)")  # fmt: skip
    parser.add_argument("--sigma", type=float, default=0.5, metavar="PX",
                        help="a priori sigma of the tie points written to the CSV, px "
                        "(default 0.5)")  # fmt: skip
    add_quiet(parser)
    add_json(parser)
    parser.set_defaults(func=run, tolerance_option="--tolerance")


def _check_options(args) -> None:
    """Values the parser cannot check, before any file is read (named by their options)."""
    from . import CommandError

    if len(args.images) < 2:
        raise CommandError("give at least two images")
    for option, value in ((args.tolerance_option, args.tolerance), ("--sigma", args.sigma)):
        if not (math.isfinite(value) and value > 0):
            raise CommandError(f"{option} {value:g}: must be a number > 0 (px)")
    if args.tolerance > MAX_TOLERANCE_PX:
        raise CommandError(f"{args.tolerance_option} {args.tolerance:g}: at most "
                           f"{MAX_TOLERANCE_PX:g} px (the models' relative bias; matching time "
                           "and memory grow with it: fix a larger bias first, jaxgeo adjust "
                           "with a few GCPs)")  # fmt: skip
    check_dem_options(args)


def _check_tolerance(args, images) -> None:
    """``--tolerance`` within a quarter of the smallest image's shorter side."""
    from . import CommandError

    sized = [im for im in images if im.size]
    if not sized:
        return
    image = min(sized, key=lambda im: min(im.size))
    most = min(image.size) // 4
    if args.tolerance > most:
        raise CommandError(f"{args.tolerance_option} {args.tolerance:g}: at most {most:g} px for "
                           f"{image.path} ({image.size[0]} x {image.size[1]} px): a quarter of "
                           "its shorter side: a wider band constrains nothing")  # fmt: skip


@contextlib.contextmanager
def _warning_lines():
    """jaxgeo's warnings printed as they come, as ``jaxgeo match: warning:`` lines naming this
    command's option for a setting; other libraries' notices go to Python's filters."""
    import warnings

    from ..errors import JaxgeoWarning

    with warnings.catch_warnings():
        warnings.simplefilter("always", JaxgeoWarning)
        show = warnings.showwarning

        def line(message, category, *where):
            if not issubclass(category, JaxgeoWarning):
                return show(message, category, *where)
            text = str(message).replace("epipolar_tol_px", "--tol")
            print(f"jaxgeo match: warning: {text}", file=sys.stderr, flush=True)

        warnings.showwarning = line
        yield


def _print_pairs(reports, args) -> None:
    for report in () if args.json else reports:
        print("\n".join(report.summary()), flush=True)


def run(args: argparse.Namespace) -> int:
    from ..stereo import MatchSettings, NoTiesError, match_images

    _check_options(args)
    images = open_images(args.images, args)
    _check_tolerance(args, images)
    inputs = [p for im in images for p in im.inputs] + dem_inputs(args)
    out = guard_outputs([args.out], inputs, args.overwrite)[0]  # before any work
    if args.roi is not None:
        check_roi(args.roi, images[0])
    settings = MatchSettings(roi=args.roi, height_range_m=args.heights,
                             epipolar_tol_px=args.tolerance, sigma_px=args.sigma)  # fmt: skip
    with _warning_lines():
        dem = open_dem(args)
        try:
            result = match_images(images, settings, dem=dem,
                                  progress=not args.quiet)  # fmt: skip
        except NoTiesError as err:  # the summary says why, before the error
            _print_pairs(err.reports, args)
            raise
    _print_pairs(result.pairs, args)
    result.write(out, overwrite=args.overwrite)
    if args.json:
        print_json({"out": str(out), **result.as_dict()})
    else:
        print(f"wrote {result.describe()}, to {out}")
    return 0
