"""Image-space bias corrections (eq. 2 of 000_, eq. 8-11 of 003_) composed onto an RPC."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from jaxgeo import AffineBias, Biased, ShiftBias, ShiftDriftBias
from jaxgeo.models.internal import BIAS_KINDS
from tests.conftest import cube_points

BIASES = {
    "shift": ShiftBias([3.2, -33.0]),
    "shift-drift": ShiftDriftBias([3.2, -33.0], [2e-4, -1.5e-4]),
    "affine": AffineBias([3.2, -33.0], [[1e-4, 2e-4], [-3e-5, -1.5e-4]]),
}


@pytest.mark.parametrize("kind", list(BIASES))
def test_equation_2_holds(pleiades, kind):
    rpc, _ = pleiades
    bias = BIASES[kind]
    model = Biased(rpc, bias)
    g = cube_points(rpc, 200, seed=11)
    xy = np.asarray(model.project(g))
    x, y = xy[:, 0], xy[:, 1]
    a0, m = (np.asarray(v) for v in bias.coefficients())
    b0, a0_ = a0
    (b2, b1), (a2, a1) = m
    rpc_xy = np.asarray(rpc.project(g))
    # x + B0 + B1 y + B2 x = Num_x / Den_x ;  y + A0 + A1 y + A2 x = Num_y / Den_y
    np.testing.assert_allclose(x + b0 + b1 * y + b2 * x, rpc_xy[:, 0], rtol=0, atol=1e-8)
    np.testing.assert_allclose(y + a0_ + a1 * y + a2 * x, rpc_xy[:, 1], rtol=0, atol=1e-8)
    assert BIAS_KINDS[kind] is type(bias)


def test_parameterisations_nest():
    assert (ShiftBias().n_params, ShiftDriftBias().n_params, AffineBias().n_params) == (2, 4, 6)
    _, m = ShiftDriftBias([0, 0], [1e-4, 2e-4]).coefficients()
    # drift is in line: only the y column of the matrix is non-zero
    np.testing.assert_array_equal(np.asarray(m), [[0, 1e-4], [0, 2e-4]])
    xy = jnp.array([[10.0, 20.0], [3000.0, -4.0]])
    np.testing.assert_allclose(
        ShiftBias([1.0, 2.0]).to_model(xy), AffineBias([1.0, 2.0]).to_model(xy), rtol=0, atol=0
    )


def test_003_form_is_the_same_family(pleiades):
    rpc, _ = pleiades
    a = np.array([2.0, 1e-4, -2e-4])  # S = x_m + a0 + a1 S + a2 P
    b = np.array([-5.0, 3e-5, 1e-4])
    model = Biased(rpc, AffineBias.from_image_affine(a, b))
    g = cube_points(rpc, 50, seed=12)
    s, p = np.asarray(model.project(g)).T
    xm, ym = np.asarray(rpc.project(g)).T
    np.testing.assert_allclose(s, xm + a[0] + a[1] * s + a[2] * p, rtol=0, atol=1e-8)
    np.testing.assert_allclose(p, ym + b[0] + b[1] * s + b[2] * p, rtol=0, atol=1e-8)


@pytest.mark.parametrize("kind", list(BIASES))
def test_round_trip_and_batch(pleiades, kind):
    rpc, _ = pleiades
    model = Biased(rpc, BIASES[kind])
    g = cube_points(rpc, 300, seed=13, fraction=0.9).reshape(3, 100, 3)
    p = model.project(g)
    assert p.shape == (3, 100, 2)
    back = model.localize(p, g[..., 2])
    assert np.abs(np.asarray(model.project(back)) - np.asarray(p)).max() < 1e-6
    np.testing.assert_allclose(back, g, rtol=0, atol=1e-9)


@pytest.mark.parametrize("kind", list(BIASES))
def test_gradients(pleiades, kind):
    rpc, _ = pleiades
    model = Biased(rpc, BIASES[kind])
    g = jnp.asarray(cube_points(rpc, 3, seed=14, fraction=0.8))
    check_grads(model.project, (g,), order=2, modes=("fwd", "rev"), eps=1e-6, atol=1e-4, rtol=1e-4)
    # only the bias leaves adjusted: the filter pattern every adjustment uses
    spec = jax.tree.map(lambda _: False, model)
    spec = eqx.tree_at(lambda m: m.bias, spec, jax.tree.map(eqx.is_inexact_array, model.bias))
    params, static = eqx.partition(model, spec)

    def f(p):
        return eqx.combine(p, static).project(g)

    check_grads(f, (params,), order=2, modes=("fwd", "rev"), eps=1e-6, atol=1e-6, rtol=1e-5)
    img = model.project(g)
    check_grads(
        lambda x: model.localize(x, g[:, 2]), (img,), order=1, modes=("fwd", "rev"),
        eps=1e-3, atol=1e-9, rtol=1e-4,
    )  # fmt: skip


def test_biased_model_keeps_the_soft_constraints_of_the_model_it_wraps(pleiades):
    import jaxgeo.models._base as base

    rpc, _ = pleiades

    class Constrained(base.AbstractSensorModel):
        inner: object

        def project(self, ground):
            return self.inner.project(ground)

        def reference_ground(self):
            return self.inner.reference_ground()

        def adjustable_filter(self):
            return False

        def required_gcps(self, dynamic):
            return None

        def prior_residuals(self):
            return jnp.array([1.5, -2.0])

    wrapped = Biased(Constrained(rpc), AffineBias())
    np.testing.assert_array_equal(np.asarray(wrapped.prior_residuals()), [1.5, -2.0])
    assert Biased(rpc, ShiftBias()).prior_residuals().shape == (0,)
