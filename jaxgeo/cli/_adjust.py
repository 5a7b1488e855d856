"""``jaxgeo adjust``: bundle block adjustment of RPC images with bias compensation.

    jaxgeo adjust IMG [IMG ...] | --image NAME=FILE [--image ...] [--model IMG=FILE]
                  [--image-origin IMG=C,R]
                  --observations OBS.csv [--ground GROUND.csv] [--bias KIND]
                  [--bias-prior-shift-px S --bias-prior-matrix M]
                  [--dem FILE [--dem-height H] [--geoid G] [--dem-offset-m N]]
                  [-o DIR [--overwrite]] [--json] [--quiet]

The images are named by their file stem (as ``jaxgeo match`` writes them in OBS.csv), as in
every command, or by ``--image NAME=FILE`` where a name differs from the stem. IMG or FILE is
the image raster (its RPC in its tags or an .RPB/_RPC.TXT sidecar; ``--model`` names
another model file, ``--image-origin`` a crop's origin in the model's frame when the raster
does not carry it; IMG there is the image's name, its file name or its stem) or a model file
alone. With a raster, every measurement must lie inside it;
with a model file alone, inside the RPC's image domain. GROUND.csv:
``id,lon,lat,h,role[,sigma_e_m,sigma_n_m,sigma_h_m]`` (role gcp or check); OBS.csv:
``id,image,x,y[,sigma_px]`` in the image's pixels; points in OBS but not in GROUND are tie
points. Without any GCP the adjustment is a relative orientation: the biases are held by priors
(10 px, 1e-4 px/px unless given). The report compares direct georeferencing (the given models,
no GCP) with the adjustment, as tables 3 and 4 of 000_5aba1cb50921f3c6.txt.

``-o DIR`` writes the adjusted models (per image an RPC where GDAL finds it for that image:
``<image stem>_RPC.TXT`` or as ``--rpc-format`` says, beside a copy of the image with
``--copy-images`` or in a copied GeoTIFF's tags with ``--write-into``; the bias folded in exactly
where it can be, else refitted with the refit error reported; an image given as a raster gets an
RPC in that raster's pixels, the one GDAL needs for it), a JSON with RPC + bias + sigmas, the
adjusted points, the residuals and the report. Every output is checked before any computation;
no input is ever replaced (``--overwrite`` replaces earlier outputs only); the report is printed
before anything is written.

``--bias jitter`` adds to the affine bias offsets along the lines (a spline with a knot every
``--jitter-knot-lines``, by default chosen per image from its lines and measurements, held
smooth by ``--jitter-smoothness-px`` and each coefficient by ``--jitter-knot-sigma-px``; the
report states the knots and these priors) for attitude jitter; the RPC written holds the
affine part and ``<image>_jitter.csv`` the rest (``image = RPC(ground) + (dx, dy)`` at the
RPC's line).

Gross errors: by default the image observations and GCP coordinates get a Cauchy loss at 3 a
priori sigmas (IRLS), then data snooping (Baarda's w-test, iterated) removes the flagged
observations and re-solves (``--keep-blunders``: flag only). Snooping removes at most
max(1, 20 %) of the GCPs and of each image's observations: more "gross errors" than that are
models that do not fit their images (swapped RPC files, a model of another image), which the
command declares (warning, exit 3) rather than cut away. Without GCPs, tie points fit almost any
models; the block's geometry then decides (tie heights outside the models' validity range or the
DEM's, rays that do not meet with the given models, biases far beyond their priors: warning,
exit 3). Check-point statistics are given for all check points and for those without a flagged
observation.

The options shared with ``jaxgeo strip`` are defined once (:mod:`._adjustment_options`); the
command parses, calls :func:`jaxgeo.bundle.adjust_files` and prints.
"""

from __future__ import annotations

import argparse
import json
import pathlib

