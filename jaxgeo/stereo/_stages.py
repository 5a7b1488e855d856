"""Wall and CPU seconds per stage of a DSM tile, for the report and the benchmark's shares.

A :class:`StageTimes` is made active by the work that wants the times (``with StageTimes() as
times:``, e.g. a tile of :class:`~jaxgeo.stereo._tiled.DSMJob`); the stages time themselves
with :func:`stage` wherever they run, so that no signature of the chain grows a clock
argument. With no active clock :func:`stage` costs two clock reads. CPU seconds are the
process's (every thread: JAX's and OpenCV's included), so they may exceed the wall seconds.
"""

from __future__ import annotations

import contextlib
import contextvars
import time

STAGES = ("reading", "sift", "ties", "rectification", "resampling", "sgm", "refinement",
          "triangulation", "sigma", "rasterisation", "writing")  # fmt: skip
"""The stages in chain order: reading the secondary image's window, SIFT detection (with the
reading of the reference's window, once per tile), tie matching and verification (the tie
points' height range and checks), epipolar grids and vertical disparity, resampling of the
epipolar bands, dense matching (SGM), sub-pixel refinement, triangulation (and the validity
check), height sigmas, rasterisation, writing of the tile."""

_ACTIVE: contextvars.ContextVar[StageTimes | None] = contextvars.ContextVar(
    "jaxgeo_stage_times", default=None
)


class StageTimes:
    """Seconds per stage (:data:`STAGES`; others are kept too), summed over the calls made
    while it is active (``with StageTimes() as times:``)."""

    def __init__(self):
        self.wall: dict[str, float] = {}
        self.cpu: dict[str, float] = {}
        self._token = None

    def add(self, name: str, wall_s: float, cpu_s: float) -> None:
        self.wall[name] = self.wall.get(name, 0.0) + wall_s
        self.cpu[name] = self.cpu.get(name, 0.0) + cpu_s

    def as_dict(self) -> dict[str, dict[str, float]]:
        """``{stage: {"wall_s": s, "cpu_s": s}}`` in chain order (JSON)."""
        names = [n for n in STAGES if n in self.wall] + [n for n in self.wall if n not in STAGES]
        return {n: {"wall_s": round(self.wall[n], 3), "cpu_s": round(self.cpu[n], 3)}
                for n in names}  # fmt: skip

    def __enter__(self) -> StageTimes:
        self._token = _ACTIVE.set(self)
        return self

    def __exit__(self, *exc) -> None:
        _ACTIVE.reset(self._token)


@contextlib.contextmanager
def stage(name: str):
    """Time the block as stage ``name`` of the active :class:`StageTimes` (none: not kept)."""
    times = _ACTIVE.get()
    if times is None:
        yield
        return
    wall, cpu = time.perf_counter(), time.process_time()
    try:
        yield
    finally:
        times.add(name, time.perf_counter() - wall, time.process_time() - cpu)
