"""Tie points that are true by default: guided SIFT matches, each one verified geometrically.

:func:`tie_points` matches two images whose models work in their rasters' pixels
(:func:`jaxgeo.io.open_image` gives such models, crops included), as :class:`MatchSettings`
says (:func:`jaxgeo.stereo.match_images` matches every pair of several images):

1. **Height range**, the search range along the epipolar curves and a check on every tie, from
   (``TieReport.height_source``): ``"given"`` (``height_range_m``); ``"dem"``: the DEM's
   heights over the footprint of the ROI (its corners and edges localised on the DEM,
   iterated), +- ``dem_margin_m``, within the models' RPC validity range; ``"coarse matching"``: a
   sparse subset of keypoints matched over the whole validity range with a strict ratio test,
   verified as below, their heights' 1st-99th percentiles widened by ``max(30 m, 25 %)``;
   ``"rpc validity"`` when that finds too few ties.
2. **Matching** within ``epipolar_tol_px`` of the epipolar segments over that range, Lowe's ratio
   test (:func:`~jaxgeo.stereo.epipolar_candidates`).
3. **Checks**, each counted in ``TieReport.rejected``: ``duplicate`` (one SIFT keypoint with
   several orientations matched more than once: collapsed to one tie); ``ambiguous`` (a
   location of one image matched to several locations of the other: the best kept if it passes
   the ratio test against the next, else none; matches are one to one); ``across_epipolar``
   (the offset across the epipolar curves is the pair's relative bias, one smooth value: a tie
   farther than ``max(3.5 sigma, 0.5 px)`` from its robust affine trend over image 1 is
   dropped); ``triangulation`` (no converged intersection); ``height_range`` (triangulated
   height outside the range); ``residual`` (reprojection residual, each image's median
   removed, above ``max(4 sigma, 0.5 px)``); ``height_neighbours`` (height farther from the
   median of its 8 nearest ties than ``max(20 m, 5 sigma, 3x`` the neighbours' own spread``)``:
   a gross mismatch along the epipolar curve).

Heights are triangulated with :func:`jaxgeo.stereo.triangulate` (the models' relative bias left
in: a pair's uncorrected pointing shifts them by metres). Image coordinates are pixels of the
rasters (integer = pixel centre); heights ellipsoidal metres.
"""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass, field

import numpy as np

from ..io.internal import dem_against_ties, open_raster
from ..models import AbstractSensorModel
from ._match_settings import MatchSettings, TieError, TieWarning
from ._matching import Candidates, Features, epipolar_candidates, sift_features_raster
from ._rectification import _batched, _loc, _transfer
from ._triangulation import triangulate

CHECKS = ("duplicate", "ambiguous", "across_epipolar", "triangulation", "height_range",
          "residual", "height_neighbours")  # fmt: skip
"""The checks of a tie, in the order they run (keys of ``TieReport.rejected``)."""
CHECK_LABELS = {
    "duplicate": "duplicate",
    "ambiguous": "ambiguous",
    "across_epipolar": "across the epipolar curve",
    "triangulation": "not triangulated",
    "height_range": "height outside the range",
    "residual": "reprojection residual",
    "height_neighbours": "height unlike its neighbours'",
}
"""How :meth:`TieReport.summary` names each check's rejections."""
COARSE_KEYPOINTS = 2000
COARSE_RATIO = 0.6
COARSE_MIN_TIES = 20
COARSE_MARGIN_M = 30.0
COARSE_MARGIN_FRACTION = 0.25
NON_RPC_HALF_RANGE_M = 1000.0
ACROSS_K, ACROSS_FLOOR_PX = 3.5, 0.5
RESIDUAL_K, RESIDUAL_FLOOR_PX = 4.0, 0.5
NEIGHBOURS, NEIGHBOUR_K, NEIGHBOUR_FLOOR_M = 8, 5.0, 20.0
TRIANGULATION_BLOCK = 1024
"""Ties per triangulation call (NaN-padded): one compiled shape whatever the count."""