EXIT_CODES = {
    0: "adjusted (gross errors, if any, removed and listed)",
    1: "the solve did not converge (the last state is reported and written)",
    3: "the observations do not fit the models (s0 > 3, or more gross errors than snooping\n"
    "       may remove; without GCPs, tie heights outside the models' or the DEM's range,\n"
    "       rays that do not meet, biases far beyond their priors; converged or not): the\n"
    "       warning names the images (e.g. swapped RPCs)",
    4: "the adjustment ran but -o/--out could not be written (the report is printed first)",
}


def register(sub) -> None:
    from ..bundle.internal import BIAS_CHOICES
    from ._adjustment_options import add_adjustment_options, add_jitter_options
    from ._common import add_command
    from ._inputs import add_image_options
    from ._report_option import add_report

    parser = add_command(sub, "adjust", "bundle block adjustment of RPC images (bias "
                         "compensation)", __doc__, EXIT_CODES)  # fmt: skip
    parser.add_argument("images", nargs="*", metavar="IMG",
                        help="the images: rasters (RPC in their tags or sidecar) or model "
                        "files, named by their file stem as in OBS.csv")  # fmt: skip
    parser.add_argument("--image", action="append", default=[], metavar="NAME=FILE",
                        help="an image named otherwise than its file stem: its name (as in "
                        "OBS.csv) and its raster or model file; repeat per image")  # fmt: skip
    add_image_options(parser)
    add_adjustment_options(
        parser,
        tables_required=True,
        bias_choices=BIAS_CHOICES,
        bias_help="image-space bias model adjusted per image (default affine; jitter: affine "
        "plus smooth offsets along the lines, for attitude jitter, from dense ties); without "
        "GCPs the bias priors default to a relative orientation's",
        tie_height_sigma_m=10.0,
    )
    add_jitter_options(parser)
    add_report(parser, "report.html in -o DIR")
    parser.add_argument("--copy-images", action="store_true", help="also copy each image into "
                        "--out beside its adjusted RPC (GDAL then opens the copy with the "
                        "adjusted model)")  # fmt: skip
    parser.add_argument("--write-into", action="store_true", help="write each adjusted RPC "
                        "into the tags of a copy of its GeoTIFF in --out")  # fmt: skip
    parser.set_defaults(func=run)


def _images(files: list[str], specs: list[str]) -> dict[str, str]:
    """Image name -> file: each IMG named by its stem, each ``--image NAME=FILE`` by NAME."""
    from . import CommandError
    from ._common import path_or_url

    named = [(path_or_url(f).stem, f, f"image {f}") for f in files]  # a URL: no query string
    for spec in specs:
        name, sep, path = spec.partition("=")
        if not sep or not name or not path:
            raise CommandError(f"--image {spec!r}: expected NAME=FILE (a raster or model file)")
        named.append((name, path, f"--image {spec}"))
    if not named:
        raise CommandError("give the images: IMG ... (named by their file stem) or --image "
                           "NAME=FILE")  # fmt: skip
    out: dict[str, str] = {}
    for name, path, given in named:
        if name in out:
            raise CommandError(f"{given}: image {name!r} given twice (images are named by their "
                               "file stem; --image NAME=FILE names one otherwise)")  # fmt: skip
        out[name] = path
    return out


def open_named_images(args: argparse.Namespace) -> dict:
    """Image name -> :class:`~jaxgeo.io.SensorImage` from ``--image``, ``--model`` and
    ``--image-origin`` (their IMG: the image name of ``--image``, its file name or stem)."""
    from ..bundle.internal import sensor_image
    from . import CommandError
    from ._inputs import image_settings

    files = _images(args.images, args.image)
    alias = {
        a: n for n, f in files.items() for a in (f, pathlib.Path(f).name, pathlib.Path(f).stem)
    }
    alias.update({n: n for n in files})

    def named(specs):  # IMG=... with IMG a file name or stem -> the image's name
        return [
            f"{alias.get(k, k)}={v}" if s else k for k, s, v in (x.partition("=") for x in specs)
        ]

    specs = argparse.Namespace(model=named(args.model), image_origin=named(args.image_origin))
    models, origins = image_settings(specs, list(files))
    try:
        return {n: sensor_image(n, f, models.get(n), origins.get(n)) for n, f in files.items()}
    except FileNotFoundError as err:
        raise CommandError(f"--image: {err}") from None
    except ValueError as err:
        if "separate model file" not in str(err):
            raise
        raise CommandError(f"--model: {err}") from None


