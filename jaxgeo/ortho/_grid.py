"""The ground footprint of an image on a DEM and the output grid of its orthoimage (its default
resolution: :func:`common_resolution`; its cells: :meth:`jaxgeo.tiles.OutputGrid.covering`)."""

from __future__ import annotations

import math
import warnings

import numpy as np

from .._runtime.kept import kept_points
from ..errors import JaxgeoWarning
from ..geodesy import utm_epsg, utm_zone
from ..io.internal import dem_against_model, dem_coverage
from ..tiles import OutputGrid

BATCH = 64
"""Host-side localisations run in chunks of ``BATCH`` points (the last one padded): one shape,
one program, whatever the number of points (the border's 64, the GSD's 3)."""
ON_DEM_STEPS = 24
"""Regula falsi (Illinois) steps of :func:`on_dem`."""
ON_DEM_TOL_M = 0.01
"""A point of :func:`on_dem` is kept when ``|DEM(ground) - h|`` ends below this (m)."""
COMMON_STEPS = (1.0, 1.2, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 6.0, 8.0)
"""The default resolution of an orthoimage is the image's GSD rounded to the nearest (in ratio)
of these times a power of ten: within 16 % of the GSD, and the same for the views of one
scene whose GSDs differ by a few percent (0.497, 0.521, 0.532 m on a Pleiades triplet: 0.5 m),
so that their orthoimages share a grid (with target-aligned pixels) at default settings."""


@kept_points(BATCH)
def _at_height(model, xy, h):
    """Image points ``xy`` ``(n, 2)`` localised at heights ``h`` ``(n,)``: ``(n, 3)``."""
    return model.localize(xy, h)


@kept_points(BATCH)
def _dem_height(grid, lonlat):
    """The DEM ``grid``'s bilinear height at ``lonlat`` ``(n, 2)`` (NaN outside, on nodata)."""
    return grid.height(lonlat)


def on_dem(model, xy: np.ndarray, grid) -> tuple[np.ndarray, np.ndarray]:
    """Ground points ``(n, 3)`` where image points ``xy`` ``(n, 2)`` meet the DEM ``grid``, and
    which did (bool ``(n,)``).

    The footprint and the GSD need an intersection of each line of sight with the DEM, not
    the first one :func:`~jaxgeo.models.localize_on_dem` marches to (hidden terrain decides no
    border of a footprint): a root of ``f(h) = DEM(localize(xy, h)) - h`` between the grid's
    lowest (``f >= 0``) and highest (``f <= 0``) heights by the Illinois method, its steps on
    the host around two kept programs of ``BATCH`` points (a localisation at given heights, a
    DEM height), the programs the rest of the plan runs: a warm run loads no other (one program
    with the whole loop held two localisations; loading its 1.4 MB executable took 0.27 s of
    every ``jaxgeo ortho``, compiling it 2.5 s of the first). The best point of each line is
    kept: the ground point of the smallest ``|f|`` met.
    """
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    n = len(xy)
    z = np.asarray(grid.heights_m)
    lo, hi = float(np.nanmin(z)) - 1.0, float(np.nanmax(z)) + 1.0

    def f(h):
        g = _at_height(model, xy, h)
        return g, _dem_height(grid, g[:, :2]) - h

    with np.errstate(invalid="ignore", divide="ignore"):  # NaN: no height there, never kept
        a, b = np.full(n, lo), np.full(n, hi)
        (g_a, fa), (g_b, fb) = f(a), f(b)
        g = np.where((np.abs(fa) < np.abs(fb))[:, None], g_a, g_b)
        best = np.where(np.isfinite(fa) | np.isfinite(fb), np.fmin(np.abs(fa), np.abs(fb)),
                        np.inf)  # fmt: skip
        side = np.zeros(n, dtype=int)
        for _ in range(ON_DEM_STEPS):
            den = fb - fa
            c = np.where(np.abs(den) > 1e-12, (a * fb - b * fa) / np.where(den == 0, 1, den),
                         0.5 * (a + b))  # fmt: skip
            gc, fc = f(c)
            better = np.abs(fc) < best
            g = np.where(better[:, None], gc, g)
            best = np.where(better, np.abs(fc), best)
            to_b = fc * fb > 0  # c replaces b (same sign)
            fa = np.where(to_b & (side == -1), 0.5 * fa, fa)
            fb = np.where(~to_b & (side == 1), 0.5 * fb, fb)
            a, fa = np.where(to_b, a, c), np.where(to_b, fa, fc)
            b, fb = np.where(to_b, c, b), np.where(to_b, fc, fb)
            side = np.where(to_b, -1, 1)
            if not np.any(best > 1e-6):  # all within a micron (a point without heights: inf)
                break
    ok = np.isfinite(best) & (best < ON_DEM_TOL_M) & np.all(np.isfinite(g), axis=-1)
    return g, ok


