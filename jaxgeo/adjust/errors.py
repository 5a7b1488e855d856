"""Errors and warnings of the adjustment: every message names the image, point or parameter."""

from __future__ import annotations


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


class NotConvergedWarning(UserWarning):
    """The solver stopped before convergence; the result holds the last state."""
