"""What ``jaxgeo adjust`` and ``jaxgeo strip`` share: their options, their checks, their start.

The options are defined once here: the tables (``--observations``, ``--ground``), the bias and
its priors, the solver (``--method``, ``--max-steps``), gross errors (``--loss``,
``--loss-scale``, ``--keep-blunders``), tie heights from a DEM (``--dem``, ``--dem-height``,
``--geoid``, plus ``--dem-offset-m``: added to the DEM's ellipsoidal heights, refused with a
geoid, and ``--tie-height-sigma-m``), the output (``-o/--out``, ``--overwrite``,
``--rpc-format``, ``--json``, ``--quiet``) and adjust's jitter spline (``--jitter-*``, refused
with another bias). The checks name the options, never a library parameter.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import math

RPC_FORMATS = ("txt", "rpb", "geom", "dimap")


def add_adjustment_options(
    parser: argparse.ArgumentParser,
    *,
    tables_required: bool,
    bias_choices: tuple[str, ...],
    bias_help: str,
    tie_height_sigma_m: float,
) -> None:
    """The options both commands share (see the module docstring); ``tables_required``:
    ``--observations`` must be given (``strip`` finds its tables beside ``strip.json``)."""
    from ..lsq import LOSSES
    from ..lsq.internal import DEFAULT_SOLVER
    from ._common import add_json, add_quiet
    from ._inputs import add_dem_options

    where = "" if tables_required else " (default: the one beside STRIP)"
    parser.add_argument("--observations", required=tables_required, metavar="OBS.csv",
                        help=f"image measurements{where}")  # fmt: skip
    parser.add_argument("--ground", metavar="GROUND.csv", help=f"GCPs and check points{where}")
    adjust = parser.add_argument_group("biases and solver")
    adjust.add_argument("--bias", choices=bias_choices, default="affine", help=bias_help)
    adjust.add_argument(
        "--bias-prior-shift-px",
        type=float,
        metavar="S",
        help="prior sigma (px) of every image's bias shift (fixes what GCPs and ties leave open)",
    )
    adjust.add_argument(
        "--bias-prior-matrix",
        type=float,
        metavar="M",
        help="prior sigma (px/px) of the affine matrix (or shift-drift drift) terms",
    )
    adjust.add_argument("--method", choices=("lm", "gn"), default=DEFAULT_SOLVER.method,
                        help="Levenberg-Marquardt (default) or Gauss-Newton")  # fmt: skip
    adjust.add_argument("--max-steps", type=int, default=DEFAULT_SOLVER.max_steps, metavar="N",
                        help=f"solver steps (default {DEFAULT_SOLVER.max_steps})")  # fmt: skip
    gross = parser.add_argument_group("gross errors")
    gross.add_argument("--loss", choices=LOSSES, default="cauchy",
                       help="loss on image measurements and GCP coordinates (default cauchy, "
                       "IRLS)")  # fmt: skip
    gross.add_argument("--loss-scale", type=float, default=DEFAULT_SOLVER.loss_scale,
                       metavar="C", help="robust loss threshold in a priori sigmas (default "
                       f"{DEFAULT_SOLVER.loss_scale:g})")  # fmt: skip
    gross.add_argument("--keep-blunders", action="store_true", help="flag gross errors "
                       "(w-test) but do not remove them and re-solve")  # fmt: skip
    add_dem_options(parser, "tie heights, as height observations of the tie points")
    heights = parser.add_argument_group("tie heights")
    heights.add_argument("--dem-offset-m", type=float, default=0.0, metavar="N",
                         help="added to the (ellipsoidal) DEM heights: a constant vertical shift; "
                         "an orthometric DEM takes --geoid")  # fmt: skip
    heights.add_argument("--tie-height-sigma-m", type=float, default=tie_height_sigma_m,
                         metavar="M", help="sigma of the tie heights (m, default "
                         f"{tie_height_sigma_m:g}; smaller with a good --dem)")  # fmt: skip
    out = parser.add_argument_group("output")
    out.add_argument("-o", "--out", metavar="DIR",
                     help="write the adjusted models and the report into this folder (created "
                     "if needed; default: print the report only)")  # fmt: skip
    out.add_argument("--overwrite", action="store_true", help="replace earlier outputs in "
                     "-o/--out (an input is never replaced)")  # fmt: skip
    out.add_argument("--rpc-format", choices=RPC_FORMATS, default="txt",
                     help="adjusted RPC per image in --out: <name>_RPC.TXT (default), <name>.RPB, "
                     "OSSIM <name>.geom or DIMAP v2 RPC_<name>.XML")  # fmt: skip
    add_json(parser)
    add_quiet(parser)


def add_jitter_options(parser: argparse.ArgumentParser) -> None:
    """The spline of ``--bias jitter`` (:class:`jaxgeo.bundle.JitterSettings`)."""
    from ..bundle import JitterSettings

    d, group = JitterSettings(), parser.add_argument_group("jitter (--bias jitter only)")
    group.add_argument("--jitter-knot-lines", type=float, metavar="N",
                       help="a spline knot every N lines, about an eighth of the shortest "
                       "jitter period to follow (default: per image from its lines and "
                       "measurements, ~100 lines, stated in the report); refused when the "
                       "measurements cannot support that many knots")  # fmt: skip
    for flag, value, what in (("--jitter-smoothness-px", d.smoothness_px, "the spline's second "
                               "differences (smaller is smoother)"), ("--jitter-knot-sigma-px",
                               d.knot_sigma_px, "each coefficient about 0 (holds what the "
                               "measurements leave open)")):  # fmt: skip
        group.add_argument(flag, type=float, metavar="S",
                           help=f"prior sigma (px) of {what}; default {value:g}")  # fmt: skip


def jitter_settings(args: argparse.Namespace):
    """The :class:`jaxgeo.bundle.JitterSettings` of ``--jitter-*`` (refused with another bias)."""
    from ..bundle import JitterSettings
    from . import CommandError

    names = ("--jitter-knot-lines", "--jitter-smoothness-px", "--jitter-knot-sigma-px")
    values = (args.jitter_knot_lines, args.jitter_smoothness_px, args.jitter_knot_sigma_px)
    given = [(flag, v) for flag, v in zip(names, values, strict=True) if v is not None]
    positive(*given)
    if given and args.bias != "jitter":
        raise CommandError(f"{', '.join(f for f, _ in given)}: only with --bias jitter "
                           f"(--bias is {args.bias})")  # fmt: skip
    return JitterSettings(*(d if v is None else v for v, d in zip(values, JitterSettings(),
                                                                   strict=True)))  # fmt: skip


def check_adjustment_options(args: argparse.Namespace) -> None:
    """Every shared option in range, before any file is read (errors name the options)."""
    from . import CommandError
    from ._inputs import check_dem_options

    check_dem_options(args)
    if args.dem_offset_m and not args.dem:
        raise CommandError("--dem-offset-m applies to --dem heights only")
    if not math.isfinite(args.dem_offset_m):
        raise CommandError(f"--dem-offset-m must be finite, got {args.dem_offset_m}")
    if args.max_steps < 1:
        raise CommandError(f"--max-steps must be at least 1, got {args.max_steps}")
    positive(("--loss-scale", args.loss_scale), ("--tie-height-sigma-m", args.tie_height_sigma_m),
             ("--bias-prior-shift-px", args.bias_prior_shift_px),
             ("--bias-prior-matrix", args.bias_prior_matrix))  # fmt: skip


def positive(*options: tuple[str, float | None]) -> None:
    """Each ``(option, value)`` given (not ``None``) a positive finite number, else an error
    naming the option."""
    from . import CommandError

    for flag, value in options:
        if value is not None and not (0 < value < math.inf):
            raise CommandError(f"{flag} must be a positive number, got {value}")


@contextlib.contextmanager
def out_checked():
    """The errors of a ``-o/--out`` check before any computation, named by the option."""
    from . import CommandError

    try:
        yield
    except CommandError as err:
        raise CommandError(f"-o/--out: {err}") from None
    except (OSError, ValueError) as err:
        text = err.strerror if isinstance(err, OSError) and err.strerror else str(err)
        where = f"{err.filename}: " if getattr(err, "filename", None) else ""
        raise CommandError(f"-o/--out: {where}{text}") from None


def solver_config(args: argparse.Namespace, base):
    """``base`` (a :class:`jaxgeo.lsq.SolverConfig`) with the solver and gross-error options."""
    return dataclasses.replace(
        base,
        method=args.method,
        max_steps=args.max_steps,
        loss=args.loss,
        loss_scale=args.loss_scale,
        remove_blunders=not args.keep_blunders,
    )


def tie_dem(args: argparse.Namespace):
    """The :class:`~jaxgeo.io.DEM` of ``--dem`` (``--dem-height``, ``--geoid``, then
    ``--dem-offset-m`` added), ``None`` without one."""
    from . import CommandError
    from ._common import note
    from ._inputs import open_dem

    dem = open_dem(args)
    if dem is not None and args.dem_offset_m:
        if dem.height_reference == "orthometric":  # never both: a geoid and an undulation
            raise CommandError(
                f"--dem-offset-m {args.dem_offset_m:g}: the heights of {args.dem} are made "
                "ellipsoidal with a geoid already (--geoid, or its vertical CRS); give "
                "--dem-height ellipsoidal to add the offset to the file's values instead"
            )
        dem = dataclasses.replace(dem, offset_m=args.dem_offset_m)
        note(f"{dem.describe()} (--dem-offset-m)", args.quiet)
    return dem


class Start:
    """The start of an adjustment command: progress lines (``say``), the library's warnings
    printed as the command's own lines (even with ``--quiet``: they decide what a result is
    worth), and the exit code of a result's fields."""

    def __init__(self, command: str, args: argparse.Namespace):
        self.command, self.args = command, args

    def say(self, line: str) -> None:
        from ._common import note

        note(f"jaxgeo {self.command}: {line}", self.args.quiet)

    def warn(self, line: str, kind: str = "warning") -> None:
        from ._common import note

        note(f"jaxgeo {self.command}: {kind}: {line}")

    @contextlib.contextmanager
    def warnings_printed(self, serious: tuple[type[Warning], ...] = ()):
        """Record the warnings of the block and print jaxgeo's as lines (``warning:`` for the
        ``serious`` categories, :class:`~jaxgeo.bundle.NotConvergedWarning` and
        :class:`~jaxgeo.bundle.PoorFitWarning`; ``note:`` for the others), also when the block
        raises (a warning on the input matters most when the adjustment then fails)."""
        import warnings

        from ..bundle import NotConvergedWarning, PoorFitWarning
        from ._common import ours

        caught = []
        try:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                yield
        finally:
            for w in ours(caught):
                worth = issubclass(w.category, (NotConvergedWarning, PoorFitWarning, *serious))
                self.warn(str(w.message), "warning" if worth else "note")

    @staticmethod
    def exit_code(converged: bool, poor_fit: bool) -> int:
        """The misfit first: a solve it drove off does not converge either."""
        from ._common import EXIT_NOT_CONVERGED, EXIT_OK, EXIT_POOR_FIT

        return EXIT_POOR_FIT if poor_fit else EXIT_OK if converged else EXIT_NOT_CONVERGED

    def write_failed(self, err: Exception, data: dict) -> int:
        """A failed ``-o/--out``: the JSON (the text report was printed before), the error."""
        from ._common import EXIT_WRITE, print_json

        if self.args.json:
            print_json({**data, "exit_status": EXIT_WRITE})
        self.warn(f"writing -o/--out failed: {err}", "error")
        return EXIT_WRITE
