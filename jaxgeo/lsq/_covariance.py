"""Covariance: cofactor matrices of the unknowns, redundancy numbers, and the singularity test.

The inverse of the normal matrix by blocks at the solution (``Q_cc = S^-1`` of the reduced
camera system, the 3x3 point blocks, and the diagonal of ``J Q J^T`` per observation), and from
it the variance inflation ``Q_ii H_ii`` of every unknown: 1 for an uncorrelated unknown, huge
or NaN for one the observations do not determine (:func:`undetermined_unknowns`).
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from . import _band as band
from . import _schur
from ._factor import cho_solve, cholesky
from ._problem import Problem, Structure
from ._schur import (
    Jacobians,
    NormalBlocks,
    chunked_segment_sum,
    reduced_system,
    u_diagonal,
    wv,
)

INFLATION_MAX = 1e6
"""An unknown whose variance is this many times that of an uncorrelated one (its sigma amplified
1000x by correlations) is numerically undetermined; minimal legitimate set-ups stay below ~1e3."""


class Covariance(eqx.Module):
    """Cofactor matrices (a priori sigma 1) of the unknowns in the solver's variables.

    ``cc`` (N, N) camera parameters (a :class:`~._band.Band`, the inverse on the pattern of the
    reduced system only, when it is banded); ``pp`` (n, 3, 3) points (ENU metres); ``obs``
    (M, 2) and ``ground`` (c, 3): the diagonal of ``J Q J^T`` per observation (1 - redundancy
    number);
    ``inflation_params`` (N,) / ``inflation_points`` (n, 3): ``Q_ii H_ii``, 1 for an
    uncorrelated unknown, huge (or NaN) for one the observations do not determine.
    """

    cc: Float[Array, "N N"] | band.Band
    pp: Float[Array, "n 3 3"]
    obs: Float[Array, "M 2"]
    ground: Float[Array, "c 3"]
    inflation_params: Float[Array, " N"]
    inflation_points: Float[Array, "n 3"]


def cofactors(jac: Jacobians, blocks: NormalBlocks, s: Structure) -> Covariance:
    """Inverse of the normal matrix, by blocks: ``Q_cc = S^-1``, point blocks, and the
    diagonal of ``J Q J^T`` per observation (for redundancy numbers / standardised residuals)."""
    n = s.n_params
    big_s, vinv = reduced_system(blocks, s, 0.0)
    if s.band:  # the inverse only where the pattern of S is (linear in the sub-scenes)
        qcc = band.selected_inverse(band.band_cholesky(big_s))
        ob = s.obs_block

        def q_blocks(a, b):  # Q_cc blocks (k, P, P) between the parameters of a and of b
            return qcc.blocks(ob[a], ob[b], s.width)

        cc, diag_q = qcc, qcc.diagonal()
    else:
        qcc = cho_solve(cholesky(big_s), jnp.eye(n + 1))

        def q_blocks(a, b):
            pa, pb = s.obs_params[a], s.obs_params[b]
            return qcc[pa[:, :, None], pb[:, None, :]]

        cc, diag_q = qcc[:n, :n], jnp.diagonal(qcc)[:n]
    m = s.obs_point.shape[0]

    def per_pair(a, b):  # pairs of observations of one point: their Q_cc block with W V^-1
        qab = q_blocks(a, b)
        ya, yb = wv(blocks, vinv, s, a), wv(blocks, vinv, s, b)
        t = jnp.einsum("kpi,kpq,kqj->kij", ya, qab, yb)
        return t, -jnp.einsum("kpq,kqj->kpj", qab, yb)

    # summed per point and per observation over chunks of the pairs: no (K, P, P) temporary
    t, qcp = chunked_segment_sum(
        per_pair, (s.pair_a, s.pair_b), (s.pair_point, s.pair_a), (s.n_points, m)
    )
    qpp = vinv + t
    jc, jp = jac.jc, jac.jp

    def per_obs(i):  # the diagonal of J Q J^T, observation by observation
        return (
            jnp.einsum("mkp,mpq,mkq->mk", jc[i], q_blocks(i, i), jc[i])
            + 2.0 * jnp.einsum("mkp,mpj,mkj->mk", jc[i], qcp[i], jp[i])
            + jnp.einsum("mki,mij,mkj->mk", jp[i], qpp[s.obs_point[i]], jp[i])
        )

    rows = jnp.arange(m)
    fit = per_obs(rows) if m <= _schur.SUM_CHUNK else chunked_segment_sum(per_obs, (rows,), rows, m)
    gfit = jnp.einsum("cki,cij,ckj->ck", jac.jg, qpp[s.ground_point], jac.jg)
    infl_c = diag_q * u_diagonal(blocks, s)
    infl_p = jnp.diagonal(qpp, axis1=1, axis2=2) * jnp.diagonal(blocks.v, axis1=1, axis2=2)
    return Covariance(
        cc=cc,
        pp=qpp,
        obs=fit,
        ground=gfit,
        inflation_params=infl_c,
        inflation_points=infl_p,
    )


def undetermined_unknowns(
    problem: Problem,
    q_params: Float[Array, "N N"] | band.Band,
    inflation_params: Float[Array, " N"],
    inflation_points: Float[Array, "n 3"],
) -> tuple[Bool[Array, " N"], Bool[Array, " n"]]:
    """``(parameters, points)`` masks of the unknowns the normal equations do not determine
    (inflation above ``INFLATION_MAX`` or NaN); jit and vmap safe.

    A parameter with a prior is determined by it, however weakly the observations see it
    (e.g. the common bias of a strip tied only to itself): only a variance above the prior's
    (impossible in exact arithmetic) is then a numerical failure.
    """
    wt = jnp.concatenate(
        [
            w.reshape(-1) if w.shape[1] else jnp.zeros(g.n_blocks * g.n_params)
            for w, g in zip(problem.prior_weight, problem.groups, strict=True)
        ]
        + [jnp.zeros(0)]
    )
    q = q_params.diagonal() if isinstance(q_params, band.Band) else jnp.diagonal(q_params)
    has_prior = wt > 0
    prior_ok = has_prior & (q * jnp.where(has_prior, wt, 0.0) ** 2 < 1.5)
    bad_p = ~(jnp.abs(inflation_params) < INFLATION_MAX) & ~prior_ok
    bad_q = jnp.any(~(jnp.abs(inflation_points) < INFLATION_MAX), axis=1)
    return bad_p, bad_q
