"""``jaxgeo match``: verified tie points between images, by SIFT matching guided by their models.

    jaxgeo match IMG1 IMG2 [IMG3 ...] -o TIES.csv [--dem DEM [--dem-height H] [--geoid G]]
                 [--heights HMIN HMAX] [--roi X Y W H] [--tol PX] [--sigma PX]
                 [--model IMG=FILE] [--image-origin IMG=COL,ROW] [--overwrite] [--quiet] [--json]

Every pair of images is matched (:func:`jaxgeo.stereo.tie_points`): keypoints of the earlier
image are searched within ``--tol`` px of the epipolar curve its model predicts in the later one,
over a height range that is ``--heights`` if given, else the DEM's heights over the footprint
(``--dem``), else found by a first coarse matching over the models' validity range; every tie is
then verified (duplicates, one-to-one, offset across the epipolar curves, triangulated height,
reprojection residual, height against its neighbours). A summary per pair says how many ties
were kept and why the others were rejected. Ties of several pairs that share a keypoint are
joined into one point seen in all those images (:func:`jaxgeo.stereo.join_ties`), which ties the
pairs' heights together in ``jaxgeo adjust``. Output: the observations CSV ``jaxgeo adjust``
reads (``id,image,x,y,sigma_px``; image = file stem; pixels of the rasters given, integer =
pixel centre). ``--roi`` restricts the keypoints of the first image.
"""

from __future__ import annotations

import argparse
import math

from ._common import (
    add_command,
    add_dem_options,
    add_heights,
    add_image_options,
    add_json,
    add_out,
    add_quiet,
    check_dem_options,
    check_roi,
    dem_inputs,
    guard_outputs,
    note,
    open_dem,
    open_images,
    ours,
    print_json,
)

FEW_TIES = 20
"""Fewer ties than this in a pair: a warning (too few to adjust the pair reliably)."""
CHECK_NAMES = {
    "duplicate": "duplicate",
    "ambiguous": "ambiguous",
    "across_epipolar": "across the epipolar curve",
    "triangulation": "not triangulated",
    "height_range": "height outside the range",
    "residual": "reprojection residual",
    "height_neighbours": "height unlike its neighbours'",
}


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
    parser.add_argument("--tol", type=float, default=10.0, metavar="PX",
                        help="how far from the models' epipolar curves a match may lie (the "
                        "models' relative bias), px (default 10)")  # fmt: skip
    parser.add_argument("--sigma", type=float, default=0.5, metavar="PX",
                        help="a priori sigma of the tie points written to the CSV, px "
                        "(default 0.5)")  # fmt: skip
    add_quiet(parser)
    add_json(parser)
    parser.set_defaults(func=run)


def _check_options(args) -> None:
    """Values the parser cannot check, before any file is read."""
    from . import CommandError

    if len(args.images) < 2:
        raise CommandError("give at least two images")
    for name in ("tol", "sigma"):
        value = getattr(args, name)
        if not (math.isfinite(value) and value > 0):
            raise CommandError(f"--{name} {value:g}: must be a number > 0 (px)")
    check_dem_options(args)


def summary(names, report) -> list[str]:
    """The human lines of one pair's :class:`~jaxgeo.stereo.TieReport`."""
    a, b = names
    rejected = ", ".join(f"{n} {CHECK_NAMES.get(k, k)}" for k, n in report.rejected.items() if n)
    lo, hi = report.height_range_m
    v0, v1 = report.validity_m
    lines = [
        f"{a} - {b}: {report.n_kept} ties kept of {report.n_candidates} candidates"
        + (f" (rejected: {rejected})" if rejected else "")
    ]
    source = report.height_source
    if report.n_coarse is not None:
        source += f", {report.n_coarse} coarse ties"
    lines.append(
        f"  heights searched {lo:.0f}..{hi:.0f} m ({source}; models valid {v0:.0f}..{v1:.0f} m)"
    )
    if report.n_kept:
        p5, p50, p95 = report.heights_m
        lines.append(
            f"  tie heights p5/p50/p95 {p5:.1f} / {p50:.1f} / {p95:.1f} m; offset across the "
            f"epipolar curves {report.across_px:+.2f} px (sigma {report.across_sigma_px:.2f} px)"
        )
    return lines


