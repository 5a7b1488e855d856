"""The sensor-model abstraction: ``project(ground) -> image`` and ``localize(image, h) -> ground``.

Ground coordinates are geodetic ``(lon_deg, lat_deg, h_m)`` on WGS84 (ellipsoidal height);
image coordinates are ``(x, y) = (col, row)`` in pixels with integer values at pixel centres and
``(0, 0)`` the centre of the first pixel. Every method broadcasts over leading batch axes.
"""

from __future__ import annotations

import abc

import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx
from jaxtyping import Array, ArrayLike, Float

LOCALIZE_RTOL = 0.0
LOCALIZE_ATOL = 1e-13
"""Tolerance of the localisation Newton iteration, on lon/lat (deg) and image (px) alike."""
LOCALIZE_MAX_STEPS = 64


class AbstractSensorModel(eqx.Module):
    """A sensor model: a pure, differentiable map between ground and image.

    Subclasses implement :meth:`project` and :meth:`reference_ground` (a ground point near the
    centre of the scene, the start of the default :meth:`localize`). Everything else comes from
    autodiff.
    """

    @abc.abstractmethod
    def project(self, ground: Float[ArrayLike, "*batch 3"]) -> Float[Array, "*batch 2"]:
        """Ground ``(lon_deg, lat_deg, h_m)`` -> image ``(x, y)`` in pixels."""

    @abc.abstractmethod
    def reference_ground(self) -> Float[Array, "3"]:
        """A ground point ``(lon_deg, lat_deg, h_m)`` inside the scene (start of localisation)."""

    def localize(
        self,
        image: Float[ArrayLike, "*batch 2"],
        h: Float[ArrayLike, "*batch"],
        guess: Float[ArrayLike, "*batch 2"] | None = None,
    ) -> Float[Array, "*batch 3"]:
        """Image ``(x, y)`` px at ellipsoidal height ``h`` m -> ground ``(lon_deg, lat_deg, h_m)``.

        Solves ``project(lon, lat, h) = image`` by Newton's method with autodiff Jacobians, from
        ``guess`` (lon, lat) or the scene's reference point. Differentiable (implicit function
        theorem). A point that does not converge, or with a NaN input, comes back as NaN.
        """
        return localize_newton(self, image, h, guess)

    def prior_residuals(self) -> Float[Array, " n"]:
        """Weighted residuals (already divided by their sigma) of the model's own observations.

        Soft constraints and direct observations of orbit/attitude live here; the adjustment
        adds them to the cost of every model it adjusts. Models without any return ``(0,)``.
        """
        return jnp.zeros((0,))

    def jacobian(self, ground: Float[ArrayLike, "*batch 3"]) -> Float[Array, "*batch 2 3"]:
        """d image / d ground, ``(..., 2, 3)``: pixels per degree (lon, lat) and per metre (h)."""
        ground = jnp.asarray(ground, dtype=float)
        flat = ground.reshape(-1, 3)
        jac = jax.vmap(jax.jacfwd(lambda g: self.project(g)))(flat)
        return jac.reshape(*ground.shape[:-1], 2, 3)


def _newton_residual(lonlat, args):
    model, image, h = args
    ground = jnp.concatenate([lonlat, h[None]])
    return model.project(ground) - image


def _localize_one(model, image, h, guess):
    bad = ~(jnp.all(jnp.isfinite(image)) & jnp.isfinite(h) & jnp.all(jnp.isfinite(guess)))
    # double-where: a NaN input must not poison the iteration (or its gradient) of other points
    image_safe = jnp.where(bad, jnp.zeros_like(image), image)
    h_safe = jnp.where(bad, 0.0, h)
    guess_safe = jnp.where(bad, jax.lax.stop_gradient(model.reference_ground()[:2]), guess)
    solver = optx.Newton(rtol=LOCALIZE_RTOL, atol=LOCALIZE_ATOL)
    sol = optx.root_find(
        _newton_residual,
        solver,
        guess_safe,
        args=(model, image_safe, h_safe),
        max_steps=LOCALIZE_MAX_STEPS,
        throw=False,
    )
    # a step that stalls at machine precision is still a converged point: judge by the residual
    resid = _newton_residual(sol.value, (model, image_safe, h_safe))
    ok_resid = jnp.all(jnp.abs(resid) < 1e-7)
    failed = bad | ((sol.result != optx.RESULTS.successful) & ~ok_resid)
    lonlat = jnp.where(failed, jnp.nan, sol.value)
    return jnp.concatenate([lonlat, jnp.where(bad, jnp.nan, h)[None]])


def localize_newton(
    model: AbstractSensorModel,
    image: Float[ArrayLike, "*batch 2"],
    h: Float[ArrayLike, "*batch"],
    guess: Float[ArrayLike, "*batch 2"] | None = None,
) -> Float[Array, "*batch 3"]:
    """Default localisation of :class:`AbstractSensorModel` (see :meth:`~.localize`)."""
    image = jnp.asarray(image, dtype=float)
    if image.shape[-1:] != (2,):
        raise ValueError(f"image coordinates must have a last axis of size 2, got {image.shape}")
    h = jnp.asarray(h, dtype=float)
    batch = jnp.broadcast_shapes(image.shape[:-1], h.shape)
    image = jnp.broadcast_to(image, (*batch, 2)).reshape(-1, 2)
    h = jnp.broadcast_to(h, batch).reshape(-1)
    if guess is None:
        guess = jnp.broadcast_to(model.reference_ground()[:2], image.shape)
    else:
        guess = jnp.broadcast_to(jnp.asarray(guess, dtype=float), (*batch, 2)).reshape(-1, 2)
    out = jax.vmap(_localize_one, in_axes=(None, 0, 0, 0))(model, image, h, guess)
    return out.reshape(*batch, 3)
