"""Which ortho pixels are hidden from the sensor by terrain: a march in ground space.

An ortho pixel is the ground point ``P = (lon, lat, h)`` on the DEM whose image point is ``xy``.
Its line of sight goes from ``P`` up toward the sensor; over a DEM's height range (at most a few
kilometres against a sensor hundreds of kilometres away) it is a straight line in ``(lon, lat,
h)`` to far better than a DEM cell, so one localisation per pixel gives it:
``Q = model.localize(xy, h_top)`` at the DEM's top, and the ray is ``P + t (Q - P)``,
``t in (0, 1]``. The pixel is hidden when the ray passes below the DEM (bilinear heights)
somewhere more than ``thresh_m`` horizontally away from ``P``; the ray is sampled every half DEM
cell (the number of samples is the largest horizontal travel of the tile, in half cells, so no
ridge is stepped over). Cost: one localisation plus ``n`` bilinear look-ups per pixel, instead
of a per-step localisation of :func:`jaxgeo.models.localize_on_dem` (seconds, not minutes, on a
1 m DEM). The straight-line error is reported by :func:`los_curvature_m` in the tests.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from ..models import DEMGrid

_M_PER_DEG = 111_320.0


@functools.partial(jax.jit, static_argnames=("n_samples",))
def _hidden(dem: DEMGrid, p, q, thresh_m, n_samples: int):
    """``p``, ``q`` ``(n, 3)``: ray ends (DEM surface, DEM top). True where the ray dips below
    the DEM more than ``thresh_m`` (horizontally) from ``p``."""
    coslat = jnp.cos(jnp.radians(p[:, 1]))

    def body(k, hidden):
        t = (k + 1.0) / n_samples
        g = p + t * (q - p)
        dist = jnp.hypot((g[:, 0] - p[:, 0]) * coslat, g[:, 1] - p[:, 1]) * _M_PER_DEG
        below = g[:, 2] < dem.height(g[:, :2])  # NaN (outside / nodata): not below
        return hidden | (below & (dist > thresh_m))

    return jax.lax.fori_loop(0, n_samples, body, jnp.zeros(p.shape[0], dtype=bool))


@jax.jit
def _top_points(model, xy, lonlat, h_top):
    return model.localize(xy, jnp.full(xy.shape[:-1], h_top), guess=lonlat)


_CHUNK = 1 << 14  # padded batch: one compilation per run, whatever the tile's valid count


def occluded_pixels(
    model, dem: DEMGrid, xy: np.ndarray, lonlat: np.ndarray, h: np.ndarray, thresh_m: float
) -> np.ndarray:
    """Boolean ``(rows, cols)``: the pixels of a tile hidden from the sensor (module docstring).

    ``xy`` ``(rows, cols, 2)`` image points, ``lonlat`` ``(rows, cols, 2)`` and ``h`` the DEM
    ground points of the ortho pixels; non-finite entries are not hidden.
    """
    shape = h.shape
    ok = np.all(np.isfinite(xy), axis=-1) & np.all(np.isfinite(lonlat), axis=-1)
    ok &= np.isfinite(h)
    out = np.zeros(shape, dtype=bool)
    if not ok.any():
        return out
    h_top = float(np.asarray(dem.height_range())[1]) + 1.0
    p = np.concatenate([lonlat[ok], h[ok][:, None]], axis=-1)
    xy_ok = xy[ok]
    n = len(p)
    pad = (-n) % _CHUNK
    xy_pad = np.concatenate([xy_ok, np.repeat(xy_ok[:1], pad, axis=0)])
    ll_pad = np.concatenate([p[:, :2], np.repeat(p[:1, :2], pad, axis=0)])
    q = np.concatenate([
        np.asarray(_top_points(model, xy_pad[i : i + _CHUNK], ll_pad[i : i + _CHUNK], h_top))
        for i in range(0, n + pad, _CHUNK)
    ])[:n]  # fmt: skip
    # samples: the largest horizontal travel of the tile in half DEM cells (power of 2: few
    # distinct compilations)
    travel = np.abs(np.asarray(dem.pixel(q[:, :2])) - np.asarray(dem.pixel(p[:, :2])))
    travel = travel[np.all(np.isfinite(travel), axis=-1)]
    if travel.size == 0:
        return out
    n_samples = int(2 ** np.ceil(np.log2(max(2.0 * travel.max(), 2.0))))
    q = np.where(np.isfinite(q), q, p)
    p_pad = np.concatenate([p, np.repeat(p[:1], pad, axis=0)])
    q_pad = np.concatenate([q, np.repeat(p[:1], pad, axis=0)])  # zero-length rays: not hidden
    hidden = np.concatenate([
        np.asarray(_hidden(dem, jnp.asarray(p_pad[i : i + _CHUNK]),
                           jnp.asarray(q_pad[i : i + _CHUNK]), thresh_m, n_samples))
        for i in range(0, n + pad, _CHUNK)
    ])[:n]  # fmt: skip
    out[ok] = hidden
    return out


__all__ = ["occluded_pixels"]
