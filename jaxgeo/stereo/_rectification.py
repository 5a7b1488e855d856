"""Epipolar rectification grids for any pair of sensor models (the shareloc/OTB method).

Only ``model.project`` and ``model.localize`` are used, so every jaxgeo model (RPC, RPC + bias,
Kepler, ephemeris, spline pushbroom) can be rectified.

Method (the one of OTB's StereoRectificationGridGenerator and CNES shareloc
``compute_stereorectification_epipolar_grids``, re-implemented): the local epipolar direction at
a left-image point is the line, in the left image, joining the images of the right ray through
that point's right correspondent at ``h - dh`` and ``h + dh`` (``dh`` = ``elevation_offset_m``).
Starting at the upper-left corner of the left image's epipolar bounding box, the grid is built
by walking ``epi_step`` pixels perpendicular to the local epipolar direction (first column of
nodes), then along it (each row); every node's right position is its left position carried to
the right image at the reference elevation (``localize`` in the left, ``project`` in the right).

Conventions: jaxgeo image coordinates (integer = pixel centre) in the sensor images and in
the epipolar images. Node ``(i, j)`` sits at epipolar pixel ``(xe, ye) = (step j, step i)``;
node ``(0, 0)`` is the centre of the window's first pixel. Between nodes the grids are bilinear
with linear extrapolation (as shareloc and CARS read them). OTB/shareloc displacement grids are
``sensor (their +0.5 convention) - node``: :meth:`EpipolarGrids.displacement` returns them, so
``displacement + node - 0.5`` is the jaxgeo sensor position (checked against OTB's grids and
CARS's triangulation of the Ventoux disparity map: an epipolar pixel index is used as is).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from ..models import AbstractSensorModel

Elevation = float | Callable[[np.ndarray], np.ndarray]
"""A constant ellipsoidal height (m) or a function ``(lon_deg, lat_deg) (n, 2) -> h_m (n,)``."""

DEM_ITERATIONS = 12


@dataclass(frozen=True)
class EpipolarGrids:
    """Rectification grids of a stereo pair.

    Fields:
        left, right: ``(rows, cols, 2)`` sensor ``(x, y)`` px (jaxgeo convention) at the nodes.
        step_px: node spacing in epipolar pixels.
        epipolar_shape: ``(rows, cols)`` of the epipolar images.
        mean_baseline_ratio: mean over the nodes of the left-image length of the local epipolar
            segment per metre of height (px/m): disparity per metre.
        heights_m: ``(rows, cols)`` reference ellipsoidal height at each node.
    """

    left: np.ndarray
    right: np.ndarray
    step_px: float
    epipolar_shape: tuple[int, int]
    mean_baseline_ratio: float
    heights_m: np.ndarray

    def node_xy(self) -> np.ndarray:
        """``(rows, cols, 2)`` epipolar ``(xe, ye)`` of the nodes."""
        return node_xy(self.left.shape[:2], self.step_px)

    def displacement(self, side: str) -> np.ndarray:
        """``(rows, cols, 2)`` displacement grid as OTB/shareloc write it: sensor position in
        their convention (jaxgeo + 0.5) minus node position (band order col, row)."""
        grid = {"left": self.left, "right": self.right}[side]
        return grid + 0.5 - self.node_xy()

    @classmethod
    def from_displacement(cls, left, right, step_px, epipolar_shape) -> EpipolarGrids:
        """Grids from OTB/shareloc displacement grids ``(rows, cols, 2)`` (band 1 col, 2 row)."""
        nodes = node_xy(np.shape(left)[:2], step_px)
        left = np.asarray(left, dtype=float) + nodes - 0.5
        right = np.asarray(right, dtype=float) + nodes - 0.5
        nan = np.full(left.shape[:2], np.nan)
        return cls(left, right, float(step_px), tuple(epipolar_shape), float("nan"), nan)

    def to_sensor(self, side: str, epi_xy: np.ndarray) -> np.ndarray:
        """Epipolar ``(..., 2)`` ``(xe, ye)`` -> sensor ``(x, y)`` of ``side`` (bilinear, linear
        extrapolation outside the nodes)."""
        grid = {"left": self.left, "right": self.right}[side]
        return interpolate_grid(grid, self.step_px, epi_xy)

    def mesh_to_sensor(self, side: str, xs, ys, y_of=None, origin_xy=(0.0, 0.0), dtype=float):
        """:meth:`to_sensor` on the mesh of epipolar columns ``xs`` and rows ``ys`` (sampled at
        rows ``y_of(xe, ye)`` when given), minus ``origin_xy``: ``(len(ys), len(xs), 2)`` of
        ``dtype`` (:func:`interpolate_mesh`)."""
        grid = {"left": self.left, "right": self.right}[side]
        return interpolate_mesh(grid, self.step_px, xs, ys, y_of, origin_xy, dtype)

    def mesh_in_window(self, side: str, xs, ys, window, margin_px: float = 1e-6) -> np.ndarray:
        """``(len(ys), len(xs))``: True where :meth:`mesh_to_sensor`'s pixel of the mesh of
        epipolar columns ``xs`` and rows ``ys`` falls in the sensor ``window = (col, row, w, h)``
        (``col - 0.5 <= x < col + w - 0.5``, likewise in rows).

        Why: a band's million pixels mapped one by one only to be tested cost a third of a
        tile's triangulation. A bilinear value is a convex combination of its cell's four nodes:
        a grid cell whose nodes all lie inside the window (by ``margin_px``, for rounding) is
        inside, one whose nodes all lie beyond one edge is outside; only the pixels of the other
        cells, and those beyond the nodes (extrapolated), are mapped: the same answer."""
        grid = {"left": self.left, "right": self.right}[side]
        xs, ys = np.asarray(xs, dtype=float), np.asarray(ys, dtype=float)
        col, row, w, h = window
        lo, hi = np.array([col - 0.5, row - 0.5]), np.array([col + w - 0.5, row + h - 0.5])

        def cells(nodes):  # all four nodes of each cell
            return nodes[:-1, :-1] & nodes[1:, :-1] & nodes[:-1, 1:] & nodes[1:, 1:]

        state = np.zeros((grid.shape[0] - 1, grid.shape[1] - 1), np.int8)  # 0: undecided
        state[cells(np.all((grid >= lo + margin_px) & (grid < hi - margin_px), axis=-1))] = 1
        for k in (0, 1):
            state[cells(grid[..., k] < lo[k] - margin_px)] = 2
            state[cells(grid[..., k] >= hi[k] + margin_px)] = 2
        ci, cj = (np.floor(v / self.step_px).astype(np.int64) for v in (ys, xs))
        oki, okj = (ci >= 0) & (ci < state.shape[0]), (cj >= 0) & (cj < state.shape[1])
        mesh = np.zeros((len(ys), len(xs)), np.int8)
        mesh[np.ix_(oki, okj)] = state[np.ix_(ci[oki], cj[okj])]
        inside = mesh == 1
        r, c = np.nonzero(mesh == 0)
        if r.size:
            v = interpolate_grid(grid, self.step_px, np.stack([xs[c], ys[r]], axis=-1))
            inside[r, c] = np.all((v >= lo) & (v < hi), axis=-1)
        return inside

    def along(self, side: str, epi_xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`to_sensor` and the sensor step ``(..., 2)`` per epipolar pixel along the
        lines (the derivative in ``xe``) at the same points."""
        grid = {"left": self.left, "right": self.right}[side]
        return interpolate_grid(grid, self.step_px, epi_xy, along=True)

    def to_epipolar(self, side: str, sensor_xy: np.ndarray) -> np.ndarray:
        """Sensor ``(..., 2)`` ``(x, y)`` of ``side`` -> epipolar ``(xe, ye)`` (the inverse of
        :meth:`to_sensor`; NaN where it has none)."""
        grid = {"left": self.left, "right": self.right}[side]
        return invert_grid(grid, self.step_px, sensor_xy)


