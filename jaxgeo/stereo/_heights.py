"""The heights a DSM's plan searches (:func:`~._tiled.plan_dsm`): the terrain's height range
under the ROI from the tie points of five windows of the reference (each tile's window is
projected at it), and the range each tile's own tie points search (that range widened, so that no
tile matches coarsely over the models' whole validity range first)."""

from __future__ import annotations

import dataclasses

import numpy as np

from ._dem_check import window_tie_ground
from ._match_settings import TieError
from ._ties import MatchSettings, tie_points, validity_heights
from ._triangulation import los_heights

SAMPLE_WINDOW_PX = 512
"""Side (px) of the five reference windows whose tie points give a scene's height range."""
HEIGHT_MARGIN_M = 50.0
"""Metres (at least; a quarter of the span if more) added on both sides of the sampled heights."""


def scene_heights(models, paths, roi) -> tuple[float, float] | None:
    """The terrain's height range (m) under ``roi = (col, row, w, h)`` of the first image, from
    the tie points of the pair (first, second) in five windows of :data:`SAMPLE_WINDOW_PX` (the
    centre and the four quarters' centres): their 0.5-99.5 percentiles widened by
    :data:`HEIGHT_MARGIN_M` or a quarter of the span; ``None`` with fewer than 20 ties. A tile's
    reference window is projected at these heights: the models' whole validity range instead
    (hundreds of metres) widens every window by its parallax (a 1 Mpx tile read 1.7 Mpx)."""
    return sampled_heights(models, paths, sample_windows(roi), los_heights(models[0]))


def sample_windows(roi) -> list[tuple[int, int, int, int]]:
    """The five windows of :func:`scene_heights` in ``roi`` (repeated in a small ROI)."""
    col, row, w, h = roi
    side = min(SAMPLE_WINDOW_PX, w, h)
    windows = []
    for fx, fy in ((0.5, 0.5), (0.25, 0.25), (0.75, 0.25), (0.25, 0.75), (0.75, 0.75)):
        c0 = int(min(max(col + fx * w - side / 2, col), col + w - side))
        r0 = int(min(max(row + fy * h - side / 2, row), row + h - side))
        windows.append((c0, r0, side, side))
    return windows


def sampled_heights(models, paths, windows, limits) -> tuple[float, float] | None:
    """The 0.5-99.5 percentiles of the tie points' heights in ``windows`` widened by
    :data:`HEIGHT_MARGIN_M` or a quarter of the span, within ``limits``; ``None`` with fewer
    than 20 ties."""
    found = []
    for window in windows:
        ground = window_tie_ground(models, paths, window)
        if ground is not None:  # else no texture there: the other windows
            found.append(ground[:, 2])
    heights = np.concatenate(found) if found else np.zeros(0)
    heights = heights[np.isfinite(heights)]
    if heights.size < 20:
        return None
    lo, hi = (float(v) for v in np.percentile(heights, [0.5, 99.5]))
    margin = max(HEIGHT_MARGIN_M, 0.25 * (hi - lo))
    lo, hi = max(lo - margin, limits[0]), min(hi + margin, limits[1])
    return (lo, hi) if lo < hi else None


def tile_tie_heights(models, heights, source) -> tuple[float, float] | None:
    """The height range (m) a tile's tie points search, from the plan's ``heights`` and their
    ``source`` (:func:`dsm_heights`): as given, the DEM's, or the sampled tie points' widened
    once more by their margin (:data:`HEIGHT_MARGIN_M` or a quarter of the span; the models'
    common validity range at most): a tile's ties reach terrain a little beyond what the five
    windows saw, and its disparity range follows them. ``None`` (each tile matches coarsely
    over the validity range first) when nothing measured the heights."""
    if source in ("given", "dem"):
        return tuple(float(v) for v in heights)
    if source != "tie points":
        return None
    lo, hi = heights
    margin = max(HEIGHT_MARGIN_M, 0.25 * (hi - lo))
    valid = [validity_heights(m) for m in models]
    lo, hi = max(lo - margin, *(v[0] for v in valid)), min(hi + margin, *(v[1] for v in valid))
    return (float(lo), float(hi)) if lo < hi else None