@dataclass(frozen=True)
class TieReport:
    """What :func:`tie_points` did: ``n_keypoints`` per image, ``n_candidates`` matches passing
    the ratio test, ``n_kept`` ties, ``rejected`` per check (:data:`CHECKS`),
    ``height_range_m`` searched and its ``height_source`` (``"given"``, ``"dem"``,
    ``"coarse matching"``, ``"rpc validity"``), ``validity_m`` (the models' common RPC height
    range), ``n_coarse`` ties of the coarse matching (``None`` when not run), ``heights_m``
    p5/p50/p95 of the kept ties, ``across_px`` median offset across the epipolar curves (the
    relative bias) and ``across_sigma_px`` its robust spread about its trend; ``images`` the
    pair's names (:func:`~jaxgeo.stereo.match_images`; ``None`` from :func:`tie_points`)."""

    n_keypoints: tuple[int, int]
    n_candidates: int
    n_kept: int
    rejected: dict[str, int]
    height_range_m: tuple[float, float]
    height_source: str
    validity_m: tuple[float, float]
    n_coarse: int | None
    heights_m: tuple[float, float, float]
    across_px: float
    across_sigma_px: float
    images: tuple[str, str] | None = None

    def as_dict(self) -> dict:
        """Plain JSON-able values (NaN as ``None``; ``images`` first, left out when ``None``)."""

        def clean(v):
            if isinstance(v, dict):
                return {k: clean(x) for k, x in v.items()}
            if isinstance(v, tuple | list):
                return [clean(x) for x in v]
            if isinstance(v, float) and not np.isfinite(v):
                return None
            return v

        fields = {k: clean(v) for k, v in self.__dict__.items() if k != "images"}
        return fields if self.images is None else {"images": list(self.images), **fields}

    def summary(self) -> list[str]:
        """The human lines: ties kept of candidates and the rejections by check, the heights
        searched and their source, the ties' heights and offset across the epipolar curves."""
        a, b = self.images or ("image 1", "image 2")
        rejected = ", ".join(f"{n} {CHECK_LABELS.get(k, k)}" for k, n in self.rejected.items() if n)
        lo, hi = self.height_range_m
        v0, v1 = self.validity_m
        lines = [
            f"{a} - {b}: {self.n_kept} ties kept of {self.n_candidates} candidates"
            + (f" (rejected: {rejected})" if rejected else "")
        ]
        source = self.height_source
        if self.n_coarse is not None:
            source += f", {self.n_coarse} coarse ties"
        lines.append(
            f"  heights searched {lo:.0f}..{hi:.0f} m ({source}; models valid {v0:.0f}..{v1:.0f} m)"
        )
        if self.n_kept:
            p5, p50, p95 = self.heights_m
            lines.append(
                f"  tie heights p5/p50/p95 {p5:.1f} / {p50:.1f} / {p95:.1f} m; offset across the "
                f"epipolar curves {self.across_px:+.2f} px (sigma {self.across_sigma_px:.2f} px)"
            )
        return lines


@dataclass(frozen=True)
class TiePoints:
    """Verified ties: ``xy1``, ``xy2`` ``(n, 2)`` raster px, ``ground`` ``(n, 3)`` lon/lat/h of
    their triangulation, ``across_px`` ``(n,)`` offset across the epipolar curve, ``report``."""

    xy1: np.ndarray
    xy2: np.ndarray
    ground: np.ndarray
    across_px: np.ndarray
    report: TieReport = field(repr=False)

    @property
    def heights_m(self) -> np.ndarray:
        return self.ground[:, 2]

    def __len__(self) -> int:
        return self.xy1.shape[0]


def validity_heights(model: AbstractSensorModel) -> tuple[float, float]:
    """The ellipsoidal heights (m) over which ``model`` is valid: its RPC's ground cube ``h_off
    +- h_scale`` (the model's :meth:`base_rpc`), else its reference height +- 1000 m."""
    rpc = model.base_rpc()
    if rpc is not None:
        h0, hs = float(rpc.ground_offset[2]), abs(float(rpc.ground_scale[2]))
        return h0 - hs, h0 + hs
    h0 = float(model.reference_ground()[2])
    return h0 - NON_RPC_HALF_RANGE_M, h0 + NON_RPC_HALF_RANGE_M


def _image_size(path) -> tuple[int, int]:
    with open_raster(path) as src:
        return int(src.width), int(src.height)


def _check_roi(roi, size, path) -> tuple[int, int, int, int]:
    if roi is None:
        return (0, 0, *size)
    col, row, w, h = (int(v) for v in roi)
    if col < 0 or row < 0 or w <= 0 or h <= 0 or col + w > size[0] or row + h > size[1]:
        raise TieError(
            f"ROI x={col} y={row} w={w} h={h} is not inside {path} ({size[0]} x {size[1]} px)"
        )
    return col, row, w, h


