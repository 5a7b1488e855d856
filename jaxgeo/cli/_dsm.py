"""``jaxgeo dsm``: a digital surface model from two or more images and their sensor models.

    jaxgeo dsm IMG1 IMG2 [IMG3 ...] [--model IMG=RPCFILE ...] [--roi X Y W H] [--res M]
               [--crs EPSG:n] [--triangulation {intersect,los_midpoint}] [--no-register]
               [--band-rows N] [--keep DIR] [--quiet] -o dsm.tif [--overwrite]

IMG1 is the reference: each pair (IMG1, IMGi) is rectified, matched densely (SGM) and
triangulated; the points are pooled into one height per cell (median; bands: height above the
WGS84 ellipsoid, count, spread). ``--roi`` in pixels of IMG1; ``--res`` metres (default 0.5);
CRS default the local UTM zone. ``--keep DIR`` writes each pair's intermediate products.
Dense matching runs over bands of ``--band-rows`` epipolar rows (default 512), so its memory
follows the band, not the image; a progress bar per pair shows the bands (``--quiet``: none).
"""

from __future__ import annotations

import argparse
import json


def register(sub) -> None:
    parser = sub.add_parser(
        "dsm",
        help="digital surface model from a stereo pair or triplet",
        description=__doc__.split("\n\n")[0],
    )
    parser.add_argument("images", nargs="+", metavar="IMG", help="images, reference first")
    parser.add_argument("--model", action="append", default=[], metavar="IMG=RPCFILE")
    parser.add_argument("--roi", type=int, nargs=4, metavar=("X", "Y", "W", "H"))
    parser.add_argument("--res", type=float, default=0.5, help="cell size, m (default 0.5)")
    parser.add_argument("--crs", help="output CRS as EPSG:n (default local UTM)")
    parser.add_argument(
        "--triangulation", choices=("intersect", "los_midpoint"), default="intersect"
    )
    parser.add_argument(
        "--no-register", action="store_true", help="do not remove the pairs' height offsets"
    )
    parser.add_argument(
        "--band-rows", type=int, default=512, metavar="N",
        help="epipolar rows per band of dense matching (default 512)",
    )  # fmt: skip
    parser.add_argument("--keep", metavar="DIR", help="keep intermediate products here")
    parser.add_argument("--quiet", action="store_true", help="no progress display")
    parser.add_argument("-o", "--output", required=True, metavar="DSM.tif")
    parser.add_argument("--overwrite", action="store_true")
    parser.set_defaults(func=run)


def _epsg(crs: str | None) -> int | None:
    from . import CommandError

    if crs is None:
        return None
    code = crs.upper().removeprefix("EPSG:")
    if not code.isdigit():
        raise CommandError(f"--crs {crs!r}: expected EPSG:n")
    return int(code)


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from ..io import refuse_existing
    from ..stereo import dsm_from_images, write_dsm
    from . import CommandError
    from ._match import models_of

    if len(args.images) < 2:
        raise CommandError("give at least two images")
    if args.band_rows < 1:
        raise CommandError(f"--band-rows {args.band_rows}: expected a positive number of rows")
    refuse_existing(args.output, args.overwrite)
    models = models_of(args.images, args.model)
    dsm, stats = dsm_from_images(
        models,
        args.images,
        roi=tuple(args.roi) if args.roi else None,
        res_m=args.res,
        epsg=_epsg(args.crs),
        method=args.triangulation,
        keep_dir=args.keep,
        progress=not args.quiet,
        register=not args.no_register,
        band_rows=args.band_rows,
    )
    write_dsm(dsm, args.output, overwrite=args.overwrite)
    filled = float(np.isfinite(dsm.height).mean())
    print(json.dumps({"output": str(args.output), "epsg": dsm.epsg, "shape": dsm.height.shape,
                      "filled": round(filled, 4), "pairs": stats}, default=str))  # fmt: skip
    return 0
