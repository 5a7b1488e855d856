"""``jaxgeo adjust``: bundle block adjustment of RPC images with bias compensation.

    jaxgeo adjust --image NAME=RPCFILE [--image ...] --ground GROUND.csv
                  --observations OBS.csv --bias {none,shift,shift-drift,affine}
                  [--bias-prior-shift-px S --bias-prior-matrix M] [--dem FILE]
                  [--json] [--out DIR] [--overwrite]

GROUND.csv: ``id,lon,lat,h,role[,sigma_e_m,sigma_n_m,sigma_h_m]`` (role gcp or check);
OBS.csv: ``id,image,x,y[,sigma_px]``; points in OBS but not in GROUND are tie points. The
report compares direct georeferencing (forward intersection with the given RPCs, no GCP) with
the adjustment, as tables 3 and 4 of 000_5aba1cb50921f3c6.txt. ``--out DIR`` writes the
adjusted models (per image an RPC where GDAL finds it for that image, ``<image stem>_RPC.TXT``
or as ``--rpc-format`` says, beside a copy of the image with ``--copy-images`` or in a copied
GeoTIFF's tags with ``--write-into``: the bias folded in exactly where it can be, else refitted
with the refit error reported; and a JSON with RPC + bias + sigmas), the
adjusted points, the residuals and the report; inputs and existing files are never replaced
(``--overwrite`` allows replacing earlier outputs, never the inputs); ``--out`` is checked
before any computation, and the report is printed before anything is written.

Gross errors: by default the image observations and GCP coordinates get a Cauchy loss at 3 a
priori sigmas (solved by iteratively reweighted least squares), then data snooping (Baarda's
w-test, iterated) removes the flagged observations and re-solves (``--keep-blunders``: flag
only). Check-point statistics leave out the points with a flagged observation.
"""

from __future__ import annotations

import argparse

EXIT_CODES = """exit status:
  0  adjusted (gross errors, if any, removed and listed)
  1  the solve did not converge (the last state is reported)
  2  bad input or options (the file, line or point is named)
  3  adjusted, but s0 > 3: the observations do not fit the models (see the warning naming the
     worst images and points, e.g. two RPC files swapped)
  4  the adjustment ran but --out could not be written (the report is printed first)"""


def register(sub) -> None:
    from ..bundle import BIAS_CHOICES
    from ..lsq import LOSSES

    parser = sub.add_parser(
        "adjust",
        help="bundle block adjustment of RPC images (bias compensation)",
        description=__doc__.split("\n\n")[0],
        epilog=EXIT_CODES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "--image",
        action="append",
        required=True,
        metavar="NAME=RPCFILE",
        help="an image name (as in OBS.csv) and its RPC file; repeat per image",
    )
    parser.add_argument("--ground", metavar="GROUND.csv", help="GCPs and check points")
    parser.add_argument(
        "--observations", required=True, metavar="OBS.csv", help="image measurements"
    )
    parser.add_argument(
        "--bias",
        choices=BIAS_CHOICES,
        default="affine",
        help="image-space bias model adjusted per image (default affine)",
    )
    parser.add_argument(
        "--method",
        choices=("lm", "gn"),
        default="lm",
        help="Levenberg-Marquardt (default) or Gauss-Newton",
    )
    parser.add_argument(
        "--loss",
        choices=LOSSES,
        default="cauchy",
        help="loss on image observations and GCP coordinates (default cauchy, IRLS)",
    )
    parser.add_argument(
        "--loss-scale",
        type=float,
        default=3.0,
        metavar="C",
        help="robust loss threshold in a priori sigmas (default 3)",
    )
    parser.add_argument(
        "--keep-blunders",
        action="store_true",
        help="flag gross errors (w-test) but do not remove them and re-solve",
    )
    parser.add_argument(
        "--bias-prior-shift-px",
        type=float,
        metavar="S",
        help="prior sigma (px) of every image's bias shift (fixes what GCPs and ties leave open)",
    )
    parser.add_argument(
        "--bias-prior-matrix",
        type=float,
        metavar="M",
        help="prior sigma (px/px) of the affine matrix (or shift-drift drift) terms",
    )
    parser.add_argument(
        "--dem",
        metavar="FILE",
        help="tie heights from a single-band DEM raster (ellipsoidal m, any CRS), as height "
        "observations of the tie points (fixes what the ties leave open against their heights)",
    )
    parser.add_argument(
        "--dem-offset-m",
        type=float,
        default=0.0,
        metavar="N",
        help="added to the DEM heights (e.g. the geoid undulation for orthometric DEMs)",
    )
    parser.add_argument(
        "--tie-height-sigma-m",
        type=float,
        default=10.0,
        metavar="M",
        help="sigma of the DEM tie heights (m, default 10)",
    )
    parser.add_argument("--max-steps", type=int, default=100, help="solver steps (default 100)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--out", metavar="DIR", help="write adjusted models and the report here")
    parser.add_argument(
        "--rpc-format",
        choices=("txt", "rpb", "geom", "dimap"),
        default="txt",
        help="adjusted RPC per image in --out, named after the image: <stem>_RPC.TXT (default), "
        "<stem>.RPB, OSSIM <stem>.geom or DIMAP v2 RPC_<stem>.XML",
    )
    parser.add_argument(
        "--copy-images",
        action="store_true",
        help="also copy each image into --out beside its adjusted RPC (GDAL then opens the copy "
        "with the adjusted model)",
    )
    parser.add_argument(
        "--write-into",
        action="store_true",
        help="write each adjusted RPC into the tags of a copy of its GeoTIFF in --out",
    )
    parser.add_argument(
        "--overwrite",
        action="store_true",
        help="replace earlier outputs in --out (never the inputs)",
    )
    parser.set_defaults(func=run)


