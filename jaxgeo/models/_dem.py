"""DEM-aware localisation: the first intersection of a line of sight with a height grid.

    grid = DEMGrid(heights_m, origin, step)               # or jaxgeo.io.read_dem(...).grid(...)
    ground, status = localize_on_dem(model, image_xy, grid)

:class:`DEMGrid` is the array-level DEM the models layer works with: ellipsoidal WGS84 heights
(m) on a north-up grid in geographic ``(lon_deg, lat_deg)`` or a WGS84 UTM zone, NaN for nodata,
bilinear between cell centres. Reading files, other CRSs and geoids happen on the host in
:mod:`jaxgeo.io._dem`.

:func:`localize_on_dem` works for any :class:`~jaxgeo.models.AbstractSensorModel` through its
``localize``: it marches down the line of sight from above the DEM's highest cell to below its
lowest, in height steps that move the ray at most half a DEM cell horizontally (so no ridge is
jumped over), stops at the first sign change of ``h - dem(lon, lat)`` (the first intersection
seen from the sensor: hidden terrain is never returned), and refines by Illinois regula falsi.
Gradients (with respect to the model, the image point and the DEM heights) follow from the
implicit function theorem at the converged point. That march is the robust search; each point is
first searched by a fast one (:mod:`._dem_fast`: the same march on a quadratic through three
localisations of the line of sight, DEM look-ups alone), which leaves to the robust search only
the points it cannot decide beyond doubt.
"""

from __future__ import annotations

import abc
import enum

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from .._runtime.arrays import device_array
from ..geodesy import geodetic_to_utm
from ._base import AbstractSensorModel
from ._rpc_eval import is_concrete

__all__ = ["AbstractDEM", "DEMGrid", "DEMStatus", "localize_on_dem"]

DEM_HEIGHT_SPAN_M = 1000.0
"""Heights searched, +- about the reference height, for the DEM window of a model without an
RPC (:func:`localize_on_dem` given a host-side DEM)."""


class AbstractDEM(abc.ABC):
    """A host-side DEM (e.g. :class:`jaxgeo.io.DEM`, what :func:`jaxgeo.io.read_dem` returns):
    anything that gives a :class:`DEMGrid` over an area."""

    @abc.abstractmethod
    def grid(self, bounds_lonlat, margin_cells: int = 2) -> DEMGrid:
        """The DEM over ``(lon_min, lat_min, lon_max, lat_max)`` (degrees) as a :class:`DEMGrid`
        (ellipsoidal heights, NaN on nodata); raises ``ValueError`` if it does not cover it."""


class DEMStatus(enum.IntEnum):
    """Per-point outcome of :func:`localize_on_dem` (the ground point is NaN unless ``OK``)."""

    OK = 0
    OUTSIDE = 1  # the line of sight never meets the DEM inside its extent
    NODATA = 2  # the ray crossed nodata cells before (or at) the intersection
    NOT_CONVERGED = 3  # the refinement or the model's localisation failed
    BAD_INPUT = 4  # non-finite image coordinates


