"""``jaxgeo adjust``: bundle block adjustment of RPC images with bias compensation.

    jaxgeo adjust --image NAME=FILE [--image ...] [--model NAME=FILE] [--image-origin NAME=C,R]
                  --observations OBS.csv [--ground GROUND.csv] [--bias KIND]
                  [--bias-prior-shift-px S --bias-prior-matrix M] [--dem FILE]
                  [-o DIR [--overwrite]] [--json] [--quiet]

FILE is the image raster (its RPC in its tags or an .RPB/_RPC.TXT sidecar; ``--model`` names
another model file, ``--image-origin`` a crop's origin in the model's frame when the raster
does not carry it) or a model file alone. With a raster, every measurement must lie inside it;
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
``--jitter-knot-lines``, held smooth by ``--jitter-smoothness-px``) for attitude jitter; the
RPC written holds the affine part and ``<image>_jitter.csv`` the rest (``image = RPC(ground) +
(dx, dy)`` at the RPC's line).

Gross errors: by default the image observations and GCP coordinates get a Cauchy loss at 3 a
priori sigmas (IRLS), then data snooping (Baarda's w-test, iterated) removes the flagged
observations and re-solves (``--keep-blunders``: flag only). Snooping removes at most
max(1, 20 %) of the GCPs and of each image's observations: more "gross errors" than that are
models that do not fit their images (swapped RPC files, a model of another image), which the
command declares (warning, exit 3) rather than cut away. Check-point statistics are given for all
check points and for those without a flagged observation.
"""

from __future__ import annotations

import argparse

EXIT_CODES = {
    0: "adjusted (gross errors, if any, removed and listed)",
    1: "the solve did not converge (the last state is reported and written)",
    3: "the observations do not fit the models (s0 > 3, or more gross errors than snooping\n"
    "       may remove; converged or not): the warning names the images (e.g. swapped RPCs)",
    4: "the adjustment ran but -o/--out could not be written (the report is printed first)",
}


