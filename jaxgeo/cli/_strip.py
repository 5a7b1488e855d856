"""``jaxgeo strip``: two-level full-strip adjustment of the sub-scenes of a strip (003_).

    jaxgeo strip STRIP [--ground CSV] [--observations CSV] [--ties-per-pair N]
                 [--tie-height M | --dem FILE [--dem-height H] [--geoid G]]
                 [--bias affine|shift-drift|shift]
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

The command parses, builds a :class:`jaxgeo.strip.StripConfig`, calls
:func:`jaxgeo.strip.adjust_strip_files` and prints; the checks and their messages are the
library's (settings named by their flags, :data:`FLAGS`); the options it shares with ``jaxgeo
adjust`` are defined once (:mod:`._adjustment_options`).
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
    from ..models.internal import BIAS_KINDS
    from ..strip import Level1Config, Level2Config, RefitConfig, TieConfig
    from ..strip.internal import DEGREES
    from ._adjustment_options import add_adjustment_options
    from ._common import add_command
    from ._report_option import add_report

    ties0, refit0 = TieConfig(), RefitConfig()
    parser = add_command(sub, "strip", "two-level full-strip adjustment of a Carto-2S-style "
                         "strip of sub-scenes", __doc__, EXIT_CODES)  # fmt: skip
    parser.add_argument("strip", metavar="STRIP", help="strip folder or its strip.json")
    add_adjustment_options(
        parser,
        tables_required=False,
        bias_choices=tuple(BIAS_KINDS),
        bias_help=f"image bias adjusted per sub-scene (default {Level1Config().bias}, as in 003_)",
        tie_height_sigma_m=ties0.height_sigma_m,
    )
    ties = parser.add_argument_group("level 1: tie points")
    ties.add_argument("--ties-per-pair", type=int, default=ties0.per_pair, metavar="N",
                      help=f"ties formed per adjacent pair (default {ties0.per_pair})")  # fmt: skip
    ties.add_argument("--tie-margin-px", type=float, default=ties0.margin_px, metavar="PX",
                      help=f"ties kept this far inside each overlap (px, default "
                      f"{ties0.margin_px:g})")  # fmt: skip
    ties.add_argument("--tie-sigma-px", type=float, default=ties0.sigma_px, metavar="PX",
                      help=f"a priori tie sigma (px, default {ties0.sigma_px:g})")  # fmt: skip
    ties.add_argument("--tie-height", type=float, metavar="M",
                      help="one ellipsoidal height (m) for all ties (default: mean GCP/check "
                      "height; not with --dem)")  # fmt: skip
    ties.add_argument("--ties-only-level1", action="store_true",
                      help="level 1 sees the ties only (the GCPs enter at level 2); needs the "
                      "bias priors")  # fmt: skip
    parser.add_argument("--degree", choices=DEGREES, default=Level2Config().degree,
                        help="level 2: the universal correction (default quadratic, eq. "
                        "12-13 of 003_; auto: the degree that best predicts each GCP scene "
                        "left out)")  # fmt: skip
    parser.add_argument("--rpc-grid", type=int, nargs=3, default=refit0.grid,
                        metavar=("NX", "NY", "NH"), help="RPC refit grid of -o/--out: columns, "
                        "rows, height layers (default %(default)s)")  # fmt: skip
    add_report(parser, "report.html in -o DIR")
    parser.set_defaults(func=run)


def strip_config(args: argparse.Namespace, dem=None):
    """The :class:`jaxgeo.strip.StripConfig` and :class:`~jaxgeo.strip.RefitConfig` of the
    arguments (tie heights from ``dem``, a :class:`~jaxgeo.io.DEM`, else ``--tie-height``)."""
    from .. import strip as lib
    from ..strip.internal import STRIP_SOLVER
    from ._adjustment_options import solver_config

    ties = lib.TieConfig(
        per_pair=args.ties_per_pair,
        margin_px=args.tie_margin_px,
        sigma_px=args.tie_sigma_px,
        height=args.tie_height if dem is None else dem,
        height_sigma_m=args.tie_height_sigma_m,
    )
    level1 = lib.Level1Config(
        bias=args.bias,
        use_gcps=not args.ties_only_level1,
        bias_prior_shift_px=args.bias_prior_shift_px,
        bias_prior_matrix=args.bias_prior_matrix,
    )
    solver = solver_config(args, STRIP_SOLVER)
    level2 = lib.Level2Config(args.degree)
    config = lib.StripConfig(ties=ties, level1=level1, level2=level2, solver=solver)
    return config, lib.RefitConfig(grid=tuple(args.rpc_grid))


def run(args: argparse.Namespace) -> int:
    from ..strip import ConfigError
    from . import CommandError

    try:
        return _run(args)
    except ConfigError as err:
        raise CommandError(err.render(FLAGS)) from None


def _run(args: argparse.Namespace) -> int:
    from .. import strip as library
    from ..strip.internal import REFIT_WARN_PX, worst_refit
    from . import CommandError
    from . import _adjustment_options as shared
    from ._common import print_json
    from ._report_option import report_target

    start = shared.Start("strip", args)
    if args.tie_height is not None and args.dem is not None:
        raise CommandError("--tie-height and --dem both give the tie heights: give one")
    shared.check_adjustment_options(args)
    config, refit = strip_config(args)  # checked before any work (and again with the DEM)
    outputs = (
        library.StripOutputs(args.out, args.rpc_format, args.overwrite, refit) if args.out else None
    )
    page = report_target(args, [args.strip], folder=True)
    if args.dem is not None:
        config, _ = strip_config(args, shared.tie_dem(args))
    serious = (library.GCPDistributionWarning, library.UniversalCorrectionWarning,
               library.LineOffsetWarning, library.MeasuredTieWarning)  # fmt: skip
    with start.warnings_printed(serious):
        run = library.adjust_strip_files(
            args.strip, config, ground=args.ground, observations=args.observations,
            outputs=outputs, progress=start.say,
        )  # fmt: skip
    if not run.converged:
        start.warn("the level-1 bundle adjustment did not converge")
    code = start.exit_code(run.converged, bool(run.poor_fit))
    if not args.json:
        print(run.format(), flush=True)  # the report first
    if outputs is None:
        if args.json:
            print_json({**run.summary(), "exit_status": code})
        return code
    start.say(f"refitting {len(run.result.strip.names)} RPCs and writing {args.out}")
    try:
        data = run.write()
    except (OSError, ValueError) as err:
        return start.write_failed(err, run.summary())
    if page is not None:
        from ..report import write_strip_report

        start.say(f"writing {page}")
        data["written"].append(str(write_strip_report(run, page, overwrite=args.overwrite)))
    worst, px = worst_refit(data)
    if px > REFIT_WARN_PX:
        start.warn(f"the refitted RPC of {worst} differs from its adjusted model by up to "
                   f"{px:.3g} px on the check grid")  # fmt: skip
    if args.json:
        print_json({**data, "exit_status": code})
    else:
        print(f"\nwrote {len(data['written'])} files to {args.out} (updated RPCs: refit "
              f"error <= {px:.2g} px on the check grid)")  # fmt: skip
    return code