class DEMGrid(eqx.Module):
    """A north-up height grid: ``heights_m[row, col]`` ellipsoidal WGS84 metres, NaN = nodata.

    Cell ``(row, col)`` has its centre at grid coordinates ``origin + (col, row) * step``; grid
    coordinates are ``(lon_deg, lat_deg)`` when ``utm_zone == 0``, else ``(easting_m,
    northing_m)`` in WGS84 UTM zone ``|utm_zone|`` (negative: southern hemisphere). Heights are
    bilinear between cell centres; a point in the outer half cell holds the edge value, a point
    beyond that is outside (NaN).
    """

    heights_m: Float[Array, "rows cols"]
    origin: Float[Array, "2"]
    step: Float[Array, "2"]
    utm_zone: int = eqx.field(static=True, default=0)

    def __init__(
        self,
        heights_m: Float[ArrayLike, "rows cols"],
        origin: Float[ArrayLike, "2"],
        step: Float[ArrayLike, "2"],
        utm_zone: int = 0,
    ):
        # copied to the device, not converted by jax: a float32 grid (a DEM as read) made an
        # eager program, lowered and compiled (or read from the cache) in every process
        self.heights_m = device_array(heights_m, float)
        self.origin = device_array(origin, float)
        self.step = device_array(step, float)
        self.utm_zone = int(utm_zone)

    def __check_init__(self):
        if self.heights_m.ndim != 2 or min(self.heights_m.shape) < 2:
            raise ValueError(f"DEMGrid.heights_m must be 2-D, at least 2x2; got "
                             f"{self.heights_m.shape}")  # fmt: skip
        if self.origin.shape != (2,) or self.step.shape != (2,):
            raise ValueError("DEMGrid.origin and DEMGrid.step must have shape (2,)")
        if not 0 <= abs(self.utm_zone) <= 60:
            raise ValueError(f"DEMGrid.utm_zone must be in -60..60, got {self.utm_zone}")

    def pixel(self, lonlat: Float[ArrayLike, "*batch 2"]) -> Float[Array, "*batch 2"]:
        """WGS84 ``(lon_deg, lat_deg)`` -> fractional ``(col, row)``, integer at cell centres."""
        lonlat = jnp.asarray(lonlat, dtype=float)
        if self.utm_zone == 0:
            xy = lonlat
        else:
            g = jnp.concatenate([lonlat, jnp.zeros_like(lonlat[..., :1])], axis=-1)
            xy = geodetic_to_utm(g, abs(self.utm_zone), self.utm_zone > 0)[..., :2]
        return (xy - self.origin) / self.step

    def height(self, lonlat: Float[ArrayLike, "*batch 2"]) -> Float[Array, "*batch"]:
        """Bilinear ellipsoidal height (m) at ``(lon_deg, lat_deg)``; NaN outside or on nodata."""
        return self.height_at_pixel(self.pixel(lonlat))

    def height_at_pixel(self, colrow: Float[ArrayLike, "*batch 2"]) -> Float[Array, "*batch"]:
        """Bilinear height at fractional ``(col, row)`` (cell centres integer); NaN outside."""
        colrow = jnp.asarray(colrow, dtype=float)
        rows, cols = self.heights_m.shape
        c, r = colrow[..., 0], colrow[..., 1]
        inside = (c >= -0.5) & (c <= cols - 0.5) & (r >= -0.5) & (r <= rows - 0.5)
        # double-where: keep NaN inputs out of the arithmetic so gradients stay finite
        c = jnp.clip(jnp.where(inside, c, 0.0), 0.0, cols - 1.0)
        r = jnp.clip(jnp.where(inside, r, 0.0), 0.0, rows - 1.0)
        c0 = jnp.minimum(jnp.floor(c), cols - 2).astype(int)
        r0 = jnp.minimum(jnp.floor(r), rows - 2).astype(int)
        tc, tr = c - c0, r - r0
        z = self.heights_m
        h = (1 - tr) * ((1 - tc) * z[r0, c0] + tc * z[r0, c0 + 1]) + tr * (
            (1 - tc) * z[r0 + 1, c0] + tc * z[r0 + 1, c0 + 1]
        )
        return jnp.where(inside, h, jnp.nan)

    def contains(self, lonlat: Float[ArrayLike, "*batch 2"]) -> Array:
        """True where ``(lon_deg, lat_deg)`` lies inside the grid's extent (nodata or not)."""
        colrow = self.pixel(lonlat)
        rows, cols = self.heights_m.shape
        c, r = colrow[..., 0], colrow[..., 1]
        return (c >= -0.5) & (c <= cols - 0.5) & (r >= -0.5) & (r <= rows - 0.5)

    def height_range(self) -> Float[Array, "2"]:
        """``(min, max)`` height (m) over the valid cells."""
        return jnp.stack([jnp.nanmin(self.heights_m), jnp.nanmax(self.heights_m)])


def _stop(tree):
    dynamic, static = eqx.partition(tree, eqx.is_inexact_array)
    return eqx.combine(jax.lax.stop_gradient(dynamic), static)


