"""The stereo chain for one pair and for N images: ties -> rectification -> SGM -> points -> DSM.

For a pair (reference image, secondary image) and a ROI of the reference image:

1. SIFT tie points guided by the models (:mod:`._matching`); their heights (chord-midpoint
   triangulation) give the reference elevation of the rectification (median) and, after
   rectification, the disparity range.
2. Epipolar grids at that elevation (:mod:`._rectification`) and resampling of both images.
3. The residual vertical disparity (the models' relative bias across the epipolar lines) is
   measured with SIFT matches on the rectified pair and removed by shifting the right sampling
   (s2p's "relative pointing correction", a translation); it is reported before and after.
4. Semi-global matching (:mod:`._dense`), masked where either epipolar image has no data.
5. Triangulation of every valid disparity (:mod:`._triangulation`).

The N-image DSM pools the points of the pairs (reference, i) and rasterises them (:mod:`._dsm`).
"""

from __future__ import annotations

import os
import pathlib
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from ..models import AbstractSensorModel
from ._dense import DEFAULT_SGM, SGMSettings, resample_epipolar, sgm_disparity
from ._dsm import DSMGrid, rasterize
from ._matching import guided_matches, sift_features, stretch_limits, to_uint8
from ._rectification import EpipolarGrids, epipolar_grids
from ._triangulation import los_heights, triangulate

DISPARITY_MARGIN_PX = 8.0
MIN_TIE_POINTS = 10
BAND_ROWS = 512
"""Epipolar rows per band of dense matching (memory grows with the band, not the image)."""
BAND_OVERLAP_ROWS = 32
BAND_MARGIN_PX = 8
TRIANGULATION_CHUNK = 65536


def read_window(path: str | os.PathLike, window: tuple[int, int, int, int]) -> np.ndarray:
    """Band 1 of ``path`` over ``(col_off, row_off, width, height)`` as float32 (only that
    window is read)."""
    from rasterio.windows import Window

    with _open(path) as src:
        return src.read(1, window=Window(*window)).astype(np.float32)


def _open(path):
    """rasterio dataset of a sensor image: no geotransform is expected (no warning for it)."""
    import warnings

    import rasterio
    from rasterio.errors import NotGeoreferencedWarning

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        return rasterio.open(path)


def image_size(path: str | os.PathLike) -> tuple[int, int]:
    """``(width, height)`` of a raster."""
    with _open(path) as src:
        return src.width, src.height


@dataclass
class PairProducts:
    """Result of :func:`stereo_pair`: ``points`` ``(n, 3)`` lon/lat/h, ``stats`` (numbers to
    report) and, when kept, the intermediate products (grids, epipolar images, disparity,
    tie points)."""

    points: np.ndarray
    stats: dict
    grids: EpipolarGrids | None = None
    intermediates: dict = field(default_factory=dict)


def _sec_window(ref, sec, roi, h_range, size, margin=64):
    col, row, w, h = roi
    xs = np.linspace(col, col + w - 1, 5)
    ys = np.linspace(row, row + h - 1, 5)
    xy = np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)
    pts = [np.asarray(sec.project(ref.localize(xy, z))) for z in h_range]
    pts = np.concatenate(pts)
    if not np.all(np.isfinite(pts)):
        raise ValueError("stereo: the ROI does not project into the secondary image")
    c0 = int(max(np.floor(pts[:, 0].min()) - margin, 0))
    r0 = int(max(np.floor(pts[:, 1].min()) - margin, 0))
    c1 = int(min(np.ceil(pts[:, 0].max()) + margin, size[0]))
    r1 = int(min(np.ceil(pts[:, 1].max()) + margin, size[1]))
    if c1 <= c0 or r1 <= r0:
        raise ValueError("stereo: the ROI's footprint misses the secondary image")
    return c0, r0, c1 - c0, r1 - r0


def _epipolar_sift(left8, right8, ratio=0.8):
    """SIFT matches between the rectified images: ``(n, 2)`` left and right epipolar xy."""
    import cv2

    xl, dl = sift_features(left8)
    xr, dr = sift_features(right8)
    if len(xl) < 2 or len(xr) < 2:
        return np.zeros((0, 2)), np.zeros((0, 2))
    knn = cv2.BFMatcher(cv2.NORM_L2).knnMatch(dl, dr, k=2)
    good = [m[0] for m in knn if len(m) == 2 and m[0].distance < ratio * m[1].distance]
    a = np.array([xl[m.queryIdx] for m in good]).reshape(-1, 2)
    b = np.array([xr[m.trainIdx] for m in good]).reshape(-1, 2)
    return a, b


