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
import optimistix as optx
from jaxtyping import Array, Float, Int, PyTree

from . import band
from .factor import cho_solve, cholesky, inv3_spd
from .loss import newton_corrected
from .problem import Structure
from .trust_region import NOISE_FLOOR, NoiseTolerantTrustRegion

CONVERGED_FLOOR = 1e-16
"""Relative cost reduction promised by the full step below which the solve has converged."""
STAGNANT_STEPS = 3
"""Accepted steps in a row that fail to halve a decrement already under the cost's rounding
noise (``NOISE_FLOOR`` of the cost) after which the solve has converged: the linear solve's own
rounding then sets the decrement (seen at 320 sub-scenes: 3e-12 for ever, above ``tol**2``)."""
NEGLIGIBLE_DAMPING = 1e-6
"""Damping ``lambda`` (relative to ``diag(J^T J)``) at or below which a step is the undamped
Gauss-Newton step that ``query`` already solved for the decrement: one factorisation per step
instead of two once the trust region has grown (``lambda = damping / step_size``, 1e-4 at the
start, 10x smaller after each very successful step). The trust region judges the step by the
cost either way."""
DIAG_MIN = 1e-6
DIAG_MAX = 1e32


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


def colours(y: PyTree, width: int) -> PyTree:
    """The ``width + 3`` tangents of the colouring, stacked on a leading axis, shaped like ``y``."""
    z, u = y
    eye = jnp.eye(width, dtype=u.dtype)
    zs = tuple(
        jnp.concatenate(
            [
                jnp.broadcast_to(eye[:, None, : zg.shape[1]], (width, *zg.shape)),
                jnp.zeros((3, *zg.shape), zg.dtype),
            ]
        )
        for zg in z
    )
    us = jnp.concatenate(
        [
            jnp.zeros((width, *u.shape), u.dtype),
            jnp.broadcast_to(jnp.eye(3, dtype=u.dtype)[:, None, :], (3, *u.shape)),
        ]
    )
    return zs, us


def jacobians(linear: Callable, residual: PyTree, y: PyTree, width: int) -> Jacobians:
    """The non-zero Jacobian blocks from ``width + 3`` JVPs of ``linear`` (the linearised
    residual function) at ``y``; ``residual`` is the residual pytree ``(img, gnd, prior)``."""
    out_img, out_gnd, out_pr = jax.vmap(linear)(colours(y, width))
    img, gnd, pr = residual

    def split(o):  # (P + 3, m, k) -> (m, k, P), (m, k, 3)
        return jnp.moveaxis(o[:width], 0, -1), jnp.moveaxis(o[width:], 0, -1)

    jc, jp = zip(*(split(o) for o in out_img), strict=True) if out_img else ((), ())
    return Jacobians(
        jc=jnp.concatenate(jc) if jc else jnp.zeros((0, 2, width)),
        jp=jnp.concatenate(jp) if jp else jnp.zeros((0, 2, 3)),
        r=jnp.concatenate(img) if img else jnp.zeros((0, 2)),
        jg=jnp.moveaxis(out_gnd[width:], 0, -1),
        rg=gnd,
        jpr=tuple(jnp.moveaxis(o[:width], 0, -1) for o in out_pr),
        rpr=tuple(pr),
    )


def add_per_block(target: Array, s: Structure, values: Array) -> Array:
    """``target`` (N+1,) or (N+1, N+1) plus per-observation ``values`` (M, P) or (M, P, P) at
    their parameters: summed per block first (``segment_sum``), then one small scatter (a
    scatter-add of every element is slow on CPU: ~10x at 40 000 x 6 x 6)."""
    bp = s.all_block_params
    summed = jax.ops.segment_sum(values, s.obs_block, bp.shape[0])
    if values.ndim == 2:
        return target.at[bp].add(summed)
    return target.at[bp[:, :, None], bp[:, None, :]].add(summed)


