"""One path for every tiled product: plan -> run -> mosaic -> clean-up (:func:`make_product`).

A product (the orthoimage, the DSM) gives its tile plan, its per-tile work (``work(tile, path)``,
:mod:`._runner`) and the :class:`RasterSpec` of its pixels; :func:`make_product` runs the tiles in
a work folder (``TileSettings.resume``, or a temporary folder beside the output), joins them into
one COG renamed onto the output at the end, and removes the work folder after success (a
``resume`` folder is kept after a failure or an interruption, for the next run). Each tile's
statistics (the JSON object its work returned) are read into a typed :class:`TileStats`; the
product's totals are their sum.
"""

from __future__ import annotations

import dataclasses
import os
import pathlib
import time
from collections.abc import Callable, Iterable, Mapping

from .._runtime.progress import say
from ..errors import JaxgeoError
from ..io.internal import refuse_existing
from ._mosaic import RasterSpec, mosaic_cog
from ._plan import TilePlan, write_plan
from ._runner import TileRun, WorkerPool, remove_work, run_tiles, work_folder
from ._settings import TileSettings

DEFAULT_TILES = TileSettings()
"""The default :class:`TileSettings` (where tiles run: decided by the product's size)."""

_COUNTERS = ("valid_px", "filled_px", "occluded_px", "blocks", "refined_blocks")
_MAXIMA = ("grid_error_px",)


class EmptyProduct(JaxgeoError, ValueError):
    """No tile of a product holds data (nothing is written); ``stats``: each tile's
    :class:`TileStats` (``no_data`` says why, where the work said it)."""

    def __init__(self, message: str, stats: Mapping[str, TileStats]):
        super().__init__(message)
        self.stats = dict(stats)

    def reasons(self) -> list[str]:
        """The distinct reasons the tiles gave for having no data (sorted)."""
        return sorted({s.no_data for s in self.stats.values() if s.no_data})


@dataclasses.dataclass(frozen=True)
class TileStats:
    """The statistics of one tile (or, summed with ``+`` / :meth:`total`, of a product).

    Counters (summed): ``valid_px`` output pixels (cells) with data, ``filled_px`` of them
    interpolated (a DSM's ``filled`` band), ``occluded_px`` hidden from the sensor, ``blocks``
    and ``refined_blocks`` of the coarse-grid mapping (an orthoimage's); ``grid_error_px``: the
    largest mapping error left (px; the maximum over the tiles). ``no_data``: why a tile has no
    data (``None``: it has some). ``details``: what else the tile's work reported (JSON: a DSM
    tile's pairs and window), per tile only (not summed)."""

    valid_px: int = 0
    filled_px: int = 0
    occluded_px: int = 0
    blocks: int = 0
    refined_blocks: int = 0
    grid_error_px: float = 0.0
    no_data: str | None = None
    details: dict = dataclasses.field(default_factory=dict, compare=False)
    reported: tuple[str, ...] = dataclasses.field(default=(), compare=False, repr=False)
    """The counters the tile's work reported (:meth:`as_dict` writes those)."""

    @classmethod
    def from_dict(cls, record: Mapping | None) -> TileStats:
        """The typed record of the JSON object a tile's work returned (unknown keys go to
        ``details``)."""
        record = dict(record or {})
        known = {k: record.pop(k) for k in (*_COUNTERS, *_MAXIMA, "no_data") if k in record}
        for k in _COUNTERS:
            if k in known:
                known[k] = int(known[k])
        for k in _MAXIMA:
            if k in known:
                known[k] = float(known[k])
        reported = tuple(k for k in (*_COUNTERS, *_MAXIMA) if k in known)
        return cls(**known, details=record, reported=reported)

    def as_dict(self) -> dict:
        """JSON: a tile without data as ``{"no_data": why}``, else the counters its work
        reported (all of them for a sum) and ``details``."""
        if self.no_data is not None:
            return {"no_data": self.no_data}
        out = {k: getattr(self, k) for k in self.reported or (*_COUNTERS, *_MAXIMA)}
        return {**out, **self.details}

    def __add__(self, other: TileStats) -> TileStats:
        if not isinstance(other, TileStats):
            return NotImplemented
        sums = {k: getattr(self, k) + getattr(other, k) for k in _COUNTERS}
        maxima = {k: max(getattr(self, k), getattr(other, k)) for k in _MAXIMA}
        reported = tuple(k for k in (*_COUNTERS, *_MAXIMA)
                         if k in self.reported or k in other.reported)  # fmt: skip
        return TileStats(**sums, **maxima, reported=reported)

    @staticmethod
    def total(stats: Iterable[TileStats]) -> TileStats:
        """The sum of ``stats`` (counters summed, ``grid_error_px`` the largest)."""
        out = TileStats()
        for s in stats:
            out = out + s
        return out