def border_pixels(width: int, height: int, n: int = 16) -> np.ndarray:
    """``(4n, 2)`` points along the image's outer pixel edges (jaxgeo ``(x, y)``)."""
    t = np.linspace(0.0, 1.0, n, endpoint=False)
    x0, x1, y0, y1 = -0.5, width - 0.5, -0.5, height - 0.5
    top = np.stack([x0 + t * (x1 - x0), np.full(n, y0)], -1)
    right = np.stack([np.full(n, x1), y0 + t * (y1 - y0)], -1)
    bottom = np.stack([x1 - t * (x1 - x0), np.full(n, y1)], -1)
    left = np.stack([np.full(n, x0), y1 - t * (y1 - y0)], -1)
    return np.concatenate([top, right, bottom, left])


def rough_bounds(model, border_xy: np.ndarray, dh_m: float = 500.0, heights=None):
    """lon/lat box of the border localised at the model's reference height +- ``dh_m`` (or at
    ``(h_min, h_ref, h_max)`` given as ``heights``), and the box at the middle height."""
    h0 = float(np.asarray(model.reference_ground())[2])  # numpy: no eager jax program
    pts = []
    for h in heights if heights is not None else (h0 - dh_m, h0, h0 + dh_m):
        g = np.asarray(_at_height(model, border_xy, np.full(len(border_xy), float(h))))
        pts.append(g[:, :2])
    pts = np.concatenate(pts)
    if not np.all(np.isfinite(pts)):
        raise ValueError("the model cannot localise the image border (localisation failed)")
    at_ref = pts[len(border_xy) : 2 * len(border_xy)]
    lo, hi = pts.min(0), pts.max(0)
    pad = 0.05 * (hi - lo)
    box = (lo[0] - pad[0], lo[1] - pad[1], hi[0] + pad[0], hi[1] + pad[1])
    ref_box = (*at_ref.min(0), *at_ref.max(0))
    return box, ref_box


def dem_for_image(model, dem, width: int, height: int, source: str = "image", need=None):
    """The :class:`DEMGrid` around the image footprint (clipped to the DEM); error if the DEM
    does not cover the footprint, or, given ``need`` (the lon/lat box of the requested output,
    e.g. its bounds), the part of the footprint in ``need``: a DEM that covers the output is
    enough; error if its heights there lie outside the model's validity range
    (:func:`jaxgeo.io.internal.dem_against_model`)."""
    border = border_pixels(width, height)
    box, ref_box = rough_bounds(model, border)
    check, what = ref_box, f"the footprint of {source}"
    if need is not None:
        inner = (max(ref_box[0], need[0]), max(ref_box[1], need[1]), min(ref_box[2], need[2]),
                 min(ref_box[3], need[3]))  # fmt: skip
        if inner[2] > inner[0] and inner[3] > inner[1]:  # else: the bounds' own check says so
            check, what = inner, f"the requested output over {source}"
    cover = dem_coverage(dem, check)
    if cover < 1.0 - 1e-9:
        b = dem.bounds_lonlat
        raise ValueError(
            f"{dem.path}: the DEM covers only {100 * cover:.1f}% of {what} (lon "
            f"{check[0]:.5f}..{check[2]:.5f}, lat {check[1]:.5f}..{check[3]:.5f}); it spans lon "
            f"{b[0]:.5f}..{b[2]:.5f}, lat {b[1]:.5f}..{b[3]:.5f}: give output bounds inside it, "
            "or a DEM that covers it (or a fill DEM: fill=)"
        )
    b = dem.bounds_lonlat

    def clip(box):
        return (max(box[0], b[0]), max(box[1], b[1]), min(box[2], b[2]), min(box[3], b[3]))

    grid = dem.grid(clip(box))
    # second pass: the footprint at the DEM's own height range, which the first box may miss
    z = np.asarray(grid.heights_m)
    lo, hi = float(np.nanmin(z)), float(np.nanmax(z))
    box2, _ = rough_bounds(model, border, heights=(lo - 10.0, 0.5 * (lo + hi), hi + 10.0))
    if not (box2[0] >= box[0] and box2[1] >= box[1] and box2[2] <= box[2] and box2[3] <= box[3]):
        box = (min(box[0], box2[0]), min(box[1], box2[1]), max(box[2], box2[2]),
               max(box[3], box2[3]))  # fmt: skip
        grid = dem.grid(clip(box))
    why = dem_against_model(z, model, str(dem.path), source)  # feet, hundreds of metres off
    if why is not None:
        raise ValueError(why)
    return grid


