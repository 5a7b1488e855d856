"""Host data onto the device without compiling anything.

Outside a trace, ``jnp.asarray`` of a numpy array runs a compiled identity (jax 0.10's
``lax.stage``) and ``jnp.asarray(x, dtype=float)`` / ``jnp.zeros_like`` a compiled conversion or
broadcast: one XLA program per shape and dtype, tens of milliseconds each on an empty
compilation cache and a trace and a cache lookup on a warm one. Preparing a bundle adjustment
made ~30 of them (``jaxgeo demo``). :func:`device_array` copies the data to the device
instead (``jax.device_put``); inside a trace (a tracer given) it is ``jnp.asarray``.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike


def device_array(x: ArrayLike, dtype: Any = None) -> Array:
    """``jnp.asarray(x, dtype)``: a jax array (or tracer) as it is (converted if ``dtype``
    differs), host data (numpy, Python values) copied to the default device, no XLA program.
    A Python scalar without ``dtype`` stays weakly typed, as ``jnp.asarray`` makes it."""
    if isinstance(x, jax.Array):  # tracers too; of the same type, ``jnp.asarray`` returns x
        return x if dtype is None else jnp.asarray(x, dtype)
    if dtype is None and isinstance(x, bool | int | float | complex):
        return jax.device_put(x)
    # a private copy: the transfer is asynchronous, and the caller may change its array
    # before it is done (seen on a CPU: a value written after the call reached the device)
    return jax.device_put(np.array(x, dtype=dtype, copy=True))


def zeros_like(x: ArrayLike) -> Array:
    """``jnp.zeros_like(x)`` (float ``x``), without an XLA program outside a trace."""
    if isinstance(x, jax.core.Tracer):
        return jnp.zeros_like(x)
    dtype = x.dtype if isinstance(x, jax.Array | np.ndarray | np.generic) else np.result_type(x)
    return device_array(np.zeros(np.shape(x), dtype=dtype))
