"""The rational function model against GDAL, round trips, gradients, NaN and domain handling."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads
from rasterio.transform import RPCTransformer

from jaxgeo import RPC
from jaxgeo.models._rpc import A_TO_B, B_TO_A, RPC00A_TERMS, RPC00B_TERMS, from_rpc00b
from tests.conftest import REFERENCE_GROUND, REFERENCE_IMAGE, cube_points
from tests.typecheck import unchecked


def _gdal_project(rpcs, ground):
    with RPCTransformer(rpcs) as t:
        rows, cols = t.rowcol(ground[:, 0], ground[:, 1], zs=ground[:, 2], op=lambda v: v)
    return np.stack([np.asarray(cols), np.asarray(rows)], axis=-1) - 0.5


def test_reference_point(pleiades):
    rpc, _ = pleiades
    got = np.asarray(rpc.project(np.array(REFERENCE_GROUND)))
    assert np.abs(got - REFERENCE_IMAGE).max() < 1e-2


def test_projection_equals_gdal(pleiades):
    rpc, rpcs = pleiades
    ground = cube_points(rpc, 3000, seed=1)
    ours = np.asarray(eqx.filter_jit(RPC.project)(rpc, ground))
    assert np.abs(ours - _gdal_project(rpcs, ground)).max() < 1e-6


def test_localize_project_round_trip_over_validity_cube(pleiades):
    rpc, _ = pleiades
    rng = np.random.default_rng(2)
    # image points over the whole image domain, heights over the whole cube
    n = 2000
    img = np.asarray(rpc.image_offset) + rng.uniform(-1, 1, (n, 2)) * np.asarray(rpc.image_scale)
    h = np.asarray(rpc.ground_offset)[2] + rng.uniform(-1, 1, n) * np.asarray(rpc.ground_scale)[2]
    ground = np.asarray(rpc.localize(img, h))
    assert np.all(np.isfinite(ground))
    np.testing.assert_array_equal(ground[:, 2], h)
    # Newton converges below 1e-9 px (the bar for localize), so the round trip is tight
    assert np.abs(np.asarray(rpc.project(ground)) - img).max() < 1e-9
    # project -> localize -> project
    g2 = cube_points(rpc, n, seed=3)
    p2 = np.asarray(rpc.project(g2))
    back = np.asarray(rpc.localize(p2, g2[:, 2]))
    assert np.abs(np.asarray(rpc.project(back)) - p2).max() < 1e-6
    assert np.abs(back[:, :2] - g2[:, :2]).max() < 1e-10  # degrees


@pytest.mark.parametrize("shape", [(), (1,), (3, 1, 2)])
def test_batch_shapes(pleiades, shape):
    rpc, _ = pleiades
    g = cube_points(rpc, int(np.prod(shape, dtype=int)), seed=4).reshape(*shape, 3)
    p = rpc.project(g)
    assert p.shape == (*shape, 2)
    back = rpc.localize(p, g[..., 2])
    assert back.shape == (*shape, 3)
    np.testing.assert_allclose(back, g, rtol=0, atol=1e-8)
    # broadcast a scalar height over the batch
    assert rpc.localize(p, 100.0).shape == (*shape, 3)


def test_nan_in_nan_out_for_that_point_only(pleiades):
    rpc, _ = pleiades
    g = cube_points(rpc, 5, seed=5)
    p = np.asarray(rpc.project(g))
    g_bad = g.copy()
    g_bad[2, 1] = np.nan
    p_bad = np.asarray(rpc.project(g_bad))
    assert np.all(np.isnan(p_bad[2])) and np.all(np.isfinite(np.delete(p_bad, 2, 0)))
    np.testing.assert_array_equal(np.delete(p_bad, 2, 0), np.delete(p, 2, 0))
    p_in = p.copy()
    p_in[1, 0] = np.nan
    h = g[:, 2].copy()
    h[3] = np.nan
    out = np.asarray(rpc.localize(p_in, h))
    assert np.all(np.isnan(out[1])) and np.all(np.isnan(out[3]))
    good = [0, 2, 4]
    np.testing.assert_allclose(out[good], g[good], rtol=0, atol=1e-9)
    # and the gradient of the good points is not poisoned by the bad ones
    grad = jax.grad(lambda x: jnp.nansum(rpc.localize(x, h)[jnp.array(good)]))(jnp.asarray(p_in))
    assert np.all(np.isfinite(np.asarray(grad)[good]))


def test_validity_domain(pleiades):
    rpc, _ = pleiades
    g = cube_points(rpc, 4, seed=6, fraction=0.9)
    outside = g.copy()
    outside[1, 0] += 1.5 * float(rpc.ground_scale[0])
    outside[2, 2] -= 2.5 * float(rpc.ground_scale[2])
    outside[3, 1] = np.nan
    mask = np.asarray(rpc.in_domain(outside))
    np.testing.assert_array_equal(mask, [True, False, False, False])
    assert np.asarray(rpc.in_domain(outside[1], margin=1.0))
    cube = np.asarray(rpc.validity_cube())
    np.testing.assert_allclose(cube.mean(0), rpc.ground_offset)
    assert np.asarray(rpc.image_in_domain(rpc.project(g))).all()


def test_term_orders(pleiades):
    rpc, _ = pleiades
    # the two orders name the same 20 monomials
    assert sorted("".join(sorted(t)) for t in RPC00A_TERMS) == sorted(
        "".join(sorted(t)) for t in RPC00B_TERMS
    )
    np.testing.assert_array_equal(A_TO_B[B_TO_A], np.arange(20))
    assert RPC00B_TERMS[10] == "PLH" and RPC00A_TERMS[7] == "LPH"
    vendor = rpc.to_vendor(order="RPC00A")
    as_a = RPC.from_vendor(**vendor, order="RPC00A")
    g = cube_points(rpc, 100, seed=7)
    np.testing.assert_array_equal(np.asarray(as_a.project(g)), np.asarray(rpc.project(g)))
    # an RPC00A file read as if it were RPC00B is wrong: the order matters
    wrong = RPC.from_vendor(**vendor, order="RPC00B")
    assert np.abs(np.asarray(wrong.project(g)) - np.asarray(rpc.project(g))).max() > 1e-3
    assert np.array_equal(from_rpc00b(rpc.num, "RPC00A")[..., A_TO_B], np.asarray(rpc.num))
    with pytest.raises(ValueError, match="term order"):
        RPC.from_vendor(**vendor, order="RPC00C")


def test_shape_errors(pleiades):
    rpc, _ = pleiades
    with pytest.raises(ValueError, match="last axis of size 3"):
        unchecked(RPC.project)(rpc, np.zeros((4, 2)))
    with pytest.raises(ValueError, match="last axis of size 2"):
        unchecked(RPC.localize)(rpc, np.zeros((4, 3)), 0.0)
    # the library's ValueError, or the test suite's type checker (TypeError) first: both name it
    with pytest.raises((ValueError, TypeError), match="num"):
        RPC(np.zeros((2, 19)), np.ones((2, 20)), np.zeros(3), np.ones(3), np.zeros(2), np.ones(2))


def test_gradients_project(pleiades):
    rpc, _ = pleiades
    g = jnp.asarray(cube_points(rpc, 3, seed=8, fraction=0.8))
    check_grads(rpc.project, (g,), order=2, modes=("fwd", "rev"), eps=1e-6, atol=1e-4, rtol=1e-4)
    params, static = eqx.partition(rpc, eqx.is_inexact_array)

    def f(p):
        return eqx.combine(p, static).project(g)

    check_grads(f, (params,), order=2, modes=("fwd", "rev"), eps=1e-7, atol=1e-3, rtol=1e-4)


def test_gradients_localize(pleiades):
    rpc, _ = pleiades
    g = cube_points(rpc, 3, seed=9, fraction=0.8)
    img = jnp.asarray(rpc.project(g))
    h = jnp.asarray(g[:, 2])
    # first order (the solver's Jacobians); jitted, so each transform is one compiled program
    # instead of hundreds of op-by-op ones (order 2 took ~4 min of compilation in the suite)
    check_grads(
        jax.jit(lambda x, hh: rpc.localize(x, hh)), (img, h), order=1, modes=("fwd", "rev"),
        eps=1e-3, atol=1e-9, rtol=1e-4,
    )  # fmt: skip
    # implicit-function derivative equals the inverse of the projection Jacobian
    jac_loc = jax.jacfwd(lambda x: rpc.localize(x, h[0])[:2])(img[0])
    jac_proj = rpc.jacobian(rpc.localize(img[0], h[0]))[:, :2]
    np.testing.assert_allclose(jac_loc @ jac_proj, np.eye(2), atol=1e-9)
    params, static = eqx.partition(rpc, eqx.is_inexact_array)

    def f(p):
        return eqx.combine(p, static).localize(img, h)

    check_grads(
        jax.jit(f), (params,), order=1, modes=("fwd", "rev"), eps=1e-8, atol=1e-9, rtol=1e-3
    )


def test_which_calls_return_numpy_and_which_jax(pleiades):
    """As documented in ``jaxgeo.models``: an RPC's ``project`` / ``localize`` return numpy for
    numpy (or list) input, JAX for JAX input or under a transformation; every other model
    returns JAX arrays."""
    from jaxgeo import Biased, ShiftBias

    rpc = pleiades[0]
    g = np.asarray(rpc.reference_ground())[None].repeat(4, axis=0)
    assert type(rpc.project(g)) is np.ndarray
    assert type(rpc.project(g.tolist())) is np.ndarray
    assert isinstance(rpc.project(jnp.asarray(g)), jax.Array)
    assert type(rpc.localize(np.zeros((4, 2)), 100.0)) is np.ndarray
    assert isinstance(rpc.localize(jnp.zeros((4, 2)), 100.0), jax.Array)
    np.testing.assert_array_equal(rpc.project(g), rpc.project(jnp.asarray(g)))
    assert isinstance(jax.jit(lambda x: rpc.project(x))(g), jax.Array)
    assert isinstance(jax.jit(lambda x: rpc.localize(x, 100.0))(np.zeros((4, 2))), jax.Array)
    assert isinstance(Biased(rpc, ShiftBias()).project(g), jax.Array)
