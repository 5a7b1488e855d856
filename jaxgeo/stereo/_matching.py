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

import contextlib
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..io.internal import open_raster
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


SPREAD_CELLS = 8
"""A capped detection keeps the strongest keypoints of each of ``SPREAD_CELLS`` x
``SPREAD_CELLS`` cells in turn: spread over the image (the strongest of all cluster where the
texture is strongest; a rectification's vertical disparity and range need them everywhere)."""


def _spread(kps, most, shape) -> list:
    """``most`` of the keypoints ``kps``: the strongest of every cell of a grid over ``shape``,
    then the second strongest of every cell, and so on."""
    xy = np.array([k.pt for k in kps]).reshape(-1, 2)
    response = np.array([k.response for k in kps])
    step = np.maximum(np.asarray(shape[::-1], float) / SPREAD_CELLS, 1.0)
    cx, cy = (np.clip(xy // step, 0, SPREAD_CELLS - 1).astype(int)).T
    cell = cy * SPREAD_CELLS + cx
    order = np.lexsort((-response, cell))  # by cell, strongest first
    first = np.searchsorted(cell[order], cell[order])  # each cell's first position
    rank = np.empty(len(kps), int)
    rank[order] = np.arange(len(kps)) - first
    pick = np.lexsort((-response, rank))[:most]
    return [kps[i] for i in np.sort(pick)]


def _detect(sift, tile8, core, offset, tile_px, most=None):
    tile8 = np.ascontiguousarray(tile8)
    if most is None:
        kps, desc = sift.detectAndCompute(tile8, None)
    else:  # the descriptors (most of the cost) of the keypoints kept only
        kps = sift.detect(tile8, None)
        if len(kps) > most:
            kps = _spread(kps, most, tile8.shape)
        kps, desc = sift.compute(tile8, kps) if len(kps) else (kps, None)
    if desc is None or len(kps) == 0:  # OpenCV 4: None; OpenCV >= 5: a (0, 128) array
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


def _share(most, share):
    """A detection tile's ``share`` (of the whole image's area) of ``most`` keypoints (all:
    ``None``). Most of SIFT's cost is the descriptors (13 000 of a 0.46 Mpx image: 2/3 of it)."""
    return None if most is None else max(int(np.ceil(most * share)), 1)


def sift_features(
    image8: np.ndarray, tile_px: int = 2048, most: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """SIFT keypoints ``(n, 2)`` (x, y) and descriptors ``(n, 128)`` float32 of a uint8 image,
    detected tile by tile (a keypoint is kept by the tile whose core holds it); ``most``: about
    ``most`` of them, the strongest spread over the image (each tile its share by area;
    ``None``: all)."""
    import cv2

    sift = cv2.SIFT_create()
    parts = []
    for core, (ra, ca, rb, cb) in _tiles(*image8.shape, tile_px):
        n = _share(most, (rb - ra) * (cb - ca) / image8.size)
        parts.append(_detect(sift, image8[ra:rb, ca:cb], core, (ca, ra), tile_px, n))
    return _concat(parts)


def sift_features_raster(
    path, window: Sequence[int] | None = None, tile_px: int = 2048, most: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`sift_features` of band 1 of a raster file over ``window = (col, row, w, h)``
    (whole image by default), reading one tile at a time (bounded memory for large images);
    the uint8 stretch comes from a decimated read. Keypoints in full-image pixels; ``most``:
    as :func:`sift_features`."""
    import cv2
    from rasterio.windows import Window

    sift = cv2.SIFT_create()
    with open_raster(path) as src, pixels_of(path):
        col, row, w, h = window if window is not None else (0, 0, src.width, src.height)
        scale = max(1, int(np.ceil(max(w, h) / 1024)))
        small = src.read(1, window=Window(col, row, w, h), out_shape=(h // scale, w // scale))
        limits = stretch_limits(small)
        parts = []
        for core, (ra, ca, rb, cb) in _tiles(h, w, tile_px):
            tile = src.read(1, window=Window(col + ca, row + ra, cb - ca, rb - ra))
            n = _share(most, tile.size / (w * h))
            xy, desc = _detect(sift, to_uint8(tile, limits), core, (ca, ra), tile_px, n)
            parts.append((xy + (col, row), desc))
    return _concat(parts)


@contextlib.contextmanager
def pixels_of(path):
    """Reading ``path``'s pixels: GDAL's read error (a truncated or corrupt file, whose header
    opened) becomes an :class:`~jaxgeo.io.ImageError` naming the file."""
    from rasterio.errors import RasterioIOError

    from ..io import ImageError

    try:
        yield
    except RasterioIOError as err:
        raise ImageError(
            f"{path}: its pixels cannot be read (truncated or corrupt? {err})"
        ) from None


def _epipolar_segments(m1, m2, xy, h_lo, h_hi):
    """Image-2 ends of the epipolar segments of image-1 points (the rectification's compiled
    transfer, shared)."""
    a = _batched(_transfer, (m1, m2), xy, h_lo)
    b = _batched(_transfer, (m1, m2), xy, h_hi)
    return a, b


@dataclass(frozen=True)
class Candidates:
    """Epipolar-guided matches before any geometric check: keypoint indices ``i1``, ``i2``
    ``(n,)``, ``across_px`` ``(n,)`` signed distance of the image-2 keypoint from the epipolar
    segment of the image-1 keypoint, ``distance`` ``(n,)`` SIFT descriptor distance (unit
    descriptors, 0..2) and ``ratio`` ``(n,)`` best / second-best distance (0 when every other
    candidate sits at the same location); ``n_searched`` image-1 keypoints whose segment is
    defined."""

    i1: np.ndarray
    i2: np.ndarray
    across_px: np.ndarray
    distance: np.ndarray
    ratio: np.ndarray
    n_searched: int

    def __len__(self) -> int:
        return self.i1.shape[0]

    def take(self, keep: np.ndarray) -> Candidates:
        """The candidates selected by ``keep`` (a boolean mask or indices)."""
        return Candidates(
            self.i1[keep],
            self.i2[keep],
            self.across_px[keep],
            self.distance[keep],
            self.ratio[keep],
            self.n_searched,
        )


CANDIDATE_CHUNK = 512
"""Image-1 keypoints searched at once (bounds the memory of the vectorised search)."""


def _unit(desc):
    desc = np.asarray(desc, dtype=np.float32)
    return desc / np.maximum(np.linalg.norm(desc, axis=1, keepdims=True), 1e-12)


Features = tuple[np.ndarray, np.ndarray]
"""SIFT keypoints ``(n, 2)`` (x, y) px and their descriptors ``(n, 128)``, as
:func:`sift_features` and :func:`sift_features_raster` return them."""


def epipolar_candidates(
    model1: AbstractSensorModel,
    model2: AbstractSensorModel,
    features1: Features,
    features2: Features,
    height_range_m: Sequence[float],
    epipolar_tol_px: float = 10.0,
    ratio: float = 0.8,
) -> Candidates:
    """For each keypoint of image 1 (``features1 = (xy1, desc1)``, :data:`Features`), its
    nearest descriptor among the image-2 keypoints (``features2``) within ``epipolar_tol_px``
    of its epipolar segment (heights ``height_range_m``), kept when it passes Lowe's ratio test
    ``ratio``. The second-best is taken among candidates at another location than the best:
    SIFT gives one keypoint several orientations (one descriptor each), which are not rival
    matches."""
    (xy1, desc1), (xy2, desc2) = features1, features2
    xy1, xy2 = np.asarray(xy1, dtype=float), np.asarray(xy2, dtype=float)
    empty = Candidates(*(np.zeros(0, int),) * 2, *(np.zeros(0),) * 3, 0)
    if len(xy1) == 0 or len(xy2) == 0:
        return empty
    h_lo, h_hi = map(float, height_range_m)
    a, b = (np.asarray(v) for v in _epipolar_segments(model1, model2, xy1, h_lo, h_hi))
    ok1 = np.all(np.isfinite(a), axis=1) & np.all(np.isfinite(b), axis=1)
    if not ok1.any():  # no keypoint's ray reaches image 2
        return empty
    half = np.linalg.norm(b - a, axis=1) / 2
    u = (b - a) / np.maximum(2 * half, 1e-12)[:, None]
    index = _SegmentIndex(xy2, a, b, float(epipolar_tol_px))  # NaN segments never queried
    d1n, d2n = _unit(desc1), _unit(desc2)
    parts = []
    searched = np.flatnonzero(ok1)
    tol = float(epipolar_tol_px)
    for s in range(0, len(searched), CANDIDATE_CHUNK):
        idx = searched[s : s + CANDIDATE_CHUNK]
        rows, cols = index.query(idx)
        if rows.size == 0:
            continue
        rows = idx[rows]
        rel = xy2[cols] - a[rows]
        along = np.einsum("ij,ij->i", rel, u[rows])
        perp = rel[:, 0] * -u[rows, 1] + rel[:, 1] * u[rows, 0]
        inside = (np.abs(perp) <= tol) & (along >= -tol) & (along <= 2 * half[rows] + tol)
        rows, cols, perp = rows[inside], cols[inside], perp[inside]
        cos = np.einsum("ij,ij->i", d1n[rows], d2n[cols]).astype(float)
        dist = np.sqrt(np.maximum(2 - 2 * cos, 0))  # SIFT L2 between unit descriptors
        parts.append(_best_per_keypoint(rows, cols, perp, dist, xy2, ratio))
    if not parts:
        return Candidates(
            empty.i1, empty.i2, empty.across_px, empty.distance, empty.ratio, len(searched)
        )
    cat = [np.concatenate(p) for p in zip(*parts, strict=True)]
    return Candidates(*cat, len(searched))


class _SegmentIndex:
    """Image-2 points indexed for "which points lie near segment i" queries: in a frame turned
    to the mean epipolar direction and scaled by the typical segment's half-extent, the
    bounding box of each segment (widened by ``sqrt(2) tol``) is nearly a square, found by one
    Chebyshev-ball query (far fewer candidates than a Euclidean ball around a long segment)."""

    def __init__(self, xy2, a, b, tol):
        from scipy.spatial import cKDTree

        d = np.nanmean(b - a, axis=0)
        u0 = d / max(float(np.linalg.norm(d)), 1e-12) if np.all(np.isfinite(d)) else np.eye(2)[0]
        self.rot = np.array([u0, [-u0[1], u0[0]]]).T  # columns: along, across
        ra, rb = a @ self.rot, b @ self.rot
        pad = np.sqrt(2.0) * tol
        self.lo = np.minimum(ra, rb) - pad
        self.hi = np.maximum(ra, rb) + pad
        half = (self.hi - self.lo) / 2
        self.scale = np.maximum(np.nanmedian(half, axis=0), 1e-6)
        self.tree = cKDTree((xy2 @ self.rot) / self.scale)

    def query(self, idx):
        """``(rows, cols)``: the image-2 points in the box of segment ``idx[row]``."""
        centre = (self.lo[idx] + self.hi[idx]) / 2 / self.scale
        radius = np.max((self.hi[idx] - self.lo[idx]) / 2 / self.scale, axis=1)
        balls = self.tree.query_ball_point(centre, radius, p=np.inf, return_sorted=False)
        counts = np.fromiter((len(c) for c in balls), int, len(balls))
        if counts.sum() == 0:
            return np.zeros(0, int), np.zeros(0, int)
        cols = np.concatenate([np.asarray(c, dtype=int) for c in balls])
        return np.repeat(np.arange(len(idx)), counts), cols


def _best_per_keypoint(rows, cols, perp, dist, xy2, ratio):
    """Best candidate of each image-1 keypoint (``rows``) and its ratio to the best candidate
    at another image-2 location; those failing the ratio test are dropped."""
    if rows.size == 0:
        return np.zeros(0, int), np.zeros(0, int), np.zeros(0), np.zeros(0), np.zeros(0)
    order = np.lexsort((dist, rows))
    rows, cols, perp, dist = rows[order], cols[order], perp[order], dist[order]
    keys, first, inverse = np.unique(rows, return_index=True, return_inverse=True)
    best = first[inverse]  # position of each candidate's group best
    other = np.any(xy2[cols] != xy2[cols[best]], axis=1)
    second = np.full(keys.size, np.inf)
    if other.any():
        k2, f2 = np.unique(rows[other], return_index=True)
        second[np.searchsorted(keys, k2)] = dist[np.flatnonzero(other)[f2]]
    d_best = dist[first]
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.where(np.isfinite(second), d_best / np.maximum(second, 1e-12), 0.0)
    keep = r < ratio
    return keys[keep], cols[first][keep], perp[first][keep], d_best[keep], r[keep]


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
    features1: Features,
    features2: Features,
    height_range_m: Sequence[float],
    epipolar_tol_px: float = 10.0,
    ratio: float = 0.8,
) -> Matches:
    """Match keypoints of image 1 (``features1 = (xy1, desc1)``, :data:`Features`) to those of
    image 2 (``features2``) within ``epipolar_tol_px`` of the predicted epipolar segment
    (heights ``height_range_m``), Lowe ratio ``ratio`` (:func:`epipolar_candidates`), then
    reject outliers across the epipolar direction (module docstring). No check of the heights:
    :func:`~jaxgeo.stereo.tie_points` verifies every tie (heights, duplicates, one-to-one) and
    finds the height range itself."""
    empty = Matches(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0), 0)
    xy1, xy2 = np.asarray(features1[0], dtype=float), np.asarray(features2[0], dtype=float)
    if len(xy1) == 0 or len(xy2) < 2:
        return empty
    c = epipolar_candidates(
        model1, model2, features1, features2, height_range_m, epipolar_tol_px, ratio
    )
    if len(c) == 0:
        return empty
    # one keypoint of image 2 matched twice: keep neither (ambiguous)
    _, inv, counts = np.unique(c.i2, return_inverse=True, return_counts=True)
    c = c.take(counts[inv] == 1)
    across = c.across_px
    n_cand = len(c)
    med = np.median(across) if n_cand else 0.0
    sigma = 1.4826 * np.median(np.abs(across - med)) if n_cand else 0.0
    keep = np.abs(across - med) <= max(3.5 * sigma, 0.5)
    return Matches(xy1[c.i1[keep]], xy2[c.i2[keep]], across[keep], n_cand)


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
