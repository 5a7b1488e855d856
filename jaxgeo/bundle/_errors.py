"""Errors of the adjustment workflow: raised on the host with the image, point or parameter
named (the outcomes of a solve as data are :class:`jaxgeo.lsq.RESULTS`)."""

from __future__ import annotations

from ..errors import JaxgeoError, JaxgeoWarning


class AdjustmentError(JaxgeoError, ValueError):
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
