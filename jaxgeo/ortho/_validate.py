"""Checks of an orthoimage's options before any tile is computed: CRS, resolution, bounds, size.

Each refusal is an :class:`OrthoError` (a ``ValueError``) whose one-line message names the option
at fault and what would have happened: an invalid CRS, a resolution that is not positive or, in a
geographic CRS, that looks like metres given as degrees, bounds that miss the image's footprint
(a product with no data), a product over the pixel limit or of a handful of pixels.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import JaxgeoError

MAX_PIXELS = 2_000_000_000
"""Products above this many pixels are refused unless asked (``max_pixels``): a 40 000 x 42 000
px Pleiades scene at its GSD is 1.7e9 px; more is usually a resolution typed wrong."""
MIN_SIDE_PX = 8
"""An output narrower than this (px) is refused: a resolution far coarser than the footprint."""
DEGREES_AS_METRES = 50.0
"""In a geographic CRS, a resolution of at least 0.01 degree and this many times the image's GSD
(in degrees) is taken for metres given as degrees."""
M_PER_DEG = 111_320.0


class OrthoError(JaxgeoError, ValueError):
    """An orthoimage that cannot be made as asked (options, footprint, size); nothing written."""


def check_crs(crs):
    """The pyproj CRS of ``crs`` (anything pyproj takes); a horizontal 2-D one."""
    import pyproj

    try:
        out = pyproj.CRS.from_user_input(crs)
    except pyproj.exceptions.CRSError as err:
        first = str(err).split("\n")[0].split(": (")[0]
        raise OrthoError(f"invalid CRS {str(crs)!r}: {first}") from None
    if out.is_compound:
        out = next((c for c in out.sub_crs_list if not c.is_vertical), out)
    if not (out.is_projected or out.is_geographic) or out.is_geocentric:
        raise OrthoError(f"CRS {str(crs)!r} ({out.name}) is not a map CRS (projected or "
                         "geographic)")  # fmt: skip
    return out


def check_res(res, crs, gsd_m: float | None) -> float:
    """``res`` (CRS units) as a float: finite and > 0; in a geographic CRS not metres."""
    try:
        value = float(res)
    except (TypeError, ValueError):
        raise OrthoError(f"resolution {res!r}: not a number") from None
    if not math.isfinite(value) or value <= 0:
        raise OrthoError(f"resolution must be > 0 (CRS units), got {res}")
    if gsd_m and crs.is_geographic:
        gsd_deg = gsd_m / M_PER_DEG
        if value >= 0.01 and value >= DEGREES_AS_METRES * gsd_deg:
            raise OrthoError(
                f"resolution {value:g} in the geographic CRS {crs.name} is {value:g} degrees "
                f"(~{value * M_PER_DEG / 1000:.3g} km a pixel, {value / gsd_deg:.3g} x the "
                f"image's GSD): degrees given as metres? The GSD is {gsd_deg:.3g} degrees "
                f"({gsd_m:.3g} m)"
            )
    return value


def check_bounds(bounds) -> tuple[float, float, float, float]:
    """``(W, S, E, N)``: four finite numbers, W < E and S < N."""
    try:
        w, s, e, n = (float(v) for v in bounds)
    except (TypeError, ValueError):
        raise OrthoError(f"bounds {bounds!r}: expected four numbers W S E N") from None
    if not all(map(math.isfinite, (w, s, e, n))):
        raise OrthoError(f"bounds {bounds!r}: not finite")
    if not (e > w and n > s):
        raise OrthoError(f"bounds W S E N = {w:g} {s:g} {e:g} {n:g} are empty: need W < E and "
                         "S < N")  # fmt: skip
    return w, s, e, n


def clip_polygon(poly: np.ndarray, box) -> np.ndarray:
    """The part of polygon ``poly`` ``(n, 2)`` inside ``box`` ``(W, S, E, N)`` (Sutherland-Hodgman;
    may be empty)."""
    w, s, e, n = box
    pts = [tuple(p) for p in poly]
    for axis, limit, keep_above in ((0, w, True), (0, e, False), (1, s, True), (1, n, False)):
        out = []
        for i, cur in enumerate(pts):
            prev = pts[i - 1]
            cur_in = cur[axis] >= limit if keep_above else cur[axis] <= limit
            prev_in = prev[axis] >= limit if keep_above else prev[axis] <= limit
            if cur_in != prev_in:
                t = (limit - prev[axis]) / (cur[axis] - prev[axis])
                out.append(tuple(prev[k] + t * (cur[k] - prev[k]) for k in range(2)))
            if cur_in:
                out.append(cur)
        pts = out
        if not pts:
            break
    return np.asarray(pts, dtype=float).reshape(-1, 2)


def polygon_area(poly: np.ndarray) -> float:
    if len(poly) < 3:
        return 0.0
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))


def check_bounds_cover(bounds, footprint_xy: np.ndarray, source: str, what: str = "") -> float:
    """Fraction of ``bounds`` covered by the image footprint polygon ``footprint_xy`` (output
    CRS); an :class:`OrthoError` when it is zero (the product would hold no data). ``what``:
    where the bounds come from (default: the bounds given)."""
    w, s, e, n = bounds
    inside = polygon_area(clip_polygon(footprint_xy, bounds))
    fraction = inside / ((e - w) * (n - s))
    if fraction <= 0:
        lo, hi = footprint_xy.min(0), footprint_xy.max(0)
        raise OrthoError(
            f"{what or 'bounds'} W S E N = {w:.10g} {s:.10g} {e:.10g} {n:.10g} "
            f"{'lies' if what else 'lie'} outside the footprint of {source} "
            f"(it spans {lo[0]:.6g}..{hi[0]:.6g}, {lo[1]:.6g}..{hi[1]:.6g} in the output CRS): "
            "the product would hold no data"
        )
    return fraction


def check_size(width: int, height: int, res: float, max_pixels: float | None, gsd: float,
               min_side: int = MIN_SIDE_PX):  # fmt: skip
    """Refuse a ``width`` x ``height`` product over ``max_pixels`` (``None`` or 0: no limit) or
    with a side under ``min_side`` px (a grid taken from another raster: its own shape)."""
    if min(width, height) < min_side:
        raise OrthoError(
            f"the product would be {width} x {height} px at resolution {res:g}: far coarser "
            f"than the footprint allows (the image's GSD is {gsd:.3g} in CRS units); check "
            "the resolution (--res)"
        )
    n = width * height
    if max_pixels and n > max_pixels:
        raise OrthoError(
            f"the product would be {width} x {height} = {n:.3g} px at resolution {res:g} (the "
            f"image's GSD is {gsd:.3g} in CRS units), over the limit of {max_pixels:.3g} px: "
            "check the resolution and bounds, or raise the limit (--max-pixels, 0 = none)"
        )