def add_per_pair(target: Array, s: Structure, values: Array) -> Array:
    """``target`` (N+1, N+1) plus per-pair ``values`` (K, P, P) at (parameters of the pair's
    first observation, of its second), summed per block pair first."""
    summed = jax.ops.segment_sum(values, s.pair_seg, s.pair_blocks.shape[0])
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
    jtj = jnp.einsum("mkp,mkq->mpq", jac.jc, jac.jc)
    if s.band:  # one group: its blocks in order, the priors' blocks aligned with them
        u = jax.ops.segment_sum(jtj, s.obs_block, s.n_blocks)
    else:
        u = add_per_block(jnp.zeros((n1, n1)), s, jtj)
    gc = add_per_block(jnp.zeros(n1), s, jnp.einsum("mkp,mk->mp", jac.jc, jac.r))
    for bidx, jpr, rpr in zip(s.block_params, jac.jpr, jac.rpr, strict=True):
        prior = jnp.einsum("bqp,bqr->bpr", jpr, jpr)
        u = u + prior if s.band else u.at[bidx[:, :, None], bidx[:, None, :]].add(prior)
        gc = gc.at[bidx].add(jnp.einsum("bqp,bq->bp", jpr, rpr))
    seg = jax.ops.segment_sum
    v = seg(jnp.einsum("mki,mkj->mij", jac.jp, jac.jp), s.obs_point, s.n_points)
    gp = seg(jnp.einsum("mki,mk->mi", jac.jp, jac.r), s.obs_point, s.n_points)
    v = v + seg(jnp.einsum("cki,ckj->cij", jac.jg, jac.jg), s.ground_point, s.n_points)
    gp = gp + seg(jnp.einsum("cki,ck->ci", jac.jg, jac.rg), s.ground_point, s.n_points)
    w = jnp.einsum("mkp,mkj->mpj", jac.jc, jac.jp)
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


def reduced_system(
    blocks: NormalBlocks, s: Structure, lam: Float[Array, ""] | float
) -> tuple[Float[Array, "N1 N1"] | band.Band, Float[Array, "n 3 3"], Float[Array, "M P 3"]]:
    """``(S, V^-1, W V^-1)`` of the damped normal equations (damping ``lam * diag``); ``S``
    dense (N+1, N+1), or a :class:`~.band.Band` (N,) when ``Structure.band``."""
    n = s.n_params
    u, v = damped(blocks, s, lam)
    vinv = inv3(v)
    y = jnp.einsum("mpj,mjk->mpk", blocks.w, vinv[s.obs_point])
    sub = jnp.einsum("kpj,kqj->kpq", y[s.pair_a], blocks.w[s.pair_b])
    if s.band:
        summed = jax.ops.segment_sum(sub, s.pair_seg, s.pair_blocks.shape[0])
        return band.assemble(u, s.pair_blocks, -summed, s.band, n), vinv, y
    big_s = add_per_pair(u, s, -sub)
    # the dummy (padding) parameter stays an identity row
    big_s = big_s.at[n, :].set(0.0).at[:, n].set(0.0).at[n, n].set(1.0)
    return big_s, vinv, y


def factorise(big_s: Array | band.Band) -> Array | band.BandFactor:
    """Cholesky factor of the reduced system, dense or banded (NaN if not positive definite)."""
    return band.cholesky(big_s) if isinstance(big_s, band.Band) else cholesky(big_s)


def solve_factored(chol: Array | band.BandFactor, rhs: Float[Array, " N1"]) -> Float[Array, " N1"]:
    """``S^-1 rhs`` from :func:`factorise` (the dummy entry, last, stays 0 when banded)."""
    if isinstance(chol, band.BandFactor):
        return rhs.at[:-1].set(band.solve(chol, rhs[:-1])).at[-1].set(0.0)
    return cho_solve(chol, rhs)


def schur_solve(
    blocks: NormalBlocks, s: Structure, lam: Float[Array, ""] | float
) -> tuple[Float[Array, " N"], Float[Array, "n 3"]]:
    """Solve ``(J^T J + lam D) d = J^T r`` for the camera ``dc`` (N,) and point ``dp`` (n, 3).

    No iterative refinement: at our conditioning the solution agrees with a dense QR solve to
    the noise floor of the cost."""
    n = s.n_params
    big_s, vinv, y = reduced_system(blocks, s, lam)
    chol = factorise(big_s)
    idx, pt = s.obs_params, s.obs_point
    gc, gp = blocks.gc.at[n].set(0.0), blocks.gp
    rhs = add_per_block(gc, s, -jnp.einsum("mpj,mj->mp", y, gp[pt])).at[n].set(0.0)
    dc = solve_factored(chol, rhs)
    back = jax.ops.segment_sum(jnp.einsum("mpj,mp->mj", blocks.w, dc[idx]), pt, s.n_points)
    return dc[:n], jnp.einsum("nij,nj->ni", vinv, gp - back)


