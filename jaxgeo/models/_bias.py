"""Image-space bias corrections composed onto any sensor model.

Equation 2 of 000_5aba1cb50921f3c6.txt (Fraser & Hanley bias compensation) relates a measured
image point ``(x, y)`` to the model's projection ``(x_m, y_m)`` of its ground point:

    x + B0 + B1 * y + B2 * x = x_m
    y + A0 + A1 * y + A2 * x = y_m

``ShiftBias`` keeps ``A0, B0``; ``ShiftDriftBias`` adds the drift in line ``A1, B1``;
``AffineBias`` has all six. The relation is solved exactly for the measured point (a 2x2
linear system), so ``project`` and ``localize`` of a :class:`Biased` model are exact inverses
of each other.

Equations 8-11 of 003_a7d3ea260371d8c5.txt write the same family with the other sign,
``S = x_m + a0 + a1 S + a2 P``: use :meth:`AffineBias.from_image_affine` for that form.
"""

from __future__ import annotations

import abc

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, PyTree

from .._runtime.arrays import device_array
from ._base import AbstractSensorModel, all_inexact, nothing
from ._rpc import RPC


class AbstractBias(eqx.Module):
    """An image-space correction between measured image coordinates and the uncorrected
    model's: ``to_model(image)`` and its inverse ``from_model``."""

    @abc.abstractmethod
    def coefficients(self) -> tuple[Float[Array, "2"], Float[Array, "2 2"]]:
        """``(a0, M)`` of the affine part: the shift ``(B0, A0)`` and the matrix
        ``[[B2, B1], [A2, A1]]``."""

    @property
    @abc.abstractmethod
    def n_params(self) -> int:
        """Number of bias parameters GCPs must determine (the minimum number of GCP
        observations per image / 2); parameters a prior holds are not counted."""

    @abc.abstractmethod
    def to_model(self, image: Float[ArrayLike, "*batch 2"]) -> Float[Array, "*batch 2"]:
        """Measured image coordinates -> the uncorrected model's image coordinates."""

    @abc.abstractmethod
    def from_model(self, model_image: Float[ArrayLike, "*batch 2"]) -> Float[Array, "*batch 2"]:
        """The uncorrected model's image coordinates -> measured image coordinates."""

    @abc.abstractmethod
    def prior_residuals(self) -> Float[Array, " n"]:
        """Weighted soft constraints of the bias (none for the affine family)."""


class AbstractLinearBias(AbstractBias):
    """``to_model(image) = image + a0 + M @ image`` (eq. 2), inverted exactly (2x2 system)."""

    def to_model(self, image: Float[ArrayLike, "*batch 2"]) -> Float[Array, "*batch 2"]:
        a0, m = self.coefficients()
        image = jnp.asarray(image, dtype=float)
        return image + a0 + jnp.einsum("ij,...j->...i", m, image)

    def from_model(self, model_image: Float[ArrayLike, "*batch 2"]) -> Float[Array, "*batch 2"]:
        a0, m = self.coefficients()
        return solve_affine(a0, m, jnp.asarray(model_image, dtype=float))

    def prior_residuals(self) -> Float[Array, " n"]:
        return jnp.zeros(0)


def solve_affine(a0: Float[Array, "2"], m: Float[Array, "2 2"], rhs: Float[Array, "*batch 2"]):
    """``image`` with ``image + a0 + m @ image = rhs`` (explicit 2x2 inverse: cheap, exact,
    broadcasts and differentiates everywhere)."""
    lhs = jnp.eye(2) + m
    det = lhs[0, 0] * lhs[1, 1] - lhs[0, 1] * lhs[1, 0]
    inv = jnp.array([[lhs[1, 1], -lhs[0, 1]], [-lhs[1, 0], lhs[0, 0]]]) / det
    return jnp.einsum("ij,...j->...i", inv, rhs - a0)


class ShiftBias(AbstractLinearBias):
    """Shift only: ``shift_px = (B0, A0)`` in pixels (x, y)."""

    shift_px: Float[Array, "2"]

    def __init__(self, shift_px: Float[ArrayLike, "2"] = (0.0, 0.0)):
        self.shift_px = jnp.asarray(shift_px, dtype=float)

    def coefficients(self):
        return self.shift_px, jnp.zeros((2, 2))

    @property
    def n_params(self) -> int:
        return 2