def _robust(values, k=3.5, floor=0.5):
    med = np.median(values)
    sigma = 1.4826 * np.median(np.abs(values - med))
    return np.abs(values - med) <= max(k * sigma, floor)


def stereo_pair(
    ref: AbstractSensorModel,
    sec: AbstractSensorModel,
    ref_path: str | os.PathLike,
    sec_path: str | os.PathLike,
    roi: tuple[int, int, int, int] | None = None,
    epi_step: int = 30,
    sgm: SGMSettings = DEFAULT_SGM,
    method: str = "intersect",
    keep: bool = False,
    log: Callable[[str], None] | None = None,
    band_rows: int | None = BAND_ROWS,
    on_band: Callable[[int, int], None] | None = None,
    epipolar_tol_px: float = 10.0,
) -> PairProducts:
    """3D points of a pair over ``roi = (col, row, width, height)`` of the reference image
    (whole image by default); ``method`` the triangulation (``intersect`` or
    ``los_midpoint``).

    Dense matching and triangulation run over bands of ``band_rows`` epipolar rows (``None``:
    one band), each resampled from the sensor pixels it needs; ``on_band(done, total)`` is
    called after each band (progress). ``epipolar_tol_px``: how far from the models' epipolar
    curves tie points may lie (the models' relative bias across the epipolar lines; the
    rectified pair's vertical disparity is then measured and removed, whatever its size)."""
    log = log or (lambda _: None)
    clock = [time.perf_counter()]

    def lap(name):
        now = time.perf_counter()
        stats[f"time_{name}_s"] = round(now - clock[0], 2)
        clock[0] = now

    ref_size, sec_size = image_size(ref_path), image_size(sec_path)
    if roi is None:
        roi = (0, 0, *ref_size)
    col, row, w, h = map(int, roi)
    if col < 0 or row < 0 or w <= 0 or h <= 0 or col + w > ref_size[0] or row + h > ref_size[1]:
        raise ValueError(
            f"stereo: ROI {roi} is not inside {ref_path} ({ref_size[0]} x {ref_size[1]})"
        )
    roi = (col, row, w, h)
    stats: dict = {}
    h_valid = los_heights(ref)
    win2 = _sec_window(ref, sec, roi, h_valid, sec_size)
    img1, img2 = read_window(ref_path, roi), read_window(sec_path, win2)
    log("tie points")
    x1, d1 = sift_features(to_uint8(img1))
    x2, d2 = sift_features(to_uint8(img2))
    ties = guided_matches(
        ref, sec, x1 + roi[:2], d1, x2 + win2[:2], d2, h_valid, epipolar_tol_px=epipolar_tol_px
    )
    if len(ties) < MIN_TIE_POINTS:
        raise ValueError(
            f"stereo: only {len(ties)} tie points between {ref_path} and {sec_path} "
            f"(need {MIN_TIE_POINTS}); check the models and the ROI"
        )
    ground, _ = triangulate([ref, sec], np.stack([ties.xy1, ties.xy2], axis=1), "los_midpoint")
    heights = ground[:, 2][np.isfinite(ground[:, 2])]
    h0 = float(np.median(heights))
    stats.update(n_ties=len(ties), ties_across_px=float(np.median(ties.across_px)), h_ref_m=h0)
    lap("ties")
    log(f"{len(ties)} tie points, reference height {h0:.1f} m; rectification")
    grids = epipolar_grids(ref, sec, roi, elevation=h0, epi_step=epi_step)
    left = resample_epipolar(img1, grids, "left", origin_xy=roi[:2])
    right = resample_epipolar(img2, grids, "right", origin_xy=win2[:2])
    lap("rectification")
    a, b = _epipolar_sift(to_uint8(left), to_uint8(right))
    dy = b[:, 1] - a[:, 1]
    centre = np.nanmedian(dy) if len(dy) else 0.0  # the models' relative bias, if any
    ok = (np.abs(dy - centre) < 10.0) & np.isfinite(dy)
    ok[ok] = _robust(dy[ok])
    if ok.sum() < MIN_TIE_POINTS:
        raise ValueError(f"stereo: only {ok.sum()} matches on the rectified pair")
    dy_med = float(np.median(dy[ok]))
    dx = (b[:, 0] - a[:, 0])[ok]
    ok_dx = _robust(dx, k=5.0, floor=3.0)
    dmin = float(dx[ok_dx].min() - DISPARITY_MARGIN_PX)
    dmax = float(dx[ok_dx].max() + DISPARITY_MARGIN_PX)
    stats.update(
        vertical_disparity_px=dy_med,
        vertical_disparity_std_px=float(np.std(dy[ok])),
        n_epipolar_matches=int(ok.sum()),
        disparity_range_px=(dmin, dmax),
        mean_baseline_ratio_px_per_m=grids.mean_baseline_ratio,
        epipolar_shape=grids.epipolar_shape,
    )
    right = resample_epipolar(img2, grids, "right", origin_xy=win2[:2], y_shift_px=dy_med)
    a2, b2 = _epipolar_sift(to_uint8(left), to_uint8(right))
    dy2 = b2[:, 1] - a2[:, 1]
    ok2 = np.abs(dy2) < 10.0
    ok2[ok2] = _robust(dy2[ok2])
    stats["vertical_disparity_after_px"] = float(np.median(dy2[ok2])) if ok2.any() else np.nan
    stats["vertical_disparity_after_std_px"] = float(np.std(dy2[ok2])) if ok2.any() else np.nan
    lap("vertical_disparity")
    log(f"vertical disparity {dy_med:+.2f} px removed; SGM over [{dmin:.0f}, {dmax:.0f}] px")
    # widen the epipolar images by the disparity range: the right matches of the left image's
    # edge columns lie outside its own epipolar extent
    rows_e, cols_e = grids.epipolar_shape
    x0, x1 = min(0, int(np.floor(dmin))), cols_e + max(0, int(np.ceil(dmax)))
    lims = (stretch_limits(left), stretch_limits(right))
    del left, right
    band = rows_e if band_rows is None else max(int(band_rows), 1)
    starts = list(range(0, rows_e, band))
    dense = _Dense(img1, img2, roi[:2], win2[:2], grids, dy_med, (x0, x1), lims, (dmin, dmax), sgm)
    matches, kept, n_valid, n_disp = [], [], 0, 0
    points, sigma_h = [], []
    for k, r0 in enumerate(starts):
        r1 = min(r0 + band, rows_e)
        disp, valid_l, images = dense.band(r0, r1, keep)
        n_valid += int(valid_l.sum())
        ye, xe = np.mgrid[r0:r1, x0:x1].astype(float)
        sel = np.isfinite(disp)
        n_disp += int(sel.sum())
        xl = grids.to_sensor("left", np.stack([xe[sel], ye[sel]], axis=-1))
        xr = grids.to_sensor("right", np.stack([xe[sel] + disp[sel], ye[sel] + dy_med], axis=-1))
        matches.append(np.stack([xl, xr], axis=1))
        if keep:
            kept.append((disp, *images))
        pending = sum(len(m) for m in matches)
        if pending >= TRIANGULATION_CHUNK or k == len(starts) - 1:
            pts, sig = _triangulate(ref, sec, np.concatenate(matches), method)
            points.append(pts)
            sigma_h.append(sig)
            matches = []
        if on_band is not None:
            on_band(k + 1, len(starts))
    stats["disparity_fill"] = float(n_disp / max(n_valid, 1))
    stats["n_bands"] = len(starts)
    lap("sgm_triangulation")
    points = np.concatenate(points)
    sigma_h = np.concatenate(sigma_h)
    if method == "intersect" and np.isfinite(sigma_h).any():
        stats["median_sigma_h_m"] = float(np.nanmedian(sigma_h))
    log(f"{len(points)} points ({method})")
    products = PairProducts(points=points, stats=stats)
    if keep:
        disp, left_w, right_w = (np.concatenate(a) for a in zip(*kept, strict=True))
        products.grids = grids
        products.intermediates = dict(
            left=left_w,
            right=right_w,
            epipolar_x0=x0,
            disparity=disp,
            ties_xy1=ties.xy1,
            ties_xy2=ties.xy2,
        )
    return products


