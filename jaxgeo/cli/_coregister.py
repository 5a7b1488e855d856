"""``jaxgeo coregister``: align a DSM onto a reference DEM (Nuth and Kääb 2011).

    jaxgeo coregister DSM REF -o OUT [--diff DH] [--dem-height {ellipsoidal,orthometric}]
                      [--geoid G] [--mask MASK] [--tilt] [--vertical-only]
                      [--min-slope DEG] [--max-slope DEG]
                      [--nmad-k K] [--max-iterations N] [--tolerance M] [--json] [--quiet]
                      [--overwrite]

Parse -> :func:`jaxgeo.coreg.coregister` -> print (the human summary, or ``--json``); what
it does is ``DESCRIPTION`` (the ``--help`` text) and docs/coregister.md. The reference DEM is
the positional REF (``--dem`` would only rename it); ``--dem-height`` and ``--geoid`` give its
height reference, as in every command that reads a DEM. Without them REF's values are compared
as they are (the behaviour before these options, kept).
"""

from __future__ import annotations

import argparse
import sys

DESCRIPTION = (
    "Align DSM onto REF: the horizontal shift by Nuth and Kääb's slope/aspect method (iterated "
    "until the increment is below --tolerance) and the vertical bias (median of DSM - REF after "
    "it); print the statistics of DSM - REF before and after (mean, median, NMAD, RMSE, LE90 = "
    "90th percentile of |dh|, cells used; metres) and write the shifted DSM to OUT on the DSM's "
    "own grid. shift_m = (dx east, dy north, dz up) is what was added to the DSM. The DSM must "
    "be in a projected CRS in metres; REF and MASK may be in any CRS and resolution (REF is "
    "resampled onto the DSM grid, bilinear). --diff DH writes the height difference after the "
    "alignment (shifted DSM - REF, on the DSM's grid, NaN where either has no height: change "
    "between two dates) with its statistics before and after, over all its cells, in the output "
    "and its tags. OUT and DH are never one of the inputs. A DSM whose heights span fewer than "
    "10 of REF's cells in either direction (e.g. a few hundred metres on 90 m SRTM) cannot "
    "determine a horizontal shift and is refused (exit 2): --vertical-only fits dz alone (and "
    "the plane with --tilt). Not converged (exit 1): the statistics before and after are over "
    "the same cells."
)
EXTRA_CODES = {1: "the iterations did not converge (OUT written with the last shift, reported)"}
OPTIONS = {
    "max_iterations": "--max-iterations",
    "tolerance_m": "--tolerance",
    "min_slope_deg": "--min-slope",
    "max_slope_deg": "--max-slope",
    "nmad_k": "--nmad-k",
    "tilt": "--tilt",
    "vertical_only": "--vertical-only",
}
"""The option of each :class:`jaxgeo.coreg.NuthKaab` field (a refused value is named by it)."""


def register(sub) -> None:
    from ._common import add_command, add_json, add_out, add_quiet
    from ._inputs import add_height_options
    from ._report_option import add_report

    parser = add_command(
        sub,
        "coregister",
        help="align a DSM onto a reference DEM (Nuth and Kääb), statistics before/after",
        doc=DESCRIPTION,
        extra_codes=EXTRA_CODES,
    )
    parser.add_argument("dsm", metavar="DSM", help="DSM to align (band 1; projected CRS, m)")
    parser.add_argument("ref", metavar="REF", help="reference DEM (band 1; any CRS, heights m)")
    add_out(parser, "OUT", "the shifted DSM (GeoTIFF, float32, on the DSM's grid)")
    add_report(parser, "OUT.report.html beside OUT: DSM - REF before and after")
    parser.add_argument("--diff", metavar="DH",
                        help="also write the height difference after the alignment, shifted "
                        "DSM - REF (GeoTIFF, float32, m, on the DSM's grid, NaN where either "
                        "has no height), its statistics in its tags")  # fmt: skip
    add_height_options(parser, "REF", "its values as they are, in the DSM's vertical datum; "
                       "with either option REF's heights are made ellipsoidal, like a jaxgeo "
                       "DSM's")  # fmt: skip
    parser.add_argument("--mask", metavar="MASK",
                        help="raster of stable terrain (non-zero = stable, any CRS); only those "
                        "cells are used, for the fit and the statistics")  # fmt: skip
    parser.add_argument("--min-slope", type=float, default=3.0, metavar="DEG",
                        help="flatter cells are left out of the horizontal fit "
                        "(default 3)")  # fmt: skip
    parser.add_argument("--max-slope", type=float, default=70.0, metavar="DEG",
                        help="steeper cells are left out of the horizontal fit "
                        "(default 70)")  # fmt: skip
    parser.add_argument("--nmad-k", type=float, default=3.0, metavar="K",
                        help="cells with |dh - median| > K NMAD are outliers, left out of the "
                        "fit (default 3)")  # fmt: skip
    parser.add_argument("--tilt", action="store_true",
                        help="also fit and remove a tilt (a plane) of DSM - REF, as between "
                        "DSMs of two relative orientations (default: a constant dz "
                        "only)")  # fmt: skip
    parser.add_argument("--vertical-only", action="store_true",
                        help="no horizontal shift: dz alone, the median of DSM - REF (and "
                        "the plane with --tilt); for a DSM spanning too few of REF's cells for a "
                        "horizontal fit")  # fmt: skip
    parser.add_argument("--max-iterations", type=int, default=20, metavar="N",
                        help="at most N iterations (default 20)")  # fmt: skip
    parser.add_argument("--tolerance", type=float, default=0.01, metavar="M",
                        help="stop when the horizontal increment is below M metres "
                        "(default 0.01)")  # fmt: skip
    add_json(parser)
    add_quiet(parser)
    parser.set_defaults(func=run)


