"""Resampling through the epipolar grids and dense matching (OpenCV semi-global matching).

Disparity convention (shareloc/CARS): left epipolar pixel ``(xe, ye)`` matches right epipolar
``(xe + d, ye)``. OpenCV's StereoSGBM returns ``d_cv`` with ``left(x) = right(x - d_cv)``, so
``d = -d_cv``.

Why OpenCV's SGBM: it installs as a wheel everywhere (``opencv-python-headless``), runs the
3-way SGM on a 700 x 700 Pleiades crop in well under a second on one core, and with its
left-right check, uniqueness and speckle filters gives the DSM figures reported in issue 13 on
the s2p triplet. CNES's ``pandora``/``libsgm`` (CARS's matcher) were not evaluated here. Its
sub-pixel disparities lock to whole pixels; :func:`refine_disparity` re-estimates them by
correlation on the float images.

Before SGM, SIFT matches on the rectified pair measure the vertical disparity that remains (the
models' relative bias across the epipolar lines: :func:`vertical_disparity`) and give SGM's
disparity range (:func:`disparity_range`). :class:`BandMatcher` runs SGM over bands of rows.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ._matching import to_uint8
from ._rectification import EpipolarGrids
from ._stages import stage
from ._triangulation import StereoError

YShift = float | Sequence[float]
"""A shift across the epipolar lines (px): a constant, or ``(a, b_x, b_y)`` for the affine
``a + b_x xe + b_y ye`` of the (right) epipolar pixel ``(xe, ye)``."""


def y_shift_at(y_shift_px: YShift, xe: np.ndarray, ye: np.ndarray) -> np.ndarray:
    """The shift ``y_shift_px`` (:data:`YShift`) at epipolar pixels ``(xe, ye)``."""
    if np.ndim(y_shift_px) == 0:
        return np.full(np.broadcast_shapes(np.shape(xe), np.shape(ye)), float(y_shift_px))
    a, bx, by = (float(v) for v in y_shift_px)
    return a + bx * np.asarray(xe, dtype=float) + by * np.asarray(ye, dtype=float)


def resample_epipolar(
    image: np.ndarray,
    grids: EpipolarGrids,
    side: str,
    origin_xy: tuple[float, float] = (0.0, 0.0),
    y_shift_px: YShift = 0.0,
    interpolation: str = "cubic",
    x_range: tuple[int, int] | None = None,
    y_range: tuple[int, int] | None = None,
) -> np.ndarray:
    """The epipolar image of ``side`` (``grids.epipolar_shape``, float32, NaN outside), or its
    columns ``x_range`` and rows ``y_range`` (``[start, stop)`` epipolar pixels).

    ``image`` holds pixels of the sensor image starting at sensor ``origin_xy`` (a window);
    ``y_shift_px`` moves the sampling across the epipolar lines (:data:`YShift`: the measured
    vertical disparity, right-image correction of the relative bias)."""
    import cv2

    rows, cols = grids.epipolar_shape
    x0, x1 = (0, cols) if x_range is None else x_range
    y0, y1 = (0, rows) if y_range is None else y_range
    # maps relative to the window are small numbers: float32 keeps 1e-4 px (made row block by
    # row block: no float64 mesh of the band)
    sensor = grids.mesh_to_sensor(
        side, np.arange(x0, x1, dtype=float), np.arange(y0, y1, dtype=float),
        lambda xe, ye: ye + y_shift_at(y_shift_px, xe, ye), origin_xy, np.float32,
    )  # fmt: skip
    map_x, map_y = sensor[..., 0], sensor[..., 1]
    flag = {"linear": cv2.INTER_LINEAR, "cubic": cv2.INTER_CUBIC}[interpolation]
    src = np.asarray(image, dtype=np.float32)
    out = cv2.remap(src, sensor, None, flag, borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan)
    h, w = src.shape
    inside = (map_x >= -0.5) & (map_x <= w - 0.5) & (map_y >= -0.5) & (map_y <= h - 0.5)
    return np.where(inside, out, np.nan).astype(np.float32)


MATCHERS = ("jax", "opencv")
"""The dense matchers: the census SGM in JAX (:mod:`._sgm`) and OpenCV's StereoSGBM."""


