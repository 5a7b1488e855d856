"""The sensor-model interface: one image (``AbstractSensorModel``) or several (multi-image).

Ground coordinates are geodetic ``(lon_deg, lat_deg, h_m)`` on WGS84 (ellipsoidal height);
image coordinates are ``(x, y) = (col, row)`` in pixels with integer values at pixel centres and
``(0, 0)`` the centre of the first pixel. Every method broadcasts over leading batch axes.

What the adjustment asks of a model is declared here, never probed with ``hasattr``: which
leaves it adjusts by default (:meth:`~AbstractSensorModel.adjustable_filter`), how many GCPs an
image needs (:meth:`~AbstractSensorModel.required_gcps`), its soft constraints
(:meth:`~AbstractSensorModel.prior_residuals`), an exact RPC form for export
(:meth:`~AbstractSensorModel.exact_rpc`) and the RPC whose validity domain applies
(:meth:`~AbstractSensorModel.base_rpc`, composed models included).

Return types: every method returns JAX arrays, with exceptions made for speed: an
:class:`~jaxgeo.models.RPC`'s ``project`` and ``localize`` (without ``guess``), and every
model's ``localize_on_dem``, given numpy arrays or lists (no JAX array among the inputs,
outside any transformation) run compiled programs and return ``numpy.ndarray`` -- numpy in,
numpy out. Given a JAX
array, or under ``jit``, ``vmap`` or ``grad``, they return JAX arrays like every other model.
``np.asarray(result)`` is correct (and free on the CPU) in every case.
"""

from __future__ import annotations

import abc
from typing import TYPE_CHECKING

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int, PyTree

from ._newton import newton_root

if TYPE_CHECKING:
    from ._dem import AbstractDEM, DEMGrid
    from ._rpc import RPC

LOCALIZE_ATOL = 1e-13
"""Step tolerance of the localisation Newton iteration on lon/lat (deg)."""
LOCALIZE_MAX_STEPS = 64
LOCALIZE_RESIDUAL_PX = 1e-7
"""A point whose steps stall at machine precision is converged if ``|project - image|`` is below
this (px)."""


class AbstractSensorModel(eqx.Module):
    """A sensor model: a pure, differentiable map between ground and image.

    Subclasses implement :meth:`project`, :meth:`reference_ground` (a ground point near the
    centre of the scene, the start of the default localisation), :meth:`adjustable_filter` and
    :meth:`required_gcps`. Everything else comes from autodiff.
    """

    @abc.abstractmethod
    def project(self, ground: Float[ArrayLike, "*batch 3"]) -> Float[Array, "*batch 2"]:
        """Ground ``(lon_deg, lat_deg, h_m)`` -> image ``(x, y)`` in pixels."""

    @abc.abstractmethod
    def reference_ground(self) -> Float[Array, "3"]:
        """A ground point ``(lon_deg, lat_deg, h_m)`` inside the scene (start of localisation)."""

    @abc.abstractmethod
    def adjustable_filter(self) -> PyTree[bool]:
        """Filter spec (``eqx.partition``) of the leaves an adjustment varies by default."""

    @abc.abstractmethod
    def required_gcps(self, dynamic: PyTree) -> tuple[int, str] | None:
        """``(n, what)``: the GCPs one image needs to determine the adjusted part ``dynamic``
        (the first output of ``eqx.partition``), ``what`` naming it for error messages; ``None``
        when GCPs are not needed (tie points and soft constraints suffice)."""

    def prior_residuals(self) -> Float[Array, " n"]:
        """Weighted residuals (already divided by their sigma) of the model's own observations.

        Soft constraints and direct observations of orbit/attitude live here; the adjustment
        adds them to the cost of every model it adjusts. Models without any return ``(0,)``.
        """
        return jnp.zeros((0,))

    def exact_rpc(self) -> RPC | None:
        """An RPC that projects exactly like this model, or ``None`` (the exporter then refits).

        Host-side (reads concrete values)."""
        return None

    def base_rpc(self) -> RPC | None:
        """The RPC this model is built on, whose validity domain (ground cube, image extent)
        applies to it: the RPC itself, the wrapped model's for a composed model (a bias, a
        correction), ``None`` for a physical model. Host-side checks and exports use it."""
        return None

    def localize_on_dem(
        self,
        image: Float[ArrayLike, "*batch 2"],
        dem: DEMGrid | AbstractDEM,
        **options,
    ) -> tuple[Float[Array | np.ndarray, "*batch 3"], Int[Array | np.ndarray, "*batch"]]:
        """Image ``(x, y)`` px -> ground ``(lon_deg, lat_deg, h_m)`` on a DEM, and a status.

        The first intersection of the line of sight with the DEM seen from the sensor
        (:func:`~jaxgeo.models.localize_on_dem`; ``status`` a :class:`~jaxgeo.models.DEMStatus`
        per point, the ground point NaN unless it is ``OK``). ``dem`` is what
        :func:`jaxgeo.io.read_dem` returns (host-side: the window the points need is read,
        over the heights of :meth:`base_rpc`'s validity range or the reference height
        +-1000 m) or a :class:`~jaxgeo.models.DEMGrid` (jittable and differentiable).
        Numpy in, numpy out (a JAX array in, JAX arrays out).
        ``options``: ``max_steps``, ``max_refine``, ``h_tol_m``.
        """
        from ._dem import localize_on_dem

        return localize_on_dem(self, image, dem, **options)

    def localize(
        self,
        image: Float[ArrayLike, "*ibatch 2"],
        h: Float[ArrayLike, "*hbatch"],
        guess: Float[ArrayLike, "*gbatch 2"] | None = None,
    ) -> Float[Array, "... 3"]:
        """Image ``(x, y)`` px at ellipsoidal height ``h`` m -> ground ``(lon_deg, lat_deg, h_m)``.

        Per point :meth:`_localize_point`: by default Newton's method on ``project(lon, lat, h)
        = image`` (:func:`~jaxgeo.models.newton_root`, implicit derivatives) from
        ``guess`` (lon, lat) or the scene's reference point. A point that does not converge,
        or with a NaN input, comes back as NaN.
        """
        image = jnp.asarray(image, dtype=float)
        if image.shape[-1:] != (2,):
            raise ValueError(
                f"image coordinates must have a last axis of size 2, got {image.shape}"
            )
        h = jnp.asarray(h, dtype=float)
        batch = jnp.broadcast_shapes(image.shape[:-1], h.shape)
        image = jnp.broadcast_to(image, (*batch, 2)).reshape(-1, 2)
        h = jnp.broadcast_to(h, batch).reshape(-1)
        if guess is None:
            out = jax.vmap(lambda x, z: self._localize_point(x, z, None))(image, h)
        else:
            guess = jnp.broadcast_to(jnp.asarray(guess, dtype=float), (*batch, 2)).reshape(-1, 2)
            out = jax.vmap(self._localize_point)(image, h, guess)
        return out.reshape(*batch, 3)

    def _localize_point(
        self, image: Float[Array, "2"], h: Float[Array, ""], guess: Float[Array, "2"] | None
    ) -> Float[Array, "3"]:
        """One point of :meth:`localize`: the shared Newton solve. Models with a direct
        solution (a ray meeting the height surface, a closed form) override this."""
        return localize_newton_point(self, image, h, guess)

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


