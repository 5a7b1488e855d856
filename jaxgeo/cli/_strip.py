"""``jaxgeo strip``: two-level full-strip adjustment of the sub-scenes of a strip (003_).

    jaxgeo strip STRIP [--ground CSV] [--observations CSV] [--ties-per-pair N]
                 [--tie-height M | --dem FILE] [--bias affine|shift-drift|shift]
                 [--degree quadratic|affine|shift] [--loss l2|huber|cauchy]
                 [--loss-scale C] [--keep-blunders] [--json] [--quiet]
                 [-o DIR [--rpc-format txt|rpb|geom|dimap]] [--overwrite]

STRIP is a folder holding ``strip.json`` (or the json file itself; see
:func:`jaxgeo.strip.read_strip`) with the sub-scenes' vendor RPCs, ``ground.csv`` and
``observations.csv`` beside it, as ``jaxgeo simulate carto2s-strip`` writes them. Level 1 forms
tie points in the overlaps of adjacent sub-scenes and bundle-adjusts an image bias per
sub-scene with the ties and the GCPs; level 2 fits one universal lat/lon correction to the GCPs
and applies it to every sub-scene (003_a7d3ea260371d8c5.txt sections 6-9). The report gives,
per sub-scene, the check-point RMS (east/north m) of the vendor RPCs (``direct``), after level 1
and after level 2, and per adjacent pair the gap between a tie localised in one sub-scene and in
the other. ``-o/--out DIR`` writes one RPC per sub-scene refitted to its final model
(``NAME_RPC.TXT`` or ``NAME.RPB``), ``report.json`` and ``report.txt``; every destination is
checked before any computation, inputs (strip.json, the RPC files, the tables, the DEM) are
never replaced and earlier outputs only with ``--overwrite``; the report is printed before
anything is written. Progress goes to stderr (``--quiet``: none).

Gross errors, as ``jaxgeo adjust``: by default a Cauchy loss at 3 a priori sigmas (``--loss``,
``--loss-scale``; IRLS) at both levels, then data snooping (Baarda's w-test with redundancy
numbers, iterated) removes the flagged observations and re-solves (``--keep-blunders``: flag
only); the report lists them (level, point, sub-scene, w). A sub-scene whose line offset is
wrong shows at its seams (the vendor RPCs disagree at its formed ties) and is named in a
warning: its bias would absorb it silently.

The command parses, builds a :class:`jaxgeo.strip.StripConfig`, calls the library and prints;
the checks and their messages are the library's (settings named by their flags, :data:`FLAGS`).
"""

from __future__ import annotations

import argparse

EXIT_CODES = {
    0: "adjusted (gross errors, if any, removed and listed)",
    1: "the level-1 bundle adjustment did not converge (the last state is reported)",
    3: "the observations do not fit the models (s0 > 3, or more gross errors than snooping\n"
    "       may remove; converged or not): the warning names the sub-scenes",
    4: "the adjustment ran but -o/--out could not be written (the report is printed first)",
}


def _flag(name: str):
    """Name a :class:`jaxgeo.strip.Setting` by its flag (with the value a message proposes)."""
    return lambda s: f"{name} {s.value}" if s.has_value and not isinstance(s.value, bool) else name


FLAGS = {
    "ties.per_pair": _flag("--ties-per-pair"),
    "ties.margin_px": _flag("--tie-margin-px"),
    "ties.sigma_px": _flag("--tie-sigma-px"),
    "ties.height": _flag("--tie-height"),
    "ties.height_sigma_m": _flag("--tie-height-sigma-m"),
    "level1.bias": _flag("--bias"),
    "level1.use_gcps": _flag("--ties-only-level1"),
    "level1.bias_prior_shift_px": _flag("--bias-prior-shift-px"),
    "level1.bias_prior_matrix": _flag("--bias-prior-matrix"),
    "level2.degree": _flag("--degree"),
    "refit.grid": _flag("--rpc-grid"),
    "rpc_format": _flag("--rpc-format"),
    "out": _flag("--out"),
    "overwrite": _flag("--overwrite"),
}
"""Library setting (:class:`jaxgeo.strip.Setting` path) -> how this command names it."""


