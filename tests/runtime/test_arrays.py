"""``jaxgeo._runtime.arrays``: host data onto the device with the values and types of
``jnp.asarray``, without compiling an XLA program."""

import logging

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxgeo._runtime.arrays import device_array, zeros_like


def _compiled(caplog, fn):
    caplog.clear()
    with caplog.at_level(logging.WARNING), jax.log_compiles():
        out = fn()
    return out, [r.getMessage() for r in caplog.records if "ompil" in r.getMessage()]


@pytest.mark.parametrize(
    "value, dtype",
    [
        (np.arange(7.0).reshape(7, 1) * 1.5, None),
        (np.arange(5, dtype=np.int64), np.int32),
        ([[1, 2], [3, 4]], float),
        ((0.5, 0.25), None),
        (np.float64(2.5), None),
    ],
)
def test_same_as_jnp_asarray_without_compiling(caplog, value, dtype):
    want = jnp.asarray(value, dtype)
    shape = (11, 3) if np.ndim(value) else ()  # shapes compiled by no one before
    value = np.broadcast_to(value, shape + np.shape(value)) if shape else value
    want = jnp.broadcast_to(want, shape + want.shape) if shape else want
    got, compiled = _compiled(caplog, lambda: device_array(value, dtype))
    assert compiled == []
    assert isinstance(got, jax.Array)
    assert got.dtype == want.dtype and got.weak_type == want.weak_type
    np.testing.assert_array_equal(np.asarray(got), np.asarray(want))


def test_python_scalars_stay_weakly_typed():
    for v in (3, 2.5):
        assert device_array(v).weak_type and jnp.asarray(v).weak_type
        assert device_array(v).dtype == jnp.asarray(v).dtype
    assert not device_array(2.5, float).weak_type


def test_a_copy_not_a_view():
    a = np.arange(4.0)
    x = device_array(a)
    a[0] = 9.0
    assert float(x[0]) == 0.0


def test_jax_arrays_and_tracers_pass_through():
    x = jnp.arange(3.0)
    assert device_array(x) is x and device_array(x, float) is x
    assert device_array(x, np.float32).dtype == np.float32

    @jax.jit
    def f(t):
        return device_array(t, float) * 2 + zeros_like(t)

    np.testing.assert_array_equal(f(x), np.arange(3.0) * 2)
    np.testing.assert_array_equal(jax.vmap(f)(jnp.ones((2, 3))), np.full((2, 3), 2.0))


def test_zeros_like_without_compiling(caplog):
    x = jnp.ones((13, 5))
    z, compiled = _compiled(caplog, lambda: zeros_like(x))
    assert compiled == []
    assert z.shape == (13, 5) and z.dtype == x.dtype and not np.any(np.asarray(z))
    assert zeros_like(np.ones(2, np.int32)).dtype == np.int32
