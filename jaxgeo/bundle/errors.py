"""Errors of the adjustment: raised on the host with the image, point or parameter named, and
:class:`RESULTS`, the outcomes of a solve as data (jit and vmap safe, optimistix style)."""

from __future__ import annotations

import optimistix as optx

from ..errors import JaxgeoWarning


class AdjustmentError(ValueError):
    """An adjustment that cannot be set up or solved as given (bad input, too little control)."""


class TooFewControlPoints(AdjustmentError):
    """An image has fewer GCPs than its adjustable parameters need."""


class SingularNormalEquations(AdjustmentError):
    """The normal equations are singular: some parameters or points are not determined.

    ``parameters`` names the undetermined camera parameters (``image: leaf[index]``) and
    ``points`` the undetermined ground points.
    """

    def __init__(self, message: str, parameters=(), points=()):
        super().__init__(message)
        self.parameters = tuple(parameters)
        self.points = tuple(points)


class NotConvergedWarning(JaxgeoWarning):
    """The solver stopped before convergence; the result holds the last state."""


class PoorFitWarning(JaxgeoWarning):
    """s0 far above 1 (above ``S0_WARN``) after the adjustment: the observations do not fit
    the models; the message names the worst images and points and the likely cause."""


S0_WARN = 3.0
"""s0 above which :class:`PoorFitWarning` is emitted (``jaxgeo adjust`` then exits 3)."""


class RESULTS(optx.RESULTS):  # pyright: ignore
    """Outcomes of :func:`jaxgeo.bundle.solve.solve`: optimistix' and lineax' own, plus the
    engine's. ``RESULTS[result]`` is the message; under ``vmap`` each problem has its own."""

    undetermined = (
        "The normal equations are singular: some parameters or ground points are not "
        "determined (add GCPs or tie points, or choose fewer adjustable parameters)."
    )
    outside_domain = "Ground or image points lie outside the validity domain of a sensor model."
    not_converged = (
        "The bundle adjustment did not converge: the maximum number of steps was reached."
    )


def describe(result: RESULTS) -> tuple[bool, str]:
    """``(converged, short message)`` of a (concrete, unbatched) result, for reports."""
    if bool(result == RESULTS.successful):
        return True, "converged"
    for item, text in (
        (RESULTS.not_converged, "maximum number of steps reached"),
        (RESULTS.nonlinear_max_steps_reached, "maximum number of steps reached"),
        (RESULTS.nonfinite, "non-finite values"),
        (RESULTS.nonlinear_divergence, "non-finite values"),
        (RESULTS.undetermined, "singular normal equations"),
        (RESULTS.outside_domain, "outside the validity domain"),
    ):
        if bool(result == item):
            return False, text
    return False, "solver failed"
