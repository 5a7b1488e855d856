"""The stereo chain for one pair and for N images: ties -> rectification -> SGM -> points -> DSM.

For a pair (reference image, secondary image) and a ROI of the reference image (matched with
``CONTEXT_PX`` of context around it; only the ROI's points are kept):

1. Verified tie points (:func:`~jaxgeo.stereo.tie_points`, SIFT at half resolution on a tile's
   windows: :mod:`._keypoints`); their heights give the reference elevation of the
   rectification (median); tie points outside the models' validity cube are an error naming
   the images (the models do not fit them).
2. Epipolar grids at that elevation (:mod:`._rectification`) and resampling of both images.
3. The residual vertical disparity (the models' relative bias across the epipolar lines) is
   measured on the tie points carried into the epipolar frame through the grids (s2p's
   "relative pointing correction" from its sensor-space matches) and removed by shifting the
   right sampling (a translation, or an affine trend when the ties determine one); it is
   reported before and after (the ties' residual). The same ties give SGM's disparity range
   (their 0.5-99.5 percentiles, widened).
4. Semi-global matching over bands of epipolar rows (:mod:`._dense`), masked where either
   epipolar image has no data, then a correlation refinement of the sub-pixel disparities.
5. Triangulation of every valid disparity (:mod:`._triangulation`: interpolated between the
   exactly triangulated nodes of an epipolar lattice, checked to a millimetre); points outside
   the models' validity cube are dropped, and most of them outside is an error naming the images.

The N-image DSM pools the points of the pairs (reference, i) and rasterises them (:mod:`._dsm`:
point footprints against the aliasing of the point lattice and the cells, small holes
interpolated and flagged).
"""

from __future__ import annotations

import os
import pathlib
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from .._runtime.progress import Progress, say
from ..io.internal import open_raster
from ..models import AbstractSensorModel
from ._dense import (
    BandMatcher,
    disparity_range,
    vertical_disparity,
    y_shift_at,
)
from ._dsm import DSMGrid, local_utm_epsg, point_spacing, rasterize, to_map
from ._heights import ties_over_terrain
from ._keypoints import reference_features, sift_level, window_keypoints
from ._matching import stretch_limits
from ._rectification import EpipolarGrids, epipolar_grids
from ._settings import DEFAULT_DSM, DSMSettings
from ._stages import stage
from ._ties import MatchSettings
from ._triangulation import (
    MIN_LATTICE_POINTS,
    StereoError,
    check_ties,
    disparity_lattice,
    drop_outside_validity,
    los_heights,
    triangulate_disparities,
)
from ._uncertainty import Orientation, pair_orientation, point_height_sigmas

MIN_TIE_POINTS = 10
CONTEXT_PX = 16
"""Reference-image pixels matched around the ROI (context at its edges; not in the output)."""
TIE_KEYPOINTS = 1500
"""Reference keypoints matched per pair (the strongest of each part of the window; the
secondary's window keeps as many per pixel): the ties give the rectification's height, the
vertical disparity and the disparity range, for which several hundred are plenty (10 000 gave
~7 500 ties and cost a quarter of a 1 Mpx tile; SIFT's cost is mostly the descriptors)."""


def read_window(path: str | os.PathLike, window: tuple[int, int, int, int]) -> np.ndarray:
    """Band 1 of ``path`` over ``(col_off, row_off, width, height)`` as float32 (only that
    window is read)."""
    from rasterio.windows import Window

    from ._matching import pixels_of

    with _open(path) as src, pixels_of(path):
        return src.read(1, window=Window(*window)).astype(np.float32)


def _open(path):
    """rasterio dataset of a sensor image: no geotransform is expected (no warning for it)."""

    return open_raster(path)


def image_size(path: str | os.PathLike) -> tuple[int, int]:
    """``(width, height)`` of a raster."""
    with _open(path) as src:
        return src.width, src.height