def localize_newton_point(
    model: AbstractSensorModel,
    image: Float[Array, "2"],
    h: Float[Array, ""],
    guess: Float[Array, "2"] | None = None,
) -> Float[Array, "3"]:
    """The default localisation of one point (see :meth:`AbstractSensorModel.localize`)."""
    start = jax.lax.stop_gradient(model.reference_ground()[:2])
    guess = start if guess is None else guess
    bad = ~(jnp.all(jnp.isfinite(image)) & jnp.isfinite(h) & jnp.all(jnp.isfinite(guess)))
    # double-where: a NaN input must not poison the iteration (or its gradient) of other points
    image_safe = jnp.where(bad, jnp.zeros_like(image), image)
    h_safe = jnp.where(bad, 0.0, h)
    guess_safe = jnp.where(bad, start, guess)
    args = (model, image_safe, h_safe)
    sol = newton_root(
        _newton_residual, guess_safe, args, max_steps=LOCALIZE_MAX_STEPS, tol=LOCALIZE_ATOL
    )
    # a step that stalls at machine precision is still a converged point: judge by the residual
    resid = _newton_residual(sol.value, args)
    ok_resid = jnp.all(jnp.abs(resid) < LOCALIZE_RESIDUAL_PX)
    failed = bad | ~(sol.converged | ok_resid)
    lonlat = jnp.where(failed, jnp.nan, sol.value)
    return jnp.concatenate([lonlat, jnp.where(bad, jnp.nan, h)[None]])


class AbstractMultiImageModel(eqx.Module):
    """Several images sharing parameters (e.g. one orbit of an along-track sequence).

    ``image(i)`` is image ``i`` as an :class:`AbstractSensorModel`; the adjustment stacks and
    partitions the multi-image model as one parameter block.
    """

    @property
    @abc.abstractmethod
    def n_images(self) -> int:
        """Number of images."""

    @abc.abstractmethod
    def image(self, i: int) -> AbstractSensorModel:
        """Image ``i`` as a sensor model (a view sharing this model's parameters)."""

    @abc.abstractmethod
    def adjustable_filter(self) -> PyTree[bool]:
        """Filter spec (``eqx.partition``) of the leaves an adjustment varies by default."""

    @abc.abstractmethod
    def required_gcps(self, dynamic: PyTree) -> tuple[int, str] | None:
        """``(n, what)`` GCPs each image needs for the adjusted part ``dynamic``, or ``None``."""

    def prior_residuals(self) -> Float[Array, " n"]:
        """Weighted soft-constraint residuals of the shared parameters (default none)."""
        return jnp.zeros((0,))


def all_inexact(tree: PyTree) -> PyTree[bool]:
    """Filter spec selecting every floating-point array leaf of ``tree``."""
    return jax.tree.map(eqx.is_inexact_array, tree)


def nothing(tree: PyTree) -> PyTree[bool]:
    """Filter spec selecting no leaf of ``tree``."""
    return jax.tree.map(lambda _: False, tree)