def default_matcher() -> str:
    """The matcher of ``SGMSettings(matcher=None)``: ``jax`` when JAX's default device is a GPU
    or TPU, else ``opencv`` (on a CPU, OpenCV's SGBM is the faster)."""
    import jax

    return "opencv" if jax.default_backend() == "cpu" else "jax"


@dataclass(frozen=True)
class SGMSettings:
    """Dense matcher settings. ``matcher``: ``jax``, ``opencv`` or ``None`` (by device:
    :func:`default_matcher`). OpenCV's StereoSGBM (OpenCV names): block size, smoothness
    ``P1 = p1 * block**2`` and ``P2 = p2 * block**2``; the JAX census matcher: ``census_p1``,
    ``census_p2`` (census bits of 48; ``P2`` falls at intensity edges) over ``paths`` (8 or 4)
    directions, in chunks of rows that fit ``memory_mb`` (MB; ``None``: from the device,
    :func:`~._sgm.memory_budget`). Both: uniqueness ratio (%), left-right tolerance
    ``disp12_max_diff`` px, speckle filter (window px, range px)."""

    block_size: int = 5
    p1: int = 8
    p2: int = 32
    uniqueness_ratio: int = 10
    disp12_max_diff: int = 1
    speckle_window: int = 50
    speckle_range: int = 2
    refine_window: int = 9
    """Window (px) of the sub-pixel refinement (:func:`refine_disparity`); 0: OpenCV's
    disparities as they are (parabola fit, locked to whole pixels)."""
    matcher: str | None = None
    census_p1: int = 16
    census_p2: int = 160
    paths: int = 8
    memory_mb: float | None = None

    def __post_init__(self):
        if self.matcher is not None and self.matcher not in MATCHERS:
            raise ValueError(f"matcher {self.matcher!r}: expected one of {MATCHERS} (or None: "
                             "by device)")  # fmt: skip
        if self.paths not in (4, 8):
            raise ValueError(f"paths {self.paths}: expected 8 or 4")
        if self.memory_mb is not None and not 0 < self.memory_mb < np.inf:
            raise ValueError(f"memory_mb {self.memory_mb}: expected megabytes > 0 (or None)")


DEFAULT_SGM = SGMSettings()
SPECKLE_NONE = -32768
"""No disparity, for OpenCV's speckle filter (int16, 1/16 px)."""