def register(sub) -> None:
    from ..bundle import (
        BIAS_CHOICES,
        RELATIVE_PRIOR_MATRIX,
        RELATIVE_PRIOR_SHIFT_PX,
        JitterSettings,
    )
    from ..lsq import LOSSES
    from ._common import add_command, add_image_options, add_json, add_quiet

    parser = add_command(
        sub,
        "adjust",
        "bundle block adjustment of RPC images (bias compensation)",
        __doc__,
        EXIT_CODES,
    )
    parser.add_argument(
        "--image",
        action="append",
        required=True,
        metavar="NAME=FILE",
        help="an image name (as in OBS.csv) and its raster (RPC in its tags or sidecar) or "
        "model file; repeat per image",
    )
    add_image_options(parser)
    parser.add_argument(
        "--observations", required=True, metavar="OBS.csv", help="image measurements"
    )
    parser.add_argument("--ground", metavar="GROUND.csv", help="GCPs and check points")
    parser.add_argument(
        "--bias",
        choices=BIAS_CHOICES,
        default="affine",
        help="image-space bias model adjusted per image (default affine; jitter: affine plus "
        "smooth offsets along the lines, for attitude jitter, from dense ties)",
    )
    parser.add_argument(
        "--jitter-knot-lines",
        type=float,
        default=JitterSettings().knot_lines,
        metavar="N",
        help=f"--bias jitter: a spline knot every N lines (default {JitterSettings().knot_lines:g};"
        " about an eighth of the shortest jitter period to follow)",
    )
    parser.add_argument(
        "--jitter-smoothness-px",
        type=float,
        default=JitterSettings().smoothness_px,
        metavar="S",
        help="--bias jitter: prior sigma (px) of the spline's second differences (default "
        f"{JitterSettings().smoothness_px:g}; smaller is smoother)",
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
        help="prior sigma (px) of every image's bias shift (fixes what GCPs and ties leave "
        f"open; default none, {RELATIVE_PRIOR_SHIFT_PX:g} without GCPs)",
    )
    parser.add_argument(
        "--bias-prior-matrix",
        type=float,
        metavar="M",
        help="prior sigma (px/px) of the affine matrix (or shift-drift drift) terms (default "
        f"none, {RELATIVE_PRIOR_MATRIX:g} without GCPs)",
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
    parser.add_argument(
        "--max-steps", type=int, default=100, metavar="N", help="solver steps (default 100)"
    )
    parser.add_argument(
        "-o",
        "--out",
        metavar="DIR",
        help="write the adjusted models, points, residuals and report into this folder "
        "(created if needed; default: print the report only)",
    )
    parser.add_argument(
        "--overwrite",
        action="store_true",
        help="replace earlier outputs in -o/--out (an input is never replaced)",
    )
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
    add_json(parser)
    add_quiet(parser)
    parser.set_defaults(func=run)


def _images(specs: list[str]) -> dict[str, str]:
    from . import CommandError

    out: dict[str, str] = {}
    for spec in specs:
        name, sep, path = spec.partition("=")
        if not sep or not name or not path:
            raise CommandError(f"--image {spec!r}: expected NAME=FILE (a raster or model file)")
        if name in out:
            raise CommandError(f"--image {name!r} given twice")
        out[name] = path
    return out


def open_named_images(args: argparse.Namespace) -> dict:
    """Image name -> :class:`~jaxgeo.io.SensorImage` from ``--image``, ``--model`` and
    ``--image-origin`` (NAME is the image name of ``--image``)."""
    import pathlib

    from ..io import detect_rpc_format, open_image
    from . import CommandError
    from ._common import image_settings

    files = _images(args.image)
    models, origins = image_settings(args, list(files))
    images = {}
    for name, file in files.items():
        path = pathlib.Path(file)
        if not path.is_file():
            what = "is not a file" if path.exists() else "no such file"
            raise CommandError(f"--image {name}={file}: {what}")
        raster = detect_rpc_format(path) == "raster"
        if name in models and not raster:
            raise CommandError(
                f"--model {name}={models[name]}: image {name!r} is given as a model file "
                f"({file}); give its raster with --image {name}=RASTER, or drop --model"
            )
        if raster:
            img = open_image(path, model=models.get(name), origin=origins.get(name), name=name)
        else:
            img = open_image(model=path, origin=origins.get(name), name=name)
        images[name] = img
    return images


def _check_out(args, images, inputs) -> None:
    """Before any computation: every file ``-o DIR`` will get is not an input (whatever
    ``--overwrite``), does not exist unless ``--overwrite``, and can be written."""
    import os
    import pathlib

    from ..bundle import check_out_dir, output_paths
    from . import CommandError
    from ._common import guard_outputs

    out = pathlib.Path(args.out)
    options = dict(rpc_format=args.rpc_format, copy_images=args.copy_images,
                   write_into=args.write_into)  # fmt: skip
    try:
        check_out_dir(out, images, inputs, overwrite=args.overwrite, **options)
        if out.is_dir():
            guard_outputs(output_paths(out, images, **options), inputs, args.overwrite)
    except CommandError as err:
        raise CommandError(f"-o/--out: {err}") from None
    except (OSError, ValueError) as err:
        text = err.strerror if isinstance(err, OSError) and err.strerror else str(err)
        where = f"{err.filename}: " if getattr(err, "filename", None) else ""
        raise CommandError(f"-o/--out: {where}{text}") from None
    if not out.exists() and not os.access(_existing_parent(out), os.W_OK | os.X_OK):
        raise CommandError(f"-o/--out: {out}: cannot be created (not writable)")


def _existing_parent(path):
    while not path.exists() and path != path.parent:
        path = path.parent
    return path


def run(args: argparse.Namespace) -> int:
    import json
    import pathlib
    import warnings

    from .. import bundle
    from ..bundle import JitterSettings, NotConvergedWarning, PoorFitWarning, image_inputs
    from ..lsq import SolverConfig
    from . import CommandError
    from ._common import (
        EXIT_NOT_CONVERGED,
        EXIT_OK,
        EXIT_POOR_FIT,
        EXIT_WRITE,
        note,
        ours,
        print_json,
    )

    def say(line: str) -> None:
        note(f"jaxgeo adjust: {line}", args.quiet)

    if args.dem_offset_m and not args.dem:
        raise CommandError("--dem-offset-m applies to --dem heights only")
    if not (args.tie_height_sigma_m > 0 and args.tie_height_sigma_m < float("inf")):
        raise CommandError(f"--tie-height-sigma-m must be positive, got {args.tie_height_sigma_m}")
    for flag, value in (("--jitter-knot-lines", args.jitter_knot_lines),
                        ("--jitter-smoothness-px", args.jitter_smoothness_px)):  # fmt: skip
        if not (0 < value < float("inf")):
            raise CommandError(f"{flag} must be a positive number, got {value}")
    if args.max_steps < 1:
        raise CommandError(f"--max-steps must be at least 1, got {args.max_steps}")
    for flag, value in (("--bias-prior-shift-px", args.bias_prior_shift_px),
                        ("--bias-prior-matrix", args.bias_prior_matrix)):  # fmt: skip
        if value is not None and not (0 < value < float("inf")):
            raise CommandError(f"{flag} must be a positive number, got {value}")
    solver = SolverConfig(
        method=args.method,
        loss=args.loss,
        loss_scale=args.loss_scale,
        max_steps=args.max_steps,
        remove_blunders=not args.keep_blunders,
    )
    images = open_named_images(args)
    if args.copy_images or args.write_into:
        from ..io import pixel_frame

        for name, img in images.items():
            if img.path is not None and pixel_frame(img.path) != (0.0, 0.0):
                raise CommandError(
                    f"--copy-images/--write-into: image {name!r} ({img.path}) is a crop whose "
                    "geotransform puts it in its product's frame; a copy would carry that frame "
                    "and an RPC already in the crop's pixels (read shifted by tools that apply "
                    "the frame): write the RPC files only"
                )
    sources = {name: img.path or img.model_path for name, img in images.items()}
    inputs = [p for img in images.values() for p in image_inputs(img)]
    inputs += [args.observations] + ([args.ground] if args.ground else [])
    inputs += [args.dem] if args.dem else []
    if args.out:  # before any computation
        _check_out(args, sources, inputs)
    dem = None
    if args.dem:
        from ..io import read_dem

        dem = read_dem(args.dem, offset_m=args.dem_offset_m)
        if dem.vertical_crs and not args.dem_offset_m:
            say(f"note: {args.dem} declares vertical CRS {dem.vertical_crs!r}; heights are used "
                "as ellipsoidal")  # fmt: skip
        if args.bias == "jitter":  # printed even with --quiet: it decides what the DSM gets
            note(f"jaxgeo adjust: note: with --bias jitter the heights of {args.dem} fix the "
                 "along-track jitter the ties leave open: the DEM's own errors at the jitter's "
                 "scale go into the models (use a DEM more accurate than the corrugation to "
                 "remove: docs/getting-started.md, jitter)")  # fmt: skip
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        run = bundle.adjust_files(
            images, args.observations, args.ground, bias=args.bias, solver=solver,
            bias_prior_shift_px=args.bias_prior_shift_px,
            bias_prior_matrix=args.bias_prior_matrix, dem=dem,
            tie_height_sigma_m=args.tie_height_sigma_m, progress=say,
            jitter=JitterSettings(args.jitter_knot_lines, args.jitter_smoothness_px),
        )  # fmt: skip
    for w in ours(caught):  # warnings are printed even with --quiet
        warn = issubclass(w.category, (NotConvergedWarning, PoorFitWarning))
        note(f"jaxgeo adjust: {'warning' if warn else 'note'}: {w.message}")
    if args.json:  # (the text report holds them)
        for line in run.notes:
            say(f"note: {line}")
    data = run.summary()
    if not args.json:
        print(run.format(), flush=True)  # the report first: a failed write cannot lose it
    code = EXIT_OK
    if run.result.poor_fit:  # the misfit first: a solve it drove off does not converge either
        code = EXIT_POOR_FIT
    elif not run.result.converged:
        code = EXIT_NOT_CONVERGED
    if args.out:
        say(f"writing {args.out}")
        rpc_options = dict(rpc_format=args.rpc_format, copy_images=args.copy_images,
                           write_into=args.write_into)  # fmt: skip
        try:
            written = run.write(args.out, overwrite=args.overwrite, **rpc_options)
        except (OSError, ValueError) as err:
            if args.json:
                print_json(data)
            note(f"jaxgeo adjust: error: writing -o/--out failed: {err}")
            return EXIT_WRITE
        data["written"] = [str(p) for p in written]
        report = json.loads((pathlib.Path(args.out) / "report.json").read_text())
        data["rpc_files"] = report.get("rpc_files", {})  # per image: exact or refit + error
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
