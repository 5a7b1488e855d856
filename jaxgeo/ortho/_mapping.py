"""Inverse mapping of an output tile: ground cell -> DEM height -> image ``(x, y)``.

Exact projection of every output pixel is what the orthoimage needs; this module gets it at
the cost of one projection per ``step x step`` block. On a coarse grid of nodes it projects the
ground point on the DEM and the derivative ``dP/dh``; a pixel's image position is the bilinear
interpolation of the nodes plus ``dP/dh * (h_pixel - h_interpolated)``, which follows the DEM's
own (bilinear, kinked) surface exactly to first order. The result is checked against a full
projection at the centre of every block; blocks whose error exceeds the tolerance are
projected in full, pixel by pixel (:func:`refine`).

Image coordinates are jaxgeo's: ``(x, y) = (col, row)``, integer at pixel centres.
"""

from __future__ import annotations

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..models import AbstractSensorModel, DEMGrid


def _interp(v: Array, step: int, rows: int, cols: int) -> Array:
    """Bilinear interpolation of node values ``(nr, nc, k)`` to ``(rows, cols, k)`` pixels."""
    i = jnp.arange(rows)
    j = jnp.arange(cols)
    ri, fr = i // step, (i % step) / step
    cj, fc = j // step, (j % step) / step
    top = v[ri]  # (rows, nc, k)
    bot = v[ri + 1]
    col_v = top + fr[:, None, None] * (bot - top)
    left = col_v[:, cj]
    right = col_v[:, cj + 1]
    return left + fc[None, :, None] * (right - left)


def _project_with_slope(model, ground):
    def p(h):
        return model.project(jnp.concatenate([ground[:2], h[None]]))

    return jax.jvp(p, (ground[2],), (jnp.ones(()),))


@functools.partial(eqx.filter_jit)
def map_tile(
    model: AbstractSensorModel,
    dem: DEMGrid,
    node_lonlat: Float[Array, "nr nc 2"],
    step: int,
    rows: int,
    cols: int,
):
    """Image ``(x, y)`` of every pixel of a ``rows x cols`` tile from its node lon/lat grid.

    Node ``(a, b)`` sits on tile pixel ``(a * step, b * step)``; ``rows, cols`` are multiples
    of ``step`` and the grid has ``rows / step + 1`` by ``cols / step + 1`` nodes. Returns
    ``(xy (rows, cols, 2), lonlat (rows, cols, 2), h (rows, cols), block_error_px (nr-1,
    nc-1))``; the block error is the interpolation error at the block's centre pixel (NaN where
    the DEM has no height).
    """
    nr, nc = node_lonlat.shape[:2]
    h_nodes = dem.height(node_lonlat)
    g_nodes = jnp.concatenate([node_lonlat, h_nodes[..., None]], axis=-1).reshape(-1, 3)
    xy_nodes, slope_nodes = jax.vmap(lambda g: _project_with_slope(model, g))(g_nodes)
    packed = jnp.concatenate([xy_nodes, slope_nodes, h_nodes.reshape(-1, 1)], axis=-1).reshape(
        nr, nc, 5
    )
    lonlat = _interp(node_lonlat, step, rows, cols)
    h = dem.height(lonlat)
    inter = _interp(packed, step, rows, cols)
    xy = inter[..., :2] + inter[..., 2:4] * (h - inter[..., 4])[..., None]
    # check: full projection at each block's centre pixel
    c = step // 2
    ci = jnp.arange(nr - 1) * step + c
    cj = jnp.arange(nc - 1) * step + c
    ll_c = lonlat[ci][:, cj]
    g_c = jnp.concatenate([ll_c, h[ci][:, cj][..., None]], axis=-1)
    full = model.project(g_c)
    err = jnp.max(jnp.abs(full - xy[ci][:, cj]), axis=-1)
    return xy, lonlat, h, err


@eqx.filter_jit
def _project(model, ground):
    return model.project(ground)


def refine(model, xy, lonlat, h, block_error, step: int, tol_px: float):
    """Project in full the pixels of blocks whose error exceeds ``tol_px`` (numpy, in place).

    Returns ``(xy, refined_fraction, error_left_px)``: the largest block-centre error among
    the blocks left interpolated.
    """
    xy = np.array(xy)
    err = np.asarray(block_error)
    bad = err > tol_px
    left = err[~bad & np.isfinite(err)]
    error_left = float(left.max()) if left.size else 0.0
    if not bad.any():
        return xy, 0.0, error_left
    mask = np.repeat(np.repeat(bad, step, axis=0), step, axis=1)[: xy.shape[0], : xy.shape[1]]
    idx = np.flatnonzero(mask.ravel())
    ground = np.concatenate(
        [np.asarray(lonlat).reshape(-1, 2)[idx], np.asarray(h).reshape(-1, 1)[idx]], axis=1
    )
    # pad to a power of two: few distinct shapes, few compilations
    n = len(idx)
    size = 1 << max(int(np.ceil(np.log2(max(n, 1)))), 10)
    pad = np.zeros((size, 3))
    pad[:n] = ground
    pad[n:] = ground[0]
    out = np.asarray(_project(model, pad))[:n]
    flat = xy.reshape(-1, 2)
    flat[idx] = out
    return flat.reshape(xy.shape), float(bad.mean()), error_left