class ShiftDriftBias(AbstractLinearBias):
    """Shift plus drift in line: ``shift_px = (B0, A0)``, ``drift = (B1, A1)`` (px per line)."""

    shift_px: Float[Array, "2"]
    drift: Float[Array, "2"]

    def __init__(
        self,
        shift_px: Float[ArrayLike, "2"] = (0.0, 0.0),
        drift: Float[ArrayLike, "2"] = (0.0, 0.0),
    ):
        self.shift_px = jnp.asarray(shift_px, dtype=float)
        self.drift = jnp.asarray(drift, dtype=float)

    def coefficients(self):
        zero = jnp.zeros(2)
        return self.shift_px, jnp.stack([zero, self.drift], axis=-1)

    @property
    def n_params(self) -> int:
        return 4


class AffineBias(AbstractLinearBias):
    """Full 2D affine: ``shift_px = (B0, A0)``, ``matrix = [[B2, B1], [A2, A1]]`` (per pixel)."""

    shift_px: Float[Array, "2"]
    matrix: Float[Array, "2 2"]

    def __init__(
        self,
        shift_px: Float[ArrayLike, "2"] = (0.0, 0.0),
        matrix: Float[ArrayLike, "2 2"] = ((0.0, 0.0), (0.0, 0.0)),
    ):
        self.shift_px = device_array(shift_px, float)
        self.matrix = device_array(matrix, float)

    @classmethod
    def from_image_affine(cls, a: Float[ArrayLike, "3"], b: Float[ArrayLike, "3"]) -> AffineBias:
        """From eq. 10-11 of 003_: ``x = x_m + a0 + a1 x + a2 y``, ``y = y_m + b0 + b1 x + b2 y``.

        Rearranged, ``x - a0 - a1 x - a2 y = x_m``: the eq. 2 coefficients are the negatives.
        """
        a = jnp.asarray(a, dtype=float)
        b = jnp.asarray(b, dtype=float)
        return cls(
            shift_px=-jnp.stack([a[0], b[0]]),
            matrix=-jnp.array([[a[1], a[2]], [b[1], b[2]]]),
        )

    def coefficients(self):
        return self.shift_px, self.matrix

    @property
    def n_params(self) -> int:
        return 6


class Biased(AbstractSensorModel):
    """A sensor model with an image-space bias: ``project = bias.from_model(model.project(.))``."""

    model: AbstractSensorModel
    bias: AbstractBias

    def project(self, ground: Float[ArrayLike, "*batch 3"]) -> Float[Array, "*batch 2"]:
        return self.bias.from_model(self.model.project(ground))

    def _localize_point(self, image, h, guess):
        # exact inverse of project: undo the bias (closed form), then the wrapped model's own
        # localisation (direct where it has one), not a Newton solve on the biased projection
        return self.model.localize(self.bias.to_model(image), h, guess)

    def reference_ground(self) -> Float[Array, "3"]:
        return self.model.reference_ground()

    def prior_residuals(self) -> Float[Array, " n"]:
        """The wrapped model's soft constraints, then the bias's (a jitter's smoothness)."""
        return jnp.concatenate([self.model.prior_residuals(), self.bias.prior_residuals()])

    def adjustable_filter(self) -> PyTree[bool]:
        """The bias's floating-point leaves; the wrapped model stays fixed."""
        return eqx.tree_at(lambda m: m.bias, nothing(self), all_inexact(self.bias))

    def required_gcps(self, dynamic: PyTree) -> tuple[int, str] | None:
        """Half the bias parameters in GCPs when the bias is adjusted."""
        if jax.tree.leaves(dynamic.bias):
            n = self.bias.n_params
            return n // 2, f"the {type(self.bias).__name__} ({n} parameters)"
        return None

    def base_rpc(self) -> RPC | None:
        """The wrapped model's RPC (the bias does not change the validity domain)."""
        return self.model.base_rpc()

    def exact_rpc(self) -> RPC | None:
        """The wrapped model's exact RPC with a pure shift (``ShiftBias``, or zero drift / matrix)
        folded into its image offsets; ``None`` for other biases (they mix sample and line,
        whose denominators differ: the exporter refits)."""
        inner = self.model.exact_rpc()
        if inner is None:
            return None
        if not isinstance(self.bias, AbstractLinearBias):
            return None  # a correction that varies along the lines: the exporter refits
        a0, m = (np.asarray(x) for x in _coefficients(self.bias))
        if not (isinstance(self.bias, ShiftBias) or not np.any(m)):
            return None
        return RPC(
            inner.num,
            inner.den,
            inner.ground_offset,
            inner.ground_scale,
            np.asarray(inner.image_offset) - a0,
            inner.image_scale,
        )


@eqx.filter_jit
def _coefficients(bias):
    return bias.coefficients()


BIAS_KINDS = {"shift": ShiftBias, "shift-drift": ShiftDriftBias, "affine": AffineBias}
"""CLI / config names of the bias corrections."""
