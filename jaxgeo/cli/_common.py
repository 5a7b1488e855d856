"""What every sub-command shares: option names, images, output guards, exit codes.

One convention across commands: ``-o/--out`` names the output (a file, or a folder where a
command writes several), ``--overwrite`` allows replacing an earlier output (never an input),
``--quiet`` silences progress, ``--json`` prints the result as one JSON object on stdout instead
of the human summary. Images are given as rasters (their RPC inside or beside them) with
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
from collections.abc import Iterable, Sequence

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


def add_quiet(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--quiet", action="store_true", help="no progress display on stderr")


def add_json(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--json", action="store_true", help="print the result as one JSON object (machine use)"
    )


def add_image_options(parser: argparse.ArgumentParser) -> None:
    """``--model IMG=FILE`` and ``--image-origin IMG=COL,ROW`` (both repeatable)."""
    parser.add_argument(
        "--model",
        action="append",
        default=[],
        metavar="IMG=FILE",
        help="the sensor model file of image IMG (default: the RPC in the image or its "
        "sidecar); repeat per image",
    )
    parser.add_argument(
        "--image-origin",
        action="append",
        default=[],
        metavar="IMG=COL,ROW",
        help="model pixel of the first pixel of image IMG, for a crop whose model describes the "
        "full product (default: the crop's pixel-space geotransform, else 0,0)",
    )


def add_dem_options(parser: argparse.ArgumentParser, use: str) -> None:
    """``--dem``, ``--dem-height``, ``--geoid`` (``use``: what the DEM is for, in the help)."""
    parser.add_argument("--dem", default=None, metavar="DEM", help=f"DEM raster (any CRS): {use}")
    add_height_options(parser)


def add_height_options(
    parser: argparse.ArgumentParser,
    dem: str = "the DEM",
    default: str = "the file's vertical CRS if it declares EGM96/EGM2008, else ellipsoidal",
) -> None:
    """``--dem-height`` and ``--geoid``: the height reference of ``dem`` (a phrase for the help:
    ``"REF"`` where the DEM is a positional argument); ``default``: what is assumed without
    them. The values go to :func:`jaxgeo.io.read_dem` (``height=``, ``geoid=``)."""
    parser.add_argument(
        "--dem-height",
        choices=("ellipsoidal", "orthometric"),
        default=None,
        help=f"height reference of the values of {dem} (default: {default})",
    )
    parser.add_argument(
        "--geoid",
        default=None,
        help=f"egm96, egm2008 (PROJ grids) or a geoid grid file, for orthometric heights of {dem} "
        "(implies --dem-height orthometric)",
    )


def check_height_options(args: argparse.Namespace) -> None:
    """``--geoid`` not with ``--dem-height ellipsoidal`` (a geoid converts orthometric
    heights)."""
    from . import CommandError

    if args.geoid is not None and args.dem_height == "ellipsoidal":
        raise CommandError(f"--geoid {args.geoid}: a geoid converts orthometric heights; not with "
                           "--dem-height ellipsoidal")  # fmt: skip


def add_heights(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--heights",
        type=float,
        nargs=2,
        default=None,
        metavar=("HMIN", "HMAX"),
        help="height range of the terrain, ellipsoidal m (default: from --dem, else from a "
        "first coarse matching)",
    )


def check_dem_options(args: argparse.Namespace) -> None:
    """``--heights`` finite and ordered; ``--geoid`` / ``--dem-height`` only with ``--dem``."""
    import math

    from . import CommandError

    if getattr(args, "heights", None) is not None:
        lo, hi = args.heights
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            raise CommandError(f"--heights {lo:g} {hi:g}: need finite HMIN < HMAX (metres)")
    if args.geoid is not None and args.dem is None:
        raise CommandError("--geoid applies to a DEM: give --dem too")
    if args.dem_height is not None and args.dem is None:
        raise CommandError("--dem-height applies to a DEM: give --dem too")


def dem_inputs(args: argparse.Namespace) -> list[pathlib.Path]:
    """The DEM and geoid files among a command's inputs."""
    files = [pathlib.Path(args.dem)] if args.dem is not None else []
    if args.geoid is not None and pathlib.Path(args.geoid).exists():
        files.append(pathlib.Path(args.geoid))
    return files