def _lonlat_at(model, xy, h, guess):
    return model.localize(xy, h, guess=guess)[:2]


def _residual(model, dem, xy, h, guess):
    """``h - dem(lon, lat)`` on the line of sight at height ``h``, and the ``(lon, lat)``."""
    ll = _lonlat_at(model, xy, h, guess)
    return h - dem.height(ll), ll


def _search_one(model, xy, dem, max_steps, max_refine, h_tol):
    """Non-differentiable search: converged height, its (lon, lat) and the status."""
    lo_hi = dem.height_range()
    h_top, h_bottom = lo_hi[1] + 1.0, lo_hi[0] - 1.0
    ref = model.reference_ground()[:2]
    ll_top = _lonlat_at(model, xy, h_top, ref)
    ll_bottom = _lonlat_at(model, xy, h_bottom, ll_top)
    travel_px = jnp.max(jnp.abs(dem.pixel(ll_top) - dem.pixel(ll_bottom)))
    # each step moves the ray at most half a cell horizontally: no ridge is stepped over
    n = jnp.clip(jnp.ceil(travel_px / 0.5), 1, max_steps)
    n = jnp.where(jnp.isfinite(n), n, max_steps)
    dh = (h_top - h_bottom) / n
    f_top = h_top - dem.height(ll_top)

    # march: state (k, h, f, ll, crossed, saw_nodata)
    def march_cond(s):
        k, _, _, _, crossed, _, _, _ = s
        return (k < n) & ~crossed

    def march_body(s):
        k, h_prev, f_prev, ll_prev, _, nodata, _, _ = s
        h = h_top - (k + 1) * dh
        f, ll = _residual(model, dem, xy, h, ll_prev)
        valid = jnp.isfinite(f)
        inside = dem.contains(ll)
        crossed = valid & (f <= 0.0)
        nodata = nodata | (inside & ~valid & jnp.all(jnp.isfinite(ll)))
        # a non-finite ll (localisation failed) keeps the last good guess
        ll_keep = jnp.where(jnp.all(jnp.isfinite(ll)), ll, ll_prev)
        # on crossing, carry the bracket's upper end (h_prev, f_prev) in the last two slots
        return k + 1, h, f, ll_keep, crossed, nodata, h_prev, f_prev

    init = (
        jnp.asarray(0.0),
        h_top,
        f_top,
        ll_top,
        jnp.asarray(False),
        jnp.asarray(False),
        h_top,
        f_top,
    )
    _, h_a, f_a, ll_a, crossed, nodata, h_b, f_b = jax.lax.while_loop(march_cond, march_body, init)
    # bracket: f(h_a) <= 0 < f(h_b) (or f_b NaN: the ray entered the DEM between the two)
    f_b = jnp.where(jnp.isfinite(f_b), f_b, h_b - h_a)

    def refine_cond(s):
        k, h_a, _, h_b, _, _, _ = s
        return (k < max_refine) & (h_b - h_a > h_tol)

    def refine_body(s):
        k, h_a, f_a, h_b, f_b, ll, side = s
        h = jnp.where(f_b - f_a > 0, (h_a * f_b - h_b * f_a) / (f_b - f_a), 0.5 * (h_a + h_b))
        # keep the secant point away from the ends: guaranteed shrinking
        width = h_b - h_a
        h = jnp.clip(h, h_a + 1e-3 * width, h_b - 1e-3 * width)
        f, ll_new = _residual(model, dem, xy, h, ll)
        f = jnp.where(jnp.isfinite(f), f, 0.0)  # treat a nodata probe as a hit (conservative)
        below = f <= 0.0
        # Illinois: halve the function value of the end that stays twice in a row
        f_b_new = jnp.where(below, jnp.where(side == 1, 0.5 * f_b, f_b), f)
        f_a_new = jnp.where(below, f, jnp.where(side == -1, 0.5 * f_a, f_a))
        h_a_new = jnp.where(below, h, h_a)
        h_b_new = jnp.where(below, h_b, h)
        side_new = jnp.where(below, 1, -1).astype(side.dtype)
        ll_keep = jnp.where(jnp.all(jnp.isfinite(ll_new)), ll_new, ll)
        return k + 1, h_a_new, f_a_new, h_b_new, f_b_new, ll_keep, side_new

    k, h_a, f_a, h_b, f_b, ll, _ = jax.lax.while_loop(
        refine_cond, refine_body, (jnp.asarray(0), h_a, f_a, h_b, f_b, ll_a, jnp.asarray(0))
    )
    h_root = jnp.where(f_b - f_a > 0, (h_a * f_b - h_b * f_a) / (f_b - f_a), h_a)
    converged = h_b - h_a <= h_tol
    status = jnp.where(
        ~crossed,
        jnp.where(nodata, DEMStatus.NODATA, DEMStatus.OUTSIDE),
        jnp.where(
            nodata, DEMStatus.NODATA, jnp.where(converged, DEMStatus.OK, DEMStatus.NOT_CONVERGED)
        ),
    )
    ok_ll = jnp.all(jnp.isfinite(ll_top)) & jnp.all(jnp.isfinite(ll_bottom))
    status = jnp.where(ok_ll | crossed, status, DEMStatus.NOT_CONVERGED)
    return h_root, ll, status.astype(int)


