"""Attitude jitter as an image-space correction: the affine bias plus offsets along the lines.

A pushbroom's attitude oscillates (a fraction of a pixel to pixels, at periods of hundreds to
thousands of lines); a vendor's RPC is smooth and cannot hold it. :class:`JitterBias` adds to
the affine bias of eq. 2 (000_5aba1cb50921f3c6.txt) an offset ``s(y) = (s_x(y), s_y(y))`` px
that varies with the line ``y`` only: a uniform cubic B-spline with a knot every
``knot_lines`` lines:

    to_model(image) = image + a0 + M @ image + s(y)

Its coefficients are held by soft priors: second differences of the coefficients with sigma
``smoothness_px`` (a jitter is smooth at the knot spacing) and the part of the spline the
affine bias already holds (the constant and the linear trend in ``y``) pinned at ``1e-3 px``
(:meth:`JitterBias.prior_residuals`), and each coefficient ``0 +- knot_sigma_px``
(:attr:`JitterBias.knot_sigma_px`: a parameter prior, which the adjustment applies as it applies
the user's bias priors, so that the solver knows the coefficients are held). Dense tie points
alone determine what the two images see differently (the offsets across the epipolar
direction); what no image observes (a knot beyond the measurements, the offsets common to the
images, those along the epipolar direction without a DEM) stays at the priors: never
undetermined. GCPs, when there are any, tie the correction to the ground.

A spline made with ``auto_knots=True`` (``knot_lines`` then the whole span, one segment) is a
placeholder: the adjustment chooses its spacing from the image's lines and measurements
(:mod:`jaxgeo.bundle`'s preparation) before solving.

The inverse, ``from_model``, is a fixed-point iteration on the line (the offset's slope is
small: a jitter of amplitude A and period P has slope ``2 pi A / P``, 1e-2 at 1.5 px / 1000
lines), exact to 1e-12 px after 6 steps at that slope.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from ._bias import AbstractBias, solve_affine

PIN_SIGMA_PX = 1e-3
"""Prior sigma of the spline's constant and linear parts (the affine bias holds them)."""
KNOT_SIGMA_PX = 5.0
"""Default prior sigma (px) of each coefficient about zero: a few times the largest attitude
jitter of current sensors (~1-2 px), so it does not bias what the measurements determine, and
it holds what they do not."""
FIXED_POINT_STEPS = 6


def spline_basis(u: Float[Array, "*batch"], n: int) -> tuple[Array, Array]:
    """First coefficient index ``(*batch,)`` and the 4 uniform cubic B-spline weights
    ``(*batch, 4)`` at knot coordinate ``u`` (segment ``i`` covers ``[i, i + 1)``) for ``n``
    coefficients; outside the knots the end values hold (no cubic extrapolation)."""
    u = jnp.clip(u, 0.0, n - 3.0)
    i = jnp.clip(jnp.floor(u), 0, n - 4)
    t = u - i
    t2, t3 = t * t, t * t * t
    w = (
        jnp.stack([(1 - t) ** 3, 3 * t3 - 6 * t2 + 4, -3 * t3 + 3 * t2 + 3 * t + 1, t3], axis=-1)
        / 6.0
    )
    return i.astype(jnp.int32), w


