"""Robust losses: IRLS weights and curvature against autodiff of rho, and Newton's model of
``sum rho(|r|^2)`` (Triggs' correction) against the exact gradient and Hessian."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxgeo.lsq._loss import CURVATURE_FLOOR, curvature_ratio, newton_corrected, robust
from jaxgeo.lsq.internal import irls_weights

C = 3.0


def rho(s, loss):
    """``rho(s)`` from the rescaled residual of a vector of squared norm ``s``."""
    r = jnp.stack([jnp.sqrt(s), jnp.zeros_like(s)], axis=-1).reshape(-1, 2)
    return jnp.sum(robust(r, loss, C) ** 2, axis=-1).reshape(jnp.shape(s))


@pytest.mark.parametrize("loss", ["l2", "huber", "cauchy"])
def test_weights_and_curvature_are_rho_derivatives(loss):
    s = jnp.array([0.01, 0.5, 4.0, 8.0, 10.0, 30.0, 400.0])  # both sides of c^2 = 9
    d1 = jax.vmap(jax.grad(lambda x: rho(x, loss)))(s)
    d2 = jax.vmap(jax.grad(jax.grad(lambda x: rho(x, loss))))(s)
    np.testing.assert_allclose(irls_weights(s, loss, C), d1, rtol=1e-12)
    np.testing.assert_allclose(curvature_ratio(s, loss, C), 1.0 + 2.0 * s * d2 / d1, atol=1e-12)


def linear_problem(scale):
    """Residuals ``r = A theta - b`` of 6 two-vector observations in 4 unknowns."""
    rng = np.random.default_rng(3)
    a = jnp.asarray(rng.normal(size=(6, 2, 4)))
    b = jnp.asarray(rng.normal(scale=scale, size=(6, 2)))
    theta = jnp.asarray(rng.normal(scale=0.1, size=4))
    return a, b, theta


def corrected_model(a, b, theta, loss):
    r = jnp.einsum("mkp,p->mk", a, theta) - b
    rt, jt = newton_corrected(r, (a,), loss, C)
    g = jnp.einsum("mkp,mk->p", jt, rt)
    h = jnp.einsum("mkp,mkq->pq", jt, jt)
    return r, g, h


def exact(a, b, theta, loss):
    def cost(t):  # 1/2 sum rho(|r|^2): Gauss-Newton's cost for the residuals' sum of squares
        r = jnp.einsum("mkp,p->mk", a, t) - b
        return 0.5 * jnp.sum(rho(jnp.sum(r**2, axis=-1), loss))

    return jax.grad(cost)(theta), jax.hessian(cost)(theta)


@pytest.mark.parametrize("loss", ["huber", "cauchy"])
def test_newton_model_of_inliers_is_exact(loss):
    a, b, theta = linear_problem(scale=0.7)  # every residual within c: rho convex along r
    r, g, h = corrected_model(a, b, theta, loss)
    assert float(jnp.max(jnp.sum(r**2, axis=-1))) < 0.9 * C**2 * (1 - CURVATURE_FLOOR)
    g_exact, h_exact = exact(a, b, theta, loss)
    np.testing.assert_allclose(g, g_exact, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(h, h_exact, rtol=1e-12, atol=1e-14)
    # and differs from IRLS' rho' J^T J, the model it replaces, for Cauchy
    w = irls_weights(jnp.sum(r**2, axis=-1), loss, C)
    irls = jnp.einsum("m,mkp,mkq->pq", w, a, a)
    if loss == "cauchy":
        assert float(jnp.max(jnp.abs(irls - h_exact))) > 1e-3 * float(jnp.max(jnp.abs(h_exact)))


@pytest.mark.parametrize("loss", ["huber", "cauchy"])
def test_newton_model_with_outliers_keeps_the_gradient_and_stays_positive(loss):
    a, b, theta = linear_problem(scale=6.0)  # residuals beyond c: rho concave or flat along r
    r, g, h = corrected_model(a, b, theta, loss)
    assert float(jnp.max(jnp.sum(r**2, axis=-1))) > 4.0 * C**2
    g_exact, h_exact = exact(a, b, theta, loss)
    np.testing.assert_allclose(g, g_exact, rtol=1e-12, atol=1e-14)
    assert float(jnp.min(jnp.linalg.eigvalsh(h))) > 0.0
    assert float(jnp.min(jnp.linalg.eigvalsh(h_exact))) < float(jnp.min(jnp.linalg.eigvalsh(h)))


def test_zero_residual_is_finite():
    r = jnp.zeros((2, 2))
    out = newton_corrected(r, (jnp.ones((2, 2, 3)),), "cauchy", C)
    assert all(bool(jnp.all(jnp.isfinite(x))) for x in out)
    np.testing.assert_allclose(out[1], jnp.ones((2, 2, 3)))