def register(sub) -> None:
    from ..lsq import LOSSES
    from ..models import BIAS_KINDS
    from ..strip import (
        DEGREES,
        STRIP_SOLVER,
        SUFFIX,
        Level1Config,
        Level2Config,
        RefitConfig,
        TieConfig,
    )
    from ._common import add_command, add_json, add_quiet

    ties0, level1, refit0 = TieConfig(), Level1Config(), RefitConfig()
    parser = add_command(
        sub,
        "strip",
        "two-level full-strip adjustment of a Carto-2S-style strip of sub-scenes",
        __doc__,
        EXIT_CODES,
    )
    parser.add_argument("strip", metavar="STRIP", help="strip folder or its strip.json")
    parser.add_argument("--ground", metavar="CSV", help="GCPs/check points (default ground.csv)")
    parser.add_argument(
        "--observations", metavar="CSV", help="image measurements (default observations.csv)"
    )
    ties = parser.add_argument_group("level 1: tie points and biases")
    ties.add_argument("--ties-per-pair", type=int, default=ties0.per_pair, metavar="N",
                      help=f"ties formed per adjacent pair (default {ties0.per_pair})")  # fmt: skip
    ties.add_argument("--tie-margin-px", type=float, default=ties0.margin_px, metavar="PX",
                      help=f"ties kept this far inside each overlap (px, default "
                      f"{ties0.margin_px:g})")  # fmt: skip
    ties.add_argument("--tie-sigma-px", type=float, default=ties0.sigma_px, metavar="PX",
                      help=f"a priori tie sigma (px, default {ties0.sigma_px:g})")  # fmt: skip
    height = ties.add_mutually_exclusive_group()
    height.add_argument(
        "--tie-height",
        type=float,
        metavar="M",
        help="one ellipsoidal height (m) for all ties (default: mean GCP/check height)",
    )
    height.add_argument(
        "--dem",
        metavar="FILE",
        help="tie heights from a single-band DEM raster (ellipsoidal m, any CRS)",
    )
    ties.add_argument(
        "--dem-offset-m",
        type=float,
        default=0.0,
        metavar="N",
        help="added to the DEM heights (e.g. the geoid undulation for orthometric DEMs)",
    )
    ties.add_argument("--tie-height-sigma-m", type=float, default=ties0.height_sigma_m,
                      metavar="M", help="sigma of the tie height priors (m, default "
                      f"{ties0.height_sigma_m:g}; smaller with a good --dem)")  # fmt: skip
    ties.add_argument(
        "--bias",
        choices=tuple(BIAS_KINDS),
        default=level1.bias,
        help=f"image bias adjusted per sub-scene (default {level1.bias}, as in 003_)",
    )
    ties.add_argument(
        "--ties-only-level1",
        action="store_true",
        help="level 1 sees the ties only (the GCPs enter at level 2); needs the bias priors",
    )
    ties.add_argument(
        "--bias-prior-shift-px",
        type=float,
        metavar="S",
        help="prior sigma (px) of every sub-scene's bias shift",
    )
    ties.add_argument(
        "--bias-prior-matrix",
        type=float,
        metavar="X",
        help="prior sigma (px/px) of the affine matrix (or shift-drift drift) terms",
    )
    ties.add_argument(
        "--method",
        choices=("lm", "gn"),
        default="lm",
        help="level-1 solver: Levenberg-Marquardt (default) or Gauss-Newton",
    )
    ties.add_argument(
        "--max-steps", type=int, default=100, metavar="N", help="level-1 solver steps (100)"
    )
    gross = parser.add_argument_group("gross errors (both levels, as jaxgeo adjust)")
    gross.add_argument(
        "--loss",
        choices=LOSSES,
        default=STRIP_SOLVER.loss,
        help=f"loss on image measurements and GCP coordinates (default {STRIP_SOLVER.loss}, IRLS)",
    )
    gross.add_argument(
        "--loss-scale",
        type=float,
        default=STRIP_SOLVER.loss_scale,
        metavar="C",
        help=f"robust loss threshold in a priori sigmas (default {STRIP_SOLVER.loss_scale:g})",
    )
    gross.add_argument(
        "--keep-blunders",
        action="store_true",
        help="flag gross errors (w-test) but do not remove them and re-solve",
    )
    parser.add_argument(
        "--degree",
        choices=DEGREES,
        default=Level2Config().degree,
        help="level 2: the universal correction (default quadratic, eq. 12-13 of 003_; auto: "
        "the degree that best predicts each GCP scene left out)",
    )
    add_json(parser)
    add_quiet(parser)
    out = parser.add_argument_group("output")
    out.add_argument("-o", "--out", metavar="DIR",
                     help="write the updated RPCs and the report into this folder (created if "
                     "needed; default: print the report only)")  # fmt: skip
    out.add_argument(
        "--rpc-format",
        choices=tuple(SUFFIX),
        default="txt",
        help="updated RPC files as NAME_RPC.TXT (default), NAME.RPB, OSSIM NAME.geom or DIMAP v2 "
        "RPC_NAME.XML",
    )
    out.add_argument(
        "--rpc-grid",
        type=int,
        nargs=3,
        default=refit0.grid,
        metavar=("NX", "NY", "NH"),
        help="RPC refit grid: columns, rows, height layers (default %(default)s)",
    )
    out.add_argument(
        "--overwrite",
        action="store_true",
        help="replace earlier outputs in -o/--out (an input is never replaced)",
    )
    parser.set_defaults(func=run)


