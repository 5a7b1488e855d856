"""DEM co-registration on arrays: Nuth and Kääb (2011) horizontal shift plus vertical bias.

Nuth, C. and Kääb, A. (2011), *Co-registration and bias corrections of satellite elevation data
sets for quantifying glacier thickness change*, The Cryosphere 5, 271-290. A DSM displaced
horizontally by ``t`` (east, north, m) from the reference terrain ``T`` differs from it by
``dh = -grad(T) . t`` (first order); with the slope ``alpha`` and the aspect ``psi`` (downslope
direction, clockwise from north) of the reference this is their equation 3,

    dh / tan(alpha) = |t| cos(b - psi) + c  =  t_east sin(psi) + t_north cos(psi) + c,

linear in ``(t_east, t_north, c)``. Each iteration resamples the DSM by the shift found so far,
takes the median of ``(dh - median(dh)) / tan(alpha)`` in aspect bins (robust, every aspect
weighted alike), fits the cosine to the bin medians and moves the DSM by the opposite of the
displacement found; it stops when that increment is below the tolerance. The iterations run
coarse to fine: first on the grids averaged over 4 x 4 and 2 x 2 blocks (a pyramid: short
texture makes the first-order relation underestimate shifts of several cells, so on the full
grid alone the iterations creep), then on the full grid. The vertical shift is
the opposite of the median ``dh`` after the horizontal one. Cells take part where they are
stable (the caller's mask), their slope is within limits and ``dh`` is within ``nmad_k`` NMAD
of its median (outliers: clouds, changes, blunders).

Geometry: arrays are north-up rasters of one grid; ``step_m = (a, e)`` are the signed map
displacements of one column and one row (the geotransform's ``a`` and ``e``: ``(0.5, -0.5)``
for a usual 0.5 m grid). Shifts are map metres: ``dx`` east, ``dy`` north, ``dz`` up.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from ..errors import JaxgeoError, JaxgeoWarning
from ._result import Coregistration
from ._stats import dh_stats, nmad


class CoregistrationError(JaxgeoError, ValueError):
    """A co-registration jaxgeo refuses: rasters that do not overlap, too few cells, a CRS
    that is not metric, terrain whose aspects cannot determine a shift; the message names the
    files (file-level calls) or the cause. A refused :class:`NuthKaab` names its fields in the
    message and in ``settings`` (a caller names them its own way: the CLI by its options)."""

    def __init__(self, message: str, settings: tuple[str, ...] = ()):
        super().__init__(message)
        self.settings = tuple(settings)


class CoregistrationWarning(JaxgeoWarning):
    """The co-registration did not converge, or left the heights further apart than before."""


@dataclass(frozen=True)
class NuthKaab:
    """Settings of the Nuth and Kääb co-registration (module docstring).

    ``max_iterations`` and ``tolerance_m`` (stop when the horizontal increment is shorter);
    cells with slope outside ``[min_slope_deg, max_slope_deg]`` do not enter the horizontal fit
    (flat cells carry no horizontal information, cliffs are unreliable); ``nmad_k``: cells with
    ``|dh - median| > nmad_k * NMAD`` are outliers (re-evaluated every iteration);
    ``aspect_bins`` bins of aspect, each used when it holds ``min_bin_cells`` cells; fewer than
    ``min_cells`` usable cells is an error. ``pyramid``: the grids averaged over blocks of these
    factors are co-registered first, coarse to fine, each starting the next (texture shorter than
    the block no longer hides a shift of many cells; ``()``: the full grid only, which then
    converges slowly for shifts of several cells over rough terrain). ``max_cells`` (file-level
    :func:`~jaxgeo.coreg.coregister` only): rasters with more cells are estimated on the DSM
    grid decimated by the smallest integer step that leaves at most that many. ``tilt``: also
    fit a plane to the difference (a vertical offset varying linearly east and north, as
    between DSMs of two relative orientations; xDEM's ``Deramp`` of order 1), removed before
    each horizontal fit (a tilt left in ``dh`` correlates with the aspects of a small scene and
    would be taken for a shift) and added to the aligned DSM; off by default (a plane can also
    absorb a real trend of change).

    ``vertical_only``: no horizontal fit, only ``dz`` (the median of ``DSM - REF`` over the
    inliers; and the plane with ``tilt``): for a DSM spanning too few reference cells for a
    horizontal shift to be determined (the check below), or when the horizontal registration is
    known. ``min_ref_cells`` (file-level :func:`~jaxgeo.coreg.coregister` only): the heights
    both rasters share must span at least this many of REF's cells (its posts, as they fall on
    the DSM's CRS; or of the estimate grid's cells where REF is finer) east-west and
    north-south, else the horizontal fit is refused: the reference's surface, interpolated
    between its posts, is a few bilinear patches whose slopes and aspects do not determine a
    shift (a 500 x 160 m DSM on 90 m SRTM, 7.5 x 1.7 posts, swung by tens of metres per
    iteration). ``max_shift_fraction``: a horizontal shift longer than this fraction of the
    shorter side of the shared heights' extent stops the fit with an error (a run-away: the
    overlap left would not determine it either).
    """

    max_iterations: int = 20
    tolerance_m: float = 0.01
    min_slope_deg: float = 3.0
    max_slope_deg: float = 70.0
    nmad_k: float = 3.0
    aspect_bins: int = 36
    min_bin_cells: int = 10
    min_cells: int = 500
    pyramid: tuple[int, ...] = (4, 2)
    max_cells: int = 8_000_000
    tilt: bool = False
    vertical_only: bool = False
    min_ref_cells: float = 10.0
    max_shift_fraction: float = 0.25

    def __post_init__(self):
        def refuse(message: str, *fields: str):
            raise CoregistrationError(message, settings=fields)

        if self.max_iterations < 1:
            refuse(f"max_iterations {self.max_iterations}: expected >= 1", "max_iterations")
        if not self.tolerance_m > 0:
            refuse(f"tolerance_m {self.tolerance_m}: expected > 0 (metres)", "tolerance_m")
        if not 0 <= self.min_slope_deg < self.max_slope_deg <= 90:
            refuse(f"min_slope_deg {self.min_slope_deg}, max_slope_deg {self.max_slope_deg}: "
                   "expected 0 <= min_slope_deg < max_slope_deg <= 90 (degrees)",
                   "min_slope_deg", "max_slope_deg")  # fmt: skip
        if not self.nmad_k > 0:
            refuse(f"nmad_k {self.nmad_k}: expected > 0", "nmad_k")
        if any(f < 2 for f in self.pyramid):
            refuse(f"pyramid {self.pyramid}: expected factors >= 2", "pyramid")
        if not isinstance(self.tilt, bool):
            refuse(f"tilt {self.tilt!r}: expected True or False", "tilt")
        if not isinstance(self.vertical_only, bool):
            refuse(f"vertical_only {self.vertical_only!r}: expected True or False",
                   "vertical_only")  # fmt: skip
        if not self.min_ref_cells >= 1:
            refuse(f"min_ref_cells {self.min_ref_cells}: expected >= 1", "min_ref_cells")
        if not 0 < self.max_shift_fraction <= 1:
            refuse(f"max_shift_fraction {self.max_shift_fraction}: expected in (0, 1]",
                   "max_shift_fraction")  # fmt: skip
        if self.max_cells < 1000:
            refuse(f"max_cells {self.max_cells}: expected >= 1000", "max_cells")
        if self.aspect_bins < 8 or self.min_bin_cells < 1 or self.min_cells < 10:
            refuse("aspect_bins >= 8, min_bin_cells >= 1 and min_cells >= 10 expected",
                   "aspect_bins", "min_bin_cells", "min_cells")  # fmt: skip


def _take(z: np.ndarray, di: int, dj: int) -> np.ndarray:
    """``out[r, c] = z[r + di, c + dj]``, NaN where that falls outside ``z``."""
    rows, cols = z.shape
    out = np.full(z.shape, np.nan, dtype=np.float64)
    r0, r1 = max(0, -di), min(rows, rows - di)
    c0, c1 = max(0, -dj), min(cols, cols - dj)
    if r0 < r1 and c0 < c1:
        out[r0:r1, c0:c1] = z[r0 + di : r1 + di, c0 + dj : c1 + dj]
    return out


def shift_heights(
    z: np.ndarray, shift_m: tuple[float, float, float], step_m: tuple[float, float]
) -> np.ndarray:
    """The raster ``z`` (NaN = no data) moved by ``shift_m = (dx, dy, dz)`` on its own grid:
    ``out(p) = z(p - (dx, dy)) + dz`` with bilinear interpolation (float64). A cell is NaN where
    a neighbour with a non-zero weight is NaN or off the grid. ``step_m = (a, e)``: the signed
    grid steps (m; ``e < 0`` for a north-up raster), as :func:`nuth_kaab` takes them."""
    dx, dy, dz = (float(v) for v in shift_m)
    drow, dcol = -dy / step_m[1], -dx / step_m[0]  # source position minus target position
    i0, j0 = math.floor(drow), math.floor(dcol)
    fr, fc = drow - i0, dcol - j0
    z = np.asarray(z, dtype=np.float64)
    out = np.zeros(z.shape, dtype=np.float64)
    for di, wr in ((0, 1.0 - fr), (1, fr)):
        for dj, wc in ((0, 1.0 - fc), (1, fc)):
            if wr * wc > 0.0:
                out += wr * wc * _take(z, i0 + di, j0 + dj)
    return out + dz


def slope_aspect(ref: np.ndarray, step_m: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """``(tan(slope), aspect_rad)`` of a height raster: central differences (NaN next to no
    data); aspect = downslope direction, clockwise from north, in ``(-pi, pi]``."""
    d_row, d_col = np.gradient(np.asarray(ref, dtype=np.float64))
    g_east, g_north = d_col / step_m[0], d_row / step_m[1]
    return np.hypot(g_east, g_north), np.arctan2(-g_east, -g_north)


def _aspect_bins(y: np.ndarray, aspect: np.ndarray, settings: NuthKaab):
    """Rows ``(mean sin(psi), mean cos(psi), 1)`` and medians of ``y`` of the aspect bins that
    hold ``settings.min_bin_cells`` cells; :class:`CoregistrationError` when they cannot
    determine a horizontal displacement (fewer than 3, or nearly one direction)."""
    nb = settings.aspect_bins
    idx = np.minimum(((aspect + np.pi) / (2 * np.pi) * nb).astype(np.int64), nb - 1)
    order = np.argsort(idx, kind="stable")
    idx, y, aspect = idx[order], y[order], aspect[order]
    bounds = np.searchsorted(idx, np.arange(nb + 1))
    rows, rhs = [], []
    for b in range(nb):
        lo, hi = bounds[b], bounds[b + 1]
        if hi - lo < settings.min_bin_cells:
            continue
        psi = aspect[lo:hi]
        rows.append((np.mean(np.sin(psi)), np.mean(np.cos(psi)), 1.0))
        rhs.append(np.median(y[lo:hi]))
    a = np.asarray(rows, dtype=np.float64).reshape(-1, 3)
    sv = np.linalg.svd(a, compute_uv=False) if a.shape[0] >= 3 else np.zeros(1)
    if a.shape[0] < 3 or sv[-1] < 1e-3 * sv[0]:
        raise CoregistrationError(
            f"the stable terrain's aspects cannot determine a horizontal shift ({a.shape[0]} "
            f"of {nb} aspect bins hold >= {settings.min_bin_cells} cells with slope "
            f"{settings.min_slope_deg}-{settings.max_slope_deg} deg; terrain too flat or too "
            "uniform)"
        )
    return a, np.asarray(rhs)


def _fit_displacement(
    dh: np.ndarray, tan_slope: np.ndarray, aspect: np.ndarray, settings: NuthKaab
) -> tuple[float, float]:
    """Displacement ``(t_east, t_north)`` of the DSM from the cosine fit of the aspect-bin
    medians of ``dh / tan(slope)`` (``dh`` centred on its median)."""
    a, rhs = _aspect_bins(dh / tan_slope, aspect, settings)
    (t_east, t_north, _), *_ = np.linalg.lstsq(a, rhs, rcond=None)
    return float(t_east), float(t_north)


def _inliers(dh: np.ndarray, usable: np.ndarray, nmad_k: float) -> tuple[np.ndarray, float]:
    """Cells of ``usable`` within ``nmad_k`` NMAD of the median ``dh``, and that median."""
    med = float(np.median(dh[usable]))
    spread = nmad(dh[usable])
    return usable & (np.abs(dh - med) <= nmad_k * spread + 1e-9), med


def _block_mean(z: np.ndarray, factor: int) -> np.ndarray:
    """Means of ``factor x factor`` blocks of the finite values (NaN where fewer than half of a
    block's cells are finite); the last partial blocks are dropped."""
    rows, cols = (n // factor for n in z.shape)
    z = np.asarray(z, dtype=np.float64)[: rows * factor, : cols * factor]
    z = z.reshape(rows, factor, cols, factor)
    finite = np.isfinite(z)
    count = finite.sum(axis=(1, 3))
    total = np.where(finite, z, 0.0).sum(axis=(1, 3))
    return np.where(2 * count >= factor * factor, total / np.maximum(count, 1), np.nan)


def _spread(dsm, ref, stable, shift, step_m, settings) -> float:
    """NMAD of ``DSM - REF`` (less its plane with ``settings.tilt``) over the stable cells with
    the DSM moved by ``shift`` (east, north); infinite where fewer than 10 cells are left."""
    dh = shift_heights(dsm, (shift[0], shift[1], 0.0), step_m) - ref
    cells = stable & np.isfinite(dh)
    if int(cells.sum()) < 10:
        return math.inf
    return nmad(_detrended(dh, cells, step_m, settings)[0][cells])


def tilt_plane(shape, step_m: tuple[float, float], tilt_m_per_m) -> np.ndarray:
    """The plane ``east_gradient * east + north_gradient * north`` (m) on a grid of ``shape``
    and signed steps ``step_m``, east and north measured from the grid's centre."""
    rows, cols = shape
    east = (np.arange(cols) - (cols - 1) / 2.0) * step_m[0]
    north = (np.arange(rows) - (rows - 1) / 2.0) * step_m[1]
    return tilt_m_per_m[0] * east[None, :] + tilt_m_per_m[1] * north[:, None]


def _fit_tilt(dh: np.ndarray, cells: np.ndarray, step_m, nmad_k: float) -> tuple[float, float]:
    """Gradient (east, north; m/m) of the plane fitted to ``dh`` over ``cells``, refitted
    twice on the cells within ``nmad_k`` NMAD of the last plane (changes, blunders)."""
    rows, cols = np.nonzero(cells)
    east = (cols - (dh.shape[1] - 1) / 2.0) * step_m[0]
    north = (rows - (dh.shape[0] - 1) / 2.0) * step_m[1]
    values = dh[rows, cols]
    a = np.stack([east, north, np.ones_like(east)], axis=1)
    use = np.ones(values.size, bool)
    for _ in range(3):
        sol, *_ = np.linalg.lstsq(a[use], values[use], rcond=None)
        r = values - a @ sol
        use = np.abs(r - np.median(r[use])) <= nmad_k * nmad(r[use]) + 1e-9
    return float(sol[0]), float(sol[1])


def _detrended(dh, usable, step_m, settings) -> tuple[np.ndarray, tuple[float, float]]:
    """``dh`` less its plane (``settings.tilt``; else as it is), and the plane's gradient."""
    if not settings.tilt:
        return dh, (0.0, 0.0)
    g = _fit_tilt(dh, usable, step_m, settings.nmad_k)
    return dh - tilt_plane(dh.shape, step_m, g), g


def _iterate(grids, step_m, settings, shift, tolerance_m, callback, limit_m=math.inf):
    """Nuth and Kääb iterations on one grid ``grids = (dsm, ref, stable)`` from ``shift``
    (east, north): the new shift, the increments, whether the last one was below
    ``tolerance_m``, the cells of the last fit. ``callback(i, increment, shift)`` after each
    (``i`` from 1 on this grid). A shift longer than ``limit_m`` is refused (a run-away)."""
    dsm, ref, stable = grids
    tan_slope, aspect = slope_aspect(ref, step_m)
    lo, hi = (math.tan(math.radians(d)) for d in (settings.min_slope_deg, settings.max_slope_deg))
    sloped = stable & (tan_slope >= max(lo, 1e-6)) & (tan_slope <= hi)
    shift = np.array(shift, dtype=np.float64)
    increments: list[tuple[float, float]] = []
    converged, fit_cells = False, 0
    for it in range(1, settings.max_iterations + 1):
        dh = shift_heights(dsm, (shift[0], shift[1], 0.0), step_m) - ref
        usable = stable & np.isfinite(dh)
        if int(usable.sum()) < settings.min_cells:
            raise CoregistrationError(
                f"only {int(usable.sum())} stable cells left after shifting the DSM by "
                f"({shift[0]:.2f}, {shift[1]:.2f}) m (need >= {settings.min_cells})"
            )
        dh, _ = _detrended(dh, usable, step_m, settings)
        inlier, med = _inliers(dh, usable, settings.nmad_k)
        fit = inlier & sloped
        fit_cells = int(fit.sum())
        if fit_cells < settings.min_cells:
            raise CoregistrationError(
                f"only {fit_cells} stable cells with slope {settings.min_slope_deg}-"
                f"{settings.max_slope_deg} deg and dh within {settings.nmad_k} NMAD (need "
                f">= {settings.min_cells})"
            )
        t = _fit_displacement(dh[fit] - med, tan_slope[fit], aspect[fit], settings)
        shift -= t
        increments.append((-t[0], -t[1]))
        if callback is not None:
            callback(it, (-t[0], -t[1]), (float(shift[0]), float(shift[1])))
        if math.hypot(*shift) > limit_m:
            fraction = settings.max_shift_fraction
            raise CoregistrationError(
                f"the horizontal shift ran to ({shift[0]:+.2f}, {shift[1]:+.2f}) m after {it} "
                f"iteration{'s' if it > 1 else ''}, beyond {limit_m:.1f} m ({fraction:g} x the "
                f"{limit_m / fraction:.0f} m shorter side of the extent both rasters have "
                "heights over): the fit is not determined by this overlap (too small, or too "
                "smooth, for the reference's cells); use a larger DSM, a finer reference, or "
                "vertical_only",
                settings=("max_shift_fraction", "vertical_only"),
            )
        if math.hypot(*t) < tolerance_m:
            converged = True
            break
    return shift, increments, converged, fit_cells


def nuth_kaab(
    dsm: np.ndarray,
    ref: np.ndarray,
    step_m: tuple[float, float],
    stable: np.ndarray | None = None,
    settings: NuthKaab | None = None,
    callback: Callable[..., object] | None = None,
) -> Coregistration:
    """Co-register ``dsm`` onto ``ref`` (two height rasters of one grid, m, NaN = no data).

    ``step_m = (a, e)``: the grid's *signed* steps, the geotransform's ``a`` and ``e`` (m);
    ``e < 0`` for a north-up raster (GDAL's, rasterio's ``transform.e``). Passing ``(res,
    res)`` for a north-up grid gives the north shift with the wrong sign.

    ``stable`` (bool, same shape): cells of stable terrain (default: all); ``settings`` default
    ``NuthKaab()``. ``callback(i, increment_m, shift_m)`` is called after each iteration (of
    every level of the pyramid; ``i`` counts them all). Warns
    (:class:`CoregistrationWarning`) when the iterations do not converge or the result fits
    worse than the input. Raises :class:`CoregistrationError` for too few cells, for terrain
    whose slopes and aspects cannot determine the shift (checked up front on REF where both
    have heights, and at each iteration), and for a shift that runs beyond
    ``settings.max_shift_fraction`` of the shorter side of the extent both have heights over.
    With ``settings.vertical_only`` only ``dz`` (and the plane with ``tilt``) is fitted: no
    iteration, ``converged`` True.
    """
    settings = NuthKaab() if settings is None else settings
    dsm = np.asarray(dsm, dtype=np.float64)
    ref = np.asarray(ref, dtype=np.float64)
    if dsm.shape != ref.shape or dsm.ndim != 2:
        raise CoregistrationError(f"DSM {dsm.shape} and REF {ref.shape}: expected one 2-D grid")
    stable = np.ones(dsm.shape, bool) if stable is None else np.asarray(stable, dtype=bool)
    if stable.shape != dsm.shape:
        raise CoregistrationError(f"stable mask {stable.shape}: expected {dsm.shape}")
    stable = stable & np.isfinite(ref)
    both = stable & np.isfinite(dsm)
    if int(both.sum()) < settings.min_cells:
        raise CoregistrationError(
            f"only {int(both.sum())} stable cells have heights in both rasters (need "
            f">= {settings.min_cells})"
        )
    if settings.vertical_only:
        return _vertical(dsm, ref, stable, (0.0, 0.0), step_m, settings, 0, True, ())
    # up front: the reference's slopes and aspects where both have heights must determine a
    # shift (else the iterations wander), and a shift is bounded by the extent they share
    tan_slope, aspect = slope_aspect(ref, step_m)
    lo, hi = (math.tan(math.radians(d)) for d in (settings.min_slope_deg, settings.max_slope_deg))
    sloped = both & (tan_slope >= max(lo, 1e-6)) & (tan_slope <= hi)
    _aspect_bins(np.zeros(int(sloped.sum())), aspect[sloped], settings)
    rows, cols = (np.flatnonzero(np.any(both, axis=k)) for k in (1, 0))
    extent = ((cols[-1] - cols[0] + 1) * abs(step_m[0]), (rows[-1] - rows[0] + 1) * abs(step_m[1]))
    limit = settings.max_shift_fraction * min(extent)
    shift, increments, ran = np.zeros(2), [], 0

    def counted(done: int):  # the callback's iteration number counts every level's
        return None if callback is None else lambda i, *rest: callback(done + i, *rest)

    for factor in settings.pyramid:
        coarse = [_block_mean(v, factor) for v in (dsm, ref, stable)]
        if min(coarse[0].shape) < 8:
            continue
        try:  # a coarse level only starts the next one; the full grid decides what fails
            start, steps, _, _ = _iterate(
                (coarse[0], coarse[1], coarse[2] >= 0.5), (step_m[0] * factor, step_m[1] * factor),
                settings, shift, factor * settings.tolerance_m, counted(ran), limit,
            )  # fmt: skip
        except CoregistrationError:
            continue
        ran += len(steps)
        # kept only if it brings the full grids closer (a coarse level cannot lead astray)
        spreads = (_spread(dsm, ref, stable, v, step_m, settings) for v in (start, shift))
        if next(spreads) <= next(spreads):
            shift = start
            increments += steps
    shift, steps, converged, fit_cells = _iterate(
        (dsm, ref, stable), step_m, settings, shift, settings.tolerance_m, counted(ran), limit
    )
    increments += steps
    ran += len(steps)
    result = _vertical(dsm, ref, stable, shift, step_m, settings, ran, converged, increments)
    result = replace(result, fit_cells=fit_cells)
    if not converged:
        last = math.hypot(*increments[-1])
        warnings.warn(
            f"co-registration did not converge in {settings.max_iterations} iterations on the "
            f"full grid (last increment {last:.3f} m > {settings.tolerance_m} m); the last "
            f"shift is reported, the statistics before and after it over the same "
            f"{result.after.cells} cells",
            CoregistrationWarning,
            stacklevel=2,
        )
    before, after = result.before, result.after
    if after.nmad_m > 1.05 * before.nmad_m + 1e-3:
        warnings.warn(
            f"co-registration left the heights further apart (NMAD {before.nmad_m:.3f} m before, "
            f"{after.nmad_m:.3f} m after): check that DSM and REF show the same terrain",
            CoregistrationWarning,
            stacklevel=2,
        )
    return result


def _vertical(dsm, ref, stable, shift, step_m, settings, ran, converged, increments):
    """The :class:`Coregistration` of the horizontal ``shift`` (east, north): ``dz`` (and the
    plane with ``settings.tilt``) from the inliers of ``DSM moved - REF``, the statistics before
    and after (over the same cells when not ``converged``)."""
    both = stable & np.isfinite(dsm)
    dh = shift_heights(dsm, (shift[0], shift[1], 0.0), step_m) - ref
    usable = stable & np.isfinite(dh)
    if not converged:  # the same cells before and after: no improvement by losing cells
        both = usable = both & usable
    dh, gradient = _detrended(dh, usable, step_m, settings)
    inlier, _ = _inliers(dh, usable, settings.nmad_k)
    dz = -float(np.median(dh[inlier]))
    return Coregistration(
        shift_m=(float(shift[0]), float(shift[1]), dz),
        before=dh_stats(dsm[both] - ref[both]),
        after=dh_stats(dh[usable] + dz),
        iterations=ran,
        converged=converged,
        fit_cells=int(inlier.sum()),
        increments_m=tuple(increments),
        tilt_m_per_m=(-gradient[0], -gradient[1]),
    )