def sgm_disparity(
    left8: np.ndarray,
    right8: np.ndarray,
    disp_min: float,
    disp_max: float,
    settings: SGMSettings | None = None,
    valid: np.ndarray | None = None,
) -> np.ndarray:
    """Disparity ``d`` (float32, NaN = no match) of two uint8 epipolar images in the range
    ``[disp_min, disp_max]`` (shareloc convention, module docstring), with a left-right check
    (``disp12_max_diff``), uniqueness and speckle filters, by ``settings.matcher``: OpenCV's
    StereoSGBM (3-way) or the census SGM in JAX (:func:`~._sgm.census_sgm`, on JAX's default
    device; its speckle filter is OpenCV's, on the host)."""
    import cv2

    settings = DEFAULT_SGM if settings is None else settings
    if (settings.matcher or default_matcher()) == "jax":
        from ._sgm import census_sgm

        checks = (settings.uniqueness_ratio, settings.disp12_max_diff)
        memory = None if settings.memory_mb is None else settings.memory_mb * 2**20
        disp = census_sgm(left8, right8, disp_min, disp_max, (settings.census_p1,
                          settings.census_p2), checks, settings.paths, memory)  # fmt: skip
        disp = disp.astype(np.float32)
        if settings.speckle_window > 0:  # OpenCV's own way: 1/16 px in int16, in place
            fixed = np.where(np.isfinite(disp), np.rint(16 * np.nan_to_num(disp)), SPECKLE_NONE)
            fixed = np.clip(fixed, SPECKLE_NONE, 32767).astype(np.int16)
            cv2.filterSpeckles(fixed, SPECKLE_NONE, settings.speckle_window,
                               16 * settings.speckle_range)  # fmt: skip
            disp[fixed == SPECKLE_NONE] = np.nan
        if valid is not None:
            disp[~valid] = np.nan
        return disp
    # d = -d_cv: d in [dmin, dmax] <=> d_cv in [-dmax, -dmin]
    min_cv = int(np.floor(-disp_max))
    num = int(np.ceil((-disp_min - min_cv + 1) / 16.0)) * 16
    b = settings.block_size
    sgbm = cv2.StereoSGBM_create(
        minDisparity=min_cv,
        numDisparities=max(num, 16),
        blockSize=b,
        P1=settings.p1 * b * b,
        P2=settings.p2 * b * b,
        disp12MaxDiff=settings.disp12_max_diff,
        uniquenessRatio=settings.uniqueness_ratio,
        speckleWindowSize=settings.speckle_window,
        speckleRange=settings.speckle_range,
        mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY,
    )
    raw = sgbm.compute(left8, right8).astype(np.float32) / 16.0
    bad = raw < min_cv  # OpenCV marks invalid as (minDisparity - 1)
    disp = np.where(bad, np.nan, -raw).astype(np.float32)
    if valid is not None:
        disp[~valid] = np.nan
    return disp


def _box(image: np.ndarray, window: int) -> np.ndarray:
    import cv2

    return cv2.blur(image, (window, window), borderType=cv2.BORDER_REFLECT)


def _zncc_tile(left, right, rows, cols, shifts, window):
    """ZNCC ``(n_shifts, rows, cols)`` of ``window`` squares between ``left`` (already cut to
    ``rows``, ``cols`` padded by half a window) and ``right`` sampled at ``x + shift``."""
    import cv2

    ys, xs = np.mgrid[rows, cols].astype(np.float32)
    mean_l = _box(left, window)
    var_l = _box(left * left, window) - mean_l * mean_l
    out = np.empty((len(shifts), *left.shape), np.float32)
    for k, shift in enumerate(shifts):
        warped = cv2.remap(right, xs + np.float32(shift), ys, cv2.INTER_CUBIC)
        mean_r = _box(warped, window)
        var_r = _box(warped * warped, window) - mean_r * mean_r
        cov = _box(left * warped, window) - mean_l * mean_r
        out[k] = cov / np.sqrt(np.maximum(var_l * var_r, 1e-6))
    return out


def refine_disparity(
    left: np.ndarray,
    right: np.ndarray,
    disparity: np.ndarray,
    window_px: int = 9,
    reach_px: float = 1.0,
    step_px: float = 0.5,
    tile_px: int = 128,
) -> np.ndarray:
    """Sub-pixel refinement of ``disparity`` (:func:`refine_disparity_sigma`, without the
    sigmas)."""
    return refine_disparity_sigma(left, right, disparity, window_px, reach_px, step_px, tile_px)[0]


UNREFINED_SIGMA_PX = 0.5
"""Matching sigma (px) of a disparity the correlation does not refine (SGBM's, locked to whole
pixels, or at the edge of the reach): half a pixel."""
MATCH_SIGMA_SCALE = 2.2
"""Scale of :func:`correlation_sigma_px`: the correlation window's pixels are not independent
(band-limited images, bicubic resampling), ``81 / 2.2**2 ~ 17`` of a 9 x 9 window count.
Calibrated once on simulated truth (``jaxgeo simulate stereo-scene --size 600 --seed 11
--exact-rpc``, 371 000 cells): the value that makes the median of ``|DSM - truth| /
height_sigma`` a Gaussian's 0.674 (1.28 with a scale of 1); tested on other seeds."""
MIN_MATCH_SIGMA_PX = 0.01
MAX_MATCH_SIGMA_PX = 1.0
"""Bounds of a refined disparity's sigma (px): the refinement's reach at most."""