def _images(specs: list[str]) -> dict[str, str]:
    from . import CommandError

    out: dict[str, str] = {}
    for spec in specs:
        name, sep, path = spec.partition("=")
        if not sep or not name or not path:
            raise CommandError(f"--image {spec!r}: expected NAME=RPCFILE")
        if name in out:
            raise CommandError(f"--image {name!r} given twice")
        out[name] = path
    return out


def run(args: argparse.Namespace) -> int:
    import json
    import pathlib
    import sys
    import warnings

    from .. import bundle
    from ..bundle import NotConvergedWarning, PoorFitWarning, check_out_dir
    from ..lsq import SolverConfig
    from . import CommandError

    images = _images(args.image)
    if args.dem_offset_m and not args.dem:
        raise CommandError("--dem-offset-m applies to --dem heights only")
    if not (args.tie_height_sigma_m > 0 and args.tie_height_sigma_m < float("inf")):
        raise CommandError(f"--tie-height-sigma-m must be positive, got {args.tie_height_sigma_m}")
    solver = SolverConfig(
        method=args.method,
        loss=args.loss,
        loss_scale=args.loss_scale,
        max_steps=args.max_steps,
        remove_blunders=not args.keep_blunders,
    )
    if args.out:  # before any computation
        inputs = [*images.values(), args.observations] + ([args.ground] if args.ground else [])
        inputs += [args.dem] if args.dem else []
        try:
            check_out_dir(
                args.out, images, inputs, overwrite=args.overwrite, rpc_format=args.rpc_format,
                copy_images=args.copy_images, write_into=args.write_into,
            )  # fmt: skip
        except (OSError, ValueError) as err:
            raise CommandErrorOut(str(err)) from None
    dem = None
    if args.dem:
        from ..io import read_dem

        dem = read_dem(args.dem, offset_m=args.dem_offset_m)
        if dem.vertical_crs and not args.dem_offset_m:
            print(f"jaxgeo adjust: note: {args.dem} declares vertical CRS {dem.vertical_crs!r}; "
                  "heights are used as ellipsoidal", file=sys.stderr)  # fmt: skip
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        run = bundle.adjust_files(
            images, args.observations, args.ground, bias=args.bias, solver=solver,
            bias_prior_shift_px=args.bias_prior_shift_px,
            bias_prior_matrix=args.bias_prior_matrix, dem=dem,
            tie_height_sigma_m=args.tie_height_sigma_m,
        )  # fmt: skip
    poor = False
    for w in caught:
        poor |= issubclass(w.category, PoorFitWarning)
        warn = issubclass(w.category, (NotConvergedWarning, PoorFitWarning))
        print(f"jaxgeo adjust: {'warning' if warn else 'note'}: {w.message}", file=sys.stderr)
    data = run.summary()
    if not args.json:
        print(run.format(), flush=True)  # the report first: a failed write cannot lose it
    if args.out:
        rpc_options = dict(images=images, rpc_format=args.rpc_format,
                           copy_images=args.copy_images, write_into=args.write_into)  # fmt: skip
        try:
            written = run.write(args.out, overwrite=args.overwrite, **rpc_options)
        except OSError as err:
            if args.json:
                print(json.dumps(data, indent=1))
            print(f"jaxgeo adjust: error: writing --out failed: {err}", file=sys.stderr)
            return 4
        data["written"] = [str(p) for p in written]
        report = json.loads((pathlib.Path(args.out) / "report.json").read_text())
        data["rpc_files"] = report.get("rpc_files", {})  # per image: exact or refit + error
    if args.json:
        print(json.dumps(data, indent=1))
    elif args.out:
        print(f"\nwrote {len(data['written'])} files to {args.out}")
        for name, info in data["rpc_files"].items():
            err = (
                f", max refit error {info['max_error_px']:.3g} px" if info["how"] == "refit" else ""
            )
            print(f"  {name}: RPC {info['how']}{err}: {', '.join(info.get('files', []))}")
    if not run.result.converged:
        return 1
    return 3 if poor else 0


def CommandErrorOut(message: str):  # noqa: N802 - an error factory
    from . import CommandError

    return CommandError(f"--out: {message}")