class _Dense:
    """SGM over bands of epipolar rows: each band is resampled from the sensor pixels it needs,
    with ``BAND_OVERLAP_ROWS`` of context above and below (SGM's vertical paths) dropped after
    matching, so the result matches one pass over the whole image up to those paths' reach."""

    def __init__(self, img1, img2, origin1, origin2, grids, dy, x_range, lims, drange, sgm):
        self.img = {"left": img1, "right": img2}
        self.origin = {"left": np.asarray(origin1, float), "right": np.asarray(origin2, float)}
        self.shift = {"left": 0.0, "right": dy}
        self.grids, self.x_range, self.lims, self.drange, self.sgm = (
            grids, x_range, lims, drange, sgm
        )  # fmt: skip

    def _resample(self, side, ra, rb):
        """Epipolar rows ``[ra, rb)`` of ``side`` from the part of the image they sample."""
        x0, x1 = self.x_range
        border = np.concatenate([
            np.stack([np.arange(x0, x1 + 1, 8.0), np.full_like(np.arange(x0, x1 + 1, 8.0), y)], -1)
            for y in (ra, rb)
        ] + [np.stack([np.full_like(np.arange(ra, rb + 1, 8.0), x), np.arange(ra, rb + 1, 8.0)],
                      -1) for x in (x0, x1)])  # fmt: skip
        border[:, 1] += self.shift[side]
        sensor = self.grids.to_sensor(side, border) - self.origin[side]
        image = self.img[side]
        h, w = image.shape
        c0 = int(np.clip(np.floor(sensor[:, 0].min()) - BAND_MARGIN_PX, 0, w))
        c1 = int(np.clip(np.ceil(sensor[:, 0].max()) + BAND_MARGIN_PX + 1, c0, w))
        r0 = int(np.clip(np.floor(sensor[:, 1].min()) - BAND_MARGIN_PX, 0, h))
        r1 = int(np.clip(np.ceil(sensor[:, 1].max()) + BAND_MARGIN_PX + 1, r0, h))
        if c1 <= c0 or r1 <= r0:
            return np.full((rb - ra, x1 - x0), np.nan, np.float32)
        return resample_epipolar(
            image[r0:r1, c0:c1], self.grids, side,
            origin_xy=tuple(float(v) for v in self.origin[side] + (c0, r0)),
            y_shift_px=self.shift[side], x_range=self.x_range, y_range=(ra, rb),
        )  # fmt: skip

    def band(self, r0, r1, keep=False):
        """Disparity ``(r1 - r0, width)`` of epipolar rows ``[r0, r1)`` (NaN = none), the left
        image's valid mask there, and (``keep``) both epipolar images of the band."""
        rows_e = self.grids.epipolar_shape[0]
        ra, rb = max(r0 - BAND_OVERLAP_ROWS, 0), min(r1 + BAND_OVERLAP_ROWS, rows_e)
        left, right = self._resample("left", ra, rb), self._resample("right", ra, rb)
        valid_l, valid_r = np.isfinite(left), np.isfinite(right)
        disp = sgm_disparity(
            to_uint8(left, self.lims[0]), to_uint8(right, self.lims[1]), *self.drange, self.sgm,
            valid=valid_l,
        )  # fmt: skip
        x0, x1 = self.x_range
        ye, xe = np.mgrid[0 : rb - ra, x0:x1]
        xr = np.rint(xe + np.nan_to_num(disp)).astype(np.int64) - x0
        in_r = (xr >= 0) & (xr < x1 - x0)
        ok_r = np.zeros_like(valid_l)
        ok_r[in_r] = valid_r[ye[in_r], xr[in_r]]
        disp = np.where(ok_r, disp, np.nan)
        core = slice(r0 - ra, r1 - ra)
        images = (left[core], right[core]) if keep else ()
        return disp[core], valid_l[core], images