def correlation_sigma_px(zncc, curvature_per_px2, window_px):
    """Standard deviation (px) of the disparity at the peak of a ZNCC curve of correlation
    ``zncc`` and second derivative ``curvature_per_px2`` (< 0) over ``window_px`` squares:
    ``MATCH_SIGMA_SCALE * sqrt(2 (1 - zncc) / (window_px**2 |curvature|))``.

    Why: with image noise of variance ``s_n**2`` in both images, signal variance ``s_i**2`` and
    mean squared gradient ``g2``, least-squares matching has ``var(d) = 2 s_n**2 / (n g2)``
    (``n`` pixels); the ZNCC peak gives ``1 - zncc = s_n**2 / s_i**2`` and
    ``|curvature| = g2 / s_i**2``, whose ratio is that variance without knowing the noise."""
    one_minus = np.clip(1.0 - np.asarray(zncc, float), 1e-4, 2.0)
    curv = np.abs(np.asarray(curvature_per_px2, float))
    with np.errstate(divide="ignore", invalid="ignore"):
        sigma = MATCH_SIGMA_SCALE * np.sqrt(2.0 * one_minus / (window_px**2 * curv))
    sigma = np.where(np.isfinite(sigma), sigma, MAX_MATCH_SIGMA_PX)
    return np.clip(sigma, MIN_MATCH_SIGMA_PX, MAX_MATCH_SIGMA_PX)