def node_xy(shape: tuple[int, int], step: float) -> np.ndarray:
    """``(rows, cols, 2)`` epipolar ``(xe, ye)`` of grid nodes: ``(step j, step i)``."""
    xe = step * np.arange(shape[1], dtype=float)
    ye = step * np.arange(shape[0], dtype=float)
    return np.stack(np.meshgrid(xe, ye), axis=-1)


GRID_BLOCK = 8192
"""Points per block of :func:`interpolate_grid`: its dozen temporaries of this many rows stay in
the cache and are reused, where one pass over a 1 Mpx band made 1e6-row float64 temporaries
(page faults: ~0.25 s per 100 MB measured on the 2-core VM; 198 calls cost 8.5 CPU-s over a
9-tile DSM ROI)."""


def _bilinear(grid: np.ndarray, step: float, epi_xy: np.ndarray):
    """Bilinear value ``(n, k)`` of the grid at epipolar ``(n, 2)`` points and its derivatives
    in ``xe`` and ``ye`` (per epipolar pixel); border cells extended, NaN points give NaN."""
    rows, cols, k = grid.shape
    u = epi_xy[:, 0] * (1.0 / step)
    v = epi_xy[:, 1] * (1.0 / step)
    j0 = np.clip(np.floor(np.nan_to_num(u)), 0, cols - 2).astype(np.intp)
    i0 = np.clip(np.floor(np.nan_to_num(v)), 0, rows - 2).astype(np.intp)
    flat = grid.reshape(-1, k)
    idx = i0 * cols + j0
    g00, g01, g10, g11 = (flat.take(i, axis=0) for i in (idx, idx + 1, idx + cols, idx + cols + 1))
    fu, fv = (u - j0)[:, None], (v - i0)[:, None]
    top, bottom = g00 + (g01 - g00) * fu, g10 + (g11 - g10) * fu
    d_top, d_bottom = g01 - g00, g11 - g10
    d_xe = (d_top + (d_bottom - d_top) * fv) * (1.0 / step)
    return top + (bottom - top) * fv, d_xe, (bottom - top) * (1.0 / step)


