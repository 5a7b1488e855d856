"""Uniform B-splines against scipy.interpolate.BSpline: values, derivatives, fit, gradients."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads
from scipy.interpolate import BSpline

from jaxgeo.models import Spline
from jaxgeo.models._spline import uniform_basis_matrix


def _random_spline(degree, n_segments, dim=3, seed=0, t0=-1.5, t1=2.5):
    rng = np.random.default_rng(seed)
    return Spline(rng.normal(size=(n_segments + degree, dim)), t0, t1, degree)


@pytest.mark.parametrize("degree, n_segments", [(1, 3), (2, 1), (2, 4), (3, 5), (4, 2)])
def test_values_and_derivatives_equal_scipy(degree, n_segments):
    spline = _random_spline(degree, n_segments, seed=degree * 10 + n_segments)
    ref = BSpline(np.asarray(spline.knots()), np.asarray(spline.coeffs), degree, extrapolate=True)
    # inside, on every knot, and extrapolated beyond both ends
    t = np.concatenate([np.linspace(-2.5, 3.5, 97), np.asarray(spline.knots())])
    for order in range(degree + 2):
        ours = np.asarray(spline.derivative(t, order))
        theirs = ref(t, nu=order) if order <= degree else np.zeros_like(ours)
        scale = max(1.0, np.abs(theirs).max())
        assert np.abs(ours - theirs).max() < 1e-12 * scale, (degree, n_segments, order)
    np.testing.assert_allclose(spline(t), ref(t), rtol=0, atol=1e-12)


def test_knots_are_uniform_over_the_interval():
    spline = _random_spline(3, 4, t0=10.0, t1=14.0)
    knots = np.asarray(spline.knots())
    assert knots.shape == (4 + 3 + 3 + 1,)
    np.testing.assert_allclose(np.diff(knots), 1.0, rtol=0, atol=1e-14)
    # the base interval of scipy's BSpline is [t_start, t_end]
    assert knots[3] == 10.0 and knots[-4] == 14.0


@pytest.mark.parametrize("degree", [2, 3])
def test_basis_matrix_partition_of_unity(degree):
    m = uniform_basis_matrix(degree)
    s = np.linspace(0, 1, 11)
    basis = (s[:, None] ** np.arange(degree + 1)) @ m.T
    np.testing.assert_allclose(basis.sum(-1), 1.0, rtol=0, atol=1e-14)
    assert np.all(basis >= -1e-15)
    if degree == 2:  # the textbook quadratic: (1-s)^2/2, (1 + 2s - 2s^2)/2, s^2/2
        np.testing.assert_allclose(m, [[0.5, -1, 0.5], [0.5, 1, -1], [0, 0, 0.5]], atol=1e-15)


@pytest.mark.parametrize("shape", [(), (5,), (2, 3)])
def test_batch_shapes(shape):
    spline = _random_spline(2, 3, dim=4)
    t = np.linspace(-1.0, 2.0, int(np.prod(shape, dtype=int))).reshape(shape)
    assert spline(t).shape == (*shape, 4)
    assert spline.derivative(t).shape == (*shape, 4)
    assert spline.basis(t).shape == (*shape, 5)
    ref = BSpline(np.asarray(spline.knots()), np.asarray(spline.coeffs), 2)
    np.testing.assert_allclose(spline(t), ref(t), rtol=0, atol=1e-12)
    np.testing.assert_allclose(spline.basis(t) @ spline.coeffs, ref(t), rtol=0, atol=1e-12)


def test_fit_recovers_a_spline_and_constant():
    truth = _random_spline(3, 4, seed=3)
    t = np.linspace(-1.5, 2.5, 40)
    fitted = Spline.fit(t, truth(t), -1.5, 2.5, degree=3, n_segments=4)
    np.testing.assert_allclose(fitted.coeffs, truth.coeffs, rtol=0, atol=1e-10)
    const = Spline.constant(np.array([1.0, -2.0, 3.0]), 0.0, 4.0, degree=2, n_segments=3)
    np.testing.assert_allclose(const(np.linspace(-1, 5, 7)), np.tile([1.0, -2.0, 3.0], (7, 1)))
    np.testing.assert_allclose(const.derivative(np.linspace(-1, 5, 7)), 0.0, atol=1e-14)


def test_jit_and_gradients_wrt_coefficients_and_time():
    spline = _random_spline(3, 3, seed=5)
    t = jnp.array([-1.3, 0.1, 0.77, 2.4])  # away from knots: the spline is C^2 only there
    f = jax.jit(lambda s, t: s(t))
    np.testing.assert_allclose(f(spline, t), spline(t), rtol=0, atol=1e-14)
    value = jax.jit(lambda c, tt: Spline(c, -1.5, 2.5, 3)(tt))
    check_grads(value, (spline.coeffs, t), order=2, modes=("fwd",))
    check_grads(value, (spline.coeffs, t), order=1, modes=("rev",))
    # d spline / dt by autodiff equals the analytic derivative
    auto = jax.vmap(jax.jacfwd(lambda tt: spline(tt)))(t)
    np.testing.assert_allclose(auto, spline.derivative(t), rtol=1e-12, atol=1e-12)


def test_bad_input_raises():
    with pytest.raises(ValueError, match="degree"):
        Spline(np.zeros((3, 1)), 0.0, 1.0, degree=0)
    with pytest.raises(ValueError, match="n_segments"):
        Spline(np.zeros((2, 3)), 0.0, 1.0, degree=2)
    with pytest.raises(ValueError, match="t_end_s > t_start_s"):
        Spline(np.zeros((3, 3)), 1.0, 1.0, degree=2)
    with pytest.raises(ValueError, match="at least 4 samples"):
        Spline.fit(np.arange(3.0), np.zeros((3, 2)), 0.0, 2.0, degree=2, n_segments=2)
    with pytest.raises(ValueError, match="derivative order"):
        Spline(np.zeros((3, 3)), 0.0, 1.0).derivative(0.5, -1)