def refine_disparity_sigma(
    left: np.ndarray,
    right: np.ndarray,
    disparity: np.ndarray,
    window_px: int = 9,
    reach_px: float = 1.0,
    step_px: float = 0.5,
    tile_px: int = 128,
) -> tuple[np.ndarray, np.ndarray]:
    """Sub-pixel refinement of ``disparity`` (float32, NaN = none) on the float epipolar images
    (NaN = no data): the disparity within ``reach_px`` of SGBM's that maximises the zero-mean
    normalised cross-correlation of ``window_px`` squares (right image resampled bicubically
    every ``step_px``, then a parabola through the best step and its neighbours).

    Why: OpenCV's SGBM fits a parabola to its aggregated costs, which locks disparities to whole
    pixels (on a Pleiades pair of the s2p triplet, 4x more disparities within 1/16 px of an
    integer than at the half pixel); at 4.4 m of height per pixel of disparity that costs up to
    ~1 m. Measured there against s2p's DSM: median |dh| 0.69 -> 0.50 m. The correlation is
    exact for each pixel's own window at a constant shift (evaluated tile by tile over the
    shifts the tile needs). A disparity whose best correlation lies at the edge of the reach, or
    whose window meets no-data, keeps SGBM's value.

    Returns the disparities and their matching sigmas (px, float32, NaN where no disparity):
    :func:`correlation_sigma_px` of the refined ones' correlation peaks, ``UNREFINED_SIGMA_PX``
    for those that keep SGBM's value."""
    import cv2

    found = np.isfinite(disparity)
    sigma = np.where(found, UNREFINED_SIGMA_PX, np.nan).astype(np.float32)
    if not found.any() or window_px < 3:
        return disparity, sigma
    nrows, ncols = disparity.shape
    half = window_px // 2
    lft = np.where(np.isfinite(left), left, 0.0).astype(np.float32)
    rgt = np.where(np.isfinite(right), right, 0.0).astype(np.float32)
    # no data within the window: the left's, and the right's around the match
    kernel = np.ones((window_px + 2, window_px + 4), np.uint8)
    gap_l = cv2.dilate((~np.isfinite(left)).astype(np.uint8), kernel) > 0
    gap_r = cv2.dilate((~np.isfinite(right)).astype(np.uint8), kernel) > 0
    out = disparity.astype(np.float32).copy()
    for r0 in range(0, nrows, tile_px):
        for c0 in range(0, ncols, tile_px):
            r1, c1 = min(r0 + tile_px, nrows), min(c0 + tile_px, ncols)
            d = disparity[r0:r1, c0:c1]
            use = np.isfinite(d) & ~gap_l[r0:r1, c0:c1]
            if not use.any():
                continue
            lo = np.floor((d[use].min() - reach_px) / step_px) - 1
            hi = np.ceil((d[use].max() + reach_px) / step_px) + 1
            shifts = np.arange(lo, hi + 1) * step_px
            ra, rb = max(r0 - half, 0), min(r1 + half, nrows)
            ca, cb = max(c0 - half, 0), min(c1 + half, ncols)
            z = _zncc_tile(lft[ra:rb, ca:cb], rgt, slice(ra, rb), slice(ca, cb), shifts, window_px)
            z = z[:, r0 - ra : r1 - ra, c0 - ca : c1 - ca]
            near = np.abs(shifts[:, None, None] - d[None]) <= reach_px
            near[0], near[-1] = False, False
            k = np.argmax(np.where(near, z, -np.inf), axis=0)
            at_edge = ~np.take_along_axis(near, (k - 1)[None], 0)[0]
            at_edge |= ~np.take_along_axis(near, (k + 1)[None], 0)[0]
            zm, z0, zp = (np.take_along_axis(z, (k + o)[None], 0)[0] for o in (-1, 0, 1))
            curv = zm - 2 * z0 + zp
            frac = np.where(curv < 0, 0.5 * (zm - zp) / np.where(curv < 0, curv, -1.0), 0.0)
            best = shifts[k] + np.clip(frac, -0.5, 0.5) * step_px
            ys, xs = np.mgrid[r0:r1, c0:c1]
            xr = np.clip(np.rint(xs + np.nan_to_num(best)).astype(np.int64), 0, ncols - 1)
            ok = use & ~at_edge & np.isfinite(best) & ~gap_r[ys, xr]
            out[r0:r1, c0:c1] = np.where(ok, best, d)
            # the parabola's value at its vertex
            peak = z0 - 0.25 * (zm - zp) * np.clip(frac, -0.5, 0.5)
            s = correlation_sigma_px(peak, np.where(curv < 0, curv, 0.0) / step_px**2, window_px)
            sigma[r0:r1, c0:c1] = np.where(ok, s, sigma[r0:r1, c0:c1])
    return out, sigma


DISPARITY_MARGIN_PX = 8.0
DISPARITY_MARGIN_FRACTION = 0.2
MIN_MATCHES = 10
MIN_AFFINE_MATCHES = 50
MAX_TREND_PX = 2.0
"""An affine trend of the vertical disparity is used when it stays within this many px of its
median over the epipolar image (otherwise the matches do not determine it: a constant)."""


def robust_inliers(values, k=3.5, floor=0.5):
    """True where ``values`` lie within ``max(k sigma, floor)`` of their median (sigma from the
    MAD)."""
    med = np.median(values)
    sigma = 1.4826 * np.median(np.abs(values - med))
    return np.abs(values - med) <= max(k * sigma, floor)


