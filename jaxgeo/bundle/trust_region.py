"""The trust region of the structured Levenberg-Marquardt solve: optimistix' classical one,
tolerant of the cost's rounding noise near the optimum."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx
from jaxtyping import Array, Float

NOISE_FLOOR = 1e-9
"""Relative cost change below which a step cannot be verified by evaluating the cost: pixel
coordinates of ~1e4 carry ~1e-11 px of rounding, which makes the sum of squares noisy at
~1e-10 relative (measured on the Pleiades pair)."""


class _TrustRegionState(eqx.Module):
    step_size: Float[Array, ""]


class NoiseTolerantTrustRegion(optx.AbstractSearch):
    """``optx.ClassicalTrustRegion``, except that a step whose predicted and actual changes of
    the cost are both below its rounding noise (``NOISE_FLOOR`` of the cost) is accepted.

    Near the optimum the quadratic model is exact to second order while the cost cannot
    resolve the improvement: the classical test then rejects good steps at random, and the
    damping grows until the solve stalls short of the optimum.
    """

    high_cutoff: float = 0.99
    low_cutoff: float = 0.01
    high_constant: float = 10.0
    low_constant: float = 0.25
    noise: float = NOISE_FLOOR

    def init(self, y, f_info_struct) -> _TrustRegionState:
        del y, f_info_struct
        return _TrustRegionState(step_size=jnp.array(1.0))

    def step(self, first_step, y, y_eval, f_info, f_eval_info, state):
        y_diff = jax.tree.map(lambda a, b: a - b, y_eval, y)
        predicted = f_info.jac.mv(y_diff)
        rtr = sum_squares(f_info.residual)
        model = sum_squares(jax.tree.map(lambda a, b: a + b, predicted, f_info.residual))
        reduction = 0.5 * (model - rtr)  # predicted change of the cost (negative: decrease)
        f_min, f_min_eval = f_info.as_min(), f_eval_info.as_min()
        diff = f_min_eval - f_min
        noise = self.noise * jnp.abs(f_min)
        tiny = (-reduction <= noise) & (diff <= 10.0 * noise) & jnp.isfinite(f_min_eval)
        accept = (diff <= self.low_cutoff * reduction) | tiny | first_step
        good = (diff < self.high_cutoff * reduction) & (reduction < 0) & ~first_step
        mul = jnp.where(good, self.high_constant, 1.0)
        mul = jnp.where(accept, mul, self.low_constant)
        new = mul * state.step_size
        return new, accept, optx.RESULTS.successful, _TrustRegionState(step_size=new)


def sum_squares(tree) -> Float[Array, ""]:
    return sum((jnp.sum(x**2) for x in jax.tree.leaves(tree)), jnp.zeros(()))