def strip_config(args: argparse.Namespace, tie_height=None):
    """The :class:`jaxgeo.strip.StripConfig` and :class:`~jaxgeo.strip.RefitConfig` of the
    arguments (``tie_height``: a DEM, else ``--tie-height``)."""
    import dataclasses

    from ..strip import (
        STRIP_SOLVER,
        Level1Config,
        Level2Config,
        RefitConfig,
        StripConfig,
        TieConfig,
    )

    ties = TieConfig(
        per_pair=args.ties_per_pair,
        margin_px=args.tie_margin_px,
        sigma_px=args.tie_sigma_px,
        height=args.tie_height if tie_height is None else tie_height,
        height_sigma_m=args.tie_height_sigma_m,
    )
    level1 = Level1Config(
        bias=args.bias,
        use_gcps=not args.ties_only_level1,
        bias_prior_shift_px=args.bias_prior_shift_px,
        bias_prior_matrix=args.bias_prior_matrix,
    )
    solver = dataclasses.replace(
        STRIP_SOLVER,
        method=args.method,
        max_steps=args.max_steps,
        loss=args.loss,
        loss_scale=args.loss_scale,
        remove_blunders=not args.keep_blunders,
    )
    strip = StripConfig(ties=ties, level1=level1, level2=Level2Config(args.degree), solver=solver)
    return strip, RefitConfig(grid=tuple(args.rpc_grid))


def run(args: argparse.Namespace) -> int:
    from ..strip import ConfigError
    from . import CommandError

    try:
        return _run(args)
    except ConfigError as err:
        raise CommandError(err.render(FLAGS)) from None


def _guard(args, strip, targets) -> None:
    """Before any computation: the outputs are no input (whatever ``--overwrite``), and the
    folder they go into is writable."""
    import os
    import pathlib
    import tempfile

    from . import CommandError
    from ._common import guard_outputs

    inputs = [*(strip.files.all() if strip.files is not None else ()),
              *([args.dem] if args.dem else [])]  # fmt: skip
    out = pathlib.Path(args.out)
    if out.is_dir():
        try:
            guard_outputs(targets.values(), inputs, args.overwrite)
        except CommandError as err:
            raise CommandError(f"-o/--out: {err}") from None
        return
    base = out
    while not base.exists() and base != base.parent:
        base = base.parent
    try:  # a folder made and removed: os.access says yes to root everywhere
        os.rmdir(tempfile.mkdtemp(prefix=".jaxgeo-probe-", dir=base))
    except OSError as err:
        raise CommandError(f"-o/--out: {out}: cannot be created ({base}: {err.strerror})") from None


