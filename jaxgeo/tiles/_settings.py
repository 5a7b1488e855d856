"""How a product made tile by tile runs: one settings object for every tiled product."""

from __future__ import annotations

import dataclasses
import os

DEFAULT_RETRIES = 2
"""Retries of a failed tile (and reschedulings of a tile whose worker died) before the run
stops."""
MAX_RETRIES = 10
"""At most this many retries: a tile that failed ten times fails for a reason a retry does not
remove, and more would only delay the error."""


def max_local_workers() -> int:
    """The most local worker processes a product may start: two per core this process may use,
    at least 4 (a worker's tile keeps a core busy most of the time; a few more overlap its
    reads and writes, hundreds only contend for the cores and each holds its own JAX runtime
    in memory). More workers run on a dask cluster (``scheduler``)."""
    from .._runtime.jaxconfig import usable_cores

    return max(4, 2 * usable_cores())


@dataclasses.dataclass(frozen=True)
class TileSettings:
    """Where and how the tiles of a product (ortho, DSM) run; the same for every product.

    Attributes:
        workers: worker processes; ``None``: one per core for a large product, none for a small
            one or on 1-2 cores; ``0``: every tile in this process; at most two per core
            (:func:`max_local_workers`), and not with a ``scheduler``.
        scheduler: address of an existing dask scheduler (``tcp://host:8786``) to run the tiles
            on, instead of local workers.
        retries: retries of a failing tile, or of a tile whose worker died (at most
            :data:`MAX_RETRIES`).
        resume: a folder that keeps finished tiles; a later run of the same job reuses them.
        progress: a bar over the tiles on stderr.
        plan: write the tile plan (JSON) to this file and stop, computing nothing
            (:func:`jaxgeo.tiles.make_product`).
    """

    workers: int | None = None
    scheduler: str | None = None
    retries: int = DEFAULT_RETRIES
    resume: str | os.PathLike | None = None
    progress: bool = True
    plan: str | os.PathLike | None = None

    def __post_init__(self):
        if self.workers is not None and self.workers < 0:
            raise ValueError(f"workers must be >= 0 (or None), got {self.workers}")
        if self.workers is not None and self.scheduler:
            raise ValueError(f"workers {self.workers} with a scheduler: the cluster's workers "
                             "run the tiles (start more there); give one of them")  # fmt: skip
        most = max_local_workers()
        if self.workers is not None and self.workers > most:
            raise ValueError(f"workers {self.workers}: at most {most}, one per core of this "
                             "machine (more only contend for the cores); run more on a dask "
                             "cluster (scheduler)")  # fmt: skip
        if not 0 <= self.retries <= MAX_RETRIES:
            raise ValueError(f"retries must be in 0..{MAX_RETRIES}, got {self.retries}")