def _roi_points(roi, n=5) -> np.ndarray:
    col, row, w, h = roi
    xs = np.linspace(col - 0.5, col + w - 0.5, n)
    ys = np.linspace(row - 0.5, row + h - 0.5, n)
    return np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)


def footprint_dem_heights(
    model: AbstractSensorModel, dem, roi: tuple[int, int, int, int], iterations: int = 8
) -> tuple[float, float]:
    """Lowest and highest DEM height (m) over the footprint of ``roi = (col, row, w, h)`` of an
    image: a 5 x 5 grid of its pixels localised on the DEM (localisation at a height, the DEM
    read there, repeated), then every DEM cell in the box they span. ``dem`` is a
    :class:`jaxgeo.io.DEM` (:func:`jaxgeo.io.read_dem`); a DEM that does not cover the footprint
    raises its ``ValueError`` naming the file. A point on a hole of the DEM (a DSM's) takes the
    median of the others' heights."""
    xy = _roi_points(roi)
    lo, hi = validity_heights(model)
    h = np.full(len(xy), (lo + hi) / 2)
    for _ in range(iterations):
        ground = _batched(_loc, (model,), xy, h)
        if not np.all(np.isfinite(ground)):
            raise TieError(f"{dem.path}: the image's corners cannot be localised on the DEM")
        h_new = np.asarray(dem.sample(ground[:, :2]), dtype=float)  # NaN: outside, a hole
        if not np.isfinite(h_new).any():
            raise TieError(f"{dem.path}: no DEM height under the ROI's footprint (outside the "
                           "DEM or on its nodata)")  # fmt: skip
        h_new = np.where(np.isfinite(h_new), h_new, np.nanmedian(h_new))
        done = np.max(np.abs(h_new - h)) < 0.5
        h = h_new
        if done:
            break
    ground = _batched(_loc, (model,), xy, h)
    box = (*ground[:, :2].min(axis=0), *ground[:, :2].max(axis=0))
    heights = np.asarray(dem.grid(box, margin_cells=1).heights_m)
    heights = heights[np.isfinite(heights)]
    if heights.size == 0:
        raise TieError(f"{dem.path}: no DEM height over the image's footprint (all nodata)")
    return float(min(heights.min(), h.min())), float(max(heights.max(), h.max()))


def _intersect_ranges(a, b):
    return max(a[0], b[0]), min(a[1], b[1])


def _window2(model1, model2, roi1, size2, h_range, margin):
    """The window ``(col, row, w, h)`` of image 2 that the ROI of image 1 sees over
    ``h_range`` (its 5 x 5 grid carried over at both ends), widened by ``margin`` px."""
    xy = _roi_points(roi1)
    pts = np.concatenate([_batched(_transfer, (model1, model2), xy, z) for z in h_range])
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    if len(pts) == 0:
        return None
    c0 = int(max(np.floor(pts[:, 0].min() - margin), 0))
    r0 = int(max(np.floor(pts[:, 1].min() - margin), 0))
    c1 = int(min(np.ceil(pts[:, 0].max() + margin), size2[0]))
    r1 = int(min(np.ceil(pts[:, 1].max() + margin), size2[1]))
    if c1 <= c0 or r1 <= r0:
        return None
    return c0, r0, c1 - c0, r1 - r0


def _robust_sigma(r) -> float:
    return float(1.4826 * np.median(np.abs(r))) if len(r) else 0.0


def _across_residuals(xy1, across) -> tuple[np.ndarray, float]:
    """``across`` minus its robust trend (constant, affine in image-1 coordinates when there are
    30 ties or more: a bias with a drift), and the robust sigma of what is left."""
    n = len(across)
    if n == 0:
        return across, 0.0
    r = across - np.median(across)
    if n < 30:
        return r, _robust_sigma(r)
    centre, scale = xy1.mean(axis=0), np.maximum(xy1.std(axis=0), 1.0)
    design = np.column_stack([np.ones(n), (xy1 - centre) / scale])
    for _ in range(5):
        sigma = _robust_sigma(r)
        inl = np.abs(r) <= max(ACROSS_K * sigma, ACROSS_FLOOR_PX)
        if inl.sum() < 10:
            break
        coef, *_ = np.linalg.lstsq(design[inl], across[inl], rcond=None)
        r = across - design @ coef
    return r, _robust_sigma(r[np.abs(r) <= max(ACROSS_K * _robust_sigma(r), ACROSS_FLOOR_PX)])