@dataclass
class PairProducts:
    """Result of :func:`stereo_pair`: ``points`` ``(n, 3)`` lon/lat/h, ``stats`` (numbers to
    report), the points' height sigmas and, when kept, the intermediate products (grids,
    epipolar images, disparity, tie points)."""

    points: np.ndarray
    stats: dict
    grids: EpipolarGrids | None = None
    match_sigma_m: np.ndarray | None = None
    """``(n,)`` height sigma of each point from the matching (m, :mod:`._uncertainty`)."""
    orientation_sigma_m: np.ndarray | None = None
    """``(n,)`` height sigma of each point from the models' orientation (m; 0: unknown)."""
    intermediates: dict = field(default_factory=dict)


def _check_roi(roi, size, path) -> tuple[int, int, int, int]:
    if roi is None:
        return (0, 0, *size)
    col, row, w, h = map(int, roi)
    if col < 0 or row < 0 or w <= 0 or h <= 0 or col + w > size[0] or row + h > size[1]:
        raise StereoError(f"stereo: ROI {tuple(roi)} is not inside {path} ({size[0]} x {size[1]})")
    return col, row, w, h


def _clip(window, size) -> tuple[int, int, int, int]:
    col, row, w, h = window
    c0, r0 = max(col, 0), max(row, 0)
    return c0, r0, min(col + w, size[0]) - c0, min(row + h, size[1]) - r0


def _sec_window(ref, sec, window, h_range, size, paths, margin=64):
    col, row, w, h = window
    xs = np.linspace(col, col + w - 1, 5)
    ys = np.linspace(row, row + h - 1, 5)
    xy = np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)
    pts = np.concatenate([np.asarray(sec.project(ref.localize(xy, z))) for z in h_range])
    ref_path, sec_path = paths
    if not np.all(np.isfinite(pts)):
        raise StereoError(
            f"stereo: the models do not carry the ROI of {ref_path} into {sec_path} (NaN)"
        )
    c0 = int(max(np.floor(pts[:, 0].min()) - margin, 0))
    r0 = int(max(np.floor(pts[:, 1].min()) - margin, 0))
    c1 = int(min(np.ceil(pts[:, 0].max()) + margin, size[0]))
    r1 = int(min(np.ceil(pts[:, 1].max()) + margin, size[1]))
    if c1 <= c0 or r1 <= r0:
        raise StereoError(
            f"stereo: according to the models, {sec_path} does not see the ROI of {ref_path} "
            "(a model of another scene?)"
        )
    return c0, r0, c1 - c0, r1 - r0