def _run(args: argparse.Namespace) -> int:
    import sys
    import warnings

    from ..bundle import NotConvergedWarning, PoorFitWarning
    from ..io import read_dem
    from ..strip import (
        REFIT_WARN_PX,
        GCPDistributionWarning,
        LineOffsetWarning,
        MeasuredTieWarning,
        UniversalCorrectionWarning,
        adjust_strip,
        format_strip_result,
        read_strip,
        strip_output_paths,
        strip_summary,
        worst_refit,
        write_strip_outputs,
    )
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
        note(f"jaxgeo strip: {line}", args.quiet)

    if args.dem_offset_m and not args.dem:
        raise CommandError("--dem-offset-m applies to --dem heights only")
    config, refit = strip_config(args)  # checked before any work
    strip = read_strip(args.strip, args.ground, args.observations)
    targets = None
    if args.out:
        targets = strip_output_paths(strip, args.out, args.rpc_format, args.overwrite,
                                      [args.dem] if args.dem else [])  # fmt: skip
        _guard(args, strip, targets)
    if args.dem:
        dem = read_dem(args.dem, offset_m=args.dem_offset_m)
        if dem.vertical_crs and not args.dem_offset_m:
            say(f"note: {args.dem} declares vertical CRS {dem.vertical_crs!r}; heights are used "
                "as ellipsoidal")  # fmt: skip
        config, _ = strip_config(args, tie_height=dem)
    say(f"adjusting {len(strip.names)} sub-scenes: tie points, level-1 bundle adjustment and "
        "snooping, level-2 correction (the first run of a strip shape compiles, up to a "
        "minute)")  # fmt: skip
    poor = False
    caught = []
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            result = adjust_strip(strip, config)
    finally:  # the GCP distribution warning matters most when the adjustment fails
        for w in ours(caught):
            warns = (GCPDistributionWarning, UniversalCorrectionWarning, LineOffsetWarning,
                     NotConvergedWarning, PoorFitWarning, MeasuredTieWarning)  # fmt: skip
            kind = "warning" if issubclass(w.category, warns) else "note"
            poor |= issubclass(w.category, PoorFitWarning)
            print(f"jaxgeo strip: {kind}: {w.message}", file=sys.stderr)
    converged = bool(result.report.strip["converged"])
    if not converged:
        print("jaxgeo strip: warning: the level-1 bundle adjustment did not converge",
              file=sys.stderr)  # fmt: skip
    # the misfit first: a solve it drove off does not converge either
    code = EXIT_POOR_FIT if poor else EXIT_OK if converged else EXIT_NOT_CONVERGED
    if not args.json:
        print(format_strip_result(result), flush=True)  # the report first
    if targets is None:
        if args.json:
            print_json({**strip_summary(result), "exit_status": code})
        return code
    say(f"refitting {len(strip.names)} RPCs and writing {args.out}")
    try:
        data = write_strip_outputs(result, targets, refit, args.rpc_format, args.overwrite)
    except (OSError, ValueError) as err:
        if args.json:
            print_json({**strip_summary(result), "exit_status": EXIT_WRITE})
        note(f"jaxgeo strip: error: writing -o/--out failed: {err}")
        return EXIT_WRITE
    worst, px = worst_refit(data)
    if px > REFIT_WARN_PX:
        print(f"jaxgeo strip: warning: the refitted RPC of {worst} differs from its adjusted "
              f"model by up to {px:.3g} px on the check grid", file=sys.stderr)  # fmt: skip
    if args.json:
        print_json({**data, "exit_status": code})
    else:
        print(f"\nwrote {len(data['written'])} files to {args.out} (updated RPCs: refit "
              f"error <= {px:.2g} px on the check grid)")  # fmt: skip
    return code
