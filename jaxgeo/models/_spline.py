"""Uniform B-splines in pure JAX: the orbit ``S(t)`` and the attitude angles of the pushbroom model.

A :class:`Spline` of degree ``k`` with ``n_segments`` segments has ``n_segments + k``
coefficients (control points) of any dimension and uniform knots over ``[t_start_s, t_end_s]``,
extended by ``k`` knots of the same spacing on each side (not clamped): with
``h = (t_end_s - t_start_s) / n_segments`` the full knot vector is
``t_start_s + (j - k) h`` for ``j = 0 .. n_coeffs + k``, exactly
``scipy.interpolate.BSpline(spline.knots(), spline.coeffs, k)``. Outside the interval the end
segments' polynomials are extrapolated (scipy's ``extrapolate=True``).

Evaluation and derivatives broadcast over any batch shape of ``t``, are jittable, and are
differentiable with respect to the coefficients and ``t`` (the spline is ``C^(k-1)``).
"""

from __future__ import annotations

import functools
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float


def _f64(x) -> Array:
    return jnp.asarray(x, dtype=float)


MIN_DEGREE = 1
MAX_DEGREE = 5


def uniform_basis_matrix(degree: int) -> np.ndarray:
    """``M`` with ``B_r(s) = sum_m M[r, m] s^m``: the ``k + 1`` B-splines active on one segment.

    ``s`` in ``[0, 1)`` is the position inside the segment and ``B_r`` multiplies the control
    point ``i + r`` of segment ``i``. From the cardinal B-spline
    ``N(x) = 1/k! sum_j (-1)^j C(k+1, j) (x - j)_+^k`` with ``B_r(s) = N(s + k - r)``.
    """
    k = int(degree)
    m = np.zeros((k + 1, k + 1))
    for r in range(k + 1):
        for p in range(k + 1):
            acc = sum(
                (-1) ** j * math.comb(k + 1, j) * (k - r - j) ** (k - p) for j in range(k - r + 1)
            )
            m[r, p] = math.comb(k, p) * acc / math.factorial(k)
    return m


class Spline(eqx.Module):
    """Uniform B-spline ``t -> R^dim`` over ``[t_start_s, t_end_s]`` (seconds).

    Fields:
        coeffs: ``(n_segments + degree, dim)`` control points (the adjustable leaves).
        t_start_s, t_end_s: the interval covered by the ``n_segments`` uniform segments.
        degree: polynomial degree (static), 1 to 5; 2 or 3 for orbits and attitudes.
    """

    coeffs: Float[Array, "n_coeffs dim"]
    t_start_s: Float[Array, ""]
    t_end_s: Float[Array, ""]
    degree: int = eqx.field(static=True)

    def __init__(
        self,
        coeffs: Float[ArrayLike, "n_coeffs dim"],
        t_start_s: Float[ArrayLike, ""],
        t_end_s: Float[ArrayLike, ""],
        degree: int = 2,
    ):
        self.coeffs = jnp.asarray(coeffs, dtype=float)
        self.t_start_s = jnp.asarray(t_start_s, dtype=float)
        self.t_end_s = jnp.asarray(t_end_s, dtype=float)
        self.degree = int(degree)

    def __check_init__(self):
        if not MIN_DEGREE <= self.degree <= MAX_DEGREE:
            raise ValueError(
                f"spline degree must be in {MIN_DEGREE}..{MAX_DEGREE}, got {self.degree}"
            )
        if self.coeffs.ndim != 2 or self.coeffs.shape[0] < self.degree + 1:
            raise ValueError(
                f"spline coeffs must be (n_segments + degree, dim) with n_segments >= 1, got "
                f"shape {self.coeffs.shape} for degree {self.degree}"
            )
        if self.t_start_s.shape != () or self.t_end_s.shape != ():
            raise ValueError("spline t_start_s and t_end_s must be scalars")
        try:
            span = float(self.t_end_s - self.t_start_s)
        except jax.errors.ConcretizationTypeError:  # built inside jit: values unknown here
            span = None
        if span is not None and not span > 0.0:
            raise ValueError(
                f"spline interval must have t_end_s > t_start_s, got "
                f"[{float(self.t_start_s)}, {float(self.t_end_s)}]"
            )

    # -- construction -------------------------------------------------------------------------

    @classmethod
    def constant(
        cls,
        value: Float[ArrayLike, " dim"],
        t_start_s: float,
        t_end_s: float,
        degree: int = 2,
        n_segments: int = 1,
    ) -> Spline:
        """A spline equal to ``value`` everywhere (all control points equal)."""
        value = jnp.asarray(value, dtype=float)
        coeffs = jnp.broadcast_to(value, (int(n_segments) + int(degree), value.shape[-1]))
        return cls(coeffs, t_start_s, t_end_s, degree)

    @classmethod
    def fit(
        cls,
        times_s: Float[ArrayLike, " n"],
        values: Float[ArrayLike, "n dim"],
        t_start_s: float,
        t_end_s: float,
        degree: int = 2,
        n_segments: int = 1,
    ) -> Spline:
        """Least-squares fit of the control points to ``values`` sampled at ``times_s``."""
        values = jnp.asarray(values, dtype=float)
        times_s = jnp.asarray(times_s, dtype=float)
        if values.ndim != 2 or times_s.shape != values.shape[:1]:
            raise ValueError(
                f"Spline.fit needs times (n,) and values (n, dim), got {times_s.shape} and "
                f"{values.shape}"
            )
        n_coeffs = int(n_segments) + int(degree)
        if values.shape[0] < n_coeffs:
            raise ValueError(f"Spline.fit needs at least {n_coeffs} samples, got {values.shape[0]}")
        shell = cls(jnp.zeros((n_coeffs, values.shape[1])), t_start_s, t_end_s, degree)
        design = shell.basis(times_s)
        coeffs = jnp.linalg.lstsq(design, values)[0]
        return cls(coeffs, t_start_s, t_end_s, degree)

    # -- properties ---------------------------------------------------------------------------

    @property
    def n_segments(self) -> int:
        return self.coeffs.shape[0] - self.degree

    @property
    def dim(self) -> int:
        return self.coeffs.shape[1]

    def knots(self) -> Float[Array, " n_knots"]:
        """The full (extended, uniform) knot vector, ``n_coeffs + degree + 1`` values."""
        h = (self.t_end_s - self.t_start_s) / self.n_segments
        j = jnp.arange(self.coeffs.shape[0] + self.degree + 1, dtype=float)
        return self.t_start_s + (j - self.degree) * h

    # -- evaluation ---------------------------------------------------------------------------

    def derivative(
        self, t: Float[ArrayLike, "*batch"], order: int = 1
    ) -> Float[Array, "*batch dim"]:
        """``d^order S / dt^order`` at ``t`` (seconds); ``order=0`` is the value."""
        if order < 0:
            raise ValueError(f"derivative order must be >= 0, got {order}")
        t = jnp.asarray(t, dtype=float)
        if order > self.degree:
            return jnp.zeros((*t.shape, self.dim))
        return _evaluate(self.coeffs, self.t_start_s, self.t_end_s, t, self.degree, int(order))

    def __call__(self, t: Float[ArrayLike, "*batch"]) -> Float[Array, "*batch dim"]:
        """The spline's value at ``t`` (seconds)."""
        return self.derivative(t, 0)

    def basis(self, t: Float[ArrayLike, "*batch"]) -> Float[Array, "*batch n_coeffs"]:
        """All ``n_coeffs`` basis functions at ``t``: ``spline(t) = basis(t) @ coeffs``."""
        eye = jnp.eye(self.coeffs.shape[0])
        t = jnp.asarray(t, dtype=float)
        return _evaluate(eye, self.t_start_s, self.t_end_s, t, self.degree, 0)