def vertical_disparity(a, b, epipolar_shape, paths, tol_px):
    """The right image's :data:`YShift` (the models' relative bias across the epipolar lines:
    a constant, or an affine trend when it is well determined) from matches of the pair in
    epipolar coordinates (``a`` left, ``b`` right, ``(n, 2)``: the tie points carried through
    the grids), the stats and the along-line offsets ``dx`` of the inlier matches. The stats'
    ``vertical_disparity_after_px`` / ``_std_px`` are the inliers' residual offsets across the
    lines once the shift is applied."""
    pair = f"{paths[0]} and {paths[1]}"
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    finite = np.all(np.isfinite(a), axis=1) & np.all(np.isfinite(b), axis=1)
    a, b = a[finite], b[finite]
    dy = b[:, 1] - a[:, 1]
    if len(dy) < MIN_MATCHES:
        raise StereoError(
            f"stereo: only {len(dy)} tie points between {pair} in the epipolar frame (need "
            f"{MIN_MATCHES}): no common texture, or models that do not fit the images"
        )
    ok = np.abs(dy - np.median(dy)) < tol_px
    ok[ok] = robust_inliers(dy[ok])
    dy_med = float(np.median(dy[ok])) if ok.any() else float(np.median(dy))
    if ok.sum() < MIN_MATCHES or abs(dy_med) > tol_px:
        raise StereoError(
            f"stereo: the rectified {pair} are offset by {dy_med:+.1f} px across the epipolar "
            f"lines ({ok.sum()} consistent tie points of {len(dy)}; a relative bias of the "
            f"models is within {tol_px:g} px): the models do not fit the images"
        )
    shift: YShift = dy_med
    trend = (0.0, 0.0)
    if ok.sum() >= MIN_AFFINE_MATCHES:
        design = np.column_stack([np.ones(ok.sum()), b[ok]])
        coef = np.linalg.lstsq(design, dy[ok], rcond=None)[0]
        rows, cols = epipolar_shape
        corners = np.array([[1, 0, 0], [1, cols, 0], [1, 0, rows], [1, cols, rows]], float)
        if np.max(np.abs(corners @ coef - dy_med)) <= MAX_TREND_PX:
            shift, trend = tuple(float(c) for c in coef), (1e3 * coef[1], 1e3 * coef[2])
    after = dy[ok] - y_shift_at(shift, b[ok, 0], a[ok, 1])
    stats = dict(
        vertical_disparity_px=dy_med,
        vertical_disparity_std_px=float(np.std(dy[ok])),
        vertical_disparity_trend_px_per_1000px=tuple(round(float(t), 4) for t in trend),
        n_epipolar_matches=int(ok.sum()),
        vertical_disparity_after_px=float(np.median(after)),
        vertical_disparity_after_std_px=float(np.std(after)),
    )
    return shift, stats, (b[:, 0] - a[:, 0])[ok]


def disparity_range(dx):
    """SGM's disparity range from the along-line offsets of the epipolar matches: their 0.5 and
    99.5 percentiles (a few false matches ignored, a minority surface such as roofs or a valley
    kept) widened by ``max(DISPARITY_MARGIN_PX, DISPARITY_MARGIN_FRACTION`` of the span)."""
    lo, hi = (float(v) for v in np.percentile(dx, [0.5, 99.5]))
    margin = max(DISPARITY_MARGIN_PX, DISPARITY_MARGIN_FRACTION * (hi - lo))
    return lo - margin, hi + margin


BAND_OVERLAP_ROWS = 32
BAND_MARGIN_PX = 8


def _whole_window(valid: np.ndarray, box: tuple[int, int]) -> np.ndarray:
    """Where the ``box`` (rows, columns) around a pixel lies within ``valid`` (the array's
    own edges count as valid: the band's rows go on beyond them)."""
    import cv2

    kernel = np.ones(box, np.uint8)
    return cv2.erode(valid.astype(np.uint8), kernel, borderValue=1) > 0


