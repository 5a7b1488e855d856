"""The block-banded reduced system: factor, solve and selected inverse against dense algebra."""

import jax.numpy as jnp
import numpy as np
import pytest

from jaxgeo.lsq import _band as band


def _banded_spd(n_blocks, width, k, rng, singular=False):
    """A random symmetric positive definite matrix with blocks within ``k`` of the diagonal,
    and its ``(a, b)`` block pairs with their values (both orders, as the reduced system's)."""
    n = n_blocks * width
    a = np.zeros((n, n))
    for i in range(n_blocks):
        for j in range(max(0, i - k), i + 1):
            x = rng.normal(size=(width, width))
            x = x + x.T if i == j else x
            a[i * width : (i + 1) * width, j * width : (j + 1) * width] = x
            a[j * width : (j + 1) * width, i * width : (i + 1) * width] = x.T
    a += np.diag(np.abs(a).sum(axis=1) + 1.0)
    if singular:  # a block row made a copy of its neighbour: rank deficient
        a[width, :] = a[0, :]
        a[:, width] = a[:, 0]
    pairs = [(i, j) for i in range(n_blocks) for j in range(n_blocks) if abs(i - j) <= k]
    vals = [a[i * width : (i + 1) * width, j * width : (j + 1) * width] for i, j in pairs]
    return a, np.array(pairs), np.array(vals)


@pytest.mark.parametrize(("n_blocks", "k", "per_super"), [(23, 2, 3), (24, 1, 1), (10, 1, 4)])
def test_factor_solve_and_selected_inverse_equal_dense(n_blocks, k, per_super):
    rng = np.random.default_rng(n_blocks)
    width = 6
    a, pairs, vals = _banded_spd(n_blocks, width, k, rng)
    # diagonal blocks given apart from the pairs, as the solve gives U and the point terms
    diag = np.zeros((n_blocks, width, width))
    s = band.assemble_band(
        jnp.asarray(diag), jnp.asarray(pairs), jnp.asarray(vals), per_super, a.shape[0]
    )
    np.testing.assert_array_equal(np.asarray(s.todense()), a)
    np.testing.assert_array_equal(np.asarray(s.diagonal()), np.diag(a))
    f = band.band_cholesky(s)
    b = rng.normal(size=(a.shape[0], 3))
    x = np.asarray(band.band_solve(f, jnp.asarray(b)))
    np.testing.assert_allclose(x, np.linalg.solve(a, b), rtol=0, atol=1e-12)
    inv = np.linalg.inv(a)
    sel = band.selected_inverse(f)
    pattern = np.asarray(s.todense()) != 0
    np.testing.assert_allclose(np.asarray(sel.todense())[pattern], inv[pattern], atol=1e-13)
    got = np.asarray(sel.blocks(jnp.asarray(pairs[:, 0]), jnp.asarray(pairs[:, 1]), width))
    want = np.array(
        [inv[i * width : (i + 1) * width, j * width : (j + 1) * width] for i, j in pairs]
    )
    np.testing.assert_allclose(got, want, atol=1e-13)
    np.testing.assert_allclose(sel.to_sparse().toarray()[pattern], inv[pattern], atol=1e-13)
    scale = rng.uniform(0.5, 2.0, a.shape[0])
    scaled = np.asarray(sel.scaled(jnp.asarray(scale)).todense())
    np.testing.assert_allclose(
        scaled, np.asarray(sel.todense()) * np.outer(scale, scale), atol=1e-13
    )


def test_singular_system_gives_nan_as_dense_cholesky():
    rng = np.random.default_rng(0)
    a, pairs, vals = _banded_spd(12, 6, 1, rng, singular=True)
    s = band.assemble_band(
        jnp.zeros((12, 6, 6)), jnp.asarray(pairs), jnp.asarray(vals), 2, a.shape[0]
    )
    f = band.band_cholesky(s)
    assert not np.all(np.isfinite(np.asarray(f.c)))
    assert not np.all(np.isfinite(np.asarray(band.selected_inverse(f).diagonal())))


def test_super_blocks_choice():
    # a strip: 6 parameters a sub-scene, neighbours tied: 4 sub-scenes a super-block
    assert band.super_blocks(80, 6, 1) == 4
    assert band.super_blocks(1280, 6, 1) == 4
    # too few super-blocks: the dense system
    assert band.super_blocks(12, 6, 1) == 0
    assert band.super_blocks(2, 6, 1) == 0
    # a wide band widens the super-blocks; all tied to all: dense
    assert band.super_blocks(200, 6, 20) == 20
    assert band.super_blocks(40, 6, 39) == 0
    assert band.block_bandwidth(np.array([[0, 0], [3, 1], [1, 3]])) == 2
