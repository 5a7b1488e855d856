"""How a product made tile by tile runs: one settings object for every tiled product."""

from __future__ import annotations

import dataclasses
import os

DEFAULT_RETRIES = 2
"""Retries of a failed tile (and reschedulings of a tile whose worker died) before the run
stops."""


@dataclasses.dataclass(frozen=True)
class TileSettings:
    """Where and how the tiles of a product (ortho, DSM) run; the same for every product.

    Attributes:
        workers: worker processes; ``None``: one per core for a large product, none for a small
            one or on 1-2 cores; ``0``: every tile in this process.
        scheduler: address of an existing dask scheduler (``tcp://host:8786``) to run the tiles
            on, instead of local workers.
        retries: retries of a failing tile, or of a tile whose worker died.
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
        if self.retries < 0:
            raise ValueError(f"retries must be >= 0, got {self.retries}")