class SchurState(eqx.Module):
    """Descent state at the last accepted point: Jacobian blocks, normal blocks, the undamped
    Gauss-Newton step ``(dc, dp)`` and its squared Newton decrement ``g^T H^-1 g`` (the squared
    length of the full Gauss-Newton step in units of its own standard deviations; ``inf``
    before the first query or when singular)."""

    jac: Jacobians
    blocks: NormalBlocks
    decrement: Float[Array, ""]
    stagnant: Int[Array, ""]
    """Accepted steps in a row whose decrement did not halve the previous one."""
    dc: Float[Array, " N"]
    dp: Float[Array, "n 3"]


def _zeros_state(s: Structure, m: int, c: int, priors: tuple[tuple[int, int], ...]) -> SchurState:
    n1, p = s.n_params + 1, s.width
    jac = Jacobians(
        jc=jnp.zeros((m, 2, p)),
        jp=jnp.zeros((m, 2, 3)),
        r=jnp.zeros((m, 2)),
        jg=jnp.zeros((c, 3, 3)),
        rg=jnp.zeros((c, 3)),
        jpr=tuple(jnp.zeros((b, q, p)) for b, q in priors),
        rpr=tuple(jnp.zeros((b, q)) for b, q in priors),
    )
    blocks = NormalBlocks(
        u=jnp.zeros((s.n_blocks, p, p)) if s.band else jnp.zeros((n1, n1)),
        gc=jnp.zeros(n1),
        v=jnp.zeros((s.n_points, 3, 3)),
        gp=jnp.zeros((s.n_points, 3)),
        w=jnp.zeros((m, p, 3)),
    )
    zeros = (jnp.zeros(s.n_params), jnp.zeros((s.n_points, 3)))
    return SchurState(jac, blocks, jnp.array(jnp.inf), jnp.array(0), *zeros)


def split_params(flat: Float[Array, " N"], s: Structure) -> tuple[Float[Array, "b p"], ...]:
    """Flat camera parameters (N,) -> per group ``(n_blocks, n_params)``."""
    out, start = [], 0
    for b, p in s.group_shapes:
        out.append(flat[start : start + b * p].reshape(b, p))
        start += b * p
    return tuple(out)


class SchurDescent(optx.AbstractDescent):
    """(Damped) Gauss-Newton step by the Schur complement of the point blocks.

    ``query`` builds the Jacobian and normal blocks once per accepted point (``width + 3``
    JVPs of the linearised residuals), the undamped Gauss-Newton step and its Newton decrement;
    ``step`` solves the damped system for the trust region's step size, ``lambda = damping /
    step_size`` with Marquardt's ``diag(J^T J)`` scaling (Levenberg-Marquardt; the query's step
    itself once ``lambda <= NEGLIGIBLE_DAMPING``), or returns ``step_size`` times the
    Gauss-Newton step when ``damped`` is False.
    """

    structure: Structure
    damping: float = 1e-4
    damped: bool = eqx.field(static=True, default=True)
    fn: Callable | None = eqx.field(static=True, default=None)
    args: Any = None
    """The residual function and its arguments: given, the Jacobian blocks come from
    :func:`split_jacobians` (faster) instead of the solver's linearisation."""
    robust: tuple[str, float] | None = eqx.field(static=True, default=None)
    """``(loss, c)``: ``fn`` gives plain residuals, modelled by :func:`~.loss.newton_corrected`."""

    def init(self, y, f_info_struct) -> SchurState:
        img, gnd, pr = f_info_struct.residual
        m = sum(x.shape[0] for x in img)
        return _zeros_state(self.structure, m, gnd.shape[0], tuple(x.shape for x in pr))

    def query(self, y, f_info, state) -> SchurState:
        s = self.structure
        if self.fn is not None:
            jac = split_jacobians(self.fn, self.args, y, s.width)
            if self.robust is not None:
                r, jc, jp = newton_corrected(jac.r, (jac.jc, jac.jp), *self.robust)
                rg, jg = newton_corrected(jac.rg, (jac.jg,), *self.robust)
                jac = eqx.tree_at(lambda j: (j.r, j.jc, j.jp, j.rg, j.jg), jac, (r, jc, jp, rg, jg))
        else:
            jac = jacobians(f_info.jac.mv, f_info.residual, y, s.width)
        blocks = normal_blocks(jac, s)
        dc, dp = schur_solve(blocks, s, 0.0)
        dec = jnp.dot(blocks.gc[: s.n_params], dc) + jnp.sum(blocks.gp * dp)
        dec = jnp.where(jnp.isfinite(dec), dec, jnp.inf)
        stagnant = jnp.where(dec > 0.5 * state.decrement, state.stagnant + 1, 0)
        return SchurState(jac, blocks, dec, stagnant, dc, dp)

    def step(self, step_size, state: SchurState):
        s = self.structure
        if self.damped:
            tiny = jnp.finfo(jnp.result_type(step_size)).tiny
            lam = self.damping / jnp.maximum(step_size, tiny)
            # negligible damping: the query's undamped step, without a second factorisation
            dc, dp = jax.lax.cond(
                lam <= NEGLIGIBLE_DAMPING,
                lambda: (state.dc, state.dp),
                lambda: schur_solve(state.blocks, s, lam),
            )
            scale = 1.0
        else:
            dc, dp = state.dc, state.dp
            scale = step_size
        finite = jnp.all(jnp.isfinite(dc)) & jnp.all(jnp.isfinite(dp))
        # a non-finite damped step is rejected by the trust region, which then damps more
        result = optx.RESULTS.where(
            finite | self.damped, optx.RESULTS.successful, optx.RESULTS.nonfinite
        )
        return (split_params(-scale * dc, s), -scale * dp), result


