"""The jitter correction: an affine bias plus a cubic B-spline in the line (models/_jitter.py)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from jaxgeo.models import AffineBias, Biased, JitterBias
from tests.conftest import cube_points


def sinusoid_jitter(rpc, amplitude_px=1.5, period_lines=800.0, knot_lines=100.0):
    """A JitterBias whose spline holds a sinusoid across the lines (least-squares coefficients)."""
    first, last = 0.0, 2.0 * float(rpc.image_offset[1])
    bias = JitterBias((first, last), knot_lines=knot_lines)
    lines = np.linspace(first, last, 4000)
    target = amplitude_px * np.sin(2 * np.pi * lines / period_lines)
    unit = np.eye(bias.knots_px.shape[0])
    basis = np.stack([
        np.asarray(JitterBias((first, last), knot_lines,
                              knots_px=np.stack([e, 0 * e], 1)).offsets(lines))[:, 0]
        for e in unit
    ], axis=1)  # fmt: skip
    coef, *_ = np.linalg.lstsq(basis, target, rcond=None)
    knots = np.stack([coef, 0.5 * coef], axis=1)  # across (x) and a half along (y)
    return JitterBias((first, last), knot_lines, shift_px=(2.0, -3.0),
                      matrix=((1e-5, 2e-5), (0.0, -1e-5)), knots_px=knots), target  # fmt: skip


def test_spline_holds_a_sinusoid_at_period_eight_knots(pleiades):
    rpc, _ = pleiades
    bias, target = sinusoid_jitter(rpc)
    lines = np.linspace(0.0, 2.0 * float(rpc.image_offset[1]), 4000)
    s = np.asarray(bias.offsets(lines))
    # cubic B-spline, 8 knots per period: the sinusoid to 1 % of its amplitude
    assert np.max(np.abs(s[:, 0] - target)) < 0.015 * 1.5
    np.testing.assert_allclose(s[:, 1], 0.5 * s[:, 0], rtol=0, atol=1e-12)


def test_project_localize_round_trip_and_exact_inverse(pleiades):
    rpc, _ = pleiades
    bias, _ = sinusoid_jitter(rpc)
    model = Biased(rpc, bias)
    g = cube_points(rpc, 300, seed=3)
    xy = model.project(g)
    np.testing.assert_allclose(bias.to_model(bias.from_model(rpc.project(g))), rpc.project(g),
                               rtol=0, atol=1e-9)  # fmt: skip
    back = model.localize(xy, g[:, 2])
    np.testing.assert_allclose(model.project(back), xy, rtol=0, atol=1e-7)
    # the jitter moves points by up to its amplitude against the affine bias alone
    affine = Biased(rpc, AffineBias(bias.shift_px, bias.matrix))
    moved = np.abs(np.asarray(xy - affine.project(g)))[:, 0]
    assert 0.5 < moved.max() <= 1.55


def test_gradients(pleiades):
    rpc, _ = pleiades
    bias, _ = sinusoid_jitter(rpc)
    g = cube_points(rpc, 5, seed=4)

    def f(knots, shift):
        b = JitterBias((bias.line0, bias.line0 + 10 * bias.knot_lines), bias.knot_lines,
                       shift_px=shift, matrix=bias.matrix, knots_px=knots)  # fmt: skip
        return Biased(rpc, b).project(g)

    check_grads(f, (bias.knots_px[:13], bias.shift_px), order=1, modes=["fwd", "rev"],
                atol=1e-5, rtol=1e-5)  # fmt: skip


def test_prior_pins_what_the_affine_bias_holds(pleiades):
    rpc, _ = pleiades
    bias = JitterBias((0.0, 1000.0), knot_lines=100.0)
    n = bias.knots_px.shape[0]
    assert n == 13 and Biased(rpc, bias).prior_residuals().shape == (2 * (n - 2) + 4,)
    # a constant or linear spline costs 1e-3 px sigma; a smooth wave only its curvature
    k = np.arange(n, dtype=float)
    for knots in (np.ones((n, 2)), np.stack([k, k], 1) * 0.1):
        r = np.asarray(JitterBias((0, 1000), 100.0, knots_px=knots).prior_residuals())
        assert np.abs(r[: 2 * (n - 2)]).max() < 1e-12 and np.abs(r).max() > 50
    wave = np.sin(2 * np.pi * k / 8)[:, None] * np.ones(2)
    wave -= wave.mean(0)
    r = np.asarray(JitterBias((0, 1000), 100.0, knots_px=wave).prior_residuals())
    assert np.abs(r[: 2 * (n - 2)]).max() == pytest.approx(2 - 2 * np.cos(np.pi / 4), rel=0.1)


def test_vmaps_and_jits(pleiades):
    rpc, _ = pleiades
    bias, _ = sinusoid_jitter(rpc)
    lines = jnp.linspace(0, 1000, 7)
    np.testing.assert_allclose(jax.jit(jax.vmap(bias.offsets))(lines), bias.offsets(lines),
                               rtol=0, atol=1e-12)  # fmt: skip
