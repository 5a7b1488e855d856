"""Block-banded reduced camera systems (strips): factorisation, solve and selected inverse.

A strip's sub-scenes are tied only to their neighbours, so its reduced camera system
``S = U - W V^-1 W^T`` has non-zero blocks only within ``k`` blocks of the diagonal. Grouping
``g >= k`` consecutive parameter blocks into a *super-block* of ``G = g P`` parameters makes it
block tridiagonal::

    S = [ D_0  E_1^T            ]        L = [ C_0              ]
        [ E_1  D_1  E_2^T       ]            [ M_1  C_1         ]
        [      E_2  D_2  ...    ]            [      M_2  C_2    ]

with the Cholesky factor ``L`` block bidiagonal: ``M_j = E_j C_{j-1}^-T``,
``C_j = chol(D_j - M_j M_j^T)``, one ``lax.scan`` over the ``J`` super-blocks. The cofactors the
solve reports (the diagonal, each observation's block, each pair of blocks that share a point)
all lie inside this pattern, and the inverse restricted to it (the *selected inverse*) follows
from ``L`` by the backward recurrence of Takahashi et al. (1973)::

    Sigma_{j,j+1} = -C_j^-T M_{j+1}^T Sigma_{j+1,j+1}
    Sigma_{j,j}   =  C_j^-T (C_j^-1 - M_{j+1}^T Sigma_{j+1,j})

Time and memory grow linearly with the number of sub-scenes (``J`` factorisations of ``G x G``),
not as ``N^3`` / ``N^2`` like the dense system. A singular system gives NaN, as the dense
Cholesky does.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.linalg import solve_triangular
from jaxtyping import Array, Float, Int

SUPER_PARAMS = 24
"""Fewest parameters in a super-block (4 sub-scenes of 6 parameters). The 80-scene strip's
compiled two-level call takes the same time (within 0.01 s of noise, 0.09-0.10 s) with 6 to 48;
96 is slower (0.12 s), as is the dense system (0.13 s); fewer parameters mean fewer flops
(``B g^2 P^3`` for ``B`` blocks), more mean fewer scan steps."""
MIN_SUPER_BLOCKS = 4
"""Fewest super-blocks for which the banded solve is used (fewer: the dense system is as cheap)."""


def super_blocks(n_blocks: int, width: int, bandwidth: int) -> int:
    """Parameter blocks per super-block for a system of ``n_blocks`` blocks of ``width``
    parameters whose non-zero blocks lie within ``bandwidth`` of the diagonal; 0 when the
    banded solve does not pay (too few super-blocks)."""
    if width == 0 or n_blocks == 0:
        return 0
    g = max(bandwidth, 1, -(-SUPER_PARAMS // width))
    return g if -(-n_blocks // g) >= MIN_SUPER_BLOCKS else 0


def block_bandwidth(pair_blocks: np.ndarray) -> int:
    """Largest ``|a - b|`` over the block pairs ``(Q, 2)`` that share a point (0: none)."""
    pb = np.asarray(pair_blocks).reshape(-1, 2)
    return int(np.max(np.abs(pb[:, 0] - pb[:, 1]), initial=0))


class Band(eqx.Module):
    """A symmetric matrix stored as block-tridiagonal super-blocks (or the selected inverse of
    one: the same pattern of another matrix).

    ``diag`` (J, G, G) the diagonal super-blocks, ``sub`` (J, G, G) ``sub[j] = A[j, j - 1]``
    (``sub[0]`` zero); ``size`` the number of rows that are real (the rest pad the last
    super-block with an identity).
    """

    diag: Float[Array, "J G G"]
    sub: Float[Array, "J G G"]
    size: int = eqx.field(static=True)

    @property
    def shape(self) -> tuple[int, int]:
        return (self.size, self.size)

    def diagonal(self) -> Float[Array, " n"]:
        """The diagonal (``size``,)."""
        return jnp.diagonal(self.diag, axis1=1, axis2=2).reshape(-1)[: self.size]

    def todense(self) -> Float[Array, "n n"]:
        """The dense matrix (``size``, ``size``), zero outside the pattern (diagnostics, tests)."""
        j, g = self.diag.shape[0], self.diag.shape[1]
        a = jnp.zeros((j, g, j, g))
        idx = jnp.arange(j)
        a = a.at[idx, :, idx, :].set(self.diag)
        a = a.at[idx[1:], :, idx[:-1], :].set(self.sub[1:])
        a = a.at[idx[:-1], :, idx[1:], :].set(jnp.swapaxes(self.sub[1:], 1, 2))
        return a.reshape(j * g, j * g)[: self.size, : self.size]

    def to_sparse(self):
        """The entries within the pattern as a ``scipy.sparse.csr_array`` (``size``, ``size``),
        host side; entries outside it were not computed and read as zero."""
        import scipy.sparse as sp

        d, s = np.asarray(self.diag), np.asarray(self.sub)
        j, g = d.shape[0], d.shape[1]
        rows, cols, vals = [], [], []
        base = np.arange(g)
        for k in range(j):
            r = k * g + base
            rows.append(np.repeat(r, g))
            cols.append(np.tile(r, g))
            vals.append(d[k].reshape(-1))
            if k:
                c = (k - 1) * g + base
                for a, b, v in ((r, c, s[k]), (c, r, s[k].T)):
                    rows.append(np.repeat(a, g))
                    cols.append(np.tile(b, g))
                    vals.append(v.reshape(-1))
        rows, cols, vals = (np.concatenate(x) for x in (rows, cols, vals))
        keep = (rows < self.size) & (cols < self.size)
        shape = (self.size, self.size)
        return sp.csr_array((vals[keep], (rows[keep], cols[keep])), shape=shape)

    def scaled(self, scale: Float[Array, " n"]) -> Band:
        """``diag(scale) A diag(scale)``."""
        s = _pad(scale, self.diag.shape[0] * self.diag.shape[1]).reshape(self.diag.shape[:2])
        prev = jnp.concatenate([jnp.zeros_like(s[:1]), s[:-1]])
        return Band(
            self.diag * s[:, :, None] * s[:, None, :],
            self.sub * s[:, :, None] * prev[:, None, :],
            self.size,
        )

    def blocks(self, a: Int[Array, " k"], b: Int[Array, " k"], width: int) -> Float[Array, "k P P"]:
        """The ``(width, width)`` blocks ``A[block a, block b]`` (parameter block ``i`` = rows
        ``i * width ...``); both blocks in one super-block or in neighbouring ones."""
        j, big = self.diag.shape[0], self.diag.shape[1]
        g = big // width
        d = self.diag.reshape(j, g, width, g, width)
        s = self.sub.reshape(j, g, width, g, width)
        ja, la, jb, lb = a // g, a % g, b // g, b % g
        same = d[ja, la, :, lb, :]
        below = s[ja, la, :, lb, :]  # a one super-block below b
        above = jnp.swapaxes(s[jb, lb, :, la, :], -1, -2)
        return jnp.where(
            (ja == jb)[:, None, None], same, jnp.where((ja > jb)[:, None, None], below, above)
        )


class BandFactor(eqx.Module):
    """Cholesky factor of a :class:`Band`: ``c`` (J, G, G) lower factors of the pivots, ``m``
    (J, G, G) the sub-diagonal blocks ``M_j = E_j C_{j-1}^-T`` (``m[0]`` zero)."""

    c: Float[Array, "J G G"]
    m: Float[Array, "J G G"]
    size: int = eqx.field(static=True)


def assemble_band(
    diag_blocks: Float[Array, "B P P"],
    pair_blocks: Int[Array, "Q 2"],
    pair_values: Float[Array, "Q P P"],
    per_super: int,
    size: int,
) -> Band:
    """The :class:`Band` of ``blockdiag(diag_blocks) + sum_q E(a_q, b_q) pair_values[q]`` (a
    pair adds its block at block row ``a``, block column ``b``; pairs above the diagonal are
    the transposes of those below and are left out), ``per_super`` blocks per super-block;
    padding rows get an identity."""
    n_blocks, width = diag_blocks.shape[0], diag_blocks.shape[1]
    g = per_super
    j = -(-n_blocks // g)
    pad = j * g - n_blocks
    eye = jnp.eye(width, dtype=diag_blocks.dtype)
    diag_blocks = jnp.concatenate([diag_blocks, jnp.broadcast_to(eye, (pad, width, width))])
    d = diag_blocks.reshape(j, g, width, width)
    # block-diagonal super-blocks: (J, g, P, g, P) with d on the (l, l) positions
    dense = jnp.einsum("jlpq,lm->jlpmq", d, jnp.eye(g, dtype=d.dtype))
    t = jnp.concatenate([jnp.zeros_like(dense), dense], axis=3)  # columns: sub | diag
    a, b = pair_blocks[:, 0], pair_blocks[:, 1]
    ja, la, jb, lb = a // g, a % g, b // g, b % g
    col = lb + g * (1 - (ja - jb))  # sub: lb, diag: g + lb, above (ja < jb): out of range
    col = jnp.where(ja < jb, 2 * g, col)
    t = t.at[ja, la, :, col, :].add(pair_values, mode="drop")
    t = t.reshape(j, g * width, 2, g * width)
    sub = t[:, :, 0].at[0].set(0.0)
    return Band(t[:, :, 1], sub, size)


def band_cholesky(a: Band) -> BandFactor:
    """Block-bidiagonal Cholesky factor of ``a`` (one ``lax.scan``; NaN if not positive
    definite)."""

    def step(c_prev, dm):
        d, e = dm
        m = solve_triangular(c_prev, e.T, lower=True).T  # E_j C_{j-1}^-T
        c = jnp.linalg.cholesky(d - m @ m.T)
        return c, (c, m)

    eye = jnp.eye(a.diag.shape[1], dtype=a.diag.dtype)
    _, (c, m) = jax.lax.scan(step, eye, (a.diag, a.sub))
    return BandFactor(c, m, a.size)


def _pad(x: Array, n: int) -> Array:
    return jnp.concatenate([x, jnp.zeros((n - x.shape[0], *x.shape[1:]), x.dtype)])


def band_solve(f: BandFactor, b: Float[Array, "n ..."]) -> Float[Array, "n ..."]:
    """``A^-1 b`` from the factor of ``A`` (forward, then backward scan)."""
    j, g = f.c.shape[0], f.c.shape[1]
    rest = b.shape[1:]
    bb = _pad(b, j * g).reshape(j, g, *rest)

    def forward(z_prev, cmb):
        c, m, bj = cmb
        z = solve_triangular(c, bj - jnp.tensordot(m, z_prev, axes=1), lower=True)
        return z, z

    _, z = jax.lax.scan(forward, jnp.zeros((g, *rest), b.dtype), (f.c, f.m, bb))
    m_next = jnp.concatenate([f.m[1:], jnp.zeros_like(f.m[:1])])

    def backward(x_next, cmz):
        c, m, zj = cmz
        x = solve_triangular(c, zj - jnp.tensordot(m.T, x_next, axes=1), lower=True, trans=1)
        return x, x

    _, x = jax.lax.scan(backward, jnp.zeros((g, *rest), b.dtype), (f.c, m_next, z), reverse=True)
    return x.reshape(j * g, *rest)[: b.shape[0]]


def selected_inverse(f: BandFactor) -> Band:
    """``A^-1`` on the pattern of ``A`` (its diagonal and first sub-diagonal super-blocks)
    from the factor of ``A`` (Takahashi's backward recurrence, one scan)."""
    eye = jnp.eye(f.c.shape[1], dtype=f.c.dtype)
    m_next = jnp.concatenate([f.m[1:], jnp.zeros_like(f.m[:1])])

    def step(sig_next, cm):
        c, m = cm
        cinv = solve_triangular(c, eye, lower=True)  # C_j^-1
        upper = -solve_triangular(c, m.T @ sig_next, lower=True, trans=1)  # Sigma_{j,j+1}
        sig = solve_triangular(c, cinv - m.T @ upper.T, lower=True, trans=1)
        sig = 0.5 * (sig + sig.T)
        return sig, (sig, upper)

    _, (diag, upper) = jax.lax.scan(step, jnp.zeros_like(eye), (f.c, m_next), reverse=True)
    sub = jnp.concatenate([jnp.zeros_like(upper[:1]), jnp.swapaxes(upper[:-1], 1, 2)])
    return Band(diag, sub, f.size)
