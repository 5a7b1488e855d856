"""Fast evaluation of RPCs: the rational functions in Horner form, and numpy-in/numpy-out calls.

:func:`rational` evaluates one RPC00B cubic in Horner form over separate ``L, P, H`` arrays
(35 multiply-adds instead of 20 monomials and 20 products; XLA fuses the four polynomials of a
projection into one elementwise loop). :meth:`RPC.project <jaxgeo.models.RPC.project>` uses it
everywhere, traced or not.

Called with concrete values (numpy arrays, lists, or jax arrays outside any transformation),
``project`` and ``localize`` dispatch to compiled kernels (``jax.jit`` on the model's arrays,
no ``eqx.filter_jit``): a small call costs ~0.1 ms (dispatch and XLA's latency) instead of
tracing every time, and numpy inputs are processed in chunks of ``CHUNK`` points (padded to a
bucket size, so that every size reuses a few compiled programs) written into one numpy output,
which keeps the working set in cache. A projection of a size used before runs whole instead,
with no copy in or out (:func:`._host.call_exact`). Where jax's default device is a GPU, numpy
projections run on the host's CPU device all the same (0.61 against 0.07 G points/s through an
H100 at 1e6-1e8 points: the copies cost more than the projection), and jax arrays on the GPU
run there (:func:`_project_body_direct`: 29.8 G points/s at 1e8 on the H100, 1.2x the CPU's
body there); localisation, compute-bound, runs on the default device either way.

Localisation runs one iteration everywhere (:func:`localize_lph`: Newton, then chord steps with
the Jacobian frozen, over whole arrays): the numpy kernel, and under ``jit``/``vmap``/``grad``
:func:`localize_traced`, which adds the derivatives of the implicit function theorem. A user's
own ``jax.jit`` of ``rpc.localize`` thus gets the numpy call's values, NaN flags and speed
(it ran the per-point Newton of :func:`~jaxgeo.models.newton_root` before: 0.24x).
"""

from __future__ import annotations

import functools
from typing import TYPE_CHECKING

import jax
import jax.numpy as jnp
import numpy as np

from ._host import call_exact, host_device, on_host, runs_on_cpu, writable

if TYPE_CHECKING:
    from ._base import AbstractSensorModel

CHUNK = 1 << 17
"""Points per compiled call of the numpy paths (larger inputs loop over chunks): a projection
of 1e6 points used once takes 3.5 ms in chunks of 2^17 against 3.8 ms in 2^16 (1e7: 63 / 67
ms; localisation the same within 3 %)."""
MIN_BUCKET = 16
"""Smallest padded size of the numpy paths."""
NEWTON_STEPS = 3
"""Newton steps of the numpy-path localisation before its Jacobian is frozen (chord steps)."""
IN_FLIGHT = 4
"""Chunks dispatched (asynchronously) ahead of the one being copied out."""
WRITABLE_MIN = 1024
"""Points from which a one-chunk call hands over XLA's output instead of copying it."""


def rational(c, lon, lat, h):
    """``sum_k c[k] m_k(L, P, H)`` over the RPC00B monomials ``m_k``, in Horner form."""
    a0 = (
        c[0]
        + lat * (c[2] + lat * (c[8] + lat * c[15]) + h * (c[6] + lat * c[18] + h * c[16]))
        + h * (c[3] + h * (c[9] + h * c[19]))
    )
    a1 = c[1] + lat * (c[4] + lat * c[12]) + h * (c[5] + h * c[13] + lat * c[10])
    a2 = c[7] + lat * c[14] + h * c[17]
    return a0 + lon * (a1 + lon * (a2 + lon * c[11]))


def _normalized(rpc, lon, lat, h):
    """Normalised ``L, P, H`` of ground ``lon_deg, lat_deg, h_m`` (separate arrays)."""
    go, gs = rpc.ground_offset, rpc.ground_scale
    # lon - lon_off into (-180, 180] (antimeridian; see RPC.normalize_ground): whole turns come
    # off the longitude itself, so lon and lon +- 360 give bit-identical values
    lon = lon - 360.0 * jnp.ceil((lon - go[0] - 180.0) * (1.0 / 360.0))
    # reciprocals, not a float64 division per point: XLA's GPU fusion counts f64 division as
    # expensive and will not recompute it for both x and y, so the normalised values went
    # through memory in a second kernel
    inv = 1.0 / gs
    return (lon - go[0]) * inv[0], (lat - go[1]) * inv[1], (h - go[2]) * inv[2]


