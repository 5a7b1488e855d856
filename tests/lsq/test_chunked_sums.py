"""Per-block sums of products formed a chunk of rows at a time (``_schur.chunked_segment_sum``:
the normal equations, the reduced camera system and the covariance of large problems) equal
the sums formed at once, in a whole solve too (dense and block-banded reduced system)."""

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxgeo.lsq import RESULTS, SolverConfig, _schur, solve
from jaxgeo.lsq import _band as band


@pytest.mark.parametrize(("k", "chunk"), [(50, 7), (49, 7), (5, 16), (64, 64)])
def test_chunked_segment_sum_equals_segment_sum(k, chunk):
    rng = np.random.default_rng(k)
    x = jnp.asarray(rng.normal(size=(k, 3, 2)))
    y = jnp.asarray(rng.normal(size=(k, 2)))
    seg = jnp.asarray(rng.integers(0, 4, k))
    rows = jnp.arange(k)

    def values(i):
        return jnp.einsum("kpj,kj->kp", x[i], y[i]), y[i] ** 2

    want = (
        jax.ops.segment_sum(jnp.einsum("kpj,kj->kp", x, y), seg, 4),
        jax.ops.segment_sum(y**2, rows, k),
    )
    got = _schur.chunked_segment_sum(values, (rows,), (seg, rows), (4, k), chunk=chunk)
    for a, b in zip(got, want, strict=True):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-14, atol=1e-14)
    one = _schur.chunked_segment_sum(lambda i: y[i], (rows,), seg, 4, chunk=chunk)
    np.testing.assert_allclose(one, jax.ops.segment_sum(y, seg, 4), rtol=1e-14, atol=1e-14)


def _solve_with_chunk(problem, chunk, monkeypatch):
    monkeypatch.setattr(_schur, "SUM_CHUNK", chunk)
    # a new jitted function: traced again with this chunk size
    return eqx.filter_jit(lambda p, s: solve(p, s))(problem, SolverConfig(loss="l2"))


@pytest.mark.parametrize("banded", [False, True])
def test_solve_in_chunks_equals_solve_at_once(block_problem, monkeypatch, banded):
    problem = block_problem
    s = problem.structure
    if banded:  # the same block solved through the block-banded reduced system
        g = band.block_bandwidth(np.asarray(s.pair_blocks))
        problem = dataclasses.replace(problem, structure=dataclasses.replace(s, band=g))
    m, k = int(s.obs_point.shape[0]), int(s.pair_a.shape[0])
    assert m > 7 and k > 7  # both sums run in several chunks below
    want = _solve_with_chunk(problem, 1 << 20, monkeypatch)
    got = _solve_with_chunk(problem, 7, monkeypatch)
    assert bool(want.result == RESULTS.successful) and bool(got.result == RESULTS.successful)
    assert int(got.num_steps) == int(want.num_steps)
    q = (lambda x: x.todense()) if banded else (lambda x: x)
    pairs = [
        (got.theta[0], want.theta[0]),
        (got.ground, want.ground),
        (q(got.q_params), q(want.q_params)),
        (got.q_points, want.q_points),
        (got.redundancy_image, want.redundancy_image),
        (got.s0, want.s0),
    ]
    for a, b in pairs:
        a, b = np.asarray(a), np.asarray(b)
        np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-12 * max(1.0, np.abs(b).max()))