def footprint(
    model, grid, width: int, height: int, source: str = "the DEM", warn: bool = True
) -> np.ndarray:
    """``(m, 3)`` ground points of the image border on the DEM.

    Border points whose line of sight meets no DEM height (the DEM's nodata: a DSM's holes, its
    area outside a stereo overlap) are placed at the DEM's median height, so that the product
    still spans the whole image (nodata there), with a warning naming ``source``; a border
    that meets the DEM nowhere is an error. With ``warn`` false (output bounds the DEM covers:
    the border need not meet it) neither."""
    border = border_pixels(width, height)
    g, ok = on_dem(model, border, grid)
    if ok.all():
        return g
    if not ok.any() and warn:
        raise ValueError(
            f"{source}: no point of the image border meets a DEM height: the DEM (or its valid "
            "cells) does not cover the image footprint"
        )
    z = np.asarray(grid.heights_m)
    h = float(np.nanmedian(z))
    far = np.asarray(_at_height(model, border[~ok], np.full(int((~ok).sum()), h)))
    if not np.all(np.isfinite(far)):
        raise ValueError(f"{source}: the model cannot localise the image border")
    if warn:
        warnings.warn(
            f"{source}: {100 * (1 - ok.mean()):.0f}% of the image border falls where the DEM "
            f"has no height ({100 * np.isnan(z).mean():.0f}% of its cells under the image are "
            "nodata): the orthoimage is nodata there",
            JaxgeoWarning,
            stacklevel=2,
        )
    out = g.copy()
    out[~ok] = far
    return out


def default_crs(lonlat: np.ndarray):
    """The WGS84 UTM zone of the centre of ``lonlat`` points."""
    import pyproj

    lon, lat = np.mean(lonlat[:, 0]), np.mean(lonlat[:, 1])
    return pyproj.CRS.from_epsg(utm_epsg(utm_zone(float(lon)), bool(lat >= 0)))


def ground_sample_distance(model, grid, crs, width: int, height: int) -> float:
    """Geometric mean ground size (CRS units) of a pixel at the image centre, on the DEM."""
    import pyproj

    c = np.array([(width - 1) / 2, (height - 1) / 2])
    pts = np.stack([c, c + [1.0, 0.0], c + [0.0, 1.0]])
    g, ok = on_dem(model, pts, grid)
    if not np.all(ok):  # a hole of the DEM under the centre: at its median height
        h = float(np.nanmedian(np.asarray(grid.heights_m)))
        g = np.asarray(_at_height(model, pts, np.full(len(pts), h)))
    tr = pyproj.Transformer.from_crs(4326, crs, always_xy=True)
    x, y = tr.transform(g[:, 0], g[:, 1])
    a = np.array([[x[1] - x[0], x[2] - x[0]], [y[1] - y[0], y[2] - y[0]]])
    return float(math.sqrt(abs(np.linalg.det(a))))


def common_resolution(gsd: float) -> float:
    """``gsd`` (CRS units, > 0) rounded to the nearest of :data:`COMMON_STEPS` times a power of
    ten, the nearest in ratio (``0.532 -> 0.5``, ``0.56 -> 0.6``, ``2.2 -> 2``, ``0.31 -> 0.3``);
    ``float(repr)``-clean (``0.5``, not ``0.5000000000000001``)."""
    if not (math.isfinite(gsd) and gsd > 0):
        raise ValueError(f"a GSD must be a positive number, got {gsd}")
    exp = math.floor(math.log10(gsd))
    steps = [*COMMON_STEPS, 10.0]
    mantissa = gsd / 10.0**exp
    best = min(steps, key=lambda m: abs(math.log(mantissa / m)))
    return float(f"{best}e{exp}")


def output_grid(ground: np.ndarray, crs, res_m: float, bounds=None, tap: bool = True) -> OutputGrid:
    """The grid of ``res_m`` pixels covering ``ground`` lon/lat points (or ``bounds`` W S E N in
    ``crs``); ``tap``: its edges on multiples of ``res_m`` (:meth:`OutputGrid.covering`)."""
    import pyproj

    if bounds is None:
        tr = pyproj.Transformer.from_crs(4326, crs, always_xy=True)
        x, y = tr.transform(ground[:, 0], ground[:, 1])
        bounds = (np.min(x), np.min(y), np.max(x), np.max(y))
    return OutputGrid.covering(bounds, crs, res_m, tap)
