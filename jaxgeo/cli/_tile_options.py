"""How a product made tile by tile runs, the same options in every tiled command: ``--tile``,
``--workers``, ``--scheduler``, ``--retries``, ``--resume``, ``--plan``
(:class:`jaxgeo.tiles.TileSettings`)."""

from __future__ import annotations

import argparse
import pathlib
from collections.abc import Sequence

from ._common import guard_outputs, note


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
