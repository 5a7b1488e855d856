"""What every sub-command shares: option names, images, output guards, exit codes.

One convention across commands: ``-o/--out`` names the output (a file, or a folder where a
command writes several), ``--overwrite`` allows replacing an earlier output (never an input),
``--quiet`` silences progress, ``--json`` prints the result as one JSON object on stdout instead
of the human summary -- always exactly one, with ``ok``, ``exit_code`` and, when the command
fails, ``error`` (:class:`._run.CommandRun`). Every output is claimed when the command starts
(:func:`jaxgeo.io.internal.claim_output`): a second run writing the same path is refused at
once. Images are given as rasters (their RPC inside or beside them) with
``--model IMG=FILE`` for a separate model file and ``--image-origin IMG=COL,ROW`` for a crop
whose pixel frame the raster does not carry (:func:`jaxgeo.io.open_image`). The whole
convention, for users, is :data:`CONVENTIONS_PAGE` (named at the end of every ``--help``).
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import sys
import warnings
from collections.abc import Iterable

EXIT_OK, EXIT_NOT_CONVERGED, EXIT_INPUT, EXIT_POOR_FIT, EXIT_WRITE = 0, 1, 2, 3, 4
EXIT_INTERNAL, EXIT_INTERRUPTED = 70, 130

_BASE_CODES = {
    EXIT_OK: "done",
    EXIT_INPUT: "bad input or options (the file, line, image or point is named); nothing written",
    EXIT_INTERNAL: "internal error (a bug: please report it; JAXGEO_TRACEBACK=1 shows the trace)",
    EXIT_INTERRUPTED: "interrupted (Ctrl-C or SIGTERM); no partial output is left",
}


CONVENTIONS_PAGE = "docs/cli-conventions.md"
"""The page of the options every command shares and of the exit codes (in the docs site:
"CLI conventions and exit codes"); ``docs/cli.md`` is the reference of every option."""
SEE_CONVENTIONS = f"conventions and exit codes: {CONVENTIONS_PAGE}; every option: docs/cli.md"
"""The last line of every command's ``--help`` (and of ``jaxgeo --help``)."""


def exit_codes(extra: dict[int, str] | None = None) -> str:
    """The ``exit status`` epilog of a sub-command: the shared codes plus ``extra``, then the
    line naming the conventions page (:data:`SEE_CONVENTIONS`)."""
    codes = {**_BASE_CODES, **(extra or {})}
    lines = [f"  {code:>3}  {text}" for code, text in sorted(codes.items())]
    return "exit status:\n" + "\n".join(lines) + "\n\n" + SEE_CONVENTIONS


def add_command(sub, name: str, help: str, doc: str, extra_codes: dict[int, str] | None = None):
    """A sub-command parser with the module docstring's first paragraph as description and the
    exit codes as epilog."""
    return sub.add_parser(
        name,
        help=help,
        description=doc.split("\n\n")[0],
        epilog=exit_codes(extra_codes),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )


def add_out(parser: argparse.ArgumentParser, metavar: str, help: str) -> None:
    """``-o/--out`` (required) and ``--overwrite``."""
    parser.add_argument("-o", "--out", required=True, metavar=metavar, help=help)
    parser.add_argument(
        "--overwrite",
        action="store_true",
        help="replace an existing output (an input is never replaced)",
    )


def in_range(option: str, value: float | None, low: float | None = None,
             high: float | None = None, unit: str = "", *, above: bool = False,
             why: str = "") -> None:  # fmt: skip
    """Refuse ``value`` of ``option`` outside ``[low, high]`` (``above``: ``> low``), NaN and
    infinities, naming the option and the valid range (``why``: what the bound means); ``None``
    (the option not given) passes. A value that cannot make sense (a negative size, a zero
    resolution, a window wider than any image) never reaches the work."""
    from . import CommandError

    if value is None:
        return
    low_ok = low is None or (value > low if above else value >= low)
    if value == value and abs(value) != float("inf") and low_ok and (high is None or value <= high):
        return
    lo = "" if low is None else f"> {low:g}" if above else f">= {low:g}"
    hi = "" if high is None else f"<= {high:g}"
    rule = " and ".join(r for r in (lo, hi) if r)
    unit = f" {unit}" if unit else ""
    raise CommandError(f"{option} must be {rule}{unit}, got {value:g}{why}")


