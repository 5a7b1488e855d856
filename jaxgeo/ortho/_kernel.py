"""The per-tile kernels of the orthoimage: image positions of every output pixel, then sampling.

:func:`map_pixels` does what :func:`jaxgeo.ortho._mapping.map_tile` does (projection on a coarse
grid of nodes, bilinear interpolation, first-order height correction ``dP/dh * (h_pixel -
h_interpolated)`` on the DEM's own surface, a full projection at every block's centre to check),
but faster: the per-pixel work is a few multiply-adds in ``dtype`` on values relative to the
tile (the image window's corner, the DEM window's first cell, the tile's mean height), float32
for integer images (2e-4 px at 2 000 px from the corner: far below the 0.01 px tolerance the
check enforces) and float64 for float64 images; only the node projections and the checks are
float64. Interpolating DEM pixel coordinates instead of lon/lat keeps every map projection off
the per-pixel path.

:func:`sample_window` resamples an image window at those positions (nearest, bilinear, cubic
Keys a = -0.5 like GDAL's) and converts to the output type (rounded and clipped for integers),
nodata where a position falls outside the image.

Both are kept programs (:func:`jaxgeo._runtime.kept.kept_kernel`): one per tile shape, traced
once across runs, so that a second ``jaxgeo ortho`` loads them instead of tracing them.

Coordinates: image ``(x, y) = (col, row)`` with integers at pixel centres (jaxgeo's convention).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .._runtime.kept import kept_kernel
from ..models import AbstractSensorModel, DEMGrid

RESAMPLINGS = ("nearest", "bilinear", "cubic")


def _project_with_slope(model, ground):
    def p(h):
        return model.project(jnp.concatenate([ground[:2], h[None]]))

    return jax.jvp(p, (ground[2],), (jnp.ones(()),))


def _interp(v, step: int):
    """Bilinear interpolation of node values ``(k, nr, nc)`` onto ``(k, (nr-1) step, (nc-1)
    step)`` pixels (node ``(a, b)`` on pixel ``(a step, b step)``), separably."""
    k, nr, nc = v.shape
    f = (jnp.arange(step) / step).astype(v.dtype)
    a = v[:, :, :-1, None] + f * (v[:, :, 1:, None] - v[:, :, :-1, None])
    a = a.reshape(k, nr, (nc - 1) * step)
    b = a[:, :-1, None, :] + f[:, None] * (a[:, 1:, None, :] - a[:, :-1, None, :])
    return b.reshape(k, (nr - 1) * step, (nc - 1) * step)


def _bilinear(z, c, r):
    """``z`` ``(rows, cols)`` at fractional ``(c, r)`` (cell centres integer), as
    :meth:`DEMGrid.height_at_pixel`: held in the outer half cell, NaN beyond. The four corners
    of every cell are gathered as one 4-vector (3x faster on a CPU than four gathers)."""
    rows, cols = z.shape
    inside = (c >= -0.5) & (c <= cols - 0.5) & (r >= -0.5) & (r <= rows - 0.5)
    c = jnp.clip(jnp.where(inside, c, 0), 0, cols - 1)
    r = jnp.clip(jnp.where(inside, r, 0), 0, rows - 1)
    c0 = jnp.minimum(jnp.floor(c), cols - 2)
    r0 = jnp.minimum(jnp.floor(r), rows - 2)
    tc, tr = c - c0, r - r0
    corners = jnp.stack([z[:-1, :-1], z[:-1, 1:], z[1:, :-1], z[1:, 1:]], axis=-1)
    q = corners.reshape(-1, 4)[(r0 * (cols - 1) + c0).astype(jnp.int32)]
    top = q[..., 0] + tc * (q[..., 1] - q[..., 0])
    bottom = q[..., 2] + tc * (q[..., 3] - q[..., 2])
    return jnp.where(inside, top + tr * (bottom - top), jnp.nan)


@kept_kernel
def map_pixels(model: AbstractSensorModel, dem: DEMGrid, nodes_lonlat, step: int, dtype: str):
    """Image positions of a tile's pixels, their range, and the check error of every block.

    ``nodes_lonlat`` ``(nr, nc, 2)``: WGS84 lon/lat of nodes every ``step`` pixels (node
    ``(a, b)`` on tile pixel ``(a step, b step)``). Returns ``xy`` ``(2, (nr-1) step, (nc-1)
    step)`` in ``dtype``, relative to ``ref`` ``(2,)`` (float64, integer: the nodes' smallest
    image position, rounded down; 0 when no node projects), ``lo``, ``hi`` ``(2,)``: bounds of
    the finite ``xy`` (NaN when none), and ``block_error_px`` ``(nr-1, nc-1)`` float64: the
    difference between a full projection and the interpolated position at each block's centre
    pixel (NaN where the DEM has no height).
    """
    dt = jnp.dtype(dtype)
    nr, nc = nodes_lonlat.shape[:2]
    h_nodes = dem.height(nodes_lonlat)
    ground = jnp.concatenate([nodes_lonlat, h_nodes[..., None]], axis=-1).reshape(-1, 3)
    xy_n, slope_n = jax.vmap(lambda g: _project_with_slope(model, g))(ground)
    ref = jnp.nan_to_num(jnp.floor(jnp.nanmin(xy_n, axis=0)))
    px_n = dem.pixel(nodes_lonlat)
    ref_px = jnp.nan_to_num(jnp.floor(jnp.nanmin(px_n.reshape(-1, 2), axis=0)))
    h_ref = jnp.nan_to_num(jnp.nanmean(h_nodes))
    rel = jnp.concatenate(
        [(px_n - ref_px).reshape(-1, 2), xy_n - ref, slope_n, (h_nodes - h_ref).reshape(-1, 1)],
        axis=-1,
    )
    inter = _interp(jnp.moveaxis(rel.reshape(nr, nc, 7).astype(dt), -1, 0), step)
    # the DEM window shifted instead of the points: heights relative to h_ref, in dtype
    z = (dem.heights_m - h_ref).astype(dt)
    h = _bilinear(z, inter[0] + ref_px[0].astype(dt), inter[1] + ref_px[1].astype(dt))
    dh = h - inter[6]
    xy = jnp.stack([inter[2] + inter[4] * dh, inter[3] + inter[5] * dh])
    # their range: the nodes' (a bilinear value lies between its nodes') widened by the largest
    # height correction the DEM window's relief allows (a reduction over every pixel breaks
    # XLA's fusion: measured 30 ms of a 60 ms tile)
    relief = jnp.nanmax(dem.heights_m) - jnp.nanmin(dem.heights_m)
    pad = jnp.nanmax(jnp.abs(slope_n)) * (relief + 1.0)
    lo, hi = jnp.nanmin(xy_n - ref, axis=0) - pad, jnp.nanmax(xy_n - ref, axis=0) + pad
    # check: a full float64 projection at each block's centre pixel (step is even: the centre
    # pixel is the block's centre, the mean of its four nodes)
    c = step // 2
    ll_c = 0.25 * (nodes_lonlat[:-1, :-1] + nodes_lonlat[1:, :-1] + nodes_lonlat[:-1, 1:]
                   + nodes_lonlat[1:, 1:])  # fmt: skip
    g_c = jnp.concatenate([ll_c, dem.height(ll_c)[..., None]], axis=-1)
    full = model.project(g_c) - ref
    at_c = xy[:, c::step, c::step].astype(float)
    err = jnp.max(jnp.abs(full - jnp.moveaxis(at_c, 0, -1)), axis=-1)
    return xy, ref, lo, hi, err


def _keys(t):
    """Cubic convolution weights (a = -0.5, GDAL's ``cubic``) of the taps at -1, 0, 1, 2."""
    a = -0.5

    def w(d):
        d = jnp.abs(d)
        near = ((a + 2) * d - (a + 3)) * d * d + 1
        far = ((a * d - 5 * a) * d + 8 * a) * d - 4 * a
        return jnp.where(d <= 1, near, jnp.where(d < 2, far, 0))

    return [w(t + 1), w(t), w(1 - t), w(2 - t)]


@kept_kernel
def sample_window(window, xy, offset, size, image_box, nodata, method: str, out_dtype: str):
    """Resample ``window`` ``(bands, WH, WW)`` at positions ``xy - offset`` (``xy`` ``(2, rows,
    cols)``, ``offset`` ``(2,)`` integer: the window's first pixel in ``xy``'s frame; the
    subtraction is exact in float32 for positions below 2^23).

    ``size`` ``(w, h)``: the window's real size (the array may be padded beyond it);
    ``image_box`` ``(x0, y0, x1, y1)``: the image's pixel area in window coordinates (a position
    outside it is nodata; one in its outer half pixel holds the edge pixel). Returns
    ``(values (bands, rows, cols) out_dtype, valid (rows, cols), missed)``: ``missed`` counts
    the positions inside the image but outside the window (a window read too small: 0).
    """
    bands, wh, ww = window.shape
    dt = xy.dtype
    x, y = xy[0] - offset[0].astype(dt), xy[1] - offset[1].astype(dt)
    x0, y0, x1, y1 = (image_box[i].astype(dt) for i in range(4))
    in_image = jnp.isfinite(x) & jnp.isfinite(y) & (x >= x0) & (x <= x1) & (y >= y0) & (y <= y1)
    w_real, h_real = size[0].astype(dt), size[1].astype(dt)
    in_window = (x >= -0.5) & (x <= w_real - 0.5) & (y >= -0.5) & (y <= h_real - 0.5)
    valid = in_image & in_window
    missed = jnp.sum(in_image & ~in_window)
    xs = jnp.clip(jnp.where(valid, x, 0), 0, w_real - 1)
    ys = jnp.clip(jnp.where(valid, y, 0), 0, h_real - 1)
    src = window.reshape(bands, -1)
    last_c, last_r = size[0] - 1, size[1] - 1

    def tap(r, c):
        r = jnp.clip(r, 0, last_r)
        c = jnp.clip(c, 0, last_c)
        return src[:, (r * ww + c).astype(jnp.int32)].astype(dt)

    if method == "nearest":
        out = tap(jnp.floor(ys + 0.5).astype(jnp.int32), jnp.floor(xs + 0.5).astype(jnp.int32))
    elif method == "bilinear":  # one index, four offsets (the last cell for the edge)
        c0 = jnp.clip(jnp.floor(xs), 0, jnp.maximum(w_real - 2, 0))
        r0 = jnp.clip(jnp.floor(ys), 0, jnp.maximum(h_real - 2, 0))
        tc, tr = xs - c0, ys - r0
        i = (r0 * ww + c0).astype(jnp.int32)
        a, b, d, e = (src[:, i + k].astype(dt) for k in (0, 1, ww, ww + 1))
        top = a + tc * (b - a)
        bottom = d + tc * (e - d)
        out = top + tr * (bottom - top)
    elif method == "cubic":
        c0, r0 = jnp.floor(xs), jnp.floor(ys)
        wc, wr = _keys(xs - c0), _keys(ys - r0)
        c0, r0 = c0.astype(jnp.int32), r0.astype(jnp.int32)
        out = 0
        for i in range(4):
            row = sum(wc[j] * tap(r0 + i - 1, c0 + j - 1) for j in range(4))
            out = out + wr[i] * row
    else:
        raise ValueError(f"unknown resampling {method!r}")
    odt = np.dtype(out_dtype)
    if np.issubdtype(odt, np.integer):
        info = np.iinfo(odt)
        out = jnp.clip(jnp.round(out), info.min, info.max)
    out = jnp.where(valid, out, jnp.asarray(nodata, dt))
    return out.astype(odt), valid, missed
