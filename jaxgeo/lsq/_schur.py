"""Structured Gauss-Newton / Levenberg-Marquardt: the Schur complement (reduced camera system).

Every observation depends on one camera block and/or one ground point, so the Jacobian has
non-zero blocks only there. They all come from ``P + 3`` Jacobian-vector products whatever the
size of the problem ("colouring": tangent ``i`` sets parameter ``i`` of *every* block, or axis
``i`` of every point, at once). The normal equations

    [ U   W ] [dc]   [gc]
    [ W^T V ] [dp] = [gp]

have 3x3 point blocks ``V``; eliminating them gives the reduced camera system
``S = U - W V^-1 W^T`` (dense, one row per camera parameter), solved by Cholesky, and the points
by back-substitution. Levenberg-Marquardt damping is Marquardt's diagonal scaling
``lambda diag(J^T J)`` (clamped to [1e-6, 1e32], as Ceres does), added before elimination.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int, PyTree

from . import _band as band
from ._factor import cho_solve, cholesky, inv3_spd
from ._problem import Structure

DIAG_MIN = 1e-6
DIAG_MAX = 1e32
SUM_CHUNK = 1 << 14
"""Rows (observations, pairs of observations) whose products are formed at a time when they are
summed per block (:func:`chunked_segment_sum`): a 100 000-tie pair has 400 000 pairs, whose
6 x 6 products alone would take 115 MB at once, and the solve held several such temporaries
(1.5 GB peak); in chunks of 2^14 rows they take 4.7 MB, and the sum runs in cache."""


class Jacobians(eqx.Module):
    """Non-zero Jacobian blocks and residuals, all image observations concatenated.

    ``jc`` (M, 2, P) w.r.t. the observation's camera parameters, ``jp`` (M, 2, 3) w.r.t. its
    point, ``r`` (M, 2); ``jg`` (c, 3, 3), ``rg`` (c, 3) of the ground observations; ``jpr``,
    ``rpr`` per group ``(n_blocks, q, P)``, ``(n_blocks, q)`` of the block priors.
    """

    jc: Float[Array, "M 2 P"]
    jp: Float[Array, "M 2 3"]
    r: Float[Array, "M 2"]
    jg: Float[Array, "c 3 3"]
    rg: Float[Array, "c 3"]
    jpr: tuple[Float[Array, "b q P"], ...]
    rpr: tuple[Float[Array, "b q"], ...]


class NormalBlocks(eqx.Module):
    """Blocks of ``J^T J`` and ``J^T r``: ``u`` (N+1, N+1) dense (last row/column a dummy for
    padding), or (B, P, P) its diagonal blocks when the reduced system is banded
    (``Structure.band``; ``U`` is block diagonal: an observation sees one camera block);
    ``gc`` (N+1,), ``v`` (n, 3, 3), ``gp`` (n, 3), ``w`` (M, P, 3) per observation."""

    u: Float[Array, "N1 N1"] | Float[Array, "B P P"]
    gc: Float[Array, " N1"]
    v: Float[Array, "n 3 3"]
    gp: Float[Array, "n 3"]
    w: Float[Array, "M P 3"]


def chunked_segment_sum(
    values: Callable[..., Array | tuple[Array, ...]],
    rows: tuple[Array, ...],
    segments: Array | tuple[Array, ...],
    num_segments: int | tuple[int, ...],
    chunk: int | None = None,
) -> Array | tuple[Array, ...]:
    """``segment_sum(values(*rows), segments, num_segments)`` without forming ``values`` for
    all rows at once: ``values`` maps index arrays (a chunk of each of ``rows``, all of one
    length K) to per-row values, summed over ``chunk`` (default :data:`SUM_CHUNK`) rows at a
    time (a ``scan``; one call when K fits in a chunk). Several outputs: ``values`` returns a
    tuple, and ``segments`` / ``num_segments`` are tuples (one per output)."""
    chunk = SUM_CHUNK if chunk is None else int(chunk)
    many = isinstance(num_segments, tuple)
    segs = segments if many else (segments,)
    nums = num_segments if many else (num_segments,)

    def add(acc, idx, seg):  # scatter-add into the accumulators (in place in the loop)
        out = values(*idx)
        out = out if many else (out,)
        return tuple(a.at[g].add(o, mode="drop") for a, o, g in zip(acc, out, seg, strict=True))

    shapes = jax.eval_shape(lambda *r: values(*r), *(r[:1] for r in rows))
    shapes = shapes if many else (shapes,)
    init = tuple(jnp.zeros((n, *o.shape[1:]), o.dtype) for o, n in zip(shapes, nums, strict=True))
    k = rows[0].shape[0]
    if k <= chunk:
        out = add(init, rows, segs)
        return out if many else out[0]
    n_chunks = -(-k // chunk)

    def body(acc, c):  # chunk c, sliced in place (no padded copy of the index arrays); the
        # last one ends at row k, and its rows that an earlier chunk had are dropped
        start = jnp.minimum(c * chunk, k - chunk)
        idx = tuple(jax.lax.dynamic_slice_in_dim(r, start, chunk) for r in rows)
        fresh = start + jnp.arange(chunk) >= c * chunk
        seg = tuple(
            jnp.where(fresh, jax.lax.dynamic_slice_in_dim(g, start, chunk), n)
            for g, n in zip(segs, nums, strict=True)
        )
        return add(acc, idx, seg), None

    out, _ = jax.lax.scan(body, init, jnp.arange(n_chunks))
    return out if many else out[0]


def add_block_sums(target: Array, s: Structure, summed: Array) -> Array:
    """``target`` (N+1,) or (N+1, N+1) plus per-block sums (B, P) or (B, P, P) at their
    parameters (one small scatter)."""
    bp = s.all_block_params
    if summed.ndim == 2:
        return target.at[bp].add(summed)
    return target.at[bp[:, :, None], bp[:, None, :]].add(summed)


def add_pair_sums(target: Array, s: Structure, summed: Array) -> Array:
    """``target`` (N+1, N+1) plus per-block-pair sums (Q, P, P) at (parameters of the pair's
    first block, of its second)."""
    pa = s.all_block_params[s.pair_blocks[:, 0]]
    pb = s.all_block_params[s.pair_blocks[:, 1]]
    return target.at[pa[:, :, None], pb[:, None, :]].add(summed)


def split_jacobians(fn: Callable, args: Any, y: PyTree, width: int) -> Jacobians:
    """:func:`jacobians` from two linearisations of ``fn(y, args)``, in the camera parameters
    (``width`` tangents) and in the points (3): the sensor models' derivatives in the ground
    coordinates are evaluated for the 3 point tangents only, not for every parameter colour as
    well (2.5x faster for 200 000 RPC observations)."""
    z, u = y
    r, lin_z = jax.linearize(lambda zz: fn((zz, u), args), z)
    _, lin_u = jax.linearize(lambda uu: fn((z, uu), args), u)
    eye = jnp.eye(width, dtype=u.dtype)
    zs = tuple(jnp.broadcast_to(eye[:, None, : zg.shape[1]], (width, *zg.shape)) for zg in z)
    us = jnp.broadcast_to(jnp.eye(3, dtype=u.dtype)[:, None, :], (3, *u.shape))
    img_z, _, pr_z = jax.vmap(lin_z)(zs)
    img_u, gnd_u, _ = jax.vmap(lin_u)(us)
    img, gnd, pr = r
    last = lambda o: jnp.moveaxis(o, 0, -1)  # noqa: E731
    return Jacobians(
        jc=jnp.concatenate([last(o) for o in img_z]) if img_z else jnp.zeros((0, 2, width)),
        jp=jnp.concatenate([last(o) for o in img_u]) if img_u else jnp.zeros((0, 2, 3)),
        r=jnp.concatenate(img) if img else jnp.zeros((0, 2)),
        jg=last(gnd_u),
        rg=gnd,
        jpr=tuple(last(o) for o in pr_z),
        rpr=tuple(pr),
    )


def normal_blocks(jac: Jacobians, s: Structure) -> NormalBlocks:
    """Assemble :class:`NormalBlocks` from the Jacobian blocks (no dense ``J``)."""
    n1 = s.n_params + 1
    m = s.obs_block.shape[0]
    jc, jp, r = jac.jc, jac.jp, jac.r

    def products(jc, jp, r):
        return (
            jnp.einsum("mkp,mkq->mpq", jc, jc),
            jnp.einsum("mkp,mk->mp", jc, r),
            jnp.einsum("mki,mkj->mij", jp, jp),
            jnp.einsum("mki,mk->mi", jp, r),
        )

    # summed per block and per point, in chunks of observations when there are many (no
    # (M, P, P) temporary); a small problem (each of a batch) at once, without index arrays
    nb = s.all_block_params.shape[0]
    segs = (s.obs_block, s.obs_block, s.obs_point, s.obs_point)
    nums = (nb, nb, s.n_points, s.n_points)
    if m <= SUM_CHUNK:
        found = zip(products(jc, jp, r), segs, nums, strict=True)
        jtj, gcb, v, gp = (jax.ops.segment_sum(x, g, k) for x, g, k in found)
    else:
        jtj, gcb, v, gp = chunked_segment_sum(
            lambda i: products(jc[i], jp[i], r[i]), (jnp.arange(m),), segs, nums
        )
    if s.band:  # one group: its blocks in order, the priors' blocks aligned with them
        u = jtj
    else:
        u = add_block_sums(jnp.zeros((n1, n1)), s, jtj)
    gc = add_block_sums(jnp.zeros(n1), s, gcb)
    for bidx, jpr, rpr in zip(s.block_params, jac.jpr, jac.rpr, strict=True):
        prior = jnp.einsum("bqp,bqr->bpr", jpr, jpr)
        u = u + prior if s.band else u.at[bidx[:, :, None], bidx[:, None, :]].add(prior)
        gc = gc.at[bidx].add(jnp.einsum("bqp,bq->bp", jpr, rpr))
    seg = jax.ops.segment_sum
    v = v + seg(jnp.einsum("cki,ckj->cij", jac.jg, jac.jg), s.ground_point, s.n_points)
    gp = gp + seg(jnp.einsum("cki,ck->ci", jac.jg, jac.rg), s.ground_point, s.n_points)
    w = jnp.einsum("mkp,mkj->mpj", jc, jp)
    return NormalBlocks(u=u, gc=gc, v=v, gp=gp, w=w)


def inv3(v: Float[Array, "n 3 3"]) -> Float[Array, "n 3 3"]:
    """Batched inverse of symmetric 3x3 blocks (closed form, no LAPACK; NaN where not positive
    definite)."""
    return inv3_spd(v)


def u_diagonal(blocks: NormalBlocks, s: Structure) -> Float[Array, " N"]:
    """The diagonal of ``U`` (N,), dense or banded storage."""
    if s.band:
        return jnp.diagonal(blocks.u, axis1=1, axis2=2).reshape(-1)
    return jnp.diagonal(blocks.u)[: s.n_params]


def damped(blocks: NormalBlocks, s: Structure, lam) -> tuple[Array, Array]:
    """``U + lam diag(U)`` (dummy row/column: identity) and ``V + lam diag(V)``."""
    n = s.n_params
    if s.band:
        du = jnp.clip(jnp.diagonal(blocks.u, axis1=1, axis2=2), DIAG_MIN, DIAG_MAX)
        u = blocks.u + lam * du[:, :, None] * jnp.eye(s.width)
    else:
        du = jnp.clip(jnp.diagonal(blocks.u), DIAG_MIN, DIAG_MAX)
        u = blocks.u + lam * jnp.diag(du)
        u = u.at[n, :].set(0.0).at[:, n].set(0.0).at[n, n].set(1.0)
    dv = jnp.clip(jnp.diagonal(blocks.v, axis1=1, axis2=2), DIAG_MIN, DIAG_MAX)
    v = blocks.v + lam * dv[:, :, None] * jnp.eye(3)
    return u, v


def wv(blocks: NormalBlocks, vinv: Float[Array, "n 3 3"], s: Structure, rows: Array) -> Array:
    """``W V^-1`` (k, P, 3) of the observations ``rows`` (k,): formed where it is used, a chunk
    at a time, never for all observations at once."""
    return jnp.einsum("kpj,kjl->kpl", blocks.w[rows], vinv[s.obs_point[rows]])


def reduced_system(
    blocks: NormalBlocks, s: Structure, lam: Float[Array, ""] | float
) -> tuple[Float[Array, "N1 N1"] | band.Band, Float[Array, "n 3 3"]]:
    """``(S, V^-1)`` of the damped normal equations (damping ``lam * diag``); ``S`` dense
    (N+1, N+1), or a :class:`~._band.Band` (N,) when ``Structure.band``."""
    n = s.n_params
    u, v = damped(blocks, s, lam)
    vinv = inv3(v)
    # W V^-1 W^T summed per block pair, over chunks of the pairs (no (K, P, P) temporary)
    summed = chunked_segment_sum(
        lambda a, b: jnp.einsum("kpj,kqj->kpq", wv(blocks, vinv, s, a), blocks.w[b]),
        (s.pair_a, s.pair_b), s.pair_seg, s.pair_blocks.shape[0],
    )  # fmt: skip
    if s.band:
        return band.assemble_band(u, s.pair_blocks, -summed, s.band, n), vinv
    big_s = add_pair_sums(u, s, -summed)
    # the dummy (padding) parameter stays an identity row
    big_s = big_s.at[n, :].set(0.0).at[:, n].set(0.0).at[n, n].set(1.0)
    return big_s, vinv


def factorise(big_s: Array | band.Band) -> Array | band.BandFactor:
    """Cholesky factor of the reduced system, dense or banded (NaN if not positive definite)."""
    return band.band_cholesky(big_s) if isinstance(big_s, band.Band) else cholesky(big_s)


def solve_factored(chol: Array | band.BandFactor, rhs: Float[Array, " N1"]) -> Float[Array, " N1"]:
    """``S^-1 rhs`` from :func:`factorise` (the dummy entry, last, stays 0 when banded)."""
    if isinstance(chol, band.BandFactor):
        return rhs.at[:-1].set(band.band_solve(chol, rhs[:-1])).at[-1].set(0.0)
    return cho_solve(chol, rhs)


def schur_solve(
    blocks: NormalBlocks, s: Structure, lam: Float[Array, ""] | float
) -> tuple[Float[Array, " N"], Float[Array, "n 3"]]:
    """Solve ``(J^T J + lam D) d = J^T r`` for the camera ``dc`` (N,) and point ``dp`` (n, 3).

    No iterative refinement: at our conditioning the solution agrees with a dense QR solve to
    the noise floor of the cost."""
    n = s.n_params
    big_s, vinv = reduced_system(blocks, s, lam)
    chol = factorise(big_s)
    idx, pt = s.obs_params, s.obs_point
    gc, gp = blocks.gc.at[n].set(0.0), blocks.gp
    vg = jnp.einsum("nij,nj->ni", vinv, gp)  # W V^-1 g_p = W (V^-1 g_p): no (M, P, 3) product
    nb = s.all_block_params.shape[0]
    wvg = per_observation_sum(
        lambda i: jnp.einsum("kpj,kj->kp", blocks.w[i], vg[pt[i]]), s.obs_block, nb
    )
    rhs = add_block_sums(gc, s, -wvg).at[n].set(0.0)
    dc = solve_factored(chol, rhs)
    back = per_observation_sum(
        lambda i: jnp.einsum("kpj,kp->kj", blocks.w[i], dc[idx[i]]), pt, s.n_points
    )
    return dc[:n], jnp.einsum("nij,nj->ni", vinv, gp - back)


def per_observation_sum(
    values: Callable[[Array | slice], Array], segments: Int[Array, " M"], num_segments: int
) -> Array:
    """``segment_sum(values(all rows), segments, num_segments)``: at once for a small problem
    (each of a batch; ``values`` gets ``slice(None)``, no gather), in chunks of observations
    for a large one (``values`` gets index arrays; no (M, ...) temporary: a 200 000-observation
    pair's (M, P) products are 9.6 MB each)."""
    m = segments.shape[0]
    if m <= SUM_CHUNK:
        return jax.ops.segment_sum(values(slice(None)), segments, num_segments)
    return chunked_segment_sum(values, (jnp.arange(m),), segments, num_segments)


def zero_blocks(s: Structure, m: int) -> NormalBlocks:
    """All-zero :class:`NormalBlocks` of ``m`` image observations (a solver's initial state)."""
    n1, p = s.n_params + 1, s.width
    return NormalBlocks(
        u=jnp.zeros((s.n_blocks, p, p)) if s.band else jnp.zeros((n1, n1)),
        gc=jnp.zeros(n1),
        v=jnp.zeros((s.n_points, 3, 3)),
        gp=jnp.zeros((s.n_points, 3)),
        w=jnp.zeros((m, p, 3)),
    )


def model_change(
    blocks: NormalBlocks, s: Structure, dc: Float[Array, " N"], dp: Float[Array, "n 3"]
) -> Float[Array, ""]:
    """``g^T d + d^T H d / 2`` for the step ``d = (dc, dp)``: the change of half the cost that
    the quadratic model of the normal blocks predicts (``g = J^T r``, ``H = J^T J``), from
    ``U``, ``W`` and ``V`` without the Jacobian."""
    n = s.n_params
    if s.band:
        dcb = dc.reshape(s.n_blocks, s.width)
        uu = jnp.einsum("bp,bpq,bq->", dcb, blocks.u, dcb)
    else:
        uu = jnp.dot(dc, blocks.u[:n, :n] @ dc)
    dc1 = jnp.concatenate([dc, jnp.zeros(1)])  # the dummy (padding) parameter
    ww = per_observation_sum(
        lambda i: jnp.einsum("kp,kpj,kj->k", dc1[s.obs_params[i]], blocks.w[i], dp[s.obs_point[i]]),
        jnp.zeros(s.obs_point.shape[0], dtype=jnp.int32),
        1,
    )[0]
    vv = jnp.einsum("ni,nij,nj->", dp, blocks.v, dp)
    g = jnp.dot(blocks.gc[:n], dc) + jnp.sum(blocks.gp * dp)
    return g + 0.5 * (uu + 2.0 * ww + vv)


def split_params(flat: Float[Array, " N"], s: Structure) -> tuple[Float[Array, "b p"], ...]:
    """Flat camera parameters (N,) -> per group ``(n_blocks, n_params)``."""
    out, start = [], 0
    for b, p in s.group_shapes:
        out.append(flat[start : start + b * p].reshape(b, p))
        start += b * p
    return tuple(out)
