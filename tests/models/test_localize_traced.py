"""``rpc.localize`` under ``jit``/``vmap``/``grad`` runs the numpy call's iteration
(``_rpc_eval.localize_traced``): the same values and NaN flags, implicit derivatives."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxgeo import AffineBias, Biased
from jaxgeo.models import AbstractSensorModel
from tests.conftest import cube_points


def _points(rpc, n=200, seed=0):
    """Image points over the image and beyond it, heights over the cube; some unreachable
    (1e9 px) or NaN."""
    rng = np.random.default_rng(seed)
    go, gs = np.asarray(rpc.image_offset), np.asarray(rpc.image_scale)
    xy = go + rng.uniform(-1.2, 1.2, (n, 2)) * gs
    h = float(rpc.ground_offset[2]) + rng.uniform(-1.5, 1.5, n) * float(rpc.ground_scale[2])
    xy[0] = [1e9, -1e9]
    xy[1, 0] = np.nan
    h[2] = np.nan
    return xy, h


def test_jit_and_vmap_equal_the_numpy_call(pleiades):
    rpc, _ = pleiades
    xy, h = _points(rpc)
    want = rpc.localize(xy, h)
    assert isinstance(want, np.ndarray)
    jit = jax.jit(lambda m, a, b: m.localize(a, b))(rpc, xy, h)
    vmap = jax.jit(lambda m, a, b: jax.vmap(lambda p, z: m.localize(p, z))(a, b))(rpc, xy, h)
    for got in (np.asarray(jit), np.asarray(vmap)):
        np.testing.assert_array_equal(np.isnan(got), np.isnan(want))  # the same flags
        assert np.isnan(got[:3, :2]).all() and np.isfinite(got[3:]).all()
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    # the per-point Newton of the base class (the traced path before) agrees to its tolerance
    generic = np.asarray(jax.jit(lambda a, b: AbstractSensorModel.localize(rpc, a, b))(xy, h))
    ok = np.isfinite(want[:, 0])
    np.testing.assert_allclose(generic[ok], want[ok], rtol=0, atol=1e-11)


def test_guess_and_biased_model(pleiades):
    rpc, _ = pleiades
    g = cube_points(rpc, 50, seed=11, fraction=0.8)
    xy = np.asarray(rpc.project(g))
    guess = g[:, :2] + 1e-3
    guess[4] = np.nan  # a NaN start: that point is NaN
    out = np.asarray(jax.jit(lambda a, b, c: rpc.localize(a, b, c))(xy, g[:, 2], guess))
    assert np.isnan(out[4, :2]).all()
    np.testing.assert_allclose(np.delete(out, 4, 0), np.delete(g, 4, 0), rtol=0, atol=1e-9)
    biased = Biased(rpc, AffineBias([3.0, -2.0], [[1e-4, 0.0], [0.0, -1e-4]]))
    xy_b = np.asarray(biased.project(g))
    back = np.asarray(jax.jit(lambda m, a, b: m.localize(a, b))(biased, xy_b, g[:, 2]))
    np.testing.assert_allclose(back, g, rtol=0, atol=1e-9)


def test_gradients_are_the_implicit_ones(pleiades):
    """First derivatives: the inverse of the projection's (image, height and model); second
    derivatives (through the derivative rule itself) against central differences."""
    rpc, _ = pleiades
    g = cube_points(rpc, 2, seed=12, fraction=0.7)
    xy, h = jnp.asarray(rpc.project(g)), jnp.asarray(g[:, 2])

    def loc(p, z):
        return rpc.localize(p, z)[:2]

    jac = jax.jit(jax.jacfwd(loc))(xy[0], h[0])
    np.testing.assert_allclose(jac @ rpc.jacobian(g[0])[:, :2], np.eye(2), atol=1e-9)
    rev = jax.jit(jax.jacrev(loc))(xy[0], h[0])
    np.testing.assert_allclose(rev, jac, rtol=1e-12, atol=1e-18)
    # d(lon, lat)/dh: moving the height along the line of sight keeps the projection
    dh = jax.jit(jax.jacfwd(loc, argnums=1))(xy[0], h[0])
    proj = rpc.jacobian(g[0])
    np.testing.assert_allclose(proj[:, :2] @ dh + proj[:, 2], 0.0, atol=1e-9)
    # second order: the derivative of the Jacobian against central differences of it
    hess = jax.jit(jax.jacfwd(jax.jacfwd(loc)))(xy[0], h[0])
    eps = 0.5  # px: the Jacobian of an RPC is smooth on this scale
    for k in range(2):
        step = jnp.zeros(2).at[k].set(eps)
        fd = (jax.jit(jax.jacfwd(loc))(xy[0] + step, h[0]) - jax.jit(jax.jacfwd(loc))(
            xy[0] - step, h[0]
        )) / (2 * eps)  # fmt: skip
        np.testing.assert_allclose(hess[:, :, k], fd, rtol=1e-4, atol=1e-16)


def test_nan_point_does_not_poison_the_model_gradient(pleiades):
    rpc, _ = pleiades
    xy, h = _points(rpc, n=6, seed=3)
    leaves = jax.tree.leaves(jax.grad(lambda m: jnp.nansum(m.localize(xy, h)[:, :2]))(rpc))
    assert all(np.all(np.isfinite(np.asarray(x))) for x in leaves)


@pytest.mark.parametrize("shape", [(), (3,), (2, 1, 2)])
def test_batch_shapes_broadcast(pleiades, shape):
    rpc, _ = pleiades
    n = int(np.prod(shape, dtype=int))
    g = cube_points(rpc, n, seed=13).reshape(*shape, 3)
    xy = np.asarray(rpc.project(g))
    out = jax.jit(lambda a, b: rpc.localize(a, b))(xy, g[..., 2])
    assert out.shape == (*shape, 3)
    np.testing.assert_allclose(out, g, rtol=0, atol=1e-9)
    assert jax.jit(lambda a: rpc.localize(a, 100.0))(xy).shape == (*shape, 3)


def test_traced_chunks_equal_one_call(pleiades, monkeypatch):
    """Over ``CHUNK`` points the traced path runs chunk by chunk (``lax.map``), as the numpy
    path does: the same values and flags as one whole-array iteration."""
    from jaxgeo.models import _rpc_eval

    rpc, _ = pleiades
    xy, h = _points(rpc, n=200, seed=5)
    whole = np.asarray(jax.jit(lambda a, b: rpc.localize(a, b))(xy, h))
    monkeypatch.setattr(_rpc_eval, "CHUNK", 64)  # 4 chunks, the last one padded
    chunked = np.asarray(jax.jit(lambda a, b: rpc.localize(a, b))(xy, h))
    np.testing.assert_array_equal(chunked, whole)
    vmapped = jax.jit(lambda a, b: jax.vmap(lambda p, z: rpc.localize(p, z))(a, b))(xy, h)
    np.testing.assert_array_equal(np.asarray(vmapped), whole)