def project_stacked(rpc, lon, lat, h):
    """:func:`project_lph` with the four polynomials evaluated as one (a quarter of the traced
    operations: a smaller program to compile inside the adjustment); ``(..., 2)`` px."""
    ln, pn, hn = _normalized(rpc, lon, lat, h)
    coef = jnp.stack([rpc.num[0], rpc.den[0], rpc.num[1], rpc.den[1]], axis=-1)
    v = rational(coef, ln[..., None], pn[..., None], hn[..., None])
    xy = jnp.stack([v[..., 0] / v[..., 1], v[..., 2] / v[..., 3]], axis=-1)
    return rpc.image_offset + rpc.image_scale * xy


def project_lph(rpc, lon, lat, h):
    """``(x, y)`` px of ground ``lon_deg, lat_deg, h_m`` given as separate arrays."""
    ln, pn, hn = _normalized(rpc, lon, lat, h)
    x = rational(rpc.num[0], ln, pn, hn) / rational(rpc.den[0], ln, pn, hn)
    y = rational(rpc.num[1], ln, pn, hn) / rational(rpc.den[1], ln, pn, hn)
    return rpc.image_offset[0] + rpc.image_scale[0] * x, rpc.image_offset[1] + rpc.image_scale[
        1
    ] * y


def _project_body(treedef, leaves, ground):
    rpc = jax.tree.unflatten(treedef, leaves)
    # one transposing copy in and one out: the polynomials then run over contiguous lon, lat, h
    # rows (a vectorised loop); over the strided columns of (n, 3), or writing an interleaved
    # (n, 2) from the loop, XLA's CPU code runs 1.5-2x slower
    g = ground.reshape(-1, 3).T
    x, y = project_lph(rpc, g[0], g[1], g[2])
    return jnp.stack([x, y]).T.reshape(*ground.shape[:-1], 2)


_project_kernel = jax.jit(_project_body, static_argnums=0)


def _project_body_direct(treedef, leaves, ground):
    # on a GPU: the columns read in place and (n, 2) written as one elementwise loop, element
    # (i, k) evaluating image axis k's two polynomials. Measured on an H100 (1e8 points,
    # benchmarks/results/device-1e6to1e8_direct-16core-gpu.json): 29.8 G points/s (36 % of the
    # nominal bandwidth), the transposing CPU body 24.7 G/s, x and y computed apart then
    # stacked 24.4 G/s; separate x, y outputs 47.5 G/s. XLA still writes the normalised
    # lon, lat, h to memory in a kernel of their own (it does not recompute them for both
    # output columns): the (n, 3) -> (n, 2) call stays under half the bound
    rpc = jax.tree.unflatten(treedef, leaves)
    g = ground.reshape(-1, 3)
    ln, pn, hn = (v[:, None] for v in _normalized(rpc, g[:, 0], g[:, 1], g[:, 2]))
    xy = rational(rpc.num.T, ln, pn, hn) / rational(rpc.den.T, ln, pn, hn)
    return (rpc.image_offset + rpc.image_scale * xy).reshape(*ground.shape[:-1], 2)


_project_kernel_direct = jax.jit(_project_body_direct, static_argnums=0)


@functools.partial(jax.jit, static_argnums=0)
def _localize_kernel(treedef, leaves, image, h):
    return _localized(jax.tree.unflatten(treedef, leaves), image[..., 0], image[..., 1], h)


def _localized(rpc, x, y, h, lon0=None, lat0=None):
    """``(n, 3)`` ground of :func:`localize_lph`: NaN ``lon, lat`` where a point did not
    converge, NaN ``h`` where an input was not finite (the numpy path's and the traced path's
    output, the same numbers and flags)."""
    (lon, lat), ok = localize_lph(rpc, x, y, h, lon0=lon0, lat0=lat0)
    lon, lat = (jnp.where(ok, v, jnp.nan) for v in (lon, lat))
    bad = ~(jnp.isfinite(x) & jnp.isfinite(y) & jnp.isfinite(h))
    return jnp.stack([lon, lat, jnp.where(bad, jnp.nan, h)], axis=-1)