def stereo_pair(
    models: Sequence[AbstractSensorModel],
    paths: Sequence[str | os.PathLike],
    settings: DSMSettings = DEFAULT_DSM,
    *,
    dem=None,
    orientation: Orientation = None,
    keep: bool = False,
    log: Callable[[str], None] | None = None,
    on_band: Callable[[int, int], None] | None = None,
) -> PairProducts:
    """3D points of a pair ``models = (ref, sec)`` of the images ``paths`` over
    ``settings.roi = (col, row, width, height)`` of the reference image (whole image by
    default); ``settings.triangulation``: ``intersect`` or ``los_midpoint``
    (:class:`~jaxgeo.stereo.DSMSettings`: also ``epi_step``, ``sgm``, ``band_rows``,
    ``heights``, ``epipolar_tol_px``).

    The epipolar images cover the ROI and ``CONTEXT_PX`` around it (the image pixels there,
    where there are some, are context for matching at the ROI's edges); the points kept are
    those whose reference pixel lies in the ROI. Dense matching and triangulation run over
    bands of ``band_rows`` epipolar rows (``None``: one band), each resampled from the sensor
    pixels it needs; ``on_band(done, total)`` is called after each band and ``log(message)`` at
    each stage (progress); ``keep``: the intermediate products in the result.
    Tie points: :func:`~jaxgeo.stereo.tie_points` (verified; their height range from
    ``heights`` (m, ellipsoidal), else ``dem`` (a :class:`jaxgeo.io.DEM`), else a coarse
    matching); ``epipolar_tol_px``: how far from the models' epipolar curves they may lie (the
    models' relative bias across the epipolar lines; the rectified pair's vertical disparity
    is then measured and removed). Points far outside a model's RPC validity cube (by more than
    ``BLUNDER_MARGIN`` of its half-width) are dropped (NaN). :class:`StereoError` (naming the
    images) when the models do not fit the images: the ROI not seen by the secondary image, too
    few verified tie points, tie points or most 3D points outside a model's validity cube, a
    vertical disparity over ``epipolar_tol_px``.

    Each point's height sigma (:mod:`._uncertainty`): from its disparity's matching sigma, and
    from ``orientation`` (the shift covariance of ``(ref, sec)``, px^2,
    :data:`~jaxgeo.stereo.Orientation`), propagated through the intersection."""
    log = log or (lambda _: None)
    ref, sec = models
    ref_path, sec_path = paths
    method, band_rows, epipolar_tol_px = (settings.triangulation, settings.band_rows,
                                          settings.epipolar_tol_px)  # fmt: skip
    clock = [time.perf_counter()]

    def lap(name):
        now = time.perf_counter()
        stats[f"time_{name}_s"] = round(now - clock[0], 2)
        clock[0] = now

    paths = (ref_path, sec_path)
    ref_size, sec_size = image_size(ref_path), image_size(sec_path)
    roi = _check_roi(settings.roi, ref_size, ref_path)
    col, row, w, h = roi
    grid_win = (col - CONTEXT_PX, row - CONTEXT_PX, w + 2 * CONTEXT_PX, h + 2 * CONTEXT_PX)
    data_win = _clip(grid_win, ref_size)
    stats: dict = {}
    h_valid = los_heights(ref)
    win2 = _sec_window(ref, sec, data_win, h_valid, sec_size, paths)
    with stage("sift"):  # the reference's window, stretch and keypoints: once per tile
        img1, lim1, features1 = reference_features(ref_path, data_win, read_window, TIE_KEYPOINTS)
    with stage("reading"):
        img2 = read_window(sec_path, win2)
        lims = (lim1, stretch_limits(img2[::2, ::2]))
    log("tie points")

    def keypoints(heights):  # both images' where ``heights`` put the ROI in image 2 (None:
        if sift_level(data_win[2:]) == 1:  # tie_points' own full-resolution search)
            return features1, None
        with stage("sift"):
            try:
                c, r, cw, rh = _sec_window(ref, sec, data_win, heights, sec_size, paths,
                                           margin=int(epipolar_tol_px) + 16)  # fmt: skip
            except StereoError:  # not there: both searched anew at one level (full)
                return None, None
            c, r = max(c, win2[0]), max(r, win2[1])  # within img2
            part2 = img2[r - win2[1] : r - win2[1] + rh, c - win2[0] : c - win2[0] + cw]
            most2 = TIE_KEYPOINTS * part2.size / (data_win[2] * data_win[3])  # same density
            return features1, window_keypoints(part2, (c, r), lims[1], int(np.ceil(most2)), 2)

    features = keypoints(h_valid if settings.heights is None else settings.heights)
    with stage("ties"):
        match = MatchSettings(roi=data_win, height_range_m=settings.heights,
                              epipolar_tol_px=epipolar_tol_px)  # fmt: skip
        ties, stats["tie_heights_widened"] = ties_over_terrain(
            (ref, sec), paths, match, dem, (*features, keypoints), MIN_TIE_POINTS
        )
    if len(ties) < MIN_TIE_POINTS:
        raise StereoError(
            f"stereo: only {len(ties)} verified tie points between {ref_path} and {sec_path} "
            f"(need {MIN_TIE_POINTS}): the models do not fit the images (a model of another "
            "image or scene?), or the ROI holds too little texture"
        )
    check_ties(ties.ground, (ref, sec), paths, MIN_TIE_POINTS)
    h0 = float(np.nanmedian(ties.ground[:, 2]))
    stats.update(
        n_ties=len(ties), ties_across_px=ties.report.across_px, h_ref_m=h0,
        ties=ties.report.as_dict(),
    )  # fmt: skip
    lap("ties")
    log(f"{len(ties)} tie points, reference height {h0:.1f} m; rectification")
    with stage("rectification"):
        grids = epipolar_grids(ref, sec, grid_win, elevation=h0, epi_step=settings.epi_step)
        # the tie points in the epipolar frame measure the vertical disparity and the
        # disparity range (s2p's pointing correction from its sensor-space SIFT matches): no
        # second matching
        shift, vstats, dx = vertical_disparity(
            grids.to_epipolar("left", ties.xy1), grids.to_epipolar("right", ties.xy2),
            grids.epipolar_shape, paths, epipolar_tol_px,
        )  # fmt: skip
        dmin, dmax = disparity_range(dx)
    stats.update(
        vstats,
        disparity_range_px=(dmin, dmax),
        mean_baseline_ratio_px_per_m=grids.mean_baseline_ratio,
        epipolar_shape=grids.epipolar_shape,
    )
    lap("vertical_disparity")
    log(f"vertical disparity {vstats['vertical_disparity_px']:+.2f} px removed; "
        f"SGM over [{dmin:.0f}, {dmax:.0f}] px")  # fmt: skip
    # widen the epipolar images by the disparity range: the right matches of the left image's
    # edge columns lie outside its own epipolar extent
    rows_e, cols_e = grids.epipolar_shape
    x0, x1 = min(0, int(np.floor(dmin))), cols_e + max(0, int(np.ceil(dmax)))
    band = rows_e if band_rows is None else max(int(band_rows), 1)
    starts = list(range(0, rows_e, band))
    dense = BandMatcher((img1, img2), (data_win[:2], win2[:2]), grids, shift, (x0, x1), lims,
                        (dmin, dmax), settings.sgm)  # fmt: skip
    kept, n_valid, n_disp = [], 0, 0

    def right_epipolar(epi):  # the right epipolar point of (xe, ye, d), vertical shift included
        right = np.empty((len(epi), 2))
        right[:, 0] = epi[:, 0] + epi[:, 2]
        right[:, 1] = epi[:, 1] + y_shift_at(shift, right[:, 0], epi[:, 1])
        return right

    epipolar, sigma_d, direction = [], [], []
    for k, r0 in enumerate(starts):
        r1 = min(r0 + band, rows_e)
        disp, disp_sigma, valid_l, images = dense.band(r0, r1, keep)
        with stage("triangulation"):
            # the pixels the ROI holds, cell by cell of the grids, then only the matched
            # pixels: no (pixels, 2) float64 mesh per band
            cols, rows = np.arange(x0, x1, dtype=float), np.arange(r0, r1, dtype=float)
            in_roi = valid_l & grids.mesh_in_window("left", cols, rows, roi)
            n_valid += int(in_roi.sum())
            sel = np.isfinite(disp) & in_roi
            n_disp += int(sel.sum())
            row, col = np.nonzero(sel)
            epi = np.empty((len(row), 3))
            epi[:, 0], epi[:, 1], epi[:, 2] = col + x0, row + r0, disp[sel]
            direction.append(grids.along("right", right_epipolar(epi))[1])
            sigma_d.append(disp_sigma[sel])
            epipolar.append(epi)
        if keep:
            kept.append((disp, *images))
        if on_band is not None:
            on_band(k + 1, len(starts))
    stats.update(disparity_fill=float(n_disp / max(n_valid, 1)), n_bands=len(starts))
    lap("sgm")
    with stage("triangulation"):
        epipolar, lattice = np.concatenate(epipolar), None

        def matches_of(rows):  # sensor points of the matches the lattice does not answer
            pair = np.empty((len(rows), 2, 2))
            pair[:, 0] = grids.to_sensor("left", epipolar[rows, :2])
            pair[:, 1] = grids.to_sensor("right", right_epipolar(epipolar[rows]))
            return pair

        if len(epipolar) >= MIN_LATTICE_POINTS:  # the points interpolated between exact nodes
            d, y_of = epipolar[:, 2], lambda xe, ye: ye + y_shift_at(shift, xe, ye)
            lattice = disparity_lattice((ref, sec), grids, lambda xe, ye: np.stack(
                [xe, y_of(xe, ye)], -1), (x0, x1, 0, rows_e), (float(d.min()), float(d.max())),
                method)  # fmt: skip
            stats.update(triangulation_lattice_error_m=lattice.check_error_m,
                         triangulation_lattice=lattice.usable,
                         sigma_lattice_jacobian_error=lattice.jacobian_check_error)  # fmt: skip
        points, sigma_h, up = triangulate_disparities(
            (ref, sec), lattice, epipolar, matches_of, method, up_jacobian=True
        )
        stats.update(drop_outside_validity(points, (ref, sec), paths))
    lap("triangulation")
    with stage("sigma"):
        match_sigma, orient_sigma = point_height_sigmas(
            (ref, sec), points, np.concatenate(direction), np.concatenate(sigma_d), orientation,
            up_jacobian=up,
        )  # fmt: skip
    if np.isfinite(match_sigma).any():
        stats["median_match_sigma_px"] = float(np.nanmedian(np.concatenate(sigma_d)))
        stats["median_match_sigma_h_m"] = float(np.nanmedian(match_sigma))
        stats["median_orientation_sigma_h_m"] = float(np.nanmedian(orient_sigma))
    if method == "intersect" and np.isfinite(sigma_h).any():
        stats["median_sigma_h_m"] = float(np.nanmedian(sigma_h))
    log(f"{len(points)} points ({method})")
    products = PairProducts(
        points=points, stats=stats, match_sigma_m=match_sigma, orientation_sigma_m=orient_sigma
    )
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