@dataclasses.dataclass(frozen=True)
class ProductRun:
    """What :func:`make_product` did: the product's ``path`` (``None``: only the plan was
    written, at ``plan_path``), the tile ``run`` (``None`` then), every tile's
    :class:`TileStats` (plan order) and their ``total``; ``seconds`` in all, of which
    ``tiles_s`` running the tiles and ``mosaic_s`` writing the COG."""

    path: pathlib.Path | None
    plan: TilePlan
    run: TileRun | None
    stats: dict[str, TileStats]
    total: TileStats
    seconds: float
    tiles_s: float = 0.0
    mosaic_s: float = 0.0
    plan_path: pathlib.Path | None = None

    @property
    def tiles(self) -> int:
        return len(self.plan)

    @property
    def empty_tiles(self) -> int:
        """Tiles without data."""
        return 0 if self.run is None else self.run.empty

    @property
    def reused_tiles(self) -> int:
        """Tiles taken from an earlier run (``resume``)."""
        return 0 if self.run is None else self.run.reused

    @property
    def workers(self) -> int:
        return 0 if self.run is None else self.run.workers

    @property
    def scheduler(self) -> str | None:
        return None if self.run is None else self.run.scheduler


def make_product(
    plan: TilePlan,
    work: Callable,
    out: str | os.PathLike,
    spec: RasterSpec,
    settings: TileSettings = DEFAULT_TILES,
    *,
    overwrite: bool = False,
    compress: str = "deflate",
    pool: WorkerPool | None = None,
) -> ProductRun:
    """Make the product of ``plan`` at ``out``: ``work(tile, path)`` on every tile (where
    ``settings`` says, :func:`jaxgeo.tiles.run_tiles`; ``pool``: workers started earlier, left
    open), then one COG of ``spec`` (:func:`jaxgeo.tiles.mosaic_cog`, overviews resampled with
    ``spec.overview_resampling``; ``compress``), written atomically (``overwrite``: replace an
    existing ``out``). The work folder is ``settings.resume`` (kept after a failure or an
    interruption, emptied after success) or a temporary folder beside ``out`` (always removed).
    With ``settings.plan`` only the plan is written there (``overwrite`` applies to it) and
    nothing is computed. :class:`EmptyProduct` when no tile holds data (nothing written);
    :class:`jaxgeo.tiles.TileError` naming a tile that kept failing."""
    t0 = time.perf_counter()
    if settings.plan is not None:
        path = write_plan(plan, settings.plan, overwrite=overwrite)
        return ProductRun(None, plan, None, {}, TileStats(), time.perf_counter() - t0,
                          plan_path=pathlib.Path(path))  # fmt: skip
    out = refuse_existing(out, overwrite)  # before the work, not after it
    resume = settings.resume
    folder, done, mosaic_s = None, False, 0.0
    try:
        folder = work_folder(out, resume)
        run = run_tiles(plan, work, folder, settings, pool=pool)
        stats = {k: _stats(r) for k, r in run.results.items()}
        if all(r.path is None for r in run.results.values()):
            raise EmptyProduct(f"no tile of the {plan.kind} holds data", stats)
        t_mosaic = time.perf_counter()
        say(f"{plan.kind}: writing {out.name} (the mosaic of the tiles, its overviews)",
            settings.progress)  # fmt: skip
        mosaic_cog(run, plan, spec, out, overwrite=overwrite, compress=compress,
                   overview_resampling=spec.overview_resampling)  # fmt: skip
        mosaic_s = time.perf_counter() - t_mosaic
        done = True
    finally:
        if folder is not None and (resume is None or done):
            remove_work(folder, created=resume is None)
    total = TileStats.total(s for k, s in stats.items() if run.results[k].path is not None)
    return ProductRun(out, plan, run, stats, total, time.perf_counter() - t0,
                      tiles_s=run.seconds, mosaic_s=mosaic_s)  # fmt: skip


def _stats(result) -> TileStats:
    stats = TileStats.from_dict(result.stats)
    if result.path is None and stats.no_data is None:
        stats = dataclasses.replace(stats, no_data="")
    return stats
