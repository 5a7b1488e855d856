"""How a product made tile by tile runs, the same options in every tiled command: ``--tile``,
``--workers``, ``--scheduler``, ``--retries``, ``--resume``, ``--plan``
(:class:`jaxgeo.tiles.TileSettings`)."""

from __future__ import annotations

import argparse
import os
import pathlib
from collections.abc import Sequence

from ._common import guard_outputs, in_range, note

MIN_TILE, MAX_TILE = 64, 8192
"""``--tile`` range: smaller tiles are all margin; a larger one holds some 0.5 GB per band of
float64 output (and a DSM tile's matching several times that) in one worker."""


def add_tile_options(parser: argparse.ArgumentParser, tile: int, unit: str) -> None:
    """``--tile``, ``--workers``, ``--scheduler``, ``--retries``, ``--resume``, ``--plan``: how a
    product made tile by tile (:mod:`jaxgeo.tiles`) runs (ranges: :func:`check_tile_options`)."""
    from ..tiles.internal import MAX_RETRIES

    parser.add_argument("--tile", type=int, default=None, metavar="N",
                        help=f"tile size in {unit} (default {tile}; <= {MAX_TILE})")  # fmt: skip
    parser.add_argument(
        "--workers",
        type=int,
        default=None,
        metavar="N",
        help="worker processes (default: one per core for a large product, none "
        "for a small one or on 1-2 cores; 0: all tiles in this process; at most two per "
        "core (at least 4), more on a cluster with --scheduler)",
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
        help=f"retries of a failing tile or of a tile whose worker died (default: 2; at most "
        f"{MAX_RETRIES})",
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


def check_tile_options(args: argparse.Namespace, inputs: Sequence[os.PathLike],
                       min_tile: int) -> None:  # fmt: skip
    """The tile options in range; ``--resume`` a folder that is not an input; the outputs (the
    product, or the plan only: the product is then only named) guarded (:func:`guard_outputs`)."""
    from ..tiles.internal import MAX_RETRIES, max_local_workers
    from . import CommandError

    in_range("--tile", args.tile, min_tile, MAX_TILE)
    in_range("--retries", args.retries, 0, MAX_RETRIES)
    why = " (two per core of this machine, at least 4; more on a cluster: --scheduler)"
    in_range("--workers", args.workers, 0, max_local_workers(), why=why)
    if args.workers is not None and args.scheduler:
        raise CommandError(f"--workers {args.workers} with --scheduler: the cluster's workers run "
                           "the tiles (start more there); give one of them")  # fmt: skip
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