class BandMatcher:
    """SGM over bands of epipolar rows: each band is resampled from the sensor pixels it needs,
    with ``BAND_OVERLAP_ROWS`` of context above and below (SGM's vertical paths) dropped after
    matching, so the result matches one pass over the whole image up to those paths' reach.

    ``images``/``origins``: the left and right sensor windows and their sensor origins;
    ``y_shift``: the right image's :data:`YShift`; ``x_range``: the epipolar columns matched;
    ``limits``: the uint8 stretch of each side; ``disparity_range``: SGM's ``(min, max)``."""

    def __init__(self, images, origins, grids, y_shift, x_range, limits, disparity_range, sgm):
        self.img = dict(zip(("left", "right"), images, strict=True))
        left_origin, right_origin = (np.asarray(o, float) for o in origins)
        self.origin = {"left": left_origin, "right": right_origin}
        self.shift = {"left": 0.0, "right": y_shift}
        self.grids, self.x_range, self.lims = grids, x_range, limits
        self.drange, self.sgm = disparity_range, sgm

    def _resample(self, side, ra, rb):
        """Epipolar rows ``[ra, rb)`` of ``side`` from the part of the image they sample."""
        x0, x1 = self.x_range
        xs, ys = np.arange(x0, x1 + 1, 8.0), np.arange(ra, rb + 1, 8.0)
        border = np.concatenate(
            [np.stack([xs, np.full_like(xs, y)], -1) for y in (ra, rb)]
            + [np.stack([np.full_like(ys, x), ys], -1) for x in (x0, x1)]
        )
        border[:, 1] += y_shift_at(self.shift[side], border[:, 0], border[:, 1])
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
        """Disparity ``(r1 - r0, width)`` of epipolar rows ``[r0, r1)`` (NaN = none), its
        matching sigma (px, :func:`refine_disparity_sigma`), the left image's valid mask there,
        and (``keep``) both epipolar images of the band. A pixel whose matching window, in the
        left image or around its match in the right, meets no data has no disparity."""
        rows_e = self.grids.epipolar_shape[0]
        ra, rb = max(r0 - BAND_OVERLAP_ROWS, 0), min(r1 + BAND_OVERLAP_ROWS, rows_e)
        with stage("resampling"):
            left, right = self._resample("left", ra, rb), self._resample("right", ra, rb)
            valid_l, valid_r = np.isfinite(left), np.isfinite(right)
            left8, right8 = to_uint8(left, self.lims[0]), to_uint8(right, self.lims[1])
        # a disparity whose matching window (SGBM's block, the refinement's) meets no data in
        # either image is dropped: SGBM sees the fill (0 in uint8) as texture, matches the edge
        # of one image's data to the other's, and its paths carry that into the neighbouring
        # pixels; nor can the correlation check such a disparity (it kept SGBM's). Measured
        # within 3 cells of the DSM's edge, before: height error RMS 4.1 m against 0.22 m inside
        # on a simulated pair, 11 % of the Ventoux cells > 5 m from their neighbours' median
        # (tests/stereo/test_dsm_edges.py); a ring of about 6 px is lost
        b, w = self.sgm.block_size, self.sgm.refine_window
        # the refinement's window with its reach and the bicubic's support, as the no-data
        # test of refine_disparity_sigma
        box = (max(b, w + 2), max(b, w + 4)) if w else (b, b)
        whole_l, whole_r = _whole_window(valid_l, box), _whole_window(valid_r, box)
        with stage("sgm"):
            disp = sgm_disparity(left8, right8, *self.drange, self.sgm, valid=whole_l)
        sigma = np.where(np.isfinite(disp), UNREFINED_SIGMA_PX, np.nan).astype(np.float32)
        if self.sgm.refine_window:
            with stage("refinement"):
                disp, sigma = refine_disparity_sigma(left, right, disp, self.sgm.refine_window)
        x0, x1 = self.x_range
        ye, xe = np.mgrid[0 : rb - ra, x0:x1]
        xr = np.rint(xe + np.nan_to_num(disp)).astype(np.int64) - x0
        in_r = (xr >= 0) & (xr < x1 - x0)
        ok_r = np.zeros_like(valid_l)
        ok_r[in_r] = whole_r[ye[in_r], xr[in_r]]
        disp = np.where(ok_r, disp, np.nan)
        core = slice(r0 - ra, r1 - ra)
        images = (left[core], right[core]) if keep else ()
        return disp[core], np.where(ok_r, sigma, np.nan)[core], valid_l[core], images