def _triangulate(model1, model2, xy1, xy2):
    n = len(xy1)
    pad = -n % TRIANGULATION_BLOCK
    pts = np.concatenate([np.stack([xy1, xy2], axis=1), np.full((pad, 2, 2), np.nan)])
    ground, res = triangulate([model1, model2], pts, chunk=TRIANGULATION_BLOCK)
    ok = np.asarray(res.converged)[:n] & np.all(np.isfinite(ground[:n]), axis=1)
    return ground[:n], np.asarray(res.residuals_px)[:n], ok


def _neighbour_outliers(xy1, h) -> np.ndarray:
    """Ties whose height is far from the median height of their nearest ties (image 1)."""
    from scipy.spatial import cKDTree

    n = len(h)
    if n < 2 * NEIGHBOURS:
        return np.zeros(n, bool)
    _, idx = cKDTree(xy1).query(xy1, k=NEIGHBOURS + 1)
    nb = h[idx[:, 1:]]
    med = np.median(nb, axis=1)
    spread = 1.4826 * np.median(np.abs(nb - med[:, None]), axis=1)
    dh = h - med
    tol = np.maximum(NEIGHBOUR_FLOOR_M, np.maximum(NEIGHBOUR_K * _robust_sigma(dh), 3 * spread))
    return np.abs(dh) > tol


def _collapse(xy1, xy2, c: Candidates, ratio, rejected):
    """One tie per pair of locations (SIFT's several orientations of one keypoint), then one to
    one: where a location is matched to several locations of the other image, the best match
    is kept if it passes the ratio test against the next (``ratio``), none otherwise."""
    c = c.take(np.argsort(c.distance, kind="stable"))  # best first in every group below
    p1, p2 = np.round(xy1[c.i1], 3), np.round(xy2[c.i2], 3)
    _, first = np.unique(np.hstack([p1, p2]), axis=0, return_index=True)
    rejected["duplicate"] = len(c) - len(first)
    c = c.take(np.sort(first))
    keep = np.ones(len(c), bool)
    for p in (np.round(xy1[c.i1], 3), np.round(xy2[c.i2], 3)):
        _, first, inv, counts = np.unique(
            p, axis=0, return_index=True, return_inverse=True, return_counts=True
        )
        inv = inv.reshape(-1)
        shared = counts[inv] > 1
        # the runner-up of each group: its smallest distance after the best's
        runner = np.full(len(first), np.inf)
        others = np.flatnonzero(shared & (np.arange(len(c)) != first[inv]))
        np.minimum.at(runner, inv[others], c.distance[others])
        is_best = np.arange(len(c)) == first[inv]
        clear = c.distance < ratio * runner[inv]
        keep &= ~shared | (is_best & clear)
    rejected["ambiguous"] = int((~keep).sum())
    return c.take(keep)


def _verify(model1, model2, xy1, xy2, c: Candidates, h_range, ratio):
    """The geometric checks (module docstring) of candidate matches: ``(xy1, xy2, ground,
    across, rejected, across_sigma)`` of the ties kept."""
    rejected = dict.fromkeys(CHECKS, 0)
    c = _collapse(xy1, xy2, c, ratio, rejected)
    a1, a2 = xy1[c.i1], xy2[c.i2]
    across = c.across_px
    r, sigma = _across_residuals(a1, across)
    keep = np.abs(r) <= max(ACROSS_K * sigma, ACROSS_FLOOR_PX)
    rejected["across_epipolar"] = int((~keep).sum())
    a1, a2, across = a1[keep], a2[keep], across[keep]
    ground, res, ok = _triangulate(model1, model2, a1, a2) if len(a1) else (
        np.zeros((0, 3)), np.zeros((0, 2, 2)), np.zeros(0, bool))  # fmt: skip
    rejected["triangulation"] = int((~ok).sum())
    h = ground[:, 2]
    with np.errstate(invalid="ignore"):
        inside = ok & (h >= h_range[0]) & (h <= h_range[1])
    rejected["height_range"] = int((ok & ~inside).sum())
    comps = res.reshape(len(res), 4)  # x, y residuals in both images
    if inside.any():
        comps = comps - np.median(comps[inside], axis=0)  # each image's common bias
    bound = max(RESIDUAL_K * _robust_sigma(comps[inside].ravel()), RESIDUAL_FLOOR_PX)
    small = inside & (np.max(np.abs(comps), axis=1) <= bound)
    rejected["residual"] = int((inside & ~small).sum())
    sel = np.flatnonzero(small)
    gross = _neighbour_outliers(a1[sel], h[sel])
    rejected["height_neighbours"] = int(gross.sum())
    sel = sel[~gross]
    return a1[sel], a2[sel], ground[sel], across[sel], rejected, sigma


