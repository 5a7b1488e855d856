"""The results of a co-registration: :class:`Coregistration` (the shift, the statistics before
and after) and :class:`HeightDifference` (the difference raster a file-level call wrote)."""

from __future__ import annotations

from dataclasses import dataclass

from ._stats import DHStats


@dataclass(frozen=True)
class HeightDifference:
    """The height difference a co-registration wrote (``coregister(..., diff=)``): ``output``
    the raster (``DSM - REF`` after the alignment, on the DSM's grid), ``before`` / ``after``
    the statistics of ``DSM - REF`` before and after the alignment over all its cells with
    heights in both (the change included: no mask, no outlier filter), or over every
    ``grid_step``-th row and column of it when the DSM is decimated for the estimate; when the
    co-registration did not converge, both over the same cells (heights before and after)."""

    output: str
    before: DHStats
    after: DHStats
    grid_step: int = 1

    def as_dict(self) -> dict:
        """JSON-ready dict: ``output``, ``before``, ``after``, ``grid_step``."""
        return {"output": self.output, "before": self.before.as_dict(),
                "after": self.after.as_dict(), "grid_step": self.grid_step}  # fmt: skip


@dataclass(frozen=True)
class Coregistration:
    """Result of a co-registration.

    ``shift_m = (dx, dy, dz)``: what was added to the DSM to align it onto the reference (dx
    east, dy north: the DSM's content moved by them; dz up), metres. ``before`` / ``after``:
    statistics of ``DSM - REF`` over the stable cells (the mask only: no slope or outlier
    filter) with heights in both, before and after the alignment; when it did not converge
    (``converged`` False), both over the same cells, those with heights before and after the
    last shift (a shift that moves the DSM off most of the reference would otherwise look like
    an improvement, its "after" over the few cells left). ``iterations``: all iterations run,
    at every level of the pyramid; ``increments_m``: the horizontal increments applied (those
    of a coarse level are dropped when its result does not bring the full grids closer);
    ``fit_cells``: cells in the last fit (the inliers of ``dz`` with ``vertical_only``).
    File-level calls add ``output`` (the path written, if any), ``grid_step`` (1, or the
    decimation of the grid the estimate was made on) and ``diff`` (the
    :class:`HeightDifference` written, if any).
    ``tilt_m_per_m = (east, north)``: the gradient of the plane also added to the DSM
    (``NuthKaab(tilt=True)``; zero otherwise), zero at the centre of the grid: for arrays,
    ``tilt_origin_m`` is None and the plane is ``east (col - (cols-1)/2) a + north (row -
    (rows-1)/2) e``; file-level calls give that centre in map coordinates.
    """

    shift_m: tuple[float, float, float]
    before: DHStats
    after: DHStats
    iterations: int
    converged: bool
    fit_cells: int
    increments_m: tuple[tuple[float, float], ...]
    output: str | None = None
    grid_step: int = 1
    diff: HeightDifference | None = None
    tilt_m_per_m: tuple[float, float] = (0.0, 0.0)
    tilt_origin_m: tuple[float, float] | None = None

    def as_dict(self) -> dict:
        """JSON-ready dict: ``shift_m``, ``before``, ``after`` and the other fields."""
        return {
            "shift_m": list(self.shift_m),
            "before": self.before.as_dict(),
            "after": self.after.as_dict(),
            "iterations": self.iterations,
            "converged": self.converged,
            "fit_cells": self.fit_cells,
            "increments_m": [list(i) for i in self.increments_m],
            "output": self.output,
            "grid_step": self.grid_step,
            "diff": None if self.diff is None else self.diff.as_dict(),
            "tilt_m_per_m": list(self.tilt_m_per_m),
            "tilt_origin_m": None if self.tilt_origin_m is None else list(self.tilt_origin_m),
        }