END_FRACTION = 0.1
END_SHARE = 0.02
"""A range searched is too narrow for a tile when more than ``END_SHARE`` of its tie points (and
at least 5) lie within ``END_FRACTION`` of its span from one end (:func:`crowded_ends`)."""
WIDENINGS = 2
"""How many times a tile widens its tie points' height range (each time by its span at the
crowded ends) before it falls back to a coarse matching over the models' validity range."""


def crowded_ends(
    heights: np.ndarray | None, searched: tuple[float, float], limits=(-np.inf, np.inf)
) -> tuple[bool, bool]:
    """Whether tie points of ``heights`` (m; ``None``: too few ties, both ends) crowd the low
    and the high end of the height range ``searched``, each only inside ``limits`` (the models'
    validity range: nothing is searched beyond it): the terrain may go on beyond that end (a
    steep tile beyond what the plan's five windows saw, a ``--heights`` too narrow), where no
    tie is found and the disparity range stops short.

    Why: a plan's range is the windows' heights widened twice (:func:`tile_tie_heights`), so
    a tile inside it has its ties well within; ties cut off at an end show the terrain beyond."""
    lo, hi = searched
    if heights is None:
        return lo > limits[0], hi < limits[1]
    h = np.asarray(heights, float)
    h = h[np.isfinite(h)]
    edge = END_FRACTION * (hi - lo)
    least = max(5.0, END_SHARE * len(h))
    low = lo > limits[0] and np.sum(h < lo + edge) >= least
    return bool(low), bool(hi < limits[1] and np.sum(h > hi - edge) >= least)


def ties_over_terrain(models, paths, match: MatchSettings, dem, features, least: int):
    """:func:`~._ties.tie_points` of ``models = (ref, sec)`` over ``match.height_range_m``; when
    those ties crowd an end of it inside the models' validity range (:func:`crowded_ends`) or
    are fewer than ``least``, again over the range widened by its span at those ends (up to
    :data:`WIDENINGS` times), then over a coarse matching's range. A DEM's range is kept.
    ``features = (f1, f2, keypoints)``: image 1's keypoints, image 2's, and the function giving
    both where a height range puts the ROI in image 2 (keypoints of one resolution level: OpenCV's
    SIFT places a keypoint of its doubled first octave a quarter pixel off, so a
    half-resolution reference with full-resolution secondary keypoints measured a false
    0.25 px vertical disparity). Returns the ties and whether the range was widened."""
    (ref, sec), (f1, f2, keypoints) = models, features
    if match.height_range_m is None or dem is not None:
        return tie_points(ref, sec, *paths, match, dem=dem, features1=f1, features2=f2), False
    valid = [validity_heights(m) for m in models]
    limits = (max(v[0] for v in valid), min(v[1] for v in valid))
    for k in range(WIDENINGS + 1):
        try:
            ties = tie_points(ref, sec, *paths, match, features1=f1, features2=f2)
        except TieError:
            ties = None
        h = None if ties is None or len(ties) < least else ties.ground[:, 2]
        low, high = crowded_ends(h, match.height_range_m, limits)
        if ties is not None and not (low or high):
            return ties, k > 0
        if not (low or high):
            break
        lo, hi = match.height_range_m
        span = hi - lo
        wider = (
            max(lo - span, limits[0]) if low else lo,
            min(hi + span, limits[1]) if high else hi,
        )
        match = dataclasses.replace(match, height_range_m=wider)
        f1, f2 = keypoints(wider)
    # both images' own full-resolution search over a coarse matching's range
    return tie_points(ref, sec, *paths, dataclasses.replace(match, height_range_m=None)), True