def interpolate_grid(
    grid: np.ndarray, step: float, epi_xy: np.ndarray, along: bool = False
) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """Bilinear interpolation of a ``(rows, cols, k)`` node grid at epipolar ``(..., 2)`` points,
    nodes at ``step * index``; outside the nodes the border cells are extended linearly. NaN
    points give NaN. ``along``: also the derivative along the epipolar lines (per epipolar
    pixel of ``xe``). Computed in blocks of :data:`GRID_BLOCK` points."""
    epi_xy = np.asarray(epi_xy, dtype=float)
    shape = (*epi_xy.shape[:-1], grid.shape[2])
    flat = epi_xy.reshape(-1, 2)
    value = np.empty((flat.shape[0], grid.shape[2]))
    d_xe = np.empty_like(value) if along else None
    for s in range(0, flat.shape[0], GRID_BLOCK):
        v, dx, _ = _bilinear(grid, step, flat[s : s + GRID_BLOCK])
        value[s : s + GRID_BLOCK] = v
        if along:
            d_xe[s : s + GRID_BLOCK] = dx
    return (value.reshape(shape), d_xe.reshape(shape)) if along else value.reshape(shape)


def interpolate_mesh(
    grid: np.ndarray,
    step: float,
    xs: np.ndarray,
    ys: np.ndarray,
    y_of: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
    origin_xy: tuple[float, float] = (0.0, 0.0),
    dtype: type = np.float64,
) -> np.ndarray:
    """:func:`interpolate_grid` of a ``(rows, cols, 2)`` grid on the mesh of epipolar columns
    ``xs`` ``(m,)`` and rows ``ys`` ``(n,)``, minus ``origin_xy``, as an ``(n, m, 2)`` array of
    ``dtype``: the same arithmetic, row block by row block, without the mesh's ``(n m, 2)``
    float64 coordinates and temporaries. ``y_of(xe, ye)``: the epipolar row actually sampled
    at each mesh point (a vertical shift; ``None``: ``ye``)."""
    xs, ys = np.asarray(xs, dtype=float), np.asarray(ys, dtype=float)
    out = np.empty((len(ys), len(xs), grid.shape[2]), dtype)
    per = max(GRID_BLOCK // max(len(xs), 1), 1)
    origin = np.asarray(origin_xy, dtype=float)
    block = np.empty((per, len(xs), 2))
    for s in range(0, len(ys), per):
        ye = ys[s : s + per]
        pts = block[: len(ye)]
        pts[..., 0] = xs
        pts[..., 1] = ye[:, None]
        if y_of is not None:
            pts[..., 1] = y_of(pts[..., 0], pts[..., 1])
        value = _bilinear(grid, step, pts.reshape(-1, 2))[0] - origin
        out[s : s + len(ye)] = value.reshape(len(ye), len(xs), -1)
    return out


def invert_grid(
    grid: np.ndarray, step: float, sensor_xy: np.ndarray, iterations: int = 8
) -> np.ndarray:
    """Epipolar ``(..., 2)`` ``(xe, ye)`` whose bilinear grid value (:func:`interpolate_grid`)
    is the sensor ``(..., 2)`` point: Newton's method from the nodes' least-squares affine map
    (the grids are smooth: it converges to 1e-9 px in a few steps). NaN where it does not."""
    sensor_xy = np.asarray(sensor_xy, dtype=float)
    shape = sensor_xy.shape
    target = sensor_xy.reshape(-1, 2)
    nodes = node_xy(grid.shape[:2], step).reshape(-1, 2)
    design = np.column_stack([np.ones(len(nodes)), grid.reshape(-1, 2)])
    affine = np.linalg.lstsq(design, nodes, rcond=None)[0]
    epi = np.column_stack([np.ones(len(target)), target]) @ affine
    for k in range(iterations + 1):
        value, jx, jy = _bilinear(grid, step, epi)
        residual = target - value
        if k == iterations or np.nanmax(np.abs(residual), initial=0.0) < 1e-9:
            break
        det = jx[:, 0] * jy[:, 1] - jy[:, 0] * jx[:, 1]
        dxe = (jy[:, 1] * residual[:, 0] - jy[:, 0] * residual[:, 1]) / det
        dye = (jx[:, 0] * residual[:, 1] - jx[:, 1] * residual[:, 0]) / det
        epi = epi + np.column_stack([dxe, dye])
    epi[~(np.abs(residual).max(axis=1) < 1e-6)] = np.nan
    return epi.reshape(shape)


@jax.jit
def _transfer(src, dst, xy, h):
    return dst.project(src.localize(xy, h))


@jax.jit
def _loc(src, xy, h):
    return src.localize(xy, h)


BATCH = 64
"""Points per call of the jitted transfers: one compiled shape whatever the grid size."""


def _batched(fn, models, xy, h):
    """``fn(*models, xy, h)`` over fixed-size batches (NaN-padded)."""
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    h = np.broadcast_to(np.asarray(h, dtype=float), xy.shape[:1])
    n = xy.shape[0]
    pad = -n % BATCH
    xy = np.concatenate([xy, np.zeros((pad, 2))])
    h = np.concatenate([h, np.zeros(pad)])
    out = [
        np.asarray(fn(*models, jnp.asarray(xy[s : s + BATCH]), jnp.asarray(h[s : s + BATCH])))
        for s in range(0, n + pad, BATCH)
    ]
    return np.concatenate(out)[:n]


class _Pair:
    """Transfers between the two images at given heights (module-level jits: compiled once)."""

    def __init__(self, left: AbstractSensorModel, right: AbstractSensorModel, elevation):
        self.elevation = elevation
        self.left, self.right = left, right

    def height(self, model, xy):
        """Reference height under image points of ``model``: the constant, or the DEM met by
        the ray (fixed-point iteration ``h <- dem(localize(xy, h))``)."""
        xy = np.asarray(xy, dtype=float)
        if not callable(self.elevation):
            return np.full(xy.shape[0], float(self.elevation))
        h = np.zeros(xy.shape[0])
        for _ in range(DEM_ITERATIONS):
            g = _batched(_loc, (model,), xy, h)
            h_new = np.asarray(self.elevation(g[:, :2]), dtype=float)
            if np.nanmax(np.abs(h_new - h)) < 1e-6:
                h = h_new
                break
            h = h_new
        return h

    def coloc(self, src, dst, xy, h):
        return _batched(_transfer, (src, dst), xy, h)


def _epipolar_segment(pair: _Pair, xy_left: np.ndarray, dh: float):
    """Left-image start/end of the local epipolar segment through ``xy_left`` (n, 2), and the
    reference heights."""
    h = pair.height(pair.left, xy_left)
    xy_right = pair.coloc(pair.left, pair.right, xy_left, h)
    start = pair.coloc(pair.right, pair.left, xy_right, h - dh)
    end = pair.coloc(pair.right, pair.left, xy_right, h + dh)
    return start, end, h


def _angle(start, end):
    """Direction of the epipolar segment in the left image, radians from the x (column) axis
    towards +y (rows)."""
    return np.arctan2(end[:, 1] - start[:, 1], end[:, 0] - start[:, 0])


def epipolar_grids(
    left: AbstractSensorModel,
    right: AbstractSensorModel,
    window: tuple[float, float, int, int],
    elevation: Elevation = 0.0,
    epi_step: int = 30,
    elevation_offset_m: float = 50.0,
) -> EpipolarGrids:
    """Epipolar rectification grids of the left image ``window = (col_off, row_off, width,
    height)`` (pixels of ``left``'s model; the whole image is ``(0, 0, W, H)``).

    ``elevation``: the reference surface, a constant ellipsoidal height (m) or a DEM function
    ``(lon, lat) -> h`` (ellipsoidal). The epipolar image size, grid size and node placement
    follow shareloc/OTB exactly (same 612 x 612 image and 22 x 22 grid on the Ventoux pair).
    """
    col_off, row_off, width, height = window
    if width <= 0 or height <= 0 or epi_step <= 0 or elevation_offset_m <= 0:
        raise ValueError(
            f"epipolar_grids: window {window}, epi_step {epi_step} and elevation_offset_m "
            f"{elevation_offset_m} must be positive"
        )
    pair = _Pair(left, right, elevation)
    dh = float(elevation_offset_m)
    # start at the centre of the window's first pixel: shareloc's "origin" is the geotransform
    # applied to pixel index (0, 0) plus half a pixel, i.e. that centre (checked against the
    # first epipolar point asserted by shareloc on the Ventoux pair, 1e-5 px)
    corner = np.array([[col_off, row_off]], dtype=float)
    start, end, _ = _epipolar_segment(pair, corner, dh)
    if not np.all(np.isfinite(start)) or not np.all(np.isfinite(end)):
        raise ValueError("epipolar_grids: the models do not localise the window's corner")
    alpha = float(_angle(start, end)[0])
    ca, sa = np.cos(alpha), np.sin(alpha)
    # bounding box of the window in the epipolar frame (x along the epipolar line), as OTB
    xs = [0.0, ca * width, sa * height, ca * width + sa * height]
    ys = [0.0, -sa * width, ca * height, -sa * width + ca * height]
    minx, maxx, miny, maxy = min(xs), max(xs), min(ys), max(ys)
    epi_shape = (int(maxy - miny), int(maxx - minx))
    grid_shape = (int(epi_shape[0] / epi_step + 2), int(epi_shape[1] / epi_step + 2))
    first = corner[0] + np.array([ca * minx - sa * miny, sa * minx + ca * miny])

    rows, cols = grid_shape
    left_grid = np.zeros((rows, cols, 2))
    alphas = np.zeros((rows, cols))
    heights = np.zeros((rows, cols))
    ratios = np.zeros((rows, cols))
    # first column: walk perpendicular to the local epipolar direction
    point = first[None, :]
    for i in range(rows):
        if i > 0:
            a = alphas[i - 1, :1]
            point = point + epi_step * np.stack([-np.sin(a), np.cos(a)], axis=-1)
        s, e, h = _epipolar_segment(pair, point, dh)
        left_grid[i, 0], alphas[i, 0], heights[i, 0] = point[0], _angle(s, e)[0], h[0]
        ratios[i, 0] = np.hypot(*(e - s)[0]) / (2 * dh)
    # every row: walk along the local epipolar direction, all rows at once
    point = left_grid[:, 0]
    for j in range(1, cols):
        a = alphas[:, j - 1]
        point = point + epi_step * np.stack([np.cos(a), np.sin(a)], axis=-1)
        s, e, h = _epipolar_segment(pair, point, dh)
        left_grid[:, j], alphas[:, j], heights[:, j] = point, _angle(s, e), h
        ratios[:, j] = np.hypot(*(e - s).T) / (2 * dh)
    flat = left_grid.reshape(-1, 2)
    right_grid = pair.coloc(left, right, flat, heights.reshape(-1)).reshape(rows, cols, 2)
    if not np.all(np.isfinite(right_grid)):
        raise ValueError("epipolar_grids: some grid nodes do not localise / project (NaN)")
    return EpipolarGrids(
        left=left_grid,
        right=right_grid,
        step_px=float(epi_step),
        epipolar_shape=epi_shape,
        mean_baseline_ratio=float(np.mean(ratios)),
        heights_m=heights,
    )