def _warnings(caught, prefix: str = "") -> None:
    """jaxgeo's own warnings as ``jaxgeo match: warning:`` lines (other libraries' notices are
    not the user's business)."""
    import sys

    for w in ours(caught):
        print(f"jaxgeo match: warning: {prefix}{w.message}", file=sys.stderr)


def run(args: argparse.Namespace) -> int:
    import sys
    import warnings

    import numpy as np

    from ..io import Observations, write_observations
    from ..stereo import join_ties, sift_features_raster, tie_points
    from . import CommandError

    _check_options(args)
    images = open_images(args.images, args)
    inputs = [p for im in images for p in im.inputs] + dem_inputs(args)
    out = guard_outputs([args.out], inputs, args.overwrite)[0]  # before any work
    if args.roi is not None:
        check_roi(args.roi, images[0])
    dem = None
    if args.dem is not None:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            dem = open_dem(args)
        _warnings(caught)
    features = []
    for k, im in enumerate(images):
        note(f"SIFT keypoints of {im.name} ({k + 1}/{len(images)})", args.quiet)
        features.append(sift_features_raster(im.path, args.roi if k == 0 else None))
    found, pairs = [], []
    for i in range(len(images)):
        for j in range(i + 1, len(images)):
            a, b = images[i], images[j]
            note(f"matching {a.name} - {b.name}", args.quiet)
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                ties = tie_points(
                    a.model, b.model, a.path, b.path, roi=args.roi if i == 0 else None, dem=dem,
                    height_range_m=args.heights, epipolar_tol_px=args.tol,
                    features1=features[i], features2=features[j],
                )  # fmt: skip
            _warnings(caught, f"{a.name} - {b.name}: ")
            if len(ties) < FEW_TIES:
                print(f"jaxgeo match: warning: {a.name} - {b.name}: only {len(ties)} ties (do the "
                      "images overlap? are the models right? a larger --tol for a large relative "
                      "bias?)", file=sys.stderr)  # fmt: skip
            pairs.append({"images": [a.name, b.name], **ties.report.as_dict()})
            if not args.json:
                print("\n".join(summary((a.name, b.name), ties.report)), flush=True)
            found.append((i, j, ties.xy1, ties.xy2))
    joined = join_ties(found)
    if len(joined.point) == 0:
        raise CommandError("no tie point survived the checks in any pair (see the summary)")
    names = [im.name for im in images]
    width = len(str(len(joined.n_views) - 1))
    obs = Observations(
        tuple(f"tie{k:0{width}d}" for k in joined.point),
        tuple(names[k] for k in joined.image),
        joined.xy,
        np.full(len(joined.point), args.sigma),
    )
    write_observations(obs, out, overwrite=args.overwrite)
    views = {int(v): int(n) for v, n in enumerate(np.bincount(joined.n_views)) if n}
    if args.json:
        print_json({"out": str(out), "n_points": len(joined.n_views),
                    "n_observations": len(obs), "points_by_views": views,
                    "n_conflicting_dropped": joined.n_conflicting, "pairs": pairs})  # fmt: skip
    else:
        seen = ", ".join(f"{n} in {v} images" for v, n in views.items())
        dropped = (f"; {joined.n_conflicting} groups of ties reaching two points of one image "
                   "dropped") if joined.n_conflicting else ""  # fmt: skip
        print(f"wrote {len(joined.n_views)} tie points ({seen}; ties sharing a keypoint joined"
              f"{dropped}), {len(obs)} observations, to {out}")  # fmt: skip
    return 0