class SplineObservations(eqx.Module):
    """Direct observations of a spline (orbit positions in m or attitude angles in rad).

    ``values[i]`` observed at ``times_s[i]`` (model time, seconds after the epoch) with standard
    deviations ``sigma`` (broadcast to ``values``). Residuals are ``(spline(t) - value) / sigma``.
    """

    times_s: Float[Array, " n"] = eqx.field(converter=_f64)
    values: Float[Array, "n dim"] = eqx.field(converter=_f64)
    sigma: Float[Array, "n dim"] = eqx.field(converter=_f64)

    def __check_init__(self):
        if self.values.ndim != 2 or self.times_s.shape != self.values.shape[:1]:
            raise ValueError(
                f"observations need times (n,) and values (n, dim), got {self.times_s.shape} "
                f"and {self.values.shape}"
            )
        try:
            jnp.broadcast_to(self.sigma, self.values.shape)
        except ValueError as err:
            raise ValueError(
                f"observation sigma of shape {self.sigma.shape} does not broadcast to values "
                f"{self.values.shape}"
            ) from err
        try:
            positive = bool(jnp.all(self.sigma > 0))
        except jax.errors.ConcretizationTypeError:  # built inside jit: values unknown here
            positive = True
        if not positive:
            raise ValueError("observation sigma must be > 0 (leave an observation out instead)")

    def residuals(self, spline: Spline) -> Float[Array, " n_dim"]:
        return ((spline(self.times_s) - self.values) / self.sigma).reshape(-1)


def _derivative_basis(degree: int, order: int) -> np.ndarray:
    """``W[r, q]``: ``d^order B_r / ds^order = sum_q W[r, q] s^q``."""
    m = uniform_basis_matrix(degree)
    w = np.zeros_like(m)
    for q in range(degree + 1 - order):
        w[:, q] = m[:, q + order] * math.perm(q + order, order)
    return w


@functools.partial(jax.jit, static_argnames=("degree", "order"))
def _evaluate(coeffs, t_start_s, t_end_s, t, degree: int, order: int):
    n_segments = coeffs.shape[0] - degree
    h = (t_end_s - t_start_s) / n_segments
    u = (t - t_start_s) / h
    # the segment index is piecewise constant: no gradient flows through it, none is needed
    i = jnp.clip(jnp.floor(u), 0, n_segments - 1).astype(int)
    s = (u - i)[..., None]
    w_mat = jnp.asarray(_derivative_basis(degree, order))
    w = jnp.broadcast_to(w_mat[:, degree], (*u.shape, degree + 1))
    for q in range(degree - 1, -1, -1):  # Horner: no s**0 (its derivative is NaN at s = 0)
        w = w * s + w_mat[:, q]
    w = w / h**order
    idx = i[..., None] + jnp.arange(degree + 1)
    return jnp.einsum("...r,...rd->...d", w, coeffs[idx])