def open_dem(args: argparse.Namespace):
    """The :class:`~jaxgeo.io.DEM` of ``--dem`` (``None`` without one); its height reference
    is printed on stderr unless ``--quiet``."""
    if args.dem is None:
        return None
    from ..io import read_dem

    dem = read_dem(args.dem, height=args.dem_height, geoid=args.geoid)
    note(dem.describe(), getattr(args, "quiet", False))
    return dem


def check_roi(roi, image) -> tuple[int, int, int, int]:
    """``--roi X Y W H`` inside the raster of ``image``, else a named error."""
    from . import CommandError

    x, y, w, h = roi
    width, height = image.size
    if x < 0 or y < 0 or w <= 0 or h <= 0 or x + w > width or y + h > height:
        raise CommandError(
            f"--roi {x} {y} {w} {h}: not inside {image.path} ({width} x {height} px; need "
            "X, Y >= 0, W, H > 0, X + W <= width, Y + H <= height)"
        )
    return (x, y, w, h)


def add_tile_options(parser: argparse.ArgumentParser, tile: int, unit: str) -> None:
    """``--tile``, ``--workers``, ``--scheduler``, ``--retries``, ``--resume``, ``--plan``: how a
    product made tile by tile (:mod:`jaxgeo.tiles`) runs."""
    parser.add_argument("--tile", type=int, default=None, metavar="N",
                        help=f"tile size in {unit} (default {tile})")  # fmt: skip
    parser.add_argument(
        "--workers",
        type=int,
        default=None,
        metavar="N",
        help="worker processes (default: one per core for a large product, none "
        "for a small one or on 1-2 cores; 0: all tiles in this process)",
    )
    parser.add_argument(
        "--scheduler",
        default=None,
        metavar="ADDRESS",
        help="run the tiles on the dask cluster of this scheduler "
        "(tcp://host:8786) instead of local workers",
    )
    parser.add_argument(
        "--retries",
        type=int,
        default=2,
        metavar="N",
        help="retries of a failing tile or of a tile whose worker died (default: 2)",
    )
    parser.add_argument(
        "--resume",
        default=None,
        metavar="DIR",
        help="keep finished tiles in DIR (created if needed) and reuse those an "
        "interrupted run of the same command left there",
    )
    parser.add_argument(
        "--plan",
        default=None,
        metavar="FILE",
        help="write the tile plan (JSON: tiles, windows, job) to FILE and stop, computing nothing",
    )


def check_tile_options(args: argparse.Namespace, inputs: Sequence[pathlib.Path],
                       min_tile: int) -> None:  # fmt: skip
    """The tile options in range; ``--resume`` a folder that is not an input; the outputs (the
    product, or the plan only: the product is then only named) guarded (:func:`guard_outputs`)."""
    from . import CommandError

    for name, value, low in (("--workers", args.workers, 0), ("--retries", args.retries, 0),
                             ("--tile", args.tile, min_tile)):  # fmt: skip
        if value is not None and value < low:
            raise CommandError(f"{name} must be >= {low}, got {value}")
    if args.plan:  # the plan is written; the product is only named (never an input)
        guard_outputs([args.plan], inputs, args.overwrite)
        guard_outputs([args.out], inputs, overwrite=True)
    else:
        guard_outputs([args.out], inputs, args.overwrite)
    if args.resume:
        resume = pathlib.Path(args.resume)
        if resume.exists() and not resume.is_dir():
            raise CommandError(f"--resume {resume}: exists and is not a folder")
        for p in inputs:
            if resume.resolve() == pathlib.Path(p).resolve():
                raise CommandError(f"--resume {resume}: is an input; name a folder")