def _coarse_range(model1, model2, f1, f2, validity, tol):
    """Height range from a coarse matching (module docstring), or ``None`` and the tie count."""
    xy1, d1 = f1
    if len(xy1) > COARSE_KEYPOINTS:
        pick = np.sort(np.random.default_rng(0).choice(len(xy1), COARSE_KEYPOINTS, False))
        xy1, d1 = xy1[pick], d1[pick]
    c = epipolar_candidates(model1, model2, (xy1, d1), f2, validity, tol, COARSE_RATIO)
    ties = _verify(model1, model2, xy1, f2[0], c, validity, COARSE_RATIO)
    h = ties[2][:, 2]
    if len(h) < COARSE_MIN_TIES:
        return None, len(h)
    lo, hi = np.percentile(h, [1, 99])
    margin = max(COARSE_MARGIN_M, COARSE_MARGIN_FRACTION * (hi - lo))
    return _intersect_ranges((lo - margin, hi + margin), validity), len(h)


def _height_range(model1, model2, height_range_m, dem, roi1, margin_m, path1):
    """``(range, source, validity)`` for the given range or the DEM; ``range`` ``None`` when
    the coarse matching must find it."""
    v1, v2 = validity_heights(model1), validity_heights(model2)
    validity = _intersect_ranges(v1, v2)
    if validity[0] >= validity[1]:
        raise TieError(
            f"the models' height validity ranges do not overlap ({v1[0]:.0f}..{v1[1]:.0f} m "
            f"and {v2[0]:.0f}..{v2[1]:.0f} m): are they models of the same area?"
        )
    if height_range_m is not None:  # checked by MatchSettings
        lo, hi = height_range_m
        if lo < validity[0] or hi > validity[1]:
            warnings.warn(
                f"the height range {lo:.0f}..{hi:.0f} m reaches outside the models' validity "
                f"range {validity[0]:.0f}..{validity[1]:.0f} m (the RPCs extrapolate there)",
                TieWarning,
                stacklevel=3,
            )
        return (lo, hi), "given", validity
    if dem is not None:
        lo, hi = footprint_dem_heights(model1, dem, roi1)
        wanted = (lo - margin_m, hi + margin_m)
        rng = _intersect_ranges(wanted, validity)
        if rng[0] >= rng[1]:
            raise TieError(
                f"{dem.path}: its heights over the footprint of {path1} ({lo:.0f}..{hi:.0f} m) "
                f"lie outside the models' validity range ({validity[0]:.0f}..{validity[1]:.0f} "
                "m): a DEM of another place, or orthometric heights taken as ellipsoidal?"
            )
        if lo < validity[0] or hi > validity[1]:
            warnings.warn(
                f"{dem.path}: its heights over the footprint ({lo:.0f}..{hi:.0f} m) reach "
                f"outside the models' validity range ({validity[0]:.0f}..{validity[1]:.0f} m); "
                f"searching {rng[0]:.0f}..{rng[1]:.0f} m",
                TieWarning,
                stacklevel=3,
            )
        return rng, "dem", validity
    return None, "coarse matching", validity