def dsm_from_images(
    models: Sequence[AbstractSensorModel],
    paths: Sequence[str | os.PathLike],
    settings: DSMSettings = DEFAULT_DSM,
    *,
    origin: tuple[float, float] | None = None,
    shape: tuple[int, int] | None = None,
    dem=None,
    orientation: Orientation = None,
    progress: bool = False,
) -> tuple[DSMGrid, list[dict]]:
    """DSM of ``settings.roi`` of the first image from the pairs (first, i) in memory (the
    DSM of a file, whole scenes included: :func:`~jaxgeo.stereo.make_dsm`): pooled points,
    median per cell (:func:`rasterize`: each point also stands for the cells its footprint
    covers, the pairs' point spacing; holes up to ``settings.max_hole_m`` across interpolated
    and flagged in the ``filled`` band) at ``settings.res_m`` in ``settings.epsg`` (default the
    local UTM zone); ``origin`` (upper-left corner, m) and ``shape`` (rows, cols) default to the
    points' extent. Returns the grid and each pair's stats. ``dem`` / ``settings.heights``: the
    tie points' height range (:func:`stereo_pair`).

    ``register``: with three or more images, remove each pair's height offset relative to the
    per-cell median of the pairs before pooling. One pair cannot observe the component of the
    models' relative bias along the epipolar lines; it shifts that pair's heights (by +-2.5 m
    between the two pairs of the s2p triplet, without GCPs). s2p registers its pair height maps
    too. With GCPs, adjust the models first (``jaxgeo adjust``) and pass ``register=False``.

    ``height_sigma`` (:mod:`._uncertainty`): the matching's sigma of every point, and
    ``orientation`` (the covariance of the models' remaining image shifts, px^2,
    :data:`~jaxgeo.stereo.Orientation`: from an adjustment,
    :func:`~jaxgeo.stereo.adjustment_covariance`; from its files,
    :func:`~jaxgeo.stereo.orientation_covariances`; ``None``: no orientation term, the
    matching's sigma alone, as for exact models: :func:`~jaxgeo.stereo.make_dsm` gives models
    that were not adjusted their a priori sigma instead), through the intersection, combined
    per cell.

    ``settings.keep``: write each pair's intermediate
    products there (``pair_i.npz``: epipolar images, disparity, tie points, points).
    ``settings.band_rows``: epipolar rows per band of dense matching (:func:`stereo_pair`);
    ``progress``: the bands of each pair counted on stderr, with their ETA (:class:`_Progress`)."""
    if len(models) != len(paths) or len(paths) < 2:
        raise StereoError(
            f"dsm: give at least two images, each with its model ({len(paths)} images, "
            f"{len(models)} models)"
        )
    res_m, epsg, keep_dir = settings.res_m, settings.epsg, settings.keep
    all_points, all_stats, all_sigmas = [], [], []
    n = len(paths) - 1
    for i in range(1, len(paths)):
        bar = _Progress(f"pair {i}/{n}", progress)
        try:
            pair = stereo_pair(
                (models[0], models[i]), (paths[0], paths[i]), settings, dem=dem,
                orientation=pair_orientation(orientation, len(paths), 0, i),
                keep=keep_dir is not None, log=bar.log, on_band=bar.band,
            )  # fmt: skip
        finally:
            bar.close()
        all_points.append(pair.points)
        all_stats.append(pair.stats)
        all_sigmas.append((pair.match_sigma_m, pair.orientation_sigma_m))
        if keep_dir is not None:
            out = pathlib.Path(keep_dir)
            out.mkdir(parents=True, exist_ok=True)
            np.savez_compressed(out / f"pair_{i}.npz", points=pair.points, **pair.intermediates)
    say("[dsm] rasterising", progress)
    if settings.register and len(all_points) > 1:
        offsets = _height_offsets(all_points, res_m, epsg)
        for pts, st, off in zip(all_points, all_stats, offsets, strict=True):
            pts[:, 2] -= off
            st["height_offset_removed_m"] = float(off)
    # a point's footprint is its own pair's spacing (pooled pairs interleave their lattices)
    footprint = max(_spacing(p, epsg) for p in all_points)
    dsm = rasterize(
        np.concatenate(all_points), res_m, epsg=epsg, origin=origin, shape=shape,
        footprint_m=footprint, max_hole_m=settings.max_hole_m,
        sigmas=tuple(np.concatenate(s) for s in zip(*all_sigmas, strict=True)),
    )  # fmt: skip
    return dsm, all_stats