def tiles_kept(args: argparse.Namespace, command: str) -> None:
    """After an interruption or a failed tile: say where the finished tiles are kept."""
    if args.resume and pathlib.Path(args.resume).is_dir():
        note(f"jaxgeo {command}: the finished tiles are kept in {args.resume}: the same command "
             "reuses them")  # fmt: skip


def _by_image(specs: Sequence[str], images: Sequence[str], option: str) -> dict[str, str]:
    """``{image path: value}`` from ``IMG=VALUE`` specs; IMG is the path as given, its file name
    or its stem; a spec without ``IMG=`` is allowed when there is one image. An IMG that names
    no image is refused with the names accepted (:func:`accepted_image_names`)."""
    from . import CommandError

    aliases = {}
    for img in images:
        path = pathlib.Path(img)
        for alias in (img, path.name, path.stem):
            aliases.setdefault(alias, img)
    out = {}
    for spec in specs:
        key, sep, value = spec.partition("=")
        if not sep and len(images) == 1:
            key, value = images[0], spec
        if not sep and len(images) != 1 or key not in aliases:
            expected = "FILE" if option == "--model" else "COL,ROW"
            raise CommandError(
                f"{option} {spec!r}: expected IMG={expected} with IMG one of the images, by its "
                f"path, file name or stem: {accepted_image_names(images)}"
            )
        img = aliases[key]
        if img in out:
            raise CommandError(f"{option}: image {img} given twice")
        out[img] = value
    return out


def accepted_image_names(images: Sequence[str]) -> str:
    """The names an ``IMG`` may take for each image (its path as given, file name, stem), for a
    message: ``"a/left.tif (left.tif, left); b/right.tif (right.tif, right)"``."""
    out = []
    for img in images:
        path = pathlib.Path(img)
        others = list(dict.fromkeys(a for a in (path.name, path.stem) if a != img))
        out.append(f"{img} ({', '.join(others)})" if others else img)
    return "; ".join(out)


def _origin(text: str, option_value: str):
    from . import CommandError

    try:
        col, row = (float(v) for v in text.replace(" ", "").split(","))
    except ValueError:
        raise CommandError(f"--image-origin {option_value!r}: expected IMG=COL,ROW") from None
    return col, row


def open_images(paths: Sequence[str], args: argparse.Namespace):
    """The :class:`~jaxgeo.io.SensorImage` of each raster in ``paths`` (``args.model`` and
    ``args.image_origin`` applied); file stems must differ (they name the images)."""
    from ..io import open_image
    from . import CommandError

    names = [pathlib.Path(p).stem for p in paths]
    if len(set(names)) != len(names):
        raise CommandError("image file names (stems) must differ: they name the images")
    models, origins = image_settings(args, list(paths))
    return [open_image(p, model=models.get(p), origin=origins.get(p)) for p in paths]


def image_settings(args: argparse.Namespace, images: Sequence[str]) -> tuple[dict, dict]:
    """``({image: model file}, {image: (col, row)})`` from ``--model`` and ``--image-origin``
    (IMG is an entry of ``images``, its file name or its stem)."""
    models = _by_image(getattr(args, "model", None) or [], images, "--model")
    specs = getattr(args, "image_origin", None) or []
    origins = {k: _origin(v, v) for k, v in _by_image(specs, images, "--image-origin").items()}
    return models, origins


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
    from . import CommandError

    inputs = [pathlib.Path(p) for p in inputs]
    checked = []
    for out in map(pathlib.Path, outputs):
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


def print_json(result: dict) -> None:
    """``result`` as one JSON line on stdout (numpy values converted)."""
    print(json.dumps(result, default=_jsonable))


def _jsonable(value):
    import numpy as np

    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    return str(value)


def note(message: str, quiet: bool = False) -> None:
    """A progress or context line on stderr (not with ``--quiet``)."""
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