def _table(result) -> str:
    head = (f"{'':8}{'cells':>10}{'mean':>9}{'median':>9}{'NMAD':>9}{'std':>9}{'RMSE':>9}"
            f"{'LE90':>9}  (m)")  # fmt: skip
    lines = [head]
    for name, s in (("before", result.before), ("after", result.after)):
        lines.append(f"{name:8}{s.cells:>10d}{s.mean_m:>9.3f}{s.median_m:>9.3f}"
                     f"{s.nmad_m:>9.3f}{s.std_m:>9.3f}{s.rmse_m:>9.3f}"
                     f"{s.le90_m:>9.3f}")  # fmt: skip
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    import warnings

    from .._runtime.progress import Stages
    from ..coreg import CoregistrationError, CoregistrationWarning, NuthKaab, coregister
    from ..io import read_dem
    from . import CommandError, _one_line
    from ._common import (
        EXIT_NOT_CONVERGED,
        EXIT_OK,
        guard_outputs,
        name_options,
        note,
        ours,
        print_json,
    )
    from ._inputs import check_height_options
    from ._report_option import report_target

    check_height_options(args)
    inputs = [args.dsm, args.ref] + ([args.mask] if args.mask else [])
    guard_outputs([args.out] + ([args.diff] if args.diff else []), inputs, args.overwrite)
    page = report_target(args, inputs, folder=False)
    try:
        settings = NuthKaab(
            max_iterations=args.max_iterations,
            tolerance_m=args.tolerance,
            min_slope_deg=args.min_slope,
            max_slope_deg=args.max_slope,
            nmad_k=args.nmad_k,
            tilt=args.tilt,
            vertical_only=args.vertical_only,
        )
    except CoregistrationError as err:
        raise CommandError(name_options(str(err), OPTIONS, err.settings)) from None

    stages = Stages(None if args.quiet else note, started=True)  # the iterations' times

    def progress(it, increment, shift):
        stages(f"iteration {it}: increment ({increment[0]:+.3f}, {increment[1]:+.3f}) m, "
               f"shift ({shift[0]:+.3f}, {shift[1]:+.3f}) m")  # fmt: skip

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", CoregistrationWarning)
        ref = args.ref  # its values as they are, unless its height reference is given
        if args.dem_height is not None or args.geoid is not None:
            ref = read_dem(args.ref, height=args.dem_height, geoid=args.geoid)
            note(f"REF {ref.describe().removeprefix('DEM ')}", args.quiet)
        try:
            result = coregister(
                args.dsm, ref, args.out, diff=args.diff, mask=args.mask, settings=settings,
                overwrite=args.overwrite, callback=progress,
            )  # fmt: skip
        except CoregistrationError as err:  # named by the options (--vertical-only)
            raise CommandError(name_options(str(err), OPTIONS, err.settings)) from None
    for w in ours(caught):
        print(f"jaxgeo coregister: warning: {_one_line(w.message)}", file=sys.stderr)
    if page is not None:
        from ..report import write_coregistration_report

        write_coregistration_report(result, args.dsm, ref, page, overwrite=args.overwrite)
    dx, dy, dz = result.shift_m
    if args.json:
        print_json({"dsm": args.dsm, "ref": args.ref, "mask": args.mask, **result.as_dict(),
                    **({"report": str(page)} if page else {})})  # fmt: skip
    else:
        state = "converged" if result.converged else "NOT converged"
        state = "vertical only" if settings.vertical_only else state
        print(f"shift added to the DSM: dx {dx:+.3f} m (east), dy {dy:+.3f} m (north), "
              f"dz {dz:+.3f} m (up); {result.iterations} iterations, {state}; "
              f"{result.fit_cells} cells in the last fit")  # fmt: skip
        if result.tilt_origin_m is not None:
            gx, gy = (100.0 * g for g in result.tilt_m_per_m)
            x0, y0 = result.tilt_origin_m
            print(f"tilt added to the DSM: {gx:+.3f} m per 100 m east, {gy:+.3f} m per 100 m "
                  f"north (zero at {x0:.1f}, {y0:.1f})")  # fmt: skip
        if result.grid_step > 1:
            print(f"estimated on the DSM grid decimated by {result.grid_step}")
        if not result.converged:
            print(f"NOT converged: the last shift's statistics, before and after it over the same "
                  f"{result.after.cells} cells (not an improvement to rely on)")  # fmt: skip
        print(_table(result))
        if result.diff is not None:
            step = result.diff.grid_step
            where = "every cell" if step == 1 else f"every {step}th row and column"
            print(f"height difference DSM - REF over {where} with both (no mask):")
            print(_table(result.diff))
            print(f"wrote {result.diff.output}")
        print(f"wrote {result.output}" + (f"\nwrote {page}" if page else ""))
    return EXIT_OK if result.converged else EXIT_NOT_CONVERGED
