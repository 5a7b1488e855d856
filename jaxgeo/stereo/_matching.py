"""Tie points by SIFT matching under the guidance of the sensor models.

A keypoint of image 1 may only match a keypoint of image 2 that lies near the epipolar curve the
models predict: the image-2 segment between the projections of the keypoint's ray at heights
``h_min`` and ``h_max``, widened by ``epipolar_tol_px`` for the models' relative bias. Among
those candidates Lowe's ratio test picks the match. Outliers are then rejected on the offset
across the epipolar direction: it must be one (bias) value up to noise, so matches further than
``max(3.5 sigma, 0.5 px)`` (robust sigma from the MAD) from the median are dropped.

Detection runs on tiles (``tile_px`` with a 32 px overlap) so that OpenCV's SIFT never holds
more than one tile's scale space. Image coordinates: jaxgeo (integer = pixel centre).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..models import AbstractSensorModel
from ._rectification import _batched, _transfer

TILE_OVERLAP_PX = 32


def stretch_limits(image: np.ndarray, low_pct: float = 0.5, high_pct: float = 99.5):
    """Percentiles of the finite values of ``image`` (the uint8 stretch limits)."""
    image = np.asarray(image, dtype=float)
    finite = image[np.isfinite(image)]
    if finite.size == 0:
        return 0.0, 1.0
    lo, hi = np.percentile(finite, [low_pct, high_pct])
    return float(lo), float(max(hi, lo + 1e-12))


def to_uint8(image: np.ndarray, limits: tuple[float, float] | None = None) -> np.ndarray:
    """Linear stretch of a (uint16 / float) image to uint8 between ``limits`` (default the 0.5
    and 99.5 percentiles of its finite values); NaN -> 0."""
    image = np.asarray(image, dtype=float)
    lo, hi = stretch_limits(image) if limits is None else limits
    scaled = (np.where(np.isfinite(image), image, lo) - lo) * (255.0 / (hi - lo))
    return np.clip(np.rint(scaled), 0, 255).astype(np.uint8)


def _tiles(rows, cols, tile_px):
    for r0 in range(0, rows, tile_px):
        for c0 in range(0, cols, tile_px):
            ra, ca = max(r0 - TILE_OVERLAP_PX, 0), max(c0 - TILE_OVERLAP_PX, 0)
            rb = min(r0 + tile_px + TILE_OVERLAP_PX, rows)
            cb = min(c0 + tile_px + TILE_OVERLAP_PX, cols)
            yield (r0, c0), (ra, ca, rb, cb)


def _detect(sift, tile8, core, offset, tile_px):
    kps, desc = sift.detectAndCompute(np.ascontiguousarray(tile8), None)
    if desc is None:
        return np.zeros((0, 2)), np.zeros((0, 128), np.float32)
    # OpenCV keypoints are in pixel-centre-at-0 coordinates like jaxgeo's
    xy = np.array([k.pt for k in kps], dtype=float) + offset
    r0, c0 = core
    keep = (xy[:, 0] >= c0 - 0.5) & (xy[:, 0] < c0 + tile_px - 0.5)
    keep &= (xy[:, 1] >= r0 - 0.5) & (xy[:, 1] < r0 + tile_px - 0.5)
    return xy[keep], desc[keep]


def _concat(parts):
    if not parts:
        return np.zeros((0, 2)), np.zeros((0, 128), np.float32)
    return np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])


def sift_features(image8: np.ndarray, tile_px: int = 2048) -> tuple[np.ndarray, np.ndarray]:
    """SIFT keypoints ``(n, 2)`` (x, y) and descriptors ``(n, 128)`` float32 of a uint8 image,
    detected tile by tile (a keypoint is kept by the tile whose core holds it)."""
    import cv2

    sift = cv2.SIFT_create()
    parts = []
    for core, (ra, ca, rb, cb) in _tiles(*image8.shape, tile_px):
        parts.append(_detect(sift, image8[ra:rb, ca:cb], core, (ca, ra), tile_px))
    return _concat(parts)


def sift_features_raster(
    path, window: Sequence[int] | None = None, tile_px: int = 2048
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`sift_features` of band 1 of a raster file over ``window = (col, row, w, h)``
    (whole image by default), reading one tile at a time (bounded memory for large images);
    the uint8 stretch comes from a decimated read. Keypoints in full-image pixels."""
    import cv2
    import rasterio
    from rasterio.windows import Window

    sift = cv2.SIFT_create()
    with rasterio.open(path) as src:
        col, row, w, h = window if window is not None else (0, 0, src.width, src.height)
        scale = max(1, int(np.ceil(max(w, h) / 1024)))
        small = src.read(1, window=Window(col, row, w, h), out_shape=(h // scale, w // scale))
        limits = stretch_limits(small)
        parts = []
        for core, (ra, ca, rb, cb) in _tiles(h, w, tile_px):
            tile = src.read(1, window=Window(col + ca, row + ra, cb - ca, rb - ra))
            xy, desc = _detect(sift, to_uint8(tile, limits), core, (ca, ra), tile_px)
            parts.append((xy + (col, row), desc))
    return _concat(parts)


def _epipolar_segments(m1, m2, xy, h_lo, h_hi):
    """Image-2 ends of the epipolar segments of image-1 points (the rectification's compiled
    transfer, shared)."""
    a = _batched(_transfer, (m1, m2), xy, h_lo)
    b = _batched(_transfer, (m1, m2), xy, h_hi)
    return a, b


@dataclass(frozen=True)
class Matches:
    """Matched points ``xy1``, ``xy2`` ``(n, 2)`` px; ``across_px`` ``(n,)`` signed distance of
    ``xy2`` from the models' epipolar curve of ``xy1`` (the relative bias shows as its median);
    ``n_candidates`` matches before outlier rejection."""

    xy1: np.ndarray
    xy2: np.ndarray
    across_px: np.ndarray
    n_candidates: int

    def __len__(self) -> int:
        return self.xy1.shape[0]


def guided_matches(
    model1: AbstractSensorModel,
    model2: AbstractSensorModel,
    xy1: np.ndarray,
    desc1: np.ndarray,
    xy2: np.ndarray,
    desc2: np.ndarray,
    height_range_m: Sequence[float],
    epipolar_tol_px: float = 10.0,
    ratio: float = 0.8,
) -> Matches:
    """Match keypoints of image 1 to image 2 within ``epipolar_tol_px`` of the predicted epipolar
    segment (heights ``height_range_m``), Lowe ratio ``ratio``, then reject outliers across the
    epipolar direction (module docstring)."""
    from scipy.spatial import cKDTree

    empty = Matches(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0), 0)
    if len(xy1) == 0 or len(xy2) < 2:
        return empty
    h_lo, h_hi = map(float, height_range_m)
    a, b = (np.asarray(v) for v in _epipolar_segments(model1, model2, xy1, h_lo, h_hi))
    ok1 = np.all(np.isfinite(a), axis=1) & np.all(np.isfinite(b), axis=1)
    mid, half = (a + b) / 2, np.linalg.norm(b - a, axis=1) / 2
    u = (b - a) / np.maximum(2 * half, 1e-12)[:, None]
    tree = cKDTree(xy2)
    pairs, across = [], []
    d1n = desc1 / np.maximum(np.linalg.norm(desc1, axis=1, keepdims=True), 1e-12)
    d2n = desc2 / np.maximum(np.linalg.norm(desc2, axis=1, keepdims=True), 1e-12)
    for i in np.flatnonzero(ok1):
        cand = np.asarray(tree.query_ball_point(mid[i], half[i] + epipolar_tol_px), dtype=int)
        if cand.size < 1:
            continue
        rel = xy2[cand] - a[i]
        perp = rel[:, 0] * -u[i, 1] + rel[:, 1] * u[i, 0]
        along = rel @ u[i]
        inside = (np.abs(perp) <= epipolar_tol_px) & (along >= -epipolar_tol_px)
        inside &= along <= 2 * half[i] + epipolar_tol_px
        cand, perp = cand[inside], perp[inside]
        if cand.size < 1:
            continue
        dist = np.sqrt(np.maximum(2 - 2 * d2n[cand] @ d1n[i], 0))  # SIFT L2 on unit vectors
        order = np.argsort(dist)
        if cand.size > 1 and dist[order[0]] > ratio * dist[order[1]]:
            continue
        pairs.append((i, cand[order[0]]))
        across.append(perp[order[0]])
    if not pairs:
        return empty
    pairs = np.array(pairs)
    across = np.array(across)
    # one keypoint of image 2 matched twice: keep neither (ambiguous)
    _, inv, counts = np.unique(pairs[:, 1], return_inverse=True, return_counts=True)
    single = counts[inv] == 1
    pairs, across = pairs[single], across[single]
    n_cand = len(pairs)
    med = np.median(across) if n_cand else 0.0
    sigma = 1.4826 * np.median(np.abs(across - med)) if n_cand else 0.0
    keep = np.abs(across - med) <= max(3.5 * sigma, 0.5)
    return Matches(xy1[pairs[keep, 0]], xy2[pairs[keep, 1]], across[keep], n_cand)


def epipolar_offsets(
    model1: AbstractSensorModel,
    model2: AbstractSensorModel,
    xy1: np.ndarray,
    xy2: np.ndarray,
    height_range_m: Sequence[float],
) -> np.ndarray:
    """Signed distance (px) of each ``xy2`` from the epipolar curve of ``xy1`` in image 2 (the
    segment between heights ``height_range_m``): the models' relative bias across the epipolar
    direction, as :class:`Matches` reports it in ``across_px``."""
    h_lo, h_hi = map(float, height_range_m)
    a, b = (np.asarray(v) for v in _epipolar_segments(model1, model2, xy1, h_lo, h_hi))
    u = (b - a) / np.linalg.norm(b - a, axis=1, keepdims=True)
    rel = np.asarray(xy2, dtype=float) - a
    return rel[:, 0] * -u[:, 1] + rel[:, 1] * u[:, 0]
