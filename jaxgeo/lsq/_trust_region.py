"""The trust region of the structured Levenberg-Marquardt solve: optimistix' classical one
(``optx.ClassicalTrustRegion``), tolerant of the cost's rounding noise near the optimum."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

NOISE_FLOOR = 1e-9
"""Relative cost change below which a step cannot be verified by evaluating the cost: pixel
coordinates of ~1e4 carry ~1e-11 px of rounding, which makes the sum of squares noisy at
~1e-10 relative (measured on the Pleiades pair)."""


class TrustRegion(eqx.Module):
    """Accept a step when the cost fell by at least ``low_cutoff`` of the decrease the model
    predicted; grow the region ``high_constant`` times when it fell by more than
    ``high_cutoff`` of it, shrink it ``low_constant`` times on a rejection. A step whose
    predicted and actual changes are both below the cost's rounding noise (``NOISE_FLOOR`` of
    the cost) is accepted: near the optimum the quadratic model is exact to second order while
    the cost cannot resolve the improvement, and the classical test would reject good steps at
    random until the damping stalls the solve short of the optimum."""

    high_cutoff: float = eqx.field(static=True, default=0.99)
    low_cutoff: float = eqx.field(static=True, default=0.01)
    high_constant: float = eqx.field(static=True, default=10.0)
    low_constant: float = eqx.field(static=True, default=0.25)
    noise: float = eqx.field(static=True, default=NOISE_FLOOR)

    def update(
        self,
        first_step: Bool[Array, ""],
        f: Float[Array, ""],
        f_eval: Float[Array, ""],
        predicted: Float[Array, ""],
        step_size: Float[Array, ""],
    ) -> tuple[Bool[Array, ""], Float[Array, ""]]:
        """``(accept, new step size)`` for a step from cost ``f`` to ``f_eval`` whose model
        predicted the change ``predicted`` (negative: a decrease). The first step (the
        starting point's evaluation) is accepted as it is."""
        diff = f_eval - f
        noise = self.noise * jnp.abs(f)
        tiny = (-predicted <= noise) & (diff <= 10.0 * noise) & jnp.isfinite(f_eval)
        accept = (diff <= self.low_cutoff * predicted) | tiny | first_step
        good = (diff < self.high_cutoff * predicted) & (predicted < 0) & ~first_step
        mul = jnp.where(good, self.high_constant, 1.0)
        mul = jnp.where(accept, mul, self.low_constant)
        return accept, mul * step_size


def sum_squares(tree) -> Float[Array, ""]:
    return sum((jnp.sum(x**2) for x in jax.tree.leaves(tree)), jnp.zeros(()))