def localize_lph(
    rpc, x, y, h, max_steps: int = 64, tol: float = 1e-13, resid_px: float = 1e-7, *,
    lon0=None, lat0=None,
):  # fmt: skip
    """Newton's method on ``project(lon, lat, h) = (x, y)`` over whole arrays at once.

    The same guarded iteration as :func:`~jaxgeo.models.newton_root` (start at ``lon0, lat0``,
    default the scene's reference point; stop a point when its step is at most ``tol`` deg, or
    all after ``max_steps``; converged when the last step is at most ``tol`` or the residual is
    below ``resid_px``), written over separate ``x, y, h`` arrays with the 2x2 Jacobian from two
    forward-mode tangents of the Horner kernel, so that every step is one fused elementwise
    loop: :data:`NEWTON_STEPS` Newton steps, then chord steps with the last Jacobian kept (one
    evaluation instead of three; the Jacobian of an RPC barely changes over the last pixels:
    the same fixed point, the same convergence test). One loop with a ``cond``: written as two
    loops (Newton, then chord) or unrolled, XLA's CPU code ran 2-4x slower. Batched (``vmap``)
    it would run both branches at every step: :func:`localize_traced` folds a ``vmap`` over
    points into the points instead. Not differentiated here: :func:`localize_traced` gives it
    implicit derivatives.
    Returns ``((lon, lat), converged)``.
    """
    bad = ~(jnp.isfinite(x) & jnp.isfinite(y) & jnp.isfinite(h))
    if lon0 is not None:
        bad = bad | ~(jnp.isfinite(lon0) & jnp.isfinite(lat0))
    x, y, h = (jnp.where(bad, 0.0, v) for v in (x, y, h))
    if lon0 is None:
        lon0 = jnp.full_like(x, rpc.ground_offset[0])
        lat0 = jnp.full_like(x, rpc.ground_offset[1])
    else:
        lon0 = jnp.where(bad, rpc.ground_offset[0], lon0)
        lat0 = jnp.where(bad, rpc.ground_offset[1], lat0)

    def fun(lon, lat):
        px, py = project_lph(rpc, lon, lat, h)
        return px - x, py - y

    def jacobian(lon, lat):
        (fx, fy), (ax, cy) = jax.jvp(fun, (lon, lat), (jnp.ones_like(lon), jnp.zeros_like(lat)))
        _, (bx, dy) = jax.jvp(fun, (lon, lat), (jnp.zeros_like(lon), jnp.ones_like(lat)))
        return (fx, fy), (ax, bx, cy, dy)

    def update(lon, lat, step, f, jac):
        (fx, fy), (ax, bx, cy, dy) = f, jac
        det = ax * dy - bx * cy
        dlon = (dy * fx - bx * fy) / det
        dlat = (ax * fy - cy * fx) / det
        active = step > tol  # a converged (or NaN) point keeps its value
        lon = jnp.where(active, lon - dlon, lon)
        lat = jnp.where(active, lat - dlat, lat)
        new = jnp.maximum(jnp.abs(dlon), jnp.abs(dlat))
        return lon, lat, jnp.where(active, new, step)

    def cond(carry):
        k, _, _, step, _ = carry
        return (k < max_steps) & jnp.any(step > tol)

    def body(carry):
        k, lon, lat, step, jac = carry
        f, jac = jax.lax.cond(
            k < NEWTON_STEPS, jacobian, lambda lo, la: (fun(lo, la), jac), lon, lat
        )
        return k + 1, *update(lon, lat, step, f, jac), jac

    inf = jnp.full_like(x, jnp.inf)
    jac0 = (jnp.ones_like(x), jnp.zeros_like(x), jnp.zeros_like(x), jnp.ones_like(x))
    _, lon, lat, step, _ = jax.lax.while_loop(cond, body, (0, lon0, lat0, inf, jac0))
    fx, fy = fun(lon, lat)
    small = (jnp.abs(fx) < resid_px) & (jnp.abs(fy) < resid_px)
    return (lon, lat), ~bad & ((step <= tol) | small)