def _localize_one(model, xy, dem, max_steps, max_refine, h_tol):
    bad = ~jnp.all(jnp.isfinite(xy))
    ref_xy = jax.lax.stop_gradient(model.project(model.reference_ground()))
    xy_safe = jnp.where(bad, ref_xy, xy)
    h_star, ll_star, status = _search_one(
        _stop(model), jax.lax.stop_gradient(xy_safe), _stop(dem), max_steps, max_refine, h_tol
    )
    status = jnp.where(bad, DEMStatus.BAD_INPUT, status)
    ok = status == DEMStatus.OK
    h_star = jnp.where(ok, h_star, jax.lax.stop_gradient(model.reference_ground()[2]))
    ll_star = jnp.where(ok, ll_star, jax.lax.stop_gradient(model.reference_ground()[:2]))

    # implicit function theorem: one Newton step at the root carries the exact first derivative
    # dh/dtheta = -(dF/dtheta) / F'(h*) (and polishes the value)
    def f(h):
        return _residual(model, dem, xy_safe, h, ll_star)[0]

    f_val, f_slope = jax.jvp(f, (h_star,), (jnp.ones_like(h_star),))
    f_slope = jax.lax.stop_gradient(f_slope)
    safe_slope = jnp.where(ok & (jnp.abs(f_slope) > 1e-12), f_slope, 1.0)
    step = jnp.where(ok, f_val / safe_slope, 0.0)
    h = h_star - step
    ll = _lonlat_at(model, xy_safe, h, ll_star)
    ground = jnp.concatenate([ll, h[None]])
    return jnp.where(ok, ground, jnp.nan), status