def _spacing(points, epsg):
    """Median distance (m) between neighbouring points of one pair (0 for too few points)."""
    points = points[np.all(np.isfinite(points), axis=1)]
    if len(points) < 2:
        return 0.0
    if epsg is None:
        epsg = local_utm_epsg(*(float(v) for v in np.median(points[:, :2], axis=0)))
    return point_spacing(to_map(points, epsg)[:, :2])


class _Progress:
    """The dense-matching bands of one pair (:class:`~jaxgeo._runtime.progress.Progress`: a
    bar, or plain lines off a terminal, with ETA); the stage messages as its note. Silent when
    not ``enabled``."""

    def __init__(self, name: str, enabled: bool):
        self.bar = Progress(name, None, "band", enabled=enabled)

    def log(self, msg: str) -> None:
        self.bar.note(msg)

    def band(self, done: int, total: int) -> None:
        self.bar.set(done, total)

    def close(self) -> None:
        self.bar.close()


def _height_offsets(all_points, res_m, epsg):
    """Per pair, the median over shared cells of its height minus the per-cell median of all
    pairs: the pairs' relative height offsets (zero-sum for two pairs)."""
    pooled = np.concatenate(all_points)
    measured = dict(footprint_m=0.0, max_hole_m=0.0)  # the cells' own points only
    base = rasterize(pooled, res_m, epsg=epsg, **measured)
    maps = [
        rasterize(
            p,
            res_m,
            epsg=base.epsg,
            origin=(base.x0, base.y0),
            shape=base.height.shape,
            **measured,
        )  # fmt: skip
        for p in all_points
    ]
    stack = np.stack([m.height for m in maps])
    common = np.all(np.isfinite(stack), axis=0)
    if common.sum() < 100:
        return np.zeros(len(all_points))
    level = np.median(stack[:, common], axis=0)
    return np.array([float(np.median(h[common] - level)) for h in stack])