def add_quiet(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--quiet", action="store_true", help="no progress display on stderr")


def add_json(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--json", action="store_true", help="print the result as one JSON object (machine use)"
    )


def path_or_url(path: str | os.PathLike):
    """``path`` as a :class:`pathlib.Path`, or a URL as a RemotePath (``//`` kept; its last
    segment, query string dropped, gives the file name and the image's name)."""
    from ..io.internal import as_path

    return as_path(path)


def _same(a: pathlib.Path, b: pathlib.Path) -> bool:
    try:
        return a.resolve() == b.resolve() or (a.exists() and b.exists() and os.path.samefile(a, b))
    except OSError:
        return False


def guard_outputs(
    outputs: Iterable[str | os.PathLike], inputs: Iterable[str | os.PathLike], overwrite: bool
) -> list[pathlib.Path]:
    """Check outputs before any computation: none is an input (whatever ``overwrite``), none
    exists unless ``overwrite``, each one's folder exists and is writable."""
    from ..io.internal import is_remote
    from . import CommandError

    # an input by URL is never a local output (and pathlib would fold its "//")
    inputs = [pathlib.Path(p) for p in inputs if not is_remote(p)]
    checked = []
    for out in outputs:
        if is_remote(out):
            raise CommandError(f"{out}: an output is a local file, not a URL")
        out = pathlib.Path(out)
        for inp in inputs:
            if _same(out, inp):
                raise CommandError(f"{out}: this output is an input of the command; name another")
        if out.is_dir():
            raise CommandError(f"{out}: is a folder; give a file name")
        if out.exists() and not overwrite:
            raise CommandError(f"{out}: exists; pass --overwrite to replace it")
        parent = out.parent if str(out.parent) else pathlib.Path(".")
        if not parent.is_dir():
            what = "is not a folder" if parent.exists() else "does not exist"
            raise CommandError(f"{out}: the output folder {parent} {what}")
        if not os.access(parent, os.W_OK | os.X_OK):
            raise CommandError(f"{out}: the output folder {parent} is not writable")
        checked.append(out)
    return checked


OPTION_WORDS = {
    "(pass overwrite=True)": "(pass --overwrite to replace it)",
    "(height='orthometric')": "(--dem-height orthometric)",
    "pass height= and geoid= explicitly": "pass --dem-height and --geoid",
    "orthometric heights need a geoid (": "orthometric heights need a geoid (--geoid ",
    "(read_dem(REF, height=, geoid=))": "(--dem-height, --geoid)",
    "(band=N)": "(--dem-band N)",
    "a fill DEM: fill=": "--dem-fill DEM2",
}
"""Library messages name the API's keywords; on the command line they are options (every
error a command prints goes through these replacements)."""


def name_options(message: str, options: dict[str, str], names: Iterable[str] | None = None) -> str:
    """``message`` of a library error with its parameter names (the keys of ``options``, or those
    of them in ``names``) replaced by the command's options (``{"tolerance_m": "--tolerance"}``):
    errors name what the user typed."""
    import re

    for name in options if names is None else names:
        if name in options:
            message = re.sub(rf"\b{re.escape(name)}\b", options[name], message)
    return message


class Parser(argparse.ArgumentParser):
    """``argparse``'s parser that keeps its usage error's message for the JSON object of a
    command run with ``--json`` (:class:`CommandRun`); sub-parsers are of the same class."""

    last_error: str | None = None

    def error(self, message):
        Parser.last_error = f"{self.prog}: error: {message}"
        super().error(message)


def parse(parser: argparse.ArgumentParser, argv: list[str]) -> argparse.Namespace:
    """``argv`` parsed; a usage error (exit 2) with ``--json`` also prints its JSON object.
    ``--quiet`` silences every progress display of the run (:mod:`jaxgeo._runtime.progress`,
    whatever a library default says); without it, each display's own switch decides."""
    from .._runtime.progress import silence

    Parser.last_error = None
    try:
        args = parser.parse_args(argv)
        silence(bool(getattr(args, "quiet", False)))
        return args
    except SystemExit as end:
        if end.code and "--json" in argv:
            from ._run import CommandRun

            run = CommandRun("jaxgeo", argv, json=True)
            run.error = Parser.last_error or "usage error"
            run.finish(EXIT_INPUT)
        raise


def print_json(result: dict) -> None:
    """``result`` as one JSON line on stdout (numpy values converted); inside a command run, the
    result of its JSON object, printed at its end (:meth:`._run.CommandRun.finish`)."""
    from ._run import CommandRun

    if CommandRun.current is not None and CommandRun.current.json:
        CommandRun.current.result = result
        return
    print(json.dumps(result, default=_jsonable))


def _jsonable(value):
    import numpy as np

    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    return str(value)


def note(message: str, quiet: bool = False) -> None:
    """A progress or context line on stderr (not with ``--quiet``: ``quiet`` is the command's
    flag; a counted step with its ETA is :class:`jaxgeo._runtime.progress.Progress`)."""
    if not quiet:
        print(message, file=sys.stderr, flush=True)


def ours(caught: Iterable[warnings.WarningMessage]) -> list[warnings.WarningMessage]:
    """jaxgeo's warnings among those a command caught (``warnings.catch_warnings(record=True)``),
    for it to print as its own lines. The others (a library's ``DeprecationWarning``, numpy's
    ``RuntimeWarning``) go back to Python's filters, which hide most unless the user asks
    (``-W``, ``PYTHONWARNINGS``): they are not the user's business, and a run on a newer numpy
    printed rasterio's deprecation notices as ``jaxgeo coregister: warning:`` lines. Call it
    after the ``catch_warnings`` block."""
    from ..errors import JaxgeoWarning

    kept = []
    for w in list(caught):  # (re-issued inside the recording context, they would join it)
        if issubclass(w.category, JaxgeoWarning):
            kept.append(w)
        else:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    return kept
