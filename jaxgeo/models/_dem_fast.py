"""The fast search of :func:`~jaxgeo.models.localize_on_dem`, and its dispatch: numpy points
over kept programs (the fast search, then the robust one for the points it leaves), or one
program under a transformation.

The robust search (:func:`._dem._search_one`) localises the image point at every march step
and regula-falsi probe: 14.8x the time of a ``localize`` at a constant height for 1e5 points
(Pleiades RPC, hills on an 80 m grid, a loaded 2-core AMD EPYC). Over a DEM's height range a
line of sight is a quadratic in ``h`` to within a fraction of a millimetre, so the fast search
localises three times (the DEM's top, bottom and middle), runs the same march and a Newton
iteration on DEM look-ups alone, array-wide, and polishes the root by the robust search's own
Newton step on the exact line of sight (one more localisation): 5.2x a ``localize`` in the
same run, the same statuses and ground points within 1e-13 deg and 1e-9 m. A point whose
outcome it cannot decide beyond doubt goes to the robust search, which gives every such point
its own result (0.02-0.05 % of those points; ``benchmarks/speed/localize_dem.py``).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .._runtime.kept import kept_points
from ._dem import DEMStatus, _localize_one, _stop

FAST_CHUNKS = (2048, 1 << 14)
"""Points per compiled call of the fast search on concrete inputs
(:func:`jaxgeo._runtime.kept.kept_points`): 2 048 below 16 384 points, 16 384 from there on
(1e5 points padded to 114 688, 15 %); at most two programs per model type and DEM shape."""
ROBUST_CHUNK = 256
"""Points per compiled call of the robust search on the points the fast one leaves to it
(few, as a rule: one program per model type and DEM shape)."""
FAST_GUARD_M = 0.01
"""m: a march sample of the fast search closer than this to the terrain (``|h - dem|``), up to
the first crossing, leaves the point to the robust search: its quadratic line of sight is off
the exact one by at most 0.25 mm over a 4 100 m DEM range (the Pleiades RPC and a simulated
Cartosat-1 model, measured), i.e. a sign decided beyond doubt on slopes up to 40."""
FAST_GUARD_PX = 1e-3
"""DEM cells: a march sample this close to the DEM's edge (or, on a DEM with nodata, to a cell
line) leaves the point to the robust search (inside/outside, nodata or not, beyond doubt)."""
FAST_STEP_MAX_M = 1e-3
"""m: the final Newton step (on the exact line of sight) of an accepted fast point is at most
this; a larger one means the quadratic was not close enough: the robust search decides."""


def _bilinear(z, p, dp):
    """The bilinear height of :meth:`DEMGrid.height_at_pixel` at pixels ``p`` (n, 2), its
    derivative along ``dp`` (n, 2), and whether inside the extent: the four heights of a cell
    from one gather of a 2 x 2 window (one gather instead of four: XLA's CPU fusion repeats a
    gather's arithmetic in each of its consumers)."""
    rows, cols = z.shape
    c, r = p[:, 0], p[:, 1]
    inside = (c >= -0.5) & (c <= cols - 0.5) & (r >= -0.5) & (r <= rows - 0.5)
    c = jnp.clip(jnp.where(inside, c, 0.0), 0.0, cols - 1.0)
    r = jnp.clip(jnp.where(inside, r, 0.0), 0.0, rows - 1.0)
    c0 = jnp.minimum(jnp.floor(c), cols - 2)
    r0 = jnp.minimum(jnp.floor(r), rows - 2)
    tc, tr = c - c0, r - r0
    cell = jax.vmap(lambda i, j: jax.lax.dynamic_slice(z, (i, j), (2, 2)))(
        r0.astype(int), c0.astype(int)
    )
    z00, z01, z10, z11 = cell[:, 0, 0], cell[:, 0, 1], cell[:, 1, 0], cell[:, 1, 1]
    h = (1 - tr) * ((1 - tc) * z00 + tc * z01) + tr * ((1 - tc) * z10 + tc * z11)
    dh_dc = (1 - tr) * (z01 - z00) + tr * (z11 - z10)
    dh_dr = (1 - tc) * (z10 - z00) + tc * (z11 - z01)
    slope = dh_dc * dp[:, 0] + dh_dr * dp[:, 1]
    return jnp.where(inside, h, jnp.nan), slope, inside


def _fast_search(model, dem, options, xy):
    """The fast search over flat points ``(n, 2)``: ``(ground (n, 3), status (n,), robust
    (n,) bool)``, the points flagged ``robust`` to be searched again by :func:`_localize_one`.

    The robust search (:func:`._dem._search_one`) localises at every march step and
    regula-falsi probe. Over a DEM's height range a line of sight is a quadratic in ``h`` to
    within a fraction of a millimetre (:data:`FAST_GUARD_M`), so here three localisations (the
    DEM's top and bottom, as the robust search, and their middle) give it, in DEM pixels; the
    same march (the same heights, the same flags) and a Newton iteration kept in the march's
    bracket run on DEM look-ups alone, array-wide; the root is then polished by the robust
    search's own Newton step on the exact line of sight, whose value carries the implicit
    derivatives (its slope, and the line's direction over the step, are the quadratic's:
    derivatives exact up to the quadratic's error). A point is flagged when a
    decision of the march could differ on the exact line of sight, when the Newton iteration
    did not converge, or when the last step or the residual after it is too large. Where the
    march's bracket holds several roots (a ray grazing the terrain within half a cell), the
    Newton iteration and the robust search's regula falsi may each stop on another one.
    """
    max_steps, max_refine, h_tol = options
    n = xy.shape[0]
    bad = ~jnp.all(jnp.isfinite(xy), axis=-1)
    ref = jax.lax.stop_gradient(model.reference_ground())
    ref_xy = jax.lax.stop_gradient(model.project(ref))
    xy_safe = jnp.where(bad[:, None], ref_xy, xy)
    m, d, xs = _stop(model), _stop(dem), jax.lax.stop_gradient(xy_safe)
    rows, cols = d.heights_m.shape
    has_nan = jnp.any(jnp.isnan(d.heights_m))

    lo_hi = d.height_range()
    h_top, h_bottom = lo_hi[1] + 1.0, lo_hi[0] - 1.0
    h_mid = 0.5 * (h_top + h_bottom)
    ones = jnp.ones(n)
    ll_top = m.localize(xs, h_top * ones, jnp.broadcast_to(ref[:2], (n, 2)))[:, :2]
    ll_bottom = m.localize(xs, h_bottom * ones, ll_top)[:, :2]
    ll_mid = m.localize(xs, h_mid * ones, 0.5 * (ll_top + ll_bottom))[:, :2]

    def ray(h):
        """The quadratic through the three localisations, at heights ``h`` (n,): ``(lon,
        lat)``."""
        t = ((h - h_bottom) / (h_top - h_bottom))[:, None]
        return (ll_bottom * (1 - t) * (1 - 2 * t) + ll_mid * 4 * t * (1 - t)
                + ll_top * t * (2 * t - 1))  # fmt: skip

    # the same quadratic through the DEM pixels of the three (the march and the refinement run
    # in pixel space: a UTM DEM's projection is not in their loops), in Horner form in ``t``
    p_bottom, p_mid, p_top = (d.pixel(v) for v in (ll_bottom, ll_mid, ll_top))
    quad = 2.0 * (p_bottom - 2.0 * p_mid + p_top)
    lin = p_top - p_bottom - quad
    per_m = 1.0 / (h_top - h_bottom)
    z = d.heights_m

    def sample(h):
        """``h - dem``, its derivative in ``h``, whether inside the extent, and whether a
        decision there is in doubt (near the edge; near a cell line on a DEM with nodata)."""
        t = ((h - h_bottom) * per_m)[:, None]
        p = p_bottom + t * (lin + t * quad)
        dp = (lin + 2.0 * t * quad) * per_m
        f, slope, inside = _bilinear(z, p, dp)
        c, r = p[:, 0], p[:, 1]
        g = FAST_GUARD_PX
        edge = (jnp.minimum(jnp.abs(c + 0.5), jnp.abs(c - cols + 0.5)) < g) | (
            jnp.minimum(jnp.abs(r + 0.5), jnp.abs(r - rows + 0.5)) < g
        )
        line = jnp.minimum(jnp.abs(c - jnp.round(c)), jnp.abs(r - jnp.round(r))) < g
        return h - f, 1.0 - slope, inside, edge | (has_nan & line)

    travel_px = jnp.max(jnp.abs(p_top - p_bottom), axis=-1)
    steps = jnp.clip(jnp.ceil(travel_px / 0.5), 1, max_steps)
    steps = jnp.where(jnp.isfinite(steps), steps, max_steps)
    dh = (h_top - h_bottom) / steps
    f_top, _, _, doubt_top = sample(h_top * ones)

    # the robust search's march (the same heights, the same flags), all points at once
    def march_cond(s):
        k, crossed = s[0], s[2]
        return jnp.any((k < steps) & ~crossed)

    def march_body(s):
        k, h_prev, crossed, nodata, doubt, h_a, f_a, h_b, f_b, f_prev = s
        active = (k < steps) & ~crossed
        h = h_top - (k + 1) * dh
        f, _, inside, doubt_here = sample(h)
        valid = jnp.isfinite(f)
        hit = active & valid & (f <= 0.0)
        near = valid & (jnp.abs(f) < FAST_GUARD_M)
        doubt = doubt | (active & (doubt_here | near))
        nodata = nodata | (active & inside & ~valid)
        h_a, f_a = jnp.where(hit, h, h_a), jnp.where(hit, f, f_a)
        h_b, f_b = jnp.where(hit, h_prev, h_b), jnp.where(hit, f_prev, f_b)
        h_prev, f_prev = jnp.where(active, h, h_prev), jnp.where(active, f, f_prev)
        return k + 1, h_prev, crossed | hit, nodata, doubt, h_a, f_a, h_b, f_b, f_prev

    no = jnp.zeros(n, dtype=bool)
    init = (jnp.asarray(0.0), h_top * ones, no, no, doubt_top, h_top * ones, f_top,
            h_top * ones, f_top, f_top)  # fmt: skip
    _, _, crossed, nodata, doubt, h_a, f_a, h_b, f_b, _ = jax.lax.while_loop(
        march_cond, march_body, init
    )
    f_b = jnp.where(jnp.isfinite(f_b), f_b, h_b - h_a)

    # the root in the bracket: Newton on the quadratic, the bracket kept (a step out of it is
    # replaced by the bracket's midpoint)
    def refine_cond(s):
        k, active = s[0], s[-1]
        return (k < max_refine) & jnp.any(active)

    def refine_body(s):
        k, h_a, h_b, h, f, slope, doubt, active = s
        h_n = h - f / jnp.where(slope != 0.0, slope, jnp.inf)
        within = (h_n > h_a) & (h_n < h_b) & jnp.isfinite(h_n)
        h_n = jnp.where(within, h_n, 0.5 * (h_a + h_b))
        f_n, slope_n, _, doubt_here = sample(h_n)
        f_n = jnp.where(jnp.isfinite(f_n), f_n, 0.0)  # a nodata probe is a hit (as robust)
        below = f_n <= 0.0
        done = (jnp.abs(h_n - h) <= h_tol) | (f_n == 0.0)
        new = (jnp.where(below, h_n, h_a), jnp.where(below, h_b, h_n), h_n, f_n, slope_n)
        old = (h_a, h_b, h, f, slope)
        kept = tuple(jnp.where(active, x, y) for x, y in zip(new, old, strict=True))
        return k + 1, *kept, doubt | (active & doubt_here), active & ~done

    # from the secant of the bracket
    h0 = jnp.where(f_b - f_a > 0, (h_a * f_b - h_b * f_a) / (f_b - f_a), 0.5 * (h_a + h_b))
    h0 = jnp.where(crossed, h0, h_a)
    f0, slope0, _, _ = sample(h0)
    init = (jnp.asarray(0), h_a, h_b, h0, f0, slope0, doubt, crossed)
    _, _, _, h_root, _, _, doubt, active = jax.lax.while_loop(refine_cond, refine_body, init)
    converged = ~active
    status = jnp.where(
        ~crossed,
        jnp.where(nodata, DEMStatus.NODATA, DEMStatus.OUTSIDE),
        jnp.where(nodata, DEMStatus.NODATA, DEMStatus.OK),
    )
    finite = jnp.all(jnp.isfinite(ll_top) & jnp.isfinite(ll_bottom), axis=-1)
    status = jnp.where(finite | crossed, status, DEMStatus.NOT_CONVERGED)
    # the robust search decides: doubts, a refinement that did not converge, no quadratic
    robust = ~bad & (
        doubt | (crossed & ~nodata & ~converged) | ~jnp.all(jnp.isfinite(ll_mid), axis=-1) & finite
    )
    status = jnp.where(bad, DEMStatus.BAD_INPUT, status)
    ok = (status == DEMStatus.OK) & ~robust

    # the robust search's last step (:func:`_localize_one`) on the exact line of sight: one
    # Newton step from the root, which carries the implicit derivatives; its slope, and the
    # line of sight's direction over the step (<= FAST_STEP_MAX_M), those of the quadratic
    h_star = jnp.where(ok, h_root, h_mid)
    ll_star, direction = jax.jvp(ray, (h_star,), (ones,))
    ll_exact = model.localize(xy_safe, h_star, ll_star)[:, :2]
    f_val = h_star - dem.height(ll_exact)
    _, f_slope, _, _ = sample(h_star)
    safe_slope = jnp.where(ok & (jnp.abs(f_slope) > 1e-12), f_slope, 1.0)
    step = jnp.where(ok, f_val / safe_slope, 0.0)
    h = h_star - step
    ll = ll_exact - direction * step[:, None]
    # checked: the quadratic's root near the exact one, the result on the DEM
    left = jax.lax.stop_gradient(h - d.height(ll))
    good = (jnp.abs(step) <= FAST_STEP_MAX_M) & (jnp.abs(left) <= max(h_tol, 1e-6))
    robust = robust | (ok & ~jax.lax.stop_gradient(good))
    ground = jnp.concatenate([ll, h[:, None]], axis=-1)
    ground = jnp.where((ok & ~robust)[:, None], ground, jnp.nan)
    return ground, status.astype(int), robust


def _robust_search(model, dem, options, xy):
    """The robust search (:func:`_localize_one`) vmapped over flat points ``(n, 2)``."""
    max_steps, max_refine, h_tol = options
    return jax.vmap(lambda p: _localize_one(model, p, dem, max_steps, max_refine, h_tol))(xy)


@kept_points(FAST_CHUNKS, fixed=3)
def _fast_chunk(model, dem, options, xy):
    return _fast_search(model, dem, options, xy)


@kept_points(ROBUST_CHUNK, fixed=3)
def _robust_chunk(model, dem, options, xy):
    return _robust_search(model, dem, options, xy)


def on_dem_concrete(model, dem, options, flat: np.ndarray):
    """Numpy points ``(n, 2)`` -> numpy ``(ground, status)``: the fast search over chunks, the
    points it leaves run by the robust one."""
    ground, status, robust = _fast_chunk(model, dem, options, flat)
    ground, status = np.array(ground), np.array(status)
    again = np.flatnonzero(robust)
    if again.size:
        ground[again], status[again] = _robust_chunk(model, dem, options, flat[again])
    return ground, status


def on_dem_traced(model, dem, options, flat):
    """Under a transformation: the fast search, and the robust one over all the points (then
    taken where the fast one left a point) only when a point needs it (``lax.cond``)."""
    ground, status, robust = _fast_search(model, dem, options, flat)

    def again(_):
        g, s = _robust_search(model, dem, options, flat)
        return jnp.where(robust[:, None], g, ground), jnp.where(robust, s, status)

    return jax.lax.cond(jnp.any(robust), again, lambda _: (ground, status), None)
