"""Factorisations of the normal equations' blocks without batched LAPACK calls.

Under ``vmap`` (many independent problems) ``jnp.linalg.cholesky`` / ``cho_solve`` become
jaxlib's batched LAPACK kernels, which hung every time for >= 1000 problems on a 2-core CPU
(both XLA threads waiting in ``lapack_dtrsm_ffi``'s ``ParallelBatchMap``). The point blocks are
3x3 and the reduced systems of pairs and blocks are small, so they are factorised here in closed
form (3x3) or by a Cholesky looping over the columns (up to ``UNROLL_MAX`` unknowns): plain
elementwise code that vmaps into wide vector loops and never calls LAPACK (a ``fori_loop``,
not unrolled: the unrolled form cost ~2.6 s of an affine pair's 9 s compilation). Larger
systems (a strip's reduced system) keep LAPACK, which is then called once per problem.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

UNROLL_MAX = 32
"""Largest system factorised by the LAPACK-free Cholesky (its cost grows as n^3 per call)."""


def inv3_spd(v: Float[Array, "*b 3 3"]) -> Float[Array, "*b 3 3"]:
    """Inverse of symmetric 3x3 blocks in closed form; NaN where not positive definite
    (leading minors tested, as a Cholesky would fail)."""
    a, b, c = v[..., 0, 0], v[..., 0, 1], v[..., 0, 2]
    d, e, f = v[..., 1, 1], v[..., 1, 2], v[..., 2, 2]
    c00 = d * f - e * e
    c01 = c * e - b * f
    c02 = b * e - c * d
    c11 = a * f - c * c
    c12 = b * c - a * e
    c22 = a * d - b * b
    det = a * c00 + b * c01 + c * c02
    pd = (a > 0) & (c22 > 0) & (det > 0)
    inv_det = jnp.where(pd, 1.0 / jnp.where(pd, det, 1.0), jnp.nan)
    rows = [[c00, c01, c02], [c01, c11, c12], [c02, c12, c22]]
    return jnp.stack([jnp.stack(r, axis=-1) for r in rows], axis=-2) * inv_det[..., None, None]


def cholesky(a: Float[Array, "n n"]) -> Float[Array, "n n"]:
    """Lower Cholesky factor; NaN where ``a`` is not positive definite (as LAPACK's in jax).

    A loop over the columns (``lax.fori_loop``: one traced column, whatever ``n``) for
    ``n <= UNROLL_MAX``, else ``jnp.linalg.cholesky``."""
    n = a.shape[-1]
    if n > UNROLL_MAX:
        return jnp.linalg.cholesky(a)
    a = jnp.asarray(a)
    below = jnp.arange(n)

    def column(j, carry):  # columns < j done, the others still zero
        low, ok = carry
        row = low[j]
        piv = a[j, j] - jnp.dot(row, row)
        ljj = jnp.sqrt(jnp.where(piv > 0, piv, 1.0))
        col = jnp.where(below > j, (a[:, j] - low @ row) / ljj, 0.0)
        col = jnp.where(below == j, ljj, col)
        return low.at[:, j].set(col), ok & (piv > 0)

    low, ok = jax.lax.fori_loop(0, n, column, (jnp.zeros_like(a), jnp.array(True)))
    return jnp.where(ok, low, jnp.nan)


def cho_solve(low: Float[Array, "n n"], b: Array) -> Array:
    """``(L L^T)^-1 b`` by forward and back substitution (``lax.fori_loop`` over the rows for
    ``n <= UNROLL_MAX``)."""
    n = low.shape[-1]
    if n > UNROLL_MAX:
        return jax.scipy.linalg.cho_solve((low, True), b)
    b = jnp.asarray(b)

    def forward(i, z):  # rows < i done, the others still zero
        return z.at[i].set((b[i] - jnp.tensordot(low[i], z, axes=1)) / low[i, i])

    def back(k, x):  # rows > i done, the others still zero
        i = n - 1 - k
        return x.at[i].set((z[i] - jnp.tensordot(low[:, i], x, axes=1)) / low[i, i])

    z = jax.lax.fori_loop(0, n, forward, jnp.zeros_like(b))
    return jax.lax.fori_loop(0, n, back, jnp.zeros_like(b))