def localize_on_dem(
    model: AbstractSensorModel,
    image: Float[ArrayLike, "*batch 2"],
    dem: DEMGrid | AbstractDEM,
    *,
    max_steps: int = 4096,
    max_refine: int = 100,
    h_tol_m: float = 1e-6,
) -> tuple[Float[Array | np.ndarray, "*batch 3"], Int[Array | np.ndarray, "*batch"]]:
    """Image ``(x, y)`` px -> ground ``(lon_deg, lat_deg, h_m)`` on the DEM, and a status.

    The ground point is the first intersection of the line of sight with the bilinear DEM seen
    from the sensor (occluded terrain behind it is never returned). ``status`` is a
    :class:`DEMStatus` per point; the ground point is NaN unless it is ``OK``. Works for every
    model through its ``localize``; jittable, vmapped over the batch, differentiable in the
    model, the image point and ``dem.heights_m``.

    ``dem`` is a :class:`DEMGrid`, or a host-side :class:`AbstractDEM` (what
    :func:`jaxgeo.io.read_dem` returns): then the grid is read over the area the points see
    between the heights of the model's RPC validity range (``h_off +- h_scale``; a model without
    an RPC: its reference height +- :data:`DEM_HEIGHT_SPAN_M`), on the host.

    Numpy in, numpy out: given numpy arrays or lists (no JAX array among the inputs, outside
    any transformation) it runs compiled programs kept across runs, over chunks of points, and
    returns ``numpy.ndarray`` s; a JAX array gives JAX arrays. Each point is first searched on a
    quadratic through three localisations of its line of sight (:mod:`._dem_fast`: the
    march and the regula falsi on DEM look-ups alone, then the same Newton step on the exact
    line of sight as the robust search); a point whose outcome that search cannot decide
    beyond doubt (a sample within :data:`FAST_GUARD_M` of the terrain before the intersection,
    near the DEM's edge or a nodata cell, a failed check of the result) is searched again by
    the robust search, which localises at every step: the same results, statuses included.

    Args:
        max_steps: cap on the number of march steps (each moves the ray <= half a DEM cell).
        max_refine: cap on the regula-falsi iterations; h_tol_m: bracket width (m) to stop at.
    """
    if isinstance(dem, AbstractDEM):
        dem = dem.grid(_footprint(model, np.asarray(image, dtype=float)))
    elif not isinstance(dem, DEMGrid):
        raise TypeError(
            f"dem must be a DEMGrid or a DEM from jaxgeo.io.read_dem, got {type(dem).__name__}"
        )
    from ._dem_fast import on_dem_concrete, on_dem_traced

    options = (int(max_steps), int(max_refine), float(h_tol_m))
    numpy_out = not isinstance(image, jax.Array)
    if is_concrete(model, dem, image):
        flat = np.asarray(image, dtype=float)
        if flat.shape[-1:] != (2,):
            raise ValueError(f"image coordinates must have a last axis of size 2, got {flat.shape}")
        batch = flat.shape[:-1]
        ground, status = on_dem_concrete(model, dem, options, flat.reshape(-1, 2))
        ground, status = ground.reshape(*batch, 3), status.reshape(batch)
        return (ground, status) if numpy_out else (jnp.asarray(ground), jnp.asarray(status))
    image = jnp.asarray(image, dtype=float)
    if image.shape[-1:] != (2,):
        raise ValueError(f"image coordinates must have a last axis of size 2, got {image.shape}")
    batch = image.shape[:-1]
    ground, status = on_dem_traced(model, dem, options, image.reshape(-1, 2))
    return ground.reshape(*batch, 3), status.reshape(batch)


def _footprint(model: AbstractSensorModel, image: np.ndarray) -> tuple[float, float, float, float]:
    """``(lon_min, lat_min, lon_max, lat_max)`` the lines of sight of ``image`` cross between
    the model's lowest and highest plausible heights (host-side)."""
    rpc = model.base_rpc()
    if rpc is not None:
        h0, hs = float(rpc.ground_offset[2]), float(rpc.ground_scale[2])
    else:
        h0, hs = float(model.reference_ground()[2]), DEM_HEIGHT_SPAN_M
    xy = np.asarray(image, dtype=float).reshape(-1, 2)
    xy = xy[np.all(np.isfinite(xy), axis=1)]
    if xy.size == 0:
        raise ValueError("no finite image point to localise on the DEM")
    lo, hi = xy.min(axis=0), xy.max(axis=0)  # the box's corners bound a smooth model's rays
    corners = np.array([[lo[0], lo[1]], [hi[0], lo[1]], [lo[0], hi[1]], [hi[0], hi[1]]])
    pts = np.concatenate([corners, xy[:: max(1, len(xy) // 64)]])
    ground = np.concatenate(
        [np.asarray(model.localize(pts, h)).reshape(-1, 3) for h in (h0 - hs, h0 + hs)]
    )
    ground = ground[np.all(np.isfinite(ground), axis=1)]
    if ground.size == 0:
        raise ValueError("the model cannot localise these image points (no DEM window)")
    lon, lat = ground[:, 0], ground[:, 1]
    return float(lon.min()), float(lat.min()), float(lon.max()), float(lat.max())