class StructuredGaussNewton(optx.AbstractGaussNewton):
    """Levenberg-Marquardt (or Gauss-Newton) over the Schur-complement descent.

    ``method="lm"``: :class:`SchurDescent` with Marquardt-scaled damping inside
    :class:`NoiseTolerantTrustRegion`; ``method="gn"``: undamped steps of length 1.

    Termination is scale-free: the solve stops when the full Gauss-Newton step at the current
    point is shorter than ``tol`` of its own standard deviation (``g^T H^-1 g < tol^2``) or
    promises less than ``CONVERGED_FLOOR`` of the cost, or when it promises less than the cost's
    rounding noise and has stopped shrinking (``STAGNANT_STEPS``: large, ill-conditioned reduced
    systems, where the solve's rounding keeps it above ``tol**2``), or when ``max_rejections``
    steps in a row were rejected (the damping grew by 4^k without any decrease of the cost: the
    cost is at its floating-point floor). The Cauchy criterion of optimistix on the raw
    parameters is off (``rtol = atol = 0``): parameters of very different units (pixels, pixels
    per pixel, metres) make it meaningless.
    """

    rtol: float
    atol: float
    norm: Callable[[PyTree], Array]
    descent: SchurDescent
    search: Any
    verbose: Callable[..., None]
    tol: float = eqx.field(static=True)
    max_rejections: int = eqx.field(static=True)

    def __init__(
        self,
        structure: Structure,
        tol: float = 1e-6,
        method: str = "lm",
        damping: float = 1e-4,
        max_rejections: int = 8,
        verbose: bool = False,
        fn: Callable | None = None,
        args: Any = None,
        robust: tuple[str, float] | None = None,
    ):
        if method not in ("lm", "gn"):
            raise ValueError(f"method must be 'lm' or 'gn', got {method!r}")
        self.rtol = 0.0
        self.atol = 0.0
        self.norm = optx.max_norm
        self.descent = SchurDescent(
            structure, damping=damping, damped=method == "lm", fn=fn, args=args, robust=robust
        )
        self.search = NoiseTolerantTrustRegion() if method == "lm" else optx.LearningRate(1.0)
        self.verbose = _print_verbose if verbose else _silent
        self.tol = tol
        self.max_rejections = max_rejections

    def terminate(self, fn, y, args, options, state, tags):
        # the decrement is the cost reduction the full step promises: below 1e-12 of the cost
        # it is under the rounding noise of the cost itself and no step can be verified
        cost = sum((jnp.sum(r**2) for r in jax.tree.leaves(state.f_info.residual)), 0.0)
        floor = jnp.maximum(self.tol**2, CONVERGED_FLOOR * cost)
        dec = state.descent_state.decrement
        small = dec < floor
        small |= (dec < NOISE_FLOOR * cost) & (state.descent_state.stagnant >= STAGNANT_STEPS)
        stalled = state.num_steps_since_acceptance >= self.max_rejections
        done = (small & ~state.first_step) | stalled | state.terminate
        return done, state.result


def _silent(**kwargs):
    del kwargs


def _print_verbose(**kwargs):
    keep = ("num_steps", "accepted_steps", "loss_this_step", "loss_last_accepted_step", "step_size")
    jax.debug.print(
        " ".join(f"{kwargs[k][0]}: {{{k}}}" for k in keep if k in kwargs),
        **{k: kwargs[k][1] for k in keep if k in kwargs},
    )
