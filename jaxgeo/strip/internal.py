"""Stages of :mod:`jaxgeo.strip` that other jaxgeo packages use: not the user API (names here
may change without notice); a user imports from ``jaxgeo.strip``."""

from ._config import DEGREES as DEGREES
from ._config import STRIP_SOLVER as STRIP_SOLVER
from ._export import REFIT_WARN_PX as REFIT_WARN_PX
from ._export import worst_refit as worst_refit