def _triangulate(ref, sec, matches, method):
    """Points ``(n, 3)`` and height sigmas ``(n,)`` (NaN for ``los_midpoint``) of ``(n, 2, 2)``
    matches, in chunks of one size (one compilation whatever the band)."""
    n = matches.shape[0]
    pad = -n % TRIANGULATION_CHUNK
    if pad:
        matches = np.concatenate([matches, np.full((pad, 2, 2), np.nan)])
    points, result = triangulate([ref, sec], matches, method, chunk=TRIANGULATION_CHUNK)
    sigma_h = np.full(n, np.nan)
    if result is not None:
        sigma_h = np.asarray(result.sigma_enu)[:n, 2]
    return points[:n], sigma_h


def dsm_from_images(
    models: Sequence[AbstractSensorModel],
    paths: Sequence[str | os.PathLike],
    roi: tuple[int, int, int, int] | None = None,
    res_m: float = 0.5,
    epsg: int | None = None,
    origin: tuple[float, float] | None = None,
    shape: tuple[int, int] | None = None,
    method: str = "intersect",
    keep_dir: str | os.PathLike | None = None,
    progress: bool = False,
    register: bool = True,
    band_rows: int | None = BAND_ROWS,
) -> tuple[DSMGrid, list[dict]]:
    """DSM of ``roi`` of the first image from the pairs (first, i): pooled points, median per
    cell. Returns the grid and each pair's stats.

    ``register``: with three or more images, remove each pair's height offset relative to the
    per-cell median of the pairs before pooling. One pair cannot observe the component of the
    models' relative bias along the epipolar lines; it shifts that pair's heights (by +-2.5 m
    between the two pairs of the s2p triplet, without GCPs). s2p registers its pair height maps
    too. With GCPs, adjust the models first (``jaxgeo adjust``) and pass ``register=False``.

    ``keep_dir``: write each pair's intermediate
    products there (``pair_i.npz``: epipolar images, disparity, tie points, points).
    ``band_rows``: epipolar rows per band of dense matching (:func:`stereo_pair`); ``progress``:
    a progress bar per pair (tqdm, on stderr)."""
    if len(models) != len(paths) or len(paths) < 2:
        raise ValueError("dsm: give at least two images, each with its model")
    all_points, all_stats = [], []
    n = len(paths) - 1
    for i in range(1, len(paths)):
        bar = _Progress(f"pair {i}/{n}", progress)
        try:
            pair = stereo_pair(
                models[0], models[i], paths[0], paths[i], roi, method=method,
                keep=keep_dir is not None, log=bar.log, band_rows=band_rows, on_band=bar.band,
            )  # fmt: skip
        finally:
            bar.close()
        all_points.append(pair.points)
        all_stats.append(pair.stats)
        if keep_dir is not None:
            out = pathlib.Path(keep_dir)
            out.mkdir(parents=True, exist_ok=True)
            np.savez_compressed(out / f"pair_{i}.npz", points=pair.points, **pair.intermediates)
    if progress:
        print("[dsm] rasterising", file=sys.stderr, flush=True)
    if register and len(all_points) > 1:
        offsets = _height_offsets(all_points, res_m, epsg)
        for pts, st, off in zip(all_points, all_stats, offsets, strict=True):
            pts[:, 2] -= off
            st["height_offset_removed_m"] = float(off)
    dsm = rasterize(np.concatenate(all_points), res_m, epsg=epsg, origin=origin, shape=shape)
    return dsm, all_stats