def _solve_lph_impl(rpc, x, y, h, lon0, lat0):
    n = x.shape[0]
    if n <= CHUNK:
        (lon, lat), ok = localize_lph(rpc, x, y, h, lon0=lon0, lat0=lat0)
        return lon, lat, ok
    # in chunks of CHUNK points, one after another, as the numpy path: the working set of a
    # chunk stays in cache, and each chunk stops when its own points have converged (1e6
    # points at once ran at half the numpy path's speed)
    chunks = -(-n // CHUNK)
    pad = chunks * CHUNK - n

    def split(a):
        return jnp.concatenate([a, jnp.broadcast_to(a[-1:], (pad,))]).reshape(chunks, CHUNK)

    def one(args):
        (lon, lat), ok = localize_lph(rpc, *args[:3], lon0=args[3], lat0=args[4])
        return lon, lat, ok

    out = jax.lax.map(one, tuple(split(a) for a in (x, y, h, lon0, lat0)))
    return tuple(a.reshape(-1)[:n] for a in out)


_solve_lph = jax.custom_batching.custom_vmap(_solve_lph_impl)
""":func:`localize_lph` over flat arrays of points ``(lon, lat, converged)``, with a batching
rule (:func:`_solve_lph_vmap`)."""


@_solve_lph.def_vmap
def _solve_lph_vmap(axis_size, in_batched, rpc, x, y, h, lon0, lat0):
    """A ``vmap`` over points (one model) becomes more points: the batch axis is folded into
    the points and the iteration runs unbatched (a batched loop would run both branches of its
    ``cond`` at every step: 2-7x slower). A ``vmap`` over models: the iteration batched."""
    batched = (x, y, h, lon0, lat0)
    if any(jax.tree.leaves(in_batched[0])):
        rpc_axes = jax.tree.map(lambda b: 0 if b else None, in_batched[0])
        axes = (rpc_axes, *(0 if b else None for b in in_batched[1:]))
        out = jax.vmap(_solve_lph_impl, in_axes=axes)(rpc, *batched)
        return out, (True, True, True)
    data = [
        a if b else jnp.broadcast_to(a, (axis_size, *a.shape))
        for a, b in zip(batched, in_batched[1:], strict=True)
    ]
    shape = data[0].shape
    lon, lat, ok = _solve_lph(rpc, *(a.reshape(-1) for a in data))
    return (lon.reshape(shape), lat.reshape(shape), ok.reshape(shape)), (True, True, True)


@jax.custom_jvp
def _root_lph(rpc, x, y, h, lon0, lat0):
    """:func:`localize_lph` as a function of the model and the data, with the derivatives of
    the implicit function theorem (:func:`_root_lph_jvp`): ``(lon, lat, converged)``."""
    return _solve_lph(rpc, x, y, h, lon0, lat0)


@_root_lph.defjvp
def _root_lph_jvp(primals, tangents):
    """``d(lon, lat) = -f_ll^-1 (f_rpc drpc + f_h dh - d(x, y))`` at the root, with ``f =
    project - (x, y)``: the derivative of :func:`~jaxgeo.models.newton_root` (the exact
    Jacobian, whatever the iteration used), zero for the starting point. Linearised at a
    finite stand-in where a point failed (double ``where``), whose tangent is zero: a NaN
    point poisons neither the others nor the model's derivative."""
    rpc, x, y, h, lon0, lat0 = primals
    d_rpc, dx, dy, dh, _, _ = tangents
    lon, lat, ok = _root_lph(rpc, x, y, h, lon0, lat0)  # itself differentiable: higher orders
    finite = ok & jnp.isfinite(lon) & jnp.isfinite(lat)
    lon_s = jnp.where(finite, lon, rpc.ground_offset[0])
    lat_s = jnp.where(finite, lat, rpc.ground_offset[1])
    h_s = jnp.where(finite, h, rpc.ground_offset[2])

    def at(r, lo, la, hh):
        return project_lph(r, lo, la, hh)

    zero, one = jnp.zeros_like(lon_s), jnp.ones_like(lon_s)
    _, (ax, cy) = jax.jvp(lambda lo: at(rpc, lo, lat_s, h_s), (lon_s,), (one,))
    _, (bx, dyy) = jax.jvp(lambda la: at(rpc, lon_s, la, h_s), (lat_s,), (one,))
    d_h = jnp.where(finite, dh, zero)
    _, (fx, fy) = jax.jvp(lambda r, hh: at(r, lon_s, lat_s, hh), (rpc, h_s), (d_rpc, d_h))
    fx = fx - jnp.where(finite, dx, zero)
    fy = fy - jnp.where(finite, dy, zero)
    det = ax * dyy - bx * cy
    good = finite & jnp.isfinite(det) & (det != 0.0)
    det = jnp.where(good, det, 1.0)
    d_lon = jnp.where(good, -(dyy * fx - bx * fy) / det, 0.0)
    d_lat = jnp.where(good, -(ax * fy - cy * fx) / det, 0.0)
    float0 = np.zeros(jnp.shape(ok), dtype=jax.dtypes.float0)
    return (lon, lat, ok), (d_lon, d_lat, float0)


def localize_traced(rpc, image, h, guess=None):
    """``rpc.localize(image, h, guess)`` under ``jit``/``vmap``/``grad`` (or with a ``guess``):
    the numpy path's iteration (:func:`localize_lph`: the same values and the same NaN flags)
    over the flattened points, differentiable by the implicit function theorem (the start
    ``guess`` gets no gradient). ``(..., 3)`` over the broadcast batch of the inputs."""
    image = jnp.asarray(image, dtype=float)
    if image.shape[-1:] != (2,):
        raise ValueError(f"image coordinates must have a last axis of size 2, got {image.shape}")
    h = jnp.asarray(h, dtype=float)
    shapes = [image.shape[:-1], h.shape]
    if guess is not None:
        guess = jax.lax.stop_gradient(jnp.asarray(guess, dtype=float))
        shapes.append(guess.shape[:-1])
    batch = jnp.broadcast_shapes(*shapes)
    image = jnp.broadcast_to(image, (*batch, 2)).reshape(-1, 2)
    x, y = image[:, 0], image[:, 1]
    h = jnp.broadcast_to(h, batch).reshape(-1)
    if guess is None:
        lon0 = jnp.full_like(x, rpc.ground_offset[0])
        lat0 = jnp.full_like(x, rpc.ground_offset[1])
    else:
        guess = jnp.broadcast_to(guess, (*batch, 2)).reshape(-1, 2)
        lon0, lat0 = guess[:, 0], guess[:, 1]
    lon0, lat0 = (jax.lax.stop_gradient(v) for v in (lon0, lat0))
    lon, lat, ok = _root_lph(rpc, x, y, h, lon0, lat0)
    lon, lat = (jnp.where(ok, v, jnp.nan) for v in (lon, lat))
    bad = ~(jnp.isfinite(x) & jnp.isfinite(y) & jnp.isfinite(h))
    out = jnp.stack([lon, lat, jnp.where(bad, jnp.nan, h)], axis=-1)
    return out.reshape(*batch, 3)


def _flat(model):
    # the model's arrays as a list and its (hashable) structure: jit's C++ dispatch handles a
    # list of arrays far faster than an equinox Module, whose flattening runs in Python
    leaves, treedef = jax.tree.flatten(model)
    return treedef, leaves


def is_concrete(*trees) -> bool:
    """True when no leaf of ``trees`` is a tracer (the call is not inside jit/vmap/grad)."""
    return not any(isinstance(x, jax.core.Tracer) for t in trees for x in jax.tree.leaves(t))


def _bucket(n: int) -> int:
    """The padded size of ``n`` points: the next of 1, 1.25, 1.5, 1.75 times a power of two
    (at most 25 % padding, four compiled programs per octave of sizes used)."""
    if n <= MIN_BUCKET:
        return MIN_BUCKET
    octave = 1 << ((n - 1).bit_length() - 1)  # the power of two below n
    step = octave // 4
    return -(-n // step) * step


def _padded(part: np.ndarray, size: int) -> np.ndarray:
    """``part`` with its last row repeated up to ``size`` rows (``np.pad(mode="edge")``
    without its ~30 us of overhead)."""
    if part.shape[0] == size:
        return part
    out = np.empty((size, *part.shape[1:]), dtype=part.dtype)
    out[: part.shape[0]] = part
    out[part.shape[0] :] = part[-1]
    return out


def chunked(kernel, args_np: tuple[np.ndarray, ...], n: int, out_width: int) -> np.ndarray:
    """``kernel(*chunk)`` over row chunks of the flat numpy arrays ``args_np`` (``n`` rows),
    padded (edge values) to a :func:`_bucket` size up to ``CHUNK``; one numpy output
    ``(n, width)``. Up to ``IN_FLIGHT`` chunks are dispatched before the first is collected,
    so that XLA computes one while the host copies another."""
    size = min(_bucket(n), CHUNK)
    if WRITABLE_MIN <= n <= size and runs_on_cpu():
        # one chunk: its output without a copy (10 % faster at 1e4 points, slower below 1e3)
        return writable(kernel(*(_padded(a, size) for a in args_np)))[:n]
    out = np.empty((n, out_width))
    pending: list[tuple[int, int, jax.Array]] = []

    def collect():
        start, stop, result = pending.pop(0)
        out[start:stop] = np.asarray(result)[: stop - start]

    for start in range(0, n, size):
        stop = min(start + size, n)
        parts = [_padded(a[start:stop], size) for a in args_np]
        pending.append((start, stop, kernel(*parts)))
        if len(pending) >= IN_FLIGHT:
            collect()
    while pending:
        collect()
    return out


def project_concrete(rpc, ground) -> np.ndarray | jax.Array:
    """``rpc.project(ground)`` for concrete inputs: numpy out for numpy/list in, else jax."""
    if isinstance(ground, jax.Array):
        on_cpu = all(d.platform == "cpu" for d in ground.devices())
        kernel = _project_kernel if on_cpu else _project_kernel_direct
        return kernel(*_flat(rpc), jnp.asarray(ground, dtype=float))
    if not runs_on_cpu():
        # numpy in and out on a GPU machine: computed on the host's CPU, where the data are (a
        # projection moves 40 B a point; over PCIe that costs more than computing it: 1e6
        # points 0.07-0.19 G/s through an H100 against 0.80 G/s on its 16-core host)
        treedef, leaves = _flat(rpc)
        with jax.default_device(host_device()):
            return project_concrete(jax.tree.unflatten(treedef, on_host(leaves)), ground)
    g = np.asarray(ground, dtype=float)
    if g.shape[-1:] != (3,):
        raise ValueError(f"ground coordinates must have a last axis of size 3, got {g.shape}")
    batch = g.shape[:-1]
    flat = np.ascontiguousarray(g.reshape(-1, 3))
    if flat.shape[0] == 0:
        return np.zeros((*batch, 2))
    treedef, leaves = _flat(rpc)
    out = call_exact(_project_body, treedef, leaves, (flat,), flat.shape[0])
    if out is None:
        out = chunked(lambda a: _project_kernel(treedef, leaves, a), (flat,), flat.shape[0], 2)
    return out.reshape(*batch, 2)


def localize_concrete(model: AbstractSensorModel, image, h) -> np.ndarray | jax.Array:
    """``model.localize(image, h)`` (no guess) for concrete inputs, compiled once per model
    type and chunk size: numpy out for numpy/list in, else jax."""
    if isinstance(image, jax.Array) or isinstance(h, jax.Array):
        return _localize_kernel(*_flat(model), jnp.asarray(image, float), jnp.asarray(h, float))
    img = np.asarray(image, dtype=float)
    if img.shape[-1:] != (2,):
        raise ValueError(f"image coordinates must have a last axis of size 2, got {img.shape}")
    hh = np.asarray(h, dtype=float)
    batch = np.broadcast_shapes(img.shape[:-1], hh.shape)
    img = np.ascontiguousarray(np.broadcast_to(img, (*batch, 2)).reshape(-1, 2))
    hh = np.ascontiguousarray(np.broadcast_to(hh, batch).reshape(-1))
    if img.shape[0] == 0:
        return np.zeros((*batch, 3))
    treedef, leaves = _flat(model)
    out = chunked(lambda a, b: _localize_kernel(treedef, leaves, a, b), (img, hh), img.shape[0], 3)
    return out.reshape(*batch, 3)