def tie_points(
    model1: AbstractSensorModel,
    model2: AbstractSensorModel,
    path1: str | os.PathLike,
    path2: str | os.PathLike,
    settings: MatchSettings | None = None,
    *,
    dem=None,
    features1: Features | None = None,
    features2: Features | None = None,
) -> TiePoints:
    """Verified tie points between two images (module docstring), as ``settings`` says
    (default :class:`MatchSettings()`; its ``sigma_px`` and ``few_ties`` are for
    :func:`~jaxgeo.stereo.match_images`).

    ``model1``, ``model2`` work in the pixels of the rasters ``path1``, ``path2`` (see
    :func:`jaxgeo.io.open_image`); ``settings.roi = (col, row, width, height)`` restricts image
    1's keypoints (px; inside the image, else :class:`TieError`). The height range is
    ``settings.height_range_m`` (m, ellipsoidal) if given, else from ``dem`` (a
    :class:`jaxgeo.io.DEM`, +- ``settings.dem_margin_m``), else from a coarse matching.
    ``features1``/``features2``: SIFT keypoints and descriptors already detected
    (:func:`~jaxgeo.stereo.sift_features_raster`, raster px) to reuse; by default they are
    detected over the ROI and the part of image 2 it sees (about ``keypoints`` of them).
    """
    settings = MatchSettings() if settings is None else settings
    roi, tol, ratio = settings.roi, float(settings.epipolar_tol_px), settings.ratio
    size1, size2 = _image_size(path1), _image_size(path2)
    roi1 = _check_roi(roi, size1, path1)
    h_range, source, validity = _height_range(
        model1, model2, settings.height_range_m, dem, roi1, float(settings.dem_margin_m), path1
    )
    most = settings.keypoints
    if features1 is None:
        features1 = sift_features_raster(path1, roi1 if roi is not None else None, most=most)
    else:
        col, row, w, h = roi1
        xy = np.asarray(features1[0], dtype=float)
        inside = (xy[:, 0] >= col - 0.5) & (xy[:, 0] < col + w - 0.5)
        inside &= (xy[:, 1] >= row - 0.5) & (xy[:, 1] < row + h - 0.5)
        features1 = (xy[inside], np.asarray(features1[1])[inside])
    if features2 is None:
        win2 = _window2(model1, model2, roi1, size2, h_range or validity, tol + 16)
        if win2 is None:
            raise TieError(f"the ROI of {path1} is not seen in {path2}")
        most2 = most and int(np.ceil(most * win2[2] * win2[3] / (roi1[2] * roi1[3])))  # per px
        features2 = sift_features_raster(path2, win2 if win2[2:] != size2 else None, most=most2)
    features2 = (np.asarray(features2[0], dtype=float), np.asarray(features2[1]))
    n_coarse = None
    if h_range is None:
        h_range, n_coarse = _coarse_range(model1, model2, features1, features2, validity, tol)
        if h_range is None:
            h_range, source = validity, "rpc validity"
    xy1, xy2 = features1[0], features2[0]
    c = epipolar_candidates(model1, model2, features1, features2, h_range, tol, ratio)
    k1, k2, ground, across, rejected, sigma = _verify(model1, model2, xy1, xy2, c, h_range, ratio)
    h = ground[:, 2]
    report = TieReport(
        n_keypoints=(len(xy1), len(xy2)),
        n_candidates=len(c),
        n_kept=len(k1),
        rejected=rejected,
        height_range_m=(float(h_range[0]), float(h_range[1])),
        height_source=source,
        validity_m=(float(validity[0]), float(validity[1])),
        n_coarse=n_coarse,
        heights_m=tuple(float(v) for v in np.percentile(h, [5, 50, 95]))
        if len(h)
        else (np.nan,) * 3,
        across_px=float(np.median(across)) if len(across) else np.nan,
        across_sigma_px=float(sigma),
    )
    if source == "dem":  # the DEM gave the heights: do the ties' own agree with it?
        _check_dem(dem, ground, report)
    return TiePoints(k1, k2, ground, across, report)


def _check_dem(dem, ground: np.ndarray, report: TieReport) -> None:
    """Warn (:class:`TieWarning`) when ``dem``'s heights at the ties disagree with theirs
    (:func:`jaxgeo.io.internal.dem_against_ties`): it also chose the range searched."""
    dem_h = np.asarray(dem.sample(ground[:, :2]), dtype=float)  # NaN outside the DEM
    why = dem_against_ties(ground[:, 2], dem_h, str(dem.path)) if len(ground) else None
    if why is not None:
        lo, hi = report.height_range_m
        warnings.warn(
            f"{why}; only {report.n_kept} ties kept ({report.rejected.get('height_range', 0)} "
            f"more rejected outside the height range {lo:.0f}..{hi:.0f} m it gave: far fewer "
            "than the images support)", TieWarning, stacklevel=3,
        )  # fmt: skip