class _Progress:
    """A tqdm bar over the dense-matching bands of one pair; the stage messages as its postfix.
    Silent when not ``enabled``."""

    def __init__(self, name: str, enabled: bool):
        self.bar = None
        if enabled:
            from tqdm import tqdm

            self.bar = tqdm(total=1, desc=name, unit="band", file=sys.stderr, leave=True)

    def log(self, msg: str) -> None:
        if self.bar is not None:
            self.bar.set_postfix_str(msg[:60])

    def band(self, done: int, total: int) -> None:
        if self.bar is not None:
            self.bar.total = total
            self.bar.n = done
            self.bar.refresh()

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def _height_offsets(all_points, res_m, epsg):
    """Per pair, the median over shared cells of its height minus the per-cell median of all
    pairs: the pairs' relative height offsets (zero-sum for two pairs)."""
    pooled = np.concatenate(all_points)
    base = rasterize(pooled, res_m, epsg=epsg)
    maps = [
        rasterize(p, res_m, epsg=base.epsg, origin=(base.x0, base.y0), shape=base.height.shape)
        for p in all_points
    ]
    stack = np.stack([m.height for m in maps])
    common = np.all(np.isfinite(stack), axis=0)
    if common.sum() < 100:
        return np.zeros(len(all_points))
    level = np.median(stack[:, common], axis=0)
    return np.array([float(np.median(h[common] - level)) for h in stack])
