"""LAPACK-free small factorisations (closed-form 3x3 inverse, unrolled Cholesky) against numpy."""

import jax
import numpy as np

from jaxgeo.lsq._factor import cho_solve, cholesky, inv3_spd


def _spd(rng, n, batch=()):
    a = rng.normal(size=(*batch, n, n))
    return a @ np.swapaxes(a, -1, -2) + n * np.eye(n)


def test_inv3_matches_numpy_and_flags_non_positive_definite():
    rng = np.random.default_rng(0)
    v = _spd(rng, 3, (50,))
    np.testing.assert_allclose(inv3_spd(v), np.linalg.inv(v), rtol=1e-12, atol=1e-14)
    bad = np.diag([1.0, -1.0, 1.0])[None]
    assert np.all(np.isnan(np.asarray(inv3_spd(bad))))


def test_unrolled_cholesky_solves_like_lapack_under_vmap():
    rng = np.random.default_rng(1)
    a = _spd(rng, 13, (4,))
    b = rng.normal(size=(4, 13))
    x = jax.jit(jax.vmap(lambda m, r: cho_solve(cholesky(m), r)))(a, b)
    np.testing.assert_allclose(x, np.linalg.solve(a, b[..., None])[..., 0], rtol=1e-10)
    low = jax.jit(cholesky)(a[0])
    np.testing.assert_allclose(low, np.linalg.cholesky(a[0]), rtol=1e-12, atol=1e-14)
    not_pd = a[0] - 100.0 * np.eye(13)
    assert np.all(np.isnan(np.asarray(jax.jit(cholesky)(not_pd))))