def run(args: argparse.Namespace) -> int:
    from .. import bundle
    from ..bundle import AdjustSettings
    from ..bundle.internal import check_out_dir, image_inputs
    from ..lsq.internal import DEFAULT_SOLVER
    from . import _adjustment_options as shared
    from ._common import note, print_json
    from ._inputs import dem_inputs
    from ._report_option import report_target

    start = shared.Start("adjust", args)
    shared.check_adjustment_options(args)
    jitter = shared.jitter_settings(args)
    solver = shared.solver_config(args, DEFAULT_SOLVER)
    images = open_named_images(args)
    sources = {name: img.path or img.model_path for name, img in images.items()}
    inputs = [p for img in images.values() for p in image_inputs(img)] + dem_inputs(args)
    inputs += [args.observations] + ([args.ground] if args.ground else [])
    rpc = dict(rpc_format=args.rpc_format, copy_images=args.copy_images, write_into=args.write_into)
    if args.out:  # before any computation
        with shared.out_checked():
            check_out_dir(args.out, sources, inputs, overwrite=args.overwrite, **rpc)
    page = report_target(args, inputs, folder=True)
    settings = AdjustSettings(
        bias_prior_shift_px=args.bias_prior_shift_px, bias_prior_matrix=args.bias_prior_matrix,
        jitter=jitter, tie_height=shared.tie_dem(args), tie_height_sigma_m=args.tie_height_sigma_m,
        progress=start.say,
    )  # fmt: skip
    if args.dem is not None and args.bias == "jitter":  # even with --quiet: it decides the DSM
        note(f"jaxgeo adjust: note: with --bias jitter the heights of {args.dem} fix the along-"
             "track jitter the ties leave open: the DEM's own errors at the jitter's scale go "
             "into the models (use a DEM more accurate than the corrugation to remove: "
             "docs/getting-started.md, jitter)")  # fmt: skip
    with start.warnings_printed():
        run = bundle.adjust_files(images, args.observations, args.ground, bias=args.bias,
                                  solver=solver, settings=settings)  # fmt: skip
    for line in run.notes if args.json else ():  # (the text report holds them)
        start.say(f"note: {line}")
    if not args.json:
        print(run.format(), flush=True)  # the report first: a failed write cannot lose it
    data = run.summary()
    code = start.exit_code(run.result.converged, bool(run.result.poor_fit))
    if args.out:
        start.say(f"writing {args.out}")
        try:
            data["written"] = [str(p) for p in run.write(args.out, args.overwrite, **rpc)]
        except (OSError, ValueError) as err:
            return start.write_failed(err, data)
        report = json.loads((pathlib.Path(args.out) / "report.json").read_text())
        data["rpc_files"] = report.get("rpc_files", {})  # per image: exact or refit + error
    if page is not None:
        from ..report import write_adjustment_report

        start.say(f"writing {page}")
        data["written"].append(str(write_adjustment_report(run, page, overwrite=args.overwrite)))
    data["exit_status"] = code
    if args.json:
        print_json(data)
    elif args.out:
        print(f"\nwrote {len(data['written'])} files to {args.out}")
        for name, info in data["rpc_files"].items():
            err = (
                f", max refit error {info['max_error_px']:.3g} px" if info["how"] == "refit" else ""
            )
            print(f"  {name}: RPC {info['how']}{err}: {', '.join(info.get('files', []))}")
    return code