class JitterBias(AbstractBias):
    """Affine bias plus smooth offsets along the lines (module docstring).

    ``shift_px`` ``(2,)`` and ``matrix`` ``(2, 2)`` as :class:`AffineBias`; ``knots_px``
    ``(n, 2)`` the spline's coefficients (x, y offsets, px); ``line0`` the line of the first
    segment's start and ``knot_lines`` the knot spacing (lines); ``smoothness_px`` the prior
    sigma of the coefficients' second differences (px); ``knot_sigma_px`` the prior sigma of
    each coefficient about zero (px); ``auto_knots``: a placeholder whose spacing the
    adjustment chooses (module docstring).
    """

    shift_px: Float[Array, "2"]
    matrix: Float[Array, "2 2"]
    knots_px: Float[Array, "n 2"]
    line0: float = eqx.field(static=True)
    knot_lines: float = eqx.field(static=True)
    smoothness_px: float = eqx.field(static=True)
    knot_sigma_px: float = eqx.field(static=True)
    auto_knots: bool = eqx.field(static=True)

    def __init__(
        self,
        lines: tuple[float, float],
        knot_lines: float = 250.0,
        smoothness_px: float = 1.0,
        shift_px: Float[ArrayLike, "2"] = (0.0, 0.0),
        matrix: Float[ArrayLike, "2 2"] = ((0.0, 0.0), (0.0, 0.0)),
        knots_px: Float[ArrayLike, "n 2"] | None = None,
        *,
        knot_sigma_px: float = KNOT_SIGMA_PX,
        auto_knots: bool = False,
    ):
        """A zero jitter over image lines ``lines = (first, last)`` (e.g. ``(0, height - 1)``)
        with a knot every ``knot_lines`` lines."""
        first, last = (float(v) for v in lines)
        if not (0 < knot_lines < math.inf and last > first):
            raise ValueError(f"JitterBias: need knot_lines > 0 and lines first < last, got "
                             f"{knot_lines}, {lines}")  # fmt: skip
        for name, value in (("smoothness_px", smoothness_px), ("knot_sigma_px", knot_sigma_px)):
            if not (0 < value < math.inf):
                raise ValueError(f"JitterBias: {name} must be a positive number, got {value!r}")
        n = math.ceil((last - first) / knot_lines - 1e-9) + 3
        self.line0 = first
        self.knot_lines = float(knot_lines)
        self.smoothness_px = float(smoothness_px)
        self.knot_sigma_px = float(knot_sigma_px)
        self.auto_knots = bool(auto_knots)
        self.shift_px = jnp.asarray(shift_px, dtype=float)
        self.matrix = jnp.asarray(matrix, dtype=float)
        self.knots_px = jnp.zeros((n, 2)) if knots_px is None else jnp.asarray(knots_px, float)

    def coefficients(self):
        return self.shift_px, self.matrix

    @property
    def last_line(self) -> float:
        """The line where the spline's last segment ends (``>=`` the last line it was made
        for; equal when the span is a whole number of knot spacings)."""
        return self.line0 + (self.knots_px.shape[0] - 3) * self.knot_lines

    @property
    def n_params(self) -> int:
        return 6  # the affine part; the prior holds the spline

    def offsets(self, line: Float[ArrayLike, "*batch"]) -> Float[Array, "*batch 2"]:
        """The spline ``s(y)`` (px) at image lines ``line``."""
        n = self.knots_px.shape[0]
        u = (jnp.asarray(line, dtype=float) - self.line0) / self.knot_lines
        i, w = spline_basis(u, n)
        idx = i[..., None] + jnp.arange(4)
        return jnp.einsum("...k,...kc->...c", w, self.knots_px[idx])

    def to_model(self, image: Float[ArrayLike, "*batch 2"]) -> Float[Array, "*batch 2"]:
        image = jnp.asarray(image, dtype=float)
        return (image + self.shift_px + jnp.einsum("ij,...j->...i", self.matrix, image)
                + self.offsets(image[..., 1]))  # fmt: skip

    def from_model(self, model_image: Float[ArrayLike, "*batch 2"]) -> Float[Array, "*batch 2"]:
        rhs = jnp.asarray(model_image, dtype=float)
        image = solve_affine(self.shift_px, self.matrix, rhs)
        for _ in range(FIXED_POINT_STEPS):
            image = solve_affine(self.shift_px, self.matrix, rhs - self.offsets(image[..., 1]))
        return image

    def prior_residuals(self) -> Float[Array, " n"]:
        """Second differences (sigma ``smoothness_px``), then the mean and the trend of the
        coefficients (sigma :data:`PIN_SIGMA_PX`), x and y each; ``knot_sigma_px`` is not here
        (the adjustment applies it as a parameter prior: module docstring)."""
        c = self.knots_px
        n = c.shape[0]
        second = (c[2:] - 2 * c[1:-1] + c[:-2]) / self.smoothness_px
        k = jnp.arange(n, dtype=float) - (n - 1) / 2
        pinned = jnp.stack([c.mean(axis=0), (k[:, None] * c).sum(axis=0) / jnp.sum(k * k)])
        return jnp.concatenate([second.ravel(), pinned.ravel() / PIN_SIGMA_PX])
