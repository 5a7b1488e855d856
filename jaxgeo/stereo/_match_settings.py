"""How images are matched (:class:`MatchSettings`, for :func:`~jaxgeo.stereo.tie_points` and
:func:`~jaxgeo.stereo.match_images`), and what a matching that cannot run as asked raises."""

from __future__ import annotations

import math
import numbers
from collections.abc import Sequence
from dataclasses import dataclass

from ..errors import JaxgeoError, JaxgeoWarning

DEM_MARGIN_M = 50.0
"""The DEM's heights over the footprint are widened by this much (m) by default."""


class TieError(JaxgeoError, ValueError):
    """Tie points cannot be searched as asked (an ROI outside the image, a height range that is
    empty or outside the models' validity, a DEM of another place)."""


class TieWarning(JaxgeoWarning):
    """Tie points were found, but under an assumption the user should know about (or too few
    of them in a pair)."""


@dataclass(frozen=True)
class MatchSettings:
    """How images are matched: :func:`~jaxgeo.stereo.tie_points` (a pair) and
    :func:`~jaxgeo.stereo.match_images` (every pair of several images) take it. Checked when
    made (a :class:`TieError`, a ``ValueError``, naming the field).

    Attributes:
        roi: ``(col, row, width, height)`` px of the first image (of the pair): only its
            keypoints are searched; ``None``: the whole image.
        height_range_m: ``(h_min, h_max)`` ellipsoidal m of the terrain, searched along the
            epipolar curves; ``None``: from the DEM given, else from a coarse matching.
        epipolar_tol_px: how far from the models' epipolar curves a match may lie (the models'
            relative bias), px.
        ratio: Lowe's ratio test, best / second-best descriptor distance below it.
        dem_margin_m: the DEM's heights over the footprint are widened by this, m.
        sigma_px: a priori sigma of the tie observations (``match_images``), px.
        few_ties: fewer ties than this in a pair: a :class:`TieWarning` naming the pair
            (``match_images``; too few to adjust the pair reliably).
        keypoints: about this many keypoints of image 1's ROI searched, the strongest of each
            part of it (image 2's window keeps as many per pixel); ``None``: all. Where a few
            hundred ties do (a height range, a rectification) a cap saves most of SIFT's and
            the matching's cost.
    """

    roi: Sequence[int] | None = None  # stored as a tuple
    height_range_m: Sequence[float] | None = None  # stored as a tuple
    epipolar_tol_px: float = 10.0
    ratio: float = 0.8
    dem_margin_m: float = DEM_MARGIN_M
    sigma_px: float = 0.5
    few_ties: int = 20
    keypoints: int | None = None

    def __post_init__(self):
        def bad(name, need):
            return TieError(f"MatchSettings: {name}={getattr(self, name)!r}: {need}")

        def real(v):
            return isinstance(v, numbers.Real) and math.isfinite(v)

        def items(v):
            try:
                return tuple(v)
            except TypeError:
                return ()

        if self.roi is not None:
            roi = items(self.roi)
            if len(roi) != 4 or not all(real(v) and v == int(v) for v in roi):
                raise bad("roi", "need four integers (col, row, width, height) px")
            col, row, w, h = (int(v) for v in roi)
            if col < 0 or row < 0 or w <= 0 or h <= 0:
                raise bad("roi", "need col, row >= 0 and width, height > 0 (px)")
            object.__setattr__(self, "roi", (col, row, w, h))
        if self.height_range_m is not None:
            hr = items(self.height_range_m)
            if len(hr) != 2 or not (all(map(real, hr)) and hr[0] < hr[1]):
                raise bad("height_range_m", "need finite HMIN < HMAX (m, ellipsoidal)")
            object.__setattr__(self, "height_range_m", (float(hr[0]), float(hr[1])))
        if not (real(self.epipolar_tol_px) and self.epipolar_tol_px > 0):
            raise bad("epipolar_tol_px", "the epipolar tolerance must be a number > 0 (px)")
        if not (real(self.ratio) and 0 < self.ratio <= 1):
            raise bad("ratio", "Lowe's ratio must be in (0, 1]")
        if not (real(self.dem_margin_m) and self.dem_margin_m >= 0):
            raise bad("dem_margin_m", "must be a number >= 0 (m)")
        if not (real(self.sigma_px) and self.sigma_px > 0):
            raise bad("sigma_px", "must be a number > 0 (px)")
        if not (isinstance(self.few_ties, numbers.Integral) and self.few_ties >= 0):
            raise bad("few_ties", "must be an integer >= 0")
        if self.keypoints is not None and not (
            isinstance(self.keypoints, numbers.Integral) and self.keypoints > 0
        ):
            raise bad("keypoints", "must be an integer > 0, or None (all)")
